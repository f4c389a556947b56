"""Our reader against the truth and against an independent reader, format variant by format variant (issue 26, 4).

Every variant is written with KNOWN voxels and geometry: NRRD with pynrrd, NIfTI-1 with nibabel, a DICOM CT series
with pydicom, MetaImage by hand, TIFF with tifffile or Pillow, Zarr and OME-Zarr with zarr or by hand, VTK image data
with VTK's writer or by hand. Each file is read with :func:`isosimtf.volume_io.read_volume` and with an independent
reader: pynrrd, nibabel, pydicom, Pillow for TIFF (ours reads with tifffile), and for Zarr and VTI, whose readers we
use ourselves (zarr, VTK), a decoding written here from the formats' specifications (json and chunk files; the XML
with base64, zlib and lzma). No independent MetaImage reader is installed: checked against the truth only. Three
things are checked:

1. our voxels, spacing and IJK-to-RAS matrix are the truth as Slicer shows it: in RAS (NRRD ``left-posterior-superior``,
   MetaImage, DICOM and TIFF are LPS; NIfTI and NRRD ``right-anterior-superior`` are RAS; Zarr and VTI carry no
   anatomical frame and are taken as RAS), and a left-handed index frame made right-handed by reversing the slice
   order (Slicer's ``ForceRightHandedIJKCoordinateSystem``);
2. the independent reader gives the truth in the file's own index order;
3. the two agree voxel for voxel at the same RAS positions (up to that reordering of the slices).

Where Slicer follows a rule of its own (NIfTI sform / qform precedence, TIFF resolution tags, a VTI extent not
starting at 0) or the independent reader cannot say what the file holds (Pillow's 8-bit signed samples) the rule is
named where it is used. Variants that are no 3-D scalar volume are refused in one line (exit 2).

The header round trips (Slicer writes, Slicer reads) are in test_volume_io.py, the lazy path of raw NRRD / MetaImage
in test_header_variants.py; TIFF and Zarr are read lazily, as dask arrays (``chunked_readers.read_chunked``), which
test_chunked_readers.py checks further (previews, chunked designs).
"""

from __future__ import annotations

import importlib.util
import lzma
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
from test_volume_io import _rotation

from isosimtf.volume_io import Volume, read_volume

nibabel = pytest.importorskip("nibabel")
nrrd = pytest.importorskip("nrrd")
pydicom = pytest.importorskip("pydicom")

SHAPE = (5, 6, 7)  # (K, J, I): different along every axis, so a wrong axis order shows
SPACING = (0.6, 0.9, 1.7)  # mm along i, j, k: anisotropic
ORIGIN = (12.5, -30.25, 7.0)  # RAS mm of the centre of voxel (0, 0, 0)
ROTATION = _rotation(30.0, 2) @ _rotation(-20.0, 0)  # RAS, right-handed, no axis along a world axis
LPS = np.diag([-1.0, -1.0, 1.0])  # RAS <-> LPS, its own inverse

#: Axis directions (columns, RAS) of the index frame as written in the file.
DIRECTIONS = {
    "axis-aligned": np.eye(3),
    "rotated": ROTATION,
    "rotated-left-handed": ROTATION @ np.diag([1.0, 1.0, -1.0]),
}
DTYPES = ("uint8", "int8", "int16", "uint16", "int32", "uint32", "float32", "float64")


# ---------------------------------------------------------------------------------------------------------------
# The truth, and the three checks
# ---------------------------------------------------------------------------------------------------------------


def _truth(dtype: str) -> np.ndarray:
    """Known voxels (K, J, I) of ``dtype``: integers span the whole type (both extremes must survive), floats are not
    round numbers; shuffled, so every voxel differs from its neighbours along every axis."""
    dtype_ = np.dtype(dtype)
    n = int(np.prod(SHAPE))
    rng = np.random.default_rng(26)
    if dtype_.kind in "iu":
        info = np.iinfo(dtype_)
        low, high = max(float(info.min), -(2.0**53)), min(float(info.max), 2.0**53)  # 64-bit: where floats are exact
        ramp = np.round(np.linspace(low, high, n))
    else:
        ramp = rng.normal(0.0, 1000.0, n) / 3.0
    return ramp[rng.permutation(n)].reshape(SHAPE).astype(dtype_)


def _ijk_to_ras(
    directions: np.ndarray, spacing: tuple[float, float, float] = SPACING, origin: tuple[float, float, float] = ORIGIN
) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3] = np.asarray(directions, float) * np.asarray(spacing, float)[np.newaxis, :]
    matrix[:3, 3] = origin
    return matrix


