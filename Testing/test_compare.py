"""Tests of the first-click benchmark's pieces: picture metrics, presets.xml reading, tissue ray casting, verdicts.

Slicer's presets.xml is never needed: the tests write a tiny presets file of their own.
"""

import importlib
import sys
from pathlib import Path
from typing import Optional

import numpy as np
import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _load(name):
    """Import a module of benchmarks/ (its folder on sys.path, as when the scripts run)."""
    if str(BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(BENCHMARKS))
    return importlib.import_module(name)


metrics = _load("picture_metrics")
presets = _load("slicer_presets")
tissues = _load("tissue_visibility")


def _canvas(size=32, color=(0, 0, 0)):
    picture = np.empty((size, size, 3), dtype=np.uint8)
    picture[:] = color
    return picture


# ------------------------------------------------------------------------------------------------ picture metrics


def test_foreground_is_what_differs_from_the_backdrop():
    picture = _canvas(color=(10, 20, 30))
    picture[4:8, 4:12] = (200, 200, 200)
    picture[20, 20] = (13, 22, 33)  # within the tolerance: still backdrop
    mask = metrics.foreground_mask(picture, backdrop=(10, 20, 30))
    assert mask.sum() == 4 * 8
    assert mask[4:8, 4:12].all()


def test_foreground_against_a_gradient_backdrop_picture():
    backdrop = np.repeat(np.linspace(60, 200, 32).astype(np.uint8)[:, None], 32, axis=1)[..., None].repeat(3, 2)
    picture = backdrop.copy()
    picture[10:14, 10:14] = (255, 0, 0)
    assert metrics.foreground_mask(picture, backdrop).sum() == 16


def test_brightness_is_mean_luma_over_the_foreground_only():
    picture = _canvas()
    picture[:8, :8] = (255, 255, 255)
    picture[8:16, :8] = (100, 100, 100)
    result = metrics.picture_metrics(picture)
    assert result["brightness"] == pytest.approx((255 + 100) / 2)
    assert result["coverage"] == pytest.approx(128 / 32**2)


def test_luma_and_chroma_follow_bt601():
    picture = np.array([[[255, 0, 0], [128, 128, 128]]], dtype=np.uint8)
    assert metrics.luma(picture)[0, 0] == pytest.approx(0.299 * 255)
    cb, cr = metrics.chroma(picture)[0, 0]
    assert cb == pytest.approx(-0.168736 * 255) and cr == pytest.approx(0.5 * 255)
    assert np.allclose(metrics.chroma(picture)[0, 1], 0.0, atol=1e-9)  # grey has no chroma


def test_uniform_colour_has_no_colour_noise_even_at_its_silhouette():
    picture = _canvas()
    picture[6:26, 6:26] = (200, 120, 40)  # one orange disc-like square on black
    assert metrics.picture_metrics(picture)["colour_noise"] == pytest.approx(0.0, abs=1e-9)


def test_alternating_hues_are_noisier_than_a_smooth_hue_ramp():
    rainbow = _canvas()
    rainbow[:, ::2] = (220, 60, 60)
    rainbow[:, 1::2] = (60, 60, 220)
    ramp = _canvas()
    ramp[:] = np.stack(np.broadcast_arrays(np.linspace(60, 220, 32)[None, :], 60, 120), -1).astype(np.uint8)
    noisy = metrics.picture_metrics(rainbow)["colour_noise"]
    smooth = metrics.picture_metrics(ramp)["colour_noise"]
    assert noisy > 40.0
    assert smooth < 2.0


def test_grey_texture_is_not_colour_noise():
    rng = np.random.default_rng(0)
    grey = rng.integers(30, 255, size=(32, 32), dtype=np.uint8)
    picture = np.repeat(grey[..., None], 3, axis=2)
    assert metrics.picture_metrics(picture)["colour_noise"] == pytest.approx(0.0, abs=1e-6)


