"""Step 3 of the pipeline: hierarchical isovalue similarity (Ma & Entezari 2018, as aggregated in the thesis).

For every octree level h, ``O_h(i, j)`` is the number of hyper-cells crossed by both isovalues i and j. It comes from a
joint histogram of (hyper-cell min, hyper-cell max): for ``i <= j``, an inclusive crossing needs ``min <= i`` and
``max >= j``, a strict one ``min < i`` and ``max > j``, so ``O_h`` is a 2-D cumulative sum of that table.
"""

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from .cells import hyper_cell_intervals, octree_levels, unit_cell_intervals

CROSSINGS = ("inclusive", "strict")
NORMALIZATIONS = ("thesis", "ma-entezari")

# Hyper-cells binned at once: bounds the int64 index array of the joint histogram to ~64 MB.
_HISTOGRAM_CHUNK = 1 << 23

ProgressCallback = Callable[[float, str], None]


@dataclass(frozen=True)
class IsovalueSimilarity:
    """Similarity of every pair of isovalues, with what it was made of.

    Attributes:
        matrix: ``(n_bins, n_bins)`` float64, symmetric, in [0, 1]; ``1 - matrix`` is the distance.
        cell_counts: ``(n_levels, n_bins)`` int64, ``n_h(i)``: hyper-cells crossed by isovalue i at level h
            (row 0 is level 1, the coarsest).
        level_sizes: hyper-cell size in unit cells per axis, per level used (coarsest first).
        weights: weight of each level used, ``h / (1 + ... + n_levels)``.
    """

    matrix: np.ndarray
    cell_counts: np.ndarray
    level_sizes: tuple
    weights: np.ndarray

    @property
    def empty_isovalues(self) -> np.ndarray:
        """Bins that cross no cell at any level used (they cannot be compared with anything), ascending."""
        return np.flatnonzero(~self.cell_counts.any(axis=0))


def joint_interval_histogram(mins: np.ndarray, maxs: np.ndarray, n_bins: int) -> np.ndarray:
    """Count cells per (min, max) pair.

    Args:
        mins, maxs: integer arrays of the same shape, values in ``[0, n_bins)``.

    Returns:
        ``(n_bins, n_bins)`` int64 table; entry ``[a, b]`` is the number of cells with min ``a`` and max ``b``.
    """
    flat_mins, flat_maxs = mins.reshape(-1), maxs.reshape(-1)
    counts = np.zeros(n_bins * n_bins, dtype=np.int64)
    for start in range(0, flat_mins.size, _HISTOGRAM_CHUNK):
        index = flat_mins[start : start + _HISTOGRAM_CHUNK].astype(np.intp)
        index *= n_bins
        index += flat_maxs[start : start + _HISTOGRAM_CHUNK]
        counts += np.bincount(index, minlength=n_bins * n_bins)
    return counts.reshape(n_bins, n_bins)


def overlap_counts(histogram: np.ndarray, crossing: str = "inclusive") -> np.ndarray:
    """Number of cells crossed by both isovalues, for every pair, from the joint (min, max) histogram.

    Args:
        histogram: ``(n_bins, n_bins)`` table from :func:`joint_interval_histogram`.
        crossing: ``"inclusive"`` (``min <= mu <= max``) or ``"strict"`` (``min < mu < max``).

    Returns:
        ``(n_bins, n_bins)`` int64, symmetric; the diagonal is the cell count of each isovalue.
    """
    # below[i, j] = cells with min <= i and max >= j.
    below = np.cumsum(histogram, axis=0)
    below = np.cumsum(below[:, ::-1], axis=1)[:, ::-1]
    if crossing == "strict":
        shifted = np.zeros_like(below)
        shifted[1:, :-1] = below[:-1, 1:]
        below = shifted
    upper = np.triu(below)
    return upper + np.triu(below, 1).T


def _check_options(crossing: str, normalization: str) -> None:
    if crossing not in CROSSINGS:
        raise ValueError(f"crossing must be one of {CROSSINGS}; got {crossing!r}")
    if normalization not in NORMALIZATIONS:
        raise ValueError(f"normalization must be one of {NORMALIZATIONS}; got {normalization!r}")


def level_weights(n_levels: int) -> np.ndarray:
    """Weight of levels 1..n_levels, ``h / (1 + 2 + ... + n_levels)``: the finest level weighs most; sums to 1."""
    h = np.arange(1, n_levels + 1, dtype=np.float64)
    return h / h.sum()


