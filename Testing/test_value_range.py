"""The default value range leaves out padding and outliers, in one warning line (issue 18, item 4): before, one voxel
at -1e30 gave an all-black picture and CT padding at -3024 or -32768 took the bins from the tissues, silently.
Built from the Debian head CT and the phantom."""

import json
from pathlib import Path

import numpy as np
import pytest

from IsoSimilarityTFLib.design import design_transfer_function
from IsoSimilarityTFLib.value_range import robust_value_range
from isosimtf import cli
from isosimtf.phantom import head_phantom
from isosimtf.volume_io import read_volume, real_dataset_path


def _head_ct() -> np.ndarray:
    path = real_dataset_path("head-ct")
    if path is None:
        pytest.skip("Debian package invesalius-examples is not installed")
    return read_volume(path).values


@pytest.mark.parametrize("name", ["head-ct", "brain-mri", "brain-stripped"])
def test_clean_scans_keep_their_whole_range(name: str) -> None:
    """MRI background at 0 and CT air at -1024 are not padding: nothing is left out, no warning."""
    path = real_dataset_path(name)
    if path is None:
        pytest.skip(f"real dataset {name} not installed")
    values = read_volume(path).values
    robust = robust_value_range(values)
    assert robust.value_range == (float(values.min()), float(values.max())) and robust.warning() is None


@pytest.mark.parametrize("padding", [-3024, -2048, -32768])
def test_ct_padding_is_left_out_and_the_design_is_the_unpadded_one(padding: int) -> None:
    ct = _head_ct()[::2, ::2, ::2].copy()
    padded = ct.copy()
    padded[:, :, :20], padded[:, :, -20:] = padding, padding  # outside the field of view
    robust = robust_value_range(padded)
    assert robust.value_range == (float(ct.min()), float(ct.max()))
    count = int(np.count_nonzero(padded == padding))
    assert robust.padding == ((float(padding), count),)
    assert f"leaving out {count} padding voxels at {padding}" in robust.warning()
    assert "--range LOW HIGH" in robust.warning() and "value_range=(" in robust.warning("value_range=(low, high)")
    ours = design_transfer_function(padded, value_range=robust.value_range, tissues="all")
    clean = design_transfer_function(ct, tissues="all")
    assert len(ours.classes) == pytest.approx(len(clean.classes), abs=2)


def test_one_outlier_voxel_no_longer_blacks_out_the_picture(tmp_path: Path, capfd) -> None:
    values = head_phantom(32, seed=0).values.astype(np.float32)
    values[2, 3, 4] = -1e30
    np.save(tmp_path / "outlier.npy", values)
    code = cli.main([str(tmp_path / "outlier.npy"), "-o", str(tmp_path / "out"), "--no-render", "-q"])
    err = capfd.readouterr().err
    assert code == 0
    (line,) = [line for line in err.splitlines() if "isovalue bins cover" in line]
    assert "leaving out 1 outlier voxel(s) from -1e+30" in line and "--range LOW HIGH" in line
    assert "shows nothing" not in err
    document = json.loads((tmp_path / "out" / "classes.json").read_text())
    assert document["value_range"] == [float(np.delete(values.ravel(), 2 * 32 * 32 + 3 * 32 + 4).min()),
                                       float(values.max())]  # fmt: skip
    assert sum(c["visible"] for c in document["classes"]) >= 3  # tissues shown, not the outlier alone

    code = cli.main([str(tmp_path / "outlier.npy"), "-o", str(tmp_path / "own"), "--no-render", "-q",
                     "--range", "-2000", "2000"])  # fmt: skip
    assert code == 0 and "isovalue bins cover" not in capfd.readouterr().err  # --range overrides the rule
    assert json.loads((tmp_path / "own" / "classes.json").read_text())["value_range"] == [-2000.0, 2000.0]


def test_label_maps_and_binary_masks_are_not_padding() -> None:
    mask = np.zeros((30, 30, 30), np.uint8)
    mask[10:20, 10:20, 10:20] = 1
    assert not robust_value_range(mask).excludes


def test_volumes_read_lazily_get_the_same_range() -> None:
    da = pytest.importorskip("dask.array")
    values = head_phantom(32, seed=0).values.copy()
    values[:, :, :4] = -3024
    robust = robust_value_range(values)
    assert robust.excludes and robust.padding[0][0] == -3024
    assert robust_value_range(da.from_array(values, chunks=8)) == robust


def test_the_api_leaves_padding_out_as_the_command_line_and_the_panel_do() -> None:
    """One design whoever calls the engine: design_transfer_function applies the robust range itself, says what it
    left out, and an explicit range turns it off."""
    ct = _head_ct()[::2, ::2, ::2].copy()
    padded = ct.copy()
    padded[:, :, :20] = -3024
    design = design_transfer_function(padded, n_bins=64)
    assert design.value_range == (float(ct.min()), float(ct.max()))
    assert design.options["value_range"] is None  # the user's option, as given
    assert "padding voxels at -3024" in design.range_warning("--range LOW HIGH")
    assert design.robust_range == robust_value_range(padded)
    given = design_transfer_function(padded, n_bins=64, value_range=(-3024, float(ct.max())))
    assert given.value_range == (-3024.0, float(ct.max())) and given.range_warning() is None
    assert design_transfer_function(ct, n_bins=64).range_warning() is None


@pytest.mark.parametrize(("share", "left_out"), [(0.49, True), (0.51, False)])
def test_a_fill_holding_most_of_the_volume_is_a_masked_exports_background_not_padding(share, left_out):
    """Padding is left out up to PADDING_MAX_FRACTION of the voxels; a vessel tree exported with 95-99 % zeros keeps
    its zeros in the range (so its faint edges stay apart from them in bins)."""
    from IsoSimilarityTFLib.value_range import PADDING_MAX_FRACTION

    assert PADDING_MAX_FRACTION == 0.5
    values = np.random.default_rng(0).normal(300.0, 40.0, 100_000)
    filled = int(round(share * values.size))
    values[:filled] = -3024.0
    volume = values.reshape(40, 50, 50)
    robust = robust_value_range(volume)
    assert robust.excludes is left_out
    assert robust.value_range[0] == (float(values[filled:].min()) if left_out else -3024.0)
