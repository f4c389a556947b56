"""Thumbnails of a transfer function: a small shaded orthographic ray caster in numpy.

The gallery of looks shows each look as a one-click button with a picture, as Slicer's preset icons. The picture is
rendered from the design's preview (:class:`.visibility.Preview`, about 48^3 voxels), so it takes a few ms and needs
neither VTK nor a GPU:

* **Rays**: one per preview column along the view's axis, one nearest sample per voxel (bins are classes; an
  average of two bins would be a third tissue), composited front to back slice by slice with an explicit running
  transmittance: ``C += T * alpha * colour``, ``T *= 1 - alpha``.
* **Pre-integrated segments** (Engel, Kraus & Ertl, "High-quality pre-integrated volume rendering using
  hardware-accelerated pixel shading", 2001): the step from one sample to the next passes every bin between theirs,
  as a ray through the full volume does, and takes their mean extinction and extinction-weighted colour. A preview
  samples every few voxels, so the partial-volume skin of a structure (the rim a thin-structures look shows) lies
  between two samples rather than on one: without it the skin of a plant's trunk, drawn whole by VTK, shows as
  scattered dots. A homogeneous stretch is sampled as before.
* **Opacity per unit distance**, as a ``vtkVolumeProperty``'s ``ScalarOpacityUnitDistance``: a sample of a step of
  ``d`` mm with scalar opacity ``a`` has ``alpha = 1 - (1 - a) ** (d / unit_distance)``.
* **A headlight**: the normal is the gradient of the opacity field (each voxel's bin opacity), smoothed by a 3-tap
  binomial filter per axis so a coarse preview's staircase does not show, and taken half a voxel toward the camera
  (where the ray enters the voxel, so a shell one voxel thick faces the camera instead of its staircase); the shade
  is ``AMBIENT + DIFFUSE * |n . view|``, and 1 where the opacity does not change (inside a homogeneous tissue).

:func:`ray_visibility` measures, with the same compositing, the light each bin sends to the eye: an independent
oracle for :func:`.visibility.visibility_histogram`, which computes it with cumulative sums of logarithms.

Orientation. Arrays are indexed ``[k, j, i]`` (z, y, x) and the spacing is ``(x, y, z)`` in mm, as everywhere in the
library. Which way each index axis points is the volume's IJK-to-RAS directions (``directions``: column ``c`` the
RAS direction of axis ``c`` = i, j, k; the identity by default, where ``i`` increases toward the patient's right,
``j`` toward anterior, ``k`` toward superior). Each index axis is taken along the patient's axis it is nearest to
(an oblique acquisition is shown as the axis-aligned one nearest to it; a NIfTI or DICOM file whose ``j`` runs
toward posterior still shows the face from the front). Each view is what a camera placed on that side of the
patient sees, looking at the centre (as Slicer's view buttons, not mirrored), with image row 0 at the top (the table
for the identity):

=========  ======================  =================  =========================================
view       camera on, rays toward  picture top        picture left
=========  ======================  =================  =========================================
anterior   high j, toward j = 0    high k (superior)  high i (patient's right: radiological)
posterior  j = 0, toward high j    high k             i = 0 (patient's left)
left       i = 0, toward high i    high k             high j (the face looks left)
right      high i, toward i = 0    high k             j = 0 (the face looks right)
superior   high k, toward k = 0    high j (anterior)  i = 0 (patient's left)
inferior   k = 0, toward high k    high j             high i (patient's right)
=========  ======================  =================  =========================================

The picture keeps the physical aspect of the projected plane (from the shape and the spacing): its longest side
fills the ``size`` pixels, the other is centred between bands of background, and the preview's pixels are resampled
bilinearly (the composite, not the bins, so no class is invented).
"""

from collections.abc import Iterable, Sequence
from itertools import permutations
from typing import Optional

import numpy as np

from .visibility import Preview

#: The views of the gallery's thumbnails.
VIEWS = ("anterior", "left", "superior")
#: The six axis views (Slicer's view buttons); :func:`ray_visibility` sums over them by default.
VIEWS_ALL_SIX = ("anterior", "posterior", "left", "right", "superior", "inferior")

