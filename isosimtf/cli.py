"""The ``isosimtf`` command: design a volume-rendering transfer function automatically and write it to a folder.

``isosimtf INPUT -o OUTDIR [options]``. INPUT is a volume file (NRRD, MetaImage, NIfTI, VTK image, ``.npy``,
InVesalius ``.inv3``), a DICOM series folder, or the word ``phantom``. The options mirror the Python names of
:func:`design_transfer_function`. The work is done by :mod:`.run`; this module only parses arguments, prints and
turns failures into one error line and an exit status (2: usage or input error, 1: processing error).

Set ``ISOSIMTF_DEBUG=1`` to get the Python traceback of a failure instead of the one-line message.
"""

import argparse
import os
import re
import sys
from collections.abc import Sequence
from typing import Any, Callable, NoReturn, Optional

from IsoSimilarityTFLib.errors import (
    ClusteringError,
    IsoSimilarityTFError,
    OutputError,
    RenderError,
)
from IsoSimilarityTFLib.options import LOOK_NAMES, OPTIONS, Option

from . import __version__
from .console import ProgressPrinter, summary_text
from .inputs import DEFAULT_PHANTOM_SIZE, MAX_PHANTOM_SIZE, MIN_PHANTOM_SIZE
from .outputs import DEFAULT_BACKDROP, DEFAULT_RAY_CASTING, DEFAULT_SIZE, DEFAULT_VIEW, MAX_SIZE, MIN_SIZE
from .rendering import BACKDROPS, RAY_CASTING, VIEW_DIRECTIONS
from .run import STAGES, run
from .scheduler import use_scheduler

PROG = "isosimtf"
EXIT_OK, EXIT_PROCESSING, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130


#: Any number argparse must take as a value, not an option: argparse's own pattern (``-1``, ``-.5``) misses
#: ``-1e3`` before Python 3.13, so ``--range -1e3 3e3`` failed with "expected 2 arguments".
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line: ``isosimtf: error: ...`` (no usage block)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # No option of ours looks like a negative number, so every word matching this is a value (argparse's rule).
        self._negative_number_matcher = _NEGATIVE_NUMBER

    def error(self, message: str) -> NoReturn:
        _print_error(f"{message} (see {self.prog} --help)")
        raise SystemExit(EXIT_USAGE)


def _print_error(message: str) -> None:
    sys.stderr.write(f"{PROG}: error: {' '.join(str(message).split())}\n")
    sys.stderr.flush()


def _print_warning(message: str) -> None:
    sys.stderr.write(f"{PROG}: warning: {' '.join(str(message).split())}\n")
    sys.stderr.flush()


def _integer(minimum: int, maximum: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not minimum <= value <= maximum:
            raise argparse.ArgumentTypeError(f"must be from {minimum} to {maximum}, got {value}")
        return value

    return parse


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _checked_by(option: Option) -> Callable[[str], Any]:
    """The argparse ``type`` of an option: parse the word, then check it against the option's table entry."""

    def parse(text: str) -> Any:
        if option.choices and text.lower() in option.choices:
            return text.lower()
        if option.kind in ("int", "choice-or-int"):
            try:
                value: Any = int(text)
            except ValueError:
                raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        else:
            value = _finite(text)
        try:
            return option.check(value)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error).replace(f"{option.name} must", "must")) from None

    return parse


