"""Per-texel uncertainty of the specular parameters from SH power spectra (METHOD.md §3.8).

Per texel and colour channel, a grid of specular hypotheses psi = (alpha_i, k_j),
alpha_i = (i / (R-1))^2 (roughness i / (R-1), uniform) and k_j = j / (R-1), is scored against the
power spectrum of the observed radiance S_out(l) for l = 1..l* (l = 0 also carries the diffuse
term and is left out). The likelihood over the grid is turned into a normalised entropy; the map
is the minimum over RGB (the best-informed channel). Two modes:

``paper`` reproduces the published recipe:

    S_psi(l) = k^2 exp(-2 alpha^2 l^2) S_refl(l),  E = S_out(0)^2 mean_l (S_psi(l) - S_out(l))^2,
    P(psi) ∝ exp(-(E - min E) / tau),  H = -sum P log P / log R^2,

including the prototype's factor S_out(0)^2: E then scales with exposure to the 8th power and a
dark texel (S_out(0) ~ 0) gets a flat likelihood, i.e. it is called uncertain.

``calibrated`` (the default) is an honest posterior over the same hypothesis box:

- Residuals are taken on amplitudes sqrt(S(l)), not on powers. Noise on a fitted coefficient is
  additive, so on an amplitude it is roughly constant, whereas on a power it shrinks to second
  order near zero: power residuals make a black texel unable to rule out a specular lobe that
  reflects 14 % of the light. The model is sqrt(S_psi(l)) = k K_sigma(alpha, l) sqrt(S_refl(l)),
  with K_sigma = ``brdf.brdf_kernel(alpha, l*, sigma)``, the band-limit compensated kernel.
- Residuals are measured against the LIGHT's RMS amplitude sqrt(P), P = mean over RGB of
  sum_{l=0..l*} S_refl(l): scaling every image and the environment by kappa scales all amplitudes
  by kappa and leaves the map unchanged, and a dark texel under bright, sharp light is a strong
  observation (k ~ 0), not a missing one.
- The temperature is a noise model: each degree's amplitude has noise std ``noise_level`` x
  sqrt(P), so P(psi) ∝ exp(-sum_l (k a_l - b_l)^2 / (2 s^2)), s^2 = noise_level^2 P. With
  ``residual_noise`` (default) s^2 also includes the misfit of the best hypothesis per residual
  degree of freedom (l* - 2), as a likelihood with unknown noise would: real photographs depart
  from the model (Fresnel, masking, diffuse leakage into l > 0, sparse sampling), and a texel
  that no hypothesis explains must not concentrate on the least bad one. Measured on a Mitsuba
  bunny (64 views): Spearman rho of entropy vs roughness error -0.02 -> 0.18, AURG -0.06 -> 0.12.
- All hypotheses with k = 0 are one material (no specular lobe, roughness undefined). The prior
  is uniform over the R (R-1) + 1 distinct materials and the entropy is taken over them and
  normalised by log(R (R-1) + 1): H = 1 means the data says nothing, H = 0 one material.

Speed: for fixed alpha the misfit is a quadratic in t (t = k^2 in paper mode, t = k in calibrated
mode), e(t) = A (t - t*)^2 + e(t*), whose coefficients are sums over l; the whole grid costs
O(R l* + R^2) per texel and channel. Cells more than CUTOFF above the minimum (in units of the
temperature) are clamped there: their share is below e^-CUTOFF.

Flags (bit field, uint8 per texel) say why a texel should not be trusted; see FLAG_*.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba
import numpy as np

from freqbrdf import brdf, sh
from freqbrdf.config import UncertaintyConfig

if TYPE_CHECKING:
    from freqbrdf.observations import Observations

FLAG_UNOBSERVED = 1  # no sample at all: entropy 1, uniform likelihood, no estimate
FLAG_FEW_SAMPLES = 2  # fewer weighted samples than SH coefficients: the fit leans on its regulariser
FLAG_BELOW_BOUND = 4  # the most likely alpha lies below the sampling bound alpha' (appendix eq. 12)
FLAG_AMBIGUOUS = 8  # entropy above config.ambiguous_entropy: the light does not separate hypotheses
FLAG_NAMES = {
    FLAG_UNOBSERVED: "unobserved",
    FLAG_FEW_SAMPLES: "few_samples",
    FLAG_BELOW_BOUND: "below_bound",
    FLAG_AMBIGUOUS: "ambiguous",
}

# Cells whose misfit exceeds the minimum by more than CUTOFF temperatures are weighted as if at
# CUTOFF: e^-30 ~ 1e-13 is far below the float32 resolution of the likelihood, and the entropy
# moves by less than R^2 CUTOFF e^-CUTOFF / log R^2 < 1e-8.
CUTOFF = 30.0
_BLOCK = 512  # texels per parallel work item


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

    def to_texture(self, observations: Observations, quantity: str = "entropy", fill: float = 0.0) -> np.ndarray:
        """Scatter one per-texel field (e.g. "entropy", "flags", "best_alpha") into a (T, T, ...) texture."""
        values = getattr(self, quantity)
        if values is None:
            raise ValueError(f"{quantity} was not computed")
        return observations.to_texture(values, fill=fill)


# --------------------------------------------------------------------------------------------
# Entry points


def entropy_map(
    observations: Observations, config: UncertaintyConfig = UncertaintyConfig(), return_likelihood: bool = True
) -> Uncertainty:
    """The uncertainty map of a capture's observations (see the module docstring)."""
    return entropy_from_spectra(
        observations.mirrored_spectrum,
        observations.observed_spectrum,
        sigma=observations.sigma,
        alpha_bound=observations.alpha_bound,
        fit_status=observations.fit_status,
        config=config,
        return_likelihood=return_likelihood,
    )


