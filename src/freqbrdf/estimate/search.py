"""The global estimator: inputs, orchestration, the neighbour vote (METHOD.md §3.7).
"""

from __future__ import annotations

import hashlib
import math
import time
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from freqbrdf.config import Config, EstimateConfig, FitConfig
from freqbrdf.estimate._search_kernels import MIN_SAMPLES, global_search_kernel, squared_residual_kernel
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
from freqbrdf.sphere import harmonics as sh

if TYPE_CHECKING:
    from freqbrdf.estimate import HypothesisRecorder

# Texels per block when expanding the light by degree: bounds the (block, V, K) SH basis.
_PROJECTION_BLOCK = 8192


class EstimatorResult(NamedTuple):
    """What an estimator returns: `MaterialEstimate` is made of it."""

    params: np.ndarray  # (N, 5) float64 base colour RGB, roughness, metallic
    loss: np.ndarray  # (N,) float64
    estimated: np.ndarray  # (N,) bool
    method: str
    timings: dict
    roughness_curvature: np.ndarray | None


def angular_loss(
    observations: Observations,
    params: brdf.PrincipledParams,
    config: Config = Config(),
    light_coeffs: np.ndarray | None = None,
) -> np.ndarray:
    """(N,) the weighted mean squared residual of ``params`` (see `MaterialEstimate.loss`).

    light_coeffs (N, 3, K): the incoming light's SH fit; default the unshadowed mirrored light.
    Texels without samples get NaN.
    """
    settings = config.estimate
    light = observations.mirrored_coeffs if light_coeffs is None else light_coeffs
    loss = np.empty(observations.n_texels)
    base_color = np.asarray(params.base_color, dtype=np.float64)
    metallic = np.asarray(params.metallic, dtype=np.float64)
    (tangent, normal, environment, blend, prefiltered, n_full, world_to_local, map_height,
     map_width) = _environment_inputs(observations, settings)
    for rows in texel_blocks(observations.n_texels, _PROJECTION_BLOCK):
        if len(environment):
            azimuthal = np.ascontiguousarray(environment_azimuthal(
                observations.view_direction[rows], observations.weight[rows], tangent[rows], normal[rows],
                environment))
        else:
            azimuthal = np.zeros((rows.stop - rows.start, observations.n_views, 3, 0))
        # The prefiltered light replaces the fitted one: its expansion would be read by nothing.
        fitted = (np.zeros((rows.stop - rows.start, 3, 1, observations.n_views), np.float32) if n_full else
                  mirror_projections(observations.view_direction[rows], observations.weight[rows], light[rows],
                                     observations.lmax))
        squared_residual_kernel(
            fitted,
            observations.view_direction[rows], observations.weight[rows], observations.observed[rows],
            lambert_scale(observations)[rows], base_color[rows], metallic[rows],
            np.asarray(params.roughness, dtype=np.float64)[rows], observations.sigma, settings.fresnel,
            settings.masking, uses_split_sum(settings), _uses_exact_dielectric(settings), _uses_burley(settings),
            split_sum_table(), environment_response_table(), _burley_response(settings), azimuthal, blend,
            tangent[rows], normal[rows], prefiltered, n_full, world_to_local, map_height, map_width, loss[rows],
        )
    return np.where(observations.n_samples > 0, loss, np.nan)


def _node_rows(roughness: np.ndarray, roughness_grid: int) -> np.ndarray:
    """(roughness_grid,) int64: per roughness node of the search, the index into ``roughness`` (R,)
    of a hypothesis at that node, or -1."""
    rows = np.full(roughness_grid, -1, dtype=np.int64)
    nodes = np.rint(roughness * (roughness_grid - 1)).astype(np.int64)
    on_node = (np.abs(nodes / (roughness_grid - 1) - roughness) < 1e-12) & (nodes >= 0) & (nodes < roughness_grid)
    rows[nodes[on_node]] = np.flatnonzero(on_node)
    return rows


