"""The fast similarity path equals the slow, obvious reference; known answers on the thesis' test images."""

import itertools

import numpy as np
import pytest
from reference import reference_level_sizes, reference_similarity_matrix

from IsoSimilarityTFLib import isovalue_similarity, octree_levels, similarity_matrix, stream, unit_cell_intervals
from IsoSimilarityTFLib.cells import OctreeBuilder, unit_cell_slabs
from IsoSimilarityTFLib.similarity import overlap_counts
from IsoSimilarityTFLib.stream import joint_interval_histogram

RULES = list(itertools.product(("inclusive", "strict"), ("thesis", "ma-entezari")))


def random_volume(rng, shape, n_bins, kind):
    if kind == "uniform":
        return rng.integers(0, n_bins, shape)
    if kind == "sorted":  # smooth along one axis: nested isosurfaces
        return np.sort(rng.integers(0, n_bins, shape), axis=int(rng.integers(0, 3)))
    if kind == "blobs":  # a few flat regions with noisy borders
        grid = np.indices(shape).astype(float)
        centre = [rng.uniform(0, s) for s in shape]
        r = np.sqrt(sum((g - c) ** 2 for g, c in zip(grid, centre)))
        levels = rng.integers(0, n_bins, 3)
        volume = np.select([r < 2, r < 4], levels[:2], levels[2])
        return np.clip(volume + rng.integers(-1, 2, shape), 0, n_bins - 1)
    raise ValueError(kind)


SHAPES = [(2, 2, 2), (2, 3, 5), (2, 9, 4), (3, 3, 3), (5, 2, 7), (6, 6, 6), (7, 11, 3), (9, 4, 10), (12, 5, 5)]


@pytest.mark.parametrize("crossing,normalization", RULES)
@pytest.mark.parametrize("kind", ["uniform", "sorted", "blobs"])
def test_fast_path_equals_reference(crossing, normalization, kind):
    rng = np.random.default_rng(abs(hash((crossing, normalization, kind))) % 2**32)
    for shape in SHAPES:
        n_bins = int(rng.choice([2, 5, 16, 37]))
        bins = random_volume(rng, shape, n_bins, kind)
        fast = similarity_matrix(bins, n_bins, crossing=crossing, normalization=normalization)
        slow = reference_similarity_matrix(bins, n_bins, crossing, normalization)
        np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12, err_msg=f"{shape} {n_bins}")
        assert fast.dtype == np.float64 and fast.shape == (n_bins, n_bins)
        np.testing.assert_array_equal(fast, fast.T)


@pytest.mark.parametrize("crossing,normalization", RULES)
def test_fast_path_equals_reference_with_fewer_levels(crossing, normalization):
    rng = np.random.default_rng(7)
    for shape in [(9, 6, 13), (4, 17, 5), (10, 10, 10)]:
        bins = random_volume(rng, shape, 24, "sorted")
        n_levels = len(octree_levels(tuple(s - 1 for s in shape)))
        for levels in range(1, n_levels + 1):
            fast = similarity_matrix(bins, 24, crossing=crossing, normalization=normalization, levels=levels)
            slow = reference_similarity_matrix(bins, 24, crossing, normalization, levels)
            np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12)


def test_many_random_volumes_all_rules():
    """Property check over many small random volumes, odd shapes and bin counts."""
    rng = np.random.default_rng(2024)
    for _ in range(40):
        shape = tuple(int(s) for s in rng.integers(2, 10, 3))
        n_bins = int(rng.integers(2, 40))
        bins = random_volume(rng, shape, n_bins, str(rng.choice(["uniform", "sorted", "blobs"])))
        crossing, normalization = RULES[int(rng.integers(0, 4))]
        fast = similarity_matrix(bins, n_bins, crossing=crossing, normalization=normalization)
        np.testing.assert_allclose(
            fast, reference_similarity_matrix(bins, n_bins, crossing, normalization), rtol=0, atol=1e-12
        )


