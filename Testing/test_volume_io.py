"""Tests for isosimtf.volume_io: format round trips, geometry, DICOM series, clear errors, real data."""

from __future__ import annotations

import gzip
import io
import plistlib
import struct
import tarfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from volume_writers import write_volume

from IsoSimilarityTFLib import memory
from IsoSimilarityTFLib.errors import InsufficientMemoryError
from isosimtf.volume_io import Volume, VolumeReadError, read_volume, real_dataset_path

SHAPE = (5, 7, 9)  # (k, j, i): odd and different along every axis
SPACING = (0.7, 1.3, 2.1)  # anisotropic, mm along i, j, k
ORIGIN = (10.5, -20.25, 33.0)  # RAS mm


def _rotation(degrees: float, axis: int) -> np.ndarray:
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    a, b = [n for n in range(3) if n != axis]
    rot = np.eye(3)
    rot[a, a], rot[a, b], rot[b, a], rot[b, b] = c, -s, s, c
    return rot


def _volume(left_handed: bool) -> Volume:
    rng = np.random.default_rng(1234)
    values = rng.integers(-1024, 3072, size=SHAPE).astype(np.int16)
    values[0, 0, 0], values[-1, -1, -1] = -32768, 32767  # int16 extremes must survive
    directions = _rotation(25.0, 2) @ _rotation(-10.0, 0)
    if left_handed:
        directions[:, 2] *= -1.0  # like most CT series once converted to RAS
    return Volume(values, SPACING, ORIGIN, directions, "phantom")


def _right_handed(volume: Volume) -> Volume:
    """The same voxels at the same RAS positions with a right-handed index frame, as Slicer's readers give them.

    Slicer's ITK-based reader reverses the slice order of a left-handed volume (and negates the k direction).
    """
    if np.linalg.det(volume.directions) > 0:
        return volume
    flip = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, volume.shape[0] - 1], [0, 0, 0, 1]], dtype=float)
    return Volume.from_ijk_to_ras(volume.values[::-1], volume.ijk_to_ras() @ flip, volume.name)


def _assert_same(read: Volume, expected: Volume, geometry: bool = True, slicer: bool = True) -> None:
    if geometry and slicer:
        expected = _right_handed(expected)
    assert read.values.dtype == expected.values.dtype
    assert read.values.shape == expected.values.shape
    np.testing.assert_array_equal(read.values, expected.values)
    if geometry:
        np.testing.assert_allclose(read.spacing, expected.spacing, rtol=0, atol=1e-5)
        np.testing.assert_allclose(read.origin, expected.origin, rtol=0, atol=1e-5)
        np.testing.assert_allclose(read.directions, expected.directions, rtol=0, atol=1e-5)
        np.testing.assert_allclose(read.ijk_to_ras(), expected.ijk_to_ras(), rtol=0, atol=1e-5)


@pytest.mark.parametrize("left_handed", [False, True], ids=["right-handed", "left-handed"])
@pytest.mark.parametrize("suffix", [".nrrd", ".nhdr", ".mha", ".mhd", ".nii", ".nii.gz", ".vti"])
def test_round_trip_keeps_values_and_geometry(tmp_path: Path, suffix: str, left_handed: bool, capfd) -> None:
    volume = _volume(left_handed)
    path = tmp_path / f"phantom{suffix}"
    write_volume(volume, path)
    read = read_volume(path)
    _assert_same(read, volume, slicer=suffix != ".vti")
    assert read.name == "phantom"
    assert capfd.readouterr().err == ""  # nothing from VTK on stderr


def test_round_trip_npy_keeps_values_only(tmp_path: Path) -> None:
    volume = _volume(left_handed=False)
    path = tmp_path / "phantom.npy"
    write_volume(volume, path)
    read = read_volume(path)
    _assert_same(read, volume, geometry=False)
    assert read.spacing == (1.0, 1.0, 1.0)
    assert read.origin == (0.0, 0.0, 0.0)
    np.testing.assert_array_equal(read.directions, np.eye(3))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32, np.float32, np.float64])
