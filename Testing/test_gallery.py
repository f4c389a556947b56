"""The class roles, the gallery of looks and its oracle (check_look)."""

import dataclasses

import numpy as np
import pytest
from test_look import make_classes

from IsoSimilarityTFLib import design_transfer_function, quantize
from IsoSimilarityTFLib.classes import mark_face_neighbours, voxel_noise_sd
from IsoSimilarityTFLib.design import TransferFunctionDesign
from IsoSimilarityTFLib.gallery import (
    LOOK_NAMES,
    GalleryLook,
    LookContext,
    _bracketed_search,
    _default,
    _dense_ramp,
    broken_shares,
    check_look,
    class_shares,
    first_look_name,
    gallery,
    is_thin,
    make_look,
)
from IsoSimilarityTFLib.look import SHOWN_PLACE, bin_opacity_of, ramp_colors
from IsoSimilarityTFLib.roles import RULES, class_roles, dense_classes, fog_width, is_constant_background, noise_width
from IsoSimilarityTFLib.visibility import SURROUNDINGS, Preview, box_sums, surroundings_fill, visibility_histogram
from isosimtf.phantom import head_phantom

# Roles: each threshold on both sides of its boundary -----------------------------------------------------------------


def roles_of(means, voxels, contact=None, noise_sd=1.0, tissue_of=None):
    classes = make_classes(voxels, contact)
    tissue_of = np.arange(len(voxels)) if tissue_of is None else np.asarray(tissue_of)
    return class_roles(classes, tissue_of, np.asarray(means, dtype=float), noise_sd)


@pytest.mark.parametrize("gap, role", [(RULES.fog_separation - 0.01, "fog"), (RULES.fog_separation + 0.01, "bulk")])
def test_a_class_within_the_fog_separation_of_the_background_is_fog(gap, role):
    # background at 0, a class `gap` noise widths above it, the main tissue far above
    assert roles_of([0.0, gap, 40.0], [5000, 100, 3000])[1] == role
    # and below it: a cropped CT whose largest class (the background) is soft tissue, with lungs far below
    assert roles_of([20.0, 20.0 - gap, 60.0], [5000, 100, 3000])[1] == role


@pytest.mark.parametrize("gap, role", [(RULES.fog_separation - 0.01, "fog"), (RULES.fog_separation + 0.01, "bulk")])
def test_a_low_class_is_fog_only_when_its_tissue_lies_at_the_background_too(gap, role):
    # A skull-stripped brain (the background all zeros): the outer cortex's class, 2 noise widths above the
    # background and not touching it, belongs to the brain's tissue, whose largest class lies `gap` noise widths up.
    classes = make_classes([50_000, 300, 3000], contact=[1.0, 0.1, 0.0])
    assert class_roles(classes, np.array([0, 1, 1]), np.array([0.0, 2.0, gap]), 1.0)[1] == role


@pytest.mark.parametrize("share, role", [(RULES.located_share - 0.01, "bulk"), (RULES.located_share + 0.01, "fog")])
def test_a_low_class_is_fog_where_most_of_its_tissues_voxels_lie_at_the_background(share, role):
    # A skull-stripped brain in a storage where the cortex's edge (bin 10, apart from the background) is its
    # tissue's largest class by a few voxels: the CSF's two classes (bins 1 and 2, not touching the background) hold
    # `share` of the tissue's voxels, each fewer than the edge.
    csf = 10_000
    edge = round(2 * csf * (1 - share) / share)
    assert edge > csf
    classes = make_classes([500_000, csf, csf, edge], contact=[1.0, 0.1, 0.1, 0.0])
    roles = class_roles(classes, np.array([0, 1, 1, 1]), np.array([0.0, 1.0, 2.0, 10.0]), 1.0)
    assert roles == ["background", role, role, "bulk"]


def test_a_tissue_mostly_at_the_background_keeps_its_far_peak():
    # A CT cropped to the body: soft tissue is the background (bin 50), the lungs the one structure below it; the
    # bone's tissue is mostly its partial volume with the soft tissue (bins 51 and 52), its peak far above (bin 100).
    # The partial volume is at the background's intensity; the bone is a structure, not noise beyond the background.
    classes = make_classes([500_000, 50_000, 10_000, 10_000, 15_000], contact=[1.0, 0.0, 0.0, 0.0, 0.0])
    roles = class_roles(classes, np.array([0, 1, 2, 2, 2]), np.array([50.0, 10.0, 51.0, 52.0, 100.0]), 1.0)
    assert roles == ["background", "bulk", "fog", "fog", "dense"]


def air_around_a_tube(below=0):
    """Roles of: ethanol, the background (bin 40); the air's noise tissue below it (its largest class 3 noise widths
    down, its tail 6); the specimen above (bin 100); and ``below`` voxels of a tissue of their own far below (bin 0)."""
    classes = make_classes([50_000, 20_000, 8_000, 5_000, below])
    return class_roles(classes, np.array([0, 1, 1, 2, 3]), np.array([40.0, 37.0, 34.0, 100.0, 0.0]), 1.0)


def test_the_tail_of_noise_on_the_side_of_no_structure_is_fog_however_far_out():
    # A micro-CT's tube of ethanol in air: the air lies 3 noise widths below the ethanol, its lower half 6.
    assert air_around_a_tube()[:4] == ["background", "fog", "fog", "dense"]


@pytest.mark.parametrize("factor, role", [(0.95, "fog"), (1.05, "bulk")])
def test_a_real_structure_beyond_the_noise_keeps_its_tail_apart(factor, role):
    # A tissue below the air holding a real share of the voxels is a structure there: the air's tail stays shown
    # (a stray few voxels are not).
    share = factor * RULES.real_share
    below = round(share * 33_000 / (1.0 - share))
    assert air_around_a_tube(below)[2] == role


@pytest.mark.parametrize("contact, role", [(RULES.rim_contact - 0.01, "bulk"), (RULES.rim_contact + 0.01, "fog")])
def test_a_low_class_mostly_touching_the_background_is_fog_in_any_tissue(contact, role):
    # Noise scattered in the air touches it: fog, even when the intensity model put it in a tissue apart.
    classes = make_classes([50_000, 300, 3000], contact=[1.0, contact, 0.0])
    assert class_roles(classes, np.array([0, 1, 1]), np.array([0.0, 2.0, 20.0]), 1.0)[1] == role


@pytest.mark.parametrize("contact, role", [(RULES.rim_contact - 0.01, "bulk"), (RULES.rim_contact + 0.01, "rim")])
def test_a_class_mostly_touching_the_background_is_rim(contact, role):
    assert roles_of([0.0, 20.0, 40.0], [5000, 100, 3000], contact=[1.0, contact, 0.0])[1] == role


@pytest.mark.parametrize("gap, dense", [(RULES.dense_separation - 0.01, False), (RULES.dense_separation + 0.01, True)])
def test_a_real_tissue_above_the_largest_by_the_dense_separation_is_dense(gap, dense):
    roles = roles_of([0.0, 20.0, 20.0 + gap], [5000, 3000, 300])
    assert (roles[2] == "dense") is dense


@pytest.mark.parametrize("share, dense", [(0.0099, False), (0.0101, True)])
def test_a_dense_class_must_be_of_a_real_tissue(share, dense):
    # non-background voxels: 10_000 in all; the top tissue holds `share` of them
    top = int(round(share * 10_000))
    classes = make_classes([50_000, 10_000 - top, top])
    assert (2 in dense_classes(classes, np.arange(3), np.array([0.0, 20.0, 60.0]), 1.0)) is dense


@pytest.mark.parametrize("offset, dense", [(-0.01, False), (0.01, True)])
def test_a_dense_class_lies_above_a_background_that_is_not_the_lowest(offset, dense):
    # A CT cropped to the body: soft tissue (bin 40) is the largest class, the background; the lungs (bin 10) are the
    # main material. A class between them is their blend; above the soft tissue it is contrast or bone.
    classes = make_classes([50_000, 20_000, 3000, 3000])
    bins = np.array([40.0, 10.0, 40.0 + offset, 60.0])
    assert dense_classes(classes, np.arange(4), bins, 1.0) == ([2, 3] if dense else [3])


