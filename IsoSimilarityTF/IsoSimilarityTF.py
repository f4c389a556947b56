"""IsoSimilarityTF: automatic transfer function for volume rendering (Slicer scripted module).

The module is a thin shell around ``IsoSimilarityTFLib``: the engine designs the transfer function, ``mrml`` shows it
in the volume rendering, ``pictures`` draws the similarity matrix. This file only wires them to the panel.
"""

import functools
import logging
import os
import shutil
import sys
from typing import Annotated, Optional

import ctk
import numpy as np
import qt
import slicer
import vtk
from slicer import vtkMRMLScalarVolumeNode
from slicer.i18n import tr as _
from slicer.i18n import translate
from slicer.parameterNodeWrapper import Choice, WithinRange, parameterNodeWrapper
from slicer.ScriptedLoadableModule import (
    ScriptedLoadableModule,
    ScriptedLoadableModuleLogic,
    ScriptedLoadableModuleTest,
    ScriptedLoadableModuleWidget,
)
from slicer.util import VTKObservationMixin

from IsoSimilarityTFLib.options import OPTIONS
from IsoSimilarityTFLib.panel import (
    CANCELLED,
    DONE,
    IDLE,
    RUNNING,
    RUNNING_CHILD,
    RUNNING_HERE,
    VOLUME_REMOVED,
    PanelModel,
    PanelView,
    engine_options,
    gui_tag,
)
from IsoSimilarityTFLib.session import AUTO_DETAIL, CLASS, TISSUE, DesignSession

#
# IsoSimilarityTF
#


class IsoSimilarityTF(ScriptedLoadableModule):
    """Module description shown in the module panel and the module finder."""

    def __init__(self, parent):
        ScriptedLoadableModule.__init__(self, parent)
        self.parent.title = _("Iso-Similarity Transfer Function")
        # "Rendering" is a category of the Extensions Index (ACCEPTED_EXTENSION_CATEGORIES); Slicer's own Volume
        # Rendering module sits at the top level.
        self.parent.categories = [translate("qSlicerAbstractCoreModule", "Rendering")]
        self.parent.dependencies = ["VolumeRendering", "Segmentations"]
        # No author has been recorded for the project yet: replace with "First Last (Organization)" entries.
        self.parent.contributors = ["IsoSimilarityTF maintainers"]
        self.parent.helpText = _(
            """
Designs a multi-class transfer function for volume rendering automatically, from the volume alone.
Isovalues whose isosurfaces cross the same cells of a hierarchical (octree) grid are similar; affinity propagation
groups similar isovalues into classes without being told how many, and the classes are grouped into tissues (the
Detail slider regroups them at once). Each tissue and each class gets a colour and an opacity that you can change,
hide, or show alone, without computing anything again.
See the <a href="https://github.com/isosimilaritytf/SlicerIsoSimilarityTF">project page</a> for documentation.
"""
        )
        self.parent.acknowledgementText = _(
            """
Implements the master's thesis "Efficient Generation of Transfer Function for Direct Volume Rendering", which
combines the hierarchical isovalue similarity of Ma and Entezari (IEEE TVCG 2018) with the affinity propagation of
Frey and Dueck (Science 2007).
"""
        )


#
# IsoSimilarityTFParameterNode
#

# The engine options' ranges, choices and defaults come from the one options table of the library.


def _withinRange(option: str, minimum: Optional[float] = None) -> WithinRange:
    entry = OPTIONS[option]
    return WithinRange(entry.minimum if minimum is None else minimum, entry.maximum)


def _choice(option: str, *extra: str, default: Optional[str] = None) -> Choice:
    """The option's words and the extra ones, the parameter's default first (by default the option's): a combo box
    being rebuilt selects its first item, and on Slicer 5.8 a connector left connected wrote it (Slicer#7545)."""
    first = OPTIONS[option].default if default is None else default
    words = [*OPTIONS[option].choices, *extra]
    return Choice([first, *(word for word in words if word != first)])


def _default(option: str):
    return OPTIONS[option].default


@parameterNodeWrapper
class IsoSimilarityTFParameterNode:
    """The user's choices, saved with the scene.

    inputVolume - the volume to design a transfer function for.
    bins - number of isovalue bins the volume's value range is quantized to.
    levels - number of octree levels used, coarsest first (0: all).
    crossing - when an isovalue crosses a cell: "inclusive" (min <= v <= max) or "strict" (min < v < max).
    normalization - per-level similarity: "thesis" (overlap / max count) or "ma-entezari" (the method authors').
    preference - affinity propagation preference: "median" or "minimum" affinity, or "number" (preferenceValue).
    preferenceValue - the preference when preference is "number" (affinity units, <= 0; lower gives fewer classes).
    damping - affinity propagation damping, in [0.5, 1).
    maxIterations, convergenceIterations - affinity propagation stopping rules.
    maxClasses - how many classes (largest first, background excluded) are shown at first.
    background - which class is hidden as background: "largest", "lowest" or "none".
    unconverged - what to do when affinity propagation does not converge: "raise-damping", "error" or "keep".
    tissues - the Detail slider: how the classes are grouped into tissues. 0 (the default) is the automatic count
        (the engine's tissues="auto"); n >= 1 is n tissues; a count at or above the design's number of classes is one
        tissue per class (tissues="all", the thesis). Moving it regroups the shown design at once; Apply uses it too.
    colors - tissue colours: "ramp" (intensity-ordered, as Slicer's presets) or "distinct" (a qualitative palette).
    modality - kind of volume, a hint to the look: "auto" (detected from the histogram, whatever the units; the
        engine's None), "ct" (a dense tail shown through what encloses it), "mr" or "8bit" (the outer surface).
    gradientOpacity - "off" (constant, as Slicer's presets) or "auto" (homogeneous insides fade, boundaries stay).
    """

    inputVolume: vtkMRMLScalarVolumeNode
    bins: Annotated[int, _withinRange("n_bins")] = _default("n_bins")
    levels: Annotated[int, _withinRange("levels", minimum=0)] = 0  # 0: all levels (None in the engine)
    crossing: Annotated[str, _choice("crossing")] = _default("crossing")
    normalization: Annotated[str, _choice("normalization")] = _default("normalization")
    preference: Annotated[str, _choice("preference", "number")] = _default("preference")
    preferenceValue: Annotated[float, WithinRange(-100.0, 0.0)] = -1.0
    damping: Annotated[float, _withinRange("damping")] = _default("damping")
    maxIterations: Annotated[int, _withinRange("max_iter")] = _default("max_iter")
    convergenceIterations: Annotated[int, _withinRange("convergence_iter")] = _default("convergence_iter")
    maxClasses: Annotated[int, _withinRange("max_classes")] = _default("max_classes")
    background: Annotated[str, _choice("background")] = _default("background")
    unconverged: Annotated[str, _choice("unconverged")] = _default("unconverged")
    tissues: Annotated[int, _withinRange("tissues", minimum=AUTO_DETAIL)] = AUTO_DETAIL  # AUTO_DETAIL: "auto"
    colors: Annotated[str, _choice("colors")] = _default("colors")
    modality: Annotated[str, _choice("modality", "auto", default="auto")] = "auto"  # "auto": detected (engine: None)
    gradientOpacity: Annotated[str, _choice("gradient_opacity")] = _default("gradient_opacity")


