"""Tests of IsoSimilarityTFLib.pictures: the similarity-matrix picture (plain numpy, no Qt)."""

import numpy as np
import pytest

from IsoSimilarityTFLib.classes import PALETTE
from IsoSimilarityTFLib.pictures import lightness_ramp, similarity_image


def _block_matrix(sizes):
    """Block-diagonal similarity (1 inside a block, 0.25 between blocks) and the matching labels."""
    labels = np.repeat(np.arange(len(sizes)), sizes)
    similarity = np.where(labels[:, None] == labels[None, :], 1.0, 0.25)
    return similarity, labels


def _offset(image_size):
    return max(3, image_size // 40) + max(1, image_size // 128)


def test_lightness_ramp_ends_and_monotonic():
    values = np.linspace(0.0, 1.0, 101)
    grey = lightness_ramp(values)
    assert grey.dtype == np.uint8
    assert grey[0] == 0 and grey[-1] == 255
    assert np.all(np.diff(grey.astype(int)) >= 0)
    # Perceptual: mid lightness (L* = 50) is about sRGB 119, not 128 (linear) nor 188 (linear luminance).
    assert 114 <= int(lightness_ramp(np.array([0.5]))[0]) <= 124
    # NaN and out-of-range values are clipped.
    assert lightness_ramp(np.array([np.nan, -1.0, 2.0])).tolist() == [0, 0, 255]


def test_default_size_scales_small_matrices_up():
    similarity, labels = _block_matrix([10, 22])
    image = similarity_image(similarity, labels)
    assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
    assert image.shape[0] == image.shape[1]
    # 32 isovalues scaled by 8 to 256 pixels, plus the strip and gap.
    matrix_pixels = 256
    assert image.shape[0] == matrix_pixels + max(4, matrix_pixels // 40) + 2


def test_default_size_is_one_pixel_per_isovalue_for_256():
    similarity, labels = _block_matrix([100, 156])
    image = similarity_image(similarity, labels)
    assert image.shape[0] == 256 + max(4, 256 // 40) + 2


def test_grey_levels_class_strips_and_boundaries():
    size = 200
    similarity, labels = _block_matrix([25, 25, 50])
    colors = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    image = similarity_image(similarity, labels, colors, size=size)
    assert image.shape == (size, size, 3)
    offset = _offset(size)
    matrix_pixels = size - offset
    scale = matrix_pixels / 100

    def at(i, j):  # pixel at the middle of isovalue pair (i, j)
        return image[offset + int((i + 0.5) * scale), offset + int((j + 0.5) * scale)]

    # Inside a block: white; between blocks: grey of 0.25, same on all three channels.
    assert at(10, 10).tolist() == [255, 255, 255]
    between = at(10, 80)
    assert between[0] == between[1] == between[2] == lightness_ramp(np.array([0.25]))[0]
    assert at(80, 10).tolist() == between.tolist()  # symmetric matrix, symmetric picture

    # Left strip: class colour of each row; top strip: of each column.
    assert image[offset + int(10 * scale), 0].tolist() == [255, 0, 0]
    assert image[offset + int(40 * scale), 0].tolist() == [0, 255, 0]
    assert image[offset + int(90 * scale), 0].tolist() == [0, 0, 255]
    assert image[0, offset + int(90 * scale)].tolist() == [0, 0, 255]

    # Boundary lines in the colour of the class that starts there, across the whole matrix, along both axes.
    green_rows = np.flatnonzero(np.all(image[offset:, offset + 5] == [0, 255, 0], axis=1))
    blue_rows = np.flatnonzero(np.all(image[offset:, offset + 5] == [0, 0, 255], axis=1))
    assert green_rows.size >= 1 and abs(green_rows[0] - 25 * scale) <= 1
    assert blue_rows.size >= 1 and abs(blue_rows[0] - 50 * scale) <= 1
    green_cols = np.flatnonzero(np.all(image[offset + 5, offset:] == [0, 255, 0], axis=1))
    assert green_cols.tolist() == green_rows.tolist()
    # No line inside a class.
    red_rows = np.flatnonzero(np.all(image[offset:, offset + 5] == [255, 0, 0], axis=1))
    assert red_rows.size == 0


def test_downsampling_averages_instead_of_dropping():
    # 1000 isovalues on 100 pixels: a checkerboard of 0/1 must average to mid grey, not alias to black or white.
    n = 1000
    similarity = np.indices((n, n)).sum(axis=0) % 2 == 0
    labels = np.zeros(n, dtype=int)
    image = similarity_image(similarity.astype(float), labels, size=128)
    offset = _offset(128)
    matrix = image[offset:, offset:, 0].astype(int)
    mid = int(lightness_ramp(np.array([0.5]))[0])
    assert np.abs(matrix - mid).max() <= 12


def test_default_colors_come_from_the_palette():
    similarity, labels = _block_matrix([8, 8])
    image = similarity_image(similarity, labels, size=64)
    offset = _offset(64)
    expected = np.round(255 * np.asarray(PALETTE[1])).astype(np.uint8)
    assert image[offset + 50, 0].tolist() == expected.tolist()


def test_nan_is_drawn_as_zero():
    similarity, labels = _block_matrix([4, 4])
    similarity[0, 7] = similarity[7, 0] = np.nan
    image = similarity_image(similarity, labels, size=64)
    offset = _offset(64)
    scale = (64 - offset) / 8
    assert image[offset + int(0.5 * scale), offset + int(7.5 * scale)].tolist() == [0, 0, 0]


@pytest.mark.parametrize(
    ("similarity", "labels", "colors", "size"),
    [
        (np.zeros((3, 4)), np.zeros(3, dtype=int), None, None),  # not square
        (np.zeros((4, 4)), np.zeros(3, dtype=int), None, None),  # labels too short
        (np.zeros((4, 4)), np.zeros(4), None, None),  # float labels
        (np.zeros((4, 4)), np.array([0, 1, 1, 2]), np.zeros((2, 3)), None),  # too few colours
        (np.zeros((4, 4)), np.array([0, 1, 1, 1]), np.full((2, 3), 2.0), None),  # colours outside [0, 1]
        (np.zeros((4, 4)), np.array([0, 1, 1, 1]), None, 8),  # too small
        (np.zeros((4, 4)), np.array([0, 1, 1, 1]), None, 64.0),  # not an integer
    ],
)
def test_bad_arguments(similarity, labels, colors, size):
    with pytest.raises(ValueError):
        similarity_image(similarity, labels, colors, size=size)
