"""Tissues: the affinity-propagation classes grouped into the tissues of the intensity histogram.

Affinity propagation cuts the isovalues into 20-30 classes, slices of the histogram that a user (and V-measure)
does not think of as tissues. Merging classes by their mean similarity does not find tissues either: the isosurfaces
of neighbouring tissues lie next to each other, so grey and white matter are similar and merge early. Here a tissue
is what the histogram says it is:

1. **An intensity model with partial volume.** The non-background isovalue histogram is fitted by ``K`` "pure"
   tissues, Gaussians with one shared noise width (scanner noise does not depend on the tissue; a tissue that
   looks wider is mostly partial volume), plus between each pair of neighbouring tissues a *mixel* component: the
   voxels that hold a fraction ``a`` of the upper tissue and ``1 - a`` of the lower one, ``a`` uniform in (0, 1)
   (Santago & Gage 1993; Shattuck et al. 2001 for brain MRI). Fitted by expectation-maximization on the histogram
   (``n_bins`` points, so it costs nothing next to the similarity). Without the mixels, a free-width Gaussian
   swallows the partial-volume ramp and its boundary lands in the wrong place: on the held-out MNI152 brain the
   plain mixture scores V-measure 0.52, the partial-volume model 0.785 (the best any grouping of these classes
   can reach; see ``docs/evaluation.md``).
2. **The number of tissues**: models of 1 to 8 tissues are fitted (each from the optimal 1-D k-means and, greedily,
   from the previous model plus a tissue where the histogram is least explained: Verbeek et al. 2003); the count is
   the largest whose last tissue gains at least half as much log-likelihood as the best tissue added. BIC's penalty
   (``log(N) / N`` per parameter) is useless at millions of voxels, which are neither independent (blur, partial
   volume) nor exactly Gaussian: it keeps adding tissues forever; a fixed penalty per tissue falls off a cliff as
   noise lowers every gain (2 tissues on a noisy brain); a share of the best gain does not. The fits stop at the
   first count after which no further tissue could pay even if it fitted the histogram perfectly (the histogram's
   own entropy bounds every model's likelihood): the same choice as fitting all 8, in a fifth of the time on CT.
3. **Classes to tissues.** Each voxel of a partial-volume bin belongs to the tissue it holds most of (a mixel at
   ``a < 1/2`` goes to the lower tissue), so the model gives every bin a tissue posterior; a class takes the
   tissue holding most of its voxels, under the constraint that **tissues are contiguous in intensity** (a run of
   classes in exemplar order). Contiguity is what a 1-D transfer function can show as one tissue anyway, keeps
   far tails of a wide tissue from jumping over its neighbours, and makes every regrouping a set of cut points.

A hierarchy makes every count instant (:class:`TissueHierarchy`): the boundaries between neighbouring classes are
ranked once, and ``n`` tissues are the first ``n - 1`` boundaries. Below the automatic count, tissues merge by
Ward's criterion on intensity (the pair whose merge adds the least within-tissue variance); above it, a tissue
splits where its classes are least similar (mean isovalue similarity of the two sides, the thesis' measure: inside
one tissue it tells apart nested isosurfaces, which intensity alone does not).

All functions are pure and work on bin indices (``0..n_bins-1``), never on the volume.
"""

from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from itertools import islice
from typing import Optional

import numpy as np

# Partial-volume fractions used to integrate a mixel component (midpoint rule): 8 is below the histogram's
# resolution for any noise width above half a bin.
_MIXEL_FRACTIONS = (np.arange(8) + 0.5) / 8
# The last tissue's likelihood gain must reach this share of the largest gain (see choose_intensity_model). Colin27
# with scalp needs 0.37-0.81 to keep its 4 tissues (below, within-tissue shapes count as tissues); 0.5 is inside.
RELATIVE_GAIN = 0.5
MAX_TISSUES = 8
_EM_ITERATIONS = 200
# The narrowest noise width, in steps between the values the histogram holds (a histogram cannot resolve less).
_MIN_SD_STEPS = 0.5
# EM stops when the log-likelihood per voxel improves by less than this (nats): far below any tissue's gain.
_EM_TOLERANCE = 1e-6
# Exponents below this give a density of exactly 0 in an EM step (see _em_step).
_LOWEST = -700.0


