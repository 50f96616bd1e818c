"""Capture guidance (freqbrdf.applications.guidance, `freqbrdf next-views`).

The incremental state and the scores are checked against from-scratch sums on synthetic models;
the model against the whole-surface posterior it reads, and the choice of views, on a small
Mitsuba-rendered sphere whose cameras all look from above, so that its lower half is unseen.
"""

import dataclasses
import json
import shutil

import numpy as np
import pytest

from freqbrdf import pipeline
from freqbrdf.applications import guidance
from freqbrdf.applications._diversity import REFIT_NOISE, Spread
from freqbrdf.applications.candidates import (
    candidate_samples,
    farthest_point_views,
    sample_candidates,
)
from freqbrdf.capture.camera import look_at
from freqbrdf.capture.camera_layouts import bounding_sphere
from freqbrdf.capture.layouts import Frame, load
from freqbrdf.capture.transforms_file import write_transforms
from freqbrdf.config import Config, TexelConfig
from freqbrdf.fileio import OUTPUT_MARKER
from freqbrdf.synthetic.synth import SynthSettings, synthesize

LMAX = 3


def synthetic_model(rng, n_texels=40) -> guidance.UncertaintyModel:
    """A model of n texels with random precisions and couplings; the first half without data."""
    return guidance.UncertaintyModel(
        rows=np.arange(n_texels), area=rng.uniform(0.5, 1.5, n_texels),
        prior_std=np.column_stack([np.full(n_texels, 0.3), np.full(n_texels, 0.45), np.full(n_texels, 0.2)]),
        fit_samples=np.where(np.arange(n_texels) < n_texels // 2, 0, 12),
        roughness_precision=np.where(np.arange(n_texels) < n_texels // 2, 0.0, rng.uniform(0.5, 2.0, n_texels)),
        roughness_per_unit=0.1, base_information=np.zeros(n_texels), roughness_coupling=rng.uniform(1.0, 3.0, n_texels),
        roughness_scale=0.01, roughness_level=0.5, color_precision=rng.uniform(1.0, 4.0, (n_texels, 3)),
        color_coupling=rng.uniform(0.5, 1.0, n_texels), color_scale=0.002, color_level=2.0,
        metal_probability=rng.uniform(0.05, 0.95, n_texels), border_variance=np.zeros(n_texels),
        label_color_difference=rng.uniform(-0.5, 0.5, (n_texels, 3)),
        evidence_scale=rng.uniform(0.5, 2.0, n_texels),
        taken_evidence=rng.uniform(0.0, 3.0, n_texels),
        typical_samples=8.0, few_sample_power=2.0, std_scale=1.0, sigma=0.25,
    )


def random_fisher(rng, n_texels, n_samples) -> np.ndarray:
    """(n, 6) Fisher entries of ``n_samples`` random samples per texel (3 channels each)."""
    jacobian = rng.normal(size=(n_texels, n_samples * 3, 3))
    full = np.einsum("nsi,nsj->nij", jacobian, jacobian)
    return np.stack([full[:, i, j] for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))], axis=1)


def synthetic_view(rng, texels) -> guidance.ViewInformation:
    texels = np.sort(np.asarray(texels))
    return guidance.ViewInformation(texels, random_fisher(rng, len(texels), 1), rng.uniform(0.0, 2.0, len(texels)))


def synthetic_state(n_texels=40) -> guidance.GuidanceState:
    """The first half unseen, the second seen by 12 views each."""
    samples = np.where(np.arange(n_texels) < n_texels // 2, 0, 12)
    fisher = random_fisher(np.random.default_rng(0), n_texels, 12) * (samples > 0)[:, None]
    return guidance.GuidanceState(samples.astype(np.int64), fisher, np.zeros(n_texels))


def test_incremental_updates_equal_the_state_from_scratch():
    rng = np.random.default_rng(1)
    model, state = synthetic_model(rng), synthetic_state()
    views = [synthetic_view(rng, rng.choice(40, size, replace=False)) for size in (5, 17, 30, 1)]
    scratch = guidance.state_with_views(state, views)
    incremental = state.copy()
    for view in views:
        expected_drop = guidance.expected_uncertainty(model, incremental) - guidance.expected_uncertainty(
            model, guidance.state_with_views(incremental, [view]))
        assert guidance.view_gain(model, incremental, view) == pytest.approx(expected_drop, rel=1e-12)
        guidance.add_view(incremental, view)
    np.testing.assert_array_equal(incremental.samples, scratch.samples)
    np.testing.assert_allclose(incremental.fisher, scratch.fisher, rtol=1e-12)
    np.testing.assert_allclose(incremental.metal_evidence, scratch.metal_evidence, rtol=1e-12)
    np.testing.assert_allclose(guidance.texel_std(model, incremental), guidance.texel_std(model, scratch), rtol=1e-12)
    # The state the views started from is untouched by state_with_views.
    np.testing.assert_array_equal(state.samples, synthetic_state().samples)


def test_roughness_information_is_what_the_scales_cannot_explain():
    """The Schur complement of the nuisance block: equal to inverting the full 3 x 3 matrix, and 0
    for samples whose roughness derivative is a mix of the scales' derivatives."""
    rng = np.random.default_rng(4)
    fisher = random_fisher(rng, 5, 4)
    full = np.zeros((5, 3, 3))
    for entry, (i, j) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
        full[:, i, j] = full[:, j, i] = fisher[:, entry]
    np.testing.assert_allclose(guidance.roughness_information(fisher), 1.0 / np.linalg.inv(full)[:, 0, 0], rtol=1e-5)
    scales = rng.normal(size=(30, 2))
    jacobian = np.column_stack([scales @ [0.3, -1.2], scales])  # d f / d roughness explained by k and d
    collinear = jacobian.T @ jacobian
    entries = np.array([[collinear[i, j] for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))]])
    assert guidance.roughness_information(entries)[0] < 1e-5 * collinear[0, 0]


