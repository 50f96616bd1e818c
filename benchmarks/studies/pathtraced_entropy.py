"""The paper's check (docs/method.md#evaluation): the hypothesis grid scored by brute force with a path tracer
must rank texels like our fast SH-spectrum entropy.

    python benchmarks/studies/pathtraced_entropy.py [--sky gradient|flat]

On the capture of studies/entropy_scenes.py (scenes.entropy_capture, rendered on first use;
`--sky flat` for its flat sky, results then in pathtraced_entropy_flat.json), for SUBSET texels
spread over the range of our entropy, every hypothesis psi = (alpha_i, k_j) of the R x R grid is
rendered with Mitsuba's path tracer: one scene whose material is a principled BSDF with
roughness sqrt(alpha_i), metallic 1 and base colour k_j (a specular lobe of reflectance k_j, no
diffuse part), radiance traced along each texel's observed view directions (rays from just
in front of the texel towards it, SPP samples each). The brute-force likelihood per texel and
channel compares those radiances with the observed ones, sample by sample:

    misfit(psi) = sum_v w_v (o_v - d - s_psi,v)^2 / sum_v w_v,  d = max(0, weighted mean of o - s_psi)

(d is the best view-independent, i.e. diffuse, part; w_v the observation weights), and the
noise model mirrors our calibrated mode: variance = (NOISE_LEVEL x the RMS mirrored-environment
radiance of the texel's samples)^2 + the best misfit per residual degree of freedom, likelihood
exp(-n (misfit - min misfit) / (2 variance)), k = 0 column one material, normalised entropy,
minimum over RGB. This "sample" brute force asks whether the spectra lose what the samples hold.

The "spectral" brute force asks only whether our model of a hypothesis's spectrum is right: the
path-traced radiance of each hypothesis is fitted to SH at the texel's samples exactly as the
observed radiance is (its directions, weights, degree and regulariser), and the amplitude spectra
of those fits are scored exactly as our calibrated mode scores its analytic k F(alpha, l)
sqrt(S_refl(l)) (`spectral_entropy`, a direct evaluation; scoring the analytic amplitudes with it
reproduces our fast entropy: "scoring_check_max_abs_difference").

Reported: Spearman rank correlation of each brute force with ours (calibrated default and paper
mode on the 8 x 8 grid; the
angular mode on its own grid, the estimator's 9 roughness nodes, as `fit` computes it from its
search); each entropy's rank correlation with the
default fit's roughness error on the same texels; mean entropy per region (scenes.entropy_regions);
the difference of the mean entropy between the badly and the sharply lit regions, with a 95 %
bootstrap interval (is the badly lit region more uncertain?); timings, with those of the fit with
the angular entropy (the second fit in the process: compiled;
benchmarks/timing/bench_fit.py --fit-option=--entropy=angular times it as a user runs it). The
brute force is itself a Monte Carlo estimate: it is rendered twice with independent seeds, and the rank correlation of the two
brute-force entropies (its self-agreement) is the ceiling for any agreement with either. The
reference is their pooled rendering (the mean radiance of both, 2 x SPP paths per ray), whose noise
is half the variance of either; every agreement is given with a 95 % bootstrap interval over the
texels. Saves benchmarks/results/pathtraced_entropy.json. The renderings are kept in
benchmarks/.cache/ (keyed by the environment map, the rays, SPP and seed; delete them to render
again).
"""

from __future__ import annotations

import hashlib
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy import stats

from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, UncertaintyConfig
from freqbrdf.pipeline import fit
from freqbrdf.render.scenes import build_scene, mitsuba
from freqbrdf.sphere import harmonics as sh
from freqbrdf.texels import rasterise
from freqbrdf.uncertainty import entropy_map, hypothesis_filter, hypothesis_grid

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from entropy_scenes import results_name, roughness_error, sky_argument

from _common import machine, save_results
from scenes import CACHE, entropy_capture, entropy_regions