# Per view: array axes (k=0, j=1, i=2) that become (depth, picture rows, picture columns), and whether each is
# reversed so that depth 0 is the sample nearest the camera, row 0 the top and column 0 the left (module table).
_LAYOUT = {
    "anterior": ((1, 0, 2), (True, True, True)),
    "posterior": ((1, 0, 2), (False, True, False)),
    "left": ((2, 0, 1), (False, True, True)),
    "right": ((2, 0, 1), (True, True, False)),
    "superior": ((0, 1, 2), (True, True, False)),
    "inferior": ((0, 1, 2), (False, True, True)),
}
#: Headlight shading: ``AMBIENT + DIFFUSE * |n . view|`` (1 where the surface faces the camera).
AMBIENT, DIFFUSE = 0.3, 0.7
# Opacity 1 is an infinite extinction: a sample of it still passes 1e-9 of the light.
_MAX_OPACITY = 1.0 - 1e-9
# A clear bin's weight in a pre-integrated step's colour: 500 times the rounding of a double-precision sum over 4096
# bins of the largest extinction (-log(1e-9) = 20.7), so that a difference of two sums still resolves it.
_CLEAR_WEIGHT = 1e-8
# Opacity changes per voxel below this share of the largest opacity are rounding, not a surface: shade 1 there.
_FLAT = 1e-6
_MIN_SIZE = 8


def render_thumbnail(
    preview: Preview,
    bin_colors: np.ndarray,
    bin_opacity: np.ndarray,
    *,
    unit_distance: float,
    view: str = "anterior",
    size: int = 96,
    background: Sequence[float] = (0.0, 0.0, 0.0),
    shading: bool = True,
    directions: Optional[np.ndarray] = None,
) -> np.ndarray:
    """Render the transfer function applied to the preview, seen from one side (orientation in the module notes).

    Args:
        preview: the quantized volume: ``.bins`` ``(nz, ny, nx)`` integers in ``[0, n_bins)``, ``.spacing``
            ``(x, y, z)`` in mm, ``.n_bins``.
        bin_colors: ``(n_bins, 3)`` RGB of each bin in 0..1 (clipped).
        bin_opacity: ``(n_bins,)`` scalar opacity of each bin per ``unit_distance`` (clipped to [0, 1]).
        unit_distance: the scalar opacity unit distance in mm (> 0): a step of ``d`` mm through a bin of opacity
            ``a`` has ``alpha = 1 - (1 - a) ** (d / unit_distance)``.
        view: one of :data:`VIEWS_ALL_SIX` (the gallery uses :data:`VIEWS`).
        size: side of the square picture in pixels (>= 8).
        background: RGB in 0..1 where the rays pass (partly) through and outside the projected volume.
        shading: False composites the bins' colours unshaded (for testing the compositing alone).
        directions: ``(3, 3)`` IJK-to-RAS directions of the volume the preview was made from (column ``c``: the
            RAS direction of index axis ``c`` = i, j, k; lengths are ignored); None for the identity.

    Returns:
        ``(size, size, 3)`` uint8 RGB picture, row 0 at the top.

    Raises:
        ValueError: on a bad preview, colour or opacity shape, view, size, unit distance, background or directions.
    """
    bins, spacing_zyx = _checked_preview(preview)
    opacity = _checked_opacity(bin_opacity, preview.n_bins)
    colors = np.asarray(bin_colors, dtype=np.float64)
    if colors.shape != (preview.n_bins, 3) or not np.all(np.isfinite(colors)):
        raise ValueError(f"bin_colors must be a finite ({preview.n_bins}, 3) array, got shape {colors.shape}")
    back = np.asarray(background, dtype=np.float64)
    if back.shape != (3,) or not np.all(np.isfinite(back)):
        raise ValueError(f"background must be three finite numbers in 0..1, got {background!r}")
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < _MIN_SIZE:
        raise ValueError(f"size must be an integer >= {_MIN_SIZE}, got {size!r}")
    _check_unit_distance(unit_distance)
    layout = _layout(view, directions)
    depth_axis, row_axis, col_axis = layout[0]

    alpha, rgb = _segments(
        _oriented(bins, layout), opacity, np.clip(colors, 0.0, 1.0), spacing_zyx[depth_axis] / unit_distance
    )
    if shading:
        rgb = rgb * _headlight(opacity.astype(np.float32)[bins], spacing_zyx, layout)[..., None]
    weights, transmittance = _front_to_back(alpha)
    # The premultiplied colour and the transmittance are resampled, then laid over the background.
    composite = np.concatenate([np.einsum("drc,drck->rck", weights, rgb), transmittance[..., None]], axis=-1)
    picture = _fit(composite, spacing_zyx[row_axis], spacing_zyx[col_axis], int(size))
    outside = np.isnan(picture[..., 0])
    picture[outside] = (0.0, 0.0, 0.0, 1.0)  # no volume there: all background
    rgb_out = picture[..., :3] + picture[..., 3:] * np.clip(back, 0.0, 1.0)
    return np.clip(np.rint(rgb_out * 255.0), 0, 255).astype(np.uint8)


