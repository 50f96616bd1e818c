"""Tests of freqbrdf.capture.checks: the common mistakes of real captures, caught before any work."""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest

from freqbrdf.capture.checks import check_capture
from freqbrdf.capture.layouts import load
from freqbrdf.errors import InputError
from freqbrdf.images import read_image, write_exr
from freqbrdf.synthetic.synth import SynthSettings, synthesize

TINY = SynthSettings(mesh="bunny", views=6, resolution=32, spp=4, texture_res=32, test_views=0)


@pytest.fixture(scope="module")
def good_capture(tmp_path_factory):
    return synthesize(tmp_path_factory.mktemp("capture") / "good", TINY, progress=False)


@pytest.fixture
def capture_copy(good_capture, tmp_path):
    copy = tmp_path / "capture"
    shutil.copytree(good_capture, copy)
    return copy


def edit_frames(root, change):
    path = root / "transforms.json"
    document = json.loads(path.read_text())
    change(document)
    path.write_text(json.dumps(document))


def scale_mesh(root, factor=1.0, shift=0.0):
    lines = []
    for line in (root / "mesh.obj").read_text().splitlines():
        if line.startswith("v "):
            x, y, z = (float(value) * factor + shift for value in line.split()[1:4])
            line = f"v {x} {y} {z}"
        lines.append(line)
    (root / "mesh.obj").write_text("\n".join(lines) + "\n")


def test_a_good_capture_passes_with_its_figures(good_capture):
    check = check_capture(load(good_capture))
    assert check.warnings == []
    assert check.figures["views"] == 6 and check.figures["behind"] == 0.0
    assert check.figures["mask_overlap"] > 0.8 and check.figures["pixels"] > 10 and check.figures["black_frames"] == 0


def test_opencv_axes_are_named(capture_copy):
    def to_opencv(document):
        for frame in document["frames"]:
            frame["transform_matrix"] = (np.array(frame["transform_matrix"]) @ np.diag([1.0, -1.0, -1.0, 1.0])).tolist()

    edit_frames(capture_copy, to_opencv)
    with pytest.raises(InputError, match=r"transforms.json: the mesh is behind the camera in 100% of the views: the "
                                         r"cameras look along \+Z, OpenCV"):
        check_capture(load(capture_copy))


def test_a_mesh_in_millimetres_is_named(capture_copy):
    scale_mesh(capture_copy, factor=1000.0)
    with pytest.raises(InputError, match="mesh.obj: the mesh is .*x larger than the cameras' distance.*millimetres"):
        check_capture(load(capture_copy))


def test_cameras_far_too_far_are_named(capture_copy):
    def far(document):
        for frame in document["frames"]:
            frame["transform_matrix"] = [row[:3] + [row[3] * 1000.0] if index < 3 else row
                                         for index, row in enumerate(frame["transform_matrix"])]

    edit_frames(capture_copy, far)
    with pytest.raises(InputError, match="spans .* pixels in the closest view"):
        check_capture(load(capture_copy))


def test_a_misaligned_mesh_gives_its_overlap_with_the_masks(capture_copy):
    scale_mesh(capture_copy, shift=0.6)
    with pytest.raises(InputError, match=r"only \d+% of the mesh's projected points fall inside the masks"):
        check_capture(load(capture_copy))


def test_one_view_black_frames_and_a_dark_map(capture_copy):
    frames = json.loads((capture_copy / "transforms.json").read_text())["frames"]
    black = np.zeros_like(read_image(capture_copy / frames[0]["file_path"]))
    write_exr(capture_copy / frames[0]["file_path"], black)
    check = check_capture(load(capture_copy))
    assert check.figures["black_frames"] == 1 and check.warnings == [
        f"1 of 6 frames are black (first: {capture_copy / frames[0]['file_path']})"]
    for frame in frames:
        write_exr(capture_copy / frame["file_path"], black)
    with pytest.raises(InputError, match="every frame is black"):
        check_capture(load(capture_copy))
    edit_frames(capture_copy, lambda document: document.update(frames=document["frames"][:1]))
    with pytest.raises(InputError, match="transforms.json: 1 view: every texel needs samples from at least two"):
        check_capture(load(capture_copy))


def test_an_empty_mask_is_named_and_its_view_left_as_given(capture_copy):
    import imageio.v3 as iio

    from freqbrdf.calibrate import refine_cameras
    from freqbrdf.capture.layouts import read_frame_mask_coverage

    frames = json.loads((capture_copy / "transforms.json").read_text())["frames"]
    mask_path = capture_copy / frames[2]["mask_path"]
    iio.imwrite(mask_path, np.zeros_like(iio.imread(mask_path)))
    capture = load(capture_copy)
    check = check_capture(capture)
    assert check.figures["empty_masks"] == 1
    assert f"1 of 6 masks are empty (first: {mask_path})" in check.warnings[0]
    # The camera refinement leaves that view as given, quietly (no numerical warnings).
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        refined = refine_cameras(capture.mesh, [frame.camera for frame in capture.frames],
                                 [read_frame_mask_coverage(frame) for frame in capture.frames])
    assert refined.cameras[2] is capture.frames[2].camera


