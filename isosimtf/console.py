"""What ``isosimtf`` prints: one progress line per stage on stderr, and the summary table on stdout."""

import sys
from typing import TYPE_CHECKING, Optional, TextIO

from IsoSimilarityTFLib.design import STAGES as DESIGN_STAGES

from .formatting import color_hex, format_percent, format_ranges, value_decimals
from .read_errors import set_progress_sink

if TYPE_CHECKING:  # pragma: no cover - typing only
    from .outputs import RunResult


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
        """Start the next stage: print ``[i/N] name detail``. Long reads during the stage show their steps on its
        line (:meth:`show_step`, through :func:`.read_errors.report_progress`)."""
        self.index += 1
        self._line = f"[{self.index}/{self.total}] {name}" + (f" {detail}" if detail else "")
        set_progress_sink(self.show_step)
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

    def show_step(self, message: str, fraction: float) -> None:
        """Show a step of a long pass of the current stage, with a bar while it runs (terminals only)."""
        self.update(f"{message} {progress_bar(fraction)}" if 0.0 < fraction < 1.0 else message)

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
        if fraction == 0.0 and stage in DESIGN_STAGES:
            details = {"similarity": "(hierarchical isosurface similarity)", "clustering": "(affinity propagation)"}
            self.stage(stage, details.get(stage, ""))
        elif message:
            text = message[len(stage) + 2 :] if message.startswith(f"{stage}: ") else message
            self.update(f"{text} {progress_bar(fraction)}" if 0.0 < fraction < 1.0 else text)


def progress_bar(fraction: float, width: int = 20) -> str:
    """``[#####...............]  25%``: the share of a long pass done, for a terminal line."""
    filled = int(round(max(0.0, min(1.0, fraction)) * width))
    return f"[{'#' * filled}{'.' * (width - filled)}] {fraction:4.0%}"


def summary_text(result: "RunResult") -> str:
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
        f"damping {clustering.get('damping', design.options.get('damping'))}"
        f"{' on the distinct isovalues' if clustering.get('distinct') else ''}, "
        f"preference {clustering.get('preference', 0.0):.4g} ({design.options.get('preference')})"
    )
    times = ", ".join(f"{stage} {seconds:.2f}" for stage, seconds in result.timings_s.items() if stage != "total")
    lines.append(f"time (s): {times}; total {result.timings_s.get('total', 0.0):.2f}")
    lines.append(f"output: {result.outdir}")
    lines += [f"  {path.relative_to(result.outdir).as_posix()}" for path in result.files.values()]
    return "\n".join(lines) + "\n"
