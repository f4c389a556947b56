"""The default value range of a volume, robust to padding and outliers: the range the isovalue bins cover.

Quantizing over a volume's minimum and maximum lets a few voxels decide every bin: one voxel at -1e30 squeezes the
whole head into the first bin (and the transfer function shows nothing), and CT padding outside the field of view
(-3024, -2048, -32768: a large constant block far below air) halves the bins left for tissue. This module finds
both and leaves them out of the default range; their voxels still count, in the first or last bin.
:func:`~.design.design_transfer_function` applies this rule (:func:`robust_value_range`) whoever calls it (Python,
the command line, the Slicer module), and an explicit range (``value_range``, ``--range``) overrides it.

- **Padding**: the volume's lowest (or highest) value holds at least :data:`PADDING_FRACTION` of the voxels (and
  at most :data:`PADDING_MAX_FRACTION`) and lies more than :data:`PADDING_GAP` of the value span away from the next
  value present, and the other values are a continuous scan (at least :data:`MIN_DISTINCT` distinct values), not a
  label map. A fill holding most of the volume is the background of a masked export (a vessel tree exported with
  95-99 % zeros), not padding around a scan: left in the range, it keeps its distance from the object's faint edges
  in bins, which the look measures (left out, it would share the first bin with them and take them for noise). MRI
  background at 0, with noise from 7 up, and CT air clamped at -1024 are not padding: their gap is small.
- **Outliers**: values more than :data:`OUTLIER_SPREADS` times the spread of the central values (0.1th to 99.9th
  percentile, padding left out) beyond them. CT metal at 3071 beside bone at 1500 is not an outlier.

Decisions come from the survey's strided sample (every s-th voxel, at most ``SAMPLE_VOXELS``, see :mod:`.survey`);
the range's ends and the counts of voxels left out are exact: from the survey's value histogram for integers of at
most 16 bits, else from one more pass, only when something is left out.
"""

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from .source import VolumeSource
from .survey import SAMPLE_VOXELS, Survey, beyond_float_sums, survey_volume

#: Least share of the voxels at one extreme value for it to be padding.
PADDING_FRACTION = 0.005
#: Largest share: a fill holding more of the voxels is a masked export's background (see the module notes).
PADDING_MAX_FRACTION = 0.5
#: Least gap, as a share of the value span, between a padding value and the next value present.
PADDING_GAP = 0.15
#: Least number of distinct values besides the padding for the volume to be a scan rather than a label map.
MIN_DISTINCT = 32
#: Spreads of the central values (0.1th to 99.9th percentile) beyond which a value is an outlier.
OUTLIER_SPREADS = 2.0
# Voxels compared at a time in the pass for the exact counts: a few of their boolean masks stay in cache.
_BLOCK_VOXELS = 1 << 16


@dataclass(frozen=True)
class RobustRange:
    """The default value range of a volume and what it leaves out.

    Attributes:
        value_range: ``(low, high)`` in volume units: the range to quantize over (the data range when nothing is
            left out).
        data_range: the volume's minimum and maximum.
        padding: the padding values left out (lowest and/or highest value), with their voxel counts.
        outliers_low, outliers_high: voxels below / above ``value_range`` left out as outliers (not padding).
    """

    value_range: tuple[float, float]
    data_range: tuple[float, float]
    padding: tuple[tuple[float, int], ...] = ()
    outliers_low: int = 0
    outliers_high: int = 0

    @property
    def excludes(self) -> bool:
        """Whether the range leaves anything out (then :meth:`warning` says what)."""
        return self.value_range != self.data_range

    def warning(self, override: str = "--range LOW HIGH") -> Optional[str]:
        """One line saying what the default range leaves out and how to choose another; None if nothing.

        Args:
            override: how the caller's user sets the range: ``"--range LOW HIGH"`` on the command line,
                ``"value_range=(low, high)"`` in Python, the name of the module's range setting in Slicer.
        """
        if not self.excludes:
            return None
        parts = [f"{count} padding voxels at {value:g}" for value, count in self.padding]
        if self.outliers_low:
            parts.append(f"{self.outliers_low} outlier voxel(s) from {self.data_range[0]:g}")
        if self.outliers_high:
            parts.append(f"{self.outliers_high} outlier voxel(s) up to {self.data_range[1]:g}")
        low, high = self.value_range
        return (
            f"the isovalue bins cover {low:g} to {high:g}, leaving out {' and '.join(parts)} (they fall in the "
            f"first or last bin); set {override} to choose the range yourself"
        )


