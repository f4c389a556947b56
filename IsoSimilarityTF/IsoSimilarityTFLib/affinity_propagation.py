"""Affinity propagation (Frey & Dueck, Science 2007) in numpy: message passing over a similarity matrix.

The engine's own implementation, so that neither Slicer nor the command line needs scikit-learn (about a second of
import and, in Slicer, a package to install) and a long run can report progress and be cancelled between iterations.
It follows scikit-learn's ``sklearn.cluster.affinity_propagation`` step for step (the same tie-breaking noise from
``numpy.random.RandomState(seed)``, the same damped updates, the same convergence rule and the same final refinement of
exemplars), so the classes are those the thesis tables were checked with: ``Testing/test_affinity_propagation.py``
compares the two bit for bit on many matrices.
"""

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

#: ``on_iteration(iteration, max_iter)``, called after each iteration; raising from it stops the run.
IterationCallback = Callable[[int, int], None]


@dataclass(frozen=True)
class AffinityPropagationResult:
    """Exemplars and labels of one affinity propagation run.

    Attributes:
        exemplars: ``(n_exemplars,)`` int, indices of the exemplars, increasing; empty if no point became one.
        labels: ``(n,)`` int, the position in ``exemplars`` of each point's exemplar; -1 everywhere if there is none.
        n_iter: iterations run.
        converged: whether the exemplars stayed the same for ``convergence_iter`` iterations before ``max_iter``.
    """

    exemplars: np.ndarray
    labels: np.ndarray
    n_iter: int
    converged: bool


def affinity_propagation(
    similarity: np.ndarray,
    preference: float,
    *,
    damping: float = 0.5,
    max_iter: int = 200,
    convergence_iter: int = 15,
    seed: int = 0,
    on_iteration: Optional[IterationCallback] = None,
) -> AffinityPropagationResult:
    """Cluster ``n`` points from their pairwise similarities by passing responsibility and availability messages.

    Args:
        similarity: ``(n, n)`` float, how well point k suits point i as its exemplar (higher is better); the diagonal
            is ignored.
        preference: how much each point prefers to be an exemplar itself (same units as ``similarity``); a higher
            preference gives more exemplars.
        damping: in [0.5, 1): each iteration moves the messages ``1 - damping`` of the way to their new values.
        max_iter: most iterations.
        convergence_iter: the run has converged once the set of exemplars stayed the same for this many iterations.
        seed: seed of the tiny noise (relative 2.2e-16) added to the similarities to break ties between equal
            candidates reproducibly.
        on_iteration: see :data:`IterationCallback`.

    Returns:
        The exemplars and labels. When the run did not converge they are those of its last iteration.
    """
    similarity = np.array(similarity, dtype=np.float64)  # a copy: the diagonal and the noise are written into it
    n = similarity.shape[0]
    off_diagonal = similarity[~np.eye(n, dtype=bool)]
    if n == 1 or np.all(off_diagonal == off_diagonal[0]):
        # Nothing tells the points apart: every point is its own exemplar if it prefers itself over the others,
        # else one exemplar (the first point) holds them all.
        if n > 1 and preference > off_diagonal[0]:
            return AffinityPropagationResult(np.arange(n), np.arange(n), 0, True)
        return AffinityPropagationResult(np.zeros(1, dtype=np.intp), np.zeros(n, dtype=np.intp), 0, True)

    np.fill_diagonal(similarity, preference)
    tiny = np.finfo(np.float64).tiny
    noise = np.random.RandomState(seed).standard_normal(size=(n, n))
    similarity += (np.finfo(np.float64).eps * similarity + tiny * 100) * noise

    responsibility = np.zeros((n, n))
    availability = np.zeros((n, n))
    scratch = np.zeros((n, n))
    rows = np.arange(n)
    diagonal = (rows, rows)
    # Whether each point was an exemplar in each of the last convergence_iter iterations (a ring buffer).
    history = np.zeros((n, convergence_iter))
    converged = False
    for iteration in range(max_iter):
        # Responsibility r(i, k) = s(i, k) - max over k' != k of (a(i, k') + s(i, k')).
        np.add(availability, similarity, scratch)
        best = np.argmax(scratch, axis=1)
        best_value = scratch[rows, best]
        scratch[rows, best] = -np.inf
        second_value = np.max(scratch, axis=1)
        np.subtract(similarity, best_value[:, None], scratch)
        scratch[rows, best] = similarity[rows, best] - second_value
        scratch *= 1 - damping
        responsibility *= damping
        responsibility += scratch

        # Availability a(i, k) = min(0, r(k, k) + sum over i' not in {i, k} of max(0, r(i', k))), a(k, k) without
        # the min; computed as its negation in scratch.
        np.maximum(responsibility, 0, out=scratch)
        scratch[diagonal] = responsibility[diagonal]
        scratch -= np.sum(scratch, axis=0)
        self_availability = scratch[diagonal].copy()
        scratch.clip(0, np.inf, scratch)
        scratch[diagonal] = self_availability
        scratch *= 1 - damping
        availability *= damping
        availability -= scratch

        is_exemplar = (availability[diagonal] + responsibility[diagonal]) > 0
        history[:, iteration % convergence_iter] = is_exemplar
        if on_iteration is not None:
            on_iteration(iteration + 1, max_iter)
        if iteration >= convergence_iter:
            times_exemplar = np.sum(history, axis=1)
            steady = (times_exemplar == convergence_iter) | (times_exemplar == 0)
            if steady.all() and is_exemplar.any():
                converged = True
                break

    exemplars = np.flatnonzero(is_exemplar)
    if exemplars.size == 0:
        no_exemplar = np.zeros(0, dtype=np.intp)
        return AffinityPropagationResult(no_exemplar, np.full(n, -1, dtype=np.intp), iteration + 1, False)
    # Each point joins its most similar exemplar; each class then takes as exemplar the member most similar to the
    # others, and the points join the refined exemplars.
    nearest = np.argmax(similarity[:, exemplars], axis=1)
    nearest[exemplars] = np.arange(exemplars.size)
    for k in range(exemplars.size):
        members = np.flatnonzero(nearest == k)
        exemplars[k] = members[np.argmax(np.sum(similarity[np.ix_(members, members)], axis=0))]
    nearest = np.argmax(similarity[:, exemplars], axis=1)
    nearest[exemplars] = np.arange(exemplars.size)
    exemplar_of_point = exemplars[nearest]
    unique_exemplars = np.unique(exemplar_of_point)
    labels = np.searchsorted(unique_exemplars, exemplar_of_point)
    return AffinityPropagationResult(unique_exemplars, labels, iteration + 1, converged)
