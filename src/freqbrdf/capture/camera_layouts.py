"""Where cameras go around an object: evenly spread or random directions on an orbit.

Used to place synthetic captures' views and capture guidance's candidates (METHOD.md §4).
World +y is up.
"""

from __future__ import annotations

import numpy as np

from freqbrdf.capture.camera import Camera, look_at

WORLD_UP = np.array([0.0, 1.0, 0.0])


FIELD_OF_VIEW_DEG = 40.0  # horizontal = vertical: images are square


FRAME_FILL = 0.9  # the bounding sphere's silhouette spans this fraction of the field of view


GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def fibonacci_directions(count: int, hemisphere: bool) -> np.ndarray:
    """Evenly spread unit directions ``(count, 3)`` on the sphere or the upper (+y) hemisphere.

    The Fibonacci spiral: heights equally spaced in y (equal areas, by Archimedes) and
    azimuths advancing by the golden angle.
    """
    index = np.arange(count) + 0.5
    height = 1.0 - index / count if hemisphere else 1.0 - 2.0 * index / count  # (N,)
    azimuth = GOLDEN_ANGLE * np.arange(count)
    ring = np.sqrt(np.clip(1.0 - height**2, 0.0, 1.0))
    return np.stack([ring * np.cos(azimuth), height, ring * np.sin(azimuth)], axis=1)


def random_directions(count: int, hemisphere: bool, rng: np.random.Generator) -> np.ndarray:
    """Uniformly random unit directions ``(count, 3)`` on the sphere or the upper hemisphere."""
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    if hemisphere:
        directions[:, 1] = np.abs(directions[:, 1])
    return directions


def bounding_sphere(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre ``(3,)`` (of the bounding box) and radius enclosing all ``vertices`` ``(V, 3)``."""
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return centre, float(np.linalg.norm(vertices - centre, axis=1).max())


def orbit_cameras(
    directions: np.ndarray, centre: np.ndarray, radius: float, resolution: int
) -> list[Camera]:
    """Square cameras at ``centre + distance * direction`` looking at ``centre``.

    ``distance`` makes a sphere of ``radius`` fill ``FRAME_FILL`` of the field of view.
    """
    half_fov = np.radians(FIELD_OF_VIEW_DEG) / 2.0
    distance = radius / np.sin(FRAME_FILL * half_fov)
    cameras = []
    for direction in directions:
        # Straight above or below the object, world up cannot orient the image; use +z.
        up = WORLD_UP if abs(direction @ WORLD_UP) < 0.999 else np.array([0.0, 0.0, 1.0])
        pose = look_at(centre + distance * direction, centre, up)
        cameras.append(Camera.from_fov(2.0 * half_fov, resolution, resolution, pose))
    return cameras


def camera_directions(layout: str, count: int, rng: np.random.Generator) -> np.ndarray:
    """Training view directions ``(count, 3)``: Fibonacci on the hemisphere or sphere, or
    uniformly random on the hemisphere."""
    if layout == "random":
        return random_directions(count, hemisphere=True, rng=rng)
    return fibonacci_directions(count, hemisphere=layout == "hemisphere")
