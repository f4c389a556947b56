"""Step 6 of the pipeline: the piecewise-constant transfer function, as VTK objects and as Slicer files.

Files: Slicer's ``.vp.json`` (volume-property schema v1.0.0, the default since Slicer 5.10) and the legacy ``.vp``
text format (interpolation, shade, diffuse, ambient, specular, specular power, then scalar opacity, gradient opacity
and colour functions, each prefixed by its number of values: 2N, 2N and 4N for N points).
"""

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import numpy as np

from .errors import TransferFunctionFileError

VP_JSON_SCHEMA = (
    "https://raw.githubusercontent.com/slicer/slicer/main/Modules/Loadable/VolumeRendering/Resources/Schema/"
    "volume-property-schema-v1.0.0.json#"
)
# VTK's GPU ray caster samples each function into a lookup table of range / (smallest distance between two points)
# entries (vtkOpenGLVolumeLookupTable::ComputeIdealTextureSize via EstimateMinNumberOfSamples) and, past the
# OpenGL texture limit (8192-32768 here and there), warns and falls back to a table too coarse for the steps.
# A step between two bins is therefore a quarter of a bin, and never narrower than 1/4096 of the value range:
# at most 4096 entries for up to 1024 bins, under every OpenGL limit, and still sharp (a bin is 1/256 of the range).
MAX_TABLE_SIZE = 4096
STEP_BINS = 0.25

# Lighting like Slicer's CT presets: shaded, mostly diffuse.
AMBIENT, DIFFUSE, SPECULAR, SPECULAR_POWER = 0.2, 0.8, 0.2, 10.0

PathLike = Union[str, Path]