def test_empty_picture_measures_zero():
    assert metrics.picture_metrics(_canvas()) == {"brightness": 0.0, "colour_noise": 0.0, "coverage": 0.0}


def test_box_sum_matches_a_direct_sum():
    rng = np.random.default_rng(1)
    image = rng.random((9, 11))
    result = metrics.box_sum(image, 5)
    padded = np.pad(image, 2)
    direct = np.array([[padded[r : r + 5, c : c + 5].sum() for c in range(11)] for r in range(9)])
    assert np.allclose(result, direct)
    with pytest.raises(ValueError):
        metrics.box_sum(image, 4)


def test_resize_area_keeps_the_mean_and_the_shape():
    rng = np.random.default_rng(2)
    picture = rng.integers(0, 256, size=(512, 512, 3), dtype=np.uint8)
    small = metrics.resize_area(picture, 384, 384)
    assert small.shape == (384, 384, 3) and small.dtype == np.uint8
    assert abs(small.astype(float).mean() - picture.astype(float).mean()) < 0.5


# ------------------------------------------------------------------------------------------------ presets.xml

TINY_PRESETS = """<?xml version="1.0" encoding="UTF-8"?>
<MRML>
  <VolumeProperty name="Ramp-A" interpolation="1" shade="1" ambient="0.2" diffuse="0.9" specular="0.1"
    specularPower="10" scalarOpacity="6 0 0 50 0.5 100 1" gradientOpacity="4 0 1 255 1"
    colorTransfer="8 0 0 0 0 100 1 0.5 0.25" effectiveRange="0 100"/>
  <VolumeProperty name="Broken-Range" scalarOpacity="4 -10 0 10 1" colorTransfer="4 0 1 1 1"
    effectiveRange="-250.0.0 1550.0"/>
</MRML>
"""


def _write_presets(folder: Path) -> Path:
    path = folder / "presets.xml"
    path.write_text(TINY_PRESETS, encoding="utf-8")
    return path


def test_read_presets_parses_functions_range_and_shading(tmp_path):
    read = presets.read_presets(_write_presets(tmp_path))
    assert list(read) == ["Ramp-A", "Broken-Range"]
    ramp = read["Ramp-A"]
    assert ramp.scalar_opacity.tolist() == [[0, 0], [50, 0.5], [100, 1]]
    assert ramp.color.tolist() == [[0, 0, 0, 0], [100, 1, 0.5, 0.25]]
    assert ramp.gradient_opacity.tolist() == [[0, 1], [255, 1]]
    assert ramp.effective_range == (0.0, 100.0)
    assert ramp.shading["specularPower"] == 10.0
    assert read["Broken-Range"].effective_range is None  # malformed in Slicer's own file: kept as unknown


def test_parse_function_rejects_a_wrong_count():
    with pytest.raises(ValueError):
        presets.parse_function("5 0 0 1 1", 2)
    assert presets.parse_function("", 2).shape == (0, 2)


def test_find_presets_order_explicit_then_environment_then_shared(tmp_path, monkeypatch):
    explicit = _write_presets(tmp_path)
    env_dir = tmp_path / "env"
    env_dir.mkdir()
    from_env = _write_presets(env_dir)
    repo = tmp_path / "repo"
    repo.mkdir()
    (tmp_path / "shared").mkdir()
    shared = _write_presets(tmp_path / "shared")
    no_mirror = tmp_path / "no-mirror"

    monkeypatch.setenv(presets.PRESETS_ENV, str(from_env))
    assert presets.find_presets(str(explicit), repo, mirror=no_mirror).path == explicit.resolve()
    assert presets.find_presets(None, repo, mirror=no_mirror).path == from_env.resolve()
    monkeypatch.delenv(presets.PRESETS_ENV)
    assert presets.find_presets(None, repo, mirror=no_mirror).path == shared.resolve()


