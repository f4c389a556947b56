"""What each class is in the picture, decided once from its own measurements, and the rules that decide it.

A class's *role* says what a look may do with it; the looks (:mod:`.gallery`) read the roles and never re-derive
them. Every threshold is one field of :class:`LookRules`, which takes one decision, with its reason.

Roles, in the order they are decided (the first that applies):

- ``"background"``: the background class (the thesis' rule: the largest class; see :mod:`.classes`).
- ``"fog"``: noise in the background: the class's mean bin lies within :attr:`LookRules.fog_separation` noise widths
  (:func:`noise_width`) of the background's, either side (a micro-CT's noisy air, the haze of an MRI), and so does its
  tissue (the tissue *is* at the background's intensity: noisy air, haze): its largest class, or most of its voxels
  (:attr:`LookRules.located_share`); or most of its voxels touch the background (:attr:`LookRules.rim_contact`: noise
  scattered in the air). A low class of a tissue that stands apart from the background (its largest class and most
  of its voxels), which does not touch it, is that tissue's darker part or partial volume (the outer cortex of a
  skull-stripped brain), not noise. Whether a tissue lies at the background's intensity is counted in the
  background's noise (:func:`fog_width`): a background of one stored value has none, and the tissue next to it is
  then measured by the voxels' noise (a flame's faint envelope around its empty space); noisy air on CT-like data is
  at least as wide as the voxels' noise (the model may fit its tails narrower). Where every structure (a real tissue
  whose largest class is not at the background's intensity) lies on one side of the background, a class of a tissue
  whose largest class is at the background's intensity on the other side is fog however far out it lies
  (:func:`beyond_structures`): it is that noise's tail, with nothing beyond it (the air around a micro-CT's tube of
  ethanol, the ethanol the background). No look shows fog.
- ``"dense"``: a class whose mean lies :attr:`LookRules.dense_separation` noise widths above the *main material*,
  in a real tissue: bone or contrast in soft tissue, the parts inside a housing, the core of a vessel, a bright
  lesion (widths of the intensity model on CT-like data, of the voxels' noise where smaller on other data: see
  :func:`noise_width`). The main material is placed by the larger of two estimates: the mean of the largest
  tissue, and the mean of the largest class (affinity propagation gives the peak of a material's histogram a class
  of its own; a tissue's mean follows its partial-volume tail down: in an export whose air was set to 0, the lowest
  tissue is mostly the blur of the skull, and its mean lies far below the brain). Decided per class: where the
  intensity model puts trabecular bone in one tissue with the soft tissue (its histogram has no valley between
  them), the bone's classes are still dense. A dense class lies above the background too: where the background is
  not the lowest material (the soft tissue of a CT cropped to the body, its largest class), the classes between it
  and the main material below (the lungs) are their blend.
- ``"rim"``: most of its voxels touch the background (:attr:`LookRules.rim_contact`): the partial-volume skin of
  an object, or a structure only a voxel or two thick (a small vessel, a twig), which is all skin. Where it lies in
  the open, along lines (:attr:`LookRules.line_fill`), whether it *is* the structure or hides it, the data cannot
  say: one look shows it, another clears it; where it lies against the body it blurs, it is a surface's skin.
- ``"bulk"``: everything else: the tissue that fills or encloses the rest (soft tissue, a housing, a brain).
"""

from collections.abc import Sequence
from dataclasses import dataclass
from math import erf, sqrt
from typing import Optional

import numpy as np

from .classes import IsovalueClass
from .tissues import value_step

ROLES = ("background", "fog", "dense", "rim", "bulk")
#: The narrowest noise a histogram resolves, in bins: the floor of the voxels' noise (:func:`noise_width`) and the
#: noise whose spread defines a background without any (:attr:`LookRules.constant_neighbour_share`).
RESOLVED_SD = 0.5
# A Gaussian of that width holds erf(x / _ERF_SCALE) of its mass within x of its mean.
_ERF_SCALE = RESOLVED_SD * sqrt(2.0)


