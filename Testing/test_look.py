"""The default look: the visibility step, storage invariance, kind detection, colours, ramps, per-mm opacity."""

import dataclasses

import numpy as np
import pytest

from IsoSimilarityTFLib import TransferFunctionDesign, design_transfer_function
from IsoSimilarityTFLib.classes import IsovalueClass
from IsoSimilarityTFLib.look import (
    IVORY_PLACE,
    RAMP,
    SHOWN_PLACE,
    _VisibilityStep,
    bin_opacity_of,
    default_look,
    dense_tail,
    detect_kind,
    fog_apart,
    fringe_cores_apart,
    gradient_ramp_top,
    ramp_colors,
    ramped_opacity,
)
from IsoSimilarityTFLib.roles import RULES
from IsoSimilarityTFLib.visibility import Preview, preview_bins, preview_steps, visibility_histogram
from isosimtf.phantom import head_phantom


def make_classes(voxels, contact=None, background=0):
    contact = contact or [0.0] * len(voxels)
    return [
        IsovalueClass(
            id=i, rank=1, voxels=v, fraction=0.0, isovalue_bins=[i], value_ranges=[[i, i + 1]], exemplar_bin=i,
            background=i == background, background_contact=contact[i],
        )
        for i, v in enumerate(voxels)
    ]  # fmt: skip


# The ray caster ------------------------------------------------------------------------------------------------------


def slow_visibility(bins, spacing, opacity, unit_distance):
    """Front-to-back compositing written out: every ray of the six axis directions, sample by sample."""
    light = np.zeros(opacity.size)
    spacing_zyx = spacing[::-1]
    for axis in range(3):
        stack = np.moveaxis(bins, axis, 0)
        for reverse in (False, True):
            ordered = stack[::-1] if reverse else stack
            for ray in np.ndindex(*ordered.shape[1:]):
                transmittance = 1.0
                for sample in ordered[(slice(None), *ray)]:
                    alpha = 1.0 - (1.0 - opacity[sample]) ** (spacing_zyx[axis] / unit_distance)
                    light[sample] += transmittance * alpha
                    transmittance *= 1.0 - alpha
    return light


@pytest.mark.parametrize("seed", range(6))
def test_visibility_histogram_matches_the_slow_ray_caster(seed):
    rng = np.random.default_rng(seed)
    shape = tuple(int(n) for n in rng.integers(2, 7, 3))
    n_bins = int(rng.integers(2, 9))
    bins = rng.integers(0, n_bins, shape)
    spacing = tuple(float(s) for s in rng.uniform(0.3, 3.0, 3))
    opacity = rng.uniform(0, 1, n_bins)
    opacity[rng.integers(0, n_bins)] = 1.0  # an opaque bin: what lies behind it gets no light
    preview = Preview(bins, spacing, n_bins)
    fast = visibility_histogram(preview, opacity)
    slow = slow_visibility(bins, spacing, opacity, preview.unit_distance)
    np.testing.assert_allclose(fast, slow, rtol=1e-5, atol=1e-6)


def test_preview_is_about_cubic_and_small():
    steps, spacing = preview_steps((108, 256, 256), (0.957, 0.957, 1.5))
    assert steps == (3, 5, 5) and spacing == pytest.approx((4.785, 4.785, 4.5))
    preview = preview_bins(np.zeros((108, 256, 256), np.uint8), (0.957, 0.957, 1.5), 256)
    assert preview.bins.shape == (36, 52, 52) and preview.bins.size <= 48**3
    assert preview_steps((10, 10, 10), (1, 1, 1))[0] == (1, 1, 1)  # small volumes are kept whole


# Boundary ramps ------------------------------------------------------------------------------------------------------


def test_steps_climb_over_the_noise_width_on_the_more_opaque_side():
    opacity = np.array([0.0, 0.0, 0.6, 0.6, 0.6, 0.6, 0.2, 0.2, 0.2])
    # Rising 0 -> 0.6 at bin 2: bins 2 and 3 climb by thirds; falling 0.6 -> 0.2 at bin 6: bins 5 and 4 climb from
    # 0.2 by thirds of 0.4; where two ramps meet the lower one holds. The hidden side and the 0.2 side keep theirs.
    expected = [0.0, 0.0, 0.2, 0.4, 0.2 + 0.8 / 3, 0.2 + 0.4 / 3, 0.2, 0.2, 0.2]
    np.testing.assert_allclose(ramped_opacity(opacity, 3.0), expected)
    np.testing.assert_array_equal(ramped_opacity(opacity, 1.0), opacity)  # under two bins: no ramp


# Kind of volume ------------------------------------------------------------------------------------------------------


def test_the_hint_wins_and_unknown_modalities_are_refused():
    assert detect_kind([10, 50], [100, 10], 1.0, "CT") == "ct"
    assert detect_kind([10, 50], [100, 10], 1.0, "MRI") == "mr"
    with pytest.raises(ValueError, match="modality"):
        detect_kind([], [], 1.0, "PET")


def test_a_dense_tail_enclosed_by_the_largest_tissue_is_a_ct():
    means, voxels = [20.0, 70.0, 140.0], [230.0, 700.0, 65.0]  # fat, soft tissue, bone (the head CT's model)
    assert dense_tail(means, voxels, 2.6) == [2]
    assert detect_kind(means, voxels, 2.6, encloses=lambda outer, inner: 0.99) == "ct"
    # Not enclosed by it (scalp fat around the brain), too close (4 noise widths), or not a tail (white matter).
    assert detect_kind(means, voxels, 2.6, encloses=lambda outer, inner: 0.2) == "mr"
    assert detect_kind([20.0, 70.0, 80.0], voxels, 2.6) == "mr"
    assert detect_kind([77.0, 155.0, 206.0], [47.0, 483.0, 470.0], 7.75) == "mr"


