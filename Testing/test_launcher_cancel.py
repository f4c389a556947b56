"""Cancel through a launcher: in Slicer, ``PythonSlicer`` is CTKAppLauncher, which starts ``python-real`` as its own
child (a QProcess) and waits for it, with no signal handler (commontk/AppLauncher v0.1.31 ctkAppLauncher.cpp:696,
Main.cpp), after putting its own paths before the inherited PYTHONPATH (:533-539). The stand-in here does the same, so
killing only the process that was started leaves the computation running (audit F3), and a stale copy of the library
on the launcher's path is imported first unless the child puts its own first (F8).

The job stops in three layers (see :mod:`IsoSimilarityTFLib.worker`): (a) Cancel kills its process group, (b) the child
ends itself when the ``cancel`` file appears or its folder is removed, (c) the child ends itself when its parent is
gone. ``test_layer_*`` checks each with the other two out of the way, from the test's side only."""

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
from unittest import mock

import numpy as np
import pytest
from test_module_widget import module  # noqa: F401 (the module file with stand-ins for Qt)

from IsoSimilarityTFLib import worker
from IsoSimilarityTFLib.panel import RUNNING_CHILD
from IsoSimilarityTFLib.worker import DesignProcess
from isosimtf.phantom import head_phantom

LAUNCHER = """\
#!{python}
import os, subprocess, sys
environment = dict(os.environ)
extra = environment.get("LAUNCHER_PYTHONPATH")
if extra:  # the launcher's own paths come first
    environment["PYTHONPATH"] = os.pathsep.join(p for p in (extra, environment.get("PYTHONPATH", "")) if p)
child = subprocess.Popen([sys.executable] + sys.argv[1:], env=environment)
with open(environment["LAUNCHER_PIDS"], "a") as pids:
    pids.write("%d %d\\n" % (os.getpid(), child.pid))
sys.exit(child.wait())
"""


@pytest.fixture()
def launcher(tmp_path, monkeypatch):
    """``(path of the stand-in PythonSlicer, function giving the pids it recorded)``."""
    path = tmp_path / "bin" / "PythonSlicer"
    path.parent.mkdir()
    path.write_text(LAUNCHER.format(python=sys.executable))
    path.chmod(0o755)
    pids_file = tmp_path / "pids.txt"
    monkeypatch.setenv("LAUNCHER_PIDS", str(pids_file))

    def pids():
        if not pids_file.exists():
            return []
        return [int(p) for line in pids_file.read_text().split("\n") if line for p in line.split()]

    return str(path), pids


