"""Volumes larger than memory: the design of a ``dask.array``, bit-identical to the in-memory engine.

Two passes over the volume: its value range (reductions run where the chunks are read, a part at a time for
progress), then the similarity's. In that one the volume is quantized chunk by chunk (lazily, with the whole volume's
range) and streamed to the engine as slabs of whole planes along axis 0, one row of chunks at a time (computed by the
scheduler while the engine works on the previous one), each with the last plane of the previous row (the unit cells
across the border need it: a one-voxel halo). The engine folds the slabs into the octree levels exactly across their
borders, each level holding only its unfinished row of hyper-cells (:class:`~.cells.OctreeBuilder`), and the same
slabs give the voxel counts and the planes the background rule samples (:class:`SlabTap`), so the similarity, the
voxel counts and the classes are those of the whole volume held in memory. Memory: about two rows of chunks (bins and
source values), one plane of hyper-cells per level and the levels small enough to be gathered whole; nothing grows
with the volume's depth.

On a dask.distributed cluster (or dask's ``"processes"`` scheduler) the similarity pass is a map-reduce: the volume
is cut along axis 0 into one part per worker (whole rows of chunks), each part is read and counted by a worker as
above, and the parts' counts are merged pairwise (:func:`~.similarity.merge_counts`): the joint histograms of rows of
hyper-cells wholly inside a part add up, and a row across a border is the hull of its parts' halves. The result is
the same, bit for bit; each worker needs what the whole pass needs in one process.

dask is an optional dependency, imported only when a dask array is given: the Slicer module never needs it.
"""

from collections.abc import Iterator
from typing import Callable, Optional

import numpy as np

from .classes import contact_planes
from .quantize import (
    Quantization,
    bin_volume,
    bins_dtype,
    checked_n_bins,
    count_bins,
    resolved_value_range,
    validate_volume,
)


def is_dask_array(values: object) -> bool:
    """Whether ``values`` is a ``dask.array.Array`` (without importing dask)."""
    return any(cls.__module__.startswith("dask.") and cls.__name__ == "Array" for cls in type(values).__mro__)


def chunk_row_bytes(volume, n_bins: int) -> int:
    """Bytes of the thickest row of chunks of a dask volume along axis 0: its source values and their bins."""
    plane_voxels = int(np.prod(volume.shape[1:], dtype=np.int64))
    return max(volume.chunks[0]) * plane_voxels * (volume.dtype.itemsize + bins_dtype(n_bins).itemsize)


def voxel_slabs(volume, overlap: bool = True) -> Iterator[tuple[int, np.ndarray]]:
    """Consecutive slabs of a dask volume along axis 0, every chunk computed once.

    The next row of chunks is computed (read and quantized, by dask's scheduler) while the caller works on the current
    one, so the reading overlaps the octree pass: about two rows of chunks are held at a time.

    Args:
        volume: 3-D dask array.
        overlap: the unit cells across the border of two rows need a plane of each (a one-voxel halo): before each row
            but the first, yield the two planes of its border (the previous row's last plane, kept, and its first), so
            that no row is read twice nor copied.

    Yields:
        ``(first, slab)``: index of the slab's first plane and the slab as a numpy array: each row of chunks, with the
        border slabs between them when ``overlap``.
    """
    from concurrent.futures import ThreadPoolExecutor

    starts = [int(first) for first in np.cumsum((0, *volume.chunks[0]))]
    with ThreadPoolExecutor(1) as reader:
        pending = reader.submit(np.asarray, volume[starts[0] : starts[1]])
        previous = None
        for k, first in enumerate(starts[:-1]):
            row = pending.result()
            if k + 2 < len(starts):
                pending = reader.submit(np.asarray, volume[starts[k + 1] : starts[k + 2]])
            if overlap and previous is not None:
                yield first - 1, np.concatenate((previous, row[:1]))
            yield first, row
            previous = row[-1:].copy()
            del row  # let the row go before the next one is waited for


def quantize_chunked(
    values,
    n_bins: int = 256,
    value_range: Optional[tuple[float, float]] = None,
    progress: Optional[Callable[[float, str], None]] = None,
) -> Quantization:
    """:func:`~.quantize.quantize` of a dask volume: the value range is computed, the bins are a lazy dask array.

    ``progress(fraction, message)`` is called as the pass over the volume for its range goes (raising from it aborts).

    Every chunk is quantized by :func:`~.quantize.quantize` with the whole volume's range (or the one given), which is
    what the in-memory quantization does, so the bins are the same.
    """
    # The in-memory checks, before any pass over the data: the volume's on a zero-stride stand-in of its shape and
    # dtype (no memory).
    validate_volume(np.lib.stride_tricks.as_strided(np.zeros(1, dtype=values.dtype), values.shape, (0,) * values.ndim))
    n_bins = checked_n_bins(n_bins)
    low, high = _value_bounds(values, progress)
    value_range = resolved_value_range(value_range, (float(low), float(high)))
    # A chunk one voxel thick along an axis is no volume for quantize(): give it its neighbour's planes too.
    values = values.rechunk(tuple(_merge_thin_chunks(chunks) for chunks in values.chunks))
    value_range = (float(value_range[0]), float(value_range[1]))
    bins = values.map_blocks(lambda block: bin_volume(block, n_bins, value_range), dtype=bins_dtype(n_bins))
    return Quantization(bins=bins, n_bins=n_bins, value_range=value_range)


