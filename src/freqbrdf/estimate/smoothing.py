"""The whole-surface solve's smoothing along the surface, and what it gives texels no view sees.

`smooth_on_surface` holds each texel's value by its precision and couples it to its neighbours
(docs/method.md#whole-surface-estimate, M13); texels without data take the solve's values, taken
towards their UV chart's mean (`chart_prior`) as far as held-out texels show the solve does not
carry (`shrink_unseen_to_charts`, M23). Used by `freqbrdf.estimate.surface.whole_surface`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from freqbrdf.config import SurfaceConfig
from freqbrdf.estimate._surface_kernels import conjugate_gradients, huber_weights
from freqbrdf.model.materials import UNIFORM_VARIANCE

__all__ = ["CARRY_HOPS", "HELD_OUT_ENOUGH", "HELD_OUT_PER_UNSEEN", "HELD_OUT_SHARE", "MAX_HELD_OUT_HOPS",
           "MIN_CHART_TEXELS", "MIN_HELD_OUT_TEXELS", "PRIOR_PRECISION", "HeldOutTrial", "chart_prior", "held_out_trial",
           "shrink_by_trial", "shrink_unseen_to_charts", "smooth_on_surface"]

# The precision that pins a texel without data to the mean of the estimated texels, relative to
# the coupling: only decides components of the graph that no estimated texel reaches.
PRIOR_PRECISION = 1e-4
# A UV chart with fewer texels with data than this gives its texels without data the mean of all.
MIN_CHART_TEXELS = 8
# How far the solve carries into texels without data is measured by holding out this share of the
# texels with data, in balls as wide as those texels lie from data, at most this many hops across;
# with fewer held-out texels than MIN_HELD_OUT_TEXELS it is not measured. Where few texels lack data,
# fewer are held out: at most the larger of HELD_OUT_ENOUGH and HELD_OUT_PER_UNSEEN per texel without data.
HELD_OUT_SHARE = 0.15
HELD_OUT_ENOUGH = 2000
HELD_OUT_PER_UNSEEN = 10
MAX_HELD_OUT_HOPS = 32
MIN_HELD_OUT_TEXELS = 20
# The lengths (hops) the extrapolation's decay towards the chart mean is chosen from; inf: no decay.
CARRY_HOPS = np.concatenate([np.geomspace(0.25, 256.0, 41), [np.inf]])
# Conjugate gradients stop where the preconditioned residual norm falls below this share of the right-hand side's.
_CG_TOLERANCE = 1e-4


def chart_prior(values: np.ndarray, has_data: np.ndarray, charts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Give each texel its UV chart's mean and variance of the values of the texels with data.

    Charts usually follow an object's parts, so a texel no view sees is most like the seen texels
    of its own chart. A chart with fewer than `MIN_CHART_TEXELS` texels with data takes the mean
    and variance of all of them.

    Parameters
    ----------
    values : (N, C) float64
        The per-texel values.
    has_data : (N,) bool
        The texels whose values count.
    charts : (N,) int64
        Each texel's chart (0, 1, ...).

    Returns
    -------
    mean, variance : (N, C) float64
        Per texel, its chart's.
    """
    n_charts = int(charts.max()) + 1 if charts.size else 0
    counts = np.bincount(charts[has_data], minlength=n_charts).astype(np.float64)
    data = values[has_data]
    overall_mean, overall_variance = data.mean(axis=0), data.var(axis=0)
    means = np.empty((n_charts, values.shape[1]))
    variances = np.empty((n_charts, values.shape[1]))
    for c in range(values.shape[1]):
        sums = np.bincount(charts[has_data], data[:, c], minlength=n_charts)
        squares = np.bincount(charts[has_data], data[:, c] ** 2, minlength=n_charts)
        safe = np.maximum(counts, 1.0)
        means[:, c] = sums / safe
        variances[:, c] = np.maximum(squares / safe - means[:, c] ** 2, 0.0)
    few = counts < MIN_CHART_TEXELS
    means[few], variances[few] = overall_mean, overall_variance
    return means[charts], variances[charts]


