"""One typed configuration with one set of defaults, and named presets.

Every stage reads its settings from here; the command line only overrides fields. Each settings
class follows a stage of docs/method.md#pipeline: `TexelConfig` (docs/method.md#texels), `ObserveConfig` (docs/method.md#observations, docs/method.md#irradiance), `FitConfig` (docs/method.md#sh-fit and docs/method.md#band-limit),
`EstimateConfig` (docs/method.md#forward-model and docs/method.md#estimation), `UncertaintyConfig` (docs/method.md#entropy), `SurfaceConfig` (docs/method.md#applications). Each field's
docstring says what it is, why its default, and where docs/results.md has the figures.
`preset` names the configurations a user chooses between: ``default``, ``fast`` and ``paper``
(the authors' prototype, for comparison).
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from dataclasses import dataclass, field
from typing import Literal

__all__ = [
    "CalibrationConfig", "Config", "EstimateConfig", "FitConfig", "ObserveConfig", "PRESETS", "RegulariserKind", "SPECTRAL_GRID_RES",
    "SurfaceConfig", "TexelConfig", "UncertaintyConfig", "choices", "preset",
]

RegulariserKind = Literal["none", "constant", "exponential"]


@functools.cache
def choices(settings_class: type) -> dict[str, tuple]:
    """List the fields of a settings class that are typed as a Literal, with their allowed values.

    The command line checks its choice options against these, so that each list exists once.

    Parameters
    ----------
    settings_class : type
        One of the settings dataclasses of this module (e.g. `EstimateConfig`).

    Returns
    -------
    dict of str to tuple
        Field name to the values its Literal allows, in declaration order.
    """
    return {name: typing.get_args(hint) for name, hint in typing.get_type_hints(settings_class).items()
            if typing.get_origin(hint) is Literal}


def _require(settings, name: str, valid: bool, rule: str) -> None:
    """Raise a ValueError naming the field ``name`` and its allowed range ``rule`` unless ``valid``.

    Out of range, these settings give NaN or silently meaningless maps.
    """
    if not valid:
        raise ValueError(f"{type(settings).__name__}.{name} must lie in {rule}; got {getattr(settings, name)!r}")


def _check_choices(settings) -> None:
    """Raise a ValueError where a field typed as a Literal holds another value, naming the choices.

    Dataclasses do not check, and a misspelt option would otherwise surface only when (and if) the
    stage that reads it runs, after the work before it.
    """
    for name, allowed in choices(type(settings)).items():
        value = getattr(settings, name)
        if value not in allowed:
            raise ValueError(f"{type(settings).__name__}.{name} must be one of "
                             f"{', '.join(repr(choice) for choice in allowed)}; got {value!r}")


@dataclass(frozen=True)
class TexelConfig:
    """The texels: texture resolution, seam dilation and the resolution estimated on (docs/method.md#texels).

    `pipeline.fit` observes and estimates on ``estimation_res`` texels, then takes the results to the
    T x T texels of ``texture_res`` (`pipeline.to_texels`).
    """

    texture_res: int = 512
    """T: the maps are T x T; 512 as in docs/method.md#texels."""
    dilation_px: int = 8
    """Texels the exported maps are grown across chart seams, so that filtered lookups near a seam miss the empty
    atlas."""
    estimation_res: int | Literal["pixel", "coarse", "full"] = "pixel"
    """Texels estimated on: "pixel" (coarsest no wider than a pixel of the closest view: no detail lost, and faster),
    "coarse" (finest at least a pixel wide), "full" (T) or a number <= T. docs/results.md#estimation-resolution"""


@dataclass(frozen=True)
class FitConfig:
    """The weighted, degree-regularised SH least squares of each texel (docs/method.md#sh-fit and docs/method.md#band-limit).

    Minimises sum w^2 (Y c - f)^2 + lambda_eff sum_lm e^l c_lm^2 per texel and channel (appendix eqs. 19-20,
    App. B), then applies the views' band limit (appendix C, eq. 12).
    """

    lmax: int = 5
    """l*, the degree of the per-texel fits ((l*+1)^2 = 36 coefficients); the default of docs/method.md#sh-fit. The entropy needs
    >= 1."""
    reg_lambda: float = 1.2e-4
    """lambda, relative to sum w^2 when scaled: the prototype's absolute 1e-3 at a typical capture's weight.
    docs/results.md#sh-fit-and-regularisation"""
    regulariser: RegulariserKind = "exponential"
    """The penalty's growth with the degree: e^l interpolates unseen directions smoothly ("constant", "none":
    docs/method.md#sh-fit says they give wrong BRDF estimates)."""
    scale_lambda_with_weight: bool = True
    """lambda_eff = reg_lambda sum_i w_i^2, the same relative strength whatever the number of views (off: paper preset).
    docs/results.md#sh-fit-and-regularisation"""
    band_limit: bool = True
    """Low-pass the light with exp(-(sigma l)^2), sigma = 1/floor(sqrt(V)), and divide it out of the BRDF kernel, as
    the prototype does (docs/method.md#band-limit)."""
    attenuation_threshold: float = 0.5
    """t in alpha' = sqrt(-ln t) / l* (appendix eq. 12), below which roughness is flagged unresolvable; 0.5 as in docs/method.md#band-limit.
    In (0, 1)."""

    def __post_init__(self):
        _check_choices(self)
        _require(self, "attenuation_threshold", 0.0 < self.attenuation_threshold < 1.0, "(0, 1)")


@dataclass(frozen=True)
class ObserveConfig:
    """The texels' samples and the light they receive (docs/method.md#observations, docs/method.md#irradiance)."""

    environment_occlusion: bool = True
    """Correct the light for the object hiding its own environment: the irradiance (shadow rays to the map's compact
    lights, cosine rays that see the object's observed radiance instead) and the smooth lobes' light where a sample's
    mirror lobe meets the object (`freqbrdf.observe.occlusion`; beyond the paper).
    docs/results.md#environment-occlusion"""


SPECTRAL_GRID_RES = 8
"""The paper's hypothesis grid side R (R x R hypotheses): `UncertaintyConfig.grid_res` in the spectral modes."""


@dataclass(frozen=True)
class UncertaintyConfig:
    """The entropy of the specular hypotheses and the roughness std (docs/method.md#entropy).

    The entropy scores an R x R grid of hypotheses (alpha_i = (i/(R-1))^2, k_j = j/(R-1)): from the SH
    spectra ("calibrated", "paper") or in the sample domain with the global estimator's model ("angular").
    The roughness std is the posterior spread of the estimated roughness.
    """

    # --- the entropy, every mode ---
    mode: Literal["calibrated", "paper", "angular"] = "calibrated"
    """The entropy: "calibrated" (spectra, exposure invariant, milliseconds; guidance predicts it, the applications are
    tuned on it), "paper" (docs/method.md#entropy) or "angular" (agrees with a path tracer).
    docs/results.md#the-entropy"""
    grid_res: int | None = None
    """R. None: the paper's 8 in the spectral modes; in angular mode the estimator's roughness nodes
    (`EstimateConfig.roughness_grid`), which its search probes anyway: then the entropy costs `pipeline.fit` little."""

    # --- paper mode only ---
    temperature: float = 1e-5
    """tau of the paper's likelihood exp(-(E - min E) / tau); 1e-5 as in docs/method.md#entropy. Positive."""

    # --- calibrated mode only ---
    noise_level: float = 0.02
    """One sample's noise std relative to the light's RMS amplitude sqrt(sum_l S_refl(l)); a fitted coefficient's
    variance is noise_level^2 P K / n_samples. Positive."""
    residual_noise: bool = True
    """Add the best hypothesis's misfit per residual degree of freedom to the noise (off: a fixed noise_level): only
    then does the entropy rank the estimate's errors at all. docs/results.md#the-entropy"""

    # --- the flags ---
    ambiguous_entropy: float = 0.7
    """Texels above this entropy are flagged ambiguous (over 57^0.7 ~ 17 of 57 materials plausible): few texels, with
    well above the others' errors. In [0, 1]. docs/results.md#flags"""

    # --- the roughness std (Uncertainty.roughness_std; needs the estimate); its terms add as variances ---
    roughness_window: int = 7
    """Side of the square over which the per-texel roughness estimates' scatter is taken (0: off): their own noise;
    7 ranked the errors best of the windows measured. docs/results.md#the-roughness-std"""
    loss_curvature: bool = True
    """Add the Laplace variance of the estimator's profiled loss around the estimate (free from the global search's
    probes): it adds what the window misses. docs/results.md#the-roughness-std"""
    split_half: bool = False
    """Add the scatter between estimates from the even and from the odd views alone: ranks the errors better, but costs
    a large share of the fit again, so off (``fit --split-half``). docs/results.md#the-roughness-std"""
    split_half_stride: int = 2
    """With split_half, re-estimate every this many-th row and column only (the window spreads their scatter): the
    same ranking at about a quarter of the cost (1: every texel). docs/results.md#the-roughness-std"""
    trust_std: float = 0.2
    """A texel is trusted (the fit folder's trust.exr) where every std it has (roughness, metallic, the base
    colour's mean over RGB) is at most this, in the parameters' units (a fifth of their range). In (0, 1].
    docs/method.md#trust"""

    # --- each capture calibrates its own std (freqbrdf.uncertainty.heldout, docs/method.md#held-out-std-calibration) ---
    heldout_folds: int = 4
    """K: the views are split into K folds, each held out in turn, to scale the roughness and base-colour std maps so
    that one std covers 68 % of the held-out deviations (0: off, the std maps as modelled). 0 or >= 2."""
    heldout_texels: int = 2000
    """The most texels (spread evenly over those seen) estimated again per fold: the calibration's cost. >= 1."""
    heldout_misfit_reference: float = 0.005
    """The median relative misfit (a texel's mean squared residual over its mean squared radiance) of a capture the
    forward model explains; above it the factors grow with sqrt(misfit / reference). Positive.
    docs/results.md#held-out-std-calibration"""
    heldout_narrow_views: int = 24
    """The views each fold must keep for the calibration to narrow a std (a factor below 1); with fewer the folds
    share too few views to show an over-wide std, and it only widens. >= 1. docs/results.md#held-out-std-calibration"""

    def __post_init__(self):
        _check_choices(self)
        _require(self, "heldout_narrow_views", self.heldout_narrow_views >= 1, "[1, inf)")
        _require(self, "heldout_folds", self.heldout_folds == 0 or self.heldout_folds >= 2, "0 or [2, inf)")
        _require(self, "heldout_texels", self.heldout_texels >= 1, "[1, inf)")
        _require(self, "heldout_misfit_reference", self.heldout_misfit_reference > 0.0, "(0, inf)")
        _require(self, "noise_level", self.noise_level > 0.0, "(0, inf)")
        _require(self, "temperature", self.temperature > 0.0, "(0, inf)")
        _require(self, "ambiguous_entropy", 0.0 <= self.ambiguous_entropy <= 1.0, "[0, 1]")
        _require(self, "trust_std", 0.0 < self.trust_std <= 1.0, "(0, 1]")

    def resolution(self, roughness_grid: int | None = None) -> int:
        """Give R, the side of the hypothesis grid.

        Parameters
        ----------
        roughness_grid : int, optional
            The estimator's roughness nodes (`EstimateConfig.roughness_grid`): the angular mode's default
            grid, so needed there when ``grid_res`` is None.

        Returns
        -------
        int
            ``grid_res`` if set, else `SPECTRAL_GRID_RES` in the spectral modes, else ``roughness_grid``.

        Raises
        ------
        ValueError
            In angular mode with neither ``grid_res`` nor ``roughness_grid``.
        """
        if self.grid_res is not None:
            return self.grid_res
        if self.mode != "angular":
            return SPECTRAL_GRID_RES
        if roughness_grid is None:
            raise ValueError("the angular mode's default grid is the estimator's roughness nodes: pass roughness_grid")
        return roughness_grid


@dataclass(frozen=True)
class EstimateConfig:
    """Per-texel base colour, roughness and metallic from the observations (docs/method.md#forward-model and docs/method.md#estimation).

    Two estimators: ``global`` (the default: an exhaustive roughness and metallic search with a closed-form
    solve of the rest, after the note in docs/method.md#estimation) and ``paper`` (the prototype's Adam on the L1 loss).
    Most settings belong to one of them; the sections below say which.
    """

    # --- the estimator ---
    method: Literal["global", "paper"] = "global"
    """The estimator: "global" (exhaustive search: ahead of the prototype and of Mitsuba's inverse renderer on every
    score measured) or "paper" (the prototype's Adam, for comparison). docs/results.md#materials-at-a-glance"""
    forward_model: Literal["angular", "sh_coeffs", "spectrum"] = "angular"
    """The paper estimator's forward model (docs/method.md#forward-model), angular being the most accurate; global is angular only.
    docs/results.md#the-paper-estimator"""

    # --- global estimator: the reflection model ---
    specular_model: Literal["split_sum", "g1"] = "split_sum"
    """The specular's view dependence: "split_sum" (R0 A + B, the GGX lobe's directional albedo: Mitsuba's model) or
    "g1" (the F G1 of docs/method.md#forward-model, too bright on rough lobes; paper: always). See
    docs/results.md#the-reflection-model"""
    diffuse_model: Literal["burley", "lambert"] = "burley"
    """The diffuse: "burley" (the view-dependent principled diffuse Mitsuba renders) or "lambert" (the d E / pi of docs/method.md#forward-model;
    paper: always). docs/results.md#the-reflection-model"""
    dielectric_fresnel: Literal["exact", "schlick"] = "exact"
    """With split_sum, the dielectric part's Fresnel: "exact" (eta 1.5, as Mitsuba's principled BSDF) or "schlick"
    (too low at oblique views). docs/results.md#the-reflection-model"""

    # --- global estimator: the light the model reads (needs observations that carry the environment) ---
    environment_light: bool = True
    """Rough lobes read the environment's own SH (l <= 5) through the GGX lobe's exact response instead of the texel's
    fit of its mirrored samples: with the prefiltered light, what puts global ahead.
    docs/results.md#the-environment-light-and-the-prefiltered-light"""
    environment_blend: tuple[float, float] = (0.3, 0.6)
    """Roughness over which the environment light's share rises from 0 to 1 (smoothstep): smooth lobes keep the
    sharp features its l <= 5 SH lacks. docs/results.md#the-environment-light-and-the-prefiltered-light"""
    burley_environment: bool = True
    """With burley, average Burley's view dependence over the environment's own light instead of uniform light: no
    longer too dark at grazing views, for a few % of the estimate.
    docs/results.md#the-reflection-model"""
    prefiltered_light: bool = True
    """Smooth lobes read the environment map prefiltered by the GGX lobe at their world mirror direction instead of the
    texel's SH fit, which cannot hold sharp reflections. docs/results.md#the-environment-light-and-the-prefiltered-light"""

    # --- global estimator: after the search ---
    neighbour_vote: bool = True
    """Texels over a grid cell from their 5 x 5 neighbours' median roughness (metallic) move towards it unless their
    data reject it: it lowered every texture error measured. docs/results.md#search-grids-and-the-robust-pass"""

    # --- the "g1" specular model (the paper estimator, or global with specular_model "g1") ---
    fresnel: bool = True
    """Fresnel's rise towards grazing views (Schlick's F); off: F = R0."""
    masking: bool = True
    """Masking G1(theta_o) on the reflected light."""
    shadowing: bool = True
    """Shadowing G1(theta_i) on the incoming light before its SH fit (appendix eq. 6)."""

    # --- global estimator: the search ---
    roughness_grid: int = 9
    """Roughness nodes of the first scan (uniform on [0, 1], refined by Brent): 9 x 4 matches 17 x 6 in every score,
    in less time. docs/results.md#search-grids-and-the-robust-pass"""
    metallic_grid: int = 4
    """Metallic nodes of the profile at each roughness (refined by Brent); see roughness_grid.
    docs/results.md#search-grids-and-the-robust-pass"""
    robust_passes: int = 1
    """Re-weighted passes towards the paper's L1 loss, which discounts what the model cannot explain (interreflections,
    silhouettes); 0: least squares. docs/results.md#search-grids-and-the-robust-pass"""
    shadowing_refreshes: int = 1
    """With "g1": re-fit the light shadowed at the estimate and search again (split_sum needs none).
    docs/results.md#search-grids-and-the-robust-pass"""

    # --- paper estimator only (the prototype's Adam, docs/method.md#estimation) ---
    iterations: int = 100
    """Adam steps; the prototype's 100."""
    learning_rate: float = 0.02
    """Adam's step size; the prototype's 0.02."""
    shadowing_refresh_every: int = 50
    """Iterations between refreshes of the shadowed light; the prototype's 50."""
    tv_weight: float = 1e-3
    """Weight of the texture-space total variation on texels with entropy < 1; the prototype's 1e-3."""
    init_base_color: float = 0.5
    """Initial base colour of every texel; the prototype's 0.5."""
    init_roughness: float = 0.5
    """Initial roughness of every texel; the prototype's 0.5."""
    init_metallic: float = 0.5
    """Initial metallic of every texel; the prototype's 0.5."""

    def __post_init__(self):
        _check_choices(self)


@dataclass(frozen=True)
class CalibrationConfig:
    """What the photographs themselves calibrate before the fit (docs/method.md#calibration).

    A real capture's light probe is shot at another exposure and white balance than the object's
    photographs and turned into place by hand; `freqbrdf.calibrate` estimates those quantities
    on the texels of a coarse texture and hands the fit a corrected capture.
    """

    gains: bool = True
    """Estimate one gain per colour channel between the photographs and the environment map (exposure and white
    balance) with the materials; off: the photographs and the map share one radiometric scale."""
    frame_gains: Literal["off", "on"] = "off"
    """A relative gain per photograph, for photographs at other shutter speeds or with auto-exposure: "on"
    measures them from the photographs' pairwise ratios and applies each where likelier off the others than
    alike. Off by default: the frames it corrects can move the exposure's reading (docs/results.md#calibration)."""
    cameras: bool = True
    """Refine each camera's pose so that the mesh's outline falls on its mask's edge (photographs with a mask)."""
    probe_rotation: bool = True
    """Refine the environment map's rotation by how well it explains the photographs' reflections."""
    probe_search_deg: float = 25.0
    """Largest turn of the map searched, in degrees about each axis."""
    drop_bad_views: bool = False
    """Drop photographs that disagree with the others, or whose outline refining does not bring onto their mask,
    beyond what calibration explains (else only named in a warning)."""
    texture_res: int = 64
    """Side of the coarse texture whose texels calibrate (a few thousand texels: milliseconds per hypothesis)."""
    warn_gain: float = 0.10
    """A gain farther than this (as |log gain|) from 1 is named in a warning."""
    warn_rotation_deg: float = 3.0
    """A map turn larger than this is named in a warning."""
    warn_camera_deg: float = 0.25
    """Cameras turned by more than this (the median over the views) are named in a warning."""

    def __post_init__(self):
        _check_choices(self)
        _require(self, "probe_search_deg", 0.0 <= self.probe_search_deg <= 90.0, "[0, 90]")
        _require(self, "texture_res", 8 <= self.texture_res <= 1024, "[8, 1024]")
        _require(self, "warn_gain", self.warn_gain > 0.0, "(0, inf)")
        _require(self, "warn_rotation_deg", self.warn_rotation_deg > 0.0, "(0, inf)")
        _require(self, "warn_camera_deg", self.warn_camera_deg > 0.0, "(0, inf)")

    @property
    def enabled(self) -> bool:
        """Whether anything is calibrated."""
        return self.gains or self.cameras or self.probe_rotation or self.frame_gains == "on"


@dataclass(frozen=True)
class SurfaceConfig:
    """The whole-surface estimate: the per-texel evidence weighed against a prior over the surface.

    See `freqbrdf.estimate.surface`; figures in docs/results.md#whole-surface.
    """

    enabled: bool = True
    """Solve the whole surface (the default); off, each texel keeps its own estimate (``fit --per-texel``)."""
    neighbours: int = 8
    """Nearest texels on the mesh (3D, across seams) each texel is coupled to."""
    appearance_width: float = 0.25
    """Width of the appearance affinity, in log apparent albedo: neighbours this different weigh exp(-1/2)."""
    lookalikes: int = 8
    """Texels of like appearance anywhere on the surface each texel shares its metal label and base colour with."""
    lookalike_width: float = 0.05
    """Width of the look-alike affinity, in log apparent albedo (and half the roughness and metallic, for colour)."""
    noise_inflation: float = 10.0
    """How much the model's misfit exceeds independent noise: divides the samples' evidence."""
    metal_prior: float = 0.4
    """Prior probability that a texel is metal: a texel is metal only with evidence."""
    label_coupling: float = 0.5
    """Ising coupling of a texel's metal label to each alike neighbour's."""
    mixed_evidence: float = 2.0
    """Log-likelihood a texel's samples must lose by its label's pure metallic (0 or 1) to keep its own metallic."""
    label_iterations: int = 30
    """Damped mean-field sweeps of the metal labels."""
    roughness_smoothing: float = 3.0
    """Coupling of neighbours' roughness, relative to the median precision of a texel's own roughness."""
    color_smoothing: float = 0.3
    """Coupling of neighbours' base colour, relative to the median precision of a texel's own base colour."""
    few_sample_power: float = 2.0
    """A texel with fewer samples than the median has its precision scaled by (n / median) to this power."""
    roughness_huber: float = 0.05
    """Roughness difference above which the coupling is L1 (Huber): keeps edges."""
    color_huber: float = 0.05
    """Base-colour difference (Euclidean, linear RGB) above which the coupling is L1 (Huber)."""
    smoothing_passes: int = 3
    """Re-weightings of the Huber coupling (IRLS)."""
    cg_iterations: int = 200
    """Conjugate-gradient iterations per re-weighting."""
    std_scale: float = 1.0
    """Multiplies the posterior std maps (1: as the solve's scatter calibrates them)."""


@dataclass(frozen=True)
class Config:
    """All settings of a fit, one section per stage (docs/method.md#pipeline to docs/method.md#applications).

    Build one with `preset`, or by replacing sections of the default:
    ``Config(texels=TexelConfig(texture_res=256))``.
    """

    texels: TexelConfig = field(default_factory=TexelConfig)
    """The texels: resolution, dilation, estimation resolution."""
    observe: ObserveConfig = field(default_factory=ObserveConfig)
    """The samples and their light."""
    fit: FitConfig = field(default_factory=FitConfig)
    """The per-texel SH fits."""
    uncertainty: UncertaintyConfig = field(default_factory=UncertaintyConfig)
    """The entropy and the roughness std."""
    estimate: EstimateConfig = field(default_factory=EstimateConfig)
    """The material estimator."""
    surface: SurfaceConfig = field(default_factory=SurfaceConfig)
    """The whole-surface estimate (on by default)."""
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    """What the photographs calibrate before the fit: exposure, white balance, the map's rotation (on by default)."""
    seed: int = 0
    """Seed of every random choice a fit makes, so that a fit is reproducible."""
    device: Literal["auto", "cpu", "cuda"] = "auto"
    """Where the SH least squares, the global search and the entropy run: "cpu" (the reference), "cuda" (the
    ``[gpu]`` extra and an NVIDIA GPU) or "auto" (CUDA where both are present, else the CPU; `freqbrdf.devices`).
    The backends agree to rounding. docs/results.md#the-gpu-backend"""

    def __post_init__(self):
        _check_choices(self)

    def replace(self, **sections) -> "Config":
        """Copy the configuration with whole sections or top-level fields replaced.

        Parameters
        ----------
        **sections
            Field name to its new value, e.g. ``fit=FitConfig(lmax=4)`` or ``seed=1``.

        Returns
        -------
        Config
            The new configuration; this one is unchanged.
        """
        return dataclasses.replace(self, **sections)

    def to_dict(self) -> dict:
        """Give every setting as nested plain data, as summary.json records it.

        Returns
        -------
        dict
            Section name to a dict of its fields, ``seed`` and ``device``.
        """
        return dataclasses.asdict(self)


def preset(name: str = "default") -> Config:
    """Return a named configuration.

    ``default`` is ours: the global estimator on texels no wider than a pixel, with the calibrated
    entropy. ``fast`` is ``default`` estimated on texels at least a pixel wide
    (``TexelConfig.estimation_res`` "coarse", then taken to T x T), with the least-squares optimum
    (no robust pass) on a 5-node roughness grid: several times faster, its maps about as close to
    the truth texel by texel but smoother, with less of the detail a rendering shows; still ahead of
    ``paper`` and of Mitsuba's inverse renderer on every score measured. ``paper`` is the authors'
    prototype: every texel of T, its absolute SH regularisation, the paper's entropy recipe and its
    Adam estimator, for comparison. Figures: docs/results.md#presets.

    Parameters
    ----------
    name : {"default", "fast", "paper"}
        The preset (`PRESETS`).

    Returns
    -------
    Config
        A new configuration.

    Raises
    ------
    ValueError
        For a name not in `PRESETS`.
    """
    if name == "default":
        return Config()
    if name == "fast":
        return Config(texels=TexelConfig(estimation_res="coarse"),
                      estimate=EstimateConfig(robust_passes=0, roughness_grid=5))
    if name == "paper":
        return Config(
            texels=TexelConfig(estimation_res="full"),  # the prototype estimates every texel of T
            observe=ObserveConfig(environment_occlusion=False),  # and assumes an unoccluded environment
            fit=FitConfig(reg_lambda=1e-3, scale_lambda_with_weight=False),
            uncertainty=UncertaintyConfig(mode="paper", grid_res=8, temperature=1e-5),
            estimate=EstimateConfig(method="paper"),
            calibration=CalibrationConfig(gains=False, frame_gains="off", cameras=False, probe_rotation=False),  # assumes a calibrated capture
        )
    raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")


PRESETS = ("default", "fast", "paper")
"""The names `preset` takes."""
