"""Triangle meshes with one UV atlas: loading, atlas generation (xatlas), OBJ output.

The mesh is the known geometry of docs/method.md#problem; meshes without UVs get an xatlas atlas (docs/method.md#texels).
UV convention: origin at the bottom-left of the texture, as in OBJ (and glTF after trimesh's
flip on import). Texel (row i, column j) of a T x T texture covers
uv = ((j + 0.5) / T, 1 - (i + 0.5) / T); row 0 is the top row of the stored image.
"""

from __future__ import annotations

import hashlib
import warnings
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path

import numpy as np
import trimesh
import xatlas

from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_path

MESH_SUFFIXES = (".obj", ".ply", ".gltf", ".glb")

# xatlas packing: charts are laid out for a 1024^2 atlas with 8 texels between them, i.e. gutters
# of 4 texels at T = 512 and 2 at T = 256, so UV-space rasterisation never mixes charts.
ATLAS_RESOLUTION = 1024
ATLAS_PADDING = 8
# Part of the cache key: change it whenever the atlas settings or algorithm change.
_ATLAS_VERSION = f"xatlas-{version('xatlas')}-res{ATLAS_RESOLUTION}-pad{ATLAS_PADDING}"
_CACHE_TAG = "# freqbrdf atlas cache"


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields explicitly
class Mesh:
    """A triangle mesh with one shading normal and one UV per vertex.

    Vertices are split along UV seams, so one index addresses position, normal and UV.

    Attributes
    ----------
    vertices : (n_vertices, 3) float64
        Positions in world space.
    faces : (n_faces, 3) int64
        Vertex indices, counter-clockwise seen from outside.
    normals : (n_vertices, 3) float64
        Unit shading normals.
    uv : (n_vertices, 2) float64
        Texture coordinates in [0, 1], origin bottom-left (see the module docstring).
    path : Path or None
        The file it was loaded from.
    atlas_generated : bool
        Whether ``uv`` is an xatlas atlas made here (the file had no usable UVs), so maps made
        for the file's own UV layout do not apply.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uv: np.ndarray
    path: Path | None = None
    atlas_generated: bool = False


def load_mesh(path: str | Path, atlas_cache: str | Path | None = None) -> Mesh:
    """Load an OBJ, PLY, glTF or GLB file as one mesh (scene parts merged, transforms applied).

    Normals from the file are kept; missing ones are smooth (area-weighted over faces sharing a
    position, so they do not break along UV seams). A mesh without UVs on every part gets an
    xatlas atlas. UVs outside [0, 1] (tiling) are replaced by an atlas, with a warning.
    Unreferenced vertices are dropped.

    Parameters
    ----------
    path : str or Path
        The mesh file (``.obj``, ``.ply``, ``.gltf`` or ``.glb``).
    atlas_cache : str or Path, optional
        An ``.obj`` path where a generated atlas mesh is stored and reused while the source
        file's content (SHA-256) and the atlas settings are unchanged (for ``.gltf`` only the
        JSON file is hashed, not external buffers).

    Returns
    -------
    Mesh
        The mesh, with ``path`` set.

    Raises
    ------
    InputError
        If the file type is unsupported, the file is missing or unreadable, it holds no
        triangles, or it has non-finite vertices or faces indexing missing vertices.
    """
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(
            path, f"unsupported mesh type {path.suffix!r} (supported: {', '.join(MESH_SUFFIXES)})"
        )
    if not path.is_file():
        raise InputError(path, "file does not exist" if not path.exists() else "is not a file")
    cache_key = None
    if atlas_cache is not None:
        atlas_cache = Path(atlas_cache)
        cache_key = f"{hashlib.sha256(path.read_bytes()).hexdigest()} {_ATLAS_VERSION}"
        cached = _read_atlas_cache(atlas_cache, cache_key)
        if cached is not None:
            vertices, faces, normals, uv = cached
            return Mesh(vertices, faces, normals, uv, path, atlas_generated=True)
    vertices, faces, normals, uv = _read_geometry(path)
    if uv is not None:
        return Mesh(vertices, faces, normals, uv, path)
    mesh = Mesh(*generate_atlas(vertices, faces, normals), path, atlas_generated=True)
    if atlas_cache is not None:
        save_obj(atlas_cache, mesh, comment=f"{_CACHE_TAG} {cache_key}")
    return mesh


def generate_atlas(
    vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Generate a UV atlas with xatlas, splitting vertices at its seams.

    UVs are scaled uniformly into [0, 1]^2 (xatlas normalises width and height separately, which
    would make texels non-square on the surface).

    Parameters
    ----------
    vertices : (n_vertices, 3) float64
        Positions.
    faces : (n_faces, 3) int64
        Vertex indices.
    normals : (n_vertices, 3) float64
        Unit shading normals.

    Returns
    -------
    vertices : (n_split, 3) float64
        Positions of the split vertices.
    faces : (n_faces, 3) int64
        The faces, indexing the split vertices.
    normals : (n_split, 3) float64
        Normals of the split vertices.
    uv : (n_split, 2) float64
        Texture coordinates in [0, 1].
    """
    atlas = xatlas.Atlas()
    atlas.add_mesh(
        vertices.astype(np.float32), faces.astype(np.uint32), normals.astype(np.float32)
    )
    pack_options = xatlas.PackOptions()
    pack_options.resolution = ATLAS_RESOLUTION
    pack_options.padding = ATLAS_PADDING
    atlas.generate(xatlas.ChartOptions(), pack_options)
    source_vertex, atlas_faces, uv = atlas[0]  # (V',), (F, 3), (V', 2)
    extent = np.array([atlas.width, atlas.height], dtype=np.float64)
    uv = uv.astype(np.float64) * extent / extent.max()
    source_vertex = source_vertex.astype(np.int64)
    return vertices[source_vertex], atlas_faces.astype(np.int64), normals[source_vertex], uv


