"""Does the entropy map mean something? A Mitsuba-rendered capture built to contain a badly lit
and a rarely seen region, fitted by the pipeline, its entropy compared with its roughness error.

    python benchmarks/studies/entropy_scenes.py [--sky gradient|flat]

The scene (scenes.entropy_capture): the bundled sphere with the bundled "bands" material (stripes
of roughness, metallic and colour), under a synthetic environment whose +x cap holds small bright
lights (every degree l <= l* carries power) and which is elsewhere a smooth sky, photographed
from the upper hemisphere only. Two skies (`--sky`, scenes.ENTROPY_SKIES): `gradient` (the
default; 0.25 + 0.15 y, almost nothing above l = 1, whose l = 1 part still tells roughness values
apart), and `flat` (0.3: only l = 0, the lowest frequency there is). Regions by world normal n
(scenes.entropy_regions):

- badly lit: n_x < -0.5, not rarely seen: its mirror directions see the smooth gradient;
- rarely seen: n_y < -0.5: the cameras see it at grazing angles or not at all;
- sharply lit: n_x > 0.5, not rarely seen: the reference;
- the rest.

Measured: mean entropy and mean |roughness error| per region (calibrated, paper and angular modes,
the last as `fit` computes it), Spearman rho (entropy vs |roughness error| of the global
estimate), AUSE and AURG (freqbrdf.outputs.sparsification), timings; and the same scores of the
roughness std (as exported: texels without an estimate take its prior) against the error of each
fit's own estimate, for the default fit and the fast preset, each without and with the split-half
term (`fit --split-half`), with each fit's seconds. Saves benchmarks/results/entropy_scenes.json
and entropy_scenes.png (entropy map, error map, regions); with `--sky flat`,
entropy_scenes_flat.{json,png}. The capture is rendered once into benchmarks/.cache/ and reused;
delete it to render again.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numba
import numpy as np

from freqbrdf.capture.layouts import Capture, load
from freqbrdf.config import Config, UncertaintyConfig, preset
from freqbrdf.model.materials import resize
from freqbrdf.outputs import export, sparsification
from freqbrdf.pipeline import FitResult, fit
from freqbrdf.uncertainty import FLAG_UNOBSERVED, entropy_map

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import RESULTS_DIR, machine, save_results
from scenes import (
    ENTROPY_LIGHT_CAP_X,
    ENTROPY_LIGHT_RADIUS_DEG,
    ENTROPY_LIGHTS,
    ENTROPY_REGIONS,
    ENTROPY_SCENE,
    ENTROPY_SKIES,
    entropy_capture,
    entropy_regions,
)

# The fits whose roughness std is scored (module docstring).
SPREAD_FITS = {
    "default": Config(),
    "default + split half": Config(uncertainty=UncertaintyConfig(split_half=True)),
    "fast": preset("fast"),
    "fast + split half": preset("fast").replace(uncertainty=UncertaintyConfig(split_half=True)),
}


def roughness_error(result: FitResult, capture: Capture) -> np.ndarray:
    """(N,) |estimated - true roughness| per texel (NaN where not estimated)."""
    truth = resize(capture.ground_truth, result.estimate.texture_res)
    flat = result.estimate.texel_index
    return np.abs(result.estimate.roughness - truth.roughness.ravel()[flat])


def results_name(name: str, sky: str) -> str:
    """The results file's name for ``sky``: the gradient's keeps the plain name."""
    return name if sky == "gradient" else f"{name}_{sky}"


def sky_argument(description: str) -> str:
    """The --sky option of the command line."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--sky", choices=sorted(ENTROPY_SKIES), default="gradient",
                        help="the sky outside the lights (module docstring)")
    return parser.parse_args().sky


