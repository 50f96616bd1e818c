"""The numba kernels of the uncertainty stage (docs/method.md#entropy).

Two ways of scoring the hypothesis grid (alpha_i, k_j) per texel and channel, each fused into one
pass that scores the cells, turns them into a likelihood and takes its normalised entropy, the
channel with the lowest entropy winning:

- `grid_entropy_kernel` scores SH power spectra (the spectral modes of
  `freqbrdf.uncertainty.spectral`), SIMD across ``_LANES`` texels at a time;
- `moment_entropy_kernel` scores the hypotheses' moments of the samples (the angular mode of
  `freqbrdf.uncertainty.angular`), texel by texel.

Their inputs and outputs are named records (`SpectraInputs`, `SpectralOptions`, `MomentInputs`,
`EntropyOutputs`). numba compiles a kernel once per combination of its arguments' types, so the
builders in those modules give each field one type (the spectra: float32 or float64, as given).
Shapes: N texels, V views, L degrees, R the grid's side. exp and log are computed in float
arithmetic only (`_exp_neg`, `_log`), so that the loops over lanes vectorise. The callers
validate; nothing else should call these kernels.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from freqbrdf.estimate import scattering_stride

# Cells whose misfit exceeds the minimum by more than CUTOFF temperatures are weighted as if at
# CUTOFF: their share e^-CUTOFF of the likelihood is far below its float32 resolution.
CUTOFF = 30.0
_MOMENT_CHUNK = 64  # texels per parallel work item of the angular entropy: amortises the scratch arrays
_LANES = 64  # texels side by side in the spectral kernel's SIMD loops (docs/results.md#the-entropy)


class SpectraInputs(NamedTuple):
    """The texels' power spectra and how the spectral grid weighs their misfits."""

    light: np.ndarray  # (N, 3, L) float32 or float64 S_refl(l), the mirrored light's power spectrum
    observed: np.ndarray  # (N, 3, L) the dtype of light, S_out(l), the observed radiance's
    scale: np.ndarray  # (N, 3) or (N, 1) float64: a misfit difference times scale is in temperatures
    row_filter: np.ndarray  # (R, L) float64 the per-degree factor of each alpha row
    alphas: np.ndarray  # (R,) float64 the rows' alpha


class SpectralOptions(NamedTuple):
    """How the spectral kernel scores (the calibrated mode: all True; the paper's: all False)."""

    amplitude: bool  # compare amplitudes sqrt(S), t_j = k_j, bound the specular DC; else powers, t_j = k_j^2
    per_light_power: bool  # divide scale by the texel's light power P
    merge_zero: bool  # the k = 0 column is one hypothesis
    residual_dof: float  # > 0: the noise variance grows by the best misfit / residual_dof; 0: off
    want_likelihood: bool  # write EntropyOutputs.likelihood


class MomentInputs(NamedTuple):
    """The angular mode's hypotheses: their moments and the samples' weights and light."""

    moments: np.ndarray  # (N, R, 3, 8) float64 `estimate.hypothesis_moments`
    weight: np.ndarray  # (N, V) float32 sample weights, 0 where unsampled
    mirrored: np.ndarray  # (N, V, 3) float32 the environment in the mirror direction (the noise floor's light)
    n_samples: np.ndarray  # (N,) integer samples per texel
    alphas: np.ndarray  # (R,) float64 the rows' alpha
    specular: np.ndarray  # (R,) float64 the columns' k
    noise_level: float  # a sample's noise std relative to the light's RMS radiance
    want_likelihood: bool  # write EntropyOutputs.likelihood


class EntropyOutputs(NamedTuple):
    """What both kernels write per texel (N of them)."""

    entropy: np.ndarray  # (N,) float32 normalised entropy in [0, 1], the minimum over RGB
    channel: np.ndarray  # (N,) int8 the channel of that minimum
    best_alpha: np.ndarray  # (N,) float32 the arg-max cell's alpha, NaN where its k = 0
    best_ks: np.ndarray  # (N,) float32 the arg-max cell's k
    likelihood: np.ndarray  # (N, R, R) float32 the chosen channel's likelihood; (0, R, R) when not wanted