def test_dense_is_decided_per_class_inside_a_tissue():
    # Soft tissue and trabecular bone in one tissue (no valley between them in the histogram): the bone's class is
    # dense, the soft tissue's next to it is not.
    classes = make_classes([50_000, 8_000, 1_000, 600])
    roles = class_roles(classes, np.array([0, 1, 1, 2]), np.array([0.0, 20.0, 20.0 + 5.0, 40.0]), 1.0)
    assert roles == ["background", "bulk", "dense", "dense"]


@pytest.mark.parametrize("gap, dense", [(RULES.dense_separation - 0.01, False), (RULES.dense_separation + 0.01, True)])
def test_dense_is_measured_from_the_largest_class_above_the_largest_tissues_mean(gap, dense):
    # An export whose air was set to 0: the lowest tissue is mostly the blur of the skull (three classes spread low,
    # the most voxels, mean bin 10), the brain is the largest class (bin 30): the skull is dense only `gap` noise
    # widths above the brain, and the brain itself is not dense (20 noise widths above the lowest tissue's mean).
    classes = make_classes([50_000, 2000, 2000, 2000, 3000, 500])
    means = np.array([0.0, 5.0, 10.0, 15.0, 30.0, 30.0 + gap])
    roles = class_roles(classes, np.array([0, 1, 1, 1, 2, 2]), means, 1.0)
    assert roles[4] == "bulk"
    assert (roles[5] == "dense") is dense


@pytest.mark.parametrize("gap, dense", [(RULES.dense_separation - 0.01, False), (RULES.dense_separation + 0.01, True)])
def test_dense_is_measured_from_the_largest_tissues_mean_above_the_largest_class(gap, dense):
    # The largest tissue's mean (two classes, 20.0) lies above its largest class (bin 18): measured from the mean.
    classes = make_classes([50_000, 3000, 3000, 300])
    means = np.array([0.0, 18.0, 22.0, 20.0 + gap])
    assert (class_roles(classes, np.array([0, 1, 1, 2]), means, 1.0)[3] == "dense") is dense


@pytest.mark.parametrize("gap, role", [(RULES.fog_separation - 0.01, "fog"), (RULES.fog_separation + 0.01, "bulk")])
@pytest.mark.parametrize("kind", ["mr", "ct"])
def test_the_roles_count_in_the_voxels_noise_on_data_that_are_not_ct_like(gap, role, kind):
    # The model's width is 5 bins, the voxels' noise 2: a low tissue `gap` voxel-noise widths above the background.
    # On MRI it is fog only within 4 of those; on CT, within 4 of the model's (so fog on both sides here).
    classes = make_classes([50_000, 3000, 6000])
    context = LookContext.build(
        classes=classes, tissue_of_class=np.arange(3), class_values=np.array([0.0, 2.0 * gap, 60.0]),
        class_bins=np.array([0.0, 2.0 * gap, 60.0]), labels=np.repeat(np.arange(3), [10, 30, 40]), noise_sd=5.0,
        voxel_noise_sd=2.0, preview=None, kind=kind,
    )  # fmt: skip
    assert context.roles[1] == (role if kind == "mr" else "fog")
    # The first click decides fog in the same width, and so does the CT's outer surface (a look of another kind).
    bins = np.full((8, 8, 8), 5, dtype=np.uint16)  # the air (class 0), the low tissue (1) around a core (2)
    bins[1:7, 1:7, 1:7] = 25
    bins[3:5, 3:5, 3:5] = 60
    preview = Preview(bins, (1.0, 1.0, 1.0), 80)
    context = dataclasses.replace(context, preview=preview)
    outer = make_look("outer-surface", context)
    assert outer is not None and outer.visible[1] == (role == "bulk" and kind == "mr")


def test_the_noise_width_is_the_models_on_ct_and_the_smaller_voxel_noise_on_other_data():
    assert noise_width("ct", 20.0, 8.0) == 20.0  # bone is another material: the soft tissues' contrasts are not
    assert noise_width("mr", 20.0, 8.0) == 8.0
    assert noise_width("mr", 20.0, 30.0) == 20.0  # never wider than the model's
    assert noise_width("mr", 20.0, 0.0) == 0.5  # data stored in coarse steps: a histogram resolves no less
    assert noise_width("mr", 20.0, None) == 20.0  # a design saved before the voxels' noise was measured


def test_on_ct_a_tissue_is_at_the_background_in_the_voxels_noise_where_that_is_one_value_or_wider():
    assert fog_width("ct", 20.0, 8.0, constant_background=False) == 20.0  # noisy air: the wider of the two
    assert fog_width("ct", 3.5, 10.8, constant_background=False) == 10.8  # the model fits the air's tails narrower
    assert fog_width("ct", 20.0, None, constant_background=False) == 20.0
    assert fog_width("ct", 20.0, 8.0, constant_background=True) == 8.0  # one stored value: no noise of its own
    assert fog_width("mr", 20.0, 8.0, constant_background=False) == 8.0
    assert fog_width("ct", 20.0, None, constant_background=True) == 20.0  # a design saved before it was measured


@pytest.mark.parametrize("gap, role", [(RULES.fog_separation - 0.01, "fog"), (RULES.fog_separation + 0.01, "bulk")])
def test_a_tissue_at_the_background_is_fog_within_the_fog_width(gap, role):
    # The model's width is 4 bins, the fog width 1: a class `gap` bins up, the largest of its tissue, not touching
    # the background, is fog within 4 fog widths, whatever the model's width says.
    classes = make_classes([50_000, 3000, 3000], contact=[1.0, 0.0, 0.0])
    roles = class_roles(classes, np.array([0, 1, 2]), np.array([0.0, gap, 100.0]), 4.0, fog_sd=1.0)
    assert roles[1] == role


@pytest.mark.parametrize(
    "gap, role", [(RULES.fog_separation * 4.0 - 0.01, "fog"), (RULES.fog_separation * 4.0 + 0.01, "rim")]
)
def test_noise_scattered_in_the_background_is_fog_within_the_noise_width(gap, role):
    # A zeroed MRI's leftover noise touches the zeros: fog within 4 of the data's widths (4 bins), not the fog width.
    classes = make_classes([50_000, 3000, 3000], contact=[1.0, 0.9, 0.0])
    roles = class_roles(classes, np.array([0, 1, 2]), np.array([0.0, gap, 100.0]), 4.0, fog_sd=1.0)
    assert roles[1] == role


def test_a_constant_backgrounds_threshold_is_what_noise_of_half_a_bin_puts_beside_its_fullest_bin():
    # Gaussian noise of 0.5 bin: the bin beside the fullest holds P(0.5 < x < 1.5) / P(|x| < 0.5) of it
    rng = np.random.default_rng(0)
    counts = np.bincount(np.rint(np.abs(rng.normal(0.0, 0.5, 4_000_000))).astype(int))
    assert counts[1] / 2 / counts[0] == pytest.approx(RULES.constant_neighbour_share, rel=0.01)


@pytest.mark.parametrize("margin, constant", [(-0.001, True), (0.001, False)])
def test_a_background_is_one_value_when_the_bins_beside_it_hold_less_than_half_a_bins_noise_puts_there(
    margin, constant
):
    beside = round((RULES.constant_neighbour_share + margin) * 100_000)
    counts = np.zeros(64, dtype=np.int64)
    counts[10], counts[40:50] = 100_000, 500
    for side in (9, 11):
        near = counts.copy()
        near[side] = beside
        assert is_constant_background(near, np.arange(8, 13)) is constant
    # data stored in steps of 3 bins: the stored values beside it are compared, not the empty bins between
    lattice = np.zeros(64, dtype=np.int64)
    lattice[10], lattice[13], lattice[40:64:3] = 100_000, beside, 500
    assert is_constant_background(lattice, np.arange(8, 13)) is constant
    # air at the bottom of the range: one side only
    bottom = np.zeros(64, dtype=np.int64)
    bottom[0], bottom[1], bottom[40:50] = 100_000, beside, 500
    assert is_constant_background(bottom, np.arange(0, 3)) is constant


def test_the_objects_own_values_beyond_the_datas_step_are_not_the_backgrounds_noise():
    # A masked volume: zeros, then the object's values from bin 40 up, nothing between.
    counts = np.zeros(64, dtype=np.int64)
    counts[0], counts[40:64] = 100_000, 30_000
    assert is_constant_background(counts, np.arange(0, 5))


