"""The command's INPUT: a volume file, a DICOM series folder, or the built-in phantom."""

import os
from pathlib import Path
from typing import Callable, Optional, Union

import numpy as np

from IsoSimilarityTFLib.errors import UsageError
from IsoSimilarityTFLib.memory import check_memory
from IsoSimilarityTFLib.source import is_lazy

from .phantom import head_phantom
from .volume_io import Volume, read_volume

PathLike = Union[str, "os.PathLike[str]"]

#: The INPUT word that selects the built-in head phantom (a file or folder named so is read as ``./phantom``).
PHANTOM_INPUT = "phantom"
DEFAULT_PHANTOM_SIZE = 128
#: Phantom sizes: 8 voxels is the smallest head with every tissue; 512^3 (the benchmark volume, ~1 min) the largest.
MIN_PHANTOM_SIZE, MAX_PHANTOM_SIZE = 8, 512


def is_phantom_input(source: PathLike) -> bool:
    """Whether INPUT names the built-in phantom: exactly the word ``phantom`` (``./phantom`` is a path)."""
    return isinstance(source, str) and source == PHANTOM_INPUT


def load_input(
    source: PathLike,
    *,
    phantom_size: int = DEFAULT_PHANTOM_SIZE,
    seed: int = 0,
    n_bins: Optional[int] = None,
    warn: Optional[Callable[[str], None]] = None,
) -> Volume:
    """Read the input volume: a file or DICOM folder (see :func:`read_volume`), or the word ``phantom``.

    The phantom is centred on the RAS origin. The word ``phantom`` always means the phantom; write ``./phantom`` to
    read a file or folder of that name. Whatever the input, its size is checked against the memory available
    (counting the design with ``n_bins`` bins) before its voxels are read or made. ``warn`` takes each warning line
    of the read (see :func:`read_volume`).

    Raises:
        VolumeReadError: unreadable or unsupported input. UsageError: phantom size out of bounds. ValueError: bad
        seed. InsufficientMemoryError: the volume would not fit in memory.
    """
    if is_phantom_input(source):
        if not MIN_PHANTOM_SIZE <= phantom_size <= MAX_PHANTOM_SIZE:
            raise UsageError(
                f"the phantom size must be from {MIN_PHANTOM_SIZE} to {MAX_PHANTOM_SIZE} voxels; got {phantom_size}"
            )
        check_memory((phantom_size,) * 3, n_bins, input_bytes=2 * phantom_size**3)  # int16 voxels
        phantom = head_phantom(phantom_size, seed=seed)
        dims = np.asarray(phantom.values.shape[::-1], dtype=float)
        origin = -0.5 * (dims - 1.0) * np.asarray(phantom.spacing)
        return Volume(phantom.values, phantom.spacing, tuple(origin), np.eye(3), PHANTOM_INPUT)
    return read_volume(source, n_bins=n_bins, warn=warn)


def input_info(source: PathLike, volume: Volume) -> dict:
    """The ``input`` entry of ``classes.json``: where the volume came from and its geometry."""
    is_phantom = is_phantom_input(source)
    values = volume.values
    lazy = is_lazy(values)  # its range would cost a pass over the volume: the design's own pass finds it
    return {
        "path": PHANTOM_INPUT if is_phantom else str(Path(source).resolve()),
        "name": volume.name,
        "shape": list(volume.shape),
        "dimensions": list(volume.shape[::-1]),
        "spacing": [float(s) for s in volume.spacing],
        "origin": [float(o) for o in volume.origin],
        "ijk_to_ras": volume.ijk_to_ras().tolist(),
        "dtype": str(values.dtype),
        "value_min": float(np.min(values)) if values.size and not lazy else None,
        "value_max": float(np.max(values)) if values.size and not lazy else None,
        "read_lazily": lazy,
    }
