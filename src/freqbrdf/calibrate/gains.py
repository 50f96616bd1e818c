"""Exposure and white balance: the gain per colour channel between the photographs and the map.

docs/method.md#calibration. Photographs at gain g_c of the map's scale make every texel's
radiance g_c times what the map predicts. A free base colour absorbs that for a metal, but not for
a dielectric: its specular reflectance is fixed (F0 = 0.04), so only the right gain lets its
diffuse and its specular agree, and a base colour cannot exceed 1. Over thousands of texels this
fixes three numbers.

`channel_gains` scores a gain per texel by its misfit as the best *pure* material (dielectric or
metal), in the photographs' units, relative to its own radiance. The search records per texel and
channel the weighted sums the two labels' losses come from, at the estimated roughness and at a
grid of roughness nodes (`freqbrdf.estimate.label_sums`), so the misfit of any gain is closed form
(`freqbrdf.calibrate._kernels`). Each texel's minimiser over a grid of log gains is its own
estimate. The exposure is their median, one vote a texel (their readings scatter by the model's
misfit, which a texel's own precision does not see); the white-balance ratios, in which what the
channels share cancels, are medians weighted by each texel's curvature over its misfit. Their std
adds the model's own misfit on calibrated captures, and a prior of one log unit keeps a gain the
texels do not determine (an all-metal object) near 1.

`frame_gains` compares the photographs two by two, on the texels both see from nearby directions
(where a texel shows about the same radiance to both, whatever its material), and solves for one
gain per photograph that explains every pair's ratio, for captures whose frames are exposed
differently.

The decision rules (`_significant`, `_significant_frames`, `_decision_log_std`): each gain is
either exactly 1 or off by a normal amount (spike and slab), applied where the texels make "off"
the likelier, and the error of that decision's outcome.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from freqbrdf.calibrate._kernels import channel_gain_curves, texel_gain_curves

__all__ = ["GainEstimate", "channel_gains", "frame_gains"]

# The prior on log gain: a photograph and its probe within a factor e of each other (1 sigma).
PRIOR_LOG_STD = 1.0
# Each texel's log-gain grid: a factor 4 either way, in steps of about 3.5 %. A texel whose minimum
# lies on the grid's edge says nothing; wider grids let in texels whose minimum is the model's misfit
# (docs/results.md#calibration).
LOG_GAIN_GRID = np.log(2.0) * np.arange(-2.0, 2.0001, 0.05)
# Two photographs' ratio is read on the texels both see from directions at most this far apart (degrees)
# and where there are at least FRAME_PAIR_TEXELS of them (docs/results.md#calibration).
FRAME_PAIR_DEG = 40.0
FRAME_PAIR_TEXELS = 10
# The std of the exposure and of a white-balance ratio that the model's own misfit gives on a
# calibrated capture, added to the texels' spread (docs/results.md#calibration: the clean scenes').
MODEL_EXPOSURE_LOG_STD = 0.10
MODEL_RATIO_LOG_STD = 0.03
# How far a probe's exposure and white balance are from the photographs' when they are not equal (1
# sigma, in log): the exposure within a factor e (`PRIOR_LOG_STD`), each
# white-balance ratio within 10 % (a probe shot with another camera or another white-balance
# setting). Each is applied where the texels say it is more likely off than exactly 1
# (`_significant`).
WHITE_BALANCE_PRIOR_LOG_STD = 0.1
# A photograph's exposure against the others' is either the same or off by a normal amount of this std
# (in log: auto-exposure moves it by a stop or so); the pairs' own misfit on photographs exposed alike
# (the view dependence between nearby directions) adds FRAME_MODEL_LOG_STD to each frame's std
# (docs/results.md#calibration).
FRAME_PRIOR_LOG_STD = 0.7
FRAME_MODEL_LOG_STD = 0.10
# A texel's misfit floor in the white-balance ratios' weights, as a share of the texels' median misfit:
# a near-exact fit does not take over.
MISFIT_FLOOR = 0.05
# Texels estimated rougher than this do not calibrate: their lobe is not told apart from the diffuse.
MAX_ROUGHNESS = 0.6
# A base colour at or above this is at its bound: the loss's minimum is the bound's kink.
BASE_BOUND = 0.98


@dataclass
class GainEstimate:
    """Gains per colour channel and how well the texels determine them.

    Attributes
    ----------
    gain : (3,) float64
        The photographs' radiance over the map's per channel: divide the photographs by it.
    log_std : (3,) float64
        Std of log gain (posterior, with the prior of `PRIOR_LOG_STD`).
    texels : int
        Texels whose own data determine a gain (a minimum inside the grid).
    exposure_log_std : float
        Std of the log of the gains' geometric mean (the exposure).
    ratio_log_std : (3,) float64
        Std of each channel's log ratio to it (the white balance).
    """

    gain: np.ndarray
    log_std: np.ndarray
    texels: int
    exposure_log_std: float = PRIOR_LOG_STD
    ratio_log_std: np.ndarray = field(default_factory=lambda: np.full(3, PRIOR_LOG_STD))


def slab_log_odds(value, std, prior_std):
    """Return the log odds of "off by a normal amount of std ``prior_std``" over "exactly 0" for a measurement.

    The spike-and-slab rule of the calibration (docs/method.md#calibration): ``value`` measured with
    ``std`` (elementwise) is N(0, std^2) under the spike and N(0, std^2 + prior_std^2) under the slab.

    Parameters
    ----------
    value, std : float or array
        The measurement (a log gain, a turn about an axis) and its std.
    prior_std : float
        The slab's std.

    Returns
    -------
    float64 array
        ln N(value; 0, std^2 + prior_std^2) - ln N(value; 0, std^2), elementwise.
    """
    variance = np.maximum(np.asarray(std, np.float64) ** 2, 1e-24)
    slab = prior_std ** 2
    return 0.5 * np.asarray(value, np.float64) ** 2 / variance * slab / (slab + variance) - 0.5 * np.log1p(slab / variance)


def _grid_minimum(values: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Find each row's minimum of ``values`` (n, G) on the grid.

    Returns the parabola's minimiser through the best node and its neighbours, its value, its
    curvature and whether the best node is inside the grid (with a positive curvature).
    """
    best = np.argmin(values, axis=1)
    inside = (best > 0) & (best < len(grid) - 1)
    index = np.clip(best, 1, len(grid) - 2)
    rows = np.arange(len(values))
    left, centre, right = values[rows, index - 1], values[rows, index], values[rows, index + 1]
    spacing = grid[1] - grid[0]
    curvature = (left - 2.0 * centre + right) / spacing ** 2
    usable = inside & (curvature > 0.0)
    shift = np.where(usable, 0.5 * spacing * (left - right) / np.where(usable, left - 2.0 * centre + right, 1.0), 0.0)
    minimum = centre - 0.125 * np.where(usable, (left - right) ** 2 / np.where(usable, left - 2 * centre + right, 1), 0)
    return grid[index] + shift, minimum, np.where(usable, curvature, 0.0), usable


def channel_gains(moments: np.ndarray, roughness: np.ndarray | None = None,
                  model_exposure_log_std: float = MODEL_EXPOSURE_LOG_STD) -> GainEstimate:
    """Estimate the gain per colour channel from the texels' label sums.

    Each texel's label (dielectric or metal) is the one that fits it best at its best gain. With
    that label, its loss summed over the channels over `LOG_GAIN_GRID` gives the texel's own log
    gain (the parabola through its grid minimum); each channel's loss alone gives the texel's log
    gain of that channel, taken relative to its common one (a white-balance ratio, in which what the
    channels share cancels). The exposure is the median of the texels' common log gains, every texel
    one vote: the readings scatter by the model's misfit far beyond what a texel's own curvature
    says, and weighting by it lets the few texels the model fits most sharply decide
    (docs/results.md#calibration). A texel whose base colour reaches 1 at its best gain reads the
    bound's kink: its samples alone would read a lower gain, but no base colour exceeds 1, so the
    gain is at least the kink's. In the median it votes on the side of the kink it lies on (a
    censored median); left out, the bright texels' low readings went missing and the exposure
    walked upwards pass after pass (docs/results.md#calibration). Each channel's ratio is the median
    of theirs weighted by the texel's curvature over its misfit (an inverse variance), normalised to
    a geometric mean of 1, over the texels whose base colour lies inside its bounds (a channel at
    its kink says nothing of its ratio). A texel says nothing where its loss has no minimum inside
    the grid (a metal, whose free base colour takes any gain) or where its estimated roughness is
    above `MAX_ROUGHNESS` (a lobe that wide is not told apart from the diffuse: rough dielectrics
    bias the gains). Each texel's loss at
    a gain is its least over the roughness slots and the two labels, so that a gain is not judged at
    a roughness found under another. The std is the (weighted) spread over the square root of the
    (effective) number of texels with `MODEL_EXPOSURE_LOG_STD` (`MODEL_RATIO_LOG_STD`) added in
    quadrature, and the prior of `PRIOR_LOG_STD` keeps a gain that few texels determine near 1.

    Parameters
    ----------
    moments : (N, S, 3, 16) float64
        The search's label sums per texel at its estimated roughness (slot 0) and at S - 1
        roughness nodes evenly on [0, 1] (`freqbrdf.estimate.label_sums`); texels without sums
        are left out.
    roughness : (N,) float64, optional
        The texels' estimated roughness (slot 0's); None: slot 0 is not used.
    model_exposure_log_std : float, optional
        The exposure's std that the model's misfit gives on calibrated captures (added to the
        texels' spread): `MODEL_EXPOSURE_LOG_STD` on every texel, less on the dielectrics of
        `freqbrdf.calibrate` (``DIELECTRIC_EXPOSURE_LOG_STD``).

    Returns
    -------
    GainEstimate
        The gains and their std.
    """
    moments = np.ascontiguousarray(moments, np.float64)
    n_slots = moments.shape[1]
    slot_roughness = np.empty((len(moments), n_slots))
    slot_roughness[:, 0] = np.inf if roughness is None else roughness
    slot_roughness[:, 1:] = np.linspace(0.0, 1.0, n_slots - 1)
    scored = moments[:, 0, :, 14].sum(axis=1) > 0.0
    moments, slot_roughness = moments[scored], slot_roughness[scored]
    if len(moments) == 0:
        return GainEstimate(np.ones(3), np.full(3, PRIOR_LOG_STD), 0)
    grid = LOG_GAIN_GRID
    curves = np.empty((len(moments), len(grid)))
    choice = np.empty((len(moments), len(grid)), np.int64)
    texel_gain_curves(moments, grid, curves, choice)
    position, _, _, usable = _grid_minimum(curves, grid)
    # The roughness slot and label that fit the texel best at its best gain node, and with them
    # each channel's loss over the gains.
    rows = np.arange(len(moments))
    node = np.clip(np.round((position - grid[0]) / (grid[1] - grid[0])).astype(int), 0, len(grid) - 1)
    texel_loss, texel_base = np.empty((len(moments), len(grid), 3)), np.empty((len(moments), len(grid), 3))
    channel_gain_curves(moments, grid, np.ascontiguousarray(choice[rows, node]), texel_loss, texel_base)
    at_best = texel_base[rows, node]  # (N, 3)
    usable &= (slot_roughness[:, 0] <= MAX_ROUGHNESS) & np.any(at_best > 0.0, axis=1)
    if usable.sum() < 2:
        return GainEstimate(np.ones(3), np.full(3, PRIOR_LOG_STD), 0)
    # A texel at its base colour's bound votes at the bound's kink: on the side of the median it lies on.
    exposure, exposure_variance = _robust_mean(position[usable])
    readers = int(usable.sum())
    usable &= np.all(at_best < BASE_BOUND, axis=1)
    ratios, ratio_variance = np.zeros(3), np.zeros(3)
    for c in range(3):
        channel_position, channel_minimum, channel_curvature, channel_usable = _grid_minimum(texel_loss[:, :, c], grid)
        both = usable & channel_usable
        if both.sum() < 2:
            continue
        ratios[c], ratio_variance[c] = _robust_mean((channel_position - position)[both],
                                                    _precision(channel_minimum, channel_curvature, both)[both])
    ratios -= ratios.mean()
    log_gain = exposure + ratios
    # The texels' errors are not independent: the model's own misfit moves them together.
    exposure_variance += model_exposure_log_std ** 2
    ratio_variance = ratio_variance + MODEL_RATIO_LOG_STD ** 2
    variance = exposure_variance + ratio_variance
    precision = 1.0 / np.maximum(variance, 1e-12) + 1.0 / PRIOR_LOG_STD ** 2
    shrunk = log_gain / np.maximum(variance, 1e-12) / precision
    return GainEstimate(np.exp(shrunk), 1.0 / np.sqrt(precision), readers,
                        float(np.sqrt(exposure_variance)), np.sqrt(ratio_variance))


def _precision(minimum: np.ndarray, curvature: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """Texels' inverse variances of a log gain: curvature over misfit (floored), 0 where not usable."""
    floor = max(MISFIT_FLOOR * float(np.median(minimum[usable])), 1e-12)
    return np.where(usable, curvature / (np.maximum(minimum, 0.0) + floor), 0.0)


def _robust_mean(values: np.ndarray, weight: np.ndarray | None = None) -> tuple[float, float]:
    """Return the weighted median of values (n,) (weights (n,), None: one each) and its variance.

    The variance is the weighted spread (as 1.4826 median absolute deviations) squared over the
    effective number of values, times pi / 2 (a median's efficiency).
    """
    weight = np.ones(len(values)) if weight is None else weight
    centre = _weighted_median(values, weight)
    spread = 1.4826 * _weighted_median(np.abs(values - centre), weight)
    effective = float(np.sum(weight) ** 2 / max(np.sum(weight ** 2), 1e-300))
    return centre, 0.5 * np.pi * spread ** 2 / max(effective, 1.0)


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """Return the weighted median of values (n,) with weights (n,) >= 0."""
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def frame_gains(view_direction: np.ndarray, weight: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Estimate a relative gain per photograph and channel from the photographs' pairwise ratios.

    Two photographs u and v that see a texel from directions less than `FRAME_PAIR_DEG` apart see
    about the same radiance there, whatever its material: the median over such texels (at least
    `FRAME_PAIR_TEXELS`) of log(f_u / f_v) reads log g_u - log g_v. The log gains are the weighted
    least-squares solution over all pairs (weights the square root of each pair's texels, Huber's
    on the pairs' residuals, three passes), with a geometric mean of 1 over the photographs in
    pairs. A gain the photographs multiply moves every pair's ratio by it, so the estimate follows
    it exactly (what remains is the view dependence of nearby directions, the same at any gain).

    Parameters
    ----------
    view_direction : (N, V, 3) float32
        Local view directions.
    weight : (N, V) float32
        Sample weights (0: no sample).
    observed : (N, V, 3) float32
        Observed radiance.

    Returns
    -------
    gain : (V, 3) float64
        Relative gain per view and channel (geometric mean 1 over the views in pairs; 1 for the
        others).
    log_std : (V, 3) float64
        The std of each log gain: its pairs' residuals (1.4826 median absolute deviations) over the
        square root of their count; inf for a view in fewer than two pairs.
    """
    n_views = weight.shape[1]
    seen = (np.asarray(weight) > 0) & np.all(np.asarray(observed) > 0, axis=2)
    log_radiance = np.log(np.where(seen[..., None], observed, 1.0).astype(np.float64))
    directions = np.asarray(view_direction, np.float64)
    closest = np.cos(np.radians(FRAME_PAIR_DEG))
    first, second, ratios, counts = [], [], [], []
    for u in range(n_views - 1):
        both = seen[:, u, None] & seen[:, u + 1:]  # (N, V - u - 1)
        both &= np.einsum("nk,nvk->nv", directions[:, u], directions[:, u + 1:]) >= closest
        for offset in np.flatnonzero(both.sum(axis=0) >= FRAME_PAIR_TEXELS):
            rows = both[:, offset]
            v = u + 1 + offset
            first.append(u)
            second.append(v)
            ratios.append(np.median(log_radiance[rows, u] - log_radiance[rows, v], axis=0))
            counts.append(rows.sum())
    log_gain, log_std = np.zeros((n_views, 3)), np.full((n_views, 3), np.inf)
    if not first:
        return np.ones((n_views, 3)), log_std
    first, second, ratios = np.array(first), np.array(second), np.array(ratios)
    pairs = len(first)
    design = np.zeros((pairs + 1, n_views))
    design[np.arange(pairs), first] = 1.0
    design[np.arange(pairs), second] = -1.0
    paired = np.zeros(n_views, bool)
    paired[first] = paired[second] = True
    design[pairs, paired] = 1.0  # the geometric mean of the paired views' gains is 1
    base_weight = np.sqrt(np.array(counts, np.float64))
    for c in range(3):
        pair_weight = base_weight.copy()
        for _ in range(3):
            rows_weight = np.append(pair_weight, base_weight.sum())
            solution = np.linalg.lstsq(design * rows_weight[:, None], np.append(ratios[:, c], 0.0) * rows_weight,
                                       rcond=None)[0]
            residual = ratios[:, c] - (solution[first] - solution[second])
            scale = 1.4826 * float(np.median(np.abs(residual))) + 1e-9
            pair_weight = base_weight * np.minimum(1.0, 1.5 * scale / np.maximum(np.abs(residual), 1e-12))
        log_gain[paired, c] = solution[paired]
        for view in np.flatnonzero(paired):
            mine = (first == view) | (second == view)
            if mine.sum() >= 2:
                log_std[view, c] = 1.4826 * float(np.median(np.abs(residual[mine]))) / np.sqrt(mine.sum())
    return np.exp(log_gain), log_std


def _with_selection(found: GainEstimate, exposure_log_std: float,
                    ratio_log_std: float | np.ndarray | None = None) -> GainEstimate:
    """Return the gains with more std added in quadrature: the exposure's and each white-balance ratio's.

    ``ratio_log_std`` is per ratio (3,) or one for all; None: ``exposure_log_std``.
    """
    ratio_log_std = np.asarray(exposure_log_std if ratio_log_std is None else ratio_log_std, np.float64)
    if exposure_log_std <= 0.0 and np.all(ratio_log_std <= 0.0):
        return found
    exposure_variance = found.exposure_log_std ** 2 + exposure_log_std ** 2
    ratio_variance = found.ratio_log_std ** 2 + ratio_log_std ** 2
    precision = 1.0 / (exposure_variance + ratio_variance) + 1.0 / PRIOR_LOG_STD ** 2
    return replace(found, log_std=1.0 / np.sqrt(precision), exposure_log_std=float(np.sqrt(exposure_variance)),
                   ratio_log_std=np.sqrt(ratio_variance))


def _significant(gain: np.ndarray, found: GainEstimate) -> np.ndarray:
    """Return the gains with the parts the texels do not tell from 1 set to 1.

    The exposure (the gains' geometric mean) and each channel's white-balance ratio to it are each
    either exactly 1 (the probe shot with the photographs' settings) or off by a normal amount of
    std tau (`PRIOR_LOG_STD` for the exposure, `WHITE_BALANCE_PRIOR_LOG_STD` for a ratio). A
    measurement x of std s is applied where the second is the likelier (even prior odds): where
    (x / s)^2 exceeds (1 + s^2 / tau^2) ln(1 + tau^2 / s^2), about 2.1 std for the exposure and 1.6
    for a ratio at the model's own misfit; it is then applied as measured: the normal slab decides
    whether a gain is off, but how far off a probe shot at another setting is has heavier tails
    (daylight against tungsten is a factor 2), and shrinking x by tau^2 / (tau^2 + s^2) left a large
    white balance short (docs/results.md#calibration). A gain the model's misfit could give on
    a calibrated capture is not applied.
    """
    log_gain = np.log(gain)
    exposure = float(log_gain.mean())
    ratios = log_gain - exposure
    exposure = _applied(exposure, found.exposure_log_std, PRIOR_LOG_STD)
    ratios = _applied(ratios, found.ratio_log_std, WHITE_BALANCE_PRIOR_LOG_STD)
    return np.exp(exposure + ratios)


def _significant_frames(gain: np.ndarray, log_std: np.ndarray) -> np.ndarray:
    """Return the frames' gains (V, 3) with those the pairs do not tell from the others' set to 1.

    Each frame's exposure (its gains' geometric mean; its channels alike) is the same as the others'
    or off by a normal amount of std `FRAME_PRIOR_LOG_STD`; measured with its pairs' std and
    `FRAME_MODEL_LOG_STD` in quadrature, it is applied as measured where the second is the likelier
    (`_significant`'s rule): on photographs exposed alike the pairs' misfit reads 0.08-0.12 in log
    (docs/results.md#calibration), which applied to every frame would cost more than it mends.
    """
    log_gain = np.log(gain).mean(axis=1)
    finite = np.isfinite(log_std)
    measured = finite.any(axis=1)  # frames in enough pairs
    own_variance = (np.where(finite, log_std, 0.0) ** 2).sum(axis=1) / np.maximum(finite.sum(axis=1), 1)
    std = np.sqrt(own_variance + FRAME_MODEL_LOG_STD ** 2)
    applied = np.where(measured, _applied(log_gain, std, FRAME_PRIOR_LOG_STD), 0.0)
    return np.repeat(np.exp(applied)[:, None], 3, axis=1)


def _decision_log_std(gain: np.ndarray, found: GainEstimate) -> np.ndarray:
    """Return the std (3,) of the error of the log gains `_significant` applies, per channel.

    Under the spike-and-slab posterior of a measurement x of std s (`_significant`), the gain is off
    1 with probability p = sigmoid(`slab_log_odds`), then by x with variance s^2 (the slab's heavy
    tails). Applying a (x, or 0) is off by a - x with that variance in the first case and by a in
    the second: the expected square of the error, for the exposure and for each ratio, added.
    """
    log_gain = np.log(gain)
    exposure = float(log_gain.mean())
    return np.sqrt(_decision_variance(exposure, found.exposure_log_std, PRIOR_LOG_STD)
                   + _decision_variance(log_gain - exposure, found.ratio_log_std, WHITE_BALANCE_PRIOR_LOG_STD))


def _decision_variance(value, std, prior_std):
    """Return the expected squared error of `_applied` for a measurement ``value`` of ``std`` (`_decision_log_std`)."""
    value, variance = np.asarray(value, np.float64), np.maximum(np.asarray(std, np.float64) ** 2, 1e-24)
    off = 1.0 / (1.0 + np.exp(-np.clip(slab_log_odds(value, np.sqrt(variance), prior_std), -700.0, 700.0)))
    applied = _applied(value, np.sqrt(variance), prior_std)
    return off * ((applied - value) ** 2 + variance) + (1.0 - off) * applied ** 2


def _applied(value, std, prior_std):
    """Return the log gain to apply for a measurement ``value`` of ``std``.

    0 where exactly 1 is the likelier (`_likelier_off`), else the measurement (`_significant`).
    """
    value = np.asarray(value, np.float64)
    return np.where(_likelier_off(value, std, prior_std), value, 0.0)


def _likelier_off(value, std, prior_std):
    """Whether a log gain measured as ``value`` with ``std`` is likelier off 1 (std ``prior_std``) than exactly 1."""
    return slab_log_odds(value, std, prior_std) > 0.0
