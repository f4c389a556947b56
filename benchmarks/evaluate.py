"""Quality evaluation of the automatic transfer function against the phantom's ground truth (GitHub issue 6).

Usage::

    .venv/bin/python benchmarks/evaluate.py           # full run (~5-10 min), writes benchmarks/results/evaluation.*
    .venv/bin/python benchmarks/evaluate.py --quick   # short run (~1 min), writes benchmarks/results/evaluation-quick.*

What is measured
----------------
A voxel's class is ``design.labels[bin of the voxel]`` (the class of its isovalue bin). Against the phantom's tissue
labels: homogeneity, completeness and V-measure (``sklearn.metrics``); per tissue, the share of its voxels that
falls in a shown class (visible and not the background); and whether the background class is air (the tissue most of
its voxels belong to).

Compared: the method's options (thesis vs Ma-Entezari normalization, inclusive vs strict crossing, median vs minimum
preference, 128/256/512 bins) and baselines given the SAME number of classes K as affinity propagation found with the
default options (see ``baselines.py``): equal-width intensity bins, k-means on intensity, k-medoids on the same
similarity matrix (unweighted = Ma & Entezari, and weighted by voxel count). Baselines get the method's visibility
rule: the largest class is the background, the next ``max_classes`` (15) largest are shown. The bin-majority oracle
(reads the ground truth) labels each bin with its majority tissue: its purity is the highest any classification
of isovalues can reach (a 1-D transfer function cannot do better), but it is not a V-measure ceiling.

Sweeps: noise 0-80 HU and blur 0-2 mm on a 96^3 phantom, 3 seeds each (mean ± std). No option is tuned to a case:
every run uses the library defaults except the one option named.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from baselines import (  # noqa: E402
    bin_majority_oracle,
    equal_width_labels,
    kmeans_intensity_labels,
    kmedoids_isovalues,
)
from tissue_quality import REGROUP_COUNTS, colin27_cases, mni152_case, phantom_cases, score_case  # noqa: E402

RESULTS = HERE / "results"
MAX_CLASSES = 15

DEFAULT = "AP default (thesis, inclusive, median, 256 bins)"
VARIANTS: dict[str, dict] = {
    DEFAULT: {},
    "AP ma-entezari normalization": {"normalization": "ma-entezari"},
    "AP strict crossing": {"crossing": "strict"},
    "AP ma-entezari + strict (authors' code)": {"normalization": "ma-entezari", "crossing": "strict"},
    "AP minimum preference": {"preference": "minimum"},
    "AP 128 bins": {"n_bins": 128},
    "AP 512 bins": {"n_bins": 512},
}
SWEEP_VARIANTS = (
    DEFAULT,
    "AP ma-entezari normalization",
    "AP strict crossing",
    "AP minimum preference",
    "AP 128 bins",
)
BASELINES = (
    "equal-width bins (K)",
    "k-means on intensity (K)",
    "k-medoids on 1-S, unweighted (K)",
    "k-medoids on 1-S, voxel-weighted (K)",
)
ORACLE = "oracle: bin-majority tissue (reads truth)"


# ----------------------------------------------------------------------------------------------------- metrics


def voxel_classes(bin_labels: np.ndarray, bins: np.ndarray) -> np.ndarray:
    """Class of every voxel: the class of its isovalue bin."""
    return np.asarray(bin_labels)[np.asarray(bins)]


def label_scores(truth: np.ndarray, predicted: np.ndarray) -> dict[str, float]:
    """Homogeneity, completeness and V-measure of ``predicted`` classes against ``truth`` (scikit-learn)."""
    from sklearn.metrics import homogeneity_completeness_v_measure

    h, c, v = homogeneity_completeness_v_measure(np.asarray(truth).reshape(-1), np.asarray(predicted).reshape(-1))
    return {"homogeneity": float(h), "completeness": float(c), "v_measure": float(v)}


def contingency(truth: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """``(n_tissues, n_classes)`` voxel counts."""
    truth = np.asarray(truth).reshape(-1).astype(np.intp)
    predicted = np.asarray(predicted).reshape(-1).astype(np.intp)
    n_t, n_c = int(truth.max()) + 1, int(predicted.max()) + 1
    return np.bincount(truth * n_c + predicted, minlength=n_t * n_c).reshape(n_t, n_c)


def purity(truth: np.ndarray, predicted: np.ndarray) -> float:
    """Share of voxels whose class's majority tissue is their own tissue (1 = every class holds one tissue)."""
    table = contingency(truth, predicted)
    return float(table.max(axis=0).sum() / table.sum())


