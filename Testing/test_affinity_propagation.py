"""The engine's affinity propagation against scikit-learn's, bit for bit, on many matrices.

scikit-learn is the reference here only (the engine does not need it): same exemplars, labels, iteration count and
convergence on random point clouds, the engine's own isovalue affinities, ties, runs cut short and degenerate matrices.
"""

import warnings

import numpy as np
import pytest

from IsoSimilarityTFLib.affinity_propagation import affinity_propagation
from IsoSimilarityTFLib.clustering import preference_value
from IsoSimilarityTFLib.quantize import quantize
from IsoSimilarityTFLib.similarity import isovalue_similarity

sklearn_cluster = pytest.importorskip("sklearn.cluster")
from sklearn.exceptions import ConvergenceWarning  # noqa: E402


def sklearn_run(similarity: np.ndarray, preference: float, **options):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        exemplars, labels, n_iter = sklearn_cluster.affinity_propagation(
            similarity, preference=preference, return_n_iter=True, random_state=0, **options
        )
    converged = not any(issubclass(w.category, ConvergenceWarning) for w in caught)
    return np.asarray(exemplars, dtype=np.intp), np.asarray(labels), n_iter, converged


def assert_same(similarity: np.ndarray, preference: float, **options) -> None:
    ours = affinity_propagation(similarity, preference, **options)
    exemplars, labels, n_iter, converged = sklearn_run(similarity, preference, **options)
    np.testing.assert_array_equal(ours.exemplars, exemplars)
    np.testing.assert_array_equal(ours.labels, labels)
    assert (ours.n_iter, ours.converged) == (n_iter, converged)


def point_cloud(rng: np.random.Generator, n: int) -> np.ndarray:
    """Negative squared distances between ``n`` points drawn around a few centres (scikit-learn's usual input)."""
    centres = rng.normal(scale=5.0, size=(rng.integers(2, 6), 2))
    points = centres[rng.integers(0, len(centres), n)] + rng.normal(size=(n, 2))
    return -np.sum((points[:, None, :] - points[None, :, :]) ** 2, axis=-1)


@pytest.mark.parametrize("seed", range(40))
def test_point_clouds_match_scikit_learn(seed: int) -> None:
    rng = np.random.default_rng(seed)
    similarity = point_cloud(rng, int(rng.integers(2, 120)))
    off_diagonal = similarity[~np.eye(len(similarity), dtype=bool)]
    damping = float(rng.choice([0.5, 0.7, 0.9]))
    for preference in (np.median(off_diagonal), off_diagonal.min(), float(rng.uniform(off_diagonal.min(), 0))):
        assert_same(similarity, preference, damping=damping)


@pytest.mark.parametrize("seed", range(25))
def test_isovalue_affinities_match_scikit_learn(seed: int) -> None:
    """What the engine clusters: ``similarity - 1`` of small random volumes, with the median and minimum preference."""
    rng = np.random.default_rng(1000 + seed)
    shape = tuple(int(s) for s in rng.integers(6, 24, 3))
    volume = rng.normal(size=shape).cumsum(axis=int(rng.integers(3)))
    n_bins = int(rng.choice([16, 32, 64, 128]))
    quantized = quantize(volume, n_bins)
    result = isovalue_similarity(quantized.bins, quantized.n_bins)
    members = np.flatnonzero(result.matrix.any(axis=1))
    if members.size < 2:
        pytest.skip("fewer than two isovalues cross a cell")
    affinity = result.matrix[np.ix_(members, members)] - 1.0
    for preference in ("median", "minimum"):
        assert_same(affinity, preference_value(affinity, preference), damping=float(rng.choice([0.5, 0.7, 0.9])))


@pytest.mark.parametrize("max_iter", [1, 5, 16, 30])
def test_runs_cut_short_match_scikit_learn(max_iter: int) -> None:
    """Not converged: the last iteration's exemplars (or none), reported as not converged, like scikit-learn."""
    rng = np.random.default_rng(max_iter)
    for _ in range(5):
        similarity = point_cloud(rng, 60)
        assert_same(similarity, float(np.median(similarity)), max_iter=max_iter, convergence_iter=15, damping=0.9)


def test_ties_and_degenerate_matrices_match_scikit_learn() -> None:
    rng = np.random.default_rng(7)
    integer_valued = -rng.integers(0, 4, size=(30, 30)).astype(float)
    integer_valued = np.minimum(integer_valued, integer_valued.T)  # symmetric, with many equal entries
    for similarity, preference in [
        (integer_valued, -1.0),
        (integer_valued, -3.0),
        (np.full((5, 5), -1.0), -1.0),  # all equal: one class
        (np.full((5, 5), -1.0), 0.0),  # all equal, each prefers itself: five classes
        (np.array([[0.0, -1.0], [-1.0, 0.0]]), -1.0),
        (np.array([[0.0, -1.0], [-1.0, 0.0]]), -0.5),
        (np.zeros((1, 1)), 0.0),
    ]:
        assert_same(similarity, preference)
        assert_same(similarity, preference, damping=0.7, convergence_iter=3)


def test_input_is_not_modified_and_progress_can_stop_the_run() -> None:
    similarity = point_cloud(np.random.default_rng(3), 40)
    before = similarity.copy()
    seen = []
    result = affinity_propagation(similarity, float(np.median(similarity)), on_iteration=lambda i, m: seen.append(i))
    np.testing.assert_array_equal(similarity, before)
    assert seen == list(range(1, result.n_iter + 1))

    class Stop(Exception):
        pass

    def stop_at_third(iteration: int, max_iter: int) -> None:
        if iteration == 3:
            raise Stop

    with pytest.raises(Stop):
        affinity_propagation(similarity, float(np.median(similarity)), on_iteration=stop_at_third)
