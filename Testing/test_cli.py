"""Tests of the ``isosimtf`` command (isosimtf.cli) and its output folder (isosimtf.run, isosimtf.outputs)."""

from __future__ import annotations

import io
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

from test_volume_io import _right_handed, _rotation
from volume_writers import write_volume

import IsoSimilarityTFLib
import isosimtf
from IsoSimilarityTFLib import __version__
from IsoSimilarityTFLib.clustering import unconverged_advice
from IsoSimilarityTFLib.design import Tissue, TransferFunctionDesign, design_transfer_function
from isosimtf import cli, console, figures, formatting, run
from isosimtf.phantom import head_phantom
from isosimtf.rendering import slicer_core_available
from isosimtf.volume_io import Volume

# The folders that hold the two packages, for a subprocess that runs without the editable install.
PACKAGE_DIRS = [Path(package.__file__).resolve().parents[1] for package in (IsoSimilarityTFLib, isosimtf)]

needs_slicer = pytest.mark.skipif(
    not slicer_core_available(), reason="slicer-core (Slicer's Qt-free MRML libraries) is not installed"
)

DESIGN_KEYS = {"value_range", "n_bins", "options", "timings_s", "clustering", "labels", "classes"}
CLASS_KEYS = {
    "id", "rank", "voxels", "fraction", "isovalue_bins", "value_ranges", "exemplar_bin", "color", "opacity",
    "visible", "background",
}  # fmt: skip
DATA_FILES = (
    "similarity.npy", "similarity.png", "classes.json", "transfer_function.vp.json", "transfer_function.vp", "looks.png"
)  # fmt: skip
RENDER_FILES = ("render.png", "classes.png", "scene/scene.mrml")
RENDER_SIZE = 96  # render.png side in the tests (class tiles are half of it): small keeps CPU ray casting fast