def _add_option(group: argparse._ArgumentGroup, option: Option) -> None:
    """One design option as a command-line argument, from its table entry."""
    default = f"default: {option.none_means}" if option.none_means else "default %(default)s"
    arguments: dict[str, Any] = {"dest": option.name, "default": option.default, "help": f"{option.help} ({default})"}
    if option.kind == "choice":
        arguments["choices"] = option.choices
    elif option.kind == "range":
        arguments.update(type=_finite, nargs=2)
    else:
        arguments["type"] = _checked_by(option)
    if option.metavar is not None:
        arguments["metavar"] = option.metavar
    group.add_argument(option.flag, **arguments)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``isosimtf``."""
    parser = _Parser(
        prog=PROG,
        description=(
            "Design a multi-class volume-rendering transfer function automatically (hierarchical isosurface "
            "similarity + affinity propagation) and write it, with pictures and a Slicer scene, to OUTDIR."
        ),
        epilog=(
            "Outputs: similarity.npy, similarity.png, classes.json, transfer_function.vp.json, transfer_function.vp "
            "(the chosen look), looks/NAME.vp.json (every look offered), looks.png, and unless --no-render: "
            "render.png, classes.png, classes.seg.nrrd, scene/scene.mrml. Exit status: 0 success, 2 usage or "
            "input error, 1 processing error (including a volume too large for memory), 130 interrupted."
        ),
    )
    parser.add_argument(
        "input",
        metavar="INPUT",
        help="volume file (.nrrd, .nhdr, .mha, .mhd, .nii, .nii.gz, .vti, .npy, .inv3, .tif, .tiff), a DICOM series "
        "folder or a file of the series, a Zarr or OME-Zarr store or a folder of TIFF planes (read lazily), or the "
        "word 'phantom' for the built-in head phantom (./phantom for a file of that name)",
    )
    parser.add_argument("-o", "--output", metavar="OUTDIR", required=True, help="output folder (created if missing)")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")

    method = parser.add_argument_group("method (the Python option names of design_transfer_function)")
    for option in OPTIONS.values():
        _add_option(method, option)

    output = parser.add_argument_group("output")
    output.add_argument(
        "--look",
        choices=LOOK_NAMES,
        help="the look of the gallery that transfer_function.vp.json shows, if the data offer it (default: the first "
        "click: thin-structures for thin structures alone, or lying along lines on data that are not CT-like; else "
        "dense-parts on CT-like data; else outer-surface)",
    )
    output.add_argument(
        "--overwrite",
        action="store_true",
        help="replace files in OUTDIR that have an output's name but were not written by isosimtf (by default such "
        "a run is refused; a file isosimtf wrote and someone changed since is never replaced)",
    )
    output.add_argument(
        "--no-render",
        action="store_true",
        help="skip render.png, classes.png, classes.seg.nrrd and the Slicer scene (faster; the data files and "
        "looks.png are still written)",
    )
    output.add_argument(
        "--view",
        choices=tuple(VIEW_DIRECTIONS),
        default=DEFAULT_VIEW,
        help="camera direction of the renders (default %(default)s)",
    )
    output.add_argument(
        "--size",
        type=_integer(MIN_SIZE, MAX_SIZE),
        default=DEFAULT_SIZE,
        metavar="PIXELS",
        help="side of render.png in pixels; class tiles are half of it (default %(default)s)",
    )
    output.add_argument(
        "--backdrop",
        choices=BACKDROPS,
        default=DEFAULT_BACKDROP,
        help="3D view backdrop of the pictures: black, or slicer (the blue gradient of Slicer's 3D view) "
        "(default %(default)s)",
    )
    output.add_argument(
        "--ray-casting",
        choices=tuple(RAY_CASTING),
        default=DEFAULT_RAY_CASTING,
        help="Slicer's CPU or GPU (OpenGL) ray casting for the pictures (default %(default)s)",
    )
    output.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="dask.distributed scheduler that reads a volume larger than memory (default: dask's local threads)",
    )
    output.add_argument(
        "-q", "--quiet", action="store_true", help="no progress lines on stderr (the summary still goes to stdout)"
    )

    phantom = parser.add_argument_group("phantom (INPUT 'phantom')")
    phantom.add_argument(
        "--phantom-size",
        type=_integer(MIN_PHANTOM_SIZE, MAX_PHANTOM_SIZE),
        default=DEFAULT_PHANTOM_SIZE,
        metavar="N",
        help="voxels per axis (default %(default)s)",
    )
    phantom.add_argument("--seed", type=_integer(0, 2**32 - 1), default=0, help="phantom seed (default %(default)s)")
    return parser


def design_options(args: argparse.Namespace) -> dict:
    """The ``design_transfer_function`` options named by the parsed arguments."""
    return {name: getattr(args, name) for name in OPTIONS}


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run ``isosimtf`` with ``argv`` (default: the command line); return the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_request:  # --help, --version, or a usage error already printed
        return exit_request.code if isinstance(exit_request.code, int) else EXIT_USAGE
    if args.value_range and not args.value_range[0] < args.value_range[1]:
        try:
            low, high = args.value_range
            parser.error(f"argument --range: LOW must be below HIGH, got {low:g} {high:g}")
        except SystemExit as exit_request:
            return exit_request.code if isinstance(exit_request.code, int) else EXIT_USAGE

    total = len(STAGES) - (1 if args.no_render else 0)
    progress = ProgressPrinter(total, stream=sys.stderr, quiet=args.quiet)
    try:
        use_scheduler(args.scheduler)
        result = run(
            args.input,
            args.output,
            options=design_options(args),
            render=not args.no_render,
            view=args.view,
            size=args.size,
            phantom_size=args.phantom_size,
            seed=args.seed,
            progress=progress,
            warn=_print_warning,
            backdrop=args.backdrop,
            ray_casting=args.ray_casting,
            look=args.look,
            overwrite=args.overwrite,
        )
    except BaseException as error:  # one line, no traceback (ISOSIMTF_DEBUG=1 shows it)
        progress.finish()
        if os.environ.get("ISOSIMTF_DEBUG"):
            raise
        if isinstance(error, KeyboardInterrupt):
            _print_error("interrupted")
            return EXIT_INTERRUPTED
        if isinstance(error, SystemExit):
            raise
        _print_error(_message(error))
        return _exit_status(error)
    _write_summary(summary_text(result))
    return EXIT_OK


def _write_summary(text: str) -> None:
    """The summary on stdout; a closed stdout (``>&-``) or a reader gone (``| head``) loses only the summary: the
    outputs are written, and the run succeeded."""
    if sys.stdout is None:
        return
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except (BrokenPipeError, ValueError, OSError):
        pass


def _exit_status(error: BaseException) -> int:
    if isinstance(error, (ClusteringError, OutputError, RenderError, MemoryError)):
        return EXIT_PROCESSING
    if isinstance(error, ValueError):  # bad input or option, ours (UsageError, VolumeReadError, ...) or numpy's
        return EXIT_USAGE
    return EXIT_PROCESSING


def _message(error: BaseException) -> str:
    if isinstance(error, ClusteringError):
        return _cli_spelling(str(error))
    if isinstance(error, IsoSimilarityTFError):
        return str(error)
    if isinstance(error, MemoryError):
        return "out of memory (try a smaller volume or fewer --bins)"
    if isinstance(error, ValueError):
        return f"invalid input or option: {error}"
    if isinstance(error, OSError):
        return f"{error.strerror or error}" + (f": {error.filename}" if error.filename else "")
    return f"internal error ({type(error).__name__}: {error}); rerun with ISOSIMTF_DEBUG=1 for details"


def _cli_spelling(text: str) -> str:
    """Advice written with the Python option names (``preference='minimum'``, ``max_iter``) in the command's own
    spelling (``--preference minimum``, ``--max-iter``)."""
    for option in OPTIONS.values():
        text = re.sub(rf"(?<![-\w]){option.name}='([^']*)'", rf"{option.flag} \1", text)
        text = re.sub(rf"(?<![-\w]){option.name}=(-?[\d.]+(?:e-?\d+)?)", rf"{option.flag} \1", text)
        text = re.sub(rf"\b(raise|lower|set) {option.name}\b", rf"\1 {option.flag}", text)
    for option in OPTIONS.values():  # "raise --max-iter or damping": the second name of the pair too
        text = re.sub(rf"(\b(?:raise|lower|set) --[\w-]+ or ){option.name}\b", rf"\1{option.flag}", text)
    return text


def _open_closed_standard_streams() -> None:
    """Give a standard descriptor the command was started without (``2>&-``) the null device: the first file opened
    would take it otherwise, and what native libraries write to stderr would land in an output. A closed stderr
    then loses the progress lines only; a closed stdout still loses only the summary (``sys.stdout`` stays None)."""
    for descriptor in (0, 1, 2):
        try:
            os.fstat(descriptor)
        except OSError:
            opened = os.open(os.devnull, os.O_RDWR)  # the lowest free descriptor: this one
            if opened != descriptor:  # pragma: no cover - a lower one was free, which the loop rules out
                os.dup2(opened, descriptor)
                os.close(opened)
    if sys.stderr is None:
        sys.stderr = open(os.devnull, "w", encoding="utf-8")  # open until the process ends


def console_main() -> NoReturn:
    """The ``isosimtf`` command: :func:`main`, then the process ends at once with its exit status.

    Every output file is closed by then; what the interpreter's own shutdown would add (tearing down the modules of
    VTK and slicer-core, a last garbage collection) took 0.5 s of a 2 s run.
    """
    _open_closed_standard_streams()
    code = main()
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:
                stream.flush()
        except (BrokenPipeError, ValueError, OSError):
            pass
    os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    console_main()