def test_an_environment_map_without_light(capture_copy):
    envmap = read_image(capture_copy / "envmap.exr")
    write_exr(capture_copy / "envmap.exr", np.zeros_like(envmap))
    with pytest.raises(InputError, match="envmap.exr: the environment map has no light"):
        check_capture(load(capture_copy))


def test_fit_refuses_a_broken_capture_before_any_work(capture_copy, tmp_path, run_cli, capsys):
    scale_mesh(capture_copy, factor=1000.0)
    assert run_cli("fit", capture_copy, "--out", tmp_path / "fit", "--texture-res", 16) == 2
    error = capsys.readouterr().err.strip()
    assert "millimetres" in error and "\n" not in error
    assert not (tmp_path / "fit").exists()


def test_negative_noise_is_one_warning_and_deep_negatives_are_refused(capture_copy, tmp_path, run_cli, capsys):
    frames = json.loads((capture_copy / "transforms.json").read_text())["frames"]
    for frame in frames[:2]:  # two frames with an HDR merge's noise near black
        image = read_image(capture_copy / frame["file_path"])
        image[0, 0] = -0.002
        write_exr(capture_copy / frame["file_path"], image)
    check = check_capture(load(capture_copy))
    assert len(check.warnings) == 1 and check.warnings[0].startswith(
        "2 of 6 frames had slightly negative pixels (HDR merge noise), clamped to 0")
    # Calibration off: a capture this small (6 views of 40 x 40) has warnings of its own about its gains.
    assert run_cli("fit", capture_copy, "--out", tmp_path / "fit", "--texture-res", 8, "--calibration", "none") == 0
    warnings_printed = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert len(warnings_printed) == 1 and "slightly negative" in warnings_printed[0]
    assert json.loads((tmp_path / "fit" / "summary.json").read_text())["warnings"] == check.warnings
    envmap = read_image(capture_copy / "envmap.exr")
    envmap[0, 0] = -0.5 * envmap.max()
    write_exr(capture_copy / "envmap.exr", envmap)
    with pytest.raises(InputError, match="envmap.exr: 1 negative pixel.* deeper than the noise of an HDR merge"):
        load(capture_copy)


def test_an_environment_map_too_small_for_the_fit(capture_copy, tmp_path, run_cli, capsys):
    write_exr(capture_copy / "envmap.exr", np.ones((8, 16, 3), np.float32))
    assert run_cli("fit", capture_copy, "--out", tmp_path / "fit", "--lmax", 8, "--quiet") == 2
    assert "a 16x8 map resolves degrees up to 6, not 8 (--lmax)" in capsys.readouterr().err
    write_exr(capture_copy / "envmap.exr", np.ones((1, 2, 3), np.float32))
    with pytest.raises(InputError, match="envmap.exr: environment map of 2x1 pixels is too small"):
        load(capture_copy)
    assert not (tmp_path / "fit").exists()


def test_a_repeated_pose_a_frame_exposed_apart_and_ldr_data_are_one_warning_each(capture_copy):
    def repeat_first(document):
        document["frames"][3]["transform_matrix"] = document["frames"][0]["transform_matrix"]

    edit_frames(capture_copy, repeat_first)
    bright = capture_copy / "images" / "0001.exr"
    write_exr(bright, read_image(bright) * 40.0)  # four stops and more above the others
    for name in ("0002.exr", "0004.exr"):  # 8-bit sRGB values written as float
        path = capture_copy / "images" / name
        encoded = np.round(np.clip(read_image(path) ** (1 / 2.2), 0, 1) * 255) / 255
        write_exr(path, encoded.astype(np.float32))
    check = check_capture(load(capture_copy))
    assert check.figures["duplicate_poses"] == 1 and check.figures["ldr_frames"] == 2
    assert check.figures["exposure_range"][1] > 10
    assert len(check.warnings) == 3, check.warnings
    repeated, exposure, ldr = (next(line for line in check.warnings if word in line)
                               for word in ("repeat", "exposed", "LDR"))
    assert "frame 3 = frame 0" in repeated
    assert "1 of 6 frames are exposed unlike the others" in exposure and "0001.exr" in exposure
    assert "2 of 6 HDR frames hold LDR data" in ldr and "0002.exr" in ldr


def test_an_exr_clipped_at_one_is_ldr_data(capture_copy):
    for path in sorted((capture_copy / "images").glob("*.exr")):
        write_exr(path, np.minimum(read_image(path) * 4.0, 1.0))
    check = check_capture(load(capture_copy))
    assert check.figures["ldr_frames"] == 6 and any("clipped at 1.0" in line for line in check.warnings)


def test_an_lmax_far_beyond_the_views_per_point_is_refused_with_the_highest_that_fits(capture_copy, tmp_path, run_cli,
                                                                                      capsys):
    check = check_capture(load(capture_copy), lmax=5)
    most = check.figures["views_per_point"]["most"]
    assert 1 <= most <= 6 and check.figures["views_per_point"]["median"] <= most
    out = tmp_path / "fit"
    assert run_cli("fit", capture_copy, "--out", out, "--lmax", 50, "--quiet") == 2
    error = capsys.readouterr().err.strip()
    assert "--lmax 50 fits (lmax+1)^2 = 2601 SH coefficients per texel" in error and "\n" not in error
    assert f"at most {most} views see any point" in error and not out.exists()
