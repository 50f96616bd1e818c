"""Does the uncertainty mean something? Rank correlation and sparsification curves.

The uncertainty-quality measures of docs/method.md#evaluation. A per-texel uncertainty is useful when it ranks texels by their error. Two standard measures:

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
    """Sparsification curves and scores of one uncertainty against one error (S steps).

    Attributes
    ----------
    fractions : (S,) float64
        Fraction of texels removed.
    by_uncertainty : (S,) float64
        Mean error of the kept texels over the full-set mean error, most uncertain removed first.
    oracle : (S,) float64
        The same, removing the largest errors first.
    random : (S,) float64
        The expectation under a random order: all ones.
    ause : float
        Area between ``by_uncertainty`` and ``oracle`` (0 is perfect).
    aurg : float
        Area between ``random`` and ``by_uncertainty`` (> 0: better than chance).
    spearman : float
        Rank correlation of uncertainty and error; NaN if either is constant.
    texels : int
        Number of texels scored (finite in both).
    """

    fractions: np.ndarray
    by_uncertainty: np.ndarray
    oracle: np.ndarray
    random: np.ndarray
    ause: float
    aurg: float
    spearman: float
    texels: int


def sparsification(uncertainty: np.ndarray, error: np.ndarray, steps: int = 50,
                   max_fraction: float = 0.99) -> Sparsification:
    """Compute sparsification curves and scores of an uncertainty against an error.

    Non-finite entries (of either) are left out. Ties in uncertainty are broken by texel order
    (stable sort), so the result is deterministic.

    Parameters
    ----------
    uncertainty : (N,) array_like
        Per-texel uncertainty, higher meaning less certain.
    error : (N,) array_like
        Per-texel error (its absolute value is used).
    steps : int, optional
        Number of fractions S, evenly spaced on [0, max_fraction].
    max_fraction : float, optional
        The largest fraction of texels removed.

    Returns
    -------
    Sparsification
        The curves and AUSE, AURG and Spearman's rho; flat curves and zero areas when no texel
        is left or the mean error is 0.

    Raises
    ------
    ValueError
        If ``uncertainty`` and ``error`` differ in length.
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
    """Return the mean of ``error_removed_first[k:]`` with k = floor(f N) for each fraction f."""
    n_texels = len(error_removed_first)
    suffix_sum = np.concatenate([np.cumsum(error_removed_first[::-1])[::-1], [0.0]])  # (N + 1,)
    removed = np.minimum(np.floor(fractions * n_texels).astype(np.int64), n_texels - 1)
    return suffix_sum[removed] / (n_texels - removed)


def to_dict(result: Sparsification) -> dict:
    """Convert a result to JSON-ready values for ``metrics.json``.

    Parameters
    ----------
    result : Sparsification
        The result.

    Returns
    -------
    dict
        ``texels``, ``spearman`` (None for NaN), ``ause``, ``aurg`` and the ``fractions``,
        ``by_uncertainty`` and ``oracle`` curves as rounded lists.
    """
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
    """Plot sparsification curves as a PNG, one panel per error kind.

    Each panel has one curve per uncertainty with its AUSE, AURG and Spearman in the legend, and
    the oracle and random curves of the first uncertainty (the same for all when they are scored
    on the same texels).

    Parameters
    ----------
    results : dict of str to dict of str to Sparsification
        ``results[uncertainty][error kind]``, e.g. ``results["entropy"]["roughness"]``; every
        uncertainty has the same error kinds.
    path : str or Path
        The PNG file, written atomically.
    """
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
