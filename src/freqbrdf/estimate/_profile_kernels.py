"""The profiled loss's minimisers, for the search kernels (docs/method.md#estimation).

Brent's bounded minimiser in reverse communication, and the closed-form base colour with the
metallic profiled out by a grid and safeguarded Newton.
"""

from __future__ import annotations

import math

import numpy as np

from freqbrdf.model._kernels import borrowing_jit

_BRENT_MAX_EVALS = 60


# Brent's bounded minimiser (golden section with parabolic steps, as scipy's fminbound) in
# reverse communication: the caller evaluates the objective, so no function is passed around
# (numba cannot cache functions taking functions). State slots of a (12,) float64 array:
_LO, _HI, _X, _FX, _W, _FW, _V, _FV, _STEP, _PREV_STEP, PROBE, _EVALS, _XTOL = range(13)
_GOLDEN = 0.5 * (3.0 - math.sqrt(5.0))
_SQRT_EPS = math.sqrt(2.2e-16)


@borrowing_jit
def brent_start(state, lower, upper, xtol):
    """Begin minimising on [lower, upper] to absolute tolerance xtol; return the first point to evaluate."""
    state[_LO], state[_HI], state[_XTOL] = lower, upper, xtol
    state[PROBE] = lower + _GOLDEN * (upper - lower)
    state[_STEP] = state[_PREV_STEP] = 0.0
    state[_EVALS] = 0.0
    return state[PROBE]


@borrowing_jit
def brent_seed(state, lower, upper, xtol, x, fx, w, fw, v, fv):
    """Begin minimising on [lower, upper] from three evaluated points.

    x the best, w the second best, v the third (a bracketing grid's node and its neighbours), so
    that the first step is the parabola through them rather than golden steps that re-discover them.
    Returns True with the first point to evaluate in state[PROBE], or False when the bracket is
    already within tolerance (the best point is state[_X]).
    """
    state[_LO], state[_HI], state[_XTOL] = lower, upper, xtol
    state[_X], state[_FX], state[_W], state[_FW], state[_V], state[_FV] = x, fx, w, fw, v, fv
    # As if golden steps of the bracket's size had led here: the parabola may take any step
    # that stays inside (Brent accepts one below half the step before last).
    state[_STEP] = state[_PREV_STEP] = upper - lower
    state[_EVALS] = 3.0
    return _brent_propose(state)


@borrowing_jit
def brent_next(state, f_probe):
    """Take f at the last point; return True with the next point in state[PROBE], or False when done.

    When done, the best point is state[_X] with value state[_FX].
    """
    a, b, u = state[_LO], state[_HI], state[PROBE]
    if state[_EVALS] == 0.0:
        state[_X] = state[_W] = state[_V] = u
        state[_FX] = state[_FW] = state[_FV] = f_probe
    else:
        x, fx, w, fw, v, fv = state[_X], state[_FX], state[_W], state[_FW], state[_V], state[_FV]
        if f_probe <= fx:
            if u >= x:
                a = x
            else:
                b = x
            v, fv, w, fw, x, fx = w, fw, x, fx, u, f_probe
        else:
            if u < x:
                a = u
            else:
                b = u
            if f_probe <= fw or w == x:
                v, fv, w, fw = w, fw, u, f_probe
            elif f_probe <= fv or v == x or v == w:
                v, fv = u, f_probe
        state[_LO], state[_HI] = a, b
        state[_X], state[_FX], state[_W], state[_FW], state[_V], state[_FV] = x, fx, w, fw, v, fv
    state[_EVALS] += 1.0
    return _brent_propose(state)


