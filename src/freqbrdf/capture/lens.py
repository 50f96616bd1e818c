"""Lens distortion: photographs taken through a real lens, made pinhole photographs as they are read.

Structure-from-motion (COLMAP, nerfstudio) gives each camera a distortion beside its pinhole
intrinsics, in OpenCV's models (docs/capture-format.md): ``OPENCV`` (radial k1..k4 as a polynomial
in r², tangential p1, p2) and ``OPENCV_FISHEYE`` (the angle from the axis distorted by k1..k4). The
rest of freqbrdf projects with the pinhole (`freqbrdf.capture.camera.Camera`), so each photograph and
its mask are read through the lens: the observations project each texel with the pinhole and then
through the lens (`distort_pixels`) and read the photograph as taken, once, where its ray lands; the
other readers (the masks' outlines, the checks, the relit views) read the photograph resampled onto
the pinhole image of the same size and intrinsics (`undistort_image`: cubic B-spline reads, negative
ringing cut at 0; pinhole pixels whose ray falls outside the photograph read 0 and are not object).

Normalised image coordinates follow OpenCV: x = (u - cx) / fx, y = (v - cy) / fy with u, v in the
pixel coordinates of `freqbrdf.capture.camera` (y runs down the image).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["LensDistortion", "distort", "distort_pixels", "undistort", "undistort_image", "unfolded"]

# Fixed-point steps of `undistort`: a lens that does not fold its image converges well within them.
UNDISTORT_STEPS = 50


@dataclass(frozen=True)
class LensDistortion:
    """A lens's distortion in one of OpenCV's models.

    Attributes
    ----------
    model : str
        ``"opencv"`` (radial and tangential) or ``"fisheye"`` (equidistant with a radial polynomial).
    radial : (4,) tuple of float
        k1, k2, k3, k4.
    tangential : (2,) tuple of float
        p1, p2 (``"opencv"`` only; zero for the fisheye).
    """

    model: str
    radial: tuple[float, float, float, float]
    tangential: tuple[float, float] = (0.0, 0.0)


def distort(x: np.ndarray, y: np.ndarray, lens: LensDistortion) -> tuple[np.ndarray, np.ndarray]:
    """Map pinhole normalised coordinates to where the lens images them.

    Parameters
    ----------
    x, y : (...) float64
        Normalised coordinates of the rays (x right, y down).
    lens : LensDistortion
        The lens.

    Returns
    -------
    (...) float64, (...) float64
        The distorted normalised coordinates.
    """
    k1, k2, k3, k4 = lens.radial
    r2 = x * x + y * y
    if lens.model == "fisheye":
        r = np.sqrt(r2)
        theta = np.arctan(r)
        t2 = theta * theta
        theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        scale = np.where(r > 1e-12, theta_d / np.where(r > 1e-12, r, 1.0), 1.0)
        return x * scale, y * scale
    p1, p2 = lens.tangential
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * (k3 + r2 * k4)))
    xy = x * y
    return (x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy)


def undistort(x_d: np.ndarray, y_d: np.ndarray, lens: LensDistortion) -> tuple[np.ndarray, np.ndarray]:
    """Invert `distort`: the pinhole normalised coordinates the lens images at ``x_d``, ``y_d``.

    By fixed-point steps x <- x - (distort(x) - x_d), as OpenCV's ``undistortPoints``.

    Parameters
    ----------
    x_d, y_d : (...) float64
        Distorted normalised coordinates.
    lens : LensDistortion
        The lens (`unfolded` over the coordinates given).

    Returns
    -------
    (...) float64, (...) float64
        The pinhole normalised coordinates.
    """
    x, y = np.array(x_d, np.float64), np.array(y_d, np.float64)
    for _ in range(UNDISTORT_STEPS):
        x_f, y_f = distort(x, y, lens)
        x, y = x - (x_f - x_d), y - (y_f - y_d)
    return x, y


def distort_pixels(x: np.ndarray, y: np.ndarray, camera, lens: LensDistortion) -> tuple[np.ndarray, np.ndarray]:
    """Map pinhole pixel coordinates to where the lens images them in the photograph.

    Parameters
    ----------
    x, y : (...) float64
        Pixel coordinates of the camera's pinhole image (`freqbrdf.capture.camera`).
    camera : Camera
        The pinhole intrinsics.
    lens : LensDistortion
        The lens.

    Returns
    -------
    (...) float64, (...) float64
        The photograph's pixel coordinates.
    """
    x_d, y_d = distort((x - camera.cx) / camera.fx, (y - camera.cy) / camera.fy, lens)
    return x_d * camera.fx + camera.cx, y_d * camera.fy + camera.cy


def unfolded(lens: LensDistortion, camera) -> bool:
    """Tell whether the lens maps the pinhole image without folding it.

    Its distorted radius must grow from the centre to every corner: coefficients of the wrong sign or
    units fold the image, and the photograph would be read twice over.

    Parameters
    ----------
    lens : LensDistortion
        The lens.
    camera : Camera
        The pinhole intrinsics and size (`freqbrdf.capture.camera.Camera`).

    Returns
    -------
    bool
        True where the radius grows monotonically along the rays to every corner.
    """
    corners_x = (np.array([0.0, camera.width]) - camera.cx) / camera.fx
    corners_y = (np.array([0.0, camera.height]) - camera.cy) / camera.fy
    steps = np.linspace(0.0, 1.0, 257)[:, None]
    for x_corner in corners_x:
        for y_corner in corners_y:
            x_d, y_d = distort(steps * x_corner, steps * y_corner, lens)
            if np.any(np.diff(np.hypot(x_d, y_d)[:, 0]) <= 0.0) or not np.all(np.isfinite(x_d) & np.isfinite(y_d)):
                return False
    return True


@functools.lru_cache(maxsize=8)
def _sample_coordinates(height: int, width: int, fx: float, fy: float, cx: float, cy: float,
                        lens: LensDistortion) -> np.ndarray:
    """(2, H, W) float64: the (row, column) of the photograph each pinhole pixel's centre reads."""
    rows, columns = np.mgrid[0:height, 0:width].astype(np.float64)
    x, y = (columns + 0.5 - cx) / fx, (rows + 0.5 - cy) / fy
    x_d, y_d = distort(x, y, lens)
    coordinates = np.stack([y_d * fy + cy - 0.5, x_d * fx + cx - 0.5])
    coordinates.flags.writeable = False
    return coordinates


def undistort_image(image: np.ndarray, camera, lens: LensDistortion) -> np.ndarray:
    """Resample a photograph taken through ``lens`` onto its camera's pinhole image.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        The photograph (or mask coverage), of the camera's size.
    camera : Camera
        Its pinhole intrinsics (`freqbrdf.capture.camera.Camera`).
    lens : LensDistortion
        The lens's distortion.

    Returns
    -------
    (H, W) or (H, W, C) float32
        The pinhole image: cubic reads of the photograph (at least 0), 0 where the ray falls outside it.
    """
    from scipy import ndimage  # a lens's resampling only

    coordinates = _sample_coordinates(camera.height, camera.width, float(camera.fx), float(camera.fy),
                                      float(camera.cx), float(camera.cy), lens)
    planes = image[..., None] if image.ndim == 2 else image
    out = np.empty(planes.shape, np.float32)
    for channel in range(planes.shape[2]):
        out[..., channel] = ndimage.map_coordinates(np.asarray(planes[..., channel], np.float32), coordinates,
                                                    order=3, mode="constant", cval=0.0)
    np.maximum(out, 0.0, out=out)  # the cubic's ringing at an edge: radiance and coverage are not negative
    return out[..., 0] if image.ndim == 2 else out
