"""The output folder: data files, classes.json, and the pictures and scene rendered by headless Slicer.

The folder holds ``similarity.npy``, ``similarity.png``, ``classes.json``, ``transfer_function.vp.json`` and
``transfer_function.vp`` (the chosen look), ``looks/<name>.vp.json`` (every look of the gallery), ``looks.png``
(their thumbnails, from the Lib's numpy ray caster, with their names) and, when rendering, ``render.png`` (the
volume rendered with the automatic transfer function by Slicer's own volume rendering, headless), ``classes.png``
(one small render per shown tissue, labelled), ``scene/scene.mrml`` (a Slicer scene with the volume and the
transfer function, to open in Slicer) and ``classes.seg.nrrd`` (one segment per shown class, Slicer's
segmentation file).

A volume read lazily (larger than memory) is pictured from a :class:`Preview`, every s-th voxel of it, with the
design of the whole volume; the scene and the segmentation, which would hold only the preview, are then not written.
"""

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from IsoSimilarityTFLib import __version__
from IsoSimilarityTFLib.design import Tissue, TransferFunctionDesign
from IsoSimilarityTFLib.mrml import apply_design, export_segmentation, update_property_node
from IsoSimilarityTFLib.pictures import similarity_image

from .console import ProgressPrinter
from .figures import class_grid, tissue_label_lines
from .formatting import value_decimals
from .output_folder import (
    LOOKS_FOLDER,
    OUTPUT_FILES,
    file_stamp,
    journal_output,
    look_file,
    save_scene,
    write_atomically,
)
from .read_errors import captured_native_output, first_message
from .rendering import HeadlessSlicer, write_png
from .volume import Volume

#: Side of a thumbnail in looks.png, in pixels.
THUMBNAIL_SIZE = 160
DEFAULT_VIEW = "anterior"
DEFAULT_SIZE = 512
DEFAULT_BACKDROP = "black"
DEFAULT_RAY_CASTING = "cpu"
MIN_SIZE = 32
#: Largest render.png side: bigger off-screen windows fail inside the OpenGL driver (a crash, not an error).
MAX_SIZE = 4096


@dataclass(frozen=True)
class Preview:
    """The in-memory volume the pictures of a volume read lazily are rendered from: every ``step``-th voxel of it.

    Attributes:
        volume: the preview, shape ``ceil((K, J, I) / step)``, spacing ``step`` times the input's, same origin and
            directions (see :func:`.chunked_readers.read_preview`).
        step: voxels of the input per preview voxel along each axis; 1: the whole volume, read into memory.
        read_s: seconds its read took.
    """

    volume: Volume
    step: int
    read_s: float

    def document(self) -> dict:
        """The ``input.preview`` entry of ``classes.json``."""
        return {
            "step": self.step,
            "shape": list(self.volume.shape),
            "dimensions": list(self.volume.shape[::-1]),
            "spacing": [float(s) for s in self.volume.spacing],
            "read_s": self.read_s,
        }


@dataclass
class RunResult:
    """What one run produced.

    Attributes:
        design: the transfer function design.
        volume: the input volume (its values a dask array when read lazily).
        info: the ``input`` entry of ``classes.json`` (without ``preview``, added from :attr:`preview`).
        outdir: the output folder (absolute).
        files: output role -> path of each file written (see :data:`OUTPUT_FILES`).
        scene_files: every file of the saved Slicer scene (scene.mrml and its data files).
        timings_s: seconds per stage: load, quantize, similarity, clustering, classes, write, render, total.
        warnings: warning lines given during the run.
        preview: what the pictures of a volume read lazily are rendered from; None for a volume in memory.
        kept: files a previous run wrote and someone changed since, left untouched: relative name -> the stamp
            recorded then, carried into ``written_stamps`` so that later runs leave them alone too.
        journaled: whether each output is journaled as it lands (:meth:`record`): the run's own process, not the
            render process working on a copy.
    """

    design: TransferFunctionDesign
    volume: Volume
    info: dict
    outdir: Path
    files: dict[str, Path] = field(default_factory=dict)
    scene_files: list[Path] = field(default_factory=list)
    timings_s: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    preview: Optional[Preview] = None
    kept: dict[str, Any] = field(default_factory=dict)
    journaled: bool = False

    def record(self, role: str, path: Path) -> None:
        """Record an output once it is complete (and journal it, so a run killed later still knows it is ours)."""
        self.files[role] = path
        if self.journaled:
            journal_output(self.outdir, path)

    def record_scene(self, paths: list[Path]) -> None:
        """Record the files of the saved scene (see :meth:`record`)."""
        self.scene_files = list(paths)
        if self.journaled:
            for path in self.scene_files:
                journal_output(self.outdir, path)

    @property
    def pictured(self) -> Volume:
        """The volume the pictures show: the preview, if any, else the input."""
        return self.volume if self.preview is None else self.preview.volume

    @property
    def full_resolution(self) -> bool:
        """Whether the pictured volume is the whole input: only then are the scene and the segmentation written."""
        return self.preview is None or self.preview.step == 1

    def document(self) -> dict:
        """The ``classes.json`` content: the design's document plus input, tool and output information."""
        document = self.design.to_dict()
        roles = self.design.look_context().roles
        document["looks"] = [look.summary(roles) for look in self.design.looks]
        document["timings_s"] = dict(self.timings_s)
        document["input"] = {**self.info, "preview": None if self.preview is None else self.preview.document()}
        document["tool"] = {"name": "isosimtf", "version": __version__}
        document["outputs"] = {role: path.relative_to(self.outdir).as_posix() for role, path in self.files.items()}
        # Every file this run wrote, with its size and time: the next run into this folder replaces or removes those
        # still as written, and never touches one changed since (nor those a previous run found changed: kept).
        # classes.json holds the stamps, so it cannot hold its own.
        names = {p.relative_to(self.outdir).as_posix(): p for p in self.written()}
        document["written"] = sorted({*names, *self.kept})
        document["written_stamps"] = {
            name: file_stamp(names[name]) if name in names else self.kept[name]
            for name in document["written"]
            if name != OUTPUT_FILES["classes_json"]
        }
        return document

    def written(self) -> list[Path]:
        """Every file this run wrote into the output folder."""
        return [*self.files.values(), *self.scene_files]


