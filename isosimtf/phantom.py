"""Built-in CT-like head phantom, in Hounsfield units, with ground-truth tissue labels.

The phantom is a simplified but anatomically plausible head: a scalp and face of soft tissue with a nose, eyes and
a neck; an ellipsoidal skull (thicker frontal bone holding a frontal sinus, a tilted skull base); air-filled nasal
cavity and maxillary sinuses; inside the skull a thin CSF layer, a grey-matter cortex with a bumpy (gyrus-like) inner
boundary, a white-matter core and two lateral ventricles filled with CSF.

Every tissue has one constant value (`TISSUE_HU`); partial-volume effects come from a Gaussian blur of ``blur_mm``
(the scanner's point-spread function) and acquisition noise from additive Gaussian noise of ``noise_hu``. The labels
are sampled from the sharp geometry at voxel centres, so they are the ground truth for evaluating a classification.

Conventions: arrays are indexed ``[k, j, i]`` = ``[z, y, x]`` (shape ``(nz, ny, nx)``), spacing is given as
``(x, y, z)`` in mm, like the rest of the library. The field of view is 240 mm along every axis whatever the number
of voxels, centred on the head; +x is the patient's left, +y anterior (the face looks toward increasing ``j``), +z
superior (the top of the head is at high ``k``), i.e. RAS axes with an identity direction matrix.

Only numpy is used. The geometry is computed in float64 from a seeded ``numpy.random.Generator`` (PCG64), the blur
and noise in float32 with a fixed operation order, so a given ``seed`` gives the same volume on every run.
"""

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Callable, Optional, Union

import numpy as np
from numpy.typing import DTypeLike

__all__ = ["FIELD_OF_VIEW_MM", "TISSUES", "TISSUE_HU", "Phantom", "head_phantom"]

#: Tissue names; the index in this tuple is the label value in `Phantom.labels` (0 = air outside the head).
TISSUES = ("air", "soft tissue", "skull", "grey matter", "white matter", "csf", "sinus air")

#: Mean value of each tissue in Hounsfield units, indexed by label (same order as `TISSUES`).
TISSUE_HU = (-1000.0, 60.0, 1000.0, 40.0, 25.0, 5.0, -900.0)

#: Physical extent of the volume along every axis, in mm (the voxel spacing is this divided by the voxel count).
FIELD_OF_VIEW_MM = 240.0

_AIR, _SOFT, _SKULL, _GREY, _WHITE, _CSF, _SINUS = range(len(TISSUES))

# Relative amount (per axis) by which the whole head may be scaled from one seed to the next.
_SCALE_JITTER = 0.03
# Truncation of the Gaussian kernel, in standard deviations.
_TRUNCATE = 3.0
# Approximate number of voxels per slab when painting the labels (bounds the temporary memory).
_SLAB_VOXELS = 1 << 21


@dataclass(frozen=True, eq=False)
class Phantom:
    """A generated head volume and its ground truth.

    Attributes:
        values: CT values in Hounsfield units, shape ``(nz, ny, nx)`` indexed ``[k, j, i]``; dtype as requested
            (``int16`` by default, like real CT).
        labels: ``uint8`` tissue label per voxel (an index into ``tissues``), same shape, from the sharp geometry.
        spacing: voxel size in mm as ``(x, y, z)``.
        tissues: tissue names, indexed by label (`TISSUES`).
    """

    values: np.ndarray
    labels: np.ndarray
    spacing: tuple[float, float, float]
    tissues: tuple[str, ...] = TISSUES


@dataclass(frozen=True)
class _Ellipsoid:
    """Ellipsoid in the phantom's nominal frame: centre and semi-axes in mm, optional rotation about z (radians)."""

    center: tuple[float, float, float]
    semi: tuple[float, float, float]
    yaw: float = 0.0


@dataclass(frozen=True)
class _Geometry:
    """All random choices of one phantom (the fixed anatomy lives in `_labels_slab`)."""

    scale: tuple[float, float, float]  # per-axis scale of the whole head (x, y, z), ~1
    ventricles: tuple[_Ellipsoid, _Ellipsoid]
    frontal_sinus: _Ellipsoid
    # Gyri of the grey/white boundary: unit directions (n, 3), angular frequencies (n,), phases (n,), amplitudes (n,),
    # the amplitudes relative to the white-matter semi-axes.
    gyri_dirs: np.ndarray
    gyri_freq: np.ndarray
    gyri_phase: np.ndarray
    gyri_amp: np.ndarray