def run_search_kernel(observations: Observations, settings: EstimateConfig, light: np.ndarray,
                      hypothesis_roughness: np.ndarray, hypothesis_moments: np.ndarray, search: bool,
                      params: np.ndarray, loss: np.ndarray, curvature: np.ndarray,
                      candidate: np.ndarray = np.zeros((0, 2))) -> None:
    """`global_search_kernel` on the observations with this light fit (N, 3, K) and settings. With
    ``search``, hypotheses on the roughness nodes are recorded by the search's first scan."""
    tangent, normal, environment, blend, *prefiltered = _environment_inputs(observations, settings)
    hypothesis_roughness = np.ascontiguousarray(hypothesis_roughness, dtype=np.float64)
    node_rows = (_node_rows(hypothesis_roughness, settings.roughness_grid) if search and len(hypothesis_roughness)
                 else np.full(0, -1, dtype=np.int64))
    global_search_kernel(
        observations.view_direction, observations.weight, observations.observed,
        np.ascontiguousarray(light, dtype=np.float32), lambert_scale(observations), observations.sigma,
        settings.fresnel, settings.masking, uses_split_sum(settings), _uses_exact_dielectric(settings),
        _uses_burley(settings), split_sum_table(), split_sum_rows(), settings.roughness_grid,
        settings.metallic_grid, settings.robust_passes, observations.lmax, *sh._legendre_tables(observations.lmax),
        tangent, normal, environment, blend, environment_response_table(),
        *environment_quadrature(max(math.isqrt(len(environment)) - 1, 0)), _burley_response(settings),
        *prefiltered, hypothesis_roughness, hypothesis_moments, node_rows,
        search, candidate, params, loss, curvature,
    )


def texel_blocks(n_texels: int, size: int = _PROJECTION_BLOCK):
    for start in range(0, n_texels, size):
        yield slice(start, min(start + size, n_texels))


def lambert_scale(observations: Observations) -> np.ndarray:
    """(N, 3) E / pi: the Lambertian radiance per unit diffuse albedo."""
    return observations.irradiance.astype(np.float64) / np.pi


# With the prefiltered light (`EstimateConfig.prefiltered_light`) a smooth lobe reads the environment
# map itself, filtered by the GGX lobe's per-degree response at normal incidence (`ggx_lobe_gains`) at
# roughness nodes PREFILTER_STEP apart, looked up bilinearly at each sample's world mirror direction
# (as `envmap.lookup`) and interpolated linearly in roughness between the nodes.


def prefilter_nodes(settings: EstimateConfig) -> int:
    """Roughness nodes (0, PREFILTER_STEP, ...) of the prefiltered maps the estimator reads: up to
    where the environment light takes over (environment_blend[1]) or to roughness 1 without it."""
    end = settings.environment_blend[1] if settings.environment_light else 1.0
    return min(math.ceil(end / PREFILTER_STEP - 1e-9), round(1.0 / PREFILTER_STEP)) + 1


def _burley_response(settings: EstimateConfig) -> np.ndarray:
    """`burley_response_table` for the kernels when Burley's diffuse reads the environment's light
    (with the environment light), else an empty one (uniform light)."""
    if _uses_burley(settings) and settings.environment_light and settings.burley_environment:
        return burley_response_table()
    return np.zeros((4, TABLE_COS_NODES, 0))


def _uses_burley(settings: EstimateConfig) -> bool:
    return settings.method == "global" and settings.diffuse_model == "burley"


def uses_split_sum(settings: EstimateConfig) -> bool:
    return settings.method == "global" and settings.specular_model == "split_sum"


def _uses_exact_dielectric(settings: EstimateConfig) -> bool:
    return uses_split_sum(settings) and settings.fresnel and settings.dielectric_fresnel == "exact"


