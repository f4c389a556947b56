"""The module's self-test checks, without Qt: the module's Test class runs them in Slicer ("Reload and Test", ctest),
and ``make test`` runs the same functions on a headless ``slicer-core`` scene (``Testing/test_module_selftest.py``),
so a broken self-test cannot hide.

Each check takes ``new_session()`` (a new :class:`~.session.DesignSession`: the module's logic in Slicer) and
``add_volume(values, spacing, name)`` (adds a scalar volume node to the scene the session works on and returns it).
Volumes are built in memory; nothing is downloaded.
"""

import os
import tempfile
import unittest
from typing import Callable

import numpy as np

from . import mrml
from .classes import build_classes
from .design import STAGES, TransferFunctionDesign
from .options import OPTIONS
from .panel import PANEL_NONE, PANEL_OPTIONS, PanelModel, PanelView
from .session import AUTO_DETAIL, CLASS, TISSUE
from .tissues import tissue_hierarchy
from .transfer_function import read_vp, read_vp_json

SPACING = (0.5, 0.5, 0.8)

_case = unittest.TestCase()
_case.maxDiff = None


def nested_volume(size: int = 24) -> np.ndarray:
    """Float volume ``[k, j, i]``: background 0, a cube of 100, a ball of 300 inside, a small ball of 600."""
    k, j, i = np.mgrid[:size, :size, :size].astype(np.float32)
    centre = (size - 1) / 2.0
    radius2 = (i - centre) ** 2 + (j - centre) ** 2 + (k - centre) ** 2
    values = np.zeros((size, size, size), dtype=np.float32)
    values[3:-3, 3:-3, 3:-3] = 100.0
    values[radius2 < (size / 4.0) ** 2] = 300.0
    values[radius2 < (size / 10.0) ** 2] = 600.0
    return values


def hand_made_design() -> TransferFunctionDesign:
    """A design made by hand, without running the engine (instant): 64 bins over 0..640, 4 classes."""
    n_bins = 64
    labels = np.repeat(np.arange(4), [8, 16, 24, 16])
    exemplars = np.array([4, 16, 36, 56])
    bin_voxels = np.ones(n_bins, dtype=np.int64)
    bin_voxels[:8] = 1000
    edges = np.linspace(0.0, 640.0, n_bins + 1)
    classes = build_classes(labels, exemplars, bin_voxels, edges, background="largest")
    similarity = np.where(labels[:, None] == labels[None, :], 1.0, 0.2)
    design = TransferFunctionDesign(
        value_range=(0.0, 640.0),
        n_bins=n_bins,
        labels=labels,
        classes=classes,
        options={"n_bins": n_bins},
        clustering={"n_iter": 10, "converged": True, "n_classes": 4, "damping": 0.5},
        timings_s={"quantize": 0.01, "similarity": 0.02, "clustering": 0.03, "classes": 0.0},
        bin_voxels=bin_voxels,
        hierarchy=tissue_hierarchy(labels, bin_voxels, [1, 2, 3], similarity),
        spacing=SPACING,
        similarity=similarity,
    )
    design.regroup("all")
    return design


def opacity_at(property_node, value: float) -> float:
    return property_node.GetVolumeProperty().GetScalarOpacity().GetValue(value)


def _property_node_count(scene) -> int:
    return scene.GetNumberOfNodesByClass("vtkMRMLVolumePropertyNode")


AddVolume = Callable[[np.ndarray, tuple, str], object]


