"""How much of `global`'s remaining error is the light it reads? (issue #5)

    python benchmarks/light_representation.py [--scenes bunny,plane] [--texture-res 128]

The estimator's model reads, per sample, the incoming light filtered by the lobe: the per-texel
SH fit of the mirrored light (l* = 5, from the texel's ~40 samples) times the Gaussian kernel
exp(-(alpha^2 - sigma^2) l^2), at the mirror direction. On rough dielectrics of the demo capture
that predicted 0.0104 of specular at grazing views where a brute-force integral of the principled
BSDF over the environment gives 0.0190 (and 0.0106 against 0.0137 near the normal): the fit
extrapolates where a rough lobe reads it, and the GGX lobe's per-degree response is far from the
Gaussian (at r = 1, degree 1: 0.62 against 0.37).

This benchmark scores two light models with the same brute-force least-squares search (41
roughness nodes, the metallic profiled by `estimate._profile_metallic`, no Brent, no robust pass),
so only the light differs:

- ``fitted``: the estimator's light (mirror lookup, fitted light, Gaussian kernel);
- ``hybrid``: for roughness above 0.3 blended (smoothstep to 0.6) towards the environment's exact
  world-frame SH (l* 5) read at a direction tilted towards the normal with per-degree gains, both
  fitted per (view cosine, roughness, lobe term) to the GGX lobe's response (`fit_ggx_response`);
  smooth lobes keep the fitted light, which reproduces the mirrored samples.

Scenes: compare_estimators.py's 64-view captures (render them there first), at a reduced
texture resolution since the search here is plain numpy. Saves
benchmarks/results/light_representation.json. Not a product path: it measures what a better
light would buy before it is built into the search kernel.
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np
from _common import machine, save_results
from compare_estimators import CACHE

from freqbrdf import export, metrics, sh
from freqbrdf import envmap as envmaps
from freqbrdf import estimate as est
from freqbrdf.capture import load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.materials import resize
from freqbrdf.observations import observe
from freqbrdf.texels import rasterise

LMAX = 5
NODES = 17  # (view cosine, roughness) nodes of the fitted response tables
ROUGHNESS_SEARCH = np.linspace(0.0, 1.0, 41)
BLEND = (0.3, 0.6)  # roughness over which the hybrid light moves from fitted to exact


def fit_ggx_response(cos_theta: float, roughness: float, term: str):
    """(tilt, gains (l*+1,)) whose lookup gain_l Y_lm(w'(tilt)) best matches the lobe term's SH
    response (`estimate.lobe_sh_response`): per tilt on a grid, each degree's gain by least squares."""
    albedo, response, view = est.lobe_sh_response(cos_theta, roughness, term, LMAX)
    response = response / max(albedo, 1e-12)
    degree = sh.sh_degrees(LMAX)
    tilts = np.linspace(0.0, 1.0, 201)
    looked_up = tilts[:, None] * view + (1.0 - tilts)[:, None] * np.array([0.0, 0.0, 1.0])
    basis = sh.eval_sh(looked_up / np.linalg.norm(looked_up, axis=1, keepdims=True), LMAX)
    best = (np.inf, 1.0, np.ones(LMAX + 1))
    for tilt, row in zip(tilts, basis):
        gains = np.array([row[degree == l] @ response[degree == l] / max(row[degree == l] @ row[degree == l], 1e-12)
                          for l in range(LMAX + 1)])
        misfit = np.sum((gains[degree] * row - response) ** 2)
        if misfit < best[0]:
            best = (misfit, tilt, gains)
    return best[1], best[2]


def response_tables() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """term -> (tilt (NODES, NODES), gains (NODES, NODES, l*+1)) over (view cosine, roughness)."""
    path = CACHE / "ggx_response_tables.npz"
    if path.exists():
        stored = np.load(path)
        return {term: (stored[f"{term}_tilt"], stored[f"{term}_gains"]) for term in est.LOBE_TERMS}
    nodes = np.linspace(0.0, 1.0, NODES)
    tables = {}
    for term in est.LOBE_TERMS:
        fits = [[fit_ggx_response(c, r, term) for r in nodes] for c in nodes]
        tables[term] = (np.array([[fit[0] for fit in row] for row in fits]),
                        np.array([[fit[1] for fit in row] for row in fits]))
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **{f"{term}_{part}": table[i] for term, table in tables.items()
                      for i, part in enumerate(("tilt", "gains"))})
    return tables


def bilinear(table: np.ndarray, cos_theta: np.ndarray, roughness: float) -> np.ndarray:
    x = np.clip(cos_theta, 0.0, 1.0) * (NODES - 1)
    i = np.minimum(x.astype(int), NODES - 2)
    fx = x - i
    y = min(max(roughness, 0.0), 1.0) * (NODES - 1)
    j = min(int(y), NODES - 2)
    fy = y - j
    if table.ndim == 3:
        fx = fx[..., None]
    return ((table[i, j] * (1 - fx) + table[i + 1, j] * fx) * (1 - fy)
            + (table[i, j + 1] * (1 - fx) + table[i + 1, j + 1] * fx) * fy)


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
        est._metallic_quadratics(moments, squared, diffuse_scale[t], quadratics)
        out_loss[t] = est._profile_metallic(quadratics, state, 4)
        out_state[t] = state


