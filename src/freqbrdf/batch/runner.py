"""The driver of a batch: scheduling the captures on Ray, retries, interruption and progress.

`run` checks the whole manifest (`freqbrdf.batch.manifest`) and the output folder before any work,
takes the batch's lock, marks each capture skipped (up to date: `freqbrdf.batch.state`) or
pending, starts or joins Ray (`freqbrdf.batch.cluster`) and sends the pending captures as Ray
tasks (`freqbrdf.batch.tasks.process_capture`), at most ``workers`` at once, each with its CPUs
and memory. Ray retries a task whose worker or node died, at most `MAX_RETRIES` times, on any live
node; a capture that fails otherwise is recorded with its one-line error. After every capture, batch.json and
index.html are rewritten (`freqbrdf.batch.index`). Ctrl-C (or SIGTERM) cancels the captures in
flight, records them as "interrupted" and raises `BatchInterrupted`; a rerun goes on from there.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import threading
import time
import uuid
from pathlib import Path

from freqbrdf import __version__
from freqbrdf.batch.cluster import (
    FIT_THREADS,
    MAX_RETRIES,
    check_workers,
    default_workers,
    fit_memory,
    join_cluster,
    largest_node,
    last_line,
    parse_address,
    start_local_ray,
)
from freqbrdf.batch.index import INDEX_FILE, write_summary
from freqbrdf.batch.manifest import ManifestEntry, read_manifest
from freqbrdf.batch.settings import capture_config, full_settings, settings_hash
from freqbrdf.batch.state import WORK_FOLDER, count_attempts, locked, recover, timestamp, up_to_date
from freqbrdf.batch.tasks import process_capture
from freqbrdf.errors import InputError
from freqbrdf.fileio import check_output_path
from freqbrdf.progress import SILENT, Reporter

STATUSES = ("done", "skipped", "failed", "interrupted")
# Test-only fault injection, read by `run` from its environment: a JSON object with
# "kill_first_attempt": [names] (the first attempt of each kills its own worker with SIGKILL when
# the fit starts, as the kernel's out-of-memory killer would), "sleep_s": {name: seconds} (the
# capture waits that long before it starts) and "first_attempt_sleep_s": seconds (every capture's
# first attempt waits that long, holding it in flight). Unset, nothing changes.
TEST_HOOKS_VARIABLE = "FREQBRDF_BATCH_TEST_HOOKS"


class BatchInterrupted(KeyboardInterrupt):
    """The batch was interrupted (Ctrl-C or SIGTERM); ``summary`` is what `run` wrote to batch.json.

    Parameters
    ----------
    summary : dict
        The batch summary, with status "interrupted" for every capture that did not finish.
    signal_number : int
        The signal that stopped it (``signal.SIGINT`` for Ctrl-C).
    """

    def __init__(self, summary: dict, signal_number: int = signal.SIGINT):
        super().__init__("batch interrupted")
        self.summary = summary
        self.signal_number = signal_number


def _texture_res(entry: ManifestEntry) -> int:
    return capture_config(entry.settings).texels.texture_res


def run(manifest: str | Path, out: str | Path, *, workers: int | None = None, threads: int | None = None,
        address: str | None = None, force: bool = False, defaults: dict | None = None,
        reporter: Reporter = SILENT) -> dict:
    """Fit every capture of a manifest into ``out/<name>/`` with Ray; the batch's summary.

    The whole manifest is checked first (`read_manifest`: InputError on any problem, before any
    work). Captures whose outputs are complete and up to date are skipped unless ``force``. Ray
    starts on this machine unless it already runs in this process or ``address`` names a cluster
    (whose nodes need this freqbrdf version and the captures and ``out`` at the same paths).
    ``out/batch.json`` and ``out/index.html`` are rewritten after every capture.

    Parameters
    ----------
    manifest : str or Path
        CSV or JSON Lines file, or a folder of captures (see `read_manifest`).
    out : str or Path
        The batch's output folder.
    workers : int, optional
        Captures at once (default: `default_workers` on this machine, or as many as the
        cluster's CPUs give ``threads`` each).
    threads : int, optional
        CPUs and numba threads per capture (default: `FIT_THREADS`, or this machine's cores
        shared among ``workers`` when those are given; at most its cores).
    address : str, optional
        A Ray cluster's address (``"auto"``, ``"ray://host:10001"``, ``"host:6379"``).
    force : bool
        Redo captures whose outputs are up to date.
    defaults : dict, optional
        Settings for every capture its manifest line does not set (keys of `SETTINGS`).
    reporter : Reporter
        Progress over the captures (and the running ones) on its console when enabled.

    Returns
    -------
    dict
        The content of batch.json: ``captures`` (one dict per capture: name, capture, status
        among `STATUSES`, seconds (in its worker), wall_seconds (from its submission to Ray until
        its answer), attempts, error, metrics, paths, settings), ``counts`` per status,
        ``engine`` (Ray's version, address, live nodes, CPUs, workers, threads, ``cluster``: what
        `join_cluster` joined where ``address`` is given, ``dispatch_s``: seconds from the first
        task sent to the last answer), times and the freqbrdf version.

    Raises
    ------
    InputError
        For a problem of the manifest, the output folder or the arguments, for a Ray cluster
        that does not answer or whose workers cannot run this freqbrdf, and where another batch
        writes to ``out``; before any capture is sent.
    BatchInterrupted
        On Ctrl-C or SIGTERM, after batch.json records what finished.

    Examples
    --------
    A manifest of one tiny synthetic capture (JSON Lines: one capture a line), checked as `run`
    checks it before any work (`read_manifest`). The run itself starts Ray and its workers, which
    takes longer than an example should, so its two lines are shown but not run here
    (``tests/batch`` runs batches):

    >>> import json
    >>> import tempfile
    >>> from pathlib import Path
    >>> from freqbrdf import batch
    >>> from freqbrdf.synthetic import example_capture
    >>> work = tempfile.TemporaryDirectory()
    >>> root = Path(work.name)
    >>> _ = example_capture(root / "captures" / "sphere")
    >>> line = {"name": "ball", "capture": "captures/sphere", "texture_res": 32, "report": False}
    >>> _ = (root / "captures.jsonl").write_text(json.dumps(line))
    >>> [(entry.name, entry.capture.name, entry.settings) for entry in batch.read_manifest(root / "captures.jsonl")]
    [('ball', 'sphere', {'texture_res': 32, 'report': False})]
    >>> summary = batch.run(root / "captures.jsonl", root / "out", workers=1)  # doctest: +SKIP
    >>> summary["counts"]  # doctest: +SKIP
    {'done': 1, 'skipped': 0, 'failed': 0, 'interrupted': 0}
    >>> work.cleanup()
    """
    manifest, out = Path(manifest), Path(out)
    entries = read_manifest(manifest, defaults)
    check_output_path(out, folder=True)
    resolved_out = out.resolve()
    for entry in entries:
        root, folder = entry.root.resolve(), resolved_out / entry.name
        if resolved_out == root or root in resolved_out.parents:
            raise InputError(out, f"output folder lies in capture {entry.name} ({root}), whose inputs it would "
                                  "change; choose another --out")
        if root == folder or folder in root.parents:
            raise InputError(out, f"writing {folder} would replace capture {entry.name} ({root}); choose another "
                                  "--out or name")
    if workers is not None and workers < 1:
        raise InputError(None, f"workers must be >= 1, got {workers}")
    if threads is not None and threads < 1:
        raise InputError(None, f"threads must be >= 1, got {threads}")
    if address is not None:
        parse_address(address)
    hooks = _test_hooks()
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    batch = _Batch(manifest, out, entries, reporter)
    try:
        with locked(out):
            batch.plan(force)
            to_run = [entry for entry in entries if batch.rows[entry.name]["status"] == "pending"]
            if to_run:
                batch.dispatch(to_run, workers, threads, address, hooks)
            batch.finish()
    except InputError:
        if created:  # refused before any capture was sent (Ray or the cluster): leave no folder behind
            with contextlib.suppress(OSError):
                out.rmdir()
        raise
    return batch.summary()


def _test_hooks() -> dict:
    text = os.environ.get(TEST_HOOKS_VARIABLE)
    if not text:
        return {}
    try:
        hooks = json.loads(text)
    except json.JSONDecodeError as err:
        raise InputError(None, f"{TEST_HOOKS_VARIABLE} is not JSON: {err.msg}") from None
    return hooks if isinstance(hooks, dict) else {}


class _Batch:
    """The rows of batch.json as the captures finish, and the driver's loop."""

    def __init__(self, manifest: Path, out: Path, entries: list[ManifestEntry], reporter: Reporter):
        self.manifest, self.out, self.entries, self.reporter = manifest, out, entries, reporter
        self.rows: dict[str, dict] = {}
        self.started, self.start = timestamp(), time.perf_counter()
        self.finished: str | None = None
        self.seconds: float | None = None  # the whole batch's, once finished
        self.engine: dict = {}
        self.run_id = uuid.uuid4().hex[:12]
        self.interrupted = False
        self.display = _Display(reporter, len(entries))

    # -- rows

    def _row(self, entry: ManifestEntry, status: str, **fields) -> dict:
        return {"name": entry.name, "capture": str(entry.capture), "where": entry.where, "status": status,
                "seconds": None, "attempts": 0, "error": None, "metrics": None,
                "paths": {"folder": entry.name, "report": None, "metrics": None},
                "settings": full_settings(entry.settings), **fields}

    def plan(self, force: bool) -> None:
        """Mark each capture skipped (up to date, unless ``force``) or pending.

        The attempts files of earlier runs are removed: under the lock, those runs are over (a
        driver that was killed leaves its own).
        """
        shutil.rmtree(self.out / WORK_FOLDER / "runs", ignore_errors=True)
        for entry in self.entries:
            recover(self.out / WORK_FOLDER / "work" / entry.name, self.out / entry.name)
            record = None if force else up_to_date(entry, self.out)
            if record is None:
                self.rows[entry.name] = self._row(entry, "pending")
            else:
                self.rows[entry.name] = self._row(
                    entry, "skipped", seconds=record.get("seconds"), attempts=record.get("attempts", 1),
                    metrics=record.get("metrics"), finished=record.get("finished"))
                self._paths(entry.name)
        self.display.start(sum(row["status"] == "skipped" for row in self.rows.values()))

    def _paths(self, name: str) -> None:
        folder = self.out / name
        self.rows[name]["paths"] = {
            "folder": name,
            "report": f"{name}/report/report.html" if (folder / "report" / "report.html").is_file() else None,
            "metrics": f"{name}/evaluation/metrics.json" if (folder / "evaluation" / "metrics.json").is_file()
            else None,
        }

    def summary(self) -> dict:
        """Gather the batch's summary as it stands (`run` returns it at the end)."""
        counts = {status: 0 for status in STATUSES}
        for row in self.rows.values():
            counts[row["status"]] = counts.get(row["status"], 0) + 1
        return {
            "freqbrdf": __version__, "manifest": str(self.manifest.resolve()), "out": str(self.out.resolve()),
            "started": self.started, "finished": self.finished,
            "seconds": time.perf_counter() - self.start if self.seconds is None else self.seconds,
            "interrupted": self.interrupted,
            "engine": self.engine, "counts": counts,
            "captures": [self.rows[entry.name] for entry in self.entries],
        }

    def write(self) -> None:
        """Rewrite batch.json and index.html with the summary as it stands."""
        write_summary(self.out, self.summary())

    def finish(self) -> None:
        """Record the batch's end, write its summary and remove this run's attempt counts."""
        self.finished, self.seconds = timestamp(), time.perf_counter() - self.start
        self.write()
        shutil.rmtree(self.out / WORK_FOLDER / "runs" / self.run_id, ignore_errors=True)
        self.display.stop(self.summary(), self.out / INDEX_FILE)

    # -- the loop

    def dispatch(self, to_run: list[ManifestEntry], workers: int | None, threads: int | None,
                 address: str | None, hooks: dict) -> None:
        """Run ``to_run`` as Ray tasks, at most ``workers`` at once, recording each as it finishes.

        On Ctrl-C (or SIGTERM) cancel the rest and raise `BatchInterrupted`.
        """
        import ray

        owns = not ray.is_initialized()
        cluster = None
        in_flight: dict = {}  # ObjectRef -> (entry, submitted at)
        stopped = {"signal": signal.SIGINT}
        previous = signal.getsignal(signal.SIGTERM)
        try:
            largest = max(_texture_res(entry) for entry in to_run)
            if owns and address is None:
                cores = os.cpu_count() or 1
                if threads is None:
                    threads = min(FIT_THREADS, cores) if workers is None else max(1, cores // workers)
                if workers is None:
                    workers = min(default_workers(threads, largest, cores), len(to_run))
                start_local_ray(workers * threads)
            elif owns:
                cluster = join_cluster(address)

            def terminate(number, frame):  # set after ray.init, which sets its own
                stopped["signal"] = number
                raise KeyboardInterrupt

            if threading.current_thread() is threading.main_thread():  # signals reach the main thread only
                signal.signal(signal.SIGTERM, terminate)
            cpus = int(ray.cluster_resources().get("CPU", 1))
            if threads is None:
                threads = min(FIT_THREADS, int(largest_node(ray.nodes(), "CPU")) or 1) if workers is None \
                    else max(1, cpus // workers)
            if workers is None:
                workers = max(1, min(cpus // threads, len(to_run)))
            self.engine = {"ray": ray.__version__, "address": address or ("this machine" if owns else "existing"),
                           "nodes": sum(1 for node in ray.nodes() if node.get("Alive")), "cpus": cpus,
                           "workers": workers, "threads_per_capture": threads, "max_retries": MAX_RETRIES}
            if cluster is not None:
                self.engine["cluster"] = cluster
                self.display.joined(cluster, workers, threads)
            env = {"NUMBA_NUM_THREADS": str(threads), "OMP_NUM_THREADS": str(threads)}
            check_workers(ray, {"num_cpus": threads, "runtime_env": {"env_vars": env}},
                          sorted({str(entry.capture) for entry in to_run}), str(self.out.resolve()))
            self.write()  # every capture pending
            task = ray.remote(max_retries=MAX_RETRIES, retry_exceptions=False)(process_capture)
            self._loop(ray, task, to_run, workers, threads, largest_node(ray.nodes(), "memory"), hooks, in_flight)
        except KeyboardInterrupt:
            self.interrupted = True
            self._cancel(ray, in_flight)
            for row in self.rows.values():
                if row["status"] in ("pending", "running"):
                    row["status"] = "interrupted"
            self.finish()
            raise BatchInterrupted(self.summary(), stopped["signal"]) from None
        finally:
            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGTERM, previous)
            if owns and ray.is_initialized():
                ray.shutdown()

    def _attempts_path(self, name: str) -> Path:
        return (self.out / WORK_FOLDER / "runs" / self.run_id / f"{name}.attempts").resolve()

    def _spec(self, entry: ManifestEntry, hooks: dict) -> dict:
        return {"name": entry.name, "capture": str(entry.capture), "folder": str((self.out / entry.name).resolve()),
                "work": str((self.out / WORK_FOLDER / "work" / entry.name).resolve()),
                "attempts": str(self._attempts_path(entry.name)),
                "settings": entry.settings, "settings_hash": settings_hash(entry.settings),
                "version": __version__, "run": self.run_id, "hooks": hooks}

    def _loop(self, ray, task, to_run: list[ManifestEntry], workers: int, threads: int, memory_cap: float,
              hooks: dict, in_flight: dict) -> None:
        queue = list(reversed(to_run))
        env = {"NUMBA_NUM_THREADS": str(threads), "OMP_NUM_THREADS": str(threads)}  # as check_workers'
        first_sent = time.perf_counter()
        while queue or in_flight:
            while queue and len(in_flight) < workers:
                entry = queue.pop()
                options = {"num_cpus": threads, "runtime_env": {"env_vars": env}}
                if memory_cap:
                    options["memory"] = min(fit_memory(_texture_res(entry)), int(0.9 * memory_cap))
                ref = task.options(**options).remote(self._spec(entry, hooks))
                in_flight[ref] = (entry, time.perf_counter())
                self.rows[entry.name]["status"] = "running"
            ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=0.25)
            for ref in ready:
                entry, submitted = in_flight.pop(ref)
                self.engine["dispatch_s"] = time.perf_counter() - first_sent  # first task sent to this answer
                self._finished(entry, self._result(ray, ref, entry, submitted), submitted)
            self.display.update(self._running(in_flight))

    def _result(self, ray, ref, entry: ManifestEntry, submitted: float) -> dict:
        try:
            return ray.get(ref)
        except ray.exceptions.TaskCancelledError:
            return {"status": "interrupted", "error": "cancelled"}
        except ray.exceptions.OutOfMemoryError:
            error = f"out of memory: Ray's memory monitor stopped every attempt ({MAX_RETRIES + 1})"
        except ray.exceptions.RayTaskError as err:  # Ray could not run the task (not the capture's failure)
            error = f"Ray could not run it: {last_line(err.cause if err.cause is not None else err)}"
        except ray.exceptions.RayError as err:
            error = f"its worker died on every attempt ({MAX_RETRIES + 1}): {type(err).__name__}: {last_line(err)}"
        return {"status": "failed", "error": error, "seconds": time.perf_counter() - submitted,
                "attempts": count_attempts(self._attempts_path(entry.name))}

    def _finished(self, entry: ManifestEntry, result: dict, submitted: float) -> None:
        row = self.rows[entry.name]
        row.update({key: value for key, value in result.items() if key != "input_hash"})
        row["wall_seconds"] = time.perf_counter() - submitted  # from its submission to Ray until its answer
        if row["status"] == "done":
            self._paths(entry.name)
        self.write()
        self.display.finished(row)

    def _running(self, in_flight: dict) -> list[tuple[str, float]]:
        now = time.perf_counter()
        running = []
        for entry, submitted in in_flight.values():
            started = self._attempts_path(entry.name).exists()
            running.append((entry.name, now - submitted if started else None))
        return running

    def _cancel(self, ray, in_flight: dict) -> None:
        """Record the captures in flight that have just finished, and kill the workers of the rest.

        A worker killed while it renames a finished capture into place leaves it whole in
        ``OUT/.freqbrdf-batch/work/<name>``, from where the next run puts it back (`recover`).
        """
        with contextlib.suppress(KeyboardInterrupt):  # a second Ctrl-C: stop now
            ready, _ = ray.wait(list(in_flight), num_returns=len(in_flight), timeout=0) if in_flight else ([], [])
            for ref in ready:
                entry, submitted = in_flight.pop(ref)
                result = self._result(ray, ref, entry, submitted)
                if result["status"] in ("done", "failed"):
                    self._finished(entry, result, submitted)
        for ref in in_flight:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)


# ---------------------------------------------------------------------------------------------
# What the person running it sees


class _Display:
    """Show a rich progress bar over the captures, the running ones under it.

    Also a line per finished capture; nothing when the reporter is disabled.
    """

    def __init__(self, reporter: Reporter, total: int):
        self.enabled, self.console, self.total = reporter.enabled, reporter.console, total
        self.live = self.progress = self.task = None
        self.running: list = []

    def start(self, skipped: int) -> None:
        """Show the bar, ``skipped`` captures already counted."""
        if not self.enabled:
            return
        from rich.console import Group
        from rich.live import Live
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.progress = Progress(TextColumn("{task.description:<24}"), BarColumn(), MofNCompleteColumn(),
                                 TimeElapsedColumn(), console=self.console)
        self.task = self.progress.add_task("captures", total=self.total, completed=skipped)
        if skipped:
            self.console.print(f"{skipped} of {self.total} captures up to date (skipped)", highlight=False)
        self.group = Group(self.progress, "")
        self.live = Live(self.group, console=self.console, refresh_per_second=4, transient=False)
        self.live.start()

    def joined(self, cluster: dict, workers: int, threads: int) -> None:
        """Say which Ray cluster the batch joined, before any capture is sent."""
        if not self.enabled:
            return
        from rich.markup import escape

        def count(number: int, noun: str) -> str:
            return f"{number} {noun}{'' if number == 1 else 's'}"

        token = f"token from {cluster['token']}" if cluster.get("token") else "no token"
        self.console.print(escape(
            f"joined the Ray cluster at {cluster['address']} ({cluster['head']}, {cluster['mode']}, {token}): "
            f"{count(cluster['nodes'], 'node')}, {count(cluster['cpus'], 'CPU')}; {count(workers, 'capture')} at "
            f"once, {count(threads, 'thread')} each"), highlight=False, soft_wrap=True)

    def update(self, running: list[tuple[str, float | None]]) -> None:
        """Name the captures in flight, with their seconds since submission (None: queued)."""
        if self.live is None:
            return
        from rich.console import Group
        from rich.text import Text

        parts = [f"{name} {seconds:.0f} s" if seconds is not None else f"{name} (queued)"
                 for name, seconds in running]
        self.live.update(Group(self.progress, Text("running: " + ", ".join(parts) if parts else "",
                                                   style="dim", overflow="ellipsis", no_wrap=True)))

    def finished(self, row: dict) -> None:
        """Advance the bar by a finished capture and print its line."""
        if self.live is None:
            return
        from rich.markup import escape

        self.progress.advance(self.task)
        seconds = f"{row['seconds']:.1f} s" if row.get("seconds") is not None else ""
        retried = f", {row['attempts']} attempts" if row.get("attempts", 1) > 1 else ""
        if row["status"] == "done":
            self.console.print(f"[green]done[/green]   {escape(row['name'])} ({seconds}{retried})", highlight=False)
        elif row["status"] == "failed":
            self.console.print(f"[red]failed[/red] {escape(row['name'])}: {escape(str(row['error']))}",
                               highlight=False, soft_wrap=True)

    def stop(self, summary: dict, index: Path) -> None:
        """Close the bar and print the counts and where index.html is."""
        if not self.enabled:
            return
        if self.live is not None:
            self.update([])
            self.live.stop()
            self.live = None
        counts = summary["counts"]
        parts = ", ".join(f"{counts[status]} {status}" for status in STATUSES if counts.get(status))
        from rich.markup import escape

        self.console.print(f"{len(summary['captures'])} captures: {parts} in {summary['seconds']:.0f} s; "
                           f"{escape(str(index))}", highlight=False, soft_wrap=True)
