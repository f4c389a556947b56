"""Regenerate the README pictures under Resources/Screenshots with the isosimtf tool itself.

Run from the repository root: .venv/bin/python docs/make_screenshots.py (needs the Debian packages
invesalius-examples and mricron-data for the two real volumes). Class grids and the gallery's thumbnails are stored
as 256-colour PNGs (Pillow's max-coverage quantizer) to keep the repository small; commit a picture only when it
changes what a reader sees.
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


if __name__ == "__main__":
    main()
