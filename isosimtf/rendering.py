"""Headless Slicer volume rendering: a real MRML scene and Slicer's own volume rendering, rendered off-screen.

This module stands up the Qt-free part of 3D Slicer that PyPI's ``slicer-core`` ships (MRML scene, application
logic, ``vtkSlicerVolumeRenderingLogic`` and the volume rendering displayable manager) in an off-screen 3D view, so
that the command-line tool and the tests render exactly what Slicer's 3D view renders, with no Qt and no Slicer
application. ``slicer-core`` (and the ``vtk`` it pins) is imported lazily: importing this module never needs it, only
using :class:`HeadlessSlicer` or :func:`render_volume` does, and then a missing ``slicer-core`` raises a
:class:`RuntimeError` that says how to install it.

Off-screen rendering: set the environment variable ``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow`` on a machine
without a display (this module sets it when it is unset and no ``DISPLAY`` exists, before VTK is first loaded).

Coordinates: volumes are placed in Slicer's RAS world (millimetres); ``values`` arrays are indexed ``[k, j, i]``
(slice, row, column = z, y, x), like ``slicer.util.arrayFromVolume``.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .read_errors import captured_native_output, captured_vtk_messages, first_message

if TYPE_CHECKING:  # pragma: no cover - typing only
    from vtkmodules.vtkRenderingCore import vtkVolume, vtkVolumeProperty

__all__ = [
    "BACKDROPS",
    "DEFAULT_RENDERING_METHOD",
    "LOOKUP_TABLE_FALLBACK",
    "LOOKUP_TABLE_LIMIT",
    "RAY_CASTING",
    "VIEW_DIRECTIONS",
    "HeadlessSlicer",
    "captured_vtk_messages",
    "content_box",
    "frame_content",
    "lookup_table_fallbacks",
    "lookup_table_width",
    "render_volume",
    "slicer_core_available",
    "write_png",
]

#: Rendering method pinned by default: CPU ray casting gives reproducible pictures (GPU ray casting differs from it
#: at small voxel spacing, a known Slicer behaviour).
DEFAULT_RENDERING_METHOD = "vtkMRMLCPURayCastVolumeRenderingDisplayNode"

#: View directions accepted by :meth:`HeadlessSlicer.render`, as names of ``vtkMRMLCameraNode`` axis constants.
#: "anterior" puts the camera in front of the patient (looking towards posterior), like Slicer's "A" view button.
VIEW_DIRECTIONS = {
    "anterior": "Anterior",
    "posterior": "Posterior",
    "left": "Left",
    "right": "Right",
    "superior": "Superior",
    "inferior": "Inferior",
}

#: View angle of a new Slicer 3D view's camera, in degrees (``vtkMRMLCameraNode``, like ``vtkCamera``).
DEFAULT_VIEW_ANGLE = 30.0

_RENDERING_METHODS = (
    "vtkMRMLCPURayCastVolumeRenderingDisplayNode",
    "vtkMRMLGPURayCastVolumeRenderingDisplayNode",
    "vtkMRMLMultiVolumeRenderingDisplayNode",
)

#: Short names of the ray casters (the ``--ray-casting`` option) -> volume rendering display node class. GPU ray
#: casting runs headless too (OpenGL through EGL; with Mesa's llvmpipe it runs on the CPU cores).
RAY_CASTING = {
    "cpu": "vtkMRMLCPURayCastVolumeRenderingDisplayNode",
    "gpu": "vtkMRMLGPURayCastVolumeRenderingDisplayNode",
}

#: 3D view backdrops (the ``--backdrop`` option): "black" (uniform, the default of our pictures) or "slicer" (the
#: blue gradient a new Slicer 3D view starts with: ``vtkMRMLViewNode::defaultBackgroundColor()`` (light, at the
#: bottom) and ``defaultBackgroundColor2()`` (darker, at the top), read from a new slicer-core view node at run time).
BACKDROPS = ("black", "slicer")

#: Start of the warning VTK's GPU ray caster logs (``vtkOpenGLVolumeLookupTable::GetMaximumSupportedTextureWidth``)
#: when a transfer function needs a lookup table wider than the OpenGL texture limit (16384 with Mesa): the table is
#: then cut to the limit and narrow steps of the transfer function are lost or misplaced.
LOOKUP_TABLE_FALLBACK = "does not support the required texture size"

# Presets that vtkSlicerVolumeRenderingLogic looks up by name. "US-Fetal" is mandatory: SetRecommendedVolumeRendering-
# Properties (run by CreateDefaultVolumeRenderingNodes) copies it unchecked for 8-bit volumes and crashes when it is
# missing. "MR-Default" and "CT-Chest-Contrast-Enhanced" are only used when present; they are left out, so a new
# display node of a non-8-bit volume keeps the transfer function the logic derives from the volume's window/level.
# This ramp is written for this project, it is not Slicer's preset: pass ``presets_file`` to use Slicer's own
# presets.xml when one is at hand.
_MINIMAL_PRESETS = {
    # name: (scalar opacity points (x, a), colour points (x, r, g, b))
    "US-Fetal": (
        ((0.0, 0.0), (40.0, 0.0), (160.0, 0.6), (255.0, 0.9)),
        ((0.0, 0.0, 0.0, 0.0), (80.0, 0.6, 0.35, 0.25), (180.0, 0.95, 0.8, 0.65), (255.0, 1.0, 1.0, 1.0)),
    ),
}


def slicer_core_available() -> bool:
    """Return True when ``slicer-core`` can be imported (without importing it when it is missing)."""
    import importlib.util

    try:
        return importlib.util.find_spec("slicer_core") is not None
    except (ImportError, ValueError):
        return False


def _prepare_offscreen_environment() -> None:
    """Select VTK's EGL render window when there is no X display, before VTK's rendering classes are loaded."""
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def _import_slicer() -> Any:
    """Import and return the ``slicer`` package of ``slicer-core``; raise RuntimeError with advice when missing."""
    _prepare_offscreen_environment()
    try:
        import slicer
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise RuntimeError(
            "Headless Slicer rendering needs the 'slicer-core' package (Slicer's Qt-free MRML libraries): "
            "pip install 'isosimilaritytf[slicer]' or pip install slicer-core"
        ) from exc
    if not hasattr(slicer, "vtkSlicerVolumeRenderingLogic"):
        raise RuntimeError(
            "The imported 'slicer' module has no vtkSlicerVolumeRenderingLogic: install PyPI's 'slicer-core' "
            "(inside the Slicer application use slicer.modules.volumerendering.logic() instead of this module)"
        )
    return slicer


def _function_string(points: Sequence[Sequence[float]]) -> str:
    """Serialize points as Slicer's presets.xml does: the number of values, then the values."""
    values = [float(v) for point in points for v in point]
    return " ".join([str(len(values))] + [repr(v) for v in values])