def test_no_background_or_an_empty_one_is_not_a_constant_background():
    counts = np.zeros(64, dtype=np.int64)
    counts[40:50] = 500
    assert not is_constant_background(counts, np.arange(0, 0))  # the option background=none: no class
    assert not is_constant_background(counts, np.arange(0, 5))  # a background class holding no voxels
    design = design_transfer_function(_flame(noisy_air=False), 1.0, modality="ct", background="none")
    assert design.background_class is None and not design.constant_background


def _flame(noisy_air: bool) -> np.ndarray:
    """A smooth field fading from 255 in its core into empty space (values under 8 set to 0, as a simulation's
    cut-off), declared CT; with ``noisy_air`` the empty space holds noise around 6 instead."""
    k, j, i = np.indices((48, 64, 64))
    values = 255.0 * np.exp(-2.5 * (((k - 24) / 14.0) ** 2 + ((j - 32) / 20.0) ** 2 + ((i - 32) / 20.0) ** 2))
    values[values < 8] = 0.0
    if noisy_air:
        air = values == 0
        values[air] = np.random.default_rng(0).normal(6.0, 2.0, int(air.sum()))
    return np.clip(np.rint(values), 0, 255).astype(np.uint8)


def test_the_faint_edge_of_a_field_in_empty_space_is_not_fog_and_noisy_air_still_is():
    faint = {}
    for noisy_air in (False, True):
        design = design_transfer_function(_flame(noisy_air), 1.0, modality="ct")
        context = design.look_context()
        assert design.kind == "ct" and design.constant_background is not noisy_air
        # classes up to 40 values up: beyond 4 fog widths of the background (voxels' noise on the constant one),
        # within 4 of the model's
        fog_reach = RULES.fog_separation * fog_width("mr", context.noise_sd, context.voxel_noise_sd, False)
        band = [c.id for c in design.classes if fog_reach < context.class_bins[c.id] < 40]
        assert band and max(context.class_bins[band]) < RULES.fog_separation * context.noise_sd
        faint[noisy_air] = [context.roles[c] for c in band]
    assert "fog" not in faint[False]
    assert "fog" in faint[True]


