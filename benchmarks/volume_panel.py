"""The panel of volumes the default look is judged on (issue 16): none of them was used to set a constant.

Each entry gives ``(values [k, j, i], spacing (x, y, z) mm, truth)``: ``truth`` is ``(labels, names)`` where the
volume has ground truth (the phantoms) and ``None`` otherwise; for CT, :func:`dense_labels` labels the voxels by
density instead ("dense" = at least 300 HU, the bone and contrast that CT presets show).

- **Storage variants** of the head CT and of the phantom: Hounsfield units (int16), HU + 1024 as uint16 (raw DICOM
  pixel data, micro-CT), an 8-bit export (the range mapped linearly to 0..255), a float32 copy, HU clipped at 0 in
  62.5-HU steps (:func:`hu_clipped_quantized`, as a stented aorta's CTA came), and the head CT's clipped storage
  exported again to 8 bits through an auto-contrast window (a few dozen values over many bins); two MRIs (Colin27
  coarse, the shared stroke T1) stored as the integers 0..300 (:func:`rescaled_uint16`; the stroke T1 also as
  0..600, a loss), Colin27's also read through a slope as float32 (:func:`slope_scaled`). The same data: a look that
  depends on storage shows in these rows (:data:`VARIANT_GROUPS`; the HU originals are :data:`REFERENCES`).
- **Resolution variants**: the phantom at 64^3 (3.75 mm), Colin27 at 0.5 mm (``ch2better``) and averaged down to
  2 x 2 x 3 mm (a coarse clinical T1); **voxel-size variants**: the phantom's own voxels with the spacing scaled by
  0.05 and by 3 (a look must not change with the voxel size alone).
- **Other real volumes** from Debian's mricron-data and nilearn's package data: the skull-stripped MNI152 T1, the
  INIA19 macaque brain.
- **Synthetic volumes with ground truth**, for kinds no package ships: an 8-bit CT angiogram of head and neck (the
  phantom with contrast-filled arteries and a plastic head holder, windowed to 8 bits), and a micro-CT of a small
  specimen (a bone shell with denser teeth inside a plastic tube, uint16 arbitrary units, noisy air: the fog test),
  also exported to 8 bits through a window (:func:`windowed_8bit`), as micro-CT software exports it.
  Then the kinds users bring that ``../shared/data`` lacks, each built in numpy with its truth:
  :func:`synthetic_angiogram` (vessel trees only, thresholded, 95-99% zeros; large and small vessels),
  :func:`synthetic_specimen` (micro-CT of trabecular bone at 0.05 mm; also exported to 8 bits through an
  auto-contrast window), :func:`synthetic_housing` (industrial CT: steel parts inside an aluminium housing),
  :func:`synthetic_plant` (a tree in a pot, twigs below a voxel),
  :func:`contrast_ct_8bit` (an 8-bit export of a contrast chest CT), :func:`synthetic_abdomen_ct` (an abdomen-pelvis
  CT in int32 HU, 3 mm slices, on its table; also exported to 8 bits through the chest CT's window,
  :func:`hu_windowed_8bit`) and :func:`synthetic_abdomen_mri` (an abdominal T1 slab with coil
  shading and Rician noise).
- **The ten real volumes of ../shared/data** (:data:`REAL_VOLUMES`, when the folder is there; never copied into the
  repository): their labels are the README's "band scanned for" as value bands (:func:`band_labels`). A reading, not
  ground truth: the bands come from histograms and slices.

``kind`` says which presets suit: "CT", "MRI", "micro-CT", and "angio" (vessels only), "industrial", "plant",
"simulation" (no modality: flow fields).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: synthetic_cta's window: stored = (HU + 1024) * 255 / 3024.
CTA_MAP = (255.0 / 3024.0, 1024.0 * 255.0 / 3024.0)
HEAD_CT = "/usr/share/doc/invesalius-examples/examples/Cranium.inv3"
TEMPLATES = Path("/usr/share/mricron/templates")
DENSE_HU = 300.0
#: The phantom's voxel-size variants: the same voxels, the spacing scaled by these.
VOXEL_SIZE_SCALES = (0.05, 3.0)


#: A preset of Slicer's ``presets.xml`` and the shift (volume units; the module's Shift slider) a user gave it.
Kept = tuple[str, float]


@dataclass(frozen=True)
class PanelVolume:
    """One volume of the panel.

    Attributes:
        key: short name. title: for tables and montages. kind: which presets suit: "CT", "MRI", "micro-CT",
            "angio", "industrial", "plant" or "simulation".
        load: returns ``(values [k, j, i], ijk_to_ras 4x4, labels or None, label names or None, storage)``, storage
            the map ``stored = slope * HU + offset`` as ``(slope, offset)`` for CT, None otherwise.
        shown_for: the label names a user scanned for (their share of the picture is the target), or ().
        fog: the label name that must take no share of the picture (the air), or None.
        available: whether its data is on this machine.
        source: where the data comes from.
        kept: the preset a demanding user would keep on it, and its shift (``../shared/data/README.md``'s reading;
            the real volumes only), or None.
    """

    key: str
    title: str
    kind: str
    load: Callable[[], tuple]
    shown_for: tuple[str, ...]
    fog: str | None
    available: Callable[[], bool]
    source: str
    kept: Kept | None = None


def gaussian_blur(values: np.ndarray, sigma_vox: tuple[float, float, float]) -> np.ndarray:
    """Separable Gaussian blur by FFT (periodic edges: every volume here has air at its borders)."""
    out = np.fft.rfftn(values.astype(np.float64))
    for axis, sigma in enumerate(sigma_vox):
        n = values.shape[axis]
        freq = np.fft.rfftfreq(n) if axis == values.ndim - 1 else np.fft.fftfreq(n)
        shape = [1] * values.ndim
        shape[axis] = freq.size
        out *= np.exp(-2 * (np.pi * sigma * freq) ** 2).reshape(shape)
    return np.fft.irfftn(out, s=values.shape, axes=tuple(range(values.ndim)))


def storages(hu: np.ndarray) -> dict[str, tuple[np.ndarray, tuple[float, float]]]:
    """The same CT in five storages, each with the map ``stored = slope * HU + offset`` that made it: HU, HU + 1024
    as uint16, an 8-bit export of the whole range, float32, and HU clipped at 0 in 62.5-HU steps
    (:func:`hu_clipped_quantized`; the map holds from 0 HU up)."""
    low, high = float(hu.min()), float(hu.max())
    scale = 255.0 / (high - low)
    return {
        "hu": (hu, (1.0, 0.0)),
        "uint16": ((hu.astype(np.int32) + 1024).clip(0, 65535).astype(np.uint16), (1.0, 1024.0)),
        "8bit": (np.round((hu - low) * scale).astype(np.uint8), (scale, -low * scale)),
        "float": (hu.astype(np.float32), (1.0, 0.0)),
        "clipped": hu_clipped_quantized(hu),
    }


#: :func:`hu_clipped_quantized`'s step: the CTA of a stented aorta (the issue) was stored as HU clipped at 0 in
#: steps of 62.5 HU, a few dozen distinct values.
CLIPPED_STEP_HU = 62.5


def hu_clipped_quantized(hu: np.ndarray, step: float = CLIPPED_STEP_HU) -> tuple[np.ndarray, tuple[float, float]]:
    """HU clipped at 0 and stored as a number of ``step``-HU steps: ``stored = round(max(HU, 0) / step)``.

    Returns ``(stored, (slope, offset))``, the map ``stored = slope * HU + offset`` being ``(1 / step, 0)``: mapped
    back, every value is a multiple of ``step`` HU, and everything below 0 HU is 0. uint8 while the steps fit.
    """
    steps = np.round(np.clip(np.asarray(hu, dtype=np.float64), 0.0, None) / step)
    dtype = np.uint8 if steps.max() <= 255 else np.uint16
    return steps.clip(0, np.iinfo(dtype).max).astype(dtype), (1.0 / step, 0.0)


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


def _colin27_coarse() -> tuple:
    """Colin27's T1 (``ch2``, 1 mm, scalp included) averaged over 3 x 2 x 2 voxels: a coarse scan of a whole head."""
    return _downsampled(TEMPLATES / "ch2.nii.gz", (3, 2, 2))


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


