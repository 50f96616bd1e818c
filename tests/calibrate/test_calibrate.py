"""Calibration from the photographs: each quantity recovered on a small Mitsuba capture with a known error.

One capture (a sphere of smooth and rough dielectric and metal gradients under the lobby map,
32 views of 96 x 96) is rendered once; the errors are applied to copies of it as a user's capture has them:
the photographs at another exposure and white balance, one photograph at another shutter speed,
the map turned in its transforms. Gains are compared with the clean capture's own (what the
model calls 1 on this capture), so that the test measures the calibration, not the model.
"""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from freqbrdf.calibrate import MIN_GAIN_SAMPLES, POORLY_DETERMINED, axis_angle, calibrate, rotation_about
from freqbrdf.capture.layouts import load
from freqbrdf.config import CalibrationConfig, Config, TexelConfig
from freqbrdf.images import read_image, write_exr
from freqbrdf.synthetic.synth import SynthSettings, synthesize

CONFIG = Config(texels=TexelConfig(texture_res=64), calibration=CalibrationConfig(texture_res=64))


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> Path:
    from freqbrdf.assets import mesh_path
    from freqbrdf.capture.mesh import load_mesh
    from freqbrdf.model.materials import save_material_maps
    from freqbrdf.synthetic.materials import gradient_material

    root = tmp_path_factory.mktemp("calibration")
    save_material_maps(root / "materials", gradient_material(load_mesh(mesh_path("sphere")), 64, seed=0))
    settings = SynthSettings(mesh="sphere", envmap="lobby", materials=str(root / "materials"), views=32,
                             resolution=96, spp=8, texture_res=64, test_views=0, cameras="hemisphere")
    return synthesize(root / "clean", settings, progress=False)


def _copy(source: Path, target: Path, gain=(1.0, 1.0, 1.0), frame_gain: dict | None = None,
          turn: np.ndarray | None = None, clip_quantile: float | None = None) -> Path:
    """The capture with its photographs times ``gain`` (one frame also times frame_gain[index]),
    clipped at the ``clip_quantile`` of each photograph's object values (blown highlights), and its
    map's to_world turned by ``turn``."""
    target.mkdir()
    transforms = json.loads((source / "transforms.json").read_text())
    for name in os.listdir(source):
        if name not in ("transforms.json", "images"):
            os.symlink(source.resolve() / name, target / name)
    (target / "images").mkdir()
    for index, frame in enumerate(transforms["frames"]):
        factor = np.asarray(gain, np.float32) * np.float32((frame_gain or {}).get(index, 1.0))
        image = read_image(source / frame["file_path"]) * factor
        if clip_quantile is not None:
            image = np.minimum(image, np.quantile(image[image.max(axis=2) > 0], clip_quantile))
        write_exr(target / frame["file_path"], image)
    if turn is not None:
        matrix = np.eye(4)
        matrix[:3, :3] = turn
        transforms["envmap_to_world"] = (matrix @ np.array(transforms.get("envmap_to_world", np.eye(4)))).tolist()
    (target / "transforms.json").write_text(json.dumps(transforms))
    return target


@pytest.fixture(scope="module")
def clean_calibration(clean):
    return calibrate(load(clean), CONFIG)[1]


def test_exposure_and_white_balance_are_recovered(clean, clean_calibration, tmp_path):
    applied = np.array([2.0 * 1.1, 2.0, 2.0 * 0.9])
    capture, found = calibrate(load(_copy(clean, tmp_path / "gain", gain=applied)), CONFIG)
    # Against the clean capture's own gains: what the calibration adds, not what the model misses.
    # The exposure is well determined; the white balance less so on a capture this small.
    relative = found.gain_measured / clean_calibration.gain_measured
    np.testing.assert_allclose(np.exp(np.log(relative).mean()), np.exp(np.log(applied).mean()), rtol=0.05)
    np.testing.assert_allclose(relative, applied, rtol=0.10)
    assert relative[0] > relative[1] > relative[2]  # the white balance's direction
    # On a capture this small (32 views of 96 x 96, 8 spp) the model itself reads a gain within 35 % of 1.
    np.testing.assert_allclose(clean_calibration.gain_measured, 1.0, atol=0.35)
    # Applied where the texels tell it from 1: the exposure surely; each white-balance ratio is
    # applied as measured or, within its noise of 1, left at 1.
    # applied as measured, shrunk towards 1 by the prior (by at most 2 % for the exposure, at most halved
    # for a ratio, whose prior is narrower).
    measured_exposure = np.log(found.gain_measured).mean()
    measured_ratio = np.log(found.gain_measured) - measured_exposure
    left = np.log(found.gain) - measured_exposure  # (the applied ratio) up to 2 % of the exposure
    slack = 0.02 * abs(measured_exposure)
    kept_at_one = np.abs(left) <= slack
    shrunk = (np.sign(left) == np.sign(measured_ratio)) & (np.abs(left) <= np.abs(measured_ratio) + slack) & (
        np.abs(left) >= 0.5 * np.abs(measured_ratio) - slack)
    assert np.all(kept_at_one | shrunk)
    assert np.all(found.gain_log_std > 0) and np.all(found.gain_log_std < POORLY_DETERMINED)  # well determined
    # The corrected capture's photographs are divided by the gains.
    corrected = capture.image(0)
    original = read_image(capture.frames[0].image_path)
    np.testing.assert_allclose(corrected, original / found.gain.astype(np.float32), rtol=1e-5)
    assert any("exposure" in line for line in found.warnings)


