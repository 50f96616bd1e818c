"""UV-space rasterisation: geometry of the samples, coverage rule, frames, scatter/gather, dilation."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from freqbrdf import texels as tx
from freqbrdf.capture.mesh import Mesh, generate_atlas, plane_mesh, uv_sphere_mesh
from freqbrdf.errors import InputError


def texel_centres_uv(texels: tx.Texels) -> np.ndarray:
    """(N, 2) uv of each covered texel's centre, straight from the documented convention."""
    rows, cols = np.divmod(texels.texel_index, texels.texture_res)
    res = texels.texture_res
    return np.stack([(cols + 0.5) / res, 1.0 - (rows + 0.5) / res], axis=-1)


def assert_right_handed_orthonormal(texels: tx.Texels) -> None:
    frame = np.stack([texels.tangent, texels.bitangent, texels.normal], axis=1)  # (N, 3, 3)
    identity = np.broadcast_to(np.eye(3), frame.shape)
    np.testing.assert_allclose(frame @ np.swapaxes(frame, 1, 2), identity, atol=1e-12)
    np.testing.assert_allclose(np.cross(texels.tangent, texels.bitangent), texels.normal, atol=1e-12)


def affine_quad(uv_corners: np.ndarray, world_from_uv: np.ndarray, world_origin: np.ndarray) -> Mesh:
    """A quad whose world position is world_origin + world_from_uv @ uv, normals constant."""
    vertices = world_origin + uv_corners @ world_from_uv.T
    normal = np.cross(world_from_uv[:, 0], world_from_uv[:, 1])
    normal /= np.linalg.norm(normal)
    faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    return Mesh(vertices, faces, np.tile(normal, (4, 1)), uv_corners)


def single_triangle(uv_corners: np.ndarray) -> Mesh:
    """One triangle whose world position is (u, v, 0): world and UV space coincide."""
    vertices = np.concatenate([uv_corners, np.zeros((3, 1))], axis=1)
    return Mesh(vertices, np.array([[0, 1, 2]]), np.tile([0.0, 0.0, 1.0], (3, 1)), uv_corners)


@pytest.fixture(scope="module")
def atlas_icosphere() -> Mesh:
    sphere = trimesh.creation.icosphere(subdivisions=2)
    return Mesh(*generate_atlas(np.asarray(sphere.vertices), np.asarray(sphere.faces, np.int64),
                                np.asarray(sphere.vertex_normals)))


# --------------------------------------------------------------------------------------------
# Geometry of the samples


def test_full_plane_covers_every_texel_at_its_analytic_point():
    res = 32
    texels = tx.rasterise(plane_mesh(), res)
    assert texels.mask.all() and texels.n_texels == res * res
    assert not texels.snapped.any() and texels.overlap_texels == 0
    uv = texel_centres_uv(texels)
    # plane_mesh: u = x + 0.5, v = 0.5 - z, y = 0
    expected = np.stack([uv[:, 0] - 0.5, np.zeros(len(uv)), 0.5 - uv[:, 1]], axis=-1)
    np.testing.assert_allclose(texels.position, expected, atol=1e-14)
    np.testing.assert_array_equal(texels.normal, np.broadcast_to([0.0, 1.0, 0.0], texels.normal.shape))
    np.testing.assert_allclose(texels.texel_area, 1.0 / res**2, rtol=1e-12)
    assert_right_handed_orthonormal(texels)


@pytest.mark.parametrize("mirrored", [False, True])
def test_affine_chart_samples_lie_at_their_uv_points(mirrored):
    """A sheared, scaled, tilted chart inside the atlas (mirrored charts have clockwise UVs)."""
    rng = np.random.default_rng(3)
    world_from_uv = rng.normal(size=(3, 2))
    origin = rng.normal(size=3)
    corners = np.array([[0.12, 0.2], [0.83, 0.2], [0.83, 0.71], [0.12, 0.71]])
    if mirrored:
        corners[:, 0] = 1.0 - corners[:, 0]
    mesh = affine_quad(corners, world_from_uv, origin)
    res = 40
    texels = tx.rasterise(mesh, res)
    centres = texel_centres_uv(texels)
    sample_uv = np.einsum("nk,nkd->nd", texels.barycentric, corners[mesh.faces[texels.face_id]])
    np.testing.assert_allclose(texels.position, origin + sample_uv @ world_from_uv.T, atol=1e-12)

    inside = np.all((centres >= corners.min(0)) & (centres <= corners.max(0)), axis=1)
    np.testing.assert_array_equal(texels.snapped, ~inside)
    np.testing.assert_allclose(sample_uv[inside], centres[inside], atol=1e-14)
    # Snapped samples are on the chart's boundary, within half a texel diagonal of the centre.
    snap_px = np.linalg.norm(sample_uv[~inside] - centres[~inside], axis=1) * res
    assert np.all(snap_px > 0) and np.all(snap_px <= np.sqrt(0.5) + 1e-12)
    assert np.all((sample_uv >= corners.min(0) - 1e-15) & (sample_uv <= corners.max(0) + 1e-15))

    np.testing.assert_allclose(texels.normal - mesh.normals[0], 0.0, atol=1e-15)
    world_area = np.linalg.norm(np.cross(world_from_uv[:, 0], world_from_uv[:, 1]))  # per unit UV area
    np.testing.assert_allclose(texels.texel_area, world_area / res**2, rtol=1e-12)
    assert_right_handed_orthonormal(texels)