@pytest.mark.parametrize("above, tail", [(RULES.tail_share * 0.99, True), (RULES.tail_share * 1.01, False)])
def test_a_dense_tail_holds_at_most_the_tail_share_of_the_largest_tissue(above, tail):
    # Soft tissue of 1000 voxels; the tissues above it hold `above` of that, the bone and a second dense tissue.
    voxels = [230.0, 1000.0, 1000.0 * above / 2, 1000.0 * above / 2]
    assert (dense_tail([20.0, 70.0, 140.0, 160.0], voxels, 2.6) != []) is tail


@pytest.mark.parametrize("gap, tail", [(RULES.dense_separation + 0.05, True), (RULES.dense_separation - 0.05, False)])
def test_a_tissue_of_the_dense_tail_lies_the_dense_separation_above_the_largest(gap, tail):
    # Bone `gap` noise widths of 2.6 bins above the soft tissue (bin 70).
    assert (dense_tail([20.0, 70.0, 70.0 + gap * 2.6], [230.0, 700.0, 65.0], 2.6) == [2]) is tail


@pytest.mark.parametrize("share, tail", [(RULES.real_share * 1.02, True), (RULES.real_share * 0.98, False)])
def test_a_tissue_of_the_dense_tail_is_real(share, tail):
    # The dense tissue holds `share` of all the voxels of the tissues.
    others = 1230.0
    dense = share * others / (1.0 - share)
    assert (dense_tail([20.0, 70.0, 140.0], [230.0, 1000.0, dense], 2.6) == [2]) is tail


@pytest.mark.parametrize("contact, shown", [(RULES.rim_contact - 0.01, True), (RULES.rim_contact + 0.01, False)])
def test_a_tissue_most_of_whose_voxels_touch_the_background_starts_hidden(contact, shown):
    classes = make_classes([10_000, 1000, 3000], contact=[1.0, contact, 0.0])
    look = default_look(classes, np.arange(3), np.array([0.0, 20.0, 40.0]), "mr", noise_sd=1.0)
    assert look.visible == [False, shown, True]


@pytest.mark.parametrize("gap, shown", [(RULES.fog_separation + 0.1, True), (RULES.fog_separation - 0.1, False)])
def test_a_tissue_is_fog_where_its_largest_class_lies_not_where_its_mean_does(gap, shown):
    # Tissue 1 is a partial-volume tail (1 and 2 noise widths above the background) and its peak, `gap` noise widths
    # above it: its mean lies within fog_separation of the background either way (a head MRI's skin, CSF and grey
    # matter in one tissue, whose mean the tail pulls down); its peak decides.
    classes = make_classes([10_000, 900, 900, 1000, 500])
    means = np.array([0.0, 1.0, 2.0, gap, 10.0])
    assert (900 * 1.0 + 900 * 2.0 + 1000 * gap) / 2800 < RULES.fog_separation
    look = default_look(classes, np.array([0, 1, 1, 1, 2]), means, "mr", class_bins=means, noise_sd=1.0)
    assert look.visible == [False, shown, shown, shown, True]


@pytest.mark.parametrize("gap, shown", [(RULES.fog_separation + 0.1, True), (RULES.fog_separation - 0.1, False)])
def test_the_first_click_decides_fog_in_the_width_it_is_given(gap, shown):
    # The model's width is 3 bins, the fog's 1 (an MRI's voxels' noise): the low tissue's largest class `gap` fog
    # widths above the background (within 4 model widths either way) is shown beyond 4 of them; without it, never.
    classes = make_classes([10_000, 900, 1000, 500])
    means = np.array([0.0, 1.0, gap, 20.0])
    tissue_of = np.array([0, 1, 1, 2])
    look = default_look(classes, tissue_of, means, "mr", class_bins=means, noise_sd=3.0, fog_sd=1.0)
    assert look.visible[2] == shown
    assert not default_look(classes, tissue_of, means, "mr", class_bins=means, noise_sd=3.0).visible[2]


@pytest.mark.parametrize(
    "kind, offset, rim, filled",
    [("mr", -0.01, False, True), ("mr", 0.01, False, False), ("ct", -0.01, False, False), ("mr", -0.01, True, False)],
)
def test_in_a_surface_a_tissue_between_two_shown_ones_is_shown(kind, offset, rim, filled):
    # With room for 2 classes, the largest tissue (classes 1-2, `share` of the foreground) is shown and the densest
    # real one (class 4) always. Where the largest fills the object (fill_share just under its share) on data that
    # are not CT-like, it is the object's surface and the tissue between them (class 3) is shown too, past
    # max_classes, unless it lies on the background's fringe (`rim`: most of its voxels touch it); a stray tissue
    # above the densest real one (class 5, under 1% of the voxels) is not between two shown ones and stays hidden.
    voxels = [10_000, 2000, 2000, 1000, 500, 10]
    share = 4000 / sum(voxels[1:])
    rules = dataclasses.replace(RULES, fill_share=share + offset)
    classes = make_classes(voxels, contact=[1.0, 0.0, 0.0, 0.9 if rim else 0.0, 0.0, 0.0])
    look = default_look(
        classes, np.array([0, 1, 1, 2, 3, 4]), np.arange(6.0) * 10, kind, noise_sd=0.2, max_classes=2, rules=rules
    )
    assert look.visible == [False, True, True, filled, True, False]