def _write_minimal_presets(directory: Path) -> Path:
    """Write a minimal ``presets.xml`` (an MRML scene of VolumeProperty elements) into ``directory``."""
    elements = []
    for index, (name, (opacity, colors)) in enumerate(_MINIMAL_PRESETS.items(), start=1):
        elements.append(
            f'<VolumeProperty id="vtkMRMLVolumePropertyNode{index}" name="{name}" interpolation="1" shade="1" '
            'diffuse="0.6" ambient="0.3" specular="0.5" specularPower="40" '
            f'scalarOpacity="{_function_string(opacity)}" gradientOpacity="4 0 1 255 1" '
            f'colorTransfer="{_function_string(colors)}"></VolumeProperty>'
        )
    text = (
        '<?xml version="1.0" encoding="UTF-8"?>\n<MRML version="Slicer4.4.0">\n' + "\n".join(elements) + "\n</MRML>\n"
    )
    path = directory / "presets.xml"
    path.write_text(text, encoding="utf-8")
    return path


def _as_vtk_matrix(matrix: Any) -> Any:
    """Return a vtkMatrix4x4 from a vtkMatrix4x4 or a 4x4 array-like."""
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    if isinstance(matrix, vtkMatrix4x4):
        return matrix
    array = np.asarray(matrix, dtype=np.float64)
    if array.shape != (4, 4):
        raise ValueError(f"ijk_to_ras must be 4x4, got shape {array.shape}")
    result = vtkMatrix4x4()
    for row in range(4):
        for column in range(4):
            result.SetElement(row, column, float(array[row, column]))
    return result


def copy_volume_property(source: vtkVolumeProperty, target: vtkVolumeProperty) -> None:
    """Copy transfer functions and shading of ``source`` into ``target`` in place (component 0).

    The function objects of ``target`` are kept (their points are replaced), so observers that a
    ``vtkMRMLVolumePropertyNode`` holds on them stay valid.
    """
    target.GetRGBTransferFunction().DeepCopy(source.GetRGBTransferFunction())
    target.GetScalarOpacity().DeepCopy(source.GetScalarOpacity())
    target.GetGradientOpacity().DeepCopy(source.GetGradientOpacity())
    target.SetDisableGradientOpacity(source.GetDisableGradientOpacity())
    target.SetScalarOpacityUnitDistance(source.GetScalarOpacityUnitDistance())
    target.SetInterpolationType(source.GetInterpolationType())
    target.SetShade(source.GetShade())
    target.SetAmbient(source.GetAmbient())
    target.SetDiffuse(source.GetDiffuse())
    target.SetSpecular(source.GetSpecular())
    target.SetSpecularPower(source.GetSpecularPower())
    target.SetIndependentComponents(source.GetIndependentComponents())