def test_find_presets_without_any_says_how_to_provide_it(tmp_path, monkeypatch):
    monkeypatch.delenv(presets.PRESETS_ENV, raising=False)
    with pytest.raises(presets.PresetsNotFound) as error:
        presets.find_presets(None, tmp_path / "repo", mirror=tmp_path / "no-mirror")
    message = str(error.value)
    assert "PRESETS=" in message and "\n" not in message
    with pytest.raises(presets.PresetsNotFound):
        presets.find_presets(str(tmp_path / "missing.xml"), None, mirror=tmp_path / "no-mirror")


# ------------------------------------------------------------------------------------------------ tissue ray casting


def test_ray_axis_follows_the_ijk_to_ras_matrix():
    identity = np.eye(4)
    assert tissues.ray_axis(identity, "anterior") == (1, True)  # rays enter at high j (anterior) going posterior
    assert tissues.ray_axis(identity, "left") == (2, False)  # from the patient's left (-x) towards +x
    flipped = np.diag([-1.0, -1.0, 1.0, 1.0])  # LPS-like storage
    assert tissues.ray_axis(flipped, "anterior") == (1, False)
    assert tissues.ray_axis(flipped, "left") == (2, True)


def test_opaque_shell_hides_what_is_behind_it():
    labels = np.zeros((4, 4, 10), dtype=np.uint8)
    labels[..., 2] = 1  # a thin "skull" plane seen first from the left (i = 0 side)
    labels[..., 5:8] = 2  # "brain" behind it
    values = np.where(labels == 1, 1000.0, np.where(labels == 2, 40.0, -1000.0))
    opaque_bone = tissues.piecewise_linear(np.array([[-1000, 0], [500, 0], [501, 1], [2000, 1]]))
    weights, crosses = tissues.tissue_weights(values, labels, 3, opaque_bone, (1, 1, 1), axis=2, reverse=False)
    summary = tissues.tissue_summary(weights, crosses, ("air", "skull", "brain"))
    assert summary["skull"]["visibility"] == pytest.approx(1.0)
    assert summary["skull"]["share"] == pytest.approx(1.0)
    assert summary["brain"]["visibility"] == 0.0
    # From the other side the brain is in front but clear: the skull still makes the picture.
    weights, crosses = tissues.tissue_weights(values, labels, 3, opaque_bone, (1, 1, 1), axis=2, reverse=True)
    assert tissues.tissue_summary(weights, crosses, ("air", "skull", "brain"))["skull"]["share"] == 1.0


def test_opacity_is_per_unit_distance():
    labels = np.ones((1, 1, 20), dtype=np.uint8)
    values = np.zeros((1, 1, 20))
    half = tissues.piecewise_linear(np.array([[0.0, 0.1], [1.0, 0.1]]))
    fine, _ = tissues.tissue_weights(values, labels, 2, half, (0.5, 1, 1), axis=2, reverse=False)
    coarse, _ = tissues.tissue_weights(values[..., :10], labels[..., :10], 2, half, (1.0, 1, 1), 2, False)
    # 10 mm of the same material, sampled every 0.5 mm or every 1 mm, gives the same opacity.
    assert fine.sum() == pytest.approx(coarse.sum()) == pytest.approx(1 - 0.9**10)


# ------------------------------------------------------------------------------------------------ verdicts


def test_verdict_applies_the_issue_targets():
    compare = _load("compare")
    assert compare.verdict(0.8, 1.3)
    assert not compare.verdict(0.79, 1.0)
    assert not compare.verdict(1.0, 1.31)
    assert not compare.verdict(None, 1.0)
    assert compare.ratio(2.0, 4.0) == 0.5 and compare.ratio(1.0, 0.0) is None