def entropy_from_spectra(
    light_spectrum: np.ndarray,
    observed_spectrum: np.ndarray,
    *,
    sigma: float = 0.0,
    alpha_bound: np.ndarray | None = None,
    fit_status: np.ndarray | None = None,
    config: UncertaintyConfig = UncertaintyConfig(),
    return_likelihood: bool = True,
) -> Uncertainty:
    """Uncertainty from power spectra: light_spectrum, observed_spectrum (N, 3, l*+1).

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
        raise ValueError(f"unknown uncertainty mode {config.mode!r}")
    n_texels, _, n_degrees = light_spectrum.shape
    lmax = n_degrees - 1
    grid = hypothesis_grid(config.grid_res)
    paper = config.mode == "paper"

    if paper:
        # Power residuals, uncompensated kernel, the prototype's S_out(0)^2 weight and mean over l.
        row_filter = np.square(brdf.brdf_kernel(grid.alpha, lmax))
        steps = np.square(grid.specular)
        scale = np.square(observed_spectrum[..., 0].astype(np.float64)) / (lmax * config.temperature)
    else:
        # Amplitude residuals against the light's RMS amplitude (module docstring).
        row_filter = brdf.brdf_kernel(grid.alpha, lmax, sigma)
        steps = grid.specular
        light_power = light_spectrum.astype(np.float64).sum(axis=2).mean(axis=1)  # (N,)
        with np.errstate(divide="ignore"):
            inverse_power = np.where(light_power > 0, 1.0 / light_power, 0.0)  # no light: no information
        scale = np.repeat((inverse_power / (2.0 * config.noise_level**2))[:, None], 3, axis=1)

    # Amplitudes of degrees 1..l* against two parameters (alpha, k): l* - 2 residual degrees of freedom.
    residual_dof = float(max(lmax - 2, 1)) if (not paper and config.residual_noise) else 0.0
    resolution = grid.resolution
    entropy = np.empty(n_texels, dtype=np.float32)
    channel = np.empty(n_texels, dtype=np.int8)
    best_row = np.empty(n_texels, dtype=np.int32)
    best_col = np.empty(n_texels, dtype=np.int32)
    likelihood = np.empty((n_texels if return_likelihood else 0, resolution, resolution), dtype=np.float32)
    _grid_entropy_kernel(
        _kernel_input(light_spectrum), _kernel_input(observed_spectrum),
        np.ascontiguousarray(scale, dtype=np.float64), row_filter, steps,
        not paper, not paper, residual_dof, return_likelihood,
        entropy, channel, best_row, best_col, likelihood,
    )

    best_alpha = grid.alpha[best_row].astype(np.float32)
    best_ks = grid.specular[best_col].astype(np.float32)
    best_alpha[best_col == 0] = np.nan  # no specular lobe: roughness undefined

    status = np.zeros(n_texels, np.uint8) if fit_status is None else np.asarray(fit_status)
    unobserved = status == sh.FIT_EMPTY
    entropy[unobserved] = 1.0
    channel[unobserved] = -1
    best_alpha[unobserved] = np.nan
    best_ks[unobserved] = np.nan
    if return_likelihood:
        likelihood[unobserved] = _prior(grid, merge_zero=not paper)

    flags = np.zeros(n_texels, dtype=np.uint8)
    flags[unobserved] |= FLAG_UNOBSERVED
    flags[status == sh.FIT_UNDERDETERMINED] |= FLAG_FEW_SAMPLES
    if alpha_bound is not None:
        with np.errstate(invalid="ignore"):  # NaN best_alpha compares False: not below the bound
            below = best_alpha < np.asarray(alpha_bound)
        flags[below & ~unobserved] |= FLAG_BELOW_BOUND
    flags[(entropy > config.ambiguous_entropy) & ~unobserved] |= FLAG_AMBIGUOUS

    return Uncertainty(
        entropy=entropy,
        flags=flags,
        likelihood=likelihood if return_likelihood else None,
        best_alpha=best_alpha,
        best_ks=best_ks,
        channel=channel,
        mode=config.mode,
        grid=grid,
    )


def summary(uncertainty: Uncertainty) -> dict:
    """Summary statistics for ``summary.json``: entropy over observed texels, fraction per flag.

    Flag fractions are over all texels; entropy statistics over texels with at least one sample.
    """
    observed = (uncertainty.flags & FLAG_UNOBSERVED) == 0
    entropy = uncertainty.entropy[observed].astype(np.float64)
    n_texels = len(uncertainty.entropy)
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


@numba.njit(inline="always", fastmath={"contract"})
def _exp_neg(distance):
    """exp(-distance) for 0 <= distance <= CUTOFF, relative error < 1e-9, without a libm call so
    that the loops over cells vectorise: exp(-d) = exp(-d / 128)^128, the inner exp by its
    degree-8 Taylor polynomial on [-0.24, 0], then seven squarings."""
    r = distance * (-1.0 / 128.0)
    p = 1.0 + r * (1.0 + r * (1.0 / 2 + r * (1.0 / 6 + r * (1.0 / 24 + r * (1.0 / 120 + r * (
        1.0 / 720 + r * (1.0 / 5040 + r * (1.0 / 40320))))))))
    p = p * p
    p = p * p
    p = p * p
    p = p * p
    p = p * p
    p = p * p
    return p * p


@numba.njit(inline="always")
def _cell_misfit(quad, vertex, at_vertex, dc_excess, steps, j):
    """Misfit of cell (i, j) from its row's quadratic: A (t_j - t*)^2 + e(t*) + DC excess."""
    offset = steps[j] - vertex
    return quad * offset * offset + at_vertex + dc_excess[j]


