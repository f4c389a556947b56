"""The module's panel code (IsoSimilarityTF.py) run headless: real MRML (slicer-core) and the real logic, with
stand-ins for what needs the Slicer application (Qt widgets, CTK, the parameter node wrapper, the i18n functions).

It cannot tell whether a Qt call exists or behaves as in Slicer (the module's own widget test, run in Slicer, does);
it runs every line of the tissue tree, the Detail slider and the in-process Apply against the real design and scene,
so a wrong name or a wrong call into the logic fails here.
"""

import importlib.util
import sys
import types
from pathlib import Path
from unittest import mock

import pytest

from IsoSimilarityTFLib import mrml
from IsoSimilarityTFLib.selftest import SPACING, hand_made_design, nested_volume
from IsoSimilarityTFLib.session import AUTO_DETAIL, CLASS, TISSUE

MODULE_FILE = Path(__file__).resolve().parents[1] / "IsoSimilarityTF" / "IsoSimilarityTF.py"


class _Base:
    def __init__(self, *args, **kwargs):
        pass


def _fake_qt():
    qt = mock.MagicMock(name="qt")
    qt.Qt.Unchecked, qt.Qt.PartiallyChecked, qt.Qt.Checked = 0, 1, 2
    return qt


@pytest.fixture()
def module(slicer_app, monkeypatch):
    """IsoSimilarityTF.py imported with stand-ins for Qt, CTK and the Slicer application."""
    import slicer
    import slicer.util

    qt = _fake_qt()
    monkeypatch.setitem(sys.modules, "qt", qt)
    monkeypatch.setitem(sys.modules, "ctk", mock.MagicMock(name="ctk"))
    i18n = types.ModuleType("slicer.i18n")
    i18n.tr = lambda text: text
    i18n.translate = lambda context, text: text
    wrapper = types.ModuleType("slicer.parameterNodeWrapper")
    wrapper.Choice = wrapper.WithinRange = lambda *args: args
    wrapper.parameterNodeWrapper = lambda cls: cls
    scripted = types.ModuleType("slicer.ScriptedLoadableModule")
    for name in ("ScriptedLoadableModule", "ScriptedLoadableModuleWidget", "ScriptedLoadableModuleTest"):
        setattr(scripted, name, type(name, (_Base,), {}))
    scripted.ScriptedLoadableModuleLogic = type("ScriptedLoadableModuleLogic", (_Base,), {})
    for name, fake in (("slicer.i18n", i18n), ("slicer.parameterNodeWrapper", wrapper),
                       ("slicer.ScriptedLoadableModule", scripted)):  # fmt: skip
        monkeypatch.setitem(sys.modules, name, fake)
    app = mock.MagicMock(name="slicer.app")
    app.testingEnabled.return_value = True  # tryWithErrorDisplay re-raises without a dialog
    monkeypatch.setattr(slicer, "app", app, raising=False)
    monkeypatch.setattr(slicer, "mrmlScene", slicer_app.scene, raising=False)
    modules = mock.MagicMock(name="slicer.modules")
    modules.volumerendering.logic.return_value = slicer_app.volume_rendering_logic
    monkeypatch.setattr(slicer, "modules", modules, raising=False)
    monkeypatch.setattr(slicer, "qMRMLUtils", mock.MagicMock(name="qMRMLUtils"), raising=False)
    spec = importlib.util.spec_from_file_location("IsoSimilarityTF_under_test", MODULE_FILE)
    loaded = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(loaded)
    return loaded


class _ParameterNode(types.SimpleNamespace):
    pass


@pytest.fixture()
def panel(module, slicer_app):
    """A widget with stand-in widgets, the real logic, a volume with a hand-made design shown."""
    widget = module.IsoSimilarityTFWidget()
    widget.ui = mock.MagicMock(name="ui")
    widget.logic = module.IsoSimilarityTFLogic()
    volume = slicer_app.add_volume(nested_volume(), spacing=SPACING, name="Nested")
    widget._parameterNode = _ParameterNode(inputVolume=volume, tissues=AUTO_DETAIL, preference="median")
    widget.logic.apply(volume, hand_made_design())
    return widget, volume


