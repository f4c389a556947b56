"""Step 3 of the pipeline: hierarchical isovalue similarity (Ma & Entezari 2018, as aggregated in the thesis).

For every octree level h, ``O_h(i, j)`` is the number of hyper-cells crossed by both isovalues i and j. It comes from a
joint histogram of (hyper-cell min, hyper-cell max): for ``i <= j``, an inclusive crossing needs ``min <= i`` and
``max >= j``, a strict one ``min < i`` and ``max > j``, so ``O_h`` is a 2-D cumulative sum of that table.
"""

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from itertools import islice
from typing import Callable, Optional

import numpy as np

from .cells import GATHERED_CELLS, OctreeBuilder, Shape3, octree_levels, unit_cell_slabs
from .chunked import is_dask_array, voxel_slabs
from .memory import check_memory
from .quantize import checked_n_bins

CROSSINGS = ("inclusive", "strict")
NORMALIZATIONS = ("thesis", "ma-entezari")

# Unit cells per slab, and (min, max) pairs counted per np.bincount call: bincount first converts its input to a
# 64-bit index, which must stay in the core's cache (2 MB of 256K cells).
_SLAB_CELLS = 1 << 18
# Progress is reported (and the run can be cancelled) at least every this many unit cells: well under a second.
_PROGRESS_CELLS = 1 << 24
# Joint-histogram entries of the levels finished together (one cumulative sum for all): 8 MB of int64 per table.
_STACKED_ENTRIES = 1 << 20

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


