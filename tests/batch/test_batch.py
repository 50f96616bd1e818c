"""`freqbrdf batch` on a real local Ray cluster: manifests, resumption, faults, Ctrl-C."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import ray

from freqbrdf import batch
from freqbrdf.batch import state, tasks
from freqbrdf.batch.runner import TEST_HOOKS_VARIABLE
from freqbrdf.cli import RERUN_VARIABLE
from freqbrdf.errors import InputError
from freqbrdf.outputs.fit_folder import load_fit
from freqbrdf.synthetic.synth import SynthSettings, synthesize

TINY = SynthSettings(mesh="bunny", views=8, resolution=32, spp=4, texture_res=32, test_views=1,
                     test_envmaps=("studio",))


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """Two tiny captures and a broken one (an image missing), in one folder."""
    folder = tmp_path_factory.mktemp("captures")
    synthesize(folder / "bunny", TINY, progress=False)
    synthesize(folder / "sphere", dataclasses.replace(TINY, mesh="sphere", seed=1), progress=False)
    shutil.copytree(folder / "bunny", folder / "broken")
    (folder / "broken" / "images" / "0003.exr").unlink()
    return folder


@pytest.fixture(scope="module")
def cluster():
    """One local Ray cluster for the module's tests (`batch.run` uses a running one)."""
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False,
             logging_level=logging.ERROR, object_store_memory=128 * 2**20)
    yield
    ray.shutdown()


def write_csv(path: Path, rows: list[str]) -> Path:
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def snapshot(folder: Path) -> dict:
    """Every file under ``folder``: (size, mtime_ns)."""
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


def rows(summary: dict) -> dict:
    return {row["name"]: row for row in summary["captures"]}


# ---------------------------------------------------------------------------------------------
# The manifest, checked whole before any work (no Ray needed)


def test_manifest_formats(captures, tmp_path):
    csv_path = write_csv(captures / "m.csv", ["name,capture,texture_res,evaluate,report",
                                              "a,bunny,16,false,", ",sphere,,auto,no"])
    entries = batch.read_manifest(csv_path, {"lmax": 4})
    assert [entry.name for entry in entries] == ["a", "sphere"]  # no name: the capture folder's
    assert entries[0].capture == (captures / "bunny").resolve() and entries[0].where == "m.csv line 2"
    assert entries[0].settings == {"lmax": 4, "texture_res": 16, "evaluate": False}
    assert entries[1].settings == {"lmax": 4, "evaluate": "auto", "report": False}

    jsonl = captures / "m.jsonl"
    jsonl.write_text('{"name": "a", "capture": "bunny/transforms.json", "preset": "fast", "per_texel": true}\n\n'
                     '{"capture": "sphere", "estimation_res": 8}\n', encoding="utf-8")
    entries = batch.read_manifest(jsonl)
    assert [(e.name, e.settings) for e in entries] == [("a", {"preset": "fast", "per_texel": True}),
                                                       ("sphere", {"estimation_res": 8})]
    assert entries[0].root == (captures / "bunny").resolve()
    assert not batch.capture_config(entries[0].settings).surface.enabled

    # A folder: its subfolders holding a capture, by name (files and other folders ignored).
    (captures / "not_a_capture").mkdir(exist_ok=True)
    assert [e.name for e in batch.read_manifest(captures)] == ["broken", "bunny", "sphere"]
    # Settings change the hash; equal settings written differently do not.
    assert batch.settings_hash({"texture_res": 16}) != batch.settings_hash({"texture_res": 32})
    assert batch.settings_hash({"preset": "default", "report": True}) == batch.settings_hash({})


@pytest.mark.parametrize("lines, message", [
    (["name,capture", "a,bunny", "A,sphere"], "m.csv: line 3: name 'A' also on line 2"),
    (["name,capture", "a,nowhere"], "m.csv: line 2: capture 'nowhere' does not exist"),
    (["name,capture,colour", "a,bunny,red"], "m.csv: line 1: unknown column 'colour'"),
    (["name,capture,texture_res", "a,bunny,big"], "m.csv: line 2: texture_res 'big' must be a whole number >= 1"),
    (["name,capture,preset", "a,bunny,quick"], "m.csv: line 2: preset 'quick' must be one of default, fast, paper"),
    (["name,capture,evaluate", "a,bunny,maybe"], "m.csv: line 2: evaluate 'maybe' must be true or false"),
    (["name,capture,texture_res,estimation_res", "a,bunny,16,32"], "m.csv: line 2: estimation_res 32 exceeds"),
    (["name,capture", "../a,bunny"], "m.csv: line 2: name '../a' must start with a letter or digit"),
    (["name,capture", "a,bunny,extra"], "m.csv: line 2: 3 cells, the header has 2 columns"),
    (["name,capture", "a,not_a_folder_capture"], "m.csv: line 2: capture 'not_a_folder_capture' holds no"),
    (["name"], "m.csv: line 1: the header needs a 'capture' column"),
    (["name,capture"], "m.csv: manifest lists no capture"),
])
def test_manifest_errors_name_the_line(captures, lines, message):
    (captures / "not_a_folder_capture").mkdir(exist_ok=True)
    with pytest.raises(InputError) as error:
        batch.read_manifest(write_csv(captures / "m.csv", lines))
    assert str(error.value).startswith(f"{captures}/{message}"), str(error.value)


