"""The panel's state (IsoSimilarityTFLib.panel) on a real headless scene (slicer-core), with the events in Slicer's
own order: the real ``vtkMRMLScene.Import`` of a saved scene, the real singleton parameter node, the real Volume
Rendering logic's presets. The self-test check ``panel`` (test_module_selftest.py) covers the selector's
auto-selection (F4), two volumes and ``Clear``.

What stands in for Slicer's Python: the parameter node wrapper (only the two parameters the state reads, stored in the
real MRML node as the wrapper stores them: selftest.NodeParameters).
"""

import numpy as np
import pytest

from IsoSimilarityTFLib import mrml
from IsoSimilarityTFLib.panel import (
    CANCELLED,
    DONE,
    IDLE,
    REFUSED,
    RUNNING,
    RUNNING_CHILD,
    RUNNING_HERE,
    VOLUME_REMOVED,
    PanelModel,
    gui_tag,
)
from IsoSimilarityTFLib.selftest import (
    SPACING,
    NodeParameters,
    RecordingView,
    hand_made_design,
    nested_volume,
    singleton_parameter_node,
)
from IsoSimilarityTFLib.session import TISSUE, DesignSession

MODULE_NAME = "IsoSimilarityTF"


def open_panel(app, view=None):
    """The panel opened once in a session: it observes the scene and the parameter node from then on (until
    ``stop``, the widget's cleanup)."""
    model = PanelModel(DesignSession(app.volume_rendering_logic), view or RecordingView())
    model.observe_scene(app.scene)
    model.set_parameters(NodeParameters(singleton_parameter_node(app.scene, MODULE_NAME)))
    return model


@pytest.fixture()
def panel_of(slicer_app):
    """``panel_of(view=None)``: the panel opened on the test's scene, cleaned up before the scene is."""
    models = []

    def open_one(view=None):
        models.append(open_panel(slicer_app, view))
        return models[-1]

    yield open_one
    for model in models:
        model.stop()


def add_volume(app, name):
    return app.add_volume(nested_volume(), spacing=SPACING, name=name)


def designed_volume(app, model, volume=None):
    """A volume (by default a new one) selected in the panel, designed (Apply) and shown: ``(volume, property
    node)``."""
    volume = add_volume(app, "Nested") if volume is None else volume
    model.parameters.inputVolume = volume
    property_node = model.session.apply(volume, hand_made_design())
    model.show_result(volume, model.session.design)
    return volume, property_node


def saved_scene(tmp_path, edit, names=("Head",)):
    """A scene saved as a bundle: volumes ``names``, the module's parameter node selecting the last (added after
    them, as when the module is opened after loading), and the last one's design with the user's ``edit``. Returns
    the .mrml path and the saved design."""
    from isosimtf.rendering import HeadlessSlicer

    folder = tmp_path / "saved"
    folder.mkdir()
    with HeadlessSlicer(size=(32, 32)) as app:
        volumes = [add_volume(app, name) for name in names]
        model = open_panel(app)
        designed_volume(app, model, volumes[-1])
        edit(model)
        assert app.scene.SaveSceneToSlicerDataBundleDirectory(str(folder))
        # The design is in a .txt file, read after every node is added (vtkMRMLTextNode.cxx:131-133,176-178).
        assert list(folder.rglob("*.txt"))
        text = (folder / "saved.mrml").read_text()
        assert '"classes"' not in text
        # The audit's failing order: the parameter node is copied in place before the design's text node is added.
        assert text.index('singletonTag="IsoSimilarityTF"') < text.index("IsoSimilarityTF design")
        saved = mrml.design_of_volume(volumes[-1]).to_dict()
        model.stop()
    return folder / "saved.mrml", saved


def _blue_tissue(model):
    model.edit(lambda: model.session.edit(TISSUE, 3, color=(0.0, 0.0, 1.0)))