def test_a_photograph_at_another_shutter_speed_is_found_when_asked(clean, clean_calibration, tmp_path):
    assert clean_calibration.frame_gain is None  # off by default
    asked = CONFIG.replace(calibration=CalibrationConfig(texture_res=64, frame_gains="on"))
    capture, found = calibrate(load(_copy(clean, tmp_path / "frame", frame_gain={3: 1.6})), asked)
    relative = found.frame_gain[3] / np.exp(np.log(np.delete(found.frame_gain, 3, axis=0)).mean(axis=0))
    # Measured from the other views' prediction of each texel: most of the factor, never the wrong way.
    assert np.all(relative > 1.25) and np.all(relative < 1.8), relative
    assert capture.frames[3].exposure is not None


def test_a_turned_probe_is_registered(clean, clean_calibration, tmp_path):
    turn = rotation_about(np.array([0.0, 1.0, 0.0]), np.radians(8.0))
    capture, found = calibrate(load(_copy(clean, tmp_path / "turned", turn=turn)), CONFIG)
    assert clean_calibration.probe.angle_deg < 1.0
    axis, angle = axis_angle(found.probe.rotation @ turn)  # what is left of the turn
    assert np.degrees(angle) < 1.5, f"found {found.probe.angle_deg:.2f} deg, {np.degrees(angle):.2f} deg left"
    np.testing.assert_allclose(capture.envmap.rotation, found.probe.rotation @ turn @ load(clean).envmap.rotation,
                               atol=1e-9)


@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0)])
def test_a_turned_probes_loss_is_the_loss_of_the_capture_observed_with_it(clean, axis):
    # The registration scores a turn without observing again (harmonics rotated, prefiltered maps read
    # in the turned frame, irradiance at turned normals): the same loss as observing the turned capture.
    from freqbrdf.calibrate import _search_config, _turned
    from freqbrdf.calibrate.probe import _ModelLoss
    from freqbrdf.observe import observe

    config = Config(texels=TexelConfig(texture_res=32))
    capture = load(clean)
    turn = rotation_about(np.array(axis), np.radians(3.0))
    settings = _search_config(config).estimate
    cheap = _ModelLoss(observe(capture, config), settings)(turn)
    observed = _ModelLoss(observe(_turned(capture, turn), config), settings)(np.eye(3))
    assert cheap == pytest.approx(observed, rel=1e-5)
    assert cheap != pytest.approx(_ModelLoss(observe(capture, config), settings)(np.eye(3)), rel=1e-3)


def test_clipped_highlights_neither_turn_the_probe_nor_move_the_gains(clean, clean_calibration, tmp_path):
    # Highlights clipped (censored samples, docs/method.md#censored-samples): the texels that keep
    # only their dimmer views would prefer a turn and a lower gain if read as measurements.
    capture, found = calibrate(load(_copy(clean, tmp_path / "clipped", clip_quantile=0.95)), CONFIG)
    assert found.probe.angle_deg < 1.0
    # The gains read only the texels without a censored sample (fewer: a wider std) and stay within
    # that std of the clean capture's.
    assert np.all(found.gain_log_std > clean_calibration.gain_log_std)
    spread = np.hypot(found.gain_log_std, clean_calibration.gain_log_std)
    assert np.all(np.abs(np.log(found.gain_measured / clean_calibration.gain_measured)) < 2.0 * spread)


def test_a_turned_probe_is_registered_on_clipped_photographs(clean, tmp_path):
    # Every seen texel scores the turn with its clipped samples left out: the texels without a
    # clipped sample alone are those whose views met no bright part of the map, a selection that
    # widened the turn's std until no turn was found (docs/method.md#calibration).
    turn = rotation_about(np.array([0.0, 1.0, 0.0]), np.radians(8.0))
    _, found = calibrate(load(_copy(clean, tmp_path / "turned_clipped", turn=turn, clip_quantile=0.95)), CONFIG)
    _, angle = axis_angle(found.probe.rotation @ turn)
    assert np.degrees(angle) < 2.0, f"found {found.probe.angle_deg:.2f} deg, {np.degrees(angle):.2f} deg left"


