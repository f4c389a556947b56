"""Tests of the one table of design options (IsoSimilarityTFLib.options) and of the front ends built from it."""

import math

import numpy as np
import pytest

from IsoSimilarityTFLib import OPTIONS, OptionError, design_transfer_function
from IsoSimilarityTFLib.options import DEFAULT_OPTIONS, check_options
from isosimtf import cli


def test_defaults_pass_their_own_checks():
    assert check_options({}) == {name: option.check(option.default) for name, option in OPTIONS.items()}
    assert DEFAULT_OPTIONS == {name: option.default for name, option in OPTIONS.items()}


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("damping", math.nan),
        ("damping", None),
        ("damping", 1.0),
        ("damping", "0.7"),
        ("max_iter", None),
        ("max_iter", 10.5),
        ("max_iter", True),
        ("n_bins", 1),
        ("n_bins", 100_000),
        ("value_range", (1,)),
        ("value_range", (5.0, 5.0)),
        ("value_range", (0.0, math.inf)),
        ("crossing", "both"),
        ("preference", "mean"),
        ("preference", math.inf),
        ("levels", 0),
    ],
)
def test_a_value_outside_its_entry_is_one_clear_option_error(name, value):
    with pytest.raises(OptionError, match=name):
        check_options({name: value})


def test_canonical_types():
    checked = check_options({"value_range": [-1000, 3000], "damping": 0.7, "preference": -2, "levels": 3})
    assert checked["value_range"] == (-1000.0, 3000.0)
    assert checked["preference"] == -2.0 and isinstance(checked["preference"], float)
    assert checked["levels"] == 3


def test_unknown_option_is_a_type_error_naming_it():
    with pytest.raises(TypeError, match="colour"):
        check_options({"colour": "red"})


def test_design_checks_options_before_any_work():
    with pytest.raises(OptionError, match="damping"):
        design_transfer_function(None, damping=math.nan)  # the volume is never looked at


def test_every_option_is_a_cli_argument_with_the_table_default():
    parser = cli.build_parser()
    args = parser.parse_args(["phantom", "-o", "out"])
    assert cli.design_options(args) == DEFAULT_OPTIONS
    flags = {action.dest: action.option_strings for action in parser._actions}
    for name, option in OPTIONS.items():
        assert flags[name] == [option.flag]


def test_cli_applies_the_table_checks(capsys):
    status = cli.main(["phantom", "-o", "out", "--damping", "1.5"])
    assert status == cli.EXIT_USAGE
    assert "--damping: must be a number from 0.5 to 0.99; got 1.5" in capsys.readouterr().err


def test_the_options_table_is_a_leaf_whose_words_every_module_uses():
    """options.py imports no module of the library but errors (no import cycle through it), and the modules that
    check a word list or a bound use the table's own."""
    import ast
    from pathlib import Path

    from IsoSimilarityTFLib import classes, clustering, look, memory, options, similarity

    tree = ast.parse(Path(options.__file__).read_text(encoding="utf-8"))
    relative = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.level}
    assert relative == {"errors"}
    assert classes.BACKGROUND_RULES is options.BACKGROUND_RULES
    assert clustering.PREFERENCES is options.PREFERENCES
    assert look.KINDS is options.KINDS and look.COLOR_SCHEMES is options.COLOR_SCHEMES
    assert look.GRADIENT_OPACITY is options.GRADIENT_OPACITY and memory.MAX_BINS is options.MAX_BINS
    assert similarity.CROSSINGS is options.CROSSINGS and similarity.NORMALIZATIONS is options.NORMALIZATIONS
    assert options.OPTIONS["crossing"].choices is options.CROSSINGS


def test_the_checks_across_options_are_the_engines_and_the_command_line_words_them_with_its_flags():
    from IsoSimilarityTFLib.options import check_together

    values = np.random.default_rng(0).normal(size=(8, 8, 8))
    with pytest.raises(OptionError, match="convergence_iter 101 is more than max_iter 100"):
        design_transfer_function(values, max_iter=100, convergence_iter=101)
    check_options({"max_iter": 100, "convergence_iter": 100})  # equal: refused only above
    with pytest.raises(OptionError, match="tissues 65 is more than n_bins 64"):
        check_options({"n_bins": 64, "tissues": 65})
    check_options({"n_bins": 64, "tissues": 64})
    with pytest.raises(OptionError, match="--tissues 65 is more than --bins 64"):
        check_together({"n_bins": 64, "tissues": 65}, lambda option: OPTIONS[option].flag)