def test_octree_levels_follow_the_definition():
    assert octree_levels((127, 127, 114)) == [
        (127, 127, 114), (64, 64, 57), (32, 32, 29), (16, 16, 15), (8, 8, 8), (4, 4, 4), (2, 2, 2), (1, 1, 1)
    ]  # fmt: skip
    assert len(octree_levels((255, 255, 255))) == 9
    assert octree_levels((1, 1, 1)) == [(1, 1, 1)]
    assert octree_levels((1, 5, 2)) == [(1, 5, 2), (1, 3, 1), (1, 2, 1), (1, 1, 1)]
    for shape in [(3, 7, 1), (100, 2, 33), (511, 511, 511)]:
        assert octree_levels(shape) == reference_level_sizes(shape)


def direct_block_intervals(bins, size, index):
    """Interval of one hyper-cell read straight from its voxels."""
    block = bins[tuple(slice(i * s, min((i + 1) * s, n - 1) + 1) for i, s, n in zip(index, size, bins.shape))]
    return block.min(), block.max()


@pytest.mark.parametrize("planes", [1, 2, 3, 5, 7, 32])
@pytest.mark.parametrize("shape", [(14, 9, 23), (17, 6, 5), (31, 4, 3), (2, 12, 9)])
def test_hyper_cell_intervals_match_direct_blocks_for_any_slab_thickness(planes, shape):
    """Slabs of any thickness give every level exactly, row by row, including levels nested in no finer one."""
    rng = np.random.default_rng(sum(shape) * 10 + planes)
    bins = rng.integers(0, 200, shape).astype(np.uint8)
    mins, maxs = unit_cell_intervals(bins)
    assert mins.shape == tuple(n - 1 for n in shape)
    for index in itertools.product(*(range(n) for n in mins.shape)):
        assert (mins[index], maxs[index]) == direct_block_intervals(bins, (1, 1, 1), index)
    rows = {}  # level -> first row -> (mins, maxs) handed to the sink

    def sink(level, first_row, row_mins, row_maxs):
        assert first_row not in rows.setdefault(level, {})
        rows[level][first_row] = (row_mins.copy(), row_maxs.copy())

    builder = OctreeBuilder(mins.shape, bins.dtype, sink)
    for first, slab_mins, slab_maxs in unit_cell_slabs(bins, planes):
        builder.add_slab(first, slab_mins, slab_maxs)
    seen = []
    for level in sorted(rows, reverse=True):
        seen.append(level)
        size = octree_levels(mins.shape)[level - 1]
        batches = sorted(rows[level].items())
        # Consecutive batches of rows from row 0, each handed on once.
        assert [first for first, _ in batches] == list(np.cumsum([0] + [len(m) for _, (m, _) in batches[:-1]]))
        level_mins, level_maxs = (np.concatenate([batch[k] for _, batch in batches]) for k in (0, 1))
        assert level_mins.shape == builder.tiles(level)
        for index in itertools.product(*(range(n) for n in level_mins.shape)):
            expected = direct_block_intervals(bins, size, index)
            assert (level_mins[index], level_maxs[index]) == expected, (level, index)
    assert seen == list(range(len(octree_levels(mins.shape)) - 1, 0, -1))


@pytest.mark.parametrize("crossing,normalization", RULES)
def test_fast_path_equals_reference_across_slab_boundaries(crossing, normalization, monkeypatch):
    """Slabs of one, two or three planes (odd steps against the octree's even ones) change nothing."""
    rng = np.random.default_rng(17)
    shapes = [(13, 6, 7), (16, 5, 4), (9, 17, 3), (30, 3, 3)]
    volumes = [(random_volume(rng, shape, 19, "sorted"), shape) for shape in shapes]
    for cells_per_slab in (1, 20, 50):
        monkeypatch.setattr(stream, "_SLAB_CELLS", cells_per_slab)
        for bins, shape in volumes:
            n_levels = len(octree_levels(tuple(s - 1 for s in shape)))
            for levels in (1, n_levels // 2 + 1, n_levels):
                fast = similarity_matrix(bins, 19, crossing=crossing, normalization=normalization, levels=levels)
                slow = reference_similarity_matrix(bins, 19, crossing, normalization, levels)
                np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12, err_msg=f"{shape} {cells_per_slab}")


