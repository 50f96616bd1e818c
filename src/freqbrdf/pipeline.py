"""The whole job on one capture: texels -> observations -> estimate -> uncertainty -> textures.

The pipeline of docs/method.md#pipeline. `fit` runs the stages in memory (`FitResult`; on coarser texels than
the maps' when ``TexelConfig.estimation_res`` says so, then `to_texels`); `write_fit` writes the
fit folder (`freqbrdf.outputs.export.write_fit_outputs`); `inpaint_fit` fills a fit's uncertain
texels (docs/method.md#inpainting). Reading a fit folder back and scoring it live in
`freqbrdf.outputs.fit_folder` and `freqbrdf.outputs.evaluate`.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy import ndimage

from freqbrdf.applications import guidance, inpaint
from freqbrdf.calibrate import Calibration, calibrate
from freqbrdf.capture.camera import Camera
from freqbrdf.capture.layouts import Capture, release_decoded_frames
from freqbrdf.config import Config
from freqbrdf.errors import InputError
from freqbrdf.estimate import MaterialEstimate
from freqbrdf.estimate import estimate as estimate_materials
from freqbrdf.estimate.censored import impute_censored
from freqbrdf.estimate.surface import merged_std, whole_surface
from freqbrdf.fileio import atomic_directory, write_json
from freqbrdf.images import write_png
from freqbrdf.model.materials import MaterialMaps, save_material_maps
from freqbrdf.observe.observations import Observations, observe
from freqbrdf.outputs import export, gltf
from freqbrdf.outputs.fit_folder import check_output_folder, load_fit
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.texels import Texels, rasterise
from freqbrdf.texels import estimation_resolution as texels_estimation_resolution
from freqbrdf.uncertainty import (
    FLAG_UNOBSERVED,
    AngularEntropy,
    Uncertainty,
    entropy_map,
    roughness_std,
)
from freqbrdf.uncertainty.heldout import StdCalibration, calibrate_std

# A fit whose photographs clip this share of the samples says so (a warning in summary.json and on the command line).
CENSORED_NOTE_FRACTION = 0.01
# A fit whose per-texel base colour reaches its bound of 1 on this share of the texels says the photographs
# look brighter than the map lights them (docs/results.md#calibration: far more often on photographs exposed
# above the map than on calibrated ones): what a capture whose gains are not estimated shows of an exposure mismatch.
BASE_BOUND_NOTE_FRACTION = 0.3
# A fit whose UV layout puts this share of the texels under two or more faces (overlapping or mirrored charts)
# says that their maps mix those parts of the surface.
UV_OVERLAP_NOTE_FRACTION = 0.01
# A base colour at least this is at its bound.
_BASE_AT_BOUND = 0.99


@dataclass(eq=False)
class FitResult:
    """A fit of one capture, in memory.

    Attributes
    ----------
    capture : Capture
        The capture fitted.
    observations : Observations
        The observations of its N texels (without samples where taken to finer texels).
    estimate : MaterialEstimate
        The material estimate of those texels.
    uncertainty : Uncertainty
        Their uncertainty.
    maps : MaterialMaps
        The hole-free T x T textures, as exported.
    timings : dict of str to float
        Seconds per stage; sub-stages are named ``"<stage>.<part>"``, ``total`` sums the stages.
    estimation_res : int or None
        The texture resolution observed and estimated on (`estimation_resolution`); below T, the
        observations, estimate and uncertainty above are its, taken to the T x T texels
        (`to_texels`).
    warnings : list of str
        What is suspicious about the capture (`freqbrdf.capture.checks`, the calibration's), for
        summary.json.
    calibration : Calibration or None
        What the photographs calibrated (`freqbrdf.calibrate`): the gains, the probe's turn; the
        observations were made of the capture corrected by it.
    std_calibration : StdCalibration or None
        How the held-out views scaled the std maps (`freqbrdf.uncertainty.heldout.calibrate_std`);
        None where ``UncertaintyConfig.heldout_folds`` is 0.
    observed_capture : Capture or None
        That corrected capture: what was observed.
    surface_fit : SurfaceFit or None
        With ``fit(..., keep_surface_fit=True)`` and the whole-surface estimate: the observations,
        per-texel and whole-surface estimates and posterior on the estimation texels, which
        `next_views` reuses; else None.
    censored_fraction : float
        The share of the samples with a clipped channel, read as lower bounds
        (docs/method.md#censored-samples); summary.json's ``coverage``.
    carry_hops : dict of str to float
        With the whole-surface estimate: per parameter ("roughness", "base_color"), how far its
        solve carries into texels no view sees (`freqbrdf.estimate.surface.shrink_unseen_to_charts`);
        empty without it.
    """

    capture: Capture
    observations: Observations
    estimate: MaterialEstimate
    uncertainty: Uncertainty
    maps: MaterialMaps
    timings: dict[str, float] = field(default_factory=dict)
    estimation_res: int | None = None
    warnings: list[str] = field(default_factory=list)
    calibration: Calibration | None = None
    std_calibration: StdCalibration | None = None
    observed_capture: Capture | None = None
    surface_fit: guidance.SurfaceFit | None = None
    censored_fraction: float = 0.0
    carry_hops: dict[str, float] = field(default_factory=dict)


def estimation_resolution(capture: Capture, config: Config = Config(), fine: Texels | None = None) -> int:
    """Return the texture resolution `fit` observes and estimates on (``TexelConfig.estimation_res``).

    Parameters
    ----------
    capture : Capture
        The capture; its cameras measure a pixel's width for "pixel" and "coarse".
    config : Config, optional
        The settings: ``texels.estimation_res`` ("full", "pixel", "coarse" or a whole number) and
        ``texels.texture_res`` T.
    fine : Texels, optional
        The mesh's texels at T, when already rasterised.

    Returns
    -------
    int
        The resolution, from 1 to T (`freqbrdf.texels.estimation_resolution` for "pixel" and
        "coarse").

    Raises
    ------
    ValueError
        If ``estimation_res`` is none of these or a number outside [1, T].
    """
    setting, texture_res = config.texels.estimation_res, config.texels.texture_res
    if setting == "full":
        return texture_res
    if setting in ("pixel", "coarse"):
        fine = rasterise(capture.mesh, texture_res) if fine is None else fine
        centres = np.array([frame.camera.camera_to_world[:3, 3] for frame in capture.frames]).reshape(-1, 3)
        focal = np.array([0.5 * (frame.camera.fx + frame.camera.fy) for frame in capture.frames])
        return texels_estimation_resolution(fine, centres, focal, setting)
    if isinstance(setting, bool) or not isinstance(setting, int) or not 1 <= setting <= texture_res:
        raise ValueError(f"estimation_res must be 'pixel', 'coarse', 'full' or a whole number from 1 to the "
                         f"texture resolution {texture_res}, got {setting!r}")
    return setting


def observe_on_estimation_texels(capture: Capture, config: Config = Config(),
                                 reporter: Reporter = SILENT) -> tuple[Observations, Texels | None]:
    """Observe a capture on the texels of `estimation_resolution`.

    Parameters
    ----------
    capture : Capture
        The capture.
    config : Config, optional
        The settings.
    reporter : Reporter, optional
        Receives progress.

    Returns
    -------
    observations : Observations
        The observations on the estimation texels.
    fine : Texels or None
        Where those are coarser than T, the mesh's T x T texels, to take the results there
        (`to_texels`, `uncertainty_to_texels`); else None.
    """
    texture_res = config.texels.texture_res
    # "pixel" and "coarse" measure the texels at T: rasterised once, and observed where they settle on T.
    fine = rasterise(capture.mesh, texture_res) if config.texels.estimation_res in ("pixel", "coarse") else None
    estimation_res = estimation_resolution(capture, config, fine)
    if estimation_res == texture_res:
        return observe(capture, config, reporter, texels=fine), None
    coarse = config.replace(texels=replace(config.texels, texture_res=estimation_res))
    return observe(capture, coarse, reporter), rasterise(capture.mesh, texture_res) if fine is None else fine


def fit(capture: Capture, config: Config = Config(), reporter: Reporter = SILENT,
        keep_surface_fit: bool = False) -> FitResult:
    """Observe, estimate, compute the uncertainty and make the textures (docs/method.md#pipeline).

    The first three run on the texels of `estimation_resolution` (`observe_on_estimation_texels`);
    where those are coarser than T, the results are then taken to the T x T texels (`to_texels`).
    With ``config.surface.enabled`` (the default) the ``global`` estimate becomes the whole-surface
    estimate after the uncertainty (`freqbrdf.estimate.surface`, docs/method.md#whole-surface-estimate), whose posterior
    gives the metallic std, the roughness std where it is wider than the spread of the texel's own
    estimate (`freqbrdf.uncertainty.roughness_std`), and the base-colour std with the distance of
    the texel's own estimate from the solution added in quadrature. With
    ``config.uncertainty.heldout_folds`` (the default) the roughness and base-colour std maps are
    then calibrated on the capture's held-out views (`freqbrdf.uncertainty.heldout.calibrate_std`,
    docs/method.md#held-out-std-calibration; ``FitResult.std_calibration``). Where photographs
    clip, a first estimate on the exact samples fills the censored channels
    (`freqbrdf.estimate.censored.impute_censored`, docs/method.md#censored-samples) before the estimate
    that reads every sample (``timings["censored"]``).

    Parameters
    ----------
    capture : Capture
        The capture.
    config : Config, optional
        The settings.
    reporter : Reporter, optional
        Receives progress.
    keep_surface_fit : bool, optional
        Keep the whole-surface fit on the estimation texels (``FitResult.surface_fit``) for
        `next_views`.

    Returns
    -------
    FitResult
        The observations, estimate, uncertainty, textures and seconds per stage.

    Raises
    ------
    ValueError
        If ``config.fit.lmax`` < 1 (the entropy compares degrees 1 .. l*).

    Examples
    --------
    A tiny synthetic capture (six 24 x 24 views of a sphere) fitted into 32 x 32 maps, and the fit
    folder written (`write_fit`) as ``freqbrdf fit`` writes it:

    >>> import tempfile
    >>> from pathlib import Path
    >>> from freqbrdf import pipeline
    >>> from freqbrdf.capture import load
    >>> from freqbrdf.config import Config, TexelConfig
    >>> from freqbrdf.synthetic import example_capture
    >>> work = tempfile.TemporaryDirectory()
    >>> capture = load(example_capture(Path(work.name) / "capture"))
    >>> config = Config(texels=TexelConfig(texture_res=32))
    >>> result = pipeline.fit(capture, config)
    >>> result.maps.base_color.shape, result.maps.roughness.shape, result.maps.metallic.shape  # T x T
    ((32, 32, 3), (32, 32), (32, 32))
    >>> result.observations.observed.shape  # (N, V, 3): N texels, V views
    (1024, 6, 3)
    >>> result.uncertainty.roughness_std.shape, result.uncertainty.base_color_std.shape  # (N,), (N, 3)
    ((1024,), (1024, 3))
    >>> folder = pipeline.write_fit(Path(work.name) / "fit", result, config)
    >>> sorted(path.name for path in folder.glob("*.exr"))
    ['base_color.exr', 'base_color_std.exr', 'entropy.exr', 'metallic.exr', 'metallic_std.exr',
     'roughness.exr', 'roughness_std.exr', 'trust.exr']
    >>> (folder / "material.glb").is_file(), (folder / "summary.json").is_file()
    (True, True)
    >>> work.cleanup()
    """
    if config.fit.lmax < 1:  # checked before the work: the entropy compares degrees 1..l*
        raise ValueError(f"fit needs FitConfig.lmax >= 1 (the entropy compares degrees 1..l*), got {config.fit.lmax}")
    timings: dict[str, float] = {}
    given = capture
    surface_fit = None
    start = time.perf_counter()
    capture, calibration = calibrate(capture, config, reporter)
    if config.calibration.enabled:
        timings["calibrate"] = time.perf_counter() - start
    start = time.perf_counter()
    observations, fine = observe_on_estimation_texels(capture, config, reporter)
    release_decoded_frames()  # every reader of the photographs is done
    estimation_res = observations.texture_res
    timings["observe"] = time.perf_counter() - start
    timings.update({f"observe.{stage}": seconds for stage, seconds in observations.timings.items()
                    if stage != "total"})  # "observe" is the total

    whole = config.surface.enabled and config.estimate.method == "global"
    texels = observations.texels if observations.texels is not None or not whole else rasterise(capture.mesh,
                                                                                                  estimation_res)
    censored_fraction, notes, censored_first, carry_hops = 0.0, [], None, {}
    if texels is not None and texels.overlap_texels >= UV_OVERLAP_NOTE_FRACTION * len(texels.texel_index):
        notes.append(f"{texels.overlap_texels / len(texels.texel_index):.0%} of the texels lie under two or more faces "
                     f"(overlapping or mirrored UV charts in {capture.mesh.path or 'the mesh'}): their maps mix those "
                     "parts of the surface; give the mesh non-overlapping UVs, or none (freqbrdf then unwraps it)")
    if observations.censored_weight is not None:  # clipped photographs: docs/method.md#censored-samples
        start = time.perf_counter()
        n_censored = int(np.count_nonzero(observations.censored_weight))
        censored_fraction = n_censored / max(n_censored + int(np.count_nonzero(observations.weight)), 1)
        if censored_fraction >= CENSORED_NOTE_FRACTION:
            notes.append(f"{censored_fraction:.1%} of the samples are clipped in a channel (8-bit photographs or blown "
                         "highlights): read as lower bounds; HDR photographs measure them")
        with reporter.stage("censored samples", 1) as advance:
            # Least squares without the neighbour vote: only the censored channels read this estimate.
            first_config = config.replace(estimate=replace(config.estimate, robust_passes=0, neighbour_vote=False))
            first = estimate_materials(observations, first_config)
            if whole:
                first, _ = whole_surface(observations, first, texels, first_config)
            observations = impute_censored(observations, first.principled(), config)
            censored_first = (np.asarray(observations.censored).any(axis=(1, 2)), first.base_color)
            advance(1)
        timings["censored"] = time.perf_counter() - start

    # The angular entropy's hypotheses are probed by the estimator's search anyway: scored on the way.
    angular = AngularEntropy(observations, config) if AngularEntropy.recorded_by_search(config) else None
    start = time.perf_counter()
    estimate = estimate_materials(observations, config, reporter, angular.recorder() if angular else None)
    timings["estimate"] = time.perf_counter() - start - (angular.seconds if angular else 0.0)
    at_bound = float(np.mean(np.any(estimate.base_color[estimate.estimated] >= _BASE_AT_BOUND, axis=1))
                     ) if estimate.estimated.any() else 0.0
    if at_bound >= BASE_BOUND_NOTE_FRACTION:
        notes.append(f"the base colour of {at_bound:.0%} of the texels reached its bound of 1: the photographs look "
                     "brighter than the environment map lights them (an exposure or envmap_scale mismatch?); "
                     "the base colour is clipped there")

    start = time.perf_counter()
    with reporter.stage("entropy", 1) as advance:
        uncertainty = (angular.result() if angular else
                       entropy_map(observations, config.uncertainty, estimate_config=config.estimate,
                                   device=config.device))
        uncertainty.roughness_std = roughness_std(observations, estimate, config)  # the texel's own spread
        advance(1)
    timings["uncertainty"] = time.perf_counter() - start + (angular.seconds if angular else 0.0)

    if whole:
        start = time.perf_counter()
        own_base_color = estimate.base_color
        with reporter.stage("whole-surface solve", 1) as advance:
            per_texel = estimate
            estimate, posterior = whole_surface(observations, estimate, texels, config)
            carry_hops = dict(posterior.carry_hops)
            if keep_surface_fit:
                surface_fit = guidance.SurfaceFit(observations, texels, per_texel, estimate, posterior)
            advance(1)
        uncertainty.roughness_std, uncertainty.metallic_std, uncertainty.base_color_std = merged_std(
            uncertainty.roughness_std, own_base_color, estimate, posterior)
        timings["surface"] = time.perf_counter() - start
        timings.update({f"surface.{step}": seconds for step, seconds in posterior.timings.items()})

    if censored_first is not None:
        _widen_by_censoring(uncertainty, estimate, *censored_first)
    std_calibration = None
    if config.uncertainty.heldout_folds:  # docs/method.md#held-out-std-calibration
        start = time.perf_counter()
        std_calibration = calibrate_std(observations, uncertainty, config, estimate)
        timings["std_calibration"] = time.perf_counter() - start
    # After the held-out views: every fold reads the photographs with the same gains, so none shows their error.
    _widen_by_calibration(uncertainty, estimate, calibration)

    if fine is not None:
        start = time.perf_counter()
        observations, estimate, uncertainty = to_texels(observations, estimate, uncertainty, fine,
                                                        config.texels.dilation_px)
        timings["upsample"] = time.perf_counter() - start

    start = time.perf_counter()
    maps = export.material_textures(estimate, config.texels.dilation_px)
    timings["textures"] = time.perf_counter() - start
    timings["total"] = sum(seconds for stage, seconds in timings.items() if "." not in stage)
    return FitResult(given, observations, estimate, uncertainty, maps, timings, estimation_res,
                     warnings=list(calibration.warnings) + notes, calibration=calibration,
                     std_calibration=std_calibration, observed_capture=capture, surface_fit=surface_fit,
                     censored_fraction=censored_fraction, carry_hops=carry_hops)


def next_views(result: FitResult, candidates: list[Camera], budget: int, config: Config = Config(), *,
               max_texels: int = guidance.MAX_TEXELS, reporter: Reporter = SILENT) -> list[guidance.Pick]:
    """Choose the next photographs of a fitted capture, reusing the fit's observations and solve.

    `freqbrdf.applications.guidance.select_views` on the capture as the fit observed it
    (calibrated), scored on the fit's estimation texels with its whole-surface fit: nothing is
    observed or estimated again (docs/method.md#guidance).

    Parameters
    ----------
    result : FitResult
        A fit made with ``keep_surface_fit=True`` (and the whole-surface estimate).
    candidates : list of Camera
        The cameras to choose from (`freqbrdf.applications.sample_candidates`, ``load_candidates``).
    budget : int
        How many to choose.
    config : Config, optional
        The fit's settings.
    max_texels : int, optional
        Texels scored (a seeded random subset).
    reporter : Reporter, optional
        Progress of the picks.

    Returns
    -------
    list of Pick
        ``budget`` picks, in the order chosen.

    Raises
    ------
    ValueError
        If the fit kept no whole-surface fit, or as `select_views` does.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from freqbrdf import pipeline
    >>> from freqbrdf.applications import sample_candidates
    >>> from freqbrdf.capture import load
    >>> from freqbrdf.config import Config, TexelConfig
    >>> from freqbrdf.synthetic import example_capture
    >>> work = tempfile.TemporaryDirectory()
    >>> capture = load(example_capture(Path(work.name) / "capture"))
    >>> config = Config(texels=TexelConfig(texture_res=32))
    >>> result = pipeline.fit(capture, config, keep_surface_fit=True)
    >>> picks = pipeline.next_views(result, sample_candidates(capture, 12), 2, config)
    >>> [pick.rank for pick in picks]
    [0, 1]
    >>> work.cleanup()
    """
    if result.surface_fit is None or result.observed_capture is None:
        raise ValueError("the fit kept no whole-surface fit: fit with keep_surface_fit=True and the whole-surface "
                         "estimate")
    scoring = config.replace(texels=replace(config.texels, texture_res=result.surface_fit.observations.texture_res))
    return guidance.select_views(result.observed_capture, candidates, budget, scoring, fit=result.surface_fit,
                                 max_texels=max_texels, reporter=reporter)


def _widen_by_censoring(uncertainty: Uncertainty, estimate: MaterialEstimate, rows: np.ndarray,
                        first_base_color: np.ndarray) -> None:
    """Add how far filling the censored channels moved the base colour to its std (docs/method.md#censored-samples).

    A texel with a censored sample reads values its first estimate filled in; the distance from that
    estimate's base colour (N, 3) to the final one is added in quadrature to the std of the ``rows``
    (N,) bool with a censored sample, per channel.
    """
    move = np.nan_to_num(np.asarray(first_base_color, np.float64) - estimate.base_color)
    widened = np.sqrt(np.asarray(uncertainty.base_color_std, np.float64) ** 2 + move ** 2)
    uncertainty.base_color_std = np.where(rows[:, None], widened, uncertainty.base_color_std).astype(np.float32)


def _widen_by_calibration(uncertainty: Uncertainty, estimate: MaterialEstimate, calibration: Calibration) -> None:
    """Add what the calibration leaves undetermined to the base colour's std (docs/method.md#calibration).

    A base colour b estimated from photographs divided by a gain whose log is off by a std s
    (`Calibration.gain_error_log_std`) is off by about b s: added in quadrature, per channel.
    """
    spread = np.nan_to_num(np.asarray(estimate.base_color, np.float64)) * calibration.gain_error_log_std[None, :]
    if not np.any(spread > 0.0):
        return
    own = (np.zeros_like(spread) if uncertainty.base_color_std is None
           else np.nan_to_num(np.asarray(uncertainty.base_color_std, np.float64)))
    uncertainty.base_color_std = np.sqrt(own ** 2 + spread ** 2).astype(np.float32)


def to_texels(observations: Observations, estimate: MaterialEstimate, uncertainty: Uncertainty, fine: Texels,
              dilation_px: int) -> tuple[Observations, MaterialEstimate, Uncertainty]:
    """Take a fit made on coarser texels to the texels of a finer T x T texture.

    Base colour, roughness and metallic are sampled bilinearly from the coarse estimate's
    hole-free textures (`freqbrdf.outputs.export.material_textures`, grown by ``dilation_px``
    across seams) at each fine texel's centre, and so is roughness_std; the rest as
    `uncertainty_to_texels`.

    Parameters
    ----------
    observations : Observations
        The coarse observations.
    estimate : MaterialEstimate
        The coarse estimate.
    uncertainty : Uncertainty
        The coarse uncertainty.
    fine : Texels
        The mesh's texels at T (N of them).
    dilation_px : int
        Rings of dilation of the coarse textures across seams.

    Returns
    -------
    observations : Observations
        On the fine texels, without samples (V = 0) or SH coefficients (K = 0; their spectra kept).
    estimate : MaterialEstimate
        On the fine texels; NaN where the coarse texel was not estimated.
    uncertainty : Uncertainty
        On the fine texels.
    """
    parent = _parent_texels(observations.texture_res, observations.texel_index, fine)
    sample = _bilinear_sampler(observations.texture_res, fine)
    fine_observations, fine_uncertainty = uncertainty_to_texels(observations, uncertainty, fine, dilation_px, parent)
    maps = export.material_textures(estimate, dilation_px)
    estimated = estimate.estimated[parent]
    has_value = np.isfinite(estimate.roughness)[parent]  # the whole-surface solve gives unseen texels values too

    def where_estimated(values):
        return np.where(has_value.reshape((-1,) + (1,) * (values.ndim - 1)), values, np.nan)

    fine_estimate = replace(
        estimate, texture_res=fine.texture_res, texel_index=fine.texel_index,
        base_color=where_estimated(np.stack([sample(maps.base_color[..., c]) for c in range(3)], axis=1)),
        roughness=where_estimated(sample(maps.roughness)), metallic=where_estimated(sample(maps.metallic)),
        estimated=estimated, loss=estimate.loss[parent],
        roughness_curvature=None if estimate.roughness_curvature is None else estimate.roughness_curvature[parent],
    )
    if uncertainty.roughness_std is not None:
        # Bilinear too, so that neighbouring fine texels are not ranked as ties; NaN (not
        # estimated) from the parent.
        spread = sample(export.roughness_std_texture(uncertainty, estimate, dilation_px)).astype(np.float32)
        fine_uncertainty.roughness_std = np.where(
            np.isfinite(uncertainty.roughness_std[parent]), spread, np.float32(np.nan))
    return fine_observations, fine_estimate, fine_uncertainty


def uncertainty_to_texels(observations: Observations, uncertainty: Uncertainty, fine: Texels, dilation_px: int,
                          parent: np.ndarray | None = None) -> tuple[Observations, Uncertainty]:
    """Take observations and their uncertainty on coarser texels to the texels of a finer texture.

    The entropy is sampled bilinearly from its hole-free texture (grown by ``dilation_px`` across
    seams) at each fine texel's centre, and is the coarse texel's (1) where unobserved;
    everything else per texel (spectra, sample counts, flags, likelihood, arg-max, roughness_std)
    comes from the coarse parent texel.

    Parameters
    ----------
    observations : Observations
        The coarse observations.
    uncertainty : Uncertainty
        Their uncertainty.
    fine : Texels
        The mesh's texels at T (N of them).
    dilation_px : int
        Rings of dilation of the entropy texture across seams.
    parent : (N,) int64, optional
        Per fine texel, the row of the coarse texel its centre lies in, or of the nearest covered
        one where that one is not covered; computed when not given.

    Returns
    -------
    observations : Observations
        On the fine texels, without samples or SH coefficients (`Observations.texel_fields`); the coarse
        ``observations`` hold them.
    uncertainty : Uncertainty
        On the fine texels.
    """
    if parent is None:
        parent = _parent_texels(observations.texture_res, observations.texel_index, fine)
    fine_observations = replace(observations.texel_fields(parent), texture_res=fine.texture_res,
                                texel_index=fine.texel_index)
    # np.take: a gather along the first axis; the same as indexing, several times faster on the (N, R, R) likelihood.
    changes = {name: np.take(getattr(uncertainty, name), parent, axis=0)
               for name in ("flags", "likelihood", "best_alpha", "best_ks", "channel", "roughness_std", "metallic_std",
                            "base_color_std")
               if getattr(uncertainty, name) is not None}
    # The entropy varies smoothly: bilinear, so that neighbouring fine texels are not ranked as ties.
    entropy_texture = export.entropy_texture(uncertainty, observations, dilation_px)
    entropy = _bilinear_sampler(observations.texture_res, fine)(entropy_texture).astype(np.float32)
    changes["entropy"] = np.where((changes["flags"] & FLAG_UNOBSERVED) != 0, uncertainty.entropy[parent], entropy)
    return fine_observations, replace(uncertainty, **changes)


def _bilinear_sampler(coarse_res: int, fine: Texels):
    """Make a function that samples a coarse texture bilinearly at the centres of ``fine``'s texels.

    The function maps (coarse_res, coarse_res) -> (N_fine,) float64, clamped at the border.
    """
    rows, columns = np.divmod(fine.texel_index, fine.texture_res)
    scale = coarse_res / fine.texture_res
    coordinates = np.stack([(rows + 0.5) * scale - 0.5, (columns + 0.5) * scale - 0.5])

    def sample(texture):
        return ndimage.map_coordinates(texture.astype(np.float64), coordinates, order=1, mode="nearest")

    return sample


def _parent_texels(coarse_res: int, coarse_index: np.ndarray, fine: Texels) -> np.ndarray:
    """Find each fine texel's parent: (N_fine,) int64 rows in ``coarse_index``.

    ``coarse_index`` lists a coarse_res x coarse_res texture's covered texels; the parent is the
    coarse texel the fine centre lies in, or the nearest covered coarse texel where that one is
    not covered.
    """
    if len(coarse_index) == 0:
        raise ValueError("no coarse texel to take the fine texels' values from")
    lookup = np.full(coarse_res * coarse_res, -1, np.int64)
    lookup[coarse_index] = np.arange(len(coarse_index))
    lookup = lookup.reshape(coarse_res, coarse_res)
    _, (nearest_row, nearest_column) = ndimage.distance_transform_edt(lookup < 0, return_indices=True)
    rows, columns = np.divmod(fine.texel_index, fine.texture_res)
    scale = coarse_res / fine.texture_res
    coarse_rows = np.minimum(((rows + 0.5) * scale).astype(np.int64), coarse_res - 1)
    coarse_columns = np.minimum(((columns + 0.5) * scale).astype(np.int64), coarse_res - 1)
    return lookup[nearest_row[coarse_rows, coarse_columns], nearest_column[coarse_rows, coarse_columns]]


def write_fit(out_dir: str | Path, result: FitResult, config: Config = Config()) -> Path:
    """Write the fit folder, replacing it as a whole, atomically.

    ``summary.json`` also records the capture, its layout, the estimation resolution, the
    capture's number of views, the warnings about it (``result.warnings``) and the time taken to
    write.

    Parameters
    ----------
    out_dir : str or Path
        The fit folder; it must not contain the capture.
    result : FitResult
        The fit; its ``timings`` gain ``write``.
    config : Config, optional
        The settings the fit was made with.

    Returns
    -------
    Path
        The fit folder.

    Raises
    ------
    InputError
        If ``out_dir`` would replace the capture's folder.
    """
    start = time.perf_counter()
    capture_root = Path(result.capture.root).resolve()
    check_output_folder(out_dir, {"the capture": capture_root})
    lenses = [frame.lens for frame in result.capture.frames if frame.lens is not None]
    extra = {"capture": str(capture_root), "layout": result.capture.layout,
             # The lenses the photographs were read through (docs/capture-format.md): None for pinholes.
             "lens": None if not lenses else {"frames": len(lenses), "distortions": [
                 {"model": lens.model, "radial": list(lens.radial), "tangential": list(lens.tangential)}
                 for lens in dict.fromkeys(lenses)]},
             "estimation_res": result.estimation_res or result.estimate.texture_res,
             # The views of the capture, also where the observations were taken to finer texels
             # without their samples (`to_texels`).
             "coverage": {**export.coverage(result.observations, result.estimate),
                          "views": len(result.capture.frames), "censored_fraction": result.censored_fraction},
             "warnings": list(result.warnings),
             "calibration": None if result.calibration is None else result.calibration.to_dict(),
             "std_calibration": None if result.std_calibration is None else result.std_calibration.to_dict(),
             # JSON has no infinity or NaN: null where nothing was measured, "inf" where it carries any distance.
             "unseen_carry_hops": {name: None if np.isnan(hops) else ("inf" if np.isinf(hops) else round(hops, 2))
                                   for name, hops in result.carry_hops.items()}}
    out = export.write_fit_outputs(
        out_dir, result.capture.mesh, result.observations, result.estimate, result.uncertainty,
        config, timings=result.timings, extra_summary=extra, maps=result.maps,
    )
    result.timings["write"] = time.perf_counter() - start
    # The write time is known only after the folder exists: record it in place (atomically).
    summary_path = out / export.FILES["summary"]
    summary = json.loads(summary_path.read_text(encoding="utf-8"))
    summary["timings"] = dict(result.timings)
    write_json(summary_path, summary)
    return out


def inpaint_fit(fit_dir: str | Path, out_dir: str | Path, settings: inpaint.InpaintSettings = inpaint.InpaintSettings(),
                capture: str | Path | None = None) -> Path:
    """Inpaint a fit folder's uncertain texels (docs/method.md#inpainting), writing a new folder atomically.

    Files: the three EXR maps and their PNG previews, ``mask.png`` (white: filled texels, grey:
    the rest of the atlas), ``material.glb`` (the capture's mesh with the new maps) and
    ``summary.json``.

    Parameters
    ----------
    fit_dir : str or Path
        The fit folder; it must hold the uncertainty.
    out_dir : str or Path
        The output folder, replaced as a whole.
    settings : InpaintSettings, optional
        The mask's entropy threshold (None: the flags), the fill backend and the maps to fill.
    capture : str or Path, optional
        Where the mesh comes from; default the fit's capture.

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    InputError
        If the threshold is outside [0, 1], the fit folder is unreadable or has no uncertainty,
        or no capture is known.
    """
    from freqbrdf.capture.layouts import load

    if settings.threshold is not None and not 0.0 <= settings.threshold <= 1.0:
        raise InputError(None, f"threshold must lie in [0, 1] (normalised entropy), got {settings.threshold}")
    start = time.perf_counter()
    fit = load_fit(fit_dir)
    for name in ("flags", "entropy"):
        if name not in fit.arrays:
            raise InputError(fit.folder / export.FILES["uncertainty"], "missing: the fit has no uncertainty to mask by")
    capture_path = capture if capture is not None else fit.capture_path
    if capture_path is None:
        raise InputError(fit.folder / export.FILES["summary"], "names no capture: pass --capture")
    mesh = load(capture_path).mesh
    fill = inpaint.load_diffusion_fill(settings) if settings.backend == "diffusion" else inpaint.biharmonic_fill
    resolution = fit.maps.resolution
    atlas = np.zeros(resolution * resolution, bool)
    atlas[fit.texel_index] = True
    atlas = atlas.reshape(resolution, resolution)
    mask = inpaint.inpaint_mask(atlas, fit.texel_index, fit.arrays["flags"], fit.arrays["entropy"], settings.threshold)
    dilation = int(fit.summary.get("settings", {}).get("texels", {}).get("dilation_px", 8))
    result = inpaint.inpaint_maps(fit.maps, atlas, mask, fill, settings.maps, dilation)
    seconds = time.perf_counter() - start
    summary = {
        "fit": str(fit.folder.resolve()),
        "capture": str(Path(capture_path).resolve()),
        "settings": asdict(settings),
        "mask": "flags unobserved|ambiguous" if settings.threshold is None
                else f"flag unobserved or entropy >= {settings.threshold}",
        "atlas_texels": int(atlas.sum()),
        "masked_texels": int(mask.sum()),
        "masked_fraction": float(mask.sum() / max(atlas.sum(), 1)),
        "charts": result.charts,
        "unfilled_texels": result.unfilled_texels,
        "seconds": seconds,
    }
    with atomic_directory(out_dir) as folder:
        save_material_maps(folder, result.maps)
        export.write_material_previews(folder, result.maps)
        gltf.write_gltf(folder / export.FILES["gltf"], mesh, result.maps)
        write_png(folder / inpaint.MASK_PNG, np.where(mask, 1.0, np.where(atlas, 0.25, 0.0)).astype(np.float32))
        write_json(folder / export.FILES["summary"], summary)
    return Path(out_dir)