def _kept_case(
    shares: dict, brightness: dict, noise: dict, shown_for=("core", "envelope"), coverage: Optional[dict] = None
) -> dict:
    """One volume of compare.json as kept_summary reads it: per look, each structure's share, B, N and C (coverage,
    0.5 unless given), both views."""
    compare = _load("compare")
    looks = {compare.OURS: 0, compare.KEPT: 1}
    coverage = coverage or dict.fromkeys(looks, 0.5)
    view = {
        "tissues": {look: {t: {"share": shares[look][i]} for i, t in enumerate(shown_for)} for look in looks},
        "metrics": {
            look: {"brightness": brightness[look], "colour_noise": noise[look], "coverage": coverage[look]}
            for look in looks
        },
    }
    return {
        "kept": ["CT-AAA", 100.0],
        "shown_for": list(shown_for),
        "best_look": None,
        "tissues": {v: view["tissues"] for v in compare.VIEWS},
        "metrics": {v: view["metrics"] for v in compare.VIEWS},
    }


@pytest.mark.parametrize(("envelope", "keeps_up"), [(0.59, True), (0.58, False)])
def test_the_kept_preset_is_matched_structure_by_structure(envelope, keeps_up):
    # The kept picture shows the envelope at 0.6: ours must too (within SHARE_TOLERANCE), whatever the sum says.
    compare = _load("compare")
    assert compare.SHARE_TOLERANCE == 0.01
    case = _kept_case(
        {compare.OURS: (1.0 - envelope, envelope), compare.KEPT: (0.4, 0.6)},
        {compare.OURS: 100.0, compare.KEPT: 100.0},
        {compare.OURS: 1.0, compare.KEPT: 1.0},
    )
    lines = compare.kept_summary({"heptane": case})
    rows = [line for line in lines if line.startswith("| heptane |")]
    assert len(rows) == 2 and all(("| yes |" in row) == keeps_up for row in rows)
    assert f"on **{int(keeps_up)} of 1** volumes" in lines[-1]


@pytest.mark.parametrize(
    ("brightness", "noise", "keeps_up"), [(80.0, 1.3, True), (79.0, 1.0, False), (100.0, 1.31, False)]
)
def test_the_kept_preset_is_matched_in_brightness_and_colour_noise(brightness, noise, keeps_up):
    compare = _load("compare")
    case = _kept_case(
        {compare.OURS: (0.9,), compare.KEPT: (0.9,)},
        {compare.OURS: brightness, compare.KEPT: 100.0},
        {compare.OURS: noise, compare.KEPT: 1.0},
        shown_for=("skull",),
    )
    lines = compare.kept_summary({"head": case})
    assert f"on **{int(keeps_up)} of 1** volumes" in lines[-1]


def _with_gallery(case: dict, looks: dict) -> dict:
    """``case`` with gallery looks as ``add_gallery_looks`` ranks them: ``looks[name][view] = (share, brightness)``."""
    compare = _load("compare")
    case = {**case, "gallery_looks": list(looks), "best_look": next(iter(looks))}
    case["tissues"] = {v: dict(case["tissues"][v]) for v in compare.VIEWS}
    case["metrics"] = {v: dict(case["metrics"][v]) for v in compare.VIEWS}
    for name, views in looks.items():
        for view, (share, brightness) in views.items():
            case["tissues"][view][compare.GALLERY_LOOK + name] = {"skull": {"share": share}}
            case["metrics"][view][compare.GALLERY_LOOK + name] = {
                "brightness": brightness,
                "colour_noise": 1.0,
                "coverage": 0.5,
            }
    return case


def test_some_look_keeps_up_when_one_look_does_in_every_view():
    # The first click is too dark; the look showing most is too (ranked first); a later one keeps up in both views.
    compare = _load("compare")
    dark = _kept_case(
        {compare.OURS: (0.9,), compare.KEPT: (0.9,)}, {compare.OURS: 50.0, compare.KEPT: 100.0},
        {compare.OURS: 1.0, compare.KEPT: 1.0}, shown_for=("skull",),
    )  # fmt: skip
    both = dict.fromkeys(compare.VIEWS, (0.95, 60.0))
    lines = compare.kept_summary(
        {"head": _with_gallery(dark, {"most": both, "bright": dict.fromkeys(compare.VIEWS, (0.9, 80.0))})}
    )
    rows = [line for line in lines if line.startswith("| head |")]
    assert all("| bright | 90% | 0.80 | 1.00 | 1.00 | yes |" in row for row in rows)
    assert "on **0 of 1** volumes; the first click or the best look, on **1 of 1**" in lines[-1]
    # One look per view is not one look: each keeps up in one view only.
    halves = {
        "anterior-only": {"anterior": (0.9, 80.0), "left": (0.9, 79.0)},
        "left-only": {"anterior": (0.9, 79.0), "left": (0.9, 80.0)},
    }
    lines = compare.kept_summary({"head": _with_gallery(dark, halves)})
    assert "the first click or the best look, on **0 of 1**" in lines[-1]
    assert all("| anterior-only |" in line for line in lines if line.startswith("| head |"))  # the first ranked