def alive(pid):
    """Whether the process runs (a zombie, dead but not yet reaped by a parent that does not wait, has ended)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except FileNotFoundError:
        return False


def wait_until(condition, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


pytestmark = pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads process states from /proc")


@pytest.fixture(scope="module")
def values():
    return head_phantom(64, seed=1).values  # 1024 bins: similarity and affinity propagation each take seconds


def _job_at(stage, values, python, pids, temporary_folder, options=None):
    job = DesignProcess(values, None, options or {"n_bins": 1024}, python=python, temporary_folder=temporary_folder)
    seen = []
    assert wait_until(lambda: len(pids()) == 2, timeout=60)
    if stage is not None:
        assert wait_until(lambda: seen.extend(s for s, _, _ in job.poll()) or stage in seen, timeout=300), seen
    assert job.running and all(alive(pid) for pid in pids())
    return job


@pytest.mark.parametrize("stage", [None, "quantize", "similarity", "clustering"])
def test_f3_cancel_ends_every_process_of_the_job_and_leaves_no_folder(stage, values, launcher, tmp_path):
    python, pids = launcher
    temporary = tmp_path / "slicer-temporary"
    job = _job_at(stage, values, python, pids, str(temporary))
    assert os.path.dirname(job.folder) == str(temporary)  # F6: Slicer's temporary path, not the system's
    job.cancel()
    job.close()
    assert wait_until(lambda: not any(alive(pid) for pid in pids()), timeout=5.0), pids()
    assert list(temporary.iterdir()) == []


def test_f3_the_child_ends_itself_when_only_the_launcher_is_killed(values, launcher, tmp_path):
    python, pids = launcher
    job = _job_at("similarity", values, python, pids, str(tmp_path))
    child_pid = pids()[1]
    job._process.kill()  # what cancel() did before: the launcher alone
    job._process.wait()
    open(os.path.join(job.folder, "cancel"), "wb").close()
    assert wait_until(lambda: not alive(child_pid), timeout=5.0)
    job.close()


def test_f3_the_child_ends_itself_when_its_folder_is_removed(values, launcher, tmp_path):
    import shutil

    python, pids = launcher
    job = _job_at("similarity", values, python, pids, str(tmp_path))
    shutil.rmtree(job.folder, ignore_errors=True)
    assert wait_until(lambda: not any(alive(pid) for pid in pids()), timeout=5.0)
    job.close()


def test_f8_the_child_imports_the_library_of_the_running_module(launcher, tmp_path, monkeypatch):
    """An installed copy on the launcher's path (Slicer v5.8.1 qSlicerExtensionsManagerModel.cxx:732-735) must not
    be the one the child runs."""
    python = launcher[0]
    stale = tmp_path / "installed" / "IsoSimilarityTFLib"
    stale.mkdir(parents=True)
    (stale / "__init__.py").write_text("")
    (stale / "worker.py").write_text(textwrap.dedent("""\
        import sys
        def main(argv=None):
            sys.stderr.write("the installed copy ran\\n")
            return 7
        if __name__ == "__main__":
            sys.exit(main())
        """))  # fmt: skip
    monkeypatch.setenv("LAUNCHER_PYTHONPATH", str(stale.parent))
    with DesignProcess(np.random.default_rng(0).random((12, 12, 12)), None, {"n_bins": 16}, python=python) as job:
        design = job.wait(timeout=120)
    assert design.n_bins == 16


def test_f3_closing_slicer_ends_a_running_job(module, values, launcher, tmp_path):  # noqa: F811
    """Slicer calls the widget's cleanup() when it quits (and before a Reload)."""
    python, pids = launcher
    widget = module.IsoSimilarityTFWidget()
    widget.ui = mock.MagicMock(name="ui")
    widget.logic = module.IsoSimilarityTFLogic()
    widget.panel = module.PanelModel(widget.logic, widget)
    widget._pollTimer = mock.MagicMock(name="timer")
    widget.panel.job = _job_at("similarity", values, python, pids, str(tmp_path / "temporary"))
    widget.panel.apply_state = RUNNING_CHILD  # as PanelModel.apply() leaves it while a child designs
    folder = widget.panel.job.folder
    widget.cleanup()
    assert widget.panel.job is None
    assert wait_until(lambda: not any(alive(pid) for pid in pids()), timeout=5.0)
    assert not os.path.exists(folder)


# A job that runs until it is stopped: affinity propagation needs at least 10000 iterations of 1024 isovalues (about
# 90 s here, far past the 20 s a stop may take), so a child that ends in time was stopped, not finished.
ENDLESS = {"n_bins": 1024, "max_iter": 100_000, "convergence_iter": 10_000}
#: Seconds a stop may take on a slow, loaded machine (the child checks every 0.1 s).
STOP_S = 20.0


def still_running(pids):
    return [pid for pid in pids() if alive(pid)]


def job_processes(folder):
    """The running processes whose command line names the job's folder (the launcher and python-real)."""
    found = []
    for pid in (int(entry) for entry in os.listdir("/proc") if entry.isdigit()):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as file:
                if folder.encode() in file.read() and alive(pid):
                    found.append(pid)
        except OSError:
            pass
    return found


def end_leftovers(pids, folder):
    """What a broken layer left running: killed, by pid, so a failing test does not leave a computation behind."""
    for pid in set(pids()) | set(job_processes(folder)):
        if alive(pid):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def cancel_within(job, timeout):
    """``job.cancel()``, which waits for the launcher, bounded (it would wait for ever if no layer stopped it)."""
    thread = threading.Thread(target=job.cancel, daemon=True)
    thread.start()
    thread.join(timeout)
    return not thread.is_alive()


def stopped(job, pids):
    """Every process of the job ended within STOP_S, by a stop (no design written), and none is left in /proc."""
    assert wait_until(lambda: not still_running(pids), timeout=STOP_S), still_running(pids)
    assert job_processes(job.folder) == []
    assert not os.path.exists(os.path.join(job.folder, worker.DESIGN_FILE))


