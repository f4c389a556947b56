"""Refuse a volume that would not fit in memory, before allocating it.

Linux over-commits memory: an oversized array is granted, and the process is killed when its pages are touched,
taking the user's Slicer session with it. A clear error up front is better.
"""

import os
from typing import Optional

from .quantize import MAX_BINS

# Bytes per voxel at the peak of the similarity stage, per byte of bin index: the quantized volume (not held for a
# volume streamed from a dask array), and the hyper-cell minima and maxima of the second finest octree level (1/8 of
# the voxels; the unit cells are never held whole), of the coarser levels reduced from it (1/7 of that) and of a level
# nested in no finer one (at most 1/27).
_BINS_BYTES_PER_VOXEL = 1
_LEVELS_BYTES_PER_VOXEL = 2 / 8 * (1 + 1 / 7) + 2 / 27
# Float64 matrices of n_bins x n_bins alive at once while aggregating the levels.
_MATRICES = 6
# Slabs, chunks and libraries.
_OVERHEAD_BYTES = 256 << 20


class InsufficientMemoryError(MemoryError):
    """The volume (or the number of bins) needs more memory than the machine has available."""


def available_memory_bytes() -> Optional[int]:
    """Memory available to a new allocation without swapping, in bytes; None where the system does not say."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):
        return None


def design_memory_bytes(shape: tuple, n_bins: int, streamed: bool = False) -> int:
    """Estimated peak memory of designing a transfer function, in bytes, for a volume of ``shape`` voxels.

    Counts what the pipeline allocates beyond the input volume itself. ``streamed``: the volume is a dask array, read
    one row of chunks at a time, whose bins are never held whole.
    """
    voxels = 1
    for n in shape:
        voxels *= int(n)
    index_bytes = 1 if n_bins <= 256 else 2
    per_voxel = _LEVELS_BYTES_PER_VOXEL + (0 if streamed else _BINS_BYTES_PER_VOXEL)
    return int(voxels * index_bytes * per_voxel + _MATRICES * 8 * n_bins * n_bins + _OVERHEAD_BYTES)


def check_memory(shape: tuple, n_bins: int, streamed: bool = False) -> None:
    """Raise :class:`InsufficientMemoryError` when the design would need more memory than is available.

    A bad ``n_bins`` is let through: the step that uses it says what is wrong with it. ``streamed``: see
    :func:`design_memory_bytes`.
    """
    if isinstance(n_bins, bool) or not isinstance(n_bins, int) or not 2 <= n_bins <= MAX_BINS:
        return
    available = available_memory_bytes()
    needed = design_memory_bytes(shape, n_bins, streamed)
    if available is not None and needed > available:
        dims = " x ".join(str(int(n)) for n in shape)
        raise InsufficientMemoryError(
            f"a volume of {dims} voxels with {n_bins} bins needs about {needed / 2**30:.1f} GB of memory and "
            f"{available / 2**30:.1f} GB are available: crop or downsample the volume, or use fewer bins"
        )
