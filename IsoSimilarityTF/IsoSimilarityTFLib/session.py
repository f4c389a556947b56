"""What the Slicer module does, without Qt: design a volume's transfer function, keep it in sync with the scene, edit
it class by class, and hand it to the rest of Slicer (files, segments, presets).

The module's logic (``IsoSimilarityTFLogic``) is this class plus Slicer's ``ScriptedLoadableModuleLogic``; headless,
it runs on a ``slicer-core`` scene, so the module's self-test checks (:mod:`.selftest`) run in ``make test`` too.
"""

import logging
from dataclasses import dataclass
from typing import Optional, Union

from . import mrml
from .cells import octree_levels
from .design import TransferFunctionDesign, design_transfer_function
from .options import check_options
from .worker import DesignProcess

# Similarity matrices kept for volumes designed in this session (4096 bins: 128 MB each).
MAX_KEPT_SIMILARITIES = 4

#: Levels of the panel's tree: a tissue row, a class row (inside its tissue).
TISSUE, CLASS = "tissue", "class"
LEVELS = (TISSUE, CLASS)

#: The "Detail" setting (the parameter node's ``tissues``) that stands for the automatic number of tissues.
AUTO_DETAIL = 0
#: How a user of the logic sets the value range, in the note on what the default range left out.
RANGE_OVERRIDE = "value_range=(low, high) in IsoSimilarityTFLib.design_transfer_function"


def volume_values(volume_node):
    """The voxel array (a view, ``[k, j, i]`` like ``slicer.util.arrayFromVolume``) and the spacing (mm) of a scalar
    volume node."""
    return mrml.voxel_array(volume_node), tuple(volume_node.GetSpacing())


def fit_levels(shape, options: dict) -> tuple:
    """``(options, available)``: ``levels`` larger than the volume's number of octree levels becomes None (all
    levels) and ``available`` is that number; otherwise the options unchanged and None."""
    options = dict(options)
    levels = options.get("levels")
    if levels and min(shape) >= 2:
        available = len(octree_levels(tuple(n - 1 for n in shape)))
        if levels > available:
            options["levels"] = None
            return options, available
    return options, None


def grouping_of_detail(detail: int, max_tissues: int) -> Union[str, int]:
    """The ``tissues`` grouping (``"auto"``, ``"all"`` or a count) of a Detail setting.

    The panel's Detail is an integer: :data:`AUTO_DETAIL` (0) is the automatic count, ``n >= 1`` is ``n`` tissues,
    and a count at or above the design's number of non-background classes is one tissue per class (``"all"``, the
    thesis). So a count saved with the scene still means something on a volume with fewer classes.
    """
    if detail == AUTO_DETAIL:
        return "auto"
    if detail < 0:
        raise ValueError(f"the detail must be {AUTO_DETAIL} (automatic) or a number of tissues; got {detail}")
    return "all" if detail >= max_tissues else int(detail)


def detail_of_design(design: TransferFunctionDesign) -> int:
    """The Detail setting that gives the design's current grouping: :data:`AUTO_DETAIL` when the automatic count was
    asked for (and is what the design shows), else its number of tissues."""
    if design.options.get("tissues", "auto") == "auto" and design.n_tissues == design.hierarchy.auto:
        return AUTO_DETAIL
    return design.n_tissues


def regroup_design(design: TransferFunctionDesign, detail: int) -> None:
    """Group the design's classes as a Detail setting says (instant: nothing is computed again) and record the
    grouping in the design's options, so that the scene keeps what the user chose (``"auto"``, a count, ``"all"``).
    The tissues get their default look again."""
    grouping = grouping_of_detail(detail, design.hierarchy.max_tissues)
    design.regroup(grouping)
    design.options["tissues"] = grouping


def _engine_grouping(options: dict) -> tuple:
    """``(options for the engine, Detail to regroup to afterwards or None)``.

    A number of tissues is known to fit only once the classes are known: the engine groups automatically and the
    session regroups the finished design (instant), one tissue per class when the volume has fewer classes.
    """
    options = dict(options)
    tissues = options.get("tissues")
    if isinstance(tissues, int) and not isinstance(tissues, bool):
        options["tissues"] = "auto"
        return options, tissues
    return options, None


