"""Per-texel uncertainty of the specular parameters from SH power spectra or samples (METHOD.md §3.8).

Per texel and colour channel, a grid of specular hypotheses psi = (alpha_i, k_j),
alpha_i = (i / (R-1))^2 (roughness i / (R-1), uniform) and k_j = j / (R-1), is scored against the
power spectrum of the observed radiance S_out(l) for l = 1..l* (l = 0 also carries the diffuse
term and is left out). The likelihood over the grid is turned into a normalised entropy; the map
is the minimum over RGB (the best-informed channel). Three modes:

``paper`` reproduces the published recipe:

    S_psi(l) = k^2 exp(-2 alpha^2 l^2) S_refl(l),  E = S_out(0)^2 mean_l (S_psi(l) - S_out(l))^2,
    P(psi) ∝ exp(-(E - min E) / tau),  H = -sum P log P / log R^2,

including the prototype's factor S_out(0)^2: E then scales with exposure to the 8th power and a
dark texel (S_out(0) ~ 0) gets a flat likelihood, i.e. it is called uncertain.

``calibrated`` (the default) is an honest posterior over the same hypothesis box:

- Residuals are taken on amplitudes sqrt(S(l)), not on powers. Noise on a fitted coefficient is
  additive, so on an amplitude it is roughly constant, whereas on a power it shrinks to second
  order near zero: power residuals make a black texel unable to rule out a specular lobe that
  reflects 14 % of the light. The model is sqrt(S_psi(l)) = k F(alpha, l) sqrt(S_refl(l)),
  F = `hypothesis_filter`, the paper's K_sigma = ``brdf.brdf_kernel(alpha, l*, sigma)`` divided
  by the band-limit blur. The specular DC
  k sqrt(S_refl(0)) may not exceed the observed DC: a rough lobe puts nearly all its energy in
  l = 0, which the degrees l >= 1 alone cannot rule out on a dark texel.
- Residuals are measured against the LIGHT's RMS amplitude sqrt(P), P = mean over RGB of
  sum_{l=0..l*} S_refl(l): scaling every image and the environment by kappa scales all
  coefficients by kappa and leaves the map unchanged, and a dark texel under bright, sharp light
  is a strong observation (k ~ 0), not a missing one.
- The temperature is a noise model: each sample's radiance has noise std ``noise_level`` x
  sqrt(P); least squares over n samples for K = (l*+1)^2 coefficients leaves each fitted
  coefficient a variance of about s^2 = noise_level^2 P K / n, and P(psi) ∝ exp(-misfit / (2 s^2)).
  So a texel seen from few views is less certain than the same texel seen from many. With
  ``residual_noise`` (default) s^2 also includes the misfit of the best hypothesis per residual
  degree of freedom (l* - 2), as a likelihood with unknown noise would: real photographs depart
  from the model (Fresnel, masking, diffuse leakage into l > 0, sparse sampling), and a texel
  that no hypothesis explains must not concentrate on the least bad one.
- All hypotheses with k = 0 are one material (no specular lobe, roughness undefined). The prior
  is uniform over the R (R-1) + 1 distinct materials and the entropy is taken over them and
  normalised by log(R (R-1) + 1): H = 1 means the data says nothing, H = 0 one material.

Speed: for fixed alpha the misfit is a quadratic in t (t = k^2 in paper mode, t = k in calibrated
mode, plus the convex DC bound), e(t) = A (t - t*)^2 + e(t*), whose coefficients are sums over l; the whole grid costs
O(R l* + R^2) per texel and channel. Cells more than CUTOFF above the minimum (in units of the
temperature) are clamped there: their share is below e^-CUTOFF. The kernel (_grid_entropy_kernel)
runs SIMD across texels: moments and row minima in float64, the R^2 cells in float32 with a
polynomial exp; measured figures in benchmarks/results/bench_entropy.json.

``angular`` scores a grid of hypotheses in the sample domain instead of on spectra, with the
`global` estimator's own forward model (`entropy_angular`; by default on the estimator's roughness
nodes, 9 x 9, as UncertaintyConfig.grid_res says): per hypothesis, the radiance a metal of base
colour k and roughness sqrt(alpha) reflects at each observed view (split-sum albedo, the prefiltered
and environment light), the best constant diffuse part, and the misfit of the samples; the noise
model of the calibrated mode in radiance units. It is what benchmarks/pathtraced_entropy.py computes
with a path tracer, and agrees with it: Spearman 0.81 [0.76, 0.86] (95 % bootstrap interval, 400
texels, 9 x 9) against the pooled rendering of two seeds, which agree with each other at 0.89; on
the 8 x 8 grid the calibrated mode 0.19 (with GGX lobes, a retired option, 0.38), the paper's recipe
0.17. It costs R probes of the estimator's search per texel: on its own seconds, not milliseconds
(2.0 s for the 256k texels there); inside `pipeline.fit` the search makes those probes anyway
(`AngularEntropy`), and the fit takes about 3 % longer.
Both the brute force and this mode find the smooth-gradient ("badly lit") region of
entropy_scenes.py about as certain as the sharply lit one (brute force 0.15 and 0.17, this mode
0.16 and 0.18): the view dependence of Fresnel and masking, which a spectrum of the mirrored light
leaves out, pins the roughness down there; the paper's recipe calls it uncertain (0.78 against
0.20).

Why the spectra disagree with the path tracer, measured by benchmarks/pathtraced_entropy.py's
"spectral" brute force (the path-traced radiance of each hypothesis fitted to SH at the texel's
samples and scored exactly as the calibrated mode scores its model; scoring the model's own spectra
that way reproduces this module's entropy to 1e-6): it agrees with itself at 0.98 and with the
calibrated mode at 0.17 only, so the model of a hypothesis's spectrum is what is wrong, not the
scoring. The GGX lobe's gains and albedo (a retired option) took it to 0.45; the rest is what one
zonal filter per texel cannot hold (the albedo's and the lobe's change across the texel's views, the
sparse samples' aliasing), and to 0.68 without the residual term in the noise. Neither brute force
ranks the estimate's roughness errors (0.11 and 0.18 on those texels; the roughness std 0.40):
agreeing with the path tracer and ranking the errors are different goals.

Flags (bit field, uint8 per texel) say why a texel should not be trusted; see FLAG_*.

The entropy scores the hypotheses against the spectra, not the estimate, and ranks the `global`
estimate's per-texel roughness errors poorly (Spearman 0.28 on the Mitsuba bunny, 0.31 on the
sphere of entropy_scenes.py; GGX lobes 0.25 and 0.29; the angular mode 0.28 and 0.21).
`roughness_std` is the posterior spread of the estimate itself (UncertaintyConfig.roughness_window,
loss_curvature): 0.56 and 0.48, measured in benchmarks/entropy_variants.py (session-10 estimator,
with the neighbour vote); with the scatter between the even and the odd views' estimates too
(UncertaintyConfig.split_half, `fit --split-half`, seconds) 0.57 and 0.51.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba
import numpy as np
from scipy import ndimage

from freqbrdf.config import Config, EstimateConfig, UncertaintyConfig
from freqbrdf.estimate import (
    CURVATURE_STEP,
    FITTED_PARAMETERS,
    HYPOTHESIS_BLOCK,
    HypothesisRecorder,
    angular_loss,
    hypothesis_moments,
    model_light,
    texel_blocks,
)
from freqbrdf.estimate import (
    estimate as estimate_materials,
)
from freqbrdf.model import brdf
from freqbrdf.sphere import harmonics as sh
from freqbrdf.uncertainty._kernels import CUTOFF, _grid_entropy_kernel, _moment_entropy_kernel

__all__ = [
    "FLAG_UNOBSERVED",
    "FLAG_FEW_SAMPLES",
    "FEW_SAMPLES_FRACTION",
    "FLAG_BELOW_BOUND",
    "FLAG_AMBIGUOUS",
    "FLAG_NAMES",
    "CUTOFF",
    "PRIOR_ROUGHNESS_VARIANCE",
    "CURVATURE_NOISE_FLOOR",
    "HypothesisGrid",
    "hypothesis_grid",
    "Uncertainty",
    "entropy_map",
    "roughness_std",
    "cross_spectrum",
    "hypothesis_filter",
    "entropy_from_spectra",
    "entropy_angular",
    "entropy_from_moments",
    "AngularEntropy",
    "summary",
]

if TYPE_CHECKING:
    from freqbrdf.estimate import MaterialEstimate
    from freqbrdf.observe.observations import Observations

FLAG_UNOBSERVED = 1  # no sample at all: entropy 1, uniform likelihood, no estimate
# Fewer samples than a quarter of the SH coefficients: the fit mostly extrapolates. (Fewer than all
# of them flagged 80 % of the Mitsuba bunny's texels at 64 views; a quarter flags 6.5 %, whose
# roughness error is 1.9x the others'.)
FLAG_FEW_SAMPLES = 2
FEW_SAMPLES_FRACTION = 0.25
FLAG_BELOW_BOUND = 4  # the most likely alpha lies below the sampling bound alpha' (appendix eq. 12)
FLAG_AMBIGUOUS = 8  # entropy above config.ambiguous_entropy: the light does not separate hypotheses
FLAG_NAMES = {
    FLAG_UNOBSERVED: "unobserved",
    FLAG_FEW_SAMPLES: "few_samples",
    FLAG_BELOW_BOUND: "below_bound",
    FLAG_AMBIGUOUS: "ambiguous",
}

# What a texel's roughness variance is without information: roughness uniform on [0, 1].
PRIOR_ROUGHNESS_VARIANCE = 1.0 / 12.0
# Noise floor of the loss curvature's noise variance: a sample's noise std relative to the RMS of
# the texel's observed radiance, so that a texel fitted exactly is not called certain.
CURVATURE_NOISE_FLOOR = 0.02


@dataclass(frozen=True)
class HypothesisGrid:
    """The R x R specular hypotheses; likelihood grids are indexed [alpha index, k index]."""

    alpha: np.ndarray  # (R,) float64 alpha_i = (i / (R-1))^2
    specular: np.ndarray  # (R,) float64 k_j = j / (R-1)

    @property
    def resolution(self) -> int:
        return len(self.alpha)


def hypothesis_grid(grid_res: int) -> HypothesisGrid:
    """The paper's grid: roughness and specular amplitude uniform in [0, 1], R values each."""
    if grid_res < 2:
        raise ValueError(f"grid_res must be at least 2, got {grid_res}")
    steps = np.arange(grid_res) / (grid_res - 1)
    return HypothesisGrid(alpha=np.square(steps), specular=steps)