def test_manifest_errors_other_formats(captures, tmp_path, run_cli, capsys):
    jsonl = tmp_path / "m.jsonl"
    jsonl.write_text(f'{{"capture": "{captures / "bunny"}"}}\n[1, 2]\n', encoding="utf-8")
    with pytest.raises(InputError, match=r"m.jsonl: line 2: must be a JSON object"):
        batch.read_manifest(jsonl)
    jsonl.write_text(f'{{"capture": "{captures / "bunny"}", "lmax": 0}}\n', encoding="utf-8")
    with pytest.raises(InputError, match=r"m.jsonl: line 1: lmax 0 must be a whole number >= 1"):
        batch.read_manifest(jsonl)
    with pytest.raises(InputError, match="is a capture, not a folder of captures"):
        batch.read_manifest(captures / "bunny")
    with pytest.raises(InputError, match=r"must be a \.csv or \.jsonl file"):
        batch.read_manifest(captures / "bunny" / "transforms.json")
    # The command line: one line, exit code 2, nothing written.
    bad = write_csv(tmp_path / "bad.csv", ["name,capture", f"a,{captures / 'bunny'}", f"a,{captures / 'sphere'}"])
    assert run_cli("batch", bad, "--out", tmp_path / "out") == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("error: ") and "bad.csv: line 3: name 'a' also on line 2" in error
    assert len(error.splitlines()) == 1 and not (tmp_path / "out").exists()
    # An output folder inside a capture would change its inputs.
    good = write_csv(tmp_path / "good.csv", ["name,capture", f"a,{captures / 'bunny'}"])
    with pytest.raises(InputError, match="lies in capture a"):
        batch.run(good, captures / "bunny" / "out")


def test_default_workers():
    gib = 2**30
    assert batch.default_workers(2, 512, cores=2, memory=20 * gib) == 1
    assert batch.default_workers(1, 512, cores=2, memory=20 * gib) == 2
    assert batch.default_workers(2, 512, cores=16, memory=6 * gib) == 4  # memory-bound: 1.5 GiB each
    assert batch.default_workers(2, 1024, cores=64, memory=64 * gib) == 17  # 3.75 GiB each at T = 1024
    assert batch.default_workers(2, 512, cores=1, memory=gib) == 1


# ---------------------------------------------------------------------------------------------
# On Ray


