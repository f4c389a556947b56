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

import numpy as np
import pytest
import vtk

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


def _connect(widget, module, parameters):
    """The widget's panel state on stand-in parameters (writes to them send no event: the tests call refresh)."""
    import vtk

    widget.panel = module.PanelModel(widget.logic, widget)
    widget._looksTimer = mock.MagicMock(name="looks timer")  # setup() makes it; its timeout is _showLooks
    widget._parameterNode = parameters
    widget.panel.set_parameters(parameters, node=vtk.vtkObject())


@pytest.fixture()
def panel(module, slicer_app):
    """A widget with stand-in widgets, the real logic, a volume with a hand-made design shown."""
    widget = module.IsoSimilarityTFWidget()
    widget.ui = mock.MagicMock(name="ui")
    widget.logic = module.IsoSimilarityTFLogic()
    volume = slicer_app.add_volume(nested_volume(), spacing=SPACING, name="Nested")
    _connect(widget, module, _ParameterNode(inputVolume=volume, tissues=AUTO_DETAIL, preference="median"))
    widget.logic.apply(volume, hand_made_design())
    return widget, volume


def test_showing_a_design_fills_the_tree_and_the_detail(panel):
    widget, volume = panel
    widget.panel.refresh()  # a new volume for the panel: its design is restored and shown
    assert widget.panel.shown_volume is volume
    assert sorted(widget._rowWidgets) == [(TISSUE, i) for i in range(4)]  # one tissue per class
    assert widget._parameterNode.tissues == widget.panel.detail_shown == 3
    widget.ui.detailSlider.setRange.assert_called_with(AUTO_DETAIL, 3)
    assert widget.ui.detailValueLabel.text == "One per class: 3 (thesis)"


def test_the_detail_regroups_and_the_tree_edits_reach_the_transfer_function(panel):
    widget, volume = panel
    widget.panel.refresh()
    widget._parameterNode.tissues = 1
    widget.panel.refresh()
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
    widget.panel.refresh()
    assert design.n_tissues == 3 and widget._parameterNode.tissues == 3
    widget._parameterNode.tissues = AUTO_DETAIL
    widget.panel.refresh()
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
    widget.panel.refresh()
    assert widget.logic.design is None and widget._rowWidgets == {}
    assert widget._parameterNode.tissues == 7
    assert widget.ui.detailSlider.enabled is False


def _apply_parameters(widget, module, volume, **values):
    widget._parameterNode = _defaults(module, inputVolume=volume, **values)
    widget.panel.set_parameters(widget._parameterNode, node=__import__("vtk").vtkObject())
    widget._pollTimer = mock.MagicMock(name="timer")


def test_apply_in_process_shows_the_design_and_cancel_changes_nothing(panel, slicer_app, module):
    widget, volume = panel
    _apply_parameters(widget, module, volume, bins=32, tissues=1)
    widget.onApplyButton()
    assert widget.logic.design.n_bins == 32 and widget.logic.design.n_tissues == 1
    assert widget._parameterNode.tissues == 1 and not widget.panel.running
    stored = mrml.design_of_volume(volume).to_dict()

    import slicer

    pressed = []

    def press_cancel():  # the user presses Cancel once, while the design runs
        if widget.panel.running and not pressed:
            pressed.append(True)
            widget.onCancelButton()

    slicer.app.processEvents.side_effect = press_cancel
    widget._parameterNode.bins = 64
    widget.onApplyButton()
    assert mrml.design_of_volume(volume).to_dict() == stored
    assert pressed and widget.ui.statusLabel.text == "Cancelled." and not widget.panel.running
    assert widget.ui.applyButton.enabled is True


def test_g2_a_second_apply_queued_while_slicer_is_busy_is_refused(panel, slicer_app, module, tmp_path, monkeypatch):
    """The job path: Apply's own processEvents (the status line, the progress bar) handles a queued second click."""
    import slicer

    widget, volume = panel
    _apply_parameters(widget, module, volume, bins=32)
    monkeypatch.setattr(widget.logic, "runs_in_process", lambda *args: False)
    monkeypatch.setattr(widget.logic, "python_executable", lambda: sys.executable)
    slicer.app.temporaryPath = str(tmp_path)
    clicks = []

    def second_click():
        if not clicks:
            clicks.append(True)
            widget.onApplyButton()

    slicer.app.processEvents.side_effect = second_click
    widget.onApplyButton()
    assert clicks and len(list(tmp_path.glob("IsoSimilarityTF-*"))) == 1
    widget._pollTimer.start.assert_called()
    widget.onCancelButton()
    assert list(tmp_path.glob("IsoSimilarityTF-*")) == [] and not widget.panel.running
    widget._pollTimer.stop.assert_called()


