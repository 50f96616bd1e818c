"""Set-up shared by the benchmarks: timing, peak memory, machine facts, saving results.

The benchmarks are scripts in timing/ (how fast) and studies/ (measurements that informed a
decision), run from the repository root as ``python benchmarks/timing/bench_x.py``. Each inserts
this folder (benchmarks/) into sys.path before importing this module and scenes.py (the captures
they measure on). Results are written to benchmarks/results/ (``RESULTS_DIR``).
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path
from typing import Callable

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def median_seconds(run: Callable[[], object], repeats: int) -> float:
    """Median wall time of ``repeats`` calls of ``run``."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def first_call_seconds(run: Callable[[], object]) -> tuple[float, object]:
    """Wall time of one call (the first one loads or compiles numba kernels) and its result."""
    start = time.perf_counter()
    result = run()
    return time.perf_counter() - start, result


def peak_mib(run: Callable[[], object]) -> float:
    """Largest Python-visible allocation (tracemalloc, which numpy reports to) during one call."""
    tracemalloc.start()
    try:
        run()
        _, peak_bytes = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak_bytes / 2**20


def control_seconds(repeats: int = 3) -> float:
    """Median seconds of a fixed workload (eight 1500 x 1500 float64 matrix products on every core,
    then a sort of 4M floats on one), to tell how fast this machine runs at the moment: its speed
    drifts over time, so timings taken at different times compare fairly only relative to this."""
    import numpy as np

    rng = np.random.default_rng(0)
    matrix, values = rng.standard_normal((1500, 1500)), rng.standard_normal(4_000_000)

    def workload():
        for _ in range(8):
            matrix @ matrix
        np.sort(values)

    return median_seconds(workload, repeats)


def machine() -> dict:
    """What the figures depend on: core count, processor, load average at the time, Python."""
    return {
        "cpu_count": os.cpu_count(),
        "python": sys.version.split()[0],
        "machine": platform.processor() or platform.machine(),
        "load_average": round(os.getloadavg()[0], 2),
    }


def source_commit() -> str:
    """The commit the sources were checked out at ("" outside a git checkout), with "+" where they differ from it."""
    root = Path(__file__).resolve().parents[1]
    found = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    if found.returncode != 0:
        return ""
    changed = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--", "src"], capture_output=True,
                             text=True).stdout.strip()
    return found.stdout.strip() + ("+" if changed else "")


def save_results(name: str, result: dict) -> Path:
    """Print ``result`` and write it to benchmarks/results/<name>.json."""
    text = json.dumps(result, indent=2)
    print(text)
    path = RESULTS_DIR / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + "\n")
    return path
