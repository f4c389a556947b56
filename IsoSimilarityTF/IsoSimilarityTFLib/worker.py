"""Design a transfer function in a separate Python process that reports its progress and can be stopped at once.

Why a process. Slicer runs its Python on the Qt main thread, and while Qt waits for events the main thread keeps
Python's global interpreter lock (CTK never turns on PythonQt's thread support, ``PythonQt::setEnableThreadSupport``),
so a Python thread started from a module only moves while Python code runs on the main thread. A design in Slicer's
own process therefore runs on the main thread: it can be cancelled at each progress report (between affinity
propagation's iterations too), but Slicer repaints only there and is otherwise frozen. That is fine for a design of
under a second (:func:`.session.runs_in_process`); a longer one runs in a process, which computes at full speed beside
the application while Slicer stays responsive, and Cancel kills it at once, at any stage. This is how Slicer runs its
own long computations (command-line modules run as processes and Cancel terminates them).

The parent (:class:`DesignProcess`) writes the voxels (``.npy``), the spacing and the options into a temporary
folder and starts the child, which imports this library from the parent's folder first; the child (:func:`main`) runs
:func:`~.design.design_transfer_function`, appends each progress report to ``progress.jsonl`` and writes the design
(``design.json``) and its similarity matrix (``similarity.npy``), or ``error.json``. Nothing here needs Qt: the Slicer
module polls :meth:`DesignProcess.poll` from a ``qt.QTimer``; scripts and tests can simply wait.

Stopping every process of the job. In Slicer the child's executable, ``PythonSlicer``, is CTKAppLauncher: it starts
``python-real`` as its own child and waits for it, and killing it leaves that child running. So the job runs in its
own process group (POSIX), which Cancel kills whole (``taskkill /T`` on Windows), and the child also ends itself
within :data:`WATCH_INTERVAL_S` when the ``cancel`` file appears, its folder is removed or the parent is gone.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from typing import Optional

import numpy as np

from . import errors
from .design import TransferFunctionDesign

REQUEST_FILE = "request.json"
VALUES_FILE = "values.npy"
PROGRESS_FILE = "progress.jsonl"
DESIGN_FILE = "design.json"
SIMILARITY_FILE = "similarity.npy"
ERROR_FILE = "error.json"
LOG_FILE = "log.txt"
CANCEL_FILE = "cancel"
#: How often the child checks whether it should end (seconds).
WATCH_INTERVAL_S = 0.1

# The child's first lines: this library from the parent's folder, ahead of any other copy on the path (a launcher
# such as CTKAppLauncher puts its own paths before the inherited PYTHONPATH).
_BOOTSTRAP = "import sys; sys.path.insert(0, sys.argv[1]); from IsoSimilarityTFLib.worker import main; sys.exit(main())"

# Errors the child reports by name and the parent raises again with the same type.
_ERROR_TYPES = {
    cls.__name__: cls
    for cls in (
        errors.OptionError,
        errors.InsufficientMemoryError,
        errors.ClusteringError,
        ValueError,
        MemoryError,
        TypeError,
    )
}


class DesignProcess:
    """One design computed by a child process.

    Args:
        values: the voxels (any 3-D array; saved to a temporary ``.npy`` file for the child).
        spacing: voxel spacing in mm, or None.
        options: :func:`~.design.design_transfer_function` keywords (JSON-serializable values).
        python: the Python executable of the child: ``PythonSlicer`` in Slicer; default ``sys.executable``.
        env: environment of the child (default: this process's).
        temporary_folder: where the job's folder is made (in Slicer, ``slicer.app.temporaryPath``); default the
            system's.

    Use :meth:`poll` until :attr:`running` is False, then :meth:`result`; :meth:`cancel` stops it; :meth:`close`
    (or the ``with`` statement) removes the temporary folder.
    """

    def __init__(
        self,
        values,
        spacing=None,
        options: Optional[dict] = None,
        *,
        python: Optional[str] = None,
        env: Optional[dict] = None,
        temporary_folder: Optional[str] = None,
    ) -> None:
        if temporary_folder:
            os.makedirs(temporary_folder, exist_ok=True)
        self.folder = tempfile.mkdtemp(prefix="IsoSimilarityTF-", dir=temporary_folder or None)
        self.cancelled = False
        self._progress_offset = 0
        self._process = None
        try:
            np.save(os.path.join(self.folder, VALUES_FILE), np.ascontiguousarray(values))
            request = {
                "spacing": None if spacing is None else [float(s) for s in spacing],
                "options": options or {},
                "parent": os.getpid(),
            }
            with open(os.path.join(self.folder, REQUEST_FILE), "w", encoding="utf-8") as file:
                json.dump(request, file)
            package_parent = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
            if os.name == "nt":
                group = {"creationflags": subprocess.CREATE_NO_WINDOW}
            else:
                group = {"start_new_session": True}  # a process group of its own, killed whole by cancel()
            with open(os.path.join(self.folder, LOG_FILE), "wb") as log:
                self._process = subprocess.Popen(
                    [python or sys.executable, "-c", _BOOTSTRAP, package_parent, self.folder],
                    stdin=subprocess.DEVNULL,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    env=dict(os.environ if env is None else env),
                    **group,
                )
        except BaseException:
            self.close()
            raise

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    def poll(self) -> list:
        """The progress reports ``(stage, fraction, message)`` written since the last call."""
        path = os.path.join(self.folder, PROGRESS_FILE)
        if not os.path.exists(path):
            return []
        with open(path, "rb") as file:
            file.seek(self._progress_offset)
            data = file.read()
        complete = data[: data.rfind(b"\n") + 1]
        self._progress_offset += len(complete)
        reports = []
        for line in complete.decode("utf-8").splitlines():
            stage, fraction, message = json.loads(line)
            reports.append((stage, float(fraction), message))
        return reports

    def wait(self, timeout: Optional[float] = None, progress=None) -> TransferFunctionDesign:
        """Wait for the design (polling every 0.1 s); ``progress(stage, fraction, message)`` gets each report and may
        raise to cancel. Returns :meth:`result`."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            finished = not self.running
            for report in self.poll():
                if progress is not None:
                    try:
                        progress(*report)
                    except BaseException:
                        self.cancel()
                        raise
            if finished:
                return self.result()
            if deadline is not None and time.monotonic() > deadline:
                self.cancel()
                raise TimeoutError(f"the design took more than {timeout} s")
            time.sleep(0.1)

    def cancel(self) -> None:
        """Stop the computation now (every process of the job is killed); :meth:`result` then raises."""
        self.cancelled = True
        try:  # ends the child even if a process between it and us is killed alone
            open(os.path.join(self.folder, CANCEL_FILE), "wb").close()
        except OSError:
            pass
        if self.running:
            self._kill_group()
        if self._process is not None:
            self._process.wait()

    def _kill_group(self) -> None:
        if os.name == "nt":
            subprocess.run(
                ["taskkill", "/T", "/F", "/PID", str(self._process.pid)],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                creationflags=subprocess.CREATE_NO_WINDOW,
            )
        else:
            try:
                os.killpg(self._process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if self.running:
            self._process.kill()

    def result(self) -> TransferFunctionDesign:
        """The design, with its similarity matrix, once the child has finished.

        Raises:
            RuntimeError: still running, cancelled, or the child failed without saying why (its output is quoted).
            The child's own error (OptionError, ClusteringError, ValueError, ...) with its message.
        """
        if self.running:
            raise RuntimeError("the design is still being computed")
        if self.cancelled:
            raise RuntimeError("the design was cancelled")
        error_path = os.path.join(self.folder, ERROR_FILE)
        if os.path.exists(error_path):
            with open(error_path, encoding="utf-8") as file:
                error = json.load(file)
            raise _ERROR_TYPES.get(error["type"], RuntimeError)(error["message"])
        design_path = os.path.join(self.folder, DESIGN_FILE)
        if self._process.returncode != 0 or not os.path.exists(design_path):
            raise RuntimeError(
                f"the design process ended with code {self._process.returncode}: {self.log_tail() or 'no output'}"
            )
        with open(design_path, encoding="utf-8") as file:
            design = TransferFunctionDesign.from_json(file.read())
        design.similarity = np.load(os.path.join(self.folder, SIMILARITY_FILE))
        return design

    def log_tail(self, characters: int = 2000) -> str:
        """The end of the child's output (warnings, a traceback)."""
        try:
            with open(os.path.join(self.folder, LOG_FILE), "rb") as file:
                return file.read().decode("utf-8", "replace")[-characters:].strip()
        except OSError:
            return ""

    def close(self) -> None:
        """Stop the child if it still runs and remove the temporary folder."""
        if self._process is not None and self.running:
            self.cancel()
        shutil.rmtree(self.folder, ignore_errors=True)

    def __enter__(self) -> "DesignProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _write_json(path: str, data) -> None:
    """Write a file whole (to a temporary name, then renamed), so the parent never reads half of it."""
    with open(path + ".part", "w", encoding="utf-8") as file:
        json.dump(data, file)
    os.replace(path + ".part", path)


def _parent_alive(pid: Optional[int]) -> bool:
    if pid is None or os.name == "nt":  # on Windows os.kill would terminate it: the folder check remains
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return True


def _watch(folder: str, parent: Optional[int]) -> None:
    """The child's watchdog thread: end the process when it is cancelled, its folder removed or its parent gone."""
    while True:
        time.sleep(WATCH_INTERVAL_S)
        if os.path.exists(os.path.join(folder, CANCEL_FILE)) or not os.path.isdir(folder) or not _parent_alive(parent):
            os._exit(3)


def main(argv=None) -> int:
    """The child: ``python -c _BOOTSTRAP LIBRARY_PARENT FOLDER`` (or ``python -m IsoSimilarityTFLib.worker FOLDER``)."""
    from .design import design_transfer_function

    argv = sys.argv[1:] if argv is None else argv
    folder = argv[-1]
    with open(os.path.join(folder, REQUEST_FILE), encoding="utf-8") as file:
        request = json.load(file)
    threading.Thread(target=_watch, args=(folder, request.get("parent")), daemon=True).start()
    values = np.load(os.path.join(folder, VALUES_FILE), mmap_mode="r")
    with open(os.path.join(folder, PROGRESS_FILE), "a", encoding="utf-8") as progress_file:

        def progress(stage: str, fraction: float, message: str) -> None:
            progress_file.write(json.dumps([stage, float(fraction), message]) + "\n")
            progress_file.flush()

        try:
            design = design_transfer_function(values, request["spacing"], progress=progress, **request["options"])
        except (errors.IsoSimilarityTFError, ValueError, MemoryError, TypeError) as error:
            _write_json(os.path.join(folder, ERROR_FILE), {"type": type(error).__name__, "message": str(error)})
            return 1
    np.save(os.path.join(folder, SIMILARITY_FILE + ".part.npy"), design.similarity)
    os.replace(os.path.join(folder, SIMILARITY_FILE + ".part.npy"), os.path.join(folder, SIMILARITY_FILE))
    with open(os.path.join(folder, DESIGN_FILE + ".part"), "w", encoding="utf-8") as file:
        file.write(design.to_json())
    os.replace(os.path.join(folder, DESIGN_FILE + ".part"), os.path.join(folder, DESIGN_FILE))
    return 0


if __name__ == "__main__":
    sys.exit(main())
