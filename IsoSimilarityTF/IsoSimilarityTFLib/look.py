"""The default look: colour and opacity of every class, chosen from its tissue and the kind of volume.

What Slicer's presets do, and why we do it too (the presets are read to learn from, not copied):

* **Colours along one ramp** ordered by intensity, dark red -> tan -> ivory -> white, placed by mean value between
  the lowest shown tissue and the densest real one: one colour per tissue, so neighbouring classes never read as
  rainbow rings ("wood grain"); on CT, where values are densities, each class at its own mean HU, continuous as in
  the CT presets. The qualitative palette stays available (``colors="distinct"``).
* **Opacity per millimetre**: the scalar opacity unit distance is 1 mm whatever the voxel spacing (presets leave
  VTK's default of 1 world unit, a millimetre in Slicer), so a 0.5 mm volume is not twice as hazy.
* **Opacity by the kind of volume** (:func:`detect_kind`): CT values are Hounsfield units, so opacity follows a fixed
  curve of HU (soft tissue nearly clear, bone opaque, no veil); MRI and other uncalibrated scalars get a flat
  moderate ramp in intensity order that peaks at the main bright tissue (not the brightest one: on a T1 head the
  brightest tissue is scalp fat, which would hide the brain).

Gradient opacity (option ``gradient_opacity="auto"``; ``"off"`` by default) scales opacity by the local gradient: 0
where the value does not change, 1 from :func:`gradient_ramp_top` up, so homogeneous insides fade and boundaries stay.

Rules that hold for every kind: the background is hidden; a class most of whose voxels touch the background
(noise in the air, the partial-volume rim) is hidden; the densest real tissue (holding at least ``REAL_SHARE`` of
the non-background voxels) is always shown; a tiny class never gets more opacity than the nearest real class below
it, so a few voxels denser than bone never become the most opaque thing in the picture.
"""

from collections.abc import Sequence
from typing import Optional

import numpy as np

from .classes import PALETTE, IsovalueClass
from .options import COLOR_SCHEMES, GRADIENT_OPACITY, KINDS  # noqa: F401 (GRADIENT_OPACITY: still importable here)

# Tissue colour ramp, low to high intensity: dark red, tan, ivory, white (our own anchors, in 0..1).
RAMP = (
    (0.00, (0.50, 0.10, 0.06)),
    (0.40, (0.80, 0.50, 0.32)),
    (0.75, (0.94, 0.88, 0.74)),
    (1.00, (1.00, 1.00, 1.00)),
)
# CT opacity per mm against Hounsfield units: air and fat clear, soft tissue (0-100 HU) barely there, so it never
# veils the skull; trabecular bone translucent, cortical bone opaque.
CT_OPACITY = ((-200.0, 0.0), (100.0, 0.004), (200.0, 0.05), (400.0, 0.35), (800.0, 0.75), (1500.0, 0.85))
# Uncalibrated scalars: opacity per mm from the lowest shown tissue to the peak tissue, linear in their rank.
MR_LOW, MR_HIGH = 0.02, 0.5
# A tissue brighter than the peak (scalp fat on a T1 head) is shown but never emphasised.
MR_ABOVE_PEAK = 0.03
# The peak tissue holds at least this share of the non-background voxels (the brain, not 3 % of fat).
PEAK_SHARE = 0.15
# A class or tissue with at least this share of the non-background voxels is a real tissue, not stray voxels.
REAL_SHARE = 0.01
# A class most of whose voxels touch the background is noise in it or the rim around objects.
FRINGE_CONTACT = 0.5
BACKGROUND_GREY = [0.5, 0.5, 0.5]


def detect_kind(dtype: np.dtype, value_range: Sequence[float], modality: Optional[str] = None) -> str:
    """The kind of volume: ``"ct"``, ``"mr"`` (uncalibrated scalars) or ``"8bit"``.

    Rule: a modality given by the caller (from the file: DICOM Modality, a NIfTI intent, the user) wins: ``CT`` ->
    ``"ct"``, ``MR``/``MRI`` -> ``"mr"``. Otherwise data stored in 8 bits (``uint8``/``int8``, or any integers
    within 0..255) is ``"8bit"``; signed or floating data whose range reaches air in Hounsfield units (minimum at
    most -900) and bone (maximum at least 300) is ``"ct"``; anything else is ``"mr"``. ``"8bit"`` uses the
    uncalibrated opacity curve: 8 bits hold MRI templates, ultrasound and microscopy far more often than CT.
    """
    if modality is not None:
        normalized = str(modality).strip().lower()
        if normalized == "ct":
            return "ct"
        if normalized in ("mr", "mri"):
            return "mr"
        if normalized in KINDS:
            return normalized
        raise ValueError(f"modality must be CT, MR or one of {KINDS}; got {modality!r}")
    dtype = np.dtype(dtype)
    low, high = float(value_range[0]), float(value_range[1])
    if dtype.itemsize == 1 or (dtype.kind in "iu" and low >= 0 and high <= 255):
        return "8bit"
    if dtype.kind in "if" and low <= -900 and high >= 300:
        return "ct"
    return "mr"