_EXP_CENTRE = math.exp(-CUTOFF / 64)  # e^-y0 at the centre y0 = CUTOFF / 64 of the reduced argument


@numba.njit(inline="always", fastmath={"contract", "reassoc", "nsz", "arcp"})
def _exp_neg(distance):
    """Return exp(-distance) in float32 for 0 <= distance <= CUTOFF, relative error < 1e-5.

    In float arithmetic only (no libm call, no integer exponent tricks, which numba widens to 64
    bits), so that the loops over lanes vectorise. exp(-d) = (e^-y)^32, y = d / 32 in [0, 2 y0]:
    e^-y = e^-y0 e^-(y - y0) by the degree-7 Taylor polynomial of e^-(y - y0) (|y - y0| <= 0.47,
    truncation 5e-8), then five squarings, each of which doubles the relative error.
    """
    y = distance * np.float32(1 / 32) - np.float32(CUTOFF / 64)
    p = np.float32(1.0) - y * (np.float32(1.0) - y * (np.float32(1 / 2) - y * (np.float32(1 / 6) - y * (
        np.float32(1 / 24) - y * (np.float32(1 / 120) - y * (np.float32(1 / 720) - y * np.float32(1 / 5040)))))))
    p = p * np.float32(_EXP_CENTRE)
    p = p * p
    p = p * p
    p = p * p
    p = p * p
    return p * p


_LN2 = math.log(2.0)
_SQRT2 = math.sqrt(2.0)


@numba.njit(inline="always", fastmath={"contract", "reassoc", "nsz", "arcp"})
def _log(x):
    """Return ln x for 0.7 <= x < 2^32, error < 1e-12.

    The partition function Z lies in [1, number of hypotheses]. In float arithmetic only (selects,
    one division), so that the loop over lanes vectorises. x = 2^e m by halving steps (16, 8, 4,
    2, 1 and one to m <= sqrt 2), then ln m = 2 atanh z, z = (m - 1) / (m + 1), |z| <= 0.172: the
    series to z^13 leaves < 1.3e-12.
    """
    exponent = 0.0
    big = x >= 65536.0
    x = x * (1.0 / 65536.0) if big else x
    exponent += 16.0 if big else 0.0
    big = x >= 256.0
    x = x * (1.0 / 256.0) if big else x
    exponent += 8.0 if big else 0.0
    big = x >= 16.0
    x = x * (1.0 / 16.0) if big else x
    exponent += 4.0 if big else 0.0
    big = x >= 4.0
    x = x * 0.25 if big else x
    exponent += 2.0 if big else 0.0
    big = x >= 2.0
    x = x * 0.5 if big else x
    exponent += 1.0 if big else 0.0
    big = x > _SQRT2
    x = x * 0.5 if big else x
    exponent += 1.0 if big else 0.0
    z = (x - 1.0) / (x + 1.0)
    z2 = z * z
    series = 1.0 + z2 * (1 / 3 + z2 * (1 / 5 + z2 * (1 / 7 + z2 * (1 / 9 + z2 * (1 / 11 + z2 * (1 / 13))))))
    return 2.0 * z * series + exponent * _LN2


@numba.njit(inline="always")
def _larger(a, b):
    """Return max(a, b) as a compare and select (numba's builtin max is a call: no vectorising)."""
    return a if a > b else b


@numba.njit(inline="always")
def _smaller(a, b):
    """Return min(a, b) as a compare and select (see `_larger`)."""
    return a if a < b else b


@numba.njit(parallel=True, cache=True)
def moment_entropy_kernel(inputs, outputs):
    """Score the angular mode's grid per texel from its hypotheses' moments.

    Per texel, channel and cell, the misfit of the samples with the best constant diffuse part
    (`freqbrdf.uncertainty.angular.entropy_angular` states the model), the likelihood and its
    normalised entropy; texels without moments (too few samples) get the prior.

    Parameters
    ----------
    inputs : MomentInputs
        The moments (N, R, 3, 8), the samples' weights and mirrored light, the grid.
    outputs : EntropyOutputs
        Written per texel (N of them).
    """
    n_chunks = (inputs.moments.shape[0] + _MOMENT_CHUNK - 1) // _MOMENT_CHUNK
    stride = scattering_stride(n_chunks)  # texels without moments cost little: spread them over the threads
    for item in numba.prange(n_chunks):
        _moment_entropy_chunk((np.int64(item) * stride) % n_chunks, inputs, outputs)


