"""Writing a capture's transforms file (docs/capture-format.md): what `freqbrdf.capture.layouts.load` reads back.

Used by the synthetic captures (`freqbrdf.synthetic.synth`) and the next views a fit proposes
(`freqbrdf.applications.next_views`); cameras round-trip bit for bit.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from freqbrdf.capture.camera import Camera
from freqbrdf.capture.layouts import Frame
from freqbrdf.fileio import atomic_path

__all__ = ["write_transforms"]


def write_transforms(
    path: str | Path,
    frames: Sequence[Frame],
    *,
    mesh: str | Path | None = None,
    envmap: str | Path | None = None,
    envmap_to_world: np.ndarray | None = None,
    envmap_scale: float | None = None,
    frame_fields: Sequence[dict[str, Any]] | None = None,
) -> None:
    """Write a transforms file of our format, atomically; `load` reads back identical cameras.

    Paths are stored relative to the file's folder. Intrinsics shared by all frames go to the top
    level. Frames with an ``envmap_path`` (test frames) get their own ``envmap``, to_world and
    scale.

    Parameters
    ----------
    path : str or Path
        The file to write (``transforms.json`` or ``transforms_test.json``).
    frames : sequence of Frame
        The frames, at least one.
    mesh, envmap : str or Path, optional
        The mesh and environment map; they belong in ``transforms.json``.
    envmap_to_world : (4, 4) array_like, optional
        The environment map's Mitsuba to_world.
    envmap_scale : float, optional
        The factor applied to the environment map's radiance.
    frame_fields : sequence of dict, optional
        One dict per frame, adding or overriding keys of its entry, e.g. Stanford-ORB's
        ``scene_name`` with a ``file_path`` relative to that scene's folder.

    Raises
    ------
    ValueError
        If ``frames`` is empty or ``frame_fields`` does not have one entry per frame.
    """
    path = Path(path)
    if not frames:
        raise ValueError("write_transforms needs at least one frame")
    if frame_fields is not None and len(frame_fields) != len(frames):
        raise ValueError(f"frame_fields has {len(frame_fields)} entries for {len(frames)} frames")
    folder = path.parent

    def relative(file: str | Path) -> str:
        return Path(os.path.relpath(Path(file).absolute(), folder.absolute())).as_posix()

    document: dict[str, Any] = {}
    if mesh is not None:
        document["mesh"] = relative(mesh)
    if envmap is not None:
        document["envmap"] = relative(envmap)
    if envmap_to_world is not None:
        document["envmap_to_world"] = np.asarray(envmap_to_world, dtype=np.float64).tolist()
    if envmap_scale is not None:
        document["envmap_scale"] = float(envmap_scale)

    intrinsics = [_intrinsics(frame.camera) for frame in frames]
    shared = all(values == intrinsics[0] for values in intrinsics)
    if shared:
        document.update(intrinsics[0])
    entries = []
    for frame, values in zip(frames, intrinsics):
        entry: dict[str, Any] = {"file_path": relative(frame.image_path)}
        if frame.mask_path is not None:
            entry["mask_path"] = relative(frame.mask_path)
        entry["transform_matrix"] = frame.camera.camera_to_world.tolist()
        if not shared:
            entry.update(values)
        if frame.envmap_path is not None:
            entry["envmap"] = relative(frame.envmap_path)
            to_world = np.eye(4) if frame.envmap_to_world is None else frame.envmap_to_world
            entry["envmap_to_world"] = np.asarray(to_world, dtype=np.float64).tolist()
            entry["envmap_scale"] = float(frame.envmap_scale)
        if frame_fields is not None:
            entry.update(frame_fields[len(entries)])
        entries.append(entry)
    document["frames"] = entries
    with atomic_path(path) as tmp:
        # json writes floats in shortest round-trip form, so cameras load back bit for bit.
        tmp.write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")


def _intrinsics(camera: Camera) -> dict[str, float | int]:
    return {
        "fl_x": float(camera.fx),
        "fl_y": float(camera.fy),
        "cx": float(camera.cx),
        "cy": float(camera.cy),
        "w": int(camera.width),
        "h": int(camera.height),
    }
