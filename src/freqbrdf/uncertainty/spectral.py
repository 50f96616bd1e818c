"""The entropy of the specular hypotheses from SH power spectra (docs/method.md#entropy).

Per texel and channel the R x R grid (`hypothesis_grid`) is scored against the observed
radiance's power spectrum S_out(l), l = 1..l* (l = 0 also carries the diffuse term). Two modes:

- ``paper`` reproduces the published recipe: S_psi(l) = k^2 exp(-2 alpha^2 l^2) S_refl(l),
  E = S_out(0)^2 mean_l (S_psi(l) - S_out(l))^2, P(psi) ∝ exp(-(E - min E) / tau),
  H = -sum P log P / log R^2. Its S_out(0)^2 makes E scale with exposure to the 8th power and
  calls every dark texel uncertain.
- ``calibrated`` (the default) is a posterior over the same box. Residuals are on amplitudes,
  sqrt(S_psi(l)) = k F(alpha, l) sqrt(S_refl(l)) with F = `hypothesis_filter` (band-limit
  compensated), and the specular DC may not exceed the observed DC. They are measured against
  the light's RMS amplitude sqrt(P), P = mean over RGB of sum_l S_refl(l), so scaling the images
  and the environment by kappa leaves the map unchanged. The temperature is a noise model: a
  fitted coefficient's variance s^2 = noise_level^2 P K / n over n samples, plus (with
  ``residual_noise``) the best hypothesis's misfit per residual degree of freedom (l* - 2). All
  k = 0 cells are one material; the entropy is normalised by log(R (R-1) + 1).

For fixed alpha the misfit is a quadratic in t (t = k^2 in paper mode, t = k in calibrated mode,
plus the convex DC bound), so the grid costs O(R l* + R^2) per texel and channel
(`freqbrdf.uncertainty._kernels.grid_entropy_kernel`). docs/results.md#the-entropy has the
speed and how these maps compare with a path tracer.
"""

from __future__ import annotations

import numba
import numpy as np

from freqbrdf.config import UncertaintyConfig
from freqbrdf.devices import resolve_device
from freqbrdf.model import brdf
from freqbrdf.sphere import harmonics as sh
from freqbrdf.uncertainty._kernels import EntropyOutputs, SpectraInputs, SpectralOptions, grid_entropy_kernel
from freqbrdf.uncertainty._result import HypothesisGrid, Uncertainty, hypothesis_grid, uncertainty_of_grid


def cross_spectrum(observed_coeffs: np.ndarray, light_coeffs: np.ndarray) -> np.ndarray:
    """Return the cross spectrum X(l) = sum_m o_lm m_lm per degree.

    Parameters
    ----------
    observed_coeffs, light_coeffs : (..., K) array_like
        SH coefficients, broadcast against each other.

    Returns
    -------
    (..., L) float64
        One value per degree l = 0..l*.
    """
    lmax = sh.lmax_of(observed_coeffs.shape[-1])
    product = np.multiply(observed_coeffs, light_coeffs, dtype=np.float64)
    return np.add.reduceat(product, np.arange(lmax + 1) ** 2, axis=-1)


def hypothesis_filter(grid: HypothesisGrid, lmax: int, sigma: float) -> np.ndarray:
    """Return the calibrated mode's per-degree amplitude filter of each alpha row.

    The paper's exp(-(alpha l)^2) divided by the band-limit blur exp(-(sigma l)^2) the mirrored
    light went through (``brdf.brdf_kernel``).

    Parameters
    ----------
    grid : HypothesisGrid
        The hypotheses (R rows).
    lmax : int
        l*.
    sigma : float
        The band-limit width.

    Returns
    -------
    (R, L) float64
        The filter of row i at degree l.
    """
    return brdf.brdf_kernel(grid.alpha, lmax, sigma)


