"""A gallery of looks: several transfer functions of the same classes, each with its own promise, one click each.

Where the data cannot say what the user wants (a housing to see through or to clear, partial volume that is the
structure or hides it), the design offers the looks the data support, ranked, as the Volume Rendering module offers
preset icons; the first is the first click. Every look is colours, opacities and visibility of the same classes, so
switching recomputes nothing. Each look decides from the class roles (:mod:`.roles`), never from units:

=================== ======================================================== ======================================
name                what it shows                                            offered when
=================== ======================================================== ======================================
``dense-parts``     the dense parts inside, the bulk around them cleared     a class is ``dense`` (always on CT)
                    until they give :attr:`.LookRules.dense_share` of
                    the picture (bone of a CT, the parts of an engine;
                    those the default hides on the ramp up to the rest:
                    a plume's fringe); on other data the dense parts
                    alone (a FLAIR's lesion)
``densest-parts``   on data that are not CT-like, the densest of two dense     the dense classes hold a second
                    materials alone (the bone inside the organs of an        material, a tissue of its own with a
                    abdominal CT whose fat makes it read as an MRI)          real share (:attr:`LookContext.densest`)
``outer-surface``   the tissue met first as a surface (the skin of a head,   always
                    a brain's cortex: MR-Default's look)
``see-through``     the dense parts look, with the bulk around them kept at   a class is ``dense`` and another
                    :attr:`.LookRules.see_through` of the picture            ``bulk``
``thin-structures`` the rim shown as structure, in its colour: small       thin structures alone, or a real share
                    vessels, twigs; the rest cleared until the rim gives     of the voxels is ``rim`` lying along
                    :attr:`.LookRules.thin_share` of the picture (a          lines in the open
                    plant's twigs, not its pot)
``all-tissues``     every tissue, on the presets' monotone ramp              two tissues or more
``classes``         one palette colour per class (the thesis)                two classes or more
=================== ======================================================== ======================================

The first click is ``thin-structures`` for thin structures alone in an empty field of view (:func:`is_thin`: a
vessel tree exported with 95-99 % zeros) and, on data that are not CT-like, beside other objects where the rim lies
along lines in the open (:attr:`LookContext.rim_in_the_open`: a plant's twigs), else ``dense-parts`` on CT-like
data (:func:`.look.detect_kind`), else ``outer-surface``; a look whose transfer function equals an earlier one is left
out. Each look states its *promise*, the share of the picture some roles give (measured by the visibility histogram
of :mod:`.visibility`); :func:`check_look` measures it again with an independent ray caster
(:func:`.thumbnails.ray_visibility`).
"""

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable, Optional

import numpy as np

from .classes import PALETTE, IsovalueClass
from .look import BACKGROUND_GREY, bin_opacity_of, default_look
from .options import LOOK_NAMES
from .roles import (
    RULES,
    LookRules,
    class_roles,
    dense_classes,
    fog_width,
    in_real_tissue,
    noise_width,
    tissue_mean_bins,
)
from .thumbnails import ray_visibility  # check_look's independent ray caster: an oracle, not the fast path
from .visibility import Preview, surroundings_fill, visibility_histogram

# Rounding allowed on a measured share (sums of float shares) when checking a promise.
_SHARE_ROUNDING = 1e-9
# The visibility step stops within this of the light it aims to keep (its last round's measure, float32 sums).
_KEPT_TOLERANCE = 0.01
# Renders of the clearing's bracketed search (regula falsi) after its start, first step and far end.
_CLEARING_ROUNDS = 8
# The clearing aims this far above the aims it must reach (shares, kept light), and stops within twice this above.
_SHARE_MARGIN = 0.02
# Rounds of the see-through look's search for the bulk's opacity (a secant in log opacity: 6 reach 1 % of share).
_SEE_THROUGH_ROUNDS = 6
# The smallest factor the clearing scales the others' opacities by: the far end of its search.
_LOWEST_FACTOR = 1e-6


