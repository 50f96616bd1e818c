"""The light probe's registration: the turn of the environment map under which the model best explains the photographs.

docs/method.md#calibration. A probe turned into place by hand is off by a few degrees; every
reflection then reads the wrong part of the map. `register_probe` scores a turn of the map by the
model's own likelihood: the global search's least-squares loss (base colour, roughness and
metallic profiled out per texel, `freqbrdf.estimate.search`) summed over the texels whose
radiance varies most over their views. A turn changes only the light: the map's world-frame
harmonics (rotated by it, not transformed again), the prefiltered maps' lookup frame and the
irradiance (read at turned normals), so that a hypothesis costs one search of a few hundred
texels. The turn is searched about the map's own pole (the usual hand turn) on a grid, then about
each world axis in turn (coordinate descent); it is applied where the texels make "turned" the
likelier than "registered exactly" (`PRIOR_TURN_DEG`) and it removes `MIN_LOSS_REDUCTION` of the
loss or its log odds are decisive (`DECISIVE_LOG_ODDS`), as the posterior mean; what it removes is
measured with the exposure free over its range (`EXPOSURE_RANGE_STD`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from freqbrdf.calibrate.gains import slab_log_odds
from freqbrdf.config import EstimateConfig
from freqbrdf.estimate.search import run_search_kernel
from freqbrdf.observe.irradiance import irradiance_map
from freqbrdf.observe.observations import Observations
from freqbrdf.sphere import envmap as envmaps
from freqbrdf.sphere import harmonics as sh

__all__ = ["ProbeRegistration", "axis_angle", "convention_turn", "register_probe", "rotation_about"]

# The grid about the map's pole, in degrees.
POLE_STEP_DEG = 5.0
# The search about each world axis (coordinate descent): the steps, coarse to fine, in degrees,
# and the sweeps over the three axes at each.
AXIS_STEPS_DEG = (4.0, 2.0, 1.0, 0.5)
AXIS_SWEEPS = 1
# The texels scored: at least this many views each, the half whose radiance varies most over its
# views (they carry the map's position), at most this many (evenly over the texture).
MIN_VIEWS = 8
MAX_TEXELS = 512
# A probe turned into place by hand is either registered exactly or off by a normal amount of this
# std about each axis.
PRIOR_TURN_DEG = 10.0
# On a capture whose map is registered exactly the model's own misfit moves the loss's least by
# about this much (docs/results.md#calibration): added, as a std about each axis, to the curvature's.
MISFIT_TURN_DEG = 1.0
# A turn must also remove this share of the model's loss on the texels scored: on captures whose map
# is registered exactly the model's misfit prefers turns of a few degrees that remove less
# (docs/results.md#calibration).
MIN_LOSS_REDUCTION = 0.05
# ... unless the texels make "turned" overwhelmingly the likelier (log odds at least this: 150 to 1):
# a map turned by hand on a material whose misfit dominates the loss removes little of it, at log
# odds far beyond the misfit's own turns on registered maps (docs/results.md#calibration).
DECISIVE_LOG_ODDS = 5.0
# A turn is judged with the exposure free over this many of its std either side of the exposure read
# (`register_probe`'s ``exposure_log_std``), in steps of one std.
EXPOSURE_RANGE_STD = 2
# The std of the turn about an axis the loss does not curve about at the least the descent found (a
# flat or noisy direction): far wider than the prior, so that the turn about it is not applied.
UNDETERMINED_TURN_DEG = 180.0
# Tools disagree on where an equirectangular map's azimuth starts (by quarter turns about its pole) and
# on which world axis is up: a turn between such conventions is taken for the map's where it leaves at
# most this share of the given registration's loss, at the photographs' scale as given and with the
# exposure free over a factor CONVENTION_EXPOSURE_RANGE either way (the gains are read after it): at
# the given scale alone clipped photographs at 2x the map's exposure, whose clipped samples select by
# where the light is, took a false one; on the calibration study's captures none is taken but on its
# maps tilted 10° (the pole back to +y, docs/results.md#calibration).
CONVENTION_LOSS_SHARE = 0.8
CONVENTION_EXPOSURE_RANGE = 2.0
# The world's up axes captures are made in (Mitsuba's and most tools' +y, Blender's +z): the map's pole
# is tried on each, at each quarter turn about it.
WORLD_UP_AXES = ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
# Texels whose normals' mean has this length or more (a plane, a relief: normals within about 25°
# of one direction) do not register the map: for them a turn mimics the model's own misfit of the
# lobe's shape (its off-specular shift is one direction for every texel).
MAX_NORMAL_ALIGNMENT = 0.9


@dataclass
class ProbeRegistration:
    """A turn of the environment map and how well the photographs determine it.

    Attributes
    ----------
    rotation : (3, 3) float64
        World rotation to apply before the map's to_world (identity: the registration stands).
    angle_deg : float
        Its angle.
    std_deg : float
        The std of the turn (the loss's curvature and `MISFIT_TURN_DEG`) about its least
        determined axis; inf where undetermined.
    loss : tuple of float
        The model's loss on the texels scored at the given registration and at the turn found
        (before the posterior's shrink towards none), over the first.
    log_odds : float
        The log odds of "turned" over "registered exactly" (`PRIOR_TURN_DEG`); the turn is applied
        where positive.
    convention_deg : float
        The turn the map's convention was found off by (`convention_turn`: where its azimuth starts,
        which world axis is up), included in ``rotation``; the other fields are of the turn after it.
    """

    rotation: np.ndarray
    angle_deg: float
    std_deg: float
    loss: tuple[float, float]
    log_odds: float
    convention_deg: float = 0.0


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Return the (3, 3) rotation by ``angle`` radians about the unit ``axis`` (right-handed, Rodrigues).

    Parameters
    ----------
    axis : (3,) float
        A unit axis.
    angle : float
        Radians.

    Returns
    -------
    (3, 3) float64
        The rotation.
    """
    axis = np.asarray(axis, np.float64)
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * cross + (1.0 - np.cos(angle)) * cross @ cross


def axis_angle(rotation: np.ndarray) -> tuple[np.ndarray, float]:
    """Return the unit axis and the angle (radians, in [0, pi]) of a (3, 3) rotation."""
    rotation = np.asarray(rotation, np.float64)
    angle = float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))
    axis = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0], rotation[1, 0] - rotation[0, 1]])
    norm = np.linalg.norm(axis)
    return (axis / norm if norm > 1e-12 else np.array([0.0, 1.0, 0.0])), angle


