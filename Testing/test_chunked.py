"""A dask volume, streamed chunk row by chunk row, gives exactly the design of the same volume held in memory."""

import itertools

import dask.array as da
import numpy as np
import pytest

from IsoSimilarityTFLib import InsufficientMemoryError, design_transfer_function, isovalue_similarity, memory, quantize
from IsoSimilarityTFLib.chunked import is_dask_array, quantize_chunked

RULES = list(itertools.product(("inclusive", "strict"), ("thesis", "ma-entezari")))
# Irregular chunks, one voxel thick ones included, on an odd shape.
CHUNKS = [((7, 1, 8, 7), (9, 9), (31,)), ((1, 22), (18,), (4, 27)), (23, 18, 31)]


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
def test_quantized_chunks_equal_the_in_memory_bins(dtype, n_bins, value_range):
    values = blob_volume(dtype)
    expected = quantize(values, n_bins, value_range)
    for chunks in CHUNKS:
        quantized = quantize_chunked(da.from_array(values, chunks=chunks), n_bins, value_range)
        assert quantized.value_range == expected.value_range and quantized.n_bins == expected.n_bins
        np.testing.assert_array_equal(np.asarray(quantized.bins), expected.bins)
        np.testing.assert_array_equal(quantized.voxel_counts(), expected.voxel_counts())


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


def test_a_dask_volume_needs_memory_for_the_octree_levels_only(monkeypatch):
    """Streamed, a volume needs a third of a byte per voxel (the levels above the unit cells), not the bins' byte."""
    shape = (2048, 2048, 3200)
    in_memory, streamed = memory.design_memory_bytes(shape, 256), memory.design_memory_bytes(shape, 256, True)
    voxels = 2048 * 2048 * 3200
    assert in_memory - streamed == voxels and 0.3 < (streamed - (256 << 20)) / voxels < 0.4
    volume = da.zeros(shape, dtype=np.uint16, chunks=(64, 2048, 2048))
    monkeypatch.setattr(memory, "available_memory_bytes", lambda: (in_memory + streamed) // 2)

    class Started(Exception):
        pass

    def stop_at_start(stage, fraction, message):
        raise Started

    with pytest.raises(Started):  # past the memory check: enough for the streamed design
        design_transfer_function(volume, progress=stop_at_start)
    monkeypatch.setattr(memory, "available_memory_bytes", lambda: streamed - 1)
    with pytest.raises(InsufficientMemoryError, match="crop or downsample"):
        design_transfer_function(volume, progress=stop_at_start)
