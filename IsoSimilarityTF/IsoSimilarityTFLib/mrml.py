"""Slicer side of the pipeline: a design in a volume's 3D rendering, as segments and as a preset, without Qt.

Imports only Slicer's MRML classes (through the objects it is given, or ``slicer`` for the Segmentations classes)
and VTK: it runs inside the Slicer application and headless with PyPI's ``slicer-core`` alike.

Where the design lives. The design (classes, colours, opacities; JSON) is the text of its own ``vtkMRMLTextNode``,
referenced from the volume (role :data:`DESIGN_ROLE`); the text node references the ``vtkMRMLVolumePropertyNode`` the
design writes its transfer function into (role :data:`PROPERTY_ROLE`). The Volume Rendering module's own actions act
on the property node only (a preset is copied into it with ``CopyContent``, which replaces all its attributes; Shift
and Synchronize-with-Volumes rewrite its functions in place; the user may show another property node), so none of
them can erase the design, and :func:`modified_outside` tells when one of them changed what is shown. Both nodes are
saved with the scene. Scenes from earlier versions, which kept the design as an attribute of the property node
(:data:`LEGACY_DESIGN_ATTRIBUTE`, the property node referencing the volume with :data:`LEGACY_VOLUME_ROLE`), are
read, and moved to a text node at the next write.
"""

import logging
from typing import Optional

import numpy as np

from .design import TransferFunctionDesign
from .pictures import transfer_function_icon
from .quantize import quantize
from .transfer_function import configure_volume_property, points_of_volume_property

#: Reference role from the volume node to the text node holding its design.
DESIGN_ROLE = "IsoSimilarityTFDesign"
#: Reference role from the design's text node to the property node the design writes.
PROPERTY_ROLE = "IsoSimilarityTFVolumeProperty"
#: Where versions before the design node kept the design (an attribute of the property node), and how that property
#: node found its volume.
LEGACY_DESIGN_ATTRIBUTE = "IsoSimilarityTF.Design"
LEGACY_VOLUME_ROLE = "IsoSimilarityTFVolume"
NODE_NAME_SUFFIX = "IsoSimilarityTF"
#: Name of the segmentation representation the classes are exported as.
BINARY_LABELMAP = "Binary labelmap"

#: Answers of :func:`outside_change`.
CHANGE_OTHER_NODE = "other-property-node"  # the volume rendering shows another property node
CHANGE_EDITED = "edited"  # the design's property node shows another transfer function (preset, Shift, Synchronize)

#: Largest difference, in colour or opacity units, still counted as the design's own transfer function.
TOLERANCE = 1e-6


# Finding nodes ------------------------------------------------------------------------------------------------------
def design_text_node(volume_node) -> Optional[object]:
    """The ``vtkMRMLTextNode`` holding the volume's design, or None."""
    if volume_node is None or volume_node.GetScene() is None:
        return None
    return volume_node.GetNodeReference(DESIGN_ROLE)


def _legacy_property_node(volume_node) -> Optional[object]:
    scene = volume_node.GetScene() if volume_node is not None else None
    if scene is None:
        return None
    for index in range(scene.GetNumberOfNodesByClass("vtkMRMLVolumePropertyNode")):
        node = scene.GetNthNodeByClass(index, "vtkMRMLVolumePropertyNode")
        if node.GetNodeReferenceID(LEGACY_VOLUME_ROLE) == volume_node.GetID():
            return node
    return None


def design_node_of(volume_node) -> Optional[object]:
    """The ``vtkMRMLVolumePropertyNode`` the volume's design writes its transfer function into, or None."""
    text_node = design_text_node(volume_node)
    if text_node is not None:
        return text_node.GetNodeReference(PROPERTY_ROLE)
    return _legacy_property_node(volume_node)


def _parse(text: Optional[str], where: str) -> Optional[TransferFunctionDesign]:
    if not text:
        return None
    try:
        return TransferFunctionDesign.from_json(text)
    except ValueError as error:
        logging.warning("Ignoring the IsoSimilarityTF design stored in %s: %s", where, error)
        return None


