"""Step 1 of the pipeline: map a scalar volume to ``n_bins`` isovalues, keeping the way back to its units."""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .options import MAX_BINS, OPTIONS
from .source import VolumeSource, validate_volume

# Voxels of a float volume binned at a time: their float64 copy (512 KB) stays in the core's cache.
_FLOAT_CHUNK = 1 << 16
# Integer volumes whose value span is at most this many values are quantized through a lookup table.
_MAX_LOOKUP_SPAN = 1 << 22
# Sampled values whose distinct values tell whether a float storage's values repeat (a lattice), and those checked
# to lie on it; within this many steps of it (float32 rounds a value of 10^4 to 10^-3).
_LATTICE_PROBE = 1 << 16
_LATTICE_CHECK = 1 << 18
_LATTICE_TOLERANCE = 0.01
# A float volume's extremes (the range's ends) lie within this many float32 ulps of their lattice values.
_RANGE_ULPS = 4
# Voxels looked up at once: small enough that the index array stays in cache.
_LOOKUP_CHUNK = 1 << 20
#: Largest magnitude of a value range: the design sums values weighted by voxel counts (up to 2^64) and takes their
#: differences in float64, which overflow beyond (every colour white, numpy's warnings on stderr).
MAX_VALUE_MAGNITUDE = float(np.finfo(np.float64).max) / 2.0**64
# Values counted per np.bincount call: their 64-bit copy (2 MB) stays in the core's cache, and each call's table
# (64K entries when counting voxel pairs) is small beside them.
_COUNT_CHUNK = 1 << 18


@dataclass(frozen=True)
class Quantization:
    """A volume quantized to isovalue bins.

    Bin ``b`` holds the values in ``[edges[b], edges[b + 1])`` (the last bin also holds ``value_range[1]``), in the
    units of the volume (HU for CT, raw units for MRI).

    Attributes:
        bins: integer array, same shape as the volume, values in ``[0, n_bins)``; uint8 when ``n_bins <= 256``,
            else uint16.
        n_bins: number of isovalues.
        value_range: ``(low, high)`` in volume units, the values mapped to the first and last bin edge.
    """

    bins: np.ndarray
    n_bins: int
    value_range: tuple[float, float]

    @property
    def bin_width(self) -> float:
        """Width of one bin in volume units."""
        low, high = self.value_range
        return (high - low) / self.n_bins

    @property
    def edges(self) -> np.ndarray:
        """Bin edges in volume units, shape ``(n_bins + 1,)``, strictly increasing."""
        low, high = self.value_range
        return np.linspace(low, high, self.n_bins + 1)

    @property
    def isovalues(self) -> np.ndarray:
        """Bin centres in volume units, shape ``(n_bins,)``: the isovalue each bin stands for."""
        edges = self.edges
        return 0.5 * (edges[:-1] + edges[1:])

    def voxel_counts(self) -> np.ndarray:
        """Number of voxels per bin, shape ``(n_bins,)`` int64 (the volume's histogram)."""
        return sum(count_bins(slab, self.n_bins) for _, slab in VolumeSource(self.bins).slabs())

    def value_to_bin(self, values: np.ndarray) -> np.ndarray:
        """Bin index of each value (values outside ``value_range`` go to the first or last bin)."""
        return _bin_index(np.asarray(values, dtype=np.float64), self.value_range, self.n_bins)


