"""The numba kernels of the per-texel SH least squares (docs/method.md#sh-fit), shared by both backends.

Private to `freqbrdf.sphere.harmonics.fit_sh`. The CPU runs `_fit_kernel`, which solves ``lanes``
texels side by side (SIMD across them); the CUDA kernel (`freqbrdf.sphere._cuda_kernels`) runs the
same per-texel functions with one lane per thread: `texel_normal_equations` builds a texel's
regularised normal equations in a lane of a `FitScratch`, `solve_lanes` factorises and solves the
lanes' systems (Cholesky, float64).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from freqbrdf.sphere.harmonics import _sh_block

# A Cholesky pivot below this fraction of its diagonal entry marks the normal equations as
# numerically singular (cond >~ 1e11); such texels are re-solved by an SVD least-squares solve.
_PIVOT_RTOL = 1e-11
# Fast-math without the no-NaN/no-Inf assumptions, which would fold the isfinite tests to True.
_FAST_FINITE_MATH = {"nsz", "arcp", "contract", "afn", "reassoc"}


@numba.njit(fastmath=_FAST_FINITE_MATH, cache=True)
def _gram_upper(augmented, n_coeffs, n_padded, upper, lane):
    """Set upper[j, i, lane] = sum_s augmented[j, s] augmented[i, s] for j < n_coeffs, i >= j.

    Register-tiled: rows j .. j + 2 against columns i .. i + 3 share every load, so each sample costs
    7 loads for 12 multiply-adds (one dot product per entry needs 2 per 1).
    Tiles that overhang the matrix repeat its last row or column; entries below the diagonal that
    a tile also computes are written but never read.
    """
    n_rows = augmented.shape[0]
    for j in range(0, n_coeffs, 3):
        j1, j2 = min(j + 1, n_coeffs - 1), min(j + 2, n_coeffs - 1)
        for i in range(j, n_rows, 4):
            i1, i2, i3 = min(i + 1, n_rows - 1), min(i + 2, n_rows - 1), min(i + 3, n_rows - 1)
            a0 = a1 = a2 = a3 = b0 = b1 = b2 = b3 = c0 = c1 = c2 = c3 = 0.0
            for s in range(n_padded):
                x, y, z = augmented[j, s], augmented[j1, s], augmented[j2, s]
                p0, p1, p2, p3 = augmented[i, s], augmented[i1, s], augmented[i2, s], augmented[i3, s]
                a0 += x * p0
                a1 += x * p1
                a2 += x * p2
                a3 += x * p3
                b0 += y * p0
                b1 += y * p1
                b2 += y * p2
                b3 += y * p3
                c0 += z * p0
                c1 += z * p1
                c2 += z * p2
                c3 += z * p3
            upper[j, i, lane], upper[j, i1, lane], upper[j, i2, lane], upper[j, i3, lane] = a0, a1, a2, a3
            upper[j1, i, lane], upper[j1, i1, lane], upper[j1, i2, lane], upper[j1, i3, lane] = b0, b1, b2, b3
            upper[j2, i, lane], upper[j2, i1, lane], upper[j2, i2, lane], upper[j2, i3, lane] = c0, c1, c2, c3


@numba.njit(parallel=True, cache=True)
def _fit_kernel(
    directions, weights, values, lmax, diag, rec_a, rec_b, reg, reg_lambda, scale_by_weight, lanes, n_threads,
    coeffs, n_samples, solved,
):
    """Solve the regularised normal equations per texel in float64, one Cholesky for all C channels.

    Per texel, the usable samples are compacted into an augmented design matrix
    A = [w Y; w f] (K + C, n) with contiguous rows; `_gram_upper` fills the upper triangle
    U (K, K + C) of its Gram matrix, Y^T W^2 Y beside the right-hand sides Y^T W^2 f, and the
    regulariser lambda_eff R is added to the diagonal. The factorisation then runs on ``lanes``
    texels at once with the texel index innermost (the same operation sequence for every texel, so
    it vectorises without reductions): eliminating the first K pivots in place turns U into the
    Cholesky factor and the forward-substituted right-hand sides, leaving one back substitution.
    ``lanes`` is a run-time value on purpose: with a compile-time trip count LLVM unrolls the lane
    loops into scalar code it cannot prove alias-free (much slower); as a run-time count
    they are vectorised behind one overlap check. n_threads: numba's thread count (read outside,
    which keeps the kernel cacheable); each worker allocates its scratch once.
    ``solved[t]`` is False when a pivot was (numerically) non-positive.
    """
    n_groups = (weights.shape[0] + lanes - 1) // lanes
    n_workers = min(n_threads, n_groups)  # worker w takes groups w, w + n_workers, ...
    for worker in numba.prange(n_workers):
        # np.int64: the loop index is unsigned in numba's parallel code and signed when typed: one
        # signature, not two.
        _fit_worker(np.int64(worker), n_workers, directions, weights, values, lmax, diag, rec_a, rec_b, reg,
                    reg_lambda, scale_by_weight, lanes, coeffs, n_samples, solved)


@numba.njit(fastmath=_FAST_FINITE_MATH, cache=True)
def _fit_worker(
    worker, n_workers, directions, weights, values, lmax, diag, rec_a, rec_b, reg, reg_lambda, scale_by_weight,
    lanes, coeffs, n_samples, solved,
):
    """Do `_fit_kernel`'s work for the texel groups worker, worker + n_workers, ....

    A function of its own, so that numba's parallel passes see a small loop (on the whole body
    they took much of the kernel's compile time).
    """
    n_texels, n_views = weights.shape
    n_channels = values.shape[2]
    n_coeffs = reg.shape[0]
    n_groups = (n_texels + lanes - 1) // lanes
    scratch = _fit_scratch_inline(n_views, n_coeffs, n_channels, lanes)
    for group in range(worker, n_groups, n_workers):
        first = group * lanes
        n_lanes = min(lanes, n_texels - first)
        for lane in range(lanes):
            _texel_normal_equations_inline(first + lane if lane < n_lanes else -1, directions, weights, values,
                                           lmax, diag, rec_a, rec_b, reg, reg_lambda, scale_by_weight, lane, scratch,
                                           n_samples)
        _solve_lanes_inline(first, n_lanes, scratch, coeffs, n_samples, solved)


class FitScratch(NamedTuple):
    """The scratch arrays of the fit for ``lanes`` texels solved side by side (`fit_scratch`)."""

    xyz: np.ndarray  # (3, V') one texel's usable sample directions
    sample_weights: np.ndarray  # (V',)
    sh_scratch: np.ndarray  # (5, V') `_sh_block`'s
    augmented: np.ndarray  # (K + C, V') rows: w_i Y_k(d_i), then w_i f_ic
    upper: np.ndarray  # (K, K + C, lanes) Gram | rhs, then Cholesky factor | R^-T b
    gram_diagonal: np.ndarray  # (K, lanes) before elimination, for the pivot test
    inv_diagonal: np.ndarray  # (K, lanes) 1 / diagonal of the Cholesky factor
    solution: np.ndarray  # (K, C, lanes)
    lane_ok: np.ndarray  # (lanes,) bool


@numba.njit(cache=True)
def fit_scratch(n_views, n_coeffs, n_channels, lanes):
    """Allocate one `FitScratch` for V views, K coefficients, C channels and ``lanes`` texels.

    V' = V rounded up to a multiple of 8: the dot products run over a multiple of the SIMD width.
    """
    padded_views = (n_views + 7) // 8 * 8
    n_rows = n_coeffs + n_channels
    return FitScratch(np.empty((3, padded_views)), np.empty(padded_views), np.empty((5, padded_views)),
                      np.empty((n_rows, padded_views)), np.empty((n_coeffs, n_rows, lanes)),
                      np.empty((n_coeffs, lanes)), np.empty((n_coeffs, lanes)),
                      np.empty((n_coeffs, n_channels, lanes)), np.empty(lanes, dtype=np.bool_))


@numba.njit(fastmath=_FAST_FINITE_MATH, cache=True)
def texel_normal_equations(t, directions, weights, values, lmax, diag, rec_a, rec_b, reg, reg_lambda,
                           scale_by_weight, lane, scratch, n_samples):
    """Set up texel t's regularised normal equations in lane ``lane`` of scratch (`FitScratch`).

    Its usable samples are compacted into the augmented design matrix, `_gram_upper` fills
    scratch.upper[:, :, lane] and lambda_eff R is added to the diagonal. Writes n_samples[t]. A
    texel without usable samples, or t = -1 (a padding lane), gets an identity system with a zero
    right-hand side, which solves to 0.
    """
    xyz, sample_weights, sh_scratch, augmented = scratch.xyz, scratch.sample_weights, scratch.sh_scratch, \
        scratch.augmented
    upper, gram_diagonal, lane_ok = scratch.upper, scratch.gram_diagonal, scratch.lane_ok
    n_views = weights.shape[1]
    n_channels = values.shape[2]
    n_coeffs = reg.shape[0]
    n_rows = n_coeffs + n_channels
    n = 0
    weight_sq_sum = 0.0
    for v in range(n_views if t >= 0 else 0):
        w = np.float64(weights[t, v])
        usable = w > 0.0
        for axis in range(3):
            usable = usable and math.isfinite(directions[t, v, axis])
        for c in range(n_channels):
            usable = usable and math.isfinite(values[t, v, c])
        if not usable:
            continue
        for axis in range(3):
            xyz[axis, n] = directions[t, v, axis]
        for c in range(n_channels):
            augmented[n_coeffs + c, n] = w * values[t, v, c]
        sample_weights[n] = w
        weight_sq_sum += w * w
        n += 1
    if t >= 0:
        n_samples[t] = n
    lane_ok[lane] = n > 0
    if n == 0:  # empty (or padding) lane: an identity system with zero rhs solves to 0
        for j in range(n_coeffs):
            for i in range(n_rows):
                upper[j, i, lane] = 1.0 if i == j else 0.0
            gram_diagonal[j, lane] = 1.0
        return
    _sh_block(xyz[0], xyz[1], xyz[2], n, lmax, diag, rec_a, rec_b, augmented, sh_scratch)
    n_padded = (n + 7) // 8 * 8
    for k in range(n_rows):
        for s in range(n, n_padded):
            augmented[k, s] = 0.0
    for k in range(n_coeffs):
        for s in range(n):
            augmented[k, s] *= sample_weights[s]
    _gram_upper(augmented, n_coeffs, n_padded, upper, lane)
    lam = reg_lambda * weight_sq_sum if scale_by_weight else reg_lambda
    for j in range(n_coeffs):
        upper[j, j, lane] += lam * reg[j]
        gram_diagonal[j, lane] = upper[j, j, lane]


@numba.njit(fastmath=_FAST_FINITE_MATH, cache=True)
def solve_lanes(first, n_lanes, scratch, coeffs, n_samples, solved):
    """Solve the normal equations of scratch's lanes (`texel_normal_equations`) for texels first, ....

    The factorisation runs on all lanes at once with the lane innermost (the same operation
    sequence for every texel, so it vectorises without reductions): eliminating the first K
    pivots in place turns the upper triangle into the Cholesky factor and the forward-substituted
    right-hand sides, leaving one back substitution. Writes coeffs and solved of the n_lanes
    texels from ``first``; ``solved[t]`` is False when a pivot was (numerically) non-positive.
    """
    upper, gram_diagonal, inv_diagonal = scratch.upper, scratch.gram_diagonal, scratch.inv_diagonal
    solution, lane_ok = scratch.solution, scratch.lane_ok
    n_coeffs, n_rows, lanes = upper.shape
    n_channels = n_rows - n_coeffs
    # Left-looking Cholesky on the upper triangle, row by row; its row updates also carry the
    # rhs. Row i takes the updates of all earlier rows, two at a time, while it stays in cache
    # (faster than one right-looking rank-1 update per pivot).
    # A failed lane continues with a unit pivot (finite garbage) and is re-solved by the caller.
    for i in range(n_coeffs):
        for j in range(0, i - 1, 2):
            for k in range(i, n_rows):
                for lane in range(lanes):
                    upper[i, k, lane] -= (
                        upper[j, i, lane] * upper[j, k, lane] + upper[j + 1, i, lane] * upper[j + 1, k, lane]
                    )
        if i % 2 == 1:
            for k in range(i, n_rows):
                for lane in range(lanes):
                    upper[i, k, lane] -= upper[i - 1, i, lane] * upper[i - 1, k, lane]
        for lane in range(lanes):
            pivot = upper[i, i, lane]
            if not (pivot > 0.0 and pivot > _PIVOT_RTOL * gram_diagonal[i, lane]):
                lane_ok[lane] = False
                pivot = 1.0
            inv_diagonal[i, lane] = 1.0 / math.sqrt(pivot)
        for k in range(i, n_rows):
            for lane in range(lanes):
                upper[i, k, lane] *= inv_diagonal[i, lane]
    # Back substitution R x = R^-T b.
    for i in range(n_coeffs - 1, -1, -1):
        for c in range(n_channels):
            for lane in range(lanes):
                solution[i, c, lane] = upper[i, n_coeffs + c, lane]
        for k in range(i + 1, n_coeffs):
            for c in range(n_channels):
                for lane in range(lanes):
                    solution[i, c, lane] -= upper[i, k, lane] * solution[k, c, lane]
        for c in range(n_channels):
            for lane in range(lanes):
                solution[i, c, lane] *= inv_diagonal[i, lane]
    for lane in range(n_lanes):
        solved[first + lane] = lane_ok[lane] or n_samples[first + lane] == 0
        for c in range(n_channels):
            for k in range(n_coeffs):
                coeffs[first + lane, c, k] = solution[k, c, lane]


# The CPU worker's copies of `fit_scratch`, `texel_normal_equations` and `solve_lanes`, inlined into it
# (numba IR), so that LLVM sees the scratch arrays as the worker's own allocations, of known shapes, as
# in one function.
_fit_scratch_inline = numba.njit(cache=True, inline="always")(fit_scratch.py_func)
_texel_normal_equations_inline = numba.njit(fastmath=_FAST_FINITE_MATH, cache=True,
                                            inline="always")(texel_normal_equations.py_func)
_solve_lanes_inline = numba.njit(fastmath=_FAST_FINITE_MATH, cache=True, inline="always")(solve_lanes.py_func)
