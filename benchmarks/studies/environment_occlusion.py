"""How well the irradiance of `observe` explains Mitsuba's path-traced Lambertian objects, with and
without the environment's occlusion by the object itself (``ObserveConfig.environment_occlusion``).

    python benchmarks/studies/environment_occlusion.py

Captures: a grey (albedo 0.5) Lambertian bunny and Stanford dragon (a plain ``diffuse`` BSDF in
place of synth's principled one), under the bundled ``sunset`` (a low sun) and ``forest`` (no
sun) maps, 32 views of 128 x 128 pixels at 128 spp on the whole sphere, rendered once into
benchmarks/.cache/. Per texel (T = 128, texels with at least 3 samples) the mean observed
radiance is compared with albedo x E / pi, E unoccluded (the paper's) and corrected by
`freqbrdf.observe.occlusion`: median absolute and signed relative error over all such texels and
over the occluded ones (where the correction moves E by more than 10 %), and the seconds of the
correction. Writes benchmarks/results/environment_occlusion.json.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from unittest import mock

import numpy as np

from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, ObserveConfig, TexelConfig
from freqbrdf.observe.observations import observe
from freqbrdf.synthetic.synth import SynthSettings, synthesize

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import machine, save_results
from scenes import dragon_mesh

CACHE = Path(__file__).resolve().parents[1] / ".cache"
ALBEDO = 0.5
TEXTURE_RES = 128
MIN_SAMPLES = 3
OCCLUDED_CHANGE = 0.1  # a texel counts as occluded where the correction moves E by more than this share
LIGHTS = ("sunset", "forest")


def lambertian_capture(mesh: str, light: str):
    folder = CACHE / f"lambertian_{mesh}_{light}_v32_r128"
    if not (folder / "transforms.json").is_file():
        settings = SynthSettings(mesh=str(dragon_mesh()) if mesh == "dragon" else mesh, envmap=light,
                                 materials="bands", views=32, resolution=128, spp=128, texture_res=64,
                                 cameras="sphere", test_views=0, seed=0)
        diffuse = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [ALBEDO] * 3}}
        print(f"rendering {folder} (once)", flush=True)
        with mock.patch("freqbrdf.synthetic.synth.principled_bsdf", lambda materials: dict(diffuse)):
            synthesize(folder, settings, progress=False)
    return load(folder)


def errors(relative: np.ndarray) -> dict:
    return {"median_abs_rel_error": round(float(np.median(np.abs(relative))), 4),
            "median_signed_rel_error": round(float(np.median(relative)), 4)}


def measure(mesh: str, light: str) -> dict:
    capture = lambertian_capture(mesh, light)
    config = Config(texels=TexelConfig(texture_res=TEXTURE_RES))
    plain = observe(capture, config.replace(observe=ObserveConfig(environment_occlusion=False)))
    traced = observe(capture, config)
    weight = plain.weight.astype(np.float64)
    total = weight.sum(axis=1)
    usable = plain.n_samples >= MIN_SAMPLES
    mean_radiance = np.einsum("nv,nvc->nc", weight, plain.observed) / np.maximum(total, 1e-30)[:, None]
    change = np.abs(traced.irradiance.sum(axis=1) / np.maximum(plain.irradiance.sum(axis=1), 1e-30) - 1.0)
    occluded = usable & (change > OCCLUDED_CHANGE)
    row = {"mesh": mesh, "light": light, "texels": int(usable.sum()), "occluded_texels": int(occluded.sum()),
           "occlusion_seconds": round(traced.timings["occlusion"], 3), "observe_seconds": round(traced.timings["total"], 3)}
    for name, observations in (("unoccluded", plain), ("occlusion_traced", traced)):
        predicted = ALBEDO * observations.irradiance.astype(np.float64) / np.pi
        relative = (mean_radiance / np.maximum(predicted, 1e-30) - 1.0).mean(axis=1)
        row[name] = {"all": errors(relative[usable]), "occluded": errors(relative[occluded])}
    print(row, flush=True)
    return row


def main() -> int:
    start = time.perf_counter()
    rows = [measure(mesh, light) for mesh in ("bunny", "dragon") for light in LIGHTS]
    save_results("environment_occlusion", {
        "study": "irradiance against Mitsuba's path-traced Lambertian objects, unoccluded and occlusion traced",
        **machine(), "albedo": ALBEDO, "texture_res": TEXTURE_RES, "min_samples": MIN_SAMPLES,
        "occluded_change": OCCLUDED_CHANGE, "rows": rows, "seconds": round(time.perf_counter() - start, 1)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
