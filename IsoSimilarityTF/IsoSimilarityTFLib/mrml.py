"""Slicer side of the pipeline: show a design in a volume's 3D rendering, without Qt.

Imports only Slicer's MRML classes (through the objects it is given) and VTK: it runs inside the Slicer application
and headless with PyPI's ``slicer-core`` alike. The design travels with its property node as a JSON attribute, so it
survives saving and reopening the scene.
"""

import logging
from typing import Optional

from .design import TransferFunctionDesign
from .transfer_function import configure_volume_property

DESIGN_ATTRIBUTE = "IsoSimilarityTF.Design"
# A node reference (not an attribute) so the link follows node ID changes on scene import.
VOLUME_REFERENCE_ROLE = "IsoSimilarityTFVolume"
NODE_NAME_SUFFIX = "IsoSimilarityTF"


def design_node_of(volume_node) -> Optional[object]:
    """The ``vtkMRMLVolumePropertyNode`` our design wrote for this volume, or None."""
    scene = volume_node.GetScene() if volume_node is not None else None
    if scene is None:
        return None
    for index in range(scene.GetNumberOfNodesByClass("vtkMRMLVolumePropertyNode")):
        node = scene.GetNthNodeByClass(index, "vtkMRMLVolumePropertyNode")
        if node.GetNodeReferenceID(VOLUME_REFERENCE_ROLE) == volume_node.GetID():
            return node
    return None


def design_of(property_node) -> Optional[TransferFunctionDesign]:
    """The design stored on a property node (None when it holds none or an unreadable one)."""
    text = property_node.GetAttribute(DESIGN_ATTRIBUTE) if property_node is not None else None
    if not text:
        return None
    try:
        return TransferFunctionDesign.from_json(text)
    except ValueError as error:
        logging.warning("Ignoring the IsoSimilarityTF design stored on %s: %s", property_node.GetName(), error)
        return None


def update_property_node(property_node, design: TransferFunctionDesign) -> None:
    """Rewrite the node's transfer function from the design, in place, and store the design with it."""
    design.update_volume_property(property_node.GetVolumeProperty())
    property_node.SetAttribute(DESIGN_ATTRIBUTE, design.to_json())


def apply_design(volume_node, design: TransferFunctionDesign, volume_rendering_logic):
    """Show ``design`` in the volume rendering of ``volume_node``.

    Creates a ``vtkMRMLVolumePropertyNode`` named after the volume (or reuses the one an earlier run made for it),
    attaches it to the volume's volume rendering display node (created if missing), and leaves the property node
    shown before, which may hold the user's own work, in the scene untouched.

    Args:
        volume_node: a ``vtkMRMLScalarVolumeNode`` in a scene.
        design: the transfer function design.
        volume_rendering_logic: ``slicer.modules.volumerendering.logic()`` in Slicer, a
            ``vtkSlicerVolumeRenderingLogic`` headless.

    Returns:
        The property node now shown for the volume.
    """
    scene = volume_node.GetScene() if volume_node is not None else None
    if scene is None:
        raise ValueError("the volume is not in a scene (was the scene closed?)")
    display_node = volume_rendering_logic.GetFirstVolumeRenderingDisplayNode(volume_node)
    if display_node is None:
        display_node = volume_rendering_logic.CreateDefaultVolumeRenderingNodes(volume_node)
    property_node = design_node_of(volume_node)
    if property_node is None:
        name = scene.GenerateUniqueName(f"{volume_node.GetName()} {NODE_NAME_SUFFIX}")
        property_node = scene.AddNewNodeByClass("vtkMRMLVolumePropertyNode", name)
        property_node.SetNodeReferenceID(VOLUME_REFERENCE_ROLE, volume_node.GetID())
    configure_volume_property(property_node.GetVolumeProperty(), design.unit_distance, design.gradient_ramp_top)
    update_property_node(property_node, design)
    low, high = volume_node.GetImageData().GetScalarRange()
    property_node.SetEffectiveRange(low, high)
    # Following the volume's window/level would overwrite the transfer function at once.
    display_node.SetFollowVolumeDisplayNode(False)
    display_node.SetAndObserveVolumePropertyNodeID(property_node.GetID())
    display_node.SetVisibility(True)
    return property_node
