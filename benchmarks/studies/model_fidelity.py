"""How close is the estimator's forward model to Mitsuba's path tracer, sample by sample? (issues #5, #6)

    python benchmarks/studies/model_fidelity.py

On the capture of studies/entropy_scenes.py (scenes.entropy_capture: a sphere under a gradient sky and 24 small lights, no
interreflection), for the texels pathtraced_entropy.py scores, a metal of base colour k and
roughness r (the hypothesis grid's) is rendered with Mitsuba's path tracer along every observed
view (pathtraced_entropy.hypothesis_radiance, two seeds) and predicted by the `global` model of
the default EstimateConfig, written with the estimator's numpy references: split-sum albedo
(A, B), the prefiltered map (`model.light.prefiltered_light`) blended into the environment light
(`model.light.environment_filtered_light`) plus the map's degrees above 5. Reported per roughness:
the relative RMS error of the model against one rendering, the rendering's own Monte Carlo noise
(half the RMS difference of the two seeds' radiance, relative, per rendering), the ratio of the
summed radiance, and the error per band of view cosine at k = 1. Saves
benchmarks/results/model_fidelity.json.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from freqbrdf import estimate as est
from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, EstimateConfig
from freqbrdf.model.light import (
    environment_filtered_light,
    environment_weight,
    prefiltered_environment,
    prefiltered_light,
)
from freqbrdf.model.tables import split_sum_terms
from freqbrdf.observe.observations import observe
from freqbrdf.texels import rasterise
from freqbrdf.uncertainty import entropy_map, hypothesis_grid

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from pathtraced_entropy import SEEDS, choose_texels, hypothesis_radiance

from _common import machine, save_results
from scenes import entropy_capture

COSINE_BANDS = ((0.0, 0.3), (0.3, 0.5), (0.5, 0.7), (0.7, 0.85), (0.85, 1.0001))


def relative_rms(model: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean((model - truth) ** 2)) / np.sqrt(np.mean(truth**2)))


def model_terms(observations, roughness: float, settings: EstimateConfig) -> tuple[np.ndarray, np.ndarray]:
    """(X, Y) (n, V, 3) of a metal's specular k X + Y at this roughness under the default model."""
    directions = observations.view_direction.astype(np.float64)
    weight, tangent = observations.weight, observations.tangent.astype(np.float64)
    normal = observations.normal.astype(np.float64)
    environment = observations.environment_coeffs.astype(np.float64)
    envmap, rotation = observations.environment(), observations.environment_rotation
    per_texel = np.full(observations.n_texels, roughness)
    share = float(environment_weight(np.array(roughness), settings.environment_blend))
    own = prefiltered_light(directions, tangent, normal, prefiltered_environment(
        envmap, est.prefilter_nodes(settings)), rotation, per_texel) if share < 1.0 else 0.0
    high = prefiltered_light(directions, tangent, normal, prefiltered_environment(
        envmap, est.prefilter_nodes(EstimateConfig(environment_light=False)),
        skip_degrees=min(observations.lmax, 5) + 1),  # the environment light holds degrees <= min(l*, 5)
        rotation, per_texel)
    scale, bias, _ = split_sum_terms(directions[..., 2], roughness)
    terms = []
    for albedo, term in ((scale, "scale"), (bias, "bias")):
        environment_light = (environment_filtered_light(directions, weight, tangent, normal, environment,
                                                            per_texel, term) if share > 0.0 else 0.0)
        terms.append(albedo[..., None] * ((1.0 - share) * own + share * (environment_light + high)))
    return terms[0], terms[1]


def main() -> None:
    capture = load(entropy_capture())
    config = Config()
    texels = rasterise(capture.mesh, config.texels.texture_res)
    observations = observe(capture, config, texels=texels)
    chosen = choose_texels(entropy_map(observations, config.uncertainty, return_likelihood=False).entropy,
                           observations.n_samples)
    centres = np.array([frame.camera.center for frame in capture.frames])
    texel_of, view_of = np.nonzero(observations.weight[chosen] > 0)
    positions = texels.position[chosen][texel_of].astype(np.float64)
    directions = centres[view_of] - positions
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    grid = hypothesis_grid(config.uncertainty.resolution())
    rendered, other = (hypothesis_radiance(capture, positions, directions, grid, seed) for seed in SEEDS)
    subset = observations.select(chosen)
    sampled = subset.weight > 0  # row-major: the rays' order
    cosine = subset.view_direction[..., 2][sampled].astype(np.float64)
    rows = {}
    for i, alpha in enumerate(grid.alpha):
        roughness = math.sqrt(alpha)
        scale_terms, bias_terms = (term[sampled] for term in model_terms(subset, roughness, config.estimate))
        errors, noise = [], []
        for j, specular in enumerate(grid.specular):
            if specular == 0.0:
                continue
            errors.append(relative_rms(specular * scale_terms + bias_terms, rendered[i, j]))
            noise.append(relative_rms(other[i, j], rendered[i, j]) / math.sqrt(2.0))  # var(a - b) = 2 var
        model = scale_terms + bias_terms  # k = 1
        rows[f"{roughness:.3f}"] = {
            "relative_rms_error_by_k": [round(e, 4) for e in errors],
            "monte_carlo_noise_by_k": [round(e, 4) for e in noise],
            "summed_radiance_ratio_k1": round(float(model.sum() / rendered[i, -1].sum()), 4),
            "relative_rms_error_k1_by_view_cosine": {
                f"{low:g}-{min(high, 1.0):g}": round(relative_rms(model[band], rendered[i, -1][band]), 4)
                for low, high in COSINE_BANDS if (band := (cosine >= low) & (cosine < high)).any()},
        }
        print(f"r = {roughness:.3f}: {rows[f'{roughness:.3f}']}", flush=True)
    save_results("model_fidelity", {
        "benchmark": "the global model's per-sample radiance against Mitsuba's path tracer (metal hypotheses)",
        **machine(), "capture": "benchmarks/studies/entropy_scenes.py", "texels": len(chosen), "rays": len(positions),
        "by_roughness": rows,
    })


if __name__ == "__main__":
    main()
