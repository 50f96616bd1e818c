"""Time the three hot stages and the whole fit on the CPU and on a CUDA device, in one run (issue #32).

    python benchmarks/timing/bench_gpu.py [--capture plane|bunny|PATH] [--texture-res 512] [--repeats 3]
        [--name bench_gpu]

The capture is loaded once (studies/compare_estimators.py's plane by default: 64 views of
256 x 256, rendered into benchmarks/.cache/ if missing). Per backend (``Config.device`` "cpu",
then "cuda" where `freqbrdf.devices.cuda_status` finds a device and numba-cuda):

- ``fit``: observe + estimate (global search) + uncertainty (calibrated entropy) on the
  estimation texels of the default preset at T, the data already loaded; the seconds of each;
- the stages inside it: the SH least squares (``observe.fits``), the search (``estimate.search``)
  and the entropy (``uncertainty``);
- ``entropy_8x8``: the spectral entropy alone on T x T synthetic texels at 8 x 8 hypotheses
  (`entropy_from_spectra`, no likelihood returned), the issue's figure.

The first fit per backend loads or compiles the kernels and is reported apart (``first_fit_s``);
the figures are medians of ``--repeats`` warm runs. Where both backends ran, the largest
differences between their maps are recorded too. Without CUDA the run says so and times the CPU
only. Prints and saves benchmarks/results/<name>.json.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, TexelConfig, UncertaintyConfig
from freqbrdf.devices import cuda_status, describe_device
from freqbrdf.estimate import estimate as estimate_materials
from freqbrdf.pipeline import observe_on_estimation_texels
from freqbrdf.uncertainty import entropy_from_spectra, entropy_map

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import control_seconds, machine, save_results
from scenes import COMPARE_SCENES, compare_capture


def one_fit(capture, config: Config) -> tuple[dict, dict]:
    """Observe, estimate and score the uncertainty once; return the seconds and the maps."""
    start = time.perf_counter()
    observations, _ = observe_on_estimation_texels(capture, config)
    observe_s = time.perf_counter() - start
    tick = time.perf_counter()
    estimate = estimate_materials(observations, config)
    estimate_s = time.perf_counter() - tick
    tick = time.perf_counter()
    uncertainty = entropy_map(observations, config.uncertainty, return_likelihood=False,
                              estimate_config=config.estimate, device=config.device)
    uncertainty_s = time.perf_counter() - tick
    seconds = {
        "total": time.perf_counter() - start, "observe": observe_s, "estimate": estimate_s,
        "uncertainty": uncertainty_s, "sh_fit": observations.timings["fits"],
        "search": estimate.timings.get("search", float("nan")),
    }
    maps = {"observed_coeffs": observations.observed_coeffs, "base_color": estimate.base_color,
            "roughness": estimate.roughness, "metallic": estimate.metallic, "entropy": uncertainty.entropy}
    return seconds, maps


def synthetic_spectra(n_texels: int, lmax: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Light and observed power spectra (N, 3, l* + 1) of a falling light spectrum and random lobes."""
    rng = np.random.default_rng(0)
    degrees = np.arange(lmax + 1)
    light = (1.0 + degrees) ** -2.0 * np.exp(0.3 * rng.standard_normal((n_texels, 3, 1)))
    gain = np.exp(-rng.uniform(0.0, 1.0, (n_texels, 1, 1)) * degrees**2) * rng.uniform(0.0, 1.0, (n_texels, 3, 1))
    observed = light * gain**2 + 1e-4 * rng.random((n_texels, 3, lmax + 1))
    return light.astype(np.float32), observed.astype(np.float32), np.full(n_texels, 64)


def median(values: list[float]) -> float:
    return statistics.median(values)


def time_backend(capture, config: Config, spectra: tuple, repeats: int) -> tuple[dict, dict]:
    """The figures of one backend, and the maps of its last fit."""
    first_s, maps = one_fit(capture, config)
    fits = [one_fit(capture, config) for _ in range(repeats)]
    maps = fits[-1][1]
    light, observed, n_samples = spectra
    grid = UncertaintyConfig(grid_res=8)

    def entropy_8x8() -> float:
        start = time.perf_counter()
        entropy_from_spectra(light, observed, n_samples=n_samples, config=grid, return_likelihood=False,
                             device=config.device)
        return time.perf_counter() - start

    entropy_8x8()  # loads or compiles the kernel
    figures = {
        "backend": describe_device(config.device),
        "first_fit_s": first_s,
        "fit_s": {stage: median([seconds[stage] for seconds, _ in fits]) for stage in fits[0][0]},
        "entropy_8x8_ms": 1000.0 * median([entropy_8x8() for _ in range(max(repeats, 5))]),
    }
    return figures, maps


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--capture", default="plane", help="plane, bunny (compare_estimators.py's) or a path")
    parser.add_argument("--texture-res", type=int, default=512, help="T")
    parser.add_argument("--repeats", type=int, default=3, help="warm runs per backend (median)")
    parser.add_argument("--name", default="bench_gpu", help="results file name")
    args = parser.parse_args(argv)

    folder = compare_capture(args.capture) if args.capture in COMPARE_SCENES else Path(args.capture)
    capture = load(folder)
    status = cuda_status()
    backends = ["cpu"]
    if status.available and status.extra_installed and not status.simulator:
        backends.append("cuda")
    else:
        print(f"no CUDA backend here ({status.name}; numba-cuda installed: {status.extra_installed}): "
              "timing the CPU only", flush=True)
    spectra = synthetic_spectra(args.texture_res**2)
    result = {
        "machine": machine(), "control_s": control_seconds(), "capture": str(folder), "views": len(capture.frames),
        "texture_res": args.texture_res, "repeats": args.repeats, "cuda": status._asdict(), "backends": {},
    }
    maps = {}
    for device in backends:
        config = Config(texels=TexelConfig(texture_res=args.texture_res), device=device)
        print(f"timing {describe_device(device)} ...", flush=True)
        result["backends"][device], maps[device] = time_backend(capture, config, spectra, args.repeats)
    if len(maps) == 2:
        result["largest_difference_cuda_vs_cpu"] = {
            name: float(np.nanmax(np.abs(np.asarray(maps["cuda"][name], np.float64)
                                         - np.asarray(maps["cpu"][name], np.float64)), initial=0.0))
            for name in maps["cpu"]}
    save_results(args.name, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
