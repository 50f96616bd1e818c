"""Real spherical harmonics: evaluation, regularised fitting, spectra, filtering, rotation.

The SH fits of docs/method.md#sh-fit (`fit_sh`), the power spectrum of docs/method.md#conventions (`power_spectrum`) and the
band-limit filter of docs/method.md#band-limit (`gaussian_lowpass`). Convention (appendix eqs. 14-16, docs/method.md#conventions):
polar axis +z, theta = acos(z), phi = atan2(y, x); flat index k = l*l + l + m, m = -l..l,
K = (lmax + 1)^2 coefficients, L = lmax + 1 degrees.

    Y_lm = sqrt(2) N_lm P_l^m(cos theta) cos(m phi)       m > 0
    Y_l0 =         N_l0 P_l^0(cos theta)
    Y_lm = sqrt(2) N_l|m| P_l^|m|(cos theta) sin(|m| phi)  m < 0
    N_lm = sqrt((2l + 1) / (4 pi) (l - m)! / (l + m)!)

with P_l^m the associated Legendre function WITHOUT the Condon-Shortley phase (-1)^m, so the
basis is orthonormal on the sphere and the degree-1 functions are +sqrt(3 / 4 pi) times
(y, z, x) for m = -1, 0, 1. In terms of scipy's complex harmonics (which carry the phase),
Y_lm = sqrt(2) (-1)^m Re Y_l^m for m > 0 and sqrt(2) (-1)^m Im Y_l^|m| for m < 0.

Evaluation uses the normalised three-term recurrences for P_l^m / sin^m(theta) and builds
sin^m(theta) cos(m phi), sin^m(theta) sin(m phi) as the real and imaginary parts of (x + i y)^m,
so no trigonometric functions or factorials are evaluated and every intermediate stays bounded
(stable to high degree, float32 or float64).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np

from freqbrdf.config import RegulariserKind
from freqbrdf.devices import resolve_device

# SHFit.status values
FIT_OK = 0
FIT_UNDERDETERMINED = 1  # fewer weighted samples than K (or a rank-deficient sample set)
FIT_EMPTY = 2  # no weighted sample at all: coefficients are zero

# Texels factorised together in the fit kernel, one per SIMD lane.
_LANES = 32


def num_coeffs(lmax: int) -> int:
    """Count the real SH up to and including a degree.

    Parameters
    ----------
    lmax : int
        The highest degree, >= 0.

    Returns
    -------
    int
        K = (lmax + 1)^2.

    Raises
    ------
    ValueError
        If ``lmax`` is negative.
    """
    if lmax < 0:
        raise ValueError(f"lmax must be >= 0, got {lmax}")
    return (lmax + 1) ** 2


def sh_degrees(lmax: int) -> np.ndarray:
    """Return the degree l of each flat index.

    Parameters
    ----------
    lmax : int
        The highest degree.

    Returns
    -------
    (K,) int64
        E.g. [0, 1, 1, 1, 2, ...].
    """
    return np.repeat(np.arange(lmax + 1), 2 * np.arange(lmax + 1) + 1)


def lmax_of(n_coeffs: int) -> int:
    """Return the highest degree of K coefficients: the inverse of `num_coeffs`.

    Parameters
    ----------
    n_coeffs : int
        The number of coefficients K.

    Returns
    -------
    int
        lmax with (lmax + 1)^2 = K.

    Raises
    ------
    ValueError
        If ``n_coeffs`` is not a positive perfect square.
    """
    lmax = math.isqrt(n_coeffs) - 1
    if lmax < 0 or num_coeffs(lmax) != n_coeffs:
        raise ValueError(f"{n_coeffs} SH coefficients is not (lmax + 1)^2 for any lmax")
    return lmax


# --------------------------------------------------------------------------------------------
# Evaluation


@functools.lru_cache(maxsize=None)
def _legendre_tables(lmax: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Recurrence factors for Q_lm = sqrt(2 - delta_m0) N_lm P_l^m / sin^m(theta).

    diag (lmax+1,):            Q_mm = diag[m] Q_{m-1,m-1}, Q_00 = diag[0] = 1 / sqrt(4 pi)
    a, b (lmax+1, lmax+1):     Q_lm = a[l, m] (z Q_{l-1,m} - b[l, m] Q_{l-2,m}) for l >= m + 2
    and Q_{m+1,m} = sqrt(2m + 3) z Q_mm. The sqrt(2) of the real basis is folded into diag[1]
    so every m > 0 inherits it through the (linear) recurrences.
    """
    m = np.arange(1, lmax + 1, dtype=np.float64)
    diag = np.empty(lmax + 1)
    diag[0] = 1.0 / math.sqrt(4.0 * math.pi)
    diag[1:] = np.sqrt((2.0 * m + 1.0) / (2.0 * m))
    if lmax >= 1:
        diag[1] *= math.sqrt(2.0)
    a = np.zeros((lmax + 1, lmax + 1))
    b = np.zeros((lmax + 1, lmax + 1))
    for order in range(lmax + 1):
        for degree in range(order + 2, lmax + 1):
            l2, m2 = degree * degree, order * order
            a[degree, order] = math.sqrt((4.0 * l2 - 1.0) / (l2 - m2))
            b[degree, order] = math.sqrt(((degree - 1) ** 2 - m2) / (4.0 * (degree - 1) ** 2 - 1.0))
    return diag, a, b


