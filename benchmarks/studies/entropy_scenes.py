"""Does the entropy map mean something? A Mitsuba-rendered capture built to contain a badly lit
and a rarely seen region, fitted by the pipeline, its entropy compared with its roughness error.

The scene: the bundled sphere with the bundled "bands" material (stripes of roughness, metallic
and colour), under a synthetic environment whose +x cap holds small bright lights (every
degree l <= l* carries power) and which is elsewhere a smooth sky, photographed from the upper
hemisphere only. Two skies (`--sky`): `gradient` (the default; 0.25 + 0.15 y, almost nothing above
l = 1, whose l = 1 part still tells roughness values apart: the path-traced entropy of
pathtraced_entropy.py does not call the region below more uncertain), and `flat` (0.3: only l = 0,
the lowest frequency there is). Regions by world normal n:

- badly lit: n_x < -0.5, not rarely seen: its mirror directions see the smooth gradient;
- rarely seen: n_y < -0.5: the cameras see it at grazing angles or not at all;
- sharply lit: n_x > 0.5, not rarely seen: the reference;
- the rest.

Measured: mean entropy and mean |roughness error| per region (calibrated, paper and angular modes,
the last as `fit` computes it),
Spearman rho (entropy vs |roughness error| of the global estimate), AUSE and AURG
(freqbrdf.outputs.sparsification), timings; and the same scores of the roughness std (as exported:
texels without an estimate take its prior) against the error of each fit's own estimate, for the
default fit and the fast preset, each without and with the split-half term (`fit --split-half`),
with each fit's seconds. Saves benchmarks/results/entropy_scenes.json and
entropy_scenes.png (entropy map, error map, regions); with `--sky flat`,
entropy_scenes_flat.{json,png}. The capture is rendered once into benchmarks/.cache/ and
reused; delete it to render again.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numba
import numpy as np
from _common import RESULTS_DIR, machine, save_results

from freqbrdf.capture.layouts import Capture, load
from freqbrdf.config import Config, UncertaintyConfig, preset
from freqbrdf.images import write_exr
from freqbrdf.model.materials import resize
from freqbrdf.outputs import export, sparsification
from freqbrdf.pipeline import FitResult, fit
from freqbrdf.synthetic.synth import SynthSettings, synthesize
from freqbrdf.uncertainty import FLAG_UNOBSERVED, entropy_map

CACHE = Path(__file__).resolve().parent / ".cache"
ENVMAP_SIZE = (256, 512)  # H, W
SETTINGS = SynthSettings(
    mesh="sphere", materials="bands", views=48, resolution=192, spp=64, texture_res=256,
    cameras="hemisphere", seed=0, test_envmaps=0, test_views=0,
)
N_LIGHTS = 24  # small bright lights in the cap x > LIGHT_CAP_X
LIGHT_CAP_X = 0.6  # far from x = 0, so that the band-limit blur does not carry them into the -x half
LIGHT_RADIUS_DEG = 4.0
# The sky outside the lights: radiance = constant + slope x (world y, up).
SKIES = {"gradient": (0.25, 0.15), "flat": (0.3, 0.0)}
REGIONS = ("sharply_lit", "badly_lit", "rarely_seen", "rest")
# The fits whose roughness std is scored (module docstring).
SPREAD_FITS = {
    "default": Config(),
    "default + split half": Config(uncertainty=UncertaintyConfig(split_half=True)),
    "fast": preset("fast"),
    "fast + split half": preset("fast").replace(uncertainty=UncertaintyConfig(split_half=True)),
}


def capped_lights_envmap(seed: int = 0, sky: str = "gradient") -> np.ndarray:
    """(H, W, 3) float32 lat-long radiance in Mitsuba's envmap layout: a smooth sky (SKIES)
    everywhere plus N_LIGHTS small bright disks at random directions with x > LIGHT_CAP_X."""
    height, width = ENVMAP_SIZE
    # Mitsuba's texel centres (as freqbrdf.synthetic.synth.resample_envmap): azimuth from -z towards +x.
    azimuth = 2.0 * np.pi * (np.arange(width) + 0.5) / width
    polar = np.pi * np.arange(height) / (height - 1)
    directions = np.stack(np.broadcast_arrays(
        np.sin(polar)[:, None] * np.sin(azimuth)[None, :],
        np.cos(polar)[:, None],
        -np.sin(polar)[:, None] * np.cos(azimuth)[None, :],
    ), axis=-1)  # (H, W, 3) world directions, +y up
    constant, slope = SKIES[sky]
    radiance = np.repeat((constant + slope * directions[..., 1:2]), 3, axis=-1)
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(20 * N_LIGHTS, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    centres = centres[centres[:, 0] > LIGHT_CAP_X][:N_LIGHTS]
    cos_radius = np.cos(np.radians(LIGHT_RADIUS_DEG))
    for centre, colour in zip(centres, rng.uniform(0.6, 1.0, (N_LIGHTS, 3))):
        radiance[directions @ centre > cos_radius] += 40.0 * colour
    return radiance.astype(np.float32)


def capture_path(sky: str = "gradient") -> Path:
    """The rendered capture under ``sky`` (rendered on first use)."""
    suffix = "" if sky == "gradient" else f"_{sky}"
    folder = CACHE / f"entropy_scenes_sphere_cap{LIGHT_CAP_X}{suffix}"
    if not (folder / "transforms.json").is_file():
        CACHE.mkdir(parents=True, exist_ok=True)
        envmap_file = CACHE / f"entropy_scenes_cap{LIGHT_CAP_X}{suffix}.exr"
        write_exr(envmap_file, capped_lights_envmap(sky=sky))
        settings = dataclasses.replace(SETTINGS, envmap=str(envmap_file))
        synthesize(folder, settings, progress=False)
    return folder


def regions(normal: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean masks (N,) of the regions (module docstring) from world normals (N, 3)."""
    rarely_seen = normal[:, 1] < -0.5
    badly_lit = (normal[:, 0] < -0.5) & ~rarely_seen
    sharply_lit = (normal[:, 0] > 0.5) & ~rarely_seen
    return {"sharply_lit": sharply_lit, "badly_lit": badly_lit, "rarely_seen": rarely_seen,
            "rest": ~(rarely_seen | badly_lit | sharply_lit)}


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
    parser.add_argument("--sky", choices=sorted(SKIES), default="gradient",
                        help="the sky outside the lights (module docstring)")
    return parser.parse_args().sky


def main(sky: str) -> None:
    start = time.perf_counter()
    path = capture_path(sky)
    render_s = time.perf_counter() - start
    capture = load(path)
    result = fit(capture, Config())
    observations = result.observations
    error = roughness_error(result, capture)
    masks = regions(observations.normal)
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
        spread_masks = regions(spread_fit.observations.normal)
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
        "scene": {**{name: getattr(SETTINGS, name) for name in
                     ("mesh", "materials", "views", "resolution", "spp", "texture_res", "cameras")},
                  "envmap": f"{sky} sky {SKIES[sky]} + {N_LIGHTS} lights of {LIGHT_RADIUS_DEG} deg "
                            f"where x > {LIGHT_CAP_X}"},
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
    for index, region in enumerate(REGIONS):
        region_index[masks[region]] = index
    panels = (
        ("entropy (calibrated)", observations.to_texture(result.uncertainty.entropy, np.nan), "magma", (0, 1)),
        ("|roughness error|", observations.to_texture(error.astype(np.float32), np.nan), "viridis", (0, 0.5)),
        ("regions: " + ", ".join(f"{i} {r}" for i, r in enumerate(REGIONS)),
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
