"""The Ray task of a batch: one capture's whole job, run in a worker.

`process_capture` is what each capture's Ray task runs (a function at module level, which Ray
pickles by reference to this module): it loads the capture (`freqbrdf.capture.layouts.load`),
hashes its inputs (`freqbrdf.batch.state`), runs the pipeline of docs/method.md#pipeline with the capture's
`Config` (`freqbrdf.pipeline.fit`, `write_fit`), scores it where asked (docs/method.md#evaluation,
`freqbrdf.outputs.evaluate`), writes its report (`freqbrdf.outputs.report`) and records
``batch_entry.json``, all in a work folder that is renamed into ``OUT/<name>/`` when complete.

The task runs the same code as ``freqbrdf fit``, with numba's threads set to the task's CPUs (the
driver sets ``NUMBA_NUM_THREADS`` in the task's environment). A worker whose numba compiled
kernels (a cold cache) makes its captures in a fresh process (`in_fresh_process`), whose kernels
come from the cache, so that the results match every later run's (see `freqbrdf.jit`).
`worker_facts` is the small task that checks each node before any capture is sent.

Ray retries a capture whose worker or node died; a retry that finds the capture already made by
this run (``batch_entry.json`` with the run's id, the folder complete) answers with it instead of
fitting it again (`_made_in_this_run`).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from freqbrdf import __version__
from freqbrdf.batch.settings import capture_config, full_settings
from freqbrdf.batch.state import (
    ENTRY_FILE,
    capture_inputs,
    input_record,
    publish,
    record_attempt,
    recover,
    timestamp,
)
from freqbrdf.errors import InputError
from freqbrdf.fileio import write_json
from freqbrdf.progress import SILENT, Reporter


def process_capture(spec: dict) -> dict:
    """Fit, evaluate and report one capture into ``spec["folder"]``: the Ray task of a capture.

    Bad input and other exceptions become status "failed" with a one-line error; only the
    worker's death (or a fresh process killed by a signal) ends the task without an answer, which
    Ray retries.

    Parameters
    ----------
    spec : dict
        What the driver sends (JSON-compatible): ``name``, ``capture`` (its path), ``folder``
        (``OUT/<name>``, absolute), ``work`` (its work folder), ``attempts`` (its attempts file),
        ``settings`` and ``settings_hash`` (`freqbrdf.batch.settings`), ``version`` (the driver's
        freqbrdf) and ``hooks`` (the test hooks, ``{}`` outside the tests).

    Returns
    -------
    dict
        The fields of its row in batch.json: ``status`` ("done" or "failed"), ``error``,
        ``metrics``, ``evaluated``, ``attempts``, ``worker`` (host, pid, numba threads),
        ``seconds`` (in this worker), and ``input_hash`` where done.
    """
    start = time.perf_counter()
    node = _node_id()
    attempt = record_attempt(Path(spec["attempts"]), node) if spec.get("attempts") else 1
    hooks = spec.get("hooks", {})
    delay = float(hooks.get("sleep_s", {}).get(spec["name"], 0.0))
    if attempt == 1:
        delay += float(hooks.get("first_attempt_sleep_s", 0.0))
    if delay > 0:
        time.sleep(delay)
    spec = {**spec, "attempt": attempt, "started_at": time.time(), "node": node}
    row = {"attempts": attempt, "worker": {"host": socket.gethostname(), "pid": os.getpid(), "node": node}}
    try:
        if spec["version"] != __version__:
            raise InputError(None, f"this worker has freqbrdf {__version__}, the batch {spec['version']}: install the "
                                   "same version on every node")
        made = _made_in_this_run(spec)
        if made is not None:
            row.update(made)
        elif not spec.get("child") and _compiled_here():
            row.update(in_fresh_process(spec))
        else:
            row.update(_make_outputs(spec, kill=spec["name"] in hooks.get("kill_first_attempt", ()) and attempt == 1))
    except InputError as err:
        row.update(status="failed", error=str(err))
    except MemoryError as err:
        row.update(status="failed", error=f"out of memory ({err or 'MemoryError'}); a smaller texture_res needs less")
    except Exception as err:  # noqa: BLE001 - any other failure is this capture's, not the batch's
        row.update(status="failed", error=f"{type(err).__name__}: {err}".splitlines()[0])
    if "numba" in sys.modules:  # the threads its fits ran with (NUMBA_NUM_THREADS, set per task)
        row["worker"]["threads"] = sys.modules["numba"].config.NUMBA_NUM_THREADS
    row["seconds"] = time.perf_counter() - start
    return row


def _made_in_this_run(spec: dict) -> dict | None:
    """Answer for a capture this batch run has already made, without making it again.

    An attempt whose worker or node died after the capture's folder was renamed into place (or
    while it was) leaves it complete; Ray's retry then finds it here (put back by `recover` where
    half renamed) with this run's id in its ``batch_entry.json``.
    """
    if not spec.get("run"):
        return None
    folder = Path(spec["folder"])
    recover(Path(spec["work"]), folder)
    try:
        entry = json.loads((folder / ENTRY_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(entry, dict) or entry.get("run") != spec["run"] \
            or entry.get("settings_hash") != spec["settings_hash"]:
        return None
    for relative, size in entry.get("outputs", {}).items():
        path = folder / relative
        if not path.is_file() or path.stat().st_size != size:
            return None
    return {"status": "done", "error": None, "metrics": entry.get("metrics"), "evaluated": entry.get("evaluated"),
            "input_hash": entry.get("inputs", {}).get("hash"), "made_by_attempt": entry.get("attempts")}


def _compiled_here() -> bool:
    from freqbrdf.jit import compiled_here

    return bool(compiled_here())


class _KillAtFirstStage(Reporter):
    """A silent reporter that kills its own process when the fit's first stage starts (test hook)."""

    def __init__(self):
        super().__init__(enabled=False)

    @contextlib.contextmanager
    def stage(self, description: str, total: int) -> Iterator:
        os.kill(os.getpid(), signal.SIGKILL)
        yield lambda steps=1: None