@dataclass(frozen=True)
class Row:
    """One row of the panel's tree: a tissue, or one of its classes. Qt-free: the panel only draws it.

    Attributes:
        level: :data:`TISSUE` or :data:`CLASS`.
        id: the tissue's or the class's id (shown from 1).
        color: ``(r, g, b)`` in 0..1.
        opacity: opacity per mm when shown.
        visible: the visible flag; for a tissue, None when some of its classes are visible and some not.
        solo: whether this row is shown alone.
        shown: whether it appears in the transfer function (for a tissue: any of its classes).
        voxels, fraction: voxels in the row, and their share of the volume.
        value_ranges: ``[low, high]`` runs in volume units.
        background: whether the row is the background.
        classes: the class ids (a class row: its own id).
        children: a tissue's class rows, when it has more than one class (else empty).
    """

    level: str
    id: int
    color: tuple
    opacity: float
    visible: Optional[bool]
    solo: bool
    shown: bool
    voxels: int
    fraction: float
    value_ranges: tuple
    background: bool
    classes: tuple
    children: tuple = ()


def design_rows(design: TransferFunctionDesign) -> list:
    """The tissue rows of a design (each with its class rows), in intensity order."""
    total = max(int(sum(c.voxels for c in design.classes)), 1)
    rows = []
    for tissue in design.tissues:
        class_rows = tuple(
            Row(
                level=CLASS,
                id=c.id,
                color=tuple(c.color),
                opacity=c.opacity,
                visible=c.visible,
                solo=design.solo_class == c.id,
                shown=design.is_shown(c.id),
                voxels=c.voxels,
                fraction=c.fraction,
                value_ranges=tuple(tuple(r) for r in c.value_ranges),
                background=c.background,
                classes=(c.id,),
            )
            for c in (design.classes[i] for i in tissue.classes)
        )
        flags = {row.visible for row in class_rows}
        rows.append(
            Row(
                level=TISSUE,
                id=tissue.id,
                color=tuple(tissue.color),
                opacity=tissue.opacity,
                visible=flags.pop() if len(flags) == 1 else None,
                solo=design.solo_tissue_id == tissue.id,
                shown=any(row.shown for row in class_rows),
                voxels=tissue.voxels,
                fraction=tissue.voxels / total,
                value_ranges=tuple(tuple(r) for r in tissue.value_ranges),
                background=tissue.background,
                classes=tuple(tissue.classes),
                children=class_rows if len(class_rows) > 1 else (),
            )
        )
    return rows


class Cancelled(Exception):
    """Raised by a progress callback to stop a design computed in this process (see :meth:`DesignSession.run`)."""


# Where an Apply runs -------------------------------------------------------------------------------------------------
# In Slicer, a design in a child process (:mod:`.worker`) costs, on every Apply, starting PythonSlicer and importing
# numpy and the library (0.15-0.26 s with plain Python here) and passing the volume and the design through files; in
# Slicer's own process the design runs on the main thread, which repaints and honours Cancel only at progress reports
# (between affinity propagation's iterations too), so Slicer stands still for the longest step between two reports.
# So a design runs in-process when it is expected to take less than about a second, and in a child process otherwise.
# The cost model (seconds), measured with benchmarks/apply_cost.py on shared 2-core VMs (numpy 2; see
# docs/apply-cost.md):
#: Quantization, similarity and classes: one pass each over the voxels (5.4 ns of them the similarity's cells).
COST_PER_VOXEL_S = 12e-9
#: Per octree level, the cumulative sums over the n_bins x n_bins overlap table.
COST_PER_LEVEL_BIN2_S = 40e-9
#: One affinity propagation iteration over the n_bins x n_bins similarity (3.3-7.6 ns measured, as scikit-learn's).
COST_PER_ITERATION_BIN2_S = 7e-9
#: Tissues (the intensity model fitted to the histogram, up to 8 tissues) and showing the design.
COST_FIXED_S = 0.25
COST_TISSUES_PER_BIN2_S = 0.2e-6
#: Expected seconds under which a design runs in Slicer's process.
IN_PROCESS_BUDGET_S = 1.0


