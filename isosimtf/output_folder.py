"""The output folder: checked, created and locked before any work, and only our own unchanged files replaced or
removed.

A run never deletes or replaces what it did not write, nor what it wrote but someone changed since. Each run
records in ``classes.json`` the files it wrote (``written``) with their size and modification time
(``written_stamps``). The next run into the folder replaces those files or, when it does not write them again (e.g.
``render.png`` on a ``--no-render`` re-run), removes them, so that the folder never mixes two runs; a recorded file
whose size or time changed (e.g. ``scene/scene.mrml`` saved from Slicer) is never touched: a run that would replace it
is refused before the design, and one that would only remove it keeps it, with a warning, and keeps it recorded as
changed. Every file is written under a temporary name in its folder and renamed into place once complete, so an
interrupted or failed write leaves no half file; it is recorded only then. A symbolic link among the outputs is
refused, never written through. One run at a time writes into a folder (a lock file, ``.isosimtf.lock``).
"""

import json
import os
import shutil
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Union

from IsoSimilarityTFLib.errors import OutputError, RenderError, UsageError

PathLike = Union[str, "os.PathLike[str]"]

#: The scene's folder; Slicer names the scene file after the folder it saves into (``scene/scene.mrml``).
SCENE_FOLDER = "scene"
#: The file a run records its outputs in; read back to find a previous run's files.
CLASSES_JSON = "classes.json"
#: Longest output folder path accepted: Slicer's writers crash (a segmentation fault, not an error) on paths near
#: the system's 4096-character limit, and the scene's files add their own names below the folder.
MAX_OUTDIR_CHARACTERS = 1024


def check_output_path(outdir: PathLike) -> Path:
    """The output folder as an absolute path, refused before any work when it cannot be one; nothing is created.

    Raises:
        UsageError: the path is empty, too long, is a file, or lies under a file.
    """
    text = os.fspath(outdir)
    if not text.strip():
        raise UsageError("the output folder is empty: name a folder (e.g. -o out; -o . for the current folder)")
    path = Path(text).expanduser().resolve()
    if len(str(path)) > MAX_OUTDIR_CHARACTERS:
        raise UsageError(
            f"the output folder path has {len(str(path))} characters; at most {MAX_OUTDIR_CHARACTERS} are accepted "
            "(Slicer's writers fail on long paths): choose a shorter -o"
        )
    for folder in (path, *path.parents):
        if folder.exists() and not folder.is_dir():
            where = "is" if folder == path else f"lies under '{folder}', which is"
            raise UsageError(f"the output path '{text}' {where} a file, not a folder")
    return path


#: Prefix of the temporary files and staging folders of a run; any left in the folder are a killed run's, removed
#: by the next run (which holds the lock, so no other run is writing them).
TEMPORARY_PREFIX = ".isosimtf-"
#: The lock file: held (``flock``) by the run writing into the folder.
LOCK_FILE = ".isosimtf.lock"


def file_stamp(path: Path) -> list[int]:
    """``[size in bytes, modification time in ns]`` of a file: what tells that it changed since it was written."""
    status = path.stat()
    return [int(status.st_size), int(status.st_mtime_ns)]


@dataclass
class PreviousRun:
    """The files a previous ``isosimtf`` run recorded in the folder's classes.json that still exist.

    Attributes:
        unchanged: files as that run wrote them (absolute paths): this run may replace or remove them.
        changed: relative name -> recorded stamp of the files changed since (or of unknown state): never touched.
    """

    unchanged: list[Path] = field(default_factory=list)
    changed: dict[str, list[int]] = field(default_factory=dict)