def _uses_environment_light(observations: Observations, settings: EstimateConfig) -> bool:
    """The environment light needs the split-sum model and observations that carry the environment."""
    return (uses_split_sum(settings) and settings.environment_light and observations.tangent is not None
            and observations.environment_coeffs is not None)


def _uses_prefiltered_light(observations: Observations, settings: EstimateConfig) -> bool:
    """The prefiltered light needs the split-sum model and observations that carry the map and frames."""
    return (uses_split_sum(settings) and settings.prefiltered_light and observations.tangent is not None
            and observations.environment() is not None)


def _environment_inputs(observations: Observations, settings: EstimateConfig) -> tuple:
    """(tangent (N, 3), normal (N, 3), environment (K, 3) float64, blend, prefiltered (H W, nodes, 3)
    float32, n_full, world_to_local (3, 3), H, W) for the kernels: the environment's SH up to degree
    min(l*, 5) (K = 0 without the environment light), no nodes without the prefiltered light. The
    prefiltered nodes are `prefilter_nodes` full maps, then (with the environment light) the
    degrees above the environment light's at all `_HIGH_NODES` roughness nodes: what the
    environment light adds."""
    tangent = np.zeros((observations.n_texels, 3), np.float32) if observations.tangent is None else observations.tangent
    environment_degrees = min(observations.lmax, ENVIRONMENT_LMAX)
    if _uses_environment_light(observations, settings):
        environment = (np.ascontiguousarray(observations.environment_coeffs[:sh.num_coeffs(environment_degrees)],
                                            dtype=np.float64), tuple(float(b) for b in settings.environment_blend))
    else:
        environment = (np.zeros((0, 3)), (0.0, 0.0))
    if _uses_prefiltered_light(observations, settings):
        n_full = prefilter_nodes(settings)
        high_degrees = environment_degrees + 1 if len(environment[0]) else None
        stack, height, width = _prefiltered_stack(observations, n_full, high_degrees)
        prefiltered = (stack, n_full, np.ascontiguousarray(observations.environment_rotation.T, dtype=np.float64),
                       height, width)
    else:
        prefiltered = (np.zeros((1, 0, 3), np.float32), 0, np.eye(3), 2, 2)
    return (tangent, observations.normal, *environment, *prefiltered)


# Roughness nodes (0, PREFILTER_STEP, ..., 1) of the degrees the environment light leaves out.
_HIGH_NODES = round(1.0 / PREFILTER_STEP) + 1
# The last prefiltered stack: `angular_loss` and `hypothesis_moments` run many times on the same
# observations (uncertainty, sharing, blocks of texels), and the transforms take ~0.2 s.
_PREFILTERED_CACHE: dict = {}


def _prefiltered_stack(observations: Observations, n_full: int, high_degrees: int | None) -> tuple:
    """(stack (H W, nodes, 3) float32, H, W) for the kernels: the n_full `prefiltered_environment`
    maps, then, unless high_degrees is None, the `_HIGH_NODES` maps of the degrees from
    high_degrees on; pixel-major, so that a texel's lookups at several nodes share cache lines."""
    radiance = observations.environment_radiance
    key = (hashlib.blake2b(np.ascontiguousarray(radiance).tobytes(), digest_size=16).hexdigest(), radiance.shape,
           observations.environment_rotation.tobytes(), n_full, high_degrees)
    if key not in _PREFILTERED_CACHE:
        envmap = observations.environment()
        maps = prefiltered_environment(envmap, n_full)
        if high_degrees is not None:
            maps = np.concatenate([maps, prefiltered_environment(envmap, _HIGH_NODES, high_degrees)])
        _PREFILTERED_CACHE.clear()
        _PREFILTERED_CACHE[key] = (np.ascontiguousarray(maps.reshape(maps.shape[0], -1, 3).transpose(1, 0, 2)),
                                   *maps.shape[1:3])
    return _PREFILTERED_CACHE[key]


