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
from IsoSimilarityTFLib.session import DesignSession

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
groups similar isovalues into classes without being told how many. Each class gets a colour and an opacity that you
can change, hide, or show alone, without computing anything again.
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


def resourcePath(fileName: str) -> str:
    """Path of a file in the module's Resources folder."""
    return os.path.join(os.path.dirname(os.path.abspath(__file__)), "Resources", fileName)


#
# IsoSimilarityTFParameterNode
#

# The engine options' ranges, choices and defaults come from the one options table of the library.


def _withinRange(option: str, minimum: Optional[float] = None) -> WithinRange:
    entry = OPTIONS[option]
    return WithinRange(entry.minimum if minimum is None else minimum, entry.maximum)


def _choice(option: str, *extra: str) -> Choice:
    return Choice([*OPTIONS[option].choices, *extra])


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


#
# IsoSimilarityTFWidget
#

# Columns of the classes table (headers are set in the .ui file).
COLUMN_CLASS, COLUMN_COLOR, COLUMN_OPACITY, COLUMN_VISIBLE, COLUMN_SOLO, COLUMN_VOXELS, COLUMN_RANGE = range(7)

# Share of the progress bar per stage of the engine (clustering gives no progress of its own).
STAGE_PROGRESS = {"quantize": (0, 5), "similarity": (5, 60), "clustering": (60, 97), "classes": (97, 100)}

# How often the panel reads the progress of the design process, in milliseconds.
POLL_INTERVAL_MS = 100

# Side of the similarity picture in the panel, in pixels (a multiple of 4: Qt image rows are 4-byte aligned).
SIMILARITY_PICTURE_SIZE = 256


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
    }


