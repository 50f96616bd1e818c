"""Time UV-space rasterisation of the bundled bunny (3.7k faces, xatlas atlas) at T = 512.

Prints the figures and saves them to benchmarks/results/bench_texels.json. The first call loads
(or compiles) the numba kernels and is reported separately; the warm figure is the median of
several runs. Peak memory is the largest Python-visible allocation (tracemalloc) of one warm run.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
import tracemalloc
from pathlib import Path

from freqbrdf.assets import mesh_path
from freqbrdf.mesh import load_mesh
from freqbrdf.texels import dilate, rasterise, scatter

RESULTS = Path(__file__).resolve().parent / "results" / "bench_texels.json"
TEXTURE_RES = 512
DILATION_PX = 8
REPEATS = 7


def median_seconds(run, repeats: int = REPEATS) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    mesh = load_mesh(mesh_path("bunny"))
    start = time.perf_counter()
    texels = rasterise(mesh, TEXTURE_RES)
    first_call = time.perf_counter() - start

    conservative_s = median_seconds(lambda: rasterise(mesh, TEXTURE_RES))
    centre_only_s = median_seconds(lambda: rasterise(mesh, TEXTURE_RES, conservative=False))
    tracemalloc.start()
    rasterise(mesh, TEXTURE_RES)
    _, peak_bytes = tracemalloc.get_traced_memory()
    tracemalloc.stop()

    image = scatter(texels, texels.normal.astype("float32"))
    dilate_s = median_seconds(lambda: dilate(image, texels.mask, DILATION_PX))

    result = {
        "benchmark": "texels: rasterise bunny in UV space",
        "cpu_count": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "faces": len(mesh.faces),
        "texture_res": TEXTURE_RES,
        "texels": texels.n_texels,
        "snapped_texels": int(texels.snapped.sum()),
        "overlap_texels": texels.overlap_texels,
        "first_call_s": round(first_call, 4),
        "rasterise_s": round(conservative_s, 4),
        "rasterise_centre_only_s": round(centre_only_s, 4),
        "rasterise_peak_mib": round(peak_bytes / 2**20, 2),
        "dilate_px": DILATION_PX,
        "dilate_rgb_float32_s": round(dilate_s, 4),
    }
    print(json.dumps(result, indent=2))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
