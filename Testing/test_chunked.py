"""A dask volume, streamed chunk row by chunk row, gives exactly the design of the same volume held in memory."""

import itertools
from functools import partial

import dask.array as da
import numpy as np
import pytest

from IsoSimilarityTFLib import (
    InsufficientMemoryError,
    design_transfer_function,
    isovalue_similarity,
    memory,
    quantize,
    stream,
)
from IsoSimilarityTFLib import source as source_module
from IsoSimilarityTFLib.quantize import Quantization, bin_volume, bins_dtype
from IsoSimilarityTFLib.source import VolumeSource, is_dask_array
from IsoSimilarityTFLib.survey import survey_volume

RULES = list(itertools.product(("inclusive", "strict"), ("thesis", "ma-entezari")))
# Irregular chunks, one voxel thick ones included, on an odd shape.
CHUNKS = [((7, 1, 8, 7), (9, 9), (31,)), ((1, 22), (18,), (4, 27)), (23, 18, 31), ((2, 2, 3, 5, 11), (1, 17), (30, 1))]


def blob_volume(dtype=np.int16, seed=0):
    """Nested blobs with noisy borders, in CT-like units."""
    rng = np.random.default_rng(seed)
    grid = np.indices((23, 18, 31)).astype(float)
    r = np.sqrt(((grid - np.array([11, 8, 14])[:, None, None, None]) ** 2).sum(axis=0))
    values = np.select([r < 4, r < 7, r < 10], [1200, 300, 40], -1000) + rng.normal(0, 25, r.shape)
    return values.astype(dtype)


def test_dask_arrays_are_recognised_without_importing_dask_for_others():
    assert is_dask_array(da.zeros((2, 2, 2)))
    assert not is_dask_array(np.zeros((2, 2, 2))) and not is_dask_array([1, 2])


@pytest.mark.parametrize("dtype", [np.int16, np.float32, np.uint8])
@pytest.mark.parametrize("n_bins,value_range", [(256, None), (1000, None), (64, (-500.0, 900.0))])
def test_binned_chunks_equal_the_in_memory_bins(dtype, n_bins, value_range):
    """The design's path for a dask volume: its survey, then its chunks binned lazily with the whole volume's range."""
    values = blob_volume(dtype)
    expected = quantize(values, n_bins, value_range)
    for chunks in CHUNKS:
        source = VolumeSource(da.from_array(values, chunks=chunks))
        survey = survey_volume(source)
        assert survey.data_range == (float(values.min()), float(values.max()))
        binning = partial(bin_volume, n_bins=n_bins, value_range=expected.value_range, data_range=survey.data_range)
        bins = source.map_slabs(binning, bins_dtype(n_bins))
        assert bins.lazy
        np.testing.assert_array_equal(np.asarray(bins.values), expected.bins)
        quantized = Quantization(bins.values, n_bins, expected.value_range)
        np.testing.assert_array_equal(quantized.voxel_counts(), expected.voxel_counts())


@pytest.mark.parametrize("planes, starts", [(40, [0, 6, 12, 18, 24, 30, 36]), (37, [0, 6, 12, 18, 24, 30])])
def test_a_volume_in_memory_is_binned_a_slab_at_a_time(monkeypatch, planes, starts):
    """The design's bins of a volume in memory are never made whole: each slab of a few planes is binned as it is
    read, with the two border planes between slabs (for the unit cells across them), as a dask volume's rows are; a
    last slab one plane thick is merged into the one before."""
    monkeypatch.setattr(source_module, "_MAPPED_SLAB_VOXELS", 6 * 5 * 7)  # slabs of 6 planes
    values = np.random.default_rng(3).integers(-1000, 2000, size=(planes, 5, 7)).astype(np.int16)
    binned = []

    def binning(voxels):
        binned.append(len(voxels))
        return bin_volume(voxels, 64, (-1000.0, 2000.0))

    mapped = VolumeSource(values).map_slabs(binning, np.uint8)
    assert binned == [] and mapped.shape == values.shape and mapped.dtype == np.uint8
    slabs = list(mapped.slabs(overlap=True))
    expected = bin_volume(values, 64, (-1000.0, 2000.0))
    for first, voxels in slabs:
        np.testing.assert_array_equal(voxels, expected[first : first + len(voxels)])
    ends = [*starts[1:], planes]
    rows = [(first, end - first) for first, end in zip(starts, ends)]
    borders = [(first - 1, 2) for first in starts[1:]]
    assert [(first, len(voxels)) for first, voxels in slabs] == [rows[0], *itertools.chain(*zip(borders, rows[1:]))]
    assert binned == [n for _, n in rows]  # each plane binned once, no slab thicker than asked (but the merged one)
    np.testing.assert_array_equal(mapped.values, expected)


