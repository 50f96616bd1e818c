"""The applications of the uncertainty (issue #8), measured on Mitsuba-rendered captures.

    python benchmarks/applications.py [--applications guidance] [--scenes bunny_forest,...]
        [--texture-res 128] [--pool 100] [--random-seeds 3]

One function per application; each returns its results, which are saved as JSON (and a plot) in
benchmarks/results/applications_<application>.{json,png}.

Scenes (``SCENES``): bundled meshes, materials and environment maps, each rendered once by Mitsuba
as a pool of ``--pool`` views evenly spread (Fibonacci) over the whole sphere around the object,
128 x 128 pixels at 16 spp, cached in benchmarks/.cache/applications_<scene>_<pool>.

guidance: every strategy starts from the same 10 farthest-point views of the pool and grows to 40,
10 views a round, at equal budgets:
- entropy-guided: `guidance.select_views` on the views taken so far (the fit's own observations),
  10 picks per round chosen before their photographs are "taken" (committed with the expected
  radiance), then the real photographs are used for the next round and the fits;
- random: uniformly from the rest of the pool, mean of ``--random-seeds`` seeds;
- farthest-point: the pool view farthest (in angle) from all taken so far.
Each subset is fitted with `pipeline.fit` (our defaults, T = --texture-res). Texture error is
measured against the ground truth on every texel some pool view samples (so that texels a
strategy leaves unseen count, with the exported fill), entropy as the mean over all atlas texels
(unobserved ones count 1). The paired test (Wilcoxon signed-rank, scipy) pairs the guided error
with each baseline's over all (scene, budget in 20/30/40) cells.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from _common import machine  # benchmarks/ is on sys.path when a script runs

from freqbrdf import guidance
from freqbrdf.capture import Capture, load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.export import write_json
from freqbrdf.fileio import atomic_path
from freqbrdf.materials import resize
from freqbrdf.observations import observe
from freqbrdf.pipeline import fit
from freqbrdf.synth import SynthSettings, synthesize
from freqbrdf.uncertainty import FLAG_UNOBSERVED

ROOT = Path(__file__).resolve().parent
CACHE = ROOT / ".cache"
RESULTS = ROOT / "results"
SCENES = {
    "bunny_forest": SynthSettings(mesh="bunny", envmap="forest", materials="bands"),
    "bunny_sunset": SynthSettings(mesh="bunny", envmap="sunset", materials="chelsea"),
    "sphere_city": SynthSettings(mesh="sphere", envmap="city", materials="coffee"),
    "sphere_studio": SynthSettings(mesh="sphere", envmap="studio", materials="astronaut"),
}
APPLICATIONS = ("guidance",)
INITIAL_VIEWS = 10
STEP_VIEWS = 10
FINAL_VIEWS = 40


def scene_capture(name: str, pool: int) -> Capture:
    """The scene's pool of views, rendered once (cached)."""
    settings = dataclasses.replace(SCENES[name], views=pool, cameras="sphere", resolution=128, spp=16,
                                   texture_res=256, test_views=0)
    folder = CACHE / f"applications_{name}_{pool}"
    if not folder.is_dir():
        start = time.perf_counter()
        synthesize(folder, settings, progress=False)
        print(f"[{name}] rendered {pool} views in {time.perf_counter() - start:.0f} s", flush=True)
    return load(folder)


def with_views(capture: Capture, views: list[int]) -> Capture:
    return dataclasses.replace(capture, frames=tuple(capture.frames[view] for view in views))


# --------------------------------------------------------------------------------------------
# Capture guidance


def guidance_scene(name: str, args) -> dict:
    pool = scene_capture(name, args.pool)
    config = Config(texels=TexelConfig(texture_res=args.texture_res))
    cameras = [frame.camera for frame in pool.frames]
    directions = guidance.view_directions(pool, cameras)
    # Texels some pool view samples: where every strategy could have looked.
    coverable = observe(pool, config).n_samples > 0
    truth = resize(pool.ground_truth, args.texture_res)
    initial = guidance.farthest_point_views(directions, INITIAL_VIEWS)

    def score(views: list[int]) -> tuple[dict, object]:
        result = fit(with_views(pool, views), config)
        index = result.observations.texel_index[coverable]
        maps = result.maps
        unobserved = (result.uncertainty.flags & FLAG_UNOBSERVED) != 0
        colour_error = maps.base_color.reshape(-1, 3)[index] - truth.base_color.reshape(-1, 3)[index]
        row = {
            "views": len(views),
            "roughness_mae": float(np.mean(np.abs(maps.roughness.ravel()[index] - truth.roughness.ravel()[index]))),
            "base_color_mae": float(np.mean(np.abs(colour_error))),
            "metallic_mae": float(np.mean(np.abs(maps.metallic.ravel()[index] - truth.metallic.ravel()[index]))),
            "entropy_mean": float(np.mean(result.uncertainty.entropy)),
            "observed_fraction": float(np.mean(~unobserved)),
            "fit_seconds": result.timings["total"],
        }
        return row, result

    start_row, start_fit = score(initial)
    curves: dict[str, list] = {}
    pick_seconds: list[float] = []
    views, current = list(initial), start_fit
    curves["guided"] = [start_row]
    while len(views) < FINAL_VIEWS:
        remaining = [view for view in range(len(cameras)) if view not in views]
        picks = guidance.select_views(with_views(pool, views), [cameras[view] for view in remaining], STEP_VIEWS,
                                      config, observations=current.observations, max_texels=args.max_texels)
        pick_seconds += [pick.seconds for pick in picks]
        views += [remaining[pick.candidate] for pick in picks]
        row, current = score(views)
        row["expected_entropy_of_subset"] = picks[-1].expected_entropy
        curves["guided"].append(row)
        print(f"[{name}] guided {len(views)}: {json.dumps(row)}", flush=True)

    views = list(initial)
    curves["farthest_point"] = [start_row]
    while len(views) < FINAL_VIEWS:
        views += guidance.farthest_point_views(directions, STEP_VIEWS, chosen=views)
        curves["farthest_point"].append(score(views)[0])
        print(f"[{name}] farthest-point {len(views)}: {json.dumps(curves['farthest_point'][-1])}", flush=True)

    random_runs = []
    for seed in range(args.random_seeds):
        rng = np.random.default_rng(seed)
        order = rng.permutation([view for view in range(len(cameras)) if view not in initial])
        run = [start_row]
        for count in range(INITIAL_VIEWS + STEP_VIEWS, FINAL_VIEWS + 1, STEP_VIEWS):
            run.append(score(initial + list(order[:count - INITIAL_VIEWS]))[0])
        random_runs.append(run)
        print(f"[{name}] random seed {seed}: {json.dumps(run[-1])}", flush=True)
    curves["random"] = [
        {key: float(np.mean([run[step][key] for run in random_runs])) for key in start_row}
        for step in range(len(random_runs[0]))
    ]
    return {
        "settings": dataclasses.asdict(dataclasses.replace(SCENES[name], views=args.pool, cameras="sphere")),
        "coverable_texels": int(coverable.sum()),
        "curves": curves,
        "random_runs": random_runs,
        "seconds_per_pick": {"mean": float(np.mean(pick_seconds)), "median": float(np.median(pick_seconds)),
                             "candidates": f"{args.pool - FINAL_VIEWS + STEP_VIEWS}..{args.pool - INITIAL_VIEWS}"},
    }


