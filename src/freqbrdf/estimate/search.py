"""The ``global`` estimator: an exhaustive search with a closed-form base colour (docs/method.md#estimation).

It minimises the weighted squared residual sum_v w_v^2 (L(w_v) - f_v)^2 of the model in
`freqbrdf.model`. Write L = m (b X + Y) + (1 - m) Z + (1 - m) b e D with X = A S_A, Y = B S_B,
Z = E S_E (S_k the light as lobe term k reads it, A, B, E the split-sum albedo terms) and
e = E / pi. For fixed (r, m) the model is linear in b per channel, so the best b is a clipped
closed form, and the loss at it a function of quadratics in m from 14 weighted moments of X, Y, Z,
D and f over the views. The roughness is searched on a grid with the metallic profiled out
(grid, then safeguarded Newton) at each node, and the best cell is refined by Brent started from
the parabola through the best node and its neighbours: the global optimum in (b, m, r) up to the
grid's resolution. ``EstimateConfig.robust_passes`` passes of iteratively re-weighted least
squares then move towards the L1 loss, weighting a sample by w / max(|r|, a tenth of the texel's
mean |r|), so that samples the model cannot explain count less.

The angular model (docs/method.md#forward-model) shadows the light by G1 before its fit, which makes the light depend
on the roughness: the first search uses the unshadowed light, and each of
``EstimateConfig.shadowing_refreshes`` refreshes re-fits it shadowed at a secant prediction of the
fixed point r = search(light shadowed at r) and searches again. The split-sum albedo holds the
shadowing, so it fits the light once.

Last, the neighbour vote (``EstimateConfig.neighbour_vote``): where the median roughness (or
metallic) of a texel's 5 x 5 neighbours lies more than a grid cell from its estimate, a local
minimum near that median replaces it, unless the texel's own data reject it by a
likelihood-ratio test at 95 %.

This module builds the kernels' records (`freqbrdf.estimate._records`) from the observations and
runs the kernels (`freqbrdf.estimate._global_kernels` and the pieces in
`freqbrdf.estimate._search_kernels`, `freqbrdf.estimate._loss_kernels`) on the CPU, or their CUDA
port (`freqbrdf.estimate._cuda_kernels`) where ``Config.device`` resolves to CUDA.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from freqbrdf.config import Config, EstimateConfig, FitConfig
from freqbrdf.devices import resolve_device
from freqbrdf.estimate._global_kernels import global_search_kernel
from freqbrdf.estimate._loss_kernels import squared_residual_kernel
from freqbrdf.estimate._records import (
    EnvironmentLight,
    Estimates,
    Hypotheses,
    ModelOptions,
    ModelTables,
    PrefilteredLight,
    Samples,
    SearchSettings,
    ShRecurrence,
)
from freqbrdf.estimate._search_kernels import MIN_SAMPLES
from freqbrdf.model import brdf
from freqbrdf.model.light import (
    environment_azimuthal,
    environment_quadrature,
    mirror_projections,
    prefiltered_environment,
)
from freqbrdf.model.tables import (
    ENVIRONMENT_LMAX,
    PREFILTER_STEP,
    TABLE_COS_NODES,
    burley_response_table,
    environment_response_table,
    split_sum_rows,
    split_sum_table,
)
from freqbrdf.observe.observations import Observations
from freqbrdf.progress import Reporter
from freqbrdf.sphere import envmap as envmaps
from freqbrdf.sphere import harmonics as sh

if TYPE_CHECKING:
    from freqbrdf.estimate import HypothesisRecorder

# Texels per block when expanding the light by degree: bounds the (block, V, K) SH basis.
_PROJECTION_BLOCK = 8192
# Texels per call of the search kernel: the progress bar's step.
SEARCH_BLOCK = 8192
# Roughness nodes (0, PREFILTER_STEP, ..., 1) of the degrees the environment light leaves out.
_HIGH_NODES = round(1.0 / PREFILTER_STEP) + 1
# The last prefiltered stack: `angular_loss` and `hypothesis_moments` run many times on the same
# observations (uncertainty, sharing, blocks of texels), and its transforms are costly.
_PREFILTERED_CACHE: dict = {}


class EstimatorResult(NamedTuple):
    """What an estimator of `freqbrdf.estimate.ESTIMATORS` returns (N texels).

    Attributes
    ----------
    params : (N, 5) float64
        Base colour RGB, roughness, metallic; undefined where not estimated.
    loss : (N,) float64
        `MaterialEstimate.loss`; undefined where not estimated.
    estimated : (N,) bool
        The texels estimated.
    method : str
        `MaterialEstimate.method`.
    timings : dict of str to float
        Seconds per stage.
    roughness_curvature : (N,) float64 or None
        `MaterialEstimate.roughness_curvature`, or None where the estimator has none.
    label_loss : (N, 2) float64 or None
        `MaterialEstimate.label_loss`, or None where the estimator has none.
    label_base_color : (N, 2, 3) float64 or None
        `MaterialEstimate.label_base_color`, or None where the estimator has none.
    """

    params: np.ndarray
    loss: np.ndarray
    estimated: np.ndarray
    method: str
    timings: dict
    roughness_curvature: np.ndarray | None
    label_loss: np.ndarray | None = None
    label_base_color: np.ndarray | None = None


def estimate_global(observations: Observations, config: Config, reporter: Reporter,
                    hypotheses: HypothesisRecorder | None) -> EstimatorResult:
    """Estimate the Principled parameters per texel with the global search.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    config : Config
        ``config.estimate`` the search's settings; ``config.fit`` the fit the observations were
        made with (shadowing refreshes re-fit the light with it).
    reporter : Reporter
        Receives progress.
    hypotheses : HypothesisRecorder or None
        Hypotheses the first search records on its way, handed over block by block.

    Returns
    -------
    EstimatorResult
        The estimate of the texels with at least `MIN_SAMPLES` samples.
    """
    settings = config.estimate
    timings = {"light": 0.0, "search": 0.0}
    n_texels = observations.n_texels
    estimated = observations.n_samples >= MIN_SAMPLES
    params = np.zeros((n_texels, 5))  # base colour RGB, roughness, metallic
    loss = np.zeros(n_texels)
    curvature = np.zeros(n_texels)
    labels = (np.zeros((n_texels, 2)), np.zeros((n_texels, 2, 3)))  # as a dielectric and as a metal
    # The light of pass 0 is unshadowed, i.e. shadowed at alpha = 0 (G1 = 1). Each further pass
    # shadows it at a roughness closer to the fixed point r = search(light shadowed at r): a
    # secant step on search(r) - r, which converges much faster than re-using the last estimate.
    light = observations.mirrored_coeffs
    shadow_roughness = np.zeros(n_texels)
    previous_roughness = previous_residual = None
    # The split-sum albedo holds the shadowing: the light is never re-fitted.
    split_sum = uses_split_sum(settings)
    n_passes = 1 + (settings.shadowing_refreshes if settings.shadowing and not split_sum else 0)
    # In blocks of texels, so that the bar moves; each texel's search is its own, whatever the blocks.
    blocks = list(texel_blocks(n_texels, SEARCH_BLOCK)) if hypotheses is None else [slice(0, n_texels)]
    with reporter.stage("estimating (global)", n_passes * len(blocks) + settings.neighbour_vote) as advance:
        for pass_index in range(n_passes):
            tick = time.perf_counter()
            if pass_index > 0:
                light = shadowed_light_coeffs(observations, brdf.alpha_from_roughness(shadow_roughness), config.fit,
                                              config.device)
            timings["light"] += time.perf_counter() - tick
            tick = time.perf_counter()
            if pass_index == 0 and hypotheses is not None:  # pass 0's light is the one hypotheses are scored in
                for rows in texel_blocks(n_texels, hypotheses.block):
                    moments = np.zeros((rows.stop - rows.start, len(hypotheses.roughness), 3, 8))
                    run_search_kernel(observations.select(rows), settings, light[rows], hypotheses.roughness,
                                      moments, True, params[rows], loss[rows], curvature[rows],
                                      labels=(labels[0][rows], labels[1][rows]), device=config.device)
                    hypotheses.consume(rows, moments)
            else:
                for rows in blocks:
                    run_search_kernel(observations.select(rows), settings, light[rows], np.zeros(0),
                                      np.zeros((0, 0, 3, 8)), True, params[rows], loss[rows], curvature[rows],
                                      labels=(labels[0][rows], labels[1][rows]), device=config.device)
                    advance(1)
            timings["search"] += time.perf_counter() - tick
            residual = params[:, 3] - shadow_roughness
            next_roughness = params[:, 3].copy()
            if previous_residual is not None:
                slope = residual - previous_residual
                usable = np.abs(slope) > 1e-12
                secant = shadow_roughness[usable] - residual[usable] * (
                    shadow_roughness[usable] - previous_roughness[usable]) / slope[usable]
                next_roughness[usable] = np.where((secant >= 0.0) & (secant <= 1.0), secant, next_roughness[usable])
            previous_roughness, previous_residual = shadow_roughness, residual
            shadow_roughness = next_roughness
            if pass_index == 0 and hypotheses is not None:
                advance(1)
        if settings.neighbour_vote:
            tick = time.perf_counter()
            candidate = np.stack([neighbour_median(observations, np.where(estimated, params[:, column], np.nan))
                                  for column in (3, 4)], axis=1)  # (N, 2) roughness, metallic
            candidate = np.where(np.isnan(candidate), params[:, 3:5], candidate)
            run_search_kernel(observations, settings, light, np.zeros(0), np.zeros((0, 0, 3, 8)), False, params,
                              loss, curvature, candidate, labels=labels, device=config.device)
            timings["vote"] = time.perf_counter() - tick
            advance(1)
    timings["total"] = sum(timings.values())
    return EstimatorResult(params, loss, estimated, "global", timings, curvature, *labels)


def run_search_kernel(observations: Observations, settings: EstimateConfig, light: np.ndarray,
                      hypothesis_roughness: np.ndarray, hypothesis_moments: np.ndarray, search: bool,
                      params: np.ndarray, loss: np.ndarray, curvature: np.ndarray,
                      candidate: np.ndarray = np.zeros((0, 2)),
                      labels: tuple[np.ndarray, np.ndarray] | None = None, device: str = "auto",
                      label_moments: np.ndarray | None = None) -> None:
    """Run the search kernel on the observations.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    settings : EstimateConfig
        The search's settings.
    light : (N, 3, K) array
        The incoming light's SH fit.
    hypothesis_roughness : (R,) float64
        Roughness hypotheses whose moments to record (`hypothesis_moments`); (0,): none.
    hypothesis_moments : (N, R, 3, 8) float64
        Receives their moments.
    search : bool
        Search the roughness; the first scan records the hypotheses on the grid's nodes.
        Without it, only the hypotheses (or the neighbour vote) are evaluated.
    params : (N, 5) float64
        Receives base colour RGB, roughness and metallic; the vote's starting estimate.
    loss, curvature : (N,) float64
        Receive `MaterialEstimate.loss` and the unnormalised roughness curvature.
    candidate : (N, 2) float64, optional
        The neighbour vote's (roughness, metallic) per texel; (0, 2): no vote.
    labels : tuple of (N, 2) and (N, 2, 3) float64, optional
        Receive the loss and base colour as a dielectric and as a metal at the estimated roughness
        (`MaterialEstimate.label_loss`, ``label_base_color``): after a search, and where the
        neighbour vote moves a texel's roughness.
    device : {"auto", "cpu", "cuda"}, optional
        Where the search runs (`freqbrdf.devices.resolve_device`); the backends agree to rounding
        (docs/results.md).
    label_moments : (N, S, 3, 16) float64, optional
        With ``labels``, after a search: receives per channel the weighted sums the label losses
        come from, at the estimated roughness and at S - 1 roughness nodes evenly on [0, 1]
        (`Estimates.label_moments`).
    """
    tangent, environment, prefiltered = _light_inputs(observations, settings)
    hypothesis_roughness = np.ascontiguousarray(hypothesis_roughness, dtype=np.float64)
    node_rows = (_node_rows(hypothesis_roughness, settings.roughness_grid) if search and len(hypothesis_roughness)
                 else np.full(0, -1, dtype=np.int64))
    kernel = global_search_kernel
    if resolve_device(device) == "cuda":
        from freqbrdf.estimate._cuda_kernels import global_search_on_cuda as kernel
    kernel(
        _samples(observations, tangent), np.ascontiguousarray(light, dtype=np.float32),
        ShRecurrence(observations.lmax, *sh._legendre_tables(observations.lmax)), _model_options(observations, settings),
        _model_tables(settings), environment, prefiltered,
        SearchSettings(settings.roughness_grid, settings.metallic_grid, settings.robust_passes, search),
        Hypotheses(hypothesis_roughness, hypothesis_moments, node_rows), candidate,
        Estimates(params, loss, curvature, *(labels or (np.zeros((0, 2)), np.zeros((0, 2, 3)))),
                  np.zeros((0, 1, 3, 16)) if label_moments is None else label_moments),
    )


def label_sums(observations: Observations, config: Config, roughness_nodes: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """Search every texel and return the weighted sums its pure materials' losses come from.

    One search pass (no shadowing refresh, no neighbour vote) with ``config.estimate``; per texel
    and channel the 14 weighted sums of `freqbrdf.estimate._profile_kernels.metallic_quadratics`,
    sum w^2 f^2 and the diffuse scale e, at the estimated roughness and at ``roughness_nodes``
    roughness values evenly on [0, 1]: with them the loss of a dielectric or a metal of any base
    colour, at any gain of the photographs, is closed form (`freqbrdf.calibrate.gains.channel_gains`).

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    config : Config
        The estimator's settings.
    roughness_nodes : int, optional
        S - 1, the roughness values besides the estimate (>= 2).

    Returns
    -------
    params : (N, 5) float64
        Base colour RGB, roughness and metallic; zero where fewer than `MIN_SAMPLES` samples.
    sums : (N, S, 3, 16) float64
        The sums, slot 0 at the estimated roughness, slot i > 0 at (i - 1) / (S - 2); zero where
        fewer than `MIN_SAMPLES` samples.
    """
    n_texels = observations.n_texels
    params, loss, curvature = np.zeros((n_texels, 5)), np.zeros(n_texels), np.zeros(n_texels)
    labels = (np.zeros((n_texels, 2)), np.zeros((n_texels, 2, 3)))
    sums = np.zeros((n_texels, 1 + max(int(roughness_nodes), 2), 3, 16))
    run_search_kernel(observations, config.estimate, observations.mirrored_coeffs, np.zeros(0),
                      np.zeros((0, 0, 3, 8)), True, params, loss, curvature, labels=labels, device=config.device,
                      label_moments=sums)
    return params, sums


def angular_loss(
    observations: Observations,
    params: brdf.PrincipledParams,
    config: Config = Config(),
    light_coeffs: np.ndarray | None = None,
) -> np.ndarray:
    """Return the weighted mean squared residual of parameters under the ``global`` model.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    params : brdf.PrincipledParams
        Base colour (N, 3), roughness and metallic (N,).
    config : Config, optional
        The model's settings (``config.estimate``).
    light_coeffs : (N, 3, K) array, optional
        The incoming light's SH fit (`model_light`); default the unshadowed mirrored light.

    Returns
    -------
    (N,) float64
        sum_v,c w_v^2 (L_c(w_v) - f_v,c)^2 / sum_v w_v^2 (`MaterialEstimate.loss`); NaN for texels
        without samples.
    """
    loss, _ = _model_residuals(observations, params, config, light_coeffs, predict=False)
    return np.where(observations.n_samples > 0, loss, np.nan)


def predict_samples(observations: Observations, params: brdf.PrincipledParams, config: Config = Config()) -> np.ndarray:
    """Return the radiance the ``global`` model predicts at every sample of positive weight.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels, V views).
    params : brdf.PrincipledParams
        Base colour (N, 3), roughness and metallic (N,).
    config : Config, optional
        The model's settings (``config.estimate``); the light is the unshadowed mirrored light.

    Returns
    -------
    (N, V, 3) float32
        L_c(w_v) per sample; NaN where the weight is 0.
    """
    _, predicted = _model_residuals(observations, params, config, None, predict=True)
    return predicted


def _model_residuals(observations: Observations, params: brdf.PrincipledParams, config: Config,
                     light_coeffs: np.ndarray | None, predict: bool) -> tuple[np.ndarray, np.ndarray]:
    """Return the model's weighted mean squared residual (N,) and radiance (N, V, 3).

    The radiance is NaN where not predicted, and (N, 0, 3) unless ``predict``.
    """
    settings = config.estimate
    light = observations.mirrored_coeffs if light_coeffs is None else light_coeffs
    loss = np.empty(observations.n_texels)
    predicted = np.full((observations.n_texels, observations.n_views if predict else 0, 3), np.nan, np.float32)
    base_color = np.asarray(params.base_color, dtype=np.float64)
    metallic = np.asarray(params.metallic, dtype=np.float64)
    tangent, environment, prefiltered = _light_inputs(observations, settings)
    options, tables = _model_options(observations, settings), _model_tables(settings)
    for rows in texel_blocks(observations.n_texels, _PROJECTION_BLOCK):
        if len(environment.coeffs):
            azimuthal = np.ascontiguousarray(environment_azimuthal(
                observations.view_direction[rows], observations.weight[rows], tangent[rows],
                observations.normal[rows], environment.coeffs))
        else:
            azimuthal = np.zeros((rows.stop - rows.start, observations.n_views, 3, 0))
        # The prefiltered light replaces the fitted one: its expansion would be read by nothing.
        fitted = (np.zeros((rows.stop - rows.start, 3, 1, observations.n_views), np.float32) if prefiltered.n_full
                  else mirror_projections(observations.view_direction[rows], observations.weight[rows], light[rows],
                                          observations.lmax))
        squared_residual_kernel(
            fitted, _samples(observations, tangent, rows), base_color[rows], metallic[rows],
            np.asarray(params.roughness, dtype=np.float64)[rows], options, tables, environment, azimuthal,
            prefiltered, loss[rows], predicted[rows],
        )
    return loss, predicted


def texel_blocks(n_texels: int, size: int = _PROJECTION_BLOCK) -> Iterator[slice]:
    """Split the texels into consecutive blocks.

    Parameters
    ----------
    n_texels : int
        N.
    size : int, optional
        Texels per block (the last one may hold fewer).

    Yields
    ------
    slice
        The rows of one block.
    """
    for start in range(0, n_texels, size):
        yield slice(start, min(start + size, n_texels))


def neighbour_median(observations: Observations, values: np.ndarray, window: int = 5) -> np.ndarray:
    """Return the median of per-texel values over each texel's neighbours in the texture.

    Parameters
    ----------
    observations : Observations
        The texels (N of them) and their texture.
    values : (N,) float64
        One value per texel; NaN values are left out.
    window : int, optional
        The side of the square of texels around each texel (the texel itself left out, and
        texels off the mesh).

    Returns
    -------
    (N,) float64
        The median; NaN where no neighbour has a value.
    """
    texture = observations.to_texture(np.asarray(values, np.float64), fill=np.nan)
    reach = window // 2
    padded = np.pad(texture, reach, constant_values=np.nan)
    rows, cols = np.divmod(observations.texel_index, observations.texture_res)
    squares = np.lib.stride_tricks.sliding_window_view(padded, (window, window))[rows, cols]  # (N, window, window)
    squares = squares.reshape(len(rows), window * window).copy()
    squares[:, window * window // 2] = np.nan  # not the texel itself
    squares.sort(axis=1)  # NaN last
    counts = np.sum(~np.isnan(squares), axis=1)
    index = np.arange(len(counts))
    # Sorted once: faster than np.nanmedian.
    median = 0.5 * (squares[index, np.maximum(counts - 1, 0) // 2] + squares[index, counts // 2])
    return np.where(counts > 0, median, np.nan)


def prefilter_nodes(settings: EstimateConfig) -> int:
    """Return how many prefiltered maps the estimator reads.

    Their roughness nodes are 0, `PREFILTER_STEP`, ..., up to where the environment light takes
    over (``environment_blend[1]``), or to roughness 1 without it.

    Parameters
    ----------
    settings : EstimateConfig
        The estimator's settings.

    Returns
    -------
    int
        The number of nodes.
    """
    end = settings.environment_blend[1] if settings.environment_light else 1.0
    return min(math.ceil(end / PREFILTER_STEP - 1e-9), round(1.0 / PREFILTER_STEP)) + 1


def uses_split_sum(settings: EstimateConfig) -> bool:
    """Return whether the estimator's model is the split-sum one.

    Parameters
    ----------
    settings : EstimateConfig
        The estimator's settings.

    Returns
    -------
    bool
        True for the ``global`` estimator with ``specular_model`` "split_sum".
    """
    return settings.method == "global" and settings.specular_model == "split_sum"


def lambert_scale(observations: Observations) -> np.ndarray:
    """Return the Lambertian radiance per unit diffuse albedo.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).

    Returns
    -------
    (N, 3) float64
        E / pi, E the irradiance.
    """
    return observations.irradiance.astype(np.float64) / np.pi


def shadowed_light_coeffs(observations: Observations, alpha: np.ndarray, fit: FitConfig,
                          device: str = "auto") -> np.ndarray:
    """Fit the mirrored light shadowed by G1 (appendix eq. 6).

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    alpha : (N,) float64
        The GGX width per texel.
    fit : FitConfig
        The SH fit's settings.
    device : {"auto", "cpu", "cuda"}, optional
        Where the fit runs (`freqbrdf.sphere.harmonics.fit_sh`).

    Returns
    -------
    (N, 3, K) float32
        The SH fit of the mirrored light shadowed by G1(theta_i, alpha).
    """
    light = brdf.shadowed_light(observations.mirrored, observations.view_direction[..., 2], alpha)
    return sh.fit_sh(
        observations.view_direction, observations.weight, light.astype(np.float32), observations.lmax,
        fit.reg_lambda, fit.regulariser, fit.scale_lambda_with_weight, device,
    ).coeffs


def _node_rows(roughness: np.ndarray, roughness_grid: int) -> np.ndarray:
    """Return, per roughness node of the search, the index into roughness (R,) of a hypothesis there.

    (roughness_grid,) int64; -1 where none.
    """
    rows = np.full(roughness_grid, -1, dtype=np.int64)
    nodes = np.rint(roughness * (roughness_grid - 1)).astype(np.int64)
    on_node = (np.abs(nodes / (roughness_grid - 1) - roughness) < 1e-12) & (nodes >= 0) & (nodes < roughness_grid)
    rows[nodes[on_node]] = np.flatnonzero(on_node)
    return rows


def _samples(observations: Observations, tangent: np.ndarray, rows: slice = slice(None)) -> Samples:
    """Return the kernels' `Samples` of these rows of the observations (tangent (N, 3): `_light_inputs`)."""
    if observations.mirror_occluded is None:  # not traced: no mirror lobe meets the object
        occluded = np.zeros((observations.n_texels, 0), dtype=np.float32)[rows]
        surface = np.zeros((observations.n_texels, 0, 3), dtype=np.float32)[rows]
    else:
        occluded, surface = observations.mirror_occluded[rows], observations.mirror_surface[rows]
    return Samples(observations.view_direction[rows], observations.weight[rows], observations.observed[rows],
                   lambert_scale(observations)[rows], tangent[rows], observations.normal[rows], occluded, surface)


