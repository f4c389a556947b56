"""Step 2 of the pipeline: marching-cubes cells, their value intervals, and the octree of hyper-cells over them.

A unit cell is the 2x2x2 block of neighbouring voxels; its interval is ``[min, max]`` over its 8 corners. The octree
levels tile the grid of unit cells with hyper-cells whose interval is the union (hull) of their unit cells' intervals.
"""

from collections.abc import Iterator
from typing import Optional

import numpy as np

Shape3 = tuple[int, int, int]

# Voxel planes handled at once when reducing voxels to unit cells: bounds temporaries on large volumes.
_SLAB_PLANES = 32


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


def unit_cell_intervals(bins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum and maximum over the 8 corners of every unit cell.

    Args:
        bins: 3-D integer array of shape ``(n0, n1, n2)``, every axis at least 2.

    Returns:
        ``(mins, maxs)``, each of shape ``(n0 - 1, n1 - 1, n2 - 1)`` and the dtype of ``bins``.
    """
    n0, n1, n2 = bins.shape
    mins = np.empty((n0 - 1, n1 - 1, n2 - 1), dtype=bins.dtype)
    maxs = np.empty_like(mins)
    for start in range(0, n0 - 1, _SLAB_PLANES):
        stop = min(start + _SLAB_PLANES, n0 - 1)
        slab = bins[start : stop + 1]
        for reduce, out in ((np.minimum, mins), (np.maximum, maxs)):
            pairs = reduce(slab[:-1], slab[1:])
            pairs = reduce(pairs[:, :-1], pairs[:, 1:])
            reduce(pairs[:, :, :-1], pairs[:, :, 1:], out=out[start:stop])
    return mins, maxs


def _block_reduce(values: np.ndarray, factors: Shape3, reduce: np.ufunc) -> np.ndarray:
    """Reduce ``values`` over blocks of ``factors`` elements per axis, tiling from index 0 (last block clipped)."""
    for axis, factor in enumerate(factors):
        length = values.shape[axis]
        if factor == 1 or length == 1:
            continue
        take = [slice(None)] * 3
        take[axis] = slice(0, None, factor)
        out = values[tuple(take)].copy()
        # Offset r of every block at once: a strided view, so each element is read once whatever the factor.
        for offset in range(1, min(factor, length)):
            take[axis] = slice(offset, None, factor)
            part = values[tuple(take)]
            head = [slice(None)] * 3
            head[axis] = slice(0, part.shape[axis])
            reduce(out[tuple(head)], part, out=out[tuple(head)])
        values = out
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


def hyper_cell_intervals(
    mins: np.ndarray, maxs: np.ndarray, levels: Optional[int] = None
) -> Iterator[tuple[int, Shape3, np.ndarray, np.ndarray]]:
    """Intervals of the hyper-cells at each octree level, finest level first.

    Each level is block-reduced from the smallest already reduced level whose tiling nests in it, which is the next
    finer level whenever sizes halve exactly (power-of-two grids), and the unit cells otherwise.

    Args:
        mins, maxs: unit-cell intervals from :func:`unit_cell_intervals`, shape ``(c0, c1, c2)``.
        levels: keep only the ``levels`` coarsest levels (default: all).

    Yields:
        ``(level, size, level_mins, level_maxs)``: level number (1 = coarsest), hyper-cell size in unit cells, and the
        interval arrays of shape ``ceil(c / size)`` per axis.
    """
    grid = mins.shape
    sizes = octree_levels(grid)
    n_levels = len(sizes) if levels is None else levels
    reduced: dict[Shape3, tuple[np.ndarray, np.ndarray]] = {sizes[-1]: (mins, maxs)}
    for level in range(len(sizes), 0, -1):
        size = sizes[level - 1]
        if size not in reduced:
            candidates = []
            for source_size, (source_mins, source_maxs) in reduced.items():
                factors = _reduction_factors(source_size, size, grid)
                if factors is not None:
                    candidates.append((source_mins.size, factors, source_mins, source_maxs))
            _, factors, source_mins, source_maxs = min(candidates, key=lambda c: c[0])
            reduced[size] = (
                _block_reduce(source_mins, factors, np.minimum),
                _block_reduce(source_maxs, factors, np.maximum),
            )
        if level <= n_levels:
            yield (level, size, *reduced[size])
