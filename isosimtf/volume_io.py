"""Read and write scalar volumes with their geometry, using only numpy, VTK's readers and the standard library.

Every reader returns a :class:`Volume`: the voxel values as a ``(K, J, I)`` array (slowest axis first, i.e. z, y, x)
in the file's own dtype, plus spacing, origin and axis directions in Slicer's RAS world coordinates. Formats whose
world space is LPS (NRRD's usual ``left-posterior-superior``, DICOM, MetaImage) are converted to RAS by negating
the first two world coordinates.

Supported inputs (``read_volume``):

- ``.nrrd`` / ``.nhdr``: ``vtkNrrdReader`` for the voxels (raw, ascii, gzip encodings); the header is parsed here
  for ``space``, ``space directions`` and ``space origin``, which the VTK reader ignores.
- ``.mha`` / ``.mhd``: ``vtkMetaImageReader`` for the voxels; ``TransformMatrix`` and ``Offset`` are parsed here.
- ``.nii`` / ``.nii.gz``: ``vtkNIFTIImageReader``; geometry from the sform (if its code is set) else the qform,
  else the voxel size alone. ``scl_slope``/``scl_inter`` are applied when they are not the identity (the values
  then become float64).
- ``.vti``: ``vtkXMLImageDataReader``; VTK image coordinates are taken as RAS.
- ``.npy``: ``numpy.load`` without pickles; spacing 1 mm, origin 0, identity directions.
- a directory: a DICOM series, ``vtkDICOMImageReader`` (slices sorted along the slice normal, rescale applied).
- ``.inv3``: an InVesalius project (gzip tar holding ``main.plist`` and the raw int16 ``matrix.dat``).

Any failure raises :class:`VolumeReadError` with a one-line message naming the file; VTK's own error printing is
captured during reads and never reaches stderr.
"""

from __future__ import annotations

import contextlib
import gzip
import os
import plistlib
import re
import tarfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Union

import numpy as np

from IsoSimilarityTFLib.errors import VolumeReadError

PathLike = Union[str, "os.PathLike[str]"]

__all__ = [
    "Volume",
    "VolumeReadError",
    "read_volume",
    "real_dataset_path",
    "write_volume",
]

#: Diagonal that converts LPS coordinates to RAS and back (its own inverse).
_LPS_TO_RAS = np.array([-1.0, -1.0, 1.0])

#: File suffixes (lower case, longest first) and the format they select.
_SUFFIXES: tuple[tuple[str, str], ...] = (
    (".nii.gz", "nifti"),
    (".nrrd", "nrrd"),
    (".nhdr", "nrrd"),
    (".mha", "meta"),
    (".mhd", "meta"),
    (".nii", "nifti"),
    (".vti", "vti"),
    (".npy", "npy"),
    (".inv3", "inv3"),
)

_SUPPORTED_TEXT = ".nrrd, .nhdr, .mha, .mhd, .nii, .nii.gz, .vti, .npy, .inv3 or a DICOM series folder"

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
}


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
        values = np.asarray(self.values)
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


# ---------------------------------------------------------------------------------------------------------------
# Public entry points
# ---------------------------------------------------------------------------------------------------------------


def read_volume(path: PathLike) -> Volume:
    """Read a scalar 3-D volume from ``path`` (see the module docstring for formats).

    Raises:
        VolumeReadError: the path is missing, of an unsupported kind, corrupt or truncated, or holds a 2-D or a
            multi-component (vector/RGB) image.
    """
    path = Path(path)
    if not path.exists():
        raise VolumeReadError(f"Cannot read '{path}': no such file or directory")
    if path.is_dir():
        reader: Callable[[Path], Volume] = _read_dicom_series
    else:
        kind = _format_of(path)
        if kind is None:
            raise VolumeReadError(
                f"Cannot read '{path}': unsupported file type '{''.join(path.suffixes) or path.name}'"
                f" (expected {_SUPPORTED_TEXT})"
            )
        reader = _READERS[kind]
    try:
        volume = reader(path)
    except VolumeReadError:
        raise
    except (OSError, EOFError, ValueError, KeyError, IndexError, TypeError, zlib.error, tarfile.TarError) as exc:
        raise VolumeReadError(f"Cannot read '{path}': {_one_line(str(exc)) or type(exc).__name__}") from None
    return volume


def write_volume(volume: Volume, path: PathLike) -> None:
    """Write ``volume`` to ``path``; the format follows the suffix.

    Supported: ``.nrrd`` (gzip), ``.nhdr`` (+ ``.raw`` beside it), ``.mha``, ``.mhd`` (+ ``.raw``), ``.nii``,
    ``.nii.gz``, ``.vti``, ``.npy`` (values only: spacing, origin and directions are lost). Geometry is written in
    the format's own world convention (LPS for NRRD and MetaImage, RAS for NIfTI and VTI).

    Raises:
        ValueError: unsupported suffix or dtype.
        OSError: the file cannot be written.
    """
    path = Path(path)
    kind = _format_of(path)
    writers: dict[str, Callable[[Volume, Path], None]] = {
        "nrrd": _write_nrrd,
        "meta": _write_meta,
        "nifti": _write_nifti,
        "vti": _write_vti,
        "npy": _write_npy,
    }
    if kind not in writers:
        raise ValueError(
            f"Cannot write '{path}': unsupported suffix (expected .nrrd, .nhdr, .mha, .mhd, .nii, "
            ".nii.gz, .vti or .npy)"
        )
    if volume.values.dtype.kind not in "iuf":
        raise ValueError(f"Cannot write '{path}': values of dtype {volume.values.dtype} are not numeric")
    writers[kind](volume, path)


