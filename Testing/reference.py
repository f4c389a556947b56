"""The slow, obvious similarity: what the fast path in :mod:`.similarity` must equal.

Every hyper-cell is enumerated, its interval read straight from its voxels, and the isovalues crossing it written into
an explicit incidence matrix per level; ``O_h = X^T X``. Used by the tests and the benchmarks, never by the pipeline.
"""

import itertools
import math

import numpy as np


def reference_level_sizes(cell_grid_shape):
    """Hyper-cell sizes per level, coarsest first, by the words of the definition."""
    sizes = [tuple(cell_grid_shape)]
    while any(s > 1 for s in sizes[-1]):
        sizes.append(tuple(max(1, math.ceil(s / 2)) for s in sizes[-1]))
    return sizes


def reference_incidence(bins, n_bins, size, crossing):
    """Boolean matrix (hyper-cells x isovalues): does isovalue mu cross the hyper-cell?"""
    grid = [n - 1 for n in bins.shape]
    starts = [range(0, g, s) for g, s in zip(grid, size)]
    rows = []
    mu = np.arange(n_bins)
    for a0, a1, a2 in itertools.product(*starts):
        # Unit cells [a, a + s) along an axis span voxels [a, a + s].
        block = bins[
            a0 : min(a0 + size[0], grid[0]) + 1,
            a1 : min(a1 + size[1], grid[1]) + 1,
            a2 : min(a2 + size[2], grid[2]) + 1,
        ]
        low, high = int(block.min()), int(block.max())
        if crossing == "inclusive":
            rows.append((low <= mu) & (mu <= high))
        else:
            rows.append((low < mu) & (mu < high))
    return np.array(rows)


def reference_similarity_matrix(bins, n_bins, crossing="inclusive", normalization="thesis", levels=None):
    """The similarity matrix, computed the slow way (intended for volumes of a few thousand voxels)."""
    bins = np.asarray(bins)
    sizes = reference_level_sizes([n - 1 for n in bins.shape])
    n_levels = len(sizes) if levels is None else levels
    weight_sum = n_levels * (n_levels + 1) / 2
    total = np.zeros((n_bins, n_bins))
    for h in range(1, n_levels + 1):
        incidence = reference_incidence(bins, n_bins, sizes[h - 1], crossing).astype(np.int64)
        overlap = incidence.T @ incidence
        counts = np.diag(overlap)
        level = np.zeros((n_bins, n_bins))
        for i in range(n_bins):
            for j in range(n_bins):
                if normalization == "thesis":
                    denominator = max(counts[i], counts[j])
                    level[i, j] = overlap[i, j] / denominator if denominator > 0 else 0.0
                else:
                    level[i, j] = overlap[i, j] / counts[j] if counts[j] > 0 else np.nan
        total = total + (h / weight_sum) * level
    if normalization == "ma-entezari":
        result = np.zeros((n_bins, n_bins))
        for i in range(n_bins):
            for j in range(n_bins):
                a, b = total[i, j], total[j, i]
                if np.isnan(a) and np.isnan(b):
                    result[i, j] = 0.0
                elif np.isnan(a) or np.isnan(b):
                    result[i, j] = b if np.isnan(a) else a
                else:
                    result[i, j] = min(a, b)
        total = result
    return total
