"""The panel of volumes the default look is judged on (issue 16): none of them was used to set a constant.

Each entry gives ``(values [k, j, i], spacing (x, y, z) mm, truth)``: ``truth`` is ``(labels, names)`` where the
volume has ground truth (the phantoms) and ``None`` otherwise; for CT, :func:`dense_labels` labels the voxels by
density instead ("dense" = at least 300 HU, the bone and contrast that CT presets show).

- **Storage variants** of the head CT and of the phantom: Hounsfield units (int16), HU + 1024 as uint16 (raw DICOM
  pixel data, micro-CT), an 8-bit export (the range mapped linearly to 0..255), a float32 copy. The same data: a look
  that depends on storage shows in these rows.
- **Resolution variants**: the phantom at 64^3 (3.75 mm), Colin27 at 0.5 mm (``ch2better``) and averaged down to
  2 x 2 x 3 mm (a coarse clinical T1).
- **Other real volumes** from Debian's mricron-data and nilearn's package data: the skull-stripped MNI152 T1, the
  INIA19 macaque brain.
- **Synthetic volumes with ground truth**, for kinds no package ships: an 8-bit CT angiogram of head and neck (the
  phantom with contrast-filled arteries and a plastic head holder, windowed to 8 bits), and a micro-CT of a small
  specimen (a bone shell with denser teeth inside a plastic tube, uint16 arbitrary units, noisy air: the fog test).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: synthetic_cta's window: stored = (HU + 1024) * 255 / 3024.
CTA_MAP = (255.0 / 3024.0, 1024.0 * 255.0 / 3024.0)
HEAD_CT = "/usr/share/doc/invesalius-examples/examples/Cranium.inv3"
TEMPLATES = Path("/usr/share/mricron/templates")
DENSE_HU = 300.0


@dataclass(frozen=True)
class PanelVolume:
    """One volume of the panel.

    Attributes:
        key: short name. title: for tables and montages. kind: "CT", "MRI" or "micro-CT" (which presets suit).
        load: returns ``(values [k, j, i], ijk_to_ras 4x4, labels or None, label names or None, storage)``, storage
            the map ``stored = slope * HU + offset`` as ``(slope, offset)`` for CT, None otherwise.
        shown_for: the label names a user scanned for (their share of the picture is the target), or ().
        fog: the label name that must take no share of the picture (the air), or None.
        available: whether its data is on this machine.
        source: where the data comes from.
    """

    key: str
    title: str
    kind: str
    load: Callable[[], tuple]
    shown_for: tuple[str, ...]
    fog: str | None
    available: Callable[[], bool]
    source: str


def gaussian_blur(values: np.ndarray, sigma_vox: tuple[float, float, float]) -> np.ndarray:
    """Separable Gaussian blur by FFT (periodic edges: every volume here has air at its borders)."""
    out = np.fft.rfftn(values.astype(np.float64))
    for axis, sigma in enumerate(sigma_vox):
        n = values.shape[axis]
        freq = np.fft.rfftfreq(n) if axis == values.ndim - 1 else np.fft.fftfreq(n)
        shape = [1] * values.ndim
        shape[axis] = freq.size
        out *= np.exp(-2 * (np.pi * sigma * freq) ** 2).reshape(shape)
    return np.fft.irfftn(out, s=values.shape)


def storages(hu: np.ndarray) -> dict[str, tuple[np.ndarray, tuple[float, float]]]:
    """The same CT in four storages, each with the map ``stored = slope * HU + offset`` that made it."""
    low, high = float(hu.min()), float(hu.max())
    scale = 255.0 / (high - low)
    return {
        "hu": (hu, (1.0, 0.0)),
        "uint16": ((hu.astype(np.int32) + 1024).clip(0, 65535).astype(np.uint16), (1.0, 1024.0)),
        "8bit": (np.round((hu - low) * scale).astype(np.uint8), (scale, -low * scale)),
        "float": (hu.astype(np.float32), (1.0, 0.0)),
    }


def partial_volume(
    values: np.ndarray, labels: np.ndarray, means: np.ndarray, noise: float, blur_vox: float
) -> np.ndarray:
    """The labels a picture's samples are attributed to: a voxel the blur raised towards a denser neighbour shows that
    neighbour (``tissue_visibility.partial_volume_labels``, 3 noise sigma of tolerance, the blur's 3-sigma reach)."""
    from tissue_visibility import partial_volume_labels

    return partial_volume_labels(values, labels, means, 3.0 * noise, int(np.ceil(3.0 * blur_vox)))


def _grid(spacing: tuple[float, float, float]) -> np.ndarray:
    """IJK-to-RAS of an axis-aligned volume (the phantom's frame: +x left, +y anterior, +z superior)."""
    return np.diag([*spacing, 1.0])


def dense_labels(hu: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
    """Voxels labelled by density: 0 below 300 HU ("soft and air"), 1 from it ("dense": bone, contrast)."""
    return (hu >= DENSE_HU).astype(np.uint8), ("soft and air", "dense")


def _read(path) -> tuple[np.ndarray, np.ndarray]:
    from isosimtf.volume_io import read_volume

    volume = read_volume(path)
    return volume.values, volume.ijk_to_ras()


def _downsampled(path: Path, factors: tuple[int, int, int]) -> tuple:
    """A volume averaged over blocks of ``factors`` voxels (z, y, x): a coarse acquisition of the same head."""
    values, ijk_to_ras = _read(path)
    fz, fy, fx = factors
    nz, ny, nx = (n // f * f for n, f in zip(values.shape, factors))
    blocks = values[:nz, :ny, :nx].astype(np.float64).reshape(nz // fz, fz, ny // fy, fy, nx // fx, fx)
    coarse = np.round(blocks.mean(axis=(1, 3, 5))).astype(values.dtype)
    matrix = ijk_to_ras.copy()
    matrix[:3, :3] = ijk_to_ras[:3, :3] * np.array([fx, fy, fz])[None, :]
    return coarse, matrix, None, None, None


def _nilearn_t1() -> Path | None:
    import importlib.util

    spec = importlib.util.find_spec("nilearn")
    if spec is None or spec.origin is None:
        return None
    return Path(spec.origin).parent / "datasets" / "data" / "mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz"


def synthetic_cta(size: int = 128, seed: int = 0) -> tuple[np.ndarray, tuple, tuple]:
    """An 8-bit CT angiogram of head and neck with ground truth (see the module notes).

    The phantom's anatomy plus carotid and vertebral arteries (350 HU, 3 and 2 mm radius) rising through the neck
    into a ring at the skull base, and a plastic head holder (a 6 mm cradle, 150 HU) under the back of the head;
    blurred 1 mm, noise 15 HU, then windowed from -1024..2000 HU to 0..255.
    """
    from isosimtf.phantom import FIELD_OF_VIEW_MM, TISSUE_HU, TISSUES, head_phantom

    phantom = head_phantom(size, seed=seed, noise_hu=0.0, blur_mm=0.0)
    labels = phantom.labels.copy()
    step = FIELD_OF_VIEW_MM / size
    z, y, x = (np.indices(labels.shape, dtype=np.float64) + 0.5) * step - FIELD_OF_VIEW_MM / 2
    vessel, holder = len(TISSUES), len(TISSUES) + 1
    arteries = np.zeros(labels.shape, dtype=bool)
    for cx, cy, radius in ((-22.0, 10.0, 3.0), (22.0, 10.0, 3.0), (-9.0, -25.0, 2.0), (9.0, -25.0, 2.0)):
        arteries |= ((x - cx) ** 2 + (y - cy) ** 2 <= radius**2) & (z < -25.0)
    ring = (np.hypot(x, y + 5.0) - 20.0) ** 2 + (z + 25.0) ** 2 <= 2.0**2
    arteries |= ring
    arteries &= labels != 0
    labels[arteries] = vessel
    # The cradle: a half shell 6 mm thick around the back of the head, where the phantom has air.
    radius = np.hypot(x / 1.05, (y + 5.0) / 1.25)
    cradle = (radius > 82.0) & (radius < 88.0) & (y < -20.0) & (z > -60.0) & (z < 40.0) & (labels == 0)
    labels[cradle] = holder
    hu_of = np.array([*TISSUE_HU, 350.0, 150.0])
    hu = gaussian_blur(hu_of[labels], (1.0 / step,) * 3)
    hu += np.random.default_rng(seed).normal(0.0, 15.0, hu.shape)
    stored = np.round((np.clip(hu, -1024.0, 2000.0) + 1024.0) / 3024.0 * 255.0).astype(np.uint8)
    slope, offset = CTA_MAP
    labels = partial_volume(stored, labels, slope * hu_of + offset, 15.0 * slope, 1.0 / step)
    return stored, _grid((step, step, step)), labels, (*TISSUES, "artery", "head holder"), CTA_MAP


def synthetic_micro_ct(size: int = 128, seed: int = 0) -> tuple[np.ndarray, tuple, tuple]:
    """A micro-CT of a small specimen with ground truth (see the module notes); uint16, arbitrary units.

    A 6.4 mm field of view (0.05 mm voxels): a plastic tube (wall 0.3 mm) holding a specimen in ethanol, a bone
    shell 0.25 mm thick with two teeth denser than bone inside it; air 1000, tube 3000, ethanol 2600, soft tissue
    3800, bone 11000, teeth 17000; blurred 1.2 voxels, noise 500 (reconstruction noise: a fog in the air).
    """
    names = ("air", "tube", "ethanol", "soft tissue", "bone", "teeth")
    values_of = np.array([1000.0, 3000.0, 2600.0, 3800.0, 11000.0, 17000.0])
    step = 6.4 / size
    z, y, x = (np.indices((size, size, size), dtype=np.float64) + 0.5) * step - 3.2
    labels = np.zeros((size, size, size), dtype=np.uint8)
    r = np.hypot(x, y)
    inside_tube = (r < 2.7) & (np.abs(z) < 3.0)
    labels[inside_tube] = 2
    labels[(r >= 2.7) & (r < 3.0) & (np.abs(z) < 3.0)] = 1
    shell = np.sqrt((x / 1.9) ** 2 + (y / 1.5) ** 2 + (z / 2.3) ** 2)
    labels[shell < 1.0] = 3
    labels[(shell >= 0.87) & (shell < 1.0)] = 4
    for cx in (-0.6, 0.6):
        labels[((x - cx) ** 2 + (y - 0.5) ** 2) / 0.3**2 + ((z + 0.8) / 0.9) ** 2 < 1.0] = 5
    values = gaussian_blur(values_of[labels], (1.2, 1.2, 1.2))
    values += np.random.default_rng(seed).normal(0.0, 500.0, values.shape)
    stored = np.clip(np.round(values), 0, 65535).astype(np.uint16)
    labels = partial_volume(stored, labels, values_of, 500.0, 1.2)
    return stored, _grid((step, step, step)), labels, names, None


def _phantom_storage(name: str, size: int = 128):
    def load():
        from isosimtf.phantom import TISSUE_HU, TISSUES, head_phantom

        phantom = head_phantom(size, seed=0)
        values, (slope, offset) = storages(phantom.values)[name]
        means = slope * np.asarray(TISSUE_HU) + offset
        labels = partial_volume(values, phantom.labels, means, 20.0 * slope, 1.0 / phantom.spacing[0])
        return values, _grid(phantom.spacing), labels, TISSUES, (slope, offset)

    return load


def ct_storage(name: str):
    def load():
        hu, ijk_to_ras = _read(HEAD_CT)
        values, storage = storages(hu)[name]
        labels, names = dense_labels(hu)
        return values, ijk_to_ras, labels, names, storage

    return load


def _file(path) -> Callable[[], bool]:
    return lambda: path is not None and Path(path).is_file()


def _always() -> bool:
    return True


def _file_load(path) -> Callable[[], tuple]:
    return lambda: (*_read(path), None, None, None)


PANEL: tuple[PanelVolume, ...] = (
    *(
        PanelVolume(f"head-ct-{s}", f"Head CT, {s}", "CT", ct_storage(s), ("dense",), None,
                    _file(HEAD_CT), "Debian invesalius-examples (Cranium.inv3), re-stored")
        for s in ("uint16", "8bit", "float")  # in HU it is compare.py's head-ct
    ),
    *(
        PanelVolume(f"phantom-{s}", f"Phantom 128^3, {s}", "CT", _phantom_storage(s), ("skull",),
                    "air", _always, "isosimtf phantom, seed 0, re-stored")
        for s in ("uint16", "8bit", "float")
    ),
    PanelVolume("phantom-64", "Phantom 64^3 (3.75 mm)", "CT", _phantom_storage("hu", 64), ("skull",),
                "air", _always, "isosimtf phantom, seed 0, 64 voxels"),
    PanelVolume("cta-8bit", "CT angiogram, 8-bit (synthetic)", "CT", synthetic_cta, ("skull", "artery"),
                "air", _always, "the phantom with arteries and a head holder, windowed to 8 bits"),
    PanelVolume("micro-ct", "Micro-CT specimen in a tube, uint16 (synthetic)", "micro-CT", synthetic_micro_ct,
                ("bone", "teeth"), "air", _always, "synthetic"),
    PanelVolume("colin27-05mm", "Colin27 T1 at 0.5 mm (ch2better)", "MRI", _file_load(TEMPLATES / "ch2better.nii.gz"),
                (), None, _file(TEMPLATES / "ch2better.nii.gz"), "Debian mricron-data"),
    PanelVolume("colin27-coarse", "Colin27 T1 averaged to 2 x 2 x 3 mm", "MRI",
                lambda: _downsampled(TEMPLATES / "ch2.nii.gz", (3, 2, 2)), (), None,
                _file(TEMPLATES / "ch2.nii.gz"), "Debian mricron-data, block means"),
    PanelVolume("mni152", "MNI152 T1 (nilearn)", "MRI", lambda: (*_read(_nilearn_t1()), None, None, None), (), None,
                lambda: _file(_nilearn_t1())(), "nilearn package data"),
    PanelVolume("inia19", "INIA19 macaque T1 brain", "MRI", _file_load(TEMPLATES / "inia19-t1-brain.nii.gz"),
                (), None, _file(TEMPLATES / "inia19-t1-brain.nii.gz"), "Debian mricron-data"),
)  # fmt: skip
