"""What the ``isosimtf`` command does, without the argument parsing: read, design, write the output folder, render."""

import gc
import time
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from IsoSimilarityTFLib.design import STAGES as DESIGN_STAGES
from IsoSimilarityTFLib.design import design_transfer_function
from IsoSimilarityTFLib.errors import OptionError, RenderError, UsageError
from IsoSimilarityTFLib.options import DEFAULT_OPTIONS, LOOK_NAMES, OPTIONS, check_together
from IsoSimilarityTFLib.source import is_lazy

from .chunked_readers import PreviewTap, preview_step, read_preview
from .console import ProgressPrinter
from .inputs import DEFAULT_PHANTOM_SIZE, PathLike, input_info, load_input
from .output_folder import (
    OutputFolder,
    PreviousRun,
    check_output_path,
    check_outputs,
    end_journal,
    look_file,
    previous_outputs,
    remove_stale,
)
from .outputs import (
    DEFAULT_BACKDROP,
    DEFAULT_RAY_CASTING,
    DEFAULT_SIZE,
    DEFAULT_VIEW,
    MAX_SIZE,
    MIN_SIZE,
    OUTPUT_FILES,
    Preview,
    RunResult,
    write_classes_json,
    write_data_files,
)
from .render_process import RenderProcess
from .rendering import BACKDROPS, RAY_CASTING, VIEW_DIRECTIONS, slicer_core_available

#: The command's stages, in order, as printed and as keys of ``timings_s`` in classes.json.
STAGES = ("read", *DESIGN_STAGES, "write", "render")

#: The outputs of a run without rendering, and of one with (the scene's files besides).
DATA_ROLES = ("similarity_npy", "similarity_png", "classes_json", "vp_json", "vp", "looks_png")
RENDER_ROLES = (*DATA_ROLES, "render_png", "classes_png", "segmentation")

#: Bins above which affinity propagation (cost: bins^2 per iteration, up to 3 rounds) takes minutes, silently.
SLOW_CLUSTERING_BINS = 1024
#: Integer volumes with at most this many distinct values are taken for label maps.
LABEL_MAP_VALUES = 16
#: Share of neighbouring voxel pairs (along i, outside the most common value) holding equal values above which an
#: integer volume is piecewise constant: a label map. Measured: AAL 0.89, Harvard-Oxford 0.91, JHU white matter
#: 0.75; the Colin27 T1 0.09, its skull-stripped brain 0.12, the head CT 0.06, the phantom 0.01.
LABEL_MAP_EQUAL_NEIGHBOURS = 0.5
#: Most distinct values of a label map (an atlas has tens to hundreds of labels).
LABEL_MAP_MAX_LABELS = 1024


