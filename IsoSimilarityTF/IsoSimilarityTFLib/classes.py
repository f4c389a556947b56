"""Step 5 of the pipeline: turn isovalue clusters into ranked, coloured classes of voxels."""

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from .options import BACKGROUND_RULES

# Kelly's colours of maximum contrast (without white and black), so neighbouring classes stay distinguishable.
PALETTE: tuple[tuple[float, float, float], ...] = tuple(
    tuple(int(code[i : i + 2], 16) / 255.0 for i in (0, 2, 4))
    for code in (
        "F3C300", "875692", "F38400", "A1CAF1", "BE0032", "C2B280", "848482", "008856", "E68FAC", "0067A5",
        "F99379", "604E97", "F6A600", "B3446C", "DCD300", "882D17", "8DB600", "654522", "E25822", "2B3D26",
    )
)  # fmt: skip

# Voxels sampled (whole planes, evenly spaced) to measure background contact: enough for a share, and fast.
_CONTACT_SAMPLE_VOXELS = 1 << 22
# Voxels the noise is measured on (whole planes of the contact planes, evenly spaced): the median of half a million
# pairs varies by a few thousandths, and the measure costs 2-3 ms.
_NOISE_SAMPLE_VOXELS = 1 << 18
# Background runs tested by comparisons; more take a table lookup (see _background_test).
_MAX_COMPARED_RUNS = 4


@dataclass
class IsovalueClass:
    """One class of isovalues and the voxels it holds.

    Attributes:
        id: class id, 0 for the lowest exemplar isovalue, increasing with intensity.
        rank: 1 for the class with the most voxels, 2 for the next, ...
        voxels: number of voxels whose value falls in the class's isovalue bins.
        fraction: ``voxels`` over all voxels.
        isovalue_bins: the class's bins, ascending.
        value_ranges: ``[low, high]`` in volume units for each run of consecutive bins.
        exemplar_bin: the bin affinity propagation chose as the class's exemplar.
        color: ``[r, g, b]`` in 0..1.
        opacity: opacity in 0..1 when shown.
        visible: whether the class is shown.
        background: whether this is the background class (hidden by default).
    """

    id: int
    rank: int
    voxels: int
    fraction: float
    isovalue_bins: list[int]
    value_ranges: list[list[float]]
    exemplar_bin: int
    color: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])
    opacity: float = 1.0
    visible: bool = True
    background: bool = False
    background_contact: float = 0.0

    def to_dict(self) -> dict:
        return {
            "id": self.id,
            "rank": self.rank,
            "voxels": self.voxels,
            "fraction": self.fraction,
            "isovalue_bins": list(self.isovalue_bins),
            "value_ranges": [list(r) for r in self.value_ranges],
            "exemplar_bin": self.exemplar_bin,
            "color": list(self.color),
            "opacity": self.opacity,
            "visible": self.visible,
            "background": self.background,
            "background_contact": self.background_contact,
        }

    @classmethod
    def from_dict(cls, data: dict) -> "IsovalueClass":
        return cls(
            id=int(data["id"]),
            rank=int(data["rank"]),
            voxels=int(data["voxels"]),
            fraction=float(data["fraction"]),
            isovalue_bins=[int(b) for b in data["isovalue_bins"]],
            value_ranges=[[float(lo), float(hi)] for lo, hi in data["value_ranges"]],
            exemplar_bin=int(data["exemplar_bin"]),
            color=[_unit_number(c, "color") for c in data["color"]],
            opacity=_unit_number(data["opacity"], "opacity"),
            visible=_flag(data["visible"], "visible"),
            background=_flag(data["background"], "background"),
            background_contact=float(data.get("background_contact", 0.0)),
        )


def _flag(value: object, name: str) -> bool:
    """A JSON ``true`` or ``false`` (``bool("no")`` is True: a plausible wrong answer)."""
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be true or false; got {value!r}")
    return value


def _unit_number(value: object, name: str) -> float:
    """A number in [0, 1] (a colour component, an opacity); not a text or a flag, which ``float`` would take."""
    numeric = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    if not numeric or not 0.0 <= float(value) <= 1.0:
        raise ValueError(f"{name} must be a number in [0, 1]; got {value!r}")
    return float(value)