def real_dataset_path(name: str) -> Path | None:
    """Return the installed path of a real test volume, or None when its Debian package is not installed.

    Args:
        name: ``"head-ct"`` (InVesalius ``Cranium.inv3``, package ``invesalius-examples``) or ``"brain-mri"``
            (Colin27 ``ch2.nii.gz``, package ``mricron-data``).

    Raises:
        KeyError: unknown name.
    """
    if name not in _REAL_DATASETS:
        raise KeyError(f"Unknown dataset '{name}'; known: {', '.join(sorted(_REAL_DATASETS))}")
    for candidate in _REAL_DATASETS[name]:
        if Path(candidate).is_file():
            return Path(candidate)
    return None


# ---------------------------------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------------------------------


def _format_of(path: Path) -> str | None:
    lower = path.name.lower()
    for suffix, kind in _SUFFIXES:
        if lower.endswith(suffix) and len(lower) > len(suffix):
            return kind
    return None


def _stem(path: Path) -> str:
    lower = path.name.lower()
    for suffix, _ in _SUFFIXES:
        if lower.endswith(suffix):
            return path.name[: -len(suffix)]
    return path.name


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _fail(path: Path, reason: str) -> VolumeReadError:
    return VolumeReadError(f"Cannot read '{path}': {_one_line(reason)}")


_VTK_PREFIX = re.compile(r"^\s*(ERROR|WARNING|Warning|Error|Generic Warning)?:?\s*In\s+\S+,\s*line\s+\d+\s*", re.I)
_VTK_OBJECT = re.compile(r"^\s*vtk\w*\s*\(0x[0-9a-fA-F]+\):\s*")


def _clean_vtk_message(text: str) -> str:
    """Turn VTK's multi-line 'ERROR: In file.cxx, line N / vtkX (0x..): msg' text into its first message line."""
    messages = []
    for line in text.splitlines():
        line = _VTK_PREFIX.sub("", line)
        line = _VTK_OBJECT.sub("", line).strip()
        if line and not line.startswith("ERROR:") and not line.lower().startswith("generic warning"):
            messages.append(line)
    return messages[0] if messages else _one_line(text)


@contextlib.contextmanager
def _captured_vtk_errors() -> Iterator[list[str]]:
    """Route VTK's error/warning text into a list instead of stderr, for the duration of the block."""
    from vtkmodules.vtkCommonCore import vtkLogger, vtkOutputWindow, vtkStringOutputWindow

    previous = vtkOutputWindow.GetInstance()
    window = vtkStringOutputWindow()
    vtkOutputWindow.SetInstance(window)
    # VTK built with its logger also logs warnings and errors to stderr on its own; mute that sink meanwhile.
    logger_cutoff = vtkLogger.GetCurrentVerbosityCutoff()
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    errors: list[str] = []
    try:
        yield errors
    finally:
        vtkLogger.SetStderrVerbosity(vtkLogger.ConvertToVerbosity(logger_cutoff))
        text = window.GetOutput()
        if text and text.strip():
            errors.append(text)
        vtkOutputWindow.SetInstance(previous)


def _run_vtk_reader(reader: Any, path: Path, *, warnings_fatal: bool = False) -> Any:
    """Update a VTK image reader with errors captured; return its ``vtkImageData`` output or raise."""
    observed: list[str] = []

    def on_error(_obj: Any, _event: str, *args: Any) -> None:
        observed.append(str(args[0]) if args else "VTK error")

    on_error.CallDataType = "string0"  # type: ignore[attr-defined]  # ask VTK to pass the message text
    reader.AddObserver("ErrorEvent", on_error)
    if warnings_fatal:
        reader.AddObserver("WarningEvent", on_error)
    with _captured_vtk_errors() as printed:
        reader.Update()
    messages = observed + [m for m in printed if "ERROR" in m.upper() or warnings_fatal]
    if messages:
        detail = _clean_vtk_message(messages[0]).replace(str(path), "the file")
        raise _fail(path, f"{_corrupt_text} ({reader.GetClassName()}: {detail})")
    if reader.GetErrorCode() if hasattr(reader, "GetErrorCode") else 0:
        from vtkmodules.vtkCommonCore import vtkErrorCode

        detail = vtkErrorCode.GetStringFromErrorCode(reader.GetErrorCode())
        raise _fail(path, f"{_corrupt_text} ({reader.GetClassName()}: {detail})")
    return reader.GetOutput()


_corrupt_text = "the file is corrupt or truncated"


