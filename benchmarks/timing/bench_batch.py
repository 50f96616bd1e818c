"""Time ``freqbrdf batch`` (Ray) against a plain loop of ``freqbrdf fit`` commands (issue #30).

Eight small captures (bunny, sphere and plane in turn, 16 views of 64 x 64, seeds 0-7; rendered
once into benchmarks/.cache/batch_small_<i>) are fitted at T = 128, fit only (no evaluation, no
report), three ways, each as a user runs it, in a fresh process:

- ``loop``: ``freqbrdf fit CAPTURE --out DIR --texture-res 128 --quiet`` for each capture in turn;
- ``batch_1``: ``freqbrdf batch MANIFEST --out DIR --workers 1 --no-evaluate --no-report`` (one
  capture at a time with the machine's cores as its threads);
- ``batch_2``: the same with ``--workers 2`` (two captures at once, their cores shared).

Each records its wall time (process start to exit) and captures per minute. For the batches,
batch.json gives each capture's time in its worker (``seconds``: load, input hash, fit, write) and
from its submission to Ray until its answer (``wall_seconds``); their difference is what Ray adds
per capture (scheduling, the worker's start for its first capture, moving the task and its answer).
Ray's own start and stop are timed apart (``ray.init`` + ``ray.shutdown`` in a fresh process), and
so is hashing the inputs of one capture (which ``fit`` does not do).

Ray's overhead per capture is set against one T = 512 fit of studies/compare_estimators.py's plane
(scenes.compare_capture: 64 views of 256 x 256), run as ``freqbrdf fit`` and as a batch of one.

    python benchmarks/timing/bench_batch.py [--name bench_batch]

A fit at T = 32 first, untimed, has numba compile (or load) its kernels. Saves
benchmarks/results/<name>.json and prints a table. On a machine of two cores one fit already uses
both, so two workers can gain only what one fit leaves idle (its serial parts, reading files).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import control_seconds, machine, save_results
from freqbrdf.synthetic.synth import SynthSettings, synthesize
from scenes import CACHE, compare_capture

CAPTURES = 8
TEXTURE_RES = 128
MESHES = ("bunny", "sphere", "plane")
SMALL = SynthSettings(views=16, resolution=64, spp=8, texture_res=TEXTURE_RES, test_views=0, envmap="forest")
REFERENCE_RES = 512


def freqbrdf() -> list[str]:
    """The installed console script next to this interpreter, else ``python -m freqbrdf.cli``."""
    script = Path(sys.executable).with_name("freqbrdf")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "freqbrdf.cli"]


def small_captures() -> list[Path]:
    folders = []
    for index in range(CAPTURES):
        folder = CACHE / f"batch_small_{index}"
        if not (folder / "transforms.json").is_file():
            print(f"rendering {folder} (once)", flush=True)
            synthesize(folder, dataclasses.replace(SMALL, mesh=MESHES[index % len(MESHES)], seed=index),
                       progress=False)
        folders.append(folder)
    return folders


def timed(command: list[str]) -> float:
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr}")
    return wall


def loop(captures: list[Path], scratch: Path) -> dict:
    walls = [timed([*freqbrdf(), "fit", str(capture), "--out", str(scratch / "loop" / capture.name),
                    "--texture-res", str(TEXTURE_RES), "--quiet"]) for capture in captures]
    total = sum(walls)
    return {"wall_s": total, "captures_per_minute": 60 * len(captures) / total, "fit_wall_s": walls}


def batch(manifest: Path, out: Path, workers: int) -> dict:
    wall = timed([*freqbrdf(), "batch", str(manifest), "--out", str(out), "--workers", str(workers),
                  "--no-evaluate", "--no-report", "--force", "--quiet"])
    summary = json.loads((out / "batch.json").read_text(encoding="utf-8"))
    rows = summary["captures"]
    assert all(row["status"] == "done" for row in rows), [row["error"] for row in rows]
    seconds = [row["seconds"] for row in rows]
    added = [row["wall_seconds"] - row["seconds"] for row in rows]
    return {
        "wall_s": wall, "captures_per_minute": 60 * len(rows) / wall, "driver_s": summary["seconds"],
        "engine": summary["engine"], "capture_seconds": seconds, "capture_wall_seconds": [r["wall_seconds"] for r in rows],
        "ray_added_per_capture_s": {"first": added[0], "median_of_rest": statistics.median(added[1:] or added),
                                    "all": added},
        "fit_seconds": [row["metrics"]["fit_seconds"] for row in rows],
    }


def ray_start_seconds(runs: int = 2) -> list[float]:
    """ray.init (a local cluster of two CPUs) and ray.shutdown in a fresh process, as a batch does."""
    code = ("import time, logging; start = time.perf_counter(); import ray; "
            "ray.init(address='local', num_cpus=2, include_dashboard=False, log_to_driver=False, "
            "logging_level=logging.ERROR, object_store_memory=256 * 2**20); ray.shutdown(); "
            "print(time.perf_counter() - start)")
    values = []
    for _ in range(runs):
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        values.append(float(done.stdout.strip().splitlines()[-1]))
    return values


def hash_seconds(capture: Path) -> float:
    """Seconds to hash one capture's inputs, as each batch task does (page cache warm)."""
    code = ("import time; from freqbrdf.batch import state; from freqbrdf.capture.layouts import load; "
            f"capture = load({str(capture)!r}); start = time.perf_counter(); "
            "state.input_record(*state.capture_inputs(capture)); print(time.perf_counter() - start)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(done.stdout.strip().splitlines()[-1])


def write_manifest(path: Path, captures: list[Path], texture_res: int) -> Path:
    lines = ["name,capture,texture_res"] + [f"{capture.name},{capture},{texture_res}" for capture in captures]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--name", default="bench_batch", help="results file stem under benchmarks/results/")
    args = parser.parse_args(argv)
    captures = small_captures()
    reference = compare_capture("plane")
    with tempfile.TemporaryDirectory(prefix="bench_batch.") as folder:
        scratch = Path(folder)
        # Untimed: numba compiles the kernels here if its cache is cold, not in a timed run.
        timed([*freqbrdf(), "fit", str(captures[0]), "--out", str(scratch / "warm_up"), "--texture-res", "32",
               "--quiet"])
        manifest = write_manifest(scratch / "small.csv", captures, TEXTURE_RES)
        control = control_seconds()
        results = {"loop": loop(captures, scratch)}
        print(f"loop: {results['loop']['wall_s']:.1f} s", flush=True)
        for workers in (1, 2):
            results[f"batch_{workers}"] = batch(manifest, scratch / f"batch_{workers}", workers)
            print(f"batch, {workers} workers: {results[f'batch_{workers}']['wall_s']:.1f} s", flush=True)
        starts = ray_start_seconds()
        hashing = [hash_seconds(capture) for capture in captures[:3]]
        fit_512 = timed([*freqbrdf(), "fit", str(reference), "--out", str(scratch / "reference"), "--quiet"])
        one = batch(write_manifest(scratch / "reference.csv", [reference], REFERENCE_RES), scratch / "reference_batch",
                    1)
        reference_hash = hash_seconds(reference)
    added = results["batch_1"]["ray_added_per_capture_s"]["median_of_rest"]
    result = {
        "benchmark": "freqbrdf batch (Ray) vs a loop of freqbrdf fit, 8 small captures at T = 128 (issue #30)",
        **machine(),
        "captures": [str(capture) for capture in captures],
        "capture_settings": {key: value for key, value in dataclasses.asdict(SMALL).items() if key != "mesh"}
        | {"meshes": list(MESHES)},
        "texture_res": TEXTURE_RES,
        "control_s": round(control, 4),
        **results,
        "ray_start_and_stop_s": starts,
        "hash_inputs_s_small": hashing,
        "reference": {
            "capture": str(reference), "texture_res": REFERENCE_RES, "fit_command_wall_s": fit_512,
            "batch_of_one": one, "hash_inputs_s": reference_hash,
        },
        "overhead_per_capture": {
            "ray_added_s": added,
            "hash_inputs_s": reference_hash,
            "fraction_of_t512_fit": (added + reference_hash) / fit_512,
            "ray_start_and_stop_s_once_per_batch": statistics.median(starts),
        },
        "measured": time.strftime("%Y-%m-%d %H:%M"),
    }
    save_results(args.name, result)
    print(f"{'':<10} {'wall s':>8} {'captures/min':>13}")
    for key in ("loop", "batch_1", "batch_2"):
        print(f"{key:<10} {results[key]['wall_s']:8.1f} {results[key]['captures_per_minute']:13.1f}")
    print(f"Ray start + stop {statistics.median(starts):.1f} s once per batch; per capture Ray adds {added:.3f} s "
          f"and hashing {reference_hash:.3f} s: {result['overhead_per_capture']['fraction_of_t512_fit']:.1%} of "
          f"a T = 512 fit ({fit_512:.1f} s as a command)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
