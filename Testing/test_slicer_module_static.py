"""Static checks of the Slicer module and extension files, without Slicer: build lists, .ui bindings, imports, tests,
catalog entry, icons and Python 3.9 grammar."""

import ast
import importlib.util
import json
import os
import re
import struct
import sys
import sysconfig
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from IsoSimilarityTFLib.options import OPTIONS
from IsoSimilarityTFLib.panel import PANEL_OPTIONS

ROOT = Path(__file__).resolve().parents[1]
MODULE_DIR = ROOT / "IsoSimilarityTF"
MODULE_FILE = MODULE_DIR / "IsoSimilarityTF.py"
LIB_DIR = MODULE_DIR / "IsoSimilarityTFLib"
UI_FILE = MODULE_DIR / "Resources" / "UI" / "IsoSimilarityTF.ui"
CATALOG_FILE = ROOT / "IsoSimilarityTF.json"

# Modules Slicer's Python has besides the standard library.
SLICER_TOP_LEVEL_MODULES = {"slicer", "qt", "ctk", "vtk", "vtkmodules", "numpy", "IsoSimilarityTFLib"}
# Imported only for input Slicer never gives (a dask array: volumes larger than memory, from the command line).
COMMAND_LINE_ONLY_MODULES = {"dask", "distributed"}
# Widget classes the parameter node wrapper can bind to each parameter type (Slicer's guiConnectors).
BINDABLE_WIDGETS = {
    "int": {"QSpinBox", "QSlider"},
    "float": {"QDoubleSpinBox", "ctkSliderWidget", "qMRMLSliderWidget", "ctkDoubleSpinBox", "ctkDoubleSlider"},
    "bool": {"QCheckBox", "ctkCheckBox", "QPushButton"},
    "choice": {"QComboBox", "ctkComboBox"},
    "node": {"qMRMLNodeComboBox"},
}
# Choice parameters that offer more than the engine option's words ("number": the preference is preferenceValue).
EXTRA_CHOICES = {"preference": {"number"}, "modality": {"auto"}}
# Parameter node field -> engine option whose table entry gives its range or choices and its default (the panel's own
# mapping, which test_module_widget.py checks option by option).
ENGINE_OPTIONS = PANEL_OPTIONS
# Fields whose default stands for the engine option's default in the field's own type: levels 0 is None (all levels),
# tissues AUTO_DETAIL (0) is "auto", modality "auto" is None (detected).
SPECIAL_DEFAULTS = {"levels": "0", "tissues": "AUTO_DETAIL", "modality": "'auto'"}


def _module_tree() -> ast.Module:
    return ast.parse(MODULE_FILE.read_text(encoding="utf-8"))


def _class(tree: ast.Module, name: str) -> ast.ClassDef:
    found = [node for node in tree.body if isinstance(node, ast.ClassDef) and node.name == name]
    assert found, f"class {name} not found in {MODULE_FILE.name}"
    return found[0]


