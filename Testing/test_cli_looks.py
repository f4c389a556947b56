"""The gallery on the command line: looks/<name>.vp.json for every look, looks.png, --look, classes.json."""

import json
from pathlib import Path

import numpy as np
import pytest

from IsoSimilarityTFLib.gallery import LOOK_NAMES
from isosimtf import cli

PHANTOM = ["phantom", "--phantom-size", "32", "-q", "--no-render"]


def _run(argv: list, capfd) -> tuple[int, str]:
    code = cli.main([str(a) for a in argv])
    return code, capfd.readouterr().err


def test_every_look_is_written_and_the_chosen_one_is_the_transfer_function(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    code, err = _run([*PHANTOM, "-o", outdir], capfd)
    assert code == 0, err
    document = json.loads((outdir / "classes.json").read_text(encoding="utf-8"))
    names = [look["name"] for look in document["looks"]]
    assert names and set(names) <= set(LOOK_NAMES) and document["look"] == names[0]
    for look in document["looks"]:
        assert (outdir / "looks" / f"{look['name']}.vp.json").is_file()
        assert f"looks/{look['name']}.vp.json" in document["written"]  # recorded like every output
        assert look["objective"] and abs(sum(look["role_shares"].values()) - 1.0) < 1e-9
    assert (outdir / "looks.png").is_file() and "looks.png" in document["written"]
    first = (outdir / "looks" / f"{names[0]}.vp.json").read_text(encoding="utf-8")
    assert (outdir / "transfer_function.vp.json").read_text(encoding="utf-8") == first

    # --look picks another one: transfer_function.vp.json is that look's, the gallery files are the same.
    other = names[-1]
    code, err = _run([*PHANTOM, "-o", outdir, "--look", other], capfd)
    assert code == 0, err
    chosen = (outdir / "looks" / f"{other}.vp.json").read_text(encoding="utf-8")
    assert (outdir / "transfer_function.vp.json").read_text(encoding="utf-8") == chosen != first
    assert json.loads((outdir / "classes.json").read_text(encoding="utf-8"))["look"] == other


def test_a_look_the_data_do_not_offer_is_refused_in_one_line(tmp_path: Path, capfd) -> None:
    outdir = tmp_path / "out"
    code, err = _run([*PHANTOM, "-o", outdir], capfd)
    offered = [look["name"] for look in json.loads((outdir / "classes.json").read_text())["looks"]]
    missing = [name for name in LOOK_NAMES if name not in offered]
    if not missing:
        pytest.skip("the phantom offers every look")
    before = (outdir / "transfer_function.vp.json").read_text()
    code, err = _run([*PHANTOM, "-o", outdir, "--look", missing[0]], capfd)
    assert code == 2 and err.count("\n") == 1
    assert f"--look {missing[0]} is not offered for this volume; its looks: {', '.join(offered)}" in err
    assert (outdir / "transfer_function.vp.json").read_text() == before  # nothing written


def test_an_unknown_look_is_a_usage_error(tmp_path: Path, capfd) -> None:
    code, err = _run([*PHANTOM, "-o", tmp_path / "out", "--look", "rainbow"], capfd)
    assert code == 2 and "invalid choice: 'rainbow'" in err and not (tmp_path / "out").exists()


def test_a_linked_looks_folder_is_never_written_through(tmp_path: Path, capfd) -> None:
    outdir, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    outdir.mkdir()
    elsewhere.mkdir()
    (outdir / "looks").symlink_to(elsewhere)
    code, err = _run([*PHANTOM, "-o", outdir], capfd)
    assert code == 2 and "is a symbolic link" in err and not list(elsewhere.iterdir())


def test_looks_png_is_seen_from_the_patients_front_however_the_file_stores_the_voxels(
    tmp_path: Path, capfd, monkeypatch
) -> None:
    """A file stored as most DICOM series are (i toward the left, j toward posterior): its thumbnails are rendered
    with those directions (:mod:`.thumbnails` shows the patient's front with them; read as RAS, the back)."""
    nrrd = pytest.importorskip("nrrd")
    from IsoSimilarityTFLib.design import TransferFunctionDesign
    from isosimtf.phantom import head_phantom

    phantom = head_phantom(24, seed=0)
    lps = np.diag([-1.0, -1.0, 1.0])
    header = {"space": "right-anterior-superior", "space directions": lps * np.asarray(phantom.spacing),
              "space origin": np.zeros(3), "kinds": ["domain"] * 3, "encoding": "raw"}  # fmt: skip
    nrrd.write(str(tmp_path / "lps.nrrd"), np.ascontiguousarray(phantom.values), header, index_order="C")
    asked = []
    original = TransferFunctionDesign.thumbnail
    monkeypatch.setattr(
        TransferFunctionDesign, "thumbnail", lambda self, *a, **kw: asked.append(kw) or original(self, *a, **kw)
    )
    code, err = _run([tmp_path / "lps.nrrd", "-o", tmp_path / "out", "-q", "--no-render"], capfd)
    assert code == 0, err
    assert asked and all(np.allclose(kw["directions"], lps) for kw in asked)
