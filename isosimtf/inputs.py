"""The command's INPUT: a volume file, a DICOM series folder, or the built-in phantom."""

import os
from pathlib import Path
from typing import Union

import numpy as np

from .volume_io import Volume, read_volume

PathLike = Union[str, "os.PathLike[str]"]

#: The INPUT word that selects the built-in head phantom (a file or folder named so is read as ``./phantom``).
PHANTOM_INPUT = "phantom"
DEFAULT_PHANTOM_SIZE = 128


def is_phantom_input(source: PathLike) -> bool:
    """Whether INPUT names the built-in phantom: exactly the word ``phantom`` (``./phantom`` is a path)."""
    return isinstance(source, str) and source == PHANTOM_INPUT


def load_input(source: PathLike, *, phantom_size: int = DEFAULT_PHANTOM_SIZE, seed: int = 0) -> Volume:
    """Read the input volume: a file or DICOM folder (see :func:`read_volume`), or the word ``phantom``.

    The phantom is centred on the RAS origin. The word ``phantom`` always means the phantom; write ``./phantom`` to
    read a file or folder of that name.

    Raises:
        VolumeReadError: unreadable or unsupported input. ValueError: bad phantom size or seed.
    """
    if is_phantom_input(source):
        from .phantom import head_phantom

        phantom = head_phantom(phantom_size, seed=seed)
        dims = np.asarray(phantom.values.shape[::-1], dtype=float)
        origin = -0.5 * (dims - 1.0) * np.asarray(phantom.spacing)
        return Volume(phantom.values, phantom.spacing, tuple(origin), np.eye(3), PHANTOM_INPUT)
    return read_volume(source)


def input_info(source: PathLike, volume: Volume) -> dict:
    """The ``input`` entry of ``classes.json``: where the volume came from and its geometry."""
    is_phantom = is_phantom_input(source)
    values = volume.values
    return {
        "path": PHANTOM_INPUT if is_phantom else str(Path(source).resolve()),
        "name": volume.name,
        "shape": list(volume.shape),
        "dimensions": list(volume.shape[::-1]),
        "spacing": [float(s) for s in volume.spacing],
        "origin": [float(o) for o in volume.origin],
        "ijk_to_ras": volume.ijk_to_ras().tolist(),
        "dtype": str(values.dtype),
        "value_min": float(np.min(values)) if values.size else None,
        "value_max": float(np.max(values)) if values.size else None,
    }

