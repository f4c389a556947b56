"""The Qt-free parts of the module's panel (IsoSimilarityTFLib.session): the Detail setting and the tissue rows.
Their MRML side (edits, solo, storage in the scene, segments) is the self-test check ``tissues``, run on real MRML
in test_module_selftest.py."""

import pytest

from IsoSimilarityTFLib.selftest import hand_made_design
from IsoSimilarityTFLib.session import (
    AUTO_DETAIL,
    CLASS,
    TISSUE,
    _engine_grouping,
    design_rows,
    detail_of_design,
    grouping_of_detail,
    regroup_design,
)


def test_detail_settings_map_to_groupings():
    assert grouping_of_detail(AUTO_DETAIL, 5) == "auto"
    assert grouping_of_detail(1, 5) == 1
    assert grouping_of_detail(4, 5) == 4
    assert grouping_of_detail(5, 5) == "all"
    assert grouping_of_detail(40, 5) == "all"  # a count saved for a volume with more classes
    with pytest.raises(ValueError):
        grouping_of_detail(-1, 5)


def test_the_engine_groups_automatically_and_the_session_regroups_a_count():
    assert _engine_grouping({"n_bins": 64, "tissues": 3}) == ({"n_bins": 64, "tissues": "auto"}, 3)
    assert _engine_grouping({"tissues": "all"}) == ({"tissues": "all"}, None)
    assert _engine_grouping({}) == ({}, None)


def test_regroup_records_the_choice_and_detail_reads_it_back():
    design = hand_made_design()
    assert detail_of_design(design) == 3  # made with one tissue per class
    regroup_design(design, 1)
    assert (design.n_tissues, design.options["tissues"], detail_of_design(design)) == (1, 1, 1)
    regroup_design(design, AUTO_DETAIL)
    assert design.options["tissues"] == "auto" and detail_of_design(design) == AUTO_DETAIL
    assert design.n_tissues == design.hierarchy.auto
    regroup_design(design, 7)
    assert design.options["tissues"] == "all" and detail_of_design(design) == 3


def test_rows_hold_tissues_and_their_classes():
    design = hand_made_design()
    regroup_design(design, 1)
    rows = design_rows(design)
    assert [r.level for r in rows] == [TISSUE, TISSUE]
    background, tissue = rows
    assert background.background and background.children == () and not background.shown
    assert [c.level for c in tissue.children] == [CLASS] * 3
    assert tissue.voxels == sum(c.voxels for c in tissue.children)
    assert sum(r.fraction for r in rows) == pytest.approx(1.0)
    design.set_class(2, visible=False)
    assert design_rows(design)[1].visible is None
    design.solo(2)
    rows = design_rows(design)
    assert [c.solo for c in rows[1].children] == [False, True, False] and not rows[1].solo
    assert [c.shown for c in rows[1].children] == [False, True, False] and rows[1].shown