def _slicer_view(values: np.ndarray, ijk_to_ras: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What Slicer shows of voxels in file order: a left-handed index frame is made right-handed by reversing the
    slice order (k) and negating the k column (``ForceRightHandedIJKCoordinateSystem``), every voxel keeping its RAS
    position. Written here again, not taken from :func:`isosimtf.volume.right_handed`, so the check is independent."""
    if np.linalg.det(ijk_to_ras[:3, :3]) > 0:
        return values, ijk_to_ras
    flip = np.eye(4)
    flip[2, 2], flip[2, 3] = -1.0, values.shape[0] - 1
    return values[::-1], ijk_to_ras @ flip


def _assert_values(actual: np.ndarray, expected: np.ndarray, rtol: float, atol: float = 0.0) -> None:
    """Integers exactly; floats within ``rtol`` / ``atol``."""
    actual = np.asarray(actual)
    assert actual.shape == expected.shape
    if expected.dtype.kind in "iu":
        np.testing.assert_array_equal(actual, expected)
    else:
        np.testing.assert_allclose(actual, expected, rtol=rtol, atol=atol)


def _assert_same_world(
    values: np.ndarray,
    ijk_to_ras: np.ndarray,
    other: np.ndarray,
    other_ijk_to_ras: np.ndarray,
    rtol: float,
    value_atol: float = 0.0,
) -> None:
    """Two readings hold the same voxel values at the same RAS positions, up to a reordering of the index axes (as
    ``_assert_same_world_volume`` in test_cli.py compares a reloaded scene)."""
    mapping = np.linalg.inv(other_ijk_to_ras) @ ijk_to_ras  # our index -> the other reading's index
    np.testing.assert_allclose(mapping, np.round(mapping), rtol=0, atol=1e-3)
    mapping = np.round(mapping).astype(int)
    assert sorted(np.abs(mapping[:3, :3]).sum(axis=0).tolist()) == [1, 1, 1]  # a permutation with flips
    k, j, i = np.indices(values.shape).reshape(3, -1)
    source = mapping @ np.stack([i, j, k, np.ones_like(i)])
    assert source.min() >= 0
    _assert_values(values.reshape(-1), np.asarray(other)[source[2], source[1], source[0]], rtol, value_atol)


def _check(
    path: Path,
    truth: np.ndarray,
    truth_matrix: np.ndarray,
    independent: tuple[np.ndarray, np.ndarray] | None,
    *,
    rtol: float = 0.0,
    value_atol: float = 0.0,
    atol: float = 1e-6,
    dtype: str | None = None,
) -> Volume:
    """The three checks of the module docstring for the file at ``path``.

    Args:
        truth: voxels (K, J, I) in the file's own order, with the values a reader must give (rescaled if so).
        truth_matrix: their IJK-to-RAS matrix. independent: ``(values (K, J, I), IJK-to-RAS)`` of the other reader,
            None when there is none (then checks 2 and 3 are skipped).
        rtol, value_atol: for float voxels (ours; the independent reader's within ``rtol``). atol: mm, for the
            geometry. dtype: the dtype our reader must give, when known.
    """
    ours = read_volume(path)
    expected_values, expected_matrix = _slicer_view(truth, truth_matrix)
    if dtype is not None:
        assert ours.values.dtype == np.dtype(dtype)
    _assert_values(ours.values, expected_values, rtol, value_atol)
    np.testing.assert_allclose(ours.spacing, np.linalg.norm(truth_matrix[:3, :3], axis=0), rtol=0, atol=atol)
    np.testing.assert_allclose(ours.ijk_to_ras(), expected_matrix, rtol=0, atol=atol)
    if independent is not None:
        other, other_matrix = independent
        _assert_values(other, truth, rtol)
        np.testing.assert_allclose(other_matrix, truth_matrix, rtol=0, atol=atol)
        _assert_same_world(ours.values, ours.ijk_to_ras(), other, other_matrix, rtol, value_atol)
    return ours


def _rtol(dtype: str) -> float:
    return {"float32": 1e-6, "float64": 1e-12}.get(dtype, 0.0)


# ---------------------------------------------------------------------------------------------------------------
# NRRD, written with pynrrd, read back with pynrrd
# ---------------------------------------------------------------------------------------------------------------

#: NRRD ``space`` -> the matrix taking its world coordinates to RAS.
NRRD_SPACES = {
    "left-posterior-superior": LPS,
    "right-anterior-superior": np.eye(3),
    "left-anterior-superior": np.diag([-1.0, 1.0, 1.0]),
}


def _write_nrrd(
    path: Path, values: np.ndarray, ijk_to_ras: np.ndarray, *, space: str, encoding: str, endian: str
) -> None:
    to_space = np.eye(4)
    to_space[:3, :3] = NRRD_SPACES[space]  # RAS -> the file's space (LPS and RAS are each their own inverse)
    matrix = to_space @ ijk_to_ras
    header = {
        "space": space,
        "space directions": matrix[:3, :3].T,  # one row per axis (i, j, k), in the file's space
        "space origin": matrix[:3, 3],
        "kinds": ["domain"] * 3,
        "encoding": encoding,
    }
    stored = values.astype(values.dtype.newbyteorder(">" if endian == "big" else "<"))
    nrrd.write(str(path), stored, header, detached_header=path.suffix == ".nhdr", index_order="C")
    text = path.read_bytes().split(b"\n\n")[0].decode()
    assert f"encoding: {encoding}" in text and f"space: {space}" in text  # the variant is the one named
    assert values.dtype.itemsize == 1 or encoding == "ascii" or f"endian: {endian}" in text
    assert ("data file:" in text) == (path.suffix == ".nhdr")


def _read_nrrd(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """pynrrd's reading: voxels (K, J, I) and IJK-to-RAS from ``space``, ``space directions``, ``space origin``."""
    values, header = nrrd.read(str(path), index_order="C")
    matrix = np.eye(4)
    matrix[:3, :3] = np.asarray(header["space directions"], float).T
    matrix[:3, 3] = header["space origin"]
    to_ras = np.eye(4)
    to_ras[:3, :3] = NRRD_SPACES[header["space"]]
    return values, to_ras @ matrix


def _nrrd_storage_variants() -> list:
    """Every dtype x byte order (binary encodings of multi-byte types only) x encoding x header layout."""
    cases = []
    for dtype in DTYPES:
        for encoding in ("raw", "gzip", "ascii"):
            binary = encoding != "ascii" and np.dtype(dtype).itemsize > 1
            for endian in ("little", "big") if binary else ("little",):
                for suffix in (".nrrd", ".nhdr"):
                    layout = "attached" if suffix == ".nrrd" else "detached"
                    name = f"{dtype}-{endian}-{encoding}-{layout}" if binary else f"{dtype}-{encoding}-{layout}"
                    cases.append(pytest.param(dtype, endian, encoding, suffix, id=name))
    return cases


@pytest.mark.parametrize(("dtype", "endian", "encoding", "suffix"), _nrrd_storage_variants())
def test_nrrd_storage(tmp_path: Path, dtype: str, endian: str, encoding: str, suffix: str) -> None:
    """Every dtype, byte order, encoding and header layout, with a rotated, anisotropic, shifted LPS frame."""
    truth, matrix = _truth(dtype), _ijk_to_ras(ROTATION)
    path = tmp_path / f"v{suffix}"
    _write_nrrd(path, truth, matrix, space="left-posterior-superior", encoding=encoding, endian=endian)
    _check(path, truth, matrix, _read_nrrd(path), rtol=_rtol(dtype), dtype=dtype)


@pytest.mark.parametrize("space", list(NRRD_SPACES))
@pytest.mark.parametrize("directions", list(DIRECTIONS))
def test_nrrd_geometry(tmp_path: Path, directions: str, space: str) -> None:
    """Each frame in each world space: the same RAS truth written in LPS or in RAS reads the same."""
    truth, matrix = _truth("int16"), _ijk_to_ras(DIRECTIONS[directions])
    path = tmp_path / "v.nrrd"
    _write_nrrd(path, truth, matrix, space=space, encoding="raw", endian="little")
    _check(path, truth, matrix, _read_nrrd(path), dtype="int16")


# ---------------------------------------------------------------------------------------------------------------
# NIfTI-1, written with nibabel, read back with nibabel
# ---------------------------------------------------------------------------------------------------------------

#: NIfTI xyzt_units -> millimetres per unit.
NIFTI_UNITS_MM = {"mm": 1.0, "meter": 1000.0, "micron": 1e-3}
#: Another frame than the truth's, for a qform and an sform that disagree (same spacing: ITK takes it from pixdim).
OTHER_MATRIX = _ijk_to_ras(_rotation(-15.0, 1), origin=(-4.0, 8.5, -60.0))


def _write_nifti(
    path: Path,
    stored: np.ndarray,
    *,
    sform: np.ndarray | None,
    sform_code: int,
    qform: np.ndarray | None,
    qform_code: int,
    scaling: tuple[float, float] | None = None,
    unit: str = "mm",
    endian: str = "<",
    extension: bytes = b"",
    four_d: bool = False,
) -> None:
    """Write ``stored`` (K, J, I) with the given forms (RAS mm), in ``unit`` (xyzt_units: the forms and pixdim are
    written in that unit), byte order ``endian``, a comment ``extension`` when given, as a 4-D image of one volume
    (dim[0] = 4, dim[4] = 1) when ``four_d``."""
    per_mm = 1.0 / NIFTI_UNITS_MM[unit]
    in_unit = np.diag([per_mm, per_mm, per_mm, 1.0])
    data = stored.transpose(2, 1, 0)  # nibabel indexes [i, j, k]
    image = nibabel.Nifti1Image(
        data[..., np.newaxis] if four_d else data, None, nibabel.Nifti1Header(endianness=endian)
    )
    image.set_data_dtype(stored.dtype)
    header = image.header
    if extension:
        header.extensions.append(nibabel.nifti1.Nifti1Extension("comment", extension))
    header.set_sform(None if sform is None else in_unit @ sform, code=sform_code)
    header.set_qform(None if qform is None else in_unit @ qform, code=qform_code)
    header.set_zooms(
        [s * per_mm for s in SPACING] + [1.0] * four_d
    )  # pixdim: ITK's spacing, whichever form gives the directions
    header.set_xyzt_units(unit)
    if scaling is not None:
        header.set_slope_inter(*scaling)
    nibabel.save(image, str(path))
    written = nibabel.load(str(path))
    assert (int(written.header["sform_code"]), int(written.header["qform_code"])) == (sform_code, qform_code)
    np.testing.assert_array_equal(np.asarray(written.dataobj.get_unscaled()).reshape(data.shape), data)
    assert written.get_data_dtype() == stored.dtype.newbyteorder(endian)
    assert written.header.endianness == endian and len(written.header.extensions) == bool(extension)
    if scaling is not None:
        assert (float(written.dataobj.slope), float(written.dataobj.inter)) == scaling


def _read_nifti(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """nibabel's reading: ``get_fdata`` (scaled, float64) or the stored type, and its affine (the sform when
    sform_code > 0, else the qform when qform_code > 0) turned to mm: nibabel gives the affine in the header's spatial
    unit (xyzt_units), Slicer's reader (ITK's NiftiImageIO) converts metres and microns to millimetres."""
    image = nibabel.load(str(path))
    scaled = image.dataobj.slope != 1 or image.dataobj.inter != 0
    values = image.get_fdata() if scaled else np.asanyarray(image.dataobj)
    if values.ndim == 4 and values.shape[3] == 1:  # a 3-D volume stored as 4-D (one time point)
        values = values[..., 0]
    mm = NIFTI_UNITS_MM[image.header.get_xyzt_units()[0]]
    return values.transpose(2, 1, 0), np.diag([mm, mm, mm, 1.0]) @ np.asarray(image.affine, float)


@pytest.mark.parametrize("suffix", [".nii", ".nii.gz"])
@pytest.mark.parametrize("dtype", DTYPES)
def test_nifti_storage(tmp_path: Path, dtype: str, suffix: str) -> None:
    """Every dtype, plain and gzipped, with a rotated frame in both forms (nibabel's sform, codes 1 and 1)."""
    truth, matrix = _truth(dtype), _ijk_to_ras(ROTATION)
    path = tmp_path / f"v{suffix}"
    _write_nifti(path, truth, sform=matrix, sform_code=1, qform=matrix, qform_code=1)
    _check(path, truth, matrix, _read_nifti(path), rtol=_rtol(dtype), atol=1e-4, dtype=dtype)


#: name -> (stored dtype, suffix, _write_nifti options)
NIFTI_LAYOUTS = {
    "big-endian-int16": ("int16", ".nii", {"endian": ">"}),
    "big-endian-float64-gz": ("float64", ".nii.gz", {"endian": ">"}),
    "extension": ("int16", ".nii", {"extension": b"a header extension before the voxels " * 5}),
    "extension-gz": ("uint16", ".nii.gz", {"extension": b"a header extension before the voxels " * 5}),
    "4d-one-volume": ("int16", ".nii", {"four_d": True}),
}


@pytest.mark.parametrize("layout", list(NIFTI_LAYOUTS))
def test_nifti_layouts(tmp_path: Path, layout: str) -> None:
    """Byte order, header extensions (the voxels further on), a 3-D volume stored as 4-D of one time point."""
    dtype, suffix, options = NIFTI_LAYOUTS[layout]
    truth, matrix = _truth(dtype), _ijk_to_ras(ROTATION)
    path = tmp_path / f"v{suffix}"
    _write_nifti(path, truth, sform=matrix, sform_code=1, qform=matrix, qform_code=1, **options)
    _check(path, truth, matrix, _read_nifti(path), rtol=_rtol(dtype), atol=1e-4, dtype=dtype)


@pytest.mark.parametrize("unit", list(NIFTI_UNITS_MM))
def test_nifti_spatial_units(tmp_path: Path, unit: str) -> None:
    """The same millimetre frame written in mm, metres or microns: Slicer's frame is in mm whatever the unit."""
    truth, matrix = _truth("int16"), _ijk_to_ras(ROTATION)
    path = tmp_path / "v.nii"
    _write_nifti(path, truth, sform=matrix, sform_code=1, qform=matrix, qform_code=1, unit=unit)
    _check(path, truth, matrix, _read_nifti(path), atol=1e-4, dtype="int16")


#: name -> (sform code, qform code, whether the qform is another frame than the sform, the frame Slicer uses).
#: Slicer's reader is ITK's NiftiImageIO: it takes the sform when the qform code is 0, when sform_code is 1
#: (NIFTI_XFORM_SCANNER_ANAT), or when the two forms are about the same; else (an sform of code 2, 3 or 4 that
#: differs from a valid qform) the qform. nibabel takes the sform whenever its code is above 0.
NIFTI_XFORMS = {
    "sform-only": (2, 0, False, "sform"),
    "qform-only": (0, 1, False, "qform"),
    "both-agree": (1, 1, False, "sform"),
    "sform-scanner-qform-differs": (1, 1, True, "sform"),
    "sform-aligned-qform-differs": (2, 1, True, "qform"),  # ITK: the qform, nibabel: the sform
}


@pytest.mark.parametrize("directions", ["rotated", "rotated-left-handed"])
@pytest.mark.parametrize("xform", list(NIFTI_XFORMS))
def test_nifti_sform_and_qform(tmp_path: Path, xform: str, directions: str) -> None:
    sform_code, qform_code, differ, slicer_form = NIFTI_XFORMS[xform]
    truth, matrix = _truth("int16"), _ijk_to_ras(DIRECTIONS[directions])
    other = OTHER_MATRIX.copy()
    if directions.endswith("left-handed"):
        other[:3, 2] *= -1.0
    sform = matrix if sform_code else None
    qform = (other if differ else matrix) if qform_code else None
    path = tmp_path / "v.nii"
    _write_nifti(path, truth, sform=sform, sform_code=sform_code, qform=qform, qform_code=qform_code)
    nibabel_values, nibabel_matrix = _read_nifti(path)
    nibabel_form = "sform" if sform_code else "qform"
    forms = {"sform": sform, "qform": qform}
    if slicer_form == nibabel_form:
        _check(path, truth, forms[slicer_form], (nibabel_values, nibabel_matrix), atol=1e-4, dtype="int16")
    else:
        # The precedence rule above: the two readers place the same voxels in different frames, each the one its
        # rule picks; only the voxels (file order for nibabel, Slicer's order for ours) can be compared.
        _check(path, truth, forms[slicer_form], None, atol=1e-4, dtype="int16")
        _assert_values(nibabel_values, truth, 0.0)
        np.testing.assert_allclose(nibabel_matrix, forms[nibabel_form], rtol=0, atol=1e-4)


#: (stored dtype, scl_slope, scl_inter): the values are stored * slope + inter, float32 in Slicer.
NIFTI_SCALINGS = [("int16", 0.5, 10.0), ("uint8", 2.0, -100.0), ("uint16", 1.0, -1024.0), ("float32", 2.0, 1.5)]


@pytest.mark.parametrize("suffix", [".nii", ".nii.gz"])
@pytest.mark.parametrize(
    ("dtype", "slope", "inter"), NIFTI_SCALINGS, ids=[f"{d}-slope{s:g}-inter{i:g}" for d, s, i in NIFTI_SCALINGS]
)
def test_nifti_scaled(tmp_path: Path, dtype: str, slope: float, inter: float, suffix: str) -> None:
    stored, matrix = _truth(dtype), _ijk_to_ras(ROTATION)
    path = tmp_path / f"v{suffix}"
    _write_nifti(path, stored, sform=matrix, sform_code=1, qform=matrix, qform_code=1, scaling=(slope, inter))
    truth = stored.astype(np.float64) * slope + inter
    # float32 results, computed in float32: within float32's resolution of the largest operand
    value_atol = float(np.abs(stored.astype(np.float64) * slope).max() + abs(inter)) * 2e-7
    _check(path, truth, matrix, _read_nifti(path), value_atol=value_atol, atol=1e-4, dtype="float32")


# ---------------------------------------------------------------------------------------------------------------
# DICOM: a CT series written with pydicom, read back with pydicom and sorted along the slice normal
# ---------------------------------------------------------------------------------------------------------------

DICOM_ORIENTATIONS = {
    "axial": np.eye(3),
    "oblique": _rotation(25.0, 2) @ _rotation(-15.0, 0),  # LPS: columns row direction, column direction, normal
}
#: name -> (stored type: PixelRepresentation 1 if signed, Bits Stored, Rescale Slope, Rescale Intercept); None: no
#: Rescale Slope / Intercept at all.
DICOM_PIXELS = {
    "int16-no-rescale": ("int16", 16, None, None),
    "int16-slope1": ("int16", 16, 1.0, -1024.0),
    "int16-slope2": ("int16", 16, 2.0, -1000.0),
    "int16-slope0.25": ("int16", 16, 0.25, -10.5),
    "uint16-slope1": ("uint16", 16, 1.0, -1024.0),
    "uint12-slope1": ("uint16", 12, 1.0, -1024.0),  # the usual CT: 12 of 16 bits, unsigned
    "int12-slope1": ("int16", 12, 1.0, 0.0),  # 12 of 16 bits, signed (sign-extended in the 16)
}
PIXEL_SPACING = (0.9, 0.6)  # DICOM PixelSpacing: (between rows (along j), between columns (along i)) mm
SLICE_GAP = 1.7
ORIGIN_LPS = np.array([-120.25, 80.5, -40.0])


def _ds(value: float) -> str:
    """A DICOM decimal string (at most 16 characters)."""
    return pydicom.valuerep.format_number_as_ds(float(value))


def _write_dicom_series(
    folder: Path,
    stored: np.ndarray,
    orientation: np.ndarray,
    bits_stored: int,
    slope: float | None,
    inter: float | None,
    transfer_syntax: str = "ExplicitVRLittleEndian",
) -> np.ndarray:
    """One CT file per slice, the files named in a shuffled order; returns the IJK-to-RAS matrix written (from the
    decimal strings as written, so rounding to 16 characters is part of the truth)."""
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, generate_uid

    folder.mkdir()
    row, column = (np.array([float(_ds(v)) for v in orientation[:, a]]) for a in (0, 1))
    normal = np.cross(row, column)
    uid = "1.2.826.0.1.3680043.10.1326"
    order = np.random.default_rng(5).permutation(stored.shape[0])  # file names do not follow the slice order
    positions = []
    for name_index, k in enumerate(order):
        position = [float(_ds(v)) for v in ORIGIN_LPS + k * SLICE_GAP * normal]
        positions.append((k, position))
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = CTImageStorage
        meta.MediaStorageSOPInstanceUID = generate_uid(entropy_srcs=[uid, str(k)])
        meta.TransferSyntaxUID = getattr(pydicom.uid, transfer_syntax)
        ds = Dataset()
        ds.file_meta = meta
        ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
        ds.Modality, ds.PatientName, ds.PatientID = "CT", "Test^Differential", "26"
        ds.StudyInstanceUID, ds.SeriesInstanceUID = f"{uid}.1", f"{uid}.2"
        ds.FrameOfReferenceUID = f"{uid}.3"
        ds.InstanceNumber = name_index + 1
        ds.ImagePositionPatient = [_ds(v) for v in position]
        ds.ImageOrientationPatient = [_ds(v) for v in (*row, *column)]
        ds.PixelSpacing = [_ds(v) for v in PIXEL_SPACING]
        ds.SliceThickness = _ds(SLICE_GAP)
        ds.Rows, ds.Columns = stored.shape[1], stored.shape[2]
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        ds.BitsAllocated, ds.BitsStored, ds.HighBit = 16, bits_stored, bits_stored - 1
        ds.PixelRepresentation = int(stored.dtype.kind == "i")
        if slope is not None:
            ds.RescaleSlope, ds.RescaleIntercept, ds.RescaleType = _ds(slope), _ds(inter), "HU"
        big = transfer_syntax == "ExplicitVRBigEndian"  # pydicom writes Pixel Data's bytes as given
        ds.PixelData = stored[k].astype(stored.dtype.newbyteorder(">" if big else "<")).tobytes()
        ds["PixelData"].VR = "OW"
        ds.save_as(folder / f"IM{name_index:04d}", enforce_file_format=True)
    first = dict(positions)[0]
    matrix = np.eye(4)
    matrix[:3, :3] = LPS @ np.column_stack(
        [row * PIXEL_SPACING[1], column * PIXEL_SPACING[0], np.asarray(dict(positions)[1]) - first]
    )
    matrix[:3, 3] = LPS @ np.asarray(first)
    return matrix


def _read_dicom(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """pydicom's reading: the slices sorted by Image Position along the normal of Image Orientation, rescaled."""
    from pydicom.pixels import apply_rescale

    slices = [pydicom.dcmread(path) for path in sorted(folder.iterdir())]
    orientation = np.array([float(v) for v in slices[0].ImageOrientationPatient])
    normal = np.cross(orientation[:3], orientation[3:])
    slices.sort(key=lambda ds: float(np.dot([float(v) for v in ds.ImagePositionPatient], normal)))
    values = np.stack([apply_rescale(ds.pixel_array, ds) for ds in slices])
    positions = np.array([[float(v) for v in ds.ImagePositionPatient] for ds in slices])
    row_spacing, column_spacing = (float(v) for v in slices[0].PixelSpacing)
    matrix = np.eye(4)
    matrix[:3, :3] = LPS @ np.column_stack(
        [orientation[:3] * column_spacing, orientation[3:] * row_spacing, positions[1] - positions[0]]
    )
    matrix[:3, 3] = LPS @ positions[0]
    return values, matrix


def _dicom_case(tmp_path: Path, orientation: str, pixels: str, transfer_syntax: str) -> None:
    dtype, bits_stored, slope, inter = DICOM_PIXELS[pixels]
    stored = _truth(dtype) >> (16 - bits_stored)  # the whole range of the bits stored
    folder = tmp_path / "series"
    matrix = _write_dicom_series(
        folder, stored, DICOM_ORIENTATIONS[orientation], bits_stored, slope, inter, transfer_syntax
    )
    if slope is None:
        truth = stored
    elif slope == int(slope) and inter == int(inter):
        truth = stored.astype(np.int64) * int(slope) + int(inter)
    else:
        truth = stored.astype(np.float64) * slope + inter
    ours = _check(folder, truth, matrix, _read_dicom(folder), rtol=1e-7, atol=1e-5)
    # Integer rescaling gives integers (GDCM widens the type to hold the rescaled range), a fraction floats.
    assert ours.values.dtype.kind == ("f" if truth.dtype.kind == "f" else "i")
    np.testing.assert_allclose(ours.spacing, (PIXEL_SPACING[1], PIXEL_SPACING[0], SLICE_GAP), rtol=0, atol=1e-5)


@pytest.mark.parametrize("pixels", list(DICOM_PIXELS))
@pytest.mark.parametrize("orientation", list(DICOM_ORIENTATIONS))
def test_dicom_series(tmp_path: Path, orientation: str, pixels: str) -> None:
    _dicom_case(tmp_path, orientation, pixels, "ExplicitVRLittleEndian")


@pytest.mark.parametrize(
    "transfer_syntax", ["ImplicitVRLittleEndian", "ExplicitVRBigEndian", "DeflatedExplicitVRLittleEndian"]
)
def test_dicom_transfer_syntaxes(tmp_path: Path, transfer_syntax: str) -> None:
    _dicom_case(tmp_path, "oblique", "int16-slope1", transfer_syntax)


# ---------------------------------------------------------------------------------------------------------------
# MetaImage, written by hand (no independent reader installed): the truth only
# ---------------------------------------------------------------------------------------------------------------

MET_TYPES = {"uint8": "MET_UCHAR", "int8": "MET_CHAR", "int16": "MET_SHORT", "uint16": "MET_USHORT",
             "int32": "MET_INT", "uint32": "MET_UINT", "float32": "MET_FLOAT", "float64": "MET_DOUBLE"}  # fmt: skip


def _write_metaimage(
    path: Path,
    values: np.ndarray,
    ijk_to_ras: np.ndarray,
    *,
    compressed: bool = False,
    msb: bool = False,
    origin_key: str = "Offset",
    element_type: str | None = None,
) -> None:
    """ITK's MetaImage world is LPS: ``Offset`` (or its synonyms ``Origin``, ``Position``) is the LPS position of
    voxel 0, ``TransformMatrix`` lists the LPS direction of each index axis in turn (i, then j, then k),
    ``ElementSpacing`` the spacing along i, j, k."""
    matrix = np.eye(4)
    matrix[:3, :3] = LPS
    matrix = matrix @ ijk_to_ras
    spacing = np.linalg.norm(matrix[:3, :3], axis=0)
    data = values.astype(values.dtype.newbyteorder(">" if msb else "<")).tobytes()
    if compressed:
        data = zlib.compress(data)
    fields = [
        "ObjectType = Image",
        "NDims = 3",
        "BinaryData = True",
        f"BinaryDataByteOrderMSB = {msb}",
        f"CompressedData = {compressed}",
        *([f"CompressedDataSize = {len(data)}"] if compressed else []),
        "TransformMatrix = " + " ".join(repr(float(v)) for v in (matrix[:3, :3] / spacing).T.ravel()),
        f"{origin_key} = " + " ".join(repr(float(v)) for v in matrix[:3, 3]),
        "ElementSpacing = " + " ".join(repr(float(v)) for v in spacing),
        "DimSize = " + " ".join(str(n) for n in values.shape[::-1]),
        f"ElementType = {element_type or MET_TYPES[values.dtype.name]}",
    ]
    if path.suffix == ".mha":
        path.write_bytes(("\n".join([*fields, "ElementDataFile = LOCAL"]) + "\n").encode() + data)
    else:
        data_file = path.with_suffix(".zraw" if compressed else ".raw")
        data_file.write_bytes(data)
        path.write_text("\n".join([*fields, f"ElementDataFile = {data_file.name}"]) + "\n")


def _metaimage_storage_variants() -> list:
    return [
        pytest.param(dtype, suffix, compressed, id=f"{dtype}-{suffix[1:]}-{'zlib' if compressed else 'raw'}")
        for dtype in DTYPES
        for suffix in (".mha", ".mhd")
        for compressed in (False, True)
    ]


@pytest.mark.parametrize(("dtype", "suffix", "compressed"), _metaimage_storage_variants())
def test_metaimage_storage(tmp_path: Path, dtype: str, suffix: str, compressed: bool) -> None:
    truth, matrix = _truth(dtype), _ijk_to_ras(ROTATION)
    path = tmp_path / f"v{suffix}"
    _write_metaimage(path, truth, matrix, compressed=compressed)
    _check(path, truth, matrix, None, rtol=_rtol(dtype), dtype=dtype)


@pytest.mark.parametrize("msb", [False, True], ids=["lsb", "msb"])
@pytest.mark.parametrize("directions", list(DIRECTIONS))
def test_metaimage_geometry(tmp_path: Path, directions: str, msb: bool) -> None:
    truth, matrix = _truth("float32"), _ijk_to_ras(DIRECTIONS[directions])
    path = tmp_path / "v.mha"
    _write_metaimage(path, truth, matrix, msb=msb)
    _check(path, truth, matrix, None, rtol=1e-6, dtype="float32")


@pytest.mark.parametrize("origin_key", ["Origin", "Position"])
def test_metaimage_origin_synonyms(tmp_path: Path, origin_key: str) -> None:
    truth, matrix = _truth("int16"), _ijk_to_ras(ROTATION)
    path = tmp_path / "v.mha"
    _write_metaimage(path, truth, matrix, origin_key=origin_key)
    _check(path, truth, matrix, None, dtype="int16")


@pytest.mark.parametrize(("element_type", "dtype"), [("MET_LONG", "int32"), ("MET_ULONG", "uint32")])
def test_metaimage_long_is_32_bits(tmp_path: Path, element_type: str, dtype: str) -> None:
    """MetaIO's MET_LONG and MET_ULONG are 4 bytes (MET_ValueTypeSize), whatever C's long is."""
    truth, matrix = _truth(dtype), _ijk_to_ras(ROTATION)
    path = tmp_path / "v.mha"
    _write_metaimage(path, truth, matrix, element_type=element_type)
    _check(path, truth, matrix, None, dtype=dtype)


# ---------------------------------------------------------------------------------------------------------------
# TIFF, written with tifffile or Pillow, read back with Pillow (ours reads with tifffile: Pillow's libtiff decoder is
# the independent one)
# ---------------------------------------------------------------------------------------------------------------

#: (dtype, byte order) written by tifffile that Pillow cannot open: it has no 64-bit float and no big-endian 32-bit
#: unsigned mode. Those are checked against the truth only (the test asserts that Pillow still fails on them).
PILLOW_CANNOT = {("float64", "<"), ("float64", ">"), ("uint32", ">")}
#: A resolution in pixels per centimetre (ResolutionUnit 3): ITK's spacing 10 / 20 = 0.5 mm along i, 0.25 along j.
TIFF_CM = {"resolution": (20.0, 40.0), "resolutionunit": "CENTIMETER"}


def _tiff_matrix(spacing: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """Where Slicer puts a TIFF's voxels: ITK's TIFFImageIO gives origin 0 and identity directions in LPS, so in RAS
    i points left and j posterior; the spacing along k (pages, planes) is 1."""
    return np.diag([-spacing[0], -spacing[1], 1.0, 1.0])


def _itk_tiff_spacing(x_resolution, y_resolution, unit) -> tuple[float, float]:
    """ITK's TIFFImageIO spacing rule, written again from its source: with a ResolutionUnit of 2 (inch) 25.4 mm
    over the resolution, of 3 (centimetre) 10 mm over it; no unit tag, unit 1, or a resolution not above 0: 1."""
    x = float(x_resolution) if x_resolution is not None else 1.0
    y = float(y_resolution) if y_resolution is not None else 1.0
    per_unit = {2: 25.4, 3: 10.0}.get(int(unit) if unit is not None else 1)
    if per_unit is None or x <= 0 or y <= 0:
        return 1.0, 1.0
    return per_unit / float(np.float32(x)), per_unit / float(np.float32(y))


def _read_tiff_pillow(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Pillow's reading of a multi-page TIFF file or a folder of planes: every frame in turn (K, J, I), and the
    geometry of the ITK rule from the tags Pillow gives.

    Where Pillow's mode loses the stored type, the frames are taken as the stored bytes the TIFF tags describe
    (``SampleFormat`` 2 is signed, 1 unsigned; TIFF 6.0): Pillow reads signed 8-bit samples as ``L`` (uint8) and
    unsigned 32-bit samples as ``I`` (int32). Ours reads the stored type, as ITK's reader (``CHAR`` for signed 8-bit).
    """
    from PIL import Image, ImageSequence

    files = sorted(path.iterdir()) if path.is_dir() else [path]  # the planes are named z000, z001, ...
    frames, first = [], None
    for file in files:
        with Image.open(file) as image:
            for frame in ImageSequence.Iterator(image):
                tags = dict(frame.tag_v2)
                first = first or tags
                values = np.array(frame)
                signed, bits = _first(tags.get(339, 1)) == 2, _first(tags.get(258, 8))
                if signed and values.dtype == np.uint8:
                    values = values.view(np.int8)
                elif not signed and bits == 32 and values.dtype == np.int32:
                    values = values.view(np.uint32)
                frames.append(values)
    spacing = _itk_tiff_spacing(first.get(282), first.get(283), first.get(296))
    return np.stack(frames), _tiff_matrix(spacing)


def _first(value):
    """The first of a TIFF tag's values (Pillow gives a tag of one value per sample as a tuple)."""
    return value[0] if isinstance(value, tuple) else value


def _write_tiff_pillow(path: Path, values: np.ndarray, **options) -> None:
    """A multi-page TIFF written by Pillow (``compression``: ``"packbits"``, ``"tiff_lzw"``, ...), no resolution tag."""
    from PIL import Image

    images = [Image.fromarray(plane) for plane in values]
    images[0].save(path, save_all=True, append_images=images[1:], **options)


def _tiff_variants() -> list:
    return [
        pytest.param(dtype, order, id=f"{dtype}-{'big' if order == '>' else 'little'}")
        for dtype in DTYPES
        for order in ("<", ">")
        if np.dtype(dtype).itemsize > 1 or order == "<"
    ]


@pytest.mark.parametrize(("dtype", "order"), _tiff_variants())
def test_tiff_storage(tmp_path: Path, dtype: str, order: str) -> None:
    """Every dtype in both byte orders, one page per plane, the resolution in pixels per centimetre."""
    tifffile = pytest.importorskip("tifffile")
    truth, path = _truth(dtype), tmp_path / "v.tif"
    tifffile.imwrite(path, truth, byteorder=order, photometric="minisblack", **TIFF_CM)
    with tifffile.TiffFile(path) as tiff:
        assert tiff.byteorder == order and len(tiff.pages) == SHAPE[0] and tiff.pages[0].dtype == np.dtype(dtype)
    if (dtype, order) in PILLOW_CANNOT:
        with pytest.raises(Exception, match="cannot identify image file"):
            _read_tiff_pillow(path)
        independent = None
    else:
        independent = _read_tiff_pillow(path)
    _check(path, truth, _tiff_matrix((0.5, 0.25)), independent, rtol=_rtol(dtype), dtype=dtype)


#: name -> (writer, options): compressions tifffile decodes without imagecodecs (zlib and Adobe deflate, with the
#: horizontal predictor too, LZMA, PackBits), and tiled pages. ITK reads tiled pages as 8-bit RGBA (TIFFReadRGBAImage):
#: ours, tifffile and Pillow read the stored values, which is what the file holds.
TIFF_COMPRESSIONS = {
    "none": ("tifffile", {}),
    "zlib": ("tifffile", {"compression": "zlib"}),
    "zlib-predictor": ("tifffile", {"compression": "zlib", "predictor": True}),
    "deflate": ("tifffile", {"compression": "deflate"}),
    "lzma": ("tifffile", {"compression": "lzma"}),
    "packbits": ("pillow", {"compression": "packbits"}),
    "tiled": ("tifffile", {"tile": (16, 16)}),
    "tiled-zlib": ("tifffile", {"tile": (16, 16), "compression": "zlib"}),
}


@pytest.mark.parametrize(
    ("compression", "dtype"),
    [
        pytest.param(compression, dtype, id=f"{compression}-{dtype}")
        for compression in TIFF_COMPRESSIONS
        for dtype in ("uint16", "float32")
        if not (compression == "zlib-predictor" and dtype == "float32")  # its predictor 3 needs imagecodecs
    ],
)
def test_tiff_compressions(tmp_path: Path, compression: str, dtype: str) -> None:
    tifffile = pytest.importorskip("tifffile")
    writer, options = TIFF_COMPRESSIONS[compression]
    truth, path = _truth(dtype), tmp_path / "v.tif"
    if writer == "pillow":
        _write_tiff_pillow(path, truth, **options)
    else:
        tifffile.imwrite(path, truth, photometric="minisblack", **options)
    with tifffile.TiffFile(path) as tiff:
        expected = {"none": "NONE", "tiled": "NONE", "deflate": "DEFLATE", "packbits": "PACKBITS", "lzma": "LZMA"}
        assert tiff.pages[0].compression.name == expected.get(compression, "ADOBE_DEFLATE")
        assert tiff.pages[0].is_tiled == compression.startswith("tiled")
    # tifffile writes 1 pixel per unit NONE, Pillow no resolution: spacing 1 either way
    _check(path, truth, _tiff_matrix(), _read_tiff_pillow(path), rtol=_rtol(dtype), dtype=dtype)


#: name -> (tifffile's resolution and resolutionunit, or None for Pillow's file without resolution tags; the spacing
#: along i and j Slicer gives it).
TIFF_RESOLUTIONS = {
    "no-tags": (None, (1.0, 1.0)),
    "unit-none": ({"resolution": (2.0, 4.0), "resolutionunit": "NONE"}, (1.0, 1.0)),  # ImageJ's pixels per micron
    "inch": ({"resolution": (2.5, 4.0), "resolutionunit": "INCH"}, (10.16, 6.35)),
    "inch-300-dpi": ({"resolution": (300.0, 300.0), "resolutionunit": "INCH"}, (25.4 / 300, 25.4 / 300)),
    "centimetre": (TIFF_CM, (0.5, 0.25)),
    "centimetre-fraction": ({"resolution": ((1000, 3), (7, 2)), "resolutionunit": "CENTIMETER"}, (0.03, 20 / 7)),
}


@pytest.mark.parametrize("resolution", list(TIFF_RESOLUTIONS))
def test_tiff_resolution_gives_the_spacing_slicer_gives(tmp_path: Path, resolution: str) -> None:
    """Slicer's spacing of a TIFF comes from the first page's XResolution, YResolution and ResolutionUnit (ITK's
    rule, :func:`_itk_tiff_spacing`); the spacing ImageJ writes into its description (unit NONE) is not read."""
    tifffile = pytest.importorskip("tifffile")
    options, spacing = TIFF_RESOLUTIONS[resolution]
    truth, path = _truth("uint16"), tmp_path / "v.tif"
    if options is None:
        _write_tiff_pillow(path, truth)
    else:
        tifffile.imwrite(path, truth, photometric="minisblack", **options)
    with tifffile.TiffFile(path) as tiff:
        assert ("XResolution" in tiff.pages[0].tags) == (options is not None)
    _check(path, truth, _tiff_matrix(spacing), _read_tiff_pillow(path), atol=1e-6, dtype="uint16")


def _write_tiff_planes(folder: Path, values: np.ndarray, **options) -> None:
    """One single-plane TIFF a slice, named so that text order and natural order agree (z000, z001, ...)."""
    tifffile = pytest.importorskip("tifffile")
    folder.mkdir()
    for k, plane in enumerate(values):
        tifffile.imwrite(folder / f"z{k:03d}.tif", plane, photometric="minisblack", **options)


#: name -> how the stack is laid out: one multi-page file (tifffile's shaped series, plain pages without a
#: description, an ImageJ hyperstack) or a folder of single-plane files; rows stored bottom to top (Orientation 4).
TIFF_LAYOUTS = ["shaped", "plain-pages", "imagej", "folder", "bottom-left", "folder-bottom-left"]


@pytest.mark.parametrize("layout", TIFF_LAYOUTS)
def test_tiff_layouts(tmp_path: Path, layout: str) -> None:
    """Rows stored bottom to top (Orientation 4): ITK puts the file's last row at j = 0, and so does Pillow's
    libtiff decoder; tifffile alone would not, so ours flips them."""
    tifffile = pytest.importorskip("tifffile")
    truth = _truth("int16")
    bottom_left = {"extratags": [(274, "H", 1, 4, False)]} if layout.endswith("bottom-left") else {}
    stored = truth[:, ::-1, :] if bottom_left else truth  # what the file holds, its first row first
    path = tmp_path / ("planes" if layout.startswith("folder") else "v.tif")
    if layout.startswith("folder"):
        _write_tiff_planes(path, stored, **TIFF_CM, **bottom_left)
    else:
        options = {"plain-pages": {"metadata": None}, "imagej": {"imagej": True}}.get(layout, {})
        tifffile.imwrite(path, stored, photometric="minisblack", **TIFF_CM, **options, **bottom_left)
    with tifffile.TiffFile(sorted(path.iterdir())[0] if path.is_dir() else path) as tiff:
        assert tiff.pages[0].tags.valueof("Orientation", 1) == (4 if bottom_left else 1)
        np.testing.assert_array_equal(tiff.pages[0].asarray(), stored[0])
    _check(path, truth, _tiff_matrix((0.5, 0.25)), _read_tiff_pillow(path), dtype="int16")


def _refused_line(path: Path, tmp_path: Path, capfd) -> str:
    """The one error line of ``isosimtf PATH -o OUT --no-render -q`` refusing its input (exit 2)."""
    from isosimtf import cli

    code = cli.main([str(path), "-o", str(tmp_path / "out"), "--no-render", "-q"])
    err = capfd.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("isosimtf: error: Cannot read "), err
    return err


def _tiff_refused_case(path: Path, case: str) -> None:
    tifffile = pytest.importorskip("tifffile")
    planes = _truth("uint16")
    if case in ("pages-differ-in-size", "pages-differ-in-type"):
        other = planes[0, :4] if case.endswith("size") else planes[0].astype(np.float32)
        with tifffile.TiffWriter(path) as writer:
            for plane in (*planes, other):
                writer.write(plane, photometric="minisblack", metadata=None)
    elif case == "planes-differ-in-type":
        _write_tiff_planes(path, planes)
        tifffile.imwrite(path / "z999.tif", planes[0].astype(np.int16), photometric="minisblack")
    elif case == "two-series":
        with tifffile.TiffWriter(path) as writer:
            writer.write(planes[:2], photometric="minisblack")
            writer.write(planes[2:4], photometric="minisblack")
    elif case == "rgb":
        tifffile.imwrite(path, np.stack([planes] * 3, axis=-1).astype(np.uint8), photometric="rgb")
    elif case == "rgba-planar":  # what tifffile wrote for an array of 4 slices unless told minisblack
        tifffile.imwrite(path, planes[:4], photometric="rgb", planarconfig="separate")
    elif case == "palette":
        colours = np.tile(np.arange(256, dtype=np.uint16) * 257, (3, 1))
        tifffile.imwrite(path, planes.astype(np.uint8), photometric="palette", colormap=colours)
    elif case == "orientation-bottom-right":
        tifffile.imwrite(path, planes, photometric="minisblack", extratags=[(274, "H", 1, 3, False)])
    elif case == "lzw":
        _write_tiff_pillow(path, planes, compression="tiff_lzw")


#: name -> what the one line says. Pages or planes that are no slices of one scalar volume, or that tifffile cannot
#: decode without imagecodecs (LZW, the commonest TIFF compression: Slicer reads it).
TIFF_REFUSED = {
    "pages-differ-in-size": "its TIFF pages differ: page 1 is (6, 7) of uint16, page 6 is (4, 7) of uint16",
    "pages-differ-in-type": "its TIFF pages differ: page 1 is (6, 7) of uint16, page 6 is (6, 7) of float32",
    "planes-differ-in-type": "its TIFF planes differ: z000.tif is (6, 7) of uint16, z999.tif is (6, 7) of int16",
    "two-series": "its TIFF pages form 2 separate images (series)",
    "rgb": "it has 3 components per voxel",
    "rgba-planar": "it has 4 components per voxel",
    "palette": "palette (colour-mapped) images",
    "orientation-bottom-right": "its TIFF Orientation is 3",
    "lzw": "its pages are LZW-compressed, which tifffile decodes only with the imagecodecs package",
}


@pytest.mark.parametrize("case", list(TIFF_REFUSED))
def test_tiff_that_is_no_scalar_stack_is_refused_in_one_line(tmp_path: Path, capfd, case: str) -> None:
    if case == "lzw" and importlib.util.find_spec("imagecodecs") is not None:
        pytest.skip("imagecodecs is installed: tifffile decodes LZW")
    path = tmp_path / ("planes" if case.startswith("planes") else "v.tif")
    _tiff_refused_case(path, case)
    assert TIFF_REFUSED[case] in _refused_line(path, tmp_path, capfd)


# ---------------------------------------------------------------------------------------------------------------
# Zarr and OME-Zarr, written with zarr (or by hand), read back chunk by chunk with json and numpy (ours reads with
# zarr and dask: the raw reading below is the independent one)
# ---------------------------------------------------------------------------------------------------------------

#: Zarr v2 and v3 byte codecs the raw reading decodes: the standard library's, and numcodecs' Blosc and Zstd frames.
_ZARR_BYTE_CODECS = ("zlib", "gzip", "blosc", "zstd", "crc32c")


def _zarr_decode_bytes(data: bytes, codec: dict) -> bytes:
    import gzip

    name = codec.get("id") or codec.get("name")
    if name == "zlib":
        return zlib.decompress(data)
    if name == "gzip":
        return gzip.decompress(data)
    if name == "crc32c":
        return data[:-4]  # the checksum after the bytes
    import numcodecs

    return bytes({"blosc": numcodecs.Blosc, "zstd": numcodecs.Zstd}[name]().decode(data))


def _zarr_metadata(folder: Path) -> dict:
    """An array's metadata, v2 (``.zarray``) or v3 (``zarr.json``), as one form: shape, chunk shape, dtype (with its
    byte order), fill value, the key of a chunk, and the decoding of a chunk's bytes into its array."""
    import json

    if (folder / ".zarray").exists():
        meta = json.loads((folder / ".zarray").read_text())
        dtype = np.dtype(meta["dtype"])
        separator = meta.get("dimension_separator", ".")
        codecs = [*(meta.get("filters") or []), *([meta["compressor"]] if meta.get("compressor") else [])]
        assert all(codec["id"] in _ZARR_BYTE_CODECS for codec in codecs), codecs

        def decode(data: bytes, shape: tuple) -> np.ndarray:
            for codec in reversed(codecs):
                data = _zarr_decode_bytes(data, codec)
            return np.frombuffer(data, dtype).reshape(shape, order=meta["order"])

        return {
            "shape": tuple(meta["shape"]),
            "chunks": tuple(meta["chunks"]),
            "dtype": dtype,
            "fill": meta["fill_value"],
            "key": lambda index: separator.join(map(str, index)),
            "decode": decode,
        }
    meta = json.loads((folder / "zarr.json").read_text())
    assert meta["node_type"] == "array" and meta["chunk_grid"]["name"] == "regular"
    encoding = meta["chunk_key_encoding"]
    separator = encoding.get("configuration", {}).get("separator", "/" if encoding["name"] == "default" else ".")
    prefix = ["c"] if encoding["name"] == "default" else []
    dtype = np.dtype(meta["data_type"])
    return {
        "shape": tuple(meta["shape"]),
        "chunks": tuple(meta["chunk_grid"]["configuration"]["chunk_shape"]),
        "dtype": dtype,
        "fill": meta["fill_value"],
        "key": lambda index: separator.join([*prefix, *map(str, index)]) if index else "c",
        "decode": lambda data, shape: _zarr3_decode(data, shape, dtype, meta["codecs"]),
    }


def _zarr3_decode(data: bytes, shape: tuple, dtype: np.dtype, codecs: list) -> np.ndarray:
    """A Zarr v3 chunk: its bytes through the codec chain backwards (bytes -> bytes codecs, then the ``bytes`` codec
    with its byte order, then ``transpose``); a ``sharding_indexed`` chunk is a shard of inner chunks."""
    if codecs[0]["name"] == "sharding_indexed":
        config = codecs[0]["configuration"]
        inner = tuple(config["chunk_shape"])
        grid = tuple(-(-n // c) for n, c in zip(shape, inner))
        index_bytes = int(np.prod(grid)) * 16 + 4 * any(c["name"] == "crc32c" for c in config["index_codecs"])
        assert config["index_location"] == "end"
        index = np.frombuffer(data[len(data) - index_bytes :][: int(np.prod(grid)) * 16], "<u8").reshape((*grid, 2))
        shard = np.zeros(shape, dtype)  # an inner chunk left out (offset and size 2^64 - 1) is the fill value, 0 here
        for position in np.ndindex(*grid):
            offset, count = (int(v) for v in index[position])
            if offset == 2**64 - 1:
                continue
            part = tuple(slice(p * c, (p + 1) * c) for p, c in zip(position, inner))
            shard[part] = _zarr3_decode(data[offset : offset + count], inner, dtype, config["codecs"])
        return shard
    order = None
    for codec in reversed(codecs):
        name, config = codec["name"], codec.get("configuration", {})
        if name == "bytes":
            data = np.frombuffer(data, dtype.newbyteorder("<" if config.get("endian", "little") == "little" else ">"))
        elif name == "transpose":
            order = tuple(config["order"])
        else:
            assert name in _ZARR_BYTE_CODECS, name
            data = _zarr_decode_bytes(data, codec)
    if order is None:
        return data.reshape(shape)
    return data.reshape(tuple(shape[a] for a in order)).transpose(np.argsort(order))


def _read_zarr_raw(folder: Path) -> np.ndarray:
    """The array of a Zarr v2 or v3 store, read chunk file by chunk file; a chunk that is missing is its fill value
    (the Zarr specification)."""
    meta = _zarr_metadata(folder)
    shape, chunks = meta["shape"], meta["chunks"]
    values = np.full(shape, meta["fill"], meta["dtype"])
    for index in np.ndindex(*(-(-n // c) for n, c in zip(shape, chunks))):
        file = folder / meta["key"](index)
        if not file.exists():
            continue
        chunk = meta["decode"](file.read_bytes(), chunks)
        part = tuple(slice(i * c, min((i + 1) * c, n)) for i, c, n in zip(index, chunks, shape))
        values[part] = chunk[tuple(slice(0, p.stop - p.start) for p in part)]
    return values


def _zarr_codecs(zarr_format: int, compressor: str) -> dict:
    """zarr.create_array's options for a named compressor in a format."""
    import numcodecs
    from zarr.codecs import BloscCodec, GzipCodec, ZstdCodec

    if compressor == "none":
        return {"compressors": None}
    if zarr_format == 2:
        codec = {
            "zlib": numcodecs.Zlib(level=1),
            "gzip": numcodecs.GZip(),
            "zstd": numcodecs.Zstd(),
            "blosc-lz4": numcodecs.Blosc(cname="lz4", shuffle=numcodecs.Blosc.SHUFFLE),
            "blosc-zstd-bitshuffle": numcodecs.Blosc(cname="zstd", shuffle=numcodecs.Blosc.BITSHUFFLE),
        }
    else:
        codec = {
            "gzip": GzipCodec(),
            "zstd": ZstdCodec(),
            "blosc-lz4": BloscCodec(cname="lz4", shuffle="shuffle"),
            "blosc-zstd-bitshuffle": BloscCodec(cname="zstd", shuffle="bitshuffle"),
        }
    return {"compressors": codec[compressor]}


#: A Zarr array has no geometry: spacing 1, origin 0, its axes (z, y, x) taken as RAS (k, j, i).
ZARR_MATRIX = np.eye(4)


def _write_zarr(path: Path, values: np.ndarray, zarr_format: int, **options) -> None:
    zarr = pytest.importorskip("zarr")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # zarr's note that v2 stores are not the newest format
        zarr.create_array(str(path), data=values, zarr_format=zarr_format, **options)


def _zarr_storage_variants() -> list:
    cases = [
        pytest.param(
            zarr_format, dtype, "zstd" if zarr_format == 3 else "zlib", (2, 4, 3), id=f"v{zarr_format}-{dtype}"
        )
        for zarr_format in (2, 3)
        for dtype in (*DTYPES, "int64", "float16")
    ]
    compressors = ("none", "zlib", "gzip", "zstd", "blosc-lz4", "blosc-zstd-bitshuffle")
    cases += [
        pytest.param(zarr_format, "int16", compressor, (2, 4, 3), id=f"v{zarr_format}-{compressor}")
        for zarr_format in (2, 3)
        for compressor in compressors
        if not (zarr_format == 3 and compressor == "zlib")  # v3 has no zlib codec
    ]
    chunkings = {
        "one-chunk": SHAPE,
        "one-plane-a-chunk": (1, SHAPE[1], SHAPE[2]),
        "larger-than-the-array": (8, 8, 8),
        "single-voxels": (1, 1, 1),
        "uneven": (3, 5, 4),
    }
    cases += [
        pytest.param(zarr_format, "uint16", "gzip", chunks, id=f"v{zarr_format}-chunks-{name}")
        for zarr_format in (2, 3)
        for name, chunks in chunkings.items()
    ]
    return cases


@pytest.mark.parametrize(("zarr_format", "dtype", "compressor", "chunks"), _zarr_storage_variants())
def test_zarr_storage(tmp_path: Path, zarr_format: int, dtype: str, compressor: str, chunks: tuple) -> None:
    """Every dtype (int64 and float16 too), compressor and chunking, in both formats."""
    truth, path = _truth(dtype), tmp_path / "v.zarr"
    _write_zarr(path, truth, zarr_format, chunks=chunks, **_zarr_codecs(zarr_format, compressor))
    _check(path, truth, ZARR_MATRIX, (_read_zarr_raw(path), ZARR_MATRIX), rtol=_rtol(dtype), dtype=dtype)


#: name -> (format, zarr.create_array options): byte orders, Fortran order and transposed chunks, chunk key
#: encodings, shards.
ZARR_LAYOUTS = {
    "v2-big-endian": (2, {"dtype": ">i2"}),
    "v2-fortran-order": (2, {"order": "F"}),
    "v2-nested-keys": (2, {"chunk_key_encoding": {"name": "v2", "separator": "/"}}),
    "v3-big-endian": (3, {"serializer": "big-endian"}),
    "v3-transposed": (3, {"filters": "transpose"}),
    "v3-dotted-keys": (3, {"chunk_key_encoding": {"name": "default", "separator": "."}}),
    "v3-v2-keys": (3, {"chunk_key_encoding": {"name": "v2", "separator": "."}}),
    "v3-sharded": (3, {"shards": (4, 6, 8)}),
}


@pytest.mark.parametrize("layout", list(ZARR_LAYOUTS))
def test_zarr_layouts(tmp_path: Path, layout: str) -> None:
    from zarr.codecs import BytesCodec, TransposeCodec

    zarr_format, options = ZARR_LAYOUTS[layout]
    options = dict(options)
    truth, path = _truth("int16"), tmp_path / "v.zarr"
    if options.get("serializer") == "big-endian":
        options["serializer"] = BytesCodec(endian="big")
    if options.get("filters") == "transpose":
        options["filters"] = [TransposeCodec(order=(2, 0, 1))]
    stored = truth.astype(options.pop("dtype")) if "dtype" in options else truth
    _write_zarr(path, stored, zarr_format, chunks=(2, 3, 4), **options)
    _check(path, truth, ZARR_MATRIX, (_read_zarr_raw(path), ZARR_MATRIX), dtype="int16")


@pytest.mark.parametrize("zarr_format", [2, 3])
def test_zarr_missing_chunks_are_the_fill_value(tmp_path: Path, zarr_format: int) -> None:
    zarr = pytest.importorskip("zarr")
    truth, path = _truth("int16"), tmp_path / "v.zarr"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        array = zarr.create_array(
            str(path), shape=SHAPE, chunks=(2, 3, 4), dtype="int16", fill_value=-77, zarr_format=zarr_format
        )
    array[:2] = truth[:2]  # the chunks of the first two planes only
    truth = truth.copy()
    truth[2:] = -77
    _check(path, truth, ZARR_MATRIX, (_read_zarr_raw(path), ZARR_MATRIX), dtype="int16")


def test_zarr_written_by_hand(tmp_path: Path) -> None:
    """A v2 store written from the specification alone (json and raw chunk bytes, big-endian, Fortran order, nested
    keys, one chunk left out): no zarr writer involved."""
    import json

    truth, path = _truth("int32"), tmp_path / "v.zarr"
    chunks = (2, 4, 5)
    path.mkdir()
    meta = {
        "zarr_format": 2,
        "shape": list(SHAPE),
        "chunks": list(chunks),
        "dtype": ">i4",
        "compressor": None,
        "fill_value": 7,
        "order": "F",
        "filters": None,
        "dimension_separator": "/",
    }
    (path / ".zarray").write_text(json.dumps(meta))
    expected = truth.copy()
    for index in np.ndindex(*(-(-n // c) for n, c in zip(SHAPE, chunks))):
        part = tuple(slice(i * c, (i + 1) * c) for i, c in zip(index, chunks))
        if index == (1, 1, 0):
            expected[part] = 7
            continue
        chunk = np.full(chunks, 7, ">i4")  # edge chunks are stored whole, padded with the fill value
        block = truth[part]
        chunk[tuple(slice(0, n) for n in block.shape)] = block
        file = path.joinpath(*map(str, index))
        file.parent.mkdir(parents=True, exist_ok=True)
        file.write_bytes(chunk.tobytes(order="F"))
    _check(path, expected, ZARR_MATRIX, (_read_zarr_raw(path), ZARR_MATRIX), dtype="int32")


# OME-Zarr ---------------------------------------------------------------------------------------------------------

#: Axis name -> OME type.
_OME_TYPES = {"t": "time", "c": "channel", "z": "space", "y": "space", "x": "space"}
_OME_UNIT_MM = {"millimeter": 1.0, "micrometer": 1e-3, "nanometer": 1e-6, "centimeter": 10.0, None: 1.0}


def _write_ome_zarr(path: Path, levels: dict[str, np.ndarray], multiscale: dict, zarr_format: int = 2) -> None:
    """An OME-Zarr image: ``levels`` (path -> array, in the order of ``multiscale['datasets']``), NGFF 0.4 in a v2
    store, 0.5 (the attributes under ``ome``) in a v3 store."""
    zarr = pytest.importorskip("zarr")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        group = zarr.open_group(str(path), mode="w", zarr_format=zarr_format)
        for name, values in levels.items():
            group.create_array(name, data=values, chunks=tuple(max(1, n // 2) for n in values.shape))
        if zarr_format == 2:
            group.attrs["multiscales"] = [{"version": "0.4", **multiscale}]
        else:
            group.attrs["ome"] = {"version": "0.5", "multiscales": [multiscale]}


def _read_ome_raw(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """An OME-Zarr image read from its json and chunk files: level 0 (the first dataset), its leading axes of one
    element (t, c) dropped, and the IJK-to-world matrix of the specification: the level's transformations, then the
    image's, each a scale then a translation, on the last three axes (z, y, x), in millimetres."""
    import json

    meta = json.loads((path / (".zattrs" if (path / ".zattrs").exists() else "zarr.json")).read_text())
    attrs = meta.get("attributes", meta)
    multiscale = (attrs.get("ome", attrs))["multiscales"][0]
    dataset = multiscale["datasets"][0]
    values = _read_zarr_raw(path / dataset["path"])
    values = values.reshape(values.shape[-3:])
    transform = np.eye(4)  # index (i, j, k) -> (x, y, z), in the axes' unit
    for step in [*dataset.get("coordinateTransformations", []), *multiscale.get("coordinateTransformations", [])]:
        vector = np.asarray(step[step["type"]], float)[-3:][::-1]  # z, y, x -> x, y, z
        matrix = np.eye(4)
        if step["type"] == "scale":
            matrix[:3, :3] = np.diag(vector)
        else:
            matrix[:3, 3] = vector
        transform = matrix @ transform
    units = [axis.get("unit") for axis in multiscale["axes"]][-3:][::-1]
    return values, np.diag([*(_OME_UNIT_MM[u] for u in units), 1.0]) @ transform


def _ome_axes(names: str, unit: str | None = "millimeter") -> list[dict]:
    return [
        {"name": n, "type": _OME_TYPES[n], **({"unit": unit} if unit and _OME_TYPES[n] == "space" else {})}
        for n in names
    ]


def _scale(axes: str, zyx: tuple) -> dict:
    return {"type": "scale", "scale": [1.0] * (len(axes) - 3) + list(zyx)}


def _translation(axes: str, zyx: tuple) -> dict:
    return {"type": "translation", "translation": [0.0] * (len(axes) - 3) + list(zyx)}


@pytest.mark.parametrize("zarr_format", [2, 3], ids=["ngff-0.4", "ngff-0.5"])
@pytest.mark.parametrize("axes", ["zyx", "czyx", "tzyx", "tczyx"])
def test_ome_zarr_axes_and_levels(tmp_path: Path, axes: str, zarr_format: int) -> None:
    """Leading time and channel axes of one element, three levels with their own scale and translation, and the
    image's own scale and translation after them: level 0 is read, placed by its transformations then the image's.
    The levels' paths are not "0", "1": the first dataset is level 0 whatever its name."""
    truth = _truth("uint16")
    lead = (1,) * (len(axes) - 3)
    levels = {
        "full": truth.reshape(lead + SHAPE),
        "half": truth[::2, ::2, ::2].reshape(lead + truth[::2, ::2, ::2].shape),
        "quarter": truth[::4, ::4, ::4].reshape(lead + truth[::4, ::4, ::4].shape),
    }
    level_scales = {"full": (2.0, 0.5, 0.25), "half": (4.0, 1.0, 0.5), "quarter": (8.0, 2.0, 1.0)}
    multiscale = {
        "axes": _ome_axes(axes),
        "datasets": [
            {
                "path": name,
                "coordinateTransformations": [
                    _scale(axes, level_scales[name]),
                    _translation(axes, (10.0, -20.0, 30.5)),
                ],
            }
            for name in levels
        ],
        "coordinateTransformations": [_scale(axes, (3.0, 3.0, 3.0)), _translation(axes, (-100.0, 200.0, 300.0))],
    }
    path = tmp_path / "v.ome.zarr"
    _write_ome_zarr(path, levels, multiscale, zarr_format)
    # x = 3 (0.25 i + 30.5) + 300, y = 3 (0.5 j - 20) + 200, z = 3 (2 k + 10) - 100
    matrix = np.diag([0.75, 1.5, 6.0, 1.0])
    matrix[:3, 3] = (391.5, 140.0, -70.0)
    _check(path, truth, matrix, _read_ome_raw(path), dtype="uint16")


@pytest.mark.parametrize("unit", ["millimeter", "micrometer", "nanometer", "centimeter", None])
def test_ome_zarr_units(tmp_path: Path, unit: str | None) -> None:
    """Slicer's world is in millimetres: the axes' unit converts scale and translation (a unit not given is taken as
    millimetres, with a warning)."""
    truth = _truth("int16")
    multiscale = {
        "axes": _ome_axes("zyx", unit),
        "datasets": [
            {
                "path": "0",
                "coordinateTransformations": [_scale("zyx", (4.0, 2.0, 1.0)), _translation("zyx", (8.0, 6.0, 5.0))],
            }
        ],
    }
    path = tmp_path / "v.ome.zarr"
    _write_ome_zarr(path, {"0": truth}, multiscale)
    mm = _OME_UNIT_MM[unit]
    matrix = np.diag([1.0 * mm, 2.0 * mm, 4.0 * mm, 1.0])
    matrix[:3, 3] = np.array([5.0, 6.0, 8.0]) * mm
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _check(path, truth, matrix, _read_ome_raw(path), atol=1e-12, dtype="int16")
    said = [str(w.message) for w in caught if "mm" in str(w.message) or "millimetres" in str(w.message)]
    assert len(said) == (unit != "millimeter"), said


#: name -> (axes, level-0 shape, what the one line says): what ours does not read as a 3-D scalar volume.
OME_REFUSED = {
    "x-y-z-order": ("xyz", SHAPE, "its last three axes are x, y, z"),
    "z-x-y-order": ("zxy", SHAPE, "its last three axes are z, x, y"),
    "two-channels": ("czyx", (2, *SHAPE), "it holds an array of shape (2, 5, 6, 7)"),
    "two-time-points": ("tzyx", (2, *SHAPE), "it holds an array of shape (2, 5, 6, 7)"),
}


@pytest.mark.parametrize("case", list(OME_REFUSED))
def test_ome_zarr_that_is_no_3d_volume_is_refused_in_one_line(tmp_path: Path, capfd, case: str) -> None:
    axes, shape, message = OME_REFUSED[case]
    values = np.arange(int(np.prod(shape)), dtype=np.int16).reshape(shape)
    path = tmp_path / "v.ome.zarr"
    _write_ome_zarr(path, {"0": values}, {"axes": _ome_axes(axes), "datasets": [{"path": "0"}]})
    assert message in _refused_line(path, tmp_path, capfd)


@pytest.mark.parametrize(
    ("dtype", "message"),
    [("complex64", "its voxels are of type complex64"), ("<U3", "its voxels are of type <U3")],
    ids=["complex", "text"],
)
def test_zarr_of_no_numbers_is_refused_in_one_line(tmp_path: Path, capfd, dtype: str, message: str) -> None:
    """Before: a traceback-free but unclear "data type ... not inexact", or numpy's ComplexWarning lines."""
    path = tmp_path / "v.zarr"
    _write_zarr(path, np.arange(210).reshape(SHAPE).astype(dtype), 2, chunks=(2, 3, 4))
    assert message in _refused_line(path, tmp_path, capfd)


def test_zarr_of_booleans_is_read_as_uint8(tmp_path: Path) -> None:
    """As ``.npy`` booleans: 0 and 1 as uint8 (the design needs numbers)."""
    truth, path = (_truth("int16") > 0), tmp_path / "v.zarr"
    _write_zarr(path, truth, 3, chunks=(2, 3, 4))
    _check(path, truth.astype(np.uint8), ZARR_MATRIX, (_read_zarr_raw(path), ZARR_MATRIX), dtype="uint8")


# ---------------------------------------------------------------------------------------------------------------
# VTK image data (.vti), written with VTK's XML writer (or by hand), decoded here from the XML with base64, zlib and
# lzma (ours reads with VTK's XML reader: the decoding below is the independent one)
# ---------------------------------------------------------------------------------------------------------------

_VTK_TYPES = {
    "Int8": "i1",
    "UInt8": "u1",
    "Int16": "i2",
    "UInt16": "u2",
    "Int32": "i4",
    "UInt32": "u4",
    "Int64": "i8",
    "UInt64": "u8",
    "Float32": "f4",
    "Float64": "f8",
}
_VTK_DECOMPRESS = {"vtkZLibDataCompressor": zlib.decompress, "vtkLZMADataCompressor": lzma.decompress}


def _vti_binary(data: bytes, start: int, encoded: bool, header: np.dtype, compressor: str | None) -> bytes:
    """The bytes of one array of a VTK XML file, from ``start`` in ``data`` (the text of an inline array, or the
    appended block): a header of ``header`` integers, one byte count, or with a compressor the block count, block
    size, last block size and each block's compressed size, then the data; base64-encoded when ``encoded``, the
    header of compressed data encoded apart from it."""
    import base64

    def chars(count: int) -> int:  # base64 characters of ``count`` bytes
        return 4 * -(-count // 3)

    size = header.itemsize
    if not encoded:
        raw = data[start:]
        if compressor is None:
            count = int(np.frombuffer(raw[:size], header)[0])
            return raw[size : size + count]
        blocks = int(np.frombuffer(raw[:size], header)[0])
        sizes = np.frombuffer(raw[: (3 + blocks) * size], header)[3:]
        body = raw[(3 + blocks) * size :]
    else:
        text = data[start:].split(b"<", 1)[0].strip()
        if compressor is None:
            raw = base64.b64decode(text)
            count = int(np.frombuffer(raw[:size], header)[0])
            return raw[size : size + count]
        blocks = int(np.frombuffer(base64.b64decode(text[: chars(size)])[:size], header)[0])
        head = chars((3 + blocks) * size)
        sizes = np.frombuffer(base64.b64decode(text[:head]), header)[3:]
        body = base64.b64decode(text[head:])
    ends = np.cumsum(sizes)
    return b"".join(_VTK_DECOMPRESS[compressor](body[e - s : e]) for s, e in zip(sizes, ends))


def _read_vti_raw(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A VTI file decoded from its XML: the point array named ``Scalars`` (else the first), every piece placed in the
    whole extent (K, J, I), and VTK's geometry: index (i, j, k) of the whole extent at ``Origin + Direction @
    (Spacing * (i, j, k))``, ``Direction`` given row by row; so the file's first voxel is at its extent's start."""
    import xml.etree.ElementTree as ElementTree

    data = path.read_bytes()
    head, appended, tail = data.partition(b"<AppendedData")
    root = ElementTree.fromstring(head + (b"</VTKFile>" if appended else b""))
    order = "<" if root.get("byte_order", "LittleEndian") == "LittleEndian" else ">"
    header = np.dtype(order + _VTK_TYPES[root.get("header_type", "UInt32")])
    compressor = root.get("compressor")
    if appended:
        encoding = tail.split(b">", 1)[0]
        block_start = len(head) + len(appended) + tail.index(b"_") + 1
    image = root.find("ImageData")
    whole = [int(v) for v in image.get("WholeExtent").split()]
    shape = tuple(whole[2 * a + 1] - whole[2 * a] + 1 for a in (2, 1, 0))
    values = None
    for piece in image.findall("Piece"):
        extent = [int(v) for v in piece.get("Extent").split()]
        point_data = piece.find("PointData")
        arrays = point_data.findall("DataArray")
        array = next((a for a in arrays if a.get("Name") == point_data.get("Scalars")), arrays[0])
        dtype = np.dtype(order + _VTK_TYPES[array.get("type")])
        if array.get("format") == "ascii":
            flat = np.array(array.text.split(), dtype=np.float64).astype(dtype)
        elif array.get("format") == "binary":
            text = array.text.strip().encode()
            flat = np.frombuffer(_vti_binary(text, 0, True, header, compressor), dtype)
        else:
            start = block_start + int(array.get("offset"))
            flat = np.frombuffer(_vti_binary(data, start, b"base64" in encoding, header, compressor), dtype)
        if values is None:
            values = np.zeros(shape, dtype)
        part = tuple(slice(extent[2 * a] - whole[2 * a], extent[2 * a + 1] - whole[2 * a] + 1) for a in (2, 1, 0))
        values[part] = flat.reshape(tuple(s.stop - s.start for s in part))
    direction = np.array([float(v) for v in image.get("Direction", "1 0 0 0 1 0 0 0 1").split()]).reshape(3, 3)
    spacing = np.array([float(v) for v in image.get("Spacing").split()])
    matrix = _ijk_to_ras(direction, tuple(spacing), tuple(float(v) for v in image.get("Origin").split()))
    matrix[:3, 3] += matrix[:3, :3] @ np.array(whole[::2], float)
    return values, matrix


#: The extent's first index along i, j, k: not 0 (VTK places the first voxel at its extent's start).
VTI_START = (3, -2, 5)


def _vtk_image(values: np.ndarray, directions: np.ndarray = ROTATION, start: tuple = VTI_START):
    """A vtkImageData of ``values`` (K, J, I) as active point scalars, extent from ``start``, rotated frame."""
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonDataModel import vtkImageData

    image = vtkImageData()
    k, j, i = values.shape
    image.SetExtent(start[0], start[0] + i - 1, start[1], start[1] + j - 1, start[2], start[2] + k - 1)
    image.SetSpacing(*SPACING)
    image.SetOrigin(*ORIGIN)
    image.SetDirectionMatrix(*[float(v) for v in np.asarray(directions).ravel()])
    array = numpy_to_vtk(np.ascontiguousarray(values).ravel(), deep=True)
    array.SetName("density")
    image.GetPointData().SetScalars(array)
    return image


def _vti_truth_matrix(directions: np.ndarray = ROTATION, start: tuple = VTI_START) -> np.ndarray:
    """The truth of the geometry, from the image's own numbers: voxel (0, 0, 0) of the file at the extent's start."""
    matrix = _ijk_to_ras(directions)
    matrix[:3, 3] += matrix[:3, :3] @ np.asarray(start, float)
    return matrix


def _write_vti(
    path: Path, image, mode: str, compressor: str = "none", header: str = "UInt32", big_endian: bool = False
) -> None:
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(path))
    writer.SetInputData(image)
    {
        "ascii": writer.SetDataModeToAscii,
        "binary": writer.SetDataModeToBinary,
        "appended-raw": writer.SetDataModeToAppended,
        "appended-base64": writer.SetDataModeToAppended,
    }[mode]()
    writer.SetEncodeAppendedData(mode == "appended-base64")
    {
        "none": writer.SetCompressorTypeToNone,
        "zlib": writer.SetCompressorTypeToZLib,
        "lzma": writer.SetCompressorTypeToLZMA,
    }[compressor]()
    writer.SetBlockSize(64)  # several compressed blocks per array
    getattr(writer, f"SetHeaderTypeTo{header}")()
    (writer.SetByteOrderToBigEndian if big_endian else writer.SetByteOrderToLittleEndian)()
    assert writer.Write()


@pytest.mark.parametrize("dtype", [*DTYPES, "int64", "uint64"])
def test_vti_storage(tmp_path: Path, dtype: str) -> None:
    """Every VTK scalar type (appended raw data, VTK's default), in a rotated frame whose extent starts off 0."""
    truth, path = _truth(dtype), tmp_path / "v.vti"
    _write_vti(path, _vtk_image(truth), "appended-raw")
    _check(path, truth, _vti_truth_matrix(), _read_vti_raw(path), rtol=_rtol(dtype), atol=1e-9, dtype=dtype)


def _vti_encodings() -> list:
    cases = [pytest.param("ascii", "none", "UInt32", False, id="ascii")]
    for mode in ("binary", "appended-raw", "appended-base64"):
        for compressor in ("none", "zlib", "lzma"):
            for header in ("UInt32", "UInt64"):
                for big in (False, True):
                    name = f"{mode}-{compressor}-{header}-{'big' if big else 'little'}"
                    cases.append(pytest.param(mode, compressor, header, big, id=name))
    return cases


@pytest.mark.parametrize(("mode", "compressor", "header", "big_endian"), _vti_encodings())
def test_vti_encodings(tmp_path: Path, mode: str, compressor: str, header: str, big_endian: bool) -> None:
    """ASCII, inline base64, appended raw and base64; no compressor, zlib and LZMA in blocks; 32- and 64-bit
    headers; both byte orders."""
    truth, path = _truth("float32"), tmp_path / "v.vti"
    _write_vti(path, _vtk_image(truth), mode, compressor, header, big_endian)
    text = path.read_bytes()
    assert (b'byte_order="BigEndian"' in text) == big_endian and (compressor == "none") != (b"compressor=" in text)
    _check(
        path,
        truth,
        _vti_truth_matrix(),
        _read_vti_raw(path),
        rtol=1e-6 if mode == "ascii" else 0.0,
        atol=1e-9,
        dtype="float32",
    )


@pytest.mark.parametrize("start", [(0, 0, 0), VTI_START, (-7, -8, -9)], ids=["at-0", "mixed", "negative"])
@pytest.mark.parametrize("directions", ["axis-aligned", "rotated"])
def test_vti_extents_and_directions(tmp_path: Path, directions: str, start: tuple) -> None:
    """VTK's rule for an extent that does not start at 0: the file's first voxel is at origin + direction @ (spacing
    * start), not at the origin (ParaView shows it there; before issue 26 ours put it at the origin)."""
    truth, path = _truth("int16"), tmp_path / "v.vti"
    _write_vti(path, _vtk_image(truth, DIRECTIONS[directions], start), "binary")
    _check(path, truth, _vti_truth_matrix(DIRECTIONS[directions], start), _read_vti_raw(path), atol=1e-9)


def _write_vti_by_hand(
    path: Path,
    pieces: list[tuple[tuple, dict[str, np.ndarray]]],
    scalars: str | None,
    cell_arrays: dict[str, np.ndarray] | None = None,
) -> None:
    """A VTI file written from the format's description alone: ``pieces`` of (extent, point arrays in order),
    ASCII data, ``Scalars`` naming the active array (or none), the whole extent spanning the pieces."""
    types = {v: k for k, v in _VTK_TYPES.items()}
    extents = np.array([extent for extent, _ in pieces])
    whole = [int(extents[:, a].min()) if a % 2 == 0 else int(extents[:, a].max()) for a in range(6)]
    direction = " ".join(repr(float(v)) for v in ROTATION.ravel())

    def arrays_xml(arrays: dict[str, np.ndarray]) -> str:
        return "".join(
            f'<DataArray type="{types[a.dtype.str[1:]]}" Name="{name}" format="ascii" '
            f'NumberOfComponents="{a.shape[-1] if a.ndim == 4 else 1}">{" ".join(map(str, a.ravel().tolist()))}'
            "</DataArray>\n"
            for name, a in arrays.items()
        )

    active = f' Scalars="{scalars}"' if scalars else ""
    body = "".join(
        f'<Piece Extent="{" ".join(map(str, extent))}">\n'
        f"<PointData{active}>\n{arrays_xml(arrays)}</PointData>\n"
        f"<CellData>\n{arrays_xml(cell_arrays or {})}</CellData>\n</Piece>\n"
        for extent, arrays in pieces
    )
    path.write_text(
        '<?xml version="1.0"?>\n<VTKFile type="ImageData" version="1.0" byte_order="LittleEndian">\n'
        f'<ImageData WholeExtent="{" ".join(map(str, whole))}" Origin="{" ".join(map(repr, ORIGIN))}" '
        f'Spacing="{" ".join(map(repr, SPACING))}" Direction="{direction}">\n{body}</ImageData>\n</VTKFile>\n'
    )


def _extent(start: tuple, shape: tuple) -> tuple:
    """A VTK extent (i0, i1, j0, j1, k0, k1) of ``shape`` (K, J, I) from ``start`` (i, j, k)."""
    return tuple(v for a in range(3) for v in (start[a], start[a] + shape[2 - a] - 1))


@pytest.mark.parametrize("scalars", ["density", None], ids=["active-scalars", "no-active-scalars"])
def test_vti_written_by_hand(tmp_path: Path, scalars: str | None) -> None:
    """No VTK writer involved: the arrays ``density`` then ``mask``; with no active scalars named, the first point
    array is read, as VTK's tools take it, with a warning naming it."""
    truth, path = _truth("int16"), tmp_path / "v.vti"
    arrays = {"density": truth, "mask": (truth > 0).astype(np.uint8)}
    _write_vti_by_hand(path, [(_extent(VTI_START, SHAPE), arrays)], scalars)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _check(path, truth, _vti_truth_matrix(), _read_vti_raw(path), atol=1e-9, dtype="int16")
    said = [
        str(w.message) for w in caught if "first point-data array, 'density' (of 2: density, mask)" in str(w.message)
    ]
    assert len(said) == (scalars is None), [str(w.message) for w in caught]


def test_vti_of_two_pieces(tmp_path: Path) -> None:
    """A serial file of two pieces along k: VTK joins them into the whole extent."""
    truth, path = _truth("uint16"), tmp_path / "v.vti"
    first, second = truth[:2], truth[2:]
    start = VTI_START
    pieces = [
        (_extent(start, first.shape), {"density": first}),
        (_extent((start[0], start[1], start[2] + 2), second.shape), {"density": second}),
    ]
    _write_vti_by_hand(path, pieces, "density")
    _check(path, truth, _vti_truth_matrix(), _read_vti_raw(path), atol=1e-9, dtype="uint16")


#: name -> (pieces' point arrays, cell arrays, what the one line says).
VTI_REFUSED = {
    "cell-data-only": ({}, {"density": np.zeros((4, 5, 6), np.int16)}, "the file holds no point scalars"),
    "three-components": ({"rgb": np.zeros((*SHAPE, 3), np.uint8)}, None, "it has 3 components per voxel"),
}


@pytest.mark.parametrize("case", list(VTI_REFUSED))
def test_vti_that_is_no_scalar_volume_is_refused_in_one_line(tmp_path: Path, capfd, case: str) -> None:
    points, cells, message = VTI_REFUSED[case]
    path = tmp_path / "v.vti"
    _write_vti_by_hand(path, [(_extent(VTI_START, SHAPE), points)], None, cells)
    assert message in _refused_line(path, tmp_path, capfd)
