"""Pinhole camera: projection against hand-computed values, NeRF field of view, rays, look_at."""

import numpy as np
import pytest

from freqbrdf.capture.camera import Camera, check_rigid, focal_length, look_at
from freqbrdf.errors import InputError

# A quarter turn about +y: the camera's x axis is world -z, its z axis world +x, so it looks
# down world -x.
QUARTER_TURN_Y = np.array([[0.0, 0, 1, 0], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]])


def test_project_matches_hand_computed_pinhole():
    camera = Camera(np.eye(4), fx=100.0, fy=80.0, cx=32.0, cy=24.0, width=64, height=48)
    pixels, depth = camera.project(np.array([[1.0, 2.0, -10.0]]))
    # x = cx + fx * 1 / 10, y = cy - fy * 2 / 10 (image y runs down, camera y up)
    np.testing.assert_allclose(pixels, [[42.0, 8.0]])
    np.testing.assert_allclose(depth, [10.0])

    pose = QUARTER_TURN_Y.copy()
    pose[:3, 3] = [5.0, 0.0, 0.0]
    moved = Camera(pose, fx=100.0, fy=80.0, cx=32.0, cy=24.0, width=64, height=48)
    # (0, 1, -2) is (-5, 1, -2) from the centre: camera x = 2, y = 1, depth 5.
    pixels, depth = moved.project(np.array([[0.0, 1.0, -2.0]]))
    np.testing.assert_allclose(pixels, [[72.0, 8.0]])
    np.testing.assert_allclose(depth, [5.0])
    np.testing.assert_array_equal(moved.center, [5.0, 0.0, 0.0])


def test_points_behind_the_camera_have_no_pixel():
    camera = Camera(np.eye(4), 10.0, 10.0, 4.0, 4.0, 8, 8)
    pixels, depth = camera.project(np.array([[0.0, 0.0, 3.0], [0.0, 0.0, -3.0]]))
    assert depth[0] == -3.0 and np.isnan(pixels[0]).all()
    np.testing.assert_allclose(pixels[1], [4.0, 4.0])


def test_from_fov_puts_the_field_of_view_on_the_image_edges():
    fov_x, fov_y = 0.7, 0.5
    camera = Camera.from_fov(fov_x, 64, 32, np.eye(4), camera_angle_y=fov_y)
    assert (camera.cx, camera.cy) == (32.0, 16.0)
    # Directions at half the field of view land on the left / right and top edges.
    edges = np.array(
        [[np.tan(fov_x / 2), 0, -1], [-np.tan(fov_x / 2), 0, -1], [0, np.tan(fov_y / 2), -1]]
    )
    pixels, _ = camera.project(edges)
    np.testing.assert_allclose(pixels, [[64.0, 16.0], [0.0, 16.0], [32.0, 0.0]], atol=1e-12)
    square = Camera.from_fov(fov_x, 64, 32, np.eye(4))
    assert square.fy == square.fx == focal_length(fov_x, 64)


def test_ray_directions_pass_through_pixel_centres():
    pose = look_at([1.0, 2.0, 3.0], [0.1, -0.2, 0.3], up=[0.0, 1.0, 0.0])
    camera = Camera(pose, fx=9.0, fy=11.0, cx=3.7, cy=2.2, width=6, height=5)
    directions = camera.ray_directions()  # (5, 6, 3)
    assert directions.shape == (5, 6, 3)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=-1), 1.0, atol=1e-12)
    points = camera.center + 2.5 * directions.reshape(-1, 3)
    pixels, depth = camera.project(points)
    rows, columns = np.mgrid[0:5, 0:6]
    centres = np.stack([columns.ravel() + 0.5, rows.ravel() + 0.5], axis=1)
    np.testing.assert_allclose(pixels, centres, atol=1e-9)
    assert (depth > 0).all()


def test_look_at_centres_the_target_with_up_pointing_up():
    eye, target = np.array([3.0, 1.0, -2.0]), np.array([0.5, 0.2, 0.1])
    up = np.array([0.0, 0.0, 1.0])
    pose = look_at(eye, target, up)
    rotation = pose[:3, :3]
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    camera = Camera(pose, 50.0, 50.0, 16.0, 16.0, 32, 32)
    np.testing.assert_allclose(camera.center, eye)
    forward = (target - eye) / np.linalg.norm(target - eye)
    true_up = up - forward * (up @ forward)
    right = np.cross(forward, up)
    pixels, depth = camera.project(np.stack([target, target + 0.1 * true_up, target + 0.1 * right]))
    assert depth[0] == pytest.approx(np.linalg.norm(target - eye))
    np.testing.assert_allclose(pixels[0], [16.0, 16.0], atol=1e-9)
    assert pixels[1, 1] < 16.0 and pixels[1, 0] == pytest.approx(16.0)  # up is up in the image
    assert pixels[2, 0] > 16.0 and pixels[2, 1] == pytest.approx(16.0)  # right is right
    # The default camera of OpenGL: at +z looking at the origin is the identity rotation.
    np.testing.assert_allclose(look_at([0, 0, 5], [0, 0, 0])[:3, :3], np.eye(3), atol=1e-15)
    with pytest.raises(ValueError, match="parallel"):
        look_at([0, 0, 0], [0, 2, 0], up=[0, 1, 0])


@pytest.mark.parametrize(
    "matrix, problem",
    [
        (np.zeros((4, 4)) + np.diag([0, 0, 0, 1.0]), "singular"),
        (np.diag([1.0, 1.2, 1.0, 1.0]), "not rigid"),
        (np.diag([-1.0, 1.0, 1.0, 1.0]), "reflection"),
        (np.eye(3), "4x4"),
        ([[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "4x4 array of numbers"),
        (np.full((4, 4), np.nan), "non-finite"),
    ],
)
def test_bad_camera_matrices_name_the_file_and_frame(matrix, problem):
    with pytest.raises(InputError, match=problem) as caught:
        check_rigid(matrix, "scene/transforms.json", "frame 3: transform_matrix")
    assert str(caught.value).startswith("scene/transforms.json: frame 3: transform_matrix")


def test_camera_refuses_a_non_rigid_pose():
    with pytest.raises(ValueError, match="not rigid"):
        Camera(np.diag([2.0, 2.0, 2.0, 1.0]), 10.0, 10.0, 4.0, 4.0, 8, 8)


def test_rigid_matrix_with_text_precision_is_snapped_to_a_rotation():
    pose = look_at([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(check_rigid(pose, "t.json", "frame 0"), pose)  # exact: as is
    rounded = np.round(pose, 5)  # as written with five decimals in a JSON file
    snapped = check_rigid(rounded.tolist(), "t.json", "frame 0")
    np.testing.assert_allclose(snapped[:3, :3].T @ snapped[:3, :3], np.eye(3), atol=1e-14)
    np.testing.assert_allclose(snapped, pose, atol=1e-5)
    np.testing.assert_array_equal(snapped[:3, 3], rounded[:3, 3])