@pytest.mark.slow
def test_batch_resumes_and_redoes_only_what_changed(cluster, captures, tmp_path):
    out = tmp_path / "out"
    manifest = write_csv(tmp_path / "m.csv", [
        "name,capture,texture_res,evaluate,report,spp",
        f"a,{captures / 'bunny'},32,true,true,2",
        f"b,{captures / 'sphere'},32,false,false,",
        f"broken,{captures / 'broken'},32,false,false,",
    ])
    summary = batch.run(manifest, out, workers=2)
    found = rows(summary)
    assert summary["counts"] == {"done": 2, "skipped": 0, "failed": 1, "interrupted": 0}
    assert summary["engine"]["workers"] == 2 and summary["engine"]["threads_per_capture"] == 1
    assert found["broken"]["status"] == "failed" and found["broken"]["attempts"] == 1
    error = found["broken"]["error"]
    assert error == f"{captures / 'broken' / 'images' / '0003.exr'}: image of frame 3 in transforms.json does not exist"
    assert not (out / "broken").exists()
    for name in ("a", "b"):
        assert found[name]["status"] == "done" and found[name]["attempts"] == 1 and found[name]["seconds"] > 0
        assert found[name]["worker"]["threads"] == 1  # numba's threads: the task's one CPU
        assert load_fit(out / name).maps.resolution == 32
    # a: evaluated (texture scores: the capture has ground truth) and reported; b: neither.
    assert found["a"]["metrics"]["base_color_psnr"] > 0 and found["a"]["metrics"]["psnr_hdr"] > 0
    assert found["a"]["paths"] == {"folder": "a", "report": "a/report/report.html",
                                   "metrics": "a/evaluation/metrics.json"}
    assert json.loads((out / "a" / "evaluation" / "metrics.json").read_text())["fit"] == str((out / "a").resolve())
    assert found["b"]["paths"]["report"] is None and "base_color_psnr" not in found["b"]["metrics"]
    assert json.loads((out / "batch.json").read_text()) == json.loads(json.dumps(summary))
    index = (out / "index.html").read_text()
    assert 'href="a/report/report.html"' in index and 'href="b/summary.json"' in index and "0003.exr" in index
    assert not (out / batch.WORK_FOLDER).exists()  # nothing left behind

    # A rerun does nothing to the finished captures; the failed one is tried again.
    before = {name: snapshot(out / name) for name in ("a", "b")}
    summary = batch.run(manifest, out, workers=2)
    assert [row["status"] for row in summary["captures"]] == ["skipped", "skipped", "failed"]
    assert rows(summary)["a"]["metrics"] == found["a"]["metrics"]
    assert {name: snapshot(out / name) for name in ("a", "b")} == before

    # Touched without a change of content: still up to date (the hash is of contents).
    transforms = captures / "bunny" / "transforms.json"
    os.utime(transforms, ns=(time.time_ns(), time.time_ns()))
    fixed = write_csv(tmp_path / "fixed.csv", manifest.read_text().splitlines()[:3])
    assert [row["status"] for row in batch.run(fixed, out)["captures"]] == ["skipped", "skipped"]

    # A changed setting redoes that capture alone; so does a changed input file.
    changed = write_csv(tmp_path / "changed.csv", [
        "name,capture,texture_res,evaluate,report,spp",
        f"a,{captures / 'bunny'},32,true,true,2",
        f"b,{captures / 'sphere'},16,false,false,",
    ])
    summary = batch.run(changed, out, workers=2)
    assert [row["status"] for row in summary["captures"]] == ["skipped", "done"]
    assert snapshot(out / "a") == before["a"] and load_fit(out / "b").maps.resolution == 16
    sphere_transforms = captures / "sphere" / "transforms.json"
    sphere_transforms.write_text(json.dumps(json.loads(sphere_transforms.read_text()), indent=1))
    assert [row["status"] for row in batch.run(changed, out, workers=2)["captures"]] == ["skipped", "done"]

    # --force redoes an up-to-date capture.
    only_b = write_csv(tmp_path / "only_b.csv", changed.read_text().splitlines()[::2])
    assert [row["status"] for row in batch.run(only_b, out)["captures"]] == ["skipped"]
    assert [row["status"] for row in batch.run(only_b, out, force=True)["captures"]] == ["done"]

    # One batch at a time per folder: a live holder of the lock refuses, a dead one is taken over.
    lock = out / batch.WORK_FOLDER / "lock.json"
    lock.parent.mkdir()
    lock.write_text(json.dumps({"host": socket.gethostname(), "pid": os.getpid(), "since": "now"}))
    with pytest.raises(InputError, match=f"another batch \\(pid {os.getpid()}"):
        batch.run(only_b, out)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    lock.write_text(json.dumps({"host": socket.gethostname(), "pid": dead.pid, "since": "then"}))
    assert [row["status"] for row in batch.run(only_b, out)["captures"]] == ["skipped"]
    assert not lock.exists()


@pytest.mark.slow
def test_killed_worker_is_retried(cluster, captures, tmp_path, monkeypatch):
    """The first attempt of `a` kills its own worker with SIGKILL mid-fit (fault injection): Ray
    retries it and the batch finishes with complete outputs."""
    monkeypatch.setenv(TEST_HOOKS_VARIABLE, json.dumps({"kill_first_attempt": ["a"]}))
    manifest = write_csv(tmp_path / "m.csv", ["name,capture,texture_res,evaluate,report",
                                              f"a,{captures / 'bunny'},32,false,false"])
    summary = batch.run(manifest, tmp_path / "out", workers=2)
    row = rows(summary)["a"]
    assert row["status"] == "done" and row["attempts"] == 2, row
    assert load_fit(tmp_path / "out" / "a").maps.resolution == 32
    entry = json.loads((tmp_path / "out" / "a" / batch.ENTRY_FILE).read_text())
    assert entry["attempts"] == 2 and set(entry["outputs"]) == set(snapshot(tmp_path / "out" / "a")) - {batch.ENTRY_FILE}


