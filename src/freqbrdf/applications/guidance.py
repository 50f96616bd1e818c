"""Capture guidance: the next photographs that most lower the whole-surface posterior's uncertainty.

docs/method.md#guidance (capture guidance). `freqbrdf fit` returns the whole-surface estimate
(`freqbrdf.estimate.surface`): every texel's roughness, metallic and base colour with a posterior
std. Guidance plans for that estimate. Its objective is the area-weighted mean over the texels of

    U_t = std_roughness + std_metallic + mean over RGB of std_base_colour,

all three parameters on their [0, 1] scale, and a candidate camera is worth the expected drop of
that mean once its photograph is added (`UncertaintyModel`, `expected_uncertainty`):

- **roughness and base colour**: the solve's variance per texel, s^2 / (P_t few(n_t) + lambda_t),
  with the surface coupling lambda_t and the calibration s^2 of the current fit, the sample count
  n_t (`few` down-weights texels with fewer samples than the median, as the solve does), and for
  roughness the precision P_t proportional to the samples' roughness information I_t: the
  Fisher information on roughness of f = k spec L_alpha(w_r) + d diffuse E / pi once the scales
  k and d are fitted too (`roughness_information`), L_alpha the specular light in the mirror
  direction (lobe exp(-(alpha^2 + sigma^2) l^2) on the environment's SH, sigma the band limit the
  capture will have once the views are added). Each texel's P_t / I_t is taken from the current
  fit (its loss curvature over the noise);
- **metallic**: the label's log-odds x = logit(p) move by A as the evidence
  E = sum_i w_i^2 |f_metal - f_dielectric|^2 of the samples grows: the fit's own log-ratio per
  square root of its evidence (misfit adds up like noise) times the growth of sqrt(E), towards
  the label that turns out true: E[std] = p s(x + A) + (1 - p) s(x - A),
  s(x) = sqrt(sigmoid(x) sigmoid(-x)); a texel a view brings to data weighs all its samples'
  evidence (its label was the prior's and its neighbours' until then);
- **coverage**: a texel no view samples (or with fewer than the estimate's minimum) keeps the
  posterior's std of a texel without data (growing with its distance from the data up to the
  std of a value uniform on [0, 1]: `freqbrdf.estimate.surface.smooth_on_surface`). Seeing it
  turns it into a data texel (each sample on the way to the minimum credited its share); that is
  the gain of a view of unseen parts, in the same units.

What a candidate would add to each texel is known without a photograph (its visibility, view and
mirror directions: `freqbrdf.applications.candidates.view_samples`), and it depends only on the
current estimate, so a budget is chosen greedily (`select_views`) with exact incremental updates
of per-texel sums (`GuidanceState`, `add_view`): no refit per candidate. The model's misfit is
correlated between samples from nearby view directions, so a candidate's information and
evidence at a texel count only its effective share of a sample, less the closer it is to the
views already sampling the texel; and where the candidates' gains differ by less than a refit's
own scatter, the view farthest from those taken and picked is chosen
(`freqbrdf.applications._diversity`). The texels scored are a seeded random subset of the
estimation texels (``max_texels``). `surface_fit` makes the fit the
model reads (the steps of `freqbrdf.pipeline.fit` up to the whole-surface solve).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from freqbrdf.applications._diversity import Spread
from freqbrdf.applications.candidates import view_directions
from freqbrdf.applications.information import FISHER_ENTRIES, ViewInformation, roughness_information, view_information
from freqbrdf.capture.camera import Camera
from freqbrdf.capture.layouts import Capture
from freqbrdf.config import Config
from freqbrdf.estimate import MaterialEstimate
from freqbrdf.estimate import estimate as estimate_materials
from freqbrdf.estimate._search_kernels import MIN_SAMPLES
from freqbrdf.estimate.search import lambert_scale
from freqbrdf.estimate.surface import (
    PRIOR_PRECISION,
    SurfacePosterior,
    apparent_albedo,
    data_precision,
    metal_evidence,
    surface_graphs,
    whole_surface,
)
from freqbrdf.model.brdf import band_limit_sigma
from freqbrdf.observe.observations import Observations, observe
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.texels import Texels, rasterise

MAX_TEXELS = 8192  # texels scored per candidate (a seeded random subset of the estimation texels)
# Candidates closer than this (cosine, seen from the object) to a view taken are not proposed again.
TAKEN_COSINE = 0.9999


@dataclass(frozen=True)
class Pick:
    """One chosen view, in the order chosen.

    Attributes
    ----------
    rank : int
        0 = take this photograph first.
    candidate : int
        Index into the candidate list.
    camera : Camera
        The candidate camera.
    uncertainty_before : float
        Area-weighted mean of U_t over the scored texels before this pick.
    expected_uncertainty : float
        The same once this view is added (the views picked before it included).
    unseen_area : float
        Share of the scored area without data (fewer samples than the estimate needs) that this
        view samples.
    texels_seen : int
        Scored texels the view samples.
    decided_by : str
        "gain": the best expected gain; "spread": one of the candidates whose gains are within a
        refit's own scatter of the best, the farthest from the views taken and picked.
    seconds : float
        Time spent scoring every remaining candidate and committing this one.
    """

    rank: int
    candidate: int
    camera: Camera
    uncertainty_before: float
    expected_uncertainty: float
    unseen_area: float
    texels_seen: int
    decided_by: str
    seconds: float

    @property
    def expected_gain(self) -> float:
        """The expected drop of the mean uncertainty from this view."""
        return self.uncertainty_before - self.expected_uncertainty


@dataclass(eq=False)
class SurfaceFit:
    """A whole-surface fit of a capture on N texels: what the uncertainty model reads.

    Attributes
    ----------
    observations : Observations
        The N texels' samples.
    texels : Texels
        The same texels on the mesh.
    per_texel : MaterialEstimate
        The ``global`` estimator's per-texel estimate (with its label losses and curvature).
    estimate : MaterialEstimate
        The whole-surface estimate.
    posterior : SurfacePosterior
        Its std maps and label probabilities.
    """

    observations: Observations
    texels: Texels
    per_texel: MaterialEstimate
    estimate: MaterialEstimate
    posterior: SurfacePosterior


@dataclass(eq=False)
class GuidanceState:
    """Per scored texel (n), the sums the views taken and picked so far make.

    Attributes
    ----------
    samples : (n,) int64
        Sample count (the fit's, plus one per picked view that sees the texel).
    fisher : (n, 6) float64
        Sum of the views' Fisher information (`ViewInformation`).
    metal_evidence : (n,) float64
        Sum of the picked views' metal evidence (the fit's own is in the label probability).
    """

    samples: np.ndarray
    fisher: np.ndarray
    metal_evidence: np.ndarray

    def copy(self) -> GuidanceState:
        """Return an independent copy.

        Returns
        -------
        GuidanceState
            The same sums in new arrays.
        """
        return GuidanceState(self.samples.copy(), self.fisher.copy(), self.metal_evidence.copy())


@dataclass(eq=False)
class UncertaintyModel:
    """The whole-surface posterior's std as a function of the samples, on n scored texels.

    Attributes
    ----------
    rows : (n,) int64
        Rows of the scored texels in the fit.
    area : (n,) float64
        Their areas (the objective's weights).
    prior_std : (n, 3) float64
        The posterior's std of roughness, metallic and mean base colour where a texel has no data.
    fit_samples : (n,) int64
        The fit's sample count per texel.
    roughness_precision : (n,) float64
        The fit's roughness precision (its loss curvature over the noise; 0 without one).
    roughness_per_unit : float
        Roughness precision per unit of new roughness information: the median over the estimated
        texels of their precision over their taken views' information.
    base_information : (n,) float64
        The taken views' roughness information at the scoring band limit.
    roughness_coupling : (n,) float64
        lambda sum_j w_tj of the roughness solve (plus its pin).
    roughness_scale : float
        The roughness solve's calibration s^2.
    roughness_level : float
        The median over the fit's data texels of P few: the solve's coupling and calibration
        scale with it.
    color_precision : (n, 3) float64
        Base-colour precision per channel before the few-sample factor.
    color_coupling : (n,) float64
        lambda sum_j w_tj of the base-colour solve (plus its pin).
    color_scale : float
        The base-colour solve's calibration s^2.
    color_level : float
        As ``roughness_level``, of the mean over RGB.
    metal_probability : (n,) float64
        The metal label's probability now.
    border_variance : (n,) float64
        The metallic variance of the label's disagreement over the texel's neighbourhood
        (`freqbrdf.estimate.surface.border_variance`), held as the fit has it.
    label_color_difference : (n, 3) float64
        The base colour as a metal minus as a dielectric: the label's doubt in the base-colour std.
    evidence_scale : (n,) float64
        The texel's log-ratio (as the solve weighs it) over the square root of its taken views'
        evidence (the median over the estimated texels where it has none).
    taken_evidence : (n,) float64
        The taken views' metal evidence.
    typical_samples : float
        The median sample count of the estimated texels (the few-sample factor's reference).
    few_sample_power : float
        The few-sample factor's exponent.
    std_scale : float
        The solve's std scale.
    sigma : float
        The band limit the views are scored with.
    """

    rows: np.ndarray
    area: np.ndarray
    prior_std: np.ndarray
    fit_samples: np.ndarray
    roughness_precision: np.ndarray
    roughness_per_unit: float
    base_information: np.ndarray
    roughness_coupling: np.ndarray
    roughness_scale: float
    roughness_level: float
    color_precision: np.ndarray
    color_coupling: np.ndarray
    color_scale: float
    color_level: float
    metal_probability: np.ndarray
    border_variance: np.ndarray
    label_color_difference: np.ndarray
    evidence_scale: np.ndarray
    taken_evidence: np.ndarray
    typical_samples: float
    few_sample_power: float
    std_scale: float
    sigma: float


# --------------------------------------------------------------------------------------------
# The selection


def select_views(
    capture: Capture,
    candidates: Sequence[Camera],
    budget: int,
    config: Config = Config(),
    *,
    fit: SurfaceFit | None = None,
    max_texels: int = MAX_TEXELS,
    reporter: Reporter = SILENT,
) -> list[Pick]:
    """Choose some of the candidate views greedily by the expected drop of the posterior's uncertainty.

    Every pick scores each remaining candidate by the drop of the area-weighted mean U_t
    (module docstring) that it adds on top of the views taken and picked so far, its samples
    counted by their effective share (`Spread.discount`), and commits one (`add_view`): the best,
    or where other candidates come within a refit's scatter of it, the one of those farthest from
    the views taken and picked (`Spread.choose`, ``Pick.decided_by``). All views are scored with
    the band limit of the capture once the whole budget is added. Candidates at a view already
    taken (`TAKEN_COSINE`) do not compete. The texel subset and every tie are deterministic in
    ``config.seed``; ties go to the earliest candidate.

    Parameters
    ----------
    capture : Capture
        The views taken so far, the mesh and the environment map.
    candidates : sequence of Camera
        The cameras to choose from (`sample_candidates`, `load_candidates`).
    budget : int
        How many to choose, 1 .. the candidates that compete.
    config : Config
        Texture resolution of the estimate (the fit's estimation resolution) and the fit settings.
    fit : SurfaceFit or None
        The capture's whole-surface fit at ``config``'s resolution, reused when given; None fits it
        (`surface_fit`).
    max_texels : int
        Texels scored (a seeded random subset), >= 1.
    reporter : Reporter
        Progress of the fit and the picks.

    Returns
    -------
    list of Pick
        ``budget`` picks, in the order chosen.

    Raises
    ------
    ValueError
        If ``budget`` is out of range or ``max_texels`` < 1.

    Examples
    --------
    Two of twelve candidate views around a tiny synthetic capture (six 24 x 24 views of a
    sphere), scored on 32 x 32 texels (``freqbrdf next-views`` scores on the fit's estimation
    resolution):

    >>> import tempfile
    >>> from pathlib import Path
    >>> from freqbrdf.applications import sample_candidates, select_views
    >>> from freqbrdf.capture import load
    >>> from freqbrdf.config import Config, TexelConfig
    >>> from freqbrdf.synthetic import example_capture
    >>> work = tempfile.TemporaryDirectory()
    >>> capture = load(example_capture(Path(work.name) / "capture"))
    >>> candidates = sample_candidates(capture, 12)  # spread on a sphere around the object
    >>> picks = select_views(capture, candidates, 2, Config(texels=TexelConfig(texture_res=32)))
    >>> [pick.rank for pick in picks], len({pick.candidate for pick in picks})
    ([0, 1], 2)
    >>> all(pick.expected_uncertainty < pick.uncertainty_before for pick in picks)  # each lowers the mean std
    True
    >>> picks[0].camera.width, picks[0].camera.height  # the capture's intrinsics
    (24, 24)
    >>> work.cleanup()
    """
    taken = view_directions(capture, [frame.camera for frame in capture.frames])
    directions = view_directions(capture, candidates) if len(candidates) else np.zeros((0, 3))
    competing = [index for index, direction in enumerate(directions)
                 if float(np.max(taken @ direction)) < TAKEN_COSINE]
    if budget < 1:
        raise ValueError(f"budget must be at least 1, got {budget}")
    if budget > len(competing):
        raise ValueError(f"budget {budget} exceeds the {len(competing)} candidates away from the views taken")
    if fit is None:
        fit = surface_fit(capture, config, reporter)
    rows = texel_subset(fit.texels.n_texels, max_texels, config.seed)
    sigma = band_limit_sigma(len(capture.frames) + budget)
    model = uncertainty_model(capture, fit, rows, config, sigma)
    texels = subset_texels(fit.texels, rows)
    taken_information = view_information(capture, texels, fit, rows, [frame.camera for frame in capture.frames],
                                         sigma)
    state = initial_state(model, fit.observations.n_samples[rows], taken_information)
    information = view_information(capture, texels, fit, rows, [candidates[index] for index in competing], sigma)
    spread = Spread(len(rows), taken, directions[competing], [view.texel for view in taken_information])
    picks: list[Pick] = []
    remaining = list(range(len(competing)))
    total_area = float(model.area.sum())
    with reporter.stage("choosing views", budget) as advance:
        for rank in range(budget):
            start = time.perf_counter()
            before = expected_uncertainty(model, state)
            effective = [_discounted(information[index], spread.discount(index, information[index].texel))
                         for index in remaining]
            gains = np.array([view_gain(model, state, view, before) for view in effective])
            position, by_spread = spread.choose(gains, remaining, before)
            best, view = remaining[position], effective[position]
            unseen = state.samples[view.texel] < MIN_SAMPLES
            add_view(state, view)
            spread.add(best, view.texel)
            remaining.remove(best)
            picks.append(Pick(
                rank=rank, candidate=competing[best], camera=candidates[competing[best]],
                uncertainty_before=before, expected_uncertainty=before - float(gains[position]),
                unseen_area=float(model.area[view.texel[unseen]].sum() / total_area),
                texels_seen=len(view.texel), decided_by="spread" if by_spread else "gain",
                seconds=time.perf_counter() - start,
            ))
            advance(1)
    return picks


def surface_fit(capture: Capture, config: Config = Config(), reporter: Reporter = SILENT) -> SurfaceFit:
    """Fit a capture up to the whole-surface estimate, keeping what guidance reads.

    The steps of `freqbrdf.pipeline.fit` at ``config.texels.texture_res`` (pass the fit's
    estimation resolution there): observe, the ``global`` estimate, the whole-surface solve.

    Parameters
    ----------
    capture : Capture
        The capture.
    config : Config
        The fit's settings.
    reporter : Reporter
        Progress.

    Returns
    -------
    SurfaceFit
        Its observations, texels, per-texel and whole-surface estimates and posterior.
    """
    texels = rasterise(capture.mesh, config.texels.texture_res)
    observations = observe(capture, config, reporter, texels=texels)
    per_texel = estimate_materials(observations, config, reporter)
    estimate, posterior = whole_surface(observations, per_texel, texels, config)
    return SurfaceFit(observations, texels, per_texel, estimate, posterior)


# --------------------------------------------------------------------------------------------
# The model


def uncertainty_model(capture: Capture, fit: SurfaceFit, rows: np.ndarray, config: Config,
                      sigma: float) -> UncertaintyModel:
    """Build the posterior's std model on the scored texels from a whole-surface fit.

    The precisions, couplings and calibrations are those of `freqbrdf.estimate.surface`'s solve
    on this fit; the roughness precision per unit of information and the log-odds per unit of
    evidence are each texel's measured value over what its taken views give
    (`view_information` at the fit's band limit), the median of the estimated texels where a
    texel has none.

    Parameters
    ----------
    capture : Capture
        The capture fitted (its cameras and light).
    fit : SurfaceFit
        Its whole-surface fit (N texels).
    rows : (n,) int64
        The scored texels' rows in the fit.
    config : Config
        The fit's settings (``config.surface``).
    sigma : float
        The band limit to score views with.

    Returns
    -------
    UncertaintyModel
        On the n scored texels.
    """
    settings = config.surface
    observations, per_texel, posterior = fit.observations, fit.per_texel, fit.posterior
    estimated = per_texel.estimated
    # The solve's own graphs: roughness along the surface, the base colour with its look-alikes too.
    graph, _, color_graph = surface_graphs(fit.texels.position, fit.texels.normal,
                                           np.log(apparent_albedo(observations)), per_texel,
                                           observations.n_samples, settings)
    neighbours = np.asarray(graph.sum(axis=1)).ravel()
    color_neighbours = np.asarray(color_graph.sum(axis=1)).ravel()
    data = data_precision(observations, per_texel, posterior.metal_probability > 0.5, settings)
    noise, few, typical = data.noise, data.few, data.typical_samples
    roughness_precision, color_precision = data.roughness, data.color  # before the few-sample factor
    typical_noise = float(np.median(noise[estimated])) if estimated.any() else 1.0
    unseen_color_precision = lambert_scale(observations) ** 2 / typical_noise

    def coupling(precision: np.ndarray, smoothing: float, degree: np.ndarray) -> tuple[np.ndarray, float]:
        """Return the solve's lambda sum_j w_tj + pin, and lambda."""
        with_few = precision * (few[:, None] if precision.ndim == 2 else few)
        per_texel_mean = with_few.mean(axis=1) if with_few.ndim == 2 else with_few
        has_data = per_texel_mean > 0
        scale = float(np.median(per_texel_mean[has_data])) if has_data.any() else 1.0
        strength = smoothing * scale
        return degree * strength + PRIOR_PRECISION * strength, strength

    roughness_coupling, _ = coupling(roughness_precision, settings.roughness_smoothing, neighbours)
    color_coupling, _ = coupling(color_precision, settings.color_smoothing, color_neighbours)
    std_scale = settings.std_scale

    def calibration(std: np.ndarray, precision: np.ndarray, couple: np.ndarray) -> float:
        """s^2 of the solve: std^2 (P few + coupling) is the same for every texel with data."""
        has_data = precision > 0
        if not has_data.any():
            return 1.0
        return float(np.median((np.nan_to_num(std[has_data]) / std_scale) ** 2 * (precision[has_data] * few[has_data]
                                                                                    + couple[has_data])))

    roughness_scale = calibration(posterior.roughness_std.astype(np.float64), roughness_precision, roughness_coupling)
    # The base-colour std holds the label's doubt beside the solve's spread: calibrate on the spread.
    log_ratio, _, labelled = metal_evidence(per_texel, observations.n_samples)
    label_difference = labelled[1][:, :3] - labelled[0][:, :3]
    label_variance = posterior.metal_probability * (1.0 - posterior.metal_probability)
    color_spread = np.sqrt(np.maximum(posterior.base_color_std[:, 0].astype(np.float64) ** 2
                                      - label_variance * label_difference[:, 0] ** 2, 0.0))
    color_scale = calibration(color_spread, color_precision[:, 0], color_coupling)

    # What the views taken give, at the fit's own band limit: the measured precision per unit.
    fit_texels = subset_texels(fit.texels, rows)
    taken = view_information(capture, fit_texels, fit, rows, [frame.camera for frame in capture.frames],
                             observations.sigma)
    information = roughness_information(_summed(len(rows), taken, "fisher"))
    evidence = _summed(len(rows), taken, "metal_evidence")
    has_data = estimated[rows] & (information > 0) & (roughness_precision[rows] > 0)
    per_unit = float(np.median(roughness_precision[rows][has_data] / information[has_data])) if has_data.any() else 1.0
    base_information = information if sigma == observations.sigma else roughness_information(_summed(
        len(rows), view_information(capture, fit_texels, fit, rows, [frame.camera for frame in capture.frames],
                                    sigma), "fisher"))

    # The metal label: the texel's log-ratio (as the solve weighs it) per unit of its views' evidence.
    weighed = np.abs(log_ratio[rows]) / settings.noise_inflation
    measured = estimated[rows] & (evidence > 0)
    evidence_scale = np.zeros(len(rows))
    evidence_scale[measured] = weighed[measured] / np.sqrt(evidence[measured])
    evidence_scale[~measured] = float(np.median(evidence_scale[measured])) if measured.any() else 0.0

    # The solve's coupling is a multiple of its data texels' median P, and its calibration s^2, the
    # mean of P (estimate - solution)^2, grows with P where the scatter is the model's, not noise:
    # both follow the median precision (a view that adds to every texel alike changes no std).
    color = np.where(estimated[rows, None], color_precision[rows], unseen_color_precision[rows])
    # The same means as `texel_std` takes them, at the fit's own samples (so its factors are 1 there).
    counted = (observations.n_samples[rows] >= MIN_SAMPLES) & (roughness_precision[rows] > 0)
    roughness_level = float(np.median((roughness_precision[rows] * few[rows])[counted])) if counted.any() else 1.0
    color_level = float(np.median((color * few[rows, None]).mean(axis=1)[counted])) if counted.any() else 1.0

    prior = np.column_stack([posterior.roughness_std[rows], posterior.metallic_std[rows],
                             posterior.base_color_std[rows].mean(axis=1)]).astype(np.float64)
    return UncertaintyModel(
        rows=np.asarray(rows, np.int64), area=fit.texels.texel_area[rows].astype(np.float64),
        prior_std=np.nan_to_num(prior), fit_samples=observations.n_samples[rows].astype(np.int64),
        roughness_precision=roughness_precision[rows], roughness_per_unit=per_unit, base_information=base_information,
        roughness_coupling=roughness_coupling[rows],
        roughness_scale=roughness_scale, roughness_level=roughness_level,
        color_precision=color, color_coupling=color_coupling[rows], color_scale=color_scale,
        color_level=color_level, metal_probability=posterior.metal_probability[rows].astype(np.float64),
        border_variance=np.maximum(posterior.metallic_std[rows].astype(np.float64) ** 2
                                   - posterior.metal_probability[rows] * (1.0 - posterior.metal_probability[rows]), 0.0),
        label_color_difference=label_difference[rows],
        evidence_scale=evidence_scale, taken_evidence=evidence, typical_samples=typical, few_sample_power=settings.few_sample_power,
        std_scale=std_scale, sigma=sigma,
    )


def initial_state(model: UncertaintyModel, samples: np.ndarray,
                  taken: Sequence[ViewInformation]) -> GuidanceState:
    """Build the state of the views taken: their sample counts and Fisher information.

    Parameters
    ----------
    model : UncertaintyModel
        The model (n scored texels).
    samples : (n,) int
        The fit's sample counts of the scored texels.
    taken : sequence of ViewInformation
        What the views taken give, at the band limit the picks are scored with.

    Returns
    -------
    GuidanceState
        No metal evidence yet (the fit's own is in the label probability).
    """
    n_texels = len(model.rows)
    return GuidanceState(np.asarray(samples, np.int64).copy(), _summed(n_texels, taken, "fisher"),
                         np.zeros(n_texels))


def add_view(state: GuidanceState, view: ViewInformation) -> None:
    """Commit a view to the state (in place): one more sample, its information and evidence.

    Parameters
    ----------
    state : GuidanceState
        Updated in place.
    view : ViewInformation
        The view's samples at the texels it sees.
    """
    state.samples[view.texel] += 1
    state.fisher[view.texel] += view.fisher
    state.metal_evidence[view.texel] += view.metal_evidence


def state_with_views(state: GuidanceState, views: Sequence[ViewInformation]) -> GuidanceState:
    """Return the state with all of ``views`` added at once (the from-scratch sums of `add_view`).

    Parameters
    ----------
    state : GuidanceState
        The views taken (not changed).
    views : sequence of ViewInformation
        The views to add.

    Returns
    -------
    GuidanceState
        A new state.
    """
    n_texels = len(state.samples)
    counts = np.zeros(n_texels, np.int64)
    for view in views:
        counts[view.texel] += 1
    return GuidanceState(state.samples + counts,
                         state.fisher + _summed(n_texels, views, "fisher"),
                         state.metal_evidence + _summed(n_texels, views, "metal_evidence"))


def texel_std(model: UncertaintyModel, state: GuidanceState) -> np.ndarray:
    """Return the modelled posterior std of roughness, metallic and mean base colour per texel.

    Each texel's precision follows its samples (module docstring); the solve's calibration and
    coupling follow the median precision (`UncertaintyModel.roughness_level`): a view that adds to
    every texel alike changes little, one that adds where the precision lags does.

    Parameters
    ----------
    model : UncertaintyModel
        The model (n scored texels).
    state : GuidanceState
        The views taken and picked.

    Returns
    -------
    (n, 3) float64
        Roughness, metallic and the mean over RGB of base-colour std.
    """
    samples = state.samples
    # A texel becomes a data texel at MIN_SAMPLES samples; on the way there each sample is credited
    # its share of that change (a texel below it has no estimate of its own and keeps the prior).
    base = model.fit_samples
    fraction = np.where(base >= MIN_SAMPLES, 1.0,
                        np.clip((samples - base) / np.maximum(MIN_SAMPLES - base, 1), 0.0, 1.0))
    few = np.minimum(np.maximum(samples, MIN_SAMPLES) / model.typical_samples, 1.0) ** model.few_sample_power
    added = np.maximum(roughness_information(state.fisher) - model.base_information, 0.0)
    roughness_precision = (model.roughness_precision + model.roughness_per_unit * added) * few
    color_precision = model.color_precision * few[:, None]
    data = (fraction >= 1.0) & (roughness_precision > 0)
    roughness_level = _level(roughness_precision, data, model.roughness_level)
    color_level = _level(color_precision.mean(axis=1), data, model.color_level)
    roughness_var = (model.roughness_scale * roughness_level
                     / (roughness_precision + model.roughness_coupling * roughness_level))
    color_var = model.color_scale * color_level / (color_precision + model.color_coupling[:, None] * color_level)
    probability = np.clip(model.metal_probability, 1e-12, 1.0 - 1e-12)
    log_odds = np.log(probability / (1.0 - probability))
    # A label's log-ratio grows like the square root of the evidence (an ambiguous texel's
    # difference of losses is mostly misfit, which adds up like noise). A texel that becomes a data
    # texel weighs all its samples' evidence, the earlier ones too (until then its label was the
    # prior's and its neighbours'), credited on the way there as the other parameters are.
    earlier = np.where(base >= MIN_SAMPLES, np.sqrt(model.taken_evidence), 0.0)
    shift = model.evidence_scale * (np.sqrt(model.taken_evidence + state.metal_evidence) - earlier)
    data_metal_std = probability * _label_std(log_odds + shift) + (1.0 - probability) * _label_std(log_odds - shift)
    label_std = _label_std(log_odds)
    metal_std = np.sqrt((label_std + fraction * (data_metal_std - label_std)) ** 2 + model.border_variance)
    prior = model.prior_std
    roughness_std = prior[:, 0] + fraction * (np.sqrt(roughness_var) * model.std_scale - prior[:, 0])
    # The base colour's posterior is a mixture over the label (`freqbrdf.estimate.surface`).
    color_rgb = np.sqrt(color_var * model.std_scale ** 2 + (data_metal_std[:, None] * model.label_color_difference) ** 2)
    color_std = prior[:, 2] + fraction * (color_rgb.mean(axis=1) - prior[:, 2])
    return np.column_stack([roughness_std, metal_std, color_std])


def _level(precision: np.ndarray, data: np.ndarray, fit_level: float) -> float:
    """Return the median precision of the data texels over the fit's (1 without either)."""
    if not data.any() or fit_level <= 0:
        return 1.0
    return float(np.median(precision[data])) / fit_level


def texel_uncertainty(model: UncertaintyModel, state: GuidanceState) -> np.ndarray:
    """Return U_t = std_roughness + std_metallic + mean std_base_colour per texel.

    Parameters
    ----------
    model : UncertaintyModel
        The model (n scored texels).
    state : GuidanceState
        The views taken and picked.

    Returns
    -------
    (n,) float64
        U_t (`texel_std` summed).
    """
    return texel_std(model, state).sum(axis=1)


def expected_uncertainty(model: UncertaintyModel, state: GuidanceState) -> float:
    """Return the area-weighted mean of U_t over the scored texels.

    Parameters
    ----------
    model : UncertaintyModel
        The model.
    state : GuidanceState
        The views taken and picked.

    Returns
    -------
    float
        sum_t a_t U_t / sum_t a_t.
    """
    return float(np.dot(model.area, texel_uncertainty(model, state)) / model.area.sum())


def view_gain(model: UncertaintyModel, state: GuidanceState, view: ViewInformation,
              before: float | None = None) -> float:
    """Return the drop of the area-weighted mean U_t that a view adds; ``state`` is not changed.

    Parameters
    ----------
    model : UncertaintyModel
        The model.
    state : GuidanceState
        The views taken and picked.
    view : ViewInformation
        The candidate.
    before : float or None
        `expected_uncertainty` of ``state``, when known.

    Returns
    -------
    float
        expected_uncertainty(state) - expected_uncertainty(state with the view).
    """
    if before is None:
        before = expected_uncertainty(model, state)
    return before - expected_uncertainty(model, state_with_views(state, [view]))


# --------------------------------------------------------------------------------------------
# Helpers


def texel_subset(n_texels: int, max_texels: int, seed: int) -> np.ndarray:
    """Return sorted rows of at most ``max_texels`` texels, drawn without replacement (seeded).

    Parameters
    ----------
    n_texels : int
        Texels to draw from.
    max_texels : int
        How many at most, >= 1.
    seed : int
        The draw's seed.

    Returns
    -------
    (n,) int64
        Ascending rows.
    """
    if max_texels < 1:
        raise ValueError(f"max_texels must be at least 1, got {max_texels}")
    if n_texels <= max_texels:
        return np.arange(n_texels, dtype=np.int64)
    return np.sort(np.random.default_rng(seed).choice(n_texels, max_texels, replace=False)).astype(np.int64)


def subset_texels(texels: Texels, rows: np.ndarray) -> Texels:
    """Return the texels of ``rows`` only (the mask keeps just them).

    Parameters
    ----------
    texels : Texels
        N texels.
    rows : (n,) int64
        Rows to keep.

    Returns
    -------
    Texels
        n texels.
    """
    mask = np.zeros(texels.texture_res * texels.texture_res, dtype=bool)
    mask[texels.texel_index[rows]] = True
    names = ("texel_index", "face_id", "barycentric", "position", "normal", "tangent", "bitangent", "texel_area",
             "snapped")
    per_texel = {name: getattr(texels, name)[rows] for name in names}
    return dataclasses.replace(texels, mask=mask.reshape(texels.mask.shape), **per_texel)


def _summed(n_texels: int, views: Sequence[ViewInformation], name: str) -> np.ndarray:
    """(n, ...) float64: the views' ``name`` summed per texel, view by view in order."""
    shape = getattr(views[0], name).shape[1:] if len(views) else (FISHER_ENTRIES,) if name == "fisher" else ()
    total = np.zeros((n_texels, *shape))
    for view in views:
        total[view.texel] += getattr(view, name)
    return total


def _discounted(view: ViewInformation, share: np.ndarray) -> ViewInformation:
    """Return the view with its information and evidence scaled by each texel's effective share of a sample."""
    return ViewInformation(view.texel, view.fisher * share[:, None], view.metal_evidence * share)


def _label_std(log_odds: np.ndarray) -> np.ndarray:
    """sqrt(q (1 - q)), q = sigmoid(log_odds): the std of a label of that probability."""
    decay = np.exp(-0.5 * np.abs(log_odds))
    return decay / (1.0 + decay * decay)


