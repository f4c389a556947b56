"""Step 4 of the pipeline: group isovalues with affinity propagation (Frey & Dueck 2007), no class count needed."""

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Optional, Union

import numpy as np

from .affinity_propagation import IterationCallback, affinity_propagation
from .errors import ClusteringError
from .options import OPTIONS, PREFERENCES

# Frey & Dueck's remedy for oscillating messages: more damping, tried in turn when the requested damping fails.
# Messages then move (1 - damping) of the way per iteration, so the iteration limits grow by the same factor;
# otherwise a slow run of unchanged exemplars passes for convergence.
FALLBACK_DAMPINGS = (0.7, 0.9)
# Rounding allowed in a similarity matrix's range and symmetry.
_TOLERANCE = 1e-9


@dataclass(frozen=True)
class ClusteringResult:
    """Classes of isovalues.

    Attributes:
        labels: ``(n_bins,)`` int, class id per isovalue; ids run from 0 in increasing order of exemplar isovalue.
        exemplars: ``(n_classes,)`` int, the exemplar isovalue (bin) of each class.
        n_iter: iterations affinity propagation ran.
        converged: whether it converged before ``max_iter`` (if not, the grouping is the last iteration's).
        preference: the preference value used (affinity units, <= 0).
        clustered: ``(n_bins,)`` bool, isovalues that took part; the others (empty isovalues) took the class of the
            nearest one that did.
    """

    labels: np.ndarray
    exemplars: np.ndarray
    n_iter: int
    converged: bool
    preference: float
    clustered: np.ndarray

    @property
    def n_classes(self) -> int:
        return int(self.exemplars.size)


def preference_value(affinity: np.ndarray, preference: Union[str, float]) -> float:
    """The AP preference: median or minimum of the off-diagonal affinities, or the number given."""
    if isinstance(preference, str):
        preference = preference.strip().lower()  # any letter case, as the options table takes it
        if preference not in PREFERENCES:
            raise ValueError(f"preference must be one of {PREFERENCES} or a number; got {preference!r}")
        off_diagonal = affinity[~np.eye(affinity.shape[0], dtype=bool)]
        return float(np.median(off_diagonal) if preference == "median" else off_diagonal.min())
    value = float(preference)
    if not np.isfinite(value):
        raise ValueError(f"preference must be finite; got {preference!r}")
    return value


def unconverged_advice(max_iter: int, dampings: Sequence[float]) -> str:
    """What to try when affinity propagation did not converge, what works first, never a value already tried.

    AP that oscillates between two groupings (a label map, a volume of few distinct intensities: many isovalues
    with equal similarities) keeps oscillating however long it runs: on a 33-label atlas, max_iter 1000 and 5000
    both failed where preference='minimum' converged. So the preference comes first; more damping and more
    iterations help a slow convergence, not an oscillation. Python names (``preference``, ``damping``,
    ``max_iter``); the command line shows its own flags.
    """
    tips = ["set preference='minimum' (fewer classes; it converges where the default oscillates)"]
    if max(dampings) < 0.95:
        tips.append("raise damping to 0.95")
    most_iter = int(OPTIONS["max_iter"].maximum or max_iter)
    if max_iter < most_iter:
        tips.append(f"raise max_iter (e.g. {min(most_iter, max(1000, 5 * max_iter))}) if it was still converging")
    return ", ".join(tips[:-1]) + (", or " if len(tips) > 1 else "") + tips[-1]


def _nearest(members: np.ndarray, n_bins: int) -> np.ndarray:
    """For each bin, the nearest member bin (the lower one on ties)."""
    right = np.searchsorted(members, np.arange(n_bins)).clip(0, members.size - 1)
    left = (right - 1).clip(0, members.size - 1)
    bins = np.arange(n_bins)
    use_left = np.abs(bins - members[left]) <= np.abs(members[right] - bins)
    return np.where(use_left, members[left], members[right])


