"""Write test volumes: NRRD, MetaImage and NIfTI through Slicer's own storage node, VTK image data, and .npy.

Test-only: the command line reads volumes, it never writes them. Writing through
``vtkMRMLVolumeArchetypeStorageNode`` (PyPI's ``slicer-core``) gives files as Slicer saves them, in each format's own
world convention (LPS for NRRD and MetaImage, RAS for NIfTI).
"""

from pathlib import Path

import numpy as np

from isosimtf.volume_io import Volume

SLICER_SUFFIXES = (".nrrd", ".nhdr", ".mha", ".mhd", ".nii", ".nii.gz")


def _vtk_image(values: np.ndarray):
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonDataModel import vtkImageData

    values = np.ascontiguousarray(values)
    image = vtkImageData()
    image.SetDimensions(*values.shape[::-1])
    image.GetPointData().SetScalars(numpy_to_vtk(values.ravel(), deep=True))
    return image


def _vtk_matrix(array: np.ndarray):
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    matrix = vtkMatrix4x4()
    for r in range(4):
        for c in range(4):
            matrix.SetElement(r, c, float(array[r, c]))
    return matrix


def write_volume(volume: Volume, path: Path, *, compress: bool = True) -> None:
    """Write ``volume`` to ``path``; the format follows the suffix (``.npy`` keeps the values only)."""
    path = Path(path)
    lower = path.name.lower()
    if lower.endswith(".npy"):
        np.save(path, volume.values, allow_pickle=False)
    elif lower.endswith(".vti"):
        from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

        image = _vtk_image(volume.values)
        image.SetSpacing(*volume.spacing)
        image.SetOrigin(*volume.origin)
        image.SetDirectionMatrix(*[float(v) for v in volume.directions.ravel()])
        writer = vtkXMLImageDataWriter()
        writer.SetFileName(str(path))
        writer.SetInputData(image)
        if not writer.Write():
            raise OSError(f"cannot write {path}")
    elif lower.endswith(SLICER_SUFFIXES):
        import slicer

        scene = slicer.vtkMRMLScene()
        node = scene.AddNewNodeByClass("vtkMRMLScalarVolumeNode")
        node.SetAndObserveImageData(_vtk_image(volume.values))
        node.SetIJKToRASMatrix(_vtk_matrix(volume.ijk_to_ras()))
        storage = scene.AddNewNodeByClass("vtkMRMLVolumeArchetypeStorageNode")
        storage.SetFileName(str(path))
        storage.SetUseCompression(int(compress))
        if not storage.WriteData(node):
            raise OSError(f"cannot write {path}")
    else:
        raise ValueError(f"cannot write {path}: unknown suffix")