# The visibility step -------------------------------------------------------------------------------------------------


def shell_volume(n=40, noise=0.0, seed=0):
    """Air, a thick soft shell (bin 10) around a small dense core (bin 30), optional noise in bins."""
    z, y, x = np.indices((n, n, n)) - (n - 1) / 2
    r = np.sqrt(x**2 + y**2 + z**2)
    bins = np.select([r < 5, r < 17], [30, 10], 0).astype(float)
    bins += np.random.default_rng(seed).normal(0, noise, bins.shape)
    return np.clip(np.round(bins), 0, 39).astype(np.intp)


def shell_look(preview, kind="ct", rules=RULES):
    """One class per bin; tissues air (bins 0-4, class 0 the background), soft (5-19), dense (20-39)."""
    voxels = np.bincount(shell_volume().ravel(), minlength=40)
    classes = make_classes(voxels.tolist())
    tissue_of = np.select([np.arange(40) < 5, np.arange(40) < 20], [0, 1], 2)
    bins = np.arange(40.0)
    return default_look(
        classes, tissue_of, bins, kind, labels=np.arange(40), class_bins=bins, preview=preview, rules=rules
    )


def test_an_enclosed_dense_tissue_is_seen_through_the_tissue_around_it():
    preview = Preview(shell_volume(), (1.0, 1.0, 1.0), 40)
    start = shell_look(None)  # the monotone start: the soft shell is opaque and hides the core
    look = shell_look(preview)
    assert start.opacities[10] == RULES.opacity_low and start.opacities[30] == RULES.opacity_high
    assert look.opacities[30] >= RULES.opacity_high and look.opacities[10] < start.opacities[10]
    core = [visibility_histogram(preview, np.array(o))[20:].sum() for o in (start.opacities, look.opacities)]
    assert core[1] > core[0]
    shares = look.tissue_shares
    assert shares.sum() == pytest.approx(1.0) and shares[0] == 0.0
    # The core keeps at least RULES.seen of the light it gives alone.
    opacity = np.array(look.opacities)
    alone = visibility_histogram(preview, np.where(np.arange(40) >= 20, opacity, 0.0))[20:].sum()
    assert visibility_histogram(preview, opacity)[20:].sum() >= 0.95 * RULES.seen * alone
    # Its partial volume ramps in from 4 noise widths above the soft tissue (bin 14) to the core (bin 20).
    assert look.opacities[13] == look.opacities[10] < look.opacities[16] < look.opacities[19] < look.opacities[20]


@pytest.mark.parametrize("separation, cleared", [(19.9, True), (20.1, False)])
def test_a_tissue_is_cleared_in_front_of_a_feature_it_lies_the_dense_separation_below(separation, cleared):
    # The soft shell (bin 10) lies 20 noise widths below the core (bin 30): apart from it when the rule says so.
    look = shell_look(
        Preview(shell_volume(), (1.0, 1.0, 1.0), 40), rules=dataclasses.replace(RULES, dense_separation=separation)
    )
    assert look.opacities[30] >= RULES.opacity_high
    assert (look.opacities[10] < RULES.opacity_low) is cleared


@pytest.mark.parametrize("ramp_start", [4.5, 6.5])
def test_the_partial_volume_ramp_starts_ramp_start_noise_widths_above_the_tissue_below(ramp_start):
    rules = dataclasses.replace(RULES, ramp_start=ramp_start)
    look = shell_look(Preview(shell_volume(), (1.0, 1.0, 1.0), 40), rules=rules)
    first = int(np.ceil(10 + ramp_start))  # the soft tissue's mean (bin 10) plus ramp_start noise widths of 1 bin
    assert look.opacities[first - 1] == look.opacities[10] < look.opacities[first]


@pytest.mark.parametrize("seen", [0.28, 0.6, 0.95])
def test_an_enclosed_feature_keeps_the_seen_share_of_its_light_whatever_it_is(seen):
    # Uncleared (with a dense separation over 20 noise widths), the core keeps 0.26 of its light: at 0.28, within a
    # tenth of the aim, the soft shell is cleared all the same. It is cleared only as far as the rule asks: the
    # estimate T ** s is exact on a shell of one thickness and lands just over the aim.
    preview = Preview(shell_volume(), (1.0, 1.0, 1.0), 40)
    opacity = np.array(shell_look(preview, rules=dataclasses.replace(RULES, seen=seen)).opacities)
    alone = visibility_histogram(preview, np.where(np.arange(40) >= 20, opacity, 0.0))[20:].sum()
    kept = visibility_histogram(preview, opacity)[20:].sum() / alone
    assert seen - 0.005 <= kept <= seen + 0.01


def test_a_fog_class_next_to_the_background_stays_clear():
    # Noise in the air: a class just above the background, touching little of it (it is everywhere in the air).
    classes = make_classes([5000, 400, 3000, 800], contact=[1.0, 0.3, 0.0, 0.0])
    tissue_of = np.arange(4)
    means = np.array([0.0, 2.0, 20.0, 40.0])  # the fog 2 noise widths from the air, under RULES.fog_separation
    labels = np.repeat(np.arange(4), 10)
    bins = np.random.default_rng(0).integers(0, 40, (12, 12, 12))
    look = default_look(classes, tissue_of, means, "mr", labels=labels, class_bins=means, noise_sd=1.0,
                        preview=Preview(bins, (1.0, 1.0, 1.0), 40))  # fmt: skip
    assert look.visible == [False, False, True, True] and look.tissue_shares[1] == 0.0