def design_of_volume(volume_node) -> Optional[TransferFunctionDesign]:
    """The design stored for the volume (None when it has none or an unreadable one).

    It is read from the volume's design node, so it is there even after the Volume Rendering module copied a preset
    into the property node; scenes saved by earlier versions are read from the property node's attribute.
    """
    text_node = design_text_node(volume_node)
    if text_node is not None:
        return _parse(text_node.GetText(), text_node.GetName())
    legacy = _legacy_property_node(volume_node)
    return _parse(legacy.GetAttribute(LEGACY_DESIGN_ATTRIBUTE), legacy.GetName()) if legacy is not None else None


def _text_nodes_of_property_node(property_node) -> list:
    scene = property_node.GetScene() if property_node is not None else None
    if scene is None:
        return []
    found = []
    for index in range(scene.GetNumberOfNodesByClass("vtkMRMLTextNode")):
        node = scene.GetNthNodeByClass(index, "vtkMRMLTextNode")
        if node.GetNodeReferenceID(PROPERTY_ROLE) == property_node.GetID():
            found.append(node)
    return found


def design_of(property_node) -> Optional[TransferFunctionDesign]:
    """The design that writes this property node (None when no design does)."""
    for text_node in _text_nodes_of_property_node(property_node):
        return _parse(text_node.GetText(), text_node.GetName())
    if property_node is None:
        return None
    return _parse(property_node.GetAttribute(LEGACY_DESIGN_ATTRIBUTE), property_node.GetName())


def volume_rendering_display_node(volume_node) -> Optional[object]:
    """The volume's first volume rendering display node (as ``GetFirstVolumeRenderingDisplayNode``), or None."""
    if volume_node is None:
        return None
    for index in range(volume_node.GetNumberOfDisplayNodes()):
        node = volume_node.GetNthDisplayNode(index)
        if node is not None and node.IsA("vtkMRMLVolumeRenderingDisplayNode"):
            return node
    return None


def displayed_property_node(volume_node) -> Optional[object]:
    """The property node the volume rendering of the volume actually shows, or None."""
    display_node = volume_rendering_display_node(volume_node)
    return display_node.GetVolumePropertyNode() if display_node is not None else None


# Comparing ----------------------------------------------------------------------------------------------------------
def shows_design(property_node, design: TransferFunctionDesign, tolerance: float = TOLERANCE) -> bool:
    """Whether the node's colour and scalar opacity functions are what the design writes into a volume property."""
    from vtkmodules.vtkRenderingCore import vtkVolumeProperty

    if property_node is None or property_node.GetVolumeProperty() is None:
        return False
    expected_property = vtkVolumeProperty()
    design.update_volume_property(expected_property)
    opacity, _, color = points_of_volume_property(property_node.GetVolumeProperty())
    expected_opacity, _, expected_color = points_of_volume_property(expected_property)
    scale = max(1.0, float(np.abs(expected_opacity[:, 0]).max(initial=0.0)))
    for actual, expected in ((opacity, expected_opacity), (color, expected_color)):
        if actual.shape != expected.shape:
            return False
        if actual.size == 0:
            continue
        if np.abs(actual[:, 0] - expected[:, 0]).max() > tolerance * scale:
            return False
        if np.abs(actual[:, 1:] - expected[:, 1:]).max() > tolerance:
            return False
    return True


def outside_change(volume_node, design: Optional[TransferFunctionDesign] = None) -> Optional[str]:
    """How the transfer function shown for the volume differs from its design, or None if it does not.

    ``design``: the volume's design when the caller holds it (else it is read from the scene).

    Returns:
        None when the volume has no design, when its design's transfer function is shown, or when no transfer
        function is shown at all (writing the design then loses nothing); :data:`CHANGE_OTHER_NODE` when the volume
        rendering shows another property node; :data:`CHANGE_EDITED` when the design's property node holds another
        transfer function (a preset was copied into it, Shift or Synchronize with Volumes was used, or it was edited).
    """
    if design is None:
        design = design_of_volume(volume_node)
    if design is None:
        return None
    ours, shown = design_node_of(volume_node), displayed_property_node(volume_node)
    if shown is None:
        return None
    if shown is not ours:
        return CHANGE_OTHER_NODE
    return None if shows_design(ours, design) else CHANGE_EDITED


