"""The environment's occlusion by the object itself (freqbrdf.observe.occlusion)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from freqbrdf.assets import mesh_path
from freqbrdf.capture.mesh import Mesh, load_mesh, plane_mesh, uv_sphere_mesh
from freqbrdf.observe.occlusion import (
    MIRROR_CENTRE_WEIGHT,
    _SurfaceRadiance,  # noqa: PLC2701 (the rule itself)
    compact_lights,
    cosine_directions,
    may_be_hidden,
    mirror_occlusion,
    occluded_irradiance,
    occlusion_steps,
    self_occluding,
    uv_texels,
)
from freqbrdf.render.occluder import Occluder
from freqbrdf.sphere.envmap import Envmap, local_directions
from freqbrdf.texels import rasterise

HEIGHT, WIDTH = 64, 128
SUN_ROW, SUN_COLUMN = 11, 40  # about 31 degrees from the map's pole (world +y with an identity to_world)


def sun_map(sun: float = 2000.0, sky: float = 1.0) -> Envmap:
    radiance = np.full((HEIGHT, WIDTH, 3), sky, np.float32)
    radiance[SUN_ROW:SUN_ROW + 2, SUN_COLUMN:SUN_COLUMN + 2] = sun
    return Envmap(radiance)


def map_energy(radiance: np.ndarray) -> np.ndarray:
    """(3,) radiance x solid angle summed over a lat-long map (rows on the poles)."""
    height, width = radiance.shape[:2]
    polar = math.pi * np.arange(height) / (height - 1)
    half = 0.5 * math.pi / (height - 1)
    band = np.cos(np.clip(polar - half, 0, math.pi)) - np.cos(np.clip(polar + half, 0, math.pi))
    return np.einsum("h,hwc->c", band * 2 * math.pi / width, radiance.astype(np.float64))


def test_compact_lights_finds_the_sun_and_keeps_the_energy():
    envmap = sun_map()
    lights = compact_lights(envmap)
    assert lights.direction.shape == (1, 3)
    polar = math.pi * (SUN_ROW + 0.5) / (HEIGHT - 1)
    azimuth = 2 * math.pi * (SUN_COLUMN + 1.0) / WIDTH
    expected = local_directions(np.array([polar]), np.array([azimuth]))[0, 0]
    assert math.degrees(math.acos(np.clip(lights.direction[0] @ expected, -1, 1))) < 2.0
    # The lights and the rest hold the map's energy (the rest is area-averaged to fewer rows).
    total = lights.power[0] + map_energy(lights.rest.radiance)
    np.testing.assert_allclose(total, map_energy(envmap.radiance), rtol=0.02)
    assert lights.rest.radiance.max() < 100.0  # the sun has left the rest


def test_a_map_without_bright_spots_has_no_compact_lights():
    lights = compact_lights(sun_map(sun=3.0))
    assert lights.direction.shape == (0, 3)
    np.testing.assert_allclose(map_energy(lights.rest.radiance), map_energy(sun_map(sun=3.0).radiance), rtol=0.02)


@pytest.mark.parametrize(("mesh", "expected"), [
    (plane_mesh(), False), (uv_sphere_mesh(), False), (load_mesh(mesh_path("bunny")), True)])
def test_self_occluding_tells_convex_and_flat_meshes_from_the_rest(mesh, expected):
    assert self_occluding(mesh.vertices, mesh.faces) is expected


def test_cosine_directions_are_cosine_distributed():
    directions = cosine_directions(4096)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
    # E[cos] under the cosine density is 2/3; the mean of the rays' cosines approaches it.
    assert abs(directions[:, 2].mean() - 2 / 3) < 1e-3


def floor_and_roof() -> Mesh:
    """A floor y = 0 over x, z in [-1, 1] and a roof at y = 0.05 over x in [-1, -0.4]."""
    vertices = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1],
                         [-1, 0.05, -1], [-0.4, 0.05, -1], [-0.4, 0.05, 1], [-1, 0.05, 1]], np.float64)
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]])
    return Mesh(vertices=vertices, faces=faces, normals=np.tile([0.0, 1.0, 0.0], (len(vertices), 1)),
                uv=np.zeros((len(vertices), 2)))


def test_occluded_irradiance_loses_the_sun_under_a_roof_and_nothing_in_the_open():
    envmap = sun_map()
    mesh = floor_and_roof()
    occluder = Occluder(mesh)
    position = np.array([[-0.7, 1e-3, 0.0], [0.9, 1e-3, 0.0]])  # under the roof, in the open
    frame = np.tile(np.array([[1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0]]), (2, 1, 1))  # rows t, b, n = +y
    unoccluded = np.full((2, 3), 10.0)
    shown = np.zeros((2, 3))
    corrected = occluded_irradiance(occluder, envmap, unoccluded, position, frame, shown, np.zeros(2, bool),
                                    np.ones(2))
    sun = compact_lights(envmap)
    sun_share = sun.power[0] * (sun.direction[0] @ [0.0, 1.0, 0.0])
    assert np.array_equal(corrected[1], unoccluded[1].astype(np.float32))  # nothing blocked: unchanged
    assert np.all(corrected[0] <= unoccluded[0] - sun_share + 1e-3)  # the sun is gone, and more

    # What the object shows in the blocked directions comes back: a bright roof lights the texel.
    bright = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    lit_position = np.vstack([position, [[-0.7, 0.049, 0.0]]])
    lit_frame = np.concatenate([frame, frame[:1]])
    shows = np.vstack([bright, [[5.0, 5.0, 5.0]]])
    observed = np.array([False, False, True])
    brighter = occluded_irradiance(occluder, envmap, np.full((3, 3), 10.0), lit_position, lit_frame, shows, observed,
                                   np.full(3, 0.1))
    assert np.all(brighter[0] > corrected[0] + 5.0)


def test_occluded_irradiance_is_deterministic():
    envmap = sun_map()
    occluder = Occluder(floor_and_roof())
    rng = np.random.default_rng(0)
    position = np.column_stack([rng.uniform(-1, 1, 50), np.full(50, 1e-3), rng.uniform(-1, 1, 50)])
    frame = np.tile(np.array([[1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0]]), (50, 1, 1))
    arguments = (occluder, envmap, np.full((50, 3), 10.0), position, frame, np.ones((50, 3)), np.ones(50, bool),
                 np.full(50, 0.05))
    assert np.array_equal(occluded_irradiance(*arguments), occluded_irradiance(*arguments))


def test_the_occluder_traces_on_numba_s_threads_with_the_same_hits():
    """Mitsuba traces on as many threads as the fit's numba kernels (a batch task's CPUs), hit for hit the same."""
    import drjit
    import numba

    from freqbrdf.observe.observations import _occluder

    rng = np.random.default_rng(1)
    origins = np.column_stack([rng.uniform(-1, 1, 500), np.full(500, 1e-3), rng.uniform(-1, 1, 500)])
    directions = rng.normal(size=(500, 3))
    directions[:, 1] = np.abs(directions[:, 1])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    threads, traced = numba.get_num_threads(), drjit.thread_count()
    try:
        mesh = floor_and_roof()
        numba.set_num_threads(1)
        one = _occluder(mesh)
        assert drjit.thread_count() == 1
        hits_on_one = one.hits(origins, directions)
        numba.set_num_threads(threads)
        every = _occluder(mesh)  # the same scene, traced on the threads numba has now
        assert every is one and drjit.thread_count() == threads
        assert Occluder(mesh, 1) is not None and drjit.thread_count() == 1
        np.testing.assert_array_equal(every.hits(origins, directions), hits_on_one)
        assert 0 < hits_on_one.sum() < 500
    finally:
        numba.set_num_threads(threads)
        drjit.set_thread_count(traced)


def test_occluded_irradiance_reports_every_step():
    envmap = sun_map()
    occluder = Occluder(floor_and_roof())
    position = np.column_stack([np.linspace(-0.9, 0.9, 7), np.full(7, 1e-3), np.zeros(7)])
    frame = np.tile(np.array([[1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0]]), (7, 1, 1))
    steps = []
    occluded_irradiance(occluder, envmap, np.full((7, 3), 10.0), position, frame, np.ones((7, 3)), np.ones(7, bool),
                        np.full(7, 0.05), steps.append)
    assert sum(steps) == occlusion_steps(7) == 2


def test_mirror_occlusion_finds_the_roof_in_the_mirror_lobe_and_what_it_shows():
    occluder = Occluder(floor_and_roof())
    # A texel under the roof (the roof's underside is observed, showing (5, 4, 3)) and one in the open.
    position = np.array([[-0.7, 1e-3, 0.0], [0.9, 1e-3, 0.0], [-0.7, 0.049, 0.0]])
    frame = np.tile(np.array([[1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0]]), (3, 1, 1))  # rows t, b, n = +y
    tilted = np.array([math.sin(0.3), 0.0, math.cos(0.3)])  # 17 degrees from the normal: the lobe is under the roof
    grazing = np.array([math.sin(1.5), 0.0, math.cos(1.5)])  # 4 degrees above the floor: the roof's edge
    view_direction = np.stack([np.stack([tilted, grazing])] * 3).astype(np.float32)  # (3, 2, 3)
    visible = np.array([[True, True], [True, False], [False, False]])
    shows = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [5.0, 4.0, 3.0]])
    occluded, surface = mirror_occlusion(occluder, position, frame, view_direction, visible, shows,
                                         np.array([False, True, True]), np.full(3, 0.1))
    assert occluded[0, 0] == 1.0  # the whole lobe meets the roof
    np.testing.assert_allclose(surface[0, 0], [5.0, 4.0, 3.0])  # the roof texel nearest the hits
    # The grazing lobe's centre passes under the roof's edge; the rays of its ring tilted up meet the roof.
    assert 0.0 < occluded[0, 1] < 1.0 - MIRROR_CENTRE_WEIGHT + 1e-6
    assert not occluded[1].any() and not surface[1].any()  # in the open: nothing met, 0


def test_occlusion_steps_count_the_mirror_rays_batches():
    occluder = Occluder(floor_and_roof())
    position = np.column_stack([np.linspace(-0.9, 0.9, 7), np.full(7, 1e-3), np.zeros(7)])
    frame = np.tile(np.array([[1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0]]), (7, 1, 1))
    steps = []
    mirror_occlusion(occluder, position, frame, np.tile(np.array([0.0, 0.0, 1.0], np.float32), (7, 4, 1)),
                     np.ones((7, 4), bool), np.ones((7, 3)), np.ones(7, bool), np.full(7, 0.05), steps.append)
    assert sum(steps) == occlusion_steps(7, 4) - occlusion_steps(7) == 1


def test_rays_not_traced_from_texels_above_the_whole_mesh_are_the_rays_that_would_miss():
    """`may_be_hidden` is conservative: the bunny's texels it clears meet nothing upwards, and skipping them
    changes neither the irradiance nor the mirror occlusion."""
    mesh = load_mesh(mesh_path("bunny"))
    rng = np.random.default_rng(3)
    faces = rng.choice(len(mesh.faces), 400, replace=False)
    corners = mesh.vertices[mesh.faces[faces]]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    origin = corners.mean(axis=1) + 1e-3 * normal
    hidden = may_be_hidden(origin, normal, mesh.vertices)
    assert 0 < hidden.sum() < len(hidden)  # concave: some texels see the mesh above them, others not
    occluder = Occluder(mesh)
    clear = np.flatnonzero(~hidden)
    directions = rng.normal(size=(len(clear), 32, 3))
    directions /= np.linalg.norm(directions, axis=2, keepdims=True)
    directions *= np.sign(np.einsum("trc,tc->tr", directions, normal[clear]))[..., None]  # upwards
    assert not occluder.hits(np.repeat(origin[clear], 32, axis=0), directions.reshape(-1, 3)).any()
    # A floor under a roof: the floor's texels may be hidden, the roof's top ones not.
    roofed = floor_and_roof()
    points = np.array([[-0.7, 1e-3, 0.0], [0.0, 0.06, 0.0]])
    np.testing.assert_array_equal(may_be_hidden(points, np.array([[0.0, 1.0, 0.0]] * 2), roofed.vertices),
                                  [True, False])

    tangent = np.cross(normal, [0.0, 0.0, 1.0])
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    frame = np.stack([tangent, np.cross(normal, tangent), normal], axis=1)
    envmap, shown = sun_map(), rng.uniform(0.0, 1.0, (len(origin), 3))
    observed, size = np.ones(len(origin), bool), np.full(len(origin), 0.01)
    irradiance = np.full((len(origin), 3), 10.0)
    np.testing.assert_array_equal(
        occluded_irradiance(occluder, envmap, irradiance, origin, frame, shown, observed, size, hidden=hidden),
        occluded_irradiance(occluder, envmap, irradiance, origin, frame, shown, observed, size))
    view = rng.normal(size=(len(origin), 6, 3))
    view[..., 2] = np.abs(view[..., 2])
    view /= np.linalg.norm(view, axis=2, keepdims=True)
    visible = rng.random((len(origin), 6)) < 0.7
    for traced, full in zip(
            mirror_occlusion(occluder, origin, frame, view, visible, shown, observed, size, hidden=hidden),
            mirror_occlusion(occluder, origin, frame, view, visible, shown, observed, size)):
        np.testing.assert_array_equal(traced, full)


def test_a_hit_reads_the_texel_that_holds_it_in_uv():
    """Rays aimed at the bunny's texel points find them by face and barycentric coordinates: the
    texel read is the texel aimed at (the nearest-texel rule agrees), and an unobserved texel is
    replaced by its nearest observed one."""
    mesh = load_mesh(mesh_path("bunny"))
    texels = rasterise(mesh, 64)
    uv = uv_texels(mesh.uv, mesh.faces, texels.mask)
    assert uv.face_xy.shape == (len(mesh.faces), 3, 2)
    assert np.array_equal(uv.texel_of_pixel.ravel()[texels.texel_index], np.arange(texels.n_texels))
    assert (uv.texel_of_pixel[~texels.mask] == -1).all()

    rng = np.random.default_rng(5)
    aimed = rng.choice(np.flatnonzero(~texels.snapped), 300, replace=False)
    origins = texels.position[aimed] + 0.05 * texels.normal[aimed]
    occluder = Occluder(mesh)
    hits, distance, face, barycentric = occluder.first_hits_rows(
        np.ascontiguousarray(origins.T, np.float32), np.ascontiguousarray(-texels.normal[aimed].T, np.float32))
    points = origins[hits] - distance[:, None] * texels.normal[aimed][hits]
    shown = rng.uniform(0.0, 1.0, (texels.n_texels, 3))
    observed = np.ones(texels.n_texels, bool)
    located = _SurfaceRadiance(texels.position, shown, observed, texels.texel_size, uv)
    nearest = _SurfaceRadiance(texels.position, shown, observed, texels.texel_size)
    read = located.at(points, face, barycentric)
    same_texel = np.all(read == shown[aimed[hits]], axis=1)
    assert same_texel.mean() > 0.9  # the rest: the ray met another part first, or an edge texel's neighbour
    assert np.all(read == nearest.at(points, face, barycentric), axis=1).mean() > 0.9
    hidden_texel = aimed[hits][same_texel][0]
    observed[hidden_texel] = False
    instead = _SurfaceRadiance(texels.position, shown, observed, texels.texel_size, uv).at(points, face, barycentric)
    row = np.flatnonzero(aimed[hits] == hidden_texel)[0]
    assert not np.array_equal(instead[row], shown[hidden_texel])
    assert any(np.array_equal(instead[row], shown[t]) for t in np.flatnonzero(observed))


def test_an_occluder_traces_the_same_after_giving_back_its_buffers():
    occluder = Occluder(floor_and_roof())
    origins = np.ascontiguousarray(np.array([[-0.7, 0.9], [1e-3, 1e-3], [0.0, 0.0]], np.float32))
    up = np.ascontiguousarray(np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 0.0]], np.float32))
    before = occluder.first_hits_rows(origins, up)
    occluder.release_memory()
    after = occluder.first_hits_rows(origins, up)
    assert list(before[0]) == [0]  # under the roof only
    np.testing.assert_allclose(before[1], [0.05 - 1e-3], rtol=1e-5)
    for found, again in zip(before, after):
        np.testing.assert_array_equal(found, again)
