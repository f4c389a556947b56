"""Step 2 of the pipeline: marching-cubes cells, their value intervals, and the octree of hyper-cells over them.

A unit cell is the 2x2x2 block of neighbouring voxels; its interval is ``[min, max]`` over its 8 corners. The octree
levels tile the grid of unit cells with hyper-cells whose interval is the union (hull) of their unit cells' intervals.

The unit cells of a large volume are never held whole: they are computed slab by slab (a few planes at a time, in
reused buffers that stay in cache), and each slab is reduced at once into the coarser levels that need it
(:class:`OctreeBuilder`), which are 8 or more times smaller.
"""

from collections.abc import Iterator
from typing import Optional

import numpy as np

Shape3 = tuple[int, int, int]


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


class OctreeBuilder:
    """Intervals of the hyper-cells of every octree level but the unit cells, from a stream of unit-cell slabs.

    Each level is block-reduced from the smallest finer level whose tiling nests in it: the next finer level whenever
    sizes halve exactly (power-of-two grids). A level nested in no finer level but the unit cells (e.g. 15 unit cells
    per hyper-cell under a level of 8) is reduced from the unit-cell slabs as they stream by, like the second finest
    level; the others are reduced once the stream has ended.

    Usage: :meth:`add_slab` for every slab of :func:`unit_cell_slabs`, in any order, then :meth:`levels`.
    """

    def __init__(self, cell_grid_shape: Shape3, dtype: np.dtype) -> None:
        self.grid = tuple(int(n) for n in cell_grid_shape)
        self.sizes = octree_levels(self.grid)
        # level -> (source level or None for the unit cells, blocks of the source per hyper-cell)
        self._sources: dict[int, tuple[Optional[int], Shape3]] = {}
        # level -> (mins, maxs) of the levels fed by the slabs; min and max identities until every slab is added.
        self._streamed: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for level in range(len(self.sizes) - 1, 0, -1):
            size = self.sizes[level - 1]
            nested = []
            for finer in self._sources:
                factors = _reduction_factors(self.sizes[finer - 1], size, self.grid)
                if factors is not None:
                    nested.append((self._cells(finer), finer, factors))
            if nested:
                _, source, factors = min(nested)
                self._sources[level] = (source, factors)
                continue
            self._sources[level] = (None, _reduction_factors((1, 1, 1), size, self.grid))
            shape = self._tiles(level)
            self._streamed[level] = (np.full(shape, np.iinfo(dtype).max, dtype=dtype), np.zeros(shape, dtype=dtype))

    def _tiles(self, level: int) -> Shape3:
        return tuple(-(-n // s) for n, s in zip(self.grid, self.sizes[level - 1]))

    def _cells(self, level: int) -> int:
        return int(np.prod(self._tiles(level)))

    @property
    def n_cells(self) -> int:
        """Hyper-cells over all levels but the unit cells."""
        return sum(self._cells(level) for level in self._sources)

    def add_slab(self, first: int, mins: np.ndarray, maxs: np.ndarray) -> None:
        """Fold unit-cell planes ``first .. first + len(mins) - 1`` into the levels reduced from the unit cells."""
        for level, targets in self._streamed.items():
            f0, f1, f2 = self._sources[level][1]
            # Planes that finish a hyper-cell begun in an earlier slab, then hyper-cells starting in this one.
            head = min(len(mins), -first % f0)
            parts = ((first // f0, 0, head, (head, f1, f2)), ((first + head) // f0, head, len(mins), (f0, f1, f2)))
            for row, start, stop, factors in parts:
                if start == stop:
                    continue
                for values, target, reduce in ((mins, targets[0], np.minimum), (maxs, targets[1], np.maximum)):
                    block = block_reduce(values[start:stop], factors, reduce)
                    rows = target[row : row + len(block)]
                    reduce(rows, block, out=rows)  # the hyper-cells may hold planes of other slabs too

    def levels(self) -> Iterator[tuple[int, Shape3, np.ndarray, np.ndarray]]:
        """Intervals of every level but the unit cells, finest first, once every slab has been added.

        Yields:
            ``(level, size, mins, maxs)``: level number (1 = coarsest), hyper-cell size in unit cells, and the interval
            arrays of shape ``ceil(c / size)`` per axis.
        """
        done: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for level, (source, factors) in self._sources.items():
            if source is None:
                done[level] = self._streamed[level]
            else:
                source_mins, source_maxs = done[source]
                done[level] = (
                    block_reduce(source_mins, factors, np.minimum),
                    block_reduce(source_maxs, factors, np.maximum),
                )
            yield (level, self.sizes[level - 1], *done[level])