def modified_outside(volume_node) -> bool:
    """Whether the transfer function shown for the volume is no longer its design's (see :func:`outside_change`)."""
    return outside_change(volume_node) is not None


# Writing ------------------------------------------------------------------------------------------------------------
def _add_display_node(volume_node, volume_rendering_logic, property_node):
    """A new volume rendering display node showing ``property_node``, without the default property node that
    ``CreateDefaultVolumeRenderingNodes`` would add (and leave unused) in the scene."""
    scene = volume_node.GetScene()
    display_node = volume_rendering_logic.CreateVolumeRenderingDisplayNode()
    display_node.UnRegister(None)  # created with a reference for the caller: the Python object now owns it
    scene.AddNode(display_node)
    for index in range(scene.GetNumberOfNodesByClass("vtkMRMLViewNode")):  # as CreateDefaultVolumeRenderingNodes
        display_node.AddViewNodeID(scene.GetNthNodeByClass(index, "vtkMRMLViewNode").GetID())
    volume_node.AddAndObserveDisplayNodeID(display_node.GetID())
    # Sets the property node, no cropping ROI; it also copies the window/level into the property node, which the
    # design overwrites right after.
    volume_rendering_logic.UpdateDisplayNodeFromVolumeNode(display_node, volume_node, property_node, None, False)
    return display_node


def _design_nodes(volume_node, create: bool):
    """(text node, property node) of the volume's design, created (or moved from a legacy scene) when asked."""
    scene = volume_node.GetScene()
    text_node = design_text_node(volume_node)
    property_node = design_node_of(volume_node)
    if not create:
        return text_node, property_node
    if property_node is None or property_node.GetScene() is None:
        name = scene.GenerateUniqueName(f"{volume_node.GetName()} {NODE_NAME_SUFFIX}")
        property_node = scene.AddNewNodeByClass("vtkMRMLVolumePropertyNode", name)
    if text_node is None:
        name = scene.GenerateUniqueName(f"{volume_node.GetName()} {NODE_NAME_SUFFIX} design")
        text_node = scene.AddNewNodeByClass("vtkMRMLTextNode", name)
        volume_node.SetNodeReferenceID(DESIGN_ROLE, text_node.GetID())
    # Internal, as Slicer's own: not listed in the Data module, where deleting it would lose the design (still saved).
    if not text_node.GetHideFromEditors():
        text_node.SetHideFromEditors(True)
    text_node.SetNodeReferenceID(PROPERTY_ROLE, property_node.GetID())
    if property_node.GetAttribute(LEGACY_DESIGN_ATTRIBUTE) is not None:  # moved to the text node
        property_node.RemoveAttribute(LEGACY_DESIGN_ATTRIBUTE)
        property_node.RemoveNodeReferenceIDs(LEGACY_VOLUME_ROLE)
    return text_node, property_node


def _store(text_node, design: TransferFunctionDesign) -> None:
    text = design.to_json()
    if text_node.GetText() != text:
        text_node.SetText(text)


def update_property_node(property_node, design: TransferFunctionDesign) -> None:
    """Rewrite the node's transfer function from the design, in place, and store the design with it.

    Also sets the scalar opacity unit distance (the legacy ``.vp`` file and Slicer 5.8's scene do not keep it).
    """
    volume_property = property_node.GetVolumeProperty()
    design.update_volume_property(volume_property)
    volume_property.SetScalarOpacityUnitDistance(design.unit_distance)
    for text_node in _text_nodes_of_property_node(property_node):
        _store(text_node, design)
    if property_node.GetAttribute(LEGACY_DESIGN_ATTRIBUTE) is not None:
        property_node.SetAttribute(LEGACY_DESIGN_ATTRIBUTE, design.to_json())


def restyle_property_node(property_node, design: TransferFunctionDesign) -> None:
    """Give the node the design's shading, lighting, interpolation and gradient opacity (a Volume Rendering preset
    copied into it with ``CopyContent`` replaced them; edits rewrite only the colour and scalar opacity)."""
    configure_volume_property(property_node.GetVolumeProperty(), design.unit_distance, design.gradient_ramp_top)


