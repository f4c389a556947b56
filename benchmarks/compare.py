"""First-click benchmark (issue 9): our default transfer function against Slicer's own first click and presets.

Usage::

    make compare                                  # or: .venv/bin/python benchmarks/compare.py
    make compare PRESETS=/path/to/presets.xml     # Slicer's presets.xml from elsewhere

For each volume (the built-in phantom, with ground-truth tissue labels; the InVesalius head CT; the Colin27 T1 with
scalp; the skull-stripped Colin27) and each view (anterior, left), one headless Slicer (real MRML scene, Slicer's
volume rendering logic with Slicer's presets.xml loaded, CPU ray casting, black backdrop) renders:

- **ours**: ``design_transfer_function(values, spacing)`` with its defaults, shown through ``mrml.apply_design``;
- **ours, best look**: where the volume has labels, the look of our gallery whose picture shows most of what the
  user scanned for (``add_best_look``), when it is not the first click; on a volume with a kept preset, every look
  of the gallery (``add_gallery_looks``), each judged against that preset;
- **Slicer's first click**: the property ``vtkSlicerVolumeRenderingLogic::CreateDefaultVolumeRenderingNodes``
  gives a new volume: ``UpdateDisplayNodeFromVolumeNode`` (a ramp from the volume's window/level), then
  ``SetRecommendedVolumeRenderingProperties``, which copies a preset unchanged: "US-Fetal" for 8-bit data, else
  "MR-Default" for a value range of 50-1500, "CT-Chest-Contrast-Enhanced" for 1500-10000;
- **the best-suited presets** (CT-AAA and CT-Bone for CT, MR-Default for MRI), applied as the module's preset menu
  does (``qSlicerVolumeRenderingPresetComboBox::applyPreset``): ``CopyContent`` of the preset node into the shown
  property node, the shift slider reset to 0. Slicer does not move a preset to the volume's range; the user can
  drag the shift slider. So the presets are rendered unshifted, at their own (absolute) values.

All looks of one view share one camera: fitted to the volume (Slicer's reset), then narrowed onto the union of what
the looks show (a quarter-size probe render of each), so the head fills the pictures with a small margin.

Measures (``picture_metrics``): brightness, colour noise, coverage over the foreground (pixels that differ from the
backdrop). On the phantom, per tissue: share of the picture and visibility (``tissue_visibility``). With GPU ray
casting available, each transfer function is also rendered once by the GPU ray caster with VTK's messages captured,
to record whether it triggers the lookup-table fallback warning.

Outputs in ``benchmarks/results/``: ``pictures/compare-<volume>.png`` (rows = views, columns = looks, labelled; the
pictures folder is not committed: regenerated pictures would grow the repository at every run),
``compare.md`` and ``compare.json``. ``--backdrop slicer`` renders on Slicer's blue gradient instead (outputs named
``compare-slicer*``, ``compare-<volume>-slicer.png``): good for looking, but the metrics then mix translucent haze
with the light backdrop (a hazy transfer function looks brighter), so the committed numbers use black.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from picture_metrics import picture_metrics, resize_area  # noqa: E402
from slicer_presets import ATTRIBUTION, PresetsNotFound, PresetsSource, find_presets, read_presets  # noqa: E402
from tissue_visibility import (  # noqa: E402
    partial_volume_labels,
    property_functions,
    ray_axis,
    tissue_summary,
    tissue_weights,
)
from volume_panel import HEAD_CT, PANEL, Kept, PanelVolume, ct_storage  # noqa: E402

REPO = HERE.parent
RESULTS = HERE / "results"
#: Regenerated pictures: written here, never committed (see .gitignore).
PICTURES = RESULTS / "pictures"
VIEWS = ("anterior", "left")
OURS = "ours"
FIRST_CLICK = "first click"
#: The preset a user would keep on a real volume of the shared panel, with its shift (its README's reading).
KEPT = "kept"
#: The look of our gallery that shows most of what the user scanned for, where it is not the first click.
BEST_LOOK = "best look"
#: Columns of every look of our gallery on a volume with a kept preset: ``look: <name>``.
GALLERY_LOOK = "look: "

#: The issue's targets, against the best-suited preset of each volume and view.
MAX_NOISE_RATIO = 1.3
MIN_BRIGHTNESS_RATIO = 0.8
#: Against a kept preset, the picture must also cover at least this share of the area the kept one covers: a share
#: of the picture says how pure it is, not how much of the structure it shows (a plume's core alone is 100% plume).
MIN_COVERAGE_RATIO = 0.8
#: A picture whose colour noise is at most this (chroma units) is grey (Slicer's window/level ramp measures 1e-16,
#: the rounding of the chroma matrix): no colour-noise ratio is taken over it.
GREY_NOISE = 0.01

CT_PRESETS = ("CT-AAA", "CT-Bone")
MR_PRESETS = ("MR-Default",)


#: The phantom's noise (HU) and blur (mm): ``head_phantom``'s defaults, which ``isosimtf phantom`` uses.
PHANTOM_NOISE_HU, PHANTOM_BLUR_MM = 20.0, 1.0


def _phantom() -> tuple:
    from isosimtf.inputs import load_input
    from isosimtf.phantom import TISSUES, head_phantom

    volume = load_input("phantom")
    labels = head_phantom(volume.values.shape[0], seed=0, noise_hu=PHANTOM_NOISE_HU, blur_mm=PHANTOM_BLUR_MM).labels
    return volume.values, volume.ijk_to_ras(), labels, TISSUES, None


def _file(path: str) -> Callable[[], tuple]:
    def load() -> tuple:
        from isosimtf.volume_io import read_volume

        volume = read_volume(path)
        return volume.values, volume.ijk_to_ras(), None, None, None

    return load


COLIN = "/usr/share/mricron/templates/ch2.nii.gz"
COLIN_BET = "/usr/share/mricron/templates/ch2bet.nii.gz"

#: The presets suited to each kind of volume, and the one the targets compare with.
_PRESETS_OF = {
    "CT": (CT_PRESETS, "CT-Bone"),
    "micro-CT": (CT_PRESETS, "CT-Bone"),
    "MRI": (MR_PRESETS, "MR-Default"),
    "angio": (("CT-AAA", "MR-Angio"), "CT-AAA"),
    "industrial": (CT_PRESETS, "CT-Bone"),
    "plant": (CT_PRESETS, "CT-AAA"),
    "simulation": (("CT-AAA", "MR-Default"), "MR-Default"),
}

#: The volumes of the benchmark: the four it began with, then the panel (issue 16: storages, resolutions, other real
#: volumes, synthetic CTA and micro-CT; none was used to set a constant).
CASES: tuple[PanelVolume, ...] = (
    PanelVolume("phantom", "Phantom (CT-like, HU, 128^3)", "CT", _phantom, ("skull",), "air", lambda: True,
                "isosimtf phantom, seed 0"),
    PanelVolume("head-ct", "Head CT (InVesalius Cranium, HU)", "CT", ct_storage("hu"), ("dense",), None,
                lambda: Path(HEAD_CT).is_file(), f"Debian invesalius-examples, {HEAD_CT}"),
    PanelVolume("colin27", "Colin27 T1 with scalp (uint8)", "MRI", _file(COLIN), (), None,
                lambda: Path(COLIN).is_file(), f"Debian mricron-data, {COLIN}"),
    PanelVolume("colin27-bet", "Colin27 T1 skull-stripped (uint8)", "MRI", _file(COLIN_BET), (), None,
                lambda: Path(COLIN_BET).is_file(), f"Debian mricron-data, {COLIN_BET}"),
    *PANEL,
)  # fmt: skip


# ---------------------------------------------------------------------------------------------------------------
# Rendering
# ---------------------------------------------------------------------------------------------------------------


@dataclass
class Look:
    """One transfer function shown for a volume: its column title and its property node."""

    name: str
    title: str
    property_node: Any


def prepare_looks(
    headless: Any,
    volume_node: Any,
    values: np.ndarray,
    spacing,
    presets: Sequence[str],
    storage=None,
    kept: Kept | None = None,
) -> list[Look]:
    """Slicer's first click, ours and the presets as property nodes of one scene (the first click first made).

    ``storage``: ``(slope, offset)`` of a CT stored as ``slope * HU + offset``: the presets are mapped onto the stored
    values (what a user does with the Shift slider, and for 8 bits a rescale too), titled "(mapped)". ``kept``: the
    preset a user would keep and its shift (in HU where there is a ``storage``), added last as :data:`KEPT`.
    """
    from IsoSimilarityTFLib import design_transfer_function
    from IsoSimilarityTFLib.mrml import apply_design

    logic = headless.volume_rendering_logic
    display_node = logic.CreateDefaultVolumeRenderingNodes(volume_node)  # Slicer's first click
    first = display_node.GetVolumePropertyNode()
    picked = first.GetName() if logic.GetPresetByName(first.GetName()) is not None else "window/level ramp"
    first_look = Look(FIRST_CLICK, f"Slicer first click ({picked})", first)
    first_look.picked = picked  # type: ignore[attr-defined]

    design = design_transfer_function(values, spacing)
    ours = Look(OURS, "ours (default)", apply_design(volume_node, design, logic))
    ours.design = design  # type: ignore[attr-defined]

    looks = [ours, first_look]
    mapped = storage is not None and tuple(storage) != (1.0, 0.0)
    for name in presets:
        node = _preset_node(headless, name, 0.0, storage if mapped else None)
        if node is not None:
            looks.append(Look(name, f"{name} (mapped)" if mapped else name, node))
    if kept is not None:
        name, shift = kept
        node = _preset_node(headless, name, shift, storage if mapped else None)
        if node is not None:
            looks.append(Look(KEPT, f"kept: {name}, shift {shift:+g}{' (mapped)' if mapped else ''}", node))
    return looks


def _preset_node(headless: Any, name: str, shift: float, storage=None) -> Any:
    """A property node holding preset ``name`` as the preset menu applies it, moved by the Shift slider's ``shift``
    (volume units, or HU with a ``storage``) and then mapped onto stored values; None if Slicer has no such preset."""
    preset = headless.volume_rendering_logic.GetPresetByName(name)
    if preset is None:
        return None
    node = headless.scene.AddNewNodeByClass("vtkMRMLVolumePropertyNode", name)
    node.CopyContent(preset)  # what the preset menu does (qSlicerVolumeRenderingPresetComboBox::applyPreset)
    if shift:
        map_property(node.GetVolumeProperty(), 1.0, shift)
    if storage is not None:
        map_property(node.GetVolumeProperty(), *storage)
    return node


def _shown_by_look(
    design: Any, values: np.ndarray, labels: np.ndarray, names: Sequence[str], shown_for: Sequence[str]
) -> dict[str, tuple[float, float]]:
    """Per look of the gallery, how much of ``shown_for`` its picture shows (the library's visibility histogram, as
    ``look_panel.py`` measures it): the rounded sum of the structures' shares, then the least of them; the first
    click is left shown."""
    from look_panel import label_fractions, picture_shares

    fractions = label_fractions(values, labels, len(names), design)
    first = design.chosen_look
    shown = {}
    for look in design.looks:
        design.use_look(look.name)
        shares = picture_shares(design, fractions)[1]
        each = [float(shares[list(names).index(n)]) for n in shown_for]
        shown[look.name] = (round(sum(each), 3), min(each))  # then, of equals, the one that shows each structure
    design.use_look(first)
    return shown


def _add_look_column(headless: Any, volume_node: Any, looks: list[Look], look: Any, column: str) -> None:
    """Append ``look`` of the first click's design as a property node of its own, in the column ``column``."""
    design = looks[0].design  # type: ignore[attr-defined]
    node = headless.scene.AddNewNodeByClass("vtkMRMLVolumePropertyNode", f"{volume_node.GetName()} {look.name}")
    node.GetVolumeProperty().DeepCopy(design.volume_property(look))
    node.SetEffectiveRange(*design.value_range)
    looks.append(Look(column, f"ours, {look.name}", node))