# F1 -----------------------------------------------------------------------------------------------------------------
def test_f1_a_scene_imported_after_the_panel_was_opened_shows_its_design_and_edits(tmp_path, slicer_app, panel_of):
    path, saved = saved_scene(tmp_path, _blue_tissue)
    view = RecordingView()
    model = panel_of(view)
    slicer_app.scene.SetURL(str(path))
    assert slicer_app.scene.Import()  # Add Data of a .mrml: no close first
    volume = slicer_app.scene.GetFirstNodeByName("Head")
    assert model.shown_volume is volume
    assert view.shown is not None and view.shown.to_dict() == saved
    assert view.shown.tissues[3].color == [0.0, 0.0, 1.0]
    assert model.detail_shown == model.parameters.tissues == 3
    # An edit now keeps the saved ones (it writes the restored design, not an empty panel's fresh one).
    model.edit(lambda: model.session.edit(TISSUE, 2, opacity=0.3))
    stored = mrml.design_of_volume(volume)
    assert stored.tissues[3].color == [0.0, 0.0, 1.0] and stored.tissues[2].opacity == pytest.approx(0.3)


def test_f1_nothing_is_restored_while_the_import_runs(tmp_path, slicer_app, panel_of):
    path, _ = saved_scene(tmp_path, _blue_tissue)
    model = panel_of()
    restored_while_importing = []
    restore = model.session.restore
    model.session.restore = lambda volume: (restored_while_importing.append(slicer_app.scene.IsImporting()),
                                            restore(volume))[1]  # fmt: skip
    slicer_app.scene.SetURL(str(path))
    assert slicer_app.scene.Import()
    assert restored_while_importing and not any(restored_while_importing)


# G1: the node selector rebuilds at EndImport -----------------------------------------------------------------------
def _selector_stand_in(app):
    """What the Input selector does at EndImport (qMRMLSceneModel::updateScene, Slicer#7492): its rows are removed
    (the combo box says None) and added again (it selects the scene's first volume), each written into the parameter
    node by its connector. Its observer is added when the selector gets the scene, before the panel opens."""
    parameters = NodeParameters(singleton_parameter_node(app.scene, MODULE_NAME))

    def rebuild(caller, event):
        parameters.inputVolume = None
        parameters.inputVolume = app.scene.GetFirstNodeByClass("vtkMRMLScalarVolumeNode")

    return app.scene.AddObserver(app.scene.EndImportEvent, rebuild)


@pytest.mark.parametrize("before", [(), ("Session",)], ids=["load-scene", "add-data-beside-a-volume"])
def test_g1_a_scene_of_two_volumes_opens_on_the_one_its_panel_showed(tmp_path, slicer_app, panel_of, before):
    path, saved = saved_scene(tmp_path, _blue_tissue, names=("First", "Second"))
    for name in before:  # Add Data into a session that holds a volume
        add_volume(slicer_app, name)
    observer = _selector_stand_in(slicer_app)
    try:
        view = RecordingView()
        model = panel_of(view)
        model.parameters.inputVolume = slicer_app.scene.GetFirstNodeByClass("vtkMRMLScalarVolumeNode")
        slicer_app.scene.SetURL(str(path))
        assert slicer_app.scene.Import()
    finally:
        slicer_app.scene.RemoveObserver(observer)
    second = slicer_app.scene.GetFirstNodeByName("Second")
    assert model.parameters.inputVolume is second and model.shown_volume is second
    assert view.shown is not None and view.shown.to_dict() == saved
    assert mrml.design_text_node(second).GetHideFromEditors()  # G8: still hidden after a save and a load


# G3: the wrapper caches each parameter, refreshed by its own observer ----------------------------------------------
class CachingParameters(NodeParameters):
    """Slicer's parameter node wrapper as it reads a node reference: from a cache (serializers.py:416-417 at v5.8.1)
    refreshed by an observer it adds when it is built (wrapper.py:84-97), before anyone else's; its own writes refresh
    the cache before the node's ModifiedEvent (wrapper.py:103-113)."""

    def __init__(self, node):
        super().__init__(node)
        self._cached = node.GetNodeReference("inputVolume")
        node.AddObserver("ModifiedEvent", self._refresh)

    def _refresh(self, caller, event):
        self._cached = self.parameterNode.GetNodeReference("inputVolume")

    @property
    def inputVolume(self):
        return self._cached

    @inputVolume.setter
    def inputVolume(self, volume):
        was = self.parameterNode.StartModify()
        NodeParameters.inputVolume.fset(self, volume)
        self._cached = volume
        self.parameterNode.EndModify(was)