@pytest.mark.parametrize("gap, shown", [(RULES.fog_separation - 0.05, False), (RULES.fog_separation + 0.05, True)])
def test_a_tissue_within_the_fog_separation_of_the_background_starts_hidden(gap, shown):
    # The low tissue lies `gap` noise widths of 2 bins above the air, touching little of it.
    classes = make_classes([5000, 400, 3000, 800], contact=[1.0, 0.3, 0.0, 0.0])
    means = np.array([0.0, 2.0 * gap, 20.0, 40.0])
    bins = np.random.default_rng(0).integers(0, 40, (12, 12, 12))
    look = default_look(classes, np.arange(4), means, "mr", labels=np.repeat(np.arange(4), 10), class_bins=means,
                        noise_sd=2.0, preview=Preview(bins, (1.0, 1.0, 1.0), 40))  # fmt: skip
    assert look.visible == [False, shown, True, True]
    if not shown:  # hidden, it keeps the ramp's low end: what a user who shows it starts from
        assert look.opacities[1] == RULES.opacity_low


@pytest.mark.parametrize("factor, shown", [(1.05, True), (0.95, False)])
def test_the_densest_tissue_is_shown_beyond_max_classes_when_it_is_real(factor, shown):
    # max_classes 1 shows the soft tissue alone; the dense tissue holds `factor` times the real share.
    share = factor * RULES.real_share
    classes = make_classes([5000, 3000, round(3000 * share / (1 - share), 6)])
    means = np.array([0.0, 20.0, 40.0])
    look = default_look(classes, np.arange(3), means, "mr", class_bins=means, noise_sd=2.0, max_classes=1)
    assert look.visible == [False, True, shown]


@pytest.mark.parametrize("factor, real", [(1.05, True), (0.95, False)])
def test_a_stray_tissue_below_the_real_share_takes_the_opacity_of_the_real_one_below(factor, real):
    # A tissue holding `factor` times the real share lies between the soft tissue and the dense one.
    share = factor * RULES.real_share
    classes = make_classes([5000, 3000, 5000 * share / (1 - share), 2000])
    means = np.array([0.0, 10.0, 25.0, 35.0])
    bins = np.random.default_rng(0).integers(0, 40, (12, 12, 12))
    look = default_look(classes, np.arange(4), means, "mr", labels=np.repeat(np.arange(4), 10), class_bins=means,
                        noise_sd=1.0, preview=Preview(bins, (1.0, 1.0, 1.0), 40))  # fmt: skip
    middle = (RULES.opacity_low + RULES.opacity_high) / 2  # its place on the ramp of three tissues
    assert look.opacities[2] == (pytest.approx(middle) if real else look.opacities[1])


@pytest.mark.parametrize("seen", [0.56, 0.6, RULES.seen, 0.9])
def test_the_outer_surface_is_raised_until_it_gives_the_seen_share_of_its_rays(seen):
    # The shell in a field of view three times wider, rendered alone: the light it sends over the rays that cross it
    # (six axis views) reaches `seen`, to within the estimate of its thickness (it lands a little under, never over).
    # At the ramp's low end it gives 0.51: at 0.56, within a tenth of the aim, it is raised all the same.
    bins = np.zeros((120, 120, 120), dtype=np.intp)
    bins[40:80, 40:80, 40:80] = shell_volume()
    preview = Preview(bins, (1.0, 1.0, 1.0), 40)
    rules = dataclasses.replace(RULES, seen=seen, fill_share=1.0)  # the shell fills the object: seen alone
    opacity = np.array(shell_look(preview, kind="mr", rules=rules).opacities)
    soft = (np.arange(40) >= 5) & (np.arange(40) < 20)
    light = visibility_histogram(preview, bin_opacity_of(np.where(soft, opacity, 0.0), np.arange(40), 1.0))
    rays = sum(2 * soft[bins].any(axis=axis).sum() for axis in range(3))
    assert seen - 0.04 <= light[soft].sum() / rays <= seen + 0.01


def test_on_uncalibrated_data_the_outer_tissue_is_a_surface_and_the_top_of_the_ramp_is_reached():
    # The shell in a field of view three times wider: a voxel is 1.7 unit distances (not 5), so at the start the
    # shell lets light through and must be made a surface.
    bins = np.zeros((120, 120, 120), dtype=np.intp)
    bins[40:80, 40:80, 40:80] = shell_volume()
    preview = Preview(bins, (1.0, 1.0, 1.0), 40)
    look = shell_look(preview, kind="mr")
    assert look.opacities[30] == RULES.opacity_high  # the monotone ramp reaches its top
    assert look.opacities[10] > RULES.opacity_low  # the enclosing tissue made a surface where it lies
    assert look.tissue_shares[1] > 0.9
    # In the tight field of view the same shell already is a surface at the start: nothing to raise.
    tight = shell_look(
        Preview(shell_volume(), (1.0, 1.0, 1.0), 40), kind="mr", rules=dataclasses.replace(RULES, fill_share=1.0)
    )
    assert tight.opacities[10] == RULES.opacity_low and tight.tissue_shares[1] > 0.9


