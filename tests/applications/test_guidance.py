"""Capture guidance (freqbrdf.applications.guidance, `freqbrdf next-views`).

The incremental fit and the candidate scoring are checked against fits from scratch
(`sh.fit_sh`) on synthetic samples; the choice of views on a small Mitsuba-rendered sphere whose
cameras all look from above, so that its lower half is unobserved.
"""

import dataclasses
import json
import shutil

import numpy as np
import pytest

from freqbrdf import pipeline
from freqbrdf.applications import guidance
from freqbrdf.applications.candidates import (
    CandidateSamples,
    candidate_samples,
    farthest_point_views,
    sample_candidates,
    view_directions,
)
from freqbrdf.capture.camera import look_at
from freqbrdf.capture.camera_layouts import bounding_sphere
from freqbrdf.capture.layouts import Frame, load, write_transforms
from freqbrdf.config import Config, FitConfig, TexelConfig
from freqbrdf.fileio import OUTPUT_MARKER
from freqbrdf.model import brdf
from freqbrdf.observe.observations import Observations
from freqbrdf.sphere import harmonics as sh
from freqbrdf.synthetic.synth import SynthSettings, synthesize
from freqbrdf.uncertainty import entropy_from_spectra
from helpers import observations_from_samples

LMAX = 3


def synthetic_observations(rng, n_texels=12, n_views=20, lmax=LMAX, sigma=0.25) -> Observations:
    """Random samples on the upper hemisphere, some missing; texel 0 has none, texel 1 only three."""
    directions = rng.normal(size=(n_texels, n_views, 3))
    directions[..., 2] = np.abs(directions[..., 2]) + 0.05
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    weight = directions[..., 2] * (rng.random((n_texels, n_views)) > 0.3)
    weight[0] = 0.0
    weight[1, 3:] = 0.0
    mirrored = rng.uniform(0.0, 2.0, (n_texels, n_views, 3))
    observed = 0.3 * mirrored + rng.uniform(0.0, 0.2, (n_texels, n_views, 3))
    return observations_from_samples(directions, weight, observed, mirrored, lmax, sigma=sigma, texture_res=4)


def new_view(rng, texels, lmax=LMAX) -> tuple[CandidateSamples, np.ndarray]:
    """A candidate's samples at ``texels``, and their local view directions (n, 3)."""
    directions = rng.normal(size=(len(texels), 3))
    directions[:, 2] = np.abs(directions[:, 2]) + 0.1
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    samples = CandidateSamples(
        texel=np.asarray(texels), weight=directions[:, 2], basis=sh.eval_sh(directions, lmax),
        light=rng.uniform(0.0, 2.0, (len(texels), 3)),
    )
    return samples, directions


def fit_from_scratch(observations, config, extra=None):
    """sh.fit_sh of light, observed and 1 on the observations' samples plus, per texel, the optional
    extra sample (texels, directions (n, 3), weights (n,), light (n, 3), observed (n, 3))."""
    directions = observations.view_direction
    weight = observations.weight
    values = np.concatenate([observations.mirrored, observations.observed,
                             np.ones(weight.shape + (1,))], axis=2)
    if extra is not None:
        texels, new_directions, new_weight, light, observed = extra
        n = len(weight)
        directions = np.concatenate([directions, np.tile([[[0.0, 0.0, 1.0]]], (n, 1, 1))], axis=1)
        weight = np.concatenate([weight, np.zeros((n, 1))], axis=1)
        values = np.concatenate([values, np.zeros((n, 1, 7))], axis=1)
        directions[texels, -1] = new_directions
        weight[texels, -1] = new_weight
        values[texels, -1] = np.concatenate([light, observed, np.ones((len(texels), 1))], axis=1)
    fit = config.fit
    return sh.fit_sh(directions, weight, values, fit.lmax, fit.reg_lambda, fit.regulariser,
                     fit.scale_lambda_with_weight).coeffs


FIT_VARIANTS = [
    FitConfig(lmax=LMAX),
    FitConfig(lmax=LMAX, regulariser="constant", reg_lambda=1e-3, scale_lambda_with_weight=False),
]


