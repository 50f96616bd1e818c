"""The reflection model in frequency space (docs/method.md#conventions and docs/method.md#forward-model, appendix A and C).

Reflection is modelled as in Ramamoorthi and Hanrahan: in the mirror parameterisation the
specular part of the radiance leaving a texel towards w_o is the incoming light, seen in the mirror
direction of w_o, convolved with an isotropic BRDF kernel whose SH coefficients are
exp(-(alpha l)^2) (appendix eq. 13). Three forward models build on it, from most to least accurate:

- angular:        L(w_o) = F(theta_o) G1(theta_o) [sum_lm k_l c^in_lm Y_lm(w_o)] + d E / pi
- SH coefficients: c_lm  = R0 k_l c^refl_lm + d E / pi * u_lm
- power spectrum: S(l)   = R0^2 k_l^2 S_refl(l) for l >= 1; l = 0 from the summed amplitudes

with k_l the (band-limit compensated) BRDF kernel, d = (1 - m) b the diffuse albedo, E the
irradiance and u the SH fit of a constant 1 on the texel's own samples (see `constant_fit_coeffs`).

Parameters live in two equivalent forms: the Principled ones a user edits (base colour, roughness,
metallic) and the microfacet ones the models are linear in (diffuse albedo, R0, alpha).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from freqbrdf.config import FitConfig
from freqbrdf.sphere import harmonics as sh

ALPHA_MIN = 1e-3  # alpha = roughness^2 is clamped here: alpha = 0 is a delta lobe, not a kernel
DIELECTRIC_F0 = 0.04  # normal-incidence reflectance of the Principled BRDF's dielectric (eta 1.5)


@dataclass(frozen=True)
class PrincipledParams:
    """Principled BRDF parameters per texel (N texels), all in [0, 1].

    Attributes
    ----------
    base_color : (N, 3) float
        Linear RGB.
    roughness : (N,) float
        alpha = roughness^2.
    metallic : (N,) float
    """

    base_color: np.ndarray
    roughness: np.ndarray
    metallic: np.ndarray


@dataclass(frozen=True)
class MicrofacetParams:
    """Torrance-Sparrow parameters (appendix eqs. 7-11): Lambertian + Schlick/GGX specular lobe.

    Attributes
    ----------
    diffuse_albedo : (N, 3) float
        (1 - metallic) base_color.
    specular_r0 : (N, 3) float
        The normal-incidence Fresnel reflectance R0.
    alpha : (N,) float
        The GGX width roughness^2, at least `ALPHA_MIN`.
    """

    diffuse_albedo: np.ndarray
    specular_r0: np.ndarray
    alpha: np.ndarray


# --------------------------------------------------------------------------------------------
# Principled <-> Torrance-Sparrow


def alpha_from_roughness(roughness: np.ndarray) -> np.ndarray:
    """Return the GGX width alpha = roughness^2 (appendix eq. 11), clamped to `ALPHA_MIN`.

    Parameters
    ----------
    roughness : array
        The Principled roughness, any shape.

    Returns
    -------
    array
        alpha, the same shape.
    """
    return np.maximum(np.square(roughness), ALPHA_MIN)


def microfacet_from_principled(params: PrincipledParams) -> MicrofacetParams:
    """Convert Principled parameters to microfacet ones (appendix eqs. 7-11).

    K_d = (1 - m) b, R0 = 0.04 + (b - 0.04) m per channel, alpha = r^2.

    Parameters
    ----------
    params : PrincipledParams
        N texels.

    Returns
    -------
    MicrofacetParams
        The same N texels.
    """
    metallic = params.metallic[:, None]  # (T, 1)
    return MicrofacetParams(
        diffuse_albedo=(1.0 - metallic) * params.base_color,
        specular_r0=DIELECTRIC_F0 + (params.base_color - DIELECTRIC_F0) * metallic,
        alpha=alpha_from_roughness(params.roughness),
    )


def principled_from_microfacet(
    mf: MicrofacetParams, grid_size: int = 129, refine_iterations: int = 40
) -> PrincipledParams:
    """Invert the Principled mapping: (diffuse albedo, R0) to (base colour, metallic); r = sqrt(alpha).

    Six numbers (d and R0 for three channels) against four unknowns (b, m), so this is a bounded
    least-squares problem in reflectance units:

        minimise over m in [0, 1], b in [0, 1]^3:
            sum_c ((1 - m) b_c - d_c)^2 + (0.04 (1 - m) + m b_c - R0_c)^2.

    For fixed m each b_c is a one-dimensional convex quadratic, so its bounded minimiser is the
    clipped unconstrained one; what remains is a smooth 1-D profile in m. We scan it on a grid,
    refine the two lowest grid minima by golden-section search and keep the lower. Consistent
    inputs (from `microfacet_from_principled`) are inverted exactly; others are projected to the
    closest valid Principled parameters.

    The forward map is not injective: eliminating b gives, per channel, the quadratic
    0.04 u^2 - (R0_c + d_c) u + d_c = 0 in u = 1 - m, whose roots are 1 - m and b_c / 0.04. For an
    achromatic base colour b < 0.04 both roots are valid for every channel, so (b, m) and
    (0.04 (1 - m), 1 - b / 0.04) render identically. Such pairs are genuinely indistinguishable;
    we return the less metallic one (near-black dielectrics are common, metals with R0 < 0.04 are
    not). For any channel above 0.04 the second root leaves [0, 1] and the inverse is unique.

    Parameters
    ----------
    mf : MicrofacetParams
        N texels.
    grid_size : int, optional
        Nodes of the metallic grid scanned.
    refine_iterations : int, optional
        Golden-section iterations per refined minimum.

    Returns
    -------
    PrincipledParams
        The same N texels, float64.
    """
    diffuse = np.asarray(mf.diffuse_albedo, dtype=np.float64)  # (T, 3)
    r0 = np.asarray(mf.specular_r0, dtype=np.float64)  # (T, 3)
    n_texels = diffuse.shape[0]
    metallic = np.empty(n_texels)
    chunk = 4096  # bounds the (chunk, grid, 3) scan to a few MB
    for start in range(0, n_texels, chunk):
        rows = slice(start, start + chunk)
        metallic[rows] = _solve_metallic(diffuse[rows], r0[rows], grid_size, refine_iterations)
    base_color, _ = _base_color_for_metallic(metallic[:, None], diffuse, r0)
    base_color, metallic = _prefer_dielectric(base_color, metallic, diffuse, r0)
    return PrincipledParams(
        base_color=base_color, roughness=np.sqrt(np.asarray(mf.alpha, dtype=np.float64)), metallic=metallic
    )


def _base_color_for_metallic(
    metallic: np.ndarray, diffuse: np.ndarray, r0: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Bounded least-squares base colour for given metallic, and the misfit summed over channels.

    metallic (..., 1) broadcasts against diffuse, r0 (..., 3); returns ((..., 3), (...)).
    """
    dielectric = 1.0 - metallic
    specular_target = r0 - DIELECTRIC_F0 * dielectric  # what m * b must explain
    base_color = np.clip(
        (dielectric * diffuse + metallic * specular_target) / (dielectric**2 + metallic**2), 0.0, 1.0
    )
    misfit = np.sum(
        (dielectric * base_color - diffuse) ** 2 + (metallic * base_color - specular_target) ** 2, axis=-1
    )
    return base_color, misfit