def _write(volume_node, design: TransferFunctionDesign, volume_rendering_logic, *, first: bool):
    scene = volume_node.GetScene() if volume_node is not None else None
    if scene is None:
        raise ValueError("the volume is not in a scene (was the scene closed?)")
    text_node, property_node = _design_nodes(volume_node, create=True)
    display_node = volume_rendering_logic.GetFirstVolumeRenderingDisplayNode(volume_node)
    if display_node is None:
        display_node = _add_display_node(volume_node, volume_rendering_logic, property_node)
        first = True
    if first:
        restyle_property_node(property_node, design)
    _store(text_node, design)
    update_property_node(property_node, design)
    low, high = volume_node.GetImageData().GetScalarRange()
    property_node.SetEffectiveRange(low, high)
    # Following the volume's window/level would overwrite the transfer function at once.
    display_node.SetFollowVolumeDisplayNode(False)
    if display_node.GetVolumePropertyNode() is not property_node:
        display_node.SetAndObserveVolumePropertyNodeID(property_node.GetID())
    if first:
        display_node.SetVisibility(True)
    return property_node


def apply_design(volume_node, design: TransferFunctionDesign, volume_rendering_logic):
    """Show ``design`` in the volume rendering of ``volume_node``.

    Creates a ``vtkMRMLVolumePropertyNode`` named after the volume (or reuses the one an earlier design of the volume
    wrote), and the design node; attaches the property node to the volume's volume rendering display node (created if
    missing, without a default property node) and makes it visible. The property node shown before, which may hold the
    user's own work, is left in the scene untouched.

    Args:
        volume_node: a ``vtkMRMLScalarVolumeNode`` in a scene.
        design: the transfer function design.
        volume_rendering_logic: ``slicer.modules.volumerendering.logic()`` in Slicer, a
            ``vtkSlicerVolumeRenderingLogic`` headless.

    Returns:
        The property node now shown for the volume.
    """
    return _write(volume_node, design, volume_rendering_logic, first=True)


def update_design(volume_node, design: TransferFunctionDesign, volume_rendering_logic):
    """Store an edited design and rewrite its transfer function in place (shading and visibility left as they are).

    If the volume rendering shows another property node, the design's is shown again: ask the user first
    (:func:`modified_outside`). Returns the design's property node.
    """
    return _write(volume_node, design, volume_rendering_logic, first=False)


# Segments -----------------------------------------------------------------------------------------------------------
def voxel_array(volume_node) -> np.ndarray:
    """The voxels of a scalar volume node, a view indexed ``[k, j, i]`` (like ``slicer.util.arrayFromVolume``)."""
    from vtkmodules.util import numpy_support

    image = volume_node.GetImageData() if volume_node is not None else None
    if image is None or image.GetPointData().GetScalars() is None:
        raise ValueError("The volume holds no image data.")
    if image.GetNumberOfScalarComponents() != 1:
        raise ValueError("The volume must be a single-component (scalar) volume.")
    columns, rows, slices = image.GetDimensions()
    return numpy_support.vtk_to_numpy(image.GetPointData().GetScalars()).reshape(slices, rows, columns)


def ijk_to_ras_directions(volume_node) -> Optional[np.ndarray]:
    """``(3, 3)`` IJK-to-RAS directions of a volume node (column ``c``: the RAS direction of index axis ``c`` = i, j,
    k), which :meth:`.TransferFunctionDesign.thumbnail` takes to show the patient's front; None without a node."""
    if volume_node is None:
        return None
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    matrix = vtkMatrix4x4()
    volume_node.GetIJKToRASDirectionMatrix(matrix)
    return np.array([[matrix.GetElement(row, column) for column in range(3)] for row in range(3)])


def class_label_volume(volume_node, design: TransferFunctionDesign) -> np.ndarray:
    """Class id per voxel (``[k, j, i]``), from the same quantization as the design's."""
    quantized = quantize(voxel_array(volume_node), design.n_bins, tuple(design.value_range))
    return np.asarray(design.labels)[quantized.bins]


#: What a segment is in :func:`export_segmentation`.
SEGMENT_LEVELS = ("class", "tissue")


def _exported_classes(design: TransferFunctionDesign, which: str) -> list:
    if which == "shown":
        return [c for c in design.classes if design.is_shown(c.id)]
    if which == "all":
        return list(design.classes)
    raise ValueError(f"which must be 'shown' or 'all'; got {which!r}")