@borrowing_jit
def _brent_propose(state):
    """Put the next point to evaluate into state[PROBE] and return True, or return False when converged."""
    a, b = state[_LO], state[_HI]
    x, fx, w, fw, v, fv = state[_X], state[_FX], state[_W], state[_FW], state[_V], state[_FV]
    middle = 0.5 * (a + b)
    tol1 = _SQRT_EPS * abs(x) + state[_XTOL] / 3.0
    tol2 = 2.0 * tol1
    if abs(x - middle) <= tol2 - 0.5 * (b - a) or state[_EVALS] >= _BRENT_MAX_EVALS:
        return False
    step, previous_step = state[_STEP], state[_PREV_STEP]
    use_golden = True
    if abs(previous_step) > tol1:  # try the parabola through x, w, v
        r = (x - w) * (fx - fv)
        q = (x - v) * (fx - fw)
        p = (x - v) * q - (x - w) * r
        q = 2.0 * (q - r)
        if q > 0.0:
            p = -p
        q = abs(q)
        older_step = previous_step
        previous_step = step
        if abs(p) < abs(0.5 * q * older_step) and q * (a - x) < p < q * (b - x):
            step = p / q
            use_golden = False
            if (x + step - a) < tol2 or (b - x - step) < tol2:
                step = tol1 if middle >= x else -tol1
    if use_golden:
        previous_step = (a - x) if x >= middle else (b - x)
        step = _GOLDEN * previous_step
    state[_STEP], state[_PREV_STEP] = step, previous_step
    state[PROBE] = x + (step if abs(step) >= tol1 else (tol1 if step >= 0.0 else -tol1))
    return True


# Safeguarded Newton on the metallic: steps stop below this, and after this many iterations.
_NEWTON_MTOL = 1e-10
_NEWTON_MAX_STEPS = 40


@borrowing_jit
def metallic_quadratics(moments, squared_values, diffuse_scale, quadratics):
    """Write the loss per channel as q2 b^2 + 2 q1 b + q0 with q2, q1, q0 quadratics in the metallic m.

    quadratics (3, 3, 3) receives [channel, (q2, q1, q0), coefficient of (1, m, m^2)]. L = b P + Q
    with P = m X + (1 - m) e D, Q = m Y + (1 - m) Z (X = A S, Y = B S, Z = E S, e = E / pi);
    moments (3, 14) per channel: the weighted sums s_xd, s_yd, s_zd, s_xx, s_xy, s_xz, s_xf, s_yy,
    s_yz, s_yf, s_zz, s_zf, s_dd, s_fd (s_ab = sum_v w^2 a b), squared_values (3,) s_ff.
    """
    # Whole indices, no row views: a view costs a reference count update (an atomic) in numba,
    # and these run at every probe.
    for c in range(3):
        s_xd, s_yd, s_zd, s_xx, s_xy = moments[c, 0], moments[c, 1], moments[c, 2], moments[c, 3], moments[c, 4]
        s_xz, s_xf, s_yy, s_yz, s_yf = moments[c, 5], moments[c, 6], moments[c, 7], moments[c, 8], moments[c, 9]
        s_zz, s_zf, s_dd, s_fd = moments[c, 10], moments[c, 11], moments[c, 12], moments[c, 13]
        e = diffuse_scale[c]
        q = quadratics
        q[c, 0, 0] = e * e * s_dd  # sum w P^2
        q[c, 0, 1] = 2.0 * e * (s_xd - e * s_dd)
        q[c, 0, 2] = s_xx - 2.0 * e * s_xd + e * e * s_dd
        q[c, 1, 0] = e * (s_zd - s_fd)  # sum w P (Q - f)
        q[c, 1, 1] = s_xz - s_xf + e * (s_yd - 2.0 * s_zd + s_fd)
        q[c, 1, 2] = s_xy - s_xz + e * (s_zd - s_yd)
        q[c, 2, 0] = s_zz - 2.0 * s_zf + squared_values[c]  # sum w (Q - f)^2
        q[c, 2, 1] = 2.0 * (s_yz - s_zz - s_yf + s_zf)
        q[c, 2, 2] = s_yy - 2.0 * s_yz + s_zz


