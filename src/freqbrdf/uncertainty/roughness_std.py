"""The posterior spread of the estimated roughness itself (docs/method.md#roughness-std-and-flags).

The entropy scores the hypotheses against the spectra, not the estimate, and ranks the
estimate's roughness errors poorly. `roughness_std` is the std of the estimate, the square root
of up to three variances that add (``UncertaintyConfig``):

- ``roughness_window``: the scatter of the estimates over the window x window texels around a
  texel (texture space);
- ``loss_curvature``: the Laplace variance of the estimator's loss around the estimate;
- ``split_half``: the scatter between the estimates from the even and from the odd views.

docs/results.md#the-roughness-std has how each ranks the errors and what it costs. The
package's ``roughness_std`` is the function, not this module: import it from
`freqbrdf.uncertainty`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from freqbrdf.config import Config
from freqbrdf.estimate import CURVATURE_STEP, FITTED_PARAMETERS, angular_loss, model_light
from freqbrdf.estimate import estimate as estimate_materials
from freqbrdf.model import brdf
from freqbrdf.model.materials import UNIFORM_VARIANCE

if TYPE_CHECKING:
    from freqbrdf.estimate import MaterialEstimate
    from freqbrdf.observe.observations import Observations

# What a texel's roughness variance is without information: roughness uniform on [0, 1].
PRIOR_ROUGHNESS_VARIANCE = UNIFORM_VARIANCE
# Noise floor of the loss curvature's noise variance: a sample's noise std relative to the RMS of
# the texel's observed radiance, so that a texel fitted exactly is not called certain.
CURVATURE_NOISE_FLOOR = 0.02


def roughness_std(
    observations: Observations, estimate: MaterialEstimate, config: Config = Config()
) -> np.ndarray | None:
    """Compute the posterior std of the estimated roughness.

    From ``config.uncertainty``'s roughness_window, loss_curvature and split_half terms, whose
    variances add.

    Parameters
    ----------
    observations : Observations
        The samples the estimate was made from (N texels).
    estimate : MaterialEstimate
        The estimate, of the same N texels.
    config : Config
        The fit's settings: the curvature scores the estimate with the estimator's model, as
        ``estimate.loss`` was, and the split halves are estimated as the whole was.

    Returns
    -------
    (N,) float32 or None
        The std; NaN where not estimated. None when all terms are off.
    """
    settings = config.uncertainty
    if settings.roughness_window < 0:
        raise ValueError(f"roughness_window must be >= 0, got {settings.roughness_window}")
    if settings.roughness_window == 0 and not settings.loss_curvature and not settings.split_half:
        return None
    if estimate.n_texels != observations.n_texels:
        raise ValueError(f"the estimate has {estimate.n_texels} texels, the observations {observations.n_texels}")
    roughness = np.where(estimate.estimated, estimate.roughness, np.nan)
    variance = np.zeros(observations.n_texels)
    if settings.roughness_window > 0:
        variance += _neighbour_variance(observations, roughness, settings.roughness_window)
    if settings.loss_curvature:
        variance += _loss_curvature_variance(observations, estimate, roughness, config)
    if settings.split_half:
        variance += _split_half_variance(observations, roughness, config)
    return np.where(np.isfinite(roughness), np.sqrt(variance), np.nan).astype(np.float32)


def _window_sums(observations: Observations, known: np.ndarray, window: int, *values: np.ndarray):
    """Sum over the ``known`` texels of the window x window square around each texel.

    In texture space; (N,) sums of 1 (how many there are), then of each of ``values`` ((N,) each).
    """
    flat = observations.texel_index

    def window_sum(value):
        texture = observations.to_texture(np.where(known, value, 0.0))
        return ndimage.uniform_filter(texture, window, mode="constant").ravel()[flat] * (window * window)

    return window_sum(np.ones(observations.n_texels)), *(window_sum(value) for value in values)


def _neighbour_variance(observations: Observations, roughness: np.ndarray, window: int) -> np.ndarray:
    """Return the (N,) variance of the estimated roughness over the window around each texel.

    Over the estimated texels of the window x window square (texture space); the prior variance
    where it holds no other texel.
    """
    known = np.isfinite(roughness)
    counts, sums, squares = _window_sums(observations, known, window, roughness, roughness * roughness)
    alone = counts < 1.5  # the texel itself only (the filter's sums are rounded)
    safe = np.where(alone, 1.0, counts)
    variance = np.maximum(squares / safe - np.square(sums / safe), 0.0)
    return np.where(alone, PRIOR_ROUGHNESS_VARIANCE, variance)


def _split_half_variance(observations: Observations, roughness: np.ndarray, config: Config) -> np.ndarray:
    """Return the (N,) scatter between the roughness estimated from the even and the odd views.

    Each half (`Observations.with_views`, the fit's estimator) has about twice the whole
    capture's variance and their difference four times, so (r_even - r_odd)^2 / 4 estimates the
    whole's, whatever makes the estimate unstable (noise, interreflection, a model that fits two
    roughness values). The prior variance where a half leaves the texel unestimated. One
    difference is a one-sample estimate, so it is averaged over the roughness_window square (when
    that is > 1). Since it is averaged, only the estimated texels of every split_half_stride-th
    row and column are estimated twice more (when the window is wider than the stride); a window
    holding none of them gets the prior variance.
    """
    settings = config.uncertainty
    window, stride = settings.roughness_window, settings.split_half_stride
    if stride < 1:
        raise ValueError(f"split_half_stride must be >= 1, got {stride}")
    stride = stride if window > stride else 1
    rows, columns = np.divmod(observations.texel_index, observations.texture_res)
    chosen = np.flatnonzero(np.isfinite(roughness) & (rows % stride == 0) & (columns % stride == 0))
    # Every texel: no copy of the samples.
    part = observations if len(chosen) == observations.n_texels else observations.select(chosen)
    halves = []
    for parity in (0, 1):
        keep = np.arange(observations.n_views) % 2 == parity
        half = estimate_materials(part.with_views(keep, config), config)
        halves.append(np.where(half.estimated, half.roughness, np.nan))
    scatter = np.square(halves[0] - halves[1]) / 4.0
    variance = np.full(observations.n_texels, PRIOR_ROUGHNESS_VARIANCE)
    variance[chosen] = np.where(np.isfinite(scatter), scatter, PRIOR_ROUGHNESS_VARIANCE)
    if window <= 1:
        return variance
    known = np.zeros(observations.n_texels, dtype=bool)
    known[chosen] = True
    counts, sums = _window_sums(observations, known, window, variance)
    return np.where(counts > 0.5, sums / np.maximum(counts, 1.0), PRIOR_ROUGHNESS_VARIANCE)


def _loss_curvature_variance(observations: Observations, estimate: MaterialEstimate, roughness: np.ndarray,
                             config: Config) -> np.ndarray:
    """Return the (N,) Laplace variance of the angular loss around the estimated roughness.

    2 s^2 / (n L''(r)) for the loss L (a weighted mean over n samples) around the estimated
    roughness r: the profiled loss (base colour and metallic re-optimised, the marginal
    posterior's) when the estimate carries the global search's
    `MaterialEstimate.roughness_curvature`, else base colour and metallic held; capped at the
    prior variance (a flat or concave loss says nothing). s^2 = L(r) 3n / (3n - 5) (the
    residual's unbiased noise variance: 3n values, five parameters fitted; the prior where
    3n <= 5) + (CURVATURE_NOISE_FLOOR)^2 x the weighted mean square of the observed radiance. L''
    is the second divided difference through r and two probes CURVATURE_STEP apart, on the side
    of r that stays within [0, 1].
    """
    loss_centre = estimate.loss
    if estimate.roughness_curvature is not None:
        curvature = estimate.roughness_curvature  # the global search's profiled curvature, for free
    else:
        step = CURVATURE_STEP
        centre = np.nan_to_num(roughness, nan=0.5)
        low_edge, high_edge = centre < step, centre > 1.0 - step
        first = np.where(low_edge, centre + step, centre - step)
        second = np.where(low_edge, centre + 2 * step, np.where(high_edge, centre - 2 * step, centre + step))

        def loss_at(probe):
            params = brdf.PrincipledParams(base_color=estimate.base_color, roughness=probe, metallic=estimate.metallic)
            return angular_loss(observations, params, config, model_light(observations, probe, config))

        loss_first, loss_second = loss_at(first), loss_at(second)
        curvature = 2.0 * ((loss_first - loss_centre) / (first - centre)
                           - (loss_second - loss_centre) / (second - centre)) / (first - second)
    # In float32 and without an (N, V, 3) temporary, for speed and memory.
    weight_sq = np.square(observations.weight)
    radiance_sq = np.nan_to_num(np.einsum("nvc,nvc->nv", observations.observed, observations.observed), copy=False)
    signal = (np.einsum("nv,nv->n", weight_sq, radiance_sq).astype(np.float64)
              / np.maximum(weight_sq.sum(axis=1, dtype=np.float64), np.finfo(np.float64).tiny))
    samples = np.maximum(observations.n_samples, 1)
    values = 3.0 * samples  # RGB per sample, against base colour, roughness and metallic
    with np.errstate(divide="ignore", invalid="ignore"):
        noise = (np.where(values > FITTED_PARAMETERS, loss_centre * values / (values - FITTED_PARAMETERS), np.inf)
                 + CURVATURE_NOISE_FLOOR**2 * signal)
        variance = 2.0 * noise / (samples * curvature)
    informative = np.isfinite(variance) & (curvature > 0)
    return np.where(informative, np.minimum(variance, PRIOR_ROUGHNESS_VARIANCE), PRIOR_ROUGHNESS_VARIANCE)
