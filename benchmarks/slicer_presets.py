"""Slicer's volume rendering presets (``presets.xml``), found and read at run time; never copied into this repository.

3D Slicer ships its presets in ``Modules/Loadable/VolumeRendering/Resources/presets.xml`` (3D Slicer, BSD-style
Slicer License, https://github.com/Slicer/Slicer/blob/main/License.txt). The file is an MRML scene of
``VolumeProperty`` elements whose transfer functions are strings "N v1 v2 ... vN": ``scalarOpacity`` pairs (x, a),
``colorTransfer`` quadruples (x, r, g, b), ``gradientOpacity`` pairs (|gradient|, a); ``effectiveRange`` is the value
range the preset is meant for.

Where the file is looked for, in order (:func:`find_presets`): an explicit path (``make compare PRESETS=...``), the
environment variable ``ISOSIMTF_PRESETS``, ``../shared/presets.xml`` next to the repository, and a bare git mirror of
Slicer's repository (``git show HEAD:<path>``, written to a temporary file).
"""

from __future__ import annotations

import os
import subprocess
import tempfile
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: Path of presets.xml inside Slicer's repository.
PRESETS_IN_SLICER = "Modules/Loadable/VolumeRendering/Resources/presets.xml"
#: Environment variable naming a presets.xml.
PRESETS_ENV = "ISOSIMTF_PRESETS"
#: Bare git mirror of Slicer's repository looked at last.
SLICER_MIRROR = Path("/work/.mirror/Slicer+Slicer/repo")
#: Attribution printed with every table that uses the presets.
ATTRIBUTION = (
    f"Presets read at run time from 3D Slicer's `{PRESETS_IN_SLICER}` (3D Slicer, BSD-style Slicer License, "
    "https://github.com/Slicer/Slicer/blob/main/License.txt); they are not copied into this repository."
)
HOW_TO_PROVIDE = (
    f"Slicer's presets.xml not found: run `make compare PRESETS=/path/to/presets.xml` (from Slicer's source, "
    f"{PRESETS_IN_SLICER}) or set {PRESETS_ENV}"
)


class PresetsNotFound(FileNotFoundError):
    """No presets.xml was found; the message says in one line how to provide it."""


@dataclass(frozen=True)
class PresetsSource:
    """Where the presets came from: ``path`` (readable file) and ``origin`` (a description for the report)."""

    path: Path
    origin: str


@dataclass(frozen=True)
class Preset:
    """One ``VolumeProperty`` of presets.xml.

    Attributes:
        name: preset name, e.g. "CT-Bone".
        scalar_opacity: ``(n, 2)`` points (value, opacity), opacity per unit distance (1 mm: presets set none).
        color: ``(n, 4)`` points (value, r, g, b), colours in 0..1.
        gradient_opacity: ``(n, 2)`` points (gradient magnitude, opacity).
        effective_range: ``(low, high)`` value range the preset is meant for, or None.
        shading: ``shade``, ``ambient``, ``diffuse``, ``specular``, ``specularPower``, ``interpolation`` as given.
    """

    name: str
    scalar_opacity: np.ndarray
    color: np.ndarray
    gradient_opacity: np.ndarray
    effective_range: tuple[float, float] | None
    shading: dict = field(default_factory=dict)


def parse_function(text: str, width: int) -> np.ndarray:
    """Parse a presets.xml function string "N v1 ... vN" into an ``(N / width, width)`` float array.

    Raises:
        ValueError: the count does not match the values, or is not a multiple of ``width``.
    """
    parts = text.split()
    if not parts:
        return np.zeros((0, width))
    count = int(float(parts[0]))
    values = [float(v) for v in parts[1:]]
    if count != len(values) or count % width:
        raise ValueError(f"function string announces {count} values, has {len(values)} (width {width})")
    return np.asarray(values, dtype=np.float64).reshape(-1, width)


def _range(text: str) -> tuple[float, float] | None:
    """``(low, high)`` from "low high"; None when missing or malformed (Slicer's own file has one "-250.0.0 ...")."""
    try:
        values = [float(v) for v in text.split()]
    except ValueError:
        return None
    return (values[0], values[1]) if len(values) == 2 else None


def read_presets(path: os.PathLike | str) -> dict[str, Preset]:
    """Read every ``VolumeProperty`` of a presets.xml, by name (file order kept)."""
    root = ElementTree.parse(os.fspath(path)).getroot()
    presets: dict[str, Preset] = {}
    for element in root.iter("VolumeProperty"):
        attributes = element.attrib
        low_high = _range(attributes.get("effectiveRange", ""))
        presets[attributes["name"]] = Preset(
            name=attributes["name"],
            scalar_opacity=parse_function(attributes.get("scalarOpacity", ""), 2),
            color=parse_function(attributes.get("colorTransfer", ""), 4),
            gradient_opacity=parse_function(attributes.get("gradientOpacity", ""), 2),
            effective_range=low_high,
            shading={
                key: float(attributes[key])
                for key in ("shade", "ambient", "diffuse", "specular", "specularPower", "interpolation")
                if key in attributes
            },
        )
    return presets


def _from_mirror(mirror: Path) -> PresetsSource | None:
    """presets.xml of the mirror's HEAD, written to a temporary file (None when git or the mirror is missing)."""
    if not mirror.is_dir():
        return None
    try:
        text = subprocess.run(
            ["git", "-C", str(mirror), "show", f"HEAD:{PRESETS_IN_SLICER}"], capture_output=True, check=True
        ).stdout
        commit = subprocess.run(
            ["git", "-C", str(mirror), "rev-parse", "HEAD"], capture_output=True, check=True, text=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    folder = Path(tempfile.mkdtemp(prefix="isosimtf_presets_"))
    path = folder / "presets.xml"
    path.write_bytes(text)
    return PresetsSource(path, f"Slicer repository {mirror} at commit {commit}: {PRESETS_IN_SLICER}")


def find_presets(
    explicit: str | None = None, repo_root: Path | None = None, mirror: Path = SLICER_MIRROR
) -> PresetsSource:
    """Find Slicer's presets.xml: ``explicit``, then ``$ISOSIMTF_PRESETS``, ``repo_root/../shared/presets.xml``, the
    git mirror of Slicer's repository.

    Raises:
        PresetsNotFound: an explicit or environment path that is not a file, or nothing found (the message says how
            to provide the file).
    """
    for given, origin in ((explicit, "PRESETS"), (os.environ.get(PRESETS_ENV), PRESETS_ENV)):
        if given:
            path = Path(given).expanduser()
            if not path.is_file():
                raise PresetsNotFound(f"{origin}={given} is not a file. {HOW_TO_PROVIDE}")
            return PresetsSource(path.resolve(), str(path.resolve()))
    if repo_root is not None:
        shared = (repo_root / ".." / "shared" / "presets.xml").resolve()
        if shared.is_file():
            return PresetsSource(shared, str(shared))
    found = _from_mirror(mirror)
    if found is None:
        raise PresetsNotFound(HOW_TO_PROVIDE)
    return found
