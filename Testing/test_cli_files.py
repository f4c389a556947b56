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
from isosimtf.output_folder import JOURNAL_FILE, LOCK_FILE, MAX_OUTDIR_CHARACTERS, TEMPORARY_PREFIX, file_stamp
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
    for name, stamp in document["written_stamps"].items():
        assert file_stamp(outdir / name) == stamp, name  # every file recorded is complete, as recorded


def test_a_killed_runs_leftovers_are_cleared_by_the_next_run(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    (outdir / f"{TEMPORARY_PREFIX}staging-123-abc_9" / "scene").mkdir(parents=True)
    (outdir / f"{TEMPORARY_PREFIX}99-render.png").write_bytes(b"part")
    (outdir / "looks").mkdir()
    (outdir / "looks" / f"{TEMPORARY_PREFIX}99-see-through.vp.json").write_bytes(b"part")
    (outdir / "notes.txt").write_text("mine")
    # Entries that only start like ours are the user's: never removed (before: every .isosimtf-* went, rmtree).
    (outdir / f"{TEMPORARY_PREFIX}my-backup" / "a").mkdir(parents=True)
    (outdir / f"{TEMPORARY_PREFIX}99-notes.txt").write_text("mine")
    assert _run([*PHANTOM, "--no-render", "-o", outdir], capfd)[0] == 0
    assert not (outdir / f"{TEMPORARY_PREFIX}staging-123-abc_9").exists()
    assert not (outdir / f"{TEMPORARY_PREFIX}99-render.png").exists()
    assert not (outdir / "looks" / f"{TEMPORARY_PREFIX}99-see-through.vp.json").exists()
    assert (outdir / "notes.txt").read_text() == "mine" and (outdir / f"{TEMPORARY_PREFIX}99-notes.txt").is_file()
    assert (outdir / f"{TEMPORARY_PREFIX}my-backup" / "a").is_dir()


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
    assert document["written_stamps"]["classes.png"] == file_stamp(outdir / "classes.png")
    assert _no_temporary_files(outdir)


# Only what is ours is ever removed or replaced (issue 26) ------------------------------------------------------------


def test_a_copied_record_never_makes_the_next_run_remove_what_it_names(tmp_path: Path, capfd) -> None:
    """Before: a classes.json the tool did not write (copied, restored from a tar with its mtimes) made the next run
    delete every file it listed, at any depth; stamps copied from the files themselves passed the check."""
    outdir = tmp_path / "out"
    (outdir / "notes").mkdir(parents=True)
    mine = {"notes/plan.txt": "mine", "render.png": "my picture", "results.csv": "1,2"}
    for name, text in mine.items():
        (outdir / name).write_text(text)
    forged = {
        "tool": {"name": "isosimtf"},
        "written": [*mine, "../outside.txt"],
        # size and time copied from the files (what the old check compared), and a real hash for a name not ours
        "written_stamps": {
            "notes/plan.txt": file_stamp(outdir / "notes/plan.txt"),
            "results.csv": file_stamp(outdir / "results.csv"),
            "render.png": [(outdir / "render.png").stat().st_size, (outdir / "render.png").stat().st_mtime_ns],
        },
    }
    (tmp_path / "outside.txt").write_text("mine too")
    (outdir / "classes.json").write_text(json.dumps(forged))
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 0, err
    assert all((outdir / name).read_text() == text for name, text in mine.items())
    assert (tmp_path / "outside.txt").read_text() == "mine too" and "warning: removed" not in err


def test_a_users_file_with_an_outputs_name_is_refused_unless_overwrite(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    outdir.mkdir()
    (outdir / "transfer_function.vp").write_text("my own transfer function")
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 2 and err.count("\n") == 1
    assert f"'{outdir / 'transfer_function.vp'}' was not written by isosimtf" in err and "--overwrite" in err
    assert (outdir / "transfer_function.vp").read_text() == "my own transfer function"
    assert not (outdir / "classes.json").exists()  # refused before any work
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir, "--overwrite"], capfd)
    assert code == 0 and (outdir / "transfer_function.vp").read_text() != "my own transfer function"
    # Now it is ours: the next run replaces it without --overwrite.
    assert _run([*PHANTOM, "--no-render", "-o", outdir], capfd)[0] == 0


