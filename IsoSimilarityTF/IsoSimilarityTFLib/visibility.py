"""What a transfer function shows: a small numpy ray caster measuring each bin's share of the picture.

The visibility of a sample is the light it sends to the eye: the transmittance in front of it times its alpha
(Correa & Ma, "Visibility histograms and visibility-driven transfer functions", TVCG 2011). Summed over every ray
by isovalue bin it is the *visibility histogram*; summed by tissue it says which tissue gives the picture. The
look (:mod:`.look`) sets opacities from it, so it must be fast and depend only on the quantized volume:

* **A preview** (:func:`preview_bins`): every s-th voxel along each axis, steps chosen so the voxels are about
  cubic in mm and at most ``max_voxels`` remain. Nearest sampling keeps the bins exact (an average would invent
  intensities between tissues).
* **Orthographic rays along the preview's axes**, both ways (the six views of Slicer's view buttons), one per voxel
  column, one sample per voxel. Front-to-back compositing is a cumulative product, so a whole direction is one
  vectorized pass: ``T = exp(cumsum(log(1 - alpha)))`` shifted by one sample.
* **Opacity per unit distance**, as the design writes it: a sample of a step of ``d`` mm has
  ``alpha = 1 - (1 - a) ** (d / u)``. The unit distance ``u`` follows the volume's extent
  (:attr:`Preview.unit_distance`), so the same voxels give the same picture at any voxel size: a specimen 10 mm across
  at 0.05 mm is as many voxels deep as a head at 1 mm, and Slicer's presets, made per mm for heads and chests about
  :data:`PRESET_EXTENT_MM` across, keep their meaning at that scale.

Perspective, trilinear sampling and shading are left out: none of them changes which tissue a ray stops in.
Arrays are indexed ``[k, j, i]`` (z, y, x), spacing is ``(x, y, z)`` in mm, as everywhere in the library.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Optional

import numpy as np

#: The scale Slicer's presets were made for: opacity per mm on a head or a chest, about 20 cm across. A volume of
#: this extent gets a unit distance of 1 mm; any other, the same share of its extent.
PRESET_EXTENT_MM = 200.0
#: Voxels of the preview: 48^3 resolves a 5 mm skull on a 24 cm head (5 mm voxels) and renders in a few ms.
PREVIEW_VOXELS = 48**3
#: Side, in preview voxels, of the cube around a voxel in which :func:`surroundings_fill` measures what lies there: a
#: tenth of the preview's side, wide enough that a plane through it (1/5 of it) and a line (1/25) differ fivefold.
SURROUNDINGS = 5
# Largest alpha a sample may have: keeps log(1 - alpha) finite (an opaque sample still passes 1e-9 of the light).
_MAX_ALPHA = 1.0 - 1e-9


@dataclass(frozen=True)
class Preview:
    """A strided copy of the quantized volume, and which rays cross which bins.

    Attributes:
        bins: ``(nz, ny, nx)`` isovalue bins of every ``step``-th voxel.
        spacing: ``(x, y, z)`` voxel size of the preview in mm.
        n_bins: number of isovalue bins.
    """

    bins: np.ndarray
    spacing: tuple[float, float, float]
    n_bins: int

    @cached_property
    def unit_distance(self) -> float:
        """Scalar opacity unit distance in mm: the preview's extent (geometric mean of its three sides, in mm) over
        :data:`PRESET_EXTENT_MM` mm. Scaling the spacing scales it alike, so the picture does not change."""
        sides = np.asarray(self.bins.shape, dtype=np.float64) * np.asarray(self.spacing[::-1], dtype=np.float64)
        return float(np.exp(np.mean(np.log(sides)))) / PRESET_EXTENT_MM

    @cached_property
    def flat_bins(self) -> np.ndarray:
        """``(n,)`` the bins as ``intp``, flat: what ``bincount`` takes without a copy each render."""
        return self.bins.ravel().astype(np.intp)

    def rays_crossing(self, group_of_bin: np.ndarray, n_groups: int) -> np.ndarray:
        """``(n_groups,)`` number of rays (over the six directions) that pass through a voxel of each group.

        Args:
            group_of_bin: ``(n_bins,)`` group (tissue) of each bin, -1 for none.
            n_groups: number of groups.
        """
        groups = np.asarray(group_of_bin)[self.bins]
        counts = np.zeros(n_groups, dtype=np.int64)
        for group in range(n_groups):
            inside = groups == group
            # A ray along an axis and its opposite cross the same voxels: count each column twice.
            counts[group] = 2 * sum(int(inside.any(axis=axis).sum()) for axis in range(3))
        return counts


def preview_steps(
    shape: Sequence[int], spacing: Optional[Sequence[float]], max_voxels: int = PREVIEW_VOXELS
) -> tuple[tuple[int, int, int], tuple[float, float, float]]:
    """The steps ``(sz, sy, sx)`` of the preview of a volume (voxels about cubic in mm, at most ``max_voxels``
    kept) and the preview's spacing ``(x, y, z)`` in mm.

    Args:
        shape: ``(nz, ny, nx)``. spacing: ``(x, y, z)`` voxel size in mm; None for 1 mm.
    """
    size = np.asarray(shape, dtype=np.float64)
    spacing_zyx = np.asarray(spacing[::-1] if spacing is not None else (1.0, 1.0, 1.0), dtype=np.float64)
    # The preview's voxel edge in mm: the volume's extent cut into at most max_voxels cubes.
    edge = float(np.prod(size * spacing_zyx) / max_voxels) ** (1.0 / 3.0)
    steps = np.maximum(1, np.round(edge / spacing_zyx)).astype(int)
    while np.prod(np.ceil(size / steps)) > max_voxels:
        steps[np.argmin(steps * spacing_zyx)] += 1  # coarsen the finest axis first
    kept_spacing = spacing_zyx * steps
    return (
        (int(steps[0]), int(steps[1]), int(steps[2])),
        (float(kept_spacing[2]), float(kept_spacing[1]), float(kept_spacing[0])),
    )


def preview_bins(
    bins: np.ndarray, spacing: Optional[Sequence[float]], n_bins: int, max_voxels: int = PREVIEW_VOXELS
) -> Preview:
    """The preview of a quantized volume in memory (see the module notes).

    Args:
        bins: ``(nz, ny, nx)`` integer bins in ``[0, n_bins)``.
        spacing: ``(x, y, z)`` voxel size in mm; None for 1 mm.
        n_bins: number of bins.
        max_voxels: at most this many voxels are kept.
    """
    (sz, sy, sx), kept_spacing = preview_steps(np.shape(bins), spacing, max_voxels)
    return Preview(bins=np.asarray(bins[::sz, ::sy, ::sx]), spacing=kept_spacing, n_bins=int(n_bins))


def visibility_histogram(preview: Preview, opacity: np.ndarray) -> np.ndarray:
    """``(n_bins,)`` light each bin sends to the eye, summed over the rays of the six axis directions.

    Args:
        preview: the volume (see :func:`preview_bins`).
        opacity: ``(n_bins,)`` scalar opacity of each bin per :attr:`Preview.unit_distance` (the transfer
            function's), in [0, 1].

    Returns:
        The visibility of each bin; summed over the bins, the opacity of all pixels of the six views.
    """
    opacity = np.clip(np.asarray(opacity, dtype=np.float64), 0.0, 1.0)
    log_clear = np.log1p(-np.minimum(opacity, _MAX_ALPHA))  # log(1 - a) per unit distance, per bin
    seen = np.zeros(preview.bins.shape, dtype=np.float32)
    for axis, step_mm in enumerate(preview.spacing[::-1]):
        # Per bin, then per sample: log(1 - alpha) over a step along this axis, and alpha (the rays run along it).
        steps = step_mm / preview.unit_distance
        log_t = (log_clear * steps).astype(np.float32)[preview.bins]
        alpha = (-np.expm1(log_clear * steps)).astype(np.float32)[preview.bins]
        behind = np.cumsum(log_t, axis=axis)  # log transmittance from the ray's start through each sample
        total = np.take(behind, [-1], axis=axis)
        # Transmittance in front of each sample seen from the start of the axis and from its end, times its alpha.
        front = np.exp(np.subtract(behind, log_t, out=log_t), out=log_t)
        back = np.exp(np.subtract(total, behind, out=behind), out=behind)
        seen += np.multiply(np.add(front, back, out=front), alpha, out=front)
    return np.bincount(preview.flat_bins, weights=seen.ravel(), minlength=preview.n_bins)


def first_met(preview: Preview, group_of_bin: np.ndarray, groups: Sequence[int]) -> np.ndarray:
    """``(len(groups),)`` number of rays (six directions) on which each of ``groups`` is the first of them met, among
    the rays that cross at least two of them: the group that encloses the others is met first most often."""
    group = np.asarray(group_of_bin)[preview.bins]
    inside = np.isin(group, groups)
    counts = np.zeros(len(groups), dtype=np.int64)
    index = {g: i for i, g in enumerate(groups)}
    for axis in range(3):
        mask = np.moveaxis(inside, axis, 0)
        labels = np.moveaxis(group, axis, 0)
        seen = np.zeros(mask.shape[1:], dtype=np.int64)
        for g in groups:  # rays that cross two groups or more
            seen += np.moveaxis(group == g, axis, 0).any(axis=0)
        several = seen >= 2
        for ordered, ordered_labels in ((mask, labels), (mask[::-1], labels[::-1])):
            first = np.take_along_axis(ordered_labels, np.argmax(ordered, axis=0)[None], axis=0)[0]
            for g, i in index.items():
                counts[i] += int(np.count_nonzero((first == g) & several))
    return counts


def enclosure(preview: Preview, group_of_bin: np.ndarray, outer: int, inner: int) -> float:
    """Share of the rays through both groups that meet ``outer`` before ``inner`` (six directions): near 1 when
    ``outer`` encloses ``inner`` (skin around bone), near 0 the other way round, 0 when no ray crosses both."""
    groups = np.asarray(group_of_bin)[preview.bins]
    first_outer = 0
    both = 0
    for axis in range(3):
        is_outer = np.moveaxis(groups == outer, axis, 0)
        is_inner = np.moveaxis(groups == inner, axis, 0)
        for ordered_outer, ordered_inner in ((is_outer, is_inner), (is_outer[::-1], is_inner[::-1])):
            crosses = ordered_outer.any(axis=0) & ordered_inner.any(axis=0)
            # argmax gives the first True along the ray (n where there is none is never compared: crosses).
            before = np.argmax(ordered_outer, axis=0) < np.argmax(ordered_inner, axis=0)
            first_outer += int((before & crosses).sum())
            both += int(crosses.sum())
    return first_outer / both if both else 0.0


def surroundings_fill(preview: Preview, member_of_bin: np.ndarray, object_of_bin: np.ndarray) -> float:
    """Median, over the preview's voxels whose bin is a member (``member_of_bin``, ``(n_bins,)`` bool), of the share of
    the cube of :data:`SURROUNDINGS` voxels a side centred on each that object voxels fill (``object_of_bin``; outside
    the preview counts as empty); 0 without members. About 1/25 for a line one voxel thick (a twig, a small vessel in
    the open), 1/5 for a plane through the cube, and over a half for the skin of a body (it lies against the body it
    blurs)."""
    members = np.asarray(member_of_bin, dtype=bool)[preview.bins]
    if not members.any():
        return 0.0
    filled = box_sums(np.asarray(object_of_bin, dtype=bool)[preview.bins], SURROUNDINGS)
    return float(np.median(filled[members])) / SURROUNDINGS**3


def box_sums(mask: np.ndarray, size: int) -> np.ndarray:
    """``mask.shape`` number of True voxels in the cube of odd ``size`` centred on each voxel (outside counts as
    False): a running sum along each axis in turn, from cumulative sums."""
    half = size // 2
    counts = mask.astype(np.int64)
    for axis in range(counts.ndim):
        along = np.moveaxis(counts, axis, 0)
        before = np.zeros((half + 1, *along.shape[1:]), dtype=np.int64)
        after = np.zeros((half, *along.shape[1:]), dtype=np.int64)
        running = np.cumsum(np.concatenate([before, along, after]), axis=0)
        counts = np.moveaxis(running[size:] - running[:-size], 0, axis)
    return counts