@dataclass(frozen=True)
class LookRules:
    """Every threshold of the roles and looks, one decision each.

    Attributes:
        real_share: a tissue holding at least this share of the non-background voxels is a real structure, not a
            few stray voxels (which never decide what is dense, nor become the most opaque thing in view).
        fog_separation: a class whose mean lies within this many noise widths (:func:`noise_width`, or
            :func:`fog_width` for the tissue it belongs to, in bins) of
            the background's mean is at the background's intensity, as noise in it would be: two Gaussians 4 sd
            apart overlap by under 2.5 % (fog when its tissue is there too, or it touches the background: see the
            module notes).
        located_share: a tissue lies at the background's intensity where more than this share of its voxels do
            (its median), or its largest class does (the peak of its histogram): where classes of near-equal size
            share a tissue (a skull-stripped brain's CSF and the cortex's edge), which one is largest changes with
            the storage, and the median does not. Decides fog within the fog's width only: beyond it a tissue
            whose peak stands apart is a structure.
        dense_separation: a real tissue this many noise widths above another is a different, denser material (bone
            over soft tissue), not a brighter shade of the same one (white over grey matter): it decides the dense
            classes (counted in :func:`noise_width`), a CT's dense tail and which tissues a feature is seen through.
        ramp_start: a feature's partial volume starts this many noise widths above the mean of the tissue below it
            (where that tissue's noise ends: its one-sided 2.5 % tail lies beyond 2 sd, and 4 sd leaves 3e-5), and
            a skin's this many fog widths above the background.
        tail_share: a CT's dense tail holds at most this share of the largest tissue's voxels (bone is 5-25 % of a
            CT's soft tissue; the tissues above a T1's or a skull-stripped brain's largest one hold 50-100 % of it).
        white_share: the ramp's white end is kept for a densest tissue holding at most this share of the largest
            one's voxels (bone, contrast); a large bright tissue (white matter) ends at ivory, or the headlight washes
            it out.
        rim_contact: a class more than this share of whose voxels touch the background lies on its fringe: its rim,
            or, at the background's intensity, noise scattered in it (fog).
        seen: the share of its own light (rendered alone) that a structure a look shows through others must keep:
            what the eye reads as "seen through a veil" rather than "behind it".
        fill_share: a tissue holding more than this share of the foreground's voxels fills the object (a head MRI's
            skin, muscle and grey matter in one tissue). As the outer tissue, seen through its whole depth it is a
            veil over everything inside, so it takes the ramp's top, as a surface; a thinner layer (the
            partial-volume edge of a brain's cortex) is seen within its own depth. And in an object a shown tissue
            fills, no tissue between two shown ones is hidden: it would punch holes in that surface.
        dense_share: the *dense parts* look promises that the dense classes give at least this share of the picture:
            they are what it shows; what is left of the bulk around them is a context taking at most half the
            least share the *see-through* look keeps it at (``1 - see_through[0] / 2``), so that the two looks are
            two pictures, and a soft tissue that one storage keeps and another makes background (HU clipped at
            0) changes the picture little.
        see_through: the *see-through* look keeps the enclosing bulk at this share of the picture, ``(low, high)``:
            enough to place the parts inside, little enough to see them.
        thin_rim_share: thin structures: at least this share of the objects' voxels are rim (touch the background):
            a one-voxel skin over a cylinder of radius r voxels holds about 2 / r of it, so objects a few voxels
            thick, as the small vessels of an angiogram.
        thin_foreground: ... and the objects fill at most this share of the volume: the vessel trees exported with
            95-99 % zeros that a first click must show whole (not a head whose soft tissue was clipped away).
        line_fill: the rim lies in the open, along lines (twigs, small vessels), where its preview voxels' median
            surroundings are filled by objects (not background, not fog) to less than this share
            (:func:`.visibility.surroundings_fill`): a plane through the cube measured fills a fifth of it, a line one
            voxel thick a twenty-fifth, while the skin of a body lies against the body it blurs (0.46-0.79 on the
            panel) and the speckle a clip at 0 HU leaves of a soft tissue fills it as the tissue did (0.30-0.63).
            Shown as structure, a surface's skin is its speckle: the *thin structures* look is offered beside other
            objects only where the rim lies along lines (a plant's twigs 0.06, a vessel tree's rim 0.14), and on
            data that are not CT-like it is the first click there: the outer surface clears the rim as the skin of
            what it covers, and lines in the open have nothing under them.
        thin_share: the *thin structures* look promises that the rim gives at least this share of the picture, the
            rest made clearer until it does: the thin structures are what it shows, more than anything around them
            (a plant's pot, which otherwise takes the picture of its twigs); not more, since the rim is also the
            skin of the thicker structures the look keeps (a vessel tree's larger vessels, a trunk).
        thin_opacity: opacity per unit distance of the lowest rim class in the *thin structures* look: a structure
            one voxel thick (a voxel is about one unit distance, see :attr:`.visibility.Preview.unit_distance`)
            must stop half the light to be seen at all.
        constant_neighbour_share: the background is one stored value, without noise (:func:`is_constant_background`),
            when the stored values next to its fullest bin each hold less than this share of it: Gaussian noise of
            half a bin, the least a histogram resolves, puts 0.23 of the fullest bin's voxels in each bin beside it.
        opacity_low, opacity_high: opacity per unit distance of the lowest and densest shown tissue on the
            presets' monotone ramp (a haze half the light passes through over 35 units; a surface within 2-3).
    """

    real_share: float = 0.01
    fog_separation: float = 4.0
    located_share: float = 0.5
    dense_separation: float = 4.0
    ramp_start: float = 4.0
    tail_share: float = 1 / 3
    white_share: float = 1 / 3
    rim_contact: float = 0.5
    seen: float = 0.8
    fill_share: float = 0.5
    dense_share: float = 0.9
    see_through: tuple[float, float] = (0.2, 0.4)
    thin_rim_share: float = 0.5
    thin_foreground: float = 0.05
    line_fill: float = 0.2
    thin_share: float = 0.5
    thin_opacity: float = 0.5
    constant_neighbour_share: float = (erf(1.5 / _ERF_SCALE) - erf(0.5 / _ERF_SCALE)) / (2 * erf(0.5 / _ERF_SCALE))
    opacity_low: float = 0.02
    opacity_high: float = 0.5


