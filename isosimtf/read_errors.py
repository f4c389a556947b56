"""How a failed read is reported: one line naming the file, never the C++ libraries' own printing; how a read
that succeeded with something the user must know (a unit converted, an array chosen) says so: one warning line; and
how a long read (a folder of many DICOM files) shows how far it has come: :func:`report_progress`.

VTK reports errors through its output window and its logger; ITK and teem also write straight to the process's
standard error. During a read both are captured (VTK's messages as the renderer captures them, file descriptor 2 into
a temporary file), and the first meaningful line can become the reason of a :class:`VolumeReadError`.
"""

import contextlib
import os
import re
import stat
import sys
import tempfile
import warnings
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Callable, Optional

from IsoSimilarityTFLib.errors import VolumeReadError

# VTK's pipeline failure ("Algorithm ... returned failure for request: vtkInformation", then an indented dump of the
# request) only says that the reader failed, never why.
_NOISE = "returned failure for request"
_ITK_LOCATION = re.compile(r"\s*\[vtk\w+\.cxx, line \d+, [^\]]*\]\s*$")
_TEEM_PREFIX = re.compile(r"^\[\w+\]\s*\w+:\s*")


_VTK_MESSAGE_HEAD = re.compile(r"^(Warning|ERROR|Error|Generic Warning): In .*, line \d+\s*$")
_VTK_OBJECT = re.compile(r"^\s*\w+ \(0x[0-9a-fA-F]+\):\s*")


@contextlib.contextmanager
def captured_vtk_messages() -> Iterator[list[str]]:
    """Collect VTK's warnings and errors (``vtkWarningMacro``, ``vtkErrorMacro``) during a block, e.g. a render.

    Yields a list that is filled when the block ends, one string per message (the object prefix and the
    "In file.cxx, line N" head removed). Meanwhile nothing of it goes to stderr; afterwards VTK's output window and
    logger are as before.
    """
    from vtkmodules.vtkCommonCore import vtkLogger, vtkOutputWindow, vtkStringOutputWindow

    previous = vtkOutputWindow.GetInstance()
    window = vtkStringOutputWindow()
    vtkOutputWindow.SetInstance(window)
    cutoff = vtkLogger.GetCurrentVerbosityCutoff()
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    messages: list[str] = []
    try:
        yield messages
    finally:
        vtkLogger.SetStderrVerbosity(vtkLogger.ConvertToVerbosity(cutoff))
        vtkOutputWindow.SetInstance(previous)
        messages.extend(split_vtk_messages(window.GetOutput() or ""))


def split_vtk_messages(text: str) -> list[str]:
    """Split the text of VTK's output window into messages, without their "In file, line" heads and object ids."""
    messages, current = [], []
    for line in [*text.splitlines(), ""]:
        if _VTK_MESSAGE_HEAD.match(line.strip()) or not line.strip():
            if current:
                messages.append(" ".join(current))
            current = []
            continue
        current.append(_VTK_OBJECT.sub("", line).strip())
    return messages


@contextlib.contextmanager
def captured_native_output() -> Iterator[list[str]]:
    """Capture VTK's messages and everything written to file descriptor 2 during the block.

    Yields a list that, once the block ends, holds the captured texts: VTK's messages one by one (through
    :func:`captured_vtk_messages`), then what ITK and teem wrote to stderr.
    """
    texts: list[str] = []
    sys.stderr.flush()
    saved_fd = os.dup(2)
    try:
        with tempfile.TemporaryFile(mode="w+b") as sink:
            with captured_vtk_messages() as messages:
                os.dup2(sink.fileno(), 2)
                try:
                    yield texts
                finally:
                    os.dup2(saved_fd, 2)
            sink.seek(0)
            texts.extend([*messages, sink.read().decode("utf-8", "replace")])
    finally:
        os.close(saved_fd)


def first_message(texts: list[str]) -> str:
    """The first meaningful line of captured C++ output (VTK's messages come without heads and object ids)."""
    for text in texts:
        for line in text.splitlines():
            line = line.strip()
            if line and _NOISE not in line:
                return line
    return ""


