"""Design a transfer function in a separate Python process that reports its progress and can be stopped at once.

Why a process. Slicer runs its Python on the Qt main thread, and while Qt waits for events the main thread keeps
Python's global interpreter lock (CTK never turns on PythonQt's thread support, ``PythonQt::setEnableThreadSupport``),
so a Python thread started from a module only moves while Python code runs on the main thread. A design in Slicer's
own process therefore runs on the main thread: it can be cancelled at each progress report (between affinity
propagation's iterations too), but Slicer repaints only there and is otherwise frozen. That is fine for a design of
under a second (:func:`.session.runs_in_process`); a longer one runs in a process, which computes at full speed beside
the application while Slicer stays responsive, and Cancel kills it at once, at any stage. This is how Slicer runs its
own long computations (command-line modules run as processes and Cancel terminates them).

The parent (:class:`DesignProcess`) makes a folder ``IsoSimilarityTF-*`` in the temporary folder, writes into it the
request (spacing, options, and the parent's pid and start time), then the voxels (``.npy``), and starts the child,
which imports this library from the parent's folder first; the child (:func:`main`) records its own pid and start time
(``child.json``), runs :func:`~.design.design_transfer_function`, appends each progress report to ``progress.jsonl``
and writes the design (``design.json``) and its similarity matrix (``similarity.npy``), or ``error.json``. Nothing here
needs Qt: the Slicer module polls :meth:`DesignProcess.poll` from a ``qt.QTimer``; scripts and tests can simply wait.

Stopping. In Slicer the child's executable, ``PythonSlicer``, is CTKAppLauncher: it starts ``python-real`` as its own
child and waits for it, and killing it leaves that child running. So the job stops in three layers, each of which ends
it alone:

(a) the job runs in a process group of its own (POSIX ``start_new_session``), which :meth:`DesignProcess.cancel` kills
    whole (``killpg``; ``taskkill /T`` on Windows);
(b) the child's watchdog thread ends the child within :data:`WATCH_INTERVAL_S` when the ``cancel`` file (written by
    :meth:`~DesignProcess.cancel` before it kills) appears in its folder or the folder is removed
    (:meth:`~DesignProcess.close`);
(c) the same watchdog ends the child when the parent is gone, e.g. Slicer crashed or was killed (:func:`_parent_alive`:
    ``os.kill(pid, 0)`` and, on Linux, the parent's state and start time in ``/proc``, so a zombie or another process
    that got the pid does not count; on Windows ``OpenProcess``, ``WaitForSingleObject`` and the creation time from
    ``GetProcessTimes``, through ctypes).

A parent that is killed cannot remove its job's folder, which may hold a copy of a large volume. So each new
:class:`DesignProcess` first removes (:func:`remove_stale_folders`) the job folders in its temporary folder whose
parent is gone and whose child no longer runs; only real directories (never a symbolic link) named
``IsoSimilarityTF-*`` that hold this module's request file, and on POSIX belong to this user, are touched.
"""

import dataclasses
import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import threading
import time
from functools import cache
from typing import Optional

import numpy as np

from . import errors
from .design import TransferFunctionDesign, design_transfer_function
from .value_range import RobustRange

REQUEST_FILE = "request.json"
VALUES_FILE = "values.npy"
PROGRESS_FILE = "progress.jsonl"
DESIGN_FILE = "design.json"
SIMILARITY_FILE = "similarity.npy"
RANGE_FILE = "robust_range.json"
ERROR_FILE = "error.json"
LOG_FILE = "log.txt"
CANCEL_FILE = "cancel"
#: The child's pid and start time, written by the child as it starts.
CHILD_FILE = "child.json"
#: How a job folder's name starts.
FOLDER_PREFIX = "IsoSimilarityTF-"
#: The keys of every request file (how :func:`remove_stale_folders` knows a folder is a job's).
REQUEST_KEYS = ("spacing", "options", "parent")
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
        temporary_folder = temporary_folder or tempfile.gettempdir()
        os.makedirs(temporary_folder, exist_ok=True)
        remove_stale_folders(temporary_folder)  # those of parents that were killed before they could remove them
        self.folder = tempfile.mkdtemp(prefix=FOLDER_PREFIX, dir=temporary_folder)
        self.cancelled = False
        self._progress_offset = 0
        self._process = None
        try:
            request = {
                "spacing": None if spacing is None else [float(s) for s in spacing],
                "options": options or {},
                "parent": os.getpid(),
                "parent_started": _start_time(os.getpid()),  # guards against another process taking the pid
            }
            # The request first: should this process be killed while the voxels are written, the folder is a job's
            # folder of a dead parent, which the next start removes.
            _write_json(os.path.join(self.folder, REQUEST_FILE), request)
            np.save(os.path.join(self.folder, VALUES_FILE), np.ascontiguousarray(values))
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
        range_path = os.path.join(self.folder, RANGE_FILE)
        if os.path.exists(range_path):
            with open(range_path, encoding="utf-8") as file:
                left_out = json.load(file)
            design.robust_range = RobustRange(
                tuple(left_out["value_range"]),
                tuple(left_out["data_range"]),
                tuple(tuple(padding) for padding in left_out["padding"]),
                int(left_out["outliers_low"]),
                int(left_out["outliers_high"]),
            )
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


