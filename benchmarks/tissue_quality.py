"""Tissue grouping against labelled volumes (issue 9, item 5): the phantom, Colin27 and a held-out MNI152 brain.

Cases (each: values, spacing, a truth label per voxel, -1 where not scored):

* **phantom** (``head_phantom``, 128^3, noise 20 HU, blur 1 mm, several seeds): its seven tissue labels, every voxel.
* **Colin27 head** (``ch2.nii.gz``, Debian ``mricron-data``): four levels from the files alone: air (outside the
  head mask: intensity > 20, closed twice, largest component, holes filled), head (inside it, outside the brain),
  brain (``ch2bet.nii.gz`` > 0) and cortex (brain voxels labelled by the AAL atlas, ``aal.nii.gz``). Coarse: AAL
  covers most of the brain, white matter included, and "head" mixes scalp, skull and CSF.
* **Colin27 brain** (``ch2bet.nii.gz``): inside the brain only, cortex (AAL) against the rest.
* **MNI152 brain, held out** (the ICBM 2009a template shipped in nilearn's package data: T1, grey- and white-matter
  probability maps): brain = grey + white > 50 %, closed three times, holes filled; the skull-stripped T1 is the T1
  inside it (0 outside); truth = the most probable of CSF (1 - grey - white), grey and white, inside the brain.
  Not used to choose any constant, but the partial-volume model was designed after looking at how Gaussian mixtures
  failed on it (see ``docs/evaluation.md``): a weaker hold-out than a volume never opened.

For each case: the default design's tissues (``tissues="auto"``), every regrouping from 1 to 8 tissues, the AP
classes (``"all"``, the thesis), baselines with the same number of groups (equal-width bins, k-means on intensity,
k-medoids on ``1 - S`` weighted by voxels), and two oracles that read the truth: every bin to its majority label
(the highest purity any 1-D transfer function can reach) and every AP class to its majority label (the same for any
grouping of these classes). Neither bounds V-measure (it also rewards few groups), but both tell how much is left.
Scores are V-measure (scikit-learn) over the scored voxels.
"""

from __future__ import annotations

import importlib.util
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from baselines import bin_majority_oracle, equal_width_labels, kmeans_intensity_labels, kmedoids_isovalues

HEAD_THRESHOLD = 20  # Colin27 T1: air is below, scalp above
MNI_FILES = {
    "t1": "mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz",
    "gm": "mni_icbm152_gm_tal_nlin_sym_09a_converted.nii.gz",
    "wm": "mni_icbm152_wm_tal_nlin_sym_09a_converted.nii.gz",
}
REGROUP_COUNTS = range(1, 9)


@dataclass
class LabelledCase:
    name: str
    values: np.ndarray
    spacing: tuple[float, float, float]
    truth: np.ndarray  # int, -1 where not scored
    labels: tuple[str, ...]
    brain_only: bool  # scored inside a brain mask: the background group holds no scored voxel


def phantom_cases(seeds=(0, 1, 2), size: int = 128) -> Iterator[LabelledCase]:
    from isosimtf.phantom import head_phantom

    for seed in seeds:
        p = head_phantom(size, seed=seed, noise_hu=20.0, blur_mm=1.0)
        yield LabelledCase(f"phantom seed {seed}", p.values, p.spacing, p.labels, tuple(p.tissues), False)


