"""How much of the guidance study's relighting differences is the relighting's own render noise.

    python benchmarks/studies/guidance_relight_noise.py [--scenes a,b] [--budget 16] [--seeds 4]
        [--name NAME] [--merge part1,part2]

`guidance.py` scores each view set's fit by one relighting (`freqbrdf.outputs.relight.evaluate`,
16 spp, render seed 0) and compares the methods per scene x budget cell. Here, on the same pools
and start views, the view sets of farthest-point, random (seed 0) and the guidance
(`freqbrdf.applications.guidance.select_views`, rounds of ``guidance.STEP``) at ``--budget``
views are each fitted once and relit with ``--seeds`` render seeds: the spread of one set's
PSNR-H over the seeds is the metric's noise, and the difference of two sets per seed says
whether their order holds beyond it. Each fit's roughness, metallic and base-colour MAE are
recorded over the texels some pool view samples (as `guidance.py` scores them) and over those the
relighting's test views show, weighted by their samples there (``errors``): where the errors
fall says which texels the relighting judges.

Writes benchmarks/results/<name>.json and prints a table; parts run side by side (``--scenes`` and
``--name``) are merged with ``--merge``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from freqbrdf.applications import guidance as package_guidance
from freqbrdf.applications.candidates import farthest_point_views, view_directions
from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.model.materials import resize
from freqbrdf.observe.observations import observe
from freqbrdf.outputs.relight import evaluate
from freqbrdf.pipeline import fit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
sys.path.insert(0, str(Path(__file__).resolve().parent))  # studies/: guidance

import guidance as study  # noqa: E402

from _common import RESULTS_DIR, machine, save_results  # noqa: E402
from scenes import whole_surface_capture  # noqa: E402

PAIRS = (("guidance", "farthest_point"), ("guidance", "random"), ("farthest_point", "random"))


def guided_views(pool, start: list[int], budget: int, config: Config) -> list[int]:
    """The guidance's view set at ``budget`` views, picked in rounds as `guidance.py` does."""
    cameras = [frame.camera for frame in pool.frames]
    views = list(start)
    while len(views) < budget:
        remaining = [view for view in range(len(cameras)) if view not in views]
        taken = study.with_views(pool, views)
        surface = package_guidance.surface_fit(taken, config)
        picks = package_guidance.select_views(taken, [cameras[view] for view in remaining],
                                              min(study.STEP, budget - len(views)), config, fit=surface)
        views += [remaining[pick.candidate] for pick in picks]
    return views


def parameter_errors(maps, truth, index: np.ndarray, weights: np.ndarray | None) -> dict:
    """Roughness, metallic and base-colour MAE over the texels ``index`` (weighted by ``weights``)."""
    def mae(estimate, reference):
        error = np.abs(estimate - reference)
        return float(np.average(error.reshape(len(index), -1).mean(axis=1), weights=weights))
    return {"roughness_mae": mae(maps.roughness.ravel()[index], truth.roughness.ravel()[index]),
            "metallic_mae": mae(maps.metallic.ravel()[index], truth.metallic.ravel()[index]),
            "base_color_mae": mae(maps.base_color.reshape(-1, 3)[index], truth.base_color.reshape(-1, 3)[index])}