def smooth_on_surface(values: np.ndarray, precision: np.ndarray, graph: sparse.csr_matrix, smoothing: float,
                      huber: float, settings: SurfaceConfig) -> tuple[np.ndarray, np.ndarray]:
    """Solve for values held by their precision and coupled to their neighbours (Huber, IRLS).

    Minimises sum_t P_t |x_t - v_t|^2 + lambda sum_ij w_ij rho(|x_i - x_j|), rho Huber's with
    threshold ``huber`` on the channels' Euclidean difference, lambda = ``smoothing`` x the median
    precision of the texels with data; ``smoothing_passes`` re-weightings, each solved by
    conjugate gradients (Jacobi preconditioner, ``cg_iterations``). Texels without data
    (P = 0) take the solve's values; a component of the graph without data, the precision-weighted
    mean of all data.

    Parameters
    ----------
    values : (N, C) array
        The per-texel values (ignored where the precision is 0).
    precision : (N, C) array
        Their precisions (1 / variance).
    graph : (N, N) scipy.sparse.csr_matrix
        `surface_graph`'s weights.
    smoothing : float
        The coupling relative to the median precision.
    huber : float
        Huber's threshold on neighbour differences.
    settings : SurfaceConfig
        ``smoothing_passes``, ``cg_iterations`` and ``std_scale``.

    Returns
    -------
    solution : (N, C) float64
        The smoothed values.
    std : (N, C) float64
        s / sqrt(P_t + lambda sum_j w_ij) per texel and channel, s^2 the mean of P_t (v_t - x_t)^2
        over the texels with data (how far they scatter about the solution for their
        precision); texels without data add s^2 / lambda per hop from the nearest texel with data,
        up to the variance of a value uniform on [0, 1] (`freqbrdf.model.materials.UNIFORM_VARIANCE`:
        nothing known); times ``std_scale``.
    """
    values = np.nan_to_num(np.asarray(values, np.float64))
    precision = np.maximum(np.asarray(precision, np.float64), 0.0)
    has_data = precision.sum(axis=1) > 0
    if not has_data.any():
        return values.copy(), np.full(values.shape, np.nan)
    scale = float(np.median(precision[has_data].mean(axis=1)))
    coupling = smoothing * scale
    mean = (precision * values).sum(axis=0) / np.maximum(precision.sum(axis=0), 1e-300)
    pin = PRIOR_PRECISION * coupling
    target = np.where(precision > 0, values, mean)
    diagonal_data = precision + pin
    solution = target.copy()
    graph = graph.tocsr()
    hops = None
    if not has_data.all():
        # A texel without data starts from its nearest texel with data (in hops): the solve then
        # only spreads what is near, rather than pulling every such texel from the overall mean.
        hops, _, source = csgraph.dijkstra(graph, unweighted=True, indices=np.flatnonzero(has_data), min_only=True,
                                           return_predecessors=True)
        reached = ~has_data & (source >= 0)
        solution[reached] = values[source[reached]]
    indptr, indices = graph.indptr.astype(np.int64), graph.indices.astype(np.int64)
    weights = graph.data.astype(np.float64)
    robust = np.empty_like(weights)
    robust_degree = np.empty(len(values))
    for _ in range(max(settings.smoothing_passes, 1)):
        huber_weights(indptr, indices, weights, solution, huber, coupling, robust, robust_degree)
        conjugate_gradients(indptr, indices, robust, robust_degree, diagonal_data, diagonal_data * target, solution,
                            settings.cg_iterations, _CG_TOLERANCE)
    degree = np.asarray(graph.sum(axis=1)).ravel() * coupling
    # A texel's variance: its own and its neighbours' precision, s^2 / (P_t + lambda sum_j w_ij), s
    # from how far the texels with data scatter about the solution for their precision; a texel
    # without data adds a neighbour's s^2 / lambda per hop from the nearest texel with data (a
    # random walk's growth), up to the variance of a value nothing is known of.
    calibration = np.mean(((values - solution) ** 2 * precision)[has_data])
    variance = calibration / (precision + degree[:, None] + pin)
    if hops is not None:
        variance = np.minimum(variance + calibration / coupling * np.nan_to_num(hops, posinf=np.inf)[:, None],
                              np.maximum(UNIFORM_VARIANCE, variance))
    return solution, np.sqrt(variance) * settings.std_scale


