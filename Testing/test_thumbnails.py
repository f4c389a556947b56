"""Thumbnails of a transfer function: compositing, visibility oracle, shading, orientation, aspect, validation."""

import numpy as np
import pytest

from IsoSimilarityTFLib.thumbnails import VIEWS, VIEWS_ALL_SIX, ray_visibility, render_thumbnail
from IsoSimilarityTFLib.visibility import Preview, visibility_histogram

BACKGROUND = (0.2, 0.4, 0.6)
BACKGROUND_U8 = np.array([51, 102, 153], dtype=np.uint8)


def random_preview(seed, n_bins=8):
    """Random bins on a random small grid with anisotropic spacing, scaled to a 200 mm extent (geometric mean of the
    three sides), where the fast path's unit distance is 1 mm whether it is fixed or derived from the extent."""
    rng = np.random.default_rng(seed)
    shape = tuple(int(n) for n in rng.integers(2, 9, 3))
    spacing = rng.uniform(0.3, 3.0, 3)
    sides = np.asarray(shape) * spacing[::-1]
    spacing *= 200.0 / np.exp(np.mean(np.log(sides)))
    opacity = rng.uniform(0.0, 1.0, n_bins)
    opacity[:2] = (0.0, 1.0)  # an invisible bin and an opaque one (nothing behind it gets light)
    return Preview(rng.integers(0, n_bins, shape), tuple(float(s) for s in spacing), n_bins), opacity


def ball(n=32, radius=11.0):
    """``(n, n, n)`` bins: 1 inside a ball of ``radius`` voxels centred in the grid, 0 outside."""
    z, y, x = np.mgrid[:n, :n, :n] - (n - 1) / 2.0
    return (x * x + y * y + z * z < radius * radius).astype(np.uint8)


def radius_map(size):
    """Distance in pixels of every pixel centre from the picture's centre."""
    rows, cols = np.mgrid[:size, :size] + 0.5 - size / 2.0
    return np.hypot(rows, cols)


def opaque(picture):
    """Pixels that are not the background."""
    return np.any(picture != BACKGROUND_U8, axis=-1)


# The visibility oracle ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(8))
def test_ray_visibility_matches_the_fast_visibility_histogram(seed):
    preview, opacity = random_preview(seed)
    fast = visibility_histogram(preview, opacity)
    oracle = ray_visibility(preview, opacity, unit_distance=1.0)
    # The fast path composites in float32: 40 random previews differ from the float64 oracle by at most 2.7e-6.
    np.testing.assert_allclose(fast, oracle, rtol=1e-5, atol=1e-6)
    assert oracle[0] == 0.0 and oracle.sum() > 0


@pytest.mark.parametrize("seed", range(4))
def test_scaling_spacing_and_unit_distance_together_changes_nothing(seed):
    preview, opacity = random_preview(seed)
    for factor in (0.1, 3.7):
        scaled = Preview(preview.bins, tuple(s * factor for s in preview.spacing), preview.n_bins)
        np.testing.assert_allclose(
            ray_visibility(scaled, opacity, unit_distance=factor),
            ray_visibility(preview, opacity, unit_distance=1.0),
            rtol=1e-12,
        )
    # The unit distance does matter on its own.
    assert not np.allclose(
        ray_visibility(preview, opacity, unit_distance=3.7), ray_visibility(preview, opacity, unit_distance=1.0)
    )


def test_an_opaque_volume_shows_its_faces_once_per_ray():
    bins = np.arange(60).reshape(3, 4, 5)  # one bin per voxel
    preview = Preview(bins, (1.0, 2.0, 0.5), 60)
    everything = ray_visibility(preview, np.ones(60), unit_distance=1.0)
    np.testing.assert_array_equal(everything.sum(), 2 * (4 * 5 + 3 * 5 + 3 * 4))  # one unit of light per ray
    anterior = ray_visibility(preview, np.ones(60), unit_distance=1.0, views=("anterior",))
    front = np.zeros(60)
    front[bins[:, -1, :].ravel()] = 1.0  # the anterior view's rays stop in the highest j
    np.testing.assert_array_equal(anterior, front)
    twice = ray_visibility(preview, np.ones(60), unit_distance=1.0, views=("anterior", "anterior"))
    np.testing.assert_array_equal(twice, 2 * front)


# Compositing against a literal per-sample ray caster -----------------------------------------------------------------

