"""What calibration costs a fit: ``freqbrdf fit`` with ``--calibration none`` and with the default, in pairs.

Each pair runs both commands in fresh processes (`bench_fit.fits_in_turn`), the order alternating, so
that the machine's drift falls on both alike; the ratio of the medians is the cost. The capture is
studies/calibration.py's dragon (32 views of 192 x 192, a concave mesh: the occlusion rays run),
fitted at T = 512 (the fit's default), rendered into benchmarks/.cache/ if it is missing.

    python benchmarks/timing/bench_calibration.py [--pairs 3] [--capture PATH]

Prints a table and saves benchmarks/results/bench_calibration.json.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fit import cost_in_turn, fit_command, fits_in_turn, spread  # noqa: E402

from _common import machine, save_results  # noqa: E402
from scenes import whole_surface_capture  # noqa: E402

SCENE = "dragon_photo_side"
RENDER = {"views": 32, "resolution": 192, "spp": 32, "texture_res": 256, "test_views": 4}  # as studies/calibration.py
SETTINGS = {"off": ["--calibration", "none"], "on": []}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--capture", default=None, help="a capture folder (default: the dragon of the study)")
    args = parser.parse_args(argv)
    capture = Path(args.capture) if args.capture else whole_surface_capture(SCENE, RENDER)
    with tempfile.TemporaryDirectory(prefix="bench_calibration.") as scratch:
        runs = fits_in_turn({name: (capture, options) for name, options in SETTINGS.items()}, args.pairs,
                            Path(scratch), "calibrate")
    cost = cost_in_turn(runs, "off", "on")
    result = {
        "benchmark": "fit with calibration off and on, fresh process per run, T = 512",
        **machine(),
        "capture": str(capture),
        "commands": {name: [*fit_command(), "fit", str(capture), "--out", "DIR", "--quiet", *options]
                     for name, options in SETTINGS.items()},
        "runs": runs,
        **cost,
        "calibrate_s": spread([run["stages_s"].get("calibrate", 0.0) for run in runs["on"]]),
        "measured": time.strftime("%Y-%m-%d %H:%M"),
    }
    save_results("bench_calibration", result)
    wall = cost["wall_s"]
    print(f"wall median off {wall['off']['median']:.2f} s, on {wall['on']['median']:.2f} s: "
          f"x{result['cost_ratio_median']:.3f} (pairs {', '.join(f'{r:.3f}' for r in result['pair_ratios'])}); "
          f"calibrate median {statistics.median(run['stages_s'].get('calibrate', 0.0) for run in runs['on']):.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