@dataclass(eq=False)
class Uncertainty:
    """Per-texel uncertainty of the specular parameters. N texels, R = grid resolution."""

    entropy: np.ndarray  # (N,) float32 normalised entropy in [0, 1] (minimum over RGB)
    flags: np.ndarray  # (N,) uint8 bit field of FLAG_*
    likelihood: np.ndarray | None  # (N, R, R) float32 posterior of the chosen channel, sums to 1
    best_alpha: np.ndarray  # (N,) float32 arg-max alpha; NaN where the arg-max has k = 0 or unobserved
    best_ks: np.ndarray  # (N,) float32 arg-max k_s; NaN where unobserved
    channel: np.ndarray  # (N,) int8 RGB channel that gave the minimum entropy; -1 where unobserved
    mode: str  # "calibrated" or "paper"
    grid: HypothesisGrid
    # (N,) float32 posterior std of the estimated roughness (`roughness_std`); NaN where not
    # estimated; None when not computed (it needs the estimate).
    roughness_std: np.ndarray | None = None

    def to_texture(self, observations: Observations, quantity: str = "entropy", fill: float = 0.0) -> np.ndarray:
        """Scatter one per-texel field (e.g. "entropy", "flags", "best_alpha") into a (T, T, ...) texture."""
        values = getattr(self, quantity)
        if values is None:
            raise ValueError(f"{quantity} was not computed")
        return observations.to_texture(values, fill=fill)


