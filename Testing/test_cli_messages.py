"""Messages that say what will work (issue 18, items 12-13): label maps recognised beyond 16 values, advice in the
command's own spelling, impossible option pairs refused before any work, sizes never printed as "0 MiB"."""

from pathlib import Path

import numpy as np
import pytest

from isosimtf import cli, run
from isosimtf.formatting import format_bytes
from isosimtf.phantom import head_phantom
from isosimtf.volume_io import read_volume

ATLASES = [
    "/usr/share/mricron/templates/aal.nii.gz",  # 117 labels
    "/usr/share/mricron/templates/HarvardOxford-cort-maxprob-thr0-1mm.nii.gz",  # 49 labels
]


@pytest.mark.parametrize("atlas", ATLASES, ids=["aal", "harvard-oxford"])
def test_atlases_with_many_labels_are_recognised(atlas: str) -> None:
    """Before: only integer volumes spanning at most 16 values were taken for label maps."""
    if not Path(atlas).is_file():
        pytest.skip("Debian package mricron-data is not installed")
    values = read_volume(atlas).values
    assert run.label_count(values) == np.unique(values[:: min(8, values.shape[0] // 32)]).size > 16


def test_scans_are_not_label_maps() -> None:
    from isosimtf.volume_io import real_dataset_path

    for name in ("head-ct", "brain-mri", "brain-stripped"):
        path = real_dataset_path(name)
        if path is not None:
            assert run.label_count(read_volume(path).values) is None, name
    assert run.label_count(head_phantom(32, seed=0).values) is None


def test_convergence_iter_above_max_iter_is_refused_before_any_work(tmp_path: Path, capfd) -> None:
    """Before: --convergence-iter 500 --max-iter 100 was accepted (and could never converge)."""
    argv = ["phantom", "-o", str(tmp_path / "out"), "--convergence-iter", "500", "--max-iter", "100", "--no-render"]
    assert cli.main(argv) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and "--convergence-iter 500 is more than --max-iter 100" in err
    assert "[1/" not in err and not (tmp_path / "out").exists()


def test_sizes_are_never_zero_mib() -> None:
    assert format_bytes(512) == "512 bytes"
    assert format_bytes(3 * 1024 + 300) == "3.3 KiB"
    assert format_bytes(41 * 2**20) == "41 MiB"
    assert format_bytes(1.5 * 2**30) == "1.5 GiB"


@pytest.mark.parametrize(
    ("name", "header", "field"),
    [
        ("z.mha", "ObjectType = Image\nNDims = 3\nDimSize = 5 4 3\nElementSpacing = 0 1 1\nElementType = MET_SHORT\n"
                  "ElementDataFile = LOCAL\n", "ElementSpacing: 0 1 1"),
        ("z.nrrd", "NRRD0004\ntype: short\ndimension: 3\nsizes: 5 4 3\nspacings: 1 0 1\nendian: little\n"
                   "encoding: raw\n\n", "spacings: 1 0 1"),
    ],
)  # fmt: skip
def test_zero_spacing_is_named_not_called_another_format(tmp_path: Path, capfd, name: str, header: str, field) -> None:
    """Before: "not a MetaImage" for a MetaImage whose ElementSpacing holds a zero."""
    path = tmp_path / name
    path.write_bytes(header.encode() + bytes(2 * 5 * 4 * 3))
    assert cli.main([str(path), "-o", str(tmp_path / "out"), "--no-render", "-q"]) == 2
    err = capfd.readouterr().err
    assert f"Cannot read '{path}': its header gives a zero voxel size ({field})" in err and err.count("\n") == 1


def test_more_tissues_than_bins_is_refused_before_the_design(tmp_path: Path, capfd) -> None:
    """Before: --tissues 999 was refused only after the whole design."""
    argv = ["phantom", "-o", str(tmp_path / "out"), "--tissues", "999", "--no-render"]
    assert cli.main(argv) == 2
    err = capfd.readouterr().err
    assert "--tissues 999 is more than --bins 256" in err and "[1/" not in err


def test_extremely_anisotropic_voxels_get_a_warning(tmp_path: Path, capfd) -> None:
    """Issue 18, item 14: 0.05 x 0.05 x 40 mm voxels rendered black without a word; now one warning line says why."""
    from volume_writers import write_volume

    from isosimtf.volume import Volume

    path = tmp_path / "thin.nrrd"
    write_volume(Volume(head_phantom(24, seed=0).values, (0.05, 0.05, 40.0), (0.0, 0.0, 0.0), name="thin"), path)
    assert cli.main([str(path), "-o", str(tmp_path / "out"), "--no-render", "-q"]) == 0
    (line,) = [line for line in capfd.readouterr().err.splitlines() if "times longer" in line]
    assert "0.05 x 0.05 x 40 mm" in line and "800 times" in line and "resample" in line
    assert not [m for m in run._input_warnings({"spacing": [1.0, 1.0, 3.0]}, 256) if "times longer" in m]


def test_advice_with_two_options_and_numbers_is_in_the_command_spelling() -> None:
    """Before: 'raise max_iter or damping (e.g. max_iter=1000, damping=0.9)' came out half converted."""
    text = cli._cli_spelling("no exemplar; raise max_iter or damping (e.g. max_iter=1000, damping=0.9)")
    assert text == "no exemplar; raise --max-iter or --damping (e.g. --max-iter 1000, --damping 0.9)"


@pytest.mark.parametrize("voxels, warned", [(2**30 - 1, False), (2**30 + 1, True)])
def test_a_volume_of_billions_of_voxels_says_how_long_its_design_takes_before_it_starts(voxels, warned):
    """Before: a 276-byte Zarr store declaring 10^12 voxels ran for hours without a word."""
    from isosimtf.run import _input_warnings

    warnings = _input_warnings({"shape": [1, 1, voxels], "spacing": [1.0, 1.0, 1.0]}, 256)
    assert any("the design reads each once, which takes about" in w for w in warnings) is warned


def test_the_estimate_of_a_trillion_voxels_is_in_hours():
    from isosimtf.run import _input_warnings

    (warning,) = _input_warnings({"shape": [10_000, 10_000, 10_000], "spacing": [1.0, 1.0, 1.0]}, 256)
    assert "1e+12 voxels" in warning and "3.3 hours" in warning  # 12 ns per voxel


def test_a_warning_ends_the_progress_line_it_interrupts(tmp_path):
    """On a terminal the stage's progress line stays open; a warning starts on a line of its own."""
    import io

    from isosimtf.console import ProgressPrinter
    from isosimtf.run import run

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    stream = Terminal()
    seen = []
    values = np.random.default_rng(0).normal(size=(12, 12, 12)).astype(np.float32)
    values[:, :, :2] = -3024.0  # padding: the range's warning comes after the design's progress
    np.save(tmp_path / "v.npy", values)
    progress = ProgressPrinter(4, stream=stream)
    run(tmp_path / "v.npy", tmp_path / "out", options={"n_bins": 16}, render=False, progress=progress,
        warn=lambda message: seen.append(stream.getvalue()))  # fmt: skip
    assert seen and all(text.endswith("\n") for text in seen)