RULES = LookRules()


def noise_width(kind: str, noise_sd: float, voxel_noise_sd: Optional[float]) -> float:
    """The noise width, in bins, that the fog and dense rules count in (:attr:`LookRules.fog_separation`,
    :attr:`LookRules.dense_separation`): the intensity model's on CT-like data (``kind`` ``"ct"``), where a dense part
    is another material, bone or contrast or metal, whose distance from the soft tissue dwarfs the soft tissues' own
    contrasts (enhanced organs are not dense parts); on other data the voxels' noise
    (:func:`.classes.voxel_noise_sd`) where it is smaller, since there the model's width also holds the spread of its
    wide tissues (grey and white matter in one): a brighter structure a few noise widths above the tissue around it
    (a FLAIR lesion, an enhancing vessel) would lie within it, and a dim tissue (the organs of an abdominal MRI) at
    its background's "noise". The voxels' noise counts as at least half a bin (a histogram resolves no less)."""
    if kind == "ct" or voxel_noise_sd is None:
        return noise_sd
    return min(noise_sd, max(voxel_noise_sd, RESOLVED_SD))


def fog_width(kind: str, noise_sd: float, voxel_noise_sd: Optional[float], constant_background: bool) -> float:
    """The background's noise, in bins: the width in which a tissue lies at the background's intensity (the fog
    rule's tissue clause, :attr:`LookRules.fog_separation`) and above which a skin's partial volume starts
    (:attr:`LookRules.ramp_start`). It is :func:`noise_width`, except on CT-like data:

    - whose background is one stored value (``constant_background``, :func:`is_constant_background`: air set to 0 by
      an export, a clip or a mask; a simulation's empty space). That background has no noise, and the intensity
      model's width of the tissue next to it is the tissue's own spread of values (a flame's envelope fading into
      empty space), not noise: the voxels' noise measures it, as on other data;
    - whose background is noisy air: the wider of the model's width and the voxels' noise. The model's one width is
      that of its narrowest peak, and where it cuts the air's noise into tails around the background class (a
      specimen exported through an auto-contrast window, the background class in the middle of the air), it fits
      each tail as a tissue a third as wide as the noise, 3.5 bins against the voxels' 10.8: the air's upper tail
      then lay 5 model widths up and was shown as thin structures. The voxels measure the noise itself.

    Noise scattered in the air (a class touching the background) is still judged in :func:`noise_width`: a zeroed
    MRI's leftover noise is that."""
    if kind == "ct" and not constant_background and voxel_noise_sd is not None:
        return max(noise_sd, voxel_noise_sd)
    return noise_width("mr" if constant_background else kind, noise_sd, voxel_noise_sd)


