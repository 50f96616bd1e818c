"""The whole-surface estimate: each texel's evidence weighed against a prior over the surface.

The per-texel search (`freqbrdf.estimate.search`) answers every texel from its own samples; where
they cannot tell materials apart the answer is arbitrary, and texels no view sees have none. This
stage keeps what each texel's samples say and lets the surface decide the rest (the sharing of
docs/method.md#whole-surface-estimate, done inside the estimate):

1. **The surface graph** (`surface_graph`): each texel's nearest texels on the mesh, in 3D and so
   across UV seams, weighted by the likeness of their apparent albedo (the mean observed radiance
   over the irradiance / pi), so that material edges survive; and its look-alikes
   (`lookalike_graph`): the confident texels anywhere on the surface that look most like it, with
   which it shares its metal label and (alike in its own roughness and metallic too) its base colour.
2. **The metal label** (`metal_evidence`, `metal_posterior`): the search scores each texel's
   samples as a dielectric (m = 0) and as a metal (m = 1), base colour re-fitted at its roughness
   (`MaterialEstimate.label_loss`); their loss difference over the noise variance, deflated by
   ``SurfaceConfig.noise_inflation`` (the model's own misfit is not independent noise), is the
   label's log-likelihood ratio. A prior favours dielectrics (a texel is metal only with
   evidence; a texel without evidence starts from its UV chart's share of metal) and texels of
   like appearance share their label (mean field on the graph); a texel
   whose samples reject its label's pure material keeps its own, mixed, metallic.
3. **Roughness and base colour** (`smooth_on_surface`): each texel's value held by its precision
   (the loss's curvature over the noise; weaker with fewer samples than the median, which are
   mostly grazing), and an edge-preserving (Huber) coupling to its neighbours; iteratively
   re-weighted least squares solved by conjugate gradients (`_surface_kernels`). Texels no view
   sees have no data term: their values come from the solve along the surface, taken towards
   their UV chart's mean as far as the solve is measured not to carry (`shrink_unseen_to_charts`).
4. **Posterior std** of roughness, metallic and base colour: the label's probability (and, for
   the metallic, how much the labels of a texel's neighbourhood disagree: `border_variance`), and each
   texel's precision in the solve with its neighbours', scaled by how far the per-texel
   estimates scatter about the solution, growing with the distance from the texels with data;
   the base colour's also holds the label's doubt (a mixture of the two labels' base colours).
   The fit reports a roughness std no narrower than the spread of the texel's own estimate
   (`freqbrdf.pipeline.fit`): neighbours share the model's errors, which their precision ignores.

Deterministic: fixed iteration counts, no random choice, each solve's sparse products on one thread (the solves
run side by side, whatever the thread count, with the same results).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, NamedTuple

import numba
import numpy as np
from scipy import ndimage, sparse
from scipy.spatial import cKDTree

from freqbrdf.config import Config, SurfaceConfig
from freqbrdf.estimate._search_kernels import FITTED_PARAMETERS
from freqbrdf.estimate.search import lambert_scale
from freqbrdf.estimate.smoothing import (  # noqa: F401  (the solve's names, also read from here)
    CARRY_HOPS,
    HELD_OUT_SHARE,
    MAX_HELD_OUT_HOPS,
    MIN_CHART_TEXELS,
    MIN_HELD_OUT_TEXELS,
    PRIOR_PRECISION,
    chart_prior,
    held_out_trial,
    shrink_by_trial,
    shrink_unseen_to_charts,
    smooth_on_surface,
)
from freqbrdf.observe.signals import mean_over_views

if TYPE_CHECKING:
    from freqbrdf.estimate import MaterialEstimate
    from freqbrdf.observe.observations import Observations
    from freqbrdf.texels import Texels

__all__ = ["DataPrecision", "SurfaceGraphs", "SurfacePosterior", "border_variance", "data_precision", "lookalike_graph",
           "merged_std", "metal_evidence", "metal_posterior", "surface_graph", "surface_graphs", "uv_charts", "whole_surface"]

# Apparent albedo floor (log space): keeps black texels' logarithm finite.
_ALBEDO_FLOOR = 1e-3
# Neighbours farther than this many median neighbour spacings are not neighbours (thin parts, gaps).
_REACH = 3.0
# Neighbours whose normals differ by more than this cosine are not neighbours (the two sides of a thin part).
_MIN_NORMAL_COSINE = 0.3
# A look-alike edge weighs this much against a neighbour of the same appearance on the mesh (1).
_LOOKALIKE_WEIGHT = 0.5
# The texels' own roughness and metallic, times this, join the appearance the base colour's
# look-alikes are found by: a difference of 0.1 in them counts as 0.05 in log albedo.
_LOOKALIKE_MATERIAL_SCALE = 0.5
# A chart's share of metal, as a texel without evidence's prior, is kept this far from 0 and 1.
CHART_METAL_SHARE_BOUND = 0.02


@dataclass(eq=False)
class SurfacePosterior:
    """The whole-surface solve's posterior per texel (N texels).

    Attributes
    ----------
    metal_probability : (N,) float64
        The posterior probability of the metal label.
    roughness_std, metallic_std : (N,) float32
        Posterior standard deviations of roughness and metallic.
    base_color_std : (N, 3) float32
        Posterior standard deviation of each base-colour channel, the metal label's doubt included.
    inferred : (N,) bool
        Texels whose values come from the surface alone (no estimate of their own).
    timings : dict of str to float
        Seconds per step.
    carry_hops : dict of str to float
        Per parameter ("roughness", "base_color"), how far (in hops on the surface graph) the
        solve's extrapolation carries into texels without data, as `shrink_unseen_to_charts`
        measured it: inf where it holds at any distance, NaN where nothing was measured (every
        texel has data, or too few do).
    """

    metal_probability: np.ndarray
    roughness_std: np.ndarray
    metallic_std: np.ndarray
    base_color_std: np.ndarray
    inferred: np.ndarray
    timings: dict
    carry_hops: dict = field(default_factory=dict)


def whole_surface(observations: Observations, estimate: MaterialEstimate, texels: Texels,
                  config: Config = Config()) -> tuple[MaterialEstimate, SurfacePosterior]:
    """Estimate the whole surface from the per-texel estimate and the surface prior.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    estimate : MaterialEstimate
        The ``global`` estimator's per-texel estimate of those texels.
    texels : Texels
        The same N texels on the mesh (positions and normals): `freqbrdf.texels.rasterise` at the
        observations' resolution.
    config : Config, optional
        ``config.surface``: the solve's settings.

    Returns
    -------
    estimate : MaterialEstimate
        Every texel of the atlas with a value; ``estimated`` unchanged (the texels with samples of
        their own).
    posterior : SurfacePosterior
        The label probabilities and the std maps.

    Raises
    ------
    ValueError
        If ``texels`` are not the observations' texels.
    """
    if not np.array_equal(texels.texel_index, observations.texel_index):
        raise ValueError("whole_surface needs the observations' own texels (rasterise at their resolution)")
    settings = config.surface
    timings: dict[str, float] = {}
    start = time.perf_counter()
    estimated = estimate.estimated.copy()
    albedo = apparent_albedo(observations)
    graph, label_graph, color_graph = surface_graphs(texels.position, texels.normal, np.log(albedo), estimate,
                                                     observations.n_samples, settings)
    timings["graph"] = time.perf_counter() - start

    start = time.perf_counter()
    log_ratio, costs, labelled = metal_evidence(estimate, observations.n_samples)
    timings["evidence"] = time.perf_counter() - start

    start = time.perf_counter()
    charts = uv_charts(texels)
    probability = metal_posterior(log_ratio / settings.noise_inflation, estimated, label_graph, settings, charts)
    metal = probability > 0.5
    params = np.where(metal[:, None], labelled[1], labelled[0])  # (N, 5): base colour, roughness, metallic
    own = np.nan_to_num(np.concatenate([estimate.base_color, estimate.roughness[:, None], estimate.metallic[:, None]],
                                       axis=1))
    # A texel whose own metallic lies within a grid cell of its label keeps its own (robust) base
    # colour; one whose samples reject its label's pure material keeps its own, mixed, metallic too.
    agrees = estimated & (np.abs(own[:, 4] - metal) * (config.estimate.metallic_grid - 1) <= 1.0)
    params[agrees, :4] = own[agrees, :4]
    params[:, 4] = metal
    mixed = estimated & (np.where(metal, costs[:, 1], costs[:, 0]) / settings.noise_inflation > settings.mixed_evidence)
    params[mixed] = own[mixed]
    timings["labels"] = time.perf_counter() - start

    start = time.perf_counter()
    data = data_precision(observations, estimate, metal, settings)
    roughness_precision = data.roughness * data.few
    color_precision = data.color * data.few[:, None]
    # Roughness and base colour are solved apart, and each texel-without-data trial (`held_out_trial`) apart from
    # its whole solve, each on one thread (`_surface_kernels`): side by side on as many as numba may use (a batch
    # worker's share), at most two, the longest first.
    roughness_args = (params[:, 3:4], roughness_precision[:, None])
    color_args = (params[:, :3], color_precision)
    with ThreadPoolExecutor(max(1, min(2, numba.get_num_threads()))) as pool:
        color_solve = pool.submit(smooth_on_surface, *color_args, color_graph, settings.color_smoothing,
                                  settings.color_huber, settings)
        roughness_solve = pool.submit(smooth_on_surface, *roughness_args, graph, settings.roughness_smoothing,
                                      settings.roughness_huber, settings)
        roughness_trial = pool.submit(held_out_trial, *roughness_args, graph, settings.roughness_smoothing,
                                      settings.roughness_huber, settings)
        color_trial = pool.submit(held_out_trial, *color_args, graph, settings.color_smoothing, settings.color_huber,
                                  settings)
        roughness, roughness_spread = roughness_solve.result()
        color, color_spread = color_solve.result()
        roughness, roughness_length, unseen_std = shrink_by_trial(roughness_trial.result(), params[:, 3:4], roughness,
                                                                  charts)
        roughness_spread = np.maximum(roughness_spread, unseen_std[:, None])
        color, color_length, unseen_std = shrink_by_trial(color_trial.result(), params[:, :3], color, charts)
        color_spread = np.maximum(color_spread, unseen_std[:, None])
    timings["smooth"] = time.perf_counter() - start

    solved = replace(
        estimate,
        base_color=np.clip(color, 0.0, 1.0), roughness=np.clip(roughness[:, 0], 0.0, 1.0),
        metallic=params[:, 4].copy(),
    )
    # The base colour's posterior is a mixture over the label: its variance adds p (1 - p) times the
    # squared difference of the two labels' base colours (the law of total variance).
    label_variance = probability * (1.0 - probability)
    posterior = SurfacePosterior(
        metal_probability=probability,
        roughness_std=roughness_spread[:, 0].astype(np.float32),
        metallic_std=np.sqrt(np.minimum(label_variance + border_variance(probability, graph), 0.25)).astype(np.float32),
        base_color_std=np.sqrt(color_spread ** 2 + label_variance[:, None]
                               * (labelled[1][:, :3] - labelled[0][:, :3]) ** 2).astype(np.float32),
        inferred=~estimated,
        timings=timings,
        carry_hops={"roughness": roughness_length, "base_color": color_length},
    )
    return solved, posterior


def merged_std(own_roughness_std: np.ndarray | None, own_base_color: np.ndarray, estimate: MaterialEstimate,
               posterior: SurfacePosterior) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge the whole-surface posterior's std with what each texel's own estimate says.

    The posterior credits a texel with its neighbours' precision as if their errors were
    independent; the systematic errors neighbours share make it far too narrow. So a texel's
    roughness std is never below the spread of its own samples' estimate, and its base colour's
    adds how far its own estimate lies from the solution, in quadrature. The metallic std is the
    posterior's.

    Parameters
    ----------
    own_roughness_std : (N,) float32 or None
        The spread of each texel's own roughness estimate (`freqbrdf.uncertainty.roughness_std`);
        NaN where unknown.
    own_base_color : (N, 3) float64
        Each texel's own base colour, before the solve; NaN where not estimated.
    estimate : MaterialEstimate
        The whole-surface estimate.
    posterior : SurfacePosterior
        Its posterior.

    Returns
    -------
    roughness_std : (N,) float32
    metallic_std : (N,) float32
    base_color_std : (N, 3) float32
    """
    if own_roughness_std is None:
        roughness = np.asarray(posterior.roughness_std, np.float32)
    else:
        roughness = np.where(np.isfinite(own_roughness_std), np.maximum(own_roughness_std, posterior.roughness_std),
                             posterior.roughness_std).astype(np.float32)
    disagreement = np.nan_to_num(np.asarray(own_base_color, np.float64) - estimate.base_color)
    base_color = np.sqrt(np.asarray(posterior.base_color_std, np.float64) ** 2 + disagreement ** 2).astype(np.float32)
    return roughness, posterior.metallic_std, base_color


