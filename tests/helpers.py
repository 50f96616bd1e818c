"""Builders shared by the tests: synthetic `Observations` from samples or from spectra."""

from __future__ import annotations

import math

import numpy as np

from freqbrdf.config import FitConfig
from freqbrdf.observe.observations import Observations
from freqbrdf.sphere import harmonics as sh

F32 = np.float32


def observations_from_samples(directions: np.ndarray, weight: np.ndarray, observed: np.ndarray,
                              mirrored: np.ndarray, lmax: int, *, irradiance: np.ndarray | None = None,
                              sigma: float = 0.0, reg_lambda: float = FitConfig().reg_lambda,
                              observed_fit_values: np.ndarray | None = None, **fields) -> Observations:
    """Observations of N texels seen from V views, with their SH fits made here.

    Parameters
    ----------
    directions : (N, V, 3)
        Unit view directions in each texel's local frame.
    weight : (N, V)
        Sample weights (0: no sample).
    observed, mirrored : (N, V, 3)
        Observed radiance and the environment in the mirror direction.
    lmax : int
        Degree l* of the fits.
    irradiance : (N, 3), optional
        Irradiance E; default 1.
    sigma : float
        Band-limit width recorded in the observations.
    reg_lambda : float
        Regularisation of the fits.
    observed_fit_values : (N, V, 3), optional
        What the observed coefficients are fitted to, when not ``observed`` (e.g. noise-free values).
    **fields
        Any other `Observations` field, overriding the defaults built here.

    Returns
    -------
    Observations
        float32 arrays, texel i at flat index i of the smallest square texture holding N texels.
    """
    n_texels, n_views = weight.shape
    irradiance = np.ones((n_texels, 3)) if irradiance is None else irradiance
    light_fit = sh.fit_sh(directions, weight, np.concatenate([mirrored, np.ones((n_texels, n_views, 1))], axis=-1),
                          lmax, reg_lambda)
    observed_fit = sh.fit_sh(directions, weight, observed if observed_fit_values is None else observed_fit_values,
                             lmax, reg_lambda)
    values = dict(
        texture_res=math.isqrt(max(n_texels - 1, 0)) + 1, texel_index=np.arange(n_texels, dtype=np.int64),
        normal=np.tile(np.array([0.0, 0.0, 1.0], F32), (n_texels, 1)),
        view_direction=np.asarray(directions, F32), observed=np.asarray(observed, F32),
        mirrored=np.asarray(mirrored, F32), weight=np.asarray(weight, F32), visible=np.asarray(weight) > 0,
        irradiance=np.asarray(irradiance, F32), lmax=lmax, sigma=sigma,
        observed_coeffs=observed_fit.coeffs.astype(F32), mirrored_coeffs=light_fit.coeffs[:, :3].astype(F32),
        constant_coeffs=light_fit.coeffs[:, 3].astype(F32), fit_status=light_fit.status,
        n_samples=light_fit.n_samples, n_facing=light_fit.n_samples.astype(np.int32),
        alpha_bound=np.zeros(n_texels, F32),
    )
    values.update(fields)
    return Observations(**values)


def observations_from_spectra(light: np.ndarray, observed: np.ndarray, texel_index: np.ndarray, texture_res: int,
                              lmax: int, n_samples: int = 64) -> Observations:
    """Observations whose fits have the given power spectra and no samples to speak of.

    Parameters
    ----------
    light, observed : (N, 3, L)
        Power spectra S(l) of the mirrored environment and of the observed radiance; each degree's
        power goes to its m = 0 coefficient, sqrt(S(l)).
    texel_index : (N,) int
        Flat indices of the texels in the T x T texture.
    texture_res : int
        T.
    lmax : int
        l* (L = l* + 1).
    n_samples : int
        Sample count recorded per texel.

    Returns
    -------
    Observations
        One placeholder sample per texel; the spectra carry the information.
    """
    n_texels = light.shape[0]
    degrees = np.arange(lmax + 1)
    zero_index = degrees**2 + degrees  # flat index of (l, m = 0)

    def coeffs(spectrum):
        out = np.zeros((n_texels, 3, sh.num_coeffs(lmax)), F32)
        out[..., zero_index] = np.sqrt(spectrum)
        return out

    return Observations(
        texture_res=texture_res, texel_index=texel_index, normal=np.zeros((n_texels, 3), F32),
        view_direction=np.zeros((n_texels, 1, 3), F32), observed=np.zeros((n_texels, 1, 3), F32),
        mirrored=np.zeros((n_texels, 1, 3), F32), weight=np.ones((n_texels, 1), F32),
        visible=np.ones((n_texels, 1), bool), irradiance=np.ones((n_texels, 3), F32), lmax=lmax,
        sigma=0.0, observed_coeffs=coeffs(observed), mirrored_coeffs=coeffs(light),
        constant_coeffs=np.zeros((n_texels, sh.num_coeffs(lmax)), F32),
        fit_status=np.zeros(n_texels, np.uint8), n_samples=np.full(n_texels, n_samples, np.int32),
        alpha_bound=np.zeros(n_texels, F32), n_facing=np.full(n_texels, n_samples, np.int32),
    )
