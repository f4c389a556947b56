"""Where a NRRD or MetaImage file keeps its voxels: the one parser of their headers' storage fields.

Slicer's reader (:mod:`.slicer_readers`) gives the dimensions, the voxel type it will produce and the geometry; it
does not say where the voxels are in the file. This module reads that part of the header, once, for every caller:
the size bound of the in-memory read (bytes on disk), the lazy reader of raw files (:mod:`.chunked_readers`), and
the exact read of 64-bit integers, which Slicer's reader turns into float32.

Fields honoured, as Slicer's ITK readers (teem for NRRD, MetaIO for MetaImage) honour them: NRRD ``encoding``,
``type``, ``sizes``, ``endian``, ``data file`` / ``datafile`` (one file), ``line skip`` and ``byte skip`` (-1: the
voxels end the file; below -1 refused: teem reads header bytes as voxels); MetaImage ``NDims``, ``DimSize``,
``ElementType``, ``ElementNumberOfChannels``, ``ElementByteOrderMSB`` / ``BinaryDataByteOrderMSB``, ``CompressedData``,
``CompressedDataSize``, ``HeaderSize`` (-1: the voxels end the file; below -1 read as 0, as MetaIO does) and
``ElementDataFile`` (``LOCAL`` or one file). Header lines may end in CRLF.

Every data file a header names (one, a ``LIST`` or a numbered pattern, :func:`check_data_files`) is checked to be a
regular file before any reader opens it.
"""

import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from IsoSimilarityTFLib.errors import VolumeReadError

from .read_errors import cannot_read, regular_file

#: Bytes of a header read at most: a header longer than this is not one we parse (Slicer's reader decides alone).
MAX_HEADER_BYTES = 1 << 16
#: Bytes of a data file name read at most (PATH_MAX): a longer line of a LIST is read in parts, each one missing.
_MAX_NAME_BYTES = 4096
#: The suffixes of the formats this module parses: NRRD (attached or detached header) and MetaImage.
NRRD_SUFFIXES = (".nrrd", ".nhdr")
METAIMAGE_SUFFIXES = (".mha", ".mhd")
RAW_HEADER_SUFFIXES = NRRD_SUFFIXES + METAIMAGE_SUFFIXES

# NRRD types and MetaImage element types, as numpy kinds (byte order added from the header).
_NRRD_TYPES = {
    **dict.fromkeys(("signed char", "int8", "int8_t"), "i1"),
    **dict.fromkeys(("uchar", "unsigned char", "uint8", "uint8_t"), "u1"),
    **dict.fromkeys(("short", "short int", "signed short", "signed short int", "int16", "int16_t"), "i2"),
    **dict.fromkeys(("ushort", "unsigned short", "unsigned short int", "uint16", "uint16_t"), "u2"),
    **dict.fromkeys(("int", "signed int", "int32", "int32_t"), "i4"),
    **dict.fromkeys(("uint", "unsigned int", "uint32", "uint32_t"), "u4"),
    **dict.fromkeys(
        ("longlong", "long long", "long long int", "signed long long", "signed long long int", "int64", "int64_t"),
        "i8",
    ),
    **dict.fromkeys(
        ("ulonglong", "unsigned long long", "unsigned long long int", "uint64", "uint64_t"),
        "u8",
    ),
    "float": "f4",
    "double": "f8",
}
_MET_TYPES = {
    "MET_CHAR": "i1", "MET_UCHAR": "u1", "MET_SHORT": "i2", "MET_USHORT": "u2", "MET_INT": "i4", "MET_UINT": "u4",
    "MET_LONG": "i4", "MET_ULONG": "u4",  # MetaIO's sizes, as Slicer's reader reads them (32 bits)
    "MET_LONG_LONG": "i8", "MET_ULONG_LONG": "u8", "MET_FLOAT": "f4", "MET_DOUBLE": "f8",
}  # fmt: skip