class DataPrecision(NamedTuple):
    """What each texel's own samples say in the surface solve (N texels; `data_precision`).

    Attributes
    ----------
    roughness : (N,) float64
        The roughness's precision, 0.5 curvature / noise (0 without an estimate).
    color : (N, 3) float64
        Each base-colour channel's precision, light^2 / noise (0 without an estimate).
    noise : (N,) float64
        The loss's noise variance per residual, inflated (1 without an estimate).
    few : (N,) float64
        The weight of few samples, (samples / median samples)^few_sample_power, at most 1; the
        solve multiplies both precisions by it.
    typical_samples : float
        That median: the samples of the estimated texels (at least 1).
    """

    roughness: np.ndarray
    color: np.ndarray
    noise: np.ndarray
    few: np.ndarray
    typical_samples: float




def data_precision(observations: Observations, estimate: MaterialEstimate, metal: np.ndarray,
                   settings: SurfaceConfig) -> DataPrecision:
    """Return the precision of each texel's own roughness and base colour (the solve's data term).

    The noise is the per-texel loss over its degrees of freedom, inflated by
    ``settings.noise_inflation`` (the model's own misfit is not independent noise); the base
    colour's derivative is the diffuse term's light for a dielectric, the mirrored light's for a
    metal. Few samples are mostly grazing or edge samples, whose errors are the model's: weaker.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).
    estimate : MaterialEstimate
        The per-texel estimate of those texels.
    metal : (N,) bool
        The texels' metal label.
    settings : SurfaceConfig
        ``noise_inflation`` and ``few_sample_power``.

    Returns
    -------
    DataPrecision
        The precisions before the few-sample weight, the noise, and that weight.
    """
    estimated = estimate.estimated
    dof = np.maximum(3.0 * observations.n_samples - FITTED_PARAMETERS, 1.0)
    noise = np.where(estimated, np.maximum(np.nan_to_num(estimate.loss), 1e-12), 1.0) / dof * settings.noise_inflation
    curvature = (np.ones(estimate.n_texels) if estimate.roughness_curvature is None
                 else np.nan_to_num(estimate.roughness_curvature))
    roughness = np.where(estimated, 0.5 * np.maximum(curvature, 0.0) / noise, 0.0)
    light = np.where(metal[:, None], mean_over_views(observations.weight, observations.mirrored), lambert_scale(observations))
    color = np.where(estimated[:, None], light.astype(np.float64) ** 2 / noise[:, None], 0.0)
    counts = observations.n_samples.astype(np.float64)
    typical = max(float(np.median(counts[estimated])), 1.0) if estimated.any() else 1.0
    few = np.minimum(counts / typical, 1.0) ** settings.few_sample_power
    return DataPrecision(roughness, color, noise, few, typical)


