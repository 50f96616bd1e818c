"""What one probe of the global search costs, per texel and per sample (issue #5).

    python benchmarks/timing/bench_probe.py [--texture-res 256] [--repeats 3]

The search evaluates the profiled loss at a few tens of roughness values per texel
(docs/results.md#speed). This times the search kernel on
studies/compare_estimators.py's plane (scenes.compare_capture: 64 views; rendered into
benchmarks/.cache if missing) in its hypothesis mode, with no search: once with no hypothesis
(the per-texel preparation), once with one (the first probe at a roughness, which also fills the
light of the roughness nodes around it for every sample), and once with eleven at the same
roughness (ten more probes at nodes already filled). It does so at three roughness values (a
smooth lobe on the prefiltered map alone, the blend of the map and the environment light, a rough
lobe on the environment light alone), and with the views cut to the first 64, 32 and 16, so that
a straight line through the three sample counts splits a probe's cost into a part per texel and a
part per sample. Hypothesis mode adds the texel's specular moments per probe (a small cost per
sample), so these figures bound the search's own probes from above. Times are the median of
``--repeats`` runs, in seconds of one core (wall x numba's threads). Prints the figures and saves
benchmarks/results/bench_probe.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numba
import numpy as np

from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.estimate import search
from freqbrdf.observe.observations import observe

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import control_seconds, machine, median_seconds, save_results
from scenes import compare_capture

ROUGHNESS = (0.2, 0.45, 0.8)  # prefiltered map only; map and environment light; environment light only
VIEWS = (64, 32, 16)
PROBES = 10  # cached probes timed on top of the first


def kernel_seconds(observations, settings, roughness: list[float], repeats: int) -> float:
    """Median wall seconds of the search kernel with these hypotheses and no search."""
    n = observations.n_texels
    hypotheses = np.asarray(roughness, np.float64)
    moments = np.zeros((n, len(hypotheses), 3, 8))
    params, loss, curvature = np.zeros((n, 5)), np.zeros(n), np.zeros(n)
    return median_seconds(lambda: search.run_search_kernel(
        observations, settings, observations.mirrored_coeffs, hypotheses, moments, False, params, loss, curvature),
        repeats)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--texture-res", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    folder = compare_capture("plane")
    config = Config(texels=TexelConfig(texture_res=args.texture_res))
    full = observe(load(folder), config)
    settings = config.estimate
    threads = numba.get_num_threads()
    kernel_seconds(full.select(slice(0, 300)), settings, [0.5], 1)  # load (or compile) the kernel
    control_before = control_seconds()
    runs = []
    for views in VIEWS:
        weight = full.weight.copy()
        weight[:, views:] = 0.0
        observations = dataclasses.replace(full, weight=weight)
        texels = observations.n_texels
        samples = int(np.count_nonzero(weight > 0.0))
        preparation = kernel_seconds(observations, settings, [], args.repeats)
        run = {"views": views, "samples_per_texel": round(samples / texels, 2),
               "preparation_us_per_texel": round(preparation * threads / texels * 1e6, 3), "roughness": {}}
        for roughness in ROUGHNESS:
            first = kernel_seconds(observations, settings, [roughness], args.repeats)
            many = kernel_seconds(observations, settings, [roughness] * (PROBES + 1), args.repeats)
            cached = (many - first) / PROBES * threads / texels
            run["roughness"][str(roughness)] = {
                "first_probe_us_per_texel": round((first - preparation) * threads / texels * 1e6, 3),
                "cached_probe_us_per_texel": round(cached * 1e6, 3),
                "cached_probe_ns_per_sample": round(cached / (samples / texels) * 1e9, 2),
            }
        runs.append(run)
        print(run, flush=True)
    fits = {}
    sample_counts = np.array([run["samples_per_texel"] for run in runs])
    for roughness in ROUGHNESS:
        costs = np.array([run["roughness"][str(roughness)]["cached_probe_us_per_texel"] for run in runs])
        slope, intercept = np.polyfit(sample_counts, costs, 1)
        fits[str(roughness)] = {"per_texel_us": round(float(intercept), 3),
                                "per_sample_ns": round(float(slope) * 1e3, 2)}
    save_results("bench_probe", {
        "benchmark": "cost of one probe of the global search: per texel and per sample",
        **machine(),
        "numba_threads": threads,
        "capture": str(folder),
        "texture_res": args.texture_res,
        "texels": full.n_texels,
        "control_s": {"before": round(control_before, 4), "after": round(control_seconds(), 4)},
        "runs": runs,
        "cached_probe_fit": fits,
    })
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
