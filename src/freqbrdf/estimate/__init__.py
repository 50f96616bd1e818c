"""Per-texel base colour, roughness and metallic from the observations (METHOD.md §3.6-3.7).

Both estimators fit a model of the radiance per texel, view v and channel c

    L_c(w) = (R0_c A(w) + B(w)) S_alpha,c(w) + d_c D(w) E_c / pi,
    S_alpha,c(w) = sum_l k_alpha(l) P_c,l(w),   P_c,l(w) = sum_m c^in_c,lm Y_lm(w),

with R0 = 0.04 (1 - m) + b m, d = (1 - m) b and k the BRDF kernel (``brdf.brdf_kernel``,
band-limit compensated). (``global``'s default replaces Schlick's dielectric, 0.04 A + B, by the
exact one, E; see below.) P, the incoming light's SH expansion split by degree, is computed once
per light fit, so a new alpha costs l* + 1 multiply-adds per sample. The specular albedo (A, B)
and diffuse factor D come in two versions (``EstimateConfig.specular_model``, ``diffuse_model``):

- METHOD.md's angular model (``brdf.predict_angular``; "g1", "lambert"): A = G1 (1 - F_c),
  B = G1 F_c with F_c = (1 - cos theta_o)^5, the light shadowed by G1 before its fit, D = 1.
- ours, the default for ``global`` ("split_sum", "burley"): (A, B) the GGX lobe's directional
  albedo with Fresnel and Smith masking-shadowing integrated over the lobe (`split_sum_table`;
  for a metal it is what Mitsuba's ``principled`` BSDF reflects, to Monte Carlo noise), D
  Mitsuba's principled diffuse averaged over the light (`burley_diffuse_factor`), and the light
  read in the mirror direction. The dielectric part (weight 1 - m) has the exact Fresnel of eta 1.5,
  as Mitsuba's principled BSDF (``EstimateConfig.dielectric_fresnel``): its albedo E replaces
  0.04 A + B, so the specular is m (b A + B) + (1 - m) E. Measured against Schlick's dielectric
  (64 views, T = 512): base-colour PSNR 19.51 -> 19.90 dB (plane), 18.26 -> 18.52 (demo capture),
  16.72 -> 16.74 (bunny), metallic MAE 0.187 -> 0.173, 0.186 -> 0.168, 0.240 -> 0.239. On the
  64-view Mitsuba captures (bunny, plane) the albedo and Burley cut roughness MAE 0.200 -> 0.169
  and 0.118 -> 0.127, metallic MAE 0.286 -> 0.238 and 0.237 -> 0.188 ("g1" lets rough metals
  pass for dark dielectrics, Lambert makes rough dielectrics look too smooth). With the
  environment light (below), D is Burley's factor averaged over the environment's own light
  instead (per channel, `environment_burley_factor`, ``EstimateConfig.burley_environment``).
- the environment light (``EstimateConfig.environment_light``, default on): the per-texel fit of
  the ~40-64 mirrored samples (l* = 5) extrapolates where a wide lobe reads it, and the Gaussian
  kernel exp(-alpha^2 l^2) is far from the GGX lobe's true per-degree response. On rough
  dielectrics of the demo capture it predicted 0.0104 of specular at grazing views where a
  brute-force integral of the principled BSDF over the environment gives 0.0190. So rough lobes
  read the environment's own SH (world frame, degrees <= 5, from the map, unoccluded) through the
  lobe's exact response to each harmonic (`environment_response_table`, per view cosine, roughness
  and lobe term; the lobe is symmetric about its plane of incidence, so 21 responses, m >= 0, in
  a frame turned to the view's azimuth). Smooth lobes keep the fitted light, which holds the sharp
  features that the map's l <= 5 SH lacks; the share moves from one to the other over roughness
  0.3-0.6 (smoothstep). Either light alone is worse. With it (64 views, T = 512): base-colour PSNR
  17.17 -> 18.43 dB (bunny), 20.11 -> 24.24 (plane), 19.20 -> 19.92 (demo capture, 96 views);
  roughness MAE 0.163 -> 0.154 and 0.113 -> 0.071; metallic MAE 0.230 -> 0.200 and 0.172 ->
  0.118; relighting PSNR-H 19.79 -> 20.18, 22.40 -> 22.65 and 22.60 -> 23.02. On the demo
  capture metallic MAE rises 0.17 -> 0.20: its rough dielectrics drift towards metal (not from
  interreflection: the material drifts as much on a sphere; see docs/measurements.md). (Those
  figures are of its first version, which read the environment at one direction tilted towards
  the normal with a gain per degree, fitted to the same responses: against Mitsuba it predicted a
  rough dielectric's specular (r = 0.86) under the demo's forest map 0.79 of the truth at grazing
  views, the exact responses 1.00. That change alone, T = 256: plane 26.01 -> 26.98 dB, metallic
  MAE 0.117 -> 0.079; bunny 18.35 -> 18.30 dB, roughness 0.143 -> 0.136, metallic 0.195 ->
  0.184; demo 20.16 -> 19.97 dB, roughness 0.133 -> 0.131; and the estimate is ~10 % faster.)
  Per texel the environment is turned into the texel's frame once (a quadrature exact for
  degree 5) and per sample into its view's azimuth (21 x 3 coefficients); the search evaluates
  the light once per roughness node it visits (every second node of the table, linear in
  roughness between them).
- the prefiltered light (``EstimateConfig.prefiltered_light``, default on): smooth lobes no longer
  read the fitted light either. With it, texels with true roughness below 0.3 came out +0.16 too
  rough on the demo capture, and the model's loss at the truth was 1.3x that at the estimate: l* = 5
  cannot hold a smooth lobe's sharp reflections. They read the environment map itself, filtered by
  the GGX lobe's per-degree response at normal incidence (`ggx_lobe_gains`, every degree the map
  holds) at roughness nodes 1/16 apart (`prefiltered_environment`, once per estimate, ~0.1 s for a
  256 x 512 map), looked up bilinearly at each sample's world mirror direction, linear in roughness
  between the nodes, and blended into the environment light over the same 0.3-0.6. It ignores
  occlusion of the mirror direction, as the environment light does. It replaces the per-texel
  expansion of the fitted light, so it also costs less. The environment light (degrees <= 5) also
  gains the map's degrees above 5 this way (maps filtered by the same gains with degrees <= 5
  removed, at roughness nodes 1/16 apart up to 1): in the blend, a lobe of roughness 0.45 still
  responds 0.17 to degree 6. Measured: see `EstimateConfig.prefiltered_light`. The mirror's node
  (roughness 0) is the map itself: cut at the band limit it rang around bright lights.

- ``global`` (ours) minimises the weighted squared residual sum_v w_v^2 (L(w_v) - f_v)^2. Write
  L = m (b X + Y) + (1 - m) Z + (1 - m) b e D with X = A S_A, Y = B S_B, Z = E S_E (S_k the light
  as term k reads it), e = E / pi. For fixed (alpha, m) the model is linear in b per channel,
  L = b (m X + (1 - m) e D) + m Y + (1 - m) Z, so the best b is a clipped closed form, and the
  loss at it a function of quadratics in m computed from 14 weighted moments of X, Y, Z, D and f
  over the views. Roughness is searched on a grid with the metallic profiled out (grid, then
  safeguarded Newton on the exact derivatives of the profiled loss) at each node, and the best
  cell is refined by Brent, started from the parabola through the best node and its neighbours:
  the global optimum in (b, m, r) up to the grid resolution, with no step size and no local
  minima to fall into. Per texel the light is expanded by degree once and everything that
  does not depend on the roughness (table positions, Burley's polynomial in r, the diffuse
  moments) is prepared before the search, so a roughness probe costs ~20 multiply-adds per sample. Then
  ``EstimateConfig.robust_passes`` (default 1) passes of iteratively re-weighted least squares move
  towards the paper's L1 loss sum_v w_v |r_v|: each weights a sample by w / max(|r|, a tenth of the
  texel's mean |r|) and searches again, so that samples the model cannot explain (interreflection,
  silhouettes) count less. One pass (64 views, T = 512): base-colour PSNR 16.94 -> 17.17 dB
  (bunny), 18.87 -> 19.20 (demo capture), 19.97 -> 20.11 (plane), roughness and metallic MAE
  lower on all three. The first search then only needs the optimum's cell (Brent to 1e-3), the
  robust one scans the nodes within one cell of it (two cost 6 % more time and moved no score by
  more than 0.002 dB): about 1.3x the least-squares search time (plane, T = 512). In all, ~31
  probes per texel with the robust pass (plane, session 8); the ``fast`` preset
  (`config.preset`) drops the pass and halves the grid.
  Last, the neighbour vote (``EstimateConfig.neighbour_vote``, default on): some texels have two
  optima that fit about equally, a smooth and a rough lobe each with its own base colour and
  metallic (on the bunny and entropy_scenes.py's sphere, the 10-12 % of texels off by more than
  0.3 in roughness make 42-49 % of the roughness error), or a metal and a dielectric (7-13 % of
  the texels off by more than 0.5 in metallic make 34-62 % of that error on the bunny and the demo
  capture). Where the median roughness of a texel's neighbours (`neighbour_median`, 5 x 5 texels)
  lies more than a grid cell from its estimate, a local minimum within a cell of that median
  replaces the estimate, and where their median metallic lies more than a metallic grid cell from
  it, the texel takes that metallic (base colour re-fitted), each unless the texel's own data
  reject it: a likelihood-ratio test at 95 % (the profiled least-squares loss may rise by chi^2_1
  3.84 noise variances, the residual over 3n - 5 degrees of freedom), so exact data never move.
  Measured: see `EstimateConfig.neighbour_vote`.
- ``paper`` reproduces the authors' prototype with METHOD.md's model: Adam (torch's defaults, lr
  0.02, 100 iterations) on the L1 loss of the cos-weighted residuals averaged over the whole T x T
  texture, parameters clamped to [0, 1] after every step, texture-space total variation on the
  observed texels, and any of the three forward models (angular, SH coefficients, power spectrum),
  with analytic gradients. Initialisation is the prototype's: base colour, roughness and metallic
  all 0.5.

Shadowing in METHOD.md's model (appendix eq. 6) makes the light's SH fit depend on alpha. Both
estimators freeze it and refresh it as the prototype does: the first search (or the first 49 Adam
steps) uses the unshadowed light; a refresh re-fits the light shadowed at the current roughness.
``global`` searches again after each of its ``shadowing_refreshes`` refreshes, shadowing at a
secant prediction of the fixed point r = search(light shadowed at r); its estimate is the global
optimum for the last frozen light (4 refreshes reach ~1e-3 in roughness on model-generated data,
6 ~1e-6). The split-sum albedo holds the shadowing, so it fits the light once.

Texels without a single sample are left unestimated (NaN, ``estimated`` False); the caller fills
them for export. ``global`` also leaves texels with fewer than `MIN_SAMPLES` samples to the fill:
one sample's three channels cannot determine five parameters, so any of a family of exact fits
would be an arbitrary pick (filling them from their neighbours raised base-colour PSNR by 0.20 dB
on the 64-view bunny, 0.34 on the demo capture and 0.07 on the plane, where 0.8 %, 0.9 % and
0.2 % of the observed texels had a single sample).
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numba
import numpy as np

from freqbrdf import texels
from freqbrdf.config import Config, EstimateConfig, FitConfig
from freqbrdf.model import brdf
from freqbrdf.model._kernels import (
    azimuthal_coefficients,
    borrowing_jit,
    cross,
    environment_burley_terms,
    environment_node,
    environment_node_lights,
    environment_share,
    fill_kernel,
    g1_and_derivative,
    mirror_stencil,
    n_sh_degrees,
    prefiltered_between,
    prefiltered_nodes_at,
    specular_albedo,
    texel_environment,
    uniform_burley_terms,
)
from freqbrdf.model.brdf import ALPHA_MIN, DIELECTRIC_F0
from freqbrdf.model.light import (
    degree_projections,
    environment_azimuthal,
    environment_quadrature,
    mirror_projections,
    prefiltered_environment,
)
from freqbrdf.model.tables import (
    DIELECTRIC_PLANE,
    ENVIRONMENT_LMAX,
    ENVIRONMENT_NODES,
    LOBE_TERMS,
    PREFILTER_STEP,
    TABLE_COS_NODES,
    burley_response_table,
    environment_response_table,
    split_sum_rows,
    split_sum_table,
    table_lookup,
)
from freqbrdf.observe.observations import Observations
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.sphere import harmonics as sh

# A robust pass scans the roughness nodes within this many cells of the previous optimum.
_ROBUST_NODES = 1
# `global` estimates texels with at least this many samples: 3 n equations for 5 unknowns.
MIN_SAMPLES = 2
# Base colour (3), roughness and metallic: the degrees of freedom a texel's residual loses.
FITTED_PARAMETERS = 5
# The neighbour vote's likelihood-ratio threshold: chi^2 with one degree of freedom at 95 %.
_VOTE_CHI2 = 3.84
# A vote's minimum this close (in grid cells) to its search's bounds lies beyond them: refused.
_VOTE_MARGIN = 0.01
# Texels per parallel work item of the search: amortises the scratch buffers.
_SEARCH_CHUNK = 64
# Texels per block when expanding the light by degree: bounds the (block, V, K) SH basis.
_PROJECTION_BLOCK = 8192
# Texels per block of hypothesis moments: bounds the (block, R, 3, 8) float64 moments to 28 MB at
# R = 9 (the 256k texels of a T = 512 texture at once: 442 MB).
HYPOTHESIS_BLOCK = 16384
# Brent's absolute tolerance on roughness; its relative part is sqrt(machine eps).
# A grid minimum on the boundary of [0, 1] is kept when the loss rises this far inside, instead of
# letting Brent creep towards the boundary in golden steps.
_BRENT_XTOL = 1e-5
_BRENT_COARSE_XTOL = 1e-3
_BRENT_MAX_EVALS = 60
# Roughness step of the profiled loss's second divided difference (MaterialEstimate.roughness_curvature).
CURVATURE_STEP = 0.05
# torch.optim.Adam's defaults, which the prototype used.
_ADAM_BETA1, _ADAM_BETA2, _ADAM_EPS = 0.9, 0.999, 1e-8
# The 8-neighbourhood of the prototype's 3 x 3 total-variation stencil (the centre adds zero).
_NEIGHBOUR_OFFSETS = tuple((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0))


@dataclass(eq=False)
class MaterialEstimate:
    """Principled parameters per texel of an Observations (N texels)."""

    texture_res: int  # T
    texel_index: np.ndarray  # (N,) int64 flat row-major index into the T x T texture
    base_color: np.ndarray  # (N, 3) float64 linear RGB in [0, 1]; NaN where not estimated
    roughness: np.ndarray  # (N,) float64 in [0, 1]; NaN where not estimated
    metallic: np.ndarray  # (N,) float64 in [0, 1]; NaN where not estimated
    estimated: np.ndarray  # (N,) bool: the texel had at least one sample
    # (N,) weighted mean squared residual of the angular model under the final light,
    # sum_v,c w_v^2 (L_c(w_v) - f_v,c)^2 / sum_v w_v^2 (channels summed); NaN where not estimated.
    loss: np.ndarray
    method: str  # "global" or "paper/<forward model>"
    timings: dict = field(default_factory=dict)  # seconds per stage
    # (N,) ``global`` only: d^2 loss / d roughness^2 of the profiled loss (base colour and metallic
    # re-optimised at each roughness) at the estimate, from a second divided difference over
    # `CURVATURE_STEP` (one-sided within [0, 1]); NaN where not estimated. Its inverse scales the
    # marginal posterior variance of the roughness (uncertainty.roughness_std).
    roughness_curvature: np.ndarray | None = None

    @property
    def n_texels(self) -> int:
        return len(self.texel_index)

    def principled(self) -> brdf.PrincipledParams:
        return brdf.PrincipledParams(base_color=self.base_color, roughness=self.roughness, metallic=self.metallic)

    def to_texture(self, values: np.ndarray, fill: float = np.nan) -> np.ndarray:
        """Per-texel values (N,) or (N, C) as a (T, T) or (T, T, C) image, ``fill`` elsewhere."""
        return texels.scatter(self, np.asarray(values), fill)  # scatter reads texture_res, texel_index

    def textures(self) -> dict[str, np.ndarray]:
        """base_color (T, T, 3), roughness and metallic (T, T): NaN off the estimated texels."""
        keep = self.estimated[:, None]
        return {
            "base_color": self.to_texture(np.where(keep, self.base_color, np.nan)),
            "roughness": self.to_texture(np.where(self.estimated, self.roughness, np.nan)),
            "metallic": self.to_texture(np.where(self.estimated, self.metallic, np.nan)),
        }


@dataclass(frozen=True)
class HypothesisRecorder:
    """Metal hypotheses for the `global` estimator to score on the way (`estimate`'s
    ``hypotheses``). Its first roughness scan probes every roughness node with the light and
    weights that `hypothesis_moments` uses, so a hypothesis on a node costs no probe of its own
    (`uncertainty.AngularEntropy` gets the angular entropy that way)."""

    roughness: np.ndarray  # (R,) the hypotheses' roughness; each value off the search's nodes costs a probe
    # Called once per block of texels (a slice of the N) with their `hypothesis_moments` (n, R, 3, 8).
    consume: Callable[[slice, np.ndarray], None]


def estimate(observations: Observations, config: Config = Config(), reporter: Reporter = SILENT,
             hypotheses: HypothesisRecorder | None = None) -> MaterialEstimate:
    """Estimate base colour, roughness and metallic per texel with ``config.estimate.method``.

    ``config.fit`` must be the fit the observations were made with: shadowing refreshes re-fit
    the light with it. With ``hypotheses`` (method "global" only) the search also hands over the
    `hypothesis_moments` of those roughness values, block by block (`HYPOTHESIS_BLOCK` texels).
    """
    settings = config.estimate
    _validate(settings)
    if settings.method == "global":
        return _estimate_global(observations, config, reporter, hypotheses)
    if hypotheses is not None:
        raise ValueError("only the global estimator records hypotheses: its search probes them")
    return _estimate_paper(observations, config, reporter)


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
        _squared_residual_kernel(
            fitted,
            observations.view_direction[rows], observations.weight[rows], observations.observed[rows],
            _diffuse_scale(observations)[rows], base_color[rows], metallic[rows],
            np.asarray(params.roughness, dtype=np.float64)[rows], observations.sigma, settings.fresnel,
            settings.masking, _uses_split_sum(settings), _uses_exact_dielectric(settings), _uses_burley(settings),
            split_sum_table(), environment_response_table(), _burley_response(settings), azimuthal, blend,
            tangent[rows], normal[rows], prefiltered, n_full, world_to_local, map_height, map_width, loss[rows],
        )
    return np.where(observations.n_samples > 0, loss, np.nan)


def model_light(observations: Observations, roughness: np.ndarray, config: Config = Config()) -> np.ndarray:
    """(N, 3, K) the incoming light's SH fit as the estimator's model sees it at ``roughness`` (N,):
    shadowed by G1 for METHOD.md's model with shadowing on, else the mirrored light (the split-sum
    albedo holds the shadowing). Pass it to `angular_loss` to score parameters as the estimator does."""
    settings = config.estimate
    if not settings.shadowing or _uses_split_sum(settings):
        return observations.mirrored_coeffs
    return _shadowed_light_coeffs(observations, brdf.alpha_from_roughness(roughness), config.fit)


def hypothesis_moments(observations: Observations, roughness: np.ndarray, config: Config = Config()) -> np.ndarray:
    """(N, R, 3, 8) float64 per texel, roughness (R,) and channel: [sum w, sum w u, sum w X,
    sum w u^2, sum w u X, sum w X^2, sum w f, sum w f^2] over the texel's samples, w the sample
    weight, f the observed radiance, u = f - Y, where a metal of base colour k reflects k X + Y
    under the `global` estimator's model of ``config.estimate`` (X = A S_A, Y = B S_B: Schlick's
    Fresnel with R0 = k, the light as that model reads it; with "g1" the unshadowed light). The
    weighted misfit of any specular hypothesis (roughness, k) plus a constant diffuse part is a
    quadratic in k and the diffuse part from these (`uncertainty.entropy_angular`), and so is that
    of no specular lobe at all. Zero for texels with fewer than `MIN_SAMPLES` samples."""
    settings = config.estimate
    _validate(settings)
    roughness = np.ascontiguousarray(roughness, dtype=np.float64)
    moments = np.zeros((observations.n_texels, len(roughness), 3, 8))
    n_texels = observations.n_texels
    _run_search_kernel(observations, settings, observations.mirrored_coeffs, roughness, moments, False,
                       np.zeros((n_texels, 5)), np.zeros(n_texels), np.zeros(n_texels))
    return moments


def _node_rows(roughness: np.ndarray, roughness_grid: int) -> np.ndarray:
    """(roughness_grid,) int64: per roughness node of the search, the index into ``roughness`` (R,)
    of a hypothesis at that node, or -1."""
    rows = np.full(roughness_grid, -1, dtype=np.int64)
    nodes = np.rint(roughness * (roughness_grid - 1)).astype(np.int64)
    on_node = (np.abs(nodes / (roughness_grid - 1) - roughness) < 1e-12) & (nodes >= 0) & (nodes < roughness_grid)
    rows[nodes[on_node]] = np.flatnonzero(on_node)
    return rows


def _run_search_kernel(observations: Observations, settings: EstimateConfig, light: np.ndarray,
                       hypothesis_roughness: np.ndarray, hypothesis_moments: np.ndarray, search: bool,
                       params: np.ndarray, loss: np.ndarray, curvature: np.ndarray,
                       candidate: np.ndarray = np.zeros((0, 2))) -> None:
    """`_global_search_kernel` on the observations with this light fit (N, 3, K) and settings. With
    ``search``, hypotheses on the roughness nodes are recorded by the search's first scan."""
    tangent, normal, environment, blend, *prefiltered = _environment_inputs(observations, settings)
    hypothesis_roughness = np.ascontiguousarray(hypothesis_roughness, dtype=np.float64)
    node_rows = (_node_rows(hypothesis_roughness, settings.roughness_grid) if search and len(hypothesis_roughness)
                 else np.full(0, -1, dtype=np.int64))
    _global_search_kernel(
        observations.view_direction, observations.weight, observations.observed,
        np.ascontiguousarray(light, dtype=np.float32), _diffuse_scale(observations), observations.sigma,
        settings.fresnel, settings.masking, _uses_split_sum(settings), _uses_exact_dielectric(settings),
        _uses_burley(settings), split_sum_table(), split_sum_rows(), settings.roughness_grid,
        settings.metallic_grid, settings.robust_passes, observations.lmax, *sh._legendre_tables(observations.lmax),
        tangent, normal, environment, blend, environment_response_table(),
        *environment_quadrature(max(math.isqrt(len(environment)) - 1, 0)), _burley_response(settings),
        *prefiltered, hypothesis_roughness, hypothesis_moments, node_rows,
        search, candidate, params, loss, curvature,
    )