@dataclass(frozen=True)
class IntensityModel:
    """Pure tissues and partial-volume mixels fitted to an isovalue histogram (in bin units).

    Attributes:
        means: ``(K,)`` pure-tissue means, ascending, in bins.
        sd: shared noise standard deviation, in bins.
        weights: ``(K,)`` share of voxels in each pure tissue.
        mixel_weights: ``(K - 1,)`` share of voxels mixing tissue k and k + 1.
        log_likelihood: mean log-likelihood per voxel of the fitted histogram (nats).
    """

    means: np.ndarray
    sd: float
    weights: np.ndarray
    mixel_weights: np.ndarray
    log_likelihood: float

    @property
    def n_tissues(self) -> int:
        return int(self.means.size)

    def densities(self, x: np.ndarray) -> np.ndarray:
        """``(n, C)`` weighted density of every component at ``x`` ``(n,)`` (see :func:`_mixing_matrix`)."""
        k = self.n_tissues
        component_weights = np.concatenate(
            [self.weights, np.repeat(self.mixel_weights / _MIXEL_FRACTIONS.size, _MIXEL_FRACTIONS.size)]
        )
        return component_weights * _gauss(x[:, None], _mixing_matrix(k) @ self.means, self.sd**2)

    def tissue_posterior(self, x: np.ndarray) -> np.ndarray:
        """``(n, K)`` probability that a voxel of value ``x`` (bins) holds mostly tissue k."""
        mostly = self.densities(np.asarray(x, dtype=np.float64)) @ _majority_matrix(self.n_tissues)
        return mostly / np.maximum(mostly.sum(axis=1, keepdims=True), 1e-300)


@cache
def _mixing_matrix(k: int) -> np.ndarray:
    """``(C, K)``: the mean of each component as a mix of the K tissue means. C = K pure components, then for each
    neighbouring pair (k, k + 1) one component per partial-volume fraction. Cached (read-only): EM asks every
    iteration."""
    f = _MIXEL_FRACTIONS.size
    matrix = np.zeros((k + (k - 1) * f, k))
    matrix[np.arange(k), np.arange(k)] = 1.0
    for low in range(k - 1):
        rows = k + low * f + np.arange(f)
        matrix[rows, low] = 1 - _MIXEL_FRACTIONS
        matrix[rows, low + 1] = _MIXEL_FRACTIONS
    matrix.flags.writeable = False
    return matrix


@cache
def _majority_matrix(k: int) -> np.ndarray:
    """``(C, K)``: 1 where a component's voxels hold mostly tissue k (a mixel goes to the side it holds more of)."""
    mixing = _mixing_matrix(k)
    majority = (mixing == mixing.max(axis=1, keepdims=True)).astype(np.float64)
    majority.flags.writeable = False
    return majority


def _gauss(x: np.ndarray, mean: np.ndarray, var: float) -> np.ndarray:
    """Normal density at ``x`` (broadcast against ``mean``), computed in place."""
    z = np.subtract(x, mean)
    z *= z
    z *= -0.5 / var
    np.exp(z, out=z)
    z *= 1.0 / np.sqrt(2 * np.pi * var)
    return z


@cache
def _mixel_averaging(k: int) -> np.ndarray:
    """``(C - K, C - K)``: right-multiplied, gives each mixel fraction the mean weight of its pair's fractions."""
    f = _MIXEL_FRACTIONS.size
    averaging = np.kron(np.eye(k - 1), np.full((f, f), 1.0 / f))
    averaging.flags.writeable = False
    return averaging


