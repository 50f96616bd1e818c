"""Pinhole cameras in the NeRF/Blender convention.

Axes are OpenGL's: in camera space x points right, y up, and the camera looks down -z.
``camera_to_world`` maps camera space to world space and must be rigid (a rotation and a
translation). Pixel coordinates: (0, 0) is the top-left corner of the top-left pixel, x runs right
and y down, and the centre of pixel (row i, column j) is (j + 0.5, i + 0.5); the principal point
(cx, cy) is given in the same coordinates, so cx = width / 2 is the image centre.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from freqbrdf.errors import InputError

# How far R^T R may stray from the identity: transforms stored as text with 6-7 significant digits
# are orthonormal to about 1e-6, while a scaled or sheared matrix misses by far more.
RIGID_TOLERANCE = 1e-3
PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV")
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


@dataclass(frozen=True)
class Camera:
    camera_to_world: np.ndarray  # (4, 4) float64, rigid, OpenGL camera axes
    fx: float  # focal lengths in pixels
    fy: float
    cx: float  # principal point in pixels (see the module docstring)
    cy: float
    width: int  # image size in pixels
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
        """NeRF's intrinsics: full horizontal field of view in radians, principal point centred.

        Pixels are square unless ``camera_angle_y`` (the full vertical field of view) is given.
        """
        fx = focal_length(camera_angle_x, width)
        fy = fx if camera_angle_y is None else focal_length(camera_angle_y, height)
        return cls(camera_to_world, fx, fy, 0.5 * width, 0.5 * height, width, height)

    @property
    def center(self) -> np.ndarray:
        """Camera position in world space ``(3,)``."""
        return self.camera_to_world[:3, 3].copy()

    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points ``(N, 3)`` in camera space ``(N, 3)``; a rigid map's inverse is R^T."""
        rotation = self.camera_to_world[:3, :3]
        return (np.asarray(points, dtype=np.float64) - self.camera_to_world[:3, 3]) @ rotation

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points ``(N, 3)`` to pixels ``(N, 2)`` (x, y) and depths ``(N,)``.

        Depth is the distance along the viewing axis (-z in camera space); it is <= 0 for points
        at or behind the camera, whose pixel coordinates are NaN.
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
        """Unit world-space directions ``(H, W, 3)`` from the centre through each pixel centre."""
        columns = (np.arange(self.width) + 0.5 - self.cx) / self.fx  # (W,)
        rows = (np.arange(self.height) + 0.5 - self.cy) / self.fy  # (H,)
        local = np.empty((self.height, self.width, 3))
        local[..., 0] = columns[None, :]
        local[..., 1] = -rows[:, None]
        local[..., 2] = -1.0
        world = local @ self.camera_to_world[:3, :3].T
        return world / np.linalg.norm(world, axis=-1, keepdims=True)


def focal_length(field_of_view: float, size: int) -> float:
    """Focal length in pixels of a full field of view (radians) spanning ``size`` pixels."""
    return float(0.5 * size / np.tan(0.5 * field_of_view))


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 1.0, 0.0)) -> np.ndarray:
    """Camera-to-world ``(4, 4)`` of a camera at ``eye`` looking at ``target``.

    The image's up direction is ``up`` made orthogonal to the viewing direction.
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
    """What makes ``matrix`` not a rigid 4x4 transform (rotation + translation), or None."""
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
    """``matrix`` as a rigid (4, 4) float64 array, or InputError naming ``source`` and ``what``.

    ``what`` says where in the file the matrix was, e.g. "frame 3: transform_matrix". A rotation
    that is orthonormal only to text precision is replaced by the nearest rotation (polar
    decomposition), so that downstream code may invert it by transposing; rotations exact to
    float precision are returned bit for bit.
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
    """The cameras of a transforms file's frames; their images need not exist.

    Frames without ``w`` and ``h`` (in the frame or at the top level) get ``image_size``
    (height, width). InputError naming the file for any problem.
    """
    path = Path(path)
    document = read_json_object(path)
    return [frame_camera(path, index, entry, document, lambda: image_size)
            for index, entry in enumerate(frame_entries(path, document))]


def read_json_object(path: Path) -> dict:
    """A JSON file holding an object at the top level; InputError otherwise."""
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
    """The non-empty ``frames`` list of a transforms document, each entry an object."""
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
    """The camera of one frame: its keys first, then the file's top-level keys.

    Without ``w`` and ``h`` the image size (height, width) is ``size_of_first()`` (NeRF's Blender
    datasets declare only the field of view; a capture takes its first image's size).
    """
    where = f"frame {index}: "

    def value(key: str) -> Any:
        return entry.get(key, document.get(key))

    camera_model = value("camera_model")
    if camera_model is not None and camera_model not in PINHOLE_MODELS:
        raise InputError(
            source, f"{where}camera_model {camera_model!r} is not supported (pinhole only)"
        )
    distorted = [key for key in DISTORTION_KEYS if value(key) not in (None, 0, 0.0)]
    if distorted:
        raise InputError(
            source,
            f"{where}lens distortion ({', '.join(distorted)}) is not supported; "
            "undistort the images",
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


def positive_number(source: Path, where: str, key: str, value: Any) -> float:
    """A finite, positive JSON number, or InputError naming ``source``, ``where`` and ``key``."""
    is_number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not is_number or not np.isfinite(value) or value <= 0:
        raise InputError(source, f"{where}{key!r} must be a positive number, got {value!r}")
    return float(value)


def required_key(source: Path, where: str, mapping: dict, key: str) -> Any:
    """mapping[key], or an InputError naming the file and where in it the key is missing."""
    if key not in mapping:
        raise InputError(source, f"{where}missing required key {key!r}")
    return mapping[key]


def _field_of_view(source: Path, where: str, key: str, value: Callable[[str], Any]) -> float:
    angle = positive_number(source, where, key, value(key))
    if angle >= np.pi:
        raise InputError(source, f"{where}{key!r} is {angle}; it must be below pi (radians)")
    return angle