@pytest.mark.parametrize("offset, fills", [(-0.01, True), (0.01, False)])
def test_an_outer_tissue_that_fills_the_object_takes_the_ramps_top(offset, fills):
    # The shell holds `share` of the foreground's voxels: with fill_share just under it, it fills the object and is
    # a surface at the ramp's top (seen through its whole depth it is a veil over the core); just over, it is only
    # made seen (already, in this tight field of view: it stays at the ramp's low end).
    counts = np.bincount(shell_volume().ravel(), minlength=40)
    share = counts[10] / (counts[10] + counts[30])
    preview = Preview(shell_volume(), (1.0, 1.0, 1.0), 40)
    look = shell_look(preview, kind="mr", rules=dataclasses.replace(RULES, fill_share=share + offset))
    assert look.opacities[10] == (RULES.opacity_high if fills else RULES.opacity_low)
    # Its partial volume with the air (bin 0), below its peak (bin 10), is ramped in as the share of shell a voxel
    # holds: bin 5 is half shell. Above the peak it is the shell.
    if fills:
        assert look.opacities[5] == pytest.approx(0.5 * RULES.opacity_high)
        assert look.opacities[9] == pytest.approx(0.9 * RULES.opacity_high)
    else:
        assert look.opacities[5] == look.opacities[9] == RULES.opacity_low
    assert look.opacities[15] == look.opacities[10]


def test_a_skin_ramps_to_its_largest_class_not_its_mean():
    # A layer of bin 6 over the shell pulls the shell tissue's mean below bin 10, where its largest class lies: the
    # skin's share is measured up to the largest class, so bin 8 holds 0.8 of the shell.
    bins = shell_volume()
    z, y, x = np.indices(bins.shape) - (bins.shape[0] - 1) / 2
    bins[(np.sqrt(x**2 + y**2 + z**2) >= 17) & (np.sqrt(x**2 + y**2 + z**2) < 19)] = 6
    counts = np.bincount(bins.ravel(), minlength=40)
    assert (6 * counts[6] + 10 * counts[10]) / (counts[6] + counts[10]) < 9.0 and counts[10] > counts[6]
    voxels = counts.tolist()
    tissue_of = np.select([np.arange(40) < 5, np.arange(40) < 20], [0, 1], 2)
    look = default_look(
        make_classes(voxels), tissue_of, np.arange(40.0), "mr", labels=np.arange(40), class_bins=np.arange(40.0),
        preview=Preview(bins, (1.0, 1.0, 1.0), 40),
    )  # fmt: skip
    assert look.opacities[10] == RULES.opacity_high
    assert look.opacities[8] == pytest.approx(0.8 * RULES.opacity_high)


@pytest.mark.parametrize("background_bin, skins", [(-np.inf, []), (0.0, [1])])
def test_a_skin_is_ramped_against_a_background_only(background_bin, skins):
    # The filling shell as the outer surface, with the background at bin 0, or without one (background="none",
    # -inf): then nothing is ramped against it, and every opacity stays a number.
    bins = shell_volume()
    bins[bins == 10] = np.where(np.indices(bins.shape)[0][bins == 10] % 2 == 0, 10, 7)  # classes 7 and 10 in the shell
    tissue_of = np.select([np.arange(40) < 5, np.arange(40) < 20], [0, 1], 2)
    step = _VisibilityStep(
        Preview(bins, (1.0, 1.0, 1.0), 40), np.arange(40), tissue_of, [1, 2], np.array([0.0, 8.5, 30.0]),
        np.array([0, 10, 30]), np.arange(40.0), background_bin, noise_sd=1.0,
    )  # fmt: skip
    opacity = step.outer_surface(
        np.array([0.0, RULES.opacity_low, RULES.opacity_high]), [1, 2], np.array([0, 0.9, 0.1])
    )
    assert step.skins == skins and opacity[1] == RULES.opacity_high
    class_opacity = step.class_opacity(opacity)
    assert np.all(np.isfinite(class_opacity))
    assert class_opacity[7] == pytest.approx(0.7 * RULES.opacity_high if skins else RULES.opacity_high)


@pytest.mark.parametrize("fog_sd, ramped", [(1.2475, True), (1.2525, False)])
def test_a_skin_starts_where_the_backgrounds_noise_ends(fog_sd, ramped):
    # The background at bin 0: a skin bin 5 is half shell, shown when it lies at least ramp_start fog widths above
    # the background (4 x 1.2475 = 4.99), the air's noise when it does not (5.01).
    bins = shell_volume()
    tissue_of = np.select([np.arange(40) < 5, np.arange(40) < 20], [0, 1], 2)
    step = _VisibilityStep(
        Preview(bins, (1.0, 1.0, 1.0), 40), np.arange(40), tissue_of, [1, 2], np.array([0.0, 10.0, 30.0]),
        np.array([0, 10, 30]), np.arange(40.0), 0.0, noise_sd=1.0, fog_sd=fog_sd,
    )  # fmt: skip
    assert RULES.ramp_start == 4.0 and tissue_of[5] == 1
    opacity = step.outer_surface(
        np.array([0.0, RULES.opacity_low, RULES.opacity_high]), [1, 2], np.array([0, 0.9, 0.1])
    )
    class_opacity = step.class_opacity(opacity)
    assert class_opacity[5] == pytest.approx(0.5 * RULES.opacity_high if ramped else 0.0)
    assert class_opacity[6] == pytest.approx(0.6 * RULES.opacity_high)


def test_tissue_colours_follow_intensity_and_are_shared_by_their_classes():
    classes = make_classes([1000, 300, 300, 200, 200, 100])
    tissue_of = np.array([0, 1, 1, 2, 2, 3])
    look = default_look(classes, tissue_of, np.arange(6.0), "mr", noise_sd=0.2)
    colors = look.colors
    assert colors[1] == colors[2] and colors[3] == colors[4]
    brightness = [sum(colors[c]) for c in (1, 3, 5)]
    assert brightness == sorted(brightness) and len(set(brightness)) == 3
    assert colors[5] == [1.0, 1.0, 1.0]  # the densest tissue, not the largest, is white
    assert not look.visible[0] and all(look.visible[1:])
    distinct = default_look(classes, tissue_of, np.arange(6.0), "mr", colors="distinct", noise_sd=0.2).colors
    assert distinct[1] == distinct[2] and distinct[1] != distinct[3]


