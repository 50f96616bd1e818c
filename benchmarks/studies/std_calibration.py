"""Each capture calibrates its own std (issue #42 item 1): the std maps against the errors, before and after.

    python benchmarks/studies/std_calibration.py [--scenes a,b] [--quick]

Scenes: the calibration study's three path-traced captures of the whole-surface suite (32 views of
192 x 192, T = 256; `studies/calibration.py`), fitted with the defaults, whose held-out std
calibration is on (`freqbrdf.uncertainty.heldout`). Per std (roughness, metallic, the base
colour's mean over RGB), on the texels a view sees: Spearman's rho with its parameter's absolute
error and the shares of errors within 1 and 2 std, for the std as modelled ("before": the
calibrated std divided by its factor; the base colour's without the gains' error, which is added after the folds),
scaled by fold factor x misfit scale also where that is
below 1 ("two-sided"), and as the fit writes it ("after": two-sided where each fold keeps
``UncertaintyConfig.heldout_narrow_views`` views, else only widened). Also the factor the truth would ask for (the 68th percentile of error / std
before), the factors, the held-out coverage and the calibration's share of the fit's time.

With --quick, the whole-surface suite's six scenes at its quick render instead (12 views of
96 x 96, T = 128; `scenes.WHOLE_SURFACE_QUICK_RENDER`): three of them the misfit's reference was
not chosen on.

Writes benchmarks/results/std_calibration{,_quick}.{json,md}.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration import RENDER, SCENES  # noqa: E402
from whole_surface import seen_texels  # noqa: E402

import scenes  # noqa: E402
from _common import machine, save_results  # noqa: E402
from freqbrdf import pipeline  # noqa: E402
from freqbrdf.capture.layouts import load  # noqa: E402
from freqbrdf.config import Config, TexelConfig  # noqa: E402
from freqbrdf.uncertainty.heldout import COVERAGE, _relative_misfit  # noqa: E402

STDS = ("roughness", "metallic", "base_color")
VARIANTS = ("before", "two_sided", "after")
# Finer rules measured against the fit's one factor per std (`finer_rules`).
FINER = ("by_label", "by_samples", "misfit_term", "misfit_scale")


def finer_rules(result, name: str, before: np.ndarray) -> dict:
    """Per texel (N,), the std ``before`` calibrated by finer rules than one factor per std.

    From the folds' deviations on the calibration's texels: one factor per metal label of the
    estimate ("by_label"), per tercile of the samples per texel ("by_samples"); the fit's
    calibrated std with each texel's relative misfit added as a variance ("misfit_term"); and the std
    times the misfit scale alone, without the folds' factor ("misfit_scale"). Only
    where the fit estimated on the maps' texels (the calibration's rows are theirs); else {}.
    """
    found = result.std_calibration
    if (found is None or found.rows is None or name not in found.factors
            or result.estimation_res != result.estimate.texture_res):
        return {}
    rows, deviation = found.rows, found.deviations[name]

    def factor(chosen):
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = deviation[:, chosen] / before[rows][chosen][None, :]
        ratio = ratio[np.isfinite(ratio)]
        return max(1.0, float(np.quantile(ratio, COVERAGE)) * found.misfit_scale) if ratio.size else 1.0

    metal = np.nan_to_num(np.asarray(result.estimate.metallic, np.float64)) > 0.5
    samples = result.observations.n_samples
    tercile = np.digitize(samples, np.quantile(samples[rows], [1 / 3, 2 / 3]))
    misfit = np.nan_to_num(_relative_misfit(result.observations, result.estimate.loss))
    return {"by_label": before * np.where(metal, factor(metal[rows]), factor(~metal[rows])),
            "by_samples": before * np.choose(tercile, [factor(tercile[rows] == k) for k in range(3)]),
            "misfit_term": np.sqrt(np.square(before * found.factors[name]) + misfit),
            "misfit_scale": before * found.misfit_scale}


def scores(std: np.ndarray, error: np.ndarray) -> dict:
    """Spearman's rho and the 1- and 2-std coverage of (n,) std against (n,) absolute error."""
    return {"rho": float(spearmanr(std, error).statistic), "within_1": float(np.mean(error <= std)),
            "within_2": float(np.mean(error <= 2.0 * std)), "texels": int(len(std))}