@pytest.mark.parametrize(("coverage", "keeps_up"), [(0.4, True), (0.39, False)])
def test_the_kept_preset_is_matched_in_the_area_it_covers(coverage, keeps_up):
    # A plume's core alone is 100% plume: the picture must also cover 0.8x the area the kept one does.
    compare = _load("compare")
    assert compare.MIN_COVERAGE_RATIO == 0.8
    case = _kept_case(
        {compare.OURS: (1.0,), compare.KEPT: (1.0,)},
        {compare.OURS: 100.0, compare.KEPT: 100.0},
        {compare.OURS: 1.0, compare.KEPT: 1.0},
        shown_for=("plume",),
        coverage={compare.OURS: coverage, compare.KEPT: 0.5},
    )
    lines = compare.kept_summary({"fuel": case})
    assert f"on **{int(keeps_up)} of 1** volumes" in lines[-1]


def test_volumes_without_a_kept_preset_have_no_kept_table():
    compare = _load("compare")
    case = _kept_case(
        {compare.OURS: (0.9,), compare.KEPT: (0.9,)}, {compare.OURS: 1.0, compare.KEPT: 1.0},
        {compare.OURS: 1.0, compare.KEPT: 1.0}, shown_for=("skull",),
    )  # fmt: skip
    assert compare.kept_summary({"phantom": {**case, "kept": None}}) == []


def test_no_colour_noise_ratio_over_a_grey_picture():
    # Slicer's window/level ramp is grey: its colour noise is float rounding, and a ratio over it means nothing.
    compare = _load("compare")
    assert compare.ratio(0.49, 1.7e-16, compare.GREY_NOISE) is None
    assert compare.ratio(0.49, compare.GREY_NOISE, compare.GREY_NOISE) is None
    assert compare.ratio(0.5, 2 * compare.GREY_NOISE, compare.GREY_NOISE) == pytest.approx(25.0)


def test_partial_volume_voxel_shows_the_tissue_that_raised_its_value():
    # One row: air, an air voxel raised by the skin, soft tissue, a soft-tissue voxel raised by the skull, skull
    # (a skull voxel lowered by soft tissue stays skull).
    labels = np.array([[[0, 0, 1, 1, 1, 1, 2, 2]]], dtype=np.uint8)
    values = np.array([[[-1000.0, -400.0, 55.0, 70.0, 62.0, 300.0, 700.0, 1000.0]]])
    means = (-1000.0, 60.0, 1000.0)
    shown = tissues.partial_volume_labels(values, labels, means, tolerance=60.0, radius=1)
    assert shown.tolist() == [[[0, 1, 1, 1, 1, 2, 2, 2]]]
    far = tissues.partial_volume_labels(values, labels, means, tolerance=60.0, radius=0)
    assert far.tolist() == labels.tolist()  # no neighbour within reach: own tissue


def test_dilate_grows_by_the_radius_without_wrapping():
    mask = np.zeros((1, 1, 7), dtype=bool)
    mask[0, 0, 0] = True
    assert tissues.dilate(mask, 2)[0, 0].tolist() == [True, True, True, False, False, False, False]


# ------------------------------------------------------------------------------------------------ with slicer-core