def own_class_recall(truth: np.ndarray, predicted: np.ndarray, n_tissues: int) -> np.ndarray:
    """Per tissue, the share of its voxels lying in classes where it is the majority tissue.

    That is how much of the tissue a user gets by showing "its" classes alone; 0 means the tissue never dominates a
    class (it cannot be isolated with this classification). NaN for a tissue with no voxel.
    """
    table = contingency(truth, predicted)
    if table.shape[0] < n_tissues:
        table = np.vstack([table, np.zeros((n_tissues - table.shape[0], table.shape[1]), dtype=table.dtype)])
    majority = table.argmax(axis=0)
    own = np.array([table[t, majority == t].sum() for t in range(n_tissues)], dtype=np.float64)
    total = table.sum(axis=1).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0, own / total, np.nan)


def visibility_by_size(voxel_labels: np.ndarray, max_classes: int = MAX_CLASSES) -> tuple[int, list[int]]:
    """The method's rule applied to any labelling: ``(background, shown)``.

    The background is the class with the most voxels; the ``max_classes`` next largest are shown (ties: lower id).
    """
    counts = np.bincount(np.asarray(voxel_labels).reshape(-1))
    order = sorted(np.flatnonzero(counts), key=lambda k: (-counts[k], k))
    return int(order[0]), [int(k) for k in order[1 : 1 + max_classes]]


def shown_share(truth: np.ndarray, voxel_labels: np.ndarray, shown: list[int], n_tissues: int) -> np.ndarray:
    """Per tissue, the share of its voxels whose class is shown (NaN for a tissue with no voxel)."""
    truth = np.asarray(truth).reshape(-1)
    labels = np.asarray(voxel_labels).reshape(-1)
    is_shown = np.zeros(int(labels.max()) + 1, dtype=bool)
    is_shown[[k for k in shown if k <= labels.max()]] = True
    total = np.bincount(truth, minlength=n_tissues).astype(np.float64)
    visible = np.bincount(truth, weights=is_shown[labels], minlength=n_tissues)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0, visible / total, np.nan)


def background_report(truth: np.ndarray, voxel_labels: np.ndarray, background: int, tissues: tuple) -> dict:
    """Which tissue the background class holds: majority tissue, its share, and the share of air it hides."""
    truth = np.asarray(truth).reshape(-1)
    in_background = np.asarray(voxel_labels).reshape(-1) == background
    per_tissue = np.bincount(truth[in_background], minlength=len(tissues))
    majority = int(np.argmax(per_tissue))
    air = tissues.index("air")
    n_air = int(np.count_nonzero(truth == air))
    return {
        "majority_tissue": tissues[majority],
        "is_air": majority == air,
        "majority_share": float(per_tissue[majority] / max(1, in_background.sum())),
        "air_hidden_share": float(per_tissue[air] / max(1, n_air)),
    }


def evaluate_labels(
    truth: np.ndarray,
    voxel_labels: np.ndarray,
    tissues: tuple,
    *,
    background: int | None = None,
    shown: list[int] | None = None,
) -> dict:
    """All metrics of one labelling. Without ``background``/``shown`` the method's size rule is applied."""
    if background is None or shown is None:
        background, shown = visibility_by_size(voxel_labels)
    result = label_scores(truth, voxel_labels)
    result["purity"] = purity(truth, voxel_labels)
    result["own_class_recall"] = [float(v) for v in own_class_recall(truth, voxel_labels, len(tissues))]
    result["n_classes"] = int(np.unique(voxel_labels).size)
    result["shown_share"] = [float(v) for v in shown_share(truth, voxel_labels, shown, len(tissues))]
    result["background"] = background_report(truth, voxel_labels, background, tissues)
    return result