def _merge_duplicates(affinity: np.ndarray, labels: np.ndarray, exemplars: np.ndarray):
    """Join classes that share isovalues with identical affinity rows.

    Such isovalues cross exactly the same cells at every level, so nothing can tell them apart; AP may still split
    them when the preference is as high as their similarity (e.g. a two-value volume, where the median affinity is
    0). Each merged class keeps the exemplar of its largest part.
    """
    _, duplicate_group = np.unique(affinity, axis=0, return_inverse=True)
    duplicate_group = duplicate_group.reshape(-1)
    parent = np.arange(exemplars.size)

    def root(k: int) -> int:
        while parent[k] != k:
            k = parent[k]
        return k

    for group in np.unique(duplicate_group):
        classes = np.unique(labels[duplicate_group == group])
        for k in classes[1:]:
            parent[root(k)] = root(classes[0])
    roots = np.array([root(k) for k in range(exemplars.size)])
    if np.array_equal(roots, np.arange(exemplars.size)):
        return labels, exemplars
    sizes = np.bincount(labels, minlength=exemplars.size)
    merged_ids, merged_labels = np.unique(roots[labels], return_inverse=True)
    merged_exemplars = np.array(
        [exemplars[max(np.flatnonzero(roots == r), key=lambda k: (sizes[k], -exemplars[k]))] for r in merged_ids]
    )
    return merged_labels.reshape(-1), merged_exemplars


def _checked_similarity(similarity: np.ndarray) -> np.ndarray:
    """``similarity`` as float64 if it is what :func:`similarity_matrix` gives: square, symmetric, in [0, 1]."""
    similarity = np.asarray(similarity, dtype=np.float64)
    if similarity.ndim != 2 or similarity.shape[0] != similarity.shape[1]:
        raise ValueError(f"similarity must be a square matrix; got shape {similarity.shape}")
    if not np.isfinite(similarity).all():
        raise ValueError("similarity must be finite")
    if similarity.size and (similarity.min() < -_TOLERANCE or similarity.max() > 1 + _TOLERANCE):
        raise ValueError(f"similarity must lie in [0, 1]; got [{similarity.min():g}, {similarity.max():g}]")
    asymmetry = float(np.abs(similarity - similarity.T).max()) if similarity.size else 0.0
    if asymmetry > _TOLERANCE:
        raise ValueError(f"similarity must be symmetric; S and its transpose differ by up to {asymmetry:g}")
    return similarity


def _checked_isovalues(isovalues: Sequence[int], n_bins: int) -> np.ndarray:
    """Isovalue indices as an array, each an integer in [0, n_bins) (a negative index would wrap around)."""
    array = np.asarray(isovalues)
    if array.size and (array.ndim != 1 or not np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"empty_isovalues must be a sequence of integer isovalues; got {isovalues!r}")
    if array.size and (array.min() < 0 or array.max() >= n_bins):
        raise ValueError(f"empty_isovalues must lie in [0, {n_bins}); got {array.min()} to {array.max()}")
    return array.astype(np.intp)


