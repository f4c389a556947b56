"""The output folder: checked, created and locked before any work, and only our own unchanged files replaced or
removed.

A run never deletes or replaces what it did not write, nor what it wrote but someone changed since. A file is ours
only when its name is one this tool writes (:func:`is_output_name`) and its content is what a run recorded when it
wrote it: each run records in ``classes.json`` the files it wrote (``written``) with the SHA-256 of their content
(``written_stamps``), and, while it runs, each file as it lands in a journal (``.isosimtf.journal``), so a run killed
midway leaves a folder the next one accepts. The next run into the folder replaces those files or, when it does not
write them again (e.g. ``render.png`` on a ``--no-render`` re-run), removes them, so that the folder never mixes two
runs. A recorded file whose content changed (e.g. ``scene/scene.mrml`` saved from Slicer) is never touched: a run that
would replace it is refused before the design, and one that would only remove it keeps it, with a warning, and keeps
it recorded as changed. A file with an output's name that no run recorded (the user's own ``render.png``) is refused
likewise, unless ``--overwrite``. The input is never removed. Every file is written under a temporary name of our own
pattern (``.isosimtf-<pid>-<name>``) in its folder and renamed into place once complete, so an interrupted or failed
write leaves no half file; only names of that pattern are cleaned. A symbolic link anywhere between the folder and an
output (``scene/Data`` and ``scene/scene_Private`` included), or as the lock file or the journal, is refused, never
written through. One run at a time writes into a folder (a lock file, ``.isosimtf.lock``). The records read back
(classes.json, the journal) are read only from regular files of bounded size: a FIFO, a device or a huge file there
records nothing.
"""

import hashlib
import json
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Union

from IsoSimilarityTFLib.errors import OutputError, RenderError, UsageError
from IsoSimilarityTFLib.options import LOOK_NAMES

PathLike = Union[str, "os.PathLike[str]"]

#: The scene's folder; Slicer names the scene file after the folder it saves into (``scene/scene.mrml``).
SCENE_FOLDER = "scene"
#: The file a run records its outputs in; read back to find a previous run's files.
CLASSES_JSON = "classes.json"
#: The folders of ``scene/`` Slicer's bundle writer saves the scene's files into: ``Data`` (the volume, the
#: transfer function) and ``scene_Private`` (the design text node, named after ``scene.mrml``). Every file there is an
#: output; a file the writer would put anywhere else is refused.
SCENE_DATA_FOLDERS = ("Data", "scene_Private")
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
    try:
        path = Path(text).expanduser().resolve()
    except (RuntimeError, OSError) as error:  # a loop of symbolic links (RuntimeError before Python 3.13)
        raise UsageError(f"the output path '{text}' cannot be resolved: {error}") from None
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


#: Prefix of the temporary files and staging folders of a run; any of our pattern left in the folder are a killed
#: run's, removed by the next run (which holds the lock, so no other run is writing them).
TEMPORARY_PREFIX = ".isosimtf-"
#: The lock file: held (``flock``) by the run writing into the folder.
LOCK_FILE = ".isosimtf.lock"
#: The journal: each output of the running run as it lands (a JSON line: name, SHA-256); removed once classes.json
#: records them all.
JOURNAL_FILE = ".isosimtf.journal"
#: Longest record read back (classes.json, the journal): a run's record takes kilobytes (its design text at most a
#: few MB); a longer one, like one that is not a regular file, records nothing.
MAX_RECORD_BYTES = 64 << 20
#: Output file names, by role.
OUTPUT_FILES = {
    "similarity_npy": "similarity.npy",
    "similarity_png": "similarity.png",
    "classes_json": CLASSES_JSON,
    "vp_json": "transfer_function.vp.json",
    "vp": "transfer_function.vp",
    "looks_png": "looks.png",
    "render_png": "render.png",
    "classes_png": "classes.png",
    "scene": f"{SCENE_FOLDER}/scene.mrml",
    "segmentation": "classes.seg.nrrd",
}
#: The files a run writes at the top of the folder.
TOP_OUTPUTS = frozenset(name for name in OUTPUT_FILES.values() if "/" not in name)
#: The folder of the gallery's transfer functions, one ``<name>.vp.json`` per look.
LOOKS_FOLDER = "looks"
# Our temporary names: a file `.isosimtf-<pid>-<output file name>`, a staging folder `.isosimtf-staging-<pid>-<any>`.
_TEMPORARY_FILE = re.compile(re.escape(TEMPORARY_PREFIX) + r"\d+-(.+)")
_STAGING_FOLDER = re.compile(re.escape(TEMPORARY_PREFIX) + r"staging-\d+-\w+")


