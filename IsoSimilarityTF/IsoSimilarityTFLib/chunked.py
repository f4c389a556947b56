"""Volumes larger than memory: the design of a ``dask.array``, bit-identical to the in-memory engine.

The volume is quantized chunk by chunk (lazily) and streamed to the engine as slabs of whole planes along axis 0, one
row of chunks at a time, each with the first plane of the next one (the unit cells across the border need it: a
one-voxel halo on the high side). The engine folds the slabs into the octree levels exactly across their borders
(:class:`~.cells.OctreeBuilder`), so the similarity, the voxel counts and the classes are those of the whole volume
held in memory. Memory: one row of chunks, plus the octree levels above the unit cells (a quarter of a byte per voxel
at 256 bins).

dask is an optional dependency, imported only when a dask array is given: the Slicer module never needs it.
"""

from collections.abc import Iterator
from typing import Optional

import numpy as np

from .quantize import Quantization, bin_volume, bins_dtype, checked_value_range, validate_volume


def is_dask_array(values: object) -> bool:
    """Whether ``values`` is a ``dask.array.Array`` (without importing dask)."""
    return any(cls.__module__.startswith("dask.") and cls.__name__ == "Array" for cls in type(values).__mro__)


def voxel_slabs(volume, halo: int = 1) -> Iterator[tuple[int, np.ndarray]]:
    """Consecutive slabs of a dask volume along axis 0, one row of chunks each, computed one at a time.

    Args:
        volume: 3-D dask array.
        halo: planes of the next row of chunks added to each slab (1 for unit cells across the border, 0 to count).

    Yields:
        ``(first, slab)``: index of the slab's first plane and the slab as a numpy array.
    """
    first = 0
    for planes in volume.chunks[0]:
        stop = min(first + planes + halo, volume.shape[0])
        yield first, np.asarray(volume[first:stop])
        first += planes


def quantize_chunked(values, n_bins: int = 256, value_range: Optional[tuple[float, float]] = None) -> Quantization:
    """:func:`~.quantize.quantize` of a dask volume: the value range is computed, the bins are a lazy dask array.

    Every chunk is quantized by :func:`~.quantize.quantize` with the whole volume's range (or the one given), which is
    what the in-memory quantization does, so the bins are the same.
    """
    import dask
    import dask.array as da

    from .options import OPTIONS  # the table imports the engine's modules, this one among them

    # The in-memory checks, before any pass over the data: the volume's on a zero-stride stand-in of its shape and
    # dtype (no memory).
    validate_volume(np.lib.stride_tricks.as_strided(np.zeros(1, dtype=values.dtype), values.shape, (0,) * values.ndim))
    n_bins = OPTIONS["n_bins"].check(n_bins)
    checks = [values.min(), values.max()]
    if np.issubdtype(values.dtype, np.floating):
        checks.append(da.isfinite(values).all())
    low, high, *finite = dask.compute(*checks)
    if finite and not finite[0]:
        raise ValueError("the volume has NaN or infinite voxels; replace or mask them first")
    if value_range is None:
        if low == high:
            raise ValueError(f"the volume is constant (every voxel is {float(low):g}): there is nothing to classify")
        value_range = (float(low), float(high))
    else:
        value_range = checked_value_range(value_range, (float(low), float(high)))
    # A chunk one voxel thick along an axis is no volume for quantize(): give it its neighbour's planes too.
    values = values.rechunk(tuple(_merge_thin_chunks(chunks) for chunks in values.chunks))
    value_range = (float(value_range[0]), float(value_range[1]))
    bins = values.map_blocks(lambda block: bin_volume(block, n_bins, value_range), dtype=bins_dtype(n_bins))
    return Quantization(bins=bins, n_bins=n_bins, value_range=value_range)


def _merge_thin_chunks(chunks: tuple[int, ...]) -> tuple[int, ...]:
    """Chunk sizes along one axis with every chunk of one voxel merged into a neighbour."""
    merged: list[int] = []
    for size in chunks:
        if merged and (size < 2 or merged[-1] < 2):
            merged[-1] += size
        else:
            merged.append(size)
    return tuple(merged)
