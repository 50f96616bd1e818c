"""Photographs exposed differently (auto-exposure): the maps with the per-frame gains (``--frame-gains``) off and on.

    python benchmarks/studies/frame_gains.py [--scenes a,b]

Scenes: the calibration study's three path-traced captures of the whole-surface suite (32 views of
192 x 192, T = 256; `studies/calibration.py`). Each photograph's exposure is multiplied by
exp(N(0, spread)) (`imperfections.Imperfection.frame_exposure_spread`, seed 1) for spreads 0
(photographs exposed alike), 0.15 and 0.3 in log; each capture is fitted with the defaults and with
``CalibrationConfig.frame_gains = "on"`` (`freqbrdf.calibrate.gains.frame_gains`, each frame applied
where likelier off the others than alike) and scored on the texels a view sees. Also: how many frames
the calibration corrected and the RMS of the frames' log exposure error (each relative to the
frames' geometric mean) before and after.

Writes benchmarks/results/frame_gains.{json,md}.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration import RENDER, TEXTURE_RES, scene_study_main, scores  # noqa: E402
from whole_surface import seen_texels  # noqa: E402

import scenes  # noqa: E402
from freqbrdf import pipeline  # noqa: E402
from freqbrdf.capture.layouts import load  # noqa: E402
from freqbrdf.config import Config, TexelConfig  # noqa: E402
from imperfections import Imperfection, imperfect_capture  # noqa: E402

SPREADS = (0.0, 0.15, 0.3)
SEED = 1


def applied_exposures(spread: float, n_frames: int) -> np.ndarray:
    """(V,) the log exposure each frame was given, relative to their mean (as `imperfect_capture` draws them)."""
    rng = np.random.default_rng(SEED)
    drawn = rng.normal(0.0, spread, n_frames) if spread else np.zeros(n_frames)
    return drawn - drawn.mean()


def run_scene(scene: str) -> dict:
    source = scenes.whole_surface_capture(scene, RENDER)
    clean = load(source)
    seen = seen_texels(clean, TEXTURE_RES)
    config = Config(texels=TexelConfig(texture_res=TEXTURE_RES))
    frames_on = config.replace(calibration=dataclasses.replace(config.calibration, frame_gains="on"))
    pipeline.fit(clean, config)  # numba's first calls, outside the timings
    rows = {}
    for spread in SPREADS:
        imperfection = Imperfection(frame_exposure_spread=spread, seed=SEED)
        folder = imperfect_capture(source, scenes.CACHE / "frame_gains" / f"{source.name}_{imperfection.name()}",
                                   imperfection) if spread else source
        truth = applied_exposures(spread, len(clean.frames))
        rows[f"{spread:g}"] = row = {"frames": len(truth)}
        for label, settings in (("off", config), ("on", frames_on)):
            start = time.perf_counter()
            result = pipeline.fit(load(folder), settings)
            found = result.calibration.frame_gain
            corrected = np.zeros(len(truth)) if found is None else np.log(found).mean(axis=1)
            row[label] = {"scores": scores(result.maps, clean.ground_truth, seen),
                          "seconds": time.perf_counter() - start, "gain": result.calibration.gain.tolist(),
                          "frames_corrected": int(np.count_nonzero(corrected)),
                          "frame_error_rms": float(np.sqrt(np.mean((truth - corrected - (truth - corrected).mean()) ** 2)))}
            print(f"[{scene}] spread {spread:g} ({label}): {row[label]['scores']} frames corrected "
                  f"{row[label]['frames_corrected']}, frame error {row[label]['frame_error_rms']:.3f} "
                  f"({row[label]['seconds']:.1f} s)", flush=True)
    return rows


def markdown(results: dict) -> str:
    lines = ["# Photographs exposed differently", "",
             "Seen texels, frame gains off / on: base colour PSNR (dB), roughness MAE; frames corrected; the RMS of the "
             "frames' log exposure error (relative to their mean).", "",
             "| scene | spread (log) | BC dB | R MAE | frames corrected | frame error |", "|---|---|---|---|---|---|"]
    for scene, rows in results["scenes"].items():
        for spread, row in rows.items():
            off, on = row["off"], row["on"]
            lines.append(f"| {scene} | {spread} | {off['scores']['base_color_psnr']:.2f} / {on['scores']['base_color_psnr']:.2f} "
                         f"| {off['scores']['roughness_mae']:.3f} / {on['scores']['roughness_mae']:.3f} "
                         f"| {on['frames_corrected']} of {row['frames']} "
                         f"| {off['frame_error_rms']:.3f} / {on['frame_error_rms']:.3f} |")
    lines += ["", f"Measured at {results['commit']}."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    return scene_study_main(argv, __doc__, "frame_gains", "photographs exposed differently, frame gains off and on",
                            run_scene, markdown)


if __name__ == "__main__":
    raise SystemExit(main())