def test_g3_a_raw_mrml_write_of_the_input_is_shown_at_once(slicer_app):
    scene = slicer_app.scene
    node = scene.AddNewNodeByClass("vtkMRMLScriptedModuleNode")  # a node no one observes yet
    parameters = CachingParameters(node)
    view = RecordingView()
    model = PanelModel(DesignSession(slicer_app.volume_rendering_logic), view)
    model.observe_scene(scene)
    model.set_parameters(parameters)
    try:
        first, other = add_volume(slicer_app, "First"), add_volume(slicer_app, "Other")
        model.session.apply(other, hand_made_design())
        parameters.inputVolume = first  # the panel's own wrapper
        assert model.shown_volume is first
        node.SetNodeReferenceID("inputVolume", other.GetID())  # a script, another wrapper, a scene view
        assert model.shown_volume is other and view.shown is not None
        node.SetNodeReferenceID("inputVolume", first.GetID())
        assert model.shown_volume is first and view.shown is None
    finally:
        model.stop()


# G8: the status follows the 3D view --------------------------------------------------------------------------------
def test_g8_an_outside_change_is_said_at_once_and_unsaid_when_the_design_is_shown_again(slicer_app, panel_of):
    view = RecordingView(answer=True)
    model = panel_of(view)
    volume, property_node = designed_volume(slicer_app, model)
    assert model.outside_change is None and view.changes[-1:] in ([], [None])
    property_node.CopyContent(slicer_app.volume_rendering_logic.GetPresetByName("US-Fetal"))  # a preset
    assert view.changes[-1] == mrml.CHANGE_EDITED == model.outside_change
    model.edit(lambda: model.session.edit(TISSUE, 3, opacity=0.5))  # "show this module's design again": yes
    assert view.changes[-1] is None and model.outside_change is None
    other = slicer_app.scene.AddNewNodeByClass("vtkMRMLVolumePropertyNode")
    mrml.volume_rendering_display_node(volume).SetAndObserveVolumePropertyNodeID(other.GetID())
    assert view.changes[-1] == mrml.CHANGE_OTHER_NODE
    model.parameters.inputVolume = None  # the panel shows no design: nothing to say
    assert view.changes[-1] is None


def test_g8_the_panels_own_edits_are_checked_once(slicer_app, panel_of):
    model = panel_of()
    designed_volume(slicer_app, model)
    checks = []
    check = mrml.outside_change
    mrml.outside_change = lambda *args: (checks.append(args), check(*args))[1]
    try:
        model.edit(lambda: model.session.edit(TISSUE, 3, opacity=0.5))  # dozens of property events
    finally:
        mrml.outside_change = check
    assert len(checks) <= 2  # the confirmation's question and the check after the writes


# F5: a preset copied in with CopyContent --------------------------------------------------------------------------
def test_f5_showing_the_design_again_after_a_preset_brings_back_its_shading_and_gradient_opacity(slicer_app, panel_of):
    view = RecordingView(answer=True)
    model = panel_of(view)
    volume, property_node = designed_volume(slicer_app, model)
    prop = property_node.GetVolumeProperty()
    ours = (prop.GetShade(), prop.GetAmbient(), prop.GetSpecular(), prop.GetGradientOpacity().GetValue(0.0))
    preset = slicer_app.volume_rendering_logic.GetPresetByName("US-Fetal")
    preset.GetVolumeProperty().SetAmbient(0.55)
    preset.GetVolumeProperty().GetGradientOpacity().RemoveAllPoints()
    preset.GetVolumeProperty().GetGradientOpacity().AddPoint(0.0, 0.25)
    property_node.CopyContent(preset)  # the Volume Rendering module's preset menu
    model.parameters.inputVolume = None
    model.parameters.inputVolume = volume
    assert view.changes[-1] == mrml.CHANGE_EDITED
    model.edit(lambda: model.session.edit(TISSUE, 3, opacity=0.5))
    assert view.asked == [mrml.CHANGE_EDITED]
    prop = property_node.GetVolumeProperty()
    assert (prop.GetShade(), prop.GetAmbient(), prop.GetSpecular(), prop.GetGradientOpacity().GetValue(0.0)) == ours
    assert not mrml.modified_outside(volume)