def test_no_shown_tissue_takes_the_dark_end_of_the_ramp():
    classes = make_classes([1000, 300, 200, 100])
    look = default_look(classes, np.arange(4), np.arange(4.0), "mr", noise_sd=0.2)
    assert look.colors[1] == pytest.approx(list(ramp_colors(np.array([SHOWN_PLACE]))[0]))  # the lowest shown: tan
    assert look.colors[3] == [1.0, 1.0, 1.0]
    middle = ramp_colors(np.array([SHOWN_PLACE + (1.0 - SHOWN_PLACE) * 0.5]))[0]  # halfway in value, halfway up
    assert look.colors[2] == pytest.approx(list(middle))


def test_a_large_bright_tissue_ends_at_ivory_not_white():
    classes = make_classes([1000, 600, 550])  # white matter: about as large as grey matter
    look = default_look(classes, np.arange(3), np.arange(3.0), "mr", noise_sd=0.2)
    assert look.colors[2] == pytest.approx(list(ramp_colors(np.array([0.75]))[0]))


@pytest.mark.parametrize("top, white", [(0.99, True), (1.01, False)])
def test_white_is_kept_for_a_densest_tissue_within_the_white_share(top, white):
    # The densest tissue holds just below or just above white_share of the largest one's 600 voxels.
    classes = make_classes([1000, 600, round(top * RULES.white_share * 600)])
    look = default_look(classes, np.arange(3), np.arange(3.0), "mr", noise_sd=0.2)
    end = 1.0 if white else 0.75
    assert look.colors[2] == pytest.approx(list(ramp_colors(np.array([end]))[0]))


def test_the_densest_real_tissue_is_always_shown_and_stray_voxels_follow_a_real_tissue():
    classes = make_classes([100000, 40000, 30000, 20000, 10000, 5000, 3])
    tissue_of = np.arange(7)
    means = np.array([0.0, 10, 12, 14, 16, 60, 90])
    labels = np.repeat(np.arange(7), 10)[:70]
    bins = np.random.default_rng(1).integers(0, 70, (10, 10, 10))
    preview = Preview(bins, (1.0, 1.0, 1.0), 70)
    look = default_look(classes, tissue_of, means, "ct", labels=labels, class_bins=means, max_classes=2,
                        preview=preview)  # fmt: skip
    assert look.visible[5] and not look.visible[6]  # beyond the size cut but the densest real tissue
    look = default_look(classes, tissue_of, means, "ct", labels=labels, class_bins=means, preview=preview)
    assert look.visible[6] and look.opacities[6] == look.opacities[5]  # 3 voxels denser: the real one's opacity


def test_fringe_classes_start_hidden():
    classes = make_classes([1000, 50, 500], contact=[1.0, 0.9, 0.1])
    look = default_look(classes, np.arange(3), np.array([0.0, 10.0, 20.0]), "mr")
    assert look.visible == [False, False, True]


@pytest.mark.parametrize("kind", ["ct", "mr", "8bit"])
@pytest.mark.parametrize("colors", ["ramp", "distinct"])
def test_a_single_background_class_gets_a_look_that_shows_nothing(kind, colors):
    """Affinity propagation may find one class only, the background: nothing to colour or show, and no error."""
    look = default_look(make_classes([5544]), np.zeros(1, int), np.zeros(1), kind, colors=colors,
                        labels=np.zeros(4, int), preview=Preview(np.zeros((3, 3, 3), int), (1, 1, 1), 4))  # fmt: skip
    assert look.visible == [False] and look.opacities == [0.0] and len(look.colors[0]) == 3


# Whole designs -------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def storages():
    """The 96^3 phantom in HU, as HU + 1024 in uint16, as an 8-bit export and as float32."""
    hu = head_phantom(96, seed=3).values
    low, high = float(hu.min()), float(hu.max())
    spacing = (2.5, 2.5, 2.5)
    volumes = {
        "hu": hu,
        "uint16": (hu.astype(np.int32) + 1024).clip(0, 65535).astype(np.uint16),  # air noise below -1024 clipped
        "8bit": np.round((hu - low) / (high - low) * 255).astype(np.uint8),
        "float": hu.astype(np.float32),
    }
    return {name: design_transfer_function(values, spacing) for name, values in volumes.items()}


def test_the_same_ct_in_any_storage_gets_the_same_look(storages):
    reference = storages["hu"]
    assert reference.kind == "ct"
    dense = max(t.id for t in reference.tissues)
    for name, design in storages.items():
        assert design.kind == "ct", name
        assert len(design.tissues) == len(reference.tissues), name
        for ours, theirs in zip(design.tissues, reference.tissues):
            assert ours.visible == theirs.visible, name
            assert ours.opacity == pytest.approx(theirs.opacity, abs=0.1), name
            assert ours.picture_share == pytest.approx(theirs.picture_share, abs=0.15), name
        # The skull gives most of the picture, whatever the storage.
        assert design.tissues[dense].picture_share > 0.5, name
    # A float copy is the same design, bit for bit.
    assert [t.to_dict() for t in storages["float"].tissues] == [t.to_dict() for t in reference.tissues]