class PairCounter:
    """Running joint histogram of cell intervals: each (min, max) pair packed into one small integer and counted.

    The packed index (``min * n_bins + max``: uint16 up to 256 bins, else uint32) is gathered in a buffer that stays in
    cache and counted by ``np.bincount`` when full; with many bins the buffer grows so that each count is worth its
    ``n_bins ** 2`` table.
    """

    def __init__(self, n_bins: int) -> None:
        self.n_bins = int(n_bins)
        entries = self.n_bins * self.n_bins
        self._buffer = np.empty(max(_SLAB_CELLS, entries // 4), dtype=np.uint16 if entries <= 1 << 16 else np.uint32)
        self._filled = 0
        self._counts = np.zeros(entries, dtype=np.int64)

    def add(self, mins: np.ndarray, maxs: np.ndarray) -> None:
        """Count cells with these intervals; integer arrays of one shape, values in ``[0, n_bins)``."""
        mins, maxs = mins.reshape(-1), maxs.reshape(-1)
        start = 0
        while start < mins.size:
            take = min(self._buffer.size - self._filled, mins.size - start)
            packed = self._buffer[self._filled : self._filled + take]
            # Unsafe casting: the values are known to fit (checked bins, any integer dtype).
            np.multiply(mins[start : start + take], self.n_bins, out=packed, dtype=packed.dtype, casting="unsafe")
            np.add(packed, maxs[start : start + take], out=packed, dtype=packed.dtype, casting="unsafe")
            self._filled += take
            start += take
            if self._filled == self._buffer.size:
                self._flush()

    def _flush(self) -> None:
        self._counts += np.bincount(self._buffer[: self._filled], minlength=self._counts.size)
        self._filled = 0

    @property
    def table(self) -> np.ndarray:
        """``(n_bins, n_bins)`` int64; entry ``[a, b]`` is the number of cells with min ``a`` and max ``b``."""
        self._flush()
        return self._counts.reshape(self.n_bins, self.n_bins)


def joint_interval_histogram(mins: np.ndarray, maxs: np.ndarray, n_bins: int) -> np.ndarray:
    """Count cells per (min, max) pair.

    Args:
        mins, maxs: integer arrays of the same shape, values in ``[0, n_bins)``.

    Returns:
        ``(n_bins, n_bins)`` int64 table; entry ``[a, b]`` is the number of cells with min ``a`` and max ``b``.
    """
    counter = PairCounter(n_bins)
    counter.add(np.asarray(mins), np.asarray(maxs))
    return counter.table


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


def _check_bins(bins: np.ndarray, n_bins: int) -> np.ndarray:
    if not is_dask_array(bins):
        bins = np.asarray(bins)
    if bins.ndim != 3 or min(bins.shape) < 2:
        raise ValueError(f"bins must be a 3-D array with at least 2 voxels per axis; got shape {bins.shape}")
    if not np.issubdtype(bins.dtype, np.integer):
        raise ValueError(f"bins must hold integers (use quantize() first); got dtype {bins.dtype}")
    n_bins = checked_n_bins(n_bins)
    # A clear error, not numpy's MemoryError (or the OOM killer) mid-way.
    check_memory(bins.shape, int(n_bins), streamed=is_dask_array(bins))
    if not is_dask_array(bins):  # a dask volume's slabs are checked as they are read: no pass of its own
        _check_bin_bounds(bins, n_bins)
    return bins


def _check_bin_bounds(bins: np.ndarray, n_bins: int) -> None:
    """Raise ValueError unless every bin lies in ``[0, n_bins)``.

    Scans only for the bounds the dtype does not already guarantee (none for uint8 and 256 bins).
    """
    limits = np.iinfo(bins.dtype)
    low = int(bins.min()) if limits.min < 0 else 0
    high = int(bins.max()) if limits.max >= n_bins else 0
    if low < 0 or high >= n_bins:
        raise ValueError(f"bins must lie in [0, {n_bins}); found {low if low < 0 else high}")


def _index_dtype(n_bins: int) -> np.dtype:
    """The smallest unsigned integer type of the bins the engine works on."""
    return np.dtype(np.uint8 if n_bins <= 256 else np.uint16)


def _counted_row_by_row(cells: int, n_bins: int) -> bool:
    """Whether a level of ``cells`` hyper-cells is counted row by row (larger than its table and than
    :data:`~.cells.GATHERED_CELLS`) rather than gathered whole."""
    return cells > max(GATHERED_CELLS, n_bins * n_bins)


class _LevelHistogram:
    """Joint (min, max) histogram of one octree level, from its rows as they are finished.

    A small level is gathered whole and counted once (its table is made only when asked for: tables are
    ``n_bins ** 2`` int64, 128 MB at 4096 bins); a large one is counted row by row and never held whole.
    """

    def __init__(self, tiles: Shape3, dtype: np.dtype, n_bins: int) -> None:
        self.n_bins = n_bins
        cells = int(np.prod(tiles))
        self._counter = PairCounter(n_bins) if _counted_row_by_row(cells, n_bins) else None
        self._gathered = None if self._counter else (np.empty(tiles, dtype=dtype), np.empty(tiles, dtype=dtype))

    def add_rows(self, first_row: int, mins: np.ndarray, maxs: np.ndarray) -> None:
        if self._counter is not None:
            self._counter.add(mins, maxs)
        else:
            self._gathered[0][first_row : first_row + len(mins)] = mins
            self._gathered[1][first_row : first_row + len(maxs)] = maxs

    def table(self) -> np.ndarray:
        """``(n_bins, n_bins)`` int64, once every row has been added."""
        if self._counter is not None:
            return self._counter.table
        return joint_interval_histogram(*self._gathered, self.n_bins)


def interval_histograms(
    bins: np.ndarray,
    n_bins: int,
    levels: int,
    progress: Optional[ProgressCallback] = None,
    on_slab: Optional[Callable[[int, np.ndarray], None]] = None,
) -> Iterator[tuple[int, Shape3, np.ndarray]]:
    """Joint (min, max) histogram of the hyper-cells of each of the ``levels`` coarsest octree levels.

    One pass over the volume in slabs along axis 0: each slab's unit cells are counted while in cache and folded into
    the coarser levels, whose rows are counted as soon as they are finished; no array of the volume's size is made,
    and a dask volume is read a few planes at a time. Memory: one plane of hyper-cells per level, the levels of at
    most ``GATHERED_CELLS`` hyper-cells, and ``n_bins ** 2`` int64 per table.

    Args:
        bins: 3-D uint8 or uint16 array (numpy), or integer dask array (checked and cast slab by slab), values in
            ``[0, n_bins)``.
        levels: how many of the coarsest levels to count.
        progress: called as ``progress(fraction, message)`` at least every ``_PROGRESS_CELLS`` unit cells and after
            each level; raising from it aborts.
        on_slab: called as ``on_slab(first, voxels)`` with each slab of bins read (in order along axis 0, the next
            slab's first plane included), so that other passes over the volume can ride on this one.

    Yields:
        ``(level, size, histogram)`` finest level first: level number (1 = coarsest), hyper-cell size in unit cells,
        ``(n_bins, n_bins)`` int64 table.
    """
    grid = tuple(n - 1 for n in bins.shape)
    sizes = octree_levels(grid)
    unit_level = len(sizes)
    histograms: dict[int, _LevelHistogram] = {}

    def count_rows(level: int, first_row: int, mins: np.ndarray, maxs: np.ndarray) -> None:
        if level in histograms:
            histograms[level].add_rows(first_row, mins, maxs)

    dtype = bins.dtype if bins.dtype in (np.uint8, np.uint16) else _index_dtype(n_bins)
    builder = OctreeBuilder(grid, dtype, count_rows)
    for level in range(min(levels, unit_level - 1), 0, -1):
        histograms[level] = _LevelHistogram(builder.tiles(level), dtype, n_bins)
    unit_cells = int(np.prod(grid))
    total = unit_cells + builder.n_cells
    unit_counter = PairCounter(n_bins) if levels == unit_level else None
    reported = 0
    chunked = is_dask_array(bins)
    for start, voxels in voxel_slabs(bins) if chunked else [(0, bins)]:
        if chunked:
            _check_bin_bounds(voxels, n_bins)
            voxels = voxels.astype(dtype, copy=False)
        if on_slab is not None:
            on_slab(start, voxels)
        for first, mins, maxs in unit_cell_slabs(voxels, _SLAB_CELLS // (grid[1] * grid[2])):
            first += start
            if unit_counter is not None:
                unit_counter.add(mins, maxs)
            builder.add_slab(first, mins, maxs)
            done = (first + len(mins)) * grid[1] * grid[2]
            if progress is not None and done - reported >= _PROGRESS_CELLS:
                progress(done / total, "similarity: unit cells")
                reported = done
    if unit_counter is not None:
        table = unit_counter.table
        unit_counter = None
        yield unit_level, (1, 1, 1), table
        del table  # tables are n_bins ** 2 int64 (128 MB at 4096 bins): hold none longer than the consumer does
    done = unit_cells
    for level, histogram in histograms.items():
        yield level, sizes[level - 1], histogram.table()
        done += builder.n_level_cells(level)
        if progress is not None:
            progress(done / total, f"similarity: level {level} of {unit_level}")


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
    on_slab: Optional[Callable[[int, np.ndarray], None]] = None,
) -> IsovalueSimilarity:
    """Hierarchical similarity of all isovalue pairs, with the per-level cell counts it came from.

    See :func:`similarity_matrix` for the arguments, and :func:`interval_histograms` for ``on_slab``.
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

    if bins.dtype not in (np.uint8, np.uint16) and not is_dask_array(bins):  # a dask volume's slabs are cast as read
        bins = bins.astype(_index_dtype(n_bins))
    weights = level_weights(levels)
    # Only the upper triangles (i <= j) are summed; the matrix is mirrored at the end. Ma & Entezari's A(i, j) and
    # A(j, i) = O(i, j) / n(i) are summed apart ("by column" and "by row"), then merged by their element-wise minimum.
    by_column = np.zeros((n_bins, n_bins), dtype=np.float64)
    by_row = np.zeros_like(by_column) if normalization == "ma-entezari" else None
    cell_counts = np.zeros((levels, n_bins), dtype=np.int64)
    sizes = [None] * levels
    histograms = interval_histograms(bins, n_bins, levels, progress, on_slab)
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
