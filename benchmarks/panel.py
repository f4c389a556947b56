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

HEAD_CT = "/usr/share/doc/invesalius-examples/examples/Cranium.inv3"
TEMPLATES = Path("/usr/share/mricron/templates")
DENSE_HU = 300.0


@dataclass(frozen=True)
class PanelVolume:
    """One volume of the panel.

    Attributes:
        key: short name. title: for tables and montages. kind: "CT", "MRI" or "micro-CT" (which preset suits).
        load: returns ``(values, spacing, truth)``; truth is ``(labels, names)`` or None.
        available: whether its data is on this machine.
        source: where the data comes from.
    """

    key: str
    title: str
    kind: str
    load: Callable[[], tuple]
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


def storages(hu: np.ndarray) -> dict[str, tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]]:
    """The same CT in four storages, each with its map back to HU."""
    low, high = float(hu.min()), float(hu.max())
    scale = (high - low) / 255.0
    return {
        "hu": (hu, lambda v: v),
        "uint16": ((hu.astype(np.int32) + 1024).clip(0, 65535).astype(np.uint16), lambda v: v - 1024.0),
        "8bit": (np.round((hu - low) / scale).astype(np.uint8), lambda v: v * scale + low),
        "float": (hu.astype(np.float32), lambda v: v),
    }


def dense_labels(hu: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
    """Voxels labelled by density: 0 below 300 HU ("soft and air"), 1 from it ("dense": bone, contrast)."""
    return (hu >= DENSE_HU).astype(np.uint8), ("soft and air", "dense")


def _head_ct() -> tuple[np.ndarray, tuple]:
    from isosimtf.volume_io import read_volume

    volume = read_volume(HEAD_CT)
    return volume.values, volume.spacing


def _phantom(size: int = 128):
    from isosimtf.phantom import head_phantom

    return head_phantom(size, seed=0)


def _nifti(path: Path):
    from isosimtf.volume_io import read_volume

    volume = read_volume(path)
    return volume.values, volume.spacing


def _downsampled(path: Path, factors: tuple[int, int, int]):
    """A volume averaged over blocks of ``factors`` voxels (z, y, x): a coarse acquisition of the same head."""
    values, spacing = _nifti(path)
    fz, fy, fx = factors
    nz, ny, nx = (n // f * f for n, f in zip(values.shape, factors))
    blocks = values[:nz, :ny, :nx].astype(np.float64).reshape(nz // fz, fz, ny // fy, fy, nx // fx, fx)
    coarse = np.round(blocks.mean(axis=(1, 3, 5))).astype(values.dtype)
    return coarse, (spacing[0] * fx, spacing[1] * fy, spacing[2] * fz)


def _mni152() -> tuple:
    import importlib.util

    spec = importlib.util.find_spec("nilearn")
    path = Path(spec.origin).parent / "datasets" / "data" / "mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz"
    values, spacing = _nifti(path)
    return values, spacing


def _has_nilearn() -> bool:
    import importlib.util

    return importlib.util.find_spec("nilearn") is not None


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
    return stored, (step, step, step), (labels, (*TISSUES, "artery", "head holder"))


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
    return np.clip(np.round(values), 0, 65535).astype(np.uint16), (step, step, step), (labels, names)


def _phantom_storage(name: str):
    def load():
        from isosimtf.phantom import TISSUES

        phantom = _phantom()
        values, _ = storages(phantom.values)[name]
        return values, phantom.spacing, (phantom.labels, TISSUES)

    return load


def _ct_storage(name: str):
    def load():
        hu, spacing = _head_ct()
        values, _ = storages(hu)[name]
        return values, spacing, dense_labels(hu)

    return load


def _always() -> bool:
    return True


def _file(path) -> Callable[[], bool]:
    return lambda: Path(path).is_file()


PANEL: tuple[PanelVolume, ...] = (
    *(
        PanelVolume(f"head-ct-{s}", f"Head CT, {s}", "CT", _ct_storage(s), _file(HEAD_CT),
                    "Debian invesalius-examples (Cranium.inv3), re-stored")
        for s in ("hu", "uint16", "8bit", "float")
    ),
    *(
        PanelVolume(f"phantom-{s}", f"Phantom 128^3, {s}", "CT", _phantom_storage(s), _always,
                    "isosimtf phantom, seed 0, re-stored")
        for s in ("hu", "uint16", "8bit", "float")
    ),
    PanelVolume("phantom-64", "Phantom 64^3 (3.75 mm)", "CT",
                lambda: (lambda p: (p.values, p.spacing, (p.labels, p.tissues)))(_phantom(64)), _always,
                "isosimtf phantom, seed 0, 64 voxels"),
    PanelVolume("cta-8bit", "CT angiogram, 8-bit (synthetic)", "CT", synthetic_cta, _always,
                "the phantom with arteries and a head holder, windowed to 8 bits"),
    PanelVolume("micro-ct", "Micro-CT specimen in a tube, uint16 (synthetic)", "micro-CT", synthetic_micro_ct,
                _always, "synthetic"),
    PanelVolume("colin27-05mm", "Colin27 T1 at 0.5 mm (ch2better)", "MRI",
                lambda: (*_nifti(TEMPLATES / "ch2better.nii.gz"), None), _file(TEMPLATES / "ch2better.nii.gz"),
                "Debian mricron-data"),
    PanelVolume("colin27-coarse", "Colin27 T1 averaged to 2 x 2 x 3 mm", "MRI",
                lambda: (*_downsampled(TEMPLATES / "ch2.nii.gz", (3, 2, 2)), None),
                _file(TEMPLATES / "ch2.nii.gz"), "Debian mricron-data, block means"),
    PanelVolume("mni152", "MNI152 T1 (nilearn)", "MRI", lambda: (*_mni152(), None), _has_nilearn,
                "nilearn package data"),
    PanelVolume("inia19", "INIA19 macaque T1 brain", "MRI",
                lambda: (*_nifti(TEMPLATES / "inia19-t1-brain.nii.gz"), None),
                _file(TEMPLATES / "inia19-t1-brain.nii.gz"), "Debian mricron-data"),
)  # fmt: skip