def content_box(
    picture: np.ndarray, backdrop: np.ndarray | None = None, threshold: int = 10
) -> tuple[int, int, int, int] | None:
    """Bounding box of the content of a picture: the pixels that differ from the backdrop.

    Args:
        picture: ``(height, width, 3)`` uint8 RGB.
        backdrop: the empty view, same shape (or an RGB colour broadcast to it); black when None.
        threshold: a pixel is content when a channel differs from the backdrop by more than this (0..255).

    Returns:
        ``(row0, row1, column0, column1)``, inclusive, or None when the picture shows nothing.
    """
    image = np.asarray(picture, dtype=np.int16)
    reference = np.zeros(3, np.int16) if backdrop is None else np.asarray(backdrop, dtype=np.int16)
    content = np.abs(image - reference).max(axis=2) > threshold
    rows = np.flatnonzero(content.any(axis=1))
    columns = np.flatnonzero(content.any(axis=0))
    if rows.size == 0:
        return None
    return int(rows[0]), int(rows[-1]), int(columns[0]), int(columns[-1])


def frame_content(
    camera: Any,
    picture: np.ndarray,
    margin: float = 0.04,
    *,
    backdrop: np.ndarray | None = None,
    box: tuple[int, int, int, int] | None = None,
) -> bool:
    """Narrow a ``vtkCamera`` so that what ``picture`` (rendered with it) shows fills the view, plus a margin.

    The camera keeps its position and direction: its view angle shrinks and its window centre moves onto the
    content, so the content fills the picture and pictures rendered next with this camera share one framing.

    Args:
        camera: the ``vtkCamera`` the picture was rendered with.
        picture: ``(height, width, 3)`` uint8 RGB.
        margin: free border, as a share of the content's larger side.
        backdrop: the empty view (see :func:`content_box`); black when None.
        box: the content box to frame (e.g. a union over several pictures) instead of the picture's own.

    Returns:
        True when the camera was changed (False: nothing shown, or the content already fills the picture).
    """
    box = box if box is not None else content_box(picture, backdrop)
    if box is None:
        return False
    height, width = picture.shape[:2]
    row0, row1, column0, column1 = box
    side = max(row1 - row0 + 1, column1 - column0 + 1) * (1.0 + margin)
    factor = min(width, height) / side
    if factor <= 1.0:
        return False
    # Content centre in normalized device coordinates (-1..1, y up), before zooming.
    centre_x = (column0 + column1 + 1) / width - 1.0
    centre_y = 1.0 - (row0 + row1 + 1) / height
    old_x, old_y = camera.GetWindowCenter()
    half_angle = math.radians(camera.GetViewAngle()) / 2.0
    camera.SetViewAngle(math.degrees(2.0 * math.atan(math.tan(half_angle) / factor)))
    camera.SetWindowCenter((old_x + centre_x) * factor, (old_y + centre_y) * factor)
    return True


#: Widest lookup table (texels) Mesa's OpenGL takes (``GL_MAX_TEXTURE_SIZE`` of llvmpipe); desktop GPUs take 16384 or
#: 32768. A transfer function whose :func:`lookup_table_width` stays within it renders without the fallback.
LOOKUP_TABLE_LIMIT = 16384


def lookup_table_width(volume_property: vtkVolumeProperty, scalar_range: Sequence[float]) -> int:
    """Width of the colour / opacity lookup table VTK's GPU ray caster asks for, without rendering.

    As ``vtkOpenGLVolumeLookupTable`` does: the functions' ``EstimateMinNumberOfSamples`` over the volume's scalar
    range (the range divided by the smallest distance between points), rounded up to a power of two, at least 1024.
    A near-vertical step (points 0.004 HU apart over a 4000 HU range) asks for 1048576; above the OpenGL limit
    (:data:`LOOKUP_TABLE_LIMIT`) VTK logs :data:`LOOKUP_TABLE_FALLBACK` and cuts the table.

    Args:
        volume_property: a ``vtkVolumeProperty`` (component 0 is checked).
        scalar_range: ``(low, high)`` of the volume's values.
    """
    low, high = float(scalar_range[0]), float(scalar_range[1])
    samples = max(
        volume_property.GetRGBTransferFunction().EstimateMinNumberOfSamples(low, high),
        volume_property.GetScalarOpacity().EstimateMinNumberOfSamples(low, high),
        1,
    )
    return max(1024, 1 << (int(samples) - 1).bit_length())