def test_a_view_of_unseen_texels_scores_higher_than_one_of_well_observed_texels():
    rng = np.random.default_rng(2)
    model, state = synthetic_model(rng), synthetic_state()
    well_observed = synthetic_view(rng, np.arange(20, 40))
    unseen = synthetic_view(rng, np.arange(0, 20))
    gain_observed = guidance.view_gain(model, state, well_observed)
    gain_unseen = guidance.view_gain(model, state, unseen)
    assert 0.0 < gain_observed < gain_unseen
    # A texel becomes a data texel at MIN_SAMPLES (2) samples: one view of an unseen texel goes halfway.
    once = guidance.state_with_views(state, [unseen])
    twice = guidance.state_with_views(once, [unseen])
    std_once, std_twice = guidance.texel_std(model, once), guidance.texel_std(model, twice)
    prior = model.prior_std[:20]
    assert np.all(std_twice[:20, 0] < prior[:, 0]) and np.all(std_twice[:20, 2] < prior[:, 2])
    np.testing.assert_allclose(std_once[:20, [0, 2]], 0.5 * (prior[:, [0, 2]] + std_twice[:20, [0, 2]]), rtol=0.1)


def test_metal_evidence_lowers_the_expected_label_std():
    rng = np.random.default_rng(3)
    model, state = synthetic_model(rng), synthetic_state()
    probability = model.metal_probability
    std = guidance.texel_std(model, state)
    np.testing.assert_allclose(std[:, 1], np.sqrt(probability * (1.0 - probability)), rtol=1e-9)
    stronger = guidance.state_with_views(state, [synthetic_view(rng, np.arange(40))])
    assert np.all(guidance.texel_std(model, stronger)[:, 1] < std[:, 1])


def test_a_texel_brought_to_data_weighs_the_evidence_of_its_earlier_samples_too():
    """Below the estimate's minimum a texel's label is the prior's and its neighbours'; once a view
    completes its samples, all of them speak (the square root of the summed evidence), whereas a
    data texel's label only moves by the growth of that root."""
    rng = np.random.default_rng(5)
    model = dataclasses.replace(synthetic_model(rng), fit_samples=np.where(np.arange(40) < 20, guidance.MIN_SAMPLES - 1, 12))
    state = dataclasses.replace(synthetic_state(), samples=model.fit_samples.copy())
    view = synthetic_view(rng, np.arange(40))
    without_earlier = dataclasses.replace(model, taken_evidence=np.zeros(40))
    after, after_without = (guidance.texel_std(m, guidance.state_with_views(state, [view]))[:, 1]
                            for m in (model, without_earlier))
    # Brought to data: the same label std as a texel whose earlier evidence arrives with the view.
    np.testing.assert_allclose(after[:20], guidance.texel_std(without_earlier, guidance.state_with_views(
        state, [dataclasses.replace(view, metal_evidence=view.metal_evidence + model.taken_evidence)]))[:20, 1],
        rtol=1e-12)
    assert np.all(after[:20] < after_without[:20])
    # Data texels: earlier evidence makes the same view's evidence worth less.
    assert np.all(after[20:] > after_without[20:])