def _noisy_planes(sd, shape=(8, 256, 256), seed=0):
    """Bins of two tissues (100 and 160) side by side with Gaussian noise of ``sd`` bins, in a background of 0."""
    rng = np.random.default_rng(seed)
    values = np.where(np.arange(shape[2]) < shape[2] // 2, 100.0, 160.0) + rng.normal(0.0, sd, shape)
    values[:, :16] = 0.0  # the background: no noise in it
    return np.clip(np.rint(values), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("sd", [2.0, 5.0, 9.0])
def test_the_voxels_noise_is_the_noise_not_the_spread_between_tissues(sd):
    # Two tissues 60 bins apart side by side: their edge's pairs do not move the median. Differences of whole bins
    # read between bins (the grouped median): within 3 % (the rounding to bins adds 1/12 bin^2 of variance).
    foreground = np.arange(256) > 0
    assert voxel_noise_sd(_noisy_planes(sd), foreground) == pytest.approx(sd, rel=0.03)


def test_the_voxels_noise_is_measured_inside_the_volume_not_on_its_edge_planes():
    # Planes of 512 x 512 (one is the whole sample): the first plane is padding, with a few stray voxels.
    bins = _noisy_planes(5.0, shape=(64, 512, 512))
    bins[0] = 0
    bins[0, :10, :10] = np.random.default_rng(2).integers(1, 255, (10, 10))
    assert voxel_noise_sd(bins, np.arange(256) > 0) == pytest.approx(5.0, rel=0.03)


def test_the_voxels_noise_leaves_the_background_out():
    bins = _noisy_planes(5.0)
    bins[:, :, :128] = np.random.default_rng(1).integers(1, 41, (8, 256, 128))  # a wildly noisy background, 1..40
    everything = np.ones(256, dtype=bool)
    outside_background = np.arange(256) > 40
    assert voxel_noise_sd(bins, everything) > 7.0  # the background's pairs (|a - b| of 1..40 at random) counted
    assert voxel_noise_sd(bins, outside_background) == pytest.approx(5.0, rel=0.03)
    assert voxel_noise_sd(bins, np.zeros(256, dtype=bool)) is None


def test_a_bright_lesion_in_a_textured_tissue_is_dense_on_mri_not_on_ct():
    # Grey and white matter (100 and 125) with a slow texture of +-25 (the intensity model's width grows with it to 26
    # bins, the neighbours' differences barely do: 5), noise 3, in an MRI's noisy air, and bright lesions at 165:
    # within 4 model widths of the main material, far beyond 4 of the voxels' noise. Dense where the data are not
    # CT-like; not when the same data are declared CT.
    rng = np.random.default_rng(3)
    shape = (48, 64, 64)
    k, j, i = np.indices(shape)
    inside = (abs(k - 24) < 20) & (abs(j - 32) < 28) & (abs(i - 32) < 28)
    texture = 25.0 * np.sin(2 * np.pi * i / 37.0) * np.sin(2 * np.pi * j / 43.0)
    values = np.where(inside, np.where(k < 24, 100.0, 125.0) + texture, 10.0)
    lesion = ((k - 30) ** 2 + (j - 32) ** 2 + (i - 40) ** 2 < 25) | ((k - 14) ** 2 + (j - 20) ** 2 + (i - 24) ** 2 < 16)
    values[lesion] = 165.0
    values = np.clip(values + rng.normal(0.0, 3.0, shape), 0, 255).astype(np.uint8)
    roles = {}
    for modality in ("mr", "ct"):
        design = design_transfer_function(values, 1.0, modality=modality)
        context = design.look_context()
        lesion_bins = quantize(values, design.n_bins, design.value_range).bins[lesion]
        lesion_classes = {int(design.labels[b]) for b in np.unique(lesion_bins)}
        roles[modality] = [context.roles[c] for c in lesion_classes]
        assert design.voxel_noise_sd < design.hierarchy.noise_sd / 2
    assert roles["mr"].count("dense") > len(roles["mr"]) / 2
    assert "dense" not in roles["ct"]


def test_a_dense_class_stays_dense_when_it_touches_the_background():
    # Bone exposed to the air is still bone: the dense decision comes before the rim's.
    assert roles_of([0.0, 20.0, 60.0], [5000, 3000, 300], contact=[1.0, 0.0, 0.9])[2] == "dense"


# The gallery on whole designs ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def phantom_design():
    phantom = head_phantom(64, seed=2)
    return design_transfer_function(phantom.values, phantom.spacing)


def test_the_first_look_is_the_first_click_and_names_are_unique(phantom_design):
    looks = phantom_design.looks
    assert 3 <= len(looks) <= len(LOOK_NAMES)
    assert looks[0].name == ("dense-parts" if phantom_design.kind == "ct" else "outer-surface")
    assert len({look.name for look in looks}) == len(looks)
    assert all(name.replace("-", "").isalnum() and name == name.lower() for name in (look.name for look in looks))
    # The design as made shows its first look, class by class.
    first = looks[0]
    assert [c.visible for c in phantom_design.classes] == first.visible
    assert [c.opacity for c in phantom_design.classes] == pytest.approx(first.opacities)


def test_no_two_looks_give_the_same_transfer_function(phantom_design):
    looks = phantom_design.looks
    for i, a in enumerate(looks):
        for b in looks[i + 1 :]:
            assert not a.same_picture(b)


def test_using_a_look_switches_the_transfer_function_and_a_regrouping_keeps_it(phantom_design):
    design = TransferFunctionDesign.from_json(phantom_design.to_json())
    names = [look.name for look in design.looks]
    first_tf = design.transfer_function()
    other = names[-1]
    design.use_look(other)
    assert design.look_name == other
    assert not np.array_equal(design.transfer_function().opacity, first_tf.opacity)
    look = {look.name: look for look in design.looks}[other]
    assert np.array_equal(design.transfer_function().opacity, design.transfer_function(look).opacity)
    # Saved and restored: the chosen look comes back, and a regrouping remakes that look.
    restored = TransferFunctionDesign.from_json(design.to_json())
    assert restored.look_name == other
    restored.regroup(restored.hierarchy.auto)
    assert restored.look_name == other
    assert np.array_equal(restored.transfer_function().opacity, design.transfer_function().opacity)
    with pytest.raises(ValueError, match="no look 'nothing'"):
        design.use_look("nothing")


def test_a_saved_design_naming_an_unknown_look_is_refused(phantom_design):
    document = phantom_design.to_dict()
    document["look"] = "rainbow"
    with pytest.raises(ValueError, match="no look 'rainbow'"):
        TransferFunctionDesign.from_dict(document)


def test_every_look_of_the_phantom_keeps_fog_and_background_clear(phantom_design):
    roles = phantom_design.look_context().roles
    for look in phantom_design.looks:
        assert not any(v and r in ("background", "fog") for v, r in zip(look.visible, roles))
        shares = look.role_shares(roles)
        assert shares["fog"] == 0.0 and shares["background"] == 0.0
        assert sum(shares.values()) == pytest.approx(1.0)


def test_the_see_through_look_keeps_the_bulk_at_its_share(phantom_design):
    look = make_look("see-through", phantom_design.look_context())
    assert look is not None
    share = look.role_shares(phantom_design.look_context().roles)["bulk"]
    low, high = RULES.see_through
    assert low <= share <= high
    assert share == pytest.approx((low + high) / 2, abs=0.01)  # its search aims at the middle, and stops within 0.01
    assert phantom_design.check_look("see-through") == []


def test_the_thumbnail_shows_the_look(phantom_design):
    looks = phantom_design.looks
    pictures = [phantom_design.thumbnail(look, size=48) for look in looks]
    assert all(p.shape == (48, 48, 3) and p.dtype == np.uint8 for p in pictures)
    assert all(p.max() > 0 for p in pictures)  # something is drawn
    assert any(not np.array_equal(pictures[0], p) for p in pictures[1:])


# The oracle on both sides of each promise ----------------------------------------------------------------------------


def balls_context(shells, edges, class_bins, kind, tissue_of_class=None, rules=RULES):
    """A 40^3 preview (5-unit voxels) of concentric balls in air (bin 0): ``shells``, ``(radius, bin)`` from the
    innermost. Bins below ``edges[0]`` are class 0, from ``edges[k - 1]`` on class ``k`` (no partial volume between
    them); one tissue per class unless ``tissue_of_class`` says otherwise."""
    n = 40
    z, y, x = np.indices((n, n, n)) - (n - 1) / 2
    r = np.sqrt(x**2 + y**2 + z**2)
    bins = np.select([r < radius for radius, _ in shells], [value for _, value in shells], 0).astype(np.intp)
    labels = np.searchsorted(edges, np.arange(n), side="right")
    class_bins = np.asarray(class_bins, dtype=float)
    voxels = np.bincount(labels[bins.ravel()], minlength=class_bins.size)
    tissue_of_class = np.arange(class_bins.size) if tissue_of_class is None else np.asarray(tissue_of_class)
    return LookContext.build(
        classes=make_classes(voxels.tolist()), tissue_of_class=tissue_of_class, class_values=class_bins,
        class_bins=class_bins, labels=labels, noise_sd=1.0, preview=Preview(bins, (5.0, 5.0, 5.0), n), kind=kind,
        rules=rules,
    )  # fmt: skip


def shell_context(rules=RULES, kind="ct"):
    """Air (bin 0), a soft shell (bins 10-19, bulk) around a dense core (bins 30-39)."""
    return balls_context([(6, 35), (17, 15)], [5, 19], [0.0, 15.0, 35.0], kind, rules=rules)


def lesion_context(kind, rules=RULES, tissue_of_class=(0, 1, 2, 3)):
    """Air (bin 0), a brain (bin 15, bulk) around a bright lesion (bin 30) with a brighter centre (bin 37): both
    dense, three tissues on the ramp, so the lesion starts below its top (or, grouped with the brain by
    ``tissue_of_class``, drawn faint with it)."""
    return balls_context(
        [(4, 37), (6, 30), (17, 15)], [5, 22, 34], [0.0, 15.0, 30.0, 37.0], kind, tissue_of_class, rules
    )


@pytest.mark.parametrize("opacity_high", [0.4, RULES.opacity_high])
def test_the_dense_parts_of_other_data_are_raised_to_the_ramps_top(opacity_high):
    """A FLAIR's lesion: the outer surface (the brain) leaves it in the ramp's middle; the dense-parts look shows it,
    and its brighter centre, as surfaces at the ramp's top."""
    context = lesion_context("mr", dataclasses.replace(RULES, opacity_high=opacity_high))
    assert context.roles == ["background", "bulk", "dense", "dense"]
    assert make_look("outer-surface", context).opacities[2] < 0.9 * opacity_high
    look = make_look("dense-parts", context)
    assert look.opacities[2] == pytest.approx(opacity_high) and look.opacities[3] == pytest.approx(opacity_high)


@pytest.mark.parametrize("opacity_high", [0.4, RULES.opacity_high])
def test_the_see_through_look_shows_every_dense_part_as_a_surface(opacity_high):
    """On CT-like data the dense-parts look clears the lesion in front of its brighter centre (a tissue 4 noise
    widths below a feature); seen through the bulk, both are surfaces at the ramp's top."""
    context = lesion_context("ct", dataclasses.replace(RULES, opacity_high=opacity_high))
    assert make_look("dense-parts", context).opacities[2] < 0.1 * opacity_high
    look = make_look("see-through", context)
    assert look.opacities[2] == pytest.approx(opacity_high) and look.opacities[3] == pytest.approx(opacity_high)


def organs_context(kind, gap, core=None):
    """An abdominal CT read as an MRI: air (bin 0), fat (bin 15, the largest tissue) around organs (bin 25, dense:
    10 noise widths above the fat) around bone (``gap`` bins above the organs), with a denser core (bin ``core``)
    when given, each a tissue of its own."""
    shells = [(4 if core else 0, 39), (6, 38), (10, 25), (17, 15)]
    means = [0.0, 15.0, 25.0, 25.0 + gap] + ([] if core is None else [core])
    return balls_context(shells, [5, 20, 38] + ([] if core is None else [39]), means, kind)


@pytest.mark.parametrize(
    "gap, offered", [(RULES.dense_separation - 0.01, False), (RULES.dense_separation + 0.01, True)]
)
def test_the_densest_parts_are_the_dense_rule_among_the_dense_classes(gap, offered):
    """The organs are dense against the fat, the bone against the organs: the densest-parts look shows the bone
    alone, at the ramp's top, where it lies the dense separation above the organs; closer, the dense classes are one
    material, and the dense-parts look already shows them."""
    context = organs_context("mr", gap)
    assert context.roles == ["background", "bulk", "dense", "dense"]
    assert context.densest.tolist() == [False, False, False, offered]
    look = make_look("densest-parts", context)
    assert (look is not None) is offered
    if offered:
        assert look.visible == [False, False, False, True]
        assert look.opacities[3] >= RULES.opacity_high
        assert "densest-parts" in [other.name for other in gallery(context)]


def test_every_densest_class_is_raised_to_the_ramps_top():
    # Bone and its denser core: the outer surface leaves the bone below the core on the ramp.
    context = organs_context("mr", 2 * RULES.dense_separation, core=38.0)
    assert context.densest.tolist() == [False, False, False, True, True]
    assert make_look("outer-surface", context).opacities[3] < 0.9 * RULES.opacity_high
    look = make_look("densest-parts", context)
    assert look.opacities[3:] == pytest.approx([RULES.opacity_high] * 2)


def bright_organs_context(voxels, tissue_of_class, class_bins):
    classes = make_classes(voxels)
    class_bins = np.asarray(class_bins, dtype=float)
    return LookContext.build(
        classes=classes, tissue_of_class=np.asarray(tissue_of_class), class_values=class_bins, class_bins=class_bins,
        labels=np.arange(len(voxels)), noise_sd=1.0, preview=None, kind="mr",
    )  # fmt: skip


@pytest.mark.parametrize("share, densest", [(0.0099, False), (0.0101, True)])
def test_the_densest_material_holds_a_real_share_of_the_voxels(share, densest):
    # Organs (bin 25, dense against the fat) below a tissue of a barely denser class (27) and a bright one (32)
    # holding `share` of the 10_000 non-background voxels: a material from a real share on, else stray voxels.
    top = int(round(share * 10_000))
    context = bright_organs_context([50_000, 6000, 3000 - top, 1000, top], [0, 1, 2, 3, 3], [0, 15, 25, 27, 32])
    assert context.roles == ["background", "bulk", "dense", "dense", "dense"]
    assert context.densest.tolist() == [False, False, False, False, densest]


@pytest.mark.parametrize("tissue_of_class, densest", [([0, 1, 2, 2], False), ([0, 1, 2, 3], True)])
def test_the_densest_material_is_a_tissue_apart_from_the_dense_parts_main_class(tissue_of_class, densest):
    # The brightest classes of the organs' own tissue are the top of its spread (a brain's brightest white matter
    # drawn as speckle), not a denser material; a tissue of their own is.
    context = bright_organs_context([50_000, 6000, 3000, 1000], tissue_of_class, [0, 15, 25, 32])
    assert context.densest.tolist() == [False, False, False, densest]


def test_the_densest_parts_look_is_not_offered_on_ct_like_data():
    # On CT the dense-parts look draws the denser material brighter, on the ramp by value.
    context = organs_context("ct", 2 * RULES.dense_separation)
    assert context.densest[3] and make_look("densest-parts", context) is None


def light_of(context, opacities, visible):
    """``(n_classes,)`` light each class sends to the eye over the preview's six views."""
    bin_opacity = bin_opacity_of(np.where(visible, opacities, 0.0), context.labels, context.noise_sd)
    light = visibility_histogram(context.preview, bin_opacity)
    return np.bincount(context.labels, weights=light, minlength=len(context.classes))


@pytest.mark.parametrize(
    "kind, dense_share, seen, kept_binds",
    [("ct", 0.3, 0.8, False), ("ct", 0.9, 0.8, False), ("ct", 0.5, 0.95, True)],
)
def test_the_dense_parts_look_clears_the_bulk_only_as_far_as_its_aims(kind, dense_share, seen, kept_binds):
    """On CT-like data the bulk is made clearer until the dense parts give ``dense_share`` of the picture and keep
    ``seen`` of their light, and no further: whichever aim binds lands within a few hundredths above it."""
    context = shell_context(dataclasses.replace(RULES, dense_share=dense_share, seen=seen), kind)
    look = make_look("dense-parts", context)
    dense = context.of_role("dense")
    opacities, visible = np.asarray(look.opacities), np.asarray(look.visible)
    share = float(look.class_shares[dense].sum())
    kept = light_of(context, opacities, visible)[dense].sum() / light_of(context, opacities, dense)[dense].sum()
    assert share >= dense_share and kept >= seen
    if kept_binds:
        assert kept <= seen + 0.02
    else:
        assert share <= dense_share + 0.05


@pytest.mark.parametrize("seen", [0.9, 0.95])
def test_on_ct_the_clearing_keeps_the_light_of_dense_classes_the_default_look_leaves_faint(seen):
    """A dense class grouped with the bulk (a plume's fringe, a specimen's tube: the default look draws its tissue
    faint, so its visibility step does not see to its light) is kept at ``seen`` of its light by the clearing of the
    shell in front of it, and no further."""
    rules = dataclasses.replace(RULES, dense_share=0.3, seen=seen)
    context = lesion_context("ct", rules, tissue_of_class=(0, 1, 1, 2))
    assert context.roles == ["background", "bulk", "dense", "dense"]
    look = make_look("dense-parts", context)
    dense, opacities, visible = context.of_role("dense"), np.asarray(look.opacities), np.asarray(look.visible)
    kept = light_of(context, opacities, visible)[dense].sum() / light_of(context, opacities, dense)[dense].sum()
    assert seen <= kept <= seen + 0.02


def fringe_context(rules=RULES):
    """A plume in empty space: a core (bin 37, a tissue of its own) inside fringe layers (bins 30 and 24, dense)
    that the intensity model grouped with the faint haze around them (bin 3, the tissue's largest class: fog), so the
    default look hides them with it."""
    return balls_context(
        [(4, 37), (5, 30), (6, 24), (17, 3)],
        [2, 14, 27, 34],
        [0.0, 3.0, 24.0, 30.0, 37.0],
        "ct",
        [0, 1, 1, 1, 2],
        rules,
    )


@pytest.mark.parametrize("opacity_low", [0.01, RULES.opacity_low])
def test_on_ct_the_dense_classes_the_default_hides_rise_from_the_ramps_start_to_the_tails(opacity_low):
    """A plume's fringe: hidden with the haze by the default look, the dense-parts look draws its dense classes on
    the presets' ramp, from ``opacity_low`` at the lowest up towards the core's opacity by mean bin, a shell that
    thickens the core rather than a faint halo around it."""
    context = fringe_context(dataclasses.replace(RULES, opacity_low=opacity_low))
    assert context.roles == ["background", "fog", "dense", "dense", "dense"]
    _, _, visible = _default(context, "ct")
    assert visible[1:] == [False, False, False, True]
    look = make_look("dense-parts", context)
    assert all(look.visible[2:])
    core = look.opacities[4]
    assert look.opacities[2] == pytest.approx(opacity_low)
    assert look.opacities[3] == pytest.approx(opacity_low + (core - opacity_low) * (30 - 24) / (37 - 24))
    assert opacity_low < look.opacities[3] < core


def test_a_hidden_dense_class_between_shown_ones_takes_their_ramp_and_the_ramp_never_falls():
    context = fringe_context()  # dense classes at bins 24, 30 and 37
    # shown at 24 and 37: the hidden one at 30 lies between them on their ramp
    ramp = _dense_ramp(context, np.array([0.0, 0.02, 0.3, 0.02, 0.5]), np.array([False, False, True, False, True]))
    assert ramp[3] == pytest.approx(0.3 + 0.2 * (30 - 24) / (37 - 24))
    # shown at 30 only: the hidden one above it takes its opacity, the one below ramps up to it
    ramp = _dense_ramp(context, np.array([0.0, 0.02, 0.02, 0.3, 0.02]), np.array([False, False, False, True, False]))
    assert ramp[2] == pytest.approx(RULES.opacity_low) and ramp[4] == pytest.approx(0.3)
    # a tail clearer than the ramp's start: flat at its opacity, not falling towards it
    ramp = _dense_ramp(context, np.array([0.0, 0.02, 0.02, 0.02, 0.01]), np.array([False, False, False, False, True]))
    assert ramp[2:].tolist() == pytest.approx([0.01, 0.01, 0.01])


@pytest.mark.parametrize("kind", ["ct", "mr"])
def test_the_dense_parts_of_other_data_are_shown_alone(kind):
    """The soft shell around the dense core: a faint veil on CT (CT-Bone's soft tissue), hidden on other data (a
    FLAIR's lesion without the brain around it), where it keeps the outer surface's opacity for a user who shows it."""
    context = shell_context(kind=kind)
    look = make_look("dense-parts", context)
    bulk = context.of_role("bulk")
    assert np.asarray(look.visible)[context.of_role("dense")].all()
    assert np.asarray(look.visible)[bulk].all() == (kind == "ct")
    if kind == "ct":
        assert 0 < float(look.class_shares[bulk].sum()) <= 1 - RULES.dense_share + 0.05
    else:
        surface = make_look("outer-surface", context)
        assert np.asarray(look.opacities)[bulk] == pytest.approx(np.asarray(surface.opacities)[bulk])
        assert float(look.class_shares[bulk].sum()) == 0.0 and check_look(context, look) == []


@pytest.mark.parametrize("name", ["all-tissues", "classes"])
@pytest.mark.parametrize("low, high", [(0.05, 0.4), (RULES.opacity_low, RULES.opacity_high)])
def test_every_tissue_and_every_class_run_up_the_ramp_from_its_low_end_to_its_top(name, low, high):
    """Brain, lesion and centre (one class each): the presets' monotone ramp, by rank of intensity."""
    context = lesion_context("mr", dataclasses.replace(RULES, opacity_low=low, opacity_high=high))
    look = make_look(name, context)
    assert look.visible == [False, True, True, True]
    assert look.opacities == pytest.approx([0.0, low, (low + high) / 2, high])


def test_check_look_measures_the_promised_share_on_both_sides():
    context = shell_context()
    look = make_look("see-through", context)
    assert check_look(context, look) == []
    # The same look with an opaque shell: the bulk takes the picture, the promise is broken.
    opaque = dataclasses.replace(look, opacities=[0.0, 1.0, look.opacities[2]])
    assert any("bulk gives" in failure for failure in check_look(context, opaque))


@pytest.mark.parametrize("excess, broken", [(2e-16, False), (1e-6, True)])
def test_a_share_summing_to_one_with_rounding_keeps_a_promise_up_to_one(excess, broken):
    # The dense parts of a housing give all the light; the float sum of their shares may exceed 1 by rounding.
    look = GalleryLook(
        name="dense-parts", title="", objective="", colors=[[1.0, 1.0, 1.0]] * 3, opacities=[0.0, 0.5, 0.5],
        visible=[False, True, True], promise={"dense": (RULES.dense_share, 1.0)}, kept={}, monotone=False,
        class_shares=np.array([0.0, 0.5, 0.5 + excess]),
    )  # fmt: skip
    assert (broken_shares(look, ["background", "dense", "dense"]) == ["dense"]) is broken


def test_check_look_measures_the_light_kept_on_both_sides():
    context = shell_context()
    look = make_look("dense-parts", context)
    assert check_look(context, look) == []
    veiled = dataclasses.replace(look, visible=[False, True, True], opacities=[0.0, 0.3, look.opacities[2]])
    assert any("dense keeps" in failure for failure in check_look(context, veiled))


def _with_share(context, look, target, scaled, share):
    """``look`` with the opacities of the ``scaled`` classes multiplied by the factor that makes the ``target``
    classes give ``share`` of the picture (bisection in log factor on the fast measure)."""
    opacities = np.asarray(look.opacities, dtype=float)

    def target_share(log_factor):
        trial = np.where(scaled, opacities * np.exp(log_factor), opacities).clip(0.0, 1.0)
        return float(class_shares(context, trial, look.visible)[target].sum()), trial

    low, high = -12.0, 12.0  # the target's share falls as the others grow
    for _ in range(60):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if target_share(middle)[0] > share else (low, middle)
    measured, trial = target_share(0.5 * (low + high))
    assert measured == pytest.approx(share, abs=0.005)
    return dataclasses.replace(look, opacities=[float(a) for a in trial])


@pytest.mark.parametrize("margin, kept", [(-0.03, False), (0.03, True)])
def test_the_dense_parts_promise_keeps_the_seen_share_of_the_dense_light(margin, kept):
    """The dense core behind a shell made opaque enough that it keeps ``seen + margin`` of its own light."""
    context = shell_context()
    look = make_look("dense-parts", context)
    dense = context.of_role("dense")
    visible = np.array([False, True, True])
    opacities = np.asarray(look.opacities, dtype=float)

    def kept_with(shell):
        trial = np.where(context.of_role("bulk"), shell, opacities)
        return light_of(context, trial, visible)[dense].sum() / light_of(context, trial, dense)[dense].sum(), trial

    low, high = 1e-6, 1.0  # the light kept falls as the shell grows opaque: bisection in log opacity
    for _ in range(60):
        middle = np.sqrt(low * high)
        low, high = (middle, high) if kept_with(middle)[0] > RULES.seen + margin else (low, middle)
    measured, trial = kept_with(np.sqrt(low * high))
    assert measured == pytest.approx(RULES.seen + margin, abs=0.005)
    moved = dataclasses.replace(look, visible=list(visible), opacities=[float(a) for a in trial])
    assert (not any("dense keeps" in failure for failure in check_look(context, moved))) is kept


@pytest.mark.parametrize(
    "share, kept",
    [
        (RULES.see_through[0] - 0.02, False),
        (RULES.see_through[0] + 0.02, True),
        (RULES.see_through[1] - 0.02, True),
        (RULES.see_through[1] + 0.02, False),
    ],
)
def test_the_see_through_promise_is_its_band_of_the_bulks_share(share, kept):
    """The shell of the see-through look made as opaque as gives it ``share`` of the picture."""
    context = shell_context()
    look = make_look("see-through", context)
    bulk = context.of_role("bulk")
    opacities = np.asarray(look.opacities, dtype=float)

    def bulk_share(shell):
        trial = np.where(bulk, shell, opacities)
        return float(class_shares(context, trial, look.visible)[bulk].sum()), trial

    low, high = 1e-6, 1.0  # the shell's share rises with its opacity: bisection in log opacity
    for _ in range(60):
        middle = np.sqrt(low * high)
        low, high = (low, middle) if bulk_share(middle)[0] > share else (middle, high)
    measured, trial = bulk_share(np.sqrt(low * high))
    assert measured == pytest.approx(share, abs=0.005)
    moved = dataclasses.replace(look, opacities=[float(a) for a in trial])
    assert (not any("bulk gives" in failure for failure in check_look(context, moved))) is kept


@pytest.mark.parametrize("margin, kept", [(-0.02, False), (0.02, True)])
def test_the_dense_parts_promise_is_the_dense_share(margin, kept):
    context = shell_context()
    look = make_look("dense-parts", context)
    dense, bulk = context.of_role("dense"), context.of_role("bulk")
    assert check_look(context, look) == []
    assert float(look.class_shares[dense].sum()) >= RULES.dense_share
    moved = _with_share(context, look, dense, bulk, RULES.dense_share + margin)
    broken = [failure for failure in check_look(context, moved) if "dense gives" in failure]
    assert (broken == []) is kept


def twigs_context(rules=RULES):
    """Air (bin 0), a large core (bins 25-39, bulk) that takes the picture of thin twigs (bins 5-24, rim: rods one
    voxel thick touching the air) beside it, as a plant's pot beside its branches."""
    n = 40
    z, y, x = np.indices((n, n, n)) - (n - 1) / 2
    bins = np.where(np.sqrt(x**2 + y**2 + z**2) < 9, 35, 0).astype(np.intp)
    for k in (4, 12, 28, 36):  # four twigs, far from the core
        bins[k, 3, 2:38] = 15
    labels = np.select([np.arange(40) < 5, np.arange(40) < 25], [0, 1], 2)
    voxels = np.bincount(labels[bins.ravel()], minlength=3)
    classes = make_classes(voxels.tolist(), contact=[1.0, 1.0, 0.1])
    class_bins = np.array([0.0, 15.0, 35.0])
    return LookContext.build(
        classes=classes, tissue_of_class=np.arange(3), class_values=class_bins, class_bins=class_bins,
        labels=labels, noise_sd=1.0, preview=Preview(bins, (5.0, 5.0, 5.0), 40), kind="mr", rules=rules,
    )  # fmt: skip


@pytest.mark.parametrize("margin, kept", [(-0.02, False), (0.02, True)])
def test_the_thin_structures_promise_is_the_thin_share(margin, kept):
    context = twigs_context()
    assert context.roles == ["background", "rim", "bulk"]
    rim, bulk = context.of_role("rim"), context.of_role("bulk")
    look = make_look("thin-structures", context)
    assert check_look(context, look) == []
    assert float(look.class_shares[rim].sum()) >= RULES.thin_share
    # The default look under it (the core a surface, the twigs at the thin opacity) leaves them a sliver.
    uncleared = dataclasses.replace(look, opacities=[0.0, look.opacities[1], RULES.opacity_high])
    assert any("rim gives" in failure for failure in check_look(context, uncleared))
    moved = _with_share(context, look, rim, bulk, RULES.thin_share + margin)
    broken = [failure for failure in check_look(context, moved) if "rim gives" in failure]
    assert (broken == []) is kept


@pytest.mark.parametrize("thin_share", [0.2, 0.3, RULES.thin_share, 0.7, 0.9])
def test_the_thin_structures_look_clears_the_rest_only_as_far_as_the_thin_share(thin_share):
    """The pot is opaque: scaling its opacity changes its light little until it is nearly gone, where a linear step
    creeps (0.2 and 0.3 were missed by 0.015 and 0.002 after six rounds of it)."""
    context = twigs_context(dataclasses.replace(RULES, thin_share=thin_share))
    look = make_look("thin-structures", context)
    assert thin_share <= float(look.class_shares[context.of_role("rim")].sum()) <= thin_share + 0.05


def test_the_bracketed_search_reaches_a_root_where_a_function_is_flat_at_one_end():
    # A picture's share against the log of the factor its opaque surfaces are scaled by: flat, then a steep rise.
    def share(x):
        return 1.0 / (1.0 + np.exp(2.0 * (x + 8.0)))

    calls = []

    def f(x):
        calls.append(x)
        return share(x) - 0.7

    start = [(0.0, f(0.0)), (-13.8, f(-13.8))]
    points = _bracketed_search(f, start, 8, lambda v: abs(v) <= 0.02)
    assert abs(points[-1][1]) <= 0.02 and len(calls) <= 2 + 8
    assert all(-13.8 <= x <= 0.0 for x in calls)  # inside the bracket it was given
    # Without a bracket (both ends short of the aim) nothing is evaluated.
    calls.clear()
    assert _bracketed_search(f, [(0.0, -0.7), (-1.0, -0.6)], 8, lambda v: abs(v) <= 0.02) == [(0.0, -0.7), (-1.0, -0.6)]
    assert calls == []


@pytest.mark.parametrize("factor, offered", [(0.95, True), (1.05, False)])
def test_thin_structures_are_offered_when_the_rim_is_a_real_share_of_the_voxels(factor, offered):
    """The twigs are 4.4 % of the voxels that are not background: a look of their own where that is a real share."""
    voxels = np.array([c.voxels for c in twigs_context().classes], dtype=float)
    rim_share = voxels[1] / voxels[1:].sum()
    context = twigs_context(dataclasses.replace(RULES, real_share=factor * rim_share))
    assert (make_look("thin-structures", context) is not None) is offered


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("size", [1, 3, 5])
def test_box_sums_count_the_cube_around_each_voxel(seed, size):
    """Against an explicit sum over each voxel's cube, cut at the edges."""
    mask = np.random.default_rng(seed).random((6, 7, 9)) < 0.4
    half = size // 2
    expected = np.zeros(mask.shape, dtype=np.int64)
    for k, j, i in np.ndindex(mask.shape):
        expected[k, j, i] = mask[max(k - half, 0) : k + half + 1, max(j - half, 0) : j + half + 1,
                                 max(i - half, 0) : i + half + 1].sum()  # fmt: skip
    assert np.array_equal(box_sums(mask, size), expected)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_surroundings_fill_is_the_median_object_share_of_the_members_cubes(seed):
    """Against a voxel-by-voxel count on a random volume (bins 0-1 empty, 2-7 objects, 2-3 members), edges
    included; a line one voxel thick fills a twenty-fifth of the cube, a plane a fifth."""
    rng = np.random.default_rng(seed)
    bins = rng.integers(0, 8, size=(6, 7, 9))
    member, objects = np.isin(np.arange(8), (2, 3)), np.arange(8) >= 2
    padded = np.pad(objects[bins], SURROUNDINGS // 2)
    fills = [padded[k : k + SURROUNDINGS, j : j + SURROUNDINGS, i : i + SURROUNDINGS].mean()
             for k, j, i in zip(*np.nonzero(member[bins]))]  # fmt: skip
    preview = Preview(bins, (1.0, 1.0, 1.0), 8)
    assert surroundings_fill(preview, member, objects) == pytest.approx(np.median(fills))
    assert surroundings_fill(preview, np.zeros(8, dtype=bool), objects) == 0.0  # no member
    line, plane = np.zeros((9, 9, 9), dtype=np.intp), np.zeros((9, 9, 9), dtype=np.intp)
    line[4, 4, :] = 1
    plane[4, :, :] = 1
    line[4, 4, 4] = plane[4, 4, 4] = 2  # the member, in the middle
    centre, objects = np.array([False, False, True]), np.array([False, True, True])
    assert surroundings_fill(Preview(line, (1.0,) * 3, 3), centre, objects) == pytest.approx(1 / SURROUNDINGS**2)
    assert surroundings_fill(Preview(plane, (1.0,) * 3, 3), centre, objects) == pytest.approx(1 / SURROUNDINGS)


def face_skin(core):
    """The voxels outside ``core`` with a face on it: a skin one voxel thick."""
    skin = np.zeros_like(core)
    mark_face_neighbours(core, skin)
    return skin & ~core


def skinned_twigs_context(twigs, rules=RULES):
    """The twigs context with the core wrapped in a skin one voxel thick of the twigs' bin (rim too): the
    partial-volume skin of a surface, lying against the core; ``twigs``: how many of the four twigs are kept."""
    context = twigs_context(rules)
    bins = context.preview.bins.copy()
    bins[bins == 15] = 0
    for k in (4, 12, 28, 36)[:twigs]:
        bins[k, 3, 2:38] = 15
    bins[face_skin(bins == 35)] = 15
    voxels = np.bincount(context.labels[bins.ravel()], minlength=3)
    return dataclasses.replace(
        context, classes=make_classes(voxels.tolist(), contact=[1.0, 1.0, 0.1]), preview=Preview(bins, (5.0,) * 3, 40)
    )


def test_a_rim_that_is_a_surfaces_skin_gives_no_thin_structures_look():
    context = skinned_twigs_context(twigs=0)
    assert context.roles == ["background", "rim", "bulk"] and not is_thin(context)
    assert not context.rim_in_the_open and make_look("thin-structures", context) is None
    assert twigs_context().rim_in_the_open and make_look("thin-structures", twigs_context()) is not None


@pytest.mark.parametrize("factor, offered", [(0.95, False), (1.05, True)])
def test_thin_structures_beside_other_objects_are_offered_where_the_rim_lies_along_lines(factor, offered):
    """Four twigs one voxel thick beside a core: their voxels' cubes are a twenty-fifth full (less at their ends)."""
    fill = surroundings_fill(twigs_context().preview, np.arange(40) == 15, np.arange(40) >= 5)
    assert 0 < fill <= 1 / SURROUNDINGS**2
    context = twigs_context(dataclasses.replace(RULES, line_fill=fill * factor))
    assert context.rim_in_the_open is offered
    assert (make_look("thin-structures", context) is not None) is offered


@pytest.mark.parametrize("kind, first", [("mr", "thin-structures"), ("ct", "dense-parts")])
@pytest.mark.parametrize("factor", [0.95, 1.05])
def test_twigs_in_the_open_are_the_first_click_on_data_that_are_not_ct_like(kind, first, factor):
    """Beside a pot, twigs that lie along lines start as thin structures where the first click would otherwise be
    the outer surface, which clears them as a skin; a CT's first click stays its dense parts."""
    fill = surroundings_fill(twigs_context().preview, np.arange(40) == 15, np.arange(40) >= 5)
    context = dataclasses.replace(twigs_context(dataclasses.replace(RULES, line_fill=fill * factor)), kind=kind)
    expected = first if factor > 1 else {"mr": "outer-surface", "ct": "dense-parts"}[kind]
    assert first_look_name(context) == expected
    assert gallery(context)[0].name == expected


def test_thin_structures_alone_are_shown_whatever_their_rims_shape():
    """A rod in its skin, alone in an empty field (the rim most of the objects, the objects under 5 % of the volume):
    the first click of a vessel tree, made although the skin lies against the rod."""
    bins = np.zeros((40, 40, 40), dtype=np.intp)
    bins[19:22, 19:22, 5:35] = 35
    bins[face_skin(bins == 35)] = 15
    labels = np.select([np.arange(40) < 5, np.arange(40) < 25], [0, 1], 2)
    class_bins = np.array([0.0, 15.0, 35.0])
    context = LookContext.build(
        classes=make_classes(np.bincount(labels[bins.ravel()], minlength=3).tolist(), contact=[1.0, 1.0, 0.1]),
        tissue_of_class=np.arange(3), class_values=class_bins, class_bins=class_bins, labels=labels, noise_sd=1.0,
        preview=Preview(bins, (5.0, 5.0, 5.0), 40), kind="mr",
    )  # fmt: skip
    assert is_thin(context) and not context.rim_in_the_open
    assert make_look("thin-structures", context) is not None


@pytest.mark.parametrize("thin_opacity", [0.3, RULES.thin_opacity])
def test_the_lowest_rim_class_starts_at_the_thin_opacity(thin_opacity):
    """The twigs (one rim class) get the thin opacity, raised from the default look's (they start hidden there), and
    keep it: the look clears what is around them, never the rim."""
    context = twigs_context(dataclasses.replace(RULES, thin_opacity=thin_opacity))
    assert make_look("outer-surface", context).visible[1] is False
    look = make_look("thin-structures", context)
    assert look.visible[1] and look.opacities[1] == pytest.approx(thin_opacity)


@pytest.mark.parametrize("opacity_high", [0.3, RULES.opacity_high])
def test_the_first_click_follows_the_contexts_rules(opacity_high):
    """The default look under every other (the outer surface here) reads the context's rules, not the module's: the
    core, the one shown tissue, takes the ramp's top."""
    look = make_look("outer-surface", twigs_context(dataclasses.replace(RULES, opacity_high=opacity_high)))
    assert look.visible[2] and look.opacities[2] == pytest.approx(opacity_high)


@pytest.mark.parametrize("thin_opacity", [0.3, 0.7])
def test_the_rim_runs_from_the_thin_opacity_up_to_the_densest_shown_opacity(thin_opacity):
    """Twigs (bin 10) and thicker twigs (bin 20), both rim: the thinner start at the thin opacity, the thicker reach
    the densest opacity shown (the core's), or the thin opacity where that is higher."""
    n = 40
    z, y, x = np.indices((n, n, n)) - (n - 1) / 2
    bins = np.where(np.sqrt(x**2 + y**2 + z**2) < 9, 35, 0).astype(np.intp)
    for k, value in ((4, 10), (12, 10), (28, 20), (36, 20)):
        bins[k, 3, 2:38] = value
    labels = np.select([np.arange(40) < 5, np.arange(40) < 15, np.arange(40) < 25], [0, 1, 2], 3)
    class_bins = np.array([0.0, 10.0, 20.0, 35.0])
    context = LookContext.build(
        classes=make_classes(np.bincount(labels[bins.ravel()], minlength=4).tolist(), contact=[1.0, 1.0, 1.0, 0.1]),
        tissue_of_class=np.arange(4), class_values=class_bins, class_bins=class_bins, labels=labels, noise_sd=1.0,
        preview=Preview(bins, (5.0, 5.0, 5.0), 40), kind="mr",
        rules=dataclasses.replace(RULES, thin_opacity=thin_opacity),
    )  # fmt: skip
    assert context.roles == ["background", "rim", "rim", "bulk"]
    core = make_look("outer-surface", context).opacities[3]
    look = make_look("thin-structures", context)
    assert look.opacities[1] == pytest.approx(thin_opacity)
    assert look.opacities[2] == pytest.approx(max(core, thin_opacity))


def test_the_thin_structures_take_the_colour_of_the_structure_not_the_ramps_low_end():
    """The twigs context with a dense centre in its core: the ramp runs from the core (tan) to the centre (white)."""
    context = twigs_context()
    bins = context.preview.bins.copy()
    z, y, x = np.indices(bins.shape) - (bins.shape[0] - 1) / 2
    bins[np.sqrt(x**2 + y**2 + z**2) < 4] = 45
    labels = np.select([np.arange(50) < 5, np.arange(50) < 25, np.arange(50) < 40], [0, 1, 2], 3)
    voxels = np.bincount(labels[bins.ravel()], minlength=4)
    class_bins = np.array([0.0, 15.0, 35.0, 45.0])
    context = LookContext.build(
        classes=make_classes(voxels.tolist(), contact=[1.0, 1.0, 0.1, 0.0]), tissue_of_class=np.arange(4),
        class_values=class_bins, class_bins=class_bins, labels=labels, noise_sd=1.0,
        preview=Preview(bins, (5.0, 5.0, 5.0), 50), kind="mr",
    )  # fmt: skip
    assert context.roles == ["background", "rim", "bulk", "dense"]
    default = make_look("outer-surface", context)
    look = make_look("thin-structures", context)
    assert default.colors[1] == default.colors[2] != default.colors[3]  # the twigs at the ramp's low end
    assert look.visible[1] and look.colors[1] == look.colors[3] == default.colors[3]
    assert look.colors[2] == default.colors[2]  # the rest keeps its colour


def test_check_look_finds_fog_shown_and_the_densest_tissue_hidden_and_a_falling_ramp():
    context = shell_context()
    look = make_look("all-tissues", context)
    assert look.monotone and check_look(context, look) == []
    falling = dataclasses.replace(look, opacities=[0.0, 0.5, 0.1])
    assert any("does not rise" in failure for failure in check_look(context, falling))
    hidden = dataclasses.replace(look, visible=[False, True, False])
    assert any("densest real tissue" in failure for failure in check_look(context, hidden))
    background = dataclasses.replace(look, visible=[True, True, True])
    assert any("background or fog shown" in failure for failure in check_look(context, background))


@pytest.mark.parametrize("factor, must_show", [(0.95, True), (1.05, False)])
def test_check_look_wants_the_densest_tissue_shown_when_it_holds_a_real_share(factor, must_show):
    """The lesion's brighter centre holds 1.4 % of the voxels that are not background: hiding it breaks a look's
    promise where that is a real share, and the lesion is then the densest tissue that must be shown."""
    voxels = np.array([c.voxels for c in lesion_context("mr").classes], dtype=float)
    rules = dataclasses.replace(RULES, real_share=factor * voxels[3] / voxels[1:].sum())
    context = lesion_context("mr", rules)
    hidden = dataclasses.replace(make_look("all-tissues", context), visible=[False, True, True, False])
    assert any("densest real tissue (3)" in failure for failure in check_look(context, hidden)) is must_show
    assert not any("densest real tissue (2)" in failure for failure in check_look(context, hidden))


# Every look of the panel keeps its promise (the oracle) -------------------------------------------------------------


def _panel_volume(name):
    from isosimtf.volume_io import read_volume, real_dataset_path

    if name == "phantom":
        phantom = head_phantom(96, seed=4)
        return phantom.values, phantom.spacing
    path = real_dataset_path(name)
    if path is None:
        pytest.skip(f"real dataset {name!r} not installed (Debian packages invesalius-examples, mricron-data)")
    volume = read_volume(path)
    return np.asarray(volume.values), volume.spacing


@pytest.mark.parametrize("name", ["phantom", "head-ct", "brain-mri", "brain-stripped"])
def test_every_look_of_the_gallery_keeps_its_promise(name):
    values, spacing = _panel_volume(name)
    design = design_transfer_function(values, spacing)
    assert len(design.looks) >= 3
    dark_end = luma(ramp_colors(np.array([SHOWN_PLACE]))[0])
    for look in design.looks:
        assert design.check_look(look.name) == [], look.name
        if look.name != "classes":  # the palette look: one distinct colour per class, some of them dark
            shown = np.array(look.colors)[np.array(look.visible)]
            assert luma(shown.T).min() >= dark_end - 1e-9, look.name  # no shown structure in the ramp's dark end


def luma(rgb):
    """BT.601 luma of ``(3, ...)`` RGB in 0..1."""
    return 0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]


# The first click for thin structures alone --------------------------------------------------------------------------


def thin_context(rim_voxels, core_voxels, background_voxels):
    """Background (bin 0), a rim class touching it (bin 20), a core class that does not (bin 60)."""
    from IsoSimilarityTFLib.gallery import LookContext

    classes = make_classes([background_voxels, rim_voxels, core_voxels], contact=[1.0, 0.9, 0.1])
    bins = np.array([0.0, 20.0, 60.0])
    return LookContext.build(
        classes=classes, tissue_of_class=np.array([0, 1, 2]), class_values=bins, class_bins=bins,
        labels=np.repeat(np.arange(3), [10, 30, 40]), noise_sd=1.0, preview=None, kind="mr",
    )  # fmt: skip


@pytest.mark.parametrize("rim_share, thin", [(RULES.thin_rim_share - 0.01, False), (RULES.thin_rim_share + 0.01, True)])
def test_mostly_rim_objects_in_an_empty_volume_start_as_thin_structures(rim_share, thin):
    from IsoSimilarityTFLib.gallery import first_look_name

    objects = 1000
    context = thin_context(round(rim_share * objects), objects - round(rim_share * objects), 100_000)
    assert first_look_name(context) == ("thin-structures" if thin else "outer-surface")


@pytest.mark.parametrize(
    "foreground, thin", [(RULES.thin_foreground * 0.98, True), (RULES.thin_foreground * 1.02, False)]
)
def test_thin_structures_start_only_when_they_fill_little_of_the_volume(foreground, thin):
    from IsoSimilarityTFLib.gallery import is_thin

    objects = 10_000
    background = round(objects / foreground) - objects
    assert is_thin(thin_context(8000, 2000, background)) is thin
