"""apply_design on real Slicer MRML (slicer-core, headless): nodes, user work kept, scene save/reload, rendering."""

import numpy as np
import pytest

from IsoSimilarityTFLib import design_transfer_function
from IsoSimilarityTFLib.mrml import DESIGN_ATTRIBUTE, apply_design, design_node_of, design_of, update_property_node
from IsoSimilarityTFLib.phantom import head_phantom


@pytest.fixture(scope="module")
def phantom():
    return head_phantom(40, seed=2)


@pytest.fixture(scope="module")
def phantom_design(phantom):
    return design_transfer_function(phantom.values, phantom.spacing)


def add_phantom(app, phantom, name="Head"):
    return app.add_volume(phantom.values, spacing=phantom.spacing, name=name)


def property_nodes(scene):
    return [
        scene.GetNthNodeByClass(i, "vtkMRMLVolumePropertyNode")
        for i in range(scene.GetNumberOfNodesByClass("vtkMRMLVolumePropertyNode"))
    ]


def tf_at(property_node, values):
    vp = property_node.GetVolumeProperty()
    colors = np.array([vp.GetRGBTransferFunction().GetColor(float(x)) for x in values])
    opacities = np.array([vp.GetScalarOpacity().GetValue(float(x)) for x in values])
    return colors, opacities


def assert_node_shows(property_node, design):
    centres = 0.5 * (design.edges[:-1] + design.edges[1:])
    colors, opacities = tf_at(property_node, centres)
    for c in design.classes:
        if design.is_shown(c.id):  # a hidden class's colour is its nearest shown neighbour's (see bin_looks)
            np.testing.assert_allclose(colors[c.isovalue_bins], np.tile(c.color, (len(c.isovalue_bins), 1)))
        np.testing.assert_allclose(opacities[c.isovalue_bins], c.opacity if design.is_shown(c.id) else 0.0)


