"""The output folder: checked before any work, created only when there is something to write, and only our own files
replaced or removed.

A run never deletes what it did not write. It replaces the files it writes, and it removes the files a previous
``isosimtf`` run listed as written in its ``classes.json`` (``written``) when this run does not write them again (e.g.
``render.png`` on a ``--no-render`` re-run), so that the folder never mixes two runs. The Slicer scene is saved into a
staging folder and its files moved into ``scene/`` one by one, so other files there survive.
"""

import json
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Union

from IsoSimilarityTFLib.errors import OutputError, RenderError, UsageError

PathLike = Union[str, "os.PathLike[str]"]

#: The scene's folder; Slicer names the scene file after the folder it saves into (``scene/scene.mrml``).
SCENE_FOLDER = "scene"
#: The file a run records its outputs in; read back to find a previous run's files.
CLASSES_JSON = "classes.json"


def check_output_path(outdir: PathLike) -> Path:
    """The output folder as an absolute path, refused before any work when it cannot be one; nothing is created.

    Raises:
        UsageError: the path is empty, is a file, or lies under a file.
    """
    text = os.fspath(outdir)
    if not text.strip():
        raise UsageError("the output folder is empty: name a folder (e.g. -o out; -o . for the current folder)")
    path = Path(text).expanduser().resolve()
    for folder in (path, *path.parents):
        if folder.exists() and not folder.is_dir():
            where = "is" if folder == path else f"lies under '{folder}', which is"
            raise UsageError(f"the output path '{text}' {where} a file, not a folder")
    return path


def create_output_folder(path: Path) -> None:
    """Create the output folder and its parents when missing.

    Raises:
        OutputError: it cannot be created.
    """
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(f"cannot create the output folder '{path}': {error.strerror or error}") from None


def previous_outputs(path: Path) -> list[Path]:
    """The files a previous ``isosimtf`` run wrote into ``path`` (its classes.json says which) that still exist.

    A classes.json that is not ours, or unreadable, gives nothing: then nothing is removed.
    """
    try:
        document = json.loads((path / CLASSES_JSON).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []
    if not isinstance(document, dict) or (document.get("tool") or {}).get("name") != "isosimtf":
        return []
    listed: Any = document.get("written")
    if not isinstance(listed, list):  # runs before "written" existed list their main files in "outputs" only
        outputs = document.get("outputs")
        listed = list(outputs.values()) if isinstance(outputs, dict) else []
    files = []
    for name in listed:
        candidate = (path / str(name)).resolve()
        if candidate.is_file() and candidate.is_relative_to(path):  # never outside the folder
            files.append(candidate)
    return files


def remove_stale(path: Path, previous: Iterable[Path], written: Iterable[Path]) -> list[str]:
    """Remove the previous run's files that this run did not write; return their names (relative, sorted).

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
    with tempfile.TemporaryDirectory(dir=outdir, prefix=".isosimtf-") as staging_root:
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