def test_g4_the_hand_overs_act_on_the_shown_volumes_design(panel, slicer_app, module):
    widget, volume = panel
    widget.panel.refresh()
    other = slicer_app.add_volume(nested_volume(), spacing=SPACING, name="Other")
    widget.logic.apply(other, hand_made_design())  # a script, with the widget's own logic
    before = mrml.design_of_volume(other).to_dict()
    widget.onRowOpacityChanged(TISSUE, 2, 30)
    assert mrml.design_of_volume(volume).tissues[2].opacity == pytest.approx(0.3)
    widget.logic.apply(other, hand_made_design())
    widget.onExportSegmentationButton()
    names = [n.GetName() for n in _nodes(volume.GetScene(), "vtkMRMLSegmentationNode")]
    assert len(names) == 1 and names[0].startswith("Nested")
    assert mrml.design_of_volume(other).to_dict() == before


def test_f4_a_design_applied_behind_the_panel_is_not_regrouped(module, slicer_app):
    """The self-test's order (F4): the selector auto-selects the first volume added (the panel caches it with no
    design), the design is applied without the panel being told, then the module is entered."""
    widget = module.IsoSimilarityTFWidget()
    widget.ui = mock.MagicMock(name="ui")
    widget.logic = module.IsoSimilarityTFLogic()
    volume = slicer_app.add_volume(nested_volume(), spacing=SPACING, name="Nested")
    _connect(widget, module, _ParameterNode(inputVolume=volume, tissues=AUTO_DETAIL, preference="median"))
    widget.panel.refresh()  # the selector's auto-selection writes inputVolume
    widget.logic.apply(volume, hand_made_design())
    other = slicer_app.add_volume(nested_volume(), spacing=SPACING, name="Other")
    widget.panel.refresh()  # enter()
    assert mrml.design_of_volume(volume).options["tissues"] != "auto"  # not regrouped behind the panel
    widget._parameterNode.inputVolume = other
    widget.panel.refresh()
    widget._parameterNode.inputVolume = volume
    widget.panel.refresh()
    assert sorted(widget._rowWidgets) == [(TISSUE, i) for i in range(4)]
    assert widget._parameterNode.tissues == 3


class _ComboBox:
    """A QComboBox as Slicer 5.8's combo box connector drives it: ``clear()`` selects no item (-1) and the first
    ``addItem`` selects item 0 (Qt behaviour, noted at qSlicerDataDialog.cxx:254), each change sent to the connected
    slots as ``currentIndexChanged``."""

    def __init__(self):
        self.items, self.currentIndex, self.slots = [], -1, []

    @property
    def count(self):
        return len(self.items)

    def _select(self, index):
        if index != self.currentIndex:
            self.currentIndex = index
            for slot in list(self.slots):
                slot(index)

    def clear(self):
        self.items = []
        self._select(-1)

    def addItem(self, text):
        self.items.append(text)
        if self.currentIndex == -1:
            self._select(0)

    def itemText(self, index):
        return self.items[index]

    def setItemText(self, index, text):
        self.items[index] = text

    def setItemData(self, *args):
        pass


class _ChoiceConnector:
    """Slicer v5.8.1 guiConnectors.py:355-399 (QComboBoxToStringableConnector), by index."""

    def __init__(self, widget, choices):
        self.widget, self.choices, self.callback = widget, choices, None
        widget.clear()
        for choice in choices:
            widget.addItem(str(choice))

    def _changed(self, index):
        self.callback()

    def onChanged(self, callback):
        if self.callback is not None:
            self.widget.slots.remove(self._changed)
        self.callback = callback
        if callback is not None:
            self.widget.slots.append(self._changed)

    def read(self):
        return self.choices[self.widget.currentIndex]

    def write(self, value):
        self.widget._select(self.choices.index(value))