def shrink_unseen_to_charts(values: np.ndarray, precision: np.ndarray, solution: np.ndarray, graph: sparse.csr_matrix,
                            charts: np.ndarray, smoothing: float, huber: float,
                            settings: SurfaceConfig) -> tuple[np.ndarray, float, np.ndarray]:
    """Take the texels without data towards their UV chart's mean as far as the solve's extrapolation fails.

    How far a solve carries into texels no view sees depends on the surface: a smooth gradient
    holds for tens of texels, a pattern of small cells for one or two. It is measured on the
    capture itself (docs/method.md#whole-surface-estimate, M23): balls of texels with data, as many
    hops across as the texels without data lie from data (their 90th percentile, at most
    `MAX_HELD_OUT_HOPS`), `HELD_OUT_SHARE` of them in all (at most the larger of `HELD_OUT_ENOUGH` and
    `HELD_OUT_PER_UNSEEN` per texel without data), are held out and the solve is run
    again without them (on the balls and the kept texels as many hops around them); at a held-out texel h hops from the data kept, the chart mean of the kept
    texels plus exp(-h / L) times the solve's departure from it predicts the full solve's value,
    and L is chosen (over `CARRY_HOPS`, infinity included) to predict them best in the least-squares
    sense. Each texel without data h hops from the data then becomes its chart's mean of the texels
    with data (`chart_prior`) plus exp(-h / L) times its departure from it, and its std at least the
    root mean square error of that prediction against the held-out texels' own values as far from the
    data kept (never less farther out).

    Parameters
    ----------
    values, precision : (N, C) array
        The solve's data and precisions (`smooth_on_surface`): the texels with data have some
        precision.
    solution : (N, C) float64
        The solve's values (of all the data).
    graph : (N, N) scipy.sparse.csr_matrix
        The surface graph along the mesh (`surface_graph`): texels without data have no look-alikes,
        so the held-out texels are solved along it too.
    charts : (N,) int64
        Each texel's UV chart (`uv_charts`).
    smoothing, huber : float
        The solve's settings (`smooth_on_surface`).
    settings : SurfaceConfig
        The solve's other settings.

    Returns
    -------
    solution : (N, C) float64
        The values; the texels with data unchanged.
    carry_hops : float
        L; inf where the extrapolation holds at every distance measured; NaN where nothing was
        measured (no texel lacks data, or fewer than `MIN_HELD_OUT_TEXELS` could be held out).
    std : (N,) float64
        The held-out error as far from data, for the texels without data; 0 elsewhere and where
        nothing was measured.
    """
    trial = held_out_trial(values, precision, graph, smoothing, huber, settings)
    return shrink_by_trial(trial, values, solution, charts)


class HeldOutTrial(NamedTuple):
    """The trial solve of `held_out_trial`: what `shrink_by_trial` needs besides the whole solve."""

    has_data: np.ndarray  # (N,) bool: some precision
    hops: np.ndarray  # (N,) hops from the nearest texel with data
    reached: np.ndarray  # (N,) bool: without data, connected to data
    radius: int  # the held-out balls' radius
    kept: np.ndarray  # (N,) bool: with data, not held out
    near: np.ndarray  # (M,) int64: the texels of the trial solve
    solution: np.ndarray  # (M, C) its values
    held_hops: np.ndarray  # (M,) hops from the data kept
    scored: np.ndarray  # (M,) bool: held out and reached


def held_out_trial(values: np.ndarray, precision: np.ndarray, graph: sparse.csr_matrix, smoothing: float, huber: float,
                   settings: SurfaceConfig) -> HeldOutTrial | None:
    """Run `shrink_unseen_to_charts`' trial solve without the held-out balls.

    Independent of the whole solve, so that the two can run side by side.

    Parameters
    ----------
    values, precision, graph, smoothing, huber, settings
        As `shrink_unseen_to_charts`: (N, C) data and precisions, the (N, N) surface graph, the solve's settings.

    Returns
    -------
    HeldOutTrial or None
        The trial; None where nothing can be measured (no texel lacks data, none without data is
        connected to data, or fewer than `MIN_HELD_OUT_TEXELS` could be held out or kept).
    """
    has_data = np.asarray(precision).sum(axis=1) > 0
    without = ~has_data
    rows_with = np.flatnonzero(has_data)
    if not without.any() or len(rows_with) < 2 * MIN_HELD_OUT_TEXELS:
        return None
    graph = graph.tocsr()
    hops = csgraph.dijkstra(graph, unweighted=True, indices=rows_with, min_only=True)
    reached = without & np.isfinite(hops)
    if not reached.any():
        return None
    radius = int(np.clip(np.percentile(hops[reached], 90), 1, MAX_HELD_OUT_HOPS))
    target = min(HELD_OUT_SHARE * len(rows_with), max(HELD_OUT_ENOUGH, HELD_OUT_PER_UNSEEN * int(reached.sum())))
    n_balls = int(np.clip(target / (3.0 * radius * radius), 1, len(rows_with)))
    held = _held_out_balls(graph, has_data, radius, n_balls)
    if held.sum() < 0.5 * target:  # balls smaller than guessed (thin parts, borders): more of them
        held = _held_out_balls(graph, has_data, radius, int(np.ceil(n_balls * target / max(held.sum(), 1))))
    kept = has_data & ~held
    if held.sum() < MIN_HELD_OUT_TEXELS or kept.sum() < MIN_HELD_OUT_TEXELS:
        return None
    # The trial solve on the balls and the kept texels within `radius` hops of them: the texels beyond keep
    # their data and barely move the balls' values. Its coupling is the whole solve's (`smooth_on_surface`
    # scales it by the median precision of the texels with data).
    near = np.flatnonzero(np.isfinite(csgraph.dijkstra(graph, unweighted=True, indices=np.flatnonzero(held),
                                                       min_only=True, limit=radius + 0.5)))
    sub_graph = graph[near][:, near]
    sub_precision = np.where(held[near, None], 0.0, precision[near])
    sub_has = sub_precision.sum(axis=1) > 0
    whole_scale = float(np.median(np.asarray(precision)[has_data].mean(axis=1)))
    sub_scale = float(np.median(sub_precision[sub_has].mean(axis=1)))
    trial, _ = smooth_on_surface(values[near], sub_precision, sub_graph, smoothing * whole_scale / sub_scale, huber,
                                 settings)
    held_hops = csgraph.dijkstra(sub_graph, unweighted=True, indices=np.flatnonzero(sub_has), min_only=True)
    return HeldOutTrial(has_data, hops, reached, radius, kept, near, trial, held_hops, held[near] & np.isfinite(held_hops))