def shadowed_light_coeffs(observations: Observations, alpha: np.ndarray, fit: FitConfig) -> np.ndarray:
    """(N, 3, K) SH fit of the mirrored light shadowed by G1(theta_i, alpha) (appendix eq. 6)."""
    light = brdf.shadowed_light(observations.mirrored, observations.view_direction[..., 2], alpha)
    return sh.fit_sh(
        observations.view_direction, observations.weight, light.astype(np.float32), observations.lmax,
        fit.reg_lambda, fit.regulariser, fit.scale_lambda_with_weight,
    ).coeffs


def estimate_global(observations: Observations, config: Config, reporter: Reporter,
                    hypotheses: HypothesisRecorder | None) -> EstimatorResult:
    settings = config.estimate
    timings = {"light": 0.0, "search": 0.0}
    n_texels = observations.n_texels
    estimated = observations.n_samples >= MIN_SAMPLES
    params = np.zeros((n_texels, 5))  # base colour RGB, roughness, metallic
    loss = np.zeros(n_texels)
    curvature = np.zeros(n_texels)
    # The light of pass 0 is unshadowed, i.e. shadowed at alpha = 0 (G1 = 1). Each further pass
    # shadows it at a roughness closer to the fixed point r = search(light shadowed at r): a
    # secant step on search(r) - r, which converges much faster than re-using the last estimate.
    light = observations.mirrored_coeffs
    shadow_roughness = np.zeros(n_texels)
    previous_roughness = previous_residual = None
    # The split-sum albedo holds the shadowing: the light is never re-fitted.
    split_sum = uses_split_sum(settings)
    n_passes = 1 + (settings.shadowing_refreshes if settings.shadowing and not split_sum else 0)
    with reporter.stage("estimating (global)", n_passes) as advance:
        for pass_index in range(n_passes):
            tick = time.perf_counter()
            if pass_index > 0:
                light = shadowed_light_coeffs(observations, brdf.alpha_from_roughness(shadow_roughness), config.fit)
            timings["light"] += time.perf_counter() - tick
            tick = time.perf_counter()
            if pass_index == 0 and hypotheses is not None:  # pass 0's light is the one hypotheses are scored in
                for rows in texel_blocks(n_texels, hypotheses.block):
                    moments = np.zeros((rows.stop - rows.start, len(hypotheses.roughness), 3, 8))
                    run_search_kernel(observations.select(rows), settings, light[rows], hypotheses.roughness,
                                      moments, True, params[rows], loss[rows], curvature[rows])
                    hypotheses.consume(rows, moments)
            else:
                run_search_kernel(observations, settings, light, np.zeros(0), np.zeros((0, 0, 3, 8)), True, params,
                                  loss, curvature)
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
            advance(1)
    if settings.neighbour_vote:
        tick = time.perf_counter()
        candidate = np.stack([neighbour_median(observations, np.where(estimated, params[:, column], np.nan))
                              for column in (3, 4)], axis=1)  # (N, 2) roughness, metallic
        candidate = np.where(np.isnan(candidate), params[:, 3:5], candidate)
        run_search_kernel(observations, settings, light, np.zeros(0), np.zeros((0, 0, 3, 8)), False, params, loss,
                          curvature, candidate)
        timings["vote"] = time.perf_counter() - tick
    timings["total"] = sum(timings.values())
    return EstimatorResult(params, loss, estimated, "global", timings, curvature)


def neighbour_median(observations: Observations, values: np.ndarray, window: int = 5) -> np.ndarray:
    """(N,) the median of ``values`` (N,) over each texel's other texels in a window x window square
    of the texture (NaN values, and texels off the mesh, left out); NaN where none has a value."""
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
    # (np.nanmedian took 0.5 s for 262k texels, this 0.13 s.)
    median = 0.5 * (squares[index, np.maximum(counts - 1, 0) // 2] + squares[index, counts // 2])
    return np.where(counts > 0, median, np.nan)