# ----------------------------------------------------------------------------------------------------- one case


def _design(values: np.ndarray, spacing, options: dict):
    """The library's design with ``options``; an unconverged AP keeps its last grouping (noted)."""
    from IsoSimilarityTFLib import design_transfer_function
    from IsoSimilarityTFLib.clustering import ClusteringError

    start = time.perf_counter()
    try:
        design, note = design_transfer_function(values, spacing, **options), None
    except ClusteringError as error:
        design = design_transfer_function(values, spacing, **{**options, "unconverged": "keep"})
        note = f"AP did not converge (kept last grouping): {error}"
    return design, note, time.perf_counter() - start


def run_phantom_case(size: int, noise: float, blur: float, seed: int, variants, with_baselines: bool) -> list[dict]:
    """Every method on one phantom; one record per method."""
    from IsoSimilarityTFLib import quantize
    from isosimtf.phantom import head_phantom

    phantom = head_phantom(size, seed=seed, noise_hu=noise, blur_mm=blur)
    values, truth, tissues = phantom.values, phantom.labels, tuple(phantom.tissues)
    case = {"size": size, "noise_hu": noise, "blur_mm": blur, "seed": seed}
    records = []
    default_design = default_bins = None
    for name in variants:
        design, note, seconds = _design(values, phantom.spacing, VARIANTS[name])
        bins = quantize(values, design.n_bins, design.value_range).bins
        labels = voxel_classes(design.labels, bins)
        shown = [c.id for c in design.classes if c.visible]
        background = design.background_class.id if design.background_class else -1
        metrics = evaluate_labels(truth, labels, tissues, background=background, shown=shown)
        records.append(
            {
                **case,
                "method": name,
                **metrics,
                "seconds": seconds,
                "converged": bool(design.clustering["converged"]),
                "n_iter": int(design.clustering["n_iter"]),
                "damping": design.clustering.get("damping"),
                "note": note,
            }
        )
        if name == DEFAULT:
            default_design, default_bins = design, bins
    if not with_baselines or default_design is None:
        return records

    k = default_design.clustering["n_classes"]
    counts = np.bincount(default_bins.reshape(-1), minlength=default_design.n_bins)
    empty = default_design.clustering.get("empty_isovalues", [])
    runs: dict[str, Any] = {
        BASELINES[0]: lambda: equal_width_labels(values, k),
        BASELINES[1]: lambda: kmeans_intensity_labels(values, k, seed=0)[0],
        BASELINES[2]: lambda: voxel_classes(
            kmedoids_isovalues(default_design.similarity, k, empty_isovalues=empty), default_bins
        ),
        BASELINES[3]: lambda: voxel_classes(
            kmedoids_isovalues(default_design.similarity, k, empty_isovalues=empty, weights=counts), default_bins
        ),
        ORACLE: lambda: voxel_classes(bin_majority_oracle(default_bins, truth, default_design.n_bins), default_bins),
    }
    for name, run in runs.items():
        start = time.perf_counter()
        labels = run()
        seconds = time.perf_counter() - start
        records.append(
            {**case, "method": name, "k_given": k, **evaluate_labels(truth, labels, tissues), "seconds": seconds}
        )
    return records