# ---------------------------------------------------------------------------------------------
# Shared pieces


def _validate(settings: EstimateConfig) -> None:
    if settings.method not in ("global", "paper"):
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


def texel_blocks(n_texels: int, size: int = _PROJECTION_BLOCK):
    for start in range(0, n_texels, size):
        yield slice(start, min(start + size, n_texels))


def _diffuse_scale(observations: Observations) -> np.ndarray:
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


def _uses_split_sum(settings: EstimateConfig) -> bool:
    return settings.method == "global" and settings.specular_model == "split_sum"


def _uses_exact_dielectric(settings: EstimateConfig) -> bool:
    return _uses_split_sum(settings) and settings.fresnel and settings.dielectric_fresnel == "exact"


def _uses_environment_light(observations: Observations, settings: EstimateConfig) -> bool:
    """The environment light needs the split-sum model and observations that carry the environment."""
    return (_uses_split_sum(settings) and settings.environment_light and observations.tangent is not None
            and observations.environment_coeffs is not None)


def _uses_prefiltered_light(observations: Observations, settings: EstimateConfig) -> bool:
    """The prefiltered light needs the split-sum model and observations that carry the map and frames."""
    return (_uses_split_sum(settings) and settings.prefiltered_light and observations.tangent is not None
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


def _shadowed_light_coeffs(observations: Observations, alpha: np.ndarray, fit: FitConfig) -> np.ndarray:
    """(N, 3, K) SH fit of the mirrored light shadowed by G1(theta_i, alpha) (appendix eq. 6)."""
    light = brdf.shadowed_light(observations.mirrored, observations.view_direction[..., 2], alpha)
    return sh.fit_sh(
        observations.view_direction, observations.weight, light.astype(np.float32), observations.lmax,
        fit.reg_lambda, fit.regulariser, fit.scale_lambda_with_weight,
    ).coeffs


@numba.njit(parallel=True, fastmath=True, cache=True)
def _squared_residual_kernel(
    proj, directions, weight, observed, diffuse_scale, base_color, metallic, roughness, sigma, fresnel, masking,
    split_sum, exact_dielectric, burley, table, response, burley_response, azimuthal, environment_blend, tangent,
    normal, prefiltered, n_full, world_to_local, map_height, map_width, out,
):
    """out[t] = sum_v,c w^2 (L - f)^2 / sum_v w^2 (0 without samples); directions (n, V, 3) local
    view directions. proj (n, 3, l*+1, V): `mirror_projections`. The specular is
    m (b X + Y) + (1 - m) Z with X = A S_A, Y = B S_B (S_k: the light filtered for term k,
    `lobe_filtered_light`) and Z = E S_E with ``exact_dielectric``, else Schlick's 0.04 X + Y.
    With azimuthal (n, V, 3, P > 0)
    (`environment_azimuthal`) each S_k is blended towards the environment light
    (`environment_filtered_light`; response `environment_response_table`), and with burley_response
    (4, cos nodes, P > 0) Burley's diffuse is averaged over its light (`environment_burley_factor`).
    With prefiltered maps (H W, nodes, 3) the lobes read `prefiltered_light` (texel frames tangent
    and normal (n, 3)) instead of proj."""
    n_texels, n_views = weight.shape
    n_degrees = proj.shape[2]
    n_terms = len(LOBE_TERMS)
    for t in numba.prange(n_texels):
        alpha = max(roughness[t] * roughness[t], ALPHA_MIN)
        kernel = np.empty(n_degrees)
        fill_kernel(alpha, sigma, kernel, np.empty(n_degrees))
        filtered = np.empty(n_terms)
        share = environment_share(roughness[t], environment_blend) if azimuthal.shape[3] > 0 else 0.0
        # The environment light at the roughness nodes on either side, per term, channel and view.
        environment_light = np.zeros((2, 3, 3, n_views))  # all three terms, used or not
        # Burley's factor c0 + r c1 + r^2 c2 per channel and view: under uniform light, or the
        # environment's.
        burley_terms = np.empty((3, 3, n_views))
        for v in range(n_views):
            uniform_burley_terms(np.float64(directions[t, v, 2]), burley, burley_terms[:, :, v])
        environment_burley = burley and burley_response.shape[2] > 0 and azimuthal.shape[3] > 0
        table_row = np.empty(n_views, dtype=np.int64)
        table_frac = np.empty(n_views)
        if share > 0.0 or environment_burley:
            for v in range(n_views):
                x = min(max(np.float64(directions[t, v, 2]), 0.0), 1.0) * (table.shape[1] - 1)
                table_row[v] = min(int(x), table.shape[1] - 2)
                table_frac[v] = x - table_row[v]
        if environment_burley:
            environment_burley_terms(n_views, table_row, table_frac, azimuthal[t], burley_response, burley_terms)
        if share > 0.0:
            node, node_frac = environment_node(roughness[t])
            for side in range(2):
                environment_node_lights(response, node + side, n_views, table_row, table_frac, azimuthal[t],
                                         environment_light[side])
        # The prefiltered light at its nodes on either side, per channel and view.
        use_prefiltered = n_full > 0 and share < 1.0
        n_high = prefiltered.shape[1] - n_full
        use_high = n_high > 0 and share > 0.0
        nodes = np.empty((prefiltered.shape[1], 3, n_views))
        cached = np.zeros(prefiltered.shape[1], dtype=np.bool_)
        lower_map = upper_map = lower_high = upper_high = 0  # the full and the high nodes
        map_frac = high_frac = 0.0
        corner = np.zeros((4, n_views), dtype=np.int64)
        stencil_frac = np.zeros((2, n_views))
        if use_prefiltered or use_high:
            xyz = np.empty((3, n_views))
            for v in range(n_views):
                for axis in range(3):
                    xyz[axis, v] = directions[t, v, axis]
            bitangent = np.empty(3)
            cross(normal[t], tangent[t], bitangent)
            mirror_stencil(xyz, n_views, tangent[t], normal[t], bitangent, world_to_local, map_height, map_width,
                            corner, stencil_frac)
        if use_prefiltered:
            lower_map, upper_map, map_frac = prefiltered_nodes_at(roughness[t], 0, n_full, n_views, prefiltered,
                                                                   corner, stencil_frac, nodes, cached)
        if use_high:
            lower_high, upper_high, high_frac = prefiltered_nodes_at(roughness[t], n_full, n_high, n_views,
                                                                      prefiltered, corner, stencil_frac, nodes, cached)
        # Without the environment light every term reads the same light; Schlick's dielectric needs
        # no light of its own.
        distinct = share > 0.0
        distinct_terms = (n_terms if exact_dielectric else n_terms - 1) if distinct else 1
        total = 0.0
        weight_sq = 0.0
        for v in range(n_views):
            w = np.float64(weight[t, v])
            if w > 0.0:
                cos_v = np.float64(directions[t, v, 2])
                scale, bias = specular_albedo(cos_v, roughness[t], alpha, fresnel, masking, split_sum, table)
                dielectric = table_lookup(table, DIELECTRIC_PLANE, cos_v, roughness[t]) if exact_dielectric else 0.0
                for c in range(3):
                    for term in range(distinct_terms):
                        filtered[term] = 0.0
                        if use_prefiltered:
                            filtered[term] = prefiltered_between(nodes, c, v, lower_map, upper_map, map_frac)
                        else:
                            for degree in range(n_degrees):
                                filtered[term] += kernel[degree] * proj[t, c, degree, v]
                        if share > 0.0:
                            lower = environment_light[0, term, c, v]
                            light = lower + node_frac * (environment_light[1, term, c, v] - lower)
                            if use_high:
                                light += prefiltered_between(nodes, c, v, lower_high, upper_high, high_frac)
                            filtered[term] = (1.0 - share) * filtered[term] + share * light
                    for term in range(distinct_terms, n_terms):
                        filtered[term] = filtered[0]
                    x, y = scale * filtered[0], bias * filtered[1]
                    z = dielectric * filtered[2] if exact_dielectric else DIELECTRIC_F0 * x + y
                    m, b = metallic[t], base_color[t, c]
                    terms = burley_terms[c, :, v]
                    diffuse_factor = terms[0] + roughness[t] * (terms[1] + roughness[t] * terms[2])
                    residual = (m * (b * x + y) + (1.0 - m) * z
                                + (1.0 - m) * b * diffuse_scale[t, c] * diffuse_factor - observed[t, v, c])
                    total += w * w * residual * residual
                weight_sq += w * w
        out[t] = total / weight_sq if weight_sq > 0.0 else 0.0


# ---------------------------------------------------------------------------------------------
# global: exhaustive search with a closed-form base colour


def _estimate_global(observations: Observations, config: Config, reporter: Reporter,
                     hypotheses: HypothesisRecorder | None) -> MaterialEstimate:
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
    split_sum = _uses_split_sum(settings)
    n_passes = 1 + (settings.shadowing_refreshes if settings.shadowing and not split_sum else 0)
    with reporter.stage("estimating (global)", n_passes) as advance:
        for pass_index in range(n_passes):
            tick = time.perf_counter()
            if pass_index > 0:
                light = _shadowed_light_coeffs(observations, brdf.alpha_from_roughness(shadow_roughness), config.fit)
            timings["light"] += time.perf_counter() - tick
            tick = time.perf_counter()
            if pass_index == 0 and hypotheses is not None:  # pass 0's light is the one hypotheses are scored in
                for rows in texel_blocks(n_texels, HYPOTHESIS_BLOCK):
                    moments = np.zeros((rows.stop - rows.start, len(hypotheses.roughness), 3, 8))
                    _run_search_kernel(observations.select(rows), settings, light[rows], hypotheses.roughness,
                                       moments, True, params[rows], loss[rows], curvature[rows])
                    hypotheses.consume(rows, moments)
            else:
                _run_search_kernel(observations, settings, light, np.zeros(0), np.zeros((0, 0, 3, 8)), True, params,
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
        _run_search_kernel(observations, settings, light, np.zeros(0), np.zeros((0, 0, 3, 8)), False, params, loss,
                           curvature, candidate)
        timings["vote"] = time.perf_counter() - tick
    timings["total"] = sum(timings.values())
    result = _result(observations, params, loss, estimated, "global", timings)
    result.roughness_curvature = np.where(estimated, curvature, np.nan)
    return result


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


def _result(observations, params, loss, estimated, method, timings) -> MaterialEstimate:
    unknown = ~estimated
    params = params.copy()
    params[unknown] = np.nan
    return MaterialEstimate(
        texture_res=observations.texture_res,
        texel_index=observations.texel_index,
        base_color=params[:, :3],
        roughness=params[:, 3],
        metallic=params[:, 4],
        estimated=estimated,
        loss=np.where(unknown, np.nan, loss),
        method=method,
        timings=timings,
    )


# Brent's bounded minimiser (golden section with parabolic steps, as scipy's fminbound) in
# reverse communication: the caller evaluates the objective, so no function is passed around
# (numba cannot cache functions taking functions). State slots of a (12,) float64 array:
_LO, _HI, _X, _FX, _W, _FW, _V, _FV, _STEP, _PREV_STEP, _PROBE, _EVALS, _XTOL = range(13)
_GOLDEN = 0.5 * (3.0 - math.sqrt(5.0))
_SQRT_EPS = math.sqrt(2.2e-16)


@borrowing_jit
def _brent_start(state, lower, upper, xtol):
    """Begin minimising on [lower, upper] to absolute tolerance xtol; returns the first point to
    evaluate."""
    state[_LO], state[_HI], state[_XTOL] = lower, upper, xtol
    state[_PROBE] = lower + _GOLDEN * (upper - lower)
    state[_STEP] = state[_PREV_STEP] = 0.0
    state[_EVALS] = 0.0
    return state[_PROBE]


@borrowing_jit
def _brent_seed(state, lower, upper, xtol, x, fx, w, fw, v, fv):
    """Begin minimising on [lower, upper] from three evaluated points: x the best, w the second
    best, v the third (a bracketing grid's node and its neighbours), so that the first step is
    the parabola through them rather than golden steps that re-discover them. Returns True with
    the first point to evaluate in state[_PROBE], or False when the bracket is already within
    tolerance (the best point is state[_X])."""
    state[_LO], state[_HI], state[_XTOL] = lower, upper, xtol
    state[_X], state[_FX], state[_W], state[_FW], state[_V], state[_FV] = x, fx, w, fw, v, fv
    # As if golden steps of the bracket's size had led here: the parabola may take any step
    # that stays inside (Brent accepts one below half the step before last).
    state[_STEP] = state[_PREV_STEP] = upper - lower
    state[_EVALS] = 3.0
    return _brent_propose(state)


@borrowing_jit
def _brent_next(state, f_probe):
    """Take f at the last point; returns True with the next point in state[_PROBE], or False when
    done, the best point being state[_X] with value state[_FX]."""
    a, b, u = state[_LO], state[_HI], state[_PROBE]
    if state[_EVALS] == 0.0:
        state[_X] = state[_W] = state[_V] = u
        state[_FX] = state[_FW] = state[_FV] = f_probe
    else:
        x, fx, w, fw, v, fv = state[_X], state[_FX], state[_W], state[_FW], state[_V], state[_FV]
        if f_probe <= fx:
            if u >= x:
                a = x
            else:
                b = x
            v, fv, w, fw, x, fx = w, fw, x, fx, u, f_probe
        else:
            if u < x:
                a = u
            else:
                b = u
            if f_probe <= fw or w == x:
                v, fv, w, fw = w, fw, u, f_probe
            elif f_probe <= fv or v == x or v == w:
                v, fv = u, f_probe
        state[_LO], state[_HI] = a, b
        state[_X], state[_FX], state[_W], state[_FW], state[_V], state[_FV] = x, fx, w, fw, v, fv
    state[_EVALS] += 1.0
    return _brent_propose(state)


@borrowing_jit
def _brent_propose(state):
    """The next point to evaluate into state[_PROBE] (True), or False when converged."""
    a, b = state[_LO], state[_HI]
    x, fx, w, fw, v, fv = state[_X], state[_FX], state[_W], state[_FW], state[_V], state[_FV]
    middle = 0.5 * (a + b)
    tol1 = _SQRT_EPS * abs(x) + state[_XTOL] / 3.0
    tol2 = 2.0 * tol1
    if abs(x - middle) <= tol2 - 0.5 * (b - a) or state[_EVALS] >= _BRENT_MAX_EVALS:
        return False
    step, previous_step = state[_STEP], state[_PREV_STEP]
    use_golden = True
    if abs(previous_step) > tol1:  # try the parabola through x, w, v
        r = (x - w) * (fx - fv)
        q = (x - v) * (fx - fw)
        p = (x - v) * q - (x - w) * r
        q = 2.0 * (q - r)
        if q > 0.0:
            p = -p
        q = abs(q)
        older_step = previous_step
        previous_step = step
        if abs(p) < abs(0.5 * q * older_step) and q * (a - x) < p < q * (b - x):
            step = p / q
            use_golden = False
            if (x + step - a) < tol2 or (b - x - step) < tol2:
                step = tol1 if middle >= x else -tol1
    if use_golden:
        previous_step = (a - x) if x >= middle else (b - x)
        step = _GOLDEN * previous_step
    state[_STEP], state[_PREV_STEP] = step, previous_step
    state[_PROBE] = x + (step if abs(step) >= tol1 else (tol1 if step >= 0.0 else -tol1))
    return True


# Safeguarded Newton on the metallic: steps stop below this, and after this many iterations.
_NEWTON_MTOL = 1e-10
_NEWTON_MAX_STEPS = 40


@borrowing_jit
def _metallic_quadratics(moments, squared_values, diffuse_scale, quadratics):
    """The loss per channel as q2 b^2 + 2 q1 b + q0 with q2, q1, q0 quadratics in the metallic m:
    quadratics (3, 3, 3) [channel, (q2, q1, q0), coefficient of (1, m, m^2)].

    L = b P + Q with P = m X + (1 - m) e D, Q = m Y + (1 - m) Z (X = A S, Y = B S, Z = E S, e = E/pi);
    moments (3, 14) per channel: the weighted sums s_xd, s_yd, s_zd, s_xx, s_xy, s_xz, s_xf, s_yy,
    s_yz, s_yf, s_zz, s_zf, s_dd, s_fd (s_ab = sum_v w^2 a b), squared_values (3,) s_ff.
    """
    # Whole indices, no row views: a view costs a reference count update (an atomic) in numba,
    # and these run at every probe.
    for c in range(3):
        s_xd, s_yd, s_zd, s_xx, s_xy = moments[c, 0], moments[c, 1], moments[c, 2], moments[c, 3], moments[c, 4]
        s_xz, s_xf, s_yy, s_yz, s_yf = moments[c, 5], moments[c, 6], moments[c, 7], moments[c, 8], moments[c, 9]
        s_zz, s_zf, s_dd, s_fd = moments[c, 10], moments[c, 11], moments[c, 12], moments[c, 13]
        e = diffuse_scale[c]
        q = quadratics
        q[c, 0, 0] = e * e * s_dd  # sum w P^2
        q[c, 0, 1] = 2.0 * e * (s_xd - e * s_dd)
        q[c, 0, 2] = s_xx - 2.0 * e * s_xd + e * e * s_dd
        q[c, 1, 0] = e * (s_zd - s_fd)  # sum w P (Q - f)
        q[c, 1, 1] = s_xz - s_xf + e * (s_yd - 2.0 * s_zd + s_fd)
        q[c, 1, 2] = s_xy - s_xz + e * (s_zd - s_yd)
        q[c, 2, 0] = s_zz - 2.0 * s_zf + squared_values[c]  # sum w (Q - f)^2
        q[c, 2, 1] = 2.0 * (s_yz - s_zz - s_yf + s_zf)
        q[c, 2, 2] = s_yy - 2.0 * s_yz + s_zz


@borrowing_jit
def _metallic_terms(metallic, quadratics, state):
    """Loss at the best base colour for this metallic (summed over channels) and its first two
    derivatives in the metallic; writes that base colour and the metallic into state[:4].

    Per channel the loss is q2 b^2 + 2 q1 b + q0 (`_metallic_quadratics`). At the optimal (or
    clipped) b the first derivative is the partial one at fixed b (envelope theorem); the second
    adds the change of the unclipped b with m.
    """
    m = metallic
    total = gradient = curvature = 0.0
    q = quadratics
    for c in range(3):  # whole indices: see `_metallic_quadratics`
        q2 = q[c, 0, 0] + m * (q[c, 0, 1] + m * q[c, 0, 2])
        q2_1 = q[c, 0, 1] + 2.0 * m * q[c, 0, 2]
        q2_2 = 2.0 * q[c, 0, 2]
        q1 = q[c, 1, 0] + m * (q[c, 1, 1] + m * q[c, 1, 2])
        q1_1 = q[c, 1, 1] + 2.0 * m * q[c, 1, 2]
        q1_2 = 2.0 * q[c, 1, 2]
        q0 = q[c, 2, 0] + m * (q[c, 2, 1] + m * q[c, 2, 2])
        q0_1 = q[c, 2, 1] + 2.0 * m * q[c, 2, 2]
        q0_2 = 2.0 * q[c, 2, 2]
        base = -q1 / q2 if q2 > 0.0 else 0.0
        interior = 0.0 < base < 1.0
        base = min(max(base, 0.0), 1.0)  # a 1-D convex quadratic: clip
        total += (q2 * base + 2.0 * q1) * base + q0
        slope = q2_1 * base + q1_1  # d b / d m = -slope / q2 where b is not clipped
        gradient += (q2_1 * base + 2.0 * q1_1) * base + q0_1
        curvature += (q2_2 * base + 2.0 * q1_2) * base + q0_2
        if interior:
            curvature -= 2.0 * slope * slope / q2
        state[c] = base
    state[3] = m
    return total, gradient, curvature


@borrowing_jit
def _profile_metallic(quadratics, state, metallic_grid):
    """min over (b, m) of the loss for fixed `_metallic_quadratics`: metallic grid, then safeguarded
    Newton on the derivative in the best cell (bisection where Newton would leave the bracket).
    Leaves the winner's base colour and metallic in state and returns its loss."""
    # Each evaluation also writes its base colour into state: the last one evaluated is tracked so
    # that the winner is re-evaluated only when it is not that one.
    best_m, best_f, slope, curvature = 0.0, np.inf, 0.0, 0.0
    for j in range(metallic_grid):
        m = j / (metallic_grid - 1)
        f, f_slope, f_curvature = _metallic_terms(m, quadratics, state)
        if f < best_f:
            best_m, best_f, slope, curvature = m, f, f_slope, f_curvature
    last_m = 1.0  # the grid's last node
    cell = 1.0 / (metallic_grid - 1)
    if (best_m == 0.0 and slope >= 0.0) or (best_m == 1.0 and slope <= 0.0) or slope == 0.0:
        # A pure dielectric or a pure metal (or a node exactly at the minimum).
        return best_f if last_m == best_m else _metallic_terms(best_m, quadratics, state)[0]
    # The minimum lies on the downhill side of the best node, within one cell.
    lower, upper = (best_m, min(best_m + cell, 1.0)) if slope < 0.0 else (max(best_m - cell, 0.0), best_m)
    m = best_m
    for _ in range(_NEWTON_MAX_STEPS):
        step = -slope / curvature if curvature > 0.0 else np.inf
        candidate = m + step
        if not (lower < candidate < upper):
            candidate = 0.5 * (lower + upper)
        if abs(candidate - m) < _NEWTON_MTOL:
            break
        m = candidate
        f_m, slope, curvature = _metallic_terms(m, quadratics, state)
        last_m = m
        if f_m < best_f:
            best_m, best_f = m, f_m
        if slope < 0.0:
            lower = m
        elif slope > 0.0:
            upper = m
        else:
            break
        if upper - lower < _NEWTON_MTOL:
            break
    return best_f if last_m == best_m else _metallic_terms(best_m, quadratics, state)[0]


@borrowing_jit
def _roughness_objective(roughness, args):
    """Profiled loss at this roughness: min over base colour and metallic (written to state).

    Per sample, only the specular albedo (A, B, E) and the diffuse factor D depend on the roughness
    besides the kernel; their roughness-free parts were prepared per texel
    (`_global_search_kernel`).
    """
    (n, cos_theta, omega, proj, values, sigma, fresnel, masking, split_sum, exact_dielectric, burley, table,
     table_row, table_frac, burley_terms, diffuse_moments, column, kernel, kernel_derivative,
     albedo, diffuse_factor, own_filtered, filtered, moments, quadratics, squared_values, diffuse_scale,
     state, metallic_grid, azimuthal, environment_blend, environment_nodes, environment_cached, response,
     prefiltered, n_full, corner, stencil_frac, prefiltered_nodes, prefiltered_cached,
     high_filtered, table_rows) = args
    # Without the environment (environment light off) the lobes read their own light alone.
    share = environment_share(roughness, environment_blend) if azimuthal.shape[2] > 0 else 0.0
    # Terms with a light of their own: A and B, and E with the exact dielectric (else Z = 0.04 X + Y).
    n_terms = 3 if exact_dielectric else 2
    alpha = max(roughness * roughness, ALPHA_MIN)
    if split_sum:  # the table's column at this roughness, linear in it (from its rows, `split_sum_rows`)
        y = min(max(roughness, 0.0), 1.0) * (table_rows.shape[1] - 1)
        j = min(int(y), table_rows.shape[1] - 2)
        fy = y - j
        for term in range(n_terms):
            for i in range(table_rows.shape[2]):
                column[term, i] = table_rows[term, j, i] * (1.0 - fy) + table_rows[term, j + 1, i] * fy
        if share > 0.0:
            # The environment light at its roughness nodes on either side, each computed once per
            # texel (the search visits few, most of them many times); on a node (the grid's nodes
            # are nodes of the table) the other one is not needed.
            node, node_frac = environment_node(roughness)
            lower_node = node if node_frac < 1.0 else node + 1
            upper_node = node + 1 if node_frac > 0.0 else node
            for needed in range(lower_node, upper_node + 1):
                if not environment_cached[needed]:
                    environment_node_lights(response, needed, n, table_row, table_frac, azimuthal,
                                             environment_nodes[needed])
                    environment_cached[needed] = True
        for s in range(n):
            row, fx = table_row[s], table_frac[s]
            for term in range(n_terms):
                albedo[term, s] = column[term, row] + fx * (column[term, row + 1] - column[term, row])
    else:
        for s in range(n):
            albedo[0, s], albedo[1, s] = specular_albedo(cos_theta[s], roughness, alpha, fresnel, masking, False,
                                                          table)
    if split_sum and not fresnel:
        for s in range(n):
            albedo[0, s] += albedo[1, s]
            albedo[1, s] = 0.0
    # Burley's factor is c0 + r c1 + r^2 c2 per channel and sample (`burley_polynomial`,
    # `environment_burley_terms`); Lambert's is 1.
    for c in range(3):
        for s in range(n):
            diffuse_factor[c, s] = burley_terms[c, 0, s] + roughness * (burley_terms[c, 1, s]
                                                                        + roughness * burley_terms[c, 2, s])
    # The lobe's own light (contiguous, vectorised loops): the fitted light filtered by the kernel,
    # or the prefiltered light. A lobe that reads the environment light alone (share 1) needs none.
    own_light = share < 1.0
    # The prefiltered light replaces the fitted one: its nodes around this roughness, each looked
    # up once per texel.
    use_prefiltered = own_light and n_full > 0
    use_fitted = own_light and n_full == 0
    lower_map = upper_map = lower_high = upper_high = 0
    map_frac = high_frac = 0.0
    if use_prefiltered:
        lower_map, upper_map, map_frac = prefiltered_nodes_at(roughness, 0, n_full, n, prefiltered, corner,
                                                               stencil_frac, prefiltered_nodes, prefiltered_cached)
    # The degrees the environment light leaves out, from the prefiltered maps' last nodes.
    n_high = prefiltered.shape[1] - n_full
    use_high = share > 0.0 and n_high > 0
    if use_high:
        lower_high, upper_high, high_frac = prefiltered_nodes_at(roughness, n_full, n_high, n, prefiltered,
                                                                  corner, stencil_frac, prefiltered_nodes,
                                                                  prefiltered_cached)
    if use_fitted:
        fill_kernel(alpha, sigma, kernel, kernel_derivative)
    # Below, whole indices rather than row views (see `_metallic_quadratics`).
    for c in range(3):
        if use_prefiltered:
            for s in range(n):
                lower = prefiltered_nodes[lower_map, c, s]
                own_filtered[s] = lower + map_frac * (prefiltered_nodes[upper_map, c, s] - lower)
        if use_high:
            for s in range(n):
                lower = prefiltered_nodes[lower_high, c, s]
                high_filtered[s] = lower + high_frac * (prefiltered_nodes[upper_high, c, s] - lower)
        if use_fitted:
            k0 = kernel[0]
            for s in range(n):
                own_filtered[s] = k0 * proj[c, 0, s]
            for degree in range(1, kernel.shape[0]):
                k = kernel[degree]
                for s in range(n):
                    own_filtered[s] += k * proj[c, degree, s]
        model = filtered
        for term in range(n_terms):
            if own_light:
                for s in range(n):
                    model[c, term, s] = albedo[term, s] * own_filtered[s]
            if share > 0.0:
                frac = node_frac if upper_node != lower_node else 0.0
                keep = 1.0 - share
                for s in range(n):
                    lower = environment_nodes[lower_node, term, c, s]
                    light = lower + frac * (environment_nodes[upper_node, term, c, s] - lower)
                    if use_high:
                        light += high_filtered[s]
                    light *= albedo[term, s]
                    model[c, term, s] = keep * model[c, term, s] + share * light if own_light else light
        if not exact_dielectric:
            for s in range(n):
                model[c, 2, s] = DIELECTRIC_F0 * model[c, 0, s] + model[c, 1, s]
        s_xd = s_yd = s_zd = s_xx = s_xy = s_xz = s_xf = s_yy = s_yz = s_yf = s_zz = s_zf = 0.0
        for s in range(n):
            x, y, z = model[c, 0, s], model[c, 1, s], model[c, 2, s]  # X = A S_A, Y = B S_B, Z = E S_E
            f = values[c, s]
            d = diffuse_factor[c, s]
            wx = omega[s] * x
            wy = omega[s] * y
            wz = omega[s] * z
            s_xd += wx * d
            s_yd += wy * d
            s_zd += wz * d
            s_xx += wx * x
            s_xy += wx * y
            s_xz += wx * z
            s_xf += wx * f
            s_yy += wy * y
            s_yz += wy * z
            s_yf += wy * f
            s_zz += wz * z
            s_zf += wz * f
        s_dd = 0.0
        for power in range(4, -1, -1):
            s_dd = s_dd * roughness + diffuse_moments[c, 0, power]
        s_fd = diffuse_moments[c, 1, 0] + roughness * (diffuse_moments[c, 1, 1] + roughness * diffuse_moments[c, 1, 2])
        for index, total in enumerate((s_xd, s_yd, s_zd, s_xx, s_xy, s_xz, s_xf, s_yy, s_yz, s_yf, s_zz, s_zf, s_dd,
                                       s_fd)):
            moments[c, index] = total
    _metallic_quadratics(moments, squared_values, diffuse_scale, quadratics)
    return _profile_metallic(quadratics, state, metallic_grid)


@borrowing_jit
def _weighted_sums(n, omega, values, burley_terms, diffuse_moments, squared_values):
    """The roughness-free weighted sums of a texel's samples for `_roughness_objective`, per channel
    c: sum w^2 D_c^2 as a quartic in r (diffuse_moments[c, 0]) and sum w^2 f_c D_c as a quadratic
    (diffuse_moments[c, 1, :3]) (Burley's D_c = c0 + r c1 + r^2 c2, burley_terms (3, 3, n)), and
    sum w^2 f_c^2. Returns sum w^2."""
    diffuse_moments[:] = 0.0
    total_weight = 0.0
    for s in range(n):
        total_weight += omega[s]
    for c in range(3):
        quartic, quadratic = diffuse_moments[c, 0], diffuse_moments[c, 1]
        squared_values[c] = 0.0
        for s in range(n):
            c0, c1, c2 = burley_terms[c, 0, s], burley_terms[c, 1, s], burley_terms[c, 2, s]
            o = omega[s]
            quartic[0] += o * c0 * c0
            quartic[1] += 2.0 * o * c0 * c1
            quartic[2] += o * (c1 * c1 + 2.0 * c0 * c2)
            quartic[3] += 2.0 * o * c1 * c2
            quartic[4] += o * c2 * c2
            of = o * values[c, s]
            quadratic[0] += of * c0
            quadratic[1] += of * c1
            quadratic[2] += of * c2
            squared_values[c] += of * values[c, s]
    return total_weight


@borrowing_jit
def _keep_state(state, best_state):
    """best_state[:] = state, element by element (a slice assignment may allocate, and these
    functions run without numba's runtime)."""
    for i in range(state.shape[0]):
        best_state[i] = state[i]


@borrowing_jit
def _search_roughness(args, state, roughness_grid, best_state, roughness_brent, node_loss, first_node, last_node,
                      xtol, node_rows, node_moments, sample_weight):
    """Scan the roughness grid's nodes first_node..last_node, then Brent (to xtol) in the best cell
    unless the loss rises inwards from a boundary node. Brent starts from the parabola through the
    best node and its neighbours when the scan holds them. The best evaluation seen wins: returns
    (roughness, loss), its base colour and metallic in best_state (`_roughness_objective` leaves
    each probe's in state, the array in args). node_loss (roughness_grid,) scratch. A node whose
    node_rows entry (`_node_rows`; (0,): none) is a row i >= 0 records its hypothesis moments into
    node_moments[i] (R, 3, 8), with the samples' weights sample_weight (n,)."""
    cell = 1.0 / (roughness_grid - 1)
    best_node, best_r, best_f = first_node, 0.0, np.inf
    for i in range(first_node, last_node + 1):
        r = i / (roughness_grid - 1)
        node_loss[i] = _roughness_objective(r, args)
        if node_rows.shape[0] > 0 and node_rows[i] >= 0:
            _record_hypothesis(args, sample_weight, node_moments[node_rows[i]])
        if node_loss[i] < best_f:
            best_node, best_r, best_f = i, r, node_loss[i]
            _keep_state(state, best_state)
    node_r, node_f = best_r, best_f
    on_boundary = best_node == 0 or best_node == roughness_grid - 1
    bracketed = first_node < best_node < last_node
    if bracketed:
        lower_f, upper_f = node_loss[best_node - 1], node_loss[best_node + 1]
        lower_r, upper_r = node_r - cell, node_r + cell
        if lower_f <= upper_f:
            search = _brent_seed(roughness_brent, lower_r, upper_r, xtol, node_r, node_f, lower_r, lower_f, upper_r,
                                 upper_f)
        else:
            search = _brent_seed(roughness_brent, lower_r, upper_r, xtol, node_r, node_f, upper_r, upper_f, lower_r,
                                 lower_f)
    else:
        search = not on_boundary
        if on_boundary:
            probe = node_r + (_BRENT_XTOL if node_r == 0.0 else -_BRENT_XTOL)
            f = _roughness_objective(probe, args)
            search = f < node_f
            if f < best_f:
                best_r, best_f = probe, f
                _keep_state(state, best_state)
        if search:
            _brent_start(roughness_brent, max(node_r - cell, 0.0), min(node_r + cell, 1.0), xtol)
    return _brent_run(args, state, best_state, roughness_brent, best_r, best_f, search)


@borrowing_jit
def _brent_run(args, state, best_state, roughness_brent, best_r, best_f, search):
    """Brent's search as started in roughness_brent (if ``search``) on the profiled loss: returns the
    best (roughness, loss) of it and of (best_r, best_f), its base colour and metallic in best_state."""
    while search:
        f = _roughness_objective(roughness_brent[_PROBE], args)
        if f < best_f:
            best_r, best_f = roughness_brent[_PROBE], f
            _keep_state(state, best_state)
        search = _brent_next(roughness_brent, f)
    return best_r, best_f


@borrowing_jit
def _record_hypothesis(args, sample_weight, out):
    """out (3, 8): per channel `_specular_moments` of the metal terms the last `_roughness_objective`
    probe left in args (in the order `_roughness_objective` unpacks them), sample weights (n,)."""
    n, values, filtered = args[0], args[4], args[22]
    for c in range(3):
        _specular_moments(n, sample_weight, values[c], filtered[c, 0], filtered[c, 1], out[c])


@borrowing_jit
def _specular_moments(n, sample_weight, values, scale_terms, bias_terms, out):
    """out = [sum w, sum w u, sum w X, sum w u^2, sum w u X, sum w X^2, sum w f, sum w f^2] over
    samples s < n, with w the sample weight, f the observed radiance, u = f - Y and X, Y a metal's
    specular terms (scale_terms, bias_terms: specular = k X + Y for base colour k)."""
    out[:] = 0.0
    for s in range(n):
        w = sample_weight[s]
        f = values[s]
        u = f - bias_terms[s]
        x = scale_terms[s]
        out[0] += w
        out[1] += w * u
        out[2] += w * x
        out[3] += w * u * u
        out[4] += w * u * x
        out[5] += w * x * x
        out[6] += w * f
        out[7] += w * f * f


@borrowing_jit
def _residual_magnitudes(n, values, filtered, diffuse_factor, diffuse_scale, params, out):
    """out[s] = |L(w_s) - f_s| over the channels for params [b_rgb, m], with the per-channel model
    terms `_roughness_objective` left in filtered (3, 3, n) and diffuse_factor at their roughness."""
    m = params[3]
    for s in range(n):
        total = 0.0
        for c in range(3):
            x, y, z = filtered[c, 0, s], filtered[c, 1, s], filtered[c, 2, s]
            b = params[c]
            residual = (b * (m * x + (1.0 - m) * diffuse_scale[c] * diffuse_factor[c, s]) + m * y + (1.0 - m) * z
                        - values[c, s])
            total += residual * residual
        out[s] = math.sqrt(total)


@borrowing_jit
def _loss_curvature(best_r, centre_f, args):
    """The profiled loss's second divided difference in roughness through its value centre_f at
    best_r and two probes CURVATURE_STEP apart on the side within [0, 1]."""
    first_r = best_r + CURVATURE_STEP if best_r < CURVATURE_STEP else best_r - CURVATURE_STEP
    if best_r < CURVATURE_STEP:
        second_r = best_r + 2.0 * CURVATURE_STEP
    elif best_r > 1.0 - CURVATURE_STEP:
        second_r = best_r - 2.0 * CURVATURE_STEP
    else:
        second_r = best_r + CURVATURE_STEP
    first_f = _roughness_objective(first_r, args)
    second_f = _roughness_objective(second_r, args)
    return 2.0 * ((first_f - centre_f) / (first_r - best_r) - (second_f - centre_f) / (second_r - best_r)) / (
        first_r - second_r)


@numba.njit(parallel=True, fastmath=True, cache=True)
def _global_search_kernel(
    directions, weight, observed, light, diffuse_scale, sigma, fresnel, masking, split_sum, exact_dielectric, burley,
    table, table_rows, roughness_grid, metallic_grid, robust_passes, lmax, diag, rec_a, rec_b,
    tangent, normal, environment, environment_blend, response, quadrature, quadrature_projection, burley_response,
    prefiltered, n_full, world_to_local, map_height, map_width, hypothesis_roughness,
    hypothesis_moments, node_rows, search, candidate,
    params, loss, curvature,
):
    """Per texel: the (base colour, roughness, metallic) of least weighted squared residual.

    directions (n, V, 3) local view directions; weight (n, V); observed (n, V, 3); light (n, 3, K)
    the incoming light's SH fit; diffuse_scale (n, 3) E / pi; (lmax, diag, rec_a, rec_b) as
    `sh._sh_block` takes them. With a world-frame SH environment (K > 0, 3) the environment light
    (texel frames tangent and normal (n, 3); `environment_filtered_light` with response
    `environment_response_table` and `environment_quadrature`'s quadrature (Q, 3) and
    quadrature_projection (K, Q)) is blended in over environment_blend (start, end), and with
    burley_response (4, cos nodes, P > 0) (`burley_response_table`) Burley's diffuse is averaged over
    that light (`environment_burley_factor`) instead of uniform light.
    With prefiltered (H W, nodes, 3) maps (`prefiltered_environment` of an H x W map whose
    emitter frame is world_to_local (3, 3) from the world), smooth lobes read them at the world
    mirror directions instead of the fitted light. Else, per texel the light is expanded by
    degree at its samples (P_c,l(w_v), `mirror_projections`; fused here to keep it in cache). Then
    the roughness is searched (if ``search``).
    With hypothesis_roughness (R,): `hypothesis_moments` of each texel into hypothesis_moments
    (n, R, 3, 8), those of node_rows (roughness_grid,) (`_node_rows`; (0,): none) recorded by the
    search's first scan, the others probed before it. With candidate (n, 2) (roughness, metallic) instead of a
    search, the neighbour vote (`EstimateConfig.neighbour_vote`) on the estimate in params. Writes params
    (n, 5) [b_rgb, r, m], loss (n,) (divided by sum_v w^2) and the profiled loss's curvature in
    roughness (n,) (`MaterialEstimate.roughness_curvature`) for texels with samples; others are
    left untouched.
    """
    n_chunks = (weight.shape[0] + _SEARCH_CHUNK - 1) // _SEARCH_CHUNK
    # numba hands each thread a contiguous run of items: where the texels the cameras see lie in
    # one half of the texture, the other thread would wait (sphere: search 5.0 -> 3.8 s scattered).
    stride = scattering_stride(n_chunks)
    for item in numba.prange(n_chunks):
        # np.int64: the loop index is unsigned in numba's parallel code and signed when typed: one
        # signature, not two (each compiles the whole search).
        chunk = (np.int64(item) * stride) % n_chunks
        _global_search_chunk(chunk, directions, weight, observed, light, diffuse_scale, sigma, fresnel,
                             masking, split_sum, exact_dielectric, burley, table, table_rows,
                             roughness_grid, metallic_grid, robust_passes, lmax, diag, rec_a, rec_b, tangent, normal,
                             environment, environment_blend, response, quadrature, quadrature_projection,
                             burley_response, prefiltered, n_full, world_to_local, map_height, map_width,
                             hypothesis_roughness, hypothesis_moments, node_rows, search, candidate,
                             params, loss, curvature)


@numba.njit(cache=True)
def scattering_stride(n_items):
    """A stride coprime to n_items near the golden section of it: item i -> (i stride) mod n_items
    visits every item once and spreads any contiguous run of i over the whole range."""
    stride = max(int(n_items * 0.6180339887), 1)
    while math.gcd(stride, n_items) != 1:
        stride += 1
    return np.int64(stride)


@numba.njit(fastmath=True, cache=True)
def _global_search_chunk(
    chunk, directions, weight, observed, light, diffuse_scale, sigma, fresnel, masking, split_sum,
    exact_dielectric, burley, table, table_rows, roughness_grid, metallic_grid, robust_passes, lmax,
    diag, rec_a, rec_b, tangent, normal, environment, environment_blend, response, quadrature,
    quadrature_projection, burley_response, prefiltered, n_full, world_to_local, map_height,
    map_width, hypothesis_roughness, hypothesis_moments, node_rows, search, candidate, params, loss,
    curvature,
):
    """`_global_search_kernel`'s work for the texels of one chunk: a function of its own, so that
    numba's parallel passes see a small loop (on the whole body they took much of the kernel's
    compile time)."""
    n_texels, n_views = weight.shape
    n_degrees = lmax + 1
    n_coeffs = n_degrees * n_degrees
    # The texel's samples with w > 0, packed and with the views innermost (vectorised loops).
    xyz = np.empty((3, n_views))
    unit = np.empty((3, n_views))
    basis = np.empty((n_coeffs, n_views))
    sh_scratch = np.empty((5, n_views))
    packed_cos = np.empty(n_views)
    omega = np.empty(n_views)  # w^2
    packed_proj = np.empty((3, n_degrees, n_views))
    values = np.empty((3, n_views))
    table_row = np.empty(n_views, dtype=np.int64)
    table_frac = np.empty(n_views)
    burley_terms = np.empty((3, 3, n_views))  # per channel, power of r and sample
    diffuse_moments = np.empty((3, 2, 5))  # per channel: sum w^2 D^2 (quartic in r), sum w^2 f D (quadratic)
    column = np.empty((table.shape[0], table.shape[1]))
    albedo = np.empty((3, n_views))  # A, B, E
    diffuse_factor = np.empty((3, n_views))
    own_filtered = np.empty(n_views)  # the lobe's own light of one channel
    filtered = np.empty((3, 3, n_views))  # per channel X, Y, Z
    sample_weight = np.empty(n_views)  # w
    residual = np.empty(n_views)
    kernel = np.empty(n_degrees)
    kernel_derivative = np.empty(n_degrees)
    moments = np.empty((3, 14))  # `_metallic_quadratics`' weighted sums
    quadratics = np.empty((3, 3, 3))
    squared_values = np.empty(3)  # sum_v w^2 f^2 per channel
    scale = np.empty(3)
    state = np.empty(4)
    best_state = np.empty(4)
    roughness_brent = np.empty(13)
    node_loss = np.empty(roughness_grid)
    # The hypotheses the first scan records: the others are probed before the search.
    scanned = np.zeros(hypothesis_roughness.shape[0], dtype=np.bool_)
    for node in range(node_rows.shape[0]):
        if node_rows[node] >= 0:
            scanned[node_rows[node]] = True
    no_rows = np.full(0, -1, dtype=np.int64)
    no_moments = np.zeros((0, 3, 8))
    # The environment in the texel's frame, then in each sample's mirrored view frame.
    n_points = quadrature.shape[0]
    local_environment = np.empty((environment.shape[0], 3))
    quadrature_world = np.empty((3, n_points))
    quadrature_basis = np.empty((environment.shape[0], n_points))
    quadrature_scratch = np.empty((5, n_points))
    quadrature_values = np.empty((3, n_points))
    n_environment_degrees = n_sh_degrees(environment.shape[0])
    azimuthal = np.zeros((n_views, 3, n_environment_degrees * (n_environment_degrees + 1) // 2))
    # The environment light per roughness node, lobe term, channel and sample.
    environment_nodes = np.empty((ENVIRONMENT_NODES, 3, 3, n_views))
    environment_cached = np.zeros(ENVIRONMENT_NODES, dtype=np.bool_)
    bitangent = np.empty(3)
    # The prefiltered light per map node, channel and sample, and each sample's lookup stencil.
    n_prefiltered = prefiltered.shape[1]
    prefiltered_nodes = np.empty((n_prefiltered, 3, n_views))
    prefiltered_cached = np.zeros(n_prefiltered, dtype=np.bool_)
    corner = np.empty((4, n_views), dtype=np.int64)
    stencil_frac = np.empty((2, n_views))
    high_filtered = np.empty(n_views)
    for t in range(chunk * _SEARCH_CHUNK, min((chunk + 1) * _SEARCH_CHUNK, n_texels)):
        # np.int64, np.bool_ and below: a literal constant where a variable goes (here into args)
        # makes numba compile the callee once more for the literal's type.
        n = np.int64(0)
        for v in range(n_views):
            w = np.float64(weight[t, v])
            if w <= 0.0:
                continue
            for axis in range(3):
                xyz[axis, n] = directions[t, v, axis]
            packed_cos[n] = xyz[2, n]
            omega[n] = w * w
            sample_weight[n] = w
            for c in range(3):
                values[c, n] = observed[t, v, c]
            n += 1
        if n < MIN_SAMPLES:
            continue
        # The neighbour vote (below) concerns only texels whose candidate roughness or metallic
        # lies more than a grid cell away: the others skip the preparation too.
        voting = candidate.shape[0] > 0
        far_roughness = voting and abs(candidate[t, 0] - params[t, 3]) * (roughness_grid - 1) > 1.0
        far_metallic = voting and abs(candidate[t, 1] - params[t, 4]) * (metallic_grid - 1) > 1.0
        if voting and not ((far_roughness or far_metallic) and 3 * n > FITTED_PARAMETERS):
            continue
        cross(normal[t], tangent[t], bitangent)
        prefiltered_cached[:] = False
        if n_full > 0:
            mirror_stencil(xyz, n, tangent[t], normal[t], bitangent, world_to_local, map_height, map_width,
                            corner, stencil_frac)
        if n_full == 0:  # the fitted light, expanded by degree at the (normalised) view directions
            for s in range(n):
                norm = math.sqrt(xyz[0, s] ** 2 + xyz[1, s] ** 2 + xyz[2, s] ** 2)
                for axis in range(3):
                    unit[axis, s] = xyz[axis, s] / norm
            sh._sh_block(unit[0], unit[1], unit[2], n, lmax, diag, rec_a, rec_b, basis, sh_scratch)
            for c in range(3):
                for degree in range(n_degrees):
                    for s in range(n):
                        packed_proj[c, degree, s] = 0.0
                    for k in range(degree * degree, (degree + 1) * (degree + 1)):
                        coefficient = np.float64(light[t, c, k])
                        for s in range(n):
                            packed_proj[c, degree, s] += coefficient * basis[k, s]
        environment_cached[:] = False
        if environment.shape[0] > 0:
            texel_environment(environment, tangent[t], normal[t], bitangent, quadrature, quadrature_projection,
                               diag, rec_a, rec_b, quadrature_world, quadrature_basis, quadrature_scratch,
                               quadrature_values, local_environment)
            azimuthal_coefficients(xyz, n, local_environment, azimuthal)
        for s in range(n):
            x = min(max(packed_cos[s], 0.0), 1.0) * (table.shape[1] - 1)
            table_row[s] = min(int(x), table.shape[1] - 2)
            table_frac[s] = x - table_row[s]
            uniform_burley_terms(packed_cos[s], burley, burley_terms[:, :, s])
        if burley and burley_response.shape[2] > 0 and environment.shape[0] > 0:
            environment_burley_terms(n, table_row, table_frac, azimuthal, burley_response, burley_terms)
        total_weight = _weighted_sums(n, omega, values, burley_terms, diffuse_moments, squared_values)
        for c in range(3):
            scale[c] = diffuse_scale[t, c]
        args = (n, packed_cos, omega, packed_proj, values, sigma, fresnel, masking, split_sum, exact_dielectric,
                burley, table, table_row, table_frac, burley_terms, diffuse_moments, column,
                kernel, kernel_derivative, albedo, diffuse_factor, own_filtered, filtered, moments, quadratics,
                squared_values, scale, state, metallic_grid, azimuthal, environment_blend, environment_nodes,
                environment_cached, response, prefiltered, n_full, corner, stencil_frac,
                prefiltered_nodes, prefiltered_cached, high_filtered, table_rows)
        for i in range(hypothesis_roughness.shape[0]):
            if not scanned[i]:
                _roughness_objective(hypothesis_roughness[i], args)
                _record_hypothesis(args, sample_weight, hypothesis_moments[t, i])
        if voting:
            # The neighbour vote. A likelihood-ratio test bounds what it may cost: the profiled
            # least-squares loss may exceed the estimate's by _VOTE_CHI2 times the noise variance
            # (the residual over its 3n - FITTED_PARAMETERS degrees of freedom). Roughness: a
            # local minimum within a grid cell of the candidate (Brent, not at its bounds, over a
            # cell from the estimate: another minimum). Then metallic: the candidate's, base
            # colour profiled, at the roughness kept.
            estimate_r = params[t, 3]
            estimate_f = _roughness_objective(estimate_r, args)
            limit = estimate_f + _VOTE_CHI2 * estimate_f / (3 * n - FITTED_PARAMETERS)
            voted_r = estimate_r
            if far_roughness:
                cell = 1.0 / (roughness_grid - 1)
                lower, upper = max(candidate[t, 0] - cell, 0.0), min(candidate[t, 0] + cell, 1.0)
                _brent_start(roughness_brent, lower, upper, _BRENT_XTOL)
                local_r, local_f = _brent_run(args, state, best_state, roughness_brent, 0.0, np.inf,
                                              np.bool_(True))
                margin = _VOTE_MARGIN * cell
                interior = ((local_r - lower > margin or lower == 0.0)
                            and (upper - local_r > margin or upper == 1.0))
                if interior and abs(local_r - estimate_r) > cell and local_f <= limit:
                    voted_r = local_r
            profiled_f = _roughness_objective(voted_r, args)  # state: its base colour, metallic
            voted_f = profiled_f
            metallic_voted = False
            if abs(candidate[t, 1] - state[3]) * (metallic_grid - 1) > 1.0:
                # Into best_state, so that state keeps the profiled fit if the test refuses it.
                fixed_f = _metallic_terms(candidate[t, 1], quadratics, best_state)[0]
                if fixed_f <= limit:
                    voted_f = fixed_f
                    _keep_state(best_state, state)
                    metallic_voted = True
            if voted_r == estimate_r and not metallic_voted:
                continue  # the estimate stands
            params[t, 0], params[t, 1], params[t, 2] = state[0], state[1], state[2]
            params[t, 3], params[t, 4] = voted_r, state[3]
            loss[t] = max(voted_f, 0.0) / total_weight
            curvature[t] = _loss_curvature(voted_r, profiled_f, args) / total_weight
            continue
        if not search:
            continue
        # A robust pass refines the roughness to _BRENT_XTOL: this search need only find its cell.
        first_xtol = _BRENT_COARSE_XTOL if robust_passes > 0 else _BRENT_XTOL
        best_r, best_f = _search_roughness(args, state, roughness_grid, best_state, roughness_brent, node_loss,
                                           np.int64(0), roughness_grid - 1, first_xtol, node_rows,
                                           hypothesis_moments[t] if node_rows.shape[0] > 0 else no_moments,
                                           sample_weight)
        if robust_passes > 0:
            # Towards the paper's L1 loss sum_v w |r_v| (IRLS): weight each sample by
            # w / max(|r|, delta), delta a tenth of the texel's mean |r| so that near-exact
            # samples do not take over, and search again.
            for _ in range(robust_passes):
                best_f = _roughness_objective(best_r, args)
                best_state[:] = state
                _residual_magnitudes(n, values, filtered, diffuse_factor, scale, best_state, residual)
                weighted_residual = weight_sum = 0.0
                for s in range(n):
                    weighted_residual += sample_weight[s] * residual[s]
                    weight_sum += sample_weight[s]
                floor = 0.1 * weighted_residual / weight_sum
                if not floor > 0.0:
                    break  # an exact fit: nothing to re-weight
                for s in range(n):
                    omega[s] = sample_weight[s] / max(residual[s], floor)
                _weighted_sums(n, omega, values, burley_terms, diffuse_moments, squared_values)
                # Re-weighting moves the optimum locally: scan the nodes within one cell of it.
                node = int(round(best_r * (roughness_grid - 1)))
                best_r, best_f = _search_roughness(args, state, roughness_grid, best_state, roughness_brent,
                                                   node_loss, max(node - _ROBUST_NODES, 0),
                                                   min(node + _ROBUST_NODES, roughness_grid - 1), _BRENT_XTOL,
                                                   no_rows, no_moments, sample_weight)
            for s in range(n):  # back to least squares for the curvature
                omega[s] = sample_weight[s] * sample_weight[s]
            _weighted_sums(n, omega, values, burley_terms, diffuse_moments, squared_values)
            # The profiled least-squares loss at the optimum for the curvature (the robust
            # pass's best_f is not profiled). The model terms this probe leaves in filtered do
            # not depend on the weights, so they also give the reported loss: the weighted
            # squared residual of the robust estimate (best_state), `MaterialEstimate.loss`.
            centre_f = _roughness_objective(best_r, args)
            _residual_magnitudes(n, values, filtered, diffuse_factor, scale, best_state, residual)
            best_f = 0.0
            for s in range(n):
                best_f += sample_weight[s] * sample_weight[s] * residual[s] * residual[s]
        else:
            centre_f = best_f
        curvature[t] = _loss_curvature(best_r, centre_f, args) / total_weight
        params[t, 0], params[t, 1], params[t, 2] = best_state[0], best_state[1], best_state[2]
        params[t, 3], params[t, 4] = best_r, best_state[3]
        loss[t] = max(best_f, 0.0) / total_weight


# ---------------------------------------------------------------------------------------------
# paper: the prototype's Adam


def _estimate_paper(observations: Observations, config: Config, reporter: Reporter) -> MaterialEstimate:
    settings = config.estimate
    timings = {"light": 0.0, "iterations": 0.0}
    n_texels = observations.n_texels
    estimated = observations.n_samples > 0
    params = np.empty((n_texels, 5))  # base colour RGB, roughness, metallic
    params[:, :3] = settings.init_base_color
    params[:, 3] = settings.init_roughness
    params[:, 4] = settings.init_metallic
    first_moment = np.zeros_like(params)
    second_moment = np.zeros_like(params)
    neighbours = _texture_neighbours(observations.texture_res, observations.texel_index, estimated)
    # The prototype's losses are means over the whole T x T texture (observed or not).
    texture_texels = observations.texture_res**2
    light = observations.mirrored_coeffs
    target = observations.observed_coeffs
    proj = None
    tick = time.perf_counter()
    if settings.forward_model == "angular":
        proj = degree_projections(observations.view_direction, observations.weight, light, observations.lmax)
    timings["light"] += time.perf_counter() - tick

    with reporter.stage("estimating (paper)", settings.iterations) as advance:
        for iteration in range(settings.iterations):
            # The prototype refreshes shadowing/masking before iterations 49, 99, ... (it + 1 = 50 k).
            if (settings.shadowing or settings.masking) and (iteration + 1) % settings.shadowing_refresh_every == 0:
                tick = time.perf_counter()
                light, target, proj = _refresh(observations, config, params, light, target, proj)
                timings["light"] += time.perf_counter() - tick
            tick = time.perf_counter()
            gradient = _data_gradient(observations, settings, params, light, target, proj, texture_texels)
            gradient += _tv_gradient(params, neighbours, settings.tv_weight / (9.0 * texture_texels))
            _adam_step(params, gradient, first_moment, second_moment, iteration + 1, settings.learning_rate)
            timings["iterations"] += time.perf_counter() - tick
            advance(1)

    tick = time.perf_counter()
    loss = angular_loss(observations, _principled(params), config, light)
    timings["loss"] = time.perf_counter() - tick
    timings["total"] = sum(timings.values())
    return _result(observations, params, np.nan_to_num(loss), estimated, f"paper/{settings.forward_model}", timings)


def _principled(params: np.ndarray) -> brdf.PrincipledParams:
    return brdf.PrincipledParams(base_color=params[:, :3], roughness=params[:, 3], metallic=params[:, 4])


def _refresh(observations, config, params, light, target, proj):
    """Re-fit the light shadowed at the current roughness (and, for the spectral models, the
    observations with the masking divided out), as the prototype does every 50 iterations."""
    settings = config.estimate
    alpha = brdf.alpha_from_roughness(params[:, 3])
    if settings.shadowing:
        light = _shadowed_light_coeffs(observations, alpha, config.fit)
        if settings.forward_model == "angular":
            proj = degree_projections(observations.view_direction, observations.weight, light, observations.lmax)
    if settings.masking and settings.forward_model != "angular":
        g1 = brdf.smith_g1_ggx(observations.view_direction[..., 2], alpha[:, None])  # (N, V)
        unmasked = observations.observed / np.maximum(g1, np.finfo(np.float32).tiny)[..., None]
        fit = config.fit
        target = sh.fit_sh(
            observations.view_direction, observations.weight, unmasked.astype(np.float32), observations.lmax,
            fit.reg_lambda, fit.regulariser, fit.scale_lambda_with_weight,
        ).coeffs
    return light, target, proj


def _data_gradient(observations, settings, params, light, target, proj, texture_texels) -> np.ndarray:
    """(N, 5) gradient of the prototype's mean L1 loss for the chosen forward model."""
    mf = brdf.microfacet_from_principled(_principled(params))
    lmax, sigma = observations.lmax, observations.sigma
    diffuse_scale = _diffuse_scale(observations)  # (N, 3)
    n_texels = observations.n_texels
    if settings.forward_model == "angular":
        grad_r0, grad_diffuse, grad_alpha = np.zeros((n_texels, 3)), np.zeros((n_texels, 3)), np.zeros(n_texels)
        _angular_l1_gradient_kernel(
            proj, observations.view_direction[..., 2], observations.weight, observations.observed, diffuse_scale,
            mf.specular_r0, mf.diffuse_albedo, mf.alpha, sigma, settings.fresnel, settings.masking,
            grad_r0, grad_diffuse, grad_alpha,
        )
        count = texture_texels * observations.n_views * 3
    else:
        constant = observations.constant_coeffs.astype(np.float64)  # (N, K)
        kernel = brdf.brdf_kernel(mf.alpha, lmax, sigma)  # (N, l*+1)
        degrees = np.arange(lmax + 1)
        kernel_derivative = -2.0 * mf.alpha[:, None] * degrees**2 * kernel  # d kernel / d alpha
        r0 = mf.specular_r0[:, :, None]  # (N, 3, 1)
        if settings.forward_model == "sh_coeffs":
            predicted = brdf.predict_sh_coeffs(mf, light, observations.irradiance, constant, sigma=sigma)
            sign = np.sign(predicted - target)  # (N, 3, K)
            per_coeff = sh.sh_degrees(lmax)
            grad_r0 = np.sum(sign * kernel[:, None, per_coeff] * light, axis=2)
            grad_diffuse = np.sum(sign * constant[:, None, :], axis=2) * diffuse_scale
            grad_alpha = np.sum(sign * r0 * kernel_derivative[:, None, per_coeff] * light, axis=(1, 2))
            count = texture_texels * 3 * sh.num_coeffs(lmax)
        else:
            light_spectrum = sh.power_spectrum(light)  # (N, 3, l*+1)
            predicted = brdf.predict_power_spectrum(
                mf, light_spectrum, observations.irradiance, constant, sigma=sigma
            )
            sign = np.sign(predicted - sh.power_spectrum(target))
            # l >= 1: S = R0^2 k^2 S_refl.  l = 0: S = a^2, a = R0 k0 sqrt(S_refl(0)) + d E/pi u_00.
            grad_r0 = np.sum(sign[..., 1:] * 2.0 * r0 * kernel[:, None, 1:] ** 2 * light_spectrum[..., 1:], axis=2)
            grad_alpha = np.sum(
                sign[..., 1:] * r0**2 * 2.0 * kernel[:, None, 1:] * kernel_derivative[:, None, 1:]
                * light_spectrum[..., 1:], axis=(1, 2),
            )
            dc_light = np.sqrt(light_spectrum[..., 0])  # (N, 3)
            amplitude = mf.specular_r0 * kernel[:, :1] * dc_light + mf.diffuse_albedo * diffuse_scale * constant[:, :1]
            grad_r0 += sign[..., 0] * 2.0 * amplitude * kernel[:, :1] * dc_light
            grad_diffuse = sign[..., 0] * 2.0 * amplitude * diffuse_scale * constant[:, :1]
            count = texture_texels * 3 * (lmax + 1)
    return _chain_to_principled(grad_r0, grad_diffuse, grad_alpha, params) / count


def _chain_to_principled(grad_r0, grad_diffuse, grad_alpha, params) -> np.ndarray:
    """Gradients in (R0 (N, 3), d (N, 3), alpha (N,)) to (base colour, roughness, metallic) (N, 5).

    R0 = 0.04 + (b - 0.04) m, d = (1 - m) b, alpha = max(r^2, ALPHA_MIN) (no gradient when clamped,
    as torch's clamp)."""
    base, roughness, metallic = params[:, :3], params[:, 3], params[:, 4]
    gradient = np.empty_like(params)
    gradient[:, :3] = grad_r0 * metallic[:, None] + grad_diffuse * (1.0 - metallic[:, None])
    gradient[:, 3] = grad_alpha * np.where(roughness**2 > brdf.ALPHA_MIN, 2.0 * roughness, 0.0)
    gradient[:, 4] = np.sum(grad_r0 * (base - brdf.DIELECTRIC_F0) - grad_diffuse * base, axis=1)
    return gradient


@numba.njit(parallel=True, fastmath=True, cache=True)
def _angular_l1_gradient_kernel(
    proj, cos_theta, weight, observed, diffuse_scale, r0, diffuse, alpha, sigma, fresnel, masking,
    grad_r0, grad_diffuse, grad_alpha,
):
    """Gradient of sum_v,c |w (L - f)| in R0, d and alpha per texel (accumulated into the grads)."""
    n_texels, n_views = weight.shape
    n_degrees = proj.shape[2]
    for t in numba.prange(n_texels):
        kernel = np.empty(n_degrees)
        kernel_derivative = np.empty(n_degrees)
        fill_kernel(alpha[t], sigma, kernel, kernel_derivative)
        for v in range(n_views):
            w = np.float64(weight[t, v])
            if w <= 0.0:
                continue
            cos_v = np.float64(cos_theta[t, v])
            g1, g1_derivative = g1_and_derivative(cos_v, alpha[t]) if masking else (1.0, 0.0)
            schlick = (1.0 - cos_v) ** 5 if fresnel else 0.0
            for c in range(3):
                filtered = 0.0
                filtered_derivative = 0.0
                for degree in range(n_degrees):
                    filtered += kernel[degree] * proj[t, c, degree, v]
                    filtered_derivative += kernel_derivative[degree] * proj[t, c, degree, v]
                fresnel_c = r0[t, c] + (1.0 - r0[t, c]) * schlick
                residual = fresnel_c * g1 * filtered + diffuse[t, c] * diffuse_scale[t, c] - observed[t, v, c]
                sign_w = w if residual > 0.0 else (-w if residual < 0.0 else 0.0)
                grad_r0[t, c] += sign_w * (1.0 - schlick) * g1 * filtered
                grad_diffuse[t, c] += sign_w * diffuse_scale[t, c]
                grad_alpha[t] += sign_w * fresnel_c * (g1_derivative * filtered + g1 * filtered_derivative)


def _texture_neighbours(texture_res: int, texel_index: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(N, 8) indices of each masked texel's masked 8-neighbours in the texture, -1 where none."""
    lookup = np.full(texture_res * texture_res, -1, dtype=np.int64)
    lookup[texel_index[mask]] = np.flatnonzero(mask)
    row, col = np.divmod(texel_index, texture_res)
    neighbours = np.full((len(texel_index), len(_NEIGHBOUR_OFFSETS)), -1, dtype=np.int64)
    for k, (d_row, d_col) in enumerate(_NEIGHBOUR_OFFSETS):
        r, c = row + d_row, col + d_col
        inside = mask & (r >= 0) & (r < texture_res) & (c >= 0) & (c < texture_res)
        neighbours[inside, k] = lookup[r[inside] * texture_res + c[inside]]
    return neighbours


def _tv_gradient(params: np.ndarray, neighbours: np.ndarray, coefficient: float) -> np.ndarray:
    """Gradient of coefficient * sum_x sum_(y in N8(x)) sum_p |params_y,p - params_x,p|.

    This is the prototype's masked 3 x 3 L1 total variation averaged over 9 T^2 stencil entries
    (coefficient = weight / (9 T^2)); each pair appears from both ends, hence the 2.
    """
    gradient = np.zeros_like(params)
    for k in range(neighbours.shape[1]):
        has = neighbours[:, k] >= 0
        gradient[has] += 2.0 * coefficient * np.sign(params[has] - params[neighbours[has, k]])
    return gradient


def _adam_step(params, gradient, first_moment, second_moment, step: int, learning_rate: float) -> None:
    """torch.optim.Adam's update (in place), then the prototype's clamps: |r|, all into [0, 1]."""
    first_moment *= _ADAM_BETA1
    first_moment += (1.0 - _ADAM_BETA1) * gradient
    second_moment *= _ADAM_BETA2
    second_moment += (1.0 - _ADAM_BETA2) * gradient**2
    denominator = np.sqrt(second_moment) / math.sqrt(1.0 - _ADAM_BETA2**step) + _ADAM_EPS
    params -= learning_rate / (1.0 - _ADAM_BETA1**step) * first_moment / denominator
    params[:, 3] = np.abs(params[:, 3])
    np.clip(params, 0.0, 1.0, out=params)