SUBSET = 400  # texels scored by brute force (enough for a narrow 95 % interval of the agreement)
MIN_VIEWS = 8  # texels with fewer samples are not candidates (the brute-force misfit needs some)
SPP = 512  # path samples per (texel, view) radiance (fewer: the brute force agrees less with itself)
NOISE_LEVEL = UncertaintyConfig().noise_level
RAY_OFFSET = 1e-3  # ray origins this far (x the object's radius) in front of the texel
SEEDS = (0, 1000)  # two independent renderings of every hypothesis
BOOTSTRAP = 2000  # resamples of the texels for the agreements' intervals


def choose_texels(entropy: np.ndarray, n_samples: np.ndarray) -> np.ndarray:
    """SUBSET texel indices with at least MIN_VIEWS samples, evenly spaced in entropy rank."""
    candidates = np.flatnonzero(n_samples >= MIN_VIEWS)
    ranked = candidates[np.argsort(entropy[candidates], kind="stable")]
    return ranked[np.linspace(0, len(ranked) - 1, SUBSET).round().astype(int)]


def hypothesis_radiance(capture, positions, directions, grid, seed: int) -> np.ndarray:
    """(R, R, M, 3) mean path-traced radiance along M rays (origin at positions + offset towards
    the camera, looking back along -directions) for every hypothesis (alpha_i, k_j)."""
    mi = mitsuba()
    radius = float(np.linalg.norm(capture.mesh.vertices - capture.mesh.vertices.mean(axis=0), axis=1).max())
    origins = positions + RAY_OFFSET * radius * directions
    n_rays = len(origins)
    bsdf = {"type": "principled", "base_color": {"type": "rgb", "value": [1.0, 1.0, 1.0]},
            "roughness": 0.5, "metallic": 1.0}
    scene = build_scene(capture.mesh, bsdf, capture.envmap)
    params = mi.traverse(scene)
    (colour_key,) = [key for key in params.keys() if key.endswith("base_color.value")]
    (roughness_key,) = [key for key in params.keys() if key.endswith("roughness.value")]
    repeated = np.repeat(np.arange(n_rays), SPP)
    ray = mi.Ray3f(mi.Point3f(*origins[repeated].T.astype(np.float32)),
                   mi.Vector3f(*(-directions[repeated]).T.astype(np.float32)))
    integrator = scene.integrator()
    sampler = mi.load_dict({"type": "independent"})
    radiance = np.zeros((grid.resolution, grid.resolution, n_rays, 3))  # k = 0: no lobe, no light
    for i, alpha in enumerate(grid.alpha):
        for j, specular in enumerate(grid.specular):
            if specular == 0.0:
                continue
            # Schlick's F with R0 = k is not linear in k: every (alpha, k) is rendered.
            params[roughness_key] = float(math.sqrt(alpha))
            params[colour_key] = mi.Color3f(float(specular), float(specular), float(specular))
            params.update()
            sampler.seed(seed + i * grid.resolution + j, len(repeated))
            spectrum, _, _ = integrator.sample(scene, sampler, ray)
            values = np.array(spectrum)
            values = values.T if values.shape[0] == 3 else values  # (rays x SPP, 3)
            radiance[i, j] = values.reshape(n_rays, SPP, 3).mean(axis=1)
    return radiance


def brute_force_entropy(observed, mirrored, weight, radiance) -> np.ndarray:
    """Normalised entropy per texel (minimum over RGB); arguments per texel: observed, mirrored
    (V, 3), weight (V,), radiance (R, R, V, 3) of the hypotheses at the same samples."""
    resolution = radiance.shape[0]
    n_samples = len(weight)
    share = weight / weight.sum()
    entropies = []
    for c in range(3):
        residual = observed[None, None, :, c] - radiance[..., c]  # (R, R, V)
        diffuse = np.maximum((residual * share).sum(axis=-1, keepdims=True), 0.0)
        misfit = ((residual - diffuse) ** 2 * share).sum(axis=-1)  # (R, R)
        light_rms = math.sqrt(float((mirrored[:, c] ** 2 * share).sum()))
        variance = (NOISE_LEVEL * light_rms) ** 2 + misfit.min() * n_samples / max(n_samples - 3, 1)
        log_weight = -n_samples * (misfit - misfit.min()) / (2.0 * max(variance, 1e-30))
        posterior = np.exp(log_weight)
        posterior[:, 0] /= resolution  # the k = 0 column is one material
        posterior /= posterior.sum()
        masses = np.concatenate([[posterior[:, 0].sum()], posterior[:, 1:].ravel()])
        masses = masses[masses > 0]
        entropies.append(-(masses * np.log(masses)).sum() / math.log(resolution * (resolution - 1) + 1))
    return float(min(entropies))


