"""Censored samples: the clipped channels of a photograph, filled in from the estimate.

docs/method.md#censored-samples. A channel read from a pixel on its clipping plateau (8-bit data,
a blown highlight; `freqbrdf.images.clipped_channels`) says only that the radiance was at least
that value. `freqbrdf.observe.observe` keeps such samples at weight 0, so the first estimate
reads the exact samples alone; `impute_censored` is then the expectation step of EM for censored
data: each censored channel becomes the larger of its lower bound and what the model predicts
under that estimate (a bright texel whose every view is clipped in red still has its exact green
and blue, and red at least the ceiling), and the samples count again, with their SH spectra
fitted anew. The estimate that follows reads every sample.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from freqbrdf.config import Config
from freqbrdf.estimate.search import predict_samples
from freqbrdf.model import brdf
from freqbrdf.observe.observations import Observations
from freqbrdf.observe.signals import CONSTANT, MIRRORED, OBSERVED, fit_signals, texel_alpha_bound

__all__ = ["impute_censored"]


def impute_censored(observations: Observations, params: brdf.PrincipledParams, config: Config = Config()) -> Observations:
    """Fill the censored channels from the model's prediction and count their samples.

    Parameters
    ----------
    observations : Observations
        N texels, V views, with ``censored`` (N, V, 3) and ``censored_weight`` (N, V) from
        `freqbrdf.observe.observe`.
    params : brdf.PrincipledParams
        An estimate of every texel: base colour (N, 3), roughness and metallic (N,); a texel with
        NaN keeps its lower bounds.
    config : Config, optional
        The model (``config.estimate``) and the SH fit (``config.fit``) the observations were made with.

    Returns
    -------
    Observations
        The same texels with each censored channel at max(its lower bound, the prediction), the
        censored samples' weights in ``weight`` (``censored_weight`` None; ``censored`` kept, to
        say which values are imputed), and the SH spectra, sample counts and alpha' of the texels
        with a censored sample fitted again. ``observations`` itself where nothing is censored.
    """
    if observations.censored_weight is None or not np.any(observations.censored_weight > 0.0):
        return observations
    rows = np.flatnonzero((observations.censored_weight > 0.0).any(axis=1))
    part = observations.select(rows)
    weight = (part.weight + part.censored_weight).astype(np.float32)
    counted = replace(part, weight=weight)
    selected = brdf.PrincipledParams(base_color=np.asarray(params.base_color)[rows],
                                     roughness=np.asarray(params.roughness)[rows], metallic=np.asarray(params.metallic)[rows])
    predicted = predict_samples(counted, selected, config)
    observed = np.where(part.censored, np.fmax(part.observed, predicted), part.observed).astype(np.float32)

    fit = fit_signals(part.view_direction, weight, observed, part.mirrored, observations.lmax, config)
    settings = config.fit

    changes = {"observed": observations.observed.copy(), "weight": observations.weight.copy(),
               "observed_coeffs": observations.observed_coeffs.copy(),
               "mirrored_coeffs": observations.mirrored_coeffs.copy(),
               "constant_coeffs": observations.constant_coeffs.copy(), "fit_status": observations.fit_status.copy(),
               "n_samples": observations.n_samples.copy(), "alpha_bound": observations.alpha_bound.copy()}
    changes["observed"][rows] = observed
    changes["weight"][rows] = weight
    changes["observed_coeffs"][rows] = fit.coeffs[:, OBSERVED]
    changes["mirrored_coeffs"][rows] = fit.coeffs[:, MIRRORED]
    changes["constant_coeffs"][rows] = fit.coeffs[:, CONSTANT]
    changes["fit_status"][rows] = fit.status
    changes["n_samples"][rows] = fit.n_samples
    changes["alpha_bound"][rows] = texel_alpha_bound(fit.n_samples, observations.lmax, settings.attenuation_threshold)
    return replace(observations, **changes, censored_weight=None)
