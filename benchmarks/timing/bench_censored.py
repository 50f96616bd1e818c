"""What clipped photographs cost a fit: the same capture in HDR and as 8-bit sRGB data, in pairs.

An 8-bit copy clips a share of the samples; the fit then estimates once more to fill those
censored channels in (docs/method.md#censored-samples). Each pair fits the HDR capture and its
8-bit copy (`benchmarks/imperfections.py`, as studies/calibration.py makes it) in fresh processes
(`bench_fit.one_fit`), the order alternating, at T = 256 as the study fits them; the ratio of the
medians is the cost. The capture is studies/calibration.py's bunny (32 views of 192 x 192).

    python benchmarks/timing/bench_censored.py [--pairs 3]

Prints a table and saves benchmarks/results/bench_censored.json.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fit import fit_command, one_fit, spread  # noqa: E402

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
    runs = {name: [] for name in captures}
    with tempfile.TemporaryDirectory(prefix="bench_censored.") as scratch:
        for name, capture in captures.items():  # numba's kernels compiled or loaded, untimed
            subprocess.run([*fit_command(), "fit", str(capture), "--out", str(Path(scratch) / f"warm_{name}"),
                            "--quiet", "--texture-res", "32"], capture_output=True, check=True)
        for pair in range(args.pairs):
            order = list(captures) if pair % 2 == 0 else list(reversed(captures))
            for name in order:
                runs[name].append(one_fit(captures[name], Path(scratch) / name, OPTIONS))
                print(f"pair {pair + 1} {name}: {runs[name][-1]['wall_s']:.2f} s wall, censored "
                      f"{runs[name][-1]['stages_s'].get('censored', 0.0):.2f} s", flush=True)
    wall = {name: spread([run["wall_s"] for run in found]) for name, found in runs.items()}
    result = {
        "benchmark": "fit of an HDR capture and of its 8-bit copy (censored samples), fresh process per run, T = 256",
        **machine(),
        "captures": {name: str(capture) for name, capture in captures.items()},
        "commands": [*fit_command(), "fit", "CAPTURE", "--out", "DIR", "--quiet", *OPTIONS],
        "runs": runs,
        "wall_s": wall,
        "censored_s": spread([run["stages_s"].get("censored", 0.0) for run in runs["8-bit"]]),
        "cost_ratio_median": wall["8-bit"]["median"] / wall["hdr"]["median"],
        "pair_ratios": [clipped["wall_s"] / hdr["wall_s"] for clipped, hdr in zip(runs["8-bit"], runs["hdr"])],
        "measured": time.strftime("%Y-%m-%d %H:%M"),
    }
    save_results("bench_censored", result)
    print(f"wall median HDR {wall['hdr']['median']:.2f} s, 8-bit {wall['8-bit']['median']:.2f} s: "
          f"x{result['cost_ratio_median']:.3f} (pairs {', '.join(f'{r:.3f}' for r in result['pair_ratios'])})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
