"""Each capture calibrates its own std maps by holding views out (docs/method.md#held-out-std-calibration).

The std maps of `freqbrdf.pipeline.fit` come from a model of the noise and of the whole-surface
posterior; how far they are from the errors differs between captures, so no constant calibrates
every capture. `calibrate_std` measures it on the capture itself: on an evenly spread subsample of
the texels the views see, the views are split into K folds, each fold is held out in turn
(`Observations.with_views`) and the texels are estimated again from the views kept. The
deviations of those estimates from the estimate of all views, scaled for the views held out
(jackknife), are samples of the estimate's error from the samples' noise; the share of them a
std covers says how far it must be scaled to cover 68 % of them. What the held-out views cannot
see, the error of a forward model that does not explain the samples (interreflection, a light
that is not the environment map), is read from the texels' misfit: where the capture's median
misfit is above what a capture the model explains leaves
(``UncertaintyConfig.heldout_misfit_reference``), the factor grows with the square root of their
ratio. Where each fold keeps fewer than ``UncertaintyConfig.heldout_narrow_views`` views, the std
is only widened (a factor of at least 1): an error those views share (a roughness that fits them
as well as the true one) moves no fold and need not raise the misfit, so folds that agree better
than the std says do not show the std too wide. With more views per fold the factor also narrows
an over-wide std.

The roughness std is scaled by the folds and the misfit. The base colour's, the whole-surface
posterior's, by the misfit alone: the folds re-estimate each texel from its own samples, whose noise
the whole-surface solve averages over its neighbours, so their deviations say how wide a texel's own
estimate is, not the solved one (docs/results.md#held-out-std-calibration); its fold factor is
reported. The metallic std is reported only (its errors are labels, mostly exactly right, which a
scale cannot calibrate).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from freqbrdf.config import Config
from freqbrdf.estimate import estimate as estimate_materials

if TYPE_CHECKING:
    from freqbrdf.estimate import MaterialEstimate
    from freqbrdf.observe.observations import Observations
    from freqbrdf.uncertainty._result import Uncertainty

__all__ = ["CALIBRATED", "COVERAGE", "FACTOR_RANGE", "FOLD_CALIBRATED", "StdCalibration", "calibrate_std", "heldout_texels"]

# The share of errors one std covers for a normal error: the target of the calibration.
COVERAGE = 0.68
# The std maps the calibration scales, and those of them the folds' factor scales (the others by the misfit alone).
CALIBRATED = ("roughness", "base_color")
FOLD_CALIBRATED = ("roughness",)
# The factors are kept within this range: a handful of texels says little.
FACTOR_RANGE = (0.125, 8.0)


@dataclass
class StdCalibration:
    """How a capture's held-out views calibrated its std maps (`calibrate_std`).

    Attributes
    ----------
    folds : int
        K, the folds the views were split into (view v in fold v mod K).
    texels : int
        The texels re-estimated per fold.
    factors : dict of str to float
        Per calibrated std ("roughness", "base_color"): the factor it was multiplied by, within
        `FACTOR_RANGE`: the roughness's fold factor x misfit_scale, at least 1 where the folds
        keep fewer than ``UncertaintyConfig.heldout_narrow_views`` views; the base colour's
        misfit_scale (`FOLD_CALIBRATED`).
    fold_factors : dict of str to float
        Per std (also "metallic"): the factor the held-out folds alone ask for.
    misfit : float
        The capture's median relative misfit (mean squared residual of a texel's samples under
        its own estimate over their mean squared radiance).
    misfit_scale : float
        sqrt(max(1, misfit / reference)): what the misfit multiplies the fold factors by.
    coverage_before : dict of str to float
        Per std, the share of the held-out deviations within one std as fitted.
    coverage_after : dict of str to float
        The same within the calibrated std.
    seconds : float
        Time taken.
    rows : (M,) int64 or None
        The texels re-estimated (rows of the observations); not in `to_dict`.
    deviations : dict of str to (K, M) float64
        Per std, the jackknife deviations d_tk of docs/method.md#held-out-std-calibration (the base
        colour's mean over RGB; NaN where a fold left a texel unestimated); not in `to_dict`.
    relative_misfit : (M,) float64 or None
        Each texel's relative misfit under the estimate of all views; not in `to_dict`.
    """

    folds: int
    texels: int
    factors: dict[str, float] = field(default_factory=dict)
    fold_factors: dict[str, float] = field(default_factory=dict)
    misfit: float = float("nan")
    misfit_scale: float = 1.0
    coverage_before: dict[str, float] = field(default_factory=dict)
    coverage_after: dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0
    rows: np.ndarray | None = field(default=None, repr=False)
    deviations: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    relative_misfit: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        """Return the calibration as JSON-ready values (``summary.json``'s ``std_calibration``).

        Returns
        -------
        dict
            Every attribute; NaN becomes None.
        """
        def clean(value):
            if isinstance(value, dict):
                return {key: clean(item) for key, item in value.items()}
            return None if isinstance(value, float) and not np.isfinite(value) else value

        return {name: clean(getattr(self, name)) for name in (
            "folds", "texels", "factors", "fold_factors", "misfit", "misfit_scale", "coverage_before",
            "coverage_after", "seconds")}


def heldout_texels(observations: Observations, estimate: MaterialEstimate | None, count: int) -> np.ndarray:
    """Choose the texels the folds re-estimate: at most ``count``, spread evenly over those seen.

    Parameters
    ----------
    observations : Observations
        The capture's observations (N texels).
    estimate : MaterialEstimate or None
        Their estimate (N texels): only its estimated texels are chosen; None: any with samples.
    count : int
        The most texels to choose.

    Returns
    -------
    (M,) int64
        Rows of the texels chosen, ascending: estimated texels with samples, every
        ceil(n / count)-th of the n there are in row order.
    """
    seen = observations.n_samples > 0
    if estimate is not None:
        seen &= np.asarray(estimate.estimated, bool)
    seen = np.flatnonzero(seen)
    if count < 1 or len(seen) == 0:
        return np.zeros(0, np.int64)
    step = int(np.ceil(len(seen) / count))
    return seen[::step].astype(np.int64)


def _std_of(uncertainty: Uncertainty, name: str) -> np.ndarray | None:
    """Return one std map per texel, (N,) float64 (the base colour's mean over RGB); None if absent."""
    std = getattr(uncertainty, f"{name}_std")
    if std is None:
        return None
    std = np.asarray(std, np.float64)
    return std.mean(axis=1) if std.ndim == 2 else std


def _value_of(estimate: MaterialEstimate, name: str) -> np.ndarray:
    """Return one parameter per texel, (n,) or (n, 3) float64, NaN where not estimated."""
    value = np.asarray(getattr(estimate, name), np.float64)
    estimated = np.asarray(estimate.estimated, bool)
    return np.where(estimated.reshape((-1,) + (1,) * (value.ndim - 1)), value, np.nan)


def _relative_misfit(observations: Observations, loss: np.ndarray) -> np.ndarray:
    """Return each texel's loss over its samples' weighted mean squared radiance, (n,) float64."""
    weight_sq = np.square(observations.weight.astype(np.float64))
    radiance_sq = np.nan_to_num(np.einsum("nvc,nvc->nv", observations.observed, observations.observed))
    signal = (weight_sq * radiance_sq).sum(axis=1) / np.maximum(weight_sq.sum(axis=1), np.finfo(np.float64).tiny)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(signal > 0.0, np.asarray(loss, np.float64) / signal, np.nan)


def calibrate_std(observations: Observations, uncertainty: Uncertainty, config: Config = Config(),
                  estimate: MaterialEstimate | None = None) -> StdCalibration | None:
    """Calibrate the std maps on the capture's held-out views, scaling them in place.

    Parameters
    ----------
    observations : Observations
        The capture's observations with their samples (N texels, V views).
    uncertainty : Uncertainty
        The fit's uncertainty (N texels): ``roughness_std`` (N,) and ``base_color_std`` (N, 3) are
        multiplied by their factors; ``metallic_std`` is left as it is.
    config : Config, optional
        ``config.uncertainty``'s heldout_folds, heldout_texels and heldout_misfit_reference; the
        texels are estimated again with the fit's estimator (``config.estimate``, ``config.fit``).
    estimate : MaterialEstimate, optional
        The fit's estimate (N texels), which chooses the texels (those estimated); default all
        texels with samples.

    Returns
    -------
    StdCalibration or None
        The factors and the held-out coverage; None where calibration is off
        (``heldout_folds`` = 0) or fewer than two views or no texel could be used (the std maps
        are then left unchanged).
    """
    settings = config.uncertainty
    folds = settings.heldout_folds
    if folds == 0 or observations.n_views < 2:
        return None
    start = time.perf_counter()
    folds = min(folds, observations.n_views)
    rows = heldout_texels(observations, estimate, settings.heldout_texels)
    if len(rows) == 0:
        return None
    part = observations.select(rows)
    # The estimate of all views on the same texels, made as the folds' are (the fit's own may
    # have used neighbours these texels lack).
    whole = estimate_materials(part, config)
    fold_estimates = []
    for fold in range(folds):
        keep = np.arange(observations.n_views) % folds != fold
        fold_estimates.append(estimate_materials(part.with_views(keep, config), config))

    # Deviations of the held-out estimates from the whole, scaled by sqrt(K - 1): for errors
    # from the samples' noise each has the whole estimate's variance.
    jackknife = np.sqrt(folds - 1.0)
    # Folds that keep many views may narrow the std; with few, an error the views share moves no fold.
    narrow = observations.n_views - -(-observations.n_views // folds) >= settings.heldout_narrow_views
    relative_misfit = _relative_misfit(part, whole.loss)
    misfit = float(np.nanmedian(relative_misfit)) if np.any(np.isfinite(relative_misfit)) else np.nan
    reference = settings.heldout_misfit_reference
    misfit_scale = float(np.sqrt(max(1.0, misfit / reference))) if np.isfinite(misfit) else 1.0
    result = StdCalibration(folds=folds, texels=len(rows), misfit=misfit, misfit_scale=misfit_scale, rows=rows,
                            relative_misfit=relative_misfit)
    for name in ("roughness", "metallic", "base_color"):
        std = _std_of(uncertainty, name)
        if std is None:
            continue
        std = std[rows]
        centre = _value_of(whole, name)
        deviation = np.stack([np.abs(_value_of(found, name) - centre) for found in fold_estimates]) * jackknife
        if deviation.ndim == 3:
            deviation = deviation.mean(axis=2)
        result.deviations[name] = deviation
        usable = np.isfinite(deviation) & np.isfinite(std)[None, :] & (std > 0.0)[None, :]
        if not usable.any():
            continue
        ratio = deviation[usable] / np.broadcast_to(std[None, :], deviation.shape)[usable]
        fold_factor = float(np.clip(np.quantile(ratio, COVERAGE), *FACTOR_RANGE))
        result.fold_factors[name] = fold_factor
        result.coverage_before[name] = float(np.mean(ratio <= 1.0))
        if name not in CALIBRATED:
            continue
        if name in FOLD_CALIBRATED:
            factor = float(np.clip(fold_factor * misfit_scale if narrow else max(1.0, fold_factor * misfit_scale),
                                   *FACTOR_RANGE))
        else:
            factor = float(np.clip(misfit_scale, *FACTOR_RANGE))
        result.factors[name] = factor
        result.coverage_after[name] = float(np.mean(ratio <= factor))
        scaled = (np.asarray(getattr(uncertainty, f"{name}_std"), np.float64) * factor).astype(np.float32)
        setattr(uncertainty, f"{name}_std", scaled)
    result.seconds = time.perf_counter() - start
    return result
