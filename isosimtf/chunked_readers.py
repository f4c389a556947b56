"""Volumes read lazily, as dask arrays: Zarr and OME-Zarr, TIFF stacks, and raw NRRD / MetaImage, a few planes a read.

None of these readers loads the volume: each returns a :class:`~.volume.Volume` whose ``values`` are a
``dask.array`` of shape ``(K, J, I)`` (slowest axis first), read a row of chunks at a time by the design
(``IsoSimilarityTFLib.source``).

- Zarr (a folder holding ``zarr.json``, ``.zarray`` or ``.zgroup``): an array, or an OME-Zarr image whose level 0
  (full resolution) is read; its coordinate transformations (the level's, then the image's: ``scale`` and
  ``translation``) give the spacing and origin, in millimetres from the axes' ``unit`` (with a warning when converted),
  its coordinates taken as RAS. Leading axes of one voxel (time, channel) are dropped.
- TIFF: a multi-page file (``.tif``, ``.tiff``) or a folder of single-plane TIFF files (in natural order: ``plane_2``
  before ``plane_10``), one page per plane along k, through ``tifffile``'s Zarr view; placed as Slicer's reader (ITK's
  TIFFImageIO) places it: origin 0, i towards left and j towards posterior (ITK's identity frame is LPS), spacing
  from the first page's ``XResolution`` / ``YResolution`` when its ``ResolutionUnit`` is inch or centimetre (else 1),
  1 along k, and rows read bottom to top when its ``Orientation`` says so. Pages that are no planes of one scalar
  volume (colour samples, a palette, other sizes or types, several series) or that tifffile cannot decode here (LZW,
  JPEG and more without ``imagecodecs``) are refused in one line.
- NRRD (``.nrrd``, ``.nhdr``) and MetaImage (``.mha``, ``.mhd``) whose voxels are stored raw (uncompressed) in the
  file after the header or in a detached data file: read from the file a few planes per chunk; geometry as Slicer
  reads it (LPS headers turned to RAS).

Which inputs are read this way (:func:`reads_chunked`): Zarr and TIFF always (the in-memory readers do not know
them); raw NRRD / MetaImage when the in-memory design would need more than half of the memory available. Every other
input, and a compressed NRRD / MetaImage of any size, is read into memory by :mod:`.volume_io`.

The pictures of such a volume are rendered from a preview read in memory (:func:`read_preview`): every s-th voxel
along each axis, at most :data:`PREVIEW_VOXELS` voxels.

Optional dependencies (the ``outofcore`` extra): ``dask[array]``, plus ``zarr`` and ``tifffile`` for their formats.
"""

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Optional

import numpy as np

from IsoSimilarityTFLib.errors import VolumeReadError
from IsoSimilarityTFLib.memory import available_memory_bytes, design_memory_bytes

from . import slicer_readers
from .headers import RAW_HEADER_SUFFIXES, StoredVoxels, stored_voxels
from .read_errors import cannot_read, python_warning, regular_file
from .volume import Volume, right_handed

if TYPE_CHECKING:  # pragma: no cover - typing only
    from .slicer_readers import ImageHeader

#: Bytes of one chunk of a raw volume (whole planes): a row of chunks is one chunk, read in one go.
RAW_CHUNK_BYTES = 64 << 20

#: Most voxels of the preview the pictures of a volume read lazily are rendered from (:func:`preview_step`): 2^25,
#: e.g. 256^3 of a 1024^3 volume, 293^3 of 2048^3, 256 x 256 x 400 of a 2048 x 2048 x 3200 micro-CT: about as many
#: voxels across as a classes.png tile has pixels (256), half of render.png's default 512. Measured on the 1024^3
#: phantom (23 tissue tiles): render stage 1.6 s and render process peak 460 MB at 256^3, against 3.9 s and 610 MB at
#: 342^3 (2^26) and 0.8 s and 360 MB at 128^3.
PREVIEW_VOXELS = 1 << 25

_TIFF_SUFFIXES = (".tif", ".tiff")
_ZARR_MARKERS = ("zarr.json", ".zarray", ".zgroup")


