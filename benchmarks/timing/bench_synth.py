"""Time a synthetic capture: 64 views of the bunny, 256 x 256 pixels, 64 samples per pixel.

    python benchmarks/timing/bench_synth.py

The capture is scenes.SYNTH_TIMING_SCENE, rendered into a scratch folder after a one-view warm-up.
Prints the figures and saves them to benchmarks/results/bench_synth.json. Rendering runs on
Mitsuba's LLVM (CPU) backend, which uses every core, so the core count is part of the result.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

from freqbrdf.synthetic.synth import SynthSettings, synthesize

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import RESULTS_DIR
from scenes import SYNTH_TIMING_SCENE as SETTINGS

RESULTS = RESULTS_DIR / "bench_synth.json"


def main() -> None:
    with tempfile.TemporaryDirectory() as scratch:
        # A one-view warm-up compiles (or loads from Dr.Jit's cache) the rendering kernels,
        # so the timed run measures rendering, not compilation.
        synthesize(Path(scratch) / "warmup", SynthSettings(mesh="bunny", views=1, resolution=32,
                                                          spp=4, texture_res=64, test_views=0),
                   progress=False)
        start = time.perf_counter()
        synthesize(Path(scratch) / "capture", SETTINGS, progress=False)
        total = time.perf_counter() - start
    result = {
        "benchmark": "synth bunny capture",
        "cpu_count": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "views": SETTINGS.views,
        "resolution": SETTINGS.resolution,
        "spp": SETTINGS.spp,
        "texture_res": SETTINGS.texture_res,
        "total_s": round(total, 3),
        "per_view_s": round(total / SETTINGS.views, 4),
    }
    print(json.dumps(result, indent=2))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
