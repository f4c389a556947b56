"""The default look: kind of volume, ramp colours, opacity rules, opacity per millimetre."""

import numpy as np
import pytest

from IsoSimilarityTFLib import design_transfer_function
from IsoSimilarityTFLib.classes import IsovalueClass
from IsoSimilarityTFLib.look import RAMP, default_look, detect_kind, gradient_ramp_top, ramp_colors


def make_classes(voxels, contact=None, background=0):
    contact = contact or [0.0] * len(voxels)
    return [
        IsovalueClass(
            id=i, rank=1, voxels=v, fraction=0.0, isovalue_bins=[i], value_ranges=[[i, i + 1]], exemplar_bin=i,
            background=i == background, background_contact=contact[i],
        )
        for i, v in enumerate(voxels)
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("dtype", "value_range", "modality", "kind"),
    [
        (np.int16, (-1024, 3071), None, "ct"),
        (np.float32, (-1000.0, 2000.0), None, "ct"),
        (np.int16, (0, 4095), None, "mr"),
        (np.float32, (0.0, 1.0), None, "mr"),
        (np.uint8, (0, 254), None, "8bit"),
        (np.int16, (0, 200), None, "8bit"),
        (np.int16, (0, 4095), "CT", "ct"),
        (np.int16, (-1024, 3071), "MR", "mr"),
    ],
)
def test_kind_detection(dtype, value_range, modality, kind):
    assert detect_kind(np.dtype(dtype), value_range, modality) == kind


def test_unknown_modality_is_refused():
    with pytest.raises(ValueError, match="modality"):
        detect_kind(np.dtype(np.int16), (0, 1), "PET")


def test_ramp_is_ordered_dark_red_to_white():
    places = np.linspace(0, 1, 6)
    colors = ramp_colors(places)
    brightness = colors.sum(axis=1)
    assert np.all(np.diff(brightness) > 0)
    np.testing.assert_allclose(colors[0], RAMP[0][1])
    np.testing.assert_allclose(colors[-1], [1, 1, 1])
    assert colors[0][0] > 2 * colors[0][2]  # red, not grey


def test_tissue_colours_follow_intensity_and_are_shared_by_their_classes():
    classes = make_classes([1000, 300, 300, 200, 200, 100])
    tissue_of = np.array([0, 1, 1, 2, 2, 3])
    colors, _, visible = default_look(classes, tissue_of, np.arange(6.0), "mr")
    assert colors[1] == colors[2] and colors[3] == colors[4]
    brightness = [sum(colors[c]) for c in (1, 3, 5)]
    assert brightness == sorted(brightness) and len(set(brightness)) == 3
    assert not visible[0] and all(visible[1:])
    distinct, _, _ = default_look(classes, tissue_of, np.arange(6.0), "mr", colors="distinct")
    assert distinct[1] == distinct[2] and distinct[1] != distinct[3]


def test_mr_opacity_peaks_at_the_main_tissue_not_the_brightest():
    # Background, CSF-like, grey, white (the main bright tissue), then 3 % of bright fat.
    classes = make_classes([5000, 300, 3000, 3000, 180])
    tissue_of = np.arange(5)
    _, opacity, visible = default_look(classes, tissue_of, np.arange(5.0), "mr")
    assert opacity[0] == 0 and opacity[1] < opacity[2] < opacity[3]
    assert visible[4] and opacity[4] < opacity[2]  # shown, never emphasised


def test_densest_real_tissue_is_always_shown_and_tiny_classes_never_stand_out():
    # Four soft classes, one real dense class, one class of 3 voxels denser still.
    classes = make_classes([100000, 40000, 30000, 20000, 10000, 5000, 3])
    values = np.array([-1000, 0, 40, 60, 80, 1200, 2500.0])
    tissue_of = np.arange(7)
    _, opacity, visible = default_look(classes, tissue_of, values, "ct", max_shown=2)
    assert visible[5]  # beyond the size cut but the densest real tissue
    assert opacity[5] == max(opacity) and opacity[6] <= opacity[5]
    assert max(opacity[1:5]) < 0.05  # soft tissue nearly clear, no veil


def test_fringe_classes_start_hidden():
    classes = make_classes([1000, 50, 500], contact=[1.0, 0.9, 0.1])
    _, _, visible = default_look(classes, np.arange(3), np.arange(3.0), "mr")
    assert visible == [False, False, True]


