"""Tests of the judging panel's volumes (benchmarks/volume_panel.py) and of the look panel (benchmarks/look_panel.py).

Every synthetic generator runs at a small size: deterministic, with the labels it promises in sensible amounts. The
real volumes of ../shared/data are only read when that folder is there.
"""

from functools import cache

import numpy as np
import pytest
from test_compare import _load

panel = _load("volume_panel")

KINDS = {"CT", "MRI", "micro-CT", "angio", "industrial", "plant", "simulation"}

#: generator, the small size the tests run it at.
GENERATORS = (
    (panel.synthetic_angiogram, 64),
    (panel.synthetic_specimen, 64),
    (panel.synthetic_housing, 48),
    (panel.synthetic_plant, 64),
    (panel.contrast_ct_8bit, 64),
    (panel.synthetic_abdomen_ct, 64),
    (panel.synthetic_abdomen_mri, 64),
)


def _fractions(labels, names):
    counts = np.bincount(labels.ravel(), minlength=len(names))
    return dict(zip(names, counts / labels.size))


def _spacing(ijk_to_ras):
    return np.linalg.norm(np.asarray(ijk_to_ras)[:3, :3], axis=0)


@pytest.mark.parametrize(("generator", "size"), GENERATORS, ids=[g.__name__ for g, _ in GENERATORS])
def test_a_generator_is_deterministic_and_keeps_the_contract(generator, size):
    first, second = generator(size), generator(size)
    values, ijk_to_ras, labels, names, storage = first
    np.testing.assert_array_equal(values, second[0])
    np.testing.assert_array_equal(labels, second[2])
    assert values.ndim == 3 and labels.shape == values.shape and labels.dtype == np.uint8
    assert np.asarray(ijk_to_ras).shape == (4, 4)
    assert labels.max() < len(names) and len(set(names)) == len(names)
    assert storage is None or len(storage) == 2
    assert all(share > 0 for share in _fractions(labels, names).values()), _fractions(labels, names)
    assert not np.array_equal(values, generator(size, seed=1)[0])


def test_the_angiogram_holds_only_vessels_with_small_ones():
    values, _ijk_to_ras, labels, names, storage = panel.synthetic_angiogram(64)
    assert names == ("background", "large vessels", "small vessels")
    assert values.dtype in (np.uint8, np.uint16) and storage is None
    zeros = float(np.mean(values == 0))
    assert 0.95 <= zeros <= 0.995
    shares = _fractions(labels, names)
    assert shares["small vessels"] > 0.001 and shares["large vessels"] > 0
    assert np.all(labels[values == 0] == 0)  # a vessel label only where the export kept the value
    assert values[values > 0].min() >= 250  # the threshold of the export
    # At the default scale the smallest vessels are below two voxels of radius and the largest above.
    full = panel.synthetic_angiogram(128)
    assert 0.95 <= float(np.mean(full[0] == 0)) <= 0.99
    assert np.mean(full[2] == 1) > 0.002 and np.mean(full[2] == 2) > 0.002


def test_the_specimen_is_a_micro_ct_at_005_mm():
    values, ijk_to_ras, labels, names, storage = panel.synthetic_specimen(64)
    np.testing.assert_allclose(_spacing(ijk_to_ras), 0.05)
    assert values.dtype == np.uint16 and storage is None
    shares = _fractions(labels, names)
    assert {"air", "bone"} <= set(names) and 0.02 < shares["bone"] < 0.3 and shares["air"] > 0.3
    air, bone = values[labels == names.index("air")], values[labels == names.index("bone")]
    assert air.std() > 200  # noisy air: the fog
    assert np.median(bone) > 3 * np.median(air)
    # At the default size, 10 mm across (216 voxels of 0.05 mm, the specimen with a margin).
    assert panel.synthetic_specimen.__defaults__[0] * 0.05 >= 10.0


def test_the_housing_holds_denser_parts():
    values, _ijk_to_ras, labels, names, storage = panel.synthetic_housing(48)
    assert {"air", "housing", "parts"} <= set(names)
    assert values.dtype in (np.float32, np.uint16) and storage is None
    medians = {n: np.median(values[labels == names.index(n)]) for n in ("air", "housing", "parts")}
    assert medians["air"] < medians["housing"] < medians["parts"]
    spacing = _spacing(panel.synthetic_housing(128)[1])
    assert np.all((spacing >= 0.2) & (spacing <= 0.5))