@pytest.mark.slow
def test_ctrl_c_keeps_finished_captures(cluster, captures, tmp_path):
    """Ctrl-C (SIGINT to the command's process group, as a terminal sends it) while `b` runs: exit
    130, `a` intact, `b` recorded as interrupted and not written; a rerun goes on with `b` alone."""
    out = tmp_path / "out"
    manifest = write_csv(tmp_path / "m.csv", ["name,capture,texture_res,evaluate,report",
                                              f"a,{captures / 'bunny'},32,false,false",
                                              f"b,{captures / 'sphere'},32,false,false"])
    # b sleeps far longer than a may take on a loaded machine, so that Ctrl-C always finds it running.
    env = {**os.environ, TEST_HOOKS_VARIABLE: json.dumps({"sleep_s": {"b": 900}})}
    # SIGINT as a terminal leaves it (a test run started in the background inherits it ignored).
    command = subprocess.Popen([sys.executable, "-m", "freqbrdf.cli", "batch", str(manifest), "--out", str(out),
                                "--workers", "1", "--quiet"], env=env, start_new_session=True,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 400  # Ray's start and a's fit, on a machine other jobs may share
        while not (out / "a" / batch.ENTRY_FILE).is_file() and command.poll() is None:
            assert time.monotonic() < deadline, "capture a did not finish"
            time.sleep(0.2)
        time.sleep(1.0)  # b has started (and sleeps)
        finished = snapshot(out / "a")
        os.killpg(command.pid, signal.SIGINT)
        _, stderr = command.communicate(timeout=300)  # Ray cancels and shuts down: slow on a loaded machine
    finally:
        if command.poll() is None:
            os.killpg(command.pid, signal.SIGKILL)
    assert command.returncode == 130, stderr
    summary = json.loads((out / "batch.json").read_text())
    assert summary["interrupted"] and [row["status"] for row in summary["captures"]] == ["done", "interrupted"]
    assert snapshot(out / "a") == finished and load_fit(out / "a").maps.resolution == 32
    assert not (out / "b").exists()
    resumed = batch.run(manifest, out)
    assert [row["status"] for row in resumed["captures"]] == ["skipped", "done"]
    assert snapshot(out / "a") == finished


@pytest.mark.slow
def test_fresh_process_makes_the_same_outputs_as_fit(captures, tmp_path):
    """A worker whose numba compiled kernels makes its captures in a fresh process (the path after
    an install): the same files as ``freqbrdf fit`` with the same settings, bit for bit, and up to
    date after.

    ``freqbrdf fit`` runs first: where it compiles the kernels (a cold cache, as in a clean checkout)
    it runs again from the cache it wrote, so its files are the cached kernels' results, which the
    fresh process loads too. `pipeline.fit` in this test's process would be compiled code wherever
    this process compiled it (see `freqbrdf.jit`), so it is not the reference."""
    import numpy as np

    from freqbrdf import __version__
    from freqbrdf.images import read_image

    settings = {"texture_res": 16, "evaluate": False, "report": False}
    direct = tmp_path / "direct"
    environment = {key: value for key, value in os.environ.items() if key != RERUN_VARIABLE}  # conftest sets it
    fitted = subprocess.run([sys.executable, "-m", "freqbrdf.cli", "fit", str(captures / "bunny"), "--out", str(direct),
                             "--texture-res", "16", "--quiet"], capture_output=True, text=True, timeout=600,
                            env=environment)
    assert fitted.returncode == 0, fitted.stderr
    out = tmp_path / "out"
    spec = {"name": "a", "capture": str((captures / "bunny").resolve()), "folder": str(out / "a"),
            "work": str(out / batch.WORK_FOLDER / "work" / "a"), "settings": settings,
            "settings_hash": batch.settings_hash(settings), "version": __version__, "hooks": {},
            "attempt": 1, "started_at": time.time()}
    row = tasks.in_fresh_process(spec)
    assert row["status"] == "done" and row["fresh_process"], row
    for name in ("base_color.exr", "roughness.exr", "metallic.exr", "entropy.exr", "roughness_std.exr"):
        assert np.array_equal(read_image(out / "a" / name), read_image(direct / name)), name
    for name in ("spectra.npz", "uncertainty.npz"):
        with np.load(out / "a" / name) as made, np.load(direct / name) as expected:
            assert made.files == expected.files
            for key in made.files:
                assert np.array_equal(made[key], expected[key], equal_nan=made[key].dtype.kind == "f"), key
    entry = batch.ManifestEntry("a", (captures / "bunny").resolve(), settings, "test")
    assert state.up_to_date(entry, out) is not None