def itk_reason(text: str) -> str:
    """The innermost reason of an ITK exception's text: the last line of its description, without locations.

    E.g. ``... Description: ITK ERROR: NrrdImageIO(0x..): Read: ... [nrrd] _nrrdEncodingGzip_read: expected 524288
    bytes but received 7433 [vtkITK...cxx, line 249, ...]`` gives ``expected 524288 bytes but received 7433``.
    """
    text = _ITK_LOCATION.sub("", text.split("Description:", 1)[-1].strip())
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return _TEEM_PREFIX.sub("", lines[-1]) if lines else ""


def cannot_read(path: Path, reason: str) -> VolumeReadError:
    """The error for an unreadable input: ``Cannot read 'PATH': reason`` on one line."""
    return VolumeReadError(f"Cannot read '{path}': {' '.join(reason.split())}")


class VolumeReadWarning(UserWarning):
    """What a reader says of a volume it read: e.g. an array chosen for want of active scalars, a unit converted."""


def python_warning(message: str) -> None:
    """The readers' warning channel when the caller gives none (a ``warn`` callback): Python's warnings."""
    warnings.warn(" ".join(message.split()), VolumeReadWarning, stacklevel=2)


def regular_file(owner: Path, file: Path, role: str) -> Path:
    """``file``, refused unless it is a regular file (links followed), before anything opens it for voxels.

    Opening a FIFO waits for a writer forever, and a device (or a link to one, e.g. ``/dev/zero``) is read without
    end: every file read for the voxels of ``owner`` (the input, a detached data file, a Zarr chunk, a TIFF plane)
    passes here first.

    Args:
        owner: the input the messages name. file: the file to check (``owner`` itself for the input).
        role: what ``file`` is to ``owner`` in messages, e.g. ``"its data file"`` (``"it"`` for the input itself).

    Raises:
        VolumeReadError: ``file`` is missing, unreadable, a folder, a FIFO, a socket or a device.
    """
    subject = role if file == owner else f"{role} '{file}'"
    if file != owner and os.path.islink(file):
        subject += f" (a link to '{os.path.realpath(file)}')"
    try:
        mode = os.stat(file).st_mode
    except OSError as error:
        raise cannot_read(owner, f"{subject} cannot be opened ({error.strerror})") from None
    if stat.S_ISDIR(mode):
        raise cannot_read(owner, f"{subject} is not a regular file (a folder)")
    if not stat.S_ISREG(mode):
        advice = "give a volume file or folder" if file == owner else "voxels are read from regular files only"
        raise cannot_read(owner, f"{subject} is not a regular file (a FIFO, socket or device): {advice}")
    return file


#: Where a long read shows how far it has come: a bound method ``show(message, fraction)``, held weakly, set by the
#: command's progress printer when a stage starts (:meth:`.console.ProgressPrinter.stage`); None: nowhere.
_progress_sink: Optional["weakref.WeakMethod[Callable[[str, float], None]]"] = None


def set_progress_sink(show: Optional[Callable[[str, float], None]]) -> None:
    """Show the progress of long reads through the bound method ``show(message, fraction)`` from now on (None: show
    it nowhere). The readers have no progress printer handed to them: they call :func:`report_progress`."""
    global _progress_sink
    _progress_sink = weakref.WeakMethod(show) if show is not None else None  # type: ignore[arg-type]


def report_progress(message: str, fraction: float) -> None:
    """Show that a long read is at ``fraction`` (0 to 1) of its work, ``message`` saying what it is doing; nothing
    when no progress is shown (the Python API, ``--quiet``, a stream that is not a terminal)."""
    show = _progress_sink() if _progress_sink is not None else None
    if show is not None:
        show(message, fraction)


class ItemProgress:
    """The progress of a pass over ``total`` items (files), reported at most about a hundred times: cheap enough to
    call for every item of a folder of 100,000 files.

    Args:
        message: what the pass does, e.g. ``"DICOM headers"``; the report reads ``"DICOM headers 1200/100000"``.
        total: the items of the pass.
    """

    def __init__(self, message: str, total: int) -> None:
        self.message, self.total = message, total
        self.every = max(1, total // 100)

    def done(self, count: int) -> None:
        """``count`` items are done."""
        if count % self.every == 0 or count == self.total:
            report_progress(f"{self.message} {count}/{self.total}", count / max(1, self.total))