def _image_to_array(image: Any, path: Path, shape: tuple[int, int, int] | None = None) -> np.ndarray:
    """Copy a single-component ``vtkImageData``'s scalars into a ``(K, J, I)`` array; reject 2-D/vector images.

    With ``shape`` given, the scalars (all components) are reshaped to it instead of to the image's dimensions.
    """
    from vtkmodules.util.numpy_support import vtk_to_numpy

    if image is None:
        raise _fail(path, "the reader produced no image")
    dims = tuple(int(d) for d in image.GetDimensions())
    scalars = image.GetPointData().GetScalars() if image.GetPointData() is not None else None
    if scalars is None:
        array_names = [image.GetPointData().GetArrayName(n) for n in range(image.GetPointData().GetNumberOfArrays())]
        if array_names:
            scalars = image.GetPointData().GetArray(0)
    if scalars is None or scalars.GetNumberOfTuples() == 0 or min(dims) < 1:
        raise _fail(path, "no voxel data could be read (empty, corrupt or not an image of this format)")
    if shape is not None:
        flat = vtk_to_numpy(scalars).reshape(-1)
        if flat.size != int(np.prod(shape)):
            raise _fail(path, f"read {flat.size} voxel values but the header announces {int(np.prod(shape))}")
        return np.array(flat.reshape(shape), copy=True)
    _check_scalar_3d(path, dims, int(scalars.GetNumberOfComponents()))
    if scalars.GetNumberOfTuples() != dims[0] * dims[1] * dims[2]:
        raise _fail(path, f"expected {dims[0] * dims[1] * dims[2]} voxels, found {scalars.GetNumberOfTuples()}")
    values = vtk_to_numpy(scalars)
    return np.array(values.reshape(dims[2], dims[1], dims[0]), copy=True)


def _check_scalar_3d(path: Path, dims_ijk: tuple[int, ...], components: int) -> None:
    if components != 1:
        raise _fail(
            path,
            f"it has {components} components per voxel (a vector or RGB image); only scalar volumes are supported",
        )
    if len(dims_ijk) < 3 or sum(int(d) > 1 for d in dims_ijk[:3]) < 3:
        size = " x ".join(str(int(d)) for d in dims_ijk)
        raise _fail(path, f"it is a 2-D image ({size} voxels); a 3-D volume is needed")


def _as_ras_geometry(
    axes_world: np.ndarray, origin_world: np.ndarray, lps: bool
) -> tuple[tuple[float, float, float], tuple[float, float, float], np.ndarray]:
    """Split world axis vectors (columns, mm per voxel step) into spacing, origin and unit directions in RAS."""
    axes = np.asarray(axes_world, dtype=float).reshape(3, 3)
    origin = np.asarray(origin_world, dtype=float).reshape(3)
    if lps:
        axes = axes * _LPS_TO_RAS[:, np.newaxis]
        origin = origin * _LPS_TO_RAS
    norms = np.linalg.norm(axes, axis=0)
    if not np.all(np.isfinite(norms)) or np.any(norms <= 0) or not np.all(np.isfinite(origin)):
        raise ValueError("the voxel spacing or orientation in the header is zero or not a number")
    directions = axes / norms[np.newaxis, :]
    return (
        (float(norms[0]), float(norms[1]), float(norms[2])),
        (float(origin[0]), float(origin[1]), float(origin[2])),
        directions,
    )


def _fmt(value: float) -> str:
    return repr(float(value))


# ---------------------------------------------------------------------------------------------------------------
# NRRD
# ---------------------------------------------------------------------------------------------------------------

_NRRD_TYPES = {
    "int8": "signed char",
    "uint8": "uchar",
    "int16": "short",
    "uint16": "ushort",
    "int32": "int",
    "uint32": "uint",
    "int64": "longlong",
    "uint64": "ulonglong",
    "float32": "float",
    "float64": "double",
}

_NRRD_RAS_SPACES = {"right-anterior-superior", "ras"}
_NRRD_LAS_SPACES = {"left-anterior-superior", "las", "3d-left-handed"}


def _parse_nrrd_header(path: Path) -> tuple[dict[str, str], int]:
    """Return the NRRD header fields (lower-case keys) and the header's length in bytes."""
    with open(path, "rb") as handle:
        head = handle.read(1 << 20)
    if not head.startswith(b"NRRD"):
        raise _fail(path, "not a NRRD file (the header does not start with 'NRRD')")
    fields: dict[str, str] = {}
    offset = 0
    lines = head.split(b"\n")
    for index, raw in enumerate(lines):
        offset += len(raw) + 1
        line = raw.decode("latin-1").rstrip("\r")
        if index == 0 or line.startswith("#"):
            continue
        if not line.strip():
            break
        if ": " in line:
            key, value = line.split(": ", 1)
            fields[key.strip().lower()] = value.strip()
        elif ":=" in line:
            continue  # key/value pairs: not needed here
    return fields, offset


def _nrrd_vector(text: str) -> list[float]:
    return [float(v) for v in text.strip().strip("()").split(",")]