def ray_visibility(
    preview: Preview, bin_opacity: np.ndarray, *, unit_distance: float, views: Iterable[str] = VIEWS_ALL_SIX
) -> np.ndarray:
    """The light each bin sends to the eye, summed over every ray of the given axis views.

    The visibility of a sample is the transmittance in front of it times its alpha; it is composited slice by
    slice with an explicit running transmittance, as :func:`render_thumbnail` does, so it checks the cumulative-log
    fast path of :func:`.visibility.visibility_histogram` (same rays: one per column, one sample per voxel).

    Args:
        preview: the quantized volume (see :func:`render_thumbnail`).
        bin_opacity: ``(n_bins,)`` scalar opacity of each bin per ``unit_distance`` (clipped to [0, 1]).
        unit_distance: the scalar opacity unit distance in mm (> 0).
        views: names from :data:`VIEWS_ALL_SIX`; a name given twice counts twice.

    Returns:
        ``(n_bins,)`` float64 visibility per bin, in rays (a ray gives at most 1): summed over the bins, the opacity
        ``1 - T`` summed over every ray of the views.

    Raises:
        ValueError: on a bad preview or opacity shape, unit distance or view name.
    """
    bins, spacing_zyx = _checked_preview(preview)
    opacity = _checked_opacity(bin_opacity, preview.n_bins)
    _check_unit_distance(unit_distance)
    if isinstance(views, str):
        raise ValueError(f"views must be a sequence of view names, got the string {views!r}")
    seen = np.zeros(preview.n_bins)
    for view in views:
        layout = _layout(view)
        alpha = _sample_alpha(opacity, spacing_zyx[layout[0][0]] / unit_distance)[bins]
        weights, _ = _front_to_back(_oriented(alpha, layout))
        seen += np.bincount(_oriented(bins, layout).ravel(), weights=weights.ravel(), minlength=preview.n_bins)
    return seen


# ------------------------------------------------------------------------------------------------------ validation


def _checked_preview(preview: Preview) -> tuple[np.ndarray, tuple[float, float, float]]:
    """The preview's bins as ``intp`` and its spacing in array-axis order ``(z, y, x)``."""
    bins = np.asarray(preview.bins)
    if bins.ndim != 3 or min(bins.shape) < 1 or not np.issubdtype(bins.dtype, np.integer):
        raise ValueError(f"preview.bins must be a non-empty 3-D integer array, got {bins.dtype} {bins.shape}")
    if int(bins.min()) < 0 or int(bins.max()) >= preview.n_bins:
        raise ValueError(f"preview.bins must lie in [0, {preview.n_bins}), got [{bins.min()}, {bins.max()}]")
    spacing = np.asarray(preview.spacing, dtype=np.float64)
    if spacing.shape != (3,) or not np.all(np.isfinite(spacing)) or np.any(spacing <= 0):
        raise ValueError(f"preview.spacing must be three positive sizes (x, y, z) in mm, got {preview.spacing!r}")
    return bins.astype(np.intp, copy=False), (float(spacing[2]), float(spacing[1]), float(spacing[0]))


def _checked_opacity(bin_opacity: np.ndarray, n_bins: int) -> np.ndarray:
    opacity = np.asarray(bin_opacity, dtype=np.float64)
    if opacity.shape != (n_bins,) or not np.all(np.isfinite(opacity)):
        raise ValueError(f"bin_opacity must be a finite ({n_bins},) array, got shape {opacity.shape}")
    return np.clip(opacity, 0.0, 1.0)


def _check_unit_distance(unit_distance: float) -> None:
    if not np.isfinite(unit_distance) or unit_distance <= 0:
        raise ValueError(f"unit_distance must be a positive number of mm, got {unit_distance!r}")