def fit_intensity_model(counts: np.ndarray, means: np.ndarray, min_sd: float = _MIN_SD_STEPS) -> IntensityModel:
    """Expectation-maximization of the partial-volume model on a histogram, from initial means.

    Args:
        counts: ``(n_bins,)`` voxels per bin (the background's bins already zeroed).
        means: ``(K,)`` initial tissue means in bins.
        min_sd: floor of the noise width in bins (a histogram cannot resolve less than a bin).

    Every component's mean is linear in the K tissue means (``_mixing_matrix``) and all share one variance, so the
    M-step for the means is one weighted least-squares solve; the variance comes from the pure components (the
    mixels' spread is partial volume, not noise).
    """
    x = np.flatnonzero(counts).astype(np.float64)
    w = counts[counts > 0].astype(np.float64)
    w /= w.sum()
    powers = np.stack((x * x, x, np.ones_like(x)), axis=1)
    k = int(np.size(means))
    mixing = _mixing_matrix(k)
    f = _MIXEL_FRACTIONS.size
    spread = float(np.sqrt(w @ (x - w @ x) ** 2))
    means = np.sort(np.asarray(means, dtype=np.float64))
    sd = max(spread / (2 * k), min_sd)
    # One weight per component: the fractions of a mixel share its weight equally.
    weights = np.concatenate(
        [np.full(k, 0.9 / k) if k > 1 else np.ones(1), np.full((k - 1) * f, 0.1 / f / max(k - 1, 1))]
    )
    log_likelihood = -np.inf
    for _ in range(_EM_ITERATIONS):
        likelihood, means, variance, weights = _em_step(powers, w, mixing, means, sd**2, weights)
        sd = max(np.sqrt(variance), min_sd)
        improved = likelihood - log_likelihood
        log_likelihood = likelihood
        if improved < _EM_TOLERANCE:
            break
    return IntensityModel(
        means=means,
        sd=float(sd),
        weights=weights[:k],
        mixel_weights=weights[k:].reshape(k - 1, f).sum(axis=1) if k > 1 else np.zeros(0),
        log_likelihood=log_likelihood,
    )


def _em_step(
    powers: np.ndarray, w: np.ndarray, mixing: np.ndarray, means: np.ndarray, variance: float, weights: np.ndarray
) -> tuple[float, np.ndarray, float, np.ndarray]:
    """One EM step: the log-likelihood per voxel of the given model and the model EM moves it to.

    ``powers`` ``(n, 3)``: ``x**2, x, 1`` for the ``n`` bins ``x``; ``w`` ``(n,)`` their shares of the voxels;
    ``mixing`` ``(C, K)``; ``means`` ``(K,)``; ``variance`` in bins^2; ``weights`` ``(C,)`` per component.

    The fits run thousands of steps on ``n x C`` arrays of at most 256 x 64, so a step is numpy's call overhead: the
    exponents of all weighted densities are one product (the square expanded, the log-weight added), and the E-step's
    sums are one product of the responsibilities' row weights with the densities. Exponents below ``_LOWEST`` give
    a density of exactly 0 (below 1e-304, nothing next to a sum clamped at 1e-300): computing their subnormal
    values would make ``exp`` ten times slower.
    """
    k = means.size
    a = 0.5 / variance
    component_means = mixing @ means
    log_scale = np.log(np.maximum(weights, np.finfo(np.float64).tiny)) - 0.5 * np.log(2 * np.pi * variance)
    coefficients = np.stack(
        (np.full(component_means.size, -a), 2 * a * component_means, log_scale - a * component_means**2)
    )
    density = powers @ coefficients  # (n, C) exponents
    far = density < _LOWEST
    np.maximum(density, _LOWEST, out=density)
    np.exp(density, out=density)
    density[far] = 0.0
    total = density @ np.ones(density.shape[1])
    np.maximum(total, 1e-300, out=total)
    likelihood = float(w @ np.log(total))
    # Row weights of the responsibilities (n, C): the moments sum_x x**p * responsibility, p = 0, 1, 2, per component.
    mass, first, second = (powers * (w / total)[:, None]).T[::-1] @ density
    normal = (mixing.T * mass) @ mixing
    normal.flat[:: k + 1] += 1e-12
    means = np.sort(np.linalg.solve(normal, first @ mixing))
    spread = second[:k] - 2 * means * first[:k] + means**2 * mass[:k]
    variance = max(float(spread.sum() / max(mass[:k].sum(), 1e-12)), 0.0)
    if k > 1:
        mass[k:] = mass[k:] @ _mixel_averaging(k)
    return likelihood, means, variance, mass


