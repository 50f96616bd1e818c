"""What clipped photographs cost a fit: the same capture in HDR and as 8-bit sRGB data, in pairs.

An 8-bit copy clips a share of the samples; the fit then estimates once more to fill those
censored channels in (docs/method.md#censored-samples). Each pair fits the HDR capture and its
8-bit copy (`benchmarks/imperfections.py`, as studies/calibration.py makes it) in fresh processes
(`bench_fit.fits_in_turn`), the order alternating, at T = 256 as the study fits them; the ratio of the
medians is the cost. The capture is studies/calibration.py's bunny (32 views of 192 x 192).

    python benchmarks/timing/bench_censored.py [--pairs 3]

Prints a table and saves benchmarks/results/bench_censored.json.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fit import cost_in_turn, fit_command, fits_in_turn, spread  # noqa: E402

import scenes  # noqa: E402
from _common import machine, save_results  # noqa: E402
from imperfections import Imperfection, imperfect_capture  # noqa: E402

SCENE = "bunny_islands_overcast"
RENDER = {"views": 32, "resolution": 192, "spp": 32, "texture_res": 256, "test_views": 4}  # as studies/calibration.py
OPTIONS = ["--texture-res", "256"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=3)
    args = parser.parse_args(argv)
    source = scenes.whole_surface_capture(SCENE, RENDER)
    imperfection = Imperfection(eight_bit=True)
    captures = {"hdr": source, "8-bit": imperfect_capture(
        source, scenes.CACHE / "calibration" / f"{source.name}_{imperfection.name()}", imperfection)}
    with tempfile.TemporaryDirectory(prefix="bench_censored.") as scratch:
        runs = fits_in_turn({name: (capture, OPTIONS) for name, capture in captures.items()}, args.pairs,
                            Path(scratch), "censored")
    cost = cost_in_turn(runs, "hdr", "8-bit")
    result = {
        "benchmark": "fit of an HDR capture and of its 8-bit copy (censored samples), fresh process per run, T = 256",
        **machine(),
        "captures": {name: str(capture) for name, capture in captures.items()},
        "commands": [*fit_command(), "fit", "CAPTURE", "--out", "DIR", "--quiet", *OPTIONS],
        "runs": runs,
        **cost,
        "censored_s": spread([run["summary_timings_s"].get("censored", 0.0) for run in runs["8-bit"]]),
        "measured": time.strftime("%Y-%m-%d %H:%M"),
    }
    save_results("bench_censored", result)
    wall = cost["wall_s"]
    print(f"wall median HDR {wall['hdr']['median']:.2f} s, 8-bit {wall['8-bit']['median']:.2f} s: "
          f"x{result['cost_ratio_median']:.3f} (pairs {', '.join(f'{r:.3f}' for r in result['pair_ratios'])})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
