"""Measures of a rendered picture, for comparing transfer functions through the same renderer and camera.

All functions are pure numpy. A picture is an ``(height, width, 3)`` uint8 RGB array; the backdrop is the picture
of the empty view (same shape) or one RGB colour. Luma and chroma follow ITU-R BT.601 (full range, as JPEG), in
0..255 units: ``Y = 0.299 R + 0.587 G + 0.114 B``; ``Cb``, ``Cr`` centred on 0 (-127.5..127.5).

- foreground: pixels that differ from the backdrop by more than a tolerance in some channel;
- brightness: mean luma over the foreground;
- colour noise: mean over the foreground of ``|(Cb, Cr) - local mean|`` (Euclidean norm), the local mean taken
  over the foreground pixels of the 5x5 window around the pixel (backdrop pixels do not enter it, so a coloured
  silhouette on a black backdrop is not counted as noise);
- coverage: the foreground's share of the picture.
"""

from __future__ import annotations

from typing import Union

import numpy as np

#: A channel difference (0..255) above which a pixel is foreground: above the rounding and dithering of a backdrop.
FOREGROUND_TOLERANCE = 8

#: Side of the window of the local chroma mean, in pixels.
NOISE_WINDOW = 5

_LUMA = np.array([0.299, 0.587, 0.114])
_CHROMA = np.array([[-0.168736, -0.331264, 0.5], [0.5, -0.418688, -0.081312]])

Backdrop = Union[np.ndarray, tuple[int, int, int]]


def _as_rgb(picture: np.ndarray) -> np.ndarray:
    array = np.asarray(picture)
    if array.ndim != 3 or array.shape[2] != 3:
        raise ValueError(f"picture must have shape (height, width, 3), got {array.shape}")
    return array.astype(np.float64)


def foreground_mask(picture: np.ndarray, backdrop: Backdrop = (0, 0, 0), tolerance: int = FOREGROUND_TOLERANCE):
    """``(height, width)`` bool: the pixels where some channel differs from the backdrop by more than ``tolerance``."""
    image = _as_rgb(picture)
    reference = np.asarray(backdrop, dtype=np.float64)
    return np.abs(image - reference).max(axis=2) > tolerance


def luma(picture: np.ndarray) -> np.ndarray:
    """``(height, width)`` BT.601 luma in 0..255."""
    return _as_rgb(picture) @ _LUMA


def chroma(picture: np.ndarray) -> np.ndarray:
    """``(height, width, 2)`` BT.601 chroma (Cb, Cr), centred on 0, in 0..255 units (grey has (0, 0))."""
    return _as_rgb(picture) @ _CHROMA.T


def box_sum(image: np.ndarray, size: int) -> np.ndarray:
    """Sum over the ``size`` x ``size`` window centred on each pixel (zero outside the picture); same shape.

    Args:
        image: ``(height, width)`` or ``(height, width, channels)``.
        size: odd window side in pixels.
    """
    if size < 1 or size % 2 == 0:
        raise ValueError(f"size must be a positive odd number, got {size}")
    half = size // 2
    pad = [(half + 1, half), (half + 1, half)] + [(0, 0)] * (image.ndim - 2)
    table = np.pad(np.asarray(image, dtype=np.float64), pad).cumsum(axis=0).cumsum(axis=1)
    return table[size:, size:] - table[:-size, size:] - table[size:, :-size] + table[:-size, :-size]


def colour_noise(picture: np.ndarray, mask: np.ndarray, window: int = NOISE_WINDOW) -> float:
    """Mean over ``mask`` of ``|(Cb, Cr) - mean of (Cb, Cr) over the masked pixels of the window|``; 0 if empty."""
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return 0.0
    cbcr = chroma(picture) * mask[..., None]
    counts = box_sum(mask.astype(np.float64), window)
    local_mean = box_sum(cbcr, window) / np.maximum(counts, 1.0)[..., None]
    deviation = np.linalg.norm(cbcr - local_mean, axis=2)
    return float(deviation[mask].mean())


def picture_metrics(picture: np.ndarray, backdrop: Backdrop = (0, 0, 0)) -> dict[str, float]:
    """Brightness (mean luma over the foreground, 0..255), colour noise (0..255 chroma units) and coverage (0..1)."""
    mask = foreground_mask(picture, backdrop)
    if not mask.any():
        return {"brightness": 0.0, "colour_noise": 0.0, "coverage": 0.0}
    return {
        "brightness": float(luma(picture)[mask].mean()),
        "colour_noise": colour_noise(picture, mask),
        "coverage": float(mask.mean()),
    }


def resize_area(picture: np.ndarray, height: int, width: int) -> np.ndarray:
    """Resize a uint8 ``(h, w, c)`` picture by area averaging (each output pixel the mean of the input it covers)."""

    def weights(n_in: int, n_out: int) -> np.ndarray:
        edges = np.linspace(0.0, n_in, n_out + 1)
        lo, hi = edges[:-1, None], edges[1:, None]
        cells = np.arange(n_in)[None, :]
        overlap = np.clip(np.minimum(hi, cells + 1) - np.maximum(lo, cells), 0.0, None)
        return overlap / overlap.sum(axis=1, keepdims=True)

    rows, columns = weights(picture.shape[0], height), weights(picture.shape[1], width)
    partial = np.tensordot(rows, np.asarray(picture, dtype=np.float64), axes=(1, 0))  # (height, w, c)
    result = np.tensordot(partial, columns, axes=(1, 1)).transpose(0, 2, 1)  # (height, width, c)
    return np.clip(np.round(result), 0, 255).astype(np.uint8)
