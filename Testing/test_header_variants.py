"""Every NRRD and MetaImage header variant is read the same by the in-memory path (Slicer's storage node) and the
lazy path (the raw reader, for files too large for memory): identical voxels and geometry, and the right ones.

Issue 18, item 2: the lazy reader ignored ``HeaderSize = -1`` (it read the header text as voxels), NRRD ``spacings``,
``line skip`` and ``byte skip -1``, left-handed directions and negative spacing, and refused CRLF headers. Both paths
now take where the voxels are from one parser (:mod:`isosimtf.headers`) and the geometry from Slicer's header pass.
"""

from pathlib import Path

import numpy as np
import pytest

from isosimtf import chunked_readers, headers
from isosimtf.phantom import head_phantom
from isosimtf.volume_io import VolumeReadError, read_volume

pytest.importorskip("dask")


def _values(dtype: str = "<i2") -> np.ndarray:
    """A crop of the phantom, (K, J, I) = (6, 7, 8): different along every axis, so a wrong order shows."""
    values = head_phantom(16, seed=0).values[5:11, 4:11, 4:12]
    if np.dtype(dtype).itemsize == 8:  # beyond float32's (and for uint64 float64's) resolution of 1
        return values.astype(dtype) + np.array(2**40 if dtype[1] == "i" else 2**63, dtype=dtype)
    return values.astype(dtype)


NK, NJ, NI = _values().shape
NRRD = "NRRD0004\ntype: {type}\ndimension: 3\nsizes: {I} {J} {K}\nendian: {endian}\nencoding: raw\n"
MHA = "ObjectType = Image\nNDims = 3\nDimSize = {I} {J} {K}\nElementType = {type}\n"
#: (ijk_to_ras of the file's own index order, values in the file) -> the pair Slicer shows (right-handed).
LPS = np.diag([-1.0, -1.0, 1.0, 1.0])


def _matrix(axes, origin) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = np.asarray(axes, float).T, origin
    return matrix