@dataclass(frozen=True)
class LookContext:
    """What every look is made from: the classes, their grouping and roles, and the preview to measure with.

    Attributes:
        classes: the classes in id order. tissue_of_class: ``(n_classes,)`` tissue id per class.
        class_values: ``(n_classes,)`` mean value per class, volume units. class_bins: the same in bins.
        labels: ``(n_bins,)`` class per bin. noise_sd: the intensity model's noise width, in bins.
        preview: the low-resolution volume (None: no look needing a measure is offered, no share is measured).
        kind: ``"ct"``, ``"mr"`` or ``"8bit"``. colors: the ``colors`` option. max_classes: the option.
        roles: one of :data:`.roles.ROLES` per class. rules: the thresholds.
        voxel_noise_sd: the voxels' noise in bins (:func:`.classes.voxel_noise_sd`), or None (not measured: a design
            saved before it was): with ``noise_sd`` and ``kind``, the width the roles count in
            (:func:`.roles.noise_width`).
        constant_background: whether the background is one stored value (see :func:`.roles.fog_width`).
    """

    classes: Sequence[IsovalueClass]
    tissue_of_class: np.ndarray
    class_values: np.ndarray
    class_bins: np.ndarray
    labels: np.ndarray
    noise_sd: float
    preview: Optional[Preview]
    kind: str
    colors: str = "ramp"
    max_classes: int = 15
    roles: list[str] = field(default_factory=list)
    rules: LookRules = RULES
    voxel_noise_sd: Optional[float] = None
    constant_background: bool = False
    # The default looks made so far, by kind ("ct" or not): several looks start from the same one.
    _defaults: dict = field(default_factory=dict, repr=False, compare=False)
    # The light per class of every transfer function rendered so far, by its bin opacities: a look's last step and
    # its measure are often one render.
    _renders: dict = field(default_factory=dict, repr=False, compare=False)
    # The looks made so far, by name: one look may start from another (see-through from the dense parts).
    _made: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def build(cls, *, rules: LookRules = RULES, **inputs) -> "LookContext":
        """The context with the roles decided (:func:`.roles.class_roles`)."""
        context = cls(**inputs, rules=rules)
        width = noise_width(context.kind, context.noise_sd, context.voxel_noise_sd)
        roles = class_roles(
            context.classes, context.tissue_of_class, context.class_bins, width, rules, fog_sd=context.fog_sd
        )
        return dataclasses.replace(context, roles=roles)

    def of_role(self, *roles: str) -> np.ndarray:
        """``(n_classes,)`` whether each class has one of ``roles``."""
        return np.isin(np.array(self.roles, dtype=object), roles)

    @property
    def n_tissues(self) -> int:
        return int(self.tissue_of_class.max()) + 1 if self.tissue_of_class.size else 0

    @cached_property
    def voxels(self) -> np.ndarray:
        """``(n_classes,)`` voxels per class, as floats (the roles' and looks' shares are sums of them)."""
        return np.array([c.voxels for c in self.classes], dtype=np.float64)

    @cached_property
    def rim_in_the_open(self) -> bool:
        """Whether the rim holds structures of its own: a real share of the objects' voxels
        (:attr:`.LookRules.real_share` of those not background or fog) lying in the open, along lines
        (:attr:`.LookRules.line_fill`), not as the skin of a body (False without a preview: nothing measured). Measured
        once: the first click and the thin-structures look both ask."""
        rim, objects = self.of_role("rim"), ~self.of_role("background", "fog")
        if self.preview is None or self.voxels[rim].sum() < self.rules.real_share * max(self.voxels[objects].sum(), 1):
            return False
        return surroundings_fill(self.preview, rim[self.labels], objects[self.labels]) < self.rules.line_fill

    @cached_property
    def densest(self) -> np.ndarray:
        """``(n_classes,)`` the dense classes of a second, denser material inside the dense parts: the dense rule
        (:func:`.roles.dense_classes`) applied among the dense classes, its main material placed among them, where
        they lie in tissues apart from the largest dense class's (the brightest classes of its own tissue are the top
        of its spread: a brain's brightest white matter, drawn as speckle) and hold a real share of the voxels
        (:attr:`.LookRules.real_share`, as a structure must). On data that are not CT-like the dense parts look shows
        the dense classes alone, one surface, and where they hold two materials the outer one hides the other: an
        abdominal CT exported through a window reads as an MRI (its fat is the largest tissue, the organs above it
        dense), and its dense parts are the organs around the bone."""
        dense = self.of_role("dense")
        densest = np.zeros(len(self.classes), dtype=bool)
        if not dense.any():
            return densest
        width = noise_width(self.kind, self.noise_sd, self.voxel_noise_sd)
        ids = dense_classes(self.classes, self.tissue_of_class, self.class_bins, width, self.rules, among=dense)
        densest[ids] = True
        largest = int(np.argmax(np.where(dense, self.voxels, -1.0)))
        densest &= self.tissue_of_class != self.tissue_of_class[largest]
        if self.voxels[densest].sum() < self.rules.real_share * self.voxels[~self.of_role("background")].sum():
            densest[:] = False  # stray voxels, not a material
        return densest

    @property
    def fog_sd(self) -> float:
        """The width, in bins, fog is decided in (:func:`.roles.fog_width`)."""
        return fog_width(self.kind, self.noise_sd, self.voxel_noise_sd, self.constant_background)