def test_calibration_none_leaves_the_capture_as_given(clean):
    given = load(clean)
    nothing = CONFIG.replace(calibration=CalibrationConfig(gains=False, cameras=False, probe_rotation=False, frame_gains="off"))
    capture, found = calibrate(given, nothing)
    assert capture is given and np.all(found.gain == 1.0) and found.probe is None and not found.warnings
    assert found.exposure_from == "" and found.to_dict()["exposure_from"] == ""


def test_the_summary_says_which_texels_read_the_exposure(clean_calibration):
    # The small synthetic capture: fewer than MIN_DIELECTRIC_TEXELS dielectrics or enough, either is named.
    recorded = clean_calibration.to_dict()
    assert recorded["exposure_from"] in ("dielectrics", "every texel") and recorded["texels"] >= 2


def test_calibration_is_deterministic(clean, clean_calibration):
    again = calibrate(load(clean), CONFIG)[1]
    assert again.to_dict() | {"seconds": 0} == clean_calibration.to_dict() | {"seconds": 0}


def test_a_flat_surface_does_not_register_the_probe(clean):
    # Normals all alike (a plane, a relief): a turn would mimic the lobe's misfit, not register the map.
    from freqbrdf.calibrate import register_probe
    from freqbrdf.config import EstimateConfig
    from freqbrdf.observe import observe

    observations = observe(load(clean), CONFIG)
    flat = replace(observations, normal=np.tile(np.float32([0.0, 0.0, 1.0]), (observations.n_texels, 1)))
    found = register_probe(flat, EstimateConfig(robust_passes=0, neighbour_vote=False), 25.0)
    assert found.angle_deg == 0.0 and np.array_equal(found.rotation, np.eye(3)) and found.log_odds == 0.0


def test_a_capture_with_too_few_views_per_texel_keeps_the_maps_scale_and_says_so(clean, clean_calibration):
    # One view in four (8 of 32): a few samples per texel cannot tell a dielectric's diffuse from its
    # specular, so the gains would read the model's misfit.
    assert clean_calibration.samples_per_texel >= MIN_GAIN_SAMPLES
    given = load(clean)
    sparse = replace(given, frames=given.frames[::4])
    capture, found = calibrate(sparse, CONFIG)
    assert found.samples_per_texel < MIN_GAIN_SAMPLES
    assert np.all(found.gain == 1.0) and found.gain_measured is None and np.all(found.gain_log_std == 0.0)
    assert all(frame.exposure in (None, 1.0) or np.allclose(frame.exposure, 1.0) for frame in capture.frames)
    assert any("too few" in line and "not estimated" in line for line in found.warnings)
    assert found.to_dict()["samples_per_texel"] == found.samples_per_texel


def test_a_gain_is_applied_where_it_is_likelier_off_one_than_exactly_one():
    """The exposure (prior: within a factor e) needs more std than a white-balance ratio (within 10 %);
    what is applied is the measurement itself."""
    from freqbrdf.calibrate import _significant
    from freqbrdf.calibrate.gains import GainEstimate

    found = GainEstimate(np.ones(3), np.full(3, 0.07), 1000, exposure_log_std=0.065, ratio_log_std=np.full(3, 0.03))
    # A 10 % white balance (3 std) is applied, a 3 % one (1 std) is not; the same split for the exposure:
    # 0.2 in log (3 std) is applied, 0.13 (2 std) is not.
    applied = _significant(np.exp(np.array([0.2 + 0.1, 0.2, 0.2 - 0.1])), found)
    np.testing.assert_allclose(np.log(applied), 0.2 + np.array([0.1, 0.0, -0.1]), atol=1e-12)
    applied = _significant(np.exp(np.array([0.13 + 0.03, 0.13, 0.13 - 0.03])), found)
    np.testing.assert_allclose(applied, 1.0, atol=1e-12)
    # A better-determined ratio (std 0.01) is applied from a smaller size; the exposure (2 std) is not.
    sharp = GainEstimate(np.ones(3), np.full(3, 0.07), 1000, exposure_log_std=0.065, ratio_log_std=np.full(3, 0.01))
    applied = np.log(_significant(np.exp(np.array([0.13 + 0.04, 0.13, 0.13 - 0.04])), sharp))
    np.testing.assert_allclose(applied, np.array([0.04, 0.0, -0.04]), atol=1e-12)