def check_edit_and_export(new_session, add_volume: AddVolume) -> None:
    """Class edits rewrite the transfer function in place; export to .vp.json and .vp."""
    volume = add_volume(nested_volume(), SPACING, "Nested")
    session = new_session()
    design = hand_made_design()
    property_node = session.apply(volume, design)
    display_node = session.volume_rendering_logic().GetFirstVolumeRenderingDisplayNode(volume)
    _case.assertIs(display_node.GetVolumePropertyNode(), property_node)
    _case.assertEqual(_property_node_count(volume.GetScene()), 1)  # no unused default property node
    _case.assertAlmostEqual(property_node.GetVolumeProperty().GetScalarOpacityUnitDistance(), design.unit_distance)

    _case.assertIsNotNone(design.background_class)
    _case.assertEqual(opacity_at(property_node, 40.0), 0.0)  # background hidden
    top = design.classes[-1]  # bins 48..63: values 480..640
    volume_property = property_node.GetVolumeProperty()
    session.set_class_opacity(top.id, 0.75)
    _case.assertIs(property_node.GetVolumeProperty(), volume_property)  # edited in place, not replaced
    _case.assertAlmostEqual(opacity_at(property_node, 560.0), 0.75, places=6)
    session.set_class_color(top.id, (0.0, 0.0, 1.0))
    _case.assertAlmostEqual(volume_property.GetRGBTransferFunction().GetColor(560.0)[2], 1.0, places=6)
    session.set_class_visible(top.id, False)
    _case.assertEqual(opacity_at(property_node, 560.0), 0.0)
    session.solo_class(top.id)
    _case.assertAlmostEqual(opacity_at(property_node, 560.0), 0.75, places=6)
    _case.assertEqual(opacity_at(property_node, 250.0), 0.0)
    session.solo_class(None)
    session.show_all_classes()
    _case.assertGreater(opacity_at(property_node, 250.0), 0.0)
    _case.assertGreater(opacity_at(property_node, 560.0), 0.0)
    session.reset_colors()
    _case.assertNotEqual(tuple(volume_property.GetRGBTransferFunction().GetColor(560.0)), (0.0, 0.0, 1.0))
    _case.assertFalse(mrml.modified_outside(volume))
    _case.assertEqual(mrml.design_of_volume(volume).to_dict(), design.to_dict())  # every edit is stored

    with tempfile.TemporaryDirectory() as folder:
        written = session.export_transfer_function(os.path.join(folder, "tf"))
        _case.assertTrue(written.endswith(".vp.json"))
        exported, effective_range = read_vp_json(written)
        _case.assertAlmostEqual(exported.GetScalarOpacity().GetValue(560.0), opacity_at(property_node, 560.0))
        _case.assertEqual(effective_range, (0.0, 640.0))
        legacy = session.export_transfer_function(os.path.join(folder, "tf"), default_extension=".vp")
        _case.assertTrue(legacy.endswith("tf.vp"))
        _case.assertAlmostEqual(read_vp(legacy).GetScalarOpacity().GetValue(250.0), opacity_at(property_node, 250.0))
    _case.assertEqual(session.default_export_extension(False), ".vp")
    _case.assertEqual(session.default_export_extension(True), ".vp.json")


def check_restore(new_session, add_volume: AddVolume) -> None:
    """A design is restored from the scene, with its unit distance; the similarity matrix only in the same session."""
    volume = add_volume(nested_volume(), SPACING, "Nested")
    session = new_session()
    design = hand_made_design()
    property_node = session.apply(volume, design)
    session.set_class_opacity(design.classes[2].id, 0.33)
    property_node.GetVolumeProperty().SetScalarOpacityUnitDistance(1.0)  # as Slicer 5.8 reads a .vp scene file

    other = new_session()
    restored = other.restore(volume)
    _case.assertIsNotNone(restored)
    _case.assertIs(other.property_node, property_node)
    _case.assertEqual(len(restored.classes), len(design.classes))
    _case.assertAlmostEqual(restored.classes[2].opacity, 0.33)
    _case.assertAlmostEqual(property_node.GetVolumeProperty().GetScalarOpacityUnitDistance(), design.unit_distance)
    _case.assertIsNone(restored.similarity)  # not stored with the scene
    # The same session keeps the similarity matrix of its own run, also after showing another volume.
    _case.assertIsNotNone(session.restore(volume).similarity)
    _case.assertIsNone(session.restore(add_volume(nested_volume(), SPACING, "Third")))
    _case.assertIsNotNone(session.restore(volume).similarity)
    # A volume without a design restores nothing.
    _case.assertIsNone(other.restore(add_volume(nested_volume(), SPACING, "Other")))
    _case.assertIsNone(other.design)