def test_round_trip_other_dtypes(tmp_path: Path, dtype: type) -> None:
    values = (np.arange(np.prod(SHAPE)) % 200).reshape(SHAPE).astype(dtype)
    volume = Volume(values, SPACING, ORIGIN, np.eye(3), "v")
    for suffix in (".nrrd", ".mha", ".nii.gz", ".vti"):
        write_volume(volume, tmp_path / f"v{suffix}")
        _assert_same(read_volume(tmp_path / f"v{suffix}"), volume)


def test_ijk_to_ras_maps_indices_to_millimetres() -> None:
    volume = _volume(left_handed=True)
    matrix = volume.ijk_to_ras()
    assert matrix.shape == (4, 4)
    np.testing.assert_allclose(matrix @ [0, 0, 0, 1], [*ORIGIN, 1.0])
    expected = np.asarray(ORIGIN) + volume.directions @ (np.array([2, 3, 4]) * np.asarray(SPACING))
    np.testing.assert_allclose((matrix @ [2, 3, 4, 1])[:3], expected)


def test_nrrd_is_read_as_lps(tmp_path: Path) -> None:
    """A NRRD written by hand in LPS is read with Slicer's geometry: RAS, the first two axes negated."""
    values = (np.arange(np.prod(SHAPE)) % 100).reshape(SHAPE).astype(np.int16)
    header = (
        "NRRD0004\ntype: short\ndimension: 3\nspace: left-posterior-superior\nsizes: 9 7 5\n"
        "space directions: (0.7,0,0) (0,1.3,0) (0,0,2.1)\nkinds: domain domain domain\nendian: little\n"
        "encoding: raw\nspace origin: (-10.5,20.25,33)\n\n"
    )
    (tmp_path / "v.nrrd").write_bytes(header.encode() + values.astype("<i2").tobytes())
    read = read_volume(tmp_path / "v.nrrd")
    np.testing.assert_array_equal(read.values, values)
    np.testing.assert_allclose(read.origin, ORIGIN, atol=1e-9)
    np.testing.assert_allclose(read.spacing, SPACING, atol=1e-9)
    np.testing.assert_allclose(read.directions, np.diag([-1.0, -1.0, 1.0]), atol=1e-9)


# ---------------------------------------------------------------------------------------------------------------
# DICOM: a minimal series written by hand (explicit VR little endian), since plain VTK has no DICOM writer
# ---------------------------------------------------------------------------------------------------------------


def _element(group: int, element: int, vr: str, value: bytes) -> bytes:
    if len(value) % 2:
        value += b"\0" if vr in ("UI", "OB") else b" "
    if vr in ("OB", "OW", "OF", "SQ", "UT", "UN"):
        return struct.pack("<HH2sHI", group, element, vr.encode(), 0, len(value)) + value
    return struct.pack("<HH2sH", group, element, vr.encode(), len(value)) + value


def _ds(*numbers: float) -> bytes:
    return "\\".join(f"{n:.6f}".rstrip("0").rstrip(".") for n in numbers).encode()


