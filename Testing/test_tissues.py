"""Tissues: the intensity model, the contiguous grouping, every regrouping, and their round trip."""

import json
import time

import numpy as np
import pytest

from IsoSimilarityTFLib import TransferFunctionDesign, design_transfer_function
from IsoSimilarityTFLib.quantize import _bin_index, values_per_bin
from IsoSimilarityTFLib.tissues import (
    _EM_ITERATIONS,
    _EM_TOLERANCE,
    _MIXEL_FRACTIONS,
    TissueHierarchy,
    _agglomerate,
    _em_step,
    _mixing_matrix,
    _ward,
    choose_intensity_model,
    contiguous_assignment,
    fit_intensity_model,
    kmeans_1d,
    log_likelihood_bound,
    tissue_hierarchy,
    value_step,
)
from isosimtf.phantom import head_phantom


def histogram(means, sd, counts, n_bins=256, seed=0):
    rng = np.random.default_rng(seed)
    values = np.concatenate([rng.normal(m, sd, n) for m, n in zip(means, counts)])
    return np.bincount(np.clip(np.round(values), 0, n_bins - 1).astype(int), minlength=n_bins).astype(float)


@pytest.fixture(scope="module")
def design():
    phantom = head_phantom(48, seed=1)
    return design_transfer_function(phantom.values, phantom.spacing)


def test_model_finds_three_separated_tissues():
    counts = histogram([60, 130, 200], 6.0, [20000, 50000, 30000])
    model = choose_intensity_model(counts)
    assert model.n_tissues == 3
    np.testing.assert_allclose(model.means, [60, 130, 200], atol=1.5)
    assert model.sd == pytest.approx(6.0, rel=0.15)
    posterior = model.tissue_posterior(np.array([60.0, 130.0, 200.0]))
    np.testing.assert_array_equal(posterior.argmax(axis=1), [0, 1, 2])


def test_value_step_is_the_median_gap_between_the_values_held():
    lattice = np.zeros(256)
    lattice[::5] = 1.0
    assert value_step(lattice) == 5.0
    assert value_step(np.ones(256)) == 1.0
    gappy_tail = np.zeros(256)
    gappy_tail[[0, 1, 2, 3, 40, 90]] = 1.0  # a few values far out do not make a lattice
    assert value_step(gappy_tail) == 1.0
    assert value_step(np.eye(1, 256, 7).ravel()) == 1.0


@pytest.mark.parametrize("sd_steps", [0.4, 0.6])
def test_values_stored_in_coarse_steps_keep_their_tissues(sd_steps):
    """HU clipped at 0 in 62.5-HU steps holds every fifth bin of 256 over its range: the same values on every fifth
    bin give the tissues they give on every bin, scaled by the step, whether the tissues are narrower than half a
    step (the floor binds: the fit on the lattice alone split them into 8 spikes) or wider."""
    rng = np.random.default_rng(0)
    values = np.concatenate([rng.normal(m, sd_steps, n) for m, n in zip([10, 14, 30], [20000, 50000, 30000])])
    steps = np.clip(np.round(values), 0, 50).astype(int)
    unit = choose_intensity_model(np.bincount(steps, minlength=51).astype(float))
    lattice = choose_intensity_model(np.bincount(5 * steps, minlength=256).astype(float))
    assert unit.n_tissues == lattice.n_tissues == 3
    np.testing.assert_allclose(lattice.means, 5 * unit.means, atol=0.05)
    assert lattice.sd == pytest.approx(5 * unit.sd, rel=0.02)
    assert lattice.sd >= 0.5 * 5


def test_integers_filling_bins_unevenly_keep_their_tissues():
    """Two overlapping tissues stored as the integers 0..300 (a uint16 MRI): 256 bins hold one or two of them, and
    the histogram is that pattern times the tissues' density. Fitted per stored value, the model finds the tissues it
    finds when every bin holds one value; fitted to the counts, it found 8, the storage's spikes."""
    rng = np.random.default_rng(0)
    values = np.concatenate([rng.normal(201, 4.93, 6547), rng.normal(209, 4.93, 34255)])  # in bins
    one_per_bin = np.bincount(np.clip(np.round(values), 0, 255).astype(int), minlength=256).astype(float)
    stored = np.clip(np.round(values * 300 / 255), 0, 300)
    counts = np.bincount(_bin_index(stored, (0.0, 300.0), 256), minlength=256).astype(float)
    every_bin = list(range(256))
    reference = tissue_hierarchy(np.arange(256), one_per_bin, every_bin)
    uneven = tissue_hierarchy(np.arange(256), counts, every_bin, values_per_bin=values_per_bin((0.0, 300.0), 256))
    assert reference.auto == uneven.auto == 2
    assert uneven.noise_sd == pytest.approx(reference.noise_sd, rel=0.05)