def test_an_edit_refused_after_a_preset_changes_nothing(slicer_app, panel_of):
    view = RecordingView(answer=False)
    model = panel_of(view)
    volume, property_node = designed_volume(slicer_app, model)
    property_node.CopyContent(slicer_app.volume_rendering_logic.GetPresetByName("US-Fetal"))
    before = mrml.design_of_volume(volume).to_dict()
    model.edit(lambda: model.session.edit(TISSUE, 3, opacity=0.5))
    model.parameters.tissues = 1
    assert view.asked == [mrml.CHANGE_EDITED, mrml.CHANGE_EDITED]
    assert mrml.design_of_volume(volume).to_dict() == before and model.parameters.tissues == 3


def test_a_colour_only_change_in_volume_rendering_is_asked_about_before_an_edit(slicer_app, panel_of):
    from test_mrml import shift_color_of_point

    view = RecordingView(answer=False)
    model = panel_of(view)
    volume, property_node = designed_volume(slicer_app, model)
    shift_color_of_point(property_node, 2)
    model.edit(lambda: model.session.edit(TISSUE, 3, opacity=0.5))
    assert view.asked == [mrml.CHANGE_EDITED] and mrml.modified_outside(volume)


def test_g4_a_design_applied_to_another_volume_behind_the_panel_leaves_the_panel_on_its_own(slicer_app, panel_of):
    view = RecordingView()
    model = panel_of(view)
    shown, _ = designed_volume(slicer_app, model)
    other = add_volume(slicer_app, "Other")
    model.session.apply(other, hand_made_design())  # a script, with the module's logic
    before = mrml.design_of_volume(other).to_dict()
    model.parameters.tissues = 1  # the Detail and the edits act on the shown volume's design
    model.edit(lambda: model.session.edit(TISSUE, 1, opacity=0.25))
    assert mrml.design_of_volume(other).to_dict() == before
    stored = mrml.design_of_volume(shown)
    assert stored.n_tissues == 1 and stored.tissues[1].opacity == pytest.approx(0.25)
    model.session.apply(other, hand_made_design())
    segmentation = model.hand_over(model.session.export_segmentation)  # Export to segmentation
    assert segmentation.GetName().startswith("Nested")
    assert model.session.volume_node is shown and mrml.design_of_volume(other).to_dict() == before


def test_g4_a_design_deleted_behind_the_panel_is_shown_as_none(slicer_app, panel_of):
    view = RecordingView()
    model = panel_of(view)
    shown, _ = designed_volume(slicer_app, model)
    model.session.apply(add_volume(slicer_app, "Other"), hand_made_design())  # a script
    slicer_app.scene.RemoveNode(mrml.design_text_node(shown))  # the design node deleted (a script, Data module)
    assert model.hand_over(model.session.export_segmentation) is None
    assert view.shown is None and model.detail_shown is None


def test_g4_nothing_is_handed_over_when_the_panel_shows_no_design(slicer_app, panel_of):
    model = panel_of()
    designed = add_volume(slicer_app, "Designed")
    model.session.apply(designed, hand_made_design())
    model.parameters.inputVolume = add_volume(slicer_app, "Plain")
    assert model.hand_over(model.session.export_segmentation) is None
    assert slicer_app.scene.GetNumberOfNodesByClass("vtkMRMLSegmentationNode") == 0


def test_the_input_follows_the_active_volume_until_the_user_picks_another(slicer_app, panel_of):
    model = panel_of()
    selection = slicer_app.app_logic.GetSelectionNode()
    model.observe_selection(selection)
    first, second = add_volume(slicer_app, "First"), add_volume(slicer_app, "Second")
    selection.SetActiveVolumeID(first.GetID())
    assert model.parameters.inputVolume is first and model.shown_volume is first
    selection.SetActiveVolumeID(second.GetID())
    assert model.parameters.inputVolume is second
    model.volume_picked(first)  # the selector's nodeActivated, then its write into the parameter node
    model.parameters.inputVolume = first
    selection.SetActiveVolumeID(None)
    selection.SetActiveVolumeID(second.GetID())
    model.select_active_volume()  # the module entered again
    assert model.parameters.inputVolume is first
    model.parameters.inputVolume = None
    model.select_active_volume()  # entered with nothing selected: the active volume, even when not followed
    assert model.parameters.inputVolume is second
    model.parameters.inputVolume = first
    model.volume_picked(second)  # picking the active volume follows it again
    model.parameters.inputVolume = second
    selection.SetActiveVolumeID(first.GetID())
    assert model.parameters.inputVolume is first
    label_map = slicer_app.scene.AddNewNodeByClass("vtkMRMLLabelMapVolumeNode")
    selection.SetActiveVolumeID(label_map.GetID())  # not a volume the selector lists
    assert model.parameters.inputVolume is first and model.active_volume() is None
    model.volume_picked(second)  # with no active volume to follow, the input follows the next one
    assert model.follow_active_volume
    model.volume_picked(None)
    assert model.follow_active_volume
    selection.SetActiveVolumeID(first.GetID())
    model.volume_picked(second)
    model.parameters.inputVolume = second
    assert not model.follow_active_volume
    slicer_app.scene.Clear(0)  # a new scene: follow the active volume again
    third = add_volume(slicer_app, "Third")
    selection = slicer_app.app_logic.GetSelectionNode()
    model.observe_selection(selection)
    selection.SetActiveVolumeID(third.GetID())
    assert model.parameters.inputVolume is third