def runs(sorted_bins: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of consecutive integers, as ``(first, last)`` pairs."""
    sorted_bins = np.asarray(sorted_bins)
    if sorted_bins.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(sorted_bins) != 1)
    firsts = np.concatenate(([sorted_bins[0]], sorted_bins[breaks + 1]))
    lasts = np.concatenate((sorted_bins[breaks], [sorted_bins[-1]]))
    return [(int(a), int(b)) for a, b in zip(firsts, lasts)]


def mark_face_neighbours(mask: np.ndarray, out: np.ndarray) -> None:
    """Set ``out`` (bool, ``mask``'s shape, any number of axes) in place wherever a face neighbour is in ``mask``:
    the voxel before or after along any axis (the array's edges have none beyond them)."""
    for axis in range(mask.ndim):
        # Views along the axis: each voxel marked where the one before or after it is in the mask.
        near, inside = np.moveaxis(out, axis, 0), np.moveaxis(mask, axis, 0)
        near[1:] |= inside[:-1]
        near[:-1] |= inside[1:]


def background_contact(
    bins: np.ndarray, labels: np.ndarray, background_id: int, bin_voxels: Optional[np.ndarray] = None
) -> np.ndarray:
    """Share of each class's voxels that have a background voxel among their 6 neighbours.

    Args:
        bins: quantized volume, shape ``(n0, n1, n2)``: numpy, dask (only the planes measured are read), or anything
            with ``shape`` whose planes ``bins[k]`` can be read for the planes of :func:`contact_planes` and their
            neighbours (:class:`~.taps.SlabTap`'s kept planes).
        labels: ``(n_bins,)`` class id per bin.
        background_id: the background class.
        bin_voxels: ``(n_bins,)`` voxels per bin in the whole volume, if known: the class totals when every plane
            is measured (saves counting them again).

    Returns:
        ``(n_classes,)`` shares in [0, 1], measured on evenly spaced planes along axis 0 for large volumes; 0 for
        a class with no voxel in the planes measured (1 for the background if it has any).
    """
    labels = np.asarray(labels)
    n_bins, n_classes = labels.size, int(labels.max()) + 1
    planes = contact_planes(bins.shape)
    counted = bin_voxels is not None and planes.step == 1
    # Counted per bin, then summed per class: no class lookup per voxel. Only voxels outside the background that
    # touch it are counted (a thin shell); the background's own voxels all touch it.
    touching = np.zeros(n_bins, dtype=np.int64)
    totals = np.asarray(bin_voxels, dtype=np.int64) if counted else np.zeros(n_bins, dtype=np.int64)
    is_background = _background_test(labels == background_id)
    # Each plane's background is found once, and kept while it neighbours the planes measured.
    looked_up: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for plane in planes:
        window = range(max(plane - 1, 0), min(plane + 2, bins.shape[0]))
        looked_up = {k: looked_up[k] if k in looked_up else is_background(np.asarray(bins[k])) for k in window}
        plane_bins, in_plane = looked_up[plane]
        near = in_plane.copy()
        for k in window:  # the neighbours in the planes either side
            if k != plane:
                near |= looked_up[k][1]
        mark_face_neighbours(in_plane, near)
        near &= ~in_plane
        touching += np.bincount(plane_bins.reshape(-1)[np.flatnonzero(near)], minlength=n_bins)
        if not counted:
            totals += np.bincount(plane_bins.reshape(-1), minlength=n_bins)
    class_touching = np.bincount(labels, weights=touching, minlength=n_classes)
    class_totals = np.bincount(labels, weights=totals, minlength=n_classes)
    class_touching[background_id] = class_totals[background_id]
    return class_touching / np.maximum(class_totals, 1)


def _background_test(background_bins: np.ndarray) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """``plane -> (plane, is background)`` for a plane of bins, ``background_bins`` ``(n_bins,)`` bool.

    The background's bins are usually one run: two comparisons per voxel cost a tenth of a table lookup (whose
    indices numpy first widens to 64 bits).
    """
    background_runs = runs(np.flatnonzero(background_bins))
    if len(background_runs) > _MAX_COMPARED_RUNS:
        return lambda plane: (plane, np.take(background_bins, plane))

    def compared(plane: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        inside = np.zeros(plane.shape, dtype=bool)
        for first, last in background_runs:
            inside |= (plane >= first) & (plane <= last)
        return plane, inside

    return compared


def contact_planes(shape: tuple[int, int, int]) -> range:
    """The planes along axis 0 on which :func:`background_contact` measures a volume of ``shape`` voxels (it also reads
    their neighbours): evenly spaced, about ``_CONTACT_SAMPLE_VOXELS`` voxels in all."""
    step = max(1, int(np.prod(shape, dtype=np.float64)) // _CONTACT_SAMPLE_VOXELS)
    return range(0, shape[0], step)


def voxel_noise_sd(bins, foreground: np.ndarray) -> Optional[float]:
    """The noise of the voxels, in bins: ``1.4826 * median |a - b| / sqrt(2)`` over the pairs of neighbouring voxels
    ``a, b`` (along both axes of :func:`contact_planes` spread over the volume, not at its edges, about
    ``_NOISE_SAMPLE_VOXELS`` voxels: a central band of rows of a plane larger than that) that are both outside the
    background.

    Neighbours inside one tissue differ by noise alone, and the pairs across an edge are too few to move a median
    (Donoho & Johnstone's MAD: for independent Gaussian noise of width ``s``, ``a - b`` has width ``s * sqrt(2)``
    and median ``|a - b| = 0.6745 * s * sqrt(2)``). So, unlike the intensity model's width, it does not grow with a
    tissue's spread of values (grey and white matter in one tissue of a brain MRI: 23 bins of 256 for the model, 10
    for the voxels). A structure's own texture counts as noise.

    Args:
        bins: quantized volume ``(n0, n1, n2)``, or anything whose planes ``bins[k]`` of :func:`contact_planes` can be
            read (:class:`~.taps.SlabTap`'s kept planes).
        foreground: ``(n_bins,)`` whether a bin lies outside the background.

    Returns:
        The width in bins (at most about half a bin where most neighbours are equal: data stored in steps coarser
        than its noise), or None without a pair of foreground neighbours.
    """
    foreground = np.asarray(foreground, dtype=bool)
    counts = np.zeros(foreground.size, dtype=np.int64)  # pairs per absolute difference, in bins
    planes = contact_planes(bins.shape)
    n1, n2 = int(bins.shape[1]), int(bins.shape[2])
    # Planes at the middles of equal runs of the measured ones (the first and last planes are often air or padding),
    # and of a plane larger than the sample, the rows of its middle.
    n_planes = min(len(planes), max(1, round(_NOISE_SAMPLE_VOXELS / (n1 * n2))))
    chosen = [planes[int((k + 0.5) * len(planes) / n_planes)] for k in range(n_planes)]
    n_rows = min(n1, max(2, _NOISE_SAMPLE_VOXELS // max(n2, 1)))
    rows = slice((n1 - n_rows) // 2, (n1 - n_rows) // 2 + n_rows)
    signed = np.int16 if foreground.size <= np.iinfo(np.int16).max else np.int32
    for plane in chosen:
        values = np.asarray(bins[plane])[rows].astype(signed)
        inside = foreground[values]
        for ahead, behind in (((slice(1, None),), (slice(None, -1),)), ((..., slice(1, None)), (..., slice(None, -1)))):
            both = inside[ahead] & inside[behind]
            step = np.abs(values[ahead][both] - values[behind][both])
            counts += np.bincount(step, minlength=counts.size)
    total = int(counts.sum())
    if total == 0:
        return None
    # The median of the differences, read between whole bins: difference m stands for the true ones in
    # [m - 1/2, m + 1/2] (0 for [0, 1/2]), spread evenly (the grouped median), so the width does not jump by a bin.
    below = np.concatenate(([0], np.cumsum(counts)))
    m = int(np.searchsorted(below, total / 2, side="right")) - 1
    low, width = max(m - 0.5, 0.0), (1.0 if m else 0.5)
    median = low + width * (total / 2 - below[m]) / counts[m]
    return 1.4826 * median / np.sqrt(2)


def planes_read(shape: tuple[int, int, int]) -> list[int]:
    """Every plane :func:`background_contact` reads of a volume of ``shape`` voxels: the :func:`contact_planes` and
    their neighbours along axis 0."""
    return sorted({k + d for k in contact_planes(shape) for d in (-1, 0, 1) if 0 <= k + d < shape[0]})


def build_classes(
    labels: np.ndarray,
    exemplars: np.ndarray,
    bin_voxels: np.ndarray,
    edges: np.ndarray,
    *,
    background: str = "largest",
    bins: Optional[np.ndarray] = None,
) -> list[IsovalueClass]:
    """Rank classes by voxel count, pick the background, and measure each class's contact with it.

    The look (colour, opacity, visibility) is the design's (see :mod:`.look`).

    Args:
        labels: ``(n_bins,)`` class id per isovalue bin (ids ``0..n_classes-1``).
        exemplars: ``(n_classes,)`` exemplar bin per class id.
        bin_voxels: ``(n_bins,)`` number of voxels per bin (the volume's histogram).
        edges: ``(n_bins + 1,)`` bin edges in volume units.
        background: ``"largest"`` (the class with most voxels, thesis), ``"lowest"`` (the class of the lowest
            occupied bin) or ``"none"``.
        bins: the quantized volume; when given, each class's ``background_contact`` is measured on it.

    Returns:
        Classes in id order.
    """
    if background not in BACKGROUND_RULES:
        raise ValueError(f"background must be one of {BACKGROUND_RULES}; got {background!r}")
    labels = np.asarray(labels)
    n_classes = int(np.asarray(exemplars).size)
    voxels = np.bincount(labels, weights=bin_voxels, minlength=n_classes).astype(np.int64)
    total = int(np.sum(bin_voxels))
    # Rank by voxel count, ties broken by id so the order is deterministic.
    order = sorted(range(n_classes), key=lambda k: (-voxels[k], k))
    rank = {class_id: r + 1 for r, class_id in enumerate(order)}
    if background == "largest":
        background_id = order[0]
    elif background == "lowest":
        background_id = int(labels[np.flatnonzero(bin_voxels)[0]])
    else:
        background_id = None

    contact = np.zeros(n_classes)
    if bins is not None and background_id is not None:
        contact = background_contact(bins, labels, background_id, bin_voxels)
    classes = []
    for class_id in range(n_classes):
        members = np.flatnonzero(labels == class_id)
        classes.append(
            IsovalueClass(
                id=class_id,
                rank=rank[class_id],
                voxels=int(voxels[class_id]),
                fraction=voxels[class_id] / total if total else 0.0,
                isovalue_bins=[int(b) for b in members],
                value_ranges=[[float(edges[a]), float(edges[b + 1])] for a, b in runs(members)],
                exemplar_bin=int(exemplars[class_id]),
                background=class_id == background_id,
                background_contact=float(contact[class_id]) if class_id != background_id else 1.0,
            )
        )
    return classes
