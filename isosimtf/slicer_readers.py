"""NRRD, MetaImage, NIfTI and DICOM series, read by Slicer's own reader (PyPI's ``slicer-core``), header first.

Slicer loads these files with ``vtkMRMLVolumeArchetypeStorageNode``, which reads through
``vtkITKArchetypeImageSeriesScalarReader`` (ITK's ImageIO classes; GDCM for DICOM). A DICOM series is grouped and
sorted as Slicer's DICOM module does (by Series Instance UID, then along the slice normal) and its file list handed to
the storage node. Here the same reader, set up as the storage node sets it up, first reads
only the header (``UpdateInformation`` runs ITK's ``ReadImageInformation``), so that the caller can refuse a volume
before any voxel is allocated: a failed allocation crashes the C++ reader, and no Python code can catch that. Then the
storage node itself reads the voxels into a ``vtkMRMLScalarVolumeNode``, so values and geometry (IJK to RAS) are
exactly Slicer's.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from .headers import spacing_problem
from .read_errors import (
    ItemProgress,
    cannot_read,
    captured_native_output,
    first_message,
    itk_reason,
    report_progress,
)

#: File suffixes read by Slicer's ITK-based reader (lower case, longest first); a DICOM file may have any suffix.
ITK_SUFFIXES = (".nii.gz", ".img.gz", ".nrrd", ".nhdr", ".mha", ".mhd", ".nii", ".hdr", ".img", ".dcm")


@dataclass(frozen=True)
class ImageHeader:
    """What the header of an image says, before its voxels are read.

    Attributes:
        dimensions: voxels along i, j, k (a 2-D image has a 1 there).
        components: values per voxel (1 for a scalar volume).
        dtype: the type of the voxel values as Slicer will hold them (e.g. rescaled DICOM values).
        files: the files that hold the voxels: one, or the slices of a DICOM series in order along the slice normal.
        ijk_to_ras: the 4x4 matrix from the voxel indices of the file's own order to RAS millimetres, as the reader
            gives it before the storage node makes a left-handed frame right-handed (:func:`.volume.right_handed`).
    """

    dimensions: tuple[int, int, int]
    components: int
    dtype: np.dtype
    files: tuple[Path, ...]
    ijk_to_ras: np.ndarray


def _slicer() -> Any:
    try:
        import slicer
    except ImportError:  # pragma: no cover - depends on the environment
        raise ImportError(
            "reading NRRD, MetaImage, NIfTI and DICOM needs Slicer's readers: pip install slicer-core"
        ) from None
    return slicer


def is_dicom_file(path: Path) -> bool:
    """Whether ``path`` is a DICOM Part 10 file (the ``DICM`` mark after the 128-byte preamble)."""
    try:
        with open(path, "rb") as handle:
            return handle.read(132)[128:] == b"DICM"
    except OSError:
        return False


def _reader(files: tuple[Path, ...]) -> Any:
    """The reader, configured as ``vtkMRMLVolumeArchetypeStorageNode::ReadDataInternal`` configures it."""
    reader = _slicer().vtkITKArchetypeImageSeriesScalarReader()
    reader.SetArchetype(str(files[0]))
    reader.SetSingleFile(int(len(files) == 1))
    if len(files) > 1:
        for file in files:
            reader.AddFileName(str(file))
    reader.SetUseOrientationFromFile(1)
    reader.SetOutputScalarTypeToNative()
    reader.SetDesiredCoordinateOrientationToNative()
    reader.SetUseNativeOriginOn()
    return reader


_FORMATS = {
    ".nrrd": "NRRD", ".nhdr": "NRRD", ".mha": "MetaImage", ".mhd": "MetaImage", ".nii": "NIfTI", ".gz": "NIfTI",
    ".hdr": "NIfTI", ".img": "NIfTI",
}  # fmt: skip


def _reason(path: Path, texts: list[str]) -> str:
    """The captured C++ error, as a reason a user can act on."""
    message = first_message(texts).replace(str(path), "the file")
    if "contains a 4D image" in message:
        size = message.split("size:", 1)[-1].split(")", 1)[0].strip()
        return f"it is a 4-D image ({size} voxels); a 3-D scalar volume is needed"
    if "Could not create IO object" in message:
        kind = _FORMATS.get(path.suffix.lower(), "DICOM")
        return f"Slicer's readers do not recognise it as {kind} (a malformed header, or not a {kind} file)"
    return message or "Slicer's reader failed without a message"


def read_header(path: Path, files: tuple[Path, ...]) -> ImageHeader:
    """Read only the header of the image held by ``files`` (``path`` names it in messages).

    Raises:
        VolumeReadError: the reader cannot read the header.
    """
    from vtkmodules.util.numpy_support import get_numpy_array_type
    from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline

    reader = _reader(files)
    with captured_native_output() as texts:
        reader.UpdateInformation()
    extent = reader.GetOutputInformation(0).Get(vtkStreamingDemandDrivenPipeline.WHOLE_EXTENT())
    if reader.GetErrorCode() or extent is None:
        raise cannot_read(path, spacing_problem(files[0]) or _reason(files[0], texts))
    dimensions = tuple(int(extent[2 * a + 1] - extent[2 * a] + 1) for a in range(3))
    dtype = np.dtype(get_numpy_array_type(reader.GetOutputScalarType()))
    matrix = reader.GetRasToIjkMatrix()
    ras_to_ijk = np.array([[matrix.GetElement(r, c) for c in range(4)] for r in range(4)])
    if not np.isfinite(ras_to_ijk).all() or abs(np.linalg.det(ras_to_ijk)) < 1e-300:
        raise cannot_read(path, "its header gives a zero or invalid voxel spacing or direction")
    components = int(reader.GetNumberOfComponents())
    return ImageHeader(dimensions, components, dtype, files, np.linalg.inv(ras_to_ijk))  # type: ignore[arg-type]


def _dicom_tags(path: Path) -> dict[str, str]:
    """The DICOM tags of one file (``"gggg|eeee"`` keys), as the reader's header pass gives them; {} if unreadable.

    Call within :func:`captured_native_output`: an unreadable file makes the reader print.
    """
    reader = _reader((path,))
    reader.UpdateInformation()
    if reader.GetErrorCode():
        return {}
    count = reader.GetNumberOfItemsInDictionary()
    return {reader.GetNthKey(n): reader.GetNthValue(n).strip() for n in range(count)}


def _numbers(text: str, count: int) -> Optional[np.ndarray]:
    try:
        values = np.array([float(v) for v in text.split("\\")])
    except ValueError:
        return None
    return values if values.size == count and np.isfinite(values).all() else None


#: DICOM files in one folder above which the read says first how long it will take (:func:`dicom_read_seconds`):
#: about ten seconds here, as the design's own estimate (``run.LONG_DESIGN_VOXELS``). A CT series has hundreds.
MANY_DICOM_FILES = 10_000
#: Seconds per DICOM file of reading a folder: its header read by :func:`dicom_series` (0.38 ms a tiny file here,
#: 3,000 to 24,000 files) ...
SECONDS_PER_DICOM_FILE = 4e-4
#: ... and per pair of files: Slicer's reader of a file list takes time growing with the square of its length (its
#: header pass and storage node: 0.3 s and 0.8 s for 3,000 tiny files, 1.0 and 5.9 s for 12,000, 3.3 and 25.9 s for
#: 24,000; 5e-8 s a pair).
SECONDS_PER_DICOM_FILE_PAIR = 5e-8


def dicom_read_seconds(files: int) -> float:
    """About how many seconds reading a series folder of ``files`` DICOM files takes here (headers, then voxels)."""
    return SECONDS_PER_DICOM_FILE * files + SECONDS_PER_DICOM_FILE_PAIR * files * files


def _duration(seconds: float) -> str:
    """``seconds`` in the largest unit that keeps a number above 1: "40 s", "12 minutes", "3.5 hours"."""
    for unit, size in (("hours", 3600.0), ("minutes", 60.0)):
        if seconds >= 2 * size:
            return f"{seconds / size:.2g} {unit}"
    return f"{seconds:.0f} s"


def dicom_series(path: Path, warn: Optional[Callable[[str], None]] = None) -> tuple[Path, ...]:
    """The slices of one DICOM series, sorted along the slice normal as Slicer's DICOM module sorts them.

    ``path`` is a folder holding one series, or a DICOM file (its series is read from its folder). Slicer's reader
    alone would take the slices in file-name order; its DICOM module sorts them by Image Position (Patient) along the
    normal of Image Orientation (Patient) and hands the sorted list to the storage node, as done here.

    A folder of more than :data:`MANY_DICOM_FILES` DICOM files says first, through ``warn``, about how long reading
    it takes (:func:`dicom_read_seconds`); every pass over the files shows its progress
    (:func:`.read_errors.report_progress`, on the command's progress line).

    Raises:
        VolumeReadError: no DICOM file (or only subfolders); several series in the folder (named, with advice);
            slices without position or orientation, sharing a position, of mixed orientations or sizes, or not
            equally spaced (missing slices).
    """
    folder = path if path.is_dir() else path.parent
    entries = sorted(p for p in folder.iterdir() if not p.name.startswith("."))
    files = [p for p in entries if p.is_file()]
    subfolders = [p for p in entries if p.is_dir()]
    looking = ItemProgress("looking for DICOM files", len(files))
    dicom = []
    for count, file in enumerate(files, 1):
        if is_dicom_file(file):
            dicom.append(file)
        looking.done(count)
    if path.is_dir() and not dicom and subfolders:
        raise cannot_read(
            path,
            f"it holds no DICOM file itself but {len(subfolders)} subfolder(s) (e.g. '{subfolders[0].name}'): "
            "give the folder of one series as INPUT (series are not searched for in subfolders)",
        )
    if path.is_dir() and not files:
        raise cannot_read(path, "the folder is empty (a DICOM series folder was expected)")
    if not dicom:
        raise cannot_read(path, f"no DICOM files found in the folder ({len(files)} other file(s))")
    if len(dicom) > MANY_DICOM_FILES and warn is not None:
        warn(
            f"'{folder}' holds {len(dicom)} DICOM files: reading their headers and voxels takes about "
            f"{_duration(dicom_read_seconds(len(dicom)))} here (Slicer's reader slows down with the square of the "
            "number of files); Ctrl+C stops it"
        )
    series: dict[str, list[tuple[Path, dict[str, str]]]] = {}
    headers = ItemProgress("DICOM headers", len(dicom))
    with captured_native_output():
        for count, file in enumerate(dicom, 1):
            tags = _dicom_tags(file)
            if tags:
                series.setdefault(tags.get("0020|000e", ""), []).append((file, tags))
            headers.done(count)
    if path.is_dir() and len(series) > 1:
        listed = "; ".join(f"{len(members)} file(s) from {members[0][0].name}" for members in series.values())
        raise cannot_read(
            path,
            f"the folder holds {len(series)} DICOM series ({listed}); give one file of the series to read as INPUT",
        )
    chosen = next((m for m in series.values() if path.is_dir() or any(f == path for f, _ in m)), None)
    if chosen is None:
        raise cannot_read(path, "Slicer's DICOM reader cannot read its header")
    return _sorted_slices(path, chosen)


#: Largest difference between two slice gaps of one volume, in mm: Slicer's DICOM scalar volume plugin's epsilon.
SLICE_GAP_TOLERANCE_MM = 0.01
#: Largest difference between two slices' orientation cosines taken for the same orientation.
ORIENTATION_TOLERANCE = 1e-4


def _sorted_slices(path: Path, members: list[tuple[Path, dict[str, str]]]) -> tuple[Path, ...]:
    """The slices in order along the normal, refused (with the reason and the fix) where Slicer's DICOM module
    would warn that the series is not one regular volume: mixed orientations or sizes, slices sharing a position,
    missing slices or uneven gaps. Slicer's reader would then read a wrong spacing or origin without a word."""
    if len(members) == 1:
        return (members[0][0],)  # one file: a single slice, or a multi-frame volume
    orientation = _numbers(members[0][1].get("0020|0037", ""), 6)
    positions = [_numbers(tags.get("0020|0032", ""), 3) for _, tags in members]
    if orientation is None or any(p is None for p in positions):
        raise cannot_read(path, "some slices lack a valid Image Position or Image Orientation (Patient)")
    others = [
        file
        for file, tags in members
        if (o := _numbers(tags.get("0020|0037", ""), 6)) is None
        or np.abs(o - orientation).max() > ORIENTATION_TOLERANCE
    ]
    if others:
        raise cannot_read(
            path,
            f"{len(others)} of its {len(members)} slices (e.g. {others[0].name}) have another Image Orientation than "
            f"{members[0][0].name} (a localizer or a tilted stack in the series): move them to another folder",
        )
    sizes = {(tags.get("0028|0010"), tags.get("0028|0011")) for _, tags in members}
    if len(sizes) > 1:
        listed = ", ".join(f"{r} x {c}" for r, c in sorted(sizes, key=str))
        raise cannot_read(path, f"its slices have different sizes ({listed} pixels): keep one size in the folder")
    normal = np.cross(orientation[:3], orientation[3:])
    distances = np.array([float(np.dot(p, normal)) for p in positions])  # type: ignore[arg-type]
    order = np.argsort(distances, kind="stable")
    gaps = np.diff(distances[order])
    if np.any(gaps <= 1e-6 * max(1.0, float(np.ptp(distances)))):
        raise cannot_read(path, "several slices of the series share one position (more than one volume in the series)")
    usual = float(np.median(gaps))
    uneven = np.flatnonzero(np.abs(gaps - usual) > SLICE_GAP_TOLERANCE_MM)
    if uneven.size:
        n = int(uneven[0])
        first, second = members[order[n]][0].name, members[order[n + 1]][0].name
        missing = int(round(float(np.sum(gaps[uneven] / usual - 1.0))))
        what = f"about {missing} missing slice(s)" if missing >= 1 else "uneven slice gaps"
        raise cannot_read(
            path,
            f"its slices are not equally spaced ({what}: gaps of {usual:.4g} mm, but {gaps[n]:.4g} mm between "
            f"{first} and {second}; {uneven.size} uneven gap(s)): a volume needs equally spaced slices; add the "
            "missing slices, or read the series in Slicer's DICOM module, which warns and can regularize it",
        )
    return tuple(members[n][0] for n in order)


def read_image(path: Path, header: ImageHeader) -> tuple[np.ndarray, np.ndarray]:
    """Read the voxels with Slicer's storage node: ``(values (K, J, I), IJK-to-RAS 4x4 matrix)``.

    Call after :func:`read_header` accepted the size: this allocates the whole volume. ``path`` names the image in
    messages.

    Raises:
        VolumeReadError: the voxels cannot be read (truncated or corrupt data).
    """
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkCommand
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    slicer = _slicer()
    scene = slicer.vtkMRMLScene()
    node = scene.AddNewNodeByClass("vtkMRMLScalarVolumeNode")
    storage = scene.AddNewNodeByClass("vtkMRMLVolumeArchetypeStorageNode")
    storage.SetFileName(str(header.files[0]))
    storage.SetSingleFile(int(len(header.files) == 1))
    if len(header.files) > 1:
        storage.ResetFileNameList()
        for file in header.files:
            storage.AddFileName(str(file))
    node.SetAndObserveStorageNodeID(storage.GetID())
    if len(header.files) > 1:  # a series: its slices' progress on the command's progress line
        storage.AddObserver(vtkCommand.ProgressEvent, _slices_progress(len(header.files)))
    with captured_native_output() as texts:
        read = storage.ReadData(node)
    image = node.GetImageData()
    scalars = image.GetPointData().GetScalars() if read and image is not None else None
    i, j, k = header.dimensions
    if scalars is None or scalars.GetNumberOfValues() != i * j * k:
        messages = storage.GetUserMessages()
        first = messages.GetNthMessageText(0) if messages.GetNumberOfMessages() else ""
        detail = itk_reason(first).replace(str(header.files[0]), "the file") or _reason(header.files[0], texts)
        if "encoding not available" in detail:  # e.g. bzip2, which NrrdIO is built without: the file may be fine
            raise cannot_read(path, f"Slicer's reader cannot decode its encoding ({detail}): save it raw or gzip")
        raise cannot_read(path, f"the voxel data are truncated or corrupt ({detail})")
    matrix = vtkMatrix4x4()
    node.GetIJKToRASMatrix(matrix)
    ijk_to_ras = np.array([[matrix.GetElement(r, c) for c in range(4)] for r in range(4)])
    # A view on Slicer's buffer (it keeps the VTK array alive): no copy of a volume that may be large.
    return vtk_to_numpy(scalars).reshape(k, j, i), ijk_to_ras


def _slices_progress(count: int) -> Callable[[Any, str, float], None]:
    """An observer of the storage node's progress events (their call data: the fraction read) that shows them."""
    from vtkmodules.util.misc import calldata_type
    from vtkmodules.util.vtkConstants import VTK_DOUBLE

    @calldata_type(VTK_DOUBLE)
    def show(caller: Any, event: str, fraction: float) -> None:
        report_progress(f"reading {count} slices", float(fraction))

    return show