# (k, j, i) of the sample at picture row r, column c and depth d (d = 0 nearest the camera): the module's table.
SAMPLE_AT = {
    "anterior": lambda r, c, d, n: (n - 1 - r, n - 1 - d, n - 1 - c),
    "posterior": lambda r, c, d, n: (n - 1 - r, d, c),
    "left": lambda r, c, d, n: (n - 1 - r, n - 1 - c, d),
    "right": lambda r, c, d, n: (n - 1 - r, c, n - 1 - d),
    "superior": lambda r, c, d, n: (n - 1 - d, n - 1 - r, c),
    "inferior": lambda r, c, d, n: (d, n - 1 - r, n - 1 - c),
}
# Depth axis of each view as an index into the (x, y, z) spacing.
DEPTH_XYZ = {"anterior": 1, "posterior": 1, "left": 0, "right": 0, "superior": 2, "inferior": 2}


def slow_picture(bins, spacing, colors, opacity, unit_distance, view, background):
    """The unshaded picture, pixel by pixel and sample by sample, when the picture has one pixel per ray: each step
    from a sample to the next (the last one's within its bin) is the bins between theirs, one after the other, each
    an equal part of the step (pre-integration, as the bins run from one sample's value to the next's)."""
    n = bins.shape[0]
    step = spacing[DEPTH_XYZ[view]]
    picture = np.zeros((n, n, 3))
    for r in range(n):
        for c in range(n):
            color, transmittance = np.zeros(3), 1.0
            for d in range(n):
                sample = bins[SAMPLE_AT[view](r, c, d, n)]
                following = bins[SAMPLE_AT[view](r, c, min(d + 1, n - 1), n)]
                crossed = range(min(sample, following), max(sample, following) + 1)
                # The crossed bins' light as one segment of mean extinction and extinction-weighted colour.
                extinction = [-np.log(1.0 - opacity[b]) for b in crossed]
                alpha = 1.0 - np.exp(-step / unit_distance * sum(extinction) / len(crossed))
                if sum(extinction) > 0:
                    mean_color = sum(e * colors[b] for e, b in zip(extinction, crossed)) / sum(extinction)
                else:
                    mean_color = colors[sample]
                color += transmittance * alpha * mean_color
                transmittance *= 1.0 - alpha
            picture[r, c] = color + transmittance * np.asarray(background)
    return np.rint(picture * 255.0)


@pytest.mark.parametrize("view", VIEWS_ALL_SIX)
def test_unshaded_compositing_matches_a_literal_ray_caster(view):
    rng = np.random.default_rng(7)
    n, n_bins = 8, 6
    bins = rng.integers(0, n_bins, (n, n, n))
    colors = rng.uniform(0.0, 1.0, (n_bins, 3))
    opacity = rng.uniform(0.0, 0.6, n_bins)
    opacity[0] = 0.0
    # 0.6 mm along the rays, 1.5 mm across them: an 8-pixel picture has one pixel per ray.
    spacing = [1.5, 1.5, 1.5]
    spacing[DEPTH_XYZ[view]] = 0.6
    preview = Preview(bins, tuple(spacing), n_bins)
    picture = render_thumbnail(
        preview, colors, opacity, unit_distance=0.7, view=view, size=n, background=BACKGROUND, shading=False
    )
    expected = slow_picture(bins, spacing, colors, opacity, 0.7, view, BACKGROUND)
    assert picture.shape == (n, n, 3) and picture.dtype == np.uint8
    assert np.abs(picture.astype(float) - expected).max() <= 1.0  # rounding to 8 bits


# A ball: shading, silhouette, background --------------------------------------------------------------------------


def test_a_ball_is_lit_in_the_middle_and_dark_at_its_rim():
    preview = Preview(ball(), (2.0, 2.0, 2.0), 2)  # 64 mm across, the ball 22 mm in radius
    white = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    opacity = np.array([0.0, 1.0])
    radius = radius_map(64)  # one pixel per mm
    for view in VIEWS:
        picture = render_thumbnail(
            preview, white, opacity, unit_distance=1.0, view=view, size=64, background=BACKGROUND
        )
        grey = picture.astype(int)
        inside, rim, outside = radius < 0.8 * 22, (radius > 0.8 * 22) & (radius < 0.9 * 22), radius > 1.15 * 22
        assert np.all(grey[inside, 0] == grey[inside, 2])  # an opaque white ball: grey, no background
        assert np.all(picture[outside] == BACKGROUND_U8)
        centre = grey[30:34, 30:34, 0].mean()
        assert centre > 240  # the surface faces the headlight
        assert grey[rim, 0].mean() < 0.8 * centre  # the surface turns away from it
        flat = render_thumbnail(
            preview, white, opacity, unit_distance=1.0, view=view, size=64, background=BACKGROUND, shading=False
        )
        assert np.all(flat[inside] == 255)