def _write_dicom_slice(
    path: Path,
    pixels: np.ndarray,
    position: np.ndarray,
    orientation: np.ndarray,
    pixel_spacing: tuple[float, float],
    number: int,
    intercept: float,
) -> None:
    """Write one CT slice; ``pixels`` is (rows, columns) int16 stored values; geometry in LPS as DICOM wants."""
    sop_class, uid_root = b"1.2.840.10008.5.1.4.1.1.2", "1.2.826.0.1.3680043.9.7133.1"
    instance = f"{uid_root}.{number + 100}".encode()
    meta_body = (
        _element(0x0002, 0x0001, "OB", b"\0\1")
        + _element(0x0002, 0x0002, "UI", sop_class)
        + _element(0x0002, 0x0003, "UI", instance)
        + _element(0x0002, 0x0010, "UI", b"1.2.840.10008.1.2.1")
    )
    meta = _element(0x0002, 0x0000, "UL", struct.pack("<I", len(meta_body))) + meta_body
    rows, columns = pixels.shape
    data = b"".join(
        [
            _element(0x0008, 0x0016, "UI", sop_class),
            _element(0x0008, 0x0018, "UI", instance),
            _element(0x0008, 0x0060, "CS", b"CT"),
            _element(0x0010, 0x0010, "PN", b"Test^Phantom"),
            _element(0x0020, 0x000D, "UI", f"{uid_root}.1".encode()),
            _element(0x0020, 0x000E, "UI", f"{uid_root}.2".encode()),
            _element(0x0020, 0x0013, "IS", str(number).encode()),
            _element(0x0020, 0x0032, "DS", _ds(*position)),
            _element(0x0020, 0x0037, "DS", _ds(*orientation)),
            _element(0x0028, 0x0002, "US", struct.pack("<H", 1)),
            _element(0x0028, 0x0004, "CS", b"MONOCHROME2"),
            _element(0x0028, 0x0010, "US", struct.pack("<H", rows)),
            _element(0x0028, 0x0011, "US", struct.pack("<H", columns)),
            _element(0x0028, 0x0030, "DS", _ds(*pixel_spacing)),
            _element(0x0028, 0x0100, "US", struct.pack("<H", 16)),
            _element(0x0028, 0x0101, "US", struct.pack("<H", 16)),
            _element(0x0028, 0x0102, "US", struct.pack("<H", 15)),
            _element(0x0028, 0x0103, "US", struct.pack("<H", 1)),
            _element(0x0028, 0x1052, "DS", _ds(intercept)),
            _element(0x0028, 0x1053, "DS", b"1"),
            _element(0x7FE0, 0x0010, "OW", pixels.astype("<i2").tobytes()),
        ]
    )
    path.write_bytes(b"\0" * 128 + b"DICM" + meta + data)


def test_dicom_series_sorted_with_geometry(tmp_path: Path, capfd) -> None:
    rng = np.random.default_rng(7)
    hu = rng.integers(-1000, 2000, size=SHAPE).astype(np.int16)
    row_lps = _rotation(20.0, 2)[:, 0]  # direction of increasing column index (i)
    col_lps = _rotation(20.0, 2)[:, 1]  # direction of increasing row index (j)
    normal = np.cross(row_lps, col_lps)
    origin_lps = np.array([-120.0, 80.5, -40.0])
    row_spacing, column_spacing, slice_spacing = 0.8, 0.6, 2.5  # DICOM Pixel Spacing = (row, column) spacing
    series = tmp_path / "series"
    series.mkdir()
    order = [3, 0, 4, 1, 2]  # file names do not follow the slice order
    for name_index, k in enumerate(order):
        _write_dicom_slice(
            series / f"IM{name_index:04d}",
            hu[k] + 1024,
            origin_lps + k * slice_spacing * normal,
            np.concatenate([row_lps, col_lps]),
            (row_spacing, column_spacing),
            name_index + 1,
            -1024.0,
        )
    (series / "notes.txt").write_text("not a DICOM file\n")

    read = read_volume(series)
    assert read.values.shape == SHAPE
    np.testing.assert_array_equal(read.values, hu)
    lps_to_ras = np.diag([-1.0, -1.0, 1.0])
    np.testing.assert_allclose(read.spacing, (column_spacing, row_spacing, slice_spacing), atol=1e-5)
    np.testing.assert_allclose(read.origin, lps_to_ras @ origin_lps, atol=1e-5)
    np.testing.assert_allclose(read.directions, lps_to_ras @ np.column_stack([row_lps, col_lps, normal]), atol=1e-5)
    assert read.name == "series"
    assert capfd.readouterr().err == ""


# ---------------------------------------------------------------------------------------------------------------
# Clear, one-line errors
# ---------------------------------------------------------------------------------------------------------------


def _read_error(path: Path, capfd) -> str:
    with pytest.raises(VolumeReadError) as info:
        read_volume(path)
    message = str(info.value)
    assert "\n" not in message and "PosixPath" not in message
    assert str(path) in message
    assert info.value.__traceback__ is not None
    assert capfd.readouterr().err == "", "VTK printed to stderr"
    return message


def test_missing_file(tmp_path: Path, capfd) -> None:
    message = _read_error(tmp_path / "absent.nrrd", capfd)
    assert "no such file" in message


