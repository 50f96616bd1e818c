"""Time the material estimators on a Mitsuba-rendered capture and score them against its ground truth.

    python benchmarks/timing/bench_estimate.py [--scene bunny|plane] [--skip paper]

The capture is studies/compare_estimators.py's (scenes.compare_capture: 64 views, T = 512, the
`bands` material; rendered once and cached in benchmarks/.cache). Observations are made once with
the default settings; each estimator then runs warm (kernels compiled, or loaded from numba's
cache, on a small slice first). Scores are on the observed texels: base-colour PSNR, roughness and
metallic MAE. Runs: ``global`` (the default: split-sum specular albedo, Burley diffuse),
``global_method_model`` (the angular model of docs/method.md#forward-model, G1 masking and
shadowing with one light refresh, Lambert diffuse) and ``paper`` (the prototype's Adam).
Prints the figures and saves them to benchmarks/results/bench_estimate_<scene>.json with
os.cpu_count().
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, EstimateConfig, preset
from freqbrdf.estimate import estimate
from freqbrdf.fileio import atomic_path
from freqbrdf.model.materials import resize
from freqbrdf.observe.observations import Observations, observe

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import RESULTS_DIR as RESULTS
from scenes import COMPARE_SCENES, compare_capture

RUNS = {
    "global": Config(),
    "global_method_model": Config(estimate=EstimateConfig(specular_model="g1", diffuse_model="lambert")),
    "paper": preset("paper"),
}
WARMUP_TEXELS = 512


def scores(result, observations: Observations, truth) -> dict:
    """Base-colour PSNR and roughness / metallic MAE over the texels with samples."""
    truth = resize(truth, observations.texture_res)
    seen = observations.n_samples > 0
    index = observations.texel_index[seen]
    colour_mse = np.mean((result.base_color[seen] - truth.base_color.reshape(-1, 3)[index]) ** 2)
    return {
        "texels": int(seen.sum()),
        "base_color_psnr": round(float(-10.0 * np.log10(colour_mse)), 3),
        "roughness_mae": round(float(np.mean(np.abs(result.roughness[seen] - truth.roughness.reshape(-1)[index]))), 4),
        "metallic_mae": round(float(np.mean(np.abs(result.metallic[seen] - truth.metallic.reshape(-1)[index]))), 4),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="bunny", choices=sorted(COMPARE_SCENES))
    parser.add_argument("--skip", default="", help="comma-separated runs to leave out")
    args = parser.parse_args(argv)
    folder = compare_capture(args.scene)
    capture = load(folder)
    start = time.perf_counter()
    observations = observe(capture, Config())
    observe_seconds = time.perf_counter() - start
    result = {
        "benchmark": "estimate: per-texel base colour, roughness, metallic on a Mitsuba capture",
        "cpu_count": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "capture": str(folder),
        "texels": observations.n_texels,
        "views": observations.n_views,
        "lmax": observations.lmax,
        "observe_seconds": round(observe_seconds, 2),
        "estimators": {},
    }
    warmup = observations.select(slice(0, WARMUP_TEXELS))
    for name, config in RUNS.items():
        if name in args.skip.split(","):
            continue
        estimate(warmup, config)
        start, cpu_start = time.perf_counter(), time.process_time()
        estimated = estimate(observations, config)
        seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
        result["estimators"][name] = {
            "seconds": round(seconds, 3),
            "cpu_seconds": round(cpu_seconds, 3),
            "stages": {stage: round(value, 3) for stage, value in estimated.timings.items()},
            "settings": dataclasses.asdict(config.estimate),
            **scores(estimated, observations, capture.ground_truth),
        }
        row = result["estimators"][name]
        print(f"{name:>20}: {seconds:6.2f} s ({cpu_seconds:.1f} CPU s)  PSNR {row['base_color_psnr']:.2f}  "
              f"roughness MAE {row['roughness_mae']:.3f}  metallic MAE {row['metallic_mae']:.3f}", flush=True)
    RESULTS.mkdir(exist_ok=True)
    with atomic_path(RESULTS / f"bench_estimate_{args.scene}.json") as tmp:
        tmp.write_text(json.dumps(result, indent=2) + "\n")
    print(f"saved {RESULTS / f'bench_estimate_{args.scene}.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
