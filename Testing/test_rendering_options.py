"""Tests of the renderer's options: Slicer's gradient backdrop, framing to the content, GPU ray casting and the
capture of VTK's warnings (the GPU ray caster's lookup-table fallback)."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

from isosimtf import read_errors, rendering

pytestmark = pytest.mark.skipif(
    not rendering.slicer_core_available(), reason="slicer-core (Slicer's Qt-free MRML libraries) is not installed"
)

SIZE = (96, 96)


def _cube(n: int = 32) -> np.ndarray:
    """Float volume [k, j, i]: 0 around a centred cube of 100 that spans the middle third."""
    values = np.zeros((n, n, n), dtype=np.float32)
    values[n // 3 : -n // 3, n // 3 : -n // 3, n // 3 : -n // 3] = 100.0
    return values


def _property(points, *, color=(1.0, 0.9, 0.7)):
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
    from vtkmodules.vtkRenderingCore import vtkColorTransferFunction, vtkVolumeProperty

    prop = vtkVolumeProperty()
    colors = vtkColorTransferFunction()
    colors.AddRGBPoint(0.0, *color)
    colors.AddRGBPoint(100.0, *color)
    opacity = vtkPiecewiseFunction()
    for value, alpha in points:
        opacity.AddPoint(value, alpha)
    prop.SetColor(colors)
    prop.SetScalarOpacity(opacity)
    return prop


SMOOTH = ((0.0, 0.0), (40.0, 0.0), (60.0, 1.0), (100.0, 1.0))
# Near-vertical step (1e-4 apart over a 0..100 range): the table it needs is wider than any OpenGL texture.
STEEP = ((0.0, 0.0), (50.0, 0.0), (50.0001, 1.0), (100.0, 1.0))


def _show(headless, values, points):
    volume_node = headless.add_volume(values)
    headless.show_volume(volume_node, headless.add_volume_property(_property(points)))
    return volume_node


def test_slicer_backdrop_is_the_default_view_gradient():
    with rendering.HeadlessSlicer(size=SIZE, background=None) as headless:
        backdrop = headless.backdrop().astype(int)
    bottom, top = backdrop[-1, SIZE[0] // 2], backdrop[0, SIZE[0] // 2]
    # Slicer's 3D view: light lavender at the bottom, darker blue at the top, blue dominant in both.
    assert bottom.sum() > top.sum() + 60
    assert bottom[2] > bottom[0] and top[2] > top[0]
    with rendering.HeadlessSlicer(size=SIZE) as headless:
        assert not headless.backdrop().any()  # black by default


def test_content_box_against_a_backdrop():
    backdrop = np.full((20, 30, 3), 100, dtype=np.uint8)
    picture = backdrop.copy()
    picture[5:9, 10:21] = 200
    assert rendering.content_box(picture, backdrop) == (5, 8, 10, 20)
    assert rendering.content_box(backdrop, backdrop) is None


def test_framed_render_fills_the_picture_with_a_margin():
    with rendering.HeadlessSlicer(size=SIZE, background=None) as headless:
        _show(headless, _cube(), SMOOTH)
        loose = headless.render("anterior")
        backdrop = headless.backdrop()
        framed = headless.render("anterior", frame=True)
        again = headless.render("left")  # a reset camera forgets the framing
    side = lambda box: max(box[1] - box[0], box[3] - box[2]) + 1  # noqa: E731
    loose_side = side(rendering.content_box(loose, backdrop))
    framed_box = rendering.content_box(framed, backdrop)
    assert loose_side < 0.8 * SIZE[0]
    assert side(framed_box) >= 0.85 * SIZE[0]  # margin 4 %, and a narrower view angle flattens the perspective
    assert min(framed_box[0], framed_box[2]) >= 0  # still inside the picture
    assert side(rendering.content_box(again, backdrop)) < 0.8 * SIZE[0]


def test_split_vtk_messages_drops_heads_and_object_ids():
    text = (
        "Warning: In vtkOpenGLVolumeLookupTable.cxx, line 73\n"
        "vtkOpenGLVolumeRGBTable (0x55d): This OpenGL implementation does not support the required texture size of "
        "1048576, falling back to maximum allowed, 16384.\n\n\n"
        "ERROR: In vtkSomething.cxx, line 9\nvtkSomething (0x1): broken\n\n"
    )
    messages = read_errors.split_vtk_messages(text)
    assert messages[1] == "broken"
    assert messages[0].startswith("This OpenGL implementation")
    assert rendering.lookup_table_fallbacks(messages) == [messages[0]]


def test_gpu_ray_casting_logs_the_lookup_table_fallback_only_for_near_vertical_steps():
    results = {}
    try:
        for name, points in (("smooth", SMOOTH), ("steep", STEEP)):
            with rendering.HeadlessSlicer(size=(64, 64), rendering_method="gpu") as headless:
                _show(headless, _cube(), points)
                with rendering.captured_vtk_messages() as messages:
                    picture = headless.render("anterior")
                results[name] = (picture, rendering.lookup_table_fallbacks(messages))
    except RuntimeError as error:  # pragma: no cover - no OpenGL here
        pytest.skip(f"GPU ray casting is not available: {error}")
    assert results["smooth"][0].any()  # the GPU ray caster renders headless
    assert results["smooth"][1] == []
    assert results["steep"][1], "a near-vertical step should make VTK fall back to a narrower lookup table"
    # The width VTK asked for is the one lookup_table_width predicts without rendering.
    predicted = rendering.lookup_table_width(_property(STEEP), (0.0, 100.0))
    assert predicted > rendering.LOOKUP_TABLE_LIMIT
    assert f"texture size of {predicted}," in results["steep"][1][0]
    assert rendering.lookup_table_width(_property(SMOOTH), (0.0, 100.0)) <= rendering.LOOKUP_TABLE_LIMIT


def test_cli_render_png_is_framed_and_takes_the_slicer_backdrop(tmp_path):
    from test_cli import read_png

    from isosimtf import cli

    status = cli.main(
        ["phantom", "-o", str(tmp_path), "--phantom-size", "32", "--size", "96", "-q", "--backdrop", "slicer"]
    )
    assert status == 0
    picture = read_png(tmp_path / "render.png")[..., :3]
    corner = picture[0, 0].astype(int)
    assert corner[2] > corner[0] + 30  # Slicer's blue backdrop, not black
    with rendering.HeadlessSlicer(size=(96, 96), background=None) as headless:
        backdrop = headless.backdrop()
    row0, row1, column0, column1 = rendering.content_box(picture, backdrop, threshold=25)
    assert max(row1 - row0, column1 - column0) + 1 >= 0.85 * 96  # the head fills the picture


def test_cli_rejects_an_unknown_backdrop(capsys):
    from isosimtf import cli

    assert cli.main(["phantom", "-o", "unused", "--backdrop", "white"]) == cli.EXIT_USAGE
    assert "--backdrop" in capsys.readouterr().err


def test_backdrop_follows_the_render_window_size():
    for background in ((0.0, 0.0, 0.0), None):
        with rendering.HeadlessSlicer(size=SIZE, background=background) as headless:
            headless.render_window.SetSize(40, 30)
            assert headless.backdrop().shape == (30, 40, 3)
