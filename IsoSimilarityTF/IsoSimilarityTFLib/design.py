"""The whole pipeline: volume in, classes and transfer function out, editable class by class without recomputing."""

import json
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable, Optional, Union

import numpy as np

from .chunked import is_dask_array, quantize_chunked
from .classes import IsovalueClass, build_classes, default_colors, default_opacities
from .clustering import ClusteringError, cluster_isovalues
from .memory import check_memory
from .quantize import Quantization, quantize
from .similarity import isovalue_similarity
from .transfer_function import (
    TransferFunctionPoints,
    fill_volume_property,
    new_volume_property,
    piecewise_constant,
    write_vp,
    write_vp_json,
)

StageProgress = Callable[[str, float, str], None]

DEFAULT_OPTIONS = {
    "n_bins": 256,
    "value_range": None,
    "crossing": "inclusive",
    "normalization": "thesis",
    "levels": None,
    "preference": "median",
    "damping": 0.5,
    "max_iter": 200,
    "convergence_iter": 15,
    "max_classes": 15,
    "background": "largest",
    "unconverged": "raise-damping",
}

UNCONVERGED_RULES = ("raise-damping", "error", "keep")
# Frey & Dueck's remedy for oscillating messages: more damping, tried in turn when the requested damping fails.
# Messages then move (1 - damping) of the way per iteration, so the iteration limits grow by the same factor;
# otherwise a slow run of unchanged exemplars passes for convergence.
FALLBACK_DAMPINGS = (0.7, 0.9)

STAGES = ("quantize", "similarity", "clustering", "classes")