def _largest_component(mask: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    labels, _ = ndimage.label(mask)
    sizes = np.bincount(labels.reshape(-1))
    sizes[0] = 0
    return labels == int(np.argmax(sizes))


def colin27_cases() -> Iterator[LabelledCase]:
    """Colin27 head and brain levels; nothing when mricron-data is not installed."""
    from scipy import ndimage

    from isosimtf.volume_io import read_volume, real_dataset_path

    path = real_dataset_path("brain-mri")
    if path is None:
        return
    head_volume = read_volume(path)
    bet = read_volume(Path(path).with_name("ch2bet.nii.gz")).values
    aal = read_volume(Path(path).with_name("aal.nii.gz")).values
    brain = bet > 0
    head = _largest_component(ndimage.binary_closing(head_volume.values > HEAD_THRESHOLD, iterations=2))
    head = ndimage.binary_fill_holes(head) | brain
    truth = np.where(head, 1, 0)
    truth[brain] = 2
    truth[brain & (aal > 0)] = 3
    spacing = tuple(float(s) for s in head_volume.spacing)
    yield LabelledCase(
        "Colin27 head (ch2)", head_volume.values, spacing, truth, ("air", "head", "brain", "cortex"), False
    )
    yield LabelledCase(
        "Colin27 brain (ch2bet)", bet, spacing, np.where(brain, (aal > 0).astype(int), -1), ("brain", "cortex"), True
    )


def nilearn_data_dir() -> Path | None:
    """nilearn's package data folder, found without importing nilearn (its dependencies are not needed)."""
    spec = importlib.util.find_spec("nilearn")
    if spec is None or spec.origin is None:
        return None
    folder = Path(spec.origin).parent / "datasets" / "data"
    return folder if all((folder / f).exists() for f in MNI_FILES.values()) else None


def mni152_case() -> LabelledCase | None:
    """The held-out MNI152 brain, or None when nilearn is not installed."""
    from scipy import ndimage

    from isosimtf.volume_io import read_volume

    folder = nilearn_data_dir()
    if folder is None:
        return None
    t1 = read_volume(folder / MNI_FILES["t1"])
    gm = read_volume(folder / MNI_FILES["gm"]).values.astype(np.float64) / 255.0
    wm = read_volume(folder / MNI_FILES["wm"]).values.astype(np.float64) / 255.0
    brain = ndimage.binary_fill_holes(ndimage.binary_closing(gm + wm > 0.5, iterations=3))
    csf = np.clip(1.0 - gm - wm, 0.0, None)
    truth = np.where(brain, np.argmax(np.stack([csf, gm, wm]), axis=0), -1)
    values = np.where(brain, t1.values, 0).astype(t1.values.dtype)
    spacing = tuple(float(s) for s in t1.spacing)
    return LabelledCase("MNI152 brain (held out)", values, spacing, truth, ("csf", "grey", "white"), True)


def v_measure(truth: np.ndarray, predicted: np.ndarray) -> float:
    from sklearn.metrics import v_measure_score

    scored = truth >= 0
    return float(v_measure_score(truth[scored], np.asarray(predicted)[scored]))


def score_case(case: LabelledCase) -> dict:
    """Every grouping of one case: V-measure, group counts, time of the design."""
    from IsoSimilarityTFLib import design_transfer_function, quantize

    start = time.perf_counter()
    design = design_transfer_function(case.values, case.spacing)
    seconds = time.perf_counter() - start
    bins = quantize(case.values, design.n_bins, design.value_range).bins
    classes = design.labels[bins]
    n_auto = design.n_tissues
    n_groups = len(design.tissues)  # with the background tissue
    scored = case.truth >= 0
    rows = {"tissues (auto)": v_measure(case.truth, design.tissue_of_class[classes])}
    regroup = {}
    for n in REGROUP_COUNTS:
        if n <= design.hierarchy.max_tissues:
            design.regroup(n)
            regroup[n] = v_measure(case.truth, design.tissue_of_class[classes])
    design.regroup("auto")
    rows["AP classes (all, thesis)"] = v_measure(case.truth, classes)
    counts = np.bincount(bins.reshape(-1), minlength=design.n_bins)
    empty = design.clustering.get("empty_isovalues", [])
    # Inside a brain mask the background group holds no scored voxel: the baselines get both counts there.
    baseline_counts = sorted({n_groups, n_auto} if case.brain_only else {n_groups})
    for k in baseline_counts:
        rows[f"equal-width bins ({k})"] = v_measure(case.truth, equal_width_labels(case.values, k))
        rows[f"k-means on intensity ({k})"] = v_measure(case.truth, kmeans_intensity_labels(case.values, k)[0])
        medoids = kmedoids_isovalues(design.similarity, k, empty_isovalues=empty, weights=counts)
        rows[f"k-medoids on 1-S, voxel-weighted ({k})"] = v_measure(case.truth, medoids[bins])
    truth_in = np.where(scored, case.truth, 0)
    rows["oracle: bin majority (reads the truth)"] = v_measure(
        case.truth, bin_majority_oracle(bins, truth_in, design.n_bins)[bins]
    )
    table = np.zeros((len(design.classes), int(case.truth.max()) + 1))
    np.add.at(table, (classes[scored], case.truth[scored]), 1)
    rows["oracle: AP class majority (reads the truth)"] = v_measure(case.truth, table.argmax(axis=1)[classes])
    return {
        "case": case.name,
        "labels": list(case.labels),
        "n_classes": len(design.classes),
        "n_tissues": n_auto,
        "n_groups": n_groups,
        "tissue_ranges": [t.value_ranges for t in design.tissues if not t.background],
        "design_seconds": seconds,
        "tissue_seconds": design.timings_s.get("tissues"),
        "v_measure": rows,
        "regroup": regroup,
    }