def _rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """Return the (3,) axis times angle (radians) of a rotation."""
    axis, angle = axis_angle(rotation)
    return axis * angle


def _rotation_from_vector(vector: np.ndarray) -> np.ndarray:
    """Return the rotation of a (3,) axis times angle (radians)."""
    angle = float(np.linalg.norm(vector))
    return np.eye(3) if angle < 1e-15 else rotation_about(vector / angle, angle)


class _ModelLoss:
    """The global search's least-squares loss of some texels, summed, under the map turned by a rotation."""

    def __init__(self, observations: Observations, settings: EstimateConfig):
        self.observations = observations
        self.settings = settings
        envmap = observations.environment()
        self.rotation = envmap.rotation.copy()
        self.harmonics = observations.environment_coeffs.T.astype(np.float64)  # (3, K), world
        self.normal = observations.normal.astype(np.float64)
        self.irradiance = irradiance_map(envmap)
        # The irradiance as observed over the unoccluded one: what the object hides keeps its share.
        unoccluded = np.asarray(envmaps.lookup(self.irradiance, self.normal), np.float64)
        self.occlusion = observations.irradiance.astype(np.float64) / np.maximum(unoccluded, 1e-12)
        self.sum_squared_weight = (observations.weight.astype(np.float64) ** 2).sum(axis=1)

    def __call__(self, turn: np.ndarray, exposure: float = 1.0) -> float:
        """Return the loss under the map turned by ``turn``, the photographs divided by ``exposure`` (in their units)."""
        rotation = turn @ self.rotation
        # E under the turned map at n is E at turn^T n (a row vector n: n turn).
        irradiance = np.asarray(envmaps.lookup(self.irradiance, self.normal @ turn), np.float64) * self.occlusion
        observed = self.observations.observed
        turned = replace(self.observations, irradiance=irradiance.astype(np.float32),
                         environment_coeffs=sh.rotate_sh(self.harmonics, turn).T.astype(np.float32),
                         environment_rotation=rotation,
                         observed=observed if exposure == 1.0 else (observed / exposure).astype(np.float32))
        n = turned.n_texels
        params, loss, curvature = np.zeros((n, 5)), np.zeros(n), np.zeros(n)
        run_search_kernel(turned, self.settings, turned.mirrored_coeffs, np.zeros(0), np.zeros((0, 0, 3, 8)), True,
                          params, loss, curvature)
        return float((loss * self.sum_squared_weight).sum()) * exposure ** 2