def _solve_metallic(diffuse: np.ndarray, r0: np.ndarray, grid_size: int, refine_iterations: int) -> np.ndarray:
    """Global minimiser over [0, 1] of the profiled misfit; diffuse, r0 (T, 3) -> (T,)."""
    grid = np.linspace(0.0, 1.0, grid_size)
    _, misfit = _base_color_for_metallic(grid[None, :, None], diffuse[:, None, :], r0[:, None, :])  # (T, G)
    # Grid local minima (end points count when lower than their single neighbour).
    padded = np.pad(misfit, ((0, 0), (1, 1)), constant_values=np.inf)
    is_local_min = (misfit <= padded[:, :-2]) & (misfit < padded[:, 2:])
    ranked = np.argsort(np.where(is_local_min, misfit, np.inf), axis=1, kind="stable")[:, :2]  # (T, 2)
    # The profile has at most two basins (the two roots above): refine both, keep the better.
    step = 1.0 / (grid_size - 1)
    lo = np.clip(grid[ranked] - step, 0.0, 1.0)
    hi = np.clip(grid[ranked] + step, 0.0, 1.0)
    candidates = _golden_section(lo, hi, diffuse[:, None, :], r0[:, None, :], refine_iterations)  # (T, 2)
    _, candidate_misfit = _base_color_for_metallic(candidates[..., None], diffuse[:, None, :], r0[:, None, :])
    best = np.argmin(candidate_misfit, axis=1)
    return np.take_along_axis(candidates, best[:, None], axis=1)[:, 0]


