"""The repository stays small enough for the Extensions Index, which clones it with its whole history."""

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: The index refuses a clone over 100 MB; 90 MB leaves room for a few releases' pictures.
MAX_CLONE_MB = 90.0


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=True).stdout


def test_a_fresh_clone_stays_under_the_index_limit():
    try:
        counts = dict(line.split(": ") for line in _git("count-objects", "-v").splitlines())
        tracked = _git("ls-files", "-z").split("\0")
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    history_kb = int(counts["size-pack"]) + int(counts["size"])  # what a clone's .git holds, packed
    tree_bytes = sum((ROOT / name).stat().st_size for name in tracked if name and (ROOT / name).is_file())
    clone_mb = history_kb / 1024 + tree_bytes / 2**20
    assert clone_mb < MAX_CLONE_MB, (
        f"a fresh clone would be about {clone_mb:.1f} MB (history {history_kb / 1024:.1f} MB)"
    )


def test_regenerated_pictures_are_not_committed():
    try:
        tracked = _git("ls-files", "benchmarks/results").split()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    assert not [name for name in tracked if name.endswith(".png")]