def test_a_sample_beside_the_views_taken_counts_less_than_one_from_a_new_side():
    taken = np.array([[0.0, 0.0, 1.0]])
    beside = np.array([0.0, 0.1, 1.0]) / np.linalg.norm([0.0, 0.1, 1.0])
    candidates = np.array([beside, [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    spread = Spread(5, taken, candidates, [np.array([0, 1, 2])])
    seen, unseen = np.array([0, 1, 2]), np.array([3, 4])
    assert np.all(spread.discount(0, seen) < spread.discount(1, seen))
    assert np.all(spread.discount(1, seen) < spread.discount(2, seen))
    np.testing.assert_array_equal(spread.discount(0, unseen), 1.0)  # no sample of those texels yet
    before = spread.discount(1, seen)
    spread.add(0, np.array([0, 1]))  # picked: its samples now correlate with later ones
    after = spread.discount(1, seen)
    assert np.all(after[:2] < before[:2]) and after[2] == before[2]


def test_candidates_within_a_refits_scatter_are_decided_by_their_spread():
    taken = np.array([[0.0, 0.0, 1.0]])
    candidates = np.array([[0.0, 0.6, 0.8], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    spread = Spread(3, taken, candidates, [np.arange(3)])
    band = np.sqrt(2.0) * REFIT_NOISE  # the scatter of the difference of two refits, at a mean std of 1
    # The best gain by more than the band wins; within it, the view farthest from those taken.
    assert spread.choose(np.array([1.0, 1.0 - 2 * band, 0.0]), [0, 1, 2], 1.0) == (0, False)
    assert spread.choose(np.array([1.0, 1.0 - 0.5 * band, 0.0]), [0, 1, 2], 1.0) == (1, True)
    assert spread.choose(np.array([1.0, 1.0 - 0.5 * band, 1.0 - 0.9 * band]), [0, 1, 2], 1.0) == (2, True)


def test_farthest_point_views_spread_and_extend_a_chosen_set():
    directions = np.array([[0, 0, 1], [0, 0.1, 0.995], [0, 0, -1], [1, 0, 0], [-1, 0, 0]], float)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    assert farthest_point_views(directions, 3) == [0, 2, 3]
    assert farthest_point_views(directions, 2, chosen=[0, 2]) == [3, 4]
    with pytest.raises(ValueError):
        farthest_point_views(directions, 4, chosen=[0, 2])


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


def near_camera(capture, degrees=4.0):
    """A camera beside the capture's first one, ``degrees`` away (seen from the object), looking at it."""
    centre, _ = bounding_sphere(capture.mesh.vertices)
    template = capture.frames[0].camera
    offset = template.center - centre
    axis = np.cross(offset, [0.0, 1.0, 0.0])
    axis /= np.linalg.norm(axis)
    angle = np.radians(degrees)
    rotated = (offset * np.cos(angle) + np.cross(axis, offset) * np.sin(angle)
               + axis * np.dot(axis, offset) * (1.0 - np.cos(angle)))
    return dataclasses.replace(template, camera_to_world=look_at(centre + rotated, centre))


@pytest.mark.slow
def test_the_model_reproduces_the_whole_surface_posterior(sphere_from_above):
    capture = sphere_from_above
    fit = guidance.surface_fit(capture, CONFIG)
    rows = guidance.texel_subset(fit.texels.n_texels, 10**6, 0)
    model = guidance.uncertainty_model(capture, fit, rows, CONFIG, fit.observations.sigma)
    texels = guidance.subset_texels(fit.texels, rows)
    taken = guidance.view_information(capture, texels, fit, rows, [frame.camera for frame in capture.frames],
                                      fit.observations.sigma)
    state = guidance.initial_state(model, fit.observations.n_samples[rows], taken)
    std = guidance.texel_std(model, state)
    posterior = fit.posterior
    estimated = fit.per_texel.estimated
    assert 0 < estimated.sum() < len(estimated)  # both kinds of texel occur
    # Roughness: the texels whose loss has a curvature are the solve's data texels (most of them).
    curved = estimated & (np.nan_to_num(fit.per_texel.roughness_curvature) > 0)
    assert curved.sum() > 0.8 * estimated.sum()
    matches = np.isclose(std[curved, 0], posterior.roughness_std[curved], rtol=1e-4)
    assert matches.mean() > 0.98, np.flatnonzero(~matches)
    np.testing.assert_allclose(std[:, 1], posterior.metallic_std, rtol=1e-4, atol=2e-6)
    np.testing.assert_allclose(std[estimated, 2], posterior.base_color_std[estimated].mean(axis=1), rtol=1e-4)
    np.testing.assert_allclose(std[~estimated, 0], np.nan_to_num(posterior.roughness_std[~estimated]), rtol=1e-6)


@pytest.mark.slow
def test_a_view_of_the_unseen_half_beats_a_view_beside_a_taken_one(sphere_from_above):
    capture = sphere_from_above
    candidates = [capture.frames[0].camera, near_camera(capture), below_camera(capture)]
    picks = guidance.select_views(capture, candidates, 2, CONFIG)
    # The taken camera itself does not compete; the unseen half comes first.
    assert [pick.candidate for pick in picks] == [2, 1]
    assert picks[0].decided_by == "gain"
    first, second = picks
    assert first.expected_gain > second.expected_gain > 0.0
    assert first.unseen_area > 0.2 and second.unseen_area < 0.1 * first.unseen_area
    assert second.uncertainty_before == pytest.approx(first.expected_uncertainty, rel=1e-9)
    assert first.texels_seen > 0 and first.seconds > 0
    # Deterministic, and the same with the fit passed in.
    fit = guidance.surface_fit(capture, CONFIG)
    again = guidance.select_views(capture, candidates, 2, CONFIG, fit=fit)
    assert [(pick.candidate, pick.expected_uncertainty) for pick in again] == [
        (pick.candidate, pick.expected_uncertainty) for pick in picks]
    with pytest.raises(ValueError, match="exceeds"):
        guidance.select_views(capture, candidates, 3, CONFIG, fit=fit)


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
    cameras = [near_camera(capture), below_camera(capture)]
    write_transforms(candidates_file, [Frame(camera, tmp_path / f"unshot_{k}.exr") for k, camera in enumerate(cameras)])
    out = tmp_path / "next"
    assert run_cli("next-views", capture.root, "--candidates", candidates_file, "--budget", 2,
                   "--out", out, "--texture-res", 32, "--quiet") == 0
    assert capsys.readouterr().err == ""
    assert {path.name for path in out.iterdir()} - {OUTPUT_MARKER} == {"next_views.json", "next_views.png", "guidance.json"}
    document = json.loads((out / "next_views.json").read_text())
    assert [frame["rank"] for frame in document["frames"]] == [0, 1]
    assert document["frames"][0]["candidate"] == 1
    assert document["frames"][0]["decided_by"] == "gain"  # the unseen half: far above a refit's scatter
    assert document["frames"][0]["expected_gain"] > document["frames"][1]["expected_gain"] > 0
    summary = json.loads((out / "guidance.json").read_text())
    assert summary["picks"][0]["expected_mean_std"] < summary["mean_std_before"]
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
    # The loop: the shot views join the capture, the next run proposes from what is left.
    merged = dataclasses.replace(capture, frames=capture.frames + shot.frames)
    picks = guidance.select_views(merged, [*cameras, *sample_candidates(capture, 6)], 1, CONFIG)
    assert picks[0].candidate >= 2  # the views just taken do not compete again

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
                "neither": "exactly one", "budget": "exceeds the 0 candidate"}[problem]
    assert expected in " ".join(error.split())
    assert not out.exists()


@pytest.mark.slow
def test_next_views_after_a_fit_reuses_its_observations(sphere_from_above, tmp_path, run_cli, monkeypatch):
    """``next-views --fit-out`` fits and picks on one observation; the picks are `pipeline.next_views`'."""
    capture = sphere_from_above
    config = Config(texels=TexelConfig(32))
    cameras = sample_candidates(capture, 8)
    result = pipeline.fit(capture, config, keep_surface_fit=True)
    expected = pipeline.next_views(result, cameras, 2, config, max_texels=200)
    with pytest.raises(ValueError, match="keep_surface_fit"):
        pipeline.next_views(dataclasses.replace(result, surface_fit=None), cameras, 2, config)

    observed = []
    real_observe = pipeline.observe
    monkeypatch.setattr(pipeline, "observe", lambda *args, **kwargs: observed.append(1) or real_observe(*args, **kwargs))
    monkeypatch.setattr(guidance, "observe", lambda *args, **kwargs: pytest.fail("guidance observed again"))
    out, fit_out = tmp_path / "next", tmp_path / "fit"
    assert run_cli("next-views", capture.root, "--sample", 8, "--budget", 2, "--out", out, "--fit-out", fit_out,
                   "--texture-res", 32, "--max-texels", 200, "--quiet") == 0
    assert len(observed) == 1  # the fit's; guidance reads it
    assert (fit_out / "summary.json").is_file() and (fit_out / "base_color.exr").is_file()
    summary = json.loads((out / "guidance.json").read_text())
    assert summary["fit"] == str(fit_out.resolve())
    assert [pick["candidate"] for pick in summary["picks"]] == [pick.candidate for pick in expected]
    np.testing.assert_allclose([pick["expected_mean_std"] for pick in summary["picks"]],
                               [pick.expected_uncertainty for pick in expected])
    assert run_cli("next-views", capture.root, "--sample", 8, "--budget", 2, "--out", out, "--fit-out", out,
                   "--quiet") == 2