@numba.njit(fastmath=True, cache=True)
def _sh_block(x, y, z, n, lmax, diag, rec_a, rec_b, out, scratch):
    """Write all K real SH at n unit directions (x, y, z: (>= n,)) to out[:, :n] (K, >= n).

    Every loop runs over the directions innermost, so it vectorises. scratch (5, >= n) holds
    Q_mm, the two previous Q_lm of the degree recurrence, and Re/Im (x + i y)^m.
    """
    q_mm, q_a, q_b, cos_m, sin_m = scratch[0], scratch[1], scratch[2], scratch[3], scratch[4]
    for s in range(n):
        q_mm[s] = diag[0]
        cos_m[s] = 1.0  # Re (x + i y)^m = sin^m(theta) cos(m phi)
        sin_m[s] = 0.0  # Im (x + i y)^m = sin^m(theta) sin(m phi)
    for m in range(lmax + 1):
        if m > 0:
            for s in range(n):
                q_mm[s] *= diag[m]
                cos_prev = cos_m[s]
                cos_m[s] = x[s] * cos_prev - y[s] * sin_m[s]
                sin_m[s] = x[s] * sin_m[s] + y[s] * cos_prev
        # q_a holds Q_{l-2,m}, q_b holds Q_{l-1,m}; the new Q_lm overwrites q_a, then they swap.
        q_prev2, q_prev = q_a, q_b
        for s in range(n):
            q_prev[s] = q_mm[s]
        for degree in range(m, lmax + 1):
            if degree == m + 1:
                factor = math.sqrt(2.0 * m + 3.0)
                for s in range(n):
                    q_prev2[s] = factor * z[s] * q_prev[s]
                q_prev2, q_prev = q_prev, q_prev2
            elif degree > m + 1:
                a, b = rec_a[degree, m], rec_b[degree, m]
                for s in range(n):
                    q_prev2[s] = a * (z[s] * q_prev[s] - b * q_prev2[s])
                q_prev2, q_prev = q_prev, q_prev2
            centre = degree * degree + degree
            if m == 0:
                for s in range(n):
                    out[centre, s] = q_prev[s]
            else:
                for s in range(n):
                    out[centre + m, s] = q_prev[s] * cos_m[s]
                    out[centre - m, s] = q_prev[s] * sin_m[s]


_EVAL_BLOCK = 64  # directions per work item of eval_sh


