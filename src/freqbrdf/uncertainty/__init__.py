"""Per-texel uncertainty of the specular parameters (docs/method.md#entropy).

Per texel and colour channel, a grid of specular hypotheses psi = (alpha_i, k_j),
alpha_i = (i / (R-1))^2 and k_j = j / (R-1) (`hypothesis_grid`), is scored against what the
texel's samples say; the likelihood over the grid becomes a normalised entropy in [0, 1], and
the map is the minimum over RGB (the best-informed channel). ``UncertaintyConfig.mode`` chooses
how the grid is scored:

- ``calibrated`` (the default) and ``paper``, from the SH power spectra
  (`freqbrdf.uncertainty.spectral`: `entropy_from_spectra`): the paper's recipe, and an
  exposure-invariant posterior over the same grid with a noise model;
- ``angular``, on the samples with the ``global`` estimator's own model
  (`freqbrdf.uncertainty.angular`: `entropy_angular`, `entropy_from_moments`, and
  `AngularEntropy`, which `pipeline.fit` feeds from the estimator's search).

`entropy_map` dispatches on the mode. The result is an `Uncertainty`, with flags (``FLAG_*``, a
bit field per texel) that say why a texel should not be trusted, and `summary` condenses it for
``summary.json``. `roughness_std` (`freqbrdf.uncertainty.roughness_std`) is the posterior std of
the estimate's roughness, which ranks the estimate's errors better than the entropy.

The numba kernels are in `freqbrdf.uncertainty._kernels`. docs/results.md#the-entropy and
docs/results.md#the-roughness-std have the figures: speed, agreement with a path tracer,
how each map ranks the errors.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from freqbrdf.config import Config, EstimateConfig, UncertaintyConfig
from freqbrdf.uncertainty._kernels import CUTOFF
from freqbrdf.uncertainty._result import (
    FEW_SAMPLES_FRACTION,
    FLAG_AMBIGUOUS,
    FLAG_BELOW_BOUND,
    FLAG_FEW_SAMPLES,
    FLAG_NAMES,
    FLAG_UNOBSERVED,
    HypothesisGrid,
    Uncertainty,
    hypothesis_grid,
)
from freqbrdf.uncertainty.angular import AngularEntropy, entropy_angular, entropy_from_moments
from freqbrdf.uncertainty.roughness_std import CURVATURE_NOISE_FLOOR, PRIOR_ROUGHNESS_VARIANCE, roughness_std
from freqbrdf.uncertainty.spectral import cross_spectrum, entropy_from_spectra, hypothesis_filter

if TYPE_CHECKING:
    from freqbrdf.observe.observations import Observations

__all__ = [
    "FLAG_UNOBSERVED",
    "FLAG_FEW_SAMPLES",
    "FEW_SAMPLES_FRACTION",
    "FLAG_BELOW_BOUND",
    "FLAG_AMBIGUOUS",
    "FLAG_NAMES",
    "CUTOFF",
    "PRIOR_ROUGHNESS_VARIANCE",
    "CURVATURE_NOISE_FLOOR",
    "HypothesisGrid",
    "hypothesis_grid",
    "Uncertainty",
    "entropy_map",
    "roughness_std",
    "cross_spectrum",
    "hypothesis_filter",
    "entropy_from_spectra",
    "entropy_angular",
    "entropy_from_moments",
    "AngularEntropy",
    "summary",
]


def entropy_map(
    observations: Observations, config: UncertaintyConfig = UncertaintyConfig(), return_likelihood: bool = True,
    estimate_config: EstimateConfig = EstimateConfig(), device: str = "auto",
) -> Uncertainty:
    """Compute the uncertainty map of a capture's observations in ``config.mode``.

    Parameters
    ----------
    observations : Observations
        The texels' samples and SH fits (N texels).
    config : UncertaintyConfig
        The mode, grid, noise model and flags.
    return_likelihood : bool
        Whether to keep the (N, R, R) likelihood.
    estimate_config : EstimateConfig
        The estimator's model, with which the ``angular`` mode scores the hypotheses
        (`entropy_angular`); unused by the spectral modes.
    device : {"auto", "cpu", "cuda"}
        Where the entropy is computed (`freqbrdf.devices.resolve_device`).

    Returns
    -------
    Uncertainty
        Of the N texels; its roughness_std is not computed (`roughness_std`).

    Examples
    --------
    The calibrated entropy of a tiny synthetic capture's observations:

    >>> import tempfile
    >>> from pathlib import Path
    >>> from freqbrdf.capture import load
    >>> from freqbrdf.config import Config, TexelConfig
    >>> from freqbrdf.observe import observe
    >>> from freqbrdf.synthetic import example_capture
    >>> from freqbrdf.uncertainty import FLAG_UNOBSERVED, entropy_map
    >>> work = tempfile.TemporaryDirectory()
    >>> capture = load(example_capture(Path(work.name) / "capture"))
    >>> observations = observe(capture, Config(texels=TexelConfig(texture_res=32)))
    >>> uncertainty = entropy_map(observations)
    >>> uncertainty.mode, uncertainty.entropy.shape, uncertainty.flags.dtype  # (N,)
    ('calibrated', (1024,), dtype('uint8'))
    >>> uncertainty.likelihood.shape  # (N, R, R): the posterior over the hypothesis grid
    (1024, 8, 8)
    >>> bool(((0 <= uncertainty.entropy) & (uncertainty.entropy <= 1)).all())
    True
    >>> unobserved = (uncertainty.flags & FLAG_UNOBSERVED) != 0
    >>> bool((uncertainty.entropy[unobserved] == 1).all())  # nothing seen: the most uncertain
    True
    >>> work.cleanup()
    """
    if config.mode == "angular":
        return entropy_angular(observations, Config(uncertainty=config, estimate=estimate_config, device=device),
                               return_likelihood)
    return entropy_from_spectra(
        observations.mirrored_spectrum,
        observations.observed_spectrum,
        n_samples=observations.n_samples,
        sigma=observations.sigma,
        alpha_bound=observations.alpha_bound,
        fit_status=observations.fit_status,
        config=config,
        return_likelihood=return_likelihood,
        device=device,
    )


def summary(uncertainty: Uncertainty) -> dict:
    """Condense an uncertainty into the statistics of ``summary.json``.

    Flag fractions are over all texels; entropy statistics over texels with at least one sample;
    roughness_std statistics (when computed) over the estimated texels.

    Parameters
    ----------
    uncertainty : Uncertainty
        What to condense.

    Returns
    -------
    dict
        ``mode``, ``grid_res``, ``texels``, ``observed_texels``, ``entropy_mean``,
        ``entropy_median``, ``flagged_fraction`` (per flag name) and, when computed,
        ``roughness_std_mean`` and ``roughness_std_median``; NaN for a statistic of no texels.
    """
    observed = (uncertainty.flags & FLAG_UNOBSERVED) == 0
    entropy = uncertainty.entropy[observed].astype(np.float64)
    n_texels = len(uncertainty.entropy)
    spread = {}
    if uncertainty.roughness_std is not None:
        estimated = uncertainty.roughness_std[np.isfinite(uncertainty.roughness_std)].astype(np.float64)
        spread = {"roughness_std_mean": float(estimated.mean()) if len(estimated) else float("nan"),
                  "roughness_std_median": float(np.median(estimated)) if len(estimated) else float("nan")}
    return {
        "mode": uncertainty.mode,
        "grid_res": uncertainty.grid.resolution,
        "texels": n_texels,
        "observed_texels": int(observed.sum()),
        "entropy_mean": float(entropy.mean()) if len(entropy) else float("nan"),
        "entropy_median": float(np.median(entropy)) if len(entropy) else float("nan"),
        "flagged_fraction": {
            name: float(np.count_nonzero(uncertainty.flags & bit)) / max(n_texels, 1)
            for bit, name in FLAG_NAMES.items()
        },
        **spread,
    }
