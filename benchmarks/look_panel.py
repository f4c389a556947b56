"""Which labels give the picture of our looks, on every volume of the panel: fast, no VTK, no Slicer.

Usage::

    .venv/bin/python benchmarks/look_panel.py                  # every available volume of the panel
    .venv/bin/python benchmarks/look_panel.py --only angiogram plant-ct

For each volume of ``volume_panel`` (its ``PANEL`` and the HU originals ``REFERENCES``) that is on this machine:
``design_transfer_function(values, spacing)`` (spacing from the IJK-to-RAS column norms, x, y, z), then for the
design's first click and, when the design has ``looks``, for each of them (``design.use_look(name)``), the share of
the picture each truth label gives. The picture is the library's own visibility histogram
(``visibility_histogram(design.preview, opacity per bin)``: the light each isovalue bin sends to the eye over the six
axis views); a bin's visibility goes to the labels of the voxels in it, in proportion::

    share(label) = sum_b vis[b] * frac_label(b) / sum_b vis[b],  frac_label(b) = voxels of label in b / voxels in b

with the bins of the design (its ``n_bins`` over its ``value_range``). "scanned for" sums the volume's ``shown_for``
labels, "fog" is its ``fog`` label. "oracle" is what ``design.check_look`` finds each look failing of its promise,
measured with the library's independent ray caster (empty: it keeps it). On the real volumes the labels are value
bands read from the data's README, not ground truth; the phantom-derived and synthetic volumes have their truth.

Invariance: for each group of ``VARIANT_GROUPS`` (one data set in several storages, or at several voxel sizes), the
largest difference between the variants' shares, per look.

Outputs: a markdown table on stdout, ``benchmarks/results/look-panel.md`` and ``look-panel.json``. A volume that
fails is one line on stderr (and in the JSON); the others go on.
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import sys
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from volume_panel import PANEL, REFERENCES, VARIANT_GROUPS, PanelVolume  # noqa: E402

RESULTS = HERE / "results"
FIRST_CLICK = "first click"


def spacing_of(ijk_to_ras: np.ndarray) -> tuple[float, float, float]:
    """Voxel size ``(x, y, z)`` in mm: the norms of the IJK-to-RAS matrix's first three columns."""
    x, y, z = (float(s) for s in np.linalg.norm(np.asarray(ijk_to_ras, dtype=np.float64)[:3, :3], axis=0))
    return x, y, z


def label_fractions(values: np.ndarray, labels: np.ndarray, n_labels: int, design: Any) -> np.ndarray:
    """``(n_labels, n_bins)``: the part of each isovalue bin's voxels that each label holds (0 in an empty bin)."""
    from IsoSimilarityTFLib import quantize

    bins = quantize(values, design.n_bins, design.value_range).bins
    index = np.asarray(labels, dtype=np.int64).ravel() * design.n_bins + bins.ravel()
    counts = np.bincount(index, minlength=n_labels * design.n_bins).reshape(n_labels, design.n_bins)
    return counts / np.maximum(counts.sum(axis=0), 1)


