"""`freqbrdf fit`, `uncertainty` and `evaluate` end to end on a tiny Mitsuba capture; bad input."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import OpenEXR
import pytest

from freqbrdf import pipeline
from freqbrdf.capture.layouts import load
from freqbrdf.cli import RERUN_VARIABLE
from freqbrdf.config import Config, TexelConfig
from freqbrdf.fileio import OUTPUT_MARKER, allow_replacing_foreign_folders
from freqbrdf.synthetic.synth import SynthSettings, synthesize

TINY = SynthSettings(mesh="bunny", views=6, resolution=40, spp=4, texture_res=32, test_views=2, test_envmaps=1)


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory):
    return synthesize(tmp_path_factory.mktemp("capture") / "tiny", TINY, progress=False)


@pytest.fixture(scope="module")
def tiny_fit(tiny_capture, tmp_path_factory):
    """A small fit folder made through the API, for the commands that read one."""
    config = Config(texels=TexelConfig(texture_res=16))
    return pipeline.write_fit(tmp_path_factory.mktemp("fit") / "fit", pipeline.fit(load(tiny_capture), config), config)


@pytest.mark.slow
def test_fit_and_evaluate_commands(run_cli, tiny_capture, tmp_path, monkeypatch, capsys):
    fit_dir = tmp_path / "fit"
    assert run_cli("fit", tiny_capture, "--out", fit_dir, "--texture-res", 32, "--lmax", 4, "--json") == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["capture"] == str(tiny_capture.resolve())
    assert summary["settings"]["texels"]["texture_res"] == 32 and summary["settings"]["fit"]["lmax"] == 4
    assert {"observe", "estimate", "uncertainty", "textures", "write", "total"} <= set(summary["timings"])
    for name in ("base_color.exr", "roughness.exr", "metallic.exr", "base_color.png", "material.glb",
                 "entropy.exr", "entropy.png", "roughness_std.exr", "roughness_std.png", "flags.png", "spectra.npz",
                 "uncertainty.npz"):
        assert (fit_dir / name).is_file(), name
    assert sorted(summary["files"]) == sorted(p.name for p in fit_dir.iterdir() if p.name != OUTPUT_MARKER)
    with np.load(fit_dir / "spectra.npz") as spectra:
        assert spectra["observed_spectrum"].shape[1:] == (3, 5)  # l* = 4: degrees 0..4

    # The capture comes from summary.json; texture, relighting and uncertainty scores all present.
    assert run_cli("evaluate", fit_dir, "--spp", 2, "--json") == 0
    metrics = json.loads(capsys.readouterr().out)
    assert metrics["texture"]["texels"] > 0 and len(metrics["views"]) == TINY.test_views
    assert metrics["relighting"]["psnr_hdr"] > 0
    assert set(metrics["uncertainty"]) >= {"roughness", "base_color", "metallic", "roughness_std"}
    assert set(metrics["uncertainty"]["roughness_std"]) == {"roughness", "base_color", "metallic"}
    evaluation = fit_dir / "evaluation"
    assert json.loads((evaluation / "metrics.json").read_text()) == metrics
    assert (evaluation / "sparsification.png").is_file() and len(list((evaluation / "relight").glob("*.png"))) == 2

    shared_dir = tmp_path / "per_texel"
    assert run_cli("fit", tiny_capture, "--out", shared_dir, "--texture-res", 32, "--per-texel",
                   "--no-neighbour-vote", "--split-half", "--estimation-res", 16, "--no-environment-occlusion",
                   "--no-calibrate-std", "--quiet") == 0
    assert capsys.readouterr().out == ""
    shared_summary = json.loads((shared_dir / "summary.json").read_text())
    assert not shared_summary["settings"]["surface"]["enabled"] and "surface" not in shared_summary["timings"]
    assert summary["settings"]["surface"]["enabled"] and "surface" in summary["timings"]
    assert not (shared_dir / "metallic_std.exr").exists() and (fit_dir / "metallic_std.exr").is_file()
    shared_settings, default_settings = shared_summary["settings"]["estimate"], summary["settings"]["estimate"]
    assert not shared_settings["neighbour_vote"]
    assert shared_summary["settings"]["uncertainty"]["split_half"]
    assert shared_summary["estimation_res"] == 16 and summary["estimation_res"] == 32  # "pixel" keeps T here
    assert shared_summary["coverage"]["texture_res"] == 32
    assert not summary["settings"]["uncertainty"]["split_half"]
    # The held-out std calibration: on by default, off with --no-calibrate-std.
    assert summary["std_calibration"]["folds"] == summary["settings"]["uncertainty"]["heldout_folds"] == 4
    assert shared_summary["std_calibration"] is None and shared_summary["settings"]["uncertainty"]["heldout_folds"] == 0
    # The default fit's:
    assert default_settings["neighbour_vote"]
    assert summary["settings"]["observe"]["environment_occlusion"]
    assert not shared_summary["settings"]["observe"]["environment_occlusion"]

    paper_dir = tmp_path / "paper"
    assert run_cli("fit", tiny_capture, "--out", paper_dir, "--texture-res", 16,
                   "--preset", "paper", "--estimator", "paper", "--model", "spectrum", "--quiet") == 0
    paper_summary = json.loads((paper_dir / "summary.json").read_text())
    assert not paper_summary["settings"]["observe"]["environment_occlusion"]  # the paper's unoccluded light
    assert paper_summary["estimate"]["method"] == "paper/spectrum"
    assert paper_summary["settings"]["estimate"]["forward_model"] == "spectrum"
    assert paper_summary["settings"]["uncertainty"]["mode"] == "paper"


@pytest.mark.slow
def test_uncertainty_command(run_cli, tiny_capture, tmp_path, monkeypatch, capsys):
    out = tmp_path / "uncertainty"
    assert run_cli("uncertainty", tiny_capture, "--out", out, "--texture-res", 32, "--json") == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["capture"] == str(tiny_capture.resolve())
    assert 0.0 <= summary["uncertainty"]["entropy_mean"] <= 1.0
    assert {"observe", "uncertainty"} <= set(summary["timings"])
    assert {p.name for p in out.iterdir()} - {OUTPUT_MARKER} == {"entropy.exr", "entropy.png", "flags.png", "uncertainty.json"}
    with OpenEXR.File(str(out / "entropy.exr"), header_only=True) as exr:  # says what it is
        assert "normalised entropy" in exr.parts[0].header["comments"]
        assert f"({summary['uncertainty']['mode']} mode)" in exr.parts[0].header["comments"]
    assert json.loads((out / "uncertainty.json").read_text()) == summary
    # No estimate, so no roughness_std: the summary and the message say so rather than omit it.
    assert "freqbrdf fit" in summary["not_computed"]["roughness_std"]
    assert run_cli("uncertainty", tiny_capture, "--out", out, "--texture-res", 16) == 0
    assert "roughness_std not computed" in capsys.readouterr().out
    # The angular entropy (the estimator's model on the samples), and a mode that does not exist.
    assert run_cli("uncertainty", tiny_capture, "--out", out, "--texture-res", 16, "--entropy", "angular",
                   "--json") == 0
    angular = json.loads(capsys.readouterr().out)
    assert angular["uncertainty"]["mode"] == "angular" and angular["settings"]["uncertainty"]["mode"] == "angular"
    assert 0.0 <= angular["uncertainty"]["entropy_mean"] <= 1.0
    other = tmp_path / "other"
    assert run_cli("uncertainty", tiny_capture, "--out", other, "--entropy", "sharpest") == 2
    assert "unknown entropy mode" in capsys.readouterr().err and not other.exists()
    # The grids: 8 x 8 in the spectral modes, the estimator's 9 roughness nodes in the angular mode.
    assert summary["uncertainty"]["grid_res"] == 8 and angular["uncertainty"]["grid_res"] == 9
    # The system refusing the write: one line naming the path, exit 1, the previous output kept.
    files_before = sorted(p.name for p in out.iterdir())

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(out.parent / ".uncertainty.tmp"))

    with monkeypatch.context() as patched:
        patched.setattr("freqbrdf.fileio.tempfile.mkdtemp", refuse)
        assert run_cli("uncertainty", tiny_capture, "--out", out, "--texture-res", 16, "--quiet") == 1
    assert ".uncertainty.tmp: Permission denied" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == files_before

    # At T = 128 both commands work on the 64 x 64 texels the 40-pixel images resolve, and their
    # entropy maps agree on the atlas.
    from freqbrdf.images import read_image
    from freqbrdf.texels import rasterise

    fine = tmp_path / "fine"
    assert run_cli("uncertainty", tiny_capture, "--out", fine, "--texture-res", 128, "--json") == 0
    assert json.loads(capsys.readouterr().out)["estimation_res"] == 64
    fitted = tmp_path / "fitted"
    assert run_cli("fit", tiny_capture, "--out", fitted, "--texture-res", 128, "--quiet") == 0
    assert json.loads((fitted / "summary.json").read_text())["estimation_res"] == 64
    atlas = rasterise(load(tiny_capture).mesh, 128).mask
    alone, with_fit = (read_image(folder / "entropy.exr")[..., 0] for folder in (fine, fitted))
    assert alone.shape == with_fit.shape == (128, 128)
    np.testing.assert_allclose(alone[atlas], with_fit[atlas], atol=1e-6)


@pytest.mark.slow
def test_a_run_that_compiles_kernels_runs_again_from_numbas_cache(tiny_capture, tmp_path):
    """With an empty numba cache the command compiles its kernels, says so, and runs again in a fresh
    process that loads them: its results are those of every later run (compiled code differs in
    the last bits from cached code)."""
    env = {key: value for key, value in os.environ.items() if key != RERUN_VARIABLE}
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "numba_cache")
    arrays, messages = [], []
    for run in ("first", "second"):
        out = tmp_path / run
        done = subprocess.run([sys.executable, "-m", "freqbrdf.cli", "observe", str(tiny_capture), "--out", str(out),
                               "--texture-res", "32"], env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr
        messages.append(" ".join(done.stderr.split()))  # rich wraps lines
        with np.load(out / "observations.npz") as data:
            arrays.append({name: data[name] for name in data.files if name != "timings_json"})
    assert "running again from its cache" in messages[0] and "numba compiled" in messages[0]
    assert messages[0].index("compiling its kernels on first use") < messages[0].index("numba compiled")
    assert "numba compiled" not in messages[1] and "on first use" not in messages[1]
    assert arrays[0].keys() == arrays[1].keys()
    for name in arrays[0]:
        np.testing.assert_array_equal(arrays[0][name], arrays[1][name], err_msg=name)


def test_bad_input_is_one_line_exit_2_and_writes_nothing(run_cli, tmp_path, monkeypatch, capsys):
    for command in ("fit", "uncertainty"):
        assert run_cli(command, tmp_path / "missing", "--out", tmp_path / "out") == 2
        assert "missing" in capsys.readouterr().err and not (tmp_path / "out").exists()

    # --out that cannot become a folder is refused before any work, and the file is left as it was.
    a_file = tmp_path / "a_file"
    a_file.write_text("keep me")
    missing = tmp_path / "missing"
    for arguments in (("fit", missing, "--out", a_file), ("uncertainty", missing, "--out", a_file),
                      ("observe", missing, "--out", a_file), ("next-views", missing, "--out", a_file),
                      ("synth", a_file), ("demo", "--out", a_file)):
        assert run_cli(*arguments) == 2
        assert "a_file: exists and is not a folder" in capsys.readouterr().err
    assert run_cli("fit", tmp_path / "missing", "--out", a_file / "fit") == 2
    assert "a_file: is a file, so nothing can be written under it" in capsys.readouterr().err
    assert a_file.read_text() == "keep me" and sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]

    # The entropy needs degree 1 at least: refused before any work.
    for command in ("fit", "uncertainty"):
        assert run_cli(command, missing, "--out", tmp_path / "out", "--lmax", 0) == 2
        assert "--lmax" in capsys.readouterr().err and not (tmp_path / "out").exists()

    # Running out of memory (e.g. a --texture-res far too large) is one line and exit 1.
    def exhaust(*args, **kwargs):
        raise MemoryError("Unable to allocate 32.0 GiB")

    with monkeypatch.context() as patched:
        patched.setattr("freqbrdf.capture.layouts.load", exhaust)
        assert run_cli("info", missing) == 1
    err = capsys.readouterr().err
    assert "out of memory (Unable to allocate 32.0 GiB)" in err and "Traceback" not in err

    not_a_fit = tmp_path / "not_a_fit"
    not_a_fit.mkdir()
    assert run_cli("evaluate", not_a_fit) == 2
    err = capsys.readouterr().err
    assert "summary.json" in err and "not a fit folder" in err
    assert not (not_a_fit / "evaluation").exists()

    (not_a_fit / "summary.json").write_text("{broken")
    assert run_cli("evaluate", not_a_fit) == 2
    assert "unreadable" in capsys.readouterr().err


@pytest.mark.slow
def test_bad_options_and_captures_are_refused_before_any_output(run_cli, tiny_capture, tiny_fit, tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    assert run_cli("fit", tiny_capture, "--out", out, "--estimator", "adam") == 2
    assert "unknown estimator" in capsys.readouterr().err and not out.exists()
    assert run_cli("fit", tiny_capture, "--out", out, "--preset", "fastest") == 2
    assert "unknown preset" in capsys.readouterr().err and not out.exists()
    for value in ("auto", "0", "1024"):
        assert run_cli("fit", tiny_capture, "--out", out, "--estimation-res", value) == 2
        assert "--estimation-res must be pixel, coarse, full or a number" in capsys.readouterr().err
        assert not out.exists()

    # --out must not replace the capture it reads.
    files_before = sorted(p.name for p in tiny_capture.iterdir())
    assert run_cli("fit", tiny_capture, "--out", tiny_capture, "--quiet") == 2
    assert "would replace the capture" in capsys.readouterr().err
    assert sorted(p.name for p in tiny_capture.iterdir()) == files_before

    # evaluate: an explicit capture that is not there, and a fit whose recorded capture moved away.
    assert run_cli("evaluate", tiny_fit, "--capture", tmp_path / "gone") == 2
    assert "gone" in capsys.readouterr().err and not (tiny_fit / "evaluation").exists()
    moved = tmp_path / "moved_fit"
    shutil.copytree(tiny_fit, moved)
    summary = json.loads((moved / "summary.json").read_text())
    summary["capture"] = str(tmp_path / "moved_capture")
    (moved / "summary.json").write_text(json.dumps(summary))
    assert run_cli("evaluate", moved) == 2
    assert "moved_capture" in capsys.readouterr().err and not (moved / "evaluation").exists()


def test_out_never_replaces_a_users_folder_nor_the_current_one(tiny_capture, tmp_path, run_cli, capsys, monkeypatch):
    """A user's folder, or the current one, as --out: one line and exit 2 before any work, nothing
    written or removed; `freqbrdf --force` lets a user's folder be replaced."""
    mine = tmp_path / "thesis"
    mine.mkdir()
    (mine / "thesis.txt").write_text("years of work")
    before = sorted(p.name for p in tmp_path.iterdir())
    assert run_cli("fit", tiny_capture, "--out", mine, "--texture-res", 16, "--quiet") == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith(f"error: {mine}: exists and holds files freqbrdf did not write") and "\n" not in error
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    monkeypatch.chdir(mine)
    assert run_cli("fit", tiny_capture, "--out", ".", "--texture-res", 16, "--quiet") == 2
    assert "is the current folder or contains it" in capsys.readouterr().err
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.txt"]
    monkeypatch.chdir(tmp_path)
    try:
        assert run_cli("--force", "fit", tiny_capture, "--out", mine, "--texture-res", 16, "--quiet") == 0
        assert (mine / "base_color.exr").is_file() and not (mine / "thesis.txt").exists()
    finally:
        allow_replacing_foreign_folders(False)  # the flag holds for the process, as for one command line


