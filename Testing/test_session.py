"""The Qt-free parts of the module's panel (IsoSimilarityTFLib.session): the Detail setting, the tissue rows, and
where an Apply runs (in Slicer's process or a child process).
Their MRML side (edits, solo, storage in the scene, segments) is the self-test check ``tissues``, run on real MRML
in test_module_selftest.py."""

import pytest

from IsoSimilarityTFLib import OptionError
from IsoSimilarityTFLib.selftest import hand_made_design
from IsoSimilarityTFLib.session import (
    AUTO_DETAIL,
    CLASS,
    TISSUE,
    DesignSession,
    _engine_grouping,
    design_rows,
    detail_of_design,
    estimate_seconds,
    grouping_of_detail,
    regroup_design,
    runs_in_process,
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


# Where an Apply runs -------------------------------------------------------------------------------------------------
def test_small_designs_run_in_process_and_large_ones_in_a_child_process():
    # The defaults (256 bins, 200 iterations) on usual volumes: in Slicer's process, no process start or file copies.
    for shape in [(64, 64, 64), (128, 128, 128), (256, 256, 256), (181, 217, 181), (108, 256, 256)]:
        assert runs_in_process(shape, {}), shape
    # A big CT, many bins (affinity propagation grows with bins squared), or long clustering: in a child process.
    assert not runs_in_process((400, 512, 512), {})
    assert not runs_in_process((64, 64, 64), {"n_bins": 1024})
    assert not runs_in_process((64, 64, 64), {"n_bins": 256, "max_iter": 5000})
    assert runs_in_process((128, 128, 128), {"n_bins": 512})


def test_the_estimate_grows_with_voxels_bins_levels_and_iterations():
    base = estimate_seconds((128, 128, 128), {})
    assert estimate_seconds((256, 256, 256), {}) > base
    assert estimate_seconds((128, 128, 128), {"n_bins": 512}) > base
    assert estimate_seconds((128, 128, 128), {"levels": 2}) < base
    assert estimate_seconds((128, 128, 128), {"max_iter": 400}) > base
    assert estimate_seconds((128, 128, 128), {"tissues": 3, "colors": "distinct"}) == base  # look options: free
    # Measured (benchmarks/apply_cost.py): 128^3 at 256 bins about 0.4 s, 64^3 at 1024 bins about 2 s.
    assert 0.2 < base < 1.0
    assert 1.0 < estimate_seconds((64, 64, 64), {"n_bins": 1024}) < 4.0
    with pytest.raises(OptionError):
        estimate_seconds((64, 64, 64), {"n_bins": 1})


def test_the_session_decides_from_the_volume_node(slicer_app):
    import numpy as np

    session = DesignSession(slicer_app.volume_rendering_logic)
    small = slicer_app.add_volume(np.zeros((8, 9, 10), dtype=np.float32), name="small")
    assert session.runs_in_process(small, {})
    assert not session.runs_in_process(small, {"n_bins": 4096})


def test_the_job_folder_is_under_the_sessions_temporary_folder(slicer_app, tmp_path):
    """In Slicer, slicer.app.temporaryPath (the folder chosen in the settings), not the system's (audit F6)."""
    import os

    from IsoSimilarityTFLib.selftest import SPACING, nested_volume

    class Session(DesignSession):
        def temporary_folder(self):
            return str(tmp_path / "slicer-temporary")

    session = Session(slicer_app.volume_rendering_logic)
    volume = slicer_app.add_volume(nested_volume(), spacing=SPACING, name="Nested")
    job = session.start(volume, {"n_bins": 16})
    try:
        assert os.path.dirname(job.folder) == str(tmp_path / "slicer-temporary")
        job.wait(timeout=120)
        assert session.finish(volume, job).n_bins == 16
    finally:
        job.close()
    assert os.listdir(tmp_path / "slicer-temporary") == []


def test_an_apply_in_slicer_leaves_padding_out_of_the_range_as_the_command_line_does(slicer_app):
    """The module uses the command line's default range (issue 18, item 4): CT padding outside the field of view is
    left out of the bins and the panel is told what was left out; a range given by the caller is kept."""

    from isosimtf.phantom import head_phantom

    ct = head_phantom(32, seed=0).values
    padded = ct.copy()
    padded[:, :, :4] = -3024
    session = DesignSession(slicer_app.volume_rendering_logic)
    volume = slicer_app.add_volume(padded, name="padded")
    design = session.run(volume, {})
    assert design.value_range == (float(ct.min()), float(ct.max()))
    assert "padding voxels at -3024" in session.range_warning and "value_range=" in session.range_warning
    design = session.run(volume, {"value_range": (-3024.0, float(ct.max()))})
    assert design.value_range == (-3024.0, float(ct.max())) and session.range_warning is None
    session.run(slicer_app.add_volume(ct, name="clean"), {})
    assert session.range_warning is None


def test_the_session_keeps_the_similarity_of_its_last_four_designs(slicer_app):
    """The scene does not store similarity matrices: the session keeps the last MAX_KEPT_SIMILARITIES, by property
    node, the most recently applied last."""
    import numpy as np

    from IsoSimilarityTFLib.selftest import SPACING, nested_volume
    from IsoSimilarityTFLib.session import MAX_KEPT_SIMILARITIES

    assert MAX_KEPT_SIMILARITIES == 4
    session = DesignSession(slicer_app.volume_rendering_logic)
    volumes = [slicer_app.add_volume(nested_volume(), spacing=SPACING, name=f"V{i}") for i in range(5)]
    matrices = []
    for volume in volumes[:4]:
        design = hand_made_design()
        design.similarity = np.full_like(design.similarity, len(matrices))
        matrices.append(design.similarity)
        session.apply(volume, design)
    session.apply(volumes[0], _with_similarity(volumes[0], matrices[0]))  # applied again: the most recent now
    session.apply(volumes[4], _with_similarity(volumes[4], np.full_like(matrices[0], 4)))
    kept = {volume.GetName(): session.restore(volume).similarity for volume in volumes}
    assert kept["V1"] is None  # the oldest left
    for name, value in (("V0", 0), ("V2", 2), ("V3", 3), ("V4", 4)):
        assert kept[name] is not None and np.all(kept[name] == value), name


def _with_similarity(volume, similarity):
    design = hand_made_design()
    design.similarity = similarity
    return design


def test_a_restore_sets_the_unit_distance_only_where_the_design_is_still_shown(slicer_app):
    """A .vp file (Slicer 5.8's scenes) keeps no unit distance: a restore puts the design's back, but not into a
    transfer function changed outside (a preset's unit distance is the preset's)."""
    from IsoSimilarityTFLib.selftest import SPACING, nested_volume

    session = DesignSession(slicer_app.volume_rendering_logic)
    volume = slicer_app.add_volume(nested_volume(), spacing=SPACING, name="V")
    design = hand_made_design()
    design.unit_distance = 0.37
    node = session.apply(volume, design)
    prop = node.GetVolumeProperty()
    prop.SetScalarOpacityUnitDistance(1.0)  # as read back from a .vp file
    session.forget()
    session.restore(volume)
    assert prop.GetScalarOpacityUnitDistance() == pytest.approx(0.37)
    node.CopyContent(slicer_app.volume_rendering_logic.GetPresetByName("US-Fetal"))
    preset = prop.GetScalarOpacityUnitDistance()
    session.restore(volume)
    assert prop.GetScalarOpacityUnitDistance() == pytest.approx(preset) != pytest.approx(0.37)


def test_a_closed_scene_forgets_the_similarities_and_a_removed_volume_is_not_edited(slicer_app):
    from IsoSimilarityTFLib.selftest import SPACING, nested_volume

    session = DesignSession(slicer_app.volume_rendering_logic)
    volume = slicer_app.add_volume(nested_volume(), spacing=SPACING, name="V")
    session.apply(volume, hand_made_design())
    session.forget()  # the scene is closed (here: the session told so)
    assert session.design is None and session.restore(volume).similarity is None
    slicer_app.scene.RemoveNode(volume)
    with pytest.raises(ValueError, match="not in a scene"):
        session.edit("tissue", 1, opacity=0.5)
