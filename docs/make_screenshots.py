"""Regenerate the README pictures under Resources/Screenshots with the isosimtf tool itself.

Run from the repository root: .venv/bin/python docs/make_screenshots.py (needs the Debian packages
invesalius-examples and mricron-data for the two real volumes). Class grids and the gallery's thumbnails are stored
as 256-colour PNGs (Pillow's max-coverage quantizer) to keep the repository small; commit a picture only when it
changes what a reader sees. The comparison montages the README shows are copied from `make compare`'s pictures
(benchmarks/results/pictures, never committed) when they are there, at 2/3 of their size in 256 colours.
"""

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from PIL import Image

from isosimtf.volume_io import real_dataset_path

ROOT = Path(__file__).resolve().parents[1]
SHOTS = ROOT / "Resources" / "Screenshots"
TOOL = Path(sys.executable).with_name("isosimtf")
#: make compare's montages the README shows: the head CT in two storages, a volume whose first click loses where a
#: look of the gallery keeps up (the stroke FLAIR), one where we lose (the heptane flame), and thin structures in the
#: open as a first click (the synthetic plant, whose twigs no preset shows).
COMPARE_PICTURES = ROOT / "benchmarks" / "results" / "pictures"
COMPARE_MONTAGES = ("head-ct", "head-ct-8bit", "mr-brain-stroke-flair", "sim-heptane", "plant-ct")


def main() -> None:
    inputs = {
        "phantom": "phantom",
        "head-ct": real_dataset_path("head-ct"),
        "brain-mri": real_dataset_path("brain-mri"),
        "brain-stripped": real_dataset_path("brain-stripped"),
    }
    SHOTS.mkdir(parents=True, exist_ok=True)
    for name, source in inputs.items():
        if source is None:
            print(f"skipping {name}: its Debian data package is not installed")
            continue
        with tempfile.TemporaryDirectory() as out:
            subprocess.run([str(TOOL), str(source), "-o", out, "--size", "320", "--quiet"], check=True)
            shutil.copyfile(Path(out) / "render.png", SHOTS / f"{name}-render.png")
            shutil.copyfile(Path(out) / "similarity.png", SHOTS / f"{name}-similarity.png")
            for grid_name in ("classes", "looks"):  # the tissues' tiles; the gallery's thumbnails
                grid = Image.open(Path(out) / f"{grid_name}.png").convert("RGB")
                quantized = grid.quantize(256, method=Image.Quantize.MAXCOVERAGE)
                quantized.save(SHOTS / f"{name}-{grid_name}.png", optimize=True)
        print(f"{name}: done")
    for name in COMPARE_MONTAGES:
        source = COMPARE_PICTURES / f"compare-{name}.png"
        if not source.is_file():
            print(f"skipping compare-{name}: run make compare first")
            continue
        montage = Image.open(source).convert("RGB")
        montage = montage.resize((montage.width * 2 // 3, montage.height * 2 // 3), Image.Resampling.LANCZOS)
        quantized = montage.quantize(256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        quantized.save(SHOTS / f"compare-{name}.png", optimize=True)
        print(f"compare-{name}: done")


if __name__ == "__main__":
    main()
