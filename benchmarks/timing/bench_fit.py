"""Time the whole ``freqbrdf fit`` command as a user runs it: a fresh process per run (issue #5).

Each run starts ``freqbrdf fit CAPTURE --out DIR --quiet`` in a new process and records its wall
time (from just before the process starts until it has exited), its CPU seconds and peak resident
memory (wait4: the child's own), the load average before it, and the seconds per stage from the
fit folder's summary.json. What no stage counts (``untimed``: interpreter start, imports, reading
the capture's description, process exit) is the wall time minus the stages. The import time of
the modules a fit needs is measured separately, also in fresh processes. They run with Python's
bytecode cache on, as a user's do (`user_environment`), whatever this machine's environment says.

The default capture is studies/compare_estimators.py's plane (scenes.compare_capture: 64 views of
256 x 256, T = 512), rendered into benchmarks/.cache/ if it is missing.

    python benchmarks/timing/bench_fit.py [--capture plane|bunny|PATH] [--runs 3] [--name bench_fit]
        [--preset default|fast] [--fit-option=--entropy=angular ...] [--baseline GIT_REF]

With ``--profile``, one more fit runs under cProfile (after the timed runs, with the current
sources): the functions that take the most time of their own (numba kernels are one call each)
are saved with the results and printed. cProfile slows Python-level code, not the kernels.

With ``--baseline``, the package's sources at that git ref (``git archive`` into benchmarks/.cache,
put first on PYTHONPATH) are timed too, a run of each in turn, so that before and after meet the
same machine; the table gives both and the ratio of their medians.

A fit at T = 32 first, untimed, has numba compile (or load) the kernels. Prints a table and saves
benchmarks/results/<name>.json. The machine may be shared: the load average is recorded per run,
and the table gives the minimum and the median. Its speed also drifts: before each run a fixed
workload is timed (`_common.control_seconds`), so runs made at different times can be compared
relative to it.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _common and scenes
from _common import control_seconds, machine, save_results
from scenes import COMPARE_SCENES, compare_capture

# The modules a fit imports (cli imports the rest inside the command).
FIT_IMPORTS = "import freqbrdf.cli, freqbrdf.pipeline, freqbrdf.capture.layouts"
STAGES = ("calibrate", "observe", "censored", "estimate", "uncertainty", "surface", "std_calibration", "upsample", "textures", "write")


def fit_command() -> list[str]:
    """The installed console script next to this interpreter, else ``python -m freqbrdf.cli``."""
    script = Path(sys.executable).with_name("freqbrdf")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "freqbrdf.cli"]


def capture_folder(name_or_path: str) -> Path:
    """A capture path as given, or compare_estimators.py's scene of that name (rendered if missing)."""
    if name_or_path not in COMPARE_SCENES:
        return Path(name_or_path)
    return compare_capture(name_or_path)


def user_environment(extra: dict | None = None) -> dict:
    """The environment a user's fit runs in: this process's, with Python's bytecode cache on.

    A machine that sets PYTHONDONTWRITEBYTECODE (sandboxes and CI often do) compiles the package's
    modules from source at every start, which an installed package never does: the fits here
    write and read the cache, as a user's do.
    """
    return {**{key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}, **(extra or {})}


def one_fit(capture: Path, out: Path, options: list[str], env: dict | None = None) -> dict:
    control = control_seconds()
    load = os.getloadavg()[0]
    start = time.perf_counter()
    with tempfile.TemporaryFile() as errors:
        child = subprocess.Popen([*fit_command(), "fit", str(capture), "--out", str(out), "--quiet", *options],
                                 stdout=subprocess.DEVNULL, stderr=errors, env=env or user_environment())
        # The child's own resources (wait4), not the largest of every child so far.
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - start
        child.returncode = os.waitstatus_to_exitcode(status)
        if child.returncode != 0:
            errors.seek(0)
            raise SystemExit(f"freqbrdf fit failed ({child.returncode}):\n{errors.read().decode(errors='replace')}")
    timings = json.loads((out / "summary.json").read_text(encoding="utf-8"))["timings"]
    stages = {stage: timings[stage] for stage in STAGES if stage in timings}
    return {
        "wall_s": wall,
        "cpu_s": usage.ru_utime + usage.ru_stime,
        # System time is mostly page faults: fresh memory is slow to map on this virtual machine.
        "system_cpu_s": usage.ru_stime,
        "peak_rss_mib": usage.ru_maxrss / 1024,
        "load_average_before": round(load, 2),
        "control_s_before": round(control, 4),
        "stages_s": stages,
        "untimed_s": wall - sum(stages.values()),
        "summary_timings_s": timings,
    }


def import_seconds(env: dict | None = None) -> float:
    """Seconds to import the fit's modules in a fresh interpreter."""
    code = f"import time; start = time.perf_counter(); {FIT_IMPORTS}; print(time.perf_counter() - start)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                          env=env or user_environment())
    return float(done.stdout.strip().splitlines()[-1])


