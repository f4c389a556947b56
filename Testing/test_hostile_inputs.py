"""Hostile inputs (issue 26): each is refused in one line (exit 2), or read right, never a hang, a traceback, unbounded
memory or a plausible wrong answer with exit 0. Every case runs ``isosimtf INPUT -o OUT --no-render -q``.

Runs that waited forever before the fix carry a deadline: in-process runs an alarm (a FIFO opened in the main thread
is interrupted), Zarr runs (whose chunks dask reads in worker threads, which no alarm interrupts) a subprocess with a
timeout and a bounded address space (a chunk linked to /dev/zero was read without end).
"""

import gzip
import io
import json
import os
import plistlib
import struct
import subprocess
import sys
import tarfile
import time
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
from deadlines import deadline
from volume_writers import write_volume

from IsoSimilarityTFLib import memory
from IsoSimilarityTFLib.quantize import MAX_VALUE_MAGNITUDE, quantize
from IsoSimilarityTFLib.value_range import robust_value_range
from isosimtf import cli
from isosimtf.rendering import slicer_core_available
from isosimtf.volume_io import MAX_INV3_PLIST_BYTES, MAX_NIFTI_EXTENSION_BYTES, Volume

needs_slicer = pytest.mark.skipif(not slicer_core_available(), reason="slicer-core is not installed")

#: Seconds a run may take before it is taken for hung (every run here ends in about one).
DEADLINE = 20
NI, NJ, NK = 8, 7, 6
NRRD = f"NRRD0004\ntype: short\ndimension: 3\nsizes: {NI} {NJ} {NK}\nendian: little\nencoding: raw\n"
MHA = f"ObjectType = Image\nNDims = 3\nDimSize = {NI} {NJ} {NK}\nElementType = MET_SHORT\n"


def _values(dtype=np.int16) -> np.ndarray:
    """A small volume (NK, NJ, NI) with a few distinct intensities, different along every axis."""
    return (np.arange(NK * NJ * NI).reshape(NK, NJ, NI) % 50 * 10).astype(dtype)


def _run(source: Path, tmp_path: Path, capfd) -> tuple[int, str]:
    """``isosimtf SOURCE -o OUT --no-render -q`` in this process: its exit status and standard error."""
    with deadline(DEADLINE):
        code = cli.main([str(source), "-o", str(tmp_path / "out"), "--no-render", "-q"])
    return code, capfd.readouterr().err


def _refused(source: Path, tmp_path: Path, capfd) -> str:
    """The one error line of a run refusing ``source`` as an input error (exit 2)."""
    code, err = _run(source, tmp_path, capfd)
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("isosimtf: error: "), err
    return err


#: Runs ``isosimtf`` (``python -m isosimtf``) with its address space bounded to the first argument, in bytes.
_BOUNDED_ISOSIMTF = (
    "import resource, runpy, sys; limit = int(sys.argv.pop(1)); "
    "resource.setrlimit(resource.RLIMIT_AS, (limit, limit)); runpy.run_module('isosimtf', run_name='__main__')"
)


def _refused_in_a_process(source: Path, tmp_path: Path) -> str:
    """The one error line of ``isosimtf`` refusing ``source``, run in a subprocess (3 GiB of address space)."""
    argv = [str(source), "-o", str(tmp_path / "out"), "--no-render", "-q"]
    done = subprocess.run(
        [sys.executable, "-c", _BOUNDED_ISOSIMTF, str(3 << 30), *argv],
        capture_output=True,
        text=True,
        timeout=DEADLINE,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("isosimtf: error: "), done.stderr
    return done.stderr


# ---------------------------------------------------------------------------------------------------------------
# 1. Every file read for voxels is a regular file
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("header", "text"),
    [
        ("v.nhdr", NRRD + "data file: x.raw\n"),
        ("v.nhdr", NRRD.replace(f"{NK}\n", "2\n") + "data file: LIST\na.raw\nx.raw\n"),
        ("v.nhdr", NRRD.replace(f"{NK}\n", "2\n") + "data file: slice%d.raw 0 1 1\n"),
        ("v.mhd", MHA + "ElementDataFile = x.raw\n"),
        ("v.mhd", MHA.replace(f"{NK}\n", "2\n") + "ElementDataFile = LIST\na.raw\nx.raw\n"),
        ("v.mhd", MHA.replace(f"{NK}\n", "2\n") + "ElementDataFile = slice%d.raw 0 1 1"),  # last line without end
    ],
    ids=["nrrd", "nrrd-list", "nrrd-pattern", "metaimage", "metaimage-list", "metaimage-pattern"],
)
def test_a_fifo_as_a_data_file_is_refused_before_it_is_opened(tmp_path: Path, capfd, header: str, text: str) -> None:
    """Before: LIST and pattern forms waited forever in Slicer's reader; one data file was said not to exist."""
    (tmp_path / header).write_text(text)
    for plane in ("a.raw", "slice0.raw"):
        (tmp_path / plane).write_bytes(_values()[0].tobytes())
    fifo = tmp_path / ("slice1.raw" if "%d" in text else "x.raw")
    os.mkfifo(fifo)
    err = _refused(tmp_path / header, tmp_path, capfd)
    assert f"its data file '{fifo}' is not a regular file (a FIFO, socket or device)" in err


