"""The whole pipeline and class editing, without recomputation."""

import json

import numpy as np
import pytest

from IsoSimilarityTFLib import ClusteringError, TransferFunctionDesign, design_transfer_function, quantize
from IsoSimilarityTFLib.classes import build_classes, runs
from isosimtf.phantom import head_phantom


@pytest.fixture(scope="module")
def phantom():
    return head_phantom(48, seed=1)


@pytest.fixture()
def design(phantom):
    return design_transfer_function(phantom.values, phantom.spacing)


def test_pipeline_on_the_phantom(design, phantom):
    assert design.n_bins == 256 and design.value_range == (float(phantom.values.min()), float(phantom.values.max()))
    assert design.clustering["converged"] and design.clustering["n_classes"] == len(design.classes) > 3
    assert set(design.timings_s) == {"quantize", "similarity", "clustering", "classes", "tissues"}
    assert design.labels.shape == (256,) and design.similarity.shape == (256, 256)
    # Ranks are a permutation ordered by voxel count; fractions sum to one.
    ranks = sorted(design.classes, key=lambda c: c.rank)
    assert [c.rank for c in ranks] == list(range(1, len(ranks) + 1))
    assert all(a.voxels >= b.voxels for a, b in zip(ranks, ranks[1:]))
    assert sum(c.voxels for c in design.classes) == phantom.values.size
    assert sum(c.fraction for c in design.classes) == pytest.approx(1.0)
    # The background is the largest class, hidden, and it is the air around the head.
    background = design.background_class
    assert background.rank == 1 and not background.visible and background.opacity == 0.0
    assert any(low <= -1000 < high for low, high in background.value_ranges)
    # Noise specks in the air (below and just above the air class) touch the background: hidden by default.
    below_air = [c for c in design.classes if c.exemplar_bin < background.exemplar_bin]
    assert below_air and all(c.background_contact > 0.5 and not c.visible for c in below_air)
    # Bone and soft tissue are shown; bone, the densest, is the most opaque shown class; soft tissue nearly clear.
    assert design.kind == "ct"
    shown = [c for c in design.classes if c.visible]
    assert any(low <= 60 < high for c in shown for low, high in c.value_ranges)
    assert any(low <= 1000 < high for c in shown for low, high in c.value_ranges)
    densest = max(shown, key=lambda c: c.exemplar_bin)
    assert densest.opacity == max(c.opacity for c in shown) >= 0.5
    soft = next(c for c in design.classes if any(low <= 60 < high for low, high in c.value_ranges))
    assert soft.opacity < 0.05
    # Every bin belongs to exactly one class.
    all_bins = sorted(b for c in design.classes for b in c.isovalue_bins)
    assert all_bins == list(range(256))


def test_max_classes_limits_what_is_shown(phantom):
    design = design_transfer_function(phantom.values, max_classes=2, tissues="all")
    shown = [c for c in design.classes if c.visible]
    candidates = sorted(c.rank for c in design.classes if not c.background and c.background_contact <= 0.5)
    # The two largest, plus the densest real class, which is always shown.
    assert sorted(c.rank for c in shown)[:2] == candidates[:2] and len(shown) <= 3
    total = sum(c.voxels for c in design.classes if not c.background)
    densest_real = max((c for c in design.classes if not c.background and c.voxels >= 0.01 * total), key=lambda c: c.id)
    assert densest_real.visible


def test_background_rules(phantom):
    lowest = design_transfer_function(phantom.values, background="lowest").background_class
    assert lowest.isovalue_bins[0] == 0
    none = design_transfer_function(phantom.values, background="none")
    assert none.background_class is None and sum(c.visible for c in none.classes) == min(15, len(none.classes))
    assert all(c.background_contact == 0.0 for c in none.classes)


def bin_centres(design):
    """Bin centres from the value range alone (not from ``design.edges``, which a bug could move)."""
    low, high = design.value_range
    return low + (np.arange(design.n_bins) + 0.5) * (high - low) / design.n_bins


def test_transfer_function_shows_class_looks_at_bin_centres(design):
    tf = design.transfer_function()
    assert np.all(np.diff(tf.x) > 0)
    color, opacity = tf(bin_centres(design))
    width = int(round(design.hierarchy.noise_sd))
    for c in design.classes:
        if c.visible:  # a hidden class takes its nearest shown neighbour's colour, so no hidden colour bleeds in
            np.testing.assert_allclose(color[c.isovalue_bins], np.tile(c.color, (len(c.isovalue_bins), 1)))
            # Its own opacity, but where a boundary ramp climbs into it (at most `width` bins from its ends).
            assert np.all(opacity[c.isovalue_bins] <= c.opacity + 1e-12) and np.all(opacity[c.isovalue_bins] > 0)
            inner = c.isovalue_bins[width:-width] if len(c.isovalue_bins) > 2 * width else []
            np.testing.assert_allclose(opacity[inner], c.opacity)
        else:
            np.testing.assert_array_equal(opacity[c.isovalue_bins], 0.0)
    hidden = [b for c in design.classes if not c.visible for b in c.isovalue_bins]
    shown = [b for c in design.classes if c.visible for b in c.isovalue_bins]
    for b in hidden:
        nearest = min(shown, key=lambda s: abs(s - b))
        np.testing.assert_allclose(color[b], color[nearest])


