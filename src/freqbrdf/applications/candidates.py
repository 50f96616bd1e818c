"""Candidate views for capture guidance, and what each would sample (docs/method.md#observations, docs/method.md#guidance).

Capture guidance (`freqbrdf.applications.guidance.select_views`, docs/method.md#guidance) chooses among
candidate cameras: spread evenly on a sphere around the object (`sample_candidates`), read from
a transforms file (`load_candidates`), or grown farthest-point from views already chosen
(`farthest_point_views`, on the directions of `view_directions`). Before any photograph is
taken, `candidate_samples` finds what a candidate would add to each texel: the view direction in
the texel's frame (its SH basis), the weight cos(theta_o) under the visibility test of
`freqbrdf.observe.observe` (docs/method.md#observations, `freqbrdf.observe.camera_samples`) and the
band-limited environment in the mirror direction (docs/method.md#conventions, docs/method.md#band-limit): a `CandidateSamples`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from freqbrdf.capture.camera import Camera, look_at, read_cameras
from freqbrdf.capture.camera_layouts import (
    WORLD_UP,
    bounding_sphere,
    fibonacci_directions,
)
from freqbrdf.capture.layouts import Capture
from freqbrdf.observe.observations import (
    RAY_OFFSET_OBJECT,
    RAY_OFFSET_TEXELS,
    Observations,
)
from freqbrdf.observe.visibility import camera_samples
from freqbrdf.render.occluder import Occluder
from freqbrdf.sphere import envmap as envmaps
from freqbrdf.sphere import harmonics as sh
from freqbrdf.texels import Texels


@dataclass(frozen=True)
class CandidateSamples:
    """What one candidate camera would add to the scored texels, n of which it sees.

    Attributes
    ----------
    texel : (n,) int64
        Rows of the scored texels.
    weight : (n,) float64
        cos(theta_o) of each sample.
    basis : (n, K) float64
        The SH at the view direction in the texel's frame.
    light : (n, 3) float64
        The band-limited environment in the mirror direction.
    """

    texel: np.ndarray
    weight: np.ndarray
    basis: np.ndarray
    light: np.ndarray


def candidate_samples(
    capture: Capture,
    texels: Texels,
    cameras: Sequence[Camera],
    observations: Observations,
    lmax: int,
) -> list[CandidateSamples]:
    """Find the samples each camera would add to the texels; no images needed.

    Visibility as in `freqbrdf.observe.observe` (`freqbrdf.observe.camera_samples`): in front,
    facing, inside the image, and an unoccluded shadow ray (Mitsuba) from the offset texel to the
    camera centre. There is no object mask yet, so silhouette texels may count where a
    photograph's mask would drop them.

    Parameters
    ----------
    capture : Capture
        Its mesh (for the shadow rays) and environment map.
    texels : Texels
        The n scored texels, those of ``observations``.
    cameras : sequence of Camera
        The candidates.
    observations : Observations
        Its band limit sigma is applied to the environment.
    lmax : int
        Degree of the SH basis at the view directions.

    Returns
    -------
    list of CandidateSamples
        One per camera, in order.
    """
    position = np.asarray(texels.position, dtype=np.float64)
    normal = np.asarray(texels.normal, dtype=np.float64)
    frame = np.stack([texels.tangent, texels.bitangent, texels.normal], axis=1)  # (n, 3, 3) rows
    seen = _visible(capture, texels, cameras)
    texel_of_ray = np.concatenate([rows for rows, _ in seen]).astype(np.int64)
    view_of_ray = np.concatenate([np.full(len(rows), view) for view, (rows, _) in enumerate(seen)])
    centres = np.stack([camera.center for camera in cameras])  # (C, 3)

    to_camera = centres[view_of_ray] - position[texel_of_ray]
    to_camera /= np.linalg.norm(to_camera, axis=1, keepdims=True)  # (M, 3) world
    local = np.einsum("mij,mj->mi", frame[texel_of_ray], to_camera)  # (t, b, n) components
    mirror = 2.0 * local[:, 2:3] * normal[texel_of_ray] - to_camera  # r = 2 (n.v) n - v
    sigma = observations.sigma
    lit = envmaps.lowpass_envmap(capture.envmap, sigma) if sigma > 0 else capture.envmap
    light = envmaps.lookup(lit, mirror).astype(np.float64)
    basis = sh.eval_sh(local, lmax)
    bounds = np.cumsum([0] + [len(rows) for rows, _ in seen])  # the rays come view by view
    return [
        CandidateSamples(texel_of_ray[take], local[take, 2], basis[take], light[take])
        for take in (slice(bounds[view], bounds[view + 1]) for view in range(len(cameras)))
    ]


def view_samples(capture: Capture, texels: Texels,
                 cameras: Sequence[Camera]) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Find the texels each camera would sample, their weights and mirror directions; no images needed.

    Visibility as `candidate_samples` (`freqbrdf.observe.camera_samples`).

    Parameters
    ----------
    capture : Capture
        Its mesh (for the shadow rays).
    texels : Texels
        The n texels.
    cameras : sequence of Camera
        The cameras.

    Returns
    -------
    list of (texel, weight, mirror)
        Per camera: rows (m,) int64 of the texels it samples, ascending; cos(theta_o) (m,) float64;
        the world mirror directions (m, 3) float64 of the view directions about the normals.
    """
    position = np.asarray(texels.position, dtype=np.float64)
    normal = np.asarray(texels.normal, dtype=np.float64)
    result = []
    for camera, (rows, cos_theta) in zip(cameras, _visible(capture, texels, cameras)):
        to_camera = camera.center[None] - position[rows]
        to_camera /= np.linalg.norm(to_camera, axis=1, keepdims=True)
        facing = np.einsum("mi,mi->m", to_camera, normal[rows])
        mirror = 2.0 * facing[:, None] * normal[rows] - to_camera
        result.append((np.asarray(rows, np.int64), np.asarray(cos_theta, np.float64), mirror))
    return result


