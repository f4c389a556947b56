"""The design in real Slicer MRML (slicer-core, headless): nodes, user work kept, the Volume Rendering module's own
actions, scene save/reload (also of older scenes), rendering, classes as segments, the design as a preset."""

import numpy as np
import pytest

from IsoSimilarityTFLib import design_transfer_function, mrml
from IsoSimilarityTFLib.mrml import apply_design, design_node_of, design_of, update_property_node
from isosimtf.phantom import head_phantom


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
    low, high = design.value_range
    centres = low + (np.arange(design.n_bins) + 0.5) * (high - low) / design.n_bins
    colors, opacities = tf_at(property_node, centres)
    _, bin_opacity = design.bin_looks()  # the class opacities with their boundary ramps (test_design checks them)
    for c in design.classes:
        if design.is_shown(c.id):  # a hidden class's colour is its nearest shown neighbour's (see bin_looks)
            np.testing.assert_allclose(colors[c.isovalue_bins], np.tile(c.color, (len(c.isovalue_bins), 1)))
            assert np.all(opacities[c.isovalue_bins] <= c.opacity + 1e-12)
        else:
            np.testing.assert_array_equal(opacities[c.isovalue_bins], 0.0)
    np.testing.assert_allclose(opacities, bin_opacity)


def test_apply_creates_and_attaches_a_named_property_node(slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    node = apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    display = slicer_app.volume_rendering_logic.GetFirstVolumeRenderingDisplayNode(volume)
    assert display is not None and display.GetVolumePropertyNode() is node and display.GetVisibility()
    assert not display.GetFollowVolumeDisplayNode()
    assert node.GetName() == "Head IsoSimilarityTF"
    # No unused default property node next to ours (CreateDefaultVolumeRenderingNodes would leave one).
    assert property_nodes(slicer_app.scene) == [node]
    assert node.GetVolumeProperty().GetScalarOpacityUnitDistance() == pytest.approx(phantom_design.unit_distance)
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
    # Our property node and the design node, once.
    assert second is first and slicer_app.scene.GetNumberOfNodes() == after_first == n_nodes + 2
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
    colors_before, _ = tf_at(node, centres)

    target = next(c for c in design.classes if c.visible)
    design.set_class(target.id, color=(0.0, 1.0, 1.0), opacity=0.05)
    update_property_node(node, design)
    assert node.GetVolumeProperty() is vp and vp.GetScalarOpacity() is opacity_function
    colors_after, opacities_after = tf_at(node, centres)
    # Colour: that class only (opacity ramps reach further; where they move, VTK's interpolation between two equal
    # colours may differ in the last bit).
    changed = np.any(np.abs(colors_after - colors_before) > 1e-9, axis=1)
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
    volume = add_phantom(slicer_app, phantom)
    design = type(phantom_design).from_json(phantom_design.to_json())
    design.set_class(design.classes[-1].id, color=(0.25, 0.5, 0.75))
    apply_design(volume, design, slicer_app.volume_rendering_logic)

    def check(reopened):
        volume_back = reopened.scene.GetFirstNodeByName("Head")
        node = design_node_of(volume_back)
        assert node is not None and mrml.design_text_node(volume_back) is not None
        assert not mrml.modified_outside(volume_back)
        display = reopened.volume_rendering_logic.GetFirstVolumeRenderingDisplayNode(volume_back)
        assert display.GetVolumePropertyNode() is node
        restored = design_of(node)
        assert restored.to_dict()["classes"] == design.to_dict()["classes"]
        assert_node_shows(node, restored)

    save_and_reopen(slicer_app.scene, tmp_path / "bundle", check)


def test_a_saved_scene_restores_the_chosen_look(tmp_path, slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    design = type(phantom_design).from_json(phantom_design.to_json())
    chosen = design.looks[-1].name  # not the first click
    design.use_look(chosen)
    apply_design(volume, design, slicer_app.volume_rendering_logic)

    def check(reopened):
        restored = design_of(design_node_of(reopened.scene.GetFirstNodeByName("Head")))
        assert restored.look_name == chosen
        assert [c.to_dict() for c in restored.classes] == [c.to_dict() for c in design.classes]
        restored.regroup(restored.options["tissues"])  # the Detail slider remakes the chosen look, not the first
        assert restored.look_name == chosen
        assert np.array_equal(restored.transfer_function().opacity, design.transfer_function().opacity)

    save_and_reopen(slicer_app.scene, tmp_path / "bundle", check)


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


# The design's own node: the Volume Rendering module's actions cannot erase it, and they are noticed ---------------
def fresh(design):
    return type(design).from_json(design.to_json())


def test_design_lives_in_its_own_node_referenced_from_the_volume(slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    node = apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    text_node = mrml.design_text_node(volume)
    assert text_node.IsA("vtkMRMLTextNode") and text_node.GetNodeReference(mrml.PROPERTY_ROLE) is node
    assert mrml.design_of_volume(volume).to_dict() == phantom_design.to_dict()
    assert not node.GetAttribute(mrml.LEGACY_DESIGN_ATTRIBUTE)
    assert mrml.outside_change(volume) is None and not mrml.modified_outside(volume)


def test_a_preset_copied_into_the_property_node_keeps_the_design_and_is_noticed(slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    design = fresh(phantom_design)
    node = apply_design(volume, design, slicer_app.volume_rendering_logic)
    # What the Volume Rendering module's preset menu does (qSlicerVolumeRenderingPresetComboBox::applyPreset).
    node.CopyContent(slicer_app.volume_rendering_logic.GetPresetByName("US-Fetal"))
    assert mrml.design_of_volume(volume).to_dict()["classes"] == design.to_dict()["classes"]
    assert mrml.outside_change(volume) == mrml.CHANGE_EDITED and mrml.modified_outside(volume)
    # Writing the design again (after the user said yes) brings it back, in the same node.
    design.set_class(design.classes[-1].id, opacity=0.3)
    assert mrml.update_design(volume, design, slicer_app.volume_rendering_logic) is node
    assert not mrml.modified_outside(volume)
    assert_node_shows(node, design)
    assert node.GetVolumeProperty().GetScalarOpacityUnitDistance() == pytest.approx(design.unit_distance)


def test_synchronize_with_volumes_and_shift_are_noticed(slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    node = apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    display = slicer_app.volume_rendering_logic.GetFirstVolumeRenderingDisplayNode(volume)
    # "Synchronize with Volumes module" (qSlicerVolumeRenderingModuleWidget::synchronizeScalarDisplayNode).
    slicer_app.volume_rendering_logic.CopyDisplayToVolumeRenderingDisplayNode(display)
    assert mrml.outside_change(volume) == mrml.CHANGE_EDITED
    mrml.update_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    assert not mrml.modified_outside(volume)
    # Shift moves every point of the functions in place.
    opacity = node.GetVolumeProperty().GetScalarOpacity()
    values = [0.0] * 4
    opacity.GetNodeValue(3, values)
    values[0] += 1.0
    opacity.SetNodeValue(3, values)
    assert mrml.modified_outside(volume)


def shift_color_of_point(node, index):
    """A colour-only edit of one point, as the Volume Rendering module's colour editor makes (opacity untouched)."""
    color = node.GetVolumeProperty().GetRGBTransferFunction()
    values = [0.0] * 6
    color.GetNodeValue(index, values)
    values[1:4] = [1.0 - v for v in values[1:4]]
    color.SetNodeValue(index, values)


def test_a_colour_only_change_is_noticed(slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    node = apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    opacity_before = tf_at(node, phantom_design.edges)[1]
    shift_color_of_point(node, node.GetVolumeProperty().GetRGBTransferFunction().GetSize() // 2)
    np.testing.assert_array_equal(tf_at(node, phantom_design.edges)[1], opacity_before)
    assert mrml.outside_change(volume) == mrml.CHANGE_EDITED and mrml.modified_outside(volume)


def test_another_property_node_shown_is_noticed_and_the_design_can_be_shown_again(slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    ours = apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    display = slicer_app.volume_rendering_logic.GetFirstVolumeRenderingDisplayNode(volume)
    other = slicer_app.scene.AddNewNodeByClass("vtkMRMLVolumePropertyNode", "Mine")
    display.SetAndObserveVolumePropertyNodeID(other.GetID())
    assert mrml.displayed_property_node(volume) is other
    assert mrml.outside_change(volume) == mrml.CHANGE_OTHER_NODE and mrml.modified_outside(volume)
    assert mrml.update_design(volume, phantom_design, slicer_app.volume_rendering_logic) is ours
    assert display.GetVolumePropertyNode() is ours and other in property_nodes(slicer_app.scene)


def test_no_design_and_nothing_shown_mean_nothing_modified(slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    assert mrml.design_of_volume(volume) is None and not mrml.modified_outside(volume)
    apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    slicer_app.volume_rendering_logic.GetFirstVolumeRenderingDisplayNode(volume).SetAndObserveVolumePropertyNodeID(None)
    assert not mrml.modified_outside(volume)


def test_edits_keep_the_unit_distance_that_a_legacy_vp_file_loses(slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    node = apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    # A unit distance other than the design's, as Slicer 5.8 reads back from a .vp scene file (1.0, its default) when
    # the design's is not 1 mm.
    node.GetVolumeProperty().SetScalarOpacityUnitDistance(2.5 * phantom_design.unit_distance)
    mrml.update_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    assert node.GetVolumeProperty().GetScalarOpacityUnitDistance() == pytest.approx(phantom_design.unit_distance)


def save_and_reopen(scene, folder, check):
    from isosimtf.rendering import HeadlessSlicer

    folder.mkdir()
    assert scene.SaveSceneToSlicerDataBundleDirectory(str(folder))
    with HeadlessSlicer(size=(64, 64)) as reopened:
        reopened.scene.SetURL(str(folder / f"{folder.name}.mrml"))
        assert reopened.scene.Connect() == 1
        check(reopened)


def test_scene_saved_with_a_legacy_vp_file_and_reopened(tmp_path, slicer_app, phantom, phantom_design):
    """Slicer 5.8 saves the property node as .vp, which has no unit distance: the design puts it back."""
    volume = add_phantom(slicer_app, phantom)
    node = apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    storage = slicer_app.scene.AddNewNodeByClass("vtkMRMLVolumePropertyStorageNode")
    storage.SetFileName(str(tmp_path / "tf.vp"))
    node.SetAndObserveStorageNodeID(storage.GetID())

    def check(reopened):
        volume_back = reopened.scene.GetFirstNodeByName("Head")
        node_back = design_node_of(volume_back)
        assert node_back.GetStorageNode().GetFileName().endswith(".vp")
        design = mrml.design_of_volume(volume_back)
        assert design.to_dict()["classes"] == phantom_design.to_dict()["classes"]
        assert not mrml.modified_outside(volume_back)
        assert node_back.GetVolumeProperty().GetScalarOpacityUnitDistance() == 1.0  # lost by the .vp file
        mrml.update_design(volume_back, design, reopened.volume_rendering_logic)
        assert node_back.GetVolumeProperty().GetScalarOpacityUnitDistance() == pytest.approx(design.unit_distance)

    save_and_reopen(slicer_app.scene, tmp_path / "bundle", check)


def test_older_scenes_with_the_design_as_an_attribute_still_load(tmp_path, slicer_app, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    # The layout of earlier versions: the design as an attribute of the property node, which references the volume.
    legacy = slicer_app.scene.AddNewNodeByClass("vtkMRMLVolumePropertyNode", "Head IsoSimilarityTF")
    legacy.SetNodeReferenceID(mrml.LEGACY_VOLUME_ROLE, volume.GetID())
    legacy.SetAttribute(mrml.LEGACY_DESIGN_ATTRIBUTE, phantom_design.to_json())
    phantom_design.update_volume_property(legacy.GetVolumeProperty())
    display = slicer_app.show_volume(volume)
    display.SetAndObserveVolumePropertyNodeID(legacy.GetID())

    def check(reopened):
        volume_back = reopened.scene.GetFirstNodeByName("Head")
        design = mrml.design_of_volume(volume_back)
        assert design is not None and design.to_dict()["classes"] == phantom_design.to_dict()["classes"]
        node_back = design_node_of(volume_back)
        assert design_of(node_back).to_dict() == design.to_dict()
        assert not mrml.modified_outside(volume_back)
        # The next write moves the design into its own node and reuses the property node.
        assert apply_design(volume_back, design, reopened.volume_rendering_logic) is node_back
        assert mrml.design_text_node(volume_back) is not None
        assert not node_back.GetAttribute(mrml.LEGACY_DESIGN_ATTRIBUTE)
        assert mrml.design_of_volume(volume_back).to_dict() == design.to_dict()

    save_and_reopen(slicer_app.scene, tmp_path / "legacy", check)


# Classes as segments -----------------------------------------------------------------------------------------------
@pytest.fixture()
def segmentations(slicer_app):
    """Slicer's Segmentations module logic on the scene (registers the converter rules, as the application does)."""
    import slicer

    logic = slicer.vtkSlicerSegmentationsModuleLogic()
    logic.SetMRMLApplicationLogic(slicer_app.app_logic)
    logic.SetMRMLScene(slicer_app.scene)
    yield logic
    logic.SetMRMLScene(None)


def segment_labels(scene, segmentation_node, reference_volume):
    """Label value 1..N (segment order) per voxel of the reference volume, from Slicer's own export."""
    import slicer
    from vtkmodules.util import numpy_support
    from vtkmodules.vtkCommonCore import vtkStringArray

    segmentation = segmentation_node.GetSegmentation()
    ids = vtkStringArray()
    for index in range(segmentation.GetNumberOfSegments()):
        ids.InsertNextValue(segmentation.GetNthSegmentID(index))
    labelmap = scene.AddNewNodeByClass("vtkMRMLLabelMapVolumeNode")
    assert slicer.vtkSlicerSegmentationsModuleLogic.ExportSegmentsToLabelmapNode(
        segmentation_node, ids, labelmap, reference_volume
    )
    image = labelmap.GetImageData()
    columns, rows, slices = image.GetDimensions()
    return numpy_support.vtk_to_numpy(image.GetPointData().GetScalars()).reshape(slices, rows, columns)


def expected_labels(design, volume, classes):
    from IsoSimilarityTFLib.quantize import quantize

    values = phantom_values(volume)
    class_ids = design.labels[quantize(values, design.n_bins, design.value_range).bins]
    lookup = np.zeros(len(design.classes), dtype=int)
    lookup[[c.id for c in classes]] = np.arange(1, len(classes) + 1)
    return lookup[class_ids]


def phantom_values(volume):
    from vtkmodules.util import numpy_support

    image = volume.GetImageData()
    columns, rows, slices = image.GetDimensions()
    return numpy_support.vtk_to_numpy(image.GetPointData().GetScalars()).reshape(slices, rows, columns)


def test_export_segmentation_gives_one_segment_per_shown_class_with_exact_voxels(
    tmp_path, slicer_app, segmentations, phantom, phantom_design
):
    volume = add_phantom(slicer_app, phantom)
    apply_design(volume, phantom_design, slicer_app.volume_rendering_logic)
    segmentation_node = mrml.export_segmentation(volume, phantom_design)
    shown = [c for c in phantom_design.classes if phantom_design.is_shown(c.id)]
    segmentation = segmentation_node.GetSegmentation()
    assert segmentation.GetNumberOfSegments() == len(shown) > 2
    for index, isovalue_class in enumerate(shown):
        segment = segmentation.GetNthSegment(index)
        assert segment.GetName() == mrml.segment_name(isovalue_class)
        assert segment.GetName().startswith(f"Class {isovalue_class.id + 1} (")
        assert segment.GetColor() == pytest.approx(isovalue_class.color, abs=1e-6)
    expected = expected_labels(phantom_design, volume, shown)
    np.testing.assert_array_equal(segment_labels(slicer_app.scene, segmentation_node, volume), expected)
    for index, isovalue_class in enumerate(shown):  # voxel counts as in the classes table
        assert np.count_nonzero(expected == index + 1) == isovalue_class.voxels
    assert segmentation_node.GetDisplayNode() is not None

    # Saved as Slicer's segmentation file and read back with Slicer's storage node: the same segments and voxels.
    path = str(tmp_path / "classes.seg.nrrd")
    writer = slicer_app.scene.AddNewNodeByClass("vtkMRMLSegmentationStorageNode")
    writer.SetFileName(path)
    assert writer.WriteData(segmentation_node)
    back = slicer_app.scene.AddNewNodeByClass("vtkMRMLSegmentationNode")
    reader = slicer_app.scene.AddNewNodeByClass("vtkMRMLSegmentationStorageNode")
    reader.SetFileName(path)
    assert reader.ReadData(back)
    names = [back.GetSegmentation().GetNthSegment(i).GetName() for i in range(len(shown))]
    assert names == [mrml.segment_name(c) for c in shown]
    np.testing.assert_array_equal(segment_labels(slicer_app.scene, back, volume), expected)


def test_export_segmentation_of_all_classes_and_solo(slicer_app, segmentations, phantom, phantom_design):
    volume = add_phantom(slicer_app, phantom)
    design = fresh(phantom_design)
    every = mrml.export_segmentation(volume, design, which="all")
    assert every.GetSegmentation().GetNumberOfSegments() == len(design.classes)
    assert (segment_labels(slicer_app.scene, every, volume) > 0).all()  # every voxel is in one class
    design.solo(design.classes[-1].id)
    alone = mrml.export_segmentation(volume, design)
    assert alone.GetSegmentation().GetNumberOfSegments() == 1
    with pytest.raises(ValueError, match="which"):
        mrml.export_segmentation(volume, design, which="some")


def test_export_segmentation_of_more_than_255_classes(slicer_app, segmentations):
    """Labels take one byte while they fit; a design with 300 classes needs two, and every voxel keeps its class."""
    values = np.arange(300 * 8, dtype=np.int16).reshape(8, 10, 30) // 8  # 300 values, 8 voxels each
    design = design_transfer_function(values, n_bins=300, preference=0.0, background="none", tissues="all")
    assert len(design.classes) > 255
    volume = slicer_app.add_volume(values, spacing=(1.0, 1.0, 1.0), name="ramp")
    every = mrml.export_segmentation(volume, design, which="all")
    assert every.GetSegmentation().GetNumberOfSegments() == len(design.classes)
    np.testing.assert_array_equal(
        segment_labels(slicer_app.scene, every, volume), expected_labels(design, volume, design.classes)
    )


# The design as a preset --------------------------------------------------------------------------------------------
def test_add_preset_puts_the_design_in_the_preset_menu_with_an_icon(slicer_app, phantom_design):
    from IsoSimilarityTFLib.pictures import ICON_SIZE, transfer_function_icon

    logic = slicer_app.volume_rendering_logic
    preset = mrml.add_preset(phantom_design, logic, "Head classes")
    assert logic.GetPresetByName("Head classes") is preset
    assert preset.GetScene() is logic.GetPresetsScene()
    assert mrml.shows_design(preset, phantom_design)
    assert preset.GetEffectiveRange() == pytest.approx(phantom_design.value_range)
    assert preset.GetVolumeProperty().GetScalarOpacityUnitDistance() == pytest.approx(phantom_design.unit_distance)
    icon = preset.GetNodeReference(logic.GetIconVolumeReferenceRole()).GetImageData()
    assert icon.GetDimensions() == (ICON_SIZE, ICON_SIZE, 1) and icon.GetNumberOfScalarComponents() == 3
    picture = transfer_function_icon(phantom_design)
    assert picture.shape == (ICON_SIZE, ICON_SIZE, 3) and len(np.unique(picture.reshape(-1, 3), axis=0)) > 2
    with pytest.raises(ValueError):
        mrml.add_preset(phantom_design, logic, "  ")


def test_a_preset_applies_to_another_volume(slicer_app, phantom, phantom_design):
    """What the preset menu does with it: CopyContent into another volume's property node shows the design."""
    mrml.add_preset(phantom_design, slicer_app.volume_rendering_logic, "Head classes")
    volume = add_phantom(slicer_app, phantom, name="Other")
    display = slicer_app.show_volume(volume)
    display.GetVolumePropertyNode().CopyContent(slicer_app.volume_rendering_logic.GetPresetByName("Head classes"))
    assert mrml.shows_design(display.GetVolumePropertyNode(), phantom_design)


# Tissues -----------------------------------------------------------------------------------------------------------
def test_scene_saved_and_reopened_keeps_the_grouping_and_tissue_edits(tmp_path, slicer_app, phantom, phantom_design):
    from IsoSimilarityTFLib.session import TISSUE, DesignSession

    volume = add_phantom(slicer_app, phantom)
    session = DesignSession(slicer_app.volume_rendering_logic)
    session.apply(volume, fresh(phantom_design))
    session.regroup(2)
    tissue = next(t for t in session.design.tissues if not t.background)
    session.edit(TISSUE, tissue.id, color=(0.1, 0.2, 0.3), opacity=0.3)
    session.solo(TISSUE, tissue.id)

    def check(reopened):
        volume_back = reopened.scene.GetFirstNodeByName("Head")
        other = DesignSession(reopened.volume_rendering_logic)
        restored = other.restore(volume_back)
        assert restored.n_tissues == 2 and restored.options["tissues"] == 2 and other.detail() == 2
        assert restored.solo_tissue_id == tissue.id
        assert other.rows() == session.rows()
        assert not mrml.modified_outside(volume_back)
        assert_node_shows(other.property_node, restored)

    save_and_reopen(slicer_app.scene, tmp_path / "bundle", check)


def tissue_lookup(design, which="shown"):
    """Expected label per class when exporting tissues: 1..N in tissue order, 0 for classes not exported."""
    lookup = np.zeros(len(design.classes), dtype=int)
    number = 0
    for tissue in design.tissues:
        members = [c for c in tissue.classes if which == "all" or design.is_shown(c)]
        if members:
            number += 1
            lookup[members] = number
    return lookup, number


def test_export_segmentation_by_tissue_holds_the_voxels_of_its_exported_classes(
    slicer_app, segmentations, phantom, phantom_design
):
    from IsoSimilarityTFLib.quantize import quantize

    volume = add_phantom(slicer_app, phantom)
    design = fresh(phantom_design)
    design.regroup(2)
    tissue = next(t for t in design.tissues if not t.background and len(t.classes) > 1)
    design.set_class(tissue.classes[0], visible=False)  # a hidden class leaves its tissue's segment
    class_ids = design.labels[quantize(phantom_values(volume), design.n_bins, design.value_range).bins]
    for which in ("shown", "all"):
        node = mrml.export_segmentation(volume, design, which=which, level="tissue")
        lookup, count = tissue_lookup(design, which)
        segmentation = node.GetSegmentation()
        assert segmentation.GetNumberOfSegments() == count
        exported = [t for t in design.tissues if lookup[t.classes].any()]
        for index, exported_tissue in enumerate(exported):
            segment = segmentation.GetNthSegment(index)
            assert segment.GetName() == mrml.tissue_segment_name(exported_tissue)
            assert segment.GetColor() == pytest.approx(exported_tissue.color, abs=1e-6)
        np.testing.assert_array_equal(segment_labels(slicer_app.scene, node, volume), lookup[class_ids])
    with pytest.raises(ValueError, match="level"):
        mrml.export_segmentation(volume, design, level="organ")
