"""The whole pipeline: volume in, classes and transfer function out, editable class by class without recomputing."""

import base64
import json
import time
import zlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from typing import Callable, Optional, Union

import numpy as np

from .classes import IsovalueClass, _flag, _unit_number, build_classes, planes_read, runs, voxel_noise_sd
from .clustering import FALLBACK_DAMPINGS, ClusteringResult, cluster_isovalues, unconverged_advice
from .errors import ClusteringError
from .gallery import GalleryLook, LookContext, check_look, first_look_name, gallery, make_look
from .look import bin_opacity_of, class_mean_values, detect_kind, gradient_ramp_top
from .memory import check_memory
from .options import DEFAULT_OPTIONS, KINDS, LOOK_NAMES, OPTIONS, check_options
from .quantize import (
    Quantization,
    bin_volume,
    bins_dtype,
    checked_n_bins,
    resolved_value_range,
    value_lattice,
    values_per_bin,
)
from .roles import is_constant_background
from .similarity import IsovalueSimilarity, isovalue_similarity
from .source import VolumeSource
from .survey import checked_data_range, survey_volume
from .taps import SlabTap
from .thumbnails import render_thumbnail
from .tissues import TissueHierarchy, tissue_hierarchy
from .transfer_function import (
    TransferFunctionPoints,
    fill_volume_property,
    new_volume_property,
    piecewise_constant,
    write_vp,
    write_vp_json,
)
from .value_range import RobustRange, robust_value_range
from .visibility import PREVIEW_VOXELS, Preview, enclosure, preview_steps

StageProgress = Callable[[str, float, str], None]

#: Affinity propagation reports progress after about this many message updates (a few milliseconds of work).
_PROGRESS_ENTRIES = 2_000_000
#: The engine's stages, in order: the keys of ``timings_s`` and the ``stage`` given to ``progress``.
STAGES = ("quantize", "similarity", "clustering", "classes", "tissues")


@dataclass
class Tissue:
    """A run of classes, contiguous in intensity, shown as one tissue.

    Attributes:
        id: tissue id, 0 for the lowest intensity, increasing.
        classes: member class ids, in intensity order.
        voxels: voxels in the member classes.
        value_ranges: ``[low, high]`` in volume units for each run of consecutive bins of the members.
        color: ``[r, g, b]`` in 0..1 (the members' colour after a tissue edit or by default).
        opacity: opacity per mm when shown.
        visible: whether the tissue is shown.
        background: whether the tissue is the background class alone.
        picture_share: share of the default look's picture this tissue gives (see :mod:`.visibility`), or None.
    """

    id: int
    classes: list[int]
    voxels: int
    value_ranges: list[list[float]]
    color: list[float]
    opacity: float
    visible: bool
    background: bool = False
    picture_share: Optional[float] = None

    def to_dict(self) -> dict:
        return {
            "id": self.id,
            "classes": list(self.classes),
            "voxels": self.voxels,
            "value_ranges": [list(r) for r in self.value_ranges],
            "color": list(self.color),
            "opacity": self.opacity,
            "visible": self.visible,
            "background": self.background,
            "picture_share": self.picture_share,
        }

    @classmethod
    def from_dict(cls, data: dict) -> "Tissue":
        return cls(
            id=int(data["id"]),
            classes=[int(c) for c in data["classes"]],
            voxels=int(data["voxels"]),
            value_ranges=[[float(lo), float(hi)] for lo, hi in data["value_ranges"]],
            color=[_unit_number(c, "color") for c in data["color"]],
            opacity=_unit_number(data["opacity"], "opacity"),
            visible=_flag(data["visible"], "visible"),
            background=_flag(data.get("background", False), "background"),
            picture_share=None if data.get("picture_share") is None else float(data["picture_share"]),
        )