def segment_name(isovalue_class) -> str:
    """Name of the segment of a class: its number (from 1, as in the module's table) and value range(s)."""
    ranges = ", ".join(f"{low:.6g} to {high:.6g}" for low, high in isovalue_class.value_ranges)
    return f"Class {isovalue_class.id + 1} ({ranges})"


def tissue_segment_name(tissue) -> str:
    """Name of the segment of a tissue: its number (from 1, as in the module's tree) and value range(s)."""
    ranges = ", ".join(f"{low:.6g} to {high:.6g}" for low, high in tissue.value_ranges)
    return f"{'Background' if tissue.background else f'Tissue {tissue.id + 1}'} ({ranges})"


def _segments(design: TransferFunctionDesign, which: str, level: str) -> list:
    """``(segment id, name, colour, class ids)`` of each segment to export."""
    classes = _exported_classes(design, which)
    if level == "class":
        return [(f"class_{c.id + 1}", segment_name(c), c.color, [c.id]) for c in classes]
    if level != "tissue":
        raise ValueError(f"level must be one of {', '.join(SEGMENT_LEVELS)}; got {level!r}")
    exported = {c.id for c in classes}
    segments = []
    for tissue in design.tissues:
        members = [c for c in tissue.classes if c in exported]
        if members:
            segments.append((f"tissue_{tissue.id + 1}", tissue_segment_name(tissue), tissue.color, members))
    return segments


def ensure_segmentation_converters() -> None:
    """Register Slicer's segmentation converter rules unless they already are.

    A segmentation cannot even hold a binary labelmap without them (``AddSegment: Unable to construct empty
    representation type 'Binary labelmap'``). In Slicer the Segmentations module registers them when it starts
    (``vtkSlicerSegmentationsModuleLogic::RegisterNodes``); headless (``slicer-core``) nobody does. Registering them
    here, as that method does, spares a caller from attaching a Segmentations module logic to the scene only for
    this, and from detaching it afterwards, which logs "GetSubjectHierarchyNode: Invalid scene given"
    (``SetMRMLSceneInternal(nullptr)`` asks for the subject hierarchy of no scene).
    """
    import slicer

    factory = slicer.vtkSegmentationConverterFactory.GetInstance()
    probe = factory.ConstructRepresentationObjectByRepresentation(BINARY_LABELMAP)
    if probe is not None:
        probe.UnRegister(None)  # created with a reference for the caller: the Python object now owns it
        return
    for rule in (
        slicer.vtkBinaryLabelmapToClosedSurfaceConversionRule,
        slicer.vtkClosedSurfaceToBinaryLabelmapConversionRule,
        slicer.vtkClosedSurfaceToFractionalLabelmapConversionRule,
        slicer.vtkFractionalLabelmapToClosedSurfaceConversionRule,
    ):
        factory.RegisterConverterRule(rule())