def _decorator_names(node: ast.ClassDef) -> set:
    names = set()
    for decorator in node.decorator_list:
        target = decorator.func if isinstance(decorator, ast.Call) else decorator
        names.add(target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", None))
    return names


def _parameter_fields() -> dict:
    """Annotated fields of the @parameterNodeWrapper class: name -> (annotation node, default node or None)."""
    tree = _module_tree()
    wrappers = [
        node
        for node in tree.body
        if isinstance(node, ast.ClassDef) and "parameterNodeWrapper" in _decorator_names(node)
    ]
    assert len(wrappers) == 1, "expected exactly one @parameterNodeWrapper class"
    return {
        statement.target.id: (statement.annotation, statement.value)
        for statement in wrappers[0].body
        if isinstance(statement, ast.AnnAssign) and isinstance(statement.target, ast.Name)
    }


def _annotation_kind(annotation: ast.expr) -> tuple:
    """("int" | "float" | "bool" | "choice" | "node", choices or None) of a field annotation."""
    choices = None
    base = annotation
    if isinstance(annotation, ast.Subscript) and getattr(annotation.value, "id", None) == "Annotated":
        elements = annotation.slice.elts
        base = elements[0]
        for extra in elements[1:]:
            if isinstance(extra, ast.Call) and getattr(extra.func, "id", None) == "_choice":
                option, *more = (ast.literal_eval(a) for a in extra.args)
                choices = [*OPTIONS[option].choices, *more]
    name = getattr(base, "id", None)
    if choices is not None:
        return "choice", choices
    if name and name.startswith("vtkMRML"):
        return "node", None
    return name, None


def _cmake_list(path: Path, variable: str) -> list:
    text = path.read_text(encoding="utf-8")
    match = re.search(rf"set\(\s*{variable}\s+(.*?)\)", text, re.S)
    assert match, f"{variable} not set in {path}"
    module_name = re.search(r"set\(\s*MODULE_NAME\s+(\S+)\s*\)", text).group(1)
    return [item.replace("${MODULE_NAME}", module_name) for item in match.group(1).split()]


def _ui_root() -> ET.Element:
    return ET.parse(UI_FILE).getroot()


def _ui_bindings() -> dict:
    """SlicerParameterName -> widget element."""
    bindings = {}
    for widget in _ui_root().iter("widget"):
        for prop in widget.findall("property"):
            if prop.get("name") == "SlicerParameterName":
                name = prop.findtext("string")
                assert name not in bindings, f"parameter {name} bound to two widgets"
                bindings[name] = widget
    return bindings


# Build lists --------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("variable", ["MODULE_PYTHON_SCRIPTS", "MODULE_PYTHON_RESOURCES"])
def test_every_file_listed_in_the_module_cmakelists_exists(variable):
    listed = _cmake_list(MODULE_DIR / "CMakeLists.txt", variable)
    assert listed
    missing = [item for item in listed if not (MODULE_DIR / item).is_file()]
    assert not missing, f"listed in IsoSimilarityTF/CMakeLists.txt but missing: {missing}"


def test_every_lib_script_and_resource_is_listed():
    scripts = set(_cmake_list(MODULE_DIR / "CMakeLists.txt", "MODULE_PYTHON_SCRIPTS"))
    present = {f"IsoSimilarityTFLib/{path.name}" for path in LIB_DIR.glob("*.py")}
    assert "IsoSimilarityTF.py" in scripts
    assert not present - scripts, f"Lib scripts not installed with the module: {sorted(present - scripts)}"
    resources = set(_cmake_list(MODULE_DIR / "CMakeLists.txt", "MODULE_PYTHON_RESOURCES"))
    assert {"Resources/Icons/IsoSimilarityTF.png", "Resources/UI/IsoSimilarityTF.ui"} <= resources


def test_module_cmakelists_builds_a_tested_scripted_module():
    text = (MODULE_DIR / "CMakeLists.txt").read_text(encoding="utf-8")
    assert re.search(r"slicerMacroBuildScriptedModule\((.*?)WITH_GENERIC_TESTS", text, re.S)
    assert re.search(
        r"if\(BUILD_TESTING\)\s*(#[^\n]*\n\s*)*slicer_add_python_unittest\(SCRIPT \$\{MODULE_NAME\}\.py\)", text
    )


def test_top_level_cmakelists():
    text = (ROOT / "CMakeLists.txt").read_text(encoding="utf-8")
    assert re.match(r"cmake_minimum_required\(VERSION \d+\.\d+\.\d+\.\.\.\d+\.\d+\.\d+ FATAL_ERROR\)", text)
    assert re.search(r"^project\(IsoSimilarityTF\)", text, re.M)
    for variable in ("HOMEPAGE", "CATEGORY", "CONTRIBUTORS", "DESCRIPTION", "ICONURL", "SCREENSHOTURLS", "DEPENDS"):
        assert re.search(rf'set\(EXTENSION_{variable} "[^"]+"\)', text), f"EXTENSION_{variable} missing"
    order = [
        "find_package(Slicer REQUIRED)",
        "include(${Slicer_USE_FILE})",
        "add_subdirectory(IsoSimilarityTF)",
        "include(${Slicer_EXTENSION_GENERATE_CONFIG})",
        "include(${Slicer_EXTENSION_CPACK})",
    ]
    positions = [text.find(line) for line in order]
    assert -1 not in positions and positions == sorted(positions)
    icon_url = re.search(r'set\(EXTENSION_ICONURL "([^"]+)"\)', text).group(1)
    assert icon_url.endswith("/Resources/IsoSimilarityTF.png")


# .ui file and parameter node ----------------------------------------------------------------------------------------
def test_ui_is_a_qmrmlwidget_with_the_scene_connected_to_node_selectors():
    root = _ui_root()
    assert root.tag == "ui"
    top = root.find("widget")
    assert top.get("class") == "qMRMLWidget"
    selectors = {w.get("name") for w in top.iter("widget") if w.get("class") == "qMRMLNodeComboBox"}
    assert selectors
    connected = {
        c.findtext("receiver")
        for c in root.iter("connection")
        if c.findtext("sender") == top.get("name")
        and c.findtext("signal") == "mrmlSceneChanged(vtkMRMLScene*)"
        and c.findtext("slot") == "setMRMLScene(vtkMRMLScene*)"
    }
    assert selectors <= connected
    custom = {c.findtext("class") for c in root.iter("customwidget")}
    used = {w.get("class") for w in top.iter("widget")} | {top.get("class")}
    assert {name for name in used if name.startswith(("ctk", "qMRML"))} <= custom


def test_ui_widget_names_are_unique():
    names = [w.get("name") for w in _ui_root().iter("widget")]
    assert len(names) == len(set(names))


def test_ui_bindings_equal_the_parameter_node_fields():
    assert set(_ui_bindings()) == set(_parameter_fields())


def test_each_bound_widget_can_represent_its_parameter_type():
    fields = _parameter_fields()
    for name, widget in _ui_bindings().items():
        kind, _ = _annotation_kind(fields[name][0])
        assert kind in BINDABLE_WIDGETS, f"{name}: unexpected annotation kind {kind}"
        assert widget.get("class") in BINDABLE_WIDGETS[kind], f"{name}: {widget.get('class')} cannot show a {kind}"


def _table_option(check: ast.expr) -> str:
    """The options-table entry a field's check is made from: ``_withinRange("n_bins")`` -> ``"n_bins"``."""
    assert isinstance(check, ast.Call) and getattr(check.func, "id", None) in ("_withinRange", "_choice"), (
        f"{ast.unparse(check)} is not made from the options table"
    )
    return ast.literal_eval(check.args[0])


def test_engine_parameters_take_their_checks_and_defaults_from_the_options_table():
    fields = _parameter_fields()
    for name, option in ENGINE_OPTIONS.items():
        annotation, default = fields[name]
        assert _table_option(annotation.slice.elts[1]) == option, name
        if name in SPECIAL_DEFAULTS:
            assert ast.unparse(default) == SPECIAL_DEFAULTS[name], name
            engine_default = OPTIONS[option].default
            assert engine_default is None or engine_default == "auto", name
        else:
            assert ast.unparse(default) == f"_default({option!r})", name


def test_choice_parameters_offer_the_engine_words():
    fields = _parameter_fields()
    for name, option in ENGINE_OPTIONS.items():
        kind, choices = _annotation_kind(fields[name][0])
        if name == "tissues":  # the Detail slider: an integer whose 0 is "auto" and whose top is "all"
            assert kind == "int"
        elif OPTIONS[option].choices:
            assert kind == "choice" and set(choices) == set(OPTIONS[option].choices) | EXTRA_CHOICES.get(name, set())


def test_every_ui_widget_the_module_uses_exists():
    used = set()
    for node in ast.walk(_module_tree()):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Attribute)
            and node.value.attr == "ui"
            and isinstance(node.value.value, ast.Name)
            and node.value.value.id in {"self", "widget"}
        ):
            used.add(node.attr)
    names = {w.get("name") for w in _ui_root().iter("widget")}
    assert used, "the module uses no ui widget?"
    assert not used - names, f"widgets used by the module but missing from the .ui: {sorted(used - names)}"


