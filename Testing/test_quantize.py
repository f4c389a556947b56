"""Quantization: exact bin mapping back to volume units, and clear errors on bad volumes."""

import numpy as np
import pytest

from IsoSimilarityTFLib import quantize
from IsoSimilarityTFLib.quantize import (
    _LATTICE_CHECK,
    _LATTICE_PROBE,
    _LATTICE_TOLERANCE,
    value_lattice,
    values_per_bin,
)


def test_uint8_with_256_bins_is_the_identity():
    values = np.arange(256, dtype=np.uint8).reshape(4, 8, 8)
    q = quantize(values)
    np.testing.assert_array_equal(q.bins, values)
    assert q.bins.dtype == np.uint8 and q.n_bins == 256 and q.value_range == (0.0, 255.0)


def test_bins_follow_the_edges_in_volume_units():
    rng = np.random.default_rng(0)
    values = rng.normal(40, 300, (6, 7, 8))
    q = quantize(values, 100)
    edges = q.edges
    assert edges.shape == (101,) and np.all(np.diff(edges) > 0)
    assert edges[0] == values.min() and edges[-1] == values.max()
    inside = values < values.max()
    # Each value lies in [edges[b], edges[b + 1]) of its bin; the maximum goes to the last bin.
    assert np.all(edges[q.bins[inside]] <= values[inside])
    assert np.all(values[inside] < edges[q.bins[inside] + 1])
    assert q.bins[values == values.max()].tolist() == [99]
    np.testing.assert_allclose(q.isovalues, 0.5 * (edges[:-1] + edges[1:]))
    np.testing.assert_array_equal(q.value_to_bin(values), q.bins)


@pytest.mark.parametrize("shape", [(9, 10, 11), (40, 50, 61)])  # the second spans several float chunks
def test_integer_lookup_path_equals_float_path(shape):
    rng = np.random.default_rng(1)
    values = rng.integers(-1024, 3072, shape).astype(np.int16)
    for n_bins in (7, 256, 1000, 4096):
        integer = quantize(values, n_bins).bins
        floating = quantize(values.astype(np.float64), n_bins).bins
        np.testing.assert_array_equal(integer, floating)
        np.testing.assert_array_equal(quantize(values.astype(np.float32), n_bins).bins, integer)
        assert integer.dtype == (np.uint8 if n_bins <= 256 else np.uint16)


@pytest.mark.parametrize(
    "dtype, first",
    [
        (np.int32, -(2**31)),
        (np.uint32, 2**32 - 70_000),
        (np.int64, 2**53),
        (np.int64, -(2**62)),
        (np.uint64, 2**64 - 65_536),
        (np.uint64, 2**63 - 1),  # float64 rounds its minimum up to 2^63: the table reaches a spacing beyond
    ],
)
def test_wide_integers_are_binned_as_their_float64_values_at_any_magnitude(dtype, first):
    # 2^53 and beyond, np.arange in float64 stepped by nothing: every voxel fell in one bin, and the design went on
    # with one class.
    values = (np.arange(65_536, dtype=np.uint64) + np.uint64(first % 2**64)).astype(dtype).reshape(16, 64, 64)
    integer = quantize(values, 7)
    np.testing.assert_array_equal(
        integer.bins, quantize(values.astype(np.float64), 7, value_range=integer.value_range).bins
    )
    assert integer.voxel_counts().min() > 0.8 * values.size / 7


@pytest.mark.parametrize(
    "value_range, n_bins",
    [
        ((0.0, 300.0), 256),
        ((0.0, 255.0), 256),
        ((-1024.0, 3071.0), 256),
        ((-3.5, 40.2), 7),
        ((2.0**53, 2.0**53 + 69), 7),  # float64 holds every other integer there: pairs share a value
    ],
)
def test_values_per_bin_counts_the_integers_the_binning_puts_in_each_bin(value_range, n_bins):
    low, high = value_range
    first, last = int(np.ceil(low)), int(np.floor(high))
    integers = np.tile(first + np.arange(last - first + 1, dtype=np.int64), (2, 2, 1))  # each integer 4 times
    binned = quantize(integers, n_bins, value_range=value_range).bins.ravel()
    np.testing.assert_array_equal(4 * values_per_bin(value_range, n_bins), np.bincount(binned, minlength=n_bins))