@dataclass(frozen=True)
class GalleryLook:
    """One look of the gallery.

    Attributes:
        name: lowercase letters and hyphens (:data:`LOOK_NAMES`). title: for buttons. objective: what it promises.
        colors: ``[r, g, b]`` per class in 0..1. opacities: opacity per unit distance per class. visible: per class.
        promise: ``{roles: (low, high)}``: the share of the picture the classes of ``roles`` (a ``"|"``-joined
            string of :data:`.roles.ROLES`) give lies in ``[low, high]``.
        kept: ``{roles: minimum}``: the shown classes of ``roles`` keep at least this share of the light they give
            rendered alone (seen through what is in front of them).
        monotone: whether opacity rises with intensity among the shown classes.
        class_shares: ``(n_classes,)`` share of the picture each class gives, or None without a preview.
    """

    name: str
    title: str
    objective: str
    colors: list[list[float]]
    opacities: list[float]
    visible: list[bool]
    promise: dict[str, tuple[float, float]]
    kept: dict[str, float]
    monotone: bool
    class_shares: Optional[np.ndarray] = None

    def role_shares(self, roles: Sequence[str]) -> dict[str, float]:
        """Share of the picture each role gives (empty without a preview)."""
        if self.class_shares is None:
            return {}
        role_array = np.array(roles, dtype=object)
        return {role: float(self.class_shares[role_array == role].sum()) for role in sorted(set(roles))}

    def summary(self, roles: Sequence[str]) -> dict:
        """The look as ``classes.json`` lists it: name, title, objective, promise and measured shares."""
        return {
            "name": self.name,
            "title": self.title,
            "objective": self.objective,
            "promise": {k: list(v) for k, v in self.promise.items()},
            "kept": dict(self.kept),
            "role_shares": self.role_shares(roles),
        }

    def same_picture(self, other: "GalleryLook") -> bool:
        """Whether both looks give the same transfer function."""
        return (
            self.visible == other.visible
            and np.allclose(np.where(self.visible, self.opacities, 0.0), np.where(other.visible, other.opacities, 0.0))
            and np.allclose(
                np.array(self.colors)[np.array(self.visible, dtype=bool)],
                np.array(other.colors)[np.array(other.visible, dtype=bool)],
            )
        )


def first_look_name(context: LookContext) -> str:
    """The first click's look: ``thin-structures`` for thin structures alone in an empty field of view (a vessel tree
    exported with 95-99 % zeros: most of the objects' voxels are rim, and they fill at most
    :attr:`.LookRules.thin_foreground` of the volume), and on data that are not CT-like where the rim lies along lines
    in the open (:attr:`LookContext.rim_in_the_open`: a plant's twigs, which the outer surface clears as if they were
    a skin); else ``dense-parts`` on CT-like data and ``outer-surface``."""
    if is_thin(context) or (context.kind != "ct" and context.rim_in_the_open):
        return "thin-structures"
    return "dense-parts" if context.kind == "ct" else "outer-surface"


def is_thin(context: LookContext) -> bool:
    """Whether the volume holds thin structures alone: :attr:`.LookRules.thin_rim_share` of the non-background,
    non-fog voxels are rim, and those voxels are at most :attr:`.LookRules.thin_foreground` of all."""
    voxels = context.voxels
    foreground = ~context.of_role("background", "fog")
    total = voxels.sum()
    objects = voxels[foreground].sum()
    if total <= 0 or objects <= 0:
        return False
    rim = voxels[context.of_role("rim")].sum()
    return bool(rim >= context.rules.thin_rim_share * objects and objects <= context.rules.thin_foreground * total)


def gallery(context: LookContext) -> list[GalleryLook]:
    """Every look the data support, the first click first, no two with the same transfer function. A look is
    supported where its roles exist and, measured on the preview, it keeps its promised shares (the first click is
    always offered)."""
    first = first_look_name(context)
    looks: list[GalleryLook] = []
    for name in (first, *(n for n in LOOK_NAMES if n != first)):
        look = make_look(name, context)
        if look is None or any(look.same_picture(earlier) for earlier in looks):
            continue
        if name == first or not broken_shares(look, context.roles):
            looks.append(look)
    return looks


