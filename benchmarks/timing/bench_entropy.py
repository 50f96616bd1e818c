"""Time the entropy map (freqbrdf.uncertainty) on T = 512 (262,144 texels), l* = 5, RGB.

    python benchmarks/timing/bench_entropy.py

Inputs are synthetic spectra of the model itself: a natural-looking light spectrum
S_refl(l) ~ (1 + l)^-2 with per-texel log-normal jitter, random materials (roughness and k_s
uniform in [0, 1], per-channel k_s) seen at a view cosine uniform in [0.2, 1], GGX lobes (their
per-degree gains and albedo), a diffuse DC term, and amplitude noise of 1 % of the light's RMS
amplitude, one coefficient per degree; 64 samples per texel. Calibrated mode runs as
`entropy_map` calls it by default. Each mode at R = 8 and R = 32, with and without returning the
(N, R, R) likelihood. Then the angular mode from its hypotheses' moments (`entropy_from_moments`, 9 x 9, synthetic moments of
64 samples per texel: `synthetic_moments`), with and without the likelihood.

Prints the figures and saves them to benchmarks/results/bench_entropy.json. The first call loads
(or compiles) the numba kernel and is reported separately; the warm figure is the median of
REPEATS runs, with all numba threads and with one (the machine is shared: with other work on it,
two threads may run no faster than one). Peak memory is the largest Python-visible allocation
(tracemalloc) of one warm run. The load average at the start is recorded with the figures, and so
is a yardstick of the machine's speed at the time, numpy's exp per element.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numba
import numpy as np

from freqbrdf.config import UncertaintyConfig
from freqbrdf.model.tables import ggx_lobe_gains, split_sum_terms
from freqbrdf.uncertainty import entropy_from_moments, entropy_from_spectra

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import first_call_seconds, machine, median_seconds, peak_mib, save_results

TEXTURE_RES = 512
LMAX = 5
REPEATS = 5
NOISE = 0.01
ANGULAR_GRID = 9  # the angular mode's default grid: the estimator's roughness nodes
ANGULAR_VIEWS = 64


def synthetic_spectra(n_texels: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    """light, observed power spectra (N, 3, l*+1) float32 (the model plus noise)."""
    rng = np.random.default_rng(seed)
    degrees = np.arange(LMAX + 1)
    light = (1.0 + degrees) ** -2.0 * rng.lognormal(0.0, 0.3, (n_texels, 3, LMAX + 1))
    roughness = rng.uniform(0.0, 1.0, n_texels)
    view_cos = rng.uniform(0.2, 1.0, n_texels)
    specular = rng.uniform(0.0, 1.0, (n_texels, 3))
    nodes = np.linspace(0.0, 1.0, 65)  # the GGX gains, linear between roughness nodes
    gains = np.stack([ggx_lobe_gains(float(node), LMAX) for node in nodes])  # (65, l*+1)
    kernel = np.stack([np.interp(roughness, nodes, gains[:, degree]) for degree in degrees], axis=1)  # (N, l*+1)
    kernel *= split_sum_terms(view_cos, roughness)[0][:, None]  # the lobe's albedo
    amplitude = specular[..., None] * kernel[:, None, :] * np.sqrt(light)
    rms = np.sqrt(light.sum(axis=2, keepdims=True))
    amplitude += NOISE * rms * rng.standard_normal(amplitude.shape)
    amplitude[..., 0] = kernel[:, None, 0] * specular * np.sqrt(light[..., 0]) + rng.uniform(0.0, 0.5, (n_texels, 3))
    return light.astype(np.float32), np.square(amplitude).astype(np.float32)


def synthetic_moments(n_texels: int, resolution: int, seed: int = 1) -> tuple[np.ndarray, ...]:
    """The angular mode's inputs: moments (N, R, 3, 8) of its R x R hypotheses, weights (N, V) and
    mirrored radiance (N, V, 3). Per texel, V = ANGULAR_VIEWS samples at view cosines uniform in
    [0.2, 1] under a light of log-normal radiance; a metal (alpha_i, k) reflects k X + Y with (X, Y)
    the split-sum albedo terms (A, B) at the sample's cosine and roughness sqrt(alpha_i) times the
    light; the observed radiance is a random hypothesis's (per channel k) plus a diffuse part plus
    1 % noise. Made in blocks of texels (the (block, R, V) terms)."""
    rng = np.random.default_rng(seed)
    views = ANGULAR_VIEWS
    roughness = np.arange(resolution) / (resolution - 1)
    moments = np.empty((n_texels, resolution, 3, 8))
    weight = rng.uniform(0.2, 1.0, (n_texels, views)).astype(np.float32)
    mirrored = rng.lognormal(0.0, 0.5, (n_texels, views, 3)).astype(np.float32)
    for start in range(0, n_texels, 8192):
        rows = slice(start, min(start + 8192, n_texels))
        count = rows.stop - rows.start
        view_cos = rng.uniform(0.2, 1.0, (count, 1, views))
        scale, bias, _ = split_sum_terms(view_cos, roughness[None, :, None])  # (n, R, V)
        light = mirrored[rows].astype(np.float64)  # (n, V, 3)
        scale_terms = scale[..., None] * light[:, None]  # (n, R, V, 3)
        bias_terms = bias[..., None] * light[:, None]
        truth = rng.integers(0, resolution, count)
        specular = rng.uniform(0.0, 1.0, (count, 3))
        picked = np.arange(count)
        observed = (specular[:, None, :] * scale_terms[picked, truth] + bias_terms[picked, truth]
                    + rng.uniform(0.0, 0.5, (count, 1, 3)))
        observed *= 1.0 + NOISE * rng.standard_normal(observed.shape)
        w = weight[rows].astype(np.float64)[:, None, :, None]  # (n, 1, V, 1)
        f = observed[:, None]  # (n, 1, V, 3)
        u = f - bias_terms
        for index, value in enumerate((np.ones_like(u), u, scale_terms, u * u, u * scale_terms,
                                       scale_terms * scale_terms, np.broadcast_to(f, u.shape),
                                       np.broadcast_to(f * f, u.shape))):
            moments[rows, :, :, index] = (w * value).sum(axis=2)
    return moments, weight, mirrored


def numpy_exp_ns() -> float:
    """Median nanoseconds per element of np.exp on 2^22 doubles: the machine's speed right now."""
    values = -np.linspace(0.0, 30.0, 1 << 22)
    return median_seconds(lambda: np.exp(values), REPEATS) / values.size * 1e9


