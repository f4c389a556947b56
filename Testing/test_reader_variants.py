"""Valid variants of the input formats that were refused, or read with a plausible wrong geometry (issue 26): NIfTI-2,
NIfTI pairs (``.hdr`` / ``.img``), a VTI without active scalars, OME-Zarr coordinate transformations. Each is
compared with the voxels and geometry it was written with.
"""

import json
from pathlib import Path

import numpy as np
import pytest
from volume_writers import write_nifti

from IsoSimilarityTFLib.errors import VolumeReadError
from isosimtf import cli
from isosimtf.read_errors import VolumeReadWarning
from isosimtf.volume_io import read_volume

zarr = pytest.importorskip("zarr")

#: int16 voxels, a different size along each axis (a transposition cannot pass).
STORED = np.random.default_rng(26).integers(-1000, 3000, size=(5, 6, 7)).astype(np.int16)


def _oblique_ijk_to_ras() -> np.ndarray:
    """Rotated (right-handed), anisotropic voxels and an origin off zero: every part of the geometry counts."""
    a, b = 0.5, 0.3
    rotation = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]) @ np.array(
        [[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]]
    )
    matrix = np.eye(4)
    matrix[:3, :3] = rotation * np.array([0.7, 1.1, 2.5])
    matrix[:3, 3] = (-12.5, 40.25, 7.0)
    return matrix


def _assert_truth(path: Path, values: np.ndarray, ijk_to_ras: np.ndarray) -> None:
    volume = read_volume(path)
    np.testing.assert_array_equal(volume.values, values)
    assert volume.values.dtype == values.dtype
    np.testing.assert_allclose(volume.ijk_to_ras(), ijk_to_ras, atol=1e-5)  # NIfTI-1 holds float32


@pytest.mark.parametrize("name", ["v.nii", "v.nii.gz"])
def test_nifti2_is_read_with_its_voxels_scaling_and_geometry(tmp_path: Path, name: str) -> None:
    ijk_to_ras = _oblique_ijk_to_ras()
    write_nifti(tmp_path / name, STORED, ijk_to_ras, version=2, slope=0.5, inter=-10.0)
    _assert_truth(tmp_path / name, (STORED * 0.5 - 10.0).astype(np.float32), ijk_to_ras)


def test_isosimtf_designs_a_nifti2_volume(tmp_path: Path, capfd) -> None:
    ijk_to_ras = _oblique_ijk_to_ras()
    write_nifti(tmp_path / "v.nii.gz", STORED, ijk_to_ras, version=2)
    assert cli.main([str(tmp_path / "v.nii.gz"), "-o", str(tmp_path / "out"), "--no-render", "-q"]) == 0
    assert capfd.readouterr().err == ""
    read = json.loads((tmp_path / "out" / "classes.json").read_text())["input"]
    np.testing.assert_allclose(read["ijk_to_ras"], ijk_to_ras, atol=1e-5)
    assert (read["dtype"], read["value_min"], read["value_max"]) == ("int16", STORED.min(), STORED.max())


def test_a_nifti2_axis_longer_than_nifti1_holds_is_refused_in_one_line(tmp_path: Path, capfd) -> None:
    write_nifti(tmp_path / "long.nii", np.zeros((2, 2, 40000), np.uint8), np.eye(4), version=2)
    assert cli.main([str(tmp_path / "long.nii"), "-o", str(tmp_path / "out"), "--no-render", "-q"]) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and "40000 x 2 x 2 voxels" in err and "at most 32767" in err, err


@pytest.mark.parametrize("version", [1, 2])
@pytest.mark.parametrize("given", [".hdr", ".img"])
def test_a_nifti_pair_is_read_from_either_file(tmp_path: Path, version: int, given: str) -> None:
    ijk_to_ras = _oblique_ijk_to_ras()
    write_nifti(tmp_path / "v.hdr", STORED, ijk_to_ras, version=version)
    _assert_truth((tmp_path / "v").with_suffix(given), STORED, ijk_to_ras)