class _Wrapper58:
    """A parameter node wrapper shaped as Slicer 5.8.1's (wrapper.py:132-260) for the choice parameters: its
    ``connectGui`` returns None, so ``disconnectGui(None)`` leaves the connectors connected; values live in the one
    (singleton) MRML node, shared by every wrapper of it."""

    def __init__(self, node, values, choices, combo_of):
        object.__setattr__(self, "parameterNode", node)
        object.__setattr__(self, "_values", values)
        object.__setattr__(self, "_choices", choices)
        object.__setattr__(self, "_combo_of", combo_of)
        object.__setattr__(self, "_parameterGUIs", {})
        object.__setattr__(self, "_nextParameterGUIsTag", 0)

    def __getattr__(self, name):
        return self._values[name]

    def __setattr__(self, name, value):
        self._values[name] = value

    def AddObserver(self, *args):
        return self.parameterNode.AddObserver(*args)

    def RemoveObserver(self, tag):
        self.parameterNode.RemoveObserver(tag)

    def connectGui(self, ui):
        connectors = {name: _ChoiceConnector(self._combo_of(ui, name), c) for name, c in self._choices.items()}
        tag = self._nextParameterGUIsTag
        object.__setattr__(self, "_nextParameterGUIsTag", tag + 1)
        self._parameterGUIs[tag] = connectors
        for name, connector in connectors.items():
            connector.write(self._values[name])
            connector.onChanged(lambda name=name, connector=connector: self.__setattr__(name, connector.read()))
        return None  # Slicer 5.8.1 wrapper.py:253: no tag

    def disconnectGui(self, tag):
        for connector in self._parameterGUIs.pop(tag, {}).values():
            connector.onChanged(None)


def test_f2_on_slicer_5_8_closing_the_scene_five_times_changes_no_choice(module, slicer_app):
    import typing

    import vtk

    hints = typing.get_type_hints(module.IsoSimilarityTFParameterNode, include_extras=True)
    choices = {name: list(hint.__metadata__[0][0]) for name, hint in hints.items()
               if hasattr(hint, "__metadata__") and hint.__origin__ is str}  # fmt: skip
    assert "modality" in choices and "crossing" in choices
    values = {name: getattr(module.IsoSimilarityTFParameterNode, name) for name in hints if name != "inputVolume"}
    values["inputVolume"] = None
    values.update(crossing="strict", modality="mr", colors="distinct")  # the user's choices, or a saved scene's
    combos = {}

    def combo_of(ui, name):
        return combos.setdefault(name, _ComboBox())

    widget = module.IsoSimilarityTFWidget()
    widget.ui = mock.MagicMock(name="ui")
    for name in choices:
        setattr(widget.ui, f"{name}ComboBox", combo_of(widget.ui, name))
    widget.logic = module.IsoSimilarityTFLogic()
    widget.panel = module.PanelModel(widget.logic, widget)
    node = vtk.vtkObject()
    before = dict(values)
    widget.setParameterNode(_Wrapper58(node, values, choices, combo_of))
    for _ in range(5):
        widget.setParameterNode(None)  # onSceneStartClose
        widget.setParameterNode(_Wrapper58(node, values, choices, combo_of))  # onSceneEndClose / enter()
    assert {name: values[name] for name in choices} == {name: before[name] for name in choices}


class _Wrapper512(_Wrapper58):
    """Slicer 5.10 and later: ``connectGui`` returns its tag (wrapper.py:253 at v5.12.3)."""

    def connectGui(self, ui):
        super().connectGui(ui)
        return max(self._parameterGUIs)


@pytest.mark.parametrize("wrapper_class", [_Wrapper58, _Wrapper512], ids=["5.8", "5.12"])
def test_g5_cleanup_leaves_no_gui_bound_to_the_parameter_node(module, slicer_app, wrapper_class):
    import vtk

    widget = module.IsoSimilarityTFWidget()
    widget.ui = mock.MagicMock(name="ui")
    widget.logic = module.IsoSimilarityTFLogic()
    widget.panel = module.PanelModel(widget.logic, widget)
    values = {name: getattr(module.IsoSimilarityTFParameterNode, name, None) for name in ("preference", "tissues")}
    wrapper = wrapper_class(vtk.vtkObject(), {**values, "inputVolume": None}, {}, lambda ui, name: None)
    widget.setParameterNode(wrapper)
    assert wrapper._parameterGUIs and wrapper.parameterNode.HasObserver("ModifiedEvent")
    widget.cleanup()  # Reload, or Slicer closing
    assert wrapper._parameterGUIs == {} and widget._parameterNode is None
    assert not wrapper.parameterNode.HasObserver("ModifiedEvent") and widget.panel.parameters is None