def estimate_seconds(shape, options: Optional[dict] = None) -> float:
    """Expected seconds to design a volume of ``shape`` (voxels per axis) with ``options``, in this process.

    Affinity propagation is counted as running to its iteration limit once (it usually converges sooner: 40 to 360
    iterations were measured at 128 to 1024 bins; a retry with more damping, ``unconverged="raise-damping"``, can
    add to it).
    """
    opts = check_options({k: v for k, v in (options or {}).items() if k != "tissues"})
    n_bins = opts["n_bins"]
    voxels = 1
    for n in shape:
        voxels *= int(n)
    cells = tuple(max(int(n) - 1, 1) for n in shape)
    levels = len(octree_levels(cells))
    if opts["levels"]:
        levels = min(levels, opts["levels"])
    bins2 = float(n_bins) ** 2
    return (
        COST_FIXED_S
        + voxels * COST_PER_VOXEL_S
        + levels * bins2 * COST_PER_LEVEL_BIN2_S
        + opts["max_iter"] * bins2 * COST_PER_ITERATION_BIN2_S
        + bins2 * COST_TISSUES_PER_BIN2_S
    )


def runs_in_process(shape, options: Optional[dict] = None, budget_s: float = IN_PROCESS_BUDGET_S) -> bool:
    """Whether a design is cheap enough to compute in Slicer's own process (see :func:`estimate_seconds`)."""
    return estimate_seconds(shape, options) <= budget_s


