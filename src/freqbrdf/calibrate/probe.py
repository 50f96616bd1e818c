"""The light probe's registration: the turn of the environment map that best explains the photographs.

docs/method.md#calibration. A probe turned into place by hand is off by a few degrees; every
reflection then reads the wrong part of the map. What a texel shows across its views follows the
light in its mirror directions: a constant (its diffuse) plus a multiple of that light (its
specular). `register_probe` scores a turn of the map by how much of the texels' view-dependent
radiance that regression explains (pooled over the texels, so the texels whose reflections vary
most, those that carry the map's position, weigh most) and searches the turn: about the map's own
pole first (the usual hand turn), then about each axis, on grids refined by parabolas. A turn is
kept only where the texels prefer it over the given registration beyond their spread.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from freqbrdf.sphere import envmap as envmaps

__all__ = ["ProbeRegistration", "axis_angle", "register_probe", "rotation_about"]

# Grid steps of the search, in degrees: about the map's pole, then each axis (coarse, fine).
POLE_STEP_DEG = 5.0
AXIS_STEPS = ((2.0, 5), (2.0, 3), (1.0, 2), (0.5, 2))  # (degrees, nodes per side): coarse to fine
# The texels must prefer the turn found by this many standard errors of their mean improvement.
MIN_SIGNIFICANCE = 3.0
# Texels whose normals' mean has this length or more (a plane, a relief: normals within about 25°
# of one direction) do not register the map: for them a turn mimics the model's own misfit of the
# lobe's shape (its off-specular shift is one direction for every texel), so a calibrated plane
# prefers a turn of a few degrees (docs/results.md#calibration).
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
        The std of the turn about each axis (the score's curvature), largest of the three; inf
        where undetermined.
    explained : tuple of float
        The share of the texels' view-dependent radiance explained at the given registration and
        at the turn found.
    significance : float
        The texels' mean improvement over its standard error.
    """

    rotation: np.ndarray
    angle_deg: float
    std_deg: float
    explained: tuple[float, float]
    significance: float


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


