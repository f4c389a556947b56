"""Pictures of a design, as plain numpy RGB arrays (no Qt, no VTK): the similarity matrix with its class boundaries.

The Slicer module shows the array in its panel and the command-line tool writes it as ``similarity.png``.
"""

from typing import Optional

import numpy as np

from .classes import PALETTE

# Background of the picture around the matrix (the corner between the two class strips and the gaps).
BACKGROUND = (255, 255, 255)
# Default side of the matrix area when no size is given: small matrices are scaled up by a whole factor to about this.
DEFAULT_MATRIX_PIXELS = 256
MIN_SIZE = 16


def lightness_ramp(values: np.ndarray) -> np.ndarray:
    """Grey levels (uint8) for values in [0, 1]: 0 black, 1 white, equal steps of CIE lightness L* (perceptual).

    NaN and values outside [0, 1] are clipped (NaN counts as 0, no similarity).
    """
    lightness = 100.0 * np.clip(np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0), 0.0, 1.0)
    # L* -> relative luminance Y (CIE 1976), then Y -> sRGB encoded value.
    f = (lightness + 16.0) / 116.0
    luminance = np.where(lightness > 8.0, f**3, lightness / 903.3)
    encoded = np.where(luminance <= 0.0031308, 12.92 * luminance, 1.055 * np.power(luminance, 1.0 / 2.4) - 0.055)
    return np.round(255.0 * np.clip(encoded, 0.0, 1.0)).astype(np.uint8)