@dataclass
class TransferFunctionDesign:
    """An automatic transfer function: the classes found in a volume, their tissues and how each one looks.

    Editing (:meth:`set_class`, :meth:`set_tissue`, :meth:`solo`, :meth:`solo_tissue`, :meth:`show_all`,
    :meth:`reset_look`, :meth:`regroup`) changes only the look or the grouping; the transfer function is derived from
    the classes each time it is asked for. A tissue edit writes through to its classes.

    Attributes:
        value_range: ``(low, high)`` of the isovalue bins, in volume units.
        n_bins: number of isovalue bins.
        labels: ``(n_bins,)`` class id per bin.
        classes: the classes, in id order (id 0 = lowest exemplar intensity).
        options: the options the design was made with.
        clustering: ``n_iter``, ``converged``, ``n_classes`` and ``preference`` of affinity propagation, and the run
            kept: its ``damping``, iteration limits and whether it was on the distinct isovalues (``distinct``).
        bin_voxels: ``(n_bins,)`` voxels per bin (the volume's histogram).
        hierarchy: every grouping of the non-background classes into tissues (see :mod:`.tissues`).
        kind: ``"ct"``, ``"mr"`` or ``"8bit"`` (see :func:`.look.detect_kind`); chooses the colours.
        tissues: the current tissues, in id order (id 0 = lowest intensity).
        timings_s: seconds per stage.
        spacing: voxel spacing in mm, or None.
        solo_class: id of the class shown alone, or None.
        solo_tissue_id: id of the tissue shown alone, or None.
        similarity: ``(n_bins, n_bins)`` similarity matrix (not serialized), or None after loading.
        preview: the low-resolution volume the look's visibility step renders (see :mod:`.visibility`), or None.
        unit_distance: scalar opacity unit distance in mm: the preview's (:attr:`.visibility.Preview.unit_distance`,
            from the volume's extent), so the picture does not change with the voxel size; 1 (per mm, as Slicer's
            presets) for a design saved before it followed the volume.
        look_name: the look of the gallery chosen with :meth:`use_look` (None: the first click's); a regrouping
            keeps it.
        robust_range: what the default value range of the run that made the design left out (padding, outliers;
            see :mod:`.value_range`), or None (a range was given; not serialized): :meth:`range_warning` says it.
        voxel_noise_sd: the voxels' noise in bins (:func:`.classes.voxel_noise_sd`), or None for a design saved
            before it was measured (the dense classes then count in the intensity model's width).
    """

    value_range: tuple[float, float]
    n_bins: int
    labels: np.ndarray
    classes: list[IsovalueClass]
    options: dict
    clustering: dict
    bin_voxels: np.ndarray
    hierarchy: TissueHierarchy
    kind: str = "mr"
    tissues: list[Tissue] = field(default_factory=list)
    timings_s: dict[str, float] = field(default_factory=dict)
    spacing: Optional[tuple[float, float, float]] = None
    solo_class: Optional[int] = None
    solo_tissue_id: Optional[int] = None
    similarity: Optional[np.ndarray] = field(default=None, repr=False)
    preview: Optional[Preview] = field(default=None, repr=False)
    unit_distance: float = 1.0
    look_name: Optional[str] = None
    robust_range: Optional[RobustRange] = field(default=None, repr=False, compare=False)
    voxel_noise_sd: Optional[float] = None
    _gallery: Optional[list[GalleryLook]] = field(default=None, init=False, repr=False, compare=False)
    # The current grouping's look context (see look_context): the gallery reuses the renders its first look needed.
    _context: Optional[LookContext] = field(default=None, init=False, repr=False, compare=False)

    @property
    def edges(self) -> np.ndarray:
        """Bin edges in volume units, ``(n_bins + 1,)``."""
        return np.linspace(self.value_range[0], self.value_range[1], self.n_bins + 1)

    @property
    def background_class(self) -> Optional[IsovalueClass]:
        return next((c for c in self.classes if c.background), None)

    def class_by_id(self, class_id: int) -> IsovalueClass:
        if isinstance(class_id, bool) or not isinstance(class_id, (int, np.integer)):
            raise KeyError(f"a class id is an integer; got {class_id!r}")  # True would be class 1
        if not 0 <= class_id < len(self.classes):
            raise KeyError(f"no class {class_id}; classes are 0 to {len(self.classes) - 1}")
        return self.classes[class_id]

    def tissue_by_id(self, tissue_id: int) -> Tissue:
        if isinstance(tissue_id, bool) or not isinstance(tissue_id, (int, np.integer)):
            raise KeyError(f"a tissue id is an integer; got {tissue_id!r}")  # True would be tissue 1
        if not 0 <= tissue_id < len(self.tissues):
            raise KeyError(f"no tissue {tissue_id}; tissues are 0 to {len(self.tissues) - 1}")
        return self.tissues[tissue_id]

    @property
    def tissue_of_class(self) -> np.ndarray:
        """``(n_classes,)`` tissue id of each class."""
        of = np.zeros(len(self.classes), dtype=np.intp)
        for t in self.tissues:
            of[t.classes] = t.id
        return of

    def is_shown(self, class_id: int) -> bool:
        """Whether the class appears in the transfer function (solo overrides the visible flags)."""
        if self.solo_class is not None:
            return class_id == self.solo_class
        if self.solo_tissue_id is not None:
            return class_id in self.tissue_by_id(self.solo_tissue_id).classes
        return self.class_by_id(class_id).visible

    # Grouping ------------------------------------------------------------------------------------------------------
    @property
    def n_tissues(self) -> int:
        """Number of non-background tissues."""
        return sum(not t.background for t in self.tissues)

    def regroup(self, tissues: Union[int, str] = "auto") -> None:
        """Group the classes into ``tissues`` non-background tissues (``"auto"``: the intensity model's count,
        ``"all"``: one per class, the thesis), instantly, and give them the default look. Leaves solo mode."""
        n = _tissue_count(tissues, self.hierarchy)
        self.options["tissues"] = tissues if isinstance(tissues, str) else int(tissues)  # rerunning reproduces it
        background = self.background_class
        groups = self.hierarchy.groups(n) if self.hierarchy.order else []
        if background is not None:
            groups.append([background.id])
        groups.sort(key=lambda members: self.classes[members[0]].exemplar_bin)
        edges = self.edges
        self.tissues = []
        for tissue_id, members in enumerate(groups):
            bins = np.flatnonzero(np.isin(self.labels, members))
            self.tissues.append(
                Tissue(
                    id=tissue_id,
                    classes=[int(c) for c in members],
                    voxels=int(sum(self.classes[c].voxels for c in members)),
                    value_ranges=[[float(edges[a]), float(edges[b + 1])] for a, b in runs(bins)],
                    color=[0.5, 0.5, 0.5],
                    opacity=0.0,
                    visible=False,
                    background=background is not None and members == [background.id],
                )
            )
        self.solo_class = self.solo_tissue_id = None
        self.reset_look()

    # Editing -------------------------------------------------------------------------------------------------------
    def set_class(
        self,
        class_id: int,
        *,
        color: Optional[Sequence[float]] = None,
        opacity: Optional[float] = None,
        visible: Optional[bool] = None,
    ) -> None:
        """Change one class's colour (``[r, g, b]`` in 0..1), opacity (0..1, per mm) or visibility."""
        _apply_edit(self.class_by_id(class_id), color, opacity, visible)

    def set_tissue(
        self,
        tissue_id: int,
        *,
        color: Optional[Sequence[float]] = None,
        opacity: Optional[float] = None,
        visible: Optional[bool] = None,
    ) -> None:
        """Change a tissue's colour, opacity or visibility, and the same on every class of the tissue."""
        tissue = self.tissue_by_id(tissue_id)
        _apply_edit(tissue, color, opacity, visible)
        for class_id in tissue.classes:
            _apply_edit(self.classes[class_id], color, opacity, visible)

    def solo(self, class_id: Optional[int]) -> None:
        """Show only this class (None: back to each class's own visibility)."""
        if class_id is not None:
            self.class_by_id(class_id)
        self.solo_class, self.solo_tissue_id = class_id, None

    def solo_tissue(self, tissue_id: Optional[int]) -> None:
        """Show only this tissue (None: back to each class's own visibility)."""
        if tissue_id is not None:
            self.tissue_by_id(tissue_id)
        self.solo_class, self.solo_tissue_id = None, tissue_id

    def show_all(self) -> None:
        """Make every class and tissue but the background visible and leave solo mode."""
        self.solo_class = self.solo_tissue_id = None
        for item in [*self.classes, *self.tissues]:
            item.visible = not item.background

    def reset_look(self) -> None:
        """Back to the chosen look (:attr:`look_name`, by default the first click's) of the current grouping: its
        colours, opacities and visibility, made again from the classes (see :mod:`.gallery`)."""
        self._gallery = self._context = None  # a new grouping: new roles, new looks
        context = self.look_context()
        first = first_look_name(context)
        look = make_look(self.look_name or first, context) or make_look(first, context)
        self._apply(look)

    # Looks ---------------------------------------------------------------------------------------------------------
    def look_context(self) -> LookContext:
        """What every look of the current grouping is made from (the classes' roles decided once): made once per
        grouping, with the renders and looks made from it."""
        if self._context is None:
            self._context = LookContext.build(
                classes=self.classes,
                tissue_of_class=self.tissue_of_class,
                class_values=class_mean_values(self.labels, self.bin_voxels, self.edges, len(self.classes)),
                class_bins=self.class_bins,
                labels=self.labels,
                noise_sd=self.hierarchy.noise_sd,
                voxel_noise_sd=self.voxel_noise_sd,
                constant_background=self.constant_background,
                preview=self.preview,
                kind=self.kind,
                colors=self.options.get("colors", DEFAULT_OPTIONS["colors"]),
                max_classes=self.options.get("max_classes", DEFAULT_OPTIONS["max_classes"]),
            )
        return self._context

    @property
    def constant_background(self) -> bool:
        """Whether the background is one stored value, without noise (:func:`.roles.is_constant_background`)."""
        background = self.background_class
        return background is not None and is_constant_background(self.bin_voxels, background.isovalue_bins)

    @property
    def looks(self) -> list[GalleryLook]:
        """The gallery: every look the data support, ranked, the first click first (see :mod:`.gallery`); made
        once per grouping."""
        if self._gallery is None:
            self._gallery = gallery(self.look_context())
        return self._gallery

    def range_warning(self, override: str = "value_range=(low, high)") -> Optional[str]:
        """One line saying what the default value range left out, and how to choose another (``override``: how the
        caller's user sets the range); None when it left nothing out or a range was given."""
        return self.robust_range.warning(override) if self.robust_range is not None else None

    @property
    def chosen_look(self) -> str:
        """The look shown: :attr:`look_name`, or the first click's (:func:`.gallery.first_look_name`)."""
        return self.look_name or first_look_name(self.look_context())

    def use_look(self, name: str) -> None:
        """Show the look ``name`` of :attr:`looks` (its colours, opacities and visibility replace the current
        ones, edits included); a regrouping keeps it. Leaves solo mode."""
        looks = {look.name: look for look in self.looks}
        if name not in looks:
            raise ValueError(f"no look {name!r} for this volume; its looks are {', '.join(looks)}")
        self.look_name = name
        self.solo_class = self.solo_tissue_id = None
        self._apply(looks[name])

    def check_look(self, name: str) -> list[str]:
        """What the look ``name`` fails of its promise (:func:`.gallery.check_look`); empty when it keeps it."""
        looks = {look.name: look for look in self.looks}
        if name not in looks:
            raise ValueError(f"no look {name!r} for this volume; its looks are {', '.join(looks)}")
        return check_look(self.look_context(), looks[name])

    def _apply(self, look: GalleryLook) -> None:
        for c, color, opacity, shown in zip(self.classes, look.colors, look.opacities, look.visible):
            c.color, c.opacity, c.visible = list(color), opacity, shown
        shares = look.class_shares
        tissue_shares = None
        if shares is not None:
            tissue_shares = np.bincount(self.tissue_of_class, weights=shares, minlength=len(self.tissues))
        for t in self.tissues:
            members = [self.classes[c] for c in t.classes]
            t.color = list(max(members, key=lambda c: c.voxels).color)  # its largest class's, where they differ
            t.opacity = max(c.opacity for c in members)
            t.visible = any(c.visible for c in members)
            t.picture_share = None if tissue_shares is None else float(tissue_shares[t.id])

    @property
    def class_bins(self) -> np.ndarray:
        """``(n_classes,)`` voxel-weighted mean bin of each class."""
        return class_mean_values(self.labels, self.bin_voxels, np.arange(self.n_bins + 1) - 0.5, len(self.classes))

    # Transfer function ---------------------------------------------------------------------------------------------
    @property
    def class_colors(self) -> np.ndarray:
        """``(n_classes, 3)`` RGB in 0..1, in class id order."""
        return np.array([c.color for c in self.classes], dtype=np.float64)

    def bin_looks(self, look: Optional[GalleryLook] = None) -> tuple[np.ndarray, np.ndarray]:
        """``(n_bins, 3)`` colour and ``(n_bins,)`` opacity per bin, 0 opacity where the class is not shown: of
        the classes as they are now, or of a ``look`` of :attr:`looks`.

        Opacity climbs across each step over the intensity model's noise width (:func:`.look.bin_opacity_of`). A bin
        that is not shown takes the colour of the nearest shown bin: the ray caster interpolates colour across
        each step, and a hidden neighbour's colour would otherwise tint the rim of what is shown.
        """
        if look is None:
            opacities = [c.opacity if self.is_shown(c.id) else 0.0 for c in self.classes]
            class_colors = self.class_colors
        else:
            opacities = np.where(look.visible, look.opacities, 0.0)
            class_colors = np.array(look.colors, dtype=np.float64)
        bin_colors = class_colors[self.labels]
        bin_opacity = bin_opacity_of(np.asarray(opacities, dtype=np.float64), self.labels, self.hierarchy.noise_sd)
        shown = np.flatnonzero(bin_opacity > 0)
        if shown.size:
            nearest = shown[np.argmin(np.abs(np.arange(self.n_bins)[:, None] - shown[None, :]), axis=1)]
            bin_colors = bin_colors[nearest]
        return bin_colors, bin_opacity

    def transfer_function(self, look: Optional[GalleryLook] = None) -> TransferFunctionPoints:
        """Piecewise-constant control points in volume units (of the classes now, or of a ``look``)."""
        return piecewise_constant(self.edges, *self.bin_looks(look))

    def thumbnail(
        self,
        look: Optional[GalleryLook] = None,
        view: str = "anterior",
        size: int = 96,
        directions: Optional[np.ndarray] = None,
    ) -> np.ndarray:
        """``(size, size, 3)`` uint8 picture of the classes now, or of a ``look``, rendered from the preview by the
        Lib's shaded numpy ray caster (:func:`.thumbnails.render_thumbnail`); black without a preview.

        ``directions``: the volume's ``(3, 3)`` IJK-to-RAS directions (column ``c``: index axis ``c`` = i, j, k), so
        that ``view`` is the patient's side whichever way the file stores the voxels; None for the identity.
        """
        if self.preview is None:
            return np.zeros((size, size, 3), dtype=np.uint8)
        colors, opacity = self.bin_looks(look)
        return render_thumbnail(
            self.preview, colors, opacity, unit_distance=self.unit_distance, view=view, size=size, directions=directions
        )

    @property
    def gradient_ramp_top(self) -> Optional[float]:
        """With option ``gradient_opacity``: the gradient (volume units per mm) from which gradient opacity is 1
        (see :func:`.look.gradient_ramp_top`, from the shown tissues); None when the option is off."""
        if self.options.get("gradient_opacity", "off") != "auto":
            return None
        values = class_mean_values(self.labels, self.bin_voxels, self.edges, len(self.classes))
        shown = [t for t in self.tissues if t.visible and not t.background]
        means = [
            np.average(values[t.classes], weights=[max(self.classes[c].voxels, 1) for c in t.classes]) for t in shown
        ]
        return gradient_ramp_top(means)

    def volume_property(self, look: Optional[GalleryLook] = None):
        """A new ``vtkVolumeProperty`` showing this design (the classes now, or a ``look`` of :attr:`looks`)."""
        return new_volume_property(self.transfer_function(look), self.unit_distance, self.gradient_ramp_top)

    def update_volume_property(self, volume_property) -> None:
        """Rewrite the colour and opacity functions of an existing ``vtkVolumeProperty`` in place."""
        fill_volume_property(volume_property, self.transfer_function())

    def write_vp_json(self, path, look: Optional[GalleryLook] = None) -> None:
        write_vp_json(self.volume_property(look), path, effective_range=self.value_range)

    def write_vp(self, path) -> None:
        write_vp(self.volume_property(), path)

    # Serialization -------------------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The ``classes.json`` document (everything but the similarity matrix)."""
        tissue_of_class = self.tissue_of_class
        return {
            "value_range": [float(v) for v in self.value_range],
            "n_bins": self.n_bins,
            "options": dict(self.options),
            "timings_s": dict(self.timings_s),
            "clustering": dict(self.clustering),
            "spacing": list(self.spacing) if self.spacing else None,
            "unit_distance": self.unit_distance,
            "voxel_noise_sd": self.voxel_noise_sd,
            "look": self.look_name,
            "kind": self.kind,
            "solo_class": self.solo_class,
            "solo_tissue": self.solo_tissue_id,
            "labels": [int(v) for v in self.labels],
            "bin_voxels": [int(v) for v in self.bin_voxels],
            "tissue_hierarchy": self.hierarchy.to_dict(),
            "classes": [{**c.to_dict(), "tissue": int(tissue_of_class[c.id])} for c in self.classes],
            "tissues": [t.to_dict() for t in self.tissues],
            "preview": None if self.preview is None else _preview_to_dict(self.preview),
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    @classmethod
    def from_dict(cls, data: dict) -> "TransferFunctionDesign":
        """The design of a ``classes.json`` document (or a scene's design text), checked as the API checks its
        arguments: the options through their table, every colour, opacity, visibility, count, id and range.

        Raises:
            ValueError: anything missing, of the wrong type or out of range, in one line.
        """
        try:
            n_bins = int(OPTIONS["n_bins"].check(data["n_bins"]))
            if not all(isinstance(x, int) and not isinstance(x, bool) for x in data["labels"]):
                raise ValueError("labels must be class ids (integers)")
            labels = np.asarray(data["labels"], dtype=np.intp)
            classes = sorted((IsovalueClass.from_dict(c) for c in data["classes"]), key=lambda c: c.id)
            if labels.shape != (n_bins,) or [c.id for c in classes] != list(range(len(classes))):
                raise ValueError("labels and classes do not match")
            if labels.size and not 0 <= labels.min() <= labels.max() < len(classes):
                raise ValueError("a label names no class")
            look_name = data.get("look")
            if look_name is not None and look_name not in LOOK_NAMES:
                raise ValueError(f"no look {look_name!r}; looks are {', '.join(LOOK_NAMES)}")
            unit_distance = float(data.get("unit_distance", 1.0))
            if not (np.isfinite(unit_distance) and unit_distance > 0):
                raise ValueError(f"unit_distance must be a positive number of mm; got {unit_distance!r}")
            voxel_noise = data.get("voxel_noise_sd")
            if voxel_noise is not None and (
                isinstance(voxel_noise, bool)
                or not isinstance(voxel_noise, (int, float))
                or not (np.isfinite(voxel_noise) and voxel_noise >= 0)
            ):
                raise ValueError(f"voxel_noise_sd must be a number of bins, at least 0; got {voxel_noise!r}")
            tissues = [Tissue.from_dict(t) for t in data["tissues"]]
            members = sorted(c for t in tissues for c in t.classes)
            if members != list(range(len(classes))) or [t.id for t in tissues] != list(range(len(tissues))):
                raise ValueError("tissues do not hold every class once")
            for item in [*classes, *tissues]:
                _apply_edit(item, item.color, item.opacity, item.visible)  # the checks of an edit
                if item.voxels < 0:
                    raise ValueError(f"voxel counts cannot be negative; got {item.voxels}")
            if any(not 0 <= b < n_bins for c in classes for b in [*c.isovalue_bins, c.exemplar_bin]):
                raise ValueError("a class names a bin outside 0 .. n_bins - 1")
            bin_voxels = np.asarray(data["bin_voxels"], dtype=np.int64)
            if bin_voxels.shape != (n_bins,) or (bin_voxels < 0).any():
                raise ValueError("bin_voxels must hold one count per bin, none negative")
            kind = str(data.get("kind", "mr"))
            if kind not in KINDS:
                raise ValueError(f"kind must be one of {KINDS}; got {kind!r}")
            design = cls(
                value_range=OPTIONS["value_range"].check(data["value_range"]),
                n_bins=n_bins,
                labels=labels,
                classes=classes,
                options=_checked_options(data.get("options", {})),
                clustering=dict(data.get("clustering", {})),
                bin_voxels=bin_voxels,
                hierarchy=TissueHierarchy.from_dict(data["tissue_hierarchy"]),
                kind=kind,
                tissues=tissues,
                timings_s={k: float(v) for k, v in data.get("timings_s", {}).items()},
                spacing=_check_spacing(data.get("spacing")),
                unit_distance=unit_distance,
                voxel_noise_sd=voxel_noise,
                look_name=look_name,
                preview=None if data.get("preview") is None else _preview_from_dict(data["preview"], n_bins),
            )
            for solo, key in ((design.solo, "solo_class"), (design.solo_tissue, "solo_tissue")):
                if data.get(key) is not None:
                    solo(data[key])  # the id checks of the API
            design.solo_class, design.solo_tissue_id = data.get("solo_class"), data.get("solo_tissue")
            return design
        except (KeyError, TypeError, ValueError, IndexError, OverflowError, RecursionError, zlib.error) as error:
            raise ValueError(f"not a valid IsoSimilarityTF design: {_reason(error)}") from None

    @classmethod
    def from_json(cls, text: str) -> "TransferFunctionDesign":
        """The design of a JSON text (see :meth:`from_dict`); larger than :data:`MAX_DESIGN_CHARACTERS`, with NaN,
        infinities or nesting deeper than a design's, refused in one line."""
        if not isinstance(text, (str, bytes)) or len(text) > MAX_DESIGN_CHARACTERS:
            raise ValueError(
                f"not a valid IsoSimilarityTF design: not a text of at most {MAX_DESIGN_CHARACTERS} characters"
            )
        try:
            data = json.loads(text, parse_constant=_refuse_constant, parse_float=_finite_float)
        except (ValueError, RecursionError) as error:
            raise ValueError(f"not a valid IsoSimilarityTF design: {_reason(error)}") from None
        if not isinstance(data, dict):
            raise ValueError("not a valid IsoSimilarityTF design: not a JSON object")
        return cls.from_dict(data)


#: Largest design text read back (characters): a design of 4096 bins with its preview is about 2 MB.
MAX_DESIGN_CHARACTERS = 32 * 2**20


def _checked_options(options: dict) -> dict:
    """The options of a saved design as saved (a design made by hand may hold a few), each checked by its table
    entry."""
    if not isinstance(options, dict):
        raise ValueError("options must be a JSON object")
    check_options(options)
    return dict(options)


def _refuse_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number a design holds")


def _finite_float(text: str) -> float:
    value = float(text)
    if not np.isfinite(value):
        raise ValueError(f"{text} is not a finite number")
    return value


def _reason(error: BaseException) -> str:
    """One line for a refused design: the message, or the kind of error when it has none (a missing key)."""
    if isinstance(error, KeyError):
        return f"{error.args[0]!r} is missing" if error.args else "a field is missing"
    if isinstance(error, RecursionError):
        return "nested too deeply"
    return str(error).splitlines()[0] if str(error) else type(error).__name__


def _preview_to_dict(preview: Preview) -> dict:
    """The preview as JSON: shape, spacing and the bins, zlib-compressed little-endian uint16, in base64."""
    data = zlib.compress(np.ascontiguousarray(preview.bins, dtype="<u2").tobytes(), 6)
    bins = base64.b64encode(data).decode()
    return {"shape": list(preview.bins.shape), "spacing": list(preview.spacing), "bins": bins}


def _preview_from_dict(data: dict, n_bins: int) -> Preview:
    shape = tuple(int(n) for n in data["shape"])
    if len(shape) != 3 or not all(0 < n <= PREVIEW_VOXELS for n in shape) or np.prod(shape) > PREVIEW_VOXELS:
        raise ValueError("the preview's shape is not a preview's")
    # Inflated no further than the shape announces: a small text must not expand to gigabytes.
    expected = 2 * int(np.prod(shape))
    inflater = zlib.decompressobj()
    raw = inflater.decompress(base64.b64decode(data["bins"], validate=True), expected + 1)
    if len(raw) != expected:
        raise ValueError("the preview does not match its shape")
    bins = np.frombuffer(raw, dtype="<u2")
    if bins.size and int(bins.max()) >= n_bins:
        raise ValueError("the preview names a bin outside 0 .. n_bins - 1")
    spacing = _check_spacing(data["spacing"])
    return Preview(bins=bins.reshape(shape).astype(np.uint16), spacing=spacing, n_bins=n_bins)


def _apply_edit(
    target: Union[IsovalueClass, Tissue],
    color: Optional[Sequence[float]],
    opacity: Optional[float],
    visible: Optional[bool],
) -> None:
    if color is not None:
        if isinstance(color, str) or len(color) != 3:
            raise ValueError(f"color must be three numbers in [0, 1]; got {color!r}")
        target.color = [_unit_number(c, "color") for c in color]
    if opacity is not None:
        target.opacity = _unit_number(opacity, "opacity")
    if visible is not None:
        if not isinstance(visible, (bool, np.bool_)):  # bool("no") is True: a plausible wrong answer
            raise ValueError(f"visible must be True or False; got {visible!r}")
        target.visible = bool(visible)


def _tissue_count(tissues: Union[int, str], hierarchy: TissueHierarchy) -> int:
    """The number of non-background tissues that ``tissues`` (``"auto"``, ``"all"`` or a count) asks for."""
    if tissues == "auto":
        return hierarchy.auto
    if tissues == "all":
        return hierarchy.max_tissues
    if isinstance(tissues, bool) or not isinstance(tissues, (int, np.integer)):
        raise ValueError(f'tissues must be "auto", "all" or a positive integer; got {tissues!r}')
    if not 1 <= tissues <= max(hierarchy.max_tissues, 1):
        raise ValueError(f"tissues must be 1 to {hierarchy.max_tissues} (one per class) here; got {tissues}")
    return int(tissues)


def _detect_kind(
    hierarchy: TissueHierarchy, labels: np.ndarray, bin_voxels: np.ndarray, preview: Preview, modality: Optional[str]
) -> str:
    """:func:`.look.detect_kind` on the intensity model's own tissues (the automatic grouping)."""
    if modality is not None:
        return detect_kind([], [], hierarchy.noise_sd, modality)
    groups = hierarchy.groups(hierarchy.auto) if hierarchy.order else []
    n = len(groups)
    group_of_bin = np.full(labels.size, n)  # the background's bins: a group of their own, left out below
    for group, members in enumerate(groups):
        group_of_bin[np.isin(labels, members)] = group
    means = class_mean_values(group_of_bin, bin_voxels, np.arange(labels.size + 1) - 0.5, n + 1)[:n]
    voxels = np.bincount(group_of_bin, weights=bin_voxels, minlength=n + 1)[:n]
    order = np.argsort(means)
    rank = np.full(n + 1, -1)
    rank[order] = np.arange(n)
    tissue_of_bin = rank[group_of_bin]  # tissues in intensity order, -1 for the background
    return detect_kind(
        means[order],
        voxels[order],
        hierarchy.noise_sd,
        encloses=lambda outer, inner: enclosure(preview, tissue_of_bin, outer, inner),
    )


def _check_spacing(spacing) -> Optional[tuple[float, float, float]]:
    if spacing is None:
        return None
    if np.ndim(spacing) == 0:  # one number: isotropic voxels
        spacing = (spacing,) * 3
    try:
        spacing = tuple(float(s) for s in spacing)
    except (TypeError, ValueError):
        raise ValueError(f"spacing must be three positive numbers (mm) or one; got {spacing!r}") from None
    if len(spacing) != 3 or not all(np.isfinite(s) and s > 0 for s in spacing):
        raise ValueError(f"spacing must be three positive numbers (mm) or one; got {spacing!r}")
    return spacing


def _clustering_progress(report: Callable[[str, float, str], None], n_bins: int, damping: float):
    """AP's ``on_iteration``: a clustering progress report about every ``_PROGRESS_ENTRIES`` message updates (an
    iteration updates ``n_bins**2`` of them), so that even 4096 bins can be cancelled between iterations."""
    every = max(1, _PROGRESS_ENTRIES // (n_bins * n_bins))

    def on_iteration(iteration: int, max_iter: int) -> None:
        if iteration % every == 0:
            report(
                "clustering",
                iteration / max_iter,
                f"affinity propagation: iteration {iteration} of at most {max_iter} (damping {damping:g})",
            )

    return on_iteration


def _clustered(
    similarity: IsovalueSimilarity, opts: dict, report: Callable[[str, float, str], None]
) -> tuple[ClusteringResult, dict]:
    """Affinity propagation with the options' damping, then, under ``unconverged="raise-damping"``, the fallback
    dampings (iteration limits scaled by the slower message updates), and then the same on the distinct isovalues
    (:func:`.clustering.cluster_isovalues`' ``distinct``): a volume stored in a few coarse steps has runs of
    identical isovalues, on which AP oscillates, or converges on a single class, which shows nothing. The first run
    that converges on more than one class is kept, else the first that converged; with what was used
    (``damping``, ``max_iter``, ``convergence_iter``, ``distinct``).

    Raises:
        ClusteringError: no run converged and ``opts["unconverged"]`` is not ``"keep"``.
    """
    n_bins = opts["n_bins"]
    retry = opts["unconverged"] == "raise-damping"
    dampings = [opts["damping"], *(d for d in FALLBACK_DAMPINGS if retry and d > opts["damping"])]
    ladder = [(d, distinct) for distinct in ((False, True) if retry else (False,)) for d in dampings]
    single = None  # the first run that converged on a single class
    for damping, distinct in ladder:
        slowdown = (1.0 - opts["damping"]) / (1.0 - damping)
        run = {
            "damping": damping,
            "max_iter": int(round(opts["max_iter"] * slowdown)),
            "convergence_iter": int(round(opts["convergence_iter"] * slowdown)),
            "distinct": distinct,
        }
        clusters = cluster_isovalues(
            similarity.matrix,
            preference=opts["preference"],
            damping=damping,
            max_iter=run["max_iter"],
            convergence_iter=run["convergence_iter"],
            empty_isovalues=similarity.empty_isovalues,
            on_iteration=_clustering_progress(report, n_bins, damping),
            distinct=distinct,
        )
        if clusters.converged and clusters.n_classes > 1:
            return clusters, run
        if clusters.converged and single is None:
            single = clusters, run
    if single is not None:
        return single
    if opts["unconverged"] != "keep":
        where = " on every isovalue, then on the distinct ones" if retry else ""
        raise ClusteringError(
            f"affinity propagation did not converge in {opts['max_iter']} iterations with damping "
            f"{', '.join(f'{d:g}' for d in dampings)}{where}; {unconverged_advice(opts['max_iter'], dampings)}"
        )
    return clusters, run


def _source(values, opts: dict) -> Union[VolumeSource, Quantization]:
    """The volume as a source (an already quantized volume as it is), once the memory the design needs is checked;
    sets ``opts``' ``n_bins`` (and ``value_range`` of a quantized volume)."""
    if isinstance(values, Quantization):
        check_memory(np.shape(values.bins), values.n_bins)
        opts["n_bins"], opts["value_range"] = values.n_bins, list(values.value_range)
        return values
    source = VolumeSource(values)
    opts["n_bins"] = n_bins = checked_n_bins(opts["n_bins"])
    row_bytes = source.row_bytes(bins_dtype(n_bins).itemsize)
    check_memory(source.shape, n_bins, row_bytes=row_bytes)
    return source


def _binned(
    source: Union[VolumeSource, Quantization],
    opts: dict,
    progress: Callable[[float], None],
    value_tap: Optional[Callable[[int, np.ndarray], None]] = None,
) -> tuple[VolumeSource, tuple[float, float], Optional[RobustRange], Optional[np.ndarray]]:
    """The volume's bins (lazy for a dask volume: binned as the stream reads it), the value range they cover, what
    the default range left out (None: nothing, or a range was given), and how many values the storage can put in
    each bin (:func:`.quantize.values_per_bin` on the lattice of the survey's sample; None where it cannot tell, and
    for bins given: they say nothing of how the values were stored).

    The survey (one pass: :func:`~.survey.survey_volume`) gives the range the rules of :mod:`.value_range` decide on
    (padding and outliers left out) unless ``opts["value_range"]`` gives one.
    """
    if isinstance(source, Quantization):
        return VolumeSource(source.bins), tuple(source.value_range), None, None
    n_bins = opts["n_bins"]
    survey = survey_volume(source, progress=progress, tap=value_tap)
    data_range = checked_data_range(survey, n_bins)
    robust = robust_value_range(source, survey=survey) if opts["value_range"] is None else None
    if robust is not None and not robust.excludes:
        robust = None
    value_range = resolved_value_range(robust.value_range if robust else opts["value_range"], data_range)
    binning = partial(bin_volume, n_bins=n_bins, value_range=value_range, data_range=data_range)
    lattice = value_lattice(survey.sample)
    per_bin = values_per_bin(value_range, n_bins, lattice, survey.sample) if lattice is not None else None
    return source.map_slabs(binning, bins_dtype(n_bins)), value_range, robust, per_bin


def design_transfer_function(
    values: Union[np.ndarray, Quantization],
    spacing: Optional[Sequence[float]] = None,
    *,
    progress: Optional[StageProgress] = None,
    value_tap: Optional[Callable[[int, np.ndarray], None]] = None,
    **options,
) -> TransferFunctionDesign:
    """Design a transfer function for a volume: quantize, similarity, affinity propagation, classes.

    Args:
        values: 3-D scalar volume (any axis order; a ``dask.array`` for volumes larger than memory), or an already
            quantized volume.
        spacing: voxel spacing ``(x, y, z)`` in mm, or one number for cubic voxels (the look's preview is made in mm).
        progress: called as ``progress(stage, fraction, message)``; raising from it cancels the design.
        value_tap: called as ``value_tap(first plane, slab)`` with every slab of the volume's values, in order
            along axis 0, during the design's first read of them (a caller's own use of that read, e.g. the command
            line's render preview of a volume read lazily: no read of its own). Not called for a quantized volume.
        **options: ``n_bins``, ``value_range``, ``crossing``, ``normalization``, ``levels``, ``preference``,
            ``damping``, ``max_iter``, ``convergence_iter``, ``max_classes``, ``background``, ``unconverged``
            (see :data:`.options.OPTIONS`). ``unconverged`` says what happens when affinity propagation does not
            converge:
            ``"raise-damping"`` retries with damping 0.7 then 0.9 and iteration limits scaled by the slower message
            updates, then the same on the distinct isovalues (see :func:`_clustered`; what was used is reported in
            ``clustering``), ``"error"`` raises,
            ``"keep"`` keeps the last iteration's grouping (reported as not converged).
            ``tissues``: ``"auto"`` (the count the intensity model chooses, see :mod:`.tissues`), ``"all"`` (one
            tissue per class: the thesis' classes) or a number of non-background tissues; :meth:`regroup` changes
            it later without recomputing anything. ``colors``: ``"ramp"`` (one intensity-ordered colour per tissue)
            or ``"distinct"`` (the qualitative palette). ``modality``: ``"CT"``, ``"MR"`` or None to detect the
            kind of volume from its dtype and value range (see :func:`.look.detect_kind`). ``gradient_opacity``:
            ``"auto"`` fades homogeneous insides by a gradient-opacity ramp (see :func:`.look.gradient_ramp_top`),
            ``"off"`` (default) leaves it constant.

    Raises:
        ValueError: bad volume or option. ClusteringError: affinity propagation gave no usable grouping.
        InsufficientMemoryError: the volume would not fit in the memory available.
    """
    opts = check_options(options)
    spacing = _check_spacing(spacing)

    def report(stage: str, fraction: float, message: str) -> None:
        if progress is not None:
            progress(stage, fraction, message)

    timings: dict[str, float] = {}

    @contextmanager
    def stage(name: str, message: str) -> Iterator[None]:
        report(name, 0.0, message)
        start = time.perf_counter()
        yield
        timings[name] = time.perf_counter() - start

    source = _source(values, opts)
    with stage("quantize", "quantizing"):
        bins, value_range, robust, per_bin = _binned(
            source, opts, lambda fraction: report("quantize", fraction, "quantize: value range"), value_tap
        )
    n_bins, shape = opts["n_bins"], bins.shape

    # One pass over the bins: the similarity's counts, and (its tap) the voxel counts, the planes the background
    # contact is measured on and the look's preview.
    steps, preview_spacing = preview_steps(shape, spacing)
    tap = SlabTap(shape, n_bins, preview_steps=steps, kept_planes=planes_read(shape))
    with stage("similarity", "measuring isosurface similarity"):
        similarity = isovalue_similarity(
            bins,
            n_bins,
            crossing=opts["crossing"],
            normalization=opts["normalization"],
            levels=opts["levels"],
            progress=lambda fraction, message: report("similarity", fraction, message),
            tap=tap,
        )

    with stage("clustering", "affinity propagation"):
        clusters, run = _clustered(similarity, opts, report)

    with stage("classes", "ranking classes"):
        bin_voxels = tap.voxel_counts
        edges = np.linspace(value_range[0], value_range[1], n_bins + 1)
        classes = build_classes(
            clusters.labels, clusters.exemplars, bin_voxels, edges, background=opts["background"], bins=tap
        )
        background = next((c.id for c in classes if c.background), None)
        voxel_noise = voxel_noise_sd(tap, clusters.labels != background)

    with stage("tissues", "grouping classes into tissues and choosing their look"):
        hierarchy = tissue_hierarchy(
            clusters.labels,
            bin_voxels,
            [c.id for c in classes if c.id != background],
            similarity.matrix,
            values_per_bin=per_bin,
        )
        preview = Preview(tap.preview(), preview_spacing, n_bins)
        kind = _detect_kind(hierarchy, clusters.labels, bin_voxels, preview, opts["modality"])
        # The tissues' look (with its visibility step) is part of the stage: the Detail slider redoes both.
        design = TransferFunctionDesign(
            value_range=value_range,
            n_bins=n_bins,
            labels=clusters.labels,
            classes=classes,
            options={k: (list(v) if isinstance(v, tuple) else v) for k, v in opts.items()},
            clustering={
                "n_iter": clusters.n_iter,
                "converged": clusters.converged,
                "n_classes": clusters.n_classes,
                "preference": clusters.preference,
                **run,
                "empty_isovalues": [int(b) for b in similarity.empty_isovalues],
            },
            bin_voxels=bin_voxels,
            hierarchy=hierarchy,
            kind=kind,
            spacing=spacing,
            similarity=similarity.matrix,
            preview=preview,
            unit_distance=preview.unit_distance,
            robust_range=robust,
            voxel_noise_sd=voxel_noise,
        )
        design.regroup(opts["tissues"])
    design.timings_s = timings
    report("tissues", 1.0, f"{clusters.n_classes} classes, {design.n_tissues} tissues")
    return design