def _golden_section(
    lo: np.ndarray, hi: np.ndarray, diffuse: np.ndarray, r0: np.ndarray, iterations: int
) -> np.ndarray:
    """Vectorised golden-section minimisation of the profiled misfit on [lo, hi] (same shapes)."""
    inv_phi = (math.sqrt(5.0) - 1.0) / 2.0
    left = hi - inv_phi * (hi - lo)
    right = lo + inv_phi * (hi - lo)
    _, f_left = _base_color_for_metallic(left[..., None], diffuse, r0)
    _, f_right = _base_color_for_metallic(right[..., None], diffuse, r0)
    for _ in range(iterations):
        go_left = f_left < f_right
        hi = np.where(go_left, right, hi)
        lo = np.where(go_left, lo, left)
        new_left = hi - inv_phi * (hi - lo)
        new_right = lo + inv_phi * (hi - lo)
        # One of the two interior points survives; only the other needs a new evaluation.
        probe = np.where(go_left, new_left, new_right)
        _, f_probe = _base_color_for_metallic(probe[..., None], diffuse, r0)
        right, f_right, left, f_left = (
            np.where(go_left, left, new_right),
            np.where(go_left, f_left, f_probe),
            np.where(go_left, probe, right),
            np.where(go_left, f_probe, f_right),
        )
    return 0.5 * (lo + hi)