def count_bins(bins: np.ndarray, n_bins: int) -> np.ndarray:
    """Voxels per bin of a numpy array of bins, shape ``(n_bins,)`` int64, in cache-sized chunks (``np.bincount``
    makes a 64-bit copy of what it counts: never of the whole array)."""
    flat = np.ascontiguousarray(bins).reshape(-1)
    if flat.dtype != np.uint8:
        return chunked_bincount(flat, n_bins)
    # Two uint8 voxels read as one uint16 index: half as many to count. Each pair counts once for each of its
    # two bins, whichever byte order the machine has.
    pairs = chunked_bincount(flat[: flat.size // 2 * 2].view(np.uint16), 1 << 16).reshape(256, 256)
    counts = pairs.sum(axis=0) + pairs.sum(axis=1)
    counts[flat[-1]] += flat.size % 2
    return counts[:n_bins]


def chunked_bincount(flat: np.ndarray, length: int, chunk: int = _COUNT_CHUNK) -> np.ndarray:
    """``np.bincount`` of a 1-D integer array, ``length`` entries, counted ``chunk`` values at a time."""
    counts = np.zeros(length, dtype=np.int64)
    for start in range(0, flat.size, chunk):
        counts += np.bincount(flat[start : start + chunk], minlength=length)
    return counts


def _finite_range(values: np.ndarray, n_bins: int) -> tuple[float, float]:
    if np.issubdtype(values.dtype, np.floating):
        finite = np.isfinite(values)
        if not finite.all():
            raise ValueError(nonfinite_message(int(values.size - np.count_nonzero(finite))))
        return float(values.min()), float(values.max())
    low, high = int(values.min()), int(values.max())  # exact, whatever the magnitude
    check_integer_span(low, high, n_bins)
    return float(low), float(high)


def nonfinite_message(count: int) -> str:
    return f"the volume has {count} NaN or infinite voxels; replace or mask them first"


def check_integer_span(low: int, high: int, n_bins: int) -> None:
    """Refuse integers whose bins would be finer than float64 resolves at their magnitude: e.g. int64 values near
    2^62 would all fall in one bin (the bins and the transfer function are in float64 volume units), and the run
    would "succeed" with one class."""
    step = float(np.spacing(float(max(abs(low), abs(high)))))
    if high > low and (high - low) / n_bins < step:
        raise ValueError(
            f"the volume's integers span {high - low} around {float(high):.4g}, where float64 steps by {step:g}: "
            f"too fine for {n_bins} bins; subtract an offset first (e.g. values - values.min())"
        )


def bins_dtype(n_bins: int) -> np.dtype:
    """The integer type of the bins: uint8 up to 256 bins, else uint16."""
    return np.dtype(np.uint8 if n_bins <= 256 else np.uint16)


def checked_n_bins(n_bins) -> int:
    """``n_bins`` as an int, checked against its entry in the options table (2 to ``MAX_BINS``)."""

    return OPTIONS["n_bins"].check(n_bins)


def resolved_value_range(value_range, data_range: tuple[float, float]) -> tuple[float, float]:
    """The range to quantize over: the volume's own ``data_range`` when ``value_range`` is None (refused when the
    volume is constant), else ``value_range`` checked and refused when it misses ``data_range`` altogether."""

    if value_range is None:
        if data_range[0] == data_range[1]:
            raise ValueError(f"the volume is constant (every voxel is {data_range[0]:g}): there is nothing to classify")
        low, high = float(data_range[0]), float(data_range[1])
    else:
        low, high = OPTIONS["value_range"].check(value_range)
        if high < data_range[0] or low > data_range[1]:
            raise ValueError(
                f"value_range [{low:g}, {high:g}] lies outside the volume's values [{data_range[0]:g}, "
                f"{data_range[1]:g}]: every voxel would fall in one bin"
            )
    if max(-low, high) > MAX_VALUE_MAGNITUDE:
        raise ValueError(
            f"the value range [{low:g}, {high:g}] reaches beyond +-{MAX_VALUE_MAGNITUDE:.3g}, where float64 sums of "
            "values overflow: scale the values first (e.g. values * 1e-300)"
        )
    if (high - low) / MAX_BINS < np.finfo(np.float64).tiny:
        # Bins narrower than the smallest normal float64 (denormal values): the bin arithmetic overflows and every
        # voxel would land in a meaningless bin.
        raise ValueError(
            f"the value range [{low:g}, {high:g}] is too narrow for float64 bins (denormal values): scale the "
            "values first (e.g. values * 1e300)"
        )
    return low, high


def value_lattice(sample: np.ndarray) -> Optional[tuple[float, float]]:
    """``(origin, step)`` of the lattice a volume's values lie on, from a sample of them (any shape): the integers,
    ``(0, 1)``, for an integer dtype; for floats, the lattice of an integer storage scaled by a slope (a NIfTI
    ``scl_slope``, a DICOM rescale slope, a float copy of an 8-bit export), found where the sample's values repeat
    (:data:`_LATTICE_PROBE` of them, spread over the sample, hold at most a quarter as many distinct values) and
    :data:`_LATTICE_CHECK` values spread over it lie within :data:`_LATTICE_TOLERANCE` steps of the lattice the gaps
    between the distinct ones span. None otherwise: values that do not repeat (a float CT, a resampled volume) fill
    every bin evenly."""
    sample = np.asarray(sample).ravel()
    if np.issubdtype(sample.dtype, np.integer):
        return 0.0, 1.0
    probe = _spread(sample, _LATTICE_PROBE)
    distinct = np.unique(probe.astype(np.float64))
    if not 2 <= distinct.size <= probe.size // 4:
        return None
    # Each gap between distinct values is a whole number of steps; measured gap by gap, float32's rounding does not
    # add up, and the step is then the span over their sum.
    # Comparisons are NaN-safe (``all`` of ``<=``) and an overflow to inf fails them: no warning to the user.
    with np.errstate(over="ignore", invalid="ignore"):
        gaps = np.diff(distinct)
        multiples = gaps / gaps.min()
        steps = np.rint(multiples)
        # At most as many steps as binning through a lookup table takes.
        if not np.all(np.abs(multiples - steps) <= _LATTICE_TOLERANCE) or not steps.sum() < _MAX_LOOKUP_SPAN:
            return None
        origin, step = float(distinct[0]), float((distinct[-1] - distinct[0]) / steps.sum())
        checked = (_spread(sample, _LATTICE_CHECK).astype(np.float64) - origin) / step
        if not np.all(np.abs(checked - np.rint(checked)) <= _LATTICE_TOLERANCE):
            return None
    return origin, step


def values_per_bin(
    value_range: tuple[float, float],
    n_bins: int,
    lattice: tuple[float, float] = (0.0, 1.0),
    stored: Optional[np.ndarray] = None,
) -> Optional[np.ndarray]:
    """How many values of a storage's ``lattice`` (``(origin, step)``, :func:`value_lattice`; the integers by
    default) each bin holds, ``(n_bins,)`` int64, binned as :func:`bin_volume` bins them (the last bin holding its
    upper edge): the values the storage can put in each bin. They differ from bin to bin where the values do not
    divide evenly into the bins (301 values over 256 bins: 1 or 2 each; a uint16 MRI of values 0..300), and a
    histogram of such data is that pattern times the tissues' density. None beyond the span :func:`bin_volume` bins
    through a lookup table, where every bin holds thousands and they differ by one.

    ``stored``: values of the volume (a sample, any shape). For a float storage, a lattice value they hold lies where
    its stored value does: on a bin's edge (or the range's), float32 rounds it either way (``k * 0.13`` computed in
    float32 or in float64), and which way moves it to the next bin. A lattice value they do not hold is in the range
    within a few float32 ulps of its ends (a float volume's extremes, rounded). Integers are exact.
    """
    low, high = value_range
    origin, step = lattice
    floats = stored is not None and not np.issubdtype(np.asarray(stored).dtype, np.integer)
    slack = _RANGE_ULPS * float(np.finfo(np.float32).eps) * max(abs(low), abs(high)) if floats else 0.0
    with np.errstate(over="ignore", invalid="ignore"):
        first = np.ceil((low - slack - origin) / step)
        last = np.floor((high + slack - origin) / step)
        if not 0 <= last - first < _MAX_LOOKUP_SPAN:  # also False for an overflow to inf, or NaN
            return None
    # Not np.arange(first, ...): beyond 2^53 its float64 steps of one add nothing, and every value is the first.
    values = origin + step * (first + np.arange(last - first + 1, dtype=np.float64))
    bins = _bin_index(values, value_range, n_bins)
    in_range = np.ones(values.size, dtype=bool)
    if floats:
        seen = _spread(np.asarray(stored).ravel(), _LATTICE_CHECK).astype(np.float64)
        index = np.rint((seen - origin) / step) - first
        on_lattice = (index >= 0) & (index < values.size)
        index, seen = index[on_lattice].astype(np.int64), seen[on_lattice]
        bins[index] = _bin_index(seen, value_range, n_bins)
        in_range[index] = (seen >= low) & (seen <= high)
    return np.bincount(bins[in_range], minlength=n_bins)


def _spread(values: np.ndarray, count: int) -> np.ndarray:
    """``count`` to ``2 * count`` of ``values`` ``(n,)`` (all of them when fewer), evenly spaced over them: a volume's
    first planes may all be padding."""
    return values[:: max(1, values.size // count)]


def _bin_index(values: np.ndarray, value_range: tuple[float, float], n_bins: int) -> np.ndarray:
    return _bins_in_place(np.array(values, dtype=np.float64), value_range, n_bins).astype(np.int64)


def _bins_in_place(scaled: np.ndarray, value_range: tuple[float, float], n_bins: int) -> np.ndarray:
    """The bin of each float64 value, as floats, computed in ``scaled`` itself (no temporary per step)."""
    low, high = value_range
    scaled -= low
    scaled *= n_bins / (high - low)
    np.floor(scaled, out=scaled)
    return np.clip(scaled, 0, n_bins - 1, out=scaled)


def quantize(values: np.ndarray, n_bins: int = 256, value_range: Optional[tuple[float, float]] = None) -> Quantization:
    """Quantize a 3-D scalar volume to ``n_bins`` equal-width isovalue bins.

    Args:
        values: 3-D array of integers or floats, any axis order.
        n_bins: number of isovalues, 2 to 4096.
        value_range: ``(low, high)`` in volume units; default: the volume's minimum and maximum. Values outside it
            are clamped to the first or last bin.

    Raises:
        ValueError: on a volume that is not 3-D scalar, holds NaN/inf, is constant, or on a bad ``n_bins``/range.
    """
    values = validate_volume(values)
    n_bins = checked_n_bins(n_bins)
    data_range = _finite_range(values, n_bins)
    value_range = resolved_value_range(value_range, data_range)

    bins = bin_volume(values, n_bins, value_range, data_range)
    return Quantization(bins=bins, n_bins=n_bins, value_range=value_range)


def bin_volume(
    values: np.ndarray,
    n_bins: int,
    value_range: tuple[float, float],
    data_range: Optional[tuple[float, float]] = None,
) -> np.ndarray:
    """The isovalue bin of every voxel, unchecked: :func:`quantize` (or a chunk of a volume it checked) calls it.

    Args:
        values: 3-D array of integers or floats.
        n_bins: number of bins (2 to ``MAX_BINS``).
        value_range: ``(low, high)`` in volume units; values outside fall in the first or last bin.
        data_range: ``values``' own minimum and maximum, when already known.

    Returns:
        Bins, same shape as ``values``: uint8 up to 256 bins, else uint16.
    """
    out_dtype = bins_dtype(n_bins)
    bins = np.empty(values.shape, dtype=out_dtype)
    flat_in, flat_out = values.reshape(-1), bins.reshape(-1)
    if data_range is None:
        data_range = (float(values.min()), float(values.max()))
    span = data_range[1] - data_range[0]
    if np.issubdtype(values.dtype, np.integer) and values.dtype.itemsize <= 2:
        # Exact and fast: every possible 8/16-bit pattern is binned once, then looked up by the raw bits.
        raw_type = values.dtype.newbyteorder("=").str.replace("i", "u")
        raw = flat_in.view(values.dtype.str.replace("i", "u"))
        codes = np.arange(2 ** (8 * values.dtype.itemsize), dtype=raw_type).view(values.dtype.newbyteorder("="))
        table = _bin_index(codes.astype(np.float64), value_range, n_bins).astype(out_dtype)
        for start in range(0, flat_in.size, _LOOKUP_CHUNK):
            np.take(table, raw[start : start + _LOOKUP_CHUNK], out=flat_out[start : start + _LOOKUP_CHUNK])
    elif np.issubdtype(values.dtype, np.integer) and span < _MAX_LOOKUP_SPAN:
        # Likewise for wider integers whose values span few numbers: every value present is binned once, as the
        # float path bins it (float64 of the value). The table's values and indices are taken in the volume's own
        # integer type (exact at any magnitude: np.arange in float64 adds nothing beyond 2^53); data_range is
        # rounded to float64, so the table reaches one float64 spacing beyond it.
        dtype = values.dtype.newbyteorder("=")
        info = np.iinfo(dtype)
        pad = int(np.spacing(max(abs(data_range[0]), abs(data_range[1])))) + 1
        first, last = max(int(data_range[0]) - pad, info.min), min(int(data_range[1]) + pad, info.max)
        codes = np.arange(last - first + 1, dtype=dtype) + dtype.type(first)
        table = _bin_index(codes.astype(np.float64), value_range, n_bins).astype(out_dtype)
        for start in range(0, flat_in.size, _LOOKUP_CHUNK):
            chunk = (flat_in[start : start + _LOOKUP_CHUNK] - dtype.type(first)).astype(np.intp)
            np.take(table, chunk, out=flat_out[start : start + _LOOKUP_CHUNK])
    else:
        # Cast straight to the bins' type: 6-8x faster than through _bin_index's int64.
        for start in range(0, flat_in.size, _FLOAT_CHUNK):
            chunk = flat_in[start : start + _FLOAT_CHUNK].astype(np.float64)
            flat_out[start : start + _FLOAT_CHUNK] = _bins_in_place(chunk, value_range, n_bins)
    return bins