def test_the_applied_gains_error_std_weighs_the_measurement_by_how_likely_the_decision_is_wrong():
    """A gain read at 1 within its std is not applied and its error std is a fraction of the measured std;
    one clearly off 1 is applied with about its measured std; a gain at the threshold is the most uncertain."""
    from freqbrdf.calibrate import _decision_log_std, _significant
    from freqbrdf.calibrate.gains import GainEstimate

    found = GainEstimate(np.ones(3), np.full(3, 0.09), 300, exposure_log_std=0.085, ratio_log_std=np.full(3, 0.03))
    near_one = np.exp(np.full(3, -0.05))
    np.testing.assert_allclose(_significant(near_one, found), 1.0)
    assert np.all(_decision_log_std(near_one, found) < 0.5 * np.hypot(0.085, 0.03))
    far = np.full(3, 2.0)
    assert np.all(_significant(far, found) > 1.9)
    np.testing.assert_allclose(_decision_log_std(far, found), np.hypot(0.085, 0.03), rtol=0.05)
    threshold = np.exp(np.full(3, 0.2))  # 2.35 std: the two hypotheses about as likely
    assert np.all(_decision_log_std(threshold, found) > _decision_log_std(far, found))


def test_clipping_widens_the_gains_std_by_the_share_of_texels_it_leaves_out():
    """Gains read on the texels left after clipping are a selection: a clipped capture's exposure that
    reads 0.77 at 3 std without clipping is not applied when 43 % of the texels were left out."""
    from freqbrdf.calibrate import CENSORED_SELECTION_LOG_STD, _significant, _with_selection
    from freqbrdf.calibrate.gains import GainEstimate

    found = GainEstimate(np.ones(3), np.full(3, 0.09), 300, exposure_log_std=0.085, ratio_log_std=np.full(3, 0.03))
    gain = np.full(3, 0.77)
    assert np.all(_significant(gain, found) < 0.8)
    widened = _with_selection(found, CENSORED_SELECTION_LOG_STD * 0.43)
    assert widened.exposure_log_std > found.exposure_log_std and np.all(widened.log_std > found.log_std)
    np.testing.assert_allclose(_significant(gain, widened), 1.0)
    assert _with_selection(found, 0.0) is found


def test_clipped_photographs_read_the_white_balance_on_exact_texels_and_the_exposure_on_every_texel(monkeypatch):
    """Where photographs clip, the texels without a clipped sample read the white balance (every
    texel's passes), then every seen texel reads the exposure from there (the dielectrics' too), the
    ratios kept."""
    import freqbrdf.calibrate as calibration
    from freqbrdf.calibrate.gains import GainEstimate

    exact, every, calls = object(), object(), []

    def passes(observations, search, start, config, ratios=True):
        calls.append((observations, "passes", ratios))
        # a white balance and a low exposure (the darker texels)
        return np.array([0.9, 0.75, 0.6]), GainEstimate(np.ones(3), np.full(3, 0.1), 300, 0.1,
                                                        np.array([0.02, 0.03, 0.04])), None

    def read(observations, search, start, config, white_balance, ratios=True):
        calls.append((observations, white_balance, ratios, np.asarray(start).copy()))
        return start * 1.2, GainEstimate(np.ones(3), np.full(3, 0.1), 400, 0.08, np.full(3, 0.5)), True

    monkeypatch.setattr(calibration, "_channel_gains", passes)
    monkeypatch.setattr(calibration, "_read_gains", read)
    gain, found, on_dielectrics = calibration._read_clipped_gains(exact, every, None, np.ones(3), None)
    assert calls[0] == (exact, "passes", True)
    assert calls[1][:3] == (every, False, False)
    np.testing.assert_allclose(calls[1][3], [0.9, 0.75, 0.6])
    np.testing.assert_allclose(gain, 1.2 * np.array([0.9, 0.75, 0.6]))
    assert on_dielectrics and found.exposure_log_std == pytest.approx(0.08)
    np.testing.assert_allclose(found.ratio_log_std, [0.02, 0.03, 0.04])
    calls.clear()  # without clipping: one reading, the white balance too
    calibration._read_clipped_gains(every, every, None, np.ones(3), None)
    assert [(c[0], c[1]) for c in calls] == [(every, True)]


def test_the_clipped_share_counts_the_seen_texels_only():
    """Unseen texels (no sample at all) are neither clipped nor kept: 1 of the 4 seen texels has a
    clipped sample, whatever the number of unseen ones."""
    from types import SimpleNamespace

    from freqbrdf.calibrate import _clipped_share

    weight = np.zeros((10, 3), np.float32)
    weight[:4] = 1.0
    censored = np.zeros((10, 3), np.float32)
    censored[0, 1] = 1.0
    weight[0, 1] = 0.0
    assert _clipped_share(SimpleNamespace(weight=weight, censored_weight=censored)) == pytest.approx(0.25)
    assert _clipped_share(SimpleNamespace(weight=weight, censored_weight=None)) == 0.0