def _scored_texels(observations: Observations) -> np.ndarray:
    """Return the indices of the texels that score a turn (`MIN_VIEWS`, the varying half, `MAX_TEXELS`)."""
    weight = observations.weight.astype(np.float64)
    keep = np.count_nonzero(weight > 0, axis=1) >= MIN_VIEWS
    grey = observations.observed.astype(np.float64).mean(axis=2)
    total = np.maximum(weight.sum(axis=1), 1e-30)
    mean = (weight * grey).sum(axis=1) / total
    spread = (weight * (grey - mean[:, None]) ** 2).sum(axis=1) / total
    if keep.sum() > 1:
        keep &= spread >= np.median(spread[keep])
    index = np.flatnonzero(keep)
    if len(index) > MAX_TEXELS:
        index = index[np.linspace(0, len(index) - 1, MAX_TEXELS).round().astype(np.int64)]
    return index


def _parabola_step(step: float, minus: float, centre: float, plus: float) -> float:
    """Return the least of the parabola through (-step, minus), (0, centre), (step, plus), within 2 steps of 0."""
    curvature = minus - 2.0 * centre + plus
    if not curvature > 0.0:
        return -step if minus < min(centre, plus) else (step if plus < centre else 0.0)
    return float(np.clip(0.5 * step * (minus - plus) / curvature, -2.0 * step, 2.0 * step))


def _descend(loss: _ModelLoss, rotation: np.ndarray, value: float) -> tuple[np.ndarray, float, np.ndarray]:
    """Return the turn of least loss near ``rotation`` (coordinate descent), its loss and the loss's curvature (3,).

    On each grid of `AXIS_STEPS_DEG` the world axes are swept in turn (at most `AXIS_SWEEPS` times,
    until a sweep moves nothing): the loss at plus and minus the step, and at its parabola's least;
    the best of the four is kept. The curvature is the last grid's, about each axis.
    """
    curvature = np.zeros(3)
    for step_deg in AXIS_STEPS_DEG:
        step = np.radians(step_deg)
        for _ in range(AXIS_SWEEPS):
            moved = False
            for index, axis in enumerate(np.eye(3)):
                minus_turn, plus_turn = rotation_about(axis, -step) @ rotation, rotation_about(axis, step) @ rotation
                minus, plus = loss(minus_turn), loss(plus_turn)
                curvature[index] = (minus - 2.0 * value + plus) / step ** 2
                candidates = [(value, rotation), (minus, minus_turn), (plus, plus_turn)]
                least = _parabola_step(step, minus, value, plus)
                if least not in (0.0, -step, step):
                    turned = rotation_about(axis, least) @ rotation
                    candidates.append((loss(turned), turned))
                best = min(range(len(candidates)), key=lambda k: candidates[k][0])
                if best > 0:
                    value, rotation = candidates[best]
                    moved = True
            if not moved:
                break
    return rotation, value, curvature


def _turn_kept(log_odds: float, loss_ratio: float) -> bool:
    """Whether a turn of these log odds (turned over registered) and loss (over the given map's) is applied.

    Likelier turned than not, removing some of the loss, and either removing `MIN_LOSS_REDUCTION` of
    it or decisive (`DECISIVE_LOG_ODDS`).
    """
    return log_odds > 0.0 and loss_ratio < 1.0 and (loss_ratio <= 1.0 - MIN_LOSS_REDUCTION
                                                     or log_odds >= DECISIVE_LOG_ODDS)


def _least_over_exposure(loss: _ModelLoss, turn: np.ndarray, value: float, exposure_log_std: float) -> float:
    """Return the least of the loss under ``turn`` (``value`` at the exposure as read) over the exposure's range.

    The range: `EXPOSURE_RANGE_STD` about the exposure as read, in steps of its std; none where it is 0.
    """
    if exposure_log_std <= 0.0:
        return value
    steps = np.arange(-EXPOSURE_RANGE_STD, EXPOSURE_RANGE_STD + 1)
    return min([value] + [loss(turn, float(np.exp(step * exposure_log_std))) for step in steps if step != 0])


