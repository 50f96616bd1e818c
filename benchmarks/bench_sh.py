"""Benchmark of the per-texel SH fit (freqbrdf.sh.fit_sh) at full texture size.

T = 512^2 texels, V = 64 views, l* = 5 (K = 36), 7 right-hand sides (3 observed + 3 mirrored
environment + 1 constant), float32 inputs as the pipeline produces them. The sample set is a
realistic capture: 64 cameras spread evenly over the sphere (Fibonacci), random texel normals,
w = max(0, cos theta_o) and a 20 % chance that a view is occluded.

It also reports sum_i w_i^2 over this sample set: with scale_lambda_with_weight the effective
lambda is reg_lambda * sum_i w_i^2, so the paper's absolute lambda = 1e-3 corresponds to
reg_lambda = 1e-3 / sum_i w_i^2 at this coverage.

Peak memory is the process's maximum resident set size (resource.getrusage ru_maxrss), which
includes the inputs, the Python/numba runtime and everything else; the inputs alone are listed.
Prints and saves JSON to benchmarks/results/bench_sh.json.
"""

from __future__ import annotations

import json
import os
import platform
import resource
import sys
import time
from pathlib import Path

import numpy as np

from freqbrdf import sh
from freqbrdf.fileio import atomic_path

N_TEXELS = 512 * 512
N_VIEWS = 64
LMAX = 5
N_RHS = 7
REPEATS = 3


def max_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kilobytes


def fibonacci_sphere(n: int) -> np.ndarray:
    index = np.arange(n) + 0.5
    z = 1.0 - 2.0 * index / n
    phi = np.pi * (1.0 + 5.0**0.5) * index
    radius = np.sqrt(1.0 - z * z)
    return np.stack([radius * np.cos(phi), radius * np.sin(phi), z], axis=-1)


def capture_samples(rng: np.random.Generator):
    """Local view directions (T, V, 3), weights (T, V) and values (T, V, C), all float32."""
    cameras = fibonacci_sphere(N_VIEWS)  # (V, 3) world directions towards the cameras
    normals = rng.normal(size=(N_TEXELS, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    tangents = np.cross(helper, normals)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    bitangents = np.cross(normals, tangents)
    frames = np.stack([tangents, bitangents, normals], axis=1).astype(np.float32)  # (T, 3, 3) rows s, t, n
    directions = np.ascontiguousarray(np.swapaxes(frames @ cameras.T.astype(np.float32), 1, 2))  # (T, V, 3)
    visible = rng.random((N_TEXELS, N_VIEWS)) > 0.2
    weights = (np.maximum(directions[..., 2], 0.0) * visible).astype(np.float32)
    values = rng.random((N_TEXELS, N_VIEWS, N_RHS), dtype=np.float32)
    return directions, weights, values


def main() -> dict:
    rng = np.random.default_rng(0)
    start = time.perf_counter()
    directions, weights, values = capture_samples(rng)
    generate_s = time.perf_counter() - start
    input_mb = (directions.nbytes + weights.nbytes + values.nbytes) / 2**20

    start = time.perf_counter()
    sh.fit_sh(directions[:64], weights[:64], values[:64], LMAX, 1e-3)  # JIT compile / cache load
    warmup_s = time.perf_counter() - start

    fit_s = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        fit = sh.fit_sh(directions, weights, values, LMAX, 1e-3, "exponential", True)
        fit_s.append(time.perf_counter() - start)
        del fit
    fit = sh.fit_sh(directions, weights, values, LMAX, 1e-3, "exponential", True)
    assert np.isfinite(fit.coeffs).all()

    # The SH-evaluation share of the fit: the basis at every sample direction, in chunks so the
    # (T V, K) result never exists at once.
    chunk = 1 << 21
    flat = directions.reshape(-1, 3)
    start = time.perf_counter()
    for first in range(0, flat.shape[0], chunk):
        sh.eval_sh(flat[first : first + chunk], LMAX)
    eval_s = time.perf_counter() - start

    weight_sq_sum = np.sum(np.square(weights, dtype=np.float64), axis=1)  # (T,)
    quartiles = np.percentile(weight_sq_sum, [25, 50, 75])
    result = {
        "benchmark": "fit_sh",
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "texels": N_TEXELS,
        "views": N_VIEWS,
        "lmax": LMAX,
        "coefficients": sh.num_coeffs(LMAX),
        "right_hand_sides": N_RHS,
        "input_dtype": "float32",
        "timings_s": {
            "generate_inputs": round(generate_s, 3),
            "warmup_compile_or_cache_load": round(warmup_s, 3),
            "fit_sh_runs": [round(t, 3) for t in fit_s],
            "fit_sh_best": round(min(fit_s), 3),
            "eval_sh_all_samples_reference": round(eval_s, 3),
        },
        "mean_samples_per_texel": round(float(fit.n_samples.mean()), 2),
        "status_counts": {
            "ok": int(np.sum(fit.status == sh.FIT_OK)),
            "underdetermined": int(np.sum(fit.status == sh.FIT_UNDERDETERMINED)),
            "empty": int(np.sum(fit.status == sh.FIT_EMPTY)),
        },
        "memory": {
            "method": "resource.getrusage(RUSAGE_SELF).ru_maxrss (peak resident set of the process)",
            "peak_rss_mb": round(max_rss_mb(), 1),
            "inputs_mb": round(input_mb, 1),
            "output_coeffs_mb": round(fit.coeffs.nbytes / 2**20, 1),
        },
        "lambda_equivalence": {
            "sum_w2_quartiles": [round(float(q), 2) for q in quartiles],
            "reg_lambda_scaled_equivalent_to_absolute_1e-3": round(1e-3 / float(quartiles[1]), 7),
        },
    }
    print(json.dumps(result, indent=2))
    out = Path(__file__).resolve().parent / "results" / "bench_sh.json"
    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
