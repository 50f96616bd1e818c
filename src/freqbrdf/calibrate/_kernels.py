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