def export_segmentation(volume_node, design: TransferFunctionDesign, which: str = "shown", level: str = "class"):
    """A new ``vtkMRMLSegmentationNode`` with one segment per class or per tissue of the design: its name, colour
    and voxels.

    A voxel belongs to a class's segment exactly when its value falls into one of the class's isovalue bins (the
    quantization the design was made with). The segmentation has the volume's geometry and parent transform.

    Args:
        which: ``"shown"`` (what the transfer function shows) or ``"all"``.
        level: ``"class"``: one segment per class; ``"tissue"``: one segment per tissue, holding the voxels of its
            classes that ``which`` selects (with ``"shown"``: exactly what the 3D view shows of that tissue, a tissue
            none of whose classes is shown has no segment), in the tissue's colour. The default stays ``"class"``
            (the command line's ``classes.seg.nrrd``); the module passes the level its tree shows.
    """
    import slicer
    from vtkmodules.util import numpy_support
    from vtkmodules.vtkCommonCore import vtkStringArray
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    scene = volume_node.GetScene() if volume_node is not None else None
    if scene is None:
        raise ValueError("the volume is not in a scene (was the scene closed?)")
    ensure_segmentation_converters()
    segments = _segments(design, which, level)
    class_ids = class_label_volume(volume_node, design)
    # One byte per voxel whenever it suffices: the labelmap is half as large to compress and save.
    label_of_class = np.zeros(len(design.classes), dtype=np.uint8 if len(segments) < 256 else np.uint16)
    for number, (_, _, _, members) in enumerate(segments, 1):
        label_of_class[members] = number
    labels = np.ascontiguousarray(label_of_class[class_ids])

    labelmap = slicer.vtkOrientedImageData()
    slices, rows, columns = labels.shape
    labelmap.SetDimensions(columns, rows, slices)
    labelmap.GetPointData().SetScalars(numpy_support.numpy_to_vtk(labels.ravel(), deep=True))
    ijk_to_ras = vtkMatrix4x4()
    volume_node.GetIJKToRASMatrix(ijk_to_ras)
    labelmap.SetImageToWorldMatrix(ijk_to_ras)

    name = scene.GenerateUniqueName(f"{volume_node.GetName()} {NODE_NAME_SUFFIX} classes")
    segmentation_node = scene.AddNewNodeByClass("vtkMRMLSegmentationNode", name)
    segmentation_node.SetReferenceImageGeometryParameterFromVolumeNode(volume_node)
    segmentation_node.SetAndObserveTransformNodeID(volume_node.GetTransformNodeID())
    segmentation_node.CreateDefaultDisplayNodes()
    segmentation = segmentation_node.GetSegmentation()
    segment_ids = vtkStringArray()
    for segment_id, segment_name_, color, _ in segments:
        color = [float(c) for c in color]
        added = segmentation.AddEmptySegment(segment_id, segment_name_, color)
        # AddEmptySegment takes grey (0.5, 0.5, 0.5), vtkSegment's "no colour", for a request to pick one.
        segmentation.GetSegment(added).SetColor(*color)
        segment_ids.InsertNextValue(added)
    if segments and not slicer.vtkSlicerSegmentationsModuleLogic.ImportLabelmapToSegmentationNode(
        labelmap, segmentation_node, segment_ids
    ):
        scene.RemoveNode(segmentation_node)
        raise RuntimeError("Slicer could not import the classes into the segmentation")
    return segmentation_node


# Presets ------------------------------------------------------------------------------------------------------------
def _icon_image(rgb: np.ndarray):
    """vtkImageData of an (H, W, 3) uint8 picture, rows top first: Slicer's preset menu mirrors icons vertically."""
    from vtkmodules.util import numpy_support
    from vtkmodules.vtkCommonDataModel import vtkImageData

    height, width = rgb.shape[:2]
    image = vtkImageData()
    image.SetDimensions(width, height, 1)
    scalars = numpy_support.numpy_to_vtk(np.ascontiguousarray(rgb, dtype=np.uint8).reshape(-1, 3), deep=True)
    image.GetPointData().SetScalars(scalars)
    return image


def add_preset(design: TransferFunctionDesign, volume_rendering_logic, name: str):
    """Add the design's transfer function to the Volume Rendering module's preset menu, for use on other volumes.

    The preset has the design's colours, opacities, shading and opacity unit distance, its effective range is the
    design's value range, and its icon is a picture of the transfer function (:func:`.pictures.transfer_function_icon`).
    The preset lasts for the session (Slicer keeps the preset menu in memory).

    Returns:
        The preset node, in ``volume_rendering_logic.GetPresetsScene()``.
    """
    if not name or not name.strip():
        raise ValueError("a preset needs a name")
    presets = volume_rendering_logic.GetPresetsScene()
    preset = presets.CreateNodeByClass("vtkMRMLVolumePropertyNode")
    preset.UnRegister(None)  # created with a reference for the caller: the Python object now owns it
    preset.SetName(name.strip())
    configure_volume_property(preset.GetVolumeProperty(), design.unit_distance, design.gradient_ramp_top)
    design.update_volume_property(preset.GetVolumeProperty())
    preset.SetEffectiveRange(*design.value_range)
    added = volume_rendering_logic.AddPreset(preset, _icon_image(transfer_function_icon(design)))
    if added is None:
        raise RuntimeError("Slicer could not add the preset")
    return added
