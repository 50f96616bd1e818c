"""One typed configuration with one set of defaults, and named presets.

Every stage reads its settings from here; the CLI only overrides fields. ``preset("paper")``
reproduces the hyper-parameters of the authors' prototype for comparison; ``preset("fast")``
trades a little accuracy for speed.
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from dataclasses import dataclass, field
from typing import Literal

RegulariserKind = Literal["none", "constant", "exponential"]


@functools.cache
def choices(settings_class: type) -> dict[str, tuple]:
    """The fields of a settings class typed as a Literal, with their allowed values (the CLI's
    option checks read them here too)."""
    return {name: typing.get_args(hint) for name, hint in typing.get_type_hints(settings_class).items()
            if typing.get_origin(hint) is Literal}


def _require(settings, name: str, valid: bool, rule: str) -> None:
    """ValueError naming the field ``name`` and its allowed range ``rule`` unless ``valid``: out of
    range, these settings give NaN or silently meaningless maps."""
    if not valid:
        raise ValueError(f"{type(settings).__name__}.{name} must lie in {rule}; got {getattr(settings, name)!r}")


def _check_choices(settings) -> None:
    """ValueError naming the field, its value and the choices where a field typed as a Literal holds
    something else: dataclasses do not check, and a misspelt option would otherwise surface only
    when (and if) the stage that reads it runs, after the work before it."""
    for name, allowed in choices(type(settings)).items():
        value = getattr(settings, name)
        if value not in allowed:
            raise ValueError(f"{type(settings).__name__}.{name} must be one of "
                             f"{', '.join(repr(choice) for choice in allowed)}; got {value!r}")


@dataclass(frozen=True)
class TexelConfig:
    texture_res: int = 512  # T: textures are T x T
    dilation_px: int = 8  # how far exported maps are grown across chart seams
    # The texture resolution `pipeline.fit` observes and estimates on; below T the results are
    # then taken to the T x T texels (`pipeline.to_texels`: maps, entropy and roughness_std
    # bilinearly). "pixel" (default): the coarsest ceil(T / 2^k) whose texels are still no wider
    # than a pixel of the closest view; "coarse" (the fast preset): the finest whose texels are at
    # least a pixel wide (`texels.estimation_resolution`); "full": T (METHOD.md's per-texel
    # recipe, the paper preset); or a number <= T. Measured (T = 512, six Mitsuba captures,
    # docs/measurements.md): "pixel" estimates on 256 x 256 where a pixel spans 2.3-3.3 texels (four captures)
    # and on T where it spans 1.5 (two): base-colour PSNR +0.8 to +1.4 dB, relighting PSNR-H
    # -0.06 to +0.16 dB, 2.6-3.9x faster; "coarse" estimates on 128-256 and relights 0.04-0.33 dB
    # worse on five of the six.
    estimation_res: int | Literal["pixel", "coarse", "full"] = "pixel"


@dataclass(frozen=True)
class FitConfig:
    """The weighted, degree-regularised SH least squares (appendix eqs. 19-20, App. B)."""

    lmax: int = 5  # l*: (l*+1)^2 = 36 coefficients
    # lambda in  sum w^2 (Yc - f)^2 + lambda_eff sum_lm e^l c_lm^2.  With the scaling below,
    # lambda_eff = reg_lambda * sum_i w_i^2: the same relative strength whatever the number of
    # views. 1.2e-4 equals the prototype's absolute 1e-3 at the median sum w^2 (8.6) of 64
    # cameras spread over the sphere (measured, benchmarks/bench_sh.py's set-up).
    reg_lambda: float = 1.2e-4
    regulariser: RegulariserKind = "exponential"
    scale_lambda_with_weight: bool = True
    # Band limit: the environment is low-passed with exp(-(sigma l)^2), sigma = 1/floor(sqrt(N)),
    # and the blur is divided back out of the BRDF kernel (prototype behaviour).
    band_limit: bool = True
    attenuation_threshold: float = 0.5  # t in alpha' = sqrt(-ln t) / l*  (appendix eq. 12)

    def __post_init__(self):
        _check_choices(self)
        _require(self, "attenuation_threshold", 0.0 < self.attenuation_threshold < 1.0, "(0, 1)")


# The paper's hypothesis grid, R x R (UncertaintyConfig.grid_res in the spectral modes).
SPECTRAL_GRID_RES = 8


@dataclass(frozen=True)
class UncertaintyConfig:
    # "angular": the hypotheses scored in the sample domain with the global estimator's own model
    # (uncertainty.entropy_angular). On its own it takes seconds (2.0 s for the 256k texels of
    # entropy_scenes.py's sphere); inside `pipeline.fit` the estimator's search probes the
    # hypotheses anyway (uncertainty.AngularEntropy), which costs the fit about 3 % (plane, T = 512:
    # 5.95 -> 6.14 s). It agrees with the path-traced brute force over the same grid
    # (benchmarks/pathtraced_entropy.py, 400 texels, 9 x 9 grid: Spearman 0.81 [0.76, 0.86] against
    # the pooled rendering of two seeds that agree with each other at 0.89) where the spectra do not
    # (8 x 8 grid: calibrated 0.19, paper 0.17). Capture guidance (which
    # predicts spectra) needs "calibrated" or "paper".
    mode: Literal["calibrated", "paper", "angular"] = "calibrated"
    # R: R x R hypotheses (alpha_i = (i/(R-1))^2, k_j = j/(R-1)). None: the paper's 8 in the
    # spectral modes; in angular mode the estimator's roughness nodes (EstimateConfig.roughness_grid,
    # 9), which its search probes anyway, so that `pipeline.fit` gets the angular entropy from the
    # search's own probes (uncertainty.AngularEntropy).
    grid_res: int | None = None
    temperature: float = 1e-5  # tau of the paper's likelihood exp(-(E - min E)/tau)  (paper mode)
    # Calibrated mode: noise std of one sample's radiance, relative to the light's RMS amplitude
    # sqrt(sum_l S_refl(l)); a fitted coefficient then has variance noise_level^2 P K / n_samples.
    noise_level: float = 0.02
    # Calibrated mode: add the best hypothesis's misfit per residual degree of freedom to the noise
    # variance (see freqbrdf.uncertainty); off reproduces a fixed noise_level.
    residual_noise: bool = True
    # Texels above this normalised entropy are flagged ambiguous: more than 57^0.7 ~ 17 of the 57
    # materials of the 8 x 8 grid stay plausible. On the Mitsuba bunny and sphere of
    # benchmarks/entropy_variants.py that is 5 % of the observed texels, whose roughness error is
    # 1.7x the others' (0.5 flagged 36 % with 1.4-1.6x).
    ambiguous_entropy: float = 0.7
    # The posterior spread of the ESTIMATED roughness (Uncertainty.roughness_std, from
    # uncertainty.roughness_std; needs the estimate). The entropy scores the spectra, not the
    # estimate, and ranks the global estimate's roughness errors poorly. Spearman rho / AURG
    # against the per-texel roughness error of the session-5 estimator (environment light;
    # benchmarks/entropy_variants.py, bunny and sphere): entropy 0.27 / 0.23 and 0.18 / 0.18. With
    # the session-6 estimator (prefiltered light) the default roughness_std reaches 0.56 / 0.50
    # (bunny), 0.40 / 0.36 (sphere), 0.28, 0.37 and 0.42 on the photo-textured bunny_sunset,
    # sphere_city and sphere_studio, 0.55 / 0.52 on the demo capture; with session 9's (the
    # mirror's map, the residual's degrees of freedom) 0.57 / 0.52, 0.49 / 0.45, 0.32, 0.38, 0.49,
    # and 0.55 / 0.52 on the demo capture. Two terms, added as variances:
    # - roughness_window: the scatter of the per-texel estimates over this many texels square
    #   (0: off). Texels are estimated independently and materials are smooth at that scale, so the
    #   scatter measures the estimate's own noise, whatever caused it (interreflection, occlusion,
    #   few views); true texture edges raise it too. Alone: 0.48 / 0.41 and 0.28 / 0.16 (window 5:
    #   0.48 and 0.25; 3: 0.45 and 0.17). Milliseconds.
    roughness_window: int = 7
    # - loss_curvature: the Laplace variance 2 s^2 / (n L''(r)) of the estimator's own angular
    #   loss L around the estimate, s^2 = L 3n / (3n - 5) + (0.02)^2 x signal (the misfit per
    #   residual degree of freedom: 3n values, five parameters); L'' is the profiled loss's (the
    #   marginal posterior's), which the global search returns for two more probes per texel
    #   (MaterialEstimate.roughness_curvature; for `paper` estimates, base colour and metallic
    #   are held and the loss is evaluated twice more). Alone: 0.43 / 0.37 and 0.29 / 0.23; with
    #   the window: 0.51 / 0.44 (bunny) and 0.40 / 0.31 (sphere).
    loss_curvature: bool = True
    # - split_half: the scatter between two more estimates, from the even-numbered and from the
    #   odd-numbered views alone ((r_even - r_odd)^2 / 4, averaged over roughness_window): an
    #   empirical variance of the estimator, whatever makes it unstable. Alone (no window): 0.38 /
    #   0.27 and 0.33 / 0.26. It adds what the two terms above miss: with all three, rho / AURG
    #   0.57 / 0.52 (bunny), 0.51 / 0.47 (sphere; 0.48 / 0.43 without it), and 0.34, 0.40, 0.48 on
    #   the photo-textured three (0.30, 0.37, 0.47 without). The two more estimates (each half
    #   observation refitted) on every other row and column cost 0.3-0.4x the observe + estimate
    #   time again (2.0-3.9 s there; on every texel 1.2-1.8x, 7.6-15.6 s), which would take the
    #   default fit below 10x Mitsuba's speed (issue #5), so it is off by default (fit --split-half).
    split_half: bool = False
    # split_half re-estimates only the texels of every this many-th texture row and column (when
    # roughness_window is wider): the window average spreads their scatter to the rest, at about a
    # quarter of the cost (1: every texel; uncertainty._split_half_variance has the figures).
    split_half_stride: int = 2

    def __post_init__(self):
        _check_choices(self)
        _require(self, "noise_level", self.noise_level > 0.0, "(0, inf)")
        _require(self, "temperature", self.temperature > 0.0, "(0, inf)")
        _require(self, "ambiguous_entropy", 0.0 <= self.ambiguous_entropy <= 1.0, "[0, 1]")

    def resolution(self, roughness_grid: int | None = None) -> int:
        """R of the hypothesis grid: grid_res, else SPECTRAL_GRID_RES, or in angular mode the
        estimator's ``roughness_grid`` (which that mode needs then)."""
        if self.grid_res is not None:
            return self.grid_res
        if self.mode != "angular":
            return SPECTRAL_GRID_RES
        if roughness_grid is None:
            raise ValueError("the angular mode's default grid is the estimator's roughness nodes: pass roughness_grid")
        return roughness_grid


