"""Read a scalar volume with its geometry, the way Slicer reads it, refusing from its header what would not fit.

One reader per format (:data:`READERS`, each a :class:`Reader`: a probe and a read that checks the header and the
size before allocating), behind one entry point, :func:`read_volume`.

Every reader returns a :class:`Volume`: the voxel values as a ``(K, J, I)`` array (slowest axis first, like
``slicer.util.arrayFromVolume``) and the spacing, origin and axis directions in Slicer's RAS world.

- NRRD (``.nrrd``, ``.nhdr``), MetaImage (``.mha``, ``.mhd``), NIfTI (``.nii``, ``.nii.gz``, or a ``.hdr`` / ``.img``
  pair), a DICOM file or a DICOM series folder: Slicer's own reader (:mod:`.slicer_readers`, from PyPI's
  ``slicer-core``), so values and geometry are what Slicer shows. A folder must hold one series; a DICOM file reads
  the series it belongs to. NIfTI-2, which Slicer's reader refuses, is read by it as the same header in NIfTI-1.
- ``.vti``: VTK's XML image reader; its coordinates are taken as RAS. A file naming no active scalars is read from
  its first point-data array, with a warning.
- ``.npy``: its header is checked before the array is loaded (no pickles); spacing 1 mm, origin 0, no rotation.
- Zarr and OME-Zarr stores, TIFF stacks, and raw NRRD / MetaImage too large for memory: read lazily as dask arrays
  (:mod:`.chunked_readers`), designed out of core.
- ``.inv3``: an InVesalius project (gzip tar holding ``main.plist`` and the raw int16 ``matrix.dat``), read here since
  no library reads it.

Before any voxel is allocated, the size given by the header is checked: a 3-D scalar volume, no larger than the file
can hold (a gzip stream expands at most about 1032 times), and small enough for the memory available
(:mod:`IsoSimilarityTFLib.memory`). Any failure raises one error with a one-line message naming the file:
:class:`VolumeReadError`, or :class:`InsufficientMemoryError` for a volume that does not fit. What a user must know of
a volume read (an array chosen, a unit converted) goes to the ``warn`` callback, one line each.
"""

import contextlib
import gzip
import math
import os
import plistlib
import struct
import tarfile
import tempfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Union
from xml.parsers.expat import ExpatError

import numpy as np

from IsoSimilarityTFLib.errors import VolumeReadError
from IsoSimilarityTFLib.memory import check_memory

from . import chunked_readers, headers, slicer_readers
from .formatting import format_bytes
from .read_errors import cannot_read, captured_native_output, first_message, python_warning, regular_file
from .volume import Volume

PathLike = Union[str, "os.PathLike[str]"]

__all__ = [
    "READERS",
    "SUPPORTED_TEXT",
    "Reader",
    "Volume",
    "VolumeReadError",
    "read_volume",
    "reader_for",
    "real_dataset_path",
]

SUPPORTED_TEXT = (
    ".nrrd, .nhdr, .mha, .mhd, .nii, .nii.gz, .hdr/.img (NIfTI pair), .vti, .npy, .inv3, .tif, .tiff, a Zarr store, "
    "a folder of TIFF planes, a DICOM file or a DICOM series folder"
)

#: The warning channel of the readers: called with each warning line.
Warn = Callable[[str], None]


#: Largest expansion of a deflate (gzip, zlib) stream: a file of N bytes holds at most about 1032 N bytes of voxels.
_MAX_DEFLATE_RATIO = 1032

#: Debian locations of the real test volumes named in DESIGN.md ("Data to test on").
_REAL_DATASETS: dict[str, tuple[str, ...]] = {
    "head-ct": (
        "/usr/share/doc/invesalius-examples/examples/Cranium.inv3",
        "/usr/share/invesalius/examples/Cranium.inv3",
    ),
    "brain-mri": (
        "/usr/share/mricron/templates/ch2.nii.gz",
        "/usr/share/mricron-data/templates/ch2.nii.gz",
        "/usr/lib/mricron/templates/ch2.nii.gz",
    ),
    "brain-stripped": (
        "/usr/share/mricron/templates/ch2bet.nii.gz",
        "/usr/share/mricron-data/templates/ch2bet.nii.gz",
        "/usr/lib/mricron/templates/ch2bet.nii.gz",
    ),
}

#: InVesalius stores axial projects with i towards the patient's left, j towards anterior (it flips DICOM rows)
#: and k towards superior: in RAS, the columns below.
_INV3_AXIAL_DIRECTIONS = np.diag([-1.0, 1.0, 1.0])


def read_volume(path: PathLike, *, n_bins: Optional[int] = None, warn: Optional[Warn] = None) -> Volume:
    """Read a scalar 3-D volume from ``path`` (see the module docstring for formats).

    Args:
        path: a volume file, a DICOM file, or a folder holding one DICOM series.
        n_bins: the bins the volume will be designed with: the memory check then also counts the design's needs.
        warn: called with each warning line about the volume read (default: Python's warnings,
            :class:`~.read_errors.VolumeReadWarning`).

    Raises:
        VolumeReadError: the path is missing, of an unsupported kind, corrupt or truncated, or holds a 2-D, 4-D or
            multi-component (vector/RGB) image. InsufficientMemoryError: the volume would not fit in memory.
    """
    path = Path(path)
    if not path.exists():
        raise cannot_read(path, "no such file or directory")
    if not path.is_dir():
        regular_file(path, path, "it")
    reader = reader_for(path)
    if reader is None:
        raise cannot_read(
            path, f"unsupported file type '{''.join(path.suffixes) or path.name}' (expected {SUPPORTED_TEXT})"
        )
    return reader.read(path, path.name if path.is_dir() else _stem(path), n_bins, warn or python_warning)


