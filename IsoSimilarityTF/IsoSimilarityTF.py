"""IsoSimilarityTF: automatic transfer function for volume rendering (Slicer scripted module).

The module is a thin shell around ``IsoSimilarityTFLib``: the engine designs the transfer function, ``mrml`` shows it
in the volume rendering, ``pictures`` draws the similarity matrix. This file only wires them to the panel.
"""

import functools
import logging
import os
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

#
# IsoSimilarityTF
#


class IsoSimilarityTF(ScriptedLoadableModule):
    """Module description shown in the module panel and the module finder."""

    def __init__(self, parent):
        ScriptedLoadableModule.__init__(self, parent)
        self.parent.title = _("Iso-Similarity Transfer Function")
        self.parent.categories = [translate("qSlicerAbstractCoreModule", "Rendering")]
        self.parent.dependencies = ["VolumeRendering"]
        self.parent.contributors = ["IsoSimilarityTF developers"]
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


class IsoSimilarityTFCancelled(Exception):
    """Raised from the progress callback when the user pressed Cancel; the design is abandoned."""


#
# IsoSimilarityTFParameterNode
#


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
    bins: Annotated[int, WithinRange(2, 4096)] = 256
    levels: Annotated[int, WithinRange(0, 32)] = 0
    crossing: Annotated[str, Choice(["inclusive", "strict"])] = "inclusive"
    normalization: Annotated[str, Choice(["thesis", "ma-entezari"])] = "thesis"
    preference: Annotated[str, Choice(["median", "minimum", "number"])] = "median"
    preferenceValue: Annotated[float, WithinRange(-100.0, 0.0)] = -1.0
    damping: Annotated[float, WithinRange(0.5, 0.99)] = 0.5
    maxIterations: Annotated[int, WithinRange(1, 100000)] = 200
    convergenceIterations: Annotated[int, WithinRange(1, 10000)] = 15
    maxClasses: Annotated[int, WithinRange(0, 1000)] = 15
    background: Annotated[str, Choice(["largest", "lowest", "none"])] = "largest"
    unconverged: Annotated[str, Choice(["raise-damping", "error", "keep"])] = "raise-damping"


#
# IsoSimilarityTFWidget
#

# Columns of the classes table (headers are set in the .ui file).
COLUMN_CLASS, COLUMN_COLOR, COLUMN_OPACITY, COLUMN_VISIBLE, COLUMN_SOLO, COLUMN_VOXELS, COLUMN_RANGE = range(7)

# Share of the progress bar per stage of the engine (clustering gives no progress of its own).
STAGE_PROGRESS = {"quantize": (0, 5), "similarity": (5, 60), "clustering": (60, 97), "classes": (97, 100)}

# Similarity matrices the logic keeps for volumes designed in this session (4096 bins: 128 MB each).
MAX_KEPT_SIMILARITIES = 4