def _model_options(observations: Observations, settings: EstimateConfig) -> ModelOptions:
    """Return the kernels' `ModelOptions` for these settings."""
    return ModelOptions(observations.sigma, settings.fresnel, settings.masking, uses_split_sum(settings),
                        _uses_exact_dielectric(settings), _uses_burley(settings))


def _model_tables(settings: EstimateConfig) -> ModelTables:
    """Return the kernels' `ModelTables`.

    Burley's response only when Burley's diffuse reads the environment's light (with the
    environment light), else an empty one (uniform light).
    """
    if _uses_burley(settings) and settings.environment_light and settings.burley_environment:
        burley_response = burley_response_table()
    else:
        burley_response = np.zeros((4, TABLE_COS_NODES, 0))
    return ModelTables(split_sum_table(), split_sum_rows(), environment_response_table(), burley_response)


def _uses_burley(settings: EstimateConfig) -> bool:
    return settings.method == "global" and settings.diffuse_model == "burley"


def _uses_exact_dielectric(settings: EstimateConfig) -> bool:
    return uses_split_sum(settings) and settings.fresnel and settings.dielectric_fresnel == "exact"


def _uses_environment_light(observations: Observations, settings: EstimateConfig) -> bool:
    """Tell whether the environment light applies: the split-sum model and an environment."""
    return (uses_split_sum(settings) and settings.environment_light and observations.tangent is not None
            and observations.environment_coeffs is not None)


