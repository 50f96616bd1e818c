"""Relighting evaluation on a tiny synthetic capture: the ground-truth material must score high."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image

from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.estimate import estimate
from freqbrdf.model.materials import MaterialMaps, load_material_maps
from freqbrdf.observe.observations import observe
from freqbrdf.outputs import export, relight
from freqbrdf.synthetic.synth import SynthSettings, synthesize
from freqbrdf.uncertainty import entropy_map

pytestmark = pytest.mark.slow  # renders with Mitsuba

RESOLUTION = 40
TEXTURE_RES = 64
SPP = 32


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    settings = SynthSettings(
        mesh="sphere", materials="bands", views=6, resolution=RESOLUTION, spp=SPP,
        texture_res=TEXTURE_RES, test_views=2, test_envmaps=1, seed=3,
    )
    return load(synthesize(tmp_path_factory.mktemp("relight") / "capture", settings, progress=False))


def constant_material(base_color: float, roughness: float, metallic: float) -> MaterialMaps:
    shape = (TEXTURE_RES, TEXTURE_RES)
    return MaterialMaps(
        np.full(shape + (3,), base_color, np.float32),
        np.full(shape, roughness, np.float32),
        np.full(shape, metallic, np.float32),
    )


def test_ground_truth_material_relights_far_better_than_a_grey_one(capture, tmp_path):
    settings = relight.RelightSettings(spp=SPP, lpips=False, seed=11)  # other noise than the reference
    observed = np.ones((TEXTURE_RES, TEXTURE_RES), bool)
    truth = relight.evaluate(capture, capture.ground_truth, observed, settings)
    grey = relight.evaluate(capture, constant_material(0.5, 0.5, 0.0), observed, settings)

    assert [view.index for view in truth.views] == [0, 1]
    # Only Monte Carlo noise separates the ground truth's renders from the references: on the
    # right conventions (UVs, cameras, light) it beats a plausible grey material by a wide margin.
    assert truth.relighting["psnr_hdr"] > grey.relighting["psnr_hdr"] + 6.0
    assert truth.relighting["psnr_ldr"] > 25.0 and truth.relighting["psnr_ldr"] > grey.relighting["psnr_ldr"] + 6.0
    assert truth.relighting["ssim"] > grey.relighting["ssim"]
    for view in truth.views:  # the least-squares scale is ~1: the renderer and light agree
        np.testing.assert_allclose(view.scores["scale"], 1.0, atol=0.1)
    assert truth.texture["base_color_psnr"] == math.inf and truth.texture["roughness_mae"] == 0.0
    assert grey.texture["roughness_mae"] > 0.1

    metrics_path = relight.write_evaluation(tmp_path / "eval", truth)
    document = json.loads(metrics_path.read_text())  # strict JSON: inf was written as null
    assert document["texture"]["base_color_psnr"] is None
    assert document["relighting"]["psnr_hdr"] == pytest.approx(truth.relighting["psnr_hdr"])
    assert [view["lpips_skipped"] for view in document["views"]] == ["not requested"] * 2
    comparison = Image.open(tmp_path / "eval" / document["views"][0]["comparison"])
    assert comparison.size == (3 * RESOLUTION, RESOLUTION)


def test_relight_views_subset_and_bad_index(capture):
    settings = relight.RelightSettings(spp=4, lpips=False, views=(1,))
    views = relight.relight_views(capture, constant_material(0.8, 0.3, 1.0), settings)
    assert [view.index for view in views] == [1]
    assert views[0].relit.shape == (RESOLUTION, RESOLUTION, 3)
    with pytest.raises(ValueError, match="does not exist"):
        relight.relight_views(capture, capture.ground_truth, relight.RelightSettings(views=(2,)))


def test_fit_outputs_and_evaluation_of_a_real_fit(capture, tmp_path):
    """The whole chain on real Observations: observe, estimate, entropy, export, evaluate."""
    config = Config(texels=TexelConfig(texture_res=32, dilation_px=2))
    observations = observe(capture, config)
    fit = estimate(observations, config)
    uncertainty = entropy_map(observations, config.uncertainty)
    out = export.write_fit_outputs(tmp_path / "fit", capture.mesh, observations, fit, uncertainty, config,
                                   timings=fit.timings)

    summary = json.loads((out / "summary.json").read_text())
    observed = observations.n_samples > 0
    assert summary["coverage"]["views"] == len(capture.frames)
    assert summary["coverage"]["observed_fraction"] == pytest.approx(observed.mean())
    assert summary["coverage"]["mean_views_per_texel"] == pytest.approx(observations.n_samples.mean())
    maps = load_material_maps(out)
    assert np.isfinite(maps.base_color).all()
    roughness = maps.roughness.reshape(-1)[observations.texel_index]
    np.testing.assert_allclose(roughness[fit.estimated], fit.roughness[fit.estimated], atol=1e-6)

    evaluation = relight.evaluate(capture, maps, observations.to_texture(observed, False),
                                  relight.RelightSettings(spp=8, lpips=False))
    assert evaluation.texture["texels"] == int(observed.sum())
    assert all(math.isfinite(evaluation.relighting[key]) for key in ("psnr_hdr", "psnr_ldr", "ssim"))
