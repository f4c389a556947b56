"""Piecewise-constant transfer functions, VTK objects, and Slicer's .vp.json / .vp files."""

import json

import numpy as np
import pytest

from IsoSimilarityTFLib import TransferFunctionFileError, read_vp, read_vp_json
from IsoSimilarityTFLib.transfer_function import (
    MAX_TABLE_SIZE,
    fill_volume_property,
    new_volume_property,
    piecewise_constant,
    points_of_volume_property,
    step_width,
    write_vp,
    write_vp_json,
)

EDGES = np.linspace(-1000.0, 3000.0, 9)  # 8 bins of 500 HU
COLORS = np.array([[0, 0, 0]] * 2 + [[1, 0, 0]] * 3 + [[0, 1, 0]] + [[0, 0, 1]] * 2, dtype=float)
OPACITY = np.array([0, 0, 0.2, 0.2, 0.2, 0.5, 0.9, 0.9])


def test_piecewise_constant_is_exact_inside_bins_and_steps_at_edges():
    tf = piecewise_constant(EDGES, COLORS, OPACITY)
    assert np.all(np.diff(tf.x) > 0), "points must be strictly increasing"
    assert tf.x[0] == EDGES[0] and tf.x[-1] == EDGES[-1]
    assert len(tf.x) == 2 * 4  # four runs of equal look
    centres = 0.5 * (EDGES[:-1] + EDGES[1:])
    color, opacity = tf(centres)
    np.testing.assert_allclose(color, COLORS)
    np.testing.assert_allclose(opacity, OPACITY)
    # At an edge the new bin's look applies; a step's width below it the old one.
    color, opacity = tf(np.array([EDGES[5], EDGES[5] - step_width(EDGES)]))
    np.testing.assert_allclose(opacity, [0.5, 0.2])


@pytest.mark.parametrize("n_bins", [8, 256, 1024])
def test_steps_fit_the_gpu_lookup_table(n_bins):
    """VTK's GPU ray caster samples range / (smallest point spacing) table entries: at most MAX_TABLE_SIZE."""
    edges = np.linspace(-1024.0, 3071.0, n_bins + 1)
    alternating = np.arange(n_bins) % 2  # every bin its own run: the most points a design can make
    tf = piecewise_constant(edges, np.zeros((n_bins, 3)), alternating.astype(float))
    assert np.all(np.diff(tf.x) > 0)
    assert (edges[-1] - edges[0]) / np.diff(tf.x).min() <= MAX_TABLE_SIZE
    assert np.diff(tf.x).min() <= 0.25 * (edges[1] - edges[0]) + 1e-9  # still a step, not a ramp


def test_vtk_volume_property_holds_the_same_function():
    tf = piecewise_constant(EDGES, COLORS, OPACITY)
    vp = new_volume_property(tf, unit_distance=0.75)
    assert vp.GetInterpolationType() == 1 and vp.GetShade() == 1
    assert vp.GetScalarOpacityUnitDistance() == 0.75
    centres = 0.5 * (EDGES[:-1] + EDGES[1:])
    opacity = [vp.GetScalarOpacity().GetValue(x) for x in centres]
    color = [vp.GetRGBTransferFunction().GetColor(x) for x in centres]
    np.testing.assert_allclose(opacity, OPACITY)
    np.testing.assert_allclose(color, COLORS)


def test_fill_in_place_keeps_the_function_objects():
    vp = new_volume_property(piecewise_constant(EDGES, COLORS, OPACITY))
    opacity_function = vp.GetScalarOpacity()
    fill_volume_property(vp, piecewise_constant(EDGES, COLORS, np.ones(8)))
    assert vp.GetScalarOpacity() is opacity_function
    assert opacity_function.GetValue(0.0) == 1.0 and opacity_function.GetSize() == 2 * 4


