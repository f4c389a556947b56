"""The output folder never loses a user's file (issue 18, items 9-11): a file changed since a run wrote it is never
removed or replaced, links are never written through, one run at a time, checks before the design, atomic writes
recorded only when complete. Runs of the phantom through ``isosimtf``'s own entry point."""

import fcntl
import json
import os
from pathlib import Path

import pytest

from IsoSimilarityTFLib.design import TransferFunctionDesign
from isosimtf import cli
from isosimtf.output_folder import LOCK_FILE, MAX_OUTDIR_CHARACTERS, TEMPORARY_PREFIX
from isosimtf.rendering import slicer_core_available

needs_slicer = pytest.mark.skipif(not slicer_core_available(), reason="slicer-core is not installed")
PHANTOM = ["phantom", "--phantom-size", "16", "-q"]


def _run(argv: list, capfd) -> tuple[int, str]:
    code = cli.main([str(a) for a in argv])
    return code, capfd.readouterr().err


def _document(outdir: Path) -> dict:
    return json.loads((outdir / "classes.json").read_text(encoding="utf-8"))


def _no_temporary_files(outdir: Path) -> bool:
    return not [p for p in outdir.rglob("*") if p.name.startswith(TEMPORARY_PREFIX) or p.name == LOCK_FILE]


@needs_slicer
def test_a_scene_saved_from_slicer_is_never_removed_or_replaced(tmp_path: Path, capfd) -> None:
    """Before: a --no-render re-run deleted scene/scene.mrml after the user saved it from Slicer."""
    outdir = tmp_path / "out"
    code, err = _run([*PHANTOM, "--size", "64", "-o", outdir], capfd)
    assert code == 0, err
    assert set(_document(outdir)["written_stamps"]) >= {"render.png", "scene/scene.mrml", "similarity.npy"}
    scene = outdir / "scene" / "scene.mrml"
    scene.write_text(scene.read_text() + "<!-- the user's markups -->\n")  # as if saved from Slicer
    edited = scene.read_text()

    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 0
    assert "kept 1 file(s) of a previous run changed since it wrote them (not removed): scene/scene.mrml" in err
    assert "removed" in err and "render.png" in err and not (outdir / "render.png").exists()  # ours, unchanged
    assert scene.read_text() == edited
    assert "scene/scene.mrml" in _document(outdir)["written"]  # still recorded as changed: later runs keep it too

    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 0 and scene.read_text() == edited

    code, err = _run([*PHANTOM, "--size", "64", "-o", outdir], capfd)  # rendering would replace it: refused
    assert code == 2 and err.count("\n") == 1
    assert f"'{scene}' has changed since isosimtf wrote it (e.g. saved from Slicer)" in err
    assert "[1/" not in err and scene.read_text() == edited and _no_temporary_files(outdir)