def test_a_fifo_as_the_input_is_refused(tmp_path: Path, capfd) -> None:
    """Refused before too; now by the check every data file goes through."""
    os.mkfifo(tmp_path / "v.nrrd")
    assert "it is not a regular file (a FIFO, socket or device)" in _refused(tmp_path / "v.nrrd", tmp_path, capfd)


def test_a_fifo_in_a_folder_of_tiff_planes_is_refused(tmp_path: Path, capfd) -> None:
    tifffile = pytest.importorskip("tifffile")
    stack = tmp_path / "planes"
    stack.mkdir()
    for k, plane in enumerate(_values(np.uint16)[:-1]):
        tifffile.imwrite(stack / f"z{k}.tif", plane)
    os.mkfifo(stack / f"z{NK - 1}.tif")
    err = _refused(stack, tmp_path, capfd)
    assert f"its TIFF plane '{stack / f'z{NK - 1}.tif'}' is not a regular file" in err


@pytest.mark.parametrize("chunk", ["fifo", "link-to-dev-zero"])
def test_a_zarr_chunk_that_is_not_a_regular_file_is_refused(tmp_path: Path, chunk: str) -> None:
    """Before: a FIFO chunk waited forever, a chunk linked to /dev/zero was read until memory ran out."""
    zarr = pytest.importorskip("zarr")
    store = tmp_path / "v.zarr"
    zarr.create_array(str(store), data=_values(), chunks=(3, NJ, NI))
    last = max(p for p in store.rglob("*") if p.is_file() and p.name not in ("zarr.json", ".zarray", ".zgroup"))
    last.unlink()
    if chunk == "fifo":
        os.mkfifo(last)
    else:
        last.symlink_to("/dev/zero")
    err = _refused_in_a_process(store, tmp_path)
    link = " (a link to '/dev/zero')" if chunk != "fifo" else ""
    assert f"its file '{last}'{link} is not a regular file (a FIFO, socket or device)" in err


@pytest.mark.parametrize("emptied", [True, False])
def test_a_zarr_chunk_replaced_by_a_folder_is_refused_not_read_as_fill(tmp_path: Path, capfd, emptied: bool) -> None:
    """Before: zarr read the chunk as missing, i.e. as the fill value, and the design ran (exit 0). A folder that
    still holds a file is a store's own layout and is read."""
    zarr = pytest.importorskip("zarr")
    store = tmp_path / "v.zarr"
    zarr.create_array(str(store), data=_values(), chunks=(3, NJ, NI))
    last = max(p for p in store.rglob("*") if p.is_file() and p.name not in ("zarr.json", ".zarray", ".zgroup"))
    if emptied:
        last.unlink()
        last.mkdir()
        assert f"its folder '{last}' is empty" in _refused(store, tmp_path, capfd)
    else:
        (store / "notes").mkdir()
        (store / "notes" / "readme.txt").write_text("kept beside the array")
        assert _run(store, tmp_path, capfd)[0] == 0


# ---------------------------------------------------------------------------------------------------------------
# 2. A VTK image whose extent does not start at 0
# ---------------------------------------------------------------------------------------------------------------