@pytest.mark.parametrize("suffix", [".vp.json", ".vp"])
def test_file_round_trip(tmp_path, suffix):
    vp = new_volume_property(piecewise_constant(EDGES, COLORS, OPACITY), unit_distance=0.5)
    path = tmp_path / f"tf{suffix}"
    if suffix == ".vp":
        write_vp(vp, path)
        back = read_vp(path)
    else:
        write_vp_json(vp, path, effective_range=(-1024, 3071))
        back, effective_range = read_vp_json(path)
        assert effective_range == (-1024.0, 3071.0)
        assert back.GetScalarOpacityUnitDistance() == 0.5
    ours, theirs = points_of_volume_property(vp), points_of_volume_property(back)
    if suffix == ".vp":  # no unit distance in the file (read as 1 mm): the same opacity, written per mm
        assert back.GetScalarOpacityUnitDistance() == 1.0
        np.testing.assert_allclose(theirs[0][:, 1], 1.0 - (1.0 - ours[0][:, 1]) ** (1.0 / 0.5), rtol=1e-12)
        ours, theirs = ours[1:], theirs[1:]
        assert not np.allclose(points_of_volume_property(vp)[0][:, 1], points_of_volume_property(back)[0][:, 1])
    for a, b in zip(ours, theirs):
        np.testing.assert_array_equal(a, b)
    for getter in ("GetShade", "GetInterpolationType", "GetAmbient", "GetDiffuse", "GetSpecular", "GetSpecularPower"):
        assert getattr(vp, getter)() == getattr(back, getter)()


def test_legacy_vp_counts_are_numbers_of_values(tmp_path):
    vp = new_volume_property(piecewise_constant(EDGES, COLORS, OPACITY))
    write_vp(vp, tmp_path / "tf.vp")
    lines = (tmp_path / "tf.vp").read_text().splitlines()
    assert len(lines) == 9
    opacity, gradient, color = (line.split() for line in lines[6:9])
    assert int(opacity[0]) == 2 * 8 == len(opacity) - 1
    assert int(gradient[0]) == 4 == len(gradient) - 1
    assert int(color[0]) == 4 * 8 == len(color) - 1


def test_vp_json_follows_slicer_schema(tmp_path):
    vp = new_volume_property(piecewise_constant(EDGES, COLORS, OPACITY))
    write_vp_json(vp, tmp_path / "tf.vp.json")
    document = json.loads((tmp_path / "tf.vp.json").read_text())
    assert document["@schema"].endswith("volume-property-schema-v1.0.0.json#")
    component = document["volumeProperties"][0]["components"][0]
    assert component["rgbTransferFunction"]["type"] == "colorTransferFunction"
    assert component["scalarOpacity"]["type"] == "piecewiseLinearFunction"
    assert len(component["scalarOpacity"]["points"]) == 8
    assert document["volumeProperties"][0]["effectiveRange"] == [0.0, -1.0]  # unset


def test_slicer_reads_our_files(tmp_path):
    slicer = pytest.importorskip("slicer", reason="slicer-core is not installed")
    vp = new_volume_property(piecewise_constant(EDGES, COLORS, OPACITY))
    write_vp_json(vp, tmp_path / "tf.vp.json", effective_range=(-1000, 3000))
    write_vp(vp, tmp_path / "tf.vp")
    for name, storage_class in (
        ("tf.vp.json", slicer.vtkMRMLVolumePropertyJsonStorageNode),
        ("tf.vp", slicer.vtkMRMLVolumePropertyStorageNode),
    ):
        node, storage = slicer.vtkMRMLVolumePropertyNode(), storage_class()
        storage.SetFileName(str(tmp_path / name))
        assert storage.ReadData(node) == 1
        for ours, theirs in zip(points_of_volume_property(vp), points_of_volume_property(node.GetVolumeProperty())):
            np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "name,text",
    [
        ("bad.vp", "1\n1\n0.8\n"),
        ("bad2.vp", "1\n1\n0.8\n0.2\n0.2\n10\n4 0 0 1\n4 0 1 255 1\n4 0 1 1 1\n"),
        ("bad.vp.json", "{not json"),
        ("bad2.vp.json", '{"volumeProperties": []}'),
    ],
)
def test_unreadable_files_give_a_clear_error(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    reader = read_vp_json if name.endswith(".json") else read_vp
    with pytest.raises(TransferFunctionFileError, match="cannot read volume property file"):
        reader(path)
    with pytest.raises(TransferFunctionFileError):
        reader(tmp_path / "missing.vp")
