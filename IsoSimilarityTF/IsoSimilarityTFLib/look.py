"""The default look: colour, opacity and visibility of every class, chosen from what the picture shows.

The opacity is *visibility-driven* (Ma & Entezari, TVCG 2018, sec. 6; Correa & Ma, TVCG 2011): the design is
rendered at low resolution (:mod:`.visibility`), each tissue's visibility is measured, and opacities are changed
until the picture shows what the data holds. Everything is computed from the isovalue bins, never from the values'
units, so a CT in Hounsfield units, the same CT as 16-bit stored values or as an 8-bit export, and a float copy get
the same tissues, the same opacities and the same picture.

1. **Which tissues are shown.** Not the background, not a tissue most of whose voxels touch it (noise in the air, the
   partial-volume rim) or whose largest class lies within :attr:`.LookRules.fog_separation` noise widths
   (:func:`.roles.fog_width`) above the background's (fog; its mean would follow its partial-volume tail down to the
   background); where a fog tissue also holds classes that are not fog (role ``"fog"``, :mod:`.roles`), those are a
   tissue of their own on the looks of data that are not CT-like (:func:`fog_apart`: the outer cortex of a
   skull-stripped brain, grouped with the dark partial volume below it); of the others, whole tissues, the largest
   first, while they hold at most ``max_classes`` classes; the
   densest real tissue always; and on data that are not CT-like, where a shown tissue fills the object (more than
   :attr:`.LookRules.fill_share` of the foreground's voxels; met first, it is the object's surface, see
   :meth:`_VisibilityStep.outer_surface`), every tissue lying between two shown ones, as every preset's ramp shows all
   values above its threshold (hidden, it would punch holes where the surface passes through its values: a head MRI's
   skin, between its grey matter and its fat).
2. **A monotone start**, as every Slicer preset: opacity per mm rises with intensity, from
   :attr:`.LookRules.opacity_low` for the lowest shown tissue to :attr:`.LookRules.opacity_high` for the densest,
   linear in their rank.
3. **An enclosing tissue never hides a distinct one inside it.** A *feature* is a real tissue
   (:attr:`.LookRules.real_share`) that stands apart from a lower tissue: their means differ by at least
   :attr:`.LookRules.dense_separation` noise widths of the intensity model (bone, contrast-filled vessels, a micro-CT's
   dense parts over soft tissue or a sample holder; not white matter over grey matter, whose histograms overlap).
   Rendered alone, a feature shows some light; rendered with the lower tissues it stands apart from, at least
   :attr:`.LookRules.seen` of that light must still reach the eye. Where it does not, those tissues are made clearer,
   by the factor the measured transmittance asks for (``T ** s = seen``), and the picture is rendered again: Ma &
   Entezari's loop, which raises the least visible feature until it is seen, turned round, since a feature is already
   at the top of the ramp. Other data than CT-like (MRI) show the tissue met first as a surface instead
   (:meth:`_VisibilityStep.outer_surface`).
4. **Soft boundaries** (:func:`ramped_opacity`): opacity climbs across a step between two bins over the noise width
   of the intensity model, on the side of the more opaque bin, so the voxel staircase of a coarse volume is not
   drawn as black contour lines and hidden bins stay hidden.

Colours follow one ramp ordered by intensity (dark red -> tan -> ivory -> white), placed by mean value between the
lowest shown tissue (at tan, :data:`SHOWN_PLACE`: no shown structure takes the dark end, which reads as a shadow)
and the densest real one: one colour per tissue, so neighbouring classes never read as rainbow
rings; on CT (``kind`` ``"ct"``) each class at its own mean, continuous as in the CT presets, and a dense class
(role ``"dense"``, :mod:`.roles`: bone, contrast, metal) from ivory up, as those presets draw them. White is kept for a
densest tissue that is a tail (at most :attr:`.LookRules.white_share` of the largest tissue's voxels: bone, contrast):
a large bright tissue (white matter) ends at ivory, or the headlight washes it out. The qualitative palette stays
available (``colors="distinct"``).

Gradient opacity (option ``gradient_opacity="auto"``; ``"off"`` by default) scales opacity by the local gradient: 0
where the value does not change, 1 from :func:`gradient_ramp_top` up, so homogeneous insides fade and boundaries stay.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from .classes import PALETTE, IsovalueClass
from .options import COLOR_SCHEMES, GRADIENT_OPACITY, KINDS  # noqa: F401 (GRADIENT_OPACITY: still importable here)
from .roles import RULES, LookRules, largest_class, tissue_mean_bins
from .visibility import Preview, enclosure, first_met, visibility_histogram

# Tissue colour ramp, low to high intensity: dark red, tan, ivory, white (in 0..1). The tan is MR-Default's colour
# at 120, where a T1 head's skin lies: a redder tan read as brown, and as colour noise wherever noise speckles a
# surface (make compare: colour noise fell on every volume with this one).
RAMP = (
    (0.00, (0.50, 0.10, 0.06)),
    (0.40, (0.78, 0.61, 0.38)),
    (0.75, (0.94, 0.88, 0.74)),
    (1.00, (1.00, 1.00, 1.00)),
)
#: Where the lowest shown tissue's colour lies: tan, the colour MR-Default gives a head's skin and CT-AAA the soft
#: parts it shows. Below it the ramp's dark red is left to nothing shown: a structure there reads as a shadow (the
#: small vessels of an angiogram, all skin, were drawn dark red at 0.3x the brightness of every preset).
SHOWN_PLACE = 0.4
#: Where a large bright tissue's colour ends: ivory (see the module notes).
IVORY_PLACE = 0.75
#: Rounds of the visibility step; each sets the clearing factor from the transmittance measured, so 4 suffice.
VISIBILITY_ROUNDS = 4
BACKGROUND_GREY = [0.5, 0.5, 0.5]


def detect_kind(
    tissue_means: Sequence[float],
    tissue_voxels: Sequence[float],
    noise_sd: float,
    modality: Optional[str] = None,
    encloses: Optional[Callable[[int, int], float]] = None,
    rules: LookRules = RULES,
) -> str:
    """The kind of volume: ``"ct"`` (a density scan) or ``"mr"`` (any other scalar), or the caller's hint.

    Rule: a modality given by the caller (from the file: DICOM Modality, a NIfTI intent, the user) wins: ``CT`` ->
    ``"ct"``, ``MR``/``MRI`` -> ``"mr"``, or a word of :data:`KINDS`. Otherwise the data decides, whatever its units
    and storage: a CT has air (the background), soft tissue (the largest tissue) and a dense tail enclosed by it: the
    tissues above the largest hold at most :attr:`.LookRules.tail_share` of its voxels, and one of them is real, lies
    :attr:`.LookRules.dense_separation` noise widths above the largest one and is met after it by most rays through
    both (bone inside the head; not the scalp fat of a T1, which lies around the brain).

    Args:
        tissue_means: mean bin of each non-background tissue, ascending.
        tissue_voxels: their voxel counts.
        noise_sd: the intensity model's noise width, in bins.
        modality: the caller's hint, or None.
        encloses: ``encloses(outer, inner)``: share of the rays through both tissues (indices into the lists) that
            meet ``outer`` first (:func:`.visibility.enclosure`); None skips that test.
        rules: the thresholds.
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
    return "ct" if dense_tail(tissue_means, tissue_voxels, noise_sd, encloses, rules) else "mr"