# name -> (files {name: bytes or header text with {raw}}, dtype, expected ijk_to_ras (file order, RAS))
def _variants() -> dict:
    v = _values()
    raw = v.tobytes()
    nrrd = NRRD.format(type="short", I=NI, J=NJ, K=NK, endian="little")
    mha = MHA.format(type="MET_SHORT", I=NI, J=NJ, K=NK)
    identity = LPS @ np.eye(4)
    directions = (
        "space: left-posterior-superior\nspace directions: (0.5,0,0) (0,0.75,0) (0,0,{z})\nspace origin: (1,2,3)\n"
    )
    right = _matrix(np.diag([-0.5, -0.75, 2.0]), [-1, -2, 3])
    left = _matrix(np.diag([-0.5, -0.75, -2.0]), [-1, -2, 3])
    return {
        "nrrd-attached": ({"v.nrrd": nrrd.encode() + directions.format(z=2).encode() + b"\n" + raw}, "<i2", right),
        "nrrd-left-handed": ({"v.nrrd": nrrd.encode() + directions.format(z=-2).encode() + b"\n" + raw}, "<i2", left),
        "nrrd-spacings": ({"v.nrrd": (nrrd + "spacings: 0.01 0.02 0.03\n\n").encode() + raw}, "<i2",
                          LPS @ _matrix(np.diag([0.01, 0.02, 0.03]), [0, 0, 0])),
        "nrrd-crlf": ({"v.nrrd": (nrrd + "spacings: 0.01 0.02 0.03\n\n").replace("\n", "\r\n").encode() + raw},
                      "<i2", LPS @ _matrix(np.diag([0.01, 0.02, 0.03]), [0, 0, 0])),
        "nrrd-big-endian": ({"v.nrrd": NRRD.format(type="short", I=NI, J=NJ, K=NK, endian="big").encode() + b"\n"
                             + v.astype(">i2").tobytes()}, "<i2", identity),
        "nhdr-line-skip": ({"v.nhdr": (nrrd + "data file: v.raw\nline skip: 2\n").encode(),
                            "v.raw": b"a comment line\nanother one\n" + raw}, "<i2", identity),
        "nhdr-byte-skip": ({"v.nhdr": (nrrd + "data file: v.raw\nbyte skip: 5\n").encode(),
                            "v.raw": b"12345" + raw}, "<i2", identity),
        "nhdr-byte-skip-minus-1": ({"v.nhdr": (nrrd + "data file: v.raw\nbyte skip: -1\n").encode(),
                                    "v.raw": b"a preamble of any length" + raw}, "<i2", identity),
        "nrrd-attached-byte-skip-minus-1": ({"v.nrrd": (nrrd + "byte skip: -1\n\n").encode() + b"xyz" + raw},
                                            "<i2", identity),
        "nrrd-int64": ({"v.nrrd": NRRD.format(type="int64", I=NI, J=NJ, K=NK, endian="little").encode() + b"\n"
                        + _values("<i8").tobytes()}, "<i8", identity),
        "nrrd-uint64": ({"v.nrrd": NRRD.format(type="uint64", I=NI, J=NJ, K=NK, endian="little").encode() + b"\n"
                         + _values("<u8").tobytes()}, "<u8", identity),
        "mha-local": ({"v.mha": (mha + "ElementSpacing = 0.5 0.75 2\nOffset = 1 2 3\nElementDataFile = LOCAL\n")
                       .encode() + raw}, "<i2", LPS @ _matrix(np.diag([0.5, 0.75, 2.0]), [1, 2, 3])),
        "mha-crlf": ({"v.mha": (mha + "ElementSpacing = 0.5 0.75 2\nElementDataFile = LOCAL\n").replace("\n", "\r\n")
                      .encode() + raw}, "<i2", LPS @ _matrix(np.diag([0.5, 0.75, 2.0]), [0, 0, 0])),
        "mha-negative-spacing": ({"v.mha": (mha + "ElementSpacing = 0.5 -0.75 2\nElementDataFile = LOCAL\n")
                                  .encode() + raw}, "<i2", LPS @ _matrix(np.diag([0.5, -0.75, 2.0]), [0, 0, 0])),
        "mha-transform": ({"v.mha": (mha + "TransformMatrix = 0 1 0 -1 0 0 0 0 1\nElementDataFile = LOCAL\n")
                           .encode() + raw}, "<i2", LPS @ _matrix([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], [0, 0, 0])),
        "mha-msb": ({"v.mha": (mha + "ElementByteOrderMSB = True\nElementDataFile = LOCAL\n").encode()
                     + v.astype(">i2").tobytes()}, "<i2", identity),
        "mha-header-size-minus-1": ({"v.mha": (mha + "HeaderSize = -1\nElementDataFile = LOCAL\n").encode()
                                     + b"padding" + raw}, "<i2", identity),
        "mha-header-size-exact": ({"v.mha": (mha + "HeaderSize = {end}\nElementDataFile = LOCAL\n").format(
                                   end=len(mha) + len("HeaderSize = 999\nElementDataFile = LOCAL\n")).encode() + raw},
                                  "<i2", identity),
        "nrrd-attached-byte-skip": ({"v.nrrd": (nrrd + "byte skip: 6\n\n").encode() + b"abcdef" + raw}, "<i2",
                                    identity),
        "mhd-header-size": ({"v.mhd": (mha + "HeaderSize = 9\nElementDataFile = v.raw\n").encode(),
                             "v.raw": b"123456789" + raw}, "<i2", identity),
        "mhd-header-size-minus-1": ({"v.mhd": (mha + "HeaderSize = -1\nElementDataFile = v.raw\n").encode(),
                                     "v.raw": b"some bytes first" + raw}, "<i2", identity),
        "mha-long-long": ({"v.mha": (MHA.format(type="MET_LONG_LONG", I=NI, J=NJ, K=NK) + "ElementDataFile = LOCAL\n")
                           .encode() + _values("<i8").tobytes()}, "<i8", identity),
    }  # fmt: skip


VARIANTS = _variants()


def _write(tmp_path: Path, files: dict) -> Path:
    for name, content in files.items():
        (tmp_path / name).write_bytes(content)
    return tmp_path / next(iter(files))