def spread(values: list[float]) -> dict:
    return {"min": min(values), "median": statistics.median(values), "max": max(values)}


def fits_in_turn(jobs: dict[str, tuple[Path, list[str]]], pairs: int, scratch: Path, stage: str) -> dict[str, list]:
    """Fit each job (capture, options) once per round in fresh processes (`one_fit`), the order
    alternating between rounds so that the machine's drift falls on all alike, after one untimed
    warm-up each (numba's kernels compiled or loaded); print ``stage``'s seconds of each run."""
    for name, (capture, options) in jobs.items():
        subprocess.run([*fit_command(), "fit", str(capture), "--out", str(scratch / f"warm_{name}"), "--quiet",
                        *options, "--texture-res", "32"], capture_output=True, check=True, env=user_environment())
    runs = {name: [] for name in jobs}
    for round_index in range(pairs):
        order = list(jobs) if round_index % 2 == 0 else list(reversed(jobs))
        for name in order:
            capture, options = jobs[name]
            runs[name].append(one_fit(capture, scratch / name, options))
            print(f"round {round_index + 1} {name}: {runs[name][-1]['wall_s']:.2f} s wall, {stage} "
                  f"{runs[name][-1]['summary_timings_s'].get(stage, 0.0):.2f} s", flush=True)
    return runs


def cost_in_turn(runs: dict[str, list], base: str, other: str) -> dict:
    """The wall time of each job's runs and the cost of ``other`` over ``base``: the ratio of the
    medians and each round's ratio."""
    wall = {name: spread([run["wall_s"] for run in found]) for name, found in runs.items()}
    return {"wall_s": wall, "cost_ratio_median": wall[other]["median"] / wall[base]["median"],
            "pair_ratios": [a["wall_s"] / b["wall_s"] for a, b in zip(runs[other], runs[base])]}


def baseline_sources(ref: str) -> dict:
    """Extract the package's sources at git ``ref``; return an environment that imports them.

    Kept in benchmarks/.cache/baseline_sources/<commit>/, so that numba's cache of that tree's
    kernels (beside its sources) serves the next comparison with the same commit.
    """
    repository = Path(__file__).resolve().parents[2]
    commit = subprocess.run(["git", "-C", str(repository), "rev-parse", ref], capture_output=True, text=True,
                            check=True).stdout.strip()
    folder = repository / "benchmarks" / ".cache" / "baseline_sources" / commit
    if not (folder / "src").is_dir():
        partial = folder.with_name(commit + ".partial")
        shutil.rmtree(partial, ignore_errors=True)
        partial.mkdir(parents=True)
        archive = subprocess.run(["git", "-C", str(repository), "archive", commit, "src"], capture_output=True,
                                 check=True)
        subprocess.run(["tar", "-x", "-C", str(partial)], input=archive.stdout, check=True)
        partial.rename(folder)
    return user_environment({"PYTHONPATH": str(folder / "src")})


PROFILE_ROWS = 25


def profile_summary(capture: Path, out: Path, options: list[str], scratch: Path) -> dict:
    """Fit once under cProfile; return the seconds of the functions that take most time of their own."""
    import pstats

    path = scratch / "fit.prof"
    subprocess.run([sys.executable, "-m", "cProfile", "-o", str(path), "-m", "freqbrdf.cli", "fit", str(capture),
                    "--out", str(out), "--quiet", *options], capture_output=True, check=True, env=user_environment())
    statistics_ = pstats.Stats(str(path))
    total = statistics_.total_tt
    root = str(Path(__file__).resolve().parents[2])
    rows = []
    for (filename, line, function), (_, calls, own, cumulative, _) in statistics_.stats.items():
        rows.append({"function": f"{filename.replace(root + '/', '')}:{line}({function})", "calls": calls,
                     "own_s": own, "cumulative_s": cumulative})
    rows.sort(key=lambda row: -row["own_s"])
    return {"profiled_wall_s": total, "top_by_own_time": rows[:PROFILE_ROWS]}


def profile_table(profile: dict) -> str:
    lines = [f"cProfile of one fit ({profile['profiled_wall_s']:.2f} s profiled): own seconds, share, calls"]
    for row in profile["top_by_own_time"]:
        share = row["own_s"] / profile["profiled_wall_s"]
        lines.append(f"{row['own_s']:7.2f} {share:6.1%} {row['calls']:6d}  {row['function'][-90:]}")
    return "\n".join(lines)


def summarised(runs: list[dict], imports: list[float]) -> dict:
    """Min, median and max of the runs' wall, CPU, stages, untimed and import seconds and the control."""
    return {
        "runs": runs,
        "wall_s": spread([run["wall_s"] for run in runs]),
        "cpu_s": spread([run["cpu_s"] for run in runs]),
        "stages_s": {stage: spread([run["stages_s"].get(stage, 0.0) for run in runs]) for stage in STAGES},
        "untimed_s": spread([run["untimed_s"] for run in runs]),
        "import_s": spread(imports),
        "control_s": spread([run["control_s_before"] for run in runs]),
        "peak_rss_mib": max(run["peak_rss_mib"] for run in runs),
    }