def entropy_from_spectra(
    light_spectrum: np.ndarray,
    observed_spectrum: np.ndarray,
    *,
    n_samples: np.ndarray | None = None,
    sigma: float = 0.0,
    alpha_bound: np.ndarray | None = None,
    fit_status: np.ndarray | None = None,
    config: UncertaintyConfig = UncertaintyConfig(),
    return_likelihood: bool = True,
    device: str = "auto",
) -> Uncertainty:
    """Score the hypothesis grid against power spectra (the calibrated or the paper mode).

    Calibrated mode compares amplitudes as if the observed and the light's coefficients were
    aligned in every degree (sqrt(S_out S_refl)). Hypothetical spectra (capture guidance) can be
    scored the same way.

    Parameters
    ----------
    light_spectrum : (N, 3, L) array_like
        Power spectrum S_refl(l) of each texel's mirrored (band-limited) environment fit, L >= 2.
    observed_spectrum : (N, 3, L) array_like
        Power spectrum S_out(l) of its observed radiance.
    n_samples : (N,) int, optional
        Samples (views with positive weight) per texel: in calibrated mode the fitted
        coefficients' noise variance is noise_level^2 P K / n_samples for K coefficients; and
        FLAG_FEW_SAMPLES. None: K samples assumed, no FLAG_FEW_SAMPLES.
    sigma : float
        The band-limit width (compensated in calibrated mode only, as in the paper's recipe).
    alpha_bound : (N,) float, optional
        The sampling bound alpha' per texel (FLAG_BELOW_BOUND); None: no bound.
    fit_status : (N,) uint8, optional
        ``sh.FIT_*`` per texel; FIT_EMPTY texels get the prior. None: all fits OK.
    config : UncertaintyConfig
        Mode "calibrated" or "paper", the grid, the noise model or temperature, the flags.
    return_likelihood : bool
        Whether to keep the (N, R, R) likelihood.
    device : {"auto", "cpu", "cuda"}
        Where the grid is scored (`freqbrdf.devices.resolve_device`); the backends agree to
        rounding (docs/results.md).

    Returns
    -------
    Uncertainty
        Of the N texels.
    """
    light_spectrum = np.asarray(light_spectrum)
    observed_spectrum = np.asarray(observed_spectrum)
    if light_spectrum.ndim != 3 or light_spectrum.shape[1] != 3 or light_spectrum.shape[2] < 2:
        raise ValueError(f"spectra must be (N, 3, l*+1) with l* >= 1, got {light_spectrum.shape}")
    if observed_spectrum.shape != light_spectrum.shape:
        raise ValueError(f"spectra shapes differ: {light_spectrum.shape} vs {observed_spectrum.shape}")
    if config.mode not in ("calibrated", "paper"):
        raise ValueError(f"spectra are scored in mode 'calibrated' or 'paper', not {config.mode!r} (the angular "
                         "mode needs the samples: entropy_map or entropy_angular)")
    n_texels, _, n_degrees = light_spectrum.shape
    lmax = n_degrees - 1
    grid = hypothesis_grid(config.resolution())
    paper = config.mode == "paper"

    if paper:
        # Power residuals, uncompensated kernel, the prototype's S_out(0)^2 weight and mean over l.
        row_filter = np.square(brdf.brdf_kernel(grid.alpha, lmax))
        scale = np.square(observed_spectrum[..., 0].astype(np.float64)) / (lmax * config.temperature)
    else:
        # Amplitude residuals against the light's RMS amplitude (module docstring).
        row_filter = hypothesis_filter(grid, lmax, sigma)
        # Least squares: each of the K fitted coefficients has about K / n_samples times a sample's
        # variance. The kernel divides by the light power P.
        samples_per_coeff = (np.ones(n_texels) if n_samples is None
                             else np.maximum(np.asarray(n_samples, dtype=np.float64), 1.0) / n_degrees**2)
        scale = (samples_per_coeff / (2.0 * config.noise_level**2))[:, None]  # the same for every channel
    # Amplitudes of degrees 1..l* against two parameters (alpha, k): l* - 2 residual degrees of freedom.
    residual_dof = float(max(lmax - 2, 1)) if (not paper and config.residual_noise) else 0.0
    resolution = grid.resolution
    outputs = EntropyOutputs(
        entropy=np.empty(n_texels, dtype=np.float32),
        channel=np.empty(n_texels, dtype=np.int8),
        best_alpha=np.empty(n_texels, dtype=np.float32),
        best_ks=np.empty(n_texels, dtype=np.float32),
        likelihood=np.empty((n_texels if return_likelihood else 0, resolution, resolution), dtype=np.float32),
    )
    spectra = SpectraInputs(
        light=_kernel_input(light_spectrum), observed=_kernel_input(observed_spectrum),
        scale=np.ascontiguousarray(scale, dtype=np.float64), row_filter=np.ascontiguousarray(row_filter),
        alphas=grid.alpha,
    )
    options = SpectralOptions(amplitude=not paper, per_light_power=not paper, merge_zero=not paper,
                              residual_dof=residual_dof, want_likelihood=bool(return_likelihood))
    if resolve_device(device) == "cuda":
        from freqbrdf.uncertainty._cuda_kernels import grid_entropy_on_cuda

        grid_entropy_on_cuda(spectra, options, outputs)
    else:
        grid_entropy_kernel(spectra, options, numba.get_num_threads(), outputs)

    status = np.zeros(n_texels, np.uint8) if fit_status is None else np.asarray(fit_status)
    return uncertainty_of_grid(status == sh.FIT_EMPTY, outputs.entropy, outputs.channel, outputs.best_alpha,
                               outputs.best_ks, outputs.likelihood if return_likelihood else None, n_samples,
                               n_degrees**2, alpha_bound, grid, config)


def _kernel_input(array: np.ndarray) -> np.ndarray:
    """Return a contiguous float32 or float64 array: those pass without a copy, others become float64."""
    return np.ascontiguousarray(array if array.dtype in (np.float32, np.float64) else array.astype(np.float64))