def dense_tail(
    tissue_means: Sequence[float],
    tissue_voxels: Sequence[float],
    noise_sd: float,
    encloses: Optional[Callable[[int, int], float]] = None,
    rules: LookRules = RULES,
) -> list[int]:
    """Indices of the tissues that form a CT's dense tail (see :func:`detect_kind`), ascending."""
    means = np.asarray(tissue_means, dtype=np.float64)
    voxels = np.asarray(tissue_voxels, dtype=np.float64)
    if means.size < 2:
        return []
    largest = int(np.argmax(voxels))
    if voxels[largest + 1 :].sum() > rules.tail_share * voxels[largest]:
        return []  # brighter tissues as large as the main one (white matter, a T1's fat and brain): no tail
    real = voxels >= rules.real_share * voxels.sum()
    candidates = np.flatnonzero(
        real & (means >= means[largest] + rules.dense_separation * noise_sd) & (voxels < voxels[largest])
    )
    return [int(t) for t in candidates if encloses is None or encloses(largest, int(t)) > 0.5]


def ramp_colors(places: np.ndarray) -> np.ndarray:
    """``(n, 3)`` RGB along :data:`RAMP` at ``places`` ``(n,)`` in [0, 1]."""
    places = np.clip(np.asarray(places, dtype=np.float64), 0.0, 1.0)
    stops = np.array([p for p, _ in RAMP])
    rgb = np.array([c for _, c in RAMP])
    return np.stack([np.interp(places, stops, rgb[:, k]) for k in range(3)], axis=-1)


