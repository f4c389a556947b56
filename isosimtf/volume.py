"""The scalar volume every reader returns: voxel values ``(K, J, I)`` with their geometry in Slicer's RAS world.

Its own module so that every reader (:mod:`.volume_io`, :mod:`.chunked_readers`) imports it without importing each
other.
"""

from dataclasses import dataclass
from typing import Any

import numpy as np

from IsoSimilarityTFLib.source import as_array

__all__ = ["Volume", "right_handed"]


@dataclass(frozen=True, eq=False)
class Volume:
    """A scalar volume with its geometry.

    Attributes:
        values: voxel values, shape ``(K, J, I)`` = (z, y, x), the file's own dtype (e.g. int16 HU for CT).
        spacing: voxel size in mm along the i, j, k axes (x, y, z order, i.e. ``values.shape[::-1]`` order).
        origin: RAS position in mm of the centre of voxel ``values[0, 0, 0]``.
        directions: shape (3, 3); column ``c`` is the unit RAS direction of index axis ``c`` (i, j, k).
        name: a short name (the file name without its suffix).
    """

    values: np.ndarray
    spacing: tuple[float, float, float] = (1.0, 1.0, 1.0)
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    directions: np.ndarray = None  # type: ignore[assignment]  # identity when omitted
    name: str = "volume"

    def __post_init__(self) -> None:
        # A dask array (a volume read lazily, see .chunked_readers) stays lazy.
        values = as_array(self.values)
        if values.ndim != 3:
            raise ValueError(f"Volume values must be 3-D (k, j, i); got shape {values.shape}")
        directions = np.eye(3) if self.directions is None else np.array(self.directions, dtype=float)
        if directions.shape != (3, 3):
            raise ValueError(f"Volume directions must be 3x3; got shape {directions.shape}")
        spacing = tuple(float(s) for s in self.spacing)
        origin = tuple(float(o) for o in self.origin)
        if len(spacing) != 3 or len(origin) != 3:
            raise ValueError("Volume spacing and origin need 3 values each")
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "directions", directions)
        object.__setattr__(self, "spacing", spacing)
        object.__setattr__(self, "origin", origin)

    @classmethod
    def from_ijk_to_ras(cls, values: np.ndarray, ijk_to_ras: np.ndarray, name: str) -> "Volume":
        """A volume from its values and the 4x4 matrix mapping voxel indices (i, j, k, 1) to RAS millimetres."""
        axes = np.asarray(ijk_to_ras, dtype=float)[:3, :3]
        spacing = np.linalg.norm(axes, axis=0)
        return cls(values, tuple(spacing), tuple(np.asarray(ijk_to_ras)[:3, 3]), axes / spacing, name)

    @property
    def shape(self) -> tuple[int, int, int]:
        """Array shape ``(K, J, I)``."""
        return tuple(int(n) for n in self.values.shape)  # type: ignore[return-value]

    def ijk_to_ras(self) -> np.ndarray:
        """Return the 4x4 homogeneous matrix mapping voxel indices (i, j, k, 1) to RAS millimetres."""
        matrix = np.eye(4)
        matrix[:3, :3] = self.directions * np.asarray(self.spacing)[np.newaxis, :]
        matrix[:3, 3] = self.origin
        return matrix


def right_handed(values: Any, ijk_to_ras: np.ndarray) -> tuple[Any, np.ndarray]:
    """The voxels and IJK-to-RAS matrix of a left-handed index frame turned right-handed, as Slicer's storage node
    does it (``ForceRightHandedIJKCoordinateSystem``): the slice order (k) is reversed and the k column negated, so
    every voxel keeps its RAS position. A right-handed frame is returned unchanged.

    Args:
        values: ``(K, J, I)`` numpy or dask array. ijk_to_ras: 4x4 matrix of the index frame of ``values``.
    """
    matrix = np.asarray(ijk_to_ras, dtype=float)
    if np.linalg.det(matrix[:3, :3]) >= 0:
        return values, matrix
    flip = np.eye(4)
    flip[2, 2], flip[2, 3] = -1.0, values.shape[0] - 1
    return values[::-1], matrix @ flip