def add_best_look(
    headless: Any,
    volume_node: Any,
    looks: list[Look],
    values: np.ndarray,
    labels: np.ndarray | None,
    names: Sequence[str] | None,
    shown_for: Sequence[str],
) -> str | None:
    """Append the look of our gallery whose picture shows most of ``shown_for`` (of equals, the one whose least
    shown structure gets most; see :func:`_shown_by_look`) as its own property node, unless it is the first click;
    return its name (None without labels or when the first click is best)."""
    design = looks[0].design  # type: ignore[attr-defined]
    if labels is None or not names or not shown_for:
        return None
    shown = _shown_by_look(design, values, labels, names, shown_for)
    first = design.chosen_look
    best = max(design.looks, key=lambda look: shown[look.name])
    if shown[best.name] <= shown[first]:
        return None
    _add_look_column(headless, volume_node, looks, best, BEST_LOOK)
    return best.name


def add_gallery_looks(
    headless: Any,
    volume_node: Any,
    looks: list[Look],
    values: np.ndarray,
    labels: np.ndarray,
    names: Sequence[str],
    shown_for: Sequence[str],
) -> list[str]:
    """Append every look of our gallery but the first click, as columns ``look: <name>``, ranked by how much of
    ``shown_for`` each shows (:func:`_shown_by_look`), most first; return their names in that order. Whether *some*
    look keeps up with a kept preset is a question about every look: the one showing most may be the darker."""
    design = looks[0].design  # type: ignore[attr-defined]
    shown = _shown_by_look(design, values, labels, names, shown_for)
    first = design.chosen_look
    others = [look for look in design.looks if look.name != first]
    ranked = sorted(others, key=lambda look: shown[look.name], reverse=True)  # stable: gallery order among equals
    for look in ranked:
        _add_look_column(headless, volume_node, looks, look, GALLERY_LOOK + look.name)
    return [look.name for look in ranked]