def uv_charts(texels: Texels) -> np.ndarray:
    """Return (N,) int64: each texel's UV chart, the islands of the atlas (8-connected in texture space)."""
    labels, _ = ndimage.label(texels.mask, structure=np.ones((3, 3), bool))
    return labels.reshape(-1)[texels.texel_index].astype(np.int64) - 1


def apparent_albedo(observations: Observations) -> np.ndarray:
    """Return each texel's mean observed radiance over its irradiance / pi.

    Parameters
    ----------
    observations : Observations
        The texels' samples (N texels).

    Returns
    -------
    (N, 3) float64
        The apparent albedo, at least ``_ALBEDO_FLOOR``; the floor where a texel has no sample.
    """
    radiance = mean_over_views(observations.weight, observations.observed)
    irradiance = np.maximum(lambert_scale(observations), 1e-12)
    return np.maximum(radiance / irradiance, _ALBEDO_FLOOR)


def surface_graph(position: np.ndarray, normal: np.ndarray, appearance: np.ndarray, observed: np.ndarray,
                  settings: SurfaceConfig) -> sparse.csr_matrix:
    """Build the texels' neighbour graph on the surface, weighted by likeness of appearance.

    Parameters
    ----------
    position, normal : (N, 3) array
        The texels' points and normals on the mesh.
    appearance : (N, C) array
        What a texel looks like (the log apparent albedo); compared only between observed texels.
    observed : (N,) bool
        Texels whose appearance is known.
    settings : SurfaceConfig
        ``neighbours`` and ``appearance_width``.

    Returns
    -------
    (N, N) scipy.sparse.csr_matrix of float64
        Symmetric weights in (0, 1]: exp(-|a_i - a_j|^2 / (2 width^2)) between observed texels, 1
        where either is unobserved; no self-loops.
    """
    n_texels = len(position)
    k = min(settings.neighbours, max(n_texels - 1, 0))
    if k == 0:
        return sparse.csr_matrix((n_texels, n_texels))
    distance, index = cKDTree(np.asarray(position, np.float64)).query(position, k=k + 1, workers=-1)
    distance, index = distance[:, 1:], index[:, 1:]
    spacing = float(np.median(distance[:, 0])) if n_texels else 0.0
    rows = np.repeat(np.arange(n_texels), k)
    cols = index.reshape(-1)
    normal = np.asarray(normal, np.float64)
    keep = (distance.reshape(-1) <= _REACH * max(spacing, 1e-12)) & (
        np.einsum("ij,ij->i", normal[rows], normal[cols]) > _MIN_NORMAL_COSINE)
    rows, cols = rows[keep], cols[keep]
    both = observed[rows] & observed[cols]
    difference = np.sum((appearance[rows] - appearance[cols]) ** 2, axis=1)
    weight = np.where(both, np.exp(-difference / (2.0 * settings.appearance_width ** 2)), 1.0)
    graph = sparse.coo_matrix((weight, (rows, cols)), shape=(n_texels, n_texels)).tocsr()
    return graph.maximum(graph.T).tocsr()


