"""Speed and memory benchmark of the IsoSimilarityTF pipeline (GitHub issue 6).

Usage::

    .venv/bin/python benchmarks/bench.py            # full run (~6-9 min on 2 cores), writes benchmarks/results/bench.*
    .venv/bin/python benchmarks/bench.py --quick    # short run (~1-2 min), writes benchmarks/results/bench-quick.*
    # Out of core only, with the 25 GiB volume (written once to --data: ~2 min, 26 GB of disk); the committed
    # benchmarks/results/bench-outofcore.* are this run's bench.* renamed:
    .venv/bin/python benchmarks/bench.py --only out_of_core --big --data /big/disk --out /tmp/bench-outofcore

Method
------
* Every configuration (volume x options) runs in a fresh child process (``bench.py --child JSON``), so peak-memory
  figures of one case do not leak into another and every case starts with the same imports.
* Times are ``time.perf_counter`` wall-clock seconds; the reported figure is the MEDIAN over the warm runs (>= 5 for
  volumes up to 256^3, >= 3 for 384^3 and 512^3). The first pipeline call of each child is run once before them and
  reported apart as "first call": it includes first-touch page faults and numpy's first calls.
* Out-of-core cases (``kind: out_of_core``) read the volume with ``isosimtf.chunked_readers`` (a dask array) and
  design it once, end to end: their "process peak" is the child's ``VmHWM`` from just before the read to the end.
* Stages: load (reading the file; for phantoms: generating it), quantize, similarity, clustering (affinity
  propagation), classes, tf (building the ``vtkVolumeProperty`` from the classes) and render (a 512x512 headless Slicer
  CPU ray-cast picture of the volume with the designed TF, new scene each time: volume copy + first render).
  "pipeline" = quantize + similarity + clustering + classes + tissues + tf of the same run.
  quantize..classes are timed by ``design_transfer_function`` itself (``design.timings_s``).
* Peak memory per stage: just before a stage starts, the kernel's peak-RSS counter of the child is reset to the
  current RSS (``echo 5 > /proc/self/clear_refs``); when the stage ends ``VmHWM`` (peak RSS) is read from
  ``/proc/self/status``. The stage's figure is ``VmHWM - VmRSS(at stage start)``: the extra resident memory the stage
  needed at its peak, exact (kernel accounting, no sampling) and free of timing overhead. Stage boundaries inside
  ``design_transfer_function`` are caught through its ``progress`` callback. The maximum over the warm runs is
  reported. "process peak" is the absolute ``VmHWM`` of the child during the pipeline, i.e. including the Python
  interpreter, numpy/VTK libraries and the input volume. Where ``clear_refs`` cannot be written, a psutil
  thread sampling RSS every 1 ms is used instead (this is said in the output).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"
CHILD_MARK = "BENCHJSON:"

# Figures of the thesis (Table 4.1 / 4.2, 256^3 volumes): similarity 13 min, classification 22-50 s.
THESIS_SIMILARITY_S = 780.0
THESIS_CLASSIFICATION_S = (22.0, 50.0)

# Targets of issue 6.
TARGET_SIM_256_UINT8_S = 0.25
TARGET_PIPELINE_256_UINT8_S = 0.5
TARGET_PIPELINE_512_INT16_S = 3.0
TARGET_PEAK_512_INT16_MB = 1.5 * 1024

# Targets of issue 12: the similarity within this multiple of the numpy floor; the 512^3 int16 design's process peak.
TARGET_FLOOR_MULTIPLE = 2.2
TARGET_PEAK_512_INT16_ISSUE12_MB = 700.0
TARGET_PEAK_1024_OUT_OF_CORE_MB = 1024.0
TARGET_PEAK_BEYOND_MEMORY_MB = 3072.0
OUT_OF_CORE_ZARR = "out of core: 1024^3 uint16 Zarr (64x256x256 chunks)"
OUT_OF_CORE_BIG = "beyond memory: 2048x2048x3200 uint16 raw NRRD (25 GiB)"
# Targets of issue 12 for the command line on the head CT (wall time of the whole command, on a quiet machine).
TARGET_LATENCY_NO_RENDER_S = 1.5
TARGET_LATENCY_FULL_S = 3.5
# Targets of issue 24: all looks with their thumbnails cost at most the similarity pass; switching a look and the
# Detail slider (a regrouping, its look included) stay interactive.
TARGET_LOOKS_OVER_SIMILARITY = 1.0
TARGET_SWITCH_LOOK_S = 0.05
TARGET_REGROUP_S = 0.1
# Cells per chunk tried for the floor; the fastest on this machine is the floor.
FLOOR_CHUNK_CELLS = (1 << 17, 1 << 18, 1 << 19)
# Targets of issue 25: the whole design (no pictures) within this multiple of its numpy floor; the stages after the
# pass (clustering, classes, tissues) together at most the pass itself. Today's figures, from the issue, beside them.
TARGET_DESIGN_FLOOR_MULTIPLE = 2.0
DESIGN_FLOOR_BEFORE = {"head CT": "8.5x", "brain MRI": "-", "256^3 uint8": "9.2x", "512^3 int16": "2.25x",
                       "256^3 float32 padded": "-", "MNI152": "23.8x"}  # fmt: skip

STAGES = ("load", "quantize", "similarity", "clustering", "classes", "tissues", "tf", "render")
PIPELINE_STAGES = ("quantize", "similarity", "clustering", "classes", "tissues", "tf")


# ----------------------------------------------------------------------------------------------------- memory probes


def _status_kb(key: str) -> int:
    with open("/proc/self/status") as handle:
        match = re.search(rf"^{key}:\s+(\d+)\s+kB", handle.read(), re.MULTILINE)
    if match is None:
        raise OSError(f"{key} not in /proc/self/status")
    return int(match.group(1))


class PeakMeter:
    """Peak RSS over a stretch of code: kernel high-water mark reset (Linux), else a 1 ms psutil sampling thread."""

    def __init__(self) -> None:
        self.method = "clear_refs"
        try:
            self._reset_kernel()
            _status_kb("VmHWM")
        except OSError:
            self.method = "psutil-1ms"
            import psutil

            self._process = psutil.Process()
            self._peak = 0
            self._running = True
            self._thread = threading.Thread(target=self._sample, daemon=True)
            self._thread.start()

    @staticmethod
    def _reset_kernel() -> None:
        with open("/proc/self/clear_refs", "w") as handle:
            handle.write("5")

    def _sample(self) -> None:
        while self._running:
            self._peak = max(self._peak, self._process.memory_info().rss)
            time.sleep(0.001)

    def rss_mb(self) -> float:
        if self.method == "clear_refs":
            return _status_kb("VmRSS") / 1024.0
        return self._process.memory_info().rss / 2**20

    def reset(self) -> float:
        """Reset the peak to the current RSS; returns the current RSS in MB."""
        if self.method == "clear_refs":
            self._reset_kernel()
        else:
            self._peak = self._process.memory_info().rss
        return self.rss_mb()

    def peak_mb(self) -> float:
        if self.method == "clear_refs":
            return _status_kb("VmHWM") / 1024.0
        return max(self._peak, self._process.memory_info().rss) / 2**20


# ----------------------------------------------------------------------------------------------------- volumes


def _load_volume(cfg: dict) -> tuple[Any, tuple[float, float, float]]:
    """The configuration's volume ``[k, j, i]`` and spacing (x, y, z) mm."""
    import numpy as np

    from isosimtf.phantom import head_phantom

    source = cfg["source"]
    if source == "phantom":
        phantom = head_phantom(cfg["size"], seed=0)
        return phantom.values, phantom.spacing
    if source == "phantom-uint8":
        # The phantom rescaled to 8 bits: [-1024, 1016] HU -> 0..255 (8 HU per step), as an 8-bit export would.
        phantom = head_phantom(cfg["size"], seed=0)
        values = np.clip((phantom.values.astype(np.int32) + 1024) // 8, 0, 255).astype(np.uint8)
        return values, phantom.spacing
    if source == "noise-uint8":
        size = cfg["size"]
        return np.random.default_rng(0).integers(0, 256, (size, size, size), dtype=np.uint8), (1.0, 1.0, 1.0)
    if source == "phantom-dask":
        return _dask_phantom(cfg["size"]), (1.0, 1.0, 1.0)
    if source in ("head-ct", "brain-mri"):
        from isosimtf.volume_io import read_volume, real_dataset_path

        path = real_dataset_path(source)
        if path is None:
            raise FileNotFoundError(f"{source}: Debian data package not installed")
        volume = read_volume(path)
        return volume.values, volume.spacing
    raise ValueError(f"unknown source {source!r}")


def _dask_phantom(size: int) -> Any:
    """A volume larger than it needs to be in memory: the 512^3 int16 phantom in a raw file (written once to the temp
    folder), read lazily by dask in 32-plane chunks and tiled ``size // 512`` times along every axis."""
    import dask
    import dask.array as da
    import numpy as np

    from isosimtf.phantom import head_phantom

    path = Path(tempfile.gettempdir()) / "isosimtf-bench-phantom-512-int16.raw"
    if not path.exists():
        head_phantom(512, seed=0).values.astype("<i2").tofile(path)
    planes, plane_shape = 32, (512, 512)

    def read(first: int) -> Any:
        with open(path, "rb") as raw:
            raw.seek(first * 512 * 512 * 2)
            return np.fromfile(raw, dtype="<i2", count=planes * 512 * 512).reshape(planes, *plane_shape)

    chunks = [
        da.from_delayed(dask.delayed(read)(first), (planes, *plane_shape), "<i2") for first in range(0, 512, planes)
    ]
    tile, tiles = da.concatenate(chunks), size // 512
    return da.block([[[tile] * tiles] * tiles] * tiles)


# ----------------------------------------------------------------------------------------------------- child side


def _median(values: list[float]) -> float | None:
    values = sorted(v for v in values if v is not None)
    if not values:
        return None
    mid = len(values) // 2
    return values[mid] if len(values) % 2 else 0.5 * (values[mid - 1] + values[mid])


def _child_pipeline(cfg: dict) -> dict:
    """One configuration: load, a first (cold) call, warm runs with per-stage time and peak memory, renders."""
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import numpy as np

    import IsoSimilarityTFLib
    from IsoSimilarityTFLib import design_transfer_function
    from IsoSimilarityTFLib.clustering import ClusteringError
    from IsoSimilarityTFLib.design import STAGES as DESIGN_STAGES

    meter = PeakMeter()
    out: dict[str, Any] = {"config": cfg, "memory_method": meter.method, "loadavg_start": os.getloadavg()}
    out["rss_after_imports_mb"] = meter.rss_mb()
    options = dict(cfg.get("options", {}))
    repeats = int(cfg["repeats"])

    # load: the first one is measured for memory from the fresh process.
    load_times, load_peak = [], None
    values = spacing = None
    for _ in range(repeats if cfg.get("repeat_load", True) else 1):
        values = spacing = None
        start_rss = meter.reset()
        start = time.perf_counter()
        values, spacing = _load_volume(cfg)
        load_times.append(time.perf_counter() - start)
        if load_peak is None:
            load_peak = meter.peak_mb() - start_rss
    out["shape"] = list(values.shape)
    out["dtype"] = str(values.dtype)
    out["voxels"] = int(values.size)
    out["volume_mb"] = values.nbytes / 2**20

    def design_once(stage_memory: dict | None) -> Any:
        state = {"stage": None, "start_rss": 0.0}

        def progress(stage: str, fraction: float, message: str) -> None:
            if stage_memory is None:
                return
            if stage != state["stage"]:
                if state["stage"] is not None:
                    stage_memory[state["stage"]] = (meter.peak_mb() - state["start_rss"], meter.peak_mb())
                state["stage"], state["start_rss"] = stage, meter.reset()
            elif stage == DESIGN_STAGES[-1] and fraction >= 1.0:
                stage_memory[stage] = (meter.peak_mb() - state["start_rss"], meter.peak_mb())

        try:
            return design_transfer_function(values, spacing, progress=progress, **options), None
        except ClusteringError as error:
            kept = {**options, "unconverged": "keep"}
            return design_transfer_function(values, spacing, progress=progress, **kept), str(error)

    # first (cold) call
    start = time.perf_counter()
    design, note = design_once(None)
    first_total = time.perf_counter() - start
    start = time.perf_counter()
    design.volume_property()
    out["first_call"] = {
        **design.timings_s,
        "tf": time.perf_counter() - start,
        "total": first_total,
    }
    out["rss_before_runs_mb"] = meter.rss_mb()

    runs = []
    for _ in range(repeats):
        memory: dict[str, tuple[float, float]] = {}
        pipeline_start_rss = meter.rss_mb()
        design, note = design_once(memory)
        start_rss = meter.reset()
        start = time.perf_counter()
        volume_property = design.volume_property()
        tf_time = time.perf_counter() - start
        memory["tf"] = (meter.peak_mb() - start_rss, meter.peak_mb())
        times = {**design.timings_s, "tf": tf_time}
        runs.append(
            {
                "times": times,
                "pipeline": sum(times[s] for s in PIPELINE_STAGES),
                "memory_increase_mb": {s: m[0] for s, m in memory.items()},
                "process_peak_mb": max(m[1] for m in memory.values()),
                "pipeline_start_rss_mb": pipeline_start_rss,
            }
        )
    out["clustering"] = {k: v for k, v in design.clustering.items() if k != "empty_isovalues"}
    out["n_empty_isovalues"] = len(design.clustering.get("empty_isovalues", []))
    out["n_classes"] = design.clustering["n_classes"]
    out["clustering_note"] = note

    median_times = {s: _median([r["times"][s] for r in runs]) for s in PIPELINE_STAGES}
    median_times["load"] = _median(load_times)
    median_times["pipeline"] = _median([r["pipeline"] for r in runs])
    memory_increase = {s: max(r["memory_increase_mb"][s] for r in runs) for s in PIPELINE_STAGES}
    memory_increase["load"] = load_peak
    out["runs"] = runs
    out["load_times"] = load_times

    # extra similarity timings (e.g. the thesis' 8 levels on 256^3)
    if cfg.get("extra_levels"):
        from IsoSimilarityTFLib import quantize, similarity_matrix

        quantized = quantize(values, options.get("n_bins", 256))
        extra = []
        for _ in range(repeats):
            start = time.perf_counter()
            similarity_matrix(quantized.bins, quantized.n_bins, levels=int(cfg["extra_levels"]))
            extra.append(time.perf_counter() - start)
        out["similarity_levels"] = {"levels": int(cfg["extra_levels"]), "median_s": _median(extra), "times": extra}

    if cfg.get("looks"):
        out["looks"] = _measure_looks(design, repeats)

    if cfg.get("render"):
        from isosimtf.rendering import render_volume

        size = (512, 512)
        start = time.perf_counter()
        picture = render_volume(values, spacing, volume_property, size=size)
        out["first_render_s"] = time.perf_counter() - start
        render_times, render_peak = [], 0.0
        for _ in range(int(cfg.get("render_repeats", min(repeats, 3)))):
            start_rss = meter.reset()
            start = time.perf_counter()
            picture = render_volume(values, spacing, volume_property, size=size)
            render_times.append(time.perf_counter() - start)
            render_peak = max(render_peak, meter.peak_mb() - start_rss)
        median_times["render"] = _median(render_times)
        memory_increase["render"] = render_peak
        out["render_times"] = render_times
        out["render_nonblack_fraction"] = float(np.mean(picture.max(axis=2) > 10))

    out["median_s"] = median_times
    out["peak_increase_mb"] = memory_increase
    out["process_peak_mb"] = max(r["process_peak_mb"] for r in runs)
    out["pipeline_peak_increase_mb"] = max(r["process_peak_mb"] - r["pipeline_start_rss_mb"] for r in runs)
    out["loadavg_end"] = os.getloadavg()
    out["library_version"] = IsoSimilarityTFLib.__version__
    return out


def _measure_looks(design: Any, repeats: int) -> dict:
    """The gallery beyond the first click (made with the grouping), the thumbnails of looks.png, switching a look,
    and a regrouping (the Detail slider, the first click remade): medians over ``repeats`` rounds."""
    from isosimtf.outputs import THUMBNAIL_SIZE

    times: dict[str, list[float]] = {"gallery": [], "thumbnails": [], "switch": [], "regroup": []}
    for _ in range(repeats):
        design.look_name = None
        design.regroup(design.options["tissues"])  # as the design leaves it: the first look made, no gallery yet
        start = time.perf_counter()
        looks = design.looks
        times["gallery"].append(time.perf_counter() - start)
        start = time.perf_counter()
        for look in looks:
            design.thumbnail(look, size=THUMBNAIL_SIZE)
        times["thumbnails"].append(time.perf_counter() - start)
        start = time.perf_counter()
        for look in looks:
            design.use_look(look.name)
        times["switch"].append((time.perf_counter() - start) / len(looks))
        design.look_name = None
        start = time.perf_counter()
        design.regroup(design.options["tissues"])
        times["regroup"].append(time.perf_counter() - start)
    return {"n_looks": len(design.looks), **{f"{k}_s": _median(v) for k, v in times.items()}}


def _timed(function: Callable, *args: Any) -> float:
    """Seconds ``function(*args)`` takes."""
    start = time.perf_counter()
    function(*args)
    return time.perf_counter() - start


def similarity_floor(bins: Any, chunk_cells: int) -> Any:
    """The numpy floor of the similarity stage (issue 12): what no numpy similarity can do with less.

    Only the unit cells: their 2x2x2 minimum and maximum (three pairwise calls each, into preallocated buffers) and a
    bincount of the (min, max) pairs packed into a uint16 index, in chunks of about ``chunk_cells`` cells that stay in
    cache. No octree levels, no normalization. ``bins``: 3-D uint8. Returns the ``(256, 256)`` joint histogram.
    """
    import numpy as np

    n0, n1, n2 = bins.shape
    planes = max(1, chunk_cells // ((n1 - 1) * (n2 - 1)))
    pairs = np.empty((planes, n1, n2), dtype=np.uint8)
    rows = np.empty((planes, n1 - 1, n2), dtype=np.uint8)
    low, high = np.empty((2, planes, n1 - 1, n2 - 1), dtype=np.uint8)
    index = np.empty((planes, n1 - 1, n2 - 1), dtype=np.uint16)
    counts = np.zeros(1 << 16, dtype=np.int64)
    for first in range(0, n0 - 1, planes):
        p = min(planes, n0 - 1 - first)
        voxels = bins[first : first + p + 1]
        for reduce, out in ((np.minimum, low), (np.maximum, high)):
            reduce(voxels[:-1], voxels[1:], out=pairs[:p])
            reduce(pairs[:p, :-1], pairs[:p, 1:], out=rows[:p])
            reduce(rows[:p, :, :-1], rows[:p, :, 1:], out=out[:p])
        np.left_shift(low[:p], 8, out=index[:p], dtype=np.uint16)
        np.bitwise_or(index[:p], high[:p], out=index[:p])
        counts += np.bincount(index[:p].reshape(-1), minlength=1 << 16)
    return counts.reshape(256, 256)


def _child_floor(cfg: dict) -> dict:
    """Our similarity (all levels, defaults) against the numpy floor, interleaved in one process."""
    import numpy as np

    from IsoSimilarityTFLib import octree_levels, quantize, similarity_matrix
    from IsoSimilarityTFLib.stream import interval_histograms

    values, _ = _load_volume(cfg)
    bins = quantize(values, 256).bins
    del values
    all_levels = len(octree_levels(tuple(n - 1 for n in bins.shape)))

    chunk_times = {}
    for chunk in FLOOR_CHUNK_CELLS:
        similarity_floor(bins, chunk)
        chunk_times[chunk] = min(_timed(similarity_floor, bins, chunk) for _ in range(3))
    chunk = min(chunk_times, key=chunk_times.get)
    _, _, unit_level = next(interval_histograms(bins, 256, all_levels))
    floor_times, ours_times = [], []
    similarity_matrix(bins, 256)
    for _ in range(int(cfg["repeats"])):
        floor_times.append(_timed(similarity_floor, bins, chunk))
        ours_times.append(_timed(similarity_matrix, bins, 256))
    floor, ours = _median(floor_times), _median(ours_times)
    return {
        "config": cfg,
        "shape": list(bins.shape),
        "floor_chunk_cells": chunk,
        "floor_chunk_best_of_3_s": {str(k): v for k, v in chunk_times.items()},
        "floor_median_s": floor,
        "ours_median_s": ours,
        "multiple": ours / floor,
        "floor_times": floor_times,
        "ours_times": ours_times,
        "floor_equals_unit_level_histogram": bool(np.array_equal(similarity_floor(bins, chunk), unit_level)),
        "loadavg_end": os.getloadavg(),
    }


def design_floor(values: Any, chunk_cells: int) -> Any:
    """The numpy floor of the whole design (issue 25): one minimum and maximum, the quantization in slabs, the unit
    cells' joint histogram (:func:`similarity_floor`). Returns that histogram."""
    from IsoSimilarityTFLib.quantize import bin_volume

    low, high = float(values.min()), float(values.max())
    return similarity_floor(bin_volume(values, 256, (low, high), (low, high)), chunk_cells)


def _child_design_floor(cfg: dict) -> dict:
    """The whole design (defaults, no pictures) against its numpy floor, interleaved in one process."""
    import numpy as np

    from IsoSimilarityTFLib import design_transfer_function

    values, spacing = _load_volume(cfg)
    if cfg.get("padded"):  # float32 CT with a padding block outside the field of view
        values = values.astype(np.float32)
        values[:, :, : values.shape[2] // 10] = -3024.0

    chunk = FLOOR_CHUNK_CELLS[1]
    design_floor(values, chunk)
    design = design_transfer_function(values, spacing)
    floor_times, ours_times, stages = [], [], []
    for _ in range(int(cfg["repeats"])):
        floor_times.append(_timed(design_floor, values, chunk))
        start = time.perf_counter()
        design = design_transfer_function(values, spacing)
        ours_times.append(time.perf_counter() - start)
        stages.append(design.timings_s)
    floor, ours = _median(floor_times), _median(ours_times)
    median_stages = {stage: _median([s[stage] for s in stages]) for stage in stages[0]}
    after = sum(median_stages[s] for s in ("clustering", "classes", "tissues"))
    return {
        "config": cfg,
        "shape": list(values.shape),
        "dtype": str(values.dtype),
        "floor_median_s": floor,
        "ours_median_s": ours,
        "multiple": ours / floor,
        "stages_s": median_stages,
        "after_pass_over_pass": after / median_stages["similarity"],
        "loadavg_end": os.getloadavg(),
    }


def _child_reference(cfg: dict) -> dict:
    """Fast similarity against the explicit incidence-matrix reference on one small phantom."""
    import numpy as np

    sys.path.insert(0, str(ROOT / "Testing"))  # the reference lives with the tests
    from reference import reference_similarity_matrix

    from IsoSimilarityTFLib import quantize, similarity_matrix
    from isosimtf.phantom import head_phantom

    meter = PeakMeter()
    phantom = head_phantom(cfg["size"], seed=0)
    quantized = quantize(phantom.values, cfg["n_bins"])
    options = {"crossing": "inclusive", "normalization": "thesis"}
    fast_times = []
    similarity_matrix(quantized.bins, quantized.n_bins, **options)
    for _ in range(int(cfg["fast_repeats"])):
        start = time.perf_counter()
        fast = similarity_matrix(quantized.bins, quantized.n_bins, **options)
        fast_times.append(time.perf_counter() - start)
    reference_times, reference_peak = [], 0.0
    for _ in range(int(cfg["reference_repeats"])):
        start_rss = meter.reset()
        start = time.perf_counter()
        reference = reference_similarity_matrix(quantized.bins, quantized.n_bins, **options)
        reference_times.append(time.perf_counter() - start)
        reference_peak = max(reference_peak, meter.peak_mb() - start_rss)
    start_rss = meter.reset()
    similarity_matrix(quantized.bins, quantized.n_bins, **options)
    fast_peak = meter.peak_mb() - start_rss
    return {
        "config": cfg,
        "memory_method": meter.method,
        "shape": list(phantom.values.shape),
        "voxels": int(phantom.values.size),
        "fast_median_s": _median(fast_times),
        "fast_times": fast_times,
        "reference_median_s": _median(reference_times),
        "reference_times": reference_times,
        "fast_peak_increase_mb": fast_peak,
        "reference_peak_increase_mb": reference_peak,
        "max_abs_difference": float(np.max(np.abs(fast - reference))),
        "loadavg_end": os.getloadavg(),
    }


def _child_out_of_core(cfg: dict) -> dict:
    """A volume on disk, written once if missing (the tiled phantom, see big_volumes.py), read lazily by isosimtf's
    reader and designed once, end to end: time per stage and the process's peak RSS from start to end."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import big_volumes
    import numpy as np

    from IsoSimilarityTFLib import design_transfer_function
    from isosimtf.chunked_readers import read_chunked

    meter = PeakMeter()
    path = Path(cfg["path"])
    shape = tuple(cfg["shape"])
    if not path.exists():
        start = time.perf_counter()
        (big_volumes.write_zarr if cfg["format"] == "zarr" else big_volumes.write_nhdr)(path, shape)
        write_s = time.perf_counter() - start
    else:
        write_s = None
    start_rss = meter.reset()
    start = time.perf_counter()
    volume = read_chunked(path)
    design = design_transfer_function(volume.values, volume.spacing, **cfg.get("options", {}))
    total = time.perf_counter() - start
    return {
        "config": cfg,
        "shape": list(volume.shape),
        "dtype": str(volume.values.dtype),
        "voxels": int(np.prod(volume.shape, dtype=np.int64)),
        "volume_gib": float(np.prod(volume.shape, dtype=np.float64)) * volume.values.dtype.itemsize / 2**30,
        "chunks": [list(c[:2]) for c in volume.values.chunks],
        "write_s": write_s,
        "median_s": {**design.timings_s, "pipeline": total},
        "process_peak_mb": meter.peak_mb(),
        "rss_at_start_mb": start_rss,
        "n_classes": design.clustering["n_classes"],
        "converged": design.clustering["converged"],
        "memory_method": meter.method,
    }


def _child_main(text: str) -> None:
    cfg = json.loads(text)
    children = {
        "reference": _child_reference,
        "floor": _child_floor,
        "design-floor": _child_design_floor,
        "pipeline": _child_pipeline,
        "out_of_core": _child_out_of_core,
    }
    result = children[cfg["kind"]](cfg)
    print(CHILD_MARK + json.dumps(result), flush=True)


# ----------------------------------------------------------------------------------------------------- parent side


def run_child(cfg: dict, timeout: float) -> dict:
    """Run one configuration in a fresh interpreter; returns its result or ``{"error": ...}``."""
    env = dict(os.environ)
    env.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    command = [sys.executable, str(Path(__file__).resolve()), "--child", json.dumps(cfg)]
    start = time.perf_counter()
    try:
        completed = subprocess.run(command, capture_output=True, text=True, timeout=timeout, env=env, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"config": cfg, "error": f"did not finish within {timeout:.0f} s", "wall_s": timeout}
    for line in reversed(completed.stdout.splitlines()):
        if line.startswith(CHILD_MARK):
            result = json.loads(line[len(CHILD_MARK) :])
            result["wall_s"] = time.perf_counter() - start
            return result
    tail = (completed.stderr or completed.stdout).strip().splitlines()[-5:]
    return {"config": cfg, "error": f"exit code {completed.returncode}: " + " | ".join(tail)}


def run_latency(cfg: dict, timeout: float) -> dict:
    """Wall time of whole ``isosimtf`` commands, the way a user runs them: each variant in turn (interleaved, so a
    change of machine load hits them alike), ``repeats`` times; medians and the load average around the runs."""
    from isosimtf.volume_io import real_dataset_path

    source = real_dataset_path(cfg["source"])
    if source is None:
        return {"config": cfg, "error": f"{cfg['source']} is not installed"}
    env = dict(os.environ)
    env.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    command = [sys.executable, "-m", "isosimtf"]
    with tempfile.TemporaryDirectory(prefix="isosimtf-latency-") as folder:
        variants = {
            "help": [*command, "--help"],
            "no_render": [*command, str(source), "-o", str(Path(folder) / "no-render"), "--no-render", "-q"],
            "full": [*command, str(source), "-o", str(Path(folder) / "full"), "-q"],
        }
        times: dict[str, list[float]] = {name: [] for name in variants}
        load_before = os.getloadavg()
        for _ in range(cfg["repeats"]):
            for name, argv in variants.items():
                start = time.perf_counter()
                completed = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, env=env, cwd=ROOT)
                if completed.returncode != 0:
                    return {"config": cfg, "error": f"{name}: {completed.stderr.strip().splitlines()[-1:]}"}
                times[name].append(time.perf_counter() - start)
        stages = json.loads((Path(folder) / "full" / "classes.json").read_text())["timings_s"]
    return {
        "config": cfg,
        "median_s": {name: _median(values) for name, values in times.items()},
        "min_s": {name: min(values) for name, values in times.items()},
        "times_s": times,
        "last_full_run_stages_s": stages,
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(),
    }


def machine_description() -> dict:
    import numpy
    import vtk

    cpu = "unknown"
    try:
        with open("/proc/cpuinfo") as handle:
            for line in handle:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        import psutil

        ram_gb = psutil.virtual_memory().total / 2**30
    except ImportError:  # pragma: no cover
        ram_gb = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    try:
        from importlib.metadata import version

        slicer_core = version("slicer-core")
    except Exception:
        slicer_core = "not installed"
    return {
        "cpu": cpu,
        "logical_cores": os.cpu_count(),
        "ram_gb": round(ram_gb, 1),
        "os": platform.platform(),
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "vtk": vtk.vtkVersion.GetVTKVersion(),
        "slicer_core": slicer_core,
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "loadavg_at_start": os.getloadavg(),
    }


def configurations(quick: bool, data: Path | None = None, big: bool = False) -> dict[str, list[dict]]:
    """All benchmark cases, grouped by section."""
    rep_small, rep_large = (3, 1) if quick else (5, 3)
    phantom_sizes = (64, 128, 256) if quick else (64, 128, 256, 384, 512)
    sizes = []
    for n in phantom_sizes:
        cfg = {
            "kind": "pipeline",
            "name": f"phantom {n}^3 int16",
            "source": "phantom",
            "size": n,
            "repeats": rep_small if n <= 256 else rep_large,
            "render": not quick or n == 128,
            "extra_levels": 8 if n == 256 else None,
        }
        sizes.append(cfg)
    real = [
        {
            "kind": "pipeline",
            "name": "head CT (Cranium.inv3)",
            "source": "head-ct",
            "repeats": rep_small,
            "render": True,
            "looks": True,
        },
        {
            "kind": "pipeline",
            "name": "brain MRI (ch2.nii.gz)",
            "source": "brain-mri",
            "repeats": rep_small,
            "render": not quick,
            "looks": True,
        },
    ]
    targets = [
        {
            "kind": "pipeline",
            "name": "target: 256^3 uint8 (phantom, 8 HU/step)",
            "source": "phantom-uint8",
            "size": 256,
            "repeats": 3 if quick else 7,
            "render": False,
            "looks": True,
        },
        {
            "kind": "pipeline",
            "name": "stress: 256^3 uint8 white noise",
            "source": "noise-uint8",
            "size": 256,
            "repeats": 3 if quick else 5,
            "render": False,
            "options": {"unconverged": "keep"},
        },
    ]
    if quick:
        targets.append(
            {
                "kind": "pipeline",
                "name": "phantom 512^3 int16",
                "source": "phantom",
                "size": 512,
                "repeats": 1,
                "render": False,
                "repeat_load": False,
            }
        )
    bins = []
    for n_bins in (1024,) if quick else (1024, 4096):
        bins.append(
            {
                "kind": "pipeline",
                "name": f"phantom 128^3, {n_bins} bins",
                "source": "phantom",
                "size": 128,
                "repeats": 3 if n_bins <= 1024 else 1,
                "render": False,
                "repeat_load": False,
                # AP on >1000 isovalues often needs more than 200 iterations: time one damping, report convergence.
                "options": {"n_bins": n_bins, "unconverged": "keep"},
            }
        )
    reference = []
    for n in (16, 24) if quick else (16, 24, 32, 40, 48):
        reference.append(
            {
                "kind": "reference",
                "name": f"reference {n}^3",
                "size": n,
                "n_bins": 256,
                "fast_repeats": 7,
                "reference_repeats": 3 if n <= 24 else 1,
            }
        )
    floor = [
        {"kind": "floor", "name": "floor 256^3 uint8", "source": "phantom-uint8", "size": 256, "repeats": 11},
        {"kind": "floor", "name": "floor 512^3 int16, 256 bins", "source": "phantom", "size": 512, "repeats": 7},
    ]
    design_floor_cases = [
        {"kind": "design-floor", "name": "head CT", "source": "head-ct", "repeats": 7},
        {"kind": "design-floor", "name": "brain MRI", "source": "brain-mri", "repeats": 5},
        {"kind": "design-floor", "name": "256^3 uint8", "source": "phantom-uint8", "size": 256, "repeats": 5},
        {"kind": "design-floor", "name": "512^3 int16", "source": "phantom", "size": 512, "repeats": 3},
        {"kind": "design-floor", "name": "256^3 float32 padded", "source": "phantom", "size": 256, "padded": True,
         "repeats": 5},
    ]  # fmt: skip
    if quick:
        design_floor_cases = design_floor_cases[:3]
    if quick:
        for cfg in floor:
            cfg["repeats"] = 5
    out_of_core = [
        {
            "kind": "pipeline",
            "name": "out of core: 1024^3 int16 dask (raw file)",
            "source": "phantom-dask",
            "size": 1024,
            "repeats": 1,
            "render": False,
            "repeat_load": False,
            "options": {"unconverged": "keep"},
        },
    ]
    data = data or Path(tempfile.gettempdir())
    out_of_core.append(
        {
            "kind": "out_of_core",
            "name": OUT_OF_CORE_ZARR,
            "format": "zarr",
            "path": str(data / "isosimtf-bench-1024-uint16.zarr"),
            "shape": [1024, 1024, 1024],
            "options": {"unconverged": "keep"},
        }
    )
    if big:
        out_of_core.append(
            {
                "kind": "out_of_core",
                "name": OUT_OF_CORE_BIG,
                "format": "nhdr",
                "path": str(data / "isosimtf-bench-3200x2048x2048-uint16.nhdr"),
                "shape": [3200, 2048, 2048],
                "options": {"unconverged": "keep"},
                "timeout_s": 3600.0,
            }
        )
    latency = [{"kind": "latency", "name": "command line: head CT", "source": "head-ct", "repeats": 3 if quick else 7}]
    return {
        "latency": latency,
        "floor": floor,
        "design_floor": design_floor_cases,
        "out_of_core": out_of_core,
        "sizes": sizes,
        "real": real,
        "targets": targets,
        "bins": bins,
        "reference": reference,
    }


# ----------------------------------------------------------------------------------------------------- reporting


def _verdict(target: str, limit: float, measured: float, spec: str) -> list[str]:
    """A row of a targets table for a multiple that must stay at or under ``limit``."""
    return [target, f"<= {limit}x", f"{measured:{spec}}x", "PASS" if measured <= limit else "FAIL"]


def _fmt_s(value: float | None) -> str:
    if value is None:
        return "-"
    if value >= 100:
        return f"{value:.0f} s"
    if value >= 1:
        return f"{value:.2f} s"
    return f"{value * 1000:.1f} ms"


def _fmt_mb(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f} MB"


def _loads(loadavg: list[float]) -> str:
    return ", ".join(f"{value:.1f}" for value in loadavg)


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _by_name(results: list[dict], name: str) -> dict | None:
    return next((r for r in results if r["config"]["name"] == name and "error" not in r), None)


def _linear_fit(xs: list[float], ys: list[float]) -> dict:
    import numpy as np

    x, y = np.asarray(xs, dtype=float), np.asarray(ys, dtype=float)
    slope, intercept = np.polyfit(x, y, 1)
    predicted = slope * x + intercept
    ss_res, ss_tot = float(np.sum((y - predicted) ** 2)), float(np.sum((y - y.mean()) ** 2))
    loglog = float(np.polyfit(np.log(x), np.log(np.maximum(y, 1e-9)), 1)[0]) if len(x) > 1 else None
    return {
        "ns_per_voxel": float(slope * 1e9),
        "intercept_ms": float(intercept * 1e3),
        "r2": 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0,
        "loglog_exponent": loglog,
    }


def _looks_verdicts(results: list[dict]) -> list[list[str]]:
    """The rows of the issue 24 targets, one set per configuration that measured its looks."""
    rows = []
    for r in results:
        looks = r.get("looks")
        if not looks:
            continue
        similarity = r["median_s"]["similarity"]
        cost = looks["gallery_s"] + looks["thumbnails_s"]
        ratio = cost / similarity
        rows.append(
            [
                f"{r['config']['name']}: {looks['n_looks']} looks + thumbnails / similarity",
                f"<= {TARGET_LOOKS_OVER_SIMILARITY:g}x",
                f"{ratio:.2f}x ({_fmt_s(looks['gallery_s'])} + {_fmt_s(looks['thumbnails_s'])} vs "
                f"{_fmt_s(similarity)})",
                "PASS" if ratio <= TARGET_LOOKS_OVER_SIMILARITY else "FAIL",
            ]
        )
        for key, label, limit in (
            ("switch_s", "switching a look", TARGET_SWITCH_LOOK_S),
            ("regroup_s", "regrouping (Detail slider)", TARGET_REGROUP_S),
        ):
            rows.append(
                [
                    f"{r['config']['name']}: {label}",
                    f"<= {limit:g} s",
                    _fmt_s(looks[key]),
                    "PASS" if looks[key] <= limit else "FAIL",
                ]
            )
    return rows


def build_report(machine: dict, groups: dict[str, list[dict]], quick: bool, wall_s: float) -> tuple[str, dict]:
    """Markdown and JSON summaries (also the PASS/FAIL verdicts)."""
    everything = [r for group in groups.values() for r in group]
    md: list[str] = []
    summary: dict[str, Any] = {"machine": machine, "mode": "quick" if quick else "full", "wall_s": wall_s}
    md.append(f"# IsoSimilarityTF benchmark ({'quick' if quick else 'full'} run)\n")
    md.append("Written by `benchmarks/bench.py`; see `docs/evaluation.md` for the discussion.\n")
    md.append("## Machine\n")
    md.append(_table(["item", "value"], [[k, v] for k, v in machine.items()]))
    method = next((r.get("memory_method") for r in everything if r.get("memory_method")), "?")
    md.append(
        "\n\nTimes: median of warm runs (the first call of each fresh process is excluded and listed "
        "separately). Memory: peak RSS increase of the stage over the RSS at its start "
        f"(method: `{method}`; kernel peak-RSS reset + VmHWM, one fresh process per configuration). "
        "pipeline = quantize + similarity + clustering + classes + tissues + tf. "
        "Render = 512x512 headless Slicer CPU ray casting, new scene each time.\n"
    )

    # ---- targets
    verdicts = []
    uint8 = _by_name(everything, "target: 256^3 uint8 (phantom, 8 HU/step)")
    big = _by_name(everything, "phantom 512^3 int16")
    if uint8:
        sim = uint8["median_s"]["similarity"]
        pipe = uint8["median_s"]["pipeline"]
        verdicts.append(
            [
                "256^3 uint8 similarity (all 9 levels), median",
                f"<= {TARGET_SIM_256_UINT8_S} s",
                _fmt_s(sim),
                "PASS" if sim <= TARGET_SIM_256_UINT8_S else "FAIL",
            ]
        )
        verdicts.append(
            [
                "256^3 uint8 whole pipeline (quantize+similarity+AP+classes+TF), median",
                f"<= {TARGET_PIPELINE_256_UINT8_S} s",
                _fmt_s(pipe),
                "PASS" if pipe <= TARGET_PIPELINE_256_UINT8_S else "FAIL",
            ]
        )
    if big:
        pipe = big["median_s"]["pipeline"]
        peak = big["process_peak_mb"]
        ok = pipe <= TARGET_PIPELINE_512_INT16_S and peak <= TARGET_PEAK_512_INT16_MB
        verdicts.append(
            [
                "512^3 int16 whole pipeline, median; process peak RSS",
                f"<= {TARGET_PIPELINE_512_INT16_S} s; <= 1.5 GB",
                f"{_fmt_s(pipe)}; {peak / 1024:.2f} GB (pipeline's own increase "
                f"{big['pipeline_peak_increase_mb']:.0f} MB)",
                "PASS" if ok else "FAIL",
            ]
        )
    summary["targets"] = [dict(zip(["target", "limit", "measured", "verdict"], v)) for v in verdicts]
    md.append("\n## Targets of issue 6\n")
    md.append(_table(["target", "limit", "measured", "verdict"], verdicts))
    md.append(
        "\n\nThe 256^3 uint8 case is the phantom rescaled to 8 bits (8 HU per step); the 512^3 int16 case is the "
        "phantom. Process peak RSS includes the interpreter, the libraries and the input volume.\n"
    )

    # ---- issue 12: the numpy floor
    floor_rows, floor_summary, verdicts12 = [], [], []
    for r in groups.get("floor", []):
        name = r["config"]["name"]
        if "error" in r:
            floor_rows.append([name, "-", "-", r["error"], "-", "-"])
            continue
        floor_rows.append(
            [
                name,
                _fmt_s(r["floor_median_s"]),
                _fmt_s(r["ours_median_s"]),
                f"{r['multiple']:.2f}x",
                f"{r['floor_chunk_cells'] // 1024}K",
                "yes" if r["floor_equals_unit_level_histogram"] else "NO",
            ]
        )
        floor_summary.append({k: r[k] for k in ("floor_median_s", "ours_median_s", "multiple")} | {"name": name})
        verdicts12.append(
            _verdict(
                f"similarity / numpy floor, {name.removeprefix('floor ')}",
                TARGET_FLOOR_MULTIPLE,
                r["multiple"],
                ".2f",
            )
        )
    if big:
        peak = big["process_peak_mb"]
        verdicts12.append(
            [
                "512^3 int16 whole design, process peak RSS",
                f"<= {TARGET_PEAK_512_INT16_ISSUE12_MB:.0f} MB",
                f"{peak:.0f} MB (pipeline's own increase {big['pipeline_peak_increase_mb']:.0f} MB)",
                "PASS" if peak <= TARGET_PEAK_512_INT16_ISSUE12_MB else "FAIL",
            ]
        )
    for name, limit in (
        (OUT_OF_CORE_ZARR, TARGET_PEAK_1024_OUT_OF_CORE_MB),
        (OUT_OF_CORE_BIG, TARGET_PEAK_BEYOND_MEMORY_MB),
    ):
        case = _by_name(everything, name)
        if case and "error" not in case:
            verdicts12.append(
                [
                    f"{name}, designed end to end, process peak RSS",
                    f"<= {limit:.0f} MB",
                    f"{case['process_peak_mb']:.0f} MB in {_fmt_s(case['median_s']['pipeline'])}",
                    "PASS" if case["process_peak_mb"] <= limit else "FAIL",
                ]
            )
    out_of_core = _by_name(everything, "out of core: 1024^3 int16 dask (raw file)")
    if out_of_core and "error" not in out_of_core:
        peak = out_of_core["process_peak_mb"]
        verdicts12.append(
            [
                "1024^3 int16 (2 GB) designed out of core (dask over a raw file), process peak RSS",
                f"<= {TARGET_PEAK_1024_OUT_OF_CORE_MB:.0f} MB",
                f"{peak:.0f} MB in {_fmt_s(out_of_core['median_s']['pipeline'])}",
                "PASS" if peak <= TARGET_PEAK_1024_OUT_OF_CORE_MB else "FAIL",
            ]
        )
    latency = _by_name(everything, "command line: head CT")
    if latency and "error" not in latency:
        load = f"load {latency['loadavg_before'][0]:.1f} before, {latency['loadavg_after'][0]:.1f} after"
        for variant, words, limit in (
            ("no_render", "isosimtf Cranium.inv3 --no-render", TARGET_LATENCY_NO_RENDER_S),
            ("full", "isosimtf Cranium.inv3 (all pictures)", TARGET_LATENCY_FULL_S),
        ):
            measured = latency["median_s"][variant]
            verdicts12.append(
                [
                    f"{words}, wall time of the command, median",
                    f"<= {limit} s (quiet machine)",
                    f"{_fmt_s(measured)} ({load})",
                    "PASS" if measured <= limit else "FAIL",
                ]
            )
    summary["floor"] = floor_summary
    summary["latency"] = latency
    summary["targets"] += [dict(zip(["target", "limit", "measured", "verdict"], v)) for v in verdicts12]
    md.append("\n## Targets of issue 12\n")
    md.append(_table(["target", "limit", "measured", "verdict"], verdicts12))
    rows25, verdicts25, design_summary = [], [], []
    for r in groups.get("design_floor", []):
        name = r["config"]["name"]
        if "error" in r:
            rows25.append([name, "-", "-", "-", "-", "-", r["error"]])
            continue
        stages = r["stages_s"]
        rows25.append(
            [
                f"{name} ({' x '.join(map(str, r['shape']))} {r['dtype']})",
                _fmt_s(r["floor_median_s"]),
                _fmt_s(r["ours_median_s"]),
                f"{r['multiple']:.1f}x",
                DESIGN_FLOOR_BEFORE.get(name, "-"),
                ", ".join(f"{stage} {seconds * 1e3:.0f}" for stage, seconds in stages.items()),
                f"{r['after_pass_over_pass']:.1f}x",
            ]
        )
        design_summary.append({k: r[k] for k in ("floor_median_s", "ours_median_s", "multiple")} | {"name": name})
        verdicts25.append(
            _verdict(f"whole design / numpy floor, {name}", TARGET_DESIGN_FLOOR_MULTIPLE, r["multiple"], ".1f")
        )
        verdicts25.append(_verdict(f"stages after the pass / the pass, {name}", 1.0, r["after_pass_over_pass"], ".1f"))
    summary["design_floor"] = design_summary
    summary["targets"] += [dict(zip(["target", "limit", "measured", "verdict"], v)) for v in verdicts25]
    if rows25:
        md.append("\n\n## Targets of issue 25 (the whole design against its numpy floor)\n")
        md.append(
            "The floor: one minimum and maximum, the quantization, the unit cells' joint histogram, in numpy, timed "
            "interleaved with the whole design (defaults, no pictures) in one process. Stages in ms; the last "
            "column is clustering + classes + tissues over the similarity pass.\n\n"
        )
        md.append(
            _table(["volume", "floor", "design", "multiple", "before (issue)", "stages (ms)", "after / pass"], rows25)
        )
        md.append("\n\n")
        md.append(_table(["target", "limit", "measured", "verdict"], verdicts25))
    verdicts24 = _looks_verdicts(everything)
    summary["targets"] += [dict(zip(["target", "limit", "measured", "verdict"], v)) for v in verdicts24]
    md.append("\n\n## Targets of issue 24 (the gallery of looks)\n")
    md.append(
        "The gallery beyond the first click (which the tissues stage makes with the grouping), plus the "
        "thumbnails of looks.png, against the similarity pass of the same run; switching a look (per look); a "
        "regrouping with its first click remade (the Detail slider).\n\n"
    )
    md.append(_table(["target", "limit", "measured", "verdict"], verdicts24))
    if latency and "error" not in latency:
        md.append("\n\n### Command-line latency (head CT, whole commands, interleaved)\n")
        md.append(
            _table(
                ["command", "median", "min", "runs"],
                [
                    [
                        variant,
                        _fmt_s(latency["median_s"][variant]),
                        _fmt_s(latency["min_s"][variant]),
                        str(len(latency["times_s"][variant])),
                    ]
                    for variant in ("help", "no_render", "full")
                ],
            )
        )
        stages = ", ".join(f"{k} {_fmt_s(v)}" for k, v in latency["last_full_run_stages_s"].items())
        md.append(
            f"\n\nWall time of `python -m isosimtf` from start to exit, each variant in turn, "
            f"{latency['config']['repeats']} rounds; load average (1, 5, 15 min) {_loads(latency['loadavg_before'])} "
            f"before and {_loads(latency['loadavg_after'])} after (2 cores: a load above 1 slows every figure). "
            "Stages of the last full "
            f"run: {stages}.\n"
        )
    md.append("\n\n### Similarity against the numpy floor (same process, interleaved)\n")
    md.append(
        _table(
            ["case", "floor (median)", "ours (median)", "ours / floor", "floor chunk", "floor = our unit level"],
            floor_rows,
        )
    )
    md.append(
        "\n\nThe floor (`similarity_floor` in this file) is the least any numpy similarity must do: the unit cells' "
        "2x2x2 min and max and a bincount of their (min, max) pairs packed into a uint16 index, in cache-sized chunks "
        "(the fastest of "
        + ", ".join(f"{c // 1024}K" for c in FLOOR_CHUNK_CELLS)
        + " cells on this machine); no octree levels, no normalization. Ours is `similarity_matrix` with the defaults "
        "(256 bins, all levels). Each repetition runs the floor then ours; medians over the repetitions.\n"
    )

    # ---- per configuration stage table
    md.append("\n## Per-stage median time and peak memory increase\n")
    rows = []
    for r in everything:
        if r["config"]["kind"] != "pipeline":
            continue
        if "error" in r:
            rows.append([r["config"]["name"], "-", "-", r["error"], "", "", "", "", "", "", "", ""])
            continue
        med, mem = r["median_s"], r["peak_increase_mb"]
        cells = [r["config"]["name"], "x".join(str(n) for n in r["shape"]), str(len(r["runs"]))]
        for stage in STAGES:
            cells.append(f"{_fmt_s(med.get(stage))} / {_fmt_mb(mem.get(stage))}" if stage in med else "-")
        cells.append(_fmt_s(med["pipeline"]))
        cells.append(f"{r['process_peak_mb']:.0f} MB")
        conv = r["clustering"]
        cells.append(
            f"{r['n_classes']} ({'conv.' if conv['converged'] else 'NOT conv.'} {conv['n_iter']} it, "
            f"damping {conv.get('damping', '?')})"
        )
        rows.append(cells)
    md.append(
        _table(
            [
                "case",
                "shape (z,y,x)",
                "runs",
                *[f"{s} (time / mem)" for s in STAGES],
                "pipeline",
                "process peak",
                "AP classes",
            ],
            rows,
        )
    )
    md.append("\n\nFirst (cold) call in each fresh process, for comparison:\n")
    rows = []
    for r in everything:
        if r["config"]["kind"] == "pipeline" and "error" not in r:
            first = r["first_call"]
            rows.append(
                [
                    r["config"]["name"],
                    _fmt_s(first["clustering"]),
                    _fmt_s(first["total"]),
                    _fmt_s(r["median_s"]["clustering"]),
                    _fmt_s(r["median_s"]["pipeline"]),
                    _fmt_s(r.get("first_render_s")),
                ]
            )
    md.append(
        _table(
            [
                "case",
                "first-call clustering",
                "first-call total",
                "warm clustering",
                "warm pipeline",
                "first render (imports Slicer)",
            ],
            rows,
        )
    )

    # ---- scaling with voxel count
    sizes = [r for r in groups["sizes"] if "error" not in r]
    scaling = {}
    if len(sizes) >= 2:
        md.append("\n\n## Scaling with voxel count (phantom)\n")
        voxels = [r["voxels"] for r in sizes]
        # The fit leaves out volumes below 128^3, where fixed per-call costs (n_bins^2 work per level, Python
        # overhead) dominate; the local exponent is log(t2 / t1) / log(N2 / N1) between the two largest sizes.
        fit_at = [i for i, v in enumerate(voxels) if v >= 128**3] or list(range(len(voxels)))
        rows = []
        for stage in ("quantize", "similarity", "clustering", "classes", "tf", "pipeline"):
            times = [r["median_s"][stage] for r in sizes]
            fit = _linear_fit([voxels[i] for i in fit_at], [times[i] for i in fit_at])
            local = math.log(times[-1] / times[-2]) / math.log(voxels[-1] / voxels[-2]) if len(times) > 1 else None
            fit["local_exponent_largest"] = local
            scaling[stage] = {**fit, "voxels": voxels, "median_s": times, "fitted_sizes": fit_at}
            per_voxel = ", ".join(f"{t / v * 1e9:.1f}" for t, v in zip(times, voxels))
            rows.append(
                [
                    stage,
                    per_voxel,
                    f"{fit['ns_per_voxel']:.2f}",
                    f"{fit['intercept_ms']:.1f}",
                    f"{fit['r2']:.3f}",
                    f"{fit['loglog_exponent']:.2f}",
                    "-" if local is None else f"{local:.2f}",
                ]
            )
        fitted = ", ".join(f"{round(voxels[i] ** (1 / 3))}^3" for i in fit_at)
        md.append(
            _table(
                [
                    "stage",
                    "ns/voxel at " + ", ".join(f"{round(v ** (1 / 3))}^3" for v in voxels),
                    f"fit t = a + b N ({fitted}): b ns/voxel",
                    "a ms",
                    "R^2",
                    "log-log exponent (same sizes)",
                    "exponent between the two largest",
                ],
                rows,
            )
        )
        md.append(
            "\n\nAn exponent near 1 means linear in the voxel count. Clustering (AP on the n_bins x n_bins matrix) "
            "does not depend on the voxel count; its time follows the number of AP iterations (and the damping "
            "retries) of each volume.\n"
        )
    summary["scaling"] = scaling

    # ---- scaling with n_bins
    md.append("\n## Scaling with n_bins (phantom 128^3)\n")
    rows = []
    base = _by_name(everything, "phantom 128^3 int16")
    for r in ([base] if base else []) + list(groups["bins"]):
        if "error" in r:
            rows.append([r["config"]["name"], r["error"], "", "", "", "", ""])
            continue
        med, conv = r["median_s"], r["clustering"]
        rows.append(
            [
                r["config"].get("options", {}).get("n_bins", 256),
                _fmt_s(med["similarity"]),
                _fmt_s(med["clustering"]),
                _fmt_s(med["pipeline"]),
                f"{r['process_peak_mb']:.0f} MB",
                r["n_classes"],
                f"{'yes' if conv['converged'] else 'no'} ({conv['n_iter']} it)",
            ]
        )
    md.append(
        _table(
            ["n_bins", "similarity", "clustering (AP)", "pipeline", "process peak", "AP classes", "AP converged"], rows
        )
    )
    md.append(
        '\n\nFor n_bins > 256 the run uses `unconverged="keep"` (one damping, 200 iterations) so the AP time is '
        "one pass; the default `raise-damping` would add up to two more passes when AP does not converge.\n"
    )

    # ---- reference
    md.append("\n## Fast similarity vs the explicit reference (phantom, 256 bins, all levels, same run)\n")
    rows, ref_summary = [], []
    for r in groups["reference"]:
        if "error" in r:
            rows.append([f"{r['config']['size']}^3", "-", r["error"], "-", "-", "-"])
            ref_summary.append({"size": r["config"]["size"], "error": r["error"]})
            continue
        ratio = r["reference_median_s"] / r["fast_median_s"]
        rows.append(
            [
                f"{r['config']['size']}^3",
                _fmt_s(r["fast_median_s"]),
                f"{_fmt_s(r['reference_median_s'])} ({len(r['reference_times'])} run(s))",
                f"{ratio:,.0f}x",
                f"{r['fast_peak_increase_mb']:.0f} / {r['reference_peak_increase_mb']:.0f} MB",
                f"{r['max_abs_difference']:.1e}",
            ]
        )
        ref_summary.append(
            {
                "size": r["config"]["size"],
                "fast_s": r["fast_median_s"],
                "reference_s": r["reference_median_s"],
                "ratio": ratio,
                "max_abs_difference": r["max_abs_difference"],
            }
        )
    md.append(
        _table(
            ["size", "fast (median of 7)", "reference", "reference / fast", "peak mem fast / ref", "max abs diff"], rows
        )
    )
    summary["reference"] = ref_summary

    # ---- thesis
    md.append("\n\n## Against the thesis (Table 4.1 / 4.2: 256^3 volumes, 8 octree levels)\n")
    p256 = _by_name(everything, "phantom 256^3 int16")
    thesis = {}
    if p256:
        sim9 = p256["median_s"]["similarity"]
        sim8 = p256.get("similarity_levels", {}).get("median_s") or sim9
        clus = p256["median_s"]["clustering"]
        thesis = {
            "similarity_8_levels_s": sim8,
            "similarity_9_levels_s": sim9,
            "clustering_s": clus,
            "similarity_speedup": THESIS_SIMILARITY_S / sim8,
            "classification_speedup": [t / clus for t in THESIS_CLASSIFICATION_S],
        }
        rows = [
            ["similarity (8 levels)", "780 s (13 min)", _fmt_s(sim8), f"{THESIS_SIMILARITY_S / sim8:,.0f}x"],
            ["similarity (all 9 levels)", "-", _fmt_s(sim9), f"{THESIS_SIMILARITY_S / sim9:,.0f}x"],
            [
                "classification (AP on 256 isovalues)",
                "22-50 s",
                _fmt_s(clus),
                f"{THESIS_CLASSIFICATION_S[0] / clus:,.0f}x - {THESIS_CLASSIFICATION_S[1] / clus:,.0f}x",
            ],
        ]
        md.append(_table(["stage", "thesis", "this run (phantom 256^3)", "ratio thesis / this"], rows))
        md.append(
            "\n\nDifferent machines and volumes: the ratio says how far the cost moved, not a controlled comparison.\n"
        )
    summary["thesis"] = thesis
    summary["load_average"] = [r.get("loadavg_end") for r in everything]
    md.append(
        f"\n\nTotal benchmark wall time: {wall_s:.0f} s. Load average (1, 5, 15 min) at start: "
        f"{', '.join(f'{v:.2f}' for v in machine['loadavg_at_start'])}; at the end of each case: "
        + "; ".join(f"{r['config']['name']}: {r['loadavg_end'][0]:.2f}" for r in everything if r.get("loadavg_end"))
        + ".\n"
    )
    summary["results"] = groups
    return "\n".join(md) + "\n", summary


def print_console(summary: dict, groups: dict[str, list[dict]]) -> None:
    print("\nstage medians (warm) and peak RSS increase:")
    header = f"{'case':44s} " + " ".join(f"{s:>17s}" for s in (*STAGES, "pipeline"))
    print(header)
    for group in groups.values():
        for r in group:
            if r["config"]["kind"] != "pipeline":
                continue
            if "error" in r:
                print(f"{r['config']['name']:44s} ERROR {r['error']}")
                continue
            cells = []
            for stage in (*STAGES, "pipeline"):
                t = r["median_s"].get(stage)
                m = r["peak_increase_mb"].get(stage)
                cells.append(f"{_fmt_s(t):>9s}/{_fmt_mb(m):>7s}" if t is not None else f"{'-':>17s}")
            print(f"{r['config']['name']:44s} " + " ".join(cells))
    print("\nreference vs fast similarity:")
    for ref in summary["reference"]:
        if "error" in ref:
            print(f"  {ref['size']}^3: {ref['error']}")
        else:
            print(
                f"  {ref['size']}^3: fast {_fmt_s(ref['fast_s'])}, reference {_fmt_s(ref['reference_s'])}, "
                f"ratio {ref['ratio']:,.0f}x, max diff {ref['max_abs_difference']:.1e}"
            )
    if summary["thesis"]:
        t = summary["thesis"]
        print(
            f"\nthesis: similarity 780 s vs {_fmt_s(t['similarity_8_levels_s'])} (8 levels) = "
            f"{t['similarity_speedup']:,.0f}x; classification 22-50 s vs {_fmt_s(t['clustering_s'])} = "
            f"{t['classification_speedup'][0]:,.0f}x-{t['classification_speedup'][1]:,.0f}x"
        )
    for floor in summary.get("floor", []):
        print(
            f"{floor['name']}: floor {_fmt_s(floor['floor_median_s'])}, ours {_fmt_s(floor['ours_median_s'])}, "
            f"{floor['multiple']:.2f}x the floor"
        )
    print("\ntargets:")
    for v in summary["targets"]:
        print(f"  {v['verdict']}: {v['target']} {v['limit']}: {v['measured']}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="short run; writes bench-quick.md/.json")
    parser.add_argument("--out", type=Path, default=RESULTS, help="results folder (default benchmarks/results)")
    parser.add_argument("--only", default=None, help="comma-separated sections of the run")
    parser.add_argument("--data", type=Path, default=None, help="folder of the out-of-core volumes (default: temp)")
    parser.add_argument(
        "--big", action="store_true", help="also design a 25 GiB volume (written to --data once: ~2 min, 26 GB)"
    )
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child is not None:
        _child_main(args.child)
        return 0

    started = time.perf_counter()
    machine = machine_description()
    groups = configurations(args.quick, args.data, args.big)
    if args.only:
        keep = set(args.only.split(","))
        groups = {k: (v if k in keep else []) for k, v in groups.items()}
    results: dict[str, list[dict]] = {k: [] for k in groups}
    log: Callable[[str], None] = lambda text: print(text, flush=True)  # noqa: E731
    for section, cfgs in groups.items():
        for cfg in cfgs:
            timeout = cfg.get("timeout_s", 240.0 if cfg["kind"] == "reference" else 600.0)
            log(f"[{time.perf_counter() - started:6.0f} s] {cfg['name']} ...")
            result = run_latency(cfg, timeout) if cfg["kind"] == "latency" else run_child(cfg, timeout)
            if "error" in result:
                log(f"    ERROR: {result['error']}")
            elif cfg["kind"] in ("floor", "design-floor"):
                log(
                    f"    floor {_fmt_s(result['floor_median_s'])}, ours {_fmt_s(result['ours_median_s'])}: "
                    f"{result['multiple']:.2f}x"
                )
            elif cfg["kind"] == "latency":
                log("    " + ", ".join(f"{name} {_fmt_s(t)}" for name, t in result["median_s"].items()))
            elif cfg["kind"] == "reference":
                log(f"    fast {_fmt_s(result['fast_median_s'])}, reference {_fmt_s(result['reference_median_s'])}")
            else:
                log(
                    f"    pipeline {_fmt_s(result['median_s']['pipeline'])}, "
                    f"process peak {result['process_peak_mb']:.0f} MB, {result['n_classes']} classes"
                )
            results[section].append(result)
            if cfg["kind"] == "reference" and "error" in result:
                break  # larger sizes would take even longer
    wall = time.perf_counter() - started
    markdown, summary = build_report(machine, results, args.quick, wall)
    print_console(summary, results)
    args.out.mkdir(parents=True, exist_ok=True)
    stem = "bench-quick" if args.quick else "bench"
    (args.out / f"{stem}.md").write_text(markdown)
    (args.out / f"{stem}.json").write_text(json.dumps(summary, indent=1, default=float))
    print(f"\nwrote {args.out / (stem + '.md')} and {stem}.json in {wall:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