def test_ui_loaded_from_resources_and_bound_through_the_parameter_node():
    source = MODULE_FILE.read_text(encoding="utf-8")
    assert 'slicer.util.loadUI(self.resourcePath("UI/IsoSimilarityTF.ui"))' in source
    assert "slicer.util.childWidgetVariables(" in source
    assert "connectGui(self.ui)" in source
    assert 'tryWithErrorDisplay(_("Failed to compute the transfer function."), waitCursor=True)' in source


# Module source ------------------------------------------------------------------------------------------------------
def test_module_has_the_four_scripted_module_classes():
    tree = _module_tree()
    bases = {
        "IsoSimilarityTF": "ScriptedLoadableModule",
        "IsoSimilarityTFWidget": "ScriptedLoadableModuleWidget",
        "IsoSimilarityTFLogic": "ScriptedLoadableModuleLogic",
        "IsoSimilarityTFTest": "ScriptedLoadableModuleTest",
    }
    for name, base in bases.items():
        assert base in {getattr(b, "id", None) for b in _class(tree, name).bases}, name
    assert "VTKObservationMixin" in {getattr(b, "id", None) for b in _class(tree, "IsoSimilarityTFWidget").bases}


def _is_standard_library(name: str) -> bool:
    """Whether a top-level module comes with Python (works on 3.9, which has no ``sys.stdlib_module_names``)."""
    if name in sys.builtin_module_names:
        return True
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None:
        return False
    if spec.origin in ("built-in", "frozen"):
        return True
    origin = os.path.realpath(spec.origin)
    folders = {os.path.realpath(sysconfig.get_paths()[key]) for key in ("stdlib", "platstdlib")}
    return "site-packages" not in origin and any(origin.startswith(folder + os.sep) for folder in folders)


