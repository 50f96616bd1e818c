"""Texels no view sees (issue #42): the whole-surface estimate against the plainest fill, its UV chart's mean.

    python benchmarks/studies/unseen_fill.py [--name unseen_fill]

Captures: the whole-surface suite's quick renders (12 views of 96 x 96, T = 128:
scenes.WHOLE_SURFACE_QUICK_RENDER) and the calibration study's three (32 views of 192 x 192,
T = 256), each fitted with the defaults. On the atlas texels no view sees: base-colour PSNR,
roughness and metallic MAE of the fit, and of the fit with those texels filled with the mean of
its confident seen texels of the same UV chart (`whole_surface.chart_mean_fill`, as the
whole-surface study's baseline), and of the two blended per texel by inverse variance: the fit's
std against the spread of those chart texels (`chart_blend`; the metallic blended, then rounded).

Writes benchmarks/results/<name>.{json,md}.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from whole_surface import chart_mean_fill, chart_texture, parameter_scores, seen_texels, std_textures  # noqa: E402

import scenes  # noqa: E402
from _common import machine, save_results  # noqa: E402
from freqbrdf import pipeline  # noqa: E402
from freqbrdf.capture.layouts import load  # noqa: E402
from freqbrdf.config import Config, TexelConfig  # noqa: E402
from freqbrdf.estimate.surface import chart_prior  # noqa: E402
from freqbrdf.model.materials import MaterialMaps  # noqa: E402

CALIBRATION_RENDER = {"views": 32, "resolution": 192, "spp": 32, "texture_res": 256, "test_views": 4}
CAPTURES = [(name, scenes.WHOLE_SURFACE_QUICK_RENDER) for name in scenes.WHOLE_SURFACE_SCENES] + [
    (name, CALIBRATION_RENDER) for name in ("sphere_gradients_lobby", "dragon_photo_side")]
KEYS = ("base_color_psnr", "roughness_mae", "metallic_mae")


def chart_blend(maps: MaterialMaps, stds: dict, confident: np.ndarray, unseen: np.ndarray,
                chart: np.ndarray) -> MaterialMaps:
    """The maps with every unseen texel the inverse-variance blend of its value and its chart's mean.

    The fit's value weighs 1 / std^2 (its std map); its chart's mean of the confident texels weighs
    1 / their variance (`freqbrdf.estimate.surface.chart_prior`: all confident texels' where the
    chart has too few).
    """
    blended = MaterialMaps(maps.base_color.copy(), maps.roughness.copy(), maps.metallic.copy())
    if not confident.any():
        return blended
    covered = chart >= 0
    for name in ("base_color", "roughness", "metallic"):
        texture = getattr(blended, name)
        values = getattr(maps, name)[covered].astype(np.float64).reshape(int(covered.sum()), -1)  # (n, C)
        mean, variance = chart_prior(values, confident[covered], chart[covered])
        rows = unseen[covered]
        own = values[rows]
        std = stds.get(name)
        own_variance = (np.full_like(own, np.inf) if std is None else
                        np.nan_to_num(std[covered].astype(np.float64).reshape(-1, own.shape[1])[rows] ** 2, nan=np.inf))
        chart_variance = np.maximum(variance[rows], 1e-6)
        weight = chart_variance / (chart_variance + np.maximum(own_variance, 1e-12))  # the fit's share
        value = weight * own + (1.0 - weight) * mean[rows]
        if name == "metallic":
            value = np.round(value)
        texture[unseen & covered] = value.reshape(texture[unseen & covered].shape).astype(np.float32)
    return blended


def run_capture(name: str, render: dict) -> dict | None:
    capture = load(scenes.whole_surface_capture(name, render))
    texture_res = render["texture_res"]
    seen = seen_texels(capture, texture_res)
    covered, chart = chart_texture(capture.mesh, texture_res)
    unseen = covered & ~seen
    if not unseen.any():
        return None
    config = Config(texels=TexelConfig(texture_res=texture_res))
    result = pipeline.fit(capture, config)
    observations = result.observations
    confident = observations.to_texture(
        result.estimate.estimated & (result.uncertainty.entropy < config.uncertainty.ambiguous_entropy)
        & (observations.n_samples > 0), fill=False).astype(bool) & seen
    fit = parameter_scores(result.maps, capture.ground_truth, unseen)
    fill = parameter_scores(chart_mean_fill(result.maps, confident, unseen, chart), capture.ground_truth, unseen)
    blend = parameter_scores(chart_blend(result.maps, std_textures(result), confident, unseen, chart),
                             capture.ground_truth, unseen)
    return {"unseen_texels": int(unseen.sum()), "fit": {key: fit[key] for key in KEYS},
            "chart_mean": {key: fill[key] for key in KEYS}, "blend": {key: blend[key] for key in KEYS}}


def markdown(results: dict) -> str:
    lines = ["# Unseen texels: the fit against its chart-mean fill", "",
             "`benchmarks/studies/unseen_fill.py`; on the atlas texels no view sees, fit / chart-mean fill / "
             "their inverse-variance blend.", "",
             "| capture | unseen texels | BC dB | R MAE | M MAE |", "|---|---|---|---|---|"]
    for name, row in results["captures"].items():
        cells = [f"{row['fit'][key]:.3f} / {row['chart_mean'][key]:.3f}"
                 + (f" / {row['blend'][key]:.3f}" if "blend" in row else "") for key in KEYS]
        lines.append(f"| {name} | {row['unseen_texels']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--name", default="unseen_fill")
    args = parser.parse_args(argv)
    results = {"machine": machine(), "captures": {}}
    for name, render in CAPTURES:
        row = run_capture(name, render)
        if row is not None:
            label = f"{name} ({render['views']} views, T = {render['texture_res']})"
            results["captures"][label] = row
            print(label, row, flush=True)
    save_results(args.name, results)
    (Path(__file__).resolve().parents[1] / "results" / f"{args.name}.md").write_text(markdown(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