def smooth_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Compute area-weighted vertex normals, shared by all vertices at the same position.

    Parameters
    ----------
    vertices : (n_vertices, 3) float64
        Positions (vertices split at UV seams are welded by position).
    faces : (n_faces, 3) int64
        Vertex indices.

    Returns
    -------
    (n_vertices, 3) float64
        Unit normals; +z where the faces around a position cancel or degenerate.
    """
    _, welded = np.unique(vertices, axis=0, return_inverse=True)
    welded = welded.reshape(-1)
    corners = vertices[faces]  # (F, 3, 3)
    # The cross product's length is twice the triangle area: area weighting for free.
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    accumulated = np.zeros((welded.max() + 1, 3))
    for corner in range(3):
        np.add.at(accumulated, welded[faces[:, corner]], face_normals)
    normals = accumulated[welded]
    return unit_or_fallback(normals, np.array([0.0, 0.0, 1.0]))


def save_obj(path: str | Path, mesh: Mesh, comment: str | None = None) -> None:
    """Write positions, UVs and normals (one shared index per vertex) as OBJ, atomically.

    Floats are written in shortest round-trip form, so `load_mesh` gives back identical arrays.

    Parameters
    ----------
    path : str or Path
        The ``.obj`` file to write.
    mesh : Mesh
        The mesh.
    comment : str, optional
        Header lines, each written as an OBJ comment (``#`` added where missing).
    """
    lines = [] if comment is None else [line if line.startswith("#") else f"# {line}"
                                        for line in comment.splitlines()]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in mesh.vertices.tolist()]
    lines += [f"vt {u!r} {v!r}" for u, v in mesh.uv.tolist()]
    lines += [f"vn {x!r} {y!r} {z!r}" for x, y, z in mesh.normals.tolist()]
    lines += [f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}" for a, b, c in (mesh.faces + 1).tolist()]
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def plane_mesh() -> Mesh:
    """Make a unit square at y = 0 facing +y: x, z in [-0.5, 0.5], u = x + 0.5, v = 0.5 - z.

    Seen from above with -z pointing up the image, the texture appears upright.

    Returns
    -------
    Mesh
        Four vertices, two faces, normals +y.
    """
    vertices = np.array([[-0.5, 0, 0.5], [0.5, 0, 0.5], [0.5, 0, -0.5], [-0.5, 0, -0.5]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    normals = np.tile([0.0, 1.0, 0.0], (4, 1))
    uv = np.stack([vertices[:, 0] + 0.5, 0.5 - vertices[:, 2]], axis=1)
    return Mesh(vertices, faces, normals, uv)


def uv_sphere_mesh(n_longitude: int = 64, n_latitude: int = 32) -> Mesh:
    """Make a unit sphere at the origin, poles on the y axis, u = longitude / 2 pi.

    v is 0 at the south pole and 1 at the north pole. Longitude phi runs from +x towards -z
    (counter-clockwise seen from +y). The seam column (u = 0 and u = 1) is duplicated, and each
    pole has one vertex per longitude segment with u at the segment centre, so no triangle spans
    the seam or degenerates in UV.

    Parameters
    ----------
    n_longitude : int, optional
        Number of longitude segments.
    n_latitude : int, optional
        Number of latitude segments (pole to pole).

    Returns
    -------
    Mesh
        The sphere; its normals equal its positions.
    """
    # Ring vertices: latitude rows 1 .. n_latitude - 1, longitude columns 0 .. n_longitude.
    ring_v = 1.0 - np.arange(1, n_latitude) / n_latitude  # (n_latitude - 1,)
    ring_u = np.arange(n_longitude + 1) / n_longitude  # (n_longitude + 1,)
    v_grid, u_grid = np.meshgrid(ring_v, ring_u, indexing="ij")
    pole_u = (np.arange(n_longitude) + 0.5) / n_longitude
    uv = np.concatenate(
        [
            np.stack([pole_u, np.ones(n_longitude)], axis=1),  # north pole fan
            np.stack([u_grid.ravel(), v_grid.ravel()], axis=1),
            np.stack([pole_u, np.zeros(n_longitude)], axis=1),  # south pole fan
        ]
    )
    polar = np.pi * (1.0 - uv[:, 1])  # angle from +y
    azimuth = 2.0 * np.pi * np.mod(uv[:, 0], 1.0)  # u = 1 lands exactly on the u = 0 column
    vertices = np.stack(
        [np.sin(polar) * np.cos(azimuth), np.cos(polar), -np.sin(polar) * np.sin(azimuth)], axis=1
    )
    vertices[:n_longitude] = [0.0, 1.0, 0.0]  # exact poles (sin(pi) is not exactly 0)
    vertices[-n_longitude:] = [0.0, -1.0, 0.0]
    columns = n_longitude + 1

    def ring(row, col):  # index of ring vertex at latitude row (0-based among rings) and column
        return n_longitude + row * columns + col

    col = np.arange(n_longitude)
    south = n_longitude + (n_latitude - 1) * columns
    triangles = [np.stack([col, ring(0, col), ring(0, col + 1)], axis=1)]
    for row in range(n_latitude - 2):
        top_left, top_right = ring(row, col), ring(row, col + 1)
        bottom_left, bottom_right = ring(row + 1, col), ring(row + 1, col + 1)
        triangles.append(np.stack([top_left, bottom_left, bottom_right], axis=1))
        triangles.append(np.stack([top_left, bottom_right, top_right], axis=1))
    last = n_latitude - 2
    triangles.append(np.stack([ring(last, col), south + col, ring(last, col + 1)], axis=1))
    faces = np.concatenate(triangles).astype(np.int64)
    return Mesh(vertices, faces, vertices.copy(), uv)


# --- internals ------------------------------------------------------------------------------------


def _read_geometry(path: Path):
    """Read (vertices, faces, normals, uv or None) of all mesh parts, in world space, validated."""
    try:
        scene = trimesh.load_scene(path, process=False)
    except Exception as err:  # trimesh raises many types on malformed input
        problem = f"could not be read as a mesh ({type(err).__name__}: {err})"
        raise InputError(path, problem) from None
    parts = []
    for node in scene.graph.nodes_geometry:
        transform, geometry_name = scene.graph[node]
        geometry = scene.geometry[geometry_name]
        if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces) > 0:
            parts.append((geometry, transform))
    if not parts:
        raise InputError(path, "contains no triangles")

    vertex_blocks, face_blocks, normal_blocks, uv_blocks = [], [], [], []
    offset = 0
    for geometry, transform in parts:
        vertices = np.asarray(geometry.vertices, dtype=np.float64)
        faces = np.asarray(geometry.faces, dtype=np.int64)
        _check_geometry(path, vertices, faces)
        # trimesh keeps normals read from the file in its cache and has no public flag for them.
        loaded = geometry._cache["vertex_normals"] if "vertex_normals" in geometry._cache else None
        if loaded is None or np.shape(loaded) != vertices.shape:
            normals = np.full(vertices.shape, np.nan)  # filled with smooth normals below
        else:  # normals transform with the inverse transpose
            normals = np.asarray(loaded, dtype=np.float64) @ np.linalg.inv(transform[:3, :3])
        vertices = vertices @ transform[:3, :3].T + transform[:3, 3]
        if np.linalg.det(transform[:3, :3]) < 0:  # a mirroring transform flips the winding
            faces = faces[:, ::-1]
        uv = getattr(geometry.visual, "uv", None)
        uv_blocks.append(None if uv is None or len(uv) != len(vertices) else np.asarray(uv, float))
        vertex_blocks.append(vertices)
        face_blocks.append(faces + offset)
        normal_blocks.append(normals)
        offset += len(vertices)

    vertices = np.concatenate(vertex_blocks)
    faces = np.concatenate(face_blocks)
    # Smooth normals over the merged mesh, so they are continuous across part boundaries too;
    # they also replace missing, zero or non-finite normals from the file.
    normals = unit_or_fallback(np.concatenate(normal_blocks), smooth_normals(vertices, faces))
    # Parts are assumed to share one texture (as glTF primitives of one object do).
    uv = None if any(block is None for block in uv_blocks) else np.concatenate(uv_blocks)
    if uv is not None and not (np.isfinite(uv).all() and (uv >= 0).all() and (uv <= 1).all()):
        # Tiling or broken UVs cannot address one texel per surface point.
        warnings.warn(f"{path.name}: UVs outside [0, 1]; generating a new atlas", stacklevel=3)
        uv = None
    # Drop unreferenced vertices: they would get meaningless normals and UV texels.
    used = np.zeros(len(vertices), dtype=bool)
    used[faces] = True
    if not used.all():
        new_index = np.cumsum(used) - 1
        vertices, normals, faces = vertices[used], normals[used], new_index[faces]
        uv = None if uv is None else uv[used]
    return vertices, faces, normals, uv


def _check_geometry(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Refuse non-finite vertices and faces that index missing vertices (InputError)."""
    bad_vertices = ~np.isfinite(vertices).all(axis=1)
    if bad_vertices.any():
        first = int(np.argmax(bad_vertices))
        raise InputError(
            path, f"{int(bad_vertices.sum())} vertices are not finite (first: vertex {first})"
        )
    out_of_range = ((faces < 0) | (faces >= len(vertices))).any(axis=1)
    if out_of_range.any():
        first = int(np.argmax(out_of_range))
        raise InputError(
            path,
            f"{int(out_of_range.sum())} faces index missing vertices "
            f"(first: face {first}, {len(vertices)} vertices)",
        )


def unit_or_fallback(vectors: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Normalise rows; rows that are zero or non-finite take the fallback.

    Rows already of unit length (to 1e-12) are kept bit for bit, so that loading a saved mesh
    gives back exactly the normals that were saved.

    Parameters
    ----------
    vectors : (M, 3) float64
        The vectors.
    fallback : (3,) or (M, 3) float64
        What replaces zero or non-finite rows (one row for all, or one per row).

    Returns
    -------
    (M, 3) float64
        Unit vectors.
    """
    length = np.linalg.norm(vectors, axis=1, keepdims=True)
    valid = np.isfinite(length) & (length > 1e-12)
    length = np.where(np.abs(length - 1.0) < 1e-12, 1.0, length)
    unit = np.divide(vectors, length, out=np.zeros_like(vectors), where=valid)
    return np.where(valid, unit, np.broadcast_to(fallback, vectors.shape))


def _read_atlas_cache(cache: Path, key: str):
    """Read the cached (vertices, faces, normals, uv) when ``cache`` was made for ``key``, else None."""
    if not cache.is_file():
        return None
    with cache.open(errors="replace") as file:
        if file.readline().strip() != f"{_CACHE_TAG} {key}":
            return None
    try:
        vertices, faces, normals, uv = _read_geometry(cache)
    except InputError:  # a damaged cache is rebuilt, not reported
        return None
    return None if uv is None else (vertices, faces, normals, uv)
