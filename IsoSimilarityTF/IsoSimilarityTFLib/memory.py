"""Refuse a volume that would not fit in memory, before allocating it.

Linux over-commits memory: an oversized array is granted, and the process is killed when its pages are touched,
taking the user's Slicer session with it. A clear error up front is better.
"""

import os
from typing import Optional

from .cells import GATHERED_CELLS, octree_levels
from .errors import InsufficientMemoryError
from .options import MAX_BINS

# The bins are never held whole (each slab is binned as the similarity pass reads it: source.VolumeSource.map_slabs),
# nor are the unit cells, nor the octree levels above them: a level of more than ``cells.GATHERED_CELLS`` hyper-cells
# is counted row by row into its own table, a smaller one is gathered whole.
# Float64 matrices of n_bins x n_bins alive at once while aggregating the levels.
_MATRICES = 6
# Slabs, chunks and libraries.
_OVERHEAD_BYTES = 256 << 20


def available_memory_bytes() -> Optional[int]:
    """Memory available to a new allocation, in bytes; None where the system does not say.

    The smallest of: the system's available memory, what the process's address-space limit (``ulimit -v``) leaves,
    and what its container's memory limit (cgroup v2 ``memory.max``) leaves. Any of them refuses an allocation.
    """
    limits = [_system_available(), _address_space_left(), _cgroup_left()]
    known = [n for n in limits if n is not None]
    return max(0, min(known)) if known else None


def _system_available() -> Optional[int]:
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


def _address_space_left() -> Optional[int]:
    try:
        import resource

        limit = resource.getrlimit(resource.RLIMIT_AS)[0]
        if limit == resource.RLIM_INFINITY:
            return None
        with open("/proc/self/statm", encoding="ascii") as statm:
            used = int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        return limit - used
    except (ImportError, OSError, ValueError, AttributeError):
        return None


def _cgroup_left() -> Optional[int]:
    try:
        with open("/sys/fs/cgroup/memory.max", encoding="ascii") as handle:
            text = handle.read().strip()
        if text == "max":
            return None
        with open("/sys/fs/cgroup/memory.current", encoding="ascii") as handle:
            return int(text) - int(handle.read().strip())
    except (OSError, ValueError):
        return None


def design_memory_bytes(shape: tuple, n_bins: int) -> int:
    """Estimated peak memory of designing a transfer function, in bytes, for a volume of ``shape`` voxels.

    Counts what the pipeline allocates beyond the input volume itself (and, for a dask volume, beyond the rows of
    chunks it holds: :func:`check_memory`'s ``row_bytes``).
    """
    index_bytes = 1 if n_bins <= 256 else 2
    table_bytes = 8 * n_bins * n_bins
    levels_bytes = table_bytes  # the unit cells' table
    grid = tuple(max(int(n) - 1, 1) for n in shape)
    for size in octree_levels(grid)[:-1] if len(grid) == 3 else ():  # not a volume: refused by the step that reads it
        cells = 1
        for n, s in zip(grid, size):
            cells *= -(-n // s)
        levels_bytes += table_bytes if cells > max(GATHERED_CELLS, n_bins * n_bins) else 2 * cells * index_bytes
    return int(levels_bytes + _MATRICES * table_bytes + _OVERHEAD_BYTES)


# Rows of chunks of a streamed volume held at once at worst: the one the engine folds, the next one being computed
# (its source values and bins), and the one the engine still refers to while it waits (see source.VolumeSource.slabs).
_ROWS_HELD = 3


def check_memory(shape: tuple, n_bins: Optional[int], *, input_bytes: int = 0, row_bytes: int = 0) -> None:
    """Raise :class:`InsufficientMemoryError` when the design would need more memory than is available.

    Args:
        shape: the volume's shape.
        n_bins: the number of bins; None (or a bad value, which the step that uses it reports) counts the input only.
        input_bytes: bytes still to be allocated for the volume itself (a reader checking a header before reading).
        row_bytes: bytes of one row of chunks of a streamed volume along axis 0, source values and bins together
            (:meth:`~.source.VolumeSource.row_bytes`): a volume chunked in thick rows needs that much more.
    """
    valid_bins = not isinstance(n_bins, bool) and isinstance(n_bins, int) and 2 <= n_bins <= MAX_BINS
    available = available_memory_bytes()
    needed = int(input_bytes) + _ROWS_HELD * int(row_bytes)
    needed += design_memory_bytes(shape, n_bins) if valid_bins else 0  # type: ignore[arg-type]
    if available is not None and needed > available:
        dims = " x ".join(str(int(n)) for n in shape)
        bins = f" with {n_bins} bins" if valid_bins else ""
        raise InsufficientMemoryError(
            f"a volume of {dims} voxels{bins} needs about {needed / 2**30:.1f} GB of memory and "
            f"{available / 2**30:.1f} GB are available: crop or downsample the volume, or use fewer bins"
        )