def _make_outputs(spec: dict, kill: bool = False) -> dict:
    from freqbrdf import pipeline
    from freqbrdf.capture.layouts import load

    settings = spec["settings"]
    capture = load(spec["capture"])
    inputs = input_record(*capture_inputs(capture))
    config = capture_config(settings)
    result = pipeline.fit(capture, config, _KillAtFirstStage() if kill else SILENT)
    if not spec.get("child") and _compiled_here():
        # numba compiled kernels in this worker: their results differ in the last bits from the
        # cached kernels' (freqbrdf.jit); the fresh process loads those from the cache just written.
        return in_fresh_process(spec)
    evaluate = settings.get("evaluate", "auto")
    if evaluate == "auto":
        evaluate = capture.ground_truth is not None or bool(capture.test_frames)
    work, folder = Path(spec["work"]), Path(spec["folder"])
    shutil.rmtree(work, ignore_errors=True)  # what a killed attempt left
    staging = work / "new"
    pipeline.write_fit(staging, result, config)
    del result
    if evaluate:
        from freqbrdf.outputs.evaluate import evaluate_fit
        from freqbrdf.outputs.fit_folder import load_fit
        from freqbrdf.outputs.relight import RelightSettings

        evaluate_fit(load_fit(staging), capture, staging / "evaluation", RelightSettings(spp=settings.get("spp", 64)))
        metrics_path = staging / "evaluation" / "metrics.json"
        document = json.loads(metrics_path.read_text(encoding="utf-8"))
        document["fit"] = str(folder)  # where the fit will be, not where it was made
        write_json(metrics_path, document)
    if settings.get("report", True):
        from freqbrdf.outputs.report import write_report

        write_report(staging)
    metrics = _metrics(staging)
    outputs = {str(path.relative_to(staging)): path.stat().st_size
               for path in sorted(staging.rglob("*")) if path.is_file()}
    entry = {
        "name": spec["name"], "capture": spec["capture"], "freqbrdf": __version__,
        "settings": full_settings(settings), "settings_hash": spec["settings_hash"],
        "inputs": inputs, "outputs": outputs, "evaluated": bool(evaluate), "metrics": metrics,
        "finished": timestamp(), "seconds": time.time() - spec.get("started_at", time.time()),
        "attempts": spec.get("attempt", 1), "run": spec.get("run"),
        "worker": {"host": socket.gethostname(), "pid": os.getpid(), "node": spec.get("node")},
    }
    write_json(staging / ENTRY_FILE, entry)
    publish(staging, folder, work / "old")
    shutil.rmtree(work, ignore_errors=True)
    return {"status": "done", "error": None, "metrics": metrics, "evaluated": bool(evaluate),
            "input_hash": inputs["hash"]}