@needs_slicer
def test_a_vti_extent_not_starting_at_0_places_the_voxels_as_vtk_does(tmp_path: Path, capfd) -> None:
    """Before: voxel 0 was placed at the origin, the volume shifted by 5 voxels along i with exit 0."""
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    image = vtkImageData()
    image.SetExtent(5, 5 + NI - 1, 0, NJ - 1, 0, NK - 1)
    image.SetSpacing(0.5, 2.0, 3.0)
    image.SetOrigin(1.0, 2.0, 3.0)
    image.SetDirectionMatrix(0, -1, 0, 1, 0, 0, 0, 0, 1)
    image.GetPointData().SetScalars(numpy_to_vtk(_values().ravel(), deep=True))
    writer = vtkXMLImageDataWriter()
    writer.SetFileName(str(tmp_path / "v.vti"))
    writer.SetInputData(image)
    assert writer.Write()
    code, err = _run(tmp_path / "v.vti", tmp_path, capfd)
    assert code == 0, err
    ijk_to_ras = np.array(json.loads((tmp_path / "out" / "classes.json").read_text())["input"]["ijk_to_ras"])
    for index in [(0, 0, 0), (NI - 1, 0, 0), (2, 3, 4)]:  # the file's voxel (i, j, k) is VTK's point (5 + i, j, k)
        truth = [0.0, 0.0, 0.0]
        image.TransformIndexToPhysicalPoint(5 + index[0], index[1], index[2], truth)
        np.testing.assert_allclose(ijk_to_ras @ [*index, 1.0], [*truth, 1.0], atol=1e-9)


# ---------------------------------------------------------------------------------------------------------------
# 3. A compressed MetaImage whose CompressedDataSize is not its compressed size
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("local", "error"), [(True, -10), (True, 100), (False, -50)])
def test_a_wrong_compressed_data_size_is_refused(tmp_path: Path, capfd, local: bool, error: int) -> None:
    """Before: a smaller size read voxels of garbage with exit 0 (a larger one failed with an unrelated reason)."""
    compressed = zlib.compress(_values().tobytes())
    header = MHA + f"CompressedData = True\nCompressedDataSize = {len(compressed) + error}\n"
    if local:
        path = tmp_path / "v.mha"
        path.write_bytes(f"{header}ElementDataFile = LOCAL\n".encode() + compressed)
    else:
        path = tmp_path / "v.mhd"
        path.write_text(f"{header}ElementDataFile = v.zraw\n")
        (tmp_path / "v.zraw").write_bytes(compressed)
    err = _refused(path, tmp_path, capfd)
    assert f"it says CompressedDataSize = {len(compressed) + error}, but {len(compressed)} bytes" in err


# ---------------------------------------------------------------------------------------------------------------
# 4. Values near the float64 maximum
# ---------------------------------------------------------------------------------------------------------------


def test_values_near_the_float64_maximum_are_refused_without_warnings(tmp_path: Path, capfd) -> None:
    """Before: numpy's overflow warnings on stderr, one class and every colour white, with exit 0."""
    values = np.zeros((NK, NJ, NI))
    values[: NK // 2], values[NK // 2 :] = -1.7e308, 1.7e308
    values[1, 2, 3] = 0.0
    np.save(tmp_path / "v.npy", values)
    err = _refused(tmp_path / "v.npy", tmp_path, capfd)
    assert "the value range [-1.7e+308, 1.7e+308] reaches beyond" in err and "Warning" not in err
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="reaches beyond"):
            quantize(values)
        # Up to the bound, the bins are right and nothing overflows.
        bound = np.array([-1.0, -0.5, 0.0, 0.5, 1.0]) * MAX_VALUE_MAGNITUDE
        at_bound = np.broadcast_to(bound, (2, 2, 5))
        assert robust_value_range(at_bound).value_range == (-MAX_VALUE_MAGNITUDE, MAX_VALUE_MAGNITUDE)
        np.testing.assert_array_equal(quantize(at_bound, n_bins=4).bins[0, 0], [0, 1, 2, 3, 3])


# ---------------------------------------------------------------------------------------------------------------
# 5. NIfTI header extensions
# ---------------------------------------------------------------------------------------------------------------


