"""The entropy of the specular hypotheses scored on the samples (docs/method.md#entropy, angular mode).

The R x R grid of `freqbrdf.uncertainty.spectral`, scored in the sample domain with the
``global`` estimator's own forward model instead of on spectra (``UncertaintyConfig.mode``
"angular"), as benchmarks/studies/pathtraced_entropy.py scores it with a path tracer. Per texel,
channel and hypothesis (alpha_i, k_j), a metal of base colour k_j and roughness sqrt(alpha_i)
reflects s_v = k_j X_v + Y_v at each observed view (split-sum albedo, the prefiltered and
environment light: `estimate.hypothesis_moments`); the best constant diffuse part is fitted and
the misfit of the samples weighed with the calibrated mode's noise model in radiance units.

It costs R probes of the estimator's search per texel. Inside `pipeline.fit` the search makes
those probes anyway and hands their moments to an `AngularEntropy` block by block
(`estimate.HypothesisRecorder`); with the default grid (the estimator's roughness nodes) that
costs the search no probe of its own. docs/results.md#angular-mode has the figures.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from freqbrdf.config import Config, UncertaintyConfig
from freqbrdf.devices import resolve_device
from freqbrdf.estimate import HYPOTHESIS_BLOCK, HypothesisRecorder, hypothesis_moments, texel_blocks
from freqbrdf.sphere import harmonics as sh
from freqbrdf.uncertainty._kernels import EntropyOutputs, MomentInputs, moment_entropy_kernel
from freqbrdf.uncertainty._result import Uncertainty, hypothesis_grid, uncertainty_of_grid

if TYPE_CHECKING:
    from freqbrdf.observe.observations import Observations


def entropy_angular(observations: Observations, config: Config = Config(),
                    return_likelihood: bool = True) -> Uncertainty:
    """Score the hypothesis grid on the samples with the ``global`` estimator's model.

    With the best view-independent (diffuse) part d = max(0, mean_w(f - s)) the misfit of a
    hypothesis is e = mean_w (f - d - s)^2 (w the sample weights, f the observed radiance; k = 0:
    no lobe, s = 0, not a black metal's grazing Fresnel). Noise variance: (noise_level x the RMS
    of the mirrored environment's radiance)^2 + the best misfit x n / (n - 3) (three parameters
    fitted); likelihood exp(-n (e - min e) / (2 variance)) over n samples; the k = 0 column is one
    material; normalised entropy, minimum over RGB. Scaling every image and the environment by
    kappa scales e and the variance by kappa^2: the map does not change. Costs R probes of the
    estimator's search per texel; `pipeline.fit` takes them from its own search instead
    (`AngularEntropy`).

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    config : Config
        ``uncertainty`` (its grid, noise level and flags), ``estimate`` (the model) and ``device``.
    return_likelihood : bool
        Whether to keep the (N, R, R) likelihood.

    Returns
    -------
    Uncertainty
        Of the N texels, mode "angular".
    """
    scorer = AngularEntropy(observations, config, return_likelihood)
    for rows in texel_blocks(observations.n_texels, HYPOTHESIS_BLOCK):
        scorer.consume(rows, hypothesis_moments(observations.select(rows), scorer.roughness, scorer.config))
    return scorer.result()


def entropy_from_moments(
    moments: np.ndarray, weight: np.ndarray, mirrored: np.ndarray, n_samples: np.ndarray, *,
    config: UncertaintyConfig = UncertaintyConfig(mode="angular"), return_likelihood: bool = True,
    device: str = "auto",
) -> Uncertainty:
    """Score the angular mode's grid from its hypotheses' moments alone.

    What `entropy_angular` and `AngularEntropy` do block by block. Texels without samples get the
    prior; no flags but FLAG_AMBIGUOUS (the sampling bound and the SH fit are not known here).

    Parameters
    ----------
    moments : (N, R, 3, 8) array_like
        The R x R hypotheses' moments, `estimate.hypothesis_moments` at roughness i / (R - 1).
    weight : (N, V) float32
        The samples' weights.
    mirrored : (N, V, 3) float32
        The samples' mirrored radiance (the noise floor's light).
    n_samples : (N,) int
        Samples per texel.
    config : UncertaintyConfig
        Mode "angular"; its noise level and ``ambiguous_entropy``.
    return_likelihood : bool
        Whether to keep the (N, R, R) likelihood.
    device : {"auto", "cpu", "cuda"}
        Where the grid is scored (`freqbrdf.devices.resolve_device`).

    Returns
    -------
    Uncertainty
        Of the N texels.
    """
    if config.mode != "angular":
        raise ValueError(f"moments are scored in the angular mode, not {config.mode!r}")
    n_texels, resolution = moments.shape[:2]
    if moments.shape[2:] != (3, 8) or weight.shape[0] != n_texels or mirrored.shape[:2] != weight.shape:
        raise ValueError(f"moments (N, R, 3, 8), weight (N, V) and mirrored (N, V, 3) disagree: {moments.shape}, "
                         f"{weight.shape}, {mirrored.shape}")
    grid = hypothesis_grid(resolution)
    outputs = EntropyOutputs(
        entropy=np.empty(n_texels, np.float32),
        channel=np.empty(n_texels, np.int8),
        best_alpha=np.empty(n_texels, np.float32),
        best_ks=np.empty(n_texels, np.float32),
        likelihood=np.empty((n_texels if return_likelihood else 0, resolution, resolution), np.float32),
    )
    inputs = MomentInputs(
        moments=np.ascontiguousarray(moments, dtype=np.float64), weight=weight, mirrored=mirrored,
        n_samples=n_samples, alphas=grid.alpha, specular=grid.specular, noise_level=float(config.noise_level),
        want_likelihood=bool(return_likelihood),
    )
    _score_moments(inputs, outputs, device)
    return uncertainty_of_grid(np.asarray(n_samples) == 0, outputs.entropy, outputs.channel, outputs.best_alpha,
                               outputs.best_ks, outputs.likelihood if return_likelihood else None, None, 0, None,
                               grid, config)


class AngularEntropy:
    """`entropy_angular` fed with its hypotheses' moments block by block.

    Fed by `entropy_angular`, or by the ``global`` estimator's search while it estimates
    (`estimate.estimate`'s ``hypotheses``, `recorder`), whose first scan probes the roughness
    nodes anyway. With the default grid (the estimator's nodes) that costs the search no probe of
    its own.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    config : Config
        ``uncertainty`` (grid, noise level, flags) and ``estimate`` (the model, its roughness
        grid: the default hypothesis grid).
    return_likelihood : bool
        Whether to keep the (N, R, R) likelihood.

    Attributes
    ----------
    grid : HypothesisGrid
        The hypotheses scored.
    roughness : (R,) float64
        Their roughness sqrt(alpha_i), the values the search records.
    seconds : float
        Time spent in `consume`.
    """

    def __init__(self, observations: Observations, config: Config = Config(), return_likelihood: bool = True):
        settings = config.uncertainty
        self.config = config
        self.grid = hypothesis_grid(settings.resolution(config.estimate.roughness_grid))
        self.roughness = np.sqrt(self.grid.alpha)  # (R,)
        self.observations = observations
        n_texels, resolution = observations.n_texels, self.grid.resolution
        self.entropy = np.empty(n_texels, np.float32)
        self.channel = np.empty(n_texels, np.int8)
        self.best_alpha = np.empty(n_texels, np.float32)
        self.best_ks = np.empty(n_texels, np.float32)
        self.likelihood = np.empty((n_texels, resolution, resolution), np.float32) if return_likelihood else None
        self.seconds = 0.0  # spent in `consume`

    @staticmethod
    def recorded_by_search(config: Config) -> bool:
        """Tell whether the estimator of ``config`` can record this mode's hypotheses as it searches.

        Parameters
        ----------
        config : Config
            The fit's settings.

        Returns
        -------
        bool
            True for the angular mode with the ``global`` estimator.
        """
        return config.uncertainty.mode == "angular" and config.estimate.method == "global"

    def recorder(self) -> HypothesisRecorder:
        """Make the recorder the search feeds (`estimate.estimate`'s ``hypotheses``).

        Returns
        -------
        HypothesisRecorder
            At `roughness`, calling `consume`.
        """
        return HypothesisRecorder(self.roughness, self.consume)

    def consume(self, rows: slice, moments: np.ndarray) -> None:
        """Score a block of texels from their hypotheses' moments.

        Parameters
        ----------
        rows : slice
            The block's texels among the N.
        moments : (n, R, 3, 8) float64
            Their `hypothesis_moments` at `roughness`.
        """
        start = time.perf_counter()
        want_likelihood = self.likelihood is not None
        observations = self.observations
        inputs = MomentInputs(
            moments=moments, weight=observations.weight[rows], mirrored=observations.mirrored[rows],
            n_samples=observations.n_samples[rows], alphas=self.grid.alpha, specular=self.grid.specular,
            noise_level=float(self.config.uncertainty.noise_level), want_likelihood=want_likelihood,
        )
        outputs = EntropyOutputs(
            entropy=self.entropy[rows], channel=self.channel[rows], best_alpha=self.best_alpha[rows],
            best_ks=self.best_ks[rows],
            likelihood=self.likelihood[rows] if want_likelihood else np.empty((0, 0, 0), np.float32),
        )
        _score_moments(inputs, outputs, self.config.device)
        self.seconds += time.perf_counter() - start

    def result(self) -> Uncertainty:
        """Return the Uncertainty, once every texel has been consumed.

        Returns
        -------
        Uncertainty
            Of the N texels, with the flags of the observations' sample counts and sampling bound.
        """
        observations = self.observations
        return uncertainty_of_grid(observations.n_samples == 0, self.entropy, self.channel, self.best_alpha,
                                   self.best_ks, self.likelihood, observations.n_samples,
                                   sh.num_coeffs(observations.lmax), observations.alpha_bound, self.grid,
                                   self.config.uncertainty)


def _score_moments(inputs: MomentInputs, outputs: EntropyOutputs, device: str) -> None:
    """Run the angular mode's kernel on the device that ``device`` resolves to."""
    if resolve_device(device) == "cuda":
        from freqbrdf.uncertainty._cuda_kernels import moment_entropy_on_cuda

        moment_entropy_on_cuda(inputs, outputs)
    else:
        moment_entropy_kernel(inputs, outputs)