@dataclass
class TransferFunctionDesign:
    """An automatic transfer function: the classes found in a volume and how each one looks.

    Editing (:meth:`set_class`, :meth:`solo`, :meth:`show_all`, :meth:`reset_look`) changes only the look; the
    transfer function is derived from the classes each time it is asked for.

    Attributes:
        value_range: ``(low, high)`` of the isovalue bins, in volume units.
        n_bins: number of isovalue bins.
        labels: ``(n_bins,)`` class id per bin.
        classes: the classes, in id order (id 0 = lowest exemplar intensity).
        options: the options the design was made with.
        clustering: ``n_iter``, ``converged``, ``n_classes`` and ``preference`` of affinity propagation.
        timings_s: seconds per stage.
        spacing: voxel spacing in mm (sets the opacity unit distance), or None.
        solo_class: id of the class shown alone, or None.
        similarity: ``(n_bins, n_bins)`` similarity matrix (not serialized), or None after loading.
    """

    value_range: tuple[float, float]
    n_bins: int
    labels: np.ndarray
    classes: list[IsovalueClass]
    options: dict
    clustering: dict
    timings_s: dict[str, float] = field(default_factory=dict)
    spacing: Optional[tuple[float, float, float]] = None
    solo_class: Optional[int] = None
    similarity: Optional[np.ndarray] = field(default=None, repr=False)

    @property
    def edges(self) -> np.ndarray:
        """Bin edges in volume units, ``(n_bins + 1,)``."""
        return np.linspace(self.value_range[0], self.value_range[1], self.n_bins + 1)

    @property
    def background_class(self) -> Optional[IsovalueClass]:
        return next((c for c in self.classes if c.background), None)

    def class_by_id(self, class_id: int) -> IsovalueClass:
        if not 0 <= class_id < len(self.classes):
            raise KeyError(f"no class {class_id}; classes are 0 to {len(self.classes) - 1}")
        return self.classes[class_id]

    def is_shown(self, class_id: int) -> bool:
        """Whether the class appears in the transfer function (solo overrides the visible flags)."""
        if self.solo_class is not None:
            return class_id == self.solo_class
        return self.class_by_id(class_id).visible

    # Editing -------------------------------------------------------------------------------------------------------
    def set_class(
        self,
        class_id: int,
        *,
        color: Optional[Sequence[float]] = None,
        opacity: Optional[float] = None,
        visible: Optional[bool] = None,
    ) -> None:
        """Change one class's colour (``[r, g, b]`` in 0..1), opacity (0..1) or visibility."""
        target = self.class_by_id(class_id)
        if color is not None:
            color = [float(c) for c in color]
            if len(color) != 3 or not all(0.0 <= c <= 1.0 for c in color):
                raise ValueError(f"color must be three numbers in [0, 1]; got {color!r}")
            target.color = color
        if opacity is not None:
            if not 0.0 <= float(opacity) <= 1.0:
                raise ValueError(f"opacity must be in [0, 1]; got {opacity!r}")
            target.opacity = float(opacity)
        if visible is not None:
            target.visible = bool(visible)

    def solo(self, class_id: Optional[int]) -> None:
        """Show only this class (None: back to each class's own visibility)."""
        if class_id is not None:
            self.class_by_id(class_id)
        self.solo_class = class_id

    def show_all(self) -> None:
        """Make every class but the background visible and leave solo mode."""
        self.solo_class = None
        for c in self.classes:
            c.visible = not c.background

    def reset_look(self) -> None:
        """Back to the default colours and opacities (visibility untouched)."""
        max_classes = self.options.get("max_classes", DEFAULT_OPTIONS["max_classes"])
        looks = zip(default_colors(self.classes), default_opacities(self.classes, max_classes))
        for c, (color, opacity) in zip(self.classes, looks):
            c.color, c.opacity = color, opacity

    # Transfer function ---------------------------------------------------------------------------------------------
    @property
    def class_colors(self) -> np.ndarray:
        """``(n_classes, 3)`` RGB in 0..1, in class id order."""
        return np.array([c.color for c in self.classes], dtype=np.float64)

    def bin_looks(self) -> tuple[np.ndarray, np.ndarray]:
        """``(n_bins, 3)`` colour and ``(n_bins,)`` opacity per bin, 0 opacity where the class is not shown."""
        colors = self.class_colors
        opacities = np.array([c.opacity if self.is_shown(c.id) else 0.0 for c in self.classes], dtype=np.float64)
        return colors[self.labels], opacities[self.labels]

    def transfer_function(self) -> TransferFunctionPoints:
        """Piecewise-constant control points in volume units."""
        return piecewise_constant(self.edges, *self.bin_looks())

    @property
    def unit_distance(self) -> float:
        """Scalar opacity unit distance in mm: the smallest voxel spacing, so opacity is per voxel step."""
        return float(min(self.spacing)) if self.spacing else 1.0

    def volume_property(self):
        """A new ``vtkVolumeProperty`` showing this design."""
        return new_volume_property(self.transfer_function(), self.unit_distance)

    def update_volume_property(self, volume_property) -> None:
        """Rewrite the colour and opacity functions of an existing ``vtkVolumeProperty`` in place."""
        fill_volume_property(volume_property, self.transfer_function())

    def write_vp_json(self, path) -> None:
        write_vp_json(self.volume_property(), path, effective_range=self.value_range)

    def write_vp(self, path) -> None:
        write_vp(self.volume_property(), path)

    # Serialization -------------------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The ``classes.json`` document (everything but the similarity matrix)."""
        return {
            "value_range": [float(v) for v in self.value_range],
            "n_bins": self.n_bins,
            "options": dict(self.options),
            "timings_s": dict(self.timings_s),
            "clustering": dict(self.clustering),
            "spacing": list(self.spacing) if self.spacing else None,
            "solo_class": self.solo_class,
            "labels": [int(v) for v in self.labels],
            "classes": [c.to_dict() for c in self.classes],
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    @classmethod
    def from_dict(cls, data: dict) -> "TransferFunctionDesign":
        try:
            n_bins = int(data["n_bins"])
            labels = np.asarray(data["labels"], dtype=np.intp)
            classes = [IsovalueClass.from_dict(c) for c in data["classes"]]
            if labels.shape != (n_bins,) or sorted(c.id for c in classes) != list(range(len(classes))):
                raise ValueError("labels and classes do not match")
            if labels.size and not 0 <= labels.min() <= labels.max() < len(classes):
                raise ValueError("a label names no class")
            spacing = data.get("spacing")
            return cls(
                value_range=(float(data["value_range"][0]), float(data["value_range"][1])),
                n_bins=n_bins,
                labels=labels,
                classes=sorted(classes, key=lambda c: c.id),
                options=dict(data.get("options", {})),
                clustering=dict(data.get("clustering", {})),
                timings_s={k: float(v) for k, v in data.get("timings_s", {}).items()},
                spacing=tuple(float(s) for s in spacing) if spacing else None,
                solo_class=data.get("solo_class"),
            )
        except (KeyError, TypeError, ValueError, IndexError) as error:
            raise ValueError(f"not a valid IsoSimilarityTF design: {error!r}") from None

    @classmethod
    def from_json(cls, text: str) -> "TransferFunctionDesign":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as error:
            raise ValueError(f"not a valid IsoSimilarityTF design: {error}") from None
        return cls.from_dict(data)


def _check_spacing(spacing) -> Optional[tuple[float, float, float]]:
    if spacing is None:
        return None
    spacing = tuple(float(s) for s in spacing)
    if len(spacing) != 3 or not all(np.isfinite(s) and s > 0 for s in spacing):
        raise ValueError(f"spacing must be three positive numbers (mm); got {spacing!r}")
    return spacing


def design_transfer_function(
    values: Union[np.ndarray, Quantization],
    spacing: Optional[Sequence[float]] = None,
    *,
    progress: Optional[StageProgress] = None,
    **options,
) -> TransferFunctionDesign:
    """Design a transfer function for a volume: quantize, similarity, affinity propagation, classes.

    Args:
        values: 3-D scalar volume (any axis order; a ``dask.array`` for volumes larger than memory), or an already
            quantized volume.
        spacing: voxel spacing in mm, used for the opacity unit distance.
        progress: called as ``progress(stage, fraction, message)``; raising from it cancels the design.
        **options: ``n_bins``, ``value_range``, ``crossing``, ``normalization``, ``levels``, ``preference``,
            ``damping``, ``max_iter``, ``convergence_iter``, ``max_classes``, ``background``, ``unconverged``
            (see DEFAULT_OPTIONS). ``unconverged`` says what happens when affinity propagation does not converge:
            ``"raise-damping"`` retries with damping 0.7 then 0.9 and iteration limits scaled by the slower message
            updates (what was used is reported in ``clustering``), ``"error"`` raises,
            ``"keep"`` keeps the last iteration's grouping (reported as not converged).

    Raises:
        ValueError: bad volume or option. ClusteringError: affinity propagation gave no usable grouping.
        InsufficientMemoryError: the volume would not fit in the memory available.
    """
    unknown = sorted(set(options) - set(DEFAULT_OPTIONS))
    if unknown:
        raise TypeError(f"unknown option(s): {', '.join(unknown)}; known: {', '.join(DEFAULT_OPTIONS)}")
    opts = {**DEFAULT_OPTIONS, **options}
    if opts["unconverged"] not in UNCONVERGED_RULES:
        raise ValueError(f"unconverged must be one of {UNCONVERGED_RULES}; got {opts['unconverged']!r}")
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

    chunked = is_dask_array(values)
    check_memory(np.shape(values.bins if isinstance(values, Quantization) else values), opts["n_bins"], chunked)
    with stage("quantize", "quantizing"):
        if isinstance(values, Quantization):
            quantized = values
            opts["n_bins"], opts["value_range"] = quantized.n_bins, list(quantized.value_range)
        elif chunked:
            quantized = quantize_chunked(values, opts["n_bins"], opts["value_range"])
        else:
            quantized = quantize(values, opts["n_bins"], opts["value_range"])

    with stage("similarity", "measuring isosurface similarity"):
        similarity = isovalue_similarity(
            quantized.bins,
            quantized.n_bins,
            crossing=opts["crossing"],
            normalization=opts["normalization"],
            levels=opts["levels"],
            progress=lambda fraction, message: report("similarity", fraction, message),
        )

    with stage("clustering", "affinity propagation"):
        dampings = [opts["damping"]]
        if opts["unconverged"] == "raise-damping":
            dampings += [d for d in FALLBACK_DAMPINGS if d > opts["damping"]]
        for damping in dampings:
            slowdown = (1.0 - opts["damping"]) / (1.0 - damping)
            iterations = {
                "max_iter": int(round(opts["max_iter"] * slowdown)),
                "convergence_iter": int(round(opts["convergence_iter"] * slowdown)),
            }
            clusters = cluster_isovalues(
                similarity.matrix,
                preference=opts["preference"],
                damping=damping,
                empty_isovalues=similarity.empty_isovalues,
                **iterations,
            )
            if clusters.converged:
                break
        if not clusters.converged and opts["unconverged"] != "keep":
            raise ClusteringError(
                f"affinity propagation did not converge in {opts['max_iter']} iterations with damping "
                f"{', '.join(f'{d:g}' for d in dampings)}; raise max_iter (e.g. 1000) or damping (e.g. 0.95)"
            )

    with stage("classes", "ranking classes"):
        classes = build_classes(
            clusters.labels,
            clusters.exemplars,
            quantized.voxel_counts(),
            quantized.edges,
            background=opts["background"],
            max_classes=opts["max_classes"],
            bins=quantized.bins,
        )
    design = TransferFunctionDesign(
        value_range=quantized.value_range,
        n_bins=quantized.n_bins,
        labels=clusters.labels,
        classes=classes,
        options={k: (list(v) if isinstance(v, tuple) else v) for k, v in opts.items()},
        clustering={
            "n_iter": clusters.n_iter,
            "converged": clusters.converged,
            "n_classes": clusters.n_classes,
            "preference": clusters.preference,
            "damping": damping,
            **iterations,
            "empty_isovalues": [int(b) for b in similarity.empty_isovalues],
        },
        spacing=spacing,
        similarity=similarity.matrix,
    )
    design.timings_s = timings
    report("classes", 1.0, f"{clusters.n_classes} classes")
    return design
