"""The numba kernels of the calibration (docs/method.md#calibration): texels' losses over a grid of gains."""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(fastmath=False, cache=True)
def _label_loss(sums, label, inverse, gain):
    """(loss, base colour) of a pure material (label 0: dielectric, 1: metal) on the data f / gain.

    sums (16,): the search's weighted sums of one channel (`freqbrdf.estimate.label_sums`); the
    loss is q2 b^2 + 2 q1 b + q0 at the best b in [0, 1], times gain^2 (the photographs' units).
    """
    if label == 0:
        e = sums[15]
        q2 = e * e * sums[12]
        q1 = e * (sums[2] - sums[13] * inverse)
        q0 = sums[10] - 2.0 * sums[11] * inverse + sums[14] * inverse * inverse
    else:
        q2 = sums[3]
        q1 = sums[4] - sums[6] * inverse
        q0 = sums[7] - 2.0 * sums[9] * inverse + sums[14] * inverse * inverse
    base = -q1 / q2 if q2 > 0.0 else 0.0
    base = min(max(base, 0.0), 1.0)
    return max((q2 * base + 2.0 * q1) * base + q0, 0.0) * gain * gain, base


@numba.njit(parallel=True, fastmath=False, cache=True)
def texel_gain_curves(sums, log_gain, curves, choice):
    """Write each texel's least loss over roughness slots and labels at every gain (numba, parallel).

    sums (N, S, 3, 16); log_gain (G,); curves (N, G) receives the channel-summed loss over the
    texel's radiance sum_c s_ff; choice (N, G) the winning slot * 2 + label.
    """
    n_texels, n_slots = sums.shape[0], sums.shape[1]
    for t in numba.prange(n_texels):
        radiance = max(sums[t, 0, 0, 14] + sums[t, 0, 1, 14] + sums[t, 0, 2, 14], 1e-30)
        for g in range(log_gain.shape[0]):
            gain = math.exp(log_gain[g])
            inverse = 1.0 / gain
            best, winner = np.inf, 0
            for slot in range(n_slots):
                for label in range(2):
                    total = 0.0
                    for c in range(3):
                        total += _label_loss(sums[t, slot, c], label, inverse, gain)[0]
                    if total < best:
                        best, winner = total, slot * 2 + label
            curves[t, g] = best / radiance
            choice[t, g] = winner


@numba.njit(parallel=True, fastmath=False, cache=True)
def channel_gain_curves(sums, log_gain, choice, curves, base):
    """Write each texel's loss per channel over the gains at one slot and label (numba, parallel).

    sums (N, S, 3, 16); log_gain (G,); choice (N,) slot * 2 + label; curves (N, G, 3) receives the
    loss over the texel's radiance, base (N, G, 3) the base colour.
    """
    for t in numba.prange(sums.shape[0]):
        radiance = max(sums[t, 0, 0, 14] + sums[t, 0, 1, 14] + sums[t, 0, 2, 14], 1e-30)
        slot, label = choice[t] // 2, choice[t] % 2
        for g in range(log_gain.shape[0]):
            gain = math.exp(log_gain[g])
            for c in range(3):
                loss, colour = _label_loss(sums[t, slot, c], label, 1.0 / gain, gain)
                curves[t, g, c] = loss / radiance
                base[t, g, c] = colour


@numba.njit(fastmath=False, cache=True)
def _inside_triangle(x, y, ax, ay, bx, by, cx, cy):
    d0 = (bx - ax) * (y - ay) - (by - ay) * (x - ax)
    d1 = (cx - bx) * (y - by) - (cy - by) * (x - bx)
    d2 = (ax - cx) * (y - cy) - (ay - cy) * (x - cx)
    return (d0 >= 0.0 and d1 >= 0.0 and d2 >= 0.0) or (d0 <= 0.0 and d1 <= 0.0 and d2 <= 0.0)


@numba.njit(fastmath=False, cache=True)
def _face_cells(pixels, a, b, c, height, width):
    """Return the pixel columns and rows a projected face's bounding box meets: col0, col1, row0, row1."""
    col0 = max(int(math.floor(min(pixels[a, 0], pixels[b, 0], pixels[c, 0]))), 0)
    col1 = min(int(math.floor(max(pixels[a, 0], pixels[b, 0], pixels[c, 0]))), width - 1)
    row0 = max(int(math.floor(min(pixels[a, 1], pixels[b, 1], pixels[c, 1]))), 0)
    row1 = min(int(math.floor(max(pixels[a, 1], pixels[b, 1], pixels[c, 1]))), height - 1)
    return col0, col1, row0, row1


@numba.njit(fastmath=False, cache=True, nogil=True)
def covered_points(queries, skip, pixels, in_front, faces, used, height, width):
    """Whether a projected face covers each query point (exactly, not at pixel resolution).

    queries (M, 2) x, y in pixels; skip (M, 2) faces not to test for each (-1: none); pixels
    (n_vertices, 2) and in_front (n_vertices,) the projected vertices; faces (F, 3), of which
    only the ``used`` (F,) bool are tested. Returns (M,) bool. Faces are binned first into the
    pixels the queries lie in (faces with a vertex behind the camera are left out).
    """
    # Only the pixels a query lies in are binned: the faces far from every query are passed over.
    wanted = np.zeros(height * width, np.bool_)
    for m in range(queries.shape[0]):
        col, row = int(math.floor(queries[m, 0])), int(math.floor(queries[m, 1]))
        if 0 <= col < width and 0 <= row < height:
            wanted[row * width + col] = True
    counts = np.zeros(height * width + 1, np.int64)
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        if used[f] and in_front[a] and in_front[b] and in_front[c]:
            col0, col1, row0, row1 = _face_cells(pixels, a, b, c, height, width)
            for row in range(row0, row1 + 1):
                for col in range(col0, col1 + 1):
                    if wanted[row * width + col]:
                        counts[row * width + col + 1] += 1
    for cell in range(height * width):
        counts[cell + 1] += counts[cell]
    filled = counts[:-1].copy()
    binned = np.empty(counts[-1], np.int64)
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        if used[f] and in_front[a] and in_front[b] and in_front[c]:
            col0, col1, row0, row1 = _face_cells(pixels, a, b, c, height, width)
            for row in range(row0, row1 + 1):
                for col in range(col0, col1 + 1):
                    if wanted[row * width + col]:
                        binned[filled[row * width + col]] = f
                        filled[row * width + col] += 1
    result = np.zeros(queries.shape[0], np.bool_)
    for m in range(queries.shape[0]):
        x, y = queries[m, 0], queries[m, 1]
        col, row = int(math.floor(x)), int(math.floor(y))
        if col < 0 or row < 0 or col >= width or row >= height:
            continue
        cell = row * width + col
        for k in range(counts[cell], counts[cell + 1]):
            f = binned[k]
            if f == skip[m, 0] or f == skip[m, 1]:
                continue
            a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
            if _inside_triangle(x, y, pixels[a, 0], pixels[a, 1], pixels[b, 0], pixels[b, 1],
                                pixels[c, 0], pixels[c, 1]):
                result[m] = True
                break
    return result