def test_f2_every_choice_parameter_defaults_to_its_first_choice(module):
    """A rebuilt combo box selects item 0 (Qt); a choice defaulting to another word was overwritten on Slicer 5.8."""
    import typing

    hints = typing.get_type_hints(module.IsoSimilarityTFParameterNode, include_extras=True)
    choices = {name: list(hint.__metadata__[0][0]) for name, hint in hints.items()
               if hasattr(hint, "__metadata__") and hint.__origin__ is str}  # fmt: skip
    assert len(choices) == 8
    for name, words in choices.items():
        assert words[0] == getattr(module.IsoSimilarityTFParameterNode, name), name
        assert len(set(words)) == len(words), name


def test_f7_the_detail_slider_has_no_ticks_while_no_design_is_shown(panel, module):
    widget, _ = panel
    widget.show_design(None)
    widget.ui.detailSlider.setTickPosition.assert_called_with(module.qt.QSlider.NoTicks)
    widget.panel.refresh()  # the design is shown
    widget.ui.detailSlider.setTickPosition.assert_called_with(module.qt.QSlider.TicksBelow)


def test_the_visibility_boxes_are_disabled_in_solo_mode(panel, module):
    widget, _ = panel
    module.qt.QCheckBox.side_effect = lambda *args: mock.MagicMock(name="QCheckBox")  # one per row and column
    widget.panel.refresh()
    boxes = [w["visible"] for w in widget._rowWidgets.values()]
    assert len({id(box) for box in boxes}) == len(boxes) == 4 and all(box.enabled for box in boxes)
    widget.onRowSoloToggled(TISSUE, 2, True)
    assert not any(box.enabled for box in boxes)
    widget.onShowAllButton()
    assert all(box.enabled for box in boxes)


# The panel's parameters to the engine's options -------------------------------------------------------------------
def _defaults(module, **changes):
    import typing

    cls = module.IsoSimilarityTFParameterNode
    values = {name: getattr(cls, name, None) for name in typing.get_type_hints(cls)}
    values.update(changes)
    return _ParameterNode(**values)


def _other_value(option):
    """A value of the option's entry other than its default: another word, or a number inside the bounds."""
    from IsoSimilarityTFLib.options import OPTIONS

    entry = OPTIONS[option]
    if entry.kind == "choice":
        return next(word for word in reversed(entry.choices) if word != entry.default)
    default = entry.default if entry.default is not None else entry.minimum
    step = 1 if entry.kind in ("int", "choice-or-int") else 0.125
    if isinstance(default, str):  # preference: a word; the other word
        return next(word for word in entry.choices if word != default)
    return default + step if entry.maximum is None or default + step <= entry.maximum else default - step


def test_the_defaults_of_the_panel_are_the_engines(module):
    import typing

    from IsoSimilarityTFLib.options import DEFAULT_OPTIONS
    from IsoSimilarityTFLib.panel import PANEL_OPTIONS

    fields = set(typing.get_type_hints(module.IsoSimilarityTFParameterNode))
    assert fields - {"inputVolume", "preferenceValue"} == set(PANEL_OPTIONS)  # every parameter reaches the engine
    options = module.IsoSimilarityTFLogic.designOptions(_defaults(module))
    assert set(options) == set(PANEL_OPTIONS.values()) == set(DEFAULT_OPTIONS) - {"value_range"}
    expected = {**{k: DEFAULT_OPTIONS[k] for k in options}, "tissues": AUTO_DETAIL}  # the Detail: automatic
    assert options == expected
    assert options["levels"] is None and options["modality"] is None


@pytest.mark.parametrize("parameter", sorted(__import__("IsoSimilarityTFLib.panel").panel.PANEL_OPTIONS))
def test_each_parameter_reaches_its_engine_option_and_only_it(module, parameter):
    from IsoSimilarityTFLib.panel import PANEL_OPTIONS

    option = PANEL_OPTIONS[parameter]
    base = module.IsoSimilarityTFLogic.designOptions(_defaults(module))
    value = 2 if parameter == "tissues" else _other_value(option)
    options = module.IsoSimilarityTFLogic.designOptions(_defaults(module, **{parameter: value}))
    assert options[option] == value and type(options[option]) is type(value)
    assert {k: v for k, v in options.items() if k != option} == {k: v for k, v in base.items() if k != option}


