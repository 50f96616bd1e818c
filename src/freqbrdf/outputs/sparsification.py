"""Does the uncertainty mean something? Rank correlation and sparsification curves.

A per-texel uncertainty is useful when it ranks texels by their error. Two standard measures:

- Spearman's rho between uncertainty and absolute error.
- Sparsification (Ilg et al., ECCV 2018): remove the most uncertain fraction f of the texels and
  take the mean error of the rest, for f from 0 to ``max_fraction``. The oracle removes the
  largest errors first (the best any ranking can do); a random order keeps the mean error flat.
  AUSE = area between our curve and the oracle's (0 is perfect), AURG = area between the random
  curve and ours (> 0 means better than chance). Both are taken over f in [0, max_fraction] with
  the curves divided by the full-set mean error, so that they compare across captures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats


@dataclass(eq=False)
class Sparsification:
    fractions: np.ndarray  # (S,) fraction of texels removed
    by_uncertainty: np.ndarray  # (S,) mean error of the kept texels / full-set mean error
    oracle: np.ndarray  # (S,) the same, removing the largest errors first
    random: np.ndarray  # (S,) the expectation under a random order: all ones
    ause: float
    aurg: float
    spearman: float  # rank correlation of uncertainty and error (NaN if either is constant)
    texels: int


def sparsification(uncertainty: np.ndarray, error: np.ndarray, steps: int = 50,
                   max_fraction: float = 0.99) -> Sparsification:
    """Curves and scores for per-texel ``uncertainty`` (N,) against absolute ``error`` (N,).

    Non-finite entries (of either) are left out. Ties in uncertainty are broken by texel order
    (stable sort), so the result is deterministic.
    """
    uncertainty = np.asarray(uncertainty, np.float64).ravel()
    error = np.abs(np.asarray(error, np.float64).ravel())
    if uncertainty.shape != error.shape:
        raise ValueError(f"uncertainty {uncertainty.shape} and error {error.shape} differ in length")
    keep = np.isfinite(uncertainty) & np.isfinite(error)
    uncertainty, error = uncertainty[keep], error[keep]
    n_texels = len(error)
    fractions = np.linspace(0.0, max_fraction, steps)
    if n_texels == 0 or error.mean() == 0:
        ones = np.ones(steps)
        return Sparsification(fractions, ones, ones, ones, 0.0, 0.0, float("nan"), n_texels)
    full_mean = error.mean()
    curve = _kept_mean(error[np.argsort(-uncertainty, kind="stable")], fractions) / full_mean
    oracle = _kept_mean(np.sort(error)[::-1], fractions) / full_mean
    random = np.ones(steps)
    rho = stats.spearmanr(uncertainty, error).statistic if np.ptp(uncertainty) > 0 and np.ptp(error) > 0 else np.nan
    return Sparsification(
        fractions=fractions,
        by_uncertainty=curve,
        oracle=oracle,
        random=random,
        ause=float(np.trapezoid(curve - oracle, fractions)),
        aurg=float(np.trapezoid(random - curve, fractions)),
        spearman=float(rho),
        texels=n_texels,
    )


def _kept_mean(error_removed_first: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    """Mean of ``error_removed_first[k:]`` with k = floor(f N) for each fraction f."""
    n_texels = len(error_removed_first)
    suffix_sum = np.concatenate([np.cumsum(error_removed_first[::-1])[::-1], [0.0]])  # (N + 1,)
    removed = np.minimum(np.floor(fractions * n_texels).astype(np.int64), n_texels - 1)
    return suffix_sum[removed] / (n_texels - removed)


def to_dict(result: Sparsification) -> dict:
    return {
        "texels": result.texels,
        "spearman": None if np.isnan(result.spearman) else result.spearman,
        "ause": result.ause,
        "aurg": result.aurg,
        "fractions": result.fractions.round(4).tolist(),
        "by_uncertainty": result.by_uncertainty.round(5).tolist(),
        "oracle": result.oracle.round(5).tolist(),
    }


# Colours of the uncertainties' curves in the plot, by name; others take matplotlib's cycle.
PLOT_COLOURS = {"entropy": "C0", "roughness_std": "C3"}


def plot(results: dict[str, dict[str, Sparsification]], path) -> None:
    """One panel per error kind (e.g. roughness, base colour) with one curve per uncertainty
    (``results[uncertainty][error kind]``, e.g. "entropy", "roughness_std") and their AUSE, AURG and
    Spearman in the legend, the oracle and random curves (of the first uncertainty: the same for
    all when they are scored on the same texels)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from freqbrdf.fileio import atomic_path

    error_kinds = list(next(iter(results.values())))
    figure, axes = plt.subplots(1, len(error_kinds), figsize=(4.2 * len(error_kinds), 3.6), squeeze=False)
    for axis, kind in zip(axes[0], error_kinds):
        for index, (name, by_error) in enumerate(results.items()):
            result = by_error[kind]
            axis.plot(result.fractions, result.by_uncertainty, color=PLOT_COLOURS.get(name, f"C{index + 4}"),
                      label=f"by {name}: AUSE {result.ause:.3f}, AURG {result.aurg:.3f}, "
                            f"ρ {result.spearman:.2f}")
        first = next(iter(results.values()))[kind]
        axis.plot(first.fractions, first.oracle, label="oracle", color="C2", linestyle="--")
        axis.plot(first.fractions, first.random, label="random", color="0.5", linestyle=":")
        axis.set_title(f"{kind} error ({first.texels} texels)", fontsize=9)
        axis.set_xlabel("fraction of texels removed (most uncertain first)")
        axis.set_ylabel("mean error of the rest / mean error")
        axis.set_xlim(0, 1)
        axis.set_ylim(bottom=0)
        axis.legend(fontsize=7)
    figure.tight_layout()
    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=110, format="png")
    plt.close(figure)