@borrowing_jit
def metallic_terms(metallic, quadratics, state):
    """Return the loss at the best base colour for a metallic, and its first two derivatives in it.

    Summed over channels; writes that base colour and the metallic into state[:4]. Per channel the
    loss is q2 b^2 + 2 q1 b + q0 (`metallic_quadratics`). At the optimal (or clipped) b the first
    derivative is the partial one at fixed b (envelope theorem); the second adds the change of the
    unclipped b with m.
    """
    m = metallic
    total = gradient = curvature = 0.0
    q = quadratics
    for c in range(3):  # whole indices: see `metallic_quadratics`
        q2 = q[c, 0, 0] + m * (q[c, 0, 1] + m * q[c, 0, 2])
        q2_1 = q[c, 0, 1] + 2.0 * m * q[c, 0, 2]
        q2_2 = 2.0 * q[c, 0, 2]
        q1 = q[c, 1, 0] + m * (q[c, 1, 1] + m * q[c, 1, 2])
        q1_1 = q[c, 1, 1] + 2.0 * m * q[c, 1, 2]
        q1_2 = 2.0 * q[c, 1, 2]
        q0 = q[c, 2, 0] + m * (q[c, 2, 1] + m * q[c, 2, 2])
        q0_1 = q[c, 2, 1] + 2.0 * m * q[c, 2, 2]
        q0_2 = 2.0 * q[c, 2, 2]
        base = -q1 / q2 if q2 > 0.0 else 0.0
        interior = 0.0 < base < 1.0
        base = min(max(base, 0.0), 1.0)  # a 1-D convex quadratic: clip
        total += (q2 * base + 2.0 * q1) * base + q0
        slope = q2_1 * base + q1_1  # d b / d m = -slope / q2 where b is not clipped
        gradient += (q2_1 * base + 2.0 * q1_1) * base + q0_1
        curvature += (q2_2 * base + 2.0 * q1_2) * base + q0_2
        if interior:
            curvature -= 2.0 * slope * slope / q2
        state[c] = base
    state[3] = m
    return total, gradient, curvature


@borrowing_jit
def profile_metallic(quadratics, state, metallic_grid):
    """Return min over (b, m) of the loss of fixed `metallic_quadratics`.

    A metallic grid, then safeguarded Newton on the derivative in the best cell (bisection where
    Newton would leave the bracket). Leaves the winner's base colour and metallic in state.
    """
    # Each evaluation also writes its base colour into state: the last one evaluated is tracked so
    # that the winner is re-evaluated only when it is not that one.
    best_m, best_f, slope, curvature = 0.0, np.inf, 0.0, 0.0
    for j in range(metallic_grid):
        m = j / (metallic_grid - 1)
        f, f_slope, f_curvature = metallic_terms(m, quadratics, state)
        if f < best_f:
            best_m, best_f, slope, curvature = m, f, f_slope, f_curvature
    last_m = 1.0  # the grid's last node
    cell = 1.0 / (metallic_grid - 1)
    if (best_m == 0.0 and slope >= 0.0) or (best_m == 1.0 and slope <= 0.0) or slope == 0.0:
        # A pure dielectric or a pure metal (or a node exactly at the minimum).
        return best_f if last_m == best_m else metallic_terms(best_m, quadratics, state)[0]
    # The minimum lies on the downhill side of the best node, within one cell.
    lower, upper = (best_m, min(best_m + cell, 1.0)) if slope < 0.0 else (max(best_m - cell, 0.0), best_m)
    m = best_m
    for _ in range(_NEWTON_MAX_STEPS):
        step = -slope / curvature if curvature > 0.0 else np.inf
        candidate = m + step
        if not (lower < candidate < upper):
            candidate = 0.5 * (lower + upper)
        if abs(candidate - m) < _NEWTON_MTOL:
            break
        m = candidate
        f_m, slope, curvature = metallic_terms(m, quadratics, state)
        last_m = m
        if f_m < best_f:
            best_m, best_f = m, f_m
        if slope < 0.0:
            lower = m
        elif slope > 0.0:
            upper = m
        else:
            break
        if upper - lower < _NEWTON_MTOL:
            break
    return best_f if last_m == best_m else metallic_terms(best_m, quadratics, state)[0]
