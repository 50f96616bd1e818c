"""Texels: the mesh rasterised in UV space (docs/method.md#texels), and texture helpers.

Texel (row i, column j) of a T x T texture is centred at uv = ((j + 0.5)/T, 1 - (i + 0.5)/T), UV
origin bottom-left (as in `freqbrdf.capture.mesh`). Internally UVs map to texel coordinates
x = u T - 0.5, y = (1 - v) T - 0.5, so texel (i, j) is centred at the lattice point (x, y) = (j, i)
and covers the unit square around it.

Coverage rule:

- Centre sampling: a texel belongs to a triangle whose UV footprint contains its centre (edges
  included, with a 1e-9 barycentric tolerance so a centre on a shared edge is never lost to
  round-off). Its sample point is the centre itself.
- Conservative extension (``conservative=True``, the default): a texel whose centre lies in no
  triangle but whose square a triangle overlaps with positive area (exact separating-axis test)
  is kept too, sampled at the point of that triangle closest to its centre ("snapped", within
  half a texel diagonal). Slivers narrower than a texel are then not lost, and the one-texel ring
  around every chart carries real surface values, which bilinear filtering reads at chart edges.

Winners depend on nothing but the mesh: a centre-covered texel goes to the lowest face id
containing its centre; a snapped texel to the triangle closest to its centre (ties: lowest face
id); centre coverage beats snapping. Texels whose centre lies strictly inside two or more
triangles (overlapping charts) are counted in ``Texels.overlap_texels``; faces with
(numerically) zero UV area own no texture space and are skipped and counted.

Each texel's local frame (tangent, bitangent, normal) comes from the shading normal alone, by the
branchless orthonormal basis of Duff et al. 2017 ("Building an Orthonormal Basis, Revisited"):
deterministic, right-handed and continuous except where n_z changes sign. Downstream quantities
are rotation invariant about n (docs/method.md#conventions), so no UV-aligned tangent is needed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numba
import numpy as np
from scipy import ndimage

from freqbrdf.capture.mesh import Mesh, unit_or_fallback
from freqbrdf.errors import InputError

INSIDE_TOLERANCE = 1e-9  # barycentric slack of the centre test: centres on shared edges stay covered
STRICT_INSIDE = 1e-7  # barycentric margin for "strictly inside" when counting UV overlaps
SEPARATION_TOLERANCE = 1e-9  # texels; a triangle that only touches a texel's square does not cover it
DEGENERATE_UV_AREA = 1e-12  # texels^2 (twice the area); faces below own no texture space
UV_RANGE_TOLERANCE = 1e-6  # loaders may round UVs slightly outside [0, 1]


@dataclass(frozen=True, eq=False)
class Texels:
    """The covered texels of a T x T texture, in flat row-major order of ``texel_index``.

    Attributes
    ----------
    texture_res : int
        The texture side T.
    mask : (T, T) bool
        True where a texel is covered.
    texel_index : (N,) int64
        Flat row-major indices i * T + j of the covered texels, ascending.
    face_id : (N,) int64
        The face each texel samples.
    barycentric : (N, 3) float64
        The sample point in that face (>= 0, summing to 1).
    position : (N, 3) float64
        World position of the sample point.
    normal : (N, 3) float64
        Interpolated, normalised shading normal.
    tangent, bitangent : (N, 3) float64
        The rest of the local frame: tangent x bitangent = normal.
    texel_area : (N,) float64
        World-space area one texel covers on its face.
    snapped : (N,) bool
        True where the centre missed every triangle (conservative coverage).
    overlap_texels : int
        Texels whose centre lies strictly inside two or more triangles.
    degenerate_uv_faces : int
        Faces skipped because their UV area is zero.
    """

    texture_res: int
    mask: np.ndarray
    texel_index: np.ndarray
    face_id: np.ndarray
    barycentric: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    tangent: np.ndarray
    bitangent: np.ndarray
    texel_area: np.ndarray
    snapped: np.ndarray
    overlap_texels: int
    degenerate_uv_faces: int

    @property
    def n_texels(self) -> int:
        """The number of covered texels, N."""
        return len(self.texel_index)

    @property
    def texel_size(self) -> np.ndarray:
        """World-space edge length of each texel, sqrt(texel_area), (N,) float64: the scale for ray offsets."""
        return np.sqrt(self.texel_area)


def rasterise(mesh: Mesh, texture_res: int = 512, conservative: bool = True) -> Texels:
    """Rasterise a mesh in UV space, by the coverage rule of the module docstring.

    Parameters
    ----------
    mesh : Mesh
        The mesh; its UVs must lie in [0, 1].
    texture_res : int, optional
        The texture side T.
    conservative : bool, optional
        Also keep texels whose centre misses every triangle but whose square one overlaps.

    Returns
    -------
    Texels
        The covered texels (N of them) and their surface samples.

    Raises
    ------
    InputError
        If ``texture_res`` is not a positive integer, the UVs are malformed, non-finite or
        outside [0, 1], or the UV layout covers no texel.
    """
    uv_px = _validated_texel_coords(mesh, texture_res)  # (F, 3, 2)
    edge_1 = uv_px[:, 1] - uv_px[:, 0]
    edge_2 = uv_px[:, 2] - uv_px[:, 0]
    twice_uv_area = np.abs(edge_1[:, 0] * edge_2[:, 1] - edge_1[:, 1] * edge_2[:, 0])  # (F,) texels^2
    has_uv_area = twice_uv_area > DEGENERATE_UV_AREA

    face_of_texel = np.full((texture_res, texture_res), -1, np.int64)
    snap_distance = np.full((texture_res, texture_res), np.inf)  # texels; 0 where the centre is covered
    centre_hits = np.zeros((texture_res, texture_res), np.uint8)  # strict containments, saturating
    _rasterise_faces(uv_px, has_uv_area, conservative, face_of_texel, snap_distance, centre_hits)

    mask = face_of_texel >= 0
    if not mask.any():
        raise InputError(
            mesh.path, f"the UV layout covers no texel of a {texture_res}x{texture_res} texture"
        )
    texel_index = np.flatnonzero(mask)  # (N,) row-major, hence sorted
    face_id = face_of_texel.ravel()[texel_index]
    rows, cols = np.divmod(texel_index, texture_res)
    barycentric = np.empty((len(texel_index), 3))
    _closest_barycentrics(uv_px, face_id, rows.astype(np.float64), cols.astype(np.float64), barycentric)

    texel_faces = mesh.faces[face_id]  # (N, 3) vertex ids
    position = _interpolate(mesh.vertices, texel_faces, barycentric)
    shading = _interpolate(mesh.normals, texel_faces, barycentric)
    corners = np.asarray(mesh.vertices, np.float64)[mesh.faces]  # (F, 3, 3)
    geometric = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])  # (F, 3), 2 x area
    # Opposed vertex normals can cancel; the face's own normal is then the only sensible choice.
    normal = unit_or_fallback(shading, unit_or_fallback(geometric[face_id], np.array([0.0, 0.0, 1.0])))
    tangent, bitangent = orthonormal_basis(normal)

    # The UV -> world map is affine per face, so every texel of a face covers the same world area.
    twice_world_area = np.linalg.norm(geometric, axis=-1)
    world_area_per_uv_area = twice_world_area / np.where(has_uv_area, twice_uv_area, np.inf)
    return Texels(
        texture_res=texture_res,
        mask=mask,
        texel_index=texel_index,
        face_id=face_id,
        barycentric=barycentric,
        position=position,
        normal=normal,
        tangent=tangent,
        bitangent=bitangent,
        texel_area=world_area_per_uv_area[face_id],
        snapped=snap_distance.ravel()[texel_index] > 0.0,
        overlap_texels=int(np.count_nonzero(centre_hits >= 2)),
        degenerate_uv_faces=int(np.count_nonzero(~has_uv_area)),
    )


def orthonormal_basis(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Complete unit normals to right-handed orthonormal frames.

    Duff et al. 2017: branchless, exact at n = (0, 0, -1), continuous except across n_z = 0.

    Parameters
    ----------
    normals : (N, 3) float64
        Unit normals.

    Returns
    -------
    tangent, bitangent : (N, 3) float64
        Unit vectors with tangent x bitangent = normal.
    """
    x, y, z = normals[..., 0], normals[..., 1], normals[..., 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    tangent = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    bitangent = np.stack([b, sign + y * y * a, -y], axis=-1)
    return tangent, bitangent


def world_to_local(texels: Texels, directions: np.ndarray) -> np.ndarray:
    """Express world directions in each texel's (tangent, bitangent, normal) frame.

    Parameters
    ----------
    texels : Texels
        The texels (N of them).
    directions : (N, ..., 3) float64
        World directions, any number of them per texel.

    Returns
    -------
    (N, ..., 3) float64
        The directions in the local frames, z along the normal.
    """
    frame = np.stack([texels.tangent, texels.bitangent, texels.normal], axis=1)  # (N, 3, 3) rows
    extra_axes = (1,) * (directions.ndim - 2)
    frame = frame.reshape(frame.shape[:1] + extra_axes + (3, 3))
    return np.einsum("...ij,...j->...i", frame, directions)


def scatter(texels: Texels, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
    """Lay per-texel values out as a texture; the inverse of `gather`.

    Parameters
    ----------
    texels : Texels
        The texels (N of them).
    values : (N,) or (N, C) array
        One value (or C channels) per texel.
    fill : float, optional
        The value of uncovered texels.

    Returns
    -------
    (T, T) or (T, T, C) array
        The texture, of ``values``'s dtype.
    """
    res = texels.texture_res
    image = np.full((res * res,) + values.shape[1:], fill, dtype=values.dtype)
    image[texels.texel_index] = values
    return image.reshape((res, res) + values.shape[1:])


def gather(texels: Texels, image: np.ndarray) -> np.ndarray:
    """Sample a texture at the covered texels; the inverse of `scatter`.

    Parameters
    ----------
    texels : Texels
        The texels (N of them).
    image : (T, T) or (T, T, C) array
        The texture.

    Returns
    -------
    (N,) or (N, C) array
        The texture's value at each texel.
    """
    res = texels.texture_res
    return image.reshape((res * res,) + image.shape[2:])[texels.texel_index]


def dilate(texture: np.ndarray, mask: np.ndarray, pixels: int) -> np.ndarray:
    """Grow a texture outwards from its masked texels, ring by ring.

    Each ring is the set of empty texels with a filled 8-neighbour; it takes the mean of those
    neighbours. Texture filtering at chart edges (bilinear, mip levels) then blends surface values
    with plausible continuations instead of empty atlas space (docs/method.md#texels).

    Parameters
    ----------
    texture : (T, T) or (T, T, C) float array
        The texture; texels outside ``mask`` may hold anything, NaN included.
    mask : (T, T) bool
        The filled texels; they are returned unchanged.
    pixels : int
        Number of rings to grow. Texels farther (in the chessboard metric) keep their input values.

    Returns
    -------
    (T, T) or (T, T, C) float array
        The dilated texture, of ``texture``'s shape and dtype.

    Raises
    ------
    ValueError
        If ``texture`` and ``mask`` differ in size.
    """
    if texture.shape[:2] != mask.shape:
        raise ValueError(f"texture {texture.shape} and mask {mask.shape} differ in size")
    channels_last = texture if texture.ndim == 3 else texture[..., None]
    grown = channels_last.copy()
    filled = mask.copy()
    for _ in range(pixels):
        neighbours = _box_sum_3x3(filled.astype(grown.dtype))  # (T, T)
        ring = ~filled & (neighbours > 0)
        if not ring.any():
            break
        # Empty texels may hold anything (NaN included); only filled ones enter the sums.
        sums = _box_sum_3x3(np.where(filled[..., None], grown, 0))
        grown[ring] = sums[ring] / neighbours[ring][:, None]
        filled |= ring
    return grown if texture.ndim == 3 else grown[..., 0]


def _interpolate(per_vertex: np.ndarray, texel_faces: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """Interpolate ``per_vertex`` (n_vertices, 3) barycentrically over each texel's face: (N, 3)."""
    per_vertex = np.asarray(per_vertex, np.float64)
    return sum(barycentric[:, [k]] * per_vertex[texel_faces[:, k]] for k in range(3))


def _box_sum_3x3(image: np.ndarray) -> np.ndarray:
    """Sum over each texel's 3x3 neighbourhood, zero outside the image: (T, T[, C]) -> same shape."""
    res_y, res_x = image.shape[:2]
    padded = np.pad(image, [(1, 1), (1, 1)] + [(0, 0)] * (image.ndim - 2))
    total = np.zeros_like(image)
    for dy in range(3):
        for dx in range(3):
            total += padded[dy : dy + res_y, dx : dx + res_x]
    return total


def _validated_texel_coords(mesh: Mesh, texture_res: int) -> np.ndarray:
    """Return (n_faces, 3, 2) face corners in texel coordinates (texel (i, j) centred at (j, i))."""
    if not isinstance(texture_res, (int, np.integer)) or texture_res < 1:
        raise InputError(None, f"texture resolution must be a positive integer, got {texture_res!r}")
    uv = np.asarray(mesh.uv, np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2 or len(uv) != len(mesh.vertices):
        raise InputError(mesh.path, f"expected one (u, v) per vertex, got UVs of shape {uv.shape}")
    if not np.all(np.isfinite(uv)):
        raise InputError(mesh.path, "texture coordinates contain NaN or infinity")
    if uv.min() < -UV_RANGE_TOLERANCE or uv.max() > 1.0 + UV_RANGE_TOLERANCE:
        raise InputError(
            mesh.path,
            f"texture coordinates span [{uv.min():.4g}, {uv.max():.4g}]; a texture atlas needs [0, 1]",
        )
    return face_texel_coords(uv, mesh.faces, texture_res)


def face_texel_coords(uv: np.ndarray, faces: np.ndarray, texture_res: int) -> np.ndarray:
    """Place each face's corners in texel coordinates of a T x T texture.

    Parameters
    ----------
    uv : (P, 2) array
        Texture coordinates per vertex (v up, as in OBJ).
    faces : (F, 3) int array
        The triangles.
    texture_res : int
        T.

    Returns
    -------
    (F, 3, 2) float64
        (column, row) of each corner; texel (i, j) is centred at (j, i).
    """
    uv = np.asarray(uv, np.float64)
    texel_xy = np.stack([uv[:, 0] * texture_res - 0.5, (1.0 - uv[:, 1]) * texture_res - 0.5], axis=-1)
    return np.ascontiguousarray(texel_xy[np.asarray(faces)])


# --------------------------------------------------------------------------------------------
# Kernels. The face loop is serial on purpose: faces compete for texels, and visiting them in
# order makes "lowest face id wins" hold without atomics. It touches each texel of a face's
# bounding box once.


@numba.njit(cache=True)
def _rasterise_faces(uv_px, has_uv_area, conservative, face_of_texel, snap_distance, centre_hits):
    res = face_of_texel.shape[0]
    reach = 0.5 if conservative else 0.0  # how far outside the UV bounding box texel centres matter
    for face in range(uv_px.shape[0]):
        if not has_uv_area[face]:
            continue
        ax, ay = uv_px[face, 0, 0], uv_px[face, 0, 1]
        bx, by = uv_px[face, 1, 0], uv_px[face, 1, 1]
        cx, cy = uv_px[face, 2, 0], uv_px[face, 2, 1]
        twice_area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)  # signed: mirrored charts are fine
        col_lo = max(0, int(np.ceil(min(ax, bx, cx) - reach)))
        col_hi = min(res - 1, int(np.floor(max(ax, bx, cx) + reach)))
        row_lo = max(0, int(np.ceil(min(ay, by, cy) - reach)))
        row_hi = min(res - 1, int(np.floor(max(ay, by, cy) + reach)))
        for row in range(row_lo, row_hi + 1):
            py = float(row)
            for col in range(col_lo, col_hi + 1):
                px = float(col)
                w_a = ((bx - px) * (cy - py) - (by - py) * (cx - px)) / twice_area
                w_b = ((cx - px) * (ay - py) - (cy - py) * (ax - px)) / twice_area
                w_c = 1.0 - w_a - w_b
                w_min = min(w_a, w_b, w_c)
                if w_min >= -INSIDE_TOLERANCE:
                    if w_min > STRICT_INSIDE and centre_hits[row, col] < 255:
                        centre_hits[row, col] += 1
                    if snap_distance[row, col] > 0.0:  # first containing face = lowest id
                        snap_distance[row, col] = 0.0
                        face_of_texel[row, col] = face
                elif (
                    conservative
                    and snap_distance[row, col] > 0.0
                    and _overlaps_texel(ax, ay, bx, by, cx, cy, px, py)
                ):
                    w_a, w_b, w_c = _closest_point_barycentrics(ax, ay, bx, by, cx, cy, px, py)
                    dx = w_a * ax + w_b * bx + w_c * cx - px
                    dy = w_a * ay + w_b * by + w_c * cy - py
                    distance = np.sqrt(dx * dx + dy * dy)
                    if distance < snap_distance[row, col]:  # strict: ties keep the lower face id
                        snap_distance[row, col] = distance
                        face_of_texel[row, col] = face


@numba.njit(cache=True)
def _overlaps_texel(ax, ay, bx, by, cx, cy, px, py):
    """Test whether the triangle overlaps the unit square centred at (px, py) with positive area.

    Separating axes: the square's two and the triangle's three edge normals.
    """
    lo = px - 0.5 + SEPARATION_TOLERANCE
    hi = px + 0.5 - SEPARATION_TOLERANCE
    if max(ax, bx, cx) <= lo or min(ax, bx, cx) >= hi:
        return False
    lo = py - 0.5 + SEPARATION_TOLERANCE
    hi = py + 0.5 - SEPARATION_TOLERANCE
    if max(ay, by, cy) <= lo or min(ay, by, cy) >= hi:
        return False
    corners = ((ax, ay, bx, by, cx, cy), (bx, by, cx, cy, ax, ay), (cx, cy, ax, ay, bx, by))
    for e0x, e0y, e1x, e1y, ox, oy in corners:
        nx = e0y - e1y  # normal of the edge e0 -> e1
        ny = e1x - e0x
        on_edge = nx * e0x + ny * e0y
        opposite = nx * ox + ny * oy
        centre = nx * px + ny * py
        half_width = 0.5 * (abs(nx) + abs(ny))
        slack = SEPARATION_TOLERANCE * (abs(nx) + abs(ny))
        if max(on_edge, opposite) <= centre - half_width + slack:
            return False
        if min(on_edge, opposite) >= centre + half_width - slack:
            return False
    return True


@numba.njit(cache=True)
def _closest_point_barycentrics(ax, ay, bx, by, cx, cy, px, py):
    """Return the barycentrics of the triangle's point closest to (px, py).

    Ericson, Real-Time Collision Detection, 5.1.5 (Voronoi regions of vertices, then edges, else
    the interior).
    """
    abx, aby, acx, acy = bx - ax, by - ay, cx - ax, cy - ay
    apx, apy = px - ax, py - ay
    d1 = abx * apx + aby * apy
    d2 = acx * apx + acy * apy
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bpx, bpy = px - bx, py - by
    d3 = abx * bpx + aby * bpy
    d4 = acx * bpx + acy * bpy
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return 1.0 - v, v, 0.0
    cpx, cpy = px - cx, py - cy
    d5 = abx * cpx + aby * cpy
    d6 = acx * cpx + acy * cpy
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return 1.0 - w, 0.0, w
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - w, w
    scale = 1.0 / (va + vb + vc)
    v = vb * scale
    w = vc * scale
    return 1.0 - v - w, v, w


@numba.njit(cache=True)
def _closest_barycentrics(uv_px, face_id, rows, cols, out):
    """Write into ``out`` (N, 3) the barycentrics of each texel's sample point.

    The sample point is the winning face's point closest to the texel centre: for a centre
    inside the face, the centre itself.
    """
    for texel in range(face_id.shape[0]):
        face = face_id[texel]
        out[texel, 0], out[texel, 1], out[texel, 2] = _closest_point_barycentrics(
            uv_px[face, 0, 0], uv_px[face, 0, 1], uv_px[face, 1, 0], uv_px[face, 1, 1],
            uv_px[face, 2, 0], uv_px[face, 2, 1], cols[texel], rows[texel],
        )


def estimation_resolution(texels: Texels, camera_centres: np.ndarray, focal_px: np.ndarray,
                          rule: Literal["pixel", "coarse"] = "pixel") -> int:
    """Choose the texture resolution to estimate on, ceil(T / 2^k) with k >= 0.

    Texels finer than the pixels add little information: each one's samples are bilinear lookups
    between the same few pixels as its neighbours', so their separate estimates share the data
    and multiply the work and the noise. A texel's width is the median over ``texels`` of
    sqrt(texel_area); a pixel's width at the object is the distance from the camera centre to the
    texels' centroid over the focal length in pixels, in the closest view.

    Parameters
    ----------
    texels : Texels
        The texels at full resolution T.
    camera_centres : (V, 3) array_like
        World positions of the views' cameras.
    focal_px : (V,) array_like
        Their focal lengths in pixels.
    rule : {"pixel", "coarse"}, optional
        "pixel": the largest k whose texels are still no wider than a pixel of the closest view
        (the coarsest grid that keeps a texel per pixel, so that no detail the images resolve is
        lost); "coarse": the smallest k whose texels are at least a pixel wide.

    Returns
    -------
    int
        The resolution; T itself where there is nothing to measure (no texels, no cameras).

    Raises
    ------
    ValueError
        If ``rule`` is neither "pixel" nor "coarse".
    """
    camera_centres = np.asarray(camera_centres, dtype=np.float64).reshape(-1, 3)
    focal_px = np.asarray(focal_px, dtype=np.float64).reshape(-1)
    if texels.n_texels == 0 or len(camera_centres) == 0:
        return texels.texture_res
    texel_width = float(np.median(texels.texel_size))
    centroid = texels.position.mean(axis=0)
    pixel_width = float(np.min(np.linalg.norm(camera_centres - centroid, axis=1) / focal_px))
    if not (texel_width > 0.0 and pixel_width > 0.0):
        return texels.texture_res
    if rule not in ("pixel", "coarse"):
        raise ValueError(f"rule must be 'pixel' or 'coarse', got {rule!r}")
    texels_per_pixel = math.log2(pixel_width / texel_width)
    levels = max(math.floor(texels_per_pixel + 1e-9) if rule == "pixel" else math.ceil(texels_per_pixel - 1e-9), 0)
    return max(math.ceil(texels.texture_res / 2**levels), 1)


def fill_texture(texture: np.ndarray, atlas: np.ndarray, dilation_px: int, fallback: float) -> np.ndarray:
    """Fill the unknown (NaN) texels of a texture.

    Atlas texels without a value take the nearest known texel's; then the atlas is dilated by
    ``dilation_px`` rings (`dilate`); the remaining texels take the mean over the atlas.

    Parameters
    ----------
    texture : (T, T) or (T, T, C) float array
        The texture, NaN where unknown.
    atlas : (T, T) bool
        The texels on the surface; its finite texels are the known ones, returned unchanged.
    dilation_px : int
        Rings of dilation beyond the atlas.
    fallback : float
        The value of every texel when no texel is known.

    Returns
    -------
    (T, T) or (T, T, C) float32
        The filled texture.
    """
    texture = np.asarray(texture, np.float32)
    values = texture if texture.ndim == 3 else texture[..., None]  # (T, T, C)
    known = atlas & np.isfinite(values).all(axis=-1)
    if not known.any():
        return np.full(texture.shape, fallback, np.float32)
    # Index of the nearest known texel for every texel (distance 0 for the known ones).
    nearest = ndimage.distance_transform_edt(~known, return_distances=False, return_indices=True)
    filled = np.full_like(values, np.nan)
    filled[atlas] = values[nearest[0], nearest[1]][atlas]
    filled = dilate(filled, atlas, dilation_px)
    far = ~np.isfinite(filled).all(axis=-1)
    filled[far] = filled[atlas].mean(axis=0)
    return filled if texture.ndim == 3 else filled[..., 0]
