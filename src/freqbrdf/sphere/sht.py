"""Real spherical-harmonic transforms of equiangular lat-long maps.

A map (H, W) holds samples on H rings at colatitudes theta_i = pi i / (H - 1), both poles
included (a Clenshaw-Curtis grid), and W columns at azimuths phi_j = phi0 + 2 pi j / W. The basis
is `freqbrdf.sh`'s: real, orthonormal, flat index l*l + l + m, no Condon-Shortley phase,

    Y_lm = lambda_l|m|(theta) cos(m phi) (m >= 0),   lambda_l|m|(theta) sin(|m| phi) (m < 0),

with lambda_lm = sqrt(2 - delta_m0) N_lm P_l^m(cos theta), theta from +z.

`analysis` (map -> coefficients up to lmax; needs lmax <= H - 2 and 2 lmax + 1 <= W) is exact
for maps band-limited to lmax. A real FFT of each ring gives its azimuthal Fourier coefficients
F_m(theta_i), m <= lmax, and c_lm is the integral of F_m(theta) lambda_lm(theta) sin(theta)
over [0, pi], computed in one of two ways:

- H >= 2 lmax + 2: the H-point Clenshaw-Curtis rule (exact for polynomials in cos(theta) of
  degree <= H - 1, which covers the degree-2 lmax products of band-limited F_m with lambda_lm)
  applied to the ring values as they are;
- otherwise F_m is extended around the whole meridian circle with the parity (-1)^m that a
  smooth function on the sphere has there, replaced by its trigonometric interpolant, and the
  interpolant's product with lambda_lm is integrated exactly by a Clenshaw-Curtis rule on a grid
  fine enough for the product's degree. The weighted samples are then truncated in Fourier to
  degree lmax and folded onto lmax + 2 rings, where sums against lambda_lm are still exact.

For a map that is not band-limited the two rules alias the degrees above lmax differently. They
are the rules of the "CC" geometry of ducc0's analysis, which this module replaced; the second
differs from ducc0's only where ducc0's own fine grid is too coarse for the product's degree, so
that its quadrature aliases as well (tests/test_sht.py, docs/results.md).

`synthesis` evaluates a band-limited function at a grid's samples exactly.

The associated Legendre functions come from the normalised three-term recurrence in l for each
m. Near the poles their starting values lambda_mm = O(sin^m theta) underflow at high orders while
the functions they start can grow back to O(1) at high degrees: below 2^-600 they are carried as
a mantissa and a power of 2^600 until they grow into the range of doubles, and values below
2^-600 (about 1e-181) are written as zero.

Everything is float64 and runs in a fixed order: the same input gives the same output bit for bit.
"""

from __future__ import annotations

import contextlib
import functools
import math

import numba
import numpy as np
import scipy.fft

from freqbrdf.sphere import harmonics as sh

# lambda_mm below 1 / _SCALE is carried as a mantissa and a power of _SCALE (module docstring)
_SCALE = 2.0**600
_INV_SCALE = 2.0**-600


# Multiply-adds of a Legendre kernel below which it runs on one thread: waking numba's other
# threads costs more than they save on small transforms (docs/results.md).
_PARALLEL_WORK = 2e8


@contextlib.contextmanager
def _threads_for(work: float):
    """Within the block, numba's parallel kernels use one thread if ``work`` is below
    _PARALLEL_WORK (each order's sums stay in the same order: the results are the same).
    """
    if work >= _PARALLEL_WORK or numba.get_num_threads() == 1:
        yield
        return
    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(previous)


def check_resolution(height: int, width: int, lmax: int) -> None:
    """ValueError unless an H x W grid resolves degree lmax (lmax <= H - 2, 2 lmax + 1 <= W)."""
    if lmax < 0 or lmax > height - 2 or 2 * lmax + 1 > width:
        raise ValueError(
            f"a {width}x{height} map resolves degrees up to {min(height - 2, (width - 1) // 2)}, not {lmax}"
        )