def _read_nrrd(path: Path) -> Volume:
    from vtkmodules.vtkIOImage import vtkNrrdReader

    fields, header_bytes = _parse_nrrd_header(path)
    try:
        dimension = int(fields.get("dimension", "0"))
        sizes = [int(s) for s in fields.get("sizes", "").split()]
    except ValueError:
        raise _fail(path, "the 'dimension' or 'sizes' field of the NRRD header is not a list of integers") from None
    if dimension != len(sizes) or dimension == 0:
        raise _fail(path, "the NRRD header has no valid 'dimension'/'sizes' fields")
    kinds = fields.get("kinds", "").split()
    if dimension == 4 or (kinds and kinds[0].lower() not in ("domain", "space", "time")):
        raise _fail(
            path, f"it has {sizes[0]} components per voxel (a vector or RGB image); only scalar volumes are supported"
        )
    if "none" in fields.get("space directions", "").split():
        raise _fail(
            path, f"it has {sizes[0]} components per voxel (a vector or RGB image); only scalar volumes are supported"
        )
    if dimension != 3:
        raise _fail(path, f"it is a {dimension}-D image ({' x '.join(map(str, sizes))} voxels); a 3-D volume is needed")
    _check_scalar_3d(path, sizes, 1)
    encoding = fields.get("encoding", "raw").lower()
    type_name = fields.get("type", "")
    data_file = fields.get("data file", fields.get("datafile"))
    if encoding == "raw" and (data_file is None or len(data_file.split()) == 1):
        itemsize = _nrrd_itemsize(type_name)
        expected = int(np.prod(sizes)) * itemsize
        if data_file is None:
            available = path.stat().st_size - header_bytes
        else:
            data_path = path.parent / data_file
            if not data_path.is_file():
                raise _fail(path, f"its data file '{data_file}' is missing")
            available = data_path.stat().st_size
        if itemsize and available < expected:
            raise _fail(
                path, f"the file is truncated: {expected} bytes of voxel data expected, {max(available, 0)} found"
            )

    reader = vtkNrrdReader()
    reader.SetFileName(str(path))
    try:
        image = _run_vtk_reader(reader, path)
    except VolumeReadError:
        if encoding in ("gzip", "gz"):
            raise _fail(path, "the gzip-compressed voxel data is truncated or corrupt") from None
        raise
    # vtkNrrdReader guesses that a fastest axis of 9 samples or fewer holds vector components; the header says it is
    # a spatial axis, and the memory layout is the same, so take the scalars as they are and use the header's sizes.
    values = _image_to_array(image, path, shape=(sizes[2], sizes[1], sizes[0]))

    space = fields.get("space", "").lower()
    if space in _NRRD_LAS_SPACES:
        values = np.ascontiguousarray(values[:, ::-1, :])  # vtkNrrdReader flips rows for left-handed spaces
    if "space directions" in fields:
        vectors = [v for v in re.findall(r"\([^)]*\)|none", fields["space directions"])]
        axes = np.array([_nrrd_vector(v) for v in vectors if v != "none"], dtype=float).T
        if axes.shape != (3, 3):
            raise _fail(path, "the NRRD 'space directions' field does not hold three 3-D vectors")
    else:
        spacings = [float(s) for s in fields.get("spacings", "1 1 1").split()]
        spacings = [s if np.isfinite(s) and s > 0 else 1.0 for s in spacings] + [1.0] * (3 - len(spacings))
        axes = np.diag(spacings[:3])
    origin = np.array(_nrrd_vector(fields["space origin"]) if "space origin" in fields else [0.0, 0.0, 0.0])
    if space in _NRRD_RAS_SPACES:
        spacing, origin_ras, directions = _as_ras_geometry(axes, origin, lps=False)
    elif space in _NRRD_LAS_SPACES:
        flip = np.array([-1.0, 1.0, 1.0])
        spacing, origin_ras, directions = _as_ras_geometry(axes * flip[:, None], origin * flip, lps=False)
    else:  # LPS, and like ITK/Slicer, any non-anatomical space too
        spacing, origin_ras, directions = _as_ras_geometry(axes, origin, lps=True)
    return Volume(values, spacing, origin_ras, directions, _stem(path))


def _nrrd_itemsize(type_name: str) -> int:
    t = type_name.strip().lower()
    table = {
        1: ("signed char", "int8", "int8_t", "uchar", "unsigned char", "uint8", "uint8_t"),
        2: (
            "short",
            "short int",
            "signed short",
            "signed short int",
            "int16",
            "int16_t",
            "ushort",
            "unsigned short",
            "unsigned short int",
            "uint16",
            "uint16_t",
        ),
        4: ("int", "signed int", "int32", "int32_t", "uint", "unsigned int", "uint32", "uint32_t", "float"),
        8: (
            "longlong",
            "long long",
            "long long int",
            "signed long long",
            "signed long long int",
            "int64",
            "int64_t",
            "ulonglong",
            "unsigned long long",
            "unsigned long long int",
            "uint64",
            "uint64_t",
            "double",
        ),
    }
    for size, names in table.items():
        if t in names:
            return size
    return 0


def _typed_values(volume: Volume, path: Path, types: dict, format_name: str) -> tuple[np.ndarray, str]:
    """The voxels in little-endian order and the format's name of their type (ValueError when it has none)."""
    values = _little_endian(volume.values)
    type_name = types.get(values.dtype.name)
    if type_name is None:
        raise ValueError(f"Cannot write '{path}': dtype {values.dtype} has no {format_name} type")
    return values, type_name


def _write_header_and_data(
    path: Path, header: bytes, values: np.ndarray, data_name: str, *, detached: bool, compress: bool = False
) -> None:
    """Write a header followed by the raw voxels, or the header alone with the voxels in ``data_name`` beside it."""
    raw = np.ascontiguousarray(values).tobytes()
    if detached:
        path.write_bytes(header)
        (path.parent / data_name).write_bytes(raw)
    else:
        path.write_bytes(header + (gzip.compress(raw, compresslevel=1) if compress else raw))


