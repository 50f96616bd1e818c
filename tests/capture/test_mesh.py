"""Meshes: loading OBJ/PLY/GLB, normals, xatlas atlases and their cache, generated primitives."""

import numpy as np
import pytest
import trimesh

from freqbrdf.assets import mesh_path
from freqbrdf.capture import mesh as mesh_module
from freqbrdf.capture.mesh import Mesh, load_mesh, plane_mesh, save_obj, uv_sphere_mesh
from freqbrdf.errors import InputError


def uv_coverage(uv, faces, resolution=256):
    """How many triangles cover each texel centre ``(R, R)``; > 1 means overlapping charts."""
    counts = np.zeros((resolution, resolution), dtype=np.int32)
    for a, b, c in uv[faces] * resolution:
        lo = np.floor(np.minimum(np.minimum(a, b), c) - 0.5).astype(int).clip(0, resolution - 1)
        hi = np.ceil(np.maximum(np.maximum(a, b), c) - 0.5).astype(int).clip(0, resolution - 1)
        x, y = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
        px, py = x + 0.5, y + 0.5
        area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        if area == 0:
            continue
        w0 = ((b[0] - px) * (c[1] - py) - (b[1] - py) * (c[0] - px)) / area
        w1 = ((c[0] - px) * (a[1] - py) - (c[1] - py) * (a[0] - px)) / area
        inside = (w0 > 1e-9) & (w1 > 1e-9) & (1 - w0 - w1 > 1e-9)
        counts[y[inside], x[inside]] += 1
    return counts


def face_corner_positions(vertices, faces):
    """Faces as sorted tuples of corner positions: compares geometry across re-indexing."""
    corners = np.round(vertices[faces], 9)  # (F, 3, 3)
    return sorted(tuple(sorted(map(tuple, triangle))) for triangle in corners.tolist())


def write_obj_without_normals(path, mesh):
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in mesh.vertices.tolist()]
    lines += [f"vt {u!r} {v!r}" for u, v in mesh.uv.tolist()]
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in (mesh.faces + 1).tolist()]
    path.write_text("\n".join(lines) + "\n")