@functools.lru_cache(maxsize=64)
def clenshaw_curtis_weights(n: int) -> np.ndarray:
    """(n,) weights w of the interpolatory rule on x_i = cos(pi i / (n - 1)), i = 0..n-1:
    sum_i w_i p(x_i) = int_{-1}^{1} p(x) dx for every polynomial p of degree <= n - 1 (n >= 2).

    Interpolating p in Chebyshev polynomials, p = sum''_k a_k T_k with
    a_k = (2 / N) sum''_i p(x_i) cos(k theta_i) (N = n - 1; sum'' halves the first and last terms),
    and int T_k = 2 / (1 - k^2) for even k (0 for odd k) gives
    w_i = gamma_i (2 / N) sum''_{k even} cos(k theta_i) 2 / (1 - k^2), gamma = 1/2 at the ends.
    Returned read-only (cached).
    """
    if n < 2:
        raise ValueError(f"a Clenshaw-Curtis rule needs at least 2 nodes, got {n}")
    last = n - 1
    nodes = np.arange(n)
    degrees = np.arange(0, last + 1, 2)
    moments = 2.0 / (1.0 - degrees.astype(np.float64) ** 2)
    moments[(degrees == 0) | (degrees == last)] *= 0.5
    # cos(pi i k / N) with the argument reduced exactly in integers first
    cosines = np.cos(np.pi * (np.outer(nodes, degrees) % (2 * last)) / last)
    weights = (2.0 / last) * (cosines @ moments)
    weights[[0, -1]] *= 0.5
    weights = 0.5 * (weights + weights[::-1])  # the rule is symmetric; make it so to the last bit
    weights.flags.writeable = False
    return weights