def _write_nrrd(volume: Volume, path: Path) -> None:
    values, type_name = _typed_values(volume, path, _NRRD_TYPES, "NRRD")
    axes_lps = (volume.directions * np.asarray(volume.spacing)[None, :]) * _LPS_TO_RAS[:, None]
    origin_lps = np.asarray(volume.origin) * _LPS_TO_RAS
    k, j, i = values.shape
    detached = path.name.lower().endswith(".nhdr")
    data_name = _stem(path) + ".raw"
    lines = [
        "NRRD0004",
        "# Complete NRRD file format specification at:",
        "# http://teem.sourceforge.net/nrrd/format.html",
        f"type: {type_name}",
        "dimension: 3",
        "space: left-posterior-superior",
        f"sizes: {i} {j} {k}",
        "space directions: " + " ".join("(" + ",".join(_fmt(c) for c in axes_lps[:, a]) + ")" for a in range(3)),
        "kinds: domain domain domain",
        "endian: little",
        f"encoding: {'raw' if detached else 'gzip'}",
        "space origin: (" + ",".join(_fmt(c) for c in origin_lps) + ")",
    ]
    if detached:
        lines.append(f"data file: {data_name}")
    header = ("\n".join(lines) + "\n\n").encode("ascii")
    _write_header_and_data(path, header, values, data_name, detached=detached, compress=True)


def _little_endian(values: np.ndarray) -> np.ndarray:
    if values.dtype.byteorder == ">" or (values.dtype.byteorder == "=" and not np.little_endian):
        return values.astype(values.dtype.newbyteorder("<"))
    return values


# ---------------------------------------------------------------------------------------------------------------
# MetaImage
# ---------------------------------------------------------------------------------------------------------------

_META_TYPES = {
    "int8": "MET_CHAR",
    "uint8": "MET_UCHAR",
    "int16": "MET_SHORT",
    "uint16": "MET_USHORT",
    "int32": "MET_INT",
    "uint32": "MET_UINT",
    "int64": "MET_LONG_LONG",
    "uint64": "MET_ULONG_LONG",
    "float32": "MET_FLOAT",
    "float64": "MET_DOUBLE",
}


def _parse_meta_header(path: Path) -> tuple[dict[str, str], int]:
    """Return MetaImage header fields (lower-case keys) and the header's length in bytes (for LOCAL data)."""
    with open(path, "rb") as handle:
        head = handle.read(1 << 16)
    fields: dict[str, str] = {}
    offset = 0
    for raw in head.split(b"\n"):
        offset += len(raw) + 1
        line = raw.decode("latin-1").strip()
        if "=" not in line:
            if line:
                break
            continue
        key, value = line.split("=", 1)
        fields[key.strip().lower()] = value.strip()
        if key.strip().lower() == "elementdatafile":
            break
    if "ndims" not in fields or "dimsize" not in fields or "elementtype" not in fields:
        raise _fail(path, "not a MetaImage file (NDims, DimSize or ElementType missing from the header)")
    return fields, offset


def _read_meta(path: Path) -> Volume:
    from vtkmodules.vtkIOImage import vtkMetaImageReader

    fields, header_bytes = _parse_meta_header(path)
    try:
        ndims = int(fields["ndims"])
        sizes = [int(s) for s in fields["dimsize"].split()]
        channels = int(fields.get("elementnumberofchannels", "1"))
    except ValueError:
        raise _fail(path, "the NDims, DimSize or ElementNumberOfChannels field is not an integer") from None
    _check_scalar_3d(path, sizes if ndims == 3 else sizes[:ndims], channels)
    if ndims != 3:
        raise _fail(path, f"it is a {ndims}-D image; a 3-D volume is needed")
    data_file = fields.get("elementdatafile", "")
    compressed = fields.get("compresseddata", "false").lower() == "true"
    item = {
        "MET_CHAR": 1,
        "MET_UCHAR": 1,
        "MET_SHORT": 2,
        "MET_USHORT": 2,
        "MET_INT": 4,
        "MET_UINT": 4,
        "MET_FLOAT": 4,
        "MET_LONG_LONG": 8,
        "MET_ULONG_LONG": 8,
        "MET_DOUBLE": 8,
    }.get(fields["elementtype"], 0)
    expected = int(np.prod(sizes)) * item
    if not compressed and item:
        if data_file.upper() == "LOCAL":
            available = path.stat().st_size - header_bytes
        else:
            data_path = path.parent / data_file
            if not data_path.is_file():
                raise _fail(path, f"its data file '{data_file}' is missing")
            available = data_path.stat().st_size
        if available < expected:
            raise _fail(
                path, f"the file is truncated: {expected} bytes of voxel data expected, {max(available, 0)} found"
            )

    reader = vtkMetaImageReader()
    reader.SetFileName(str(path))
    image = _run_vtk_reader(reader, path)
    values = _image_to_array(image, path)

    spacing_text = fields.get("elementspacing") or fields.get("elementsize") or "1 1 1"
    spacing = np.array([float(s) for s in spacing_text.split()][:3])
    matrix_text = fields.get("transformmatrix") or fields.get("rotation") or fields.get("orientation")
    # TransformMatrix lists the axis directions one after the other (i axis first), as ITK reads it.
    rotation = np.array([float(v) for v in matrix_text.split()]).reshape(3, 3).T if matrix_text else np.eye(3)
    offset_text = fields.get("offset") or fields.get("position") or fields.get("origin") or "0 0 0"
    origin = np.array([float(v) for v in offset_text.split()][:3])
    spacing_mm, origin_ras, directions = _as_ras_geometry(rotation * spacing[None, :], origin, lps=True)
    return Volume(values, spacing_mm, origin_ras, directions, _stem(path))