def test_the_panel_words_for_none_and_a_number(module):
    design_options = module.IsoSimilarityTFLogic.designOptions
    assert design_options(_defaults(module, levels=3))["levels"] == 3
    assert design_options(_defaults(module, modality="mr"))["modality"] == "mr"
    assert design_options(_defaults(module, preference="number", preferenceValue=-2.5))["preference"] == -2.5
    assert design_options(_defaults(module, preference="minimum", preferenceValue=-2.5))["preference"] == "minimum"
    assert design_options(_defaults(module, tissues=9))["tissues"] == 9


def test_the_summary_says_when_affinity_propagation_ran_on_the_distinct_isovalues(module):
    design = hand_made_design()
    summary = module.IsoSimilarityTFLogic.summaryText
    design.clustering.update(converged=True, n_iter=61, damping=0.5, distinct=False)
    assert "converged in 61 iterations, damping 0.5." in summary(design)
    design.clustering["distinct"] = True
    assert "converged in 61 iterations on the distinct isovalues, damping 0.5." in summary(design)


@pytest.mark.parametrize(("parameter", "value"), [("bins", 1), ("damping", 1.5), ("crossing", "both"), ("tissues", -1)])
def test_a_bad_parameter_is_refused_before_anything_runs(module, parameter, value):
    from IsoSimilarityTFLib import OptionError

    with pytest.raises(OptionError):
        module.IsoSimilarityTFLogic.designOptions(_defaults(module, **{parameter: value}))


def test_apply_designs_with_the_panels_options(panel, module):
    widget, volume = panel
    widget._parameterNode = _defaults(module, inputVolume=volume, bins=32, levels=2, modality="mr")
    widget.panel.set_parameters(widget._parameterNode, node=__import__("vtk").vtkObject())
    widget._pollTimer = mock.MagicMock(name="timer")
    widget.onApplyButton()
    design = widget.logic.design
    assert (design.n_bins, design.options["levels"], design.options["modality"]) == (32, 2, "mr")
    assert design.options["tissues"] == "auto" and widget.panel.shown_volume is volume and not widget.panel.running
    assert mrml.design_of_volume(volume).to_dict() == design.to_dict()


def test_the_look_thumbnails_show_the_patients_front_however_the_volume_is_stored(panel, module, monkeypatch):
    from IsoSimilarityTFLib.design import TransferFunctionDesign

    widget, volume = panel
    # Column c: the RAS direction of index axis c. i toward posterior, j toward the right (a sagittal series).
    stored = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    matrix = vtk.vtkMatrix4x4()
    for row, column in np.ndindex(3, 3):
        matrix.SetElement(row, column, stored[row, column])
    volume.SetIJKToRASDirectionMatrix(matrix)
    module.qt.QToolButton.side_effect = lambda *args: mock.MagicMock(name="QToolButton")
    asked = []
    original = TransferFunctionDesign.thumbnail
    monkeypatch.setattr(
        TransferFunctionDesign, "thumbnail", lambda self, *a, **kw: asked.append(kw) or original(self, *a, **kw)
    )
    widget.panel.refresh()
    widget._showLooks()
    assert asked and all(np.array_equal(kw["directions"], stored) for kw in asked)


def test_the_looks_are_drawn_after_the_tree_one_button_each(panel, module):
    widget, _ = panel
    module.qt.QToolButton.side_effect = lambda *args: mock.MagicMock(name="QToolButton")  # one per look
    widget.panel.refresh()  # the design is shown: the tree now, the looks when the timer fires
    widget._looksTimer.start.assert_called()
    widget._showLooks()  # the timer's timeout
    design = widget.logic.design
    assert list(widget._lookButtons) == [look.name for look in design.looks]
    assert [name for name, button in widget._lookButtons.items() if button.checked] == [design.chosen_look]
    other = [look.name for look in design.looks][-1]
    widget.onLookClicked(other)
    assert design.look_name == other and widget._lookButtons[other].checked
    assert not widget._lookButtons[design.looks[0].name].checked
