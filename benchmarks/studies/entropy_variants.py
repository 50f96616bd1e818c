"""Which definition of the entropy ranks the estimate's errors best? (issue #6)

    python benchmarks/studies/entropy_variants.py

On two Mitsuba-rendered captures, fitted once with our defaults (`global` estimator, T = 512):
- bunny: benchmarks/.cache/compare_bunny_64 (scenes.compare_capture, compare_estimators.py's
  bunny: bands material, forest map, 64 views on the upper hemisphere), rendered if missing;
- sphere: the capture of entropy_scenes.py (scenes.entropy_capture: sharp lights on one side, a
  smooth gradient elsewhere, cameras on the upper hemisphere only), rendered if missing;
each entropy variant is scored on the observed texels by Spearman rho and AURG
(freqbrdf.outputs.sparsification) against the per-texel roughness, base-colour (mean over RGB) and
metallic errors, and on the sphere by its mean per region. Variants:

- paper: the published recipe (UncertaintyConfig(mode="paper"));
- calibrated_fixed_noise: the calibrated mode before the noise floor depended on the number of
  samples (n_samples not passed: K samples assumed), amplitudes in phase;
- calibrated (the default): amplitudes in phase, coefficient noise noise_level^2 P K / n, the
  paper's Gaussian lobe exp(-(alpha l)^2);
- angular: the same grid scored in the sample domain with the estimator's own model
  (UncertaintyConfig(mode="angular"), `uncertainty.entropy_angular`);
- each calibrated and angular variant also with noise_level 0.05 (default 0.02). Seconds per
  variant include numba's loading the first time a kernel is used in the process;

and the posterior spread of the estimated roughness (`uncertainty.roughness_std`), which is not an
entropy over the hypotheses but the estimate's own uncertainty: the neighbour scatter alone
(windows 3, 5, 7; 7 is the default), the loss curvature alone, and both. To check that it is not
an artefact of the striped "bands" material, it is also scored on three photo-textured captures
of applications.py (scenes.application_capture: 100 views all around, rendered if missing):
bunny_sunset (chelsea), sphere_city (coffee), sphere_studio (astronaut).

Agreement with the path-traced brute force is measured by pathtraced_entropy.py. Saves
benchmarks/results/entropy_variants.json.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, UncertaintyConfig
from freqbrdf.estimate import estimate
from freqbrdf.model.materials import resize
from freqbrdf.observe.observations import Observations, observe
from freqbrdf.outputs import sparsification
from freqbrdf.sphere import harmonics as sh
from freqbrdf.uncertainty import entropy_from_spectra, entropy_map, roughness_std

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import machine, save_results
from scenes import application_capture, compare_capture, entropy_capture, entropy_regions

SPREAD_VARIANTS = {  # name: (roughness_window, loss_curvature, split_half)
    "roughness_std window 3": (3, False, False),
    "roughness_std window 5": (5, False, False),
    "roughness_std window 7": (7, False, False),
    "roughness_std curvature": (0, True, False),
    "roughness_std window 7 + curvature (default)": (7, True, False),
    "roughness_std split half": (0, False, True),
    "roughness_std window 7 + curvature + split half (fit --split-half)": (7, True, True),
}
TEXTURED_SCENES = ("bunny_sunset", "sphere_city", "sphere_studio")  # applications.py's, photo textures


def bunny_path():
    return compare_capture("bunny")


def sphere_path():
    return entropy_capture()


def variant_entropy(observations: Observations, name: str, noise_level: float) -> np.ndarray:
    """(N,) entropy of one variant (module docstring)."""
    if name == "angular":
        return entropy_map(observations, UncertaintyConfig(mode="angular", noise_level=noise_level),
                           return_likelihood=False).entropy
    if name == "paper":
        config = UncertaintyConfig(mode="paper")
    else:
        config = UncertaintyConfig(noise_level=noise_level)
    n_samples = None if name == "calibrated_fixed_noise" else observations.n_samples
    return entropy_from_spectra(
        observations.mirrored_spectrum, observations.observed_spectrum,
        n_samples=n_samples, sigma=observations.sigma,
        alpha_bound=observations.alpha_bound,
        fit_status=observations.fit_status, config=config, return_likelihood=False,
    ).entropy


def textured_path(name: str):
    return application_capture(name, 100)


def scene_scores(name: str, path) -> dict:
    capture = load(path)
    config = Config()
    start = time.perf_counter()
    observations = observe(capture, config)
    result = estimate(observations, config)
    fit_s = time.perf_counter() - start
    truth = resize(capture.ground_truth, observations.texture_res)
    flat = observations.texel_index
    observed = observations.fit_status != sh.FIT_EMPTY
    errors = {
        "roughness": np.abs(result.roughness - truth.roughness.ravel()[flat]),
        "base_color": np.abs(result.base_color - truth.base_color.reshape(-1, 3)[flat]).mean(axis=1),
        "metallic": np.abs(result.metallic - truth.metallic.ravel()[flat]),
    }
    masks = None
    if name == "sphere":
        masks = entropy_regions(observations.normal)

    def scores_of(uncertainty: np.ndarray) -> dict:
        scores = {}
        for error_name, error in errors.items():
            curves = sparsification.sparsification(uncertainty[observed], error[observed])
            scores[error_name] = {"spearman": round(float(curves.spearman), 4), "aurg": round(curves.aurg, 4)}
        return scores

    variants = {}
    for variant in ("paper", "calibrated_fixed_noise", "calibrated", "angular"):
        for noise_level in ((None,) if variant == "paper" else (0.02, 0.05)):
            start = time.perf_counter()
            entropy = variant_entropy(observations, variant, noise_level)
            seconds = time.perf_counter() - start
            key = variant if noise_level is None else f"{variant}@{noise_level}"
            entry = {"scores": scores_of(entropy), "mean_entropy": round(float(entropy[observed].mean()), 4),
                     "seconds": round(seconds, 3)}
            if masks is not None:
                entry["mean_entropy_by_region"] = {
                    region: round(float(entropy[mask & observed].mean()), 4) for region, mask in masks.items()}
            variants[key] = entry
            print(name, key, entry, flush=True)
    for key, (window, curvature, split_half) in SPREAD_VARIANTS.items():
        spread_config = dataclasses.replace(config, uncertainty=UncertaintyConfig(
            roughness_window=window, loss_curvature=curvature, split_half=split_half))
        start = time.perf_counter()
        spread = roughness_std(observations, result, spread_config)
        entry = {"scores": scores_of(spread), "mean_roughness_std": round(float(np.nanmean(spread[observed])), 4),
                 "seconds": round(time.perf_counter() - start, 3)}
        variants[key] = entry
        print(name, key, entry, flush=True)
    return {"capture": str(path), "observed_texels": int(observed.sum()), "fit_seconds": round(fit_s, 2),
            "variants": variants}


def main() -> int:
    scenes = {"bunny": scene_scores("bunny", bunny_path()), "sphere": scene_scores("sphere", sphere_path())}
    for name in TEXTURED_SCENES:
        scenes[name] = scene_scores(name, textured_path(name))
    save_results("entropy_variants", {
        "benchmark": "entropy variants vs per-texel errors of the global estimate",
        **machine(),
        "error_of": "absolute per-texel error on observed texels (base colour: mean over RGB)",
        "scenes": scenes,
    })
    return 0


if __name__ == "__main__":
    sys.exit(main())