@pytest.mark.parametrize("fit", FIT_VARIANTS, ids=["scaled-exponential", "absolute-constant"])
def test_incremental_update_equals_a_fit_from_scratch(fit):
    rng = np.random.default_rng(1)
    config = Config(fit=fit)
    observations = synthetic_observations(rng)
    state = guidance.initial_state(observations, config)
    np.testing.assert_allclose(guidance.state_coeffs(state, config), fit_from_scratch(observations, config),
                               rtol=1e-7, atol=1e-9)

    texels = np.array([0, 1, 4, 7, 11])  # the empty texel and the nearly empty one included
    samples, directions = new_view(rng, texels)
    observed = rng.uniform(0.0, 1.0, (len(texels), 3))
    guidance.add_samples(state, samples, observed)
    expected = fit_from_scratch(observations, config, (texels, directions, samples.weight, samples.light, observed))
    np.testing.assert_allclose(guidance.state_coeffs(state, config), expected, rtol=1e-7, atol=1e-9)
    assert state.n_samples[0] == 1 and state.n_samples[2] == observations.n_samples[2]


@pytest.mark.parametrize("mode", ["calibrated", "paper"])
def test_expected_entropy_of_a_known_material_equals_the_entropy_of_the_refit(mode):
    """With the posterior on one hypothesis, the expectation is that hypothesis' simulated sample
    added to the data and the fits redone from scratch."""
    rng = np.random.default_rng(2)
    config = Config(fit=FitConfig(lmax=LMAX))
    config = config.replace(uncertainty=dataclasses.replace(config.uncertainty, mode=mode))
    observations = synthetic_observations(rng)
    state = guidance.initial_state(observations, config)
    coeffs = guidance.state_coeffs(state, config)
    texels = np.arange(observations.n_texels)
    samples, directions = new_view(rng, texels)
    alpha_index, k_index = 3, 5
    grid_res = config.uncertainty.resolution()
    likelihood = np.zeros((len(texels), grid_res, grid_res))
    likelihood[:, alpha_index, k_index] = 1.0
    expected, radiance = guidance.expected_entropy(state, coeffs, likelihood, samples, observations.sigma, config)

    # The same from scratch: the light refitted with its new sample, the hypothesis' radiance at
    # the new direction (the lobe-filtered light plus the diffuse share of the current DC, less the
    # lobe's share), the observed radiance refitted with it.
    alpha, k = (alpha_index / (grid_res - 1)) ** 2, k_index / (grid_res - 1)
    light = fit_from_scratch(observations, config, (texels, directions, samples.weight, samples.light,
                                                    np.zeros((len(texels), 3))))[:, 0:3]
    if mode == "paper":
        kernel = brdf.brdf_kernel(np.array([alpha]), LMAX)[0]
    else:
        kernel = brdf.brdf_kernel(np.array([alpha]), LMAX, observations.sigma)[0]
    filtered = np.einsum("tck,tk->tc", light * kernel[sh.sh_degrees(LMAX)], samples.basis)
    current = fit_from_scratch(observations, config)
    with np.errstate(divide="ignore", invalid="ignore"):
        diffuse = (current[:, 3:6, 0] - k * current[:, 0:3, 0]) / current[:, 6:7, 0]
    diffuse = np.where(current[:, 6:7, 0] > 0, diffuse, 0.0)
    simulated = k * filtered + np.maximum(diffuse, 0.0)
    np.testing.assert_allclose(radiance, simulated, rtol=1e-9, atol=1e-12)
    refit = fit_from_scratch(observations, config, (texels, directions, samples.weight, samples.light, simulated))
    direct = entropy_from_spectra(
        sh.power_spectrum(refit[:, 0:3]), sh.power_spectrum(refit[:, 3:6]),
        n_samples=observations.n_samples + 1, sigma=observations.sigma,
        config=config.uncertainty,
    ).entropy
    np.testing.assert_allclose(expected, direct, atol=2e-5)


def test_farthest_point_views_spread_and_extend_a_chosen_set():
    directions = np.array([[0, 0, 1], [0, 0.1, 0.995], [0, 0, -1], [1, 0, 0], [-1, 0, 0]], float)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    assert farthest_point_views(directions, 3) == [0, 2, 3]
    assert farthest_point_views(directions, 2, chosen=[0, 2]) == [3, 4]
    with pytest.raises(ValueError):
        farthest_point_views(directions, 4, chosen=[0, 2])


def test_regularisation_is_required():
    with pytest.raises(ValueError, match="regularised"):
        guidance.select_views(None, [], 1, Config(fit=FitConfig(regulariser="none")))