def _nifti_with_extension(path: Path, extension_bytes: int, *, declared: int = 0) -> None:
    """A NIfTI-1 file (Slicer's own writing) with ``extension_bytes`` of zeros as a header extension between the
    header and the voxels; ``declared``: a larger extension (and vox_offset) than the file holds."""
    plain = path.with_name("plain.nii")
    write_volume(Volume(_values(), name="v"), plain, compress=False)
    data = plain.read_bytes()
    size = declared or extension_bytes
    header = bytearray(data[:348])
    struct.pack_into("<f", header, 108, float(352 + size))  # vox_offset
    extension = struct.pack("<4B2i", 1, 0, 0, 0, size, 0) + bytes(extension_bytes - 8)
    with gzip.open(path, "wb", compresslevel=1) if path.name.endswith(".gz") else open(path, "wb") as handle:
        handle.write(bytes(header) + extension + data[352:])


@needs_slicer
@pytest.mark.parametrize("name", ["v.nii", "v.nii.gz"])
def test_a_nifti_extension_past_the_end_of_the_file_is_refused(tmp_path: Path, capfd, name: str) -> None:
    _nifti_with_extension(tmp_path / name, 16, declared=3 << 29)  # 1.5 GiB declared
    vox_offset = int(np.float32(352 + (3 << 29)))
    err = _refused(tmp_path / name, tmp_path, capfd)
    assert f"it is truncated: its voxels start at byte {vox_offset} (vox_offset), past its end" in err


@needs_slicer
def test_a_nifti_extension_beyond_the_bound_is_refused_before_slicer_reads_it(tmp_path: Path, capfd) -> None:
    """Before: a 90 KB .nii.gz holding 80 MiB of extension was read (Slicer's reader holds it in memory)."""
    _nifti_with_extension(tmp_path / "v.nii.gz", MAX_NIFTI_EXTENSION_BYTES + (16 << 20))
    assert (tmp_path / "v.nii.gz").stat().st_size < 1 << 20
    assert "its header extensions take 80 MiB" in _refused(tmp_path / "v.nii.gz", tmp_path, capfd)


@needs_slicer
def test_nifti_extensions_count_in_the_memory_check(tmp_path: Path, capfd, monkeypatch) -> None:
    """Before: the memory check counted the voxels only, not the extensions Slicer's reader holds beside them."""
    _nifti_with_extension(tmp_path / "v.nii", 4 << 20)
    needed_without = memory.design_memory_bytes((NK, NJ, NI), 256) + _values().nbytes
    monkeypatch.setattr(memory, "available_memory_bytes", lambda: needed_without + (1 << 20))
    code, err = _run(tmp_path / "v.nii", tmp_path, capfd)
    assert code == 1 and err.count("\n") == 1 and f"a volume of {NK} x {NJ} x {NI} voxels" in err, err
    monkeypatch.setattr(memory, "available_memory_bytes", lambda: needed_without + (5 << 20))
    assert _run(tmp_path / "v.nii", tmp_path, capfd)[0] == 0


# ---------------------------------------------------------------------------------------------------------------
# 6. InVesalius projects
# ---------------------------------------------------------------------------------------------------------------


def _inv3(path: Path, *, empty_members: int = 0, plist_padding: int = 0, dtype: str = "int16", voxels=None) -> None:
    """An InVesalius project: ``empty_members`` empty files, then main.plist (followed by ``plist_padding`` zero
    bytes) and matrix.dat."""
    voxels = _values().tobytes() if voxels is None else voxels
    main = {"matrix": {"shape": [NK, NJ, NI], "dtype": dtype, "filename": "matrix.dat"}, "spacing": [1.0, 1.0, 1.0]}
    members = [("main.plist", plistlib.dumps(main) + bytes(plist_padding)), ("matrix.dat", voxels)]
    with tarfile.open(path, "w:gz", compresslevel=1) as archive:
        empty = tarfile.TarInfo("project/empty")
        for n in range(empty_members):
            empty.name = f"project/empty_{n}"
            archive.addfile(empty)
        for name, data in members:
            info = tarfile.TarInfo(f"project/{name}")
            info.size = len(data)
            archive.addfile(info, io.BytesIO(data))


def test_an_inv3_main_plist_larger_than_the_bound_is_refused_unread(tmp_path: Path, capfd) -> None:
    """Before: read whole (a member of zeros inflates 1000-fold), then an internal error from the XML parser."""
    _inv3(tmp_path / "v.inv3", plist_padding=MAX_INV3_PLIST_BYTES + 1)
    assert "its main.plist holds 16 MiB, more than the 16 MiB" in _refused(tmp_path / "v.inv3", tmp_path, capfd)