def _write_meta(volume: Volume, path: Path) -> None:
    values, element_type = _typed_values(volume, path, _META_TYPES, "MetaImage")
    directions_lps = volume.directions * _LPS_TO_RAS[:, None]
    origin_lps = np.asarray(volume.origin) * _LPS_TO_RAS
    k, j, i = values.shape
    detached = path.name.lower().endswith(".mhd")
    data_name = _stem(path) + ".raw"
    lines = [
        "ObjectType = Image",
        "NDims = 3",
        "BinaryData = True",
        "BinaryDataByteOrderMSB = False",
        "CompressedData = False",
        "TransformMatrix = " + " ".join(_fmt(v) for v in directions_lps.T.ravel()),
        "Offset = " + " ".join(_fmt(v) for v in origin_lps),
        "CenterOfRotation = 0 0 0",
        "AnatomicalOrientation = RAI",
        "ElementSpacing = " + " ".join(_fmt(v) for v in volume.spacing),
        f"DimSize = {i} {j} {k}",
        f"ElementType = {element_type}",
        f"ElementDataFile = {data_name if detached else 'LOCAL'}",
    ]
    header = ("\n".join(lines) + "\n").encode("ascii")
    _write_header_and_data(path, header, values, data_name, detached=detached)


# ---------------------------------------------------------------------------------------------------------------
# NIfTI
# ---------------------------------------------------------------------------------------------------------------


def _matrix_to_numpy(matrix: Any) -> np.ndarray:
    return np.array([[matrix.GetElement(r, c) for c in range(4)] for r in range(4)], dtype=float)


def _numpy_to_matrix(array: np.ndarray) -> Any:
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    matrix = vtkMatrix4x4()
    for r in range(4):
        for c in range(4):
            matrix.SetElement(r, c, float(array[r, c]))
    return matrix


def _read_nifti(path: Path) -> Volume:
    from vtkmodules.vtkIOImage import vtkNIFTIImageReader

    if path.name.lower().endswith(".gz"):
        try:
            with gzip.open(path, "rb") as handle:
                head = handle.read(540)
        except (OSError, EOFError, zlib.error) as exc:
            raise _fail(path, f"the gzip stream is corrupt ({_one_line(str(exc))})") from None
    else:
        with open(path, "rb") as handle:
            head = handle.read(540)
    if len(head) < 348 or (head[344:348] not in (b"n+1\0", b"ni1\0") and head[4:8] not in (b"n+2\0", b"ni2\0")):
        raise _fail(path, "not a NIfTI-1/2 file (bad header size or magic)")
    reader = vtkNIFTIImageReader()
    reader.SetFileName(str(path))
    image = _run_vtk_reader(reader, path)
    header = reader.GetNIFTIHeader()
    dims = [int(header.GetDim(n)) for n in range(8)]
    components = int(image.GetNumberOfScalarComponents()) if image is not None else 1
    if (dims[0] >= 4 and any(d > 1 for d in dims[4 : dims[0] + 1])) or components > 1:
        n_comp = max(components, int(np.prod([d for d in dims[4 : dims[0] + 1] if d > 0] or [1])))
        raise _fail(
            path,
            f"it has {n_comp} values per voxel (a vector, RGB or time-series image); only scalar volumes are supported",
        )
    values = _image_to_array(image, path)

    slope = float(reader.GetRescaleSlope())
    intercept = float(reader.GetRescaleIntercept())
    if slope not in (0.0, 1.0) or intercept != 0.0:
        values = values.astype(np.float64) * (slope if slope != 0.0 else 1.0) + intercept

    spacing = np.array(image.GetSpacing(), dtype=float)
    if header.GetSFormCode() > 0 and reader.GetSFormMatrix() is not None:
        world = _matrix_to_numpy(reader.GetSFormMatrix())
    elif header.GetQFormCode() > 0 and reader.GetQFormMatrix() is not None:
        world = _matrix_to_numpy(reader.GetQFormMatrix())
    else:
        world = np.eye(4)
    # VTK's NIfTI matrices map VTK data coordinates (index * spacing, origin 0) to world (RAS) coordinates.
    ijk_to_world = world.copy()
    ijk_to_world[:3, :3] = world[:3, :3] * spacing[None, :]
    if reader.GetQFac() < 0:
        # With qfac = -1, vtkNIFTIImageReader reverses the slices (and adjusts its matrices); restore the file order.
        values = np.ascontiguousarray(values[::-1])
        ijk_to_world = ijk_to_world @ _reverse_k(values.shape[0])
    spacing_mm, origin_ras, directions = _as_ras_geometry(ijk_to_world[:3, :3], ijk_to_world[:3, 3], lps=False)
    return Volume(values, spacing_mm, origin_ras, directions, _stem(path))


def _write_nifti(volume: Volume, path: Path) -> None:
    from vtkmodules.vtkIOImage import vtkNIFTIImageWriter

    writer = vtkNIFTIImageWriter()
    writer.SetFileName(str(path))
    ijk_to_ras = volume.ijk_to_ras()
    if np.linalg.det(volume.directions) < 0:
        # A qform is a rotation; a left-handed grid is stored with qfac = -1. vtkNIFTIImageWriter expects the image
        # in VTK order (slices reversed, right-handed matrix) and reverses the slices itself when writing, so the
        # file keeps the volume's own slice order.
        ijk_to_ras = ijk_to_ras @ _reverse_k(volume.values.shape[0])
        volume = Volume(volume.values[::-1], volume.spacing, volume.origin, volume.directions, volume.name)
        writer.SetQFac(-1.0)
    matrix = np.eye(4)
    matrix[:3, :3] = ijk_to_ras[:3, :3] / np.asarray(volume.spacing)[None, :]
    matrix[:3, 3] = ijk_to_ras[:3, 3]
    writer.SetInputData(_to_vtk_image(volume, with_geometry=False))
    writer.SetQFormMatrix(_numpy_to_matrix(matrix))
    writer.SetSFormMatrix(_numpy_to_matrix(matrix))
    _run_vtk_writer(writer, path)