@numba.njit(cache=True, fastmath={"contract", "reassoc", "nsz", "arcp"})
def _moment_entropy_chunk(chunk, inputs, outputs):
    """Do `moment_entropy_kernel`'s work for the texels of one chunk, with one set of scratch arrays.

    The cells' weights w = exp(-d) (d the misfit above the least in temperatures, at most CUTOFF)
    in float32 with `_exp_neg`; the entropy without a log per cell: for p = w / Z,
    -sum p log p = (sum w d) / Z + log Z over the k > 0 cells, and the k = 0 column's merged mass
    P0 adds -P0 log P0.
    """
    moments = inputs.moments
    resolution = moments.shape[1]
    misfit = np.empty((resolution, resolution))
    cell_weight = np.empty((3, resolution, resolution), np.float32)
    norm = np.empty(3)
    light_mean_square = np.empty(3)
    for t in range(chunk * _MOMENT_CHUNK, min((chunk + 1) * _MOMENT_CHUNK, moments.shape[0])):
        _moment_entropy_texel(t, inputs, outputs, misfit, cell_weight, norm, light_mean_square)


@numba.njit(cache=True, fastmath={"contract", "reassoc", "nsz", "arcp"})
def _moment_entropy_texel(t, inputs, outputs, misfit, cell_weight, norm, light_mean_square):
    """Do `_moment_entropy_chunk`'s work for texel t, with its scratch arrays."""
    moments, weight, mirrored, n_samples, alphas, specular, noise_level, want_likelihood = inputs
    entropy, channel, best_alpha, best_ks, likelihood = outputs
    resolution = moments.shape[1]
    n_materials = resolution * (resolution - 1) + 1
    log_hypotheses = math.log(n_materials)
    light_mean_square[:] = 0.0
    weight_sum = 0.0
    for v in range(weight.shape[1]):
        w = np.float64(weight[t, v])
        if w > 0.0:
            weight_sum += w
            for c in range(3):
                light_mean_square[c] += w * np.float64(mirrored[t, v, c]) ** 2
    best_entropy = 2.0
    best_channel, best_row, best_column = 0, 0, 0
    for c in range(3):
        total = moments[t, 0, c, 0]
        if not total > 0.0:  # no moments: the prior
            norm[c] = 1.0
            for i in range(resolution):
                for j in range(resolution):
                    cell_weight[c, i, j] = np.float32(1.0 / n_materials) / (resolution if j == 0 else 1)
            value, row, column = 1.0, 0, 0
        else:
            lowest = np.inf
            inverse_total = 1.0 / total
            for i in range(resolution):
                m = moments[t, i, c]
                mean_u, mean_x, mean_f = m[1] * inverse_total, m[2] * inverse_total, m[6] * inverse_total
                square_u, cross_ux, square_x = m[3] * inverse_total, m[4] * inverse_total, m[5] * inverse_total
                diffuse = _larger(mean_f, 0.0)  # k = 0: no specular lobe at all
                misfit[i, 0] = _larger(m[7] * inverse_total - 2.0 * diffuse * mean_f + diffuse * diffuse, 0.0)
                for j in range(1, resolution):
                    k = specular[j]
                    residual = mean_u - k * mean_x  # the diffuse part's least-squares value, unclamped
                    diffuse = _larger(residual, 0.0)
                    e = square_u - 2.0 * k * cross_ux + k * k * square_x - 2.0 * diffuse * residual + diffuse * diffuse
                    misfit[i, j] = _larger(e, 0.0)
                for j in range(resolution):
                    lowest = _smaller(lowest, misfit[i, j])
            n = max(n_samples[t], 1)
            mean_square = light_mean_square[c] / weight_sum if weight_sum > 0.0 else 0.0
            variance = max(noise_level * noise_level * mean_square + lowest * n / max(n - 3, 1), 1e-30)
            to_temperature = n / (2.0 * variance)
            zero = 0.0  # the k = 0 column's weight: one material, so each of its cells counts 1 / R
            weighted_distance = 0.0  # sum w d over the k > 0 cells
            partition = 0.0  # Z over the k > 0 cells, then with the k = 0 column
            for i in range(resolution):
                w = _exp_neg(np.float32(_smaller((misfit[i, 0] - lowest) * to_temperature, CUTOFF)))
                cell_weight[c, i, 0] = w / np.float32(resolution)
                zero += cell_weight[c, i, 0]
                for j in range(1, resolution):
                    distance = np.float32(_smaller((misfit[i, j] - lowest) * to_temperature, CUTOFF))
                    w = _exp_neg(distance)
                    cell_weight[c, i, j] = w
                    partition += w
                    weighted_distance += w * distance
            partition += zero
            row, column, largest = 0, 0, np.float32(-1.0)
            for i in range(resolution):
                for j in range(1, resolution):
                    if cell_weight[c, i, j] > largest:
                        row, column, largest = i, j, cell_weight[c, i, j]
            norm[c] = partition
            zero_mass = zero / partition
            value = (weighted_distance + (partition - zero) * math.log(partition)) / partition
            if zero_mass > 0.0:
                value -= zero_mass * math.log(zero_mass)
            if zero >= largest:
                row, column = 0, 0
            value = min(max(value / log_hypotheses, 0.0), 1.0)
        if value < best_entropy:
            best_entropy, best_channel, best_row, best_column = value, c, row, column
    entropy[t] = best_entropy
    channel[t] = best_channel
    best_alpha[t] = alphas[best_row] if best_column > 0 else np.nan
    best_ks[t] = specular[best_column]
    if want_likelihood:
        scale = 1.0 / norm[best_channel]
        for i in range(resolution):
            for j in range(resolution):
                likelihood[t, i, j] = cell_weight[best_channel, i, j] * scale