def is_chunked_format(path: Path) -> bool:
    """Whether ``path`` is a Zarr store or a TIFF stack: formats only this module reads."""
    if path.is_dir():
        return any((path / marker).exists() for marker in _ZARR_MARKERS) or bool(_tiff_files(path))
    return path.name.lower().endswith(_TIFF_SUFFIXES)


def reads_chunked(path: Path, n_bins: Optional[int], stored: Optional[StoredVoxels] = None) -> bool:
    """Whether ``path`` is read lazily: a Zarr or TIFF input, or a raw NRRD / MetaImage too large for memory.

    Too large: the in-memory read and design (:func:`~IsoSimilarityTFLib.memory.design_memory_bytes` with the voxels
    themselves) would need more than half the memory available; the other half stays for the rest of the machine.

    Args:
        stored: the file's :func:`.headers.stored_voxels`, when the caller has it (else it is read here).
    """
    if is_chunked_format(path):
        return True
    if not path.is_file() or not path.name.lower().endswith(RAW_HEADER_SUFFIXES):
        return False
    stored = stored if stored is not None else stored_voxels(path)
    available = available_memory_bytes()
    if stored is None or not stored.raw or available is None:
        return False
    needed = stored.nbytes + design_memory_bytes(stored.shape, n_bins or 256)
    return needed > available // 2


def read_chunked(
    path: Path, stored: Optional[StoredVoxels] = None, *, warn: Callable[[str], None] = python_warning
) -> Volume:
    """Open ``path`` lazily (see the module docstring) as a :class:`~.volume.Volume` holding a dask array.

    Args:
        stored: the file's :func:`.headers.stored_voxels`, when the caller has it. warn: called with each warning
            line (a unit converted).

    Raises:
        VolumeReadError: not a format read here, a compressed raw file, a raw file missing or truncated, or not a 3-D
            scalar volume.
    """
    name = path.name.split(".")[0] or path.name
    if path.is_dir() and any((path / marker).exists() for marker in _ZARR_MARKERS):
        values, spacing, origin = _zarr_volume(path, warn)
        return Volume(values, spacing, origin, name=name)
    if is_chunked_format(path):
        return _tiff_volume(path)
    stored = stored if stored is not None else stored_voxels(path)
    if stored is None or not stored.raw:
        raise cannot_read(
            path, "its voxels are not stored raw (uncompressed): it cannot be read a few planes at a time"
        )
    values, ijk_to_ras = raw_values(path, stored, raw_volume)
    return Volume.from_ijk_to_ras(values, ijk_to_ras, name)


def raw_values(
    path: Path,
    stored: StoredVoxels,
    read: Callable[[Path, tuple[int, int, int], np.dtype, int], Any],
    header: Optional["ImageHeader"] = None,
) -> tuple[Any, np.ndarray]:
    """The voxels of a raw file read by ``read`` (lazily or not), placed as Slicer's storage node places them.

    Dimensions and geometry come from Slicer's own header pass (:func:`.slicer_readers.read_header`), so every
    geometry field Slicer honours (``space directions``, ``spacings``, ``space``, ``TransformMatrix``, negative
    spacing, ...) means here what it means in Slicer; a left-handed frame is made right-handed as the storage node
    makes it. :mod:`.headers` gives only where the voxels are.

    Args:
        read: ``read(data file, (K, J, I), dtype, offset)`` -> the values, ``(K, J, I)``: :func:`raw_volume` for a
            dask array, ``numpy.fromfile``-like for memory.
        header: Slicer's header of ``path`` when the caller has read it already; None: read here.

    Returns:
        ``(values (K, J, I) right-handed, IJK-to-RAS 4x4)``.

    Raises:
        VolumeReadError: Slicer's reader cannot read the header or sees another size or type, or the file is
            truncated.
    """
    if header is None:
        header = slicer_readers.read_header(path, (path,))
    if header.components != 1 or header.dimensions != stored.shape[::-1]:
        raise cannot_read(
            path,
            f"its header is ambiguous: Slicer reads {header.dimensions} voxels, its storage fields say "
            f"{stored.shape[::-1]}",
        )
    found = stored.data.stat().st_size - stored.offset
    if found < stored.nbytes:
        raise cannot_read(path, f"it is truncated: {stored.nbytes} bytes of voxel data expected, {max(found, 0)} found")
    return right_handed(read(stored.data, stored.shape, stored.dtype, stored.offset), header.ijk_to_ras)