@numba.njit(parallel=True, cache=True, fastmath={"contract", "reassoc", "nsz"})
def _grid_entropy_kernel(
    light, observed, scale, row_filter, steps, amplitude, merge_zero, residual_dof, want_likelihood,
    entropy, channel, best_row, best_col, likelihood,
):
    """Fused grid misfit, likelihood and entropy per texel; the minimum-entropy channel wins.

    light, observed (N, 3, l*+1) power spectra; scale (N, 3) turns a misfit difference into
    temperatures; row_filter (R, l*+1) the per-degree factor of alpha_i (kernel^2 for powers,
    kernel for amplitudes); steps (R,) the grid values t_j (k^2 or k), ascending, t_0 = 0.
    amplitude: compare sqrt(S) and bound the specular DC by the observed one; merge_zero: the
    k = 0 column is one hypothesis; residual_dof > 0: the noise variance 1 / (2 scale) grows by the
    best cell's misfit / residual_dof (0: off). Outputs per texel: entropy, channel, arg-max cell (best_row,
    best_col) and, if wanted, the (R, R) likelihood of the chosen channel.

    No (R, R) misfit is stored: each cell's misfit is rebuilt from its row's quadratic in three
    FMAs. Per row the misfit is convex in t, so its grid minimum is found by walking downhill
    from the vertex, and exps are taken only where d < CUTOFF: an interval of t around the vertex
    (the DC excess only adds), found by bisection on the sorted steps.
    """
    n_texels, n_channels, n_degrees = light.shape
    resolution = steps.shape[0]
    n_zero = 1 if merge_zero else resolution  # how many hypotheses the k = 0 column counts as
    log_hypotheses = math.log(resolution * (resolution - 1) + n_zero)
    stored = resolution if want_likelihood else 1  # likelihood grids are kept only when returned
    n_blocks = (n_texels + _BLOCK - 1) // _BLOCK
    for block in numba.prange(n_blocks):
        weight = np.zeros((n_channels, stored, stored))
        light_row = np.empty(n_degrees)
        observed_row = np.empty(n_degrees)
        row_scaled = np.empty(n_degrees)
        quad = np.empty(resolution)
        vertex = np.empty(resolution)
        at_vertex = np.empty(resolution)
        dc_excess = np.zeros(resolution)
        for texel in range(block * _BLOCK, min(n_texels, (block + 1) * _BLOCK)):
            lowest_entropy = 2.0
            for c in range(n_channels):
                constant = 0.0  # the misfit at k = 0: sum_{l >= 1} b_l^2
                for l in range(n_degrees):
                    light_value = max(light[texel, c, l], 0.0)
                    observed_value = max(observed[texel, c, l], 0.0)
                    if amplitude:
                        light_value = math.sqrt(light_value)
                        observed_value = math.sqrt(observed_value)
                    light_row[l] = light_value
                    observed_row[l] = observed_value
                    if l > 0:
                        constant += observed_value * observed_value
                if amplitude:
                    # l = 0 holds specular plus a non-negative diffuse part: the specular DC
                    # amplitude t K_0 sqrt(S_refl(0)) (K_0 = 1) may not exceed the observed one.
                    for j in range(resolution):
                        excess = max(steps[j] * light_row[0] - observed_row[0], 0.0)
                        dc_excess[j] = excess * excess
                # Per alpha row the misfit is a quadratic in t: A (t - t*)^2 + e(t*), with
                # A = sum_l a_l^2, t* = sum_l a_l b_l / A, a_l = filter(alpha_i, l) x light_l.
                lowest = constant
                lowest_i, lowest_j = 0, 0
                for i in range(resolution):
                    row_quad = 0.0
                    cross = 0.0
                    for l in range(1, n_degrees):
                        row_scaled[l] = row_filter[i, l] * light_row[l]
                        row_quad += row_scaled[l] * row_scaled[l]
                        cross += row_scaled[l] * observed_row[l]
                    row_vertex = 0.0
                    row_at_vertex = constant
                    if row_quad > 0.0:
                        # e(t*) summed directly: both terms non-negative, no cancellation.
                        row_vertex = cross / row_quad
                        row_at_vertex = 0.0
                        for l in range(1, n_degrees):
                            residual = row_vertex * row_scaled[l] - observed_row[l]
                            row_at_vertex += residual * residual
                    quad[i] = row_quad
                    vertex[i] = row_vertex
                    at_vertex[i] = row_at_vertex
                    # Grid minimum of the row over j >= 1: downhill from the step nearest the vertex.
                    j = min(max(np.searchsorted(steps, row_vertex), 1), resolution - 1)
                    here = _cell_misfit(row_quad, row_vertex, row_at_vertex, dc_excess, steps, j)
                    while j > 1:
                        left = _cell_misfit(row_quad, row_vertex, row_at_vertex, dc_excess, steps, j - 1)
                        if left > here:
                            break
                        j, here = j - 1, left
                    while j < resolution - 1:
                        right = _cell_misfit(row_quad, row_vertex, row_at_vertex, dc_excess, steps, j + 1)
                        if right >= here:
                            break
                        j, here = j + 1, right
                    if here < lowest:  # the k = 0 column and earlier rows win ties
                        lowest, lowest_i, lowest_j = here, i, j
                # Likelihood w = exp(-d), d = (e - min e) x scale, and H = log Z + sum w d / Z.
                to_temperature = scale[texel, c]
                if residual_dof > 0.0 and to_temperature > 0.0:
                    # Noise variance = the stated floor + the best hypothesis's residual per degree
                    # of freedom: a texel no hypothesis explains is not sure of any of them.
                    to_temperature = 1.0 / (1.0 / to_temperature + 2.0 * lowest / residual_dof)
                zero_distance = min((constant - lowest) * to_temperature, CUTOFF)
                zero_weight = _exp_neg(zero_distance)
                total = n_zero * zero_weight
                weighted_distance = n_zero * zero_weight * zero_distance
                if want_likelihood:
                    weight[c] = 0.0
                    weight[c, :, 0] = zero_weight * n_zero / resolution
                for i in range(resolution):
                    first, stop = 1, resolution
                    if to_temperature > 0.0:
                        slack = CUTOFF / to_temperature - (at_vertex[i] - lowest)  # in misfit units
                        if slack < 0.0:
                            continue
                        if quad[i] > 0.0:
                            half_width = math.sqrt(slack / quad[i])
                            first = max(np.searchsorted(steps, vertex[i] - half_width), 1)
                            stop = np.searchsorted(steps, vertex[i] + half_width, side="right")
                    row_quad, row_vertex, row_at_vertex = quad[i], vertex[i], at_vertex[i]
                    for j in range(first, stop):
                        misfit = _cell_misfit(row_quad, row_vertex, row_at_vertex, dc_excess, steps, j)
                        # >= 0 up to rounding, which a huge scale (paper mode, bright texel) can amplify
                        distance = min(max((misfit - lowest) * to_temperature, 0.0), CUTOFF)
                        w = _exp_neg(distance)
                        total += w
                        weighted_distance += w * distance
                        if want_likelihood:
                            weight[c, i, j] = w
                value = (math.log(total) + weighted_distance / total) / log_hypotheses
                value = min(max(value, 0.0), 1.0)
                if value < lowest_entropy:
                    lowest_entropy = value
                    entropy[texel] = value
                    channel[texel] = c
                    best_row[texel] = lowest_i
                    best_col[texel] = lowest_j
                    if want_likelihood:
                        inverse_total = 1.0 / total
                        for i in range(resolution):
                            for j in range(resolution):
                                likelihood[texel, i, j] = weight[c, i, j] * inverse_total