def class_mean_values(labels: np.ndarray, bin_voxels: np.ndarray, edges: np.ndarray, n_classes: int) -> np.ndarray:
    """``(n_classes,)`` voxel-weighted mean value of each class, in the units of ``edges`` (bin centres; an empty
    class gets the plain mean of its bins). With ``edges = arange(n_bins + 1) - 0.5`` the unit is the bin."""
    centres = 0.5 * (edges[:-1] + edges[1:])
    voxels = np.bincount(labels, weights=bin_voxels, minlength=n_classes)
    weighted = np.bincount(labels, weights=bin_voxels * centres, minlength=n_classes)
    plain = np.bincount(labels, weights=centres, minlength=n_classes) / np.maximum(
        np.bincount(labels, minlength=n_classes), 1
    )
    return np.where(voxels > 0, weighted / np.maximum(voxels, 1e-300), plain)


def ramped_opacity(bin_opacity: np.ndarray, width_bins: float) -> np.ndarray:
    """``(n_bins,)`` opacity whose steps climb over ``width_bins`` bins instead of one.

    At each step between neighbouring bins the more opaque side takes a linear ramp from the other side's opacity up
    to its own over ``round(width_bins)`` bins (at most its run's length): a hidden bin stays hidden, a shown one
    never gets more opacity than it had.
    """
    opacity = np.asarray(bin_opacity, dtype=np.float64)
    width = int(round(width_bins))
    out = opacity.copy()
    if width < 2:
        return out
    for step in np.flatnonzero(opacity[1:] != opacity[:-1]) + 1:
        low, high = sorted((opacity[step - 1], opacity[step]))
        rising = opacity[step] > opacity[step - 1]
        for offset in range(width - 1):
            at = step + offset if rising else step - 1 - offset
            if not 0 <= at < opacity.size or opacity[at] != high:
                break
            out[at] = min(out[at], low + (high - low) * (offset + 1) / width)
    return out


def bin_opacity_of(class_opacity: np.ndarray, labels: np.ndarray, noise_sd: float) -> np.ndarray:
    """``(n_bins,)`` the transfer function's opacity per mm: each bin its class's ``class_opacity`` ``(n_classes,)``
    (0 for a class not shown), every step softened over the noise width in bins (:func:`ramped_opacity`). The
    design writes it and the visibility step renders it."""
    return ramped_opacity(np.asarray(class_opacity, dtype=np.float64)[np.asarray(labels)], noise_sd)


@dataclass(frozen=True)
class Look:
    """The default look of every class and what its picture shows.

    Attributes:
        colors: ``[r, g, b]`` per class, in 0..1.
        opacities: opacity per mm per class.
        visible: whether each class is shown.
        tissue_shares: ``(n_tissues,)`` share of the (low-resolution, six-view) picture each tissue gives, summing
            to 1 over the tissues, or None without a preview.
    """

    colors: list[list[float]]
    opacities: list[float]
    visible: list[bool]
    tissue_shares: Optional[np.ndarray] = None


