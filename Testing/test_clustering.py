"""Affinity propagation over isovalues: options, honesty about convergence, determinism, empty isovalues."""

import numpy as np
import pytest

from IsoSimilarityTFLib import ClusteringError, cluster_isovalues, quantize, similarity_matrix
from IsoSimilarityTFLib.clustering import preference_value


def block_similarity(sizes, within=0.95, between=0.1):
    """Similarity of isovalues that form blocks of mutually similar values."""
    n = sum(sizes)
    s = np.full((n, n), between)
    start = 0
    for size in sizes:
        s[start : start + size, start : start + size] = within
        start += size
    np.fill_diagonal(s, 1.0)
    return s


def test_groups_become_classes_ordered_by_intensity():
    # Isovalues at three well separated places on a line; similarity decays with distance.
    x = np.concatenate([np.linspace(0, 0.4, 5), np.linspace(3, 3.2, 3), np.linspace(6, 6.6, 7)])
    result = cluster_isovalues(np.exp(-np.abs(x[:, None] - x[None, :])))
    assert result.converged and result.n_classes == 3
    np.testing.assert_array_equal(result.labels, [0] * 5 + [1] * 3 + [2] * 7)
    assert list(result.exemplars) == sorted(result.exemplars)
    assert all(result.labels[e] == k for k, e in enumerate(result.exemplars))


def test_preference_rules():
    s = block_similarity([4, 4])
    affinity = s - 1
    off = affinity[~np.eye(8, dtype=bool)]
    assert preference_value(affinity, "median") == np.median(off)
    assert preference_value(affinity, "minimum") == off.min()
    assert preference_value(affinity, -0.25) == -0.25
    with pytest.raises(ValueError, match="preference"):
        preference_value(affinity, "mean")
    with pytest.raises(ValueError, match="finite"):
        preference_value(affinity, float("nan"))


def shells_similarity():
    grid = np.indices((24, 24, 24)).astype(float)
    r = np.sqrt(((grid - 12) ** 2).sum(axis=0))
    values = np.select([r < 4, r < 7, r < 10], [200, 140, 80], 20) + np.random.default_rng(0).normal(0, 4, r.shape)
    return similarity_matrix(quantize(values, 64).bins, 64)


def test_lower_preference_gives_fewer_classes_on_a_real_like_volume():
    s = shells_similarity()
    runs = [
        cluster_isovalues(s, preference=p, damping=0.7, max_iter=400, convergence_iter=25)
        for p in (-0.05, "median", "minimum")
    ]
    assert all(r.converged for r in runs)
    assert runs[0].n_classes > runs[1].n_classes > runs[2].n_classes > 1


def test_deterministic():
    rng = np.random.default_rng(3)
    s = similarity_matrix(np.sort(rng.integers(0, 40, (10, 10, 10)), axis=0), 40)
    a, b = cluster_isovalues(s), cluster_isovalues(s)
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_array_equal(a.exemplars, b.exemplars)
    assert a.n_iter == b.n_iter


def test_non_convergence_is_reported_not_hidden():
    # Undamped enough to oscillate on this volume: AP stops at max_iter with its last exemplars.
    result = cluster_isovalues(shells_similarity(), damping=0.5, max_iter=100)
    assert not result.converged and result.n_iter == 100
    assert result.labels.shape == (64,) and result.labels.min() >= 0 and result.n_classes > 1


def test_no_exemplar_is_an_error_not_a_degenerate_result():
    with pytest.raises(ClusteringError, match="no exemplar"):
        cluster_isovalues(block_similarity([5, 3, 7]), max_iter=3, convergence_iter=2)


def test_empty_isovalues_take_the_nearest_class():
    s = np.zeros((10, 10))
    s[2:8, 2:8] = block_similarity([3, 3])
    result = cluster_isovalues(s)
    assert list(np.flatnonzero(~result.clustered)) == [0, 1, 8, 9]
    np.testing.assert_array_equal(result.labels, [0, 0, 0, 0, 0, 1, 1, 1, 1, 1])


def test_identical_isovalues_are_never_split():
    # Two-value volume: 30 isovalues cross exactly the same cells; the median affinity is 0, as high as theirs.
    s = block_similarity([1, 30, 1], within=1.0, between=0.4)
    result = cluster_isovalues(s)
    assert len(set(result.labels[1:31])) == 1 and result.n_classes == 3


def test_distinct_isovalues_are_clustered_once_each():
    # The empty bins between a coarse storage's values repeat an isovalue's row: with distinct=True AP runs on one
    # copy of each row, which is AP on the matrix of the distinct rows, its labels copied to the repeats.
    rng = np.random.default_rng(3)
    x = np.sort(rng.uniform(0, 6, 9))
    distinct = np.exp(-np.abs(x[:, None] - x[None, :]))
    copies = np.array([1, 12, 1, 9, 1, 1, 15, 1, 1])
    of = np.repeat(np.arange(9), copies)  # isovalue -> distinct row
    repeated = distinct[np.ix_(of, of)]
    reference = cluster_isovalues(distinct)
    result = cluster_isovalues(repeated, distinct=True)
    assert result.converged and result.n_classes == reference.n_classes
    np.testing.assert_array_equal(result.labels, reference.labels[of])
    firsts = np.concatenate([[0], np.cumsum(copies)[:-1]])  # each exemplar at the lowest isovalue of its row
    np.testing.assert_array_equal(result.exemplars, firsts[reference.exemplars])
    # Without it, the copies are points of their own: another grouping (the preference's median is theirs).
    assert not np.array_equal(cluster_isovalues(repeated).labels, result.labels)


def test_everything_empty_or_one_isovalue():
    with pytest.raises(ClusteringError, match="nothing to cluster"):
        cluster_isovalues(np.zeros((5, 5)))
    s = np.zeros((5, 5))
    s[2, 2] = 1.0
    result = cluster_isovalues(s)
    assert result.n_classes == 1 and list(result.labels) == [0] * 5


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"damping": 0.2}, "damping"),
        ({"damping": 1.0}, "damping"),
        ({"max_iter": 0}, "max_iter"),
        ({"convergence_iter": 1.5}, "convergence_iter"),
    ],
)
def test_bad_options(kwargs, message):
    with pytest.raises(ValueError, match=message):
        cluster_isovalues(block_similarity([2, 2]), **kwargs)


def test_bad_matrices():
    with pytest.raises(ValueError, match="square"):
        cluster_isovalues(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="finite"):
        cluster_isovalues(np.full((3, 3), np.nan))


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        ({"damping": float("nan")}, "damping must be a number from 0.5 to 0.99"),
        ({"damping": None}, "damping must be given"),  # before: TypeError from '<='
        ({"max_iter": None}, "max_iter must be a positive integer"),
        ({"max_iter": 10.5}, "max_iter must be a positive integer"),
        ({"empty_isovalues": [-1]}, r"empty_isovalues must lie in \[0, 8\)"),  # before: bin 7 silently left out
        ({"empty_isovalues": [1.5]}, "empty_isovalues must be a sequence of integer isovalues"),
    ],
)
def test_bad_arguments_are_named(arguments, message):
    with pytest.raises(ValueError, match=message):
        cluster_isovalues(block_similarity([4, 4]), **arguments)


def test_similarity_must_be_what_similarity_matrix_gives():
    """Before: an asymmetric or > 1 matrix was clustered without a word."""
    with pytest.raises(ValueError, match="symmetric"):
        cluster_isovalues(np.triu(block_similarity([4, 4])))
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        cluster_isovalues(2 * block_similarity([4, 4]))
