"""Time capture guidance (issue #28): seconds per pick for 100 candidates at T = 512.

The capture is studies/guidance.py's bunny pool (scenes.whole_surface_capture with
studies/guidance.py's RENDER, rendered into benchmarks/.cache/ if missing): its first ``--start``
farthest-point views are the views taken, ``--candidates`` of the rest are the candidates. Times,
separately: the whole-surface fit guidance reads (`guidance.surface_fit`, at the estimation
resolution `fit` uses), and `guidance.select_views` with that fit (its setup: the uncertainty
model and what every candidate samples; then each pick, as `Pick.seconds` reports it: scoring
every remaining candidate and committing one). Kernels are compiled by an untimed run first.

    python benchmarks/timing/bench_guidance.py [--texture-res 512] [--candidates 100] [--budget 10]
        [--max-texels N] [--estimation-res full] [--name bench_guidance]

Saves benchmarks/results/<name>.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
from pathlib import Path

from freqbrdf import pipeline
from freqbrdf.applications import guidance
from freqbrdf.applications.candidates import farthest_point_views, view_directions
from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, TexelConfig

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import control_seconds, machine, save_results  # noqa: E402
from scenes import whole_surface_capture  # noqa: E402

SCENE = "bunny_islands_overcast"
RENDER = {"views": 110, "resolution": 128, "spp": 16, "texture_res": 512, "test_views": 4}  # studies/guidance.py's


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--texture-res", type=int, default=512)
    parser.add_argument("--candidates", type=int, default=100)
    parser.add_argument("--start", type=int, default=8)
    parser.add_argument("--budget", type=int, default=10)
    parser.add_argument("--max-texels", type=int, default=guidance.MAX_TEXELS)
    parser.add_argument("--estimation-res", default=None,
                        help="TexelConfig.estimation_res (default: fit's; 'full' estimates on every texel of T)")
    parser.add_argument("--name", default="bench_guidance")
    args = parser.parse_args(argv)
    pool = load(whole_surface_capture(SCENE, RENDER))
    directions = view_directions(pool, [frame.camera for frame in pool.frames])
    start = farthest_point_views(directions, args.start)
    taken = dataclasses.replace(pool, frames=tuple(pool.frames[view] for view in start))
    candidates = [frame.camera for view, frame in enumerate(pool.frames) if view not in start][:args.candidates]
    config = Config(texels=TexelConfig(texture_res=args.texture_res))
    if args.estimation_res is not None:
        config = config.replace(texels=dataclasses.replace(config.texels, estimation_res=args.estimation_res))
    estimation_res = pipeline.estimation_resolution(taken, config)
    config = config.replace(texels=dataclasses.replace(config.texels, texture_res=estimation_res))

    warm = config.replace(texels=dataclasses.replace(config.texels, texture_res=32))
    guidance.select_views(taken, candidates[:3], 1, warm)  # compile, untimed
    control = control_seconds()
    began = time.perf_counter()
    fit = guidance.surface_fit(taken, config)
    fit_seconds = time.perf_counter() - began
    began = time.perf_counter()
    picks = guidance.select_views(taken, candidates, args.budget, config, fit=fit, max_texels=args.max_texels)
    select_seconds = time.perf_counter() - began
    pick_seconds = [pick.seconds for pick in picks]
    results = {
        **machine(), "control_seconds": control, "capture": whole_surface_capture(SCENE, RENDER).name,
        "texture_res": args.texture_res, "estimation_res": estimation_res, "texels": fit.texels.n_texels,
        "max_texels": args.max_texels, "candidates": len(candidates), "views_taken": len(start),
        "budget": args.budget, "fit_seconds": fit_seconds,
        "setup_seconds": select_seconds - sum(pick_seconds), "pick_seconds": pick_seconds,
        "pick_seconds_median": statistics.median(pick_seconds), "pick_seconds_max": max(pick_seconds),
    }
    save_results(args.name, results)
    print(f"T = {args.texture_res} (estimation {estimation_res}, {fit.texels.n_texels} texels), "
          f"{len(candidates)} candidates, {args.max_texels} texels scored: fit {fit_seconds:.1f} s, "
          f"setup {results['setup_seconds']:.1f} s, per pick median {results['pick_seconds_median']:.3f} s, "
          f"max {results['pick_seconds_max']:.3f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
