"""Cancel through a launcher: in Slicer, ``PythonSlicer`` is CTKAppLauncher, which starts ``python-real`` as its own
child (a QProcess) and waits for it, with no signal handler (commontk/AppLauncher v0.1.31 ctkAppLauncher.cpp:696,
Main.cpp), after putting its own paths before the inherited PYTHONPATH (:533-539). The stand-in here does the same, so
killing only the process that was started leaves the computation running (audit F3), and a stale copy of the library
on the launcher's path is imported first unless the child puts its own first (F8)."""

import os
import sys
import textwrap
import time
from unittest import mock

import numpy as np
import pytest
from test_module_widget import module  # noqa: F401 (the module file with stand-ins for Qt)

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


def _job_at(stage, values, python, pids, temporary_folder):
    job = DesignProcess(values, None, {"n_bins": 1024}, python=python, temporary_folder=temporary_folder)
    seen = []
    assert wait_until(lambda: len(pids()) == 2)
    if stage is not None:
        assert wait_until(lambda: seen.extend(s for s, _, _ in job.poll()) or stage in seen, timeout=120), seen
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
    folder = widget.panel.job.folder
    widget.cleanup()
    assert widget.panel.job is None
    assert wait_until(lambda: not any(alive(pid) for pid in pids()), timeout=5.0)
    assert not os.path.exists(folder)