@dataclass(frozen=True)
class StoredVoxels:
    """Where and how a file stores its voxels.

    Attributes:
        data: the file holding the voxels (the header file itself, or its detached data file).
        shape: ``(K, J, I)`` voxels, I fastest in the file.
        dtype: the stored type, with its byte order (what the file holds, before any reader converts it).
        raw: whether the voxels are stored uncompressed (then :attr:`offset` says where they start).
        offset: bytes before the first voxel in :attr:`data` when raw, else None.
        stored_bytes: bytes on disk holding the voxels (header and data file), the bound a deflate stream cannot
            exceed by more than about 1032 times; None when unknown (bzip2).
        size_mismatch: why the voxels cannot be read, found in the storage fields, for the reader to say once it
            has accepted the volume's size (a header announcing more voxels than the file holds says more): a
            compressed MetaImage whose ``CompressedDataSize`` is not the size of its compressed voxels (MetaIO
            inflates exactly that many bytes: fewer give voxels of garbage, more a failed read). None: nothing.
    """

    data: Path
    shape: tuple[int, int, int]
    dtype: np.dtype
    raw: bool
    offset: Optional[int]
    stored_bytes: Optional[int]
    size_mismatch: Optional[str] = None

    @property
    def nbytes(self) -> int:
        """Bytes of the voxels once read."""
        return int(np.prod(self.shape, dtype=np.float64)) * self.dtype.itemsize


def stored_voxels(path: Path) -> Optional[StoredVoxels]:
    """How the NRRD (``.nrrd``, ``.nhdr``) or MetaImage (``.mha``, ``.mhd``) at ``path`` stores its voxels.

    Returns None for a header this parser does not describe (not scalar 3-D, a list or pattern of data files, an
    unknown type, a malformed field): Slicer's reader then decides alone, and nothing is read lazily.

    Raises:
        VolumeReadError: the detached data file is missing or not a regular file; a compressed MetaImage without
            ``CompressedDataSize`` in its own file (ITK's reader then reads the wrong bytes); the voxels lie before
            the header's end.
    """
    lower = path.name.lower()
    if not lower.endswith(RAW_HEADER_SUFFIXES):
        return None
    try:
        with open(path, "rb") as handle:
            head = handle.read(MAX_HEADER_BYTES)
    except OSError:
        return None
    try:
        return _nrrd(path, head) if lower.endswith(NRRD_SUFFIXES) else _metaimage(path, head)
    except VolumeReadError:
        raise
    except (ValueError, TypeError, IndexError):  # a malformed header: Slicer's reader says what is wrong with it
        return None


def _lines(head: bytes) -> list[tuple[str, int]]:
    """The header's lines (without their end, LF or CRLF) with the byte offset just past each one."""
    lines, start = [], 0
    while True:
        end = head.find(b"\n", start)
        if end < 0:
            return lines
        lines.append((head[start:end].rstrip(b"\r").decode("latin-1"), end + 1))
        start = end + 1


def _data_file(path: Path, name: str) -> Path:
    data = path.parent / name
    if not data.exists():
        raise cannot_read(path, f"its data file '{data}' does not exist (the header names it; keep the two together)")
    return regular_file(path, data, "its data file")


def check_data_files(path: Path) -> None:
    """Refuse a NRRD or MetaImage header naming a data file that is missing or not a regular file (a FIFO, a device,
    a link to one), before Slicer's reader opens it (it would wait or read forever).

    The data files are named as teem and MetaIO read them, relative to the header's folder: one file; ``LIST`` (NRRD
    ``data file: LIST [subdim]``, MetaImage ``ElementDataFile = LIST [2D]``), one name a line from the next line to
    the end of the header file; or a pattern ``name%03d.raw first last step [subdim]``.

    Raises:
        VolumeReadError: a named data file is missing or not a regular file.
    """
    for name in _named_data_files(path):
        _data_file(path, name)


def _named_data_files(path: Path) -> Iterator[str]:
    """The names of the detached data files a NRRD or MetaImage header gives (none for other files, or voxels in the
    header's own file), one at a time: a pattern may number more files than exist, and the first missing one ends
    the check."""
    lower = path.name.lower()
    if not lower.endswith(RAW_HEADER_SUFFIXES):
        return
    nrrd = lower.endswith(NRRD_SUFFIXES)
    with open(path, "rb") as handle:
        head = handle.read(MAX_HEADER_BYTES)
    if len(head) < MAX_HEADER_BYTES:
        head += b"\n"  # the whole header: its last line counts even without an end (MetaIO reads it)
    field = _data_file_field(head, nrrd)
    if field is None:
        return
    value, end = field
    words = value.split()
    if not words or (not nrrd and words[0].upper() == "LOCAL"):
        return
    if words[0].upper() == "LIST":
        with open(path, "rb") as handle:
            handle.seek(end)
            for line in iter(lambda: handle.readline(_MAX_NAME_BYTES), b""):  # a line without end is not held whole
                name = line.decode("latin-1").strip()
                if name:
                    yield name
        return
    numbers = [int(w) for w in words[1:4] if w.lstrip("-").isdigit()]
    if "%" not in words[0] or len(numbers) != 3:
        yield value.strip()  # one file (its name may hold spaces)
        return
    first, last, step = numbers
    if step == 0:
        return  # not a pattern the readers accept: Slicer's reader says so
    for number in range(first, last + (1 if step > 0 else -1), step):
        try:
            name = words[0] % number
        except (ValueError, TypeError):  # a format teem's printf reads but Python's does not: Slicer's reader decides
            return
        yield name