def _log_odds(vector: np.ndarray, covariance: np.ndarray, prior_std: float) -> float:
    """Return the log odds of "turned by a normal amount of ``prior_std`` per axis" over "not turned".

    For a rotation vector x of diagonal covariance S: the sum over the axes of `slab_log_odds`.
    """
    return float(slab_log_odds(vector, np.sqrt(np.diagonal(covariance)), prior_std).sum())


def convention_turn(observations: Observations, settings: EstimateConfig, search_deg: float) -> np.ndarray:
    """Return the turn the map's convention is off by: where its azimuth starts, which axis is up (identity: none).

    Each turn that puts the map's pole on one of `WORLD_UP_AXES` at a quarter turn about it (the
    quarter turns about the pole as given among them) is scored by the model's loss (`_ModelLoss`,
    on the texels `register_probe` scores); the least is taken where it leaves at most
    `CONVENTION_LOSS_SHARE` of the given registration's loss, at the photographs' scale and with
    the exposure free (`CONVENTION_EXPOSURE_RANGE`). `register_probe` then refines the turn from
    there.

    Parameters
    ----------
    observations : Observations
        As `register_probe` takes them.
    settings : EstimateConfig
        The search that scores a turn.
    search_deg : float
        `register_probe`'s range; 0: the map is not registered, identity.

    Returns
    -------
    (3, 3) float64
        The world rotation to apply before the map's to_world.
    """
    identity = np.eye(3)
    loss = _registration_loss(observations, settings, search_deg)
    if loss is None:
        return identity
    given = loss(identity)
    turns = _convention_turns(loss.rotation @ np.array([0.0, 1.0, 0.0]))
    values = [loss(turn) for turn in turns]
    best = int(np.argmin(values))
    if not (given > 0.0 and values[best] <= CONVENTION_LOSS_SHARE * given):
        return identity
    # The other exposures over the range (the exposure as given is scored above).
    exposures = np.exp(np.array([-1.0, -0.5, 0.5, 1.0]) * np.log(CONVENTION_EXPOSURE_RANGE))

    def least(turn: np.ndarray, at_given: float) -> float:
        return min([at_given] + [loss(turn, float(exposure)) for exposure in exposures])

    kept = least(turns[best], values[best]) <= CONVENTION_LOSS_SHARE * least(identity, given)
    return turns[best] if kept else identity


def _convention_turns(pole: np.ndarray) -> list[np.ndarray]:
    """Return the turns that take the map's ``pole`` (3,) onto each of `WORLD_UP_AXES`, at each quarter turn about it.

    The identity (the map as given) is left out.
    """
    turns = []
    for up in np.asarray(WORLD_UP_AXES):
        axis = np.cross(pole, up)
        sine, cosine = float(np.linalg.norm(axis)), float(pole @ up)
        if sine > 1e-9:
            tilt = rotation_about(axis / sine, float(np.arctan2(sine, cosine)))
        else:  # the pole on the up axis, or opposite it: a half turn about any axis across it
            across = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])
            tilt = np.eye(3) if cosine > 0.0 else rotation_about(across / np.linalg.norm(across), np.pi)
        for quarter in range(4):
            turn = rotation_about(up, np.radians(90.0 * quarter)) @ tilt
            if not np.allclose(turn, np.eye(3), atol=1e-9):
                turns.append(turn)
    return turns


def _registration_loss(observations: Observations, settings: EstimateConfig, search_deg: float) -> _ModelLoss | None:
    """Return the loss that scores the map's turns, or None where the texels cannot register it.

    None where nothing is searched (``search_deg`` 0), the capture has no map, no texel is seen,
    the seen texels' normals are too alike to tell a turn from the model's misfit
    (`MAX_NORMAL_ALIGNMENT`) or fewer than 4 texels score it (`_scored_texels`).
    """
    seen = (observations.weight > 0).any(axis=1)
    if (search_deg <= 0.0 or observations.environment() is None or not seen.any()
            or np.linalg.norm(observations.normal[seen].mean(axis=0)) >= MAX_NORMAL_ALIGNMENT):
        return None
    texels = _scored_texels(observations)
    return _ModelLoss(observations.select(texels), settings) if len(texels) >= 4 else None


