"""The design in a child process: same result as in-process, progress, errors, and Cancel within a second at every
stage (the child is killed, clustering included)."""

import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from IsoSimilarityTFLib import OptionError, design_transfer_function, worker
from IsoSimilarityTFLib.worker import DesignProcess
from isosimtf.phantom import head_phantom


@pytest.fixture(scope="module")
def phantom():
    return head_phantom(40, seed=2)


def test_child_gives_the_same_design_as_in_process(phantom):
    reports = []
    with DesignProcess(phantom.values, phantom.spacing, {"n_bins": 128}) as job:
        design = job.wait(timeout=120, progress=lambda *report: reports.append(report))
        folder = job.folder
    assert not os.path.exists(folder)
    expected = design_transfer_function(phantom.values, phantom.spacing, n_bins=128)
    np.testing.assert_array_equal(design.labels, expected.labels)
    assert design.to_dict()["classes"] == expected.to_dict()["classes"]
    # The Slicer module's child gets the look's visibility step, and its preview for the Detail slider.
    assert design.to_dict()["tissues"] == expected.to_dict()["tissues"]
    assert all(t.picture_share is not None for t in design.tissues)
    np.testing.assert_array_equal(design.preview.bins, expected.preview.bins)
    np.testing.assert_array_equal(design.similarity, expected.similarity)
    assert design.spacing == expected.spacing
    stages = [stage for stage, _, _ in reports]
    assert stages[0] == "quantize" and stages[-1] == "tissues" and "similarity" in stages and "clustering" in stages


def test_child_errors_come_back_with_their_type_and_message(phantom):
    with DesignProcess(phantom.values, None, {"n_bins": 1}) as job:
        with pytest.raises(OptionError, match="n_bins"):
            job.wait(timeout=120)
    with DesignProcess(np.zeros((8, 8, 8)), None, {}) as job:
        with pytest.raises(ValueError, match="constant"):
            job.wait(timeout=120)


def test_a_child_that_dies_is_reported(phantom, tmp_path):
    script = tmp_path / "python"
    script.write_text("#!/bin/sh\necho 'Fatal Python error: on purpose'\nexit 3\n")
    script.chmod(0o755)
    with DesignProcess(phantom.values, None, {}, python=str(script)) as job:
        with pytest.raises(RuntimeError, match="ended with code 3: Fatal Python error: on purpose"):
            job.wait(timeout=120)


def cancel_at(stage_wanted, values, options):
    """Start a design, cancel it as soon as ``stage_wanted`` is reported; seconds from Cancel to the child's end."""
    with DesignProcess(values, None, options) as job:
        deadline = time.monotonic() + 300
        seen = []
        while time.monotonic() < deadline and job.running:
            seen += [stage for stage, _, _ in job.poll()]
            if stage_wanted in seen:
                break
            time.sleep(0.02)
        assert stage_wanted in seen and job.running, f"never saw {stage_wanted} while running: {seen}"
        start = time.monotonic()
        job.cancel()
        elapsed = time.monotonic() - start
        assert not job.running
        with pytest.raises(RuntimeError, match="cancelled"):
            job.result()
    return elapsed


@pytest.mark.parametrize("stage", ["similarity", "clustering"])
def test_cancel_stops_every_stage_within_a_second(stage):
    # 1024 bins of a 64^3 phantom: similarity and affinity propagation each take seconds here.
    values = head_phantom(64, seed=1).values
    assert cancel_at(stage, values, {"n_bins": 1024}) < 1.0


# The parent check (stop layer c) and the sweep of stale job folders.


def dead_pid():
    """The pid of a process that has ended and been reaped."""
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


@pytest.mark.skipif(os.name == "nt", reason="the POSIX path")
def test_parent_check_posix_live_and_dead_pids():
    assert worker._parent_alive(None)  # no parent recorded: nothing to watch
    assert worker._parent_alive(os.getpid(), worker._start_time(os.getpid()))
    assert worker._parent_alive(os.getpid())
    assert not worker._parent_alive(dead_pid())
    with subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]) as live:
        try:
            assert worker._parent_alive(live.pid, worker._start_time(live.pid))
        finally:
            live.kill()


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="start times and states from /proc")
def test_parent_check_sees_a_reused_pid_and_a_zombie():
    started = worker._start_time(os.getpid())
    assert isinstance(started, int)
    assert not worker._parent_alive(os.getpid(), started + 1)  # another process that got the pid
    zombie = subprocess.Popen([sys.executable, "-c", "pass"])
    try:
        deadline = time.monotonic() + 60  # not reaped (no poll()) until it has become a zombie
        while (worker._proc_stat(zombie.pid) or ("?",))[0] != "Z" and time.monotonic() < deadline:
            time.sleep(0.02)
        os.kill(zombie.pid, 0)  # os.kill alone takes it for alive
        assert not worker._parent_alive(zombie.pid)
    finally:
        zombie.wait()


