"""The repository stays small enough for the Extensions Index, which clones it with its whole history."""

import subprocess
from pathlib import Path
from typing import Optional

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: The index refuses a clone over 100 MB; 90 MB leaves room for a few releases' pictures.
MAX_CLONE_MB = 90.0


def _git(*args: str, stdin: Optional[str] = None) -> str:
    return subprocess.run(
        ["git", "-C", str(ROOT), *args], input=stdin, capture_output=True, text=True, check=True
    ).stdout


def _history_bytes() -> int:
    """Packed bytes of every object a clone receives (HEAD, its branches and tags), each counted once.

    ``git count-objects`` would sum the packs on disk, which a checkout made by fetching into an existing repository
    can hold twice; a clone gets each object once.
    """
    objects = _git("rev-list", "--objects", "HEAD", "--branches", "--tags")
    # %(rest) makes cat-file read only the name before the path rev-list adds
    sizes = _git("cat-file", "--batch-check=%(objectsize:disk) %(rest)", stdin=objects)
    return sum(int(line.split()[0]) for line in sizes.splitlines())


def test_a_fresh_clone_stays_under_the_index_limit():
    try:
        history_bytes = _history_bytes()
        tracked = _git("ls-files", "-z").split("\0")
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    tree_bytes = sum((ROOT / name).stat().st_size for name in tracked if name and (ROOT / name).is_file())
    clone_mb = (history_bytes + tree_bytes) / 2**20
    assert clone_mb < MAX_CLONE_MB, (
        f"a fresh clone would be about {clone_mb:.1f} MB (history {history_bytes / 2**20:.1f} MB)"
    )


def test_regenerated_pictures_are_not_committed():
    try:
        tracked = _git("ls-files", "benchmarks/results").split()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    assert not [name for name in tracked if name.endswith(".png")]