def check_outside_changes(new_session, add_volume: AddVolume) -> None:
    """The Volume Rendering module's preset menu, Synchronize and Property selector cannot erase the design, and are
    noticed; an edit then shows the design again (the panel asks the user first)."""
    volume = add_volume(nested_volume(), SPACING, "Nested")
    session = new_session()
    design = hand_made_design()
    property_node = session.apply(volume, design)
    vr_logic = session.volume_rendering_logic()
    # The preset menu copies the preset into the shown property node (CopyContent replaces all attributes).
    property_node.CopyContent(vr_logic.GetPresetByName("US-Fetal"))
    _case.assertEqual(session.outside_change(), mrml.CHANGE_EDITED)
    _case.assertEqual(mrml.design_of_volume(volume).to_dict(), design.to_dict())
    _case.assertEqual(new_session().restore(volume).to_dict(), design.to_dict())
    session.set_class_opacity(design.classes[-1].id, 0.5)
    _case.assertIsNone(session.outside_change())
    _case.assertAlmostEqual(opacity_at(property_node, 560.0), 0.5, places=6)
    # "Synchronize with Volumes module".
    display_node = vr_logic.GetFirstVolumeRenderingDisplayNode(volume)
    vr_logic.CopyDisplayToVolumeRenderingDisplayNode(display_node)
    _case.assertEqual(session.outside_change(), mrml.CHANGE_EDITED)
    session.update()
    _case.assertIsNone(session.outside_change())
    # Another property node picked in the Volume Rendering module: noticed, and an edit shows ours again.
    users = volume.GetScene().AddNewNodeByClass("vtkMRMLVolumePropertyNode", "Mine")
    display_node.SetAndObserveVolumePropertyNodeID(users.GetID())
    _case.assertEqual(session.outside_change(), mrml.CHANGE_OTHER_NODE)
    session.set_class_visible(design.classes[-1].id, False)
    _case.assertIs(display_node.GetVolumePropertyNode(), property_node)
    _case.assertEqual(opacity_at(property_node, 560.0), 0.0)
    _case.assertIsNotNone(volume.GetScene().GetNodeByID(users.GetID()))  # the user's node is kept


def check_segments_and_preset(new_session, add_volume: AddVolume) -> None:
    """The shown classes as segments (names, colours, voxels), the design as a Volume Rendering preset."""
    volume = add_volume(nested_volume(), SPACING, "Nested")
    session = new_session()
    design = hand_made_design()
    session.apply(volume, design)
    shown = [c for c in design.classes if design.is_shown(c.id)]
    segmentation_node = session.export_segmentation()
    segmentation = segmentation_node.GetSegmentation()
    _case.assertEqual(segmentation.GetNumberOfSegments(), len(shown))
    labels = mrml.class_label_volume(volume, design)
    for index, isovalue_class in enumerate(shown):
        segment = segmentation.GetNthSegment(index)
        _case.assertEqual(segment.GetName(), mrml.segment_name(isovalue_class))
        _case.assertEqual(list(np.round(segment.GetColor(), 6)), list(np.round(isovalue_class.color, 6)))
        _case.assertGreater(int(np.count_nonzero(labels == isovalue_class.id)), 0)

    name = f"{volume.GetName()} classes"
    preset = session.add_preset(name)
    _case.assertIs(session.volume_rendering_logic().GetPresetByName(name), preset)
    _case.assertTrue(mrml.shows_design(preset, design))
    _case.assertIsNotNone(preset.GetNodeReference(session.volume_rendering_logic().GetIconVolumeReferenceRole()))
    session.volume_rendering_logic().RemovePreset(preset)


