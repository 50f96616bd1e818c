"""Tests of freqbrdf.uncertainty: the toy cases of the paper's Fig. 4, exposure invariance, dark
texels, flags, and the fast kernel against a direct O(R^2 l*) evaluation of the grid.

Spectra are built from the model itself, one SH coefficient per degree: the light's a_l =
sqrt(S_refl(l)) from a chosen light spectrum, the observation's b_l = k_s G_l(alpha) a_l (plus
noise; G the lobe's filter, `lobe_filter`: exp(-alpha^2 l^2)),
b_0 = specular plus diffuse; S_out = b^2.
These are unit tests of the mathematics; no rendering.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from freqbrdf import uncertainty as unc
from freqbrdf.config import EstimateConfig, UncertaintyConfig
from freqbrdf.sphere import harmonics as sh
from freqbrdf.uncertainty.roughness_std import _neighbour_variance
from helpers import observations_from_spectra

LMAX = 5
DEGREES = np.arange(LMAX + 1)
SHARP_LIGHT = np.ones(LMAX + 1)  # flat spectrum: every degree carries power
LOW_LIGHT = np.array([1.0, 0.6, 0.0, 0.0, 0.0, 0.0])  # only l <= 1
CALIBRATED = UncertaintyConfig()
PAPER = UncertaintyConfig(mode="paper")


def lobe_filter(alpha, sigma=0.0):
    """Per-degree amplitude filter of a lobe of GGX alpha (scalar, or (..., 1) -> (..., l*+1)),
    divided by the band-limit blur exp(-(sigma l)^2): the paper's Gaussian."""
    alpha = np.asarray(alpha, float)
    return np.exp(-(alpha**2 - sigma**2) * DEGREES**2)


def model_spectra(light, alpha, specular, *, diffuse=0.3, noise=0.0, n=1, seed=0):
    """light, observed (n, 3, l*+1): S_out = k^2 G(alpha)^2 S_refl (`lobe_filter`), noise on
    amplitudes (std ``noise`` x the light's RMS amplitude), DC = (k sqrt(S_refl(0)) + diffuse)^2."""
    rng = np.random.default_rng(seed)
    light = np.broadcast_to(np.asarray(light, float), (n, 3, LMAX + 1)).copy()
    amplitude = specular * lobe_filter(alpha) * np.sqrt(light)
    amplitude = amplitude + noise * np.sqrt(light.sum(-1, keepdims=True)) * rng.standard_normal(light.shape)
    amplitude[..., 0] = np.broadcast_to(specular, light.shape)[..., 0] * np.sqrt(light[..., 0]) + diffuse
    return light, np.square(amplitude)


def entropy(light, observed, **kwargs):
    """`entropy_from_spectra`."""
    return unc.entropy_from_spectra(light, observed, **kwargs)


def naive_grid(light, observed, sigma, config, n_samples=None):
    """Direct evaluation: per texel and channel the full (R, R) grid summed over l, exact exp.

    Returns entropy (N, 3) per channel, likelihood (N, 3, R, R) and misfit (N, 3, R, R).
    """
    grid = unc.hypothesis_grid(config.resolution())
    resolution = grid.resolution
    alpha = grid.alpha[:, None, None]  # (R, 1, 1) rows
    specular = grid.specular[None, :, None]  # (1, R, 1) columns
    degrees = DEGREES[1:][None, None, :]
    n_texels = light.shape[0]
    entropy = np.empty((n_texels, 3))
    likelihood = np.empty((n_texels, 3, resolution, resolution))
    misfits = np.empty((n_texels, 3, resolution, resolution))
    for texel in range(n_texels):
        light_power = light[texel].sum(-1).mean()
        for c in range(3):
            s_refl, s_out = light[texel, c], np.maximum(observed[texel, c], 0.0)
            if config.mode == "paper":
                predicted = specular**2 * np.exp(-2 * alpha**2 * degrees**2) * s_refl[1:]
                misfit = np.mean((predicted - s_out[1:]) ** 2, axis=-1) * s_out[0] ** 2
                exponent = (misfit - misfit.min()) / config.temperature
                prior = np.ones((resolution, resolution))
            else:
                kernel = np.array([lobe_filter(a, sigma) for a in grid.alpha])[:, None, 1:]
                predicted = specular * kernel * np.sqrt(s_refl[1:])  # amplitudes in phase
                misfit = np.sum((predicted - np.sqrt(s_out[1:])) ** 2, axis=-1)
                # The specular DC may not exceed the observed DC.
                dc_excess = np.maximum(grid.specular[None, :] * math.sqrt(s_refl[0]) - math.sqrt(s_out[0]), 0.0) ** 2
                misfit = misfit + dc_excess
                samples_per_coeff = 1.0 if n_samples is None else max(n_samples[texel], 1) / (LMAX + 1) ** 2
                noise = 2 * config.noise_level**2 * light_power / samples_per_coeff
                if config.residual_noise:  # plus the best cell's misfit per residual degree of freedom
                    noise += 2 * misfit.min() / max(LMAX - 2, 1)
                exponent = (misfit - misfit.min()) / noise if light_power > 0 else np.zeros_like(misfit)
                prior = np.ones((resolution, resolution))
                prior[:, 0] = 1.0 / resolution  # the k = 0 column is one material
            posterior = prior * np.exp(-exponent)
            posterior /= posterior.sum()
            if config.mode == "paper":
                masses = posterior.ravel()
                n_hypotheses = resolution**2
            else:
                masses = np.concatenate([[posterior[:, 0].sum()], posterior[:, 1:].ravel()])
                n_hypotheses = resolution * (resolution - 1) + 1
            masses = masses[masses > 0]
            entropy[texel, c] = -np.sum(masses * np.log(masses)) / math.log(n_hypotheses)
            likelihood[texel, c] = posterior
            misfits[texel, c] = misfit
    return entropy, likelihood, misfits