def run_real_volume(name: str, variants) -> list[dict]:
    """No ground truth: class count, convergence, and what the background class covers."""
    from isosimtf.volume_io import read_volume, real_dataset_path

    path = real_dataset_path(name)
    if path is None:
        return [{"volume": name, "error": "Debian data package not installed"}]
    volume = read_volume(path)
    values = volume.values
    records = []
    for variant in variants:
        design, note, seconds = _design(values, volume.spacing, VARIANTS[variant])
        background = design.background_class
        records.append(
            {
                "volume": name,
                "shape": list(values.shape),
                "method": variant,
                "n_classes": int(design.clustering["n_classes"]),
                "converged": bool(design.clustering["converged"]),
                "n_iter": int(design.clustering["n_iter"]),
                "damping": design.clustering.get("damping"),
                "background_ranges": background.value_ranges if background else None,
                "background_fraction": background.fraction if background else None,
                "background_is_lowest": bool(background and background.value_ranges[0][0] <= float(values.min())),
                "n_shown": sum(c.visible for c in design.classes),
                "seconds": seconds,
                "note": note,
            }
        )
    return records


# ----------------------------------------------------------------------------------------------------- aggregation


def aggregate(records: list[dict], keys: tuple[str, ...]) -> list[dict]:
    """Mean and std over seeds of the numeric metrics, per (keys..., method)."""
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        groups.setdefault((*(r[k] for k in keys), r["method"]), []).append(r)
    rows = []
    for key, members in groups.items():
        row = dict(zip((*keys, "method"), key))
        row["seeds"] = len(members)
        for metric in ("v_measure", "homogeneity", "completeness", "purity", "n_classes", "seconds"):
            vals = np.array([m[metric] for m in members], dtype=np.float64)
            row[metric] = float(vals.mean())
            row[metric + "_std"] = float(vals.std())
        shares = np.array([m["shown_share"] for m in members], dtype=np.float64)
        row["shown_share"] = [float(v) for v in np.nanmean(shares, axis=0)]
        recall = np.array([m["own_class_recall"] for m in members], dtype=np.float64)
        row["own_class_recall"] = [float(v) for v in np.nanmean(recall, axis=0)]
        row["background_is_air"] = sum(m["background"]["is_air"] for m in members)
        row["air_hidden_share"] = float(np.mean([m["background"]["air_hidden_share"] for m in members]))
        row["not_converged"] = sum(1 for m in members if m.get("converged") is False)
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------------------------------- report


def _table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _pm(row: dict, metric: str, digits: int = 3) -> str:
    return f"{row[metric]:.{digits}f} ± {row[metric + '_std']:.{digits}f}"


def main_table(rows: list[dict]) -> str:
    header = [
        "method",
        "K",
        "V-measure",
        "homogeneity",
        "completeness",
        "purity",
        "bg = air",
        "air hidden",
        "time",
        "AP not conv.",
    ]
    body = []
    for r in rows:
        body.append(
            [
                r["method"],
                f"{r['n_classes']:.1f}",
                _pm(r, "v_measure"),
                _pm(r, "homogeneity"),
                _pm(r, "completeness"),
                _pm(r, "purity"),
                f"{r['background_is_air']}/{r['seeds']}",
                f"{r['air_hidden_share']:.3f}",
                f"{r['seconds']:.2f} s",
                r["not_converged"] if r["method"].startswith("AP") else "-",
            ]
        )
    return _table(header, body)


def tissue_table(rows: list[dict], tissues: tuple) -> str:
    header = ["method", *tissues]
    body = []
    for r in rows:
        cells = [r["method"]]
        for shown, own in zip(r["shown_share"], r["own_class_recall"]):
            cells.append(f"{shown:.2f} / {own:.2f}")
        body.append(cells)
    return _table(header, body)


def sweep_table(rows: list[dict], key: str, unit: str) -> str:
    levels = sorted({r[key] for r in rows})
    methods = list(dict.fromkeys(r["method"] for r in rows))
    header = ["method", *[f"{key.split('_')[0]} {v:g} {unit}" for v in levels]]
    body = []
    for method in methods:
        cells = [method]
        for v in levels:
            r = next((r for r in rows if r["method"] == method and r[key] == v), None)
            cells.append("-" if r is None else f"{_pm(r, 'v_measure')} (K {r['n_classes']:.0f})")
        body.append(cells)
    return _table(header, body)