def test_the_survey_keeps_no_slab_alive():
    """Before: the survey's sample was a strided view of each slab, which kept every row of a dask volume in memory
    (a 1024^3 volume read lazily peaked at 2.4 GB)."""
    import weakref

    read, alive = [], []

    class Rows(VolumeSource):
        def slabs(self, overlap=False):
            for first in range(0, self.shape[0], 4):
                alive.append(sum(ref() is not None for ref in read[:-1]))  # rows before the one just surveyed
                row = np.array(self.values[first : first + 4])  # a fresh array per row, as dask gives
                read.append(weakref.ref(row))
                yield first, row
                del row

    survey = survey_volume(Rows(blob_volume(np.int16)), sample_voxels=2000)
    assert survey.sample.size > 0 and len(read) > 2
    assert alive == [0] * len(read)


@pytest.mark.parametrize("crossing,normalization", RULES)
def test_similarity_of_chunked_bins_is_bit_identical(crossing, normalization):
    quantized = quantize(blob_volume(), 48)
    for chunks, levels in itertools.product(CHUNKS, (None, 2)):
        options = {"crossing": crossing, "normalization": normalization, "levels": levels}
        expected = isovalue_similarity(quantized.bins, 48, **options)
        result = isovalue_similarity(da.from_array(quantized.bins, chunks=chunks), 48, **options)
        np.testing.assert_array_equal(result.matrix, expected.matrix)
        np.testing.assert_array_equal(result.cell_counts, expected.cell_counts)


@pytest.mark.parametrize(
    "options",
    [
        {"n_bins": 64},
        {"n_bins": 64, "crossing": "strict", "normalization": "ma-entezari", "levels": 3, "background": "lowest"},
        {"n_bins": 300, "value_range": (-900, 1300), "background": "none", "unconverged": "keep"},
    ],
)
def test_design_of_a_dask_volume_is_bit_identical(options):
    values = blob_volume()
    expected = design_transfer_function(values, (0.5, 0.5, 1.0), **options)
    design = design_transfer_function(da.from_array(values, chunks=CHUNKS[0]), (0.5, 0.5, 1.0), **options)
    assert {**design.to_dict(), "timings_s": None} == {**expected.to_dict(), "timings_s": None}
    np.testing.assert_array_equal(design.similarity, expected.similarity)


def test_bad_dask_volumes_are_refused_like_arrays():
    with pytest.raises(ValueError, match="constant"):
        design_transfer_function(da.full((4, 4, 4), 7, dtype=np.int16, chunks=2))
    values = blob_volume(np.float32)
    values[3, 4, 5] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        design_transfer_function(da.from_array(values, chunks=8))
    with pytest.raises(ValueError, match="3-D"):
        design_transfer_function(da.zeros((4, 4), chunks=2))
    with pytest.raises(ValueError, match="n_bins"):
        design_transfer_function(da.from_array(blob_volume(), chunks=8), n_bins=1)