# --------------------------------------------------------------------------------------------
# The toy cases of Fig. 4


def test_sharp_light_is_certain_and_recovers_the_material():
    alpha, specular = (4 / 7) ** 2, 6 / 7  # on the R = 8 grid
    light, observed = model_spectra(SHARP_LIGHT, alpha, specular, noise=0.002)
    result = entropy(light, observed, config=CALIBRATED)
    assert result.entropy[0] < 0.15
    assert result.best_alpha[0] == pytest.approx(alpha)
    assert result.best_ks[0] == pytest.approx(specular)
    assert result.likelihood[0].max() > 0.5


def test_low_frequency_light_gives_a_ridge_of_roughness_values():
    alpha, specular = (4 / 7) ** 2, 6 / 7
    sharp = entropy(*model_spectra(SHARP_LIGHT, alpha, specular, noise=0.002))
    low = entropy(*model_spectra(LOW_LIGHT, alpha, specular, noise=0.002))
    assert low.entropy[0] > sharp.entropy[0] + 0.2

    # A ridge: many roughness rows hold a cell nearly as likely as the best one; sharp light
    # singles out one or two rows.
    def plausible_rows(result):
        grid = result.likelihood[0]
        return int(np.sum(grid.max(axis=1) > 0.1 * grid.max()))

    assert plausible_rows(low) >= 5
    assert plausible_rows(sharp) <= 2
    # The paper's recipe sees it too, though its absolute tau makes the size exposure dependent.
    paper_sharp = entropy(*model_spectra(SHARP_LIGHT, alpha, specular, noise=0.002), config=PAPER)
    paper_low = entropy(*model_spectra(LOW_LIGHT, alpha, specular, noise=0.002), config=PAPER)
    assert paper_low.entropy[0] > paper_sharp.entropy[0] + 0.1


def test_weak_specular_relative_to_noise_is_uncertain():
    config = UncertaintyConfig(noise_level=0.05)
    alpha = (4 / 7) ** 2
    strong = entropy(*model_spectra(SHARP_LIGHT, alpha, 0.9, noise=0.05), config=config)
    weak = entropy(*model_spectra(SHARP_LIGHT, alpha, 0.15, noise=0.05), config=config)
    assert weak.entropy[0] > 0.5
    assert weak.entropy[0] > strong.entropy[0] + 0.25


# --------------------------------------------------------------------------------------------
# What the calibrated mode fixes


def test_exposure_invariance_holds_in_calibrated_mode_and_fails_in_paper_mode():
    rng = np.random.default_rng(3)
    light, observed = model_spectra(
        SHARP_LIGHT * np.exp(-0.3 * DEGREES), rng.uniform(0, 1, (40, 1, 1)) ** 2, rng.uniform(0, 1, (40, 3, 1)),
        noise=0.01, n=40,
    )
    reference = entropy(light, observed, config=CALIBRATED)
    paper_reference = entropy(light, observed, config=PAPER)
    for kappa in (1e-3, 1e-1, 10.0, 1e3):
        # images and environment scaled by kappa: every spectrum by kappa^2
        scaled = entropy(light * kappa**2, observed * kappa**2, config=CALIBRATED)
        np.testing.assert_allclose(scaled.entropy, reference.entropy, atol=1e-5)
        np.testing.assert_allclose(scaled.likelihood, reference.likelihood, atol=1e-5)
        np.testing.assert_array_equal(scaled.channel, reference.channel)
        paper = entropy(light * kappa**2, observed * kappa**2, config=PAPER)
        assert np.max(np.abs(paper.entropy - paper_reference.entropy)) > 0.1