@dataclass(frozen=True)
class EstimateConfig:
    """Per-texel base colour, roughness and metallic from the observations (METHOD.md §3.7)."""

    method: Literal["global", "paper"] = "global"  # exhaustive search (ours) or the prototype's Adam
    forward_model: Literal["angular", "sh_coeffs", "spectrum"] = "angular"  # "global" is angular only
    # global: how the specular lobe's reflectance depends on the view. "split_sum": R0 A + B, the
    # GGX lobe's directional albedo with Schlick Fresnel and Smith masking-shadowing integrated over
    # the lobe (as in real-time split-sum shading); "g1": METHOD.md §3.6, F(theta_o) G1(theta_o)
    # on the G1-shadowed light. "g1" overestimates rough lobes (r = 0.8: 1.0 vs 0.56 at normal
    # view), so rough metals came out as dark dielectrics. "paper" always uses "g1".
    specular_model: Literal["split_sum", "g1"] = "split_sum"
    # global: "burley" is Mitsuba's principled diffuse (view-dependent, with retro-reflection on
    # rough texels) averaged over uniform light; "lambert": METHOD.md's d E / pi. "paper": lambert.
    diffuse_model: Literal["burley", "lambert"] = "burley"
    # global, split_sum: the dielectric part's Fresnel. "exact": the unpolarised Fresnel equations
    # at eta 1.5, as Mitsuba's principled BSDF reflects (its metallic part is Schlick's);
    # "schlick": R0 = 0.04 (1 - m) + m b in Schlick's approximation, 10-27 % below at view
    # cosines 0.3-0.8.
    dielectric_fresnel: Literal["exact", "schlick"] = "exact"
    # global, split_sum: rough lobes read the environment's own SH (world frame, l <= 5, unoccluded)
    # through the GGX lobe's exact response to each harmonic (estimate.environment_response_table)
    # instead of the per-texel fit of the mirrored samples, which extrapolates where a wide lobe
    # reads it; the share rises from 0 at roughness environment_blend[0] to 1 at [1] (smoothstep).
    # Smooth lobes keep the fitted light: it holds the sharp features the environment's l <= 5
    # SH lacks. Needs observations that carry the environment (`Observations.environment_coeffs`).
    # Base-colour PSNR (64 views, T = 512): bunny 17.17 -> 18.43 dB, plane 20.11 -> 24.24; see
    # the estimate module's docstring for the rest.
    environment_light: bool = True
    environment_blend: tuple[float, float] = (0.3, 0.6)
    # global, burley, with the environment light: Burley's view dependence averaged over the
    # environment's own light (degrees <= 3, per channel; estimate.environment_burley_factor)
    # instead of uniform light, which under the demo's forest map predicts a rough dielectric's
    # diffuse 6 % too dark at grazing views. T = 256: bunny 18.30 -> 18.43 dB (roughness MAE
    # 0.136 -> 0.128), demo capture 19.97 -> 20.14 dB (0.131 -> 0.129), plane 26.98 -> 27.01 dB;
    # ~1-4 % of the estimate's time.
    burley_environment: bool = True
    # global, split_sum: smooth lobes (below environment_blend[1], all of them without the
    # environment light) read the environment map itself, prefiltered by the GGX lobe's
    # per-degree response (estimate.prefiltered_environment), at each sample's world mirror
    # direction, instead of the per-texel SH fit (l* = 5) of the mirrored samples, which cannot
    # hold a smooth lobe's sharp reflections. Needs observations that carry the map
    # (`Observations.environment_radiance`); ignores occlusion of the mirror direction. The
    # environment light also gains the map's degrees above its own 5 from such maps. Measured (64
    # views, T = 512; benchmarks/results/compare_estimators.md): base-colour PSNR 18.43 -> 18.69
    # dB (bunny), 24.24 -> 24.42 (plane); roughness MAE 0.154 -> 0.142, 0.071 -> 0.064; metallic
    # MAE 0.200 -> 0.191, 0.118 -> 0.118; relighting PSNR-H 20.19 -> 21.90, 22.65 -> 23.47; the demo
    # capture 19.92 -> 20.25 dB, relighting 23.02 -> 24.06. The model's mean loss drops 45-72 %
    # (benchmarks/results/prefiltered_light.json).
    prefiltered_light: bool = True
    # global: after the search, each texel whose estimate lies more than a grid cell from the median
    # roughness of its neighbours (5 x 5 texels) takes a local minimum within a cell of that median,
    # and one more than a metallic grid cell from their median metallic takes that metallic, unless
    # its data reject the result (a likelihood-ratio test at 95 %, estimate._VOTE_CHI2): bimodal
    # texels (a smooth or a rough lobe, a metal or a dielectric, fitting about equally) follow
    # their neighbourhood. At T = 512 (compare_estimators.md), without -> with: bunny base colour
    # 18.81 -> 19.00 dB, roughness MAE 0.126 -> 0.121, metallic 0.178 -> 0.171, relighting PSNR-H
    # 22.10 -> 22.12; plane 25.00 -> 25.10 dB, 0.0584 -> 0.0581, 0.0807 -> 0.0796, 23.49 -> 23.50;
    # photo-textured scenes (applications.py's): bunny_sunset 20.71 -> 21.08 dB, roughness 0.132
    # -> 0.129, metallic 0.217 -> 0.208; sphere_city 25.79 -> 26.14, 0.070 -> 0.069, 0.111 -> 0.108;
    # sphere_studio 17.49 -> 17.51, 0.121 -> 0.118, 0.172 -> 0.170. Cost, in one process: +0.6 s of
    # the bunny's 4.2 s estimate, +0.5-0.7 s of the plane's 9.8 s. Windows of 3, 9 or 15 texels
    # instead of 5 moved roughness MAE by at most 0.001 (T = 256, bunny and demo capture; measured
    # with the roughness vote alone).
    neighbour_vote: bool = True
    fresnel: bool = True  # Schlick F; off: F = R0
    masking: bool = True  # "g1": G1(theta_o) on the reflected light
    shadowing: bool = True  # "g1": G1(theta_i) on the incoming light before its SH fit (appendix eq. 6)
    # global: roughness grid (uniform in r on [0, 1]) and metallic grid, each refined by Brent.
    # On the 64-view Mitsuba bunny (T = 512, 141k texels) 9 x 4 matches 17 x 6 to 1e-3 in every
    # score at about 70 % of the CPU time (benchmarks/bench_estimate.py).
    roughness_grid: int = 9
    metallic_grid: int = 4
    # global: passes of iteratively re-weighted least squares towards the paper's L1 loss
    # sum_v w |r_v| (each weights a sample by w / max(|r|, a tenth of the texel's mean |r|) and
    # searches again); 0: the least-squares optimum. L1 discounts the samples the model cannot
    # explain (interreflections, silhouettes).
    robust_passes: int = 1
    # global with specular_model "g1": re-fit the light shadowed nearer the fixed point, search
    # again (split_sum needs none). 1 refresh: roughness MAE 0.217 -> 0.200 on that bunny.
    shadowing_refreshes: int = 1
    # paper: the prototype's Adam on the L1 loss, its initialisation and texture-space TV.
    iterations: int = 100
    learning_rate: float = 0.02
    shadowing_refresh_every: int = 50
    tv_weight: float = 1e-3
    init_base_color: float = 0.5
    init_roughness: float = 0.5
    init_metallic: float = 0.5

    def __post_init__(self):
        _check_choices(self)


