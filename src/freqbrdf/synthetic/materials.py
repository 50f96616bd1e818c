"""Ground-truth material maps for synthetic captures: bands, photos and materials on a surface.

Synthetic captures judge parameter recovery against known maps (docs/method.md#evaluation); the photographs
come from ``skimage.data`` (docs/method.md#data). `cells_material`, `islands_material` and `gradient_material`
are defined on the surface (by each texel's world position), so that their regions run on
across UV chart seams as a real object's materials do.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from skimage.transform import resize as resize_image

from freqbrdf.capture.camera_layouts import bounding_sphere
from freqbrdf.capture.mesh import Mesh
from freqbrdf.images import LUMINANCE, linear_to_srgb, srgb_to_linear
from freqbrdf.model.materials import MaterialMaps
from freqbrdf.texels import rasterise

# sRGB display colours of the bands: red, gold, green, blue, light grey, near black (the last
# checks that dark texels are still treated as observed).
BAND_COLOURS_SRGB = np.array(
    [
        [0.80, 0.15, 0.12],
        [0.95, 0.70, 0.25],
        [0.20, 0.60, 0.25],
        [0.15, 0.30, 0.80],
        [0.85, 0.85, 0.85],
        [0.12, 0.12, 0.12],
    ]
)


BAND_METALLIC = (0.0, 0.5, 1.0)  # top, middle, bottom third


BAND_ROUGHNESS = (0.05, 1.0)  # ramp across each colour band, left to right


def bands_material(resolution: int = 512) -> MaterialMaps:
    """Make a factorial test pattern in the spirit of the paper's plane scene.

    Six vertical colour bands; inside each band roughness ramps linearly from 0.05 (left edge)
    to 1 (right edge); three horizontal strips with metallic 0, 0.5 and 1 from top to bottom.
    Every colour thus appears with every roughness and metallic level.

    Parameters
    ----------
    resolution : int, optional
        The texture side T.

    Returns
    -------
    MaterialMaps
        Base colour (T, T, 3) linear, roughness and metallic (T, T), float32.
    """
    n_bands = len(BAND_COLOURS_SRGB)
    column = (np.arange(resolution) + 0.5) / resolution * n_bands  # band coordinate per column
    band = np.minimum(column.astype(int), n_bands - 1)  # (T,)
    within_band = column - band  # position inside its band, in [0, 1)
    row_strip = np.minimum((np.arange(resolution) * len(BAND_METALLIC)) // resolution, 2)
    low, high = BAND_ROUGHNESS
    roughness_row = low + (high - low) * within_band  # (T,)
    colours = srgb_to_linear(BAND_COLOURS_SRGB)  # (6, 3)
    base_color = np.broadcast_to(colours[band], (resolution, resolution, 3))
    roughness = np.broadcast_to(roughness_row, (resolution, resolution))
    metallic = np.broadcast_to(
        np.asarray(BAND_METALLIC)[row_strip][:, None], (resolution, resolution)
    )
    return MaterialMaps(
        np.ascontiguousarray(base_color, dtype=np.float32),
        np.ascontiguousarray(roughness, dtype=np.float32),
        np.ascontiguousarray(metallic, dtype=np.float32),
    )


def photo_material(photo_srgb: np.ndarray, resolution: int = 512) -> MaterialMaps:
    """Derive ground-truth maps from an 8-bit sRGB photograph, deterministically.

    - The central square crop is resized to ``resolution`` (in linear space).
    - base colour: the linear image mapped into [0.03, 0.93], the range of real albedos.
    - roughness: 0.1 + 0.85 * e, where e is the local detail of the sRGB luminance (Sobel
      gradient magnitude, Gaussian-blurred over resolution / 128 texels, divided by its 95th
      percentile, clipped to 1): busy regions (hair, fabric) are rough, smooth ones glossy.
    - metallic: bright, unsaturated regions are metal (HSV value ramps 0.5 -> 0.75 times
      (1 - saturation ramp 0.1 -> 0.25), blurred over one texel): mostly 0 or 1, soft borders.

    Parameters
    ----------
    photo_srgb : (H, W, 3) uint8
        The photograph (extra channels are ignored).
    resolution : int, optional
        The texture side T.

    Returns
    -------
    MaterialMaps
        Base colour (T, T, 3) linear, roughness and metallic (T, T), float32.
    """
    height, width = photo_srgb.shape[:2]
    side = min(height, width)
    top, left = (height - side) // 2, (width - side) // 2
    crop = photo_srgb[top : top + side, left : left + side, :3].astype(np.float64) / 255.0
    linear = resize_image(
        srgb_to_linear(crop).astype(np.float64),
        (resolution, resolution, 3),
        order=1,
        anti_aliasing=resolution < side,
        preserve_range=True,
    )
    linear = np.clip(linear, 0.0, 1.0)
    base_color = 0.03 + 0.9 * linear
    display = linear_to_srgb(linear).astype(np.float64)  # (T, T, 3) sRGB of the resized image

    luminance = display @ LUMINANCE
    gradient = np.hypot(ndimage.sobel(luminance, axis=0), ndimage.sobel(luminance, axis=1))
    detail = ndimage.gaussian_filter(gradient, sigma=resolution / 128)
    detail = np.clip(detail / np.percentile(detail, 95), 0.0, 1.0)
    roughness = 0.1 + 0.85 * detail

    value = display.max(axis=2)
    saturation = np.where(value > 0, np.ptp(display, axis=2) / np.maximum(value, 1e-6), 0.0)
    metallic = _smoothstep(0.5, 0.75, value) * (1.0 - _smoothstep(0.1, 0.25, saturation))
    metallic = np.clip(ndimage.gaussian_filter(metallic, sigma=1.0), 0.0, 1.0)
    return MaterialMaps(
        base_color.astype(np.float32), roughness.astype(np.float32), metallic.astype(np.float32)
    )


def _squared_distances(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(T, T, M) squared distances of (T, T, 3) points to (M, 3) centres."""
    return np.maximum((points**2).sum(axis=-1)[..., None] - 2.0 * points @ centres.T + (centres**2).sum(axis=1), 0.0)