def test_dark_texel_under_sharp_light_is_certain_in_calibrated_mode_only():
    light, observed = model_spectra(SHARP_LIGHT, 0.3, 0.0, diffuse=0.0, noise=0.002)
    calibrated = entropy(light, observed, config=CALIBRATED)
    assert calibrated.entropy[0] < 0.1
    assert calibrated.best_ks[0] == 0.0 and np.isnan(calibrated.best_alpha[0])  # no lobe, no roughness
    paper = entropy(light, observed, config=PAPER)
    assert paper.entropy[0] > 0.9


def test_a_texel_no_hypothesis_explains_is_not_called_certain():
    # Observed power that rises with l under a flat light: no (alpha, k) produces it. With a fixed
    # noise floor the posterior still piles onto the least bad cell; with the residual in the
    # noise (the default) the texel is uncertain.
    light = np.tile(SHARP_LIGHT, (1, 3, 1))
    observed = np.tile(0.05 * (1.0 + DEGREES) ** 2, (1, 3, 1))
    fixed = entropy(light, observed, config=UncertaintyConfig(residual_noise=False))
    residual = entropy(light, observed, config=CALIBRATED)
    assert fixed.entropy[0] < 0.25
    assert residual.entropy[0] > fixed.entropy[0] + 0.3


def test_fewer_samples_mean_more_uncertainty():
    # The same fitted spectra from 8 or 200 samples: each coefficient is noisier with fewer.
    light, observed = model_spectra(SHARP_LIGHT, (3 / 7) ** 2, 3 / 7, noise=0.01)
    few = entropy(light, observed, n_samples=np.array([8]), config=CALIBRATED)
    many = entropy(light, observed, n_samples=np.array([200]), config=CALIBRATED)
    assert few.entropy[0] > many.entropy[0] + 0.1


def test_band_limit_compensation_is_applied_in_calibrated_mode():
    # Data made with the blurred light: the compensated kernel recovers the true alpha.
    sigma, alpha, specular = 0.3, (4 / 7) ** 2, 6 / 7
    blurred = SHARP_LIGHT * np.exp(-2 * sigma**2 * DEGREES**2)
    light = model_spectra(blurred, alpha, specular)[0]
    amplitude = np.sqrt(model_spectra(SHARP_LIGHT, alpha, specular)[1])  # the sharp truth was observed
    observed = np.square(amplitude)
    compensated = entropy(light, observed, sigma=sigma, config=CALIBRATED)
    uncompensated = entropy(light, observed, sigma=0.0, config=CALIBRATED)
    assert compensated.best_alpha[0] == pytest.approx(alpha)
    assert uncompensated.best_alpha[0] < alpha


# --------------------------------------------------------------------------------------------
# The fast kernel against the direct evaluation


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    grid_res=st.integers(2, 10),
    mode=st.sampled_from(["calibrated", "paper"]),
    sigma=st.sampled_from([0.0, 0.1, 0.25]),
    residual_noise=st.booleans(),
    with_counts=st.booleans(),
)
def test_fast_kernel_equals_direct_evaluation(seed, grid_res, mode, sigma, residual_noise, with_counts):
    rng = np.random.default_rng(seed)
    n_texels = 7
    light = rng.uniform(0.0, 1.0, (n_texels, 3, LMAX + 1)) * np.exp(-rng.uniform(0, 1) * DEGREES)
    observed = light * rng.uniform(0.0, 1.0, (n_texels, 3, 1)) * np.exp(-rng.uniform(0, 2) * DEGREES)
    observed += rng.uniform(0.0, 0.05, observed.shape)
    config = UncertaintyConfig(mode=mode, grid_res=grid_res, noise_level=rng.uniform(0.01, 0.2),
                               temperature=10 ** rng.uniform(-4, -1), residual_noise=residual_noise)
    n_samples = rng.integers(0, 100, n_texels) if with_counts else None
    fast = entropy(light, observed, n_samples=n_samples, sigma=sigma, config=config)
    calibrated = mode == "calibrated"
    per_channel, likelihood, misfit = naive_grid(light, observed, sigma if calibrated else 0.0, config,
                                                 n_samples if calibrated else None)

    texels = np.arange(n_texels)
    chosen = fast.channel.astype(int)
    # The kernel's cells are float32 with an exp of relative error < 1e-5: 2e-5 is ~30x the
    # float32 resolution of an entropy near 1, and far below any difference a mistake in a
    # misfit, temperature or normalisation makes.
    np.testing.assert_allclose(fast.entropy, per_channel.min(axis=1), atol=2e-5)
    np.testing.assert_allclose(per_channel[texels, chosen], per_channel.min(axis=1), atol=2e-5)
    np.testing.assert_allclose(fast.likelihood, likelihood[texels, chosen], atol=2e-5)
    # The arg-max cell has the least misfit of its channel's grid (k = 0: any row, same misfit).
    col = np.abs(fast.grid.specular[None, :] - fast.best_ks[:, None]).argmin(axis=1)
    row = np.abs(fast.grid.alpha[None, :] - np.nan_to_num(fast.best_alpha)[:, None]).argmin(axis=1)
    best_misfit = misfit[texels, chosen, row, col]
    lowest = misfit[texels, chosen].reshape(n_texels, -1).min(axis=1)
    np.testing.assert_allclose(best_misfit, lowest, rtol=1e-9, atol=1e-15)