def shrink_by_trial(trial: HeldOutTrial | None, values: np.ndarray, solution: np.ndarray,
                    charts: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Finish `shrink_unseen_to_charts` from its trial solve and the whole solve.

    Parameters
    ----------
    trial : HeldOutTrial or None
        `held_out_trial` of the same values, precisions and graph.
    values : (N, C) array
        The solve's data.
    solution : (N, C) float64
        The whole solve's values (`smooth_on_surface`).
    charts : (N,) int64
        Each texel's UV chart (`uv_charts`).

    Returns
    -------
    solution : (N, C) float64
        The values; the texels with data unchanged.
    carry_hops : float
        L (`shrink_unseen_to_charts`); NaN where ``trial`` is None.
    std : (N,) float64
        The held-out error as far from data, for the texels without data; 0 elsewhere.
    """
    if trial is None:
        return solution, float("nan"), np.zeros(len(solution))
    has_data, hops, reached, radius, kept, near, trial_solution, held_hops, scored = trial
    kept_mean, _ = chart_prior(solution, kept, charts)
    departure = trial_solution[scored] - kept_mean[near][scored]
    target_departure = solution[near][scored] - kept_mean[near][scored]
    costs = [np.sum((np.exp(-held_hops[scored] / length)[:, None] * departure - target_departure) ** 2)
             for length in CARRY_HOPS]
    length = float(CARRY_HOPS[int(np.argmin(costs))])
    # How far off that prediction is from the held-out texels' own values, by hops from the data kept
    # (never nearer data surer): the std of a texel without data as far from data.
    predicted = kept_mean[near][scored] + np.exp(-held_hops[scored] / length)[:, None] * departure
    squared = np.mean((predicted - np.asarray(values, np.float64)[near][scored]) ** 2, axis=1)
    by_hop = np.clip(held_hops[scored], 1, radius).astype(np.int64)
    counts = np.bincount(by_hop, minlength=radius + 1)[1:]
    sums = np.bincount(by_hop, squared, minlength=radius + 1)[1:]
    error = np.sqrt(np.maximum.accumulate(np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)))
    mean, _ = chart_prior(solution, has_data, charts)
    shrunk = solution.copy()
    shrunk[reached] = mean[reached] + np.exp(-hops[reached] / length)[:, None] * (solution[reached] - mean[reached])
    std = np.zeros(len(solution))
    std[reached] = error[np.clip(hops[reached], 1, radius).astype(np.int64) - 1]
    return shrunk, length, std


def _held_out_balls(graph: sparse.csr_matrix, has_data: np.ndarray, radius: int, n_balls: int) -> np.ndarray:
    """(N,) bool: the texels with data within ``radius`` hops of n_balls centres spread evenly over them."""
    rows_with = np.flatnonzero(has_data)
    n_balls = min(n_balls, len(rows_with))
    centres = rows_with[(np.arange(n_balls) * len(rows_with)) // n_balls + len(rows_with) // (2 * n_balls)]
    reach = csgraph.dijkstra(graph, unweighted=True, indices=centres, min_only=True, limit=radius + 0.5)
    return np.isfinite(reach) & has_data