def write_data_files(result: RunResult) -> None:
    """Write similarity.npy/png, the transfer function files and classes.json into the output folder."""
    design, outdir = result.design, result.outdir
    writers = {
        "similarity_npy": lambda path: np.save(path, np.asarray(design.similarity, dtype=np.float64)),
        "similarity_png": lambda path: write_png(
            similarity_image(design.similarity, design.labels, design.class_colors), path
        ),
        "vp_json": design.write_vp_json,
        "vp": design.write_vp,
    }
    for role, write in writers.items():
        path = outdir / OUTPUT_FILES[role]
        write_atomically(path, write)
        result.record(role, path)  # once complete
    write_looks(result)
    write_classes_json(result)


def write_looks(result: RunResult) -> None:
    """Write ``looks/<name>.vp.json`` for every look of the gallery and ``looks.png``, their thumbnails."""
    design, outdir = result.design, result.outdir
    (outdir / LOOKS_FOLDER).mkdir(exist_ok=True)  # a link there was refused before any work (check_outputs)
    for look in design.looks:
        path = outdir / look_file(look.name)
        write_atomically(path, lambda temporary, look=look: design.write_vp_json(temporary, look))
        result.record(f"look_{look.name}", path)
    path = outdir / OUTPUT_FILES["looks_png"]
    picture = looks_picture(design, directions=result.volume.directions)
    write_atomically(path, lambda temporary: write_png(picture, temporary))
    result.record("looks_png", path)


def looks_picture(
    design: TransferFunctionDesign, size: int = THUMBNAIL_SIZE, directions: Optional[np.ndarray] = None
) -> np.ndarray:
    """The gallery's thumbnails side by side, each with its title and what it promises (the first is the first
    click, the chosen one marked), seen from the patient's front (``directions``: the volume's ``(3, 3)`` IJK-to-RAS
    directions, see :meth:`.TransferFunctionDesign.thumbnail`)."""
    chosen = design.look_name or design.looks[0].name
    tiles, labels, swatches = [], [], []
    for look in design.looks:
        tiles.append(design.thumbnail(look, size=size, directions=directions))
        labels.append((f"{look.title}{' (shown)' if look.name == chosen else ''}", look.name))
        shown = [c for c, v in zip(look.colors, look.visible) if v]
        swatches.append(shown[-1] if shown else [0.5, 0.5, 0.5])
    return class_grid(tiles, labels, swatches, columns=len(tiles))


def write_classes_json(result: RunResult) -> Path:
    """(Re)write classes.json with the run's current timings and file list."""
    path = result.outdir / OUTPUT_FILES["classes_json"]
    result.files["classes_json"] = path
    text = json.dumps(result.document(), indent=1) + "\n"
    write_atomically(path, lambda temporary: temporary.write_text(text, encoding="utf-8"))
    return path


def shown_tissues(design: TransferFunctionDesign) -> list[Tissue]:
    """The tissues the transfer function shows (some class of theirs is shown), in intensity order."""
    return [t for t in design.tissues if not t.background and any(design.is_shown(c) for c in t.classes)]


