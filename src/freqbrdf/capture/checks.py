"""A capture checked against itself before any work: the mesh against the cameras, the frames, the light.

`load` (`freqbrdf.capture.layouts`) checks that every file is there and readable; a capture can
still be wrong in ways only the whole shows, which `check_capture` finds in about a second, before
the minutes of a fit (the capture format: docs/capture-format.md; what a fit needs: docs/method.md#pipeline):

- the cameras against the mesh: the mesh in front of them (OpenCV's +Z-forward axes put it behind),
  of a size they can resolve (not a mesh in millimetres before cameras a metre away, nor one a
  pixel wide), inside the masks where there are masks (a misaligned mesh is not);
- the frames: at least two distinct views, each principal point inside its image, not black, masks
  not empty, not the same pose twice, exposed alike, and HDR (not clipped at 1 or on 8-bit steps);
- the fits' SH degree: not far beyond what the views per texel can determine;
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
from freqbrdf.images import HDR_SUFFIXES, CaptureDataWarning, SrgbImageWarning
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
# A frame whose median object radiance differs from the frames' median by more than this factor
# (either way) is exposed differently: views of one object under one light stay well within it.
EXPOSURE_FACTOR = 10.0
# An HDR frame whose values all lie on 1/255 steps, or whose brightest values sit at 1.0 in more
# than this share of its lit pixels, holds LDR data.
CLIPPED_SHARE = 0.005
# The unknowns of one texel's SH fit, (lmax + 1)^2, above this multiple of the views that can see
# a point of the mesh: the degree is far beyond what the samples determine (and costs O(lmax^4)).
MAX_UNKNOWNS_PER_VIEW = 16


@dataclass
class CaptureCheck:
    """What `check_capture` measured of a capture.

    Attributes
    ----------
    figures : dict
        ``views``, ``behind`` (share of views with the mesh behind the camera), ``size_ratio``
        (bounding radius over the median camera distance), ``pixels`` (the mesh's largest extent
        in pixels over the views), ``views_per_point`` (median and most views that see a point
        of the mesh, occlusion aside), ``duplicate_poses``, ``mask_overlap`` (median share of
        projected points inside the masks; None without masks), ``black_frames``,
        ``exposure_range`` (the least and most median object radiance over the frames' median)
        and ``ldr_frames``.
    warnings : list of str
        Suspicious but usable data, one line per kind (black frames, duplicate poses, frames
        exposed differently, LDR data in HDR files; the frames'
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
        small to see, masks that the mesh does not fall in, every frame black, an ``lmax`` with
        far more unknowns than views per point, or an environment map without light or too coarse
        for ``lmax``.
    """
    transforms = capture.root / "transforms.json"
    source = transforms if transforms.is_file() else capture.root
    check = CaptureCheck()
    views = len(capture.frames)
    check.figures["views"] = views
    if views < 2:
        raise InputError(source, f"{views} view: every texel needs samples from at least two views to be estimated")
    duplicates = _duplicate_poses([frame.camera for frame in capture.frames])
    if views - len(duplicates) < 2:
        raise InputError(source, f"the {views} frames share one camera pose: every texel needs samples from at least "
                                 "two views to be estimated (copied entries?)")
    for index, frame in enumerate(capture.frames):
        camera = frame.camera
        if not (0.0 <= camera.cx <= camera.width and 0.0 <= camera.cy <= camera.height):
            raise InputError(source, f"frame {index}: the principal point (cx, cy) = ({camera.cx:g}, {camera.cy:g}) "
                                     f"lies outside its {camera.width}x{camera.height} image (pixels, from the "
                                     "top-left corner)")
    vertices = np.asarray(capture.mesh.vertices, np.float64)
    points, normals = _surface_points_and_normals(vertices, np.asarray(capture.mesh.faces),
                                                  np.asarray(capture.mesh.normals, np.float64))
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
    counts = _views_per_point(capture, points, normals)
    check.figures["views_per_point"] = {"median": float(np.median(counts)), "most": int(counts.max())}
    if lmax is not None and (lmax + 1) ** 2 > MAX_UNKNOWNS_PER_VIEW * max(int(counts.max()), 1):
        highest = int(np.sqrt(MAX_UNKNOWNS_PER_VIEW * max(int(counts.max()), 1))) - 1
        raise InputError(source, f"--lmax {lmax} fits (lmax+1)^2 = {(lmax + 1) ** 2} SH coefficients per texel, but "
                                 f"at most {counts.max()} views see any point of the mesh: choose --lmax {highest} or "
                                 "lower, or take more views")
    check.figures["duplicate_poses"] = len(duplicates)
    if duplicates:
        first, second = duplicates[0]
        check.warnings.append(f"{len(duplicates)} frame(s) repeat an earlier frame's camera exactly (first: frame "
                              f"{second} = frame {first}, {capture.frames[second].image_path.name}): a copied entry?")
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
    return _surface_points_and_normals(vertices, faces)[0]


def _surface_points_and_normals(vertices: np.ndarray, faces: np.ndarray,
                                vertex_normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`surface_points` (M, 3) and the shading normals there (M, 3), from ``vertex_normals`` (or none)."""
    weights = np.array([[1 / 3, 1 / 3, 1 / 3], [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])
    count = min(CHECK_VERTICES // len(weights), len(faces))
    picked = faces[np.linspace(0, len(faces) - 1, count).astype(np.int64)]  # (count, 3)
    points = np.einsum("wk,fkc->fwc", weights, vertices[picked]).reshape(-1, 3)
    if vertex_normals is None:
        return points, np.zeros_like(points)
    normals = np.einsum("wk,fkc->fwc", weights, vertex_normals[picked]).reshape(-1, 3)
    return points, normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)


def _views_per_point(capture: Capture, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """How many views see each point (M,): in front of the camera, inside its image, facing it."""
    counts = np.zeros(len(points), np.int64)
    for frame in capture.frames:
        camera = frame.camera
        pixels, depth = camera.project(points)
        inside = (depth > 0) & (pixels[:, 0] >= 0) & (pixels[:, 0] < camera.width) & (pixels[:, 1] >= 0) & (
            pixels[:, 1] < camera.height)
        facing = np.sum(normals * (camera.center - points), axis=1) > 0
        counts += inside & facing
    return counts


def _duplicate_poses(cameras: list) -> list[tuple[int, int]]:
    """(earlier, later) index pairs of frames with exactly the same camera."""
    first_of, pairs = {}, []
    for index, camera in enumerate(cameras):
        key = (np.asarray(camera.camera_to_world).tobytes(), camera.fx, camera.fy, camera.cx, camera.cy,
               camera.width, camera.height)
        if key in first_of:
            pairs.append((first_of[key], index))
        else:
            first_of[key] = index
    return pairs


def _aggregated(caught: list, views: int) -> list[str]:
    """One line per kind of `CaptureDataWarning` the frames raised."""
    srgb = [warning.message for warning in caught if issubclass(warning.category, SrgbImageWarning)]
    negative = [str(warning.message) for warning in caught if issubclass(warning.category, CaptureDataWarning)
                and not issubclass(warning.category, SrgbImageWarning) and "negative" in str(warning.message)]
    lines = []
    if srgb:
        depths = " or ".join(str(bits) for bits in sorted({warning.bits for warning in srgb}))
        lines.append(f"{len(srgb)} of {views} frames are {depths}-bit sRGB, linearised as radiance: clipped highlights and "
                     "quantisation bias the result; HDR input (.exr, .hdr) is preferred")
    if negative:
        lines.append(f"{len(negative)} of {views} frames had slightly negative pixels (HDR merge noise), clamped to "
                     f"0; first: {negative[0]}")
    return lines


def _check_frames(capture: Capture, points: np.ndarray, check: CaptureCheck) -> None:
    """Black frames, exposure, LDR data in HDR files, and the masks' overlap with the projected mesh."""
    black, overlaps, levels, ldr, empty = [], [], [], [], []
    for index, frame in enumerate(capture.frames):
        image = capture.image(index)
        mask = capture.mask(index)
        if not float(np.max(image)) > BLACK:
            black.append(frame.image_path)
        if frame.mask_path is not None and not mask.any():
            empty.append(frame.mask_path)
        object_pixels = image[mask] if mask.any() else image.reshape(-1, 3)
        levels.append(float(np.median(object_pixels.mean(axis=1))))
        if frame.image_path.suffix.lower() in HDR_SUFFIXES and _looks_ldr(image):
            ldr.append(frame.image_path)
        if frame.mask_path is None:
            continue
        pixels, depth = frame.camera.project(points)
        inside = (depth > 0) & (pixels[:, 0] >= 0) & (pixels[:, 0] < mask.shape[1]) & (pixels[:, 1] >= 0) & (
            pixels[:, 1] < mask.shape[0])
        if inside.any():
            columns = pixels[inside, 0].astype(np.int64)
            rows = pixels[inside, 1].astype(np.int64)
            overlaps.append(float(np.mean(mask[rows, columns])))
    _check_exposure(capture, np.array(levels), check)
    check.figures["ldr_frames"] = len(ldr)
    if ldr:
        check.warnings.append(f"{len(ldr)} of {len(capture.frames)} HDR frames hold LDR data (values clipped at 1.0 "
                              f"or on 1/255 steps; first: {ldr[0]}): sRGB-encoded or clipped images bias the "
                              "estimate, give linear HDR radiance")
    check.figures["black_frames"] = len(black)
    if len(black) == len(capture.frames):
        raise InputError(black[0], f"every frame is black ({len(black)} of {len(black)}): nothing to estimate from")
    if black:
        check.warnings.append(f"{len(black)} of {len(capture.frames)} frames are black (first: {black[0]})")
    check.figures["empty_masks"] = len(empty)
    if empty:
        check.warnings.append(f"{len(empty)} of {len(capture.frames)} masks are empty (first: {empty[0]}): those "
                              "frames see nothing of the object")
    if overlaps:
        overlap = float(np.median(overlaps))
        check.figures["mask_overlap"] = overlap
        if overlap < MIN_MASK_OVERLAP:
            raise InputError(capture.mesh.path or capture.root,
                             f"only {overlap:.0%} of the mesh's projected points fall inside the masks (an aligned "
                             "capture has nearly all): the mesh is not aligned with the cameras (another frame, "
                             "scale or axes?)")


def _looks_ldr(image: np.ndarray) -> bool:
    """Whether an HDR file's pixels (H, W, 3) are LDR data: on 8-bit steps, or clipped at 1.0."""
    if float(image.max()) > 1.0 + 1e-6:  # HDR data goes above 1 somewhere
        return False
    lit = image[image.max(axis=2) > BLACK]
    if lit.size == 0:
        return False
    steps = lit * 255.0
    if np.mean(np.abs(steps - np.round(steps)) < 1e-3) > 0.99:
        return True
    return float(np.mean(lit.max(axis=1) >= 1.0 - 1e-6)) > CLIPPED_SHARE


def _check_exposure(capture: Capture, levels: np.ndarray, check: CaptureCheck) -> None:
    """Frames whose median object radiance is far from the frames' median: exposed differently."""
    reference = float(np.median(levels))
    if not reference > 0.0:
        check.figures["exposure_range"] = None
        return
    ratio = levels / reference
    check.figures["exposure_range"] = [float(ratio.min()), float(ratio.max())]
    odd = np.flatnonzero((ratio > EXPOSURE_FACTOR) | ((ratio < 1.0 / EXPOSURE_FACTOR) & (levels > BLACK)))
    if odd.size:
        worst = int(odd[np.argmax(np.abs(np.log(np.maximum(ratio[odd], 1e-30))))])
        check.warnings.append(
            f"{odd.size} of {len(levels)} frames are exposed unlike the others (median object radiance "
            f"{ratio[worst]:.3g}x the frames' median in {capture.frames[worst].image_path.name}): every frame must "
            "be in the same radiometric units (merge brackets to one exposure scale)")