def test_option_mistakes_are_refused_before_any_work(tiny_capture, tmp_path, run_cli, capsys):
    """A paper forward model without the paper estimator, and an empty test-map name, are refused
    before anything is observed or rendered: exit 2, nothing written."""
    assert run_cli("fit", tiny_capture, "--out", tmp_path / "fit", "--model", "spectrum", "--quiet") == 2
    assert "add --estimator paper" in capsys.readouterr().err
    assert run_cli("synth", tmp_path / "synth", "--test-envmaps", "studio,", "--views", 2, "--resolution", 8,
                   "--spp", 1) == 2
    error = capsys.readouterr().err
    assert "test_envmaps has an empty name" in error and "rendering" not in error
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_truncated_exr_is_one_line_on_stderr_and_nothing_on_stdout(tiny_capture, tmp_path):
    """OpenEXR prints its own lines about a damaged file (one on stdout); `--json` output stays clean."""
    capture = tmp_path / "capture"
    shutil.copytree(tiny_capture, capture)
    frame = sorted((capture / "images").glob("*.exr"))[1]
    frame.write_bytes(frame.read_bytes()[:2000])
    done = subprocess.run([sys.executable, "-m", "freqbrdf.cli", "fit", str(capture), "--out", str(tmp_path / "fit"),
                           "--texture-res", "16", "--json"], capture_output=True, text=True, timeout=300,
                          env={key: value for key, value in os.environ.items() if key != RERUN_VARIABLE})
    assert done.returncode == 2 and done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {frame}: not a readable OpenEXR file ("), lines