def check_tissues(new_session, add_volume: AddVolume) -> None:
    """The tree of tissues and classes: Detail regroups instantly, edits and solo work on both levels, everything is
    stored in the scene and restored, the segments follow the tree's level."""
    volume = add_volume(nested_volume(), SPACING, "Nested")
    session = new_session()
    design = hand_made_design()  # one tissue per class: classes 1..3 besides the background class 0
    property_node = session.apply(volume, design)
    _case.assertEqual(session.detail_range(), (1, 3))
    _case.assertEqual(session.detail(), 3)
    rows = session.rows()
    _case.assertEqual([(r.level, r.classes, r.children) for r in rows], [(TISSUE, (i,), ()) for i in range(4)])
    _case.assertTrue(rows[0].background and not rows[0].shown)
    _case.assertEqual(session.level(), CLASS)

    # Detail 1: one tissue holding classes 1 to 3, shown as a tissue row with three class rows.
    session.regroup(1)
    _case.assertIs(session.design, design)
    rows = session.rows()
    _case.assertEqual(len(rows), 2)
    tissue = rows[1]
    _case.assertEqual((tissue.level, tissue.classes), (TISSUE, (1, 2, 3)))
    _case.assertEqual([(c.level, c.id) for c in tissue.children], [(CLASS, 1), (CLASS, 2), (CLASS, 3)])
    _case.assertEqual(session.detail(), 1)
    _case.assertEqual(session.level(), TISSUE)
    _case.assertEqual(mrml.design_of_volume(volume).n_tissues, 1)  # stored at once

    # A tissue edit reaches every class of the tissue; a class edit only its class.
    session.edit(TISSUE, tissue.id, opacity=0.5, color=(0.0, 1.0, 0.0))
    for value in (160.0, 400.0, 560.0):  # classes 1, 2 and 3 (bins 8-23, 24-47, 48-63 of 10 units each)
        _case.assertAlmostEqual(opacity_at(property_node, value), 0.5, places=6)
    _case.assertEqual({r.color for r in session.rows()[1].children}, {(0.0, 1.0, 0.0)})
    session.edit(CLASS, 3, opacity=0.25)
    _case.assertAlmostEqual(opacity_at(property_node, 560.0), 0.25, places=6)
    _case.assertAlmostEqual(opacity_at(property_node, 160.0), 0.5, places=6)
    session.edit(CLASS, 2, visible=False)
    _case.assertIsNone(session.rows()[1].visible)  # partly visible
    _case.assertEqual(opacity_at(property_node, 400.0), 0.0)
    session.edit(TISSUE, tissue.id, visible=True)
    _case.assertTrue(session.rows()[1].visible)

    # Solo on both levels.
    session.solo(CLASS, 2)
    _case.assertEqual([c.shown for c in session.rows()[1].children], [False, True, False])
    _case.assertEqual(opacity_at(property_node, 160.0), 0.0)
    _case.assertAlmostEqual(opacity_at(property_node, 400.0), 0.5, places=6)
    session.solo(TISSUE, tissue.id)
    _case.assertTrue(session.rows()[1].solo)
    _case.assertFalse(any(c.solo for c in session.rows()[1].children))
    _case.assertGreater(opacity_at(property_node, 160.0), 0.0)
    _case.assertFalse(mrml.modified_outside(volume))

    # The grouping, the edits and solo are stored in the scene and restored by another session.
    other = new_session()
    other.restore(volume)
    _case.assertEqual(other.rows(), session.rows())
    _case.assertEqual(other.detail(), 1)

    # Segments at the tree's level: one per shown tissue, with the voxels of its shown classes.
    session.solo(TISSUE, None)
    segmentation = session.export_segmentation().GetSegmentation()
    shown = [r for r in session.rows() if r.shown]
    _case.assertEqual(segmentation.GetNumberOfSegments(), len(shown))
    _case.assertEqual(segmentation.GetNthSegment(0).GetName(), mrml.tissue_segment_name(design.tissues[1]))
    _case.assertEqual(
        list(np.round(segmentation.GetNthSegment(0).GetColor(), 6)), list(np.round(design.tissues[1].color, 6))
    )
    classes = session.export_segmentation(level=CLASS).GetSegmentation()
    _case.assertEqual(classes.GetNumberOfSegments(), sum(design.is_shown(c.id) for c in design.classes))

    # Back to the automatic count, and past the top (one tissue per class).
    session.regroup(AUTO_DETAIL)
    _case.assertEqual(session.detail(), AUTO_DETAIL)
    _case.assertEqual(design.n_tissues, design.hierarchy.auto)
    _case.assertEqual(mrml.design_of_volume(volume).options["tissues"], "auto")
    session.regroup(99)
    _case.assertEqual((design.n_tissues, session.detail()), (3, 3))
    _case.assertEqual(new_session().restore(volume).options["tissues"], "all")