@numba.njit(parallel=True, cache=True)
def grid_entropy_kernel(spectra, options, n_threads, outputs):
    """Score the spectral grid per texel: fused misfit, likelihood and entropy.

    ``spectra.scale`` turns a misfit difference into temperatures, divided by the texel's light
    power P = mean over channels of sum_l S_refl(l) when ``options.per_light_power`` (no light:
    temperature 0, no information). ``row_filter`` is the kernel for amplitudes, the kernel
    squared for powers. With ``options.residual_dof`` > 0 the noise variance 1 / (2 scale) grows
    by the best cell's misfit / residual_dof.

    SIMD runs across _LANES texels at a time (structure of arrays, [..., lane]), so the loops over
    lanes are branch-free and vectorise whatever R is. Each texel's inputs are read once, in
    memory order, into the block's lanes. Per texel and channel:

    1. moments (float64): a_l^2 and a_l b_l for l >= 1 and C = sum_l b_l^2 (the misfit at k = 0),
       a_l, b_l the light's and the observation's amplitudes (or powers);
    2. per alpha row (float64): A = sum_l f_il^2 a_l^2, X = sum_l f_il a_l b_l; the misfit
       C - 2 X t + A t^2 plus the DC excess _larger(t a_0 - b_0, 0)^2 is convex in t, so the row's
       grid minimum t_b is one of the two grid values around its continuous minimiser, which has a
       closed form (one division);
    3. per cell (float32): the distance in temperatures relative to the row's grid minimum,
       d = D_i + (t_j - t_b)(A (t_j - t_b) + 2 (A t_b - X)) / T + DC excess difference: exact at the
       row minimum, no cancellation elsewhere; exp(-d) by _exp_neg. Rows whose minimum lies beyond
       CUTOFF in every lane are clamped without evaluating their cells.

    H = log Z + sum w d / Z (w = e^-d, Z = sum w), summed per row in float32, over rows in float64;
    log by _log. The cell loop writes the likelihood's weights in place.

    Parameters
    ----------
    spectra : SpectraInputs
        The spectra (N, 3, L), their scale, the rows' filter and alpha.
    options : SpectralOptions
        How to score.
    n_threads : int
        numba's thread count (read by the caller, which keeps the kernel cacheable).
    outputs : EntropyOutputs
        Written per texel (N of them).
    """
    n_blocks = (spectra.light.shape[0] + _LANES - 1) // _LANES
    n_workers = _smaller(n_threads, n_blocks)  # worker w takes blocks w, w + n_workers, ...
    for worker in numba.prange(n_workers):
        # np.int64: the loop index is unsigned in numba's parallel code and signed when typed: one
        # signature, not two (each compiles the whole kernel).
        _grid_entropy_worker(np.int64(worker), n_workers, spectra, options, outputs)


