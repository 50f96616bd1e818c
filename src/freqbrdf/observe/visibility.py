"""Which surface points a camera samples, before any photograph is taken (METHOD.md §3.2)."""

from __future__ import annotations

import numpy as np

from freqbrdf.render.occluder import Occluder


def camera_samples(cameras, points: np.ndarray, normals: np.ndarray, ray_origins: np.ndarray,
                   occluder: Occluder) -> list[tuple[np.ndarray, np.ndarray]]:
    """For each camera, the surface points it would sample and their cos(theta_o); no image needed.

    points, normals (N, 3) world; ray_origins (N, 3): the points offset off the surface, where the
    shadow rays start. A point is sampled when it lies in front of the camera and inside its
    image, faces it (cos theta_o > 0 between its normal and the direction to the centre) and the
    segment from its ray origin to the camera centre misses ``occluder`` (as
    `freqbrdf.observe.observations.observe` decides visibility). Returns per camera (rows (n,) int64,
    cos_theta (n,) float64), rows ascending.
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
