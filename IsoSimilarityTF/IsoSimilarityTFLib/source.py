"""The volume as the engine reads it: one source over a numpy array, a memmap or a ``dask.array``.

This is the only module that knows whether a volume is a dask array. Everything else reads a :class:`VolumeSource`:

- :meth:`~VolumeSource.slabs`: slabs of whole planes along axis 0, in order. A numpy volume is one slab (it is in
  memory already); a dask volume is one row of chunks at a time, the next row read by dask's scheduler while the
  caller works on the current one, with the two border planes between rows when the caller needs a one-voxel halo
  (the unit cells across the border).
- :meth:`~VolumeSource.map_slabs`: the same function applied to every slab as it is read (the bins): lazily for a
  dask volume, a few planes at a time for one in memory, so the mapped volume is never held whole.
- :meth:`~VolumeSource.map_reduce`: a function of consecutive slabs over parts of the volume along axis 0, merged
  pairwise: one part counted here, or on a dask.distributed cluster (or dask's ``"processes"`` scheduler) one part
  per worker, each reading its own chunks.

dask is an optional dependency, imported only when a dask array is given: the Slicer module never needs it.
"""

from collections.abc import Iterator
from typing import Callable, Optional, TypeVar

import numpy as np

Slab = tuple[int, np.ndarray]
Result = TypeVar("Result")

# Voxels of the slabs an in-memory volume is mapped in (see VolumeSource.map_slabs): 8-16 MB of bins, 32 times the
# engine's cache-sized pieces (stream._SLAB_CELLS). On 256^3 phantoms (uint8, int16) binning and similarity took
# 0.99-1.04x the time of the whole-volume bins at 2^23 voxels, 1.02-1.07x at 2^22 (noise about 5 %).
_MAPPED_SLAB_VOXELS = 1 << 23


def is_dask_array(values: object) -> bool:
    """Whether ``values`` is a ``dask.array.Array`` (without importing dask)."""
    return any(cls.__module__.startswith("dask.") and cls.__name__ == "Array" for cls in type(values).__mro__)


def is_lazy(values: object) -> bool:
    """Whether a volume is read lazily, a row of chunks at a time (a dask array), rather than held in memory."""
    return is_dask_array(values)


def as_array(values):
    """The volume as an array: a lazy one as it is, anything else through ``np.asarray``."""
    return values if is_lazy(values) else np.asarray(values)


def validate_volume(values):
    """Return ``values`` as an array (a dask array as it is) if it is a 3-D real scalar volume, else raise
    ``ValueError`` saying why.

    A masked array is refused rather than silently unmasked: the method works on whole 2x2x2 cells, and what a cell
    with masked corners means is the caller's choice (fill them, e.g. ``values.filled(values.min())``, or crop).
    """
    if isinstance(values, np.ma.MaskedArray):
        raise ValueError(
            "masked arrays are not supported (the mask would be ignored): fill the masked voxels, e.g. "
            "values.filled(values.min()), or crop the volume"
        )
    values = as_array(values)
    numeric = np.issubdtype(values.dtype, np.integer) or np.issubdtype(values.dtype, np.floating)
    if values.dtype == bool or not numeric:
        raise ValueError(f"expected a scalar volume of integers or floats; got dtype {values.dtype}")
    if values.ndim == 4 and values.shape[-1] in (2, 3, 4):
        raise ValueError(
            f"expected a scalar volume; got {values.shape[-1]} components per voxel (shape {values.shape}): "
            "convert vector/RGB volumes to a scalar volume first"
        )
    if values.ndim != 3:
        raise ValueError(f"expected a 3-D scalar volume; got a {values.ndim}-D array of shape {values.shape}")
    if min(values.shape) < 2:
        raise ValueError(
            f"expected at least 2 voxels along every axis (a unit cell is 2x2x2 voxels); got shape {values.shape}"
        )
    return values