def open_headless(
    size: int = DEFAULT_SIZE,
    *,
    backdrop: str = DEFAULT_BACKDROP,
    ray_casting: str = DEFAULT_RAY_CASTING,
) -> "HeadlessSlicer":
    """The headless Slicer that :func:`render_outputs` draws in, its window at tile size: half of ``size`` (at least
    ``MIN_SIZE``).

    Args:
        backdrop: "black" or "slicer" (Slicer's blue gradient), see ``rendering.BACKDROPS``.
        ray_casting: "cpu" or "gpu", see ``rendering.RAY_CASTING``.
    """
    tile_size = max(MIN_SIZE, size // 2)
    background = (0.0, 0.0, 0.0) if backdrop == "black" else None
    return HeadlessSlicer(size=(tile_size, tile_size), rendering_method=ray_casting, background=background)


def render_outputs(
    result: RunResult,
    *,
    view: str = DEFAULT_VIEW,
    size: int = DEFAULT_SIZE,
    progress: Optional[ProgressPrinter] = None,
    headless: Optional["HeadlessSlicer"] = None,
) -> None:
    """Render with Slicer's volume rendering (headless): classes.png, render.png, and save the Slicer scene.

    One headless Slicer serves all pictures: the design goes onto the volume through :func:`mrml.apply_design`. The
    window starts at tile size, where the camera is fitted and framed to the content (the volume fills the pictures
    with a small margin) and each tissue tile shows ``design.solo_tissue(tissue)`` written into the same property node
    in place; only then does the window grow to ``size`` for render.png, seen from the same camera: every ray cast
    at full size is one render.png keeps. The scene is saved after solo mode is left, so it shows the full transfer
    function as in render.png. A volume read lazily is pictured from ``result.preview``; unless the preview is the
    whole volume (step 1), the scene and classes.seg.nrrd, which would hold only the preview, are not written.

    Args:
        headless: a new, empty :func:`open_headless` to draw in (the caller closes it); None: one with the defaults,
            opened and closed here.
    """
    design, volume, outdir = result.design, result.pictured, result.outdir
    if headless is None:
        with open_headless(size) as headless:
            render_outputs(result, view=view, size=size, progress=progress, headless=headless)
        return
    volume_node = headless.add_volume(volume.values, name=volume.name, ijk_to_ras=volume.ijk_to_ras())
    # The scene's copy of the volume is written raw: gzip took longer than all the tissue tiles (0.2 s on the
    # head CT), and the input is at hand for anyone who wants it small.
    volume_node.AddDefaultStorageNode()
    volume_node.GetStorageNode().SetUseCompression(False)
    property_node = apply_design(volume_node, design, headless.volume_rendering_logic)
    headless.frame_camera(view)
    tissues = shown_tissues(design)
    if tissues:
        path = outdir / OUTPUT_FILES["classes_png"]
        grid = _tissue_grid(headless, property_node, design, tissues, progress)
        write_atomically(path, lambda temporary: write_png(grid, temporary))
        result.record("classes_png", path)

    if progress is not None:
        progress.update("render.png")
    headless.render_window.SetSize(size, size)
    path = outdir / OUTPUT_FILES["render_png"]
    picture = headless.render(view=None, reset_camera=False)
    write_atomically(path, lambda temporary: write_png(picture, temporary))
    result.record("render_png", path)
    if not result.full_resolution:
        return

    if progress is not None:
        progress.update("classes.seg.nrrd")
    write_segmentation(result, headless, volume_node)

    if progress is not None:
        progress.update("scene")
    result.record_scene(save_scene(headless.scene, outdir))
    result.record("scene", outdir / OUTPUT_FILES["scene"])


def _tissue_grid(
    headless: "HeadlessSlicer",
    property_node: Any,
    design: TransferFunctionDesign,
    tissues: list[Tissue],
    progress: Optional[ProgressPrinter],
) -> np.ndarray:
    """classes.png: one tile per tissue, rendered alone (solo) in the current window and camera, labelled."""
    decimals = value_decimals(design.value_range, design.n_bins)
    total = max(int(np.sum(design.bin_voxels)), 1)
    tiles, labels = [], []
    previous_class, previous_tissue = design.solo_class, design.solo_tissue_id
    try:
        for number, tissue in enumerate(tissues, 1):
            if progress is not None:
                progress.update(f"tissue {number} of {len(tissues)}")
            design.solo_tissue(tissue.id)
            update_property_node(property_node, design)
            tiles.append(headless.render(view=None, reset_camera=False))
            labels.append(tissue_label_lines(tissue, tissue.voxels / total, decimals))
    finally:
        if previous_tissue is not None:
            design.solo_tissue(previous_tissue)
        else:
            design.solo(previous_class)
        update_property_node(property_node, design)
    return class_grid(tiles, labels, [t.color for t in tissues])


def write_segmentation(result: RunResult, headless, volume_node) -> None:
    """classes.seg.nrrd: one segment per shown class, with its name, colour and voxels (Slicer opens it as a
    segmentation). The segmentation is not left in the scene saved afterwards.

    No Segmentations module logic is attached to the scene: ``export_segmentation`` registers the converter rules it
    needs, and detaching such a logic afterwards logs a VTK warning ("Invalid scene given")."""
    path = result.outdir / OUTPUT_FILES["segmentation"]
    node = export_segmentation(volume_node, result.design)
    storage = headless.scene.AddNewNodeByClass("vtkMRMLSegmentationStorageNode")

    def write(temporary: Path) -> None:
        storage.SetFileName(str(temporary))
        with captured_native_output() as texts:
            written = storage.WriteData(node)
        if not written:
            raise OSError(first_message(texts) or "Slicer's segmentation writer failed")

    try:
        write_atomically(path, write)
    finally:
        for added in (storage, node.GetDisplayNode(), node):
            if added is not None:
                headless.scene.RemoveNode(added)
    result.record("segmentation", path)