def _pixel_bins(n: int, pixels: int) -> tuple[np.ndarray, np.ndarray]:
    """For each pixel along an axis of ``pixels``, the half-open range of bins ``[low, high)`` it covers (>= 1 bin)."""
    p = np.arange(pixels)
    low = (p * n) // pixels
    high = np.maximum(low + 1, ((p + 1) * n) // pixels)
    return low, np.minimum(high, n)


def _box_means(matrix: np.ndarray, pixels: int) -> np.ndarray:
    """``(pixels, pixels)`` resampling of a square matrix: each pixel the mean of the bins it covers.

    Scaling up repeats bins (nearest); scaling down averages them, so thin blocks are not lost to aliasing.
    """
    n = matrix.shape[0]
    integral = np.zeros((n + 1, n + 1), dtype=np.float64)
    integral[1:, 1:] = np.cumsum(np.cumsum(matrix, axis=0), axis=1)
    low, high = _pixel_bins(n, pixels)
    total = (
        integral[np.ix_(high, high)]
        - integral[np.ix_(low, high)]
        - integral[np.ix_(high, low)]
        + integral[np.ix_(low, low)]
    )
    count = np.outer(high - low, high - low)
    return total / count


def _check_colors(colors, n_classes: int) -> np.ndarray:
    if colors is None:
        palette = np.asarray(PALETTE, dtype=np.float64)
        return palette[np.arange(n_classes) % len(palette)]
    colors = np.asarray(colors, dtype=np.float64)
    if colors.ndim != 2 or colors.shape[1] != 3:
        raise ValueError(f"colors must be an array of shape (K, 3); got shape {colors.shape}")
    if colors.shape[0] < n_classes:
        raise ValueError(f"colors has {colors.shape[0]} rows but the labels name {n_classes} classes")
    if not np.all(np.isfinite(colors)) or colors.min() < 0.0 or colors.max() > 1.0:
        raise ValueError("colors must be RGB values in [0, 1]")
    return colors


def similarity_image(
    similarity: np.ndarray,
    labels: np.ndarray,
    colors: Optional[np.ndarray] = None,
    size: Optional[int] = None,
) -> np.ndarray:
    """Picture of the isovalue similarity matrix with the class boundaries.

    Isovalue 0 is at the top left; the matrix is drawn in grey (black = 0, white = 1, perceptual lightness ramp).
    A strip of class colours runs along the top and the left edge, and a thin line in the colour of the class that
    starts there marks each class boundary (a change of label between neighbouring isovalues) across the matrix, along
    both axes.

    Args:
        similarity: ``(n, n)`` similarity, values in [0, 1] (NaN drawn as 0).
        labels: ``(n,)`` class id (0..K-1) per isovalue.
        colors: ``(K, 3)`` RGB in [0, 1] per class id; None: the default class palette.
        size: side of the square picture in pixels; None: the matrix scaled up by a whole factor to about
            256 pixels (one pixel per isovalue for 256 or more isovalues) plus the strips.

    Returns:
        ``(size, size, 3)`` uint8 RGB.
    """
    similarity = np.asarray(similarity, dtype=np.float64)
    if similarity.ndim != 2 or similarity.shape[0] != similarity.shape[1] or similarity.shape[0] < 1:
        raise ValueError(f"similarity must be a square matrix; got shape {similarity.shape}")
    n = similarity.shape[0]
    labels = np.asarray(labels)
    if labels.shape != (n,):
        raise ValueError(f"labels must have shape ({n},) to match the similarity matrix; got {labels.shape}")
    if not np.issubdtype(labels.dtype, np.integer) or labels.min() < 0:
        raise ValueError("labels must be non-negative integer class ids")
    labels = labels.astype(np.intp)
    colors8 = np.round(255.0 * _check_colors(colors, int(labels.max()) + 1)).astype(np.uint8)

    if size is None:
        matrix_pixels = n * max(1, -(-DEFAULT_MATRIX_PIXELS // n))
        strip, gap = max(4, matrix_pixels // 40), 2
        size = strip + gap + matrix_pixels
    else:
        if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < MIN_SIZE:
            raise ValueError(f"size must be an integer >= {MIN_SIZE}; got {size!r}")
        size = int(size)
        strip, gap = max(3, size // 40), max(1, size // 128)
        matrix_pixels = size - strip - gap
    offset = strip + gap

    image = np.empty((size, size, 3), dtype=np.uint8)
    image[:] = BACKGROUND
    image[offset:, offset:] = lightness_ramp(_box_means(np.nan_to_num(similarity, nan=0.0), matrix_pixels))[..., None]

    # Class of each pixel row/column: the class of the first bin it covers.
    low, _ = _pixel_bins(n, matrix_pixels)
    pixel_colors = colors8[labels[low]]
    image[offset:, :strip] = pixel_colors[:, None, :]
    image[:strip, offset:] = pixel_colors[None, :, :]

    # Boundaries: bin b starts a new class; its line goes at the first pixel showing bin b or later.
    boundaries = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    thickness = max(1, matrix_pixels // 512)
    for b in boundaries.tolist():
        pixel = int(np.searchsorted(low, b))
        if pixel >= matrix_pixels:
            continue
        color = colors8[labels[b]]
        rows = slice(offset + pixel, offset + min(matrix_pixels, pixel + thickness))
        image[rows, offset:] = color
        image[offset:, rows] = color
    return image


# Icon of a transfer function (the Volume Rendering preset menu shows one per preset) ---------------------------------
ICON_SIZE = 64
ICON_BACKGROUND = (40, 40, 40)


def transfer_function_icon(design, size: int = ICON_SIZE) -> np.ndarray:
    """Picture of a design's transfer function: intensity from left to right, each column in its colour, filled from
    the bottom to a height that grows with its opacity (square root, so faint classes still show).

    Args:
        design: a :class:`~.design.TransferFunctionDesign`.
        size: side of the square picture in pixels.

    Returns:
        ``(size, size, 3)`` uint8 RGB, the top row first.
    """
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < MIN_SIZE:
        raise ValueError(f"size must be an integer >= {MIN_SIZE}; got {size!r}")
    size = int(size)
    low, high = design.value_range
    centres = low + (np.arange(size) + 0.5) * (high - low) / size
    color, opacity = design.transfer_function()(centres)
    heights = np.round(np.sqrt(np.clip(opacity, 0.0, 1.0)) * size).astype(int)
    heights[(opacity > 0) & (heights == 0)] = 1
    image = np.empty((size, size, 3), dtype=np.uint8)
    image[:] = ICON_BACKGROUND
    rows_from_bottom = (size - 1 - np.arange(size))[:, None]
    filled = rows_from_bottom < heights[None, :]
    colors8 = np.round(255.0 * np.clip(color, 0.0, 1.0)).astype(np.uint8)
    image[filled] = np.broadcast_to(colors8[None, :, :], (size, size, 3))[filled]
    return image
