"""What an Apply costs in the Slicer module: the design in-process, stage by stage, against the start-up of the
child process (``IsoSimilarityTFLib.worker``). Feeds the cost model of ``IsoSimilarityTFLib.session``.

    .venv/bin/python benchmarks/apply_cost.py [--sizes 64 128 256] [--bins 128 256 512 1024] [--json out.json]

Prints one line per (size, bins): seconds per stage; then the child process's round trip on a small volume and the
time to import what the child imports.
"""

import argparse
import json
import subprocess
import sys
import time

import numpy as np

from IsoSimilarityTFLib.design import design_transfer_function
from IsoSimilarityTFLib.worker import DesignProcess
from isosimtf.phantom import head_phantom


def child_imports() -> float:
    code = "import numpy, sklearn.cluster, IsoSimilarityTFLib.design"
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True)
    return time.perf_counter() - start


def child_round_trip(values, options) -> float:
    start = time.perf_counter()
    with DesignProcess(values, None, options) as job:
        job.wait(timeout=600)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 256])
    parser.add_argument("--bins", type=int, nargs="+", default=[128, 256, 512, 1024])
    parser.add_argument("--json")
    args = parser.parse_args()
    rows = []
    import sklearn.cluster  # noqa: F401  (imported once, as in Slicer after the first Apply)

    for size in args.sizes:
        values = head_phantom(size, seed=1).values
        for n_bins in args.bins:
            start = time.perf_counter()
            design = design_transfer_function(values, None, n_bins=n_bins)
            total = time.perf_counter() - start
            row = {"size": size, "voxels": int(values.size), "n_bins": n_bins, "total_s": total,
                   "n_iter": design.clustering["n_iter"], **design.timings_s}  # fmt: skip
            rows.append(row)
            stages = ", ".join(f"{k} {v:.3f}" for k, v in design.timings_s.items())
            print(f"{size}^3 {n_bins:5d} bins: total {total:.3f} s ({stages}); AP {row['n_iter']} iterations",
                  flush=True)  # fmt: skip
    small = head_phantom(32, seed=1).values
    design_transfer_function(small, None, n_bins=64)
    start = time.perf_counter()
    design_transfer_function(small, None, n_bins=64)
    in_process = time.perf_counter() - start
    imports = [child_imports() for _ in range(3)]
    trips = [child_round_trip(small, {"n_bins": 64}) for _ in range(3)]
    print(f"32^3, 64 bins: in-process {in_process:.3f} s; child round trip {min(trips):.3f}-{max(trips):.3f} s; "
          f"child imports alone {min(imports):.3f}-{max(imports):.3f} s")  # fmt: skip
    if args.json:
        with open(args.json, "w", encoding="utf-8") as file:
            json.dump({"rows": rows, "in_process_small_s": in_process, "child_round_trip_s": trips,
                       "child_imports_s": imports, "numpy": np.__version__}, file, indent=1)  # fmt: skip


if __name__ == "__main__":
    main()