def lookup_table_fallbacks(messages: Sequence[str]) -> list[str]:
    """The GPU ray caster's lookup-table fallback warnings among ``messages`` (see :data:`LOOKUP_TABLE_FALLBACK`)."""
    return [message for message in messages if LOOKUP_TABLE_FALLBACK in message]


class HeadlessSlicer:
    """Real MRML scene + application logic + volume rendering logic + an off-screen 3D view.

    Nothing of Qt or of the Slicer application is used: the scene, ``vtkSlicerApplicationLogic``, the colour logic,
    ``vtkSlicerVolumeRenderingLogic`` (:attr:`volume_rendering_logic`, usable like
    ``slicer.modules.volumerendering.logic()`` in Slicer) and a 3D view (:attr:`view_node`, a ``vtkMRMLViewNode``
    driven by Slicer's displayable managers into an off-screen ``vtkRenderWindow``).

    Args:
        size: picture size ``(width, height)`` in pixels.
        rendering_method: volume rendering display node class used for new display nodes, or a short name of
            :data:`RAY_CASTING` ("cpu", "gpu"); CPU ray casting (default) gives reproducible pictures.
        background: view background colour ``(r, g, b)`` in 0..1 (uniform, no gradient); Slicer's default blue
            gradient when None (see :data:`BACKDROPS`).
        presets_file: a Slicer ``presets.xml`` to load as the volume rendering presets; when None a minimal presets
            file is generated in a temporary folder (see the module notes).

    Use as a context manager, or call :meth:`close` when done.
    """

    def __init__(
        self,
        size: tuple[int, int] = (512, 512),
        rendering_method: str = DEFAULT_RENDERING_METHOD,
        *,
        background: tuple[float, float, float] | None = (0.0, 0.0, 0.0),
        presets_file: str | os.PathLike | None = None,
    ) -> None:
        rendering_method = RAY_CASTING.get(rendering_method, rendering_method)
        if rendering_method not in _RENDERING_METHODS:
            raise ValueError(f"rendering_method must be one of {_RENDERING_METHODS}, got {rendering_method!r}")
        if len(size) != 2 or int(size[0]) < 1 or int(size[1]) < 1:
            raise ValueError(f"size must be (width, height) with positive values, got {size!r}")
        slicer = _import_slicer()
        # Loads the OpenGL2 implementations of the rendering classes (object factory overrides).
        import vtkmodules.vtkRenderingOpenGL2
        import vtkmodules.vtkRenderingVolumeOpenGL2  # noqa: F401
        from vtkmodules.vtkCommonCore import vtkCollection
        from vtkmodules.vtkRenderingCore import vtkRenderer, vtkRenderWindow, vtkRenderWindowInteractor

        self._slicer = slicer
        self._closed = False
        self._size = (int(size[0]), int(size[1]))
        self.rendering_method = rendering_method

        # --- scene and application logic (what qSlicerCoreApplication sets up, minus Qt)
        self.scene = slicer.vtkMRMLScene()
        self.app_logic = slicer.vtkSlicerApplicationLogic()
        self.app_logic.SetMRMLScene(self.scene)
        self.app_logic.SetViewLogics(vtkCollection())
        self.app_logic.SetSliceLogics(vtkCollection())
        self.color_logic = self.app_logic.GetColorLogic()
        if self.color_logic is None:  # pragma: no cover - slicer-core versions without a built-in colour logic
            self.color_logic = slicer.vtkMRMLColorLogic()
            self.app_logic.SetColorLogic(self.color_logic)
        self.color_logic.SetMRMLApplicationLogic(self.app_logic)
        self.color_logic.SetMRMLScene(self.scene)
        self.color_logic.AddDefaultColorNodes()  # grey colour table used by new scalar volume display nodes
        self.app_logic.SetModuleLogic("Colors", self.color_logic)

        # --- volume rendering logic, with a presets file so that CreateDefaultVolumeRenderingNodes is safe
        self.volume_rendering_logic = slicer.vtkSlicerVolumeRenderingLogic()
        self.volume_rendering_logic.SetMRMLApplicationLogic(self.app_logic)
        self.volume_rendering_logic.SetMRMLScene(self.scene)
        if presets_file is not None and not Path(presets_file).is_file():
            raise FileNotFoundError(f"presets file not found: {Path(presets_file)}")
        if presets_file is not None and Path(presets_file).name == "presets.xml":
            self.volume_rendering_logic.SetModuleShareDirectory(str(Path(presets_file).parent))
            loaded = self.volume_rendering_logic.GetPresetByName("US-Fetal") is not None
        else:
            # The logic reads presets.xml once, into its presets scene (GetPresetsScene): our copy goes at once, so
            # that no temporary folder outlives a render process that is killed.
            with tempfile.TemporaryDirectory(prefix="isosimtf_vr_") as presets_dir:
                if presets_file is not None:
                    shutil.copyfile(presets_file, Path(presets_dir) / "presets.xml")
                else:
                    _write_minimal_presets(Path(presets_dir))
                self.volume_rendering_logic.SetModuleShareDirectory(presets_dir)
                loaded = self.volume_rendering_logic.GetPresetByName("US-Fetal") is not None
        if not loaded:
            raise RuntimeError("volume rendering presets could not be loaded (no 'US-Fetal' preset)")
        self.volume_rendering_logic.SetDefaultRenderingMethod(rendering_method)
        self.app_logic.SetModuleLogic("VolumeRendering", self.volume_rendering_logic)

        # --- off-screen 3D view. The interactor must exist before the view node is attached (else a crash).
        self.renderer = vtkRenderer()
        self.render_window = vtkRenderWindow()
        self.render_window.SetOffScreenRendering(1)
        self.render_window.SetMultiSamples(0)
        self.render_window.SetSize(*self._size)
        self.render_window.AddRenderer(self.renderer)
        self.interactor = vtkRenderWindowInteractor()
        self.interactor.SetRenderWindow(self.render_window)

        factory = slicer.vtkMRMLThreeDViewDisplayableManagerFactory.GetInstance()
        factory.SetMRMLApplicationLogic(self.app_logic)
        for manager in (
            "vtkMRMLCameraDisplayableManager",
            "vtkMRMLViewDisplayableManager",
            "vtkMRMLVolumeRenderingDisplayableManager",
        ):
            if not factory.IsDisplayableManagerRegistered(manager):
                factory.RegisterDisplayableManager(manager)
        self.displayable_manager_group = slicer.vtkMRMLDisplayableManagerGroup()
        self.displayable_manager_group.Initialize(factory, self.renderer)

        self.view_logic = slicer.vtkMRMLViewLogic()
        self.view_logic.SetMRMLApplicationLogic(self.app_logic)
        self.app_logic.GetViewLogics().AddItem(self.view_logic)
        self.view_logic.SetMRMLScene(self.scene)
        self.view_node = self.view_logic.AddViewNode("1")
        self._background = None if background is None else tuple(float(c) for c in background)
        self._apply_view_settings()
        self.displayable_manager_group.SetMRMLDisplayableNode(self.view_node)

    # ------------------------------------------------------------------ context manager
    def __enter__(self) -> HeadlessSlicer:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def size(self) -> tuple[int, int]:
        """Picture size ``(width, height)`` in pixels."""
        return self._size

    @property
    def camera_node(self) -> Any:
        """The ``vtkMRMLCameraNode`` of the 3D view (None before the camera displayable manager made one)."""
        self._check_open()
        manager = self.displayable_manager_group.GetDisplayableManagerByClassName("vtkMRMLCameraDisplayableManager")
        return manager.GetCameraNode() if manager is not None else None

    def _apply_view_settings(self) -> None:
        """Hide the bounding box and axis labels, set the background (again after a scene clear resets them)."""
        view_node = self.view_node
        modifying = view_node.StartModify()
        view_node.SetBoxVisible(False)
        view_node.SetAxisLabelsVisible(False)
        if self._background is not None:
            view_node.SetBackgroundColor(*self._background)
            view_node.SetBackgroundColor2(*self._background)
        else:
            # A new view node holds Slicer's defaults (the static defaultBackgroundColor() is not wrapped usably).
            defaults = self._slicer.vtkMRMLViewNode()
            view_node.SetBackgroundColor(*defaults.GetBackgroundColor())
            view_node.SetBackgroundColor2(*defaults.GetBackgroundColor2())
        view_node.EndModify(modifying)

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("this HeadlessSlicer is closed")

    # ------------------------------------------------------------------ data
    def add_volume(
        self,
        values: np.ndarray,
        spacing: Sequence[float] = (1.0, 1.0, 1.0),
        origin: Sequence[float] = (0.0, 0.0, 0.0),
        name: str = "Volume",
        ijk_to_ras: Any = None,
    ) -> Any:
        """Add a scalar volume to the scene, like ``slicer.util.addVolumeFromArray``.

        Args:
            values: 3-D array indexed ``[k, j, i]`` (z, y, x); its dtype is kept (bool becomes uint8).
            spacing: voxel size ``(i, j, k)`` = (x, y, z) in millimetres.
            origin: RAS position of voxel (0, 0, 0) in millimetres.
            name: node name (made unique in the scene).
            ijk_to_ras: optional 4x4 IJK-to-RAS matrix (array-like or vtkMatrix4x4); overrides spacing and origin.

        Returns:
            the new ``vtkMRMLScalarVolumeNode``, with a default scalar volume display node (grey, auto window/level).
        """
        self._check_open()
        from vtkmodules.util import numpy_support
        from vtkmodules.vtkCommonDataModel import vtkImageData

        array = np.asarray(values)
        if array.ndim != 3:
            raise ValueError(f"values must be a 3-D array indexed [k, j, i], got shape {array.shape}")
        if array.dtype == np.bool_:
            array = array.astype(np.uint8)
        if array.dtype.byteorder not in ("=", "|"):
            array = array.astype(array.dtype.newbyteorder("="))
        if len(spacing) != 3 or len(origin) != 3:
            raise ValueError("spacing and origin must have 3 values (x, y, z)")
        array = np.ascontiguousarray(array)
        image = vtkImageData()
        image.SetDimensions(array.shape[2], array.shape[1], array.shape[0])
        scalars = numpy_support.numpy_to_vtk(array.ravel(), deep=True)
        scalars.SetName("ImageScalars")
        image.GetPointData().SetScalars(scalars)

        volume_node = self.scene.AddNewNodeByClass("vtkMRMLScalarVolumeNode", self.scene.GenerateUniqueName(name))
        if ijk_to_ras is not None:
            volume_node.SetIJKToRASMatrix(_as_vtk_matrix(ijk_to_ras))
        else:
            volume_node.SetSpacing(*(float(s) for s in spacing))
            volume_node.SetOrigin(*(float(o) for o in origin))
        volume_node.SetAndObserveImageData(image)
        volume_node.CreateDefaultDisplayNodes()
        return volume_node

    def show_volume(self, volume_node: Any, property_node: Any = None) -> Any:
        """Make sure ``volume_node`` has a volume rendering display node that is visible in this view.

        The display node is the volume's first one, or made by ``CreateDefaultVolumeRenderingNodes`` (as in Slicer).

        Args:
            volume_node: a ``vtkMRMLScalarVolumeNode`` of this scene.
            property_node: optional ``vtkMRMLVolumePropertyNode`` to show (added to the scene when it is not in it).

        Returns:
            the ``vtkMRMLVolumeRenderingDisplayNode``.
        """
        self._check_open()
        logic = self.volume_rendering_logic
        display_node = logic.GetFirstVolumeRenderingDisplayNode(volume_node)
        if display_node is None:
            display_node = logic.CreateDefaultVolumeRenderingNodes(volume_node)
        if display_node is None:
            raise RuntimeError(f"could not create a volume rendering display node for {volume_node.GetName()!r}")
        if property_node is not None:
            if property_node.GetScene() is None:
                self.scene.AddNode(property_node)
            display_node.SetAndObserveVolumePropertyNodeID(property_node.GetID())
        view_id = self.view_node.GetID()
        if display_node.GetNumberOfViewNodeIDs() > 0 and not display_node.IsViewNodeIDPresent(view_id):
            display_node.AddViewNodeID(view_id)
        display_node.SetVisibility(True)
        return display_node

    def add_volume_property(self, volume_property: vtkVolumeProperty, name: str = "VolumeProperty") -> Any:
        """Add a ``vtkMRMLVolumePropertyNode`` holding a copy of ``volume_property`` to the scene.

        The node's effective range is set to the colour transfer function's range, so the points all show in
        Slicer's transfer function editor.
        """
        self._check_open()
        node = self.scene.AddNewNodeByClass("vtkMRMLVolumePropertyNode", self.scene.GenerateUniqueName(name))
        copy_volume_property(volume_property, node.GetVolumeProperty())
        low, high = volume_property.GetRGBTransferFunction().GetRange()
        if high > low:
            node.SetEffectiveRange(low, high)
        return node

    # ------------------------------------------------------------------ rendering
    def get_volume_actor(self, volume_node: Any) -> vtkVolume | None:
        """The ``vtkVolume`` the volume rendering displayable manager renders for ``volume_node`` (or None).

        Its ``GetProperty()`` is the ``vtkVolumeProperty`` of the display node's volume property node. Call after
        :meth:`render` (or after the display node is visible).
        """
        self._check_open()
        # Displayable managers are looked up each time, never kept: a Python reference to one that outlives the
        # displayable manager group crashes when it is released.
        manager = self.displayable_manager_group.GetDisplayableManagerByClassName(
            "vtkMRMLVolumeRenderingDisplayableManager"
        )
        return manager.GetVolumeActor(volume_node) if manager is not None else None

    def rendered_volumes(self) -> list:
        """All visible ``vtkVolume`` props of the 3D view's renderer (after :meth:`render`)."""
        self._check_open()
        volumes = self.renderer.GetVolumes()
        volumes.InitTraversal()
        result = []
        for _ in range(volumes.GetNumberOfItems()):
            prop = volumes.GetNextVolume()
            if prop is not None and prop.GetVisibility():
                result.append(prop)
        return result

    def reset_camera(self) -> None:
        """Fit the camera to the visible props, keeping its direction (Slicer's "reset field of view").

        A narrowing left by ``render(frame=True)`` (view angle, window centre) is undone first.
        """
        self._check_open()
        camera = self.renderer.GetActiveCamera()
        camera.SetViewAngle(DEFAULT_VIEW_ANGLE)
        camera.SetWindowCenter(0.0, 0.0)
        self.renderer.ResetCamera()
        self.renderer.ResetCameraClippingRange()

    def render(self, view: str | None = "anterior", reset_camera: bool = True, *, frame: bool = False) -> np.ndarray:
        """Render the 3D view off-screen and return the picture.

        Args:
            view: camera direction, one of :data:`VIEW_DIRECTIONS` ("anterior", "posterior", "left", "right",
                "superior", "inferior"); None keeps the current camera.
            reset_camera: fit the camera to the volume after a first render (the volume's bounds are only known
                then). Disable to keep a camera that was set up by hand.
            frame: then narrow the camera onto what the picture shows (:func:`frame_content`) and render again, so
                the content fills the picture with a small margin (the camera stays narrowed afterwards).

        Returns:
            ``(height, width, 3)`` uint8 RGB array, row 0 at the top of the picture.
        """
        self._check_open()
        picture = self._render(view, reset_camera)
        if frame and self._frame(picture):
            picture = self._render(None, False)
        return picture

    def frame_camera(self, view: str | None = "anterior") -> None:
        """Point the camera (``view``), fit it to the volume and narrow it onto what the view shows, without rendering
        the framed picture: done in a small window, this frames the pictures rendered next (larger) at little cost.
        """
        self._check_open()
        self._frame(self._render(view, True))

    def _frame(self, picture: np.ndarray) -> bool:
        """Narrow the camera onto what ``picture`` shows (:func:`frame_content`); whether the camera changed."""
        camera_node = self.camera_node
        return camera_node is not None and frame_content(camera_node.GetCamera(), picture, backdrop=self.backdrop())

    def backdrop(self) -> np.ndarray:
        """The picture of the empty view (its backdrop): ``(height, width, 3)`` uint8, rendered with every volume
        hidden. Compare a picture with it to tell content from backdrop (:func:`content_box`)."""
        self._check_open()
        if self._background is not None:
            color = np.round(255.0 * np.clip(self._background, 0.0, 1.0)).astype(np.uint8)
            width, height = self.render_window.GetSize()  # the current size (it may have been changed)
            return np.broadcast_to(color, (height, width, 3)).copy()
        hidden = self.rendered_volumes()
        for prop in hidden:
            prop.SetVisibility(False)
        try:
            self.render_window.Render()
            return self._grab()
        finally:
            for prop in hidden:
                prop.SetVisibility(True)

    def _render(self, view: str | None, reset_camera: bool) -> np.ndarray:
        """Point the camera (``view``), render, fit the camera when asked, and return the picture."""
        self._apply_view_settings()
        camera_node = self.camera_node
        if view is not None:
            key = view.lower()
            if key not in VIEW_DIRECTIONS:
                raise ValueError(f"view must be one of {sorted(VIEW_DIRECTIONS)} or None, got {view!r}")
            if camera_node is not None:
                camera_node.RotateTo(getattr(self._slicer.vtkMRMLCameraNode, VIEW_DIRECTIONS[key]))
        self.render_window.Render()
        if reset_camera:
            self.reset_camera()
            self.render_window.Render()
        return self._grab()

    def _grab(self) -> np.ndarray:
        """The last rendered picture as ``(height, width, 3)`` uint8 RGB, row 0 at the top."""
        from vtkmodules.util import numpy_support
        from vtkmodules.vtkRenderingCore import vtkWindowToImageFilter

        grabber = vtkWindowToImageFilter()
        grabber.SetInput(self.render_window)
        grabber.SetInputBufferTypeToRGB()
        grabber.ReadFrontBufferOff()
        grabber.ShouldRerenderOff()
        grabber.Update()
        image = grabber.GetOutput()
        width, height, _ = image.GetDimensions()
        pixels = numpy_support.vtk_to_numpy(image.GetPointData().GetScalars())
        rgb = pixels.reshape(height, width, -1)[::-1, :, :3]
        return np.ascontiguousarray(rgb, dtype=np.uint8)

    # ------------------------------------------------------------------ teardown
    def close(self) -> None:
        """Detach the view, clear the scene and release every VTK object; safe to call more than once.

        After closing, :attr:`scene`, :attr:`volume_rendering_logic`, :attr:`view_node` etc. are None.
        """
        if self._closed:
            return
        self._closed = True
        try:
            self.displayable_manager_group.SetMRMLDisplayableNode(None)
            self.scene.Clear(0)
            self.app_logic.GetViewLogics().RemoveItem(self.view_logic)
            self.view_logic.SetMRMLScene(None)
            self.render_window.Finalize()
        finally:
            # Release the VTK objects from the view down to the scene (the order the view was built in, reversed).
            for attribute in (
                "displayable_manager_group",
                "view_logic",
                "view_node",
                "interactor",
                "render_window",
                "renderer",
                "volume_rendering_logic",
                "color_logic",
                "app_logic",
                "scene",
            ):
                setattr(self, attribute, None)