def test_layer_a_cancel_kills_the_process_group_alone(values, launcher, tmp_path, monkeypatch):
    """(a) alone: cancel() writes its cancel file under a name the child does not watch, the folder stays and the
    parent (this process) lives, so only the process-group kill can end python-real behind the launcher."""
    python, pids = launcher
    monkeypatch.setattr(worker, "CANCEL_FILE", "cancel-not-watched")  # the parent's name only; the child's is "cancel"
    job = _job_at("clustering", values, python, pids, str(tmp_path), ENDLESS)
    try:
        assert cancel_within(job, STOP_S)
        stopped(job, pids)
        assert job._process.returncode == -signal.SIGKILL
        assert os.path.isdir(job.folder) and not os.path.exists(os.path.join(job.folder, "cancel"))
    finally:
        end_leftovers(pids, job.folder)
        job.close()


def test_layer_b_the_cancel_file_alone_ends_the_child(values, launcher, tmp_path, monkeypatch):
    """(b) alone: cancel() kills nothing (``_kill_group`` does nothing), the folder stays and the parent lives, so
    only the child's watchdog, seeing the cancel file, can end it. (Its other trigger, the folder removed, is
    test_f3_the_child_ends_itself_when_its_folder_is_removed, where nothing is killed either.)"""
    python, pids = launcher
    monkeypatch.setattr(DesignProcess, "_kill_group", lambda self: None)
    job = _job_at("clustering", values, python, pids, str(tmp_path), ENDLESS)
    try:
        assert cancel_within(job, STOP_S)
        stopped(job, pids)
        assert job._process.returncode == 3  # the watchdog's exit code, passed on by the launcher
        assert os.path.isdir(job.folder)
    finally:
        end_leftovers(pids, job.folder)
        job.close()


PARENT = """\
import os, sys, time
import numpy as np
sys.path.insert(0, {library!r})
from IsoSimilarityTFLib.worker import DesignProcess
job = DesignProcess(np.load({values!r}), None, {options!r}, python={python!r}, temporary_folder={temporary!r})
seen = []
while "clustering" not in seen and job.running:
    seen += [stage for stage, _, _ in job.poll()]
    time.sleep(0.05)
with open({ready!r} + ".part", "w") as file:
    file.write(job.folder)
os.replace({ready!r} + ".part", {ready!r})
time.sleep(3600)
"""


def test_layer_c_the_child_ends_itself_when_its_parent_is_killed(values, launcher, tmp_path):
    """(c) alone: a parent process starts the job and is killed with SIGKILL, so it neither cancels nor removes the
    folder, and the job's own process group survives it; only the child's parent check can end python-real. The
    folder it leaves is then a stale one, which the next start's sweep removes."""
    python, pids = launcher
    np.save(tmp_path / "values.npy", values)
    temporary, ready = tmp_path / "temporary", tmp_path / "ready.txt"
    script = PARENT.format(
        library=os.path.dirname(os.path.dirname(worker.__file__)),
        values=str(tmp_path / "values.npy"),
        options=ENDLESS,
        python=python,
        temporary=str(temporary),
        ready=str(ready),
    )
    parent = subprocess.Popen([sys.executable, "-c", script])
    folder = ""
    try:
        assert wait_until(lambda: ready.exists() or parent.poll() is not None, timeout=300)
        assert ready.exists(), f"the parent ended with code {parent.returncode}"
        folder = ready.read_text()
        assert len(pids()) == 2 and all(alive(pid) for pid in pids())
        with open(os.path.join(folder, worker.CHILD_FILE)) as file:
            assert json.load(file)["pid"] == pids()[1]  # python-real recorded itself
        parent.kill()
        parent.wait()
        assert wait_until(lambda: not still_running(pids), timeout=STOP_S), still_running(pids)
        assert job_processes(folder) == []
        assert not os.path.exists(os.path.join(folder, worker.DESIGN_FILE))
        assert not os.path.exists(os.path.join(folder, worker.CANCEL_FILE))
        assert worker.remove_stale_folders(str(temporary)) == [folder]
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        end_leftovers(pids, folder or str(temporary))
        shutil.rmtree(temporary, ignore_errors=True)