def test_an_edited_output_is_not_replaced(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    assert _run([*PHANTOM, "--no-render", "-o", outdir], capfd)[0] == 0
    (outdir / "transfer_function.vp.json").write_text('{"mine": true}')
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 2 and "transfer_function.vp.json' has changed since isosimtf wrote it" in err
    assert (outdir / "transfer_function.vp.json").read_text() == '{"mine": true}'


def test_links_in_the_output_folder_are_never_written_through(tmp_path: Path, capfd) -> None:
    """Before: a symlink in OUTDIR was written through, overwriting a file outside OUTDIR."""
    outside = tmp_path / "precious.vp"
    outside.write_text("precious")
    outdir = tmp_path / "out"
    outdir.mkdir()
    (outdir / "transfer_function.vp").symlink_to(outside)
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 2 and "is a symbolic link" in err and "never writes through links" in err
    assert outside.read_text() == "precious"
    (outdir / "transfer_function.vp").unlink()
    if slicer_core_available():
        (outdir / "scene").symlink_to(tmp_path, target_is_directory=True)
        code, err = _run([*PHANTOM, "--size", "64", "-o", outdir], capfd)
        assert code == 2 and f"'{outdir / 'scene'}' is a symbolic link" in err


def test_a_second_run_into_the_folder_is_refused_while_one_runs(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    outdir.mkdir()
    with open(outdir / LOCK_FILE, "a+b") as held:  # what a running isosimtf holds
        fcntl.flock(held.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 2 and f"another isosimtf run is writing into '{outdir}'" in err
    assert "[1/" not in err and not (outdir / "classes.json").exists()
    assert _run([*PHANTOM, "--no-render", "-o", outdir], capfd)[0] == 0 and _no_temporary_files(outdir)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_output_folder_is_refused_before_the_design(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    outdir.mkdir()
    outdir.chmod(0o555)
    try:
        code, err = _run(["phantom", "--phantom-size", "16", "--no-render", "-o", outdir], capfd)
    finally:
        outdir.chmod(0o755)
    assert code == 1 and "cannot write into the output folder" in err and "[1/" not in err


def test_an_overlong_output_path_is_refused_before_the_design(tmp_path: Path, capfd) -> None:
    """Before: a 4,045-character path segfaulted the render process and left a staging folder."""
    outdir = tmp_path / ("d" * 200) / ("e" * 200) / ("f" * 200) / ("g" * 200) / ("h" * 200)
    assert len(str(outdir)) > MAX_OUTDIR_CHARACTERS
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert (
        code == 2 and f"at most {MAX_OUTDIR_CHARACTERS} are accepted" in err and not (tmp_path / ("d" * 200)).exists()
    )


def test_a_failed_write_leaves_no_part_and_records_nothing_half_written(tmp_path: Path, capfd, monkeypatch) -> None:
    """Before: a full disk left a truncated file that was not in `written`."""
    outdir = tmp_path / "out"
    assert _run([*PHANTOM, "--no-render", "-o", outdir], capfd)[0] == 0
    before = (outdir / "transfer_function.vp").read_bytes()

    def full_disk(self, path) -> None:
        Path(path).write_bytes(b"half a fi")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(TransferFunctionDesign, "write_vp", full_disk)
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 1 and err.count("\n") == 1
    assert f"cannot write '{outdir / 'transfer_function.vp'}': No space left on device" in err
    assert (outdir / "transfer_function.vp").read_bytes() == before  # the old file, whole
    assert _no_temporary_files(outdir)
    document = _document(outdir)
    for name, (size, _) in document["written_stamps"].items():
        assert (outdir / name).stat().st_size == size, name  # every file recorded is complete


def test_a_killed_runs_leftovers_are_cleared_by_the_next_run(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    (outdir / f"{TEMPORARY_PREFIX}abc123" / "scene").mkdir(parents=True)
    (outdir / f"{TEMPORARY_PREFIX}99-render.png").write_bytes(b"part")
    (outdir / "notes.txt").write_text("mine")
    assert _run([*PHANTOM, "--no-render", "-o", outdir], capfd)[0] == 0
    assert _no_temporary_files(outdir) and (outdir / "notes.txt").read_text() == "mine"


def test_a_full_disk_leaves_the_previous_files_whole(tmp_path: Path, capfd) -> None:
    """A real failed write: the isosimtf process may write files of at most 100 KB (RLIMIT_FSIZE, as a full disk
    fails a write), so similarity.npy (512 KiB) cannot be written. One line, no part file, the old file whole."""
    import resource
    import signal
    import subprocess
    import sys

    outdir = tmp_path / "out"
    assert _run([*PHANTOM, "--no-render", "-o", outdir], capfd)[0] == 0
    before = {p.relative_to(outdir): p.read_bytes() for p in outdir.rglob("*") if p.is_file()}

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, 100_000))

    argv = [sys.executable, "-m", "isosimtf", *PHANTOM, "--no-render", "--bins", "128", "-o", str(outdir)]
    done = subprocess.run(argv, capture_output=True, text=True, preexec_fn=limit, timeout=300)
    assert done.returncode == 1 and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith(f"isosimtf: error: cannot write '{outdir / 'similarity.npy'}': ")
    assert {p.relative_to(outdir): p.read_bytes() for p in outdir.rglob("*") if p.is_file()} == before
    assert _no_temporary_files(outdir)


@needs_slicer
def test_a_render_that_fails_midway_still_records_its_complete_pictures(tmp_path: Path, capfd) -> None:
    """Before: pictures the render process had written were recorded only when it finished, so a failure or Ctrl+C
    left them unrecorded. Here render.png cannot be written (a folder holds its name), after classes.png was."""
    outdir = tmp_path / "out"
    (outdir / "render.png").mkdir(parents=True)
    code, err = _run([*PHANTOM, "--size", "64", "-o", outdir], capfd)
    assert code == 1 and "rendering failed" in err
    document = _document(outdir)
    assert "classes.png" in document["written"] and "render.png" not in document["written"]
    assert document["written_stamps"]["classes.png"][0] == (outdir / "classes.png").stat().st_size
    assert _no_temporary_files(outdir)