def is_constant_background(bin_voxels: np.ndarray, background_bins: np.ndarray, rules: LookRules = RULES) -> bool:
    """Whether the background is one stored value (air set to 0 by an export, a clip or a mask; a simulation's empty
    space) rather than noise around one (:attr:`LookRules.constant_neighbour_share`). The bins compared are those
    within the data's step of its fullest bin (:func:`.tissues.value_step`: data stored in coarser steps than the
    bins leave the bins between their values empty), not the object's own values further up.

    Args:
        bin_voxels: ``(n_bins,)`` voxels per bin. background_bins: the background class's bins.
    """
    counts = np.asarray(bin_voxels)
    background_bins = np.asarray(background_bins, dtype=np.intp)
    if background_bins.size == 0 or counts[background_bins].max() <= 0:
        return False
    fullest = int(background_bins[np.argmax(counts[background_bins])])
    distance = np.abs(np.arange(counts.size) - fullest)
    beside = (distance > 0) & (distance <= value_step(counts))
    return bool(np.all(counts[beside] < rules.constant_neighbour_share * counts[fullest]))


def class_roles(
    classes: Sequence[IsovalueClass],
    tissue_of_class: np.ndarray,
    class_bins: np.ndarray,
    noise_sd: float,
    rules: LookRules = RULES,
    fog_sd: Optional[float] = None,
) -> list[str]:
    """The role of every class (see the module notes).

    Args:
        classes: the classes, in id order (``background``, ``voxels``, ``background_contact`` are read).
        tissue_of_class: ``(n_classes,)`` tissue id per class (the background's tissue holds it alone).
        class_bins: ``(n_classes,)`` voxel-weighted mean bin of each class.
        noise_sd: the noise width the rules count in, in bins (:func:`noise_width`).
        rules: the thresholds.
        fog_sd: the noise width in which a tissue lies at the background's intensity, in bins (:func:`fog_width`;
            ``noise_sd`` if None); a class touching the background is fog within ``noise_sd`` of it.

    Returns:
        One of :data:`ROLES` per class.
    """
    tissue_of_class = np.asarray(tissue_of_class)
    class_bins = np.asarray(class_bins, dtype=np.float64)
    background = next((c.id for c in classes if c.background), None)
    background_bin = class_bins[background] if background is not None else -np.inf
    dense = set(dense_classes(classes, tissue_of_class, class_bins, noise_sd, rules))
    voxels = np.array([c.voxels for c in classes], dtype=np.float64)
    distance = np.abs(class_bins - background_bin)
    near = distance < rules.fog_separation * noise_sd
    at_background = distance < rules.fog_separation * (noise_sd if fog_sd is None else fog_sd)
    # Where a tissue lies: its largest class (the peak of its histogram), or for a class within the fog also most of
    # its voxels (the median). Beyond the fog, a tissue whose peak stands apart is a structure (bone whose
    # partial volume with a cropped CT's soft tissue is most of its voxels).
    peak_at_background = at_background[[largest_class(tissue_of_class, voxels, t) for t in tissue_of_class]]
    tissue_at_background = peak_at_background | mostly_at(tissue_of_class, voxels, at_background, rules)
    beyond = beyond_structures(classes, tissue_of_class, class_bins, ~peak_at_background, rules)
    roles = []
    for c in classes:
        if c.background:
            roles.append("background")
        elif (
            (at_background[c.id] and tissue_at_background[c.id])
            or (beyond[c.id] and peak_at_background[c.id])
            or (near[c.id] and c.background_contact > rules.rim_contact)
        ):
            roles.append("fog")
        elif c.id in dense:
            roles.append("dense")
        elif c.background_contact > rules.rim_contact:
            roles.append("rim")
        else:
            roles.append("bulk")
    return roles