@numba.njit(parallel=True, fastmath=True, cache=True)
def _eval_sh_kernel(directions, lmax, diag, rec_a, rec_b, out):
    n_directions = directions.shape[0]
    n_coeffs = out.shape[1]
    for block in numba.prange((n_directions + _EVAL_BLOCK - 1) // _EVAL_BLOCK):
        start = block * _EVAL_BLOCK
        n = min(_EVAL_BLOCK, n_directions - start)
        xyz = np.empty((3, _EVAL_BLOCK))
        for s in range(n):
            for axis in range(3):
                xyz[axis, s] = directions[start + s, axis]
        values = np.empty((n_coeffs, _EVAL_BLOCK))
        _sh_block(xyz[0], xyz[1], xyz[2], n, lmax, diag, rec_a, rec_b, values, np.empty((5, _EVAL_BLOCK)))
        for s in range(n):
            for k in range(n_coeffs):
                out[start + s, k] = values[k, s]


def eval_sh(directions: np.ndarray, lmax: int) -> np.ndarray:
    """Evaluate the real SH at unit directions.

    Directions are not renormalised (off-unit input gives the harmonic polynomials' values).

    Parameters
    ----------
    directions : (..., 3) array_like
        Unit directions.
    lmax : int
        The highest degree.

    Returns
    -------
    (..., K) float32 or float64
        The basis at each direction; float32 for float32 input, else float64.

    Raises
    ------
    ValueError
        If the trailing axis is not 3.
    """
    directions = np.asarray(directions)
    if directions.shape[-1] != 3:
        raise ValueError(f"directions must have a trailing axis of 3, got shape {directions.shape}")
    dtype = np.float32 if directions.dtype == np.float32 else np.float64
    flat = np.ascontiguousarray(directions.reshape(-1, 3), dtype=dtype)
    out = np.empty((flat.shape[0], num_coeffs(lmax)), dtype=dtype)
    _eval_sh_kernel(flat, lmax, *_legendre_tables(lmax), out)
    return out.reshape(directions.shape[:-1] + (out.shape[1],))


# --------------------------------------------------------------------------------------------
# Spectra and filters


def power_spectrum(coeffs: np.ndarray) -> np.ndarray:
    """Compute the power spectrum S(l) = sum_m c_lm^2 (appendix eq. 17, no normalisation).

    One pass in numba, summed in float64 in index order (faster than numpy's square and
    reduceat); a strided view is copied first, which is faster than reading it in place.

    Parameters
    ----------
    coeffs : (..., K) array_like
        SH coefficients.

    Returns
    -------
    (..., L) float32 or float64
        S(l) for l = 0 .. lmax, in the coefficients' float type (float64 for any other).

    Raises
    ------
    ValueError
        If K is not a perfect square.
    """
    coeffs = np.asarray(coeffs)
    lmax = lmax_of(coeffs.shape[-1])
    if coeffs.dtype not in (np.float32, np.float64):
        coeffs = coeffs.astype(np.float64)
    flat = np.ascontiguousarray(coeffs).reshape(-1, coeffs.shape[-1])
    out = np.empty((flat.shape[0], lmax + 1), dtype=coeffs.dtype)
    _power_spectrum_kernel(flat, out)
    return out.reshape(coeffs.shape[:-1] + (lmax + 1,))


@numba.njit(parallel=True, cache=True)
def _power_spectrum_kernel(coeffs, out):  # (M, K), out (M, L); summed in float64, in order
    for row in numba.prange(coeffs.shape[0]):
        for degree in range(out.shape[1]):
            total = 0.0
            for index in range(degree * degree, (degree + 1) * (degree + 1)):
                value = np.float64(coeffs[row, index])
                total += value * value
            out[row, degree] = total


def gaussian_lowpass(coeffs: np.ndarray, sigma: float) -> np.ndarray:
    """Low-pass SH coefficients: multiply each degree l by exp(-(sigma l)^2) (docs/method.md#band-limit).

    Parameters
    ----------
    coeffs : (..., K) array_like
        SH coefficients.
    sigma : float
        The filter width.

    Returns
    -------
    (..., K) array
        The filtered coefficients, at least float32.
    """
    coeffs = np.asarray(coeffs)
    degrees = sh_degrees(lmax_of(coeffs.shape[-1]))
    return coeffs * np.exp(-np.square(sigma * degrees)).astype(np.result_type(coeffs, np.float32))


def sphere_quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Make a Gauss-Legendre (in cos theta) x uniform (in phi) quadrature on the unit sphere.

    Exact for polynomials of total degree <= ``degree`` restricted to the sphere, e.g. for the
    product of two SH of degree <= degree / 2.

    Parameters
    ----------
    degree : int
        The highest total degree integrated exactly.

    Returns
    -------
    directions : (M, 3) float64
        Unit nodes, M = (degree // 2 + 1) (degree + 1).
    weights : (M,) float64
        Their weights, summing to 4 pi.
    """
    cos_theta, gl_weights = np.polynomial.legendre.leggauss(degree // 2 + 1)
    n_phi = degree + 1
    phi = 2.0 * np.pi * np.arange(n_phi) / n_phi
    sin_theta = np.sqrt(1.0 - cos_theta**2)
    directions = np.stack(
        [
            np.outer(sin_theta, np.cos(phi)),
            np.outer(sin_theta, np.sin(phi)),
            np.repeat(cos_theta[:, None], n_phi, axis=1),
        ],
        axis=-1,
    ).reshape(-1, 3)
    weights = np.repeat(gl_weights * (2.0 * np.pi / n_phi), n_phi)
    return directions, weights


def rotation_matrix_sh(rotation: np.ndarray, lmax: int) -> np.ndarray:
    """Build the SH rotation matrix D, with rotate_sh(c, rotation) = c @ D.T.

    D[j, i] = integral of Y_j(w) Y_i(R^T w) dw, computed with a quadrature that is exact for these
    degree-2 lmax products, so it is exact to rounding for any degree.

    Parameters
    ----------
    rotation : (3, 3) array_like
        A proper rotation R (see `rotate_sh`).
    lmax : int
        The highest degree.

    Returns
    -------
    (K, K) float64
        D, block diagonal (rotations never mix degrees).

    Raises
    ------
    ValueError
        If ``rotation`` is not a (3, 3) proper rotation.
    """
    rotation = np.asarray(rotation, dtype=np.float64)
    if rotation.shape != (3, 3):
        raise ValueError(f"rotation must be (3, 3), got {rotation.shape}")
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
        raise ValueError("rotation must be a proper rotation matrix (orthonormal, det +1)")
    directions, weighted_basis, mixed = _rotation_quadrature(lmax)
    rotated_basis = eval_sh(directions @ rotation, lmax)  # (N, K): Y_i(R^T w_n)
    matrix = weighted_basis @ rotated_basis
    matrix[mixed] = 0.0  # rotations never mix degrees
    return matrix


@functools.lru_cache(maxsize=8)
def _rotation_quadrature(lmax: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return `rotation_matrix_sh`'s quadrature, the same for every rotation (read-only).

    The nodes (N, 3), the basis at them times the weights, transposed (K, N), and the (K, K) mask
    of coefficient pairs of different degrees.
    """
    directions, weights = sphere_quadrature(2 * lmax)
    weighted_basis = (eval_sh(directions, lmax) * weights[:, None]).T
    degrees = sh_degrees(lmax)
    mixed = degrees[:, None] != degrees[None, :]
    for array in (directions, weighted_basis, mixed):
        array.setflags(write=False)
    return directions, weighted_basis, mixed


def rotate_sh(coeffs: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Rotate a function given by SH coefficients: g(w) = f(R^T w).

    Parameters
    ----------
    coeffs : (..., K) array_like
        Coefficients of f.
    rotation : (3, 3) array_like
        R, mapping directions of f's frame to g's frame (g(R w) = f(w)); e.g. an object-to-world
        rotation turns object-frame coefficients into world-frame ones.

    Returns
    -------
    (..., K) array
        Coefficients of g, at least float32.

    Raises
    ------
    ValueError
        If ``rotation`` is not a proper rotation or K is not a perfect square.
    """
    coeffs = np.asarray(coeffs)
    matrix = rotation_matrix_sh(rotation, lmax_of(coeffs.shape[-1]))
    return coeffs @ matrix.T.astype(np.result_type(coeffs, np.float32))


# --------------------------------------------------------------------------------------------
# Regularised least-squares fit (appendix eqs. 19-20, App. B)


@dataclass
class SHFit:
    """The result of `fit_sh` for N texels and C channels.

    Attributes
    ----------
    coeffs : (N, C, K) float32 or float64
        Coefficients; float32 when all inputs were float32, else float64.
    n_samples : (N,) int32
        Samples with positive weight and finite data.
    status : (N,) uint8
        ``FIT_OK``, ``FIT_UNDERDETERMINED`` or ``FIT_EMPTY``.
    """

    coeffs: np.ndarray
    n_samples: np.ndarray
    status: np.ndarray


def regulariser_weights(lmax: int, regulariser: RegulariserKind) -> np.ndarray:
    """Return the regulariser's weight reg(l) at each flat index.

    Parameters
    ----------
    lmax : int
        The highest degree.
    regulariser : {"exponential", "constant", "none"}
        e^l (the paper's), 1 or 0.

    Returns
    -------
    (K,) float64
        reg(l_k).

    Raises
    ------
    ValueError
        If ``regulariser`` is unknown.
    """
    degrees = sh_degrees(lmax).astype(np.float64)
    if regulariser == "exponential":
        return np.exp(degrees)
    if regulariser == "constant":
        return np.ones_like(degrees)
    if regulariser == "none":
        return np.zeros_like(degrees)
    raise ValueError(f"unknown regulariser {regulariser!r}; choose 'exponential', 'constant' or 'none'")


def _solve_by_svd(directions, weights, values, lmax, reg_lambda, reg, scale_lambda_with_weight):
    """Solve one texel's regularised problem by SVD least squares (the minimum-norm solution).

    directions (V, 3), weights (V,), values (V, C). Stacks [w Y; sqrt(lambda_eff reg)] against
    [w f; 0]; with no regulariser this is the minimum-norm weighted least-squares solution.
    Returns coeffs (C, K) and the numerical rank of the stacked system.
    """
    usable = (weights > 0) & np.isfinite(directions).all(-1) & np.isfinite(values).all(-1)
    w = weights[usable].astype(np.float64)
    lam = reg_lambda * np.sum(w * w) if scale_lambda_with_weight else reg_lambda
    reg_diagonal = lam * reg
    design = eval_sh(directions[usable].astype(np.float64), lmax) * w[:, None]  # (n, K)
    targets = values[usable].astype(np.float64) * w[:, None]  # (n, C)
    design = np.concatenate([design, np.diag(np.sqrt(reg_diagonal))], axis=0)
    targets = np.concatenate([targets, np.zeros((reg_diagonal.shape[0], targets.shape[1]))], axis=0)
    solution, _, rank, _ = np.linalg.lstsq(design, targets, rcond=None)
    return solution.T, rank


def fit_sh(
    directions: np.ndarray,
    weights: np.ndarray,
    values: np.ndarray,
    lmax: int,
    reg_lambda: float,
    regulariser: RegulariserKind = "exponential",
    scale_lambda_with_weight: bool = True,
    device: str = "auto",
    coeffs_out: np.ndarray | None = None,
) -> SHFit:
    """Fit SH to each texel's samples by weighted, degree-regularised least squares (docs/method.md#sh-fit).

    Minimises, per texel and channel c,

        sum_i w_i^2 (sum_k x_ck Y_k(d_i) - f_ic)^2 + lambda_eff sum_k reg(l_k) x_ck^2,

    with reg(l) from `regulariser_weights`. The normal equations (Y^T W^2 Y + lambda_eff R) are
    factorised once per texel (Cholesky, float64) and serve all C right-hand sides.

    A texel without samples gets zeros and FIT_EMPTY; one with fewer samples than K gets
    FIT_UNDERDETERMINED (its regularised solution is still well defined). Where the normal
    equations are numerically singular (no regulariser and too few or degenerate samples), the
    texel is solved by SVD least squares instead, which returns the minimum-norm solution, and is
    flagged FIT_UNDERDETERMINED when that system is rank deficient.

    Parameters
    ----------
    directions : (N, V, 3) array_like
        Unit sample directions per texel.
    weights : (N, V) array_like
        Sample weights; a sample counts only where w > 0 and its direction and values are finite.
    values : (N, V, C) array_like
        Sample values.
    lmax : int
        The highest degree l*.
    reg_lambda : float
        The regulariser's strength lambda, >= 0.
    regulariser : {"exponential", "constant", "none"}, optional
        reg(l) = e^l (the paper's), 1 or 0.
    scale_lambda_with_weight : bool, optional
        lambda_eff = reg_lambda * sum_i w_i^2: the penalty then has the same strength relative to
        the data term whatever the number of views or their weights (doubling every sample leaves
        the solution unchanged). Otherwise lambda_eff = reg_lambda (the paper's absolute lambda).
    device : {"auto", "cpu", "cuda"}, optional
        Where the normal equations are built and solved (`freqbrdf.devices.resolve_device`); the
        SVD fallback runs on the CPU. The backends agree to rounding (docs/results.md).
    coeffs_out : (N, C, K) array, optional
        C-contiguous, float32 where all inputs are float32 (else float64): the coefficients are
        written there (e.g. a block of a larger array) instead of into a new array.

    Returns
    -------
    SHFit
        Coefficients (N, C, K) (``coeffs_out`` where given), sample counts and status per texel.

    Raises
    ------
    ValueError
        If the shapes do not match, ``reg_lambda`` < 0, ``regulariser`` or ``device`` is unknown, or
        ``device`` is "cuda" where no CUDA device answers.

    Examples
    --------
    One texel seen from 200 directions; its radiance is 1 + z, which degree 1 holds exactly.

    >>> import numpy as np
    >>> from freqbrdf.sphere.harmonics import fit_sh
    >>> d = np.random.default_rng(0).normal(size=(1, 200, 3))
    >>> d /= np.linalg.norm(d, axis=-1, keepdims=True)
    >>> f = 1.0 + d[..., 2:3]
    >>> fit = fit_sh(d, np.ones((1, 200)), f, lmax=2, reg_lambda=1e-6, device="cpu")
    >>> fit.coeffs.shape, int(fit.n_samples[0])
    ((1, 1, 9), 200)
    >>> np.round(fit.coeffs[0, 0, :3] / np.sqrt(np.pi), 2) + 0.0  # Y_00 = 1/sqrt(4 pi), Y_10 = sqrt(3/(4 pi)) z
    array([2.  , 0.  , 1.15])
    """
    directions = np.asarray(directions)
    weights = np.asarray(weights)
    values = np.asarray(values)
    if directions.ndim != 3 or directions.shape[-1] != 3:
        raise ValueError(f"directions must be (T, V, 3), got {directions.shape}")
    if weights.shape != directions.shape[:2] or values.shape[:2] != directions.shape[:2] or values.ndim != 3:
        raise ValueError(
            f"shape mismatch: directions {directions.shape}, weights {weights.shape}, values {values.shape}"
        )
    if reg_lambda < 0:
        raise ValueError(f"reg_lambda must be >= 0, got {reg_lambda}")
    reg = regulariser_weights(lmax, regulariser)
    n_texels, _ = weights.shape
    n_coeffs = num_coeffs(lmax)
    all_float32 = all(a.dtype == np.float32 for a in (directions, weights, values))
    out_dtype = np.float32 if all_float32 else np.float64

    def as_kernel_input(array):
        # float32 and float64 pass through without a copy; anything else becomes float64
        return np.ascontiguousarray(array if array.dtype in (np.float32, np.float64) else array.astype(np.float64))

    shape = (n_texels, values.shape[2], n_coeffs)
    if coeffs_out is None:
        coeffs = np.empty(shape, dtype=out_dtype)
    elif coeffs_out.shape != shape or coeffs_out.dtype != out_dtype or not coeffs_out.flags.c_contiguous:
        raise ValueError(f"coeffs_out must be C-contiguous {np.dtype(out_dtype).name} {shape}, got "
                         f"{coeffs_out.dtype.name} {coeffs_out.shape}")
    else:
        coeffs = coeffs_out
    n_samples = np.empty(n_texels, dtype=np.int32)
    solved = np.empty(n_texels, dtype=np.bool_)
    inputs = (as_kernel_input(directions), as_kernel_input(weights), as_kernel_input(values))
    if resolve_device(device) == "cuda":
        from freqbrdf.sphere._cuda_kernels import fit_on_cuda

        fit_on_cuda(*inputs, lmax, _legendre_tables(lmax), reg, float(reg_lambda), bool(scale_lambda_with_weight),
                    coeffs, n_samples, solved)
    else:
        from freqbrdf.sphere._fit_kernels import _fit_kernel  # it imports _sh_block from here

        _fit_kernel(*inputs, lmax, *_legendre_tables(lmax), reg, float(reg_lambda), bool(scale_lambda_with_weight),
                    _LANES, numba.get_num_threads(), coeffs, n_samples, solved)
    status = np.where(n_samples == 0, FIT_EMPTY, np.where(n_samples < n_coeffs, FIT_UNDERDETERMINED, FIT_OK))
    status = status.astype(np.uint8)
    for t in np.flatnonzero(~solved):
        coeffs[t], rank = _solve_by_svd(
            directions[t], weights[t], values[t], lmax, reg_lambda, reg, scale_lambda_with_weight
        )
        if rank < n_coeffs:
            status[t] = max(status[t], FIT_UNDERDETERMINED)
    return SHFit(coeffs=coeffs, n_samples=n_samples, status=status)
