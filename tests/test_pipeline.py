"""The fit pipeline's API (fit, write_fit, load_fit, evaluate_fit) and the sparsification maths."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from freqbrdf import pipeline
from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, FitConfig, TexelConfig, UncertaintyConfig, preset
from freqbrdf.errors import InputError
from freqbrdf.fileio import OUTPUT_MARKER
from freqbrdf.model.materials import MaterialMaps
from freqbrdf.outputs import sparsification
from freqbrdf.outputs.evaluate import _uncertainty_scores, evaluate_fit
from freqbrdf.outputs.fit_folder import (
    EVALUATION_FOLDER,
    SPARSIFICATION_PLOT,
    FitOutputs,
    load_fit,
)
from freqbrdf.outputs.relight import RelightSettings
from freqbrdf.synthetic.synth import SynthSettings, synthesize
from freqbrdf.uncertainty import FLAG_UNOBSERVED
from freqbrdf.uncertainty.trust import trusted_texels

TINY = SynthSettings(mesh="bunny", views=6, resolution=40, spp=4, texture_res=32, test_views=2, test_envmaps=1)
NO_LPIPS = RelightSettings(spp=2, lpips=False)  # LPIPS is tested in test_metrics; here it would only cost seconds


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory):
    return synthesize(tmp_path_factory.mktemp("capture") / "tiny", TINY, progress=False)


# --- sparsification ---------------------------------------------------------------------------


def test_fit_refuses_degree_zero_before_any_work():
    # The entropy compares degrees 1..l*: refused before the capture is even read.
    with pytest.raises(ValueError, match="lmax >= 1"):
        pipeline.fit(None, Config(fit=FitConfig(lmax=0)))


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
    outputs = FitOutputs(tmp_path, {}, estimated, None, np.ones((size, size), bool), arrays["texel_index"], arrays)
    scores = _uncertainty_scores(outputs, SimpleNamespace(ground_truth=truth), tmp_path)

    by_spread, by_entropy = scores["roughness_std"]["roughness"], scores["roughness"]
    assert by_spread["texels"] == by_entropy["texels"] == n_texels - 4
    assert by_spread["spearman"] == pytest.approx(1.0) and by_spread["ause"] == pytest.approx(0.0, abs=1e-9)
    assert by_entropy["spearman"] == pytest.approx(-1.0) and by_entropy["aurg"] < 0 < by_spread["aurg"]
    assert set(scores["roughness_std"]) == {"roughness", "base_color", "metallic"}
    assert (tmp_path / SPARSIFICATION_PLOT).is_file()
    # A fit without roughness_std (older, or turned off) is scored on the entropy alone.
    del arrays["roughness_std"]
    assert "roughness_std" not in _uncertainty_scores(outputs, SimpleNamespace(ground_truth=truth), tmp_path)


# --- the pipeline -----------------------------------------------------------------------------


@pytest.mark.slow
def test_fit_writes_a_complete_folder_that_loads_back(tiny_capture, tmp_path, monkeypatch):
    config = Config(texels=TexelConfig(texture_res=32))
    result = pipeline.fit(load(tiny_capture), config)
    assert {"observe", "estimate", "uncertainty", "textures", "total"} <= set(result.timings)
    folder = pipeline.write_fit(tmp_path / "fit", result, config)
    outputs = load_fit(folder)
    assert outputs.capture_path == tiny_capture.resolve()
    np.testing.assert_allclose(outputs.maps.roughness, result.maps.roughness)
    np.testing.assert_array_equal(outputs.arrays["flags"], result.uncertainty.flags)
    assert outputs.arrays["likelihood"].shape == (result.observations.n_texels, *result.uncertainty.likelihood.shape[1:])
    assert outputs.observed.sum() == np.count_nonzero(result.observations.n_samples)
    assert "write" in outputs.summary["timings"]
    # The held-out std calibration (on by default): its factors and coverage in summary.json.
    calibration = outputs.summary["std_calibration"]
    assert calibration == json.loads(json.dumps(result.std_calibration.to_dict()))
    assert calibration["folds"] == config.uncertainty.heldout_folds and calibration["texels"] > 0
    assert set(calibration["factors"]) == {"roughness", "base_color"}
    assert all(np.isfinite(factor) and factor >= 1.0 for factor in calibration["factors"].values())
    assert "std_calibration" in result.timings
    # The trust mask: every std at most the threshold, as the summary counts it.
    trusted = trusted_texels(result.uncertainty, config.uncertainty.trust_std)
    assert outputs.summary["trust"]["threshold"] == config.uncertainty.trust_std
    assert outputs.summary["trust"]["trusted_fraction"] == pytest.approx(trusted.mean())
    np.testing.assert_array_equal(outputs.trust, result.estimate.to_texture(trusted, fill=False).astype(bool))
    assert trusted_texels(result.uncertainty, 1.0).sum() >= trusted.sum() >= trusted_texels(result.uncertainty, 1e-6).sum()
    scene = trimesh.load(folder / "material.glb")
    assert len(scene.geometry) == 1

    # The evaluation folder appears whole or not at all: a failing last step keeps the old one.
    evaluation = folder / EVALUATION_FOLDER
    document = evaluate_fit(outputs, load(tiny_capture), settings=NO_LPIPS)
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
        evaluate_fit(outputs, load(tiny_capture), settings=NO_LPIPS)
    assert (evaluation / "metrics.json").read_bytes() == before
    assert [p.name for p in folder.iterdir() if p.name.startswith(".")] == [OUTPUT_MARKER]  # no temporary left


@pytest.mark.slow
def test_the_held_out_std_calibration_is_deterministic_and_only_widens(tiny_capture):
    """Two fits of one capture calibrate the std maps bit for bit alike; the calibration only widens them."""
    config = Config(texels=TexelConfig(texture_res=16))
    first, second = pipeline.fit(load(tiny_capture), config), pipeline.fit(load(tiny_capture), config)
    assert first.std_calibration.to_dict() | {"seconds": 0} == second.std_calibration.to_dict() | {"seconds": 0}
    for name in ("roughness_std", "metallic_std", "base_color_std"):
        np.testing.assert_array_equal(getattr(first.uncertainty, name), getattr(second.uncertainty, name))
    off = pipeline.fit(load(tiny_capture), config.replace(uncertainty=UncertaintyConfig(heldout_folds=0)))
    assert off.std_calibration is None and "std_calibration" not in off.timings
    np.testing.assert_array_equal(off.uncertainty.metallic_std, first.uncertainty.metallic_std)
    for name in ("roughness", "base_color"):
        factor = first.std_calibration.factors[name]
        assert factor >= 1.0
        np.testing.assert_allclose(getattr(first.uncertainty, f"{name}_std"),
                                   getattr(off.uncertainty, f"{name}_std") * factor, rtol=1e-6)


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
        evaluate_fit(load_fit(folder), capture, out_dir=folder)
    assert json.loads((folder / "summary.json").read_text())["capture"] == str(tiny_capture.resolve())


def test_load_fit_names_what_is_missing(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        load_fit(tmp_path / "nowhere")
    with pytest.raises(InputError, match="summary.json.*not a fit folder"):
        load_fit(tmp_path)
    (tmp_path / "summary.json").write_text("[1, 2]")
    with pytest.raises(InputError, match="JSON object"):
        load_fit(tmp_path)


# --- estimation on coarser texels ------------------------------------------------------------


def _unit_square():
    from freqbrdf.capture.mesh import Mesh

    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
    return Mesh(vertices=vertices, faces=np.array([[0, 1, 2], [0, 2, 3]]),
                normals=np.tile([0.0, 0.0, 1.0], (4, 1)), uv=vertices[:, :2].copy())


@pytest.mark.parametrize("texture_res, focal, pixel, coarse", [
    (64, 64.0, 64, 64),  # a pixel is a texel wide: every texel is resolved
    (64, 200.0, 64, 64),  # pixels finer than texels
    (64, 32.0, 32, 32),  # two texels a pixel: one level coarser, texels exactly a pixel wide
    (64, 25.0, 32, 16),  # 2.56 texels a pixel: still no wider than a pixel / at least a pixel wide
    (100, 100 / 3, 50, 25),  # three texels a pixel at T = 100: ceil(100 / 2), ceil(100 / 4)
])
def test_estimation_resolution_by_texels_per_pixel(texture_res, focal, pixel, coarse):
    from freqbrdf.texels import estimation_resolution, rasterise

    texels = rasterise(_unit_square(), texture_res)
    # The closest camera, 1 from the square's centre, decides; a farther one does not matter.
    centres = np.array([[0.5, 0.5, 1.0], [0.5, 0.5, 5.0]])
    focal_px = np.array([focal, focal])
    assert estimation_resolution(texels, centres, focal_px) == pixel  # "pixel" by default
    assert estimation_resolution(texels, centres, focal_px, "coarse") == coarse
    assert estimation_resolution(texels, np.zeros((0, 3)), np.zeros(0)) == texture_res
    with pytest.raises(ValueError, match="rule must be"):
        estimation_resolution(texels, centres, focal_px, "auto")


def test_to_texels_samples_the_maps_bilinearly_and_takes_the_rest_from_the_parent_texel():
    """A coarse 4 x 4 fit with an affine roughness and a missing texel, taken to 8 x 8 texels."""
    from dataclasses import replace as replaced

    from freqbrdf.sphere import harmonics as sh
    from freqbrdf.texels import rasterise
    from freqbrdf.uncertainty import entropy_map
    from uncertainty.test_uncertainty import LMAX, _estimate_of, _observations_from_spectra

    coarse_index = np.array([i for i in range(16) if i != 5])  # texel (1, 1) not covered
    rows, columns = np.divmod(coarse_index, 4)
    n = len(coarse_index)
    light = np.tile(np.linspace(1.0, 0.1, LMAX + 1), (n, 3, 1))
    observations = _observations_from_spectra(light, 0.5 * light, coarse_index, texture_res=4)
    observations = replaced(observations, n_samples=np.arange(n, dtype=np.int32) + 10,
                            fit_status=np.where(coarse_index == 15, sh.FIT_EMPTY, sh.FIT_OK).astype(np.uint8))
    roughness = 0.1 + 0.05 * rows + 0.02 * columns
    estimated = coarse_index != 15  # the last texel has no estimate
    estimate = _estimate_of(observations, roughness, estimated)
    uncertainty = entropy_map(observations)
    uncertainty.roughness_std = np.where(estimated, 0.1, np.nan).astype(np.float32)

    fine = rasterise(_unit_square(), 8)
    fine_observations, fine_estimate, fine_uncertainty = pipeline.to_texels(
        observations, estimate, uncertainty, fine, dilation_px=2)
    assert fine_estimate.texture_res == fine_observations.texture_res == 8
    np.testing.assert_array_equal(fine_estimate.texel_index, fine.texel_index)
    assert fine_observations.n_views == 0 and fine_observations.n_texels == fine.n_texels

    fine_rows, fine_columns = np.divmod(fine.texel_index, 8)
    parent_flat = (fine_rows // 2) * 4 + fine_columns // 2
    parent = np.searchsorted(coarse_index, parent_flat)
    own = np.isin(parent_flat, coarse_index)
    # The fine texels of the uncovered coarse texel (1, 1) take a covered neighbour's fields.
    assert (~own).sum() == 4
    for name in ("n_samples", "fit_status"):
        np.testing.assert_array_equal(getattr(fine_observations, name)[own], getattr(observations, name)[parent[own]])
    np.testing.assert_array_equal(fine_uncertainty.flags[own], uncertainty.flags[parent[own]])
    assert np.all(fine_observations.n_samples[~own] > 0)
    # The SH coefficients stay with the coarse texels; their spectra come along.
    assert fine_observations.observed_coeffs.shape == (fine.n_texels, 3, 0)
    for name in ("observed_spectrum", "mirrored_spectrum"):
        np.testing.assert_array_equal(getattr(fine_observations, name)[own], getattr(observations, name)[parent[own]])
    # Bilinear reproduces the affine roughness wherever the four coarse texels around a fine
    # centre are estimated texels: between the coarse centres, away from (1, 1) and (3, 3).
    y = (fine_rows + 0.5) / 2 - 0.5
    x = (fine_columns + 0.5) / 2 - 0.5
    inside = (y >= 0) & (y <= 3) & (x >= 0) & (x <= 3)
    clear = inside & ~((y < 2) & (x < 2) & (y > 0) & (x > 0)) & ~((y > 2) & (x > 2))
    assert clear.sum() >= 10
    np.testing.assert_allclose(fine_estimate.roughness[clear], (0.1 + 0.05 * y + 0.02 * x)[clear], atol=1e-12)
    # Not estimated where the parent is not; the entropy of an unobserved texel stays the prior's.
    unestimated = parent_flat == 15
    assert np.all(np.isnan(fine_estimate.roughness[unestimated])) and not fine_estimate.estimated[unestimated].any()
    assert np.all(np.isnan(fine_uncertainty.roughness_std[unestimated]))
    # roughness_std as exported: the unestimated texel's prior std blends into its neighbours.
    from freqbrdf.outputs.export import UNESTIMATED_ROUGHNESS_STD

    beside = (y > 2) & (x > 2) & ~unestimated
    np.testing.assert_allclose(fine_uncertainty.roughness_std[~unestimated & ~beside], 0.1, atol=1e-6)
    assert np.all((fine_uncertainty.roughness_std[beside] > 0.1)
                  & (fine_uncertainty.roughness_std[beside] < UNESTIMATED_ROUGHNESS_STD))
    assert np.all(fine_uncertainty.entropy[unestimated] == 1.0)


@pytest.mark.slow
def test_fit_on_coarser_texels_writes_t_by_t_maps_that_load_and_evaluate(tiny_capture, tmp_path):
    config = Config(texels=TexelConfig(texture_res=32, estimation_res=16))
    capture = load(tiny_capture)
    result = pipeline.fit(capture, config)
    assert result.estimation_res == 16 and "upsample" in result.timings
    assert result.estimate.texture_res == 32 and result.maps.resolution == 32
    assert result.uncertainty.entropy.shape == (result.estimate.n_texels,)
    folder = pipeline.write_fit(tmp_path / "fit", result, config)
    outputs = load_fit(folder)
    assert outputs.summary["estimation_res"] == 16
    coverage = outputs.summary["coverage"]
    assert coverage["views"] == len(capture.frames) and coverage["texture_res"] == 32
    assert outputs.observed.sum() == np.count_nonzero(result.observations.n_samples)
    document = evaluate_fit(outputs, capture, settings=NO_LPIPS)
    assert document["texture"]["texels"] == outputs.observed.sum()
    # The rules on this capture (40-pixel images): what the images resolve, whatever T above it.
    def automatic(texture_res, rule):
        return pipeline.estimation_resolution(capture, Config(texels=TexelConfig(texture_res, estimation_res=rule)))

    assert automatic(64, "pixel") == automatic(128, "pixel") == automatic(512, "pixel") == 64
    assert automatic(32, "coarse") == automatic(128, "coarse") == automatic(512, "coarse") == 32
    assert automatic(16, "pixel") == automatic(16, "coarse") == 16
    assert pipeline.estimation_resolution(capture, Config(texels=TexelConfig(512))) == 64  # the default: pixel
    assert preset("paper").texels.estimation_res == "full" and preset("fast").texels.estimation_res == "coarse"
    with pytest.raises(ValueError, match="estimation_res must be"):
        pipeline.estimation_resolution(capture, Config(texels=TexelConfig(texture_res=32, estimation_res=64)))


def test_fit_takes_the_angular_entropy_from_the_estimators_search(tiny_capture, monkeypatch):
    """With the angular mode, `fit` scores the hypotheses during the estimator's search instead of
    in a pass of its own: the same entropy and likelihood as that pass on the fit's observations,
    and the same estimate as a fit with the default entropy."""
    from freqbrdf import uncertainty as unc

    config = Config(texels=TexelConfig(texture_res=32, estimation_res="full"),
                    uncertainty=UncertaintyConfig(mode="angular"))
    capture = load(tiny_capture)
    passes = []
    monkeypatch.setattr(unc, "entropy_angular", lambda *args, **kwargs: passes.append(args))
    monkeypatch.setattr(pipeline, "entropy_map", lambda *args, **kwargs: passes.append(args))
    result = pipeline.fit(capture, config)
    assert not passes  # no pass of its own
    monkeypatch.undo()
    alone = unc.entropy_map(result.observations, config.uncertainty, estimate_config=config.estimate)
    assert result.uncertainty.mode == "angular" and result.uncertainty.grid.resolution == 9
    np.testing.assert_allclose(result.uncertainty.entropy, alone.entropy, atol=1e-6)
    np.testing.assert_allclose(result.uncertainty.likelihood, alone.likelihood, atol=1e-6)
    default = pipeline.fit(capture, config.replace(uncertainty=UncertaintyConfig()))
    np.testing.assert_array_equal(result.estimate.roughness, default.estimate.roughness)
    np.testing.assert_array_equal(result.estimate.base_color, default.estimate.base_color)


@pytest.mark.slow
def test_a_fit_of_a_mesh_that_cannot_hide_itself_loads_no_ray_tracer(tmp_path):
    """A convex mesh casts no shadow rays: the fit, in a fresh interpreter, never imports Mitsuba."""
    from freqbrdf.synthetic import example_capture

    capture = example_capture(tmp_path / "capture")  # a sphere
    code = ("import sys; from freqbrdf import pipeline; from freqbrdf.capture import load; "
            "from freqbrdf.config import Config, TexelConfig; "
            f"pipeline.fit(load({str(capture)!r}), Config(texels=TexelConfig(texture_res=32))); "
            "print(sorted({name.split('.')[0] for name in sys.modules} & {'mitsuba', 'drjit'}))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]"


def test_photographs_much_brighter_than_the_map_are_named(tiny_capture):
    # Six views: too few for the gains (the map's scale is kept); at 4x the map's exposure most base
    # colours reach their bound, and the fit says what that suggests.
    capture = load(tiny_capture)
    config = Config(texels=TexelConfig(texture_res=32))
    clean = pipeline.fit(capture, config)
    bright = pipeline.fit(replace(capture, frames=tuple(replace(frame, exposure=4.0) for frame in capture.frames)), config)
    assert not any("reached its bound" in line for line in clean.warnings)
    assert any("reached its bound" in line and "exposure" in line for line in bright.warnings)
    assert any("too few" in line for line in bright.warnings)  # and why the gains did not correct it


def test_overlapping_uv_charts_are_named(tiny_capture):
    # The bunny with its UV layout folded onto its left half: the right half's faces land on texels
    # the left half's already hold.
    capture = load(tiny_capture)
    config = Config(texels=TexelConfig(texture_res=32))
    assert not any("overlapping" in line for line in pipeline.fit(capture, config).warnings)
    uv = np.asarray(capture.mesh.uv, np.float64).copy()
    uv[:, 0] = np.where(uv[:, 0] < 0.5, uv[:, 0], 1.0 - uv[:, 0])
    folded = replace(capture, mesh=replace(capture.mesh, uv=uv))
    assert any("overlapping or mirrored UV charts" in line for line in pipeline.fit(folded, config).warnings)
