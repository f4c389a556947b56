"""Which ground-truth tissue a rendered picture shows: an independent ray caster over the phantom's labels.

A 1-D transfer function cannot be split per tissue (tissues share intensities), so the per-tissue part of a picture
is measured by ray casting the same opacity functions in numpy and attributing each sample's contribution to the
tissue label of its voxel. Rays are orthographic and axis-aligned (one per pixel of the volume's cross-section,
along the view direction), samples are the voxels (nearest, one per voxel step), compositing is front-to-back::

    alpha = 1 - (1 - a(v) * g(|grad v|)) ** (step_mm / unit_distance)      (opacity per unit distance, as VTK)
    weight of the sample = T * alpha, then T *= 1 - alpha                   (T = transmittance so far)

``a`` is the scalar opacity function, ``g`` the gradient opacity (1 when disabled or constant).

Partial volume: the scanner's blur moves values across tissue borders, so the first voxel a CT-Bone ray stops in is
often a soft-tissue voxel whose value the nearby skull has raised (labels are sampled from the sharp geometry). Such
a voxel shows the skull's surface, not soft tissue. Rule: a sample whose value lies more than ``tolerance`` (3 noise
sigma) above its own tissue's mean, with a denser tissue within ``radius`` voxels (the blur's reach), is attributed
to that denser tissue (the one whose mean is nearest the value); every other sample to its own tissue
(:func:`partial_volume_labels`). Only upward: opacity in these transfer functions rises with the value, so the
surface a border renders is its denser side's, and a voxel lowered by a lighter neighbour still shows its own tissue.

For a tissue t:

- picture share: the sum of its samples' weights over all rays divided by the sum over all tissues: which part of
  what the picture shows is t (the weights of a ray add up to that pixel's opacity);
- visibility: the sum of its weights divided by the number of rays that cross t: 1 when t is seen opaque wherever
  it projects, 0 when it is hidden (clear, or behind opaque tissue).

This differs from the real renderer in perspective, trilinear sampling and shading, none of which changes which
tissue a ray stops in. Arrays are indexed ``[k, j, i]`` (z, y, x) like the rest of the library.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Callable

import numpy as np

#: Direction the rays travel in RAS (mm) for each camera position of Slicer's view buttons: the camera of the
#: "anterior" view sits in front of the face and looks towards posterior, etc.
RAY_DIRECTIONS = {
    "anterior": (0.0, -1.0, 0.0),
    "posterior": (0.0, 1.0, 0.0),
    "left": (1.0, 0.0, 0.0),
    "right": (-1.0, 0.0, 0.0),
    "superior": (0.0, 0.0, -1.0),
    "inferior": (0.0, 0.0, 1.0),
}

OpacityFunction = Callable[[np.ndarray], np.ndarray]


def ray_axis(ijk_to_ras: np.ndarray, view: str) -> tuple[int, bool]:
    """The array axis the rays of ``view`` run along, and whether they run towards decreasing index.

    Args:
        ijk_to_ras: 4x4 (or 3x3) IJK-to-RAS matrix; the volume must be about axis-aligned.
        view: a key of :data:`RAY_DIRECTIONS`.

    Returns:
        ``(axis, reverse)``: axis of the ``[k, j, i]`` array (0, 1 or 2); ``reverse`` True when the first sample of
        a ray is the last index.
    """
    direction = np.asarray(RAY_DIRECTIONS[view])
    columns = np.asarray(ijk_to_ras, dtype=np.float64)[:3, :3]
    unit = columns / np.linalg.norm(columns, axis=0, keepdims=True)
    alignment = direction @ unit  # cosine between the ray and the increasing i, j, k directions
    index_axis = int(np.argmax(np.abs(alignment)))
    return 2 - index_axis, bool(alignment[index_axis] < 0)


def piecewise_linear(points: np.ndarray) -> OpacityFunction:
    """A function of the value from ``(n, 2)`` points (x, y), linear between them, constant outside (as VTK)."""
    points = np.asarray(points, dtype=np.float64)
    return lambda values: np.interp(values, points[:, 0], points[:, 1])


def function_points(function) -> np.ndarray:
    """``(n, 2)`` nodes (x, y) of a ``vtkPiecewiseFunction``."""
    node = [0.0, 0.0, 0.0, 0.0]
    points = []
    for index in range(function.GetSize()):
        function.GetNodeValue(index, node)
        points.append(node[:2])
    return np.asarray(points, dtype=np.float64).reshape(-1, 2)


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Grow a boolean mask by ``radius`` voxels along every axis (a cube neighbourhood), without wrapping around."""
    out = np.asarray(mask, dtype=bool)
    for axis in range(out.ndim):
        pad = [(radius, radius) if a == axis else (0, 0) for a in range(out.ndim)]
        padded = np.pad(out, pad)
        size = out.shape[axis]
        out = np.logical_or.reduce([np.take(padded, range(s, s + size), axis=axis) for s in range(2 * radius + 1)])
    return out


