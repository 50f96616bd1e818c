"""Time the per-texel SH fit (freqbrdf.sphere.harmonics.fit_sh) at full texture size.

    python benchmarks/timing/bench_sh.py

T = 512^2 texels, V = 64 views, l* = 5 (K = 36), 7 right-hand sides (3 observed + 3 mirrored
environment + 1 constant), float32 inputs as the pipeline produces them. Two sample sets:

- ``sphere_cameras``: 64 cameras spread evenly over the sphere (Fibonacci), random texel normals,
  w = max(0, cos theta_o) and a 20 % chance that a view is occluded: fewer samples per texel than
  K, as on a closed object (the bunny);
- ``hemisphere_cameras``: 64 cameras over the upper hemisphere of a plane whose normals tilt by at
  most 10 degrees, 5 % occluded: more samples per texel than K, like the Mitsuba-rendered plane
  capture. The fit's cost grows with the samples per texel, so this is the slower case.

It also reports sum_i w_i^2 over the first sample set: with scale_lambda_with_weight the effective
lambda is reg_lambda * sum_i w_i^2, so the paper's absolute lambda = 1e-3 corresponds to
reg_lambda = 1e-3 / sum_i w_i^2 at this coverage.

Timings are wall seconds and, less sensitive to other load on a shared machine, CPU seconds of
all threads (time.process_time). Peak memory is the process's maximum resident set size
(resource.getrusage ru_maxrss), which includes the inputs, the Python/numba runtime and everything
else; the inputs alone are listed.
Prints and saves JSON to benchmarks/results/bench_sh.json.
"""

from __future__ import annotations

import resource
import sys
import time
from pathlib import Path

import numba
import numpy as np

from freqbrdf.sphere import harmonics as sh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import machine, save_results

N_TEXELS = 512 * 512
N_VIEWS = 64
LMAX = 5
N_RHS = 7
REPEATS = 3
MAX_TILT_DEG = 10.0  # hemisphere_cameras: largest angle between a texel normal and +z


def max_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kilobytes


def fibonacci_sphere(n: int, hemisphere: bool = False) -> np.ndarray:
    """n near-uniform unit directions over the sphere, or over its z > 0 half."""
    index = np.arange(n) + 0.5
    z = 1.0 - index / n if hemisphere else 1.0 - 2.0 * index / n
    phi = np.pi * (1.0 + 5.0**0.5) * index
    radius = np.sqrt(1.0 - z * z)
    return np.stack([radius * np.cos(phi), radius * np.sin(phi), z], axis=-1)


def capture_samples(rng: np.random.Generator, hemisphere: bool = False, n_texels: int = N_TEXELS):
    """Local view directions (T, V, 3), weights (T, V) and values (T, V, C), all float32."""
    cameras = fibonacci_sphere(N_VIEWS, hemisphere)  # (V, 3) world directions towards the cameras
    if hemisphere:
        tilt = np.deg2rad(MAX_TILT_DEG) * np.sqrt(rng.random(n_texels))
        azimuth = 2.0 * np.pi * rng.random(n_texels)
        normals = np.stack([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)], -1)
    else:
        normals = rng.normal(size=(n_texels, 3))
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    tangents = np.cross(helper, normals)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    bitangents = np.cross(normals, tangents)
    frames = np.stack([tangents, bitangents, normals], axis=1).astype(np.float32)  # (T, 3, 3) rows s, t, n
    directions = np.ascontiguousarray(np.swapaxes(frames @ cameras.T.astype(np.float32), 1, 2))  # (T, V, 3)
    visible = rng.random((n_texels, N_VIEWS)) > (0.05 if hemisphere else 0.2)
    weights = (np.maximum(directions[..., 2], 0.0) * visible).astype(np.float32)
    values = rng.random((n_texels, N_VIEWS, N_RHS), dtype=np.float32)
    return directions, weights, values


def run_scenario(hemisphere: bool) -> tuple[dict, np.ndarray]:
    """Timings and fit statistics of one sample set; also returns its sum_i w_i^2 per texel."""
    start = time.perf_counter()
    directions, weights, values = capture_samples(np.random.default_rng(0), hemisphere)
    generate_s = time.perf_counter() - start

    fit_s, fit_cpu_s = [], []
    for _ in range(REPEATS):
        start, start_cpu = time.perf_counter(), time.process_time()
        fit = sh.fit_sh(directions, weights, values, LMAX, 1e-3, "exponential", True)
        fit_s.append(time.perf_counter() - start)
        fit_cpu_s.append(time.process_time() - start_cpu)
    assert np.isfinite(fit.coeffs).all()

    # The SH-evaluation share of the fit: the basis at every sample direction, in chunks so the
    # (T V, K) result never exists at once.
    chunk = 1 << 21
    flat = directions.reshape(-1, 3)
    start = time.perf_counter()
    for first in range(0, flat.shape[0], chunk):
        sh.eval_sh(flat[first : first + chunk], LMAX)
    eval_s = time.perf_counter() - start

    result = {
        "timings_s": {
            "generate_inputs": round(generate_s, 3),
            "fit_sh_runs": [round(t, 3) for t in fit_s],
            "fit_sh_best": round(min(fit_s), 3),
            "fit_sh_cpu_runs": [round(t, 3) for t in fit_cpu_s],  # all threads; less load-dependent
            "eval_sh_all_samples_reference": round(eval_s, 3),
        },
        "mean_samples_per_texel": round(float(fit.n_samples.mean()), 2),
        "status_counts": {
            "ok": int(np.sum(fit.status == sh.FIT_OK)),
            "underdetermined": int(np.sum(fit.status == sh.FIT_UNDERDETERMINED)),
            "empty": int(np.sum(fit.status == sh.FIT_EMPTY)),
        },
        "inputs_mb": round((directions.nbytes + weights.nbytes + values.nbytes) / 2**20, 1),
        "output_coeffs_mb": round(fit.coeffs.nbytes / 2**20, 1),
    }
    return result, np.sum(np.square(weights, dtype=np.float64), axis=1)


def main() -> dict:
    small = capture_samples(np.random.default_rng(0), n_texels=64)
    start = time.perf_counter()
    sh.fit_sh(*small, LMAX, 1e-3)  # JIT compile / cache load
    warmup_s = time.perf_counter() - start

    sphere, weight_sq_sum = run_scenario(hemisphere=False)
    hemisphere, _ = run_scenario(hemisphere=True)
    quartiles = np.percentile(weight_sq_sum, [25, 50, 75])
    result = {
        "benchmark": "fit_sh",
        **machine(),
        "numba_threads": numba.get_num_threads(),
        "numpy": np.__version__,
        "texels": N_TEXELS,
        "views": N_VIEWS,
        "lmax": LMAX,
        "coefficients": sh.num_coeffs(LMAX),
        "right_hand_sides": N_RHS,
        "input_dtype": "float32",
        "warmup_compile_or_cache_load_s": round(warmup_s, 3),
        "scenarios": {"sphere_cameras": sphere, "hemisphere_cameras": hemisphere},
        "memory": {
            "method": "resource.getrusage(RUSAGE_SELF).ru_maxrss (peak resident set of the process)",
            "peak_rss_mb": round(max_rss_mb(), 1),
        },
        "lambda_equivalence": {
            "sum_w2_quartiles": [round(float(q), 2) for q in quartiles],
            "reg_lambda_scaled_equivalent_to_absolute_1e-3": round(1e-3 / float(quartiles[1]), 7),
        },
    }
    save_results("bench_sh", result)
    return result


if __name__ == "__main__":
    main()