def _northern_nodes(n_rings: int) -> tuple[np.ndarray, np.ndarray]:
    """Cos and sin of the colatitudes pi i / (P - 1) of the rings i < ceil(P / 2) (the northern
    half with the equator if P is odd), each computed so that poles and equator are exact.
    """
    rings = np.arange((n_rings + 1) // 2)
    cos_theta = np.sin(np.pi * (n_rings - 1 - 2 * rings) / (2.0 * (n_rings - 1)))
    sin_theta = np.sin(np.pi * rings / (n_rings - 1))
    return cos_theta, sin_theta


@numba.njit(fastmath=False, cache=True)
def _order_starts(lmax, sin_theta):
    """(values, exponents), each (lmax + 1, n): lambda_mm(theta_i) = sqrt(2 - delta_m0) N_mm
    P_m^m(cos theta_i) = values[m, i] _SCALE^exponents[m, i], exponents <= 0, with values in
    [1 / _SCALE, 1) wherever the exponent is negative; by lambda_mm = sqrt((2m + 1) / (2m))
    sin(theta) lambda_{m-1,m-1} (times sqrt(2) at m = 1, which every m > 0 inherits).
    """
    n = sin_theta.shape[0]
    values = np.empty((lmax + 1, n))
    exponents = np.zeros((lmax + 1, n), np.int64)
    for i in range(n):
        values[0, i] = 1.0 / math.sqrt(4.0 * math.pi)
    for m in range(1, lmax + 1):
        factor = math.sqrt((2.0 * m + 1.0) / (2.0 * m)) * (math.sqrt(2.0) if m == 1 else 1.0)
        for i in range(n):
            value = values[m - 1, i] * factor * sin_theta[i]
            exponent = exponents[m - 1, i]
            if value < _INV_SCALE and value != 0.0:
                value *= _SCALE
                exponent -= 1
            values[m, i] = value
            exponents[m, i] = exponent
    return values, exponents


@numba.njit(fastmath=False, cache=True)
def _recurrence(m, lmax):
    """(2, lmax - m + 1): the factors a_k, b_k of lambda_{m+k,m} = a_k (x lambda_{m+k-1,m} -
    b_k lambda_{m+k-2,m}) for k >= 2 (a_1 = sqrt(2m + 3), b_1 = 0; k = 0 unused).
    """
    factors = np.zeros((2, lmax - m + 1))
    if lmax > m:
        factors[0, 1] = math.sqrt(2.0 * m + 3.0)
    for k in range(2, lmax - m + 1):
        degree = m + k
        factors[0, k] = math.sqrt((4.0 * degree * degree - 1.0) / (degree * degree - m * m))
        factors[1, k] = math.sqrt(((degree - 1.0) ** 2 - m * m) / (4.0 * (degree - 1.0) ** 2 - 1.0))
    return factors


@numba.njit(fastmath=False, cache=True)
def _legendre_block(factors, cos_theta, value, exponent, first, count, out):
    """out[k, r] = lambda_{m+k, m}(theta_{first + r}) for k = 0..lmax - m, r < count, from the
    `_order_starts` of the order, by the normalised three-term recurrence in the degree with the
    order's `_recurrence` factors.

    Rings whose lambda_mm is below 1 / _SCALE (near the poles, at high orders) run the recurrence
    on the mantissa and raise its power of _SCALE whenever it passes 1, until the functions grow
    into the range of doubles; until then they are written as 0 (they are below 2^-600).
    """
    n_degrees = factors.shape[1]
    for r in range(count):
        out[0, r] = value[first + r] if exponent[first + r] == 0 else 0.0
    if n_degrees > 1:
        for r in range(count):
            out[1, r] = factors[0, 1] * cos_theta[first + r] * out[0, r]
    for k in range(2, n_degrees):
        a, b = factors[0, k], factors[1, k]
        for r in range(count):
            out[k, r] = a * (cos_theta[first + r] * out[k - 1, r] - b * out[k - 2, r])
    for r in range(count):
        power = exponent[first + r]
        if power == 0:
            continue
        x = cos_theta[first + r]
        previous, current = 0.0, value[first + r]
        for k in range(1, n_degrees):
            previous, current = current, factors[0, k] * (x * current - factors[1, k] * previous)
            if power < 0 and abs(current) > 1.0:
                previous *= _INV_SCALE
                current *= _INV_SCALE
                power += 1
            out[k, r] = current if power == 0 else 0.0


def _legendre_values(m: int, lmax: int, theta: np.ndarray) -> np.ndarray:
    """(lmax - m + 1, n) lambda_lm(theta) for l = m..lmax at colatitudes theta (n,) in [0, pi / 2]
    (as the kernels compute them; for the tests).
    """
    theta = np.asarray(theta, dtype=np.float64)
    starts, exponents = _order_starts(m, np.sin(theta))
    out = np.empty((lmax - m + 1, theta.size))
    _legendre_block(_recurrence(m, lmax), np.cos(theta), starts[m], exponents[m], 0, theta.size, out)
    return out


_LANES = 8  # partial sums of the projection, added in a fixed order at the end


@numba.njit(fastmath=False, cache=True)
def _paired_order(pair, side, lmax):
    """The parallel kernels run over pairs of orders (pair, lmax - pair), whose degree counts add
    to lmax + 2, so that equal chunks of pairs are equal work: the order of this pair and side,
    or -1 for the middle order's second side.
    """
    first, last = np.int64(pair), np.int64(lmax) - np.int64(pair)  # (prange's index may be unsigned)
    if side == 0:
        return first
    return -1 if last == first else last


@numba.njit(fastmath=False, cache=True)
def _project_order(m, lmax, cos_theta, start, exponent, even, odd, row, out):
    """out[row + k, c] = sum over the northern rings i of lambda_{m+k,m}(theta_i) times even[c, i]
    (k even) or odd[c, i] (k odd), k = 0..lmax - m. Each sum runs in _LANES interleaved partial
    sums (vectorised), then adds them pairwise.
    """
    n_columns, n_north = even.shape
    n_full = n_north - n_north % _LANES
    count = lmax - m + 1
    values = np.empty((count, n_north))
    _legendre_block(_recurrence(m, lmax), cos_theta, start, exponent, 0, n_north, values)
    for k in range(count):
        source = even if k % 2 == 0 else odd
        for c in range(n_columns):
            s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = 0.0
            for i in range(0, n_full, _LANES):
                s0 += values[k, i] * source[c, i]
                s1 += values[k, i + 1] * source[c, i + 1]
                s2 += values[k, i + 2] * source[c, i + 2]
                s3 += values[k, i + 3] * source[c, i + 3]
                s4 += values[k, i + 4] * source[c, i + 4]
                s5 += values[k, i + 5] * source[c, i + 5]
                s6 += values[k, i + 6] * source[c, i + 6]
                s7 += values[k, i + 7] * source[c, i + 7]
            rest = 0.0
            for i in range(n_full, n_north):
                rest += values[k, i] * source[c, i]
            out[row + k, c] = (((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))) + rest


@numba.njit(parallel=True, fastmath=False, cache=True)
def _project_kernel(lmax, cos_theta, starts, exponents, even, odd, offsets, out):
    """`_project_order` for every order m: even[m], odd[m] (M, C, northern rings), out (sum of
    the orders' degree counts, C) in `_packing`'s rows.
    """
    for pair in numba.prange((lmax + 2) // 2):
        for side in range(2):
            m = _paired_order(pair, side, lmax)
            if m >= 0:
                _project_order(m, lmax, cos_theta, starts[m], exponents[m], even[m], odd[m], offsets[m], out)


@numba.njit(fastmath=False, cache=True)
def _evaluate_order(m, lmax, cos_theta, start, exponent, by_degree, scale, block, out):
    """The order-m azimuthal spectra of band-limited functions at the rings of a P-ring grid
    (northern rings computed, southern ones by parity): for map b and ring i,
    out[b, i, m] = scale (G_c - i G_s), G_c = sum over l of lambda_lm(theta_i) by_degree[c_lm, b]
    and G_s the same with c_l,-m (0 for m = 0); by_degree (K, B) holds the maps' coefficients by
    flat index. The northern rings go in blocks of ``block``, the sums' inner loops over a
    block's rings (vectorised).
    """
    n_north = cos_theta.shape[0]
    n_maps, n_rings = out.shape[0], out.shape[1]
    n_pairs = n_rings // 2
    count = lmax - m + 1
    n_parts = 2 if m > 0 else 1  # cosine and sine parts
    factors = _recurrence(m, lmax)
    values = np.empty((count, block))
    # Sums over the degrees l with l - m even and odd: the cosine parts of all maps, then the sine parts.
    even = np.zeros((2 * n_maps, block))
    odd = np.zeros((2 * n_maps, block))
    for first in range(0, n_north, block):
        rings = min(block, n_north - first)
        _legendre_block(factors, cos_theta, start, exponent, first, rings, values)
        even[:] = 0.0
        odd[:] = 0.0
        for k in range(0, count, 2):
            degree = m + k
            centre = degree * degree + degree
            next_centre = centre + 2 * degree + 2  # of degree + 1
            for part in range(n_parts):
                order = m if part == 0 else -m
                for b in range(n_maps):
                    column = part * n_maps + b
                    p0 = by_degree[centre + order, b]
                    if k + 1 < count:
                        p1 = by_degree[next_centre + order, b]
                        for r in range(rings):
                            even[column, r] += p0 * values[k, r]
                            odd[column, r] += p1 * values[k + 1, r]
                    else:
                        for r in range(rings):
                            even[column, r] += p0 * values[k, r]
        for r in range(rings):
            ring = first + r
            for b in range(n_maps):
                out[b, ring, m] = scale * complex(even[b, r] + odd[b, r], -(even[n_maps + b, r] + odd[n_maps + b, r]))
            if ring < n_pairs:
                for b in range(n_maps):
                    out[b, n_rings - 1 - ring, m] = scale * complex(
                        even[b, r] - odd[b, r], -(even[n_maps + b, r] - odd[n_maps + b, r]))


@numba.njit(parallel=True, fastmath=False, cache=True)
def _evaluate_kernel(lmax, cos_theta, starts, exponents, by_degree, scale, block, out):
    """`_evaluate_order` for every order m: by_degree (K, B), scale (M,), out (B, P, >= lmax + 1)
    complex; orders above lmax are left as they are.
    """
    for pair in numba.prange((lmax + 2) // 2):
        for side in range(2):
            m = _paired_order(pair, side, lmax)
            if m >= 0:
                _evaluate_order(m, lmax, cos_theta, starts[m], exponents[m], by_degree, scale[m], block, out)


@functools.lru_cache(maxsize=16)
def _packing(lmax: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coefficients packed order by order (m = 0..lmax, then l = m..lmax): the offset of each
    order's first row, and per row the flat index of c_lm and of c_l,-m (that of c_lm for m = 0).
    """
    orders = np.concatenate([np.full(lmax + 1 - m, m) for m in range(lmax + 1)])
    degrees = np.concatenate([np.arange(m, lmax + 1) for m in range(lmax + 1)])
    offsets = np.concatenate([[0], np.cumsum(lmax + 1 - np.arange(lmax + 1))[:-1]]).astype(np.int64)
    centre = degrees * degrees + degrees
    for array in (offsets, centre):
        array.flags.writeable = False
    return offsets, centre + orders, centre - orders


def _ring_spectra(maps: np.ndarray, lmax: int, phi0: float) -> np.ndarray:
    """(B, H, lmax + 1) complex: F_m(theta_i) = int f(theta_i, phi) e^{-i m phi} dphi by the
    trapezoid rule over the W columns (exact for azimuthal degrees < W - lmax).
    """
    width = maps.shape[-1]
    orders = np.arange(lmax + 1)
    spectra = scipy.fft.rfft(maps, axis=-1)[..., : lmax + 1]
    return spectra * ((2.0 * np.pi / width) * np.exp(-1j * orders * phi0))


def _fine_circle_points(height: int, lmax: int) -> int:
    """Points around the meridian circle on which `_interpolation_rule` integrates: the
    interpolant has degree <= H - 1, its product with lambda_lm degree <= H - 1 + lmax, and the
    Clenshaw-Curtis rule on the circle's n / 2 + 1 rings is exact up to degree n / 2.
    """
    return 2 * scipy.fft.next_fast_len(height - 1 + lmax)


@functools.lru_cache(maxsize=16)
def _interpolation_rule(height: int, lmax: int) -> np.ndarray:
    """(2, lmax + 2, H) read-only: for orders m of each parity (even, odd), the matrix A with
    sum_n (A F)_n lambda_lm(theta_n) = the integral over [0, pi] of (the trigonometric interpolant
    of F) lambda_lm sin(theta), exactly, for ring values F (H,) of order m and the lmax + 2 rings
    theta_n = pi n / (lmax + 1) (the second rule of the module docstring). The steps are linear
    and depend on m only through its parity, so they run once per grid on unit vectors.
    """
    n_circle = 2 * height - 2
    n_fine = _fine_circle_points(height, lmax)
    half = clenshaw_curtis_weights(n_fine // 2 + 1)
    circle_weights = np.concatenate([half[:1], 0.5 * half[1:-1], half[-1:], 0.5 * half[-2:0:-1]])
    n_coarse = 2 * lmax + 2
    identity = np.eye(height)
    rule = np.empty((2, lmax + 2, height))
    for index, parity in enumerate((1.0, -1.0)):
        # Around the meridian circle, theta in [0, 2 pi): F(2 pi - theta) = (-1)^m F(theta). A
        # smooth function's odd orders vanish at the poles; even orders keep the pole samples.
        circle = np.empty((height, n_circle))
        circle[:, :height] = identity
        circle[:, height:] = parity * identity[:, height - 2:0:-1]
        circle[:, [0, height - 1]] *= 0.5 * (1.0 + parity)
        coefficients = scipy.fft.fft(circle, axis=-1)
        padded = np.zeros((height, n_fine), np.complex128)  # the Nyquist term split between +-(H - 1)
        padded[:, : height - 1] = coefficients[:, : height - 1]
        padded[:, n_fine - (height - 2):] = coefficients[:, height:]
        padded[:, height - 1] = 0.5 * coefficients[:, height - 1]
        padded[:, n_fine - (height - 1)] = 0.5 * coefficients[:, height - 1]
        fine = scipy.fft.ifft(padded, axis=-1) * (n_fine / n_circle)
        weighted = scipy.fft.fft(fine * circle_weights, axis=-1)
        # Only degrees <= lmax of the weighted samples meet lambda_lm: keep those, on 2 lmax + 2
        # points, and fold the circle onto the rings of [0, pi] with the same parity.
        truncated = np.zeros((height, n_coarse), np.complex128)
        truncated[:, : lmax + 1] = weighted[:, : lmax + 1]
        if lmax > 0:
            truncated[:, n_coarse - lmax:] = weighted[:, n_fine - lmax:]
        coarse = scipy.fft.ifft(truncated, axis=-1).real  # real: a real, parity-symmetric circle
        folded = coarse[:, : lmax + 2].copy()
        folded[:, 1: lmax + 1] += parity * coarse[:, n_coarse - 1: lmax + 1: -1]
        rule[index] = folded.T
    rule.flags.writeable = False
    return rule


@numba.njit(fastmath=False, cache=True)
def _apply_rule(rule, values, out):
    """out[b] = rule @ values[b]: rule (N, H), values (B, H, Q), out (B, N, Q), each sum over h in
    order (numpy's matmul would call a multi-threaded BLAS, which is slow on a busy machine).
    """
    n_maps, height, n_columns = values.shape
    sums = np.empty(n_columns)
    for b in range(n_maps):
        for n in range(rule.shape[0]):
            sums[:] = 0.0
            for h in range(height):
                factor = rule[n, h]
                for q in range(n_columns):
                    sums[q] += factor * values[b, h, q]
            out[b, n, :] = sums


def _interpolated_ring_values(spectra: np.ndarray, lmax: int) -> np.ndarray:
    """(B, H, M) ring spectra F -> (B, lmax + 2, M) ring values of `_interpolation_rule`."""
    n_maps, height, n_orders = spectra.shape
    rule = _interpolation_rule(height, lmax)
    out = np.empty((n_maps, lmax + 2, n_orders), np.complex128)
    for parity in (0, 1):
        orders = np.ascontiguousarray(spectra[:, :, parity::2])  # (B, H, M') complex
        values = np.empty((n_maps, lmax + 2, orders.shape[2]), np.complex128)
        _apply_rule(rule[parity], orders.view(np.float64), values.view(np.float64))
        out[:, :, parity::2] = values
    return out


def _project(ring_values: np.ndarray, lmax: int) -> np.ndarray:
    """(B, P, M) complex ring values R on a P-ring grid -> (B, K) real coefficients
    c_lm = sum_n lambda_lm(theta_n) Re R_nm, c_l,-m = -sum_n lambda_lm(theta_n) Im R_nm.
    """
    n_maps, n_rings, _ = ring_values.shape
    n_pairs = n_rings // 2
    # lambda_lm(pi - theta) = (-1)^(l + m) lambda_lm(theta): sums and differences of mirrored rings
    north = ring_values[:, : (n_rings + 1) // 2]
    mirrored = np.zeros_like(north)
    mirrored[:, :n_pairs] = ring_values[:, n_rings - 1: n_rings - 1 - n_pairs: -1]
    # (M, 2B, rings) real: the cosine parts of all maps, then the sine parts
    even, odd = (np.ascontiguousarray(np.concatenate([part.real, -part.imag]).transpose(2, 0, 1))
                 for part in (north + mirrored, north - mirrored))
    offsets, cosine_index, sine_index = _packing(lmax)
    cos_theta, sin_theta = _northern_nodes(n_rings)
    packed = np.empty((cosine_index.size, 2 * n_maps))
    with _threads_for(n_maps * sh.num_coeffs(lmax) * cos_theta.size):
        _project_kernel(lmax, cos_theta, *_order_starts(lmax, sin_theta), even, odd, offsets, packed)
    coeffs = np.empty((n_maps, sh.num_coeffs(lmax)))
    coeffs[:, sine_index] = packed[:, n_maps:].T  # m = 0 rows write c_l0 here, overwritten next
    coeffs[:, cosine_index] = packed[:, :n_maps].T
    return coeffs


def analysis(maps: np.ndarray, lmax: int, phi0: float = 0.0) -> np.ndarray:
    """Real SH coefficients (B, K) float64 up to lmax of maps (B, H, W) sampled on the grid of the
    module docstring (rings theta_i = pi i / (H - 1), columns phi_j = phi0 + 2 pi j / W).
    """
    maps = np.asarray(maps, dtype=np.float64)
    if maps.ndim != 3:
        raise ValueError(f"maps must be (B, H, W), got {maps.shape}")
    height, width = maps.shape[1:]
    check_resolution(height, width, lmax)
    spectra = _ring_spectra(maps, lmax, phi0)
    if height >= 2 * lmax + 2:
        ring_values = spectra * clenshaw_curtis_weights(height)[:, None]
    else:
        ring_values = _interpolated_ring_values(spectra, lmax)
    return _project(ring_values, lmax)


def synthesis(coeffs: np.ndarray, height: int, width: int, phi0: float = 0.0) -> np.ndarray:
    """(B, H, W) float64: the band-limited functions with real SH coefficients (B, K) at the
    samples of the H x W grid of the module docstring. Needs lmax <= H - 2 and 2 lmax + 1 <= W
    (the grid could hold the values with fewer rings, but `analysis` could not read them back).
    """
    coeffs = np.asarray(coeffs, dtype=np.float64)
    if coeffs.ndim != 2:
        raise ValueError(f"coeffs must be (B, K), got {coeffs.shape}")
    n_maps = coeffs.shape[0]
    lmax = sh.lmax_of(coeffs.shape[1])
    check_resolution(height, width, lmax)
    by_degree = np.ascontiguousarray(coeffs.T)  # (K, B); free if coeffs is the transpose of such an array
    cos_theta, sin_theta = _northern_nodes(height)
    orders = np.arange(lmax + 1)
    scale = np.where(orders == 0, float(width), 0.5 * width) * np.exp(1j * orders * phi0)
    spectra = np.empty((n_maps, height, width // 2 + 1), np.complex128)
    spectra[..., lmax + 1:] = 0.0
    # Ring blocks whose two (columns x rings) sums take about 128 KiB, within a core's L2 cache
    # (the fastest block size measured; docs/results.md).
    block = int(np.clip(8192 // (2 * n_maps) // 8 * 8, 8, max(8, cos_theta.size)))
    starts, exponents = _order_starts(lmax, sin_theta)
    with _threads_for(n_maps * sh.num_coeffs(lmax) * cos_theta.size):
        _evaluate_kernel(lmax, cos_theta, starts, exponents, by_degree, scale, block, spectra)
        return scipy.fft.irfft(spectra, n=width, axis=-1, workers=numba.get_num_threads())