def beyond_structures(
    classes: Sequence[IsovalueClass],
    tissue_of_class: np.ndarray,
    class_bins: np.ndarray,
    apart: np.ndarray,
    rules: LookRules = RULES,
) -> np.ndarray:
    """``(n_classes,)`` whether each class lies on the other side of the background's mean bin from every structure:
    a class of a real tissue (:attr:`LookRules.real_share` of the non-background voxels) whose largest class stands
    apart from the background's intensity. All False without a background, or with structures on both sides.

    Args:
        classes: the classes, in id order. tissue_of_class: ``(n_classes,)`` tissue id per class.
        class_bins: ``(n_classes,)`` mean bin per class. apart: ``(n_classes,)`` whether each class's tissue stands
            apart from the background's intensity (its largest class does).
    """
    background = next((c.id for c in classes if c.background), None)
    if background is None:
        return np.zeros(len(classes), dtype=bool)
    structure = in_real_tissue(classes, tissue_of_class, rules) & np.asarray(apart, dtype=bool)
    side = np.sign(np.asarray(class_bins, dtype=np.float64) - class_bins[background])
    structure_sides = np.unique(side[structure])
    if structure_sides.size != 1 or structure_sides[0] == 0:
        return np.zeros(len(classes), dtype=bool)
    return side == -structure_sides[0]


def in_real_tissue(
    classes: Sequence[IsovalueClass], tissue_of_class: np.ndarray, rules: LookRules = RULES
) -> np.ndarray:
    """``(n_classes,)`` whether each class belongs to a real tissue: one holding :attr:`LookRules.real_share` of the
    non-background voxels (none when there are none)."""
    counted = np.array([0.0 if c.background else float(c.voxels) for c in classes])
    tissue_voxels = np.bincount(tissue_of_class, weights=counted)
    return tissue_voxels[tissue_of_class] >= rules.real_share * max(counted.sum(), 1.0)


def mostly_at(tissue_of_class: np.ndarray, voxels: np.ndarray, at: np.ndarray, rules: LookRules = RULES) -> np.ndarray:
    """``(n_classes,)`` whether more than :attr:`LookRules.located_share` of the voxels of each class's tissue lie
    where ``at`` holds (its median does).

    Args:
        tissue_of_class: ``(n_classes,)`` tissue id per class. voxels: ``(n_classes,)``. at: ``(n_classes,)`` bool,
            whether each class lies there (at the background's intensity).
    """
    tissue_of_class = np.asarray(tissue_of_class)
    voxels = np.asarray(voxels, dtype=np.float64)
    held = np.bincount(tissue_of_class, weights=np.where(np.asarray(at, dtype=bool), voxels, 0.0))
    total = np.bincount(tissue_of_class, weights=voxels)
    return (held > rules.located_share * total)[tissue_of_class]


