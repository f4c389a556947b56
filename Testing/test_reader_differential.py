"""Our reader against the truth and against an independent reader, format variant by format variant (issue 26, 4).

Every variant is written with KNOWN voxels and geometry: NRRD with pynrrd, NIfTI-1 with nibabel, a DICOM CT series
with pydicom, MetaImage by hand (no independent MetaImage reader is installed: checked against the truth only). Each
file is read with :func:`isosimtf.volume_io.read_volume` and with the independent reader (pynrrd, nibabel, pydicom),
and three things are checked:

1. our voxels, spacing and IJK-to-RAS matrix are the truth as Slicer shows it: in RAS (NRRD ``left-posterior-superior``,
   MetaImage and DICOM are LPS; NIfTI and NRRD ``right-anterior-superior`` are RAS), and a left-handed index frame
   made right-handed by reversing the slice order (Slicer's ``ForceRightHandedIJKCoordinateSystem``);
2. the independent reader gives the truth in the file's own index order;
3. the two agree voxel for voxel at the same RAS positions (up to that reordering of the slices).

Where Slicer follows a rule of its own (NIfTI sform / qform precedence, below) the rule is named where it is used.

The header round trips (Slicer writes, Slicer reads) are in test_volume_io.py, the lazy path of raw NRRD / MetaImage
in test_header_variants.py; TIFF and Zarr are not here: :func:`read_volume` reads them only lazily, as dask arrays
(``chunked_readers.read_chunked``), which test_chunked_readers.py checks.
"""

from __future__ import annotations

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
        ramp = np.round(np.linspace(float(info.min), float(info.max), n))
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