def test_showing_a_design_fills_the_tree_and_the_detail(panel):
    widget, volume = panel
    widget._onParameterNodeModified()  # a new volume for the panel: its design is restored and shown
    assert widget._shownVolume is volume
    assert sorted(widget._rowWidgets) == [(TISSUE, i) for i in range(4)]  # one tissue per class
    assert widget._parameterNode.tissues == widget._detailShown == 3
    widget.ui.detailSlider.setRange.assert_called_with(AUTO_DETAIL, 3)
    assert widget.ui.detailValueLabel.text == "One per class: 3 (thesis)"


def test_the_detail_regroups_and_the_tree_edits_reach_the_transfer_function(panel):
    widget, volume = panel
    widget._onParameterNodeModified()
    widget._parameterNode.tissues = 1
    widget._onParameterNodeModified()
    design = widget.logic.design
    assert design.n_tissues == 1 and mrml.design_of_volume(volume).n_tissues == 1
    assert sorted(widget._rowWidgets) == [(CLASS, 1), (CLASS, 2), (CLASS, 3), (TISSUE, 0), (TISSUE, 1)]
    assert widget.ui.detailValueLabel.text == "1 tissue"

    color = mock.MagicMock(**{"redF.return_value": 0.0, "greenF.return_value": 1.0, "blueF.return_value": 0.0})
    widget.onRowColorChanged(TISSUE, 1, color)
    assert all(design.classes[c].color == [0.0, 1.0, 0.0] for c in (1, 2, 3))
    widget.onRowOpacityChanged(TISSUE, 1, 40)
    assert {design.classes[c].opacity for c in (1, 2, 3)} == {0.4}
    widget.onRowOpacityChanged(CLASS, 3, 20)
    assert design.classes[3].opacity == 0.2 and design.classes[2].opacity == 0.4
    widget.onRowVisibleChanged(CLASS, 2, 0)  # unchecked
    assert not design.classes[2].visible
    assert widget.logic.rows()[1].visible is None
    widget.onRowVisibleChanged(TISSUE, 1, 2)  # from partly checked to checked
    assert design.classes[2].visible
    widget.onRowSoloToggled(CLASS, 2, True)
    assert design.solo_class == 2
    widget.onRowSoloToggled(TISSUE, 1, True)
    assert (design.solo_class, design.solo_tissue_id) == (None, 1)
    widget.onShowAllButton()
    assert design.solo_tissue_id is None
    assert not mrml.modified_outside(volume)
    assert mrml.design_of_volume(volume).to_dict() == design.to_dict()

    # Past the top of the slider (a saved count): one tissue per class, and the slider follows the design.
    widget._parameterNode.tissues = 9
    widget._onParameterNodeModified()
    assert design.n_tissues == 3 and widget._parameterNode.tissues == 3
    widget._parameterNode.tissues = AUTO_DETAIL
    widget._onParameterNodeModified()
    assert design.options["tissues"] == "auto" and widget.ui.detailValueLabel.text.startswith("Automatic")

    widget.onExportSegmentationButton()
    names = [n.GetName() for n in _nodes(volume.GetScene(), "vtkMRMLSegmentationNode")]
    assert len(names) == 1


def _nodes(scene, class_name):
    return [scene.GetNthNodeByClass(i, class_name) for i in range(scene.GetNumberOfNodesByClass(class_name))]


def test_no_design_leaves_the_saved_detail_alone(panel, slicer_app):
    widget, _ = panel
    widget._parameterNode.tissues = 7
    widget._parameterNode.inputVolume = slicer_app.add_volume(nested_volume(), spacing=SPACING, name="Other")
    widget._onParameterNodeModified()
    assert widget.logic.design is None and widget._rowWidgets == {}
    assert widget._parameterNode.tissues == 7
    assert widget.ui.detailSlider.enabled is False


def test_apply_in_process_shows_the_design_and_cancel_changes_nothing(panel, slicer_app, module):
    widget, volume = panel
    widget._onParameterNodeModified()
    options = {"n_bins": 32, "tissues": 1}
    assert widget.logic.runs_in_process(volume, options)
    widget._runInProcess(volume, options)
    assert widget.logic.design.n_bins == 32 and widget.logic.design.n_tissues == 1
    assert widget._parameterNode.tissues == 1 and not widget._running
    stored = mrml.design_of_volume(volume).to_dict()

    import slicer

    def press_cancel():  # the user presses Cancel while the design runs
        widget.onCancelButton()

    slicer.app.processEvents.side_effect = press_cancel
    widget._runInProcess(volume, {"n_bins": 64})
    assert mrml.design_of_volume(volume).to_dict() == stored
    assert widget.ui.statusLabel.text == "Cancelled." and not widget._running