#
# IsoSimilarityTFWidget
#

# Columns of the tissue tree (headers are set in the .ui file).
COLUMN_NAME, COLUMN_COLOR, COLUMN_OPACITY, COLUMN_VISIBLE, COLUMN_SOLO, COLUMN_VOXELS, COLUMN_RANGE = range(7)

# Share of the progress bar per stage of the engine (affinity propagation reports its iterations).
STAGE_PROGRESS = {
    "quantize": (0, 5),
    "similarity": (5, 55),
    "clustering": (55, 85),
    "classes": (85, 90),
    "tissues": (90, 100),
}

# How often the panel reads the progress of the design process, in milliseconds.
POLL_INTERVAL_MS = 100

# Side of the similarity picture in the panel, in pixels (a multiple of 4: Qt image rows are 4-byte aligned).
SIMILARITY_PICTURE_SIZE = 256

# Side of a look's thumbnail on its button, in pixels (a multiple of 4), and buttons per row of the looks.
LOOK_THUMBNAIL_SIZE = 64
LOOKS_PER_ROW = 3


def choiceLabels() -> dict:
    """Readable, translatable labels of the choice parameters' values, by parameter and value.

    The parameter node keeps the values themselves (scenes stay readable by every version); the combo boxes show
    these labels (the wrapper's combo box connector reads and writes by index, not by text).
    """
    return {
        "crossing": {
            "inclusive": _("Inclusive: min <= value <= max (thesis)"),
            "strict": _("Strict: min < value < max (Ma and Entezari's code)"),
        },
        "normalization": {
            "thesis": _("Thesis: overlap / larger count"),
            "ma-entezari": _("Ma and Entezari: overlap / count, then the smaller"),
        },
        "preference": {
            "median": _("Median similarity"),
            "minimum": _("Minimum similarity (fewer classes)"),
            "number": _("Value below"),
        },
        "background": {
            "largest": _("Largest class"),
            "lowest": _("Lowest intensity class"),
            "none": _("None (show every class)"),
        },
        "unconverged": {
            "raise-damping": _("Retry with more damping"),
            "error": _("Stop with an error"),
            "keep": _("Keep the last grouping"),
        },
        "colors": {
            "ramp": _("Intensity ramp (as Slicer's presets)"),
            "distinct": _("Distinct colours"),
        },
        "modality": {
            "auto": _("Detect from the data"),
            "ct": _("CT (Hounsfield units)"),
            "mr": _("MRI or other scalars"),
            "8bit": _("8-bit data"),
        },
        "gradientOpacity": {
            "off": _("Off (as Slicer's presets)"),
            "auto": _("Automatic (fade homogeneous insides)"),
        },
    }


