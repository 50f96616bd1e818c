"""The comparison of issue #5: our `global` estimator (also its fast preset, without its neighbour
vote and without its environment light), the paper's recipe (angular and spectrum forward models)
and Mitsuba 3 inverse rendering, on Mitsuba-rendered captures.

    python benchmarks/studies/compare_estimators.py [--scenes bunny,plane] [--texture-res 512]
        [--views 64] [--relight-spp 32] [--skip mitsuba,paper_spectrum] [--quick]

Each scene (scenes.COMPARE_SCENES) is rendered once by Mitsuba (cached in
benchmarks/.cache/compare_<scene>_<views>, scenes.compare_capture): a bundled mesh with the
procedural `bands` material under a bundled environment map, 64 views on the upper hemisphere,
and a relighting test set of 8 views under two other bundled maps. Every method gets the same
capture and texture resolution and is scored on the observed texels (base-colour PSNR, roughness
and metallic MAE) and by relighting (Stanford-ORB protocol, PSNR-H/PSNR-L/SSIM). Seconds are
wall-clock from the capture to the maps (our methods: observe + estimate, with their CPU seconds
beside them since the machine may be shared; `global` and `global_fast`, whose texels depend on
the pixels (TexelConfig.estimation_res "pixel" and "coarse"), the whole `pipeline.fit`: texels,
observe, estimate, uncertainty, upsampling and textures, all its CPU seconds under estimate;
Mitsuba: its own loop, image loading and compilation included). Saves JSON and a markdown table
to benchmarks/results/compare_estimators.{json,md}, merged into what is there: rows of methods
left out with ``--skip`` (or scenes not run) are kept from the earlier run, and every row says
when it was measured and under what load. ``--quick`` (a smoke run: 24 views of 128x128 pixels,
T = 128, 4 test views at 8 spp) writes compare_estimators_quick.{json,md} instead, so that it
never overwrites the full table.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

from freqbrdf import pipeline
from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, EstimateConfig, SurfaceConfig, TexelConfig, preset
from freqbrdf.estimate import estimate
from freqbrdf.fileio import atomic_path
from freqbrdf.observe.observations import observe
from freqbrdf.outputs import export, metrics
from freqbrdf.outputs.relight import RelightSettings, evaluate
from freqbrdf.render import inverse as baselines

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import RESULTS_DIR as RESULTS
from _common import control_seconds, machine
from scenes import FULL_RENDER, QUICK_RENDER, compare_capture, compare_settings

METHODS = ("whole_surface", "global", "global_without_vote", "global_fast", "global_environment_light", "global_fitted_light",
           "paper_angular", "paper_spectrum", "mitsuba")
QUICK_ARGS = {"views": 24, "texture_res": 128, "relight_spp": 8}


def method_config(method: str, texture_res: int) -> Config:
    """Our default Config for `whole_surface` (the whole-surface estimate); the `global*` methods
    are the per-texel estimate (SurfaceConfig.enabled off, `fit --per-texel`): `global`;
    `global_environment_light` without the prefiltered light (smooth lobes read the per-texel fit
    of the mirrored light); `global_fitted_light` without the environment light either (every lobe
    reads that fit); `global_without_vote`:
    without EstimateConfig.neighbour_vote; `global_fast`: the fast preset; the paper preset (its
    lambda, Adam, TV) for `paper_*`."""
    texels = TexelConfig(texture_res=texture_res)
    if method == "whole_surface":
        return Config(texels=texels)
    per_texel = SurfaceConfig(enabled=False)
    if method == "global_fast":
        fast = preset("fast")
        return fast.replace(texels=dataclasses.replace(fast.texels, texture_res=texture_res), surface=per_texel)
    if method.startswith("global"):
        return Config(texels=texels, surface=per_texel, estimate=EstimateConfig(
            environment_light=method != "global_fitted_light",
            prefiltered_light=method in ("global", "global_without_vote"),
            neighbour_vote=method != "global_without_vote"))
    model = method.split("_", 1)[1]
    config = preset("paper")
    return config.replace(texels=texels, estimate=dataclasses.replace(config.estimate, forward_model=model))


def run_scene(name: str, args) -> dict:
    render = QUICK_RENDER if args.quick else FULL_RENDER
    settings = compare_settings(name, args.views, args.texture_res, render)
    folder = compare_capture(name, args.views, args.texture_res, render)
    capture = load(folder)
    relight_settings = RelightSettings(spp=args.relight_spp)
    rows = {}
    observed_by_fit = {}  # FitConfig -> (observations, seconds): methods with the same fit share them

    def observations_for(config: Config):
        if config.fit not in observed_by_fit:
            start, cpu_start = time.perf_counter(), time.process_time()
            observations = observe(capture, config)
            observed_by_fit[config.fit] = (observations, time.perf_counter() - start,
                                           time.process_time() - cpu_start)
        return observed_by_fit[config.fit]

    for method in METHODS:
        if method in args.skip:
            continue
        print(f"[{name}] {method} ...", flush=True)
        # Mitsuba is scored on the texels our default observation sees, like the others.
        observations, observe_seconds, observe_cpu = observations_for(
            method_config("global" if method == "mitsuba" else method, args.texture_res))
        config = None if method == "mitsuba" else method_config(method, args.texture_res)
        if method == "mitsuba":
            maps, seconds, _ = baselines.mitsuba_inverse(capture, args.texture_res)
            timings = {"total": seconds}
        elif config.texels.estimation_res != "full":  # texels by the pixels: the whole fit
            start, cpu_start = time.perf_counter(), time.process_time()
            result = pipeline.fit(capture, config)
            maps = result.maps
            timings = {"observe": result.timings["observe"],
                       "estimate": result.timings["estimate"] + result.timings.get("upsample", 0.0),
                       "total": time.perf_counter() - start, "observe_cpu": 0.0,
                       "estimate_cpu": time.process_time() - cpu_start, "estimation_res": result.estimation_res}
        else:
            start, cpu_start = time.perf_counter(), time.process_time()
            result = estimate(observations, config)
            estimate_seconds, estimate_cpu = time.perf_counter() - start, time.process_time() - cpu_start
            maps = export.material_textures(result, config.texels.dilation_px)
            timings = {"observe": observe_seconds, "estimate": estimate_seconds,
                       "total": observe_seconds + estimate_seconds,
                       "observe_cpu": observe_cpu, "estimate_cpu": estimate_cpu}
        observed = observations.to_texture(observations.n_samples > 0, fill=False).astype(bool)
        texture = metrics.texture_scores(maps, capture.ground_truth, observed)
        relit = evaluate(capture, maps, settings=relight_settings).relighting
        rows[method] = {"seconds": timings, "texture": texture, "relighting": relit,
                        "measured": time.strftime("%Y-%m-%d %H:%M"), "load_average": machine()["load_average"],
                        "control_s": round(control_seconds(), 4)}
        print(f"[{name}] {method}: {json.dumps(rows[method])}", flush=True)
    return {"settings": dataclasses.asdict(settings), "capture": str(folder), "methods": rows}


def markdown(results: dict) -> str:
    lines = ["| scene | method | base colour PSNR | roughness MAE | metallic MAE | relight PSNR-H | PSNR-L | SSIM "
             "| seconds | CPU seconds |", "|---|---|---|---|---|---|---|---|---|---|"]
    for scene, data in results["scenes"].items():
        for method, row in data["methods"].items():
            t, r = row["texture"], row["relighting"]
            lines.append(f"| {scene} | {method} | {t['base_color_psnr']:.2f} | {t['roughness_mae']:.3f} | "
                         f"{t['metallic_mae']:.3f} | {r['psnr_hdr']:.2f} | {r['psnr_ldr']:.2f} | {r['ssim']:.3f} | "
                         f"{row['seconds']['total']:.1f} | {cpu_seconds(row['seconds'])} |")
    notes = [f"{scene}/{method}: {row['measured']}, load {row['load_average']}"
             + (f", control {row['control_s']:.2f} s" if "control_s" in row else "")
             for scene, data in results["scenes"].items() for method, row in data["methods"].items()
             if "measured" in row]
    text = "\n".join(lines) + "\n"
    if results.get("note"):
        text += "\n" + results["note"] + "\n"
    if notes:
        text += ("\nMeasured (2 cores; the load average is over 1 minute; control: `_common.control_seconds`, "
                 "the machine's speed at the time): " + "; ".join(notes) + ".\n")
    return text


def cpu_seconds(seconds: dict) -> str:
    """observe + estimate CPU seconds where they were recorded (not for Mitsuba or older rows)."""
    if "observe_cpu" not in seconds:
        return "-"
    return f"{seconds['observe_cpu'] + seconds['estimate_cpu']:.1f}"


def _set(settings: dict | None) -> dict:
    """Settings as recorded, tuples as lists, without the fields left at None (so that a field
    added to SynthSettings since, at its None default, keeps the earlier rows)."""
    return {key: value for key, value in (settings or {}).items() if value is not None}


def merged(previous: dict, scene: str, data: dict) -> dict:
    """The scene's new rows over the rows of an earlier run of the same capture and settings."""
    earlier = previous.get("scenes", {}).get(scene)
    if not earlier or _set(earlier.get("settings")) != _set(json.loads(json.dumps(data["settings"]))):
        return data
    return {**data, "methods": {**earlier["methods"], **data["methods"]}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", default="bunny,plane")
    parser.add_argument("--texture-res", type=int, default=512)
    parser.add_argument("--views", type=int, default=64)
    parser.add_argument("--relight-spp", type=int, default=32)
    parser.add_argument("--skip", default="", help="comma-separated methods to leave out")
    parser.add_argument("--quick", action="store_true",
                        help="small smoke-test settings; results go to compare_estimators_quick.*")
    parser.add_argument("--note", default=None, help="a sentence for the table (default: keep the earlier one)")
    args = parser.parse_args(argv)
    if args.quick:
        vars(args).update(QUICK_ARGS)
    args.skip = {method for method in args.skip.split(",") if method}
    results = {
        "benchmark": "estimator comparison (issue #5)",
        **machine(),
        "texture_res": args.texture_res,
        "relight_spp": args.relight_spp,
        "quick": args.quick,
        "scenes": {},
    }
    stem = "compare_estimators_quick" if args.quick else "compare_estimators"
    previous_path = RESULTS / f"{stem}.json"
    previous = json.loads(previous_path.read_text()) if previous_path.is_file() else {}
    results["scenes"] = dict(previous.get("scenes", {}))  # scenes not run this time are kept
    note = previous.get("note") if args.note is None else args.note
    if note:
        results["note"] = note
    for name in args.scenes.split(","):
        results["scenes"][name] = merged(previous, name, run_scene(name, args))
        RESULTS.mkdir(exist_ok=True)
        with atomic_path(RESULTS / f"{stem}.json") as tmp:
            tmp.write_text(json.dumps(results, indent=2, default=float) + "\n")
        with atomic_path(RESULTS / f"{stem}.md") as tmp:
            tmp.write_text(markdown(results))
    print(markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