@dataclass(frozen=True)
class Reader:
    """One input format behind the one interface every read goes through (:func:`read_volume`).

    Attributes:
        name: the format, as messages name it.
        probe: whether a path (an existing file or folder) is of this format; cheap (a suffix, a magic number).
        read: ``read(path, volume name, n_bins, warn)`` -> :class:`Volume`. It reads the header once, checks from it
            the size (a 3-D scalar volume that the file can hold and the memory fits, :func:`_check_size`) before
            any voxel is allocated, then reads the voxels (into memory, or lazily as a dask array when the format or
            the size asks for it), or raises one :class:`VolumeReadError` (or ``InsufficientMemoryError``) line.
            ``warn`` takes each warning line.
    """

    name: str
    probe: Callable[[Path], bool]
    read: Callable[[Path, str, Optional[int], Warn], Volume]


def reader_for(path: Path) -> Optional[Reader]:
    """The reader of an existing file or folder (the first of :data:`READERS` whose probe accepts it), or None."""
    return next((reader for reader in READERS if reader.probe(path)), None)


def _read_nrrd_metaimage_nifti(path: Path, name: str, n_bins: Optional[int], warn: Optional[Warn] = None) -> Volume:
    """NRRD, MetaImage, NIfTI: Slicer's reader, or the lazy raw reader for a raw file too large for memory."""
    headers.check_data_files(path)
    # The storage fields of a NRRD / MetaImage header, parsed once for the lazy-or-not choice, the size bound and
    # the exact read of 64-bit integers.
    stored = headers.stored_voxels(path)  # None for NIfTI
    if chunked_readers.reads_chunked(path, n_bins, stored):
        return chunked_readers.read_chunked(path, stored)
    # A NIfTI's storage is checked first: Slicer's header pass reads its extensions into memory.
    nifti = _nifti_layout(path) if path.name.lower().endswith(NIFTI_SUFFIXES) else None
    if nifti is not None and warn is not None:
        for message in _nifti_warnings(path, nifti):
            warn(message)
    return _read_with_slicer(path, (path,), name, n_bins, stored, nifti)


def _suffix(*suffixes: str) -> Callable[[Path], bool]:
    return lambda path: path.is_file() and path.name.lower().endswith(suffixes)


def real_dataset_path(name: str) -> Optional[Path]:
    """Return the installed path of a real test volume, or None when its Debian package is not installed.

    Args:
        name: ``"head-ct"`` (InVesalius ``Cranium.inv3``, package ``invesalius-examples``), ``"brain-mri"``
            (Colin27 ``ch2.nii.gz``, package ``mricron-data``) or ``"brain-stripped"`` (its skull-stripped
            ``ch2bet.nii.gz``, same package).

    Raises:
        KeyError: unknown name.
    """
    if name not in _REAL_DATASETS:
        raise KeyError(f"Unknown dataset '{name}'; known: {', '.join(sorted(_REAL_DATASETS))}")
    for candidate in _REAL_DATASETS[name]:
        if Path(candidate).is_file():
            return Path(candidate)
    return None


def _stem(path: Path) -> str:
    suffix = next((s for s in (".nii.gz", ".img.gz") if path.name.lower().endswith(s)), path.suffix)
    return path.name[: -len(suffix)] if suffix and len(suffix) < len(path.name) else path.name


def _check_size(
    path: Path,
    dimensions: tuple[int, ...],
    components: int,
    dtype: np.dtype,
    n_bins: Optional[int],
    stored_bytes: Optional[int] = None,
    held_bytes: int = 0,
) -> None:
    """Refuse, from the header alone, what is not a 3-D scalar volume, cannot be in the file, or would not fit.

    Args:
        dimensions: voxels along i, j, k. components: values per voxel. dtype: the values' type.
        n_bins: passed to the memory check. stored_bytes: bytes of the file(s) holding the voxels, when the format
            stores them raw or deflated (the bound above which the header must be lying). held_bytes: bytes the
            reader holds in memory beside the voxels (NIfTI header extensions).
    """
    if components != 1:
        raise cannot_read(
            path, f"it has {components} components per voxel (a vector or RGB image); only scalar volumes are supported"
        )
    size = " x ".join(str(int(d)) for d in dimensions)
    if len(dimensions) != 3 or min(dimensions) < 1 or sum(int(d) > 1 for d in dimensions) < 3:
        raise cannot_read(path, f"it is a 2-D image ({size} voxels); a 3-D volume is needed")
    voxel_bytes = int(np.prod([int(d) for d in dimensions], dtype=np.float64)) * dtype.itemsize
    if stored_bytes is not None and voxel_bytes > stored_bytes * _MAX_DEFLATE_RATIO:
        raise cannot_read(
            path,
            f"its header announces {size} voxels of {dtype.name} ({format_bytes(voxel_bytes)}), more than its "
            f"{stored_bytes} bytes on disk can hold: it is truncated or corrupt",
        )
    check_memory(tuple(int(d) for d in dimensions[::-1]), n_bins, input_bytes=voxel_bytes + held_bytes)


