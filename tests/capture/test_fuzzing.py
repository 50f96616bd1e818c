"""Fuzzing of what users hand in: transforms files and image headers. Whatever the bytes, reading
them either works or raises `InputError` (one line naming the file), never anything else."""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from freqbrdf.capture.checks import check_capture
from freqbrdf.capture.layouts import load
from freqbrdf.errors import InputError
from freqbrdf.images import image_has_alpha, read_alpha_mask, read_image, read_mask, write_exr, write_png
from freqbrdf.sphere.envmap import load_envmap
from freqbrdf.synthetic.synth import SynthSettings, synthesize

TINY = SynthSettings(mesh="plane", views=3, resolution=16, spp=1, texture_res=16, test_views=1, test_envmaps=1)
FUZZ = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                        HealthCheck.too_slow])

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12),
    lambda children: st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=20,
)
# The keys a transforms file has, where a wrong value is most likely to slip through.
TOP_KEYS = ["frames", "mesh", "envmap", "envmap_to_world", "envmap_scale", "camera_angle_x", "camera_angle_y",
            "fl_x", "fl_y", "cx", "cy", "w", "h", "camera_model", "k1", "applied_transform", "applied_scale"]
FRAME_KEYS = ["file_path", "mask_path", "transform_matrix", "fl_x", "w", "h", "envmap"]


@pytest.fixture(scope="module")
def small_capture(tmp_path_factory):
    return synthesize(tmp_path_factory.mktemp("capture") / "small", TINY, progress=False)


def _load_and_check(folder: Path) -> None:
    try:
        check_capture(load(folder), lmax=2)
    except InputError as err:
        message = str(err)
        assert message and "\n" not in message and "Traceback" not in message


@FUZZ
@given(changes=st.lists(st.tuples(st.sampled_from(TOP_KEYS), json_values), min_size=1, max_size=3),
       frame_changes=st.lists(st.tuples(st.integers(0, 2), st.sampled_from(FRAME_KEYS), json_values), max_size=3),
       test_file=st.booleans())
def test_a_fuzzed_transforms_file_loads_or_is_one_input_error(small_capture, changes, frame_changes, test_file):
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch) / "capture"
        shutil.copytree(small_capture, folder)
        name = "transforms_test.json" if test_file else "transforms.json"
        document = json.loads((folder / name).read_text())
        for key, value in changes:
            document[key] = value
        for index, key, value in frame_changes:
            frames = document.get("frames")
            if isinstance(frames, list) and index < len(frames) and isinstance(frames[index], dict):
                frames[index][key] = value
        (folder / name).write_text(json.dumps(document))
        _load_and_check(folder)


@FUZZ
@given(text=st.text(max_size=200))
def test_any_text_as_a_transforms_file_loads_or_is_one_input_error(small_capture, text):
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch) / "capture"
        shutil.copytree(small_capture, folder)
        (folder / "transforms.json").write_text(text)
        _load_and_check(folder)


def _image_bytes(suffix: str) -> bytes:
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as scratch:
        path = Path(scratch) / f"image{suffix}"
        pixels = rng.random((6, 8, 3 if suffix == ".exr" else 4)).astype(np.float32)
        (write_exr if suffix == ".exr" else write_png)(path, pixels)
        return path.read_bytes()


@pytest.mark.parametrize("suffix", [".exr", ".png", ".hdr"])
# A damaged 16-bit PNG may still read, as 8 bits: the sRGB warning is what it should say, not a failure.
@pytest.mark.filterwarnings("ignore::freqbrdf.images.SrgbImageWarning")
@FUZZ
@given(data=st.data())
def test_a_damaged_image_header_reads_or_is_one_input_error(suffix, data):
    source = _image_bytes(".exr" if suffix == ".hdr" else suffix) if suffix != ".hdr" else (
        b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 8\n" + bytes(range(128)))
    edits = data.draw(st.lists(st.tuples(st.integers(0, min(len(source), 400) - 1), st.integers(0, 255)),
                               min_size=1, max_size=6))
    cut = data.draw(st.integers(8, len(source)))
    damaged = bytearray(source[:cut])
    for position, value in edits:
        if position < len(damaged):
            damaged[position] = value
    with tempfile.TemporaryDirectory() as scratch:
        path = Path(scratch) / f"frame{suffix}"
        path.write_bytes(bytes(damaged))
        for reader in (lambda p: read_image(p, validate=True), read_mask, image_has_alpha):
            try:
                reader(path)
            except InputError as err:
                assert str(path) in str(err) and "\n" not in str(err)
        try:
            if image_has_alpha(path):
                read_alpha_mask(path)
        except InputError:
            pass
        try:
            envmap = load_envmap(path)
            assert all(math.isfinite(value) for value in envmap.radiance.reshape(-1)[:16])
        except InputError as err:
            assert "\n" not in str(err)