def test_the_step_measures_the_transfer_function_it_writes(storages):
    """The tissues' shares of the picture are those of the written transfer function's bins, rendered again here,
    on the CT (a feature with its partial-volume ramp) and after regrouping."""
    design = TransferFunctionDesign.from_json(storages["hu"].to_json())
    for tissues in ("auto", design.hierarchy.auto + 2):
        design.regroup(tissues)
        light = visibility_histogram(design.preview, design.bin_looks()[1])
        by_tissue = np.bincount(design.tissue_of_class[design.labels], weights=light, minlength=len(design.tissues))
        np.testing.assert_allclose([t.picture_share for t in design.tissues], by_tissue / by_tissue.sum(), atol=1e-12)


def test_soft_tissue_on_a_ct_is_no_veil(storages):
    design = storages["hu"]
    soft = next(c for c in design.classes if any(lo <= 60 < hi for lo, hi in c.value_ranges))
    assert design.is_shown(soft.id) and soft.opacity <= 0.02  # per mm: 2 cm of it lets 2/3 of the light through
    skull = next(c for c in design.classes if any(lo <= 1000 < hi for lo, hi in c.value_ranges))
    assert skull.opacity >= RULES.opacity_high


def test_regrouping_runs_the_step_again_and_survives_json(storages):
    design = TransferFunctionDesign.from_json(storages["hu"].to_json())
    assert design.preview is not None
    np.testing.assert_array_equal(design.preview.bins, storages["hu"].preview.bins)
    design.regroup(design.hierarchy.max_tissues)
    shares = [t.picture_share for t in design.tissues]
    assert all(s is not None for s in shares) and sum(shares) == pytest.approx(1.0)
    design.regroup("auto")
    assert [t.to_dict() for t in design.tissues] == [t.to_dict() for t in storages["hu"].tissues]


def test_the_picture_does_not_change_with_the_voxel_size():
    """A micro-CT at 0.05 mm is as many voxels deep as a head at 1 mm: the same voxels at another voxel size give
    the same look, because the unit distance follows the volume's extent."""
    phantom = head_phantom(64, seed=1)
    values, spacing = phantom.values, np.asarray(phantom.spacing)
    designs = {scale: design_transfer_function(values, tuple(spacing * scale)) for scale in (1.0, 0.05, 3.0)}
    base = designs[1.0]
    for scale, design in designs.items():
        assert design.unit_distance == pytest.approx(base.unit_distance * scale, rel=1e-9)
        assert design.volume_property().GetScalarOpacityUnitDistance() == pytest.approx(design.unit_distance)
        for ours, theirs in zip(design.tissues, base.tissues):
            assert ours.picture_share == pytest.approx(theirs.picture_share, abs=0.05)
            assert ours.opacity == pytest.approx(theirs.opacity, abs=1e-9)


def test_the_unit_distance_is_the_extent_over_the_presets_scale():
    from IsoSimilarityTFLib.visibility import PRESET_EXTENT_MM

    head = Preview(np.zeros((40, 50, 50), dtype=np.uint16), (4.0, 4.0, 5.0), 2)  # 200 mm on every side
    assert head.unit_distance == pytest.approx(200.0 / PRESET_EXTENT_MM)
    slab = Preview(np.zeros((10, 40, 40), dtype=np.uint16), (1.0, 1.0, 1.0), 2)  # 40 x 40 x 10 mm
    assert slab.unit_distance == pytest.approx((40.0 * 40.0 * 10.0) ** (1 / 3) / PRESET_EXTENT_MM)


def test_modality_option_is_a_hint():
    rng = np.random.default_rng(0)
    values = np.where(np.indices((20, 20, 20)).sum(axis=0) > 25, 1000, 100) + rng.normal(0, 10, (20, 20, 20))
    assert design_transfer_function(values).kind == "mr"
    assert design_transfer_function(values, modality="CT").kind == "ct"


def test_ramp_is_ordered_dark_red_to_white():
    places = np.linspace(0, 1, 6)
    colors = ramp_colors(places)
    brightness = colors.sum(axis=1)
    assert np.all(np.diff(brightness) > 0)
    np.testing.assert_allclose(colors[0], RAMP[0][1])
    np.testing.assert_allclose(colors[-1], [1, 1, 1])
    assert colors[0][0] > 2 * colors[0][2]  # red, not grey


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


def test_max_classes_counts_classes_in_whole_tissues():
    """Tissues of 2, 4 and 3 classes (the first the smallest, below the others) and a dense one: 7 classes take the
    two largest whole tissues; the smallest lies below every shown one, so no gap rule shows it."""
    voxels = [9000, 400, 400, 900, 900, 900, 900, 700, 700, 700, 300]
    tissue_of = np.array([0, 1, 1, 2, 2, 2, 2, 3, 3, 3, 4])
    classes = make_classes(voxels)
    values = np.array([0.0, 5, 6, 10, 11, 12, 13, 20, 21, 22, 60])
    visible = default_look(classes, tissue_of, values, "mr", max_classes=7).visible
    assert sum(visible) == 8 and visible[3:10] == [True] * 7 and visible[-1]  # plus the densest real tissue
    assert not any(visible[1:3])
    assert default_look(classes, tissue_of, values, "mr", max_classes=0).visible == [False] * 10 + [True]