@contextmanager
def _cyclic_gc_paused() -> Iterator[None]:
    """Pause Python's cyclic garbage collector (reference counting still frees everything else).

    A run makes almost no cyclic garbage, but importing VTK and slicer-core creates about a million objects,
    and the collector's full passes over them cost 0.2-0.3 s of a rendered run on the head CT.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


@_cyclic_gc_paused()
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
    look: Optional[str] = None,
    overwrite: bool = False,
) -> RunResult:
    """Read ``source``, design its transfer function and fill ``outdir``.

    The output folder is checked, created and locked first, before any work (see :mod:`.output_folder`); a run that
    fails before writing removes the folders it created. Files a previous run wrote there and this run does not
    (e.g. the pictures on a ``--no-render`` re-run) are removed, with a warning, unless changed since; no other file
    is touched.

    Args:
        source: a volume file, a DICOM folder, or ``"phantom"``.
        outdir: the output folder (created when missing).
        options: design options (see ``IsoSimilarityTFLib.options.OPTIONS``).
        render: also write render.png, classes.png, the scene and classes.seg.nrrd (needs ``slicer-core``; skipped
            with a warning when it is missing). A volume read lazily is pictured from a preview, every s-th voxel of
            it (see :func:`.chunked_readers.preview_step`), and its scene and segmentation are skipped with a warning
            unless the preview is the whole volume.
        view: camera direction (see ``VIEW_DIRECTIONS``).
        size: render.png side in pixels (class tiles are half of it).
        phantom_size, seed: voxels per axis and seed of the phantom.
        progress: stage printer.
        warn: called with each warning line.
        backdrop: 3D view backdrop of the pictures, "black" or "slicer" (see ``BACKDROPS``).
        ray_casting: "cpu" (default, reproducible) or "gpu" (see ``RAY_CASTING``).
        look: the look of the gallery the transfer function shows (one of ``LOOK_NAMES``; None: the first click's).
            A look the data do not support is refused once the design is made, before anything is written.
        overwrite: replace files with an output's name that no run of isosimtf recorded (a file a run wrote and
            someone changed since is still refused).

    Raises:
        UsageError, VolumeReadError, ValueError: bad output path, input or option (a usage or input error), another
            run writing into ``outdir``, or an output there changed since a previous run wrote it.
        ClusteringError: affinity propagation failed.
        OutputError: a file cannot be written. RenderError: rendering failed (the data files are written by then).
    """
    if view not in VIEW_DIRECTIONS:
        raise UsageError(f"view must be one of {', '.join(VIEW_DIRECTIONS)}; got {view!r}")
    if not MIN_SIZE <= size <= MAX_SIZE:
        raise UsageError(f"size must be from {MIN_SIZE} to {MAX_SIZE} pixels; got {size}")
    if backdrop not in BACKDROPS:
        raise UsageError(f"backdrop must be one of {', '.join(BACKDROPS)}; got {backdrop!r}")
    if ray_casting not in RAY_CASTING:
        raise UsageError(f"ray casting must be one of {', '.join(RAY_CASTING)}; got {ray_casting!r}")
    if look is not None and look not in LOOK_NAMES:
        raise UsageError(f"look must be one of {', '.join(LOOK_NAMES)}; got {look!r}")
    options = dict(options or {})
    try:  # the checks across options, worded with the flags (the design makes them again)
        check_together(options, lambda option: OPTIONS[option].flag)
    except OptionError as error:
        raise UsageError(str(error)) from None
    warnings: list[str] = []

    def warning(message: str) -> None:
        warnings.append(message)
        if warn is not None:
            if progress is not None:  # a warning starts its own line, never the end of a progress line
                progress.finish()
            warn(message)

    if render and not slicer_core_available():
        warning(
            "slicer-core is not installed, so render.png, classes.png and the scene are skipped "
            "(pip install slicer-core)"
        )
        render = False
    if progress is None:
        progress = ProgressPrinter(len(STAGES), quiet=True)
    progress.total = len(STAGES) if render else len(STAGES) - 1  # known before reading: it never changes mid-run
    path = check_output_path(outdir)
    with OutputFolder(path):
        previous = previous_outputs(path)
        names = [OUTPUT_FILES[role] for role in (RENDER_ROLES if render else DATA_ROLES)]
        names += [look_file(name) for name in LOOK_NAMES]
        input_file = Path(source) if Path(source).is_file() else None
        check_outputs(path, names, previous, scene=render, overwrite=overwrite, source=input_file)
        return _run_locked(
            source,
            path,
            previous,
            options,
            warning,
            warnings,
            render,
            progress,
            view=view,
            size=size,
            phantom_size=phantom_size,
            seed=seed,
            backdrop=backdrop,
            ray_casting=ray_casting,
            look=look,
            input_file=input_file,
        )


def _run_locked(
    source: PathLike,
    path: Path,
    previous: PreviousRun,
    options: dict,
    warning: Callable[[str], None],
    warnings: list[str],
    render: bool,
    progress: ProgressPrinter,
    *,
    view: str,
    size: int,
    phantom_size: int,
    seed: int,
    backdrop: str,
    ray_casting: str,
    look: Optional[str],
    input_file: Optional[Path],
) -> RunResult:
    """:func:`run` once the output folder is checked and locked: read, design, write, render."""
    # The pictures are made by a second process, started now so that its slow start overlaps reading and designing.
    renderer = RenderProcess(size=size, backdrop=backdrop, ray_casting=ray_casting) if render else nullcontext()
    with renderer:
        started = time.perf_counter()
        progress.stage("read", str(source))
        n_bins = options.get("n_bins", DEFAULT_OPTIONS["n_bins"])
        volume = load_input(source, phantom_size=phantom_size, seed=seed, n_bins=n_bins, warn=warning)
        timings = {"read": time.perf_counter() - started}
        info = input_info(source, volume)
        for message in _input_warnings(info, n_bins, volume.values):
            warning(message)
        step = preview_step(volume.shape) if render and info["read_lazily"] else None
        if step is not None and step > 1:
            warning(_preview_warning(volume.shape, volume.spacing, step))

        # The render preview of a volume read lazily is kept from the design's first read: no read of its own.
        preview = PreviewTap(volume.shape, step) if step is not None else None
        design = design_transfer_function(
            volume.values, volume.spacing, progress=progress.design_callback, value_tap=preview, **options
        )
        # Padding and outliers the design's default range left out, as the Slicer module says.
        range_warning = design.range_warning("--range LOW HIGH")
        if range_warning is not None:
            warning(range_warning)
        offered = [offered.name for offered in design.looks]
        if look is not None and look not in offered:
            raise UsageError(f"--look {look} is not offered for this volume; its looks: {', '.join(offered)}")
        design.use_look(look or offered[0])
        timings.update(design.timings_s)
        result = RunResult(design, volume, info, path, timings_s=timings, warnings=warnings, journaled=True)
        for message in _design_warnings(result):
            warning(message)

        start = time.perf_counter()
        progress.stage("write", str(path))
        result.kept = dict(previous.changed)  # changed since written: never touched, still recorded
        write_data_files(result)
        timings["write"] = time.perf_counter() - start

        try:
            if render:
                start = time.perf_counter()
                detail = f", from every {_ordinal(step)} voxel" if step is not None and step > 1 else ""
                progress.stage("render", f"(Slicer volume rendering, headless{detail})")
                _render(renderer, result, preview, view=view, size=size, progress=progress)
                timings["render"] = time.perf_counter() - start
        finally:
            removed = remove_stale(path, previous.unchanged, result.written(), input_file)
            if removed:
                progress.finish()
                names = ", ".join(removed)
                warning(f"removed {len(removed)} file(s) of a previous run that this run did not write: {names}")
            if previous.changed:
                progress.finish()
                names = ", ".join(sorted(previous.changed))
                warning(
                    f"kept {len(previous.changed)} file(s) of a previous run changed since it wrote them (not "
                    f"removed): {names}"
                )
            progress.finish()
            timings["total"] = time.perf_counter() - started
            write_classes_json(result)
            end_journal(path)  # classes.json records every output now
    return result


def _render(
    renderer: RenderProcess,
    result: RunResult,
    preview: Optional[PreviewTap],
    *,
    view: str,
    size: int,
    progress: ProgressPrinter,
) -> None:
    """The render stage: ``renderer`` makes the pictures and the scene; a failure is one :class:`RenderError` line.

    Args:
        preview: for a volume read lazily, the preview pictured (into ``result.preview``): kept from the design's
            read, or read now if that read did not give it all; None for a volume in memory.
    """
    try:
        if preview is not None:
            start = time.perf_counter()
            if preview.complete:
                volume = preview.preview(result.volume)
            else:
                progress.update(f"reading every {_ordinal(preview.step)} voxel" if preview.step > 1 else "reading")
                volume = read_preview(result.volume, preview.step)
            result.preview = Preview(volume, preview.step, time.perf_counter() - start)
        renderer.render(result, view=view, size=size, progress=progress)
    except (RuntimeError, OSError, ValueError) as error:
        raise RenderError(
            f"rendering failed ({error}); the other outputs are in '{result.outdir}' "
            "(use --no-render to skip rendering)"
        ) from None


def _preview_warning(shape: tuple[int, int, int], spacing: tuple[float, float, float], step: int) -> str:
    """The one line saying that the pictures come from a preview, and what is not written because of it."""
    dims = " x ".join(str(-(-n // step)) for n in shape[::-1])
    mm = " x ".join(f"{s * step:.3g}" for s in spacing)
    return (
        f"the volume is read lazily (out of core): render.png and classes.png are rendered from a preview, every "
        f"{_ordinal(step)} voxel along each axis ({dims} voxels of {mm} mm), with the transfer function designed on "
        "every voxel; the scene and classes.seg.nrrd are skipped (they would hold only the preview)"
    )


def _ordinal(number: int) -> str:
    """``"2nd"``, ``"3rd"``, ``"4th"``, ``"11th"``, ``"21st"``."""
    suffix = "th" if 10 <= number % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(number % 10, "th")
    return f"{number}{suffix}"


def label_count(values: np.ndarray) -> Optional[int]:
    """The number of labels (at least: those seen) of an integer volume that is a label map, else None.

    Taken on every s-th plane (k; s at most 8, and at least 32 planes): a label map is piecewise constant, the share
    of neighbouring voxel pairs along i that hold equal values, leaving out pairs of the most common value (the
    background), above :data:`LABEL_MAP_EQUAL_NEIGHBOURS`; or it spans at most :data:`LABEL_MAP_VALUES` values.
    """
    if not np.issubdtype(values.dtype, np.integer) or is_lazy(values):
        return None
    planes = values[:: max(1, min(8, values.shape[0] // 32))]  # at least 32 planes: small labels stay in
    # A part never holds more values than the whole: a scan's thousands of values show on every 4th row and column
    # (the 256^3 phantom: 13 ms instead of 65 ms).
    if np.unique(planes[:, ::4, ::4]).size > LABEL_MAP_MAX_LABELS:
        return None
    labels, counts = np.unique(planes, return_counts=True)
    if labels.size < 2 or labels.size > LABEL_MAP_MAX_LABELS:
        return None
    if int(labels[-1]) - int(labels[0]) < LABEL_MAP_VALUES:
        return int(labels.size)
    background = labels[np.argmax(counts)]
    left, right = planes[:, :, :-1], planes[:, :, 1:]
    counted = (left != background) | (right != background)
    equal = np.count_nonzero((left == right) & counted) / max(int(np.count_nonzero(counted)), 1)
    return int(labels.size) if equal > LABEL_MAP_EQUAL_NEIGHBOURS else None


#: Voxels this many times longer along one axis than another (e.g. 0.05 x 0.05 x 40 mm, a thick-slice stack of
#: fine images) render badly: the ray caster's steps follow the smallest spacing (issue 18, item 14).
MAX_ANISOTROPY = 20.0
#: Volumes of more voxels than this get an estimate of the time their design takes before it starts (a small Zarr
#: store may declare 10^12 voxels): about ten seconds of work at the rate below.
LONG_DESIGN_VOXELS = 2**30
#: Seconds per voxel of a design read from disk in chunks: make bench's out-of-core runs (7.4 s for 1024^3 int16,
#: 11.4 s for 1024^3 uint16 Zarr chunks: 7-11 ns per voxel), rounded up.
SECONDS_PER_VOXEL = 1.2e-8


def _input_warnings(info: dict, n_bins: int, values: Optional[np.ndarray] = None) -> list[str]:
    """Warnings about the input that the design cannot fix: a label map, or a clustering that will take minutes."""
    warnings = []
    labels = None if values is None else label_count(values)
    if labels is not None:
        warnings.append(
            f"the volume looks like a label map (at least {labels} distinct integer values, piecewise constant): "
            "isovalue similarity groups intensities of a continuous scan; label maps are better shown with their own "
            "colour table (if affinity propagation does not converge on it, use --preference minimum)"
        )
    spacing = info.get("spacing")
    if spacing and min(spacing) > 0 and max(spacing) / min(spacing) > MAX_ANISOTROPY:
        warnings.append(
            f"voxels of {' x '.join(f'{s:g}' for s in spacing)} mm are {max(spacing) / min(spacing):.0f} times longer "
            "along one axis than another: the pictures and Slicer's ray casting, which step by the smallest "
            "spacing, may come out dark or blocky; resample the volume to less anisotropic voxels for rendering"
        )
    voxels = float(np.prod(info.get("shape") or [0], dtype=np.float64))
    if voxels > LONG_DESIGN_VOXELS:
        warnings.append(
            f"the volume has {voxels:.3g} voxels: the design reads each once, which takes about "
            f"{_duration(voxels * SECONDS_PER_VOXEL)} here (longer from a slow disk or network); Ctrl+C stops it"
        )
    if n_bins > SLOW_CLUSTERING_BINS:
        warnings.append(
            f"affinity propagation on {n_bins} isovalues may take many minutes (its cost grows with the square of "
            f"--bins; the default is {DEFAULT_OPTIONS['n_bins']})"
        )
    return warnings


def _duration(seconds: float) -> str:
    """``seconds`` in the largest unit that keeps a number above 1: "40 s", "12 minutes", "3.5 hours", "2.1 days"."""
    for unit, size in (("days", 86400.0), ("hours", 3600.0), ("minutes", 60.0)):
        if seconds >= 2 * size:
            return f"{seconds / size:.2g} {unit}"
    return f"{seconds:.0f} s"


def _design_warnings(result: RunResult) -> list[str]:
    """Warnings about a transfer function that would show nothing useful (the run still succeeds)."""
    design = result.design
    shown = [c for c in design.classes if design.is_shown(c.id)]
    if len(design.classes) == 1:
        return ["affinity propagation found a single class, the background: the transfer function shows nothing"]
    if not shown:
        return ["every class is hidden (background, or --max-classes 0): the transfer function shows nothing"]
    return []