class SurfaceGraphs(NamedTuple):
    """The three graphs of the whole-surface solve (N texels; `surface_graphs`).

    Attributes
    ----------
    surface : (N, N) scipy.sparse.csr_matrix
        Neighbours on the mesh (`surface_graph`): roughness is shared along it.
    label : (N, N) scipy.sparse.csr_matrix
        ``surface`` with look-alikes by appearance (`lookalike_graph`): the metal label's.
    color : (N, N) scipy.sparse.csr_matrix
        ``surface`` with look-alikes by appearance and own roughness and metallic: the base colour's.
    """

    surface: sparse.csr_matrix
    label: sparse.csr_matrix
    color: sparse.csr_matrix


def surface_graphs(position: np.ndarray, normal: np.ndarray, appearance: np.ndarray, estimate: MaterialEstimate,
                   n_samples: np.ndarray, settings: SurfaceConfig) -> SurfaceGraphs:
    """Build the graphs the whole-surface solve shares each parameter along.

    Look-alikes anywhere on the surface share the metal label (by appearance) and the base colour
    (by appearance and the texels' own roughness and metallic: alike colour, other material);
    roughness is shared along the surface only (alike colours often differ in roughness). The
    look-alikes are the confident texels: estimated, with at least the median samples.

    Parameters
    ----------
    position, normal : (N, 3) array
        The texels' points and normals on the mesh.
    appearance : (N, C) array
        What a texel looks like (the log apparent albedo).
    estimate : MaterialEstimate
        The per-texel estimate: which texels have one, and their roughness and metallic.
    n_samples : (N,) int
        Each texel's samples.
    settings : SurfaceConfig
        The graphs' settings.

    Returns
    -------
    SurfaceGraphs
        The surface, label and colour graphs.
    """
    estimated = estimate.estimated
    graph = surface_graph(position, normal, appearance, estimated, settings)
    confident = estimated & (n_samples >= np.median(n_samples[estimated])) if estimated.any() else estimated
    label = graph.maximum(lookalike_graph(appearance, estimated, confident, settings)).tocsr()
    own_material = _LOOKALIKE_MATERIAL_SCALE * np.nan_to_num(np.column_stack([estimate.roughness, estimate.metallic]))
    color = graph.maximum(lookalike_graph(np.column_stack([appearance, own_material]), estimated, confident,
                                          settings)).tocsr()
    return SurfaceGraphs(graph, label, color)


