"""Time the observation stage on the bunny (T = 512, 64 views at 256 x 256).

    python benchmarks/timing/bench_observe.py [--scene plane|bunny]

The capture (scenes.observe_timing_capture) is rendered once with freqbrdf.synthetic.synth into
benchmarks/.cache/ and reused. Timing: per stage, for the first call in the process (cold: numba
kernels loaded from their cache, Mitsuba's ray-test kernel compiled) and for a second call (warm);
wall and CPU seconds, peak resident memory (ru_maxrss) and the load average, since the machine may
be shared. Prints the figures and saves them to benchmarks/results/bench_observe.json. (The file's
``environment_occlusion_accuracy`` and ``warm_with_environment_occlusion`` entries measured a
retired form of ObserveConfig.environment_occlusion: docs/results.md#tried-and-not-kept.)

``--scene`` times only the observation of studies/compare_estimators.py's capture of that scene
(scenes.compare_capture: 64 views at 256 x 256, T = 512; the plane is its largest case) and stores
it under ``timing_<scene>`` in the same JSON, keeping the rest.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import time
from pathlib import Path

from freqbrdf.capture.layouts import load
from freqbrdf.config import Config
from freqbrdf.fileio import atomic_path
from freqbrdf.observe.observations import observe

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import RESULTS_DIR
from scenes import COMPARE_SCENES, OBSERVE_TIMING_SCENE, compare_capture, observe_timing_capture

RESULTS = RESULTS_DIR / "bench_observe.json"


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def timed_run(capture, config: Config) -> dict:
    wall, cpu = time.perf_counter(), time.process_time()
    observations = observe(capture, config)
    return {
        "wall_s": round(time.perf_counter() - wall, 3),
        "cpu_s": round(time.process_time() - cpu, 3),
        "stages_s": {stage: round(seconds, 3) for stage, seconds in observations.timings.items()},
        "texels": observations.n_texels,
        "mean_samples_per_texel": round(float(observations.n_samples.mean()), 2),
        "peak_rss_mib_so_far": round(peak_rss_mib(), 1),
    }


def timing() -> dict:
    capture = load(observe_timing_capture())
    config = Config()
    cold = timed_run(capture, config)
    warm = timed_run(capture, config)
    return {"texture_res": config.texels.texture_res, "views": len(capture.frames),
            "image_size": OBSERVE_TIMING_SCENE.resolution, "cold": cold, "warm": warm}


def scene_timing(scene: str) -> dict:
    """Cold and warm observation of compare_estimators.py's capture of ``scene``."""
    folder = compare_capture(scene)
    capture = load(folder)
    config = Config()
    return {"capture": str(folder), "texture_res": config.texels.texture_res, "views": len(capture.frames),
            "load_average_before": [round(load, 2) for load in os.getloadavg()],
            "cold": timed_run(capture, config), "warm": timed_run(capture, config),
            "load_average_after": [round(load, 2) for load in os.getloadavg()]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", choices=sorted(COMPARE_SCENES), help="only time the observation of this scene")
    args = parser.parse_args()
    previous = json.loads(RESULTS.read_text()) if RESULTS.is_file() else {}
    if args.scene:
        result = {**previous, "cpu_count": os.cpu_count(), f"timing_{args.scene}": scene_timing(args.scene)}
        print(json.dumps(result[f"timing_{args.scene}"], indent=2))
        save(result)
        return
    result = {
        "benchmark": "observations: bunny, T = 512, 64 views at 256 x 256",
        "cpu_count": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "load_average_before": [round(load, 2) for load in os.getloadavg()],
        "timing": timing(),
    }
    result["peak_rss_mib"] = round(peak_rss_mib(), 1)
    result["load_average_after"] = [round(load, 2) for load in os.getloadavg()]
    # The per-scene timings (--scene) are kept.
    result.update({key: value for key, value in previous.items() if key.startswith("timing_")})
    print(json.dumps(result, indent=2))
    save(result)


def save(result: dict) -> None:
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(RESULTS) as tmp:
        tmp.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