# --- on a rendered capture ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def sphere_from_above(tmp_path_factory):
    """A sphere photographed from six cameras above it (its lower half is never seen)."""
    settings = SynthSettings(mesh="sphere", envmap="forest", materials="bands", views=6, resolution=48, spp=4,
                             texture_res=16, cameras="hemisphere", test_views=0, seed=1)
    return load(synthesize(tmp_path_factory.mktemp("guidance") / "capture", settings, progress=False))


def below_camera(capture):
    """A camera under the object at the distance of the capture's first one, looking up at it."""
    centre, _ = bounding_sphere(capture.mesh.vertices)
    template = capture.frames[0].camera
    distance = np.linalg.norm(template.center - centre)
    pose = look_at(centre + distance * np.array([0.3, -1.0, 0.2]) / np.linalg.norm([0.3, -1.0, 0.2]), centre)
    return dataclasses.replace(template, camera_to_world=pose)


CONFIG = Config(texels=TexelConfig(texture_res=32))


@pytest.mark.slow
def test_a_view_of_the_unseen_half_beats_a_duplicate_and_lowers_the_expected_entropy(sphere_from_above):
    capture = sphere_from_above
    duplicate = capture.frames[0].camera
    candidates = [duplicate, below_camera(capture)]
    picks = guidance.select_views(capture, candidates, 2, CONFIG)
    assert [pick.candidate for pick in picks] == [1, 0]
    first = picks[0]
    assert first.expected_entropy < first.entropy_before - 0.05  # a whole unseen half becomes observed
    assert first.texels_seen > 0 and first.seconds > 0
    # The duplicate still adds a sample (and its penalty), but far less than the new half.
    assert picks[1].entropy_before - picks[1].expected_entropy < first.entropy_before - first.expected_entropy
    # The same texels and the same choice when a fit's observations are passed in.
    from freqbrdf.observe.observations import observe

    again = guidance.select_views(capture, candidates, 1, CONFIG, observations=observe(capture, CONFIG))
    assert again[0].candidate == 1
    assert again[0].expected_entropy == pytest.approx(first.expected_entropy, abs=1e-6)


@pytest.mark.slow
def test_spread_lets_only_the_candidates_far_from_the_taken_views_compete(sphere_from_above):
    capture = sphere_from_above
    candidates = sample_candidates(capture, 8)
    directions = view_directions(capture, candidates)
    taken = view_directions(capture, [frame.camera for frame in capture.frames])
    # Nearly all excluded: each pick is the candidate farthest from every view taken or picked.
    picks = guidance.select_views(capture, candidates, 3, CONFIG, max_texels=200, spread=0.99)
    closeness = (directions @ taken.T).max(axis=1)
    expected = []
    for _ in range(3):
        index = int(np.argmin(np.where(np.isin(np.arange(8), expected), np.inf, closeness)))
        expected.append(index)
        closeness = np.maximum(closeness, directions @ directions[index])
    assert [pick.candidate for pick in picks] == expected
    with pytest.raises(ValueError, match="spread"):
        guidance.select_views(capture, candidates, 1, CONFIG, spread=1.0)


@pytest.mark.slow
def test_candidate_samples_of_the_capture_cameras_are_the_observed_samples(sphere_from_above):
    """Camera-only sampling (visibility.camera_samples through guidance) agrees with `observe` on the
    views that were shot; only silhouette texels, which a photograph's mask drops, may differ."""
    from freqbrdf.observe.observations import observe
    from freqbrdf.texels import rasterise

    capture = sphere_from_above
    observations = observe(capture, CONFIG)
    texels = rasterise(capture.mesh, CONFIG.texels.texture_res)
    cameras = [frame.camera for frame in capture.frames]
    samples = candidate_samples(capture, texels, cameras, observations, LMAX)
    for view, sample in enumerate(samples):
        observed = np.flatnonzero(observations.visible[:, view])
        assert np.isin(observed, sample.texel).all()
        # The extra ones lie on the silhouette (grazing): within ~1.5 pixels of this 48-pixel
        # image's outline, where a photograph's mask drops the sample.
        extra = ~np.isin(sample.texel, observed)
        assert np.all(sample.weight[extra] < 0.4)
        rows = np.searchsorted(sample.texel, observed)
        np.testing.assert_allclose(sample.weight[rows], observations.weight[observed, view], atol=1e-5)
        np.testing.assert_allclose(sample.light[rows], observations.mirrored[observed, view], rtol=1e-4, atol=1e-5)


