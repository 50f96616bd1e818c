"""Which surface points a camera samples, before any photograph is taken (docs/method.md#observations).

The same tests as `freqbrdf.observe.observations.observe` (in front of the camera, inside its
image, facing it, and an unoccluded shadow ray to its centre), for cameras that have no image
yet: capture guidance (`freqbrdf.applications.guidance`, docs/method.md#guidance) scores candidate views
with them. There is no object mask, so silhouette points may count where a photograph's mask
would drop them.
"""

from __future__ import annotations

import numpy as np

from freqbrdf.render.occluder import Occluder


def camera_samples(cameras, points: np.ndarray, normals: np.ndarray, ray_origins: np.ndarray,
                   occluder: Occluder) -> list[tuple[np.ndarray, np.ndarray]]:
    """Find the surface points each camera would sample, and their cos(theta_o); no image needed.

    A point is sampled when it lies in front of the camera and inside its image, faces it
    (cos theta_o > 0 between its normal and the direction to the centre) and the segment from its
    ray origin to the camera centre misses ``occluder`` (as `freqbrdf.observe.observations.observe`
    decides visibility). The shadow rays of all cameras are traced in one batch.

    Parameters
    ----------
    cameras : sequence of Camera
        V cameras (OpenGL convention, `freqbrdf.capture.camera.Camera`).
    points : (M, 3) array_like
        World positions of the surface points.
    normals : (M, 3) array_like
        Their unit world normals.
    ray_origins : (M, 3) array_like
        The points offset off the surface, where the shadow rays start.
    occluder : Occluder
        The object, for the shadow rays.

    Returns
    -------
    list of (rows, cos_theta)
        Per camera, rows (n,) int64 of the points it samples, ascending, and their
        cos_theta (n,) float64.
    """
    points = np.asarray(points, np.float64)
    normals = np.asarray(normals, np.float64)
    facing_rows, facing_cos, owners = [], [], []
    for view, camera in enumerate(cameras):
        pixels, depth = camera.project(points)
        to_camera = camera.center - points
        cos_theta = np.einsum("ij,ij->i", normals, to_camera) / np.linalg.norm(to_camera, axis=1)
        with np.errstate(invalid="ignore"):  # NaN pixels behind the camera compare False
            inside = ((pixels[:, 0] >= 0) & (pixels[:, 0] <= camera.width)
                      & (pixels[:, 1] >= 0) & (pixels[:, 1] <= camera.height))
        rows = np.flatnonzero((depth > 0) & (cos_theta > 0) & inside)
        facing_rows.append(rows)
        facing_cos.append(cos_theta[rows])
        owners.append(np.full(len(rows), view))
    rows, owner = np.concatenate(facing_rows), np.concatenate(owners)
    centres = np.stack([camera.center for camera in cameras]) if len(cameras) else np.zeros((0, 3))
    origins = np.asarray(ray_origins, np.float64)[rows]
    segment = centres[owner] - origins
    length = np.linalg.norm(segment, axis=1)
    # Stop just short of the camera (cameras never sit on the surface).
    blocked = occluder.hits(origins, segment / length[:, None], length * (1.0 - 1e-5))
    bounds = np.cumsum([0] + [len(r) for r in facing_rows])
    return [(facing_rows[view][~blocked[bounds[view]:bounds[view + 1]]],
             facing_cos[view][~blocked[bounds[view]:bounds[view + 1]]]) for view in range(len(cameras))]
