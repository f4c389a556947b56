"""Picture composition without Qt or matplotlib: label text from VTK's FreeType renderer and the class grid.

Pictures are ``(height, width, 3)`` uint8 RGB numpy arrays.
"""

import math
from typing import Optional

import numpy as np

from IsoSimilarityTFLib.design import Tissue

from .formatting import format_percent, format_ranges

# Class grid: tile background (the 3D view's black) and the label strip under each tile.
LABEL_BACKGROUND = (28, 28, 28)
LABEL_TEXT = (235, 235, 235)
GRID_GAP = 4
GRID_BACKGROUND = (64, 64, 64)
# Opacity per mm below which a tissue's tile is labelled "nearly clear" (a few % over the few cm of a head).
NEARLY_CLEAR = 0.01


def text_image(text: str, font_size: int = 13) -> Optional[np.ndarray]:
    """Coverage (alpha, float 0..1) of ``text`` as a ``(height, width)`` array, from VTK's FreeType renderer.

    Returns None when VTK has no text renderer (then labels are left out).
    """
    import vtkmodules.vtkRenderingFreeType  # noqa: F401  (registers the FreeType text renderer)
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkRenderingCore import vtkTextProperty, vtkTextRenderer

    renderer = vtkTextRenderer.GetInstance()
    if renderer is None or not text:
        return None
    prop = vtkTextProperty()
    prop.SetFontFamilyToArial()
    prop.SetFontSize(int(font_size))
    prop.SetColor(1.0, 1.0, 1.0)
    prop.SetJustificationToLeft()
    prop.SetVerticalJustificationToBottom()
    image = vtkImageData()
    dims = [0, 0]
    if not renderer.RenderString(prop, text, image, dims, 72):
        return None
    width, height, _ = image.GetDimensions()
    rgba = vtk_to_numpy(image.GetPointData().GetScalars()).reshape(height, width, -1)[::-1]
    alpha = rgba[..., -1].astype(np.float64) / 255.0
    rows = np.flatnonzero(alpha.max(axis=1) > 0)
    columns = np.flatnonzero(alpha.max(axis=0) > 0)
    if rows.size == 0:
        return None
    return alpha[: rows[-1] + 1, : columns[-1] + 1]


def draw_text(image: np.ndarray, text: str, x: int, y: int, font_size: int, color=LABEL_TEXT) -> int:
    """Blend ``text`` into ``image`` (uint8 RGB, in place) with its top-left corner at ``(x, y)``.

    Text that does not fit is clipped. Returns the width drawn in pixels (0 when nothing was drawn).
    """
    alpha = text_image(text, font_size)
    if alpha is None:
        return 0
    height = min(alpha.shape[0], image.shape[0] - y)
    width = min(alpha.shape[1], image.shape[1] - x)
    if height <= 0 or width <= 0:
        return 0
    a = alpha[:height, :width, None]
    region = image[y : y + height, x : x + width].astype(np.float64)
    blended = region * (1.0 - a) + np.asarray(color, dtype=np.float64) * a
    image[y : y + height, x : x + width] = np.round(blended).astype(np.uint8)
    return width


def tissue_label_lines(tissue: Tissue, fraction: float, decimals: int) -> tuple[str, str]:
    """The two label lines of a tissue tile: its name (as its segment is named) and voxel share, then its intensity
    range(s)."""
    first = f"Tissue {tissue.id + 1}  {format_percent(fraction)}% of voxels"
    second = format_ranges(tissue.value_ranges, decimals, limit=1)
    # A tissue the look keeps almost transparent (fat and air on CT) renders as an empty tile: say why.
    return first, second + ("  nearly clear" if tissue.opacity < NEARLY_CLEAR else "")


def class_grid(
    tiles: list[np.ndarray], labels: list[tuple[str, str]], colors: list, *, columns: Optional[int] = None
) -> np.ndarray:
    """A grid of equally sized RGB tiles, each with a two-line label and a colour swatch under it.

    Args:
        tiles: ``(h, w, 3)`` uint8 pictures, all the same size.
        labels: two text lines per tile.
        colors: ``[r, g, b]`` in 0..1 per tile (the swatch).
        columns: tiles per row; default about square.
    """
    if not tiles:
        raise ValueError("no tiles to lay out")
    height, width = tiles[0].shape[:2]
    count = len(tiles)
    columns = columns or max(1, math.ceil(math.sqrt(count)))
    rows = math.ceil(count / columns)
    font_size = int(min(16, max(9, width // 16)))
    line_height = font_size + 4
    label_height = 2 * line_height + 6
    cell_height = height + label_height
    grid = np.empty(
        (rows * cell_height + (rows + 1) * GRID_GAP, columns * width + (columns + 1) * GRID_GAP, 3), dtype=np.uint8
    )
    grid[:] = GRID_BACKGROUND
    swatch = line_height - 4
    for index, (tile, (line1, line2), color) in enumerate(zip(tiles, labels, colors)):
        row, column = divmod(index, columns)
        top = GRID_GAP + row * (cell_height + GRID_GAP)
        left = GRID_GAP + column * (width + GRID_GAP)
        grid[top : top + height, left : left + width] = tile
        strip = np.empty((label_height, width, 3), dtype=np.uint8)
        strip[:] = LABEL_BACKGROUND
        strip[4 : 4 + swatch, 4 : 4 + swatch] = np.round(255.0 * np.clip(np.asarray(color, float), 0, 1))
        draw_text(strip, line1, 8 + swatch, 3, font_size)
        draw_text(strip, line2, 4, 3 + line_height, font_size)
        grid[top + height : top + cell_height, left : left + width] = strip
    return grid