# --------------------------------------------------------------------------------------------
# Flags, the Observations entry point, summary, determinism


def test_flags_mark_unobserved_few_samples_below_bound_and_ambiguous():
    light, observed = model_spectra(SHARP_LIGHT, (2 / 7) ** 2, 6 / 7, noise=0.002, n=5)
    light[3], observed[3] = 0.0, 0.0  # nothing observed
    light[4, :, 1:] = 0.0  # no light above l = 0: nothing to tell hypotheses apart
    observed[4, :, 1:] = 0.0
    alpha_bound = np.array([0.1, 0.01, 0.01, 0.01, 0.01], np.float32)  # texel 0: (2/7)^2 = 0.08 < 0.1
    fit_status = np.array([sh.FIT_OK, sh.FIT_UNDERDETERMINED, sh.FIT_OK, sh.FIT_EMPTY, sh.FIT_OK], np.uint8)
    n_samples = np.array([64, 8, 64, 0, 64])  # texel 1: fewer than a quarter of the 36 coefficients
    result = entropy(light, observed, n_samples=n_samples, alpha_bound=alpha_bound, fit_status=fit_status)
    expected = [unc.FLAG_BELOW_BOUND, unc.FLAG_FEW_SAMPLES, 0, unc.FLAG_UNOBSERVED, unc.FLAG_AMBIGUOUS]
    np.testing.assert_array_equal(result.flags, expected)
    assert result.entropy[3] == 1.0 and result.channel[3] == -1 and np.isnan(result.best_ks[3])
    assert result.likelihood[3].sum() == pytest.approx(1.0)
    assert result.entropy[4] > 0.99

    stats = unc.summary(result)
    assert stats["observed_texels"] == 4
    assert stats["flagged_fraction"]["unobserved"] == pytest.approx(0.2)
    assert stats["entropy_mean"] == pytest.approx(float(np.delete(result.entropy, 3).mean()), rel=1e-6)


def _observations_from_spectra(light, observed, texel_index, texture_res):
    """An Observations whose fits have the given spectra (degree LMAX), 64 samples per texel."""
    return observations_from_spectra(light, observed, texel_index, texture_res, LMAX)


def test_entropy_map_from_observations_and_texture():
    light, observed = model_spectra(SHARP_LIGHT, (4 / 7) ** 2, 6 / 7, noise=0.002, n=3)
    observed[1] = model_spectra(LOW_LIGHT, (4 / 7) ** 2, 6 / 7)[1][0]
    light[1] = LOW_LIGHT
    observations = _observations_from_spectra(light, observed, np.array([0, 5, 15]), texture_res=4)
    result = unc.entropy_map(observations)
    direct = entropy(light, observed, n_samples=observations.n_samples)
    np.testing.assert_allclose(result.entropy, direct.entropy, atol=1e-5)  # float32 coefficients
    texture = result.to_texture(observations, "entropy", fill=-1.0)
    assert texture.shape == (4, 4)
    assert texture[1, 1] == result.entropy[1] and texture[3, 3] == result.entropy[2]
    assert np.count_nonzero(texture == -1.0) == 13
    assert result.to_texture(observations, "likelihood").shape == (4, 4, 8, 8)


def test_likelihood_is_optional_and_results_are_deterministic():
    rng = np.random.default_rng(11)
    light, observed = model_spectra(SHARP_LIGHT, rng.uniform(0, 1, (3000, 1, 1)) ** 2,
                                    rng.uniform(0, 1, (3000, 3, 1)), noise=0.02, n=3000)
    config = UncertaintyConfig(grid_res=16)
    first = entropy(light, observed, config=config)
    without = entropy(light, observed, config=config, return_likelihood=False)
    assert without.likelihood is None
    np.testing.assert_array_equal(first.entropy, without.entropy)
    np.testing.assert_array_equal(first.best_ks, without.best_ks)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        single = entropy(light, observed, config=config)
    finally:
        numba.set_num_threads(threads)
    for name in ("entropy", "flags", "likelihood", "best_alpha", "best_ks", "channel"):
        np.testing.assert_array_equal(getattr(single, name), getattr(first, name))
    np.testing.assert_allclose(first.likelihood.sum(axis=(1, 2)), 1.0, rtol=1e-5)


