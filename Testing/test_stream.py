"""The volume's one path through the engine (issue 25): a survey, then one stream, whatever holds the volume.

What is counted: the chunk reads of a wrapped dask array, the way a chunked store (Zarr, TIFF) reads it, on the path
the command line and the Slicer module take (the robust range included); and what the child process hands back.
"""

import ast
from collections import defaultdict
from pathlib import Path

import dask.array as da
import numpy as np
import pytest

from IsoSimilarityTFLib import design_transfer_function
from IsoSimilarityTFLib.source import VolumeSource
from IsoSimilarityTFLib.survey import survey_volume
from IsoSimilarityTFLib.value_range import robust_value_range
from IsoSimilarityTFLib.worker import DesignProcess
from isosimtf.chunked_readers import PreviewTap

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"IsoSimilarityTFLib": ROOT / "IsoSimilarityTF" / "IsoSimilarityTFLib", "isosimtf": ROOT / "isosimtf"}


class ChunkStore:
    """A volume read chunk by chunk, as a Zarr or TIFF store reads it: every request reads the whole chunks it
    touches, and those reads are counted."""

    def __init__(self, values: np.ndarray, chunks: tuple[int, int, int]) -> None:
        self.values, self.chunks = values, chunks
        self.shape, self.dtype, self.ndim = values.shape, values.dtype, values.ndim
        self.voxels_read = 0

    def __getitem__(self, key):
        touched = [
            range(k.start // c, (k.stop - 1) // c + 1) if k.stop > k.start else range(0)
            for k, c in zip(key, self.chunks)
        ]
        for index in np.ndindex(*(len(t) for t in touched)):
            corner = [t[i] * c for t, i, c in zip(touched, index, self.chunks)]
            self.voxels_read += int(np.prod([min(c, n - s) for c, n, s in zip(self.chunks, self.shape, corner)]))
        return self.values[key]

    def whole_reads(self) -> float:
        return self.voxels_read / self.values.size


def _blobs(dtype) -> np.ndarray:
    rng = np.random.default_rng(0)
    r = np.sqrt(((np.indices((48, 40, 44)) - np.array([24, 20, 22])[:, None, None, None]) ** 2).sum(axis=0))
    return (np.select([r < 8, r < 14, r < 19], [1200, 300, 40], -1000) + rng.normal(0, 25, r.shape)).astype(dtype)


@pytest.mark.parametrize(
    ("dtype", "padded", "most"), [(np.int16, False, 2), (np.int16, True, 2), (np.float32, True, 3)]
)
def test_a_chunked_volume_is_read_at_most_twice_or_three_times(dtype, padded, most):
    """The survey and the stream: twice, the render preview included; a float volume with padding once more for the
    exact range (the previous path read an int16 volume 4 times and a padded float32 one 9 times, and the command
    line read its preview apart)."""
    values = _blobs(dtype)
    if padded:
        values[:, :, :5] = -3024
    store = ChunkStore(values, (8, 40, 44))
    preview = PreviewTap(values.shape, 3)  # the command line's render preview of a volume read lazily
    lazy = da.from_array(store, chunks=store.chunks, asarray=True)
    design = design_transfer_function(lazy, n_bins=64, value_tap=preview)
    assert store.whole_reads() == most and preview.complete
    expected = design_transfer_function(values, n_bins=64)
    assert {**design.to_dict(), "timings_s": None} == {**expected.to_dict(), "timings_s": None}
    assert (design.range_warning() is None) == (not padded) and design.robust_range == expected.robust_range


@pytest.mark.parametrize("dtype", [np.int16, np.uint16, np.int8, ">i2", np.float32, np.int32])
def test_the_survey_of_a_dask_volume_is_the_arrays(dtype):
    values = _blobs(np.int16).astype(dtype)
    kind = np.dtype(dtype)
    values[3, 4, 5] = np.iinfo(kind).min if kind.kind in "iu" else -32000
    in_memory = survey_volume(VolumeSource(values))
    lazy = survey_volume(VolumeSource(da.from_array(values, chunks=(5, 40, 44))))
    assert (in_memory.low, in_memory.high) == (lazy.low, lazy.high) == (values.min().item(), values.max().item())
    np.testing.assert_array_equal(in_memory.sample, lazy.sample)
    np.testing.assert_array_equal(lazy.sample, values[:: lazy.step, :: lazy.step, :: lazy.step].reshape(-1))
    if lazy.histogram is not None:  # integers of at most 16 bits read lazily: exact counts per value
        assert lazy.histogram.sum() == values.size
        assert lazy.histogram[values[3, 4, 5] - lazy.offset] == np.count_nonzero(values == values[3, 4, 5])


def test_non_finite_voxels_are_counted_where_min_or_max_shows_them():
    values = _blobs(np.float32)
    values[1, 2, 3], values[4, 5, 6] = np.nan, np.inf
    for volume in (values, da.from_array(values, chunks=(7, 40, 44))):
        assert survey_volume(VolumeSource(volume)).nonfinite == 2
    with pytest.raises(ValueError, match="2 NaN or infinite voxels"):
        design_transfer_function(values)


def test_the_child_process_hands_back_what_the_range_left_out():
    values = _blobs(np.int16)
    values[:, :, :5] = -3024
    with DesignProcess(values, (1.0, 1.0, 1.0), {"n_bins": 32}) as job:
        design = job.wait(timeout=120)
    assert design.robust_range == robust_value_range(values) and "-3024" in design.range_warning()


def _imports() -> tuple[dict, list]:
    """The package-internal import graph of the Lib and the command line (type-only imports left out), and the
    imports made inside functions."""
    graph, inside = defaultdict(set), []
    for package, folder in PACKAGES.items():
        for path in sorted(folder.glob("*.py")):
            module = package if path.stem == "__init__" else f"{package}.{path.stem}"
            tree = ast.parse(path.read_text())
            in_functions = {
                id(node)
                for function in ast.walk(tree)
                if isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef))
                for node in ast.walk(function)
            }
            # Imports for type annotations only (``if TYPE_CHECKING:``) never run: they make no circle.
            typing_only = {
                id(node)
                for block in ast.walk(tree)
                if isinstance(block, ast.If) and isinstance(block.test, ast.Name) and block.test.id == "TYPE_CHECKING"
                for node in ast.walk(block)
            }
            for node in ast.walk(tree):
                if id(node) in typing_only:
                    continue
                if isinstance(node, ast.ImportFrom):
                    base = package if node.level else (node.module or "")
                    names = [f"{base}.{node.module}" if node.level and node.module else base]
                    if node.level and not node.module:
                        names = [f"{package}.{alias.name}" for alias in node.names]
                elif isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                else:
                    continue
                for name in names:
                    target = next((m for m in (name, name.rsplit(".", 1)[0]) if m.split(".")[0] in PACKAGES), None)
                    if target is None or target == module:
                        continue
                    graph[module].add(target)
                    if id(node) in in_functions:
                        inside.append(f"{module} -> {target} (line {node.lineno})")
    return graph, inside


def test_no_import_circles_in_the_lib_or_the_command_line():
    graph, _ = _imports()
    modules = {m for m in graph} | {t for targets in graph.values() for t in targets}

    def reaches(start, goal, seen):
        return any(t == goal or (t not in seen and not seen.add(t) and reaches(t, goal, seen)) for t in graph[start])

    circles = sorted(m for m in modules if reaches(m, m, set()))
    assert not circles, f"modules on an import circle: {circles}"


def test_the_package_imports_nothing_of_its_own_inside_functions():
    """A module needed inside a function is imported at the top: a function-level import hides a circle."""
    _, inside = _imports()
    assert not inside, "\n".join(inside)