# A fringe tissue's core ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("top_contact, split", [(RULES.rim_contact - 0.01, True), (RULES.rim_contact + 0.01, False)])
def test_a_fringe_tissues_core_is_a_tissue_of_its_own(top_contact, split):
    # Tissue 1 is a fringe (most of its voxels touch the background): its top class is its core when it does not.
    contact = np.array([1.0, 0.9, 0.8, top_contact, 0.0])
    voxels = np.array([10_000.0, 500, 400, 300, 2000])
    tissue_of = np.array([0, 1, 1, 1, 2])
    apart = fringe_cores_apart(tissue_of, contact, voxels, np.array([True, False, False, False, False]))
    assert apart.tolist() == ([0, 1, 1, 2, 3] if split else [0, 1, 1, 1, 2])


@pytest.mark.parametrize("margin, split", [(0.01, True), (-0.01, False)])
def test_a_tissue_is_a_fringe_when_more_than_the_rim_contact_of_its_voxels_touch_the_background(margin, split):
    # Tissue 1: a class touching the background everywhere (contact 1) and a core touching it nowhere, in the
    # proportion that puts the tissue's contact `margin` above or below the rim contact.
    contact_share = RULES.rim_contact + margin
    voxels = np.array([10_000.0, 1000 * contact_share, 1000 * (1 - contact_share), 500])
    apart = fringe_cores_apart(np.array([0, 1, 1, 2]), np.array([1.0, 1.0, 0.0, 0.0]), voxels, np.arange(4) == 0)
    assert apart.tolist() == ([0, 1, 2, 3] if split else [0, 1, 1, 2])


def test_a_tissue_that_is_no_fringe_is_never_split():
    contact = np.array([1.0, 0.6, 0.1, 0.0])  # tissue 1 as a whole: 0.6 * 100 + 0.1 * 900 over 1000 = 0.15
    tissue_of = np.array([0, 1, 1, 2])
    apart = fringe_cores_apart(tissue_of, contact, np.array([10_000.0, 100, 900, 500]), np.arange(4) == 0)
    assert apart.tolist() == [0, 1, 1, 2]


def test_the_core_of_small_vessels_is_shown_with_the_fringe_cleared():
    """A thresholded angiogram: the lowest tissue holds the partial volume of every vessel; its classes touching the
    background are cleared, the one that does not (small vessels' cores) is shown (before: hidden with its tissue)."""
    classes = make_classes([90_000, 3000, 2500, 1200, 2000], contact=[1.0, 1.0, 0.9, 0.2, 0.0])
    tissue_of = np.array([0, 1, 1, 1, 2])
    means = np.array([0.0, 20.0, 30.0, 40.0, 60.0])
    look = default_look(classes, tissue_of, means, "mr", noise_sd=1.0)
    assert look.visible == [False, False, False, True, True]


@pytest.mark.parametrize("kind", ["ct", "mr"])
def test_a_dense_class_is_drawn_from_ivory_up_on_ct(kind):
    # Soft tissue (classes 1-2), a low dense class (3, bone's partial volume) and the bone's peak (4), a tail: on CT
    # the ramp alone puts class 3 at mid-ramp, below ivory; as a dense class it starts at ivory, the peak at white.
    classes = make_classes([10_000, 2000, 2000, 100, 100])
    means = np.array([0.0, 10.0, 12.0, 20.0, 40.0])
    tissue_of = np.array([0, 1, 1, 2, 2])
    plain = default_look(classes, tissue_of, means, kind, noise_sd=1.0)
    dense = default_look(classes, tissue_of, means, kind, noise_sd=1.0, dense_classes=[False] * 3 + [True] * 2)
    ivory = ramp_colors(np.array([IVORY_PLACE]))[0]
    if kind == "ct":
        assert sum(plain.colors[3]) < ivory.sum() - 1e-6  # the ramp alone: darker than ivory
        assert np.allclose(dense.colors[3], ivory) and np.allclose(dense.colors[4], 1.0)
        assert dense.colors[:3] == plain.colors[:3]  # the other classes keep the ramp's colour
    else:
        assert dense.colors == plain.colors  # one colour per tissue elsewhere


# A fog tissue's other classes -----------------------------------------------------------------------------------------


def test_fog_apart_splits_each_run_of_fog_and_keeps_intensity_order():
    tissue_of = np.array([0, 1, 1, 1, 2, 2])
    fog = np.array([False, True, True, False, False, False])
    assert fog_apart(tissue_of, fog).tolist() == [0, 1, 1, 2, 3, 3]
    assert fog_apart(tissue_of, np.zeros(6, dtype=bool)).tolist() == tissue_of.tolist()


@pytest.mark.parametrize(
    "kind, fog_of_class_2, shown", [("mr", False, True), ("mr", True, False), ("ct", False, False)]
)
def test_a_surface_shows_the_classes_above_the_fog_of_their_tissue(kind, fog_of_class_2, shown):
    # Tissue 1: noise 1 width above the background (class 1, fog) and the dark outer cortex 6 widths above it
    # (class 2, not fog: it does not touch the background), grouped by the model; its largest class is the fog, so
    # as a whole it is fog. As its own tissue (not fog), class 2 is shown on a surface look, not on a CT's, which
    # clears the soft tissue whole; as fog it stays hidden.
    classes = make_classes([10_000, 3000, 1000, 5000])
    means = np.array([0.0, 1.0, 6.0, 20.0])
    tissue_of = np.array([0, 1, 1, 2])
    fog = [False, True, fog_of_class_2, False]
    look = default_look(classes, tissue_of, means, kind, class_bins=means, noise_sd=1.0, fog_classes=fog)
    assert look.visible == [False, False, shown, True]
    assert not default_look(classes, tissue_of, means, kind, class_bins=means, noise_sd=1.0).visible[2]
