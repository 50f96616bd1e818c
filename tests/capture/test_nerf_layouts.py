"""NeRF-synthetic and nerfstudio captures, made here from a small Mitsuba capture, load and fit end to
end; Stanford-ORB is recognised only by its own markers."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from freqbrdf import pipeline
from freqbrdf.capture.checks import check_capture
from freqbrdf.capture.layouts import load
from freqbrdf.config import Config, TexelConfig
from freqbrdf.errors import InputError
from freqbrdf.images import linear_to_srgb, read_image, read_mask, write_png
from freqbrdf.synthetic.synth import SynthSettings, synthesize

TINY = SynthSettings(mesh="bunny", views=6, resolution=40, spp=4, texture_res=32, test_views=2, test_envmaps=1)
# nerfstudio's COLMAP processing: (x, y, z) -> (x, z, -y) applied to the poses.
NERFSTUDIO_APPLIED = [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0]]


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory):
    return synthesize(tmp_path_factory.mktemp("capture") / "tiny", TINY, progress=False)


def _fit(capture):
    config = Config(texels=TexelConfig(texture_res=16))
    return pipeline.fit(capture, config)


def _nerf_synthetic(source, folder):
    """NeRF-synthetic's layout: train/ and test/ RGBA PNGs named without extension in the splits,
    the mask in alpha, ``camera_angle_x``, no envmap in the test split."""
    shutil.copytree(source, folder, ignore=shutil.ignore_patterns("images", "masks", "test", "transforms*.json"))
    train = json.loads((source / "transforms.json").read_text())
    test = json.loads((source / "transforms_test.json").read_text())
    for split, document in (("train", train), ("test", test)):
        (folder / split).mkdir()
        width = document.get("w") or train["w"]
        fx = document.get("fl_x") or train["fl_x"]
        frames = []
        for index, frame in enumerate(document["frames"]):
            rgb = np.clip(linear_to_srgb(read_image(source / frame["file_path"])), 0, 1)
            alpha = read_mask(source / frame["mask_path"])[..., None] if "mask_path" in frame else \
                np.ones(rgb.shape[:2] + (1,), bool)
            write_png(folder / split / f"r_{index}.png", np.concatenate([rgb, alpha], axis=2))
            frames.append({"file_path": f"./{split}/r_{index}", "rotation": 0.0,
                           "transform_matrix": frame["transform_matrix"]})
        out = {"camera_angle_x": 2 * float(np.arctan(width / (2 * fx))), "frames": frames}
        if split == "train":
            out.update(mesh=train["mesh"], envmap=train["envmap"], envmap_to_world=train["envmap_to_world"])
        (folder / f"transforms_{split}.json").write_text(json.dumps(out))
    return folder


@pytest.mark.filterwarnings("ignore::freqbrdf.images.CaptureDataWarning")  # its frames are 8-bit, as NeRF's
def test_a_nerf_synthetic_folder_fits_with_alpha_masks_and_its_test_split_under_its_light(tiny_capture, tmp_path):
    folder = _nerf_synthetic(tiny_capture, tmp_path / "lego")
    original = load(tiny_capture)
    for path in (folder, folder / "transforms_train.json"):
        capture = load(path)
        assert capture.layout == "nerf-synthetic" and len(capture.frames) == len(original.frames)
    assert all(frame.mask_from_alpha and frame.mask_path == frame.image_path for frame in capture.frames)
    for index in range(len(capture.frames)):
        np.testing.assert_array_equal(capture.mask(index), original.mask(index))
        np.testing.assert_allclose(capture.frames[index].camera.camera_to_world,
                                   original.frames[index].camera.camera_to_world)
    assert [frame.envmap_path for frame in capture.test_frames] == [capture.envmap_path] * len(capture.test_frames)
    check = check_capture(capture)
    assert check.figures["mask_overlap"] > 0.9
    assert any("8-bit sRGB" in line for line in check.warnings)
    result = _fit(capture)
    assert result.maps.base_color.shape == (16, 16, 3) and np.isfinite(result.maps.base_color).all()
    assert result.observations.n_texels > 0


@pytest.mark.filterwarnings("ignore::freqbrdf.images.CaptureDataWarning")
def test_nerf_synthetic_without_a_mesh_says_what_to_add(tiny_capture, tmp_path):
    folder = _nerf_synthetic(tiny_capture, tmp_path / "lego")
    document = json.loads((folder / "transforms_train.json").read_text())
    del document["mesh"]
    (folder / "transforms_train.json").write_text(json.dumps(document))
    with pytest.raises(InputError, match="missing required key 'mesh'.*add \"mesh\""):
        load(folder)


@pytest.mark.filterwarnings("ignore::freqbrdf.images.CaptureDataWarning")
def test_some_images_with_alpha_and_some_without_are_refused(tiny_capture, tmp_path):
    folder = _nerf_synthetic(tiny_capture, tmp_path / "lego")
    first = folder / "train" / "r_0.png"
    write_png(first, read_image(first))  # RGB only
    with pytest.raises(InputError, match="5 of 6 images have an alpha channel.*frame 0"):
        load(folder)


def _nerfstudio(source, folder, scale, applied=True):
    """The capture with its poses moved as nerfstudio's data processing moves them, the mesh left in
    the reconstruction's frame."""
    shutil.copytree(source, folder)
    document = json.loads((folder / "transforms.json").read_text())
    transform = np.vstack([NERFSTUDIO_APPLIED, [0, 0, 0, 1]])
    for frame in document["frames"]:
        pose = transform @ np.asarray(frame["transform_matrix"])
        pose[:3, 3] *= scale
        frame["transform_matrix"] = pose.tolist()
        frame.update(fl_x=document["fl_x"], fl_y=document["fl_y"])  # per-frame intrinsics
    if applied:
        document.update(applied_transform=NERFSTUDIO_APPLIED, applied_scale=scale)
    (folder / "transforms.json").write_text(json.dumps(document))
    (folder / "transforms_test.json").unlink()
    return folder