def test_uv_sphere_samples_lie_on_the_sphere_with_radial_normals():
    mesh = uv_sphere_mesh(n_longitude=64, n_latitude=32)
    texels = tx.rasterise(mesh, 128)
    radius = np.linalg.norm(texels.position, axis=1)
    # Flat triangles lie between the sphere and their planes' distance from the centre.
    corners = mesh.vertices[mesh.faces]
    twice_area_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    twice_area = np.linalg.norm(twice_area_normal, axis=1)
    plane_normal = twice_area_normal / twice_area[:, None]
    closest_plane = np.abs(np.einsum("fd,fd->f", plane_normal, corners[:, 0]))[texels.face_id]
    assert np.all(radius <= 1.0 + 1e-12) and np.all(radius >= closest_plane - 1e-12)
    assert radius.min() > 0.99
    # Smooth normals interpolate the radial directions at the corners.
    cosine = np.einsum("nd,nd->n", texels.normal, texels.position / radius[:, None])
    assert cosine.min() > np.cos(np.pi / 32)
    assert_right_handed_orthonormal(texels)
    # Centre-sampled texels partition the charts, so their world areas add up to the mesh's area.
    # (Not the conservative ones: they also fill the UV gaps between the pole fan triangles.)
    centre_sampled = tx.rasterise(mesh, 128, conservative=False)
    np.testing.assert_allclose(centre_sampled.texel_area.sum(), 0.5 * twice_area.sum(), rtol=1e-3)


def test_world_to_local_maps_the_frame_to_the_axes():
    texels = tx.rasterise(uv_sphere_mesh(16, 8), 16)
    local = tx.world_to_local(texels, np.stack([texels.tangent, texels.bitangent, texels.normal], axis=1))
    np.testing.assert_allclose(local, np.broadcast_to(np.eye(3), local.shape), atol=1e-12)