def _slicer_view(values: np.ndarray, ijk_to_ras: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What Slicer shows of voxels in file order: a left-handed frame made right-handed (slice order reversed)."""
    if np.linalg.det(ijk_to_ras[:3, :3]) > 0:
        return values, ijk_to_ras
    flip = np.eye(4)
    flip[2, 2], flip[2, 3] = -1.0, values.shape[0] - 1
    return values[::-1], ijk_to_ras @ flip


@pytest.mark.parametrize("name", list(VARIANTS))
def test_every_header_variant_reads_the_same_both_ways_and_right(tmp_path: Path, name: str) -> None:
    files, dtype, expected_matrix = VARIANTS[name]
    path = _write(tmp_path, files)
    expected_values, expected_matrix = _slicer_view(_values(dtype), expected_matrix)

    in_memory = read_volume(path)
    lazy = chunked_readers.read_chunked(path)
    lazy_values = np.asarray(lazy.values)

    assert in_memory.values.dtype == np.dtype(dtype).newbyteorder("=")  # int64 stays int64, exact
    np.testing.assert_array_equal(in_memory.values, expected_values)
    np.testing.assert_allclose(in_memory.ijk_to_ras(), expected_matrix, atol=1e-9)
    assert lazy_values.dtype.newbyteorder("=") == in_memory.values.dtype
    np.testing.assert_array_equal(lazy_values, in_memory.values)
    np.testing.assert_allclose(lazy.ijk_to_ras(), in_memory.ijk_to_ras(), atol=1e-12)


def test_the_parser_finds_the_voxels_where_slicer_does(tmp_path: Path) -> None:
    files, _, _ = VARIANTS["nhdr-byte-skip-minus-1"]
    path = _write(tmp_path, files)
    stored = headers.stored_voxels(path)
    assert stored is not None and stored.raw
    assert stored.data == tmp_path / "v.raw" and stored.offset == len(b"a preamble of any length")
    assert stored.shape == (NK, NJ, NI) and stored.dtype == np.dtype("<i2")


def test_compressed_metaimage_without_its_size_is_refused_in_one_line(tmp_path: Path) -> None:
    import zlib

    path = tmp_path / "v.mha"
    compressed = zlib.compress(_values().tobytes())
    header = MHA.format(type="MET_SHORT", I=NI, J=NJ, K=NK) + "CompressedData = True\nElementDataFile = LOCAL\n"
    path.write_bytes(header.encode() + compressed)
    for read in (read_volume, chunked_readers.read_chunked):
        with pytest.raises(
            VolumeReadError, match=f"without CompressedDataSize.*'CompressedDataSize = {len(compressed)}'"
        ):
            read(path)
    # With the line the message asks for, the file reads right.
    text = path.read_bytes().replace(
        b"ElementDataFile", f"CompressedDataSize = {len(compressed)}\nElementDataFile".encode()
    )
    path.write_bytes(text)
    np.testing.assert_array_equal(read_volume(path).values, _values())


def test_a_missing_data_file_is_named(tmp_path: Path) -> None:
    nrrd = NRRD.format(type="short", I=NI, J=NJ, K=NK, endian="little") + "data file: gone.raw\n"
    (tmp_path / "v.nhdr").write_text(nrrd)
    (tmp_path / "v.mhd").write_text(MHA.format(type="MET_SHORT", I=NI, J=NJ, K=NK) + "ElementDataFile = gone.raw\n")
    for name in ("v.nhdr", "v.mhd"):
        for read in (read_volume, chunked_readers.read_chunked):
            with pytest.raises(VolumeReadError, match=r"its data file '.*gone\.raw' does not exist"):
                read(tmp_path / name)


def test_compressed_int64_is_refused_rather_than_rounded(tmp_path: Path) -> None:
    import gzip

    path = tmp_path / "v.nrrd"
    header = NRRD.format(type="int64", I=NI, J=NJ, K=NK, endian="little").replace("raw", "gzip") + "\n"
    path.write_bytes(header.encode() + gzip.compress(_values("<i8").tobytes()))
    with pytest.raises(VolumeReadError, match="int64 voxels, which Slicer's reader rounds to float32"):
        read_volume(path)


def test_a_local_header_size_inside_the_header_is_refused(tmp_path: Path) -> None:
    """MetaIO reads a LOCAL file from byte HeaderSize of the file itself: HeaderSize = 4 read the header as voxels."""
    path = tmp_path / "v.mha"
    header = MHA.format(type="MET_SHORT", I=NI, J=NJ, K=NK) + "HeaderSize = 4\nElementDataFile = LOCAL\n"
    path.write_bytes(header.encode() + b"abcd" + _values().tobytes())
    for read in (read_volume, chunked_readers.read_chunked):
        with pytest.raises(
            VolumeReadError, match="HeaderSize = 4 with ElementDataFile = LOCAL, but its header ends at"
        ):
            read(path)