def timed(run, entry: dict) -> dict:
    """``entry`` with the first call's seconds (numba loads or compiles), the warm median with all
    numba threads and with one, the peak memory of a warm call and the entropy's mean; printed."""
    threads = numba.get_num_threads()
    first_call, result = first_call_seconds(run)
    warm = median_seconds(run, REPEATS)
    numba.set_num_threads(1)
    try:
        one_thread = median_seconds(run, REPEATS)
    finally:
        numba.set_num_threads(threads)
    entry = {**entry, "first_call_s": round(first_call, 4), "warm_median_s": round(warm, 4),
             "one_thread_median_s": round(one_thread, 4), "peak_mib": round(peak_mib(run), 1),
             "entropy_mean": round(float(result.entropy.mean()), 4)}
    print(entry)
    return entry


def main() -> None:
    n_texels = TEXTURE_RES * TEXTURE_RES
    light, observed = synthetic_spectra(n_texels)
    n_samples = np.full(n_texels, 64, np.int32)
    facts = machine()
    exp_ns_at_start = numpy_exp_ns()
    threads = numba.get_num_threads()
    runs = []
    for mode in ("calibrated", "paper"):
        for grid_res in (8, 32):
            config = UncertaintyConfig(mode=mode, grid_res=grid_res)
            for with_likelihood in (False, True):

                def run():
                    return entropy_from_spectra(light, observed, n_samples=n_samples, config=config,
                                                return_likelihood=with_likelihood)

                runs.append(timed(run, {"mode": mode, "grid_res": grid_res, "likelihood": with_likelihood}))

    # The angular mode, scored from its hypotheses' moments (inside `fit`, the estimator's search
    # collects them while it searches; on its own they take seconds, see UncertaintyConfig.mode).
    moments, weight, mirrored = synthetic_moments(n_texels, ANGULAR_GRID)
    n_views = np.full(n_texels, ANGULAR_VIEWS, np.int32)
    for with_likelihood in (False, True):

        def run_angular():
            return entropy_from_moments(moments, weight, mirrored, n_views, return_likelihood=with_likelihood)

        runs.append(timed(run_angular, {"mode": "angular (from moments)", "grid_res": ANGULAR_GRID,
                                        "likelihood": with_likelihood}))

    save_results("bench_entropy", {
        "benchmark": "uncertainty: entropy map from SH power spectra (and the angular mode's from moments)",
        **facts,
        "numba_threads": threads,
        "numpy_exp_ns_per_element": {"start": round(exp_ns_at_start, 2), "end": round(numpy_exp_ns(), 2)},
        "texels": n_texels,
        "lmax": LMAX,
        "channels": 3,
        "runs": runs,
    })


if __name__ == "__main__":
    main()
