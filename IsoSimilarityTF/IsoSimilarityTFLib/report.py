"""What the ``isosimtf`` command does, without the argument parsing: read, design, write the output folder, render.

The output folder holds ``similarity.npy``, ``similarity.png``, ``classes.json``, ``transfer_function.vp.json``,
``transfer_function.vp`` and, unless rendering is off or ``slicer-core`` is missing, ``render.png`` (the volume
rendered with the automatic transfer function by Slicer's own volume rendering, headless), ``classes.png`` (one small
render per shown class, labelled) and ``scene/scene.mrml`` (a Slicer scene with the volume and the transfer function,
to open in Slicer).

No Qt, no matplotlib: pictures are numpy arrays written with VTK's PNG writer, label text comes from VTK's built-in
FreeType text renderer. ``slicer-core`` is imported only when rendering.
"""

import json
import math
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional, TextIO, Union

import numpy as np

from .classes import IsovalueClass
from .design import DEFAULT_OPTIONS, TransferFunctionDesign, design_transfer_function
from .pictures import similarity_image
from .rendering import BACKDROPS, RAY_CASTING, VIEW_DIRECTIONS, slicer_core_available
from .volume_io import Volume, read_volume

PathLike = Union[str, "os.PathLike[str]"]

#: The INPUT word that selects the built-in head phantom (a file or folder named so is read as ``./phantom``).
PHANTOM_INPUT = "phantom"

#: Output file names, by role.
OUTPUT_FILES = {
    "similarity_npy": "similarity.npy",
    "similarity_png": "similarity.png",
    "classes_json": "classes.json",
    "vp_json": "transfer_function.vp.json",
    "vp": "transfer_function.vp",
    "render_png": "render.png",
    "classes_png": "classes.png",
    "scene": "scene/scene.mrml",
}
SCENE_FOLDER = "scene"

DEFAULT_VIEW = "anterior"
DEFAULT_SIZE = 512
DEFAULT_BACKDROP = "black"
DEFAULT_RAY_CASTING = "cpu"
MIN_SIZE = 32
DEFAULT_PHANTOM_SIZE = 128

# Class grid: tile background (the 3D view's black) and the label strip under each tile.
LABEL_BACKGROUND = (28, 28, 28)
LABEL_TEXT = (235, 235, 235)
GRID_GAP = 4
GRID_BACKGROUND = (64, 64, 64)

STAGE_NAMES = ("reading", "quantizing", "similarity", "clustering", "classes", "writing", "rendering")


class OutputError(RuntimeError):
    """The output folder or a file in it cannot be written."""


class UsageError(ValueError):
    """The command was asked something it cannot do (e.g. the output folder is a file)."""


class RenderError(RuntimeError):
    """Rendering with headless Slicer failed (the other outputs are written)."""


# ---------------------------------------------------------------------------------------------------------------
# Progress
# ---------------------------------------------------------------------------------------------------------------


class ProgressPrinter:
    """One line per stage on a stream (``[3/7] similarity``); on a terminal, sub-steps rewrite the current line.

    Args:
        total: number of stages.
        stream: where to write (stderr by default).
        quiet: print nothing.
    """

    def __init__(self, total: int, stream: Optional[TextIO] = None, quiet: bool = False) -> None:
        self.total = total
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self.index = 0
        self._line = ""
        self._open = False
        isatty = getattr(self.stream, "isatty", None)
        self.tty = bool(isatty()) if callable(isatty) else False

    def stage(self, name: str, detail: str = "") -> None:
        """Start the next stage: print ``[i/N] name detail``."""
        self.index += 1
        self._line = f"[{self.index}/{self.total}] {name}" + (f" {detail}" if detail else "")
        if self.quiet:
            return
        self._end_line()
        self.stream.write(self._line)
        self._open = True
        if not self.tty:
            self._end_line()
        self.stream.flush()

    def update(self, message: str) -> None:
        """Show a sub-step of the current stage on the same line (terminals only)."""
        if self.quiet or not self.tty or not self._open:
            return
        self.stream.write(f"\r\x1b[K{self._line}: {message}")
        self.stream.flush()

    def finish(self) -> None:
        """End the current line (call before printing anything else on the stream)."""
        if not self.quiet:
            self._end_line()
            self.stream.flush()

    def _end_line(self) -> None:
        if self._open:
            self.stream.write("\n")
            self._open = False

    def design_callback(self, stage: str, fraction: float, message: str) -> None:
        """Adapter for :func:`design_transfer_function`'s ``progress(stage, fraction, message)``."""
        names = {"quantize": "quantizing", "similarity": "similarity", "clustering": "clustering", "classes": "classes"}
        if fraction == 0.0 and stage in names:
            details = {"similarity": "(hierarchical isosurface similarity)", "clustering": "(affinity propagation)"}
            self.stage(names[stage], details.get(stage, ""))
        elif message:
            self.update(message[len(stage) + 2 :] if message.startswith(f"{stage}: ") else message)