def test_a_classes_json_of_someone_else_is_refused(tmp_path: Path, capfd) -> None:
    """A classes.json beside a segmentation, not isosimtf's record: not replaced without --overwrite."""
    outdir = tmp_path / "out"
    outdir.mkdir()
    (outdir / "classes.json").write_text('{"labels": ["liver", "spleen"]}')
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 2 and f"'{outdir / 'classes.json'}' was not written by isosimtf" in err
    assert json.loads((outdir / "classes.json").read_text()) == {"labels": ["liver", "spleen"]}


def test_a_run_killed_midway_leaves_a_folder_the_next_run_accepts(tmp_path: Path, capfd) -> None:
    """Before: a run killed while writing left files rewritten but unrecorded, and every later run refused the
    folder with a false "changed since isosimtf wrote it". The journal records each output as it lands."""
    outdir = tmp_path / "out"
    assert _run([*PHANTOM, "--no-render", "-o", outdir], capfd)[0] == 0
    # What a killed second run leaves: one output rewritten, journaled, classes.json still the first run's.
    rewritten = outdir / "similarity.png"
    rewritten.write_bytes(rewritten.read_bytes() + b"\0")
    journal = outdir / JOURNAL_FILE
    journal.write_text(json.dumps({"name": "similarity.png", "sha256": file_stamp(rewritten)}) + "\n{cut by the ki")
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 0, err
    assert not journal.exists()  # classes.json records every output again
    # Without the journal line the same folder is refused: the file changed since it was recorded.
    rewritten.write_bytes(rewritten.read_bytes() + b"\0")
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 2 and "has changed since isosimtf wrote it" in err


