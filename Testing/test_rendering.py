"""Tests of isosimtf.rendering: Slicer's own volume rendering in a headless, off-screen 3D view."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

from isosimtf import rendering

LIB_DIR = Path(rendering.__file__).resolve().parents[1]

needs_slicer = pytest.mark.skipif(
    not rendering.slicer_core_available(),
    reason="slicer-core (PyPI package of Slicer's Qt-free MRML libraries) is not installed: pip install slicer-core",
)

SIZE = (160, 120)  # (width, height) in pixels: small pictures keep the tests fast


def _phantom(n: int = 48) -> np.ndarray:
    """Float volume [k, j, i]: background 0, a cube of 100 with a sphere of 200 inside."""
    k, j, i = np.mgrid[:n, :n, :n].astype(np.float32)
    centre = (n - 1) / 2.0
    values = np.zeros((n, n, n), dtype=np.float32)
    values[8:-8, 8:-8, 8:-8] = 100.0
    values[(i - centre) ** 2 + (j - centre) ** 2 + (k - centre) ** 2 < 10.0**2] = 200.0
    return values


def _volume_property(opacity_points, color=(1.0, 0.8, 0.2)):
    """vtkVolumeProperty with a constant colour and the given (value, opacity) points."""
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
    from vtkmodules.vtkRenderingCore import vtkColorTransferFunction, vtkVolumeProperty

    prop = vtkVolumeProperty()
    colors = vtkColorTransferFunction()
    colors.AddRGBPoint(0.0, *color)
    colors.AddRGBPoint(200.0, *color)
    prop.SetColor(colors)
    opacity = vtkPiecewiseFunction()  # a new property's default opacity function already holds points
    for value, alpha in opacity_points:
        opacity.AddPoint(value, alpha)
    prop.SetScalarOpacity(opacity)
    prop.SetInterpolationTypeToLinear()
    return prop


OPAQUE = ((0.0, 0.0), (50.0, 0.0), (90.0, 1.0), (200.0, 1.0))  # cube and sphere
SPHERE_ONLY = ((0.0, 0.0), (150.0, 0.0), (190.0, 1.0), (200.0, 1.0))
TRANSPARENT = ((0.0, 0.0), (200.0, 0.0))


def _foreground(rgb: np.ndarray) -> int:
    """Number of pixels that differ from the (black) background."""
    return int(np.count_nonzero(rgb.max(axis=2) > 8))


def test_module_imports_without_slicer_core():
    """Importing the module never imports slicer-core; using it without slicer-core raises a clear RuntimeError."""
    code = (
        "import sys\n"
        "import isosimtf.rendering as r\n"
        "assert 'slicer' not in sys.modules and 'slicer_core' not in sys.modules\n"
        "sys.modules['slicer'] = None\n"  # makes `import slicer` fail as if slicer-core were not installed
        "try:\n"
        "    r.HeadlessSlicer()\n"
        "except RuntimeError as exc:\n"
        "    assert 'slicer-core' in str(exc), exc\n"
        "else:\n"
        "    raise SystemExit('no RuntimeError')\n"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(LIB_DIR), os.environ.get("PYTHONPATH", "")]))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr


@needs_slicer
def test_opaque_and_transparent_transfer_functions_differ():
    with rendering.HeadlessSlicer(size=SIZE) as headless:
        volume_node = headless.add_volume(_phantom(), spacing=(1.0, 1.0, 1.0), name="Phantom")
        counts = {}
        pictures = {}
        for name, points in (("opaque", OPAQUE), ("sphere", SPHERE_ONLY), ("transparent", TRANSPARENT)):
            property_node = headless.add_volume_property(_volume_property(points), name=name)
            display_node = headless.show_volume(volume_node, property_node)
            assert display_node.GetVolumePropertyNode() is property_node
            pictures[name] = headless.render("anterior")
            counts[name] = _foreground(pictures[name])
    height, width = SIZE[1], SIZE[0]
    assert pictures["opaque"].shape == (height, width, 3)
    assert pictures["opaque"].dtype == np.uint8
    assert counts["transparent"] == 0
    # the cube covers a good part of the picture, the sphere inside it less, nothing shows through a transparent TF
    assert counts["opaque"] > 0.1 * width * height
    assert 0.02 * width * height < counts["sphere"] < 0.8 * counts["opaque"]
    # the colour of the transfer function is what shows (yellow-orange: red > blue)
    visible = pictures["opaque"][pictures["opaque"].max(axis=2) > 8].astype(int)
    assert np.mean(visible[:, 0]) > np.mean(visible[:, 2])


@needs_slicer
def test_rendered_volume_uses_property_node_volume_property():
    with rendering.HeadlessSlicer(size=SIZE) as headless:
        volume_node = headless.add_volume(_phantom())
        property_node = headless.add_volume_property(_volume_property(OPAQUE), name="TF")
        display_node = headless.show_volume(volume_node, property_node)
        assert display_node.IsA(rendering.DEFAULT_RENDERING_METHOD)
        headless.render()
        actor = headless.get_volume_actor(volume_node)
        assert actor is not None
        assert actor.GetProperty() is property_node.GetVolumeProperty()
        assert any(volume.GetProperty() is property_node.GetVolumeProperty() for volume in headless.rendered_volumes())
        # the copy holds our transfer function, in the volume's units
        opacity = property_node.GetVolumeProperty().GetScalarOpacity()
        assert opacity.GetValue(200.0) == pytest.approx(1.0)
        assert opacity.GetValue(10.0) == pytest.approx(0.0)


@needs_slicer
def test_uint8_volume_through_create_default_volume_rendering_nodes():
    values = (_phantom() > 150).astype(np.uint8) * 200
    with rendering.HeadlessSlicer(size=SIZE) as headless:
        volume_node = headless.add_volume(values, spacing=(0.5, 0.5, 0.8), name="Mask")
        logic = headless.volume_rendering_logic
        assert logic.GetFirstVolumeRenderingDisplayNode(volume_node) is None
        display_node = logic.CreateDefaultVolumeRenderingNodes(volume_node)  # Slicer copies "US-Fetal" for uint8
        assert display_node is not None
        assert display_node.GetVolumePropertyNode() is not None
        assert headless.show_volume(volume_node) is display_node
        picture = headless.render("left")
        assert _foreground(picture) > 0.01 * SIZE[0] * SIZE[1]


@needs_slicer
def test_no_temporary_presets_folder_outlives_loading_the_presets(tmp_path, monkeypatch):
    # A render process killed mid-render (the CLI's watchdog, out of memory) cannot clean up: nothing may be left.
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with rendering.HeadlessSlicer(size=SIZE) as headless:
        assert list(tmp_path.iterdir()) == []
        volume_node = headless.add_volume((_phantom() > 150).astype(np.uint8) * 200)
        display_node = headless.volume_rendering_logic.CreateDefaultVolumeRenderingNodes(volume_node)
        assert display_node.GetVolumePropertyNode().GetName() == "US-Fetal"  # read from the folder now gone


@needs_slicer
def test_view_directions_follow_ras_axes():
    """A slab long along x (R-L) looks wide from the front and narrow from the side."""
    values = np.zeros((24, 24, 48), dtype=np.float32)  # [k, j, i]
    values[8:16, 8:16, 4:44] = 200.0
    with rendering.HeadlessSlicer(size=(120, 120)) as headless:
        volume_node = headless.add_volume(values)
        headless.show_volume(volume_node, headless.add_volume_property(_volume_property(OPAQUE)))
        widths = {}
        for view in ("anterior", "left", "superior"):
            columns = np.flatnonzero(headless.render(view).max(axis=(0, 2)) > 8)
            widths[view] = columns[-1] - columns[0] + 1 if columns.size else 0
        with pytest.raises(ValueError):
            headless.render("sideways")
    assert widths["anterior"] > 2 * widths["left"] > 0
    assert widths["superior"] > 2 * widths["left"]


@needs_slicer
def test_scene_clear_after_render_and_close():
    headless = rendering.HeadlessSlicer(size=SIZE)
    volume_node = headless.add_volume(_phantom())
    headless.show_volume(volume_node, headless.add_volume_property(_volume_property(OPAQUE)))
    assert _foreground(headless.render()) > 0
    headless.scene.Clear(0)  # what File / Close scene does in Slicer
    assert headless.scene.GetNodesByClass("vtkMRMLScalarVolumeNode").GetNumberOfItems() == 0
    assert _foreground(headless.render()) == 0
    # the harness still works after a clear
    volume_node = headless.add_volume(_phantom())
    headless.show_volume(volume_node, headless.add_volume_property(_volume_property(OPAQUE)))
    assert _foreground(headless.render()) > 0
    headless.close()
    headless.close()  # idempotent
    assert headless.scene is None
    with pytest.raises(RuntimeError):
        headless.render()
    del volume_node  # dropping the last reference after close must not crash either


@needs_slicer
def test_render_volume_and_write_png(tmp_path):
    from vtkmodules.util import numpy_support
    from vtkmodules.vtkIOImage import vtkPNGReader

    prop = _volume_property(OPAQUE)
    picture = rendering.render_volume(_phantom(), (1.0, 1.0, 1.0), prop, size=(64, 48), view="superior")
    assert picture.shape == (48, 64, 3)
    assert _foreground(picture) > 0
    # the caller's property is untouched
    assert prop.GetScalarOpacity().GetSize() == len(OPAQUE)

    path = tmp_path / "sub" / "render.png"
    rendering.write_png(picture, path)
    reader = vtkPNGReader()
    reader.SetFileName(str(path))
    reader.Update()
    image = reader.GetOutput()
    width, height, _ = image.GetDimensions()
    back = numpy_support.vtk_to_numpy(image.GetPointData().GetScalars()).reshape(height, width, -1)[::-1]
    np.testing.assert_array_equal(back, picture)
    with pytest.raises(ValueError):
        rendering.write_png(picture.astype(np.float32), path)


def test_a_png_on_a_full_disk_is_one_error_without_library_dumps(tmp_path: Path) -> None:
    """Issue 18, item 10: a full disk printed VTK's and libpng's own dumps on stderr. The disk is "full" after 4 KB
    here: a child process with a file size limit (RLIMIT_FSIZE, its SIGXFSZ ignored), so every larger write fails."""
    import subprocess
    import sys

    script = f"""
import resource, signal
import numpy as np
from isosimtf import rendering
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
noise = np.random.default_rng(0).integers(0, 256, (256, 256, 3), dtype=np.uint8)  # does not compress to 4 KB
try:
    rendering.write_png(noise, {str(tmp_path / "big.png")!r})
except OSError as error:
    print("OSError:", error)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.stdout.startswith("OSError: could not write PNG"), done.stdout + done.stderr
    assert done.stderr == ""
