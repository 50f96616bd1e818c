"""The peer baseline: Mitsuba 3 inverse rendering of the material maps from the same capture.

This is what a user would otherwise run, and a baseline of every results table (docs/method.md#evaluation,
which also quotes its Stanford-ORB relighting scores): the Principled BSDF's base colour,
roughness and metallic textures are optimised by gradient descent through Mitsuba's path-replay
backpropagation integrator (``prb``), with the authors' prototype's recipe:

- Adam (beta 0.9 / 0.999, eps 1e-8), parameters clamped to [0, 1] after every step;
- L1 loss on log-then-gamma compressed radiance (``compress_radiance``), so that the loss is
  about relative errors and the bright environment reflections do not drown dark texels;
- texture-space total variation, weight 1e-3.

Departures from the prototype, each for a stated reason:

- it drew one image's worth of random pixels from all views per step (a custom ray integrator);
  we render whole views with ``mi.render`` (``views_per_step`` random views per step), the
  standard Mitsuba workflow, and take the loss only on pixels inside the object's mask;
- its TV also ran across texels outside the UV charts, which never receive gradients, dragging
  chart borders towards the initial value; ours only couples pairs of covered texels;
- it initialised metallic at 0.5 like the other maps; we start at 0 (see ``INITIAL_METALLIC``).

The scene is `freqbrdf.render.scenes.build_scene` with `principled_bsdf`, i.e. exactly the scene the
synthetic captures were rendered from: on those captures its errors come from the data and the
optimisation, never from a mismatched forward model.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from freqbrdf.capture.layouts import Capture
from freqbrdf.errors import InputError
from freqbrdf.model.materials import MaterialMaps
from freqbrdf.render.scenes import (
    DEFAULT_MAX_DEPTH,
    build_scene,
    mitsuba,
    path_integrator,
    perspective_sensor,
    principled_bsdf,
    view_seed,
)
from freqbrdf.texels import rasterise

# Defaults sized for a CPU and the small synthetic captures.
DEFAULT_TEXTURE_RES = 256
DEFAULT_ITERATIONS = 256
DEFAULT_SPP = 16  # per pixel, primal and adjoint pass alike; the prototype's Stanford-ORB setting
DEFAULT_LEARNING_RATE = 0.01  # the prototype's
DEFAULT_TV_WEIGHT = 1e-3  # the prototype's

# Initial maps. Base colour and roughness start mid-range, as in the prototype: roughness 0.5
# gives usable gradients towards both glossy and matte (a near-mirror start would see the
# environment only along isolated mirror directions). Metallic starts at 0 rather than the
# prototype's 0.5: most real texels are dielectrics, and at m = 0 the base colour is seen through
# the diffuse lobe in every pixel, so it converges first, while the metallic gradient stays
# informative (raising m trades diffuse for a tinted specular lobe).
INITIAL_BASE_COLOR = 0.5
INITIAL_ROUGHNESS = 0.5
INITIAL_METALLIC = 0.0

# The prototype's compression: radiance scaled by 2^16, log with epsilon 1e-6 normalised to 1 at
# scaled radiance 1, then the sRGB gamma 1.055 y^(1/2.4) (its -0.055 offset cancels in residuals).
LOG_SCALE = 2.0**16
LOG_EPSILON = 1e-6
GAMMA = 2.4
GAMMA_SLOPE = 1.055

TEXTURE_KEYS = {
    name: f"object.bsdf.{name}.data" for name in ("base_color", "roughness", "metallic")
}  # `build_scene` names the shape "object"

SETTINGS = Path("mitsuba_inverse settings")  # what InputError names for a bad argument

# Called at requested iteration counts with (iterations done, seconds so far, current maps).
CheckpointCallback = Callable[[int, float, MaterialMaps], None]


def compress_radiance(radiance):
    """Compress linear radiance by log then gamma, as the prototype's loss did.

    Parameters
    ----------
    radiance : Dr.Jit array or tensor
        Linear radiance, any shape.

    Returns
    -------
    Dr.Jit array or tensor
        The compressed radiance, same shape.
    """
    import drjit as dr

    scaled = radiance * (LOG_SCALE / LOG_EPSILON)
    normalised_log = dr.log(1.0 + scaled) / math.log1p(1.0 / LOG_EPSILON)
    # Exactly 0 (a pixel with no light) would have an infinite gamma slope; such pixels get none.
    return GAMMA_SLOPE * dr.power(dr.maximum(normalised_log, 1e-12), 1.0 / GAMMA)


def texture_total_variation(texture, pair_weights: tuple, n_texels: int):
    """Sum |differences| between adjacent covered texels, per covered texel.

    Parameters
    ----------
    texture : (T, T, C) Dr.Jit tensor
        The texture.
    pair_weights : tuple of two Dr.Jit tensors
        (T, T-1, 1) and (T-1, T, 1): 1 where both texels of a horizontal or vertical pair are
        covered, else 0.
    n_texels : int
        The number of covered texels.

    Returns
    -------
    Dr.Jit scalar
        The total variation, summed over channels and pairs, divided by ``n_texels``.
    """
    import drjit as dr

    across, down = pair_weights
    horizontal = dr.sum(across * dr.abs(texture[:, 1:, :] - texture[:, :-1, :]), axis=None)
    vertical = dr.sum(down * dr.abs(texture[1:, :, :] - texture[:-1, :, :]), axis=None)
    return (horizontal + vertical) / n_texels


def mitsuba_inverse(
    capture: Capture,
    texture_res: int = DEFAULT_TEXTURE_RES,
    iterations: int = DEFAULT_ITERATIONS,
    spp: int = DEFAULT_SPP,
    learning_rate: float = DEFAULT_LEARNING_RATE,
    tv_weight: float = DEFAULT_TV_WEIGHT,
    seed: int = 0,
    views_per_step: int = 1,
    max_depth: int = DEFAULT_MAX_DEPTH,
    checkpoints: Sequence[int] = (),
    on_checkpoint: CheckpointCallback | None = None,
) -> tuple[MaterialMaps, float, np.ndarray]:
    """Estimate the material maps of a capture by Mitsuba inverse rendering.

    Each Adam step renders ``views_per_step`` training views chosen at random and
    back-propagates the masked L1 loss of the compressed radiance plus ``tv_weight`` times the
    total variation of the three textures.

    Parameters
    ----------
    capture : Capture
        The capture (V views).
    texture_res : int, optional
        The texture side T of the estimated maps.
    iterations : int, optional
        Number of Adam steps.
    spp : int, optional
        Samples per pixel, primal and adjoint pass alike.
    learning_rate : float, optional
        Adam's learning rate, > 0.
    tv_weight : float, optional
        Weight of the texture-space total variation, >= 0.
    seed : int, optional
        Seeds the choice of views and the renders.
    views_per_step : int, optional
        Views rendered per step (at most V).
    max_depth : int, optional
        Maximum path length; should match the renderer of the photographs
        (``DEFAULT_MAX_DEPTH`` for our synthetic captures).
    checkpoints : sequence of int, optional
        Step counts after which ``on_checkpoint`` is called.
    on_checkpoint : callable (int, float, MaterialMaps) -> None, optional
        Called with the steps done, the seconds so far and the current maps.

    Returns
    -------
    maps : MaterialMaps
        The maps, T x T; texels outside the UV charts keep their initial values.
    seconds : float
        Wall-clock time from capture to maps (loading images, building the scene and compiling
        kernels included; time spent in ``on_checkpoint`` excluded).
    loss : (iterations,) float64
        The loss of each step.

    Raises
    ------
    InputError
        If a count is not a positive integer, ``learning_rate`` <= 0 or ``tv_weight`` < 0.
    """
    counts = {"texture_res": texture_res, "iterations": iterations, "spp": spp,
              "views_per_step": views_per_step, "max_depth": max_depth}
    for name, value in counts.items():
        if not (isinstance(value, int) and value >= 1):
            raise InputError(SETTINGS, f"{name} must be a positive integer, got {value!r}")
    if not learning_rate > 0 or not tv_weight >= 0:
        raise InputError(
            SETTINGS, f"need learning_rate > 0 and tv_weight >= 0, got {learning_rate}, {tv_weight}"
        )
    mi = mitsuba()
    import drjit as dr

    start = time.perf_counter()
    callback_seconds = 0.0
    n_views = len(capture.frames)
    views_per_step = min(views_per_step, n_views)

    initial = MaterialMaps(
        np.full((texture_res, texture_res, 3), INITIAL_BASE_COLOR, np.float32),
        np.full((texture_res, texture_res), INITIAL_ROUGHNESS, np.float32),
        np.full((texture_res, texture_res), INITIAL_METALLIC, np.float32),
    )
    scene = build_scene(capture.mesh, principled_bsdf(initial), capture.envmap, max_depth)
    # The same path tracer as `build_scene`'s (depth, visible environment), with adjoint passes.
    integrator = mi.load_dict({**path_integrator(max_depth), "type": "prb"})
    sensors = [mi.load_dict(perspective_sensor(frame.camera, spp)) for frame in capture.frames]
    targets, masks, mask_pixels = [], [], []
    for view in range(n_views):
        mask = capture.mask(view)  # (H, W) bool
        targets.append(compress_radiance(mi.TensorXf(capture.image(view))))  # (H, W, 3)
        masks.append(mi.TensorXf(mask[..., None].astype(np.float32)))  # (H, W, 1)
        mask_pixels.append(max(int(mask.sum()), 1))

    covered = rasterise(capture.mesh, texture_res).mask  # (T, T) bool, our texture orientation
    pair_weights = (
        mi.TensorXf((covered[:, 1:] & covered[:, :-1])[..., None].astype(np.float32)),
        mi.TensorXf((covered[1:, :] & covered[:-1, :])[..., None].astype(np.float32)),
    )
    n_covered = int(covered.sum())

    params = mi.traverse(scene)
    optimizer = mi.ad.Adam(lr=learning_rate)
    for key in TEXTURE_KEYS.values():
        optimizer[key] = params[key]
    params.update(optimizer)

    def current_maps() -> MaterialMaps:
        maps = {name: np.array(params[key], dtype=np.float32) for name, key in TEXTURE_KEYS.items()}
        return MaterialMaps(maps["base_color"], maps["roughness"][..., 0], maps["metallic"][..., 0])

    rng = np.random.default_rng(seed)
    checkpoints = set(checkpoints)
    loss_history = np.empty(iterations)
    for step in range(iterations):
        step_loss = 0.0
        for view in rng.choice(n_views, size=views_per_step, replace=False):
            image = mi.render(
                scene, params, sensor=sensors[view], integrator=integrator, spp=spp, spp_grad=spp,
                seed=view_seed(seed, step * n_views + int(view)),
            )
            residual = dr.abs(compress_radiance(image[:, :, :3]) - targets[view])
            data_loss = dr.sum(masks[view] * residual, axis=None) / (
                3 * mask_pixels[view] * views_per_step
            )
            dr.backward(data_loss)  # gradients of the views add up in the textures
            step_loss += data_loss.array[0]
        if tv_weight > 0:
            tv_loss = tv_weight * sum(
                texture_total_variation(optimizer[key], pair_weights, n_covered)
                for key in TEXTURE_KEYS.values()
            )
            dr.backward(tv_loss)
            step_loss += tv_loss.array[0]
        optimizer.step()
        for key in TEXTURE_KEYS.values():
            optimizer[key] = dr.clip(optimizer[key], 0.0, 1.0)
        params.update(optimizer)
        loss_history[step] = step_loss
        if on_checkpoint is not None and step + 1 in checkpoints:
            tick = time.perf_counter()
            maps = current_maps()
            elapsed = tick - start - callback_seconds
            on_checkpoint(step + 1, elapsed, maps)
            callback_seconds += time.perf_counter() - tick

    maps = current_maps()
    return maps, time.perf_counter() - start - callback_seconds, loss_history
