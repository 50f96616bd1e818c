"""The signals a texel's samples are fitted on, and what is read from its samples alone (docs/method.md#sh-fit).

Per texel, `fit_signals` fits the SH spectra of seven signals on the same samples: observed RGB,
mirrored environment RGB and the constant 1 (`OBSERVED`, `MIRRORED`, `CONSTANT`);
`mean_over_views` averages a per-sample value over a texel's samples; `texel_alpha_bound` is the
roughness the texel's samples can resolve (docs/method.md#band-limit). Used by
`freqbrdf.observe.observations` and by the estimate where it refits samples.
"""

from __future__ import annotations

import numpy as np

from freqbrdf.config import Config
from freqbrdf.observe._kernels import _weighted_view_sums
from freqbrdf.sphere import harmonics as sh

__all__ = ["CONSTANT", "MIRRORED", "N_SIGNALS", "OBSERVED", "fit_signals", "mean_over_views", "texel_alpha_bound"]

# Channel layout of the fitted signals.
OBSERVED = slice(0, 3)
MIRRORED = slice(3, 6)
CONSTANT = 6
N_SIGNALS = 7


def fit_signals(view_direction: np.ndarray, weight: np.ndarray, observed: np.ndarray, mirrored: np.ndarray,
                lmax: int, config: Config) -> sh.SHFit:
    """Fit the SH spectra of samples again, as `observe` fits them.

    The signals are observed RGB, mirrored RGB and the constant 1 (`OBSERVED`, `MIRRORED`,
    `CONSTANT` of the coefficients).

    Parameters
    ----------
    view_direction : (N, V, 3) float32
        Local view directions.
    weight : (N, V) float32
        The samples' weights.
    observed, mirrored : (N, V, 3) float32
        Observed radiance and mirrored environment.
    lmax : int
        The degree.
    config : Config
        ``config.fit``'s regulariser; ``config.device``.

    Returns
    -------
    sh.SHFit
        Coefficients (N, 7, K), sample counts and fit status.
    """
    signals = np.empty((*weight.shape, N_SIGNALS), dtype=np.float32)
    signals[..., OBSERVED] = observed
    signals[..., MIRRORED] = mirrored
    signals[..., CONSTANT] = 1.0
    settings = config.fit
    return sh.fit_sh(view_direction, weight, signals, lmax, settings.reg_lambda, settings.regulariser,
                     settings.scale_lambda_with_weight, config.device)


def mean_over_views(weight: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Return the weighted mean of per-sample values over each texel's samples.

    Parameters
    ----------
    weight : (N, V) array
        The samples' weights (`Observations.weight`).
    values : (N, V, 3) array
        A value per sample, e.g. ``Observations.observed``.

    Returns
    -------
    (N, 3) float64
        The mean; 0 for a texel without samples.
    """
    # Strided views (a channel slice of the signals) are read in place: a copy of (N, V, 3) costs
    # more than the sums.
    total, summed = _weighted_view_sums(weight, values)
    return np.where(total[:, None] > 0, summed / np.maximum(total, 1e-30)[:, None], 0.0)


def texel_alpha_bound(n_samples: np.ndarray, lmax: int, attenuation: float) -> np.ndarray:
    """Return the roughness bound alpha' (appendix eq. 12, docs/method.md#band-limit) of each texel.

    alpha' = sqrt(-ln t) / l, with l the usable degree: the smaller of what the texel's n
    samples resolve (l < sqrt(n), `freqbrdf.model.brdf.resolvable_degree`) and the fit's l*
    (spectra carry no information above l*).

    Parameters
    ----------
    n_samples : (N,) int
        Samples per texel.
    lmax : int
        l*, the degree of the fits.
    attenuation : float
        t in (0, 1), the acceptable attenuation (``FitConfig.attenuation_threshold``).

    Returns
    -------
    (N,) float32
        alpha' per texel; inf where fewer than 2 samples (no degree resolved).
    """
    n_samples = np.asarray(n_samples, dtype=np.int64)
    root = np.floor(np.sqrt(n_samples)).astype(np.int64)
    resolvable = np.minimum(root - (root * root == n_samples), lmax)
    bound = np.full(n_samples.shape, np.inf, dtype=np.float32)
    ok = resolvable >= 1
    bound[ok] = np.sqrt(-np.log(attenuation)) / resolvable[ok]
    return bound
