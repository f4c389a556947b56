"""What the ``isosimtf`` command does, without the argument parsing: read, design, write the output folder, render."""

import time
from typing import Callable, Optional

from IsoSimilarityTFLib.design import STAGES as DESIGN_STAGES
from IsoSimilarityTFLib.design import design_transfer_function
from IsoSimilarityTFLib.errors import RenderError, UsageError

from .console import ProgressPrinter
from .inputs import DEFAULT_PHANTOM_SIZE, PathLike, input_info, load_input
from .outputs import (
    DEFAULT_BACKDROP,
    DEFAULT_RAY_CASTING,
    DEFAULT_SIZE,
    DEFAULT_VIEW,
    MIN_SIZE,
    RunResult,
    prepare_output_folder,
    render_outputs,
    write_classes_json,
    write_data_files,
)
from .rendering import BACKDROPS, RAY_CASTING, VIEW_DIRECTIONS, slicer_core_available

#: The command's stages, in order, as printed and as keys of ``timings_s`` in classes.json.
STAGES = ("read", *DESIGN_STAGES, "write", "render")


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
    path = prepare_output_folder(outdir)

    started = time.perf_counter()
    progress.stage("read", str(source))
    volume = load_input(source, phantom_size=phantom_size, seed=seed)
    timings = {"read": time.perf_counter() - started}

    design = design_transfer_function(volume.values, volume.spacing, progress=progress.design_callback, **options)
    timings.update(design.timings_s)
    result = RunResult(design, volume, input_info(source, volume), path, timings_s=timings, warnings=warnings)

    start = time.perf_counter()
    progress.stage("write", str(path))
    write_data_files(result)
    timings["write"] = time.perf_counter() - start

    if render:
        start = time.perf_counter()
        progress.stage("render", "(Slicer volume rendering, headless)")
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