def check_run(new_session, add_volume: AddVolume) -> None:
    """A full run, in this process and in a child process: the same design."""
    volume = add_volume(nested_volume(), SPACING, "Nested")
    session = new_session()
    stages = []
    # More levels than the 24^3 volume has (6): all are used.
    options = {"n_bins": 64, "levels": 32}
    design = session.run(volume, options, progress=lambda stage, fraction, message: stages.append(stage))
    _case.assertGreaterEqual(len(design.classes), 2)
    _case.assertEqual(design.n_bins, 64)
    _case.assertIsNone(design.options["levels"])
    _case.assertEqual(set(design.timings_s), set(STAGES))
    _case.assertEqual(stages[0], "quantize")
    _case.assertIn("classes", stages)
    display_node = session.volume_rendering_logic().GetFirstVolumeRenderingDisplayNode(volume)
    _case.assertIs(display_node.GetVolumePropertyNode(), session.property_node)
    # Running again reuses the property node made for the volume.
    property_node = session.property_node
    job = session.start(volume, options)
    reports = []
    job.wait(timeout=300, progress=lambda *report: reports.append(report))
    again = session.finish(volume, job)
    _case.assertIs(session.property_node, property_node)
    _case.assertFalse(os.path.exists(job.folder))
    _case.assertEqual(again.to_dict()["classes"], design.to_dict()["classes"])
    _case.assertEqual(reports[-1][0], STAGES[-1])
    # The Detail setting (the panel's "tissues"): a count past the volume's classes is one tissue per class.
    grouped = session.run(volume, {**options, "tissues": 1})
    _case.assertEqual((grouped.n_tissues, session.detail()), (1, 1))
    job = session.start(volume, {**options, "tissues": 999})
    job.wait(timeout=300)
    every = session.finish(volume, job)
    _case.assertEqual(every.options["tissues"], "all")
    _case.assertEqual(every.n_tissues, every.hierarchy.max_tissues)
    _case.assertEqual(mrml.design_of_volume(volume).options["tissues"], "all")


class _Cancelled(Exception):
    pass


def check_cancel(new_session, add_volume: AddVolume) -> None:
    """Cancelling leaves the scene untouched, in this process (progress raises, in the similarity or between affinity
    propagation's iterations) and in a child process (killed)."""
    volume = add_volume(nested_volume(), SPACING, "Nested")
    scene = volume.GetScene()
    session = new_session()
    nodes = scene.GetNumberOfNodes()

    def cancel(stage, fraction, message):
        if stage == "similarity":
            raise _Cancelled()

    with _case.assertRaises(_Cancelled):
        session.run(volume, {"n_bins": 32}, progress=cancel)
    _case.assertIsNone(session.design)
    # Affinity propagation reports between its iterations (at 512 bins every 7th; it needs at least 16), so Cancel
    # stops it there, not at the end of the stage.
    reports = []

    def cancel_clustering(stage, fraction, message):
        reports.append((stage, fraction))
        if stage == "clustering" and fraction > 0:
            raise _Cancelled()

    with _case.assertRaises(_Cancelled):
        session.run(volume, {"n_bins": 512}, progress=cancel_clustering)
    stage, fraction = reports[-1]
    _case.assertEqual(stage, "clustering")
    _case.assertLess(fraction, 0.5)
    _case.assertIsNone(session.design)
    job = session.start(volume, {"n_bins": 32})
    job.cancel()
    _case.assertFalse(job.running)
    with _case.assertRaises(RuntimeError):
        session.finish(volume, job)
    _case.assertFalse(os.path.exists(job.folder))
    _case.assertIsNone(session.design)
    _case.assertEqual(scene.GetNumberOfNodes(), nodes)