def test_gain_passes_that_walk_widen_the_std_by_their_scatter(monkeypatch):
    """Passes whose corrections are chance steps (each within its std) multiplied to a gain 0.71x: the
    spread of where they arrived widens the std so that the walk is not applied."""
    import freqbrdf.calibrate as calibration
    from freqbrdf.calibrate.gains import GainEstimate

    steps = iter([1.02, 0.87, 0.95, 0.985, 0.86, 1.0])  # a walk from 1 to 0.71 in five passes, then still
    monkeypatch.setattr(calibration, "label_sums", lambda observations, search: (np.zeros((1, 5)), None))
    monkeypatch.setattr(calibration, "channel_gains", lambda sums, roughness: GainEstimate(
        np.full(3, next(steps)), np.full(3, 0.17), 350, exposure_log_std=0.165, ratio_log_std=np.full(3, 0.03)))
    monkeypatch.setattr(calibration, "_scaled", lambda observations, divisor, config: observations)
    gain, found, _ = calibration._channel_gains(None, Config(), np.ones(3), Config())
    np.testing.assert_allclose(gain, 1.02 * 0.87 * 0.95 * 0.985 * 0.86)
    assert found.exposure_log_std > 0.165
    alone = GainEstimate(np.ones(3), np.full(3, 0.17), 350, exposure_log_std=0.165, ratio_log_std=np.full(3, 0.03))
    assert np.all(calibration._significant(gain, alone) < 0.8)  # one pass's std alone would apply it
    np.testing.assert_allclose(calibration._significant(gain, found), 1.0)


def test_passes_after_the_ratio_passes_move_the_exposure_only(monkeypatch):
    """The exposure converges slowly and keeps its passes; the white balance moves in the first
    `RATIO_PASSES`, so that its chance steps do not walk."""
    import freqbrdf.calibrate as calibration
    from freqbrdf.calibrate.gains import GainEstimate

    tilt = np.array([1.02, 1.0, 0.98])
    steps = iter([1.3 * tilt] * calibration.RATIO_PASSES + [1.1 * tilt, 1.0 * tilt])
    monkeypatch.setattr(calibration, "label_sums", lambda observations, search: (np.zeros((1, 5)), None))
    monkeypatch.setattr(calibration, "channel_gains", lambda sums, roughness: GainEstimate(
        next(steps), np.full(3, 0.1), 350, exposure_log_std=0.1, ratio_log_std=np.full(3, 0.03)))
    monkeypatch.setattr(calibration, "_scaled", lambda observations, divisor, config: observations)
    gain, _, _ = calibration._channel_gains(None, Config(), np.ones(3), Config())
    exposure = np.exp(np.log(tilt).mean())
    expected = (1.3 * tilt) ** calibration.RATIO_PASSES * 1.1 * exposure * exposure
    np.testing.assert_allclose(gain, expected, rtol=1e-12)


class _Texels:
    """Stands for Observations in `_dielectric_gains`: n texels, `select` keeps a count."""

    def __init__(self, n):
        self.n_texels = n

    def select(self, rows):
        return _Texels(int(np.count_nonzero(rows)))


def _dielectric_search(monkeypatch, metallic, reading, log_exposure=0.0):
    """Mock the search (every texel of roughness 0.2 and the given metallic) and the readings at a gain."""
    import freqbrdf.calibrate as calibration
    from freqbrdf.calibrate.gains import GainEstimate

    applied = {"log_exposure": log_exposure}  # the gain of the first search, handed in

    def label_sums(texels, search):
        params = np.zeros((texels.n_texels, 5))
        params[:, 3], params[:, 4] = 0.2, metallic[:texels.n_texels]
        sums = np.zeros((texels.n_texels, 2, 3, 16))
        sums[:, 0, :, 14] = 1.0
        return params, sums

    def scaled(texels, divisor, config):
        applied["log_exposure"] = float(np.mean(np.log(divisor)))
        return texels

    monkeypatch.setattr(calibration, "label_sums", label_sums)
    monkeypatch.setattr(calibration, "_scaled", scaled)
    monkeypatch.setattr(calibration, "channel_gains", lambda sums, roughness, model_std: GainEstimate(
        np.full(3, np.exp(reading(applied["log_exposure"]))), np.full(3, 0.05), len(sums),
        exposure_log_std=model_std, ratio_log_std=np.full(3, 0.03)))
    return calibration


def test_the_dielectrics_exposure_reaches_the_fixed_point_the_passes_approach(monkeypatch):
    """Readings that recover half the remaining error a pass (the roughness follows the gain half the
    way) reach their fixed point in two passes and a check, not in many."""
    truth = np.log(1.1)
    calibration = _dielectric_search(monkeypatch, np.zeros(500), lambda x: -0.5 * (x - truth), np.log(1.3))
    start = np.full(3, 1.3)
    gain, found = calibration._dielectric_gains(_Texels(500), Config(), start, Config(),
                                                calibration.label_sums(_Texels(500), None))
    np.testing.assert_allclose(np.log(gain), truth, atol=1e-12)
    assert found.exposure_log_std == calibration.DIELECTRIC_EXPOSURE_LOG_STD and found.texels == 500