# Apply and Cancel ----------------------------------------------------------------------------------------------------
def _select(model, volume, **values):
    """The panel's parameters: ``volume`` selected, the engine's parameters ``values`` (others at their default)."""
    for name, value in values.items():
        setattr(model.parameters, name, value)
    model.parameters.inputVolume = volume


def test_apply_here_shows_the_design_and_cancel_changes_nothing(slicer_app, panel_of):
    view = RecordingView()
    model = panel_of(view)
    volume = add_volume(slicer_app, "Nested")
    _select(model, volume, bins=32, tissues=1)
    reports = []
    assert model.apply(lambda *report: reports.append(report)) == DONE
    design = view.shown
    assert design.n_bins == 32 and model.shown_volume is volume and not model.running
    assert view.states == [RUNNING_HERE, IDLE]
    assert model.parameters.tissues == model.detail_shown == 1 and reports[0][0] == "quantize"
    stored, nodes = mrml.design_of_volume(volume).to_dict(), slicer_app.scene.GetNumberOfNodes()

    def press_cancel(stage, fraction, message):  # Cancel pressed while the similarity is computed
        assert model.apply_state in (RUNNING_HERE, "cancelling")
        assert model.apply(press_cancel) == REFUSED  # a second Apply, handled while this one repaints
        if stage == "similarity":
            model.cancel()

    model.parameters.bins = 64
    assert model.apply(press_cancel) == CANCELLED
    assert mrml.design_of_volume(volume).to_dict() == stored and slicer_app.scene.GetNumberOfNodes() == nodes
    assert not model.running and view.shown is design and view.states[-1] == IDLE

    def remove_volume(stage, fraction, message):
        if stage == "similarity" and volume.GetScene() is not None:
            slicer_app.scene.RemoveNode(volume)

    assert model.apply(remove_volume) == VOLUME_REMOVED and not model.running


def test_cancel_then_apply_designs_again_and_the_input_chosen_meanwhile_is_shown_after(slicer_app, panel_of):
    view = RecordingView()
    model = panel_of(view)
    volume, other = add_volume(slicer_app, "Nested"), add_volume(slicer_app, "Other")
    _select(model, volume, bins=32)
    assert model.apply(lambda *report: model.cancel()) == CANCELLED
    assert mrml.design_of_volume(volume) is None and view.states == [RUNNING_HERE, "cancelling", IDLE]

    selection = slicer_app.app_logic.GetSelectionNode()
    model.observe_selection(selection)

    def select_other(stage, fraction, message):  # the active volume changes, then a script selects another volume
        assert model.apply_volume is volume and model.shown_volume is volume
        if model.parameters.inputVolume is volume:
            selection.SetActiveVolumeID(other.GetID())
            assert model.parameters.inputVolume is volume  # the input is left alone while the design runs
            model.parameters.inputVolume = other

    assert model.apply(select_other) == DONE and model.apply_volume is None
    assert mrml.design_of_volume(volume).n_bins == 32 and view.designs[-2].n_bins == 32
    assert model.shown_volume is other and view.shown is None and not model.running


def _poll_until_done(model, timeout=120):
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        outcome = model.poll_job()[1]
        if outcome != RUNNING:
            return outcome
        time.sleep(0.05)
    raise TimeoutError


def _in_child(model):
    model.session.runs_in_process = lambda volume, options=None: False