def run_scene(scene: str, render: dict) -> dict:
    capture = load(scenes.whole_surface_capture(scene, render))
    texture_res = render["texture_res"]
    config = Config(texels=TexelConfig(texture_res=texture_res))
    result = pipeline.fit(capture, config)
    found = result.std_calibration
    seen = seen_texels(capture, texture_res)
    rows = {}
    for name in STDS:
        std = getattr(result.uncertainty, f"{name}_std")
        if std is None:
            continue
        std = np.asarray(std, np.float64)
        written = result.estimate.to_texture(std.mean(axis=1) if std.ndim == 2 else std, fill=np.nan)
        if name == "base_color":  # the gains' error is added after the folds: their std is the one without it
            gains = np.nan_to_num(result.estimate.base_color) * result.calibration.gain_error_log_std[None, :]
            std = np.sqrt(np.maximum(std ** 2 - gains ** 2, 0.0))
        std = std.mean(axis=1) if std.ndim == 2 else std
        texture = result.estimate.to_texture(std, fill=np.nan)
        error = np.abs(getattr(result.maps, name) - getattr(capture.ground_truth, name))
        error = error.mean(axis=-1) if error.ndim == 3 else error
        keep = seen & np.isfinite(texture) & np.isfinite(written)
        factor = found.factors.get(name, 1.0)
        before = texture[keep] / factor
        finer = {rule: scores(result.estimate.to_texture(values, fill=np.nan)[keep], error[keep])
                 for rule, values in finer_rules(result, name, std / factor).items()}
        rows[name] = {"before": scores(before, error[keep]),
                      "two_sided": scores(before * found.fold_factors.get(name, 1.0) * found.misfit_scale
                                          if name in found.factors else before, error[keep]),
                      "after": scores(written[keep], error[keep]),
                      "truth_factor": float(np.quantile(error[keep] / np.maximum(before, 1e-12), 0.68)),
                      **finer}
        print(f"[{scene}] {name}: {rows[name]}", flush=True)
    fit_seconds = result.timings["total"] - result.timings.get("std_calibration", 0.0)
    return {"stds": rows, "calibration": found.to_dict(), "fit_seconds": fit_seconds,
            "calibration_seconds": result.timings.get("std_calibration", 0.0),
            "cost_share": result.timings.get("std_calibration", 0.0) / fit_seconds}


def markdown(results: dict) -> str:
    lines = ["# Held-out std calibration", "",
             "`benchmarks/studies/std_calibration.py`: per std, Spearman's rho with its parameter's absolute error "
             "and the shares of errors within 1 and 2 std (0.68 and 0.95 = calibrated), on the texels a view sees; "
             "before: the std as modelled; two-sided: times fold factor x misfit scale, also below 1; after: "
             "as the fit writes it (two-sided where each fold keeps UncertaintyConfig.heldout_narrow_views views, "
             "else only widened: max(1, fold factor x misfit scale)).", "",
             "| scene | std | rho | 1 std before / two-sided / after | 2 std before / two-sided / after | "
             "factor the truth asks for |", "|---|---|---|---|---|---|"]
    for scene, found in results["scenes"].items():
        for name, row in found["stds"].items():
            lines.append(f"| {scene} | {name} | {row['after']['rho']:.2f} | "
                         + " / ".join(f"{row[v]['within_1']:.0%}" for v in VARIANTS) + " | "
                         + " / ".join(f"{row[v]['within_2']:.0%}" for v in VARIANTS)
                         + f" | {row['truth_factor']:.2f} |")
    lines += ["", "Finer rules than one factor per std, 1 std coverage / rho: one factor per metal label, per tercile of "
              "the samples per texel, the texel's relative misfit added to the calibrated std as a variance, and the misfit "
              "scale alone (no fold factor):", "",
              "| scene | std | one factor | by label | by samples | misfit term | misfit scale alone |",
              "|---|---|---|---|---|---|---|"]
    for scene, found in results["scenes"].items():
        for name, row in found["stds"].items():
            if all(rule in row for rule in FINER):
                lines.append(f"| {scene} | {name} | " + " | ".join(
                    f"{row[rule]['within_1']:.0%} / {row[rule]['rho']:.2f}" for rule in ("after", *FINER)) + " |")
    lines += ["", "| scene | factors (roughness, base colour) | fold factors (R, M, BC) | misfit / scale | "
              "held-out 1-std coverage before -> after (R, BC) | texels x folds | cost (share of the fit) |",
              "|---|---|---|---|---|---|---|"]
    for scene, found in results["scenes"].items():
        c = found["calibration"]
        fold = ", ".join(f"{c['fold_factors'].get(k, float('nan')):.2f}" for k in STDS)
        held = ", ".join(f"{c['coverage_before'][k]:.0%} -> {c['coverage_after'][k]:.0%}" for k in c["factors"])
        lines.append(f"| {scene} | {c['factors'].get('roughness', 1):.2f}, {c['factors'].get('base_color', 1):.2f} | "
                     f"{fold} | {c['misfit']:.4f} / {c['misfit_scale']:.2f} | {held} | {c['texels']} x {c['folds']} | "
                     f"{found['calibration_seconds']:.1f} s of {found['fit_seconds']:.1f} s "
                     f"({found['cost_share']:.0%}) |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default=None)
    parser.add_argument("--quick", action="store_true", help="the suite's six scenes at its quick render")
    args = parser.parse_args(argv)
    render = scenes.WHOLE_SURFACE_QUICK_RENDER if args.quick else RENDER
    names = args.scenes or ",".join(scenes.WHOLE_SURFACE_SCENES if args.quick else SCENES)
    results = {"machine": machine(), "render": render, "scenes": {}}
    for scene in names.split(","):
        results["scenes"][scene] = run_scene(scene, render)
    name = "std_calibration_quick" if args.quick else "std_calibration"
    save_results(name, results)
    path = Path(__file__).resolve().parents[1] / "results" / f"{name}.md"
    path.write_text(markdown(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
