"""Capture guidance against farthest-point and random views (issue #28).

    python benchmarks/studies/guidance.py [--scenes a,b] [--texture-res 256] [--random-seeds 5]
        [--spearman-candidates 20] [--misfit] [--methods m1,m2 --baselines guidance]
        [--misfit-width W --refit-noise F] [--name guidance] [--merge part1,part2]
        [--prediction-only [--start 8]]

Scenes (``SCENES``, from scenes.WHOLE_SURFACE_SCENES): the bunny with metal islands under the
overcast map (cameras all around), the dragon with metal and dielectric cells under the low sun
of "sunset" (all around), the sphere with smooth gradients in the "lobby" (upper hemisphere),
the dragon with a photo texture under the raised sun, cameras on one side only. Each is rendered
once by Mitsuba (path traced) as a pool of ``POOL`` views of the scene's camera layout, ``RENDER``
(pixels, spp), with relighting views under two other maps, cached in benchmarks/.cache/.

Every method starts from the same ``START`` farthest-point views of the pool and grows to
``FINAL`` views, ``STEP`` a round, choosing among the rest of the pool (the candidates):
- ``uncertainty``: `freqbrdf.applications.guidance.select_views` (the package's guidance) on the
  views so far, ``STEP`` picks a round, then their photographs are taken (the pool's renders);
- ``farthest_point``: the pool view farthest (in angle) from all taken so far;
- ``random``: uniformly from the rest of the pool, ``--random-seeds`` seeds.
Each view set is fitted by `freqbrdf.pipeline.fit` (defaults, whole-surface estimate, T =
``--texture-res``) and scored against the ground truth: roughness, metallic and base-colour MAE on
the texels some pool view samples (where any method could look), relighting PSNR-H over the test
views (`freqbrdf.outputs.relight.evaluate`, ``RELIGHT``). Paired tests (Wilcoxon signed-rank)
pair the guidance with each baseline over all scene x budget cells after the start.

Prediction check: from the start views, for ``--spearman-candidates`` candidates spread over the
pool, the guidance's predicted mean uncertainty (area-weighted std of roughness + metallic + mean
base colour over its scored texels) after adding the candidate, against the same quantity of the
whole-surface posterior refitted with its photograph; Spearman's rho across candidates, per scene.
Per round, the prediction after the round's picks against the refit's. Each part of the mean
(roughness, metallic, base colour) is compared too (``parts``); ``--prediction-only`` runs these
checks alone (results: each scene's ``prediction``). Every fit also records the
posterior's mean std over the coverable texels (``posterior_std``): within a cell, Spearman's rho
between it and each error over the view sets says whether lowering the posterior std can lower
the error at all (``posterior_std_against_error``).

Misfit check (``--misfit``): how the residuals of per-texel estimates of the whole pool
correlate between two samples of a texel, against the angle between their view directions
(`misfit_correlation`), which sets the width of the guidance's kernel
(`freqbrdf.applications._diversity`); ``--misfit-width`` (0: no discount) and ``--refit-noise``
(0: the best gain only) replace its constants for a run (variants). ``--methods`` runs only some
methods and takes the others' curves from the results file ``--baselines`` (refused unless the
start views' fit gives the same errors).

Writes benchmarks/results/guidance.{json,png} (``--name``); parts run side by side (``--scenes``
and ``--name``) are merged with ``--merge``, and ``--held-out`` adds a run on scenes the
guidance's constants were not chosen on (``held_out``, its own paired tests). A run with
``--spearman-candidates 0`` skips the prediction checks.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from freqbrdf.applications import _diversity, guidance
from freqbrdf.applications.candidates import farthest_point_views, view_directions
from freqbrdf.capture.layouts import Capture, load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.fileio import atomic_path, write_json
from freqbrdf.model.brdf import band_limit_sigma
from freqbrdf.model.materials import resize
from freqbrdf.observe.observations import observe
from freqbrdf.outputs.relight import RelightSettings
from freqbrdf.outputs.relight import evaluate as relight_evaluate
from freqbrdf.pipeline import fit
from freqbrdf.texels import rasterise

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes

from _common import RESULTS_DIR as RESULTS  # noqa: E402
from _common import machine  # noqa: E402
from scenes import whole_surface_capture  # noqa: E402

SCENES = ("bunny_islands_overcast", "dragon_cells_sunset", "sphere_gradients_lobby", "dragon_photo_side")
POOL = 110
RENDER = {"views": POOL, "resolution": 128, "spp": 16, "texture_res": 512, "test_views": 4}
START = 8
STEP = 8
FINAL = 40
RELIGHT = RelightSettings(spp=16, lpips=False)
METHODS = ("uncertainty", "farthest_point", "random")
METRICS = ("roughness_mae", "metallic_mae", "base_color_mae", "psnr_hdr")


def with_views(capture: Capture, views: list[int]) -> Capture:
    return dataclasses.replace(capture, frames=tuple(capture.frames[view] for view in views))


def scene_run(name: str, args) -> dict:
    pool = load(whole_surface_capture(name, RENDER))
    config = Config(texels=TexelConfig(texture_res=args.texture_res))
    cameras = [frame.camera for frame in pool.frames]
    directions = view_directions(pool, cameras)
    pooled = observe(pool, config)
    coverable = pooled.n_samples > 0
    misfit = misfit_correlation(pool, config, pooled) if args.misfit else None
    print(f"[{name}] misfit correlation {json.dumps(misfit)}", flush=True)
    truth = resize(pool.ground_truth, args.texture_res)
    area = rasterise(pool.mesh, args.texture_res).texel_area
    start = farthest_point_views(directions, START)

    def score(views: list[int]) -> dict:
        result = fit(with_views(pool, views), config)
        index = result.observations.texel_index[coverable]
        maps = result.maps
        relit = relight_evaluate(with_views(pool, views), maps, settings=RELIGHT).relighting
        uncertainty = result.uncertainty
        std = np.nan_to_num(uncertainty.roughness_std + uncertainty.metallic_std
                            + uncertainty.base_color_std.mean(axis=1))[coverable]
        return {
            "views": len(views),
            "roughness_mae": float(np.mean(np.abs(maps.roughness.ravel()[index] - truth.roughness.ravel()[index]))),
            "metallic_mae": float(np.mean(np.abs(maps.metallic.ravel()[index] - truth.metallic.ravel()[index]))),
            "base_color_mae": float(np.mean(np.abs(maps.base_color.reshape(-1, 3)[index]
                                                   - truth.base_color.reshape(-1, 3)[index]))),
            "psnr_hdr": float(relit["psnr_hdr"]),
            "posterior_std": float(np.dot(area[coverable], std) / area[coverable].sum()),
        }

    def log(method: str, row: dict) -> None:
        print(f"[{name}] {method} {json.dumps(row)}", flush=True)

    start_row = score(start)
    log("start", start_row)
    curves: dict[str, list] = {}
    seconds_per_pick: dict[str, list[float]] = {"uncertainty": []}
    rounds, decided = [], []
    baseline = json.loads((RESULTS / f"{args.baselines}.json").read_text())["scenes"][name] if args.baselines else None
    if baseline is not None:
        if not all(np.isclose(baseline["curves"]["farthest_point"][0][metric], start_row[metric], rtol=1e-5, atol=0)
                   for metric in METRICS):
            raise SystemExit(f"[{name}] the start views' fit differs from {args.baselines}'s: rerun every method")
        for method in METHODS:
            if method not in args.methods and method in baseline["curves"]:
                curves[method] = baseline["curves"][method]
    for method in [method for method in ("uncertainty",) if method in args.methods]:
        views, curves[method] = list(start), [start_row]
        while len(views) < FINAL:
            remaining = [view for view in range(len(cameras)) if view not in views]
            taken = with_views(pool, views)
            candidates = [cameras[view] for view in remaining]
            surface = guidance.surface_fit(taken, config)
            picks = guidance.select_views(taken, candidates, STEP, config, fit=surface,
                                          max_texels=args.max_texels)
            seconds_per_pick[method] += [pick.seconds for pick in picks]
            views += [remaining[pick.candidate] for pick in picks]
            row = score(views)
            if method == "uncertainty" and args.spearman_candidates:
                rounds.append({"views": len(views), "predicted": picks[-1].expected_uncertainty,
                               "before": picks[0].uncertainty_before,
                               "measured": measured_uncertainty(with_views(pool, views), config, args)})
            curves[method].append(row)
            log(method, row)
            if method == "uncertainty":
                decided.append(sum(pick.decided_by == "spread" for pick in picks))
    views = list(start)
    if "farthest_point" in args.methods:
        curves["farthest_point"] = [start_row]
    while len(views) < FINAL and "farthest_point" in args.methods:
        views += farthest_point_views(directions, STEP, chosen=views)
        curves["farthest_point"].append(score(views))
        log("farthest_point", curves["farthest_point"][-1])
    random_runs = baseline["random_runs"] if baseline is not None and "random" not in args.methods else []
    for seed in range(args.random_seeds) if "random" in args.methods else []:
        order = np.random.default_rng(seed).permutation([view for view in range(len(cameras)) if view not in start])
        run = [start_row]
        for count in range(START + STEP, FINAL + 1, STEP):
            run.append(score(start + [int(view) for view in order[:count - START]]))
        random_runs.append(run)
        log(f"random seed {seed}", run[-1])
    curves["random"] = [{key: float(np.mean([run[step][key] for run in random_runs])) for key in start_row}
                        for step in range(len(random_runs[0]))]
    random_std = [{key: float(np.std([run[step][key] for run in random_runs], ddof=1)) for key in METRICS}
                  for step in range(len(random_runs[0]))]
    return {
        "capture": whole_surface_capture(name, RENDER).name,
        "coverable_texels": int(coverable.sum()),
        "start_views": start,
        "curves": curves,
        "random_runs": random_runs,
        "random_std": random_std,
        "seconds_per_pick": {method: float(np.median(seconds)) for method, seconds in seconds_per_pick.items()},
        "rounds": rounds,
        "picks_decided_by_spread": decided,
        "misfit_correlation": misfit,
        "prediction": prediction_check(pool, start, config, args, name) if args.spearman_candidates else None,
    }


def misfit_correlation(pool: Capture, config: Config, observations) -> dict:
    """How alike the model's misfit is between two samples of a texel, against their angle.

    The per-texel ``global`` estimate of the whole pool predicts each sample (the angular
    model of docs/method.md#forward-model, `predict_angular`); the residuals (summed over RGB), scaled to unit mean square per
    texel, are multiplied pairwise within each texel and averaged in bins of the angle between the
    two view directions. ``rho_0`` and ``width``: rho_0 exp((cos - 1) / w^2) fitted to the bins.
    """
    from freqbrdf.estimate import estimate as estimate_materials
    from freqbrdf.estimate import model_light
    from freqbrdf.model.brdf import PrincipledParams, microfacet_from_principled, predict_angular

    per_texel = estimate_materials(observations, config)
    rows = np.flatnonzero(per_texel.estimated & (observations.n_samples >= 12))
    rows = np.sort(np.random.default_rng(0).choice(rows, min(len(rows), 4000), replace=False))
    roughness = per_texel.roughness[rows].astype(np.float64)
    params = PrincipledParams(per_texel.base_color[rows].astype(np.float64), roughness,
                              per_texel.metallic[rows].astype(np.float64))
    sub = dataclasses.replace(observations, mirrored_coeffs=observations.mirrored_coeffs[rows],
                              mirrored=observations.mirrored[rows], weight=observations.weight[rows],
                              view_direction=observations.view_direction[rows], irradiance=observations.irradiance[rows],
                              observed=observations.observed[rows], visible=observations.visible[rows],
                              n_samples=observations.n_samples[rows])
    predicted = predict_angular(microfacet_from_principled(params), sub.view_direction.astype(np.float64),
                                np.asarray(model_light(sub, roughness, config), np.float64), sub.irradiance,
                                sigma=observations.sigma)
    residual = (sub.observed - predicted).sum(axis=2) * sub.weight  # (n, V)
    edges = np.radians(np.arange(0, 181, 10))
    products, counts = np.zeros(len(edges) - 1), np.zeros(len(edges) - 1)
    for row in range(len(rows)):
        seen = np.flatnonzero(sub.weight[row] > 0)
        values = residual[row, seen]
        values = values / np.sqrt(np.mean(values ** 2) + 1e-30)
        cosine = np.clip(sub.view_direction[row, seen] @ sub.view_direction[row, seen].T, -1.0, 1.0)
        upper = np.triu_indices(len(seen), 1)
        angle = np.arccos(cosine[upper])
        bins = np.clip(np.digitize(angle, edges) - 1, 0, len(edges) - 2)
        np.add.at(products, bins, np.outer(values, values)[upper])
        np.add.at(counts, bins, 1)
    correlation = np.where(counts > 0, products / np.maximum(counts, 1), np.nan)
    centres = 0.5 * (edges[1:] + edges[:-1])
    # log rho = log rho_0 + (cos - 1) / w^2 by least squares, bins below 90 degrees with a positive correlation
    usable = (counts > 100) & (correlation > 0) & (centres < np.pi / 2)
    slope, intercept = np.polyfit(np.cos(centres[usable]) - 1.0, np.log(correlation[usable]), 1)
    width = float(1.0 / np.sqrt(slope)) if slope > 0 else float("nan")
    return {"texels": len(rows), "degrees": np.degrees(centres).tolist(), "correlation": correlation.tolist(),
            "pairs": counts.astype(int).tolist(), "width": width,
            "rho_0": float(np.exp(intercept))}


def measured_uncertainty(capture: Capture, config: Config, args, rows: np.ndarray | None = None,
                         held: tuple[float, float] | None = None) -> float | tuple:
    """The refitted posterior's area-weighted mean std (roughness + metallic + mean base colour).

    With ``held`` (the roughness and base-colour calibrations s^2 of another fit), also the same
    mean with the refit's calibrations replaced by those, the refit's own calibrations, and the
    mean of each part.
    """
    surface, rows, area, parts = refitted_parts(capture, config, args, rows)
    mean = float(np.dot(area, np.nan_to_num(parts.sum(axis=1))) / area.sum())
    if held is None:
        return mean
    model = guidance.uncertainty_model(capture, surface, rows, config, surface.observations.sigma)
    own = (model.roughness_scale, model.color_scale)
    rescaled = parts[:, 0] * np.sqrt(held[0] / own[0]) + parts[:, 1] + parts[:, 2] * np.sqrt(held[1] / own[1])
    return mean, float(np.dot(area, np.nan_to_num(rescaled)) / area.sum()), own, area_means(area, parts)


def refitted_parts(capture: Capture, config: Config, args, rows: np.ndarray | None = None) -> tuple:
    """The whole-surface refit of ``capture``, the scored rows, their areas and (n, 3) posterior std.

    The std columns: roughness, metallic, mean base colour; ``rows`` None: the seeded subset.
    """
    surface = guidance.surface_fit(capture, config)
    if rows is None:
        rows = guidance.texel_subset(surface.texels.n_texels, args.max_texels, config.seed)
    posterior = surface.posterior
    parts = np.column_stack([posterior.roughness_std[rows], posterior.metallic_std[rows],
                             posterior.base_color_std[rows].mean(axis=1)]).astype(np.float64)
    return surface, rows, surface.texels.texel_area[rows], parts


def area_means(area: np.ndarray, std: np.ndarray) -> list[float]:
    """The area-weighted mean of each column of ``std`` (roughness, metallic, mean base colour)."""
    return (area @ np.nan_to_num(std) / area.sum()).tolist()


def prediction_check(pool: Capture, start: list[int], config: Config, args, name: str) -> dict:
    """Predicted vs refitted uncertainty after adding one candidate to the start views.

    The candidates are scored as `select_views` scores its first pick (the spread discount
    included). ``measured_held``: the refits with the start fit's calibrations s^2, which the
    prediction keeps up to the change of the median precision.
    """
    from scipy.stats import spearmanr

    taken = with_views(pool, start)
    surface = guidance.surface_fit(taken, config)
    rows = guidance.texel_subset(surface.texels.n_texels, args.max_texels, config.seed)
    model = guidance.uncertainty_model(taken, surface, rows, config, band_limit_sigma(len(start) + 1))
    texels = guidance.subset_texels(surface.texels, rows)
    taken_views = guidance.view_information(taken, texels, surface, rows, [frame.camera for frame in taken.frames],
                                            model.sigma)
    state = guidance.initial_state(model, surface.observations.n_samples[rows], taken_views)
    before = guidance.expected_uncertainty(model, state)
    remaining = [view for view in range(len(pool.frames)) if view not in start]
    chosen = remaining[::max(1, len(remaining) // args.spearman_candidates)][:args.spearman_candidates]
    cameras = [pool.frames[view].camera for view in chosen]
    information = guidance.view_information(taken, texels, surface, rows, cameras, model.sigma)
    spread = _diversity.Spread(len(rows), view_directions(taken, [frame.camera for frame in taken.frames]),
                               view_directions(taken, cameras), [view.texel for view in taken_views])
    # Each candidate's state as `select_views` scores its first pick (the spread's discount included):
    # the parts' area means sum to its expected uncertainty.
    predicted_parts = [area_means(model.area, guidance.texel_std(model, guidance.state_with_views(
        state, [guidance._discounted(view, spread.discount(k, view.texel))]))) for k, view in enumerate(information)]
    predicted = [float(sum(parts)) for parts in predicted_parts]
    start_model = guidance.uncertainty_model(taken, surface, rows, config, surface.observations.sigma)
    held = (start_model.roughness_scale, start_model.color_scale)
    refits = [measured_uncertainty(with_views(pool, start + [view]), config, args, rows, held) for view in chosen]
    measured = [refit[0] for refit in refits]
    measured_held = [refit[1] for refit in refits]
    measured_before = measured_uncertainty(taken, config, args, rows)
    rho = float(spearmanr(predicted, measured).statistic)
    rho_held = float(spearmanr(predicted, measured_held).statistic)
    rho_drop = float(spearmanr(before - np.array(predicted), measured_before - np.array(measured)).statistic)
    measured_parts = np.array([refit[3] for refit in refits])
    parts = {part: {"predicted": np.array(predicted_parts)[:, k].tolist(), "measured": measured_parts[:, k].tolist(),
                    "spearman": float(spearmanr(np.array(predicted_parts)[:, k], measured_parts[:, k]).statistic)}
             for k, part in enumerate(("roughness", "metallic", "base_color"))}
    print(f"[{name}] prediction: spearman {rho:.3f}, calibration held {rho_held:.3f}, per part "
          + ", ".join(f"{part} {record['spearman']:.2f}" for part, record in parts.items()), flush=True)
    return {"candidates": chosen, "predicted": predicted, "measured": measured, "measured_held": measured_held,
            "parts": parts,
            "calibrations": {"start": held, "refits": [refit[2] for refit in refits]},
            "predicted_before": before, "measured_before": measured_before, "spearman": rho,
            "spearman_calibration_held": rho_held, "spearman_of_drops": rho_drop}


def paired_tests(scenes: dict) -> dict:
    """The guidance vs each baseline over all (scene, budget > start) cells, per metric."""
    from scipy.stats import wilcoxon

    tests = {}
    for baseline in [method for method in ("farthest_point", "random")
                     if all(method in scene["curves"] for scene in scenes.values())]:
        for metric in METRICS:
            ours = np.array([row[metric] for scene in scenes.values() for row in scene["curves"]["uncertainty"][1:]])
            other = np.array([row[metric] for scene in scenes.values() for row in scene["curves"][baseline][1:]])
            better = ours > other if metric == "psnr_hdr" else ours < other
            difference = ours - other
            result = wilcoxon(ours, other) if np.any(difference != 0) else None
            tests[f"{metric}: uncertainty vs {baseline}"] = {
                "pairs": len(difference), "uncertainty_better": int(better.sum()),
                "mean_difference": float(difference.mean()),
                "wilcoxon_p": None if result is None else float(result.pvalue),
            }
    return tests


def std_against_error(scenes: dict) -> dict:
    """Does the refitted posterior's std rank the view sets of one cell by their error?

    Per scene and budget, Spearman's rho between the posterior's mean std and each error over the
    view sets of that cell (every method and random seed); the mean over the cells.
    """
    from scipy.stats import spearmanr

    result = {}
    for metric in METRICS:
        rhos = []
        for scene in scenes.values():
            for step in range(1, len(scene["curves"]["uncertainty"])):
                rows = [scene["curves"][method][step] for method in ("uncertainty", "farthest_point")
                        if method in scene["curves"]]
                rows += [run[step] for run in scene["random_runs"]]
                rho = spearmanr([row["posterior_std"] for row in rows], [row[metric] for row in rows]).statistic
                rhos.append(float(rho) if np.isfinite(rho) else 0.0)
        result[metric] = {"mean_rho": float(np.mean(rhos)), "cells": rhos}
    return result


def cells_within_random_spread(scenes: dict) -> dict:
    """Per metric, the cells where the guidance is worse than farthest-point by more than random's std."""
    worse = {}
    for metric in METRICS:
        sign = -1.0 if metric == "psnr_hdr" else 1.0
        worse[metric] = [
            {"scene": name, "views": ours["views"], "excess": sign * (ours[metric] - other[metric]),
             "random_std": spread[metric]}
            for name, scene in scenes.items()
            for ours, other, spread in zip(scene["curves"]["uncertainty"][1:], scene["curves"]["farthest_point"][1:],
                                           scene["random_std"][1:])
            if sign * (ours[metric] - other[metric]) > spread[metric]
        ]
    return worse


def plot(scenes: dict, path: Path) -> None:
    from matplotlib.figure import Figure

    labels = {"roughness_mae": "roughness MAE", "metallic_mae": "metallic MAE", "base_color_mae": "base colour MAE",
              "psnr_hdr": "relighting PSNR-H (dB)"}
    styles = {"uncertainty": ("C3", "guidance"),
              "farthest_point": ("C2", "farthest-point"), "random": ("C0", "random (mean)")}
    figure = Figure(figsize=(3.4 * len(scenes), 2.6 * (len(METRICS) + 1)), dpi=90, layout="constrained")
    axes = figure.subplots(len(METRICS) + 1, len(scenes), squeeze=False)
    for column, (name, scene) in enumerate(scenes.items()):
        for row, metric in enumerate(METRICS):
            ax = axes[row, column]
            for method, (colour, legend) in styles.items():
                if method not in scene["curves"]:
                    continue
                curve = scene["curves"][method]
                ax.plot([r["views"] for r in curve], [r[metric] for r in curve], "o-", color=colour, label=legend,
                        markersize=3)
            for run in scene["random_runs"]:
                ax.plot([r["views"] for r in run], [r[metric] for r in run], color="C0", alpha=0.2, linewidth=0.7)
            ax.set_ylabel(labels[metric], fontsize=8)
            if row == 0:
                ax.set_title(name, fontsize=9)
        ax = axes[len(METRICS), column]
        check = scene["prediction"]
        if check is None:
            ax.set_axis_off()
            continue
        ax.scatter(check["predicted"], check["measured"], s=10, color="C3", label="refitted")
        ax.scatter(check["predicted"], check["measured_held"], s=10, color="0.5", label="calibration held")
        ax.set_xlabel("predicted mean std", fontsize=8)
        ax.set_ylabel("refitted mean std", fontsize=8)
        ax.set_title(f"Spearman {check['spearman']:.2f}, held {check['spearman_calibration_held']:.2f}", fontsize=8)
        ax.legend(fontsize=6)
    axes[0, 0].legend(fontsize=7)
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png")


def summarise(scenes: dict, args, seconds: float) -> dict:
    return {
        "study": "capture guidance (issue #28)", **machine(), "texture_res": args.texture_res,
        "max_texels": args.max_texels, "pool": POOL,
        "render": RENDER, "relight": dataclasses.asdict(RELIGHT), "start": START, "step": STEP, "final": FINAL,
        "random_seeds": args.random_seeds, "methods_run": args.methods, "baselines_from": args.baselines or None,
        "spread": {"width": _diversity.MISFIT_WIDTH, "refit_noise": _diversity.REFIT_NOISE},
        "scenes": scenes, "paired_tests": paired_tests(scenes),
        "worse_than_farthest_point_by_more_than_random_std": cells_within_random_spread(scenes),
        # Only where every method was fitted by this run (the std maps' definition may have changed since).
        "posterior_std_against_error": std_against_error(scenes) if not args.baselines else None,
        "seconds": seconds,
    }


def prediction_only(args, started: float) -> int:
    """Run the prediction check alone on each of ``args.scenes`` (or merge parts); write <name>.json."""
    if args.merge:
        parts = [json.loads((RESULTS / f"{part}.json").read_text()) for part in args.merge.split(",")]
        write_json(RESULTS / f"{args.name}.json",
                   dict(parts[0], scenes={name: scene for part in parts for name, scene in part["scenes"].items()},
                        seconds=sum(part["seconds"] for part in parts)))
        return 0
    scenes = {}
    for name in args.scenes.split(","):
        pool = load(whole_surface_capture(name, RENDER))
        config = Config(texels=TexelConfig(texture_res=args.texture_res))
        start = farthest_point_views(view_directions(pool, [frame.camera for frame in pool.frames]), args.start)
        scenes[name] = {"start_views": start, "prediction": prediction_check(pool, start, config, args, name)}
        write_json(RESULTS / f"{args.name}.json", {
            "study": "capture guidance (issue #28): prediction check", **machine(), "texture_res": args.texture_res,
            "max_texels": args.max_texels, "pool": POOL, "render": RENDER, "start": args.start,
            "spread": {"width": _diversity.MISFIT_WIDTH, "refit_noise": _diversity.REFIT_NOISE},
            "scenes": scenes, "seconds": time.perf_counter() - started})
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", default=",".join(SCENES))
    parser.add_argument("--texture-res", type=int, default=256)
    parser.add_argument("--random-seeds", type=int, default=5)
    parser.add_argument("--max-texels", type=int, default=guidance.MAX_TEXELS)
    parser.add_argument("--spearman-candidates", type=int, default=20)
    parser.add_argument("--methods", default=",".join(METHODS),
                        help="methods to run; the others' curves come from --baselines")
    parser.add_argument("--baselines", default="", help="results file (name) to take the methods not run from")
    parser.add_argument("--misfit-width", type=float, default=_diversity.MISFIT_WIDTH,
                        help="w of the guidance's kernel on view directions (0: no discount)")
    parser.add_argument("--refit-noise", type=float, default=_diversity.REFIT_NOISE,
                        help="the guidance's tie band, relative to the mean std (0: the best gain only)")
    parser.add_argument("--misfit", action="store_true", help="also measure the misfit's correlation between views")
    parser.add_argument("--name", default="guidance", help="results file name (parts of a run: see --merge)")
    parser.add_argument("--merge", default="", help="comma-separated results files of parts to merge into --name")
    parser.add_argument("--held-out", default="", help="with --merge: a results file of scenes the guidance's "
                        "constants were not chosen on, kept apart with its own paired tests")
    parser.add_argument("--prediction-only", action="store_true",
                        help="run only the prediction check of each scene (results: scenes -> prediction)")
    parser.add_argument("--start", type=int, default=START, help="with --prediction-only: the start views")
    args = parser.parse_args(argv)
    args.methods = args.methods.split(",")
    _diversity.MISFIT_WIDTH, _diversity.REFIT_NOISE = args.misfit_width, args.refit_noise
    started = time.perf_counter()
    RESULTS.mkdir(exist_ok=True)
    if args.prediction_only:
        return prediction_only(args, started)
    if args.merge:
        scenes, seconds = {}, 0.0
        for part in args.merge.split(","):
            loaded = json.loads((RESULTS / f"{part}.json").read_text())
            scenes.update(loaded["scenes"])
            seconds += loaded["seconds"]
        results = summarise(scenes, args, seconds)
        drawn = dict(scenes)
        if args.held_out:
            held = json.loads((RESULTS / f"{args.held_out}.json").read_text())
            results["held_out"] = {"scenes": held["scenes"], "paired_tests": paired_tests(held["scenes"]),
                                   "worse_than_farthest_point_by_more_than_random_std":
                                       cells_within_random_spread(held["scenes"]), "seconds": held["seconds"]}
            drawn.update({f"{name} (held out)": scene for name, scene in held["scenes"].items()})
        write_json(RESULTS / f"{args.name}.json", results)
        plot(drawn, RESULTS / f"{args.name}.png")
    scenes = {}
    for name in args.scenes.split(",") if not args.merge else []:
        scenes[name] = scene_run(name, args)
        results = summarise(scenes, args, time.perf_counter() - started)
        write_json(RESULTS / f"{args.name}.json", results)
        plot(scenes, RESULTS / f"{args.name}.png")
    print(json.dumps(results["paired_tests"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