def test_values_per_bin_tells_where_integers_fill_bins_unevenly():
    assert sorted(set(values_per_bin((0.0, 300.0), 256).tolist())) == [1, 2]  # 301 values: 45 bins hold two
    assert set(values_per_bin((0.0, 255.0), 256).tolist()) == {1}
    assert values_per_bin((0.25, 0.75), 256) is None  # no integer in the range
    assert values_per_bin((0.0, 2.0**40), 256) is None  # beyond the lookup span every bin holds billions


@pytest.mark.parametrize(
    "slope, intercept", [(0.37, 11.0), (1.0, -1024.0), (0.001, 0.0), (2.5, -3000.0), (0.0123, 5.5)]
)
def test_a_float_copy_of_integers_keeps_their_lattice(slope, intercept):
    # 4001 integers read through a slope as float32 (a NIfTI scl_slope, a DICOM rescale slope): float32 rounds each
    # value, and a step measured between two neighbours alone misses the far end of the range by several steps.
    integers = np.random.default_rng(0).integers(0, 4001, 1 << 19)
    stored = (integers * slope + intercept).astype(np.float32)
    origin, step = value_lattice(stored)
    assert step == pytest.approx(slope, rel=1e-6)
    assert origin == pytest.approx(intercept + slope * integers.min(), abs=1e-3 * slope)
    scaled_range = (float(stored.min()), float(stored.max()))
    integer_range = (float(integers.min()), float(integers.max()))
    np.testing.assert_array_equal(values_per_bin(scaled_range, 256, (origin, step)), values_per_bin(integer_range, 256))


def test_the_ends_of_the_range_count_as_float32_rounds_them():
    # 0..255 through scl_slope 0.37, scl_inter 11: the top, 105.35, is 105.34999847 in float32, 254.99999 steps up,
    # and the sample holds no voxel of it.
    top = float(np.float32(11.0 + 0.37 * 255))
    sample = (np.arange(255) * 0.37 + 11.0).astype(np.float32)
    counted = values_per_bin((11.0, top), 256, (11.0, 0.37), sample)
    np.testing.assert_array_equal(counted, values_per_bin((0.0, 255.0), 256))


@pytest.mark.parametrize("value_range", [(0.005, 300.0), (0.0, 299.995)])
def test_integers_just_outside_a_given_range_are_not_counted(value_range):
    # A range the user gives, a two-hundredth inside the integers 0 and 300: 300 of them lie in it.
    assert values_per_bin(value_range, 256).sum() == 300


def test_values_that_do_not_repeat_or_lie_off_a_lattice_have_none():
    rng = np.random.default_rng(1)
    assert value_lattice(rng.normal(0.0, 1.0, 1 << 18).astype(np.float32)) is None  # a float CT, resampled data
    assert value_lattice(np.tile(np.float32([0.0, 1.0, 2.5, 2.7]), 1000)) is None  # gaps of 1, 1.5 and 0.2
    assert value_lattice(np.arange(10, dtype=np.uint8)) == (0.0, 1.0)  # an integer storage: the integers


@pytest.mark.filterwarnings("error")
def test_a_hostile_sample_has_no_lattice_and_no_warning():
    assert value_lattice(np.tile([np.nan, 1.0, 2.0], 100)) is None
    assert value_lattice(np.tile([0.0, 1.0, np.inf], 100)) is None
    assert value_lattice(np.tile([0.0, 5e-324, 1e-323, 1e289], 100)) is None  # gaps 5e-324 apart over 1e289: inf steps
    assert values_per_bin((0.0, 1e289), 256, (0.0, 5e-324)) is None