def _read_with_slicer(
    path: Path,
    files: tuple[Path, ...],
    name: str,
    n_bins: Optional[int],
    stored: Optional[headers.StoredVoxels] = None,
    nifti: Optional["_NiftiLayout"] = None,
) -> Volume:
    """Read with Slicer's storage node, or (64-bit integers) exactly from the raw file; ``stored``: the storage
    fields of a NRRD / MetaImage header, ``nifti``: the storage of a NIfTI input (None for other formats)."""
    if stored is not None:
        on_disk = stored.stored_bytes
    elif nifti is not None:
        on_disk = sum(f.stat().st_size for f in {nifti.header, nifti.data})
    elif path.name.lower().endswith(headers.RAW_HEADER_SUFFIXES):
        on_disk = None  # a list or pattern of data files: only the memory bound applies
    else:
        on_disk = sum(f.stat().st_size for f in files)
    with _slicer_files(path, files, nifti) as files:
        header = slicer_readers.read_header(path, files)
        held = nifti.extension_bytes if nifti is not None else 0
        _check_size(path, header.dimensions, header.components, header.dtype, n_bins, on_disk, held)
        if stored is not None and stored.size_mismatch:
            raise cannot_read(path, stored.size_mismatch)
        if nifti is not None:
            _check_nifti(path, header.dimensions, nifti)
        if stored is not None and stored.dtype.kind in "iu" and stored.dtype.itemsize == 8:
            # Slicer's reader turns 64-bit integers into float32 (exact only below 2^24): read the stored integers.
            if not stored.raw:
                raise cannot_read(
                    path,
                    f"it holds {stored.dtype.name} voxels, which Slicer's reader rounds to float32, and they are "
                    "compressed: save them uncompressed (raw), or as int32 or float64",
                )
            _check_size(path, header.dimensions, 1, stored.dtype, n_bins, stored.stored_bytes)
            values, ijk_to_ras = chunked_readers.raw_values(path, stored, chunked_readers.raw_array, header)
            return Volume.from_ijk_to_ras(values, ijk_to_ras, name)
        values, ijk_to_ras = slicer_readers.read_image(path, header)
    return Volume.from_ijk_to_ras(values, ijk_to_ras, name)


#: NIfTI inputs: one file, or the header (``.hdr``) or the voxels (``.img``, ``.img.gz``) of a pair.
NIFTI_SUFFIXES = (".nii", ".nii.gz", ".hdr", ".img", ".img.gz")

#: NIfTI datatype codes of 64-bit integers (NIFTI_TYPE_INT64, NIFTI_TYPE_UINT64).
_NIFTI_INT64 = {1024: "int64", 1280: "uint64"}


#: Bytes of NIfTI header extensions accepted. They hold metadata (AFNI attributes, a DICOM header, XML): kilobytes to
#: a few MB. Slicer's reader holds them in memory beside the voxels, so a small ``.nii.gz`` declaring gigabytes of
#: zeros there would take gigabytes.
MAX_NIFTI_EXTENSION_BYTES = 64 << 20


@dataclass(frozen=True)
class _NiftiLayout:
    """Where a NIfTI input keeps its header and voxels.

    Attributes:
        header: the file holding the header (the ``.nii``, or the ``.hdr`` of a pair); head: its first bytes (the
            whole header), endian: its byte order (``"<"`` or ``">"``); version: 1 or 2.
        data: the file holding the voxels (the same, or the ``.img`` of a pair). They start at byte ``offset``
            (``vox_offset``) of it, once inflated ``size`` bytes long, and take ``bitpix`` bits each.
        extension_bytes: bytes of header extensions, read into memory by Slicer's reader.
    """

    header: Path
    head: bytes
    endian: str
    version: int
    data: Path
    offset: int
    size: int
    bitpix: int
    extension_bytes: int


def _nifti_files(path: Path) -> tuple[Path, Path]:
    """The header file and the voxels' file of a NIfTI input: the file itself, or the ``.hdr`` and the ``.img`` (or
    ``.img.gz``, looked for in that order, as the NIfTI library does) of a pair, either given.

    Raises:
        VolumeReadError: the other file of a pair is missing or not a regular file; the ``.img.gz`` given is not the
            file Slicer's reader would read (a ``.img`` beside it).
    """
    lower = path.name.lower()
    if lower.endswith((".nii", ".nii.gz")):
        return path, path
    stem = path.name[: -len(next(s for s in (".hdr", ".img.gz", ".img") if lower.endswith(s)))]
    upper = path.name[len(stem) + 1 : len(stem) + 4].isupper()  # the library keeps the case of the suffix given
    header = path if lower.endswith(".hdr") else path.with_name(stem + (".HDR" if upper else ".hdr"))
    if not header.exists():
        raise cannot_read(path, f"its header '{header.name}' does not exist: a NIfTI pair is read from its .hdr")
    candidates = [path.with_name(stem + suffix) for suffix in ((".IMG", ".IMG.gz") if upper else (".img", ".img.gz"))]
    data = next((file for file in candidates if file.exists()), None)
    if data is None:
        raise cannot_read(path, f"its voxel file '{candidates[0].name}' does not exist (the .img of the .hdr)")
    if path not in (header, data):
        raise cannot_read(
            path, f"Slicer's reader reads the voxels of '{header.name}' from '{data.name}', not this file"
        )
    return regular_file(path, header, "its header"), regular_file(path, data, "its voxel file")