def run_scene(name: str, texture_res: int, tables) -> dict:
    folder = CACHE / f"compare_{name}_64"
    if not folder.is_dir():
        raise SystemExit(f"{folder} is missing: run benchmarks/compare_estimators.py --scenes {name} first "
                         "(it renders it)")
    capture = load(folder)
    config = Config(texels=TexelConfig(texture_res=texture_res))
    observations = observe(capture, config)
    texels = rasterise(capture.mesh, texture_res)
    rows = np.searchsorted(texels.texel_index, observations.texel_index)
    frame = np.stack([texels.tangent[rows], texels.bitangent[rows], texels.normal[rows]], axis=1)  # (N, 3, 3)
    environment = envmaps.envmap_sh(capture.envmap, LMAX)  # (K, 3) world frame
    directions = observations.view_direction.astype(np.float64)
    cos_theta = directions[..., 2]
    omega = observations.weight.astype(np.float64) ** 2
    values = observations.observed.astype(np.float64)
    diffuse_scale = observations.irradiance.astype(np.float64) / np.pi
    degree = sh.sh_degrees(LMAX)
    n_texels = observations.n_texels
    truth = resize(capture.ground_truth, texture_res)
    observed = observations.to_texture(observations.n_samples > 0, fill=False).astype(bool)

    def fitted(roughness):
        return est.lobe_filtered_light(directions, observations.weight, observations.mirrored_coeffs, observations.lmax,
                                       observations.sigma, np.full(n_texels, roughness), False)

    def exact(roughness, term):
        tilt_table, gain_table = tables[term]
        tilt = bilinear(tilt_table, cos_theta, roughness)
        gains = bilinear(gain_table, cos_theta, roughness)
        looked_up = directions * np.array([-1.0, -1.0, 1.0]) * tilt[..., None]
        looked_up[..., 2] += 1.0 - tilt
        looked_up /= np.maximum(np.linalg.norm(looked_up, axis=-1, keepdims=True), 1e-12)
        world = np.einsum("nvi,nij->nvj", looked_up, frame)
        return np.einsum("nvk,kc->nvc", sh.eval_sh(world, LMAX) * gains[..., degree], environment)

    scores = {}
    for model in ("fitted", "hybrid"):
        start = time.perf_counter()
        best_loss = np.full(n_texels, np.inf)
        best = np.zeros((n_texels, 5))
        for roughness in ROUGHNESS_SEARCH:
            scale, bias, dielectric = est.split_sum_terms(cos_theta, roughness)
            light = fitted(roughness)
            lights = [light, light, light]
            blend = np.clip((roughness - BLEND[0]) / (BLEND[1] - BLEND[0]), 0.0, 1.0)
            blend = blend * blend * (3.0 - 2.0 * blend)
            if model == "hybrid" and blend > 0.0:
                lights = [(1.0 - blend) * light + blend * exact(roughness, term) for term in est.LOBE_TERMS]
            x, y, z = (albedo[..., None] * term_light for albedo, term_light in zip((scale, bias, dielectric), lights))
            state, loss = np.zeros((n_texels, 4)), np.zeros(n_texels)
            profile_texels(x, y, z, est.burley_diffuse_factor(cos_theta, roughness), values, omega, diffuse_scale,
                           state, loss)
            better = loss < best_loss
            best_loss[better] = loss[better]
            best[better, :3], best[better, 3], best[better, 4] = state[better, :3], roughness, state[better, 3]
        estimated = observations.n_samples >= est.MIN_SAMPLES
        result = est.MaterialEstimate(texture_res, observations.texel_index, best[:, :3], best[:, 3], best[:, 4],
                                      estimated, best_loss / np.maximum(omega.sum(axis=1), 1e-12), model)
        result.base_color[~estimated] = np.nan
        result.roughness[~estimated] = np.nan
        result.metallic[~estimated] = np.nan
        texture = metrics.texture_scores(export.material_textures(result, config.texels.dilation_px), truth, observed)
        scores[model] = {"texture": texture, "mean_loss": float(np.mean(result.loss[estimated])),
                         "seconds": round(time.perf_counter() - start, 1)}
        print(f"[{name}] {model}: {texture}", flush=True)
    return {"texture_res": texture_res, "texels": int(n_texels), "models": scores}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="bunny,plane")
    parser.add_argument("--texture-res", type=int, default=128)
    args = parser.parse_args(argv)
    tables = response_tables()
    result = {"benchmark": "light representation of the global estimator's model (issue #5)", **machine(),
              "roughness_nodes": len(ROUGHNESS_SEARCH), "blend_roughness": BLEND,
              "scenes": {name: run_scene(name, args.texture_res, tables) for name in args.scenes.split(",")}}
    save_results("light_representation", result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