# Fixed anatomy, nominal frame, mm (x, y, z). The skull's inner surface is shifted back so the frontal bone is thicker.
_SKIN = _Ellipsoid((0.0, -5.0, 22.0), (78.0, 98.0, 92.0))
_FACE = _Ellipsoid((0.0, 40.0, -38.0), (52.0, 50.0, 50.0))
_NOSE = _Ellipsoid((0.0, 90.0, -22.0), (9.0, 14.0, 20.0))
_NECK = _Ellipsoid((0.0, -12.0, -140.0), (50.0, 55.0, 125.0))
_SKULL_OUT = _Ellipsoid((0.0, -5.0, 22.0), (73.0, 93.0, 87.0))
_SKULL_IN = _Ellipsoid((0.0, -8.0, 22.0), (66.0, 84.0, 80.0))
_BRAIN = _Ellipsoid((0.0, -8.0, 22.0), (64.0, 82.0, 78.0))  # 2 mm of CSF between skull and cortex
_WHITE_MATTER = _Ellipsoid((0.0, -8.0, 24.0), (53.0, 71.0, 66.0))  # before the gyral modulation
_EYES = (_Ellipsoid((-30.0, 60.0, -20.0), (11.0, 11.0, 11.0)), _Ellipsoid((30.0, 60.0, -20.0), (11.0, 11.0, 11.0)))
_NASAL_CAVITY = _Ellipsoid((0.0, 62.0, -44.0), (6.0, 24.0, 18.0))
_MAXILLARY = (_Ellipsoid((-24.0, 52.0, -52.0), (12.0, 15.0, 13.0)), _Ellipsoid((24.0, 52.0, -52.0), (12.0, 15.0, 13.0)))
# Skull base: the cranial cavity ends at z = floor(y) = _FLOOR_Z0 + _FLOOR_SLOPE * (y - _FLOOR_Y0), rising toward the
# face so the orbits lie below the frontal lobes; a bone plate of _FLOOR_BONE mm lies under it.
_FLOOR_Z0, _FLOOR_Y0, _FLOOR_SLOPE, _FLOOR_BONE = -30.0, -5.0, 0.42, 6.0
_FLOOR_CSF = 2.0  # CSF between the skull base and the brain, mm
_FACE_BONE_Y = 40.0  # below the skull base, the skull shell is kept only in front of this y (facial bones), mm
# Nominal lateral ventricles (left, right) and frontal sinus before the per-seed jitter.
_VENTRICLES = (
    _Ellipsoid((-12.0, -10.0, 34.0), (6.0, 25.0, 10.0), math.radians(12.0)),
    _Ellipsoid((12.0, -10.0, 34.0), (6.0, 25.0, 10.0), math.radians(-12.0)),
)
_FRONTAL_SINUS = _Ellipsoid((0.0, 81.0, 30.0), (16.0, 2.5, 10.0))


def head_phantom(
    size: Union[int, Sequence[int]] = 128,
    *,
    seed: int = 0,
    noise_hu: float = 20.0,
    blur_mm: float = 1.0,
    dtype: DTypeLike = np.int16,
) -> Phantom:
    """Generate the CT-like head phantom.

    Args:
        size: number of voxels, either one int for a cube or ``(nz, ny, nx)``; every axis must be >= 8. The field of
            view is always `FIELD_OF_VIEW_MM` (240 mm) per axis, so the spacing is ``240 / n`` mm per axis and the
            head fills most of the volume whatever the size (anisotropic shapes give anisotropic spacing).
        seed: non-negative integer. It sets the noise and small changes of the anatomy (head scaled by up to 3 % per
            axis, ventricles moved by up to 2 mm and resized by up to 5 %, frontal sinus resized by up to 5 %, the
            cortex folding). The same seed always gives the same volume.
        noise_hu: standard deviation of the additive Gaussian noise, in HU (>= 0; 0 = no noise).
        blur_mm: standard deviation of the Gaussian point-spread function, in mm (>= 0; 0 = no blur). It is
            converted to voxels per axis with the spacing and applied separably (kernel truncated at 3 sigma,
            edges replicated).
        dtype: dtype of ``values``: a signed integer type of at least 16 bits (values rounded to the nearest integer)
            or float32/float64. In all cases values are clipped to the int16 range [-32768, 32767].

    Returns:
        A `Phantom` whose ``values`` (HU) and ``labels`` (uint8, see `TISSUES`) have shape ``(nz, ny, nx)``.

    Raises:
        ValueError: on an invalid size, seed, noise, blur or dtype.
    """
    shape = _check_size(size)
    seed = _check_seed(seed)
    noise_hu = _check_non_negative(noise_hu, "noise_hu")
    blur_mm = _check_non_negative(blur_mm, "blur_mm")
    out_dtype = _check_dtype(dtype)

    spacing_zyx = tuple(FIELD_OF_VIEW_MM / n for n in shape)
    geometry_seq, noise_seq = np.random.SeedSequence(seed).spawn(2)
    geometry = _random_geometry(np.random.default_rng(geometry_seq))
    labels = _labels(shape, spacing_zyx, geometry)
    values = _render(labels, spacing_zyx, blur_mm, noise_hu, np.random.default_rng(noise_seq), out_dtype)
    return Phantom(values=values, labels=labels, spacing=(spacing_zyx[2], spacing_zyx[1], spacing_zyx[0]))