def register_probe(observations: Observations, settings: EstimateConfig, search_deg: float,
                   exposure_log_std: float = 0.0) -> ProbeRegistration:
    """Find the turn of the environment map under which the model best explains the texels' radiance.

    Parameters
    ----------
    observations : Observations
        The texels' samples, with the map as the capture registers it (``environment_radiance``,
        ``environment_rotation``) and the texels' frames; clipped samples at weight 0.
    settings : EstimateConfig
        The search that scores a turn (least squares: no robust pass, no neighbour vote).
    search_deg : float
        The largest turn searched about the map's pole; 0: none.
    exposure_log_std : float, optional
        The std of the log exposure the photographs were divided by (0: known). A turn found is
        judged by how much of the loss it removes with the exposure free over its range
        (`EXPOSURE_RANGE_STD`), the registered map's likewise: a wrong exposure lets a turn that
        brings brighter light into the lobes remove loss that the right exposure removes as well.

    Returns
    -------
    ProbeRegistration
        The turn: identity where "registered exactly" is the likelier, where the turn removes less
        than `MIN_LOSS_REDUCTION` of the loss at log odds under `DECISIVE_LOG_ODDS`, where the
        loss curves about none of the axes (about some: the turn about the others; ``std_deg``
        theirs),
        or where the texels' normals are too alike to tell a turn from the model's misfit
        (`MAX_NORMAL_ALIGNMENT`).
    """
    identity = np.eye(3)
    nothing = ProbeRegistration(identity, 0.0, float("inf"), (1.0, 1.0), 0.0)
    loss = _registration_loss(observations, settings, search_deg)
    if loss is None:
        return nothing
    # About the map's pole, over the whole range (the hand turn): the best node starts the descent about the axes.
    pole = loss.rotation @ np.array([0.0, 1.0, 0.0])
    angles = np.arange(-search_deg, search_deg + 1e-9, POLE_STEP_DEG)
    turns = [rotation_about(pole, np.radians(angle)) for angle in angles]
    values = [loss(turn) for turn in turns]
    given = values[int(np.argmin(np.abs(angles)))] if np.any(angles == 0.0) else loss(identity)
    if not given > 0.0:
        return nothing
    best = int(np.argmin(values))
    start, start_value = (turns[best], values[best]) if values[best] < given else (identity, given)
    rotation, value, curvature = _descend(loss, start, start_value)
    determined = curvature > 0.0
    if not determined.any():
        return ProbeRegistration(identity, 0.0, float("inf"), (1.0, 1.0), 0.0)
    # The noise: the loss per texel (the texels are the independent units), less the turn's 3; the
    # model's misfit adds its own spread. An axis the loss does not curve about leaves the turn about
    # it undetermined (`UNDETERMINED_TURN_DEG`), not the turn about the others.
    noise = value / max(loss.observations.n_texels - 3, 1)
    variance = np.where(determined, 2.0 * noise / np.where(determined, curvature, 1.0),
                        np.radians(UNDETERMINED_TURN_DEG) ** 2)
    covariance = np.diag(variance) + np.radians(MISFIT_TURN_DEG) ** 2 * identity
    std_deg = float(np.degrees(np.sqrt(covariance.diagonal()[determined].max())))
    vector = _rotation_vector(rotation)
    prior = np.radians(PRIOR_TURN_DEG)
    log_odds = _log_odds(vector, covariance, prior)
    if log_odds > 0.0 and value < given:
        value = _least_over_exposure(loss, rotation, value, exposure_log_std)
        given = _least_over_exposure(loss, identity, given, exposure_log_std)
    if not _turn_kept(log_odds, value / given):
        return ProbeRegistration(identity, 0.0, std_deg, (1.0, 1.0), log_odds)
    # The posterior mean under the slab: T (S + T)^-1 x.
    applied = _rotation_from_vector(prior ** 2 * np.linalg.solve(covariance + prior ** 2 * identity, vector))
    return ProbeRegistration(applied, float(np.degrees(axis_angle(applied)[1])), std_deg, (1.0, value / given),
                             log_odds)