def read_png(path: Path) -> np.ndarray:
    """Read a PNG written by the tool as ``(height, width, 3)`` uint8, row 0 at the top."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOImage import vtkPNGReader

    reader = vtkPNGReader()
    if not reader.CanReadFile(str(path)):
        raise OSError(f"not a PNG file: {path}")
    reader.SetFileName(str(path))
    reader.Update()
    image = reader.GetOutput()
    width, height, _ = image.GetDimensions()
    pixels = vtk_to_numpy(image.GetPointData().GetScalars()).reshape(height, width, -1)[::-1]
    return np.ascontiguousarray(pixels[..., :3])


def _small_volume(size: int = 32, left_handed: bool = True) -> Volume:
    """A small head phantom with anisotropic spacing and an oblique orientation (left-handed by default)."""
    directions = _rotation(20.0, 2) @ _rotation(-10.0, 0)
    if left_handed:
        directions[:, 2] *= -1.0
    return Volume(head_phantom(size, seed=3).values, (7.5, 6.5, 8.0), (12.5, -30.0, 4.0), directions, "head")


def _run(argv: list[str], capfd) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    captured = capfd.readouterr()
    return code, captured.out, captured.err


def _load(outdir: Path) -> dict:
    return json.loads((outdir / "classes.json").read_text(encoding="utf-8"))


def _class_signature(document: dict) -> list[tuple]:
    return [
        (c["id"], c["rank"], c["voxels"], tuple(c["isovalue_bins"]), c["background"], c["visible"])
        for c in document["classes"]
    ]


def _points(volume_property) -> tuple[np.ndarray, np.ndarray]:
    """``(P, 4)`` colour points (x, r, g, b) and ``(P, 2)`` opacity points (x, a) of a vtkVolumeProperty."""
    ctf, opacity = volume_property.GetRGBTransferFunction(), volume_property.GetScalarOpacity()
    colors, alphas = [], []
    for index in range(ctf.GetSize()):
        value = [0.0] * 6
        ctf.GetNodeValue(index, value)
        colors.append(value[:4])
    for index in range(opacity.GetSize()):
        value = [0.0] * 4
        opacity.GetNodeValue(index, value)
        alphas.append(value[:2])
    return np.array(colors), np.array(alphas)


def _assert_design_points(volume_property, document: dict) -> None:
    expected = TransferFunctionDesign.from_dict(document).transfer_function()
    colors, alphas = _points(volume_property)
    np.testing.assert_allclose(colors[:, 0], expected.x, rtol=0, atol=1e-6)
    np.testing.assert_allclose(colors[:, 1:], expected.color, rtol=0, atol=1e-6)
    np.testing.assert_allclose(alphas[:, 0], expected.x, rtol=0, atol=1e-6)
    # A volume property keeps its unit distance; the legacy .vp file has none, so its opacities are per mm.
    unit_distance = volume_property.GetScalarOpacityUnitDistance()
    opacity = (
        expected.opacity
        if unit_distance != 1.0
        else 1.0 - (1.0 - expected.opacity) ** (1.0 / document["unit_distance"])
    )
    np.testing.assert_allclose(alphas[:, 1], opacity, rtol=0, atol=1e-6)


# ---------------------------------------------------------------------------------------------------------------
# One rendered run shared by the output tests
# ---------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> Path:
    """Run ``isosimtf head.nrrd -o out --size 96 --quiet`` once (with rendering when slicer-core is present)."""
    folder = tmp_path_factory.mktemp("rendered")
    source = folder / "head.nrrd"
    write_volume(_small_volume(48), source)
    outdir = folder / "out"
    code = cli.main([str(source), "-o", str(outdir), "--size", str(RENDER_SIZE), "--quiet"])
    assert code == 0
    return outdir


def test_outputs_exist_and_follow_the_schema(rendered: Path) -> None:
    for name in DATA_FILES + (RENDER_FILES if slicer_core_available() else ()):
        assert (rendered / name).is_file(), name
    document = _load(rendered)
    assert DESIGN_KEYS <= set(document)
    n_bins = document["n_bins"]
    assert n_bins == 256 and len(document["labels"]) == n_bins
    assert document["value_range"][0] < document["value_range"][1]
    assert {"n_iter", "converged", "n_classes"} <= set(document["clustering"])
    assert document["clustering"]["converged"] is True
    assert document["clustering"]["n_classes"] == len(document["classes"]) >= 2
    stages = {"read", "quantize", "similarity", "clustering", "classes", "write", "total"}
    if slicer_core_available():
        stages.add("render")
    assert stages <= set(document["timings_s"])
    assert all(v >= 0 for v in document["timings_s"].values())
    assert document["options"]["n_bins"] == 256 and document["options"]["crossing"] == "inclusive"
    for item in document["classes"]:
        assert CLASS_KEYS <= set(item)
        assert len(item["color"]) == 3 and 0.0 <= item["opacity"] <= 1.0
    assert sorted(c["rank"] for c in document["classes"]) == list(range(1, len(document["classes"]) + 1))
    assert sum(c["background"] for c in document["classes"]) == 1
    assert abs(sum(c["fraction"] for c in document["classes"]) - 1.0) < 1e-9
    # Input information.
    source = document["input"]
    assert source["path"].endswith("head.nrrd") and source["name"] == "head"
    assert source["shape"] == [48, 48, 48] and source["dimensions"] == [48, 48, 48]
    np.testing.assert_allclose(source["spacing"], (7.5, 6.5, 8.0), atol=1e-6)
    # Slicer's reader gives a left-handed volume a right-handed index frame (slices reversed).
    np.testing.assert_allclose(source["ijk_to_ras"], _right_handed(_small_volume(48)).ijk_to_ras(), atol=1e-5)
    # The look's visibility step ran: each tissue's share of the picture, and the preview to run it again.
    shares = [t["picture_share"] for t in document["tissues"]]
    assert all(s is not None for s in shares) and sum(shares) == pytest.approx(1.0)
    # The design reloads from classes.json.
    design = TransferFunctionDesign.from_dict(document)
    assert [int(v) for v in design.labels] == document["labels"]
    assert design.preview is not None and design.preview.bins.ndim == 3

    similarity = np.load(rendered / "similarity.npy")
    assert similarity.dtype == np.float64 and similarity.shape == (n_bins, n_bins)
    np.testing.assert_allclose(similarity, similarity.T, rtol=0, atol=1e-12)
    assert np.all(np.isfinite(similarity)) and 0.0 <= similarity.min() and similarity.max() <= 1.0 + 1e-12


def test_pictures_are_readable_and_not_blank(rendered: Path) -> None:
    similarity = read_png(rendered / "similarity.png")
    assert similarity.shape[0] == similarity.shape[1] >= 256
    assert similarity.std() > 10
    if not slicer_core_available():
        pytest.skip("slicer-core is not installed: no renders")
    picture = read_png(rendered / "render.png")
    assert picture.shape == (RENDER_SIZE, RENDER_SIZE, 3)
    foreground = np.count_nonzero(picture.max(axis=2) > 20)
    assert 0.05 * picture.shape[0] * picture.shape[1] < foreground < 0.9 * picture.shape[0] * picture.shape[1]
    grid = read_png(rendered / "classes.png")
    shown = [t for t in _load(rendered)["tissues"] if t["visible"] and not t["background"]]
    tile = RENDER_SIZE // 2
    columns = (grid.shape[1] - figures.GRID_GAP) // (tile + figures.GRID_GAP)
    assert columns == math.ceil(math.sqrt(len(shown)))  # a tile a tissue
    assert grid.shape[0] > math.ceil(len(shown) / columns) * tile
    assert np.count_nonzero(grid.max(axis=2) > 200) > 50  # label text


@needs_slicer
def test_vp_json_and_vp_load_into_slicer_property_nodes(rendered: Path) -> None:
    import slicer

    document = _load(rendered)
    node, storage = slicer.vtkMRMLVolumePropertyNode(), slicer.vtkMRMLVolumePropertyJsonStorageNode()
    storage.SetFileName(str(rendered / "transfer_function.vp.json"))
    assert storage.ReadData(node) == 1
    assert node.GetVolumeProperty().GetScalarOpacityUnitDistance() == pytest.approx(document["unit_distance"])
    assert document["unit_distance"] != 1.0  # else the .vp check below would not tell the two apart
    _assert_design_points(node.GetVolumeProperty(), document)
    np.testing.assert_allclose(node.GetEffectiveRange(), document["value_range"], atol=1e-9)

    node, storage = slicer.vtkMRMLVolumePropertyNode(), slicer.vtkMRMLVolumePropertyStorageNode()
    storage.SetFileName(str(rendered / "transfer_function.vp"))
    assert storage.ReadData(node) == 1
    _assert_design_points(node.GetVolumeProperty(), document)


def _assert_same_world_volume(volume_node, expected: Volume) -> None:
    """The node holds ``expected`` at the same place in RAS: voxel for voxel, up to a reordering of the index axes.

    Slicer's NRRD reader turns a left-handed IJK frame into a right-handed one by reversing the slice order, so the
    reloaded IJK-to-RAS matrix may differ from the saved one while every voxel keeps its RAS position and value.
    """
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    matrix = vtkMatrix4x4()
    volume_node.GetIJKToRASMatrix(matrix)
    ijk_to_ras = np.array([[matrix.GetElement(r, c) for c in range(4)] for r in range(4)])
    image = volume_node.GetImageData()
    dims = image.GetDimensions()
    values = vtk_to_numpy(image.GetPointData().GetScalars()).reshape(dims[::-1])
    # Index of the expected volume's voxel at the RAS position of each reloaded voxel: must be a whole index.
    mapping = np.linalg.inv(expected.ijk_to_ras()) @ ijk_to_ras
    np.testing.assert_allclose(mapping, np.round(mapping), atol=1e-4)
    mapping = np.round(mapping).astype(int)
    assert sorted(np.abs(mapping[:3, :3]).sum(axis=0).tolist()) == [1, 1, 1]  # a permutation with flips
    k, j, i = np.indices(dims[::-1]).reshape(3, -1)
    source = mapping @ np.stack([i, j, k, np.ones_like(i)])
    np.testing.assert_array_equal(values.reshape(-1), expected.values[source[2], source[1], source[0]])


@needs_slicer
def test_saved_scene_reloads_with_geometry_and_transfer_function(rendered: Path) -> None:
    from IsoSimilarityTFLib.mrml import design_of
    from isosimtf.rendering import HeadlessSlicer

    document = _load(rendered)
    scene_file = rendered / "scene" / "scene.mrml"
    assert (rendered / "scene" / "Data" / "head.nrrd").is_file()
    with HeadlessSlicer(size=(64, 64)) as headless:
        headless.scene.SetURL(str(scene_file))
        assert headless.scene.Connect() == 1
        volume = headless.scene.GetFirstNodeByName("head")
        assert volume is not None and volume.GetImageData() is not None
        assert volume.GetImageData().GetDimensions() == (48, 48, 48)
        _assert_same_world_volume(volume, _small_volume(48))
        display = headless.volume_rendering_logic.GetFirstVolumeRenderingDisplayNode(volume)
        assert display is not None and display.GetVisibility()
        property_node = display.GetVolumePropertyNode()
        _assert_design_points(property_node.GetVolumeProperty(), document)
        stored = design_of(property_node)
        assert stored is not None and stored.solo_class is None
        assert [int(v) for v in stored.labels] == document["labels"]
        assert headless.render().max() > 20  # the reopened scene renders


# ---------------------------------------------------------------------------------------------------------------
# Inputs
# ---------------------------------------------------------------------------------------------------------------


def _write_dicom_series(volume: Volume, folder: Path) -> None:
    """Write ``volume`` as a CT series with the hand-made DICOM writer of test_volume_io (axial, LPS geometry)."""
    from test_volume_io import _write_dicom_slice

    folder.mkdir()
    values = volume.values.astype(np.int32)
    for k in range(values.shape[0]):
        _write_dicom_slice(
            folder / f"IM{k:04d}",
            (values[k] + 1024).astype(np.int16),
            np.array([0.0, 0.0, 2.0 * k]),
            np.array([1.0, 0.0, 0.0, 0.0, 1.0, 0.0]),
            (1.5, 1.5),
            k + 1,
            -1024.0,
        )


def test_every_input_format_gives_the_same_classes(tmp_path: Path, capfd) -> None:
    # Right-handed: Slicer's reader reverses the slices of a left-handed volume, .npy and .vti readers do not, and the
    # octree tiles from index 0, so a reversed volume has other coarse cells.
    volume = _small_volume(24, left_handed=False)
    sources = []
    for suffix in (".nrrd", ".nhdr", ".mha", ".mhd", ".nii", ".nii.gz", ".vti", ".npy"):
        path = tmp_path / f"head{suffix}"
        write_volume(volume, path)
        sources.append(path)
    try:
        _write_dicom_series(volume, tmp_path / "dicom")
        sources.append(tmp_path / "dicom")
    except ImportError:  # pragma: no cover - test_volume_io's DICOM writer moved
        pass
    reference = None
    for source in sources:
        outdir = tmp_path / f"out-{source.name}"
        code, out, err = _run([source, "-o", outdir, "--no-render", "--quiet"], capfd)
        assert code == 0, err
        assert err == ""
        assert "rank" in out and str(outdir) in out
        document = _load(outdir)
        signature = (document["value_range"], document["labels"], _class_signature(document))
        if reference is None:
            reference = signature
        assert signature == reference, source.name
        assert not (outdir / "render.png").exists()
    assert len(sources) >= 8


def test_phantom_word_and_options_reach_the_design(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    argv = [
        "phantom", "-o", outdir, "--phantom-size", 24, "--seed", 2, "--no-render", "--quiet",
        "--bins", 64, "--range", -1100, 1100, "--crossing", "strict", "--normalization", "ma-entezari",
        "--levels", 3, "--preference", "minimum", "--damping", 0.7, "--max-iter", 400, "--convergence-iter", 20,
        "--max-classes", 3, "--background", "lowest", "--unconverged", "keep",
    ]  # fmt: skip
    code, _, err = _run(argv, capfd)
    assert code == 0, err
    document = _load(outdir)
    options = document["options"]
    assert options["n_bins"] == 64 and options["value_range"] == [-1100.0, 1100.0]
    assert (options["crossing"], options["normalization"], options["levels"]) == ("strict", "ma-entezari", 3)
    assert (options["preference"], options["damping"], options["max_iter"]) == ("minimum", 0.7, 400)
    assert (options["convergence_iter"], options["max_classes"], options["background"]) == (20, 3, "lowest")
    assert options["unconverged"] == "keep"
    assert len(document["labels"]) == 64
    assert sum(c["visible"] for c in document["classes"]) <= 3
    assert document["input"]["path"] == "phantom" and document["input"]["shape"] == [24, 24, 24]
    # A numeric preference is accepted too.
    code, _, err = _run(
        ["phantom", "-o", tmp_path / "num", "--phantom-size", 24, "--no-render", "-q", "--preference", "-0.5"], capfd
    )
    assert code == 0, err
    assert _load(tmp_path / "num")["options"]["preference"] == -0.5


def test_phantom_word_wins_over_a_folder_named_phantom(tmp_path: Path, capfd, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(["phantom", "-o", "phantom", "--phantom-size", 16, "--no-render", "-q"], capfd)
    assert code == 0, err
    assert _load(tmp_path / "phantom")["input"]["path"] == "phantom"
    code, _, err = _run(["./phantom", "-o", "again", "--no-render", "-q"], capfd)
    assert code == 2 and "DICOM" in err  # the path is read as a (non-DICOM) folder


def test_progress_lines_and_summary(tmp_path: Path, capfd) -> None:
    code, out, err = _run(["phantom", "-o", tmp_path / "out", "--phantom-size", 24, "--no-render"], capfd)
    assert code == 0
    lines = err.splitlines()
    total = len(run.STAGES) - 1  # no render stage
    assert [line.split()[0] for line in lines] == [f"[{i}/{total}]" for i in range(1, total + 1)]
    assert [line.split()[1] for line in lines] == list(run.STAGES[:-1])
    document = _load(tmp_path / "out")
    assert "rank" in out and "intensity range(s)" in out and "colour" in out
    assert "background" in out and "affinity propagation" in out
    assert f"{document['clustering']['n_iter']} iterations" in out
    for item in document["classes"]:
        assert formatting.color_hex(item["color"]) in out
    assert "similarity" in out.split("time (s):")[1]
    assert str((tmp_path / "out").resolve()) in out


def test_progress_rewrites_the_line_on_a_terminal() -> None:
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    stream = Terminal()
    printer = console.ProgressPrinter(3, stream=stream)
    printer.stage("similarity")
    printer.update("level 1 of 2")
    printer.update("level 2 of 2")
    printer.stage("clustering")
    printer.finish()
    text = stream.getvalue()
    assert text.count("\n") == 2
    assert "\r\x1b[K[1/3] similarity: level 2 of 2\n[2/3] clustering\n" in text

    quiet = Terminal()
    printer = console.ProgressPrinter(3, stream=quiet, quiet=True)
    printer.stage("read")
    printer.update("x")
    printer.finish()
    assert quiet.getvalue() == ""


def test_version_and_help(capfd) -> None:
    code, out, _ = _run(["--version"], capfd)
    assert code == 0 and out.strip() == f"isosimtf {__version__}"
    code, out, _ = _run(["--help"], capfd)
    assert code == 0
    for option in (
        "--bins",
        "--range",
        "--crossing",
        "--normalization",
        "--levels",
        "--preference",
        "--damping",
        "--max-iter",
        "--convergence-iter",
        "--max-classes",
        "--background",
        "--unconverged",
        "--no-render",
        "--quiet",
        "--view",
        "--size",
        "--phantom-size",
        "--seed",
    ):
        assert option in out


# ---------------------------------------------------------------------------------------------------------------
# Errors: one line, non-zero exit, no traceback
# ---------------------------------------------------------------------------------------------------------------


def _bad_inputs(folder: Path) -> dict[str, Path]:
    corrupt = folder / "corrupt.nrrd"
    corrupt.write_bytes(b"NRRD0004\ntype: short\ndimension: 3\nsizes: 9 7 5\nencoding: gzip\n\nnot gzip data")
    unknown = folder / "scan.xyz"
    unknown.write_bytes(b"hello")
    constant, flat, nan = folder / "constant.npy", folder / "flat.npy", folder / "nan.npy"
    np.save(constant, np.full((8, 8, 8), 7, dtype=np.int16))
    np.save(flat, np.arange(64, dtype=np.float32).reshape(8, 8))
    values = np.arange(512, dtype=np.float32).reshape(8, 8, 8)
    values[3, 4, 5] = np.nan
    np.save(nan, values)
    return {
        "missing": folder / "absent.nrrd",
        "unknown-suffix": unknown,
        "corrupt": corrupt,
        "constant": constant,
        "2-D": flat,
        "NaN": nan,
        "empty-folder": folder,
    }


@pytest.mark.parametrize("case", ["missing", "unknown-suffix", "corrupt", "constant", "2-D", "NaN", "empty-folder"])
def test_bad_input_gives_one_error_line(tmp_path: Path, capfd, case: str) -> None:
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    source = _bad_inputs(inputs)[case]
    if case == "empty-folder":
        source = inputs / "empty"
        source.mkdir()
    code, out, err = _run([source, "-o", tmp_path / "out", "--no-render"], capfd)
    assert code == 2
    errors = [line for line in err.splitlines() if not line.startswith("[")]
    assert len(errors) == 1 and errors[0].startswith("isosimtf: error: "), err
    assert "Traceback" not in err and out == ""
    hints = {
        "missing": "no such file",
        "unknown-suffix": "unsupported",
        "constant": "constant",
        "2-D": "3-D",
        "NaN": "NaN",
        "corrupt": "corrupt.nrrd",
        "empty-folder": "empty",
    }
    assert hints[case] in errors[0]


@pytest.mark.parametrize(
    "options",
    [
        ["--bins", "1"],
        ["--bins", "abc"],
        ["--bins", "100000"],
        ["--range", "5", "1"],
        ["--range", "0"],
        ["--crossing", "sometimes"],
        ["--normalization", "l2"],
        ["--levels", "0"],
        ["--levels", "99"],
        ["--preference", "mean"],
        ["--damping", "2"],
        ["--max-iter", "0"],
        ["--max-classes", "-1"],
        ["--background", "darkest"],
        ["--unconverged", "retry"],
        ["--view", "up"],
        ["--size", "4"],
        ["--phantom-size", "3"],
        ["--seed", "-1"],
        ["--no-such-option"],
    ],
    ids=lambda options: " ".join(options),
)
def test_bad_option_gives_one_error_line(tmp_path: Path, capfd, options: list[str]) -> None:
    code, out, err = _run(
        ["phantom", "-o", tmp_path / "out", "--phantom-size", "16", "--no-render", "-q", *options], capfd
    )
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith("isosimtf: error: "), err
    assert "Traceback" not in err and out == ""


def test_missing_arguments_and_output_file(tmp_path: Path, capfd) -> None:
    for argv in ([], ["phantom"]):
        code, _, err = _run(argv, capfd)
        assert code == 2 and len(err.splitlines()) == 1 and err.startswith("isosimtf: error: ")
    not_a_folder = tmp_path / "file"
    not_a_folder.write_text("x")
    code, _, err = _run(["phantom", "-o", not_a_folder, "--phantom-size", 16, "--no-render"], capfd)
    assert code == 2 and err.strip() == f"isosimtf: error: the output path '{not_a_folder}' is a file, not a folder"


def test_unconverged_affinity_propagation_is_a_processing_error(tmp_path: Path, capfd) -> None:
    argv = [
        "phantom",
        "-o",
        tmp_path / "out",
        "--phantom-size",
        24,
        "--no-render",
        "-q",
        "--max-iter",
        2,
        "--unconverged",
        "error",
    ]
    code, out, err = _run(argv, capfd)
    assert code == 1
    assert len(err.splitlines()) == 1 and err.startswith("isosimtf: error: affinity propagation did not converge")
    assert "Traceback" not in err and out == ""


def test_unconverged_advice_never_suggests_what_was_given(tmp_path: Path, capfd) -> None:
    argv = ["phantom", "-o", tmp_path / "out", "--phantom-size", 24, "--no-render", "-q", "--unconverged", "error"]
    code, _, err = _run([*argv, "--max-iter", 2, "--damping", "0.95"], capfd)
    advice = err.split(";", 1)[1]
    assert code == 1 and "raise --max-iter (e.g. 1000)" in advice and "damping" not in advice
    assert advice.lstrip().startswith("set --preference minimum")  # what works on an oscillating AP, first
    assert "raise max_iter" not in unconverged_advice(100_000, [0.5, 0.7, 0.9])  # the table's largest
    assert "raise max_iter (e.g. 5000)" in unconverged_advice(1000, [0.5])  # before: "e.g. 1000" again
    assert "preference='minimum'" in unconverged_advice(1000, [0.5])  # Python names in Python


# ---------------------------------------------------------------------------------------------------------------
# Issue 11: limits, the output folder (never delete what we did not write), warnings for a useless result
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        (["--size", "40000"], "argument --size: must be from 32 to 4096, got 40000"),  # before: segfault
        (["--phantom-size", "2000"], "argument --phantom-size: must be from 8 to 512, got 2000"),  # before: 111 s
        (["--range", "5000", "6000"], "value_range [5000, 6000] lies outside the volume's values"),  # before: exit 0
    ],
    ids=["size", "phantom-size", "range-outside"],
)
def test_limits(tmp_path: Path, capfd, options: list[str], expected: str) -> None:
    code, _, err = _run(["phantom", "--phantom-size", 16, "-o", tmp_path / "out", "-q", *options], capfd)
    assert code == 2 and len(err.splitlines()) == 1 and expected in err, err
    assert not (tmp_path / "out").exists()  # a failing run creates no output folder


def test_negative_numbers_in_scientific_notation_are_values(tmp_path: Path, capfd) -> None:
    """Before: 'argument --range: expected 2 arguments'."""
    code, _, err = _run(["phantom", "--phantom-size", 16, "-o", tmp_path / "out", "-q", "--no-render",
                         "--range", "-1e3", "3e3", "--preference", "-1e-1"], capfd)  # fmt: skip
    assert code == 0, err
    document = _load(tmp_path / "out")
    assert document["value_range"] == [-1000.0, 3000.0] and document["options"]["preference"] == -0.1


def test_output_path_is_checked_before_any_work(tmp_path: Path, capfd) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("x")
    for outdir, expected in (("", "the output folder is empty"), (a_file / "out", "lies under")):
        code, _, err = _run(["phantom", "--phantom-size", 16, "-o", outdir, "--no-render"], capfd)
        assert code == 2 and err.startswith("isosimtf: error: ") and expected in err, err
        assert "[1/" not in err  # refused before reading the input


def test_failing_run_leaves_no_folder(tmp_path: Path, capfd) -> None:
    bad = tmp_path / "bad.npy"
    bad.write_bytes(b"not a numpy file")
    code, _, _ = _run([bad, "-o", tmp_path / "new" / "out", "--no-render", "-q"], capfd)
    assert code == 2 and not (tmp_path / "new").exists()


@needs_slicer
def test_reruns_replace_only_our_files(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    (outdir / "scene").mkdir(parents=True)
    (outdir / "scene" / "my notes.txt").write_text("mine")
    (outdir / "my.png").write_text("mine")
    code, _, err = _run(["phantom", "--phantom-size", 24, "--size", 64, "-o", outdir, "-q"], capfd)
    assert code == 0 and err == "", err  # nothing from VTK or Slicer on stderr either
    written = _load(outdir)["written"]
    assert {"render.png", "classes.png", "scene/scene.mrml", "classes.json"} <= set(written)
    assert all((outdir / name).is_file() for name in written)
    assert (outdir / "scene" / "my notes.txt").read_text() == "mine"  # before: scene/ deleted wholesale

    code, _, err = _run(["phantom", "--phantom-size", 24, "--no-render", "-o", outdir, "-q"], capfd)
    assert code == 0
    assert err.startswith("isosimtf: warning: removed") and "render.png" in err and "scene/scene.mrml" in err
    assert not (outdir / "render.png").exists() and not (outdir / "scene" / "Data").exists()
    assert (outdir / "scene" / "my notes.txt").is_file() and (outdir / "my.png").is_file()
    document = _load(outdir)
    looks = {f"looks/{look['name']}.vp.json" for look in document["looks"]}
    assert looks and set(document["written"]) == set(DATA_FILES) | looks


def test_useless_results_are_refused_or_warned(tmp_path: Path, capfd) -> None:
    big = tmp_path / "int64.npy"  # before: exit 0, every voxel in bin 0, one class
    np.save(big, np.int64(2**62) + np.random.default_rng(1).integers(0, 1000, (16, 16, 16)))
    code, _, err = _run([big, "-o", tmp_path / "a", "--no-render", "-q"], capfd)
    assert code == 2 and "subtract an offset" in err
    labels = tmp_path / "labels.npy"  # before: exit 0, no word about it
    volume = np.zeros((24, 24, 24), np.uint8)
    volume[6:18, 6:18, 6:18], volume[9:15, 9:15, 9:15] = 1, 2
    np.save(labels, volume)
    code, _, err = _run([labels, "-o", tmp_path / "b", "--no-render", "-q"], capfd)
    assert code == 0
    assert "isosimtf: warning: the volume looks like a label map (at least 3 distinct integer values" in err
    design = design_transfer_function(head_phantom(16).values)
    for item in design.classes:
        design.set_class(item.id, visible=False)
    (warning,) = run._design_warnings(SimpleNamespace(design=design))
    assert "the transfer function shows nothing" in warning


def test_many_bins_warn_that_clustering_is_slow() -> None:
    info = {"value_min": -1000.0, "value_max": 3000.0, "dtype": "int16"}
    assert run._input_warnings(info, 256) == []
    (warning,) = run._input_warnings(info, 4096)
    assert "4096 isovalues may take many minutes" in warning


def test_without_slicer_core_rendering_is_skipped_with_a_warning(tmp_path: Path, capfd, monkeypatch) -> None:
    monkeypatch.setattr(run, "slicer_core_available", lambda: False)
    code, _, err = _run(["phantom", "-o", tmp_path / "out", "--phantom-size", 16, "-q"], capfd)
    assert code == 0
    assert err.startswith("isosimtf: warning: slicer-core is not installed") and len(err.splitlines()) == 1
    assert not (tmp_path / "out" / "render.png").exists()
    assert (tmp_path / "out" / "classes.json").is_file()


# ---------------------------------------------------------------------------------------------------------------
# Processes: --no-render never imports slicer-core; the installed console script
# ---------------------------------------------------------------------------------------------------------------


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([*map(str, PACKAGE_DIRS), os.environ.get("PYTHONPATH", "")]))


def test_no_render_does_not_import_slicer_core(tmp_path: Path) -> None:
    code = (
        "import sys\n"
        "from isosimtf.cli import main\n"
        f"assert main(['phantom', '-o', {str(tmp_path / 'out')!r}, '--phantom-size', '16', '--no-render', '-q']) == 0\n"
        "loaded = sorted(m for m in sys.modules if m == 'slicer' or m.startswith(('slicer.', 'slicer_core')))\n"
        "assert not loaded, loaded\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(), timeout=120)
    assert result.returncode == 0, result.stderr


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(), timeout=120)


def test_help_and_usage_errors_import_no_engine_dependency() -> None:
    code = (
        "import sys\n"
        "from isosimtf.cli import main\n"
        "assert main(['--help']) == 0\n"
        "assert main(['phantom', '-o', 'out', '--bins', 'many']) == 2\n"
        "assert main(['phantom']) == 2\n"
        "heavy = {'vtkmodules', 'slicer', 'dask', 'zarr'} & {name.split('.')[0] for name in sys.modules}\n"
        "assert not heavy, heavy\n"
    )
    result = _python(code)
    assert result.returncode == 0, result.stderr


def test_a_run_never_imports_scikit_learn_or_scipy(tmp_path: Path) -> None:
    """Affinity propagation is the engine's own (numpy): a whole run needs neither package, nor waits for one."""
    code = (
        "import sys\n"
        "from isosimtf.cli import main\n"
        f"assert main(['phantom', '-o', {str(tmp_path / 'out')!r}, '--phantom-size', '24', '--no-render', '-q']) == 0\n"
        "loaded = {'sklearn', 'scipy'} & {name.split('.')[0] for name in sys.modules}\n"
        "assert not loaded, loaded\n"
    )
    result = _python(code)
    assert result.returncode == 0, result.stderr