def _reverse_k(n_slices: int) -> np.ndarray:
    """4x4 index map (i, j, k) -> (i, j, n_slices - 1 - k)."""
    flip = np.eye(4)
    flip[2, 2] = -1.0
    flip[2, 3] = n_slices - 1
    return flip


def _run_vtk_writer(writer: Any, path: Path) -> None:
    with _captured_vtk_errors() as printed:
        writer.Write()
    errors = [m for m in printed if "ERROR" in m.upper()]
    if errors or (writer.GetErrorCode() if hasattr(writer, "GetErrorCode") else 0):
        reason = _clean_vtk_message(errors[0]) if errors else "VTK writer failed"
        raise OSError(f"Cannot write '{path}': {reason}")


# ---------------------------------------------------------------------------------------------------------------
# VTK XML image data
# ---------------------------------------------------------------------------------------------------------------


def _to_vtk_image(volume: Volume, *, with_geometry: bool) -> Any:
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonDataModel import vtkImageData

    values = np.ascontiguousarray(volume.values)
    k, j, i = values.shape
    image = vtkImageData()
    image.SetDimensions(i, j, k)
    if with_geometry:
        image.SetSpacing(*volume.spacing)
        image.SetOrigin(*volume.origin)
        image.SetDirectionMatrix(*[float(v) for v in volume.directions.ravel()])
    else:
        image.SetSpacing(*volume.spacing)
    array = numpy_to_vtk(values.ravel(), deep=True)
    array.SetName("scalars")
    image.GetPointData().SetScalars(array)
    return image


def _read_vti(path: Path) -> Volume:
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader

    reader = vtkXMLImageDataReader()
    if not reader.CanReadFile(str(path)):
        raise _fail(path, "not a VTK XML image data (.vti) file")
    reader.SetFileName(str(path))
    image = _run_vtk_reader(reader, path)
    values = _image_to_array(image, path)
    direction = image.GetDirectionMatrix()
    rotation = np.array([[direction.GetElement(r, c) for c in range(3)] for r in range(3)], dtype=float)
    spacing = np.array(image.GetSpacing(), dtype=float)
    spacing_mm, origin_ras, directions = _as_ras_geometry(
        rotation * spacing[None, :], np.array(image.GetOrigin()), lps=False
    )
    return Volume(values, spacing_mm, origin_ras, directions, _stem(path))


def _write_vti(volume: Volume, path: Path) -> None:
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(path))
    writer.SetInputData(_to_vtk_image(volume, with_geometry=True))
    _run_vtk_writer(writer, path)


# ---------------------------------------------------------------------------------------------------------------
# NumPy
# ---------------------------------------------------------------------------------------------------------------


def _read_npy(path: Path) -> Volume:
    with open(path, "rb") as handle:
        if handle.read(6) != b"\x93NUMPY":
            raise _fail(path, "not a .npy file (bad magic bytes)")
        try:
            handle.seek(0)
            version = np.lib.format.read_magic(handle)
            header = (
                np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            )(handle)
        except (ValueError, OSError, EOFError) as exc:
            raise _fail(path, f"the .npy header is invalid ({_one_line(str(exc))})") from None
    if header[2].hasobject:
        raise _fail(path, "the array holds Python objects (pickled data), which are not loaded")
    try:
        values = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise _fail(path, f"{_corrupt_text} ({_one_line(str(exc))})") from None
    if not isinstance(values, np.ndarray) or values.dtype.kind not in "biuf":
        raise _fail(path, f"the array has dtype {getattr(values, 'dtype', '?')}; a numeric array is needed")
    if values.ndim == 4 and values.shape[-1] in (2, 3, 4):
        _check_scalar_3d(path, values.shape[2::-1], int(values.shape[-1]))
    if values.ndim != 3:
        raise _fail(path, f"the array has shape {values.shape}; a 3-D (k, j, i) array is needed")
    _check_scalar_3d(path, values.shape[::-1], 1)
    if values.dtype.kind == "b":
        values = values.astype(np.uint8)
    return Volume(np.ascontiguousarray(values), (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), np.eye(3), _stem(path))


def _write_npy(volume: Volume, path: Path) -> None:
    np.save(path, np.ascontiguousarray(volume.values), allow_pickle=False)


# ---------------------------------------------------------------------------------------------------------------
# DICOM series
# ---------------------------------------------------------------------------------------------------------------