# ---------------------------------------------------------------------------------------------------------------
# Input
# ---------------------------------------------------------------------------------------------------------------


def is_phantom_input(source: PathLike) -> bool:
    """Whether INPUT names the built-in phantom: exactly the word ``phantom`` (``./phantom`` is a path)."""
    return isinstance(source, str) and source == PHANTOM_INPUT


def load_input(source: PathLike, *, phantom_size: int = DEFAULT_PHANTOM_SIZE, seed: int = 0) -> Volume:
    """Read the input volume: a file or DICOM folder (see :func:`read_volume`), or the word ``phantom``.

    The phantom is centred on the RAS origin. The word ``phantom`` always means the phantom; write ``./phantom`` to
    read a file or folder of that name.

    Raises:
        VolumeReadError: unreadable or unsupported input. ValueError: bad phantom size or seed.
    """
    if is_phantom_input(source):
        from .phantom import head_phantom

        phantom = head_phantom(phantom_size, seed=seed)
        dims = np.asarray(phantom.values.shape[::-1], dtype=float)
        origin = -0.5 * (dims - 1.0) * np.asarray(phantom.spacing)
        return Volume(phantom.values, phantom.spacing, tuple(origin), np.eye(3), PHANTOM_INPUT)
    return read_volume(source)


def input_info(source: PathLike, volume: Volume) -> dict:
    """The ``input`` entry of ``classes.json``: where the volume came from and its geometry."""
    is_phantom = is_phantom_input(source)
    values = volume.values
    return {
        "path": PHANTOM_INPUT if is_phantom else str(Path(source).resolve()),
        "name": volume.name,
        "shape": list(volume.shape),
        "dimensions": list(volume.shape[::-1]),
        "spacing": [float(s) for s in volume.spacing],
        "origin": [float(o) for o in volume.origin],
        "ijk_to_ras": volume.ijk_to_ras().tolist(),
        "dtype": str(values.dtype),
        "value_min": float(np.min(values)) if values.size else None,
        "value_max": float(np.max(values)) if values.size else None,
    }


# ---------------------------------------------------------------------------------------------------------------
# Pictures: text, class tiles and the class grid
# ---------------------------------------------------------------------------------------------------------------


def text_image(text: str, font_size: int = 13) -> Optional[np.ndarray]:
    """Coverage (alpha, float 0..1) of ``text`` as a ``(height, width)`` array, from VTK's FreeType renderer.

    Returns None when VTK has no text renderer (then labels are left out).
    """
    import vtkmodules.vtkRenderingFreeType  # noqa: F401  (registers the FreeType text renderer)
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkRenderingCore import vtkTextProperty, vtkTextRenderer

    renderer = vtkTextRenderer.GetInstance()
    if renderer is None or not text:
        return None
    prop = vtkTextProperty()
    prop.SetFontFamilyToArial()
    prop.SetFontSize(int(font_size))
    prop.SetColor(1.0, 1.0, 1.0)
    prop.SetJustificationToLeft()
    prop.SetVerticalJustificationToBottom()
    image = vtkImageData()
    dims = [0, 0]
    if not renderer.RenderString(prop, text, image, dims, 72):
        return None
    width, height, _ = image.GetDimensions()
    rgba = vtk_to_numpy(image.GetPointData().GetScalars()).reshape(height, width, -1)[::-1]
    alpha = rgba[..., -1].astype(np.float64) / 255.0
    rows = np.flatnonzero(alpha.max(axis=1) > 0)
    columns = np.flatnonzero(alpha.max(axis=0) > 0)
    if rows.size == 0:
        return None
    return alpha[: rows[-1] + 1, : columns[-1] + 1]