def look_file(name: str) -> str:
    """The output file (relative name) of the look ``name``."""
    return f"{LOOKS_FOLDER}/{name}.vp.json"


def is_output_name(name: str) -> bool:
    """Whether ``name`` (relative to the output folder, ``/``-separated) is a file this tool writes: one of
    :data:`TOP_OUTPUTS`, ``looks/<look>.vp.json``, ``scene/scene.mrml`` or a file of ``scene/Data/`` or
    ``scene/scene_Private/`` (:data:`SCENE_DATA_FOLDERS`). A record naming anything else (``../x``, a user's notes) is
    not trusted."""
    parts = name.split("/")
    if any(part in ("", ".", "..") for part in parts):
        return False
    if len(parts) == 1:
        return name in TOP_OUTPUTS
    if parts[0] == LOOKS_FOLDER:
        return name in {look_file(look) for look in LOOK_NAMES}
    return parts[0] == SCENE_FOLDER and (
        parts[1:] == ["scene.mrml"] or (len(parts) == 3 and parts[1] in SCENE_DATA_FOLDERS)
    )


def file_stamp(path: Path) -> str:
    """The SHA-256 of a file's content, in hex: what tells that it is still the file a run wrote (a copied size and
    time would not)."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@dataclass
class PreviousRun:
    """The files a previous ``isosimtf`` run recorded in the folder's classes.json that still exist.

    Attributes:
        unchanged: files as that run wrote them (absolute paths): this run may replace or remove them.
        changed: relative name -> recorded stamp of the files changed since (or of unknown state, e.g. recorded by a
            version that stamped size and time): never touched.
        record_ours: whether the folder's classes.json is an isosimtf record (which each run rewrites).
    """

    unchanged: list[Path] = field(default_factory=list)
    changed: dict[str, Any] = field(default_factory=dict)
    record_ours: bool = False

    def ours(self, path: Path, name: str) -> bool:
        """Whether the file ``name`` in the folder ``path`` is a previous run's, unchanged."""
        return (path / name).resolve() in self.unchanged


def previous_outputs(path: Path) -> PreviousRun:
    """What previous ``isosimtf`` runs wrote into ``path``: the files its classes.json records, and those the
    journal of a run killed before recording them lists (see :class:`PreviousRun`).

    A classes.json that is not ours, or unreadable, records nothing: then nothing is removed. Only names this tool
    writes are considered (:func:`is_output_name`), and a file is unchanged only when its content has the recorded
    SHA-256.
    """
    recorded: dict[str, Any] = {}
    text = _read_record(path / CLASSES_JSON)
    try:
        document = json.loads(text) if text is not None else None
    except (ValueError, RecursionError):  # not JSON (UnicodeDecodeError is a ValueError), or nested without end
        document = None
    record_ours = isinstance(document, dict) and (document.get("tool") or {}).get("name") == "isosimtf"
    if record_ours:
        stamps = document.get("written_stamps")
        listed = document.get("written")
        for name in listed if isinstance(listed, list) else []:
            recorded[str(name)] = stamps.get(str(name)) if isinstance(stamps, dict) else None
    recorded.update(_journal(path))
    previous = PreviousRun(record_ours=record_ours)
    for name, stamp in recorded.items():
        if name == CLASSES_JSON or not is_output_name(name):
            continue  # the record itself, rewritten by every run; or a name we never write: not ours to touch
        candidate = path / name
        if _linked(path, name) or not candidate.is_file():
            continue  # gone, or not ours to touch (through a link)
        if isinstance(stamp, str) and stamp == file_stamp(candidate):
            previous.unchanged.append(candidate.resolve())
        else:
            previous.changed[name] = stamp if stamp is not None else []
    return previous


def _journal(path: Path) -> dict[str, str]:
    """``name -> SHA-256`` of the outputs a killed run's journal lists (its last entry per name)."""
    text = _read_record(path / JOURNAL_FILE)
    entries = {}
    for line in text.splitlines() if text is not None else []:
        try:
            entry = json.loads(line)
            entries[str(entry["name"])] = str(entry["sha256"])
        except (ValueError, KeyError, TypeError, RecursionError):
            continue  # a line cut by the kill
    return entries