@dataclass(frozen=True)
class _Counts:
    """Exact facts about the voxels the rules leave out: the least and greatest value strictly between ``above``
    and ``below``, how many voxels lie at or below ``above`` and at or above ``below``, and at each padding value."""

    low: float
    high: float
    below: int
    above: int
    padding: tuple[int, ...]


def _counts_from_histogram(survey: Survey, above: float, below: float, padding: list) -> _Counts:
    values, counts = survey.values(), survey.histogram
    present = counts > 0
    inside = present & (values > above) & (values < below)
    kept = values[inside]
    return _Counts(
        float(kept.min()) if kept.size else np.inf,  # nothing kept: no range (as the pass finds)
        float(kept.max()) if kept.size else -np.inf,
        int(counts[values <= above].sum()),
        int(counts[values >= below].sum()),
        tuple(int(counts[values == p].sum()) for p in padding),
    )


def _blocks(source: VolumeSource) -> Iterator[np.ndarray]:
    """The volume in flat blocks of about :data:`_BLOCK_VOXELS` voxels (whole rows), each small enough to stay in
    cache while several comparisons are made on it."""
    for _, slab in source.slabs():
        rows = slab.reshape(-1, slab.shape[-1])
        step = max(1, _BLOCK_VOXELS // rows.shape[1])
        for start in range(0, len(rows), step):
            yield rows[start : start + step]


def _counts_from_pass(source: VolumeSource, above: float, below: float, padding: list) -> _Counts:
    """:class:`_Counts` in one pass over the volume, a cache-sized block at a time, in its own dtype (a float64 copy
    would cost more than the pass). A side with no cut (``-inf`` or ``inf``) is not compared, and a padding value at
    a cut that is the volume's extreme is counted by that cut (every voxel at or beyond it holds it)."""
    dtype = source.dtype
    limits = np.iinfo(dtype) if np.issubdtype(dtype, np.integer) else np.finfo(dtype)
    low, high = limits.max, limits.min
    n_below = n_above = 0
    counted_apart = [value for value in padding if value not in (above, below)]
    at_padding = dict.fromkeys(counted_apart, 0)
    for block in _blocks(source):
        outside = None
        for cut, side in ((above, -1), (below, 1)):
            if np.isinf(cut):
                continue
            beyond = block <= cut if side < 0 else block >= cut
            count = int(np.count_nonzero(beyond))
            n_below, n_above = (n_below + count, n_above) if side < 0 else (n_below, n_above + count)
            outside = beyond if outside is None else np.logical_or(outside, beyond, out=outside)
        inside = block if outside is None else block[~outside]
        if inside.size:
            low, high = min(low, inside.min()), max(high, inside.max())
        for value in counted_apart:
            at_padding[value] += int(np.count_nonzero(block == value))
    counts = tuple(n_below if value == above else n_above if value == below else at_padding[value] for value in padding)
    return _Counts(float(low), float(high), n_below, n_above, counts)


def robust_value_range(
    values: Any, *, survey: Optional[Survey] = None, sample_voxels: int = SAMPLE_VOXELS
) -> RobustRange:
    """The default value range of a 3-D volume: its minimum and maximum, without padding and outliers.

    Args:
        values: the volume, shape ``(K, J, I)`` (any axis order), integers or floats: a numpy or dask array, or a
            :class:`~.source.VolumeSource`.
        survey: the volume's :func:`~.survey.survey_volume`, when already made (else it is made here).
        sample_voxels: voxels of the sample the decisions are taken on (when the survey is made here).

    Returns:
        A :class:`RobustRange`; its ``value_range`` is what ``quantize(values, value_range=...)`` should get, and
        its :meth:`RobustRange.warning` the one line to show when it leaves something out. A volume holding NaN or
        infinite values, or values beyond ``quantize.MAX_VALUE_MAGNITUDE`` (whose spreads overflow), is returned
        with its data range unchanged (the design refuses it, saying so).
    """
    source = values if isinstance(values, VolumeSource) else VolumeSource(values)
    if survey is None:
        survey = survey_volume(source, sample_voxels)
    low, high = survey.low, survey.high
    data_range = (float(low), float(high))
    if survey.nonfinite or beyond_float_sums(survey):
        return RobustRange(data_range, data_range)
    # Sorted in the volume's own dtype, then widened: the same order. Sorted values are the same whatever the
    # algorithm; numpy's fastest on 2M voxels here: radix (stable) for 8 bits, 8 ms, the default (a vectorized
    # quicksort) for wider types, 3-24 ms where a stable sort of floats takes 450 ms.
    sample = np.sort(survey.sample, kind="stable" if survey.sample.dtype.itemsize == 1 else None).astype(np.float64)
    if high <= low or sample.size < 2:
        return RobustRange(data_range, data_range)

    # Padding: a large constant block at either extreme, far from the next value present.
    keep_low, keep_high = 0, sample.size
    padding = []
    span = high - low
    for side in ("low", "high"):
        value = sample[keep_low] if side == "low" else sample[keep_high - 1]
        if value not in (low, high):
            continue  # the extreme the sample holds is not the volume's: too rare to be padding
        run = (
            np.searchsorted(sample, value, side="right") - keep_low
            if side == "low"
            else (keep_high - np.searchsorted(sample, value, side="left"))
        )
        rest = sample[keep_low + run : keep_high] if side == "low" else sample[keep_low : keep_high - run]
        if not PADDING_FRACTION * sample.size <= run <= PADDING_MAX_FRACTION * sample.size or rest.size == 0:
            continue
        gap = rest[0] - value if side == "low" else value - rest[-1]
        distinct = 1 + np.count_nonzero(rest[1:] != rest[:-1])  # the sample is sorted: no np.unique sort again
        if gap > PADDING_GAP * span and distinct >= MIN_DISTINCT:
            padding.append(value)
            keep_low, keep_high = (keep_low + run, keep_high) if side == "low" else (keep_low, keep_high - run)

    # Outliers: beyond the central values (padding left out) by more than OUTLIER_SPREADS spreads.
    core = sample[keep_low:keep_high]
    q_low, q_high = np.percentile(core, [0.1, 99.9], overwrite_input=True)  # the sample is ours, not needed after
    spread = q_high - q_low
    cut_low, cut_high = (
        (q_low - OUTLIER_SPREADS * spread, q_high + OUTLIER_SPREADS * spread) if spread > 0 else (-np.inf, np.inf)
    )
    above = max([cut_low, *[p for p in padding if p == low]], default=-np.inf)
    below = min([cut_high, *[p for p in padding if p == high]], default=np.inf)
    if above < low and below > high:
        return RobustRange(data_range, data_range)
    above = above if above >= low else -np.inf
    below = below if below <= high else np.inf
    if survey.histogram is not None:
        counts = _counts_from_histogram(survey, above, below, padding)
    else:
        counts = _counts_from_pass(source, above, below, padding)
    value_range = (counts.low, counts.high)
    if not value_range[0] < value_range[1]:
        return RobustRange(data_range, data_range)
    counted = tuple((float(p), c) for p, c in zip(padding, counts.padding))
    outliers_low = counts.below - sum(c for p, c in counted if p == low)
    outliers_high = counts.above - sum(c for p, c in counted if p == high)
    return RobustRange(value_range, data_range, counted, outliers_low, outliers_high)