def draw_text(image: np.ndarray, text: str, x: int, y: int, font_size: int, color=LABEL_TEXT) -> int:
    """Blend ``text`` into ``image`` (uint8 RGB, in place) with its top-left corner at ``(x, y)``.

    Text that does not fit is clipped. Returns the width drawn in pixels (0 when nothing was drawn).
    """
    alpha = text_image(text, font_size)
    if alpha is None:
        return 0
    height = min(alpha.shape[0], image.shape[0] - y)
    width = min(alpha.shape[1], image.shape[1] - x)
    if height <= 0 or width <= 0:
        return 0
    a = alpha[:height, :width, None]
    region = image[y : y + height, x : x + width].astype(np.float64)
    blended = region * (1.0 - a) + np.asarray(color, dtype=np.float64) * a
    image[y : y + height, x : x + width] = np.round(blended).astype(np.uint8)
    return width


def value_decimals(value_range: tuple[float, float], n_bins: int) -> int:
    """Decimals that tell neighbouring bin edges apart (0 for HU over 256 bins)."""
    width = (value_range[1] - value_range[0]) / max(n_bins, 1)
    if not width > 0 or not math.isfinite(width):
        return 0
    return int(min(6, max(0, math.ceil(-math.log10(width)))))


def format_ranges(ranges: list, decimals: int, limit: int = 3) -> str:
    """``"-100 .. 250, 300 .. 310"`` for a class's value ranges; past ``limit`` runs, ``"+N more"``."""
    parts = [f"{lo:.{decimals}f} .. {hi:.{decimals}f}" for lo, hi in ranges[:limit]]
    if len(ranges) > limit:
        parts.append(f"+{len(ranges) - limit} more")
    return ", ".join(parts)


def format_percent(fraction: float, decimals: int = 1) -> str:
    """A voxel share in percent; ``"<0.1"`` rather than ``"0.0"`` for a small but non-zero share."""
    percent = 100.0 * float(fraction)
    if 0.0 < percent < 10.0**-decimals:
        return f"<{10.0**-decimals:.{decimals}f}"
    return f"{percent:.{decimals}f}"


def color_hex(color) -> str:
    """``#rrggbb`` of an RGB colour in 0..1."""
    return "#" + "".join(f"{int(round(255 * min(max(float(c), 0.0), 1.0))):02x}" for c in color)


def class_label_lines(item: IsovalueClass, decimals: int) -> tuple[str, str]:
    """The two label lines of a class tile: rank and voxel share, then the intensity range(s)."""
    first = f"#{item.rank}  {format_percent(item.fraction)}% of voxels"
    return first, format_ranges(item.value_ranges, decimals, limit=1)