@pytest.mark.parametrize("view", VIEWS_ALL_SIX)
def test_a_shell_one_voxel_thick_is_lit_like_a_ball(view):
    # A 5 mm skull in a preview of 5 mm voxels: at the shell's centre the gradient across it vanishes.
    z, y, x = np.mgrid[:32, :32, :32] - 15.5
    distance = np.sqrt(x * x + y * y + z * z)
    preview = Preview(((distance >= 10.5) & (distance < 11.5)).astype(np.uint8), (2.0, 2.0, 2.0), 2)
    picture = render_thumbnail(
        preview, np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]), np.array([0.0, 1.0]), unit_distance=1.0, view=view,
        size=64,
    )  # fmt: skip
    # Within 0.7 of the radius a lit ball's shade is at least 0.3 + 0.7 * cos(asin(0.7)) = 0.8 (204 of 255).
    assert picture[radius_map(64) < 0.7 * 22, 0].min() >= 0.6 * 255


@pytest.mark.parametrize("view", VIEWS_ALL_SIX)
def test_a_skin_between_two_samples_is_drawn_where_the_rays_cross_it(view):
    """A ball of bin 4 in air (bin 0), both clear, and only bin 2 shown: no sample is of bin 2, yet every ray into
    the ball passes its values, as a ray through the full volume crosses the ball's partial-volume skin. The skin's
    colour, where the rays cross it; the background elsewhere; and nothing where the crossed bins are all clear."""
    preview = Preview(np.where(ball(16, 6.0) > 0, 4, 0), (1.0, 1.0, 1.0), 5)
    colors = np.zeros((5, 3))
    colors[2] = (1.0, 0.5, 0.0)
    opacity = np.zeros(5)
    opacity[2] = 0.9
    picture = render_thumbnail(preview, colors, opacity, unit_distance=1.0, view=view, size=16, shading=False)
    inside = radius_map(16) < 4.0
    assert np.all(picture[inside, 0] > 0) and np.all(picture[inside, 2] == 0)  # orange, through 2 crossings
    assert np.all(picture[radius_map(16) > 7.0] == 0)
    opacity[2], opacity[4] = 0.0, 0.0
    assert np.all(render_thumbnail(preview, colors, opacity, unit_distance=1.0, view=view, size=16) == 0)


def test_a_transparent_transfer_function_shows_the_background():
    preview = Preview(ball(16, 6.0), (1.0, 1.5, 3.0), 2)
    for view in VIEWS_ALL_SIX:
        picture = render_thumbnail(
            preview, np.ones((2, 3)), np.zeros(2), unit_distance=1.0, view=view, size=24, background=BACKGROUND
        )
        assert np.all(picture == BACKGROUND_U8)


def test_opacity_outside_zero_one_is_clipped():
    preview = Preview(ball(16, 6.0), (1.0, 1.0, 1.0), 2)
    colors = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    clipped = render_thumbnail(preview, colors, np.array([-0.5, 3.0]), unit_distance=1.0, size=16)
    np.testing.assert_array_equal(
        clipped, render_thumbnail(preview, colors, np.array([0.0, 1.0]), unit_distance=1.0, size=16)
    )


# Orientation and aspect ---------------------------------------------------------------------------------------------


def block_picture(where, view, colors=((1.0, 1.0, 1.0),)):
    """Picture of opaque blocks in an empty 16^3 volume: ``where`` lists (k, j, i) slices, block b gets bin b + 1."""
    bins = np.zeros((16, 16, 16), dtype=np.uint8)
    for b, block in enumerate(where):
        bins[block] = b + 1
    palette = np.vstack([[0.0, 0.0, 0.0], colors])
    opacity = np.r_[0.0, np.ones(len(colors))]
    return render_thumbnail(
        Preview(bins, (1.0, 1.0, 1.0), len(palette)), palette, opacity, unit_distance=1.0, view=view, size=32,
        background=BACKGROUND, shading=False,
    )  # fmt: skip


def rows_and_columns(picture):
    shown = opaque(picture)
    return np.flatnonzero(shown.any(axis=1)), np.flatnonzero(shown.any(axis=0))


MIDDLE = slice(6, 10)
HIGH = slice(12, 16)