def test_partial_volume_ramp_is_not_a_tissue():
    # Two tissues and the voxels mixing them (uniform fractions): a pure Gaussian mixture would put a tissue on the
    # ramp; the partial-volume model explains it by the mixel and splits it at the midpoint.
    rng = np.random.default_rng(1)
    fractions = rng.uniform(0, 1, 30000)
    mixed = 80 * (1 - fractions) + 180 * fractions + rng.normal(0, 5, fractions.size)
    pure = np.concatenate([rng.normal(80, 5, 60000), rng.normal(180, 5, 60000)])
    counts = np.bincount(np.clip(np.round(np.concatenate([pure, mixed])), 0, 255).astype(int), minlength=256)
    model = choose_intensity_model(counts.astype(float))
    assert model.n_tissues == 2
    posterior = model.tissue_posterior(np.arange(256.0))
    assert abs(int(np.argmax(posterior[:, 1] > 0.5)) - 130) <= 3


def test_em_never_lowers_the_likelihood_and_starts_matter_little():
    counts = histogram([40, 100, 170], 8.0, [30000, 30000, 30000])
    a = fit_intensity_model(counts, np.array([40.0, 100.0, 170.0]))
    b = fit_intensity_model(counts, kmeans_1d(np.arange(256.0), counts, 3))
    assert a.log_likelihood == pytest.approx(b.log_likelihood, abs=1e-3)


def test_kmeans_1d_is_optimal_on_a_small_case():
    x = np.arange(10.0)
    w = np.array([5, 5, 0, 0, 0, 3, 3, 0, 1, 1.0])
    np.testing.assert_allclose(kmeans_1d(x, w, 3), [0.5, 5.5, 8.5])


def test_contiguous_assignment_is_monotone_and_optimal():
    mass = np.array([[9, 1, 0], [1, 8, 0], [7, 2, 1], [0, 1, 9], [3, 0, 2]], dtype=float)
    assignment = contiguous_assignment(mass)
    assert np.all(np.diff(assignment) >= 0)
    # Brute force over every non-decreasing labelling.
    import itertools

    best = max(
        (sum(mass[r, t] for r, t in enumerate(labels)), labels)
        for labels in itertools.product(range(3), repeat=5)
        if all(a <= b for a, b in zip(labels, labels[1:]))
    )
    assert sum(mass[r, t] for r, t in enumerate(assignment)) == best[0]


def test_every_count_is_valid_contiguous_and_nested(design):
    hierarchy = design.hierarchy
    order = list(hierarchy.order)
    assert 1 <= hierarchy.auto <= hierarchy.max_tissues == len(design.classes) - 1
    previous_cuts: set = set()
    for n in range(1, hierarchy.max_tissues + 1):
        groups = hierarchy.groups(n)
        assert len(groups) == n and [c for g in groups for c in g] == order  # runs of the intensity order
        cuts = {order.index(g[0]) for g in groups[1:]}
        assert previous_cuts <= cuts  # nested: going from n to n + 1 tissues splits one tissue
        previous_cuts = cuts
    with pytest.raises(ValueError):
        hierarchy.groups(hierarchy.max_tissues + 1)


def test_regroup_is_instant_and_consistent(design):
    similarity = design.similarity
    start = time.perf_counter()
    for n in range(1, design.hierarchy.max_tissues + 1):
        design.regroup(n)
        assert design.n_tissues == n
        members = sorted(c for t in design.tissues for c in t.classes)
        assert members == list(range(len(design.classes)))
        for t in design.tissues:
            shown = [design.classes[c] for c in t.classes if design.classes[c].visible]
            if design.kind == "ct":  # colour follows each class's HU along the ramp: brighter with density
                brightness = [sum(c.color) for c in shown]
                assert brightness == sorted(brightness)
            else:
                assert all(c.color == t.color for c in shown)
    elapsed = (time.perf_counter() - start) / design.hierarchy.max_tissues
    assert elapsed < 0.2  # nothing heavy is recomputed: the visibility step only (make bench measures it)
    assert design.similarity is similarity
    design.regroup("auto")
    assert design.n_tissues == design.hierarchy.auto