def test_paper_preset_reproduces_the_published_grid():
    from freqbrdf.config import preset

    config = preset("paper").uncertainty
    grid = unc.hypothesis_grid(config.resolution())
    assert (config.mode, config.grid_res, config.temperature) == ("paper", 8, 1e-5)
    np.testing.assert_allclose(grid.alpha, (np.arange(8) / 7) ** 2)
    np.testing.assert_allclose(grid.specular, np.arange(8) / 7)


# --------------------------------------------------------------------------------------------
# The posterior spread of the estimated roughness (unc.roughness_std)


def _estimate_of(observations, roughness, estimated):
    from freqbrdf.estimate import MaterialEstimate

    n_texels = observations.n_texels
    return MaterialEstimate(
        texture_res=observations.texture_res, texel_index=observations.texel_index,
        base_color=np.full((n_texels, 3), 0.5), roughness=np.where(estimated, roughness, np.nan),
        metallic=np.zeros(n_texels), estimated=estimated, loss=np.zeros(n_texels), method="global",
    )


def test_neighbour_term_is_the_scatter_of_the_estimates_in_the_window():
    import dataclasses

    from freqbrdf.config import Config

    rng = np.random.default_rng(3)
    texture_res, window = 7, 3
    texel_index = np.array([i for i in range(texture_res**2) if i not in (23, 40)])  # two holes in the atlas
    light, observed = model_spectra(SHARP_LIGHT, 0.1, 0.5, n=len(texel_index))
    observations = _observations_from_spectra(light, observed, texel_index, texture_res)
    roughness = rng.uniform(0.0, 1.0, len(texel_index))
    estimated = np.ones(len(texel_index), bool)
    estimated[5] = False
    lonely = [list(texel_index).index(48)]  # the corner texel; its neighbours are left unestimated
    for neighbour in (41, 47):  # 40 is a hole
        estimated[list(texel_index).index(neighbour)] = False
    config = dataclasses.replace(Config(), uncertainty=UncertaintyConfig(roughness_window=window, loss_curvature=False))
    spread = unc.roughness_std(observations, _estimate_of(observations, roughness, estimated), config)

    texture = np.full((texture_res, texture_res), np.nan)
    texture.ravel()[texel_index[estimated]] = roughness[estimated]
    for texel, flat in enumerate(texel_index):
        if not estimated[texel]:
            assert np.isnan(spread[texel])
            continue
        row, column = divmod(flat, texture_res)
        values = texture[max(row - 1, 0):row + 2, max(column - 1, 0):column + 2]
        values = values[np.isfinite(values)]
        expected = math.sqrt(1 / 12) if len(values) == 1 else values.std()  # alone: the uniform prior
        assert spread[texel] == pytest.approx(expected, abs=1e-6), (texel, len(values))
    assert spread[lonely[0]] == pytest.approx(math.sqrt(1 / 12))

    flat_estimate = _estimate_of(observations, np.full(len(texel_index), 0.4), estimated)
    np.testing.assert_allclose(unc.roughness_std(observations, flat_estimate, config)[estimated & (np.arange(
        len(texel_index)) != lonely[0])], 0.0, atol=1e-6)  # agreeing neighbours: no scatter
    off = dataclasses.replace(Config(), uncertainty=UncertaintyConfig(roughness_window=0, loss_curvature=False))
    assert unc.roughness_std(observations, flat_estimate, off) is None