def broken_shares(look: GalleryLook, roles: Sequence[str]) -> list[str]:
    """The promised shares (:attr:`GalleryLook.promise`) that ``look`` misses, as measured when it was made."""
    if look.class_shares is None:
        return []
    role_array = np.array(roles, dtype=object)
    broken = []
    for key, (low, high) in look.promise.items():
        share = float(look.class_shares[np.isin(role_array, key.split("|"))].sum())
        if not _kept_within(share, low, high):
            broken.append(key)
    return broken


def _kept_within(share: float, low: float, high: float) -> bool:
    """Whether a measured share keeps a promise ``[low, high]``: shares are sums of floats, and a picture all of
    whose light one role gives sums to 1 + 2e-16 (the dense parts of a housing, promised ``(0.9, 1.0)``)."""
    return low - _SHARE_ROUNDING <= share <= high + _SHARE_ROUNDING


def make_look(name: str, context: LookContext) -> Optional[GalleryLook]:
    """The look ``name`` (one of :data:`LOOK_NAMES`), or None where the data do not support it."""
    if name not in _MAKERS:
        raise ValueError(f"no look {name!r}; looks are {', '.join(LOOK_NAMES)}")
    made = _made(context, name)
    if made is None:
        return None
    colors, opacities, visible = made
    visible = [bool(v) and role not in ("background", "fog") for v, role in zip(visible, context.roles)]
    title, objective, promise, kept, monotone = _DESCRIPTIONS[name](context.rules)
    return GalleryLook(
        name=name,
        title=title,
        objective=objective,
        colors=[[float(v) for v in c] for c in colors],
        opacities=[float(a) for a in opacities],
        visible=visible,
        promise=promise,
        kept=kept,
        monotone=monotone,
        class_shares=class_shares(context, opacities, visible),
    )


def class_shares(context: LookContext, opacities: Sequence[float], visible: Sequence[bool]) -> Optional[np.ndarray]:
    """``(n_classes,)`` share of the preview's picture each class gives (the transfer function the design writes:
    :func:`.look.bin_opacity_of`); None without a preview; zeros for an empty picture."""
    if context.preview is None:
        return None
    per_class = _light(context, np.asarray(opacities, dtype=np.float64), np.asarray(visible, dtype=bool))
    total = per_class.sum()
    return per_class / total if total > 0 else per_class


def _bin_opacity(context: LookContext, opacities: Sequence[float], visible: Sequence[bool]) -> np.ndarray:
    shown = np.where(np.asarray(visible, dtype=bool), np.asarray(opacities, dtype=np.float64), 0.0)
    return bin_opacity_of(shown, context.labels, context.noise_sd)


# The looks -----------------------------------------------------------------------------------------------------------
Made = Optional[tuple[list[list[float]], list[float], list[bool]]]


def _default(context: LookContext, kind: str) -> Made:
    """:func:`.look.default_look` of ``kind`` (made once per context; only ``"ct"`` differs from the others), as
    fresh lists the caller may change."""
    key = "ct" if kind == "ct" else "other"
    if key not in context._defaults:
        context._defaults[key] = default_look(
            list(context.classes),
            context.tissue_of_class,
            context.class_values,
            kind,
            labels=context.labels,
            class_bins=context.class_bins,
            noise_sd=context.noise_sd,
            fog_sd=context.fog_sd,
            preview=context.preview,
            colors=context.colors,
            max_classes=context.max_classes,
            dense_classes=context.of_role("dense"),
            fog_classes=context.of_role("fog"),
            rules=context.rules,
        )
    look = context._defaults[key]
    return [list(c) for c in look.colors], list(look.opacities), list(look.visible)