def test_all_is_the_thesis_classes(design):
    design.regroup("all")
    assert len(design.tissues) == len(design.classes)
    assert all(t.classes == [t.classes[0]] for t in design.tissues)
    thesis = design_transfer_function(head_phantom(48, seed=1).values, tissues="all")
    np.testing.assert_array_equal(thesis.labels, design.labels)
    assert [t.classes for t in thesis.tissues] == [t.classes for t in design.tissues]


def test_tissue_edits_write_through_and_solo(design):
    design.regroup("auto")
    target = next(t for t in design.tissues if t.visible and len(t.classes) > 1)
    design.set_tissue(target.id, color=(0.1, 0.2, 0.3), opacity=0.4)
    assert all(design.classes[c].color == [0.1, 0.2, 0.3] for c in target.classes)
    assert all(design.classes[c].opacity == 0.4 for c in target.classes)
    design.solo_tissue(target.id)
    _, opacity = design.bin_looks()
    shown_bins = {b for c in target.classes for b in design.classes[c].isovalue_bins}
    assert set(np.flatnonzero(opacity)) <= shown_bins and np.any(opacity)
    design.solo(target.classes[0])
    assert design.solo_tissue_id is None
    design.solo_tissue(None)
    design.set_tissue(target.id, visible=False)
    assert not any(design.is_shown(c) for c in target.classes)
    with pytest.raises(KeyError):
        design.set_tissue(len(design.tissues), opacity=0.5)


def test_json_round_trip_keeps_tissues(design):
    design.regroup(2)
    design.set_tissue(design.tissues[-1].id, color=(0.9, 0.1, 0.1))
    design.solo_tissue(design.tissues[-1].id)
    data = json.loads(design.to_json())
    assert len(data["tissues"]) == len(design.tissues)
    assert set(data["tissues"][0]) >= {"id", "classes", "value_ranges", "voxels", "color", "opacity", "visible"}
    assert all("tissue" in c for c in data["classes"])
    back = TransferFunctionDesign.from_json(design.to_json())
    assert back.to_dict() == design.to_dict()
    back.regroup(3)  # the hierarchy travels with the design: regrouping needs no similarity
    assert back.n_tissues == 3 and back.similarity is None
    broken = dict(data, tissues=data["tissues"][:-1])
    with pytest.raises(ValueError, match="not a valid"):
        TransferFunctionDesign.from_dict(broken)


def naive_agglomeration(tissue, members, counts, similarity):
    """Every neighbouring pair's cost recomputed before each merge: what the kept costs must reproduce."""

    def cost(left, right):
        same = tissue[left[-1]] == tissue[right[0]]
        bins_l = np.concatenate([members[i] for i in left])
        bins_r = np.concatenate([members[i] for i in right])
        if same and similarity is not None:
            return 0, 1.0 - float(similarity[np.ix_(bins_l, bins_r)].mean())
        return (0 if same else 1), _ward(counts[bins_l], bins_l, counts[bins_r], bins_r)

    groups, merged_at = [[i] for i in range(len(members))], []
    while len(groups) > 1:
        costs = [cost(a, b) for a, b in zip(groups[:-1], groups[1:])]
        i = min(range(len(costs)), key=costs.__getitem__)
        merged_at.append(groups[i + 1][0])
        groups[i : i + 2] = [groups[i] + groups[i + 1]]
    return merged_at


@pytest.mark.parametrize("seed", range(30))
def test_agglomeration_equals_recomputing_every_cost(seed):
    rng = np.random.default_rng(seed)
    n_classes = int(rng.integers(1, 60))
    n_bins = n_classes + int(rng.integers(0, 100))
    cuts = np.sort(rng.choice(np.arange(1, n_bins), n_classes - 1, replace=False))
    members = np.split(np.arange(n_bins), cuts)
    tissue = np.sort(rng.integers(0, int(rng.integers(1, 6)), n_classes))
    counts = rng.integers(0, 1000, n_bins).astype(float)
    similarity = rng.random((n_bins, n_bins))
    similarity = np.round((similarity + similarity.T) / 2, int(rng.integers(1, 4)))  # rounded: many equal costs
    for matrix in (similarity, None):
        assert _agglomerate(tissue, members, counts, matrix) == naive_agglomeration(tissue, members, counts, matrix)


def test_hierarchy_round_trip_and_validation():
    hierarchy = TissueHierarchy(order=(1, 2, 3, 4), boundaries=(2, 1, 3), auto=2)
    assert TissueHierarchy.from_dict(hierarchy.to_dict()) == hierarchy
    assert hierarchy.groups(2) == [[1, 2], [3, 4]]
    with pytest.raises(ValueError):
        TissueHierarchy.from_dict({"order": [1, 2, 3], "boundaries": [1], "auto": 1})


