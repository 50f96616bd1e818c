"""Imperfections of a real capture applied to a rendered one: exposure, white balance, a turned probe,
camera error, sensor noise, 8-bit data, per-frame exposure, masks grown or shrunk; and a lens's distortion
(`lens_capture`, from a render at twice the resolution).

`imperfect_capture` copies a capture folder (our layout: transforms.json, images/, masks/, the
mesh, the map, gt/ and the test views linked, not copied) with the photographs and the
transforms (and the masks, where they are offset) changed as an `Imperfection` says. The photographs are changed, not the map: the map
is what a user's probe gives, the photographs what their camera gives. Deterministic: the same
imperfection and seed give the same bytes.

Scripts import this module after inserting benchmarks/ into sys.path (see _common.py).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from pathlib import Path

import numpy as np
from scipy import ndimage

from freqbrdf.calibrate import rotation_about
from freqbrdf.capture.layouts import load
from freqbrdf.capture.lens import LensDistortion, undistort
from freqbrdf.images import linear_to_srgb, read_image, read_mask, srgb_to_linear, write_exr, write_png


@dataclasses.dataclass(frozen=True)
class Imperfection:
    """What differs from a perfectly calibrated capture (the defaults: nothing)."""

    exposure: float = 1.0  # the photographs' radiance over the map's
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)  # per channel, on top of exposure
    probe_axis: tuple[float, float, float] = (0.0, 1.0, 0.0)  # the map's to_world is turned about this world axis
    probe_deg: float = 0.0  # by this angle
    camera_deg: float = 0.0  # every camera turned this much about a random axis
    camera_shift: float = 0.0  # and moved this share of its distance to the origin, in a random direction
    shot_noise: float = 0.0  # relative std of the noise at the photographs' mean object radiance
    read_noise: float = 0.0  # std of the noise added everywhere, in radiance
    eight_bit: bool = False  # sRGB-encoded at 8 bits, clipped at the 99th percentile of the object, read back
    highlight_clip: float = 0.0  # > 0: HDR values clipped at this quantile of the object's (a sensor's full well)
    frame_exposure_spread: float = 0.0  # each photograph's exposure times exp(N(0, spread))
    mask_offset_px: int = 0  # every mask grown (> 0, a segmentation's halo) or shrunk (< 0) by this many pixels
    seed: int = 0

    def name(self) -> str:
        """A short name listing what is not perfect ("clean" for nothing)."""
        parts = []
        if self.exposure != 1.0:
            parts.append(f"exposure{self.exposure:g}")
        if self.white_balance != (1.0, 1.0, 1.0):
            parts.append("wb" + "_".join(f"{value:g}" for value in self.white_balance))
        if self.probe_deg:
            parts.append(f"probe{self.probe_deg:g}deg_" + "_".join(f"{value:g}" for value in self.probe_axis))
        if self.camera_deg or self.camera_shift:
            parts.append(f"cameras{self.camera_deg:g}deg_{self.camera_shift:g}")
        if self.shot_noise or self.read_noise:
            parts.append(f"noise{self.shot_noise:g}_{self.read_noise:g}")
        if self.eight_bit:
            parts.append("8bit")
        if self.highlight_clip:
            parts.append(f"clip{self.highlight_clip:g}")
        if self.frame_exposure_spread:
            parts.append(f"frames{self.frame_exposure_spread:g}")
        if self.mask_offset_px:
            parts.append(f"masks{self.mask_offset_px:+d}px")
        return "+".join(parts) or "clean"


def _unit(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)


def _random_unit(rng: np.random.Generator) -> np.ndarray:
    return _unit(rng.normal(size=3))


def _offset_masks(source: Path, target: Path, transforms: dict, pixels: int) -> None:
    """Write every frame's mask grown (pixels > 0) or shrunk (< 0) by ``pixels`` (8-bit PNG)."""
    for frame in transforms["frames"]:
        mask = read_mask(source / frame["mask_path"])
        moved = (ndimage.binary_dilation(mask, iterations=pixels) if pixels > 0
                 else ndimage.binary_erosion(mask, iterations=-pixels))
        path = target / frame["mask_path"]
        path.parent.mkdir(parents=True, exist_ok=True)
        write_png(path, moved.astype(np.float32))