def test_console_script(tmp_path: Path) -> None:
    script = Path(sys.executable).with_name("isosimtf")
    if not script.is_file():
        pytest.skip("the isosimtf console script is not installed (pip install -e .)")
    outdir = tmp_path / "demo"
    argv = [str(script), "phantom", "-o", str(outdir), "--phantom-size", "32", "--size", "64"]
    result = subprocess.run(argv, capture_output=True, text=True, env=_env(), timeout=300)
    assert result.returncode == 0, result.stderr
    total = len(run.STAGES) if slicer_core_available() else len(run.STAGES) - 1
    assert result.stderr.startswith(f"[1/{total}] read phantom")
    assert "Traceback" not in result.stderr
    assert "rank" in result.stdout and "output:" in result.stdout
    for name in DATA_FILES + (RENDER_FILES if slicer_core_available() else ()):
        assert (outdir / name).is_file(), name
    bad = subprocess.run(
        [str(script), str(tmp_path / "absent.mha"), "-o", str(outdir)],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=120,
    )
    assert bad.returncode == 2
    assert bad.stderr.splitlines()[-1].startswith("isosimtf: error: ") and "Traceback" not in bad.stderr


# ---------------------------------------------------------------------------------------------------------------
# Picture helpers
# ---------------------------------------------------------------------------------------------------------------