def picture_shares(design: Any, fractions: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """The design's current look: its visibility histogram, and each label's share of the picture (None without
    labels)."""
    from IsoSimilarityTFLib.visibility import visibility_histogram

    opacity = design.bin_looks()[1]
    visibility = visibility_histogram(design.preview, opacity)
    if fractions is None:
        return opacity, None
    total = float(visibility.sum())
    shares = fractions @ visibility / total if total > 0 else np.zeros(fractions.shape[0])
    return opacity, shares


def _row(name: str, shares, names, case: PanelVolume, seconds: float, first_click: bool = False, oracle=None) -> dict:
    by_label = None if shares is None else {n: float(s) for n, s in zip(names, shares)}
    scanned = sum(by_label[n] for n in case.shown_for) if by_label is not None and case.shown_for else None
    fog = by_label[case.fog] if by_label is not None and case.fog else None
    return {"look": name, "first_click": first_click, "shares": by_label, "scanned_for": scanned, "fog": fog,
            "seconds": round(seconds, 3), "oracle": oracle}  # fmt: skip


def measure(case: PanelVolume) -> dict:
    """Design the volume and measure every look (see the module notes)."""
    from IsoSimilarityTFLib import design_transfer_function

    started = time.perf_counter()
    values, ijk_to_ras, labels, names, storage = case.load()
    values = np.asarray(values)
    loaded = time.perf_counter()
    spacing = spacing_of(ijk_to_ras)
    design = design_transfer_function(values, spacing)
    designed = time.perf_counter()
    fractions = None if labels is None else label_fractions(values, labels, len(names), design)
    first_opacity, shares = picture_shares(design, fractions)
    rows = [_row(FIRST_CLICK, shares, names, case, designed - loaded, first_click=True)]
    for look in getattr(design, "looks", None) or ():
        switched = time.perf_counter()
        design.use_look(look.name)
        opacity, shares = picture_shares(design, fractions)
        seconds = time.perf_counter() - switched
        rows.append(_row(look.name, shares, names, case, seconds, oracle=design.check_look(look.name)))
        rows[-1]["first_click"] = bool(np.array_equal(opacity, first_opacity))
    if len(rows) > 1 and any(r["first_click"] for r in rows[1:]):
        rows = rows[1:]  # the first click is one of the looks: keep that one, marked, with the design's time
        next(r for r in rows if r["first_click"])["seconds"] = round(designed - loaded, 3)
    scored = [r for r in rows if r["scanned_for"] is not None]
    best = max(scored, key=lambda r: (round(r["scanned_for"], 3), -(r["fog"] or 0.0)))["look"] if scored else None
    return {
        "title": case.title,
        "kind": case.kind,
        "kind_detected": getattr(design, "kind", None),
        "source": case.source,
        "shape": list(values.shape),
        "dtype": str(values.dtype),
        "spacing": list(spacing),
        "storage": None if storage is None else list(storage),
        "labels": None if names is None else list(names),
        "shown_for": list(case.shown_for),
        "fog": case.fog,
        "n_classes": len(design.classes),
        "load_s": round(loaded - started, 3),
        "design_s": round(designed - loaded, 3),
        "looks": rows,
        "best_look": best,
    }


def invariance(volumes: dict[str, dict]) -> list[dict]:
    """Per group of variants measured (two or more): the look each variant's first click is, the looks missing from
    some variants, and per look (the first click, whichever look it is, then every look all variants have) the
    largest difference of the scanned-for share and of the fog share between the variants, with the variants that
    give the lowest and the highest scanned-for share."""
    result = []
    for group, keys in VARIANT_GROUPS.items():
        present = [k for k in keys if k in volumes and "looks" in volumes[k]]
        if len(present) < 2:
            continue
        looks = {k: [r["look"] for r in volumes[k]["looks"]] for k in present}
        everywhere = [name for name in looks[present[0]] if all(name in looks[k] for k in present)]
        missing = {
            name: [k for k in present if name not in looks[k]]
            for name in dict.fromkeys(n for k in present for n in looks[k])
            if name not in everywhere
        }
        entry = {
            "group": group,
            "volumes": present,
            "first_clicks": {k: next(r["look"] for r in volumes[k]["looks"] if r["first_click"]) for k in present},
            "looks_missing": missing,
            "looks": [],
        }
        for look in (FIRST_CLICK, *everywhere):
            if look == FIRST_CLICK:
                rows = [next(r for r in volumes[k]["looks"] if r["first_click"]) for k in present]
            else:
                rows = [next(r for r in volumes[k]["looks"] if r["look"] == look) for k in present]
            spreads = {"look": look}
            for name in ("scanned_for", "fog"):
                numbers = {k: r[name] for k, r in zip(present, rows) if r[name] is not None}
                spreads[name] = float(max(numbers.values()) - min(numbers.values())) if len(numbers) > 1 else None
                spreads[name + "_by_volume"] = numbers
                if name == "scanned_for" and numbers:
                    spreads["lowest"] = min(numbers, key=numbers.get)
                    spreads["highest"] = max(numbers, key=numbers.get)
            entry["looks"].append(spreads)
        result.append(entry)
    return result


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f}%"


def _oracle(failures: list | None) -> str:
    if failures is None:
        return "-"
    return "kept" if not failures else f"**{len(failures)} broken**"


def _by_label(shares: dict | None) -> str:
    if shares is None:
        return "-"
    return ", ".join(f"{name} {100 * share:.0f}" for name, share in shares.items())


