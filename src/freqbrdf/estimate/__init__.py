"""Per-texel base colour, roughness and metallic from the observations (docs/method.md#forward-model and docs/method.md#estimation).

Both estimators fit, per texel, view v and channel c, the radiance of the reflection model in
`freqbrdf.model`: a GGX lobe of roughness r (alpha = r^2) reading the incoming light through the
BRDF kernel, plus a diffuse term d E / pi, with R0 = 0.04 (1 - m) + b m and d = (1 - m) b.
``EstimateConfig`` chooses the model's pieces: the split-sum albedo or the angular model of docs/method.md#forward-model
(G1 and Schlick's Fresnel), Burley's diffuse or Lambert's, and which light a lobe reads (the
fitted light, the environment light of rough lobes, the prefiltered light of smooth ones). Where
a sample's mirror lobe meets the object itself (`Observations.mirror_occluded`, traced by
`freqbrdf.observe.occlusion.mirror_occlusion`), that share of the lobe's own light is what the
object shows there; the environment light that rough lobes blend in stays (a wide lobe reaches
past it).

Two estimators, in `ESTIMATORS`:

- ``global`` (`freqbrdf.estimate.search`, the default) minimises the weighted squared residual.
  For fixed (r, m) the model is linear in b, so the base colour is a clipped closed form and
  the metallic is profiled out; the roughness is searched on a grid and refined by Brent:
  the global optimum up to the grid's resolution. Robust passes then re-weight the samples
  towards an L1 loss, and a neighbour vote settles texels with two near-equal optima.
- ``paper`` (`freqbrdf.estimate.paper`) reproduces the authors' prototype: Adam on the L1 loss of
  the model of docs/method.md#forward-model over the whole texture, with texture-space total variation, for any of the
  three forward models (angular, SH coefficients, power spectrum).

Texels without a sample are left unestimated (NaN, ``estimated`` False); ``global`` also leaves
those with fewer than `MIN_SAMPLES` samples, which cannot determine five parameters. The caller
fills them for export.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from freqbrdf import texels
from freqbrdf.config import Config, EstimateConfig
from freqbrdf.estimate._global_kernels import scattering_stride
from freqbrdf.estimate._search_kernels import CURVATURE_STEP, FITTED_PARAMETERS, MIN_SAMPLES
from freqbrdf.estimate.paper import estimate_paper
from freqbrdf.estimate.search import (
    EstimatorResult,
    angular_loss,
    estimate_global,
    label_sums,
    prefilter_nodes,
    run_search_kernel,
    shadowed_light_coeffs,
    texel_blocks,
    uses_split_sum,
)
from freqbrdf.model import brdf
from freqbrdf.observe.observations import Observations
from freqbrdf.progress import SILENT, Reporter

__all__ = [
    "CURVATURE_STEP",
    "ESTIMATORS",
    "FITTED_PARAMETERS",
    "HYPOTHESIS_BLOCK",
    "MIN_SAMPLES",
    "EstimatorResult",
    "HypothesisRecorder",
    "MaterialEstimate",
    "angular_loss",
    "estimate",
    "hypothesis_moments",
    "label_sums",
    "model_light",
    "prefilter_nodes",
    "scattering_stride",
    "texel_blocks",
]

# Texels per block of hypothesis moments: bounds the (block, R, 3, 8) float64 moments.
HYPOTHESIS_BLOCK = 16384


@dataclass(eq=False)
class MaterialEstimate:
    """Principled parameters per texel of an `Observations` (N texels).

    Attributes
    ----------
    texture_res : int
        T, the side of the texture the texels index.
    texel_index : (N,) int64
        Flat row-major index of each texel into the T x T texture.
    base_color : (N, 3) float64
        Linear RGB in [0, 1]; NaN where not estimated.
    roughness, metallic : (N,) float64
        In [0, 1]; NaN where not estimated.
    estimated : (N,) bool
        Whether the texel was estimated.
    loss : (N,) float64
        The weighted mean squared residual of the angular model under the final light,
        sum_v,c w_v^2 (L_c(w_v) - f_v,c)^2 / sum_v w_v^2 (channels summed); NaN where not
        estimated.
    method : str
        "global" or "paper/<forward model>".
    timings : dict of str to float
        Seconds per stage.
    roughness_curvature : (N,) float64 or None
        ``global`` only: d^2 loss / d roughness^2 of the profiled loss (base colour and metallic
        re-optimised at each roughness) at the estimate, from a second divided difference over
        `CURVATURE_STEP` (one-sided within [0, 1]); NaN where not estimated. Its inverse scales
        the marginal posterior variance of the roughness (`uncertainty.roughness_std`).
    label_loss : (N, 2) float64 or None
        ``global`` only: the loss (as ``loss``, least squares) of the pure materials at the
        estimated roughness, base colour re-fitted: column 0 a dielectric (m = 0), column 1 a metal
        (m = 1); what the samples say about the metal label (`freqbrdf.estimate.surface`). NaN
        where not estimated.
    label_base_color : (N, 2, 3) float64 or None
        ``global`` only: those two materials' base colours; NaN where not estimated.
    """

    texture_res: int
    texel_index: np.ndarray
    base_color: np.ndarray
    roughness: np.ndarray
    metallic: np.ndarray
    estimated: np.ndarray
    loss: np.ndarray
    method: str
    timings: dict = field(default_factory=dict)
    roughness_curvature: np.ndarray | None = None
    label_loss: np.ndarray | None = None
    label_base_color: np.ndarray | None = None

    @property
    def n_texels(self) -> int:
        """N, the number of texels."""
        return len(self.texel_index)

    def principled(self) -> brdf.PrincipledParams:
        """Return the estimate as Principled parameters.

        Returns
        -------
        brdf.PrincipledParams
            Base colour (N, 3), roughness and metallic (N,); NaN where not estimated.
        """
        return brdf.PrincipledParams(base_color=self.base_color, roughness=self.roughness, metallic=self.metallic)

    def to_texture(self, values: np.ndarray, fill: float = np.nan) -> np.ndarray:
        """Scatter per-texel values into the texture.

        Parameters
        ----------
        values : (N,) or (N, C) array
            One value (or C) per texel.
        fill : float, optional
            The value of the texture's other pixels.

        Returns
        -------
        (T, T) or (T, T, C) array
            The texture.
        """
        return texels.scatter(self, np.asarray(values), fill)  # scatter reads texture_res, texel_index

    def textures(self) -> dict[str, np.ndarray]:
        """Return the estimate as textures.

        Returns
        -------
        dict of str to array
            "base_color" (T, T, 3), "roughness" and "metallic" (T, T) float64: NaN off the
            texels with a value (the estimated ones, and with the whole-surface solve every texel).
        """
        return {"base_color": self.to_texture(self.base_color), "roughness": self.to_texture(self.roughness),
                "metallic": self.to_texture(self.metallic)}


@dataclass(frozen=True)
class HypothesisRecorder:
    """Metal hypotheses for the ``global`` estimator to score on the way (`estimate`'s ``hypotheses``).

    Its first roughness scan probes every roughness node with the light and weights that
    `hypothesis_moments` uses, so a hypothesis on a node costs no probe of its own
    (`uncertainty.AngularEntropy` gets the angular entropy that way).

    Attributes
    ----------
    roughness : (R,) float64
        The hypotheses' roughness; each value off the search's nodes costs a probe.
    consume : callable
        Called once per block of texels, ``consume(rows, moments)``, with the block's slice of
        the N texels and its `hypothesis_moments` (n, R, 3, 8).
    block : int
        Texels per block; by default `HYPOTHESIS_BLOCK` at the time the recorder is made.
    """

    roughness: np.ndarray
    consume: Callable[[slice, np.ndarray], None]
    block: int = field(default_factory=lambda: HYPOTHESIS_BLOCK)


# An estimator: (observations, config, reporter, hypotheses or None) -> its result.
Estimator = Callable[[Observations, Config, Reporter, "HypothesisRecorder | None"], EstimatorResult]
ESTIMATORS: dict[str, Estimator] = {"global": estimate_global, "paper": estimate_paper}
"""The estimators by ``EstimateConfig.method``; only ``global`` records hypotheses."""


def estimate(observations: Observations, config: Config = Config(), reporter: Reporter = SILENT,
             hypotheses: HypothesisRecorder | None = None) -> MaterialEstimate:
    """Estimate base colour, roughness and metallic per texel with ``config.estimate.method``.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    config : Config, optional
        ``config.estimate`` chooses the estimator and its model; ``config.fit`` must be the fit
        the observations were made with (shadowing refreshes re-fit the light with it).
    reporter : Reporter, optional
        Receives progress.
    hypotheses : HypothesisRecorder, optional
        Method "global" only: the search also hands over the `hypothesis_moments` of these
        roughness values, block by block.

    Returns
    -------
    MaterialEstimate
        The estimate.

    Raises
    ------
    ValueError
        If the settings are invalid, or ``hypotheses`` are given to another method.

    Examples
    --------
    The per-texel estimate of a tiny synthetic capture's observations (`freqbrdf.pipeline.fit`
    adds the whole-surface estimate, which also gives values to the texels left NaN here):

    >>> import tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> from freqbrdf.capture import load
    >>> from freqbrdf.config import Config, TexelConfig
    >>> from freqbrdf.estimate import estimate
    >>> from freqbrdf.observe import observe
    >>> from freqbrdf.synthetic import example_capture
    >>> work = tempfile.TemporaryDirectory()
    >>> capture = load(example_capture(Path(work.name) / "capture"))
    >>> config = Config(texels=TexelConfig(texture_res=32))
    >>> materials = estimate(observe(capture, config), config)
    >>> materials.method, materials.base_color.shape, materials.roughness.shape  # (N, 3), (N,)
    ('global', (1024, 3), (1024,))
    >>> seen = materials.estimated
    >>> bool(np.isnan(materials.roughness[~seen]).all())  # not estimated: NaN
    True
    >>> roughness = materials.roughness[seen]
    >>> bool(((0 <= roughness) & (roughness <= 1)).all())
    True
    >>> work.cleanup()
    """
    settings = config.estimate
    _validate(settings)
    if hypotheses is not None and settings.method != "global":
        raise ValueError("only the global estimator records hypotheses: its search probes them")
    return _material_estimate(observations, ESTIMATORS[settings.method](observations, config, reporter, hypotheses))


def model_light(observations: Observations, roughness: np.ndarray, config: Config = Config()) -> np.ndarray:
    """Return the incoming light's SH fit as the estimator's model sees it at a roughness.

    Shadowed by G1 for the model of docs/method.md#forward-model with shadowing on, else the mirrored light (the
    split-sum albedo holds the shadowing). Pass it to `angular_loss` to score parameters as the
    estimator does.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    roughness : (N,) float64
        The roughness per texel.
    config : Config, optional
        The estimator's settings (``config.estimate``) and the fit (``config.fit``).

    Returns
    -------
    (N, 3, K) float32
        The light's SH coefficients per texel and channel.
    """
    settings = config.estimate
    if not settings.shadowing or uses_split_sum(settings):
        return observations.mirrored_coeffs
    return shadowed_light_coeffs(observations, brdf.alpha_from_roughness(roughness), config.fit)


def hypothesis_moments(observations: Observations, roughness: np.ndarray, config: Config = Config()) -> np.ndarray:
    """Return the weighted moments that score metal hypotheses under the ``global`` model.

    A metal of base colour k reflects k X + Y under the ``global`` estimator's model of
    ``config.estimate`` (X = A S_A, Y = B S_B: Schlick's Fresnel with R0 = k, the light as that
    model reads it; with "g1" the unshadowed light). The weighted misfit of any specular
    hypothesis (roughness, k) plus a constant diffuse part is a quadratic in k and the diffuse
    part from these moments (`uncertainty.entropy_angular`), and so is that of no specular lobe.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    roughness : (R,) float64
        The hypotheses' roughness.
    config : Config, optional
        The estimator's settings; ``device`` where the search's probes run.

    Returns
    -------
    (N, R, 3, 8) float64
        Per texel, hypothesis and channel: [sum w, sum w u, sum w X, sum w u^2, sum w u X,
        sum w X^2, sum w f, sum w f^2] over the texel's samples, w the sample weight, f the
        observed radiance, u = f - Y. Zero for texels with fewer than `MIN_SAMPLES` samples.
    """
    settings = config.estimate
    _validate(settings)
    roughness = np.ascontiguousarray(roughness, dtype=np.float64)
    moments = np.zeros((observations.n_texels, len(roughness), 3, 8))
    n_texels = observations.n_texels
    run_search_kernel(observations, settings, observations.mirrored_coeffs, roughness, moments, False,
                      np.zeros((n_texels, 5)), np.zeros(n_texels), np.zeros(n_texels), device=config.device)
    return moments


def _validate(settings: EstimateConfig) -> None:
    if settings.method not in ESTIMATORS:
        raise ValueError(f"unknown estimator {settings.method!r}; choose 'global' or 'paper'")
    if settings.forward_model not in ("angular", "sh_coeffs", "spectrum"):
        raise ValueError(f"unknown forward model {settings.forward_model!r}")
    if settings.method == "global" and settings.forward_model != "angular":
        raise ValueError("the global estimator searches the angular model; use forward_model='angular'")
    if settings.specular_model not in ("split_sum", "g1") or settings.diffuse_model not in ("burley", "lambert"):
        raise ValueError(f"unknown specular_model {settings.specular_model!r} or diffuse_model "
                         f"{settings.diffuse_model!r}; choose 'split_sum'/'g1' and 'burley'/'lambert'")
    if settings.dielectric_fresnel not in ("exact", "schlick"):
        raise ValueError(f"unknown dielectric_fresnel {settings.dielectric_fresnel!r}; choose 'exact' or 'schlick'")
    if settings.robust_passes < 0:
        raise ValueError("robust_passes must be >= 0")
    if not 0.0 <= settings.environment_blend[0] < settings.environment_blend[1]:
        raise ValueError(f"environment_blend must be (start, end) with 0 <= start < end, got "
                         f"{settings.environment_blend}")
    if settings.roughness_grid < 2 or settings.metallic_grid < 2:
        raise ValueError("roughness_grid and metallic_grid need at least 2 nodes")
    if settings.shadowing_refresh_every < 1 or settings.iterations < 0 or settings.shadowing_refreshes < 0:
        raise ValueError("iterations and shadowing_refreshes must be >= 0, shadowing_refresh_every >= 1")


def _material_estimate(observations: Observations, result: EstimatorResult) -> MaterialEstimate:
    """Make the `MaterialEstimate` of an estimator's result: NaN where not estimated."""
    unknown = ~result.estimated
    params = result.params.copy()
    params[unknown] = np.nan
    curvature = result.roughness_curvature
    return MaterialEstimate(
        texture_res=observations.texture_res,
        texel_index=observations.texel_index,
        base_color=params[:, :3],
        roughness=params[:, 3],
        metallic=params[:, 4],
        estimated=result.estimated,
        loss=np.where(unknown, np.nan, result.loss),
        method=result.method,
        timings=result.timings,
        roughness_curvature=None if curvature is None else np.where(result.estimated, curvature, np.nan),
        label_loss=None if result.label_loss is None else np.where(unknown[:, None], np.nan, result.label_loss),
        label_base_color=(None if result.label_base_color is None
                          else np.where(unknown[:, None, None], np.nan, result.label_base_color)),
    )
