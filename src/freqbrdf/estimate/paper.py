"""The ``paper`` estimator: the authors' prototype, Adam on the L1 loss of the model of docs/method.md#forward-model.

Any of the three forward models of `freqbrdf.model.brdf` (angular, SH coefficients, power
spectrum), with analytic gradients; the loss and the total variation are averaged over the
whole texture, as the prototype's are. The shadowing of docs/method.md#forward-model makes the light's SH fit depend on
the roughness: it is refreshed every ``EstimateConfig.shadowing_refresh_every`` iterations.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING

import numba
import numpy as np

from freqbrdf.config import Config
from freqbrdf.estimate.search import EstimatorResult, angular_loss, lambert_scale, shadowed_light_coeffs
from freqbrdf.model import brdf
from freqbrdf.model._kernels import fill_kernel, g1_and_derivative
from freqbrdf.model.light import degree_projections
from freqbrdf.observe.observations import Observations
from freqbrdf.progress import Reporter
from freqbrdf.sphere import harmonics as sh

if TYPE_CHECKING:
    from freqbrdf.estimate import HypothesisRecorder

# torch.optim.Adam's defaults, which the prototype used.
_ADAM_BETA1, _ADAM_BETA2, _ADAM_EPS = 0.9, 0.999, 1e-8
# The 8-neighbourhood of the prototype's 3 x 3 total-variation stencil (the centre adds zero).
_NEIGHBOUR_OFFSETS = tuple((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0))


def estimate_paper(observations: Observations, config: Config, reporter: Reporter,
                   hypotheses: HypothesisRecorder | None = None) -> EstimatorResult:
    """Estimate the Principled parameters per texel as the authors' prototype does.

    Adam (torch's defaults, ``EstimateConfig.learning_rate``, ``iterations``) on the L1 loss of the
    cos-weighted residuals averaged over the whole T x T texture, parameters clamped to [0, 1] after
    every step, texture-space total variation on the observed texels (``tv_weight``), with analytic
    gradients of ``forward_model``. Starts from ``init_base_color``, ``init_roughness``,
    ``init_metallic``; every ``shadowing_refresh_every`` iterations the light is re-fitted shadowed
    at the current roughness.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    config : Config
        ``config.estimate`` the prototype's settings; ``config.fit`` the fit the observations were
        made with.
    reporter : Reporter
        Receives progress.
    hypotheses : None
        Not recorded by this estimator (its signature is `freqbrdf.estimate.ESTIMATORS`').

    Returns
    -------
    EstimatorResult
        The estimate of the texels with a sample; its loss is `angular_loss` under the last light.
    """
    settings = config.estimate
    timings = {"light": 0.0, "iterations": 0.0}
    n_texels = observations.n_texels
    estimated = observations.n_samples > 0
    params = np.empty((n_texels, 5))  # base colour RGB, roughness, metallic
    params[:, :3] = settings.init_base_color
    params[:, 3] = settings.init_roughness
    params[:, 4] = settings.init_metallic
    first_moment = np.zeros_like(params)
    second_moment = np.zeros_like(params)
    neighbours = _texture_neighbours(observations.texture_res, observations.texel_index, estimated)
    # The prototype's losses are means over the whole T x T texture (observed or not).
    texture_texels = observations.texture_res**2
    light = observations.mirrored_coeffs
    target = observations.observed_coeffs
    proj = None
    tick = time.perf_counter()
    if settings.forward_model == "angular":
        proj = degree_projections(observations.view_direction, observations.weight, light, observations.lmax)
    timings["light"] += time.perf_counter() - tick

    with reporter.stage("estimating (paper)", settings.iterations) as advance:
        for iteration in range(settings.iterations):
            # The prototype refreshes shadowing/masking before iterations 49, 99, ... (it + 1 = 50 k).
            if (settings.shadowing or settings.masking) and (iteration + 1) % settings.shadowing_refresh_every == 0:
                tick = time.perf_counter()
                light, target, proj = _refresh(observations, config, params, light, target, proj)
                timings["light"] += time.perf_counter() - tick
            tick = time.perf_counter()
            gradient = _data_gradient(observations, settings, params, light, target, proj, texture_texels)
            gradient += _tv_gradient(params, neighbours, settings.tv_weight / (9.0 * texture_texels))
            _adam_step(params, gradient, first_moment, second_moment, iteration + 1, settings.learning_rate)
            timings["iterations"] += time.perf_counter() - tick
            advance(1)

    tick = time.perf_counter()
    loss = angular_loss(observations, _principled(params), config, light)
    timings["loss"] = time.perf_counter() - tick
    timings["total"] = sum(timings.values())
    return EstimatorResult(params, np.nan_to_num(loss), estimated, f"paper/{settings.forward_model}", timings, None)


def _principled(params: np.ndarray) -> brdf.PrincipledParams:
    return brdf.PrincipledParams(base_color=params[:, :3], roughness=params[:, 3], metallic=params[:, 4])


def _refresh(observations, config, params, light, target, proj):
    """Re-fit the light shadowed at the current roughness, as the prototype does.

    For the spectral models also the observations with the masking divided out.
    """
    settings = config.estimate
    alpha = brdf.alpha_from_roughness(params[:, 3])
    if settings.shadowing:
        light = shadowed_light_coeffs(observations, alpha, config.fit)
        if settings.forward_model == "angular":
            proj = degree_projections(observations.view_direction, observations.weight, light, observations.lmax)
    if settings.masking and settings.forward_model != "angular":
        g1 = brdf.smith_g1_ggx(observations.view_direction[..., 2], alpha[:, None])  # (N, V)
        unmasked = observations.observed / np.maximum(g1, np.finfo(np.float32).tiny)[..., None]
        fit = config.fit
        target = sh.fit_sh(
            observations.view_direction, observations.weight, unmasked.astype(np.float32), observations.lmax,
            fit.reg_lambda, fit.regulariser, fit.scale_lambda_with_weight,
        ).coeffs
    return light, target, proj


def _data_gradient(observations, settings, params, light, target, proj, texture_texels) -> np.ndarray:
    """(N, 5) gradient of the prototype's mean L1 loss for the chosen forward model."""
    mf = brdf.microfacet_from_principled(_principled(params))
    lmax, sigma = observations.lmax, observations.sigma
    diffuse_scale = lambert_scale(observations)  # (N, 3)
    n_texels = observations.n_texels
    if settings.forward_model == "angular":
        grad_r0, grad_diffuse, grad_alpha = np.zeros((n_texels, 3)), np.zeros((n_texels, 3)), np.zeros(n_texels)
        _angular_l1_gradient_kernel(
            proj, observations.view_direction[..., 2], observations.weight, observations.observed, diffuse_scale,
            mf.specular_r0, mf.diffuse_albedo, mf.alpha, sigma, settings.fresnel, settings.masking,
            grad_r0, grad_diffuse, grad_alpha,
        )
        count = texture_texels * observations.n_views * 3
    else:
        constant = observations.constant_coeffs.astype(np.float64)  # (N, K)
        kernel = brdf.brdf_kernel(mf.alpha, lmax, sigma)  # (N, l*+1)
        degrees = np.arange(lmax + 1)
        kernel_derivative = -2.0 * mf.alpha[:, None] * degrees**2 * kernel  # d kernel / d alpha
        r0 = mf.specular_r0[:, :, None]  # (N, 3, 1)
        if settings.forward_model == "sh_coeffs":
            predicted = brdf.predict_sh_coeffs(mf, light, observations.irradiance, constant, sigma=sigma)
            sign = np.sign(predicted - target)  # (N, 3, K)
            per_coeff = sh.sh_degrees(lmax)
            grad_r0 = np.sum(sign * kernel[:, None, per_coeff] * light, axis=2)
            grad_diffuse = np.sum(sign * constant[:, None, :], axis=2) * diffuse_scale
            grad_alpha = np.sum(sign * r0 * kernel_derivative[:, None, per_coeff] * light, axis=(1, 2))
            count = texture_texels * 3 * sh.num_coeffs(lmax)
        else:
            light_spectrum = sh.power_spectrum(light)  # (N, 3, l*+1)
            predicted = brdf.predict_power_spectrum(
                mf, light_spectrum, observations.irradiance, constant, sigma=sigma
            )
            sign = np.sign(predicted - sh.power_spectrum(target))
            # l >= 1: S = R0^2 k^2 S_refl.  l = 0: S = a^2, a = R0 k0 sqrt(S_refl(0)) + d E/pi u_00.
            grad_r0 = np.sum(sign[..., 1:] * 2.0 * r0 * kernel[:, None, 1:] ** 2 * light_spectrum[..., 1:], axis=2)
            grad_alpha = np.sum(
                sign[..., 1:] * r0**2 * 2.0 * kernel[:, None, 1:] * kernel_derivative[:, None, 1:]
                * light_spectrum[..., 1:], axis=(1, 2),
            )
            dc_light = np.sqrt(light_spectrum[..., 0])  # (N, 3)
            amplitude = mf.specular_r0 * kernel[:, :1] * dc_light + mf.diffuse_albedo * diffuse_scale * constant[:, :1]
            grad_r0 += sign[..., 0] * 2.0 * amplitude * kernel[:, :1] * dc_light
            grad_diffuse = sign[..., 0] * 2.0 * amplitude * diffuse_scale * constant[:, :1]
            count = texture_texels * 3 * (lmax + 1)
    return _chain_to_principled(grad_r0, grad_diffuse, grad_alpha, params) / count


def _chain_to_principled(grad_r0, grad_diffuse, grad_alpha, params) -> np.ndarray:
    """Chain gradients in (R0 (N, 3), d (N, 3), alpha (N,)) to (base colour, roughness, metallic) (N, 5).

    R0 = 0.04 + (b - 0.04) m, d = (1 - m) b, alpha = max(r^2, ALPHA_MIN) (no gradient when clamped,
    as torch's clamp).
    """
    base, roughness, metallic = params[:, :3], params[:, 3], params[:, 4]
    gradient = np.empty_like(params)
    gradient[:, :3] = grad_r0 * metallic[:, None] + grad_diffuse * (1.0 - metallic[:, None])
    gradient[:, 3] = grad_alpha * np.where(roughness**2 > brdf.ALPHA_MIN, 2.0 * roughness, 0.0)
    gradient[:, 4] = np.sum(grad_r0 * (base - brdf.DIELECTRIC_F0) - grad_diffuse * base, axis=1)
    return gradient


@numba.njit(parallel=True, fastmath=True, cache=True)
def _angular_l1_gradient_kernel(
    proj, cos_theta, weight, observed, diffuse_scale, r0, diffuse, alpha, sigma, fresnel, masking,
    grad_r0, grad_diffuse, grad_alpha,
):
    """Gradient of sum_v,c |w (L - f)| in R0, d and alpha per texel (accumulated into the grads)."""
    n_texels, n_views = weight.shape
    n_degrees = proj.shape[2]
    for t in numba.prange(n_texels):
        kernel = np.empty(n_degrees)
        kernel_derivative = np.empty(n_degrees)
        fill_kernel(alpha[t], sigma, kernel, kernel_derivative)
        for v in range(n_views):
            w = np.float64(weight[t, v])
            if w <= 0.0:
                continue
            cos_v = np.float64(cos_theta[t, v])
            g1, g1_derivative = g1_and_derivative(cos_v, alpha[t]) if masking else (1.0, 0.0)
            schlick = (1.0 - cos_v) ** 5 if fresnel else 0.0
            for c in range(3):
                filtered = 0.0
                filtered_derivative = 0.0
                for degree in range(n_degrees):
                    filtered += kernel[degree] * proj[t, c, degree, v]
                    filtered_derivative += kernel_derivative[degree] * proj[t, c, degree, v]
                fresnel_c = r0[t, c] + (1.0 - r0[t, c]) * schlick
                residual = fresnel_c * g1 * filtered + diffuse[t, c] * diffuse_scale[t, c] - observed[t, v, c]
                sign_w = w if residual > 0.0 else (-w if residual < 0.0 else 0.0)
                grad_r0[t, c] += sign_w * (1.0 - schlick) * g1 * filtered
                grad_diffuse[t, c] += sign_w * diffuse_scale[t, c]
                grad_alpha[t] += sign_w * fresnel_c * (g1_derivative * filtered + g1 * filtered_derivative)


def _texture_neighbours(texture_res: int, texel_index: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(N, 8) indices of each masked texel's masked 8-neighbours in the texture, -1 where none."""
    lookup = np.full(texture_res * texture_res, -1, dtype=np.int64)
    lookup[texel_index[mask]] = np.flatnonzero(mask)
    row, col = np.divmod(texel_index, texture_res)
    neighbours = np.full((len(texel_index), len(_NEIGHBOUR_OFFSETS)), -1, dtype=np.int64)
    for k, (d_row, d_col) in enumerate(_NEIGHBOUR_OFFSETS):
        r, c = row + d_row, col + d_col
        inside = mask & (r >= 0) & (r < texture_res) & (c >= 0) & (c < texture_res)
        neighbours[inside, k] = lookup[r[inside] * texture_res + c[inside]]
    return neighbours


def _tv_gradient(params: np.ndarray, neighbours: np.ndarray, coefficient: float) -> np.ndarray:
    """Gradient of coefficient * sum_x sum_(y in N8(x)) sum_p |params_y,p - params_x,p|.

    This is the prototype's masked 3 x 3 L1 total variation averaged over 9 T^2 stencil entries
    (coefficient = weight / (9 T^2)); each pair appears from both ends, hence the 2.
    """
    gradient = np.zeros_like(params)
    for k in range(neighbours.shape[1]):
        has = neighbours[:, k] >= 0
        gradient[has] += 2.0 * coefficient * np.sign(params[has] - params[neighbours[has, k]])
    return gradient


def _adam_step(params, gradient, first_moment, second_moment, step: int, learning_rate: float) -> None:
    """torch.optim.Adam's update (in place), then the prototype's clamps: |r|, all into [0, 1]."""
    first_moment *= _ADAM_BETA1
    first_moment += (1.0 - _ADAM_BETA1) * gradient
    second_moment *= _ADAM_BETA2
    second_moment += (1.0 - _ADAM_BETA2) * gradient**2
    denominator = np.sqrt(second_moment) / math.sqrt(1.0 - _ADAM_BETA2**step) + _ADAM_EPS
    params -= learning_rate / (1.0 - _ADAM_BETA1**step) * first_moment / denominator
    params[:, 3] = np.abs(params[:, 3])
    np.clip(params, 0.0, 1.0, out=params)
