"""The base colour's std where the photographs and the map disagree in exposure or white balance (issues #40, #42).

    python benchmarks/studies/gain_std.py [--scenes a,b]

Scenes: the calibration study's three path-traced captures of the whole-surface suite (32 views of
192 x 192, T = 256; `studies/calibration.py`), clean and with the photographs at 2x and 0.5x the
map's exposure and a white balance of (1.2, 1, 0.8) (`imperfections.imperfect_capture`), fitted with
the defaults (calibration on). A gain found to a few per cent leaves every base colour off by that
share, an error no held-out view shows (`freqbrdf.calibrate.Calibration.gain_error_log_std`): per
case, on the texels a view sees, the base colour's std (mean over RGB) against its error: Spearman's
rho, the shares within 1 and 2 std, the mean std and error, and the gains found.

Writes benchmarks/results/gain_std.{json,md}.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration import RENDER, TEXTURE_RES, scene_study_main  # noqa: E402
from whole_surface import seen_texels, std_scores, std_textures  # noqa: E402

import scenes  # noqa: E402
from freqbrdf import pipeline  # noqa: E402
from freqbrdf.capture.layouts import load  # noqa: E402
from freqbrdf.config import Config, TexelConfig  # noqa: E402
from imperfections import Imperfection, imperfect_capture  # noqa: E402

CASES = {
    "clean": Imperfection(),
    "exposure 2": Imperfection(exposure=2.0),
    "exposure 0.5": Imperfection(exposure=0.5),
    "white balance (1.2, 1, 0.8)": Imperfection(white_balance=(1.2, 1.0, 0.8)),
}


def run_scene(scene: str) -> dict:
    source = scenes.whole_surface_capture(scene, RENDER)
    clean = load(source)
    seen = seen_texels(clean, TEXTURE_RES)
    truth = clean.ground_truth
    config = Config(texels=TexelConfig(texture_res=TEXTURE_RES))
    rows = {}
    for name, imperfection in CASES.items():
        folder = imperfect_capture(source, scenes.CACHE / "calibration" / f"{source.name}_{imperfection.name()}",
                                   imperfection)
        result = pipeline.fit(load(folder), config)
        found = std_scores(std_textures(result)["base_color"], result.maps.base_color, truth.base_color, seen)
        found["gain"] = result.calibration.gain.tolist()
        found["gain_error_std"] = (result.calibration.gain * result.calibration.gain_error_log_std).tolist()
        rows[name] = found
        print(f"[{scene}] {name}: rho {found['spearman']:.2f}, within 1 std {found['coverage_1sigma']:.1%}, "
              f"mean std {found['mean_std']:.4f}, mean error {found['mean_error']:.4f}, gain "
              f"{np.round(result.calibration.gain, 3).tolist()}", flush=True)
    return rows


def markdown(results: dict) -> str:
    lines = ["# The base colour's std under a wrong exposure or white balance", "",
             "Seen texels, calibration on (the default); the std as the fit writes it. Cells: Spearman rho / within "
             "1 std / within 2 std (mean std, mean error).", "",
             "| case | " + " | ".join(results["scenes"]) + " |", "|---|" + "---|" * len(results["scenes"])]
    for case in CASES:
        cells = []
        for scene in results["scenes"].values():
            row = scene[case]
            cells.append(f"{row['spearman']:.2f} / {row['coverage_1sigma']:.0%} / {row['coverage_2sigma']:.0%} "
                         f"({row['mean_std']:.3f}, {row['mean_error']:.3f})")
        lines.append(f"| {case} | " + " | ".join(cells) + " |")
    lines += ["", f"Measured at {results['commit']}."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    return scene_study_main(argv, __doc__, "gain_std", "the base colour's std under a wrong exposure or white balance", run_scene, markdown)


if __name__ == "__main__":
    raise SystemExit(main())
