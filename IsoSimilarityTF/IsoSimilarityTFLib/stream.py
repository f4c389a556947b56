"""The one stream over the bins: the joint (min, max) histograms of the hyper-cells of every octree level.

One pass over the volume in slabs along axis 0 (:class:`~.source.VolumeSource`): each slab's unit cells are counted
while in cache and folded into the coarser levels (:class:`~.cells.OctreeBuilder`), whose rows are counted as soon
as they are finished; its tap (:class:`~.taps.SlabTap`) gathers what later steps need from the same slabs. On a
cluster the pass runs in parts along axis 0, one per worker, merged pairwise (:func:`merge_counts`): the same integer
counts. :mod:`.similarity` turns the tables into the similarity matrix.
"""

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace
from functools import partial
from typing import Callable, Optional

import numpy as np

from .cells import GATHERED_CELLS, OctreeBuilder, Shape3, complete_rows, octree_levels, unit_cell_slabs
from .memory import check_memory
from .quantize import bins_dtype, checked_n_bins
from .source import Slab, VolumeSource
from .taps import SlabTap

# Unit cells per slab, and (min, max) pairs counted per np.bincount call: bincount first converts its input to a
# 64-bit index, which must stay in the core's cache (2 MB of 256K cells).
_SLAB_CELLS = 1 << 18
# Progress is reported (and the run can be cancelled) at least every this many unit cells: well under a second.
_PROGRESS_CELLS = 1 << 24

ProgressCallback = Callable[[float, str], None]


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


def bins_source(bins, n_bins: int) -> VolumeSource:
    """The bins as a source, checked: their shape and type now, their values as each slab is read."""
    if not isinstance(bins, VolumeSource):
        shape = np.shape(bins)
        if len(shape) != 3 or min(shape) < 2:
            raise ValueError(f"bins must be a 3-D array with at least 2 voxels per axis; got shape {shape}")
        bins = VolumeSource(bins)
    if not np.issubdtype(bins.dtype, np.integer):
        raise ValueError(f"bins must hold integers (use quantize() first); got dtype {bins.dtype}")
    checked_n_bins(n_bins)
    # A clear error, not numpy's MemoryError (or the OOM killer) mid-way.
    check_memory(bins.shape, int(n_bins))
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


def _counted_row_by_row(cells: int, n_bins: int) -> bool:
    """Whether a level of ``cells`` hyper-cells is counted row by row (larger than its table and than
    :data:`~.cells.GATHERED_CELLS`) rather than gathered whole."""
    return cells > max(GATHERED_CELLS, n_bins * n_bins)


class _LevelRows:
    """The complete rows of one octree level in a part of the volume, as they are finished.

    Rows of more hyper-cells than their table (and than :data:`~.cells.GATHERED_CELLS`) are counted into a table, never
    held whole; fewer are gathered and counted when the whole volume's rows are (tables are ``n_bins ** 2`` int64,
    128 MB at 4096 bins: a part holds none it does not need).
    """

    def __init__(self, rows: range, tiles: Shape3, dtype: np.dtype, n_bins: int) -> None:
        self._first = rows.start
        shape = (len(rows), tiles[1], tiles[2])
        self._counter = PairCounter(n_bins) if _counted_row_by_row(int(np.prod(shape)), n_bins) else None
        self._gathered = None if self._counter else (np.empty(shape, dtype=dtype), np.empty(shape, dtype=dtype))

    def add_rows(self, first_row: int, mins: np.ndarray, maxs: np.ndarray) -> None:
        if self._counter is not None:
            self._counter.add(mins, maxs)
        else:
            k = first_row - self._first
            self._gathered[0][k : k + len(mins)] = mins
            self._gathered[1][k : k + len(maxs)] = maxs

    def put(self, level: int, counts: "CellCounts") -> None:
        """Hand the rows to ``counts``: as a table when counted, else as one block of rows to count."""
        if self._counter is not None:
            counts.tables[level] = self._counter.table
        elif len(self._gathered[0]):
            counts.rows[level] = [self._gathered]