class VolumeSource:
    """A 3-D volume read in slabs along axis 0.

    Args:
        values: a 3-D numpy array (or memmap, or anything ``np.asarray`` takes) or a ``dask.array.Array``; checked
            by :func:`validate_volume`.
    """

    def __init__(self, values) -> None:
        self.values = validate_volume(values)
        #: Whether the volume is read lazily, a row of chunks at a time (a dask array).
        self.lazy = is_lazy(self.values)

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(int(n) for n in self.values.shape)

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(self.values.dtype)

    def row_bytes(self, bytes_per_voxel: int = 0) -> int:
        """Bytes of the thickest row of chunks held at once (0 in memory): the source values plus
        ``bytes_per_voxel`` (the bins made of them)."""
        if not self.lazy:
            return 0
        plane_voxels = int(np.prod(self.shape[1:], dtype=np.int64))
        return max(self.values.chunks[0]) * plane_voxels * (self.dtype.itemsize + int(bytes_per_voxel))

    def slabs(self, overlap: bool = False) -> Iterator[Slab]:
        """Consecutive slabs ``(first plane, voxels)`` along axis 0, in memory, every plane read once.

        Args:
            overlap: before each row of chunks but the first, also yield the two planes of its border (the previous
                row's last plane, kept, and its first), for the unit cells across it: no row is read twice nor
                copied.
        """
        if not self.lazy:
            yield 0, self.values
            return
        yield from _dask_slabs(self.values, overlap)

    def map_slabs(self, function: Callable[[np.ndarray], np.ndarray], dtype) -> "VolumeSource":
        """``function`` (elementwise, shape-preserving, giving ``dtype``) applied to every voxel as the slabs are
        read: lazily for a dask volume (each chunk when it is read; a chunk one voxel thick gets its neighbour's
        planes too), a slab of a few planes at a time for a volume in memory (no copy of the whole volume is made)."""
        if not self.lazy:
            return _MappedSource(self.values, function, dtype)
        values = self.values.rechunk(tuple(_merge_thin_chunks(chunks) for chunks in self.values.chunks))
        return VolumeSource(values.map_blocks(function, dtype=dtype))

    def sample(self, step: int) -> np.ndarray:
        """Every ``step``-th voxel along each axis, in memory."""
        sample = self.values[::step, ::step, ::step]
        return np.asarray(sample.compute() if self.lazy else sample)

    def map_reduce(
        self,
        part: Callable[[Iterator[Slab], int, int, Optional[Callable[[float], None]]], Result],
        merge: Callable[[Result, Result], Result],
        progress: Optional[Callable[[float], None]] = None,
    ) -> Result:
        """``part(slabs, first, stop, progress)`` of the voxel planes ``first .. stop`` (its slabs with their halo),
        over parts of the volume along axis 0, merged pairwise in order (``merge(low, high)``).

        One part, worked on in this process, unless dask's scheduler is a dask.distributed client or its
        ``"processes"`` scheduler: then one part per worker (whole rows of chunks), each reading its own chunks,
        merged as they finish (a tree: few parts are held at once); ``part`` and ``merge`` must then be picklable.
        ``progress(fraction of the planes done)`` is given to a part worked on here, else called as parts finish.
        """
        if not self.lazy:
            return part(self.slabs(overlap=True), 0, self.shape[0] - 1, progress)
        return _dask_map_reduce(self.values, part, merge, progress)


class _MappedSource(VolumeSource):
    """A volume in memory read through an elementwise function, a slab of a few planes at a time: what
    :meth:`VolumeSource.map_slabs` gives for a volume in memory."""

    def __init__(self, values: np.ndarray, function: Callable[[np.ndarray], np.ndarray], dtype) -> None:
        self._source = values
        self._function = function
        self._dtype = np.dtype(dtype)
        self.lazy = False

    @property
    def values(self) -> np.ndarray:
        """The whole mapped volume, made on demand (the engine reads :meth:`slabs` instead)."""
        return self._function(self._source)

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(int(n) for n in self._source.shape)

    @property
    def dtype(self) -> np.dtype:
        return self._dtype

    def slabs(self, overlap: bool = False) -> Iterator[Slab]:
        planes = max(2, _MAPPED_SLAB_VOXELS // int(np.prod(self.shape[1:], dtype=np.int64)))
        starts = list(range(0, self.shape[0], planes))
        if len(starts) > 1 and self.shape[0] - starts[-1] < 2:
            starts.pop()  # no slab one plane thick, as a dask volume's thin chunks are merged (_merge_thin_chunks)
        rows = (
            (first, self._function(self._source[first:end])) for first, end in zip(starts, [*starts[1:], self.shape[0]])
        )
        yield from _with_borders(rows, overlap)

    def map_slabs(self, function: Callable[[np.ndarray], np.ndarray], dtype) -> VolumeSource:
        inner = self._function
        return _MappedSource(self._source, lambda values: function(inner(values)), dtype)

    def sample(self, step: int) -> np.ndarray:
        return self._function(np.asarray(self._source[::step, ::step, ::step]))


def _merge_thin_chunks(chunks: tuple[int, ...]) -> tuple[int, ...]:
    """Chunk sizes along one axis with every chunk of one voxel merged into a neighbour."""
    merged: list[int] = []
    for size in chunks:
        if merged and (size < 2 or merged[-1] < 2):
            merged[-1] += size
        else:
            merged.append(size)
    return tuple(merged)


def _dask_slabs(volume, overlap: bool) -> Iterator[Slab]:
    from concurrent.futures import ThreadPoolExecutor

    starts = [int(first) for first in np.cumsum((0, *volume.chunks[0]))]

    def rows() -> Iterator[Slab]:
        with ThreadPoolExecutor(1) as reader:
            pending = reader.submit(np.asarray, volume[starts[0] : starts[1]])
            for k, first in enumerate(starts[:-1]):
                row = pending.result()
                if k + 2 < len(starts):
                    pending = reader.submit(np.asarray, volume[starts[k + 1] : starts[k + 2]])
                yield first, row
                del row  # let the row go before the next one is waited for

    yield from _with_borders(rows(), overlap)


def _with_borders(rows: Iterator[Slab], overlap: bool) -> Iterator[Slab]:
    """The consecutive ``rows`` and, with ``overlap``, before each row but the first the two planes of its border
    (the previous row's last plane, kept, and its first), for the unit cells across it."""
    previous = None
    for first, row in rows:
        if overlap and previous is not None:
            yield first - 1, np.concatenate((previous, row[:1]))
        yield first, row
        previous = row[-1:].copy()
        del row  # let the row go before the next one is read


# Parts per worker of a map-reduce over a dask volume: one (the similarity's parts return tables of n_bins ** 2
# int64; on 2048 x 1024 x 1024 voxels and 2 workers, 2 parts per worker took 9.0 s against 8.0-10.3 s for one).
_PARTS_PER_WORKER = 1


def _workers() -> int:
    """How many parts of a dask volume are read at once: the worker threads of the dask.distributed client in use,
    the workers of dask's ``"processes"`` scheduler when it is the one chosen, else 1.

    One part by default: counted in this process while dask's threads read the next row of chunks, it already keeps
    about 1.4 of 2 cores busy. A pool of 2 processes gained nothing on a 1024^3 volume (5.2-5.3 s against 5.0-5.3 s,
    the pool's start included) and 1.2 times on 2048 x 1024 x 1024 (8.9 s against 10.3-11.7 s), but it would double
    the memory and start its processes by re-running the caller's main module (a script without a ``__main__``
    guard would run again in each).
    """
    import os

    import dask

    scheduler = dask.config.get("scheduler", None)
    if scheduler in ("dask.distributed", "distributed"):
        from distributed import default_client

        return max(1, sum(default_client().nthreads().values()))
    if scheduler in ("processes", "multiprocessing"):
        return int(dask.config.get("num_workers", None) or os.cpu_count() or 1)
    return 1


class _Unread:
    """A dask array handed to a task as it is, not computed first (dask computes the collections among a task's
    arguments): the task reads its chunks itself."""

    def __init__(self, array) -> None:
        self.array = array


def _reuse_freed_memory() -> None:
    """Let glibc reuse the memory a part frees rather than return it at once (Linux; elsewhere nothing).

    dask.distributed starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also stops glibc from raising its
    mmap threshold: every buffer of more than 128 kB (``np.bincount``'s 2 MB index, the reduced slabs) is then mapped
    and page-faulted afresh, and the similarity pass took 3 times as long (sys time 21 s of 34 s on a 1024^3 volume).
    Buffers up to 32 MB come from the heap again, and 64 MB of freed heap is kept.
    """
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c"))
        libc.mallopt(-3, 32 << 20)  # M_MMAP_THRESHOLD
        libc.mallopt(-1, 64 << 20)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError, TypeError):  # no C library found, or not glibc
        pass


