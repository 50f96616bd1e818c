"""How ``freqbrdf batch`` (Ray) scales with workers and nodes, and what Ray adds to each capture.

Eight small captures (bunny, sphere and plane in turn, 16 views of 64 x 64, seeds 0-7; rendered
once into benchmarks/.cache/batch_small_<i>) are fitted at T = 128, fit only (no evaluation, no
report), each way in a fresh process as a user runs it:

- ``loop``: ``freqbrdf fit CAPTURE --out DIR --texture-res 128 --quiet`` for each capture in turn
  (a plain fit: its command's wall time is what each capture's overhead is set against);
- ``local_w<W>_t<T>``: ``freqbrdf batch MANIFEST --out DIR --workers W --threads T`` on the Ray it
  starts on this machine: W = 1 with T = 2 (one capture at a time on the cores, as ``fit``), and
  W = 1, 2, 4 with T = 1 (the throughput's growth with workers);
- ``cluster_w<W>_t1``: the same with ``--address`` on a two-node cluster on this machine (``ray
  start --head`` and ``ray start --address``, one CPU each, token authentication as Ray's
  documentation sets it up), W = 1 and 2.

Throughput is captures per minute over the batch's dispatch (from its first task sent to its last
answer, ``engine.dispatch_s`` of batch.json) and over the command's whole wall time (Ray's start
included). Each worker's first capture pays the worker's start (imports, numba's cache): the
median seconds in the worker of first and of later captures are recorded apart. What Ray adds to each capture: the time from sending its task to its answer less the
time the task ran in its worker (``wall_seconds - seconds`` of batch.json: scheduling, the
task's and the answer's transfer), hashing its inputs (which ``fit`` does not do), and Ray's own
start and stop (``ray.init`` + ``ray.shutdown`` in a fresh process) shared among the captures of
a batch. The control workloads, timed before and after: `_common.control_seconds` (the machine's
speed at the moment) and a fixed one-thread workload run once alone and then as two processes at
once (the parallel speed-up the machine gives at the moment, the ceiling of two workers' gain).

    python benchmarks/timing/bench_batch.py [--name bench_batch]

A fit at T = 32 first, untimed, has numba compile (or load) its kernels. Saves
benchmarks/results/<name>.json and prints a table.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import secrets
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
import freqbrdf
from _common import control_seconds, machine, save_results
from freqbrdf.synthetic.synth import SynthSettings, synthesize
from scenes import CACHE

CAPTURES = 8
TEXTURE_RES = 128
MESHES = ("bunny", "sphere", "plane")
SMALL = SynthSettings(views=16, resolution=64, spp=8, texture_res=TEXTURE_RES, test_views=0, envmap="forest")
LOCAL_RUNS = ((1, 2), (1, 1), (2, 1), (4, 1))  # (workers, threads)
CLUSTER_RUNS = ((1, 1), (2, 1))
ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
CONTROL_CODE = ("import time, numpy as np; values = np.random.default_rng(0).standard_normal(3_000_000); "
                "start = time.perf_counter(); [np.sort(values) for _ in range(12)]; print(time.perf_counter() - start)")


def freqbrdf_command() -> list[str]:
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


def timed(command: list[str], env: dict | None = None) -> float:
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr}")
    return wall


def parallel_control() -> dict:
    """A one-thread workload alone, then as two processes at once: the speed-up the cores give now."""
    environment = {**os.environ, **ONE_THREAD}

    def run(count: int) -> float:
        start = time.perf_counter()
        processes = [subprocess.Popen([sys.executable, "-c", CONTROL_CODE], env=environment, stdout=subprocess.PIPE,
                                      text=True) for _ in range(count)]
        for process in processes:
            process.communicate()
        return time.perf_counter() - start

    run(1)  # warms the interpreter's and the workload's files: the first start is slower than the others
    one, two = run(1), run(2)
    return {"one_process_s": one, "two_processes_s": two, "speedup_of_two": 2 * one / two}


def loop(captures: list[Path], scratch: Path) -> dict:
    walls = [timed([*freqbrdf_command(), "fit", str(capture), "--out", str(scratch / "loop" / capture.name),
                    "--texture-res", str(TEXTURE_RES), "--quiet"]) for capture in captures]
    total = sum(walls)
    return {"wall_s": total, "captures_per_minute": 60 * len(captures) / total, "fit_wall_s": walls,
            "fit_wall_median_s": statistics.median(walls)}


def batch(manifest: Path, out: Path, workers: int, threads: int, address: str | None = None,
          env: dict | None = None) -> dict:
    command = [*freqbrdf_command(), "batch", str(manifest), "--out", str(out), "--workers", str(workers),
               "--threads", str(threads), "--no-evaluate", "--no-report", "--force", "--quiet"]
    wall = timed(command + (["--address", address] if address else []), env)
    summary = json.loads((out / "batch.json").read_text(encoding="utf-8"))
    rows = summary["captures"]
    assert all(row["status"] == "done" for row in rows), [row["error"] for row in rows]
    added = [row["wall_seconds"] - row["seconds"] for row in rows]
    dispatch = summary["engine"]["dispatch_s"]
    workers_seen, first, later = set(), [], []  # a worker's first capture pays its start (imports, numba's cache)
    for row in rows:
        key = (row["worker"].get("node"), row["worker"]["pid"])
        (later if key in workers_seen else first).append(row["seconds"])
        workers_seen.add(key)
    return {
        "workers": workers, "threads": threads, "wall_s": wall, "driver_s": summary["seconds"],
        "dispatch_s": dispatch, "captures_per_minute": 60 * len(rows) / dispatch,
        "captures_per_minute_wall": 60 * len(rows) / wall,
        "engine": summary["engine"], "capture_seconds": [row["seconds"] for row in rows],
        "ray_added_per_capture_s": {"first": added[0], "median_of_rest": statistics.median(added[1:] or added),
                                    "all": added},
        "nodes_used": len({row["worker"].get("node") for row in rows}),
        "first_capture_seconds_median": statistics.median(first),
        "later_capture_seconds_median": statistics.median(later) if later else None,
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


@contextlib.contextmanager
def two_node_cluster(scratch: Path):
    """A head and a worker node of one CPU each on this machine (``ray start``, token authentication).

    Yields the head's address and the environment a batch joins it with (the token's file).
    """
    token = scratch / "auth_token"
    token.write_text(secrets.token_hex(32), encoding="ascii")
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    environment = {key: value for key, value in os.environ.items() if not key.startswith("RAY_")}
    node_environment = {**environment, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": str(token)}
    ray = str(Path(sys.executable).with_name("ray"))
    groups, temps = [], []
    try:
        for where in (["--head", "--port", str(port), "--include-dashboard", "false"],
                      ["--address", f"127.0.0.1:{port}"]):
            temps.append(tempfile.mkdtemp(prefix="ray", dir="/tmp"))  # short: Ray's socket paths are limited
            process = subprocess.Popen([ray, "start", *where, "--num-cpus", "1", "--disable-usage-stats",
                                        "--object-store-memory", str(200 * 2**20), "--temp-dir", temps[-1]],
                                       env=node_environment, start_new_session=True, stdout=subprocess.DEVNULL,
                                       stderr=subprocess.PIPE, text=True)
            groups.append(process.pid)
            if process.wait(timeout=300) != 0:
                raise SystemExit(f"ray start failed:\n{process.stderr.read()}")
        yield f"127.0.0.1:{port}", {**environment, "RAY_AUTH_TOKEN_PATH": str(token)}
    finally:
        for group in groups:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(group, signal.SIGKILL)
        time.sleep(1.0)
        listing = subprocess.run(["ps", "-ww", "-eo", "pid=,args="], capture_output=True, text=True).stdout
        for line in listing.splitlines():  # workers (each a process group of its own) left by the nodes
            if any(temp in line for temp in temps):
                with contextlib.suppress(ProcessLookupError, ValueError):
                    os.kill(int(line.split()[0]), signal.SIGKILL)
        for temp in temps:
            shutil.rmtree(temp, ignore_errors=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--name", default="bench_batch", help="results file stem under benchmarks/results/")
    args = parser.parse_args(argv)
    captures = small_captures()
    with tempfile.TemporaryDirectory(prefix="bench_batch.") as folder:
        scratch = Path(folder)
        # Untimed: numba compiles the kernels here if its cache is cold, not in a timed run.
        timed([*freqbrdf_command(), "fit", str(captures[0]), "--out", str(scratch / "warm_up"), "--texture-res", "32",
               "--quiet"])
        manifest = write_manifest(scratch / "small.csv", captures, TEXTURE_RES)
        control_before, parallel_before = control_seconds(), parallel_control()
        results = {"loop": loop(captures, scratch)}
        print(f"loop of fit: {results['loop']['wall_s']:.1f} s", flush=True)
        for workers, threads in LOCAL_RUNS:
            key = f"local_w{workers}_t{threads}"
            results[key] = batch(manifest, scratch / key, workers, threads)
            print(f"{key}: {results[key]['wall_s']:.1f} s", flush=True)
        with two_node_cluster(scratch) as (address, environment):
            for workers, threads in CLUSTER_RUNS:
                key = f"cluster_w{workers}_t{threads}"
                results[key] = batch(manifest, scratch / key, workers, threads, address, environment)
                print(f"{key}: {results[key]['wall_s']:.1f} s", flush=True)
        starts = ray_start_seconds()
        hashing = [hash_seconds(capture) for capture in captures[:3]]
        control_after, parallel_after = control_seconds(), parallel_control()
    fit_wall = results["loop"]["fit_wall_median_s"]
    same = results["local_w1_t2"]  # one capture at a time on the cores, as a fit
    added = same["ray_added_per_capture_s"]["median_of_rest"]
    start_share = statistics.median(starts) / CAPTURES
    hashing_s = statistics.median(hashing)
    overhead = added + hashing_s  # what each capture pays, however many a batch holds
    one, two = results["local_w1_t1"]["captures_per_minute"], results["local_w2_t1"]["captures_per_minute"]
    cluster_one, cluster_two = (results["cluster_w1_t1"]["captures_per_minute"],
                                results["cluster_w2_t1"]["captures_per_minute"])
    result = {
        "benchmark": "freqbrdf batch (Ray): throughput with 1, 2, 4 workers on one machine and on a two-node local "
                     "cluster; what Ray adds per capture against a plain freqbrdf fit (8 small captures, T = 128)",
        **machine(),
        "freqbrdf_source": str(Path(freqbrdf.__file__).resolve().parent),
        "captures": [str(capture) for capture in captures],
        "capture_settings": {key: value for key, value in dataclasses.asdict(SMALL).items() if key != "mesh"}
        | {"meshes": list(MESHES)},
        "texture_res": TEXTURE_RES,
        "control": {"control_s_before": round(control_before, 4), "control_s_after": round(control_after, 4),
                    "parallel_before": parallel_before, "parallel_after": parallel_after},
        **results,
        "ray_start_and_stop_s": starts,
        "hash_inputs_s": hashing,
        "overhead_per_capture": {
            "ray_dispatch_and_transfer_s": added, "hash_inputs_s": hashing_s, "per_capture_s": overhead,
            "plain_fit_wall_s": fit_wall, "fraction_of_fit": overhead / fit_wall, "target_fraction": 0.05,
            "ray_start_and_stop_s_once_per_batch": statistics.median(starts),
            "ray_start_share_s_over_these_captures": start_share,
            "fraction_of_fit_with_start_share": (overhead + start_share) / fit_wall,
        },
        "scaling": {
            "local_two_over_one_worker": two / one, "cluster_two_over_one_worker": cluster_two / cluster_one,
            "local_four_over_one_worker": results["local_w4_t1"]["captures_per_minute"] / one,
            "control_speedup_of_two_processes": [parallel_before["speedup_of_two"], parallel_after["speedup_of_two"]],
            "target_two_over_one": 1.8,
        },
        "measured": time.strftime("%Y-%m-%d %H:%M"),
    }
    save_results(args.name, result)
    print(f"\n{os.cpu_count()} cores, load average {result['load_average']}")
    print(f"{'':<16} {'workers':>7} {'threads':>7} {'wall s':>8} {'dispatch s':>10} {'captures/min':>13} "
          f"{'first s':>8} {'later s':>8}")
    print(f"{'loop of fit':<16} {1:>7} {'all':>7} {results['loop']['wall_s']:8.1f} {'':>10} "
          f"{results['loop']['captures_per_minute']:13.1f}")
    for key, value in results.items():
        if key != "loop":
            print(f"{key:<16} {value['workers']:>7} {value['threads']:>7} {value['wall_s']:8.1f} "
                  f"{value['dispatch_s']:10.1f} {value['captures_per_minute']:13.1f} "
                  f"{value['first_capture_seconds_median']:8.2f} {value['later_capture_seconds_median']:8.2f}")
    print(f"2 workers / 1: {two / one:.2f}x here, {cluster_two / cluster_one:.2f}x on the two-node cluster; two "
          f"control processes at once: {parallel_before['speedup_of_two']:.2f}x / {parallel_after['speedup_of_two']:.2f}x")
    print(f"per capture Ray adds {added:.3f} s and hashing {hashing_s:.3f} s: {overhead / fit_wall:.1%} of a plain "
          f"fit ({fit_wall:.1f} s as a command); Ray's start and stop, once per batch, "
          f"{statistics.median(starts):.1f} s ({(overhead + start_share) / fit_wall:.1%} with its share over "
          f"{CAPTURES} captures)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
