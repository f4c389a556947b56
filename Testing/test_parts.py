"""The similarity pass of a dask volume as a map-reduce over parts along axis 0: exactly the in-memory engine's."""

import itertools
import subprocess
import sys

import dask
import dask.array as da
import numpy as np
import pytest

from IsoSimilarityTFLib import design_transfer_function, isovalue_similarity, quantize, source, stream
from IsoSimilarityTFLib.cells import OctreeBuilder, octree_levels, unit_cell_slabs

RULES = list(itertools.product(("inclusive", "strict"), ("thesis", "ma-entezari")))


def random_chunks(rng: np.random.Generator, n: int) -> tuple[int, ...]:
    """A random chunking of ``n`` planes, with chunks of one plane likely."""
    cuts = np.sort(rng.choice(np.arange(1, n), size=rng.integers(0, min(n - 1, 12) + 1), replace=False))
    return tuple(int(size) for size in np.diff(np.concatenate(([0], cuts, [n]))))


@pytest.fixture
def every_chunk_row_a_part(monkeypatch):
    """Parts as many as rows of chunks, run one after the other in this process (dask's synchronous scheduler)."""
    monkeypatch.setattr(source, "_workers", lambda: 1 << 20)
    with dask.config.set(scheduler="sync"):
        yield


def built_rows(grid, intervals, planes=None):
    """Rows handed on by an OctreeBuilder over unit-cell planes ``planes`` of ``intervals`` (slabs of 1 to 3 planes)."""
    complete, partial = {}, {}

    def keep(into):
        def sink(level, first_row, mins, maxs):
            for k in range(len(mins)):
                assert (level, first_row + k) not in into
                into[level, first_row + k] = (mins[k].copy(), maxs[k].copy())

        return sink

    first, stop = planes or (0, grid[0])
    builder = OctreeBuilder(grid, np.uint8, keep(complete), planes, keep(partial))
    rng = np.random.default_rng(first)
    plane = first
    while plane < stop:
        step = min(int(rng.integers(1, 4)), stop - plane)
        builder.add_slab(plane, intervals[0][plane : plane + step], intervals[1][plane : plane + step])
        plane += step
    builder.finish()
    return complete, partial


@pytest.mark.parametrize("n0", [1, 2, 3, 5, 17, 33])
def test_a_partial_row_builder_gives_the_whole_builders_rows(n0):
    """Every row inside a part is complete there; every row across a border is the hull of its parts' partial rows."""
    rng = np.random.default_rng(n0)
    for _ in range(6):
        grid = (n0, int(rng.integers(1, 6)), int(rng.integers(1, 6)))
        mins = rng.integers(0, 200, grid).astype(np.uint8)
        maxs = mins + rng.integers(0, 50, grid).astype(np.uint8)
        whole, none = built_rows(grid, (mins, maxs))
        assert not none
        cuts = np.concatenate(([0], np.sort(rng.integers(0, n0 + 1, rng.integers(1, 5))), [n0]))
        joined: dict = {}
        for first, stop in zip(cuts[:-1], cuts[1:]):
            complete, partial = built_rows(grid, (mins, maxs), (int(first), int(stop)))
            sizes = OctreeBuilder(grid, np.uint8, print).sizes
            for (level, row), (row_mins, row_maxs) in complete.items():
                size = sizes[level - 1][0]
                assert first <= row * size and min((row + 1) * size, n0) <= stop
                np.testing.assert_array_equal(row_mins, whole[level, row][0])
                np.testing.assert_array_equal(row_maxs, whole[level, row][1])
                assert (level, row) not in joined
                joined[level, row] = (row_mins, row_maxs, None)
            for key, (row_mins, row_maxs) in partial.items():
                assert key not in complete
                if key in joined:
                    assert joined[key][2] is not None, "a row complete in a part is partial in another"
                    row_mins, row_maxs = np.minimum(joined[key][0], row_mins), np.maximum(joined[key][1], row_maxs)
                joined[key] = (row_mins, row_maxs, "partial")
        assert joined.keys() == whole.keys()
        for key, (row_mins, row_maxs, _) in joined.items():
            np.testing.assert_array_equal(row_mins, whole[key][0])
            np.testing.assert_array_equal(row_maxs, whole[key][1])


def test_unit_cell_slabs_of_a_part_are_those_of_the_whole():
    bins = np.random.default_rng(1).integers(0, 9, (7, 4, 5)).astype(np.uint8)
    whole = dict((first, mins.copy()) for first, mins, _ in unit_cell_slabs(bins, 1))
    for first, mins, _ in unit_cell_slabs(bins[3:], 1):
        np.testing.assert_array_equal(mins, whole[first + 3])