def partial_volume_labels(
    values: np.ndarray, labels: np.ndarray, means: Sequence[float], tolerance: float, radius: int
) -> np.ndarray:
    """The tissue each voxel's value shows, with partial volume: raised by a denser neighbour, it shows that one.

    See the module notes.

    Args:
        values: scalar volume; labels: integer tissue labels (same shape).
        means: nominal value of each tissue, indexed by label.
        tolerance: how far (value units) a value may lie from its tissue's mean and still be that tissue's.
        radius: how far (voxels) a neighbouring tissue may be to explain a value.

    Returns:
        labels of the same shape and dtype.
    """
    means = np.asarray(means, dtype=np.float64)
    own = means[labels]
    raised = values.astype(np.float64) - own > tolerance
    result = labels.copy()
    best = np.full(values.shape, np.inf)
    for tissue, mean in enumerate(means):
        candidate = raised & (mean > own) & dilate(labels == tissue, radius)
        distance = np.abs(mean - values)
        better = candidate & (distance < best)
        result[better] = tissue
        best[better] = distance[better]
    return result


def tissue_weights(
    values: np.ndarray,
    labels: np.ndarray,
    n_labels: int,
    opacity: OpacityFunction,
    spacing: Sequence[float],
    axis: int,
    reverse: bool,
    unit_distance: float = 1.0,
    gradient_opacity: OpacityFunction | None = None,
    attribution: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Composite front to back along ``axis``; return per-tissue weights and which rays cross which tissue.

    Args:
        values: ``(nz, ny, nx)`` scalar volume in its own units.
        labels: same shape, integer tissue labels in ``[0, n_labels)``.
        n_labels: number of tissues.
        opacity: scalar opacity per value (per ``unit_distance`` mm).
        spacing: voxel size ``(x, y, z)`` in mm.
        axis: array axis of the rays; ``reverse``: rays start at the last index.
        unit_distance: the property's scalar opacity unit distance in mm.
        gradient_opacity: opacity factor per gradient magnitude (value units per mm), or None for 1.
        attribution: the tissue each sample's weight goes to (e.g. :func:`partial_volume_labels`); ``labels``
            when None. A ray crosses a tissue when one of its samples has that label or attribution.

    Returns:
        ``weights`` ``(rows, columns, n_labels)`` float: per ray, each tissue's share of the pixel's colour;
        ``crosses`` ``(rows, columns, n_labels)`` bool: the ray passes through the tissue (so visibility <= 1).
    """
    step_mm = float(spacing[2 - axis])
    order = slice(None, None, -1) if reverse else slice(None)
    stack = np.moveaxis(values, axis, 0)[order]
    tissue = np.moveaxis(labels, axis, 0)[order]
    shown = tissue if attribution is None else np.moveaxis(attribution, axis, 0)[order]
    if gradient_opacity is not None:
        gradients = np.gradient(values.astype(np.float32), *(float(s) for s in spacing[::-1]))
        magnitude = np.moveaxis(np.sqrt(sum(g * g for g in gradients)), axis, 0)[order]
    transmittance = np.ones(stack.shape[1:], dtype=np.float64)
    weights = np.zeros((*stack.shape[1:], n_labels), dtype=np.float64)
    crosses = np.zeros((*stack.shape[1:], n_labels), dtype=bool)
    exponent = step_mm / float(unit_distance)
    for index in range(stack.shape[0]):
        a = np.clip(opacity(stack[index].astype(np.float64)), 0.0, 1.0)
        if gradient_opacity is not None:
            a = a * np.clip(gradient_opacity(magnitude[index].astype(np.float64)), 0.0, 1.0)
        alpha = 1.0 - (1.0 - a) ** exponent
        contribution = transmittance * alpha
        tissues = np.arange(n_labels)
        weights += contribution[..., None] * (shown[index][..., None] == tissues)
        crosses |= (tissue[index][..., None] == tissues) | (shown[index][..., None] == tissues)
        transmittance *= 1.0 - alpha
    return weights, crosses


def tissue_summary(weights: np.ndarray, crosses: np.ndarray, names: Sequence[str]) -> dict[str, dict[str, float]]:
    """Per tissue name: ``share`` of the picture's content (0..1, sums to 1 over tissues) and ``visibility`` (0..1)."""
    totals = weights.reshape(-1, weights.shape[-1]).sum(axis=0)
    grand_total = float(totals.sum())
    rays = crosses.reshape(-1, crosses.shape[-1]).sum(axis=0)
    return {
        name: {
            "share": float(totals[t] / grand_total) if grand_total > 0 else 0.0,
            "visibility": float(totals[t] / rays[t]) if rays[t] else 0.0,
        }
        for t, name in enumerate(names)
    }


def property_functions(volume_property) -> tuple[OpacityFunction, OpacityFunction | None, float]:
    """Scalar opacity, gradient opacity (None when disabled or constant 1) and unit distance of a vtkVolumeProperty."""
    scalar = piecewise_linear(function_points(volume_property.GetScalarOpacity()))
    gradient = None
    if not volume_property.GetDisableGradientOpacity():
        points = function_points(volume_property.GetGradientOpacity())
        if points.size and not np.allclose(points[:, 1], 1.0):
            gradient = piecewise_linear(points)
    return scalar, gradient, float(volume_property.GetScalarOpacityUnitDistance())
