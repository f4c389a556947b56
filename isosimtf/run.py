"""What the ``isosimtf`` command does, without the argument parsing: read, design, write the output folder, render."""

import gc
import time
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from typing import Callable, Optional

from IsoSimilarityTFLib.design import STAGES as DESIGN_STAGES
from IsoSimilarityTFLib.design import design_transfer_function
from IsoSimilarityTFLib.errors import RenderError, UsageError
from IsoSimilarityTFLib.options import DEFAULT_OPTIONS

from .console import ProgressPrinter
from .inputs import DEFAULT_PHANTOM_SIZE, PathLike, input_info, load_input
from .output_folder import check_output_path, create_output_folder, previous_outputs, remove_stale
from .outputs import (
    DEFAULT_BACKDROP,
    DEFAULT_RAY_CASTING,
    DEFAULT_SIZE,
    DEFAULT_VIEW,
    MAX_SIZE,
    MIN_SIZE,
    RunResult,
    write_classes_json,
    write_data_files,
)
from .render_process import RenderProcess
from .rendering import BACKDROPS, RAY_CASTING, VIEW_DIRECTIONS, slicer_core_available

#: The command's stages, in order, as printed and as keys of ``timings_s`` in classes.json.
STAGES = ("read", *DESIGN_STAGES, "write", "render")

#: Bins above which affinity propagation (cost: bins^2 per iteration, up to 3 rounds) takes minutes, silently.
SLOW_CLUSTERING_BINS = 1024
#: Integer volumes with at most this many distinct values are taken for label maps.
LABEL_MAP_VALUES = 16


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
) -> RunResult:
    """Read ``source``, design its transfer function and fill ``outdir``.

    The output path is checked first and the folder created only when there is something to write, so a run that
    fails on its input leaves no folder behind. Files a previous run wrote there and this run does not (e.g. the
    pictures on a ``--no-render`` re-run) are removed, with a warning; no other file is touched.

    Args:
        source: a volume file, a DICOM folder, or ``"phantom"``.
        outdir: the output folder (created when missing).
        options: design options (see ``IsoSimilarityTFLib.options.OPTIONS``).
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
    options = dict(options or {})
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
        progress = ProgressPrinter(len(STAGES), quiet=True)
    progress.total = len(STAGES) if render else len(STAGES) - 1
    path = check_output_path(outdir)
    previous = previous_outputs(path)

    # The pictures are made by a second process, started now so that its slow start overlaps reading and designing.
    renderer = RenderProcess(size=size, backdrop=backdrop, ray_casting=ray_casting) if render else nullcontext()
    with renderer:
        started = time.perf_counter()
        progress.stage("read", str(source))
        n_bins = options.get("n_bins", DEFAULT_OPTIONS["n_bins"])
        volume = load_input(source, phantom_size=phantom_size, seed=seed, n_bins=n_bins)
        timings = {"read": time.perf_counter() - started}
        info = input_info(source, volume)
        for message in _input_warnings(info, n_bins):
            warning(message)
        if render and info["read_lazily"]:
            warning("the volume is larger than memory (read lazily): render.png, classes.png and the scene are skipped")
            render, progress.total = False, len(STAGES) - 1

        design = design_transfer_function(volume.values, volume.spacing, progress=progress.design_callback, **options)
        timings.update(design.timings_s)
        result = RunResult(design, volume, info, path, timings_s=timings, warnings=warnings)
        for message in _design_warnings(result):
            warning(message)

        start = time.perf_counter()
        progress.stage("write", str(path))
        create_output_folder(path)
        write_data_files(result)
        timings["write"] = time.perf_counter() - start

        try:
            if render:
                start = time.perf_counter()
                progress.stage("render", "(Slicer volume rendering, headless)")
                _render(renderer, result, view=view, size=size, progress=progress)
                timings["render"] = time.perf_counter() - start
        finally:
            removed = remove_stale(path, previous, result.written())
            if removed:
                progress.finish()
                names = ", ".join(removed)
                warning(f"removed {len(removed)} file(s) of a previous run that this run did not write: {names}")
            progress.finish()
            timings["total"] = time.perf_counter() - started
            write_classes_json(result)
    return result


def _render(renderer: RenderProcess, result: RunResult, *, view: str, size: int, progress: ProgressPrinter) -> None:
    """The render stage: ``renderer`` makes the pictures and the scene; a failure is one :class:`RenderError` line."""
    try:
        renderer.render(result, view=view, size=size, progress=progress)
    except (RuntimeError, OSError, ValueError) as error:
        raise RenderError(
            f"rendering failed ({error}); the other outputs are in '{result.outdir}' "
            "(use --no-render to skip rendering)"
        ) from None


def _input_warnings(info: dict, n_bins: int) -> list[str]:
    """Warnings about the input that the design cannot fix: a label map, or a clustering that will take minutes."""
    warnings = []
    low, high = info["value_min"], info["value_max"]
    integers = low is not None and info["dtype"].startswith(("int", "uint"))  # no range of a volume read lazily
    if integers and low < high <= low + LABEL_MAP_VALUES - 1:  # constant: an error
        warnings.append(
            f"the volume holds at most {int(high - low + 1)} distinct integer values ({low:g} to {high:g}): a label "
            "map? Isovalue similarity groups intensities of a continuous scan; label maps are better shown with "
            "their own colour table"
        )
    if n_bins > SLOW_CLUSTERING_BINS:
        warnings.append(
            f"affinity propagation on {n_bins} isovalues may take many minutes with no progress shown (its cost grows "
            f"with the square of --bins; the default is {DEFAULT_OPTIONS['n_bins']})"
        )
    return warnings


def _design_warnings(result: RunResult) -> list[str]:
    """Warnings about a transfer function that would show nothing useful (the run still succeeds)."""
    design = result.design
    shown = [c for c in design.classes if design.is_shown(c.id)]
    if len(design.classes) == 1:
        return ["affinity propagation found a single class, the background: the transfer function shows nothing"]
    if not shown:
        return ["every class is hidden (background, or --max-classes 0): the transfer function shows nothing"]
    return []
