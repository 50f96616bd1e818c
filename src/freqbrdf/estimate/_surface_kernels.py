"""numba kernels of the whole-surface solve (`freqbrdf.estimate.surface`).

The Huber re-weighting of the graph's edges and a Jacobi-preconditioned conjugate-gradient solve
of (diag(d_c) + D - W) x_c = b_c for every channel c at once, on the graph in CSR form. One
thread per solve: an iteration is a few sparse passes, and on a shared machine threads that wait for
each other at every pass cost far more than they save
(docs/results.md#the-whole-surface-estimate-the-default); they release the GIL, so that independent
solves run side by side. Dot products are summed per block
of `BLOCK` rows, then over the blocks in order.
"""

from __future__ import annotations

import numba
import numpy as np

# Rows per partial sum of a dot product: fixed, so that sums do not depend on the thread count.
BLOCK = 4096


@numba.njit(cache=True, nogil=True)
def huber_weights(indptr, indices, weights, x, huber, coupling, robust, degree):
    """Write robust[k] = coupling w_k min(1, huber / |x_i - x_j|) per edge k = (i, j) and each row's sum.

    ``x`` (N, C): the difference is the Euclidean norm over the channels.
    """
    n_rows, n_channels = x.shape
    for i in range(n_rows):
        total = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            squared = 0.0
            for c in range(n_channels):
                difference = x[i, c] - x[j, c]
                squared += difference * difference
            distance = np.sqrt(squared)
            factor = 1.0 if distance <= huber else huber / distance
            robust[k] = coupling * weights[k] * factor
            total += robust[k]
        degree[i] = total


@numba.njit(cache=True)
def _apply(indptr, indices, robust, degree, diagonal, x, out):
    """Write (diag(diagonal) + D - W) x into out, per channel.

    Three channels (the base colour) are summed in one pass over each row's edges, each channel in
    the same order as alone.
    """
    n_rows, n_channels = x.shape
    if n_channels == 3:
        for i in range(n_rows):
            d = degree[i]
            v0 = (diagonal[i, 0] + d) * x[i, 0]
            v1 = (diagonal[i, 1] + d) * x[i, 1]
            v2 = (diagonal[i, 2] + d) * x[i, 2]
            for k in range(indptr[i], indptr[i + 1]):
                j = indices[k]
                w = robust[k]
                v0 -= w * x[j, 0]
                v1 -= w * x[j, 1]
                v2 -= w * x[j, 2]
            out[i, 0] = v0
            out[i, 1] = v1
            out[i, 2] = v2
        return
    for i in range(n_rows):
        for c in range(n_channels):
            value = (diagonal[i, c] + degree[i]) * x[i, c]
            for k in range(indptr[i], indptr[i + 1]):
                value -= robust[k] * x[indices[k], c]
            out[i, c] = value


@numba.njit(cache=True)
def _block_dots(a, b, partial):
    """partial[block, c] = sum over the block's rows of a[:, c] b[:, c]."""
    n_rows, n_channels = a.shape
    n_blocks = partial.shape[0]
    for block in range(n_blocks):
        for c in range(n_channels):
            total = 0.0
            for i in range(block * BLOCK, min((block + 1) * BLOCK, n_rows)):
                total += a[i, c] * b[i, c]
            partial[block, c] = total


@numba.njit(cache=True)
def _dots(a, b, partial, out):
    """out[c] = sum_i a[i, c] b[i, c], summed block by block in order."""
    _block_dots(a, b, partial)
    for c in range(out.shape[0]):
        total = 0.0
        for block in range(partial.shape[0]):
            total += partial[block, c]
        out[c] = total


@numba.njit(cache=True)
def _update_dots(x, residual, direction, ad, step, inverse, z, partial, out):
    """Step x += step d, r -= step A d, z = M^-1 r (one step per channel), and out[c] = sum_i r[i, c] z[i, c].

    The sums as `_dots` makes them (per block of rows, then over the blocks in order), in the same pass.
    """
    n_rows, n_channels = x.shape
    for block in range(partial.shape[0]):
        for c in range(n_channels):
            partial[block, c] = 0.0
        for i in range(block * BLOCK, min((block + 1) * BLOCK, n_rows)):
            for c in range(n_channels):
                x[i, c] += step[c] * direction[i, c]
                residual[i, c] -= step[c] * ad[i, c]
                z[i, c] = inverse[i, c] * residual[i, c]
                partial[block, c] += residual[i, c] * z[i, c]
    for c in range(n_channels):
        total = 0.0
        for block in range(partial.shape[0]):
            total += partial[block, c]
        out[c] = total


@numba.njit(cache=True)
def _new_direction(direction, z, beta):
    n_rows, n_channels = direction.shape
    for i in range(n_rows):
        for c in range(n_channels):
            direction[i, c] = z[i, c] + beta[c] * direction[i, c]


@numba.njit(cache=True, nogil=True)
def conjugate_gradients(indptr, indices, robust, degree, diagonal, rhs, x, iterations,
                        tolerance):
    """Solve (diag(diagonal_c) + D - W) x_c = rhs_c in place from the given x (Jacobi-preconditioned CG).

    Stops after ``iterations`` or where every channel's preconditioned residual norm falls below
    ``tolerance`` times its right-hand side's.
    """
    n_rows, n_channels = x.shape
    n_blocks = max((n_rows + BLOCK - 1) // BLOCK, 1)
    partial = np.empty((n_blocks, n_channels))
    inverse = np.empty_like(x)
    for i in range(n_rows):
        for c in range(n_channels):
            inverse[i, c] = 1.0 / (diagonal[i, c] + degree[i])
    residual = np.empty_like(x)
    _apply(indptr, indices, robust, degree, diagonal, x, residual)
    for i in range(n_rows):
        for c in range(n_channels):
            residual[i, c] = rhs[i, c] - residual[i, c]
    z = inverse * residual
    direction = z.copy()
    ad = np.empty_like(x)
    rz = np.empty(n_channels)
    stop = np.empty(n_channels)
    scaled = inverse * rhs
    _dots(rhs, scaled, partial, stop)
    for c in range(n_channels):
        stop[c] = tolerance * tolerance * max(stop[c], 1e-300)
    _dots(residual, z, partial, rz)
    curvature = np.empty(n_channels)
    step = np.empty(n_channels)
    beta = np.empty(n_channels)
    rz_next = np.empty(n_channels)
    for _ in range(iterations):
        active = False
        for c in range(n_channels):
            if rz[c] > stop[c]:
                active = True
        if not active:
            break
        _apply(indptr, indices, robust, degree, diagonal, direction, ad)
        _dots(direction, ad, partial, curvature)
        for c in range(n_channels):
            step[c] = rz[c] / max(curvature[c], 1e-300) if rz[c] > 0.0 else 0.0
        _update_dots(x, residual, direction, ad, step, inverse, z, partial, rz_next)
        for c in range(n_channels):
            beta[c] = rz_next[c] / max(rz[c], 1e-300) if rz[c] > 0.0 else 0.0
            rz[c] = rz_next[c]
        _new_direction(direction, z, beta)
    return x
