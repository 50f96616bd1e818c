"""The trust mask (issue #42): how the maps' errors differ where the std maps trust them and where not.

    python benchmarks/studies/trust.py [--scenes a,b]

Scenes: the calibration study's three path-traced captures of the whole-surface suite (32 views of
192 x 192, T = 256; `studies/calibration.py`), fitted with the defaults. For each threshold on
every std (`freqbrdf.uncertainty.trust.trusted_texels`): the share of the atlas trusted, and inside
and outside the mask the roughness and metallic MAE, the base colour's mean absolute error and
the dielectrics called metal, on the texels a view sees and on those none sees; per std, Spearman's
rho with its parameter's absolute error and the share of errors within one std.

Writes benchmarks/results/trust.{json,md}.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration import RENDER, SCENES, TEXTURE_RES  # noqa: E402
from whole_surface import METAL_THRESHOLD, seen_texels  # noqa: E402

import scenes  # noqa: E402
from _common import machine, save_results  # noqa: E402
from freqbrdf import pipeline  # noqa: E402
from freqbrdf.capture.layouts import load  # noqa: E402
from freqbrdf.config import Config, TexelConfig  # noqa: E402
from freqbrdf.uncertainty.trust import trusted_texels  # noqa: E402

THRESHOLDS = (0.05, 0.1, 0.15, 0.2)


def errors(maps, truth, texels: np.ndarray) -> dict:
    """Mean absolute errors on ``texels`` (T, T) bool."""
    if not texels.any():
        return {"texels": 0}
    dielectric = texels & (truth.metallic < METAL_THRESHOLD)
    return {"texels": int(texels.sum()),
            "roughness_mae": float(np.abs(maps.roughness - truth.roughness)[texels].mean()),
            "metallic_mae": float(np.abs(maps.metallic - truth.metallic)[texels].mean()),
            "base_color_mae": float(np.abs(maps.base_color - truth.base_color)[texels].mean()),
            "dielectric_called_metal": float(np.mean(maps.metallic[dielectric] > METAL_THRESHOLD))
            if dielectric.any() else None}


def run_scene(scene: str) -> dict:
    capture = load(scenes.whole_surface_capture(scene, RENDER))
    config = Config(texels=TexelConfig(texture_res=TEXTURE_RES))
    result = pipeline.fit(capture, config)
    seen = seen_texels(capture, TEXTURE_RES)
    atlas = result.estimate.to_texture(result.estimate.estimated | ~result.estimate.estimated, fill=False).astype(bool)
    rows = {}
    for threshold in THRESHOLDS:
        trusted = result.estimate.to_texture(trusted_texels(result.uncertainty, threshold), fill=False).astype(bool)
        rows[str(threshold)] = {
            "trusted_fraction": float(trusted[atlas].mean()),
            "seen": {"trusted": errors(result.maps, capture.ground_truth, trusted & seen),
                     "not_trusted": errors(result.maps, capture.ground_truth, ~trusted & seen & atlas)},
            "unseen": {"trusted": errors(result.maps, capture.ground_truth, trusted & ~seen & atlas),
                       "not_trusted": errors(result.maps, capture.ground_truth, ~trusted & ~seen & atlas)}}
        print(f"[{scene}] {threshold}: {rows[str(threshold)]}", flush=True)
    # How each std ranks its parameter's errors on the seen texels (Spearman's rho).
    ranking, coverage = {}, {}
    for name, std in (("roughness", result.uncertainty.roughness_std), ("metallic", result.uncertainty.metallic_std),
                      ("base_color", None if result.uncertainty.base_color_std is None
                       else result.uncertainty.base_color_std.mean(axis=1))):
        if std is None:
            continue
        texture = result.estimate.to_texture(np.asarray(std, np.float64), fill=np.nan)
        error = np.abs(getattr(result.maps, name) - getattr(capture.ground_truth, name))
        error = error.mean(axis=-1) if error.ndim == 3 else error
        keep = seen & np.isfinite(texture)
        ranking[name] = float(spearmanr(texture[keep], error[keep]).statistic)
        coverage[name] = float(np.mean(error[keep] <= texture[keep]))
    print(f"[{scene}] std rho {ranking} 1-sigma coverage {coverage}", flush=True)
    return {"std_spearman": ranking, "std_coverage_1sigma": coverage, "capture": str(capture.root) if hasattr(capture, "root") else scene, "thresholds": rows}


def markdown(results: dict) -> str:
    lines = ["# Trust mask", "", "`benchmarks/studies/trust.py`: errors where every std is at most the threshold "
             "(trusted) and elsewhere, on the texels a view sees; R, M: roughness and metallic MAE, BC: base "
             "colour MAE, D->M: dielectrics called metal.", "",
             "| scene | threshold | trusted | R trusted / not | M trusted / not | BC trusted / not | D->M trusted / not |",
             "|---|---|---|---|---|---|---|"]

    def pair(row, key, percent=False):
        values = []
        for side in ("trusted", "not_trusted"):
            value = row["seen"][side].get(key)
            values.append("-" if value is None else (f"{value:.1%}" if percent else f"{value:.3f}"))
        return " / ".join(values)

    for scene, found in results["scenes"].items():
        for threshold, row in found["thresholds"].items():
            lines.append(f"| {scene} | {threshold} | {row['trusted_fraction']:.0%} | {pair(row, 'roughness_mae')} | "
                         f"{pair(row, 'metallic_mae')} | {pair(row, 'base_color_mae')} | "
                         f"{pair(row, 'dielectric_called_metal', True)} |")
    lines += ["", "Spearman's rho of each std with its parameter's absolute error, and the share of errors within "
              "1 std (0.68 = calibrated), seen texels:", "",
              "| scene | roughness | metallic | base colour (mean over RGB) |", "|---|---|---|---|"]
    for scene, found in results["scenes"].items():
        rho, within = found.get("std_spearman", {}), found.get("std_coverage_1sigma", {})
        lines.append(f"| {scene} | " + " | ".join(f"{rho[key]:.2f} / {within[key]:.0%}" if key in rho else "-"
                                                   for key in ("roughness", "metallic", "base_color")) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default=",".join(SCENES))
    args = parser.parse_args(argv)
    results = {"machine": machine(), "scenes": {}}
    for scene in args.scenes.split(","):
        results["scenes"][scene] = run_scene(scene)
    save_results("trust", results)
    path = Path(__file__).resolve().parents[1] / "results" / "trust.md"
    path.write_text(markdown(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