def test_tissues_option_is_checked():
    values = np.random.default_rng(0).normal(0, 1, (12, 12, 12))
    with pytest.raises(ValueError, match="tissues"):
        design_transfer_function(values, tissues="some")
    with pytest.raises(ValueError, match="colors"):
        design_transfer_function(values, colors="rainbow")
    with pytest.raises(ValueError, match="modality"):
        design_transfer_function(values, modality="PET")
    with pytest.raises(ValueError, match="gradient_opacity"):
        design_transfer_function(values, gradient_opacity="yes")
    with pytest.raises(ValueError, match="tissues"):
        design_transfer_function(values, tissues=0)


def test_the_largest_count_whose_gain_pays_is_kept():
    """Three separate tissues: the second and the third tissue both pay (two counts pass), the fourth does not."""
    x = np.arange(256, dtype=np.float64)
    counts = sum(w * np.exp(-0.5 * ((x - m) / 6.0) ** 2) for m, w in ((50, 3e5), (130, 2e5), (210, 1e5)))
    counts = np.round(counts)
    model = choose_intensity_model(counts)
    assert model.n_tissues == 3
    np.testing.assert_allclose(np.sort(model.means), [50, 130, 210], atol=1.0)


def _choose_by_fitting_every_count(counts, max_tissues=8, relative_gain=0.5):
    """The rule written out: fit every count from both starts, gains over the best earlier fit, the largest count
    whose gain reaches the share of the largest gain."""
    x = np.arange(counts.size, dtype=np.float64)
    models = []
    for k in range(1, max_tissues + 1):
        starts = [kmeans_1d(x, counts, k)]
        if models:
            residual = counts / counts.sum() - models[-1].densities(x).sum(axis=1)
            starts.append(np.append(models[-1].means, float(np.argmax(residual))))
        models.append(max((fit_intensity_model(counts, s) for s in starts), key=lambda m: m.log_likelihood))
    likelihood = np.array([m.log_likelihood for m in models])
    gains = likelihood[1:] - np.maximum.accumulate(likelihood)[:-1]
    if gains.max() <= 0:
        return models[0]
    return models[int(np.flatnonzero(gains >= relative_gain * gains.max()).max()) + 1]


@pytest.mark.parametrize(
    "tissues",
    [
        # CT-like: air cut away, a large soft tissue, a small dense tail (the counts stop early).
        (([60, 160], 3.0, [200000, 20000]),),
        # MRI-like: overlapping tissues of similar size (every count is fitted).
        (([70, 100, 130], 9.0, [40000, 60000, 50000]),),
        (([40, 90, 150, 210], 5.0, [30000, 5000, 40000, 3000]),),
    ],
)
def test_stopping_early_chooses_what_fitting_every_count_chooses(tissues):
    ((means, sd, counts_of),) = tissues
    counts = histogram(means, sd, counts_of, seed=3)
    fast, slow = choose_intensity_model(counts), _choose_by_fitting_every_count(counts)
    assert fast.n_tissues == slow.n_tissues
    np.testing.assert_array_equal(fast.means, slow.means)
    assert fast.sd == slow.sd


@pytest.mark.parametrize("seed", range(5))
def test_no_model_beats_the_likelihood_bound(seed):
    rng = np.random.default_rng(seed)
    counts = histogram(rng.uniform(20, 230, 3), rng.uniform(0.5, 10), rng.integers(100, 50000, 3), seed=seed)
    bound = log_likelihood_bound(counts)
    for k in range(1, 6):
        assert fit_intensity_model(counts, kmeans_1d(np.arange(256.0), counts, k)).log_likelihood <= bound
    # Nor does the sharpest model allowed, the histogram itself smoothed by half a bin, and it comes close.
    x = np.arange(256.0)
    density = sum(c * np.exp(-0.5 * ((x - b) / 0.5) ** 2) / np.sqrt(2 * np.pi * 0.25) for b, c in enumerate(counts))
    share = counts / counts.sum()
    sharp = float(share[counts > 0] @ np.log(density[counts > 0] / counts.sum()))
    assert bound - 0.05 < sharp <= bound