@pytest.mark.parametrize(
    ("block", "view", "expected"),
    [
        ((HIGH, MIDDLE, MIDDLE), "anterior", "top"),  # superior is up
        ((HIGH, MIDDLE, MIDDLE), "left", "top"),
        ((MIDDLE, HIGH, MIDDLE), "superior", "top"),  # anterior is up
        ((MIDDLE, MIDDLE, HIGH), "anterior", "left"),  # the patient's right on the viewer's left
        ((MIDDLE, MIDDLE, HIGH), "posterior", "right"),
        ((MIDDLE, HIGH, MIDDLE), "left", "left"),  # the face looks left
        ((MIDDLE, HIGH, MIDDLE), "right", "right"),
        ((MIDDLE, MIDDLE, HIGH), "superior", "right"),
        ((MIDDLE, MIDDLE, HIGH), "inferior", "left"),
    ],
)
def test_orientation(block, view, expected):
    rows, cols = rows_and_columns(block_picture([block], view))
    assert rows.size and cols.size
    middle = {"top": (rows.max() < 16) and (8 <= cols.min() and cols.max() < 24)}
    middle["left"] = cols.max() < 16 and 8 <= rows.min() and rows.max() < 24
    middle["right"] = cols.min() >= 16 and 8 <= rows.min() and rows.max() < 24
    assert middle[expected]


@pytest.mark.parametrize(("view", "front_color"), [("anterior", 0), ("posterior", 1), ("superior", 0)])
def test_the_camera_sees_the_nearest_block(view, front_color):
    red, green = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
    if view == "superior":
        blocks = [(HIGH, MIDDLE, MIDDLE), (slice(0, 4), MIDDLE, MIDDLE)]
    else:
        blocks = [(MIDDLE, HIGH, MIDDLE), (MIDDLE, slice(0, 4), MIDDLE)]
    picture = block_picture(blocks, view, colors=(red, green))
    expected = np.rint(np.asarray((red, green)[front_color]) * 255)
    np.testing.assert_array_equal(picture[16, 16], expected)


@pytest.mark.parametrize(
    ("shape", "spacing", "view", "width", "height"),
    [
        ((10, 10, 10), (3.0, 1.0, 1.0), "anterior", 96, 32),  # 30 mm wide (x), 10 mm tall (z)
        ((10, 10, 10), (3.0, 1.0, 1.0), "superior", 96, 32),  # 30 mm wide (x), 10 mm tall (y)
        ((10, 10, 10), (3.0, 1.0, 1.0), "left", 96, 96),  # 10 x 10 mm
        ((20, 5, 5), (1.0, 1.0, 1.0), "anterior", 24, 96),  # 5 mm wide, 20 mm tall
        ((4, 12, 6), (1.0, 1.0, 2.0), "left", 96, 64),  # 12 mm wide (y), 8 mm tall (z)
    ],
)
def test_the_picture_keeps_the_physical_aspect_centred(shape, spacing, view, width, height):
    preview = Preview(np.ones(shape, dtype=np.uint8), spacing, 2)
    picture = render_thumbnail(
        preview, np.ones((2, 3)), np.array([0.0, 0.5]), unit_distance=1.0, view=view, background=BACKGROUND
    )
    assert picture.shape == (96, 96, 3)
    rows, cols = rows_and_columns(picture)
    assert abs(cols.size - width) <= 1 and abs(rows.size - height) <= 1
    assert abs((rows.min() + rows.max()) / 2 - 47.5) <= 0.5 and abs((cols.min() + cols.max()) / 2 - 47.5) <= 0.5