def assert_same_mesh(a: Mesh, b: Mesh):
    for name in ("vertices", "faces", "normals", "uv"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


# --- loading --------------------------------------------------------------------------------------


def test_obj_round_trip_is_exact(tmp_path):
    sphere = uv_sphere_mesh(12, 6)
    save_obj(tmp_path / "s.obj", sphere, comment="test sphere")
    loaded = load_mesh(tmp_path / "s.obj")
    assert_same_mesh(loaded, sphere)
    assert loaded.path == tmp_path / "s.obj"
    assert loaded.vertices.dtype == np.float64 and loaded.faces.dtype == np.int64


def test_missing_normals_are_smooth_and_continuous_across_uv_seams(tmp_path):
    sphere = uv_sphere_mesh(48, 24)
    write_obj_without_normals(tmp_path / "s.obj", sphere)
    loaded = load_mesh(tmp_path / "s.obj")
    np.testing.assert_allclose(np.linalg.norm(loaded.normals, axis=1), 1.0, atol=1e-12)
    # On a sphere the smooth normal approximates the position direction...
    assert np.min(np.einsum("ij,ij->i", loaded.normals, loaded.vertices)) > 0.99
    # ...and the duplicated seam vertices (u = 0 and u = 1) get exactly the same normal.
    seam_start = np.flatnonzero(loaded.uv[:, 0] == 0)
    seam_end = np.flatnonzero(loaded.uv[:, 0] == 1)
    assert len(seam_start) == len(seam_end) > 0
    np.testing.assert_array_equal(loaded.vertices[seam_start], loaded.vertices[seam_end])
    np.testing.assert_array_equal(loaded.normals[seam_start], loaded.normals[seam_end])


def test_glb_with_uvs_keeps_them(tmp_path):
    sphere = uv_sphere_mesh(16, 8)
    visual = trimesh.visual.TextureVisuals(uv=sphere.uv)
    trimesh.Trimesh(sphere.vertices, sphere.faces, visual=visual, process=False).export(
        tmp_path / "s.glb"
    )
    loaded = load_mesh(tmp_path / "s.glb")
    assert loaded.faces.shape == sphere.faces.shape
    # glTF stores float32; trimesh flips v on import so the convention stays bottom-left.
    np.testing.assert_allclose(
        loaded.vertices[loaded.faces], sphere.vertices[sphere.faces], atol=1e-6
    )
    np.testing.assert_allclose(loaded.uv[loaded.faces], sphere.uv[sphere.faces], atol=1e-6)


def test_glb_scene_parts_are_merged_with_transforms(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box(), node_name="centre")
    moved = np.diag([-1.0, 1.0, 1.0, 1.0])  # a mirror, then a shift along x
    moved[0, 3] = 3.0
    scene.add_geometry(trimesh.creation.box(), node_name="moved", transform=moved)
    scene.export(tmp_path / "scene.glb")
    loaded = load_mesh(tmp_path / "scene.glb")
    assert len(loaded.faces) == 24
    np.testing.assert_allclose(loaded.vertices.min(axis=0), [-0.5, -0.5, -0.5], atol=1e-6)
    np.testing.assert_allclose(loaded.vertices.max(axis=0), [3.5, 0.5, 0.5], atol=1e-6)
    # The mirrored part keeps outward winding and outward normals.
    merged = trimesh.Trimesh(loaded.vertices, loaded.faces)
    assert merged.volume == pytest.approx(2.0, rel=1e-6)
    centres = np.where(loaded.vertices[:, [0]] > 1.5, [3.0, 0, 0], [0.0, 0, 0])
    assert np.all(np.einsum("ij,ij->i", loaded.normals, loaded.vertices - centres) > 0)


# --- atlas ----------------------------------------------------------------------------------------


def test_atlas_for_mesh_without_uvs(tmp_path):
    source = trimesh.creation.icosphere(subdivisions=3)
    source.export(tmp_path / "ico.ply")
    loaded = load_mesh(tmp_path / "ico.ply")
    assert loaded.uv.min() >= 0 and loaded.uv.max() <= 1
    coverage = uv_coverage(loaded.uv, loaded.faces)
    assert coverage.max() == 1, "charts overlap"
    assert (coverage > 0).mean() > 0.4, "atlas wastes most of the texture"
    # Same surface, only re-indexed: seams split vertices but move nothing.
    stored = trimesh.load(tmp_path / "ico.ply", process=False)  # PLY keeps float32 positions
    assert face_corner_positions(loaded.vertices, loaded.faces) == face_corner_positions(
        np.asarray(stored.vertices), np.asarray(stored.faces)
    )
    assert len(loaded.vertices) > len(stored.vertices)
    # Split copies of a vertex share its normal, so shading is continuous over chart seams.
    _, welded = np.unique(loaded.vertices, axis=0, return_inverse=True)
    first_copy = np.unique(welded, return_index=True)[1][welded]
    np.testing.assert_array_equal(loaded.normals, loaded.normals[first_copy])


def test_atlas_cache_is_written_and_reused(tmp_path, monkeypatch):
    source, cache = tmp_path / "ico.ply", tmp_path / "cache" / "ico_atlas.obj"
    trimesh.creation.icosphere(subdivisions=2).export(source)
    first = load_mesh(source, atlas_cache=cache)
    assert cache.is_file()

    class NoAtlas:
        def __init__(self):
            raise AssertionError("xatlas ran although the cache was valid")

    with monkeypatch.context() as patch:
        patch.setattr(mesh_module.xatlas, "Atlas", NoAtlas)
        second = load_mesh(source, atlas_cache=cache)
    assert_same_mesh(first, second)
    assert second.path == source

    # A changed source invalidates the cache: xatlas must run again.
    trimesh.creation.icosphere(subdivisions=2, radius=2.0).export(source)
    with monkeypatch.context() as patch:
        patch.setattr(mesh_module.xatlas, "Atlas", NoAtlas)
        with pytest.raises(AssertionError, match="xatlas ran"):
            load_mesh(source, atlas_cache=cache)
    third = load_mesh(source, atlas_cache=cache)
    np.testing.assert_allclose(np.linalg.norm(third.vertices, axis=1), 2.0)


def test_bundled_bunny_atlas_has_no_overlapping_charts():
    bunny = load_mesh(mesh_path("bunny"))
    coverage = uv_coverage(bunny.uv, bunny.faces)
    assert coverage.max() == 1 and (coverage > 0).mean() > 0.4


# --- bad input ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name, content, problem",
    [
        ("points.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\n", "no triangles"),
        ("nan.obj", "v nan 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n", "1 vertices are not finite"),
        (
            "range.ply",
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
            "end_header\n0 0 0\n1 0 0\n1 1 0\n3 0 1 7\n",
            "1 faces index missing vertices",
        ),
        ("junk.glb", "\x00\x01garbage", "could not be read"),
        ("a.stl", "solid", "unsupported mesh type"),
    ],
)
def test_bad_meshes_raise_input_error(tmp_path, name, content, problem):
    (tmp_path / name).write_text(content)
    with pytest.raises(InputError, match=problem) as err:
        load_mesh(tmp_path / name)
    assert err.value.path == tmp_path / name


