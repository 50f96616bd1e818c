"""Tests of freqbrdf.model.brdf: the Principled mapping, Fresnel/G1, the BRDF kernel, the three forward
models and the sampling-theory bounds. Every reference value is computed independently here."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, optimize

from freqbrdf.config import FitConfig
from freqbrdf.model import brdf
from freqbrdf.sphere import harmonics as sh

LMAX = 5
K = (LMAX + 1) ** 2


def _fibonacci_hemisphere(n: int) -> np.ndarray:
    """n roughly uniform unit directions with z > 0, (n, 3)."""
    i = np.arange(n) + 0.5
    z = 1.0 - i / n
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def _holey_hemisphere_samples(n_texels: int, n_views: int, rng: np.random.Generator):
    """Sparse hemisphere samples per texel with an occluded wedge and random misses.

    Returns directions (T, V, 3) and weights (T, V) = cos(theta) x observed.
    """
    base = _fibonacci_hemisphere(n_views)
    directions = np.empty((n_texels, n_views, 3))
    weights = np.empty((n_texels, n_views))
    for t in range(n_texels):
        angle = rng.uniform(0, 2 * math.pi)  # rotate so each texel has its own sample set
        c, s = math.cos(angle), math.sin(angle)
        d = base @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        phi = np.arctan2(d[:, 1], d[:, 0])
        observed = (np.abs(phi) > 0.6) & (rng.uniform(size=n_views) > 0.15)  # wedge + missed views
        directions[t] = d
        weights[t] = np.where(observed, d[:, 2], 0.0)
    return directions, weights


def _fit(directions, weights, values, fit: FitConfig):
    return sh.fit_sh(
        directions,
        weights,
        values,
        lmax=fit.lmax,
        reg_lambda=fit.reg_lambda,
        regulariser=fit.regulariser,
        scale_lambda_with_weight=fit.scale_lambda_with_weight,
    ).coeffs


def _random_microfacet(rng, n_texels, *, alpha=None):
    return brdf.MicrofacetParams(
        diffuse_albedo=rng.uniform(0.0, 1.0, (n_texels, 3)),
        specular_r0=rng.uniform(0.02, 1.0, (n_texels, 3)),
        alpha=rng.uniform(0.02, 0.6, n_texels) if alpha is None else np.full(n_texels, alpha),
    )


# ---------------------------------------------------------------------------------------------
# Fresnel and G1


def test_schlick_fresnel_limits_and_monotonicity():
    r0 = np.array([0.04, 0.5, 0.95])
    np.testing.assert_allclose(brdf.schlick_fresnel(1.0, r0), r0)
    np.testing.assert_allclose(brdf.schlick_fresnel(0.0, r0), 1.0)
    cos_theta = np.linspace(0.0, 1.0, 50)[:, None]
    fresnel = brdf.schlick_fresnel(cos_theta, r0)
    assert np.all(np.diff(fresnel, axis=0) <= 0.0)  # reflectance grows towards grazing


def test_schlick_fresnel_approximates_exact_dielectric_fresnel():
    # Schlick's curve stays within 0.036 of the exact unpolarised Fresnel reflectance of glass
    # (eta = 1.5, R0 = 0.04); an exponent of 4 or 6 would be 0.10 or 0.055 off.
    eta = 1.5
    cos_i = np.linspace(0.0, 1.0, 1001)
    cos_t = np.sqrt(1.0 - (1.0 - cos_i**2) / eta**2)
    r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    r_par = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    exact = 0.5 * (r_perp**2 + r_par**2)
    r0 = ((eta - 1.0) / (eta + 1.0)) ** 2
    assert np.max(np.abs(brdf.schlick_fresnel(cos_i, r0) - exact)) < 0.04


def _ggx_ndf(cos_m, alpha):
    return alpha**2 / (math.pi * ((alpha**2 - 1.0) * cos_m**2 + 1.0) ** 2)


def _g1_by_integration(theta_o: float, alpha: float) -> float:
    """Smith G1 from its definition: G1(w_o) = cos(theta_o) / int max(0, w_o . w_m) D(w_m) dw_m.

    The azimuthal integral of max(0, a + b cos phi) is done in closed form, the polar one by quad.
    """

    def azimuthal(theta_m):
        a = math.cos(theta_o) * math.cos(theta_m)
        b = math.sin(theta_o) * math.sin(theta_m)
        if a >= b:
            return 2.0 * math.pi * a
        phi0 = math.acos(-a / b)
        return 2.0 * (a * phi0 + math.sqrt(b * b - a * a))

    peak = math.atan(alpha)
    projected_area, _ = integrate.quad(
        lambda tm: _ggx_ndf(math.cos(tm), alpha) * math.sin(tm) * azimuthal(tm),
        0.0,
        math.pi / 2,
        points=[peak, 3 * peak],
        limit=400,
        epsabs=1e-12,
        epsrel=1e-10,
    )
    return math.cos(theta_o) / projected_area


@pytest.mark.parametrize("alpha", [0.05, 0.3, 0.8])
def test_ggx_ndf_quadrature_is_normalised(alpha):
    # Guards the reference integration below: int D(m) cos(theta_m) dm = 1.
    total, _ = integrate.quad(
        lambda tm: _ggx_ndf(math.cos(tm), alpha) * math.cos(tm) * math.sin(tm) * 2 * math.pi,
        0.0,
        math.pi / 2,
        points=[math.atan(alpha)],
        limit=400,
    )
    assert total == pytest.approx(1.0, rel=1e-8)


@pytest.mark.parametrize("alpha", [0.05, 0.3, 0.8])
@pytest.mark.parametrize("theta_deg", [20.0, 60.0, 80.0, 88.0])
def test_smith_g1_matches_masking_definition(alpha, theta_deg):
    theta = math.radians(theta_deg)
    expected = _g1_by_integration(theta, alpha)
    assert brdf.smith_g1_ggx(math.cos(theta), alpha) == pytest.approx(expected, rel=1e-6)


def test_smith_g1_limits():
    alpha = np.array([0.01, 0.3, 1.0])
    np.testing.assert_allclose(brdf.smith_g1_ggx(1.0, alpha), 1.0)
    np.testing.assert_allclose(brdf.smith_g1_ggx(0.0, alpha), 0.0)
    np.testing.assert_array_less(brdf.smith_g1_ggx(1e-6, alpha), 1e-3)
    # Rougher surfaces mask more at every oblique angle.
    g1 = brdf.smith_g1_ggx(np.linspace(0.05, 0.95, 10)[:, None], alpha)
    assert np.all(np.diff(g1, axis=1) < 0.0)


def test_shadowed_light_uses_the_view_cosine():
    rng = np.random.default_rng(0)
    light = rng.uniform(0.1, 2.0, (2, 3, 3))
    cos_theta = np.array([[1.0, 0.5, 0.0], [1.0, 0.2, 0.9]])
    alpha = np.array([0.2, 0.7])
    shadowed = brdf.shadowed_light(light, cos_theta, alpha)
    np.testing.assert_allclose(shadowed[:, 0], light[:, 0])  # normal incidence: unshadowed
    np.testing.assert_allclose(shadowed[0, 2], 0.0)  # grazing: fully shadowed
    ratio = shadowed / light
    np.testing.assert_allclose(ratio[..., 0], ratio[..., 2])  # same factor for every channel


# ---------------------------------------------------------------------------------------------
# Principled <-> microfacet


def test_alpha_is_roughness_squared_and_clamped():
    roughness = np.array([0.0, 0.01, 0.5, 1.0])
    np.testing.assert_allclose(brdf.alpha_from_roughness(roughness), [1e-3, 1e-3, 0.25, 1.0])


def test_forward_mapping_limits():
    base = np.array([[0.9, 0.5, 0.1], [0.9, 0.5, 0.1]])
    mf = brdf.microfacet_from_principled(
        brdf.PrincipledParams(base_color=base, roughness=np.array([0.5, 0.5]), metallic=np.array([0.0, 1.0]))
    )
    np.testing.assert_allclose(mf.specular_r0[0], 0.04)  # dielectric: grey 4 %
    np.testing.assert_allclose(mf.diffuse_albedo[0], base[0])
    np.testing.assert_allclose(mf.specular_r0[1], base[1])  # metal: coloured specular
    np.testing.assert_allclose(mf.diffuse_albedo[1], 0.0)


unit = st.floats(0.0, 1.0, allow_nan=False)


@settings(max_examples=150, deadline=None)
@given(base=st.tuples(unit, unit, unit), metallic=unit, roughness=unit)
def test_principled_round_trip(base, metallic, roughness):
    params = brdf.PrincipledParams(
        base_color=np.array([base]), roughness=np.array([roughness]), metallic=np.array([metallic])
    )
    mf = brdf.microfacet_from_principled(params)
    back = brdf.principled_from_microfacet(mf)
    again = brdf.microfacet_from_principled(back)
    # Always a preimage, to 1e-5 in reflectance: for near-black near-metals (b ~ 1e-4, m ~ 0.99,
    # colours not grey) the profile in m is nearly flat and has a near-twin minimum; over 400k
    # random parameters the largest miss was 4.9e-6 (diffuse) and 5e-8 (R0) ...
    np.testing.assert_allclose(again.diffuse_albedo, mf.diffuse_albedo, atol=1e-5)
    np.testing.assert_allclose(again.specular_r0, mf.specular_r0, atol=1e-5)
    assert np.all((0.0 <= back.base_color) & (back.base_color <= 1.0)) and 0.0 <= back.metallic[0] <= 1.0
    np.testing.assert_allclose(back.roughness, max(roughness, math.sqrt(brdf.ALPHA_MIN)), rtol=1e-12)
    # ... and the original one wherever the map is injective (some channel above 0.04, with
    # margin for conditioning; a colour's channels are only unused by metallic when m = 0).
    if max(base) > 0.06:
        np.testing.assert_allclose(back.metallic, metallic, atol=1e-5)
        np.testing.assert_allclose(back.base_color[0], base, atol=1e-5)


def test_inverse_of_dark_grey_prefers_the_dielectric_twin():
    # (b, m) and (0.04 (1 - m), 1 - b / 0.04) give identical reflectances when b is grey < 0.04.
    b, m = 0.01, 0.6
    twin_b, twin_m = 0.04 * (1 - m), 1 - b / 0.04
    params = [
        brdf.PrincipledParams(np.full((1, 3), bb), np.array([0.5]), np.array([mm]))
        for bb, mm in ((b, m), (twin_b, twin_m))
    ]
    mfs = [brdf.microfacet_from_principled(p) for p in params]
    np.testing.assert_allclose(mfs[0].diffuse_albedo, mfs[1].diffuse_albedo)
    np.testing.assert_allclose(mfs[0].specular_r0, mfs[1].specular_r0)
    for mf in mfs:
        back = brdf.principled_from_microfacet(mf)
        assert back.metallic[0] == pytest.approx(min(m, twin_m), abs=1e-6)


def _reflectance_misfit(params: brdf.PrincipledParams, target: brdf.MicrofacetParams) -> np.ndarray:
    """Squared distance of params' (diffuse albedo, R0) to the target's, per texel: (T,)."""
    pred = brdf.microfacet_from_principled(params)
    diffuse_error = pred.diffuse_albedo - target.diffuse_albedo
    specular_error = pred.specular_r0 - target.specular_r0
    return np.sum(diffuse_error**2 + specular_error**2, axis=1)


def test_inverse_projects_noisy_reflectances_optimally():
    rng = np.random.default_rng(3)
    n = 12
    truth = brdf.PrincipledParams(rng.uniform(0, 1, (n, 3)), rng.uniform(0, 1, n), rng.uniform(0, 1, n))
    mf = brdf.microfacet_from_principled(truth)
    noisy = brdf.MicrofacetParams(
        mf.diffuse_albedo + rng.normal(0, 0.05, (n, 3)), mf.specular_r0 + rng.normal(0, 0.05, (n, 3)), mf.alpha
    )

    back = brdf.principled_from_microfacet(noisy)
    assert np.all((back.base_color >= 0) & (back.base_color <= 1))
    assert np.all((back.metallic >= 0) & (back.metallic <= 1))
    best = _reflectance_misfit(back, noisy)
    # Independent check: bounded quasi-Newton over (b, m) from several starts per texel.
    for t in range(n):
        texel = slice(t, t + 1)
        texel_target = brdf.MicrofacetParams(
            noisy.diffuse_albedo[texel], noisy.specular_r0[texel], mf.alpha[texel]
        )

        def objective(x, target=texel_target):
            return _reflectance_misfit(brdf.PrincipledParams(x[None, :3], np.zeros(1), x[3:]), target)[0]

        starts = [np.concatenate([truth.base_color[t], truth.metallic[texel]])] + list(rng.uniform(0, 1, (3, 4)))
        bounds = [(0.0, 1.0)] * 4
        reference = min(optimize.minimize(objective, x0, method="L-BFGS-B", bounds=bounds).fun for x0 in starts)
        assert best[t] <= reference + 1e-10


# ---------------------------------------------------------------------------------------------
# The BRDF kernel and the band limit


def test_brdf_kernel_is_a_gaussian_low_pass():
    alpha = np.array([brdf.ALPHA_MIN, 0.1, 0.5])
    kernel = brdf.brdf_kernel(alpha, 20)
    np.testing.assert_allclose(kernel[:, 0], 1.0)
    assert np.all(np.diff(kernel, axis=1) < 0.0)
    assert np.all(np.diff(kernel[:, 1:], axis=0) < 0.0)  # rougher = stronger low-pass
    # It is exp(-(alpha l)^2): the log is linear in l^2 with slope -alpha^2.
    slopes = np.polyfit(np.arange(21.0) ** 2, np.log(kernel).T, 1)[0]
    np.testing.assert_allclose(slopes, -(alpha**2), rtol=1e-10)


@pytest.mark.parametrize("n_views", [16, 50, 400])
def test_band_limit_compensation_identity(n_views):
    sigma = brdf.band_limit_sigma(n_views)
    assert sigma == pytest.approx(1.0 / math.floor(math.sqrt(n_views)))
    alpha = np.array([0.5 * sigma, sigma, 0.3, 0.9])
    degrees = np.arange(11)
    lowpass = np.exp(-((sigma * degrees) ** 2))
    compensated = brdf.brdf_kernel(alpha, 10, sigma)
    np.testing.assert_allclose(compensated * lowpass, brdf.brdf_kernel(alpha, 10), rtol=1e-12)
    # Below sigma the compensated kernel amplifies (documented), at sigma it is flat.
    assert np.all(brdf.brdf_kernel(alpha[:1], 10, sigma)[0, 1:] > 1.0)
    np.testing.assert_allclose(brdf.brdf_kernel(alpha[1:2], 10, sigma), 1.0)


# ---------------------------------------------------------------------------------------------
# Forward models


def test_diffuse_term_is_consistent_with_the_fit():
    rng = np.random.default_rng(1)
    directions, weights = _holey_hemisphere_samples(6, 30, rng)
    fit = FitConfig(lmax=LMAX)
    mf = _random_microfacet(rng, 6)
    irradiance = rng.uniform(0.5, 3.0, (6, 3))
    # Observations of a purely diffuse surface: constant radiance d E / pi over the views.
    diffuse_radiance = mf.diffuse_albedo * irradiance / math.pi  # (T, 3)
    observed = np.broadcast_to(diffuse_radiance[:, None, :], (6, 30, 3))
    fitted = _fit(directions, weights, observed, fit)  # (T, 3, K)

    constant_fit = brdf.constant_fit_coeffs(directions, weights, fit)
    no_light = np.zeros((6, 3, K))
    predicted = brdf.predict_sh_coeffs(mf, no_light, irradiance, constant_fit)
    np.testing.assert_allclose(predicted, fitted, rtol=1e-9, atol=1e-12)

    # The prototype put d E / sqrt(pi) into the DC coefficient alone: not what the fit sees.
    prototype_dc = mf.diffuse_albedo * irradiance / math.sqrt(math.pi)
    ratio = fitted[..., 0] / prototype_dc
    assert np.all(np.abs(ratio - 1.0) > 0.2), ratio


def test_sh_model_reproduces_fitted_observations_of_a_near_mirror():
    # Observed = R0 x mirrored light + d E / pi at every sample, i.e. a near-mirror (kernel ~ 1 up
    # to degree 5); the model built from the two fits on the same holey samples must match the fit.
    rng = np.random.default_rng(2)
    n_texels, n_views = 5, 40
    directions, weights = _holey_hemisphere_samples(n_texels, n_views, rng)
    fit = FitConfig(lmax=LMAX)
    mf = _random_microfacet(rng, n_texels, alpha=brdf.ALPHA_MIN)
    irradiance = rng.uniform(0.5, 3.0, (n_texels, 3))
    mirrored = rng.uniform(0.0, 4.0, (n_texels, n_views, 3))
    observed = mf.specular_r0[:, None, :] * mirrored + (mf.diffuse_albedo * irradiance / math.pi)[:, None, :]

    reflected_coeffs = _fit(directions, weights, mirrored, fit)
    predicted = brdf.predict_sh_coeffs(
        mf, reflected_coeffs, irradiance, brdf.constant_fit_coeffs(directions, weights, fit)
    )
    fitted = _fit(directions, weights, observed, fit)
    scale = np.abs(fitted).max()
    np.testing.assert_allclose(predicted, fitted, atol=1e-4 * scale)


def test_power_spectrum_model_matches_sh_model_without_diffuse():
    rng = np.random.default_rng(4)
    mf = _random_microfacet(rng, 7)
    mf = brdf.MicrofacetParams(np.zeros((7, 3)), mf.specular_r0, mf.alpha)
    reflected = rng.normal(0, 1, (7, 3, K))
    reflected[..., 0] = np.abs(reflected[..., 0])
    irradiance = rng.uniform(0.5, 3.0, (7, 3))
    constant_fit = rng.normal(0, 1, (7, K))  # irrelevant without diffuse albedo
    for sigma in (0.0, 0.05):
        coeffs = brdf.predict_sh_coeffs(mf, reflected, irradiance, constant_fit, sigma=sigma)
        spectrum = brdf.predict_power_spectrum(
            mf, sh.power_spectrum(reflected), irradiance, constant_fit, sigma=sigma
        )
        np.testing.assert_allclose(sh.power_spectrum(coeffs), spectrum, rtol=1e-12)


def test_power_spectrum_model_adds_diffuse_as_dc_amplitude():
    # With a DC-only constant fit (a well-sampled sphere) the SH model's spectrum is exact, and
    # its l = 0 power contains the specular x diffuse cross term that adding powers would miss.
    rng = np.random.default_rng(5)
    mf = _random_microfacet(rng, 7)
    reflected = rng.normal(0, 1, (7, 3, K))
    reflected[..., 0] = np.abs(reflected[..., 0]) + 0.5
    irradiance = rng.uniform(0.5, 3.0, (7, 3))
    constant_fit = np.zeros((7, K))
    constant_fit[:, 0] = math.sqrt(4 * math.pi)
    coeffs = brdf.predict_sh_coeffs(mf, reflected, irradiance, constant_fit)
    spectrum = brdf.predict_power_spectrum(mf, sh.power_spectrum(reflected), irradiance, constant_fit)
    np.testing.assert_allclose(sh.power_spectrum(coeffs), spectrum, rtol=1e-12)


def test_angular_model_fit_equals_sh_model_without_fresnel_and_masking():
    rng = np.random.default_rng(6)
    n_texels, n_views = 4, 120
    directions = np.broadcast_to(_fibonacci_hemisphere(n_views), (n_texels, n_views, 3))
    weights = np.ones((n_texels, n_views))
    exact = FitConfig(lmax=LMAX, reg_lambda=0.0, regulariser="none")  # a band-limited signal is refit exactly
    mf = _random_microfacet(rng, n_texels)
    incoming = rng.normal(0, 1, (n_texels, 3, K))
    irradiance = rng.uniform(0.5, 3.0, (n_texels, 3))
    sigma = 0.1
    radiance = brdf.predict_angular(
        mf, directions, incoming, irradiance, fresnel=False, masking=False, sigma=sigma
    )
    fitted = _fit(directions, weights, radiance, exact)
    constant_fit = brdf.constant_fit_coeffs(directions, weights, exact)
    predicted = brdf.predict_sh_coeffs(mf, incoming, irradiance, constant_fit, sigma=sigma)
    np.testing.assert_allclose(fitted, predicted, atol=1e-8 * np.abs(predicted).max())


def test_angular_model_fresnel_and_masking_limits():
    rng = np.random.default_rng(7)
    mf = _random_microfacet(rng, 3)
    incoming = rng.normal(0, 1, (3, 3, K))
    irradiance = rng.uniform(0.5, 3.0, (3, 3))
    normal, grazing = [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]
    directions = np.broadcast_to(np.array([normal, grazing]), (3, 2, 3))
    full = brdf.predict_angular(mf, directions, incoming, irradiance)
    plain = brdf.predict_angular(mf, directions, incoming, irradiance, fresnel=False, masking=False)
    diffuse = mf.diffuse_albedo * irradiance / math.pi
    np.testing.assert_allclose(full[:, 0], plain[:, 0])  # F = R0 and G1 = 1 at normal view
    np.testing.assert_allclose(full[:, 1], diffuse)  # fully masked at grazing view
    # Without masking, Fresnel alone makes the grazing specular white: F = 1.
    fresnel_only = brdf.predict_angular(mf, directions, incoming, irradiance, masking=False)
    specular_plain = plain[:, 1] - diffuse
    np.testing.assert_allclose(fresnel_only[:, 1] - diffuse, specular_plain / mf.specular_r0)


# ---------------------------------------------------------------------------------------------
# Sampling theory


def test_resolvable_degree_is_strictly_below_sqrt_n():
    for n_views in range(1, 500):
        lstar = brdf.resolvable_degree(n_views)
        assert lstar < math.sqrt(n_views) <= lstar + 1


def test_min_resolvable_alpha_attenuates_lstar_by_t():
    for lstar, t in ((5, 0.5), (19, 0.5), (10, 0.1)):
        alpha = brdf.min_resolvable_alpha(lstar, t)
        assert brdf.brdf_kernel(np.array([alpha]), lstar)[0, lstar] == pytest.approx(t)
        assert brdf.min_resolvable_roughness(lstar, t) ** 2 == pytest.approx(alpha)


def test_appendix_worked_example():
    # N = 400, t = 0.5. l* < sqrt(N) strictly gives l* = 19 (l* = 20 would need N > 400), and
    # eq. 12 gives sqrt(ln 2) / 19 = 0.0438. The appendix's "alpha' ~ 0.07" is reproduced by
    # neither l* = 19 (0.044) nor l* = 20 (0.042): it matches eq. 12 only at l* = 12.
    lstar = brdf.resolvable_degree(400)
    assert lstar == 19
    alpha = brdf.min_resolvable_alpha(lstar, 0.5)
    assert alpha == pytest.approx(0.0438, abs=5e-5)
    assert abs(alpha - 0.07) > 0.02 and abs(brdf.min_resolvable_alpha(20, 0.5) - 0.07) > 0.02


@settings(max_examples=100, deadline=None)
@given(alpha=st.floats(0.01, 1.0), t=st.floats(0.05, 0.95))
def test_views_needed_is_the_fewest_sufficient(alpha, t):
    n_views = brdf.views_needed(alpha, t)
    assert brdf.min_resolvable_alpha(brdf.resolvable_degree(n_views), t) <= alpha * (1 + 1e-12)
    fewer = n_views - 1
    if fewer >= 1 and brdf.resolvable_degree(fewer) >= 1:
        assert brdf.min_resolvable_alpha(brdf.resolvable_degree(fewer), t) > alpha
