"""How a failed read is reported: one line naming the file, never the C++ libraries' own printing.

VTK reports errors through its output window and its logger; ITK and teem also write straight to the process's
standard error. During a read both are captured (VTK's messages into a string output window, file descriptor 2 into
a temporary file), and the first meaningful line can become the reason of a :class:`VolumeReadError`.
"""

import contextlib
import os
import re
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from IsoSimilarityTFLib.errors import VolumeReadError

_VTK_LOG_PREFIX = re.compile(r"^.*?(ERR|WARN)\|\s*")
_VTK_OBJECT = re.compile(r"^\s*vtk\w*\s*\(0x[0-9a-fA-F]+\):\s*")
_VTK_LEGACY_PREFIX = re.compile(
    r"^\s*(ERROR|WARNING|Warning|Error|Generic Warning)?:?\s*In\s+\S+,\s*line\s+\d+\s*", re.I
)
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
# VTK's pipeline failure ("Algorithm ... returned failure for request: vtkInformation", then an indented dump of the
# request) only says that the reader failed, never why.
_NOISE = "returned failure for request"
_ITK_LOCATION = re.compile(r"\s*\[vtk\w+\.cxx, line \d+, [^\]]*\]\s*$")
_TEEM_PREFIX = re.compile(r"^\[\w+\]\s*\w+:\s*")


@contextlib.contextmanager
def captured_native_output() -> Iterator[list[str]]:
    """Capture VTK's messages and everything written to file descriptor 2 during the block.

    Yields a list that, once the block ends, holds the captured text (one string per source, possibly empty).
    """
    from vtkmodules.vtkCommonCore import vtkLogger, vtkOutputWindow, vtkStringOutputWindow

    previous = vtkOutputWindow.GetInstance()
    window = vtkStringOutputWindow()
    vtkOutputWindow.SetInstance(window)
    # VTK built with its logger also logs warnings and errors to stderr on its own; mute that sink meanwhile.
    cutoff = vtkLogger.GetCurrentVerbosityCutoff()
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    texts: list[str] = []
    sys.stderr.flush()
    saved_fd = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield texts
        finally:
            os.dup2(saved_fd, 2)
            os.close(saved_fd)
            vtkLogger.SetStderrVerbosity(vtkLogger.ConvertToVerbosity(cutoff))
            vtkOutputWindow.SetInstance(previous)
            sink.seek(0)
            texts.extend([window.GetOutput() or "", sink.read().decode("utf-8", "replace")])


def first_message(texts: list[str]) -> str:
    """The first meaningful line of captured C++ output, without log prefixes, object addresses or colours."""
    for text in texts:
        for line in _ANSI.sub("", text).splitlines():
            if line.startswith((" ", "\t")):
                continue
            line = _VTK_LOG_PREFIX.sub("", line)
            line = _VTK_LEGACY_PREFIX.sub("", line)
            line = _VTK_OBJECT.sub("", line).strip()
            if line and not line.startswith("ERROR:") and _NOISE not in line:
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