def _check_bins(bins: np.ndarray, n_bins: int) -> np.ndarray:
    bins = np.asarray(bins)
    if bins.ndim != 3 or min(bins.shape) < 2:
        raise ValueError(f"bins must be a 3-D array with at least 2 voxels per axis; got shape {bins.shape}")
    if not np.issubdtype(bins.dtype, np.integer):
        raise ValueError(f"bins must hold integers (use quantize() first); got dtype {bins.dtype}")
    if isinstance(n_bins, bool) or not isinstance(n_bins, (int, np.integer)) or n_bins < 2:
        raise ValueError(f"n_bins must be an integer >= 2; got {n_bins!r}")
    low, high = int(bins.min()), int(bins.max())
    if low < 0 or high >= n_bins:
        raise ValueError(f"bins must lie in [0, {n_bins}); found values from {low} to {high}")
    return bins


def isovalue_similarity(
    bins: np.ndarray,
    n_bins: int = 256,
    *,
    crossing: str = "inclusive",
    normalization: str = "thesis",
    levels: Optional[int] = None,
    progress: Optional[ProgressCallback] = None,
) -> IsovalueSimilarity:
    """Hierarchical similarity of all isovalue pairs, with the per-level cell counts it came from.

    See :func:`similarity_matrix` for the arguments.
    """
    _check_options(crossing, normalization)
    bins = _check_bins(bins, n_bins)
    grid = tuple(n - 1 for n in bins.shape)
    all_levels = len(octree_levels(grid))
    if levels is None:
        levels = all_levels
    elif isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or not 1 <= levels <= all_levels:
        raise ValueError(f"levels must be an integer from 1 to {all_levels} for this volume; got {levels!r}")
    levels = int(levels)

    if bins.dtype not in (np.uint8, np.uint16):
        bins = bins.astype(np.uint8 if n_bins <= 256 else np.uint16)
    weights = level_weights(levels)
    total = np.zeros((n_bins, n_bins), dtype=np.float64)
    cell_counts = np.zeros((levels, n_bins), dtype=np.int64)
    sizes = [None] * levels
    mins, maxs = unit_cell_intervals(bins)
    for done, (level, size, level_mins, level_maxs) in enumerate(hyper_cell_intervals(mins, maxs, levels), 1):
        overlaps = overlap_counts(joint_interval_histogram(level_mins, level_maxs, n_bins), crossing)
        counts = np.diagonal(overlaps).copy()
        cell_counts[level - 1] = counts
        sizes[level - 1] = size
        weight = weights[level - 1]
        if normalization == "thesis":
            denominator = np.maximum.outer(counts, counts)
            level_similarity = np.divide(
                overlaps, denominator, out=np.zeros_like(total), where=denominator > 0, dtype=np.float64
            )
        else:
            # A_h(i, j) = O_h(i, j) / n_h(j); NaN where isovalue j crosses nothing, and NaN stays NaN in the sum.
            with np.errstate(invalid="ignore", divide="ignore"):
                level_similarity = overlaps / counts[np.newaxis, :].astype(np.float64)
        total += weight * level_similarity
        if progress is not None:
            progress(done / levels, f"similarity: level {level} of {levels}")
    if normalization == "ma-entezari":
        total = np.fmin(total, total.T)
        total[np.isnan(total)] = 0.0
    return IsovalueSimilarity(matrix=total, cell_counts=cell_counts, level_sizes=tuple(sizes), weights=weights)


def similarity_matrix(
    bins: np.ndarray,
    n_bins: int = 256,
    *,
    crossing: str = "inclusive",
    normalization: str = "thesis",
    levels: Optional[int] = None,
    progress: Optional[ProgressCallback] = None,
) -> np.ndarray:
    """Similarity of every pair of isovalues (thesis eq. 3.1 and 3.2).

    Args:
        bins: 3-D integer array (a quantized volume), values in ``[0, n_bins)``, at least 2 voxels per axis.
        n_bins: number of isovalues.
        crossing: ``"inclusive"`` (isovalue crosses a cell when ``min <= mu <= max``, thesis) or ``"strict"``
            (``min < mu < max``, Ma & Entezari's code).
        normalization: ``"thesis"`` (``O / max(n_i, n_j)`` per level) or ``"ma-entezari"`` (``O / n_j`` per level,
            then the element-wise minimum with the transpose).
        levels: use only the ``levels`` coarsest octree levels (default all); weights are re-normalized over them.
        progress: called as ``progress(fraction, message)`` after each level; raising from it aborts the computation.

    Returns:
        ``(n_bins, n_bins)`` float64 symmetric matrix with values in [0, 1].
    """
    return isovalue_similarity(
        bins, n_bins, crossing=crossing, normalization=normalization, levels=levels, progress=progress
    ).matrix