def comparison(baseline: dict, current: dict) -> str:
    """The medians of the baseline and the current sources side by side, with their ratio."""
    rows = [("wall", "wall_s"), ("cpu (user+sys)", "cpu_s")]
    lines = [f"{'median seconds':<20} {'baseline':>9} {'current':>9} {'ratio':>7}"]
    values = [(name, baseline[key]["median"], current[key]["median"]) for name, key in rows]
    values += [(stage, baseline["stages_s"][stage]["median"], current["stages_s"][stage]["median"]) for stage in STAGES]
    values += [("untimed", baseline["untimed_s"]["median"], current["untimed_s"]["median"]),
               ("imports (separate)", baseline["import_s"]["median"], current["import_s"]["median"]),
               ("peak RSS MiB", baseline["peak_rss_mib"], current["peak_rss_mib"])]
    for name, before, after in values:
        ratio = f"{before / after:7.2f}" if after > 0 else "      -"
        lines.append(f"{name:<20} {before:9.2f} {after:9.2f} {ratio}")
    return "\n".join(lines)


def table(runs: list[dict], imports: list[float]) -> str:
    rows = [("wall", [run["wall_s"] for run in runs]), ("cpu (user+sys)", [run["cpu_s"] for run in runs]),
            ("  of which sys", [run["system_cpu_s"] for run in runs])]
    rows += [(stage, [run["stages_s"].get(stage, 0.0) for run in runs]) for stage in STAGES]
    rows += [("untimed", [run["untimed_s"] for run in runs]), ("imports (separate)", imports),
             ("control (_common.control_seconds)", [run["control_s_before"] for run in runs])]
    lines = [f"{'seconds':<20} {'min':>7} {'median':>7} {'max':>7}"]
    for name, values in rows:
        stats = spread(values)
        lines.append(f"{name:<20} {stats['min']:7.2f} {stats['median']:7.2f} {stats['max']:7.2f}")
    loads = ", ".join(f"{run['load_average_before']:.2f}" for run in runs)
    lines.append(f"load average before each run: {loads}; peak RSS {max(run['peak_rss_mib'] for run in runs):.0f} MiB")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--capture", default="plane", help="plane, bunny (compare_estimators.py's) or a path")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--name", default="bench_fit", help="results file stem under benchmarks/results/")
    parser.add_argument("--preset", default="default", help="the fit's --preset (default, fast)")
    parser.add_argument("--fit-option", action="append", default=[],
                        help="one more option for the fit, e.g. --fit-option=--entropy=angular (repeatable)")
    parser.add_argument("--baseline", help="a git ref whose sources are timed too, a run of each in turn")
    parser.add_argument("--profile", action="store_true", help="one more fit under cProfile, summarised")
    args = parser.parse_args(argv)
    options = ([] if args.preset == "default" else ["--preset", args.preset]) + args.fit_option
    capture = capture_folder(args.capture)
    trees = {"current": None}
    runs = {"current": [], "baseline": []}
    imports = {"current": [], "baseline": []}
    with tempfile.TemporaryDirectory(prefix="bench_fit.") as scratch:
        if args.baseline:
            trees = {"baseline": baseline_sources(args.baseline), "current": None}
        for name, env in trees.items():
            # Untimed, at a small texture size: numba compiles the kernels here if its cache is cold
            # (a run that compiles them runs again from the cache, see freqbrdf.jit), not in a timed run.
            subprocess.run([*fit_command(), "fit", str(capture), "--out", str(Path(scratch) / "warm_up"), "--quiet",
                            "--texture-res", "32", *options], capture_output=True, check=True,
                           env=env or user_environment())
        for index in range(args.runs):
            for name, env in trees.items():
                runs[name].append(one_fit(capture, Path(scratch) / "fit", options, env))
                imports[name].append(import_seconds(env))
                print(f"run {index + 1} ({name}): {runs[name][-1]['wall_s']:.2f} s wall, "
                      f"load {runs[name][-1]['load_average_before']:.2f}", flush=True)
        profile = profile_summary(capture, Path(scratch) / "profiled", options, Path(scratch)) if args.profile else None
    result = {
        "benchmark": "freqbrdf fit end to end, fresh process per run (issue #5)",
        **machine(),
        "capture": str(capture),
        "command": [*fit_command(), "fit", str(capture), "--out", "DIR", "--quiet", *options],
        **summarised(runs["current"], imports["current"]),
        "measured": time.strftime("%Y-%m-%d %H:%M"),
    }
    if args.baseline:
        result["baseline"] = {"ref": args.baseline, **summarised(runs["baseline"], imports["baseline"])}
    if profile is not None:
        result["profile"] = profile
    save_results(args.name, result)
    print(table(runs["current"], imports["current"]))
    if profile is not None:
        print("\n" + profile_table(profile))
    if args.baseline:
        print(f"\nbaseline {args.baseline} against the current sources, runs taken in turn:")
        print(comparison(result["baseline"], result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