def _read_record(file: Path) -> Optional[bytes]:
    """The content of a record file (classes.json, the journal); None when it is missing, a symbolic link, not a
    regular file (a FIFO would wait for a writer forever, a device never end) or longer than
    :data:`MAX_RECORD_BYTES`."""
    try:
        descriptor = os.open(file, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return None
    with os.fdopen(descriptor, "rb") as handle:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            return None
        text = handle.read(MAX_RECORD_BYTES + 1)
    return text if len(text) <= MAX_RECORD_BYTES else None


def journal_output(path: Path, file: Path) -> None:
    """Append ``file`` (an output just complete) with its SHA-256 to the folder's journal."""
    entry = json.dumps({"name": file.relative_to(path).as_posix(), "sha256": file_stamp(file)})
    flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | getattr(os, "O_NOFOLLOW", 0)
    try:
        descriptor = os.open(path / JOURNAL_FILE, flags, 0o644)
        with os.fdopen(descriptor, "a", encoding="utf-8") as journal:
            journal.write(entry + "\n")
    except OSError as error:
        raise OutputError(f"cannot write into '{path}': {error.strerror or error}") from None


def end_journal(path: Path) -> None:
    """Remove the journal: classes.json now records every output."""
    (path / JOURNAL_FILE).unlink(missing_ok=True)


def _linked(path: Path, name: str) -> Optional[Path]:
    """The first symbolic link on the way from the folder ``path`` to ``name`` (itself included), or None."""
    current = path
    for part in name.split("/"):
        current = current / part
        if current.is_symlink():
            return current
    return None


def check_outputs(
    path: Path,
    names: Iterable[str],
    previous: PreviousRun,
    *,
    scene: bool,
    overwrite: bool = False,
    source: Optional[Path] = None,
) -> None:
    """Refuse, before any work, a run that would write through a link or replace a file that is not ours.

    Args:
        names: the outputs this run writes (relative names); scene: it also writes ``scene/`` (whose data files are
            named only once saved: every file there counts).
        overwrite: replace files with an output's name that no run recorded (``--overwrite``); a recorded file
            changed since is still refused.
        source: the input file, never replaced.

    Raises:
        UsageError: a link on the way to an output (or ``scene/`` and its data folders), a changed file or a file no
            run recorded (without ``overwrite``) that would be replaced, or the input among the outputs.
    """
    names = list(names)
    scene_folders = [f"{SCENE_FOLDER}/{folder}" for folder in SCENE_DATA_FOLDERS]
    scene_names = [f"{SCENE_FOLDER}/scene.mrml", *scene_folders] if scene else []
    for name in [*names, *scene_names]:
        link = _linked(path, name)
        if link is not None:
            raise UsageError(
                f"'{link}' is a symbolic link (to '{os.readlink(link)}'): isosimtf never writes through links; "
                "remove it or choose another -o"
            )
    replaced = [n for n in previous.changed if n in names or (scene and n.startswith(SCENE_FOLDER + "/"))]
    if replaced:
        raise UsageError(
            f"'{path / replaced[0]}' has changed since isosimtf wrote it (e.g. saved from Slicer), and this run would "
            f"replace it{f' and {len(replaced) - 1} other changed file(s)' if len(replaced) > 1 else ''}: move it "
            "away, or choose another -o"
        )
    existing = [n for n in names if _occupied(path / n)]
    if scene:
        existing += [f"{SCENE_FOLDER}/scene.mrml"] if _occupied(path / SCENE_FOLDER / "scene.mrml") else []
        for folder in scene_folders:
            data = path / folder
            existing += [f"{folder}/{f.name}" for f in sorted(data.iterdir())] if data.is_dir() else []
    if source is not None:
        inside = [n for n in existing if (path / n).resolve() == source.resolve()]
        if inside:
            raise UsageError(
                f"the input '{source}' is among this run's outputs ('{inside[0]}'): isosimtf never replaces its "
                "input; copy it elsewhere, or choose another -o"
            )
    # Neither a previous run's unchanged file nor our record; a changed file among them was refused above.
    foreign = [n for n in existing if not (previous.record_ours if n == CLASSES_JSON else previous.ours(path, n))]
    if foreign and not overwrite:
        raise UsageError(
            f"'{path / foreign[0]}' was not written by isosimtf"
            f"{f' (nor {len(foreign) - 1} other file(s))' if len(foreign) > 1 else ''}, and this run would replace "
            "it: move it away, choose another -o, or pass --overwrite"
        )


def _occupied(file: Path) -> bool:
    """Whether something a run would replace is at ``file``: a file, or a FIFO, socket or device (not a folder)."""
    return file.exists() and not file.is_dir()


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
        lock = self.path / LOCK_FILE
        for ours in (lock, self.path / JOURNAL_FILE):
            if ours.is_symlink():
                raise UsageError(
                    f"'{ours}' is a symbolic link (to '{os.readlink(ours)}'): isosimtf never writes through links; "
                    "remove it or choose another -o"
                )
        journal = self.path / JOURNAL_FILE
        if journal.exists() and not journal.is_file():  # a FIFO would make the first output wait forever
            raise UsageError(f"'{journal}' is not a regular file: isosimtf keeps its journal there; remove it")
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            self._created = missing
            flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0)
            self._lock = os.fdopen(os.open(lock, flags, 0o644), "a+b")
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
        for folder in (self.path, self.path / LOOKS_FOLDER):
            for leftover in folder.glob(TEMPORARY_PREFIX + "*") if folder.is_dir() and not folder.is_symlink() else ():
                if leftover.is_symlink():
                    continue
                if leftover.is_dir() and _STAGING_FOLDER.fullmatch(leftover.name):
                    shutil.rmtree(leftover, ignore_errors=True)
                elif leftover.is_file() and _temporary_of_ours(leftover.name, folder == self.path):
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


