"""Tests of the built-in CT-like head phantom (isosimtf.phantom)."""

import hashlib

import numpy as np
import pytest

from isosimtf.phantom import FIELD_OF_VIEW_MM, TISSUE_HU, TISSUES, Phantom, head_phantom

N_TISSUES = len(TISSUES)
AIR, SOFT, SKULL, GREY, WHITE, CSF, SINUS = (
    TISSUES.index(name) for name in ("air", "soft tissue", "skull", "grey matter", "white matter", "csf", "sinus air")
)


def sharp(size=64, seed=0, dtype=np.float32):
    """Noise-free, blur-free phantom."""
    return head_phantom(size, seed=seed, noise_hu=0.0, blur_mm=0.0, dtype=dtype)


def adjacent_pairs(labels):
    """Set of (a, b) label pairs, a < b, that are face neighbours somewhere in the volume."""
    pairs = set()
    for axis in range(3):
        a = np.moveaxis(labels, axis, 0)
        lo, hi = a[:-1], a[1:]
        diff = lo != hi
        p = np.minimum(lo[diff], hi[diff]).astype(np.int64)
        q = np.maximum(lo[diff], hi[diff]).astype(np.int64)
        pairs |= {(int(u) // N_TISSUES, int(u) % N_TISSUES) for u in np.unique(p * N_TISSUES + q)}
    return pairs


# ------------------------------------------------------------------------------------------------ API and shapes


def test_tables_are_consistent():
    assert len(TISSUES) == len(TISSUE_HU) == 7
    assert TISSUES[0] == "air" and TISSUE_HU[0] == -1000.0
    assert len(set(TISSUE_HU)) == len(TISSUE_HU), "every tissue needs its own mean value"
    hu = dict(zip(TISSUES, TISSUE_HU))
    assert 700 <= hu["skull"] <= 1200
    assert hu["csf"] < hu["white matter"] < hu["grey matter"] < hu["soft tissue"]
    assert -1000 < hu["sinus air"] < -800


def test_default_shape_dtype_and_spacing():
    p = head_phantom(32)
    assert isinstance(p, Phantom)
    assert p.values.shape == p.labels.shape == (32, 32, 32)
    assert p.values.dtype == np.int16
    assert p.labels.dtype == np.uint8
    assert p.spacing == (7.5, 7.5, 7.5)
    assert p.tissues == TISSUES
    assert p.labels.max() < N_TISSUES


def test_anisotropic_shape_gives_per_axis_spacing():
    nz, ny, nx = 48, 56, 64
    p = head_phantom((nz, ny, nx), noise_hu=0.0)
    assert p.values.shape == p.labels.shape == (nz, ny, nx)
    assert p.spacing == pytest.approx((FIELD_OF_VIEW_MM / nx, FIELD_OF_VIEW_MM / ny, FIELD_OF_VIEW_MM / nz))
    assert set(np.unique(p.labels).tolist()) == set(range(N_TISSUES))
    # The head fills most of the field of view along every axis, whatever the voxel count.
    head = np.nonzero(p.labels != AIR)
    for axis, n in enumerate((nz, ny, nx)):
        extent = (head[axis].max() - head[axis].min() + 1) / n
        assert extent > 0.6, (axis, extent)


def test_same_physical_anatomy_at_every_resolution():
    fractions = []
    for size in (48, 96):
        labels = sharp(size).labels
        fractions.append(np.bincount(labels.ravel(), minlength=N_TISSUES) / labels.size)
    # Thin structures are sampled coarsely at 48, so only the large tissues are compared tightly.
    for t in (AIR, SOFT, SKULL, GREY, WHITE):
        assert fractions[0][t] == pytest.approx(fractions[1][t], rel=0.15), TISSUES[t]


@pytest.mark.parametrize("size", [np.int64(16), [16, 20, 24], (np.int32(16), 20, 24), 8])
def test_size_accepts_ints_sequences_and_numpy_ints(size):
    p = head_phantom(size, noise_hu=0.0)
    expected = (int(size),) * 3 if np.ndim(size) == 0 else tuple(int(n) for n in size)
    assert p.values.shape == expected


@pytest.mark.parametrize("dtype", [np.int16, np.int32, np.float32, np.float64, "int16", "float32"])
def test_dtype(dtype):
    p = head_phantom(24, dtype=dtype)
    assert p.values.dtype == np.dtype(dtype)


def test_integer_output_is_the_rounded_float_output():
    as_float = head_phantom(32, seed=3, dtype=np.float32).values
    as_int = head_phantom(32, seed=3, dtype=np.int16).values
    np.testing.assert_array_equal(as_int, np.rint(as_float).astype(np.int16))


def test_values_are_clipped_to_the_int16_range():
    for dtype in (np.int16, np.float32):
        v = head_phantom(16, noise_hu=1.0e5, dtype=dtype).values
        assert v.min() == -32768 and v.max() == 32767


# ----------------------------------------------------------------------------------------- determinism and seeds


def test_same_seed_gives_identical_volumes():
    a = head_phantom(40, seed=5)
    b = head_phantom(40, seed=5)
    np.testing.assert_array_equal(a.values, b.values)
    np.testing.assert_array_equal(a.labels, b.labels)


def test_seed_zero_is_pinned():
    """Seed 0 must give the same phantom everywhere; update these digests only on a deliberate phantom change."""
    p = head_phantom(32, seed=0)
    labels = hashlib.sha256(np.ascontiguousarray(p.labels).tobytes()).hexdigest()
    values = hashlib.sha256(np.ascontiguousarray(p.values.astype("<i2")).tobytes()).hexdigest()
    assert (labels, values) == (PINNED_LABELS_SHA256, PINNED_VALUES_SHA256)


PINNED_LABELS_SHA256 = "75190f3b4d43a19a3d102d20739ba8f4b1a2492413921cdaceacda37e8741b6f"
PINNED_VALUES_SHA256 = "fd2025f09c43094684ec45fab0378e498317f72ee25c11b59a5395fd00d97d49"


def test_different_seeds_give_different_but_similar_heads():
    a, b = head_phantom(48, seed=0), head_phantom(48, seed=1)
    assert not np.array_equal(a.values, b.values)
    assert not np.array_equal(a.labels, b.labels)
    fa = np.bincount(a.labels.ravel(), minlength=N_TISSUES) / a.labels.size
    fb = np.bincount(b.labels.ravel(), minlength=N_TISSUES) / b.labels.size
    for t in (AIR, SOFT, SKULL, GREY, WHITE):  # the anatomy varies by a few percent only
        assert fa[t] == pytest.approx(fb[t], rel=0.2), TISSUES[t]


def test_labels_do_not_depend_on_noise_blur_or_dtype():
    ref = head_phantom(32, seed=2).labels
    for kwargs in ({"noise_hu": 0.0}, {"blur_mm": 0.0}, {"blur_mm": 4.0, "noise_hu": 50.0}, {"dtype": np.float64}):
        np.testing.assert_array_equal(head_phantom(32, seed=2, **kwargs).labels, ref)


# ----------------------------------------------------------------------------------------------- ground truth


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_every_tissue_present_at_size_64(seed):
    counts = np.bincount(head_phantom(64, seed=seed).labels.ravel(), minlength=N_TISSUES)
    assert len(counts) == N_TISSUES
    assert (counts > 0).all(), dict(zip(TISSUES, counts.tolist()))


@pytest.mark.parametrize("dtype", [np.float32, np.int16])
def test_sharp_noise_free_values_equal_the_tissue_means(dtype):
    p = sharp(48, seed=1, dtype=dtype)
    for t, hu in enumerate(TISSUE_HU):
        inside = p.values[p.labels == t]
        assert inside.size > 0, TISSUES[t]
        assert inside.mean() == pytest.approx(hu), TISSUES[t]
        assert inside.min() == inside.max() == hu, TISSUES[t]


def test_anatomy_is_nested():
    """At a fine enough sampling, every tissue touches only its anatomical neighbours."""
    for seed in (0, 1):
        pairs = adjacent_pairs(sharp(128, seed=seed).labels)
        brain = {GREY, WHITE, CSF}
        for a, b in pairs:
            if AIR in (a, b):
                assert {a, b} == {AIR, SOFT}, (TISSUES[a], TISSUES[b])  # the skin covers everything
            if a in brain and b not in brain:
                assert b == SKULL, (TISSUES[a], TISSUES[b])
            if b in brain and a not in brain:
                assert a == SKULL, (TISSUES[a], TISSUES[b])
        assert (GREY, WHITE) in pairs and (SKULL, CSF) in pairs


def test_head_is_upright_and_faces_plus_y():
    labels = sharp(64).labels
    nz, ny, _ = labels.shape
    brain = np.nonzero(np.isin(labels, (GREY, WHITE)))
    assert brain[0].mean() > nz / 2, "the brain is in the upper half (+z)"
    sinus = np.nonzero(labels == SINUS)
    assert sinus[1].mean() > ny / 2, "the sinuses are anterior (+y)"
    assert (labels[0] != AIR).any(), "the neck reaches the bottom slice"


# ------------------------------------------------------------------------------------------------- noise, blur


@pytest.mark.parametrize("noise_hu", [10.0, 35.0])
def test_noise_std_in_the_air(noise_hu):
    p = head_phantom(48, seed=4, noise_hu=noise_hu, blur_mm=1.0, dtype=np.float32)
    corner = (slice(None), slice(0, 8), slice(0, 8))  # 40 mm x 40 mm columns far from the head
    assert (p.labels[corner] == AIR).all()
    air = p.values[corner].astype(np.float64)
    assert air.mean() == pytest.approx(TISSUE_HU[AIR], abs=1.0)
    assert air.std() == pytest.approx(noise_hu, rel=0.05)


def test_no_noise_means_exact_air():
    p = head_phantom(32, noise_hu=0.0, blur_mm=2.0, dtype=np.float32)
    np.testing.assert_array_equal(p.values[:, :4, :4], np.float32(TISSUE_HU[AIR]))


def total_variation(v):
    v = v.astype(np.float64)
    return sum(np.abs(np.diff(v, axis=axis)).sum() for axis in range(3))


def test_blur_smooths_boundaries():
    size = 64
    crisp = sharp(size).values
    soft = head_phantom(size, noise_hu=0.0, blur_mm=3.0, dtype=np.float32).values
    softer = head_phantom(size, noise_hu=0.0, blur_mm=6.0, dtype=np.float32).values
    # Sharp: only the tissue means; blurred: partial-volume values in between, within the range of the means.
    assert set(np.unique(crisp).tolist()) == set(TISSUE_HU)
    assert len(np.unique(soft)) > 100
    assert soft.min() >= min(TISSUE_HU) - 1e-3 and soft.max() <= max(TISSUE_HU) + 1e-3
    # A Gaussian never increases the total variation; more blur, less variation.
    assert total_variation(softer) < total_variation(soft) < total_variation(crisp)
    # The mean value is kept away from the volume's edges (the kernel is normalized).
    inner = (slice(8, -8),) * 3
    assert soft[inner].mean() == pytest.approx(crisp[inner].mean(), rel=0.02)


def test_blurred_profile_is_monotone_from_air_to_skull():
    size = 64
    p = head_phantom(size, noise_hu=0.0, blur_mm=3.0, dtype=np.float32)
    k, j = int(size * 0.7), size // 2  # a line through the cranial vault along x
    skull = np.nonzero(p.labels[k, j] == SKULL)[0]
    assert skull.size
    profile = p.values[k, j, : skull[0] + 1].astype(np.float64)
    assert np.all(np.diff(profile) >= -1e-3), profile
    between = (profile > TISSUE_HU[AIR] + 1.0) & (profile < TISSUE_HU[SOFT] - 1.0)
    assert between.any(), "partial-volume values between air and skin"


def reference_blur(volume, sigma_vox):
    """Separable sampled Gaussian (truncated at 3 sigma, normalized, edges replicated), float64, axis by axis."""
    out = volume.astype(np.float64)
    for axis, sigma in enumerate(sigma_vox):
        radius = int(np.ceil(3.0 * sigma))
        w = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
        w /= w.sum()
        pad = [(0, 0)] * 3
        pad[axis] = (radius, radius)
        out = np.apply_along_axis(np.convolve, axis, np.pad(out, pad, mode="edge"), w, mode="valid")
    return out


def test_blur_matches_a_separable_gaussian_with_the_spacing_per_axis():
    shape, blur_mm = (24, 32, 40), 6.0  # anisotropic spacing: sigma = 0.6, 0.8 and 1.0 voxel along z, y, x
    crisp = head_phantom(shape, seed=1, noise_hu=0.0, blur_mm=0.0, dtype=np.float64).values
    blurred = head_phantom(shape, seed=1, noise_hu=0.0, blur_mm=blur_mm, dtype=np.float64).values
    sigma_vox = [blur_mm / (FIELD_OF_VIEW_MM / n) for n in shape]
    np.testing.assert_allclose(blurred, reference_blur(crisp, sigma_vox), atol=0.05)


def test_small_blur_relative_to_the_voxel_is_almost_no_blur():
    crisp = sharp(32).values
    tiny = head_phantom(32, noise_hu=0.0, blur_mm=0.5, dtype=np.float32).values  # sigma = 0.07 voxel
    np.testing.assert_allclose(tiny, crisp, atol=1e-3)


# ------------------------------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    "kwargs",
    [
        {"size": 7},
        {"size": 0},
        {"size": -64},
        {"size": (64, 64)},
        {"size": (64, 64, 64, 64)},
        {"size": (64, 7, 64)},
        {"size": (64.0, 64, 64)},
        {"size": 64.5},
        {"size": "64"},
        {"size": True},
        {"size": None},
        {"noise_hu": -1.0},
        {"noise_hu": float("nan")},
        {"noise_hu": float("inf")},
        {"noise_hu": "20"},
        {"blur_mm": -0.1},
        {"blur_mm": float("nan")},
        {"blur_mm": None},
        {"seed": -1},
        {"seed": 1.5},
        {"seed": None},
        {"dtype": np.uint8},
        {"dtype": np.uint16},
        {"dtype": np.int8},
        {"dtype": np.float16},
        {"dtype": bool},
        {"dtype": np.complex64},
        {"dtype": "not a dtype"},
    ],
)
def test_bad_arguments_raise_value_error(kwargs):
    kwargs = dict(kwargs)
    size = kwargs.pop("size", 16)
    with pytest.raises(ValueError):
        head_phantom(size, **kwargs)