def ramp_colors(places: np.ndarray) -> np.ndarray:
    """``(n, 3)`` RGB along :data:`RAMP` at ``places`` ``(n,)`` in [0, 1]."""
    places = np.clip(np.asarray(places, dtype=np.float64), 0.0, 1.0)
    stops = np.array([p for p, _ in RAMP])
    rgb = np.array([c for _, c in RAMP])
    return np.stack([np.interp(places, stops, rgb[:, k]) for k in range(3)], axis=-1)


def class_mean_values(labels: np.ndarray, bin_voxels: np.ndarray, edges: np.ndarray, n_classes: int) -> np.ndarray:
    """``(n_classes,)`` voxel-weighted mean value of each class, in volume units (bin centres; exemplar centre for
    an empty class is not needed: an empty class gets the mean of its bins)."""
    centres = 0.5 * (edges[:-1] + edges[1:])
    voxels = np.bincount(labels, weights=bin_voxels, minlength=n_classes)
    weighted = np.bincount(labels, weights=bin_voxels * centres, minlength=n_classes)
    plain = np.bincount(labels, weights=centres, minlength=n_classes) / np.maximum(
        np.bincount(labels, minlength=n_classes), 1
    )
    return np.where(voxels > 0, weighted / np.maximum(voxels, 1e-300), plain)