Layout = tuple[tuple[int, int, int], tuple[bool, bool, bool]]


def _layout(view: str, directions: Optional[np.ndarray] = None) -> Layout:
    """The array axes that become (depth, picture rows, picture columns) for the camera of ``view``, and whether each
    is reversed, for a preview whose index axes point along ``directions`` (see :func:`render_thumbnail`)."""
    if view not in _LAYOUT:
        raise ValueError(f"unknown view {view!r}; expected one of {', '.join(VIEWS_ALL_SIX)}")
    axes, flips = _LAYOUT[view]
    if directions is None:
        return axes, flips
    # The table's array axes are those of the identity: 0 (k) superior, 1 (j) anterior, 2 (i) right (RAS row 2 - a).
    carrier, reversed_ = _nearest_axes(directions)
    return (
        tuple(carrier[2 - a] for a in axes),  # type: ignore[return-value]
        tuple(flip != reversed_[2 - a] for a, flip in zip(axes, flips)),  # type: ignore[return-value]
    )


def _nearest_axes(directions: np.ndarray) -> tuple[list[int], list[bool]]:
    """For each patient axis (R, A, S), the array axis (0 = k, 1 = j, 2 = i) whose index direction is nearest to it,
    and whether that index runs the other way (toward L, P or I): the axis permutation with the largest summed
    ``|cosine|``, so every patient axis gets one array axis even when the volume is oblique."""
    matrix = np.asarray(directions, dtype=np.float64)
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
        raise ValueError(f"directions must be a finite 3 x 3 matrix (IJK-to-RAS directions), got shape {matrix.shape}")
    lengths = np.linalg.norm(matrix, axis=0)
    cosines = matrix / np.where(lengths > 0, lengths, 1.0)  # [ras, index axis c]
    if abs(np.linalg.det(cosines)) < 1e-6:  # a zero column leaves a zero column: singular too
        raise ValueError("directions must be three independent IJK-to-RAS directions, got a singular matrix")
    order = max(permutations(range(3)), key=lambda p: sum(abs(cosines[ras, c]) for ras, c in enumerate(p)))
    return [2 - c for c in order], [bool(cosines[ras, c] < 0) for ras, c in enumerate(order)]


# -------------------------------------------------------------------------------------------------------- rendering


def _sample_alpha(opacity: np.ndarray, steps: float) -> np.ndarray:
    """``(n_bins,)`` alpha of one sample of each bin over ``steps`` unit distances."""
    return 1.0 - (1.0 - opacity) ** steps


def _segments(bins: np.ndarray, opacity: np.ndarray, colors: np.ndarray, steps: float) -> tuple[np.ndarray, np.ndarray]:
    """``(depth, rows, columns)`` alpha and ``(..., 3)`` colour of the pre-integrated step from each sample of
    ``bins`` (depth 0 nearest the camera) to the next (the last one's step stays in its bin), ``steps`` unit distances
    long: the mean extinction ``-log(1 - opacity)`` over the bins between the two samples' (both included), and the
    colour those bins give weighted by it. A step within one bin is that bin's sample, as without pre-integration.
    Sums in double precision (a bin's extinction is a difference of two of them), the result in single: a picture's
    worth, and half the time of every later pass."""
    extinction = -np.log1p(-np.minimum(opacity, _MAX_OPACITY))
    # Colours weigh a clear bin _CLEAR_WEIGHT: a step through clear bins alone (its alpha 0) gets their mean colour.
    weight = extinction + _CLEAR_WEIGHT
    summed, summed_weight = (np.concatenate([[0.0], np.cumsum(w)]) for w in (extinction, weight))
    summed_color = np.concatenate([np.zeros((1, 3)), np.cumsum(weight[:, None] * colors, axis=0)])
    following = np.concatenate([bins[1:], bins[-1:]])
    low, high = np.minimum(bins, following), np.maximum(bins, following) + 1
    alpha = -np.expm1(-steps * (np.take(summed, high) - np.take(summed, low)) / (high - low))
    rgb = np.take(summed_color, high, axis=0) - np.take(summed_color, low, axis=0)
    rgb /= (np.take(summed_weight, high) - np.take(summed_weight, low))[..., None]
    return alpha.astype(np.float32), rgb.astype(np.float32)