# Our own values under the names Slicer's logic looks up (not Slicer's presets).
LOGIC_PRESETS = """<?xml version="1.0" encoding="UTF-8"?>
<MRML>
  <VolumeProperty id="vtkMRMLVolumePropertyNode1" name="US-Fetal" interpolation="1" shade="1"
    scalarOpacity="4 0 0 255 0.5" colorTransfer="8 0 0 0 0 255 1 1 1" gradientOpacity="4 0 1 255 1"/>
  <VolumeProperty id="vtkMRMLVolumePropertyNode2" name="MR-Default" interpolation="1" shade="1"
    scalarOpacity="4 0 0 400 0.4" colorTransfer="8 0 0.2 0 0 400 1 0.9 0.8" gradientOpacity="4 0 1 255 1"/>
  <VolumeProperty id="vtkMRMLVolumePropertyNode3" name="Steep" interpolation="1" shade="1"
    scalarOpacity="6 0 0 150 0 400 0.9" colorTransfer="8 0 1 0 0 400 0 0 1" gradientOpacity="4 0 1 255 1"/>
</MRML>
"""


def _logic_presets(folder: Path) -> Path:
    path = folder / "presets.xml"
    path.write_text(LOGIC_PRESETS, encoding="utf-8")
    return path


def _slicer_and_compare():
    """isosimtf.rendering and compare.py, or skip the test without slicer-core."""
    rendering = pytest.importorskip("isosimtf.rendering")
    if not rendering.slicer_core_available():
        pytest.skip("slicer-core is not installed")
    return rendering, _load("compare")


def _blob(dtype, high: float) -> np.ndarray:
    k, j, i = np.mgrid[:24, :24, :24]
    radius = np.sqrt((k - 11.5) ** 2 + (j - 11.5) ** 2 + (i - 11.5) ** 2)
    return (np.clip(1.0 - radius / 10.0, 0.0, 1.0) * high).astype(dtype)


@pytest.mark.parametrize(("dtype", "high", "picked"), [(np.uint8, 250, "US-Fetal"), (np.int16, 400, "MR-Default")])
def test_first_click_is_what_slicers_logic_recommends(tmp_path, dtype, high, picked):
    rendering, compare = _slicer_and_compare()
    values = _blob(dtype, high)
    with rendering.HeadlessSlicer(size=(64, 64), presets_file=_logic_presets(tmp_path)) as headless:
        volume_node = headless.add_volume(values)
        looks = compare.prepare_looks(headless, volume_node, values, (1.0, 1.0, 1.0), ("Steep", "Missing"))
        assert [look.name for look in looks] == [compare.OURS, compare.FIRST_CLICK, "Steep"]  # "Missing": left out
        assert looks[1].picked == picked
        steep = looks[2].property_node.GetVolumeProperty().GetScalarOpacity()
        assert steep.GetValue(400.0) == pytest.approx(0.9)  # copied unshifted, as Slicer's preset menu does
        pictures = compare.render_view(headless, volume_node, looks, "anterior", 64)
    assert set(pictures) == {look.name for look in looks}
    assert all(picture.shape == (64, 64, 3) for picture in pictures.values())
    boxes = [rendering.content_box(picture) for picture in pictures.values() if picture.any()]
    # One camera, framed onto the union of the looks: the largest content nearly fills the picture.
    assert max(max(b[1] - b[0], b[3] - b[2]) + 1 for b in boxes) >= 0.8 * 64