def test_overlap_counts_from_histogram_match_brute_force():
    rng = np.random.default_rng(5)
    mins = rng.integers(0, 12, 500)
    maxs = np.minimum(mins + rng.integers(0, 6, 500), 11)
    histogram = joint_interval_histogram(mins, maxs, 12)
    assert histogram.sum() == 500
    for crossing in ("inclusive", "strict"):
        counts = overlap_counts(histogram, crossing)
        mu = np.arange(12)
        if crossing == "inclusive":
            crossed = (mins[:, None] <= mu) & (mu <= maxs[:, None])
        else:
            crossed = (mins[:, None] < mu) & (mu < maxs[:, None])
        np.testing.assert_array_equal(counts, crossed.T.astype(int) @ crossed.astype(int))


def band_volume(band_values, shape=(16, 16, 16), seed=0):
    """Thesis test image: flat bands of a few values along one axis (a 'two-value' or 'four-value' image)."""
    volume = np.empty(shape, dtype=np.int64)
    edges = np.linspace(0, shape[0], len(band_values) + 1).astype(int)
    for value, (a, b) in zip(band_values, zip(edges[:-1], edges[1:])):
        volume[a:b] = value
    return volume


@pytest.mark.parametrize("crossing", ["inclusive", "strict"])
@pytest.mark.parametrize("values", [(0, 31), (0, 10, 20, 31)])
def test_band_images_give_identical_rows_within_each_band(crossing, values):
    n_bins = 32
    bins = band_volume(values)
    result = isovalue_similarity(bins, n_bins, crossing=crossing)
    s = result.matrix
    # Isovalues strictly between two neighbouring band values cross exactly the same cells at every level.
    for low, high in zip(values[:-1], values[1:]):
        band = list(range(low + 1, high))
        for i in band:
            np.testing.assert_array_equal(s[i], s[band[0]])
    # Isovalues in different bands cross different cells at the finest level: they are not identical.
    if len(values) > 2:
        assert not np.array_equal(s[values[0] + 1], s[values[1] + 1])


@pytest.mark.parametrize("values", [(0, 31), (0, 10, 20, 31)])
def test_band_images_cluster_into_one_class_per_band(values):
    from IsoSimilarityTFLib import design_transfer_function

    design = design_transfer_function(band_volume(values), n_bins=32, value_range=(0, 32))
    labels = design.labels
    assert design.clustering["converged"]
    for low, high in zip(values[:-1], values[1:]):
        assert len(set(labels[low + 1 : high])) == 1
    bands = [labels[low + 1] for low, high in zip(values[:-1], values[1:])]
    assert len(set(bands)) == len(bands)


def test_similarity_properties_on_a_structured_volume():
    grid = np.indices((20, 17, 15)).astype(float)
    r = np.sqrt(((grid - 8) ** 2).sum(axis=0))
    bins = np.clip(r * 2, 0, 63).astype(np.int64)
    for crossing, normalization in RULES:
        s = similarity_matrix(bins, 64, crossing=crossing, normalization=normalization)
        assert np.all((s >= 0) & (s <= 1 + 1e-12))
        np.testing.assert_array_equal(s, s.T)
    inclusive = isovalue_similarity(bins, 64)
    # Every isovalue between the volume's min and max crosses some cell, so its self-similarity is 1.
    present = np.arange(bins.min(), bins.max() + 1)
    np.testing.assert_allclose(np.diag(inclusive.matrix)[present], 1.0)
    assert list(inclusive.empty_isovalues) == [b for b in range(64) if not bins.min() <= b <= bins.max()]
    np.testing.assert_allclose(inclusive.weights.sum(), 1.0)
    assert inclusive.level_sizes[0] == (19, 16, 14) and inclusive.level_sizes[-1] == (1, 1, 1)


