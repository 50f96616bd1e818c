"""Photographs through a real lens: the maps with the lens's distortion declared in transforms.json, and without.

    python benchmarks/studies/lens.py [--scenes a,b]

Scenes: the calibration study's three path-traced captures of the whole-surface suite (32 views of
192 x 192, T = 256; `studies/calibration.py`). Each photograph and mask is resampled through an
OpenCV lens (`imperfections.Imperfection.lens_k1`: radial k1, k2 = -k1 / 4, tangential k1 / 100;
k1 = -0.2 is a wide-angle lens's barrel, +0.1 a tele lens's pincushion), bilinearly from the pinhole
render (a lens's photograph of the scene to that resampling). Fitted with the defaults, the lens in
transforms.json (`freqbrdf.capture.lens`) and not; scored on the texels a view sees against the
clean capture's fit.

Writes benchmarks/results/lens.{json,md}.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration import RENDER, SCENES, TEXTURE_RES, scores  # noqa: E402
from whole_surface import seen_texels  # noqa: E402

import scenes  # noqa: E402
from _common import machine, save_results, source_commit  # noqa: E402
from freqbrdf import pipeline  # noqa: E402
from freqbrdf.capture.layouts import load  # noqa: E402
from freqbrdf.config import Config, TexelConfig  # noqa: E402
from imperfections import Imperfection, imperfect_capture  # noqa: E402

CASES = {
    "clean": Imperfection(),
    "barrel k1 = -0.2, declared": Imperfection(lens_k1=-0.2),
    "barrel k1 = -0.2, not declared": Imperfection(lens_k1=-0.2, lens_declared=False),
    "pincushion k1 = 0.1, declared": Imperfection(lens_k1=0.1),
    "pincushion k1 = 0.1, not declared": Imperfection(lens_k1=0.1, lens_declared=False),
}


def run_scene(scene: str) -> dict:
    source = scenes.whole_surface_capture(scene, RENDER)
    clean = load(source)
    seen = seen_texels(clean, TEXTURE_RES)
    config = Config(texels=TexelConfig(texture_res=TEXTURE_RES))
    pipeline.fit(clean, config)  # numba's first calls, outside the timings
    rows = {}
    for name, imperfection in CASES.items():
        folder = imperfect_capture(source, scenes.CACHE / "lens" / f"{source.name}_{imperfection.name()}", imperfection)
        start = time.perf_counter()
        result = pipeline.fit(load(folder), config)
        rows[name] = {"scores": scores(result.maps, clean.ground_truth, seen), "seconds": time.perf_counter() - start,
                      "warnings": list(result.warnings)}
        print(f"[{scene}] {name}: {rows[name]['scores']} ({rows[name]['seconds']:.1f} s)", flush=True)
    return rows


def markdown(results: dict) -> str:
    lines = ["# Photographs through a lens", "",
             "Seen texels; base colour PSNR (dB) / roughness MAE / metallic MAE / dielectrics called metal.", "",
             "| case | " + " | ".join(results["scenes"]) + " |", "|---|" + "---|" * len(results["scenes"])]
    for case in CASES:
        cells = []
        for rows in results["scenes"].values():
            found = rows[case]["scores"]
            cells.append(f"{found['base_color_psnr']:.2f} / {found['roughness_mae']:.3f} / {found['metallic_mae']:.3f}"
                         f" / {found['dielectric_called_metal']:.1%}")
        lines.append(f"| {case} | " + " | ".join(cells) + " |")
    lines += ["", f"Measured at {results['commit']}."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default=",".join(SCENES))
    args = parser.parse_args(argv)
    results = {"study": "photographs through a lens, its distortion declared and not", **machine(),
               "commit": source_commit(), "render": RENDER, "texture_res": TEXTURE_RES,
               "scenes": {scene: run_scene(scene) for scene in args.scenes.split(",")}}
    save_results("lens", results)
    (Path(__file__).resolve().parents[1] / "results" / "lens.md").write_text(markdown(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
