"""What an Apply costs in the Slicer module: the design in-process, stage by stage, against the start-up of the
child process (``IsoSimilarityTFLib.worker``). Feeds the cost model of ``IsoSimilarityTFLib.session``.

    .venv/bin/python benchmarks/apply_cost.py [--sizes 64 128 256] [--bins 128 256 512 1024] [--repeat 3]
                                              [--json out.json]

Prints one line per (size, bins): seconds per stage, the fastest of ``--repeat`` runs with the range of the totals
(the machine may be shared); then affinity propagation's seconds per iteration with the iteration count forced; then,
on the 64^3 phantom at 256 bins, the design in-process, the same design through the child process, and the child's
start and imports alone (``--repeat`` runs each).
"""

import argparse
import json
import subprocess
import sys
import time

import numpy as np

from IsoSimilarityTFLib.affinity_propagation import affinity_propagation
from IsoSimilarityTFLib.design import design_transfer_function
from IsoSimilarityTFLib.quantize import quantize
from IsoSimilarityTFLib.similarity import similarity_matrix
from IsoSimilarityTFLib.worker import DesignProcess
from isosimtf.phantom import head_phantom


def seconds(function) -> float:
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def child_imports() -> float:
    """Start Python and import what ``python -m IsoSimilarityTFLib.worker`` imports before it reads its request."""
    return seconds(lambda: subprocess.run([sys.executable, "-c", "import IsoSimilarityTFLib.worker"], check=True))


def child_round_trip(values, options) -> float:
    def trip():
        with DesignProcess(values, None, options) as job:
            job.wait(timeout=600)

    return seconds(trip)


def ap_seconds_per_iteration(values, n_bins: int, iterations: int = 100) -> float:
    """Affinity propagation on the volume's similarity, run for exactly ``iterations`` (it cannot converge sooner)."""
    quantized = quantize(values, n_bins)
    affinity = similarity_matrix(quantized.bins, n_bins) - 1.0
    preference = float(np.median(affinity))
    return (
        seconds(lambda: affinity_propagation(affinity, preference, max_iter=iterations, convergence_iter=iterations))
        / iterations
    )


def span(values) -> str:
    return f"{min(values):.3f}-{max(values):.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 256])
    parser.add_argument("--bins", type=int, nargs="+", default=[128, 256, 512, 1024])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json")
    args = parser.parse_args()
    rows = []
    for size in args.sizes:
        values = head_phantom(size, seed=1).values
        for n_bins in args.bins:
            runs = []
            for _ in range(args.repeat):
                start = time.perf_counter()
                design = design_transfer_function(values, None, n_bins=n_bins)
                runs.append((time.perf_counter() - start, design))
            total, design = min(runs, key=lambda run: run[0])
            row = {"size": size, "voxels": int(values.size), "n_bins": n_bins, "total_s": total,
                   "totals_s": [run[0] for run in runs], "n_iter": design.clustering["n_iter"],
                   "damping": design.clustering.get("damping"), **design.timings_s}  # fmt: skip
            rows.append(row)
            stages = ", ".join(f"{k} {v:.3f}" for k, v in design.timings_s.items())
            print(f"{size}^3 {n_bins:5d} bins: total {total:.3f} s (range {span(row['totals_s'])}; {stages}); "
                  f"AP {row['n_iter']} iterations, damping {row['damping']}", flush=True)  # fmt: skip
    ap = {}
    values = head_phantom(64, seed=1).values
    for n_bins in args.bins:
        ap[n_bins] = [ap_seconds_per_iteration(values, n_bins) for _ in range(args.repeat)]
        print(f"affinity propagation at {n_bins} bins: {span([1e3 * s for s in ap[n_bins]])} ms per iteration, "
              f"{span([1e9 * s / n_bins**2 for s in ap[n_bins]])} ns per bin squared", flush=True)  # fmt: skip
    options = {"n_bins": 256}
    in_process = [seconds(lambda: design_transfer_function(values, None, **options)) for _ in range(args.repeat)]
    trips = [child_round_trip(values, options) for _ in range(args.repeat)]
    imports = [child_imports() for _ in range(args.repeat)]
    bare = [seconds(lambda: subprocess.run([sys.executable, "-c", "pass"], check=True)) for _ in range(args.repeat)]
    print(f"64^3, 256 bins: in-process {span(in_process)} s; child round trip {span(trips)} s; "
          f"child start and imports alone {span(imports)} s (bare interpreter {span(bare)} s)")  # fmt: skip
    if args.json:
        with open(args.json, "w", encoding="utf-8") as file:
            json.dump({"rows": rows, "ap_s_per_iteration": ap, "in_process_s": in_process,
                       "child_round_trip_s": trips, "child_imports_s": imports, "bare_interpreter_s": bare,
                       "numpy": np.__version__, "python": sys.version.split()[0]}, file, indent=1)  # fmt: skip


if __name__ == "__main__":
    main()