def _dense_parts(context: LookContext) -> Made:
    """The dense classes as surfaces. On CT-like data it starts from :func:`.look.default_look`'s dense tail (the
    first click there), with the dense classes the default hides below it on the ramp up to it (:func:`_dense_ramp`),
    and everything else shown is made clearer until the dense classes keep ``rules.seen`` of their light and give
    ``rules.dense_share`` of the picture: the soft tissue stays a faint veil around the bone, as
    CT-Bone draws it. On other data the dense classes are shown alone, raised to the ramp's top (a bright lesion
    inside a FLAIR brain, the enhancing vessels of a contrast T1): a structure of its own, as MR-Angio draws it, which
    a veil of brain around it would only hide; the other classes keep their outer-surface opacities, hidden."""
    dense = context.of_role("dense")
    if context.kind != "ct":
        return _alone_at_the_top(context, dense) if dense.any() else None
    colors, opacities, visible = _default(context, "ct")
    if context.preview is None or not dense.any():
        return colors, opacities, visible
    opacities = _dense_ramp(context, np.asarray(opacities, dtype=np.float64), np.asarray(visible, dtype=bool))
    cleared = _cleared_around(context, dense, opacities, visible, context.rules.dense_share, context.rules.seen)
    if cleared is None:  # the dense classes are not in the preview
        return colors, list(opacities), list(np.asarray(visible) | dense)
    return (colors, *cleared)


def _densest_parts(context: LookContext) -> Made:
    """The densest of two dense materials alone (:attr:`LookContext.densest`), raised to the ramp's top as the dense
    parts look shows the dense classes on data that are not CT-like; None on CT-like data, whose dense parts look
    already draws the denser material brighter on the ramp by value, or where the dense classes are one material."""
    if context.kind == "ct":
        return None
    densest = context.densest
    if not densest.any() or np.array_equal(densest, context.of_role("dense")):
        return None
    return _alone_at_the_top(context, densest)


def _alone_at_the_top(context: LookContext, shown: np.ndarray) -> Made:
    """The classes of ``shown`` (``(n_classes,)`` bool) alone, raised to the ramp's top; every other class keeps the
    outer surface's opacity, hidden (what a user who shows it starts from)."""
    colors, opacities, _ = _default(context, context.kind)
    return colors, list(np.where(shown, np.maximum(opacities, context.rules.opacity_high), opacities)), list(shown)