def test_the_dielectrics_exposure_needs_enough_dielectric_texels(monkeypatch):
    """Texels found metal or part-metal do not read it; too few dielectrics leave the passes' reading."""
    metallic = np.where(np.arange(500) < 99, 0.0, 0.5)
    calibration = _dielectric_search(monkeypatch, metallic, lambda x: 0.0)
    searched = calibration.label_sums(_Texels(500), None)
    assert calibration._dielectric_gains(_Texels(500), Config(), np.ones(3), Config(), searched) is None
    metallic[99] = calibration.DIELECTRIC_MAX_METALLIC
    searched = calibration.label_sums(_Texels(500), None)
    assert calibration._dielectric_gains(_Texels(500), Config(), np.ones(3), Config(), searched)[1].texels == 100


def test_a_pass_moves_a_ratio_only_where_it_reads_more_than_the_texels_scatter():
    """A white-balance ratio within the texels' chance is not a step (steps of chance, multiplied, walk)."""
    import freqbrdf.calibrate as calibration
    from freqbrdf.calibrate.gains import MODEL_RATIO_LOG_STD, GainEstimate

    scatter = np.array([0.05, 0.05, 0.05])
    ratio_std = np.sqrt(scatter ** 2 + MODEL_RATIO_LOG_STD ** 2)
    reading = GainEstimate(np.exp(np.log(1.2) + np.array([0.2, 0.03, -0.23])), np.full(3, 0.1), 500,
                           exposure_log_std=0.1, ratio_log_std=ratio_std)
    step = calibration._gain_step(reading, True)
    np.testing.assert_allclose(step, np.log(1.2) + np.array([0.2, 0.0, -0.23]))
    np.testing.assert_allclose(calibration._gain_step(reading, False), np.full(3, np.log(1.2)))


def test_a_secant_step_reaches_a_linear_fixed_point():
    """Readings -c (x - x*) (a pass recovers a share c of the error) give x* from two passes; the
    contraction is clamped (a reading that hardly moves with the gain is amplified at most 1 / floor)."""
    from freqbrdf.calibrate import CONTRACTION_FLOOR, _secant_step

    def reading(x):
        return -0.4 * (x - 0.3)

    first = (0.0, reading(0.0))
    assert _secant_step([first]) == first[1]
    second = (first[1], reading(first[1]))
    assert second[0] + _secant_step([first, second]) == pytest.approx(0.3, abs=1e-12)
    assert _secant_step([(0.0, 0.1), (0.1, 0.099)]) == pytest.approx(0.099 / CONTRACTION_FLOOR)
    assert _secant_step([(0.0, 0.1), (0.1, 0.1)]) == 0.1  # no contraction measured: the reading
    assert _secant_step([(0.0, 0.1), (0.1, -0.05)]) == -0.05  # across the fixed point: the reading


def test_a_turn_is_kept_where_it_removes_enough_loss_or_the_odds_are_decisive():
    # The misfit's own turns on registered maps: likelier at small odds, removing 2-3 % of the loss.
    from freqbrdf.calibrate.probe import DECISIVE_LOG_ODDS, MIN_LOSS_REDUCTION, _turn_kept

    assert not _turn_kept(1.7, 0.98)
    assert _turn_kept(1.7, 1.0 - MIN_LOSS_REDUCTION)
    assert _turn_kept(DECISIVE_LOG_ODDS, 0.97)  # a turned map whose loss the material's misfit dominates
    assert not _turn_kept(-0.3, 0.5)
    assert not _turn_kept(DECISIVE_LOG_ODDS + 10.0, 1.0)  # the exposure's range explains what the turn does


def test_a_turn_is_judged_with_the_exposure_free_over_its_range():
    from freqbrdf.calibrate.probe import EXPOSURE_RANGE_STD, _least_over_exposure

    def loss(turn, exposure=1.0):  # least where the photographs are 1.2x too dark for the map
        return 1.0 + (np.log(exposure) - np.log(1.2)) ** 2

    read = loss(np.eye(3))
    assert _least_over_exposure(loss, np.eye(3), read, 0.0) == read  # a known exposure: as read
    std = np.log(1.2) / EXPOSURE_RANGE_STD
    assert _least_over_exposure(loss, np.eye(3), read, std) == pytest.approx(1.0)
    assert 1.0 < _least_over_exposure(loss, np.eye(3), read, 0.5 * std) < read  # the range ends short of it