@pytest.mark.parametrize("distinct, found", [(0, True), (1, False)])
def test_a_lattice_is_found_where_the_probes_values_repeat_four_times(distinct, found):
    # The probe holds a quarter as many distinct values as voxels (each value four times): a lattice; one more
    # distinct value and the values do not repeat enough to tell a lattice from continuous data.
    count = _LATTICE_PROBE // 4 + distinct
    values = np.resize(np.arange(count, dtype=np.float32) * np.float32(0.5), _LATTICE_PROBE)
    assert (value_lattice(values) is not None) is found


@pytest.mark.parametrize("offset, found", [(0.9 * _LATTICE_TOLERANCE, True), (1.1 * _LATTICE_TOLERANCE, False)])
def test_every_checked_value_lies_on_the_lattice_within_the_tolerance(offset, found):
    # A value the probe did not see (it takes every fourth), `offset` steps off the lattice of the rest.
    values = np.random.default_rng(2).integers(0, 100, _LATTICE_CHECK).astype(np.float64)
    values[5] = 50.0 + offset
    assert (value_lattice(values) is not None) is found


def test_a_lattice_is_found_behind_padding():
    # A volume's first planes all one value (the intercept: padding), as many as the probe takes and more.
    integers = np.random.default_rng(3).integers(0, 301, 1 << 21)
    integers[: 2 * _LATTICE_PROBE] = 0
    assert value_lattice((integers * 0.37 + 11.0).astype(np.float32)) == pytest.approx((11.0, 0.37))
    # ... and values off it that the probe (every 32nd of 2^21) skips, after the part a check of the first 2^18 values
    # would read, are seen by the check (every 8th)
    off = (integers * 0.37 + 11.0).astype(np.float32)
    off[_LATTICE_CHECK + 8 :: 32] += np.float32(0.1)
    assert value_lattice(off) is None


@pytest.mark.parametrize("n_bins", [7, 256, 4096])
@pytest.mark.parametrize("slope", [0.13, 0.37, -0.61, 1.7e-3, 250.0])
@pytest.mark.parametrize("inside", [False, True])
def test_values_per_bin_counts_the_stored_values_quantize_puts_in_each_bin(n_bins, slope, inside):
    # Integers 0..300 times a slope in float32 arithmetic, as a reader applies scl_slope: values on a bin edge are
    # rounded either way, and each must be counted in the bin quantize puts it in. `inside`: a range cutting into
    # the data, whose values beyond it are clamped into the end bins and are not the lattice's there.
    integers = np.random.default_rng(4).permutation(np.tile(np.arange(301), 8))
    stored = integers.astype(np.float32) * np.float32(slope)
    low, high = sorted((float(stored.min()), float(stored.max())))
    # Inside: ends between two values (one on a value is clamped or not as float32 rounds it).
    value_range = (low + 0.1013 * (high - low), high - 0.1013 * (high - low)) if inside else (low, high)
    distinct = np.unique(stored).astype(np.float64)
    distinct = distinct[(distinct >= value_range[0]) & (distinct <= value_range[1])]
    binned = quantize(np.tile(distinct, (2, 2, 1)), n_bins, value_range=value_range).bins.ravel()  # each 4 times
    counted = values_per_bin(value_range, n_bins, value_lattice(stored), stored)
    np.testing.assert_array_equal(4 * counted, np.bincount(binned, minlength=n_bins))


def test_given_range_clamps_outside_values():
    values = np.linspace(-10, 110, 2 * 3 * 20).reshape(2, 3, 20)
    q = quantize(values, 10, value_range=(0, 100))
    assert q.value_range == (0.0, 100.0)
    assert q.bins[values < 0].max() == 0 and q.bins[values >= 100].min() == 9
    # A range may be given for a constant volume (e.g. a blank region of a larger series).
    assert quantize(np.zeros((2, 2, 2)), 4, value_range=(-1, 1)).bins.max() == 2


