"""The fit pipeline's API (fit, write_fit, load_fit, evaluate_fit) and the sparsification maths."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from freqbrdf import pipeline, sparsification
from freqbrdf.capture import load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.errors import InputError
from freqbrdf.materials import MaterialMaps
from freqbrdf.relight import RelightSettings
from freqbrdf.synth import SynthSettings, synthesize
from freqbrdf.uncertainty import FLAG_UNOBSERVED

TINY = SynthSettings(mesh="bunny", views=6, resolution=40, spp=4, texture_res=32, test_views=2, test_envmaps=1)
NO_LPIPS = RelightSettings(spp=2, lpips=False)  # LPIPS is tested in test_metrics; here it would only cost seconds


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory):
    return synthesize(tmp_path_factory.mktemp("capture") / "tiny", TINY, progress=False)


# --- sparsification ---------------------------------------------------------------------------


def test_sparsification_of_a_perfect_ranking_equals_the_oracle():
    error = np.array([0.4, 0.1, 0.3, 0.2])
    result = sparsification.sparsification(uncertainty=error * 10, error=error, steps=5, max_fraction=0.75)
    np.testing.assert_allclose(result.by_uncertainty, result.oracle)
    assert result.ause == pytest.approx(0.0) and result.spearman == pytest.approx(1.0)
    # Hand-computed: f = 0, 0.1875, 0.375, 0.5625, 0.75 removes floor(4 f) = 0, 0, 1, 2, 3 texels,
    # leaving means 0.25, 0.25, 0.2, 0.15, 0.1 of a full mean 0.25.
    np.testing.assert_allclose(result.oracle, [1.0, 1.0, 0.8, 0.6, 0.4])
    assert result.aurg == pytest.approx(0.1875 * (0.0 + 0.0 + 0.2 + 0.4 + 0.6 / 2))


def test_sparsification_of_an_imperfect_ranking_matches_hand_computed_scores():
    error = np.array([0.4, 0.1, 0.3, 0.2])
    uncertainty = np.array([3.0, 4.0, 2.0, 1.0])  # removes the errors 0.1, 0.4, 0.3, 0.2 in turn
    result = sparsification.sparsification(uncertainty, error, steps=5, max_fraction=0.75)
    # Kept means after removing 0, 0, 1, 2, 3 texels: 0.25, 0.25, 0.3, 0.25, 0.2 (divided by 0.25).
    np.testing.assert_allclose(result.by_uncertainty, [1.0, 1.0, 1.2, 1.0, 0.8])
    # Trapezoids of width 0.1875: curve - oracle = 0, 0, 0.4, 0.4, 0.4; random - curve = 0, 0, -0.2, 0, 0.2.
    assert result.ause == pytest.approx(0.1875 * (0.4 + 0.4 + 0.4 / 2))
    assert result.aurg == pytest.approx(0.1875 * (-0.2 + 0.0 + 0.2 / 2))
    # Ranks (3, 4, 2, 1) against (4, 1, 3, 2): sum d^2 = 12, rho = 1 - 6 * 12 / (4 * 15).
    assert result.spearman == pytest.approx(-0.2)


def test_sparsification_of_a_reversed_ranking_is_worse_than_random():
    error = np.linspace(0.0, 1.0, 101)
    result = sparsification.sparsification(uncertainty=-error, error=error)
    assert result.aurg < 0 and result.ause > 0 and result.spearman == pytest.approx(-1.0)


def test_sparsification_ignores_non_finite_entries_and_checks_lengths():
    result = sparsification.sparsification(np.array([1.0, np.nan, 2.0]), np.array([0.1, 0.5, np.inf]))
    assert result.texels == 1
    with pytest.raises(ValueError):
        sparsification.sparsification(np.ones(3), np.ones(4))


def test_evaluation_scores_the_entropy_and_roughness_std_on_the_same_texels(tmp_path):
    # 8 x 8 texels, every one in the atlas; roughness errors grow with the texel index. roughness_std
    # ranks them perfectly (its one unestimated texel takes the prior's std, above every other, and
    # has the largest error); the entropy ranks them backwards; unobserved texels are left out.
    size, rng = 8, np.random.default_rng(0)
    n_texels = size * size
    error = np.linspace(0.01, 0.5, n_texels)
    truth = MaterialMaps(rng.random((size, size, 3)).astype(np.float32),
                         rng.random((size, size)).astype(np.float32) * 0.4, np.zeros((size, size), np.float32))
    estimated = MaterialMaps(truth.base_color, (truth.roughness.ravel() + error).reshape(size, size).astype(np.float32),
                             truth.metallic)
    spread = (error * 0.5).astype(np.float32)
    spread[-1] = np.nan  # not estimated
    flags = np.zeros(n_texels, np.uint8)
    flags[:4] = FLAG_UNOBSERVED
    arrays = {"texel_index": np.arange(n_texels), "flags": flags, "roughness_std": spread,
              "entropy": np.linspace(1.0, 0.0, n_texels).astype(np.float32)}
    outputs = pipeline.FitOutputs(tmp_path, {}, estimated, None, np.ones((size, size), bool), arrays["texel_index"], arrays)
    scores = pipeline._uncertainty_scores(outputs, SimpleNamespace(ground_truth=truth), tmp_path)

    by_spread, by_entropy = scores["roughness_std"]["roughness"], scores["roughness"]
    assert by_spread["texels"] == by_entropy["texels"] == n_texels - 4
    assert by_spread["spearman"] == pytest.approx(1.0) and by_spread["ause"] == pytest.approx(0.0, abs=1e-9)
    assert by_entropy["spearman"] == pytest.approx(-1.0) and by_entropy["aurg"] < 0 < by_spread["aurg"]
    assert set(scores["roughness_std"]) == {"roughness", "base_color", "metallic"}
    assert (tmp_path / pipeline.SPARSIFICATION_PLOT).is_file()
    # A fit without roughness_std (older, or turned off) is scored on the entropy alone.
    del arrays["roughness_std"]
    assert "roughness_std" not in pipeline._uncertainty_scores(outputs, SimpleNamespace(ground_truth=truth), tmp_path)


# --- the pipeline -----------------------------------------------------------------------------


@pytest.mark.slow
def test_fit_writes_a_complete_folder_that_loads_back(tiny_capture, tmp_path, monkeypatch):
    config = Config(texels=TexelConfig(texture_res=32))
    result = pipeline.fit(load(tiny_capture), config)
    assert {"observe", "estimate", "uncertainty", "textures", "total"} <= set(result.timings)
    folder = pipeline.write_fit(tmp_path / "fit", result, config)
    outputs = pipeline.load_fit(folder)
    assert outputs.capture_path == tiny_capture.resolve()
    np.testing.assert_allclose(outputs.maps.roughness, result.maps.roughness)
    np.testing.assert_array_equal(outputs.arrays["flags"], result.uncertainty.flags)
    assert outputs.arrays["likelihood"].shape == (result.observations.n_texels, *result.uncertainty.likelihood.shape[1:])
    assert outputs.observed.sum() == np.count_nonzero(result.observations.n_samples)
    assert "write" in outputs.summary["timings"]
    scene = trimesh.load(folder / "material.glb")
    assert len(scene.geometry) == 1

    # The evaluation folder appears whole or not at all: a failing last step keeps the old one.
    evaluation = folder / pipeline.EVALUATION_FOLDER
    document = pipeline.evaluate_fit(outputs, load(tiny_capture), settings=NO_LPIPS)
    assert document["uncertainty"]["roughness"]["texels"] == np.count_nonzero(result.observations.n_samples)
    np.testing.assert_array_equal(outputs.arrays["roughness_std"], result.uncertainty.roughness_std)
    spread_scores = document["uncertainty"]["roughness_std"]
    assert spread_scores["roughness"]["texels"] == document["uncertainty"]["roughness"]["texels"]
    assert all(np.isfinite(spread_scores[kind]["aurg"]) for kind in ("roughness", "base_color", "metallic"))
    before = (evaluation / "metrics.json").read_bytes()

    def failing_plot(*_):
        raise RuntimeError("plot failed")

    with monkeypatch.context() as patch, pytest.raises(RuntimeError, match="plot failed"):
        patch.setattr(sparsification, "plot", failing_plot)
        pipeline.evaluate_fit(outputs, load(tiny_capture), settings=NO_LPIPS)
    assert (evaluation / "metrics.json").read_bytes() == before
    assert not [p.name for p in folder.iterdir() if p.name.startswith(".")]  # no temporary left


@pytest.mark.slow
def test_outputs_never_replace_their_inputs(tiny_capture, tmp_path):
    config = Config(texels=TexelConfig(texture_res=8))
    capture = load(tiny_capture)
    result = pipeline.fit(capture, config)
    files_before = sorted(p.name for p in tiny_capture.iterdir())
    for out in (tiny_capture, tiny_capture.parent):
        with pytest.raises(InputError, match="would replace the capture"):
            pipeline.write_fit(out, result, config)
    assert sorted(p.name for p in tiny_capture.iterdir()) == files_before

    folder = pipeline.write_fit(tmp_path / "fit", result, config)
    with pytest.raises(InputError, match="would replace the fit"):
        pipeline.evaluate_fit(pipeline.load_fit(folder), capture, out_dir=folder)
    assert json.loads((folder / "summary.json").read_text())["capture"] == str(tiny_capture.resolve())


def test_load_fit_names_what_is_missing(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        pipeline.load_fit(tmp_path / "nowhere")
    with pytest.raises(InputError, match="summary.json.*not a fit folder"):
        pipeline.load_fit(tmp_path)
    (tmp_path / "summary.json").write_text("[1, 2]")
    with pytest.raises(InputError, match="JSON object"):
        pipeline.load_fit(tmp_path)
