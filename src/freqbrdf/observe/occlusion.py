"""The object's occlusion of its own environment: the irradiance a texel actually receives.

docs/method.md#observations leaves self-shadowing optional (beyond the paper), and the irradiance of docs/method.md#irradiance is the
unoccluded E(n). Under a sun the difference is the whole light: a texel that a part of the
object hides from the sun receives a fraction of E(n), and an estimate that assumes E(n) calls it
dark. This module corrects E where the object blocks its own environment:

- **compact lights** (`compact_lights`): the map's brightest parts (a sun, lamps) become up to
  ``MAX_LIGHTS`` directional lights; one shadow ray each per texel, and a blocked light takes its
  share max(0, n.d) x power off E;
- **the rest of the map**: ``RAYS`` cosine-distributed rays per texel; a blocked ray takes the
  rest's radiance in its direction off E and adds what the object shows there instead, the mean
  observed radiance of the texel nearest the hit point (one bounce of interreflection, read from
  the photographs rather than guessed).

E is the exact unoccluded irradiance minus these corrections, so nothing changes where nothing is
blocked, and a mesh that cannot block itself (convex or flat, `self_occluding`) is not traced.

The specular lobes read the environment in each sample's mirror direction; where the object lies
there instead (`mirror_occlusion`: a centre ray and a ring of rays around it per sample), that
share of the lobe reads what the object shows at the hits, found the same way.
Deterministic: fixed ray sets, each texel's turned by a fixed angle of its index.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError, cKDTree

from freqbrdf.images import LUMINANCE
from freqbrdf.observe._kernels import (
    _cosine_rays,
    _lobe_rays,
    _lobe_totals,
    _mirror_directions,
    _sample_offsets,
    _texels_at_hits,
)
from freqbrdf.render.occluder import RAYS_PER_BATCH, Occluder
from freqbrdf.sphere import envmap as envmaps
from freqbrdf.texels import face_texel_coords

__all__ = ["CompactLights", "UVTexels", "compact_lights", "may_be_hidden", "mirror_occlusion", "occluded_irradiance",
           "occlusion_steps", "self_occluding", "uv_texels"]

# A pixel belongs to a compact light where its luminance exceeds this many times the map's mean.
LIGHT_BRIGHTNESS = 16.0
# The most powerful compact lights traced with shadow rays; dimmer ones stay in the rest of the map.
MAX_LIGHTS = 8
# Cosine-distributed rays per texel for the rest of the map.
RAYS = 64
# The rest of the map is read at this height (area-averaged), about the rays' spacing.
REST_HEIGHT = 32
# A sample's mirror lobe: its centre ray counts this much, a ring of MIRROR_RING rays at MIRROR_CONE_DEG from
# it the rest; 12 degrees is about the half-width of the reflected lobe at roughness 0.3 (2 alpha
# radians), up to which a lobe reads its own light alone.
MIRROR_CENTRE_WEIGHT = 1.0 / 3.0
MIRROR_RING = 8
MIRROR_CONE_DEG = 12.0
# A mirror lobe whose centre rises less than its cone's half-angle (plus this, in sine) above the
# texel's horizon may dip below it: traced even from a texel above the whole mesh.
_LOBE_MARGIN = 1e-6
# A hit point farther than this many texel sizes from every observed texel shows the mean radiance.
_NEAREST_REACH = 8.0
# The texel that holds a hit in UV stands for it only within this many of its own sizes (plus its
# ray origin's lift): beyond, the pixel belongs to another chart and the nearest texel is read.
_UV_REACH = 2.0
# Faces whose plane has a mesh point farther above it than this share of the mesh's extent can
# shade a texel: the mesh is not convex.
_CONVEX_TOLERANCE = 1e-6


class CompactLights(NamedTuple):
    """A map split into directional lights and the rest (`compact_lights`).

    Attributes
    ----------
    direction : (S, 3) float64
        Unit world directions the lights shine from.
    power : (S, 3) float64
        Each light's irradiance on a surface facing it (radiance x solid angle, summed).
    rest : Envmap
        The map without the lights, area-averaged to ``REST_HEIGHT`` rows.
    """

    direction: np.ndarray
    power: np.ndarray
    rest: envmaps.Envmap


def _pixel_solid_angles(height: int, width: int) -> np.ndarray:
    """(H, 1) float64: the solid angle of a pixel of each row (rows on the poles included)."""
    polar = math.pi * np.arange(height) / (height - 1)
    half = 0.5 * math.pi / (height - 1)
    band = np.cos(np.clip(polar - half, 0.0, math.pi)) - np.cos(np.clip(polar + half, 0.0, math.pi))
    return (band * 2.0 * math.pi / width)[:, None]


def compact_lights(envmap: envmaps.Envmap, max_lights: int = MAX_LIGHTS,
                   brightness: float = LIGHT_BRIGHTNESS) -> CompactLights:
    """Split an environment map into its brightest compact parts and the rest.

    Pixels whose luminance exceeds ``brightness`` x the map's mean form connected regions; each
    region's light above that level becomes a directional light at its power-weighted mean
    direction. The ``max_lights`` most powerful ones are kept; the rest of the map is what is left.

    Parameters
    ----------
    envmap : Envmap
        The environment.
    max_lights : int, optional
        The most lights returned.
    brightness : float, optional
        The level, relative to the mean luminance, above which light counts as compact.

    Returns
    -------
    CompactLights
        The lights (S <= max_lights) and the rest of the map.
    """
    radiance = envmap.radiance.astype(np.float64)
    height, width = radiance.shape[:2]
    solid = _pixel_solid_angles(height, width)
    luminance = radiance @ LUMINANCE
    mean = float((luminance * solid).sum() / (4.0 * math.pi))
    level = brightness * mean
    bright = luminance > level if mean > 0 else np.zeros(luminance.shape, dtype=bool)
    labels, n_regions = ndimage.label(bright)
    excess = np.where(bright[..., None], radiance * (1.0 - level / np.maximum(luminance, 1e-30))[..., None], 0.0)
    directions = np.empty((0, 3))
    powers = np.empty((0, 3))
    kept = np.zeros(bright.shape, dtype=bool)
    if n_regions:
        polar = math.pi * np.arange(height) / (height - 1)
        azimuth = 2.0 * math.pi * (np.arange(width) + 0.5) / width
        world = envmaps.local_directions(polar, azimuth) @ envmap.rotation.T  # (H, W, 3)
        energy = excess * solid[..., None]  # (H, W, 3)
        index = np.arange(1, n_regions + 1)
        power = np.stack([ndimage.sum(energy[..., c], labels, index) for c in range(3)], axis=1)  # (R, 3)
        strength = energy @ LUMINANCE
        centre = np.stack([ndimage.sum(strength * world[..., c], labels, index) for c in range(3)], axis=1)
        order = np.argsort(-(power @ LUMINANCE), kind="stable")[:max_lights]
        centre = centre[order]
        directions = centre / np.maximum(np.linalg.norm(centre, axis=1, keepdims=True), 1e-30)
        powers = power[order]
        kept = np.isin(labels, index[order])
    rest = np.where(kept[..., None], radiance - excess, radiance)
    rest_map = envmaps.Envmap(envmaps.downsample(rest, min(REST_HEIGHT, height)), envmap.to_world)
    return CompactLights(directions, powers, rest_map)


def self_occluding(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether a point of the mesh can hide part of the environment from another.

    False for a convex or flat mesh: every vertex (of the convex hull) lies on or below every
    face's plane.

    Parameters
    ----------
    vertices : (P, 3) array
        The mesh's vertices.
    faces : (F, 3) int array
        Its triangles.

    Returns
    -------
    bool
        True when some vertex lies above some face's plane.
    """
    vertices = np.asarray(vertices, np.float64)
    corners = vertices[np.asarray(faces)]  # (F, 3, 3)
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normal, axis=1)
    keep = length > 0
    normal = normal[keep] / length[keep, None]
    offset = np.einsum("fc,fc->f", normal, corners[keep, 0])
    try:
        candidates = vertices[ConvexHull(vertices).vertices]
    except (QhullError, ValueError):  # flat or degenerate: every vertex is a candidate
        candidates = vertices
    tolerance = _CONVEX_TOLERANCE * float(np.linalg.norm(np.ptp(vertices, axis=0)))
    faces_per_chunk = max(1, (1 << 22) // max(len(candidates), 1))
    for first in range(0, len(normal), faces_per_chunk):
        chunk = slice(first, first + faces_per_chunk)
        if (candidates @ normal[chunk].T - offset[chunk] > tolerance).any():
            return True
    return False


def may_be_hidden(ray_origin: np.ndarray, normal: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Tell the texels from which a ray leaving upwards (d.n >= 0) can meet the mesh.

    Where every vertex of the mesh lies below the plane through the texel's ray origin across its
    normal, so does the whole mesh (its triangles are made of them), and a ray that does not go
    down never meets it: such a ray need not be traced. The highest vertex over that plane is a
    vertex of the convex hull; vertices within the mesh's convexity tolerance of the plane count
    as above it.

    Parameters
    ----------
    ray_origin : (N, 3) array
        Each texel's point, lifted off the surface along its normal.
    normal : (N, 3) array
        Each texel's unit normal.
    vertices : (P, 3) array
        The mesh's vertices.

    Returns
    -------
    (N,) bool
        True where some of the mesh may lie above the texel's plane.
    """
    vertices = np.asarray(vertices, np.float64)
    try:
        candidates = vertices[ConvexHull(vertices).vertices]
    except (QhullError, ValueError):  # flat or degenerate: every vertex is a candidate
        candidates = vertices
    margin = _CONVEX_TOLERANCE * float(np.linalg.norm(np.ptp(vertices, axis=0)))
    normal = np.asarray(normal, np.float64)
    level = np.einsum("nc,nc->n", normal, np.asarray(ray_origin, np.float64))
    hidden = np.empty(len(normal), dtype=bool)
    texels_per_chunk = max(1, (1 << 22) // max(len(candidates), 1))
    for first in range(0, len(normal), texels_per_chunk):
        rows = slice(first, first + texels_per_chunk)
        hidden[rows] = (normal[rows] @ candidates.T).max(axis=1, initial=-np.inf) > level[rows] - margin
    return hidden


def cosine_directions(n_rays: int) -> np.ndarray:
    """(n_rays, 3) cosine-distributed local directions (z up), evenly spread.

    A Fibonacci spiral in the unit disc (equal-area rings: radius sqrt((k + 1/2) / n), azimuth by
    the golden angle) lifted to the hemisphere (Malley's method): each direction stands for an
    equal share of the cosine-weighted hemisphere.
    """
    index = np.arange(n_rays) + 0.5
    radius = np.sqrt(index / n_rays)
    azimuth = math.pi * (3.0 - math.sqrt(5.0)) * np.arange(n_rays)
    return np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth), np.sqrt(1.0 - radius ** 2)], axis=1)


def occlusion_steps(n_texels: int, n_views: int = 0) -> int:
    """Count the steps `occluded_irradiance` and then `mirror_occlusion` report.

    Parameters
    ----------
    n_texels : int
        The texels corrected.
    n_views : int, optional
        The views whose mirror directions `mirror_occlusion` traces (0: not traced).

    Returns
    -------
    int
        One for the lights, then one per batch of texels' rays of each.
    """
    mirror = -(-n_texels // max(1, RAYS_PER_BATCH // (n_views * (1 + MIRROR_RING)))) if n_views else 0
    return 1 + -(-n_texels // max(1, RAYS_PER_BATCH // RAYS)) + mirror


class UVTexels(NamedTuple):
    """Where the texels lie in UV, to find the texel that holds a point on the mesh (`uv_texels`).

    Attributes
    ----------
    face_xy : (F, 3, 2) float64
        Each face's corners in texel coordinates (column, row; texel centres at integers).
    texel_of_pixel : (T, T) int64
        The row (in texel order) of the texel at each pixel of the texture; -1 where none.
    """

    face_xy: np.ndarray
    texel_of_pixel: np.ndarray


def uv_texels(uv: np.ndarray, faces: np.ndarray, mask: np.ndarray) -> UVTexels:
    """Index the texels of a texture by where they lie in UV.

    Parameters
    ----------
    uv : (P, 2) array
        The mesh's texture coordinates per vertex (v up, as in OBJ).
    faces : (F, 3) int array
        Its triangles.
    mask : (T, T) bool
        The covered texels (`freqbrdf.texels.Texels.mask`), in row-major texel order.

    Returns
    -------
    UVTexels
        The faces' corners in texel coordinates and each pixel's texel.
    """
    texel_of_pixel = np.full(mask.shape, -1, dtype=np.int64)
    texel_of_pixel[mask] = np.arange(np.count_nonzero(mask))
    return UVTexels(face_texel_coords(uv, faces, mask.shape[0]), texel_of_pixel)


class _SurfaceRadiance:
    """What the object shows at points on it.

    The mean observed radiance of the texel that holds each point in UV (where ``uv`` is given,
    that texel is observed and within ``_UV_REACH`` of its own sizes), else of its observed texel
    nearest the point (within ``_NEAREST_REACH`` median texel sizes), else the mean over its
    observed texels.
    """

    def __init__(self, ray_origin: np.ndarray, surface_radiance: np.ndarray, observed: np.ndarray,
                 texel_size: np.ndarray, uv: UVTexels | None = None):
        self._surface = np.asarray(surface_radiance, np.float64)
        self._observed = np.asarray(observed, dtype=bool)
        self._origin = np.ascontiguousarray(ray_origin, np.float64)
        self._shown = np.flatnonzero(observed)
        self._uv = uv
        self.mean = self._surface[self._shown].mean(axis=0) if len(self._shown) else np.zeros(3)
        self._tree = None
        self._reach = _NEAREST_REACH * float(np.median(texel_size)) if len(texel_size) else 0.0
        self._uv_reach = _UV_REACH * np.asarray(texel_size, np.float64)

    def at(self, points: np.ndarray, face: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        """(M, 3) float64 radiance at (M, 3) world points, on (M,) faces at (M, 2) barycentrics."""
        points = np.ascontiguousarray(points, np.float64)
        radiance = np.empty((len(points), 3))
        rest = np.arange(len(points))
        if self._uv is not None and len(self._shown):
            texel = _texels_at_hits(face, barycentric, self._uv.face_xy, self._uv.texel_of_pixel, self._observed,
                                    self._origin, points, self._uv_reach)
            found = texel >= 0
            radiance[found] = self._surface[texel[found]]
            rest = np.flatnonzero(~found)
        if not len(rest):
            return radiance
        if not len(self._shown):
            radiance[rest] = self.mean
            return radiance
        if self._tree is None:
            self._tree = cKDTree(self._origin[self._shown])
        distance, nearest = self._tree.query(points[rest], workers=-1)
        radiance[rest] = np.where((distance <= self._reach)[:, None], self._surface[self._shown[nearest]], self.mean)
        return radiance


def occluded_irradiance(occluder: Occluder, envmap: envmaps.Envmap, irradiance: np.ndarray, ray_origin: np.ndarray,
                        frame: np.ndarray, surface_radiance: np.ndarray, observed: np.ndarray,
                        texel_size: np.ndarray, advance: Callable[[int], None] = lambda steps: None,
                        hidden: np.ndarray | None = None, uv: UVTexels | None = None) -> np.ndarray:
    """Correct each texel's unoccluded irradiance for what the object blocks and shows instead.

    Parameters
    ----------
    occluder : Occluder
        The object.
    envmap : Envmap
        The environment.
    irradiance : (N, 3) array
        The unoccluded irradiance E(n) per texel.
    ray_origin : (N, 3) array
        Each texel's point, lifted off the surface along its normal.
    frame : (N, 3, 3) array
        Rows: each texel's tangent, bitangent and normal.
    surface_radiance : (N, 3) array
        Each texel's mean observed radiance (what it shows the rest of the object).
    observed : (N,) bool
        Texels whose ``surface_radiance`` is known.
    texel_size : (N,) array
        Each texel's world size.
    advance : callable, optional
        Called with 1 after the lights and after each batch of texels (`occlusion_steps` in all);
        by default nothing is reported.
    hidden : (N,) bool, optional
        `may_be_hidden`: only these texels' rays are traced (every ray here leaves upwards); by
        default every texel's.
    uv : UVTexels, optional
        `uv_texels` of these texels: a hit reads the texel that holds it in UV; by default the
        observed texel nearest it.

    Returns
    -------
    (N, 3) float32
        The irradiance the texel receives, at least 0.
    """
    n_texels = len(ray_origin)
    normal = np.asarray(frame[:, 2], np.float64)
    corrected = np.asarray(irradiance, np.float64).copy()
    if n_texels == 0:
        advance(1)
        return corrected.astype(np.float32)
    origins_rows = np.ascontiguousarray(np.asarray(ray_origin, np.float32).T)
    hidden = np.ones(n_texels, dtype=bool) if hidden is None else np.asarray(hidden, dtype=bool)
    lights = compact_lights(envmap)
    for direction, power in zip(lights.direction, lights.power):
        facing = normal @ direction
        lit = np.flatnonzero((facing > 0) & hidden)
        if not len(lit):
            continue
        towards = np.ascontiguousarray(np.broadcast_to(direction.astype(np.float32)[:, None], (3, len(lit))))
        blocked = lit[occluder.hits_rows(np.ascontiguousarray(origins_rows[:, lit]), towards)]
        corrected[blocked] -= facing[blocked, None] * power
    advance(1)

    # The rest of the map: cosine rays, each blocked one trading the rest's radiance for the surface's.
    surface = _SurfaceRadiance(ray_origin, surface_radiance, observed, texel_size, uv)
    local = cosine_directions(RAYS)
    spin = 2.0 * math.pi * np.modf(np.arange(n_texels) * (math.sqrt(5.0) - 1.0) / 2.0)[0]
    texels_per_batch = max(1, RAYS_PER_BATCH // RAYS)
    ray_origin32 = np.ascontiguousarray(ray_origin, np.float32)
    frame64 = np.ascontiguousarray(frame, np.float64)
    for first in range(0, n_texels, texels_per_batch):
        # Only the texels some of the mesh may hide: every ray here leaves upwards.
        texels = first + np.flatnonzero(hidden[first:first + texels_per_batch])
        if not len(texels):
            advance(1)
            continue
        origins, directions = _cosine_rays(ray_origin32, frame64, spin, local, texels)  # (3, n M)
        rays, distance, face, barycentric = occluder.first_hits_rows(origins, directions)
        if len(rays):
            lost = envmaps.lookup(lights.rest, directions[:, rays].T.astype(np.float64))
            gained = surface.at((origins[:, rays] + distance * directions[:, rays]).T, face, barycentric)
            change = (gained - lost) * (math.pi / RAYS)
            for channel in range(3):
                corrected[texels, channel] += np.bincount(rays // RAYS, weights=change[:, channel],
                                                          minlength=len(texels))
        advance(1)
    return np.maximum(corrected, 0.0).astype(np.float32)


def mirror_occlusion(occluder: Occluder, ray_origin: np.ndarray, frame: np.ndarray, view_direction: np.ndarray,
                     visible: np.ndarray, surface_radiance: np.ndarray, observed: np.ndarray, texel_size: np.ndarray,
                     advance: Callable[[int], None] = lambda steps: None,
                     hidden: np.ndarray | None = None, uv: UVTexels | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Find how much of each sample's mirror lobe meets the object, and what the object shows there.

    Per visible sample, rays from the texel's point: one along the view direction mirrored about
    the normal (weight ``MIRROR_CENTRE_WEIGHT``) and ``MIRROR_RING`` on a cone of
    ``MIRROR_CONE_DEG`` around it (the rest, shared). The weights of the rays that hit the object
    sum to the occluded share; a hit's radiance is the mean observed radiance of the object's
    texel nearest the hit point (as `occluded_irradiance` reads it).

    Parameters
    ----------
    occluder : Occluder
        The object.
    ray_origin : (N, 3) array
        Each texel's point, lifted off the surface along its normal.
    frame : (N, 3, 3) array
        Rows: each texel's tangent, bitangent and normal.
    view_direction : (N, V, 3) array
        w_o in each texel's frame.
    visible : (N, V) bool
        The samples to trace.
    surface_radiance : (N, 3) array
        Each texel's mean observed radiance.
    observed : (N,) bool
        Texels whose ``surface_radiance`` is known.
    texel_size : (N,) array
        Each texel's world size.
    advance : callable, optional
        Called with 1 after each batch of texels (see `occlusion_steps`); by default nothing.
    hidden : (N,) bool, optional
        `may_be_hidden`: elsewhere only the samples whose lobe may dip below the texel's horizon
        are traced; by default every sample.
    uv : UVTexels, optional
        `uv_texels` of these texels: a hit reads the texel that holds it in UV; by default the
        observed texel nearest it.

    Returns
    -------
    occluded : (N, V) float32
        The share of each sample's mirror lobe that meets the object, in [0, 1].
    surface : (N, V, 3) float32
        The radiance the object shows there (the hits' weighted mean); 0 where nothing is hit.
    """
    n_texels, n_views = visible.shape
    occluded = np.zeros((n_texels, n_views), dtype=np.float32)
    shown = np.zeros((n_texels, n_views, 3), dtype=np.float32)
    if n_texels == 0 or n_views == 0:
        return occluded, shown
    surface = _SurfaceRadiance(ray_origin, surface_radiance, observed, texel_size, uv)
    hidden = np.ones(n_texels, dtype=bool) if hidden is None else np.asarray(hidden, dtype=bool)
    ring = 2.0 * math.pi * np.arange(MIRROR_RING) / MIRROR_RING
    cone = math.radians(MIRROR_CONE_DEG)
    # (rays, 3): the centre, then the ring, in a frame whose z is the mirror direction.
    offsets = np.vstack([[0.0, 0.0, 1.0], np.column_stack([math.sin(cone) * np.cos(ring), math.sin(cone) * np.sin(ring),
                                                           np.full(MIRROR_RING, math.cos(cone))])])
    weights = np.concatenate([[MIRROR_CENTRE_WEIGHT], np.full(MIRROR_RING, (1.0 - MIRROR_CENTRE_WEIGHT) / MIRROR_RING)])
    texels_per_batch = max(1, RAYS_PER_BATCH // (n_views * len(offsets)))
    ray_origin32 = np.ascontiguousarray(ray_origin, np.float32)
    for first in range(0, n_texels, texels_per_batch):
        rows = slice(first, min(first + texels_per_batch, n_texels))
        # A lobe whose every ray leaves upwards from a texel above the whole mesh meets nothing: the
        # mirror direction's height over the horizon is the view's (its local z).
        traced = visible[rows] & (hidden[rows, None] | (view_direction[rows, :, 2] < math.sin(cone) + _LOBE_MARGIN))
        texel, view = np.nonzero(traced)  # the packed order of `_mirror_directions`
        texel += first
        mirror = _mirror_directions(np.asarray(frame[rows], np.float64), view_direction[rows], traced,
                                    _sample_offsets(traced))  # normalised by `_lobe_rays`
        origins, directions = _lobe_rays(ray_origin32, texel, mirror, offsets)  # (3, n R)
        hits, distance, face, barycentric = occluder.first_hits_rows(origins, directions)
        shows = surface.at((origins[:, hits] + distance * directions[:, hits]).T, face, barycentric)
        share, radiance = _lobe_totals(hits, weights, shows, len(texel))
        met = np.flatnonzero(share > 0)
        occluded[texel[met], view[met]] = np.minimum(share[met], 1.0)
        shown[texel[met], view[met]] = radiance[met] / share[met, None]
        advance(1)
    return occluded, shown