def test_loss_curvature_spread_ranks_and_scales_like_the_roughness_error():
    """On texels rendered by the estimator's own model with noise, the Laplace std of the loss
    is on the scale of the actual roughness error and ranks it; a texel seen twice as often (every
    sample repeated) has about half the variance."""
    import dataclasses

    from scipy import stats

    from estimate.test_estimate import random_truth, synthetic_observations
    from freqbrdf.config import Config
    from freqbrdf.estimate import estimate

    truth = random_truth(200, seed=3)
    clean = synthetic_observations(truth, seed=4, model="split_sum")
    rng = np.random.default_rng(5)
    rms = np.sqrt(np.mean(np.square(clean.observed), axis=(1, 2), keepdims=True))
    observations = dataclasses.replace(
        clean, observed=(clean.observed + 0.05 * rms * rng.standard_normal(clean.observed.shape)).astype(np.float32))
    config = dataclasses.replace(Config(), uncertainty=UncertaintyConfig(roughness_window=0, loss_curvature=True))
    result = estimate(observations, config)
    spread = unc.roughness_std(observations, result, config)
    error = np.abs(result.roughness - truth.roughness)
    assert stats.spearmanr(spread, error).statistic > 0.25
    assert 0.2 < np.median(error / spread) < 1.5  # a calibrated (half-normal) error: 0.67

    def repeated(name):
        return np.concatenate([getattr(observations, name)] * 2, axis=1)

    twice = dataclasses.replace(observations, **{name: repeated(name) for name in (
        "view_direction", "observed", "mirrored", "weight", "visible")}, n_samples=2 * observations.n_samples)
    informative = spread**2 < 0.9 / 12  # not capped at the prior
    ratio = unc.roughness_std(twice, result, config)[informative] ** 2 / spread[informative] ** 2
    # Half, but for the residual's degrees of freedom: its noise variance L 3n / (3n - 5) becomes
    # L 6n / (6n - 5), which lowers the ratio the more the more of the noise is the misfit L.
    values = 3.0 * observations.n_samples[informative]
    lowest = 0.5 * (2 * values / (2 * values - 5)) / (values / (values - 5))
    assert np.all((ratio >= lowest * (1 - 1e-5)) & (ratio <= 0.5 * (1 + 1e-5)))
    assert np.any(ratio < 0.5 * (1 - 1e-3))


def test_split_half_spread_is_zero_on_exact_data_and_ranks_the_error_under_noise():
    """The split-half term alone: the even and the odd views each recover exact data of the
    estimator's own model, so they agree; with noise their scatter ranks the roughness error and is
    on its scale, and it is the halves' own estimates' difference."""
    import dataclasses

    from scipy import stats

    from estimate.test_estimate import random_truth, synthetic_observations
    from freqbrdf.config import Config
    from freqbrdf.estimate import estimate

    truth = random_truth(200, seed=3)
    # The default model, whose light is the map's (prefiltered, environment light) as on real
    # captures: a light fitted to half the samples would not be the one the data were made with.
    clean = synthetic_observations(truth, seed=4, model="split_sum", environment_light=True, prefiltered=True)
    config = dataclasses.replace(
        Config(), uncertainty=UncertaintyConfig(roughness_window=0, loss_curvature=False, split_half=True))
    exact = unc.roughness_std(clean, estimate(clean, config), config)
    assert np.nanmax(exact) < 1e-4

    rng = np.random.default_rng(5)
    rms = np.sqrt(np.mean(np.square(clean.observed), axis=(1, 2), keepdims=True))
    observations = dataclasses.replace(
        clean, observed=(clean.observed + 0.05 * rms * rng.standard_normal(clean.observed.shape)).astype(np.float32))
    result = estimate(observations, config)
    spread = unc.roughness_std(observations, result, config)
    error = np.abs(result.roughness - truth.roughness)
    # One difference per texel (no window here) is a one-sample variance estimate: a noisy ranking.
    assert stats.spearmanr(spread, error).statistic > 0.25
    assert 0.3 < np.median(error / np.maximum(spread, 1e-6)) < 3.0

    halves = [estimate(observations.with_views(np.arange(observations.n_views) % 2 == parity, config), config)
              for parity in (0, 1)]
    expected = np.abs(halves[0].roughness - halves[1].roughness) / 2.0
    both = halves[0].estimated & halves[1].estimated
    assert both.mean() > 0.9
    np.testing.assert_allclose(spread[both], expected[both], rtol=1e-5, atol=1e-7)
    assert np.all(spread[~both] == np.float32(np.sqrt(1 / 12)))