class _Scorer:
    """The share of view-dependent radiance the mirrored light explains, per texel, for a turn of the map."""

    def __init__(self, envmap: envmaps.Envmap, frame: np.ndarray, view_direction: np.ndarray, weight: np.ndarray,
                 observed: np.ndarray, censored_weight: np.ndarray | None = None):
        sampled = weight > 0
        counts = sampled.sum(axis=1)
        keep = counts >= 4
        # The texels whose radiance varies most over their views carry the map's position: the
        # half above the median variance is scored.
        grey = np.asarray(observed, np.float64).mean(axis=2)
        total = np.maximum(weight.sum(axis=1), 1e-30)
        mean = (weight * grey).sum(axis=1) / total
        spread = (weight * (grey - mean[:, None]) ** 2).sum(axis=1) / total
        if keep.sum() > 1:
            keep &= spread >= np.median(spread[keep])
        self.envmap = envmap
        self.sampled = sampled[keep]
        local = np.asarray(view_direction[keep], np.float64)[self.sampled]  # (M, 3)
        frames = np.repeat(np.asarray(frame[keep], np.float64), counts[keep], axis=0)  # (M, 3, 3) rows t, b, n
        # The mirror of the view direction about n, in the world: -x t - y b + z n.
        self.directions = np.einsum("mi,mij->mj", local * np.array([-1.0, -1.0, 1.0]), frames)
        self.texel_of = np.repeat(np.arange(int(keep.sum())), counts[keep])
        self.n_texels = int(keep.sum())
        w = np.asarray(weight[keep], np.float64)[self.sampled]
        self.w = w
        f = np.asarray(observed[keep], np.float64)[self.sampled].mean(axis=1)  # grey
        self.sum_w = np.bincount(self.texel_of, w, self.n_texels)
        self.mean_f = np.bincount(self.texel_of, w * f, self.n_texels) / self.sum_w
        centred = f - self.mean_f[self.texel_of]
        self.centred_f = centred
        self.variance_f = np.bincount(self.texel_of, w * centred * centred, self.n_texels)
        # Censored samples (docs/method.md#censored-samples) of the texels scored: lower bounds.
        self.n_exact = len(self.directions)
        self.censored_of = np.zeros(0, np.int64)
        if censored_weight is not None:
            held = np.asarray(censored_weight[keep]) > 0
            frames = np.repeat(np.asarray(frame[keep], np.float64), held.sum(axis=1), axis=0)
            local = np.asarray(view_direction[keep], np.float64)[held]
            self.directions = np.concatenate([self.directions,
                                              np.einsum("mi,mij->mj", local * np.array([-1.0, -1.0, 1.0]), frames)])
            self.censored_of = np.repeat(np.arange(self.n_texels), held.sum(axis=1))
            self.censored_w = np.asarray(censored_weight[keep], np.float64)[held]
            self.censored_f = np.asarray(observed[keep], np.float64)[held].mean(axis=1)

    def unexplained(self, rotation: np.ndarray) -> np.ndarray:
        """(n,) per texel the weighted residual of f on [1, L] with the map turned by ``rotation``.

        A censored sample adds its shortfall below its lower bound, where the texel's fit predicts less.
        """
        to_world = self.envmap.to_world.copy()
        to_world[:3, :3] = rotation @ to_world[:3, :3]
        light = envmaps.lookup(envmaps.Envmap(self.envmap.radiance, to_world), self.directions)
        light = np.asarray(light, np.float64).mean(axis=1)
        light, censored_light = light[:self.n_exact], light[self.n_exact:]
        texel, w = self.texel_of, self.w
        mean_l = np.bincount(texel, w * light, self.n_texels) / self.sum_w
        centred_l = light - mean_l[texel]
        covariance = np.bincount(texel, w * centred_l * self.centred_f, self.n_texels)
        variance_l = np.bincount(texel, w * centred_l * centred_l, self.n_texels)
        explained = np.where(variance_l > 1e-30, covariance ** 2 / np.maximum(variance_l, 1e-30), 0.0)
        residual = np.maximum(self.variance_f - explained, 0.0)
        if len(self.censored_of):
            slope = np.where(variance_l > 1e-30, covariance / np.maximum(variance_l, 1e-30), 0.0)
            of = self.censored_of
            predicted = self.mean_f[of] + slope[of] * (censored_light - mean_l[of])
            shortfall = np.maximum(self.censored_f - predicted, 0.0)
            residual = residual + np.bincount(of, self.censored_w * shortfall * shortfall, self.n_texels)
        return residual

    def total(self, rotation: np.ndarray) -> float:
        return float(self.unexplained(rotation).sum())


def _parabola_step(steps: np.ndarray, values: np.ndarray) -> float:
    best = int(np.argmin(values))
    if best == 0 or best == len(steps) - 1:
        return float(steps[best])
    left, centre, right = values[best - 1], values[best], values[best + 1]
    denominator = left - 2.0 * centre + right
    if not denominator > 0.0:
        return float(steps[best])
    return float(steps[best] + 0.5 * (steps[1] - steps[0]) * (left - right) / denominator)


def _significance(before: np.ndarray, after: np.ndarray) -> float:
    """Return the texels' mean improvement from ``before`` to ``after`` (n,) over its standard error."""
    improvement = before - after
    if len(improvement) < 2:
        return 0.0
    error = improvement.std(ddof=1) / np.sqrt(len(improvement))
    return float(improvement.mean() / error) if error > 0.0 else 0.0