def tissue_report(records: list[dict]) -> str:
    """One table per case: every grouping's V-measure, then the V-measure of every regrouping count."""
    parts = []
    for r in records:
        parts.append(
            f"\n### {r['case']}: {r['n_classes']} AP classes, {r['n_tissues']} tissues by default "
            f"(+ background), design {r['design_seconds']:.2f} s of which tissues {r['tissue_seconds']:.2f} s\n"
        )
        parts.append(_table(["grouping", "V-measure"], [[k, f"{v:.3f}"] for k, v in r["v_measure"].items()]))
        counts = [n for n in REGROUP_COUNTS if n in r["regroup"] or str(n) in r["regroup"]]
        values = [r["regroup"].get(n, r["regroup"].get(str(n))) for n in counts]
        parts.append("\n\nRegrouped to n tissues (`design.regroup(n)`):\n")
        parts.append(_table(["n", *map(str, counts)], [["V-measure", *(f"{v:.3f}" for v in values)]]))
    return "\n".join(parts)


def plot_sweeps(noise_rows: list[dict], blur_rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown_methods = [DEFAULT, "AP minimum preference", *BASELINES[:3], ORACLE]
    styles = {
        DEFAULT: ("C0", "o", "-"),
        "AP minimum preference": ("C0", "s", ":"),
        BASELINES[0]: ("C1", "^", "-"),
        BASELINES[1]: ("C2", "v", "-"),
        BASELINES[2]: ("C3", "D", "-"),
        ORACLE: ("0.4", "", "--"),
    }
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, rows, key, label in (
        (axes[0], noise_rows, "noise_hu", "noise σ (HU), blur 1 mm"),
        (axes[1], blur_rows, "blur_mm", "blur σ (mm), noise 20 HU"),
    ):
        for method in shown_methods:
            pts = sorted((r[key], r["v_measure"], r["v_measure_std"]) for r in rows if r["method"] == method)
            if not pts:
                continue
            x, y, e = zip(*pts)
            color, marker, line = styles[method]
            ax.errorbar(x, y, yerr=e, color=color, marker=marker, linestyle=line, capsize=3, label=method)
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("V-measure vs tissue labels (mean ± std, 3 seeds)")
    axes[0].legend(fontsize=7, loc="lower left")
    fig.suptitle("Phantom 96³: voxel classes vs ground-truth tissues (baselines at the K of default AP)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_tissues(rows: list[dict], tissues: tuple, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = [DEFAULT, "AP minimum preference", *BASELINES[:3]]
    rows = [r for r in rows if r["method"] in methods]
    fig, ax = plt.subplots(figsize=(11, 4))
    width = 0.8 / max(1, len(rows))
    x = np.arange(len(tissues))
    for i, r in enumerate(rows):
        ax.bar(x + (i - (len(rows) - 1) / 2) * width, r["shown_share"], width, label=r["method"])
    ax.set_xticks(x)
    ax.set_xticklabels(tissues)
    ax.set_ylabel("share of the tissue's voxels in a shown class")
    ax.set_ylim(0, 1.3)
    ax.set_yticks(np.linspace(0, 1, 6))
    ax.legend(fontsize=7, ncol=3, loc="upper center")
    ax.set_title("Phantom 128³, noise 20 HU, blur 1 mm (mean of 3 seeds): air should be hidden, the rest shown")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="short run; writes evaluation-quick.*")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)

    import sklearn

    from isosimtf.phantom import TISSUES

    started = time.perf_counter()
    quick = args.quick
    seeds = (0, 1) if quick else (0, 1, 2)
    main_size, sweep_size = (64, 64) if quick else (128, 96)
    noises = (0, 20, 80) if quick else (0, 10, 20, 40, 80)
    blurs = (0, 1, 2) if quick else (0, 0.5, 1, 2)

    def log(text: str) -> None:
        print(f"[{time.perf_counter() - started:6.0f} s] {text}", flush=True)

    main_records = []
    for seed in seeds:
        log(f"main comparison: phantom {main_size}^3, noise 20 HU, blur 1 mm, seed {seed}")
        main_records += run_phantom_case(main_size, 20.0, 1.0, seed, list(VARIANTS), True)
    sweep_records = []
    for noise in noises:
        for seed in seeds:
            log(f"noise sweep: {noise} HU, seed {seed}")
            sweep_records += [
                dict(r, sweep="noise")
                for r in run_phantom_case(sweep_size, float(noise), 1.0, seed, SWEEP_VARIANTS, True)
            ]
    for blur in blurs:
        for seed in seeds:
            log(f"blur sweep: {blur} mm, seed {seed}")
            sweep_records += [
                dict(r, sweep="blur")
                for r in run_phantom_case(sweep_size, 20.0, float(blur), seed, SWEEP_VARIANTS, True)
            ]
    real_records = []
    for name in ("head-ct", "brain-mri"):
        log(f"real volume {name}")
        real_records += run_real_volume(name, list(VARIANTS))

    tissue_records, tissue_notes = [], []
    cases = list(phantom_cases(seeds, main_size)) + list(colin27_cases())
    if not any(c.name.startswith("Colin27") for c in cases):
        tissue_notes.append("Colin27 skipped: Debian package mricron-data is not installed.")
    held_out = mni152_case()
    if held_out is None:
        tissue_notes.append("MNI152 held-out brain skipped: nilearn is not installed (`make evaluate` installs it).")
    else:
        cases.append(held_out)
    for case in cases:
        log(f"tissues: {case.name}")
        tissue_records.append(score_case(case))

    main_rows = aggregate(main_records, ("size", "noise_hu", "blur_mm"))
    noise_rows = aggregate([r for r in sweep_records if r["sweep"] == "noise"], ("noise_hu",))
    blur_rows = aggregate([r for r in sweep_records if r["sweep"] == "blur"], ("blur_mm",))

    # Wins and losses of the default against each baseline, per sweep point (mean V-measure, and whether the gap
    # exceeds the seed-to-seed spread).
    comparisons = []
    for rows, key in ((noise_rows, "noise_hu"), (blur_rows, "blur_mm")):
        for level in sorted({r[key] for r in rows}):
            ours = next(r for r in rows if r["method"] == DEFAULT and r[key] == level)
            for baseline in BASELINES:
                other = next((r for r in rows if r["method"] == baseline and r[key] == level), None)
                if other is None:
                    continue
                gap = ours["v_measure"] - other["v_measure"]
                spread = ours["v_measure_std"] + other["v_measure_std"]
                verdict = "win" if gap > spread else "loss" if gap < -spread else "tie"
                comparisons.append(
                    {
                        "sweep": key,
                        "level": level,
                        "baseline": baseline,
                        "gap": gap,
                        "spread": spread,
                        "verdict": verdict,
                    }
                )

    args.out.mkdir(parents=True, exist_ok=True)
    stem = "evaluation-quick" if quick else "evaluation"
    # Regenerated pictures go to an uncommitted folder (see .gitignore); docs/ keeps the ones a reader sees.
    (args.out / "pictures").mkdir(parents=True, exist_ok=True)
    plot_sweeps(noise_rows, blur_rows, args.out / "pictures" / f"{stem}-robustness.png")
    plot_tissues(main_rows, TISSUES, args.out / "pictures" / f"{stem}-tissues.png")

    import IsoSimilarityTFLib

    machine = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scikit_learn": sklearn.__version__,
        "library": IsoSimilarityTFLib.__version__,
        "cores": os.cpu_count(),
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "loadavg_end": os.getloadavg(),
        "wall_s": time.perf_counter() - started,
    }
    md = [
        f"# IsoSimilarityTF quality evaluation ({'quick' if quick else 'full'} run)\n",
        "Written by `benchmarks/evaluate.py`; the discussion is in `docs/evaluation.md`.\n",
        "A voxel's class is the class of its isovalue bin; scores are against the phantom's tissue labels "
        f"({', '.join(TISSUES)}). Baselines get the K that default AP found on the same volume and the same "
        f"visibility rule (largest class = background, next {MAX_CLASSES} shown). Mean ± std over seeds "
        f"{', '.join(map(str, seeds))}.\n",
        f"\n## Options and baselines: phantom {main_size}^3, noise 20 HU, blur 1 mm\n",
        main_table(main_rows),
        "\n\n'purity': share of voxels whose class's majority tissue is their own. 'air hidden': share of air "
        "voxels in the background class. 'bg = air': seeds where the background class is mostly air. Time: design "
        "(AP rows, whole pipeline) or classifier alone (baselines; k-medoids reuses the similarity matrix).\n",
        "\n### Per tissue: shown share / own-class recall\n",
        tissue_table(main_rows, TISSUES),
        "\n\n'shown share': share of the tissue's voxels in a shown (visible, non-background) class (air should "
        "be ~0, the rest ~1). 'own-class recall': share of the tissue's voxels in classes where it is the majority "
        "tissue, i.e. what showing 'its' classes alone would reveal (0 = the tissue can never be isolated).\n",
        f"\n## Noise sweep (phantom {sweep_size}^3, blur 1 mm): V-measure (K)\n",
        sweep_table(noise_rows, "noise_hu", "HU"),
        f"\n\n## Blur sweep (phantom {sweep_size}^3, noise 20 HU): V-measure (K)\n",
        sweep_table(blur_rows, "blur_mm", "mm"),
        "\n\n## Default AP vs each baseline (V-measure gap; win/loss when larger than the summed std)\n",
        _table(
            ["sweep", "level", "baseline", "gap (default - baseline)", "verdict"],
            [[c["sweep"], f"{c['level']:g}", c["baseline"], f"{c['gap']:+.3f}", c["verdict"]] for c in comparisons],
        ),
        "\n\n## Real volumes (no ground truth)\n",
        _table(
            [
                "volume",
                "method",
                "K",
                "AP converged",
                "iterations",
                "damping",
                "background range",
                "background fraction",
                "background = lowest values",
                "shown",
            ],
            [
                [
                    r["volume"],
                    r.get("method", "-"),
                    r.get("n_classes", "-"),
                    r.get("converged", "-"),
                    r.get("n_iter", "-"),
                    r.get("damping", "-"),
                    "; ".join(f"{a:g}..{b:g}" for a, b in (r.get("background_ranges") or [])),
                    f"{r['background_fraction']:.3f}" if r.get("background_fraction") is not None else "-",
                    r.get("background_is_lowest", "-"),
                    r.get("n_shown", "-"),
                ]
                for r in real_records
            ],
        ),
        f"\n\nPlots (not committed): `pictures/{stem}-robustness.png`, `pictures/{stem}-tissues.png`.\n",
        "\n## Tissues against labelled volumes (V-measure)\n",
        *tissue_notes,
        tissue_report(tissue_records),
        "\n## Run\n",
        _table(["item", "value"], [[k, v] for k, v in machine.items()]),
        "\n",
    ]
    (args.out / f"{stem}.md").write_text("\n".join(md))
    (args.out / f"{stem}.json").write_text(
        json.dumps(
            {
                "machine": machine,
                "tissues": TISSUES,
                "main": main_rows,
                "noise_sweep": noise_rows,
                "blur_sweep": blur_rows,
                "comparisons": comparisons,
                "real": real_records,
                "tissue_grouping": tissue_records,
                "records": {"main": main_records, "sweeps": sweep_records},
            },
            indent=1,
            default=float,
        )
    )
    print("\n".join(md))
    log(f"wrote {args.out / (stem + '.md')}, .json and plots")
    return 0


if __name__ == "__main__":
    sys.exit(main())