@dataclass(frozen=True)
class TransferFunctionPoints:
    """Control points shared by the colour and the opacity function.

    Attributes:
        x: ``(P,)`` positions in volume units, strictly increasing.
        color: ``(P, 3)`` RGB in 0..1.
        opacity: ``(P,)`` scalar opacity in 0..1.
    """

    x: np.ndarray
    color: np.ndarray
    opacity: np.ndarray

    def __call__(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Colour ``(..., 3)`` and opacity ``(...)`` at ``values``, interpolated linearly like VTK does."""
        values = np.asarray(values, dtype=np.float64)
        color = np.stack([np.interp(values, self.x, self.color[:, k]) for k in range(3)], axis=-1)
        return color, np.interp(values, self.x, self.opacity)


def piecewise_constant(edges: np.ndarray, bin_color: np.ndarray, bin_opacity: np.ndarray) -> TransferFunctionPoints:
    """Transfer function that is constant over each run of bins with the same look, with sharp steps between runs.

    Args:
        edges: ``(n_bins + 1,)`` bin edges in volume units, strictly increasing.
        bin_color: ``(n_bins, 3)`` RGB per bin.
        bin_opacity: ``(n_bins,)`` opacity per bin.
    """
    edges = np.asarray(edges, dtype=np.float64)
    look = np.column_stack([np.asarray(bin_color, dtype=np.float64), np.asarray(bin_opacity, dtype=np.float64)])
    starts = np.concatenate(([0], np.flatnonzero(np.any(look[1:] != look[:-1], axis=1)) + 1))
    ends = np.concatenate((starts[1:], [look.shape[0]]))
    step = step_width(edges)
    # Each run holds from its first edge to just before the next run's first edge (the last run to the top edge).
    x = np.column_stack([edges[starts], edges[ends] - step]).ravel()
    x[-1] = edges[-1]
    values = np.repeat(look[starts], 2, axis=0)
    return TransferFunctionPoints(x=x, color=values[:, :3], opacity=values[:, 3])


def step_width(edges: np.ndarray) -> float:
    """Width of a step between two neighbouring bins' looks, in volume units (see ``MAX_TABLE_SIZE``)."""
    value_range = float(edges[-1] - edges[0])
    bin_width = value_range / max(len(edges) - 1, 1)
    # Half a bin at most, so the points stay strictly increasing when more than 2048 bins make the table larger.
    return min(max(STEP_BINS * bin_width, value_range / MAX_TABLE_SIZE), 0.5 * bin_width)


def fill_volume_property(volume_property, points: TransferFunctionPoints) -> None:
    """Replace the colour and scalar opacity functions of a ``vtkVolumeProperty`` in place (other settings kept).

    The function objects are kept, so whoever observes them (a Slicer property node, a renderer) sees one change each.
    """
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
    from vtkmodules.vtkRenderingCore import vtkColorTransferFunction

    color_function = vtkColorTransferFunction()
    opacity_function = vtkPiecewiseFunction()
    for x, (r, g, b), a in zip(points.x.tolist(), points.color.tolist(), points.opacity.tolist()):
        color_function.AddRGBPoint(x, r, g, b)
        opacity_function.AddPoint(x, a)
    volume_property.GetRGBTransferFunction().DeepCopy(color_function)
    volume_property.GetScalarOpacity().DeepCopy(opacity_function)


def configure_volume_property(
    volume_property, unit_distance: float = 1.0, gradient_ramp_top: Optional[float] = None
) -> None:
    """Shading, lighting and interpolation of our transfer functions, and the gradient opacity.

    Args:
        unit_distance: scalar opacity unit distance in mm (1: opacity per millimetre, as in Slicer's presets).
        gradient_ramp_top: None for a constant gradient opacity of 1 (off, as in the presets); else the gradient
            magnitude (volume units per mm) from which it is 1, rising linearly from 0 at no gradient.
    """
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction

    gradient = vtkPiecewiseFunction()
    if gradient_ramp_top is None:
        gradient.AddPoint(0.0, 1.0)
        gradient.AddPoint(255.0, 1.0)
    else:
        gradient.AddPoint(0.0, 0.0)
        gradient.AddPoint(float(gradient_ramp_top), 1.0)
    volume_property.GetGradientOpacity().DeepCopy(gradient)
    volume_property.SetInterpolationTypeToLinear()
    volume_property.ShadeOn()
    volume_property.SetAmbient(AMBIENT)
    volume_property.SetDiffuse(DIFFUSE)
    volume_property.SetSpecular(SPECULAR)
    volume_property.SetSpecularPower(SPECULAR_POWER)
    volume_property.SetScalarOpacityUnitDistance(unit_distance)


def new_volume_property(
    points: TransferFunctionPoints, unit_distance: float = 1.0, gradient_ramp_top: Optional[float] = None
):
    """A new shaded ``vtkVolumeProperty`` with linear interpolation showing ``points`` (see
    :func:`configure_volume_property`)."""
    volume_property = _empty_volume_property()
    configure_volume_property(volume_property, unit_distance, gradient_ramp_top)
    fill_volume_property(volume_property, points)
    return volume_property


def _function_points(function, width: int) -> np.ndarray:
    values = [0.0] * (width + 3)  # position, value(s), midpoint, sharpness
    rows = []
    for index in range(function.GetSize()):
        function.GetNodeValue(index, values)
        rows.append(values[: width + 1])
    return np.array(rows, dtype=np.float64).reshape(-1, width + 1)


def points_of_volume_property(volume_property) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The control points of a ``vtkVolumeProperty``.

    Returns:
        ``(opacity, gradient_opacity, color)``: arrays of shape ``(N, 2)``, ``(M, 2)`` and ``(K, 4)``, each row a
        position followed by its value(s).
    """
    return (
        _function_points(volume_property.GetScalarOpacity(), 1),
        _function_points(volume_property.GetGradientOpacity(), 1),
        _function_points(volume_property.GetRGBTransferFunction(), 3),
    )


def _component_json(volume_property) -> dict:
    opacity, gradient, color = points_of_volume_property(volume_property)

    def scalar_points(rows):
        return [{"x": x, "y": y, "midpoint": 0.5, "sharpness": 0.0} for x, y in rows.tolist()]

    return {
        "componentWeight": 1.0,
        "shade": bool(volume_property.GetShade()),
        "lighting": {
            "diffuse": volume_property.GetDiffuse(),
            "ambient": volume_property.GetAmbient(),
            "specular": volume_property.GetSpecular(),
            "specularPower": volume_property.GetSpecularPower(),
        },
        "disableGradientOpacity": bool(volume_property.GetDisableGradientOpacity()),
        "scalarOpacityUnitDistance": volume_property.GetScalarOpacityUnitDistance(),
        "rgbTransferFunction": {
            "type": "colorTransferFunction",
            "points": [{"x": row[0], "color": row[1:], "midpoint": 0.5, "sharpness": 0.0} for row in color.tolist()],
        },
        "scalarOpacity": {"type": "piecewiseLinearFunction", "points": scalar_points(opacity)},
        "gradientOpacity": {"type": "piecewiseLinearFunction", "points": scalar_points(gradient)},
    }


def write_vp_json(volume_property, path: PathLike, effective_range: Optional[Sequence[float]] = None) -> None:
    """Write a ``vtkVolumeProperty`` as Slicer's ``.vp.json`` (effective range: the TF editor's x range)."""
    document = {
        "@schema": VP_JSON_SCHEMA,
        "volumeProperties": [
            {
                "effectiveRange": [float(v) for v in effective_range] if effective_range is not None else [0.0, -1.0],
                "isoSurfaceValues": [0.0],
                "independentComponents": True,
                "interpolationType": "linear" if volume_property.GetInterpolationType() == 1 else "nearest",
                "useClippedVoxelIntensity": False,
                "clippedVoxelIntensity": -10000000000.0,
                "scatteringAnisotropy": 0.0,
                "components": [_component_json(volume_property)],
            }
        ],
    }
    Path(path).write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")


def write_vp(volume_property, path: PathLike) -> None:
    """Write a ``vtkVolumeProperty`` as Slicer's legacy ``.vp`` text file.

    The file has no scalar opacity unit distance (Slicer reads it as 1 mm), so each opacity ``a`` per unit distance
    ``u`` is written as the same opacity per mm, ``1 - (1 - a) ** (1 / u)``: the picture stays the same.
    """
    opacity, gradient, color = points_of_volume_property(volume_property)
    unit_distance = float(volume_property.GetScalarOpacityUnitDistance())
    if unit_distance != 1.0:
        opacity = opacity.copy()
        opacity[:, 1] = 1.0 - (1.0 - np.clip(opacity[:, 1], 0.0, 1.0)) ** (1.0 / unit_distance)

    def line(rows: np.ndarray) -> str:
        flat = rows.ravel().tolist()
        return " ".join([str(len(flat))] + [repr(float(v)) for v in flat])

    lines = [
        str(volume_property.GetInterpolationType()),
        str(volume_property.GetShade()),
        repr(volume_property.GetDiffuse()),
        repr(volume_property.GetAmbient()),
        repr(volume_property.GetSpecular()),
        repr(volume_property.GetSpecularPower()),
        line(opacity),
        line(gradient),
        line(color),
    ]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def _set_points(function, rows) -> None:
    function.RemoveAllPoints()
    for row in rows:
        if len(row) == 2:
            function.AddPoint(float(row[0]), float(row[1]))
        else:
            function.AddRGBPoint(float(row[0]), float(row[1]), float(row[2]), float(row[3]))


def _empty_volume_property():
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
    from vtkmodules.vtkRenderingCore import vtkColorTransferFunction, vtkVolumeProperty

    volume_property = vtkVolumeProperty()
    volume_property.SetColor(vtkColorTransferFunction())
    volume_property.SetScalarOpacity(vtkPiecewiseFunction())
    volume_property.SetGradientOpacity(vtkPiecewiseFunction())
    return volume_property


def read_vp(path: PathLike):
    """Read a legacy ``.vp`` file into a new ``vtkVolumeProperty``."""
    try:
        lines = [line.split() for line in Path(path).read_text(encoding="utf-8").splitlines() if line.strip()]
        if len(lines) < 9:
            raise ValueError(f"expected 9 lines, found {len(lines)}")
        volume_property = _empty_volume_property()
        volume_property.SetInterpolationType(int(lines[0][0]))
        volume_property.SetShade(int(lines[1][0]))
        volume_property.SetDiffuse(float(lines[2][0]))
        volume_property.SetAmbient(float(lines[3][0]))
        volume_property.SetSpecular(float(lines[4][0]))
        volume_property.SetSpecularPower(float(lines[5][0]))
        functions = (
            (volume_property.GetScalarOpacity(), 2),
            (volume_property.GetGradientOpacity(), 2),
            (volume_property.GetRGBTransferFunction(), 4),
        )
        for words, (function, width) in zip(lines[6:9], functions):
            count = int(words[0])
            values = [float(w) for w in words[1:]]
            if count != len(values) or count % width:
                raise ValueError(f"a function line announces {count} values but holds {len(values)}")
            _set_points(function, np.array(values).reshape(-1, width))
    except (OSError, UnicodeDecodeError, ValueError, IndexError) as error:
        raise TransferFunctionFileError(f"cannot read volume property file {path}: {error}") from None
    return volume_property


def read_vp_json(path: PathLike):
    """Read the first volume property of a Slicer ``.vp.json`` file into a new ``vtkVolumeProperty``.

    Returns:
        ``(volume_property, effective_range)``; ``effective_range`` is None when the file leaves it unset.
    """
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
        entry = document["volumeProperties"][0]
        component = entry["components"][0]
        volume_property = _empty_volume_property()
        volume_property.SetInterpolationType(1 if entry.get("interpolationType", "linear") == "linear" else 0)
        volume_property.SetShade(int(bool(component.get("shade", False))))
        lighting = component.get("lighting", {})
        volume_property.SetDiffuse(float(lighting.get("diffuse", DIFFUSE)))
        volume_property.SetAmbient(float(lighting.get("ambient", AMBIENT)))
        volume_property.SetSpecular(float(lighting.get("specular", SPECULAR)))
        volume_property.SetSpecularPower(float(lighting.get("specularPower", SPECULAR_POWER)))
        volume_property.SetScalarOpacityUnitDistance(float(component.get("scalarOpacityUnitDistance", 1.0)))
        volume_property.SetDisableGradientOpacity(int(bool(component.get("disableGradientOpacity", False))))
        _set_points(
            volume_property.GetScalarOpacity(), [(p["x"], p["y"]) for p in component["scalarOpacity"]["points"]]
        )
        _set_points(
            volume_property.GetGradientOpacity(),
            [(p["x"], p["y"]) for p in component.get("gradientOpacity", {}).get("points", [])],
        )
        _set_points(
            volume_property.GetRGBTransferFunction(),
            [(p["x"], *p["color"]) for p in component["rgbTransferFunction"]["points"]],
        )
        low, high = (float(v) for v in entry.get("effectiveRange", [0.0, -1.0]))
    except (OSError, UnicodeDecodeError, ValueError, KeyError, IndexError, TypeError) as error:
        raise TransferFunctionFileError(f"cannot read volume property file {path}: {error!r}") from None
    return volume_property, ((low, high) if low <= high else None)
