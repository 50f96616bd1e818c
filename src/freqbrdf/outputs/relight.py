"""Evaluation: relight an estimated material under the test views' lights, score it, compare maps.

The relighting and parameter-recovery judgements of docs/method.md#evaluation. For each test frame of a
capture (``capture.test_frames``: a camera, its own environment map and a reference photograph
with its mask), the mesh with the estimated textures is path traced by Mitsuba
(`freqbrdf.render.scenes.principled_bsdf`, the renderer of the synthetic captures) and scored with
Stanford-ORB's protocol (`freqbrdf.outputs.metrics.relighting_scores`). Frames sharing a light share one
scene. Captures with ground-truth maps are also scored in texture space on the observed texels
(`freqbrdf.outputs.metrics.texture_scores`).

Outputs (`write_evaluation`): ``metrics.json`` (per view and mean scores, texture scores,
settings, timings) and one side-by-side PNG per view in ``relight/``: reference | relit | error,
the first two sRGB-encoded and clipped to [0, 1] (the relit image after ORB's per-channel scale,
i.e. what was scored), the error the mean absolute sRGB difference inside the eroded mask shown
with magma over [0, ERROR_RANGE].
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from matplotlib import colormaps

from freqbrdf.capture.camera import Camera, look_at
from freqbrdf.capture.layouts import Capture
from freqbrdf.fileio import write_json
from freqbrdf.images import linear_to_srgb, write_png
from freqbrdf.model.materials import MaterialMaps
from freqbrdf.outputs import metrics
from freqbrdf.progress import SILENT, Reporter
from freqbrdf.render.scenes import (
    DEFAULT_MAX_DEPTH,
    build_scene,
    principled_bsdf,
    render_view,
    view_seed,
)

ERROR_RANGE = 0.25  # sRGB units mapped to the top of the error colour map
ERROR_COLORMAP = "magma"
METRICS_FILE = "metrics.json"
COMPARISON_FOLDER = "relight"


@dataclass(frozen=True)
class RelightSettings:
    """How the relit views are rendered and scored.

    Attributes
    ----------
    spp : int
        Samples per pixel of the relit renders.
    max_depth : int
        Maximum path length.
    seed : int
        Render noise; test view k uses ``view_seed(seed, k)`` (`freqbrdf.render.scenes`).
    lpips : bool
        Compute LPIPS when its weights are installed (see `freqbrdf.outputs.metrics`).
    views : tuple of int or None
        Test frame indices to evaluate; None: all.
    """

    spp: int = 64
    max_depth: int = DEFAULT_MAX_DEPTH
    seed: int = 0
    lpips: bool = True
    views: tuple[int, ...] | None = None


@dataclass(eq=False)
class RelitView:
    """One test view, relit and scored.

    Attributes
    ----------
    index : int
        The test frame's index.
    image : str
        File name of the reference photograph.
    envmap : str
        File name of its environment map.
    scores : dict
        `freqbrdf.outputs.metrics.relighting_scores` of the view.
    reference : (H, W, 3) float32
        The reference photograph, linear.
    relit : (H, W, 3) float32
        The render, linear, unscaled.
    mask : (H, W) bool
        The reference's object mask.
    render_seconds : float
        Time spent rendering the view.
    """

    index: int
    image: str
    envmap: str
    scores: dict
    reference: np.ndarray
    relit: np.ndarray
    mask: np.ndarray
    render_seconds: float


@dataclass(eq=False)
class Evaluation:
    """The scores of an estimate against a capture.

    Attributes
    ----------
    views : list of RelitView
        The relit test views.
    relighting : dict
        The mean of each score over the views (`freqbrdf.outputs.metrics.mean_scores`).
    texture : dict or None
        `freqbrdf.outputs.metrics.texture_scores`; None without ground truth or observed mask.
    settings : RelightSettings
        How the views were rendered.
    timings : dict
        Seconds: ``relight`` (all of it) and ``render`` (the renders alone).
    """

    views: list[RelitView]
    relighting: dict
    texture: dict | None
    settings: RelightSettings
    timings: dict = field(default_factory=dict)


def relight_views(capture: Capture, materials: MaterialMaps, settings: RelightSettings = RelightSettings(),
                  reporter: Reporter = SILENT) -> list[RelitView]:
    """Render material maps on the capture's mesh for each test frame, and score each view.

    Frames sharing a light share one scene.

    Parameters
    ----------
    capture : Capture
        The capture, with test frames.
    materials : MaterialMaps
        The maps to render.
    settings : RelightSettings, optional
        Render settings and the views to evaluate.
    reporter : Reporter, optional
        Receives progress.

    Returns
    -------
    list of RelitView
        In the order of ``settings.views`` (all test frames by default).

    Raises
    ------
    ValueError
        If a requested test view does not exist.
    """
    indices = list(range(len(capture.test_frames))) if settings.views is None else list(settings.views)
    for index in indices:
        if not 0 <= index < len(capture.test_frames):
            raise ValueError(f"test view {index} does not exist ({len(capture.test_frames)} test views)")
    # One scene per distinct light: building it (and Dr.Jit's compilation) dominates tiny renders.
    by_light: dict[tuple, list[int]] = {}
    for index in indices:
        frame = capture.test_frames[index]
        key = (str(frame.envmap_path), frame.envmap_scale, np.asarray(frame.envmap_to_world).tobytes())
        by_light.setdefault(key, []).append(index)
    results: dict[int, RelitView] = {}
    with reporter.stage("relighting", len(indices)) as advance:
        for group in by_light.values():
            # A fresh BSDF dict per scene: Mitsuba takes over the tensors of the one it loads.
            scene = build_scene(capture.mesh, principled_bsdf(materials), capture.test_envmap(group[0]),
                                settings.max_depth)
            for index in group:
                frame = capture.test_frames[index]
                start = time.perf_counter()
                relit = render_view(scene, frame.camera, settings.spp, view_seed(settings.seed, index)).radiance
                seconds = time.perf_counter() - start
                reference, mask = capture.test_image(index), capture.test_mask(index)
                results[index] = RelitView(
                    index=index,
                    image=frame.image_path.name,
                    envmap=frame.envmap_path.name if frame.envmap_path is not None else "",
                    scores=metrics.relighting_scores(relit, reference, mask, with_lpips=settings.lpips),
                    reference=reference,
                    relit=relit,
                    mask=mask,
                    render_seconds=seconds,
                )
                advance()
    return [results[index] for index in indices]


def texture_metrics(capture: Capture, materials: MaterialMaps, observed: np.ndarray) -> dict | None:
    """Score material maps in texture space against the capture's ground truth.

    Parameters
    ----------
    capture : Capture
        The capture.
    materials : MaterialMaps
        The estimated maps, T x T.
    observed : (T, T) bool
        The texels to score.

    Returns
    -------
    dict or None
        `freqbrdf.outputs.metrics.texture_scores`; None without ground truth.
    """
    if capture.ground_truth is None:
        return None
    return metrics.texture_scores(materials, capture.ground_truth, observed)


def evaluate(capture: Capture, materials: MaterialMaps, observed: np.ndarray | None = None,
             settings: RelightSettings = RelightSettings(), reporter: Reporter = SILENT) -> Evaluation:
    """Score material maps: relighting over the test views and, given observed texels, texture scores.

    Parameters
    ----------
    capture : Capture
        The capture.
    materials : MaterialMaps
        The estimated maps, T x T.
    observed : (T, T) bool, optional
        The texels to score in texture space; None: no texture scores.
    settings : RelightSettings, optional
        Render settings and the views to evaluate.
    reporter : Reporter, optional
        Receives progress.

    Returns
    -------
    Evaluation
        The relit views, their mean scores, the texture scores and timings.
    """
    start = time.perf_counter()
    views = relight_views(capture, materials, settings, reporter) if capture.test_frames else []
    relight_seconds = time.perf_counter() - start
    texture = None if observed is None else texture_metrics(capture, materials, observed)
    return Evaluation(
        views=views,
        relighting=metrics.mean_scores([view.scores for view in views]),
        texture=texture,
        settings=settings,
        timings={"relight": relight_seconds, "render": sum(view.render_seconds for view in views)},
    )


def comparison_image(view: RelitView) -> np.ndarray:
    """Make the side-by-side picture of a relit view: reference | scaled relit | error heat map.

    Parameters
    ----------
    view : RelitView
        The scored view.

    Returns
    -------
    (H, 3 W, 3) float32
        The picture in [0, 1]; the error is the mean absolute sRGB difference inside the eroded
        mask, over [0, ERROR_RANGE] of the magma colour map.
    """
    scale = np.asarray(view.scores["scale"], np.float32)
    reference = linear_to_srgb(view.reference)
    relit = linear_to_srgb(view.relit * scale)
    inside = metrics.erode_mask(view.mask)
    error = np.abs(relit - reference).mean(axis=-1) * inside
    heat = colormaps[ERROR_COLORMAP](np.clip(error / ERROR_RANGE, 0.0, 1.0))[..., :3]
    return np.concatenate([reference, relit, heat.astype(np.float32)], axis=1)


def write_evaluation(out_dir: str | Path, evaluation: Evaluation, extra: dict | None = None) -> Path:
    """Write ``metrics.json`` and ``relight/<index>.png`` into a folder, each file atomically.

    Parameters
    ----------
    out_dir : str or Path
        The folder.
    evaluation : Evaluation
        The scores.
    extra : dict, optional
        Merged into ``metrics.json``.

    Returns
    -------
    Path
        The ``metrics.json`` written.
    """
    out_dir = Path(out_dir)
    for view in evaluation.views:
        write_png(out_dir / COMPARISON_FOLDER / f"{view.index:04d}.png", comparison_image(view))
    document = {
        "relighting": evaluation.relighting,
        "views": [
            {"index": view.index, "image": view.image, "envmap": view.envmap,
             "comparison": f"{COMPARISON_FOLDER}/{view.index:04d}.png",
             "render_seconds": view.render_seconds, **view.scores}
            for view in evaluation.views
        ],
        "texture": evaluation.texture,
        "settings": asdict(evaluation.settings),
        "timings": evaluation.timings,
        "protocol": "Stanford-ORB relighting (see freqbrdf.outputs.metrics); PSNR in dB, inf written as null",
        **(extra or {}),
    }
    write_json(out_dir / METRICS_FILE, document)
    return out_dir / METRICS_FILE


# Directions on the sphere scored for the side the training views saw least (Fibonacci points).
UNSEEN_SIDE_CANDIDATES = 512
UNSEEN_SIDE_PICTURE = "unseen_side.png"


def unseen_side_camera(capture: Capture) -> Camera:
    """Place a camera on the side of the object the training views saw least.

    Its direction from the mesh's bounding-box centre is the one, of `UNSEEN_SIDE_CANDIDATES`
    spread over the sphere, farthest in angle from every training camera's; it stands at the
    training cameras' mean distance, looks at the centre, with the first training view's
    intrinsics.

    Parameters
    ----------
    capture : Capture
        The capture (at least one training frame).

    Returns
    -------
    Camera
        The camera.
    """
    vertices = capture.mesh.vertices
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    positions = np.array([frame.camera.camera_to_world[:3, 3] for frame in capture.frames])
    offsets = positions - centre
    distance = float(np.mean(np.linalg.norm(offsets, axis=1)))
    seen = offsets / np.maximum(np.linalg.norm(offsets, axis=1, keepdims=True), 1e-12)
    index = np.arange(UNSEEN_SIDE_CANDIDATES) + 0.5
    height = 1.0 - 2.0 * index / UNSEEN_SIDE_CANDIDATES
    azimuth = np.pi * (1.0 + 5.0 ** 0.5) * index
    ring = np.sqrt(1.0 - height ** 2)
    candidates = np.stack([ring * np.cos(azimuth), height, ring * np.sin(azimuth)], axis=1)
    direction = candidates[int(np.argmin((candidates @ seen.T).max(axis=1)))]
    up = np.array([0.0, 1.0, 0.0]) if abs(direction[1]) < 0.9 else np.array([0.0, 0.0, 1.0])
    first = capture.frames[0].camera
    return Camera(look_at(centre + distance * direction, centre, up), first.fx, first.fy, first.cx, first.cy,
                  first.width, first.height)


def unseen_side_picture(capture: Capture, materials: MaterialMaps, path: str | Path,
                        settings: RelightSettings = RelightSettings()) -> Path:
    """Render the fitted maps (and the ground truth, when there is one) from `unseen_side_camera`.

    Under the capture's own light, path traced by Mitsuba; the picture holds the ground truth on
    the left and the fit on the right (the fit alone without ground truth), sRGB, both at the
    exposure that maps the ground truth's (else the fit's) 99th-percentile object pixel to 1.

    Parameters
    ----------
    capture : Capture
        The capture.
    materials : MaterialMaps
        The fitted maps.
    path : str or Path
        The PNG to write (atomically).
    settings : RelightSettings, optional
        Samples per pixel, path length and seed of the renders.

    Returns
    -------
    Path
        The PNG.
    """
    camera = unseen_side_camera(capture)
    sets = [capture.ground_truth, materials] if capture.ground_truth is not None else [materials]
    renders = []
    for maps in sets:
        scene = build_scene(capture.mesh, principled_bsdf(maps), capture.envmap, settings.max_depth)
        renders.append(render_view(scene, camera, settings.spp, view_seed(settings.seed, 0)))
    first = renders[0]
    inside = first.coverage > 0.5
    peak = float(np.percentile(first.radiance[inside], 99)) if inside.any() else 1.0
    pictures = [linear_to_srgb(np.clip(render.radiance / max(peak, 1e-12), 0.0, 1.0)) for render in renders]
    write_png(path, np.concatenate(pictures, axis=1))
    return Path(path)