def lookalike_graph(appearance: np.ndarray, observed: np.ndarray, confident: np.ndarray,
                    settings: SurfaceConfig) -> sparse.csr_matrix:
    """Tie each observed texel to the confident texels that look most like it, anywhere on the surface.

    Parameters
    ----------
    appearance : (N, C) array
        What a texel looks like (e.g. the log apparent albedo); compared only between observed texels.
    observed : (N,) bool
        Texels whose appearance is known: each gets edges.
    confident : (N,) bool
        The texels it may be tied to (observed, with many samples).
    settings : SurfaceConfig
        ``lookalikes`` (edges per texel) and ``lookalike_width``.

    Returns
    -------
    (N, N) scipy.sparse.csr_matrix of float64
        Symmetric weights ``_LOOKALIKE_WEIGHT`` x exp(-|a_i - a_j|^2 / (2 width^2)), no self-loops;
        empty when there are too few confident texels.
    """
    n_texels = len(appearance)
    k = settings.lookalikes
    sources, targets = np.flatnonzero(observed), np.flatnonzero(confident)
    if k < 1 or len(targets) <= k or not len(sources):
        return sparse.csr_matrix((n_texels, n_texels))
    appearance = np.asarray(appearance, np.float64)
    distance, index = cKDTree(appearance[targets]).query(appearance[sources], k=k + 1, workers=-1)
    rows = np.repeat(sources, k + 1)
    cols = targets[index.reshape(-1)]
    weight = _LOOKALIKE_WEIGHT * np.exp(-distance.reshape(-1) ** 2 / (2.0 * settings.lookalike_width ** 2))
    keep = rows != cols
    graph = sparse.coo_matrix((weight[keep], (rows[keep], cols[keep])), shape=(n_texels, n_texels)).tocsr()
    return graph.maximum(graph.T).tocsr()


