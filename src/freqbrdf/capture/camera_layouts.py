"""Where cameras go around an object: evenly spread or random directions on an orbit.

Places the views of synthetic captures and the candidate views of capture guidance
(docs/method.md#guidance, "Capture guidance"). World +y is up; cameras are square pinholes
(`freqbrdf.capture.camera.Camera`) that look at the object's bounding-sphere centre.
"""

from __future__ import annotations

import numpy as np

from freqbrdf.capture.camera import Camera, look_at

WORLD_UP = np.array([0.0, 1.0, 0.0])


FIELD_OF_VIEW_DEG = 40.0  # horizontal = vertical: images are square


FRAME_FILL = 0.9  # the bounding sphere's silhouette spans this fraction of the field of view


GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


SIDE_AXIS = np.array([1.0, 0.0, 0.0])  # the "side" layout looks at the object from around +x


SIDE_CAP_DEG = 70.0  # ... from directions within this angle of SIDE_AXIS


def fibonacci_directions(count: int, hemisphere: bool) -> np.ndarray:
    """Spread unit directions evenly on the sphere or the upper (+y) hemisphere.

    The Fibonacci spiral: heights equally spaced in y (equal areas, by Archimedes) and
    azimuths advancing by the golden angle.

    Parameters
    ----------
    count : int
        Number of directions (M).
    hemisphere : bool
        Keep to the upper hemisphere (y > 0) instead of the whole sphere.

    Returns
    -------
    (M, 3) float64
        Unit directions, from the top down.
    """
    index = np.arange(count) + 0.5
    height = 1.0 - index / count if hemisphere else 1.0 - 2.0 * index / count  # (N,)
    azimuth = GOLDEN_ANGLE * np.arange(count)
    ring = np.sqrt(np.clip(1.0 - height**2, 0.0, 1.0))
    return np.stack([ring * np.cos(azimuth), height, ring * np.sin(azimuth)], axis=1)


def cap_directions(count: int, axis: np.ndarray, half_angle_deg: float) -> np.ndarray:
    """Spread unit directions evenly on a spherical cap around an axis.

    The Fibonacci spiral of `fibonacci_directions`, with heights along ``axis`` equally spaced
    in [cos(half angle), 1] (equal areas), so that the directions keep within ``half_angle_deg``
    of the axis.

    Parameters
    ----------
    count : int
        Number of directions (M).
    axis : (3,) array_like
        The cap's centre direction (normalised here).
    half_angle_deg : float
        The cap's angular radius, degrees, in (0, 180].

    Returns
    -------
    (M, 3) float64
        Unit directions, from the axis outwards.
    """
    axis = np.asarray(axis, np.float64)
    axis = axis / np.linalg.norm(axis)
    index = np.arange(count) + 0.5
    lowest = np.cos(np.radians(half_angle_deg))
    height = 1.0 - index / count * (1.0 - lowest)  # (M,)
    azimuth = GOLDEN_ANGLE * np.arange(count)
    ring = np.sqrt(np.clip(1.0 - height**2, 0.0, 1.0))
    # Any orthonormal pair perpendicular to the axis; for +x: +y and +z.
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    first = np.cross(helper, axis)
    first /= np.linalg.norm(first)
    second = np.cross(axis, first)
    return (height[:, None] * axis + (ring * np.cos(azimuth))[:, None] * first
            + (ring * np.sin(azimuth))[:, None] * second)


def random_directions(count: int, hemisphere: bool, rng: np.random.Generator) -> np.ndarray:
    """Draw uniformly random unit directions on the sphere or the upper (+y) hemisphere.

    Parameters
    ----------
    count : int
        Number of directions (M).
    hemisphere : bool
        Fold the directions into the upper hemisphere (y >= 0).
    rng : numpy.random.Generator
        The random source.

    Returns
    -------
    (M, 3) float64
        Unit directions.
    """
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    if hemisphere:
        directions[:, 1] = np.abs(directions[:, 1])
    return directions


def bounding_sphere(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """Return a sphere that encloses a point set.

    Parameters
    ----------
    vertices : (M, 3) float64
        The points, e.g. a mesh's vertices.

    Returns
    -------
    centre : (3,) float64
        The centre of the points' bounding box.
    radius : float
        The distance from ``centre`` to the farthest point.
    """
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return centre, float(np.linalg.norm(vertices - centre, axis=1).max())


def orbit_cameras(
    directions: np.ndarray, centre: np.ndarray, radius: float, resolution: int
) -> list[Camera]:
    """Place square cameras on an orbit, looking at its centre.

    Each camera sits at ``centre + distance * direction``, where ``distance`` makes a sphere of
    ``radius`` fill ``FRAME_FILL`` of the ``FIELD_OF_VIEW_DEG`` field of view. Straight above or
    below the object the image's up direction is +z instead of world up.

    Parameters
    ----------
    directions : (M, 3) float64
        Unit directions from the centre to the cameras.
    centre : (3,) float64
        The point looked at.
    radius : float
        Radius of the sphere to frame.
    resolution : int
        Image side in pixels.

    Returns
    -------
    list of Camera
        M cameras, in the order of ``directions``.
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
    """Return the view directions of a camera layout.

    Parameters
    ----------
    layout : str
        "hemisphere" or "sphere" (Fibonacci spirals), "side" (a Fibonacci spiral within
        ``SIDE_CAP_DEG`` of ``SIDE_AXIS``: the far side of the object is never seen), or
        "random" (uniform on the upper hemisphere); any other value gives the sphere.
    count : int
        Number of views (M).
    rng : numpy.random.Generator
        The random source of the "random" layout.

    Returns
    -------
    (M, 3) float64
        Unit directions from the object to the cameras.
    """
    if layout == "random":
        return random_directions(count, hemisphere=True, rng=rng)
    if layout == "side":
        return cap_directions(count, SIDE_AXIS, SIDE_CAP_DEG)
    return fibonacci_directions(count, hemisphere=layout == "hemisphere")
