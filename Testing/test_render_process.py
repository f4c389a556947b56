"""The render stage's child process: it renders what a run in one process renders, reports its failures as one line,
and never outlives the run (nor re-runs the caller's script)."""

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_cli import read_png

from IsoSimilarityTFLib.design import design_transfer_function
from IsoSimilarityTFLib.errors import RenderError
from isosimtf import run
from isosimtf.outputs import RunResult, render_outputs
from isosimtf.phantom import head_phantom
from isosimtf.render_process import RenderProcess
from isosimtf.rendering import slicer_core_available
from isosimtf.volume_io import Volume

pytestmark = pytest.mark.skipif(not slicer_core_available(), reason="slicer-core is not installed")

psutil = pytest.importorskip("psutil")


def _result(outdir: Path) -> RunResult:
    phantom = head_phantom(24, seed=5)
    volume = Volume(phantom.values, (8.0, 8.0, 8.0), name="head")
    design = design_transfer_function(volume.values, volume.spacing)
    outdir.mkdir()
    return RunResult(design, volume, {}, outdir)


def _children() -> list:
    return [p for p in psutil.Process().children(recursive=True) if p.status() != psutil.STATUS_ZOMBIE]


def test_the_child_renders_what_one_process_renders(tmp_path: Path) -> None:
    here, there = _result(tmp_path / "here"), _result(tmp_path / "there")
    render_outputs(here, size=64)
    labels = []

    class Progress:
        def update(self, label: str) -> None:
            labels.append(label)

    with RenderProcess(size=64) as renderer:
        renderer.render(there, view="anterior", size=64, progress=Progress())
    assert sorted(there.files) == sorted(here.files)
    assert [p.relative_to(there.outdir) for p in there.scene_files] == [
        p.relative_to(here.outdir) for p in here.scene_files
    ]
    for role in ("render_png", "classes_png"):
        np.testing.assert_array_equal(read_png(there.files[role]), read_png(here.files[role]))
    assert labels[-3:] == ["render.png", "classes.seg.nrrd", "scene"]
    assert not _children()


def test_a_failure_in_the_child_is_one_render_error_line(tmp_path: Path) -> None:
    result = _result(tmp_path / "out")
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    result.outdir = blocker / "out"  # the child cannot write there
    with RenderProcess(size=64) as renderer, pytest.raises(RenderError) as caught:
        renderer.render(result, view="anterior", size=64)
    assert "\n" not in str(caught.value) and str(caught.value)
    assert not _children()


def test_a_child_that_dies_is_reported(tmp_path: Path) -> None:
    result = _result(tmp_path / "out")
    with RenderProcess(size=64) as renderer:
        renderer._process.kill()
        with pytest.raises(RenderError, match=r"^the rendering process ended unexpectedly \(exit code -9\)$"):
            renderer.render(result, view="anterior", size=64)


def test_a_run_that_fails_before_rendering_leaves_no_child(tmp_path: Path) -> None:
    start = time.perf_counter()
    with pytest.raises(Exception, match="no such file or directory"):
        run.run(tmp_path / "no-such-volume.nrrd", tmp_path / "out")
    assert not _children()
    assert time.perf_counter() - start < 10  # the child was ended, not waited for until it rendered


def test_a_script_without_a_main_guard_runs_once(tmp_path: Path) -> None:
    """The child is not ``multiprocessing``'s spawn, which would run the caller's script again in it."""
    script = tmp_path / "script.py"
    script.write_text(
        "from isosimtf.run import run\n"
        "print('script ran', flush=True)\n"
        f"run('phantom', {str(tmp_path / 'out')!r}, phantom_size=16, size=64)\n"
    )
    completed = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert completed.returncode == 0, completed.stderr
    assert completed.stdout.count("script ran") == 1
    assert (tmp_path / "out" / "render.png").is_file()


def test_close_ends_a_starting_child_at_once() -> None:
    renderer = RenderProcess(size=64)
    start = time.perf_counter()
    renderer.close()
    assert time.perf_counter() - start < 1.0  # killed, not waited for while it imports slicer-core
    assert renderer._process.returncode is not None
    assert not _children()


def test_a_child_dying_of_low_memory_says_so_in_one_line(tmp_path: Path) -> None:
    """Before: the child's native dumps (``terminate called after throwing an instance of 'std::bad_alloc'``,
    libEGL warnings) reached the terminal beside the error line, which said only "exit code -6". Now the child's
    stderr is kept, its reason joins the one line, and the dumps show with ISOSIMTF_DEBUG=1 alone."""
    limit = 1 << 30  # enough for the design of 64^3, not for the child's headless Slicer to render it
    bounded = (
        f"import resource, runpy, sys; resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit})); "
        "runpy.run_module('isosimtf', run_name='__main__')"
    )
    argv = [sys.executable, "-c", bounded, "phantom", "--phantom-size", "64", "-q", "-o", str(tmp_path / "out")]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    if done.returncode == 0:
        pytest.skip("the child rendered within the bound here")
    assert done.returncode == 1 and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith("isosimtf: error: rendering failed (the rendering process ended unexpectedly")
    assert "out of memory" in done.stderr
