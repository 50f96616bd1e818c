"""The fit pipeline and its commands end to end on a tiny Mitsuba capture; sparsification maths."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
import trimesh

from freqbrdf import pipeline, sparsification
from freqbrdf.capture import load
from freqbrdf.cli import main
from freqbrdf.config import Config, TexelConfig
from freqbrdf.synth import SynthSettings, synthesize

TINY = SynthSettings(mesh="bunny", views=6, resolution=40, spp=4, texture_res=32, test_views=2, test_envmaps=1)


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory):
    return synthesize(tmp_path_factory.mktemp("capture") / "tiny", TINY, progress=False)


def run_cli(monkeypatch, *arguments) -> int:
    monkeypatch.setattr(sys, "argv", ["freqbrdf", *map(str, arguments)])
    with pytest.raises(SystemExit) as exit_info:
        main()
    return exit_info.value.code or 0


# --- sparsification ---------------------------------------------------------------------------


def test_sparsification_of_a_perfect_ranking_equals_the_oracle():
    error = np.array([0.4, 0.1, 0.3, 0.2])
    result = sparsification.sparsification(uncertainty=error * 10, error=error, steps=5, max_fraction=0.75)
    np.testing.assert_allclose(result.by_uncertainty, result.oracle)
    assert result.ause == pytest.approx(0.0) and result.spearman == pytest.approx(1.0)
    # Hand-computed: removing 0, 1, 2 of the 4 texels (f = 0, 0.1875 -> 0, 0.375 -> 1, 0.5625 -> 2,
    # 0.75 -> 3) leaves means 0.25, 0.25, 0.2, 0.15, 0.1 of a full mean 0.25.
    np.testing.assert_allclose(result.oracle, [1.0, 1.0, 0.8, 0.6, 0.4])
    assert result.aurg == pytest.approx(np.trapezoid(1.0 - result.oracle, result.fractions))


def test_sparsification_of_a_reversed_ranking_is_worse_than_random():
    error = np.linspace(0.0, 1.0, 101)
    result = sparsification.sparsification(uncertainty=-error, error=error)
    assert result.aurg < 0 and result.ause > 0 and result.spearman == pytest.approx(-1.0)


def test_sparsification_ignores_non_finite_entries_and_checks_lengths():
    result = sparsification.sparsification(np.array([1.0, np.nan, 2.0]), np.array([0.1, 0.5, np.inf]))
    assert result.texels == 1
    with pytest.raises(ValueError):
        sparsification.sparsification(np.ones(3), np.ones(4))


# --- the pipeline -----------------------------------------------------------------------------


@pytest.mark.slow
def test_fit_writes_a_complete_folder_that_loads_back(tiny_capture, tmp_path):
    config = Config(texels=TexelConfig(texture_res=32))
    result = pipeline.fit(load(tiny_capture), config)
    assert {"observe", "estimate", "uncertainty", "textures", "total"} <= set(result.timings)
    folder = pipeline.write_fit(tmp_path / "fit", result, config)
    outputs = pipeline.load_fit(folder)
    assert outputs.capture_path == tiny_capture.resolve()
    np.testing.assert_allclose(outputs.maps.roughness, result.maps.roughness)
    np.testing.assert_array_equal(outputs.arrays["flags"], result.uncertainty.flags)
    assert outputs.observed.sum() == np.count_nonzero(result.observations.n_samples)
    assert "write" in outputs.summary["timings"]
    scene = trimesh.load(folder / "material.glb")
    assert len(scene.geometry) == 1


@pytest.mark.slow
def test_fit_and_evaluate_commands(tiny_capture, tmp_path, monkeypatch, capsys):
    fit_dir = tmp_path / "fit"
    assert run_cli(monkeypatch, "fit", tiny_capture, "--out", fit_dir, "--texture-res", 32, "--json") == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["capture"] == str(tiny_capture.resolve()) and summary["settings"]["texels"]["texture_res"] == 32
    for name in ("base_color.exr", "roughness.exr", "metallic.exr", "material.glb", "entropy.png",
                 "flags.png", "spectra.npz", "uncertainty.npz"):
        assert (fit_dir / name).is_file(), name

    assert run_cli(monkeypatch, "evaluate", fit_dir, "--spp", 2, "--json") == 0
    metrics = json.loads(capsys.readouterr().out)
    assert metrics["texture"]["texels"] > 0 and len(metrics["views"]) == TINY.test_views
    assert set(metrics["uncertainty"]) >= {"roughness", "base_color", "metallic"}
    assert (fit_dir / "evaluation" / "metrics.json").is_file()
    assert (fit_dir / "evaluation" / "sparsification.png").is_file()

    shared_dir = tmp_path / "shared"
    assert run_cli(monkeypatch, "fit", tiny_capture, "--out", shared_dir, "--texture-res", 32, "--share", "--quiet") == 0
    shared_summary = json.loads((shared_dir / "summary.json").read_text())
    assert shared_summary["settings"]["share"]["enabled"] and "share" in shared_summary["timings"]

    paper_dir = tmp_path / "paper"
    assert run_cli(monkeypatch, "fit", tiny_capture, "--out", paper_dir, "--texture-res", 16,
                   "--preset", "paper", "--model", "spectrum", "--quiet") == 0
    paper_summary = json.loads((paper_dir / "summary.json").read_text())
    assert paper_summary["estimate"]["method"] == "paper/spectrum"
    assert paper_summary["settings"]["estimate"]["forward_model"] == "spectrum"


@pytest.mark.slow
def test_uncertainty_command(tiny_capture, tmp_path, monkeypatch, capsys):
    out = tmp_path / "uncertainty"
    assert run_cli(monkeypatch, "uncertainty", tiny_capture, "--out", out, "--texture-res", 32, "--json") == 0
    summary = json.loads(capsys.readouterr().out)
    assert 0.0 <= summary["uncertainty"]["entropy_mean"] <= 1.0
    assert {p.name for p in out.iterdir()} == {"entropy.exr", "entropy.png", "flags.png", "uncertainty.json"}


def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, monkeypatch, capsys):
    assert run_cli(monkeypatch, "fit", tmp_path / "missing", "--out", tmp_path / "out") == 2
    assert "missing" in capsys.readouterr().err and not (tmp_path / "out").exists()

    not_a_fit = tmp_path / "not_a_fit"
    not_a_fit.mkdir()
    assert run_cli(monkeypatch, "evaluate", not_a_fit) == 2
    err = capsys.readouterr().err
    assert "summary.json" in err and "not a fit folder" in err
    assert not (not_a_fit / "evaluation").exists()

    (not_a_fit / "summary.json").write_text("{broken")
    assert run_cli(monkeypatch, "evaluate", not_a_fit) == 2
    assert "unreadable" in capsys.readouterr().err
