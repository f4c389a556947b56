"""The pictures and the scene, made by a second process that starts with the run.

Importing slicer-core and opening the headless 3D view take about a second, nearly all of it holding the GIL, so a
thread cannot overlap them with the design (it stalled the design's pure-Python stages instead). A process started
when the run starts does that on the machine's other core while this one reads the volume and designs; it then
receives the run (volume and design) and runs :func:`.outputs.render_outputs`, as a run in one process would. Of a
volume read lazily it receives only the in-memory preview the pictures are made from, never the dask array.

The child is ``python -m isosimtf.render_process``, a fresh interpreter: not ``multiprocessing``, whose ``spawn``
would run the caller's main script again in the child, and not ``fork``, unsafe in a process holding threads. Messages
are pickled: jobs on the child's stdin, replies on its stdout, which the child keeps for them alone (anything a library
writes to its standard output goes to stderr instead); plain pipes work on every platform (``pass_fds`` is POSIX
only). The child ends after its job, or when the parent closes its stdin (:meth:`RenderProcess.close`, or the parent
ending).
"""

from __future__ import annotations

import json
import os
import pickle
import signal
import subprocess
import sys
import tempfile
import traceback
from dataclasses import replace
from typing import Any, BinaryIO

from IsoSimilarityTFLib.errors import RenderError

from .console import ProgressPrinter
from .outputs import RunResult, open_headless, render_outputs

#: Replies of the child: ("progress", label), ("wrote", role, path) for each file once complete, ("done", files,
#: scene_files) or ("failed", one-line reason).
_PROGRESS, _WROTE, _DONE, _FAILED = "progress", "wrote", "done", "failed"


class RenderProcess:
    """A child process that opens a headless Slicer at once and renders one run's outputs when asked (:meth:`render`).

    Args:
        window: keyword arguments of :func:`.outputs.open_headless` (``size``, ``backdrop``, ``ray_casting``).
    """

    def __init__(self, **window: Any) -> None:
        # What the child and its libraries write to stderr (EGL warnings, a native "std::bad_alloc" dump, a bug's
        # traceback) is kept here, not shown beside the run's one error line: its reason joins that line when the
        # child dies, and all of it shows with ISOSIMTF_DEBUG=1. A file, not a pipe, which nobody would empty.
        self._errors = tempfile.TemporaryFile()
        self._process = subprocess.Popen(
            [sys.executable, "-m", __name__, json.dumps(window)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._errors,
            # The child imports what this process imported, from where it did.
            env={**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)},
        )
        self._replies = self._process.stdout

    def render(self, result: RunResult, *, view: str, size: int, progress: ProgressPrinter | None = None) -> None:
        """Render ``result`` in the child (see :func:`.outputs.render_outputs`) and record the files it wrote.

        Raises:
            RenderError: the child failed (its one-line reason) or ended without a word.
        """
        # The pictured volume stands in for the input: a lazy one would be read whole by the child.
        # The parent journals what the child reports, the child's copy does not.
        job = replace(result, journaled=False)
        if result.preview is not None:
            job = replace(job, volume=result.preview.volume)
        try:
            _send(self._process.stdin, (job, view, size))
            while True:
                reply = pickle.load(self._replies)
                if reply[0] == _PROGRESS and progress is not None:
                    progress.update(reply[1])
                elif reply[0] == _WROTE:  # recorded at once: an interrupted run still lists every complete picture
                    result.record(reply[1], reply[2])
                elif reply[0] == _DONE:
                    result.files.update(reply[1])
                    result.record_scene(reply[2])
                    return
                elif reply[0] == _FAILED:
                    raise RenderError(reply[1])
        except (EOFError, BrokenPipeError, ConnectionResetError):
            code = self._process.wait()
            raise RenderError(f"the rendering process ended unexpectedly (exit code {code}{self._reason()})") from None

    def _reason(self) -> str:
        """Why the child died, from what it wrote to stderr: ``"; out of memory"``, its last line, or nothing."""
        self._errors.seek(0)
        said = self._errors.read()[-(1 << 16) :].decode("utf-8", "replace")
        if "bad_alloc" in said or "MemoryError" in said or "Cannot allocate memory" in said:
            return "; out of memory"
        lines = [line.strip() for line in said.splitlines() if line.strip()]
        return f"; {lines[-1][:200]}" if lines else ""

    def close(self) -> None:
        """End the child at once and release the pipes.

        A child that replied to its job has closed every file it wrote before replying; one still starting, waiting
        or rendering (the run failed, or was interrupted) has nothing worth waiting for.
        """
        try:
            self._process.stdin.close()
        except BrokenPipeError:
            pass
        if self._process.poll() is None:
            self._process.kill()
        self._process.wait()
        self._replies.close()
        if os.environ.get("ISOSIMTF_DEBUG"):
            self._errors.seek(0)
            sys.stderr.write(self._errors.read().decode("utf-8", "replace"))
        self._errors.close()

    def __enter__(self) -> RenderProcess:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _send(stream: BinaryIO, message: Any) -> None:
    pickle.dump(message, stream, protocol=pickle.HIGHEST_PROTOCOL)
    stream.flush()


class _ReplyProgress(ProgressPrinter):
    """Sends :meth:`update` labels to the parent, which prints them."""

    def __init__(self, replies: BinaryIO) -> None:
        super().__init__(1, quiet=True)
        self._replies = replies

    def update(self, message: str) -> None:
        _send(self._replies, (_PROGRESS, message))


class _ReportedFiles(dict):
    """``result.files`` in the child: each file recorded (once complete) is reported to the parent at once."""

    def __init__(self, replies: BinaryIO, files: dict) -> None:
        super().__init__(files)
        self._replies = replies

    def __setitem__(self, role: str, path: Any) -> None:
        super().__setitem__(role, path)
        _send(self._replies, (_WROTE, role, path))


def _serve(replies: BinaryIO, window: dict) -> None:
    """The child: open the headless Slicer, wait for one run, render it, reply."""
    try:
        headless, failure = open_headless(**window), None
    except (RuntimeError, OSError, ValueError) as error:
        headless, failure = None, str(error)
    try:
        result, view, size = pickle.load(sys.stdin.buffer)
    except EOFError:  # the run ended before its render stage (an error, or nothing to render)
        return
    try:
        if failure is not None:
            raise RuntimeError(failure)
        result.files = _ReportedFiles(replies, result.files)
        render_outputs(result, view=view, size=size, progress=_ReplyProgress(replies), headless=headless)
    except (RuntimeError, OSError, ValueError) as error:
        _send(replies, (_FAILED, str(error)))
    except Exception:  # a bug: the parent shows the last line, the traceback goes to stderr
        details = traceback.format_exc()
        print(details, end="", file=sys.stderr, flush=True)
        _send(replies, (_FAILED, details.strip().splitlines()[-1]))
    else:
        _send(replies, (_DONE, dict(result.files), result.scene_files))


if __name__ == "__main__":
    # Ctrl+C reaches the whole process group: the parent handles it and ends the child.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # The replies take the standard output's file descriptor; what else would be written there goes to stderr.
    reply_stream = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    try:
        with reply_stream:
            _serve(reply_stream, json.loads(sys.argv[1]))
    except BrokenPipeError:  # the parent is gone: nobody to reply to
        pass
    # Every file is written and closed: skip tearing down VTK and the scene (a few tenths of a second).
    sys.stderr.flush()
    os._exit(0)