def anatomy():
    """A shaded preview of a small 'patient' stored as RAS (identity directions), anisotropic, with a differently
    coloured block on each of its right, anterior and superior sides (bins 2, 3, 4) around a body (bin 1)."""
    bins = np.zeros((12, 10, 8), dtype=np.uint8)  # k (superior), j (anterior), i (right)
    bins[2:10, 2:8, 2:6] = 1
    bins[4:8, 4:6, 6:8] = 2  # right
    bins[4:8, 8:10, 3:5] = 3  # anterior
    bins[10:12, 4:6, 3:5] = 4  # superior
    colors = np.array([[0, 0, 0], [0.8, 0.7, 0.5], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    return Preview(bins, (1.0, 1.5, 2.0), 5), colors, np.array([0.0, 0.3, 1.0, 1.0, 1.0])


def restored(preview, permutation, reversed_axes):
    """The same anatomy stored another way: array axes permuted (``permutation`` of (k, j, i)) and reversed, with the
    spacing and the IJK-to-RAS directions that say so."""
    bins = np.transpose(preview.bins, permutation)
    bins = bins[tuple(slice(None, None, -1) if axis in reversed_axes else slice(None) for axis in range(3))]
    directions = np.zeros((3, 3))
    spacing = []
    for c in range(3):  # new index axis c (i, j, k) is new array axis 2 - c, old array axis permutation[2 - c]
        old_index = 2 - permutation[2 - c]  # its RAS direction under the identity
        directions[old_index, c] = -1.0 if (2 - c) in reversed_axes else 1.0
        spacing.append(preview.spacing[old_index])
    return Preview(np.ascontiguousarray(bins), tuple(spacing), preview.n_bins), directions


@pytest.mark.parametrize(
    ("permutation", "reversed_axes"),
    [((0, 1, 2), (1,)), ((0, 1, 2), (1, 2)), ((2, 1, 0), ()), ((1, 0, 2), (0,)), ((2, 0, 1), (0, 1, 2))],
)
@pytest.mark.parametrize("view", VIEWS_ALL_SIX)
def test_the_picture_does_not_depend_on_how_the_file_stores_the_patient(permutation, reversed_axes, view):
    preview, colors, opacity = anatomy()
    expected = render_thumbnail(preview, colors, opacity, unit_distance=1.0, view=view, size=48)
    stored, directions = restored(preview, permutation, reversed_axes)
    picture = render_thumbnail(stored, colors, opacity, unit_distance=1.0, view=view, size=48, directions=directions)
    assert np.abs(picture.astype(int) - expected).max() <= 1  # float32 sums in another axis order
    # Read as if the file were RAS, the same voxels show another side of the patient.
    assert np.abs(render_thumbnail(stored, colors, opacity, unit_distance=1.0, view=view, size=48).astype(int)
                  - expected).max() > 1  # fmt: skip


@pytest.mark.parametrize("degrees", [-30.0, 25.0, 44.0])
def test_an_oblique_volume_is_shown_along_its_nearest_axes(degrees):
    preview, colors, opacity = anatomy()
    angle = np.radians(degrees)  # a head turned in the bore, about the superior axis
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    for view in VIEWS:
        np.testing.assert_array_equal(
            render_thumbnail(preview, colors, opacity, unit_distance=1.0, view=view, directions=2.0 * rotation),
            render_thumbnail(preview, colors, opacity, unit_distance=1.0, view=view),
        )


# Validation ---------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"bin_colors": np.ones((3, 3))}, "bin_colors"),
        ({"bin_colors": np.ones((2, 4))}, "bin_colors"),
        ({"bin_opacity": np.ones(3)}, "bin_opacity"),
        ({"bin_opacity": np.array([0.0, np.nan])}, "bin_opacity"),
        ({"view": "front"}, "unknown view"),
        ({"size": 7}, "size"),
        ({"size": 9.5}, "size"),
        ({"unit_distance": 0.0}, "unit_distance"),
        ({"unit_distance": -1.0}, "unit_distance"),
        ({"background": (1.0, 1.0)}, "background"),
        ({"preview": Preview(np.ones((4, 4)), (1.0, 1.0, 1.0), 2)}, "preview.bins"),
        ({"preview": Preview(np.full((4, 4, 4), 2), (1.0, 1.0, 1.0), 2)}, "preview.bins"),
        ({"preview": Preview(np.ones((4, 4, 4), int), (1.0, 0.0, 1.0), 2)}, "preview.spacing"),
        ({"directions": np.eye(4)}, "directions"),
        ({"directions": np.diag([1.0, np.nan, 1.0])}, "directions"),
        ({"directions": np.array([[1.0, 1.0, 0], [0, 0, 0], [0, 0, 1.0]])}, "directions"),  # i and j the same
        ({"directions": np.diag([1.0, 0.0, 1.0])}, "directions"),
    ],
)
def test_bad_input_raises_one_clear_error(change, message):
    arguments = {
        "preview": Preview(np.ones((4, 4, 4), dtype=np.uint8), (1.0, 1.0, 1.0), 2),
        "bin_colors": np.ones((2, 3)),
        "bin_opacity": np.array([0.0, 0.5]),
        "unit_distance": 1.0,
    }
    arguments.update(change)
    with pytest.raises(ValueError, match=message):
        render_thumbnail(**arguments)


def test_ray_visibility_rejects_bad_views_and_unit_distances():
    preview = Preview(np.ones((4, 4, 4), dtype=np.uint8), (1.0, 1.0, 1.0), 2)
    with pytest.raises(ValueError, match="unknown view"):
        ray_visibility(preview, np.ones(2), unit_distance=1.0, views=("anterior", "sideways"))
    with pytest.raises(ValueError, match="sequence of view names"):
        ray_visibility(preview, np.ones(2), unit_distance=1.0, views="anterior")
    with pytest.raises(ValueError, match="unit_distance"):
        ray_visibility(preview, np.ones(2), unit_distance=0.0)