def _data_file_field(head: bytes, nrrd: bool) -> Optional[tuple[str, int]]:
    """The value of a header's data file field (NRRD ``data file`` / ``datafile``, MetaImage ``ElementDataFile``)
    and the offset after its line; None when the header has none (an attached NRRD ends at its blank line)."""
    names = ("data file", "datafile") if nrrd else ("ElementDataFile",)
    for text, end in _lines(head):
        if nrrd and not text.strip():
            return None
        key, separator, value = text.partition(":" if nrrd else "=")
        key = key.strip().lower() if nrrd else key.strip()
        if separator and not value.startswith("=") and key in names:
            return value, end
    return None


def _raw_offset(path: Path, data: Path, start: int, nbytes: int, skip: int) -> int:
    """Offset of the first voxel: ``start`` plus ``skip`` bytes, or (skip -1) the last ``nbytes`` of the file."""
    size = data.stat().st_size
    if skip == -1:
        if size - nbytes < start:
            raise cannot_read(path, f"it is truncated: {nbytes} bytes of voxel data expected, {size - start} found")
        return size - nbytes
    return start + skip  # never below -1: refused (NRRD) or read as 0 (MetaImage) by the callers


def _skip_lines(data: Path, start: int, count: int) -> int:
    """The offset after ``count`` newline-ended lines from ``start`` in ``data`` (NRRD ``line skip``)."""
    with open(data, "rb") as handle:
        handle.seek(start)
        offset = start
        for _ in range(count):
            line = handle.readline()
            if not line.endswith(b"\n"):
                raise ValueError("line skip past the end of the file")
            offset += len(line)
    return offset


def _nrrd_fields(head: bytes) -> tuple[dict[str, str], Optional[int]]:
    """The fields of a NRRD header (lower-case keys) and the offset after its blank line (None: not found)."""
    lines = _lines(head)
    fields: dict[str, str] = {}
    if not lines or not lines[0][0].startswith("NRRD"):
        return fields, None
    for text, end in lines[1:]:
        if not text.strip():
            return fields, end
        if text.startswith("#") or ":=" in text or ":" not in text:
            continue
        key, _, value = text.partition(":")
        fields[key.strip().lower()] = value.strip()
    return fields, None


def _metaimage_fields(head: bytes) -> tuple[dict[str, str], Optional[int]]:
    """The fields of a MetaImage header and the offset after its ``ElementDataFile`` line (None: not found)."""
    fields: dict[str, str] = {}
    for text, end in _lines(head):
        key, separator, value = text.partition("=")
        if not separator:
            continue
        fields[key.strip()] = value.strip()
        if key.strip() == "ElementDataFile":
            return fields, end
    return fields, None