def _oriented(volume: np.ndarray, layout: Layout) -> np.ndarray:
    """A view of ``volume`` (``(nz, ny, nx, ...)``) as ``(depth, rows, columns, ...)`` for a camera's ``layout``
    (:func:`_layout`)."""
    axes, flips = layout
    out = np.transpose(volume, axes + tuple(range(3, volume.ndim)))
    return out[tuple(slice(None, None, -1) if flip else slice(None) for flip in flips)]


def _front_to_back(alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Front-to-back compositing of ``(depth, rows, columns)`` sample alphas, depth 0 nearest the camera.

    Returns:
        The weight of each sample in its pixel (transmittance in front of it times its alpha), same shape, and the
        ``(rows, columns)`` transmittance left behind the last sample.
    """
    weights = np.empty(alpha.shape, dtype=alpha.dtype)
    transmittance = np.ones(alpha.shape[1:], dtype=alpha.dtype)
    for depth, slice_alpha in enumerate(alpha):
        np.multiply(transmittance, slice_alpha, out=weights[depth])
        transmittance *= 1.0 - slice_alpha
    return weights, transmittance


def _smoothed(field: np.ndarray) -> np.ndarray:
    """The field filtered by ``[1, 2, 1] / 4`` along each axis, edges replicated."""
    for axis in range(field.ndim):
        rows = np.moveaxis(field, axis, 0)
        padded = np.concatenate([rows[:1], rows, rows[-1:]])
        field = np.moveaxis(0.25 * (padded[:-2] + padded[2:]) + 0.5 * padded[1:-1], 0, axis)
    return field


def _headlight(opacity_field: np.ndarray, spacing_zyx: tuple[float, float, float], layout: Layout) -> np.ndarray:
    """``(depth, rows, columns)`` shade of each sample of a camera's ``layout`` (see :func:`_oriented`), lit from
    the camera."""
    smooth = _smoothed(opacity_field)
    gradient = [
        _oriented(np.gradient(smooth, spacing_zyx[axis], axis=axis), layout)
        if smooth.shape[axis] > 1
        else np.zeros(_oriented(smooth, layout).shape, dtype=smooth.dtype)
        for axis in range(3)
    ]
    # The normal where the ray enters the voxel, half a voxel toward the camera: at the centre of a shell one voxel
    # thick (a 5 mm skull in 5 mm voxels) the gradient across the shell is 0 and the staircase's sideways gradient
    # alone would turn it edge-on, dark.
    gradient = [0.5 * (g + np.concatenate([g[:1], g[:-1]])) for g in gradient]
    norm = np.sqrt(sum(g * g for g in gradient))
    # A change of opacity per voxel (largest step) below _FLAT of the peak opacity is a homogeneous inside.
    surface = norm * max(spacing_zyx) > _FLAT * max(float(opacity_field.max()), np.finfo(float).tiny)
    depth_axis = layout[0][0]
    facing = np.abs(gradient[depth_axis]) / np.where(surface, norm, 1.0)
    return np.where(surface, AMBIENT + DIFFUSE * facing, 1.0)


def _fit(image: np.ndarray, row_mm: float, col_mm: float, size: int) -> np.ndarray:
    """``(size, size, c)`` bilinear resampling of ``(rows, columns, c)`` pixels of ``row_mm`` x ``col_mm`` mm,
    the longest physical side filling the picture, centred; NaN where a pixel's centre falls outside the image."""
    rows, cols = image.shape[:2]
    px_per_mm = size / max(rows * row_mm, cols * col_mm)
    resampled = image
    for axis, (count, mm) in enumerate(((rows, row_mm), (cols, col_mm))):
        # Output pixel centres, in mm from the image's first edge, then in source pixel-centre coordinates.
        position = (np.arange(size) + 0.5 - size / 2.0) / px_per_mm + count * mm / 2.0
        source = np.clip(position / mm - 0.5, 0.0, count - 1)
        low = np.floor(source).astype(np.intp)
        high = np.minimum(low + 1, count - 1)
        shape = [1] * resampled.ndim
        shape[axis] = size
        frac = (source - low).reshape(shape)
        resampled = np.take(resampled, low, axis=axis) * (1.0 - frac) + np.take(resampled, high, axis=axis) * frac
        outside = ((position < 0) | (position > count * mm)).reshape(shape)
        resampled = np.where(outside, np.nan, resampled)
    return resampled