# Side of the similarity picture in the panel, in pixels (a multiple of 4: Qt image rows are 4-byte aligned).
SIMILARITY_PICTURE_SIZE = 256


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
        self._running = False
        self._cancelRequested = False
        # The volume whose design the classes table shows (the table is rebuilt when the input changes).
        self._shownVolume = None
        self._rowWidgets = []

    def setup(self) -> None:
        ScriptedLoadableModuleWidget.setup(self)

        uiWidget = slicer.util.loadUI(self.resourcePath("UI/IsoSimilarityTF.ui"))
        self.layout.addWidget(uiWidget)
        self.ui = slicer.util.childWidgetVariables(uiWidget)
        # The .ui connects the root qMRMLWidget's mrmlSceneChanged signal to the node selector's setMRMLScene slot.
        uiWidget.setMRMLScene(slicer.mrmlScene)

        self.logic = IsoSimilarityTFLogic()
        self.logic.logCallback = self.addLog

        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.StartCloseEvent, self.onSceneStartClose)
        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.EndCloseEvent, self.onSceneEndClose)
        self._observeSelectionNode()

        self.ui.inputSelector.connect("nodeActivated(vtkMRMLNode*)", self.onInputVolumeActivated)
        self.ui.applyButton.connect("clicked(bool)", self.onApplyButton)
        self.ui.cancelButton.connect("clicked(bool)", self.onCancelButton)
        self.ui.resetColorsButton.connect("clicked(bool)", self.onResetColorsButton)
        self.ui.showAllButton.connect("clicked(bool)", self.onShowAllButton)
        self.ui.exportButton.connect("clicked(bool)", self.onExportButton)

        self.ui.progressBar.hide()
        self.ui.cancelButton.hide()
        self.ui.statusLabel.text = ""
        header = self.ui.classesTableWidget.horizontalHeader()
        header.setSectionResizeMode(qt.QHeaderView.ResizeToContents)
        header.setStretchLastSection(True)
        self._showDesign(None)

        self.initializeParameterNode()

    def cleanup(self) -> None:
        self.removeObservers()

    def enter(self) -> None:
        self.initializeParameterNode()

    def exit(self) -> None:
        if self._parameterNode:
            self._parameterNode.disconnectGui(self._parameterNodeGuiTag)
            self._parameterNodeGuiTag = None
            self.removeObserver(self._parameterNode, vtk.vtkCommand.ModifiedEvent, self._onParameterNodeModified)

    def onSceneStartClose(self, caller, event) -> None:
        # A design under way would be written into the closing scene: abandon it at its next progress report.
        self._cancelRequested = self._cancelRequested or self._running
        self.setParameterNode(None)
        self.logic.forgetDesign()
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
        if self._parameterNode:
            self._parameterNode.disconnectGui(self._parameterNodeGuiTag)
            self.removeObserver(self._parameterNode, vtk.vtkCommand.ModifiedEvent, self._onParameterNodeModified)
        self._parameterNode = inputParameterNode
        if self._parameterNode:
            # Widgets with a "SlicerParameterName" dynamic property in the .ui are bound to the parameter of that name.
            self._parameterNodeGuiTag = self._parameterNode.connectGui(self.ui)
            self.addObserver(self._parameterNode, vtk.vtkCommand.ModifiedEvent, self._onParameterNodeModified)
            self._onParameterNodeModified()

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
            self._showDesign(self.logic.restoreDesign(volume))

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

    # Apply -----------------------------------------------------------------------------------------------------------
    def onApplyButton(self) -> None:
        if self._running or not self._parameterNode or not self._parameterNode.inputVolume:
            return
        volume = self._parameterNode.inputVolume
        with slicer.util.tryWithErrorDisplay(_("Failed to compute the transfer function."), waitCursor=True):
            if not self._ensureScikitLearn():
                self.ui.statusLabel.text = _("scikit-learn is needed to group the isovalues into classes.")
                return
            self._setRunning(True)
            try:
                self.logic.run(volume, self.logic.designOptions(self._parameterNode), progress=self._onProgress)
                self._shownVolume = volume
            except IsoSimilarityTFCancelled:
                self.addLog(_("Cancelled."))
                return
            finally:
                self._setRunning(False)
            self._showDesign(self.logic.design)
            self.addLog(self.logic.summaryText(self.logic.design))

    def onCancelButton(self) -> None:
        self._cancelRequested = True
        self.ui.cancelButton.enabled = False
        self.addLog(_("Cancelling..."))

    def _onProgress(self, stage: str, fraction: float, message: str) -> None:
        low, high = STAGE_PROGRESS.get(stage, (0, 100))
        self.ui.progressBar.value = round(low + (high - low) * min(max(fraction, 0.0), 1.0))
        self.ui.progressBar.setFormat(f"{message} (%p%)")
        slicer.app.processEvents()
        if self._cancelRequested:
            raise IsoSimilarityTFCancelled()

    def _setRunning(self, running: bool) -> None:
        self._running = running
        self._cancelRequested = False
        self.ui.progressBar.value = 0
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
        slicer.util.pip_install(" ".join(requirements))
        return IsoSimilarityTFLogic.scikitLearnAvailable()

    def addLog(self, text: str) -> None:
        """Show a message of the logic under the Apply button."""
        self.ui.statusLabel.text = text
        slicer.app.processEvents()

    # Classes table ---------------------------------------------------------------------------------------------------
    def _showDesign(self, design) -> None:
        """Show a design (or nothing) in the classes table, the similarity picture and the timings label."""
        self._fillClassesTable(design)
        self._showSimilarityPicture(design)
        self.ui.timingsLabel.text = self.logic.timingsText(design) if design is not None else ""
        for button in (self.ui.resetColorsButton, self.ui.showAllButton, self.ui.exportButton):
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

            self._rowWidgets.append(
                {"color": colorButton, "opacity": opacitySlider, "visible": visibleCheckBox, "solo": soloCheckBox}
            )
        self._syncClassRows()

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

    def _edit(self, edit) -> None:
        """Apply one edit through the logic (which rewrites the transfer function in place) and refresh the panel."""
        with slicer.util.tryWithErrorDisplay(_("Failed to update the transfer function.")):
            edit()
        self._syncClassRows()

    def onClassColorChanged(self, classId: int, color) -> None:
        self._edit(lambda: self.logic.setClassColor(classId, (color.redF(), color.greenF(), color.blueF())))
        self._showSimilarityPicture(self.logic.design)

    def onClassOpacityChanged(self, classId: int, value: int) -> None:
        self._edit(lambda: self.logic.setClassOpacity(classId, value / 100.0))

    def onClassVisibleToggled(self, classId: int, checked: bool) -> None:
        self._edit(lambda: self.logic.setClassVisible(classId, checked))

    def onClassSoloToggled(self, classId: int, checked: bool) -> None:
        self._edit(lambda: self.logic.soloClass(classId if checked else None))

    def onResetColorsButton(self) -> None:
        self._edit(self.logic.resetColors)
        self._showSimilarityPicture(self.logic.design)

    def onShowAllButton(self) -> None:
        self._edit(self.logic.showAllClasses)

    def onExportButton(self) -> None:
        if self.logic.design is None:
            return
        volume = self.logic.volumeNode
        fileName = (volume.GetName() if volume else "TransferFunction") + ".vp.json"
        path = qt.QFileDialog.getSaveFileName(
            self.parent,
            _("Export transfer function"),
            os.path.join(slicer.app.defaultScenePath, fileName),
            _("Slicer volume property (*.vp.json);;Legacy Slicer volume property (*.vp)"),
        )
        if not path:
            return
        with slicer.util.tryWithErrorDisplay(_("Failed to export the transfer function."), waitCursor=True):
            self.logic.exportTransferFunction(path)

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