def test_non_contiguous_and_big_endian_volumes():
    values = np.arange(5 * 6 * 7, dtype=">i4").reshape(5, 6, 7)
    expected = quantize(values.astype(np.int32), 16).bins
    np.testing.assert_array_equal(quantize(values, 16).bins, expected)
    np.testing.assert_array_equal(quantize(values.transpose(2, 0, 1), 16).bins, expected.transpose(2, 0, 1))


@pytest.mark.parametrize(
    "values,message",
    [
        (np.zeros((8, 8)), "3-D"),
        (np.zeros((2, 3, 4, 5)), "3-D"),
        (np.zeros((4, 4, 4, 3)), "components"),
        (np.zeros((4, 4, 1)), "at least 2 voxels"),
        (np.ones((4, 4, 4)), "constant"),
        (np.array([[[0.0, np.nan], [1, 2]], [[3, 4], [5, 6]]]), "NaN or infinite"),
        (np.array([[[0.0, np.inf], [1, 2]], [[3, 4], [5, 6]]]), "NaN or infinite"),
        (np.zeros((2, 2, 2), dtype=bool), "dtype"),
        (np.zeros((2, 2, 2), dtype=complex), "dtype"),
        (np.array([[["a", "b"], ["c", "d"]]] * 2), "dtype"),
    ],
)
def test_bad_volumes_are_rejected_clearly(values, message):
    with pytest.raises(ValueError, match=message):
        quantize(values)


@pytest.mark.parametrize("n_bins", [1, 0, 4097, 2.5, True, "256"])
def test_bad_bin_counts_are_rejected(n_bins):
    with pytest.raises(ValueError, match="n_bins"):
        quantize(np.arange(8).reshape(2, 2, 2), n_bins)


@pytest.mark.parametrize("value_range", [(5, 5), (5, 1), (0, np.inf), (np.nan, 1)])
def test_bad_ranges_are_rejected(value_range):
    with pytest.raises(ValueError, match="value_range"):
        quantize(np.arange(8).reshape(2, 2, 2), 4, value_range=value_range)


def test_value_range_is_checked_against_the_table_and_the_data():
    values = np.arange(512, dtype=np.int16).reshape(8, 8, 8)
    with pytest.raises(ValueError, match=r"value_range must be two numbers"):  # before: "not enough values to unpack"
        quantize(values, value_range=(1,))
    with pytest.raises(ValueError, match=r"lies outside the volume's values \[0, 511\]"):  # before: one bin, exit 0
        quantize(values, value_range=(5000, 6000))
    assert quantize(values, value_range=(500, 6000)).value_range == (500.0, 6000.0)  # overlapping: fine


def test_huge_integers_are_quantized_exactly_or_refused():
    """int64 near 2^62: float64 steps by 1024 there, so 1000 distinct values would all fall in one bin."""
    base = np.int64(2**62)
    with pytest.raises(ValueError, match="subtract an offset"):
        quantize(base + np.arange(1000, dtype=np.int64).reshape(10, 10, 10))
    wide = base + np.arange(1000, dtype=np.int64).reshape(10, 10, 10) * 10**6  # bins far wider than the float step
    assert np.unique(quantize(wide).bins).size > 200


def test_masked_arrays_are_refused():
    """Before: the mask was silently ignored."""
    values = np.ma.masked_less(np.arange(512, dtype=np.int16).reshape(8, 8, 8), 100)
    with pytest.raises(ValueError, match="masked arrays are not supported"):
        quantize(values)


def test_denormal_values_are_refused_without_numpy_warnings() -> None:
    """Issue 18, item 14: denormal float64 volumes leaked numpy's overflow warnings and gave two meaningless
    classes. Now one clear error."""
    import warnings

    from isosimtf.phantom import head_phantom

    values = head_phantom(16, seed=0).values.astype(np.float64) * 1e-320
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"too narrow for float64 bins \(denormal values\): scale the values"):
            quantize(values)
