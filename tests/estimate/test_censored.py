"""Censored samples: clipped channels are lower bounds, filled in from the estimate (docs/method.md#censored-samples).

A small Mitsuba capture (a sphere of dielectric and metal gradients under the lobby map) is
rendered once; a copy has every photograph's red channel clipped at a ceiling a share of the
object's pixels reach, as an 8-bit camera or a blown highlight clips them.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from freqbrdf import pipeline
from freqbrdf.capture.layouts import load
from freqbrdf.config import CalibrationConfig, Config, TexelConfig
from freqbrdf.estimate import estimate
from freqbrdf.estimate.censored import impute_censored
from freqbrdf.estimate.surface import whole_surface
from freqbrdf.images import read_image, write_exr
from freqbrdf.observe import observe
from freqbrdf.synthetic.synth import SynthSettings, synthesize

OFF = CalibrationConfig(gains=False, cameras=False, probe_rotation=False, frame_gains="off")
CONFIG = Config(texels=TexelConfig(texture_res=32), calibration=OFF)
# The share of the object's red values above the ceiling.
CLIPPED_SHARE = 0.25


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> tuple[Path, Path, list[float]]:
    from freqbrdf.assets import mesh_path
    from freqbrdf.capture.mesh import load_mesh
    from freqbrdf.model.materials import save_material_maps
    from freqbrdf.synthetic.materials import gradient_material

    root = tmp_path_factory.mktemp("censored")
    save_material_maps(root / "materials", gradient_material(load_mesh(mesh_path("sphere")), 32, seed=0))
    settings = SynthSettings(mesh="sphere", envmap="lobby", materials=str(root / "materials"), views=24,
                             resolution=64, spp=8, texture_res=32, test_views=0, cameras="hemisphere")
    clean = synthesize(root / "clean", settings, progress=False)
    clipped = root / "clipped"
    clipped.mkdir()
    transforms = json.loads((clean / "transforms.json").read_text())
    for name in os.listdir(clean):
        if name != "images":
            os.symlink(clean.resolve() / name, clipped / name)
    (clipped / "images").mkdir()
    ceilings = []
    for frame in transforms["frames"]:
        image = read_image(clean / frame["file_path"])
        red = image[..., 0][image.max(axis=2) > 0]
        ceiling = float(np.quantile(red, 1.0 - CLIPPED_SHARE))
        image[..., 0] = np.minimum(image[..., 0], ceiling)
        write_exr(clipped / frame["file_path"], image)
        ceilings.append(ceiling)
    return clean, clipped, ceilings


def test_clipped_channels_are_censored_samples_and_the_others_are_kept(captures):
    clean, clipped, ceilings = captures
    exact, censored = observe(load(clean), CONFIG), observe(load(clipped), CONFIG)
    assert exact.censored is None and exact.censored_weight is None
    flags = censored.censored
    assert flags is not None and flags[..., 0].any() and not flags[..., 1:].any()  # only red was clipped
    counted = exact.weight > 0
    held = flags.any(axis=2)
    # A censored sample waits at weight 0 with its weight aside; every other sample is as before.
    assert np.all(censored.weight[held] == 0) and np.all(censored.censored_weight[held] == exact.weight[held])
    np.testing.assert_array_equal(censored.weight[~held], exact.weight[~held])
    np.testing.assert_array_equal(censored.observed[~held], exact.observed[~held])
    # A censored red value is a lower bound: at most the truth and at most the ceiling.
    ceiling = np.array(ceilings, np.float32)[None, :].repeat(len(held), axis=0)
    assert np.all(censored.observed[held & counted, 0] <= exact.observed[held & counted, 0] + 1e-6)
    assert np.all(censored.observed[held, 0] <= ceiling[held] * (1 + 1e-6))
    # Green and blue of a censored sample are exact.
    np.testing.assert_array_equal(censored.observed[held & counted, 1:], exact.observed[held & counted, 1:])


def test_imputed_channels_recover_the_base_colour_that_dropping_them_loses(captures):
    clean, clipped, _ = captures
    reference = pipeline.fit(load(clean), CONFIG).estimate
    observations = observe(load(clipped), CONFIG)
    dropped = estimate(observations, CONFIG)  # the exact samples alone
    dropped, _ = whole_surface(observations, dropped, observations.texels, CONFIG)
    imputed = impute_censored(observations, dropped.principled(), CONFIG)
    held = observations.censored.any(axis=2) & (observations.censored_weight > 0)
    assert imputed.censored_weight is None and np.all(imputed.weight[held] > 0)
    assert np.all(imputed.observed[held, 0] >= observations.observed[held, 0])  # never below its bound
    np.testing.assert_array_equal(imputed.observed[~held], observations.observed[~held])

    fitted = pipeline.fit(load(clipped), CONFIG)
    assert "censored" in fitted.timings and 0.01 < fitted.censored_fraction < 1.0
    assert any("clipped" in line for line in fitted.warnings)
    again = pipeline.fit(load(clipped), CONFIG)  # deterministic, bit for bit
    for name in ("base_color", "roughness", "metallic"):
        np.testing.assert_array_equal(getattr(again.maps, name), getattr(fitted.maps, name))
    rows = held.any(axis=1)
    error_dropped = np.abs(dropped.base_color[rows] - reference.base_color[rows]).mean()
    error_imputed = np.abs(fitted.estimate.base_color[rows] - reference.base_color[rows]).mean()
    assert error_imputed < 0.8 * error_dropped, (error_imputed, error_dropped)