def test_orthonormal_basis_is_orthonormal_right_handed_and_continuous():
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(2000, 3))
    normals = np.concatenate([normals, [[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0]]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    tangent, bitangent = tx.orthonormal_basis(normals)
    for a, b in [(tangent, bitangent), (tangent, normals), (bitangent, normals)]:
        np.testing.assert_allclose(np.einsum("nd,nd->n", a, b), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(tangent, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.cross(tangent, bitangent), normals, atol=1e-12)
    # Within a hemisphere (away from n_z = 0) the frame turns no faster than the normal, up to a
    # bounded factor: a tiny step of n gives a tiny step of the tangent.
    hemisphere = np.abs(normals[:, 2]) > 0.1
    step = 1e-6 * rng.normal(size=normals.shape)
    moved = normals + step
    moved /= np.linalg.norm(moved, axis=1, keepdims=True)
    moved_tangent, _ = tx.orthonormal_basis(moved)
    ratio = np.linalg.norm(moved_tangent - tangent, axis=1) / np.linalg.norm(moved - normals, axis=1)
    assert ratio[hemisphere].max() < 20.0


# --------------------------------------------------------------------------------------------
# Coverage rule


def test_centre_sampling_matches_an_independent_point_in_triangle_test():
    rng = np.random.default_rng(1)
    corners = rng.uniform(0.05, 0.95, size=(3, 2))
    res = 64
    texels = tx.rasterise(single_triangle(corners), res, conservative=False)
    rows, cols = np.mgrid[0:res, 0:res]
    centres = np.stack([(cols + 0.5) / res, 1.0 - (rows + 0.5) / res], axis=-1)
    edge_signs = []
    for start, end in [(0, 1), (1, 2), (2, 0)]:
        edge = corners[end] - corners[start]
        offset = centres - corners[start]
        edge_signs.append(edge[0] * offset[..., 1] - edge[1] * offset[..., 0])
    edge_signs = np.stack(edge_signs)
    expected = np.all(edge_signs > 0, axis=0) | np.all(edge_signs < 0, axis=0)
    np.testing.assert_array_equal(texels.mask, expected)


def test_conservative_coverage_is_exactly_the_overlapped_texels():
    """Lower bound: texels hit by dense samples of the triangle. Upper bound: texels whose centre
    is within half a diagonal of it. A miss or an extra texel falls outside one of them."""
    rng = np.random.default_rng(2)
    res = 48
    for _ in range(3):
        corners = rng.uniform(0.05, 0.95, size=(3, 2))
        texels = tx.rasterise(single_triangle(corners), res)
        weights = rng.dirichlet(np.ones(3), size=400_000)
        weights = np.concatenate([weights, np.eye(3)])
        points = weights @ corners
        hit = np.zeros((res, res), bool)
        hit[np.clip(((1.0 - points[:, 1]) * res).astype(int), 0, res - 1),
            np.clip((points[:, 0] * res).astype(int), 0, res - 1)] = True
        assert not (hit & ~texels.mask).any(), "a texel the triangle overlaps is missing"
        # Every covered texel's sample (its centre snapped onto the triangle) is in its reach.
        centres = texel_centres_uv(texels)
        sample_uv = texels.position[:, :2]
        assert np.all(np.linalg.norm(sample_uv - centres, axis=1) * res <= np.sqrt(0.5) + 1e-12)
        assert np.all(texels.barycentric >= 0) and np.allclose(texels.barycentric.sum(1), 1.0)
        assert texels.mask.sum() - hit.sum() <= 0.02 * hit.sum()


def test_coverage_of_an_atlas_matches_its_uv_area_plus_the_boundary_term(atlas_icosphere):
    """Centre sampling counts ~ the charts' UV area A; conservative coverage adds the Minkowski
    term of the square texel, sum over boundary edges of (|du| + |dv|) / 2 (in texels)."""
    mesh = atlas_icosphere
    res = 128
    centre = tx.rasterise(mesh, res, conservative=False)
    conservative = tx.rasterise(mesh, res)
    uv_px = mesh.uv[mesh.faces] * res
    edge_1, edge_2 = uv_px[:, 1] - uv_px[:, 0], uv_px[:, 2] - uv_px[:, 0]
    area = 0.5 * np.abs(edge_1[:, 0] * edge_2[:, 1] - edge_1[:, 1] * edge_2[:, 0]).sum()
    edges = np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique_edges, uses = np.unique(edges, axis=0, return_counts=True)
    boundary = unique_edges[uses == 1]  # UV seams split vertices, so chart borders are used once
    minkowski = 0.5 * np.abs((mesh.uv[boundary[:, 0]] - mesh.uv[boundary[:, 1]]) * res).sum()
    assert abs(centre.n_texels - area) < 0.05 * minkowski
    assert abs(conservative.n_texels - (area + minkowski)) < 0.05 * minkowski
    assert not centre.snapped.any()
    assert np.array_equal(conservative.mask & centre.mask, centre.mask)
    assert centre.overlap_texels == 0 and conservative.overlap_texels == 0
    # Centre-covered texels sample the same point either way.
    shared = np.isin(conservative.texel_index, centre.texel_index)
    np.testing.assert_array_equal(conservative.position[shared], centre.position)


def test_thin_sliver_chart_is_still_covered():
    """A 0.3-texel-wide sliver running between texel centres holds no centre at all."""
    res = 64
    left, right = (20 + 0.1) / res, (20 + 0.4) / res  # between centres at 20.5 / res and 19.5 / res
    corners = np.array([[left, 0.1], [right, 0.1], [right, 0.9]])
    with pytest.raises(InputError, match="covers no texel"):
        tx.rasterise(single_triangle(corners), res, conservative=False)
    texels = tx.rasterise(single_triangle(corners), res)
    rows, cols = np.divmod(texels.texel_index, res)
    covered_rows = np.arange(int((1 - 0.9) * res), int(np.ceil((1 - 0.1) * res)))
    assert set(cols.tolist()) == {20}
    np.testing.assert_array_equal(np.unique(rows), covered_rows)
    assert texels.snapped.all()
    assert np.all((texels.position[:, 0] >= left - 1e-15) & (texels.position[:, 0] <= right + 1e-15))
    np.testing.assert_allclose(texels.barycentric.sum(axis=1), 1.0)


def test_overlapping_charts_pick_the_lowest_face_and_are_counted():
    res = 16
    plane = plane_mesh()
    lifted = plane.vertices + [0.0, 1.0, 0.0]
    mesh = Mesh(np.concatenate([plane.vertices, lifted]), np.concatenate([plane.faces, plane.faces + 4]),
                np.concatenate([plane.normals, plane.normals]), np.concatenate([plane.uv, plane.uv]))
    texels = tx.rasterise(mesh, res)
    assert texels.mask.all()
    assert np.all(texels.face_id < 2)
    np.testing.assert_array_equal(texels.position[:, 1], 0.0)
    # Centres on the quad's diagonal (row + col = T - 1) lie on an edge, not strictly inside.
    assert texels.overlap_texels == res * res - res


def test_rasterisation_is_deterministic(atlas_icosphere):
    mesh = atlas_icosphere
    first, second = tx.rasterise(mesh, 64), tx.rasterise(mesh, 64)
    for field in ("mask", "texel_index", "face_id", "barycentric", "position", "normal", "tangent",
                  "bitangent", "texel_area", "snapped"):
        np.testing.assert_array_equal(getattr(first, field), getattr(second, field), err_msg=field)


def test_degenerate_uv_faces_are_skipped_and_counted():
    plane = plane_mesh()
    collapsed = np.array([[0, 1, 1]])  # zero UV area (and zero world area)
    mesh = Mesh(plane.vertices, np.concatenate([plane.faces, collapsed]), plane.normals, plane.uv)
    texels = tx.rasterise(mesh, 8)
    assert texels.degenerate_uv_faces == 1 and texels.mask.all() and np.all(texels.face_id < 2)


@pytest.mark.parametrize(
    "uv, res, problem",
    [
        (np.array([[0, 0], [1.5, 0], [1, 1], [0, 1.0]]), 8, "texture coordinates span"),
        (np.array([[0, 0], [np.nan, 0], [1, 1], [0, 1.0]]), 8, "NaN"),
        (np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]]), 0, "positive integer"),
    ],
)
def test_bad_input_raises_input_error(uv, res, problem):
    plane = plane_mesh()
    with pytest.raises(InputError, match=problem):
        tx.rasterise(Mesh(plane.vertices, plane.faces, plane.normals, uv), res)


