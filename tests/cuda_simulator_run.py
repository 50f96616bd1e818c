"""Run the CUDA kernels under numba's CUDA simulator beside the CPU kernels; print what differs as JSON.

Run by tests/test_devices.py in a fresh process with NUMBA_ENABLE_CUDASIM=1 (it must be set before
numba.cuda is imported). Tiny inputs: the simulator runs one Python thread per CUDA thread.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from freqbrdf.config import Config, EstimateConfig, UncertaintyConfig  # noqa: E402
from freqbrdf.devices import cuda_status  # noqa: E402
from freqbrdf.estimate import estimate as estimate_materials  # noqa: E402
from freqbrdf.sphere import envmap as envmaps  # noqa: E402
from freqbrdf.sphere import harmonics as sh  # noqa: E402
from freqbrdf.uncertainty import entropy_map  # noqa: E402
from helpers import observations_from_samples  # noqa: E402


def difference(cpu: np.ndarray, cuda: np.ndarray) -> float:
    """Largest absolute difference; inf where shapes or NaN positions differ."""
    cpu, cuda = np.asarray(cpu, np.float64), np.asarray(cuda, np.float64)
    if cpu.shape != cuda.shape or not np.array_equal(np.isnan(cpu), np.isnan(cuda)):
        return float("inf")
    both = ~np.isnan(cpu)
    return float(np.max(np.abs(cpu[both] - cuda[both]), initial=0.0))


def observations(n_texels: int, n_views: int, lmax: int, seed: int):
    """Small synthetic observations with an environment (the split-sum, environment and prefiltered lights)."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n_texels, n_views, 3))
    directions[..., 2] = np.abs(directions[..., 2]) + 0.2
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    weight = (directions[..., 2] * (rng.random((n_texels, n_views)) > 0.2)).astype(np.float32)
    weight[0] = 0.0  # no sample
    weight[1, 1:] = 0.0  # one sample
    mirrored = (0.5 + rng.random((n_texels, n_views, 3))).astype(np.float32)
    observed = (0.3 * mirrored * directions[..., 2:3] ** 2 + 0.1 * rng.random((n_texels, n_views, 3)))
    radiance = (0.5 + rng.random((16, 32, 3))).astype(np.float32)
    environment = envmaps.Envmap(radiance, np.eye(4))
    return observations_from_samples(
        directions.astype(np.float32), weight, observed.astype(np.float32), mirrored, lmax,
        tangent=np.tile(np.array([1.0, 0.0, 0.0], np.float32), (n_texels, 1)),
        environment_coeffs=envmaps.envmap_sh(environment, lmax).astype(np.float32),
        environment_radiance=radiance, environment_rotation=np.eye(3))


def main() -> None:
    report = {"simulator": cuda_status().simulator}
    rng = np.random.default_rng(0)
    # The SH least squares, with empty, single-sample and rank-deficient texels (the SVD fallback).
    directions = rng.normal(size=(48, 20, 3)).astype(np.float32)
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    weights = np.clip(rng.normal(size=(48, 20)), 0.0, None).astype(np.float32)
    weights[:3] = 0.0
    weights[3:6, 2:] = 0.0
    values = rng.normal(size=(48, 20, 7)).astype(np.float32)
    for regulariser in ("exponential", "none"):
        cpu = sh.fit_sh(directions, weights, values, 3, 1e-3, regulariser, device="cpu")
        cuda = sh.fit_sh(directions, weights, values, 3, 1e-3, regulariser, device="cuda")
        report[f"fit_sh.{regulariser}"] = {
            "coeffs": difference(cpu.coeffs, cuda.coeffs), "n_samples": difference(cpu.n_samples, cuda.n_samples),
            "status": difference(cpu.status, cuda.status)}
    observed = observations(40, 12, 4, 3)
    configs = {"default": Config(device="cpu"),
               "g1_lambert": Config(device="cpu", estimate=EstimateConfig(specular_model="g1", diffuse_model="lambert")),
               "robust_off": Config(device="cpu", estimate=EstimateConfig(robust_passes=0, neighbour_vote=False))}
    for name, config in configs.items():
        cpu = estimate_materials(observed, config)
        cuda = estimate_materials(observed, config.replace(device="cuda"))
        report[f"search.{name}"] = {field: difference(getattr(cpu, field), getattr(cuda, field))
                                    for field in ("base_color", "roughness", "metallic", "loss",
                                                  "roughness_curvature")}
    for mode in ("calibrated", "paper", "angular"):
        cpu = entropy_map(observed, UncertaintyConfig(mode=mode), device="cpu")
        cuda = entropy_map(observed, UncertaintyConfig(mode=mode), device="cuda")
        report[f"entropy.{mode}"] = {field: difference(getattr(cpu, field), getattr(cuda, field))
                                     for field in ("entropy", "likelihood", "best_alpha", "best_ks", "channel")}
    print(json.dumps(report))


if __name__ == "__main__":
    main()
