"""The hypothesis grid both entropy modes score, the `Uncertainty` they return, and its flags.

The grid is that of docs/method.md#entropy: R x R specular hypotheses psi = (alpha_i, k_j), alpha_i =
(i / (R-1))^2 (roughness i / (R-1), uniform) and k_j = j / (R-1). `uncertainty_of_grid` turns
a kernel's per-texel outputs into an `Uncertainty`: the prior where a texel is unobserved, and
the ``FLAG_*`` bits that say why a texel should not be trusted. Import these names from
`freqbrdf.uncertainty`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from freqbrdf.config import UncertaintyConfig

if TYPE_CHECKING:
    from freqbrdf.observe.observations import Observations

FLAG_UNOBSERVED = 1  # no sample at all: entropy 1, uniform likelihood, no estimate
# Fewer samples than FEW_SAMPLES_FRACTION of the SH coefficients: the fit mostly extrapolates
# (docs/results.md#flags).
FLAG_FEW_SAMPLES = 2
FEW_SAMPLES_FRACTION = 0.25
FLAG_BELOW_BOUND = 4  # the most likely alpha lies below the sampling bound alpha' (appendix eq. 12)
FLAG_AMBIGUOUS = 8  # entropy above config.ambiguous_entropy: the light does not separate hypotheses
FLAG_NAMES = {
    FLAG_UNOBSERVED: "unobserved",
    FLAG_FEW_SAMPLES: "few_samples",
    FLAG_BELOW_BOUND: "below_bound",
    FLAG_AMBIGUOUS: "ambiguous",
}


@dataclass(frozen=True)
class HypothesisGrid:
    """The R x R specular hypotheses; likelihood grids are indexed [alpha index, k index].

    Attributes
    ----------
    alpha : (R,) float64
        The rows' GGX alpha_i = (i / (R-1))^2.
    specular : (R,) float64
        The columns' specular amplitude k_j = j / (R-1).
    """

    alpha: np.ndarray
    specular: np.ndarray

    @property
    def resolution(self) -> int:
        """R, the number of values of each parameter."""
        return len(self.alpha)


def hypothesis_grid(grid_res: int) -> HypothesisGrid:
    """Make the paper's grid: roughness and specular amplitude uniform in [0, 1].

    Parameters
    ----------
    grid_res : int
        R, at least 2.

    Returns
    -------
    HypothesisGrid
        R values of each parameter.
    """
    if grid_res < 2:
        raise ValueError(f"grid_res must be at least 2, got {grid_res}")
    steps = np.arange(grid_res) / (grid_res - 1)
    return HypothesisGrid(alpha=np.square(steps), specular=steps)


@dataclass(eq=False)
class Uncertainty:
    """Per-texel uncertainty of the specular parameters (N texels, R the grid's side).

    Attributes
    ----------
    entropy : (N,) float32
        Normalised entropy in [0, 1], the minimum over RGB; 1 where unobserved.
    flags : (N,) uint8
        Bit field of ``FLAG_*``.
    likelihood : (N, R, R) float32 or None
        The posterior of the chosen channel, summing to 1; None when not kept.
    best_alpha : (N,) float32
        The arg-max cell's alpha; NaN where the arg-max has k = 0 or the texel is unobserved.
    best_ks : (N,) float32
        The arg-max cell's k_s; NaN where unobserved.
    channel : (N,) int8
        The RGB channel that gave the minimum entropy; -1 where unobserved.
    mode : str
        "calibrated", "paper" or "angular" (``UncertaintyConfig.mode``).
    grid : HypothesisGrid
        The hypotheses scored.
    roughness_std : (N,) float32 or None
        Posterior std of the estimated roughness (`freqbrdf.uncertainty.roughness_std`); NaN
        where not estimated; None when not computed (it needs the estimate). With the whole-surface
        estimate, its posterior's (`freqbrdf.estimate.surface`), for every texel.
    metallic_std : (N,) float32 or None
        The whole-surface posterior's std of the metallic; None without it.
    base_color_std : (N, 3) float32 or None
        The whole-surface posterior's std of each base-colour channel; None without it.
    """

    entropy: np.ndarray
    flags: np.ndarray
    likelihood: np.ndarray | None
    best_alpha: np.ndarray
    best_ks: np.ndarray
    channel: np.ndarray
    mode: str
    grid: HypothesisGrid
    roughness_std: np.ndarray | None = None
    metallic_std: np.ndarray | None = None
    base_color_std: np.ndarray | None = None

    def to_texture(self, observations: Observations, quantity: str = "entropy", fill: float = 0.0) -> np.ndarray:
        """Scatter one per-texel field into a texture.

        Parameters
        ----------
        observations : Observations
            The observations the uncertainty is of (their texels, N of them).
        quantity : str
            The field's name: "entropy", "flags", "likelihood", "best_alpha", "best_ks",
            "channel" or "roughness_std".
        fill : float
            The value outside the texels.

        Returns
        -------
        (T, T, ...) array
            The field in texture space, of its dtype (``likelihood``: (T, T, R, R)).
        """
        values = getattr(self, quantity)
        if values is None:
            raise ValueError(f"{quantity} was not computed")
        return observations.to_texture(values, fill=fill)


def uncertainty_of_grid(unobserved, entropy, channel, best_alpha, best_ks, likelihood, n_samples, n_coeffs,
                        alpha_bound, grid: HypothesisGrid, config: UncertaintyConfig) -> Uncertainty:
    """Make the Uncertainty of a grid evaluation: the prior where unobserved, and the flags.

    Parameters
    ----------
    unobserved : (N,) bool
        Texels without information; their outputs are set to the prior's.
    entropy, channel, best_alpha, best_ks : (N,) float32, int8, float32, float32
        The kernel's outputs, changed in place.
    likelihood : (N, R, R) float32 or None
        The kernel's likelihood, changed in place.
    n_samples : (N,) int or None
        Samples per texel: FLAG_FEW_SAMPLES below ``FEW_SAMPLES_FRACTION`` x ``n_coeffs``; None:
        no such flag.
    n_coeffs : int
        K, the SH coefficients per fit.
    alpha_bound : (N,) float or None
        The sampling bound alpha' per texel (FLAG_BELOW_BOUND); None: no such flag.
    grid : HypothesisGrid
        The grid scored.
    config : UncertaintyConfig
        Its mode and ``ambiguous_entropy`` (FLAG_AMBIGUOUS).

    Returns
    -------
    Uncertainty
        Holding the arrays given.
    """
    entropy[unobserved] = 1.0
    channel[unobserved] = -1
    best_alpha[unobserved] = np.nan
    best_ks[unobserved] = np.nan
    if likelihood is not None:
        likelihood[unobserved] = prior_likelihood(grid, merge_zero=config.mode != "paper")

    flags = np.zeros(len(entropy), dtype=np.uint8)
    flags[unobserved] |= FLAG_UNOBSERVED
    if n_samples is not None:
        few = np.asarray(n_samples) < FEW_SAMPLES_FRACTION * n_coeffs
        flags[few & ~unobserved] |= FLAG_FEW_SAMPLES
    if alpha_bound is not None:
        with np.errstate(invalid="ignore"):  # NaN best_alpha compares False: not below the bound
            below = best_alpha < np.asarray(alpha_bound)
        flags[below & ~unobserved] |= FLAG_BELOW_BOUND
    flags[(entropy > config.ambiguous_entropy) & ~unobserved] |= FLAG_AMBIGUOUS

    return Uncertainty(entropy=entropy, flags=flags, likelihood=likelihood, best_alpha=best_alpha, best_ks=best_ks,
                       channel=channel, mode=config.mode, grid=grid)


def prior_likelihood(grid: HypothesisGrid, merge_zero: bool) -> np.ndarray:
    """Return the likelihood grid of a texel without information (the prior).

    Parameters
    ----------
    grid : HypothesisGrid
        The grid (R x R).
    merge_zero : bool
        Whether the k = 0 column is one material (uniform over the R (R-1) + 1 materials), else
        uniform over the R^2 cells.

    Returns
    -------
    (R, R) float32
        The prior, summing to 1.
    """
    resolution = grid.resolution
    if not merge_zero:
        return np.full((resolution, resolution), 1.0 / resolution**2, dtype=np.float32)
    n_materials = resolution * (resolution - 1) + 1
    prior = np.full((resolution, resolution), 1.0 / n_materials)
    prior[:, 0] /= resolution  # the k = 0 column is one material
    return prior.astype(np.float32)
