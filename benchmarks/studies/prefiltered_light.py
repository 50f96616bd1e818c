"""What would prefiltered environment maps buy smooth lobes? (issue #5; a measurement, not a product path)

    python benchmarks/studies/prefiltered_light.py [--scenes demo,bunny,plane] [--texture-res 128]

With the fitted light alone, smooth texels come out too rough (on the demo capture, with the
model's loss at the true parameters above that at the estimate): below r = 0.3 the lobes read the
per-texel SH fit (l* = 5) of the mirrored samples, which cannot hold a smooth lobe's sharp
reflections. This benchmark scores these lights with the same brute-force
least-squares search (41 roughness nodes, the metallic profiled by
`estimate._profile_kernels.profile_metallic`, no Brent, no robust pass), so that only the smooth
lobes' light differs:

- ``fitted``: the estimator's light (the fitted light, blended over roughness 0.3-0.6 into its
  environment light, `model.light.environment_filtered_light`);
- ``prefiltered``: below the blend, the environment map low-passed by the paper's kernel
  exp(-(alpha l)^2) (alpha = r^2, every degree the map holds; `envmap.lowpass_envmap`), looked up
  at each sample's world mirror direction, at roughness nodes 1/16 apart and linear between them;
- ``prefiltered_ggx``: the same with the GGX lobe's own per-degree gains at normal incidence
  (`model.tables.ggx_lobe_gains`: heavier tails than the Gaussian), to see how much of what is left is
  the Gaussian's shape. This one is the estimator's default
  (`EstimateConfig.prefiltered_light`, built into the search kernel).

Scenes: the demo capture (rendered by `make demo`) and compare_estimators.py's 64-view bunny and
plane (scenes.compare_folder; rendered by compare_estimators.py). Saves
benchmarks/results/prefiltered_light.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numba
import numpy as np

from freqbrdf import estimate as est
from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, EstimateConfig, TexelConfig
from freqbrdf.estimate import _profile_kernels as profile
from freqbrdf.model.light import (
    environment_azimuthal,
    environment_filtered_light,
    environment_weight,
    lobe_filtered_light,
)
from freqbrdf.model.materials import resize
from freqbrdf.model.tables import LOBE_TERMS, burley_diffuse_factor, ggx_lobe_gains, split_sum_terms
from freqbrdf.observe.observations import observe
from freqbrdf.outputs import export, metrics
from freqbrdf.sphere import envmap as envmaps
from freqbrdf.synthetic import demo

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import machine, save_results
from scenes import compare_folder

ROUGHNESS_SEARCH = np.linspace(0.0, 1.0, 41)
PREFILTER_STEP = 1.0 / 16.0  # roughness between prefiltered maps
SMOOTH = 0.3  # texels with true roughness below this are "smooth"


@numba.njit(parallel=True)
def profile_texels(x, y, z, diffuse, values, omega, diffuse_scale, out_state, out_loss):
    """Per texel: the least-squares (b, m) for these per-sample model terms (3 channels)."""
    for t in numba.prange(x.shape[0]):
        moments = np.zeros((3, 14))
        squared = np.zeros(3)
        quadratics = np.empty((3, 3, 3))
        state = np.empty(4)
        for c in range(3):
            for v in range(x.shape[1]):
                o = omega[t, v]
                if o <= 0.0:
                    continue
                a, b, e, d, f = x[t, v, c], y[t, v, c], z[t, v, c], diffuse[t, v], values[t, v, c]
                terms = (a * d, b * d, e * d, a * a, a * b, a * e, a * f, b * b, b * e, b * f, e * e, e * f,
                         d * d, f * d)
                for k in range(14):
                    moments[c, k] += o * terms[k]
                squared[c] += o * f * f
        profile.metallic_quadratics(moments, squared, diffuse_scale[t], quadratics)
        out_loss[t] = profile.profile_metallic(quadratics, state, 4)
        out_state[t] = state


def capture_path(name: str):
    if name == "demo":
        folder = demo.capture_folder(Path(__file__).resolve().parents[2] / "out" / "demo", demo.DEFAULT_CAPTURE)
        hint = "run `make demo` first"
    else:
        folder = compare_folder(name)
        hint = f"run benchmarks/studies/compare_estimators.py --scenes {name} first"
    if not folder.is_dir():
        raise SystemExit(f"{folder} is missing: {hint}")
    return folder


def run_scene(name: str, texture_res: int) -> dict:
    capture = load(capture_path(name))
    config = Config(texels=TexelConfig(texture_res=texture_res))
    blend = EstimateConfig().environment_blend
    observations = observe(capture, config)
    n_texels = observations.n_texels
    directions = observations.view_direction.astype(np.float64)
    weight = observations.weight
    cos_theta = directions[..., 2]
    omega = weight.astype(np.float64) ** 2
    values = observations.observed.astype(np.float64)
    diffuse_scale = observations.irradiance.astype(np.float64) / np.pi
    tangent, normal = observations.tangent.astype(np.float64), observations.normal.astype(np.float64)
    environment = observations.environment_coeffs.astype(np.float64)
    mirror = directions * np.array([-1.0, -1.0, 1.0])
    bitangent = np.cross(normal, tangent)
    world = mirror[..., :1] * tangent[:, None] + mirror[..., 1:2] * bitangent[:, None] + mirror[..., 2:] * normal[:, None]
    nodes = np.arange(0.0, blend[1] + PREFILTER_STEP, PREFILTER_STEP)
    height, width = capture.envmap.radiance.shape[:2]
    map_lmax = min(height - 2, (width - 1) // 2)
    prefiltered = {
        "prefiltered": np.stack([envmaps.lookup(envmaps.lowpass_envmap(capture.envmap, r * r), world) for r in nodes]),
        "prefiltered_ggx": np.stack([envmaps.lookup(envmaps.zonal_filter(capture.envmap,
                                                                         ggx_lobe_gains(r, map_lmax)), world)
                                     for r in nodes]),
    }
    azimuthal = environment_azimuthal(directions, weight, tangent, normal, environment)
    models = ("fitted", "prefiltered", "prefiltered_ggx")
    best_loss = {model: np.full(n_texels, np.inf) for model in models}
    best = {model: np.zeros((n_texels, 5)) for model in models}
    start = time.perf_counter()
    for roughness in ROUGHNESS_SEARCH:
        scale, bias, dielectric = split_sum_terms(cos_theta, roughness)
        share = float(environment_weight(np.array(roughness), blend))
        per_texel = np.full(n_texels, roughness)
        environment_lights = [
            environment_filtered_light(directions, weight, tangent, normal, environment, per_texel, term,
                                           azimuthal) if share > 0.0 else 0.0 for term in LOBE_TERMS]
        for model in models:
            lights = []
            for term, environment_light in zip(LOBE_TERMS, environment_lights):
                if share >= 1.0:
                    own = 0.0
                elif model == "fitted":
                    own = lobe_filtered_light(directions, weight, observations.mirrored_coeffs, observations.lmax,
                                                  observations.sigma, per_texel, False, term)
                else:
                    node = min(int(roughness / PREFILTER_STEP), len(nodes) - 2)
                    frac = roughness / PREFILTER_STEP - node
                    own = prefiltered[model][node] * (1.0 - frac) + prefiltered[model][node + 1] * frac
                lights.append((1.0 - share) * own + share * environment_light)
            x, y, z = (albedo[..., None] * light for albedo, light in zip((scale, bias, dielectric), lights))
            state, loss = np.zeros((n_texels, 4)), np.zeros(n_texels)
            profile_texels(x, y, z, burley_diffuse_factor(cos_theta, roughness), values, omega, diffuse_scale,
                           state, loss)
            better = loss < best_loss[model]
            best_loss[model][better] = loss[better]
            best[model][better, :3], best[model][better, 3], best[model][better, 4] = (
                state[better, :3], roughness, state[better, 3])
    truth = resize(capture.ground_truth, texture_res)
    observed = observations.to_texture(observations.n_samples > 0, fill=False).astype(bool)
    true_roughness = truth.roughness.reshape(-1)[observations.texel_index]
    estimated = observations.n_samples >= est.MIN_SAMPLES
    smooth = estimated & (true_roughness < SMOOTH)
    scores = {}
    for model in models:
        params = np.where(estimated[:, None], best[model], np.nan)
        result = est.MaterialEstimate(texture_res, observations.texel_index, params[:, :3], params[:, 3], params[:, 4],
                                      estimated, best_loss[model] / np.maximum(omega.sum(axis=1), 1e-12), model)
        error = result.roughness[smooth] - true_roughness[smooth]
        scores[model] = {
            "texture": metrics.texture_scores(export.material_textures(result, config.texels.dilation_px), truth,
                                              observed),
            "mean_loss": float(np.mean(result.loss[estimated])),
            "smooth_texels": int(smooth.sum()),
            "smooth_roughness_bias": float(np.mean(error)),
            "smooth_roughness_mae": float(np.mean(np.abs(error))),
        }
        print(f"[{name}] {model}: {scores[model]}", flush=True)
    return {"texture_res": texture_res, "texels": int(n_texels), "search_seconds": round(time.perf_counter() - start, 1),
            "models": scores}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="demo,bunny,plane")
    parser.add_argument("--texture-res", type=int, default=128)
    args = parser.parse_args(argv)
    result = {"benchmark": "prefiltered environment maps for smooth lobes (issue #5)", **machine(),
              "roughness_nodes": len(ROUGHNESS_SEARCH), "prefilter_step": PREFILTER_STEP, "smooth_below": SMOOTH,
              "scenes": {name: run_scene(name, args.texture_res) for name in args.scenes.split(",")}}
    save_results("prefiltered_light", result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