def _uses_prefiltered_light(observations: Observations, settings: EstimateConfig) -> bool:
    """Tell whether the prefiltered light applies: the split-sum model, a map and frames."""
    return (uses_split_sum(settings) and settings.prefiltered_light and observations.tangent is not None
            and observations.environment() is not None)


def _light_inputs(observations: Observations,
                  settings: EstimateConfig) -> tuple[np.ndarray, EnvironmentLight, PrefilteredLight]:
    """(tangent (N, 3), the environment light, the prefiltered light) for the kernels.

    The environment's SH up to degree min(l*, 5) (K = 0 without the environment light), no maps
    without the prefiltered light. The prefiltered maps are `prefilter_nodes` full maps, then (with
    the environment light) the degrees above the environment light's at all `_HIGH_NODES`
    roughness nodes: what the environment light adds.
    """
    tangent = np.zeros((observations.n_texels, 3), np.float32) if observations.tangent is None else observations.tangent
    environment_degrees = min(observations.lmax, ENVIRONMENT_LMAX)
    if _uses_environment_light(observations, settings):
        coeffs = np.ascontiguousarray(observations.environment_coeffs[:sh.num_coeffs(environment_degrees)],
                                      dtype=np.float64)
        blend = np.array([float(b) for b in settings.environment_blend])
    else:
        coeffs, blend = np.zeros((0, 3)), np.zeros(2)
    environment = EnvironmentLight(coeffs, blend, *environment_quadrature(max(math.isqrt(len(coeffs)) - 1, 0)))
    if _uses_prefiltered_light(observations, settings):
        n_full = prefilter_nodes(settings)
        high_degrees = environment_degrees + 1 if len(coeffs) else None
        stack, height, width = _prefiltered_stack(observations, n_full, high_degrees)
        prefiltered = PrefilteredLight(stack, n_full, np.ascontiguousarray(observations.environment_rotation.T,
                                                                           dtype=np.float64), height, width)
    else:
        prefiltered = PrefilteredLight(np.zeros((1, 0, 3), np.float32), 0, np.eye(3), 2, 2)
    return tangent, environment, prefiltered