def metal_evidence(estimate: MaterialEstimate, n_samples: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Weigh what each texel's samples say about the metal label.

    From the search's losses of a dielectric (m = 0) and a metal (m = 1) at the texel's roughness,
    base colour re-fitted (`MaterialEstimate.label_loss`).

    Parameters
    ----------
    estimate : MaterialEstimate
        The ``global`` estimator's per-texel estimate (N texels), with its label losses.
    n_samples : (N,) int
        Each texel's samples.

    Returns
    -------
    log_ratio : (N,) float64
        (loss as a dielectric - loss as a metal) / (2 noise variance), the noise the least loss
        over its 3n - 5 degrees of freedom: the metal label's log-likelihood ratio for
        independent noise; 0 where not estimated.
    costs : (N, 2) float64
        What the samples lose as a dielectric and as a metal against the best of the estimate and
        both labels, over 2 noise variances (0 where not estimated).
    labelled : tuple of two (N, 5) float64
        Base colour RGB, roughness and metallic as a dielectric and as a metal.

    Raises
    ------
    ValueError
        If the estimate has no label losses (not the ``global`` estimator's).
    """
    if estimate.label_loss is None or estimate.label_base_color is None:
        raise ValueError("the whole-surface estimate needs the global estimator's label losses")
    estimated = estimate.estimated
    losses = np.nan_to_num(estimate.label_loss)
    dof = np.maximum(3.0 * np.asarray(n_samples, np.float64) - FITTED_PARAMETERS, 1.0)
    least = np.minimum(losses.min(axis=1), np.nan_to_num(estimate.loss, nan=np.inf))
    noise = np.maximum(least, 1e-12) / dof
    log_ratio = np.where(estimated, (losses[:, 0] - losses[:, 1]) / (2.0 * noise), 0.0)
    costs = np.where(estimated[:, None], (losses - least[:, None]) / (2.0 * noise[:, None]), 0.0)
    roughness = np.nan_to_num(estimate.roughness)[:, None]
    labelled = tuple(np.concatenate([np.nan_to_num(estimate.label_base_color[:, label]), roughness,
                                     np.full_like(roughness, float(label))], axis=1) for label in (0, 1))
    return log_ratio, costs, labelled


def border_variance(probability: np.ndarray, graph: sparse.csr_matrix) -> np.ndarray:
    """Return (N,) the variance of the metal label over each texel and its neighbours on the mesh.

    A texel on a border between metal and dielectric (a soft, blended edge, or one the texture's
    resolution cuts through) covers some of both: its metallic is uncertain by how much its
    neighbourhood's labels disagree, however sure each label is. The neighbours are the graph's,
    counted alike (its appearance weights would hide the very border).
    """
    structure = graph.tocsr(copy=True)
    structure.data[:] = 1.0
    count = 1.0 + np.asarray(structure.sum(axis=1)).ravel()
    mean = (probability + structure @ probability) / count
    second = (probability ** 2 + structure @ probability ** 2) / count
    return np.maximum(second - mean ** 2, 0.0)


def metal_posterior(log_ratio: np.ndarray, observed: np.ndarray, graph: sparse.csr_matrix,
                    settings: SurfaceConfig, charts: np.ndarray | None = None) -> np.ndarray:
    """Return each texel's probability of being metal: its evidence, the prior and its neighbours.

    Mean field on the graph's Ising model: q = sigmoid(h + J sum_j w_ij (2 q_j - 1)), h the
    texel's log-likelihood ratio plus the prior's log-odds, damped synchronous updates.

    Parameters
    ----------
    log_ratio : (N,) float64
        The metal label's log-likelihood ratio per texel (0: no evidence either way).
    observed : (N,) bool
        Texels with evidence of their own.
    graph : (N, N) scipy.sparse.csr_matrix
        `surface_graph`'s weights.
    settings : SurfaceConfig
        ``metal_prior``, ``label_coupling`` and ``label_iterations``.
    charts : (N,) int64, optional
        Each texel's UV chart: a texel without evidence then takes as its prior its chart's share
        of metal among the texels with evidence (`chart_prior`), within `CHART_METAL_SHARE_BOUND`
        of 0 and 1.

    Returns
    -------
    (N,) float64
        The posterior probability of the metal label.
    """
    prior = np.log(settings.metal_prior / (1.0 - settings.metal_prior))
    field = np.clip(np.where(observed, log_ratio, 0.0), -_MAX_LOG_RATIO, _MAX_LOG_RATIO) + prior
    if charts is not None and observed.any():
        # A texel without evidence takes its chart's share of metal among the texels with evidence.
        labels = (_sigmoid(field) > 0.5).astype(np.float64)[:, None]
        share, _ = chart_prior(labels, observed, charts)
        share = np.clip(share[:, 0], CHART_METAL_SHARE_BOUND, 1.0 - CHART_METAL_SHARE_BOUND)
        field = np.where(observed, field, np.log(share / (1.0 - share)))
    probability = _sigmoid(field)
    for _ in range(settings.label_iterations):
        updated = _sigmoid(field + settings.label_coupling * (graph @ (2.0 * probability - 1.0)))
        probability = 0.5 * (probability + updated)
    return probability


_MAX_LOG_RATIO = 50.0


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * x))