def test_split_half_on_every_other_row_and_column_is_spread_by_the_window():
    """With split_half_stride 2, only the estimated texels of even rows and columns are estimated
    twice more, and each texel's term is the mean of their scatters in its window."""
    import dataclasses

    from estimate.test_estimate import random_truth, synthetic_observations
    from freqbrdf.config import Config
    from freqbrdf.estimate import estimate

    truth = random_truth(196, seed=3)  # a 14 x 14 texture
    clean = synthetic_observations(truth, seed=4, model="split_sum", environment_light=True, prefiltered=True)
    rng = np.random.default_rng(5)
    rms = np.sqrt(np.mean(np.square(clean.observed), axis=(1, 2), keepdims=True))
    observations = dataclasses.replace(
        clean, observed=(clean.observed + 0.05 * rms * rng.standard_normal(clean.observed.shape)).astype(np.float32))
    settings = UncertaintyConfig(roughness_window=3, loss_curvature=False, split_half=True, split_half_stride=2)
    config = dataclasses.replace(Config(), uncertainty=settings)
    result = estimate(observations, config)
    spread = unc.roughness_std(observations, result, config)

    roughness = np.where(result.estimated, result.roughness, np.nan)
    rows, columns = np.divmod(observations.texel_index, observations.texture_res)
    chosen = np.flatnonzero(np.isfinite(roughness) & (rows % 2 == 0) & (columns % 2 == 0))
    assert 0.2 < len(chosen) / observations.n_texels < 0.3
    part = observations.select(chosen)
    halves = [estimate(part.with_views(np.arange(observations.n_views) % 2 == parity, config), config).roughness
              for parity in (0, 1)]
    scatter = np.nan_to_num(np.square(halves[0] - halves[1]) / 4.0, nan=1 / 12)
    near = ((np.abs(rows[:, None] - rows[chosen][None, :]) <= 1)
            & (np.abs(columns[:, None] - columns[chosen][None, :]) <= 1))
    expected = (near * scatter[None, :]).sum(axis=1) / near.sum(axis=1)  # every 3 x 3 window holds one
    neighbour = _neighbour_variance(observations, roughness, 3)
    estimated = np.isfinite(roughness)
    np.testing.assert_allclose(np.square(spread[estimated].astype(np.float64)) - neighbour[estimated],
                               expected[estimated], rtol=1e-4, atol=1e-8)
    assert np.all(np.isnan(spread[~estimated]))
    # A stride of 1 (or a window no wider than the stride) re-estimates every texel.
    every = dataclasses.replace(config, uncertainty=dataclasses.replace(settings, split_half_stride=1))
    assert not np.allclose(unc.roughness_std(observations, result, every), spread, equal_nan=True)
    with pytest.raises(ValueError, match="split_half_stride"):
        unc.roughness_std(observations, result, dataclasses.replace(
            config, uncertainty=dataclasses.replace(settings, split_half_stride=0)))


def _direct_angular_entropy(observations, grid, noise_level):
    """The angular mode written out with numpy, per texel and channel, as the path-traced brute
    force (benchmarks/pathtraced_entropy.py) scores its renderings: the hypotheses' radiance from the
    estimator's default model with the fitted light (hand-made observations carry no map)."""
    from freqbrdf.model.light import lobe_filtered_light
    from freqbrdf.model.tables import split_sum_terms

    out = np.empty(observations.n_texels)
    resolution = grid.resolution
    for t in range(observations.n_texels):
        seen = observations.weight[t] > 0
        directions = observations.view_direction[t:t + 1].astype(np.float64)
        weight = observations.weight[t].astype(np.float64)[seen]
        share = weight / weight.sum()
        radiance = np.zeros((resolution, resolution, int(seen.sum()), 3))
        for i, alpha in enumerate(grid.alpha):
            roughness = math.sqrt(alpha)
            scale, bias, _ = split_sum_terms(directions[0, seen, 2], roughness)
            light = lobe_filtered_light(directions, observations.weight[t:t + 1], observations.mirrored_coeffs[t:t + 1],
                                        observations.lmax, observations.sigma, np.array([roughness]))[0, seen]
            for j, specular in enumerate(grid.specular):
                if specular > 0:  # k = 0: no lobe
                    radiance[i, j] = (specular * scale + bias)[:, None] * light
        observed = observations.observed[t, seen].astype(np.float64)
        n = len(weight)
        entropies = []
        for c in range(3):
            residual = observed[None, None, :, c] - radiance[..., c]
            diffuse = np.maximum((residual * share).sum(axis=-1, keepdims=True), 0.0)
            misfit = ((residual - diffuse) ** 2 * share).sum(axis=-1)
            light_rms = math.sqrt(float((observations.mirrored[t, seen, c].astype(np.float64) ** 2 * share).sum()))
            variance = (noise_level * light_rms) ** 2 + misfit.min() * n / max(n - 3, 1)
            posterior = np.exp(-n * (misfit - misfit.min()) / (2.0 * variance))
            posterior[:, 0] /= resolution
            posterior /= posterior.sum()
            masses = np.concatenate([[posterior[:, 0].sum()], posterior[:, 1:].ravel()])
            masses = masses[masses > 0]
            entropies.append(-(masses * np.log(masses)).sum() / math.log(resolution * (resolution - 1) + 1))
        out[t] = min(entropies)
    return out


def _mapped_observations(truth, rng):
    """Synthetic observations of ``truth`` under a map (prefiltered and environment light), 3 % noise."""
    import dataclasses

    from estimate.test_estimate import synthetic_observations

    mapped = synthetic_observations(truth, seed=8, model="split_sum", environment_light=True, prefiltered=True)
    return dataclasses.replace(mapped, observed=(mapped.observed * (
        1.0 + 0.03 * rng.standard_normal(mapped.observed.shape))).astype(np.float32))