def _inflated_bytes(path: Path, file: Path) -> int:
    """Bytes of ``file`` once inflated: a ``.gz`` is decompressed as a stream (never held in memory), which also finds
    a truncated or corrupt stream."""
    if not file.name.lower().endswith(".gz"):
        return file.stat().st_size
    size = 0
    try:
        with gzip.open(file, "rb") as handle:
            while True:
                chunk = handle.read(1 << 22)
                if not chunk:
                    return size
                size += len(chunk)
    except (OSError, EOFError, zlib.error) as error:
        raise cannot_read(path, f"the gzip stream is truncated or corrupt ({error})") from None


def _nifti_layout(path: Path) -> _NiftiLayout:
    """The storage of a NIfTI input, checked before Slicer's reader reads its header (and the extensions with it).

    The voxels start at ``vox_offset`` and take ``bitpix`` bits each, the stored type: with ``scl_slope`` /
    ``scl_inter`` Slicer gives float32 values of int16 (or uint16, ...) voxels, so the bytes on disk are counted
    from the header's own type, never from the type Slicer returns. NIfTI-1: datatype, bitpix int16 at bytes 70, 72;
    vox_offset float32 at 108; magic at 344. NIfTI-2: int16 at 12, 14; int64 at 168; magic at 4.

    Raises:
        VolumeReadError: a truncated or corrupt gzip stream, not a NIfTI header (an Analyze 7.5 pair), 64-bit integers
            (which Slicer's reader rounds to float32), a bad ``bitpix`` or ``vox_offset``, voxels starting past the
            end of the file, or extensions larger than :data:`MAX_NIFTI_EXTENSION_BYTES`.
    """
    header, data = _nifti_files(path)
    pair = header != data
    try:
        with (gzip.open if header.name.lower().endswith(".gz") else open)(header, "rb") as handle:
            head = handle.read(540)
    except (OSError, EOFError, zlib.error) as error:
        raise cannot_read(path, f"the gzip stream is truncated or corrupt ({error})") from None
    if len(head) < 348:
        raise cannot_read(path, "the NIfTI header is truncated")
    # sizeof_hdr: byte of datatype, type and byte of vox_offset, byte of magic
    layouts = {348: (70, "f", 108, 344), 540: (12, "q", 168, 4)}
    for endian in "<>":
        sizeof_hdr = struct.unpack_from(endian + "i", head)[0]
        if sizeof_hdr in layouts and len(head) >= sizeof_hdr:
            at_type, kind, at_offset, at_magic = layouts[sizeof_hdr]
            datatype, bitpix = struct.unpack_from(endian + "hh", head, at_type)
            vox_offset = struct.unpack_from(endian + kind, head, at_offset)[0]
            magic = head[at_magic : at_magic + 4]
            break
    else:
        raise cannot_read(path, "not a NIfTI-1 or NIfTI-2 header")
    if pair and magic not in (b"ni1\0", b"ni2\0"):
        raise cannot_read(
            path,
            f"'{header.name}' is an Analyze 7.5 header (no NIfTI magic 'ni1'), whose orientation readers guess (left "
            "and right may be swapped): convert it to NIfTI or NRRD where its orientation is known",
        )
    if datatype in _NIFTI_INT64:
        raise cannot_read(
            path,
            f"it holds {_NIFTI_INT64[datatype]} voxels, which Slicer's reader rounds to float32: save them as int32, "
            "float64, or a raw NRRD (read exactly)",
        )
    if bitpix <= 0 or bitpix % 8:
        raise cannot_read(path, f"its header gives {bitpix} bits per voxel")
    if not math.isfinite(vox_offset) or vox_offset < 0:
        raise cannot_read(path, f"its header gives vox_offset {vox_offset}")
    # The voxels of one file start after its header even when vox_offset says less; a pair's .img holds only voxels.
    offset = int(vox_offset) if pair else max(int(vox_offset), sizeof_hdr)
    extension_bytes = header.stat().st_size - sizeof_hdr if pair else offset - sizeof_hdr
    size = _inflated_bytes(path, data)
    version = 1 if sizeof_hdr == 348 else 2
    layout = _NiftiLayout(header, head[:sizeof_hdr], endian, version, data, offset, size, bitpix, extension_bytes)
    if layout.offset > size:
        raise cannot_read(
            path, f"it is truncated: its voxels start at byte {layout.offset} (vox_offset), past its end ({size} bytes)"
        )
    if layout.extension_bytes > MAX_NIFTI_EXTENSION_BYTES:
        raise cannot_read(
            path,
            f"its header extensions take {format_bytes(layout.extension_bytes)} (vox_offset {layout.offset}), more "
            f"than the {format_bytes(MAX_NIFTI_EXTENSION_BYTES)} of metadata accepted (Slicer's reader holds them in "
            "memory): remove them, e.g. save the volume again from Slicer",
        )
    return layout