def _temporary_of_ours(name: str, top: bool) -> bool:
    """Whether ``name`` is a temporary file of our pattern for an output of that folder (the top or ``looks/``)."""
    match = _TEMPORARY_FILE.fullmatch(name)
    if match is None:
        return False
    output = match.group(1)
    return output in TOP_OUTPUTS if top else is_output_name(f"{LOOKS_FOLDER}/{output}")


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
        if temporary.is_symlink() or temporary.is_file():  # a name of our pattern and pid (a link planted there would
            temporary.unlink()  # be written through): we hold the folder's lock, so it is no other run's
        write(temporary)
        os.replace(temporary, path)
    except OSError as error:
        raise OutputError(f"cannot write '{path}': {error.strerror or error}") from None
    finally:
        if temporary.exists():
            temporary.unlink()


def remove_stale(
    path: Path, previous: Iterable[Path], written: Iterable[Path], source: Optional[Path] = None
) -> list[str]:
    """Remove the previous run's unchanged files that this run did not write; return their names (relative, sorted).

    The input ``source`` is never removed (a previous run's scene volume read again). Folders left empty by the
    removal (e.g. ``scene/Data``) go too; folders still holding anything stay.
    """
    kept = {p.resolve() for p in written}
    if source is not None:
        kept.add(Path(source).resolve())
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
    its files then replace their namesakes in ``scene/``, and nothing else there is touched. A file the writer put
    where no output goes (outside :data:`SCENE_DATA_FOLDERS`), or whose way holds a link, is refused, never moved.

    Raises:
        RenderError: Slicer could not save the scene. OutputError: a file cannot be moved into place, or is not an
            output.
    """
    target = outdir / SCENE_FOLDER
    written = []
    staging_prefix = f"{TEMPORARY_PREFIX}staging-{os.getpid()}-"
    with tempfile.TemporaryDirectory(dir=outdir, prefix=staging_prefix) as staging_root:
        staging = Path(staging_root) / SCENE_FOLDER
        staging.mkdir()
        if not scene.SaveSceneToSlicerDataBundleDirectory(str(staging)):
            raise RenderError(f"Slicer could not save the scene into '{target}'")
        try:
            files = sorted(p for p in staging.rglob("*") if p.is_file())
            for file in files:
                name = f"{SCENE_FOLDER}/{file.relative_to(staging).as_posix()}"
                if not is_output_name(name) or _linked(outdir, name) is not None:
                    raise OutputError(f"Slicer saved the scene file '{name}', which is not an output isosimtf writes")
            for file in files:
                destination = target / file.relative_to(staging)
                destination.parent.mkdir(parents=True, exist_ok=True)
                os.replace(file, destination)
                written.append(destination)
        except OSError as error:
            raise OutputError(f"cannot write the scene into '{target}': {error.strerror or error}") from None
    return written