def hypothesis_amplitudes(observations, chosen, texel_of, view_of, radiance, fit_settings) -> np.ndarray:
    """(M, R, R, 3, l*+1) amplitudes sqrt(S(l)) of the path-traced hypotheses' radiance, fitted to
    SH at each chosen texel's samples exactly as `observe` fits the observed radiance (its
    directions, weights, degree and ``fit_settings``' regulariser): the spectra our fast model
    predicts analytically."""
    resolution = radiance.shape[0]
    n_chosen = len(chosen)
    values = np.zeros((n_chosen, observations.n_views, resolution * resolution * 3))
    values[texel_of, view_of] = radiance.transpose(2, 0, 1, 3).reshape(len(texel_of), -1)
    fitted = sh.fit_sh(observations.view_direction[chosen], observations.weight[chosen], values, observations.lmax,
                       fit_settings.reg_lambda, fit_settings.regulariser, fit_settings.scale_lambda_with_weight)
    spectrum = sh.power_spectrum(fitted.coeffs)  # (M, R R 3, l*+1)
    return np.sqrt(np.maximum(spectrum, 0.0)).reshape(n_chosen, resolution, resolution, 3, -1)


def analytic_amplitudes(observations, chosen, grid) -> np.ndarray:
    """(M, R, R, 3, l*+1) our calibrated mode's model amplitudes k F_il sqrt(S_refl(l)): F the
    hypothesis filter."""
    lobe_filter = hypothesis_filter(grid, observations.lmax, observations.sigma)  # (R, l*+1)
    light = np.sqrt(observations.mirrored_spectrum[chosen].astype(np.float64))  # (M, 3, l*+1)
    return grid.specular[None, None, :, None, None] * lobe_filter[None, :, None, None, :] * light[:, None, None, :, :]


def spectral_entropy(observations, chosen, model_amplitude, settings: UncertaintyConfig) -> np.ndarray:
    """(M,) normalised entropy (minimum over RGB) of the hypotheses whose amplitude spectra are
    ``model_amplitude`` (M, R, R, 3, l*+1), scored as our calibrated mode scores its analytic
    ones (a direct evaluation, no fast kernel): amplitude residuals over l >= 1, the specular DC
    no larger than the observed DC, noise variance 2 noise_level^2 P K / n + 2 min misfit / (l* - 2),
    the k = 0 column one material."""
    resolution = model_amplitude.shape[1]
    lmax = observations.lmax
    observed = np.sqrt(np.maximum(observations.observed_spectrum[chosen].astype(np.float64), 0.0))  # (M, 3, l*+1)
    light_power = observations.mirrored_spectrum[chosen].astype(np.float64).sum(axis=-1).mean(axis=-1)  # (M,)
    samples_per_coeff = np.maximum(observations.n_samples[chosen], 1) / (lmax + 1) ** 2
    observed = observed[:, None, None]  # (M, 1, 1, 3, l*+1)
    misfit = (np.square(model_amplitude[..., 1:] - observed[..., 1:]).sum(axis=-1)
              + np.square(np.maximum(model_amplitude[..., 0] - observed[..., 0], 0.0)))  # (M, R, R, 3)
    best = misfit.min(axis=(1, 2), keepdims=True)
    noise = (2.0 * settings.noise_level**2 * light_power / samples_per_coeff)[:, None, None, None]
    if settings.residual_noise:
        noise = noise + 2.0 * best / max(lmax - 2, 1)
    posterior = np.exp(-(misfit - best) / np.maximum(noise, 1e-300))
    posterior[:, :, 0] /= resolution  # the k = 0 column is one material
    posterior /= posterior.sum(axis=(1, 2), keepdims=True)
    masses = np.concatenate([posterior[:, :, 0].sum(axis=1)[:, None], posterior[:, :, 1:].reshape(
        len(chosen), -1, 3)], axis=1)  # (M, R (R-1) + 1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        information = np.where(masses > 0, masses * np.log(masses), 0.0)
    entropy = -information.sum(axis=1) / math.log(resolution * (resolution - 1) + 1)
    return entropy.min(axis=-1)