def test_class_grid_layout_and_labels() -> None:
    tiles = [np.zeros((40, 50, 3), np.uint8) for _ in range(5)]
    labels = [("#1  12.5% of voxels", "-10 .. 30")] * 5
    grid = figures.class_grid(tiles, labels, [[1.0, 0.0, 0.0]] * 5)
    assert grid.dtype == np.uint8 and grid.shape[1] == 3 * 50 + 4 * figures.GRID_GAP
    assert np.any(np.all(grid == (255, 0, 0), axis=2))  # colour swatch
    assert np.count_nonzero(grid.max(axis=2) > 150) > 40  # text
    assert formatting.format_percent(0.00001) == "<0.1" and formatting.format_percent(0.5) == "50.0"
    assert formatting.format_ranges([[0.0, 1.0], [2.0, 3.0]], 1) == "0.0 .. 1.0, 2.0 .. 3.0"
    assert formatting.value_decimals((-1024.0, 3071.0), 256) == 0 and formatting.value_decimals((0.0, 1.0), 256) == 3
    assert formatting.color_hex([1.0, 0.5, 0.0]) == "#ff8000"


def test_long_passes_show_a_progress_bar_on_a_terminal() -> None:
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    stream = Terminal()
    printer = console.ProgressPrinter(3, stream=stream)
    printer.design_callback("similarity", 0.0, "measuring")
    printer.design_callback("similarity", 0.25, "similarity: unit cells")
    assert stream.getvalue().endswith(
        "similarity (hierarchical isosurface similarity): unit cells [#####...............]  25%"
    )


def test_a_nearly_clear_tissue_is_labelled_so() -> None:
    def tissue(opacity: float) -> Tissue:
        return Tissue(id=1, classes=[1], voxels=10, value_ranges=[[-977.0, -413.0]], color=[0.5, 0.1, 0.1],
                      opacity=opacity, visible=True)  # fmt: skip

    lines = figures.tissue_label_lines(tissue(0.001), 0.099, 0)
    assert lines == ("Tissue 2  9.9% of voxels", "-977 .. -413  nearly clear")
    assert figures.tissue_label_lines(tissue(0.5), 0.099, 0)[1] == "-977 .. -413"