# --------------------------------------------------------------------------------------------
# Entry points


def entropy_map(
    observations: Observations, config: UncertaintyConfig = UncertaintyConfig(), return_likelihood: bool = True,
    estimate_config: EstimateConfig = EstimateConfig(),
) -> Uncertainty:
    """The uncertainty map of a capture's observations (see the module docstring); ``angular`` mode
    scores the hypotheses with the estimator's model of ``estimate_config`` (`entropy_angular`).
    """
    if config.mode == "angular":
        return entropy_angular(observations, Config(uncertainty=config, estimate=estimate_config), return_likelihood)
    return entropy_from_spectra(
        observations.mirrored_spectrum,
        observations.observed_spectrum,
        n_samples=observations.n_samples,
        sigma=observations.sigma,
        alpha_bound=observations.alpha_bound,
        fit_status=observations.fit_status,
        config=config,
        return_likelihood=return_likelihood,
    )


def roughness_std(
    observations: Observations, estimate: MaterialEstimate, config: Config = Config()
) -> np.ndarray | None:
    """(N,) float32 posterior std of the estimated roughness, from ``config.uncertainty``'s
    roughness_window, loss_curvature and split_half terms (their variances add; see
    UncertaintyConfig); NaN where not estimated, None when all terms are off. ``config`` is the
    fit's: the curvature scores the estimate with the estimator's model, as ``estimate.loss`` was,
    and the split halves are estimated as the whole was.
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
    """(N,) sums over the ``known`` texels of the window x window square around each texel
    (texture space): of 1 (how many there are), then of each of ``values`` ((N,) each).
    """
    flat = observations.texel_index

    def window_sum(value):
        texture = observations.to_texture(np.where(known, value, 0.0))
        return ndimage.uniform_filter(texture, window, mode="constant").ravel()[flat] * (window * window)

    return window_sum(np.ones(observations.n_texels)), *(window_sum(value) for value in values)


def _neighbour_variance(observations: Observations, roughness: np.ndarray, window: int) -> np.ndarray:
    """(N,) variance of the estimated roughness over the estimated texels of the window x window
    square around each texel (texture space); the prior variance where it holds no other texel.
    """
    known = np.isfinite(roughness)
    counts, sums, squares = _window_sums(observations, known, window, roughness, roughness * roughness)
    alone = counts < 1.5  # the texel itself only (the filter's sums are rounded)
    safe = np.where(alone, 1.0, counts)
    variance = np.maximum(squares / safe - np.square(sums / safe), 0.0)
    return np.where(alone, PRIOR_ROUGHNESS_VARIANCE, variance)


def _split_half_variance(observations: Observations, roughness: np.ndarray, config: Config) -> np.ndarray:
    """(N,) the scatter between the roughness estimated from the even-numbered views alone and
    from the odd-numbered ones (`Observations.with_views`, the fit's estimator): each half's
    variance is about twice the whole capture's and their difference's four times, so
    (r_even - r_odd)^2 / 4 estimates the whole's, whatever makes the estimate unstable (noise,
    interreflection, a model that fits two roughness values). The prior variance where a half
    leaves the texel unestimated. One difference is a one-sample estimate, so it is averaged over
    the roughness_window square (when that is > 1). Since it is averaged, only the estimated texels
    of every split_half_stride-th row and column are estimated twice more (when the window is wider
    than the stride): stride 2 took 2.7 s instead of 12.2 s on entropy_scenes.py's sphere, for a
    Spearman rho of 0.513 instead of 0.515 (bunny: 1.6 s, 0.570 instead of 7.2 s, 0.572). A window
    holding none of them (0.01 % of the texels there) gets the prior variance.
    """
    settings = config.uncertainty
    window, stride = settings.roughness_window, settings.split_half_stride
    if stride < 1:
        raise ValueError(f"split_half_stride must be >= 1, got {stride}")
    stride = stride if window > stride else 1
    rows, columns = np.divmod(observations.texel_index, observations.texture_res)
    chosen = np.flatnonzero(np.isfinite(roughness) & (rows % stride == 0) & (columns % stride == 0))
    # Every texel: no copy of the samples (0.74 GB at T = 512, 64 views).
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
    """(N,) Laplace variance 2 s^2 / (n L''(r)) of the angular loss L (a weighted mean over n
    samples) around the estimated roughness r: the profiled loss (base colour and metallic
    re-optimised, the marginal posterior's) when the estimate carries the global search's
    `MaterialEstimate.roughness_curvature`, else base colour and metallic held; capped at the prior
    variance (a flat or concave loss says nothing). s^2 = L(r) 3n / (3n - 5) (the residual's
    unbiased noise variance: 3n values, five parameters fitted; the prior where 3n <= 5) +
    (CURVATURE_NOISE_FLOOR)^2 x the weighted mean square of the observed radiance. L'' is the
    second divided difference through r and two probes CURVATURE_STEP apart, on the side of r that
    stays within [0, 1].
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
    # In float32 and without an (N, V, 3) temporary: the float64 version took 1.2 s at T = 512.
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


def cross_spectrum(observed_coeffs: np.ndarray, light_coeffs: np.ndarray) -> np.ndarray:
    """X(l) = sum_m o_lm m_lm per degree: (..., K), (..., K) -> (..., l*+1) float64."""
    lmax = sh.lmax_of(observed_coeffs.shape[-1])
    product = np.multiply(observed_coeffs, light_coeffs, dtype=np.float64)
    return np.add.reduceat(product, np.arange(lmax + 1) ** 2, axis=-1)


def hypothesis_filter(grid: HypothesisGrid, lmax: int, sigma: float) -> np.ndarray:
    """(R, l*+1) calibrated mode's per-degree amplitude filter of each alpha row: the paper's
    exp(-(alpha l)^2) divided by the band-limit blur exp(-(sigma l)^2) the mirrored light went
    through (``brdf.brdf_kernel``).
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
) -> Uncertainty:
    """Uncertainty from power spectra: light_spectrum, observed_spectrum (N, 3, l*+1).

    Calibrated mode compares amplitudes as if the observed and the light's coefficients were
    aligned in every degree (sqrt(S_out S_refl)). n_samples (N,): samples (views with positive
    weight) per texel (calibrated mode: the fitted coefficients' noise variance is noise_level^2 P K / n_samples for K coefficients) and FLAG_FEW_SAMPLES; None: K
    samples assumed, no FLAG_FEW_SAMPLES.

    light_spectrum is the spectrum of the texel's mirrored (band-limited) environment fit,
    observed_spectrum that of its observed radiance; sigma the band-limit width (compensated in
    calibrated mode only, as in the paper's recipe); alpha_bound (N,) the sampling bound alpha'
    per texel (None: no bound); fit_status (N,) ``sh.FIT_*`` (None: all fits OK). Hypothetical
    spectra (capture guidance) can be scored the same way.
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
        # variance. The kernel divides by the light power P (summing (N, 3, 6) in numpy took longer
        # than the kernel's own moments).
        samples_per_coeff = (np.ones(n_texels) if n_samples is None
                             else np.maximum(np.asarray(n_samples, dtype=np.float64), 1.0) / n_degrees**2)
        scale = (samples_per_coeff / (2.0 * config.noise_level**2))[:, None]  # the same for every channel
    # Amplitudes of degrees 1..l* against two parameters (alpha, k): l* - 2 residual degrees of freedom.
    residual_dof = float(max(lmax - 2, 1)) if (not paper and config.residual_noise) else 0.0
    resolution = grid.resolution
    entropy = np.empty(n_texels, dtype=np.float32)
    channel = np.empty(n_texels, dtype=np.int8)
    best_alpha = np.empty(n_texels, dtype=np.float32)
    best_ks = np.empty(n_texels, dtype=np.float32)
    likelihood = np.empty((n_texels if return_likelihood else 0, resolution, resolution), dtype=np.float32)
    _grid_entropy_kernel(
        _kernel_input(light_spectrum), _kernel_input(observed_spectrum),
        np.ascontiguousarray(scale, dtype=np.float64), row_filter, grid.alpha,
        not paper, not paper, not paper, residual_dof, return_likelihood, numba.get_num_threads(),
        entropy, channel, best_alpha, best_ks, likelihood,
    )

    status = np.zeros(n_texels, np.uint8) if fit_status is None else np.asarray(fit_status)
    return _finish(status == sh.FIT_EMPTY, entropy, channel, best_alpha, best_ks,
                   likelihood if return_likelihood else None, n_samples, n_degrees**2, alpha_bound, grid, config)


def _finish(unobserved, entropy, channel, best_alpha, best_ks, likelihood, n_samples, n_coeffs, alpha_bound, grid,
            config: UncertaintyConfig) -> Uncertainty:
    """The Uncertainty of a grid evaluation: texels ``unobserved`` (N,) set to the prior, and the flags
    (FLAG_FEW_SAMPLES below FEW_SAMPLES_FRACTION x n_coeffs samples; none for n_samples or
    alpha_bound None).
    """
    entropy[unobserved] = 1.0
    channel[unobserved] = -1
    best_alpha[unobserved] = np.nan
    best_ks[unobserved] = np.nan
    if likelihood is not None:
        likelihood[unobserved] = _prior(grid, merge_zero=config.mode != "paper")

    flags = np.zeros(len(entropy), dtype=np.uint8)
    flags[unobserved] |= FLAG_UNOBSERVED
    if n_samples is not None:
        few = np.asarray(n_samples) < FEW_SAMPLES_FRACTION * n_coeffs
        flags[few & ~unobserved] |= FLAG_FEW_SAMPLES
    if alpha_bound is not None:
        with np.errstate(invalid="ignore"):  # NaN best_alpha compares False: not below the bound
            below = best_alpha < np.asarray(alpha_bound)
        flags[below & ~unobserved] |= FLAG_BELOW_BOUND
    flags[(entropy > config.ambiguous_entropy) & ~unobserved] |= FLAG_AMBIGUOUS

    return Uncertainty(entropy=entropy, flags=flags, likelihood=likelihood, best_alpha=best_alpha, best_ks=best_ks,
                       channel=channel, mode=config.mode, grid=grid)


def entropy_angular(observations: Observations, config: Config = Config(),
                    return_likelihood: bool = True) -> Uncertainty:
    """The same hypothesis grid scored in the sample domain with the `global` estimator's own model
    (``config.uncertainty.mode`` "angular"), as benchmarks/pathtraced_entropy.py scores it with a
    path tracer. Per texel, channel and hypothesis (alpha_i, k_j), a metal of base colour k_j and roughness sqrt(alpha_i) reflects
    s_v = k_j X_v + Y_v (`estimate.hypothesis_moments`; k = 0: no lobe, s = 0, not a black metal's
    grazing Fresnel); with the best view-independent (diffuse) part d = max(0, mean_w(f - s)) the
    misfit is e = mean_w (f - d - s)^2 (w the sample weights). Noise variance: (noise_level x the
    RMS of the mirrored environment's radiance)^2 + the best misfit x n / (n - 3) (three parameters
    fitted); likelihood exp(-n (e - min e) / (2 variance)) over n samples; the k = 0 column is one
    material; normalised entropy, minimum over RGB. Scaling every image and the environment by
    kappa scales e and the variance by kappa^2: the map does not change. Costs R probes of the
    estimator's search per texel (seconds, not milliseconds); `pipeline.fit` takes them from its
    own search instead (`AngularEntropy`).
    """
    scorer = AngularEntropy(observations, config, return_likelihood)
    for rows in texel_blocks(observations.n_texels, HYPOTHESIS_BLOCK):
        scorer.consume(rows, hypothesis_moments(observations.select(rows), scorer.roughness, scorer.config))
    return scorer.result()


def entropy_from_moments(
    moments: np.ndarray, weight: np.ndarray, mirrored: np.ndarray, n_samples: np.ndarray, *,
    config: UncertaintyConfig = UncertaintyConfig(mode="angular"), return_likelihood: bool = True,
) -> Uncertainty:
    """The angular mode's uncertainty from the R x R hypotheses' moments (N, R, 3, 8) float64
    (`estimate.hypothesis_moments` at roughness i / (R - 1)), with the samples' weights (N, V) and
    mirrored radiance (N, V, 3) (the noise floor's light) and their count n_samples (N,); what
    `entropy_angular` and `AngularEntropy` do block by block. Texels without samples get the prior;
    no flags but FLAG_AMBIGUOUS (the sampling bound and the SH fit are not known here).
    """
    if config.mode != "angular":
        raise ValueError(f"moments are scored in the angular mode, not {config.mode!r}")
    n_texels, resolution = moments.shape[:2]
    if moments.shape[2:] != (3, 8) or weight.shape[0] != n_texels or mirrored.shape[:2] != weight.shape:
        raise ValueError(f"moments (N, R, 3, 8), weight (N, V) and mirrored (N, V, 3) disagree: {moments.shape}, "
                         f"{weight.shape}, {mirrored.shape}")
    grid = hypothesis_grid(resolution)
    entropy = np.empty(n_texels, np.float32)
    channel = np.empty(n_texels, np.int8)
    best_alpha = np.empty(n_texels, np.float32)
    best_ks = np.empty(n_texels, np.float32)
    likelihood = np.empty((n_texels if return_likelihood else 0, resolution, resolution), np.float32)
    _moment_entropy_kernel(np.ascontiguousarray(moments, dtype=np.float64), weight, mirrored, n_samples, grid.alpha,
                           grid.specular, config.noise_level, return_likelihood, entropy, channel, best_alpha,
                           best_ks, likelihood)
    return _finish(np.asarray(n_samples) == 0, entropy, channel, best_alpha, best_ks,
                   likelihood if return_likelihood else None, None, 0, None, grid, config)


class AngularEntropy:
    """`entropy_angular` fed with its hypotheses' moments block by block: by `entropy_angular`, or
    by the `global` estimator's search while it estimates (`estimate.estimate`'s ``hypotheses``,
    `recorder`), whose first scan probes the roughness nodes anyway. With the default grid (the
    estimator's nodes) that costs the search no probe of its own.
    """

    def __init__(self, observations: Observations, config: Config = Config(), return_likelihood: bool = True):
        settings = config.uncertainty
        self.config = config
        self.grid = hypothesis_grid(settings.resolution(config.estimate.roughness_grid))
        self.roughness = np.sqrt(self.grid.alpha)  # (R,)
        self.observations = observations
        n_texels, resolution = observations.n_texels, self.grid.resolution
        self.entropy = np.empty(n_texels, np.float32)
        self.channel = np.empty(n_texels, np.int8)
        self.best_alpha = np.empty(n_texels, np.float32)
        self.best_ks = np.empty(n_texels, np.float32)
        self.likelihood = np.empty((n_texels, resolution, resolution), np.float32) if return_likelihood else None
        self.seconds = 0.0  # spent in `consume`

    @staticmethod
    def recorded_by_search(config: Config) -> bool:
        """Whether the estimator of ``config`` can record this mode's hypotheses as it searches: the
        global estimator.
        """
        return config.uncertainty.mode == "angular" and config.estimate.method == "global"

    def recorder(self) -> HypothesisRecorder:
        return HypothesisRecorder(self.roughness, self.consume)

    def consume(self, rows: slice, moments: np.ndarray) -> None:
        """Score the texels ``rows`` from their `hypothesis_moments` (n, R, 3, 8)."""
        start = time.perf_counter()
        want_likelihood = self.likelihood is not None
        _moment_entropy_kernel(moments, self.observations.weight[rows], self.observations.mirrored[rows],
                               self.observations.n_samples[rows], self.grid.alpha,
                               self.grid.specular, self.config.uncertainty.noise_level, want_likelihood,
                               self.entropy[rows], self.channel[rows], self.best_alpha[rows], self.best_ks[rows],
                               self.likelihood[rows] if want_likelihood else np.empty((0, 0, 0), np.float32))
        self.seconds += time.perf_counter() - start

    def result(self) -> Uncertainty:
        """The Uncertainty, once every texel has been consumed."""
        observations = self.observations
        return _finish(observations.n_samples == 0, self.entropy, self.channel, self.best_alpha, self.best_ks,
                       self.likelihood, observations.n_samples, sh.num_coeffs(observations.lmax),
                       observations.alpha_bound, self.grid, self.config.uncertainty)


def summary(uncertainty: Uncertainty) -> dict:
    """Summary statistics for ``summary.json``: entropy over observed texels, fraction per flag.

    Flag fractions are over all texels; entropy statistics over texels with at least one sample;
    roughness_std statistics (when computed) over the estimated texels.
    """
    observed = (uncertainty.flags & FLAG_UNOBSERVED) == 0
    entropy = uncertainty.entropy[observed].astype(np.float64)
    n_texels = len(uncertainty.entropy)
    spread = {}
    if uncertainty.roughness_std is not None:
        estimated = uncertainty.roughness_std[np.isfinite(uncertainty.roughness_std)].astype(np.float64)
        spread = {"roughness_std_mean": float(estimated.mean()) if len(estimated) else float("nan"),
                  "roughness_std_median": float(np.median(estimated)) if len(estimated) else float("nan")}
    return {
        "mode": uncertainty.mode,
        "grid_res": uncertainty.grid.resolution,
        "texels": n_texels,
        "observed_texels": int(observed.sum()),
        "entropy_mean": float(entropy.mean()) if len(entropy) else float("nan"),
        "entropy_median": float(np.median(entropy)) if len(entropy) else float("nan"),
        "flagged_fraction": {
            name: float(np.count_nonzero(uncertainty.flags & bit)) / max(n_texels, 1)
            for bit, name in FLAG_NAMES.items()
        },
        **spread,
    }


# --------------------------------------------------------------------------------------------
# Helpers and the kernel


def _kernel_input(array: np.ndarray) -> np.ndarray:
    """float32 and float64 pass through without a copy; anything else becomes float64."""
    return np.ascontiguousarray(array if array.dtype in (np.float32, np.float64) else array.astype(np.float64))


def _prior(grid: HypothesisGrid, merge_zero: bool) -> np.ndarray:
    """(R, R) float32 likelihood grid of a texel without information (the prior)."""
    resolution = grid.resolution
    if not merge_zero:
        return np.full((resolution, resolution), 1.0 / resolution**2, dtype=np.float32)
    n_materials = resolution * (resolution - 1) + 1
    prior = np.full((resolution, resolution), 1.0 / n_materials)
    prior[:, 0] /= resolution  # the k = 0 column is one material
    return prior.astype(np.float32)