@pytest.mark.slow
def test_sampled_candidates_look_at_the_object_with_the_capture_intrinsics(sphere_from_above):
    capture = sphere_from_above
    cameras = sample_candidates(capture, 10, hemisphere=True)
    centre, _ = bounding_sphere(capture.mesh.vertices)
    template = capture.frames[0].camera
    for camera in cameras:
        assert (camera.fx, camera.cx, camera.width, camera.height) == (template.fx, template.cx, template.width,
                                                                        template.height)
        pixel, depth = camera.project(centre[None])
        np.testing.assert_allclose(pixel[0], [camera.cx, camera.cy], atol=1e-6)
        assert depth[0] > 0 and camera.center[1] > centre[1]
    assert len({tuple(np.round(camera.center, 6)) for camera in cameras}) == 10


@pytest.mark.slow
def test_next_views_command_writes_ranked_cameras_that_load_as_a_capture(sphere_from_above, tmp_path, run_cli, monkeypatch,
                                                                          capsys):
    capture = sphere_from_above
    candidates_file = tmp_path / "candidates.json"
    cameras = [capture.frames[0].camera, below_camera(capture)]
    write_transforms(candidates_file, [Frame(camera, tmp_path / f"unshot_{k}.exr") for k, camera in enumerate(cameras)])
    out = tmp_path / "next"
    assert run_cli("next-views", capture.root, "--candidates", candidates_file, "--budget", 2,
                   "--out", out, "--texture-res", 32, "--quiet") == 0
    assert capsys.readouterr().err == ""
    assert {path.name for path in out.iterdir()} - {OUTPUT_MARKER} == {"next_views.json", "next_views.png", "guidance.json"}
    document = json.loads((out / "next_views.json").read_text())
    assert [frame["rank"] for frame in document["frames"]] == [0, 1]
    assert document["frames"][0]["candidate"] == 1
    summary = json.loads((out / "guidance.json").read_text())
    assert summary["picks"][0]["expected_mean_entropy"] < summary["mean_entropy_before"]
    # Scored on the texels `fit` would estimate on.
    assert summary["estimation_res"] == pipeline.estimation_resolution(capture, Config(texels=TexelConfig(32)))
    # Shoot the views (any image of the right size will do here) and load them as a capture.
    for frame in document["frames"]:
        (out / frame["file_path"]).parent.mkdir(exist_ok=True)
        shutil.copy(capture.frames[0].image_path, out / frame["file_path"])
    shot = load(out / "next_views.json")
    np.testing.assert_allclose(shot.frames[0].camera.camera_to_world, cameras[1].camera_to_world)
    assert shot.mesh.path.resolve() == capture.mesh.path.resolve()
    np.testing.assert_array_equal(shot.envmap.radiance, capture.envmap.radiance)

    sampled = tmp_path / "sampled"
    assert run_cli("next-views", capture.root, "--sample", 8, "--budget", 3, "--out", sampled,
                   "--texture-res", 32, "--max-texels", 200, "--quiet") == 0
    assert len(json.loads((sampled / "next_views.json").read_text())["frames"]) == 3


@pytest.mark.slow
@pytest.mark.parametrize("problem", ["missing", "malformed", "both", "neither", "budget"])
def test_next_views_command_rejects_bad_input_without_writing(sphere_from_above, tmp_path, run_cli, monkeypatch, capsys,
                                                              problem):
    capture = sphere_from_above
    candidates_file = tmp_path / "candidates.json"
    write_transforms(candidates_file, [Frame(capture.frames[0].camera, tmp_path / "unshot.exr")])
    if problem == "malformed":
        candidates_file.write_text('{"frames": [')
    choice = {
        "missing": ["--candidates", tmp_path / "nowhere.json"],
        "malformed": ["--candidates", candidates_file],
        "both": ["--candidates", candidates_file, "--sample", 4],
        "neither": [],
        "budget": ["--candidates", candidates_file],
    }[problem]
    out = tmp_path / "next"
    code = run_cli("next-views", capture.root, *choice, "--budget", 2, "--out", out,
                   "--texture-res", 32, "--quiet")
    assert code == 2
    error = capsys.readouterr().err
    expected = {"missing": "nowhere.json", "malformed": "malformed JSON", "both": "exactly one",
                "neither": "exactly one", "budget": "exceeds the 1 candidate"}[problem]
    assert expected in " ".join(error.split())
    assert not out.exists()