class DesignSession:
    """The current volume, its design and its property node; edits rewrite the transfer function in place.

    Args:
        volume_rendering_logic: ``slicer.modules.volumerendering.logic()`` in Slicer, a
            ``vtkSlicerVolumeRenderingLogic`` headless (subclasses may instead override :meth:`volume_rendering_logic`).
    """

    def __init__(self, volume_rendering_logic=None) -> None:
        self._volume_rendering_logic = volume_rendering_logic
        self.volume_node = None
        self.property_node = None
        self.design: Optional[TransferFunctionDesign] = None
        # What the last Apply's default value range left out (padding, outliers), for the panel to say; or None.
        self.range_warning: Optional[str] = None
        # Similarity matrices of this session's runs by property node ID (the scene stores the design without it).
        self._similarities = {}

    def volume_rendering_logic(self):
        return self._volume_rendering_logic

    def python_executable(self) -> Optional[str]:
        """The Python that runs :meth:`start`'s child process (None: this process's ``sys.executable``)."""
        return None

    def temporary_folder(self) -> Optional[str]:
        """Where :meth:`start` writes the volume for its child process (None: the system's temporary folder)."""
        return None

    # Designing -----------------------------------------------------------------------------------------------------
    def run(self, volume_node, options: Optional[dict] = None, progress=None) -> TransferFunctionDesign:
        """Design in this process and show the design; raising from ``progress`` cancels (nothing changes then).

        ``options["tissues"]`` may be a Detail setting (see :func:`grouping_of_detail`)."""
        values, spacing, options, detail = self._prepared(volume_node, options)
        design = design_transfer_function(values, spacing, progress=progress, **options)
        if detail is not None:
            regroup_design(design, detail)
        self.apply(volume_node, design)
        self.range_warning = design.range_warning(RANGE_OVERRIDE)
        return design

    def _prepared(self, volume_node, options: Optional[dict]) -> tuple:
        """What :meth:`run` and :meth:`start` design: the volume's values and spacing, the engine's options (octree
        levels that fit) and the Detail count to regroup to afterwards (or None). The engine leaves CT padding and
        outlier voxels out of the bins unless a range is given, as the command line does; :attr:`range_warning` says
        what it left out."""
        values, spacing = volume_values(volume_node)
        options, _ = fit_levels(values.shape, options or {})
        options, detail = _engine_grouping(options)
        return values, spacing, options, detail

    def runs_in_process(self, volume_node, options: Optional[dict] = None) -> bool:
        """Whether :meth:`run` (in this process) should design the volume, rather than :meth:`start` (a child
        process): see :func:`runs_in_process`."""
        image = volume_node.GetImageData() if volume_node is not None else None
        if image is None:
            return True  # nothing to compute: run() reports the error at once
        return runs_in_process(tuple(reversed(image.GetDimensions())), options)

    def start(self, volume_node, options: Optional[dict] = None) -> DesignProcess:
        """Start designing in a child process (see :mod:`.worker`); give the job to :meth:`finish` when it ends."""
        values, spacing, options, detail = self._prepared(volume_node, options)
        job = DesignProcess(
            values, spacing, options, python=self.python_executable(), temporary_folder=self.temporary_folder()
        )
        job.detail = detail  # what finish() regroups the design to (None: the engine's grouping)
        return job

    def finish(self, volume_node, job: DesignProcess) -> TransferFunctionDesign:
        """Show the design a finished job made (its errors are raised); the job's files are removed."""
        try:
            design = job.result()
        finally:
            job.close()
        if getattr(job, "detail", None) is not None:
            regroup_design(design, job.detail)
        self.apply(volume_node, design)
        self.range_warning = design.range_warning(RANGE_OVERRIDE)
        return design

    def apply(self, volume_node, design: TransferFunctionDesign):
        """Show a design in the volume's 3D rendering and make it current; returns the property node."""
        self.property_node = mrml.apply_design(volume_node, design, self.volume_rendering_logic())
        self.volume_node = volume_node
        self.design = design
        if design.similarity is not None:
            self._similarities.pop(self.property_node.GetID(), None)
            self._similarities[self.property_node.GetID()] = design.similarity
            while len(self._similarities) > MAX_KEPT_SIMILARITIES:  # oldest first
                self._similarities.pop(next(iter(self._similarities)))
        return self.property_node

    def restore(self, volume_node) -> Optional[TransferFunctionDesign]:
        """Make the design stored for the volume (an earlier run, a saved scene) current; None if it has none.

        When the design's transfer function is still shown, its scalar opacity unit distance is set again (Slicer 5.8
        saves property nodes as ``.vp``, which does not keep it).
        """
        design = mrml.design_of_volume(volume_node) if volume_node is not None else None
        property_node = mrml.design_node_of(volume_node) if design is not None else None
        if design is not None and property_node is not None:
            if design.similarity is None:
                design.similarity = self._similarities.get(property_node.GetID())
            if mrml.shows_design(property_node, design):
                property_node.GetVolumeProperty().SetScalarOpacityUnitDistance(design.unit_distance)
        self.volume_node = volume_node
        self.property_node = property_node
        self.design = design
        return design

    def forget(self) -> None:
        """Drop the current design and the kept similarity matrices (the scene is being closed)."""
        self.volume_node = self.property_node = self.design = None
        self._similarities = {}

    # Editing (no recomputation: the transfer function is rewritten in place) ---------------------------------------
    def outside_change(self) -> Optional[str]:
        """How the shown transfer function differs from the current design (see :func:`.mrml.outside_change`).

        Ask the user before an edit when this is not None: the edit replaces what is shown with the design.
        """
        return mrml.outside_change(self.volume_node, self.design) if self.design is not None else None

    def current_design(self) -> TransferFunctionDesign:
        if self.design is None:
            raise RuntimeError("No transfer function has been designed yet.")
        return self.design

    def update(self) -> None:
        """Write the current design into the scene (the property node is shown again if another one was)."""
        self.property_node = mrml.update_design(self.volume_node, self.current_design(), self.volume_rendering_logic())

    def restyle(self) -> None:
        """Give the design's property node the design's shading and gradient opacity again (see
        :func:`.mrml.restyle_property_node`); the next edit writes its colours and opacities."""
        if self.property_node is not None:
            mrml.restyle_property_node(self.property_node, self.current_design())

    def set_class_color(self, class_id: int, color) -> None:
        self.current_design().set_class(class_id, color=color)
        self.update()

    def set_class_opacity(self, class_id: int, opacity: float) -> None:
        self.current_design().set_class(class_id, opacity=opacity)
        self.update()

    def set_class_visible(self, class_id: int, visible: bool) -> None:
        self.current_design().set_class(class_id, visible=visible)
        self.update()

    def solo_class(self, class_id: Optional[int]) -> None:
        self.current_design().solo(class_id)
        self.update()

    # The panel's tree: tissues and their classes ----------------------------------------------------------------
    def rows(self) -> list:
        """The rows of the panel's tree for the current design (see :class:`Row`); empty without a design."""
        return design_rows(self.design) if self.design is not None else []

    def edit(
        self,
        level: str,
        item_id: int,
        *,
        color=None,
        opacity: Optional[float] = None,
        visible: Optional[bool] = None,
    ) -> None:
        """Change a tissue's (and so all its classes') or one class's colour, opacity or visibility."""
        design = self.current_design()
        if level == TISSUE:
            design.set_tissue(item_id, color=color, opacity=opacity, visible=visible)
        elif level == CLASS:
            design.set_class(item_id, color=color, opacity=opacity, visible=visible)
        else:
            raise ValueError(f"level must be one of {LEVELS}; got {level!r}")
        self.update()

    def solo(self, level: str, item_id: Optional[int]) -> None:
        """Show only this tissue or class (``item_id`` None: leave solo mode)."""
        design = self.current_design()
        if level == TISSUE:
            design.solo_tissue(item_id)
        elif level == CLASS:
            design.solo(item_id)
        else:
            raise ValueError(f"level must be one of {LEVELS}; got {level!r}")
        self.update()

    def detail_range(self) -> tuple:
        """``(1, n)``: the Detail settings the current design offers besides :data:`AUTO_DETAIL`; ``n`` (one tissue per
        non-background class) is the thesis. ``(1, 1)`` without a design."""
        if self.design is None:
            return 1, 1
        return 1, max(self.design.hierarchy.max_tissues, 1)

    def detail(self) -> Optional[int]:
        """The Detail setting of the current design's grouping (None without a design)."""
        return detail_of_design(self.design) if self.design is not None else None

    def regroup(self, detail: int) -> None:
        """Regroup the current design (:data:`AUTO_DETAIL`: the automatic count; n: n tissues, one per class at the
        top of :meth:`detail_range`), instantly; the tissues get their default look; stored in the scene."""
        regroup_design(self.current_design(), detail)
        self.update()

    def level(self) -> str:
        """What the panel hands over (segments): :data:`TISSUE` when the design groups classes into tissues,
        :data:`CLASS` when each tissue is one class (the thesis' classes, named as such)."""
        design = self.current_design()
        return TISSUE if any(len(t.classes) > 1 for t in design.tissues) else CLASS

    def use_look(self, name: str) -> None:
        """Show the look ``name`` of the current design's gallery (:meth:`.TransferFunctionDesign.use_look`)."""
        self.current_design().use_look(name)
        self.update()

    def show_all_classes(self) -> None:
        self.current_design().show_all()
        self.update()

    def reset_colors(self) -> None:
        self.current_design().reset_look()
        self.update()

    # Handing the design over ---------------------------------------------------------------------------------------
    @staticmethod
    def default_export_extension(json_reader_available: bool) -> str:
        """``.vp.json`` where Slicer can read it back (5.10 and later), else the legacy ``.vp``."""
        return ".vp.json" if json_reader_available else ".vp"

    def export_transfer_function(self, path: str, default_extension: str = ".vp.json") -> str:
        """Write the current transfer function: legacy ``.vp`` if the name ends so, ``.vp.json`` if it ends with
        ``.json``, else ``default_extension`` is appended. Returns the path written."""
        design = self.current_design()
        lower = path.lower()
        if not lower.endswith((".vp", ".json")):
            path += default_extension
            lower = path.lower()
        if lower.endswith(".vp"):
            design.write_vp(path)
        else:
            design.write_vp_json(path)
        logging.info(f"IsoSimilarityTF: transfer function written to {path}")
        return path

    def export_segmentation(self, which: str = "shown", level: Optional[str] = None):
        """A new segmentation node with one segment per shown (or every) tissue or class of the current design;
        ``level`` None: :meth:`level`."""
        level = self.level() if level is None else level
        return mrml.export_segmentation(self.volume_node, self.current_design(), which=which, level=level)

    def add_preset(self, name: str):
        """Add the current design to the Volume Rendering preset menu; returns the preset node."""
        return mrml.add_preset(self.current_design(), self.volume_rendering_logic(), name)
