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

import functools
import hashlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from freqbrdf import texels
from freqbrdf.config import Config, EstimateConfig, FitConfig
from freqbrdf.errors import InputError
from freqbrdf.model import brdf
from freqbrdf.observe.observations import Observations
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.sphere import envmap as envmaps
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
# The search's inner functions run ~30 times per texel and take ~40 arrays each. Compiled with
# numba's runtime on, each call counted a reference to every array it took (an atomic add on entry
# and exit, ~1 us per probe, as long as the probe's arithmetic at 40 samples). They allocate
# nothing and their callers hold the arrays, so they are compiled without it.
_borrowing_jit = numba.njit(fastmath=True, cache=True, _nrt=False)
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
_DIELECTRIC_F0 = brdf.DIELECTRIC_F0  # module constants, bound here for the numba kernels
_ALPHA_MIN = brdf.ALPHA_MIN
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
                  _mirror_projections(observations.view_direction[rows], observations.weight[rows], light[rows],
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
        _uses_burley(settings), split_sum_table(), _split_sum_rows(), settings.roughness_grid,
        settings.metallic_grid, settings.robust_passes, observations.lmax, *sh._legendre_tables(observations.lmax),
        tangent, normal, environment, blend, environment_response_table(),
        *_environment_quadrature(max(math.isqrt(len(environment)) - 1, 0)), _burley_response(settings),
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


# The split-sum table: nodes uniform in cos(theta_o) and in roughness, and the stratified
# quadrature over GGX-distributed half vectors that fills it (accurate to ~1e-3 except at the
# grazing, near-mirror corner, where cos-weighted samples count little).
_TABLE_COS_NODES = 33
_TABLE_ROUGHNESS_NODES = 33
_TABLE_THETA_STRATA = 64
_TABLE_PHI_STRATA = 32


@functools.cache
def split_sum_table() -> np.ndarray:
    """(3, cos nodes, roughness nodes) float64: `integrate_split_sum_table`, shipped in
    data/split_sum.csv (the three tables stacked by rows, every digit kept;
    scripts/make_split_sum_table.py): integrating it took 0.1-0.4 s of every process's first fit."""
    table = np.loadtxt(_SPLIT_SUM_TABLE_PATH, delimiter=",", ndmin=2)
    shape = (3 * _TABLE_COS_NODES, _TABLE_ROUGHNESS_NODES)
    if table.shape != shape or not np.all((table >= 0.0) & (table <= 1.01)):
        raise InputError(_SPLIT_SUM_TABLE_PATH, f"expected a {shape[0]} x {shape[1]} table of albedos in [0, 1], "
                                                f"got shape {table.shape}; regenerate it with "
                                                "scripts/make_split_sum_table.py")
    return table.reshape(3, _TABLE_COS_NODES, _TABLE_ROUGHNESS_NODES)


def integrate_split_sum_table() -> np.ndarray:
    """(3, cos nodes, roughness nodes) float64: A, B and E of the GGX lobe's directional albedo.

    For view cosine mu_o and roughness r (alpha = r^2), with Schlick weight F_c = (1 - o.h)^5,
        A = int f/F (1 - F_c) cos_i dw_i,   B = int f/F F_c cos_i dw_i,   f = F D G1(i) G1(o) / (4 mu_i mu_o),
    so a lobe of normal reflectance R0 with Schlick's Fresnel (the metallic part of Mitsuba's
    ``principled``) under uniform unit light returns R0 A + B, and
        E = int f/F F_eta(o.h) cos_i dw_i
    with the exact dielectric Fresnel F_eta of eta = `dielectric_eta` (its dielectric part). E is
    10-27 % above Schlick's 0.04 A + B at view cosines 0.3-0.8. Importance sampling the half
    vector by D (pdf D cos_h, dw_i = 4 (o.h) dw_h) leaves the integrand
    G1(i) G1(o) (o.h) / (mu_o cos_h); light reflected below the horizon is lost.
    """
    cos_view = np.maximum(np.linspace(0.0, 1.0, _TABLE_COS_NODES), 1e-4)[:, None, None, None]
    alpha = brdf.alpha_from_roughness(np.linspace(0.0, 1.0, _TABLE_ROUGHNESS_NODES))[None, :, None, None]
    u = (np.arange(_TABLE_THETA_STRATA) + 0.5) / _TABLE_THETA_STRATA  # GGX: tan^2 theta_h = alpha^2 u / (1 - u)
    phi = (np.arange(_TABLE_PHI_STRATA) + 0.5) / _TABLE_PHI_STRATA * np.pi  # symmetric about the view plane
    cos_half = 1.0 / np.sqrt(1.0 + alpha**2 * (u / (1.0 - u))[:, None])
    half_x = np.sqrt(1.0 - cos_half**2) * np.cos(phi)
    view_dot_half = np.sqrt(1.0 - cos_view**2) * half_x + cos_view * cos_half
    cos_light = 2.0 * view_dot_half * cos_half - cos_view
    integrand = np.where(
        cos_light > 0.0,
        brdf.smith_g1_ggx(cos_light, alpha) * brdf.smith_g1_ggx(cos_view, alpha) * np.maximum(view_dot_half, 0.0)
        / (cos_view * cos_half),
        0.0,
    )
    cos_incidence = np.clip(view_dot_half, 0.0, 1.0)
    schlick = (1.0 - cos_incidence) ** 5
    weights = (1.0 - schlick, schlick, dielectric_fresnel(cos_incidence))
    return np.stack([np.mean(integrand * weight, axis=(2, 3)) for weight in weights])


def dielectric_eta() -> float:
    """The relative index of refraction whose normal reflectance is brdf.DIELECTRIC_F0 (1.5)."""
    root = math.sqrt(brdf.DIELECTRIC_F0)
    return (1.0 + root) / (1.0 - root)


def dielectric_fresnel(cos_theta: np.ndarray) -> np.ndarray:
    """The exact unpolarised Fresnel reflectance of a dielectric of eta `dielectric_eta`, light
    arriving from outside at cos_theta in [0, 1] to the (micro)surface normal."""
    cos_theta = np.asarray(cos_theta, dtype=np.float64)
    eta = dielectric_eta()
    g = np.sqrt(eta * eta - 1.0 + cos_theta * cos_theta)
    perpendicular = (g - cos_theta) / (g + cos_theta)
    ratio = (cos_theta * (g + cos_theta) - 1.0) / np.maximum(cos_theta * (g - cos_theta) + 1.0, 1e-300)
    return 0.5 * perpendicular**2 * (1.0 + ratio**2)


def split_sum_terms(cos_theta: np.ndarray, roughness: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, E) of `split_sum_table`, bilinear, for broadcastable cos_theta and roughness in [0, 1]."""
    cos_theta, roughness = np.broadcast_arrays(np.asarray(cos_theta, np.float64), np.asarray(roughness, np.float64))
    terms = np.empty((3, cos_theta.size))
    _table_terms_kernel(cos_theta.ravel(), roughness.ravel(), split_sum_table(), terms)
    return tuple(term.reshape(cos_theta.shape) for term in terms)


_SPLIT_SUM_TABLE_PATH = Path(__file__).resolve().parents[1] / "model" / "data" / "split_sum.csv"
_ENVIRONMENT_LMAX = 5  # the default l*: the degrees of the environment light (`environment_response_table`)
_RESPONSE_STRATA = 64  # strata of the half vector's polar and azimuthal angle each (`lobe_sh_response`)


# The terms of the split-sum specular, each with its own Fresnel weight over the lobe and so its
# own response to the light: A (1 - F_c), B (F_c, Schlick's weight) and E (the exact dielectric Fresnel).
LOBE_TERMS = ("scale", "bias", "dielectric")


def table_nodes() -> tuple[np.ndarray, np.ndarray]:
    """The (cos theta_o, roughness) nodes of `split_sum_table`."""
    return np.linspace(0.0, 1.0, _TABLE_COS_NODES), np.linspace(0.0, 1.0, _TABLE_ROUGHNESS_NODES)


def lobe_sh_response(cos_theta: float, roughness: float, term: str = "scale", lmax: int = _ENVIRONMENT_LMAX,
                     strata: int = _RESPONSE_STRATA) -> tuple[float, np.ndarray, np.ndarray]:
    """(albedo, responses (K,), view (3,)): the GGX lobe seen from view = (sin, 0, cos theta_o),
    masking-shadowing included and weighted by the ``term``'s Fresnel factor (`LOBE_TERMS`), its
    albedo int f cos_i dw_i and its response int Y_lm(mirror(w_i)) f cos_i dw_i to each real SH
    in the mirrored parameterisation; stratified over GGX half vectors (strata x strata) as
    `split_sum_table`. Deterministic."""
    if term not in LOBE_TERMS:
        raise ValueError(f"unknown lobe term {term!r}; choose one of {LOBE_TERMS}")
    cos_theta = max(float(cos_theta), 1e-4)
    alpha = float(brdf.alpha_from_roughness(np.array(roughness)))
    u = (np.arange(strata) + 0.5) / strata
    phi = (np.arange(strata) + 0.5) / strata * 2.0 * np.pi
    cos_half = np.repeat(1.0 / np.sqrt(1.0 + alpha**2 * u / (1.0 - u)), strata)
    sin_half = np.sqrt(1.0 - cos_half**2)
    half = np.stack([sin_half * np.tile(np.cos(phi), strata), sin_half * np.tile(np.sin(phi), strata), cos_half],
                    axis=-1)
    view = np.array([math.sqrt(1.0 - cos_theta**2), 0.0, cos_theta])
    view_dot_half = half @ view
    light = 2.0 * view_dot_half[:, None] * half - view
    cos_incidence = np.clip(view_dot_half, 0.0, 1.0)
    fresnel = {"scale": 1.0 - (1.0 - cos_incidence) ** 5, "bias": (1.0 - cos_incidence) ** 5,
               "dielectric": dielectric_fresnel(cos_incidence)}[term]
    lobe = np.where(
        (light[:, 2] > 0.0) & (view_dot_half > 0.0),
        brdf.smith_g1_ggx(np.maximum(light[:, 2], 1e-12), alpha) * brdf.smith_g1_ggx(cos_theta, alpha)
        * np.maximum(view_dot_half, 0.0) / (cos_theta * cos_half) * fresnel,
        0.0,
    )
    responses = np.mean(lobe[:, None] * sh.eval_sh(light * np.array([-1.0, -1.0, 1.0]), lmax), axis=0)
    return float(np.mean(lobe)), responses, view


# With the environment light (`EstimateConfig.environment_light`), a rough lobe reads the
# environment's own SH (degrees up to `_ENVIRONMENT_LMAX`, unoccluded) through the lobe's exact response
# to each harmonic: per (cos theta_o, roughness) node and lobe term, the response to Y_lm (m >= 0) in
# a frame whose x axis is the mirrored view's azimuth (`environment_response_table`). Per texel the
# environment is turned into the texel's frame once, per sample into its view's azimuth.
_ENVIRONMENT_TABLE_PATH = Path(__file__).resolve().parents[1] / "model" / "data" / "environment_response.csv"
# The environment light is tabulated at every _ENVIRONMENT_NODE_STEP-th roughness node of the
# split-sum table and interpolated linearly in roughness between them: each is computed once per
# texel and search.
_ENVIRONMENT_NODE_STEP = 2
_ENVIRONMENT_NODES = (_TABLE_ROUGHNESS_NODES - 1) // _ENVIRONMENT_NODE_STEP + 1


def environment_pairs(lmax: int) -> int:
    """How many (l, m >= 0) harmonics up to degree lmax: their order is l, then m."""
    return (lmax + 1) * (lmax + 2) // 2


def environment_response(cos_theta: float, roughness: float, term: str = "scale",
                         lmax: int = _ENVIRONMENT_LMAX) -> np.ndarray:
    """((lmax + 1)(lmax + 2) / 2,) the ``term``'s lobe response to each real SH Y_lm with m >= 0
    (order: l, then m), relative to its albedo, for the view (sin, 0, cos theta_o), in the mirrored
    parameterisation (`lobe_sh_response`). The lobe is symmetric about its plane of incidence, so
    its response to the harmonics with m < 0 (sin m phi) is zero; a light L = sum c_lm Y_lm in the
    frame turned so that the mirrored view lies at azimuth 0 reflects sum c_lm R_lm times the albedo."""
    albedo, responses, _ = lobe_sh_response(cos_theta, roughness, term, lmax)
    pairs = [degree * degree + degree + order for degree in range(lmax + 1) for order in range(degree + 1)]
    # A lobe of no albedo (Schlick's F_c at normal incidence on a mirror) reflects nothing anyway.
    return responses[pairs] / albedo if albedo > 0.0 else np.zeros(len(pairs))


@functools.cache
def environment_response_table() -> np.ndarray:
    """(3, roughness nodes, cos nodes, 21) float64: per `LOBE_TERMS` term, `environment_response`
    (l* = 5) at every `_ENVIRONMENT_NODE_STEP`-th roughness node and every cos theta_o node of
    `split_sum_table`.

    It replaces a zonal approximation (one tilted lookup direction and a gain per degree, fitted to
    these responses), which at grazing views under the demo's forest map predicted a rough
    dielectric's specular (r = 0.86) 0.79 of Mitsuba's (this table: 1.00, benchmarks/model_fidelity.py).
    Shipped in data/environment_response.csv (rows: term, then roughness node, then cos theta_o;
    columns: the harmonics; scripts/make_environment_response_table.py).
    """
    table = np.loadtxt(_ENVIRONMENT_TABLE_PATH, delimiter=",", ndmin=2)
    pairs = environment_pairs(_ENVIRONMENT_LMAX)
    shape = (len(LOBE_TERMS) * _ENVIRONMENT_NODES * _TABLE_COS_NODES, pairs)
    if table.shape != shape or not np.all(np.isfinite(table)):
        raise InputError(_ENVIRONMENT_TABLE_PATH, f"expected a {shape[0]} x {shape[1]} table of finite responses, "
                                                  f"got shape {table.shape}; regenerate it with "
                                                  "scripts/make_environment_response_table.py")
    return np.ascontiguousarray(table.reshape(len(LOBE_TERMS), _ENVIRONMENT_NODES, _TABLE_COS_NODES, pairs))


def environment_filtered_light(directions: np.ndarray, weight: np.ndarray, tangent: np.ndarray, normal: np.ndarray,
                               environment_coeffs: np.ndarray, roughness: np.ndarray, term: str = "scale",
                               azimuthal: np.ndarray | None = None) -> np.ndarray:
    """(n, V, 3) the environment light as the ``term`` of a lobe of roughness (n,) reads it.

    directions (n, V, 3) local view directions, weight (n, V), tangent and normal (n, 3) world
    frame of each texel, environment_coeffs (K, 3) the world-frame SH of the environment (degrees
    up to min(l*, 5) are read): sum over l, m >= 0 of the lobe's responses
    (`environment_response_table`, linear in cos theta_o) times the environment's coefficients in
    each sample's mirrored view frame (`environment_azimuthal`), at the table's roughness nodes on
    either side of the roughness and interpolated linearly between them (as the split-sum albedo
    is), as the search does. Written with numpy, independently of the kernels. 0 where weight is
    0. ``azimuthal``: `environment_azimuthal` of these samples, to reuse across calls.
    """
    directions = np.asarray(directions, np.float64)
    if azimuthal is None:
        azimuthal = environment_azimuthal(directions, weight, tangent, normal, environment_coeffs)
    table = environment_response_table()[LOBE_TERMS.index(term), :, :, :azimuthal.shape[-1]]  # (nodes, cos, P)
    x = np.clip(directions[..., 2], 0.0, 1.0) * (_TABLE_COS_NODES - 1)
    row = np.minimum(x.astype(np.int64), _TABLE_COS_NODES - 2)
    fx = x[..., None] - row[..., None]
    node, fy = (np.array(part) for part in zip(*[_environment_node(r) for r in np.asarray(roughness, np.float64)]))

    def at_node(nodes):  # (n,) roughness node of each texel -> (n, V, 3)
        response = table[nodes[:, None], row] * (1.0 - fx) + table[nodes[:, None], row + 1] * fx  # (n, V, P)
        return np.einsum("nvp,nvcp->nvc", response, azimuthal)

    fy = fy[:, None, None]
    return (1.0 - fy) * at_node(node) + fy * at_node(node + 1)


def environment_azimuthal(directions: np.ndarray, weight: np.ndarray, tangent: np.ndarray, normal: np.ndarray,
                          environment_coeffs: np.ndarray) -> np.ndarray:
    """(n, V, 3, P) the environment's SH coefficients of degree l <= min(l*, 5) and order m >= 0 in
    each sample's mirrored view frame: the texel's frame (`local_environment`) turned about the
    normal by the azimuth beta of the mirrored view direction (-x, -y), c_lm cos(m beta) +
    c_l,-m sin(m beta); P = `environment_pairs`. 0 where weight is 0."""
    directions = np.asarray(directions, np.float64)
    degrees = min(sh.lmax_of(environment_coeffs.shape[0]), _ENVIRONMENT_LMAX)
    local = local_environment(environment_coeffs, tangent, normal, degrees)  # (n, K, 3)
    beta = np.arctan2(-directions[..., 1], -directions[..., 0])[..., None]  # (n, V, 1)
    out = np.empty(directions.shape[:2] + (3, environment_pairs(degrees)))
    pair = 0
    for degree in range(degrees + 1):
        for order in range(degree + 1):
            centre = degree * degree + degree
            out[..., pair] = local[:, None, centre]
            if order > 0:
                out[..., pair] = (local[:, None, centre + order] * np.cos(order * beta)
                                  + local[:, None, centre - order] * np.sin(order * beta))
            pair += 1
    return np.where(np.asarray(weight)[:, :, None, None] > 0.0, out, 0.0)


def local_environment(environment_coeffs: np.ndarray, tangent: np.ndarray, normal: np.ndarray,
                      lmax: int) -> np.ndarray:
    """(n, (lmax + 1)^2, 3) the world-frame SH environment_coeffs (K, 3) up to degree lmax in each
    texel's frame (x tangent, y normal x tangent, z normal; tangent and normal (n, 3)): projected
    with a quadrature exact for products of two such harmonics, so exact to rounding."""
    directions, weights = sh.sphere_quadrature(2 * lmax)
    tangent, normal = np.asarray(tangent, np.float64), np.asarray(normal, np.float64)
    frames = np.stack([tangent, np.cross(normal, tangent), normal], axis=1)  # (n, 3, 3) rows
    world = np.einsum("qi,nij->nqj", directions, frames)
    values = sh.eval_sh(world, lmax) @ np.asarray(environment_coeffs, np.float64)[: sh.num_coeffs(lmax)]
    return np.einsum("qk,q,nqc->nkc", sh.eval_sh(directions, lmax), weights, values)


@functools.cache
def _environment_quadrature(lmax: int) -> tuple[np.ndarray, np.ndarray]:
    """(directions (Q, 3), projection (K, Q)) of `local_environment`'s quadrature for the kernels:
    local coefficients = projection @ (the environment at the directions turned to the world)."""
    directions, weights = sh.sphere_quadrature(2 * lmax)
    return np.ascontiguousarray(directions), np.ascontiguousarray((sh.eval_sh(directions, lmax) * weights[:, None]).T)


@_borrowing_jit
def _environment_node(roughness):
    """The environment light's roughness node below ``roughness`` (clipped to [0, 1]) and the
    fraction towards the next one (its nodes: every _ENVIRONMENT_NODE_STEP-th of the table's)."""
    n_nodes = (_TABLE_ROUGHNESS_NODES - 1) // _ENVIRONMENT_NODE_STEP + 1
    y = min(max(roughness, 0.0), 1.0) * (n_nodes - 1)
    node = min(int(y), n_nodes - 2)
    return node, y - node


def environment_weight(roughness: np.ndarray, blend: tuple[float, float]) -> np.ndarray:
    """The environment light's share of the light a lobe of this roughness reads: 0 up to
    blend[0], 1 from blend[1], smoothstep between (`EstimateConfig.environment_blend`)."""
    roughness = np.asarray(roughness, np.float64)
    return np.array([_environment_share(r, blend) for r in roughness.ravel()]).reshape(roughness.shape)


# With the prefiltered light (`EstimateConfig.prefiltered_light`) a smooth lobe reads the environment
# map itself, filtered by the GGX lobe's per-degree response at normal incidence (`ggx_lobe_gains`) at
# roughness nodes PREFILTER_STEP apart, looked up bilinearly at each sample's world mirror direction
# (as `envmap.lookup`) and interpolated linearly in roughness between the nodes.
PREFILTER_STEP = 1.0 / 16.0
# Larger maps are resampled to this height (degrees up to 510, ~0.35 degrees): bounds the memory
# of the prefiltered stack (11 maps of 512 x 1024 x 3 float32: 69 MB) and its transforms.
PREFILTER_MAX_HEIGHT = 512
_GAIN_STRATA = 8192  # half-vector strata of `ggx_lobe_gains`


@functools.cache
def ggx_lobe_gains(roughness: float, lmax: int) -> np.ndarray:
    """(lmax + 1,) the GGX lobe's response to the degree-l part of the light at normal incidence,
    relative to its albedo: half vectors drawn by D(h) cos theta_h (stratified in the inverse CDF),
    light from 2 theta_h off the mirror direction (the normal), gain_l = the mean of
    P_l(cos 2 theta_h) over the light above the horizon. Masking-shadowing and Fresnel are left
    out. Where the Gaussian kernel exp(-(alpha l)^2) falls off fast, these have heavier tails
    (roughness 0.25: degree 5 0.75, degree 60 0.0019, against 0.91 and 8e-7)."""
    alpha = max(roughness * roughness, _ALPHA_MIN)
    u = (np.arange(_GAIN_STRATA) + 0.5) / _GAIN_STRATA
    cos_half_squared = 1.0 / (1.0 + alpha * alpha * u / (1.0 - u))
    cos_light = 2.0 * cos_half_squared - 1.0
    cos_light = cos_light[cos_light > 0.0]
    gains = np.empty(lmax + 1)
    previous, current = np.zeros_like(cos_light), np.ones_like(cos_light)
    for degree in range(lmax + 1):  # Legendre's three-term recurrence
        gains[degree] = current.mean()
        previous, current = current, ((2 * degree + 1) * cos_light * current - degree * previous) / (degree + 1)
    return gains


def prefilter_nodes(settings: EstimateConfig) -> int:
    """Roughness nodes (0, PREFILTER_STEP, ...) of the prefiltered maps the estimator reads: up to
    where the environment light takes over (environment_blend[1]) or to roughness 1 without it."""
    end = settings.environment_blend[1] if settings.environment_light else 1.0
    return min(math.ceil(end / PREFILTER_STEP - 1e-9), round(1.0 / PREFILTER_STEP)) + 1


def prefiltered_environment(envmap, n_nodes: int, skip_degrees: int = 0) -> np.ndarray:
    """(n_nodes, H, W, 3) float32 the map (an `envmap.Envmap`) filtered by `ggx_lobe_gains` at
    roughness j PREFILTER_STEP, every degree the map holds (at most PREFILTER_MAX_HEIGHT rows)
    from ``skip_degrees`` on (the environment light holds the degrees below). Node 0, a mirror,
    is the map itself (averaged in pixel space to the stack's size, `envmap.downsample`): cut at
    the map's band limit it would ring around bright lights (Gibbs; it read 8 % too bright beside
    entropy_scenes.py's 40x lights). The next nodes' lobes are filtered in SH as the rest: read
    raw as well, roughness between them would mix a sharp map into a blurred one (on the plane,
    T = 256, without the robust pass: roughness MAE 0.057 -> 0.064 with a 5-node grid)."""
    height, width = envmap.radiance.shape[:2]
    out_height = min(height, PREFILTER_MAX_HEIGHT, (width + 1) // 2)
    lmax = min(height - 2, (width - 1) // 2, out_height - 2)
    gains = np.stack([ggx_lobe_gains(node * PREFILTER_STEP, lmax) for node in range(n_nodes)])
    gains[:, :skip_degrees] = 0.0
    resample = out_height if out_height != height else None
    maps = np.empty((n_nodes, out_height, 2 * out_height, 3), np.float32)
    if n_nodes > 1:
        maps[1:] = envmaps.zonal_filters(envmap, gains[1:], resample)
    maps[0] = envmaps.downsample(envmap.radiance, out_height)
    if skip_degrees > 0:  # less the degrees below skip_degrees: smooth, so exact in SH
        low_pass = (np.arange(lmax + 1) < skip_degrees).astype(np.float64)[None]
        maps[0] -= envmaps.zonal_filters(envmap, low_pass, resample)[0]
    return maps


def prefiltered_light(directions: np.ndarray, tangent: np.ndarray, normal: np.ndarray, prefiltered: np.ndarray,
                      rotation: np.ndarray, roughness: np.ndarray) -> np.ndarray:
    """(n, V, 3) the prefiltered light a lobe of roughness (n,) reads: directions (n, V, 3) local view
    directions, tangent and normal (n, 3) world frame of each texel, prefiltered (nodes, H, W, 3)
    `prefiltered_environment` of a map with emitter-to-world ``rotation`` (3, 3), looked up at the
    world mirror directions and linear in roughness between its nodes (as the search reads it)."""
    directions = np.asarray(directions, np.float64)
    tangent, normal = np.asarray(tangent, np.float64), np.asarray(normal, np.float64)
    bitangent = np.cross(normal, tangent)
    mirror = directions * np.array([-1.0, -1.0, 1.0])
    world = (mirror[..., :1] * tangent[:, None] + mirror[..., 1:2] * bitangent[:, None]
             + mirror[..., 2:] * normal[:, None])
    cos_theta = np.clip(mirror[..., 2], 0.0, 1.0)
    n_nodes, height, width = prefiltered.shape[:3]

    def texel_coordinates(where: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # as envmap.map_coordinates
        local = where @ np.asarray(rotation, np.float64)
        u = np.arctan2(local[..., 0], -local[..., 2]) / (2.0 * np.pi)
        return (u - np.floor(u)) * width - 0.5, np.arccos(np.clip(local[..., 1], -1.0, 1.0)) / np.pi * (height - 1)

    def bilinear(nodes: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:  # as envmap.stencil_at
        column = np.floor(x)
        col0 = column.astype(np.int64) % width
        col1, fx = (col0 + 1) % width, (x - column)[..., None]
        y = np.clip(y, 0.0, height - 1.0)
        row0 = np.minimum(y.astype(np.int64), height - 2)
        fy = (y - row0)[..., None]

        def texel(row, col):
            return prefiltered[nodes, row, col].astype(np.float64)

        top = (1.0 - fx) * texel(row0, col0) + fx * texel(row0, col1)
        bottom = (1.0 - fx) * texel(row0 + 1, col0) + fx * texel(row0 + 1, col1)
        return (1.0 - fy) * top + fy * bottom

    x, y = texel_coordinates(world)  # of the mirror direction
    roughness = np.broadcast_to(np.asarray(roughness, np.float64)[:, None], cos_theta.shape)
    node, frac = np.vectorize(lambda r: _prefilter_node(r, n_nodes), otypes=[np.int64, np.float64])(roughness)
    lower, upper = bilinear(node, x, y), bilinear(node + 1, x, y)
    return lower + frac[..., None] * (upper - lower)


@_borrowing_jit
def _prefilter_node(roughness, n_nodes):
    """The prefiltered map's node below ``roughness`` (clipped to the nodes) and the fraction
    towards the next one."""
    y = min(max(roughness, 0.0) / PREFILTER_STEP, n_nodes - 1.0)
    node = min(int(y), n_nodes - 2)
    return node, y - node


@_borrowing_jit
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@_borrowing_jit
def _mirror_stencil(xyz, n, tangent, normal, bitangent, world_to_local, height, width, corner, stencil_frac):
    """`envmap.lookup`'s bilinear stencil at the world mirror direction of each local view direction
    xyz[:, s], s < n: corner (4, n) flat pixel indices row * width + col of (row, col), (row, col + 1),
    (row + 1, col), (row + 1, col + 1); stencil_frac (2, n) the column and row fractions."""
    for s in range(n):
        mirror_x, mirror_y, mirror_z = -xyz[0, s], -xyz[1, s], xyz[2, s]
        world_x = mirror_x * tangent[0] + mirror_y * bitangent[0] + mirror_z * normal[0]
        world_y = mirror_x * tangent[1] + mirror_y * bitangent[1] + mirror_z * normal[1]
        world_z = mirror_x * tangent[2] + mirror_y * bitangent[2] + mirror_z * normal[2]
        x, y = envmaps.map_coordinates(world_to_local, world_x, world_y, world_z, height, width)
        row0, col0, col1, fx, fy = envmaps.stencil_at(x, y, height, width)
        corner[0, s], corner[1, s] = row0 * width + col0, row0 * width + col1
        corner[2, s], corner[3, s] = (row0 + 1) * width + col0, (row0 + 1) * width + col1
        stencil_frac[0, s], stencil_frac[1, s] = fx, fy


@numba.njit(inline="always", fastmath=True)
def _bilinear(prefiltered, node, c, top_left, top_right, bottom_left, bottom_right, fx, fy):
    """Channel c of the map of node ``node`` of prefiltered (H W, nodes, 3), bilinear between four
    flat pixel indices."""
    top = (1.0 - fx) * prefiltered[top_left, node, c] + fx * prefiltered[top_right, node, c]
    bottom = (1.0 - fx) * prefiltered[bottom_left, node, c] + fx * prefiltered[bottom_right, node, c]
    return (1.0 - fy) * top + fy * bottom


@_borrowing_jit
def _prefiltered_node_light(prefiltered, node, n, corner, stencil_frac, out):
    """out[c, s] = the light of node ``node`` of prefiltered (H W, nodes, 3) for sample s < n:
    bilinear at the mirror stencil (`_mirror_stencil`). (Pixel-major: a texel's lookups at several
    nodes share cache lines.)"""
    for s in range(n):
        for c in range(3):
            out[c, s] = _bilinear(prefiltered, node, c, corner[0, s], corner[1, s], corner[2, s], corner[3, s],
                                  stencil_frac[0, s], stencil_frac[1, s])


# The planes of `split_sum_table`, as the kernels index them: the term k of `LOBE_TERMS` is plane k.
_SCALE_PLANE, _BIAS_PLANE, _DIELECTRIC_PLANE = 0, 1, 2


@functools.cache
def _split_sum_rows() -> np.ndarray:
    """(3, roughness nodes, cos nodes) `split_sum_table` with the roughness first: each probe of the
    search interpolates all its cos theta_o nodes at one roughness, contiguous this way (22 against
    75 ns strided, measured)."""
    return np.ascontiguousarray(split_sum_table().transpose(0, 2, 1))


def lobe_filtered_light(directions: np.ndarray, weight: np.ndarray, light_coeffs: np.ndarray, lmax: int,
                        sigma: float, roughness: np.ndarray) -> np.ndarray:
    """(n, V, 3) the fitted light as the split-sum model filters it for a lobe of roughness (n,).

    directions (n, V, 3) local view directions, weight (n, V), light_coeffs (n, 3, K): the SH fit
    of the mirrored light, low-passed by the BRDF kernel and read in the mirror direction; 0
    where weight is 0.
    """
    alpha = brdf.alpha_from_roughness(np.asarray(roughness, np.float64))
    kernel = brdf.brdf_kernel(alpha, lmax, sigma)  # (n, l*+1)
    return np.einsum("nl,nclv->nvc", kernel, _mirror_projections(directions, weight, light_coeffs, lmax))


def _mirror_projections(directions, weight, coeffs, lmax) -> np.ndarray:
    """(n, 3, l*+1, V) `_degree_projections` at the view directions, normalised in float64 as the
    search kernel normalises them."""
    directions = np.asarray(directions, dtype=np.float64)
    unit = directions / np.maximum(np.linalg.norm(directions, axis=-1, keepdims=True), 1e-12)  # unsampled: (0, 0, 0)
    return _degree_projections(unit, weight, coeffs, lmax)


def burley_diffuse_factor(cos_theta, roughness):
    """Mitsuba's principled diffuse relative to Lambert's, averaged over uniform incoming light.

    Mitsuba's ``principled`` BSDF (Burley's diffuse) scales base_color / pi by
        (1 - F_o / 2)(1 - F_i / 2) + R (F_o + F_i + F_o F_i (R - 1)),   R = 2 r cos^2 theta_d,
    F = (1 - cos)^5 of the view (o) and light (i): darker at grazing views, brighter at grazing
    views of rough surfaces (retro-reflection). With 2 cos^2 theta_d = 1 + w_i.w_o the averages over
    cosine-distributed w_i are polynomials in mu_o = cos theta_o: <F_i> = 1/21,
    <R> = r (1 + 2 mu_o / 3), <R F_i> = r (1/21 + mu_o / 84),
    <R^2 F_i> = r^2 (1/21 + mu_o / 42 + 11 (1 - mu_o^2) / 504 + mu_o^2 / 252). Plain arithmetic, so
    it serves numpy arrays and, compiled, the numba kernels.
    """
    schlick_view = (1.0 - cos_theta) ** 5
    retro = roughness * (1.0 + 2.0 * cos_theta / 3.0)
    retro_fresnel = roughness * (1.0 / 21.0 + cos_theta / 84.0)
    retro_squared_fresnel = roughness * roughness * (
        1.0 / 21.0 + cos_theta / 42.0 + 11.0 * (1.0 - cos_theta * cos_theta) / 504.0 + cos_theta * cos_theta / 252.0)
    return ((1.0 - 0.5 * schlick_view) * (1.0 - 0.5 / 21.0) + schlick_view * retro + retro_fresnel
            + schlick_view * (retro_squared_fresnel - retro_fresnel))


# Burley's diffuse under the environment's own light: the quadrature of `burley_response_table`.
_BURLEY_COS_STRATA = 48  # Gauss-Legendre nodes in cos theta_i
_BURLEY_PHI_STRATA = 64
# Burley's diffuse reads the light's degrees <= 3 (10 harmonics): against degrees <= 5 its factor
# moves by at most 0.25 % (0.1 % on average) under a random degree-5 light, at half the cost.
_BURLEY_LMAX = 3
# A channel's Lambert response below this fraction of its light's DC (a dark or wildly ringing
# low-order light) falls back to the uniform-light Burley factor.
_MIN_LAMBERT = 1e-3


@functools.cache
def burley_response_table(lmax: int = _BURLEY_LMAX) -> np.ndarray:
    """(4, cos nodes, P) float64, P = `environment_pairs`(lmax): Mitsuba's principled diffuse per unit
    base colour, (1 / pi) int f_j(w_i, w_o) cos theta_i Y_lm(-x_i, -y_i, z_i) dw_i for the view
    w_o = (sin, 0, cos theta_o) at the cos nodes of `split_sum_table`, per power j of the roughness:
    Burley's f = f_0 + r f_1 + r^2 f_2 with f_0 = (1 - F_o / 2)(1 - F_i / 2), f_1 = (1 + w_i.w_o)
    (F_o + F_i - F_o F_i), f_2 = (1 + w_i.w_o)^2 F_o F_i (F = (1 - cos)^5, 2 cos^2 theta_d = 1 +
    w_i.w_o); the last row is Lambert's f = 1. The harmonics are those of `environment_azimuthal`
    (the mirrored view frame), so sum_p coefficients_p row_p is the diffuse radiance under that
    light. Gauss-Legendre in cos theta_i times uniform azimuths; deterministic, ~0.1 s."""
    cos_light, weights = np.polynomial.legendre.leggauss(_BURLEY_COS_STRATA)
    cos_light, weights = 0.5 * (cos_light + 1.0), 0.5 * weights
    phi = 2.0 * np.pi * (np.arange(_BURLEY_PHI_STRATA) + 0.5) / _BURLEY_PHI_STRATA
    sin_light = np.sqrt(1.0 - cos_light**2)
    light = np.stack([np.outer(sin_light, np.cos(phi)), np.outer(sin_light, np.sin(phi)),
                      np.repeat(cos_light[:, None], len(phi), axis=1)], axis=-1).reshape(-1, 3)
    measure = np.repeat(weights * cos_light, len(phi)) * (2.0 * np.pi / len(phi)) / np.pi  # cos_i dw_i / pi
    pairs = [degree * degree + degree + order for degree in range(lmax + 1) for order in range(degree + 1)]
    basis = sh.eval_sh(light * np.array([-1.0, -1.0, 1.0]), lmax)[:, pairs]  # (Q, P)
    schlick_light = (1.0 - light[:, 2]) ** 5
    cos_view = np.linspace(0.0, 1.0, _TABLE_COS_NODES)
    out = np.empty((4, len(cos_view), len(pairs)))
    for i, mu in enumerate(cos_view):
        schlick_view = (1.0 - mu) ** 5
        retro = 1.0 + light @ np.array([math.sqrt(1.0 - mu * mu), 0.0, mu])
        parts = ((1.0 - 0.5 * schlick_view) * (1.0 - 0.5 * schlick_light),
                 retro * (schlick_view + schlick_light - schlick_view * schlick_light),
                 retro**2 * schlick_view * schlick_light, np.ones_like(schlick_light))
        for j, part in enumerate(parts):
            out[j, i] = (part * measure) @ basis
    return out


def environment_burley_factor(directions: np.ndarray, weight: np.ndarray, tangent: np.ndarray, normal: np.ndarray,
                              environment_coeffs: np.ndarray, roughness: np.ndarray,
                              azimuthal: np.ndarray | None = None) -> np.ndarray:
    """(n, V, 3) Burley's diffuse relative to Lambert's under the environment's own light (degrees
    <= min(l*, 3); `burley_response_table`, linear in cos theta_o) per channel, for roughness (n,):
    what `burley_diffuse_factor` gives under uniform light. Where a channel's Lambert response is
    not positive (a map with no light there) the uniform-light factor. Written with numpy,
    independently of the kernels; 0 where weight is 0."""
    directions = np.asarray(directions, np.float64)
    if azimuthal is None:
        azimuthal = environment_azimuthal(directions, weight, tangent, normal, environment_coeffs)
    table = burley_response_table()
    pairs = min(table.shape[-1], azimuthal.shape[-1])
    table, azimuthal = table[..., :pairs], azimuthal[..., :pairs]
    x = np.clip(directions[..., 2], 0.0, 1.0) * (_TABLE_COS_NODES - 1)
    row = np.minimum(x.astype(np.int64), _TABLE_COS_NODES - 2)
    fx = (x - row)[..., None]
    response = table[:, row] * (1.0 - fx) + table[:, row + 1] * fx  # (4, n, V, P)
    parts = np.einsum("jnvp,nvcp->jnvc", response, azimuthal)
    roughness = np.asarray(roughness, np.float64)[:, None, None]
    lambert = parts[3]
    burley = parts[0] + roughness * (parts[1] + roughness * parts[2])
    uniform = burley_diffuse_factor(directions[..., 2], roughness[..., 0])[..., None]
    factor = np.where(lambert > _MIN_LAMBERT * np.abs(azimuthal[..., 0]), burley / np.where(lambert > 0.0, lambert,
                                                                                               1.0), uniform)
    return np.where(np.asarray(weight)[:, :, None] > 0.0, factor, 0.0)


def _burley_response(settings: EstimateConfig) -> np.ndarray:
    """`burley_response_table` for the kernels when Burley's diffuse reads the environment's light
    (with the environment light), else an empty one (uniform light)."""
    if _uses_burley(settings) and settings.environment_light and settings.burley_environment:
        return burley_response_table()
    return np.zeros((4, _TABLE_COS_NODES, 0))


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
    environment_degrees = min(observations.lmax, _ENVIRONMENT_LMAX)
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


def _degree_projections(directions: np.ndarray, weight: np.ndarray, coeffs: np.ndarray, lmax: int) -> np.ndarray:
    """P_c,l(w_v) = sum_m c_c,lm Y_lm(w_v): directions (n, V, 3), weight (n, V), coeffs (n, 3, K)
    -> (n, 3, l*+1, V); 0 at samples of weight 0, which no estimator reads (a third of the work)."""
    basis = sh.eval_sh(np.ascontiguousarray(directions, dtype=np.float32), lmax)  # (n, V, K)
    out = np.empty((directions.shape[0], 3, lmax + 1, directions.shape[1]), dtype=np.float32)
    _project_degrees_kernel(basis, weight, np.ascontiguousarray(coeffs, dtype=np.float32), out)
    return out


@numba.njit(parallel=True, fastmath=True, cache=True)
def _project_degrees_kernel(basis, weight, coeffs, out):  # (n, V, K), (n, V), (n, 3, K) -> out (n, 3, l*+1, V)
    n_texels, n_views, _ = basis.shape
    n_degrees = out.shape[2]
    for t in numba.prange(n_texels):
        for v in range(n_views):
            sampled = weight[t, v] > 0.0
            for c in range(3):
                for degree in range(n_degrees):
                    acc = np.float32(0.0)
                    if sampled:
                        for k in range(degree * degree, (degree + 1) * (degree + 1)):
                            acc += basis[t, v, k] * coeffs[t, c, k]
                    out[t, c, degree, v] = acc


@numba.njit(fastmath=True, cache=True)
def _g1_and_derivative(cos_theta, alpha):
    """brdf.smith_g1_ggx for one sample (cos_theta > 0), and its derivative in alpha."""
    sin2 = 1.0 - cos_theta * cos_theta
    root = math.sqrt(cos_theta * cos_theta + alpha * alpha * sin2)
    denominator = cos_theta + root
    g1 = 2.0 * cos_theta / denominator
    return g1, -g1 / denominator * alpha * sin2 / root


@numba.njit(fastmath=True, cache=True)
def _table_lookup(table, index, cos_theta, roughness):
    """table[index] (.., cos nodes, roughness nodes) bilinear at (cos_theta, roughness) in [0, 1]."""
    x = min(max(cos_theta, 0.0), 1.0) * (table.shape[1] - 1)
    y = min(max(roughness, 0.0), 1.0) * (table.shape[2] - 1)
    i = min(int(x), table.shape[1] - 2)
    j = min(int(y), table.shape[2] - 2)
    fx, fy = x - i, y - j
    return ((table[index, i, j] * (1.0 - fx) + table[index, i + 1, j] * fx) * (1.0 - fy)
            + (table[index, i, j + 1] * (1.0 - fx) + table[index, i + 1, j + 1] * fx) * fy)


@numba.njit(parallel=True, cache=True)
def _table_terms_kernel(cos_theta, roughness, table, out):  # (n,), (n,) -> out (planes, n)
    for k in numba.prange(cos_theta.shape[0]):
        for plane in range(table.shape[0]):
            out[plane, k] = _table_lookup(table, plane, cos_theta[k], roughness[k])


@numba.njit(fastmath=True, cache=True)
def _specular_albedo(cos_theta, roughness, alpha, fresnel, masking, split_sum, table):
    """(A, B) with the specular radiance (R0 A + B) times the filtered light, for one sample.

    split_sum: `split_sum_terms`. Otherwise METHOD.md's angular model, F G1 = R0 G1 (1 - F_c) +
    G1 F_c with F_c = (1 - cos)^5. Without Fresnel, A + B and 0.
    """
    if split_sum:
        scale = _table_lookup(table, _SCALE_PLANE, cos_theta, roughness)
        bias = _table_lookup(table, _BIAS_PLANE, cos_theta, roughness)
    else:
        g1 = _g1_and_derivative(cos_theta, alpha)[0] if masking else 1.0
        schlick = (1.0 - cos_theta) ** 5
        scale, bias = g1 * (1.0 - schlick), g1 * schlick
    if not fresnel:
        return scale + bias, 0.0
    return scale, bias


@_borrowing_jit
def _fill_kernel(alpha, sigma, kernel, kernel_derivative):
    """brdf.brdf_kernel for one texel, and its derivative in alpha: -2 alpha l^2 k(l)."""
    for degree in range(kernel.shape[0]):
        kernel[degree] = math.exp(-(alpha * alpha - sigma * sigma) * degree * degree)
        kernel_derivative[degree] = -2.0 * alpha * degree * degree * kernel[degree]


@numba.njit(parallel=True, fastmath=True, cache=True)
def _squared_residual_kernel(
    proj, directions, weight, observed, diffuse_scale, base_color, metallic, roughness, sigma, fresnel, masking,
    split_sum, exact_dielectric, burley, table, response, burley_response, azimuthal, environment_blend, tangent,
    normal, prefiltered, n_full, world_to_local, map_height, map_width, out,
):
    """out[t] = sum_v,c w^2 (L - f)^2 / sum_v w^2 (0 without samples); directions (n, V, 3) local
    view directions. proj (n, 3, l*+1, V): `_mirror_projections`. The specular is
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
        alpha = max(roughness[t] * roughness[t], _ALPHA_MIN)
        kernel = np.empty(n_degrees)
        _fill_kernel(alpha, sigma, kernel, np.empty(n_degrees))
        filtered = np.empty(n_terms)
        share = _environment_share(roughness[t], environment_blend) if azimuthal.shape[3] > 0 else 0.0
        # The environment light at the roughness nodes on either side, per term, channel and view.
        environment_light = np.zeros((2, 3, 3, n_views))  # all three terms, used or not
        # Burley's factor c0 + r c1 + r^2 c2 per channel and view: under uniform light, or the
        # environment's.
        burley_terms = np.empty((3, 3, n_views))
        for v in range(n_views):
            _uniform_burley_terms(np.float64(directions[t, v, 2]), burley, burley_terms[:, :, v])
        environment_burley = burley and burley_response.shape[2] > 0 and azimuthal.shape[3] > 0
        table_row = np.empty(n_views, dtype=np.int64)
        table_frac = np.empty(n_views)
        if share > 0.0 or environment_burley:
            for v in range(n_views):
                x = min(max(np.float64(directions[t, v, 2]), 0.0), 1.0) * (table.shape[1] - 1)
                table_row[v] = min(int(x), table.shape[1] - 2)
                table_frac[v] = x - table_row[v]
        if environment_burley:
            _environment_burley_terms(n_views, table_row, table_frac, azimuthal[t], burley_response, burley_terms)
        if share > 0.0:
            node, node_frac = _environment_node(roughness[t])
            for side in range(2):
                _environment_node_lights(response, node + side, n_views, table_row, table_frac, azimuthal[t],
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
            _cross(normal[t], tangent[t], bitangent)
            _mirror_stencil(xyz, n_views, tangent[t], normal[t], bitangent, world_to_local, map_height, map_width,
                            corner, stencil_frac)
        if use_prefiltered:
            lower_map, upper_map, map_frac = _prefiltered_nodes_at(roughness[t], 0, n_full, n_views, prefiltered,
                                                                   corner, stencil_frac, nodes, cached)
        if use_high:
            lower_high, upper_high, high_frac = _prefiltered_nodes_at(roughness[t], n_full, n_high, n_views,
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
                scale, bias = _specular_albedo(cos_v, roughness[t], alpha, fresnel, masking, split_sum, table)
                dielectric = _table_lookup(table, _DIELECTRIC_PLANE, cos_v, roughness[t]) if exact_dielectric else 0.0
                for c in range(3):
                    for term in range(distinct_terms):
                        filtered[term] = 0.0
                        if use_prefiltered:
                            filtered[term] = _prefiltered_between(nodes, c, v, lower_map, upper_map, map_frac)
                        else:
                            for degree in range(n_degrees):
                                filtered[term] += kernel[degree] * proj[t, c, degree, v]
                        if share > 0.0:
                            lower = environment_light[0, term, c, v]
                            light = lower + node_frac * (environment_light[1, term, c, v] - lower)
                            if use_high:
                                light += _prefiltered_between(nodes, c, v, lower_high, upper_high, high_frac)
                            filtered[term] = (1.0 - share) * filtered[term] + share * light
                    for term in range(distinct_terms, n_terms):
                        filtered[term] = filtered[0]
                    x, y = scale * filtered[0], bias * filtered[1]
                    z = dielectric * filtered[2] if exact_dielectric else _DIELECTRIC_F0 * x + y
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


@_borrowing_jit
def _brent_start(state, lower, upper, xtol):
    """Begin minimising on [lower, upper] to absolute tolerance xtol; returns the first point to
    evaluate."""
    state[_LO], state[_HI], state[_XTOL] = lower, upper, xtol
    state[_PROBE] = lower + _GOLDEN * (upper - lower)
    state[_STEP] = state[_PREV_STEP] = 0.0
    state[_EVALS] = 0.0
    return state[_PROBE]


@_borrowing_jit
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


@_borrowing_jit
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


@_borrowing_jit
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


@_borrowing_jit
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


@_borrowing_jit
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


@_borrowing_jit
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


@_borrowing_jit
def _environment_node_lights(response, node, n, table_row, table_frac, azimuthal, out):
    """out[k, c, s] = the environment light of the three lobe terms k at samples s < n for roughness
    node ``node`` of response (`environment_response_table`), linear in cos theta_o (table_row,
    table_frac: each sample's cos node and fraction): the responses times the environment's
    coefficients in the sample's mirrored view frame, azimuthal (>= n, 3, P)
    (`environment_azimuthal`). The search evaluates it at the two nodes around a roughness and
    interpolates."""
    n_pairs = azimuthal.shape[2]
    # The three terms at once: they share each coefficient's load and the nine sums stay in
    # registers (1.6x faster than one term at a time through an interpolated row).
    for s in range(n):
        row, fx = table_row[s], table_frac[s]
        a0 = a1 = a2 = b0 = b1 = b2 = c0 = c1 = c2 = 0.0
        for pair in range(n_pairs):
            below = response[0, node, row, pair]
            scale = below + fx * (response[0, node, row + 1, pair] - below)
            below = response[1, node, row, pair]
            bias = below + fx * (response[1, node, row + 1, pair] - below)
            below = response[2, node, row, pair]
            dielectric = below + fx * (response[2, node, row + 1, pair] - below)
            red, green, blue = azimuthal[s, 0, pair], azimuthal[s, 1, pair], azimuthal[s, 2, pair]
            a0 += scale * red
            a1 += scale * green
            a2 += scale * blue
            b0 += bias * red
            b1 += bias * green
            b2 += bias * blue
            c0 += dielectric * red
            c1 += dielectric * green
            c2 += dielectric * blue
        out[0, 0, s], out[0, 1, s], out[0, 2, s] = a0, a1, a2
        out[1, 0, s], out[1, 1, s], out[1, 2, s] = b0, b1, b2
        out[2, 0, s], out[2, 1, s], out[2, 2, s] = c0, c1, c2


@numba.njit(cache=True)
def _n_degrees(n_coeffs):
    """l* + 1 of (l* + 1)^2 SH coefficients (numba has no math.isqrt)."""
    return int(math.sqrt(n_coeffs) + 0.5)


@_borrowing_jit
def _local_environment(environment, tangent, normal, bitangent, quadrature, projection, diag, rec_a, rec_b, world,
                       basis, sh_scratch, values, out):
    """out (K, 3) = `local_environment` of environment (K, 3) in the frame (tangent, bitangent,
    normal), with `_environment_quadrature`'s directions (Q, 3) and projection (K, Q); scratch
    world (3, Q), basis (K, Q), sh_scratch (5, Q), values (3, Q)."""
    n_points = quadrature.shape[0]
    for q in range(n_points):
        for axis in range(3):
            world[axis, q] = (quadrature[q, 0] * tangent[axis] + quadrature[q, 1] * bitangent[axis]
                              + quadrature[q, 2] * normal[axis])
    sh._sh_block(world[0], world[1], world[2], n_points, _n_degrees(environment.shape[0]) - 1, diag, rec_a, rec_b,
                 basis, sh_scratch)
    # Loops innermost over the quadrature points, contiguous in basis, values and projection.
    values[:] = 0.0
    for k in range(environment.shape[0]):
        for c in range(3):
            coefficient = environment[k, c]
            for q in range(n_points):
                values[c, q] += coefficient * basis[k, q]
    for k in range(environment.shape[0]):
        for c in range(3):
            total = 0.0
            for q in range(n_points):
                total += projection[k, q] * values[c, q]
            out[k, c] = total


@_borrowing_jit
def _azimuthal_coefficients(xyz, n, local, out):
    """out (>= n, 3, P) = `environment_azimuthal` of local view directions xyz (3, >= n) from the
    texel-frame coefficients local (K, 3)."""
    n_degrees = _n_degrees(local.shape[0])
    for s in range(n):
        mirrored_x, mirrored_y = -xyz[0, s], -xyz[1, s]
        radius = math.sqrt(mirrored_x * mirrored_x + mirrored_y * mirrored_y)
        # At normal incidence the lobe is symmetric (every m > 0 response is 0): any azimuth does.
        cos_beta, sin_beta = (mirrored_x / radius, mirrored_y / radius) if radius > 1e-12 else (1.0, 0.0)
        cos_m, sin_m = 1.0, 0.0
        for order in range(n_degrees):
            if order > 0:
                cos_m, sin_m = cos_m * cos_beta - sin_m * sin_beta, sin_m * cos_beta + cos_m * sin_beta
            for degree in range(order, n_degrees):
                pair = degree * (degree + 1) // 2 + order
                centre = degree * degree + degree
                for c in range(3):
                    if order == 0:
                        out[s, c, pair] = local[centre, c]
                    else:
                        out[s, c, pair] = local[centre + order, c] * cos_m + local[centre - order, c] * sin_m


@_borrowing_jit
def _prefiltered_nodes_at(roughness, first, count, n, prefiltered, corner, stencil_frac, nodes, cached):
    """Where the light of a lobe of ``roughness`` lies among the prefiltered nodes first..first +
    count - 1 (roughness 0..1 by PREFILTER_STEP), for samples s < n: (lower, upper, fraction),
    indices into nodes; on a node both are that node and the fraction is 0. The nodes read are
    looked up once per texel into nodes (cached)."""
    node, frac = _prefilter_node(roughness, count)
    lower = first + (node if frac < 1.0 else node + 1)
    upper = first + (node + 1 if frac > 0.0 else node)
    for needed in range(lower, upper + 1):
        if not cached[needed]:
            _prefiltered_node_light(prefiltered, needed, n, corner, stencil_frac, nodes[needed])
            cached[needed] = True
    return lower, upper, (frac if upper != lower else 0.0)


@numba.njit(inline="always")
def _prefiltered_between(nodes, c, s, lower, upper, frac):
    """Channel c of sample s's light between the nodes `_prefiltered_nodes_at` returned."""
    value = nodes[lower, c, s]
    return value + frac * (nodes[upper, c, s] - value) if frac > 0.0 else value


@_borrowing_jit
def _environment_share(roughness, blend):
    """`environment_weight` for one roughness; blend (start, end)."""
    ramp = min(max((roughness - blend[0]) / max(blend[1] - blend[0], 1e-12), 0.0), 1.0)
    return ramp * ramp * (3.0 - 2.0 * ramp)


@_borrowing_jit
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
    share = _environment_share(roughness, environment_blend) if azimuthal.shape[2] > 0 else 0.0
    # Terms with a light of their own: A and B, and E with the exact dielectric (else Z = 0.04 X + Y).
    n_terms = 3 if exact_dielectric else 2
    alpha = max(roughness * roughness, _ALPHA_MIN)
    if split_sum:  # the table's column at this roughness, linear in it (from its rows, `_split_sum_rows`)
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
            node, node_frac = _environment_node(roughness)
            lower_node = node if node_frac < 1.0 else node + 1
            upper_node = node + 1 if node_frac > 0.0 else node
            for needed in range(lower_node, upper_node + 1):
                if not environment_cached[needed]:
                    _environment_node_lights(response, needed, n, table_row, table_frac, azimuthal,
                                             environment_nodes[needed])
                    environment_cached[needed] = True
        for s in range(n):
            row, fx = table_row[s], table_frac[s]
            for term in range(n_terms):
                albedo[term, s] = column[term, row] + fx * (column[term, row + 1] - column[term, row])
    else:
        for s in range(n):
            albedo[0, s], albedo[1, s] = _specular_albedo(cos_theta[s], roughness, alpha, fresnel, masking, False,
                                                          table)
    if split_sum and not fresnel:
        for s in range(n):
            albedo[0, s] += albedo[1, s]
            albedo[1, s] = 0.0
    # Burley's factor is c0 + r c1 + r^2 c2 per channel and sample (`_burley_terms`,
    # `_environment_burley_terms`); Lambert's is 1.
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
        lower_map, upper_map, map_frac = _prefiltered_nodes_at(roughness, 0, n_full, n, prefiltered, corner,
                                                               stencil_frac, prefiltered_nodes, prefiltered_cached)
    # The degrees the environment light leaves out, from the prefiltered maps' last nodes.
    n_high = prefiltered.shape[1] - n_full
    use_high = share > 0.0 and n_high > 0
    if use_high:
        lower_high, upper_high, high_frac = _prefiltered_nodes_at(roughness, n_full, n_high, n, prefiltered,
                                                                  corner, stencil_frac, prefiltered_nodes,
                                                                  prefiltered_cached)
    if use_fitted:
        _fill_kernel(alpha, sigma, kernel, kernel_derivative)
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
                model[c, 2, s] = _DIELECTRIC_F0 * model[c, 0, s] + model[c, 1, s]
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


@_borrowing_jit
def _burley_terms(cos_theta, out):
    """(c0, c1, c2) with `burley_diffuse_factor`(cos_theta, r) = c0 + r c1 + r^2 c2, into out[:, 0..2]."""
    schlick_view = (1.0 - cos_theta) ** 5
    retro_fresnel = 1.0 / 21.0 + cos_theta / 84.0
    out[0] = (1.0 - 0.5 * schlick_view) * (1.0 - 0.5 / 21.0)
    out[1] = schlick_view * (1.0 + 2.0 * cos_theta / 3.0) + retro_fresnel - schlick_view * retro_fresnel
    out[2] = schlick_view * (1.0 / 21.0 + cos_theta / 42.0 + 11.0 * (1.0 - cos_theta * cos_theta) / 504.0
                             + cos_theta * cos_theta / 252.0)


@_borrowing_jit
def _uniform_burley_terms(cos_theta, burley, out):
    """out (3, 3): every channel's (c0, c1, c2) of Burley's uniform-light factor (`_burley_terms`),
    or Lambert's (1, 0, 0) without ``burley``."""
    if burley:
        _burley_terms(cos_theta, out[0])
    else:
        out[0, 0], out[0, 1], out[0, 2] = 1.0, 0.0, 0.0
    for c in range(1, 3):
        for power in range(3):
            out[c, power] = out[0, power]


@_borrowing_jit
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


@_borrowing_jit
def _environment_burley_terms(n, table_row, table_frac, azimuthal, burley_response, out):
    """out (3, 3, >= n): per channel, Burley's factor c0 + r c1 + r^2 c2 under the environment's own
    light (`environment_burley_factor`) from burley_response (4, cos nodes, >= P)
    (`burley_response_table`) and the samples' azimuthal (>= n, 3, P) coefficients; channels whose
    Lambert response is not above `_MIN_LAMBERT` x their DC keep what out holds."""
    n_pairs = min(azimuthal.shape[2], burley_response.shape[2])
    for s in range(n):
        row, fx = table_row[s], table_frac[s]
        # All rows and channels in one pass over the harmonics, the twelve sums in registers (as
        # `_environment_node_lights`).
        f0r = f0g = f0b = f1r = f1g = f1b = f2r = f2g = f2b = lr = lg = lb = 0.0
        for pair in range(n_pairs):
            red, green, blue = azimuthal[s, 0, pair], azimuthal[s, 1, pair], azimuthal[s, 2, pair]
            below = burley_response[0, row, pair]
            power0 = below + fx * (burley_response[0, row + 1, pair] - below)
            below = burley_response[1, row, pair]
            power1 = below + fx * (burley_response[1, row + 1, pair] - below)
            below = burley_response[2, row, pair]
            power2 = below + fx * (burley_response[2, row + 1, pair] - below)
            below = burley_response[3, row, pair]
            lambert = below + fx * (burley_response[3, row + 1, pair] - below)
            f0r += power0 * red
            f0g += power0 * green
            f0b += power0 * blue
            f1r += power1 * red
            f1g += power1 * green
            f1b += power1 * blue
            f2r += power2 * red
            f2g += power2 * green
            f2b += power2 * blue
            lr += lambert * red
            lg += lambert * green
            lb += lambert * blue
        for c, (power0, power1, power2, lambert) in enumerate(((f0r, f1r, f2r, lr), (f0g, f1g, f2g, lg),
                                                               (f0b, f1b, f2b, lb))):
            if lambert > _MIN_LAMBERT * abs(azimuthal[s, c, 0]):
                out[c, 0, s] = power0 / lambert
                out[c, 1, s] = power1 / lambert
                out[c, 2, s] = power2 / lambert


@_borrowing_jit
def _keep_state(state, best_state):
    """best_state[:] = state, element by element (a slice assignment may allocate, and these
    functions run without numba's runtime)."""
    for i in range(state.shape[0]):
        best_state[i] = state[i]


@_borrowing_jit
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


@_borrowing_jit
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


@_borrowing_jit
def _record_hypothesis(args, sample_weight, out):
    """out (3, 8): per channel `_specular_moments` of the metal terms the last `_roughness_objective`
    probe left in args (in the order `_roughness_objective` unpacks them), sample weights (n,)."""
    n, values, filtered = args[0], args[4], args[22]
    for c in range(3):
        _specular_moments(n, sample_weight, values[c], filtered[c, 0], filtered[c, 1], out[c])


@_borrowing_jit
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


@_borrowing_jit
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


@_borrowing_jit
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
    `environment_response_table` and `_environment_quadrature`'s quadrature (Q, 3) and
    quadrature_projection (K, Q)) is blended in over environment_blend (start, end), and with
    burley_response (4, cos nodes, P > 0) (`burley_response_table`) Burley's diffuse is averaged over
    that light (`environment_burley_factor`) instead of uniform light.
    With prefiltered (H W, nodes, 3) maps (`prefiltered_environment` of an H x W map whose
    emitter frame is world_to_local (3, 3) from the world), smooth lobes read them at the world
    mirror directions instead of the fitted light. Else, per texel the light is expanded by
    degree at its samples (P_c,l(w_v), `_mirror_projections`; fused here to keep it in cache). Then
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
    n_environment_degrees = _n_degrees(environment.shape[0])
    azimuthal = np.zeros((n_views, 3, n_environment_degrees * (n_environment_degrees + 1) // 2))
    # The environment light per roughness node, lobe term, channel and sample.
    environment_nodes = np.empty((_ENVIRONMENT_NODES, 3, 3, n_views))
    environment_cached = np.zeros(_ENVIRONMENT_NODES, dtype=np.bool_)
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
        _cross(normal[t], tangent[t], bitangent)
        prefiltered_cached[:] = False
        if n_full > 0:
            _mirror_stencil(xyz, n, tangent[t], normal[t], bitangent, world_to_local, map_height, map_width,
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
            _local_environment(environment, tangent[t], normal[t], bitangent, quadrature, quadrature_projection,
                               diag, rec_a, rec_b, quadrature_world, quadrature_basis, quadrature_scratch,
                               quadrature_values, local_environment)
            _azimuthal_coefficients(xyz, n, local_environment, azimuthal)
        for s in range(n):
            x = min(max(packed_cos[s], 0.0), 1.0) * (table.shape[1] - 1)
            table_row[s] = min(int(x), table.shape[1] - 2)
            table_frac[s] = x - table_row[s]
            _uniform_burley_terms(packed_cos[s], burley, burley_terms[:, :, s])
        if burley and burley_response.shape[2] > 0 and environment.shape[0] > 0:
            _environment_burley_terms(n, table_row, table_frac, azimuthal, burley_response, burley_terms)
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
        proj = _degree_projections(observations.view_direction, observations.weight, light, observations.lmax)
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
            proj = _degree_projections(observations.view_direction, observations.weight, light, observations.lmax)
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
        _fill_kernel(alpha[t], sigma, kernel, kernel_derivative)
        for v in range(n_views):
            w = np.float64(weight[t, v])
            if w <= 0.0:
                continue
            cos_v = np.float64(cos_theta[t, v])
            g1, g1_derivative = _g1_and_derivative(cos_v, alpha[t]) if masking else (1.0, 0.0)
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