def _read_dicom_series(path: Path) -> Volume:
    from vtkmodules.vtkIOImage import vtkDICOMImageReader

    files = sorted(p for p in path.iterdir() if p.is_file() and not p.name.startswith("."))
    if not files:
        raise _fail(path, "the folder is empty (a DICOM series folder was expected)")
    # Per-slice positions: vtkDICOMImageReader sorts slices along the normal but only reports one position.
    positions: list[np.ndarray] = []
    orientation: np.ndarray | None = None
    probe = vtkDICOMImageReader()
    with _captured_vtk_errors():
        for file in files:
            if not probe.CanReadFile(str(file)):
                continue
            probe.SetFileName(str(file))
            probe.UpdateInformation()
            positions.append(np.array(probe.GetImagePositionPatient(), dtype=float))
            if orientation is None:
                orientation = np.array(probe.GetImageOrientationPatient(), dtype=float)
    if not positions:
        raise _fail(path, f"no DICOM files found in the folder ({len(files)} other file(s))")

    reader = vtkDICOMImageReader()
    reader.SetDirectoryName(str(path))
    image = _run_vtk_reader(reader, path)
    if int(reader.GetNumberOfComponents()) > 1:
        _check_scalar_3d(path, image.GetDimensions(), int(reader.GetNumberOfComponents()))
    values = _image_to_array(image, path)
    # vtkDICOMImageReader stores rows bottom-up and slices in decreasing position along the normal (row x column):
    # restore DICOM row order and increasing slice position.
    values = np.ascontiguousarray(values[::-1, ::-1, :])

    assert orientation is not None
    row = orientation[:3]
    col = orientation[3:6]
    if not (np.isfinite(orientation).all() and np.linalg.norm(row) > 0 and np.linalg.norm(col) > 0):
        row, col = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    row = row / np.linalg.norm(row)
    col = col / np.linalg.norm(col)
    normal = np.cross(row, col)
    distances = np.array(sorted(float(np.dot(p, normal)) for p in positions))
    first = min(positions, key=lambda p: float(np.dot(p, normal)))
    spacing = reader.GetPixelSpacing()
    if len(distances) > 1:
        slice_spacing = float((distances[-1] - distances[0]) / (len(distances) - 1))
    else:
        slice_spacing = float(spacing[2]) if spacing[2] > 0 else 1.0
    if slice_spacing <= 0:
        raise _fail(path, "all slices of the series share one position (several series mixed, or not a volume)")
    # DICOM Pixel Spacing is (row spacing, column spacing); vtkDICOMImageReader already reports it as (x, y).
    axes = np.column_stack([row * float(spacing[0]), col * float(spacing[1]), normal * slice_spacing])
    spacing_mm, origin_ras, directions = _as_ras_geometry(axes, first, lps=True)
    return Volume(values, spacing_mm, origin_ras, directions, path.name)


# ---------------------------------------------------------------------------------------------------------------
# InVesalius project
# ---------------------------------------------------------------------------------------------------------------

#: InVesalius stores axial projects with i towards the patient's left, j towards anterior (it flips DICOM rows)
#: and k towards superior: in RAS, the columns below.
_INV3_AXIAL_DIRECTIONS = np.diag([-1.0, 1.0, 1.0])


def _read_inv3(path: Path) -> Volume:
    try:
        archive = tarfile.open(path, "r:gz")
    except (tarfile.TarError, OSError, EOFError, zlib.error) as exc:
        raise _fail(path, f"not an InVesalius project (gzip tar expected: {_one_line(str(exc))})") from None
    with archive:
        try:
            members = {m.name: m for m in archive.getmembers() if m.isfile()}
        except (tarfile.TarError, OSError, EOFError, zlib.error) as exc:
            raise _fail(path, f"the archive is corrupt or truncated ({_one_line(str(exc))})") from None
        main_name = next((n for n in members if n.rsplit("/", 1)[-1] == "main.plist"), None)
        if main_name is None:
            raise _fail(path, "no main.plist in the InVesalius project")
        try:
            main = plistlib.loads(_extract(archive, members[main_name]))
            matrix = main["matrix"]
            shape = tuple(int(n) for n in matrix["shape"])
            dtype = np.dtype(str(matrix.get("dtype", "int16"))).newbyteorder("<")
            spacing = tuple(float(s) for s in main["spacing"])
            data_name = str(matrix.get("filename", "matrix.dat"))
        except (plistlib.InvalidFileException, KeyError, TypeError, ValueError) as exc:
            raise _fail(path, f"main.plist lacks a valid matrix shape/dtype or spacing ({exc!r})") from None
        if len(shape) != 3 or len(spacing) != 3:
            raise _fail(path, f"the project matrix has shape {shape}; a 3-D (z, y, x) matrix is needed")
        folder = main_name.rsplit("/", 1)[0] + "/" if "/" in main_name else ""
        member = members.get(folder + data_name)
        if member is None:
            raise _fail(path, f"the project has no {data_name}")
        try:
            raw = _extract(archive, member)
        except (tarfile.TarError, OSError, EOFError, zlib.error) as exc:
            raise _fail(path, f"the archive is corrupt or truncated ({_one_line(str(exc))})") from None
    expected = int(np.prod(shape)) * dtype.itemsize
    if len(raw) != expected:
        raise _fail(path, f"{data_name} holds {len(raw)} bytes; shape {shape} of {dtype.name} needs {expected}")
    values = np.frombuffer(raw, dtype=dtype).reshape(shape).astype(dtype.newbyteorder("="))
    orientation = main.get("orientation", 1)
    directions = _INV3_AXIAL_DIRECTIONS if orientation in (1, "AXIAL") else np.eye(3)
    return Volume(values, spacing, (0.0, 0.0, 0.0), directions, _stem(path))


def _extract(archive: tarfile.TarFile, member: tarfile.TarInfo) -> bytes:
    handle = archive.extractfile(member)
    if handle is None:
        raise OSError(f"cannot extract {member.name}")
    with handle:
        data = handle.read()
    if len(data) != member.size:
        raise EOFError(f"{member.name} is truncated")
    return data


_READERS: dict[str, Callable[[Path], Volume]] = {
    "nrrd": _read_nrrd,
    "meta": _read_meta,
    "nifti": _read_nifti,
    "vti": _read_vti,
    "npy": _read_npy,
    "inv3": _read_inv3,
}