class IsoSimilarityTFWidget(ScriptedLoadableModuleWidget, VTKObservationMixin, PanelView):
    """The module panel: Qt widgets bound to the parameter node and to the panel's state (``self.panel``, a
    ``IsoSimilarityTFLib.panel.PanelModel``, which follows the scene and asks this widget, its view, to draw)."""

    def __init__(self, parent=None) -> None:
        ScriptedLoadableModuleWidget.__init__(self, parent)
        VTKObservationMixin.__init__(self)
        self.logic = None
        self._parameterNode = None
        self._parameterNodeGuiTag = None
        self._pollTimer = None
        self._looksTimer = None
        self.panel = None
        # The tree's editing widgets by (level, id) of their row, and the looks' buttons by name.
        self._rowWidgets = {}
        self._lookButtons = {}

    def setup(self) -> None:
        ScriptedLoadableModuleWidget.setup(self)

        uiWidget = slicer.util.loadUI(self.resourcePath("UI/IsoSimilarityTF.ui"))
        self.layout.addWidget(uiWidget)
        self.ui = slicer.util.childWidgetVariables(uiWidget)
        # The .ui connects the root qMRMLWidget's mrmlSceneChanged signal to the node selector's setMRMLScene slot.
        uiWidget.setMRMLScene(slicer.mrmlScene)

        self.logic = IsoSimilarityTFLogic()
        self.panel = PanelModel(self.logic, self)
        self.panel.observe_scene(slicer.mrmlScene)

        # The looks are drawn once the tree is (their thumbnails take about 30-80 ms): a Detail slider dragged over
        # several settings regroups at each and draws the looks of the last one only.
        self._looksTimer = qt.QTimer()
        self._looksTimer.setSingleShot(True)
        self._looksTimer.setInterval(0)
        self._looksTimer.connect("timeout()", self._showLooks)

        self._pollTimer = qt.QTimer()
        self._pollTimer.setInterval(POLL_INTERVAL_MS)
        self._pollTimer.connect("timeout()", self._pollJob)
        self._observeSelectionNode()

        self.ui.inputSelector.connect("nodeActivated(vtkMRMLNode*)", self.onInputVolumeActivated)
        self.ui.applyButton.connect("clicked(bool)", self.onApplyButton)
        self.ui.cancelButton.connect("clicked(bool)", self.onCancelButton)
        self.ui.resetColorsButton.connect("clicked(bool)", self.onResetColorsButton)
        self.ui.showAllButton.connect("clicked(bool)", self.onShowAllButton)
        self.ui.exportButton.connect("clicked(bool)", self.onExportButton)
        self.ui.exportSegmentationButton.connect("clicked(bool)", self.onExportSegmentationButton)
        self.ui.savePresetButton.connect("clicked(bool)", self.onSavePresetButton)

        self.ui.progressBar.hide()
        self.ui.cancelButton.hide()
        self.ui.statusLabel.text = ""
        header = self.ui.tissuesTreeWidget.header()
        header.setSectionResizeMode(qt.QHeaderView.ResizeToContents)
        header.setStretchLastSection(True)
        self.show_design(None)

        self.initializeParameterNode()

    def cleanup(self) -> None:
        """The widget is deleted (Slicer closes, or Reload): stop a design, and let go of the scene and of the
        parameter node (on Slicer 5.8 and 5.10 only ``disconnectGui`` removes the wrapper's GUI observer)."""
        for timer in (self._pollTimer, self._looksTimer):
            if timer is not None:
                timer.stop()
        self.panel.stop()
        self.setParameterNode(None)
        self.removeObservers()

    def enter(self) -> None:
        self.initializeParameterNode()

    def exit(self) -> None:
        # The GUI stays connected to the parameter node (see setParameterNode); nothing to undo here.
        pass

    def onReload(self) -> None:
        """Reload the library too: Slicer's reload executes only this file, and would keep the old
        IsoSimilarityTFLib modules of sys.modules."""
        for name in list(sys.modules):
            if name == "IsoSimilarityTFLib" or name.startswith("IsoSimilarityTFLib."):
                del sys.modules[name]
        ScriptedLoadableModuleWidget.onReload(self)

    def scene_closing(self) -> None:
        self.setParameterNode(None)

    def scene_closed(self) -> None:
        self._observeSelectionNode()
        if self.parent.isEntered:
            self.initializeParameterNode()

    # Parameter node --------------------------------------------------------------------------------------------------
    def initializeParameterNode(self) -> None:
        self.setParameterNode(self.logic.getParameterNode())
        self.panel.select_active_volume()
        self.panel.refresh()

    def setParameterNode(self, inputParameterNode: Optional[IsoSimilarityTFParameterNode]) -> None:
        """Connect the panel to a parameter node, once per MRML node.

        Re-entering the module gives a new wrapper of the same MRML node: it is not reconnected. On Slicer 5.8
        ``connectGui`` returns no tag (``gui_tag`` finds it), else ``disconnectGui`` could not undo the connection and
        each new one, after a scene close, would make the old connectors write their first choice (Slicer#7545).
        """
        if (
            inputParameterNode is not None
            and self._parameterNode is not None
            and inputParameterNode.parameterNode is self._parameterNode.parameterNode
        ):
            return
        if self._parameterNode:
            if self._parameterNodeGuiTag is not None:
                self._parameterNode.disconnectGui(self._parameterNodeGuiTag)
            self._parameterNodeGuiTag = None
        self._parameterNode = inputParameterNode
        self.panel.set_parameters(inputParameterNode)
        if self._parameterNode:
            # Widgets with a "SlicerParameterName" dynamic property in the .ui are bound to the parameter of that name.
            self._parameterNodeGuiTag = gui_tag(self._parameterNode, self._parameterNode.connectGui(self.ui))
            self._labelChoiceComboBoxes()
            self.panel.refresh()

    def _labelChoiceComboBoxes(self) -> None:
        """Show readable labels instead of the parameter values the connector put in the combo boxes."""
        comboBoxes = {
            "crossing": self.ui.crossingComboBox,
            "normalization": self.ui.normalizationComboBox,
            "preference": self.ui.preferenceComboBox,
            "background": self.ui.backgroundComboBox,
            "unconverged": self.ui.unconvergedComboBox,
            "colors": self.ui.colorsComboBox,
            "modality": self.ui.modalityComboBox,
            "gradientOpacity": self.ui.gradientOpacityComboBox,
        }
        for parameter, labels in choiceLabels().items():
            comboBox = comboBoxes[parameter]
            for index in range(comboBox.count):
                value = comboBox.itemText(index)
                if value in labels:
                    comboBox.setItemText(index, labels[value])
                    comboBox.setItemData(index, value, qt.Qt.ToolTipRole)

    def show_parameters(self) -> None:
        """The parameter node changed: enable what depends on it."""
        volume = self._parameterNode.inputVolume if self._parameterNode else None
        self.ui.applyButton.enabled = volume is not None
        self.ui.applyButton.toolTip = (
            _("Design a transfer function for the input volume and show it in the 3D view")
            if volume
            else _("Select an input volume")
        )
        self.ui.preferenceValueSpinBox.enabled = bool(
            self._parameterNode and self._parameterNode.preference == "number"
        )

    @staticmethod
    def outsideChangeText() -> str:
        return _(
            "The 3D view shows another transfer function than this design (changed in the Volume Rendering "
            "module). Editing a class or choosing a look shows the design again, after asking."
        )

    def show_outside_change(self, change: Optional[str]) -> None:
        """The status follows the 3D view: said when it shows another transfer function, gone when it no longer
        does."""
        if change is not None:
            self.ui.statusLabel.text = self.outsideChangeText()
        elif self.ui.statusLabel.text == self.outsideChangeText():
            self.ui.statusLabel.text = ""

    # Active volume ---------------------------------------------------------------------------------------------------
    def _observeSelectionNode(self) -> None:
        appLogic = slicer.app.applicationLogic()
        self.panel.observe_selection(appLogic.GetSelectionNode() if appLogic else None)

    def onInputVolumeActivated(self, node) -> None:
        """The user picked a volume in the selector: stop following the active volume unless they picked it."""
        self.panel.volume_picked(node)

    # Apply. A design expected to take less than about a second runs here, on the main thread, repainting and
    # checking Cancel at each progress report (between affinity propagation's iterations too); a longer one runs in a
    # child process, polled by a timer, so Slicer stays responsive and Cancel is at once (the process costs a few
    # tenths of a second to start: see IsoSimilarityTFLib.session). The panel's state decides; it refuses a second
    # Apply while one runs (a click queued while Slicer was busy).
    def onApplyButton(self) -> None:
        outcome = None
        try:
            with slicer.util.tryWithErrorDisplay(_("Failed to compute the transfer function."), waitCursor=True):
                outcome = self.panel.apply(self._showProgress)
        finally:
            if self.panel.apply_state == RUNNING_CHILD:
                self._pollTimer.start()
        if outcome == DONE:
            self._logResult(self.logic.design)
        elif outcome == CANCELLED:
            self.addLog(_("Cancelled."))
        elif outcome == VOLUME_REMOVED:
            self.addLog(_("The input volume was removed from the scene."))

    def _showProgress(self, stage: str, fraction: float, message: str) -> None:
        low, high = STAGE_PROGRESS.get(stage, (0, 100))
        self.ui.progressBar.value = round(low + (high - low) * min(max(fraction, 0.0), 1.0))
        self.ui.progressBar.setFormat(f"{message} (%p%)")
        slicer.app.processEvents()  # repaint, and let Cancel be pressed

    def _logResult(self, design) -> None:
        summary = self.logic.summaryText(design)
        if self.logic.range_warning:
            summary += " " + _("Note: {warning}.").format(warning=self.logic.range_warning)
        self.addLog(summary)
        name = self.logic.volume_node.GetName() if self.logic.volume_node is not None else ""
        logging.info(f"IsoSimilarityTF timings for {name}: {self.logic.timingsText(design)}")

    def _pollJob(self) -> None:
        outcome = RUNNING
        try:
            with slicer.util.tryWithErrorDisplay(_("Failed to compute the transfer function."), waitCursor=True):
                reports, outcome = self.panel.poll_job()
                for report in reports:
                    self._showProgress(*report)
                if outcome == VOLUME_REMOVED:
                    raise RuntimeError(_("The input volume was removed from the scene."))
                if outcome == DONE:
                    self._logResult(self.logic.design)
        finally:
            if self.panel.apply_state != RUNNING_CHILD:  # done, failed, removed or cancelled
                self._pollTimer.stop()

    def onCancelButton(self) -> None:
        """A child process ends at once; a design here stops at its next progress report, which then says so."""
        child = self.panel.apply_state == RUNNING_CHILD
        self.panel.cancel()
        if child:
            self._pollTimer.stop()
            self.addLog(_("Cancelled."))

    def show_apply_state(self, state: str, volume) -> None:
        running = state != IDLE
        self.ui.progressBar.value = 0
        self.ui.progressBar.setFormat("%p%")
        self.ui.progressBar.visible = running
        self.ui.cancelButton.visible = running
        self.ui.cancelButton.enabled = state in (RUNNING_HERE, RUNNING_CHILD)
        for widget in (
            self.ui.applyButton,
            self.ui.inputSelector,
            self.ui.advancedCollapsibleButton,
            self.ui.looksCollapsibleButton,
            self.ui.tissuesCollapsibleButton,
        ):
            widget.enabled = not running
        if state in (RUNNING_HERE, RUNNING_CHILD):
            # The progress bar shows before the volume is written for the design process (a large one takes a
            # while); the panel's state is set already, so a click handled here cannot start a second Apply.
            self.addLog(_("Designing a transfer function for {name}...").format(name=volume.GetName()))

    def addLog(self, text: str) -> None:
        """Show a message under the Apply button."""
        self.ui.statusLabel.text = text
        slicer.app.processEvents()

    # Looks -----------------------------------------------------------------------------------------------------------
    def _showLooks(self) -> None:
        """One button per look of the shown design's gallery (made per grouping), with its thumbnail and promise."""
        from IsoSimilarityTFLib import mrml

        design = self.panel.detail_design()
        layout = self.ui.looksButtonsWidget.layout()
        for button in self._lookButtons.values():
            layout.removeWidget(button)
            button.deleteLater()
        self._lookButtons = {}
        if design is None:
            self.ui.looksLabel.text = _("Press Apply to see the looks the data support.")
            return
        looks = design.looks
        self.ui.looksLabel.text = _("{count} looks made from these classes; the first is the first click's.").format(
            count=len(looks)
        )
        chosen = self.panel.look()
        directions = mrml.ijk_to_ras_directions(self.panel.shown_volume)  # the patient's front, however stored
        for index, look in enumerate(looks):
            button = qt.QToolButton()
            button.text = look.title
            button.checkable = True
            button.toolButtonStyle = qt.Qt.ToolButtonTextUnderIcon
            button.toolTip = look.objective
            thumbnail = design.thumbnail(look, size=LOOK_THUMBNAIL_SIZE, directions=directions)
            button.setIcon(qt.QIcon(self._pixmapFromArray(thumbnail)))
            button.setIconSize(qt.QSize(LOOK_THUMBNAIL_SIZE, LOOK_THUMBNAIL_SIZE))
            button.connect("clicked(bool)", functools.partial(self.onLookClicked, look.name))
            layout.addWidget(button, index // LOOKS_PER_ROW, index % LOOKS_PER_ROW)
            self._lookButtons[look.name] = button
        self.show_look(chosen)

    def show_look(self, name: Optional[str]) -> None:
        for lookName, button in self._lookButtons.items():
            button.checked = lookName == name

    def onLookClicked(self, name: str, checked: bool = False) -> None:
        self.panel.use_look(name)

    # Tissue tree ---------------------------------------------------------------------------------------------------
    def show_design(self, design) -> None:
        """Show a design (or nothing) in the tissue tree, the Detail slider, the similarity picture and the timings."""
        self._showDetailRange(design)
        self.show_tree(design)
        self._showSimilarityPicture(design)
        self.ui.timingsLabel.text = self.logic.timingsText(design) if design is not None else ""
        self.ui.looksCollapsibleButton.enabled = design is not None
        for button in (
            self.ui.resetColorsButton,
            self.ui.showAllButton,
            self.ui.exportButton,
            self.ui.exportSegmentationButton,
            self.ui.savePresetButton,
        ):
            button.enabled = design is not None

    def _showDetailRange(self, design) -> None:
        """The Detail slider's range: the design's (automatic, 1 tissue ... one per class), set before the panel's
        state writes the design's grouping into the parameter node, so the slider never clamps it."""
        slider = self.ui.detailSlider
        slider.enabled = design is not None
        slider.blockSignals(True)
        if design is None:
            # Any saved value fits: the slider must not clamp the parameter while no design is shown. No ticks: over
            # this range (pageStep 1) they would draw as a solid bar.
            slider.setRange(AUTO_DETAIL, int(OPTIONS["tissues"].maximum))
            slider.setTickPosition(qt.QSlider.NoTicks)
        else:
            slider.setRange(AUTO_DETAIL, self.logic.detail_range()[1])
            slider.setTickPosition(qt.QSlider.TicksBelow)
        slider.blockSignals(False)
        self.show_detail_label()

    def show_detail_label(self) -> None:
        self.ui.detailValueLabel.text = self.detailText(self.panel.detail(), self.panel.detail_design())

    @staticmethod
    def detailText(detail: int, design) -> str:
        """What a Detail setting means, for the label beside the slider."""
        if design is None:
            if detail == AUTO_DETAIL:
                return _("Automatic")
            return _("1 tissue") if detail == 1 else _("{count} tissues").format(count=detail)
        count = design.n_tissues
        if detail == AUTO_DETAIL:
            return _("Automatic: 1 tissue") if count == 1 else _("Automatic: {count} tissues").format(count=count)
        if detail >= design.hierarchy.max_tissues:
            return _("One per class: {count} (thesis)").format(count=count)
        return _("1 tissue") if count == 1 else _("{count} tissues").format(count=count)

    def show_tree(self, design) -> None:
        self._looksTimer.start()
        tree = self.ui.tissuesTreeWidget
        tree.clear()  # deletes the items and their widgets
        self._rowWidgets = {}
        if design is None:
            self.ui.tissuesCollapsibleButton.text = _("Tissues")
            return
        for row in self.logic.rows():
            item = self._addRow(tree, None, row)
            for child in row.children:
                self._addRow(tree, item, child)
        self.ui.tissuesCollapsibleButton.text = _("Tissues ({tissues} tissues, {classes} classes)").format(
            tissues=design.n_tissues, classes=len(design.classes)
        )
        self.show_rows()

    def rowName(self, row) -> str:
        """The name shown in the tree (numbers from 1, as in the segment names)."""
        if row.level == TISSUE:
            if row.background:
                return _("Background")
            if not row.children:  # one class: the tissue is that class
                return _("Tissue {id} (class {classId})").format(id=row.id + 1, classId=row.classes[0] + 1)
            return _("Tissue {id}").format(id=row.id + 1)
        return _("Class {id}").format(id=row.id + 1)

    def _addRow(self, tree, parentItem, row):
        """One item of the tree: a tissue (top level) or a class (inside its tissue), with its editing widgets."""
        item = qt.QTreeWidgetItem()
        if parentItem is None:  # the tree, or the tissue's item, owns the item (and then the widgets set on it)
            tree.addTopLevelItem(item)
        else:
            parentItem.addChild(item)
        item.setText(COLUMN_NAME, self.rowName(row))
        if row.level == TISSUE:
            item.setToolTip(
                COLUMN_NAME,
                _("Classes {ids}; an edit here changes all of them").format(
                    ids=", ".join(str(c + 1) for c in row.classes)
                ),
            )
        else:
            isoClass = self.logic.design.classes[row.id]
            item.setToolTip(
                COLUMN_NAME,
                _("Class {id}: rank {rank} by voxel count; exemplar isovalue bin {exemplar}").format(
                    id=row.id + 1, rank=isoClass.rank, exemplar=isoClass.exemplar_bin
                ),
            )
        item.setText(COLUMN_VOXELS, f"{100.0 * row.fraction:.2f} %")
        item.setTextAlignment(COLUMN_VOXELS, qt.Qt.AlignRight | qt.Qt.AlignVCenter)
        item.setToolTip(COLUMN_VOXELS, _("{voxels} voxels").format(voxels=row.voxels))
        ranges = "; ".join(f"{low:.6g} to {high:.6g}" for low, high in row.value_ranges)
        item.setText(COLUMN_RANGE, ranges)
        item.setToolTip(COLUMN_RANGE, _("Intensity range(s), in the volume's units: {ranges}").format(ranges=ranges))

        tissue = row.level == TISSUE
        colorButton = ctk.ctkColorPickerButton()
        colorButton.displayColorName = False
        colorButton.toolTip = _("Colour of the tissue (all its classes)") if tissue else _("Colour of the class")
        colorButton.connect("colorChanged(QColor)", functools.partial(self.onRowColorChanged, row.level, row.id))
        tree.setItemWidget(item, COLUMN_COLOR, colorButton)

        opacitySlider = qt.QSlider(qt.Qt.Horizontal)
        opacitySlider.setRange(0, 100)
        opacitySlider.setMinimumWidth(80)
        opacitySlider.connect("valueChanged(int)", functools.partial(self.onRowOpacityChanged, row.level, row.id))
        tree.setItemWidget(item, COLUMN_OPACITY, opacitySlider)

        visibleCheckBox = qt.QCheckBox()
        visibleCheckBox.toolTip = _("Show this tissue (all its classes)") if tissue else _("Show this class")
        # stateChanged, not toggled: from partly shown (a tissue some of whose classes are hidden) to shown, the
        # checked property stays true.
        visibleCheckBox.connect("stateChanged(int)", functools.partial(self.onRowVisibleChanged, row.level, row.id))
        tree.setItemWidget(item, COLUMN_VISIBLE, visibleCheckBox)

        soloCheckBox = qt.QCheckBox()
        soloCheckBox.toolTip = _("Show this tissue alone") if tissue else _("Show this class alone")
        soloCheckBox.connect("toggled(bool)", functools.partial(self.onRowSoloToggled, row.level, row.id))
        tree.setItemWidget(item, COLUMN_SOLO, soloCheckBox)

        self._rowWidgets[(row.level, row.id)] = {
            "item": item,
            "color": colorButton,
            "opacity": opacitySlider,
            "visible": visibleCheckBox,
            "solo": soloCheckBox,
        }
        return item

    def show_rows(self) -> None:
        """Set the tree's widgets from the shown design, without sending edits back."""
        design = self.panel.detail_design()
        if design is None:
            return
        soloMode = design.solo_class is not None or design.solo_tissue_id is not None
        rows = self.logic.rows()
        for row in [*rows, *(child for r in rows for child in r.children)]:
            widgets = self._rowWidgets.get((row.level, row.id))
            if widgets is None:
                continue
            editors = [widgets[key] for key in ("color", "opacity", "visible", "solo")]
            for widget in editors:
                widget.blockSignals(True)
            widgets["color"].color = qt.QColor.fromRgbF(*row.color)
            widgets["opacity"].value = round(100 * row.opacity)
            widgets["opacity"].toolTip = _("Opacity: {percent} % per mm").format(percent=round(100 * row.opacity))
            visible = widgets["visible"]
            visible.setTristate(row.visible is None)
            visible.setCheckState(
                qt.Qt.PartiallyChecked if row.visible is None else (qt.Qt.Checked if row.visible else qt.Qt.Unchecked)
            )
            visible.enabled = not soloMode
            widgets["solo"].checked = row.solo
            for widget in editors:
                widget.blockSignals(False)
            # What the 3D view does not show is greyed out.
            brush = qt.QBrush(self.ui.tissuesTreeWidget.palette.color(qt.QPalette.Disabled, qt.QPalette.Text))
            for column in (COLUMN_NAME, COLUMN_VOXELS, COLUMN_RANGE):
                widgets["item"].setForeground(column, qt.QBrush() if row.shown else brush)

    def confirm_overwrite(self, change: str) -> bool:
        """Before an edit: the shown transfer function is no longer the design's; ask before replacing it."""
        from IsoSimilarityTFLib import mrml

        volumeName = self.logic.volume_node.GetName() if self.logic.volume_node else ""
        if change == mrml.CHANGE_OTHER_NODE:
            reason = _("The Volume Rendering module shows another property node for {volume}.")
        else:
            reason = _(
                "The transfer function of {volume} was changed outside this module (a Volume Rendering preset, "
                "Shift, or Synchronize with Volumes)."
            )
        return slicer.util.confirmYesNoDisplay(
            reason.format(volume=volumeName)
            + "\n\n"
            + _("Show this module's design again, with your change? The other transfer function is replaced."),
            windowTitle=_("Transfer function changed"),
        )

    def attempt(self, what: str, action) -> None:
        if what == "regroup":
            message = _("Failed to regroup the classes.")
        else:
            message = _("Failed to update the transfer function.")
        with slicer.util.tryWithErrorDisplay(message):
            action()

    def _edit(self, edit) -> None:
        """Apply one edit through the logic (which rewrites the transfer function in place) and refresh the panel."""
        self.panel.edit(edit)

    def onRowColorChanged(self, level: str, itemId: int, color) -> None:
        self._edit(lambda: self.logic.edit(level, itemId, color=(color.redF(), color.greenF(), color.blueF())))
        self._showSimilarityPicture(self.panel.detail_design())

    def onRowOpacityChanged(self, level: str, itemId: int, value: int) -> None:
        self._edit(lambda: self.logic.edit(level, itemId, opacity=value / 100.0))

    def onRowVisibleChanged(self, level: str, itemId: int, state: int) -> None:
        # Partly checked is reachable only from "partly shown", so any state but unchecked means shown.
        self._edit(lambda: self.logic.edit(level, itemId, visible=state != qt.Qt.Unchecked))

    def onRowSoloToggled(self, level: str, itemId: int, checked: bool) -> None:
        self._edit(lambda: self.logic.solo(level, itemId if checked else None))

    def onResetColorsButton(self) -> None:
        self._edit(self.logic.reset_colors)
        self._showSimilarityPicture(self.panel.detail_design())

    def onShowAllButton(self) -> None:
        self._edit(self.logic.show_all_classes)

    # Handing the design over -----------------------------------------------------------------------------------------
    def onExportButton(self) -> None:
        self.panel.hand_over(self._exportTransferFunction)

    def _exportTransferFunction(self) -> None:
        volume = self.logic.volume_node
        extension = self.logic.defaultExportExtension()
        fileName = (volume.GetName() if volume else "TransferFunction") + extension
        filters = [_("Slicer volume property (*.vp.json)"), _("Legacy Slicer volume property (*.vp)")]
        if extension == ".vp":  # Slicer 5.8 reads only .vp
            filters.reverse()
        path = qt.QFileDialog.getSaveFileName(
            self.parent,
            _("Export transfer function"),
            os.path.join(slicer.app.defaultScenePath, fileName),
            ";;".join(filters),
        )
        if not path:
            return
        with slicer.util.tryWithErrorDisplay(_("Failed to export the transfer function."), waitCursor=True):
            written = self.logic.export_transfer_function(path, extension)
            self.addLog(_("Transfer function written to {path}").format(path=written))

    def onExportSegmentationButton(self) -> None:
        self.panel.hand_over(self._exportSegmentation)

    def _exportSegmentation(self) -> None:
        with slicer.util.tryWithErrorDisplay(_("Failed to export the classes to a segmentation."), waitCursor=True):
            segmentationNode = self.logic.export_segmentation()
            count = segmentationNode.GetSegmentation().GetNumberOfSegments()
            self.addLog(
                _("Segmentation {name} created with {count} segments.").format(
                    name=segmentationNode.GetName(), count=count
                )
            )

    def onSavePresetButton(self) -> None:
        self.panel.hand_over(self._savePreset)

    def _savePreset(self) -> None:
        volume = self.logic.volume_node
        name = qt.QInputDialog.getText(
            self.parent,
            _("Save as preset"),
            _("Name of the preset in the Volume Rendering module:"),
            qt.QLineEdit.Normal,
            _("{volume} classes").format(volume=volume.GetName() if volume else "IsoSimilarityTF"),
        )
        if not name or not name.strip():
            return
        with slicer.util.tryWithErrorDisplay(_("Failed to add the preset."), waitCursor=True):
            self.logic.add_preset(name)
            self.addLog(_("Preset {name} added to the Volume Rendering module.").format(name=name.strip()))

    # Similarity picture ----------------------------------------------------------------------------------------------
    def _showSimilarityPicture(self, design) -> None:
        label = self.ui.similarityImageLabel
        picture = self.logic.similarityImage(design, SIMILARITY_PICTURE_SIZE) if design is not None else None
        if picture is None:
            label.setPixmap(qt.QPixmap())
            label.text = (
                _("The similarity matrix is not kept with the scene: press Apply to see it again.")
                if design is not None
                else _("Press Apply to design a transfer function.")
            )
            return
        label.text = ""
        label.setPixmap(self._pixmapFromArray(picture))

    @staticmethod
    def _pixmapFromArray(rgb: np.ndarray):
        """QPixmap of an (H, W, 3) uint8 array whose width is a multiple of 4 (through vtkImageData)."""
        from vtk.util import numpy_support

        height, width = rgb.shape[:2]
        imageData = vtk.vtkImageData()
        imageData.SetDimensions(width, height, 1)
        # VTK images start at the bottom row; the conversion mirrors them into Qt's top-down order.
        scalars = numpy_support.numpy_to_vtk(
            np.ascontiguousarray(rgb[::-1]).reshape(-1, 3), deep=True, array_type=vtk.VTK_UNSIGNED_CHAR
        )
        imageData.GetPointData().SetScalars(scalars)
        image = qt.QImage()
        slicer.qMRMLUtils().vtkImageDataToQImage(imageData, image)
        return qt.QPixmap.fromImage(image)


#
# IsoSimilarityTFLogic
#


class IsoSimilarityTFLogic(ScriptedLoadableModuleLogic, DesignSession):
    """Runs the engine on a volume node and keeps its design in sync with the volume rendering.

    The work is done by ``IsoSimilarityTFLib.session.DesignSession`` (Qt-free, also tested headless); this class
    adds the parameter node and the texts of the panel. Usable without the widget::

        logic = IsoSimilarityTFLogic()
        design = logic.run(volumeNode, {"n_bins": 256})     # or start() / finish() to compute in a child process
        logic.set_class_opacity(design.classes[-1].id, 1.0)   # rewrites the transfer function in place
        logic.export_transfer_function("/tmp/tf.vp.json")
        logic.regroup(2)                                      # two tissues, at once
        logic.export_segmentation()                           # one segment per shown tissue
    """

    def __init__(self) -> None:
        ScriptedLoadableModuleLogic.__init__(self)
        DesignSession.__init__(self)

    def getParameterNode(self):
        return IsoSimilarityTFParameterNode(super().getParameterNode())

    def volume_rendering_logic(self):
        return slicer.modules.volumerendering.logic()

    def python_executable(self) -> str:
        """Slicer's own Python, for the design process (as slicer.util._executePythonModule finds it)."""
        executable = shutil.which("PythonSlicer")
        if not executable:
            raise RuntimeError(_("The PythonSlicer executable was not found: cannot start the computation."))
        return executable

    def temporary_folder(self) -> str:
        """The temporary folder chosen in Slicer's settings, for the volume the design process reads."""
        return slicer.app.temporaryPath

    @staticmethod
    def defaultExportExtension() -> str:
        """``.vp.json`` where this Slicer can read it (5.10 and later), else the legacy ``.vp`` (Slicer 5.8)."""
        return DesignSession.default_export_extension(hasattr(slicer, "vtkMRMLVolumePropertyJsonStorageNode"))

    # Running ---------------------------------------------------------------------------------------------------------
    @staticmethod
    def designOptions(parameterNode) -> dict:
        """The engine's options (``design_transfer_function`` keywords) from the parameter node, checked."""
        return engine_options(parameterNode)

    # Reports ---------------------------------------------------------------------------------------------------------
    @staticmethod
    def similarityImage(design, size: Optional[int] = None) -> Optional[np.ndarray]:
        """(H, W, 3) uint8 picture of the design's similarity matrix with its classes, or None if it has none."""
        if design is None or design.similarity is None:
            return None
        from IsoSimilarityTFLib.pictures import similarity_image

        return similarity_image(design.similarity, design.labels, design.class_colors, size=size)

    @staticmethod
    def timingsText(design) -> str:
        """Seconds per stage of the run that made the design, and the total."""
        timings = dict(design.timings_s) if design is not None else {}
        if not timings:
            return ""
        parts = [f"{stage} {seconds:.2f} s" for stage, seconds in timings.items()]
        return _("Last run: {stages}; total {total:.2f} s").format(stages=", ".join(parts), total=sum(timings.values()))

    @staticmethod
    def summaryText(design) -> str:
        clustering = design.clustering
        shown = sum(1 for c in design.classes if design.is_shown(c.id))
        if clustering.get("converged", True):
            convergence = _("converged in {n} iterations").format(n=clustering.get("n_iter", "?"))
        else:
            convergence = _("did not converge ({n} iterations)").format(n=clustering.get("n_iter", "?"))
        if clustering.get("distinct"):  # the retry on the distinct isovalues (a volume of few values) was kept
            convergence = _("{convergence} on the distinct isovalues").format(convergence=convergence)
        return _(
            "{count} classes ({shown} shown) in {tissues} tissues; affinity propagation {convergence}, "
            "damping {damping}."
        ).format(
            count=len(design.classes),
            shown=shown,
            tissues=design.n_tissues,
            convergence=convergence,
            damping=clustering.get("damping", "?"),
        )


#
# IsoSimilarityTFTest
#


class IsoSimilarityTFTest(ScriptedLoadableModuleTest):
    """Tests of the module, on volumes built in memory (nothing is downloaded).

    The logic checks are the Qt-free functions of IsoSimilarityTFLib.selftest, which ``make test`` also runs on a
    headless slicer-core scene; here they run in Slicer with this module's logic.
    """

    def setUp(self):
        slicer.mrmlScene.Clear()

    def runTest(self):
        """Run every test_* method, each on a clean scene."""
        for test in (
            self.test_IsoSimilarityTF_options,
            self.test_IsoSimilarityTF_similarity_picture,
            self.test_IsoSimilarityTF_edit_and_export,
            self.test_IsoSimilarityTF_restore,
            self.test_IsoSimilarityTF_outside_changes,
            self.test_IsoSimilarityTF_segments_and_preset,
            self.test_IsoSimilarityTF_tissues,
            self.test_IsoSimilarityTF_run,
            self.test_IsoSimilarityTF_cancel,
            self.test_IsoSimilarityTF_panel,
            self.test_IsoSimilarityTF_widget,
        ):
            self.setUp()
            test()

    # Helpers -----------------------------------------------------------------------------------------------------
    @staticmethod
    def _addVolume(values, spacing, name):
        volumeNode = slicer.util.addVolumeFromArray(values, name=name)
        volumeNode.SetSpacing(*spacing)
        return volumeNode

    def _check(self, name: str) -> None:
        """Run one check of IsoSimilarityTFLib.selftest with this module's logic."""
        from IsoSimilarityTFLib import selftest

        selftest.CHECKS[name](IsoSimilarityTFLogic, self._addVolume)

    # Tests -------------------------------------------------------------------------------------------------------
    def test_IsoSimilarityTF_options(self):
        self.delayDisplay("Parameter node to engine options")
        logic = IsoSimilarityTFLogic()
        parameterNode = logic.getParameterNode()
        options = logic.designOptions(parameterNode)
        from IsoSimilarityTFLib.options import DEFAULT_OPTIONS

        self.assertTrue(set(options) <= set(DEFAULT_OPTIONS))
        for key in ("n_bins", "crossing", "normalization", "preference", "damping", "max_iter", "convergence_iter"):
            self.assertEqual(options[key], DEFAULT_OPTIONS[key], key)
        self.assertIsNone(options["levels"])
        parameterNode.levels = 3
        parameterNode.preference = "number"
        parameterNode.preferenceValue = -2.5
        options = logic.designOptions(parameterNode)
        self.assertEqual(options["levels"], 3)
        self.assertEqual(options["preference"], -2.5)
        with self.assertRaises(ValueError):  # the wrapper validates every write
            parameterNode.levels = OPTIONS["levels"].maximum + 1
        self.assertIn(logic.defaultExportExtension(), (".vp", ".vp.json"))
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_similarity_picture(self):
        self.delayDisplay("Similarity picture")
        from IsoSimilarityTFLib.selftest import hand_made_design

        design = hand_made_design()
        picture = IsoSimilarityTFLogic.similarityImage(design, 128)
        self.assertEqual(picture.shape, (128, 128, 3))
        self.assertEqual(picture.dtype, np.uint8)
        pixmap = IsoSimilarityTFWidget._pixmapFromArray(IsoSimilarityTFLogic.similarityImage(design, 256))
        self.assertEqual((pixmap.width(), pixmap.height()), (256, 256))
        design.similarity = None
        self.assertIsNone(IsoSimilarityTFLogic.similarityImage(design))
        self.assertIn("total", IsoSimilarityTFLogic.timingsText(hand_made_design()))
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_edit_and_export(self):
        self.delayDisplay("Class edits rewrite the transfer function in place; export")
        self._check("edit_and_export")
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_restore(self):
        self.delayDisplay("A design is restored from the scene")
        self._check("restore")
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_outside_changes(self):
        self.delayDisplay("Volume Rendering presets, Synchronize and another property node are noticed")
        self._check("outside_changes")
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_segments_and_preset(self):
        self.delayDisplay("Classes as segments, the design as a preset")
        self._check("segments_and_preset")
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_tissues(self):
        self.delayDisplay("Tissues and their classes: Detail, edits and solo on both levels, stored in the scene")
        self._check("tissues")
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_run(self):
        self.delayDisplay("Full run, in Slicer and in a PythonSlicer process")
        self._check("run")
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_cancel(self):
        self.delayDisplay("Cancelling leaves the scene untouched")
        self._check("cancel")
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_panel(self):
        self.delayDisplay("The panel follows the scene: auto-selected input, two volumes, scene close")
        self._check("panel")
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_widget(self):
        self.delayDisplay("The panel shows the design of the selected volume")
        module = getattr(slicer.modules, "isosimilaritytf", None)
        if module is None:
            self.delayDisplay("Module not loaded in this application: widget test skipped")
            return
        from IsoSimilarityTFLib.selftest import SPACING, hand_made_design, nested_volume

        widget = module.widgetRepresentation().self()
        volumeNode = self._addVolume(nested_volume(), SPACING, "Nested")
        widget.logic.apply(volumeNode, hand_made_design())
        otherVolume = self._addVolume(nested_volume(), SPACING, "Other")
        widget.enter()
        from IsoSimilarityTFLib import mrml

        # The input selector had selected Nested before its design was applied: the design is not regrouped.
        self.assertEqual(mrml.design_of_volume(volumeNode).options["tissues"], "all")
        # Re-entering keeps the one GUI connection and the user's choices (Slicer 5.8 reset them, Slicer#7545).
        widget._parameterNode.crossing = "strict"
        widget._parameterNode.background = "lowest"
        widget.exit()
        widget.enter()
        self.assertEqual(widget._parameterNode.crossing, "strict")
        self.assertEqual(widget._parameterNode.background, "lowest")
        self.assertEqual(widget.ui.crossingComboBox.currentText, choiceLabels()["crossing"]["strict"])
        tree = widget.ui.tissuesTreeWidget
        widget._parameterNode.inputVolume = otherVolume
        self.assertEqual(tree.topLevelItemCount, 0)
        self.assertFalse(widget.ui.detailSlider.enabled)
        widget._parameterNode.inputVolume = volumeNode
        self.assertEqual(tree.topLevelItemCount, 4)  # one tissue per class: each a single row
        self.assertEqual((widget.ui.detailSlider.maximum, widget._parameterNode.tissues), (3, 3))
        # An edit in the tree reaches the volume property.
        top = widget.logic.design.tissues[-1]
        widget._rowWidgets[(TISSUE, top.id)]["opacity"].value = 40
        self.assertAlmostEqual(
            widget.logic.property_node.GetVolumeProperty().GetScalarOpacity().GetValue(560.0), 0.40, places=6
        )
        # A preset copied in is said at once. "Show this module's design again" is answered here: under ctest
        # Slicer's confirmYesNoDisplay answers No (PythonQt enums are ints; audit G6), in Reload and Test it asks.
        widget.confirm_overwrite = lambda change: True
        preset = slicer.modules.volumerendering.logic().GetPresetByName("MR-Default")
        widget.logic.property_node.CopyContent(preset)
        self.assertEqual(widget.ui.statusLabel.text, widget.outsideChangeText())
        widget._rowWidgets[(TISSUE, top.id)]["opacity"].value = 50
        self.assertEqual(widget.ui.statusLabel.text, "")
        self.assertFalse(mrml.modified_outside(volumeNode))
        del widget.confirm_overwrite
        # The looks (drawn once the tree is): one button each, the chosen one checked; a click shows that look.
        slicer.app.processEvents()
        looks = [look.name for look in widget.logic.design.looks]
        self.assertEqual(sorted(widget._lookButtons), sorted(looks))
        self.assertTrue(widget._lookButtons[widget.logic.design.chosen_look].checked)
        widget._lookButtons[looks[-1]].click()
        self.assertEqual(widget.logic.design.look_name, looks[-1])
        self.assertTrue(widget._lookButtons[looks[-1]].checked)
        self.assertEqual(mrml.design_of_volume(volumeNode).look_name, looks[-1])
        widget._rowWidgets[(TISSUE, top.id)]["solo"].checked = True
        self.assertEqual(widget.logic.design.solo_tissue_id, top.id)
        self.assertFalse(widget._rowWidgets[(TISSUE, 0)]["visible"].enabled)
        widget.ui.showAllButton.click()
        self.assertIsNone(widget.logic.design.solo_tissue_id)
        # The Detail slider regroups at once: one tissue holding classes 1 to 3, expandable into them.
        widget.ui.detailSlider.value = 1
        self.assertEqual(widget._parameterNode.tissues, 1)
        self.assertEqual(widget.logic.design.n_tissues, 1)
        self.assertEqual(tree.topLevelItemCount, 2)
        self.assertEqual(tree.topLevelItem(1).childCount(), 3)
        widget._rowWidgets[(CLASS, 2)]["visible"].checked = False
        self.assertEqual(widget._rowWidgets[(TISSUE, 1)]["visible"].checkState(), qt.Qt.PartiallyChecked)
        widget._rowWidgets[(TISSUE, 1)]["visible"].click()  # partly shown -> shown, classes included
        self.assertTrue(widget.logic.design.classes[2].visible)
        widget._parameterNode.tissues = AUTO_DETAIL
        self.assertEqual(widget.logic.design.options["tissues"], "auto")
        # The input follows the active volume until the user picks another one.
        selectionNode = slicer.app.applicationLogic().GetSelectionNode()
        widget.panel.follow_active_volume = True
        selectionNode.SetActiveVolumeID(None)
        selectionNode.SetActiveVolumeID(otherVolume.GetID())
        self.assertIs(widget._parameterNode.inputVolume, otherVolume)
        widget.onInputVolumeActivated(volumeNode)
        widget._parameterNode.inputVolume = volumeNode
        selectionNode.SetActiveVolumeID(otherVolume.GetID())
        selectionNode.SetActiveVolumeID(None)
        selectionNode.SetActiveVolumeID(otherVolume.GetID())
        self.assertIs(widget._parameterNode.inputVolume, volumeNode)
        widget._parameterNode.crossing = "inclusive"
        widget._parameterNode.background = "largest"
        # Scene closes reset the parameter node to its defaults and nothing else (on Slicer 5.8 the combo boxes'
        # old connectors wrote their first choices, audit F2).
        for _close in range(5):
            slicer.mrmlScene.Clear(0)
            widget.enter()
        self.assertEqual(widget._parameterNode.modality, "auto")
        self.assertEqual(widget.ui.modalityComboBox.currentText, choiceLabels()["modality"]["auto"])
        self.assertEqual(widget.ui.tissuesTreeWidget.topLevelItemCount, 0)
        widget.exit()
        self.delayDisplay("Test passed")
