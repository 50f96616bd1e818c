"""A corpus of the mistakes real users make, each run through the command line: one line on stderr
naming the problem (with a hint where one helps), exit code 2 (1 for a refusal by the system),
nothing written and nothing of the user's removed.

Every case starts from a copy of one small Mitsuba capture and breaks one thing.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from freqbrdf.cli import RERUN_VARIABLE
from freqbrdf.images import read_image, write_exr, write_png
from freqbrdf.synthetic.synth import SynthSettings, synthesize

TINY = SynthSettings(mesh="bunny", views=6, resolution=32, spp=4, texture_res=32, test_views=1, test_envmaps=1)


@pytest.fixture(scope="module")
def good_capture(tmp_path_factory):
    return synthesize(tmp_path_factory.mktemp("capture") / "good", TINY, progress=False)


# --- how a capture is broken ------------------------------------------------------------------


def _transforms(root: Path, change: Callable[[dict], None], name: str = "transforms.json") -> None:
    path = root / name
    document = json.loads(path.read_text())
    change(document)
    path.write_text(json.dumps(document))


def _frame(index: int, key: str, value) -> Callable[[Path], None]:
    def breaking(root):
        _transforms(root, lambda document: document["frames"][index].__setitem__(key, value))
    return breaking


def _top(key: str, value) -> Callable[[Path], None]:
    return lambda root: _transforms(root, lambda document: document.__setitem__(key, value))


def _drop(key: str, frame: int | None = None) -> Callable[[Path], None]:
    def breaking(root):
        _transforms(root, lambda document: (document if frame is None else document["frames"][frame]).pop(key))
    return breaking


def _write(relative: str, content: bytes | str) -> Callable[[Path], None]:
    def breaking(root):
        path = root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return breaking


def _image(relative: str, change: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def breaking(root):
        path = root / relative
        write_exr(path, change(read_image(path)).astype(np.float32))
    return breaking


def _all_images(change: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def breaking(root):
        for path in sorted((root / "images").glob("*.exr")):
            write_exr(path, change(read_image(path)).astype(np.float32))
    return breaking


def _mesh(change: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def breaking(root):
        lines = []
        for line in (root / "mesh.obj").read_text().splitlines():
            if line.startswith("v "):
                vertex = change(np.array([float(value) for value in line.split()[1:4]]))
                line = "v " + " ".join(repr(float(value)) for value in vertex)
            lines.append(line)
        (root / "mesh.obj").write_text("\n".join(lines) + "\n")
    return breaking


def _poses(change: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def breaking(root):
        def each(document):
            for frame in document["frames"]:
                frame["transform_matrix"] = change(np.array(frame["transform_matrix"])).tolist()
        _transforms(root, each)
    return breaking


def _z_up(vertex: np.ndarray) -> np.ndarray:
    x, y, z = vertex
    return np.array([x, -z, y])  # Blender's Z-up export of a Y-up mesh


def _envmap(pixels: np.ndarray) -> Callable[[Path], None]:
    return lambda root: write_exr(root / "envmap.exr", pixels.astype(np.float32))


def _nothing(root: Path) -> None:
    pass


@dataclass(frozen=True)
class Case:
    name: str
    breaking: Callable[[Path], None]
    arguments: tuple  # "{capture}", "{out}", "{tmp}" are filled in
    expected: str  # in the one line
    code: int = 2


FIT = ("fit", "{capture}", "--out", "{out}", "--texture-res", "16")
EYE = np.eye(4).tolist()

CASES = [
    # the capture's folder and transforms file
    Case("capture missing", _nothing, ("fit", "{tmp}/nowhere", "--out", "{out}"), "capture does not exist"),
    Case("folder without transforms", lambda root: (root / "transforms.json").unlink(), FIT, "transforms.json"),
    Case("malformed JSON", _write("transforms.json", "{\"frames\": ["), FIT, "transforms.json"),
    Case("JSON list, not object", _write("transforms.json", "[1, 2]"), FIT, "transforms.json"),
    Case("no frames key", _drop("frames"), FIT, "frames"),
    Case("empty frames", _top("frames", []), FIT, "frames"),
    Case("frame without file_path", _drop("file_path", frame=2), FIT, "file_path"),
    Case("every frame one pose", lambda root: _transforms(
        root, lambda document: document.__setitem__("frames", [document["frames"][0]] * len(document["frames"]))),
        FIT, "share one camera pose"),
    Case("principal point outside the image", _top("cx", 500.0), FIT, "principal point"),
    Case("image file missing", _frame(1, "file_path", "images/none.exr"), FIT, "does not exist"),
    Case("frame without transform_matrix", _drop("transform_matrix", frame=0), FIT, "transform_matrix"),
    Case("3x3 transform_matrix", _frame(0, "transform_matrix", np.eye(3).tolist()), FIT, "transform_matrix"),
    Case("scaled transform_matrix", _frame(0, "transform_matrix", (np.eye(4) * 2).tolist()), FIT, "transform_matrix"),
    Case("text in transform_matrix", _frame(0, "transform_matrix", [["a"] * 4] * 4), FIT, "transform_matrix"),
    Case("NaN in transform_matrix", _frame(0, "transform_matrix", [[float("nan"), 0, 0, 0], *EYE[1:]]), FIT,
         "transform_matrix"),
    Case("no focal length", lambda root: _transforms(root, lambda d: [d.pop(k) for k in ("fl_x", "fl_y")]), FIT,
         "camera_angle_x"),
    Case("negative field of view", lambda root: _transforms(root, lambda d: [d.pop(k) for k in ("fl_x", "fl_y")]
                                                            or d.update(camera_angle_x=-0.5)), FIT, "camera_angle_x"),
    Case("zero focal length", _top("fl_x", 0), FIT, "fl_x"),
    Case("image size unlike w/h", _top("w", 64), FIT, "pixels but its camera is"),
    Case("lens distortion that folds the image", _top("k1", -40.0), FIT, "folds the image"),
    Case("equirectangular camera model", _top("camera_model", "EQUIRECTANGULAR"), FIT, "is not supported"),
    # the mesh
    Case("no mesh key", _drop("mesh"), FIT, "add \"mesh\""),
    Case("mesh file missing", _top("mesh", "gone.obj"), FIT, "gone.obj"),
    Case("mesh of an unsupported type", lambda root: (shutil.copy(root / "mesh.obj", root / "mesh.stl"),
                                                      _top("mesh", "mesh.stl")(root)), FIT, "unsupported mesh type"),
    Case("mesh file of text", _write("mesh.obj", "this is not a mesh\n"), FIT, "mesh.obj"),
    Case("mesh with NaN vertices", _mesh(lambda v: v * np.nan), FIT, "mesh.obj"),
    Case("face indexing a missing vertex", lambda root: (root / "mesh.obj").write_text(
        (root / "mesh.obj").read_text() + "f 1 2 99999\n"), FIT, "mesh.obj"),
    Case("mesh in millimetres", _mesh(lambda v: v * 1000), FIT, "millimetres"),
    Case("mesh moved off the cameras", _mesh(lambda v: v + np.array([0.6, 0.0, 0.0])), FIT, "not aligned"),
    Case("mesh exported Z-up", _mesh(_z_up), FIT, "not aligned"),
    # the environment map
    Case("no envmap key", _drop("envmap"), FIT, "add \"envmap\""),
    Case("envmap file missing", _top("envmap", "sky.exr"), FIT, "sky.exr"),
    Case("envmap 2x1", _envmap(np.ones((1, 2, 3))), FIT, "envmap.exr"),
    Case("envmap not 2:1", _envmap(np.ones((32, 48, 3))), FIT, "envmap.exr"),
    Case("envmap a mirror ball (1:1)", _envmap(np.ones((32, 32, 3))), FIT, "mirror-ball"),
    Case("file_path a folder", _frame(1, "file_path", "images"), FIT, "is a folder"),
    Case("envmap all zero", _envmap(np.zeros((32, 64, 3))), FIT, "no light"),
    Case("envmap with NaN", _envmap(np.full((32, 64, 3), np.nan)), FIT, "non-finite"),
    Case("envmap deeply negative", _envmap(np.full((32, 64, 3), -5.0)), FIT, "negative"),
    Case("envmap too coarse for --lmax", _envmap(np.ones((8, 16, 3))), (*FIT, "--lmax", "8"), "--lmax"),
    Case("envmap_to_world scaled", _top("envmap_to_world", (np.eye(4) * 3).tolist()), FIT, "envmap_to_world"),
    Case("envmap_scale negative", _top("envmap_scale", -1.0), FIT, "envmap_scale"),
    Case("envmap of text", _write("envmap.exr", "not an image"), FIT, "envmap.exr"),
    # the photographs and masks
    Case("truncated image", lambda root: (root / "images" / "0002.exr").write_bytes(
        (root / "images" / "0002.exr").read_bytes()[:300]), FIT, "0002.exr"),
    Case("NaN pixels", _image("images/0001.exr", lambda x: np.where(x > 0.1, np.nan, x)), FIT, "non-finite"),
    Case("deeply negative pixels", _image("images/0003.exr", lambda x: x - 1.0), FIT, "negative"),
    Case("image of another size", _image("images/0004.exr", lambda x: np.repeat(x, 2, axis=0)), FIT, "pixels"),
    Case("image of an unsupported type", _frame(0, "file_path", "images/0000.tif"), FIT, "0000.tif"),
    Case("mask of another size", lambda root: write_png(root / "masks" / "0001.png", np.ones((8, 8, 3))), FIT,
         "pixels"),
    Case("masks for some frames", _drop("mask_path", frame=3), FIT, "mask_path given for 5 of 6 frames"),
    Case("mask file missing", _frame(2, "mask_path", "masks/none.png"), FIT, "does not exist"),
    Case("every frame black", _all_images(lambda x: 0 * x), FIT, "every frame is black"),
    Case("a single view", lambda root: _transforms(root, lambda d: d.__setitem__("frames", d["frames"][:1])), FIT,
         "at least two views"),
    # the cameras
    Case("OpenCV camera axes", _poses(lambda m: m @ np.diag([1.0, -1.0, -1.0, 1.0])), FIT, "OpenCV"),
    Case("cameras facing away", _poses(lambda m: m @ np.diag([-1.0, 1.0, -1.0, 1.0])), FIT, "behind the camera"),
    Case("cameras far too far", _poses(lambda m: np.vstack([np.hstack([m[:3, :3], m[:3, 3:] * 5000]), m[3:]])),
         FIT, "cameras far too far"),
    Case("--lmax beyond the views", _nothing, (*FIT, "--lmax", "50"), "choose --lmax"),
    # test views, ground truth and other layouts
    Case("transforms_test.json malformed", _write("transforms_test.json", "{"), FIT, "transforms_test.json"),
    Case("test view's envmap missing", lambda root: _transforms(
        root, lambda d: d["frames"][0].__setitem__("envmap", "lights/none.exr"), "transforms_test.json"),
         ("evaluate", "{tmp}/fit"), "none.exr"),
    Case("ground truth of another size", lambda root: write_exr(root / "gt" / "roughness.exr", np.ones((8, 8, 1))),
         FIT, "gt"),
    Case("ground truth out of range", lambda root: write_exr(root / "gt" / "metallic.exr", 3 * np.ones((32, 32, 1))),
         FIT, "metallic"),
    Case("applied_transform malformed", _top("applied_transform", [[1, 0], [0, 1]]), FIT, "applied_transform"),
    Case("applied_scale zero", _top("applied_scale", 0), FIT, "applied_scale"),
    # options
    Case("--texture-res 0", _nothing, ("fit", "{capture}", "--out", "{out}", "--texture-res", "0"), "--texture-res"),
    Case("unknown option", _nothing, (*FIT, "--rougness", "1"), "No such option"),
    Case("misspelt command", _nothing, ("fti", "{capture}"), "No such command"),
    Case("missing --out", _nothing, ("fit", "{capture}"), "--out"),
    Case("unknown estimator", _nothing, (*FIT, "--estimator", "adam"), "unknown estimator"),
    Case("unknown preset", _nothing, (*FIT, "--preset", "fastest"), "unknown preset"),
    Case("paper model without paper estimator", _nothing, (*FIT, "--model", "spectrum"), "--estimator paper"),
    Case("--estimation-res auto", _nothing, (*FIT, "--estimation-res", "auto"), "--estimation-res"),
    Case("--device tpu", _nothing, (*FIT, "--device", "tpu"), "device must be one of"),
    Case("synth with an empty test map name", _nothing, ("synth", "{out}", "--test-envmaps", ","), "empty name"),
    Case("synth with an unknown mesh", _nothing, ("synth", "{out}", "--mesh", "teapot2"), "teapot2"),
    # --out
    Case("--out is a file", lambda root: (root.parent / "notes.txt").write_text("mine"),
         ("fit", "{capture}", "--out", "{tmp}/notes.txt"), "not a folder"),
    Case("--out under a file", lambda root: (root.parent / "notes.txt").write_text("mine"),
         ("fit", "{capture}", "--out", "{tmp}/notes.txt/fit"), "is a file"),
    Case("--out is the capture", _nothing, ("fit", "{capture}", "--out", "{capture}"), "would replace the capture"),
    Case("--out holds a user's files", lambda root: _write("thesis/thesis.txt", "years")(root.parent),
         ("fit", "{capture}", "--out", "{tmp}/thesis"), "freqbrdf did not write"),
    Case("--out is an ancestor of the capture", _nothing, ("fit", "{capture}", "--out", "{tmp}"), "{tmp}"),
    Case("evaluate on a folder that is no fit", lambda root: _write("other/x.txt", "x")(root.parent),
         ("evaluate", "{tmp}/other"), "not a fit folder"),
    Case("evaluate with --capture missing", _nothing, ("evaluate", "{tmp}/fit", "--capture", "{tmp}/gone"), "gone"),
    Case("report on a folder that is no fit", lambda root: _write("other/x.txt", "x")(root.parent),
         ("report", "{tmp}/other"), "not a fit folder"),
    Case("inpaint of an unknown map", _nothing, ("inpaint", "{tmp}/fit", "--out", "{out}", "--maps", "albedo"),
         "albedo"),
    Case("batch manifest missing", _nothing, ("batch", "{tmp}/none.toml", "--out", "{out}"), "none.toml"),
    Case("batch manifest malformed", lambda root: _write("batch.toml", "[[capture\n")(root.parent),
         ("batch", "{tmp}/batch.toml", "--out", "{out}"), "batch.toml"),
]


@pytest.fixture(scope="module")
def fitted(good_capture, tmp_path_factory):
    """A fit folder of the good capture, for the commands that read one."""
    from freqbrdf import pipeline
    from freqbrdf.capture.layouts import load
    from freqbrdf.config import Config, TexelConfig

    config = Config(texels=TexelConfig(texture_res=16))
    return pipeline.write_fit(tmp_path_factory.mktemp("fit") / "fit", pipeline.fit(load(good_capture), config), config)


def _snapshot(folder: Path) -> dict:
    return {str(path.relative_to(folder)): hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None
            for path in sorted(folder.rglob("*"))}


def prepare_case(case: Case, good_capture: Path, fitted: Path, folder: Path) -> tuple[list[str], dict]:
    """Lay out one case in ``folder`` (the capture, broken, and a fit of it): its command line and snapshot."""
    capture = folder / "capture"
    shutil.copytree(good_capture, capture)
    shutil.copytree(fitted, folder / "fit")
    fit_summary = json.loads((folder / "fit" / "summary.json").read_text())
    fit_summary["capture"] = str(capture)
    (folder / "fit" / "summary.json").write_text(json.dumps(fit_summary))
    case.breaking(capture)
    fill = {"capture": str(capture), "out": str(folder / "out"), "tmp": str(folder)}
    return [argument.format(**fill) for argument in case.arguments], fill


def test_the_corpus_is_large_and_its_names_unique():
    assert len(CASES) >= 60 and len({case.name for case in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[case.name for case in CASES])
def test_a_broken_input_is_one_line_and_its_exit_code_and_nothing_is_written_or_removed(
        case, good_capture, fitted, tmp_path, run_cli, capsys, monkeypatch):
    arguments, fill = prepare_case(case, good_capture, fitted, tmp_path)
    monkeypatch.chdir(tmp_path)
    before = _snapshot(tmp_path)
    code = run_cli(*arguments)
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == case.code, captured.err
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err
    assert case.expected.format(**fill) in lines[0], lines[0]
    assert "Traceback" not in captured.err + captured.out
    assert _snapshot(tmp_path) == before


def _interrupted(arguments: list[str], signal_number: int, at_work: Callable[[subprocess.Popen], str]
                 ) -> subprocess.CompletedProcess:
    """Run a command in a fresh process and send it a signal once ``at_work`` (which returns what it
    read of stderr) says it is working, as Ctrl-C or a scheduler would."""
    env = {key: value for key, value in os.environ.items() if key != RERUN_VARIABLE}
    process = subprocess.Popen([sys.executable, "-m", "freqbrdf.cli", *arguments], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, env=env,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    first = at_work(process)
    process.send_signal(signal_number)
    out, err = process.communicate(timeout=300)
    return subprocess.CompletedProcess(arguments, process.returncode, out, first + err)


def _first_line(process: subprocess.Popen) -> str:
    return process.stderr.readline()


def _output_started(folder: Path) -> Callable[[subprocess.Popen], str]:
    def wait(process):
        deadline = time.monotonic() + 120
        while not any(folder.iterdir()) and time.monotonic() < deadline and process.poll() is None:
            time.sleep(0.05)
        return ""
    return wait


@pytest.mark.parametrize("signal_number", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_an_interrupted_fit_is_one_line_and_leaves_the_previous_output_as_it_was(signal_number, good_capture, fitted,
                                                                                tmp_path):
    out = tmp_path / "fit"
    shutil.copytree(fitted, out)
    before = _snapshot(tmp_path)
    done = _interrupted(["fit", str(good_capture), "--out", str(out), "--texture-res", "256"], signal_number,
                        _first_line)
    assert done.returncode == 128 + signal_number, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last == "interrupted: the outputs in progress were removed, earlier ones are unchanged"
    assert "Traceback" not in done.stderr
    assert _snapshot(tmp_path) == before


def test_an_interrupted_synth_is_one_line_and_writes_nothing(tmp_path):
    done = _interrupted(["synth", str(tmp_path / "synth"), "--views", "400", "--resolution", "128", "--spp", "64",
                         "--quiet"], signal.SIGINT, _output_started(tmp_path))
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip() == "interrupted: the outputs in progress were removed, earlier ones are unchanged"
    assert list(tmp_path.iterdir()) == []
