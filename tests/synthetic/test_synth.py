"""Mitsuba scenes and synthetic captures: the conventions that join our data to Mitsuba's.

1. Environment maps: a mirror sphere rendered by Mitsuba under a rotated bundled envmap shows
   exactly what `envmap.lookup` returns in the mirror direction of our camera's rays.
2. Cameras: a capture written by synth (both layouts) loads back with the same cameras, and
   Mitsuba's sensor for a loaded camera sends the ray through a pixel exactly where
   `Camera.project` puts the point.
3. Textures: texel (i, j) of a base colour map renders where our UV convention puts it.
"""

import sys
from dataclasses import replace

import numpy as np
import pytest
from scipy import ndimage

from freqbrdf.assets import envmap_path, mesh_path
from freqbrdf.capture.camera import Camera, look_at
from freqbrdf.capture.camera_layouts import fibonacci_directions
from freqbrdf.capture.layouts import load
from freqbrdf.capture.mesh import load_mesh
from freqbrdf.cli import main
from freqbrdf.model.materials import MaterialMaps
from freqbrdf.render import scenes as render
from freqbrdf.sphere.envmap import Envmap, load_envmap, lookup
from freqbrdf.synthetic.synth import CAPTURE_FORMATS, SynthSettings, prepare, synthesize

pytestmark = pytest.mark.slow  # every test here renders with Mitsuba