def preview_step(shape: tuple[int, int, int], max_voxels: Optional[int] = None) -> int:
    """The smallest step s such that every s-th voxel along each axis of ``shape`` is at most ``max_voxels`` voxels
    (default :data:`PREVIEW_VOXELS`); 1 when the whole volume is that small."""
    limit = PREVIEW_VOXELS if max_voxels is None else max_voxels
    step = max(1, int((float(np.prod(shape, dtype=np.float64)) / limit) ** (1 / 3)))
    while int(np.prod([-(-n // step) for n in shape], dtype=np.int64)) > limit:
        step += 1
    return step


def read_preview(volume: Volume, step: int) -> Volume:
    """Every ``step``-th voxel along each axis of a volume read lazily, in memory, in one strided read.

    Nearest sampling keeps the voxel values exact (a block average would make intensities the volume does not hold),
    so a transfer function designed on the whole volume means the same on the preview. The preview covers the same
    space: same origin (the centre of voxel 0, kept) and directions, spacing times ``step``.

    Args:
        volume: a :class:`~.volume.Volume` whose values are a dask array ``(K, J, I)``.
        step: voxels per preview voxel along each axis (see :func:`preview_step`).

    Returns:
        A :class:`~.volume.Volume` holding a numpy array of shape ``ceil((K, J, I) / step)``.
    """
    values = volume.values[::step, ::step, ::step].compute()  # on --scheduler's cluster when there is one
    spacing = tuple(s * step for s in volume.spacing)
    return Volume(values, spacing, volume.origin, volume.directions, volume.name)


class PreviewTap:
    """The preview of :func:`read_preview`, kept from the slabs of a read the design makes anyway (its
    ``value_tap``): every ``step``-th plane, strided, as the slabs go by.

    Args:
        shape: the volume's shape ``(K, J, I)``.
        step: voxels per preview voxel along each axis.
    """

    def __init__(self, shape: tuple[int, int, int], step: int) -> None:
        self.shape, self.step = tuple(int(n) for n in shape), int(step)
        self._planes: dict[int, np.ndarray] = {}

    def __call__(self, first: int, slab: np.ndarray) -> None:
        step = self.step
        for k in range(first + (-first) % step, first + len(slab), step):
            self._planes[k] = np.array(slab[k - first, ::step, ::step])

    @property
    def complete(self) -> bool:
        """Whether every plane of the preview was seen."""
        return all(k in self._planes for k in range(0, self.shape[0], self.step))

    def preview(self, volume: Volume) -> Volume:
        """The preview of ``volume``, as :func:`read_preview` reads it (once :attr:`complete`)."""
        values = np.stack([self._planes[k] for k in range(0, self.shape[0], self.step)])
        spacing = tuple(s * self.step for s in volume.spacing)
        return Volume(values, spacing, volume.origin, volume.directions, volume.name)


def raw_array(data: Path, shape: tuple[int, int, int], dtype: np.dtype, offset: int = 0) -> np.ndarray:
    """A raw volume file read into memory, in its own dtype (native byte order), shape ``(K, J, I)``."""
    values = np.fromfile(data, dtype=dtype, count=int(np.prod(shape)), offset=offset).reshape(shape)
    return values if values.dtype.isnative else values.astype(values.dtype.newbyteorder("="))


def raw_volume(data: Path, shape: tuple[int, int, int], dtype: np.dtype, offset: int = 0) -> Any:
    """A raw volume file as a dask array of chunks of whole planes (about :data:`RAW_CHUNK_BYTES` each).

    Args:
        data: the file; shape: ``(K, J, I)`` voxels, I fastest in the file; dtype: with its byte order; offset: bytes
            before the first voxel.
    """
    import dask.array as da

    plane_bytes = shape[1] * shape[2] * dtype.itemsize
    planes = max(1, min(shape[0], RAW_CHUNK_BYTES // plane_bytes))
    # from_array, not map_blocks: dask folds a later slicing (the preview's every s-th voxel) into each chunk's read,
    # so only the planes kept are read.
    return da.from_array(
        _RawFile(data, shape, dtype, offset),
        chunks=(planes, shape[1], shape[2]),
        lock=False,
        meta=np.empty((0, 0, 0), dtype=dtype),
    )


class _RawFile:
    """The voxels of a raw file as an array-like that dask reads from, one plane at a time.

    It holds the path, never the data, so a task graph holding it also runs on a distributed cluster whose workers
    see the same file system. A read with a step along k reads only the planes kept, each in one sequential read of
    the rows it spans (a memory map read the whole file for every 4th plane: the kernel's read-ahead on page faults).
    """

    def __init__(self, data: Path, shape: tuple[int, int, int], dtype: np.dtype, offset: int) -> None:
        self.data, self.shape, self.dtype, self.offset = data, shape, dtype, offset
        self.ndim = len(shape)

    def __getitem__(self, key: tuple[slice, slice, slice]) -> np.ndarray:
        """The voxels ``[k, j, i]`` of three slices (what dask asks for), in the file's dtype."""
        planes, rows, columns = (range(*axis.indices(n)) for axis, n in zip(key, self.shape))
        out = np.empty((len(planes), len(rows), len(columns)), dtype=self.dtype)
        if not out.size:
            return out
        row_bytes = self.shape[2] * self.dtype.itemsize
        whole_rows = rows.step == 1 and len(columns) == self.shape[2]  # read straight into the result
        block = None if whole_rows else np.empty((rows[-1] - rows[0] + 1, self.shape[2]), dtype=self.dtype)
        with open(self.data, "rb", buffering=0) as file:
            for n, k in enumerate(planes):
                file.seek(self.offset + (k * self.shape[1] + rows[0]) * row_bytes)
                _read_fully(file, out[n] if whole_rows else block, self.data)
                if block is not None:
                    out[n] = block[:: rows.step, columns.start : columns.stop : columns.step]
        return out

    def __dask_tokenize__(self) -> tuple:
        # The same file and layout (and not rewritten since) is the same array.
        return str(self.data), self.data.stat().st_mtime_ns, self.shape, self.dtype.str, self.offset


def _read_fully(file: Any, target: np.ndarray, path: Path) -> None:
    """Fill the C-contiguous ``target`` from ``file``'s position (a raw read may return fewer bytes than asked)."""
    view = memoryview(target.reshape(-1).view(np.uint8))  # bytes, whatever the byte order
    while view:
        count = file.readinto(view)
        if not count:
            raise cannot_read(path, "it ends before its last voxel (truncated)")
        view = view[count:]


def _zarr_volume(path: Path, warn: Callable[[str], None]) -> tuple[Any, tuple[float, ...], tuple[float, ...]]:
    """Level 0 of a Zarr array or OME-Zarr image as a 3-D dask array, with its spacing and origin (x, y, z)."""
    import dask.array as da
    import zarr

    _check_store_files(path)
    node = zarr.open(str(path), mode="r")
    spacing, origin, notes = (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), []
    if isinstance(node, zarr.Group):
        attrs = dict(node.attrs)
        multiscales = attrs.get("multiscales") or attrs.get("ome", {}).get("multiscales")
        if not multiscales:
            raise cannot_read(path, "it is a Zarr group without OME-Zarr multiscales: name the array itself")
        try:
            spacing, origin, notes = _ome_geometry(path, multiscales[0])
            level = multiscales[0]["datasets"][0]["path"]
        except (KeyError, IndexError, TypeError, ValueError) as error:
            raise cannot_read(
                path, f"its OME-Zarr multiscales metadata is malformed ({type(error).__name__}: {error})"
            ) from None
        node = node[level]
    values = da.from_zarr(node)
    while values.ndim > 3 and values.shape[0] == 1:  # OME-Zarr's time and channel axes
        values = values[0]
    _check_3d(path, values.shape)
    values = _numeric(path, values)
    for note in notes:  # once the volume is accepted
        warn(note)
    return values, spacing, origin


def _ome_geometry(path: Path, multiscale: dict) -> tuple[tuple[float, ...], tuple[float, ...], list[str]]:
    """Spacing and origin (x, y, z, in mm) of level 0 of an OME-Zarr image (OME-NGFF 0.4, 0.5), and what to warn of.

    A voxel's position is its index through the level's ``coordinateTransformations`` then the image's own (each a
    ``scale``, then optionally a ``translation``), on the last three axes (z, y, x), in the axes' ``unit``.

    Raises:
        VolumeReadError: a transformation given in a file or of another type (affine, rotation), the last three axes
            not z, y, x in space, or a unit not known. ValueError: a scale not positive, a vector not one number an
            axis.
    """
    axes = multiscale.get("axes", [])
    names = [axis.get("name") if isinstance(axis, dict) else axis for axis in axes][-3:]
    kinds = [axis.get("type") if isinstance(axis, dict) else None for axis in axes][-3:]
    spatial = [kind == "space" if kind else name not in ("t", "c") for name, kind in zip(names, kinds)]
    if axes and (len(names) < 3 or not all(spatial) or (set(names) == set("xyz") and names != list("zyx"))):
        raise cannot_read(
            path, f"its last three axes are {', '.join(map(str, names))}: a volume needs z, y, x, in space"
        )
    scale, offset = np.ones(3), np.zeros(3)
    for transform in [
        *multiscale["datasets"][0].get("coordinateTransformations", []),
        *multiscale.get("coordinateTransformations", []),  # the image's, after the level's
    ]:
        kind = transform["type"]
        if kind == "identity":
            continue
        if kind not in ("scale", "translation"):
            raise cannot_read(path, f"its '{kind}' coordinate transformation is not read here (scale, translation are)")
        if "path" in transform:
            raise cannot_read(path, f"its {kind} is given in a file ('path'), which is not read here")
        vector = np.asarray(transform[kind], dtype=float)
        if vector.ndim != 1 or vector.size != (len(axes) or 3) or not np.isfinite(vector).all():
            raise ValueError(f"{kind} {vector.tolist()} for {len(axes)} axes")
        if kind == "scale" and vector.min() <= 0:
            raise ValueError(f"scale {vector.tolist()} is not positive")
        if kind == "scale":
            scale, offset = scale * vector[-3:], offset * vector[-3:]
        else:
            offset = offset + vector[-3:]
    units = [axis.get("unit") if isinstance(axis, dict) else None for axis in axes][-3:] or [None] * 3
    millimetres = np.array([_millimetres(path, unit) for unit in units])
    converted = sorted({unit for unit in units if unit not in (None, "millimeter")})
    notes = []
    if converted:
        notes.append(f"'{path}' gives its axes in {', '.join(converted)}: spacing and origin were converted to mm")
    if None in units:
        notes.append(f"'{path}' gives no unit for some of its axes: they are taken as millimetres")
    spacing, origin = scale * millimetres, offset * millimetres
    return tuple(float(s) for s in spacing[::-1]), tuple(float(o) for o in origin[::-1]), notes


def _check_store_files(store: Path) -> None:
    """Refuse a Zarr store holding anything but regular files and folders (links followed), before zarr opens any:
    it opens chunks by name, and a chunk that is a FIFO waits forever, one linked to ``/dev/zero`` never ends. An empty
    folder is refused too: zarr writes a folder only to hold chunks or metadata, and reads a chunk replaced by a
    folder as missing, i.e. as the fill value (a plausible wrong volume)."""
    seen = set()
    for folder, subfolders, files in os.walk(store, followlinks=True):
        real = os.path.realpath(folder)
        if real in seen:  # a link back to a folder already walked
            subfolders.clear()
            continue
        seen.add(real)
        if not files and not subfolders and Path(folder) != store:
            raise cannot_read(store, f"its folder '{folder}' is empty: where zarr looks for a chunk or metadata")
        for name in files:
            regular_file(store, Path(folder) / name, "its file")


def _natural_key(path: Path) -> list:
    """Sort key that orders ``plane_2`` before ``plane_10`` (numbers by value, the rest as text)."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", path.name)]


#: OME-Zarr space units (UDUNITS-2 names) in millimetres; Slicer's world unit is the millimetre.
_UNIT_MM = {
    "millimeter": 1.0, "micrometer": 1e-3, "nanometer": 1e-6, "centimeter": 10.0, "meter": 1000.0,
    "decimeter": 100.0, "angstrom": 1e-7,
}  # fmt: skip


def _millimetres(path: Path, unit: Optional[str]) -> float:
    """Millimetres per unit of an OME-Zarr axis; no unit: the value is taken as millimetres."""
    if unit is None:
        return 1.0
    if unit not in _UNIT_MM:
        raise cannot_read(path, f"its axes are in '{unit}', a unit not known here (known: {', '.join(_UNIT_MM)})")
    return _UNIT_MM[unit]


def _tiff_files(folder: Path) -> list[Path]:
    """The TIFF planes of a folder in natural order (``plane_0, plane_1, ..., plane_10``), as Slicer's image
    stack readers and file browsers order them; text order would put ``plane_10`` after ``plane_1``."""
    return sorted((p for p in folder.iterdir() if p.name.lower().endswith(_TIFF_SUFFIXES)), key=_natural_key)


#: Slicer reads a TIFF with ITK's TIFFImageIO, whose frame is LPS with identity directions: in Slicer's RAS, index
#: i points left and j posterior (IJK to RAS ``diag(-sx, -sy, 1)``), the origin is 0.
TIFF_DIRECTIONS = np.diag([-1.0, -1.0, 1.0])
#: Millimetres per unit of the ``ResolutionUnit`` values ITK honours (2: inch, 3: centimetre). With no unit (1) or
#: none given, ITK's spacing is 1 whatever ``XResolution`` says; along k (pages or planes) it is always 1.
_TIFF_UNIT_MM = {2: 25.4, 3: 10.0}
#: TIFF ``Orientation`` values ITK reads: 1 (rows top to bottom) and 4 (bottom to top: ITK flips the rows).
_TIFF_TOP_LEFT, _TIFF_BOTTOM_LEFT = 1, 4
#: TIFF ``PhotometricInterpretation`` of a palette (colour-mapped) image.
_TIFF_PALETTE = 3


def _tiff_volume(path: Path) -> Volume:
    """A multi-page TIFF file or a folder of TIFF planes as a 3-D dask array, one chunk per page, placed as Slicer
    places it (:data:`TIFF_DIRECTIONS`, the spacing from the first page's resolution tags, :func:`_tiff_spacing`)."""
    import dask.array as da
    import tifffile
    import zarr

    if path.is_dir():
        files = [regular_file(path, file, "its TIFF plane") for file in _tiff_files(path)]
        first = _tiff_plane(path, files[0])
        for file in files[1:]:
            plane = _tiff_plane(path, file)
            if plane[:2] != first[:2]:
                raise cannot_read(
                    path,
                    f"its TIFF planes differ: {files[0].name} is {first[0]} of {first[1]}, {file.name} is "
                    f"{plane[0]} of {plane[1]}; every plane of the stack needs one size and type",
                )
            if plane[2] != first[2]:
                raise cannot_read(
                    path, f"its TIFF planes differ in Orientation: {files[0].name} {first[2]}, {file.name} {plane[2]}"
                )
        store = tifffile.TiffSequence(files).aszarr()
        page = _tiff_first_page(path, files[0])
    else:
        page = _check_tiff_pages(path)
        store = tifffile.imread(path, aszarr=True)
    orientation, spacing = page
    values = da.from_zarr(zarr.open(store, mode="r"))
    _check_3d(path, values.shape)
    values = _numeric(path, values)
    if orientation == _TIFF_BOTTOM_LEFT:
        values = values[:, ::-1, :]  # ITK puts the file's last row at j = 0
    return Volume(values, spacing, (0.0, 0.0, 0.0), TIFF_DIRECTIONS, path.name.split(".")[0] or path.name)


def _tiff_spacing(page: Any) -> tuple[float, float, float]:
    """Spacing (i, j, k) in mm of a TIFF stack whose first page is ``page``, as ITK's TIFFImageIO gives it: 25.4 /
    ``XResolution`` along i (``YResolution`` along j) for a ``ResolutionUnit`` of inch, 10 / resolution for a
    centimetre, else 1 (no unit, no or a non-positive resolution); 1 along k. ITK holds the resolution as float32."""
    tags = page.tags

    def resolution(name: str) -> float:
        value = tags.valueof(name, (1, 1))
        try:
            number = value[0] / value[1] if isinstance(value, tuple) else float(value)
        except (ZeroDivisionError, TypeError, IndexError):
            return 0.0
        return float(np.float32(number)) if np.isfinite(number) else 0.0

    try:
        millimetres = _TIFF_UNIT_MM.get(int(tags.valueof("ResolutionUnit", 1)))
    except (TypeError, ValueError):
        millimetres = None
    x, y = resolution("XResolution"), resolution("YResolution")
    if millimetres is None or not (x > 0 and y > 0):
        return (1.0, 1.0, 1.0)
    return (millimetres / x, millimetres / y, 1.0)


def _tiff_page_problem(page: Any) -> Optional[str]:
    """Why a TIFF page is not a plane of a scalar volume as Slicer reads it (None if it is): colour samples, a
    palette (ITK reads its colours, tifffile its indices), or rows in an order ITK does not read."""
    samples = int(getattr(page, "samplesperpixel", 1) or 1)
    if samples != 1:
        return f"it has {samples} components per voxel (an RGB or multi-sample image); only scalar volumes are read"
    if int(getattr(page, "photometric", 1)) == _TIFF_PALETTE:
        return (
            "its pages are palette (colour-mapped) images, of which Slicer reads the colours, not the stored "
            "indices: save the values as a grayscale stack"
        )
    orientation = int(page.tags.valueof("Orientation", _TIFF_TOP_LEFT))
    if orientation not in (_TIFF_TOP_LEFT, _TIFF_BOTTOM_LEFT):
        return f"its TIFF Orientation is {orientation}; Slicer's reader reads rows top-left (1) or bottom-left (4) only"
    return None


def _check_tiff_decodes(path: Path, tiff: Any, page: Any) -> None:
    """Decode the first strip or tile of ``page``: a compression tifffile cannot decode here (LZW, JPEG, ...
    without the ``imagecodecs`` package) is refused now, in one line, not found in the middle of the design."""
    offsets, counts = page.dataoffsets, page.databytecounts
    if not offsets or not counts or not counts[0]:
        return
    tiff.filehandle.seek(offsets[0])
    data = tiff.filehandle.read(counts[0])
    try:
        page.decode(data, 0, jpegtables=page.jpegtables)
    except Exception as error:  # tifffile raises KeyError, ValueError, ImportError, or the codec's own error
        compression = getattr(page.compression, "name", str(page.compression))
        reason = " ".join(str(error).split())
        if "imagecodecs" in reason:
            raise cannot_read(
                path,
                f"its pages are {compression}-compressed, which tifffile decodes only with the imagecodecs package: "
                "pip install imagecodecs, or save the stack uncompressed or deflate-compressed",
            ) from None
        raise cannot_read(path, f"its first {compression}-compressed page cannot be decoded ({reason})") from None


def _tiff_plane(folder: Path, file: Path) -> tuple[tuple[int, ...], str, int]:
    """Shape, dtype and Orientation of a single-plane TIFF file of a folder stack (a multi-page, colour or
    unreadable file refused)."""
    import tifffile

    try:
        with tifffile.TiffFile(file) as tiff:
            pages = len(tiff.pages)
            page = tiff.pages[0]
            shape, dtype, problem = tuple(page.shape), str(page.dtype), _tiff_page_problem(page)
            orientation = int(page.tags.valueof("Orientation", _TIFF_TOP_LEFT))
    except (tifffile.TiffFileError, OSError, ValueError, TypeError) as error:
        raise cannot_read(folder, f"{file.name} is not a readable TIFF file ({error})") from None
    if problem is not None:
        raise cannot_read(folder, f"{file.name}: {problem}")
    if pages != 1 or len(shape) != 2:
        raise cannot_read(
            folder, f"{file.name} holds {pages} page(s) of shape {shape}: a folder stack needs one 2-D plane a file"
        )
    return shape, dtype, orientation


def _tiff_first_page(folder: Path, file: Path) -> tuple[int, tuple[float, float, float]]:
    """Orientation and spacing of a folder stack, from its first plane (checked to decode)."""
    import tifffile

    try:
        with tifffile.TiffFile(file) as tiff:
            page = tiff.pages[0]
            _check_tiff_decodes(folder, tiff, page)
            return int(page.tags.valueof("Orientation", _TIFF_TOP_LEFT)), _tiff_spacing(page)
    except VolumeReadError:
        raise
    except (tifffile.TiffFileError, OSError, ValueError, TypeError) as error:
        raise cannot_read(folder, f"{file.name} is not a readable TIFF file ({error})") from None


def _check_tiff_pages(path: Path) -> tuple[int, tuple[float, float, float]]:
    """Refuse a multi-page TIFF file whose pages differ in size or type, or form several series (tifffile reads its
    first series only, a part of the file that would pass for the whole volume), or are no planes of a scalar volume
    (:func:`_tiff_page_problem`), or cannot be decoded here; return the Orientation and spacing of its pages."""
    import tifffile

    pages, orientations, compressions = [], set(), {}
    try:
        with tifffile.TiffFile(path) as tiff:
            for page in tiff.pages:  # one pass: a stack may have thousands of pages
                pages.append((page.shape, page.dtype))
                problem = _tiff_page_problem(page)
                if problem is not None:
                    raise cannot_read(path, problem)
                orientations.add(int(page.tags.valueof("Orientation", _TIFF_TOP_LEFT)))
                compressions.setdefault((page.compression, page.predictor), page)
            series = len(tiff.series)
            for page in compressions.values():
                _check_tiff_decodes(path, tiff, page)
            spacing = _tiff_spacing(tiff.pages[0])
    except VolumeReadError:
        raise
    except (tifffile.TiffFileError, OSError, ValueError, TypeError) as error:
        raise cannot_read(path, f"not a readable TIFF file ({error})") from None
    other = next((n for n, page in enumerate(pages) if page != pages[0]), None)
    if other is not None:
        (shape, dtype), (other_shape, other_dtype) = pages[0], pages[other]
        raise cannot_read(
            path,
            f"its TIFF pages differ: page 1 is {shape} of {dtype}, page {other + 1} is {other_shape} of {other_dtype}; "
            "every page of the stack needs one size and type",
        )
    if len(orientations) > 1:
        raise cannot_read(path, f"its TIFF pages differ in Orientation ({', '.join(map(str, sorted(orientations)))})")
    if series > 1:
        raise cannot_read(
            path, f"its TIFF pages form {series} separate images (series), of which one would be read: save one stack"
        )
    return orientations.pop(), spacing


def _numeric(path: Path, values: Any) -> Any:
    """The voxels of a Zarr array or TIFF stack as numbers in native byte order: booleans as uint8 (as ``.npy``
    inputs), big-endian values swapped as they are read; strings, complex numbers, dates refused in one line."""
    dtype = values.dtype
    if dtype.kind == "b":
        return values.astype(np.uint8)
    if dtype.kind not in "iuf":
        raise cannot_read(path, f"its voxels are of type {dtype}; a number type (int16, uint8, float32, ...) is needed")
    return values if dtype.isnative else values.astype(dtype.newbyteorder("="))


def _check_3d(path: Path, shape: tuple[int, ...]) -> None:
    if len(shape) != 3 or min(shape) < 2:
        raise cannot_read(path, f"it holds an array of shape {tuple(shape)}; a 3-D scalar volume is needed")