def test_standard_library_check_knows_its_modules():
    assert all(_is_standard_library(name) for name in ("os", "sys", "functools", "json", "logging", "typing"))
    assert not any(_is_standard_library(name) for name in ("numpy", "pytest", "IsoSimilarityTFLib", "no_such_module"))


def test_module_imports_only_what_slicer_has_at_top_level():
    for node in _module_tree().body:
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, "relative import in a Slicer module"
            names = [node.module]
        else:
            continue
        for name in names:
            top = name.split(".")[0]
            assert top in SLICER_TOP_LEVEL_MODULES or _is_standard_library(top), f"top-level import of {name}"


def _imports(path: Path) -> list:
    """Top-level names of every module ``path`` imports, in functions too (relative imports excluded)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names += [alias.name.split(".")[0] for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names.append(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("path", [MODULE_FILE, *sorted(LIB_DIR.glob("*.py"))], ids=lambda p: p.name)
def test_the_module_needs_nothing_slicer_does_not_ship(path):
    """Slicer ships numpy and VTK, never scikit-learn: nothing to install, not even lazily at Apply time."""
    allowed = SLICER_TOP_LEVEL_MODULES | COMMAND_LINE_ONLY_MODULES
    for name in _imports(path):
        assert name in allowed or _is_standard_library(name), f"{path.name} imports {name}"
    # Nor by name (importlib, find_spec, sys.modules, pip, a message): any string but a docstring.
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef)) and ast.get_docstring(node) is not None
    }
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            assert not re.search(r"sklearn|scikit", node.value, re.I), f"{path.name}: {node.value!r}"


def test_run_test_calls_every_test_method():
    test_class = _class(_module_tree(), "IsoSimilarityTFTest")
    methods = {f.name for f in test_class.body if isinstance(f, ast.FunctionDef) and f.name.startswith("test_")}
    assert methods
    run_test = next(f for f in test_class.body if isinstance(f, ast.FunctionDef) and f.name == "runTest")
    called = {
        node.attr
        for node in ast.walk(run_test)
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "self"
    }
    assert methods <= called, f"runTest does not call {sorted(methods - called)}"


def test_module_tests_download_nothing():
    source = ast.get_source_segment(
        MODULE_FILE.read_text(encoding="utf-8"), _class(_module_tree(), "IsoSimilarityTFTest")
    )
    for word in ("SampleData", "urllib", "downloadSample", "http://", "https://"):
        assert word not in source


@pytest.mark.parametrize("path", [MODULE_FILE, *sorted(LIB_DIR.glob("*.py"))], ids=lambda p: p.name)
def test_python_3_9_grammar(path):
    ast.parse(path.read_text(encoding="utf-8"), filename=str(path), feature_version=(3, 9))


def test_no_postponed_annotations_in_the_module():
    # The parameter node wrapper reads annotations at run time: "from __future__ import annotations" breaks it.
    for node in _module_tree().body:
        if isinstance(node, ast.ImportFrom) and node.module == "__future__":
            assert "annotations" not in {alias.name for alias in node.names}


# Catalog entry, resources -------------------------------------------------------------------------------------------
def test_catalog_entry():
    entry = json.loads(CATALOG_FILE.read_text(encoding="utf-8"))
    assert entry["$schema"] == (
        "https://raw.githubusercontent.com/Slicer/Slicer/main/Schemas/slicer-extension-catalog-entry-schema-v1.0.1.json#"
    )
    for key in ("$schema", "category", "scm_url", "scm_revision", "build_dependencies"):
        assert key in entry, key
    allowed = {
        "$schema": str,
        "category": str,
        "scm_url": str,
        "scm_revision": str,
        "scm_type": str,
        "build_dependencies": list,
        "build_subdirectory": str,
        "enabled": bool,
        "tier": int,
    }
    assert set(entry) <= set(allowed), f"not in schema v1.0.1: {set(entry) - set(allowed)}"
    for key, value in entry.items():
        assert isinstance(value, allowed[key]), key
    assert entry["category"] == "Rendering"
    assert entry["scm_url"].startswith("https://github.com/")
    assert 1 <= entry.get("tier", 1) <= 5
    cmake = (ROOT / "CMakeLists.txt").read_text(encoding="utf-8")
    assert f'set(EXTENSION_CATEGORY "{entry["category"]}")' in cmake
    homepage = re.search(r'set\(EXTENSION_HOMEPAGE "([^"]+)"\)', cmake).group(1)
    assert entry["scm_url"].removesuffix(".git") == homepage


@pytest.mark.parametrize(
    "path", [MODULE_DIR / "Resources" / "Icons" / "IsoSimilarityTF.png", ROOT / "Resources" / "IsoSimilarityTF.png"]
)
def test_icons_are_128_pixel_pngs(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    assert (width, height) == (128, 128)


def test_no_python_requirements_to_install():
    assert not (MODULE_DIR / "Resources" / "requirements.txt").exists()


def test_tissue_tree_columns_match_the_module():
    table = next(w for w in _ui_root().iter("widget") if w.get("name") == "tissuesTreeWidget")
    assert table.get("class") == "QTreeWidget"
    columns = [c.findtext("property/string") for c in table.findall("column")]
    assignment = next(
        node
        for node in _module_tree().body
        if isinstance(node, ast.Assign)
        and isinstance(node.targets[0], ast.Tuple)
        and all(isinstance(e, ast.Name) and e.id.startswith("COLUMN_") for e in node.targets[0].elts)
    )
    assert len(columns) == len(assignment.targets[0].elts) == ast.literal_eval(assignment.value.args[0])
    assert all(columns)


# Values the module's own tests write into the parameter node ----------------------------------------------------------
def _field_check(annotation: ast.expr):
    """(minimum, maximum, choices) the parameter node wrapper validates a field with."""
    choices = _annotation_kind(annotation)[1]
    if choices is not None:
        return None, None, set(choices)
    for extra in annotation.slice.elts[1:] if isinstance(annotation, ast.Subscript) else []:
        if isinstance(extra, ast.Call) and getattr(extra.func, "id", None) == "_withinRange":
            entry = OPTIONS[ast.literal_eval(extra.args[0])]
            keywords = {k.arg: _constant(k.value) for k in extra.keywords}
            return keywords.get("minimum", entry.minimum), entry.maximum, None
        if isinstance(extra, ast.Call) and getattr(extra.func, "id", None) == "WithinRange":
            low, high = (ast.literal_eval(a) for a in extra.args)
            return low, high, None
    return None, None, None


def _constant(node: ast.expr):
    """A literal, or a constant the module imports from the library (AUTO_DETAIL)."""
    if isinstance(node, ast.Name):
        from IsoSimilarityTFLib import session

        return getattr(session, node.id)
    return ast.literal_eval(node)


def test_module_tests_write_only_valid_values_into_the_parameter_node():
    """The wrapper validates every write (a ValueError in Slicer): ``levels = 99`` once broke the self-test."""
    fields = _parameter_fields()
    test_class = _class(_module_tree(), "IsoSimilarityTFTest")
    writes = 0
    for node in ast.walk(test_class):
        if not isinstance(node, ast.Assign):
            continue
        for target in node.targets:
            if not (isinstance(target, ast.Attribute) and target.attr in fields):
                continue
            owner = target.value
            owner_name = owner.attr if isinstance(owner, ast.Attribute) else getattr(owner, "id", "")
            if "parameterNode" not in owner_name and "ParameterNode" not in owner_name:
                continue
            try:
                value = ast.literal_eval(node.value)
            except ValueError:
                continue  # a node or a computed value
            writes += 1
            low, high, choices = _field_check(fields[target.attr][0])
            if choices is not None:
                assert value in choices, f"{target.attr} = {value!r} is not one of {sorted(choices)}"
            if low is not None:
                assert low <= value <= high, f"{target.attr} = {value!r} is outside [{low}, {high}]"
    assert writes >= 5


def test_every_choice_has_a_readable_label():
    function = next(n for n in _module_tree().body if isinstance(n, ast.FunctionDef) and n.name == "choiceLabels")
    returned = next(n for n in ast.walk(function) if isinstance(n, ast.Return)).value
    labels = {
        ast.literal_eval(key): {ast.literal_eval(k): v for k, v in zip(value.keys, value.values)}
        for key, value in zip(returned.keys, returned.values)
    }
    fields = _parameter_fields()
    choice_fields = {name for name, (annotation, _) in fields.items() if _annotation_kind(annotation)[0] == "choice"}
    assert set(labels) == choice_fields
    for name in choice_fields:
        assert set(labels[name]) == set(_annotation_kind(fields[name][0])[1]), name
        for label in labels[name].values():  # translatable: _("...")
            assert isinstance(label, ast.Call) and getattr(label.func, "id", None) == "_", name
