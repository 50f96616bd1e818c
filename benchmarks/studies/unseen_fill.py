"""Texels no view sees (issue #42): the whole-surface estimate against the plainest fill, its UV chart's mean.

    python benchmarks/studies/unseen_fill.py [--name unseen_fill]

Captures: the whole-surface suite's quick renders (12 views of 96 x 96, T = 128:
scenes.WHOLE_SURFACE_QUICK_RENDER) and the calibration study's three (32 views of 192 x 192,
T = 256), each fitted with the defaults. On the atlas texels no view sees: base-colour PSNR,
roughness and metallic MAE of the fit, and of the fit with those texels filled with the mean of
its confident seen texels of the same UV chart (`whole_surface.chart_mean_fill`, as the
whole-surface study's baseline), and of the fit without the measured shrinkage of those texels
towards their chart's mean (`freqbrdf.estimate.surface.shrink_by_trial` patched out: the
solve's extrapolation alone, docs/method.md#whole-surface-estimate).

Writes benchmarks/results/<name>.{json,md}.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from unittest import mock

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from whole_surface import chart_mean_fill, chart_texture, parameter_scores, seen_texels  # noqa: E402

import scenes  # noqa: E402
from _common import machine, save_results  # noqa: E402
from freqbrdf import pipeline  # noqa: E402
from freqbrdf.capture.layouts import load  # noqa: E402
from freqbrdf.config import Config, TexelConfig  # noqa: E402
from freqbrdf.estimate import surface  # noqa: E402

CALIBRATION_RENDER = {"views": 32, "resolution": 192, "spp": 32, "texture_res": 256, "test_views": 4}
CAPTURES = [(name, scenes.WHOLE_SURFACE_QUICK_RENDER) for name in scenes.WHOLE_SURFACE_SCENES] + [
    (name, CALIBRATION_RENDER) for name in ("sphere_gradients_lobby", "dragon_photo_side")]
KEYS = ("base_color_psnr", "roughness_mae", "metallic_mae")


def fit_without_shrinkage(capture, config: Config) -> pipeline.FitResult:
    """The fit with the texels without data left at the solve's extrapolation (no measured shrinkage)."""
    with mock.patch.object(surface, "shrink_by_trial", lambda trial, values, solution, charts:
                           (solution, float("nan"), np.zeros(len(solution)))):
        return pipeline.fit(capture, config)


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
    solve = parameter_scores(fit_without_shrinkage(capture, config).maps, capture.ground_truth, unseen)
    return {"unseen_texels": int(unseen.sum()), "carry_hops": {key: None if hops != hops else str(hops) if hops == float("inf") else hops
                                                             for key, hops in result.carry_hops.items()},
            "fit": {key: fit[key] for key in KEYS}, "solve_alone": {key: solve[key] for key in KEYS},
            "chart_mean": {key: fill[key] for key in KEYS}}


def markdown(results: dict) -> str:
    lines = ["# Unseen texels: the fit against its chart-mean fill", "",
             "`benchmarks/studies/unseen_fill.py`; on the atlas texels no view sees: the fit / the fit without the "
             "measured shrinkage towards the chart mean (the solve's extrapolation alone) / the chart-mean fill. "
             "Carry: the hops the fit measured its solve to carry (roughness, base colour).", "",
             "| capture | unseen texels | carry (hops) | BC dB | R MAE | M MAE |", "|---|---|---|---|---|---|"]
    for name, row in results["captures"].items():
        cells = [f"{row['fit'][key]:.3f} / {row['solve_alone'][key]:.3f} / {row['chart_mean'][key]:.3f}"
                 for key in KEYS]
        carry = ", ".join("-" if row["carry_hops"].get(key) is None else f"{float(row['carry_hops'][key]):.1f}"
                          for key in ("roughness", "base_color"))
        lines.append(f"| {name} | {row['unseen_texels']} | {carry} | " + " | ".join(cells) + " |")
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
