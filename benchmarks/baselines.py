"""Baseline classifiers the evaluation compares the method with (benchmarks only, not part of the library).

All of them are given the number of classes ``k`` (the method finds its own; the evaluation passes the ``k`` that
affinity propagation found, so the comparison is at equal class count):

* :func:`equal_width_labels`: ``k`` equal-width intensity intervals over the value range (a naive TF with ``k``
  ramps).
* :func:`kmeans_intensity_labels`: scikit-learn ``KMeans`` on voxel intensity (a random subsample for the fit, fixed
  seed and ``n_init``), every voxel then given its nearest centre.
* :func:`kmedoids` / :func:`kmedoids_isovalues`: k-medoids (PAM: greedy BUILD, then best-improvement SWAP until no
  swap lowers the cost) on the distance ``1 - S`` between isovalues, i.e. Ma & Entezari's own classifier on the same
  similarity matrix the method feeds to affinity propagation. Unweighted by default (each isovalue counts once, as in
  Ma & Entezari); ``weights`` (e.g. voxels per isovalue) gives the weighted variant. Deterministic: ties go to the
  lowest index.
* :func:`bin_majority_oracle`: not a baseline but a reference point: every isovalue bin labelled with the tissue most
  of its voxels belong to (it reads the ground truth). Its purity (accuracy) is the highest any classification of
  isovalues (a 1-D transfer function) can reach, at any number of classes; it is not a V-measure ceiling.

Only numpy (and scikit-learn for k-means).
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = [
    "bin_majority_oracle",
    "equal_width_labels",
    "kmeans_intensity_labels",
    "kmedoids",
    "kmedoids_isovalues",
    "nearest_member",
]


def equal_width_labels(values: np.ndarray, k: int, value_range: tuple[float, float] | None = None) -> np.ndarray:
    """Class ``0..k-1`` of every voxel: the index of its interval among ``k`` equal-width ones over ``value_range``.

    Args:
        values: any-shape array of intensities.
        k: number of intervals (>= 1).
        value_range: ``(low, high)``; default the data's minimum and maximum. Values outside are clamped.
    """
    if k < 1:
        raise ValueError(f"k must be >= 1; got {k}")
    values = np.asarray(values)
    low, high = (float(values.min()), float(values.max())) if value_range is None else map(float, value_range)
    if high <= low:
        return np.zeros(values.shape, dtype=np.intp)
    scaled = (values.astype(np.float64) - low) * (k / (high - low))
    return np.clip(np.floor(scaled), 0, k - 1).astype(np.intp)


def kmeans_intensity_labels(
    values: np.ndarray, k: int, *, sample: int = 200_000, n_init: int = 4, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """k-means on voxel intensity: ``(labels, centres)``, labels ``0..k'-1`` in increasing order of centre.

    The centres are fitted on ``sample`` voxels drawn without replacement (seeded); every voxel then takes its nearest
    centre (on a line: the interval between the midpoints of neighbouring centres). ``k'`` is ``k``, or the number
    of distinct intensities when there are fewer.
    """
    from sklearn.cluster import KMeans

    if k < 1:
        raise ValueError(f"k must be >= 1; got {k}")
    flat = np.asarray(values).reshape(-1)
    rng = np.random.default_rng(seed)
    fit = flat if flat.size <= sample else flat[rng.choice(flat.size, size=sample, replace=False)]
    fit = fit.astype(np.float64)
    k = min(k, np.unique(fit).size)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = KMeans(n_clusters=k, n_init=n_init, random_state=seed).fit(fit.reshape(-1, 1))
    centres = np.sort(model.cluster_centers_.reshape(-1))
    midpoints = 0.5 * (centres[:-1] + centres[1:])
    labels = np.searchsorted(midpoints, np.asarray(values, dtype=np.float64), side="right")
    return labels.astype(np.intp), centres


def kmedoids(
    distance: np.ndarray, k: int, *, weights: np.ndarray | None = None, max_swaps: int = 1000
) -> tuple[np.ndarray, np.ndarray, float]:
    """Partitioning Around Medoids on a precomputed distance matrix.

    BUILD: the first medoid minimizes the (weighted) total distance; each next one is the point that lowers the total
    distance to the nearest medoid the most. SWAP: among all (medoid, non-medoid) exchanges, apply the one that lowers
    the cost most, until none does (or ``max_swaps``).

    Args:
        distance: ``(n, n)`` symmetric, non-negative, zero diagonal.
        k: number of medoids, ``1 <= k``; with ``k >= n`` every point is its own medoid.
        weights: ``(n,)`` non-negative weight of each point in the cost (default 1 each).

    Returns:
        ``(labels, medoids, cost)``: the index (into ``medoids``) of each point's nearest medoid, the medoid indices
        in increasing order, and the weighted sum of distances to the nearest medoid.
    """
    d = np.asarray(distance, dtype=np.float64)
    n = d.shape[0]
    if d.ndim != 2 or d.shape != (n, n):
        raise ValueError(f"distance must be square; got shape {d.shape}")
    if k < 1:
        raise ValueError(f"k must be >= 1; got {k}")
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (n,) or (w < 0).any():
        raise ValueError("weights must be n non-negative numbers")
    if k >= n:
        medoids = np.arange(n)
        return np.arange(n), medoids, 0.0

    # BUILD
    medoids = [int(np.argmin(w @ d))]
    nearest = d[:, medoids[0]].copy()
    while len(medoids) < k:
        gain = w @ np.maximum(nearest[:, np.newaxis] - d, 0.0)
        gain[medoids] = -np.inf
        best = int(np.argmax(gain))
        medoids.append(best)
        np.minimum(nearest, d[:, best], out=nearest)

    # SWAP
    rows = np.arange(n)
    cost = float(w @ nearest)
    for _ in range(max_swaps):
        to_medoids = d[:, medoids]
        order = np.argsort(to_medoids, axis=1, kind="stable")
        first = to_medoids[rows, order[:, 0]]
        second = to_medoids[rows, order[:, 1]] if k > 1 else np.full(n, np.inf)
        best_cost, best_swap = cost, None
        for position in range(k):
            # Distance of every point to its nearest medoid once medoid `position` is gone, then with candidate o.
            remaining = np.where(order[:, 0] == position, second, first)
            candidate_costs = w @ np.minimum(d, remaining[:, np.newaxis])
            candidate_costs[medoids] = np.inf
            candidate = int(np.argmin(candidate_costs))
            if candidate_costs[candidate] < best_cost - 1e-12 * max(1.0, abs(best_cost)):
                best_cost, best_swap = float(candidate_costs[candidate]), (position, candidate)
        if best_swap is None:
            break
        medoids[best_swap[0]] = best_swap[1]
        cost = best_cost
    medoids_sorted = np.array(sorted(medoids), dtype=np.intp)
    labels = np.argmin(d[:, medoids_sorted], axis=1).astype(np.intp)
    return labels, medoids_sorted, float(w @ d[rows, medoids_sorted[labels]])


def nearest_member(members: np.ndarray, n: int) -> np.ndarray:
    """For each index ``0..n-1``, the nearest entry of the sorted array ``members`` (the lower one on ties)."""
    members = np.asarray(members)
    right = np.searchsorted(members, np.arange(n)).clip(0, members.size - 1)
    left = (right - 1).clip(0, members.size - 1)
    idx = np.arange(n)
    use_left = np.abs(idx - members[left]) <= np.abs(members[right] - idx)
    return np.where(use_left, members[left], members[right])


def kmedoids_isovalues(
    similarity: np.ndarray,
    k: int,
    *,
    empty_isovalues: np.ndarray | None = None,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """Class of every isovalue from k-medoids on ``1 - similarity`` (Ma & Entezari's classifier, ``k`` given).

    Isovalues in ``empty_isovalues`` (they cross no cell) are left out, as for affinity propagation, and take the
    class of the nearest other isovalue. Class ids increase with the medoid isovalue.

    Args:
        similarity: ``(n_bins, n_bins)`` similarity in [0, 1].
        k: number of classes.
        empty_isovalues: bins to leave out (default: bins whose similarity row is all zero).
        weights: ``(n_bins,)`` weight per isovalue (e.g. its voxel count) for the weighted variant.

    Returns:
        ``(n_bins,)`` class id per isovalue.
    """
    s = np.asarray(similarity, dtype=np.float64)
    n_bins = s.shape[0]
    clustered = s.any(axis=1) if empty_isovalues is None else np.ones(n_bins, dtype=bool)
    if empty_isovalues is not None:
        clustered[np.asarray(empty_isovalues, dtype=np.intp)] = False
    members = np.flatnonzero(clustered)
    distance = 1.0 - s[np.ix_(members, members)]
    np.fill_diagonal(distance, 0.0)
    member_weights = None if weights is None else np.asarray(weights, dtype=np.float64)[members]
    member_labels, _, _ = kmedoids(distance, k, weights=member_weights)
    labels = np.empty(n_bins, dtype=np.intp)
    labels[members] = member_labels
    if members.size < n_bins:
        nearest = nearest_member(members, n_bins)
        labels[~clustered] = labels[nearest[~clustered]]
    return labels


def bin_majority_oracle(bins: np.ndarray, truth: np.ndarray, n_bins: int) -> np.ndarray:
    """Per isovalue bin, the ground-truth label most of its voxels carry (bins without voxels: the nearest bin's).

    Returns:
        ``(n_bins,)`` label per bin. Reads the ground truth: the purity ceiling of 1-D (isovalue) classifiers.
    """
    bins = np.asarray(bins).reshape(-1).astype(np.intp)
    truth = np.asarray(truth).reshape(-1).astype(np.intp)
    n_labels = int(truth.max()) + 1
    table = np.bincount(bins * n_labels + truth, minlength=n_bins * n_labels).reshape(n_bins, n_labels)
    labels = table.argmax(axis=1)
    occupied = np.flatnonzero(table.sum(axis=1))
    if occupied.size < n_bins:
        nearest = nearest_member(occupied, n_bins)
        labels = labels[nearest]
    return labels.astype(np.intp)