def test_apply_creates_and_attaches_a_named_property_node(slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    node = apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    display = slicer_app.volume_rendering_logic.GetFirstVolumeRenderingDisplayNode(volume)
    assert display is not None and display.GetVolumePropertyNode() is node and display.GetVisibility()
    assert not display.GetFollowVolumeDisplayNode()
    assert node.GetName() == "Head IsoSimilarityTF"
    assert node.GetEffectiveRange() == pytest.approx(volume.GetImageData().GetScalarRange())
    assert design_node_of(volume) is node
    assert_node_shows(node, phantom_design)
    assert design_of(node).to_dict()["classes"] == phantom_design.to_dict()["classes"]


def test_users_property_node_is_kept_and_rerun_reuses_ours(slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    display = slicer_app.show_volume(volume)
    users = display.GetVolumePropertyNode()
    users.GetVolumeProperty().GetScalarOpacity().AddPoint(123.0, 0.42)  # the user's own edit
    before = [users.GetVolumeProperty().GetScalarOpacity().GetValue(x) for x in (-1000.0, 123.0, 500.0)]
    n_nodes = slicer_app.scene.GetNumberOfNodes()

    first = apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    after_first = slicer_app.scene.GetNumberOfNodes()
    second = apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    assert second is first and slicer_app.scene.GetNumberOfNodes() == after_first == n_nodes + 1
    assert users in property_nodes(slicer_app.scene)
    assert [users.GetVolumeProperty().GetScalarOpacity().GetValue(x) for x in (-1000.0, 123.0, 500.0)] == before
    assert display.GetVolumePropertyNode() is first
    assert slicer_app.scene.GetNumberOfNodesByClass("vtkMRMLVolumeRenderingDisplayNode") == 1


def test_class_edit_updates_the_node_in_place_and_only_that_class(slicer_app, phantom, phantom_design):
    design = type(phantom_design).from_json(phantom_design.to_json())
    volume = add_phantom(slicer_app, phantom)
    node = apply_design(volume, design, slicer_app.volume_rendering_logic)
    vp, opacity_function = node.GetVolumeProperty(), node.GetVolumeProperty().GetScalarOpacity()
    centres = 0.5 * (design.edges[:-1] + design.edges[1:])
    colors_before, opacities_before = tf_at(node, centres)

    target = next(c for c in design.classes if c.visible)
    design.set_class(target.id, color=(0.0, 1.0, 1.0), opacity=0.05)
    update_property_node(node, design)
    assert node.GetVolumeProperty() is vp and vp.GetScalarOpacity() is opacity_function
    colors_after, opacities_after = tf_at(node, centres)
    changed = np.any(colors_after != colors_before, axis=1) | (opacities_after != opacities_before)
    shown = opacities_after > 0
    assert list(np.flatnonzero(changed & shown)) == target.isovalue_bins
    assert design_of(node).class_by_id(target.id).color == [0.0, 1.0, 1.0]


def test_uint8_volume(slicer_app):
    values = np.zeros((24, 24, 24), dtype=np.uint8)
    values[6:18, 6:18, 6:18] = 120
    values[9:15, 9:15, 9:15] = 250
    design = design_transfer_function(values)
    volume = slicer_app.add_volume(values, name="Bytes")
    node = apply_design(volume, design, slicer_app.volume_rendering_logic)
    assert_node_shows(node, design)
    assert np.count_nonzero(slicer_app.render()) > 0


def test_scene_saved_and_reopened_keeps_tf_and_design(tmp_path, slicer_app, phantom, phantom_design):
    from IsoSimilarityTFLib.rendering import HeadlessSlicer

    volume = add_phantom(slicer_app, phantom)
    design = type(phantom_design).from_json(phantom_design.to_json())
    design.set_class(design.classes[-1].id, color=(0.25, 0.5, 0.75))
    apply_design(volume, design, slicer_app.volume_rendering_logic)
    bundle = tmp_path / "bundle"
    bundle.mkdir()
    assert slicer_app.scene.SaveSceneToSlicerDataBundleDirectory(str(bundle))

    with HeadlessSlicer(size=(64, 64)) as reopened:
        reopened.scene.SetURL(str(bundle / "bundle.mrml"))
        assert reopened.scene.Connect() == 1
        volume_back = reopened.scene.GetFirstNodeByName("Head")
        node = design_node_of(volume_back)
        assert node is not None and node.GetAttribute(DESIGN_ATTRIBUTE)
        display = reopened.volume_rendering_logic.GetFirstVolumeRenderingDisplayNode(volume_back)
        assert display.GetVolumePropertyNode() is node
        restored = design_of(node)
        assert restored.to_dict()["classes"] == design.to_dict()["classes"]
        assert_node_shows(node, restored)


def test_closing_the_scene_mid_way_gives_a_clear_error(slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    slicer_app.render()
    slicer_app.scene.Clear(0)
    with pytest.raises(ValueError, match="not in a scene"):
        apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    assert design_node_of(volume) is None
    volume = add_phantom(slicer_app, phantom)  # the application goes on working
    apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    assert slicer_app.render().any()


def test_render_uses_our_property_and_follows_class_edits(slicer_app, phantom, phantom_design):
    design = type(phantom_design).from_json(phantom_design.to_json())
    volume = add_phantom(slicer_app, phantom)
    skin = next(c for c in design.classes if c.visible and any(lo <= 60 < hi for lo, hi in c.value_ranges))
    design.set_class(skin.id, opacity=0.5)  # the outside of the head: make it count in the picture
    node = apply_design(volume, design, slicer_app.volume_rendering_logic)
    full = slicer_app.render()
    assert slicer_app.get_volume_actor(volume).GetProperty() is node.GetVolumeProperty()
    assert np.count_nonzero(full.any(axis=2)) > 0.05 * full.shape[0] * full.shape[1]

    # Hiding the class that covers the outside of the head (soft tissue) changes the picture.
    design.set_class(skin.id, visible=False)
    update_property_node(node, design)
    hidden = slicer_app.render()
    assert np.abs(hidden.astype(int) - full).mean() > 1.0

    # Solo: only that class's colour is left in the picture (shading darkens it, so compare hues).
    bone = next(c for c in design.classes if c.visible and any(lo <= 1000 < hi for lo, hi in c.value_ranges))
    design.solo(bone.id)
    update_property_node(node, design)
    solo = slicer_app.render().astype(float)
    lit = solo.sum(axis=2) > 30
    assert lit.sum() > 0
    hue = solo[lit] / solo[lit].sum(axis=1, keepdims=True)
    expected = np.array(bone.color) / sum(bone.color)
    assert np.abs(hue - expected).max() < 0.1
    design.solo(None)
    update_property_node(node, design)
    assert np.abs(slicer_app.render().astype(int) - hidden).mean() < 1e-9