class IsoSimilarityTFWidget(ScriptedLoadableModuleWidget, VTKObservationMixin):
    """The module panel."""

    def __init__(self, parent=None) -> None:
        ScriptedLoadableModuleWidget.__init__(self, parent)
        VTKObservationMixin.__init__(self)
        self.logic = None
        self._parameterNode = None
        self._parameterNodeGuiTag = None
        self._selectionNode = None
        # The input follows the scene's active volume until the user picks another volume.
        self._followActiveVolume = True
        # The design being computed: a child process (IsoSimilarityTFLib.worker) and the volume it is for.
        self._job = None
        self._jobVolume = None
        self._pollTimer = None
        # The volume whose design the classes table shows (the table is rebuilt when the input changes).
        self._shownVolume = None
        self._rowWidgets = []

    @property
    def _running(self) -> bool:
        return self._job is not None

    def setup(self) -> None:
        ScriptedLoadableModuleWidget.setup(self)

        uiWidget = slicer.util.loadUI(self.resourcePath("UI/IsoSimilarityTF.ui"))
        self.layout.addWidget(uiWidget)
        self.ui = slicer.util.childWidgetVariables(uiWidget)
        # The .ui connects the root qMRMLWidget's mrmlSceneChanged signal to the node selector's setMRMLScene slot.
        uiWidget.setMRMLScene(slicer.mrmlScene)

        self.logic = IsoSimilarityTFLogic()

        self._pollTimer = qt.QTimer()
        self._pollTimer.setInterval(POLL_INTERVAL_MS)
        self._pollTimer.connect("timeout()", self._pollJob)

        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.StartCloseEvent, self.onSceneStartClose)
        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.EndCloseEvent, self.onSceneEndClose)
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
        header = self.ui.classesTableWidget.horizontalHeader()
        header.setSectionResizeMode(qt.QHeaderView.ResizeToContents)
        header.setStretchLastSection(True)
        self._showDesign(None)

        self.initializeParameterNode()

    def cleanup(self) -> None:
        self._stopJob()
        self.removeObservers()

    def enter(self) -> None:
        self.initializeParameterNode()

    def exit(self) -> None:
        # The GUI stays connected to the parameter node (see setParameterNode); nothing to undo here.
        pass

    def onReload(self) -> None:
        """Reload the library too: Slicer's reload executes only this file, and would keep the old
        IsoSimilarityTFLib modules of sys.modules."""
        self._stopJob()
        for name in list(sys.modules):
            if name == "IsoSimilarityTFLib" or name.startswith("IsoSimilarityTFLib."):
                del sys.modules[name]
        ScriptedLoadableModuleWidget.onReload(self)

    def onSceneStartClose(self, caller, event) -> None:
        # A design under way would be written into the closing scene: stop it.
        if self._running:
            self._stopJob()
            self._setRunning(False)
        self.setParameterNode(None)
        self.logic.forget()
        self._shownVolume = None
        self._showDesign(None)

    def onSceneEndClose(self, caller, event) -> None:
        self._followActiveVolume = True
        self._observeSelectionNode()
        if self.parent.isEntered:
            self.initializeParameterNode()

    # Parameter node --------------------------------------------------------------------------------------------------
    def initializeParameterNode(self) -> None:
        self.setParameterNode(self.logic.getParameterNode())
        activeVolume = self._activeVolume()
        if activeVolume and (self._followActiveVolume or not self._parameterNode.inputVolume):
            self._parameterNode.inputVolume = activeVolume
        self._onParameterNodeModified()

    def setParameterNode(self, inputParameterNode: Optional[IsoSimilarityTFParameterNode]) -> None:
        """Connect the panel to a parameter node, once per MRML node.

        Re-entering the module gives a new wrapper of the same MRML node: it is not reconnected. On Slicer 5.8
        ``connectGui`` returns no tag, so ``disconnectGui`` cannot undo it, and each new connection rebuilds the
        choice combo boxes, which writes their first and last choices into the parameter node (Slicer#7545).
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
            self.removeObserver(self._parameterNode, vtk.vtkCommand.ModifiedEvent, self._onParameterNodeModified)
        self._parameterNode = inputParameterNode
        if self._parameterNode:
            # Widgets with a "SlicerParameterName" dynamic property in the .ui are bound to the parameter of that name.
            self._parameterNodeGuiTag = self._parameterNode.connectGui(self.ui)
            self._labelChoiceComboBoxes()
            self.addObserver(self._parameterNode, vtk.vtkCommand.ModifiedEvent, self._onParameterNodeModified)
            self._onParameterNodeModified()

    def _labelChoiceComboBoxes(self) -> None:
        """Show readable labels instead of the parameter values the connector put in the combo boxes."""
        comboBoxes = {
            "crossing": self.ui.crossingComboBox,
            "normalization": self.ui.normalizationComboBox,
            "preference": self.ui.preferenceComboBox,
            "background": self.ui.backgroundComboBox,
            "unconverged": self.ui.unconvergedComboBox,
        }
        for parameter, labels in choiceLabels().items():
            comboBox = comboBoxes[parameter]
            for index in range(comboBox.count):
                value = comboBox.itemText(index)
                if value in labels:
                    comboBox.setItemText(index, labels[value])
                    comboBox.setItemData(index, value, qt.Qt.ToolTipRole)

    def _onParameterNodeModified(self, caller=None, event=None) -> None:
        volume = self._parameterNode.inputVolume if self._parameterNode else None
        if self._running:
            return
        self.ui.applyButton.enabled = volume is not None
        self.ui.applyButton.toolTip = (
            _("Design a transfer function for the input volume and show it in the 3D view")
            if volume
            else _("Select an input volume")
        )
        self.ui.preferenceValueSpinBox.enabled = bool(
            self._parameterNode and self._parameterNode.preference == "number"
        )
        if volume is not self._shownVolume:
            self._shownVolume = volume
            design = self.logic.restore(volume)
            self._showDesign(design)
            if design is not None and self.logic.outside_change() is not None:
                self.ui.statusLabel.text = _(
                    "The 3D view shows another transfer function than this design (changed in the Volume Rendering "
                    "module). Editing a class shows the design again, after asking."
                )

    # Active volume ---------------------------------------------------------------------------------------------------
    def _observeSelectionNode(self) -> None:
        appLogic = slicer.app.applicationLogic()
        selectionNode = appLogic.GetSelectionNode() if appLogic else None
        if selectionNode is self._selectionNode:
            return
        if self._selectionNode is not None:
            self.removeObserver(self._selectionNode, vtk.vtkCommand.ModifiedEvent, self.onSelectionNodeModified)
        self._selectionNode = selectionNode
        if selectionNode is not None:
            self.addObserver(selectionNode, vtk.vtkCommand.ModifiedEvent, self.onSelectionNodeModified)

    def _activeVolume(self):
        """The scene's active volume if it is a plain scalar volume (the kind the selector lists), else None."""
        if self._selectionNode is None or not self._selectionNode.GetActiveVolumeID():
            return None
        node = slicer.mrmlScene.GetNodeByID(self._selectionNode.GetActiveVolumeID())
        return node if node is not None and node.GetClassName() == "vtkMRMLScalarVolumeNode" else None

    def onSelectionNodeModified(self, caller=None, event=None) -> None:
        if not self._followActiveVolume or self._parameterNode is None or self._running:
            return
        activeVolume = self._activeVolume()
        if activeVolume is not None and activeVolume is not self._parameterNode.inputVolume:
            self._parameterNode.inputVolume = activeVolume

    def onInputVolumeActivated(self, node) -> None:
        """The user picked a volume in the selector: stop following the active volume unless they picked it."""
        activeVolume = self._activeVolume()
        self._followActiveVolume = node is None or activeVolume is None or node is activeVolume

    # Apply: the design runs in a child process, polled by a timer, so Slicer stays responsive and Cancel is at once.
    def onApplyButton(self) -> None:
        if self._running or not self._parameterNode or not self._parameterNode.inputVolume:
            return
        volume = self._parameterNode.inputVolume
        # Asked before the busy cursor; the install (if accepted) shows its own status.
        if not self._ensureScikitLearn():
            self.ui.statusLabel.text = _("scikit-learn is needed to group the isovalues into classes.")
            return
        with slicer.util.tryWithErrorDisplay(_("Failed to compute the transfer function."), waitCursor=True):
            options = self.logic.designOptions(self._parameterNode)
            from IsoSimilarityTFLib.session import fit_levels

            dimensions = volume.GetImageData().GetDimensions() if volume.GetImageData() else (0, 0, 0)
            available = fit_levels(tuple(reversed(dimensions)), options)[1]
            if available is not None:
                logging.info(f"IsoSimilarityTF: {volume.GetName()} has {available} octree levels; using all of them")
            self.addLog(_("Designing a transfer function for {name}...").format(name=volume.GetName()))
            self._job = self.logic.start(volume, options)
            self._jobVolume = volume
            self._setRunning(True)
            self._pollTimer.start()

    def _pollJob(self) -> None:
        job = self._job
        if job is None:
            self._pollTimer.stop()
            return
        finished = not job.running
        for stage, fraction, message in job.poll():
            low, high = STAGE_PROGRESS.get(stage, (0, 100))
            self.ui.progressBar.value = round(low + (high - low) * min(max(fraction, 0.0), 1.0))
            self.ui.progressBar.setFormat(f"{message} (%p%)")
        if not finished:
            return
        self._pollTimer.stop()
        volume = self._jobVolume
        self._job = self._jobVolume = None
        try:
            with slicer.util.tryWithErrorDisplay(_("Failed to compute the transfer function."), waitCursor=True):
                if volume.GetScene() is None:
                    job.close()
                    raise RuntimeError(_("The input volume was removed from the scene."))
                design = self.logic.finish(volume, job)
                self._shownVolume = volume
                self._showDesign(design)
                self.addLog(self.logic.summaryText(design))
                logging.info(f"IsoSimilarityTF timings for {volume.GetName()}: {self.logic.timingsText(design)}")
        finally:
            self._setRunning(False)

    def onCancelButton(self) -> None:
        self._stopJob()
        self._setRunning(False)
        self.addLog(_("Cancelled."))

    def _stopJob(self) -> None:
        """Kill the design process, if any, and forget it (takes effect at once, at any stage)."""
        if self._pollTimer is not None:
            self._pollTimer.stop()
        if self._job is not None:
            self._job.close()
        self._job = self._jobVolume = None

    def _setRunning(self, running: bool) -> None:
        self.ui.progressBar.value = 0
        self.ui.progressBar.setFormat("%p%")
        self.ui.progressBar.visible = running
        self.ui.cancelButton.visible = running
        self.ui.cancelButton.enabled = running
        for widget in (
            self.ui.applyButton,
            self.ui.inputSelector,
            self.ui.advancedCollapsibleButton,
            self.ui.classesCollapsibleButton,
        ):
            widget.enabled = not running
        if not running:
            self._onParameterNodeModified()

    def _ensureScikitLearn(self) -> bool:
        """Make sure scikit-learn can be imported, installing it with the user's consent; False if it cannot."""
        requirementsFile = self.resourcePath("requirements.txt")
        try:
            import slicer.packaging as packaging  # Slicer 5.12 and later
        except ImportError:
            packaging = None
        if packaging is not None and hasattr(packaging, "pip_ensure"):
            try:
                # Asks, then installs with its own progress dialog.
                packaging.pip_ensure(packaging.load_requirements(requirementsFile), requester="IsoSimilarityTF")
            except RuntimeError as error:  # the user declined
                logging.info(f"scikit-learn not installed: {error}")
                return False
            return IsoSimilarityTFLogic.scikitLearnAvailable()
        if IsoSimilarityTFLogic.scikitLearnAvailable():
            return True
        if slicer.app.testingEnabled():
            logging.info("Testing mode: not installing scikit-learn")
            return False
        requirements = IsoSimilarityTFLogic.requirements(requirementsFile)
        if not slicer.util.confirmOkCancelDisplay(
            _(
                "This module needs the Python package scikit-learn, which Slicer does not include.\n\n"
                "Install it now ({requirements})? It is downloaded from the Python Package Index; "
                "this can take a minute."
            ).format(requirements=", ".join(requirements)),
            windowTitle=_("Install Python packages"),
        ):
            return False
        # Slicer 5.8 and 5.10 install without a progress dialog: say what is happening before it blocks.
        self.addLog(_("Installing scikit-learn... Slicer does not respond until it is done."))
        with slicer.util.tryWithErrorDisplay(_("Failed to install scikit-learn."), waitCursor=True):
            slicer.util.pip_install(" ".join(requirements))
        available = IsoSimilarityTFLogic.scikitLearnAvailable()
        self.addLog(_("scikit-learn is installed.") if available else _("scikit-learn could not be installed."))
        return available

    def addLog(self, text: str) -> None:
        """Show a message under the Apply button."""
        self.ui.statusLabel.text = text
        slicer.app.processEvents()

    # Classes table ---------------------------------------------------------------------------------------------------
    def _showDesign(self, design) -> None:
        """Show a design (or nothing) in the classes table, the similarity picture and the timings label."""
        self._fillClassesTable(design)
        self._showSimilarityPicture(design)
        self.ui.timingsLabel.text = self.logic.timingsText(design) if design is not None else ""
        for button in (
            self.ui.resetColorsButton,
            self.ui.showAllButton,
            self.ui.exportButton,
            self.ui.exportSegmentationButton,
            self.ui.savePresetButton,
        ):
            button.enabled = design is not None
        if design is None:
            self.ui.classesCollapsibleButton.text = _("Classes")
        else:
            self.ui.classesCollapsibleButton.text = _("Classes ({count})").format(count=len(design.classes))

    @staticmethod
    def _centered(widget):
        container = qt.QWidget()
        layout = qt.QHBoxLayout(container)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setAlignment(qt.Qt.AlignCenter)
        layout.addWidget(widget)
        return container

    def _fillClassesTable(self, design) -> None:
        table = self.ui.classesTableWidget
        table.clearContents()
        table.setRowCount(0)  # deletes the rows' cell widgets
        self._rowWidgets = []
        table.setRowCount(0 if design is None else len(design.classes))
        if design is None:
            return
        for row, isoClass in enumerate(design.classes):
            self._rowWidgets.append(self._fillClassRow(table, row, isoClass))
        self._syncClassRows()

    def _fillClassRow(self, table, row: int, isoClass) -> dict:
        """One row of the table: a class's name, its look (editable) and its extent. Returns the editing widgets."""
        label = str(isoClass.id + 1)
        if isoClass.background:
            label = _("{id} (background)").format(id=label)
        classItem = qt.QTableWidgetItem(label)
        classItem.setToolTip(
            _("Class {id}: rank {rank} by voxel count; exemplar isovalue bin {exemplar}").format(
                id=isoClass.id + 1, rank=isoClass.rank, exemplar=isoClass.exemplar_bin
            )
        )
        table.setItem(row, COLUMN_CLASS, classItem)

        colorButton = ctk.ctkColorPickerButton()
        colorButton.displayColorName = False
        colorButton.toolTip = _("Colour of the class")
        colorButton.connect("colorChanged(QColor)", functools.partial(self.onClassColorChanged, isoClass.id))
        table.setCellWidget(row, COLUMN_COLOR, colorButton)

        opacitySlider = qt.QSlider(qt.Qt.Horizontal)
        opacitySlider.setRange(0, 100)
        opacitySlider.setMinimumWidth(80)
        opacitySlider.connect("valueChanged(int)", functools.partial(self.onClassOpacityChanged, isoClass.id))
        table.setCellWidget(row, COLUMN_OPACITY, opacitySlider)

        visibleCheckBox = qt.QCheckBox()
        visibleCheckBox.toolTip = _("Show this class")
        visibleCheckBox.connect("toggled(bool)", functools.partial(self.onClassVisibleToggled, isoClass.id))
        table.setCellWidget(row, COLUMN_VISIBLE, self._centered(visibleCheckBox))

        soloCheckBox = qt.QCheckBox()
        soloCheckBox.toolTip = _("Show this class alone")
        soloCheckBox.connect("toggled(bool)", functools.partial(self.onClassSoloToggled, isoClass.id))
        table.setCellWidget(row, COLUMN_SOLO, self._centered(soloCheckBox))

        voxelsItem = qt.QTableWidgetItem(f"{100.0 * isoClass.fraction:.2f} %")
        voxelsItem.setTextAlignment(qt.Qt.AlignRight | qt.Qt.AlignVCenter)
        voxelsItem.setToolTip(_("{voxels} voxels").format(voxels=isoClass.voxels))
        table.setItem(row, COLUMN_VOXELS, voxelsItem)

        ranges = "; ".join(f"{low:.6g} to {high:.6g}" for low, high in isoClass.value_ranges)
        rangeItem = qt.QTableWidgetItem(ranges)
        rangeItem.setToolTip(
            _("Intensity range(s) of the class, in the volume's units: {ranges}").format(ranges=ranges)
        )
        table.setItem(row, COLUMN_RANGE, rangeItem)
        return {"color": colorButton, "opacity": opacitySlider, "visible": visibleCheckBox, "solo": soloCheckBox}

    def _syncClassRows(self) -> None:
        """Set the table's widgets from the logic's design, without sending edits back."""
        design = self.logic.design
        if design is None:
            return
        for isoClass, widgets in zip(design.classes, self._rowWidgets):
            for widget in widgets.values():
                widget.blockSignals(True)
            widgets["color"].color = qt.QColor.fromRgbF(*isoClass.color)
            widgets["opacity"].value = round(100 * isoClass.opacity)
            widgets["opacity"].toolTip = _("Opacity: {percent} %").format(percent=round(100 * isoClass.opacity))
            widgets["visible"].checked = isoClass.visible
            widgets["visible"].enabled = design.solo_class is None
            widgets["solo"].checked = design.solo_class == isoClass.id
            for widget in widgets.values():
                widget.blockSignals(False)

    def _confirmOverwrite(self) -> bool:
        """Before an edit: if the shown transfer function is no longer the design's, ask before replacing it."""
        change = self.logic.outside_change()
        if change is None:
            return True
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

    def _edit(self, edit) -> None:
        """Apply one edit through the logic (which rewrites the transfer function in place) and refresh the panel."""
        if self._confirmOverwrite():
            with slicer.util.tryWithErrorDisplay(_("Failed to update the transfer function.")):
                edit()
        self._syncClassRows()

    def onClassColorChanged(self, classId: int, color) -> None:
        self._edit(lambda: self.logic.set_class_color(classId, (color.redF(), color.greenF(), color.blueF())))
        self._showSimilarityPicture(self.logic.design)

    def onClassOpacityChanged(self, classId: int, value: int) -> None:
        self._edit(lambda: self.logic.set_class_opacity(classId, value / 100.0))

    def onClassVisibleToggled(self, classId: int, checked: bool) -> None:
        self._edit(lambda: self.logic.set_class_visible(classId, checked))

    def onClassSoloToggled(self, classId: int, checked: bool) -> None:
        self._edit(lambda: self.logic.solo_class(classId if checked else None))

    def onResetColorsButton(self) -> None:
        self._edit(self.logic.reset_colors)
        self._showSimilarityPicture(self.logic.design)

    def onShowAllButton(self) -> None:
        self._edit(self.logic.show_all_classes)

    # Handing the design over -----------------------------------------------------------------------------------------
    def onExportButton(self) -> None:
        if self.logic.design is None:
            return
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
        if self.logic.design is None:
            return
        with slicer.util.tryWithErrorDisplay(_("Failed to export the classes to a segmentation."), waitCursor=True):
            segmentationNode = self.logic.export_segmentation()
            count = segmentationNode.GetSegmentation().GetNumberOfSegments()
            self.addLog(
                _("Segmentation {name} created with {count} segments.").format(
                    name=segmentationNode.GetName(), count=count
                )
            )

    def onSavePresetButton(self) -> None:
        if self.logic.design is None:
            return
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
        logic.export_segmentation()                           # one segment per shown class
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

    @staticmethod
    def defaultExportExtension() -> str:
        """``.vp.json`` where this Slicer can read it (5.10 and later), else the legacy ``.vp`` (Slicer 5.8)."""
        return DesignSession.default_export_extension(hasattr(slicer, "vtkMRMLVolumePropertyJsonStorageNode"))

    # Running ---------------------------------------------------------------------------------------------------------
    @staticmethod
    def designOptions(parameterNode) -> dict:
        """The engine's options (``design_transfer_function`` keywords) from the parameter node."""
        return {
            "n_bins": int(parameterNode.bins),
            "levels": int(parameterNode.levels) or None,
            "crossing": parameterNode.crossing,
            "normalization": parameterNode.normalization,
            "preference": (
                float(parameterNode.preferenceValue)
                if parameterNode.preference == "number"
                else parameterNode.preference
            ),
            "damping": float(parameterNode.damping),
            "max_iter": int(parameterNode.maxIterations),
            "convergence_iter": int(parameterNode.convergenceIterations),
            "max_classes": int(parameterNode.maxClasses),
            "background": parameterNode.background,
            "unconverged": parameterNode.unconverged,
        }

    @staticmethod
    def scikitLearnAvailable() -> bool:
        import importlib
        import importlib.util

        importlib.invalidate_caches()
        return importlib.util.find_spec("sklearn") is not None

    @staticmethod
    def requirements(path: str) -> list:
        """Requirement strings of a requirements.txt file (comments, blank lines and pip options skipped)."""
        with open(path, encoding="utf-8") as file:
            lines = [line.split("#", 1)[0].strip() for line in file]
        return [line for line in lines if line and not line.startswith("-")]

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
        return _("{count} classes ({shown} shown); affinity propagation {convergence}, damping {damping}.").format(
            count=len(design.classes), shown=shown, convergence=convergence, damping=clustering.get("damping", "?")
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
            self.test_IsoSimilarityTF_run,
            self.test_IsoSimilarityTF_cancel,
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

        check, needsScikitLearn = selftest.CHECKS[name]
        if needsScikitLearn and not IsoSimilarityTFLogic.scikitLearnAvailable():
            self.delayDisplay("scikit-learn is not installed: check skipped")
            return
        check(IsoSimilarityTFLogic, self._addVolume)

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
        self.assertEqual(logic.requirements(resourcePath("requirements.txt"))[0].split(">")[0], "scikit-learn")
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

    def test_IsoSimilarityTF_run(self):
        self.delayDisplay("Full run, in Slicer and in a PythonSlicer process")
        self._check("run")
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_cancel(self):
        self.delayDisplay("Cancelling leaves the scene untouched")
        self._check("cancel")
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
        # Re-entering keeps the one GUI connection and the user's choices (Slicer 5.8 reset them, Slicer#7545).
        widget._parameterNode.crossing = "strict"
        widget._parameterNode.background = "lowest"
        widget.exit()
        widget.enter()
        self.assertEqual(widget._parameterNode.crossing, "strict")
        self.assertEqual(widget._parameterNode.background, "lowest")
        self.assertEqual(widget.ui.crossingComboBox.currentText, choiceLabels()["crossing"]["strict"])
        widget._parameterNode.inputVolume = otherVolume
        self.assertEqual(widget.ui.classesTableWidget.rowCount, 0)
        widget._parameterNode.inputVolume = volumeNode
        self.assertEqual(widget.ui.classesTableWidget.rowCount, 4)
        # An edit in the table reaches the volume property.
        top = widget.logic.design.classes[-1]
        widget._rowWidgets[top.id]["opacity"].value = 40
        self.assertAlmostEqual(
            widget.logic.property_node.GetVolumeProperty().GetScalarOpacity().GetValue(560.0), 0.40, places=6
        )
        widget._rowWidgets[top.id]["solo"].checked = True
        self.assertEqual(widget.logic.design.solo_class, top.id)
        self.assertFalse(widget._rowWidgets[0]["visible"].enabled)
        widget.ui.showAllButton.click()
        self.assertIsNone(widget.logic.design.solo_class)
        # The input follows the active volume until the user picks another one.
        selectionNode = slicer.app.applicationLogic().GetSelectionNode()
        widget._followActiveVolume = True
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
        widget.exit()
        self.delayDisplay("Test passed")