def _prefiltered_stack(observations: Observations, n_full: int, high_degrees: int | None) -> tuple:
    """Return (stack (H W, nodes, 3) float32, H, W) of the prefiltered maps for the kernels.

    The n_full `prefiltered_environment` maps, then, unless high_degrees is None, the `_HIGH_NODES`
    maps of the degrees from high_degrees on; pixel-major, so that a texel's lookups at several
    nodes share cache lines.
    """
    radiance = observations.environment_radiance
    # The maps are filtered in the map's own frame (zonal filters commute with rotations): a turn
    # of the map (`freqbrdf.calibrate`) keeps them.
    # The searches of one fit ask a hundred times or more for the same map: its digest is remembered
    # (`envmaps.radiance_digest`).
    key = (envmaps.radiance_digest(radiance), radiance.shape, n_full, high_degrees)
    if key not in _PREFILTERED_CACHE:
        envmap = observations.environment()
        maps = prefiltered_environment(envmap, n_full)
        if high_degrees is not None:
            maps = np.concatenate([maps, prefiltered_environment(envmap, _HIGH_NODES, high_degrees)])
        _PREFILTERED_CACHE.clear()
        _PREFILTERED_CACHE[key] = (np.ascontiguousarray(maps.reshape(maps.shape[0], -1, 3).transpose(1, 0, 2)),
                                   *maps.shape[1:3])
    return _PREFILTERED_CACHE[key]