def test_the_plant_has_light_wood_and_twigs():
    values, _ijk_to_ras, labels, names, storage = panel.synthetic_plant(64)
    assert names == ("air", "trunk", "branches", "pot", "soil")
    medians = {n: np.median(values[labels == names.index(n)]) for n in names}
    assert medians["air"] < medians["trunk"] < medians["soil"] < medians["pot"]
    # Twigs below a voxel: most branch voxels hold much less than the trunk's wood (partial volume).
    assert medians["branches"] < 0.5 * medians["trunk"]
    slope, offset = storage
    assert values.dtype == np.uint8 and (medians["pot"] - offset) / slope > 600  # ceramic, its thin wall blurred


def test_the_8bit_chest_ct_is_windowed_from_hu():
    values, _ijk_to_ras, labels, names, storage = panel.contrast_ct_8bit(64)
    assert values.dtype == np.uint8 and {"blood pool", "bone", "lungs"} <= set(names)
    slope, offset = storage
    hu = (values.astype(np.float64) - offset) / slope
    blood = np.median(hu[labels == names.index("blood pool")])
    assert 300 <= blood <= 500
    assert np.median(values[labels == names.index("lungs")]) == 0  # below the window: clipped to 0
    assert values.max() == 255  # cortical bone above the window


def test_the_abdomen_ct_is_int32_hu_in_3_mm_slices_on_a_table():
    values, ijk_to_ras, labels, names, storage = panel.synthetic_abdomen_ct()
    assert values.dtype == np.int32 and storage == (1.0, 0.0)
    assert np.allclose(_spacing(ijk_to_ras), (2.5, 2.5, 3.0))
    medians = {n: np.median(values[labels == names.index(n)]) for n in ("air", "fat", "soft tissue", "bone")}
    assert medians["air"] < -900 < medians["fat"] < -50 < medians["soft tissue"] < 100 < 200 < medians["bone"]
    shares = _fractions(labels, names)
    assert 0.01 < shares["bone"] < 0.05 and shares["table"] > 0.01  # a skeleton, and a table under the body


def test_the_abdominal_mri_is_a_thick_slab_with_haze_and_bright_fat():
    values, ijk_to_ras, labels, names, storage = panel.synthetic_abdomen_mri()
    assert values.dtype == np.uint16 and storage is None
    spacing = _spacing(ijk_to_ras)
    assert spacing[2] >= 2.5 * spacing[0] and values.shape[0] < values.shape[1] / 4  # a slab of thick slices
    medians = {n: np.median(values[labels == names.index(n)]) for n in names}
    assert 0 < medians["air"] < 30  # Rician noise: the air is a haze, not zero
    assert medians["fat"] > medians["organs"] > medians["muscle and bowel"] > medians["air"]


def test_the_clipped_storage_is_quantized_in_625_hu_steps():
    hu = np.array([[[-1000, -10, 0, 31, 32, 62, 100, 1000, 3071]]], dtype=np.int16)
    stored, (slope, offset) = panel.hu_clipped_quantized(hu)
    back = (stored.astype(np.float64) - offset) / slope
    np.testing.assert_allclose(np.mod(back, 62.5), 0.0)
    np.testing.assert_array_equal(back.ravel(), [0, 0, 0, 0, 62.5, 62.5, 125, 1000, 3062.5])
    assert stored.dtype == np.uint8
    same, storage = panel.storages(hu)["clipped"]
    np.testing.assert_array_equal(same, stored)
    assert storage == (slope, offset)


def test_the_clipped_phantom_maps_back_to_steps_and_keeps_its_truth():
    values, _ijk_to_ras, labels, names, (slope, offset) = panel._phantom_storage("clipped", 48)()
    back = (values.astype(np.float64) - offset) / slope
    np.testing.assert_allclose(np.mod(back, 62.5), 0.0, atol=1e-9)
    assert back.min() == 0 and values.dtype == np.uint8
    skull = names.index("skull")
    reference = panel._phantom_storage("hu", 48)()
    assert np.mean(labels == skull) == pytest.approx(np.mean(reference[2] == skull), rel=0.1)
    assert np.median(back[labels == skull]) >= 700