def _nifti_warnings(path: Path, layout: _NiftiLayout) -> list[str]:
    """Where the values Slicer's reader gives rest on a rule the NIfTI standard does not share: ``scl_slope`` 0 means
    "no scaling" in the standard (and to nibabel), but Slicer's reader still adds ``scl_inter``."""
    slope, intercept = struct.unpack_from(layout.endian + ("2f" if layout.version == 1 else "2d"), layout.head,
                                          112 if layout.version == 1 else 176)  # fmt: skip
    if slope == 0 and intercept != 0 and np.isfinite(intercept):
        return [
            f"'{path.name}' has scl_slope 0 (no scaling, by the NIfTI standard) and scl_inter {intercept:g}: its "
            f"values are read as Slicer reads them, {intercept:g} added to every voxel"
        ]
    return []


def _check_nifti(path: Path, dimensions: tuple[int, int, int], layout: _NiftiLayout) -> None:
    """Refuse a truncated NIfTI file: Slicer's NIfTI reader fills missing voxels with zeros and says nothing."""
    voxel_bytes = int(np.prod(dimensions, dtype=np.float64)) * (layout.bitpix // 8)
    if layout.size - layout.offset < voxel_bytes:
        found = layout.size - layout.offset
        raise cannot_read(path, f"it is truncated: {voxel_bytes} bytes of voxel data expected, {found} found")


#: The NIfTI-2 header fields Slicer's reader reads for the voxels and their geometry, as NIfTI-1 holds them: (NIfTI-1
#: format and byte, NIfTI-2 format and byte). The others (descriptions, slice timing, display range) decide neither.
_NIFTI2_AS_NIFTI1 = (
    ("8h", 40, "8q", 16),  # dim
    ("h", 68, "i", 504),  # intent_code
    ("2h", 70, "2h", 12),  # datatype, bitpix
    ("8f", 76, "8d", 104),  # pixdim
    ("2f", 112, "2d", 176),  # scl_slope, scl_inter
    ("B", 123, "i", 500),  # xyzt_units
    ("2h", 252, "2i", 344),  # qform_code, sform_code
    ("18f", 256, "18d", 352),  # quatern_b, c, d, qoffset_x, y, z, srow_x, srow_y, srow_z
)


def _nifti1_header(path: Path, layout: _NiftiLayout) -> bytes:
    """The NIfTI-1 pair header (magic ``ni1``) of a NIfTI-2 header: the same fields, narrower (float64 to float32,
    about 7 significant digits, as a NIfTI-1 file holds them); the voxels stay where they are (``vox_offset``).

    Raises:
        VolumeReadError: an axis longer than NIfTI-1's 32767 voxels, or a field out of NIfTI-1's range.
    """
    endian, head = layout.endian, layout.head
    dims = struct.unpack_from(endian + "8q", head, 16)
    if 1 <= dims[0] <= 7 and max(dims[1 : dims[0] + 1]) > 32767:
        size = " x ".join(str(d) for d in dims[1 : dims[0] + 1])
        raise cannot_read(
            path,
            f"it is NIfTI-2 of {size} voxels; Slicer's reader reads NIfTI-1, at most 32767 voxels an axis: save it "
            "as NRRD",
        )
    out = bytearray(348)
    try:
        for narrow, at, wide, at_wide in _NIFTI2_AS_NIFTI1:
            struct.pack_into(endian + narrow, out, at, *struct.unpack_from(endian + wide, head, at_wide))
        struct.pack_into(endian + "i", out, 0, 348)
        struct.pack_into(endian + "f", out, 108, layout.offset)
    except (struct.error, OverflowError) as error:
        raise cannot_read(
            path, f"its NIfTI-2 header holds a value NIfTI-1, which Slicer reads, cannot ({error})"
        ) from None
    if struct.unpack_from(endian + "f", out, 108)[0] != layout.offset:
        raise cannot_read(path, f"its voxels start at byte {layout.offset}, which a NIfTI-1 header cannot say exactly")
    out[344:348] = b"ni1\0"
    return bytes(out)


@contextlib.contextmanager
def _slicer_files(path: Path, files: tuple[Path, ...], nifti: Optional[_NiftiLayout]) -> Iterator[tuple[Path, ...]]:
    """The files Slicer's reader reads: ``files``, or a NIfTI's header file (a pair is read from its ``.hdr``).

    Slicer's reader refuses NIfTI-2, which differs from NIfTI-1 only in the width of its header fields: it reads one
    as the same header in NIfTI-1 (:func:`_nifti1_header`), written as a pair in a temporary folder whose ``.img``
    links to the voxels' file. Values and geometry are then Slicer's, by the rules of its NIfTI reader.
    """
    if nifti is None or nifti.version == 1:
        yield files if nifti is None else (nifti.header,)
        return
    header = _nifti1_header(path, nifti)
    with tempfile.TemporaryDirectory(prefix="isosimtf-nifti2-") as folder:
        (Path(folder) / "volume.hdr").write_bytes(header + bytes(4))  # no extensions
        voxels = Path(folder) / ("volume.img.gz" if nifti.data.name.lower().endswith(".gz") else "volume.img")
        try:
            os.symlink(nifti.data.resolve(), voxels)
        except OSError:  # Windows allows symbolic links only with a privilege; a hard link needs none
            try:
                os.link(nifti.data.resolve(), voxels)
            except OSError as error:
                raise cannot_read(path, f"its voxels cannot be linked for Slicer's reader ({error})") from None
        yield (Path(folder) / "volume.hdr",)


def _read_vti(path: Path, name: str, n_bins: Optional[int], warn: Warn) -> Volume:
    from vtkmodules.util.numpy_support import get_numpy_array_type, vtk_to_numpy
    from vtkmodules.vtkCommonDataModel import vtkDataObject, vtkDataSetAttributes
    from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader

    reader = vtkXMLImageDataReader()
    if not reader.CanReadFile(str(path)):
        raise cannot_read(path, "not a VTK XML image data (.vti) file")
    reader.SetFileName(str(path))
    with captured_native_output() as texts:
        reader.UpdateInformation()
    info = reader.GetOutputInformation(0)
    extent = info.Get(vtkStreamingDemandDrivenPipeline.WHOLE_EXTENT())
    scalars = vtkDataObject.GetActiveFieldInformation(
        info, vtkDataObject.FIELD_ASSOCIATION_POINTS, vtkDataSetAttributes.SCALARS
    )
    arrays = info.Get(vtkDataObject.POINT_DATA_VECTOR())
    fields = [arrays.GetInformationObject(n) for n in range(arrays.GetNumberOfInformationObjects())] if arrays else []
    first_array = scalars is None and bool(
        fields
    )  # no active scalars: the first point-data array, as VTK tools take it
    if first_array:
        scalars = fields[0]
    if reader.GetErrorCode() or extent is None or scalars is None:
        raise cannot_read(path, first_message(texts) or "the file holds no point scalars")
    dimensions = tuple(int(extent[2 * a + 1] - extent[2 * a] + 1) for a in range(3))
    dtype = np.dtype(get_numpy_array_type(scalars.Get(vtkDataObject.FIELD_ARRAY_TYPE())))
    # VTK XML files may be LZMA-compressed (no useful bound on the expansion): only the memory bound applies.
    _check_size(path, dimensions, scalars.Get(vtkDataObject.FIELD_NUMBER_OF_COMPONENTS()), dtype, n_bins)
    with captured_native_output() as texts:
        reader.Update()
    image = reader.GetOutput()
    point_data = image.GetPointData() if image is not None else None
    array = None if point_data is None else point_data.GetArray(0) if first_array else point_data.GetScalars()
    i, j, k = dimensions
    if reader.GetErrorCode() or array is None or array.GetNumberOfValues() != i * j * k or first_message(texts):
        raise cannot_read(path, f"the voxel data are truncated or corrupt ({first_message(texts) or 'no scalars'})")
    matrix = image.GetDirectionMatrix()
    rotation = np.array([[matrix.GetElement(r, c) for c in range(3)] for r in range(3)])
    ijk_to_ras = np.eye(4)
    ijk_to_ras[:3, :3] = rotation * np.asarray(image.GetSpacing())[np.newaxis, :]
    # VTK places index (i, j, k) of the extent at origin + direction * spacing * (i, j, k): the first voxel is at the
    # extent's start, not at the origin, when the extent does not start at 0.
    ijk_to_ras[:3, 3] = np.asarray(image.GetOrigin()) + ijk_to_ras[:3, :3] @ np.asarray(image.GetExtent()[::2], float)
    if first_array:
        names = [str(field.Get(vtkDataObject.FIELD_NAME())) for field in fields]
        listed = f" (of {len(names)}: {', '.join(names)})" if len(names) > 1 else ""
        warn(f"'{path}' names no active point scalars: its first point-data array, '{names[0]}'{listed}, was read")
    return Volume.from_ijk_to_ras(vtk_to_numpy(array).reshape(k, j, i), ijk_to_ras, name)


def _read_npy(path: Path, name: str, n_bins: Optional[int]) -> Volume:
    try:
        with open(path, "rb") as handle:
            version = np.lib.format.read_magic(handle)
            shape, fortran, dtype = (
                np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            )(handle)
            offset = handle.tell()
    except (ValueError, OSError, EOFError) as error:
        raise cannot_read(path, f"not a valid .npy file ({' '.join(str(error).split())})") from None
    if dtype.hasobject or dtype.kind not in "biuf":
        raise cannot_read(path, f"the array has dtype {dtype}; a numeric array is needed (pickles are not loaded)")
    if len(shape) == 4 and shape[-1] in (2, 3, 4):
        _check_size(path, shape[2::-1], int(shape[-1]), dtype, n_bins)
    if len(shape) != 3:
        raise cannot_read(path, f"the array has shape {shape}; a 3-D (k, j, i) array is needed")
    expected = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    available = path.stat().st_size - offset
    if available < expected:
        raise cannot_read(path, f"it is truncated: {expected} bytes of voxel data expected, {available} found")
    _check_size(path, shape[::-1], 1, dtype, n_bins)
    values = np.fromfile(path, dtype=dtype, count=int(np.prod(shape)), offset=offset)
    values = values.reshape(shape, order="F" if fortran else "C")
    if dtype.kind == "b":
        values = values.astype(np.uint8)
    return Volume(np.ascontiguousarray(values), name=name)


#: Compressed bytes inflated per zlib call when reading much of an ``.inv3`` at once (the voxels): one pass over the
#: archive in a few long zlib calls, which release the GIL (the run's background imports proceed meanwhile), where
#: calls of a few KiB would hand it back and forth thousands of times.
_INV3_READ_BYTES = 1 << 22
#: Compressed bytes inflated per call for a small read (a member's 512-byte header), and the fewest inflated bytes
#: kept ahead of the reads: headers are served from a small buffer, never sliced out of megabytes.
_INV3_SMALL_READ_BYTES = 1 << 14
_INV3_AHEAD_BYTES = 1 << 16
#: Inflated bytes discarded at a time when skipping a member (a mask, a surface): zeros inflate 1000-fold.
_INV3_SKIP_BYTES = 1 << 24
#: Largest ``main.plist`` read: a project's description (names, window, masks) takes a few KB. A member of zeros
#: inflates 1000-fold (3 MB on disk read as 3 GB), so a larger one is refused from its size before it is read.
MAX_INV3_PLIST_BYTES = 16 << 20

#: The archive errors that mean a corrupt or truncated ``.inv3``.
_ARCHIVE_ERRORS = (tarfile.TarError, OSError, EOFError, zlib.error)


class _ForwardGzip:
    """A gzip file read forward, as tarfile's ``r:`` mode reads an archive: exact reads and forward seeks, each
    inflating about what it returns.

    tarfile's stream mode (``r|gz``) inflates a whole buffer at a time and copies what is left of it after every
    512-byte header read: quadratic in the number of members (20,000 empty members took 2 s, 40,000 took 29 s).
    """

    def __init__(self, path: Path) -> None:
        self._file = open(path, "rb")
        self._inflater = zlib.decompressobj(wbits=31)  # a gzip stream
        self._input = b""  # compressed bytes not inflated yet
        self._ahead = b""  # inflated bytes, read up to self._start
        self._start = 0
        self._position = 0

    def __enter__(self) -> "_ForwardGzip":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._file.close()

    def tell(self) -> int:
        return self._position

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        """Skip forward to ``offset`` (at most to the end of the stream); backwards is refused."""
        if whence != os.SEEK_SET or offset < self._position:
            raise OSError("an .inv3 archive is read forward only")
        while self._position < offset and self.read(min(offset - self._position, _INV3_SKIP_BYTES)):
            pass
        return self._position

    def read(self, size: int) -> bytes:
        """The next ``size`` bytes, fewer at the end of the stream."""
        parts = []
        wanted = size
        while wanted > 0:
            if self._start < len(self._ahead):
                part = self._ahead[self._start : self._start + wanted]
                self._start += len(part)
            else:
                part = self._inflate(wanted)
                if not part:
                    break
                if len(part) > wanted:
                    self._ahead, self._start = part, wanted
                    part = part[:wanted]
            parts.append(part)
            wanted -= len(part)
        data = b"".join(parts)
        self._position += len(data)
        return data

    def _inflate(self, wanted: int) -> bytes:
        """The next inflated bytes: at most ``wanted`` or :data:`_INV3_AHEAD_BYTES`, whichever is larger, from
        compressed reads sized to ``wanted``; empty at the end of the stream or of the file."""
        while True:
            if not self._input:
                if self._inflater.eof:
                    return b""
                large = wanted > _INV3_AHEAD_BYTES
                self._input = self._file.read(_INV3_READ_BYTES if large else _INV3_SMALL_READ_BYTES)
                if not self._input:
                    return b""
            inflated = self._inflater.decompress(self._input, max(wanted, _INV3_AHEAD_BYTES))
            self._input = self._inflater.unconsumed_tail
            if inflated or self._inflater.eof:
                return inflated


@dataclass(frozen=True)
class _Inv3Matrix:
    """What ``main.plist`` says of the voxels: the archive member holding them, their shape, type and geometry."""

    member: str
    shape: tuple[int, ...]
    dtype: np.dtype
    spacing: tuple[float, ...]
    directions: np.ndarray


def _read_inv3(path: Path, name: str, n_bins: Optional[int]) -> Volume:
    """Read an InVesalius project in one streaming pass: ``main.plist`` comes first, then ``matrix.dat``.

    A project whose voxels come before ``main.plist`` in the archive is read in a second pass.
    """
    matrix: Optional[_Inv3Matrix] = None
    for _ in range(2):
        with _ForwardGzip(path) as stream:
            try:
                archive = tarfile.open(fileobj=stream, mode="r:")
            except _ARCHIVE_ERRORS as error:
                raise cannot_read(path, f"not an InVesalius project (gzip tar expected: {error})") from None
            try:
                with archive:
                    for member in archive:
                        if matrix is None and member.isfile() and member.name.rsplit("/", 1)[-1] == "main.plist":
                            if member.size > MAX_INV3_PLIST_BYTES:
                                raise cannot_read(
                                    path,
                                    f"its main.plist holds {format_bytes(member.size)}, more than the "
                                    f"{format_bytes(MAX_INV3_PLIST_BYTES)} a project description can take: the "
                                    "project is corrupt",
                                )
                            matrix = _inv3_matrix(path, member.name, _member_bytes(archive, member))
                        elif matrix is not None and member.isfile() and member.name == matrix.member:
                            values = _inv3_voxels(path, archive, member, matrix, n_bins)
                            return Volume(values, matrix.spacing, (0.0, 0.0, 0.0), matrix.directions, name)
            except _ARCHIVE_ERRORS as error:
                raise cannot_read(path, f"the archive is corrupt or truncated ({error})") from None
        if matrix is None:
            raise cannot_read(path, "no main.plist in the InVesalius project")
    raise cannot_read(path, f"the project has no {matrix.member.rsplit('/', 1)[-1]}")


def _inv3_matrix(path: Path, plist_name: str, text: bytes) -> _Inv3Matrix:
    """The voxels' description in ``main.plist`` (``plist_name`` locates the data file beside it)."""
    try:
        main = plistlib.loads(text)
    except (plistlib.InvalidFileException, ValueError, ExpatError):
        raise cannot_read(path, "its main.plist is not a property list") from None
    try:
        matrix = main["matrix"]
        shape = tuple(int(n) for n in matrix["shape"])
        dtype = np.dtype(str(matrix.get("dtype", "int16"))).newbyteorder("<")
        spacing = tuple(float(s) for s in main["spacing"])
        data_name = str(matrix.get("filename", "matrix.dat"))
    except (KeyError, TypeError, ValueError):
        raise cannot_read(path, "its main.plist lacks a valid matrix shape, dtype or spacing") from None
    if len(shape) != 3 or len(spacing) != 3:
        raise cannot_read(path, f"the project matrix has shape {shape}; a 3-D (z, y, x) matrix is needed")
    if dtype.kind not in "iuf":  # e.g. "object": raw bytes read into Python object references
        raise cannot_read(
            path, f"its main.plist gives the voxel type '{dtype}'; a number type (int16, uint8, float32, ...) is needed"
        )
    folder = plist_name.rsplit("/", 1)[0] + "/" if "/" in plist_name else ""
    directions = _INV3_AXIAL_DIRECTIONS if main.get("orientation", 1) in (1, "AXIAL") else np.eye(3)
    return _Inv3Matrix(folder + data_name, shape, dtype, spacing, directions)


def _inv3_voxels(
    path: Path, archive: tarfile.TarFile, member: tarfile.TarInfo, matrix: _Inv3Matrix, n_bins: Optional[int]
) -> np.ndarray:
    """The voxels of the current member, read straight into their array once their size is accepted."""
    expected = int(np.prod(matrix.shape, dtype=np.float64)) * matrix.dtype.itemsize
    if member.size != expected:
        raise cannot_read(
            path,
            f"{member.name.rsplit('/', 1)[-1]} holds {member.size} bytes; shape {matrix.shape} of "
            f"{matrix.dtype.name} needs {expected}",
        )
    _check_size(path, matrix.shape[::-1], 1, matrix.dtype, n_bins)
    values = np.empty(matrix.shape, dtype=matrix.dtype)
    handle = archive.extractfile(member)
    if handle is None or handle.readinto(memoryview(values.reshape(-1).view(np.uint8))) != member.size:
        raise EOFError(f"{member.name} is truncated")
    return values if values.dtype.isnative else values.astype(values.dtype.newbyteorder("="))


def _member_bytes(archive: tarfile.TarFile, member: tarfile.TarInfo) -> bytes:
    """The bytes of the archive's current member (a small one: main.plist)."""
    handle = archive.extractfile(member)
    data = handle.read() if handle is not None else b""
    if len(data) != member.size:
        raise EOFError(f"{member.name} is truncated")
    return data


#: Every input format, probed in this order (a DICOM file may have any suffix, so it comes before the suffixes).
READERS: tuple[Reader, ...] = (
    Reader(
        "Zarr or TIFF",
        chunked_readers.is_chunked_format,
        lambda path, name, n_bins, warn: chunked_readers.read_chunked(path, warn=warn),
    ),
    Reader(
        "DICOM",
        lambda path: path.is_dir() or slicer_readers.is_dicom_file(path),
        lambda path, name, n_bins, warn: _read_with_slicer(path, slicer_readers.dicom_series(path, warn), name, n_bins),
    ),
    Reader(".npy", _suffix(".npy"), lambda path, name, n_bins, warn: _read_npy(path, name, n_bins)),
    Reader("InVesalius", _suffix(".inv3"), lambda path, name, n_bins, warn: _read_inv3(path, name, n_bins)),
    Reader("VTK image", _suffix(".vti"), _read_vti),
    Reader(
        "NRRD, MetaImage or NIfTI",
        _suffix(*slicer_readers.ITK_SUFFIXES),
        lambda path, name, n_bins, warn: _read_nrrd_metaimage_nifti(path, name, n_bins, warn),
    ),
)