def test_strict_crossing_leaves_the_extremes_empty():
    bins = np.zeros((4, 4, 4), dtype=np.uint8)
    bins[2:] = 5
    result = isovalue_similarity(bins, 8, crossing="strict")
    assert list(result.empty_isovalues) == [0, 5, 6, 7]


class Stop(Exception):
    pass


def test_progress_is_reported_per_level_and_can_abort():
    bins = np.random.default_rng(0).integers(0, 16, (9, 9, 9))
    seen = []
    similarity_matrix(bins, 16, progress=lambda fraction, message: seen.append((fraction, message)))
    fractions = [fraction for fraction, _ in seen]
    assert fractions == sorted(fractions) and fractions[-1] == pytest.approx(1.0)
    # One report per level after the unit cells (9^3 voxels: 4 levels).
    assert [message for _, message in seen] == [f"similarity: level {level} of 4" for level in (3, 2, 1)]

    def stop(fraction, message):
        raise Stop

    with pytest.raises(Stop):
        similarity_matrix(bins, 16, progress=stop)


def test_progress_during_the_unit_cell_pass_can_cancel_it(monkeypatch):
    """A long pass over the unit cells reports as it goes, so cancelling does not wait for its end."""
    monkeypatch.setattr(stream, "_PROGRESS_CELLS", 100)
    monkeypatch.setattr(stream, "_SLAB_CELLS", 100)
    bins = np.random.default_rng(0).integers(0, 16, (30, 11, 11))
    seen = []

    def stop_early(fraction, message):
        seen.append((fraction, message))
        raise Stop

    with pytest.raises(Stop):
        similarity_matrix(bins, 16, progress=stop_early)
    # Stopped after the first plane of 10 x 10 unit cells, of 29 planes.
    [(fraction, message)] = seen
    assert message == "similarity: unit cells" and 0 < fraction < 1 / 29


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"crossing": "loose"}, "crossing"),
        ({"normalization": "max"}, "normalization"),
        ({"levels": 0}, "levels"),
        ({"levels": 99}, "levels"),
    ],
)
def test_bad_options_are_rejected(kwargs, message):
    bins = np.zeros((3, 3, 3), dtype=np.uint8)
    with pytest.raises(ValueError, match=message):
        similarity_matrix(bins, 4, **kwargs)


def test_bad_bins_are_rejected():
    with pytest.raises(ValueError, match="3-D"):
        similarity_matrix(np.zeros((3, 3), dtype=np.uint8), 4)
    with pytest.raises(ValueError, match="integers"):
        similarity_matrix(np.zeros((3, 3, 3)), 4)
    with pytest.raises(ValueError, match=r"\[0, 4\)"):
        similarity_matrix(np.full((3, 3, 3), 4, dtype=np.uint8), 4)


def test_uint16_bins_for_many_isovalues():
    rng = np.random.default_rng(11)
    bins = np.sort(rng.integers(0, 1000, (5, 6, 7)), axis=0).astype(np.uint16)
    fast = similarity_matrix(bins, 1000)
    bins_used = np.unique(bins)
    slow = reference_similarity_matrix(bins, 1000)
    np.testing.assert_allclose(fast[np.ix_(bins_used, bins_used)], slow[np.ix_(bins_used, bins_used)], atol=1e-12)
    np.testing.assert_allclose(fast, slow, atol=1e-12)


def test_memory_is_checked_before_any_work(monkeypatch):
    """Before: numpy's MemoryError asking for 74.5 GiB, or the OOM killer."""
    from IsoSimilarityTFLib import memory
    from IsoSimilarityTFLib.errors import InsufficientMemoryError

    with pytest.raises(ValueError, match="n_bins must be an integer from 2 to 4096"):
        similarity_matrix(np.zeros((2, 2, 2), np.uint16), n_bins=100_000)
    monkeypatch.setattr(memory, "available_memory_bytes", lambda: 1 << 20)
    with pytest.raises(InsufficientMemoryError, match="4096 bins"):
        similarity_matrix(np.zeros((4, 4, 4), np.uint16), n_bins=4096)