@dataclass(frozen=True)
class ShareConfig:
    """Sharing across the surface (`fit --share`, METHOD.md §4; see freqbrdf.applications.share)."""

    enabled: bool = False
    uncertain_entropy: float = 0.5  # texels at or above this normalised entropy are pulled
    # An anchor's certainty 1 - H must reach this. 0.6 rather than 0.8 since the entropy counts
    # the sample count (session 3): better than 0.8 on all 4 scenes of benchmarks/applications.py.
    anchor_certainty: float = 0.6
    anchor_cells: int = 32  # the texture is split into cells x cells; at most one anchor per cell
    neighbours: int = 8  # k nearest anchors (texture space) scored per uncertain texel
    affinity_width: float = 0.4  # Gaussian width of the affinity, in units of the mean KL divergence
    min_affinity: float = 0.1  # texels whose summed affinity is below this keep their estimate
    loss_tolerance: float = 0.05  # relative increase of a texel's data loss the pull may cost
    chunk_texels: int = 16384  # texels per affinity chunk: bounds memory to chunk x k x R^2 floats


@dataclass(frozen=True)
class Config:
    texels: TexelConfig = field(default_factory=TexelConfig)
    fit: FitConfig = field(default_factory=FitConfig)
    uncertainty: UncertaintyConfig = field(default_factory=UncertaintyConfig)
    estimate: EstimateConfig = field(default_factory=EstimateConfig)
    share: ShareConfig = field(default_factory=ShareConfig)
    seed: int = 0

    def replace(self, **sections) -> "Config":
        """Copy with whole sections or top-level fields replaced."""
        return dataclasses.replace(self, **sections)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def preset(name: str = "default") -> Config:
    """Named configurations: ``default`` (ours), ``fast`` and ``paper`` (the prototype's
    hyper-parameters).

    ``fast`` is ``default`` estimated on texels at least a pixel wide (``TexelConfig.estimation_res``
    "coarse", then taken to T x T; the default's "pixel" keeps them no wider than a pixel), with
    the least-squares optimum (no robust pass) on a 5-node roughness grid. ``freqbrdf fit --preset
    fast`` on the plane (64 views of 256 x 256, T = 512, estimated on 128 x 128): 3.8-4.1 s end to
    end against 5.9-6.7 s for ``default`` (256 x 256) and 14.0-14.5 s for every texel of T, the
    same day (benchmarks/bench_fit.py). Against ``default`` (64 views, T = 512, session 13,
    benchmarks/results/compare_estimators.md): base-colour PSNR 25.47 vs 25.88 dB (plane), 19.98
    vs 19.00 (bunny, on 256 x 256 against every texel); roughness MAE 0.058 vs 0.056, 0.110 vs
    0.121; metallic MAE 0.078 vs 0.076, 0.159 vs 0.171; but relighting PSNR-H 23.33 vs 23.44 and
    21.81 vs 22.12 dB: its maps are smoother, closer to the truth texel by texel on the bunny but
    with less of the detail a rendering shows. Still ahead of ``paper`` and of Mitsuba's inverse
    renderer on every score. (Before session 13 it estimated every texel of T: 25.08 and 18.76 dB,
    relit 23.48 and 22.08, in two thirds of the estimation time.)
    """
    if name == "default":
        return Config()
    if name == "fast":
        return Config(texels=TexelConfig(estimation_res="coarse"),
                      estimate=EstimateConfig(robust_passes=0, roughness_grid=5))
    if name == "paper":
        return Config(
            texels=TexelConfig(estimation_res="full"),  # the prototype estimates every texel of T
            fit=FitConfig(reg_lambda=1e-3, scale_lambda_with_weight=False),
            uncertainty=UncertaintyConfig(mode="paper", grid_res=8, temperature=1e-5),
            estimate=EstimateConfig(method="paper"),
        )
    raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")


PRESETS = ("default", "fast", "paper")