def reference_em_step(x, w, mixing, means, variance, weights):
    """One EM step written out: every component's weighted normal density, the responsibilities, their sums."""
    k = means.size
    density = weights * np.exp(-0.5 * (x[:, None] - mixing @ means) ** 2 / variance) / np.sqrt(2 * np.pi * variance)
    total = np.maximum(density.sum(axis=1), 1e-300)
    responsibility = density * (w / total)[:, None]
    mass = responsibility.sum(axis=0)
    normal = (mixing.T * mass) @ mixing + 1e-12 * np.eye(k)
    means = np.sort(np.linalg.solve(normal, (x @ responsibility) @ mixing))
    variance = float(((x[:, None] - means) ** 2 * responsibility[:, :k]).sum() / max(mass[:k].sum(), 1e-12))
    if k > 1:
        f = _MIXEL_FRACTIONS.size
        mass[k:] = mass[k:].reshape(k - 1, f).mean(axis=1).repeat(f)
    return float(w @ np.log(total)), means, variance, mass


def reference_fit(counts, means, min_sd=0.5):
    """:func:`fit_intensity_model`'s loop with :func:`reference_em_step`: the means, sd and log-likelihood."""
    x = np.flatnonzero(counts).astype(np.float64)
    w = counts[counts > 0] / counts.sum()
    k = means.size
    f = _MIXEL_FRACTIONS.size
    means = np.sort(means)
    sd = max(float(np.sqrt(w @ (x - w @ x) ** 2)) / (2 * k), min_sd)
    weights = np.concatenate(
        [np.full(k, 0.9 / k) if k > 1 else np.ones(1), np.full((k - 1) * f, 0.1 / f / max(k - 1, 1))]
    )
    log_likelihood = -np.inf
    for _ in range(_EM_ITERATIONS):
        likelihood, means, variance, weights = reference_em_step(x, w, _mixing_matrix(k), means, sd**2, weights)
        sd = max(np.sqrt(variance), min_sd)
        improved, log_likelihood = likelihood - log_likelihood, likelihood
        if improved < _EM_TOLERANCE:
            break
    return means, sd, log_likelihood


@pytest.mark.parametrize("seed", range(6))
def test_em_step_equals_the_written_out_step(seed):
    """The fast step (expanded square, exponents below 1e-304 as 0, moments as one product) moves a model where the
    written-out step does, to rounding: models near the histogram's k-means, some components without weight. (Far
    from every bin, where the densities are below 1e-300, the two differ: both are then meaningless.)"""
    rng = np.random.default_rng(seed)
    counts = histogram(rng.uniform(10, 245, 4), rng.uniform(0.5, 12), rng.integers(50, 50000, 4), seed=seed)
    x = np.flatnonzero(counts).astype(np.float64)
    w = counts[counts > 0] / counts.sum()
    powers = np.stack((x * x, x, np.ones_like(x)), axis=1)
    for k in range(1, 9):
        mixing = _mixing_matrix(k)
        means = np.sort(kmeans_1d(np.arange(256.0), counts, k) + rng.normal(0, 5, k))
        weights = rng.dirichlet(np.ones(mixing.shape[0]))
        weights[rng.random(weights.size) < 0.1] = 0.0
        for variance in (1.0, 16.0, rng.uniform(1.0, 400.0)):
            fast = _em_step(powers, w, mixing, means, variance, weights)
            slow = reference_em_step(x, w, mixing, means, variance, weights.copy())
            assert fast[0] == pytest.approx(slow[0], rel=1e-12)
            np.testing.assert_allclose(fast[1], slow[1], rtol=0, atol=1e-6)  # bins
            assert fast[2] == pytest.approx(slow[2], rel=1e-7)  # (x - mean)**2 magnifies the means' rounding
            np.testing.assert_allclose(fast[3], slow[3], rtol=0, atol=1e-7)  # shares of the voxels


@pytest.mark.parametrize("seed", range(3))
def test_fit_equals_the_written_out_fit(seed):
    """Whole fits (up to 200 steps, not always converged) end where the written-out steps end, to 1e-7."""
    rng = np.random.default_rng(seed)
    counts = histogram(rng.uniform(20, 230, 4), rng.uniform(1, 10), rng.integers(1000, 50000, 4), seed=seed)
    for k in (1, 3, 6):
        start = kmeans_1d(np.arange(256.0), counts, k)
        model = fit_intensity_model(counts, start)
        means, sd, log_likelihood = reference_fit(counts, start)
        np.testing.assert_allclose(model.means, means, rtol=0, atol=1e-7)
        assert model.sd == pytest.approx(sd, abs=1e-7)
        assert model.log_likelihood == pytest.approx(log_likelihood, abs=1e-12)