@numba.njit(cache=True, error_model="numpy", fastmath={"contract", "reassoc", "nsz", "arcp"})
def _grid_entropy_worker(worker, n_workers, spectra, options, outputs):
    """Do `grid_entropy_kernel`'s work for the blocks of texels worker, worker + n_workers, ...

    A function of its own, so that numba's parallel passes see a small loop (on the whole body
    they take most of the kernel's compile time).
    """
    scratch = _grid_entropy_scratch_inline(spectra, options)
    n_blocks = (spectra.light.shape[0] + _LANES - 1) // _LANES
    for block in range(worker, n_blocks, n_workers):
        _grid_entropy_block_inline(block, spectra, options, outputs, scratch)


class GridScratch(NamedTuple):
    """One worker's scratch of the spectral kernel (`grid_entropy_scratch`): [..., lane] arrays."""

    specular: np.ndarray
    steps32: np.ndarray
    filter_sq: np.ndarray
    light_lanes: np.ndarray
    observed_lanes: np.ndarray
    light_sq: np.ndarray
    light_observed: np.ndarray
    constant: np.ndarray
    light_dc: np.ndarray
    observed_dc: np.ndarray
    to_temperature: np.ndarray
    quad: np.ndarray
    linear: np.ndarray
    lowest: np.ndarray
    sums: np.ndarray
    rows: np.ndarray
    cell: np.ndarray
    cell_sums: np.ndarray
    weights: np.ndarray
    channel_sums: np.ndarray
    choice: np.ndarray
    light_power: np.ndarray


@numba.njit(cache=True, error_model="numpy", fastmath={"contract", "reassoc", "nsz", "arcp"})
def grid_entropy_scratch(spectra, options):
    """Allocate one worker's `GridScratch` for `grid_entropy_block`, with the grid's steps and filter."""
    light, row_filter = spectra.light, spectra.row_filter
    amplitude, want_likelihood = options.amplitude, options.want_likelihood
    n_channels, n_degrees = light.shape[1], light.shape[2]
    resolution = row_filter.shape[0]
    last = resolution - 1
    specular = np.arange(resolution) / last  # k_j
    steps = specular if amplitude else specular * specular  # t_j
    steps32 = steps.astype(np.float32)
    filter_sq = row_filter * row_filter
    stored = resolution if want_likelihood else 1  # likelihood grids are kept only when returned
    # Per-lane scratch, one array per quantity so that each loop over lanes reads and writes
    # few arrays (LLVM's run-time overlap checks stay within its limits and the loops vectorise).
    # The block's inputs, read once per texel in memory order: [channel, degree, lane].
    light_lanes = np.zeros((n_channels, n_degrees, _LANES))
    observed_lanes = np.zeros((n_channels, n_degrees, _LANES))
    light_sq = np.empty((n_degrees, _LANES))  # a_l^2
    light_observed = np.empty((n_degrees, _LANES))  # a_l b_l
    constant = np.empty(_LANES)  # C = sum_{l >= 1} b_l^2
    light_dc = np.empty(_LANES)  # a_0
    observed_dc = np.empty(_LANES)  # b_0
    to_temperature = np.empty(_LANES)
    quad = np.empty(_LANES)  # A of the current row
    linear = np.empty(_LANES)  # X of the current row
    lowest = np.empty((3, _LANES))  # the least misfit, its row and column
    sums = np.empty((2, _LANES))  # Z, sum w d
    rows = np.empty((resolution, 5, _LANES))  # per row: A, X, t_b, misfit at t_b, the specular DC at t = 1
    # t_b, A / T, 2 (A t_b - X) / T, D_i - DC excess at t_b, and the row's specular DC and the
    # observed DC, both times sqrt(1 / T) (0 outside amplitude mode: no DC bound)
    cell = np.zeros((6, _LANES), np.float32)
    cell_sums = np.empty((2, _LANES), np.float32)  # sum w, sum w d over the row's cells
    # The cells' weights [channel, row, column, lane], written in place by the cell loop; without
    # the likelihood one row per channel is kept as scratch.
    weights = np.empty((n_channels, stored, resolution, _LANES), np.float32)
    channel_sums = np.empty((n_channels, 2, _LANES))  # Z and the k = 0 weight per channel
    choice = np.empty((4, _LANES))  # lowest entropy, its channel, arg-max row and column
    light_power = np.ones(_LANES)
    return GridScratch(
        specular, steps32, filter_sq, light_lanes, observed_lanes, light_sq, light_observed, constant, light_dc,
        observed_dc, to_temperature, quad, linear, lowest, sums, rows, cell, cell_sums, weights, channel_sums,
        choice, light_power,
    )