def register_probe(envmap: envmaps.Envmap, frame: np.ndarray, view_direction: np.ndarray, weight: np.ndarray,
                   observed: np.ndarray, search_deg: float,
                   censored_weight: np.ndarray | None = None) -> ProbeRegistration:
    """Find the turn of the environment map that best explains the texels' reflections.

    Parameters
    ----------
    envmap : Envmap
        The map as the capture registers it (band-limited as the observations read it).
    frame : (N, 3, 3) float
        Each texel's frame, rows tangent, bitangent, normal (world).
    view_direction : (N, V, 3) float32
        Local view directions of the samples.
    weight : (N, V) float32
        Their weights (0: no sample).
    observed : (N, V, 3) float32
        Their observed radiance.
    search_deg : float
        The largest turn searched about the map's pole; 0: none.
    censored_weight : (N, V) float32, optional
        The weights of censored samples (`Observations.censored_weight`), whose ``observed`` is a
        lower bound: a turn that predicts less there is charged the shortfall.

    Returns
    -------
    ProbeRegistration
        The turn (identity where the texels do not prefer another beyond their spread, or where
        their normals are too alike to tell a turn from the model's misfit: `MAX_NORMAL_ALIGNMENT`).
    """
    identity = np.eye(3)
    seen = (weight > 0).any(axis=1)
    if not seen.any() or np.linalg.norm(frame[seen, 2].mean(axis=0)) >= MAX_NORMAL_ALIGNMENT:
        return ProbeRegistration(identity, 0.0, float("inf"), (0.0, 0.0), 0.0)
    scorer = _Scorer(envmap, frame, view_direction, weight, observed, censored_weight)
    if scorer.n_texels == 0 or search_deg <= 0.0 or not scorer.variance_f.sum() > 0.0:
        return ProbeRegistration(identity, 0.0, float("inf"), (0.0, 0.0), 0.0)
    total_variance = float(scorer.variance_f.sum())
    pole = envmap.rotation @ np.array([0.0, 1.0, 0.0])
    rotation = identity
    # About the map's pole: the hand turn, over the whole range.
    steps = np.radians(np.arange(-search_deg, search_deg + 1e-9, POLE_STEP_DEG))
    values = np.array([scorer.total(rotation_about(pole, step)) for step in steps])
    rotation = rotation_about(pole, _parabola_step(steps, values)) @ rotation
    # Then about each world axis, coarse to fine.
    axes = np.eye(3)
    for step_deg, nodes in AXIS_STEPS:
        steps = np.radians(step_deg * np.arange(-nodes, nodes + 1))
        for axis in axes:
            values = np.array([scorer.total(rotation_about(axis, step) @ rotation) for step in steps])
            turned = rotation_about(axis, _parabola_step(steps, values)) @ rotation
            # A tilt the texels do not prefer beyond their spread is not taken (cameras on one
            # side determine some axes poorly).
            if _significance(scorer.unexplained(rotation), scorer.unexplained(turned)) >= MIN_SIGNIFICANCE:
                rotation = turned
    # The texels' preference for the turn over the registration given, and the turn's spread.
    before, after = scorer.unexplained(identity), scorer.unexplained(rotation)
    significance = _significance(before, after)
    curvature_step = np.radians(0.5)
    noise = max(float(after.sum()) / max(scorer.n_texels - 3, 1), 1e-30)
    stds = []
    centre = float(after.sum())
    for axis in axes:
        plus = scorer.total(rotation_about(axis, curvature_step) @ rotation)
        minus = scorer.total(rotation_about(axis, -curvature_step) @ rotation)
        curvature = (plus - 2.0 * centre + minus) / curvature_step ** 2
        stds.append(np.degrees(np.sqrt(2.0 * noise / curvature)) if curvature > 0 else float("inf"))
    explained = (1.0 - float(before.sum()) / total_variance, 1.0 - float(after.sum()) / total_variance)
    if significance < MIN_SIGNIFICANCE:
        return ProbeRegistration(identity, 0.0, float(max(stds)), (explained[0], explained[0]), significance)
    _, angle = axis_angle(rotation)
    return ProbeRegistration(rotation, float(np.degrees(angle)), float(max(stds)), explained, significance)