def markdown(document: dict) -> str:
    lines = [
        "# Look panel: which labels give the picture",
        "",
        f"{document['date']}, {document['machine']}, {document['seconds']:.0f} s in all. "
        "`benchmarks/look_panel.py`: our design with its defaults on every available panel volume; per look, the "
        "share of the picture (the library's visibility histogram: six axis views of the design's preview) that the "
        "scanned-for labels and the fog label give. Labels are the truth of the synthetic and phantom-derived "
        "volumes, voxels of at least 300 HU on the head CT, and value bands read from `../shared/data/README.md` on "
        "the real volumes (a reading, not ground truth). time: the design (on the first click's row), switching "
        "to the look and measuring it (other rows). oracle: whether the look keeps its promise (`check_look`, an "
        "independent ray caster). Last column: every label's share, in %. The best look of each volume (largest "
        "scanned-for share) is in bold.",
        "",
        "| volume | look | scanned for | share of scanned-for | share of fog | time (s) | oracle | shares by label |",
        "|---|---|---|---:|---:|---:|---|---|",
    ]
    for key, case in document["volumes"].items():
        if "error" in case:
            lines.append(f"| {key} | **failed**: {case['error']} | | | | | | |")
            continue
        for row in case["looks"]:
            look = row["look"] + (" (first click)" if row["first_click"] and row["look"] != FIRST_CLICK else "")
            if row["look"] == case["best_look"] and len(case["looks"]) > 1:
                look = f"**{look}**"
            lines.append(
                f"| {key} | {look} | {', '.join(case['shown_for']) or '-'} | {_pct(row['scanned_for'])} | "
                f"{_pct(row['fog']) if case['fog'] else '-'} | {row['seconds']:.2f} | {_oracle(row.get('oracle'))} | "
                f"{_by_label(row['shares'])} |"
            )
    broken = [
        f"{key} {row['look']}: {'; '.join(row['oracle'])}"
        for key, case in document["volumes"].items()
        if "error" not in case
        for row in case["looks"]
        if row.get("oracle")
    ]
    checked = sum(row.get("oracle") is not None for c in document["volumes"].values() for row in c.get("looks", ()))
    lines += ["", f"Oracle (`check_look`): {checked - len(broken)} of {checked} looks keep their promise."]
    lines += [f"- {line}" for line in broken]
    best = [(k, c) for k, c in document["volumes"].items() if "error" not in c and c["best_look"] is not None]
    if any(len(c["looks"]) > 1 for _, c in best):
        lines += ["", "Best look per volume (largest scanned-for share):", ""]
        for key, case in best:
            row = next(r for r in case["looks"] if r["look"] == case["best_look"])
            lines.append(f"- {key}: {case['best_look']} ({_pct(row['scanned_for'])})")
    if document["invariance"]:
        lines += [
            "",
            "Invariance: the same data in other storages or at other voxel sizes (the clipped storage, which loses "
            "everything below 0 HU, apart with its HU original); per look, the largest difference of shares between "
            'the variants, and the variants with the lowest and the highest scanned-for share. "first click" '
            "compares each variant's first click, whichever look it is.",
            "",
            "| group | look | scanned-for spread | lowest / highest | fog spread |",
            "|---|---|---:|---|---:|",
        ]
        for entry in document["invariance"]:
            for row in entry["looks"]:
                spread, fog, by = row["scanned_for"], row["fog"], row["scanned_for_by_volume"]
                extremes = (
                    f"{row['lowest']} {_pct(by[row['lowest']])} / {row['highest']} {_pct(by[row['highest']])}"
                    if by
                    else "-"
                )
                lines.append(
                    f"| {entry['group']} | {row['look']} | {'-' if spread is None else f'{spread:.3f}'} | "
                    f"{extremes} | {'-' if fog is None else f'{fog:.3f}'} |"
                )
        lines.append("")
        for entry in document["invariance"]:
            clicks = ", ".join(f"{k}: {v}" for k, v in entry["first_clicks"].items())
            missing = "; ".join(f"{name} (not in {', '.join(keys)})" for name, keys in entry["looks_missing"].items())
            lines.append(
                f"- {entry['group']}: first click {clicks}."
                + (f" Looks not in every variant: {missing}." if missing else "")
            )
    if document["skipped"]:
        lines += ["", f"Not on this machine: {', '.join(document['skipped'])}."]
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    cases = (*REFERENCES, *PANEL)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--only", nargs="+", metavar="KEY", help="only these volumes: " + ", ".join(c.key for c in cases)
    )
    parser.add_argument("--no-write", action="store_true", help="print the table only (no files in results/)")
    args = parser.parse_args(argv)
    if args.only:
        unknown = sorted(set(args.only) - {c.key for c in cases})
        if unknown:
            parser.error(f"unknown volume(s): {', '.join(unknown)}")
    started = time.perf_counter()
    volumes: dict[str, dict] = {}
    skipped = []
    for case in cases:
        if args.only and case.key not in args.only:
            continue
        if not case.available():
            skipped.append(case.key)
            continue
        print(f"look-panel: {case.key} ...", file=sys.stderr, flush=True)
        try:
            volumes[case.key] = measure(case)
        except Exception as error:  # one failing volume must not stop the panel
            message = f"{type(error).__name__}: {error}".splitlines()[0]
            print(f"look-panel: {case.key} FAILED: {message}", file=sys.stderr, flush=True)
            volumes[case.key] = {"title": case.title, "error": message, "traceback": traceback.format_exc()}
    document = {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": f"{platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}",
        "seconds": time.perf_counter() - started,
        "volumes": volumes,
        "invariance": invariance(volumes),
        "skipped": skipped,
    }
    text = markdown(document)
    print(text)
    if not args.no_write:
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / "look-panel.md").write_text(text, encoding="utf-8")
        (RESULTS / "look-panel.json").write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
        print(f"look-panel: wrote {RESULTS / 'look-panel.md'} in {document['seconds']:.0f} s", file=sys.stderr)
    return 1 if any("error" in v for v in volumes.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
