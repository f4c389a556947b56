"""The default value range of a volume, robust to padding and outliers: the range the isovalue bins cover.

Quantizing over a volume's minimum and maximum lets a few voxels decide every bin: one voxel at -1e30 squeezes the
whole head into the first bin (and the transfer function shows nothing), and CT padding outside the field of view
(-3024, -2048, -32768: a large constant block far below air) halves the bins left for tissue. This module finds
both and leaves them out of the default range; their voxels still count, in the first or last bin. The command line
and the Slicer module call the same rule (:func:`robust_value_range`), and an explicit range (``--range``,
``value_range``) overrides it.

- **Padding**: the volume's lowest (or highest) value holds at least :data:`PADDING_FRACTION` of the voxels and lies
  more than :data:`PADDING_GAP` of the value span away from the next value present, and the other values are a
  continuous scan (at least :data:`MIN_DISTINCT` distinct values), not a label map. MRI background at 0, with noise
  from 7 up, and CT air clamped at -1024 are not padding: their gap is small.
- **Outliers**: values more than :data:`OUTLIER_SPREADS` times the spread of the central values (0.1th to 99.9th
  percentile, padding left out) beyond them. CT metal at 3071 beside bone at 1500 is not an outlier.

Decisions come from a strided sample (every s-th voxel, at most ``sample_voxels``); the range's ends and the counts
of voxels left out are exact, from full passes.
"""

from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from .chunked import is_dask_array
from .quantize import MAX_VALUE_MAGNITUDE

#: Least share of the voxels at one extreme value for it to be padding.
PADDING_FRACTION = 0.005
#: Least gap, as a share of the value span, between a padding value and the next value present.
PADDING_GAP = 0.15
#: Least number of distinct values besides the padding for the volume to be a scan rather than a label map.
MIN_DISTINCT = 32
#: Spreads of the central values (0.1th to 99.9th percentile) beyond which a value is an outlier.
OUTLIER_SPREADS = 2.0
#: Voxels of the sample the decisions are taken on.
SAMPLE_VOXELS = 1 << 21


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


def _sample(values: Any, sample_voxels: int) -> np.ndarray:
    """Every s-th voxel along each axis (at most ``sample_voxels``), in memory, as a flat float64 array."""
    step = max(1, int(np.ceil((float(np.prod(values.shape, dtype=np.float64)) / sample_voxels) ** (1 / 3))))
    sample = values[::step, ::step, ::step]
    sample = sample.compute() if is_dask_array(sample) else sample
    return np.asarray(sample, dtype=np.float64).reshape(-1)


def _min_max(values: Any, above: float = -np.inf, below: float = np.inf) -> tuple[float, float]:
    """Exact minimum and maximum of the voxels strictly between ``above`` and ``below`` (one pass, in the volume's
    own dtype: a float64 copy of a large volume would cost more than the pass)."""
    limits = np.iinfo(values.dtype) if np.issubdtype(values.dtype, np.integer) else np.finfo(values.dtype)
    if is_dask_array(values):
        import dask.array as da

        if above == -np.inf and below == np.inf:
            low, high = da.compute(values.min(), values.max())
        else:
            inside = (values > above) & (values < below)
            low, high = da.compute(
                da.where(inside, values, limits.max).min(), da.where(inside, values, limits.min).max()
            )
        return float(low), float(high)
    if above == -np.inf and below == np.inf:
        return float(np.min(values)), float(np.max(values))
    inside = (values > above) & (values < below)
    low = np.min(values, where=inside, initial=limits.max)
    return float(low), float(np.max(values, where=inside, initial=limits.min))


def _count(values: Any, mask_of: Any) -> int:
    count = np.count_nonzero(mask_of(values))
    return int(count.compute() if is_dask_array(values) else count)


def robust_value_range(values: Any, *, sample_voxels: int = SAMPLE_VOXELS) -> RobustRange:
    """The default value range of a 3-D volume: its minimum and maximum, without padding and outliers.

    Args:
        values: the volume, shape ``(K, J, I)`` (any axis order), integers or floats; a numpy or dask array.
        sample_voxels: voxels of the sample the decisions are taken on.

    Returns:
        A :class:`RobustRange`; its ``value_range`` is what ``quantize(values, value_range=...)`` should get, and
        its :meth:`RobustRange.warning` the one line to show when it leaves something out. A volume holding NaN or
        infinite values, or values beyond ``quantize.MAX_VALUE_MAGNITUDE`` (whose spreads overflow), is returned
        with its data range unchanged (the design refuses it, saying so).
    """
    if np.issubdtype(values.dtype, np.floating):
        if _count(values, lambda v: ~np.isfinite(v)):
            low, high = _min_max(values)
            return RobustRange((low, high), (low, high))
    low, high = _min_max(values)
    data_range = (low, high)
    if max(-low, high) > MAX_VALUE_MAGNITUDE:
        return RobustRange(data_range, data_range)
    sample = np.sort(_sample(values, sample_voxels))
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
        if run < PADDING_FRACTION * sample.size or rest.size == 0:
            continue
        gap = rest[0] - value if side == "low" else value - rest[-1]
        distinct = 1 + np.count_nonzero(rest[1:] != rest[:-1])  # the sample is sorted: no np.unique sort again
        if gap > PADDING_GAP * span and distinct >= MIN_DISTINCT:
            padding.append(value)
            keep_low, keep_high = (keep_low + run, keep_high) if side == "low" else (keep_low, keep_high - run)

    # Outliers: beyond the central values (padding left out) by more than OUTLIER_SPREADS spreads.
    core = sample[keep_low:keep_high]
    q_low, q_high = np.percentile(core, [0.1, 99.9])
    spread = q_high - q_low
    cut_low, cut_high = (
        (q_low - OUTLIER_SPREADS * spread, q_high + OUTLIER_SPREADS * spread) if spread > 0 else (-np.inf, np.inf)
    )
    above = max([cut_low, *[p for p in padding if p == low]], default=-np.inf)
    below = min([cut_high, *[p for p in padding if p == high]], default=np.inf)
    if above < low and below > high:
        return RobustRange(data_range, data_range)
    value_range = _min_max(values, above if above >= low else -np.inf, below if below <= high else np.inf)
    if not value_range[0] < value_range[1]:
        return RobustRange(data_range, data_range)
    counted = tuple((float(p), _count(values, lambda v, p=p: v == p)) for p in padding)
    outliers_low = _count(values, lambda v: v < value_range[0]) - sum(c for p, c in counted if p == low)
    outliers_high = _count(values, lambda v: v > value_range[1]) - sum(c for p, c in counted if p == high)
    return RobustRange(value_range, data_range, counted, outliers_low, outliers_high)


def with_robust_range(values: Any, options: dict, override: str) -> tuple[dict, Optional[str]]:
    """``options`` with the robust default range (:func:`robust_value_range`) unless they give a ``value_range``,
    and the one line saying what it leaves out (None when it leaves nothing out or a range is given).

    Args:
        override: how the caller's user sets the range (see :meth:`RobustRange.warning`).
    """
    if options.get("value_range") is not None:
        return options, None
    robust = robust_value_range(values)
    if not robust.excludes:
        return options, None
    return {**options, "value_range": robust.value_range}, robust.warning(override)