def test_editing_changes_only_that_class(design):
    before_color, before_opacity = design.transfer_function()(bin_centres(design))
    similarity = design.similarity
    target = next(c for c in design.classes if c.visible and len(c.isovalue_bins) > 6)
    design.set_class(target.id, color=(0.1, 0.2, 0.3), opacity=0.33)
    after_color, after_opacity = design.transfer_function()(bin_centres(design))
    changed = (after_opacity != before_opacity) | (np.any(after_color != before_color, axis=1) & (after_opacity > 0))
    # The colour changes on the class's bins only; the opacity also on the boundary ramps next to it.
    colour_changed = np.any(after_color != before_color, axis=1) & (after_opacity > 0)
    assert list(np.flatnonzero(colour_changed)) == target.isovalue_bins
    width = int(round(design.hierarchy.noise_sd))
    first, last = target.isovalue_bins[0], target.isovalue_bins[-1]
    assert all(first - width <= b <= last + width for b in np.flatnonzero(changed))
    middle = (first + last) // 2
    assert after_opacity[middle] == pytest.approx(0.33)
    assert design.similarity is similarity  # nothing recomputed

    design.set_class(target.id, visible=False)
    assert np.all(design.transfer_function()(design.edges[target.isovalue_bins[0]] + 0.1)[1] == 0)


def test_solo_show_all_and_reset(design):
    target = next(c for c in design.classes if c.visible and c.rank > 2)
    design.solo(target.id)
    _, opacity = design.bin_looks()
    assert set(np.flatnonzero(opacity)) == set(target.isovalue_bins)
    design.solo(None)
    design.set_class(target.id, color=(1, 1, 1), visible=False)
    design.show_all()
    assert all(c.visible != c.background for c in design.classes) and design.solo_class is None
    design.reset_look()
    assert target.color != [1.0, 1.0, 1.0]


def test_bad_edits_are_rejected(design):
    with pytest.raises(KeyError):
        design.set_class(999, opacity=0.5)
    with pytest.raises(ValueError, match="color"):
        design.set_class(0, color=(2, 0, 0))
    with pytest.raises(ValueError, match="opacity"):
        design.set_class(0, opacity=-0.1)


def test_json_round_trip_keeps_classes_and_tf(design):
    design.set_class(design.classes[-1].id, color=(0.5, 0.25, 1.0))
    design.solo(design.classes[-1].id)
    data = json.loads(design.to_json())
    for key in ("value_range", "n_bins", "options", "timings_s", "clustering", "labels", "classes"):
        assert key in data
    for key in ("n_iter", "converged", "n_classes"):
        assert key in data["clustering"]
    assert set(data["classes"][0]) >= {
        "id", "rank", "voxels", "fraction", "isovalue_bins", "value_ranges", "exemplar_bin", "color", "opacity",
        "visible", "background",
    }  # fmt: skip
    back = TransferFunctionDesign.from_json(design.to_json())
    np.testing.assert_array_equal(back.transfer_function().x, design.transfer_function().x)
    np.testing.assert_array_equal(back.transfer_function().opacity, design.transfer_function().opacity)
    assert back.solo_class == design.solo_class and back.spacing == design.spacing
    with pytest.raises(ValueError, match="not a valid"):
        TransferFunctionDesign.from_json('{"n_bins": 3}')
    with pytest.raises(ValueError, match="not a valid"):
        TransferFunctionDesign.from_json("[")


def test_quantized_input_and_progress(phantom):
    stages = []
    q = quantize(phantom.values, 64)
    design = design_transfer_function(q, progress=lambda stage, fraction, message: stages.append(stage))
    assert design.n_bins == 64 and design.options["n_bins"] == 64
    assert stages[0] == "quantize" and stages[-1] == "tissues" and "similarity" in stages and "clustering" in stages


def test_cancel_from_progress(phantom):
    class Cancelled(Exception):
        pass

    def cancel(stage, fraction, message):
        if stage == "similarity" and fraction > 0:
            raise Cancelled

    with pytest.raises(Cancelled):
        design_transfer_function(phantom.values, progress=cancel)