def _smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# --- materials on a mesh's surface ---------------------------------------------------------------

# sRGB colours of the cells' dielectrics and of metals (gold, copper, silver, iron, brass).
DIELECTRIC_COLOURS_SRGB = np.array(
    [
        [0.80, 0.15, 0.12],
        [0.20, 0.60, 0.25],
        [0.15, 0.30, 0.80],
        [0.85, 0.85, 0.80],
        [0.90, 0.60, 0.20],
        [0.45, 0.25, 0.55],
        [0.20, 0.20, 0.20],
        [0.55, 0.70, 0.75],
    ]
)
METAL_COLOURS_SRGB = np.array(
    [
        [1.00, 0.86, 0.57],
        [0.98, 0.82, 0.76],
        [0.97, 0.96, 0.91],
        [0.77, 0.78, 0.78],
        [0.98, 0.90, 0.59],
    ]
)
CELL_DIELECTRIC_ROUGHNESS = (0.15, 0.35, 0.6, 0.9)
CELL_METAL_ROUGHNESS = (0.1, 0.3, 0.5)
CELL_METAL_FRACTION = 1.0 / 3.0  # of the cells are metals
ISLAND_SURROUND_SRGB = (0.62, 0.42, 0.32)  # a clay-like rough dielectric
ISLAND_SURROUND_ROUGHNESS = 0.75
ISLAND_ROUGHNESS = 0.25
ISLAND_RADIUS = 0.07  # islands' radius, a fraction of the mesh's bounding-sphere radius