def paired_tests(scenes: dict) -> dict:
    """Guided vs each baseline over all (scene, budget > initial) cells, per metric."""
    from scipy.stats import wilcoxon

    tests = {}
    for baseline in ("random", "farthest_point"):
        for metric in ("roughness_mae", "base_color_mae", "entropy_mean"):
            guided = [row[metric] for scene in scenes.values() for row in scene["curves"]["guided"][1:]]
            other = [row[metric] for scene in scenes.values() for row in scene["curves"][baseline][1:]]
            difference = np.array(guided) - np.array(other)
            result = wilcoxon(guided, other) if np.any(difference != 0) else None
            tests[f"{metric}: guided vs {baseline}"] = {
                "pairs": len(difference),
                "guided_lower": int(np.sum(difference < 0)),
                "mean_difference": float(difference.mean()),
                "wilcoxon_p": None if result is None else float(result.pvalue),
            }
    return tests


def plot_guidance(scenes: dict, path: Path) -> None:
    from matplotlib.figure import Figure

    metrics = (("roughness_mae", "roughness MAE"), ("base_color_mae", "base colour MAE"), ("entropy_mean", "mean entropy"))
    figure = Figure(figsize=(3.6 * len(scenes), 3.0 * len(metrics)), dpi=100, layout="constrained")
    axes = figure.subplots(len(metrics), len(scenes), squeeze=False)
    styles = {"guided": ("C3", "entropy-guided"), "random": ("C0", "random (mean)"),
              "farthest_point": ("C2", "farthest-point")}
    for column, (name, scene) in enumerate(scenes.items()):
        for row, (metric, label) in enumerate(metrics):
            ax = axes[row, column]
            for strategy, (colour, legend) in styles.items():
                curve = scene["curves"][strategy]
                ax.plot([r["views"] for r in curve], [r[metric] for r in curve], "o-", color=colour, label=legend)
            for run in scene["random_runs"]:
                ax.plot([r["views"] for r in run], [r[metric] for r in run], color="C0", alpha=0.25, linewidth=0.8)
            ax.set_xlabel("views")
            ax.set_ylabel(label)
            if row == 0:
                ax.set_title(name)
    axes[0, 0].legend(fontsize=8)
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png")


def guidance_benchmark(args) -> dict:
    scenes = {}
    for name in args.scenes:
        scenes[name] = guidance_scene(name, args)
    results = {
        "application": "capture guidance (issue #8)",
        **machine(),
        "python": sys.version.split()[0],
        "texture_res": args.texture_res,
        "max_texels": args.max_texels,
        "pool": args.pool,
        "random_seeds": args.random_seeds,
        "views": list(range(INITIAL_VIEWS, FINAL_VIEWS + 1, STEP_VIEWS)),
        "scenes": scenes,
        "paired_tests": paired_tests(scenes),
    }
    plot_guidance(scenes, RESULTS / "applications_guidance.png")
    return results


# --------------------------------------------------------------------------------------------


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--applications", default=",".join(APPLICATIONS))
    parser.add_argument("--scenes", default=",".join(SCENES))
    parser.add_argument("--texture-res", type=int, default=128)
    parser.add_argument("--pool", type=int, default=100)
    parser.add_argument("--random-seeds", type=int, default=3)
    parser.add_argument("--max-texels", type=int, default=guidance.MAX_TEXELS)
    args = parser.parse_args(argv)
    args.scenes = args.scenes.split(",")
    runners = {"guidance": guidance_benchmark}
    RESULTS.mkdir(exist_ok=True)
    for application in args.applications.split(","):
        start = time.perf_counter()
        results = runners[application](args)
        results["seconds"] = time.perf_counter() - start
        write_json(RESULTS / f"applications_{application}.json", results)
        print(json.dumps(results.get("paired_tests", {}), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