def largest_class(tissue_of_class: np.ndarray, voxels: np.ndarray, tissue: int) -> int:
    """Id of the class of ``tissue`` with the most voxels (the first of equals): where the tissue itself lies, its
    mean following its partial-volume tail.

    Args:
        tissue_of_class: ``(n_classes,)`` tissue id per class. voxels: ``(n_classes,)``. tissue: a tissue id that has
            classes.
    """
    members = np.flatnonzero(np.asarray(tissue_of_class) == tissue)
    return int(members[np.argmax(np.asarray(voxels)[members])])


def dense_classes(
    classes: Sequence[IsovalueClass],
    tissue_of_class: np.ndarray,
    class_bins: np.ndarray,
    noise_sd: float,
    rules: LookRules = RULES,
    among: Optional[np.ndarray] = None,
) -> list[int]:
    """Ids of the classes of real tissues whose mean lies ``rules.dense_separation`` noise widths above the main
    material (:func:`main_material_bin`; the background left out) and above the background's, ascending: between
    the main material and a background above it lies their blend, not a denser material (a chest CT cropped to the
    body: its soft tissue is the largest class, the background, and the lungs' edge against it lies between).

    ``among``: ``(n_classes,)`` the classes the main material is placed in and the dense ones taken from (default:
    every class but the background). Among the dense classes it finds a second, denser material inside them (the bone
    inside the organs of a CT taken for an MRI, the fat its largest tissue: :attr:`.LookContext.densest`)."""
    voxels = np.array([c.voxels for c in classes], dtype=np.float64)
    foreground = np.array([not c.background for c in classes])
    counted = foreground if among is None else np.asarray(among, dtype=bool) & foreground
    n_tissues = int(tissue_of_class.max()) + 1 if tissue_of_class.size else 0
    tissue_voxels = np.bincount(tissue_of_class, weights=voxels * counted, minlength=n_tissues)
    tissue_bin = tissue_mean_bins(tissue_of_class, voxels, class_bins, n_tissues, counted=counted)
    total = tissue_voxels.sum()
    if total <= 0:
        return []
    real = in_real_tissue(classes, tissue_of_class, rules)
    main = main_material_bin(voxels * counted, tissue_voxels, tissue_bin, class_bins)
    above = class_bins >= main + rules.dense_separation * noise_sd
    if not foreground.all():
        above &= class_bins > class_bins[~foreground].max()
    return [int(c) for c in np.flatnonzero(real & above & counted)]


def main_material_bin(
    class_voxels: np.ndarray, tissue_voxels: np.ndarray, tissue_bin: np.ndarray, class_bins: np.ndarray
) -> float:
    """Where the material most of the foreground is made of lies, in bins: the larger of the mean of the largest
    tissue and the mean of the largest class (see the module notes; the background's voxels counted as 0).

    Args:
        class_voxels: ``(n_classes,)`` voxels per class, 0 for the background. tissue_voxels: ``(n_tissues,)`` the
            same per tissue. tissue_bin: ``(n_tissues,)`` mean bin per tissue. class_bins: ``(n_classes,)``.
    """
    return max(float(tissue_bin[int(np.argmax(tissue_voxels))]), float(class_bins[int(np.argmax(class_voxels))]))


def tissue_mean_bins(
    tissue_of_class: np.ndarray,
    voxels: np.ndarray,
    class_bins: np.ndarray,
    n_tissues: int,
    counted: Optional[np.ndarray] = None,
) -> np.ndarray:
    """``(n_tissues,)`` voxel-weighted mean bin of each tissue, over its classes (those of ``counted``, a
    ``(n_classes,)`` mask, when given); a class without voxels still places its tissue (weight 1e-9)."""
    weight = np.maximum(voxels, 1e-9)
    if counted is not None:
        weight = weight * counted
    totals = np.bincount(tissue_of_class, weights=weight * class_bins, minlength=n_tissues)
    return totals / np.maximum(np.bincount(tissue_of_class, weights=weight, minlength=n_tissues), 1e-300)
