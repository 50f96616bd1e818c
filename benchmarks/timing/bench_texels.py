"""Time UV-space rasterisation of the bundled bunny (3.7k faces, xatlas atlas) at T = 512.

    python benchmarks/timing/bench_texels.py

Prints the figures and saves them to benchmarks/results/bench_texels.json. The first call loads
(or compiles) the numba kernels and is reported separately; the warm figure is the median of
several runs. Peak memory is the largest Python-visible allocation (tracemalloc) of one warm run.
"""

from __future__ import annotations

import sys
from pathlib import Path

from freqbrdf.assets import mesh_path
from freqbrdf.capture.mesh import load_mesh
from freqbrdf.texels import dilate, rasterise, scatter

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import first_call_seconds, machine, median_seconds, peak_mib, save_results

TEXTURE_RES = 512
DILATION_PX = 8
REPEATS = 7


def main() -> None:
    mesh = load_mesh(mesh_path("bunny"))
    first_call, texels = first_call_seconds(lambda: rasterise(mesh, TEXTURE_RES))
    conservative_s = median_seconds(lambda: rasterise(mesh, TEXTURE_RES), REPEATS)
    centre_only_s = median_seconds(lambda: rasterise(mesh, TEXTURE_RES, conservative=False), REPEATS)
    peak = peak_mib(lambda: rasterise(mesh, TEXTURE_RES))

    image = scatter(texels, texels.normal.astype("float32"))
    dilate_s = median_seconds(lambda: dilate(image, texels.mask, DILATION_PX), REPEATS)

    result = {
        "benchmark": "texels: rasterise bunny in UV space",
        **machine(),
        "faces": len(mesh.faces),
        "texture_res": TEXTURE_RES,
        "texels": texels.n_texels,
        "snapped_texels": int(texels.snapped.sum()),
        "overlap_texels": texels.overlap_texels,
        "first_call_s": round(first_call, 4),
        "rasterise_s": round(conservative_s, 4),
        "rasterise_centre_only_s": round(centre_only_s, 4),
        "rasterise_peak_mib": round(peak, 2),
        "dilate_px": DILATION_PX,
        "dilate_rgb_float32_s": round(dilate_s, 4),
    }
    save_results("bench_texels", result)


if __name__ == "__main__":
    main()
