"""Step 3 of the pipeline: hierarchical isovalue similarity (Ma & Entezari 2018, as aggregated in the thesis).

For every octree level h, ``O_h(i, j)`` is the number of hyper-cells crossed by both isovalues i and j. It comes from a
joint histogram of (hyper-cell min, hyper-cell max): for ``i <= j``, an inclusive crossing needs ``min <= i`` and
``max >= j``, a strict one ``min < i`` and ``max > j``, so ``O_h`` is a 2-D cumulative sum of that table.
"""

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from itertools import islice
from typing import Optional

import numpy as np

from .cells import octree_levels
from .options import CROSSINGS, NORMALIZATIONS
from .stream import ProgressCallback, bins_source, interval_histograms
from .taps import SlabTap

# Joint-histogram entries of the levels finished together (one cumulative sum for all): 8 MB of int64 per table.
_STACKED_ENTRIES = 1 << 20


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


def _upper_overlaps(histograms: np.ndarray, crossing: str) -> np.ndarray:
    """Cells crossed by both isovalues i <= j, from joint (min, max) histograms; the lower triangle is meaningless.

    Args:
        histograms: ``(..., n_bins, n_bins)`` tables from :func:`joint_interval_histogram`.

    Returns:
        Same shape, int64; entry ``[..., i, j]`` for ``i <= j`` is ``O(i, j)``, the diagonal the cell count of each
        isovalue.
    """
    # below[i, j] = cells with min <= i and max >= j, i.e. crossed (inclusively) by both i and j when i <= j.
    below = np.cumsum(histograms, axis=-2)
    below = np.cumsum(below[..., ::-1], axis=-1)[..., ::-1]
    if crossing == "strict":  # min < i and max > j
        shifted = np.zeros_like(below)
        shifted[..., 1:, :-1] = below[..., :-1, 1:]
        below = shifted
    return below


def _symmetric(upper: np.ndarray) -> np.ndarray:
    """The symmetric matrix whose upper triangle (diagonal included) is that of ``upper``."""
    return np.triu(upper) + np.triu(upper, 1).T


def overlap_counts(histogram: np.ndarray, crossing: str = "inclusive") -> np.ndarray:
    """Number of cells crossed by both isovalues, for every pair, from the joint (min, max) histogram.

    Args:
        histogram: ``(n_bins, n_bins)`` table from :func:`joint_interval_histogram`.
        crossing: ``"inclusive"`` (``min <= mu <= max``) or ``"strict"`` (``min < mu < max``).

    Returns:
        ``(n_bins, n_bins)`` int64, symmetric; the diagonal is the cell count of each isovalue.
    """
    return _symmetric(_upper_overlaps(histogram, crossing))


def _check_options(crossing: str, normalization: str) -> None:
    if crossing not in CROSSINGS:
        raise ValueError(f"crossing must be one of {CROSSINGS}; got {crossing!r}")
    if normalization not in NORMALIZATIONS:
        raise ValueError(f"normalization must be one of {NORMALIZATIONS}; got {normalization!r}")


def level_weights(n_levels: int) -> np.ndarray:
    """Weight of levels 1..n_levels, ``h / (1 + 2 + ... + n_levels)``: the finest level weighs most; sums to 1."""
    h = np.arange(1, n_levels + 1, dtype=np.float64)
    return h / h.sum()


def _batched(items: Iterable, size: int) -> Iterator[list]:
    iterator = iter(items)
    while batch := list(islice(iterator, size)):
        yield batch