class FakeKernel32:
    """kernel32 as _windows_process calls it: one process, running or ended, or no handle with an error code."""

    def __init__(self, handle, wait_result=0x102, error=0):
        self.handle, self.wait_result, self.error, self.closed = handle, wait_result, error, []

    def OpenProcess(self, access, inherit, pid):
        assert access == 0x00100000 | 0x1000 and not inherit  # SYNCHRONIZE | PROCESS_QUERY_LIMITED_INFORMATION
        return self.handle

    def WaitForSingleObject(self, handle, milliseconds):
        assert handle == self.handle and milliseconds == 0
        return self.wait_result

    def GetProcessTimes(self, handle, creation, *others):
        creation._obj.dwHighDateTime, creation._obj.dwLowDateTime = 7, 9
        return 1

    def CloseHandle(self, handle):
        self.closed.append(handle)
        return 1


@pytest.mark.parametrize(
    "kernel32, expected",
    [
        (FakeKernel32(handle=42, wait_result=0x102), (True, 7 << 32 | 9)),  # WAIT_TIMEOUT: still running
        (FakeKernel32(handle=42, wait_result=0), (False, 7 << 32 | 9)),  # WAIT_OBJECT_0: it has ended
        (FakeKernel32(handle=None, error=87), (False, None)),  # ERROR_INVALID_PARAMETER: no such process
        (FakeKernel32(handle=None, error=5), (True, None)),  # access denied: it exists
    ],
)
def test_parent_check_windows_logic(kernel32, expected, monkeypatch):
    """The Windows path's decisions with a stand-in for kernel32 (the ctypes calls themselves need Windows)."""
    import ctypes

    monkeypatch.setattr(worker, "_kernel32", lambda: kernel32)
    monkeypatch.setattr(ctypes, "get_last_error", lambda: kernel32.error, raising=False)
    assert worker._windows_process(1234) == expected
    assert kernel32.closed == ([] if kernel32.handle is None else [kernel32.handle])


def job_folder(parent, name, *, temporary, started=None, child=None):
    folder = temporary / f"IsoSimilarityTF-{name}"
    folder.mkdir()
    request = {"spacing": None, "options": {}, "parent": parent, "parent_started": started}
    (folder / worker.REQUEST_FILE).write_text(json.dumps(request))
    (folder / worker.VALUES_FILE).write_bytes(b"voxels")
    if child is not None:
        (folder / worker.CHILD_FILE).write_text(json.dumps({"pid": child, "started": None}))
    return folder


def test_stale_job_folders_are_removed_and_nothing_else(tmp_path):
    dead = dead_pid()
    stale = job_folder(dead, "stale", temporary=tmp_path)
    stale_child_gone = job_folder(dead, "child-gone", child=dead_pid(), temporary=tmp_path)
    live = job_folder(os.getpid(), "live", started=worker._start_time(os.getpid()), temporary=tmp_path)
    live_child = job_folder(dead, "live-child", child=os.getpid(), temporary=tmp_path)
    started = worker._start_time(os.getpid())  # None where unknown: the pid alone then
    reused = job_folder(os.getpid(), "reused", started=None if started is None else started + 1, temporary=tmp_path)
    foreign = tmp_path / "IsoSimilarityTF-foreign"  # named like a job, without our request file
    foreign.mkdir()
    (foreign / "data.txt").write_text("someone else's")
    not_ours = tmp_path / "IsoSimilarityTF-other-keys"  # a request file, but not with our keys
    not_ours.mkdir()
    (not_ours / worker.REQUEST_FILE).write_text(json.dumps({"parent": dead}))
    (tmp_path / "elsewhere").mkdir()
    target = job_folder(dead, "target", temporary=tmp_path / "elsewhere")  # stale, but reached only through a link
    link = tmp_path / "IsoSimilarityTF-link"
    link.symlink_to(target, target_is_directory=True)
    inner_link = job_folder(dead, "inner-link", temporary=tmp_path)  # removed, but not what its link points to
    (inner_link / "outside").symlink_to(foreign, target_is_directory=True)
    other_prefix = job_folder(dead, "x", temporary=tmp_path).rename(tmp_path / "Other-x")

    removed = worker.remove_stale_folders(str(tmp_path))

    expected = [stale, stale_child_gone, inner_link] + ([] if started is None else [reused])
    assert sorted(removed) == sorted(str(folder) for folder in expected)
    for kept in (live, live_child, foreign, not_ours, link, target, other_prefix):
        assert os.path.lexists(kept), kept
    assert link.is_symlink() and (target / worker.VALUES_FILE).exists()
    assert (foreign / "data.txt").exists()
    # The link is never judged a job's folder, whatever it leads to (rmtree's own refusal is a second guard).
    assert not worker._stale(str(link)) and worker._stale(str(target))


def test_a_new_job_sweeps_its_temporary_folder(tmp_path):
    stale = job_folder(dead_pid(), "stale", temporary=tmp_path)
    live = job_folder(os.getpid(), "live", temporary=tmp_path)
    script = tmp_path / "python"
    script.write_text("#!/bin/sh\nexit 0\n")
    script.chmod(0o755)
    with DesignProcess(np.zeros((4, 4, 4)), None, {}, python=str(script), temporary_folder=str(tmp_path)) as job:
        assert not stale.exists() and live.exists()
        with open(os.path.join(job.folder, worker.REQUEST_FILE)) as file:
            request = json.load(file)
        assert request["parent"] == os.getpid() and request["parent_started"] == worker._start_time(os.getpid())
        assert set(worker.REQUEST_KEYS) <= request.keys()
        job._process.wait()
    assert live.exists()