def _offset_slabs(volume, offset: int) -> Iterator[Slab]:
    for first, slab in _dask_slabs(volume, overlap=True):
        yield offset + first, slab


def _run_part(unread: _Unread, offset: int, part: Callable) -> object:
    """A dask task: ``part`` of the voxel planes ``offset ..`` of ``unread``, read here."""
    import dask

    _reuse_freed_memory()
    # Read here (the slabs' thread reads the next row while this one is worked on): from inside a cluster's task,
    # dask's default scheduler would be the cluster, which would read the chunks elsewhere and send them here.
    with dask.config.set(scheduler="sync"):
        return part(_offset_slabs(unread.array, offset), offset, offset + len(unread.array) - 1, None)


def _dask_map_reduce(volume, part: Callable, merge: Callable, progress: Optional[Callable[[float], None]]):
    import dask
    from dask.base import tokenize
    from dask.callbacks import Callback

    planes = np.cumsum((0, *volume.chunks[0]))
    workers = _workers()
    n_parts = min(len(planes) - 1, workers * _PARTS_PER_WORKER)
    stop = volume.shape[0] - 1
    if workers == 1 or n_parts == 1:  # one part, read by the scheduler as this process works on it
        return part(_dask_slabs(volume, overlap=True), 0, stop, progress)
    bounds = planes[np.unique(np.linspace(0, len(planes) - 1, n_parts + 1).round().astype(int))]
    token = tokenize(volume, part)
    share = {}
    parts = []
    for k, (first, end) in enumerate(zip(bounds[:-1], bounds[1:])):
        key = f"isosimtf-part-{k}-{token}"
        share[key] = (int(end) - 1 - int(first)) / stop
        parts.append(dask.delayed(_run_part)(_Unread(volume[first:end]), int(first), part, dask_key_name=key))
    while len(parts) > 1:  # adjacent parts merged pairwise, the last one of an odd count carried up
        merged = [dask.delayed(merge)(low, high) for low, high in zip(parts[::2], parts[1::2])]
        parts = merged + parts[len(merged) * 2 :]
    done = 0.0

    def posttask(key, result, dsk, state, worker_id) -> None:  # local schedulers only: a cluster reports at the end
        nonlocal done
        if progress is not None and key in share:
            done += share[key]
            progress(done)

    # chunksize 1: dask's process pool would otherwise send the parts to one process in a batch.
    with Callback(posttask=posttask), dask.config.set(chunksize=1):
        (result,) = dask.compute(parts[0])
    return result
