"""Calibration from the photographs themselves: exposure, white balance, per-frame gains, the probe's turn.

docs/method.md#calibration. A real capture's light probe is shot at another exposure and white
balance than the object's photographs, some photographs at other shutter speeds, and the probe
is turned into place by hand. `calibrate` estimates these on the texels of a coarse texture
(``CalibrationConfig.texture_res``: a few thousand texels, so that every hypothesis costs
milliseconds) and returns the capture corrected (each frame's ``exposure``, the map's rotation)
with a `Calibration` that says what was found and how well the photographs determine it:

1. each camera's pose (`freqbrdf.calibrate.cameras`), so that the mesh's outline falls on the
   photograph's mask's edge;
2. relative gains per photograph (`freqbrdf.calibrate.gains.frame_gains`), where asked
   (``CalibrationConfig.frame_gains``), each applied where likelier off the others than alike;
3. one gain per colour channel between the photographs and the map
   (`freqbrdf.calibrate.gains.channel_gains`), with the materials: up to `GAIN_PASSES` times,
   each on photographs corrected by the passes before, since the roughness the search finds
   depends on the gain; the exposure then read again on the texels found dielectric (metals and
   part-metals over-read it), last, on the capture as registered;
4. the map's turn (`freqbrdf.calibrate.probe`), by the model's loss on photographs at the map's
   scale; where the map is turned, the gains again from there.

Sits after `freqbrdf.estimate` (it searches the coarse texels) and before the fit that uses it
(`freqbrdf.pipeline.fit`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from freqbrdf.calibrate.cameras import BAD_OUTLINE_PX, MASK_OFFSET_PX, CameraRefinement, refine_cameras
from freqbrdf.calibrate.gains import (  # noqa: F401  (the decision rules' names, also read through this package)
    FRAME_MODEL_LOG_STD,
    FRAME_PRIOR_LOG_STD,
    MODEL_RATIO_LOG_STD,
    PRIOR_LOG_STD,
    WHITE_BALANCE_PRIOR_LOG_STD,
    GainEstimate,
    _applied,
    _decision_log_std,
    _decision_variance,
    _likelier_off,
    _significant,
    _significant_frames,
    _with_selection,
    channel_gains,
    frame_gains,
    slab_log_odds,
)
from freqbrdf.calibrate.probe import ProbeRegistration, axis_angle, convention_turn, register_probe, rotation_about
from freqbrdf.capture.layouts import Capture, read_frame_mask_coverage
from freqbrdf.config import Config
from freqbrdf.estimate import label_sums
from freqbrdf.observe.observations import Observations, observe
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.sphere import envmap as envmaps
from freqbrdf.sphere import harmonics as sh
from freqbrdf.texels import rasterise

__all__ = ["Calibration", "CameraRefinement", "GainEstimate", "ProbeRegistration", "axis_angle", "calibrate", "channel_gains",
           "convention_turn", "frame_gains", "refine_cameras", "register_probe",
           "rotation_about"]

# Passes of the channel gains (each on photographs corrected by the ones before); they stop early
# where a pass moves the exposure by less than CONVERGED and each white-balance ratio by less than
# RATIO_CONVERGED (in log). The white balance moves in the first RATIO_PASSES only, the exposure in all
# (it converges slowly: the roughness follows the gain part of the way, docs/results.md#calibration);
# a ratio moves where a pass reads it at least RATIO_STEP_STD times the texels' scatter (`_gain_step`).
CONVERGED = 0.005
RATIO_CONVERGED = 0.01
RATIO_PASSES = 5
RATIO_STEP_STD = 1.0
GAIN_PASSES = 10
# A texel seen in more views than this calibrates with this many of its samples, evenly over its views:
# what the gains and the turn read is the model's misfit on each texel, which more samples of the same
# texel do not average away, while the searches' time grows with them (docs/results.md#calibration).
MAX_VIEWS = 32
# The gains read again on the texels the passes' last search finds dielectric (metallic at most
# DIELECTRIC_MAX_METALLIC) with a lobe told from the diffuse (roughness at most DIELECTRIC_MAX_ROUGHNESS):
# the texels of every label over-read it where metals and part-metals pass for dielectrics (their
# specular is stronger than F0 = 0.04 allows) and under-read it where rough dielectrics pass for
# smoother ones; on the dielectrics the model's misfit is DIELECTRIC_EXPOSURE_LOG_STD
# (docs/results.md#calibration). Read where at least MIN_DIELECTRIC_TEXELS of them are found, in up
# to DIELECTRIC_PASSES passes on the same texels, each step the last one's over the contraction the
# passes measure (the roughness follows the gain part of the way; at least CONTRACTION_FLOOR); the
# dielectrics are picked DIELECTRIC_PICKS times, each at the gains the last reading reached.
DIELECTRIC_MAX_METALLIC = 0.05
DIELECTRIC_MAX_ROUGHNESS = 0.3
MIN_DIELECTRIC_TEXELS = 100
DIELECTRIC_PASSES = 4
DIELECTRIC_PICKS = 2
DIELECTRIC_EXPOSURE_LOG_STD = 0.05
CONTRACTION_FLOOR = 0.25
# Where photographs clip, the white balance reads the texels without a clipped sample
# (`_exact_texels`), the exposure then every seen texel with its clipped samples left out
# (`_read_clipped_gains`); both selections bias the gains: this much log std per unit share of the
# seen texels with a clipped sample (`_clipped_share`) is added to the exposure's and each ratio's
# (the calibration study's clipped captures, docs/results.md#calibration).
CENSORED_SELECTION_LOG_STD = 0.4
# A gain whose log std exceeds this is poorly determined by the capture (named in a warning).
POORLY_DETERMINED = 0.15
# The passes recover an exposure from gain 1 within a factor of about 20 either way (a map in absolute
# units beside photographs in [0, 1] lies orders beyond: the passes settle on a wrong white balance,
# docs/results.md#calibration). Where the photographs' radiance over what a surface of TYPICAL_ALBEDO
# reflects of its irradiance (`_exposure_order`) lies beyond FAR_EXPOSURE either way, the passes
# start from it.
TYPICAL_ALBEDO = 0.3
FAR_EXPOSURE = 10.0
# Where the gains cannot be estimated (too few samples a texel, masks inside the outline) but the
# photographs' order of magnitude lies beyond FAR_EXPOSURE, it is applied with this log std (the
# calibration study's clean captures read 0.59-1.47 at gain 1).
ORDER_LOG_STD = 0.5
# The gains need texels whose samples tell a dielectric's diffuse from its fixed specular: below this
# median of samples per seen texel they read the model's misfit, not the exposure
# (docs/results.md#calibration), and are not estimated (the map's scale is kept, with a warning).
MIN_GAIN_SAMPLES = 8
# A frame whose gain is beyond this factor of the others (either way) is one calibration cannot
# trust: named in a warning, dropped with ``drop_bad_views``.
BAD_FRAME_FACTOR = 2.0


@dataclass
class Calibration:
    """What `calibrate` found.

    Attributes
    ----------
    gain : (3,) float64
        The photographs' radiance over the map's per colour channel (exposure x white balance) as
        applied: the fit divides the photographs by it.
    gain_log_std : (3,) float64
        The std of each log gain.
    gain_measured : (3,) float64 or None
        The gains as measured; the exposure and white-balance ratios the texels do not tell from
        1 (`_significant`) are not applied.
    gain_error_log_std : (3,) float64
        The std of the applied log gains' error (`_decision_log_std`): about ``gain_log_std``
        where a gain is applied; where it is not, that std weighed by how likely the gain is off 1
        after all. What the base colour's std takes in.
    frame_gain : (V, 3) float64 or None
        Relative gain per photograph and channel (geometric mean 1), where measured and applied.
    probe : ProbeRegistration or None
        The map's turn, where searched.
    cameras : CameraRefinement or None
        The cameras' corrections, where refined.
    dropped_views : list of int
        Photographs left out (``CalibrationConfig.drop_bad_views``).
    texels : int
        Texels that read the exposure: the dielectrics where they read it (`_dielectric_gains`),
        else every texel that determines a gain.
    exposure_from : str
        Which texels read the exposure (and, where no clipping left texels out, the white
        balance): "dielectrics", "every texel" (fewer than `MIN_DIELECTRIC_TEXELS` dielectrics
        found) or "" (the gains not estimated).
    samples_per_texel : float
        The median over the seen coarse texels of the views that see each (clipped samples
        included); the gains are estimated from `MIN_GAIN_SAMPLES` on.
    seconds : float
        Time taken.
    warnings : list of str
        What the user should know (a gain far from 1, a turned probe, a poorly determined gain).
    """

    gain: np.ndarray
    gain_log_std: np.ndarray
    gain_measured: np.ndarray | None = None
    gain_error_log_std: np.ndarray = field(default_factory=lambda: np.zeros(3))
    frame_gain: np.ndarray | None = None
    probe: ProbeRegistration | None = None
    cameras: CameraRefinement | None = None
    dropped_views: list[int] = field(default_factory=list)
    texels: int = 0
    exposure_from: str = ""
    samples_per_texel: float = 0.0
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)

    @property
    def exposure(self) -> float:
        """The overall gain: the geometric mean of the three."""
        return float(np.exp(np.log(self.gain).mean()))

    @property
    def white_balance(self) -> np.ndarray:
        """(3,) the gains over their geometric mean."""
        return self.gain / self.exposure

    def to_dict(self) -> dict:
        """Give the calibration as plain data, as summary.json records it.

        Returns
        -------
        dict
            ``gain`` (applied) and ``gain_std`` (per channel; the std of the gain itself),
            ``gain_error_std`` (the std of the applied gain's error, `gain_error_log_std`),
            ``gain_measured``, ``exposure``,
            ``white_balance``, ``frame_gains`` (per view, where measured and applied, or None),
            ``probe`` (the turn: ``angle_deg``, ``axis``, ``std_deg``, ``rotation``, the model's ``loss``
            at the registration given and at the turn found over the first, ``log_odds``,
            ``convention_deg``: the turn of the map's convention within it; or None),
            ``cameras`` (per view, see `CameraRefinement.to_dict`; or None), ``dropped_views``,
            ``texels``, ``exposure_from``,
            ``samples_per_texel``, ``seconds``.
        """
        probe = None
        if self.probe is not None:
            axis, _ = axis_angle(self.probe.rotation)
            probe = {"angle_deg": self.probe.angle_deg, "axis": axis.tolist(),
                     "std_deg": None if not np.isfinite(self.probe.std_deg) else self.probe.std_deg,
                     "rotation": self.probe.rotation.tolist(), "loss": list(self.probe.loss),
                     "log_odds": self.probe.log_odds, "convention_deg": self.probe.convention_deg}
        return {
            "gain": self.gain.tolist(), "gain_std": (self.gain * self.gain_log_std).tolist(),
            "gain_error_std": (self.gain * self.gain_error_log_std).tolist(),
            "gain_measured": None if self.gain_measured is None else self.gain_measured.tolist(),
            "exposure": self.exposure, "white_balance": self.white_balance.tolist(),
            "frame_gains": None if self.frame_gain is None else self.frame_gain.tolist(),
            "probe": probe, "cameras": None if self.cameras is None else self.cameras.to_dict(),
            "dropped_views": list(self.dropped_views), "texels": self.texels, "exposure_from": self.exposure_from,
            "samples_per_texel": self.samples_per_texel, "seconds": self.seconds,
        }

    def summary_line(self) -> str:
        """One line for the command line: the gains with their std, and the probe's turn."""
        std = self.gain * self.gain_log_std
        gains = ", ".join(f"{g:.3f}±{s:.3f}" for g, s in zip(self.gain, std))
        line = f"calibration: gain (R, G, B) {gains}"
        if self.frame_gain is not None:
            spread = np.exp(np.abs(np.log(self.frame_gain)).max())
            line += f"; frame gains applied (up to {spread:.2f}x)"
        if self.cameras is not None and self.cameras.refined.any():
            moved = self.cameras.turn_deg[self.cameras.refined]
            line += f"; cameras refined (median turn {np.median(moved):.2f}°, largest {moved.max():.2f}°)"
            median = self.cameras.median_mask_offset_px
            if median != 0.0:
                line += f"; masks {abs(median):.1f} px {'wider' if median > 0 else 'narrower'} than the object"
        if self.probe is not None:
            line += f"; probe turned {self.probe.angle_deg:.1f}°" if self.probe.angle_deg > 0.0 else "; probe kept"
        return line


def _scaled(observations: Observations, divisor: np.ndarray, config: Config) -> Observations:
    """Return the observations of photographs divided by ``divisor`` ((3,) per channel, or (V, 3) per view).

    Per channel the fits scale with the samples; per view the observed radiance is fitted again.
    """
    divisor = np.asarray(divisor, np.float64)
    if np.all(divisor == 1.0):
        return observations
    observed = (observations.observed / (divisor if divisor.ndim == 1 else divisor[None])).astype(np.float32)
    surface = observations.mirror_surface
    if divisor.ndim == 1:
        coeffs = (observations.observed_coeffs / divisor[None, :, None]).astype(np.float32)
        if surface is not None:
            surface = (surface / divisor).astype(np.float32)
        return replace(observations, observed=observed, observed_coeffs=coeffs, mirror_surface=surface)
    settings = config.fit
    fit = sh.fit_sh(observations.view_direction, observations.weight, observed, observations.lmax,
                    settings.reg_lambda, settings.regulariser, settings.scale_lambda_with_weight, config.device)
    return replace(observations, observed=observed, observed_coeffs=fit.coeffs)


def _at_most_views(observations: Observations, every: Observations) -> tuple[Observations, Observations]:
    """Return both observations with at most `MAX_VIEWS` samples a texel (`Observations.at_most_views`), alike where the same."""
    thinned = observations.at_most_views(MAX_VIEWS)
    return thinned, (thinned if every is observations else every.at_most_views(MAX_VIEWS))


def _search_config(config: Config) -> Config:
    """Return the estimator's settings for calibration: least squares on the coarse texels."""
    return config.replace(estimate=replace(config.estimate, robust_passes=0, neighbour_vote=False))


def calibrate(capture: Capture, config: Config = Config(),
              reporter: Reporter = SILENT) -> tuple[Capture, Calibration]:
    """Estimate what the photographs say of the capture's calibration, and correct the capture.

    Parameters
    ----------
    capture : Capture
        The capture as given.
    config : Config, optional
        ``config.calibration`` says what to calibrate; the rest how the coarse texels are observed
        and searched.
    reporter : Reporter, optional
        Receives progress.

    Returns
    -------
    capture : Capture
        The capture corrected: each frame's ``exposure`` (1 / (gain x frame gain)), its refined
        camera and, where its mask is wider than the object, ``mask_inset_px``; the map turned, bad
        views dropped where asked. The same object where nothing is calibrated.
    calibration : Calibration
        What was found.
    """
    settings = config.calibration
    start = time.perf_counter()
    calibration = Calibration(np.ones(3), np.zeros(3))
    if not settings.enabled:
        return capture, calibration
    coarse_config = config.replace(texels=replace(config.texels, texture_res=settings.texture_res))
    texels = rasterise(capture.mesh, settings.texture_res)
    with reporter.stage("calibrating", 4) as advance:
        if settings.cameras:
            calibration.cameras = refine_cameras(capture.mesh, [frame.camera for frame in capture.frames],
                                                 (read_frame_mask_coverage(frame) for frame in capture.frames))
            capture = _refined(capture, calibration.cameras)
        advance(1)
        every = observe(capture, coarse_config, texels=texels)
        search = _search_config(coarse_config)
        start_gain = _gains_start(every)
        convention = (convention_turn(_scaled(every, start_gain, config), search.estimate,
                                      settings.probe_search_deg) if settings.probe_rotation else np.eye(3))
        if not np.array_equal(convention, np.eye(3)):  # a map of another convention: observed again
            capture = _turned(capture, convention)
            every = observe(capture, coarse_config, texels=texels)
        observations = _exact_texels(every)
        dropped_share = _clipped_share(every) if observations is not every else 0.0
        views = np.count_nonzero(every.visible, axis=1)  # clipped samples included: views are what it counts
        calibration.samples_per_texel = float(np.median(views[views > 0])) if views.any() else 0.0
        advance(1)
        if settings.frame_gains == "on":
            calibration.frame_gain = _significant_frames(*frame_gains(
                observations.view_direction, observations.weight, observations.observed))
            observations = _scaled(observations, calibration.frame_gain, config)
            every = _scaled(every, calibration.frame_gain, config) if dropped_share > 0.0 else observations
        observations, every = _at_most_views(observations, every)
        estimate_gains = (settings.gains and calibration.samples_per_texel >= MIN_GAIN_SAMPLES
                          and not _masks_inside(calibration))
        gain, found, on_dielectrics = (_read_clipped_gains(observations, every, search, start_gain, config)
                                       if estimate_gains else (np.ones(3), None, False))
        # Not estimated, a map orders of magnitude off still takes the photographs' order of magnitude.
        from_order = settings.gains and not estimate_gains and not np.all(start_gain == 1.0)
        if from_order:
            gain = start_gain
        if settings.probe_rotation:
            # On photographs at the map's scale: a wrong exposure or white balance would bend the turn.
            # Every seen texel scores it, its clipped samples left out: leaving out the texels with a
            # clipped sample would keep those whose views met no bright part of the map, a selection
            # by where the light is that a turn can explain (docs/results.md#calibration).
            calibration.probe = register_probe(_scaled(every, gain, config), search.estimate,
                                               settings.probe_search_deg,
                                               found.exposure_log_std if found is not None else 0.0)
            turned = calibration.probe.angle_deg > 0.0
            if turned:
                capture = _turned(capture, calibration.probe.rotation)
            calibration.probe = _after(calibration.probe, convention)
            if turned:
                every = observe(capture, coarse_config, texels=texels)
                if calibration.frame_gain is not None:
                    every = _scaled(every, calibration.frame_gain, config)
                observations, every = _at_most_views(_exact_texels(every), every)
                if estimate_gains:  # read again under the map as registered (a turn moves every reading)
                    gain, found, on_dielectrics = _read_clipped_gains(observations, every, search, gain, config)
        if found is not None:
            calibration.exposure_from = "dielectrics" if on_dielectrics else "every texel"
        advance(1)
        log_std, scored = np.zeros(3), 0
        if found is not None:
            calibration.gain_measured = gain
            found = _with_selection(found, CENSORED_SELECTION_LOG_STD * dropped_share)
            log_std, scored = found.log_std, found.texels
            calibration.gain_error_log_std = _decision_log_std(gain, found)
            gain = _significant(gain, found)
        if from_order:
            log_std = calibration.gain_error_log_std = np.full(3, ORDER_LOG_STD)
        calibration.gain, calibration.gain_log_std, calibration.texels = gain, log_std, scored
        advance(1)
    calibration.warnings = _warnings(capture, calibration, settings)
    capture = _corrected(capture, calibration, settings.drop_bad_views)
    calibration.seconds = time.perf_counter() - start
    return capture, calibration


def _exposure_order(observations: Observations) -> float:
    """Return the photographs' scale against the map's to an order of magnitude (1: alike).

    The median over the seen samples of the radiance over what a Lambertian surface of
    `TYPICAL_ALBEDO` reflects of the texel's irradiance E / pi: within a factor of a few of the
    gain wherever the albedos lie in 0.05-1 (NaN where no sample is seen or lit).
    """
    irradiance = observations.irradiance.astype(np.float64).mean(axis=1)
    lit = (observations.weight > 0.0) & (irradiance > 0.0)[:, None]
    if not lit.any():
        return float("nan")
    texel, view = np.nonzero(lit)
    radiance = observations.observed[texel, view].astype(np.float64).mean(axis=1)
    return float(np.median(radiance / (TYPICAL_ALBEDO * irradiance[texel] / np.pi)))


def _gains_start(observations: Observations) -> np.ndarray:
    """Return (3,) the gains the passes start from: 1, or `_exposure_order` where beyond `FAR_EXPOSURE`."""
    order = _exposure_order(observations)
    far = np.isfinite(order) and order > 0.0 and abs(np.log(order)) > np.log(FAR_EXPOSURE)
    return np.full(3, order) if far else np.ones(3)


def _read_clipped_gains(exact: Observations, every: Observations, search: Config, start: np.ndarray,
                        config: Config) -> tuple[np.ndarray, GainEstimate, bool]:
    """Return the gains from ``start`` on, their estimate, and whether the dielectrics read the exposure.

    ``exact``: the texels without a clipped sample (`_exact_texels`), ``every``: every seen texel
    with its clipped samples at weight 0. Without clipping (``exact`` is ``every``), `_read_gains`.
    With it, the white balance is read on ``exact`` by every texel's passes (`_channel_gains`; the
    smooth dielectrics left there are those whose highlights stayed under the ceiling in every
    channel, their colour the ceiling's choice), then the exposure on ``every`` from there, the
    ratios kept (`_read_gains`, the dielectrics' exposure included): the texels without a clipped
    sample are the darker ones, a selection that biased the exposure (docs/results.md#calibration),
    while the clipped samples' own selection is by colour (one channel clips first), which the
    exposure does not see.
    """
    if exact is every:
        return _read_gains(exact, search, start, config, True)
    gain, found, _ = _channel_gains(exact, search, start, config)
    gain, exposure, on_dielectrics = _read_gains(every, search, gain, config, False, ratios=False)
    return gain, _with_selection(replace(exposure, ratio_log_std=np.zeros(3)), 0.0, found.ratio_log_std), on_dielectrics


def _read_gains(observations: Observations, search: Config, start: np.ndarray, config: Config,
                white_balance: bool, ratios: bool = True) -> tuple[np.ndarray, GainEstimate, bool]:
    """Return the gains from ``start`` on, their estimate, and whether the dielectrics read them.

    The passes on every texel (`_channel_gains`; the white-balance ratios only where ``ratios``),
    then the dielectrics' reading from there (`_dielectric_refined`; the white balance too where
    ``white_balance``).
    """
    gain, found, last_search = _channel_gains(observations, search, start, config, ratios)
    return _dielectric_refined(observations, search, gain, found, config, last_search, white_balance)


def _channel_gains(observations: Observations, search: Config, start: np.ndarray, config: Config,
                   ratios: bool = True) -> tuple[np.ndarray, GainEstimate, tuple[np.ndarray, np.ndarray] | None]:
    """Return the gains measured from ``start`` on, the last pass's estimate and the passes' last search.

    The estimate's std is widened by the passes' scatter; the search (`label_sums`'s params and
    sums) is returned where the passes settled, else None. Up to `GAIN_PASSES` passes, each on the
    photographs divided by the gains so far, until a pass moves the exposure by less than
    `CONVERGED` and each ratio by less than `RATIO_CONVERGED`; after
    `RATIO_PASSES` (without ``ratios``: from the first) a pass moves the exposure only (the ratios'
    chance steps would walk). Near the
    gains a pass moves them by what the texels it selects say at random (the roughness moves, and
    with it which texels calibrate), and such steps multiplied together can walk away: the spread of
    the exposure the passes after the first arrive at is added to the exposure's std, that of each
    white-balance ratio over the passes that moved it to the ratio's (`_with_selection`), so that
    such a walk is not taken for a gain.
    """
    gain = np.asarray(start, np.float64)
    current = _scaled(observations, gain, config)
    arrived = []
    settled = False
    for index in range(GAIN_PASSES):
        params, sums = label_sums(current, search)
        found = channel_gains(sums, params[:, 3])
        log_step = _gain_step(found, ratios and index < RATIO_PASSES)
        gain = gain * np.exp(log_step)
        arrived.append(np.log(gain))
        if abs(log_step.mean()) < CONVERGED and np.all(np.abs(log_step - log_step.mean()) < RATIO_CONVERGED):
            settled = True  # the roughness the search found no longer moves with the gain: its texels stand
            break
        current = _scaled(observations, gain, config)
    arrived = np.array(arrived)  # (passes, 3)
    exposure = arrived.mean(axis=1)
    ratios = (arrived - exposure[:, None])[:RATIO_PASSES]
    exposure_scatter = float(np.std(exposure[1:], ddof=1)) if len(exposure) >= 3 else 0.0
    ratio_scatter = np.std(ratios[1:], axis=0, ddof=1) if len(ratios) >= 3 else np.zeros(3)
    return gain, _with_selection(found, exposure_scatter, ratio_scatter), (params, sums) if settled else None


def _dielectric_refined(observations: Observations, search: Config, gain: np.ndarray, found: GainEstimate,
                        config: Config, searched: tuple[np.ndarray, np.ndarray] | None, white_balance: bool = True
                        ) -> tuple[np.ndarray, GainEstimate, bool]:
    """Return the gains read again on the dielectrics, their estimate, and whether they read them.

    The dielectrics' reading: `_dielectric_gains`. ``searched``: a search on the photographs
    divided by about ``gain`` (None: searched here). Which texels pass for smooth dielectrics
    depends on the gain they are searched at (a capture read from far off picks others), so they
    are picked again at the gains they read, `DIELECTRIC_PICKS` times in all. Where too few
    dielectrics are found, ``gain`` and ``found`` as given, and False. Without ``white_balance`` they
    read the exposure only, and the estimate keeps the passes' white-balance std.
    """
    if searched is None:
        searched = label_sums(_scaled(observations, gain, config), search)
    dielectric = _dielectric_gains(observations, search, gain, config, searched, white_balance)
    if dielectric is None:
        return gain, found, False
    for _ in range(DIELECTRIC_PICKS - 1):
        again = _dielectric_gains(observations, search, dielectric[0], config,
                                  label_sums(_scaled(observations, dielectric[0], config), search), white_balance)
        if again is None:
            break
        dielectric = again
    gain, reading = dielectric
    if not white_balance:
        reading = _with_selection(replace(found, exposure_log_std=0.0, ratio_log_std=np.zeros(3),
                                          texels=reading.texels), reading.exposure_log_std, found.ratio_log_std)
    return gain, reading, True


def _dielectric_gains(observations: Observations, search: Config, gain: np.ndarray, config: Config,
                      searched: tuple[np.ndarray, np.ndarray], white_balance: bool = True
                      ) -> tuple[np.ndarray, GainEstimate] | None:
    """Read the gains again on the texels found dielectric at ``gain``: (gains, their estimate), or None.

    ``searched`` is the search's (params, sums) on the photographs divided by about ``gain``
    (`label_sums`; the passes' last where it moved the gains by less than `CONVERGED`). The
    texels it finds dielectric with a lobe told from the diffuse (`DIELECTRIC_MAX_METALLIC`,
    `DIELECTRIC_MAX_ROUGHNESS`) are kept, at least `MIN_DIELECTRIC_TEXELS` of them (else None:
    the passes' reading stands). Their specular is white (F0 = 0.04 in every channel): its colour
    is the light's, so they read the white balance too, where every texel's reading is led by
    coloured metals and part-metals taken for dielectrics. On them, up to `DIELECTRIC_PASSES`
    passes of `channel_gains` (each on the photographs divided by the gains so far) move the gains
    until a step is below `CONVERGED` (`RATIO_CONVERGED` for a ratio). The roughness the search
    finds follows the gain part of the way, so each exposure step is the pass's reading over the
    contraction the last two passes measured (between `CONTRACTION_FLOOR` and 1): the fixed point in
    a few passes rather than many. The std is the last pass's, the exposure's with
    `DIELECTRIC_EXPOSURE_LOG_STD`. Without ``white_balance`` the ratios are kept as given.
    """
    params, sums = searched
    kept = ((params[:, 4] <= DIELECTRIC_MAX_METALLIC) & (params[:, 3] <= DIELECTRIC_MAX_ROUGHNESS)
            & (sums[:, 0, :, 14].sum(axis=1) > 0.0))
    if kept.sum() < MIN_DIELECTRIC_TEXELS:
        return None
    texels = observations.select(kept)
    params, sums = params[kept], sums[kept]
    log_gain = np.log(np.asarray(gain, np.float64))
    steps: list[tuple[float, float]] = []
    found = None
    for index in range(DIELECTRIC_PASSES):
        if index > 0:
            params, sums = label_sums(_scaled(texels, np.exp(log_gain), config), search)
        reading = channel_gains(sums, params[:, 3], DIELECTRIC_EXPOSURE_LOG_STD)
        if reading.texels < 2:
            break
        found = reading
        step = _gain_step(reading, white_balance)
        exposure_step = float(np.log(reading.gain).mean())
        steps.append((float(log_gain.mean()), exposure_step))
        ratio_step = step - exposure_step
        if abs(exposure_step) < CONVERGED and np.all(np.abs(ratio_step) < RATIO_CONVERGED):
            break
        log_gain = log_gain + _secant_step(steps) + ratio_step
    if found is None:
        return None
    return np.exp(log_gain), found


def _gain_step(found: GainEstimate, move_ratios: bool) -> np.ndarray:
    """Return a pass's step (3,) of log gains: its exposure, and each white-balance ratio it tells from 0.

    A ratio moves where its reading is at least `RATIO_STEP_STD` times the texels' scatter (its
    std without the model's misfit, `MODEL_RATIO_LOG_STD`, which is the same at every pass): below,
    a pass reads the texels' chance, and such steps multiplied pass after pass walk away, on
    calibrated captures too (docs/results.md#calibration).
    """
    log_gain = np.log(found.gain)
    exposure = float(log_gain.mean())
    ratios = log_gain - exposure
    scatter = np.sqrt(np.maximum(found.ratio_log_std ** 2 - MODEL_RATIO_LOG_STD ** 2, 0.0))
    moved = move_ratios & (np.abs(ratios) >= RATIO_STEP_STD * scatter)
    return exposure + np.where(moved, ratios, 0.0)


def _secant_step(steps: list[tuple[float, float]]) -> float:
    """Return the exposure's next step (log) from the passes' (log exposure searched at, its reading).

    A pass reads the remaining error only in part (the roughness the search finds follows the gain
    part of the way): its reading d_k at x_k is about -c (x_k - x*). Where the last two readings
    measure a contraction (the same sign, the last smaller), the step is d_k / c, c =
    (d_{k-1} - d_k) / (x_k - x_{k-1}) clamped to [`CONTRACTION_FLOOR`, 1]; else (the first pass,
    readings that do not shrink: a flat valley, where amplifying would only walk) the reading itself.
    """
    x, d = steps[-1]
    if len(steps) < 2 or steps[-2][0] == x:
        return d
    if not (np.sign(steps[-2][1]) == np.sign(d) and abs(d) < abs(steps[-2][1])):
        return d
    contraction = (steps[-2][1] - d) / (x - steps[-2][0])
    return d / min(max(contraction, CONTRACTION_FLOOR), 1.0)


def _masks_inside(calibration: Calibration) -> bool:
    """Whether the masks' edges lie inside the mesh's outline (median over the views, `MASK_OFFSET_PX` or more).

    Eroded masks leave out every texel's most grazing views, where a dielectric's specular rises
    (its Fresnel term): the gains rest on them, and are not estimated (docs/results.md#calibration).
    """
    return calibration.cameras is not None and calibration.cameras.median_mask_offset_px <= -MASK_OFFSET_PX


def _clipped_share(observations: Observations) -> float:
    """Return the share of the seen texels with a clipped sample (docs/method.md#censored-samples)."""
    if observations.censored_weight is None:
        return 0.0
    censored = (observations.censored_weight > 0.0).any(axis=1)
    seen = int(np.count_nonzero((observations.weight > 0.0).any(axis=1) | censored))
    return int(np.count_nonzero(censored)) / max(seen, 1)


def _exact_texels(observations: Observations) -> Observations:
    """Return the observations of the texels without a censored sample, for the gains.

    A texel with a clipped channel in some view (docs/method.md#censored-samples) has lost its
    brightest samples, its highlights: what is left understates its specular, which biases the
    gains. They read the other texels (all of them where none is, or where every texel is censored).
    """
    if observations.censored_weight is None:
        return observations
    exact = ~(observations.censored_weight > 0.0).any(axis=1)
    return observations.select(exact) if exact.any() and not exact.all() else observations


def _after(probe: ProbeRegistration, convention: np.ndarray) -> ProbeRegistration:
    """Return the registration with the convention's turn (`convention_turn`) applied before it."""
    if np.array_equal(convention, np.eye(3)):
        return probe
    rotation = probe.rotation @ convention
    return replace(probe, rotation=rotation, angle_deg=float(np.degrees(axis_angle(rotation)[1])),
                   convention_deg=float(np.degrees(axis_angle(convention)[1])))


def _turned(capture: Capture, rotation: np.ndarray) -> Capture:
    """Return the capture with its map turned by the world ``rotation`` (before its to_world)."""
    to_world = capture.envmap.to_world.copy()
    to_world[:3, :3] = rotation @ to_world[:3, :3]
    return replace(capture, envmap=envmaps.Envmap(capture.envmap.radiance, to_world))


def _refined(capture: Capture, cameras: CameraRefinement) -> Capture:
    """Return the capture with the refined cameras, each mask drawn wider than the object taken in by its offset.

    A mask wider than the object holds background at its rim: taken in before the gains and the
    probe read the photographs, as in the fit.
    """
    frames = []
    for index, (frame, camera) in enumerate(zip(capture.frames, cameras.cameras)):
        if camera is not frame.camera:
            frame = replace(frame, camera=camera)
        inset = float(cameras.mask_offset_px[index])
        if inset > 0.0:
            frame = replace(frame, mask_inset_px=inset)
        frames.append(frame)
    return replace(capture, frames=tuple(frames))


def _corrected(capture: Capture, calibration: Calibration, drop_bad_views: bool) -> Capture:
    """Return the capture with every frame's exposure set (and bad views dropped where asked)."""
    frame_gain = calibration.frame_gain if calibration.frame_gain is not None else np.ones((len(capture.frames), 3))
    frames = []
    bad = set(np.flatnonzero(np.any(np.abs(np.log(frame_gain)) > np.log(BAD_FRAME_FACTOR), axis=1)).tolist())
    if calibration.cameras is not None:
        bad |= set(calibration.cameras.bad_views.tolist())
    for index, frame in enumerate(capture.frames):
        if drop_bad_views and index in bad:
            calibration.dropped_views.append(index)
            continue
        factor = 1.0 / (calibration.gain * frame_gain[index])
        if not np.allclose(factor, 1.0, rtol=0, atol=0):
            frame = replace(frame, exposure=tuple(float(value) for value in factor))
        frames.append(frame)
    return replace(capture, frames=tuple(frames))


def _warnings(capture: Capture, calibration: Calibration, settings) -> list[str]:
    """Return the lines a user should read: a gain far from 1, a turned probe, poorly determined gains, bad views."""
    lines = []
    log_gain = np.log(calibration.gain)
    if np.any(np.abs(log_gain) > settings.warn_gain):
        lines.append(f"the photographs are {calibration.exposure:.3g}x the environment map's exposure, white balance "
                     f"(R, G, B) {', '.join(f'{value:.3f}' for value in calibration.white_balance)}: corrected "
                     "(calibration); shoot the probe with the photographs' settings or check envmap_scale")
    kept = ("(the environment map's are used)" if np.all(calibration.gain == 1.0)
            else f"(the photographs' order of magnitude, {calibration.exposure:.3g}x the map's, is used)")
    if settings.gains and _masks_inside(calibration):
        lines.append("the masks lie inside the object's outline, so the photographs' most grazing views are lost: the "
                     f"exposure and white balance are not estimated {kept}")
    elif settings.gains and calibration.samples_per_texel < MIN_GAIN_SAMPLES:
        lines.append(f"the photographs give {calibration.samples_per_texel:.0f} samples per texel (median), too few to "
                     f"tell a dielectric's diffuse from its specular: the exposure and white balance are not estimated "
                     f"{kept}; shoot more views (at least {MIN_GAIN_SAMPLES} per texel) or check envmap_scale")
    if settings.gains and np.any(calibration.gain_log_std > POORLY_DETERMINED):
        lines.append(f"the photographs determine the exposure poorly (std of the gains "
                     f"{', '.join(f'{value:.0%}' for value in calibration.gain_log_std)}; few dielectric texels?): "
                     "the base colour's std includes it")
    probe = calibration.probe
    if probe is not None and probe.angle_deg > settings.warn_rotation_deg:
        axis, _ = axis_angle(probe.rotation)
        lines.append(f"the environment map was turned {probe.angle_deg:.1f}° about "
                     f"({', '.join(f'{value:.2f}' for value in axis)}) to match the photographs' reflections "
                     + (f"(calibration; {probe.convention_deg:.0f}° of it the map's convention: where its azimuth starts, "
                        "which axis is up): "
                        if probe.convention_deg > 0.0 else "(calibration): ") + "check envmap_to_world")
    cameras = calibration.cameras
    if cameras is not None and cameras.refined.any():
        moved = cameras.turn_deg[cameras.refined]
        if np.median(moved) > settings.warn_camera_deg:
            lines.append(f"the cameras were turned by a median {np.median(moved):.2f}° (largest {moved.max():.2f}°) "
                         "to put the mesh's outline on the masks (calibration): check the poses")
        median = cameras.median_mask_offset_px
        if median != 0.0:
            lines.append(f"the masks' edges lie a median {abs(median):.1f} px {'outside' if median > 0 else 'inside'} the "
                         f"mesh's outline ({'a segmentation halo' if median > 0 else 'eroded masks'}?): the poses were "
                         "refined with that offset" + ("; the masks are taken in by it" if median > 0 else
                                                        "; the object's rim is not observed"))
        bad = cameras.bad_views
        if bad.size:
            names = ", ".join(capture.frames[index].image_path.name for index in bad[:5].tolist())
            action = "dropped" if settings.drop_bad_views else "kept (--drop-bad-views leaves them out)"
            lines.append(f"{bad.size} photographs' masks do not fit the mesh's outline after refining their poses "
                         f"(off by more than {BAD_OUTLINE_PX:g} px: {names}): {action}")
    measured = calibration.frame_gain
    if measured is not None:
        worst = np.abs(np.log(measured)).max(axis=1)
        bad = np.flatnonzero(worst > np.log(BAD_FRAME_FACTOR))
        if bad.size:
            names = ", ".join(capture.frames[index].image_path.name for index in bad[:5].tolist())
            action = "dropped" if settings.drop_bad_views else "kept (--drop-bad-views leaves them out)"
            lines.append(f"{bad.size} photographs disagree with the others by more than {BAD_FRAME_FACTOR:g}x ({names}): "
                         f"{action}")
    return lines