def _prefer_dielectric(
    base_color: np.ndarray, metallic: np.ndarray, diffuse: np.ndarray, r0: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Resolve the two-to-one ambiguity of dark achromatic colours towards the lower metallic."""
    grey = base_color.mean(axis=1)
    has_twin = (np.ptp(base_color, axis=1) <= 1e-6) & (grey < DIELECTRIC_F0)  # grey and dark only
    twin_metallic = np.clip(1.0 - grey / DIELECTRIC_F0, 0.0, 1.0)
    twin_base, twin_misfit = _base_color_for_metallic(twin_metallic[:, None], diffuse, r0)
    _, misfit = _base_color_for_metallic(metallic[:, None], diffuse, r0)
    # An exact tie up to rounding: a twin that is worse by more is a different, worse fit.
    scale = np.sum(diffuse**2 + r0**2, axis=1)
    take_twin = has_twin & (twin_metallic < metallic) & (twin_misfit <= misfit + 1e-14 * scale)
    return np.where(take_twin[:, None], twin_base, base_color), np.where(take_twin, twin_metallic, metallic)


# --------------------------------------------------------------------------------------------
# Fresnel, shadowing-masking, the BRDF kernel


def schlick_fresnel(cos_theta: np.ndarray, r0: np.ndarray) -> np.ndarray:
    """Return Schlick's Fresnel F = R0 + (1 - R0)(1 - cos theta)^5 (appendix eq. 10).

    Parameters
    ----------
    cos_theta : array
        Cosine of the incidence angle, clipped to [0, 1]; broadcasts against ``r0``.
    r0 : array
        The normal-incidence reflectance.

    Returns
    -------
    array
        F, the broadcast shape.
    """
    return r0 + (1.0 - r0) * (1.0 - np.clip(cos_theta, 0.0, 1.0)) ** 5


def dielectric_eta() -> float:
    """Return the relative index of refraction whose normal reflectance is `DIELECTRIC_F0` (1.5).

    Returns
    -------
    float
        eta.
    """
    root = math.sqrt(DIELECTRIC_F0)
    return (1.0 + root) / (1.0 - root)


def dielectric_fresnel(cos_theta: np.ndarray) -> np.ndarray:
    """Return the exact unpolarised Fresnel reflectance of the Principled BRDF's dielectric.

    The dielectric has eta `dielectric_eta`; the light arrives from outside.

    Parameters
    ----------
    cos_theta : array
        Cosine in [0, 1] of the angle to the (micro)surface normal, any shape.

    Returns
    -------
    float64 array
        The reflectance, the same shape.
    """
    cos_theta = np.asarray(cos_theta, dtype=np.float64)
    eta = dielectric_eta()
    g = np.sqrt(eta * eta - 1.0 + cos_theta * cos_theta)
    perpendicular = (g - cos_theta) / (g + cos_theta)
    ratio = (cos_theta * (g + cos_theta) - 1.0) / np.maximum(cos_theta * (g - cos_theta) + 1.0, 1e-300)
    return 0.5 * perpendicular**2 * (1.0 + ratio**2)


def smith_g1_ggx(cos_theta: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Return the exact Smith G1 of the GGX (Trowbridge-Reitz) distribution.

    G1 = 1 / (1 + Lambda), Lambda = (sqrt(1 + alpha^2 tan^2 theta) - 1) / 2, written as
    2 cos / (cos + sqrt(cos^2 + alpha^2 sin^2)) so that grazing angles need no tan (-> 0 at 90°).
    Directions below the horizon are fully masked.

    Parameters
    ----------
    cos_theta : array
        Cosine of the direction's angle to the normal; broadcasts against ``alpha``.
    alpha : array
        The GGX width.

    Returns
    -------
    array
        G1 in [0, 1], the broadcast shape.
    """
    cos_theta = np.clip(cos_theta, 0.0, 1.0)
    sin2_theta = 1.0 - cos_theta**2
    denominator = cos_theta + np.sqrt(cos_theta**2 + np.square(alpha) * sin2_theta)
    return 2.0 * cos_theta / np.maximum(denominator, np.finfo(np.float64).tiny)  # 0 / 0 only if alpha = 0


def shadowed_light(mirrored_radiance: np.ndarray, cos_theta: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Attenuate the incoming light by the shadowing G1(theta_i) before convolution (appendix eq. 6).

    In the mirror parameterisation the light sample paired with view w_o arrives from the mirror
    direction of w_o, so theta_i = theta_o: the shadowing factor is G1 of the view's own cosine.
    Fit SH to the result to get the ``incoming_coeffs`` of `predict_angular` with masking.

    Parameters
    ----------
    mirrored_radiance : (N, V, 3) array
        The light arriving from each view's mirror direction.
    cos_theta : (N, V) array
        The views' cosines.
    alpha : (N,) array
        The GGX width per texel.

    Returns
    -------
    (N, V, 3) array
        The shadowed light.
    """
    return mirrored_radiance * smith_g1_ggx(cos_theta, alpha[:, None])[..., None]


def band_limit_sigma(n_views: int) -> float:
    """Return the width of the environment low-pass that suppresses aliasing: 1 / floor(sqrt(V)).

    Parameters
    ----------
    n_views : int
        V, the number of views.

    Returns
    -------
    float
        sigma.
    """
    return 1.0 / math.isqrt(n_views)


def brdf_kernel(alpha: np.ndarray, lmax: int, sigma: float = 0.0) -> np.ndarray:
    """Return the BRDF filter per degree, exp(-(alpha^2 - sigma^2) l^2).

    With sigma = 0 this is the Gaussian exp(-(alpha l)^2) of appendix eq. 13. With sigma > 0 the
    environment is assumed low-passed by exp(-(sigma l)^2) before it was sampled (band limit), and
    this kernel divides that blur back out, so kernel * exp(-(sigma l)^2) = exp(-(alpha l)^2).

    When alpha < sigma the exponent is positive: the kernel exceeds 1 and grows with l, i.e. the
    material is sharper than the blur applied to the light. sigma ~ 1/floor(sqrt(N)) is about the
    finest width N views can resolve (appendix C), so such a texel is below the resolvable
    roughness: its prediction extrapolates detail the low-passed light does not contain and
    amplifies the fitted coefficients' noise in high degrees. The kernel is deliberately not
    clamped (that would break the identity above); flag these texels with
    `min_resolvable_alpha` instead of trusting their roughness.

    Parameters
    ----------
    alpha : (N,) array
        The GGX width per texel.
    lmax : int
        l*, the highest degree.
    sigma : float, optional
        The band limit's width (`band_limit_sigma`); 0: none.

    Returns
    -------
    (N, l*+1) array
        The kernel per texel and degree.
    """
    degrees = np.arange(lmax + 1)
    return np.exp(-(np.square(alpha)[..., None] - sigma**2) * degrees**2)


def _kernel_per_coeff(alpha: np.ndarray, lmax: int, sigma: float) -> np.ndarray:
    """brdf_kernel spread to every flat SH index: (T,) -> (T, K)."""
    return brdf_kernel(alpha, lmax, sigma)[:, sh.sh_degrees(lmax)]


# --------------------------------------------------------------------------------------------
# The diffuse term seen through the fit


def constant_fit_coeffs(directions: np.ndarray, weights: np.ndarray, fit: FitConfig) -> np.ndarray:
    """Fit SH to the constant 1 on each texel's samples.

    The fit is linear, so a texel's Lambertian radiance d E / pi (constant over w_o) contributes
    exactly d E / pi times these coefficients to its fitted SH. On a well-covered sphere without
    regularisation that is sqrt(4 pi) in l = 0 only; on a sparse, hemispherical, holey sample set
    the degree penalty shrinks the DC term and leaks into l > 0. The prototype's d E / sqrt(pi) in
    the DC coefficient alone is half the full-sphere value and ignores both effects. Cheaper in a
    pipeline: append a column of ones to the values of the observation fit, which shares its
    factorisation.

    Parameters
    ----------
    directions : (N, V, 3) array
        The samples' directions.
    weights : (N, V) array
        Their weights; 0 where unsampled.
    fit : FitConfig
        The SH fit's settings.

    Returns
    -------
    (N, K) array
        The coefficients per texel.
    """
    ones = np.ones(weights.shape + (1,))
    result = sh.fit_sh(
        directions,
        weights,
        ones,
        lmax=fit.lmax,
        reg_lambda=fit.reg_lambda,
        regulariser=fit.regulariser,
        scale_lambda_with_weight=fit.scale_lambda_with_weight,
    )
    return result.coeffs[:, 0, :]


def _diffuse_radiance(mf: MicrofacetParams, irradiance: np.ndarray) -> np.ndarray:
    """Lambertian radiance d E / pi, (T, 3)."""
    return mf.diffuse_albedo * irradiance / np.pi


# --------------------------------------------------------------------------------------------
# Forward models


def predict_angular(
    mf: MicrofacetParams,
    directions: np.ndarray,
    incoming_coeffs: np.ndarray,
    irradiance: np.ndarray,
    *,
    fresnel: bool = True,
    masking: bool = True,
    sigma: float = 0.0,
    basis: np.ndarray | None = None,
) -> np.ndarray:
    """Predict the radiance at the observed view directions with the angular model (docs/method.md#forward-model).

    L(w_o) = F(theta_o) G1(theta_o) [sum_lm k_l c^in_lm Y_lm(w_o)] + d E / pi.

    Parameters
    ----------
    mf : MicrofacetParams
        N texels.
    directions : (N, V, 3) array
        Unit view directions in the texel's local frame (z = normal).
    incoming_coeffs : (N, 3, K) array
        The SH fit of the mirrored incoming light on the same samples; for the shadowing-masking
        extension (appendix eq. 6) fit it to `shadowed_light` and keep ``masking``.
    irradiance : (N, 3) array
        E per texel.
    fresnel : bool, optional
        Schlick's Fresnel, else F = R0.
    masking : bool, optional
        G1 of the view, else G1 = 1.
    sigma : float, optional
        The band limit's width (`brdf_kernel`).
    basis : (N, V, K) array, optional
        ``sh.eval_sh(directions, lmax)``, to reuse it across calls.

    Returns
    -------
    (N, V, 3) array
        The radiance.
    """
    lmax = sh.lmax_of(incoming_coeffs.shape[-1])
    if basis is None:
        basis = sh.eval_sh(directions, lmax)
    filtered_coeffs = incoming_coeffs * _kernel_per_coeff(mf.alpha, lmax, sigma)[:, None, :]  # (T, 3, K)
    filtered = basis @ np.swapaxes(filtered_coeffs, 1, 2)  # (T, V, 3)
    cos_theta = directions[..., 2]  # (T, V)
    r0 = mf.specular_r0[:, None, :]  # (T, 1, 3)
    specular_weight = schlick_fresnel(cos_theta[..., None], r0) if fresnel else r0
    if masking:
        specular_weight = specular_weight * smith_g1_ggx(cos_theta, mf.alpha[:, None])[..., None]
    return specular_weight * filtered + _diffuse_radiance(mf, irradiance)[:, None, :]


def predict_sh_coeffs(
    mf: MicrofacetParams,
    reflected_coeffs: np.ndarray,
    irradiance: np.ndarray,
    constant_fit: np.ndarray,
    *,
    sigma: float = 0.0,
) -> np.ndarray:
    """Predict the fitted SH coefficients of the outgoing radiance.

    c_lm = R0 k_l c^refl_lm + (d E / pi) u_lm. The diffuse part is essentially l = 0, but taken
    through the fit so that it matches what fitting the observations produces (Fresnel and
    masking are not modelled here: they are products in the angular domain, not per-coefficient
    factors).

    Parameters
    ----------
    mf : MicrofacetParams
        N texels.
    reflected_coeffs : (N, 3, K) array
        The SH fit of the mirrored light.
    irradiance : (N, 3) array
        E per texel.
    constant_fit : (N, K) array
        u, `constant_fit_coeffs` on the same samples.
    sigma : float, optional
        The band limit's width (`brdf_kernel`).

    Returns
    -------
    (N, 3, K) array
        The coefficients.
    """
    lmax = sh.lmax_of(reflected_coeffs.shape[-1])
    kernel = _kernel_per_coeff(mf.alpha, lmax, sigma)  # (T, K)
    specular = mf.specular_r0[:, :, None] * kernel[:, None, :] * reflected_coeffs
    return specular + _diffuse_radiance(mf, irradiance)[:, :, None] * constant_fit[:, None, :]


def predict_power_spectrum(
    mf: MicrofacetParams,
    reflected_spectrum: np.ndarray,
    irradiance: np.ndarray,
    constant_fit: np.ndarray,
    *,
    sigma: float = 0.0,
) -> np.ndarray:
    """Predict the power spectrum of the outgoing radiance.

    S(l) = R0^2 k_l^2 S_refl(l) for l >= 1. At l = 0 there is one coefficient, so the diffuse and
    specular parts add as amplitudes, not as powers: S(0) = (R0 k_0 sqrt(S_refl(0)) + (d E / pi)
    u_00)^2, using that the DC coefficient of a radiance fit is non-negative. The constant fit's
    leakage into l > 0 is neglected, because it would add cross terms with the light's
    coefficients, which a power spectrum no longer has.

    Parameters
    ----------
    mf : MicrofacetParams
        N texels.
    reflected_spectrum : (N, 3, l*+1) array
        The power spectrum of the mirrored light's fit.
    irradiance : (N, 3) array
        E per texel.
    constant_fit : (N, K) array
        u, as in `predict_sh_coeffs`.
    sigma : float, optional
        The band limit's width (`brdf_kernel`).

    Returns
    -------
    (N, 3, l*+1) array
        The spectrum.
    """
    lmax = reflected_spectrum.shape[-1] - 1
    kernel = brdf_kernel(mf.alpha, lmax, sigma)  # (T, lmax + 1)
    r0 = mf.specular_r0[:, :, None]  # (T, 3, 1)
    spectrum = np.square(r0 * kernel[:, None, :]) * reflected_spectrum
    dc_amplitude = mf.specular_r0 * kernel[:, :1] * np.sqrt(reflected_spectrum[..., 0]) + _diffuse_radiance(
        mf, irradiance
    ) * constant_fit[:, :1]
    spectrum[..., 0] = np.square(dc_amplitude)
    return spectrum


# --------------------------------------------------------------------------------------------
# Sampling theory (appendix C)


def resolvable_degree(n_views: int) -> int:
    """Return the highest SH degree V views resolve: the largest integer l* < sqrt(V).

    Parameters
    ----------
    n_views : int
        V, at least 1.

    Returns
    -------
    int
        l*.

    Raises
    ------
    ValueError
        If ``n_views`` < 1.
    """
    if n_views < 1:
        raise ValueError(f"n_views must be positive, got {n_views}")
    root = math.isqrt(n_views)
    return root - 1 if root * root == n_views else root


def min_resolvable_alpha(lstar: int, attenuation: float = 0.5) -> float:
    """Return alpha' = sqrt(-ln t) / l* (appendix eq. 12), where the kernel exp(-(alpha l*)^2) is t.

    Materials with alpha < alpha' keep more than t of their amplitude above l*, where the views
    alias; their roughness cannot be told apart in (0, alpha'] from spectra. With 400 views and
    t = 0.5: l* = 19 gives 0.0438, l* = 20 gives 0.0416. The appendix quotes "alpha' ~ 0.07",
    which neither reproduces (eq. 12 gives 0.07 only for l* = 12).

    Parameters
    ----------
    lstar : int
        l*, the highest resolvable degree.
    attenuation : float, optional
        t, in (0, 1).

    Returns
    -------
    float
        alpha'.

    Raises
    ------
    ValueError
        If ``attenuation`` is not in (0, 1).
    """
    if not 0.0 < attenuation < 1.0:
        raise ValueError(f"attenuation must lie in (0, 1), got {attenuation}")
    return math.sqrt(-math.log(attenuation)) / lstar


def min_resolvable_roughness(lstar: int, attenuation: float = 0.5) -> float:
    """Return the Principled roughness at the bound: sqrt(alpha') (`min_resolvable_alpha`).

    Parameters
    ----------
    lstar : int
        l*, the highest resolvable degree.
    attenuation : float, optional
        t, in (0, 1).

    Returns
    -------
    float
        The roughness.
    """
    return math.sqrt(min_resolvable_alpha(lstar, attenuation))


def views_needed(alpha: float, attenuation: float = 0.5) -> int:
    """Return the fewest views whose resolvable degree reaches l* = sqrt(-ln t) / alpha (rounded up).

    V must exceed l*^2 (l* < sqrt(V)), so V = ceil(l*)^2 + 1; this is the appendix's V ~ alpha^-2.

    Parameters
    ----------
    alpha : float
        The GGX width, positive.
    attenuation : float, optional
        t, in (0, 1).

    Returns
    -------
    int
        V.

    Raises
    ------
    ValueError
        If ``alpha`` is not positive.
    """
    if alpha <= 0.0:
        raise ValueError(f"alpha must be positive, got {alpha}")
    lstar = math.ceil(math.sqrt(-math.log(attenuation)) / alpha)
    return lstar * lstar + 1