def _metrics(folder: Path) -> dict:
    """Collect the key figures of a fit folder.

    Coverage, mean entropy and fit seconds, and the evaluation's texture and relighting scores
    where it has them.
    """
    summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    metrics = {"observed_fraction": summary.get("coverage", {}).get("observed_fraction"),
               "entropy_mean": summary.get("uncertainty", {}).get("entropy_mean"),
               "fit_seconds": summary.get("timings", {}).get("total")}
    path = folder / "evaluation" / "metrics.json"
    if path.is_file():
        document = json.loads(path.read_text(encoding="utf-8"))
        for section, keys in (("texture", ("base_color_psnr", "roughness_mae", "metallic_mae")),
                              ("relighting", ("psnr_hdr", "psnr_ldr", "ssim", "lpips"))):
            values = document.get(section) or {}
            metrics.update({key: values[key] for key in keys if key in values})
    return metrics


def in_fresh_process(spec: dict) -> dict:
    """Make a capture's outputs in a new interpreter (`child_main`).

    A worker whose numba compiled kernels (a cold cache) does so, so that the kernels come from the
    cache just written and the results match every later run's (see `freqbrdf.jit`). A child
    killed by a signal kills this worker too, for Ray to retry the capture.

    Parameters
    ----------
    spec : dict
        The capture's task, as `process_capture` takes it (with its ``attempt`` and
        ``started_at``).

    Returns
    -------
    dict
        The child's answer (as `process_capture`'s, without ``attempts``, ``worker`` and
        ``seconds``) with ``fresh_process`` True, or status "failed" with the child's last line of
        error output.
    """
    child = subprocess.run([sys.executable, "-c", "from freqbrdf.batch.tasks import child_main; child_main()"],
                           input=json.dumps({**spec, "child": True}), capture_output=True, text=True)
    if child.returncode < 0:
        os.kill(os.getpid(), signal.SIGKILL)
    lines = child.stdout.strip().splitlines()
    if child.returncode != 0 or not lines:
        last = (child.stderr.strip().splitlines() or [f"exit code {child.returncode}"])[-1]
        return {"status": "failed", "error": f"the capture's fresh process failed: {last}"}
    return {**json.loads(lines[-1]), "fresh_process": True}


def child_main() -> None:
    """Make one capture's outputs as the entry of `in_fresh_process`'s interpreter.

    It reads the spec as JSON on stdin and prints the answer as JSON on stdout's last line; it
    exits when its parent (the worker) does.
    """
    spec = json.loads(sys.stdin.read())
    parent = os.getppid()

    def exit_with_parent():  # a worker killed (or cancelled) takes its capture with it
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=exit_with_parent, daemon=True).start()
    try:
        row = _make_outputs(spec)
    except InputError as err:
        row = {"status": "failed", "error": str(err)}
    except Exception as err:  # noqa: BLE001
        row = {"status": "failed", "error": f"{type(err).__name__}: {err}".splitlines()[0]}
    print(json.dumps(row, default=str), flush=True)


def worker_facts(paths: list[str] = (), out: str | None = None) -> dict:
    """Tell what a Ray worker runs and sees (`freqbrdf.batch.cluster.check_workers` asks).

    Parameters
    ----------
    paths : list of str
        Paths the worker should see (the captures).
    out : str, optional
        A folder the worker should be able to write to (the batch's output folder).

    Returns
    -------
    dict
        ``freqbrdf`` (its version), ``host`` (hostname), ``node`` (Ray's node id), ``missing``
        (those of ``paths`` it does not see) and ``writable`` (whether it can write to ``out``;
        True where none is given).
    """
    return {"freqbrdf": __version__, "host": socket.gethostname(), "node": _node_id(),
            "missing": [path for path in paths if not os.path.exists(path)],
            "writable": out is None or (os.path.isdir(out) and os.access(out, os.W_OK | os.X_OK))}


def _node_id() -> str | None:
    """Tell the Ray node this process runs on, None outside a Ray worker."""
    ray = sys.modules.get("ray")
    if ray is None or not ray.is_initialized():
        return None
    return ray.get_runtime_context().get_node_id()
