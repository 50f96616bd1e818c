"""A capture checked against itself before any work: the mesh against the cameras, the frames, the light.

`load` (`freqbrdf.capture.layouts`) checks that every file is there and readable; a capture can
still be wrong in ways only the whole shows, which `check_capture` finds in about a second, before
the minutes of a fit (the capture format: docs/capture-format.md; what a fit needs: METHOD.md §3):

- the cameras against the mesh: the mesh in front of them (OpenCV's +Z-forward axes put it behind),
  of a size they can resolve (not a mesh in millimetres before cameras a metre away, nor one a
  pixel wide), inside the masks where there are masks (a misaligned mesh is not);
- the frames: at least two views, not black;
- the environment map: some light, and fine enough for the fits' SH degree.

A problem that makes the fit meaningless is an `InputError` naming the file at fault, with a hint
at the likely cause; what is only suspicious is returned as warnings.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from freqbrdf.capture.layouts import Capture
from freqbrdf.errors import InputError
from freqbrdf.images import CaptureDataWarning
from freqbrdf.sphere.sht import check_resolution

__all__ = ["CaptureCheck", "check_capture", "surface_points"]

# Points of the mesh projected per view (inside its faces, spread over a large mesh).
CHECK_VERTICES = 2000
# Views whose median vertex lies behind the camera: above this share the cameras face away.
MAX_BEHIND = 0.5
# The mesh's bounding radius over the median camera distance above which it cannot be in view.
MAX_SIZE_RATIO = 5.0
# Pixels the mesh must span in at least one view.
MIN_PIXELS = 4.0
# Share of the projected points inside the masks below which the mesh and masks disagree.
MIN_MASK_OVERLAP = 0.8
# A frame whose brightest pixel is below this is black.
BLACK = 1e-6


@dataclass
class CaptureCheck:
    """What `check_capture` measured of a capture.

    Attributes
    ----------
    figures : dict
        ``views``, ``behind`` (share of views with the mesh behind the camera), ``size_ratio``
        (bounding radius over the median camera distance), ``pixels`` (the mesh's largest extent
        in pixels over the views), ``mask_overlap`` (median share of projected points inside
        the masks; None without masks) and ``black_frames``.
    warnings : list of str
        Suspicious but usable data, one line per kind (black frames; the frames'
        `freqbrdf.images.CaptureDataWarning`, 8-bit or with negative noise, aggregated).
    """

    figures: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)


def check_capture(capture: Capture, read_frames: bool = True, lmax: int | None = None) -> CaptureCheck:
    """Check a loaded capture before any work; raise on what makes a fit meaningless.

    Parameters
    ----------
    capture : Capture
        The capture.
    read_frames : bool, optional
        Read every frame (and mask) to find black frames and the masks' overlap with the mesh.
    lmax : int, optional
        The SH degree of the fits, which the environment map must resolve; None: not checked.

    Returns
    -------
    CaptureCheck
        The figures and warnings.

    Raises
    ------
    InputError
        Fewer than two views, cameras facing away from the mesh (with a hint at OpenCV axes where
        flipping them would put it in front), a mesh far larger than the camera distance or too
        small to see, masks that the mesh does not fall in, every frame black, or an environment
        map without light or too coarse for ``lmax``.
    """
    transforms = capture.root / "transforms.json"
    source = transforms if transforms.is_file() else capture.root
    check = CaptureCheck()
    views = len(capture.frames)
    check.figures["views"] = views
    if views < 2:
        raise InputError(source, f"{views} view: every texel needs samples from at least two views to be estimated")
    vertices = np.asarray(capture.mesh.vertices, np.float64)
    points = surface_points(vertices, np.asarray(capture.mesh.faces))
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    radius = float(np.max(np.linalg.norm(vertices - centre, axis=1)))
    cameras = [frame.camera for frame in capture.frames]
    behind = np.mean([np.median(camera.project(points)[1]) <= 0.0 for camera in cameras])
    check.figures["behind"] = float(behind)
    if behind > MAX_BEHIND:
        flipped = np.mean([np.median(-camera.project(points)[1]) <= 0.0 for camera in cameras])
        hint = ("the cameras look along +Z, OpenCV's (COLMAP's) axes? transforms.json takes OpenGL's (the camera "
                "looks down -Z, +Y up): multiply each transform_matrix by diag(1, -1, -1, 1)"
                if flipped <= MAX_BEHIND else "the cameras face away from the mesh")
        raise InputError(source, f"the mesh is behind the camera in {behind:.0%} of the views: {hint}")
    distance = float(np.median([np.linalg.norm(camera.center - centre) for camera in cameras]))
    ratio = radius / max(distance, 1e-12)
    check.figures["size_ratio"] = ratio
    if ratio > MAX_SIZE_RATIO:
        raise InputError(capture.mesh.path or source,
                         f"the mesh is {ratio:.0f}x larger than the cameras' distance from it: a mesh in millimetres "
                         "(or centimetres) with cameras in metres? Scale it to the cameras' units")
    pixels = max(2.0 * radius * camera.fx / max(np.linalg.norm(camera.center - centre), 1e-12) for camera in cameras)
    check.figures["pixels"] = float(pixels)
    if pixels < MIN_PIXELS:
        raise InputError(source, f"the mesh spans {pixels:.2g} pixels in the closest view: cameras far too far (units?)")
    check.figures["mask_overlap"] = None
    check.figures["black_frames"] = 0
    if read_frames:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", CaptureDataWarning)
            _check_frames(capture, points, check)
        check.warnings += _aggregated(caught, views)
    if not float(np.max(capture.envmap.radiance)) > 0.0:
        raise InputError(capture.envmap_path, "the environment map has no light (every pixel is 0)")
    if lmax is not None:
        height, width = capture.envmap.radiance.shape[:2]
        try:
            check_resolution(height, width, lmax)
        except ValueError as err:
            raise InputError(capture.envmap_path, f"{err} (--lmax): choose a lower --lmax or a larger map") from None
    return check


def surface_points(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Return up to `CHECK_VERTICES` points inside a mesh's faces, spread over it.

    Vertices and edges lie on silhouettes, where a mask's rounding decides; points inside the
    faces do not.

    Parameters
    ----------
    vertices : (n_vertices, 3) float64
        The mesh's positions.
    faces : (n_faces, 3) int
        Its triangles.

    Returns
    -------
    (M, 3) float64
        Every k-th face's centroid and three points between it and the corners, deterministic.
    """
    weights = np.array([[1 / 3, 1 / 3, 1 / 3], [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])
    count = min(CHECK_VERTICES // len(weights), len(faces))
    picked = vertices[faces[np.linspace(0, len(faces) - 1, count).astype(np.int64)]]  # (count, 3, 3)
    return np.einsum("wk,fkc->fwc", weights, picked).reshape(-1, 3)


def _aggregated(caught: list, views: int) -> list[str]:
    """One line per kind of `CaptureDataWarning` the frames raised."""
    messages = [str(warning.message) for warning in caught if issubclass(warning.category, CaptureDataWarning)]
    srgb = [message for message in messages if "8-bit sRGB" in message]
    negative = [message for message in messages if "negative" in message]
    lines = []
    if srgb:
        lines.append(f"{len(srgb)} of {views} frames are 8-bit sRGB, linearised as radiance: clipped highlights and "
                     "quantisation bias the result; HDR input (.exr, .hdr) is preferred")
    if negative:
        lines.append(f"{len(negative)} of {views} frames had slightly negative pixels (HDR merge noise), clamped to "
                     f"0; first: {negative[0]}")
    return lines


def _check_frames(capture: Capture, points: np.ndarray, check: CaptureCheck) -> None:
    """Black frames and the masks' overlap with the projected mesh."""
    black, overlaps = [], []
    for index, frame in enumerate(capture.frames):
        if not float(np.max(capture.image(index))) > BLACK:
            black.append(frame.image_path)
        if frame.mask_path is None:
            continue
        mask = capture.mask(index)
        pixels, depth = frame.camera.project(points)
        inside = (depth > 0) & (pixels[:, 0] >= 0) & (pixels[:, 0] < mask.shape[1]) & (pixels[:, 1] >= 0) & (
            pixels[:, 1] < mask.shape[0])
        if inside.any():
            columns = pixels[inside, 0].astype(np.int64)
            rows = pixels[inside, 1].astype(np.int64)
            overlaps.append(float(np.mean(mask[rows, columns])))
    check.figures["black_frames"] = len(black)
    if len(black) == len(capture.frames):
        raise InputError(black[0], f"every frame is black ({len(black)} of {len(black)}): nothing to estimate from")
    if black:
        check.warnings.append(f"{len(black)} of {len(capture.frames)} frames are black (first: {black[0]})")
    if overlaps:
        overlap = float(np.median(overlaps))
        check.figures["mask_overlap"] = overlap
        if overlap < MIN_MASK_OVERLAP:
            raise InputError(capture.mesh.path or capture.root,
                             f"only {overlap:.0%} of the mesh's projected points fall inside the masks (an aligned "
                             "capture has nearly all): the mesh is not aligned with the cameras (another frame, "
                             "scale or axes?)")
