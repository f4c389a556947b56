"""Step 2 of the pipeline: marching-cubes cells, their value intervals, and the octree of hyper-cells over them.

A unit cell is the 2x2x2 block of neighbouring voxels; its interval is ``[min, max]`` over its 8 corners. The octree
levels tile the grid of unit cells with hyper-cells whose interval is the union (hull) of their unit cells' intervals.

The unit cells of a large volume are never held whole: they are computed slab by slab (a few planes at a time, in
reused buffers that stay in cache), and each slab is reduced at once into the coarser levels that need it
(:class:`OctreeBuilder`); a level holds only its unfinished row of hyper-cells, so no level is held whole either.
"""

from collections.abc import Iterator
from typing import Callable, Optional

import numpy as np

Shape3 = tuple[int, int, int]

# Hyper-cells of a level small enough to be gathered whole and counted once (8 MB of uint8 minima and maxima); a larger
# level is counted row by row as its rows are finished, never held whole.
GATHERED_CELLS = 1 << 22


def octree_levels(cell_grid_shape: Shape3) -> list[Shape3]:
    """Hyper-cell size per axis at each octree level, coarsest (level 1) first, unit cells last.

    Level 1 is the whole grid of unit cells; each next level ceil-halves the size on every axis until all are 1.

    Args:
        cell_grid_shape: number of unit cells along each axis (voxels minus one).

    Returns:
        One ``(s0, s1, s2)`` size per level, in unit cells; e.g. 128 x 128 x 115 voxels gives 8 levels from
        ``(127, 127, 114)`` to ``(1, 1, 1)``.
    """
    size = tuple(int(n) for n in cell_grid_shape)
    if len(size) != 3 or min(size) < 1:
        raise ValueError(f"expected three positive unit-cell counts; got {cell_grid_shape!r}")
    sizes = [size]
    while max(size) > 1:
        size = tuple((s + 1) // 2 for s in size)
        sizes.append(size)
    return sizes


def complete_rows(size: int, n: int, first: int, stop: int) -> range:
    """The rows of hyper-cells ``size`` unit cells thick (tiling ``n`` unit-cell planes from 0, the last one clipped)
    that lie wholly inside the unit-cell planes ``[first, stop)``; a row crossing ``first`` or ``stop`` is partial."""
    return range(-(-first // size), -(-n // size) if stop == n else stop // size)


def unit_cell_slabs(bins: np.ndarray, planes: int) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Unit-cell intervals, ``planes`` planes of cells along axis 0 at a time.

    Args:
        bins: 3-D integer array of shape ``(n0, n1, n2)``, every axis at least 2.
        planes: unit-cell planes per slab (the last slab may have fewer).

    Yields:
        ``(first, mins, maxs)``: index of the slab's first unit-cell plane, and the minimum and maximum over the 8
        corners of its cells, each of shape ``(p, n1 - 1, n2 - 1)`` and the dtype of ``bins``. The arrays are buffers
        reused by the next slab: copy what must outlive the iteration.
    """
    n0, n1, n2 = bins.shape
    planes = max(1, min(int(planes), n0 - 1))
    # Reduce one axis at a time; the two scratch arrays serve the minimum, then the maximum.
    pairs = np.empty((planes, n1, n2), dtype=bins.dtype)
    rows = np.empty((planes, n1 - 1, n2), dtype=bins.dtype)
    mins = np.empty((planes, n1 - 1, n2 - 1), dtype=bins.dtype)
    maxs = np.empty_like(mins)
    for first in range(0, n0 - 1, planes):
        p = min(planes, n0 - 1 - first)
        voxels = bins[first : first + p + 1]  # the cells' voxels: one plane more than cells
        for reduce, out in ((np.minimum, mins), (np.maximum, maxs)):
            reduce(voxels[:-1], voxels[1:], out=pairs[:p])
            reduce(pairs[:p, :-1], pairs[:p, 1:], out=rows[:p])
            reduce(rows[:p, :, :-1], rows[:p, :, 1:], out=out[:p])
        yield first, mins[:p], maxs[:p]


def unit_cell_intervals(bins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum and maximum over the 8 corners of every unit cell (whole arrays: for small volumes and tests).

    Args:
        bins: 3-D integer array of shape ``(n0, n1, n2)``, every axis at least 2.

    Returns:
        ``(mins, maxs)``, each of shape ``(n0 - 1, n1 - 1, n2 - 1)`` and the dtype of ``bins``.
    """
    n0, n1, n2 = bins.shape
    mins = np.empty((n0 - 1, n1 - 1, n2 - 1), dtype=bins.dtype)
    maxs = np.empty_like(mins)
    for first, slab_mins, slab_maxs in unit_cell_slabs(bins, 32):
        mins[first : first + len(slab_mins)] = slab_mins
        maxs[first : first + len(slab_maxs)] = slab_maxs
    return mins, maxs


def _reduce_axis(values: np.ndarray, axis: int, factor: int, reduce: np.ufunc) -> np.ndarray:
    """Reduce ``values`` along ``axis`` over blocks of ``factor`` elements from index 0 (the last block clipped)."""
    length = values.shape[axis]
    if factor == 1 or length == 1:
        return values

    def every(offset: int) -> np.ndarray:  # element ``offset`` of every block that has one
        take = [slice(None)] * values.ndim
        take[axis] = slice(offset, None, factor)
        return values[tuple(take)]

    def head(array: np.ndarray, count: int) -> np.ndarray:
        take = [slice(None)] * array.ndim
        take[axis] = slice(0, count)
        return array[tuple(take)]

    firsts, seconds = every(0), every(1)
    out = np.empty(firsts.shape, dtype=values.dtype)
    paired = seconds.shape[axis]
    reduce(head(firsts, paired), seconds, out=head(out, paired))
    if paired < firsts.shape[axis]:  # the clipped last block has a single element
        take = [slice(None)] * values.ndim
        take[axis] = slice(paired, None)
        out[tuple(take)] = firsts[tuple(take)]
    # Offsets 2.. of every block at once: strided views, so each element is read once whatever the factor.
    for offset in range(2, min(factor, length)):
        part = every(offset)
        target = head(out, part.shape[axis])
        reduce(target, part, out=target)
    return out


def block_reduce(values: np.ndarray, factors: Shape3, reduce: np.ufunc) -> np.ndarray:
    """Reduce a 3-D array over blocks of ``factors`` elements per axis, tiling from index 0 (last blocks clipped).

    Axis 0 first: its blocks are whole contiguous planes, so the later, strided axes see less data.
    """
    for axis, factor in enumerate(factors):
        values = _reduce_axis(values, axis, factor, reduce)
    return values


def _reduction_factors(fine: Shape3, coarse: Shape3, cell_grid_shape: Shape3) -> Optional[Shape3]:
    """Blocks of ``fine`` hyper-cells per ``coarse`` one, or None when the two tilings do not nest."""
    factors = []
    for f, c, n in zip(fine, coarse, cell_grid_shape):
        if c >= n:
            factors.append(-(-n // f))  # one hyper-cell spans the axis: it holds every fine block
        elif c % f == 0:
            factors.append(c // f)
        else:
            return None
    return tuple(factors)


RowSink = Callable[[int, int, np.ndarray, np.ndarray], None]


class OctreeBuilder:
    """Intervals of the hyper-cells of every octree level but the unit cells, streamed row by row along axis 0.

    Each level is block-reduced from the smallest finer level whose tiling nests in it: the next finer level whenever
    sizes halve exactly (power-of-two grids); a level nested in no finer level but the unit cells (e.g. 15 unit cells
    per hyper-cell under a level of 8) is reduced from the unit-cell slabs, like the second finest level. A level holds
    only its one unfinished row of hyper-cells (a plane of them along axis 0): as soon as a row is complete it is handed
    to ``sink`` and folded into the coarser levels, so no level is held whole (memory: one plane of hyper-cells per
    level, whatever the volume's depth).

    A builder may see only the unit-cell planes ``[first, stop)`` of the grid (a part of the volume, the others being
    built elsewhere): a row wholly inside them is complete and goes to ``sink``; a row crossing ``first`` or ``stop``
    is partial, the hull of the part's unit cells in it, and goes to ``partial_sink`` (the hull of the same row from
    every part that crosses it is the row's interval). A partial row only feeds coarser rows that are partial too (a
    coarser row contains it), so the complete rows are exact.

    Usage: :meth:`add_slab` for every slab of :func:`unit_cell_slabs`, in order along axis 0 from plane ``first`` to
    ``stop``, then :meth:`finish`; every complete row of every level has been handed to ``sink`` once, and every
    partial one to ``partial_sink`` once.
    """

    def __init__(
        self,
        cell_grid_shape: Shape3,
        dtype: np.dtype,
        sink: RowSink,
        planes: Optional[tuple[int, int]] = None,
        partial_sink: Optional[RowSink] = None,
    ) -> None:
        """
        Args:
            cell_grid_shape: unit cells per axis.
            dtype: integer dtype of the intervals.
            sink: called as ``sink(level, first_row, mins, maxs)`` with complete rows ``first_row ..`` of a level
                (arrays of shape ``(rows, t1, t2)``, valid only during the call), every row of every level once.
            planes: ``(first, stop)``, the unit-cell planes along axis 0 this builder sees (default all).
            partial_sink: called like ``sink`` with each partial row (one row at a time); needed unless ``planes``
                is the whole grid.
        """
        self.grid = tuple(int(n) for n in cell_grid_shape)
        self.first, self.stop = (0, self.grid[0]) if planes is None else (int(planes[0]), int(planes[1]))
        if not 0 <= self.first <= self.stop <= self.grid[0]:
            raise ValueError(f"planes must lie in [0, {self.grid[0]}]; got {planes!r}")
        self._partial_sink = partial_sink
        self.sizes = octree_levels(self.grid)
        self._sink = sink
        # level -> (source level, or None for the unit cells; blocks of the source per hyper-cell)
        self._sources: dict[int, tuple[Optional[int], Shape3]] = {}
        for level in range(len(self.sizes) - 1, 0, -1):
            size = self.sizes[level - 1]
            nested = []
            for finer in self._sources:
                factors = _reduction_factors(self.sizes[finer - 1], size, self.grid)
                if factors is not None:
                    nested.append((self.n_level_cells(finer), finer, factors))
            if nested:
                _, source, factors = min(nested)
                self._sources[level] = (source, factors)
            else:
                self._sources[level] = (None, _reduction_factors((1, 1, 1), size, self.grid))
        self._dependents: dict[Optional[int], list[int]] = {}
        for level, (source, _) in self._sources.items():
            self._dependents.setdefault(source, []).append(level)
        # level -> (mins, maxs) of its unfinished row, shape (1, t1, t2); absent when no row is begun.
        self._pending: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def tiles(self, level: int) -> Shape3:
        """Hyper-cells per axis at ``level``."""
        return tuple(-(-n // s) for n, s in zip(self.grid, self.sizes[level - 1]))

    def n_level_cells(self, level: int) -> int:
        """Hyper-cells at ``level``."""
        return int(np.prod(self.tiles(level)))

    @property
    def n_cells(self) -> int:
        """Hyper-cells over all levels but the unit cells."""
        return sum(self.n_level_cells(level) for level in self._sources)

    def add_slab(self, first: int, mins: np.ndarray, maxs: np.ndarray) -> None:
        """Fold unit-cell planes ``first .. first + len(mins) - 1`` (the next ones along axis 0) into the levels."""
        for level in self._dependents.get(None, ()):
            self._fold(level, first, mins, maxs)

    def _fold(self, level: int, first: int, mins: np.ndarray, maxs: np.ndarray) -> None:
        """Fold planes ``first ..`` of the level's source into its rows, handing on every row they finish."""
        source, (f0, f1, f2) = self._sources[level]
        planes = self.grid[0] if source is None else self.tiles(source)[0]
        count = len(mins)
        # Planes that finish the row begun by earlier planes, then whole rows, then the start of the next row.
        head = min(count, -first % f0)
        if head:
            self._extend_pending(level, mins[:head], maxs[:head], (head, f1, f2))
            if (first + head) % f0 == 0 or first + head == planes:
                self._finish(level, first // f0, *self._pending.pop(level))
        rest = first + head
        whole = count - head if first + count == planes else (count - head) // f0 * f0
        if whole:
            reduced = [block_reduce(a[head : head + whole], (f0, f1, f2), r) for a, r in _extremes(mins, maxs)]
            self._finish(level, rest // f0, *reduced)
        if head + whole < count:
            tail = count - head - whole
            self._extend_pending(level, mins[head + whole :], maxs[head + whole :], (tail, f1, f2))

    def _extend_pending(self, level: int, mins: np.ndarray, maxs: np.ndarray, factors: Shape3) -> None:
        reduced = [block_reduce(a, factors, r) for a, r in _extremes(mins, maxs)]
        if level in self._pending:
            for target, block, (_, reduce) in zip(self._pending[level], reduced, _extremes(mins, maxs)):
                reduce(target, block, out=target)
        else:  # a copy: the block may be a view of the caller's reused buffer
            self._pending[level] = (reduced[0].copy(), reduced[1].copy())

    def finish(self) -> None:
        """Hand on the unfinished rows, partial at ``stop``: finest level first, each folded into the coarser ones."""
        for level in range(len(self.sizes) - 1, 0, -1):
            if level in self._pending:
                self._finish(level, (self.stop - 1) // self.sizes[level - 1][0], *self._pending.pop(level))

    def _finish(self, level: int, first_row: int, mins: np.ndarray, maxs: np.ndarray) -> None:
        inside = complete_rows(self.sizes[level - 1][0], self.grid[0], self.first, self.stop)
        complete = range(max(first_row, inside.start), min(first_row + len(mins), inside.stop))
        for row in range(first_row, first_row + len(mins)):
            if row not in complete:
                k = row - first_row
                self._partial_sink(level, row, mins[k : k + 1], maxs[k : k + 1])
        if complete:
            k = complete[0] - first_row
            self._sink(level, complete[0], mins[k : k + len(complete)], maxs[k : k + len(complete)])
        for coarser in self._dependents.get(level, ()):
            self._fold(coarser, first_row, mins, maxs)


def _extremes(mins: np.ndarray, maxs: np.ndarray) -> tuple[tuple[np.ndarray, np.ufunc], tuple[np.ndarray, np.ufunc]]:
    """The minima with their reduction, then the maxima with theirs."""
    return (mins, np.minimum), (maxs, np.maximum)