def test_unknown_suffix(tmp_path: Path, capfd) -> None:
    path = tmp_path / "scan.xyz"
    path.write_bytes(b"hello")
    message = _read_error(path, capfd)
    assert "unsupported file type '.xyz'" in message
    assert ".nrrd" in message and "DICOM" in message


def test_folder_without_dicom(tmp_path: Path, capfd) -> None:
    folder = tmp_path / "notdicom"
    folder.mkdir()
    (folder / "a.txt").write_text("just text\n")
    np.save(folder / "b.npy", np.zeros(3))
    message = _read_error(folder, capfd)
    assert "no DICOM files" in message


def test_empty_folder(tmp_path: Path, capfd) -> None:
    folder = tmp_path / "empty"
    folder.mkdir()
    assert "empty" in _read_error(folder, capfd)


@pytest.mark.parametrize("suffix", [".nrrd", ".nhdr", ".mha", ".nii", ".nii.gz", ".vti", ".npy"])
def test_truncated_files(tmp_path: Path, suffix: str, capfd) -> None:
    volume = _volume(left_handed=False)
    path = tmp_path / f"cut{suffix}"
    write_volume(volume, path)
    data_path = path.with_suffix(".raw.gz") if suffix == ".nhdr" else path
    data = data_path.read_bytes()
    data_path.write_bytes(data[: len(data) // 2])
    message = _read_error(path, capfd)
    assert "Cannot read" in message


def test_truncated_nrrd_messages(tmp_path: Path, capfd) -> None:
    volume = _volume(left_handed=False)
    gz = tmp_path / "cut.nrrd"
    write_volume(volume, gz)
    gz.write_bytes(gz.read_bytes()[:-200])
    assert "truncated or corrupt (expected 630 bytes but received" in _read_error(gz, capfd)
    raw = tmp_path / "raw.nrrd"
    header = b"NRRD0004\ntype: short\ndimension: 3\nsizes: 9 7 5\nencoding: raw\nendian: little\n\n"
    raw.write_bytes(header + volume.values.tobytes()[:100])
    message = _read_error(raw, capfd)
    assert "truncated or corrupt" in message and "315" in message


def test_garbage_files(tmp_path: Path, capfd) -> None:
    for suffix in (".nrrd", ".mha", ".nii", ".nii.gz", ".vti", ".npy", ".inv3"):
        path = tmp_path / f"garbage{suffix}"
        path.write_bytes(bytes(range(256)) * 4)
        _read_error(path, capfd)
    compressed = tmp_path / "garbage2.nii.gz"
    compressed.write_bytes(gzip.compress(b"\0" * 400))
    assert "NIfTI" in _read_error(compressed, capfd)


def _vtk_image(dims: tuple[int, int, int], components: int) -> object:
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonDataModel import vtkImageData

    image = vtkImageData()
    image.SetDimensions(*dims)
    n = dims[0] * dims[1] * dims[2]
    array = numpy_to_vtk((np.arange(n * components) % 250).astype(np.uint8).reshape(n, components), deep=True)
    image.GetPointData().SetScalars(array)
    return image


def _write_vti(image: object, path: Path) -> None:
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(path))
    writer.SetInputData(image)
    writer.Write()


def test_rgb_image_rejected(tmp_path: Path, capfd) -> None:
    path = tmp_path / "rgb.vti"
    _write_vti(_vtk_image((9, 7, 5), components=3), path)
    message = _read_error(path, capfd)
    assert "3 components per voxel" in message and "RGB" in message


def test_two_d_images_rejected(tmp_path: Path, capfd) -> None:
    path = tmp_path / "slice.vti"
    _write_vti(_vtk_image((9, 7, 1), components=1), path)
    assert "2-D image (9 x 7 x 1 voxels)" in _read_error(path, capfd)
    flat = tmp_path / "slice.npy"
    np.save(flat, np.zeros((7, 9), np.int16))
    assert "shape (7, 9)" in _read_error(flat, capfd)
    nrrd = tmp_path / "slice.nrrd"
    nrrd.write_bytes(b"NRRD0004\ntype: short\ndimension: 2\nsizes: 9 7\nendian: little\nencoding: raw\n\n" + bytes(126))
    assert "2-D image" in _read_error(nrrd, capfd)


def test_vector_nrrd_rejected(tmp_path: Path, capfd) -> None:
    path = tmp_path / "vectors.nrrd"
    header = b"NRRD0004\ntype: float\ndimension: 4\nsizes: 3 9 7 5\nkinds: vector domain domain domain\n"
    path.write_bytes(header + b"endian: little\nencoding: raw\n\n" + bytes(4 * 3 * 9 * 7 * 5))
    assert "3 components per voxel" in _read_error(path, capfd)


def test_pickled_npy_rejected(tmp_path: Path, capfd) -> None:
    path = tmp_path / "objects.npy"
    np.save(path, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    assert "Cannot read" in _read_error(path, capfd)


# ---------------------------------------------------------------------------------------------------------------
# Issue 11: what Slicer's readers would get wrong or crash on is refused from the header, before reading voxels
# ---------------------------------------------------------------------------------------------------------------


def _nrrd(path: Path, sizes: str, encoding: str, data: bytes) -> Path:
    header = f"NRRD0004\ntype: short\ndimension: 3\nsizes: {sizes}\nendian: little\nencoding: {encoding}\n\n"
    path.write_bytes(header.encode() + data)
    return path


def _nifti_header(dims: tuple[int, int, int]) -> bytes:
    header = bytearray(352)
    struct.pack_into("<i", header, 0, 348)
    struct.pack_into("<8h", header, 40, 3, *dims, 1, 1, 1, 1)
    struct.pack_into("<hh", header, 70, 4, 16)  # int16
    struct.pack_into("<8f", header, 76, 1, 1, 1, 1, 1, 1, 1, 1)
    struct.pack_into("<ff", header, 108, 352.0, 1.0)  # vox_offset, scl_slope
    header[344:348] = b"n+1\0"
    return bytes(header)


def test_small_files_claiming_huge_volumes_are_refused_from_the_header(tmp_path: Path, capfd) -> None:
    """Before: std::bad_alloc (exit 134) or 4.3 GB read, then 'the volume is constant'."""
    huge = "2048 2048 512"
    files = [
        _nrrd(tmp_path / "gzip.nrrd", huge, "gzip", gzip.compress(bytes(64))),
        _nrrd(tmp_path / "ascii.nrrd", huge, "ascii", b"1 2 3\n"),
    ]
    files.append(tmp_path / "raw.nii")
    files[-1].write_bytes(_nifti_header((2048, 2048, 512)) + bytes(1000))
    files.append(tmp_path / "gz.nii.gz")
    files[-1].write_bytes(gzip.compress(_nifti_header((2048, 2048, 512)) + bytes(1000)))
    files.append(tmp_path / "zlib.mha")
    files[-1].write_bytes(
        b"ObjectType = Image\nNDims = 3\nCompressedData = True\nCompressedDataSize = 20\nDimSize = 2048 2048 512\n"
        b"ElementType = MET_SHORT\nElementDataFile = LOCAL\n" + zlib.compress(bytes(100))
    )
    (tmp_path / "data.raw.gz").write_bytes(gzip.compress(bytes(100)))
    files.append(tmp_path / "detached.nhdr")
    files[-1].write_text(
        f"NRRD0004\ntype: short\ndimension: 3\nsizes: {huge}\nendian: little\nencoding: gzip\n"
        "data file: data.raw.gz\n\n"
    )
    files.append(tmp_path / "detached.mhd")
    files[-1].write_text(
        "ObjectType = Image\nNDims = 3\nDimSize = 2048 2048 512\nElementType = MET_SHORT\nCompressedData = True\n"
        "ElementDataFile = data.raw.gz\n"
    )
    for path in files:
        assert "2048 x 2048 x 512 voxels of int16 (4.0 GiB), more than its" in _read_error(path, capfd)


def test_ascii_nrrd_is_read_correctly(tmp_path: Path) -> None:
    """Before: uninitialized memory (a different value range on every run)."""
    values = np.arange(5 * 7 * 9, dtype=np.int16).reshape(SHAPE)
    path = _nrrd(tmp_path / "text.nrrd", "9 7 5", "ascii", " ".join(map(str, values.ravel())).encode() + b"\n")
    np.testing.assert_array_equal(read_volume(path).values, values)


def test_too_large_for_memory_is_refused_before_reading(tmp_path: Path, monkeypatch) -> None:
    """The header alone decides: these files hold no valid voxels (truncated gzip, a sparse file), yet the error is
    about memory, not the data."""
    monkeypatch.setattr(memory, "available_memory_bytes", lambda: 1 << 20)
    nrrd = _nrrd(tmp_path / "big.nrrd", "128 128 128", "gzip", gzip.compress(bytes(2 * 128**3))[:-100])
    npy = tmp_path / "big.npy"
    with open(npy, "wb") as handle:
        np.lib.format.write_array_header_1_0(handle, {"descr": "<i2", "fortran_order": False, "shape": (128, 128, 128)})
        handle.truncate(handle.tell() + 2 * 128**3)  # sparse: nothing on disk
    for path in (nrrd, npy):
        with pytest.raises(InsufficientMemoryError, match="128 x 128 x 128 voxels"):
            read_volume(path, n_bins=256)


def test_truncated_nifti_is_refused(tmp_path: Path, capfd) -> None:
    """Slicer's NIfTI reader fills a truncated file with zeros and says nothing."""
    for suffix in (".nii", ".nii.gz"):
        path = tmp_path / f"cut{suffix}"
        write_volume(_volume(left_handed=False), path)
        path.write_bytes(path.read_bytes()[:-100])
        assert "truncated" in _read_error(path, capfd)


def test_four_d_and_malformed_nrrd_messages(tmp_path: Path, capfd) -> None:
    four_d = tmp_path / "4d.nrrd"
    four_d.write_bytes(
        b"NRRD0004\ntype: short\ndimension: 4\nsizes: 16 8 8 8\nkinds: domain domain domain domain\n"
        b"endian: little\nencoding: raw\n\n" + bytes(2 * 16 * 8**3)
    )
    assert "it is a 4-D image (16 x 8 x 8 x 8 voxels)" in _read_error(four_d, capfd)
    malformed = tmp_path / "orientation.nrrd"
    malformed.write_bytes(
        b"NRRD0004\ntype: short\ndimension: 3\nsizes: 8 8 8\nspace: left-posterior-superior\n"
        b"space directions: (1,0,0) (0,1) (0,0,1)\nendian: little\nencoding: raw\n\n" + bytes(2 * 8**3)
    )
    assert "do not recognise it as NRRD" in _read_error(malformed, capfd)


def _write_series(folder: Path, values: np.ndarray, origin_z: float, spacing_z: float, series: str) -> None:
    folder.mkdir(exist_ok=True)
    for k in range(values.shape[0]):
        path = folder / f"{series}{k}"
        _write_dicom_slice(path, values[k] + 1024, np.array([0.0, 0.0, origin_z + k * spacing_z]),
                           np.array([1.0, 0, 0, 0, 1, 0]), (0.8, 0.6), k + 1, -1024.0)  # fmt: skip
        # A second series: another Series Instance UID (same length, so the element lengths stay right).
        path.write_bytes(path.read_bytes().replace(b"9.7133.1.2", f"9.7133.1.{series[-1]}".encode()))


def test_two_dicom_series_in_one_folder(tmp_path: Path, capfd) -> None:
    """Before: read with slice positions from both series (spacing 27.5 mm instead of 2.5)."""
    values = np.random.default_rng(3).integers(-1000, 2000, size=(5, 7, 9)).astype(np.int16)
    folder = tmp_path / "mixed"
    _write_series(folder, values, 0.0, 2.5, "A2")
    _write_series(folder, values[:3], 100.0, 30.0, "B3")
    message = _read_error(folder, capfd)
    assert "holds 2 DICOM series (5 file(s) from A20; 3 file(s) from B30)" in message
    assert "give one file of the series" in message
    first = read_volume(folder / "A22")  # a file of the series reads the whole series, sorted
    np.testing.assert_array_equal(first.values, values)
    np.testing.assert_allclose(first.spacing, (0.6, 0.8, 2.5), atol=1e-6)
    second = read_volume(folder / "B30")
    np.testing.assert_array_equal(second.values, values[:3])
    np.testing.assert_allclose(second.spacing[2], 30.0, atol=1e-6)


def test_dicom_series_with_slices_sharing_a_position(tmp_path: Path, capfd) -> None:
    """Two volumes under one Series Instance UID (e.g. two echoes) are not one volume."""
    values = np.random.default_rng(4).integers(-1000, 2000, size=(3, 7, 9)).astype(np.int16)
    folder = tmp_path / "echoes"
    _write_series(folder, values, 0.0, 2.5, "E2")  # the series UID is left as it is
    _write_series(folder, values, 0.0, 2.5, "F2")
    assert "several slices of the series share one position" in _read_error(folder, capfd)


# ---------------------------------------------------------------------------------------------------------------
# Real data (Debian packages invesalius-examples and mricron-data; skipped when absent)
# ---------------------------------------------------------------------------------------------------------------


def _real(name: str, package: str) -> Path:
    path = real_dataset_path(name)
    if path is None:
        pytest.skip(f"real dataset '{name}' not installed (Debian package {package})")
    return path


def test_invesalius_head_ct() -> None:
    volume = read_volume(_real("head-ct", "invesalius-examples"))
    assert volume.values.shape == (108, 256, 256)  # (z, y, x)
    assert volume.values.dtype == np.int16
    np.testing.assert_allclose(volume.spacing, (0.957, 0.957, 1.5), atol=1e-3)
    assert -1100 <= int(volume.values.min()) <= -1000  # air
    assert int(volume.values.max()) > 1000  # bone
    assert volume.name == "Cranium"


def test_colin27_brain_mri() -> None:
    volume = read_volume(_real("brain-mri", "mricron-data"))
    # NIfTI dims are 181 (x) x 217 (y) x 181 (z); the array is (z, y, x).
    assert volume.values.shape == (181, 217, 181)
    np.testing.assert_allclose(volume.spacing, (1.0, 1.0, 1.0), atol=1e-6)
    np.testing.assert_allclose(volume.directions, np.eye(3), atol=1e-6)  # MNI template: RAS-aligned
    assert float(volume.values.max()) > float(volume.values.min())


def test_real_dataset_path_unknown_name() -> None:
    with pytest.raises(KeyError):
        real_dataset_path("no-such-dataset")


def _write_inv3(path: Path, values: np.ndarray, spacing: tuple[float, float, float], *, voxels_first: bool) -> None:
    """An InVesalius project as InVesalius writes it (gzip tar of a folder), ``matrix.dat`` before or after
    ``main.plist``, with a member before both (the masks and surfaces of a real project)."""
    main = {"matrix": {"shape": list(values.shape), "dtype": "int16", "filename": "matrix.dat"}, "spacing": spacing}
    members = [
        ("mask_0.dat", b"\1" * 1000),
        ("main.plist", plistlib.dumps(main)),
        ("matrix.dat", values.astype("<i2").tobytes()),
    ]
    if voxels_first:
        members.reverse()
    with tarfile.open(path, "w:gz") as archive:
        for name, data in members:
            info = tarfile.TarInfo(f"tmpproject/{name}")
            info.size = len(data)
            archive.addfile(info, io.BytesIO(data))


@pytest.mark.parametrize("voxels_first", [False, True])
def test_inv3_is_read_whatever_the_member_order(tmp_path: Path, voxels_first: bool) -> None:
    values = (np.arange(5 * 6 * 7, dtype=np.int16).reshape(5, 6, 7) * 13 - 1000).astype(np.int16)
    path = tmp_path / "project.inv3"
    _write_inv3(path, values, (0.5, 0.5, 1.25), voxels_first=voxels_first)
    volume = read_volume(path)
    assert volume.values.dtype == np.int16 and volume.values.dtype.isnative
    np.testing.assert_array_equal(volume.values, values)
    assert volume.spacing == (0.5, 0.5, 1.25) and volume.name == "project"
    np.testing.assert_array_equal(volume.directions, np.diag([-1.0, 1.0, 1.0]))


def test_inv3_errors(tmp_path: Path, capfd) -> None:
    values = np.zeros((5, 6, 7), dtype=np.int16)
    path = tmp_path / "project.inv3"
    _write_inv3(path, values, (1.0, 1.0, 1.0), voxels_first=False)
    data = path.read_bytes()
    cut = tmp_path / "cut.inv3"
    cut.write_bytes(data[: len(data) // 2])
    assert "corrupt or truncated" in _read_error(cut, capfd)
    plain = tmp_path / "plain.inv3"
    plain.write_bytes(gzip.compress(b"not a tar archive" * 40))
    assert "not an InVesalius project (gzip tar expected" in _read_error(plain, capfd)
    project = tmp_path / "empty.inv3"
    with tarfile.open(project, "w:gz"):
        pass
    assert "no main.plist" in _read_error(project, capfd)


def test_a_fifo_is_refused_without_waiting(tmp_path: Path, capfd) -> None:
    import os

    fifo = tmp_path / "volume.nrrd"
    os.mkfifo(fifo)
    assert "it is not a regular file (a FIFO, socket or device)" in _read_error(fifo, capfd)


def _scaled_nifti(path: Path, stored: np.ndarray, slope: float, inter: float) -> None:
    """A NIfTI file of ``stored`` integers with scl_slope / scl_inter patched in (as nibabel and dcm2niix write)."""
    plain = path.with_name("plain.nii")
    write_volume(Volume(stored, SPACING, ORIGIN, np.eye(3), "v"), plain, compress=False)
    data = bytearray(plain.read_bytes())
    struct.pack_into("<ff", data, 112, slope, inter)  # NIfTI-1: scl_slope, scl_inter at bytes 112, 116
    path.write_bytes(gzip.compress(bytes(data)) if path.name.endswith(".gz") else bytes(data))


@pytest.mark.parametrize("name", ["scaled.nii", "scaled.nii.gz"])
@pytest.mark.parametrize(("dtype", "slope", "inter"), [(np.int16, 0.5, 10.0), (np.uint16, 1.0, -1024.0)])
def test_scaled_nifti_is_read_with_its_scaling(tmp_path: Path, name: str, dtype, slope: float, inter: float) -> None:
    """Issue 18, item 1: refused as "truncated" (the bytes were counted in float32, the type Slicer returns)."""
    from isosimtf.phantom import head_phantom

    stored = np.clip(head_phantom(16, seed=0).values.astype(np.int32) + 1024, 0, None).astype(dtype)
    _scaled_nifti(tmp_path / name, stored, slope, inter)
    read = read_volume(tmp_path / name)
    np.testing.assert_allclose(read.values, stored * slope + inter, rtol=0, atol=1e-3)
    assert read.values.dtype == np.float32


def test_truncated_scaled_nifti_is_still_refused(tmp_path: Path, capfd) -> None:
    stored = np.arange(8 * 9 * 10, dtype=np.int16).reshape(8, 9, 10)
    _scaled_nifti(tmp_path / "s.nii", stored, 2.0, 1.0)
    (tmp_path / "s.nii").write_bytes((tmp_path / "s.nii").read_bytes()[:-2])
    assert f"truncated: {stored.nbytes} bytes of voxel data expected, {stored.nbytes - 2} found" in _read_error(
        tmp_path / "s.nii", capfd
    )


@pytest.mark.parametrize(
    ("name", "reader"),
    [("v.nrrd", "NRRD, MetaImage or NIfTI"), ("v.mha", "NRRD, MetaImage or NIfTI"),
     ("v.nii.gz", "NRRD, MetaImage or NIfTI"), ("v.vti", "VTK image"), ("v.npy", ".npy")],
)  # fmt: skip
def test_each_format_has_one_reader(tmp_path: Path, name: str, reader: str) -> None:
    from isosimtf.volume_io import reader_for

    write_volume(_volume(False), tmp_path / name)
    assert reader_for(tmp_path / name).name == reader
    (tmp_path / "notes.txt").write_text("not a volume")
    assert reader_for(tmp_path / "notes.txt") is None


def test_the_debian_volumes_have_their_readers() -> None:
    from isosimtf.volume_io import reader_for

    for name, reader in (("head-ct", "InVesalius"), ("brain-mri", "NRRD, MetaImage or NIfTI")):
        path = real_dataset_path(name)
        if path is not None:
            assert reader_for(path).name == reader