def test_cancel_between_affinity_propagation_iterations(phantom):
    """Slicer's in-process Apply cancels by raising from progress: in the clustering stage that stops affinity
    propagation after the iteration that reported, not at the end of the stage."""

    class Cancelled(Exception):
        pass

    reports = []

    def cancel(stage, fraction, message):
        reports.append((stage, message))
        if stage == "clustering" and fraction > 0:  # an iteration's report, not the stage's start
            raise Cancelled

    # 512 bins: a report every 7 iterations (see design._clustering_progress).
    with pytest.raises(Cancelled) as raised:
        design_transfer_function(phantom.values, n_bins=512, progress=cancel)
    stage, message = reports[-1]
    # Iteration 7 of 200: mid-run, as convergence takes at least convergence_iter + 1 = 16 iterations.
    assert stage == "clustering" and message.startswith("affinity propagation: iteration 7 of at most 200")
    assert "affinity_propagation" in [frame.name for frame in raised.traceback]


def test_unconverged_rules():
    grid = np.indices((20, 20, 20)).astype(float)
    r = np.sqrt(((grid - 10) ** 2).sum(axis=0))
    values = np.select([r < 3, r < 6, r < 8], [200, 140, 80], 20) + np.random.default_rng(0).normal(0, 4, r.shape)
    with pytest.raises(ClusteringError, match="did not converge"):
        design_transfer_function(values, unconverged="error", max_iter=50)
    kept = design_transfer_function(values, unconverged="keep", max_iter=50)
    assert not kept.clustering["converged"]
    raised = design_transfer_function(values)
    assert raised.clustering["converged"] and raised.clustering["damping"] > 0.5
    assert raised.clustering["max_iter"] > 200 and raised.clustering["convergence_iter"] > 15


def test_a_few_values_over_many_bins_are_clustered_on_the_distinct_isovalues():
    # The head phantom clipped at 0 HU in 62.5-HU steps, then exported to 8 bits through an auto-contrast window: 5
    # values 64 bins apart. The bins between them repeat an isovalue up to 63 times, and AP on every isovalue did not
    # converge at any damping (the design raised); on the distinct ones it does, and the tissues get classes.
    steps = np.round(np.clip(head_phantom(48, seed=0).values, 0, None) / 62.5)
    low, high = np.percentile(steps, [0.5, 99.5])
    stored = np.round(np.clip((steps - low) / (high - low), 0, 1) * 255).astype(np.uint8)
    assert np.unique(stored).size == 5
    design = design_transfer_function(stored)
    assert design.clustering["converged"] and design.clustering["distinct"]
    assert len(design.classes) >= 3 and any(design.is_shown(c.id) for c in design.classes)
    with pytest.raises(ClusteringError, match="then on the distinct ones"):
        design_transfer_function(stored, max_iter=2, convergence_iter=2)
    # Where AP on every isovalue converges, that is the design (the thesis'): the distinct ones are a fallback.
    assert design_transfer_function(head_phantom(48, seed=0).values).clustering["distinct"] is False


def test_bad_options():
    values = np.arange(27).reshape(3, 3, 3)
    with pytest.raises(TypeError, match="unknown option"):
        design_transfer_function(values, bins=12)
    with pytest.raises(ValueError, match="unconverged"):
        design_transfer_function(values, unconverged="ignore")
    with pytest.raises(ValueError, match="spacing"):
        design_transfer_function(values, spacing=(1, 0, 1))
    with pytest.raises(ValueError, match="background"):
        design_transfer_function(values, background="smallest")


def test_build_classes_ranks_and_background():
    labels = np.array([0, 0, 1, 1, 1, 2, 3, 3])
    classes = build_classes(labels, np.array([0, 3, 5, 6]), np.array([50, 40, 1, 1, 1, 9, 0, 3]), np.arange(9.0))
    assert [c.rank for c in classes] == [1, 3, 2, 4]
    assert classes[0].background and not any(c.background for c in classes[1:])
    assert classes[1].value_ranges == [[2.0, 5.0]]
    assert runs(np.array([1, 2, 3, 7, 9, 10])) == [(1, 3), (7, 7), (9, 10)]