def test_a_turns_loss_at_another_exposure_is_the_loss_of_the_photographs_divided_by_it(clean):
    from freqbrdf.calibrate import _search_config
    from freqbrdf.calibrate.probe import _ModelLoss
    from freqbrdf.observe import observe

    config = Config(texels=TexelConfig(texture_res=32))
    observations = observe(load(clean), config)
    settings = _search_config(config).estimate
    turn = rotation_about(np.array([0.0, 1.0, 0.0]), np.radians(3.0))
    darker = replace(observations, observed=(observations.observed / 1.3).astype(np.float32))
    assert _ModelLoss(observations, settings)(turn, 1.3) == pytest.approx(
        1.3 ** 2 * _ModelLoss(darker, settings)(turn), rel=1e-6)


def test_a_turn_is_applied_only_where_likelier_than_none():
    # The spike-and-slab rule of the probe's turn (docs/method.md#calibration): a turn of a few std
    # against a slab of 10° per axis is likelier than none; one within the misfit is not.
    from freqbrdf.calibrate.probe import PRIOR_TURN_DEG, _log_odds

    covariance = np.radians(1.0) ** 2 * np.eye(3)
    prior = np.radians(PRIOR_TURN_DEG)
    assert _log_odds(np.radians([0.0, 8.0, 0.0]), covariance, prior) > 0.0
    assert _log_odds(np.radians([0.0, 1.5, 0.0]), covariance, prior) < 0.0
    assert _log_odds(np.zeros(3), covariance, prior) < 0.0
    # A wider std (a poorly determined turn, or clipping's selection) needs a larger turn.
    assert _log_odds(np.radians([0.0, 8.0, 0.0]), 25.0 * covariance, prior) < 0.0


def test_frame_gains_follow_a_photographs_gain_exactly():
    """A photograph multiplied by k moves every pair it is in by log k: its gain moves by k (the frames'
    geometric mean held at 1), the others' by the normalisation only; a frame's std is finite where it
    has pairs."""
    from freqbrdf.calibrate.gains import frame_gains

    rng = np.random.default_rng(3)
    n_texels, n_views = 400, 12
    # Views on a ring around each texel's normal; the radiance varies smoothly with the direction.
    angles = np.linspace(0.0, 2.0 * np.pi, n_views, endpoint=False)
    directions = np.stack([0.7 * np.cos(angles), 0.7 * np.sin(angles), np.full(n_views, np.sqrt(1 - 0.49))], axis=1)
    view_direction = np.broadcast_to(directions, (n_texels, n_views, 3)).astype(np.float32).copy()
    albedo = rng.uniform(0.2, 0.8, (n_texels, 1, 3))
    observed = (albedo * (1.0 + 0.2 * np.cos(angles)[None, :, None])
                * rng.lognormal(0.0, 0.02, (n_texels, n_views, 3))).astype(np.float32)
    weight = np.ones((n_texels, n_views), np.float32)
    gain, log_std = frame_gains(view_direction, weight, observed)
    brighter = observed.copy()
    brighter[:, 4] *= 1.6
    moved, _ = frame_gains(view_direction, weight, brighter)
    shift = np.log(moved) - np.log(gain)
    np.testing.assert_allclose(shift[4], np.log(1.6) * (1.0 - 1.0 / n_views), atol=1e-6)  # float32 photographs
    np.testing.assert_allclose(np.delete(shift, 4, axis=0), -np.log(1.6) / n_views, atol=1e-6)
    assert np.all(np.isfinite(log_std))


@pytest.mark.parametrize("scale", [1e-3, 1e3])
def test_a_map_in_other_units_is_recovered(clean, clean_calibration, tmp_path, scale):
    # A probe merged in absolute units beside photographs in [0, 1]: orders of magnitude apart, beyond
    # the passes' reach from gain 1; they start from the photographs' order of magnitude (`_gains_start`).
    _, found = calibrate(load(_copy(clean, tmp_path / "units", gain=(scale,) * 3)), CONFIG)
    relative = found.gain_measured / clean_calibration.gain_measured
    np.testing.assert_allclose(relative, scale, rtol=0.2)
    assert np.ptp(np.log(relative)) < 0.1  # no white balance made up on the way


def test_the_passes_start_from_the_photographs_order_of_magnitude_only_where_far_from_one(clean):
    from freqbrdf.calibrate import FAR_EXPOSURE, _exposure_order, _gains_start
    from freqbrdf.observe import observe

    observations = observe(load(clean), Config(texels=TexelConfig(texture_res=32)))
    order = _exposure_order(observations)
    assert 1.0 / FAR_EXPOSURE < order < FAR_EXPOSURE  # a calibrated capture: the passes start from 1
    np.testing.assert_array_equal(_gains_start(observations), np.ones(3))
    darker = replace(observations, observed=(observations.observed * 1e-3).astype(np.float32))
    assert _exposure_order(darker) == pytest.approx(1e-3 * order, rel=1e-4)  # linear in the photographs
    np.testing.assert_allclose(_gains_start(darker), 1e-3 * order, rtol=1e-4)