# --------------------------------------------------------------------------------------------
# Per-texel values <-> images


def test_scatter_and_gather_are_inverse_and_fill_the_rest():
    texels = tx.rasterise(single_triangle(np.array([[0.1, 0.1], [0.9, 0.2], [0.4, 0.8]])), 32)
    values = np.random.default_rng(4).uniform(size=(texels.n_texels, 3)).astype(np.float32)
    image = tx.scatter(texels, values, fill=-1.0)
    assert image.shape == (32, 32, 3) and image.dtype == np.float32
    np.testing.assert_array_equal(tx.gather(texels, image), values)
    np.testing.assert_array_equal(image[~texels.mask], -1.0)
    rows, cols = np.divmod(texels.texel_index, 32)
    np.testing.assert_array_equal(image[rows, cols], values)
    scalar = tx.scatter(texels, values[:, 0])
    assert scalar.shape == (32, 32) and np.all(scalar[~texels.mask] == 0)


def test_dilate_grows_neighbour_means_and_keeps_valid_texels():
    rng = np.random.default_rng(5)
    res = 24
    mask = np.zeros((res, res), bool)
    mask[8:14, 6:12] = True
    texture = np.where(mask[..., None], rng.uniform(size=(res, res, 2)), np.nan)  # empty = garbage
    grown = tx.dilate(texture, mask, pixels=3)
    np.testing.assert_array_equal(grown[mask], texture[mask])
    # Ring 1: the mean of the valid 8-neighbours.
    for row, col in [(7, 8), (14, 11), (7, 5), (10, 12)]:
        block = (slice(row - 1, row + 2), slice(col - 1, col + 2))
        np.testing.assert_allclose(grown[row, col], texture[block][mask[block]].mean(axis=0), rtol=1e-12)
    # Chessboard distance <= 3 is filled with values within the chart's range; beyond stays as it was.
    rows, cols = np.mgrid[0:res, 0:res]
    distance = np.maximum(np.maximum(8 - rows, rows - 13), np.maximum(6 - cols, cols - 11))
    near = (distance >= 1) & (distance <= 3)
    assert np.isfinite(grown[near]).all()
    assert np.all(grown[near] >= texture[mask].min(0)) and np.all(grown[near] <= texture[mask].max(0))
    assert np.isnan(grown[distance > 3]).all()


def test_dilate_of_a_constant_chart_is_constant_and_accepts_single_channel():
    mask = np.zeros((16, 16), bool)
    mask[5, 5:9] = True
    grown = tx.dilate(np.where(mask, 0.25, 0.0), mask, pixels=20)
    np.testing.assert_array_equal(grown, np.full((16, 16), 0.25))