class IsoSimilarityTFLogic(ScriptedLoadableModuleLogic):
    """Runs the engine on a volume node and keeps its design in sync with the volume rendering.

    Usable without the widget::

        logic = IsoSimilarityTFLogic()
        design = logic.run(volumeNode, {"n_bins": 256})
        logic.setClassOpacity(design.classes[-1].id, 1.0)   # rewrites the transfer function in place
        logic.exportTransferFunction("/tmp/tf.vp.json")
    """

    def __init__(self) -> None:
        ScriptedLoadableModuleLogic.__init__(self)
        self.logCallback = None
        self.volumeNode = None
        self.propertyNode = None
        self.design = None
        # Similarity matrices of this session's runs by property node ID (the node stores the design without it).
        self._similarities = {}

    def getParameterNode(self):
        return IsoSimilarityTFParameterNode(super().getParameterNode())

    def addLog(self, text: str) -> None:
        logging.info(text)
        if self.logCallback:
            self.logCallback(text)

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

    @staticmethod
    def volumeValues(volumeNode):
        """The voxel array (a view, k-j-i order) and the voxel spacing (mm) of a scalar volume node."""
        if volumeNode is None or volumeNode.GetImageData() is None:
            raise ValueError(_("The input volume holds no image data."))
        values = slicer.util.arrayFromVolume(volumeNode)
        if values.ndim != 3:
            raise ValueError(
                _("The input must be a single-component 3-D volume; its voxel array has shape {shape}.").format(
                    shape=values.shape
                )
            )
        return values, tuple(volumeNode.GetSpacing())

    def run(self, volumeNode, options: Optional[dict] = None, progress=None):
        """Design a transfer function for the volume and show it in the volume's 3D rendering.

        Args:
            volumeNode: a ``vtkMRMLScalarVolumeNode``.
            options: ``design_transfer_function`` keywords (see ``IsoSimilarityTFLib.design.DEFAULT_OPTIONS``).
            progress: ``progress(stage, fraction, message)``; raising from it cancels (nothing is changed then).

        Returns:
            The design (also kept as ``self.design``).
        """
        from IsoSimilarityTFLib import design_transfer_function, octree_levels

        values, spacing = self.volumeValues(volumeNode)
        options = dict(options or {})
        levels = options.get("levels")
        if levels and min(values.shape) >= 2:
            available = len(octree_levels(tuple(n - 1 for n in values.shape)))
            if levels > available:
                self.addLog(
                    _("The volume has {available} octree levels; using all of them.").format(available=available)
                )
                options["levels"] = None
        self.addLog(_("Designing a transfer function for {name}...").format(name=volumeNode.GetName()))
        design = design_transfer_function(values, spacing, progress=progress, **options)
        logging.info(f"IsoSimilarityTF timings for {volumeNode.GetName()}: {self.timingsText(design)}")
        self.applyDesign(volumeNode, design)
        return design

    def volumeRenderingLogic(self):
        return slicer.modules.volumerendering.logic()

    def applyDesign(self, volumeNode, design):
        """Show a design in the volume's 3D rendering; returns the volume property node."""
        from IsoSimilarityTFLib import mrml

        self.propertyNode = mrml.apply_design(volumeNode, design, self.volumeRenderingLogic())
        self.volumeNode = volumeNode
        self.design = design
        if design.similarity is not None:
            self._similarities.pop(self.propertyNode.GetID(), None)
            self._similarities[self.propertyNode.GetID()] = design.similarity
            while len(self._similarities) > MAX_KEPT_SIMILARITIES:  # oldest first
                self._similarities.pop(next(iter(self._similarities)))
        return self.propertyNode

    def restoreDesign(self, volumeNode):
        """Make the design stored with the volume's property node (from an earlier run or a saved scene) current.

        Returns:
            The design, or None (then no design is current).
        """
        from IsoSimilarityTFLib import mrml

        propertyNode = mrml.design_node_of(volumeNode) if volumeNode is not None else None
        design = mrml.design_of(propertyNode) if propertyNode is not None else None
        if design is not None and design.similarity is None:
            design.similarity = self._similarities.get(propertyNode.GetID())
        self.volumeNode = volumeNode
        self.propertyNode = propertyNode if design is not None else None
        self.design = design
        return design

    def forgetDesign(self) -> None:
        """Drop the current design and the kept similarity matrices (the scene is being closed)."""
        self.volumeNode = self.propertyNode = self.design = None
        self._similarities = {}

    # Editing (no recomputation: the transfer function is rewritten in place) ---------------------------------------
    def _updateRendering(self) -> None:
        from IsoSimilarityTFLib import mrml

        if self.propertyNode is None or self.propertyNode.GetScene() is None:
            raise RuntimeError(_("The volume property node of this design was removed; press Apply again."))
        mrml.update_property_node(self.propertyNode, self.design)

    def _currentDesign(self):
        if self.design is None:
            raise RuntimeError(_("No transfer function has been designed yet."))
        return self.design

    def setClassColor(self, classId: int, color) -> None:
        self._currentDesign().set_class(classId, color=color)
        self._updateRendering()

    def setClassOpacity(self, classId: int, opacity: float) -> None:
        self._currentDesign().set_class(classId, opacity=opacity)
        self._updateRendering()

    def setClassVisible(self, classId: int, visible: bool) -> None:
        self._currentDesign().set_class(classId, visible=visible)
        self._updateRendering()

    def soloClass(self, classId: Optional[int]) -> None:
        self._currentDesign().solo(classId)
        self._updateRendering()

    def showAllClasses(self) -> None:
        self._currentDesign().show_all()
        self._updateRendering()

    def resetColors(self) -> None:
        self._currentDesign().reset_look()
        self._updateRendering()

    def exportTransferFunction(self, path: str) -> str:
        """Write the current transfer function: legacy ``.vp`` if the name ends so, else ``.vp.json``.

        Returns:
            The path written (``.vp.json`` appended when the name has neither extension).
        """
        design = self._currentDesign()
        if path.lower().endswith(".vp"):
            design.write_vp(path)
        else:
            if not path.lower().endswith(".json"):
                path += ".vp.json"
            design.write_vp_json(path)
        self.addLog(_("Transfer function written to {path}").format(path=path))
        return path

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
    """Tests of the module, on volumes built in memory (nothing is downloaded)."""

    def setUp(self):
        slicer.mrmlScene.Clear()

    def runTest(self):
        """Run every test_* method, each on a clean scene."""
        for test in (
            self.test_IsoSimilarityTF_options,
            self.test_IsoSimilarityTF_similarity_picture,
            self.test_IsoSimilarityTF_edit_and_export,
            self.test_IsoSimilarityTF_restore,
            self.test_IsoSimilarityTF_run,
            self.test_IsoSimilarityTF_cancel,
            self.test_IsoSimilarityTF_widget,
        ):
            self.setUp()
            test()

    # Helpers -----------------------------------------------------------------------------------------------------
    @staticmethod
    def _nestedVolume(size: int = 24) -> np.ndarray:
        """Float volume (k, j, i): background 0, a cube of 100, a ball of 300 inside, a small ball of 600."""
        k, j, i = np.mgrid[:size, :size, :size].astype(np.float32)
        centre = (size - 1) / 2.0
        radius2 = (i - centre) ** 2 + (j - centre) ** 2 + (k - centre) ** 2
        values = np.zeros((size, size, size), dtype=np.float32)
        values[3:-3, 3:-3, 3:-3] = 100.0
        values[radius2 < (size / 4.0) ** 2] = 300.0
        values[radius2 < (size / 10.0) ** 2] = 600.0
        return values

    def _volumeNode(self, name: str = "Nested"):
        volumeNode = slicer.util.addVolumeFromArray(self._nestedVolume(), name=name)
        volumeNode.SetSpacing(0.5, 0.5, 0.8)
        return volumeNode

    @staticmethod
    def _handMadeDesign():
        """A design made without affinity propagation (no scikit-learn needed): 64 bins over 0..640, 4 classes."""
        from IsoSimilarityTFLib import TransferFunctionDesign
        from IsoSimilarityTFLib.classes import build_classes
        from IsoSimilarityTFLib.tissues import tissue_hierarchy

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
            spacing=(0.5, 0.5, 0.8),
            similarity=similarity,
        )
        design.regroup("all")
        return design

    @staticmethod
    def _opacityAt(propertyNode, value: float) -> float:
        return propertyNode.GetVolumeProperty().GetScalarOpacity().GetValue(value)

    # Tests -------------------------------------------------------------------------------------------------------
    def test_IsoSimilarityTF_options(self):
        self.delayDisplay("Parameter node to engine options")
        logic = IsoSimilarityTFLogic()
        parameterNode = logic.getParameterNode()
        options = logic.designOptions(parameterNode)
        from IsoSimilarityTFLib.design import DEFAULT_OPTIONS

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
        self.assertEqual(logic.requirements(resourcePath("requirements.txt"))[0].split(">")[0], "scikit-learn")
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_similarity_picture(self):
        self.delayDisplay("Similarity picture")
        design = self._handMadeDesign()
        picture = IsoSimilarityTFLogic.similarityImage(design, 128)
        self.assertEqual(picture.shape, (128, 128, 3))
        self.assertEqual(picture.dtype, np.uint8)
        pixmap = IsoSimilarityTFWidget._pixmapFromArray(IsoSimilarityTFLogic.similarityImage(design, 256))
        self.assertEqual((pixmap.width(), pixmap.height()), (256, 256))
        design.similarity = None
        self.assertIsNone(IsoSimilarityTFLogic.similarityImage(design))
        self.assertIn("total", IsoSimilarityTFLogic.timingsText(self._handMadeDesign()))
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_edit_and_export(self):
        self.delayDisplay("Class edits rewrite the transfer function in place; export")
        import tempfile

        from IsoSimilarityTFLib import read_vp, read_vp_json

        volumeNode = self._volumeNode()
        logic = IsoSimilarityTFLogic()
        design = self._handMadeDesign()
        propertyNode = logic.applyDesign(volumeNode, design)
        displayNode = logic.volumeRenderingLogic().GetFirstVolumeRenderingDisplayNode(volumeNode)
        self.assertIsNotNone(displayNode)
        self.assertIs(displayNode.GetVolumePropertyNode(), propertyNode)

        background = design.background_class
        self.assertIsNotNone(background)
        self.assertEqual(self._opacityAt(propertyNode, 40.0), 0.0)  # background hidden
        top = design.classes[-1]  # bins 48..63: values 480..640
        volumeProperty = propertyNode.GetVolumeProperty()
        logic.setClassOpacity(top.id, 0.75)
        self.assertIs(propertyNode.GetVolumeProperty(), volumeProperty)  # edited in place, not replaced
        self.assertAlmostEqual(self._opacityAt(propertyNode, 560.0), 0.75, places=6)
        logic.setClassColor(top.id, (0.0, 0.0, 1.0))
        rgb = propertyNode.GetVolumeProperty().GetRGBTransferFunction().GetColor(560.0)
        self.assertAlmostEqual(rgb[2], 1.0, places=6)
        logic.setClassVisible(top.id, False)
        self.assertEqual(self._opacityAt(propertyNode, 560.0), 0.0)
        logic.soloClass(top.id)
        self.assertAlmostEqual(self._opacityAt(propertyNode, 560.0), 0.75, places=6)
        self.assertEqual(self._opacityAt(propertyNode, 250.0), 0.0)
        logic.soloClass(None)
        logic.showAllClasses()
        self.assertGreater(self._opacityAt(propertyNode, 250.0), 0.0)
        self.assertGreater(self._opacityAt(propertyNode, 560.0), 0.0)
        logic.resetColors()
        self.assertNotAlmostEqual(propertyNode.GetVolumeProperty().GetRGBTransferFunction().GetColor(560.0)[2], 1.0)

        with tempfile.TemporaryDirectory() as folder:
            written = logic.exportTransferFunction(os.path.join(folder, "tf"))
            self.assertTrue(written.endswith(".vp.json"))
            exported, effectiveRange = read_vp_json(written)
            self.assertAlmostEqual(exported.GetScalarOpacity().GetValue(560.0), self._opacityAt(propertyNode, 560.0))
            self.assertEqual(effectiveRange, (0.0, 640.0))
            legacy = logic.exportTransferFunction(os.path.join(folder, "tf.vp"))
            self.assertAlmostEqual(
                read_vp(legacy).GetScalarOpacity().GetValue(250.0), self._opacityAt(propertyNode, 250.0)
            )
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_restore(self):
        self.delayDisplay("A design is restored from its property node")
        volumeNode = self._volumeNode()
        logic = IsoSimilarityTFLogic()
        design = self._handMadeDesign()
        propertyNode = logic.applyDesign(volumeNode, design)
        logic.setClassOpacity(design.classes[2].id, 0.33)

        otherLogic = IsoSimilarityTFLogic()
        restored = otherLogic.restoreDesign(volumeNode)
        self.assertIsNotNone(restored)
        self.assertIs(otherLogic.propertyNode, propertyNode)
        self.assertEqual(len(restored.classes), len(design.classes))
        self.assertAlmostEqual(restored.classes[2].opacity, 0.33)
        self.assertIsNone(restored.similarity)  # not stored with the node
        # The same logic keeps the similarity matrix of its own run, also after showing another volume.
        self.assertIsNotNone(logic.restoreDesign(volumeNode).similarity)
        self.assertIsNone(logic.restoreDesign(self._volumeNode("Third")))
        self.assertIsNotNone(logic.restoreDesign(volumeNode).similarity)
        # A volume without a design restores nothing.
        self.assertIsNone(otherLogic.restoreDesign(self._volumeNode("Other")))
        self.assertIsNone(otherLogic.design)
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_run(self):
        self.delayDisplay("Full run on a volume built in memory")
        if not IsoSimilarityTFLogic.scikitLearnAvailable():
            self.delayDisplay("scikit-learn is not installed: full run skipped")
            return
        volumeNode = self._volumeNode()
        logic = IsoSimilarityTFLogic()
        messages = []
        logic.logCallback = messages.append
        stages = []
        parameterNode = logic.getParameterNode()
        parameterNode.bins = 64
        parameterNode.levels = 99  # more than the volume has: all are used
        design = logic.run(volumeNode, logic.designOptions(parameterNode), progress=lambda s, f, m: stages.append(s))
        self.assertGreaterEqual(len(design.classes), 2)
        self.assertEqual(design.n_bins, 64)
        self.assertEqual(set(design.timings_s), {"quantize", "similarity", "clustering", "classes"})
        self.assertEqual(stages[0], "quantize")
        self.assertIn("classes", stages)
        self.assertTrue(messages)
        displayNode = logic.volumeRenderingLogic().GetFirstVolumeRenderingDisplayNode(volumeNode)
        self.assertIs(displayNode.GetVolumePropertyNode(), logic.propertyNode)
        self.assertEqual(IsoSimilarityTFLogic.similarityImage(design, 64).shape, (64, 64, 3))
        # Running again reuses the property node made for the volume.
        propertyNode = logic.propertyNode
        logic.run(volumeNode, {"n_bins": 32})
        self.assertIs(logic.propertyNode, propertyNode)
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_cancel(self):
        self.delayDisplay("Cancelling leaves the scene untouched")
        volumeNode = self._volumeNode()
        logic = IsoSimilarityTFLogic()
        propertyNodes = slicer.mrmlScene.GetNumberOfNodesByClass("vtkMRMLVolumePropertyNode")

        def cancel(stage, fraction, message):
            if stage == "similarity":
                raise IsoSimilarityTFCancelled()

        with self.assertRaises(IsoSimilarityTFCancelled):
            logic.run(volumeNode, {"n_bins": 32}, progress=cancel)
        self.assertIsNone(logic.design)
        self.assertEqual(slicer.mrmlScene.GetNumberOfNodesByClass("vtkMRMLVolumePropertyNode"), propertyNodes)
        self.delayDisplay("Test passed")

    def test_IsoSimilarityTF_widget(self):
        self.delayDisplay("The panel shows the design of the selected volume")
        module = getattr(slicer.modules, "isosimilaritytf", None)
        if module is None:
            self.delayDisplay("Module not loaded in this application: widget test skipped")
            return
        widget = module.widgetRepresentation().self()
        volumeNode = self._volumeNode()
        widget.logic.applyDesign(volumeNode, self._handMadeDesign())
        otherVolume = self._volumeNode("Other")
        widget.enter()
        widget._parameterNode.inputVolume = otherVolume
        self.assertEqual(widget.ui.classesTableWidget.rowCount, 0)
        widget._parameterNode.inputVolume = volumeNode
        self.assertEqual(widget.ui.classesTableWidget.rowCount, 4)
        # An edit in the table reaches the volume property.
        top = widget.logic.design.classes[-1]
        widget._rowWidgets[top.id]["opacity"].value = 40
        self.assertAlmostEqual(self._opacityAt(widget.logic.propertyNode, 560.0), 0.40, places=6)
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
        widget.exit()
        self.delayDisplay("Test passed")
