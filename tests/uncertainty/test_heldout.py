"""Each capture calibrates its own std on held-out views (freqbrdf.uncertainty.heldout, docs/method.md#held-out-std-calibration)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimate.test_estimate import random_truth, synthetic_observations
from freqbrdf.config import Config, UncertaintyConfig
from freqbrdf.estimate import estimate
from freqbrdf.uncertainty import Uncertainty, hypothesis_grid
from freqbrdf.uncertainty.heldout import COVERAGE, FACTOR_RANGE, calibrate_std, heldout_texels

# The misfit's reference so high that only the folds set the factors.
FOLDS_ONLY = 1e6


@pytest.fixture(scope="module")
def noisy():
    """Noisy observations of known materials (the default model), their truth and estimate."""
    truth = random_truth(150, seed=11)
    clean = synthetic_observations(truth, seed=12, n_views=24, model="split_sum", environment_light=True,
                                   prefiltered=True)
    rng = np.random.default_rng(13)
    rms = np.sqrt(np.mean(np.square(clean.observed), axis=(1, 2), keepdims=True))
    observations = dataclasses.replace(
        clean, observed=(clean.observed + 0.05 * rms * rng.standard_normal(clean.observed.shape)).astype(np.float32))
    return observations, truth, estimate(observations, Config())


def uncertainty_with(n_texels: int, roughness: float, metallic: float, base_color: float) -> Uncertainty:
    """An Uncertainty of n texels whose std maps are the constants given."""
    zeros = np.zeros(n_texels, np.float32)
    return Uncertainty(entropy=zeros, flags=np.zeros(n_texels, np.uint8), likelihood=None, best_alpha=zeros,
                       best_ks=zeros, channel=np.zeros(n_texels, np.int8), mode="calibrated", grid=hypothesis_grid(4),
                       roughness_std=np.full(n_texels, roughness, np.float32),
                       metallic_std=np.full(n_texels, metallic, np.float32),
                       base_color_std=np.full((n_texels, 3), base_color, np.float32))


def config_with(**changes) -> Config:
    return Config(uncertainty=UncertaintyConfig(**{"heldout_misfit_reference": FOLDS_ONLY, **changes}))


def test_a_too_narrow_roughness_std_is_widened_toward_68_percent_and_a_wide_one_is_kept(noisy):
    observations, truth, found = noisy
    config = config_with(heldout_folds=4)
    # The deviations' own scale (their 68th percentile), from a small std the factors stay free of their range.
    probe = calibrate_std(observations, uncertainty_with(observations.n_texels, 0.01, 0.1, 0.01), config, found)
    assert all(FACTOR_RANGE[0] < probe.fold_factors[name] < FACTOR_RANGE[1] for name in ("roughness", "base_color"))
    scale = {name: 0.01 * probe.fold_factors[name] for name in ("roughness", "base_color")}
    assert probe.folds == 4 and 0 < probe.texels <= observations.n_texels
    assert probe.misfit_scale == 1.0 and np.isfinite(probe.misfit) and probe.misfit > 0.0

    narrow = uncertainty_with(observations.n_texels, 0.4 * scale["roughness"], 0.1,
                              0.4 * scale["base_color"])
    before = {name: np.asarray(getattr(narrow, f"{name}_std"), np.float64).copy()
              for name in ("roughness", "metallic", "base_color")}
    result = calibrate_std(observations, narrow, config, found)
    factor = result.factors["roughness"]
    assert np.isfinite(factor) and FACTOR_RANGE[0] <= factor <= FACTOR_RANGE[1] and factor > 1.0
    assert abs(result.coverage_after["roughness"] - COVERAGE) < abs(result.coverage_before["roughness"] - COVERAGE)
    assert abs(result.coverage_after["roughness"] - COVERAGE) < 0.05
    # The base colour's std is the whole-surface posterior's: the misfit scales it, not the folds (here 1).
    assert result.factors["base_color"] == 1.0 and result.fold_factors["base_color"] > 1.0
    for name in ("roughness", "base_color"):
        np.testing.assert_allclose(getattr(narrow, f"{name}_std"),
                                   (before[name] * result.factors[name]).astype(np.float32))
    np.testing.assert_array_equal(narrow.metallic_std, before["metallic"].astype(np.float32))  # reported only
    assert "metallic" in result.fold_factors and "metallic" not in result.factors

    # Against the truth too: the calibrated roughness std covers the errors closer to 68 %.
    error = np.abs(found.roughness - truth.roughness)
    keep = found.estimated
    within_before = np.mean(error[keep] <= before["roughness"][keep])
    within_after = np.mean(error[keep] <= narrow.roughness_std[keep])
    assert abs(within_after - COVERAGE) < abs(within_before - COVERAGE)

    wide = uncertainty_with(observations.n_texels, 3.0 * scale["roughness"], 0.1, 3.0 * scale["base_color"])
    kept = calibrate_std(observations, wide, config, found)
    # 18 views per fold, fewer than heldout_narrow_views: the folds never narrow the std.
    assert kept.factors == {"roughness": 1.0, "base_color": 1.0}
    np.testing.assert_array_equal(wide.roughness_std, np.float32(3.0 * scale["roughness"]))


def test_folds_that_keep_enough_views_narrow_a_wide_roughness_std_toward_68_percent(noisy):
    observations, _, found = noisy
    probe = calibrate_std(observations, uncertainty_with(observations.n_texels, 0.01, 0.1, 0.01),
                          config_with(heldout_folds=4), found)
    scale = {name: 0.01 * probe.fold_factors[name] for name in ("roughness", "base_color")}
    wide = uncertainty_with(observations.n_texels, 3.0 * scale["roughness"], 0.1, 3.0 * scale["base_color"])
    # 24 views in 4 folds: each fold keeps 18.
    for narrow_views, narrows in ((19, False), (18, True)):
        found_factors = calibrate_std(observations, dataclasses.replace(wide), config_with(
            heldout_folds=4, heldout_narrow_views=narrow_views), found)
        factor = found_factors.factors["roughness"]
        if narrows:
            assert factor == pytest.approx(1.0 / 3.0, rel=0.02)
            assert abs(found_factors.coverage_after["roughness"] - COVERAGE) < 0.05
        else:
            assert factor == 1.0
        assert found_factors.factors["base_color"] == 1.0  # the misfit's scale alone, 1 here


def test_the_misfit_above_its_reference_widens_the_factors_and_alone_the_base_colours(noisy):
    observations, _, found = noisy
    folds_only = calibrate_std(observations, uncertainty_with(observations.n_texels, 0.01, 0.1, 0.01),
                               config_with(), found)
    reference = folds_only.misfit / 9.0
    with_misfit = calibrate_std(observations, uncertainty_with(observations.n_texels, 0.01, 0.1, 0.01),
                                config_with(heldout_misfit_reference=reference), found)
    assert with_misfit.misfit_scale == pytest.approx(3.0)
    expected = np.clip(max(1.0, folds_only.fold_factors["roughness"] * 3.0), *FACTOR_RANGE)
    assert with_misfit.factors["roughness"] == pytest.approx(expected)
    assert with_misfit.factors["base_color"] == pytest.approx(3.0)


def test_calibration_is_deterministic_bit_for_bit(noisy):
    observations, _, found = noisy
    config = config_with(heldout_folds=3, heldout_texels=60)
    results = []
    for _ in range(2):
        uncertainty = uncertainty_with(observations.n_texels, 0.01, 0.1, 0.01)
        found_calibration = calibrate_std(observations, uncertainty, config, found)
        results.append((found_calibration, uncertainty))
    (first, one), (second, other) = results
    assert first.texels == second.texels <= 60
    for name in ("factors", "fold_factors", "coverage_before", "coverage_after"):
        assert getattr(first, name) == getattr(second, name)
    for name in ("roughness", "metallic", "base_color"):
        assert first.deviations[name].shape == (3, first.texels)
        np.testing.assert_array_equal(first.deviations[name], second.deviations[name])
    np.testing.assert_array_equal(first.rows, second.rows)
    np.testing.assert_array_equal(one.roughness_std, other.roughness_std)
    np.testing.assert_array_equal(one.base_color_std, other.base_color_std)
    summary = first.to_dict()
    assert summary["folds"] == 3 and set(summary["factors"]) == {"roughness", "base_color"}
    assert not {"rows", "deviations", "relative_misfit"} & set(summary)  # per-texel arrays stay out of summary.json


def test_off_or_too_few_views_leaves_the_std_unchanged(noisy):
    observations, _, found = noisy
    uncertainty = uncertainty_with(observations.n_texels, 0.01, 0.1, 0.01)
    assert calibrate_std(observations, uncertainty, config_with(heldout_folds=0), found) is None
    one_view = observations.select(np.arange(observations.n_texels))
    one_view = dataclasses.replace(one_view, **{name: getattr(one_view, name)[:, :1] for name in
                                                ("view_direction", "observed", "mirrored", "weight", "visible")})
    assert calibrate_std(one_view, uncertainty, config_with(), found) is None
    np.testing.assert_array_equal(uncertainty.roughness_std, np.float32(0.01))


def test_heldout_texels_are_spread_evenly_over_the_seen_texels(noisy):
    observations, _, found = noisy
    rows = heldout_texels(observations, found, 40)
    seen = np.flatnonzero((observations.n_samples > 0) & found.estimated)
    assert len(rows) <= 40 and np.all(np.isin(rows, seen)) and np.all(np.diff(rows) > 0)
    assert len(heldout_texels(observations, found, 10_000)) == len(seen)
    assert len(heldout_texels(observations, None, 10_000)) == np.count_nonzero(observations.n_samples > 0)


@pytest.mark.parametrize("changes", [{"heldout_folds": 1}, {"heldout_folds": -2}, {"heldout_texels": 0},
                                     {"heldout_misfit_reference": 0.0}, {"heldout_misfit_reference": -1.0}])
def test_config_refuses_invalid_heldout_settings(changes):
    name = next(iter(changes))
    with pytest.raises(ValueError, match=name):
        UncertaintyConfig(**changes)