def test_a_job_is_shown_when_done_and_cancel_or_a_removed_volume_leave_nothing(slicer_app, panel_of):
    import os

    view = RecordingView()
    model = panel_of(view)
    _in_child(model)
    volume = add_volume(slicer_app, "Nested")
    _select(model, volume, bins=32)
    assert model.apply(None) == RUNNING
    folder = model.job.folder
    assert model.running and view.states == [RUNNING_CHILD]
    assert model.apply(None) == REFUSED and model.job.folder == folder  # a second click: refused
    other = add_volume(slicer_app, "Other")
    model.parameters.inputVolume = other  # a script: ignored while the job runs (the selector is disabled)
    assert model.shown_volume is volume
    assert _poll_until_done(model) == DONE
    assert mrml.design_of_volume(volume).n_bins == 32 and view.designs[-2].n_bins == 32
    assert model.shown_volume is other and view.shown is None  # then the panel shows the input of now
    assert model.job is None and not os.path.exists(folder) and view.states[-1] == IDLE
    _select(model, volume, bins=1024)
    model.apply(None)
    folder = model.job.folder
    model.cancel()
    assert model.job is None and not model.running and not os.path.exists(folder)
    assert model.poll_job() == ([], CANCELLED)
    model.parameters.bins = 32
    model.apply(None)
    folder = model.job.folder
    slicer_app.scene.RemoveNode(volume)
    assert _poll_until_done(model) == VOLUME_REMOVED
    assert model.job is None and not os.path.exists(folder) and not model.running


def test_a_scene_close_ends_a_running_job(slicer_app, panel_of):
    import os

    model = panel_of()
    _in_child(model)
    _select(model, add_volume(slicer_app, "Nested"), bins=1024)
    model.apply(None)
    folder = model.job.folder
    slicer_app.scene.Clear(0)
    assert model.job is None and not model.running and not os.path.exists(folder)


def test_closing_the_panel_ends_a_running_job(slicer_app):
    import os

    model = open_panel(slicer_app)
    _in_child(model)
    _select(model, add_volume(slicer_app, "Nested"), bins=1024)
    model.apply(None)
    folder = model.job.folder
    model.stop()  # the widget's cleanup: Slicer closes, or Reload
    assert model.job is None and not model.running and not os.path.exists(folder)


def test_a_job_that_cannot_start_leaves_the_panel_idle(slicer_app, panel_of):
    view = RecordingView()
    model = panel_of(view)
    _in_child(model)

    def cannot_start(volume, options=None):
        raise MemoryError("no room for the volume's copy")

    model.session.start = cannot_start
    _select(model, add_volume(slicer_app, "Nested"))
    with pytest.raises(MemoryError):
        model.apply(None)
    assert view.states == [RUNNING_CHILD, IDLE] and not model.running and model.apply_volume is None


def test_a_bad_option_starts_nothing(slicer_app, panel_of):
    from IsoSimilarityTFLib.errors import OptionError

    view = RecordingView()
    model = panel_of(view)
    _select(model, add_volume(slicer_app, "Nested"), bins=1)
    with pytest.raises(OptionError):
        model.apply(None)
    assert view.states == [] and not model.running


# F2 -----------------------------------------------------------------------------------------------------------------
class _Wrapper:
    def __init__(self, connected):
        self._parameterGUIs = dict.fromkeys(connected)


def test_f2_the_gui_tag_of_slicer_5_8_is_found():
    assert gui_tag(_Wrapper([0, 1, 2]), None) == 2  # 5.8: connectGui returned None
    assert gui_tag(_Wrapper([0, 1, 2]), 1) == 1  # 5.10 and later: the tag given
    assert gui_tag(_Wrapper([]), None) is None
    assert gui_tag(object(), None) is None


def test_stop_removes_every_observer(slicer_app, panel_of):
    view = RecordingView()
    model = panel_of(view)
    model.stop()
    parameters = NodeParameters(singleton_parameter_node(slicer_app.scene, MODULE_NAME))
    parameters.inputVolume = add_volume(slicer_app, "Nested")
    slicer_app.scene.Clear(0)
    assert view.designs == [] and model.parameters is None


def test_the_recorded_design_is_the_sessions(slicer_app, panel_of):
    model = panel_of()
    volume = add_volume(slicer_app, "Nested")
    model.session.apply(volume, hand_made_design())
    model.parameters.inputVolume = volume
    assert model.view.shown is model.session.design
    np.testing.assert_array_equal(model.view.shown.labels, hand_made_design().labels)