def _add_levels(total: np.ndarray, overlaps: np.ndarray, denominators: np.ndarray, weights: np.ndarray) -> None:
    """Add ``weights * overlaps / denominators`` of a stack of levels to ``total``, one level after the other.

    Level by level in the stack's order (finest first), so every sum is rounded the same way whatever the batching.
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        terms = np.divide(overlaps, denominators)
    terms *= weights
    for term in terms:
        total += term


def isovalue_similarity(
    bins: np.ndarray,
    n_bins: int = 256,
    *,
    crossing: str = "inclusive",
    normalization: str = "thesis",
    levels: Optional[int] = None,
    progress: Optional[ProgressCallback] = None,
    tap: Optional[SlabTap] = None,
) -> IsovalueSimilarity:
    """Hierarchical similarity of all isovalue pairs, with the per-level cell counts it came from.

    See :func:`similarity_matrix` for the arguments, and :func:`interval_histograms` for ``tap``.
    """
    _check_options(crossing, normalization)
    bins = bins_source(bins, n_bins)
    grid = tuple(n - 1 for n in bins.shape)
    all_levels = len(octree_levels(grid))
    if levels is None:
        levels = all_levels
    elif isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or not 1 <= levels <= all_levels:
        raise ValueError(f"levels must be an integer from 1 to {all_levels} for this volume; got {levels!r}")
    levels = int(levels)

    weights = level_weights(levels)
    # Only the upper triangles (i <= j) are summed; the matrix is mirrored at the end. Ma & Entezari's A(i, j) and
    # A(j, i) = O(i, j) / n(i) are summed apart ("by column" and "by row"), then merged by their element-wise minimum.
    by_column = np.zeros((n_bins, n_bins), dtype=np.float64)
    by_row = np.zeros_like(by_column) if normalization == "ma-entezari" else None
    cell_counts = np.zeros((levels, n_bins), dtype=np.int64)
    sizes = [None] * levels
    histograms = interval_histograms(bins, n_bins, levels, progress, tap)
    for batch in _batched(histograms, max(1, _STACKED_ENTRIES // (n_bins * n_bins))):
        overlaps = _upper_overlaps(np.stack([histogram for _, _, histogram in batch]), crossing)
        counts = np.diagonal(overlaps, axis1=1, axis2=2)
        stacked_weights = weights[[level - 1 for level, _, _ in batch], np.newaxis, np.newaxis]
        if normalization == "thesis":
            # O / max(n_i, n_j); where both are 0, so is O, and 0 / 1 gives the 0 the thesis asks for.
            denominator = np.maximum(counts[:, :, np.newaxis], counts[:, np.newaxis, :])
            _add_levels(by_column, overlaps, np.maximum(denominator, 1, out=denominator), stacked_weights)
        else:
            # A(i, j) = O / n_j: NaN where isovalue j crosses nothing, and NaN stays NaN in the sum.
            _add_levels(by_column, overlaps, counts[:, np.newaxis, :], stacked_weights)
            _add_levels(by_row, overlaps, counts[:, :, np.newaxis], stacked_weights)
        for k, (level, size, _) in enumerate(batch):
            cell_counts[level - 1] = counts[k]
            sizes[level - 1] = size
    if normalization == "thesis":
        matrix = _symmetric(by_column)
    else:
        matrix = _symmetric(np.fmin(by_column, by_row))
        matrix[np.isnan(matrix)] = 0.0
    return IsovalueSimilarity(matrix=matrix, cell_counts=cell_counts, level_sizes=tuple(sizes), weights=weights)


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
        bins: 3-D integer array (a quantized volume, numpy or dask), values in ``[0, n_bins)``, at least 2 voxels per
            axis.
        n_bins: number of isovalues.
        crossing: ``"inclusive"`` (isovalue crosses a cell when ``min <= mu <= max``, thesis) or ``"strict"``
            (``min < mu < max``, Ma & Entezari's code).
        normalization: ``"thesis"`` (``O / max(n_i, n_j)`` per level) or ``"ma-entezari"`` (``O / n_j`` per level,
            then the element-wise minimum with the transpose).
        levels: use only the ``levels`` coarsest octree levels (default all); weights are re-normalized over them.
        progress: called as ``progress(fraction, message)`` during the pass over the unit cells (at least every
            16M cells, a few hundredths of a second) and after each level; raising from it aborts the computation.

    Returns:
        ``(n_bins, n_bins)`` float64 symmetric matrix with values in [0, 1].
    """
    return isovalue_similarity(
        bins, n_bins, crossing=crossing, normalization=normalization, levels=levels, progress=progress
    ).matrix