def rotation(axis, angle):
    """Rotation matrix (3, 3) about ``axis`` by ``angle`` radians (Rodrigues)."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def uniform_envmap(value=1.0):
    return Envmap(np.full((8, 16, 3), value, np.float32), np.eye(4))


def subpixel_ray_directions(camera, samples_per_axis):
    """World directions (S*S, H, W, 3) through a regular grid of points inside each pixel."""
    offsets = (np.arange(samples_per_axis) + 0.5) / samples_per_axis
    rows, columns = np.meshgrid(np.arange(camera.height), np.arange(camera.width), indexing="ij")
    directions = []
    for dy in offsets:
        for dx in offsets:
            x = (columns + dx - camera.cx) / camera.fx
            y = -(rows + dy - camera.cy) / camera.fy
            local = np.stack([x, y, -np.ones_like(x)], axis=-1)
            world = local @ camera.camera_to_world[:3, :3].T
            directions.append(world / np.linalg.norm(world, axis=-1, keepdims=True))
    return np.stack(directions)


# --- 1. environment map convention ---------------------------------------------------------------


def test_mirror_sphere_shows_envmap_lookup_in_mirror_direction():
    """Mitsuba's render of a perfect mirror vs our lookup of the reflected camera rays.

    A pixel is the average of the radiance over its footprint (box filter), and the reflected
    direction sweeps across several envmap texels within one pixel, so each rendered pixel is
    compared with the average of lookups over an 8 x 8 grid of points inside it. What remains
    is Monte Carlo noise (Mitsuba's 512 random points per pixel vs our grid), about 1.5 %
    median on the sphere, where pixels span many envmap texels of this busy map, and 0.2 % in
    the background. A half-texel shift of the lookup raises these to 3.5 % and 4 %.
    """
    to_world = np.eye(4)
    to_world[:3, :3] = rotation([0.3, 1.0, 0.2], 0.8)  # tilts the zenith, not only a spin
    envmap = load_envmap(envmap_path("forest"), to_world)
    # Off-centre principal point, so that a wrong sign in the sensor conversion shows.
    pose = look_at([0.5, 1.0, 3.0], [0.0, 0.0, 0.0])
    camera = Camera(pose, fx=70.0, fy=70.0, cx=30.3, cy=25.1, width=64, height=48)
    mi = render.mitsuba()
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": render.path_integrator(),
            "mirror": {"type": "sphere", "radius": 1.0, "bsdf": {"type": "conductor"}},
            "environment": render.envmap_emitter(envmap),
        }
    )
    view = render.render_view(scene, camera, spp=512, seed=1)

    # Analytic unit sphere at the origin: hit points, normals and mirror directions.
    directions = subpixel_ray_directions(camera, 8)  # (S, H, W, 3)
    origin = camera.center
    half_b = directions @ origin  # (S, H, W)
    discriminant = half_b**2 - (origin @ origin - 1.0)
    hits = discriminant > 0
    distance = -half_b - np.sqrt(np.maximum(discriminant, 0.0))
    normals = origin + distance[..., None] * directions
    mirrored = directions - 2.0 * np.sum(directions * normals, -1, keepdims=True) * normals
    seen = np.where(hits[..., None], mirrored, directions)  # background pixels see the envmap
    expected = lookup(envmap, seen.reshape(-1, 3)).reshape(directions.shape).mean(axis=0)

    # Pixels fully on the sphere, away from the grazing rim where mirror directions change fast.
    facing = -np.sum(directions * normals, -1).min(axis=0) > 0.3
    on_sphere = hits.all(axis=0) & facing
    background = ~hits.any(axis=0)
    relative_error = np.abs(view.radiance - expected) / np.maximum(expected, 1e-6)
    assert on_sphere.sum() > 500 and background.sum() > 500
    assert np.median(relative_error[on_sphere]) < 0.025
    assert np.median(relative_error[background]) < 0.01
    # Coverage is the hit fraction: exactly 1 inside the silhouette and 0 outside it.
    # (Pixels next to the silhouette may have random samples on the other side of it.)
    np.testing.assert_array_equal(view.coverage[ndimage.binary_erosion(hits.all(axis=0))], 1.0)
    np.testing.assert_array_equal(view.coverage[~ndimage.binary_dilation(hits.any(axis=0))], 0.0)


# --- 2. capture round trip ------------------------------------------------------------------------

TINY = SynthSettings(
    mesh="bunny", views=3, resolution=24, spp=2, texture_res=16, test_views=2, test_envmaps=1
)


def mitsuba_pixel_error(camera, points):
    """How far (in pixels) Mitsuba's ray through ``camera.project(points)`` misses each point."""
    mi = render.mitsuba()
    sensor = mi.load_dict(render.perspective_sensor(camera, spp=1))
    pixels, _ = camera.project(points)
    film_position = mi.Point2f(pixels[:, 0] / camera.width, pixels[:, 1] / camera.height)
    rays, _ = sensor.sample_ray(0.0, 0.5, film_position, mi.Point2f(0.5, 0.5))
    origin = np.array(rays.o, dtype=np.float64).reshape(3, -1).T  # (N, 3)
    direction = np.array(rays.d, dtype=np.float64).reshape(3, -1).T
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    offset = points - origin
    along = np.sum(offset * direction, axis=1)
    miss = np.linalg.norm(offset - along[:, None] * direction, axis=1)
    return miss / along * camera.fx  # small angles: pixels = angle * focal length


@pytest.mark.parametrize("layout", CAPTURE_FORMATS)
def test_capture_loads_back_with_the_cameras_mitsuba_rendered(tmp_path, layout):
    settings = replace(TINY, format=layout)
    scene = prepare(settings)
    captured = load(synthesize(tmp_path / "capture", settings, progress=False))
    assert len(captured.frames) == settings.views
    for frame, camera in zip(captured.frames, scene.cameras):
        np.testing.assert_allclose(frame.camera.camera_to_world, camera.camera_to_world, atol=1e-12)
        loaded = frame.camera
        assert (loaded.fx, loaded.fy, loaded.cx, loaded.cy) == pytest.approx(
            (camera.fx, camera.fy, camera.cx, camera.cy), rel=1e-12
        )
        assert (loaded.width, loaded.height) == (settings.resolution, settings.resolution)
        assert captured.mask(0).shape == (settings.resolution, settings.resolution)
        assert mitsuba_pixel_error(loaded, captured.mesh.vertices[::50]).max() < 0.01
    # The mesh comes back with its own normals (ORB stores them in Blender's axes).
    np.testing.assert_allclose(captured.mesh.normals, scene.mesh.normals, atol=1e-12)
    if layout == "ours":
        np.testing.assert_array_equal(captured.ground_truth.base_color, scene.materials.base_color)
        assert len(captured.test_frames) == settings.test_views
        np.testing.assert_allclose(captured.envmap.radiance, scene.envmap.radiance)
    else:
        # The light is stored in test camera 0's frame; placed back in the world it is the
        # training map up to one bilinear resampling.
        directions = fibonacci_directions(2000, hemisphere=False)
        relative = np.abs(lookup(captured.envmap, directions) - lookup(scene.envmap, directions))
        assert np.median(relative / np.maximum(lookup(scene.envmap, directions), 1e-3)) < 0.05
        # The relighting views (transforms_novel.json) come back with their own light, placed in
        # the world by their camera: the test map it was rendered under, up to one resampling.
        assert len(captured.test_frames) == settings.test_views
        for frame, camera, source in zip(captured.test_frames, scene.test_cameras, scene.test_envmap_paths):
            np.testing.assert_allclose(frame.camera.camera_to_world, camera.camera_to_world, atol=1e-12)
            assert frame.image_path.is_file() and frame.mask_path.is_file()
            placed = load_envmap(frame.envmap_path, frame.envmap_to_world)
            truth = lookup(load_envmap(source, np.eye(4)), directions)
            relative = np.abs(lookup(placed, directions) - truth) / np.maximum(truth, 1e-3)
            assert np.median(relative) < 0.05


def test_synth_command_writes_a_capture_and_reports_bad_input(tmp_path, monkeypatch, capsys):
    out = tmp_path / "cli"
    arguments = ["freqbrdf", "synth", str(out), "--mesh", "plane", "--views", "2",
                 "--resolution", "16", "--spp", "2", "--texture-res", "8", "--test-views", "1",
                 "--test-envmaps", "city", "--cameras", "random", "--seed", "5"]
    monkeypatch.setattr(sys, "argv", arguments)
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code in (None, 0)
    captured = load(out)
    assert len(captured.frames) == 2 and captured.test_frames[0].envmap_path.stem.endswith("city")

    monkeypatch.setattr(sys, "argv", arguments[:3] + ["--mesh", str(tmp_path / "missing.obj")])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    assert "missing.obj" in capsys.readouterr().err
    assert len(load(out).frames) == 2  # a failed run leaves the previous capture alone


def test_fibonacci_directions_are_unit_and_evenly_spread():
    for hemisphere in (True, False):
        directions = fibonacci_directions(200, hemisphere)
        np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
        if hemisphere:
            assert (directions[:, 1] > 0).all()
        # Even spread: the centroid of a uniform sphere (hemisphere) is 0 (0.5 up the axis).
        np.testing.assert_allclose(directions.mean(axis=0), [0, 0.5 if hemisphere else 0, 0], atol=0.02)


# --- 3. texture orientation -------------------------------------------------------------------------


def test_texels_render_where_the_uv_convention_puts_them():
    """A base colour whose red grows with column j and green with row i, on the bundled plane.

    The plane is lit by a uniform white sky and seen obliquely by a rolled camera. At the pixel
    where each texel centre projects, the rendered red must grow with j and green with i, and
    follow the texture linearly; a flipped v or swapped axes reverse or scramble the order.
    """
    plane = load_mesh(mesh_path("plane"))
    resolution = 4
    rows, columns = np.meshgrid(np.arange(resolution), np.arange(resolution), indexing="ij")
    base_color = np.stack(
        [0.1 + 0.8 * columns / (resolution - 1), 0.1 + 0.8 * rows / (resolution - 1),
         np.full(rows.shape, 0.5)], axis=-1,
    ).astype(np.float32)  # (T, T, 3)
    materials = MaterialMaps(
        base_color,
        np.ones((resolution, resolution), np.float32),
        np.zeros((resolution, resolution), np.float32),
    )
    scene = render.build_scene(plane, render.principled_bsdf(materials), uniform_envmap())
    pose = look_at([0.4, 1.6, 0.7], [0.0, 0.0, 0.0], up=[1.0, 0.0, -0.3])
    camera = Camera.from_fov(np.radians(45.0), 48, 48, pose)
    view = render.render_view(scene, camera, spp=32, seed=0)

    # Texel centres on the surface: the plane's uv -> position map is affine; fit it.
    uv_h = np.column_stack([plane.uv, np.ones(len(plane.uv))])
    uv_to_position, *_ = np.linalg.lstsq(uv_h, plane.vertices, rcond=None)  # (3, 3)
    texel_uv = np.stack(
        [(columns + 0.5) / resolution, 1.0 - (rows + 0.5) / resolution], axis=-1
    ).reshape(-1, 2)
    points = np.column_stack([texel_uv, np.ones(len(texel_uv))]) @ uv_to_position
    pixels, depth = camera.project(points)
    assert (depth > 0).all()
    index = np.floor(pixels).astype(int)
    assert (index >= 0).all() and (index < 48).all()
    assert view.coverage[index[:, 1], index[:, 0]].min() == 1.0
    seen = view.radiance[index[:, 1], index[:, 0]].reshape(resolution, resolution, 3)

    assert (np.diff(seen[..., 0], axis=1) > 0).all()  # red grows along each row (with j)
    assert (np.diff(seen[..., 1], axis=0) > 0).all()  # green grows down each column (with i)
    # Blue is 0.5 everywhere: dividing by it removes the shading, which varies across the plane.
    for channel in (0, 1):
        ratio = seen[..., channel] / seen[..., 2]
        assert np.corrcoef(ratio.ravel(), base_color[..., channel].ravel())[0, 1] > 0.99


# --- rendering helpers ---------------------------------------------------------------------------


def test_render_is_deterministic_per_seed_and_views_get_distinct_noise():
    plane = load_mesh(mesh_path("plane"))
    materials = MaterialMaps(
        np.full((4, 4, 3), 0.5, np.float32), np.full((4, 4), 0.5, np.float32),
        np.zeros((4, 4), np.float32),
    )
    envmap = load_envmap(envmap_path("forest"), np.eye(4))
    scene = render.build_scene(plane, render.principled_bsdf(materials), envmap)
    camera = Camera.from_fov(np.radians(40.0), 16, 16, look_at([0.0, 0.8, 0.1], [0.0, 0.0, 0.0]))
    first, second = render.render_views(scene, [camera, camera], spp=4, seed=3)
    again = render.render_view(scene, camera, spp=4, seed=render.view_seed(3, 0))
    np.testing.assert_array_equal(first.radiance, again.radiance)
    assert not np.array_equal(first.radiance, second.radiance)  # same camera, other seed
    np.testing.assert_array_equal(first.coverage, second.coverage)  # the plane fills the frame
    assert first.coverage.min() == 1.0


def test_perspective_sensor_rejects_non_square_pixels():
    camera = Camera(np.eye(4), fx=50.0, fy=60.0, cx=8.0, cy=8.0, width=16, height=16)
    with pytest.raises(ValueError, match="square pixels"):
        render.perspective_sensor(camera, spp=1)
