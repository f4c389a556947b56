"""Shared fixtures: a real, headless Slicer (MRML scene, volume rendering logic, off-screen 3D view)."""

import os

import pytest

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

from isosimtf import rendering


@pytest.fixture()
def slicer_app():
    """A fresh :class:`HeadlessSlicer` with small pictures; skipped when slicer-core is not installed."""
    if not rendering.slicer_core_available():
        pytest.skip("slicer-core (Slicer's Qt-free MRML libraries from PyPI) is not installed")
    with rendering.HeadlessSlicer(size=(160, 160)) as app:
        yield app