def default_look(
    classes: list[IsovalueClass],
    tissue_of_class: np.ndarray,
    class_values: np.ndarray,
    kind: str,
    *,
    colors: str = "ramp",
    max_shown: int = 15,
) -> tuple[list[list[float]], list[float], list[bool]]:
    """Colour, opacity and visibility of every class.

    Args:
        classes: the classes, in id order (``background`` and ``background_contact`` are read).
        tissue_of_class: ``(n_classes,)`` tissue id per class; tissue ids increase with intensity.
        class_values: ``(n_classes,)`` mean value of each class in volume units (Hounsfield units for CT).
        kind: one of :data:`KINDS`.
        colors: ``"ramp"`` (one ramp colour per tissue) or ``"distinct"`` (one palette colour per tissue, by size).
        max_shown: at most this many tissues are shown, the largest first (the densest real one always).

    Returns:
        ``(colors, opacities, visible)``, one entry per class; opacity is per mm.
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}; got {kind!r}")
    if colors not in COLOR_SCHEMES:
        raise ValueError(f"colors must be one of {COLOR_SCHEMES}; got {colors!r}")
    tissue_of_class = np.asarray(tissue_of_class)
    class_values = np.asarray(class_values, dtype=np.float64)
    n_tissues = int(tissue_of_class.max()) + 1 if tissue_of_class.size else 0
    voxels = np.array([c.voxels for c in classes], dtype=np.float64)
    contact = np.array([c.background_contact for c in classes])
    is_background = np.array([c.background for c in classes])
    tissue_voxels = np.bincount(tissue_of_class, weights=voxels, minlength=n_tissues)
    tissue_contact = np.bincount(tissue_of_class, weights=voxels * contact, minlength=n_tissues) / np.maximum(
        tissue_voxels, 1
    )
    background_tissues = set(tissue_of_class[is_background].tolist())
    foreground = [t for t in range(n_tissues) if t not in background_tissues and tissue_voxels[t] > 0]
    total = float(sum(tissue_voxels[t] for t in foreground)) or 1.0
    share = tissue_voxels / total

    # Visible tissues: not on the background's fringe, the largest `max_shown`, and the densest real one always.
    inner = [t for t in foreground if tissue_contact[t] <= FRINGE_CONTACT] or foreground
    shown = set(sorted(inner, key=lambda t: (-tissue_voxels[t], t))[:max_shown])
    real = [t for t in foreground if share[t] >= REAL_SHARE]
    if real:
        shown.add(max(real))
    shown_sorted = sorted(shown)

    # Colours: one per tissue (per class on CT, see below).
    tissue_color = {t: list(BACKGROUND_GREY) for t in range(n_tissues)}
    class_color: dict[int, list[float]] = {}
    if colors == "ramp" and foreground:  # without a foreground (a single class, the background) nothing is coloured
        # A place on the ramp is a mean value between the lowest shown tissue's (dark red) and the densest real
        # tissue's (white), so the colour says how dense it is, as in the presets. On CT the value is a physical
        # density (HU) and the presets' colour follows it continuously, so each class takes the colour of its own
        # mean value: trabecular bone in the soft-tissue tissue is still ivory, cortical bone white. On uncalibrated
        # data one colour per tissue.
        tissue_value = np.bincount(tissue_of_class, weights=voxels * class_values, minlength=n_tissues) / np.maximum(
            tissue_voxels, 1
        )
        anchors = shown_sorted or foreground
        low = tissue_value[anchors[0]]
        high = tissue_value[max(real)] if real else tissue_value[anchors[-1]]

        def ramp_at(value: float) -> list[float]:
            place = (value - low) / (high - low) if high > low else 1.0
            return [float(v) for v in ramp_colors(np.array([place]))[0]]

        for t in foreground:
            tissue_color[t] = ramp_at(tissue_value[t])
        if kind == "ct":
            class_color = {c.id: ramp_at(class_values[c.id]) for c in classes if not c.background}
    elif colors == "distinct":
        for i, t in enumerate(sorted(foreground, key=lambda t: (-tissue_voxels[t], t))):
            tissue_color[t] = list(PALETTE[i % len(PALETTE)])

    # Opacity: per class for CT (a curve of HU), per tissue otherwise (a ramp in tissue order).
    opacity = np.zeros(len(classes))
    if kind == "ct":
        hu, alpha = zip(*CT_OPACITY)
        opacity = np.interp(class_values, hu, alpha)
    else:
        tissue_opacity = np.zeros(n_tissues)
        peaks = [t for t in shown_sorted if share[t] >= PEAK_SHARE] or shown_sorted
        peak = max(peaks) if peaks else 0
        below = [t for t in shown_sorted if t <= peak]
        for rank, t in enumerate(below):
            place = rank / (len(below) - 1) if len(below) > 1 else 1.0
            tissue_opacity[t] = MR_LOW + (MR_HIGH - MR_LOW) * place
        for t in foreground:
            if t > peak:
                tissue_opacity[t] = MR_ABOVE_PEAK
            elif t not in below:
                tissue_opacity[t] = MR_LOW
        opacity = tissue_opacity[tissue_of_class]
    opacity = _cap_tiny(opacity, voxels, is_background, class_values)
    opacity[is_background] = 0.0

    visible = [bool(tissue_of_class[c.id] in shown) and not c.background for c in classes]
    colors_out = [
        list(BACKGROUND_GREY) if c.background else class_color.get(c.id, tissue_color[tissue_of_class[c.id]])
        for c in classes
    ]
    return colors_out, [float(a) for a in opacity], visible


def _cap_tiny(opacity: np.ndarray, voxels: np.ndarray, is_background: np.ndarray, values: np.ndarray) -> np.ndarray:
    """A class below ``REAL_SHARE`` of the non-background voxels gets at most the opacity of the nearest real class
    below it in intensity (or the lowest real opacity when none is below)."""
    foreground = ~is_background
    total = float(voxels[foreground].sum()) or 1.0
    real = foreground & (voxels >= REAL_SHARE * total)
    if not real.any():
        return opacity.copy()
    capped = opacity.copy()
    real_ids = np.flatnonzero(real)
    for c in np.flatnonzero(foreground & ~real):
        lower = real_ids[values[real_ids] <= values[c]]
        ceiling = opacity[lower[np.argmax(values[lower])]] if lower.size else opacity[real_ids].min()
        capped[c] = min(opacity[c], ceiling)
    return capped


def gradient_ramp_top(tissue_values: Sequence[float], boundary_mm: float = 2.0) -> float:
    """Gradient magnitude (volume units per mm) from which gradient opacity is 1: a typical tissue boundary.

    Args:
        tissue_values: mean values of the shown tissues, in intensity order (volume units).
        boundary_mm: width over which a boundary between two tissues climbs (blur and partial volume).

    Returns:
        The median contrast between neighbouring shown tissues over ``boundary_mm``; 1 with fewer than 2 tissues.
    """
    contrasts = np.diff(np.sort(np.asarray(tissue_values, dtype=np.float64)))
    contrasts = contrasts[contrasts > 0]
    return float(np.median(contrasts)) / boundary_mm if contrasts.size else 1.0
