"""Benchmark of the spherical-harmonic transforms of environment maps: ours (freqbrdf.sphere.sht) against
ducc0's (GPL-2.0-or-later; it must be installed to run this script, it is not a dependency).

On every bundled map (256 x 512, 3 channels), in one process and interleaved (ours, then ducc0,
repeat), median wall seconds of:

- ``analysis``: `envmap._analysis` at the degrees the code uses: 5 (SH fit), 20 (irradiance),
  127 (the low-pass limit for up to 1224 views; the first rule's largest degree) and 254
  (prefiltered light; the second rule);
- ``synthesis``: `envmap._synthesis` of 3 channels at degrees 20 and 254;
- ``zonal_filters``: the prefiltered light the estimator reads (`model.light.prefiltered_environment`'s
  16 filtered nodes: one analysis, 48 syntheses at degree 254);
- ``lowpass``: `envmap.lowpass_envmap` at sigma = 1 / 8 (64 views; degree 30).

ducc0 runs as freqbrdf called it (one thread); ours with numba's default threads and with one.
Wall and CPU seconds (all threads), and their ratios ours / ducc0 (medians over the maps of each
map's ratio).
Accuracy: max over the maps of max |ours - ducc0| / max |ducc0|, for the coefficients at every
degree above and at 128 and 200 (between the rules, where ducc0's intermediate grid is coarser
than its product's degree), and for the filtered maps. Also the first call (numba's cache
loading) and the control workload of `_common` to tell the machine's speed.

Prints and saves JSON to benchmarks/results/bench_sht_transform.json.
"""

from __future__ import annotations

import math
import statistics
import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]
from _common import control_seconds, machine, save_results  # noqa: E402
from freqbrdf import assets  # noqa: E402
from freqbrdf.model import brdf, light  # noqa: E402
from freqbrdf.sphere import envmap as em  # noqa: E402
from freqbrdf.sphere import harmonics as sh  # noqa: E402

try:
    import ducc0
except ImportError:
    sys.exit("bench_sht.py compares with ducc0: pip install ducc0 (GPL-2.0-or-later) to run it")

REPEATS = 5
ANALYSIS_DEGREES = (5, 20, 127, 254)
ACCURACY_DEGREES = (5, 20, 30, 75, 127, 128, 200, 253, 254)
SYNTHESIS_DEGREES = (20, 254)
N_NODES = 17  # estimate's prefilter_nodes for the default settings (roughness 0..1 in steps of 1/16)
SIGMA = brdf.band_limit_sigma(64)


def _ducc0_index(lmax):
    degrees = sh.sh_degrees(lmax)
    orders = np.arange(sh.num_coeffs(lmax)) - degrees * (degrees + 1)
    return orders, np.abs(orders) * (2 * lmax + 1 - np.abs(orders)) // 2 + degrees


def ducc0_analysis(radiance, lmax):
    """`envmap._analysis` as it was with ducc0 (H, W, 3) -> (3, K)."""
    orders, index = _ducc0_index(lmax)
    sign = np.where(np.abs(orders) % 2 == 1, -math.sqrt(2.0), math.sqrt(2.0))
    width = radiance.shape[1]
    out = []
    for channel in np.ascontiguousarray(radiance[:, ::-1, :].transpose(2, 0, 1), dtype=np.float64):
        alm = ducc0.sht.experimental.analysis_2d(map=channel[None], spin=0, lmax=lmax, geometry="CC",
                                                 phi0=math.pi / width)[0][index]
        out.append(np.where(orders == 0, alm.real, np.where(orders > 0, sign * alm.real, -sign * alm.imag)))
    return np.stack(out)