def default_look(
    classes: list[IsovalueClass],
    tissue_of_class: np.ndarray,
    class_values: np.ndarray,
    kind: str,
    *,
    labels: Optional[np.ndarray] = None,
    class_bins: Optional[np.ndarray] = None,
    noise_sd: float = 1.0,
    fog_sd: Optional[float] = None,
    preview: Optional[Preview] = None,
    colors: str = "ramp",
    max_classes: int = 15,
    dense_classes: Optional[Sequence[bool]] = None,
    fog_classes: Optional[Sequence[bool]] = None,
    rules: LookRules = RULES,
) -> Look:
    """Colour, opacity and visibility of every class (see the module notes).

    Args:
        classes: the classes, in id order (``background``, ``voxels`` and ``background_contact`` are read).
        tissue_of_class: ``(n_classes,)`` tissue id per class; tissue ids increase with intensity.
        class_values: ``(n_classes,)`` mean value of each class in volume units (colours on CT).
        kind: one of :data:`KINDS` (colours only).
        labels: ``(n_bins,)`` class id per bin; needed with ``preview``.
        class_bins: ``(n_classes,)`` mean bin of each class (default: ``class_values``, when they are bins).
        noise_sd: the intensity model's noise width, in bins.
        fog_sd: the noise width fog is decided in, in bins: the data's (:func:`.roles.fog_width`; ``noise_sd`` if
            None). A look of another kind than the data's (the outer surface of a CT) keeps the data's.
        preview: the low-resolution volume the visibility step renders (None: the monotone start only).
        colors: ``"ramp"`` (one ramp colour per tissue) or ``"distinct"`` (one palette colour per tissue, by size).
        max_classes: tissues are shown whole, the largest first, while they hold at most this many classes (the
            densest real tissue always, besides them, and every tissue between two shown ones where a shown tissue
            fills the object on data that are not CT-like).
        dense_classes: ``(n_classes,)`` whether each class is dense (:func:`.roles.class_roles`); on CT their
            colours run from ivory (:data:`IVORY_PLACE`) up, by value among them. None: by the ramp alone.
        fog_classes: ``(n_classes,)`` whether each class is fog (:func:`.roles.class_roles`); on data that are not
            CT-like the other classes of their tissues are a tissue of their own (:func:`fog_apart`). None: whole
            tissues.
        rules: the thresholds.
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}; got {kind!r}")
    if colors not in COLOR_SCHEMES:
        raise ValueError(f"colors must be one of {COLOR_SCHEMES}; got {colors!r}")
    class_values = np.asarray(class_values, dtype=np.float64)
    class_bins = class_values if class_bins is None else np.asarray(class_bins, dtype=np.float64)
    voxels = np.array([c.voxels for c in classes], dtype=np.float64)
    contact = np.array([c.background_contact for c in classes])
    is_background = np.array([c.background for c in classes])
    tissue_of_class = fringe_cores_apart(np.asarray(tissue_of_class), contact, voxels, is_background, rules)
    if fog_classes is not None and kind != "ct":
        # On CT the soft tissue is cleared around the dense tail whole; a surface must not lose the classes above
        # the fog that the model grouped with it.
        tissue_of_class = fog_apart(tissue_of_class, np.asarray(fog_classes, dtype=bool))
    n_tissues = int(tissue_of_class.max()) + 1 if tissue_of_class.size else 0
    tissue_voxels = np.bincount(tissue_of_class, weights=voxels, minlength=n_tissues)
    tissue_contact = np.bincount(tissue_of_class, weights=voxels * contact, minlength=n_tissues) / np.maximum(
        tissue_voxels, 1
    )
    tissue_bin = tissue_mean_bins(tissue_of_class, voxels, class_bins, n_tissues)
    background_tissues = set(tissue_of_class[is_background].tolist())
    foreground = [t for t in range(n_tissues) if t not in background_tissues and tissue_voxels[t] > 0]
    total = float(sum(tissue_voxels[t] for t in foreground)) or 1.0
    share = tissue_voxels / total

    # 1. Visible tissues: not fog (on the background's fringe, or where its largest class lies no further above the
    # background's intensity than noise explains: the tissue's mean follows its partial-volume tail down to the
    # background), whole tissues, largest first, up to `max_classes` classes, the densest real one always, and, in
    # an object a shown tissue fills (on data that are not CT-like), every one between two shown ones.
    background_bin = float(class_bins[is_background][0]) if is_background.any() else -np.inf
    fog_width = noise_sd if fog_sd is None else fog_sd
    peak = np.array([largest_class(tissue_of_class, voxels, t) for t in range(n_tissues)], dtype=np.intp)
    inner = [
        t
        for t in foreground
        if tissue_contact[t] <= rules.rim_contact
        and class_bins[peak[t]] - background_bin >= rules.fog_separation * fog_width
    ] or foreground
    classes_in = np.bincount(tissue_of_class, minlength=n_tissues)
    shown: set[int] = set()
    for t in sorted(inner, key=lambda t: (-tissue_voxels[t], t)):
        if sum(classes_in[s] for s in shown) + classes_in[t] <= max_classes:
            shown.add(t)
    real = [t for t in foreground if share[t] >= rules.real_share]
    if real:
        shown.add(max(real, key=lambda t: tissue_bin[t]))
    if kind != "ct" and any(share[t] > rules.fill_share for t in shown):
        # A tissue fills the object, its surface where it is met first (step 3): one hidden between two shown ones
        # would punch holes in it. (On CT-like data it is cleared around the dense tail instead.)
        low, high = min(tissue_bin[t] for t in shown), max(tissue_bin[t] for t in shown)
        shown |= {t for t in inner if low < tissue_bin[t] < high}
    shown_sorted = sorted(shown, key=lambda t: tissue_bin[t])

    # 2. The monotone start, 3. the visibility step.
    tissue_opacity = np.zeros(n_tissues)
    for rank, t in enumerate(shown_sorted):
        place = rank / (len(shown_sorted) - 1) if len(shown_sorted) > 1 else 1.0
        tissue_opacity[t] = rules.opacity_low + (rules.opacity_high - rules.opacity_low) * place
    for t in foreground:
        if t not in shown:
            tissue_opacity[t] = rules.opacity_low  # what a user who shows it starts from
    shares = None
    if preview is not None and labels is not None and shown_sorted:
        step = _VisibilityStep(
            preview,
            labels,
            tissue_of_class,
            shown_sorted,
            tissue_bin,
            peak,
            class_bins,
            background_bin,
            noise_sd,
            rules,
            fog_width,
        )
        real_shown = [t for t in shown_sorted if share[t] >= rules.real_share]
        if kind == "ct":
            ordered = np.array(foreground)
            dense = dense_tail(
                tissue_bin[ordered], tissue_voxels[ordered], noise_sd,
                lambda a, b: enclosure(preview, step.tissue_of_bin, int(ordered[a]), int(ordered[b])), rules,
            )  # fmt: skip
            features = [int(ordered[i]) for i in dense] or real_shown[-1:]
            tissue_opacity = step.show_features(tissue_opacity, features)
        else:
            tissue_opacity = step.outer_surface(tissue_opacity, real_shown, share)
        tissue_opacity = _follow_real(tissue_opacity, shown_sorted, real_shown)
        # The picture of the transfer function written: a feature's partial-volume ramp reaches into its classes.
        class_opacity = step.class_opacity(tissue_opacity)
        shares = step.shares(step.bin_opacity(tissue_opacity))

    # Colours: one per tissue (per class on CT).
    tissue_color = {t: list(BACKGROUND_GREY) for t in range(n_tissues)}
    class_color: dict[int, list[float]] = {}
    if colors == "ramp" and foreground:  # without a foreground (a single class, the background) nothing is coloured
        tissue_value = np.bincount(tissue_of_class, weights=voxels * class_values, minlength=n_tissues) / np.maximum(
            tissue_voxels, 1
        )
        anchors = shown_sorted or foreground
        low = tissue_value[anchors[0]]
        top = max(real, key=lambda t: tissue_bin[t]) if real else anchors[-1]
        high = tissue_value[top]
        largest = max(anchors, key=lambda t: tissue_voxels[t])
        tail = top != largest and tissue_voxels[top] <= rules.white_share * tissue_voxels[largest]
        end = 1.0 if tail or len(anchors) == 1 else IVORY_PLACE

        def place_at(value: float, start: float = SHOWN_PLACE, lowest: float = low) -> float:
            share = (value - lowest) / (high - lowest) if high > lowest else 1.0
            return start + (end - start) * min(max(share, 0.0), 1.0)

        def color_at(place: float) -> list[float]:
            return [float(v) for v in ramp_colors(np.array([place]))[0]]

        for t in foreground:
            tissue_color[t] = color_at(place_at(tissue_value[t]))
        if kind == "ct":
            place = {c.id: place_at(class_values[c.id]) for c in classes if not c.background}
            dense_ids = [c for c in place if dense_classes is not None and dense_classes[c]]
            if dense_ids:
                # A dense part is another material (bone, contrast, metal): ivory to white, as the CT presets draw
                # it, placed by value among the dense classes; never darker than the ramp has it.
                lowest = min(class_values[c] for c in dense_ids)
                for c in dense_ids:
                    place[c] = max(place[c], place_at(class_values[c], IVORY_PLACE, lowest))
            class_color = {c: color_at(p) for c, p in place.items()}
    elif colors == "distinct":
        for i, t in enumerate(sorted(foreground, key=lambda t: (-tissue_voxels[t], t))):
            tissue_color[t] = list(PALETTE[i % len(PALETTE)])

    opacity = tissue_opacity[tissue_of_class] if tissue_of_class.size else np.zeros(0)
    if shares is not None:
        shown_class = np.isin(tissue_of_class, shown_sorted)
        opacity = np.where(shown_class, np.maximum(class_opacity, 0.0), opacity)
    opacity[is_background] = 0.0
    visible = [bool(tissue_of_class[c.id] in shown) and not c.background for c in classes]
    colors_out = [
        list(BACKGROUND_GREY) if c.background else class_color.get(c.id, tissue_color[tissue_of_class[c.id]])
        for c in classes
    ]
    return Look(colors_out, [float(a) for a in opacity], visible, shares)


def _share_of_upper(bins: np.ndarray, low: float, high: float) -> np.ndarray:
    """``bins.shape`` share of the upper of two materials, of mean bins ``low < high``, that a voxel in each bin
    holds: linear between them (partial volume), clipped to [0, 1]."""
    return np.clip((np.asarray(bins, dtype=np.float64) - low) / (high - low), 0.0, 1.0)


def fringe_cores_apart(
    tissue_of_class: np.ndarray,
    contact: np.ndarray,
    voxels: np.ndarray,
    is_background: np.ndarray,
    rules: LookRules = RULES,
) -> np.ndarray:
    """``(n_classes,)`` the tissue of each class as the look decides it: a fringe tissue (more than
    :attr:`.LookRules.rim_contact` of its voxels touch the background) whose densest classes do not touch it is two, its
    fringe and that core, so the core's classes are shown while the fringe is cleared (the partial volume of small
    vessels and branches falls into the lowest tissue, with the rim of the larger ones). Ids stay in intensity
    order.

    Args:
        tissue_of_class: ``(n_classes,)`` tissue per class (classes in intensity order, tissues runs of them).
        contact: ``(n_classes,)`` background contact. voxels: ``(n_classes,)``. is_background: ``(n_classes,)``.
        rules: the thresholds.
    """
    out = np.empty_like(tissue_of_class)
    next_id = 0
    for tissue in range(int(tissue_of_class.max()) + 1 if tissue_of_class.size else 0):
        members = np.flatnonzero(tissue_of_class == tissue)
        weight = voxels[members].sum()
        fringe = weight > 0 and (voxels[members] * contact[members]).sum() / weight > rules.rim_contact
        first_core = members.size
        if fringe and not is_background[members].any():
            while first_core > 0 and contact[members[first_core - 1]] <= rules.rim_contact:
                first_core -= 1
        if 0 < first_core < members.size:
            out[members[:first_core]], out[members[first_core:]] = next_id, next_id + 1
            next_id += 2
        elif members.size:
            out[members] = next_id
            next_id += 1
    return out


def fog_apart(tissue_of_class: np.ndarray, fog: np.ndarray) -> np.ndarray:
    """``(n_classes,)`` the tissue of each class as a surface look decides it: the fog classes of a tissue and its
    other classes are tissues of their own (each run of them), so the fog stays hidden while the rest is shown or
    hidden by its own measurements, not by where the fog lies. The intensity model groups by similarity, and the
    partial volume between the background and a tissue (the dark outer cortex of a skull-stripped brain, a flame's
    faint envelope) falls into one tissue with the noise below it. Ids stay in intensity order.

    Args:
        tissue_of_class: ``(n_classes,)`` tissue per class (classes in intensity order, tissues runs of them).
        fog: ``(n_classes,)`` whether each class is fog (:func:`.roles.class_roles`).
    """
    tissue_of_class = np.asarray(tissue_of_class)
    fog = np.asarray(fog, dtype=bool)
    if tissue_of_class.size == 0:
        return tissue_of_class.copy()
    starts = np.r_[True, (tissue_of_class[1:] != tissue_of_class[:-1]) | (fog[1:] != fog[:-1])]
    return np.cumsum(starts) - 1


def _follow_real(opacity: np.ndarray, shown: list[int], real: list[int]) -> np.ndarray:
    """A shown tissue below :attr:`.LookRules.real_share` takes the opacity of the nearest real tissue below it (the
    lowest real one when none is below): a few stray voxels never stand out, nor vanish."""
    if not real:
        return opacity
    opacity = opacity.copy()
    for t in shown:
        if t not in real:
            below = [r for r in real if shown.index(r) < shown.index(t)]
            opacity[t] = opacity[below[-1] if below else real[0]]
    return opacity


class _VisibilityStep:
    """Renders of one design's preview with per-tissue opacities (step 3 of the module notes).

    Every render is of the transfer function the design writes (:func:`bin_opacity_of`, which
    :meth:`.TransferFunctionDesign.bin_looks` calls too).

    Args:
        preview: the low-resolution volume.
        labels: ``(n_bins,)`` class of each bin.
        tissue_of_class: ``(n_classes,)`` tissue of each class.
        shown: the shown tissues (the others stay clear).
        tissue_bin: ``(n_tissues,)`` mean bin of each tissue.
        peak: ``(n_tissues,)`` each tissue's largest class: where the tissue itself lies; its classes below that one
            are its partial volume.
        class_bins: ``(n_classes,)`` mean bin of each class.
        background_bin: mean bin of the background (-inf without one).
        noise_sd: noise width in bins.
        rules: the thresholds.
        fog_sd: the width fog is decided in, in bins (``noise_sd`` if None): a skin's partial volume starts
            :attr:`.LookRules.ramp_start` of them above the background.
    """

    def __init__(
        self,
        preview: Preview,
        labels: np.ndarray,
        tissue_of_class: np.ndarray,
        shown: list[int],
        tissue_bin: np.ndarray,
        peak: np.ndarray,
        class_bins: np.ndarray,
        background_bin: float,
        noise_sd: float,
        rules: LookRules = RULES,
        fog_sd: Optional[float] = None,
    ) -> None:
        self.preview = preview
        self.labels = np.asarray(labels)
        self.tissue_of_bin = np.asarray(tissue_of_class)[self.labels]
        self.n_tissues = int(self.tissue_of_bin.max()) + 1
        self.bins_of_class = np.bincount(self.labels, minlength=len(tissue_of_class))
        self.shown = np.isin(np.arange(self.n_tissues), shown)
        self.tissue_bin = tissue_bin
        self.peak = np.asarray(peak)
        self.class_bins = np.asarray(class_bins, dtype=np.float64)
        self.background_bin = float(background_bin)
        self.noise_sd = float(noise_sd)
        self.fog_sd = self.noise_sd if fog_sd is None else float(fog_sd)
        self.rules = rules
        self.rays = preview.rays_crossing(self.tissue_of_bin, self.n_tissues)
        # Partial volume of a feature: (first bin, lower tissue, feature) where its ramp starts (see show_features).
        self.ramps: list[tuple[int, int, int]] = []
        # Tissues whose partial volume with the background is ramped in (see outer_surface).
        self.skins: list[int] = []
        self._last_render: tuple[Optional[np.ndarray], np.ndarray] = (None, np.zeros(0))

    def class_opacity(self, opacity: np.ndarray) -> np.ndarray:
        """``(n_classes,)`` opacity per mm of each class: its tissue's (0 where not shown); in a feature's partial
        volume, the mean over the class's bins of a ramp up to the feature's opacity; in a skin's partial volume
        with the background, the share of the tissue a bin holds times its opacity, from where the background's
        noise ends."""
        per_bin = np.where(self.shown, opacity, 0.0)[self.tissue_of_bin]
        for start, lower, feature in self.ramps:
            end = int(np.flatnonzero(self.tissue_of_bin == feature)[0])
            inside = np.arange(start, end)
            inside = inside[self.shown[self.tissue_of_bin[inside]]]
            share = _share_of_upper(inside, self.tissue_bin[lower], self.tissue_bin[feature])
            ramp = opacity[lower] + (opacity[feature] - opacity[lower]) * share
            per_bin[inside] = np.maximum(per_bin[inside], ramp)
        # A skin's partial volume starts where the background's noise ends, as a feature's starts above the tissue
        # below it: nearer the background, a voxel is the air's noise (the haze the presets' Shift cuts away).
        skin_start = self.background_bin + self.rules.ramp_start * self.fog_sd
        for tissue in self.skins:
            # Every shown bin below the skin's largest class: its own partial volume with the background, and a
            # stray tissue there that follows its opacity (_follow_real).
            inside = np.flatnonzero(self.shown[self.tissue_of_bin] & (self.labels < self.peak[tissue]))
            share = _share_of_upper(inside, self.background_bin, self.class_bins[self.peak[tissue]])
            per_bin[inside] *= np.where(inside >= skin_start, share, 0.0)
        return np.bincount(self.labels, weights=per_bin, minlength=self.bins_of_class.size) / np.maximum(
            self.bins_of_class, 1
        )

    def bin_opacity(self, opacity: np.ndarray) -> np.ndarray:
        """``(n_bins,)`` opacity per mm of each bin, as the transfer function has it (:func:`bin_opacity_of` of
        :meth:`class_opacity`)."""
        return bin_opacity_of(self.class_opacity(opacity), self.labels, self.noise_sd)

    def light(self, opacity: np.ndarray) -> np.ndarray:
        """``(n_tissues,)`` light each tissue sends to the eye over the six views, with these opacities per mm."""
        return self._light_of_bins(self.bin_opacity(opacity))

    def _light_of_bins(self, bin_opacity: np.ndarray) -> np.ndarray:
        last_opacity, last_light = self._last_render
        if last_opacity is not None and np.array_equal(last_opacity, bin_opacity):
            return last_light  # the loop's last render is often the final picture
        light = visibility_histogram(self.preview, bin_opacity)
        light = np.bincount(self.tissue_of_bin, weights=light, minlength=self.n_tissues)
        self._last_render = (bin_opacity, light)
        return light

    def shares(self, bin_opacity: np.ndarray) -> np.ndarray:
        """``(n_tissues,)`` share of the picture each tissue gives with ``bin_opacity`` (:meth:`bin_opacity`); 0
        everywhere for an empty picture."""
        light = self._light_of_bins(bin_opacity)
        total = light.sum()
        return light / total if total > 0 else light

    def make_seen(self, opacity: np.ndarray, tissue: int) -> np.ndarray:
        """Raise a tissue's opacity until, rendered alone, it gives :attr:`.LookRules.seen` of the light of the rays
        that cross it (a surface where it lies). Its visibility is about ``1 - (1 - a) ** L`` for an effective
        thickness ``L``, which gives the opacity asked; never lowered."""
        opacity = opacity.copy()
        alone = np.where(np.arange(self.n_tissues) == tissue, opacity, 0.0)
        seen = self.light(alone)[tissue] / max(self.rays[tissue], 1)
        if 0 < seen < self.rules.seen and opacity[tissue] > 0:
            thickness = np.log1p(-seen) / np.log1p(-opacity[tissue])
            opacity[tissue] = min(1.0, -np.expm1(np.log1p(-self.rules.seen) / thickness))
        return opacity

    def show_features(self, opacity: np.ndarray, features: list[int]) -> np.ndarray:
        """CT-like data: every feature (a tissue of the dense tail) is a surface where it lies, its partial volume
        is ramped in (from where the tissue below it ends, :attr:`.LookRules.ramp_start` noise widths above that
        tissue's mean, the opacity of a voxel follows the share of the feature it holds, linear between the two
        tissues' means: a thin bone blurred below the feature's range is still drawn, a soft-tissue voxel raised by
        noise is not), and the tissues below it that stand apart from it keep at least :attr:`.LookRules.seen` of its
        light (the enclosing soft tissue is cleared)."""
        shown = np.flatnonzero(self.shown)
        apart = {}
        for f in features:
            opacity = self.make_seen(opacity, f)
            lower = [
                int(o)
                for o in shown
                if self.tissue_bin[f] - self.tissue_bin[o] >= self.rules.dense_separation * self.noise_sd
            ]
            if lower:
                apart[f] = lower
                below = max(lower, key=lambda o: self.tissue_bin[o])
                start = int(np.ceil(self.tissue_bin[below] + self.rules.ramp_start * self.noise_sd))
                self.ramps.append((start, below, f))
        alone = {}
        for f, lower in apart.items():
            cleared = opacity.copy()
            cleared[lower] = 0.0
            alone[f] = self.light(cleared)[f]
        light = self.light(opacity)
        for _ in range(VISIBILITY_ROUNDS):
            factor = np.ones(self.n_tissues)
            for f, lower in apart.items():
                kept = light[f] / alone[f] if alone[f] > 0 else 1.0
                if kept < self.rules.seen:
                    # The lower tissues' transmittance T in front of f: scaling their opacity by s gives about T ** s.
                    factor[lower] = np.minimum(factor[lower], np.log(self.rules.seen) / np.log(max(kept, 1e-12)))
            if np.all(factor >= 1.0):
                break
            opacity = opacity * factor
            light = self.light(opacity)
        return opacity

    def outer_surface(self, opacity: np.ndarray, real: list[int], share: np.ndarray) -> np.ndarray:
        """Other data: the real tissue that encloses the others (met first by most rays through it and another) is
        made a surface where it lies, as MR-Default shows a head's skin and a brain's cortex: seen
        (:meth:`make_seen`); where it fills the object (``share`` ``(n_tissues,)`` of the foreground's voxels above
        :attr:`.LookRules.fill_share`), at least at the ramp's top, with the shown bins below its largest class (its
        partial volume with the background) ramped in as the share of the tissue a voxel holds, from
        :attr:`.LookRules.ramp_start` fog widths above the background: an opaque tissue would draw its blurred
        skin, not the skin. Called once per step."""
        if not real:
            return opacity
        outer = real[0]
        if len(real) > 1:
            outer = real[int(np.argmax(first_met(self.preview, self.tissue_of_bin, real)))]
        opacity = self.make_seen(opacity, outer)
        if share[outer] > self.rules.fill_share:
            opacity[outer] = max(opacity[outer], self.rules.opacity_high)
            if -np.inf < self.background_bin < self.class_bins[self.peak[outer]]:  # a background below it
                self.skins.append(outer)
        return opacity


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
