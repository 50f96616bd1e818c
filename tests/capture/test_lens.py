"""Lens distortion: photographs through OpenCV's lens models are read as pinhole photographs."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import ndimage

from freqbrdf.capture.camera import Camera, frame_lens, look_at
from freqbrdf.capture.layouts import load, read_frame_image, read_frame_mask_coverage
from freqbrdf.capture.lens import LensDistortion, distort, undistort, undistort_image, unfolded
from freqbrdf.config import Config, TexelConfig
from freqbrdf.errors import InputError
from freqbrdf.images import read_mask_coverage, write_exr, write_png
from freqbrdf.observe.observations import observe

BARREL = LensDistortion("opencv", (-0.5, 0.1, 0.0, 0.0), (0.01, -0.005))


def camera(size=24, focal=33.0):
    return Camera(look_at([0.0, 0.0, 3.0], [0.0, 0.0, 0.0]), focal, focal, size / 2, size / 2, size, size)


def through_lens(pinhole: np.ndarray, cam: Camera, lens: LensDistortion) -> np.ndarray:
    """The photograph a lens takes of a scene whose pinhole photograph is ``pinhole`` (H, W[, C])."""
    rows, columns = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    x, y = undistort((columns + 0.5 - cam.cx) / cam.fx, (rows + 0.5 - cam.cy) / cam.fy, lens)
    coordinates = np.stack([y * cam.fy + cam.cy - 0.5, x * cam.fx + cam.cx - 0.5])
    planes = pinhole[..., None] if pinhole.ndim == 2 else pinhole
    out = np.stack([ndimage.map_coordinates(planes[..., c].astype(np.float64), coordinates, order=1, mode="nearest")
                    for c in range(planes.shape[2])], axis=-1).astype(np.float32)
    return out[..., 0] if pinhole.ndim == 2 else out


def test_without_coefficients_the_opencv_model_is_the_pinhole_and_the_fisheye_the_equidistant_one():
    x, y = np.meshgrid(np.linspace(-0.6, 0.6, 7), np.linspace(-0.4, 0.4, 5))
    np.testing.assert_array_equal(distort(x, y, LensDistortion("opencv", (0.0,) * 4)), (x, y))
    x_d, y_d = distort(x, y, LensDistortion("fisheye", (0.0,) * 4))
    np.testing.assert_allclose(np.hypot(x_d, y_d), np.arctan(np.hypot(x, y)), atol=1e-12)
    np.testing.assert_allclose(np.arctan2(y_d, x_d)[np.hypot(x, y) > 0], np.arctan2(y, x)[np.hypot(x, y) > 0])


@pytest.mark.parametrize("lens", [BARREL, LensDistortion("opencv", (0.2, 0.0, 0.0, 0.0), (-0.01, 0.01)),
                                  LensDistortion("fisheye", (0.05, -0.01, 0.0, 0.0))])
def test_a_photograph_through_a_lens_is_read_back_as_its_pinhole_photograph(lens):
    """A smooth scene photographed through the lens and undistorted is the pinhole photograph again
    (inside the image: the lens's view of the corners may be outside the photograph)."""
    cam = camera(64, 60.0)
    rows, columns = np.mgrid[0:64, 0:64] + 0.5
    pinhole = np.stack([np.sin(columns / 7.0) + 2.0, np.cos(rows / 5.0) + 2.0, np.sin((rows + columns) / 9.0) + 2.0],
                       axis=-1).astype(np.float32)
    photograph = through_lens(pinhole, cam, lens)
    assert np.abs(photograph - pinhole).max() > 0.3  # the lens moves the picture
    back = undistort_image(photograph, cam, lens)
    inside = (slice(8, 56), slice(8, 56))
    assert np.abs(back[inside] - pinhole[inside]).max() < 0.02


def test_the_observations_and_the_pinhole_resampling_read_the_same_place_of_the_photograph():
    """`distort_pixels` (the observations' projection) and `undistort_image` (the other readers) agree."""
    from freqbrdf.capture.lens import _sample_coordinates, distort_pixels

    cam = camera(32, 30.0)
    rows, columns = np.mgrid[0:32, 0:32] + 0.5
    x, y = distort_pixels(columns, rows, cam, BARREL)
    coordinates = _sample_coordinates(32, 32, cam.fx, cam.fy, cam.cx, cam.cy, BARREL)
    np.testing.assert_allclose(coordinates[0], y - 0.5, atol=1e-12)
    np.testing.assert_allclose(coordinates[1], x - 0.5, atol=1e-12)


def test_undistort_inverts_distort():
    x, y = np.meshgrid(np.linspace(-0.5, 0.5, 9), np.linspace(-0.4, 0.4, 7))
    for lens in (BARREL, LensDistortion("fisheye", (0.05, -0.01, 0.0, 0.0))):
        np.testing.assert_allclose(undistort(*distort(x, y, lens), lens), (x, y), atol=1e-10)


def test_a_lens_that_folds_the_image_is_told():
    cam = camera()
    assert unfolded(BARREL, cam)
    assert not unfolded(LensDistortion("opencv", (-40.0, 0.0, 0.0, 0.0)), cam)
    assert not unfolded(LensDistortion("opencv", (0.0, -2000.0, 0.0, 0.0)), cam)


def test_frame_lens_reads_the_models_of_a_transforms_file(tmp_path):
    cam = camera()
    source = tmp_path / "transforms.json"
    assert frame_lens(source, 0, {}, {"camera_model": "OPENCV", "k1": 0.0}, cam) is None
    assert frame_lens(source, 0, {"k1": -0.5, "k2": 0.1, "p1": 0.01, "p2": -0.005}, {}, cam) == BARREL
    assert frame_lens(source, 0, {}, {"camera_model": "OPENCV_FISHEYE"}, cam) == LensDistortion("fisheye", (0.0,) * 4)
    assert frame_lens(source, 0, {"k1": 0.05}, {"is_fisheye": True}, cam).model == "fisheye"  # instant-ngp's flag
    assert frame_lens(source, 0, {"k1": 0.05}, {"camera_model": "SIMPLE_RADIAL"}, cam) == LensDistortion(
        "opencv", (0.05, 0.0, 0.0, 0.0))  # COLMAP's radial models are OpenCV's radial part
    with pytest.raises(InputError, match="'k3' must be a finite number"):
        frame_lens(source, 2, {"k3": float("nan")}, {}, cam)


PINCUSHION = LensDistortion("opencv", (1.0, 0.0, 0.0, 0.0), (0.01, -0.005))
FISHEYE = LensDistortion("fisheye", (-0.3, 0.0, 0.0, 0.0))
LENS_KEYS = {PINCUSHION: {"camera_model": "OPENCV", "k1": 1.0, "p1": 0.01, "p2": -0.005},
             FISHEYE: {"camera_model": "OPENCV_FISHEYE", "k1": -0.3}}


@pytest.mark.parametrize("lens", [PINCUSHION, FISHEYE], ids=["pincushion", "fisheye"])
def test_a_capture_through_a_lens_is_observed_as_the_pinhole_capture(tmp_path, lens):
    """The example capture (its photographs made smooth, so that resampling them twice loses nothing)
    through a pincushion lens: with the lens in transforms.json the texels' samples and the masks are
    the pinhole capture's, without it they are not; the pixels the lens did not see are not object."""
    from freqbrdf.synthetic import example_capture

    pinhole_root = example_capture(tmp_path / "pinhole", resolution=48)
    document = json.loads((pinhole_root / "transforms.json").read_text())
    lens_root = tmp_path / "lens"
    (lens_root / "images").mkdir(parents=True)
    (lens_root / "masks").mkdir()
    for name in ("mesh.obj", "envmap.exr"):
        (lens_root / name).write_bytes((pinhole_root / name).read_bytes())
    cam = load(pinhole_root).frames[0].camera
    rows, columns = np.mgrid[0:cam.height, 0:cam.width] + 0.5
    masks = {}
    for index, frame in enumerate(document["frames"]):
        smooth = np.stack([2.0 + np.sin(columns / 6.0 + index), 2.0 + np.cos(rows / 5.0), 2.0 + np.sin((rows - columns) / 8.0)],
                          axis=-1).astype(np.float32)
        write_exr(pinhole_root / frame["file_path"], smooth)
        write_exr(lens_root / frame["file_path"], through_lens(smooth, cam, lens))
        masks[index] = read_mask_coverage(pinhole_root / frame["mask_path"]) > 0.5
        coverage = through_lens(masks[index].astype(np.float32), cam, lens)
        write_png(lens_root / frame["mask_path"], np.repeat((coverage > 0.5)[..., None], 3, axis=2).astype(np.float32))
    undeclared = dict(document)
    (lens_root / "transforms.json").write_text(json.dumps(undeclared))
    config = Config(texels=TexelConfig(texture_res=16))
    ignored = observe(load(lens_root), config)
    declared_document = {**document, **LENS_KEYS[lens]}
    (lens_root / "transforms.json").write_text(json.dumps(declared_document))
    lens_capture = load(lens_root)
    assert all(frame.lens == lens for frame in lens_capture.frames)
    declared = observe(lens_capture, config)
    truth = observe(load(pinhole_root), config)

    def error(found):
        both = (found.weight > 0) & (truth.weight > 0)
        return float(np.mean(np.abs(found.observed[both] - truth.observed[both])))

    assert error(declared) < 0.25 * error(ignored) and error(declared) < 0.02
    frame = lens_capture.frames[0]
    assert read_frame_image(frame).shape == (cam.height, cam.width, 3)
    mask = read_frame_mask_coverage(frame) > 0.5
    assert np.mean(mask != masks[0]) < 0.25 * np.mean(masks[0] != (read_mask_coverage(frame.mask_path) > 0.5))
    no_mask = read_frame_mask_coverage(type(frame)(frame.camera, frame.image_path, lens=PINCUSHION))  # corners unseen
    assert no_mask.min() < 0.5 < no_mask.max() == pytest.approx(1.0)  # the corners the lens did not see
    # summary.json says which lens the photographs were read through
    from freqbrdf import pipeline

    folder = pipeline.write_fit(tmp_path / "fit", pipeline.fit(lens_capture, config), config)
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["lens"] == {"frames": len(document["frames"]), "distortions": [
        {"model": lens.model, "radial": list(lens.radial), "tangential": list(lens.tangential)}]}