@pytest.mark.parametrize(
    ("magic", "given", "removed", "message"),
    [
        (b"\0\0\0\0", "v.hdr", None, "'v.hdr' is an Analyze 7.5 header (no NIfTI magic 'ni1')"),
        (None, "v.img", "v.hdr", "its header 'v.hdr' does not exist"),
        (None, "v.hdr", "v.img", "its voxel file 'v.img' does not exist"),
    ],
)
def test_an_unreadable_pair_is_refused_in_one_line(
    tmp_path: Path, capfd, magic: bytes, given: str, removed: str, message: str
) -> None:
    write_nifti(tmp_path / "v.hdr", STORED, np.eye(4), version=1, magic=magic)
    if removed:
        (tmp_path / removed).unlink()
    assert cli.main([str(tmp_path / given), "-o", str(tmp_path / "out"), "--no-render", "-q"]) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and message in err, err


def _vti_without_active_scalars(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """A VTI whose point data hold ``arrays`` (in order) and name none of them as the scalars."""
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    image = vtkImageData()
    image.SetDimensions(*STORED.shape[::-1])
    image.SetSpacing(0.7, 1.1, 2.5)
    image.SetOrigin(-12.5, 40.25, 7.0)
    for name, values in arrays.items():
        array = numpy_to_vtk(values.ravel(), deep=True)
        array.SetName(name)
        image.GetPointData().AddArray(array)
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(path))
    writer.SetInputData(image)
    assert writer.Write()
    assert 'Scalars="' not in path.read_text(errors="replace")


def test_a_vti_without_active_scalars_is_read_from_its_first_array_with_a_warning(tmp_path: Path) -> None:
    path = tmp_path / "v.vti"
    _vti_without_active_scalars(path, {"density": STORED, "mask": (STORED > 0).astype(np.uint8)})
    said: list[str] = []
    volume = read_volume(path, warn=said.append)
    np.testing.assert_array_equal(volume.values, STORED)
    assert volume.spacing == pytest.approx((0.7, 1.1, 2.5)) and volume.origin == (-12.5, 40.25, 7.0)
    assert said == [
        f"'{path}' names no active point scalars: its first point-data array, 'density' (of 2: density, mask), was read"
    ]
    with pytest.warns(VolumeReadWarning, match="its first point-data array, 'density'"):
        read_volume(path)  # no channel given: Python's warnings


def _ome_zarr(path: Path, multiscale: dict) -> None:
    """An OME-Zarr image of :data:`STORED` at level 0 (axes c, z, y, x), a half-size level 1, and ``multiscale``."""
    group = zarr.open_group(str(path), mode="w")
    group.create_array("0", data=STORED[np.newaxis], chunks=(1, 3, 3, 7))
    group.create_array("1", data=STORED[np.newaxis, ::2, ::2, ::2])
    axes = [{"name": "c", "type": "channel"}] + [{"name": n, "type": "space", "unit": "micrometer"} for n in "zyx"]
    group.attrs["multiscales"] = [{"version": "0.4", "axes": axes, **multiscale}]


def test_ome_zarr_coordinate_transformations_give_spacing_and_origin(tmp_path: Path) -> None:
    def scale(values: list) -> dict:
        return {"type": "scale", "scale": [1.0, *values]}

    def translation(values: list) -> dict:
        return {"type": "translation", "translation": [0.0, *values]}

    # z, y, x in micrometres: level 0 (scale, translation), level 1, then the image's own (scale, translation).
    _ome_zarr(
        tmp_path / "v.ome.zarr",
        {
            "datasets": [
                {"path": "0", "coordinateTransformations": [scale([2.0, 0.5, 0.25]), translation([10.0, 20.0, 30.0])]},
                {"path": "1", "coordinateTransformations": [scale([4.0, 1.0, 0.5]), translation([11.0, 20.5, 30.5])]},
            ],
            "coordinateTransformations": [scale([3.0, 3.0, 3.0]), translation([-100.0, 200.0, 300.0])],
        },
    )
    said: list[str] = []
    volume = read_volume(tmp_path / "v.ome.zarr", warn=said.append)
    np.testing.assert_array_equal(np.asarray(volume.values), STORED)
    # x = 3 (scale_0 i + t_0) + t: spacing 3 scale_0, origin 3 t_0 + t, in millimetres (x, y, z).
    np.testing.assert_allclose(volume.spacing, (0.00075, 0.0015, 0.006))
    np.testing.assert_allclose(volume.origin, (0.39, 0.26, -0.07))
    assert said == [
        f"'{tmp_path / 'v.ome.zarr'}' gives its axes in micrometer: spacing and origin were converted to mm"
    ]