def test_a_dask_volume_needs_memory_independent_of_its_size(monkeypatch):
    """Streamed, no array grows with the voxels (the octree levels are counted row by row, the bins never held whole):
    what counts is the rows of chunks held at once."""
    shape = (2048, 2048, 3200)
    streamed = memory.design_memory_bytes(shape, 256)
    assert streamed <= memory.design_memory_bytes((8192, 8192, 8192), 256) < 300 << 20
    volume = da.zeros(shape, dtype=np.uint16, chunks=(64, 2048, 2048))
    monkeypatch.setattr(memory, "available_memory_bytes", lambda: streamed + 3 * 64 * 2048 * 3200 * (2 + 1))

    class Started(Exception):
        pass

    def stop_at_start(stage, fraction, message):
        raise Started

    with pytest.raises(Started):  # past the memory check: enough for the streamed design
        design_transfer_function(volume, progress=stop_at_start)
    monkeypatch.setattr(memory, "available_memory_bytes", lambda: streamed - 1)
    with pytest.raises(InsufficientMemoryError, match="crop or downsample"):
        design_transfer_function(volume, progress=stop_at_start)
    # The rows of chunks held at once count too: thin rows fit where thick ones do not.
    thin_row = 8 * 2048 * 3200 * (2 + 1)
    monkeypatch.setattr(memory, "available_memory_bytes", lambda: streamed + 3 * thin_row)
    with pytest.raises(Started):
        design_transfer_function(volume.rechunk((8, 2048, 3200)), progress=stop_at_start)
    with pytest.raises(InsufficientMemoryError):
        design_transfer_function(volume.rechunk((64, 2048, 3200)), progress=stop_at_start)


@pytest.mark.parametrize("shape", [(37, 5, 9), (2, 33, 17), (65, 3, 2), (19, 19, 19)])
@pytest.mark.parametrize("rows", [1, 2, 3, 8])
def test_odd_shapes_in_thin_chunk_rows_are_bit_identical(shape, rows, monkeypatch):
    """Chunk rows of a few planes against octree rows of 2, 4, 8 ... planes, with levels both gathered and counted
    row by row (the gathering threshold lowered so that small volumes have both)."""
    monkeypatch.setattr(stream, "_counted_row_by_row", lambda cells, n_bins: cells > 4)
    rng = np.random.default_rng(sum(shape) + rows)
    bins = np.sort(rng.integers(0, 40, shape), axis=0).astype(np.uint8)
    chunks = (rows, max(1, shape[1] // 2), shape[2])
    for crossing, normalization in RULES:
        options = {"crossing": crossing, "normalization": normalization}
        expected = isovalue_similarity(bins, 40, **options)
        result = isovalue_similarity(da.from_array(bins, chunks=chunks), 40, **options)
        np.testing.assert_array_equal(result.matrix, expected.matrix)
        np.testing.assert_array_equal(result.cell_counts, expected.cell_counts)


def test_a_dask_volume_is_read_twice_only():
    """The value range, then the similarity's pass, which also counts the voxels and keeps the background-contact
    planes: the classes stage reads nothing more."""
    values = blob_volume()
    reads = []

    def read(block, block_info=None):
        reads.append(tuple(block_info[0]["array-location"][0]))
        return block

    volume = da.from_array(values, chunks=(6, 18, 31)).map_blocks(read, dtype=values.dtype)
    expected = design_transfer_function(values, n_bins=64)
    design = design_transfer_function(volume, n_bins=64)
    assert {**design.to_dict(), "timings_s": None} == {**expected.to_dict(), "timings_s": None}
    assert sorted(set(reads)) == [(0, 6), (6, 12), (12, 18), (18, 23)]
    assert all(reads.count(chunk) == 2 for chunk in set(reads)), sorted(reads)


def test_dask_bins_out_of_range_are_refused_during_the_pass():
    bins = np.zeros((9, 5, 6), dtype=np.int64)
    bins[7, 2, 3] = 300  # would wrap to 44 in uint8
    with pytest.raises(ValueError, match=r"bins must lie in \[0, 256\); found 300"):
        isovalue_similarity(da.from_array(bins, chunks=(3, 5, 6)), 256)