def _visible(capture: Capture, texels: Texels, cameras: Sequence[Camera]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per camera, the rows of the texels it samples and their cos(theta_o) (`camera_samples`)."""
    position = np.asarray(texels.position, dtype=np.float64)
    normal = np.asarray(texels.normal, dtype=np.float64)
    extent = float(np.linalg.norm(np.ptp(capture.mesh.vertices, axis=0)))  # the object's scale, as observe uses it
    offset = RAY_OFFSET_TEXELS * texels.texel_size + RAY_OFFSET_OBJECT * extent
    ray_origin = position + offset[:, None] * normal
    if not len(cameras):
        return []
    return camera_samples(cameras, position, normal, ray_origin,
                          Occluder(capture.mesh, numba.get_num_threads()))


def sample_candidates(capture: Capture, count: int, hemisphere: bool = False) -> list[Camera]:
    """Spread candidate cameras evenly (Fibonacci) on a sphere around the object, looking at it.

    They share the intrinsics of the capture's first frame and sit at the median distance of the
    capture's cameras from the centre of the object's bounding sphere.

    Parameters
    ----------
    capture : Capture
        Its mesh and cameras set the centre, the distance and the intrinsics.
    count : int
        How many cameras, >= 1.
    hemisphere : bool
        Keep them above the centre (+y, the world's up).

    Returns
    -------
    list of Camera
        ``count`` cameras.

    Raises
    ------
    ValueError
        If ``count`` < 1.
    """
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    centre, _ = bounding_sphere(capture.mesh.vertices)
    distance = float(np.median([np.linalg.norm(frame.camera.center - centre) for frame in capture.frames]))
    template = capture.frames[0].camera
    cameras = []
    for direction in fibonacci_directions(count, hemisphere):
        # Straight above or below the object, world up cannot orient the image; use +z.
        up = WORLD_UP if abs(direction @ WORLD_UP) < 0.999 else np.array([0.0, 0.0, 1.0])
        pose = look_at(centre + distance * direction, centre, up)
        cameras.append(dataclasses.replace(template, camera_to_world=pose))
    return cameras


def load_candidates(path: str | Path, capture: Capture) -> list[Camera]:
    """Read candidate cameras from a transforms file in the capture format; images need not exist.

    Frames without ``w`` and ``h`` (in the frame or at the top level) get the image size of the
    capture's first frame.

    Parameters
    ----------
    path : str or Path
        The transforms file.
    capture : Capture
        Its first frame gives the default image size.

    Returns
    -------
    list of Camera
        The file's cameras, in its order.
    """
    template = capture.frames[0].camera
    return read_cameras(path, (template.height, template.width))


def farthest_point_views(directions: np.ndarray, count: int, chosen: Sequence[int] = ()) -> list[int]:
    """Choose more views, each the farthest (in angle) from those chosen so far.

    With nothing chosen the first pick is view 0. Deterministic.

    Parameters
    ----------
    directions : (V, 3) array_like
        Unit directions from the object to the cameras (`view_directions`).
    count : int
        How many more views.
    chosen : sequence of int
        Indices already chosen.

    Returns
    -------
    list of int
        The ``count`` new indices only, in the order chosen.

    Raises
    ------
    ValueError
        If fewer than ``count`` views are left.
    """
    directions = np.asarray(directions, dtype=np.float64)
    chosen = list(chosen)
    if count > len(directions) - len(chosen):
        raise ValueError(f"cannot choose {count} more of {len(directions)} views ({len(chosen)} chosen)")
    closeness = np.full(len(directions), -np.inf)  # max cosine to a chosen view
    for index in chosen:
        closeness = np.maximum(closeness, directions @ directions[index])
    new = []
    for _ in range(count):
        available = np.ones(len(directions), bool)
        available[chosen + new] = False
        index = 0 if not chosen and not new else int(np.argmin(np.where(available, closeness, np.inf)))
        new.append(index)
        closeness = np.maximum(closeness, directions @ directions[index])
    return new


def view_directions(capture: Capture, cameras: Sequence[Camera]) -> np.ndarray:
    """Return the unit directions from the object's bounding-sphere centre to the camera centres.

    Parameters
    ----------
    capture : Capture
        Its mesh sets the centre.
    cameras : sequence of Camera
        V cameras.

    Returns
    -------
    (V, 3) float64
        One unit direction per camera.
    """
    centre, _ = bounding_sphere(capture.mesh.vertices)
    offsets = np.stack([camera.center for camera in cameras]) - centre
    return offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
