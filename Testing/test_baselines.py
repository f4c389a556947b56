"""Tests of the evaluation's baseline classifiers (benchmarks/baselines.py) and metrics (benchmarks/evaluate.py)."""

import importlib.util
import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _load(name):
    if str(BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


baselines = _load("baselines")
evaluate = _load("evaluate")


# ------------------------------------------------------------------------------------------------ baselines


def test_equal_width_labels_split_the_range_into_k_intervals():
    values = np.array([0.0, 0.99, 1.0, 2.5, 3.999, 4.0])
    assert baselines.equal_width_labels(values, 4).tolist() == [0, 0, 1, 2, 3, 3]
    assert baselines.equal_width_labels(values, 4, value_range=(0.0, 2.0)).tolist() == [0, 1, 2, 3, 3, 3]
    assert baselines.equal_width_labels(np.full(3, 7.0), 5).tolist() == [0, 0, 0]
    with pytest.raises(ValueError):
        baselines.equal_width_labels(values, 0)


def test_kmeans_recovers_well_separated_intensity_groups_deterministically():
    rng = np.random.default_rng(1)
    truth = rng.integers(0, 3, size=30_000)
    values = np.array([-1000.0, 40.0, 1000.0])[truth] + rng.normal(0.0, 5.0, truth.size)
    labels, centres = baselines.kmeans_intensity_labels(values, 3, sample=5_000)
    assert np.allclose(centres, [-1000.0, 40.0, 1000.0], atol=2.0)
    assert np.array_equal(labels, truth)  # ids follow increasing centres
    again, _ = baselines.kmeans_intensity_labels(values, 3, sample=5_000)
    assert np.array_equal(labels, again)


def test_kmeans_with_more_classes_than_distinct_values():
    values = np.repeat([0.0, 10.0], 100)
    labels, centres = baselines.kmeans_intensity_labels(values, 5)
    assert centres.size == 2
    assert sorted(np.unique(labels)) == [0, 1]


def _line_distance(points):
    points = np.asarray(points, dtype=np.float64)
    return np.abs(points[:, None] - points[None, :])


def _brute_force_cost(distance, k, weights=None):
    n = distance.shape[0]
    w = np.ones(n) if weights is None else weights
    return min(float(w @ distance[:, list(m)].min(axis=1)) for m in itertools.combinations(range(n), k))


def test_kmedoids_finds_obvious_groups():
    points = [0.0, 0.1, 0.2, 5.0, 5.1, 5.3, 9.0, 9.2]
    labels, medoids, cost = baselines.kmedoids(_line_distance(points), 3)
    assert medoids.tolist() == [1, 4, 6]
    assert labels.tolist() == [0, 0, 0, 1, 1, 1, 2, 2]
    assert cost == pytest.approx(0.1 + 0.1 + 0.1 + 0.2 + 0.2)


def _swap_neighbours_cost(distance, medoids, weights):
    """Lowest cost over all single (medoid, non-medoid) swaps."""
    w = np.ones(distance.shape[0]) if weights is None else weights
    best = np.inf
    for position, candidate in itertools.product(range(len(medoids)), range(distance.shape[0])):
        if candidate in medoids:
            continue
        swapped = list(medoids)
        swapped[position] = candidate
        best = min(best, float(w @ distance[:, swapped].min(axis=1)))
    return best


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("weighted", [False, True])
def test_kmedoids_is_a_swap_local_optimum(seed, weighted):
    rng = np.random.default_rng(seed)
    points = np.sort(rng.normal(size=9))
    distance = _line_distance(points)
    weights = rng.integers(1, 20, size=9).astype(float) if weighted else None
    labels, medoids, cost = baselines.kmedoids(distance, 3, weights=weights)
    w = np.ones(9) if weights is None else weights
    assert cost == pytest.approx(float(w @ distance[np.arange(9), medoids[labels]]))
    # PAM guarantees that no single swap lowers the cost (it is a local search) ...
    assert cost <= _swap_neighbours_cost(distance, medoids.tolist(), weights) + 1e-12
    # ... and it can never beat the global optimum, which it reaches on these unweighted 1-D problems.
    optimum = _brute_force_cost(distance, 3, weights)
    assert cost >= optimum - 1e-12
    if not weighted:
        assert cost == pytest.approx(optimum, rel=1e-9)
    again = baselines.kmedoids(distance, 3, weights=weights)
    assert np.array_equal(again[1], medoids)


def test_kmedoids_edge_cases():
    distance = _line_distance([0.0, 1.0, 2.0])
    labels, medoids, cost = baselines.kmedoids(distance, 5)
    assert labels.tolist() == [0, 1, 2] and medoids.tolist() == [0, 1, 2] and cost == 0.0
    labels, medoids, cost = baselines.kmedoids(distance, 1)
    assert medoids.tolist() == [1] and labels.tolist() == [0, 0, 0] and cost == pytest.approx(2.0)
    with pytest.raises(ValueError):
        baselines.kmedoids(distance, 0)
    with pytest.raises(ValueError):
        baselines.kmedoids(distance, 2, weights=[1.0, -1.0, 1.0])


def test_kmedoids_isovalues_leaves_empty_isovalues_out_and_fills_them_from_neighbours():
    # Isovalues 0-2 alike, 4-6 alike, 3 and 7 cross nothing (zero rows).
    s = np.zeros((8, 8))
    for group in ([0, 1, 2], [4, 5, 6]):
        s[np.ix_(group, group)] = 0.9
    np.fill_diagonal(s, 1.0)
    s[3] = s[:, 3] = s[7] = s[:, 7] = 0.0
    labels = baselines.kmedoids_isovalues(s, 2)
    assert labels.tolist() == [0, 0, 0, 0, 1, 1, 1, 1]
    same = baselines.kmedoids_isovalues(s, 2, empty_isovalues=[3, 7])
    assert np.array_equal(labels, same)


def test_kmedoids_isovalues_agrees_with_the_library_on_a_small_volume():
    from IsoSimilarityTFLib import design_transfer_function
    from isosimtf.phantom import head_phantom

    phantom = head_phantom(32, seed=0)
    design = design_transfer_function(phantom.values, phantom.spacing)
    k = design.clustering["n_classes"]
    labels = baselines.kmedoids_isovalues(design.similarity, k, empty_isovalues=design.clustering["empty_isovalues"])
    assert labels.shape == (design.n_bins,)
    assert np.unique(labels).size == k


def test_nearest_member_prefers_the_lower_neighbour_on_ties():
    assert baselines.nearest_member(np.array([2, 6]), 9).tolist() == [2, 2, 2, 2, 2, 6, 6, 6, 6]


def test_bin_majority_oracle():
    bins = np.array([0, 0, 0, 1, 1, 3, 3, 3])
    truth = np.array([5, 5, 1, 2, 2, 1, 1, 2])
    assert baselines.bin_majority_oracle(bins, truth, 5).tolist() == [5, 2, 2, 1, 1]


# ------------------------------------------------------------------------------------------------ metrics


def test_perfect_and_trivial_labellings():
    truth = np.array([0, 0, 1, 1, 2, 2])
    perfect = evaluate.label_scores(truth, np.array([3, 3, 0, 0, 1, 1]))
    assert perfect == pytest.approx({"homogeneity": 1.0, "completeness": 1.0, "v_measure": 1.0})
    one_class = evaluate.label_scores(truth, np.zeros(6, dtype=int))
    assert one_class["homogeneity"] == pytest.approx(0.0) and one_class["completeness"] == pytest.approx(1.0)
    assert evaluate.purity(truth, np.zeros(6, dtype=int)) == pytest.approx(2 / 6)
    assert evaluate.purity(truth, np.arange(6)) == pytest.approx(1.0)


def test_voxel_classes_look_up_the_bin_class():
    bins = np.array([[[0, 1], [2, 2]]])
    assert evaluate.voxel_classes(np.array([4, 5, 6]), bins).tolist() == [[[4, 5], [6, 6]]]


def test_visibility_by_size_hides_the_largest_and_shows_the_next_ones():
    labels = np.array([2] * 5 + [0] * 3 + [1] * 3 + [3])
    background, shown = evaluate.visibility_by_size(labels, max_classes=2)
    assert background == 2
    assert shown == [0, 1]  # ties go to the lower id; class 3 is beyond max_classes


def test_shown_share_and_background_report():
    tissues = ("air", "bone", "brain")
    truth = np.array([0, 0, 0, 0, 1, 1, 2, 2])
    labels = np.array([0, 0, 0, 1, 1, 1, 2, 3])
    share = evaluate.shown_share(truth, labels, [1, 2], 3)
    assert share.tolist() == [0.25, 1.0, 0.5]
    report = evaluate.background_report(truth, labels, 0, tissues)
    assert report["majority_tissue"] == "air" and report["is_air"]
    assert report["majority_share"] == pytest.approx(1.0)
    assert report["air_hidden_share"] == pytest.approx(0.75)
    recall = evaluate.own_class_recall(truth, labels, 3)
    # class 1 holds 1 air + 2 bone (bone majority); classes 2 and 3 are brain's.
    assert recall.tolist() == [0.75, 1.0, 1.0]


def test_evaluate_labels_applies_the_size_rule_when_no_visibility_is_given():
    tissues = ("air", "bone")
    truth = np.array([0, 0, 0, 1, 1])
    labels = np.array([0, 0, 0, 1, 1])
    result = evaluate.evaluate_labels(truth, labels, tissues)
    assert result["background"]["is_air"]
    assert result["shown_share"] == [0.0, 1.0]
    assert result["v_measure"] == pytest.approx(1.0)
    assert result["n_classes"] == 2


def test_aggregate_means_and_stds_over_seeds():
    base = {"size": 8, "method": "m", "homogeneity": 0.5, "completeness": 0.5, "purity": 0.9, "n_classes": 3,
            "seconds": 1.0, "shown_share": [0.0, 1.0], "own_class_recall": [1.0, 0.5],
            "background": {"is_air": True, "air_hidden_share": 1.0}}  # fmt: skip
    records = [dict(base, seed=0, v_measure=0.4), dict(base, seed=1, v_measure=0.6)]
    (row,) = evaluate.aggregate(records, ("size",))
    assert row["v_measure"] == pytest.approx(0.5) and row["v_measure_std"] == pytest.approx(0.1)
    assert row["seeds"] == 2 and row["background_is_air"] == 2