def class_grid(
    tiles: list[np.ndarray], labels: list[tuple[str, str]], colors: list, *, columns: Optional[int] = None
) -> np.ndarray:
    """A grid of equally sized RGB tiles, each with a two-line label and a colour swatch under it.

    Args:
        tiles: ``(h, w, 3)`` uint8 pictures, all the same size.
        labels: two text lines per tile.
        colors: ``[r, g, b]`` in 0..1 per tile (the swatch).
        columns: tiles per row; default about square.
    """
    if not tiles:
        raise ValueError("no tiles to lay out")
    height, width = tiles[0].shape[:2]
    count = len(tiles)
    columns = columns or max(1, math.ceil(math.sqrt(count)))
    rows = math.ceil(count / columns)
    font_size = int(min(16, max(9, width // 16)))
    line_height = font_size + 4
    label_height = 2 * line_height + 6
    cell_height = height + label_height
    grid = np.empty(
        (rows * cell_height + (rows + 1) * GRID_GAP, columns * width + (columns + 1) * GRID_GAP, 3), dtype=np.uint8
    )
    grid[:] = GRID_BACKGROUND
    swatch = line_height - 4
    for index, (tile, (line1, line2), color) in enumerate(zip(tiles, labels, colors)):
        row, column = divmod(index, columns)
        top = GRID_GAP + row * (cell_height + GRID_GAP)
        left = GRID_GAP + column * (width + GRID_GAP)
        grid[top : top + height, left : left + width] = tile
        strip = np.empty((label_height, width, 3), dtype=np.uint8)
        strip[:] = LABEL_BACKGROUND
        strip[4 : 4 + swatch, 4 : 4 + swatch] = np.round(255.0 * np.clip(np.asarray(color, float), 0, 1))
        draw_text(strip, line1, 8 + swatch, 3, font_size)
        draw_text(strip, line2, 4, 3 + line_height, font_size)
        grid[top + height : top + cell_height, left : left + width] = strip
    return grid


# ---------------------------------------------------------------------------------------------------------------
# The run
# ---------------------------------------------------------------------------------------------------------------


@dataclass
class RunResult:
    """What one run produced.

    Attributes:
        design: the transfer function design.
        volume: the input volume.
        info: the ``input`` entry of ``classes.json``.
        outdir: the output folder (absolute).
        files: output role -> path of each file written (see :data:`OUTPUT_FILES`).
        timings_s: seconds per stage: load, quantize, similarity, clustering, classes, write, render, total.
        warnings: warning lines given during the run.
    """

    design: TransferFunctionDesign
    volume: Volume
    info: dict
    outdir: Path
    files: dict[str, Path] = field(default_factory=dict)
    timings_s: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def document(self) -> dict:
        """The ``classes.json`` content: the design's document plus input, tool and output information."""
        from . import __version__

        document = self.design.to_dict()
        document["timings_s"] = dict(self.timings_s)
        document["input"] = self.info
        document["tool"] = {"name": "isosimtf", "version": __version__}
        document["outputs"] = {role: path.relative_to(self.outdir).as_posix() for role, path in self.files.items()}
        return document


def prepare_output_folder(outdir: PathLike) -> Path:
    """Create the output folder (and its parents) if needed; return it absolute.

    Raises:
        UsageError: the path exists and is not a folder. OutputError: it cannot be created.
    """
    path = Path(outdir).expanduser().resolve()
    if path.exists() and not path.is_dir():
        raise UsageError(f"the output path '{outdir}' exists and is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(f"cannot create the output folder '{outdir}': {error.strerror or error}") from None
    return path


def write_data_files(result: RunResult) -> None:
    """Write similarity.npy/png, the transfer function files and classes.json into the output folder."""
    from .rendering import write_png

    design, outdir = result.design, result.outdir
    paths = {role: outdir / OUTPUT_FILES[role] for role in ("similarity_npy", "similarity_png", "vp_json", "vp")}
    try:
        np.save(paths["similarity_npy"], np.asarray(design.similarity, dtype=np.float64))
        write_png(similarity_image(design.similarity, design.labels, design.class_colors), paths["similarity_png"])
        design.write_vp_json(paths["vp_json"])
        design.write_vp(paths["vp"])
    except OSError as error:
        raise OutputError(f"cannot write into '{outdir}': {error.strerror or error}") from None
    result.files.update(paths)
    write_classes_json(result)


def write_classes_json(result: RunResult) -> Path:
    """(Re)write classes.json with the run's current timings and file list."""
    path = result.outdir / OUTPUT_FILES["classes_json"]
    result.files["classes_json"] = path
    try:
        path.write_text(json.dumps(result.document(), indent=1) + "\n", encoding="utf-8")
    except OSError as error:
        raise OutputError(f"cannot write '{path}': {error.strerror or error}") from None
    return path


def shown_classes(design: TransferFunctionDesign) -> list[IsovalueClass]:
    """The classes shown by the transfer function, largest first."""
    return sorted((c for c in design.classes if design.is_shown(c.id)), key=lambda c: c.rank)


def render_outputs(
    result: RunResult,
    *,
    view: str = DEFAULT_VIEW,
    size: int = DEFAULT_SIZE,
    tile_size: Optional[int] = None,
    progress: Optional[ProgressPrinter] = None,
    backdrop: str = DEFAULT_BACKDROP,
    ray_casting: str = DEFAULT_RAY_CASTING,
) -> None:
    """Render with Slicer's volume rendering (headless): render.png, classes.png, and save the Slicer scene.

    One headless Slicer serves all pictures: the design goes onto the volume through :func:`mrml.apply_design`;
    render.png is framed to its content (:func:`frame_content`: the volume fills the picture with a small margin),
    and each class tile shows ``design.solo(class)`` written into the same property node in place, seen from the
    same narrowed camera. The scene is saved after solo mode is left, so it shows the full transfer function as in
    render.png.

    Args:
        backdrop: "black" or "slicer" (Slicer's blue gradient), see :data:`BACKDROPS`.
        ray_casting: "cpu" or "gpu", see :data:`RAY_CASTING`.
    """
    from .mrml import apply_design, update_property_node
    from .rendering import HeadlessSlicer, write_png

    design, volume, outdir = result.design, result.volume, result.outdir
    tile_size = tile_size or max(MIN_SIZE, size // 2)
    classes = shown_classes(design)
    decimals = value_decimals(design.value_range, design.n_bins)
    background = (0.0, 0.0, 0.0) if backdrop == "black" else None
    with HeadlessSlicer(size=(size, size), rendering_method=ray_casting, background=background) as headless:
        volume_node = headless.add_volume(volume.values, name=volume.name, ijk_to_ras=volume.ijk_to_ras())
        property_node = apply_design(volume_node, design, headless.volume_rendering_logic)
        if progress is not None:
            progress.update("render.png")
        picture = headless.render(view, frame=True)
        path = outdir / OUTPUT_FILES["render_png"]
        write_png(picture, path)
        result.files["render_png"] = path

        if classes:
            headless.render_window.SetSize(tile_size, tile_size)
            tiles, labels, colors = [], [], []
            previous_solo = design.solo_class
            try:
                for number, item in enumerate(classes, 1):
                    if progress is not None:
                        progress.update(f"class {number} of {len(classes)}")
                    design.solo(item.id)
                    update_property_node(property_node, design)
                    tiles.append(headless.render(view=None, reset_camera=False))
                    labels.append(class_label_lines(item, decimals))
                    colors.append(item.color)
            finally:
                design.solo(previous_solo)
                update_property_node(property_node, design)
                headless.render_window.SetSize(size, size)
            path = outdir / OUTPUT_FILES["classes_png"]
            write_png(class_grid(tiles, labels, colors), path)
            result.files["classes_png"] = path

        if progress is not None:
            progress.update("scene")
        scene_dir = outdir / SCENE_FOLDER
        if scene_dir.exists():
            shutil.rmtree(scene_dir)
        scene_dir.mkdir(parents=True)
        if not headless.scene.SaveSceneToSlicerDataBundleDirectory(str(scene_dir)):
            raise RenderError(f"Slicer could not save the scene into '{scene_dir}'")
        result.files["scene"] = scene_dir / f"{scene_dir.name}.mrml"


def run(
    source: PathLike,
    outdir: PathLike,
    *,
    options: Optional[dict] = None,
    render: bool = True,
    view: str = DEFAULT_VIEW,
    size: int = DEFAULT_SIZE,
    phantom_size: int = DEFAULT_PHANTOM_SIZE,
    seed: int = 0,
    progress: Optional[ProgressPrinter] = None,
    warn: Optional[Callable[[str], None]] = None,
    backdrop: str = DEFAULT_BACKDROP,
    ray_casting: str = DEFAULT_RAY_CASTING,
) -> RunResult:
    """Read ``source``, design its transfer function and fill ``outdir``.

    Args:
        source: a volume file, a DICOM folder, or ``"phantom"``.
        outdir: the output folder (created when missing).
        options: design options (see ``DEFAULT_OPTIONS``).
        render: also write render.png, classes.png and the scene (needs ``slicer-core``; skipped with a warning
            when it is missing).
        view: camera direction (see ``VIEW_DIRECTIONS``).
        size: render.png side in pixels (class tiles are half of it).
        phantom_size, seed: voxels per axis and seed of the phantom.
        progress: stage printer.
        warn: called with each warning line.
        backdrop: 3D view backdrop of the pictures, "black" or "slicer" (see ``BACKDROPS``).
        ray_casting: "cpu" (default, reproducible) or "gpu" (see ``RAY_CASTING``).

    Raises:
        UsageError, VolumeReadError, ValueError: bad output path, input or option (a usage or input error).
        ClusteringError: affinity propagation failed. OutputError: a file cannot be written. RenderError: rendering
        failed (the data files are written by then).
    """
    if view not in VIEW_DIRECTIONS:
        raise UsageError(f"view must be one of {', '.join(VIEW_DIRECTIONS)}; got {view!r}")
    if size < MIN_SIZE:
        raise UsageError(f"size must be at least {MIN_SIZE} pixels; got {size}")
    if backdrop not in BACKDROPS:
        raise UsageError(f"backdrop must be one of {', '.join(BACKDROPS)}; got {backdrop!r}")
    if ray_casting not in RAY_CASTING:
        raise UsageError(f"ray casting must be one of {', '.join(RAY_CASTING)}; got {ray_casting!r}")
    options = {**DEFAULT_OPTIONS, **(options or {})}
    warnings: list[str] = []

    def warning(message: str) -> None:
        warnings.append(message)
        if warn is not None:
            warn(message)

    if render and not slicer_core_available():
        warning(
            "slicer-core is not installed, so render.png, classes.png and the scene are skipped "
            "(pip install slicer-core)"
        )
        render = False
    if progress is None:
        progress = ProgressPrinter(len(STAGE_NAMES), quiet=True)
    progress.total = len(STAGE_NAMES) if render else len(STAGE_NAMES) - 1
    path = prepare_output_folder(outdir)

    started = time.perf_counter()
    progress.stage("reading", str(source))
    volume = load_input(source, phantom_size=phantom_size, seed=seed)
    timings = {"load": time.perf_counter() - started}

    design = design_transfer_function(volume.values, volume.spacing, progress=progress.design_callback, **options)
    timings.update(design.timings_s)
    result = RunResult(design, volume, input_info(source, volume), path, timings_s=timings, warnings=warnings)

    start = time.perf_counter()
    progress.stage("writing", str(path))
    write_data_files(result)
    timings["write"] = time.perf_counter() - start

    if render:
        start = time.perf_counter()
        progress.stage("rendering", "(Slicer volume rendering, headless)")
        try:
            render_outputs(result, view=view, size=size, progress=progress, backdrop=backdrop, ray_casting=ray_casting)
        except (RuntimeError, OSError, ValueError) as error:
            raise RenderError(
                f"rendering failed ({error}); the other outputs are in '{path}' (use --no-render to skip rendering)"
            ) from None
        timings["render"] = time.perf_counter() - start
    progress.finish()
    timings["total"] = time.perf_counter() - started
    write_classes_json(result)
    return result


# ---------------------------------------------------------------------------------------------------------------
# Summary
# ---------------------------------------------------------------------------------------------------------------


def summary_text(result: RunResult) -> str:
    """The table printed at the end: classes, affinity propagation, times and the output folder."""
    design, info = result.design, result.info
    decimals = value_decimals(design.value_range, design.n_bins)
    dims = " x ".join(str(d) for d in info["dimensions"])
    spacing = " x ".join(f"{s:.3g}" for s in info["spacing"])
    low, high = design.value_range
    lines = [
        f"{info['name']}: {dims} voxels of {spacing} mm, {design.n_bins} isovalues over "
        f"[{low:.{decimals}f}, {high:.{decimals}f}]",
        "",
    ]
    rows = []
    for item in sorted(design.classes, key=lambda c: c.rank):
        state = "background" if item.background else ("shown" if design.is_shown(item.id) else "hidden")
        rows.append(
            (
                str(item.rank),
                str(item.id),
                format_percent(item.fraction, 2),
                format_ranges(item.value_ranges, decimals),
                color_hex(item.color),
                f"{item.opacity:.3f}",
                state,
            )
        )
    header = ("rank", "id", "voxels %", "intensity range(s)", "colour", "opacity", "state")
    widths = [max(len(header[k]), *(len(row[k]) for row in rows)) for k in range(len(header))]
    left = {3, 4, 6}

    def fmt(row) -> str:
        cells = [cell.ljust(w) if k in left else cell.rjust(w) for k, (cell, w) in enumerate(zip(row, widths))]
        return "  ".join(cells).rstrip()

    lines += [fmt(header), fmt(["-" * w for w in widths]), *(fmt(row) for row in rows), ""]
    clustering = design.clustering
    shown = sum(1 for c in design.classes if design.is_shown(c.id))
    lines.append(
        f"classes: {clustering.get('n_classes', len(design.classes))} ({shown} shown); affinity propagation: "
        f"{clustering.get('n_iter')} iterations, {'converged' if clustering.get('converged') else 'NOT converged'}, "
        f"damping {clustering.get('damping', design.options.get('damping'))}, "
        f"preference {clustering.get('preference', 0.0):.4g} ({design.options.get('preference')})"
    )
    times = ", ".join(f"{stage} {seconds:.2f}" for stage, seconds in result.timings_s.items() if stage != "total")
    lines.append(f"time (s): {times}; total {result.timings_s.get('total', 0.0):.2f}")
    lines.append(f"output: {result.outdir}")
    lines += [f"  {path.relative_to(result.outdir).as_posix()}" for path in result.files.values()]
    return "\n".join(lines) + "\n"
