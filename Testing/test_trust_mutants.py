"""What a mutation run of the trust modules found untested (issue 26): each test here kills mutants of
``output_folder.py``, ``headers.py``, ``volume_io.py`` or ``value_range.py`` that every other test let live, by
asserting the behaviour the mutant breaks (a file removed outside OUTDIR, a hostile header read without a check, a
value range that says less than it leaves out). Thresholds are tested on both sides of their boundary.
"""

import gzip
import json
import os
import struct
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from deadlines import deadline
from volume_writers import write_nifti

from IsoSimilarityTFLib.design import design_transfer_function
from IsoSimilarityTFLib.options import LOOK_NAMES
from IsoSimilarityTFLib.quantize import MAX_VALUE_MAGNITUDE
from IsoSimilarityTFLib.value_range import (
    MIN_DISTINCT,
    OUTLIER_SPREADS,
    PADDING_FRACTION,
    PADDING_GAP,
    PADDING_MAX_FRACTION,
    RobustRange,
    robust_value_range,
)
from isosimtf import cli, output_folder, volume_io
from isosimtf.output_folder import (
    JOURNAL_FILE,
    LOOKS_FOLDER,
    TEMPORARY_PREFIX,
    TOP_OUTPUTS,
    file_stamp,
    is_output_name,
    look_file,
)
from isosimtf.rendering import slicer_core_available
from isosimtf.volume_io import read_volume

da = pytest.importorskip("dask.array")
needs_slicer = pytest.mark.skipif(not slicer_core_available(), reason="slicer-core is not installed")
PHANTOM = ["phantom", "--phantom-size", "16", "-q"]
#: Seconds a run may take before it is taken for hung (each run here ends in a few).
DEADLINE = 60


def _run(argv: list, capfd) -> tuple[int, str]:
    with deadline(DEADLINE):
        code = cli.main([str(a) for a in argv])
    return code, capfd.readouterr().err


def _record(outdir: Path, names: list, stamps: dict) -> None:
    """A classes.json of isosimtf's form recording ``names`` with ``stamps`` (as a copied or forged record)."""
    document = {"tool": {"name": "isosimtf"}, "written": names, "written_stamps": stamps}
    (outdir / "classes.json").write_text(json.dumps(document), encoding="utf-8")


# output_folder.py ----------------------------------------------------------------------------------------------------


def test_a_record_is_trusted_only_for_names_this_tool_writes() -> None:
    ours = [*TOP_OUTPUTS, *(look_file(look) for look in LOOK_NAMES), "scene/scene.mrml", "scene/Data/head.nrrd"]
    assert all(is_output_name(name) for name in ours)
    hostile = [
        "../x",
        "../classes.json",
        "/etc/passwd",
        "scene/Data/..",
        "scene/Data/.",
        "scene/Data/",
        "scene/Data/sub/head.nrrd",
        "scene//scene.mrml",
        "scene/../render.png",
        "looks/mine.vp.json",
        "looks/notes.txt",
        "notes/Data/head.nrrd",
        "notes/scene.mrml",
        "results.csv",
        "",
    ]
    assert [name for name in hostile if is_output_name(name)] == []


def test_a_record_naming_files_beside_ours_with_their_hashes_removes_none(tmp_path: Path, capfd) -> None:
    """Before the names were checked one by one, a record could name any file under scene/Data/ or looks/ (or a
    folder's Data/) with its real hash, and the next run removed it as a previous run's output."""
    outdir = tmp_path / "out"
    mine = {
        "scene/Data/sub/head.nrrd": "my volume",
        f"{LOOKS_FOLDER}/mine.vp.json": "my look",
        "notes/Data/head.nrrd": "my notes",
        "notes/scene.mrml": "my scene",
    }
    for name, text in mine.items():
        (outdir / name).parent.mkdir(parents=True, exist_ok=True)
        (outdir / name).write_text(text)
    _record(outdir, list(mine), {name: file_stamp(outdir / name) for name in mine})
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 0, err
    assert {name: (outdir / name).read_text() for name in mine} == mine and "removed" not in err