@dataclass
class CellCounts:
    """Joint (min, max) histograms of the hyper-cells of the unit-cell planes ``[first, stop)`` along axis 0 (a part
    of the volume, or all of it), for the levels counted; parts side by side are :func:`merged <merge_counts>`.

    Attributes:
        first, stop: the unit-cell planes counted.
        tables: level -> ``(n_bins, n_bins)`` int64 table of complete rows counted.
        rows: level -> blocks ``(mins, maxs)`` of complete rows not yet counted, each of shape ``(rows, t1, t2)``.
        partial: ``(level, row)`` -> ``(mins, maxs)`` of shape ``(1, t1, t2)``: rows crossing ``first`` or ``stop``,
            the hull of this part's unit cells in them.
        ends: the first and the last voxel plane of the part, ``(n1, n2)`` each: the unit cells between two parts need
            a plane of each.
        tap: the voxel counts and background-contact planes of the part's voxels, when asked for.
    """

    first: int
    stop: int
    tables: dict[int, np.ndarray]
    rows: dict[int, list[tuple[np.ndarray, np.ndarray]]]
    partial: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]
    ends: tuple[np.ndarray, np.ndarray]
    tap: Optional[SlabTap]


@dataclass(frozen=True)
class _CountSpec:
    """What every part of one similarity pass counts: the volume's shape (voxels), bins, levels and bins' dtype, and
    whether its tap gathers voxel counts (with which preview steps and kept planes, see :class:`~.taps.SlabTap`)."""

    shape: Shape3
    n_bins: int
    levels: int
    dtype: np.dtype
    tap: bool
    preview_steps: tuple[int, int, int] = (0, 0, 0)
    kept_planes: tuple[int, ...] = ()

    @property
    def grid(self) -> Shape3:
        return tuple(n - 1 for n in self.shape)

    def counted_levels(self) -> list[int]:
        """The levels counted (the ``levels`` coarsest), finest first."""
        return list(range(self.levels, 0, -1))