def cached_radiance(capture, positions, directions, grid, seed: int) -> tuple[np.ndarray, float]:
    """`hypothesis_radiance` and the seconds it took to render, rendered once and kept in
    benchmarks/.cache/ (keyed by the environment map, the rays, grid, SPP and seed)."""
    key = hashlib.sha256(capture.envmap.radiance.tobytes() + capture.envmap.to_world.tobytes()
                         + np.ascontiguousarray(positions).tobytes() + np.ascontiguousarray(directions).tobytes()
                         + f"{grid.resolution} {SPP} {seed}".encode()).hexdigest()[:16]
    path = CACHE / f"pathtraced_entropy_{key}.npz"
    if path.is_file():
        with np.load(path) as cached:
            return cached["radiance"], float(cached["seconds"])
    start = time.perf_counter()
    radiance = hypothesis_radiance(capture, positions, directions, grid, seed)
    seconds = time.perf_counter() - start
    np.savez(path, radiance=radiance, seconds=seconds)
    return radiance, seconds


def agreement(reference: np.ndarray, ours: np.ndarray) -> dict:
    """Spearman rho of two (M,) entropies and its 95 % bootstrap interval over the M texels."""
    rho = float(stats.spearmanr(reference, ours).statistic)
    resamples = np.random.default_rng(0).integers(0, len(reference), (BOOTSTRAP, len(reference)))
    spread = [stats.spearmanr(reference[rows], ours[rows]).statistic for rows in resamples]
    low, high = np.quantile(spread, [0.025, 0.975])
    return {"rho": round(rho, 4), "interval_95": [round(float(low), 4), round(float(high), 4)]}


def region_difference(entropy: np.ndarray, badly_lit: np.ndarray, sharply_lit: np.ndarray) -> dict:
    """Mean entropy of the badly lit texels minus that of the sharply lit ones, with a 95 % bootstrap
    interval (each region resampled on its own)."""
    bad, sharp = entropy[badly_lit], entropy[sharply_lit]
    rng = np.random.default_rng(0)
    spread = (rng.choice(bad, (BOOTSTRAP, len(bad))).mean(axis=1)
              - rng.choice(sharp, (BOOTSTRAP, len(sharp))).mean(axis=1))
    low, high = np.quantile(spread, [0.025, 0.975])
    return {"difference": round(float(bad.mean() - sharp.mean()), 4),
            "interval_95": [round(float(low), 4), round(float(high), 4)]}