def test_an_inv3_with_many_empty_members_is_read_in_linear_time(tmp_path: Path, capfd) -> None:
    """Before: quadratic in the members (20,000 took 8 s, 40,000 took 30 s; 200,000 would take hours)."""
    _inv3(tmp_path / "v.inv3", empty_members=20_000)
    start = time.perf_counter()
    code, err = _run(tmp_path / "v.inv3", tmp_path, capfd)
    assert code == 0, err
    assert time.perf_counter() - start < 3.0
    assert json.loads((tmp_path / "out" / "classes.json").read_text())["input"]["value_max"] == 490


@pytest.mark.parametrize("dtype", ["object", "<U4", "no such type"])
def test_an_inv3_voxel_type_that_is_not_a_number_is_refused(tmp_path: Path, capfd, dtype: str) -> None:
    """Before: ``object`` (with as many bytes as it needs) was an internal error, ``<U4`` one from numpy."""
    _inv3(tmp_path / "v.inv3", dtype=dtype, voxels=bytes(8 * NK * NJ * NI if dtype == "object" else 16 * NK * NJ * NI))
    err = _refused(tmp_path / "v.inv3", tmp_path, capfd)
    assert f"voxel type '{dtype}'; a number type" in err or "lacks a valid matrix shape, dtype" in err


# ---------------------------------------------------------------------------------------------------------------
# 7. TIFF pages of different sizes or types
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("other", ["size", "type"])
def test_tiff_pages_that_differ_are_refused(tmp_path: Path, capfd, other: str) -> None:
    """Before: the first series alone was read, a volume that passes for the file's, with exit 0."""
    tifffile = pytest.importorskip("tifffile")
    last = np.ones((5, 5), np.uint16) if other == "size" else np.ones((NJ, NI), np.float32)
    with tifffile.TiffWriter(tmp_path / "v.tif") as writer:
        for plane in _values(np.uint16):
            writer.write(plane, metadata=None)
        writer.write(last, metadata=None)
    err = _refused(tmp_path / "v.tif", tmp_path, capfd)
    assert (
        f"its TIFF pages differ: page 1 is ({NJ}, {NI}) of uint16, page {NK + 1} is {last.shape} of {last.dtype}" in err
    )


# ---------------------------------------------------------------------------------------------------------------
# 8. A DICOM folder of very many files says first how long it takes, and shows its progress
# ---------------------------------------------------------------------------------------------------------------

#: Files of the large folder: a few thousand, as the 100,000 of the issue take minutes.
MANY = 2000


def _tiny_dicom_series(folder: Path, count: int) -> None:
    """``count`` CT slices of 2 x 2 voxels, one a file, 1 mm apart: one file written by pydicom, copied with its
    slice position, instance UID and voxels (the file's last bytes) replaced, so thousands take a fraction of a
    second."""
    pydicom = pytest.importorskip("pydicom")
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian

    uid = "1.2.826.0.1.3680043.10.1326.26"
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID, meta.TransferSyntaxUID = CTImageStorage, ExplicitVRLittleEndian
    meta.MediaStorageSOPInstanceUID = f"{uid}.9.1999999"
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
    ds.Modality, ds.StudyInstanceUID, ds.SeriesInstanceUID = "CT", f"{uid}.1", f"{uid}.2"
    ds.ImagePositionPatient, ds.ImageOrientationPatient, ds.PixelSpacing = (
        ["0", "0", "888888"],
        [1, 0, 0, 0, 1, 0],
        [1, 1],
    )
    ds.Rows = ds.Columns = 2
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 1
    ds.PixelData = np.array([0, 100, 200, 300], "<i2").tobytes()
    buffer = io.BytesIO()
    ds.save_as(buffer, enforce_file_format=True)
    template = buffer.getvalue()
    assert template.count(b"1999999") == 2 and template.count(b"888888") == 1 and pydicom
    folder.mkdir()
    for k in range(count):
        named = template.replace(b"1999999", b"1%06d" % k).replace(b"888888", b"%06d" % k)
        voxels = np.array([0, 1000, 2000, 3000], "<i2") + (k * 397 % 1000)  # the file's last bytes
        (folder / f"IM{k:06d}").write_bytes(named[:-8] + voxels.tobytes())