def test_the_voxel_size_variants_keep_the_voxels():
    reference = panel._phantom_storage("hu", 48)()
    for scale in panel.VOXEL_SIZE_SCALES:
        values, ijk_to_ras, labels, _names, _storage = panel._phantom_storage("hu", 48, spacing_scale=scale)()
        np.testing.assert_array_equal(values, reference[0])
        np.testing.assert_array_equal(labels, reference[2])
        np.testing.assert_allclose(_spacing(ijk_to_ras), _spacing(reference[1]) * scale)
    keys = {v.key for v in panel.PANEL}
    assert {f"phantom-x{s:g}" for s in panel.VOXEL_SIZE_SCALES} <= keys


def test_band_labels_take_the_first_band_that_holds_a_value():
    values = np.array([[[0, 1, 50, 99, 100, 101, 255]]], dtype=np.uint8)
    labels, names = panel.band_labels(values, (("empty", 0, 0), ("core", 100, panel.INF), ("envelope", 1, 100)))
    assert names == ("other", "empty", "core", "envelope")
    np.testing.assert_array_equal(labels.ravel(), [1, 3, 3, 3, 2, 2, 2])
    labels, names = panel.band_labels(values.astype(np.float32), (("head", 40, panel.INF),))
    np.testing.assert_array_equal(labels.ravel(), [0, 0, 1, 1, 1, 1, 1])


def test_every_panel_entry_names_its_labels_and_a_known_kind():
    for volume in (*panel.REFERENCES, *panel.PANEL):
        assert volume.kind in KINDS, volume.key
    keys = [v.key for v in (*panel.REFERENCES, *panel.PANEL)]
    assert len(keys) == len(set(keys))
    for real in panel.REAL_VOLUMES:
        bands = {name for name, _, _ in real.bands}
        assert set(real.shown_for) <= bands and (real.fog is None or real.fog in bands), real.key
    for group, members in panel.VARIANT_GROUPS.items():
        assert set(members) <= set(keys), group


@pytest.mark.skipif(not (panel.SHARED_DATA / "sim-fuel.nii.gz").is_file(), reason="../shared/data is not here")
def test_a_real_volume_reads_with_its_band_labels():
    volume = next(v for v in panel.PANEL if v.key == "sim-fuel")
    values, _ijk_to_ras, labels, names, storage = volume.load()
    assert values.shape == (32, 33, 64) and storage is None
    assert np.all(values[labels == names.index("plume")] >= 40)
    assert np.all(values[labels == names.index("empty")] == 0)


def test_the_look_panel_measures_shares_and_survives_a_failing_volume(capsys, monkeypatch):
    look_panel = _load("look_panel")

    def broken():
        raise RuntimeError("no such scanner")

    failing = panel.PanelVolume("broken", "broken", "CT", broken, (), None, lambda: True, "test")
    small = panel.PanelVolume(
        "small-phantom", "phantom 40^3", "CT", panel._phantom_storage("hu", 40), ("skull",), "air", lambda: True, "test"
    )
    monkeypatch.setattr(look_panel, "PANEL", (failing, small))
    monkeypatch.setattr(look_panel, "REFERENCES", ())
    assert look_panel.main(["--no-write"]) == 1
    out, err = capsys.readouterr()
    assert "broken FAILED: RuntimeError: no such scanner" in err
    assert "| small-phantom |" in out
    case = look_panel.measure(small)
    for row in case["looks"]:
        assert sum(row["shares"].values()) == pytest.approx(1.0)
        assert 0.0 <= row["scanned_for"] <= 1.0 and row["fog"] == pytest.approx(0.0, abs=0.05)
        assert row["oracle"] == [], row["look"]  # every look keeps its promise (check_look)
    assert any(row["first_click"] for row in case["looks"])


@cache  # a panel volume's design takes seconds; the tests only read its measures
def _measured(key):
    look_panel = _load("look_panel")
    volume = next(v for v in (*panel.REFERENCES, *panel.PANEL) if v.key == key)
    if not volume.available():
        pytest.skip(f"{key} is not on this machine")
    return look_panel.measure(volume)


def _first_click(case):
    return next(row for row in case["looks"] if row["first_click"])


