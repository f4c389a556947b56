"""The Slicer module's self-test checks (IsoSimilarityTFLib.selftest), run here on a real headless MRML scene
(slicer-core) with the same Qt-free session class the module's logic is made of: what "Reload and Test" runs in Slicer
runs in ``make test`` too, so a broken self-test cannot hide."""

import ast
from pathlib import Path

import pytest

from IsoSimilarityTFLib import selftest
from IsoSimilarityTFLib.session import DesignSession

MODULE_FILE = Path(__file__).resolve().parents[1] / "IsoSimilarityTF" / "IsoSimilarityTF.py"


@pytest.fixture()
def harness(slicer_app):
    def new_session():
        return DesignSession(slicer_app.volume_rendering_logic)

    def add_volume(values, spacing, name):
        return slicer_app.add_volume(values, spacing=spacing, name=name)

    return new_session, add_volume


@pytest.mark.parametrize("name", list(selftest.CHECKS))
def test_module_selftest_check(name, harness):
    selftest.CHECKS[name](*harness)


def test_the_module_test_class_runs_every_check():
    tree = ast.parse(MODULE_FILE.read_text(encoding="utf-8"))
    test_class = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "IsoSimilarityTFTest")
    methods = {f.name: f for f in test_class.body if isinstance(f, ast.FunctionDef)}
    for name in selftest.CHECKS:
        method = methods.get(f"test_IsoSimilarityTF_{name}")
        assert method is not None, f"the module's Test class has no test_IsoSimilarityTF_{name}"
        constants = {n.value for n in ast.walk(method) if isinstance(n, ast.Constant)}
        assert name in constants, f"test_IsoSimilarityTF_{name} does not run the check {name!r}"
