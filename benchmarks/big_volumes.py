"""Volumes larger than memory for the out-of-core benchmarks, written a plane (or a chunk) at a time.

The 512^3 int16 head phantom, shifted to uint16 (HU + 1024, as micro-CT and many scanners store it) and tiled to the
requested shape, written as a raw file with a detached NRRD header (``.nhdr``) or as a Zarr store: neither the writer
nor the reader ever holds more than one tile.
"""

from pathlib import Path

import numpy as np

TILE = 512


def phantom_tile() -> np.ndarray:
    """The 512^3 head phantom in uint16 (HU + 1024, clipped at 0), shape ``(512, 512, 512)`` = (z, y, x)."""
    from isosimtf.phantom import head_phantom

    return np.clip(head_phantom(TILE, seed=0).values.astype(np.int32) + 1024, 0, None).astype(np.uint16)


def tiled_plane(tile: np.ndarray, k: int, plane_shape: tuple[int, int]) -> np.ndarray:
    """Plane ``k`` of the tiled volume: ``tile[k % 512]`` repeated over ``plane_shape`` (y, x) voxels."""
    reps = [-(-n // TILE) for n in plane_shape]
    return np.tile(tile[k % TILE], reps)[: plane_shape[0], : plane_shape[1]]


def write_nhdr(path: Path, shape: tuple[int, int, int]) -> Path:
    """Write the tiled phantom of ``shape`` (z, y, x) voxels as ``path`` (.nhdr) and its ``.raw`` data file."""
    tile = phantom_tile()
    data = path.with_suffix(".raw")
    with open(data, "wb") as raw:
        for k in range(shape[0]):
            raw.write(tiled_plane(tile, k, shape[1:]).astype("<u2").tobytes())
    path.write_text(
        "NRRD0004\ntype: uint16\ndimension: 3\n"
        f"sizes: {shape[2]} {shape[1]} {shape[0]}\n"
        "space: left-posterior-superior\nspace directions: (0.1,0,0) (0,0.1,0) (0,0,0.1)\n"
        f"endian: little\nencoding: raw\nspace origin: (0,0,0)\ndata file: {data.name}\n",
        encoding="ascii",
    )
    return path


def write_zarr(path: Path, shape: tuple[int, int, int], chunks: tuple[int, int, int] = (64, 256, 256)) -> Path:
    """Write the tiled phantom of ``shape`` (z, y, x) voxels as a Zarr store, one row of chunks at a time."""
    import zarr

    tile = phantom_tile()
    array = zarr.create_array(str(path), shape=shape, chunks=chunks, dtype="uint16", overwrite=True)
    for first in range(0, shape[0], chunks[0]):
        planes = range(first, min(first + chunks[0], shape[0]))
        array[first : planes.stop] = np.stack([tiled_plane(tile, k, shape[1:]) for k in planes])
    return path
