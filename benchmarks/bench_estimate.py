"""Time the two material estimators on synthetic observations of bunny-at-512 size.

T = 160k texels (the bunny at 512^2 has ~140k), V = 64 views, l* = 5. The observations are
synthesised by our own forward model in blocks (tests/test_estimate.py's generator), so the
benchmark also reports the recovery errors. Prints the figures and saves them to
benchmarks/results/bench_estimate.json. Kernels are compiled (or loaded from numba's cache) on a
small warm-up first, so the timings are of warm runs.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))  # the synthetic-observation generator lives with the tests

from test_estimate import random_truth, synthetic_observations  # noqa: E402

from freqbrdf import brdf  # noqa: E402
from freqbrdf.config import Config, EstimateConfig  # noqa: E402
from freqbrdf.estimate import estimate  # noqa: E402
from freqbrdf.observations import Observations  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "bench_estimate.json"
N_TEXELS = int(os.environ.get("BENCH_TEXELS", 160_000))
BLOCK = 20_000
SEED = 0


def concatenate(parts: list[Observations]) -> Observations:
    """One Observations of all texels of ``parts`` (blocks generated separately to bound memory)."""
    fields = {}
    for name in Observations.__dataclass_fields__:
        values = [getattr(part, name) for part in parts]
        fields[name] = np.concatenate(values) if isinstance(values[0], np.ndarray) else values[0]
    n_texels = len(fields["texel_index"])
    fields["texel_index"] = np.arange(n_texels, dtype=np.int64)
    fields["texture_res"] = int(np.ceil(np.sqrt(n_texels)))
    return Observations(**fields)


def errors(result, truth) -> dict:
    return {
        "base_color_mae": float(np.mean(np.abs(result.base_color - truth.base_color))),
        "roughness_mae": float(np.mean(np.abs(result.roughness - truth.roughness))),
        "metallic_mae": float(np.mean(np.abs(result.metallic - truth.metallic))),
        "roughness_max_error": float(np.max(np.abs(result.roughness - truth.roughness))),
    }


def main() -> None:
    truth = random_truth(N_TEXELS, SEED)
    start = time.perf_counter()
    parts = []
    for first in range(0, N_TEXELS, BLOCK):
        rows = slice(first, min(first + BLOCK, N_TEXELS))
        block_truth = brdf.PrincipledParams(truth.base_color[rows], truth.roughness[rows], truth.metallic[rows])
        parts.append(synthetic_observations(block_truth, seed=SEED + first))
    observations = concatenate(parts)
    synth_s = time.perf_counter() - start

    runs = {
        "global": Config(),
        "paper_angular": Config(estimate=EstimateConfig(method="paper")),
    }
    warmup = concatenate([synthetic_observations(random_truth(256, 1), seed=1)])
    result = {
        "benchmark": "estimate: per-texel base colour, roughness, metallic",
        "cpu_count": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "texels": N_TEXELS,
        "views": observations.n_views,
        "lmax": observations.lmax,
        "synthesis_seconds": round(synth_s, 2),
        "estimators": {},
    }
    for name, config in runs.items():
        estimate(warmup, config)
        start = time.perf_counter()
        estimated = estimate(observations, config)
        seconds = time.perf_counter() - start
        result["estimators"][name] = {
            "seconds": round(seconds, 3),
            "stages": {stage: round(value, 3) for stage, value in estimated.timings.items()},
            "settings": {k: v for k, v in config.estimate.__dict__.items()},
            **errors(estimated, truth),
        }
        print(f"{name:>14}: {seconds:7.2f} s  {result['estimators'][name]}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    print(f"saved {RESULTS}")


if __name__ == "__main__":
    main()