@numba.njit(cache=True, error_model="numpy", fastmath={"contract", "reassoc", "nsz", "arcp"})
def grid_entropy_block(block, spectra, options, outputs, scratch):
    """Do `grid_entropy_kernel`'s work for texels block * _LANES, ... (one block of lanes), with a `GridScratch`."""
    light, observed, scale, row_filter, alphas = spectra
    amplitude, per_light_power, merge_zero, residual_dof, want_likelihood = options
    entropy, channel, best_alpha, best_ks, likelihood = outputs
    n_texels, n_channels, n_degrees = light.shape
    n_scales = scale.shape[1]
    resolution = row_filter.shape[0]
    last = resolution - 1
    inverse_last = 1.0 / last
    n_zero = 1 if merge_zero else resolution  # how many hypotheses the k = 0 column counts as
    log_hypotheses = math.log(resolution * (resolution - 1) + n_zero)
    clamped_weight = _exp_neg(np.float32(CUTOFF))  # a cell beyond CUTOFF, as the cell loop weighs it
    (
        specular, steps32, filter_sq, light_lanes, observed_lanes, light_sq, light_observed, constant, light_dc,
        observed_dc, to_temperature, quad, linear, lowest, sums, rows, cell, cell_sums, weights, channel_sums,
        choice, light_power,
    ) = scratch
    start = block * _LANES
    n_lanes = _smaller(_LANES, n_texels - start)
    if n_lanes < _LANES:  # padding lanes hold zeros and are computed like the others
        light_lanes[:] = 0.0
        observed_lanes[:] = 0.0
    for k in range(n_lanes):
        for c in range(n_channels):
            for l in range(n_degrees):
                light_lanes[c, l, k] = light[start + k, c, l]
                observed_lanes[c, l, k] = observed[start + k, c, l]
    choice[0] = 2.0
    if per_light_power:
        light_power[:] = 0.0
        for c in range(n_channels):
            for l in range(n_degrees):
                for k in range(_LANES):
                    light_power[k] += light_lanes[c, l, k]
        for k in range(_LANES):
            light_power[k] = light_power[k] / n_channels
    for c in range(n_channels):
        # 1. Moments.
        for k in range(_LANES):
            light_dc[k] = math.sqrt(_larger(light_lanes[c, 0, k], 0.0))
            observed_dc[k] = math.sqrt(_larger(observed_lanes[c, 0, k], 0.0))
            constant[k] = 0.0
        for l in range(1, n_degrees):
            if amplitude:  # a_l^2 = S_refl(l), a_l b_l = sqrt(S_refl(l) S_out(l)), b_l^2 = S_out(l)
                for k in range(_LANES):
                    light_value = _larger(light_lanes[c, l, k], 0.0)
                    observed_value = _larger(observed_lanes[c, l, k], 0.0)
                    light_sq[l, k] = light_value
                    light_observed[l, k] = math.sqrt(light_value * observed_value)
                    constant[k] += observed_value
            else:
                for k in range(_LANES):
                    light_value = _larger(light_lanes[c, l, k], 0.0)
                    observed_value = _larger(observed_lanes[c, l, k], 0.0)
                    light_sq[l, k] = light_value * light_value
                    light_observed[l, k] = light_value * observed_value
                    constant[k] += observed_value * observed_value
        # 2. Rows. The k = 0 column (misfit C in any row) and earlier rows win ties.
        for k in range(_LANES):
            lowest[0, k] = constant[k]
            lowest[1, k] = 0.0
            lowest[2, k] = 0.0
        for i in range(resolution):
            for k in range(_LANES):
                quad[k] = filter_sq[i, 1] * light_sq[1, k]
                linear[k] = row_filter[i, 1] * light_observed[1, k]
            for l in range(2, n_degrees):
                for k in range(_LANES):
                    quad[k] += filter_sq[i, l] * light_sq[l, k]
                    linear[k] += row_filter[i, l] * light_observed[l, k]
            for k in range(_LANES):
                a = quad[k]
                x = linear[k]
                specular_dc = light_dc[k]
                # Continuous minimiser of C - 2 X t + A t^2 + max(t a_0 - b_0, 0)^2: X / A, or
                # (X + a_0 b_0) / (A + a_0^2) where X / A would exceed the DC bound b_0 / a_0.
                numerator = x
                denominator = a
                if amplitude and x * specular_dc > observed_dc[k] * a:
                    numerator += specular_dc * observed_dc[k]
                    denominator += specular_dc * specular_dc
                target = numerator / (denominator if denominator > 0.0 else 1.0)  # no light: 0
                index = target * last if amplitude else math.sqrt(_larger(target, 0.0)) * last
                left = np.float64(_smaller(_larger(math.floor(index), 1.0), last))
                right = _smaller(left + 1.0, last)
                left_t = left * inverse_last
                right_t = right * inverse_last
                if not amplitude:
                    left_t *= left_t
                    right_t *= right_t
                left_misfit = constant[k] + left_t * (a * left_t - 2.0 * x)
                right_misfit = constant[k] + right_t * (a * right_t - 2.0 * x)
                if amplitude:
                    left_misfit += _larger(left_t * specular_dc - observed_dc[k], 0.0) ** 2
                    right_misfit += _larger(right_t * specular_dc - observed_dc[k], 0.0) ** 2
                take_right = right_misfit < left_misfit
                best_misfit = right_misfit if take_right else left_misfit
                rows[i, 0, k] = a
                rows[i, 1, k] = x
                rows[i, 2, k] = right_t if take_right else left_t
                rows[i, 3, k] = best_misfit
                rows[i, 4, k] = specular_dc
                if best_misfit < lowest[0, k]:
                    lowest[0, k] = best_misfit
                    lowest[1, k] = i
                    lowest[2, k] = right if take_right else left
        # 3. Cells. Temperature per lane, the k = 0 column, then row by row.
        for k in range(_LANES):
            temperature = scale[start + k, _smaller(c, n_scales - 1)] if k < n_lanes else 0.0
            temperature = temperature / light_power[k] if light_power[k] > 0.0 else 0.0
            if residual_dof > 0.0 and temperature > 0.0:
                # Noise variance = the stated floor + the best hypothesis's residual per
                # degree of freedom: a texel no hypothesis explains is not sure of any.
                temperature = 1.0 / (1.0 / temperature + 2.0 * _larger(lowest[0, k], 0.0) / residual_dof)
            to_temperature[k] = temperature
            zero_distance = _smaller((constant[k] - lowest[0, k]) * temperature, CUTOFF)
            zero_weight = np.float64(_exp_neg(np.float32(zero_distance)))
            channel_sums[c, 1, k] = zero_weight
            sums[0, k] = n_zero * zero_weight
            sums[1, k] = n_zero * zero_weight * zero_distance
        for i in range(resolution):
            # Lanes whose row minimum D_i lies within CUTOFF, counted as a float sum: a select
            # (min) reduction would not vectorise without assuming no NaNs.
            within = 0.0
            for k in range(_LANES):
                temperature = to_temperature[k]
                offset = (rows[i, 3, k] - lowest[0, k]) * temperature
                within += 1.0 if offset < CUTOFF else 0.0
                best_t = rows[i, 2, k]
                excess = _larger(best_t * rows[i, 4, k] - observed_dc[k], 0.0)
                excess = excess if amplitude else 0.0
                # misfit(t) - misfit(t_b) = (t - t_b) (A (t - t_b) + 2 (A t_b - X)), plus the DC excess
                cell[0, k] = best_t
                cell[1, k] = rows[i, 0, k] * temperature
                cell[2, k] = 2.0 * (rows[i, 0, k] * best_t - rows[i, 1, k]) * temperature
                cell[3, k] = offset - excess * excess * temperature
                if amplitude:
                    root_temperature = math.sqrt(temperature)
                    cell[4, k] = rows[i, 4, k] * root_temperature
                    cell[5, k] = observed_dc[k] * root_temperature
            row_weights = weights[c, i if want_likelihood else 0]
            if within == 0.0:  # every cell of this row is beyond CUTOFF in every lane
                cell_sums[0] = last * clamped_weight
                cell_sums[1] = last * clamped_weight * np.float32(CUTOFF)
                row_weights[:] = clamped_weight
            else:
                cell_sums[:] = 0.0
                for j in range(1, resolution):
                    t = steps32[j]
                    for k in range(_LANES):
                        delta = t - cell[0, k]
                        excess = _larger(t * cell[4, k] - cell[5, k], np.float32(0.0))  # the DC bound
                        distance = delta * (cell[1, k] * delta + cell[2, k]) + cell[3, k] + excess * excess
                        distance = _smaller(_larger(distance, np.float32(0.0)), np.float32(CUTOFF))
                        w = _exp_neg(distance)
                        cell_sums[0, k] += w
                        cell_sums[1, k] += w * distance
                        row_weights[j, k] = w
            for k in range(_LANES):
                sums[0, k] += cell_sums[0, k]
                sums[1, k] += cell_sums[1, k]
        # Entropy; the channel with the lowest one wins (earlier channels win ties).
        for k in range(_LANES):
            total = sums[0, k]
            value = (_log(total) + sums[1, k] / total) / log_hypotheses
            value = _smaller(_larger(value, 0.0), 1.0)
            channel_sums[c, 0, k] = total
            if value < choice[0, k]:
                choice[0, k] = value
                choice[1, k] = c
                choice[2, k] = lowest[1, k]
                choice[3, k] = lowest[2, k]
    for k in range(n_lanes):
        texel = start + k
        c = np.int64(choice[1, k])
        entropy[texel] = choice[0, k]
        channel[texel] = c
        column = np.int64(choice[3, k])
        best_alpha[texel] = alphas[np.int64(choice[2, k])] if column > 0 else np.nan  # k = 0: no lobe
        best_ks[texel] = specular[column]
        if want_likelihood:
            inverse_total = 1.0 / channel_sums[c, 0, k]
            zero_share = channel_sums[c, 1, k] * n_zero / resolution * inverse_total
            for i in range(resolution):
                likelihood[texel, i, 0] = zero_share
                for j in range(1, resolution):
                    likelihood[texel, i, j] = weights[c, i, j, k] * inverse_total


# The CPU worker's copies of `grid_entropy_scratch` and `grid_entropy_block`, inlined into it (numba IR),
# so that LLVM sees the scratch arrays as the worker's own allocations, of known shapes, and vectorises
# the loops over lanes as in one function.
_grid_entropy_scratch_inline = numba.njit(cache=True, error_model="numpy", inline="always",
                                          fastmath={"contract", "reassoc", "nsz", "arcp"})(grid_entropy_scratch.py_func)
_grid_entropy_block_inline = numba.njit(cache=True, error_model="numpy", inline="always",
                                        fastmath={"contract", "reassoc", "nsz", "arcp"})(grid_entropy_block.py_func)
