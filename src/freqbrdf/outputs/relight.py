"""Evaluation: relight an estimated material under the test views' lights, score it, compare maps.

For each test frame of a capture (``capture.test_frames``: a camera, its own environment map and
a reference photograph with its mask), the mesh with the estimated textures is path traced by
Mitsuba (``render.principled_bsdf``, the renderer of the synthetic captures) and scored with
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
    spp: int = 64  # samples per pixel of the relit renders
    max_depth: int = DEFAULT_MAX_DEPTH
    seed: int = 0  # render noise; view k uses render.view_seed(seed, k)
    lpips: bool = True  # LPIPS when its weights are installed (see freqbrdf.outputs.metrics)
    views: tuple[int, ...] | None = None  # test frame indices to evaluate; None: all


@dataclass(eq=False)
class RelitView:
    index: int  # test frame index
    image: str  # file name of the reference photograph
    envmap: str  # file name of its environment map
    scores: dict  # metrics.relighting_scores
    reference: np.ndarray  # (H, W, 3) float32 linear
    relit: np.ndarray  # (H, W, 3) float32 linear, unscaled render
    mask: np.ndarray  # (H, W) bool object mask of the reference
    render_seconds: float


@dataclass(eq=False)
class Evaluation:
    views: list[RelitView]
    relighting: dict  # mean of each score over the views (metrics.mean_scores)
    texture: dict | None  # metrics.texture_scores, or None without ground truth / observed mask
    settings: RelightSettings
    timings: dict = field(default_factory=dict)  # seconds


def relight_views(capture: Capture, materials: MaterialMaps, settings: RelightSettings = RelightSettings(),
                  reporter: Reporter = SILENT) -> list[RelitView]:
    """Render ``materials`` on the capture's mesh for each test frame and score it."""
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
    """Texture-space scores on the ``observed`` (T, T) texels, or None without ground truth."""
    if capture.ground_truth is None:
        return None
    return metrics.texture_scores(materials, capture.ground_truth, observed)


def evaluate(capture: Capture, materials: MaterialMaps, observed: np.ndarray | None = None,
             settings: RelightSettings = RelightSettings(), reporter: Reporter = SILENT) -> Evaluation:
    """Relighting scores over the test views and, given ``observed`` (T, T) bool, texture scores."""
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
    """(H, 3W, 3) display image in [0, 1]: reference | scaled relit | error heat map."""
    scale = np.asarray(view.scores["scale"], np.float32)
    reference = linear_to_srgb(view.reference)
    relit = linear_to_srgb(view.relit * scale)
    inside = metrics.erode_mask(view.mask)
    error = np.abs(relit - reference).mean(axis=-1) * inside
    heat = colormaps[ERROR_COLORMAP](np.clip(error / ERROR_RANGE, 0.0, 1.0))[..., :3]
    return np.concatenate([reference, relit, heat.astype(np.float32)], axis=1)


def write_evaluation(out_dir: str | Path, evaluation: Evaluation, extra: dict | None = None) -> Path:
    """Write ``metrics.json`` and ``relight/<index>.png`` into ``out_dir`` (each file atomically);
    ``extra`` is merged into ``metrics.json``."""
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
