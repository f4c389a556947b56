"""The classes stage's counts equal the simple, obvious way of counting, on random small volumes."""

import numpy as np
import pytest

from IsoSimilarityTFLib import Quantization, classes


def reference_background_contact(bins, labels, background_id, step):
    """Every voxel's 6 neighbours read from a padded copy of the whole volume; planes 0, step, 2 step, ... counted."""
    labels = np.asarray(labels)
    voxel_classes = labels[bins]
    background = np.pad(voxel_classes == background_id, 1)
    near = background[1:-1, 1:-1, 1:-1].copy()
    for axis in range(3):
        for shift in (-1, 1):
            near |= np.roll(background, shift, axis=axis)[1:-1, 1:-1, 1:-1]
    measured, near = voxel_classes[::step].reshape(-1), near[::step].reshape(-1)
    n_classes = int(labels.max()) + 1
    totals = np.bincount(measured, minlength=n_classes)
    return np.bincount(measured[near], minlength=n_classes) / np.maximum(totals, 1)


def random_case(rng, n_bins, runs=True):
    shape = tuple(int(s) for s in rng.integers(2, 13, 3))
    smooth = np.cumsum(rng.integers(0, 3, shape), axis=int(rng.integers(0, 3)))  # regions, not just noise
    bins = (smooth * n_bins // (smooth.max() + 1)).astype(np.uint8 if n_bins <= 256 else np.uint16)
    n_classes = int(rng.integers(1, 9))
    labels = rng.integers(0, n_classes, n_bins)
    if runs:  # classes as runs of bins, as affinity propagation mostly gives; else scattered bins
        labels = np.sort(labels)
    labels = np.unique(labels, return_inverse=True)[1]  # ids 0..k-1, as affinity propagation gives
    return bins, labels, int(rng.integers(0, labels.max() + 1))


@pytest.mark.parametrize("runs", [True, False])
@pytest.mark.parametrize("sample_voxels", [1 << 22, 300, 60])
def test_background_contact_equals_reference(sample_voxels, runs, monkeypatch):
    """All planes (small volumes) or every k-th plane (large ones, here made small), any class count and background,
    classes as runs of bins (the background tested by comparisons) or scattered (by a table), with or without the
    volume's voxel counts."""
    monkeypatch.setattr(classes, "_CONTACT_SAMPLE_VOXELS", sample_voxels)
    rng = np.random.default_rng(sample_voxels)
    for _ in range(60):
        n_bins = int(rng.choice([7, 256, 300]))
        bins, labels, background_id = random_case(rng, n_bins, runs)
        step = max(1, bins.size // sample_voxels)
        expected = reference_background_contact(bins, labels, background_id, step)
        np.testing.assert_array_equal(classes.background_contact(bins, labels, background_id), expected)
        bin_voxels = np.bincount(bins.reshape(-1), minlength=n_bins)
        np.testing.assert_array_equal(classes.background_contact(bins, labels, background_id, bin_voxels), expected)


def test_background_contact_of_a_known_volume():
    bins = np.zeros((3, 5, 5), dtype=np.uint8)
    bins[:, 1:4, 1:4] = 1  # a bar of class 1 through a background of class 0: its 8-voxel rim touches it
    bins[1, 2, 2] = 2  # class 2 in the middle of the bar: every neighbour is class 1
    labels = np.array([0, 1, 2])
    np.testing.assert_array_equal(classes.background_contact(bins, labels, 0), [1.0, 24 / 26, 0.0])
    np.testing.assert_array_equal(classes.background_contact(bins, labels, 2), [0.0, 6 / 26, 1.0])


@pytest.mark.parametrize("n_bins,dtype", [(2, np.uint8), (37, np.uint8), (256, np.uint8), (1000, np.uint16)])
def test_voxel_counts_equal_bincount(n_bins, dtype):
    rng = np.random.default_rng(n_bins)
    for shape in [(2, 2, 2), (3, 5, 7), (9, 4, 11), (64, 65, 33)]:  # odd and even voxel counts, several chunks
        bins = rng.integers(0, n_bins, shape).astype(dtype)
        counts = Quantization(bins=bins, n_bins=n_bins, value_range=(0.0, 1.0)).voxel_counts()
        np.testing.assert_array_equal(counts, np.bincount(bins.reshape(-1), minlength=n_bins))
        assert counts.dtype == np.int64 and counts.shape == (n_bins,)