def main(sky: str) -> None:
    capture = load(entropy_capture(sky))
    config = Config()
    texels = rasterise(capture.mesh, config.texels.texture_res)
    result = fit(capture, config)  # the default fit: its observations, entropy and roughness error
    observations = result.observations
    assert np.array_equal(observations.texel_index, texels.texel_index)  # estimated on every texel
    error = roughness_error(result, capture)
    entropy_map(observations, config.uncertainty, return_likelihood=False)  # loads the kernel
    start = time.perf_counter()
    ours = entropy_map(observations, config.uncertainty, return_likelihood=False)
    ours_s = time.perf_counter() - start
    paper = entropy_map(observations, UncertaintyConfig(mode="paper"), return_likelihood=False)
    # The angular mode as `fit` computes it (its grid the estimator's 9 roughness nodes, scored during
    # the search), and on its own.
    angular_config = UncertaintyConfig(mode="angular")
    angular_fit = fit(capture, config.replace(uncertainty=angular_config))
    angular = angular_fit.uncertainty
    entropy_map(observations.select(slice(0, 64)), angular_config, return_likelihood=False)  # loads its kernels
    start = time.perf_counter()
    angular_alone = entropy_map(observations, angular_config, return_likelihood=False)
    angular_s = time.perf_counter() - start
    chosen = choose_texels(ours.entropy, observations.n_samples)

    # One ray per (chosen texel, view with a sample), towards that view's camera.
    centres = np.array([frame.camera.center for frame in capture.frames])  # (V, 3)
    texel_of, view_of = np.nonzero(observations.weight[chosen] > 0)
    positions = texels.position[chosen][texel_of].astype(np.float64)
    directions = centres[view_of] - positions
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)

    def brute_forces(grid):
        """The sample brute force's entropies on ``grid`` (seed 0, the other seed, the pooled
        rendering), the renderings themselves and the seconds one seed took."""
        radiances, render_seconds = zip(*(cached_radiance(capture, positions, directions, grid, seed)
                                          for seed in SEEDS))
        radiances = [*radiances, np.mean(radiances, axis=0)]  # and the pooled rendering
        brutes = np.empty((len(radiances), len(chosen)))
        for index, texel in enumerate(chosen):
            rays = texel_of == index
            views = view_of[rays]
            for rendering, radiance in enumerate(radiances):
                brutes[rendering, index] = brute_force_entropy(
                    observations.observed[texel, views].astype(np.float64),
                    observations.mirrored[texel, views].astype(np.float64),
                    observations.weight[texel, views].astype(np.float64), radiance[:, :, rays])
        return brutes, radiances, float(np.mean(render_seconds))

    grid = hypothesis_grid(config.uncertainty.resolution())
    (brute, brute_other_seed, pooled), radiances, render_s = brute_forces(grid)
    # The angular mode's grid (the estimator's roughness nodes) has a brute force of its own.
    angular_grid = angular.grid
    (angular_brute, angular_brute_other_seed, angular_pooled), _, angular_render_s = brute_forces(angular_grid)
    # The spectral brute force: the same scoring as ours, the path-traced spectra for the analytic ones.
    spectral, spectral_other_seed, spectral_pooled = (
        spectral_entropy(observations, chosen, hypothesis_amplitudes(observations, chosen, texel_of, view_of,
                                                                     radiance, config.fit),
                         config.uncertainty) for radiance in radiances)
    # Our fast entropies, recomputed by the direct scoring from their analytic amplitudes: the check.
    scoring_error = {"default": float(np.abs(spectral_entropy(observations, chosen, analytic_amplitudes(
        observations, chosen, grid), config.uncertainty) - ours.entropy[chosen]).max())}
    roughness_std = np.nan_to_num(result.uncertainty.roughness_std[chosen], nan=1.0)
    ranks_error = {name: round(float(stats.spearmanr(values, error[chosen], nan_policy="omit").statistic), 4)
                   for name, values in (("brute_force_pooled", pooled), ("spectral_brute_force_pooled", spectral_pooled),
                                        ("ours_calibrated", ours.entropy[chosen]),
                                        ("ours_angular", angular.entropy[chosen]),
                                        ("ours_paper_mode", paper.entropy[chosen]),
                                        ("roughness_std", roughness_std))}
    # Does each entropy call the scene's badly lit and rarely seen regions uncertain?
    by_region = {}
    chosen_regions = entropy_regions(observations.normal[chosen])
    badly_lit_minus_sharply_lit = {
        name: region_difference(values, chosen_regions["badly_lit"], chosen_regions["sharply_lit"])
        for name, values in (("brute_force_pooled", pooled), ("angular_brute_force_pooled", angular_pooled),
                             ("ours_calibrated", ours.entropy[chosen]), ("ours_angular", angular.entropy[chosen]),
                             ("ours_paper_mode", paper.entropy[chosen]))}
    for region, mask in chosen_regions.items():
        if mask.any():
            by_region[region] = {"texels": int(mask.sum()), "brute_force": round(float(brute[mask].mean()), 4),
                                 "angular_brute_force": round(float(angular_brute[mask].mean()), 4),
                                 "ours_calibrated": round(float(ours.entropy[chosen][mask].mean()), 4),
                                 "ours_angular": round(float(angular.entropy[chosen][mask].mean()), 4),
                                 "ours_paper_mode": round(float(paper.entropy[chosen][mask].mean()), 4),
                                 "spectral_brute_force": round(float(spectral_pooled[mask].mean()), 4)}

    save_results(results_name("pathtraced_entropy", sky), {
        "benchmark": "fast SH entropy vs brute-force path-traced entropy over the same hypothesis grid",
        **machine(),
        "capture": f"benchmarks/studies/entropy_scenes.py --sky {sky}",
        "texels": len(chosen),
        "rays": len(positions),
        "spp": SPP,
        "grid_res": grid.resolution,
        "agreement_with_pooled_brute_force": {
            name: agreement(pooled, entropy.entropy[chosen])
            for name, entropy in (("ours_calibrated", ours), ("ours_paper_mode", paper))},
        "angular_mode": {
            "grid_res": angular_grid.resolution,
            "agreement_with_pooled_brute_force": {
                name: agreement(angular_pooled, entropy.entropy[chosen])
                for name, entropy in (("ours_angular_in_fit", angular), ("ours_calibrated", ours))},
            "agreement_with_each_seed": [agreement(values, angular.entropy[chosen])
                                         for values in (angular_brute, angular_brute_other_seed)],
            "brute_force_self_agreement": agreement(angular_brute, angular_brute_other_seed),
            "in_fit_equals_alone_max_abs_difference": round(float(np.abs(
                angular.entropy - angular_alone.entropy).max()), 8),
        },
        "spearman_rho_vs_ours_calibrated": round(float(stats.spearmanr(brute, ours.entropy[chosen]).statistic), 4),
        "spearman_rho_vs_ours_paper_mode": round(float(stats.spearmanr(brute, paper.entropy[chosen]).statistic), 4),
        "spearman_rho_vs_ours_calibrated_other_seed": round(
            float(stats.spearmanr(brute_other_seed, ours.entropy[chosen]).statistic), 4),
        "brute_force_self_agreement": agreement(brute, brute_other_seed),
        "spectral_brute_force": {
            "agreement_with_ours_calibrated": agreement(spectral_pooled, ours.entropy[chosen]),
            "agreement_with_ours_paper_mode": agreement(spectral_pooled, paper.entropy[chosen]),
            "agreement_with_ours_calibrated_per_seed": [
                agreement(values, ours.entropy[chosen]) for values in (spectral, spectral_other_seed)],
            "self_agreement": agreement(spectral, spectral_other_seed),
            "agreement_with_sample_brute_force": agreement(pooled, spectral_pooled),
            "scoring_check_max_abs_difference": {name: round(value, 6) for name, value in scoring_error.items()},
            "entropy_mean": round(float(spectral_pooled.mean()), 4),
        },
        "spearman_rho_vs_roughness_error_of_default_fit": ranks_error,
        "seeds": list(SEEDS),
        "entropy_mean": {"brute_force": round(float(brute.mean()), 4), "brute_force_pooled": round(float(pooled.mean()), 4),
                         "ours_calibrated": round(float(ours.entropy[chosen].mean()), 4),
                         "ours_angular": round(float(angular.entropy[chosen].mean()), 4)},
        "mean_entropy_by_region": by_region,
        "badly_lit_minus_sharply_lit": badly_lit_minus_sharply_lit,
        "timings_s": {"path_tracing_all_hypotheses_per_seed": round(render_s, 2),
                      "path_tracing_angular_grid_per_seed": round(angular_render_s, 2),
                      "ours_entropy_whole_capture": round(ours_s, 4),
                      "ours_angular_entropy_whole_capture_alone": round(angular_s, 2),
                      "fit_with_angular_entropy": {stage: round(seconds, 2)
                                                   for stage, seconds in angular_fit.timings.items()
                                                   if "." not in stage}},
    })


if __name__ == "__main__":
    main(sky_argument(__doc__.splitlines()[0]))