def _scratch_of(source: Path, target: Path) -> tuple[Path, dict]:
    """Make ``target``'s empty scratch folder (renamed into place when written) and read ``source``'s transforms."""
    scratch = target.with_name(target.name + ".partial")
    shutil.rmtree(scratch, ignore_errors=True)
    scratch.mkdir(parents=True)
    return scratch, json.loads((source / "transforms.json").read_text())


def imperfect_capture(source: Path, target: Path, imperfection: Imperfection) -> Path:
    """Write ``source`` with ``imperfection`` applied into ``target`` (reused where already written).

    Parameters
    ----------
    source : Path
        A capture folder in our layout.
    target : Path
        The folder to write.
    imperfection : Imperfection
        What to change.

    Returns
    -------
    Path
        ``target``.
    """
    source, target = Path(source).resolve(), Path(target)
    if (target / "transforms.json").is_file():
        return target
    scratch, transforms = _scratch_of(source, target)
    rng = np.random.default_rng(imperfection.seed)
    for name in os.listdir(source):
        if name not in ("transforms.json", "images") and not (name == "masks" and imperfection.mask_offset_px):
            os.symlink(source / name, scratch / name)
    if imperfection.mask_offset_px:
        _offset_masks(source, scratch, transforms, imperfection.mask_offset_px)
    (scratch / "images").mkdir()
    if imperfection.probe_deg:
        turn = np.eye(4)
        turn[:3, :3] = rotation_about(_unit(np.array(imperfection.probe_axis, np.float64)), np.radians(imperfection.probe_deg))
        transforms["envmap_to_world"] = (turn @ np.array(transforms.get("envmap_to_world", np.eye(4)))).tolist()
    gain = imperfection.exposure * np.array(imperfection.white_balance, np.float32)
    for frame in transforms["frames"]:
        matrix = np.array(frame["transform_matrix"], np.float64)
        if imperfection.camera_deg:
            matrix[:3, :3] = rotation_about(_random_unit(rng), np.radians(imperfection.camera_deg)) @ matrix[:3, :3]
        if imperfection.camera_shift:
            matrix[:3, 3] += imperfection.camera_shift * np.linalg.norm(matrix[:3, 3]) * _random_unit(rng)
        frame["transform_matrix"] = matrix.tolist()
        image = read_image(source / frame["file_path"]) * gain
        if imperfection.frame_exposure_spread:
            image = image * np.float32(np.exp(rng.normal(0.0, imperfection.frame_exposure_spread)))
        if imperfection.shot_noise or imperfection.read_noise:
            level = float(np.mean(image[image.max(axis=2) > 0])) if np.any(image > 0) else 1.0
            std = np.sqrt(imperfection.shot_noise ** 2 * level * np.maximum(image, 0.0) + imperfection.read_noise ** 2)
            image = np.maximum(image + std * rng.normal(size=image.shape).astype(np.float32), 0.0)
        if imperfection.highlight_clip:
            lit = image[image.max(axis=2) > 0]
            image = np.minimum(image, float(np.quantile(lit, imperfection.highlight_clip)) if lit.size else np.inf)
        if imperfection.eight_bit:
            lit = image[image.max(axis=2) > 0]
            white = float(np.percentile(lit, 99.0)) if lit.size else 1.0
            encoded = np.round(linear_to_srgb(image / white) * 255.0) / 255.0
            image = srgb_to_linear(encoded) * white
        write_exr(scratch / frame["file_path"], image.astype(np.float32))
    (scratch / "transforms.json").write_text(json.dumps(transforms, indent=1))
    shutil.rmtree(target, ignore_errors=True)
    scratch.rename(target)
    return target


