"""Write test volumes: NRRD, MetaImage and NIfTI through Slicer's own storage node, VTK image data, and .npy; and
NIfTI-2 and NIfTI pairs (``.hdr`` / ``.img``), which Slicer does not write, from the standard's header layout.

Test-only: the command line reads volumes, it never writes them. Writing through
``vtkMRMLVolumeArchetypeStorageNode`` (PyPI's ``slicer-core``) gives files as Slicer saves them, in each format's own
world convention (LPS for NRRD and MetaImage, RAS for NIfTI).
"""

import gzip
import struct
from pathlib import Path
from typing import Optional

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


#: NIfTI datatype codes of the types written by :func:`write_nifti`.
_NIFTI_DATATYPES = {np.dtype(np.uint8): 2, np.dtype(np.int16): 4, np.dtype(np.float32): 16}


def write_nifti(
    path: Path,
    values: np.ndarray,
    ijk_to_ras: np.ndarray,
    *,
    version: int = 2,
    slope: float = 1.0,
    inter: float = 0.0,
    magic: Optional[bytes] = None,
) -> None:
    """Write NIfTI-1 or NIfTI-2, one file (``.nii``, ``.nii.gz``) or a pair (``.hdr`` and ``.img``), little-endian,
    byte by byte from the standard's layout: Slicer's writer writes neither NIfTI-2 nor a pair.

    The geometry is the sform (code 2, aligned anatomical) ``ijk_to_ras`` (NIfTI's world is RAS), the qform unset;
    ``magic`` replaces the standard's (``b"\\0\\0\\0\\0"``: an Analyze 7.5 header).
    """
    path = Path(path)
    pair = path.suffix.lower() == ".hdr"
    k, j, i = values.shape
    spacing = np.linalg.norm(ijk_to_ras[:3, :3], axis=0)
    code, bitpix = _NIFTI_DATATYPES[values.dtype], values.dtype.itemsize * 8
    size = 348 if version == 1 else 540
    offset = 0 if pair else size + 4  # after the 4 bytes saying there is no extension
    header = bytearray(size)
    if version == 1:
        struct.pack_into("<i", header, 0, size)
        struct.pack_into("<8h", header, 40, 3, i, j, k, 1, 1, 1, 1)
        struct.pack_into("<2h", header, 70, code, bitpix)
        struct.pack_into("<8f", header, 76, 1.0, *spacing, 0.0, 0.0, 0.0, 0.0)
        struct.pack_into("<3f", header, 108, offset, slope, inter)
        header[123] = 2  # xyzt_units: millimetres
        struct.pack_into("<2h", header, 252, 0, 2)
        struct.pack_into("<12f", header, 280, *ijk_to_ras[:3].ravel())
        header[344:348] = magic if magic is not None else b"ni1\0" if pair else b"n+1\0"
    else:
        struct.pack_into("<i", header, 0, size)
        header[4:12] = (magic if magic is not None else b"ni2\0" if pair else b"n+2\0") + b"\r\n\x1a\n"
        struct.pack_into("<2h", header, 12, code, bitpix)
        struct.pack_into("<8q", header, 16, 3, i, j, k, 1, 1, 1, 1)
        struct.pack_into("<8d", header, 104, 1.0, *spacing, 0.0, 0.0, 0.0, 0.0)
        struct.pack_into("<q2d", header, 168, offset, slope, inter)
        struct.pack_into("<2i", header, 344, 0, 2)
        struct.pack_into("<12d", header, 400, *ijk_to_ras[:3].ravel())
        struct.pack_into("<i", header, 500, 2)  # xyzt_units: millimetres
    voxels = np.ascontiguousarray(values, dtype=values.dtype.newbyteorder("<")).tobytes()
    if pair:
        path.write_bytes(bytes(header) + bytes(4))
        path.with_suffix(".img").write_bytes(voxels)
    else:
        data = bytes(header) + bytes(4) + voxels
        path.write_bytes(gzip.compress(data) if path.name.lower().endswith(".gz") else data)