def test_a_nerfstudio_capture_has_its_applied_transform_and_scale_undone(tiny_capture, tmp_path):
    capture = load(_nerfstudio(tiny_capture, tmp_path / "ns", scale=0.25))
    original = load(tiny_capture)
    assert capture.layout == "nerfstudio"
    for frame, expected in zip(capture.frames, original.frames):
        np.testing.assert_allclose(frame.camera.camera_to_world, expected.camera.camera_to_world, atol=1e-12)
    assert check_capture(capture).figures["mask_overlap"] > 0.9
    fitted, reference = _fit(capture), _fit(original)
    np.testing.assert_allclose(fitted.maps.roughness, reference.maps.roughness, atol=1e-4)


def test_a_nerfstudio_capture_whose_applied_transform_is_lost_is_refused_with_the_alignment(tiny_capture, tmp_path):
    capture = load(_nerfstudio(tiny_capture, tmp_path / "ns", scale=1.0, applied=False))
    with pytest.raises(InputError, match=r"only \d+% of the mesh's projected points fall inside the masks"):
        check_capture(capture)


@pytest.mark.parametrize("matrix", [[[1, 0, 0], [0, 1, 0]], [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]], "x"])
def test_a_broken_applied_transform_is_one_line(tiny_capture, tmp_path, matrix):
    folder = tmp_path / "ns"
    shutil.copytree(tiny_capture, folder)
    document = json.loads((folder / "transforms.json").read_text())
    document["applied_transform"] = matrix
    (folder / "transforms.json").write_text(json.dumps(document))
    with pytest.raises(InputError, match="applied_transform"):
        load(folder)


@pytest.mark.filterwarnings("ignore::freqbrdf.images.CaptureDataWarning")
def test_a_train_split_is_stanford_orb_only_beside_its_ground_truth(tiny_capture, tmp_path):
    folder = _nerf_synthetic(tiny_capture, tmp_path / "blender_HDR" / "scene")
    assert load(folder).layout == "nerf-synthetic"
    (tmp_path / "ground_truth" / "scene").mkdir(parents=True)
    with pytest.raises(InputError, match="ground_truth"):
        load(folder)  # read as Stanford-ORB now: its test split has no env_map of its own