def main(sky: str) -> None:
    start = time.perf_counter()
    path = entropy_capture(sky)
    render_s = time.perf_counter() - start
    capture = load(path)
    result = fit(capture, Config())
    observations = result.observations
    error = roughness_error(result, capture)
    masks = entropy_regions(observations.normal)
    observed = (result.uncertainty.flags & FLAG_UNOBSERVED) == 0
    start = time.perf_counter()
    paper = entropy_map(observations, UncertaintyConfig(mode="paper"), return_likelihood=False)
    paper_s = time.perf_counter() - start
    # The angular mode as `fit` computes it (from its search's probes): the same estimate.
    angular_fit = fit(capture, Config(uncertainty=UncertaintyConfig(mode="angular")))

    scores = {}
    for name, uncertainty in (("calibrated", result.uncertainty), ("paper", paper),
                              ("angular", angular_fit.uncertainty)):
        # Unobserved texels have no estimate (NaN error): sparsification leaves them out.
        curves = sparsification.sparsification(uncertainty.entropy, error)
        scores[name] = {
            "spearman_rho_entropy_vs_roughness_error": round(float(curves.spearman), 4),
            "ause": round(curves.ause, 4),
            "aurg": round(curves.aurg, 4),
            "mean_entropy": {region: round(float(uncertainty.entropy[mask].mean()), 4)
                             for region, mask in masks.items()},
        }
    spread_scores = {}
    for name, config in SPREAD_FITS.items():
        start = time.perf_counter()
        spread_fit = result if name == "default" else fit(capture, config)
        seconds = result.timings["total"] if name == "default" else time.perf_counter() - start
        spread = export.roughness_std_values(spread_fit.uncertainty.roughness_std)
        spread_error = roughness_error(spread_fit, capture)
        curves = sparsification.sparsification(spread, spread_error)
        spread_masks = entropy_regions(spread_fit.observations.normal)
        spread_scores[name] = {
            "estimation_res": spread_fit.estimation_res,
            "spearman_rho_roughness_std_vs_roughness_error": round(float(curves.spearman), 4),
            "ause": round(curves.ause, 4),
            "aurg": round(curves.aurg, 4),
            "mean_roughness_error": round(float(np.nanmean(spread_error)), 4),
            "median_roughness_std": {region: round(float(np.median(spread[mask])), 4)
                                     for region, mask in spread_masks.items()},
            "fit_seconds": round(seconds, 2),
        }
        print(name, spread_scores[name], flush=True)
    region_facts = {
        region: {
            "texels": int(mask.sum()),
            "observed_fraction": round(float(observed[mask].mean()), 4),
            "mean_views": round(float(observations.n_samples[mask].mean()), 2),
            "mean_roughness_error": round(float(np.nanmean(error[mask])), 4),
        }
        for region, mask in masks.items()
    }
    save_results(results_name("entropy_scenes", sky), {
        "benchmark": "entropy vs roughness error on a capture with badly lit and rarely seen regions",
        **machine(),
        "scene": {**{name: getattr(ENTROPY_SCENE, name) for name in
                     ("mesh", "materials", "views", "resolution", "spp", "texture_res", "cameras")},
                  "envmap": f"{sky} sky {ENTROPY_SKIES[sky]} + {ENTROPY_LIGHTS} lights of "
                            f"{ENTROPY_LIGHT_RADIUS_DEG} deg where x > {ENTROPY_LIGHT_CAP_X}"},
        "texels": observations.n_texels,
        "regions": region_facts,
        "scores": scores,
        "roughness_std": spread_scores,
        "timings_s": {"render_capture (0 if cached)": round(render_s, 2),
                      **{stage: round(seconds, 4) for stage, seconds in result.timings.items()},
                      "uncertainty_paper_mode": round(paper_s, 4),
                      "fit_with_angular_entropy": {stage: round(seconds, 4) for stage, seconds
                                                   in angular_fit.timings.items() if "." not in stage}},
        "numba_threads": numba.get_num_threads(),
    })
    plot(result, error, masks, RESULTS_DIR / f"{results_name('entropy_scenes', sky)}.png")


def plot(result: FitResult, error: np.ndarray, masks: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    observations = result.observations
    region_index = np.zeros(observations.n_texels)
    for index, region in enumerate(ENTROPY_REGIONS):
        region_index[masks[region]] = index
    panels = (
        ("entropy (calibrated)", observations.to_texture(result.uncertainty.entropy, np.nan), "magma", (0, 1)),
        ("|roughness error|", observations.to_texture(error.astype(np.float32), np.nan), "viridis", (0, 0.5)),
        ("regions: " + ", ".join(f"{i} {r}" for i, r in enumerate(ENTROPY_REGIONS)),
         observations.to_texture(region_index.astype(np.float32), np.nan), "tab10", (0, 9)),
    )
    figure, axes = plt.subplots(1, 3, figsize=(15, 5))
    for axis, (title, image, cmap, (low, high)) in zip(axes, panels):
        shown = axis.imshow(image, cmap=cmap, vmin=low, vmax=high)
        axis.set_title(title, fontsize=9)
        axis.axis("off")
        figure.colorbar(shown, ax=axis, fraction=0.046)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


if __name__ == "__main__":
    main(sky_argument(__doc__.splitlines()[0]))