def test_a_linked_lock_file_is_refused_and_creates_nothing(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    outdir.mkdir()
    target = tmp_path / "elsewhere" / "created-by-the-lock"
    target.parent.mkdir()
    (outdir / LOCK_FILE).symlink_to(target)  # dangling
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 2 and "is a symbolic link" in err and not target.exists()


@needs_slicer
@pytest.mark.parametrize("folder", ["Data", "scene_Private"])
def test_a_linked_scene_data_folder_is_never_written_through(tmp_path: Path, capfd, folder: str) -> None:
    """Before (scene_Private, where Slicer saves the design text node): the design text was written through the
    link, outside OUTDIR, with exit 0."""
    outdir, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    (outdir / "scene").mkdir(parents=True)
    elsewhere.mkdir()
    (outdir / "scene" / folder).symlink_to(elsewhere)
    code, err = _run([*PHANTOM, "--size", "64", "-o", outdir], capfd)
    assert code == 2 and f"'{outdir / 'scene' / folder}' is a symbolic link" in err
    assert not list(elsewhere.iterdir())


@needs_slicer
def test_every_file_of_the_scene_is_an_output_checked_recorded_and_removed(tmp_path: Path, capfd) -> None:
    """Before: the scene's private file (``scene/scene_Private/<volume> IsoSimilarityTF design.txt``) was recorded
    but not an output name: a user's file of that name was replaced without a word, and a --no-render re-run left
    the previous run's copy behind."""
    outdir = tmp_path / "out"
    design_text = outdir / "scene" / "scene_Private" / "phantom IsoSimilarityTF design.txt"
    design_text.parent.mkdir(parents=True)
    design_text.write_text("my own notes")
    code, err = _run([*PHANTOM, "--size", "64", "-o", outdir], capfd)
    assert code == 2 and err.count("\n") == 1 and f"'{design_text}' was not written by isosimtf" in err
    assert design_text.read_text() == "my own notes"
    design_text.unlink()
    assert _run([*PHANTOM, "--size", "64", "-o", outdir], capfd)[0] == 0
    name = "scene/scene_Private/phantom IsoSimilarityTF design.txt"
    assert design_text.is_file() and name in _document(outdir)["written"]
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 0 and name in err, err
    assert not (outdir / "scene").exists()


@needs_slicer
def test_the_input_is_never_removed_even_when_it_is_a_previous_runs_scene_volume(tmp_path: Path, capfd) -> None:
    """Before: re-running --no-render on the previous run's scene volume, into the same folder, deleted the input."""
    outdir = tmp_path / "out"
    assert _run([*PHANTOM, "--size", "64", "-o", outdir], capfd)[0] == 0
    volume = next(p for p in (outdir / "scene" / "Data").iterdir() if p.name.endswith(".nrrd"))
    content = volume.read_bytes()
    code, err = _run([volume, "--no-render", "-q", "-o", outdir], capfd)
    assert code == 0, err
    assert volume.read_bytes() == content and "scene/scene.mrml" in err  # the rest of the scene is removed


def test_an_output_path_through_a_loop_of_links_is_one_line(tmp_path: Path, capfd) -> None:
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    code, err = _run([*PHANTOM, "--no-render", "-o", tmp_path / "loop" / "out"], capfd)
    assert code == 2 and err.count("\n") == 1 and "cannot be resolved" in err and "Traceback" not in err


def test_a_closed_stdout_loses_only_the_summary(tmp_path: Path) -> None:
    """Before: `isosimtf ... >&-` ended with a traceback and exit 1 after writing every output."""
    import os
    import subprocess
    import sys

    argv = [sys.executable, "-m", "isosimtf", *PHANTOM, "--no-render", "-o", str(tmp_path / "out")]
    done = subprocess.run(argv, stderr=subprocess.PIPE, text=True, preexec_fn=lambda: os.close(1), timeout=300)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert (tmp_path / "out" / "transfer_function.vp.json").is_file()


@pytest.mark.parametrize("name", ["similarity.npy", "classes.json", "looks/classes.vp.json"])
def test_a_link_with_this_runs_temporary_name_is_never_written_through(tmp_path: Path, capfd, name: str) -> None:
    """Before: a link planted under the temporary name this run would use (``.isosimtf-<pid>-<output>``, the pid
    guessed) was skipped by the cleanup and then written through: the output landed in the link's target, outside
    OUTDIR."""
    outdir, target = tmp_path / "out", tmp_path / "elsewhere" / "mine.txt"
    target.parent.mkdir()
    target.write_text("my own file")
    planted = outdir / name
    planted = planted.with_name(f"{TEMPORARY_PREFIX}{os.getpid()}-{planted.name}")
    planted.parent.mkdir(parents=True)
    planted.symlink_to(target)
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 0, err
    assert target.read_text() == "my own file" and (outdir / name).is_file() and not (outdir / name).is_symlink()


@pytest.mark.parametrize("closed", [2, 0], ids=["stderr", "stdin"])
def test_a_closed_standard_stream_loses_only_what_goes_there(tmp_path: Path, closed: int) -> None:
    """Before: `isosimtf ... 2>&-` (progress lines on) ended with exit 1, no message and no outputs: Python starts
    with ``sys.stderr`` None, and the first file opened would take descriptor 2, where native libraries write."""
    import subprocess
    import sys

    argv = [sys.executable, "-m", "isosimtf", *PHANTOM[:3], "--no-render", "-o", str(tmp_path / "out")]
    done = subprocess.run(argv, capture_output=closed != 2, preexec_fn=lambda: os.close(closed), timeout=300)
    assert done.returncode == 0, done.stderr
    assert json.loads((tmp_path / "out" / "classes.json").read_text())["tool"]["name"] == "isosimtf"