def _is_pid(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and 0 < value < 2**31


def _proc_stat(pid: int):
    """``(state, start time in clock ticks after boot)`` of a process from Linux's ``/proc``, or None."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as file:
            fields = file.read().rsplit(b")", 1)[1].split()  # after the command name, which may hold anything
        return fields[0].decode("ascii"), int(fields[19])  # fields 3 and 22 of proc(5)
    except (OSError, IndexError, ValueError):
        return None


@cache
def _kernel32():
    import ctypes
    from ctypes import wintypes

    kernel32 = ctypes.WinDLL("kernel32", use_last_error=True)
    kernel32.OpenProcess.argtypes = (wintypes.DWORD, wintypes.BOOL, wintypes.DWORD)
    kernel32.OpenProcess.restype = wintypes.HANDLE
    kernel32.WaitForSingleObject.argtypes = (wintypes.HANDLE, wintypes.DWORD)
    kernel32.WaitForSingleObject.restype = wintypes.DWORD
    kernel32.GetProcessTimes.argtypes = (wintypes.HANDLE,) + (ctypes.POINTER(wintypes.FILETIME),) * 4
    kernel32.GetProcessTimes.restype = wintypes.BOOL
    kernel32.CloseHandle.argtypes = (wintypes.HANDLE,)
    kernel32.CloseHandle.restype = wintypes.BOOL
    return kernel32


def _windows_process(pid: int):
    """``(alive, creation time)`` of a Windows process, from a handle to it; ``(True, None)`` where that cannot be
    told (e.g. access denied), so a live process is never taken for a dead one."""
    import ctypes
    from ctypes import wintypes

    synchronize, process_query_limited_information = 0x00100000, 0x1000
    wait_object_0, error_invalid_parameter = 0, 87
    kernel32 = _kernel32()
    handle = kernel32.OpenProcess(synchronize | process_query_limited_information, False, pid)
    if not handle:
        return ctypes.get_last_error() != error_invalid_parameter, None  # invalid parameter: no such process
    try:
        alive = kernel32.WaitForSingleObject(handle, 0) != wait_object_0  # a process is signalled once it ended
        times = [wintypes.FILETIME() for _ in range(4)]  # creation, exit, kernel, user
        created = None
        if kernel32.GetProcessTimes(handle, *(ctypes.byref(t) for t in times)):
            created = times[0].dwHighDateTime << 32 | times[0].dwLowDateTime
        return alive, created
    finally:
        kernel32.CloseHandle(handle)


def _start_time(pid: int):
    """When the process started (a number that stays the same while it runs), or None where unknown (macOS)."""
    if os.name == "nt":
        return _windows_process(pid)[1]
    info = _proc_stat(pid)
    return None if info is None else info[1]


def _process_alive(pid: int, started=None) -> bool:
    """Whether process ``pid`` runs and, when ``started`` (its :func:`_start_time`) is given and the current start
    time is known, is still the same process rather than another one that got the pid since."""
    if os.name == "nt":  # os.kill would terminate it
        alive, now = _windows_process(pid)
    else:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:  # it runs, as another user
            pass
        info = _proc_stat(pid)
        if info is not None and info[0] in ("Z", "X"):  # ended, not yet reaped by its own parent
            return False
        alive, now = True, None if info is None else info[1]
    return alive and (not isinstance(started, int) or now is None or now == started)


def _parent_alive(pid: Optional[int], started=None) -> bool:
    return pid is None or _process_alive(pid, started)


def _read_record(path: str) -> Optional[dict]:
    """A small JSON object from a regular file, never through a symbolic link; None if it is anything else."""
    if not stat.S_ISREG(os.lstat(path).st_mode):
        return None
    descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_BINARY", 0))
    with os.fdopen(descriptor, "rb") as file:
        data = file.read(1 << 20)
    try:
        record = json.loads(data.decode("utf-8"))
    except ValueError:
        return None
    return record if isinstance(record, dict) else None


def _stale(path: str) -> bool:
    """Whether ``path`` is provably a job folder (see :func:`remove_stale_folders`) whose processes are all gone."""
    info = os.lstat(path)
    if not stat.S_ISDIR(info.st_mode) or (hasattr(os, "getuid") and info.st_uid != os.getuid()):
        return False  # a symbolic link, a file, or another user's
    request = _read_record(os.path.join(path, REQUEST_FILE))
    if request is None or any(key not in request for key in REQUEST_KEYS) or not _is_pid(request["parent"]):
        return False
    if _process_alive(request["parent"], request.get("parent_started")):
        return False
    if not os.path.lexists(os.path.join(path, CHILD_FILE)):
        return True  # the child never started (or is starting, and ends itself: its parent is gone)
    child = _read_record(os.path.join(path, CHILD_FILE))
    return child is not None and _is_pid(child.get("pid")) and not _process_alive(child["pid"], child.get("started"))


def remove_stale_folders(temporary_folder: Optional[str] = None) -> list:
    """Remove the job folders in ``temporary_folder`` (default: the system's) whose parent and child are gone.

    A parent that is killed leaves its job's folder (and the voxels in it) behind; :class:`DesignProcess` calls this
    as it starts. Only folders that are provably a job's are removed: a real directory, never a symbolic link, named
    ``IsoSimilarityTF-*``, on POSIX owned by this user, holding a regular request file with :data:`REQUEST_KEYS`,
    whose parent no longer runs (a pid taken by another process since does not count, where the start time is
    known) and whose child, if it recorded itself, no longer runs. A folder that cannot be read or removed is left.

    Returns:
        The folders removed.
    """
    folder = temporary_folder or tempfile.gettempdir()
    try:
        names = [entry.name for entry in os.scandir(folder) if entry.name.startswith(FOLDER_PREFIX)]
    except OSError:
        return []
    removed = []
    for name in names:
        path = os.path.join(folder, name)
        try:
            if _stale(path):
                shutil.rmtree(path)  # does not follow symbolic links inside
                removed.append(path)
        except (OSError, UnicodeDecodeError):
            pass
    return removed


def _watch(folder: str, parent: Optional[int], parent_started=None) -> None:
    """The child's watchdog thread: end the process when it is cancelled, its folder removed or its parent gone."""
    while True:
        time.sleep(WATCH_INTERVAL_S)
        if (
            os.path.exists(os.path.join(folder, CANCEL_FILE))
            or not os.path.isdir(folder)
            or not _parent_alive(parent, parent_started)
        ):
            os._exit(3)


def main(argv=None) -> int:
    """The child: ``python -c _BOOTSTRAP LIBRARY_PARENT FOLDER`` (or ``python -m IsoSimilarityTFLib.worker FOLDER``)."""
    argv = sys.argv[1:] if argv is None else argv
    folder = argv[-1]
    with open(os.path.join(folder, REQUEST_FILE), encoding="utf-8") as file:
        request = json.load(file)
    _write_json(os.path.join(folder, CHILD_FILE), {"pid": os.getpid(), "started": _start_time(os.getpid())})
    watch = (folder, request.get("parent"), request.get("parent_started"))
    threading.Thread(target=_watch, args=watch, daemon=True).start()
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
    if design.robust_range is not None:  # not part of the design's text: the parent's note on the range
        _write_json(os.path.join(folder, RANGE_FILE), dataclasses.asdict(design.robust_range))
    np.save(os.path.join(folder, SIMILARITY_FILE + ".part.npy"), design.similarity)
    os.replace(os.path.join(folder, SIMILARITY_FILE + ".part.npy"), os.path.join(folder, SIMILARITY_FILE))
    with open(os.path.join(folder, DESIGN_FILE + ".part"), "w", encoding="utf-8") as file:
        file.write(design.to_json())
    os.replace(os.path.join(folder, DESIGN_FILE + ".part"), os.path.join(folder, DESIGN_FILE))
    return 0


if __name__ == "__main__":
    sys.exit(main())