def test_missing_mesh(tmp_path):
    with pytest.raises(InputError, match=r"nothing\.obj: file does not exist"):
        load_mesh(tmp_path / "nothing.obj")


# --- generated primitives -------------------------------------------------------------------------


def test_plane_faces_up_and_spans_the_texture():
    plane = plane_mesh()
    face_normals = trimesh.Trimesh(plane.vertices, plane.faces, process=False).face_normals
    np.testing.assert_allclose(face_normals, [[0, 1, 0], [0, 1, 0]], atol=1e-12)
    np.testing.assert_array_equal(plane.normals, np.tile([0.0, 1.0, 0.0], (4, 1)))
    np.testing.assert_array_equal(plane.uv[:, 0], plane.vertices[:, 0] + 0.5)
    np.testing.assert_array_equal(plane.uv[:, 1], 0.5 - plane.vertices[:, 2])
    assert trimesh.Trimesh(plane.vertices, plane.faces).area == pytest.approx(1.0)


def test_uv_sphere_is_closed_outward_and_seam_safe():
    sphere = uv_sphere_mesh(64, 32)
    np.testing.assert_allclose(np.linalg.norm(sphere.vertices, axis=1), 1.0, atol=1e-15)
    np.testing.assert_array_equal(sphere.normals, sphere.vertices)
    welded = trimesh.Trimesh(sphere.vertices, sphere.faces)  # merges seam and pole copies
    assert welded.is_watertight and welded.is_winding_consistent
    assert welded.volume == pytest.approx(4 / 3 * np.pi, rel=0.01)
    assert welded.volume > 0  # outward winding
    corners = sphere.uv[sphere.faces]  # (F, 3, 2)
    assert np.ptp(corners[..., 0], axis=1).max() <= 1 / 64 + 1e-12, "a triangle spans the seam"
    edge1, edge2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    uv_area = edge1[:, 0] * edge2[:, 1] - edge1[:, 1] * edge2[:, 0]
    assert np.all(uv_area > 0), "UV triangles degenerate or flipped"
    # Texture coordinates match the stated convention: v = 0 at the south pole, u along phi.
    polar = np.arccos(np.clip(sphere.vertices[:, 1], -1, 1))
    np.testing.assert_allclose(sphere.uv[:, 1], 1 - polar / np.pi, atol=1e-12)
    ring = (sphere.uv[:, 1] > 0) & (sphere.uv[:, 1] < 1) & (sphere.uv[:, 0] < 1)
    azimuth = np.arctan2(-sphere.vertices[ring, 2], sphere.vertices[ring, 0]) % (2 * np.pi)
    np.testing.assert_allclose(azimuth, 2 * np.pi * sphere.uv[ring, 0], atol=1e-9)