def lens_capture(source: Path, fine: Path, target: Path, lens: LensDistortion, declared: bool) -> Path:
    """Write ``source`` as photographed through ``lens`` into ``target`` (reused where already written).

    Each pixel of a photograph (and of its mask's coverage, then cut at 0.5) is the mean of 2 x 2
    sub-pixels, each read bilinearly from ``fine`` (the same capture rendered at twice the
    resolution) at the pinhole ray the lens bends onto it: one resampling of the scene, as a
    lens's photograph has, the rest of the blur the renderer's pixel filter.

    Parameters
    ----------
    source : Path
        A capture folder in our layout (its cameras, mesh, map, gt/ and test views are kept).
    fine : Path
        The same capture rendered at twice the resolution (the same cameras).
    target : Path
        The folder to write.
    lens : LensDistortion
        The lens.
    declared : bool
        Write the lens into transforms.json (``camera_model`` OPENCV and its coefficients); else the
        photographs pass for pinhole ones.

    Returns
    -------
    Path
        ``target``.
    """
    source, fine, target = Path(source).resolve(), Path(fine).resolve(), Path(target)
    if (target / "transforms.json").is_file():
        return target
    scratch, transforms = _scratch_of(source, target)
    for name in os.listdir(source):
        if name not in ("transforms.json", "images", "masks"):
            os.symlink(source / name, scratch / name)
    cameras = [frame.camera for frame in load(source).frames]
    fine_frames = load(fine).frames
    for frame, camera, fine_frame in zip(transforms["frames"], cameras, fine_frames):
        coordinates = _lens_coordinates(camera, fine_frame.camera, lens)
        image = _supersampled(read_image(fine_frame.image_path), coordinates)
        mask = _supersampled(read_mask(fine_frame.mask_path).astype(np.float32), coordinates) > 0.5
        for relative, pixels in ((frame["file_path"], image), (frame["mask_path"], mask.astype(np.float32))):
            (scratch / relative).parent.mkdir(parents=True, exist_ok=True)
            (write_exr if relative.endswith(".exr") else write_png)(scratch / relative, pixels)
    if declared:
        transforms.update(camera_model="OPENCV", k1=lens.radial[0], k2=lens.radial[1], k3=lens.radial[2],
                          k4=lens.radial[3], p1=lens.tangential[0], p2=lens.tangential[1])
    (scratch / "transforms.json").write_text(json.dumps(transforms, indent=1))
    shutil.rmtree(target, ignore_errors=True)
    scratch.rename(target)
    return target


def _lens_coordinates(camera, fine_camera, lens: LensDistortion) -> np.ndarray:
    """(4, 2, H, W): for each pixel's 2 x 2 sub-pixels, the (row, column) of the fine render its pinhole ray meets."""
    found = []
    for row_offset in (0.25, 0.75):
        for column_offset in (0.25, 0.75):
            rows, columns = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
            x_d = (columns + column_offset - camera.cx) / camera.fx
            y_d = (rows + row_offset - camera.cy) / camera.fy
            x, y = undistort(x_d, y_d, lens)
            found.append(np.stack([y * fine_camera.fy + fine_camera.cy - 0.5, x * fine_camera.fx + fine_camera.cx - 0.5]))
    return np.stack(found)


def _supersampled(pixels: np.ndarray, coordinates: np.ndarray) -> np.ndarray:
    """The mean over the sub-pixels of bilinear reads of ``pixels`` (H', W'[, C]) at ``coordinates`` (4, 2, H, W)."""
    planes = pixels[..., None] if pixels.ndim == 2 else pixels
    out = np.mean([np.stack([ndimage.map_coordinates(planes[..., c].astype(np.float64), where, order=1, mode="nearest")
                             for c in range(planes.shape[2])], axis=-1) for where in coordinates], axis=0)
    out = out.astype(np.float32)
    return out[..., 0] if pixels.ndim == 2 else out