def scene_run(name: str, budget: int, seeds: int, texture_res: int) -> dict:
    pool = load(whole_surface_capture(name, study.RENDER))
    config = Config(texels=TexelConfig(texture_res=texture_res))
    directions = view_directions(pool, [frame.camera for frame in pool.frames])
    start = farthest_point_views(directions, study.START)
    order = np.random.default_rng(0).permutation([view for view in range(len(pool.frames)) if view not in start])
    view_sets = {
        "guidance": guided_views(pool, start, budget, config),
        "farthest_point": start + farthest_point_views(directions, budget - study.START, chosen=list(start)),
        "random": start + [int(view) for view in order[:budget - study.START]],
    }
    truth = resize(pool.ground_truth, texture_res)
    pooled = observe(pool, config)
    tested = observe(dataclasses.replace(pool, frames=pool.test_frames), config)
    where = {"coverable": (pooled.texel_index[pooled.n_samples > 0], None),
             "test_views": (tested.texel_index[tested.n_samples > 0], tested.n_samples[tested.n_samples > 0])}
    psnr, errors = {}, {}
    for method, views in view_sets.items():
        taken = study.with_views(pool, views)
        maps = fit(taken, config).maps
        errors[method] = {region: parameter_errors(maps, truth, index, weights)
                          for region, (index, weights) in where.items()}
        psnr[method] = [float(evaluate(taken, maps, settings=dataclasses.replace(study.RELIGHT, seed=seed))
                              .relighting["psnr_hdr"]) for seed in range(seeds)]
    differences = {f"{a} - {b}": (np.array(psnr[a]) - np.array(psnr[b])).tolist() for a, b in PAIRS}
    return {
        "views": view_sets,
        "psnr_hdr": psnr,
        "errors": errors,
        "seed_std": {method: float(np.std(values, ddof=1)) for method, values in psnr.items()},
        "differences": differences,
        "difference_mean": {pair: float(np.mean(values)) for pair, values in differences.items()},
        "difference_std": {pair: float(np.std(values, ddof=1)) for pair, values in differences.items()},
    }


def print_table(scenes: dict) -> None:
    pairs = [f"{a} - {b}" for a, b in PAIRS]
    print(f"{'scene':26s} {'seed std: guid / fp / rand':26s} " + " ".join(f"{pair:>30s}" for pair in pairs))
    for name, scene in scenes.items():
        stds = " / ".join(f"{scene['seed_std'][method]:.3f}" for method in ("guidance", "farthest_point", "random"))
        cells = " ".join(f"{scene['difference_mean'][pair]:+.3f} +- {scene['difference_std'][pair]:.3f} dB".rjust(30)
                         for pair in pairs)
        print(f"{name:26s} {stds:26s} {cells}")
    print(f"{'scene':26s} {'region':12s} " + " ".join(f"{method + ': R / M / BC MAE':>36s}"
                                                      for method in ("guidance", "farthest_point", "random")))
    for name, scene in scenes.items():
        for region in ("coverable", "test_views"):
            cells = " ".join(" / ".join(f"{scene['errors'][method][region][metric]:.4f}" for metric in study.METRICS[:3])
                             .rjust(36) for method in ("guidance", "farthest_point", "random"))
            print(f"{name:26s} {region:12s} {cells}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", default=",".join(study.SCENES))
    parser.add_argument("--budget", type=int, default=16)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--texture-res", type=int, default=256)
    parser.add_argument("--name", default=None,
                        help="results file stem (default: guidance_relight_noise, _<budget> for a budget other than 16)")
    parser.add_argument("--merge", default="", help="comma-separated results files of parts to merge into --name")
    args = parser.parse_args(argv)
    if args.name is None:
        args.name = "guidance_relight_noise" + ("" if args.budget == 16 else f"_{args.budget}")
    started = time.perf_counter()
    if args.merge:
        parts = [json.loads((RESULTS_DIR / f"{part}.json").read_text()) for part in args.merge.split(",")]
        results = dict(parts[0], scenes={name: scene for part in parts for name, scene in part["scenes"].items()},
                       seconds=sum(part["seconds"] for part in parts))
    else:
        scenes = {name: scene_run(name, args.budget, args.seeds, args.texture_res)
                  for name in args.scenes.split(",")}
        results = {
            "study": "render noise of the guidance study's relighting (issue #28)", **machine(),
            "budget": args.budget, "seeds": args.seeds, "texture_res": args.texture_res,
            "relight": dataclasses.asdict(study.RELIGHT), "scenes": scenes, "seconds": time.perf_counter() - started,
        }
    save_results(args.name, results)
    print_table(results["scenes"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