def surface_points(mesh: Mesh, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """Return the surface point of every texel, normalised to the mesh's bounding sphere.

    Covered texels (`freqbrdf.texels.rasterise`) get their own point; the others take the point
    of the nearest covered texel, so that bilinear lookups at chart borders read the chart's
    material.

    Parameters
    ----------
    mesh : Mesh
        The mesh, with UVs.
    resolution : int
        The texture side T.

    Returns
    -------
    points : (T, T, 3) float64
        (position - centre) / radius of the bounding sphere (`bounding_sphere`).
    covered : (T, T) bool
        The covered texels.
    """
    texels = rasterise(mesh, resolution)
    centre, radius = bounding_sphere(mesh.vertices)
    points = np.zeros((resolution * resolution, 3))
    points[texels.texel_index] = (texels.position - centre) / radius
    points = points.reshape(resolution, resolution, 3)
    _, (rows, cols) = ndimage.distance_transform_edt(~texels.mask, return_indices=True)
    return points[rows, cols], texels.mask


def sample_surface(mesh: Mesh, count: int, rng: np.random.Generator) -> np.ndarray:
    """Draw points uniformly over a mesh's area, normalised to its bounding sphere.

    Parameters
    ----------
    mesh : Mesh
        The mesh.
    count : int
        Number of points (M).
    rng : numpy.random.Generator
        The random source.

    Returns
    -------
    (M, 3) float64
        (position - centre) / radius, as `surface_points`.
    """
    corners = mesh.vertices[mesh.faces]  # (F, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    faces = rng.choice(len(area), size=count, p=area / area.sum())
    first, second = rng.random(count), rng.random(count)
    flip = first + second > 1.0  # fold the unit square onto the triangle
    first, second = np.where(flip, 1.0 - first, first), np.where(flip, 1.0 - second, second)
    points = corners[faces, 0] + first[:, None] * (corners[faces, 1] - corners[faces, 0]) \
        + second[:, None] * (corners[faces, 2] - corners[faces, 0])
    centre, radius = bounding_sphere(mesh.vertices)
    return (points - centre) / radius


def cells_material(mesh: Mesh, resolution: int = 512, cells: int = 24, seed: int = 0) -> MaterialMaps:
    """Make piecewise-constant cells on the surface that mix metals and dielectrics.

    The surface is cut into the Voronoi cells (in 3-D) of ``cells`` points drawn uniformly over
    its area. ``CELL_METAL_FRACTION`` of the cells, chosen at random, are metals (a colour of
    ``METAL_COLOURS_SRGB``, roughness from ``CELL_METAL_ROUGHNESS``), else a dielectric (a colour
    of ``DIELECTRIC_COLOURS_SRGB``, roughness from ``CELL_DIELECTRIC_ROUGHNESS``); metallic is
    exactly 0 or 1.

    Parameters
    ----------
    mesh : Mesh
        The mesh, with UVs.
    resolution : int, optional
        The texture side T.
    cells : int, optional
        Number of cells.
    seed : int, optional
        Seeds the cells' places and materials.

    Returns
    -------
    MaterialMaps
        Base colour (T, T, 3) linear, roughness and metallic (T, T), float32.
    """
    rng = np.random.default_rng(seed)
    centres = sample_surface(mesh, cells, rng)  # (cells, 3)
    metal = rng.permutation(cells) < round(cells * CELL_METAL_FRACTION)
    colour = np.where(
        metal[:, None],
        METAL_COLOURS_SRGB[rng.integers(len(METAL_COLOURS_SRGB), size=cells)],
        DIELECTRIC_COLOURS_SRGB[rng.integers(len(DIELECTRIC_COLOURS_SRGB), size=cells)],
    )
    roughness = np.where(
        metal,
        np.asarray(CELL_METAL_ROUGHNESS)[rng.integers(len(CELL_METAL_ROUGHNESS), size=cells)],
        np.asarray(CELL_DIELECTRIC_ROUGHNESS)[rng.integers(len(CELL_DIELECTRIC_ROUGHNESS), size=cells)],
    )
    points, _ = surface_points(mesh, resolution)
    squared = _squared_distances(points, centres)  # (T, T, cells)
    cell = squared.argmin(axis=-1)
    return MaterialMaps(
        srgb_to_linear(colour[cell]).astype(np.float32),
        roughness[cell].astype(np.float32),
        metal[cell].astype(np.float32),
    )


def islands_material(mesh: Mesh, resolution: int = 512, islands: int = 16, seed: int = 0) -> MaterialMaps:
    """Make small metal islands on a rough dielectric.

    The surround is one dielectric (``ISLAND_SURROUND_SRGB``, roughness
    ``ISLAND_SURROUND_ROUGHNESS``); ``islands`` discs of radius ``ISLAND_RADIUS`` (in 3-D, as a
    fraction of the bounding-sphere radius) around points drawn uniformly over the surface are
    metals (colours of ``METAL_COLOURS_SRGB``, roughness ``ISLAND_ROUGHNESS``). Overlapping
    islands take the nearest centre's colour.

    Parameters
    ----------
    mesh : Mesh
        The mesh, with UVs.
    resolution : int, optional
        The texture side T.
    islands : int, optional
        Number of islands.
    seed : int, optional
        Seeds the islands' places and colours.

    Returns
    -------
    MaterialMaps
        Base colour (T, T, 3) linear, roughness and metallic (T, T), float32.
    """
    rng = np.random.default_rng(seed)
    centres = sample_surface(mesh, islands, rng)
    colours = METAL_COLOURS_SRGB[rng.integers(len(METAL_COLOURS_SRGB), size=islands)]
    points, _ = surface_points(mesh, resolution)
    squared = _squared_distances(points, centres)  # (T, T, islands)
    nearest = squared.argmin(axis=-1)
    metal = squared.min(axis=-1) <= ISLAND_RADIUS**2  # (T, T)
    colour = np.where(metal[..., None], colours[nearest], np.asarray(ISLAND_SURROUND_SRGB))
    return MaterialMaps(
        srgb_to_linear(colour).astype(np.float32),
        np.where(metal, ISLAND_ROUGHNESS, ISLAND_SURROUND_ROUGHNESS).astype(np.float32),
        metal.astype(np.float32),
    )


def gradient_material(mesh: Mesh, resolution: int = 512, seed: int = 0) -> MaterialMaps:
    """Make smooth gradients of every parameter over the surface.

    With p a texel's surface point in the unit bounding sphere and a, b, c random unit
    directions: sRGB base colour 0.5 + 0.35 sin(pi p . d_k + phase_k) per channel k (random
    directions d_k and phases); roughness 0.5 + 0.4 sin(pi (p . a)), from 0.1 to 0.9 over the
    object; metallic smoothstep(-0.4, 0.4, p . b) * (1 - smoothstep(0.3, 0.9, p . c)): a metal
    region with wide soft borders, dielectric elsewhere.

    Parameters
    ----------
    mesh : Mesh
        The mesh, with UVs.
    resolution : int, optional
        The texture side T.
    seed : int, optional
        Seeds the directions and phases.

    Returns
    -------
    MaterialMaps
        Base colour (T, T, 3) linear, roughness and metallic (T, T), float32.
    """
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(6, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=3)
    points, _ = surface_points(mesh, resolution)
    along = points @ directions.T  # (T, T, 6)
    colour = 0.5 + 0.35 * np.sin(np.pi * along[..., :3] + phases)
    roughness = 0.5 + 0.4 * np.sin(np.pi * along[..., 3])
    metallic = _smoothstep(-0.4, 0.4, along[..., 4]) * (1.0 - _smoothstep(0.3, 0.9, along[..., 5]))
    return MaterialMaps(
        srgb_to_linear(colour).astype(np.float32),
        roughness.astype(np.float32),
        metallic.astype(np.float32),
    )