# ---------------------------------------------------------------------------------------------------------- checks


def _check_size(size: Union[int, Sequence[int]]) -> tuple[int, int, int]:
    if isinstance(size, (bool, np.bool_)):
        raise ValueError(f"size must be an int or a (nz, ny, nx) tuple of ints, not {size!r}")
    if isinstance(size, numbers.Integral):
        dims = (int(size),) * 3
    else:
        try:
            items = tuple(size)  # type: ignore[arg-type]
        except TypeError:
            raise ValueError(f"size must be an int or a (nz, ny, nx) tuple of ints, not {size!r}") from None
        if len(items) != 3 or not all(
            isinstance(n, numbers.Integral) and not isinstance(n, (bool, np.bool_)) for n in items
        ):
            raise ValueError(f"size must be an int or a (nz, ny, nx) tuple of 3 ints, not {size!r}")
        dims = tuple(int(n) for n in items)
    if min(dims) < 8:
        raise ValueError(f"every axis of size must be at least 8 voxels, got {dims}")
    return dims  # type: ignore[return-value]


def _check_seed(seed: int) -> int:
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, not {seed!r}")
    return int(seed)


def _check_non_negative(value: float, name: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a number, not {value!r}")
    value = float(value)
    if not math.isfinite(value) or value < 0.0:
        raise ValueError(f"{name} must be finite and >= 0, got {value}")
    return value


def _check_dtype(dtype: DTypeLike) -> np.dtype:
    try:
        dt = np.dtype(dtype)
    except TypeError:
        raise ValueError(f"dtype must be a numpy dtype, not {dtype!r}") from None
    if (dt.kind == "i" and dt.itemsize >= 2) or (dt.kind == "f" and dt.itemsize >= 4):
        return dt
    raise ValueError(f"dtype must be a signed integer of >= 16 bits or float32/float64, not {dt}")


# -------------------------------------------------------------------------------------------------------- geometry


def _random_geometry(rng: np.random.Generator) -> _Geometry:
    """Draw the per-seed anatomy changes (float64 throughout, fixed draw order)."""
    scale = 1.0 + rng.uniform(-_SCALE_JITTER, _SCALE_JITTER, size=3)
    ventricles = []
    for v in _VENTRICLES:
        shift = rng.uniform(-2.0, 2.0, size=3)
        resize = 1.0 + rng.uniform(-0.05, 0.05, size=3)
        ventricles.append(
            _Ellipsoid(
                tuple(float(c + d) for c, d in zip(v.center, shift)),  # type: ignore[arg-type]
                tuple(float(a * f) for a, f in zip(v.semi, resize)),  # type: ignore[arg-type]
                v.yaw,
            )
        )
    resize = 1.0 + rng.uniform(-0.05, 0.05, size=3)
    sinus = _Ellipsoid(
        _FRONTAL_SINUS.center,
        tuple(float(a * f) for a, f in zip(_FRONTAL_SINUS.semi, resize)),  # type: ignore[arg-type]
    )
    n_gyri = 4
    dirs = rng.normal(size=(n_gyri, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freq = rng.uniform(18.0, 26.0, size=n_gyri)
    phase = rng.uniform(0.0, 2.0 * math.pi, size=n_gyri)
    amp = np.full(n_gyri, 0.025)
    return _Geometry(
        scale=(float(scale[0]), float(scale[1]), float(scale[2])),
        ventricles=(ventricles[0], ventricles[1]),
        frontal_sinus=sinus,
        gyri_dirs=dirs,
        gyri_freq=freq,
        gyri_phase=phase,
        gyri_amp=amp,
    )


def _labels(shape: tuple[int, int, int], spacing_zyx: tuple[float, ...], geometry: _Geometry) -> np.ndarray:
    """Label every voxel centre, slab by slab along z; returns uint8 (nz, ny, nx)."""
    nz, ny, nx = shape
    # Voxel-centre coordinates (mm, centred on the volume), mapped to the nominal frame by the per-seed scale.
    x = ((np.arange(nx) + 0.5 - nx / 2.0) * spacing_zyx[2]) / geometry.scale[0]
    y = ((np.arange(ny) + 0.5 - ny / 2.0) * spacing_zyx[1]) / geometry.scale[1]
    z = ((np.arange(nz) + 0.5 - nz / 2.0) * spacing_zyx[0]) / geometry.scale[2]
    labels = np.zeros(shape, dtype=np.uint8)
    step = max(1, _SLAB_VOXELS // (ny * nx))
    for k0 in range(0, nz, step):
        k1 = min(nz, k0 + step)
        _labels_slab(labels[k0:k1], x, y, z[k0:k1], geometry)
    return labels


_Box = tuple[slice, slice, slice]


def _box(e: _Ellipsoid, x: np.ndarray, y: np.ndarray, z: np.ndarray, margin: float = 0.0) -> Optional[_Box]:
    """Index box (z, y, x slices) of the voxels whose centres may lie in ``e`` grown by ``margin`` mm, or None."""
    a, b, c = (s + margin for s in e.semi)
    cos, sin = math.cos(e.yaw), math.sin(e.yaw)
    ext = (math.hypot(a * cos, b * sin), math.hypot(a * sin, b * cos), c)
    box = []
    for coord, centre, half in ((z, e.center[2], ext[2]), (y, e.center[1], ext[1]), (x, e.center[0], ext[0])):
        lo = int(np.searchsorted(coord, centre - half, side="left"))
        hi = int(np.searchsorted(coord, centre + half, side="right"))
        if hi <= lo:
            return None
        box.append(slice(lo, hi))
    return box[0], box[1], box[2]


def _quadric(e: _Ellipsoid, x: np.ndarray, y: np.ndarray, z: np.ndarray, box: _Box) -> np.ndarray:
    """``sum((d / semi)^2)`` over the box (<= 1 inside the ellipsoid), float64 of the box's shape."""
    dx = (x[box[2]] - e.center[0])[None, :]
    dy = (y[box[1]] - e.center[1])[:, None]
    dz = z[box[0]] - e.center[2]
    if e.yaw:
        cos, sin = math.cos(e.yaw), math.sin(e.yaw)
        u = cos * dx + sin * dy
        v = cos * dy - sin * dx
        plane = (u / e.semi[0]) ** 2 + (v / e.semi[1]) ** 2
    else:
        plane = (dx / e.semi[0]) ** 2 + (dy / e.semi[1]) ** 2
    return plane[None, :, :] + ((dz / e.semi[2]) ** 2)[:, None, None]


def _paint(
    labels: np.ndarray,
    e: _Ellipsoid,
    label: int,
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    *,
    only: Optional[tuple[int, ...]] = None,
    where: Optional[Callable[[np.ndarray, np.ndarray], np.ndarray]] = None,
) -> None:
    """Set ``label`` inside ``e`` (optionally only over the labels ``only`` and where ``where(y, z)`` is true)."""
    box = _box(e, x, y, z)
    if box is None:
        return
    mask = _quadric(e, x, y, z, box) <= 1.0
    target = labels[box]
    if where is not None:
        mask &= where(y[box[1]], z[box[0]])
    if only is not None:
        allowed = target == only[0]
        for lab in only[1:]:
            allowed |= target == lab
        mask &= allowed
    target[mask] = label


def _floor(y: np.ndarray) -> np.ndarray:
    """Height (mm, nominal frame) of the cranial cavity's floor at anterior position ``y``."""
    return _FLOOR_Z0 + _FLOOR_SLOPE * (y - _FLOOR_Y0)


def _above(offset: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``where`` predicate: z above the cavity floor + offset mm; broadcasts to (nz, ny, 1)."""
    return lambda y, z: (z[:, None] > _floor(y)[None, :] + offset)[:, :, None]


def _below(offset: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``where`` predicate: z at or below the cavity floor + offset mm; broadcasts to (nz, ny, 1)."""
    return lambda y, z: (z[:, None] <= _floor(y)[None, :] + offset)[:, :, None]


def _behind_face_below_base(y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``where`` predicate: under the skull base plate and behind the facial bones; broadcasts to (nz, ny, 1)."""
    return ((z[:, None] <= _floor(y)[None, :] - _FLOOR_BONE) & (y < _FACE_BONE_Y)[None, :])[:, :, None]


def _labels_slab(labels: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray, g: _Geometry) -> None:
    """Paint one z-slab, later structures over earlier ones."""
    # Soft tissue: skin envelope of the cranium, face, nose, neck.
    for e in (_SKIN, _FACE, _NOSE, _NECK):
        _paint(labels, e, _SOFT, x, y, z)
    # Skull as a full ellipsoid (hollowed below), open under the skull base except for the facial bones, with the
    # frontal sinus in the thick frontal bone.
    _paint(labels, _SKULL_OUT, _SKULL, x, y, z, only=(_SOFT,))
    _paint(labels, _SKULL_OUT, _SOFT, x, y, z, only=(_SKULL,), where=_behind_face_below_base)
    _paint(labels, g.frontal_sinus, _SINUS, x, y, z, only=(_SKULL,))
    # Eyes cut the orbits into the bone.
    for e in _EYES:
        _paint(labels, e, _SOFT, x, y, z, only=(_SOFT, _SKULL))
    # Inside the skull: soft tissue below the skull base, a bone plate, then the cranial cavity filled with CSF.
    _paint(labels, _SKULL_IN, _SOFT, x, y, z, only=(_SKULL,), where=_below(-_FLOOR_BONE))
    _paint(labels, _SKULL_IN, _CSF, x, y, z, only=(_SKULL,), where=_above(0.0))
    # Brain: cortex, folded white matter, ventricles.
    _paint(labels, _BRAIN, _GREY, x, y, z, only=(_CSF,), where=_above(_FLOOR_CSF))
    _paint_white_matter(labels, x, y, z, g)
    for e in g.ventricles:
        _paint(labels, e, _CSF, x, y, z, only=(_GREY, _WHITE))
    # Air in the nasal cavity and the maxillary sinuses.
    for e in (_NASAL_CAVITY, *_MAXILLARY):
        _paint(labels, e, _SINUS, x, y, z, only=(_SOFT,))


def _paint_white_matter(labels: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray, g: _Geometry) -> None:
    """White matter: the ellipsoid whose normalized radius is modulated by a sum of plane waves over directions."""
    e = _WHITE_MATTER
    amp_total = float(np.sum(g.gyri_amp))
    box = _box(e, x, y, z, margin=amp_total * max(e.semi))
    if box is None:
        return
    target = labels[box]
    q = _quadric(e, x, y, z, box)
    grey = target == _GREY
    # Certainly inside / certainly outside without evaluating the waves; only the boundary band needs them.
    target[grey & (q <= (1.0 - amp_total) ** 2)] = _WHITE
    band = grey & (q > (1.0 - amp_total) ** 2) & (q < (1.0 + amp_total) ** 2)
    kk, jj, ii = np.nonzero(band)
    if kk.size == 0:
        return
    p = np.stack(
        [
            (x[box[2]][ii] - e.center[0]) / e.semi[0],
            (y[box[1]][jj] - e.center[1]) / e.semi[1],
            (z[box[0]][kk] - e.center[2]) / e.semi[2],
        ]
    )
    rho = np.sqrt(q[kk, jj, ii])
    u = p / rho  # rho > 1 - amp_total > 0 in the band
    bump = np.zeros_like(rho)
    for d, f, ph, a in zip(g.gyri_dirs, g.gyri_freq, g.gyri_phase, g.gyri_amp):
        bump += a * np.sin(f * (d[0] * u[0] + d[1] * u[1] + d[2] * u[2]) + ph)
    inside = rho <= 1.0 + bump
    target[kk[inside], jj[inside], ii[inside]] = _WHITE


# --------------------------------------------------------------------------------------------------- blur and noise


def _half_kernel(sigma_vox: float) -> np.ndarray:
    """Weights w[0..r] of a normalized sampled Gaussian (w[s] applies at offsets +s and -s), float32."""
    radius = math.ceil(_TRUNCATE * sigma_vox) if sigma_vox > 0.0 else 0
    if radius == 0:
        return np.ones(1, dtype=np.float32)
    w = np.exp(-0.5 * (np.arange(radius + 1, dtype=np.float64) / sigma_vox) ** 2)
    w /= w[0] + 2.0 * w[1:].sum()
    return w.astype(np.float32)


def _blur_rows(a: np.ndarray, w: np.ndarray, axis: int, pad: np.ndarray, tmp: np.ndarray) -> None:
    """Blur the 2-D float32 array ``a`` in place along ``axis`` (edges replicated); ``pad``/``tmp`` are scratch."""
    r = len(w) - 1
    if r == 0:
        return
    n = a.shape[axis]
    if axis == 0:
        pad[r : r + n] = a
        pad[:r] = a[:1]
        pad[r + n :] = a[-1:]

        def shifted(s: int) -> np.ndarray:
            return pad[r + s : r + s + n]
    else:
        pad[:, r : r + n] = a
        pad[:, :r] = a[:, :1]
        pad[:, r + n :] = a[:, -1:]

        def shifted(s: int) -> np.ndarray:
            return pad[:, r + s : r + s + n]

    np.multiply(shifted(0), w[0], out=a)
    for s in range(1, r + 1):
        np.add(shifted(-s), shifted(s), out=tmp)
        tmp *= w[s]
        a += tmp


def _render(
    labels: np.ndarray,
    spacing_zyx: tuple[float, ...],
    blur_mm: float,
    noise_hu: float,
    rng: np.random.Generator,
    out_dtype: np.dtype,
) -> np.ndarray:
    """HU values from the labels: tissue means, separable Gaussian blur, noise, rounding; streamed slice by slice.

    The in-plane (y, x) blur is applied to each slice as it enters a ring buffer of ``2 r + 1`` slices and the z blur
    is computed from the ring, so the memory beyond the output is a few slices, and all work stays in cache.
    """
    nz, ny, nx = labels.shape
    lut = np.asarray(TISSUE_HU, dtype=np.float32)
    wz, wy, wx = (_half_kernel(blur_mm / s) for s in spacing_zyx)
    rz, ry, rx = len(wz) - 1, len(wy) - 1, len(wx) - 1
    ring_len = 2 * rz + 1
    ring = np.empty((ring_len, ny, nx), dtype=np.float32)
    pad_y = np.empty((ny + 2 * ry, nx), dtype=np.float32)
    pad_x = np.empty((ny, nx + 2 * rx), dtype=np.float32)
    tmp = np.empty((ny, nx), dtype=np.float32)
    acc = np.empty((ny, nx), dtype=np.float32)
    noise = np.empty((ny, nx), dtype=np.float32) if noise_hu > 0.0 else None
    integer = out_dtype.kind == "i"
    lo, hi = np.float32(np.iinfo(np.int16).min), np.float32(np.iinfo(np.int16).max)
    out = np.empty(labels.shape, dtype=out_dtype)

    def load(m: int) -> None:
        slot = ring[m % ring_len]
        np.take(lut, labels[m], out=slot)
        _blur_rows(slot, wy, 0, pad_y, tmp)
        _blur_rows(slot, wx, 1, pad_x, tmp)

    loaded = 0
    for k in range(nz):
        while loaded <= min(k + rz, nz - 1):
            load(loaded)
            loaded += 1
        np.multiply(ring[k % ring_len], wz[0], out=acc)
        for s in range(1, rz + 1):
            np.add(ring[max(k - s, 0) % ring_len], ring[min(k + s, nz - 1) % ring_len], out=tmp)
            tmp *= wz[s]
            acc += tmp
        if noise is not None:
            rng.standard_normal(dtype=np.float32, out=noise)
            noise *= np.float32(noise_hu)
            acc += noise
        if integer:
            np.rint(acc, out=acc)
        np.clip(acc, lo, hi, out=acc)
        out[k] = acc
    return out
