"""What the Slicer module does, without Qt: design a volume's transfer function, keep it in sync with the scene, edit
it class by class, and hand it to the rest of Slicer (files, segments, presets).

The module's logic (``IsoSimilarityTFLogic``) is this class plus Slicer's ``ScriptedLoadableModuleLogic``; headless,
it runs on a ``slicer-core`` scene, so the module's self-test checks (:mod:`.selftest`) run in ``make test`` too.
"""

import logging
from typing import Optional

from . import mrml
from .cells import octree_levels
from .design import TransferFunctionDesign, design_transfer_function
from .worker import DesignProcess

# Similarity matrices kept for volumes designed in this session (4096 bins: 128 MB each).
MAX_KEPT_SIMILARITIES = 4


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
        # Similarity matrices of this session's runs by property node ID (the scene stores the design without it).
        self._similarities = {}

    def volume_rendering_logic(self):
        return self._volume_rendering_logic

    def python_executable(self) -> Optional[str]:
        """The Python that runs :meth:`start`'s child process (None: this process's ``sys.executable``)."""
        return None

    # Designing -----------------------------------------------------------------------------------------------------
    def run(self, volume_node, options: Optional[dict] = None, progress=None) -> TransferFunctionDesign:
        """Design in this process and show the design; raising from ``progress`` cancels (nothing changes then)."""
        values, spacing = volume_values(volume_node)
        options, _ = fit_levels(values.shape, options or {})
        design = design_transfer_function(values, spacing, progress=progress, **options)
        self.apply(volume_node, design)
        return design

    def start(self, volume_node, options: Optional[dict] = None) -> DesignProcess:
        """Start designing in a child process (see :mod:`.worker`); give the job to :meth:`finish` when it ends."""
        values, spacing = volume_values(volume_node)
        options, _ = fit_levels(values.shape, options or {})
        return DesignProcess(values, spacing, options, python=self.python_executable())

    def finish(self, volume_node, job: DesignProcess) -> TransferFunctionDesign:
        """Show the design a finished job made (its errors are raised); the job's files are removed."""
        try:
            design = job.result()
        finally:
            job.close()
        self.apply(volume_node, design)
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
        return mrml.outside_change(self.volume_node) if self.design is not None else None

    def current_design(self) -> TransferFunctionDesign:
        if self.design is None:
            raise RuntimeError("No transfer function has been designed yet.")
        return self.design

    def update(self) -> None:
        """Write the current design into the scene (the property node is shown again if another one was)."""
        if self.volume_node is None or self.volume_node.GetScene() is None:
            raise RuntimeError("The volume of this design is no longer in the scene.")
        self.property_node = mrml.update_design(self.volume_node, self.current_design(), self.volume_rendering_logic())

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

    def export_segmentation(self, which: str = "shown"):
        """A new segmentation node with one segment per shown class of the current design."""
        if self.volume_node is None or self.volume_node.GetScene() is None:
            raise RuntimeError("The volume of this design is no longer in the scene.")
        return mrml.export_segmentation(self.volume_node, self.current_design(), which=which)

    def add_preset(self, name: str):
        """Add the current design to the Volume Rendering preset menu; returns the preset node."""
        return mrml.add_preset(self.current_design(), self.volume_rendering_logic(), name)