# The panel's state ----------------------------------------------------------------------------------------------
def singleton_parameter_node(scene, tag: str):
    """The scene's ``vtkMRMLScriptedModuleNode`` singleton of ``tag``, made as ScriptedLoadableModuleLogic makes a
    module's parameter node (Slicer v5.8.1 ScriptedLoadableModule.py:310-363)."""
    node = scene.GetSingletonNode(tag, "vtkMRMLScriptedModuleNode")
    if node is None:
        node = scene.CreateNodeByClass("vtkMRMLScriptedModuleNode")
        node.UnRegister(None)  # created with a reference for the caller: the Python object owns it
        node.SetSingletonTag(tag)
        node.SetAttribute("ModuleName", tag)
        node.SetName(scene.GenerateUniqueName(tag))
        node = scene.AddNode(node)
    return node


class NodeParameters:
    """The two parameters the panel's state follows, kept in an MRML node as Slicer's parameter node wrapper keeps
    them (serializers.py at v5.8.1: a node as a reference named after the parameter, :405-409; an int as its text,
    :258-261; a missing value read as its default, wrapper.py:43-46), so that writes send the node's ModifiedEvent.
    The engine's parameters are plain attributes (``values``), by default the panel's defaults."""

    def __init__(self, node, **values):
        self.parameterNode = node
        defaults = {parameter: OPTIONS[option].default for parameter, option in PANEL_OPTIONS.items()}
        self.__dict__.update(defaults, **PANEL_NONE, preferenceValue=-1.0)
        del self.__dict__["tissues"]
        self.__dict__.update(values)

    @property
    def inputVolume(self):
        return self.parameterNode.GetNodeReference("inputVolume")

    @inputVolume.setter
    def inputVolume(self, volume):
        self.parameterNode.SetParameter("inputVolume", "")
        self.parameterNode.SetNodeReferenceID("inputVolume", volume.GetID() if volume is not None else None)

    @property
    def tissues(self) -> int:
        text = self.parameterNode.GetParameter("tissues")
        return int(text) if text else AUTO_DETAIL

    @tissues.setter
    def tissues(self, value: int) -> None:
        self.parameterNode.SetParameter("tissues", str(int(value)))


class RecordingView(PanelView):
    """The panel's drawing, recorded; answers the question before overwriting an outside change with ``answer``."""

    def __init__(self, answer: bool = True) -> None:
        self.designs, self.changes, self.asked, self.answer = [], [], [], answer
        self.states, self.looks = [], []

    def show_design(self, design) -> None:
        self.designs.append(design)

    def show_outside_change(self, change) -> None:
        self.changes.append(change)

    def show_apply_state(self, state: str, volume) -> None:
        self.states.append(state)

    def show_look(self, name) -> None:
        self.looks.append(name)

    def confirm_overwrite(self, change: str) -> bool:
        self.asked.append(change)
        return self.answer

    @property
    def shown(self):
        return self.designs[-1] if self.designs else None


