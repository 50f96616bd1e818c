"""Photographs through a real lens: the maps with the lens's distortion declared in transforms.json, and without.

    python benchmarks/studies/lens.py [--scenes a,b]

Scenes: the calibration study's three path-traced captures of the whole-surface suite (32 views of
192 x 192, T = 256; `studies/calibration.py`). Each photograph and mask is taken through an OpenCV
lens (radial k1, k2 = -k1 / 4, tangential k1 / 100; k1 = -0.2 a wide-angle lens's barrel, +0.1 a
tele lens's pincushion) from the same capture rendered at 384 x 384 (`imperfections.lens_capture`:
2 x 2 sub-pixels a pixel, each read bilinearly; "no lens" the same without a lens: the reference,
less noisy than the 192 x 192 render). Fitted with the defaults, the lens in transforms.json
(`freqbrdf.capture.lens`) and not; scored on the texels a view sees.

Writes benchmarks/results/lens.{json,md}.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration import RENDER, TEXTURE_RES, scene_study_main, scores  # noqa: E402
from whole_surface import seen_texels  # noqa: E402

import scenes  # noqa: E402
from freqbrdf import pipeline  # noqa: E402
from freqbrdf.capture.layouts import load  # noqa: E402
from freqbrdf.capture.lens import LensDistortion  # noqa: E402
from freqbrdf.config import Config, TexelConfig  # noqa: E402
from imperfections import lens_capture  # noqa: E402

LENSES = {"no lens": 0.0, "barrel k1 = -0.2": -0.2, "pincushion k1 = 0.1": 0.1}
CASES = ["clean", "no lens, from the 2x render"] + [f"{lens}, {how}" for lens in LENSES if LENSES[lens]
                                                     for how in ("declared", "not declared")]


def lens_of(k1: float) -> LensDistortion:
    return LensDistortion("opencv", (k1, -k1 / 4, 0.0, 0.0), (k1 / 100, k1 / 100))


def run_scene(scene: str) -> dict:
    source = scenes.whole_surface_capture(scene, RENDER)
    clean = load(source)
    seen = seen_texels(clean, TEXTURE_RES)
    config = Config(texels=TexelConfig(texture_res=TEXTURE_RES))
    # The lens apart from the gains, which read these captures differently (docs/results.md#lens-distortion).
    without_gains = config.replace(calibration=dataclasses.replace(config.calibration, gains=False))
    pipeline.fit(clean, config)  # numba's first calls, outside the timings
    fine = scenes.whole_surface_capture(scene, {**RENDER, "resolution": 2 * RENDER["resolution"]})
    rows = {}
    for name in CASES:
        folder = source
        if name != "clean":
            lens, how = name.split(", ", 1)
            folder = lens_capture(source, fine, scenes.CACHE / "lens" / f"{source.name}_{LENSES[lens]:g}_{how.replace(' ', '_')}",
                                  lens_of(LENSES[lens]), how == "declared")  # no lens: nothing to declare
        rows[name] = {}
        for label, settings in (("default", config), ("gains off", without_gains)):
            start = time.perf_counter()
            result = pipeline.fit(load(folder), settings)
            row = rows[name][label] = {"scores": scores(result.maps, clean.ground_truth, seen),
                                       "seconds": time.perf_counter() - start, "gain": result.calibration.gain.tolist(),
                                       "warnings": list(result.warnings)}
            print(f"[{scene}] {name} ({label}): {row['scores']} gain {row['gain']} ({row['seconds']:.1f} s)", flush=True)
    return rows


def markdown(results: dict) -> str:
    lines = ["# Photographs through a lens", "",
             "Seen texels; base colour PSNR (dB) / roughness MAE / metallic MAE / dielectrics called metal; the "
             "fit's defaults, and with the gains not estimated.", ""]
    for label in ("default", "gains off"):
        lines += [f"## {label}", "", "| case | " + " | ".join(results["scenes"]) + " |",
                  "|---|" + "---|" * len(results["scenes"])]
        for case in CASES:
            cells = []
            for rows in results["scenes"].values():
                found = rows[case][label]["scores"]
                cells.append(f"{found['base_color_psnr']:.2f} / {found['roughness_mae']:.3f} / "
                             f"{found['metallic_mae']:.3f} / {found['dielectric_called_metal']:.1%}")
            lines.append(f"| {case} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += [f"Measured at {results['commit']}."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    return scene_study_main(argv, __doc__, "lens", "photographs through a lens, its distortion declared and not", run_scene, markdown)


if __name__ == "__main__":
    raise SystemExit(main())