def windowed_8bit(
    load: Callable[[], tuple], top_percentile: float = 99.9, bottom_percentile: float | None = None
) -> Callable[[], tuple]:
    """``load`` with its values exported to 8 bits through a window from the lowest stored value (or the
    ``bottom_percentile``-th) to the ``top_percentile``-th, clipped outside: how micro-CT software exports an 8-bit
    volume (a window chosen on the histogram, the densest voxels saturated; the micro-CT skulls issue 24 kept aside
    were 8-bit), or an auto-contrast window (0.5th to 99.5th percentile: the air's lowest noise saturated too).
    Labels and names unchanged; no HU map."""

    def exported(values: np.ndarray) -> np.ndarray:
        low = float(values.min() if bottom_percentile is None else np.percentile(values, bottom_percentile))
        high = float(np.percentile(values, top_percentile))
        return np.round(np.clip((values - low) / (high - low), 0.0, 1.0) * 255.0).astype(np.uint8)

    return _restored(load, exported)


def hu_windowed_8bit(load: Callable[[], tuple], window_hu: tuple[float, float]) -> Callable[[], tuple]:
    """``load`` (a CT whose storage map gives HU) exported to 8 bits through a viewer's window, ``(low, high)`` HU
    linear to 0..255 and clipped outside, as :func:`contrast_ct_8bit` is. Labels and names unchanged; the storage
    map is the window's (presets are mapped onto the stored values)."""

    def exported() -> tuple:
        values, ijk_to_ras, labels, names, (scale, offset) = load()
        hu = (np.asarray(values, dtype=np.float64) - offset) / scale
        low, per_hu = window_hu[0], 255.0 / (window_hu[1] - window_hu[0])
        stored = np.round(np.clip((hu - low) * per_hu, 0.0, 255.0)).astype(np.uint8)
        return stored, ijk_to_ras, labels, names, (per_hu, -low * per_hu)

    return exported


def rescaled_uint16(load: Callable[[], tuple], top: int) -> Callable[[], tuple]:
    """``load`` with its values mapped linearly onto the integers ``0..top`` as uint16: how an MRI is often stored (a
    few hundred values; with ``top`` 300, more values than 256 bins, and fewer than two per bin, so bins hold one or
    two). Labels and names unchanged; no HU map."""

    def stored(values: np.ndarray) -> np.ndarray:
        low, high = float(values.min()), float(values.max())
        return np.round((values - low) * (top / (high - low))).astype(np.uint16)

    return _restored(load, stored)


def slope_scaled(load: Callable[[], tuple], slope: float, intercept: float) -> Callable[[], tuple]:
    """``load`` with its values times ``slope`` plus ``intercept``, as float32: how Slicer holds an integer volume
    stored with a NIfTI ``scl_slope`` or a DICOM rescale slope (the integers' lattice, scaled). Labels and names
    unchanged; no HU map."""

    return _restored(load, lambda values: (values * slope + intercept).astype(np.float32))


def _restored(load: Callable[[], tuple], store: Callable[[np.ndarray], np.ndarray]) -> Callable[[], tuple]:
    """``load`` with its values (as float64) stored again by ``store``; labels and names unchanged, no HU map."""

    def restored() -> tuple:
        values, ijk_to_ras, labels, names, _storage = load()
        return store(np.asarray(values, dtype=np.float64)), ijk_to_ras, labels, names, None

    return restored


# ---------------------------------------------------------------------------------------------------------------
# Branching tubes (vessel trees, plants): rasterized with partial volume
# ---------------------------------------------------------------------------------------------------------------

#: One tube segment: start and end (voxel coordinates k, j, i), radius at each end (voxels), class.
Segment = tuple[np.ndarray, np.ndarray, float, float, int]


def _thin_tube_factor(radius: np.ndarray) -> np.ndarray:
    """The factor that gives the soft-edged profile ``clip(r + 0.5 - d, 0, 1)`` of a tube of radius ``r`` (voxels)
    its true cross-section ``pi r^2``: the soft edge adds mass, a lot below a voxel of radius."""
    r = np.maximum(np.asarray(radius, dtype=np.float64), 1e-3)
    a, b = np.maximum(r - 0.5, 0.0), r + 0.5
    ring = np.where(r >= 0.5, b * (b**2 - a**2) / 2 - (b**3 - a**3) / 3, b**3 / 6)
    mass = np.pi * a**2 + 2 * np.pi * ring
    return np.minimum(1.0, np.pi * r**2 / mass)


def tube_occupancy(
    shape: tuple[int, int, int], segments: list[Segment], n_classes: int, split_radius: float | None = None
) -> np.ndarray:
    """``(n_classes, *shape)`` float32: the part of each voxel a class of tubes fills (0..1, tubes of one class
    merged by maximum), each tube with a one-voxel soft edge scaled to its true cross-section, so tubes thinner than
    a voxel exist only as partial volume.

    Args:
        split_radius: None: a segment's class is its own; else the class is 0 where the local radius (voxels) is at
            least ``split_radius`` and 1 below it (large and small vessels).
    """
    occupancy = np.zeros((n_classes, *shape), dtype=np.float32)
    upper = np.asarray(shape)
    for start, end, r0, r1, kind in segments:
        reach = max(r0, r1) + 1.5
        low = np.maximum(np.floor(np.minimum(start, end) - reach).astype(int), 0)
        high = np.minimum(np.ceil(np.maximum(start, end) + reach).astype(int) + 1, upper)
        if np.any(high <= low):
            continue
        k, j, i = np.ogrid[low[0] : high[0], low[1] : high[1], low[2] : high[2]]
        d = end - start
        dk, dj, di = k - start[0], j - start[1], i - start[2]
        t = np.clip((dk * d[0] + dj * d[1] + di * d[2]) / max(d @ d, 1e-12), 0.0, 1.0)
        distance = np.sqrt((dk - t * d[0]) ** 2 + (dj - t * d[1]) ** 2 + (di - t * d[2]) ** 2)
        radius = r0 + t * (r1 - r0)
        fill = (np.clip(radius + 0.5 - distance, 0.0, 1.0) * _thin_tube_factor(radius)).astype(np.float32)
        if split_radius is None:
            parts = ((kind, fill),)
        else:
            parts = ((0, np.where(radius >= split_radius, fill, 0)), (1, np.where(radius < split_radius, fill, 0)))
        box = (slice(low[0], high[0]), slice(low[1], high[1]), slice(low[2], high[2]))
        for c, part in parts:
            np.maximum(occupancy[(c, *box)], part, out=occupancy[(c, *box)])
    return occupancy