def log_likelihood_bound(counts: np.ndarray, min_sd: float = _MIN_SD_STEPS) -> float:
    """The highest log-likelihood per voxel any model with noise widths of at least ``min_sd`` bins can reach.

    A Gaussian of width ``sd >= min_sd`` sums over the integer bins to at most ``Z = sum_m exp(-2 pi^2 sd^2 m^2)``
    (Poisson summation; 1.0144 at half a bin), so a mixture's densities at the bins form a measure of mass at most
    ``Z``, and by Gibbs' inequality no model beats the histogram itself: ``-entropy(share) + log(Z)``.
    """
    share = np.asarray(counts, dtype=np.float64)
    share = share[share > 0] / share.sum()
    m = np.arange(1, 16)
    z = 1.0 + 2.0 * float(np.exp(-2 * np.pi**2 * min_sd**2 * m**2).sum())
    return float(share @ np.log(share)) + float(np.log(z))


def choose_intensity_model(
    counts: np.ndarray, max_tissues: int = MAX_TISSUES, relative_gain: float = RELATIVE_GAIN
) -> IntensityModel:
    """Fit 1, 2, ... tissues; keep the most whose last tissue still pays: a gain of at least ``relative_gain`` of
    the best gain any added tissue brought.

    The gain of K tissues is its log-likelihood per voxel over the best fit of fewer tissues (K tissues can always
    say what K - 1 say, so a fit less likely than an earlier one is EM stuck, not a loss). The count is the largest
    K whose gain is at least ``relative_gain`` times the largest gain: a tissue must explain the histogram about as
    much better as the main tissue split does, not split one tissue's non-Gaussian shape. Relative, so it does not
    move with the noise: more noise lowers every gain alike. The counts stop where even a perfect model
    (:func:`log_likelihood_bound`) could not gain enough: on CT-like histograms that is after 3 or 4 of the 8.

    Each fit starts from two places and keeps the likelier: the optimal 1-D k-means of the histogram (exact, so the
    start never depends on luck) and the previous fit plus a tissue where that fit explains the histogram worst
    (greedy mixture learning). No noise width is narrower than half the step between the values the histogram
    holds (:func:`value_step`).

    Args:
        counts: ``(n_bins,)`` voxels per bin, background zeroed; at least one non-zero bin.
        max_tissues: largest count tried (also bounded by the number of non-empty bins).
        relative_gain: share of the largest gain that the last tissue's gain must reach, in (0, 1].
    """
    counts = np.asarray(counts, dtype=np.float64)
    x_all = np.arange(counts.size, dtype=np.float64)
    share = counts / counts.sum()
    min_sd = _MIN_SD_STEPS * value_step(counts)
    bound = log_likelihood_bound(counts, min_sd)
    models: list[IntensityModel] = []
    gains: list[float] = []
    best = -np.inf  # the likeliest fit so far
    for k, centres in zip(range(1, min(max_tissues, np.count_nonzero(counts)) + 1), _kmeans_1d_centres(x_all, counts)):
        starts = [centres]
        if models:
            residual = share - models[-1].densities(x_all).sum(axis=1)
            starts.append(np.append(models[-1].means, float(np.argmax(residual))))
        fits = (fit_intensity_model(counts, start, min_sd) for start in starts)
        models.append(max(fits, key=lambda m: m.log_likelihood))
        if k > 1:
            gains.append(models[-1].log_likelihood - best)
        best = max(best, models[-1].log_likelihood)
        if gains and bound - best < relative_gain * max(gains):
            break
    if not gains or max(gains) <= 0:
        return models[0]
    return models[int(np.flatnonzero(np.array(gains) >= relative_gain * max(gains)).max()) + 1]