def render_volume(
    values: np.ndarray,
    spacing: Sequence[float],
    volume_property: vtkVolumeProperty,
    *,
    size: tuple[int, int] = (512, 512),
    view: str = "anterior",
    origin: Sequence[float] = (0.0, 0.0, 0.0),
    rendering_method: str = DEFAULT_RENDERING_METHOD,
) -> np.ndarray:
    """Render ``values`` once with ``volume_property`` in a headless Slicer 3D view.

    Args:
        values: 3-D array indexed ``[k, j, i]`` (z, y, x), in the volume's own units.
        spacing: voxel size ``(x, y, z)`` in millimetres.
        volume_property: the transfer function (copied into a ``vtkMRMLVolumePropertyNode``; not modified).
        size: picture size ``(width, height)`` in pixels.
        view: camera direction, see :data:`VIEW_DIRECTIONS`.
        origin: RAS position of voxel (0, 0, 0) in millimetres.
        rendering_method: volume rendering display node class (CPU ray casting by default).

    Returns:
        ``(height, width, 3)`` uint8 RGB picture.
    """
    with HeadlessSlicer(size=size, rendering_method=rendering_method) as headless:
        volume_node = headless.add_volume(values, spacing=spacing, origin=origin)
        property_node = headless.add_volume_property(volume_property, name=f"{volume_node.GetName()}_TF")
        headless.show_volume(volume_node, property_node)
        return headless.render(view)