def map_property(volume_property: Any, slope: float, offset: float) -> None:
    """Move a volume property's functions from HU to values stored as ``slope * HU + offset``: the scalar opacity
    and colour points by that map, the gradient opacity points (units per mm) by the slope."""
    functions = (
        (volume_property.GetScalarOpacity(), 4, offset),
        (volume_property.GetGradientOpacity(), 4, 0.0),
        (volume_property.GetRGBTransferFunction(), 6, offset),
    )
    for function, size, shift in functions:
        nodes = []
        for index in range(function.GetSize()):
            node = [0.0] * size
            function.GetNodeValue(index, node)
            nodes.append(node)
        function.RemoveAllPoints()  # re-added in order: moving points one by one would pass their neighbours
        for x, *rest in nodes:
            if size == 4:
                function.AddPoint(x * slope + shift, rest[0], rest[1], rest[2])
            else:
                function.AddRGBPoint(x * slope + shift, *rest)


def show(headless: Any, volume_node: Any, look: Look) -> None:
    """Point the volume's display node at ``look``'s property node."""
    display_node = headless.volume_rendering_logic.GetFirstVolumeRenderingDisplayNode(volume_node)
    display_node.SetAndObserveVolumePropertyNodeID(look.property_node.GetID())


def render_view(headless: Any, volume_node: Any, looks: list[Look], view: str, size: int) -> dict[str, np.ndarray]:
    """Render every look from ``view`` with one camera framed onto the union of what they show."""
    from isosimtf.rendering import content_box, frame_content

    probe = max(64, size // 4)
    headless.render_window.SetSize(probe, probe)
    backdrop = headless.backdrop()
    boxes, picture = [], None
    for index, look in enumerate(looks):
        show(headless, volume_node, look)
        picture = headless.render(view if index == 0 else None, reset_camera=index == 0)
        box = content_box(picture, backdrop)
        if box is not None:
            boxes.append(box)
    if boxes and picture is not None:
        union = (min(b[0] for b in boxes), max(b[1] for b in boxes), min(b[2] for b in boxes), max(b[3] for b in boxes))
        frame_content(headless.camera_node.GetCamera(), picture, box=union)
    headless.render_window.SetSize(size, size)
    pictures = {}
    for look in looks:
        show(headless, volume_node, look)
        pictures[look.name] = headless.render(None, reset_camera=False)
    return pictures


def gpu_lookup_table_check(values: np.ndarray, ijk_to_ras: np.ndarray, looks: list[Look], presets_file: Path) -> dict:
    """Render each look once with GPU ray casting (small picture), VTK's messages captured.

    Returns per look name: ``{"fallback": bool, "messages": [...]}``, or ``{"error": text}`` when GPU ray casting
    is not available.
    """
    from isosimtf.rendering import HeadlessSlicer, captured_vtk_messages, lookup_table_fallbacks

    result: dict[str, Any] = {}
    try:
        with HeadlessSlicer(size=(128, 128), rendering_method="gpu", presets_file=presets_file) as gpu:
            node = gpu.add_volume(values, ijk_to_ras=ijk_to_ras)
            for look in looks:
                copy = gpu.scene.AddNewNodeByClass("vtkMRMLVolumePropertyNode", look.name)
                copy.CopyContent(look.property_node)
                gpu.show_volume(node, copy)
                with captured_vtk_messages() as messages:
                    gpu.render("anterior")
                fallbacks = lookup_table_fallbacks(messages)
                result[look.name] = {"fallback": bool(fallbacks), "messages": fallbacks[:2]}
    except RuntimeError as error:
        return {"error": str(error)}
    return result


# ---------------------------------------------------------------------------------------------------------------
# Montage
# ---------------------------------------------------------------------------------------------------------------

MONTAGE_BACKGROUND = (40, 40, 40)
HEADER_TEXT = (235, 235, 235)
GOOD, BAD = (120, 220, 120), (240, 120, 110)


def metric_line(metrics: dict, share: float | None = None) -> str:
    """``B 112 | N 3.4 | C 41% | V 64%``: brightness, colour noise, coverage, and the share of the picture from what
    the user scanned for when the volume says what that is."""
    line = f"B {metrics['brightness']:.0f} | N {metrics['colour_noise']:.2f} | C {100 * metrics['coverage']:.0f}%"
    return line if share is None else f"{line} | V {100 * share:.0f}%"


def montage(
    title: str,
    pictures: dict[tuple[str, str], np.ndarray],
    metrics: dict[tuple[str, str], dict],
    views: Sequence[str],
    columns: Sequence[tuple[str, str]],
    tile: int = 384,
    shares: dict[tuple[str, str], float] | None = None,
) -> np.ndarray:
    """A labelled grid: one row per view, one column per look (``(name, title)``), metrics under each tile (and
    ``shares``, the share of each picture from what the user scanned for, when given)."""
    from isosimtf.figures import draw_text

    gap, left, head, foot, top = 6, 84, 26, 22, 34
    width = left + len(columns) * (tile + gap) + gap
    height = top + head + len(views) * (tile + foot + gap) + gap
    image = np.empty((height, width, 3), dtype=np.uint8)
    image[:] = MONTAGE_BACKGROUND
    draw_text(image, title, 8, 8, 18, HEADER_TEXT)
    for column, (_, label) in enumerate(columns):
        draw_text(image, label, left + column * (tile + gap) + 4, top + 4, 15, HEADER_TEXT)
    for row, view in enumerate(views):
        y = top + head + row * (tile + foot + gap)
        draw_text(image, view, 8, y + tile // 2 - 8, 16, HEADER_TEXT)
        for column, (name, _) in enumerate(columns):
            x = left + column * (tile + gap)
            picture = pictures.get((view, name))
            if picture is None:
                continue
            image[y : y + tile, x : x + tile] = resize_area(picture, tile, tile)
            line = metric_line(metrics[(view, name)], (shares or {}).get((view, name)))
            draw_text(image, line, x + 4, y + tile + 3, 13, HEADER_TEXT)
    return image


# ---------------------------------------------------------------------------------------------------------------
# Run
# ---------------------------------------------------------------------------------------------------------------


def ratio(ours: float, reference: float, floor: float = 0.0) -> float | None:
    """``ours / reference``, None when the reference is at most ``floor`` (0, or :data:`GREY_NOISE`)."""
    return float(ours / reference) if reference > floor else None


def verdict(brightness_ratio: float | None, noise_ratio: float | None) -> bool:
    """Whether a picture meets the issue's targets (brightness >= 0.8x, colour noise <= 1.3x the best preset's)."""
    if brightness_ratio is None or noise_ratio is None:
        return False
    return brightness_ratio >= MIN_BRIGHTNESS_RATIO and noise_ratio <= MAX_NOISE_RATIO


def run_case(case: PanelVolume, presets: PresetsSource, size: int, gpu: bool, backdrop: str = "black") -> dict:
    """Render and measure one volume; write its montage; return its numbers.

    Args:
        backdrop: "black" or "slicer" (Slicer's gradient; the montages are then named ``compare-<key>-slicer.png``).
    """
    from isosimtf.rendering import HeadlessSlicer, write_png

    started = time.perf_counter()
    values, ijk_to_ras, labels, tissues, storage = case.load()
    suited, best = _PRESETS_OF[case.kind]
    spacing = tuple(float(s) for s in np.linalg.norm(np.asarray(ijk_to_ras)[:3, :3], axis=0))
    pictures: dict[tuple[str, str], np.ndarray] = {}
    background = (0.0, 0.0, 0.0) if backdrop == "black" else None
    with HeadlessSlicer(size=(size, size), presets_file=presets.path, background=background) as headless:
        volume_node = headless.add_volume(values, name=case.key, ijk_to_ras=ijk_to_ras)
        looks = prepare_looks(headless, volume_node, values, spacing, suited, storage, case.kept)
        gallery: list[str] = []
        if case.kept and labels is not None and tissues and case.shown_for:
            gallery = add_gallery_looks(headless, volume_node, looks, values, labels, tissues, case.shown_for)
            best_look = gallery[0] if gallery else None
        else:
            best_look = add_best_look(headless, volume_node, looks, values, labels, tissues, case.shown_for)
        for view in VIEWS:
            for name, picture in render_view(headless, volume_node, looks, view, size).items():
                pictures[(view, name)] = picture
        gpu_check = gpu_lookup_table_check(values, ijk_to_ras, looks, presets.path) if gpu else {"skipped": True}
        design = looks[0].design  # type: ignore[attr-defined]
        if labels is None:  # no ground truth: our own tissues, as the design groups them
            labels, tissues = design_tissue_labels(design, values)
        tissue_stats = tissue_statistics(
            values, ijk_to_ras, labels, tissues, looks, spacing, partial_volume=case.key == "phantom"
        )
        picked = looks[1].picked  # type: ignore[attr-defined]
        columns = [(look.name, look.title) for look in looks]
        empty = headless.backdrop()
    metrics = {key: picture_metrics(picture, empty) for key, picture in pictures.items()}
    PICTURES.mkdir(parents=True, exist_ok=True)
    montage_path = PICTURES / f"compare-{case.key}{'' if backdrop == 'black' else '-' + backdrop}.png"
    shares = {
        (view, name): sum(tissue_stats[view][name][t]["share"] for t in case.shown_for)
        for view in VIEWS
        for name, _ in columns
    } if case.shown_for else {}  # fmt: skip
    write_png(montage(case.title, pictures, metrics, VIEWS, columns, shares=shares), montage_path)

    comparisons = {}
    for view in VIEWS:
        ours = metrics[(view, OURS)]
        per_reference = {}
        for name, _ in columns[1:]:
            reference = metrics[(view, name)]
            b, n = (
                ratio(ours["brightness"], reference["brightness"]),
                ratio(ours["colour_noise"], reference["colour_noise"], GREY_NOISE),
            )
            per_reference[name] = {"brightness_ratio": b, "colour_noise_ratio": n, "pass": verdict(b, n)}
        comparisons[view] = per_reference
    return {
        "title": case.title,
        "kind": case.kind,
        "source": case.source,
        "shape": list(values.shape),
        "dtype": str(values.dtype),
        "value_range": [float(values.min()), float(values.max())],
        "spacing": list(spacing),
        "first_click_preset": picked,
        "best_preset": best,
        "best_look": best_look,
        "gallery_looks": gallery,
        "looks": [{"name": n, "title": t} for n, t in columns],
        "design": {
            "n_classes": len(design.classes),
            "n_shown": sum(1 for c in design.classes if design.is_shown(c.id)),
            "options": {k: v for k, v in design.options.items() if isinstance(v, (str, int, float, type(None)))},
        },
        "metrics": {view: {name: metrics[(view, name)] for name, _ in columns} for view in VIEWS},
        "ratios": comparisons,
        "tissues": tissue_stats,
        "shown_for": list(case.shown_for),
        "kept": list(case.kept) if any(name == KEPT for name, _ in columns) else None,  # Slicer has that preset
        "fog": case.fog,
        "kind_detected": design.kind,
        "gpu_lookup_table": gpu_check,
        "montage": montage_path.relative_to(REPO).as_posix(),
        "seconds": round(time.perf_counter() - started, 1),
    }


def design_tissue_labels(design: Any, values: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
    """Each voxel's tissue in our design (``tissue <id>``, the background ``background``): what the picture of a
    volume without ground truth is made of."""
    from IsoSimilarityTFLib import quantize

    bins = quantize(values, design.n_bins, design.value_range).bins
    tissue_of_bin = design.tissue_of_class[design.labels]
    names = tuple("background" if t.background else f"tissue {t.id}" for t in design.tissues)
    return tissue_of_bin[bins].astype(np.uint8), names


def tissue_statistics(
    values, ijk_to_ras, labels, tissues, looks: list[Look], spacing, partial_volume: bool = False
) -> dict:
    """Per view and look: each tissue's share of the picture and visibility (``tissue_visibility``).

    ``partial_volume`` (the phantom, whose tissue values and blur are known): samples are attributed with partial
    volume accounted for, 3 noise sigma of tolerance, the blur's 3-sigma reach; otherwise to their own label.
    """
    attribution = None
    if partial_volume:
        from isosimtf.phantom import TISSUE_HU

        radius = int(np.ceil(3.0 * PHANTOM_BLUR_MM / min(spacing)))
        attribution = partial_volume_labels(values, labels, TISSUE_HU, 3.0 * PHANTOM_NOISE_HU, radius)
    result: dict[str, dict] = {}
    for view in VIEWS:
        axis, reverse = ray_axis(ijk_to_ras, view)
        result[view] = {}
        for look in looks:
            opacity, gradient, unit = property_functions(look.property_node.GetVolumeProperty())
            weights, crosses = tissue_weights(
                values, labels, len(tissues), opacity, spacing, axis, reverse, unit, gradient, attribution
            )
            result[view][look.name] = tissue_summary(weights, crosses, tissues)
    return result


# ---------------------------------------------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------------------------------------------


def _fmt(value: float | None, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def markdown(document: dict) -> str:
    """compare.md: settings, per-volume metrics and ratios with pass/fail, phantom tissues, GPU warnings."""
    lines = [
        "# First click: ours against Slicer's first click and presets",
        "",
        f"Made by `make compare` on {document['date']} ({document['seconds']:.0f} s; {document['renderer']}). "
        f"Pictures {document['size']}x{document['size']}, {document['backdrop']} backdrop, one camera per volume and "
        "view (fitted, then narrowed onto the union of what all looks show). GPU LUT fallback: whether VTK's GPU ray "
        "caster logs that the transfer function needs a lookup table wider than the OpenGL texture limit (table width "
        "asked > limit) and cuts it (one 128x128 GPU render per transfer function, VTK's messages captured).",
        "",
        f"{ATTRIBUTION} Source used: {document['presets_source']}.",
        "",
        "Metrics over the foreground (pixels that differ from the backdrop): **B** brightness = mean BT.601 luma "
        "(0-255); **N** colour noise = mean |(Cb, Cr) - its 5x5 local mean| (0-255 chroma units); **C** coverage = "
        "foreground share of the picture. Targets (issue 9): N <= 1.3x and B >= 0.8x those of the best-suited "
        "preset, on every volume and view.",
        "",
        "Slicer's first click = `CreateDefaultVolumeRenderingNodes` (window/level ramp, then "
        "`SetRecommendedVolumeRenderingProperties`: US-Fetal for 8-bit data, MR-Default for a range of 50-1500, "
        "CT-Chest-Contrast-Enhanced for 1500-10000). Presets are applied as Slicer's preset menu does (`CopyContent`, "
        "shift 0): Slicer does not move a preset to the volume's range. The kept preset of a real volume is shifted "
        "as its reading says (the module's Shift slider).",
        "",
        "## Summary: ours / best-suited preset",
        "",
        "| volume | view | best preset | B ours | B preset | B ratio | N ours | N preset | N ratio | target | "
        "B ratio vs first click | N ratio vs first click |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---|---:|---:|",
    ]
    for key, case in document["volumes"].items():
        best = case["best_preset"]
        for view in VIEWS:
            ours, preset = case["metrics"][view][OURS], case["metrics"][view].get(best)
            r = case["ratios"][view].get(best)
            first = case["ratios"][view].get(FIRST_CLICK, {})
            if preset is None or r is None:
                continue
            lines.append(
                f"| {key} | {view} | {best} | {ours['brightness']:.1f} | {preset['brightness']:.1f} | "
                f"{_fmt(r['brightness_ratio'])} | {ours['colour_noise']:.2f} | {preset['colour_noise']:.2f} | "
                f"{_fmt(r['colour_noise_ratio'])} | {'pass' if r['pass'] else '**fail**'} | "
                f"{_fmt(first.get('brightness_ratio'))} | {_fmt(first.get('colour_noise_ratio'))} |"
            )
    lines += visibility_summary(document["volumes"])
    lines += kept_summary(document["volumes"])
    for key, case in document["volumes"].items():
        lines += [
            "",
            f"## {case['title']}",
            "",
            f"`{case['montage']}`: {case['source']}; {case['dtype']}, values {case['value_range'][0]:g} .. "
            f"{case['value_range'][1]:g}; Slicer's first click picks **{case['first_click_preset']}**. "
            f"Ours: {case['design']['n_shown']} of {case['design']['n_classes']} classes shown.",
            "",
            f"![{key}]({Path(case['montage']).name})",
            "",
            "| look | view | B | N | C | B ours/this | N ours/this | GPU LUT fallback |",
            "|---|---|---:|---:|---:|---:|---:|---|",
        ]
        gpu = case["gpu_lookup_table"]
        for look in case["looks"]:
            for view in VIEWS:
                m = case["metrics"][view][look["name"]]
                r = case["ratios"][view].get(look["name"], {})
                gpu_text = gpu_cell(gpu.get(look["name"], {}))
                lines.append(
                    f"| {look['title']} | {view} | {m['brightness']:.1f} | {m['colour_noise']:.2f} | "
                    f"{100 * m['coverage']:.1f}% | {_fmt(r.get('brightness_ratio'))} | "
                    f"{_fmt(r.get('colour_noise_ratio'))} | {gpu_text} |"
                )
        if case["tissues"]:
            lines += tissue_table(case)
    lines.append("")
    return "\n".join(lines)


#: The issue's visibility targets (issue 16): share of the picture from what the user scanned for, at least.
SHOWN_FOR_TARGET = {"head-ct": 0.6, "cta": 0.4}
#: ... and from the air (fog), at most; storages of one volume agree within this.
MAX_FOG_SHARE, STORAGE_AGREEMENT = 0.02, 0.15


def visibility_summary(volumes: dict) -> list[str]:
    """Markdown: per volume and view, the share of the picture from what a user scanned for (ours, the best-suited
    preset, Slicer's first click), the fog, and the verdict against the issue's targets."""
    lines = [
        "",
        "## What the pictures show (the panel)",
        "",
        "Share of each picture (independent orthographic ray caster, `benchmarks/tissue_visibility.py`) that comes "
        "from what a user scanned for: voxels of at least 300 HU on the head CT (in every storage), the skull (and "
        "arteries) of the phantoms and the CT angiogram, bone and teeth of the micro-CT; **fog** = the share from the "
        "air. Presets on re-stored CT are mapped onto the stored values (what the Shift slider does). Targets "
        f"(issue 16): head CT at least {SHOWN_FOR_TARGET['head-ct']:.0%} whatever the storage, storages within "
        f"{STORAGE_AGREEMENT}; CTA at least {SHOWN_FOR_TARGET['cta']:.0%}; micro-CT fog at most {MAX_FOG_SHARE:.0%}; "
        "MRI at least 0.8x the brightness and at most 1.3x the colour noise of MR-Default.",
        "",
        "| volume | kind found | view | scanned for | ours | best preset | first click | fog, ours | B ratio | "
        "N ratio | target |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for key, case in volumes.items():
        for view in VIEWS:
            stats = case["tissues"].get(view, {})
            best = case["best_preset"]
            r = case["ratios"][view].get(best, {})

            def share(look: str, stats: dict = stats, shown_for: tuple = tuple(case["shown_for"])) -> float | None:
                if not shown_for or look not in stats:
                    return None
                return sum(stats[look][t]["share"] for t in shown_for)

            fog = stats.get(OURS, {}).get(case["fog"], {}).get("share") if case["fog"] else None
            ours = share(OURS)
            target = next((v for k, v in SHOWN_FOR_TARGET.items() if key.startswith(k)), None)
            if case["kind"] == "MRI":
                verdict_text = "pass" if r.get("pass") else "**fail**"
            elif key == "micro-ct":
                verdict_text = "pass" if fog is not None and fog <= MAX_FOG_SHARE else "**fail**"
            elif target is not None and ours is not None:
                verdict_text = "pass" if ours >= target else "**fail**"
            else:
                verdict_text = "-"
            lines.append(
                f"| {key} | {case.get('kind_detected', '-')} | {view} | {', '.join(case['shown_for']) or '-'} | "
                f"{_pct(ours)} | {_pct(share(best))} | {_pct(share(FIRST_CLICK))} | {_pct(fog)} | "
                f"{_fmt(r.get('brightness_ratio'))} | {_fmt(r.get('colour_noise_ratio'))} | {verdict_text} |"
            )
    # The lossless storages; HU clipped at 0 (everything below it lost) is its own variant group in look_panel.py.
    storages = {
        k: v for k, v in volumes.items() if k.startswith("head-ct") and k != "head-ct-clipped" and v["shown_for"]
    }
    if len(storages) > 1:
        spread = max(
            max(sum(v["tissues"][view][OURS][t]["share"] for t in v["shown_for"]) for v in storages.values())
            - min(sum(v["tissues"][view][OURS][t]["share"] for t in v["shown_for"]) for v in storages.values())
            for view in VIEWS
        )
        verdict_text = "pass" if spread <= STORAGE_AGREEMENT else "**fail**"
        names = ", ".join(storages)
        lines += ["", f"Head CT storages ({names}): largest spread of ours {spread:.3f} ({verdict_text})."]
    return lines


#: "At least as well" as the kept preset: a share of what was scanned for at most this much below the preset's (the
#: ray caster's sampling), and the issue's brightness and colour-noise targets against the kept picture.
SHARE_TOLERANCE = 0.01


def _kept_verdict(case: dict, view: str, look: str) -> tuple[float | None, float | None, float | None, bool]:
    """Brightness, colour-noise and coverage ratios of ``look`` against the kept preset in ``view``, and whether it
    keeps up: each structure scanned for at least at the kept picture's share (a core and its envelope, not their
    sum), the brightness, colour-noise (none compared over a grey kept picture) and coverage bounds."""
    stats, metrics = case["tissues"][view], case["metrics"][view]
    b = ratio(metrics[look]["brightness"], metrics[KEPT]["brightness"])
    n = ratio(metrics[look]["colour_noise"], metrics[KEPT]["colour_noise"], GREY_NOISE)
    c = ratio(metrics[look]["coverage"], metrics[KEPT]["coverage"])
    n_ok = n is None or n <= MAX_NOISE_RATIO
    shown = all(stats[look][t]["share"] >= stats[KEPT][t]["share"] - SHARE_TOLERANCE for t in case["shown_for"])
    covers = c is not None and c >= MIN_COVERAGE_RATIO
    return b, n, c, shown and b is not None and b >= MIN_BRIGHTNESS_RATIO and n_ok and covers


def kept_summary(volumes: dict) -> list[str]:
    """Markdown: per real volume and view, ours (the first click, then our best look) against the preset a user would
    keep there, with its shift (``../shared/data/README.md``'s reading), rendered here through the same camera: the
    share of the picture from what was scanned for, and brightness and colour noise against the kept picture."""
    kept = {k: v for k, v in volumes.items() if v.get("kept") and v["shown_for"]}
    if not kept:
        return []
    lines = [
        "",
        "## Against the preset a user would keep (the shared panel)",
        "",
        "The kept preset and shift are the reading of `../shared/data/README.md` (a demanding user's choice among the "
        "presets of the volume's kind, shifted), rendered here beside ours. A view keeps up when ours shows each "
        f"structure scanned for with at least the kept picture's share (within {100 * SHARE_TOLERANCE:g} point), "
        f"at least {MIN_BRIGHTNESS_RATIO}x its brightness, at most {MAX_NOISE_RATIO}x its colour noise and at least "
        f"{MIN_COVERAGE_RATIO}x the area it covers (C ratio); a volume, when both views do. Best look: every other "
        "look of our gallery is rendered and judged the same way; the "
        "table gives the one that keeps up in both views, else the one showing most of what was scanned for.",
        "",
        "| volume | view | kept preset | scanned for | kept | first click | B ratio | N ratio | C ratio | keeps up | "
        "best look | its share | B ratio | N ratio | C ratio | keeps up |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---|---|---:|---:|---:|---:|---|",
    ]
    first_ok, any_ok = [], []
    for key, case in kept.items():
        name, shift = case["kept"]
        first = {view: _kept_verdict(case, view, OURS) for view in VIEWS}
        candidates = [GALLERY_LOOK + look for look in case.get("gallery_looks") or []] or [
            look for look in (BEST_LOOK,) if look in case["metrics"][VIEWS[0]]
        ]
        verdicts = {look: {view: _kept_verdict(case, view, look) for view in VIEWS} for look in candidates}
        # The look that keeps up in every view, else the one showing most (the candidates are ranked so).
        keeping = [look for look in candidates if all(v[3] for v in verdicts[look].values())]
        best = (keeping or candidates or [None])[0]
        best_name = case["best_look"] if best == BEST_LOOK else (best or "")[len(GALLERY_LOOK) :]
        for view in VIEWS:
            stats = case["tissues"][view]
            share = {look: _shares_text(stats[look], case["shown_for"]) for look in stats}
            b, n, c, ok = first[view]
            best_cells = "- | - | - | - | - | -"
            if best is not None:
                bb, bn, bc, bok = verdicts[best][view]
                best_cells = (
                    f"{best_name} | {share[best]} | {_fmt(bb)} | {_fmt(bn)} | {_fmt(bc)} | {'yes' if bok else '**no**'}"
                )
            lines.append(
                f"| {key} | {view} | {name}, shift {shift:+g} | {', '.join(case['shown_for'])} | "
                f"{share[KEPT]} | {share[OURS]} | {_fmt(b)} | {_fmt(n)} | {_fmt(c)} | {'yes' if ok else '**no**'} | "
                f"{best_cells} |"
            )
        first_ok.append(all(v[3] for v in first.values()))
        any_ok.append(first_ok[-1] or bool(keeping))
    lines += [
        "",
        f"The first click keeps up with the kept preset on **{sum(first_ok)} of {len(kept)}** volumes; the first click "
        f"or the best look, on **{sum(any_ok)} of {len(kept)}**.",
    ]
    return lines


def _shares_text(stats: dict, shown_for: Sequence[str]) -> str:
    """The share of the picture from what was scanned for, and from each structure where there are several."""
    total = _pct(sum(stats[t]["share"] for t in shown_for))
    if len(shown_for) < 2:
        return total
    parts = ", ".join(f"{t} {_pct(stats[t]['share'])}" for t in shown_for)
    return f"{total} ({parts})"


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.0f}%"


def gpu_cell(check: dict) -> str:
    """``no``, ``**yes** (1048576 > 16384)`` (the table width asked and the limit), or ``n/a``."""
    if "fallback" not in check:
        return "n/a"
    if not check["fallback"]:
        return "no"
    found = re.search(r"texture size of (\d+).*?maximum allowed, (\d+)", " ".join(check.get("messages", [])))
    return f"**yes** ({found.group(1)} > {found.group(2)})" if found else "**yes**"


def tissue_table(case: dict) -> list[str]:
    """Markdown rows: per look and view, each tissue's visibility and share of the picture (phantom only)."""
    names = [n for n in next(iter(next(iter(case["tissues"].values())).values()))]
    lines = [
        "",
        "Tissues (independent orthographic ray casting of the same opacity functions over the volume's labels: "
        "ground truth where there is one, voxels by density on the head CT, our own tissues otherwise; see "
        "`benchmarks/tissue_visibility.py`): **visibility** = mean weight the tissue gets in the pixels "
        "whose ray crosses it (1 = seen opaque wherever it projects, 0 = hidden); **share** = its part of what the "
        "picture shows (the weights add up to each pixel's opacity). Cells: visibility / share, in %.",
        "",
        "| look | view | " + " | ".join(names) + " |",
        "|---|---|" + "---:|" * len(names),
    ]
    for look in case["looks"]:
        for view in VIEWS:
            stats = case["tissues"][view][look["name"]]
            cells = [f"{100 * stats[n]['visibility']:.0f} / {100 * stats[n]['share']:.0f}" for n in names]
            lines.append(f"| {look['title']} | {view} | " + " | ".join(cells) + " |")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--presets", help="Slicer's presets.xml (default: $ISOSIMTF_PRESETS, ../shared, the mirror)")
    parser.add_argument("--size", type=int, default=512, help="picture side in pixels (default %(default)s)")
    parser.add_argument("--volumes", nargs="*", help="only these volumes: " + ", ".join(c.key for c in CASES))
    parser.add_argument("--no-gpu", action="store_true", help="skip the GPU lookup-table check")
    parser.add_argument(
        "--backdrop",
        choices=("black", "slicer"),
        default="black",
        help="3D view backdrop; with 'slicer' (Slicer's gradient) the outputs get a '-slicer' suffix",
    )
    args = parser.parse_args(argv)
    try:
        presets = find_presets(args.presets, REPO)
    except PresetsNotFound as error:
        print(f"compare: {error}", file=sys.stderr)
        return 2
    names = read_presets(presets.path)
    missing = [n for n in (*CT_PRESETS, *MR_PRESETS, "US-Fetal") if n not in names]
    if missing:
        print(f"compare: {presets.path} lacks the presets {', '.join(missing)}", file=sys.stderr)
        return 2
    started = time.perf_counter()
    volumes = {}
    for case in CASES:
        if args.volumes and case.key not in args.volumes:
            continue
        if not case.available():
            print(f"compare: skipping {case.key}: {case.source} is not installed", file=sys.stderr)
            continue
        print(f"compare: {case.key} ...", file=sys.stderr, flush=True)
        volumes[case.key] = run_case(case, presets, args.size, gpu=not args.no_gpu, backdrop=args.backdrop)
        print(f"compare: {case.key} done in {volumes[case.key]['seconds']} s", file=sys.stderr, flush=True)
    import vtkmodules

    document = {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "seconds": time.perf_counter() - started,
        "size": args.size,
        "backdrop": args.backdrop,
        "renderer": f"headless Slicer (slicer-core), CPU ray casting, VTK {vtkmodules.__version__}, "
        f"{platform.machine()}",
        "presets_source": presets.origin,
        "attribution": ATTRIBUTION,
        "targets": {"max_colour_noise_ratio": MAX_NOISE_RATIO, "min_brightness_ratio": MIN_BRIGHTNESS_RATIO},
        "volumes": volumes,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    stem = "compare" if args.backdrop == "black" else f"compare-{args.backdrop}"
    (RESULTS / f"{stem}.json").write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
    (RESULTS / f"{stem}.md").write_text(markdown(document), encoding="utf-8")
    print(f"compare: wrote {RESULTS / (stem + '.md')} in {document['seconds']:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
