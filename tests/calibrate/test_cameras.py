"""Camera refinement: poses turned and moved as structure-from-motion leaves them are brought back by the masks.

A bunny (16 views of 128 x 128, its masks anti-aliased as Mitsuba renders them) is rendered once;
copies of its transforms turn every camera 0.6 degrees about a random axis and move it 0.5 % of its
distance. The refinement is judged against the poses the photographs were rendered with.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from freqbrdf.calibrate import calibrate, refine_cameras, rotation_about
from freqbrdf.calibrate.cameras import MeshOutline, signed_distance
from freqbrdf.capture.layouts import load, read_frame_mask_coverage
from freqbrdf.config import CalibrationConfig, Config, TexelConfig
from freqbrdf.synthetic.synth import SynthSettings, synthesize


@pytest.fixture(scope="module")
def bunny(tmp_path_factory) -> Path:
    settings = SynthSettings(mesh="bunny", envmap="lobby", views=16, resolution=128, spp=4, texture_res=32,
                             test_views=0, cameras="sphere")
    return synthesize(tmp_path_factory.mktemp("cameras") / "clean", settings, progress=False)


def _turned_cameras(source: Path, target: Path, degrees: float, shift: float, seed: int = 0) -> Path:
    target.mkdir()
    for name in os.listdir(source):
        if name != "transforms.json":
            os.symlink(source.resolve() / name, target / name)
    transforms = json.loads((source / "transforms.json").read_text())
    rng = np.random.default_rng(seed)
    for frame in transforms["frames"]:
        matrix = np.array(frame["transform_matrix"])
        axis, direction = rng.normal(size=3), rng.normal(size=3)
        matrix[:3, :3] = rotation_about(axis / np.linalg.norm(axis), np.radians(degrees)) @ matrix[:3, :3]
        matrix[:3, 3] += shift * np.linalg.norm(matrix[:3, 3]) * direction / np.linalg.norm(direction)
        frame["transform_matrix"] = matrix.tolist()
    (target / "transforms.json").write_text(json.dumps(transforms))
    return target


def _turn_deg(cameras, truth) -> np.ndarray:
    angles = []
    for camera, frame in zip(cameras, truth.frames):
        relative = camera.camera_to_world[:3, :3] @ frame.camera.camera_to_world[:3, :3].T
        angles.append(np.degrees(np.arccos(np.clip(0.5 * (np.trace(relative) - 1.0), -1.0, 1.0))))
    return np.array(angles)


def test_turned_and_moved_cameras_are_brought_back(bunny, tmp_path):
    truth = load(bunny)
    capture = load(_turned_cameras(bunny, tmp_path / "turned", degrees=0.6, shift=0.005))
    given = [frame.camera for frame in capture.frames]
    found = refine_cameras(capture.mesh, given, [read_frame_mask_coverage(frame) for frame in capture.frames])
    before, after = _turn_deg(given, truth), _turn_deg(found.cameras, truth)
    assert np.allclose(before, 0.6)
    assert found.refined.all()
    assert np.median(after) < 0.15 and after.max() < 0.4, after
    assert np.all(found.outline_after_px < 0.5 * found.outline_before_px)
    assert not found.bad_views.size
    moved = np.array([np.linalg.norm(c.center - f.camera.center) for c, f in zip(found.cameras, truth.frames)])
    assert np.median(moved / np.linalg.norm([f.camera.center for f in truth.frames], axis=1)) < 0.003  # from 0.005


def test_exact_cameras_are_kept(bunny):
    capture = load(bunny)
    found = refine_cameras(capture.mesh, [frame.camera for frame in capture.frames],
                           [read_frame_mask_coverage(frame) for frame in capture.frames])
    assert all(refined is frame.camera for refined, frame in zip(found.cameras, capture.frames))
    assert np.all(found.turn_deg == 0.0) and np.all(found.outline_before_px < 0.3)


@pytest.mark.parametrize("pixels", [2, -2])
def test_a_mask_grown_or_shrunk_moves_no_exact_camera(bunny, tmp_path, pixels):
    """A segmentation's halo (or erosion) puts the mask's edge a constant distance off the outline: the
    offset is estimated with the pose instead of the pose taking it."""
    from scipy import ndimage

    truth = load(bunny)
    grow = (lambda mask: ndimage.binary_dilation(mask, iterations=pixels)) if pixels > 0 else (
        lambda mask: ndimage.binary_erosion(mask, iterations=-pixels))
    masks = [grow(read_frame_mask_coverage(frame) > 0.5).astype(np.float32) for frame in truth.frames]
    exact = refine_cameras(truth.mesh, [frame.camera for frame in truth.frames], masks)
    assert np.median(_turn_deg(exact.cameras, truth)) < 0.05 and _turn_deg(exact.cameras, truth).max() < 0.15
    # The offset is found (a 2-pixel dilation moves the edge 1.5-2 px) and reported.
    assert np.all(np.abs(exact.mask_offset_px - 1.75 * np.sign(pixels)) < 0.5), exact.mask_offset_px
    assert len(exact.to_dict()["mask_offset_px"]) == len(truth.frames)
    from freqbrdf.calibrate import Calibration, _warnings

    said = _warnings(truth, Calibration(np.ones(3), np.zeros(3), cameras=exact), CalibrationConfig())
    assert any(("outside" if pixels > 0 else "inside") + " the mesh's outline" in line for line in said), said
    # Eroded masks lose the grazing views the gains rest on: the gains are not estimated, and it is said.
    assert any("most grazing views are lost" in line for line in said) == (pixels < 0)
    line = Calibration(np.ones(3), np.zeros(3), cameras=exact).summary_line()
    assert f"px {'wider' if pixels > 0 else 'narrower'} than the object" in line, line
    if pixels < 0:
        return  # erosion also cuts thin parts (the ears at 128 x 128): not a constant offset
    turned = load(_turned_cameras(bunny, tmp_path / "turned", degrees=0.6, shift=0.005))
    found = refine_cameras(turned.mesh, [frame.camera for frame in turned.frames], masks)
    after = _turn_deg(found.cameras, truth)  # binary masks, 2 px off, 128 x 128: half the turn is left at most
    assert np.median(after) < 0.3 and after.max() < 0.8, after


def test_calibrate_reports_and_applies_the_cameras(bunny, tmp_path):
    capture = load(_turned_cameras(bunny, tmp_path / "turned", degrees=1.0, shift=0.0, seed=1))
    config = Config(texels=TexelConfig(texture_res=32),
                    calibration=CalibrationConfig(texture_res=32, gains=False, probe_rotation=False))
    corrected, found = calibrate(capture, config)
    assert np.allclose(found.cameras.turn_deg, 1.0, atol=0.3)
    assert all(a.camera is not b.camera for a, b in zip(corrected.frames, capture.frames))
    assert any("cameras were turned" in line for line in found.warnings)
    summary = found.to_dict()["cameras"]
    assert len(summary["turn_deg"]) == 16 and summary["bad_views"] == []
    assert "cameras refined" in found.summary_line()


def test_a_mask_that_is_not_the_object_is_named_and_dropped_when_asked(bunny, tmp_path):
    folder = _turned_cameras(bunny, tmp_path / "wrong", degrees=0.0, shift=0.0)
    transforms = json.loads((folder / "transforms.json").read_text())
    transforms["frames"][2]["mask_path"] = transforms["frames"][9]["mask_path"]  # another view's mask
    (folder / "transforms.json").write_text(json.dumps(transforms))
    config = Config(texels=TexelConfig(texture_res=32),
                    calibration=CalibrationConfig(texture_res=32, gains=False, probe_rotation=False,
                                                  drop_bad_views=True))
    corrected, found = calibrate(load(folder), config)
    assert 2 in found.cameras.bad_views.tolist() and 2 in found.dropped_views
    assert len(corrected.frames) == 16 - len(found.dropped_views)
    assert any("do not fit the mesh's outline" in line for line in found.warnings)


def test_signed_distance_places_an_anti_aliased_edge_within_its_pixel():
    coverage = np.zeros((8, 8))
    coverage[:, :4] = 1.0
    coverage[:, 4] = 0.3  # the edge 0.3 of a pixel into column 4
    distance = signed_distance(coverage)
    np.testing.assert_allclose(distance[:, 3], -0.5)
    np.testing.assert_allclose(distance[:, 4], 0.2)
    np.testing.assert_allclose(distance[:, 6], 2.5)
    assert np.isinf(signed_distance(np.ones((4, 4)))).all()


def test_a_cube_seen_along_an_axis_has_its_outline_on_its_side_faces():
    import trimesh

    from freqbrdf.capture.mesh import Mesh

    cube = trimesh.creation.box()
    mesh = Mesh(np.asarray(cube.vertices, float), np.asarray(cube.faces), np.asarray(cube.vertex_normals, float),
                np.zeros((len(cube.vertices), 2)))
    outline = MeshOutline.of(mesh)
    assert len(outline.edge_start) == 18 and np.all(outline.face_right >= 0)  # closed: 12 faces, 18 edges
    points = outline.contour(np.array([0.3, 0.2, 5.0]))[0]
    assert len(points) > 0 and np.allclose(np.abs(points[:, 2]), 0.5)  # edges of the faces z = +-0.5


def test_a_mask_drawn_wider_than_the_object_is_taken_in_as_it_is_read(bunny):
    from dataclasses import replace

    from freqbrdf.capture.layouts import read_frame_mask

    frame = load(bunny).frames[0]
    as_drawn = read_frame_mask(frame)
    taken_in = read_frame_mask(replace(frame, mask_inset_px=1.7))
    assert taken_in.sum() < as_drawn.sum() and not np.any(taken_in & ~as_drawn)
    # The rim left out is two pixels wide: every pixel kept is more than 2.2 px from the background.
    from scipy import ndimage
    assert np.all(ndimage.distance_transform_edt(as_drawn)[taken_in] > 2.2)
    assert np.array_equal(read_frame_mask(replace(frame, mask_inset_px=0.0)), as_drawn)