def test_opacity_is_per_millimetre_whatever_the_spacing():
    values = np.zeros((16, 16, 16), dtype=np.int16) - 1000
    values[4:12, 4:12, 4:12] = 1000
    fine = design_transfer_function(values, (0.5, 0.5, 0.5))
    coarse = design_transfer_function(values, (2.0, 2.0, 2.0))
    assert fine.unit_distance == coarse.unit_distance == 1.0
    assert fine.volume_property().GetScalarOpacityUnitDistance() == 1.0


def test_modality_option_chooses_the_curve():
    rng = np.random.default_rng(0)
    values = np.where(np.indices((20, 20, 20)).sum(axis=0) > 25, 1000, 100) + rng.normal(0, 10, (20, 20, 20))
    assert design_transfer_function(values).kind == "mr"
    assert design_transfer_function(values, modality="CT").kind == "ct"


def test_gradient_opacity_is_an_option_off_by_default():
    values = np.zeros((16, 16, 16), dtype=np.int16) - 1000
    values[4:12, 4:12, 4:12] = 40
    values[6:10, 6:10, 6:10] = 1000
    off = design_transfer_function(values, (1.0, 1.0, 1.0))
    gradient = off.volume_property().GetGradientOpacity()
    assert off.gradient_ramp_top is None and gradient.GetValue(0.0) == gradient.GetValue(500.0) == 1.0
    on = design_transfer_function(values, (1.0, 1.0, 1.0), gradient_opacity="auto")
    top = on.gradient_ramp_top
    gradient = on.volume_property().GetGradientOpacity()
    assert top > 0 and gradient.GetValue(0.0) == 0.0 and gradient.GetValue(top) == pytest.approx(1.0)
    assert gradient_ramp_top([0.0, 100.0, 300.0]) == pytest.approx(75.0)  # median contrast 150 over 2 mm


def test_designs_fit_the_gpu_lookup_table():
    """VTK's own estimate (EstimateMinNumberOfSamples, as the GPU ray caster computes it) stays at 4096 or less."""
    from isosimtf.rendering import lookup_table_width

    rng = np.random.default_rng(3)
    values = (np.indices((24, 24, 24)).sum(axis=0) * 60 - 1500 + rng.normal(0, 30, (24, 24, 24))).astype(np.int16)
    for tissues in ("auto", "all"):
        design = design_transfer_function(values, (0.5, 0.5, 0.5), tissues=tissues)
        assert lookup_table_width(design.volume_property(), design.value_range) <= 4096


def test_ct_colour_follows_each_class_hu():
    classes = make_classes([100000, 40000, 30000, 20000, 10000])
    values = np.array([-1000, 40, 300, 700, 1200.0])
    tissue_of = np.array([0, 1, 1, 1, 2])
    ct, _, _ = default_look(classes, tissue_of, values, "ct")
    assert [sum(ct[c]) for c in (1, 2, 3, 4)] == sorted(sum(ct[c]) for c in (1, 2, 3, 4))
    assert ct[2] != ct[3]  # one tissue, two densities, two colours on CT
    mr, _, _ = default_look(classes, tissue_of, values, "mr")
    assert mr[1] == mr[2] == mr[3]  # one colour per tissue on uncalibrated data


@pytest.mark.parametrize("colors", ["ramp", "distinct"])
@pytest.mark.parametrize("kind", ["ct", "mr", "8bit"])
def test_a_single_background_class_gets_a_look_that_shows_nothing(kind, colors):
    """Affinity propagation may find one class only, the background: nothing to colour or show, and no error."""
    colors_out, opacities, visible = default_look(
        make_classes([5544]), np.zeros(1, int), np.zeros(1), kind, colors=colors
    )
    assert visible == [False] and opacities == [0.0] and len(colors_out[0]) == 3


def test_a_design_with_a_single_class_shows_nothing():
    """A small CT-like volume whose isovalues all fall into one class (found by a randomized sweep of the engine)."""
    rng = np.random.default_rng(2)
    shape = (33, 12, 14)
    rng.choice([9, 17, 33])  # the sweep drew this before the volume
    r = np.sqrt(((np.indices(shape) - np.array(shape)[:, None, None, None] / 2) ** 2).sum(0))
    values = (np.select([r < 3, r < 5], [1000, 300], -1000) + rng.normal(0, 30, shape)).astype(np.int16)
    design = design_transfer_function(
        values, (0.5, 0.5, 1.0), n_bins=16, crossing="strict", background="largest", unconverged="keep"
    )
    assert len(design.classes) == 1 and design.classes[0].background
    assert not any(design.is_shown(c.id) for c in design.classes)
    assert design.volume_property() is not None