def write_png(rgb: np.ndarray, path: str | os.PathLike) -> None:
    """Write an ``(height, width, 3)`` (or ``(height, width, 4)``) uint8 array to a PNG file with vtkPNGWriter.

    Row 0 of ``rgb`` is the top of the picture.
    """
    from vtkmodules.util import numpy_support
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkIOImage import vtkPNGWriter

    array = np.asarray(rgb)
    if array.ndim != 3 or array.shape[2] not in (3, 4):
        raise ValueError(f"rgb must have shape (height, width, 3 or 4), got {array.shape}")
    if array.dtype != np.uint8:
        raise ValueError(f"rgb must be uint8, got {array.dtype}")
    height, width, channels = array.shape
    flipped = np.ascontiguousarray(array[::-1])  # VTK images start at the bottom row
    image = vtkImageData()
    image.SetDimensions(width, height, 1)
    scalars = numpy_support.numpy_to_vtk(flipped.reshape(-1, channels), deep=True)
    image.GetPointData().SetScalars(scalars)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    writer = vtkPNGWriter()
    writer.SetFileName(os.fspath(path))
    writer.SetInputData(image)
    with captured_native_output() as texts:  # libpng and VTK print their failures (a full disk) themselves
        writer.Write()
    if writer.GetErrorCode():
        detail = first_message(texts) or f"VTK error code {writer.GetErrorCode()}"
        raise OSError(f"could not write PNG {path} ({detail})")