def value_step(counts: np.ndarray) -> float:
    """The step, in bins, between the values a histogram holds: the median gap between its non-empty bins, at
    least 1. Data stored in coarse steps (HU clipped at 0 in 62.5-HU steps: every fifth bin of 256 over 0..3343 HU)
    leave the bins between their values empty; a tissue narrower than the step is a spike of the storage, not of the
    scan, and a model fitted to such spikes splits one tissue into several.

    Args:
        counts: ``(n_bins,)`` voxels per bin.
    """
    gaps = np.diff(np.flatnonzero(np.asarray(counts)))
    return max(float(np.median(gaps)), 1.0) if gaps.size else 1.0


def kmeans_1d(x: np.ndarray, weights: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` centres of the optimal weighted k-means of points on a line, ascending (fewer if there are fewer
    points of non-zero weight). ``x`` ``(n,)`` sorted. See :func:`_kmeans_1d_centres`."""
    return list(islice(_kmeans_1d_centres(x, weights), k))[-1]


def _kmeans_1d_centres(x: np.ndarray, weights: np.ndarray) -> Iterator[np.ndarray]:
    """The centres of the optimal weighted k-means for k = 1, 2, ... up to the number of points of non-zero weight
    (dynamic programming over sorted points, Wang & Song 2011): one O(n^2) step per k, each k from the last one's
    table. ``x`` ``(n,)`` sorted."""
    keep = weights > 0
    x, w = x[keep], weights[keep].astype(np.float64)
    n = x.size
    s0, s1, s2 = (np.concatenate(([0.0], np.cumsum(w * x**p))) for p in (0, 1, 2))
    first, last = np.triu_indices(n)
    cost = np.full((n, n), np.inf)  # cost[i, j]: sum of squares of points i..j around their weighted mean
    seg_w = s0[last + 1] - s0[first]
    cost[first, last] = s2[last + 1] - s2[first] - (s1[last + 1] - s1[first]) ** 2 / seg_w
    best = cost[0].copy()  # best[j]: the k clusters' cost over points 0..j
    splits: list[np.ndarray] = []
    for k in range(1, n + 1):
        if k > 1:
            total = best[:-1, None] + cost[1:, :]  # previous clusters end at i - 1, the new one is i..j
            start = np.argmin(total, axis=0) + 1
            best = np.concatenate(([np.inf], total[start - 1, np.arange(n)][1:]))
            splits.append(start)
        starts, end = [], n - 1  # walk back from the last point: each cluster starts where its DP step chose
        for start in reversed(splits):
            starts.append(int(start[end]))
            end = starts[-1] - 1
        bounds = [0, *reversed(starts), n]
        yield np.array([np.average(x[a:b], weights=w[a:b]) for a, b in zip(bounds[:-1], bounds[1:])])


def contiguous_assignment(mass: np.ndarray) -> np.ndarray:
    """The non-decreasing tissue index per row that holds the most mass (dynamic programming).

    Args:
        mass: ``(n_rows, K)`` voxels of row (a class, in intensity order) belonging to tissue k.

    Returns:
        ``(n_rows,)`` tissue index, non-decreasing, maximizing the sum of ``mass[row, tissue]``.
    """
    n_rows, k = mass.shape
    best = np.empty((n_rows, k))
    came_from = np.zeros((n_rows, k), dtype=np.intp)
    best[0] = mass[0]
    for row in range(1, n_rows):
        # Best predecessor at any tissue <= t: running maximum (and where it is) over the previous row.
        came_from[row] = [int(np.argmax(best[row - 1, : t + 1])) for t in range(k)]
        best[row] = best[row - 1, came_from[row]] + mass[row]
    assignment = np.empty(n_rows, dtype=np.intp)
    assignment[-1] = int(np.argmax(best[-1]))
    for row in range(n_rows - 1, 0, -1):
        assignment[row - 1] = came_from[row, assignment[row]]
    return assignment


@dataclass(frozen=True)
class TissueHierarchy:
    """Every grouping of the non-background classes into contiguous tissues, from 1 tissue to one per class.

    Attributes:
        order: non-background class ids in intensity (exemplar) order.
        boundaries: positions ``b`` (a cut between ``order[b - 1]`` and ``order[b]``), most important first.
        auto: the number of tissues the intensity model chose.
        noise_sd: the model's shared noise width, in bins (how far apart two tissues must lie to be told apart).
    """

    order: tuple[int, ...]
    boundaries: tuple[int, ...]
    auto: int
    noise_sd: float = 1.0

    @property
    def max_tissues(self) -> int:
        return len(self.order)

    def groups(self, n_tissues: int) -> list[list[int]]:
        """The class ids of each of ``n_tissues`` tissues, in intensity order."""
        if not 1 <= n_tissues <= max(self.max_tissues, 1):
            raise ValueError(f"the number of tissues must be 1 to {self.max_tissues}; got {n_tissues}")
        cuts = [0, *sorted(self.boundaries[: n_tissues - 1]), len(self.order)]
        return [list(self.order[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]

    def to_dict(self) -> dict:
        return {
            "order": list(self.order),
            "boundaries": list(self.boundaries),
            "auto": self.auto,
            "noise_sd": self.noise_sd,
        }

    @classmethod
    def from_dict(cls, data: dict) -> "TissueHierarchy":
        order = tuple(int(c) for c in data["order"])
        boundaries = tuple(int(b) for b in data["boundaries"])
        if sorted(boundaries) != list(range(1, len(order))):
            raise ValueError("tissue boundaries must rank every cut between neighbouring classes once")
        # Designs saved before the noise width was kept: one bin, the histogram's resolution.
        noise_sd = float(data.get("noise_sd", 1.0))
        return cls(order=order, boundaries=boundaries, auto=int(data["auto"]), noise_sd=noise_sd)


def tissue_hierarchy(
    labels: np.ndarray,
    counts: np.ndarray,
    order: list[int],
    similarity: Optional[np.ndarray] = None,
    model: Optional[IntensityModel] = None,
    values_per_bin: Optional[np.ndarray] = None,
) -> TissueHierarchy:
    """Rank the cuts between neighbouring classes so that ``n`` tissues are the ``n - 1`` first cuts.

    Args:
        labels: ``(n_bins,)`` class id per bin.
        counts: ``(n_bins,)`` voxels per bin.
        order: the non-background class ids in intensity order.
        similarity: ``(n_bins, n_bins)`` isovalue similarity; orders the cuts inside a tissue (without it, Ward's
            criterion does).
        model: the intensity model (default: :func:`choose_intensity_model` on the classes' bins).
        values_per_bin: ``(n_bins,)`` how many values the storage can put in each bin
            (:func:`.quantize.values_per_bin`), or None where every bin can hold as many. The default model is
            fitted to the voxels per stored value: an integer storage that puts one value in some bins and two in
            others (301 values over 256 bins) makes every sixth bin of the histogram twice as full, a pattern of
            the storage that the model would otherwise fit as tissues (a T1 head stored as uint16 0..300 was taken
            for a CT: its scalp fat became bone).
    """
    labels = np.asarray(labels)
    counts = np.asarray(counts, dtype=np.float64)
    n = len(order)
    if n <= 1:
        return TissueHierarchy(order=tuple(order), boundaries=(), auto=n)
    in_order = np.isin(labels, order)
    if model is None:
        model = choose_intensity_model(np.where(in_order, _per_stored_value(counts, values_per_bin), 0.0))
    x = np.arange(labels.size, dtype=np.float64)
    posterior = model.tissue_posterior(x) * counts[:, None]
    position = np.full(int(labels.max()) + 1, -1)
    position[order] = np.arange(n)
    mass = np.zeros((n, model.n_tissues))
    np.add.at(mass, position[labels[in_order]], posterior[in_order])
    tissue = contiguous_assignment(mass)

    members = [np.flatnonzero(labels == c) for c in order]
    merged_at = _agglomerate(tissue, members, counts, similarity)
    auto = len(np.unique(tissue))
    return TissueHierarchy(
        order=tuple(int(c) for c in order), boundaries=tuple(merged_at[::-1]), auto=auto, noise_sd=float(model.sd)
    )


def _per_stored_value(counts: np.ndarray, values_per_bin: Optional[np.ndarray]) -> np.ndarray:
    """Voxels per bin divided by the values each bin can hold, scaled back to the same total (bins that can hold
    none hold no voxels)."""
    if values_per_bin is None:
        return counts
    per = np.asarray(values_per_bin, dtype=np.float64)
    density = np.divide(counts, per, out=np.zeros_like(counts), where=per > 0)
    return density * (counts.sum() / density.sum()) if density.sum() > 0 else counts


def _agglomerate(
    tissue: np.ndarray, members: list[np.ndarray], counts: np.ndarray, similarity: Optional[np.ndarray]
) -> list[int]:
    """Merge neighbouring classes, cheapest pair first, until one group is left; the order of the merges.

    Pairs inside a tissue go first, the most similar first (``1 -`` their mean isovalue similarity), then pairs across
    tissues by Ward's criterion (or everything by Ward's without a similarity); ties go to the lowest pair.

    Args:
        tissue: ``(n,)`` tissue of each class, classes in intensity order.
        members: the bins of each class, in the same order.
        counts: ``(n_bins,)`` voxels per bin.
        similarity: ``(n_bins, n_bins)`` isovalue similarity, or None.

    Returns:
        For each merge in turn, the position of the class that starts the right-hand group (the boundary removed).
    """

    def merge_cost(left: list[int], right: list[int]) -> tuple[int, float]:
        same = tissue[left[-1]] == tissue[right[0]]
        bins_l = np.concatenate([members[i] for i in left])
        bins_r = np.concatenate([members[i] for i in right])
        if same and similarity is not None:
            return 0, 1.0 - float(similarity[np.ix_(bins_l, bins_r)].mean())
        return (0 if same else 1), _ward(counts[bins_l], bins_l, counts[bins_r], bins_r)

    groups = [[i] for i in range(len(members))]  # positions in intensity order
    costs = [merge_cost(left, right) for left, right in zip(groups[:-1], groups[1:])]  # costs[k]: groups k, k + 1
    merged_at: list[int] = []
    while len(groups) > 1:
        i = min(range(len(costs)), key=costs.__getitem__)
        merged_at.append(groups[i + 1][0])
        groups[i : i + 2] = [groups[i] + groups[i + 1]]
        # Only the merged group's two pairs change: the other costs are kept (thousands of classes at 4096 bins).
        neighbours = [merge_cost(groups[k], groups[k + 1]) for k in (i - 1, i) if 0 <= k < len(groups) - 1]
        costs[max(i - 1, 0) : i + 2] = neighbours
    return merged_at


def _ward(w_a: np.ndarray, x_a: np.ndarray, w_b: np.ndarray, x_b: np.ndarray) -> float:
    """Increase of the within-group sum of squares (bins^2, voxel-weighted) when two groups merge."""
    n_a, n_b = float(w_a.sum()), float(w_b.sum())
    if n_a == 0 or n_b == 0:
        return 0.0
    mean_a, mean_b = float(w_a @ x_a) / n_a, float(w_b @ x_b) / n_b
    return n_a * n_b / (n_a + n_b) * (mean_a - mean_b) ** 2
