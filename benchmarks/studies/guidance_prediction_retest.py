"""How far a prediction can agree with the refit: the refit's own agreement with a retaken photo.

    python benchmarks/studies/guidance_prediction_retest.py [--scenes a,b] [--start 8] [--seeds 2]
        [--prediction guidance_prediction] [--name guidance_prediction_retest] [--merge part1,part2]
        [--rescore]

`guidance.py --prediction-only` compares, across 20 candidates, the guidance's predicted
uncertainty after adding a candidate with the uncertainty of the whole-surface posterior refitted
with the candidate's photograph (the pool's render, one path-tracer seed). The prediction sees
only where the candidate looks; the refit also sees what the photograph's noise does to the
fit (label outcomes, re-estimated precisions and calibrations). Here each of the same candidates
is photographed again: the same camera and scene rendered by Mitsuba with ``--seeds`` other
render seeds, and the start views plus that photograph are refitted. Spearman's rho between the
measured uncertainties of the pool's photograph and of a retaken one (the retest agreement,
per part too) bounds what any prediction from the candidate's geometry can reach: with the
measurement = a predictable part + independent noise, a perfect prediction agrees with one
photograph's refit at about sqrt(retest rho).

Reads the predictions and the pool's measurements from benchmarks/results/<--prediction>.json
(refused unless its start views and candidates are these); writes
benchmarks/results/<name>.json and prints a table; parts run side by side are merged with
``--merge``. The photographs' refits do not depend on the guidance's model: after a rerun of the
prediction check, ``--rescore`` recomputes the agreements from the stored refits.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from freqbrdf.applications.candidates import farthest_point_views, view_directions
from freqbrdf.capture.layouts import Frame, load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.images import read_image, write_exr, write_png
from freqbrdf.render.scenes import build_scene, principled_bsdf, render_view, view_seed
from freqbrdf.synthetic.synth import prepare

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
sys.path.insert(0, str(Path(__file__).resolve().parent))  # studies/: guidance

import guidance as study  # noqa: E402

from _common import RESULTS_DIR, machine, save_results  # noqa: E402
from scenes import whole_surface_capture, whole_surface_settings  # noqa: E402

RETEST_SEED = 1_000_003  # render seeds view_seed(RETEST_SEED + k, view), k = 0 .. --seeds - 1
PARTS = ("roughness", "metallic", "base_color")


def rho(a, b) -> float:
    return float(spearmanr(a, b).statistic)


def scene_run(name: str, stored: dict, args) -> dict:
    pool = load(whole_surface_capture(name, study.RENDER))
    settings = whole_surface_settings(name, study.RENDER)
    config = Config(texels=TexelConfig(texture_res=args.texture_res))
    start = farthest_point_views(view_directions(pool, [frame.camera for frame in pool.frames]), args.start)
    prediction = stored["prediction"]
    remaining = [view for view in range(len(pool.frames)) if view not in start]
    chosen = remaining[::max(1, len(remaining) // len(prediction["candidates"]))][:len(prediction["candidates"])]
    if start != stored["start_views"] or chosen != prediction["candidates"]:
        raise SystemExit(f"[{name}] start views or candidates differ from {args.prediction}'s: rerun it")
    synth = prepare(settings)
    scene = build_scene(synth.mesh, principled_bsdf(synth.materials), synth.envmap, settings.max_depth)
    retaken: list[list[list[float]]] = []  # [seed][candidate] -> parts
    with tempfile.TemporaryDirectory() as folder:
        # The re-rendering must reproduce the pool's photograph at the pool's seed.
        first = render_view(scene, pool.frames[chosen[0]].camera, settings.spp, view_seed(settings.seed, chosen[0]))
        write_exr(Path(folder) / "pool_seed.exr", first.radiance)
        reproduced = bool(np.array_equal(read_image(Path(folder) / "pool_seed.exr"),
                                         read_image(pool.frames[chosen[0]].image_path)))
        print(f"[{name}] pool photograph reproduced: {reproduced}", flush=True)
        for k in range(args.seeds):
            row = []
            for view in chosen:
                photo = render_view(scene, pool.frames[view].camera, settings.spp, view_seed(RETEST_SEED + k, view))
                frame = Frame(pool.frames[view].camera, Path(folder) / f"{view}_{k}.exr", Path(folder) / f"{view}_{k}.png")
                write_exr(frame.image_path, photo.radiance)
                write_png(frame.mask_path, photo.coverage)
                capture = dataclasses.replace(pool, frames=tuple(pool.frames[v] for v in start) + (frame,))
                _, _, area, parts = study.refitted_parts(capture, config, args)
                row.append(study.area_means(area, parts))
                print(f"[{name}] seed {k} view {view}: {row[-1]}", flush=True)
            retaken.append(row)
    result = {"start_views": start, "candidates": chosen, "pool_photo_reproduced": reproduced, "retaken_parts": retaken}
    return dict(result, **agreements(prediction, np.array(retaken)))


def agreements(prediction: dict, retaken: np.ndarray) -> dict:
    """Spearman's rho of the prediction and of the pool photograph's refit with each retaken one's.

    ``retaken``: (seeds, candidates, 3) the retaken refits' parts; per part and of their total.
    """
    measured = np.column_stack([prediction["parts"][part]["measured"] for part in PARTS])
    predicted = np.column_stack([prediction["parts"][part]["predicted"] for part in PARTS])
    seeds = len(retaken)
    result = {}
    for label, column in [("total", slice(None))] + [(part, k) for k, part in enumerate(PARTS)]:
        def value(array, column=column):
            return array[..., column].sum(axis=-1) if label == "total" else array[..., column]
        retest = [rho(value(measured), value(retaken[k])) for k in range(seeds)]
        result[label] = {
            "predicted_vs_pool_photo": rho(value(predicted), value(measured)),
            "predicted_vs_retaken": [rho(value(predicted), value(retaken[k])) for k in range(seeds)],
            "retest": retest,
            "ceiling": float(np.sqrt(max(np.mean(retest), 0.0))),
        }
    return result


def print_table(scenes: dict) -> None:
    print(f"{'scene':26s} " + " ".join(f"{label + ': pred / retest / ceiling':>38s}" for label in ("total",) + PARTS))
    for name, scene in scenes.items():
        cells = " ".join(f"{scene[label]['predicted_vs_pool_photo']:.2f} / {np.mean(scene[label]['retest']):.2f} / "
                         f"{scene[label]['ceiling']:.2f}".rjust(38) for label in ("total",) + PARTS)
        print(f"{name:26s} {cells}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", default=",".join(study.SCENES + ("bunny_cells_side",)))
    parser.add_argument("--start", type=int, default=study.START)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--texture-res", type=int, default=256)
    parser.add_argument("--max-texels", type=int, default=study.guidance.MAX_TEXELS)
    parser.add_argument("--prediction", default="guidance_prediction", help="the prediction check's results file")
    parser.add_argument("--name", default="guidance_prediction_retest")
    parser.add_argument("--merge", default="", help="comma-separated results files of parts to merge into --name")
    parser.add_argument("--rescore", action="store_true",
                        help="recompute the agreements of --name's retaken refits with a rerun --prediction (no render)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    stored = json.loads((RESULTS_DIR / f"{args.prediction}.json").read_text())
    if args.merge:
        parts = [json.loads((RESULTS_DIR / f"{part}.json").read_text()) for part in args.merge.split(",")]
        results = dict(parts[0], scenes={name: scene for part in parts for name, scene in part["scenes"].items()},
                       seconds=sum(part["seconds"] for part in parts))
    elif args.rescore:
        results = json.loads((RESULTS_DIR / f"{args.name}.json").read_text())
        for name, scene in results["scenes"].items():
            prediction = stored["scenes"][name]["prediction"]
            if prediction["candidates"] != scene["candidates"]:
                raise SystemExit(f"[{name}] the candidates differ from {args.prediction}'s")
            scene.update(agreements(prediction, np.array(scene["retaken_parts"])))
        results["prediction"] = args.prediction
    else:
        if stored["start"] != args.start:
            raise SystemExit(f"{args.prediction} starts from {stored['start']} views, not {args.start}")
        scenes = {name: scene_run(name, stored["scenes"][name], args) for name in args.scenes.split(",")}
        results = {
            "study": "retest agreement of the guidance's prediction check (issue #28)", **machine(),
            "start": args.start, "seeds": args.seeds, "texture_res": args.texture_res, "prediction": args.prediction,
            "render": study.RENDER, "scenes": scenes, "seconds": time.perf_counter() - started,
        }
    save_results(args.name, results)
    print_table(results["scenes"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