@pytest.fixture(scope="module")
def many_dicom_files(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("many") / "series"
    _tiny_dicom_series(folder, MANY)
    return folder


@needs_slicer
def test_a_dicom_folder_of_many_files_says_first_how_long_it_takes(
    many_dicom_files: Path, tmp_path: Path, capfd, monkeypatch
) -> None:
    """Before: 100,000 tiny files took minutes without a word. Past the bound (lowered here to MANY - 1), one warning
    line before the headers are read; the run goes on (exit 0) and reads every slice."""
    from isosimtf import slicer_readers

    monkeypatch.setattr(slicer_readers, "MANY_DICOM_FILES", MANY - 1)
    code, err = _run(many_dicom_files, tmp_path, capfd)
    assert code == 0, err
    assert err == (
        f"isosimtf: warning: '{many_dicom_files}' holds {MANY} DICOM files: reading their headers and voxels takes "
        f"about {slicer_readers._duration(slicer_readers.dicom_read_seconds(MANY))} here (Slicer's reader slows down "
        "with the square of the number of files); Ctrl+C stops it\n"
    )
    assert json.loads((tmp_path / "out" / "classes.json").read_text())["input"]["shape"] == [MANY, 2, 2]


@needs_slicer
@pytest.mark.parametrize("bound", [MANY - 1, MANY], ids=["above-the-bound", "at-the-bound"])
def test_the_estimate_starts_just_above_the_bound(many_dicom_files: Path, monkeypatch, bound: int) -> None:
    from isosimtf import slicer_readers

    monkeypatch.setattr(slicer_readers, "MANY_DICOM_FILES", bound)
    said: list[str] = []
    assert len(slicer_readers.dicom_series(many_dicom_files, said.append)) == MANY
    assert len(said) == (MANY > bound) and all(f"holds {MANY} DICOM files" in line for line in said)


@needs_slicer
def test_a_small_dicom_folder_prints_nothing_extra(tmp_path: Path, capfd) -> None:
    _tiny_dicom_series(tmp_path / "series", 5)
    assert _run(tmp_path / "series", tmp_path, capfd) == (0, "")


def test_the_estimate_grows_with_the_square_of_the_files() -> None:
    """The bound is about ten seconds of reading; 100,000 files, the issue's folder, take minutes."""
    from isosimtf.slicer_readers import MANY_DICOM_FILES, _duration, dicom_read_seconds

    assert 5.0 <= dicom_read_seconds(MANY_DICOM_FILES) <= 20.0
    assert _duration(dicom_read_seconds(100_000)) == "9 minutes"
    assert dicom_read_seconds(24_000) == pytest.approx(9.6 + 28.8)  # measured: 9.6 s of headers, 29.2 s of reading


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@needs_slicer
def test_reading_a_dicom_folder_shows_its_progress_on_a_terminal(many_dicom_files: Path) -> None:
    """The read stage's line shows each pass (looking for DICOM files, their headers, Slicer reading the slices),
    at most about a hundred updates a pass, however many files."""
    from isosimtf.console import ProgressPrinter
    from isosimtf.volume_io import read_volume

    terminal = _Terminal()
    progress = ProgressPrinter(5, stream=terminal)
    progress.stage("read", str(many_dicom_files))
    assert read_volume(many_dicom_files).shape == (MANY, 2, 2)
    progress.finish()
    updates = terminal.getvalue().split("\r\x1b[K")[1:]
    for step in ("looking for DICOM files", "DICOM headers", f"reading {MANY} slices"):
        mine = [u for u in updates if u.startswith(f"[1/5] read {many_dicom_files}: {step}")]
        assert 10 <= len(mine) <= 110, (step, len(mine))
    assert f"DICOM headers {MANY}/{MANY}" in updates[-1] or f"reading {MANY} slices" in updates[-1]
    assert "looking for DICOM files 1000/2000 [##########..........]  50%" in terminal.getvalue()


def test_progress_is_shown_nowhere_without_a_printer(many_dicom_files: Path) -> None:
    """The Python API (no progress printer; or one that is gone) shows nothing and keeps no printer alive."""
    import gc

    from isosimtf import read_errors
    from isosimtf.console import ProgressPrinter

    terminal = _Terminal()
    ProgressPrinter(2, stream=terminal).stage("read")
    gc.collect()
    read_errors.report_progress("DICOM headers 1/2", 0.5)  # the printer is gone: nowhere
    assert "DICOM headers" not in terminal.getvalue()