def _dense_ramp(context: LookContext, opacities: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """``(n_classes,)`` opacities with the dense classes the default look hides (grouped with the fog or the rim
    below the dense tail: a plume's fringe, a bone's partial volume) on the presets' monotone ramp, by mean bin:
    from :attr:`.LookRules.opacity_low` at the lowest of them up to the opacity of the lowest dense class shown (the
    tail's start), and between the shown ones above it. A shell that thickens the dense parts as it nears their
    value, not a halo at the opacity a user who shows their tissue starts from."""
    dense = context.of_role("dense")
    hidden, shown = dense & ~visible, dense & visible
    if not hidden.any() or not shown.any():
        return opacities
    bins = np.asarray(context.class_bins, dtype=np.float64)
    order = np.argsort(bins[shown], kind="stable")
    anchor_bins, anchor_opacities = bins[shown][order], opacities[shown][order]
    low = bins[hidden].min()
    if low < anchor_bins[0]:
        anchor_bins = np.concatenate(([low], anchor_bins))
        anchor_opacities = np.concatenate(([min(context.rules.opacity_low, anchor_opacities[0])], anchor_opacities))
    return np.where(hidden, np.interp(bins, anchor_bins, anchor_opacities), opacities)


def _cleared_around(
    context: LookContext,
    target: np.ndarray,
    opacities: np.ndarray,
    visible: Sequence[bool],
    share_aimed: float,
    kept_aimed: float,
) -> Optional[tuple[list[float], list[bool]]]:
    """The ``target`` classes (a ``(n_classes,)`` mask) shown, every other shown class made clearer by one factor
    until the target keeps ``kept_aimed`` of its own light (0: not asked) and gives ``share_aimed`` of the picture,
    the aim that binds reached within ``2 * _SHARE_MARGIN`` (Ma & Entezari's visibility loop, turned round: the
    target is at the top already). None when the target sends no light in the preview."""
    opacities = np.asarray(opacities, dtype=np.float64)
    visible = np.asarray(visible, dtype=bool) | target
    alone = _light(context, opacities, target)[target].sum()
    if alone <= 0:
        return None
    others = visible & ~target

    def measured(log_factor: float) -> tuple[float, float]:
        """The target's share of the picture and the share of its own light it keeps, with the others' opacities
        scaled by ``exp(log_factor)``."""
        light = _light(context, np.where(others, opacities * np.exp(log_factor), opacities), visible)
        return light[target].sum() / max(light.sum(), 1e-300), light[target].sum() / alone

    def off_aim(share: float, kept: float) -> float:
        """How far the binding aim lies above its aim plus the margin, the search's aim (negative: short of it)."""
        above = min(share - share_aimed, kept - kept_aimed) if kept_aimed > 0 else share - share_aimed
        return above - _SHARE_MARGIN

    share, kept = measured(0.0)
    start = off_aim(share, kept)
    if start >= -_SHARE_MARGIN or not others.any():
        return list(opacities), list(visible)
    # The first step assumes what lies in front passes about T of the light, T ** s once its opacity is scaled by s,
    # and that a thin haze's own light scales as s. Opaque surfaces fall short of it; a bracketed search goes on.
    aim = min(share_aimed + _SHARE_MARGIN, 1.0 - 1e-6)
    factor = (share / max(1.0 - share, 1e-12)) * (1.0 - aim) / aim
    if kept_aimed > 0:
        factor = min(factor, np.log(kept_aimed) / np.log(min(max(kept, 1e-12), kept_aimed)))
    first, far = float(np.log(np.clip(factor, _LOWEST_FACTOR, 1.0))), float(np.log(_LOWEST_FACTOR))
    points = [(0.0, start), (first, off_aim(*measured(first)))]
    if points[-1][1] < -_SHARE_MARGIN:  # short of the aims: bracket them with the far end, the others all but gone
        points.append((far, off_aim(*measured(far))))
    points = _bracketed_search(
        lambda x: off_aim(*measured(x)), points, _CLEARING_ROUNDS, lambda f: abs(f) <= _SHARE_MARGIN
    )
    reached = [x for x, f in points if f >= -_SHARE_MARGIN]
    # The least clearing that reaches the aims; where none does, the nearest to them.
    best = max(reached) if reached else max(points, key=lambda p: p[1])[0]
    return list(np.where(others, opacities * np.exp(best), opacities)), list(visible)


def _bracketed_search(
    f: Callable[[float], float], points: list[tuple[float, float]], rounds: int, done: Callable[[float], bool]
) -> list[tuple[float, float]]:
    """``points`` (``(x, f(x))``, the search's start) extended by at most ``rounds`` evaluations of the monotone
    ``f`` in the tightest bracket of its root they hold: regula falsi, bisecting after two steps that landed on
    one side (``f`` may be flat at one end, as a picture's shares are where opaque surfaces are scaled, and regula
    falsi then creeps). It stops at the first ``done(f(x))``, or when the points do not bracket a root."""
    points = list(points)
    given = len(points)
    for _ in range(rounds):
        if any(done(fx) for _, fx in points):
            break
        below = [p for p in points if p[1] < 0]
        above = [p for p in points if p[1] > 0]
        if not below or not above:
            break
        (x0, f0), (x1, f1) = max(below, key=lambda p: p[1]), min(above, key=lambda p: p[1])
        creeping = len(points) - given >= 2 and (points[-1][1] > 0) == (points[-2][1] > 0)
        x = 0.5 * (x0 + x1) if creeping else x0 - f0 * (x1 - x0) / (f1 - f0)
        points.append((x, f(x)))
    return points


def _made(context: LookContext, name: str) -> Made:
    """The colours, opacities and visibility of the look ``name`` (made once per context), as fresh lists."""
    if name not in context._made:
        context._made[name] = _MAKERS[name](context)
    made = context._made[name]
    return None if made is None else ([list(c) for c in made[0]], list(made[1]), list(made[2]))


def _light(context: LookContext, opacities: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """``(n_classes,)`` light each class sends to the eye (the preview's six views)."""
    bin_opacity = _bin_opacity(context, opacities, visible)
    key = bin_opacity.tobytes()
    if key not in context._renders:
        light = visibility_histogram(context.preview, bin_opacity)
        context._renders[key] = np.bincount(context.labels, weights=light, minlength=len(context.classes))
    return context._renders[key]


def _outer_surface(context: LookContext) -> Made:
    # On CT-like data the surface look keeps the CT's per-class colours: one look of the same data.
    return _default(context, "mr" if context.kind == "ct" else context.kind)


def _see_through(context: LookContext) -> Made:
    dense, bulk = context.of_role("dense"), context.of_role("bulk")
    if context.preview is None or not dense.any() or not bulk.any():
        return None
    start = _made(context, "dense-parts")
    if start is None:
        return None
    colors, opacities, visible = start
    # The dense parts as surfaces (at least the ramp's top), the bulk around them at the share searched below.
    opacities = np.where(dense, np.maximum(opacities, context.rules.opacity_high), opacities)
    visible = np.array(visible) | bulk | dense
    low, high = context.rules.see_through
    target = 0.5 * (low + high)

    def bulk_share(log_opacity: float) -> float:
        trial = np.where(bulk, np.exp(log_opacity), opacities)
        shares = class_shares(context, trial, visible)
        return float(shares[bulk].sum())

    # The bulk's share rises with its opacity: a secant search in log opacity, from the ramp's two ends.
    points = [(np.log(context.rules.opacity_low), None), (np.log(context.rules.opacity_high), None)]
    points = [(x, bulk_share(x) - target) for x, _ in points]
    for _ in range(_SEE_THROUGH_ROUNDS):
        (x0, f0), (x1, f1) = points[-2:]
        if abs(f1) < 0.01 or f1 == f0:
            break
        x2 = float(np.clip(x1 - f1 * (x1 - x0) / (f1 - f0), np.log(1e-5), 0.0))
        points.append((x2, bulk_share(x2) - target))
    best = min(points, key=lambda p: abs(p[1]))[0]
    opacities = np.where(bulk, np.exp(best), opacities)
    return colors, list(opacities), list(visible)


def _thin_structures(context: LookContext) -> Made:
    """The rim as structure (from ``rules.thin_opacity`` at its lowest class up to the densest shown opacity, by
    intensity, in the densest shown class's colour) over the default look, everything else made clearer until the
    rim gives ``rules.thin_share`` of the picture (:func:`_cleared_around`): twigs are thin and sparse, and a pot
    left as the default look has it takes the picture of them. Made for thin structures alone (:func:`is_thin`), or
    beside other objects where the rim lies in the open (:attr:`LookContext.rim_in_the_open`), not as a surface's
    skin."""
    if not is_thin(context) and not context.rim_in_the_open:
        return None
    rim = context.of_role("rim")
    colors, opacities, visible = _default(context, context.kind)
    opacities = np.asarray(opacities, dtype=np.float64)
    # The rim as structure: from thin_opacity at its lowest class up to the densest shown opacity, by intensity.
    order = np.argsort(context.class_bins[rim])
    top = max(float(opacities[np.array(visible, dtype=bool)].max(initial=0.0)), context.rules.thin_opacity)
    ramp = np.linspace(context.rules.thin_opacity, top, max(int(rim.sum()), 1))
    rim_ids = np.flatnonzero(rim)[order]
    opacities[rim_ids] = np.maximum(opacities[rim_ids], ramp)
    visible = np.array(visible) | rim
    # Shown as structure, the rim takes the structure's colour (the densest shown class's): the ramp's low end would
    # draw small vessels and twigs as the dim skin of something else.
    densest = int(np.flatnonzero(visible)[np.argmax(context.class_bins[visible])])
    colors = [list(colors[densest]) if is_rim else color for color, is_rim in zip(colors, rim)]
    if context.preview is not None:
        cleared = _cleared_around(context, rim, opacities, visible, context.rules.thin_share, 0.0)
        if cleared is not None:
            return (colors, *cleared)
    return colors, list(opacities), list(visible)


def _all_tissues(context: LookContext) -> Made:
    if context.n_tissues - 1 < 2:
        return None
    return _monotone(context, by_class=False)


def _classes(context: LookContext) -> Made:
    if len(context.classes) - 1 < 2:
        return None
    return _monotone(context, by_class=True)


def _monotone(context: LookContext, by_class: bool) -> Made:
    """Every class shown but the background and fog, opacity on the presets' ramp by rank of intensity (of its
    tissue, or of the class itself); colours along the intensity ramp, or one palette colour per class."""
    shown = ~context.of_role("background", "fog")
    group = np.arange(len(context.classes)) if by_class else np.asarray(context.tissue_of_class)
    groups = sorted(set(group[shown].tolist()), key=lambda g: context.class_bins[group == g].mean())
    rank = {g: i for i, g in enumerate(groups)}
    low, high = context.rules.opacity_low, context.rules.opacity_high
    opacities = [
        low + (high - low) * rank[group[c]] / max(len(groups) - 1, 1) if shown[c] else 0.0
        for c in range(len(context.classes))
    ]
    if by_class:
        by_size = sorted(np.flatnonzero(shown), key=lambda c: (-context.classes[c].voxels, c))
        colors = [list(BACKGROUND_GREY) for _ in context.classes]
        for i, c in enumerate(by_size):
            colors[c] = list(PALETTE[i % len(PALETTE)])
    else:
        colors = _default(context, "mr")[0]
    return colors, opacities, list(shown)


_MAKERS: dict[str, Callable[[LookContext], Made]] = {
    "dense-parts": _dense_parts,
    "densest-parts": _densest_parts,
    "outer-surface": _outer_surface,
    "see-through": _see_through,
    "thin-structures": _thin_structures,
    "all-tissues": _all_tissues,
    "classes": _classes,
}

# name: (title, objective, promised shares, kept light, monotone opacity).
_DESCRIPTIONS: dict[str, Callable[[LookRules], tuple[str, str, dict, dict, bool]]] = {
    "dense-parts": lambda r: (
        "Dense parts",
        "the dense parts inside, what encloses them cleared",
        {"dense": (r.dense_share, 1.0)},
        {"dense": r.seen},
        False,
    ),
    # Promises nothing a share can check: it shows dense classes alone, so their share is always 1.
    "densest-parts": lambda r: ("Densest parts", "the densest of two dense materials alone", {}, {}, False),
    # Promises nothing a share can check: every class it shows is rim, bulk or dense, so such a share is always 1.
    "outer-surface": lambda r: ("Outer surface", "the tissue met first, as a surface", {}, {}, False),
    "see-through": lambda r: (
        "See-through",
        "the dense parts seen through the bulk around them",
        {"bulk": r.see_through},
        {},
        False,
    ),
    "thin-structures": lambda r: (
        "Thin structures",
        "partial volume shown as structure: small vessels, branches",
        {"rim": (r.thin_share, 1.0)},
        {},
        False,
    ),
    "all-tissues": lambda r: ("All tissues", "every tissue, on the presets' monotone ramp", {}, {}, True),
    "classes": lambda r: ("Classes", "one colour per class (the thesis)", {}, {}, True),
}


def check_look(context: LookContext, look: GalleryLook) -> list[str]:
    """What ``look`` fails of its promise, measured with an independent ray caster; empty when it keeps it.

    Checked: every promised share (:attr:`GalleryLook.promise`); opacity rising with intensity among the shown
    classes where promised; fog and background never shown; the densest real tissue shown.
    """
    failures = []
    visible = np.asarray(look.visible, dtype=bool)
    roles = np.array(context.roles, dtype=object)
    if context.preview is not None:

        def light_of(opacities: np.ndarray, shown: np.ndarray) -> np.ndarray:
            bin_opacity = _bin_opacity(context, opacities, shown)
            light = ray_visibility(context.preview, bin_opacity, unit_distance=context.preview.unit_distance)
            return np.bincount(context.labels, weights=light, minlength=len(context.classes))

        per_class = light_of(look.opacities, visible)
        total = per_class.sum()
        for key, (low, high) in look.promise.items():
            share = float(per_class[np.isin(roles, key.split("|"))].sum() / total) if total > 0 else 0.0
            if not _kept_within(share, low, high):
                failures.append(f"{look.name}: {key} gives {share:.2f} of the picture, promised {low:g}..{high:g}")
        for key, minimum in look.kept.items():
            members = np.isin(roles, key.split("|")) & visible
            alone = light_of(look.opacities, members)[members].sum()
            kept = float(per_class[members].sum() / alone) if alone > 0 else 1.0
            if kept < minimum - _KEPT_TOLERANCE:
                failures.append(f"{look.name}: {key} keeps {kept:.2f} of its own light, promised {minimum:g}")
    if look.monotone:
        shown = np.flatnonzero(visible)
        by_intensity = shown[np.argsort(context.class_bins[shown], kind="stable")]
        if np.any(np.diff(np.asarray(look.opacities)[by_intensity]) < -1e-12):
            failures.append(f"{look.name}: opacity does not rise with intensity among the shown classes")
    if np.any(visible & np.isin(roles, ("background", "fog"))):
        failures.append(f"{look.name}: background or fog shown")
    densest = _densest_real_tissue(context)
    if densest is not None and not visible[np.asarray(context.tissue_of_class) == densest].any():
        failures.append(f"{look.name}: the densest real tissue ({densest}) is not shown")
    return failures


def _densest_real_tissue(context: LookContext) -> Optional[int]:
    """The densest tissue holding ``rules.real_share`` of the non-background voxels (as :func:`.look.default_look`
    counts them), or None."""
    tissue_of_class = np.asarray(context.tissue_of_class)
    real = np.unique(tissue_of_class[in_real_tissue(context.classes, tissue_of_class, context.rules)])
    if real.size == 0:
        return None
    means = tissue_mean_bins(context.tissue_of_class, context.voxels, context.class_bins, context.n_tissues)
    return int(real[int(np.argmax(means[real]))])