def check_panel(new_session, add_volume: AddVolume) -> None:
    """The panel's state on the scene's own events: the input selector auto-selects the first volume added (with no
    design yet), a design applied behind the panel is not regrouped (audit F4), two volumes keep their own grouping,
    and a scene close shows nothing while the parameter node survives."""
    session = new_session()
    scene = session.volume_rendering_logic().GetMRMLScene()
    view = RecordingView()
    model = PanelModel(session, view)
    model.observe_scene(scene)
    parameter_node = singleton_parameter_node(scene, "IsoSimilarityTFSelfTest")
    model.set_parameters(NodeParameters(parameter_node))
    parameters = model.parameters

    from vtkmodules.util.misc import calldata_type
    from vtkmodules.util.vtkConstants import VTK_OBJECT

    @calldata_type(VTK_OBJECT)
    def select_first_volume(caller, event, node):
        # What the selector (a qMRMLNodeComboBox, noneEnabled false) does: "QMRMLCombobox selects the first instance
        # of the specified node type" (Slicer v5.8.1 qSlicerSegmentationsModuleWidget.cxx:80-81). Whether it does so
        # at once or after a batch of scene changes, and during an import, is not known here: this check adds its
        # volumes one by one, outside any import.
        if parameters.inputVolume is None and node.GetClassName() == "vtkMRMLScalarVolumeNode":
            parameters.inputVolume = node

    selecting = scene.AddObserver(scene.NodeAddedEvent, select_first_volume)
    try:
        volume = add_volume(nested_volume(), SPACING, "Nested")
        _case.assertIs(model.shown_volume, volume)
        _case.assertIsNone(view.shown)
        session.apply(volume, hand_made_design())  # the logic, the panel not told
        other = add_volume(nested_volume(), SPACING, "Other")
        model.refresh()  # the module is entered
        _case.assertEqual(mrml.design_of_volume(volume).options["tissues"], "all")
        parameters.inputVolume = other
        _case.assertIsNone(view.shown)
        _case.assertIsNone(model.detail_shown)
        parameters.inputVolume = volume
        _case.assertEqual((len(view.shown.tissues), parameters.tissues, model.detail_shown), (4, 3, 3))
        # Two volumes, each with its own grouping.
        parameters.inputVolume = other
        model.show_result(other, session.run(other, {"n_bins": 32}))
        parameters.tissues = 1
        _case.assertIn(mrml.design_of_volume(other).options["tissues"], (1, "all"))
        parameters.inputVolume = volume
        _case.assertEqual((len(view.shown.tissues), parameters.tissues), (4, 3))
        parameters.inputVolume = other
        _case.assertEqual(parameters.tissues, model.detail_shown)
        _case.assertNotEqual(parameters.tissues, 3)
        # A saved Detail is left alone while no design is shown.
        parameters.inputVolume = None
        parameters.tissues = 7
        parameters.inputVolume = add_volume(nested_volume(), SPACING, "Third")
        _case.assertEqual((parameters.tissues, model.detail_shown), (7, None))
        # Closing the scene: nothing shown; the singleton parameter node is kept (reset) and still followed.
        scene.Clear(0)
        _case.assertIs(scene.GetSingletonNode("IsoSimilarityTFSelfTest", "vtkMRMLScriptedModuleNode"), parameter_node)
        _case.assertIsNone(parameters.inputVolume)
        _case.assertIsNone(view.shown)
        _case.assertIsNone(session.design)
        last = add_volume(nested_volume(), SPACING, "Last")  # selected again by the selector
        _case.assertIs(model.shown_volume, last)
    finally:
        scene.RemoveObserver(selecting)
        model.stop()
        scene.RemoveNode(parameter_node)


#: Every check, in the order the module's Test class runs them.
CHECKS = {
    "edit_and_export": check_edit_and_export,
    "restore": check_restore,
    "outside_changes": check_outside_changes,
    "segments_and_preset": check_segments_and_preset,
    "tissues": check_tissues,
    "run": check_run,
    "cancel": check_cancel,
    "panel": check_panel,
}
