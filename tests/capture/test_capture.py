"""Capture format: round trips through write_transforms, NeRF-style input, the Stanford-ORB
layout and its quirks, and one clear InputError for every kind of bad input."""

import json
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from freqbrdf.capture.camera import Camera, look_at
from freqbrdf.capture.layouts import (
    Frame,
    load,
    release_decoded_frames,
)
from freqbrdf.capture.mesh import Mesh, plane_mesh, save_obj, uv_sphere_mesh
from freqbrdf.capture.stanford_orb import stanford_orb_envmap_to_world
from freqbrdf.capture.transforms_file import write_transforms
from freqbrdf.errors import InputError
from freqbrdf.images import write_exr, write_png
from freqbrdf.model.materials import save_material_maps
from freqbrdf.synthetic.materials import bands_material

SIZE = 8  # fixture images are SIZE x SIZE


def rotation_about(axis, angle):
    """(3, 3) rotation about ``axis`` by ``angle`` radians (Rodrigues)."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def orbit_cameras(count, rng, shared_intrinsics=True):
    cameras = []
    for index in range(count):
        eye = rng.normal(size=3)
        eye *= 3.0 / np.linalg.norm(eye)
        pose = look_at(eye, rng.normal(scale=0.1, size=3))
        if shared_intrinsics:
            cameras.append(Camera.from_fov(0.6, SIZE, SIZE, pose))
        else:  # irrational-looking values that only survive an exact round trip
            cameras.append(Camera(pose, *(rng.uniform(5, 15, size=4)), SIZE + index, SIZE))
    return cameras


def write_images(root, cameras, rng, folder="images"):
    """Radiance EXRs and PNG masks for ``cameras``; returns (image paths, mask paths, images)."""
    image_paths, mask_paths, images = [], [], []
    for index, camera in enumerate(cameras):
        image = rng.uniform(0.0, 4.0, size=(camera.height, camera.width, 3)).astype(np.float32)
        mask = np.zeros((camera.height, camera.width))
        mask[2:-2, 2:-2] = 1.0
        image_paths.append(root / folder / f"{index:03d}.exr")
        mask_paths.append(root / "masks" / f"{index:03d}.png")
        write_exr(image_paths[-1], image)
        write_png(mask_paths[-1], mask)
        images.append(image)
    return image_paths, mask_paths, images


def write_capture(root, n_frames=3, shared_intrinsics=True, seed=0):
    """A complete capture of ours; returns the frames written and their images."""
    rng = np.random.default_rng(seed)
    save_obj(root / "mesh.obj", plane_mesh())
    write_exr(root / "envmap.exr", np.full((8, 16, 3), 0.5, np.float32))
    cameras = orbit_cameras(n_frames, rng, shared_intrinsics)
    image_paths, mask_paths, images = write_images(root, cameras, rng)
    frames = [Frame(*args) for args in zip(cameras, image_paths, mask_paths)]
    envmap_to_world = np.eye(4)
    envmap_to_world[:3, :3] = rotation_about([1.0, 2.0, 0.5], 0.4)
    write_transforms(
        root / "transforms.json",
        frames,
        mesh=root / "mesh.obj",
        envmap=root / "envmap.exr",
        envmap_to_world=envmap_to_world,
        envmap_scale=2.0,
    )
    return frames, images, envmap_to_world


def edit_json(path, change):
    document = json.loads(path.read_text())
    change(document)
    path.write_text(json.dumps(document, indent=2))


def assert_same_camera(loaded: Camera, written: Camera):
    np.testing.assert_array_equal(loaded.camera_to_world, written.camera_to_world)
    for name in ("fx", "fy", "cx", "cy", "width", "height"):
        assert getattr(loaded, name) == getattr(written, name), name


# --- our format ----------------------------------------------------------------------------------


@pytest.mark.parametrize("shared_intrinsics", [True, False])
def test_write_then_load_gives_identical_cameras(tmp_path, shared_intrinsics):
    frames, images, envmap_to_world = write_capture(tmp_path, shared_intrinsics=shared_intrinsics)
    document = json.loads((tmp_path / "transforms.json").read_text())
    assert ("fl_x" in document) == shared_intrinsics  # shared intrinsics are written once

    capture = load(tmp_path / "transforms.json")
    assert capture.layout == "freqbrdf" and len(capture.frames) == 3
    for loaded, written in zip(capture.frames, frames):
        assert_same_camera(loaded.camera, written.camera)
        assert loaded.image_path.resolve() == written.image_path.resolve()
        assert loaded.mask_path.resolve() == written.mask_path.resolve()
    np.testing.assert_array_equal(capture.image(1), images[1])
    mask = capture.mask(2)
    assert mask.dtype == bool and mask[4, 4] and not mask[0, 0]
    np.testing.assert_array_equal(capture.envmap.to_world, envmap_to_world)
    np.testing.assert_allclose(capture.envmap.radiance, 1.0)  # 0.5 times envmap_scale 2
    assert len(capture.mesh.faces) == 2
    assert capture.test_frames == () and capture.ground_truth is None


def test_test_set_gives_each_view_its_own_envmap(tmp_path):
    write_capture(tmp_path)
    rng = np.random.default_rng(1)
    cameras = orbit_cameras(2, rng)
    image_paths, _, images = write_images(tmp_path, cameras, rng, folder="test")
    lights = []
    for index in range(2):
        lights.append(tmp_path / f"light{index}.exr")
        write_exr(lights[-1], np.full((4, 8, 3), index + 1.0, np.float32))
    to_world = np.eye(4)
    to_world[:3, :3] = rotation_about([0.0, 1.0, 0.0], 1.0)
    frames = [
        Frame(cameras[0], image_paths[0], envmap_path=lights[0], envmap_to_world=to_world),
        Frame(cameras[1], image_paths[1], envmap_path=lights[1], envmap_scale=3.0),
    ]
    write_transforms(tmp_path / "transforms_test.json", frames)

    capture = load(tmp_path)
    assert len(capture.test_frames) == 2
    for loaded, written in zip(capture.test_frames, frames):
        assert_same_camera(loaded.camera, written.camera)
    np.testing.assert_array_equal(capture.test_image(1), images[1])
    assert capture.test_mask(0).all()  # no mask: every pixel may show the object
    first, second = capture.test_envmap(0), capture.test_envmap(1)
    np.testing.assert_array_equal(first.to_world, to_world)
    np.testing.assert_allclose(first.radiance, 1.0)
    np.testing.assert_array_equal(second.to_world, np.eye(4))
    np.testing.assert_allclose(second.radiance, 6.0)  # 2 times its envmap_scale 3


def test_nerf_style_transforms_with_field_of_view_and_bare_file_paths(tmp_path):
    save_obj(tmp_path / "mesh.obj", plane_mesh())
    write_exr(tmp_path / "sky.exr", np.ones((8, 16, 3), np.float32))
    exr = np.full((6, SIZE, 3), 0.25, np.float32)
    write_exr(tmp_path / "train" / "r_0.exr", exr)
    write_png(tmp_path / "train" / "r_0.png", np.zeros((6, SIZE, 3)))  # .exr comes first
    save_material_maps(tmp_path / "gt", bands_material(16))
    pose = look_at([0.0, 1.0, 3.0], [0.0, 0.0, 0.0])
    document = {
        "camera_angle_x": 0.8,
        "mesh": "mesh.obj",
        "envmap": "sky.exr",
        "frames": [{"file_path": "./train/r_0", "transform_matrix": pose.tolist()}],
    }
    (tmp_path / "transforms.json").write_text(json.dumps(document))

    capture = load(tmp_path)
    frame = capture.frames[0]
    assert frame.image_path.name == "r_0.exr" and frame.mask_path is None
    assert_same_camera(frame.camera, Camera.from_fov(0.8, SIZE, 6, pose))  # size from the image
    np.testing.assert_array_equal(capture.image(0), exr)
    np.testing.assert_array_equal(capture.envmap.to_world, np.eye(4))  # default
    assert capture.ground_truth.resolution == 16
    # Written on Windows: backslash separators read as folders.
    document["frames"][0]["file_path"] = "train\\r_0.exr"
    (tmp_path / "transforms.json").write_text(json.dumps(document))
    assert load(tmp_path).frames[0].image_path == tmp_path / "train" / "r_0.exr"


def test_mesh_without_uvs_caches_its_atlas_outside_the_capture(tmp_path, monkeypatch):
    capture = tmp_path / "capture"
    write_capture(capture)
    sphere = uv_sphere_mesh(8, 4)
    lines = [f"v {x} {y} {z}" for x, y, z in sphere.vertices]
    lines += [f"f {a} {b} {c}" for a, b, c in sphere.faces + 1]
    (capture / "mesh.obj").write_text("\n".join(lines) + "\n")
    monkeypatch.setenv("FREQBRDF_CACHE", str(tmp_path / "cache"))
    before = sorted(path.name for path in capture.iterdir())

    first = load(capture).mesh
    (cache,) = (tmp_path / "cache" / "atlas").glob("mesh-*.obj")
    assert sorted(path.name for path in capture.iterdir()) == before  # the capture folder is never written
    written = cache.stat().st_mtime_ns
    second = load(capture).mesh
    assert cache.stat().st_mtime_ns == written  # reused, not rebuilt
    np.testing.assert_array_equal(first.uv, second.uv)
    assert first.uv.min() >= 0 and first.uv.max() <= 1


# --- bad input: one InputError naming the file and the problem ---------------------------------


def load_error(path) -> str:
    with pytest.raises(InputError) as caught:
        load(path)
    return str(caught.value)


def identity_with(row, column, value):
    matrix = np.eye(4)
    matrix[row, column] = value
    return matrix.tolist()


@pytest.mark.parametrize(
    "change, problem",
    [
        (lambda d: d.pop("frames"), "missing required key 'frames'"),
        (lambda d: d.pop("mesh"), "missing required key 'mesh'"),
        (lambda d: d["frames"][1].pop("transform_matrix"),
         "frame 1: missing required key 'transform_matrix'"),
        (lambda d: d.pop("fl_x"), "frame 0: missing required key 'camera_angle_x'"),
        (lambda d: d["frames"][1].update(transform_matrix=np.diag([1.0, 0, 1, 1]).tolist()),
         "frame 1: transform_matrix is singular"),
        (lambda d: d["frames"][2].update(transform_matrix=identity_with(0, 1, 0.3)),
         "frame 2: transform_matrix is not rigid"),
        (lambda d: d["frames"][2].pop("mask_path"), "mask_path given for 2 of 3 frames"),
        (lambda d: d.update(envmap_to_world=np.diag([2.0, 2, 2, 1]).tolist()),
         "envmap_to_world is not rigid"),
        (lambda d: d.update(envmap_scale=-1), "'envmap_scale' must be a positive number"),
        (lambda d: d.update(k1=-40.0), "frame 0: the lens distortion (k1 = -40) folds the image"),
        (lambda d: d.update(k2="0.1"), "frame 0: 'k2' must be a finite number"),
        (lambda d: d.update(camera_model="OPENCV_FISHEYE", p1=0.01), "frame 0: a fisheye lens (OPENCV_FISHEYE) has no"),
        (lambda d: d.update(camera_model="EQUIRECTANGULAR"), "frame 0: camera_model 'EQUIRECTANGULAR' is not supp"),
    ],
)
def test_bad_transforms_content(tmp_path, change, problem):
    write_capture(tmp_path)
    edit_json(tmp_path / "transforms.json", change)
    message = load_error(tmp_path)
    assert message.startswith(str(tmp_path / "transforms.json")) and problem in message


def test_missing_or_malformed_transforms(tmp_path):
    assert "capture does not exist" in load_error(tmp_path / "nowhere")
    assert load_error(tmp_path) == f"{tmp_path / 'transforms.json'}: file does not exist"
    (tmp_path / "transforms.json").write_text('{\n  "frames": [],\n  "mesh": "m"\n  "envmap": 1\n}')
    message = load_error(tmp_path)
    assert message.startswith(str(tmp_path / "transforms.json"))
    assert "malformed JSON at line 4, column 3" in message


def test_missing_files_are_named(tmp_path):
    write_capture(tmp_path)
    (tmp_path / "images" / "002.exr").unlink()
    message = load_error(tmp_path)
    assert message.startswith(str(tmp_path / "images" / "002.exr"))
    assert "image of frame 2 in transforms.json does not exist" in message

    write_capture(tmp_path)
    (tmp_path / "mesh.obj").unlink()
    assert load_error(tmp_path) == f"{tmp_path / 'mesh.obj'}: file does not exist"

    write_capture(tmp_path)
    (tmp_path / "envmap.exr").unlink()
    message = load_error(tmp_path)
    assert message.startswith(str(tmp_path / "envmap.exr")) and "not exist" in message

    write_capture(tmp_path)
    (tmp_path / "masks" / "001.png").unlink()
    message = load_error(tmp_path)
    assert message.startswith(str(tmp_path / "masks" / "001.png"))
    assert "mask of frame 1" in message


def test_mesh_without_faces(tmp_path):
    write_capture(tmp_path)
    (tmp_path / "mesh.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    message = load_error(tmp_path)
    assert message.startswith(str(tmp_path / "mesh.obj")) and "no triangles" in message


def test_envmap_must_be_two_to_one(tmp_path):
    write_capture(tmp_path)
    write_exr(tmp_path / "envmap.exr", np.ones((8, 8, 3), np.float32))
    message = load_error(tmp_path)
    assert message.startswith(str(tmp_path / "envmap.exr")) and "2:1" in message


@pytest.mark.parametrize(
    "value, problem", [(np.nan, "1 non-finite pixel(s), first at row 3, column 5"),
                       (-1.0, "1 negative pixel(s) down to -1, first at row 3, column 5: deeper than the noise")]
)
def test_bad_pixels_are_reported_when_the_image_is_read(tmp_path, value, problem):
    frames, images, _ = write_capture(tmp_path)
    images[1][3, 5, 2] = value
    write_exr(frames[1].image_path, images[1])
    capture = load(tmp_path)  # images are read on demand
    with pytest.raises(InputError) as caught:
        capture.image(1)
    assert str(caught.value).startswith(f"{frames[1].image_path}: {problem}")


def test_image_size_must_match_its_camera(tmp_path):
    frames, _, _ = write_capture(tmp_path)
    write_exr(frames[0].image_path, np.ones((SIZE, SIZE + 1, 3), np.float32))
    write_png(frames[2].mask_path, np.ones((SIZE - 1, SIZE)))
    capture = load(tmp_path)
    with pytest.raises(InputError, match=r"is 9x8 pixels but its camera is 8x8") as caught:
        capture.image(0)
    assert caught.value.path == frames[0].image_path
    with pytest.raises(InputError, match=r"is 8x7 pixels but its camera is 8x8") as caught:
        capture.mask(2)
    assert caught.value.path == frames[2].mask_path


# --- Stanford-ORB -----------------------------------------------------------------------------

# Stanford-ORB's environment-map convention, transcribed from its orb/utils/env_map.py: the map
# is stored in the frame of its test camera (OpenGL axes) and its pixel (u, v) in [0, 1]^2 looks
# along theta = -pi/2 + 2 pi u, phi = pi v.
def orb_direction(u, v):
    theta, phi = -0.5 * np.pi + 2 * np.pi * u, np.pi * v
    return np.array([-np.cos(theta) * np.sin(phi), np.cos(phi), -np.sin(theta) * np.sin(phi)])


# Mitsuba 3's envmap: pixel (u, v) looks along its local direction (sin 2 pi u sin pi v, cos pi v,
# -cos 2 pi u sin pi v), moved to the world by to_world.
def mitsuba_direction(u, v, to_world):
    local = np.array(
        [np.sin(2 * np.pi * u) * np.sin(np.pi * v), np.cos(np.pi * v),
         -np.cos(2 * np.pi * u) * np.sin(np.pi * v)]
    )
    return to_world[:3, :3] @ local


def write_orb_scene(data, rng):
    """A miniature Stanford-ORB download: scene_a (3 train views) and one novel view of scene_b.

    Returns (train cameras, light camera, novel camera, true mesh normals).
    """
    scene, other = data / "blender_HDR" / "scene_a", data / "blender_HDR" / "scene_b"
    truth, other_truth = data / "ground_truth" / "scene_a", data / "ground_truth" / "scene_b"
    train = orbit_cameras(3, rng)
    light_camera, novel_camera = orbit_cameras(2, rng)

    def entry(camera, name, **extra):
        return {"file_path": name, "transform_matrix": camera.camera_to_world.tolist(), **extra}

    for index, camera in enumerate(train):
        write_exr(scene / "train" / f"{index:04d}.exr", np.ones((SIZE, SIZE, 3), np.float32))
        write_png(scene / "train_mask" / f"{index:04d}.png", np.ones((SIZE, SIZE)))
    (scene / "transforms_train.json").write_text(json.dumps(
        {"camera_angle_x": 0.6,
         "frames": [entry(camera, f"./train/{i:04d}") for i, camera in enumerate(train)]}
    ))
    (scene / "transforms_test.json").write_text(json.dumps(
        {"frames": [entry(light_camera, "./test/0000", camera_angle_x=0.6)]}
    ))
    (scene / "transforms_novel.json").write_text(json.dumps(
        {"frames": [entry(novel_camera, "./test/0005", camera_angle_x=0.6, scene_name="scene_b")]}
    ))
    write_exr(other / "test" / "0005.exr", np.ones((SIZE, SIZE, 3), np.float32))
    write_png(other / "test_mask" / "0005.png", np.ones((SIZE, SIZE)))
    write_exr(truth / "env_map" / "0000.exr", np.ones((8, 16, 3), np.float32))
    write_exr(other_truth / "env_map" / "0005.exr", np.full((8, 16, 3), 2.0, np.float32))

    # The scanned mesh's normals have y and z exchanged: the file holds (x, -z, y) of the truth.
    sphere = uv_sphere_mesh(8, 6)
    true_normals = sphere.normals
    in_file = true_normals[:, [0, 2, 1]] * [1.0, -1.0, 1.0]
    scanned = Mesh(sphere.vertices, sphere.faces, in_file, sphere.uv)
    save_obj(truth / "mesh_blender" / "mesh.obj", scanned)
    return train, light_camera, novel_camera, true_normals


def test_stanford_orb_layout_loads_with_its_quirks(tmp_path):
    rng = np.random.default_rng(2)
    train, light_camera, novel_camera, true_normals = write_orb_scene(tmp_path, rng)
    scene = tmp_path / "blender_HDR" / "scene_a"

    capture = load(scene)
    assert capture.layout == "stanford-orb" and capture.ground_truth is None
    assert [frame.image_path for frame in capture.frames] == [
        scene / "train" / f"{index:04d}.exr" for index in range(3)
    ]
    assert capture.frames[1].mask_path == scene / "train_mask" / "0001.png"
    for loaded, written in zip(capture.frames, train):
        np.testing.assert_array_equal(loaded.camera.camera_to_world, written.camera_to_world)
        assert loaded.camera.fx == pytest.approx(written.fx, rel=1e-12)
    np.testing.assert_allclose(capture.mesh.normals, true_normals, atol=1e-12)  # swapped back

    # The scene's light is the first test photograph's map, placed by that camera's pose: every
    # pixel looks in the world along (camera rotation) x (its Stanford-ORB camera-space direction).
    assert capture.envmap_path == tmp_path / "ground_truth" / "scene_a" / "env_map" / "0000.exr"
    novel = capture.test_frames[0]
    assert novel.image_path == tmp_path / "blender_HDR" / "scene_b" / "test" / "0005.exr"
    assert novel.mask_path == tmp_path / "blender_HDR" / "scene_b" / "test_mask" / "0005.png"
    assert novel.envmap_path == tmp_path / "ground_truth" / "scene_b" / "env_map" / "0005.exr"
    for to_world, camera in ((capture.envmap.to_world, light_camera),
                             (novel.envmap_to_world, novel_camera)):
        for u, v in [(0.1, 0.3), (0.37, 0.5), (0.8, 0.9), (0.55, 0.05)]:
            np.testing.assert_allclose(
                mitsuba_direction(u, v, to_world),
                camera.camera_to_world[:3, :3] @ orb_direction(u, v),
                atol=1e-12,
            )
    np.testing.assert_allclose(capture.test_envmap(0).radiance, 2.0)

    # The training transforms file is accepted as the path too.
    assert len(load(scene / "transforms_train.json").frames) == 3


def test_stanford_orb_missing_mask_and_ground_truth(tmp_path):
    write_orb_scene(tmp_path, np.random.default_rng(3))
    scene = tmp_path / "blender_HDR" / "scene_a"
    (scene / "train_mask" / "0001.png").unlink()
    message = load_error(scene)
    assert message == (
        f"{scene / 'train_mask'}: has no mask for 1 of 3 frames of transforms_train.json "
        "(first missing: 0001.png)"
    )
    (tmp_path / "ground_truth" / "scene_a" / "mesh_blender" / "mesh.obj").rename(tmp_path / "x.obj")
    write_png(scene / "train_mask" / "0001.png", np.ones((SIZE, SIZE)))
    message = load_error(scene)
    assert message.startswith(str(tmp_path / "ground_truth" / "scene_a" / "mesh_blender"))
    assert "needs exactly one .obj mesh, found 0" in message


def test_stanford_orb_envmap_to_world_is_rigid_and_ignores_translation():
    pose = look_at([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    to_world = stanford_orb_envmap_to_world(pose)
    np.testing.assert_allclose(to_world[:3, :3].T @ to_world[:3, :3], np.eye(3), atol=1e-12)
    assert np.linalg.det(to_world[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_array_equal(to_world[:3, 3], 0.0)


# --- command line ------------------------------------------------------------------------------


def test_info_summarises_a_capture(tmp_path):
    from freqbrdf.cli import app

    frames, _, _ = write_capture(tmp_path)
    for frame in frames:  # masks the plane falls in, so that the capture passes its check
        write_png(frame.mask_path, np.ones((frame.camera.height, frame.camera.width)))
    result = CliRunner().invoke(app, ["info", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "3 views, 3 with masks" in result.output and "8x8" in result.output
    assert "4 vertices, 2 faces" in result.output
    assert "the mesh in front of the cameras in 100% of the views" in result.output


def test_cli_bad_input_is_one_line_and_exit_code_2(tmp_path):
    write_capture(tmp_path)
    edit_json(tmp_path / "transforms.json", lambda d: d["frames"][1].update(
        transform_matrix=np.diag([1.0, 0, 1, 1]).tolist()))
    result = subprocess.run(
        [sys.executable, "-c", "from freqbrdf.cli import main; main()", "info", str(tmp_path)],
        capture_output=True, text=True, timeout=60,
    )
    assert result.returncode == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr
    assert lines[0] == (
        f"error: {tmp_path / 'transforms.json'}: frame 1: transform_matrix is singular "
        "(its 3x3 part has determinant 0)"
    )


def test_a_frame_is_decoded_once_for_every_reader_until_it_changes_or_is_released(tmp_path, monkeypatch):
    """The capture check, calibration and observation read each photograph: one decode, warnings kept."""
    import dataclasses
    import warnings

    from freqbrdf.capture import layouts
    from freqbrdf.images import CaptureDataWarning

    frames, images, _ = write_capture(tmp_path)
    capture = load(tmp_path)
    decoded = []
    real = layouts.read_image
    monkeypatch.setattr(layouts, "read_image", lambda *args, **kwargs: decoded.append(args[0]) or real(*args, **kwargs))
    first, second = capture.image(0), capture.image(0)
    assert first is second and not first.flags.writeable and len(decoded) == 1
    np.testing.assert_array_equal(first, images[0])
    write_exr(frames[0].image_path, images[0] * 2.0)  # changed on disk: decoded again
    np.testing.assert_array_equal(capture.image(0), images[0] * 2.0)
    assert len(decoded) == 2
    release_decoded_frames()
    capture.image(0)
    assert len(decoded) == 3
    # A warning the decode raised is raised again for every later reader.
    png = tmp_path / "frame_8bit.png"
    write_png(png, np.full((SIZE, SIZE, 3), 0.5))
    eight_bit = dataclasses.replace(capture.frames[1], image_path=png)
    for _ in range(2):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            layouts.read_frame_image(eight_bit)
        assert any(issubclass(warning.category, CaptureDataWarning) for warning in caught)
    release_decoded_frames()