@pytest.mark.parametrize(
    ("multiscale", "message"),
    [
        (
            {"coordinateTransformations": [{"type": "affine", "affine": [[1, 0, 0, 0, 0]] * 4}]},
            "its 'affine' coordinate transformation is not read here",
        ),
        (
            {"coordinateTransformations": [{"type": "scale", "path": "scale.bin"}]},
            "its scale is given in a file ('path')",
        ),
        ({"axes": [{"name": n, "type": "space"} for n in "cxyz"]}, "its last three axes are x, y, z"),
        ({"axes": [{"name": n, "type": t} for n, t in zip("zcyx", ["space", "channel", "space", "space"])]}, "c, y, x"),
        (
            {"coordinateTransformations": [{"type": "scale", "scale": [1.0, 2.0]}]},
            "multiscales metadata is malformed (ValueError: scale [1.0, 2.0] for 4 axes)",
        ),
    ],
)
def test_ome_zarr_geometry_not_read_here_is_refused_in_one_line(
    tmp_path: Path, capfd, multiscale: dict, message: str
) -> None:
    _ome_zarr(tmp_path / "v.ome.zarr", {"datasets": [{"path": "0"}], **multiscale})
    assert cli.main([str(tmp_path / "v.ome.zarr"), "-o", str(tmp_path / "out"), "--no-render", "-q"]) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and message in err, err


@pytest.mark.parametrize("slope, warned", [(0.0, True), (1.0, False)])
def test_a_nifti_with_slope_0_and_an_intercept_says_it_is_read_as_slicer_reads_it(tmp_path, slope, warned):
    """The NIfTI standard (and nibabel) reads scl_slope 0 as "no scaling"; Slicer's reader still adds scl_inter.
    The values follow Slicer; the warning says so, since the result rests on that rule."""
    values = np.arange(4 * 5 * 6, dtype=np.int16).reshape(4, 5, 6)
    path = tmp_path / "v.nii"
    write_nifti(path, values, np.diag([1.0, 1.0, 1.0, 1.0]), version=1, slope=slope, inter=5.0)
    messages = []
    volume = read_volume(path, warn=messages.append)
    np.testing.assert_allclose(np.asarray(volume.values), values + 5.0)  # Slicer's reading, in both cases
    assert any("scl_slope 0" in m and "scl_inter 5" in m for m in messages) is warned


def test_a_met_long_metaimage_reads_lazily_as_32_bit_integers(tmp_path):
    """MetaIO's MET_LONG is 4 bytes (Slicer's reader reads it so); the lazy reader refused it as "not raw"."""
    from isosimtf import chunked_readers, headers

    values = (np.arange(4 * 5 * 6, dtype="<i4") * 1000 - 50_000).reshape(4, 5, 6)
    path = tmp_path / "v.mha"
    text = (
        "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\nCompressedData = False\n"
        "ElementSpacing = 1 1 1\nDimSize = 6 5 4\nElementType = MET_LONG\nElementDataFile = LOCAL\n"
    )
    path.write_bytes(text.encode() + values.tobytes())
    stored = headers.stored_voxels(path)
    assert stored is not None and stored.raw and stored.dtype == np.dtype("<i4")
    np.testing.assert_array_equal(np.asarray(chunked_readers.read_chunked(path, stored).values), values)


def test_a_bzip2_nrrd_is_refused_for_its_encoding_not_as_corrupt(tmp_path):
    nrrd = pytest.importorskip("nrrd")
    path = tmp_path / "v.nrrd"
    nrrd.write(str(path), np.arange(4 * 5 * 6, dtype=np.int16).reshape(6, 5, 4), header={"encoding": "bzip2"})
    with pytest.raises(VolumeReadError, match="cannot decode its encoding") as refused:
        read_volume(path)
    assert "corrupt" not in str(refused.value)