def count_cells(
    slabs: Iterable[tuple[int, np.ndarray]],
    spec: _CountSpec,
    first: int,
    stop: int,
    progress: Optional[ProgressCallback] = None,
) -> CellCounts:
    """Count the unit-cell planes ``[first, stop)`` of a volume into the octree levels of the whole volume.

    Args:
        slabs: ``(start, voxels)`` slabs of bins covering the voxel planes ``first .. stop`` in order along axis 0,
            each of shape ``(planes, n1, n2)`` (consecutive slabs may share a plane: each unit cell is counted once,
            from the slab holding both of its planes).
        spec: what is counted.
        progress: called as ``progress(fraction)`` with the share of the volume's unit cells counted (this part's
            unit cells), at least every ``_PROGRESS_CELLS`` unit cells.
    """
    grid, n_bins = spec.grid, spec.n_bins
    builder_levels: dict[int, _LevelRows] = {}
    partial: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def count_rows(level: int, first_row: int, mins: np.ndarray, maxs: np.ndarray) -> None:
        if level in builder_levels:
            builder_levels[level].add_rows(first_row, mins, maxs)

    def keep_partial(level: int, row: int, mins: np.ndarray, maxs: np.ndarray) -> None:
        if level in builder_levels:
            partial[level, row] = (mins.copy(), maxs.copy())

    builder = OctreeBuilder(grid, spec.dtype, count_rows, (first, stop), keep_partial)
    unit_level = len(builder.sizes)
    unit_rows = None
    for level in spec.counted_levels():
        tiles = builder.tiles(level) if level < unit_level else grid
        inside = complete_rows(builder.sizes[level - 1][0], grid[0], first, stop)
        rows = _LevelRows(inside, tiles, spec.dtype, n_bins)
        if level < unit_level:
            builder_levels[level] = rows
        else:
            unit_rows = rows
    tap = SlabTap(spec.shape, n_bins, first, spec.preview_steps, spec.kept_planes) if spec.tap else None
    total = int(np.prod(grid))
    reported = 0
    first_plane = voxels = None
    for start, voxels in slabs:
        if tap is not None:
            tap(start, voxels)
        if first_plane is None:  # a copy: a view would hold the whole slab
            first_plane = voxels[0].copy()
        for plane, mins, maxs in unit_cell_slabs(voxels, _SLAB_CELLS // (grid[1] * grid[2])):
            plane += start
            if unit_rows is not None:
                unit_rows.add_rows(plane, mins, maxs)
            builder.add_slab(plane, mins, maxs)
            done = (plane + len(mins)) * grid[1] * grid[2]
            if progress is not None and done - reported >= _PROGRESS_CELLS:
                progress(done / total)
                reported = done
    builder.finish()
    counts = CellCounts(first, stop, {}, {}, partial, (first_plane, voxels[-1].copy()), tap)
    for level, rows in builder_levels.items():
        rows.put(level, counts)
    if unit_rows is not None:
        unit_rows.put(unit_level, counts)
    return counts


def merge_counts(low: CellCounts, high: CellCounts, spec: _CountSpec) -> CellCounts:
    """The counts of two parts side by side along axis 0 (``low`` first), exactly those of the two as one part.

    The unit-cell plane between them (made of ``low``'s last voxel plane and ``high``'s first) is counted here; each
    row partial in both is the hull of its two halves, and counted once it is wholly inside the merged planes.
    Reuses (and changes) the arrays of ``low`` and ``high``.
    """
    if high.first != low.stop + 1:
        raise ValueError(f"parts must follow each other; got planes up to {low.stop} then from {high.first}")
    # Its voxels were counted by the tap of their parts.
    border_spec = replace(spec, tap=False)
    border = count_cells([(low.stop, np.stack((low.ends[1], high.ends[0])))], border_spec, low.stop, high.first)
    merged = low
    for part in (border, high):
        for level, table in part.tables.items():
            if level in merged.tables:
                merged.tables[level] += table
            else:
                merged.tables[level] = table
        for level, blocks in part.rows.items():
            merged.rows.setdefault(level, []).extend(blocks)
        for key, (mins, maxs) in part.partial.items():
            if key in merged.partial:
                np.minimum(merged.partial[key][0], mins, out=merged.partial[key][0])
                np.maximum(merged.partial[key][1], maxs, out=merged.partial[key][1])
            else:
                merged.partial[key] = (mins, maxs)
        merged.stop = part.stop
    sizes, n = octree_levels(spec.grid), spec.grid[0]
    for level, row in list(merged.partial):
        if row in complete_rows(sizes[level - 1][0], n, merged.first, merged.stop):
            merged.rows.setdefault(level, []).append(merged.partial.pop((level, row)))
    merged.ends = (low.ends[0], high.ends[1])
    if merged.tap is not None:
        merged.tap.merge(high.tap)
    return merged


def _checked_slabs(slabs: Iterable[Slab], spec: _CountSpec) -> Iterator[Slab]:
    """Slabs of bins, each checked against ``n_bins`` (one scan per slab, only for bounds its dtype does not already
    guarantee) and cast to the engine's dtype."""
    for first, voxels in slabs:
        _check_bin_bounds(voxels, spec.n_bins)
        yield first, voxels.astype(spec.dtype, copy=False)


def _count_part(
    slabs: Iterable[Slab], first: int, stop: int, progress: Optional[Callable[[float], None]], *, spec: _CountSpec
) -> CellCounts:
    """:func:`count_cells` of a part of the volume (see :meth:`.source.VolumeSource.map_reduce`)."""
    return count_cells(_checked_slabs(slabs, spec), spec, first, stop, progress)


def _level_cells(grid: Shape3) -> list[int]:
    """Hyper-cells of each octree level of a grid of unit cells, coarsest first (unit cells last)."""
    return [int(np.prod([-(-n // s) for n, s in zip(grid, size)], dtype=np.int64)) for size in octree_levels(grid)]


def _level_tables(
    counts: CellCounts, spec: _CountSpec, progress: Optional[ProgressCallback]
) -> Iterator[tuple[int, Shape3, np.ndarray]]:
    """The tables of the whole volume's counts, one level at a time, finest first (see :func:`interval_histograms`)."""
    if counts.partial or (counts.first, counts.stop) != (0, spec.grid[0]):
        raise ValueError("the counts do not cover the whole volume")
    sizes = octree_levels(spec.grid)
    cells = _level_cells(spec.grid)
    done, total = cells[-1], sum(cells)
    for level in spec.counted_levels():
        table = counts.tables.pop(level, None)
        blocks = counts.rows.pop(level, [])
        if blocks or table is None:
            counter = PairCounter(spec.n_bins)
            for mins, maxs in blocks:
                counter.add(mins, maxs)
            table = counter.table if table is None else table + counter.table
        del blocks
        yield level, sizes[level - 1], table
        del table  # tables are n_bins ** 2 int64 (128 MB at 4096 bins): hold none longer than the consumer does
        if progress is not None and level < len(sizes):
            done += cells[level - 1]
            progress(done / total, f"similarity: level {level} of {len(sizes)}")


def interval_histograms(
    bins,
    n_bins: int,
    levels: int,
    progress: Optional[ProgressCallback] = None,
    tap: Optional[SlabTap] = None,
) -> Iterator[tuple[int, Shape3, np.ndarray]]:
    """Joint (min, max) histogram of the hyper-cells of each of the ``levels`` coarsest octree levels.

    One pass over the volume in slabs along axis 0: each slab's unit cells are counted while in cache and folded into
    the coarser levels, whose rows are counted as soon as they are finished; no array of the volume's size is made,
    and a dask volume is read a few planes at a time. Memory: one plane of hyper-cells per level, the levels of at
    most ``GATHERED_CELLS`` hyper-cells, and ``n_bins ** 2`` int64 per table.

    On a dask.distributed cluster (or dask's ``"processes"`` scheduler), a dask volume is counted in parts along axis 0
    (whole rows of chunks, one part per worker) that run on the workers, each reading its own chunks, and are merged
    there (:func:`merge_counts`): the same integer counts (see :meth:`.source.VolumeSource.map_reduce`).

    Args:
        bins: a :class:`~.source.VolumeSource` of bins, or a 3-D integer array (numpy or dask), values in
            ``[0, n_bins)`` (checked and cast slab by slab).
        levels: how many of the coarsest levels to count.
        progress: called as ``progress(fraction, message)`` during the pass and after each level; raising from it
            aborts.
        tap: gathers the voxel counts, the planes it keeps and the preview during the pass.

    Yields:
        ``(level, size, histogram)`` finest level first: level number (1 = coarsest), hyper-cell size in unit cells,
        ``(n_bins, n_bins)`` int64 table.
    """
    bins = bins_source(bins, n_bins)
    dtype = bins.dtype if bins.dtype in (np.uint8, np.uint16) else bins_dtype(n_bins)
    spec = _CountSpec(
        bins.shape,
        int(n_bins),
        int(levels),
        np.dtype(dtype),
        tap is not None,
        tap.preview_steps if tap is not None else (0, 0, 0),
        tap.kept_planes if tap is not None else (),
    )
    cells = _level_cells(spec.grid)
    unit_share = cells[-1] / sum(cells)

    def report(fraction: float) -> None:
        progress(fraction * unit_share, "similarity: unit cells")

    counts = bins.map_reduce(
        partial(_count_part, spec=spec), partial(merge_counts, spec=spec), report if progress is not None else None
    )
    if tap is not None:
        tap.merge(counts.tap)
    yield from _level_tables(counts, spec, progress)