def spacing_problem(path: Path) -> Optional[str]:
    """What is wrong with the voxel size a NRRD or MetaImage header gives, when Slicer's reader refused it: a zero
    spacing (ITK then finds no reader for the file, which says nothing of the cause). None if nothing is found."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(MAX_HEADER_BYTES)
    except OSError:
        return None
    lower = path.name.lower()
    if lower.endswith(NRRD_SUFFIXES):
        fields, _ = _nrrd_fields(head)
        named = [("spacings", fields.get("spacings", ""))]
        named += [("space directions", d) for d in fields.get("space directions", "").split(")") if d.strip()]
    elif lower.endswith(METAIMAGE_SUFFIXES):
        fields, _ = _metaimage_fields(head)
        named = [(key, fields.get(key, "")) for key in ("ElementSpacing", "ElementSize")]
    else:
        return None
    for name, text in named:
        try:
            numbers = [float(v) for v in text.replace("(", " ").replace(",", " ").split() if v.lower() != "nan"]
        except ValueError:
            continue
        if numbers and (0.0 in numbers if name != "space directions" else not any(numbers)):
            return f"its header gives a zero voxel size ({name}: {text.strip(' (')}): every axis needs its size in mm"
    return None


def _nrrd(path: Path, head: bytes) -> Optional[StoredVoxels]:
    fields, header_end = _nrrd_fields(head)
    if not fields:
        return None
    byte_skip = int(fields.get("byte skip", fields.get("byteskip", 0)))
    if byte_skip < -1:  # Slicer's reader (teem) reads that many bytes before the voxels: header bytes as voxels
        raise cannot_read(
            path,
            f"its header gives byte skip {byte_skip}: only -1 (the voxels end the file) or a number of bytes from 0 "
            "up is valid (Slicer's reader would read the header's own bytes as voxels)",
        )
    sizes = [int(s) for s in fields.get("sizes", "").split()]
    kind = _NRRD_TYPES.get(fields.get("type", "").lower())
    detached = fields.get("data file", fields.get("datafile"))
    if kind is None or len(sizes) != 3 or (detached is not None and (" " in detached or detached.upper() == "LIST")):
        return None  # not scalar 3-D, or a list or pattern of data files
    if detached is None and header_end is None:
        return None  # no end of header in the first bytes
    big = fields.get("endian", "little").lower() == "big"
    dtype = np.dtype((">" if big else "<") + kind)
    shape = (sizes[2], sizes[1], sizes[0])
    encoding = fields.get("encoding", "").lower()
    data = _data_file(path, detached) if detached is not None else path
    stored = path.stat().st_size + (data.stat().st_size if data != path else 0)
    if encoding.startswith("bz"):
        return StoredVoxels(data, shape, dtype, False, None, None)
    if encoding != "raw":
        return StoredVoxels(data, shape, dtype, False, None, stored)
    start = 0 if detached is not None else header_end
    start = _skip_lines(data, start, int(fields.get("line skip", fields.get("lineskip", 0))))
    nbytes = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    offset = _raw_offset(path, data, start, nbytes, byte_skip)
    return StoredVoxels(data, shape, dtype, True, offset, stored)


def _metaimage(path: Path, head: bytes) -> Optional[StoredVoxels]:
    fields, header_end = _metaimage_fields(head)
    if header_end is None:
        return None
    sizes = [int(s) for s in fields.get("DimSize", "").split()]
    kind = _MET_TYPES.get(fields.get("ElementType", ""))
    if kind is None or len(sizes) != 3 or int(fields.get("NDims", 3)) != 3:
        return None
    if int(fields.get("ElementNumberOfChannels", 1)) != 1:
        return None
    big = fields.get("ElementByteOrderMSB", fields.get("BinaryDataByteOrderMSB", "False")).lower() == "true"
    dtype = np.dtype((">" if big else "<") + kind)
    shape = (sizes[2], sizes[1], sizes[0])
    name = fields["ElementDataFile"]
    if " " in name or "%" in name or name.upper().startswith("LIST"):
        return None
    local = name.upper() == "LOCAL"
    data = path if local else _data_file(path, name)
    stored = path.stat().st_size + (0 if local else data.stat().st_size)
    if fields.get("CompressedData", "False").lower() == "true":
        if local and "CompressedDataSize" not in fields:
            raise cannot_read(
                path,
                "it says CompressedData = True without CompressedDataSize: Slicer's reader would read the wrong "
                f"bytes; add the line 'CompressedDataSize = {os.path.getsize(path) - header_end}' before "
                "ElementDataFile (or save it again from Slicer)",
            )
        found = data.stat().st_size - (header_end if local else 0)
        declared = int(fields.get("CompressedDataSize", found))
        where = "follow its header" if local else f"are in its data file '{data.name}'"
        mismatch = (
            f"it says CompressedDataSize = {declared}, but {found} bytes of compressed voxels {where}: it is truncated "
            "or its header is wrong"
        )
        return StoredVoxels(data, shape, dtype, False, None, stored, mismatch if declared != found else None)
    nbytes = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    skip = int(fields.get("HeaderSize", 0))
    if skip < -1:
        skip = 0  # MetaIO skips bytes only for a HeaderSize above 0 (or -1): it reads the voxels from the start
    if local and skip > 0:
        if skip != header_end:
            # MetaIO then reads from byte HeaderSize of the file itself: inside the header, or past the voxels.
            raise cannot_read(
                path,
                f"it says HeaderSize = {skip} with ElementDataFile = LOCAL, but its header ends at byte {header_end}: "
                "Slicer's reader would read from byte {skip}; remove the HeaderSize line".replace("{skip}", str(skip)),
            )
        skip = 0
    offset = _raw_offset(path, data, header_end if local else 0, nbytes, skip)
    return StoredVoxels(data, shape, dtype, True, offset, stored)
