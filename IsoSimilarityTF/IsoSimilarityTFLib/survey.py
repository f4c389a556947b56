"""The survey: one pass over a volume for everything its value range is decided on, before it is quantized.

In one read of every slab (:meth:`.source.VolumeSource.slabs`): the number of NaN or infinite voxels, the minimum and
maximum, a strided sample (every s-th voxel along each axis) on which the padding and outlier rules decide
(:mod:`.value_range`), and for integer volumes of at most 16 bits read lazily the exact histogram of their values,
from which those rules take their exact counts without reading the volume again (in memory, a pass for the counts
costs less than the histogram: a few milliseconds against 30 on 192^3 int16).
"""

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from .quantize import MAX_VALUE_MAGNITUDE, check_integer_span, chunked_bincount, count_bins, nonfinite_message
from .source import VolumeSource

#: Voxels of the sample the value range's rules decide on.
SAMPLE_VOXELS = 1 << 21
# Values counted per np.bincount call into a 16-bit value histogram: its 65536 entries are worth a larger call.
_HISTOGRAM_CHUNK = 1 << 20


@dataclass(frozen=True)
class Survey:
    """What one pass over a volume found.

    Attributes:
        shape, dtype: the volume's.
        nonfinite: voxels that are NaN or infinite (a float volume's).
        low, high: the minimum and maximum, as Python numbers (exact for integers of any size); NaN when
            ``nonfinite``.
        sample: every :attr:`step`-th voxel along each axis, flat, in the volume's dtype and order.
        step: the sample's step.
        histogram: for integer volumes of at most 16 bits read lazily, ``(2 ** bits,)`` int64 voxels per value
            from :attr:`offset` up (else None).
        offset: the value of ``histogram[0]``.
    """

    shape: tuple[int, int, int]
    dtype: np.dtype
    nonfinite: int
    low: float
    high: float
    sample: np.ndarray
    step: int
    histogram: Optional[np.ndarray] = None
    offset: int = 0

    @property
    def data_range(self) -> tuple[float, float]:
        return float(self.low), float(self.high)

    def values(self) -> np.ndarray:
        """The values :attr:`histogram` counts, ``(2 ** bits,)`` int64."""
        return self.offset + np.arange(self.histogram.size, dtype=np.int64)


def sample_step(shape: tuple[int, ...], sample_voxels: int = SAMPLE_VOXELS) -> int:
    """The step of the strided sample of a volume: every s-th voxel along each axis, at most ``sample_voxels``."""
    return max(1, int(np.ceil((float(np.prod(shape, dtype=np.float64)) / sample_voxels) ** (1 / 3))))


def _small_integers(dtype: np.dtype) -> bool:
    return np.issubdtype(dtype, np.integer) and dtype.itemsize <= 2


def _value_histogram(slab: np.ndarray) -> np.ndarray:
    """Voxels per value of an integer slab of at most 16 bits, from the dtype's minimum up (a few planes at a time:
    a volume that is a strided view is never copied whole)."""
    native = slab.dtype.newbyteorder("=")
    codes = np.dtype(native.str.replace("i", "u"))
    length = 1 << (8 * native.itemsize)
    counts = np.zeros(length, dtype=np.int64)
    planes = max(1, _HISTOGRAM_CHUNK // max(1, slab[0].size))
    for k in range(0, len(slab), planes):
        raw = np.ascontiguousarray(slab[k : k + planes], dtype=native).reshape(-1).view(codes)
        counts += count_bins(raw, 256) if length == 256 else chunked_bincount(raw, length, _HISTOGRAM_CHUNK)
    if np.issubdtype(native, np.signedinteger):  # the codes of the negative values come last: put them first
        counts = np.roll(counts, length // 2)
    return counts


def survey_volume(
    source: VolumeSource,
    sample_voxels: int = SAMPLE_VOXELS,
    progress: Optional[Callable[[float], None]] = None,
    tap: Optional[Callable[[int, np.ndarray], None]] = None,
) -> Survey:
    """Survey a volume in one pass (see the module notes).

    Args:
        source: the volume.
        sample_voxels: voxels of the sample.
        progress: called as ``progress(fraction of the planes read)`` after each slab; raising from it aborts.
        tap: called as ``tap(first plane, slab)`` with every slab of the volume's values, in order along axis 0 (a
            caller's own use of the same read, e.g. a preview).
    """
    shape, dtype = source.shape, source.dtype
    step = sample_step(shape, sample_voxels)
    floating = np.issubdtype(dtype, np.floating)
    small = source.lazy and _small_integers(dtype)
    histogram = np.zeros(1 << (8 * dtype.itemsize), dtype=np.int64) if small else None
    nonfinite = 0
    low = high = None
    samples = []
    for first, slab in source.slabs():
        if tap is not None:
            tap(first, slab)
        # A copy: a strided view would keep the whole slab alive, and so every row of a dask volume (measured:
        # a 768^3 uint16 volume read lazily peaked at 1168 MB in the survey with views, 460 MB with copies).
        samples.append(slab[(-first) % step :: step, ::step, ::step].copy())
        if small:
            histogram += _value_histogram(slab)
        else:
            slab_low, slab_high = slab.min(), slab.max()
            if floating and not (np.isfinite(slab_low) and np.isfinite(slab_high)):  # NaN and infinities show there
                nonfinite += int(slab.size - np.count_nonzero(np.isfinite(slab)))
            low = slab_low if low is None else min(low, slab_low)
            high = slab_high if high is None else max(high, slab_high)
        if progress is not None:
            progress((first + len(slab)) / shape[0])
    offset = int(np.iinfo(dtype).min) if small else 0
    if small:
        present = np.flatnonzero(histogram)
        low, high = offset + int(present[0]), offset + int(present[-1])
    elif nonfinite:
        low = high = float("nan")
    else:
        low, high = low.item(), high.item()
    sample = np.concatenate([np.asarray(s).reshape(-1) for s in samples])
    return Survey(shape, dtype, nonfinite, low, high, sample, step, histogram, offset)


def checked_data_range(survey: Survey, n_bins: int) -> tuple[float, float]:
    """The volume's minimum and maximum, refused in one line when the volume cannot be quantized: NaN or infinite
    voxels, or integers spanning less than ``n_bins`` float64 steps at their magnitude."""
    if survey.nonfinite:
        raise ValueError(nonfinite_message(survey.nonfinite))
    if isinstance(survey.low, int):
        check_integer_span(survey.low, survey.high, n_bins)
    return survey.data_range


def beyond_float_sums(survey: Survey) -> bool:
    """Whether the volume's values reach past ``MAX_VALUE_MAGNITUDE`` (where float64 sums of values overflow)."""
    return max(-float(survey.low), float(survey.high)) > MAX_VALUE_MAGNITUDE