@pytest.mark.parametrize("n0", [3, 4, 18, 34, 66, 101])
def test_similarity_in_parts_is_bit_identical(n0, every_chunk_row_a_part, monkeypatch):
    """Grids of 2, 3, 17, 33, 65 and 100 unit cells along axis 0, randomly chunked (each row of chunks a part: parts
    of one voxel plane, and of one unit-cell plane, borders on no hyper-cell size), every option, 2 to 1024 bins,
    levels both gathered and counted row by row."""
    rng = np.random.default_rng(n0)
    for case in range(4):
        shape = (n0, int(rng.integers(2, 7)), int(rng.integers(2, 7)))
        n_bins = int(rng.choice([2, 3, 7, 40, 256, 300, 1024]))
        bins = np.sort(rng.integers(0, n_bins, shape), axis=int(rng.integers(0, 3))).astype(
            np.uint8 if n_bins <= 256 else np.uint16
        )
        crossing, normalization = RULES[case]
        levels = int(rng.integers(1, len(octree_levels(tuple(n - 1 for n in shape))) + 1))
        threshold = int(rng.choice([0, 4, 1 << 30]))
        monkeypatch.setattr(stream, "_counted_row_by_row", lambda cells, n_bins, t=threshold: cells > t)
        for options in ({}, {"crossing": crossing, "normalization": normalization, "levels": levels}):
            expected = isovalue_similarity(bins, n_bins, **options)
            chunks = (random_chunks(rng, n0), int(rng.integers(1, shape[1] + 1)), shape[2])
            result = isovalue_similarity(da.from_array(bins, chunks=chunks), n_bins, **options)
            np.testing.assert_array_equal(result.matrix, expected.matrix, err_msg=f"{chunks} {options} {n_bins}")
            np.testing.assert_array_equal(result.cell_counts, expected.cell_counts)


@pytest.mark.parametrize("seed", range(4))
def test_design_in_parts_is_bit_identical(seed, every_chunk_row_a_part):
    rng = np.random.default_rng(seed)
    shape = (int(rng.choice([9, 18, 34])), 12, 14)
    grid = np.indices(shape).astype(float)
    r = np.sqrt(((grid - np.array(shape)[:, None, None, None] / 2) ** 2).sum(axis=0))
    values = (np.select([r < 3, r < 5, r < 7], [1200, 300, 40], -1000) + rng.normal(0, 25, shape)).astype(np.int16)
    options = {
        "n_bins": int(rng.choice([24, 64, 300])),
        "crossing": RULES[seed][0],
        "normalization": RULES[seed][1],
        "background": ["largest", "lowest"][seed % 2],
        "unconverged": "keep",
    }
    expected = design_transfer_function(values, (0.5, 0.5, 1.0), **options)
    chunks = (random_chunks(rng, shape[0]), 6, 14)
    design = design_transfer_function(da.from_array(values, chunks=chunks), (0.5, 0.5, 1.0), **options)
    assert {**design.to_dict(), "timings_s": None} == {**expected.to_dict(), "timings_s": None}
    np.testing.assert_array_equal(design.similarity, expected.similarity)


def test_parts_read_their_chunks_once(every_chunk_row_a_part):
    """Each part reads its own rows of chunks; the unit cells between two parts come from the planes they return."""
    values = quantize(np.random.default_rng(2).normal(size=(23, 9, 8)), 64).bins
    reads = []

    def read(block, block_info=None):
        reads.append(tuple(block_info[0]["array-location"][0]))
        return block

    volume = da.from_array(values, chunks=(5, 9, 8)).map_blocks(read, dtype=values.dtype)
    expected = isovalue_similarity(values, 64)
    np.testing.assert_array_equal(isovalue_similarity(volume, 64).matrix, expected.matrix)
    assert sorted(reads) == [(0, 5), (5, 10), (10, 15), (15, 20), (20, 23)]


# Run in a child interpreter: dask's process pool leaves multiprocessing's resource tracker running in the process that
# started it, and the render tests check that the test process has no child left.
IN_PROCESSES = """
import dask, dask.array as da, numpy as np
from IsoSimilarityTFLib import isovalue_similarity, quantize, source

if __name__ == "__main__":
    values = quantize(np.random.default_rng(3).normal(size=(40, 10, 11)), 100).bins
    expected = isovalue_similarity(values, 100)
    progress = []
    with dask.config.set(scheduler="processes", num_workers=2):
        assert source._workers() == 2
        result = isovalue_similarity(
            da.from_array(values, chunks=(6, 10, 11)), 100, progress=lambda fraction, _: progress.append(fraction)
        )
    np.testing.assert_array_equal(result.matrix, expected.matrix)
    np.testing.assert_array_equal(result.cell_counts, expected.cell_counts)
    assert progress == sorted(progress) and 0 < progress[0] and progress[-1] == 1.0, progress
    print("identical")
"""


def test_parts_run_in_other_processes(tmp_path):
    """With dask's process pool, the parts run in 2 processes and what they return crosses processes intact."""
    script = tmp_path / "in_processes.py"
    script.write_text(IN_PROCESSES, encoding="utf-8")
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and run.stdout.strip() == "identical", run.stderr