def test_a_recorded_file_reached_through_a_link_is_never_removed(tmp_path: Path, capfd) -> None:
    """A record naming render.png and scene/Data/head.nrrd, both reached through links to files outside OUTDIR and
    stamped with those files' hashes: a --no-render run, which writes neither, would remove them as stale."""
    outdir, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    (outdir / "scene").mkdir(parents=True)
    elsewhere.mkdir()
    (elsewhere / "picture.png").write_bytes(b"my picture")
    (elsewhere / "head.nrrd").write_bytes(b"my volume")
    (outdir / "render.png").symlink_to(elsewhere / "picture.png")
    (outdir / "scene" / "Data").symlink_to(elsewhere, target_is_directory=True)
    names = ["render.png", "scene/Data/head.nrrd"]
    _record(outdir, names, {name: file_stamp(outdir / name) for name in names})
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 0, err
    assert (elsewhere / "picture.png").read_bytes() == b"my picture"
    assert (elsewhere / "head.nrrd").read_bytes() == b"my volume"
    assert (outdir / "render.png").is_symlink() and "removed" not in err


@needs_slicer
def test_a_users_file_in_scene_data_is_refused_by_a_run_that_saves_the_scene(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    (outdir / "scene" / "Data").mkdir(parents=True)
    (outdir / "scene" / "Data" / "phantom.nrrd").write_text("my volume")
    code, err = _run([*PHANTOM, "--size", "64", "-o", outdir], capfd)
    assert code == 2 and err.count("\n") == 1, err
    assert f"'{outdir / 'scene' / 'Data' / 'phantom.nrrd'}' was not written by isosimtf" in err
    assert (outdir / "scene" / "Data" / "phantom.nrrd").read_text() == "my volume"
    assert not (outdir / "classes.json").exists()  # refused before any work


@needs_slicer
def test_the_input_among_the_scene_a_run_would_save_is_refused(tmp_path: Path, capfd) -> None:
    """The previous run's scene volume as the input of a rendering run into the same folder: saving the scene would
    replace it. Refused in one line, though the file is the previous run's own and unchanged."""
    outdir = tmp_path / "out"
    assert _run([*PHANTOM, "--size", "64", "-o", outdir], capfd)[0] == 0
    volume = next(p for p in (outdir / "scene" / "Data").iterdir() if p.name.endswith(".nrrd"))
    content = volume.read_bytes()
    code, err = _run([volume, "-q", "--size", "64", "-o", outdir], capfd)
    assert code == 2 and err.count("\n") == 1, err
    assert f"the input '{volume}' is among this run's outputs" in err and volume.read_bytes() == content


def test_only_temporaries_of_our_pattern_for_our_outputs_are_cleaned_in_looks(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    (outdir / LOOKS_FOLDER).mkdir(parents=True)
    ours = outdir / LOOKS_FOLDER / f"{TEMPORARY_PREFIX}99-{LOOK_NAMES[0]}.vp.json"
    mine = outdir / LOOKS_FOLDER / f"{TEMPORARY_PREFIX}99-notes.txt"
    ours.write_text("part")
    mine.write_text("mine")
    assert _run([*PHANTOM, "--no-render", "-o", outdir], capfd)[0] == 0
    assert not ours.exists() and mine.read_text() == "mine"


def test_a_run_killed_before_its_rename_leaves_a_temporary_the_next_run_removes(tmp_path: Path, capfd) -> None:
    """The temporary names the writes use are the ones the clean-up knows: a run killed between writing a file and
    renaming it into place (here at its first rename) leaves its temporary, and the next run into the folder removes
    it on entering, even one that then fails on its input (so it cannot be replaced by that run's own write)."""
    outdir = tmp_path / "out"
    killed_at_rename = (
        "import os, runpy; os.replace = lambda *args, **kwargs: os._exit(9); "
        "runpy.run_module('isosimtf', run_name='__main__')"
    )
    argv = [sys.executable, "-c", killed_at_rename, *PHANTOM, "--no-render", "-o", str(outdir)]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert done.returncode == 9, done.stderr
    left = [p.name for p in outdir.iterdir() if p.name.startswith(TEMPORARY_PREFIX)]
    assert len(left) == 1, left
    code, err = _run([tmp_path / "missing.nrrd", "--no-render", "-q", "-o", outdir], capfd)
    assert code == 2 and "no such file or directory" in err, err
    assert [p.name for p in outdir.rglob(TEMPORARY_PREFIX + "*")] == []


def test_a_linked_journal_is_refused_and_nothing_is_written_through_it(tmp_path: Path, capfd) -> None:
    outdir, outside = tmp_path / "out", tmp_path / "outside.txt"
    outdir.mkdir()
    outside.write_text("mine")
    (outdir / JOURNAL_FILE).symlink_to(outside)
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 2 and err.count("\n") == 1 and "is a symbolic link" in err, err
    assert outside.read_text() == "mine" and not (outdir / "classes.json").exists()


@pytest.mark.parametrize("writer", [False, True], ids=["no-writer", "a-writer-holding-it"])
@pytest.mark.parametrize("name", ["classes.json", JOURNAL_FILE])
def test_a_fifo_among_the_records_is_refused_in_one_line_without_waiting(
    tmp_path: Path, capfd, name: str, writer: bool
) -> None:
    """Before: a FIFO named classes.json (read back as the previous run's record) or as the journal (appended to as
    each output lands) made the run wait forever. A FIFO some process holds open for writing, with nothing written,
    is no record either."""
    outdir = tmp_path / "out"
    outdir.mkdir()
    os.mkfifo(outdir / name)
    held = os.open(outdir / name, os.O_RDWR) if writer else None
    try:
        code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    finally:
        if held is not None:
            os.close(held)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert f"'{outdir / name}'" in err and (outdir / name).is_fifo()


def test_a_deeply_nested_classes_json_is_not_ours_and_is_one_line(tmp_path: Path, capfd) -> None:
    """Before: '[' nested 200,000 deep ended the run in an internal error (RecursionError)."""
    outdir = tmp_path / "out"
    outdir.mkdir()
    (outdir / "classes.json").write_text("[" * 200_000)
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    assert code == 2 and err.count("\n") == 1 and "was not written by isosimtf" in err, err
    assert _run([*PHANTOM, "--no-render", "-o", outdir, "--overwrite"], capfd)[0] == 0


@pytest.mark.parametrize("spare", [0, -1], ids=["at-the-bound", "above-the-bound"])
def test_a_record_is_read_up_to_its_bound(tmp_path: Path, capfd, monkeypatch, spare: int) -> None:
    """A classes.json longer than MAX_RECORD_BYTES is not read (a huge file, or one a link makes endless), so it
    records nothing: the next run refuses to replace the files it lists. One at the bound is read whole."""
    outdir = tmp_path / "out"
    assert _run([*PHANTOM, "--no-render", "-o", outdir], capfd)[0] == 0
    monkeypatch.setattr(output_folder, "MAX_RECORD_BYTES", (outdir / "classes.json").stat().st_size + spare)
    code, err = _run([*PHANTOM, "--no-render", "-o", outdir], capfd)
    if spare == 0:
        assert code == 0, err
    else:
        assert code == 2 and err.count("\n") == 1 and "was not written by isosimtf" in err, err


# value_range.py ------------------------------------------------------------------------------------------------------

#: Voxels of the value-range volumes: every voxel is in the sample (at most SAMPLE_VOXELS), so the rules' decisions
#: are exact, and PADDING_FRACTION of them is a whole number (1000).
SHAPE = (20, 100, 100)
N = 200_000


def _scan(levels: int, dtype=np.int16) -> np.ndarray:
    """A continuous "scan": the values 0 .. levels - 1 in equal numbers."""
    return (np.arange(N) % levels).astype(dtype).reshape(SHAPE)


def _with(values: np.ndarray, *blocks: tuple[float, int]) -> np.ndarray:
    """``values`` with blocks of voxels set to a value (``(value, count)``), the first ones in the volume's order."""
    flat, start = values.copy().reshape(-1), 0
    for value, count in blocks:
        flat[start : start + count] = value
        start += count
    return flat.reshape(values.shape)


def _robust(values: np.ndarray, **kwargs) -> RobustRange:
    """The robust range of ``values``, checked to say exactly what it leaves out, and the same read lazily."""
    robust = robust_value_range(values, **kwargs)
    low, high = robust.value_range
    left_out = int(np.count_nonzero(values < low)) + int(np.count_nonzero(values > high))
    said = sum(count for _, count in robust.padding) + robust.outliers_low + robust.outliers_high
    assert said == left_out, (robust, left_out)
    assert robust.data_range == (float(values.min()), float(values.max()))
    for value, count in robust.padding:
        assert value in robust.data_range and count == np.count_nonzero(values == value)
    if values.dtype.itemsize <= 2 and not kwargs:  # read lazily: the counts come from the survey's value histogram
        assert robust_value_range(da.from_array(values, chunks=(5, 50, 50))) == robust
    return robust


@pytest.mark.parametrize(
    ("count", "padding"), [(1000, True), (999, False)], ids=["at-the-fraction", "below-the-fraction"]
)
def test_padding_needs_its_fraction_of_the_voxels(count: int, padding: bool) -> None:
    assert PADDING_FRACTION * N == 1000
    values = _with(_scan(1000), (-3000, count))
    robust = _robust(values)
    if padding:
        assert robust.value_range == (0.0, 999.0) and robust.padding == ((-3000.0, count),)
        assert (robust.outliers_low, robust.outliers_high) == (0, 0)
    else:
        assert robust.value_range == (-3000.0, 999.0) and not robust.excludes


@pytest.mark.parametrize(("value", "padding"), [(-181, True), (-180, False)], ids=["beyond-the-gap", "at-the-gap"])
def test_padding_needs_its_gap_to_the_next_value(value: int, padding: bool) -> None:
    """Values 0 .. 1020 and 1% of the voxels at -180 (a gap of exactly PADDING_GAP of the span) or -181."""
    span, gap = 1020 - value, -value
    assert (gap > PADDING_GAP * span) == padding and (gap >= PADDING_GAP * span)
    robust = _robust(_with(_scan(1021), (value, 2000)))
    assert robust.value_range == ((0.0, 1020.0) if padding else (float(value), 1020.0))
    assert robust.padding == (((float(value), 2000),) if padding else ())


@pytest.mark.parametrize(("distinct", "padding"), [(32, True), (31, False)])
def test_padding_needs_a_scan_beside_it_not_a_label_map(distinct: int, padding: bool) -> None:
    assert distinct - padding == MIN_DISTINCT - 1
    values = _with(_scan(distinct) * 10, (-3000, 2000))
    robust = _robust(values)
    assert robust.value_range == ((0.0, 10.0 * (distinct - 1)) if padding else (-3000.0, 10.0 * (distinct - 1)))


def test_padding_at_the_highest_value_is_left_out_too() -> None:
    robust = _robust(_with(_scan(1000), (30000, 1000)))
    assert robust.value_range == (0.0, 999.0) and robust.padding == ((30000.0, 1000),)
    both = _robust(_with(_scan(1000), (30000, 1000), (-6000, 1500)))  # gaps beyond 15% of 36000
    assert both.value_range == (0.0, 999.0) and both.padding == ((-6000.0, 1500), (30000.0, 1000))
    assert (both.outliers_low, both.outliers_high) == (0, 0)


def test_padding_within_the_outlier_cuts_is_left_out_all_the_same() -> None:
    """Values 0 .. 1000 and 1% of the voxels at -500 and at 1500: both far enough to be padding (a gap of 500, more
    than 15% of the span of 2000), both within two spreads of the values, where the outlier rule keeps them."""
    robust = _robust(_with(_scan(1001), (-500, 2000), (1500, 2000)))
    assert robust.value_range == (0.0, 1000.0) and robust.padding == ((-500.0, 2000), (1500.0, 2000))


@pytest.mark.parametrize(("count", "padding"), [(N // 2, True), (N // 2 + 1, False)], ids=["half", "more-than-half"])
def test_padding_holds_at_most_half_of_the_voxels(count: int, padding: bool) -> None:
    """Beyond PADDING_MAX_FRACTION of the voxels a fill is a masked export's background, kept in the range."""
    assert PADDING_MAX_FRACTION * N == N // 2
    robust = _robust(_with(_scan(1000), (-3000, count)))
    assert robust.value_range == ((0.0, 999.0) if padding else (-3000.0, 999.0))


def test_padding_is_left_out_of_the_spread_that_finds_outliers() -> None:
    """Values 0 .. 1000, 1% padding at -10000 and one voxel at 3500: 2.5 spreads of the values beyond them, an
    outlier; with the padding counted in the spread (11 times wider) it would not be."""
    robust = _robust(_with(_scan(1001), (-10000, 2000), (3500, 1)))
    assert robust.value_range == (0.0, 1000.0)
    assert robust.padding == ((-10000.0, 2000),) and (robust.outliers_low, robust.outliers_high) == (0, 1)


@pytest.mark.parametrize(("spreads", "outlier"), [(OUTLIER_SPREADS - 0.1, False), (OUTLIER_SPREADS + 0.1, True)])
def test_an_outlier_lies_more_than_its_spreads_beyond_the_central_values(spreads: float, outlier: bool) -> None:
    values = _with(_scan(1001, np.float64), (1e6, 1))  # the highest voxel: the percentiles do not depend on it
    q_low, q_high = np.percentile(values, [0.1, 99.9])
    far = q_high + spreads * (q_high - q_low)
    values[values == 1e6] = far
    robust = _robust(values)
    assert robust.value_range == ((0.0, 1000.0) if outlier else (0.0, far))
    assert robust.outliers_high == int(outlier)


def test_padding_is_only_ever_the_volumes_own_extreme() -> None:
    """The sample (every 2nd voxel) holds -3024 padding at its lowest, but the volume's lowest voxel, outside the
    sample, is at -5000: -3024 is not the volume's extreme, so not padding. Taken as padding, the warning counted
    its voxels twice (as padding and as outliers)."""
    values = (np.arange(40**3) % 1000).astype(np.int16).reshape(40, 40, 40)
    values[:2] = -3024
    values[1, 1, 1] = -5000
    robust = _robust(values, sample_voxels=8000)
    assert robust.padding == ()


def test_a_range_the_rules_would_shrink_to_one_value_is_the_data_range() -> None:
    """4991 voxels: 5 at -1000, 5 at 1000, the rest at 0. The central values span -10 to 10 (percentiles between
    the voxels), so the rules keep only 0: a range of no width, which cannot be quantized. The data range is used."""
    values = _with(np.zeros((7, 23, 31), np.int16), (-1000, 5), (1000, 5))
    assert values.size == 4991 and np.ptp(np.percentile(values, [0.1, 99.9])) == pytest.approx(20)
    robust = _robust(values)
    assert robust.value_range == (-1000.0, 1000.0) and not robust.excludes
    assert design_transfer_function(values, n_bins=16).value_range == (-1000.0, 1000.0)


# headers.py and volume_io.py ------------------------------------------------------------------------------------------

NRRD = "NRRD0004\ntype: {type}\ndimension: 3\nsizes: 8 7 {k}\nendian: little\nencoding: {encoding}\n"
MHA = "ObjectType = Image\nNDims = 3\nDimSize = 8 7 3\nElementType = {type}\n"


def _voxels(dtype: str = "<i2", k: int = 3) -> np.ndarray:
    """(k, 7, 8) voxels, 50 distinct values; 64-bit integers beyond float32's resolution (2^40 + ...)."""
    values = np.arange(k * 7 * 8).reshape(k, 7, 8) % 50 * 10
    return (values + (2**40 if np.dtype(dtype).itemsize == 8 else 0)).astype(dtype)


def _refusal(source: Path, tmp_path: Path, capfd) -> str:
    """The one line of ``isosimtf SOURCE --no-render`` refusing its input (exit 2)."""
    code, err = _run([source, "-o", tmp_path / "out", "--no-render", "-q"], capfd)
    assert code == 2 and err.count("\n") == 1 and err.startswith("isosimtf: error: "), err
    return err


def test_a_fifo_as_the_input_is_refused_without_waiting(tmp_path: Path, capfd) -> None:
    os.mkfifo(tmp_path / "v.nrrd")
    assert "it is not a regular file (a FIFO, socket or device)" in _refusal(tmp_path / "v.nrrd", tmp_path, capfd)


def test_a_pattern_of_data_files_with_step_0_is_one_line(tmp_path: Path, capfd) -> None:
    """A numbered pattern with step 0 names no file: the readers refuse the header, in a line naming it (not Python's
    "range() arg 3 must not be zero")."""
    (tmp_path / "v.nhdr").write_text(NRRD.format(type="short", k=2, encoding="raw") + "data file: s%d.raw 0 1 0\n")
    for number in (0, 1):
        (tmp_path / f"s{number}.raw").write_bytes(_voxels(k=1).tobytes())
    assert f"Cannot read '{tmp_path / 'v.nhdr'}'" in _refusal(tmp_path / "v.nhdr", tmp_path, capfd)


def test_a_list_line_without_end_is_read_one_name_length_at_a_time(tmp_path: Path) -> None:
    """A LIST whose next line never ends (2 GiB without a newline, sparse): its first 4096 bytes are a name, missing;
    the line is never held whole (here the check runs with 1 GiB of address space)."""
    header = tmp_path / "v.nhdr"
    text = (NRRD.format(type="short", k=2, encoding="raw") + "data file: LIST\n").encode()
    with open(header, "wb") as file:
        file.write(text)
        file.truncate(len(text) + (2 << 30))
    check = (
        "import resource, sys; from pathlib import Path; resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30)); "
        "from isosimtf import headers; from IsoSimilarityTFLib.errors import VolumeReadError\n"
        "try:\n    headers.check_data_files(Path(sys.argv[1]))\n"
        "except VolumeReadError as error:\n    print('does not exist' in str(error))"
    )
    done = subprocess.run(
        [sys.executable, "-c", check, str(header)],
        capture_output=True,
        text=True,
        timeout=DEADLINE,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
    )
    assert done.returncode == 0 and done.stdout == "True\n", done.stderr[-500:]


@pytest.mark.parametrize("short", [0, 1], ids=["exactly-the-voxels", "one-byte-short"])
def test_byte_skip_minus_1_reads_the_last_bytes_of_a_data_file_holding_just_the_voxels(
    tmp_path: Path, capfd, short: int
) -> None:
    """``byte skip: -1``: the voxels are the data file's last bytes; a file holding exactly them is read (int64,
    read exactly from the raw file), one byte fewer is refused as truncated."""
    values = _voxels("<i8")
    (tmp_path / "v.nhdr").write_text(
        NRRD.format(type="int64", k=3, encoding="raw") + "data file: v.raw\nbyte skip: -1\n"
    )
    (tmp_path / "v.raw").write_bytes(values.tobytes()[short:])
    if short:
        assert f"{values.nbytes} bytes of voxel data expected, {values.nbytes - 1} found" in _refusal(
            tmp_path / "v.nhdr", tmp_path, capfd
        )
    else:
        np.testing.assert_array_equal(read_volume(tmp_path / "v.nhdr").values, values)


def test_a_byte_skip_below_minus_1_is_refused(tmp_path: Path, capfd) -> None:
    """Before: Slicer's reader took ``byte skip: -3`` as 3 bytes before the voxels, so the header's last bytes were
    read as voxels: 2570 among values of 0 .. 490, exit 0."""
    path = tmp_path / "v.nrrd"
    path.write_bytes(
        (NRRD.format(type="short", k=3, encoding="raw") + "byte skip: -3\n\n").encode() + _voxels().tobytes()
    )
    assert "its header gives byte skip -3: only -1" in _refusal(path, tmp_path, capfd)


def test_a_metaimage_header_size_below_minus_1_is_read_as_metaio_reads_it(tmp_path: Path) -> None:
    """MetaIO skips bytes only for HeaderSize -1 or above 0: -5 reads the voxels from the data file's start. Before,
    the storage parser gave up on it, so 64-bit integers went to Slicer's reader, which rounds them to float32 (the
    50 values became one)."""
    values = _voxels("<i8")
    (tmp_path / "v.mhd").write_text(MHA.format(type="MET_LONG_LONG") + "HeaderSize = -5\nElementDataFile = v.raw\n")
    (tmp_path / "v.raw").write_bytes(values.tobytes())
    read = read_volume(tmp_path / "v.mhd").values
    assert read.dtype == np.int64
    np.testing.assert_array_equal(read, values)


def test_a_detached_header_ending_in_a_blank_line_reads_its_data_file_from_the_start(tmp_path: Path) -> None:
    values = _voxels("<i8")
    (tmp_path / "v.nhdr").write_text(NRRD.format(type="int64", k=3, encoding="raw") + "data file: v.raw\n\n")
    (tmp_path / "v.raw").write_bytes(values.tobytes())
    np.testing.assert_array_equal(read_volume(tmp_path / "v.nhdr").values, values)


@pytest.mark.parametrize("beyond", [0, 1], ids=["at-the-bound", "beyond-the-bound"])
def test_a_compressed_volume_may_announce_up_to_the_deflate_bound_of_its_files(
    tmp_path: Path, capfd, beyond: int
) -> None:
    """A detached gzip NRRD: header and data file hold S bytes, so at most 1032 S bytes of voxels. A header
    announcing exactly that many goes on to Slicer's reader (which finds the stream corrupt); one voxel more is
    refused from the header, by a bound that counts the data file as well as the header."""
    header = NRRD.format(type="short", k="{k:04d}", encoding="gzip").replace("8 7", "100 10") + "data file: v.gz\n"
    stored = 250 * 40  # 129 / 250 of it is k at the bound: 1032 S bytes = 2000 k bytes (int16, 100 x 10 x k)
    k = 129 * 40 + beyond
    (tmp_path / "v.nhdr").write_text(header.format(k=k))
    (tmp_path / "v.gz").write_bytes(b"\x1f\x8b" + bytes(stored - len(header.format(k=k)) - 2))
    assert (tmp_path / "v.nhdr").stat().st_size + (tmp_path / "v.gz").stat().st_size == stored
    assert 2 * 100 * 10 * k - 1032 * stored == 2000 * beyond
    err = _refusal(tmp_path / "v.nhdr", tmp_path, capfd)
    assert ("more than its 10000 bytes on disk can hold" in err) == bool(beyond), err


def _nifti1(vox_offset: float, *, magic: bytes = b"n+1\0") -> bytes:
    """A NIfTI-1 header of int16 voxels, (K, J, I) = (3, 7, 8), 1 mm, no extension, no orientation."""
    header = bytearray(348)
    struct.pack_into("<i", header, 0, 348)
    struct.pack_into("<8h", header, 40, 3, 8, 7, 3, 1, 1, 1, 1)
    struct.pack_into("<hh", header, 70, 4, 16)
    struct.pack_into("<8f", header, 76, 1, 1, 1, 1, 1, 1, 1, 1)
    struct.pack_into("<ff", header, 108, vox_offset, 1.0)
    header[344:348] = magic
    return bytes(header)


def _plain_nifti(folder: Path, values: np.ndarray) -> np.ndarray:
    """``values`` as Slicer's reader gives them from a plain .nii (no extension, voxels right after the header)."""
    (folder / "plain").mkdir()
    (folder / "plain" / "v.nii").write_bytes(_nifti1(352) + bytes(4) + values.tobytes())
    read = read_volume(folder / "plain" / "v.nii").values
    assert sorted(read.ravel()) == sorted(values.ravel())
    return read


@pytest.mark.parametrize("beyond", [0, 1], ids=["at-the-bound", "beyond-the-bound"])
@pytest.mark.parametrize("pair", [False, True], ids=["nii", "hdr-img"])
def test_nifti_extensions_are_accepted_up_to_their_bound(
    tmp_path: Path, capfd, monkeypatch, pair: bool, beyond: int
) -> None:
    """1024 bytes after the header: between it and vox_offset in a .nii, after it in the .hdr of a pair. With the
    bound at 1024 the volume reads; at 1023 it is refused in one line."""
    monkeypatch.setattr(volume_io, "MAX_NIFTI_EXTENSION_BYTES", 1024 - beyond)
    values = _voxels()
    if pair:
        (tmp_path / "v.hdr").write_bytes(_nifti1(0, magic=b"ni1\0") + bytes(1024))
        (tmp_path / "v.img").write_bytes(values.tobytes())
    else:
        (tmp_path / "v.nii").write_bytes(_nifti1(348 + 1024) + bytes(1024) + values.tobytes())
    path = tmp_path / ("v.hdr" if pair else "v.nii")
    if beyond:
        assert "its header extensions take 1.0 KiB" in _refusal(path, tmp_path, capfd)
    else:
        np.testing.assert_array_equal(read_volume(path).values, _plain_nifti(tmp_path, values))


@pytest.mark.parametrize("short", [0, 1], ids=["whole", "one-byte-short"])
def test_a_nifti_one_byte_short_is_refused(tmp_path: Path, capfd, short: int) -> None:
    """Slicer's NIfTI reader fills missing voxels with zeros and says nothing: one byte missing is refused."""
    values = _voxels()
    path = tmp_path / "v.nii"
    path.write_bytes(_nifti1(352) + bytes(4) + values.tobytes()[: values.nbytes - short])
    if short:
        assert f"{values.nbytes} bytes of voxel data expected, {values.nbytes - 1} found" in _refusal(
            path, tmp_path, capfd
        )
    else:
        assert sorted(read_volume(path).values.ravel()) == sorted(values.ravel())


@pytest.mark.parametrize("vox_offset", [float("nan"), float("inf"), -4.0])
def test_a_nifti_vox_offset_that_is_not_a_place_in_the_file_is_one_line(tmp_path: Path, capfd, vox_offset) -> None:
    path = tmp_path / "v.nii"
    path.write_bytes(_nifti1(vox_offset) + bytes(4) + _voxels().tobytes())
    assert f"its header gives vox_offset {vox_offset}" in _refusal(path, tmp_path, capfd)


def test_a_nifti_vox_offset_inside_its_header_still_counts_the_voxels_after_it(tmp_path: Path, capfd) -> None:
    """vox_offset 0 in a .nii: the voxels start after the header anyway, so a file 100 bytes short of them is
    truncated, not complete because the header's own bytes are counted."""
    path = tmp_path / "v.nii"
    path.write_bytes(_nifti1(0) + bytes(4) + _voxels().tobytes()[:-100])
    assert "it is truncated" in _refusal(path, tmp_path, capfd)


@pytest.mark.parametrize(("given", "fifo"), [("v.hdr", "v.img"), ("v.img", "v.hdr")])
def test_a_fifo_as_the_other_file_of_a_nifti_pair_is_refused_without_waiting(
    tmp_path: Path, capfd, given: str, fifo: str
) -> None:
    (tmp_path / "v.hdr").write_bytes(_nifti1(0, magic=b"ni1\0") + bytes(4))
    (tmp_path / "v.img").write_bytes(_voxels().tobytes())
    (tmp_path / fifo).unlink()
    os.mkfifo(tmp_path / fifo)
    assert "is not a regular file (a FIFO, socket or device)" in _refusal(tmp_path / given, tmp_path, capfd)


def test_the_img_gz_of_a_pair_beside_its_img_is_refused_not_read_from_the_img(tmp_path: Path, capfd) -> None:
    """v.hdr with both v.img and v.img.gz: the NIfTI library reads v.img. Given v.img.gz, the volume read would be
    another file's: refused in one line."""
    (tmp_path / "v.hdr").write_bytes(_nifti1(0, magic=b"ni1\0") + bytes(4))
    (tmp_path / "v.img").write_bytes(_voxels().tobytes())
    (tmp_path / "v.img.gz").write_bytes(gzip.compress((_voxels() + 1).tobytes()))
    err = _refusal(tmp_path / "v.img.gz", tmp_path, capfd)
    assert "Slicer's reader reads the voxels of 'v.hdr' from 'v.img', not this file" in err


def test_a_nifti2_vox_offset_that_float32_cannot_hold_is_refused(tmp_path: Path, capfd) -> None:
    """NIfTI-2 is read as the same header in NIfTI-1, whose vox_offset is a float32: 2^24 + 1 would become 2^24, one
    byte early, and every voxel would be read shifted. Refused in one line (the .img is sparse)."""
    write_nifti(tmp_path / "v.hdr", _voxels(), np.eye(4), version=2)
    header = bytearray((tmp_path / "v.hdr").read_bytes())
    struct.pack_into("<q", header, 168, (1 << 24) + 1)
    (tmp_path / "v.hdr").write_bytes(bytes(header))
    with open(tmp_path / "v.img", "wb") as img:
        img.seek((1 << 24) + 1)
        img.write(_voxels().tobytes())
    assert "its voxels start at byte 16777217, which a NIfTI-1 header cannot say exactly" in _refusal(
        tmp_path / "v.hdr", tmp_path, capfd
    )


@pytest.mark.parametrize("beyond", [False, True], ids=["at-the-bound", "beyond-the-bound"])
def test_values_beyond_the_float_sums_bound_keep_their_data_range_without_warnings(beyond: bool) -> None:
    """Padding at the volume's lowest value, scaled so that it lies at -MAX_VALUE_MAGNITUDE (the rules apply and leave
    it out) or just beyond (the rules' spreads could overflow: the data range is returned, which the design
    refuses in one line), with numpy's warnings as errors."""
    padding = -MAX_VALUE_MAGNITUDE * (1 + 1e-9 if beyond else 1)
    values = _with(_scan(1000, np.float64) * (MAX_VALUE_MAGNITUDE / 3000), (padding, 1000))
    assert (values.min() < -MAX_VALUE_MAGNITUDE) == beyond
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        robust = robust_value_range(values)
    data_range = (float(values.min()), float(values.max()))
    assert robust.value_range == (data_range if beyond else (0.0, float(values.max())))