@pytest.mark.parametrize(
    "original, clipped",
    [
        ("phantom-hu", "phantom-clipped"),
        ("head-ct-hu", "head-ct-clipped"),
        ("head-ct-clipped", "head-ct-clipped-8bit"),  # 1 class, nothing shown, before the distinct isovalues
        ("micro-ct", "micro-ct-8bit"),
        ("specimen-ct", "specimen-ct-8bit"),
        # 0.27 apart when the CSF's tissue was placed by its largest class alone (a toss-up among three)
        ("mr-brain-stroke-t1", "mr-brain-stroke-t1-uint16"),
    ],
)
def test_another_storage_gives_nearly_the_first_click_of_its_original(original, clipped):
    # The clipped storage turns everything below 94 HU into background: the original's first click must not keep the
    # soft tissue as a veil the clipped one cannot show (0.29 of the picture apart when the dense parts were promised
    # half of it). The micro-CT's 8-bit export through a window saturates its densest voxels.
    shares = [_first_click(_measured(key))["scanned_for"] for key in (original, clipped)]
    assert abs(shares[0] - shares[1]) <= 0.15, shares


def test_a_t1_head_stored_as_a_few_hundred_integers_is_still_an_mri():
    # Stored as uint16 0..300, bins hold one or two of the values, and the intensity model fitted to the counts took
    # the pattern for tissues: the head was taken for a CT, and its first click showed the scalp fat as bone. Read
    # through a slope as float32, the same values took the same pattern for tissues until their lattice was found.
    cases = [_measured(key) for key in panel.VARIANT_GROUPS["T1 head storages"]]
    assert [case["kind_detected"] for case in cases] == ["mr", "mr", "mr"]
    assert len({_first_click(case)["look"] for case in cases}) == 1


@pytest.mark.parametrize("key", ["micro-ct-8bit", "specimen-ct-8bit"])
def test_a_micro_ct_exported_through_a_window_shows_no_air_in_any_look(key):
    # micro-ct-8bit: the air around the tube lies 3 noise widths below the ethanol (the background); in the 8-bit
    # export its lower half lay just past 4, and every look but the first click drew it (0.30-0.41 of the picture):
    # nothing lies beyond it on that side, so it is the air's noise, fog.
    # specimen-ct-8bit: an auto-contrast window puts the background class in the middle of the air, and the model
    # fitted the air's tails a third as wide as its noise: the upper tail was offered as thin structures (0.85 air).
    windowed = _measured(key)
    assert all(row["fog"] <= 0.01 for row in windowed["looks"]), [(r["look"], r["fog"]) for r in windowed["looks"]]


@pytest.mark.parametrize(
    "key, at_least",
    [
        ("plant-ct", 0.2),  # the twigs: 0.075 at best when the thin-structures look left the pot as it was
        ("ct-head-8bit-oblique", 0.85),  # the skull: 0.43 at best when the dense classes started at the scalp's blur
        ("abdomen-ct-8bit", 0.5),  # the bone: 0.21 at best (inside the organs) before the densest-parts look
    ],
)
def test_the_gallery_offers_a_look_showing_what_was_scanned_for(key, at_least):
    case = _measured(key)
    best = max(case["looks"], key=lambda row: row["scanned_for"])
    assert best["scanned_for"] >= at_least, (best["look"], best["scanned_for"])
    assert all(row["oracle"] in ([], None) for row in case["looks"])


@pytest.mark.parametrize(
    "key, offered",
    [
        ("plant-ct", True),
        ("angiogram", True),
        ("abdomen-ct", False),
        ("chest-cta-8bit", False),
        ("phantom-clipped", False),
        ("head-ct-clipped", False),
    ],
)
def test_thin_structures_are_offered_for_twigs_and_vessels_not_for_a_surfaces_skin(key, offered):
    # The rim of twigs and of a vessel tree lies along lines in the open, and is the first click there; an abdomen's
    # or a chest's skin lies against the body, and what a clip at 0 HU leaves of a soft tissue fills it as the tissue
    # did (the speckle of its noise).
    looks = [row["look"] for row in _measured(key)["looks"]]
    assert ("thin-structures" in looks) is offered, looks
    assert (_first_click(_measured(key))["look"] == "thin-structures") is offered