def cluster_isovalues(
    similarity: np.ndarray,
    *,
    preference: Union[str, float] = "median",
    damping: float = 0.5,
    max_iter: int = 200,
    convergence_iter: int = 15,
    empty_isovalues: Optional[Sequence[int]] = None,
    on_iteration: Optional[IterationCallback] = None,
    distinct: bool = False,
) -> ClusteringResult:
    """Cluster isovalues by affinity propagation on ``similarity - 1`` (the negated distance).

    Args:
        similarity: ``(n_bins, n_bins)`` symmetric similarity in [0, 1] (from :func:`similarity_matrix`).
        preference: ``"median"`` or ``"minimum"`` of the off-diagonal affinities, or a number (affinity units,
            typically in [-1, 0]); higher gives more classes.
        damping: AP damping factor (see ``options.OPTIONS``: 0.5 to 0.99).
        max_iter: most iterations.
        convergence_iter: iterations with unchanged exemplars that count as converged.
        empty_isovalues: isovalues left out of AP (they cross no cell); each takes the class of the nearest other
            isovalue. Default: those whose row of ``similarity`` is all zero.
        on_iteration: called as ``on_iteration(iteration, max_iter)`` after each AP iteration; raising from it stops
            the clustering.
        distinct: run AP on the distinct isovalues only: isovalues with identical rows (the empty bins between the
            values of a volume stored in a few coarse steps cross the same cells at every level) are one point, and
            each takes its point's class. Many copies of a point make AP's messages oscillate between equal
            exemplars, or collapse on one; without copies the preference's median is not theirs either. False: every
            isovalue is a point (the thesis), and classes that share identical rows are merged after AP.

    Returns:
        The classes; deterministic for the same input. ``converged`` is reported, not enforced.

    Raises:
        ValueError: bad arguments (options outside their table entry, a similarity that is not square, symmetric
            and in [0, 1], isovalues out of range). ClusteringError: no isovalue to cluster, or AP ended with no
            exemplar.
    """
    damping = OPTIONS["damping"].check(damping)
    # Iteration limits: any positive integer (the design scales the table's limits up with the fallback dampings).
    for name, value in (("max_iter", max_iter), ("convergence_iter", convergence_iter)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be a positive integer; got {value!r}")
    similarity = _checked_similarity(similarity)
    n_bins = similarity.shape[0]
    clustered = np.ones(n_bins, dtype=bool)
    if empty_isovalues is None:
        clustered &= similarity.any(axis=1)
    else:
        clustered[_checked_isovalues(empty_isovalues, n_bins)] = False
    members = np.flatnonzero(clustered)
    if members.size == 0:
        raise ClusteringError("no isovalue crosses any cell: there is nothing to cluster")

    if distinct:
        # One point per set of identical rows, each at its lowest isovalue; the labels are copied back below.
        _, first, point_of = np.unique(similarity[members], axis=0, return_index=True, return_inverse=True)
        points = np.sort(first)
        point_of = np.searchsorted(points, first[point_of.reshape(-1)])
    else:
        points = point_of = np.arange(members.size)
    affinity = similarity[np.ix_(members[points], members[points])] - 1.0
    if points.size == 1:
        member_labels, exemplars, n_iter, converged = np.zeros(1, dtype=np.intp), np.zeros(1, dtype=np.intp), 0, True
        pref = 0.0
    else:
        pref = preference_value(affinity, preference)
        run = affinity_propagation(
            affinity,
            pref,
            damping=damping,
            max_iter=int(max_iter),
            convergence_iter=int(convergence_iter),
            on_iteration=on_iteration,
        )
        exemplars, member_labels, n_iter, converged = run.exemplars, run.labels, run.n_iter, run.converged
        if exemplars.size == 0:
            raise ClusteringError(
                f"affinity propagation found no exemplar in {n_iter} iterations; "
                "raise max_iter or damping (e.g. max_iter=1000, damping=0.9)"
            )
    member_labels, exemplars = _merge_duplicates(affinity, np.asarray(member_labels), exemplars)
    member_labels = member_labels[point_of]
    # Class ids in order of exemplar isovalue, so class 0 is the lowest intensity group.
    exemplar_bins = members[points[exemplars]]
    order = np.argsort(exemplar_bins, kind="stable")
    rank_of = np.empty_like(order)
    rank_of[order] = np.arange(order.size)
    labels = np.empty(n_bins, dtype=np.intp)
    labels[members] = rank_of[member_labels]
    if members.size < n_bins:
        nearest = _nearest(members, n_bins)
        labels[~clustered] = labels[nearest[~clustered]]
    return ClusteringResult(
        labels=labels,
        exemplars=exemplar_bins[order],
        n_iter=int(n_iter),
        converged=bool(converged),
        preference=pref,
        clustered=clustered,
    )