@pytest.mark.parametrize("quarters", [1, 2, 3])
def test_a_map_whose_azimuth_starts_a_quarter_turn_off_is_registered(clean, clean_calibration, tmp_path, quarters):
    # Tools disagree on where an equirectangular map's azimuth starts: a map off by quarter turns about
    # its pole (beyond the hand turn's search) is found by `convention_turn`, then refined.
    turn = rotation_about(np.array([0.0, 1.0, 0.0]), np.radians(90.0 * quarters + 4.0))
    capture, found = calibrate(load(_copy(clean, tmp_path / "convention", turn=turn)), CONFIG)
    _, angle = axis_angle(found.probe.rotation @ turn)
    assert np.degrees(angle) < 1.5, f"found {found.probe.angle_deg:.2f} deg, {np.degrees(angle):.2f} deg left"
    np.testing.assert_allclose(capture.envmap.rotation, found.probe.rotation @ turn @ load(clean).envmap.rotation,
                               atol=1e-9)
    relative = found.gain_measured / clean_calibration.gain_measured  # the gains read under the map as turned
    np.testing.assert_allclose(relative, 1.0, rtol=0.05)
    assert found.probe.convention_deg == pytest.approx(90.0 * min(quarters, 4 - quarters))
    assert found.to_dict()["probe"]["convention_deg"] == found.probe.convention_deg
    assert any("the map's convention" in line for line in found.warnings)


def test_a_map_made_for_another_up_axis_is_registered(clean, clean_calibration, tmp_path):
    # A capture made in a z-up world (Blender's) with the map placed as for a y-up one: the map's pole
    # is tried on each of `WORLD_UP_AXES` (here the map's top lies along -z: taken back to +y).
    turn = rotation_about(np.array([1.0, 0.0, 0.0]), np.radians(-90.0))
    _, found = calibrate(load(_copy(clean, tmp_path / "z_up", turn=turn)), CONFIG)
    _, angle = axis_angle(found.probe.rotation @ turn)
    assert np.degrees(angle) < 1.5, f"found {found.probe.angle_deg:.2f} deg, {np.degrees(angle):.2f} deg left"
    assert found.probe.convention_deg == pytest.approx(90.0)


def test_a_quarter_turn_is_taken_for_the_convention_only_where_it_removes_most_of_the_loss(clean, monkeypatch):
    from freqbrdf.calibrate import _search_config, probe
    from freqbrdf.observe import observe

    config = Config(texels=TexelConfig(texture_res=32))
    observations = observe(load(clean), config)
    settings = _search_config(config).estimate
    np.testing.assert_array_equal(probe.convention_turn(observations, settings, 25.0), np.eye(3))  # registered
    assert np.array_equal(probe.convention_turn(observations, settings, 0.0), np.eye(3))  # not searched
    # A quarter turn that leaves just more than the share of the loss is not taken; just less, it is,
    # where it does so with the exposure free too.
    def scored(half_turn, given_at_other_exposures=None):
        def loss(self, turn, exposure=1.0):
            angle = round(float(np.degrees(axis_angle(turn)[1])))
            if angle == 0 and exposure != 1.0 and given_at_other_exposures is not None:
                return given_at_other_exposures
            return {0: 1.0, 180: half_turn}.get(angle, 2.0)
        return loss

    share = probe.CONVENTION_LOSS_SHARE
    for half_turn, other, taken in ((1.001 * share, None, False), (0.999 * share, None, True),
                                    (0.999 * share, 1.1, True), (0.999 * share, 0.9, False)):
        monkeypatch.setattr(probe._ModelLoss, "__call__", scored(half_turn, other))
        turn = probe.convention_turn(observations, settings, 25.0)
        assert np.degrees(axis_angle(turn)[1]) == pytest.approx(180.0 if taken else 0.0), (half_turn, other)


def test_a_sparse_capture_under_a_map_in_other_units_takes_the_photographs_order_of_magnitude(clean, tmp_path):
    # Too few samples a texel to estimate the gains, but the map 1000x off: its order of magnitude is
    # applied, with a wide std (`ORDER_LOG_STD`) that the base colour's std takes in.
    from freqbrdf.calibrate import ORDER_LOG_STD

    given = load(_copy(clean, tmp_path / "sparse_units", gain=(1e-3,) * 3))
    sparse = replace(given, frames=given.frames[::4])
    capture, found = calibrate(sparse, CONFIG)
    assert found.samples_per_texel < MIN_GAIN_SAMPLES and found.gain_measured is None
    assert np.all(np.abs(np.log(found.gain / 1e-3)) < np.log(2.0)), found.gain  # within a factor 2
    assert np.ptp(found.gain) == 0.0
    np.testing.assert_allclose(found.gain_log_std, ORDER_LOG_STD)
    np.testing.assert_allclose(found.gain_error_log_std, ORDER_LOG_STD)
    assert any("order of magnitude" in line for line in found.warnings)