def test_the_kept_preset_is_shifted_as_the_shift_slider_moves_it(tmp_path):
    rendering, compare = _slicer_and_compare()
    values = _blob(np.int16, 400)
    with rendering.HeadlessSlicer(size=(64, 64), presets_file=_logic_presets(tmp_path)) as headless:
        volume_node = headless.add_volume(values)
        looks = compare.prepare_looks(headless, volume_node, values, (1.0,) * 3, ("Steep",), kept=("Steep", 100.0))
        assert [look.name for look in looks] == [compare.OURS, compare.FIRST_CLICK, "Steep", compare.KEPT]
        assert "Steep, shift +100" in looks[-1].title
        kept = looks[-1].property_node.GetVolumeProperty()
        assert kept.GetScalarOpacity().GetValue(250.0) == pytest.approx(0.0)  # the preset's 150, moved by +100
        assert kept.GetScalarOpacity().GetValue(375.0) == pytest.approx(0.45)  # halfway to its 400
        assert kept.GetRGBTransferFunction().GetColor(100.0) == pytest.approx((1.0, 0.0, 0.0))  # its 0
        # On a re-stored CT the shift is in HU, then mapped onto the stored values like the other presets.
        stored = compare.prepare_looks(
            headless, volume_node, values, (1.0,) * 3, (), storage=(0.5, 10.0), kept=("Steep", 100.0)
        )
        assert stored[-1].title.endswith("(mapped)")
        opacity = stored[-1].property_node.GetVolumeProperty().GetScalarOpacity()
        assert opacity.GetValue(135.0) == pytest.approx(0.0)  # 250 HU: the preset's 150 moved by +100, then stored
        assert opacity.GetValue(197.5) == pytest.approx(0.45)
        assert compare.prepare_looks(headless, volume_node, values, (1.0,) * 3, (), kept=("Missing", 0.0))[-1].name == (
            compare.FIRST_CLICK
        )  # a preset Slicer does not have: no kept column


def test_the_best_look_of_the_gallery_joins_the_columns_when_it_beats_the_first_click(tmp_path):
    rendering, compare = _slicer_and_compare()
    values = _blob(np.int16, 400)
    shell = (values > 0) & (values < 200)  # the outer, dimmer part of the blob
    labels = np.where(shell, 1, np.where(values >= 200, 2, 0))
    names = ("air", "shell", "core")
    with rendering.HeadlessSlicer(size=(64, 64), presets_file=_logic_presets(tmp_path)) as headless:
        volume_node = headless.add_volume(values)
        looks = compare.prepare_looks(headless, volume_node, values, (1.0, 1.0, 1.0), ("Steep",))
        design = looks[0].design
        first = design.transfer_function().opacity.copy()
        added = []
        for shown_for in (("shell",), ("core",)):
            before = len(looks)
            best = compare.add_best_look(headless, volume_node, looks, values, labels, names, shown_for)
            if best is None:  # the first click shows most of it already
                assert len(looks) == before
            else:
                assert looks[-1].name == compare.BEST_LOOK and best in looks[-1].title
                assert best != design.chosen_look
                added.append(best)
            assert np.array_equal(design.transfer_function().opacity, first)  # the first click is left shown
        assert added  # the blob's shell is better shown by another look than the first click (outer-surface)
        assert compare.add_best_look(headless, volume_node, looks, values, None, None, ("shell",)) is None


def test_every_look_of_the_gallery_joins_the_columns_on_a_kept_volume(tmp_path):
    rendering, compare = _slicer_and_compare()
    values = _blob(np.int16, 400)
    labels = np.where((values > 0) & (values < 200), 1, np.where(values >= 200, 2, 0))
    names = ("air", "shell", "core")
    with rendering.HeadlessSlicer(size=(64, 64), presets_file=_logic_presets(tmp_path)) as headless:
        volume_node = headless.add_volume(values)
        looks = compare.prepare_looks(headless, volume_node, values, (1.0, 1.0, 1.0), ("Steep",))
        design = looks[0].design
        first = design.chosen_look
        before = len(looks)
        ranked = compare.add_gallery_looks(headless, volume_node, looks, values, labels, names, ("shell",))
        assert sorted(ranked) == sorted(look.name for look in design.looks if look.name != first)
        assert [look.name for look in looks[before:]] == [compare.GALLERY_LOOK + name for name in ranked]
        shown = compare._shown_by_look(design, values, labels, names, ("shell",))
        assert [shown[name] for name in ranked] == sorted((shown[name] for name in ranked), reverse=True)
        assert design.chosen_look == first  # the first click is left shown