def _turned(direction: np.ndarray, angle: float, azimuth: float) -> np.ndarray:
    """``direction`` turned by ``angle`` (radians) towards the perpendicular at ``azimuth``."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(direction[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(direction, helper)
    u /= np.linalg.norm(u)
    v = np.cross(direction, u)
    turned = np.cos(angle) * direction + np.sin(angle) * (np.cos(azimuth) * u + np.sin(azimuth) * v)
    return turned / np.linalg.norm(turned)


def branching_tree(
    rng: np.random.Generator,
    root: Sequence[float],
    direction: Sequence[float],
    radius: float,
    min_radius: float,
    length_of: Callable[[float], float],
    bounds: tuple[np.ndarray, np.ndarray],
    kind: int = 0,
    pull: Sequence[float] = (0.0, 0.0, 0.0),
    max_segments: int = 2000,
) -> list[Segment]:
    """Segments of a binary tree (voxel coordinates k, j, i; radii in voxels): each segment tapers by 8% and splits
    into a major child (radius x 0.72-0.86, turned 12-30 degrees) and a minor one (x 0.55-0.72, turned 35-65 degrees
    the other way), down to ``min_radius``; ``length_of(radius)`` sets each length, ``pull`` bends the children (a
    plant's light), ``bounds`` (low, high corners) clip the ends. Deterministic for a seeded ``rng``."""
    segments: list[Segment] = []
    pull = np.asarray(pull, dtype=np.float64)
    stack = [(np.asarray(root, dtype=np.float64), np.asarray(direction, dtype=np.float64), float(radius))]
    while stack and len(segments) < max_segments:
        start, heading, r = stack.pop()
        heading = (heading + pull) / np.linalg.norm(heading + pull)
        length = length_of(r)
        end = np.clip(start + heading * length, *bounds)
        if np.linalg.norm(end - start) < 0.3 * length:
            continue
        r_end = 0.92 * r
        segments.append((start, end, r, r_end, kind))
        azimuth = rng.uniform(0.0, 2 * np.pi)
        children = (
            (r_end * rng.uniform(0.72, 0.86), np.radians(rng.uniform(12.0, 30.0)), azimuth),
            (r_end * rng.uniform(0.55, 0.72), np.radians(rng.uniform(35.0, 65.0)), azimuth + np.pi),
        )
        for child_radius, angle, child_azimuth in children:
            if child_radius >= min_radius:
                stack.append((end, _turned(heading, angle, child_azimuth), child_radius))
    return segments


def _centred_grid(shape: tuple[int, int, int], step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Voxel-centre coordinates z, y, x in mm (open grids), the volume centred on 0."""
    k, j, i = np.ogrid[: shape[0], : shape[1], : shape[2]]
    return ((k + 0.5) * step - shape[0] * step / 2, (j + 0.5) * step - shape[1] * step / 2,
            (i + 0.5) * step - shape[2] * step / 2)  # fmt: skip


def _to_voxels(point_mm: Sequence[float], shape: tuple[int, int, int], step: float) -> np.ndarray:
    """A point ``(x, y, z)`` in mm of :func:`_centred_grid`'s frame as voxel coordinates ``(k, j, i)``."""
    x, y, z = point_mm
    return np.array([z, y, x]) / step + np.asarray(shape) / 2 - 0.5


def _heading_kji(heading: Sequence[float]) -> np.ndarray:
    """A direction ``(x, y, z)`` as a unit vector in voxel order ``(k, j, i)`` (the voxels are cubic)."""
    x, y, z = heading
    return np.array([z, y, x]) / np.linalg.norm((x, y, z))


def _box(shape: tuple[int, int, int], margin: float) -> tuple[np.ndarray, np.ndarray]:
    return np.full(3, margin), np.asarray(shape, dtype=np.float64) - 1 - margin


# ---------------------------------------------------------------------------------------------------------------
# Synthetic volumes of the kinds users bring (issue 16's second round)
# ---------------------------------------------------------------------------------------------------------------

#: synthetic_angiogram's names, in label order.
ANGIO_LABELS = ("background", "large vessels", "small vessels")
#: synthetic_angiogram: vessels of at least this radius (voxels) are "large vessels".
LARGE_VESSEL_VOXELS = 2.0


def synthetic_angiogram(size: int = 128, seed: int = 0) -> tuple:
    """A CT-DSA / TOF-MRA-like angiogram that holds only the vessels, uint16, with ground truth.

    A 64 mm field of view (0.5 mm voxels at ``size`` 128): three vessel trees rising from the bottom (two of 2 mm
    radius, one of 1.5 mm) branch down to 0.35 mm radius (4 to 0.7 voxels at 128; the small ones exist only as
    partial volume). Static tissue 120, blood 1000 (arbitrary units), blurred 0.8 voxel, noise 25, then every value
    below 250 set to 0 as MIP exports are: 95-99% zeros. Labels: "large vessels" (local radius at least 2 voxels),
    "small vessels" (below), where the value is kept and the blurred vessel fills part of the voxel (the larger
    class wins), "background" elsewhere.
    """
    step = 64.0 / size
    shape = (size, size, size)
    rng = np.random.default_rng(seed)
    bounds = _box(shape, 3.0 / step)
    segments: list[Segment] = []
    roots = (
        ((-12.0, 4.0, -29.0), (0.3, 0.2, 1.0), 2.0),
        ((12.0, 4.0, -29.0), (-0.3, 0.2, 1.0), 2.0),
        ((0.0, -12.0, -29.0), (0.0, 0.3, 1.0), 1.6),
        ((-20.0, -18.0, -29.0), (0.4, 0.5, 1.0), 1.4),
        ((20.0, -18.0, -29.0), (-0.4, 0.5, 1.0), 1.4),
    )
    for root, heading, radius in roots:
        segments += branching_tree(
            rng,
            _to_voxels(root, shape, step),
            _heading_kji(heading),
            radius / step,
            0.35 / step,
            lambda r: (6.0 * r * step + 4.0) / step,
            bounds,
        )
    occupancy = tube_occupancy(shape, segments, 2, split_radius=LARGE_VESSEL_VOXELS)
    blur = (0.8, 0.8, 0.8)
    signal = gaussian_blur(120.0 + 880.0 * occupancy.max(axis=0), blur)
    signal += rng.normal(0.0, 25.0, shape)
    signal[signal < 250.0] = 0.0
    stored = np.round(signal).clip(0, 65535).astype(np.uint16)
    blurred = np.stack([gaussian_blur(o, blur) for o in occupancy])
    labels = np.where((stored > 0) & (blurred.max(axis=0) > 0.02), 1 + np.argmax(blurred, axis=0), 0).astype(np.uint8)
    return stored, _grid((step, step, step)), labels, ANGIO_LABELS, None


#: synthetic_specimen's names, in label order.
SPECIMEN_LABELS = ("air", "holder", "soft tissue", "bone")
SPECIMEN_SPACING_MM = 0.05


def synthetic_specimen(size: int = 216, seed: int = 0) -> tuple:
    """A micro-CT of a bone specimen at 0.05 mm voxels, uint16 arbitrary units, with ground truth.

    ``size`` voxels across x (216: 10.8 mm), 0.69 of it along z, 0.8 along y; the geometry scales with ``size``, the
    voxels stay 0.05 mm. At 216 the specimen is 10 mm across: soft tissue (an ellipsoid 10 x 7.2 x 5.2 mm) around a
    bone (7.2 x 4.8 x 3.6 mm) with a cortical shell 0.25 mm thick and a trabecular interior (the zero band of a
    smooth random field: a sponge of struts about 0.1 mm thick, marrow between them), resting on a plastic holder
    plate. Air 1000, holder 3000, soft tissue and marrow 3800, bone 12000; blurred 1 voxel, noise 450 (the fog in the
    air). Labels from the sharp geometry, with partial volume attributed as in :func:`partial_volume`.
    """
    step = SPECIMEN_SPACING_MM
    g = size / 216.0
    shape = (max(int(round(size * 0.69)), 8), max(int(round(size * 0.8)), 8), size)
    z, y, x = _centred_grid(shape, step)
    rng = np.random.default_rng(seed)
    labels = np.zeros(shape, dtype=np.uint8)
    labels[(np.hypot(x, y) < 4.2 * g) & (np.abs(z + 3.05 * g) < 0.3 * g)] = 1
    zc = z - 0.35 * g
    labels[(x / (5.0 * g)) ** 2 + (y / (3.6 * g)) ** 2 + (zc / (2.6 * g)) ** 2 < 1.0] = 2
    semi = np.array([3.6, 2.4, 1.8]) * g
    outer = (x / semi[0]) ** 2 + (y / semi[1]) ** 2 + (zc / semi[2]) ** 2 < 1.0
    inner_semi = semi - 0.25 * g
    inner = (x / inner_semi[0]) ** 2 + (y / inner_semi[1]) ** 2 + (zc / inner_semi[2]) ** 2 < 1.0
    labels[outer & ~inner] = 3
    # Trabeculae: where a smooth random field (correlation 3 voxels) is near zero, inside the shell.
    field = gaussian_blur(rng.standard_normal(shape), (3.0, 3.0, 3.0))
    field /= field.std()
    labels[inner & (np.abs(field) < 0.4)] = 3
    values_of = np.array([1000.0, 3000.0, 3800.0, 12000.0])
    values = gaussian_blur(values_of[labels], (1.0, 1.0, 1.0))
    values += rng.normal(0.0, 450.0, shape)
    stored = np.clip(np.round(values), 0, 65535).astype(np.uint16)
    labels = partial_volume(stored, labels, values_of, 450.0, 1.0)
    return stored, _grid((step, step, step)), labels, SPECIMEN_LABELS, None


#: synthetic_housing's names, in label order.
HOUSING_LABELS = ("air", "housing", "parts")


def synthetic_housing(size: int = 128, seed: int = 0) -> tuple:
    """An industrial CT of steel parts inside a cast aluminium housing, float32 linear attenuation (1/cm), with
    ground truth.

    A 51.2 mm field of view (0.4 mm voxels at ``size`` 128): a closed aluminium cylinder (outer radius 21 mm, wall 6,
    end walls 4 mm) with casting pores (14 voids of 0.5-1 mm radius in its walls); inside, a steel shaft (radius 3 mm)
    through bores (radius 3.6 mm) in both end walls, a gear disc on it (radius 10 mm, 18 teeth to 11.8 mm, 4 mm
    thick), and four bolts (shank radius 1.5 mm screwed into the top wall, heads 2.8 mm) on top. Air 0, aluminium
    0.55, steel 2.8; blurred 0.7 voxel, noise 0.08. Labels "air" (outside and in the cavities), "housing" (the
    aluminium), "parts" (the steel), partial volume attributed as in :func:`partial_volume`.
    """
    step = 51.2 / size
    shape = (size, size, size)
    z, y, x = _centred_grid(shape, step)
    rng = np.random.default_rng(seed)
    r = np.hypot(x, y)
    theta = np.arctan2(y, x)
    labels = np.zeros(shape, dtype=np.uint8)
    housing = (r < 21.0) & (np.abs(z) < 16.0) & ~((r < 15.0) & (np.abs(z) < 12.0)) & ~(r < 3.6)
    for _ in range(14):  # casting pores in the side wall and the end walls
        if rng.uniform() < 0.6:
            angle, radius_at, height = rng.uniform(0, 2 * np.pi), rng.uniform(16.0, 20.0), rng.uniform(-14.0, 14.0)
        else:
            angle, radius_at, height = rng.uniform(0, 2 * np.pi), rng.uniform(5.0, 19.0), rng.choice([-1, 1]) * 14.0
        cx, cy = radius_at * np.cos(angle), radius_at * np.sin(angle)
        housing &= (x - cx) ** 2 + (y - cy) ** 2 + (z - height) ** 2 >= rng.uniform(0.5, 1.0) ** 2
    labels[housing] = 1
    parts = (r < 3.0) & (np.abs(z) < 22.0)
    teeth = (r < 11.8) & (np.cos(18 * theta) > 0)
    parts |= ((r < 10.0) | teeth) & (np.abs(z) < 2.0)
    for k in range(4):
        bx, by = 18.0 * np.cos(np.pi / 4 + k * np.pi / 2), 18.0 * np.sin(np.pi / 4 + k * np.pi / 2)
        rb = np.hypot(x - bx, y - by)
        parts |= ((rb < 1.5) & (z > 6.0) & (z < 16.0)) | ((rb < 2.8) & (z >= 16.0) & (z < 18.5))
    labels[parts] = 2
    values_of = np.array([0.0, 0.55, 2.8])
    values = gaussian_blur(values_of[labels], (0.7, 0.7, 0.7))
    values += rng.normal(0.0, 0.08, shape)
    stored = values.astype(np.float32)
    labels = partial_volume(stored, labels, values_of, 0.08, 0.7)
    return stored, _grid((step, step, step)), labels, HOUSING_LABELS, None


#: synthetic_plant's names, in label order.
PLANT_LABELS = ("air", "trunk", "branches", "pot", "soil")
PLANT_HU = (-1000.0, -350.0, -350.0, 1100.0, 300.0)


def synthetic_plant(size: int = 128, seed: int = 0) -> tuple:
    """A plant on CT (a bonsai-like tree in a pot), an 8-bit export (``CTA_MAP``'s window), with ground truth.

    A 240 mm field of view (1.875 mm voxels at ``size`` 128): a ceramic bowl (1100 HU, walls 6 mm) filled with soil
    (300 HU with a texture of 80 HU), a trunk (wood, -350 HU) rising from inside the soil, radius 10 to 6 mm, and
    branch trees from it, radius 3.5 mm down to 0.45 mm (0.24 voxel: twigs that exist only as partial volume, barely
    above the noise). Blurred 1 mm, noise 25 HU, windowed -1024..2000 HU to 0..255. Labels: the sharp geometry with
    partial volume attributed (:func:`partial_volume`); an air voxel where the blurred branches (or trunk) raise the
    value by at least two noise sigma is "branches" (or "trunk").
    """
    step = 240.0 / size
    shape = (size, size, size)
    z, y, x = _centred_grid(shape, step)
    rng = np.random.default_rng(seed)
    r = np.hypot(x, y)
    labels = np.zeros(shape, dtype=np.uint8)
    bowl_radius = 78.0 + 0.35 * (z + 105.0)
    in_bowl = (r < bowl_radius) & (z > -105.0) & (z < -62.0)
    labels[in_bowl & ~((r < bowl_radius - 6.0) & (z > -99.0))] = 3
    labels[(r < bowl_radius - 6.0) & (z > -99.0) & (z < -72.0)] = 4
    trunk_points = ((0.0, 0.0, -95.0, 10.0), (5.0, 0.0, -72.0, 9.5), (16.0, 6.0, -40.0, 8.0), (6.0, -6.0, -10.0, 6.5),
                    (-4.0, -2.0, 12.0, 5.5))  # fmt: skip
    segments: list[Segment] = []
    for (*a, ra), (*b, rb) in zip(trunk_points[:-1], trunk_points[1:]):
        segments.append((_to_voxels(a, shape, step), _to_voxels(b, shape, step), ra / step, rb / step, 0))
    bounds = _box(shape, 4.0 / step)
    limbs = (  # where on the trunk, heading (x, y, z), radius in mm
        (2, (1.0, 0.3, 0.35), 3.5),
        (3, (-1.0, -0.4, 0.4), 3.5),
        (4, (0.2, 0.9, 0.6), 3.2),
        (4, (-0.5, -0.6, 0.8), 3.0),
        (3, (0.3, -1.0, 0.2), 2.5),
    )
    for at, heading, radius in limbs:
        segments += branching_tree(
            rng,
            _to_voxels(trunk_points[at][:3], shape, step),
            _heading_kji(heading),
            radius / step,
            0.45 / step,
            lambda rad: (6.0 * rad * step + 12.0) / step,
            bounds,
            kind=1,
            pull=(0.12, 0.0, 0.0),
        )
    occupancy = tube_occupancy(shape, segments, 2)
    wood = occupancy.max(axis=0)
    labels[(occupancy[0] >= 0.5) & (labels != 3)] = 1
    labels[(occupancy[1] >= 0.5) & (labels == 0)] = 2
    hu_of = np.asarray(PLANT_HU)
    hu = hu_of[labels]
    # The wood's partial volume in air (its sharp voxels already hold it); the soil's texture.
    thin = (labels == 0) & (wood > 0)
    hu[thin] += wood[thin] * (hu_of[1] - hu_of[0])
    soil = labels == 4
    texture = gaussian_blur(rng.standard_normal(shape), (1.5, 1.5, 1.5))
    hu[soil] += 80.0 * texture[soil] / texture.std()
    hu = gaussian_blur(hu, (1.0 / step,) * 3)
    hu += rng.normal(0.0, 25.0, shape)
    slope, offset = CTA_MAP
    stored = np.round(np.clip(slope * hu + offset, 0, 255)).astype(np.uint8)
    labels = partial_volume(stored, labels, slope * hu_of + offset, 25.0 * slope, 1.0 / step)
    raised = np.stack([gaussian_blur(o, (1.0 / step,) * 3) for o in occupancy]) * (hu_of[1] - hu_of[0])
    shows = (labels == 0) & (raised.max(axis=0) >= 2.0 * 25.0)
    labels[shows] = 1 + np.argmax(raised, axis=0)[shows]
    return stored, _grid((step, step, step)), labels, PLANT_LABELS, CTA_MAP


#: contrast_ct_8bit's names, in label order.
CHEST_LABELS = ("air", "fat", "soft tissue", "lungs", "blood pool", "bone")
#: contrast_ct_8bit's window, level 300 and width 1400 HU: stored = (HU + 400) * 255 / 1400, clipped to 0..255.
CHEST_WINDOW_HU = (-400.0, 1000.0)
CHEST_MAP = (255.0 / 1400.0, 400.0 * 255.0 / 1400.0)


def contrast_ct_8bit(size: int = 128, seed: int = 0) -> tuple:
    """An 8-bit export of a contrast chest CT (a viewer's window, level 300, width 1400 HU, linear to 0..255: the
    lungs and the air clip to 0, cortical bone to 255), with ground truth.

    A 340 x 340 x 255 mm field of view (2.66 mm voxels at ``size`` 128, ``size`` x ``size`` x 0.75 ``size``): the body
    (an elliptic cylinder, a 12 mm fat layer -100 HU over soft tissue 45 HU), two lungs (-850 HU) with contrast-filled
    pulmonary vessel trees (radius 6 mm down to 1.6 mm), the heart (myocardium 45 HU) around a blood pool, the
    ascending aorta, its arch and the descending aorta (blood 400 HU); the spine (vertebral bodies with a 2.5 mm
    cortex of 1200 HU around cancellous bone of 280 HU, discs, posterior arches), ribs and a sternum (1200 HU). Blurred
    1.2 mm, noise 15 HU. Labels from the sharp geometry with partial volume attributed (:func:`partial_volume`);
    cortical and cancellous bone are both "bone".
    """
    step = 340.0 / size
    shape = (max(int(round(size * 0.75)), 8), size, size)
    z, y, x = _centred_grid(shape, step)
    rng = np.random.default_rng(seed)
    air, fat, soft, lungs, blood, cortical, cancellous = range(7)
    hu_of = np.array([-1000.0, -100.0, 45.0, -850.0, 400.0, 1200.0, 280.0])
    labels = np.zeros(shape, dtype=np.uint8)
    labels[np.broadcast_to((x / 160.0) ** 2 + (y / 115.0) ** 2 < 1.0, shape)] = fat
    labels[np.broadcast_to((x / 148.0) ** 2 + (y / 103.0) ** 2 < 1.0, shape)] = soft
    for side in (-1.0, 1.0):
        labels[((x - side * 72.0) / 58.0) ** 2 + ((y + 5.0) / 72.0) ** 2 + ((z - 15.0) / 105.0) ** 2 < 1.0] = lungs
    heart = ((x - 20.0) / 62.0) ** 2 + ((y - 30.0) / 50.0) ** 2 + ((z + 55.0) / 55.0) ** 2
    labels[heart < 1.0] = soft
    labels[((x - 20.0) / 52.0) ** 2 + ((y - 30.0) / 40.0) ** 2 + ((z + 55.0) / 45.0) ** 2 < 1.0] = blood
    # The spine: vertebral bodies (cortex around cancellous bone), discs every 26 mm, posterior arches.
    spine_r = np.hypot(x, y + 70.0)
    disc = np.broadcast_to(np.mod(z, 26.0) < 5.0, shape)
    body = np.broadcast_to(spine_r < 20.0, shape)
    labels[body] = cortical
    labels[np.broadcast_to(spine_r < 17.5, shape) & ~disc] = cancellous
    labels[body & disc] = soft
    canal_r = np.hypot(x, y + 102.0)
    arch = ((canal_r >= 9.0) & (canal_r < 15.0) & (y < -95.0)) | ((np.abs(x) < 4.0) & (y < -113.0) & (y > -135.0))
    labels[np.broadcast_to(arch, shape) & ~disc] = cortical
    # Ribs: tubes along an inner ellipse, descending anteriorly, from the spine round to the cartilage.
    ring = np.sqrt((x / 136.0) ** 2 + (y / 92.0) ** 2)
    for level in np.arange(-110.0, 111.0, 25.0):
        dz = z - (level - 0.25 * (y + 70.0))
        rib = ((ring - 1.0) * 100.0) ** 2 + dz**2 < 5.5**2
        labels[rib & np.broadcast_to((y < 50.0) & (y > -85.0), shape)] = cortical
    labels[np.broadcast_to((np.abs(x) < 18.0) & (y > 88.0) & (y < 100.0), shape) & (np.abs(z) < 90.0)] = cortical
    # The aorta and the pulmonary vessel trees (contrast), with partial volume.
    aorta = ((5.0, 35.0, -40.0, 15.0), (5.0, 25.0, 70.0, 15.0), (15.0, -10.0, 92.0, 13.0), (25.0, -45.0, 75.0, 12.0),
             (25.0, -48.0, -shape[0] * step / 2 - 5.0, 12.0))  # fmt: skip
    segments: list[Segment] = [
        (_to_voxels(a, shape, step), _to_voxels(b, shape, step), ra / step, rb / step, 0)
        for (*a, ra), (*b, rb) in zip(aorta[:-1], aorta[1:])
    ]
    bounds = _box(shape, 2.0)
    for root, heading in (((-40.0, 15.0, 20.0), (-1.0, 0.1, 0.5)), ((-40.0, 15.0, 10.0), (-1.0, -0.2, -0.6)),
                          ((45.0, 15.0, 20.0), (1.0, 0.1, 0.5)), ((45.0, 15.0, 10.0), (1.0, -0.2, -0.6))):  # fmt: skip
        segments += branching_tree(
            rng,
            _to_voxels(root, shape, step),
            _heading_kji(heading),
            6.0 / step,
            1.6 / step,
            lambda r: (4.0 * r * step + 10.0) / step,
            bounds,
        )
    vessels = tube_occupancy(shape, segments, 1)[0]
    inside_vessel = (vessels >= 0.5) & (labels != air) & (labels != fat)
    labels[inside_vessel & (labels != cortical) & (labels != cancellous)] = blood
    hu = hu_of[labels]
    thin = (vessels > 0) & (vessels < 0.5) & (labels == lungs)
    hu[thin] += vessels[thin] * (hu_of[blood] - hu_of[lungs])
    blur = (1.2 / step,) * 3
    hu = gaussian_blur(hu, blur)
    hu += rng.normal(0.0, 15.0, shape)
    slope, offset = CHEST_MAP
    low, high = CHEST_WINDOW_HU
    stored = np.round(slope * np.clip(hu, low, high) + offset).astype(np.uint8)
    means = slope * np.clip(hu_of, low, high) + offset
    labels = partial_volume(stored, labels, means, 15.0 * slope, blur[0])
    raised = gaussian_blur(vessels, blur) * (hu_of[blood] - hu_of[lungs])
    labels[(labels == lungs) & (raised >= 3.0 * 15.0) & (stored > 0)] = blood
    labels[labels == cancellous] = 5
    return stored, _grid((step, step, step)), labels, CHEST_LABELS, CHEST_MAP


#: The materials of :func:`abdomen_materials`, in label order.
ABDOMEN_MATERIALS = ("air", "fat", "muscle", "liver", "spleen", "kidney", "bowel", "bowel gas", "aorta",
                     "cortical bone", "cancellous bone", "disc", "table")  # fmt: skip
#: synthetic_abdomen_ct's HU per material, and its labels: each material's label.
ABDOMEN_HU = (-1000.0, -100.0, 50.0, 60.0, 50.0, 35.0, 20.0, -1000.0, 40.0, 800.0, 200.0, 80.0, 150.0)
ABDOMEN_CT_LABELS = ("air", "fat", "soft tissue", "bone", "table")
_ABDOMEN_CT_LABEL = (0, 1, 2, 2, 2, 2, 2, 0, 2, 3, 3, 2, 4)
#: synthetic_abdomen_mri's T1 signal per material (fat and marrow bright, flowing blood and cortical bone dark; the
#: table gives no signal), and its labels.
ABDOMEN_T1 = (0.0, 900.0, 300.0, 520.0, 380.0, 430.0, 350.0, 0.0, 120.0, 40.0, 600.0, 250.0, 0.0)
ABDOMEN_MRI_LABELS = ("air", "fat", "organs", "muscle and bowel", "bone")
_ABDOMEN_MRI_LABEL = (0, 1, 3, 2, 2, 2, 3, 0, 3, 4, 4, 3, 0)


def abdomen_materials(
    shape: tuple[int, int, int], pixel_mm: float, z_range: tuple[float, float], seed: int = 0
) -> np.ndarray:
    """``(nz, ny, nx)`` uint8 indices into :data:`ABDOMEN_MATERIALS` of a synthetic abdomen and pelvis lying on a CT
    table, sampled at voxel centres: square pixels of ``pixel_mm``, the slices spread evenly over ``z_range``, the
    (bottom, top) of the volume in mm, from the femoral heads (-150) to the liver's dome (+150).

    The body is an elliptic cylinder 340 x 250 mm (20 mm of subcutaneous fat, an 8 mm muscle wall, visceral fat
    inside); the liver, spleen and kidneys are ellipsoids; about 25 bowel loops (ellipsoids of 12-22 mm, 40 % with
    gas inside) fill the lower abdomen; the psoas muscles and the aorta run beside the lumbar spine (vertebral bodies
    with a 2.5 mm cortex around cancellous bone, discs every 32 mm, posterior arches); below it the sacrum, the
    iliac wings (curved plates 8 mm thick: two cortices around cancellous bone) and the femoral heads; the table is
    an 8 mm plate.
    """
    nz, ny, nx = shape
    x = ((np.arange(nx) + 0.5 - nx / 2) * pixel_mm)[None, None, :]
    y = ((np.arange(ny) + 0.5 - ny / 2) * pixel_mm)[None, :, None]
    z = (z_range[0] + (np.arange(nz) + 0.5) * (z_range[1] - z_range[0]) / nz)[:, None, None]
    rng = np.random.default_rng(seed)
    m = {name: index for index, name in enumerate(ABDOMEN_MATERIALS)}
    out = np.zeros(shape, dtype=np.uint8)

    def ellipsoid(cx, cy, cz, rx, ry, rz):
        return ((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2 + ((z - cz) / rz) ** 2

    def plane(mask):  # a mask of (y, x) extruded along z
        return np.broadcast_to(mask, shape)

    out[plane((x / 170.0) ** 2 + (y / 125.0) ** 2 < 1.0)] = m["fat"]
    out[plane((x / 150.0) ** 2 + (y / 105.0) ** 2 < 1.0)] = m["muscle"]
    out[plane((x / 142.0) ** 2 + (y / 97.0) ** 2 < 1.0)] = m["fat"]
    out[plane((np.abs(x) < 190.0) & (y > -143.0) & (y < -135.0))] = m["table"]
    for side in (-1.0, 1.0):
        out[plane(((x - side * 45.0) / 20.0) ** 2 + ((y + 58.0) / 20.0) ** 2 < 1.0)] = m["muscle"]
    out[ellipsoid(-60.0, 10.0, 95.0, 75.0, 70.0, 60.0) < 1.0] = m["liver"]
    out[ellipsoid(85.0, -20.0, 95.0, 35.0, 45.0, 40.0) < 1.0] = m["spleen"]
    for side in (-1.0, 1.0):
        out[ellipsoid(side * 65.0, -45.0, 40.0, 28.0, 22.0, 50.0) < 1.0] = m["kidney"]
    abdomen = plane((x / 142.0) ** 2 + (y / 97.0) ** 2 < 1.0)  # inside the muscle wall
    for _ in range(25):
        cx, cy, cz = rng.uniform(-110.0, 110.0), rng.uniform(-30.0, 75.0), rng.uniform(-90.0, 40.0)
        radius = rng.uniform(12.0, 22.0)
        loop = ellipsoid(cx, cy, cz, radius, radius * rng.uniform(0.7, 1.0), radius * rng.uniform(1.0, 1.8))
        out[(loop < 1.0) & (out == m["fat"]) & abdomen] = m["bowel"]
        if rng.uniform() < 0.4:
            out[(loop < 0.36) & (out == m["bowel"])] = m["bowel gas"]
    out[(np.hypot(x - 15.0, y + 35.0) < 11.0) & (z > -40.0)] = m["aorta"]
    # The lumbar spine: vertebral bodies with discs, posterior arches; the sacrum, iliac wings and femoral heads.
    body = plane(np.hypot(x, y + 72.0) < 22.0) & (z > -60.0)
    disc = np.broadcast_to(np.mod(z, 32.0) < 5.0, shape)
    out[body] = m["cortical bone"]
    out[plane(np.hypot(x, y + 72.0) < 19.5) & (z > -60.0) & ~disc] = m["cancellous bone"]
    out[body & disc] = m["disc"]
    canal = np.hypot(x, y + 104.0)
    arch = ((canal >= 9.0) & (canal < 15.0) & (y < -96.0)) | ((np.abs(x) < 4.0) & (y < -115.0) & (y > -128.0))
    out[plane(arch) & (z > -60.0) & ~disc] = m["cortical bone"]
    for cx, cy, cz, rx, ry, rz in (
        (0.0, -85.0, -90.0, 45.0, 20.0, 45.0),  # the sacrum
        (-90.0, -10.0, -128.0, 24.0, 24.0, 24.0),  # the femoral heads
        (90.0, -10.0, -128.0, 24.0, 24.0, 24.0),
    ):
        distance = np.sqrt(ellipsoid(cx, cy, cz, rx, ry, rz))
        out[distance < 1.0] = m["cortical bone"]
        out[distance < 1.0 - 3.0 / min(rx, ry, rz)] = m["cancellous bone"]
    for side in (-1.0, 1.0):  # the iliac wings: plates 8 mm thick (two 2.5 mm cortices around cancellous bone)
        rx, ry, rz = 70.0, 60.0, 60.0
        depth = (1.0 - np.sqrt(ellipsoid(side * 25.0, 20.0, -60.0, rx, ry, rz))) * ry  # mm inside the surface
        wing = np.broadcast_to((side * x > 40.0) & (y < 10.0), shape) & (z > -115.0) & (z < -25.0)
        out[wing & (depth >= 0.0) & (depth < 8.0)] = m["cortical bone"]
        out[wing & (depth >= 2.5) & (depth < 5.5)] = m["cancellous bone"]
    return out


def synthetic_abdomen_ct(size: int = 160, seed: int = 0) -> tuple:
    """An abdomen-pelvis CT stored as int32 HU in 3 mm slices, on its table (:func:`abdomen_materials`), with ground
    truth: a 400 mm field of view (2.5 mm pixels at ``size`` 160), 300 mm from the femoral heads to the liver's dome
    (3 mm slices at ``size`` 160). Blurred 1.2 mm, noise 20 HU. Labels "air" (bowel gas included), "fat", "soft
    tissue", "bone" (cortical and cancellous), "table", partial volume attributed (:func:`partial_volume`)."""
    nz = max(int(round(size * 0.625)), 8)
    spacing = (400.0 / size, 400.0 / size, 300.0 / nz)
    materials = abdomen_materials((nz, size, size), spacing[0], (-150.0, 150.0), seed)
    hu_of = np.asarray(ABDOMEN_HU)
    blur = (1.2 / spacing[2], 1.2 / spacing[1], 1.2 / spacing[0])
    hu = gaussian_blur(hu_of[materials], blur)
    hu += np.random.default_rng(seed).normal(0.0, 20.0, hu.shape)
    stored = np.round(hu).astype(np.int32)
    label_of = np.asarray(_ABDOMEN_CT_LABEL, dtype=np.uint8)
    means = np.array([-1000.0, -100.0, 50.0, 800.0, 150.0])  # per label: cortical bone's HU for the bone
    labels = partial_volume(stored, label_of[materials], means, 20.0, max(blur))
    return stored, _grid(spacing), labels, ABDOMEN_CT_LABELS, (1.0, 0.0)


def synthetic_abdomen_mri(size: int = 160, seed: int = 0) -> tuple:
    """A T1-weighted abdominal MRI slab, uint16, with ground truth: the anatomy of :func:`abdomen_materials` from the
    kidneys' lower poles to the liver (24 slices of 6 mm at ``size`` 160, 2.25 mm pixels), fat and marrow bright,
    the liver above the spleen and kidneys above muscle, flowing blood and cortical bone dark. The receive coils'
    shading (a smooth gain of 0.7-1.3 across the body), blur 1.5 mm, Rician noise of 12 (the magnitude of complex
    Gaussian noise: the air is a haze, not zero). Labels "air", "fat", "organs" (liver, spleen, kidneys), "muscle and
    bowel", "bone"."""
    nz = max(int(round(size * 0.15)), 6)
    spacing = (360.0 / size, 360.0 / size, 144.0 / nz)
    materials = abdomen_materials((nz, size, size), spacing[0], (10.0, 154.0), seed)
    rng = np.random.default_rng(seed)
    signal = np.asarray(ABDOMEN_T1)[materials]
    x = np.linspace(-1.0, 1.0, size)
    shading = 0.85 + 0.3 * np.outer(np.cos(np.pi * x * 0.8), np.cos(np.pi * x * 0.5))
    signal = gaussian_blur(signal * shading[None], (1.5 / spacing[2], 1.5 / spacing[1], 1.5 / spacing[0]))
    noisy = np.hypot(signal + rng.normal(0.0, 12.0, signal.shape), rng.normal(0.0, 12.0, signal.shape))
    stored = np.round(noisy).astype(np.uint16)
    label_of = np.asarray(_ABDOMEN_MRI_LABEL, dtype=np.uint8)
    means = np.array([0.0, 900.0, 450.0, 330.0, 600.0])
    labels = partial_volume(stored, label_of[materials], means, 12.0, 1.5 / spacing[0])
    return stored, _grid(spacing), labels, ABDOMEN_MRI_LABELS, None


def _phantom_storage(name: str, size: int = 128, spacing_scale: float = 1.0):
    """The phantom (seed 0) in one of :func:`storages`; ``spacing_scale``: the same voxels with the spacing scaled
    (the labels' partial volume is attributed at the phantom's own blur in voxels, so they do not change)."""

    def load():
        from isosimtf.phantom import TISSUE_HU, TISSUES, head_phantom

        phantom = head_phantom(size, seed=0)
        values, (slope, offset) = storages(phantom.values)[name]
        hu = np.asarray(TISSUE_HU)
        noise = 20.0 * slope
        if name == "clipped":  # the tissues below 0 HU are 0; the steps add up to half a step of error
            hu, noise = np.clip(hu, 0.0, None), noise + 0.5 / 3.0
        labels = partial_volume(values, phantom.labels, slope * hu + offset, noise, 1.0 / phantom.spacing[0])
        spacing = tuple(s * spacing_scale for s in phantom.spacing)
        return values, _grid(spacing), labels, TISSUES, (slope, offset)

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


# ---------------------------------------------------------------------------------------------------------------
# The real volumes of ../shared/data (never copied into the repository)
# ---------------------------------------------------------------------------------------------------------------

#: The shared panel of real volumes (``$ISOSIMTF_SHARED_DATA``, else ``../shared/data`` beside the repository).
SHARED_DATA = Path(os.environ.get("ISOSIMTF_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))

#: A band of values ``(name, low, high)``, both ends inclusive, in stored units after NIfTI scaling.
Band = tuple[str, float, float]


@dataclass(frozen=True)
class RealVolume:
    """One file of :data:`SHARED_DATA` and the reading of its README: ``bands`` label the voxels (the first band
    that holds a value wins; the rest is "other"), ``shown_for`` the band(s) a user scanned it for, ``fog`` the band
    that must give nothing, ``storage`` the map from HU where the values are HU, ``kept`` the preset and shift of
    the picture the README's reader kept (its "kept preset (shift)" column)."""

    key: str
    title: str
    kind: str
    bands: tuple[Band, ...]
    shown_for: tuple[str, ...]
    fog: str | None
    storage: tuple[float, float] | None
    source: str
    kept: Kept

    @property
    def path(self) -> Path:
        return SHARED_DATA / f"{self.key}.nii.gz"


INF = float("inf")

#: The ten real volumes and the bands a user scanned each for (the README's "band scanned for" column).
REAL_VOLUMES: tuple[RealVolume, ...] = (
    RealVolume("ct-head-8bit-oblique", "Head CT, 8-bit export, oblique (real)", "CT",
               (("air", 0, 0), ("skull", 170, INF)), ("skull",), "air", None,
               "niivue-images CT_pitch.nii.gz, courtesy of Paul Morgan (BSD-2)", ("CT-AAA", 15)),
    RealVolume("cta-chest", "CT angiography of the chest, HU (real)", "CT",
               (("air and lungs", -INF, -500), ("contrast and bone", 250, INF)), ("contrast and bone",),
               "air and lungs", (1.0, 0.0), "TotalSegmentator test data ct_cropped.nii.gz (Apache-2.0)",
               ("CT-AAA", 100)),
    RealVolume("mr-brain-contrast", "Skull-stripped contrast T1 brain MRI (real)", "MRI",
               (("background", 0, 0), ("enhancing vessels", 650, INF), ("parenchyma", 350, 650)),
               ("parenchyma", "enhancing vessels"), "background", None, "niivue-images MR_Gd.nii.gz (figshare)",
               ("CT-Chest-Contrast-Enhanced", 100)),
    RealVolume("mr-head-t1", "T1 MRI of a whole head (real)", "MRI",
               (("noise", 0, 20), ("head tissue", 40, INF)), ("head tissue",), "noise", None,
               "niivue-images chris_t1.nii.gz (CC BY-NC 4.0)", ("MR-Default", 0)),
    RealVolume("mr-head-pd-thick", "PD MRI of a head, thick slices (real)", "MRI",
               (("head tissue", 40, INF),), ("head tissue",), None, None,
               "niivue-images chris_PD.nii.gz (CC BY-NC 4.0)", ("MR-Default", 0)),
    RealVolume("mr-head-electrodes", "Head MRI with subdural electrodes (real)", "MRI",
               (("haze", 0, 50), ("head tissue", 100, INF)), ("head tissue",), "haze", None,
               "VolumeRenderingData seg3D/MR.nii.gz (Seg3DData, MIT)", ("MR-Default", 50)),
    RealVolume("mr-brain-stroke-t1", "Brain T1 MRI after a stroke, 8-bit (real)", "MRI",
               (("cortex", 60, 140), ("CSF, cavity and background", 0, 60)), ("cortex",),
               "CSF, cavity and background", None, "VolumeRenderingData stroke/T1.nii.gz (C-STAR, MIT)",
               ("US-Fetal", 0)),
    RealVolume("mr-brain-stroke-flair", "Brain FLAIR MRI after a stroke, 8-bit (real)", "MRI",
               (("hyperintense", 165, INF),), ("hyperintense",), None, None,
               "VolumeRenderingData stroke/FLAIR.nii.gz (C-STAR, MIT)", ("MR-Angio", 15)),
    RealVolume("sim-heptane", "Heptane jet flame simulation (real)", "simulation",
               (("empty", 0, 0), ("core", 100, INF), ("envelope", 1, 100)), ("core", "envelope"), "empty", None,
               "VolumeRenderingData OpenSciVis/heptane.nii.gz", ("CT-Cardiac3", 100)),
    RealVolume("sim-fuel", "Fuel injection simulation, 64 x 33 x 32 (real)", "simulation",
               (("empty", 0, 0), ("plume", 40, INF)), ("plume",), "empty", None,
               "VolumeRenderingData OpenSciVis/fuel.nii.gz", ("CT-AAA", -100)),
)  # fmt: skip


def band_labels(values: np.ndarray, bands: Sequence[Band]) -> tuple[np.ndarray, tuple[str, ...]]:
    """Voxels labelled by value bands (first band that holds the value wins, both ends inclusive); label 0 is
    "other", the voxels of no band."""
    values = np.asarray(values)
    labels = np.zeros(values.shape, dtype=np.uint8)
    free = np.ones(values.shape, dtype=bool)
    for index, (_, low, high) in enumerate(bands, start=1):
        inside = free & (values >= low) & (values <= high)
        labels[inside] = index
        free &= ~inside
    return labels, ("other", *(name for name, _, _ in bands))


def real_load(
    volume: RealVolume, restore: Callable[[np.ndarray], tuple[np.ndarray, tuple[float, float]]] | None = None
) -> Callable[[], tuple]:
    """The loader of a real volume: its values (NIfTI ``scl_slope`` / ``scl_inter`` applied by the reader), its
    IJK-to-RAS matrix and the band labels (a reading of the README, not ground truth). ``restore``: stores a CT in HU
    another way, as ``(values, storage)`` (e.g. :func:`hu_clipped_quantized`); its bands are read on the HU."""

    def load():
        values, ijk_to_ras = _read(volume.path)
        values = np.asarray(values)
        labels, names = band_labels(values, volume.bands)
        values, storage = (values, volume.storage) if restore is None else restore(values)
        return values, ijk_to_ras, labels, names, storage

    return load


_CTA_CHEST = next(v for v in REAL_VOLUMES if v.key == "cta-chest")
_STROKE_T1 = next(v for v in REAL_VOLUMES if v.key == "mr-brain-stroke-t1")

PANEL: tuple[PanelVolume, ...] = (
    *(
        PanelVolume(f"head-ct-{s}", f"Head CT, {s}", "CT", ct_storage(s), ("dense",), None,
                    _file(HEAD_CT), "Debian invesalius-examples (Cranium.inv3), re-stored")
        for s in ("uint16", "8bit", "float", "clipped")  # in HU it is compare.py's head-ct
    ),
    PanelVolume("head-ct-clipped-8bit", "Head CT, clipped, then an 8-bit auto-contrast export", "CT",
                windowed_8bit(ct_storage("clipped"), 99.5, 0.5), ("dense",), None, _file(HEAD_CT),
                "Debian invesalius-examples (Cranium.inv3), clipped at 0 HU in 62.5-HU steps, then windowed"),
    *(
        PanelVolume(f"phantom-{s}", f"Phantom 128^3, {s}", "CT", _phantom_storage(s), ("skull",),
                    "air", _always, "isosimtf phantom, seed 0, re-stored")
        for s in ("uint16", "8bit", "float", "clipped")
    ),
    *(
        PanelVolume(f"phantom-x{scale:g}", f"Phantom 128^3, HU, spacing x {scale:g} ({1.875 * scale:g} mm)", "CT",
                    _phantom_storage("hu", spacing_scale=scale), ("skull",), "air", _always,
                    "isosimtf phantom, seed 0, the same voxels at another voxel size")
        for scale in VOXEL_SIZE_SCALES
    ),
    PanelVolume("phantom-64", "Phantom 64^3 (3.75 mm)", "CT", _phantom_storage("hu", 64), ("skull",),
                "air", _always, "isosimtf phantom, seed 0, 64 voxels"),
    PanelVolume("cta-8bit", "CT angiogram, 8-bit (synthetic)", "CT", synthetic_cta, ("skull", "artery"),
                "air", _always, "the phantom with arteries and a head holder, windowed to 8 bits"),
    PanelVolume("micro-ct", "Micro-CT specimen in a tube, uint16 (synthetic)", "micro-CT", synthetic_micro_ct,
                ("bone", "teeth"), "air", _always, "synthetic"),
    PanelVolume("micro-ct-8bit", "Micro-CT specimen in a tube, 8-bit export through a window (synthetic)", "micro-CT",
                windowed_8bit(synthetic_micro_ct), ("bone", "teeth"), "air", _always,
                "synthetic, exported to 8 bits from its lowest value to its 99.9th percentile"),
    PanelVolume("colin27-05mm", "Colin27 T1 at 0.5 mm (ch2better)", "MRI", _file_load(TEMPLATES / "ch2better.nii.gz"),
                (), None, _file(TEMPLATES / "ch2better.nii.gz"), "Debian mricron-data"),
    PanelVolume("colin27-coarse", "Colin27 T1 averaged to 2 x 2 x 3 mm", "MRI", _colin27_coarse, (), None,
                _file(TEMPLATES / "ch2.nii.gz"), "Debian mricron-data, block means"),
    PanelVolume("colin27-coarse-uint16", "Colin27 T1 averaged to 2 x 2 x 3 mm, uint16 0..300", "MRI",
                rescaled_uint16(_colin27_coarse, 300), (), None, _file(TEMPLATES / "ch2.nii.gz"),
                "Debian mricron-data, block means, stored as a few hundred integers"),
    PanelVolume("colin27-coarse-scaled", "Colin27 T1 averaged to 2 x 2 x 3 mm, uint16 0..300 with a slope, float32",
                "MRI", slope_scaled(rescaled_uint16(_colin27_coarse, 300), 0.37, 11.0), (), None,
                _file(TEMPLATES / "ch2.nii.gz"),
                "Debian mricron-data, block means, a few hundred integers read through scl_slope 0.37, scl_inter 11"),
    PanelVolume("mni152", "MNI152 T1 (nilearn)", "MRI", lambda: (*_read(_nilearn_t1()), None, None, None), (), None,
                lambda: _file(_nilearn_t1())(), "nilearn package data"),
    PanelVolume("inia19", "INIA19 macaque T1 brain", "MRI", _file_load(TEMPLATES / "inia19-t1-brain.nii.gz"),
                (), None, _file(TEMPLATES / "inia19-t1-brain.nii.gz"), "Debian mricron-data"),
    PanelVolume("angiogram", "Angiogram, vessels only, thresholded, uint16 (synthetic)", "angio", synthetic_angiogram,
                ("large vessels", "small vessels"), None, _always, "synthetic vessel trees, 0.5 mm"),
    PanelVolume("specimen-ct", "Micro-CT of a bone specimen, 0.05 mm, uint16 (synthetic)", "micro-CT",
                synthetic_specimen, ("bone",), "air", _always, "synthetic trabecular bone on a holder"),
    PanelVolume("specimen-ct-8bit", "Micro-CT of a bone specimen, 8-bit auto-contrast export (synthetic)", "micro-CT",
                windowed_8bit(synthetic_specimen, 99.5, 0.5), ("bone",), "air", _always,
                "synthetic, exported to 8 bits from its 0.5th to its 99.5th percentile"),
    PanelVolume("housing-ct", "Industrial CT, steel parts in an aluminium housing, float32 (synthetic)", "industrial",
                synthetic_housing, ("parts",), "air", _always, "synthetic, 0.4 mm"),
    PanelVolume("plant-ct", "Plant CT, a tree in a pot, 8-bit (synthetic)", "plant", synthetic_plant, ("branches",),
                "air", _always, "synthetic, 1.875 mm"),
    PanelVolume("chest-cta-8bit", "Contrast chest CT, 8-bit export (synthetic)", "CT", contrast_ct_8bit,
                ("blood pool", "bone"), "air", _always, "synthetic, window 300 / 1400 HU"),
    PanelVolume("abdomen-ct", "Abdomen-pelvis CT, int32 HU, 3 mm slices (synthetic)", "CT", synthetic_abdomen_ct,
                ("bone",), "air", _always, "synthetic, on its table"),
    PanelVolume("abdomen-ct-8bit", "Abdomen-pelvis CT, 8-bit export through a 300 / 1400 HU window (synthetic)", "CT",
                hu_windowed_8bit(synthetic_abdomen_ct, CHEST_WINDOW_HU), ("bone",), "air", _always,
                "synthetic, on its table, exported as the 8-bit chest CT (window level 300, width 1400 HU)"),
    PanelVolume("abdomen-mri", "Abdominal T1 MRI slab, 6 mm slices (synthetic)", "MRI", synthetic_abdomen_mri,
                ("organs",), "air", _always, "synthetic, coil shading and Rician noise"),
    *(
        PanelVolume(v.key, v.title, v.kind, real_load(v), v.shown_for, v.fog, _file(v.path),
                    f"../shared/data/{v.key}.nii.gz: {v.source}", v.kept)
        for v in REAL_VOLUMES
    ),
    PanelVolume("cta-chest-clipped", "CT angiography of the chest, HU clipped at 0 in 62.5-HU steps (real, re-stored)",
                "CT", real_load(_CTA_CHEST, hu_clipped_quantized), _CTA_CHEST.shown_for, _CTA_CHEST.fog,
                _file(_CTA_CHEST.path),
                f"../shared/data/cta-chest.nii.gz, re-stored as a stented aorta's CTA was: {_CTA_CHEST.source}",
                _CTA_CHEST.kept),
    PanelVolume("mr-brain-stroke-t1-uint16", "Brain T1 MRI after a stroke, uint16 0..300 (real, re-stored)", "MRI",
                rescaled_uint16(real_load(_STROKE_T1), 300), _STROKE_T1.shown_for, _STROKE_T1.fog,
                _file(_STROKE_T1.path), f"../shared/data/mr-brain-stroke-t1.nii.gz, re-stored: {_STROKE_T1.source}"),
    PanelVolume("mr-brain-stroke-t1-uint16-600", "Brain T1 MRI after a stroke, uint16 0..600 (real, re-stored)", "MRI",
                rescaled_uint16(real_load(_STROKE_T1), 600), _STROKE_T1.shown_for, _STROKE_T1.fog,
                _file(_STROKE_T1.path), f"../shared/data/mr-brain-stroke-t1.nii.gz, re-stored: {_STROKE_T1.source}"),
)  # fmt: skip

#: The HU originals of the re-stored volumes: compare.py has them as ``phantom`` and ``head-ct``; look_panel.py
#: needs them to compare the storages with.
REFERENCES: tuple[PanelVolume, ...] = (
    PanelVolume("phantom-hu", "Phantom 128^3, hu", "CT", _phantom_storage("hu"), ("skull",), "air", _always,
                "isosimtf phantom, seed 0"),
    PanelVolume("head-ct-hu", "Head CT, hu", "CT", ct_storage("hu"), ("dense",), None, _file(HEAD_CT),
                "Debian invesalius-examples (Cranium.inv3)"),
)  # fmt: skip

#: Groups of the same data in other storages or at another voxel size: a look that differs within a group depends
#: on how the data were stored, not on what they hold. The clipped storage, which loses everything below 0 HU, is a
#: group of its own with its HU original.
VARIANT_GROUPS: dict[str, tuple[str, ...]] = {
    "head CT storages": tuple(f"head-ct-{s}" for s in ("hu", "uint16", "8bit", "float")),
    "head CT clipped at 0 HU": ("head-ct-hu", "head-ct-clipped", "head-ct-clipped-8bit"),
    "phantom storages": tuple(f"phantom-{s}" for s in ("hu", "uint16", "8bit", "float")),
    "phantom clipped at 0 HU": ("phantom-hu", "phantom-clipped"),
    "chest CTA clipped at 0 HU": ("cta-chest", "cta-chest-clipped"),
    "phantom voxel size": ("phantom-hu", *(f"phantom-x{scale:g}" for scale in VOXEL_SIZE_SCALES)),
    "micro-CT storages": ("micro-ct", "micro-ct-8bit"),
    "specimen storages": ("specimen-ct", "specimen-ct-8bit"),
    "abdomen CT storages": ("abdomen-ct", "abdomen-ct-8bit"),
    "T1 head storages": ("colin27-coarse", "colin27-coarse-uint16", "colin27-coarse-scaled"),
    "stroke T1 storages": ("mr-brain-stroke-t1", "mr-brain-stroke-t1-uint16", "mr-brain-stroke-t1-uint16-600"),
}