def previous_outputs(path: Path) -> PreviousRun:
    """What a previous ``isosimtf`` run wrote into ``path``, by its classes.json (see :class:`PreviousRun`).

    A classes.json that is not ours, or unreadable, gives nothing: then nothing is removed. Runs before
    ``written_stamps`` existed have their files taken as unchanged.
    """
    try:
        document = json.loads((path / CLASSES_JSON).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return PreviousRun()
    if not isinstance(document, dict) or (document.get("tool") or {}).get("name") != "isosimtf":
        return PreviousRun()
    listed: Any = document.get("written")
    if not isinstance(listed, list):  # runs before "written" existed list their main files in "outputs" only
        outputs = document.get("outputs")
        listed = list(outputs.values()) if isinstance(outputs, dict) else []
    stamps = document.get("written_stamps")
    previous = PreviousRun()
    for name in listed:
        if str(name) == CLASSES_JSON:
            continue  # the record itself, rewritten by every run
        candidate = path / str(name)
        if candidate.is_symlink() or not candidate.is_file() or not candidate.resolve().is_relative_to(path):
            continue  # gone, or not ours to touch (a link, or outside the folder)
        recorded = stamps.get(str(name)) if isinstance(stamps, dict) else None
        if isinstance(stamps, dict) and recorded != file_stamp(candidate):
            previous.changed[str(name)] = recorded if isinstance(recorded, list) else []
        else:
            previous.unchanged.append(candidate.resolve())
    return previous


def check_outputs(path: Path, names: Iterable[str], previous: PreviousRun, *, scene: bool) -> None:
    """Refuse, before any work, a run that would write through a link or replace a file changed since written.

    Args:
        names: the outputs this run writes (relative names); scene: it also writes ``scene/`` (whose data files are
            named only once saved: every changed file there counts).

    Raises:
        UsageError: an output or ``scene/`` is a symbolic link, or a changed file would be replaced.
    """
    targets = [*names, SCENE_FOLDER] if scene else list(names)
    for name in targets:
        if (path / name).is_symlink():
            raise UsageError(
                f"'{path / name}' is a symbolic link (to '{os.readlink(path / name)}'): isosimtf never writes "
                "through links; remove it or choose another -o"
            )
    replaced = [n for n in previous.changed if n in names or (scene and n.startswith(SCENE_FOLDER + "/"))]
    if replaced:
        raise UsageError(
            f"'{path / replaced[0]}' has changed since isosimtf wrote it (e.g. saved from Slicer), and this run would "
            f"replace it{f' and {len(replaced) - 1} other changed file(s)' if len(replaced) > 1 else ''}: move it "
            "away, or choose another -o"
        )


class OutputFolder:
    """The output folder, created if missing and locked for this run (a context manager).

    On entering: the folder (and missing parents) is created, the lock taken (refused if another run holds it), and
    what a killed run left (temporary files and staging folders) removed. On leaving: the lock is released and, if
    nothing was written, the folders this run created are removed again, so a run that fails on its input leaves no
    folder behind.

    Raises:
        OutputError: the folder cannot be created or written into. UsageError: another run holds the lock.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._created: list[Path] = []
        self._lock: Optional[Any] = None

    def __enter__(self) -> "OutputFolder":
        missing = [p for p in (self.path, *self.path.parents) if not p.exists()]
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            self._created = missing
            self._lock = open(self.path / LOCK_FILE, "a+b")
        except OSError as error:
            self._remove_created()
            raise OutputError(f"cannot write into the output folder '{self.path}': {error.strerror or error}") from None
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: no lock
            fcntl = None
        if fcntl is not None:
            try:
                fcntl.flock(self._lock.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                self._lock.close()
                self._lock = None
                raise UsageError(
                    f"another isosimtf run is writing into '{self.path}': wait for it to end, or choose another -o"
                ) from None
        for leftover in self.path.glob(TEMPORARY_PREFIX + "*"):
            if leftover.is_dir() and not leftover.is_symlink():
                shutil.rmtree(leftover, ignore_errors=True)
            else:
                leftover.unlink(missing_ok=True)
        return self

    def __exit__(self, *exc_info: object) -> None:
        (self.path / LOCK_FILE).unlink(missing_ok=True)  # before the lock is released: no other run holds it yet
        if self._lock is not None:
            self._lock.close()
        self._remove_created()

    def _remove_created(self) -> None:
        for folder in self._created:  # innermost first
            try:
                folder.rmdir()
            except OSError:  # not empty: something was written
                return


def write_atomically(path: Path, write: Callable[[Path], object]) -> None:
    """Write a file under a temporary name in its folder, then rename it into place: the file is either the old
    one or the complete new one, never a part (a full disk, a failure, Ctrl+C).

    Args:
        write: writes the file at the path it is given (a temporary name ending like ``path``, so that writers
            choosing the format by suffix still do).

    Raises:
        OutputError: the write or the rename failed (the temporary file is removed).
    """
    temporary = path.with_name(f"{TEMPORARY_PREFIX}{os.getpid()}-{path.name}")
    try:
        write(temporary)
        os.replace(temporary, path)
    except OSError as error:
        raise OutputError(f"cannot write '{path}': {error.strerror or error}") from None
    finally:
        if temporary.exists():
            temporary.unlink()


def remove_stale(path: Path, previous: Iterable[Path], written: Iterable[Path]) -> list[str]:
    """Remove the previous run's unchanged files that this run did not write; return their names (relative, sorted).

    Folders left empty by the removal (e.g. ``scene/Data``) go too; folders still holding anything stay.
    """
    kept = {p.resolve() for p in written}
    removed = []
    for file in sorted(set(previous) - kept):
        try:
            file.unlink()
        except OSError:
            continue
        removed.append(file.relative_to(path).as_posix())
        folder = file.parent
        while folder != path and folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
            folder = folder.parent
    return removed


def save_scene(scene: Any, outdir: Path) -> list[Path]:
    """Save a Slicer scene as ``outdir/scene/scene.mrml`` with its data files; return the files written.

    Slicer's bundle writer saves into a staging folder beside (inside ``outdir``, so moves stay on one file system);
    its files then replace their namesakes in ``scene/``, and nothing else there is touched.

    Raises:
        RenderError: Slicer could not save the scene. OutputError: a file cannot be moved into place.
    """
    target = outdir / SCENE_FOLDER
    written = []
    with tempfile.TemporaryDirectory(dir=outdir, prefix=TEMPORARY_PREFIX) as staging_root:
        staging = Path(staging_root) / SCENE_FOLDER
        staging.mkdir()
        if not scene.SaveSceneToSlicerDataBundleDirectory(str(staging)):
            raise RenderError(f"Slicer could not save the scene into '{target}'")
        try:
            for file in sorted(p for p in staging.rglob("*") if p.is_file()):
                destination = target / file.relative_to(staging)
                destination.parent.mkdir(parents=True, exist_ok=True)
                os.replace(file, destination)
                written.append(destination)
        except OSError as error:
            raise OutputError(f"cannot write the scene into '{target}': {error.strerror or error}") from None
    return written