def test_python_api_takes_what_a_user_types_or_says_why(phantom):
    """Issue 18, item 14: one number is an isotropic spacing, a preference in any letter case is taken, and a
    visibility that is not a bool is refused (bool("no") is True)."""
    from IsoSimilarityTFLib import cluster_isovalues, similarity_matrix

    values = phantom.values[::4, ::4, ::4]
    assert design_transfer_function(values, 2.0).spacing == (2.0, 2.0, 2.0)
    with pytest.raises(ValueError, match="spacing"):
        design_transfer_function(values, "2 mm")
    similarity = similarity_matrix(quantize(values, 32).bins, 32)
    assert cluster_isovalues(similarity, preference="MEDIAN").n_classes == cluster_isovalues(similarity).n_classes
    design = design_transfer_function(values)
    with pytest.raises(ValueError, match="visible"):
        design.set_class(1, visible="no")
    design.set_class(1, visible=False)
    assert not design.classes[1].visible


# Design texts read back: checked as the API checks its arguments (issue 26) -----------------------------------------


def _edited(design, edit) -> str:
    document = design.to_dict()
    edit(document)
    return json.dumps(document)


def _set(path, value):
    def edit(document):
        target = document
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return edit


@pytest.mark.parametrize(
    "path, value, reason",
    [
        (("classes", 1, "opacity"), 7.0, "opacity must be a number in"),
        (("classes", 1, "opacity"), "0.5", "opacity must be a number in"),
        (("tissues", 0, "opacity"), True, "opacity must be a number in"),
        (("classes", 1, "color"), [True, 0.5, 0.5], "color must be a number in"),
        (("labels", 0), True, "labels must be class ids"),
        (("classes", 1, "color"), [0.5, 5.0, 0.5], "color must be a number in"),
        (("classes", 1, "visible"), "no", "visible must be true or false"),
        (("tissues", 0, "visible"), 1, "visible must be true or false"),
        (("tissues", 0, "opacity"), -0.5, "opacity must be a number in"),
        (("classes", 1, "voxels"), -4, "voxel counts cannot be negative"),
        (("value_range",), [100.0, -100.0], "low < high"),
        (("value_range",), [3.0, 3.0], "low < high"),
        (("spacing",), [1.0, 0.0, 1.0], "spacing must be"),
        (("solo_class",), 999, "no class 999"),
        (("solo_tissue",), True, "a tissue id is an integer"),
        (("options", "damping"), 0.1, "damping"),
        (("kind",), "pet", "kind must be one of"),
        (("voxel_noise_sd",), -1.0, "voxel_noise_sd must be"),
        (("voxel_noise_sd",), "3", "voxel_noise_sd must be"),
    ],
)
def test_an_invalid_design_text_is_refused_in_one_line(design, path, value, reason):
    with pytest.raises(ValueError, match="not a valid IsoSimilarityTF design") as refused:
        TransferFunctionDesign.from_json(_edited(design, _set(path, value)))
    assert reason in str(refused.value) and "\n" not in str(refused.value)


def test_the_unedited_design_text_is_accepted(design):
    assert TransferFunctionDesign.from_json(_edited(design, lambda document: None)).to_dict() == design.to_dict()


def test_the_voxels_noise_is_saved_with_the_design_and_absent_from_older_texts(design):
    assert design.voxel_noise_sd is not None and design.voxel_noise_sd > 0
    assert TransferFunctionDesign.from_json(design.to_json()).voxel_noise_sd == design.voxel_noise_sd
    older = TransferFunctionDesign.from_json(_edited(design, lambda document: document.pop("voxel_noise_sd")))
    assert older.voxel_noise_sd is None and older.looks  # a design saved before: the dense rule's old width


@pytest.mark.parametrize(
    "text",
    [
        '{"n_bins": NaN}',
        '{"n_bins": 1e400}',
        '{"n_bins": 256, "labels": [' + "2" * 30 + "]}",  # an integer beyond int64
        "[" * 100_000 + "]" * 100_000,  # deeper than the parser's recursion
        '"a string"',
    ],
)
def test_hostile_numbers_and_nesting_are_one_line_not_a_crash(text):
    with pytest.raises(ValueError, match="not a valid IsoSimilarityTF design"):
        TransferFunctionDesign.from_json(text)


def test_a_preview_that_inflates_beyond_its_shape_is_refused_without_inflating(design):
    import base64
    import zlib

    bomb = base64.b64encode(zlib.compress(b"\0" * (1 << 28), 9)).decode()  # 256 MiB of zeros in 256 KB
    text = _edited(design, _set(("preview", "bins"), bomb))
    with pytest.raises(ValueError, match="the preview does not match its shape"):
        TransferFunctionDesign.from_json(text)


def test_a_boolean_is_no_id(design):
    edited = TransferFunctionDesign.from_json(design.to_json())
    with pytest.raises(KeyError, match="a tissue id is an integer"):
        edited.set_tissue(True, opacity=0.5)
    with pytest.raises(KeyError, match="a class id is an integer"):
        edited.set_class(False, opacity=0.5)