@pytest.mark.parametrize("grid_res", [None, 4])
def test_the_estimators_search_scores_the_angular_hypotheses_as_the_angular_mode(grid_res, monkeypatch):
    """The fit's shortcut: the search records the hypotheses at its roughness nodes (grid_res None:
    all of them; 4: roughness 1/3 and 2/3 lie off the nodes and are probed apart) and the entropy
    equals the angular mode's own pass, the estimate the plain estimator's. In blocks of 16 texels
    here (the last one partial), as large captures are."""
    from estimate.test_estimate import random_truth
    from freqbrdf import estimate as estimate_module
    from freqbrdf.config import Config
    from freqbrdf.estimate import estimate

    monkeypatch.setattr(estimate_module, "HYPOTHESIS_BLOCK", 16)
    observations = _mapped_observations(random_truth(40, seed=3, min_roughness=0.0), np.random.default_rng(4))
    config = Config(uncertainty=UncertaintyConfig(mode="angular", grid_res=grid_res))
    assert unc.AngularEntropy.recorded_by_search(config)
    scorer = unc.AngularEntropy(observations, config)
    recorded = estimate(observations, config, hypotheses=scorer.recorder())
    fused = scorer.result()
    alone = unc.entropy_angular(observations, config)
    assert fused.grid.resolution == (grid_res or config.estimate.roughness_grid)
    np.testing.assert_allclose(fused.entropy, alone.entropy, atol=1e-6)
    np.testing.assert_allclose(fused.likelihood, alone.likelihood, atol=1e-6)
    np.testing.assert_array_equal(fused.flags, alone.flags)
    plain = estimate(observations, config)
    for name in ("base_color", "roughness", "metallic", "loss"):
        np.testing.assert_array_equal(getattr(recorded, name), getattr(plain, name))
    # The prototype's estimator does not search: its hypotheses are scored in a pass of their own.
    assert not unc.AngularEntropy.recorded_by_search(
        Config(uncertainty=UncertaintyConfig(mode="angular"), estimate=EstimateConfig(method="paper")))
    assert not unc.AngularEntropy.recorded_by_search(Config())


def test_angular_mode_equals_a_direct_evaluation_and_is_exposure_invariant():
    import dataclasses

    from estimate.test_estimate import random_truth, synthetic_observations

    truth = random_truth(24, seed=7, min_roughness=0.0)
    clean = synthetic_observations(truth, seed=8, model="split_sum")
    rng = np.random.default_rng(9)
    observations = dataclasses.replace(clean, observed=(clean.observed * (
        1.0 + 0.03 * rng.standard_normal(clean.observed.shape))).astype(np.float32))
    config = UncertaintyConfig(mode="angular")
    result = unc.entropy_map(observations, config)
    # The default grid: the estimator's roughness nodes.
    assert result.mode == "angular" and result.likelihood.shape == (24, 9, 9)
    np.testing.assert_allclose(result.likelihood.sum(axis=(1, 2)), 1.0, rtol=1e-5)
    direct = _direct_angular_entropy(observations, unc.hypothesis_grid(9), config.noise_level)
    np.testing.assert_allclose(result.entropy, direct, atol=2e-5)
    # The same from the moments alone (the angular mode's analogue of entropy_from_spectra).
    from freqbrdf.estimate import hypothesis_moments

    moments = hypothesis_moments(observations, np.arange(9) / 8)
    scored = unc.entropy_from_moments(moments, observations.weight, observations.mirrored, observations.n_samples)
    np.testing.assert_allclose(scored.entropy, result.entropy, atol=1e-6)
    np.testing.assert_allclose(scored.likelihood, result.likelihood, atol=1e-6)
    with pytest.raises(ValueError, match="angular"):
        unc.entropy_from_moments(moments, observations.weight, observations.mirrored, observations.n_samples,
                                 config=UncertaintyConfig())
    # Fewer views, less certain: the same texels seen from their first 8 views only.
    few_weight = observations.weight.copy()
    few_weight[:, 8:] = 0.0
    few = dataclasses.replace(observations, weight=few_weight, n_samples=(few_weight > 0).sum(axis=1))
    assert unc.entropy_map(few, config).entropy.mean() > 2.0 * result.entropy.mean()
    # Exposure: every image and the environment scaled by kappa.
    kappa = 7.5
    brighter = dataclasses.replace(
        observations, observed=observations.observed * kappa, mirrored=observations.mirrored * kappa,
        mirrored_coeffs=observations.mirrored_coeffs * kappa, irradiance=observations.irradiance * kappa)
    np.testing.assert_allclose(unc.entropy_map(brighter, config).entropy, result.entropy, atol=1e-5)
    # Spectra alone cannot be scored in this mode.
    with pytest.raises(ValueError, match="angular"):
        unc.entropy_from_spectra(observations.mirrored_spectrum, observations.observed_spectrum, config=config)