# Parts of the volume whose range is computed together: progress is reported after each (and each part holds several
# rows of chunks, which the scheduler reads in parallel).
_RANGE_PARTS = 20


def _value_bounds(values, progress: Optional[Callable[[float, str], None]]) -> tuple[float, float]:
    """Minimum and maximum of a dask volume, a few rows of chunks at a time (the reductions run where the chunks are
    read: only two numbers per part come back).

    Raises:
        ValueError: the volume has NaN or infinite voxels.
    """
    import dask
    import dask.array as da

    planes = np.cumsum((0, *values.chunks[0]))
    bounds = planes[np.unique(np.linspace(0, len(planes) - 1, _RANGE_PARTS + 1).round().astype(int))]
    low, high = np.inf, -np.inf
    for k, (first, stop) in enumerate(zip(bounds[:-1], bounds[1:])):
        part = values[first:stop]
        checks = [part.min(), part.max()]
        if np.issubdtype(values.dtype, np.floating):
            checks.append(da.isfinite(part).all())
        part_low, part_high, *finite = dask.compute(*checks)
        if finite and not finite[0]:
            raise ValueError("the volume has NaN or infinite voxels; replace or mask them first")
        low, high = min(low, part_low), max(high, part_high)
        if progress is not None:
            progress((k + 1) / (len(bounds) - 1), "quantize: value range")
    return low, high


def _merge_thin_chunks(chunks: tuple[int, ...]) -> tuple[int, ...]:
    """Chunk sizes along one axis with every chunk of one voxel merged into a neighbour."""
    merged: list[int] = []
    for size in chunks:
        if merged and (size < 2 or merged[-1] < 2):
            merged[-1] += size
        else:
            merged.append(size)
    return tuple(merged)


class SlabTap:
    """What the classes stage needs of a streamed volume, gathered from the slabs of the similarity pass.

    Called as ``tap(first, slab)`` with every slab of bins in order along axis 0 (slabs may overlap by a halo plane):
    counts the voxels per bin and keeps a copy of the planes that :func:`~.classes.background_contact` measures, so
    the classes stage makes no pass of its own over the volume. Memory: ``n_bins`` counts and at most about
    3 x ``classes._CONTACT_SAMPLE_VOXELS`` voxels of bins.
    """

    def __init__(
        self, shape: tuple[int, int, int], n_bins: int, start: int = 0, preview_steps: tuple[int, int, int] = (0, 0, 0)
    ) -> None:
        """
        Args:
            shape: the whole volume's shape.
            n_bins: bins counted.
            start: the first plane this tap sees (a part of the volume; the taps of the parts are then merged).
            preview_steps: ``(sz, sy, sx)``: every ``sz``-th plane is kept, strided by ``sy, sx``, for the look's
                preview (:func:`~.visibility.preview_steps`); 0 keeps none.
        """
        self.preview_steps = tuple(int(s) for s in preview_steps)
        self._preview: dict[int, np.ndarray] = {}
        self.shape = tuple(int(n) for n in shape)
        self.voxel_counts = np.zeros(n_bins, dtype=np.int64)
        self._kept = {k + d for k in contact_planes(self.shape) for d in (-1, 0, 1) if 0 <= k + d < self.shape[0]}
        self._planes: dict[int, np.ndarray] = {}
        self._next = int(start)  # first plane not yet counted

    def __call__(self, first: int, slab: np.ndarray) -> None:
        new = slab[self._next - first :]  # the planes of the halo were counted with the previous slab
        self.voxel_counts += count_bins(new, self.voxel_counts.size)
        sz, sy, sx = self.preview_steps
        for k in range(self._next, first + len(slab)):
            if k in self._kept:
                self._planes[k] = slab[k - first].copy()
            if sz and k % sz == 0:
                self._preview[k] = slab[k - first, ::sy, ::sx].copy()
        self._next = first + len(slab)

    def merge(self, other: "SlabTap") -> None:
        """Add what ``other`` gathered from planes this tap has not seen (another part of the volume)."""
        self.voxel_counts += other.voxel_counts
        self._planes.update(other._planes)
        self._preview.update(other._preview)

    def preview(self) -> np.ndarray:
        """The kept preview planes, ``(nz', ny', nx')``, in order (after the whole pass)."""
        return np.stack([self._preview[k] for k in sorted(self._preview)])

    def __getitem__(self, plane: int) -> np.ndarray:
        """A plane kept for the background contact, shape ``(n1, n2)``."""
        return self._planes[plane]