def ducc0_synthesis(coeffs_sh_frame, height, width, out=None):
    """`envmap._synthesis` as it was with ducc0: (..., 3, K) -> (..., H, W, 3) float32."""
    coeffs_sh_frame = np.asarray(coeffs_sh_frame, np.float64)
    lmax = sh.lmax_of(coeffs_sh_frame.shape[-1])
    orders, index = _ducc0_index(lmax)
    sign = np.where(np.abs(orders) % 2 == 1, -1.0, 1.0) / math.sqrt(2.0)
    flat = coeffs_sh_frame.reshape(-1, 3, coeffs_sh_frame.shape[-1])
    given, out = out, np.empty((len(flat), height, width, 3), np.float32)
    for n, channels in enumerate(flat):
        for c, coeffs in enumerate(channels):
            alm = np.zeros((lmax + 1) * (lmax + 2) // 2, np.complex128)
            alm[index[orders == 0]] = coeffs[orders == 0]
            alm[index[orders > 0]] += sign[orders > 0] * coeffs[orders > 0]
            alm[index[orders < 0]] += -1j * sign[orders < 0] * coeffs[orders < 0]
            out[n, :, :, c] = ducc0.sht.experimental.synthesis_2d(
                alm=alm[None], spin=0, lmax=lmax, geometry="CC", ntheta=height, nphi=width, phi0=math.pi / width,
            )[0][:, ::-1]
    maps = out.reshape(coeffs_sh_frame.shape[:-2] + (height, width, 3))
    if given is None:
        return maps
    given[...] = maps
    return given


class Ducc0Transforms:
    """Within the block, envmap's transforms are ducc0's (as the estimator would call them)."""

    def __enter__(self):
        self.saved = em._analysis, em._synthesis
        em._analysis, em._synthesis = ducc0_analysis, ducc0_synthesis

    def __exit__(self, *_):
        em._analysis, em._synthesis = self.saved


def relative(ours, reference):
    return float(np.abs(np.asarray(ours, np.float64) - reference).max() / np.abs(reference).max())


def interleaved(ours, theirs, repeats=REPEATS):
    """Median wall and CPU seconds (all threads; time.process_time, less sensitive to other load
    on a shared machine) of ours and of theirs, run alternately: ((wall, cpu), (wall, cpu))."""
    samples = {"ours": [], "theirs": []}
    for _ in range(repeats):
        for name, run in (("ours", ours), ("theirs", theirs)):
            wall, cpu = time.perf_counter(), time.process_time()
            run()
            samples[name].append((time.perf_counter() - wall, time.process_time() - cpu))
    return tuple(tuple(statistics.median(column) for column in zip(*samples[name])) for name in ("ours", "theirs"))


def workloads(envmap):
    """name -> (ours, ducc0's) callables on one map."""
    radiance = envmap.radiance
    height, width = radiance.shape[:2]
    out = {}
    for lmax in ANALYSIS_DEGREES:
        out[f"analysis_l{lmax}"] = (lambda lmax=lmax: em._analysis(radiance, lmax),
                                    lambda lmax=lmax: ducc0_analysis(radiance, lmax))
    for lmax in SYNTHESIS_DEGREES:
        coeffs = em._analysis(radiance, lmax)
        out[f"synthesis_l{lmax}"] = (lambda coeffs=coeffs: em._synthesis(coeffs, height, width),
                                     lambda coeffs=coeffs: ducc0_synthesis(coeffs, height, width))

    def with_ducc0(run):
        def wrapped():
            with Ducc0Transforms():
                return run()
        return wrapped

    prefiltered = lambda: light.prefiltered_environment(envmap, N_NODES)  # noqa: E731
    lowpass = lambda: em.lowpass_envmap(envmap, SIGMA).radiance  # noqa: E731
    out["zonal_filters"] = (prefiltered, with_ducc0(prefiltered))
    out["lowpass"] = (lowpass, with_ducc0(lowpass))
    return out


def main():
    envmaps = {name: em.load_envmap(assets.envmap_path(name)) for name in assets.list_envmaps()}
    first = next(iter(envmaps.values()))
    start = time.perf_counter()
    em._synthesis(em._analysis(first.radiance, 254), 256, 512)
    em._analysis(first.radiance, 20)
    first_call = time.perf_counter() - start

    accuracy = {}
    for lmax in ACCURACY_DEGREES:
        accuracy[f"coefficients_l{lmax}"] = max(
            relative(em._analysis(envmap.radiance, lmax), ducc0_analysis(envmap.radiance, lmax))
            for envmap in envmaps.values())
    for envmap in envmaps.values():
        for name, (ours, theirs) in workloads(envmap).items():
            if not name.startswith("analysis"):
                accuracy[name] = max(accuracy.get(name, 0.0), relative(ours(), theirs()))

    control_before = control_seconds()
    timings = {}
    default_threads = numba.get_num_threads()
    for threads in sorted({default_threads, 1}, reverse=True):
        numba.set_num_threads(threads)
        per_map = {}
        for map_name, envmap in envmaps.items():
            for name, (ours, theirs) in workloads(envmap).items():
                per_map.setdefault(name, []).append(interleaved(ours, theirs))
        timings[f"ours_{threads}_threads_vs_ducc0_1_thread"] = {
            name: {"ours_wall_s": round(statistics.median(a[0] for a, _ in values), 4),
                   "ducc0_wall_s": round(statistics.median(b[0] for _, b in values), 4),
                   "ratio_wall": round(statistics.median(a[0] / b[0] for a, b in values), 2),
                   "ours_cpu_s": round(statistics.median(a[1] for a, _ in values), 4),
                   "ducc0_cpu_s": round(statistics.median(b[1] for _, b in values), 4),
                   "ratio_cpu": round(statistics.median(a[1] / max(b[1], 1e-9) for a, b in values), 2)}
            for name, values in per_map.items()}
    numba.set_num_threads(default_threads)
    control_after = control_seconds()

    save_results("bench_sht_transform", {
        "machine": machine(),
        "maps": {name: list(envmap.radiance.shape) for name, envmap in envmaps.items()},
        "repeats": REPEATS,
        "numba_default_threads": default_threads,
        "ducc0_version": ducc0.__version__,
        "first_call_s": round(first_call, 3),
        "control_s": {"before": round(control_before, 3), "after": round(control_after, 3)},
        "accuracy_max_relative_difference": {name: float(f"{value:.2e}") for name, value in accuracy.items()},
        "median_over_maps": timings,
    })


if __name__ == "__main__":
    main()
