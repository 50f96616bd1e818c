"""Pinhole cameras in the NeRF/Blender convention, and their reading from transforms files.

Axes are OpenGL's (docs/method.md#conventions, "Cameras"): in camera space x points right, y up, and the
camera looks down -z. ``camera_to_world`` maps camera space to world space and must be rigid (a
rotation and a translation). Pixel coordinates: (0, 0) is the top-left corner of the top-left
pixel, x runs right and y down, and the centre of pixel (row i, column j) is (j + 0.5, i + 0.5);
the principal point (cx, cy) is given in the same coordinates, so cx = width / 2 is the image
centre.

`read_cameras` reads the cameras of a ``transforms.json`` without its images; the parsing helpers
below it (`read_json_object`, `frame_entries`, `frame_camera`, `frame_lens`, `positive_number`, `required_key`)
are shared with `freqbrdf.capture.layouts` and raise `InputError` naming the file.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from freqbrdf.capture.lens import LensDistortion, unfolded
from freqbrdf.errors import InputError

# How far R^T R may stray from the identity: transforms stored as text with 6-7 significant digits
# are orthonormal to about 1e-6, while a scaled or sheared matrix misses by far more.
RIGID_TOLERANCE = 1e-3
# Camera models read: pinholes, and lenses whose distortion the photographs are read through
# (`frame_lens`, `freqbrdf.capture.lens`).
CAMERA_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE")
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: pose, intrinsics in pixels and image size.

    The pose is copied into a read-only float64 array on construction.

    Attributes
    ----------
    camera_to_world : (4, 4) float64
        Rigid camera-to-world transform, OpenGL camera axes (the camera looks down its -z).
    fx, fy : float
        Focal lengths in pixels, positive.
    cx, cy : float
        Principal point in pixels (see the module docstring).
    width, height : int
        Image size in pixels.

    Raises
    ------
    ValueError
        If the pose is not rigid, a focal length is not positive and finite, the principal point
        is not finite or the image size is not positive.
    """

    camera_to_world: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self):
        matrix = np.array(self.camera_to_world, dtype=np.float64)
        problem = rigid_transform_problem(matrix)
        if problem is not None:
            raise ValueError(f"camera_to_world {problem}")
        matrix.flags.writeable = False  # a frozen camera keeps its pose
        object.__setattr__(self, "camera_to_world", matrix)
        if not (self.fx > 0 and self.fy > 0 and np.isfinite([self.fx, self.fy]).all()):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if not np.isfinite([self.cx, self.cy]).all():
            raise ValueError(f"principal point must be finite, got ({self.cx}, {self.cy})")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")

    @classmethod
    def from_fov(
        cls,
        camera_angle_x: float,
        width: int,
        height: int,
        camera_to_world: np.ndarray,
        camera_angle_y: float | None = None,
    ) -> Camera:
        """Make a camera from NeRF's intrinsics: fields of view, principal point centred.

        Parameters
        ----------
        camera_angle_x : float
            Full horizontal field of view in radians.
        width, height : int
            Image size in pixels.
        camera_to_world : (4, 4) float64
            Rigid camera-to-world transform.
        camera_angle_y : float, optional
            Full vertical field of view in radians; without it pixels are square.

        Returns
        -------
        Camera
            The camera, with its principal point at the image centre.
        """
        fx = focal_length(camera_angle_x, width)
        fy = fx if camera_angle_y is None else focal_length(camera_angle_y, height)
        return cls(camera_to_world, fx, fy, 0.5 * width, 0.5 * height, width, height)

    @property
    def center(self) -> np.ndarray:
        """The camera position in world space, (3,) float64 (a copy)."""
        return self.camera_to_world[:3, 3].copy()

    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """Transform world points to camera space.

        A rigid map's inverse rotation is its transpose, so no matrix is inverted.

        Parameters
        ----------
        points : (M, 3) array_like
            Points in world space.

        Returns
        -------
        (M, 3) float64
            The points in camera space.
        """
        rotation = self.camera_to_world[:3, :3]
        return (np.asarray(points, dtype=np.float64) - self.camera_to_world[:3, 3]) @ rotation

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points to pixel coordinates.

        Parameters
        ----------
        points : (M, 3) array_like
            Points in world space.

        Returns
        -------
        pixels : (M, 2) float64
            Pixel coordinates (x, y) in the convention of the module docstring; NaN for points at
            or behind the camera.
        depth : (M,) float64
            Distance along the viewing axis (-z in camera space); <= 0 at or behind the camera.
        """
        local = self.world_to_camera(points)  # (N, 3)
        depth = -local[:, 2]
        in_front = depth > 0
        inverse_depth = np.divide(1.0, depth, out=np.full_like(depth, np.nan), where=in_front)
        # Camera y points up, pixel y down.
        pixels = np.stack(
            [self.cx + self.fx * local[:, 0] * inverse_depth,
             self.cy - self.fy * local[:, 1] * inverse_depth],
            axis=1,
        )
        return pixels, depth

    def ray_directions(self) -> np.ndarray:
        """Return the ray direction through every pixel centre.

        Returns
        -------
        (H, W, 3) float64
            Unit world-space directions from the camera centre through each pixel centre.
        """
        columns = (np.arange(self.width) + 0.5 - self.cx) / self.fx  # (W,)
        rows = (np.arange(self.height) + 0.5 - self.cy) / self.fy  # (H,)
        local = np.empty((self.height, self.width, 3))
        local[..., 0] = columns[None, :]
        local[..., 1] = -rows[:, None]
        local[..., 2] = -1.0
        world = local @ self.camera_to_world[:3, :3].T
        return world / np.linalg.norm(world, axis=-1, keepdims=True)


def focal_length(field_of_view: float, size: int) -> float:
    """Return the focal length of a field of view.

    Parameters
    ----------
    field_of_view : float
        Full field of view in radians.
    size : int
        Number of pixels the field of view spans.

    Returns
    -------
    float
        The focal length in pixels.
    """
    return float(0.5 * size / np.tan(0.5 * field_of_view))


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 1.0, 0.0)) -> np.ndarray:
    """Return the pose of a camera at ``eye`` looking at ``target``.

    Parameters
    ----------
    eye, target : (3,) array_like
        Camera position and the point it looks at, in world space.
    up : (3,) array_like, optional
        The image's up direction, made orthogonal to the viewing direction (default world +y).

    Returns
    -------
    (4, 4) float64
        The camera-to-world transform (OpenGL axes).

    Raises
    ------
    ValueError
        If ``eye`` and ``target`` coincide or ``up`` is parallel to the viewing direction.
    """
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    forward = target - eye
    if np.linalg.norm(forward) == 0:
        raise ValueError("look_at: eye and target coincide")
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9 * np.linalg.norm(up):
        raise ValueError("look_at: up is parallel to the viewing direction")
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    matrix = np.eye(4)
    # Columns are the camera's x, y, z axes in world space; it looks down its -z.
    matrix[:3, 0], matrix[:3, 1], matrix[:3, 2], matrix[:3, 3] = right, true_up, -forward, eye
    return matrix


def rigid_transform_problem(matrix: np.ndarray) -> str | None:
    """Say what makes ``matrix`` not a rigid transform.

    Parameters
    ----------
    matrix : (4, 4) array_like
        A candidate transform; rigid means a rotation and a translation, to within
        ``RIGID_TOLERANCE`` (no scale, shear or reflection).

    Returns
    -------
    str or None
        A phrase that completes "<name> ..." in an error message, or None if it is rigid.
    """
    matrix = np.asarray(matrix, dtype=np.float64)
    if matrix.shape != (4, 4):
        return f"must be a 4x4 matrix, got shape {matrix.shape}"
    if not np.isfinite(matrix).all():
        return "has non-finite entries"
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=RIGID_TOLERANCE):
        return f"has bottom row {matrix[3].tolist()}, expected [0, 0, 0, 1]"
    rotation = matrix[:3, :3]
    determinant = np.linalg.det(rotation)
    if abs(determinant) < 1e-9:
        return "is singular (its 3x3 part has determinant 0)"
    deviation = np.abs(rotation.T @ rotation - np.eye(3)).max()
    if deviation > RIGID_TOLERANCE:
        return (
            f"is not rigid: its 3x3 part is not orthonormal (|R^T R - I| up to {deviation:.3g}; "
            "scale and shear are not allowed)"
        )
    if determinant < 0:
        return "is a reflection (determinant -1), not a rotation"
    return None


def check_rigid(matrix: np.ndarray, source: str | Path, what: str) -> np.ndarray:
    """Validate a rigid transform read from a file.

    A rotation that is orthonormal only to text precision is replaced by the nearest rotation
    (polar decomposition), so that downstream code may invert it by transposing; rotations exact
    to float precision are returned bit for bit.

    Parameters
    ----------
    matrix : (4, 4) array_like
        The transform as read.
    source : str or Path
        The file it came from, for the error message.
    what : str
        Where in the file the matrix was, e.g. "frame 3: transform_matrix".

    Returns
    -------
    (4, 4) float64
        The rigid transform, bottom row exactly (0, 0, 0, 1).

    Raises
    ------
    InputError
        If ``matrix`` is not a 4x4 array of numbers or not rigid.
    """
    try:
        array = np.array(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(source, f"{what} must be a 4x4 array of numbers") from None
    problem = rigid_transform_problem(array)
    if problem is not None:
        raise InputError(source, f"{what} {problem}")
    rotation = array[:3, :3]
    if np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-12:
        left, _, right = np.linalg.svd(rotation)
        array[:3, :3] = left @ right
    array[3] = [0.0, 0.0, 0.0, 1.0]
    return array


# ---------------------------------------------------------------------------------------------
# Cameras of a NeRF/Blender transforms file


def read_cameras(path: str | Path, image_size: tuple[int, int]) -> list[Camera]:
    """Read the cameras of a transforms file's frames; their images need not exist.

    Parameters
    ----------
    path : str or Path
        A NeRF/Blender-style ``transforms.json``.
    image_size : (int, int)
        (height, width) of frames without ``w`` and ``h`` (in the frame or at the top level).

    Returns
    -------
    list of Camera
        One camera per frame, in file order.

    Raises
    ------
    InputError
        Naming the file, for any problem with it.
    """
    path = Path(path)
    document = read_json_object(path)
    return [frame_camera(path, index, entry, document, lambda: image_size)
            for index, entry in enumerate(frame_entries(path, document))]


def read_json_object(path: Path) -> dict:
    """Read a JSON file that holds an object at the top level.

    Parameters
    ----------
    path : Path
        The file.

    Returns
    -------
    dict
        The parsed object.

    Raises
    ------
    InputError
        If the file is missing, unreadable, malformed or does not hold an object.
    """
    if not path.is_file():
        raise InputError(path, "file does not exist" if not path.exists() else "is not a file")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(path, f"cannot be read ({err})") from None
    try:
        document = json.loads(text)
    except json.JSONDecodeError as err:
        raise InputError(
            path, f"malformed JSON at line {err.lineno}, column {err.colno}: {err.msg}"
        ) from None
    if not isinstance(document, dict):
        raise InputError(path, "must hold a JSON object ({...}) at the top level")
    return document


def frame_entries(source: Path, document: dict) -> list[dict]:
    """Return the ``frames`` list of a transforms document.

    Parameters
    ----------
    source : Path
        The file the document came from, for error messages.
    document : dict
        The parsed transforms file.

    Returns
    -------
    list of dict
        The frame entries.

    Raises
    ------
    InputError
        If ``frames`` is missing, empty, not a list, or has an entry that is not an object.
    """
    entries = required_key(source, "", document, "frames")
    if not isinstance(entries, list) or not entries:
        raise InputError(source, "'frames' must be a non-empty list")
    for index, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise InputError(source, f"frame {index} must be a JSON object")
    return entries


def frame_camera(
    source: Path,
    index: int,
    entry: dict,
    document: dict,
    size_of_first: Callable[[], tuple[int, int]],
) -> Camera:
    """Read the camera of one frame: its keys first, then the file's top-level keys.

    Intrinsics come from ``fl_x``/``fl_y`` or ``camera_angle_x``/``camera_angle_y``, ``cx``/``cy``
    (default: the image centre) and ``w``/``h``; only pinhole models without distortion are
    accepted.

    Parameters
    ----------
    source : Path
        The transforms file, for error messages.
    index : int
        The frame's index in ``frames``, for error messages.
    entry : dict
        The frame's entry.
    document : dict
        The whole transforms document (its top-level keys are the defaults).
    size_of_first : callable () -> (int, int)
        Gives (height, width) when neither the frame nor the file has ``w`` and ``h``. NeRF's
        Blender datasets declare only the field of view; a capture takes its first image's size.

    Returns
    -------
    Camera
        The frame's camera.

    Raises
    ------
    InputError
        If a key is missing or invalid or the camera model is not one of `CAMERA_MODELS` (a
        lens's distortion is read by `frame_lens`).
    """
    where = f"frame {index}: "

    def value(key: str) -> Any:
        return entry.get(key, document.get(key))

    camera_model = value("camera_model")
    if camera_model is not None and camera_model not in CAMERA_MODELS:
        raise InputError(
            source, f"{where}camera_model {camera_model!r} is not supported ({', '.join(CAMERA_MODELS)})"
        )
    if value("w") is not None and value("h") is not None:
        width, height = (positive_number(source, where, key, value(key)) for key in ("w", "h"))
        if width != int(width) or height != int(height):
            raise InputError(source, f"{where}'w' and 'h' must be whole numbers of pixels")
        width, height = int(width), int(height)
    else:
        height, width = size_of_first()

    if value("fl_x") is not None:
        fx = positive_number(source, where, "fl_x", value("fl_x"))
    elif value("camera_angle_x") is not None:
        fx = focal_length(_field_of_view(source, where, "camera_angle_x", value), width)
    else:
        raise InputError(source, f"{where}missing required key 'camera_angle_x' (or 'fl_x')")
    if value("fl_y") is not None:
        fy = positive_number(source, where, "fl_y", value("fl_y"))
    elif value("camera_angle_y") is not None:
        fy = focal_length(_field_of_view(source, where, "camera_angle_y", value), height)
    else:
        fy = fx  # square pixels
    cx = positive_number(source, where, "cx", value("cx")) if value("cx") is not None else 0.5 * width
    cy = positive_number(source, where, "cy", value("cy")) if value("cy") is not None else 0.5 * height
    camera_to_world = check_rigid(
        required_key(source, where, entry, "transform_matrix"), source, f"{where}transform_matrix"
    )
    return Camera(camera_to_world, fx, fy, cx, cy, width, height)


def frame_lens(source: Path, index: int, entry: dict, document: dict, camera: Camera) -> LensDistortion | None:
    """Read a frame's lens distortion (`freqbrdf.capture.lens`).

    ``camera_model`` ``OPENCV`` (COLMAP's ``SIMPLE_RADIAL`` and ``RADIAL`` are its radial part; or
    none given) with any of ``k1``-``k4``, ``p1``, ``p2`` non-zero is OpenCV's radial-tangential
    model; ``OPENCV_FISHEYE`` (or instant-ngp's ``"is_fisheye": true``) its fisheye model, whatever
    its coefficients. Frame keys override the document's.

    Parameters
    ----------
    source : Path
        The transforms file, for error messages.
    index : int
        The frame's index, for error messages.
    entry : dict
        The frame's entry.
    document : dict
        The whole transforms document (its top-level keys are the defaults).
    camera : Camera
        The frame's pinhole intrinsics (`frame_camera`): the lens must not fold its image.

    Returns
    -------
    LensDistortion or None
        None for a pinhole photograph.

    Raises
    ------
    InputError
        If a coefficient is not a finite number, a fisheye has tangential terms, or the distortion
        folds the image (its radius does not grow from the centre to the corners).
    """
    where = f"frame {index}: "

    def value(key: str) -> Any:
        return entry.get(key, document.get(key))

    coefficients = {}
    for key in DISTORTION_KEYS:
        raw = value(key)
        if raw is not None and (isinstance(raw, bool) or not isinstance(raw, (int, float)) or not math.isfinite(raw)):
            raise InputError(source, f"{where}{key!r} must be a finite number, got {raw!r}")
        coefficients[key] = 0.0 if raw is None else float(raw)
    fisheye = value("camera_model") == "OPENCV_FISHEYE" or value("is_fisheye") is True
    if fisheye and (coefficients["p1"] or coefficients["p2"]):
        raise InputError(source, f"{where}a fisheye lens (OPENCV_FISHEYE) has no tangential terms p1, p2")
    if not fisheye and not any(coefficients.values()):
        return None
    radial = tuple(coefficients[key] for key in ("k1", "k2", "k3", "k4"))
    lens = LensDistortion("fisheye" if fisheye else "opencv", radial,
                          (0.0, 0.0) if fisheye else (coefficients["p1"], coefficients["p2"]))
    if not unfolded(lens, camera):
        named = ", ".join(f"{key} = {coefficients[key]:g}" for key in DISTORTION_KEYS if coefficients[key])
        raise InputError(source, f"{where}the lens distortion ({named or 'fisheye'}) folds the image: the distorted "
                                 "radius does not grow from its centre to its corners; check the coefficients")
    return lens


def positive_number(source: Path, where: str, key: str, value: Any) -> float:
    """Validate a JSON value as a finite, positive number.

    Parameters
    ----------
    source : Path
        The file, for the error message.
    where : str
        A prefix saying where in the file, e.g. "frame 3: " (may be empty).
    key : str
        The key the value was read from.
    value : Any
        The JSON value.

    Returns
    -------
    float
        The value.

    Raises
    ------
    InputError
        If the value is not a finite, positive number (booleans are refused).
    """
    is_number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not is_number or not np.isfinite(value) or value <= 0:
        raise InputError(source, f"{where}{key!r} must be a positive number, got {value!r}")
    return float(value)


def required_key(source: Path, where: str, mapping: dict, key: str) -> Any:
    """Return ``mapping[key]``, refusing a missing key.

    Parameters
    ----------
    source : Path
        The file, for the error message.
    where : str
        A prefix saying where in the file, e.g. "frame 3: " (may be empty).
    mapping : dict
        A JSON object.
    key : str
        The required key.

    Returns
    -------
    Any
        The value.

    Raises
    ------
    InputError
        If ``key`` is missing.
    """
    if key not in mapping:
        raise InputError(source, f"{where}missing required key {key!r}")
    return mapping[key]


def _field_of_view(source: Path, where: str, key: str, value: Callable[[str], Any]) -> float:
    angle = positive_number(source, where, key, value(key))
    if angle >= np.pi:
        raise InputError(source, f"{where}{key!r} is {angle}; it must be below pi (radians)")
    return angle
