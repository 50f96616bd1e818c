"""Many captures: every capture of a manifest fitted (and scored, and reported) as a Ray task.

Datasets of scanned objects and the Stanford-ORB benchmark (42 scenes) hold far more captures than
one ``freqbrdf fit`` at a time serves (issue #30). `run` reads a manifest (`read_manifest`: a CSV
or JSON Lines file, one capture a line with optional settings, or a folder of captures), checks
all of it before any work, and runs each capture's whole job as one Ray task: the pipeline of
METHOD.md §3 (`freqbrdf.pipeline.fit`, `write_fit`), the scores of METHOD.md §5 where the capture
has ground truth or test views (`freqbrdf.outputs.evaluate`), and the report
(`freqbrdf.outputs.report`), into ``OUT/<name>/``. Ray starts on this machine by default (workers
sized to its cores and memory, `default_workers`) or joins a cluster by its address.

- A capture's folder appears complete or not at all: it is made in ``OUT/.freqbrdf-batch/`` and
  renamed into place, with ``batch_entry.json`` recording the content hash of its inputs, its
  settings and the freqbrdf version. A later run skips a capture whose record still matches (so
  an interrupted batch goes on where it stopped); ``force`` redoes every capture.
- Bad input fails that capture alone (its one-line `InputError` is recorded); a worker that dies
  (killed, out of memory) is retried by Ray, at most `MAX_RETRIES` times.
- ``OUT/batch.json`` (every capture's status, seconds, attempts, error, key metrics and paths) and
  ``OUT/index.html`` (the same as a table, with links to the reports) are rewritten atomically
  after every capture; an interrupted run (Ctrl-C) records the captures it did not finish as
  "interrupted" and raises `BatchInterrupted`.

The tasks run the same code as ``freqbrdf fit``, with numba's threads set to the task's CPUs; a
worker whose numba compiled kernels (a cold cache) makes its captures in a fresh process, whose
kernels come from the cache, so that the results match every later run's (see `freqbrdf.jit`).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import hashlib
import html
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from freqbrdf import __version__
from freqbrdf.config import PRESETS, Config, EstimateConfig, UncertaintyConfig, choices, preset
from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_path, check_output_path, write_json
from freqbrdf.progress import SILENT, Reporter

BATCH_FILE = "batch.json"
INDEX_FILE = "index.html"
ENTRY_FILE = "batch_entry.json"  # in OUT/<name>/: written last, so its presence means complete
WORK_FOLDER = ".freqbrdf-batch"  # in OUT/: captures being made, attempt counts, the lock
MANIFEST_SUFFIXES = {".csv": "csv", ".jsonl": "jsonl", ".ndjson": "jsonl"}
CAPTURE_FILES = ("transforms.json", "transforms_train.json")  # a folder holding one is a capture
MAX_RETRIES = 2  # Ray's retries of a capture whose worker died
FIT_THREADS = 2  # CPUs (numba threads) per capture by default: what one fit uses well
# Memory one fit is scheduled with, as bytes at texture side T: a fixed part (the interpreter,
# numba, Mitsuba) plus a part growing with the texels; the two sum to the ~1.2 GiB peak of a
# T = 512 fit with a margin.
FIT_MEMORY_FIXED = int(0.75 * 2**30)
FIT_MEMORY_AT_512 = int(0.75 * 2**30)
# Test-only fault injection, read by `run` from its environment: a JSON object with
# "kill_first_attempt": [names] (the first attempt of each kills its own worker with SIGKILL when
# the fit starts, as the kernel's out-of-memory killer would) and "sleep_s": {name: seconds} (the
# capture waits that long before it starts). Unset, nothing changes.
TEST_HOOKS_VARIABLE = "FREQBRDF_BATCH_TEST_HOOKS"
STATUSES = ("done", "skipped", "failed", "interrupted")
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
_RESERVED_NAMES = {BATCH_FILE, INDEX_FILE}


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


# ---------------------------------------------------------------------------------------------
# Settings of one capture


def _integer(minimum: int):
    def parse(value):
        if isinstance(value, str) and value.strip().isdigit():
            value = int(value.strip())
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise ValueError(f"must be a whole number >= {minimum}")
        return value
    return parse


def _boolean(value):
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("true", "yes", "1", "on"):
        return True
    if text in ("false", "no", "0", "off"):
        return False
    raise ValueError("must be true or false")


def _evaluate(value):
    return "auto" if str(value).strip().lower() == "auto" else _boolean(value)


def _choice(allowed):
    def parse(value):
        if value not in allowed:
            raise ValueError(f"must be one of {', '.join(allowed)}")
        return value
    return parse


def _estimation_res(value):
    if value in ("pixel", "coarse", "full"):
        return value
    try:
        return _integer(1)(value)
    except ValueError:
        raise ValueError("must be pixel, coarse, full or a whole number >= 1") from None


# Per-capture settings: key -> (parser, default). None keeps the preset's value. They mirror the
# options of `freqbrdf fit` (and `evaluate --spp`).
SETTINGS = {
    "preset": (_choice(PRESETS), "default"),
    "texture_res": (_integer(1), None),
    "lmax": (_integer(1), None),
    "estimator": (_choice(choices(EstimateConfig)["method"]), None),
    "model": (_choice(choices(EstimateConfig)["forward_model"]), None),
    "entropy": (_choice(choices(UncertaintyConfig)["mode"]), None),
    "estimation_res": (_estimation_res, None),
    "share": (_boolean, False),
    "split_half": (_boolean, False),
    "evaluate": (_evaluate, "auto"),  # auto: when the capture has ground truth or test views
    "report": (_boolean, True),
    "spp": (_integer(1), 64),  # samples per pixel of the relit renders of the evaluation
}
MANIFEST_KEYS = ("name", "capture", *SETTINGS)


def parse_settings(values: dict, where: str = "") -> dict:
    """Check and convert settings given as text (CSV) or JSON values; absent keys are left out.

    Parameters
    ----------
    values : dict
        ``{key: value}`` with keys among `SETTINGS`; None and empty strings count as absent.
    where : str
        Prefix of the error message (e.g. ``"line 3: "``).

    Returns
    -------
    dict
        The settings given, converted (whole numbers, booleans, choices).
    """
    parsed = {}
    for key, value in values.items():
        if key not in SETTINGS:
            raise ValueError(f"{where}unknown setting {key!r}; settings are {', '.join(SETTINGS)}")
        if value is None or (isinstance(value, str) and not value.strip()):
            continue
        try:
            parsed[key] = SETTINGS[key][0](value.strip() if isinstance(value, str) else value)
        except ValueError as err:
            raise ValueError(f"{where}{key} {value!r} {err}") from None
    return parsed


def capture_config(settings: dict) -> Config:
    """Make the `Config` of one capture's settings, as `freqbrdf fit` makes it from the same options.

    Parameters
    ----------
    settings : dict
        Settings as `parse_settings` returns them (absent keys: the preset's values).

    Returns
    -------
    Config
        The preset with the settings given; ValueError where the combination is invalid.
    """
    config = preset(settings.get("preset", "default"))
    texels = config.texels
    if settings.get("texture_res") is not None:
        texels = dataclasses.replace(texels, texture_res=settings["texture_res"])
    estimation_res = settings.get("estimation_res")
    if estimation_res is not None:
        if isinstance(estimation_res, int) and estimation_res > texels.texture_res:
            raise ValueError(f"estimation_res {estimation_res} exceeds the texture resolution {texels.texture_res}")
        texels = dataclasses.replace(texels, estimation_res=estimation_res)
    fit = config.fit if settings.get("lmax") is None else dataclasses.replace(config.fit, lmax=settings["lmax"])
    estimate = config.estimate
    if settings.get("estimator") is not None:
        estimate = dataclasses.replace(estimate, method=settings["estimator"])
    if settings.get("model") is not None:
        estimate = dataclasses.replace(estimate, forward_model=settings["model"])
    uncertainty = config.uncertainty
    if settings.get("entropy") is not None:
        uncertainty = dataclasses.replace(uncertainty, mode=settings["entropy"])
    if settings.get("split_half"):
        uncertainty = dataclasses.replace(uncertainty, split_half=True)
    share = dataclasses.replace(config.share, enabled=True) if settings.get("share") else config.share
    return config.replace(texels=texels, fit=fit, estimate=estimate, uncertainty=uncertainty, share=share)


def _full_settings(settings: dict) -> dict:
    """Every key of `SETTINGS`, the defaults where absent."""
    return {key: settings.get(key, default) for key, (_, default) in SETTINGS.items()}


def settings_hash(settings: dict) -> str:
    """Hash what a capture's outputs depend on besides its inputs.

    That is its whole `Config` (`capture_config`) and the evaluation and report settings.

    Parameters
    ----------
    settings : dict
        Settings as `parse_settings` returns them.

    Returns
    -------
    str
        64 hexadecimal digits.
    """
    full = _full_settings(settings)
    document = {"config": capture_config(settings).to_dict(),
                **{key: full[key] for key in ("evaluate", "report", "spp")}}
    return hashlib.sha256(json.dumps(document, sort_keys=True, default=str).encode()).hexdigest()


# ---------------------------------------------------------------------------------------------
# The manifest


@dataclass(frozen=True)
class ManifestEntry:
    """One capture of a manifest.

    Attributes
    ----------
    name : str
        The capture's output folder under OUT (letters, digits, ``.``, ``_``, ``-``).
    capture : Path
        The capture's folder or transforms file, absolute.
    settings : dict
        Its settings (`parse_settings`), the batch's defaults filled in.
    where : str
        Where it was given, for messages (``"captures.csv line 3"``).
    """

    name: str
    capture: Path
    settings: dict
    where: str

    @property
    def root(self) -> Path:
        """The capture's folder (the transforms file's folder where a file was given)."""
        return self.capture if self.capture.is_dir() else self.capture.parent


def read_manifest(path: str | Path, defaults: dict | None = None) -> list[ManifestEntry]:
    """Read and check a whole manifest before any work.

    A CSV file has a header row with the columns ``name`` (optional: the capture folder's name),
    ``capture`` (the capture's folder or transforms file, relative to the manifest's folder) and
    any of the settings of `SETTINGS`, empty cells taking the defaults. A JSON Lines file
    (``.jsonl``) holds one object a line with the same keys. A folder stands for its subfolders
    that hold a capture (``transforms.json`` or Stanford-ORB's ``transforms_train.json``), each
    named after its folder. Every problem (unknown key or value, duplicate name, missing capture)
    raises `InputError` naming the file and the line.

    Parameters
    ----------
    path : str or Path
        The manifest file or folder.
    defaults : dict, optional
        Settings for every capture that its own line does not set (`parse_settings`'s keys).

    Returns
    -------
    list of ManifestEntry
        The captures in the manifest's order.
    """
    path = Path(path)
    try:
        defaults = parse_settings(dict(defaults or {}))
    except ValueError as err:
        raise InputError(None, str(err)) from None
    if not path.exists():
        raise InputError(path, "manifest does not exist")
    if path.is_dir():
        rows = _folder_rows(path)
    elif path.suffix.lower() in MANIFEST_SUFFIXES:
        rows = _csv_rows(path) if MANIFEST_SUFFIXES[path.suffix.lower()] == "csv" else _jsonl_rows(path)
    else:
        raise InputError(path, f"manifest must be a .csv or .jsonl file or a folder of captures, "
                               f"not {path.suffix or 'a file without extension'}")
    if not rows:
        raise InputError(path, "manifest lists no capture")
    base = path if path.is_dir() else path.parent
    entries: list[ManifestEntry] = []
    seen: dict[str, int] = {}
    for line, row in rows:
        where = f"line {line}: " if not path.is_dir() else ""
        entry = _entry(path, base, line, row, defaults, where)
        key = entry.name.lower()  # case-insensitive file systems would merge two such folders
        if key in seen:
            raise InputError(path, f"{where}name {entry.name!r} also on line {seen[key]}; names must differ "
                                   "(ignoring case)")
        seen[key] = line
        entries.append(entry)
    return entries


def _entry(path: Path, base: Path, line: int, row: dict, defaults: dict, where: str) -> ManifestEntry:
    unknown = [key for key in row if key not in MANIFEST_KEYS]
    if unknown:
        raise InputError(path, f"{where}unknown key {unknown[0]!r}; keys are {', '.join(MANIFEST_KEYS)}")
    capture_value = row.get("capture")
    if not isinstance(capture_value, str) or not capture_value.strip():
        raise InputError(path, f"{where}capture is missing (a capture folder or transforms file)")
    capture = (base / capture_value.strip()).resolve()
    if not capture.exists():
        raise InputError(path, f"{where}capture {capture_value.strip()!r} does not exist ({capture})")
    if capture.is_dir() and not any((capture / name).is_file() for name in CAPTURE_FILES):
        raise InputError(path, f"{where}capture {capture_value.strip()!r} holds no {' or '.join(CAPTURE_FILES)}")
    name = row.get("name")
    if name in (None, ""):
        name = capture.name if capture.is_dir() else capture.parent.name
    if not isinstance(name, str) or not _NAME.fullmatch(name) or name in _RESERVED_NAMES:
        raise InputError(path, f"{where}name {name!r} must start with a letter or digit and hold only letters, "
                               f"digits, '.', '_' and '-' (and not be {' or '.join(sorted(_RESERVED_NAMES))})")
    try:
        settings = {**defaults, **parse_settings({k: v for k, v in row.items() if k in SETTINGS}, "")}
        capture_config(settings)  # refuses invalid combinations now, not after other captures' work
    except ValueError as err:
        raise InputError(path, f"{where}{err}") from None
    label = path.name if path.is_dir() else f"{path.name} line {line}"
    return ManifestEntry(name, capture, settings, label)


def _csv_rows(path: Path) -> list[tuple[int, dict]]:
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            reader = csv.reader(handle)
            header = next(reader, None)
            if header is None:
                return []
            header = [column.strip() for column in header]
            for column in header:
                if column not in MANIFEST_KEYS:
                    raise InputError(path, f"line 1: unknown column {column!r}; columns are "
                                           f"{', '.join(MANIFEST_KEYS)}")
            if "capture" not in header:
                raise InputError(path, "line 1: the header needs a 'capture' column")
            if len(set(header)) < len(header):
                raise InputError(path, "line 1: a column appears twice")
            rows = []
            for cells in reader:
                if not any(cell.strip() for cell in cells):
                    continue
                if len(cells) > len(header):
                    raise InputError(path, f"line {reader.line_num}: {len(cells)} cells, the header has "
                                           f"{len(header)} columns")
                rows.append((reader.line_num, dict(zip(header, cells))))
            return rows
    except (UnicodeDecodeError, csv.Error) as err:
        raise InputError(path, f"unreadable CSV: {err}") from None


def _jsonl_rows(path: Path) -> list[tuple[int, dict]]:
    rows = []
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError as err:
        raise InputError(path, f"unreadable: {err}") from None
    for number, text in enumerate(lines, start=1):
        if not text.strip():
            continue
        try:
            row = json.loads(text)
        except json.JSONDecodeError as err:
            raise InputError(path, f"line {number}: not JSON ({err.msg})") from None
        if not isinstance(row, dict):
            raise InputError(path, f"line {number}: must be a JSON object")
        rows.append((number, row))
    return rows


def _folder_rows(path: Path) -> list[tuple[int, dict]]:
    if any((path / name).is_file() for name in CAPTURE_FILES):
        raise InputError(path, "is a capture, not a folder of captures: use `freqbrdf fit`, or a manifest "
                               "listing it")
    folders = sorted(child for child in path.iterdir() if child.is_dir() and not child.name.startswith(".")
                     and any((child / name).is_file() for name in CAPTURE_FILES))
    return [(index, {"name": folder.name, "capture": folder.name}) for index, folder in enumerate(folders, 1)]


# ---------------------------------------------------------------------------------------------
# Inputs: what a capture's outputs are made from, and whether it changed


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while block := handle.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def _is_input_name(name: str) -> bool:
    # Hidden files and the atlas cache the mesh loader writes beside the capture are not inputs.
    return not name.startswith(".") and not name.endswith(".atlas.obj")


def _files_under(folder: Path) -> set[str]:
    found = set()
    for parent, folders, files in os.walk(folder):
        folders[:] = sorted(name for name in folders if not name.startswith("."))
        found.update(str(Path(parent) / name) for name in files if _is_input_name(name))
    return found


def _capture_inputs(capture) -> tuple[list[Path], list[Path]]:
    """List the folders watched for added files and the files read of a loaded `Capture`.

    The files are every file under its folder (and, in the Stanford-ORB layout, under its scene's
    ground-truth folder) and every file it names elsewhere (images, masks, environment maps, mesh).
    """
    root = Path(capture.root).resolve()
    folders = [root]
    if capture.layout == "stanford-orb":
        truth = root.parent.parent / "ground_truth" / root.name
        if truth.is_dir():
            folders.append(truth.resolve())
    named = [capture.envmap_path, capture.mesh.path]
    for frame in (*capture.frames, *capture.test_frames):
        named += [frame.image_path, frame.mask_path, frame.envmap_path]
    files = {Path(path) for folder in folders for path in _files_under(folder)}
    files.update(Path(path).resolve() for path in named if path is not None)
    return folders, sorted(files)


def _input_record(folders: list[Path], files: list[Path]) -> dict:
    """Record the inputs: ``{"folders": [...], "files": {path: [size, mtime_ns, sha256]}, "hash": ...}``.

    The hash covers the files' paths and contents; size and time let a later run skip reading a
    file that was not touched.
    """
    records = {}
    for path in files:
        status = path.stat()
        records[str(path)] = [status.st_size, status.st_mtime_ns, _sha256(path)]
    return {"folders": [str(folder) for folder in folders], "files": records, "hash": _inputs_hash(records)}


def _inputs_hash(records: dict) -> str:
    digest = hashlib.sha256()
    for path in sorted(records):
        digest.update(f"{path}\0{records[path][2]}\n".encode())
    return digest.hexdigest()


def _inputs_unchanged(record: dict) -> bool:
    """Tell whether the recorded inputs still hold the same content and no file was added.

    A file whose size and modification time are unchanged is taken as unchanged; any other is read
    and hashed again. Files added under the watched folders count as a change.
    """
    files = record.get("files", {})
    for folder in record.get("folders", []):
        if not Path(folder).is_dir() or not _files_under(Path(folder)) <= set(files):
            return False
    for path, (size, mtime_ns, digest) in files.items():
        try:
            status = os.stat(path)
        except OSError:
            return False
        if (status.st_size, status.st_mtime_ns) != (size, mtime_ns):
            try:
                if status.st_size != size or _sha256(Path(path)) != digest:
                    return False
            except OSError:
                return False
    return True


def _up_to_date(entry: ManifestEntry, out: Path) -> dict | None:
    """Read the record of ``OUT/<name>`` if its outputs are complete and up to date, else None.

    Up to date: made from the same inputs, settings and freqbrdf version.
    """
    folder = out / entry.name
    try:
        record = json.loads((folder / ENTRY_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("freqbrdf") != __version__ \
            or record.get("capture") != str(entry.capture) \
            or record.get("settings_hash") != settings_hash(entry.settings):
        return None
    for relative, size in record.get("outputs", {}).items():
        path = folder / relative
        if not path.is_file() or path.stat().st_size != size:
            return None
    return record if _inputs_unchanged(record.get("inputs", {})) else None


# ---------------------------------------------------------------------------------------------
# One capture (runs in a Ray worker)


def _process_capture(spec: dict) -> dict:
    """Fit, evaluate and report one capture into ``spec["folder"]``; the summary row's fields.

    Bad input and other exceptions become status "failed" with a one-line error; only the
    worker's death (or a fresh process killed by a signal) ends the task without an answer, which
    Ray retries.
    """
    start = time.perf_counter()
    attempt = _record_attempt(Path(spec["attempts"])) if spec.get("attempts") else 1
    hooks = spec.get("hooks", {})
    delay = float(hooks.get("sleep_s", {}).get(spec["name"], 0.0))
    if delay > 0:
        time.sleep(delay)
    spec = {**spec, "attempt": attempt, "started_at": time.time()}
    row = {"attempts": attempt, "worker": {"host": socket.gethostname(), "pid": os.getpid()}}
    try:
        if spec["version"] != __version__:
            raise InputError(None, f"this worker has freqbrdf {__version__}, the batch {spec['version']}: install the "
                                   "same version on every node")
        if not spec.get("child") and _compiled_here():
            row.update(_in_fresh_process(spec))
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
    inputs = _input_record(*_capture_inputs(capture))
    config = capture_config(settings)
    result = pipeline.fit(capture, config, _KillAtFirstStage() if kill else SILENT)
    if not spec.get("child") and _compiled_here():
        # numba compiled kernels in this worker: their results differ in the last bits from the
        # cached kernels' (freqbrdf.jit); the fresh process loads those from the cache just written.
        return _in_fresh_process(spec)
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
        "settings": _full_settings(settings), "settings_hash": spec["settings_hash"],
        "inputs": inputs, "outputs": outputs, "evaluated": bool(evaluate), "metrics": metrics,
        "finished": _now(), "seconds": time.time() - spec.get("started_at", time.time()),
        "attempts": spec.get("attempt", 1), "worker": {"host": socket.gethostname(), "pid": os.getpid()},
    }
    write_json(staging / ENTRY_FILE, entry)
    _publish(staging, folder, work / "old")
    shutil.rmtree(work, ignore_errors=True)
    return {"status": "done", "error": None, "metrics": metrics, "evaluated": bool(evaluate),
            "input_hash": inputs["hash"]}


def _recover(work: Path, folder: Path) -> None:
    """Put back a capture's folder that a worker killed in `_publish` left in ``work``.

    The new folder where it is complete (its entry file written last), else the old one.
    """
    if folder.exists() or not work.is_dir():
        return
    for candidate in (work / "new", work / "old"):
        if (candidate / ENTRY_FILE).is_file():
            os.replace(candidate, folder)
            return


def _publish(staging: Path, folder: Path, old: Path) -> None:
    """Rename ``staging`` to ``folder``, replacing what was there as a whole."""
    if folder.exists():
        os.replace(folder, old)
    os.replace(staging, folder)


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


def _record_attempt(path: Path) -> int:
    """Append this attempt to the capture's attempts file; its number (1 for the first)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a", encoding="utf-8") as handle:
        handle.write(f"{socket.gethostname()} {os.getpid()} {_now()}\n")
    return _attempts(path)


def _attempts(path: Path) -> int:
    try:
        return len(path.read_text(encoding="utf-8").splitlines())
    except OSError:
        return 0


def _in_fresh_process(spec: dict) -> dict:
    """Run `_make_outputs` in a new interpreter.

    A child killed by a signal kills this worker too, for Ray to retry the capture.
    """
    child = subprocess.run([sys.executable, "-c", "from freqbrdf.batch import _child_main; _child_main()"],
                           input=json.dumps({**spec, "child": True}), capture_output=True, text=True)
    if child.returncode < 0:
        os.kill(os.getpid(), signal.SIGKILL)
    lines = child.stdout.strip().splitlines()
    if child.returncode != 0 or not lines:
        last = (child.stderr.strip().splitlines() or [f"exit code {child.returncode}"])[-1]
        return {"status": "failed", "error": f"the capture's fresh process failed: {last}"}
    return {**json.loads(lines[-1]), "fresh_process": True}


def _child_main() -> None:
    """Entry of `_in_fresh_process`'s interpreter: the spec on stdin, the row as JSON on stdout's last line."""
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


# ---------------------------------------------------------------------------------------------
# The batch (the driver)


def fit_memory(texture_res: int) -> int:
    """Bytes of memory one capture is scheduled with at texture side ``texture_res``.

    Parameters
    ----------
    texture_res : int
        T of the fit.

    Returns
    -------
    int
        `FIT_MEMORY_FIXED` plus `FIT_MEMORY_AT_512` scaled by the texels, (T / 512)^2.
    """
    return FIT_MEMORY_FIXED + int(FIT_MEMORY_AT_512 * (texture_res / 512) ** 2)


def _available_memory() -> int:
    try:
        with open("/proc/meminfo", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def default_workers(threads: int = FIT_THREADS, texture_res: int = 512, cores: int | None = None,
                    memory: int | None = None) -> int:
    """Count the captures this machine runs at once.

    As many as its cores give ``threads`` each and its available memory holds (`fit_memory`), at
    least one.

    Parameters
    ----------
    threads : int
        CPUs per capture.
    texture_res : int
        The largest T of the captures.
    cores, memory : int, optional
        The machine's cores and available bytes (default: this machine's).

    Returns
    -------
    int
        The number of workers, >= 1.
    """
    cores = (os.cpu_count() or 1) if cores is None else cores
    memory = _available_memory() if memory is None else memory
    return max(1, min(cores // threads, memory // fit_memory(texture_res)))


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
        ``engine`` (Ray's version, workers, threads), times and the freqbrdf version.
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
    hooks = _test_hooks()
    out.mkdir(parents=True, exist_ok=True)
    batch = _Batch(manifest, out, entries, reporter)
    with _locked(out):
        batch.plan(force)
        to_run = [entry for entry in entries if batch.rows[entry.name]["status"] == "pending"]
        if to_run:
            batch.dispatch(to_run, workers, threads, address, hooks)
        batch.finish()
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


@contextlib.contextmanager
def _locked(out: Path) -> Iterator[None]:
    """Hold ``OUT/.freqbrdf-batch/lock.json``: one batch at a time writes to OUT.

    A lock left by a process of this host that no longer runs is taken over.
    """
    path = out / WORK_FOLDER / "lock.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    me = {"host": socket.gethostname(), "pid": os.getpid(), "since": _now()}
    for _ in range(3):
        try:
            descriptor = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666)
        except FileExistsError:
            try:
                other = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                other = {}
            if other.get("host") == me["host"] and isinstance(other.get("pid"), int) and not _alive(other["pid"]):
                path.unlink(missing_ok=True)
                continue
            if not other:  # being written this instant, or unreadable: look again
                time.sleep(0.2)
                continue
            raise InputError(out, f"another batch (pid {other.get('pid')} on {other.get('host')}, since "
                                  f"{other.get('since')}) writes here; if it is not running, remove {path}")
        with os.fdopen(descriptor, "w", encoding="utf-8") as handle:
            json.dump(me, handle)
        break
    else:
        raise InputError(path, "could not take the batch's lock")
    try:
        yield
    finally:
        path.unlink(missing_ok=True)
        for folder in (path.parent / "runs", path.parent / "work", path.parent):
            with contextlib.suppress(OSError):
                folder.rmdir()  # where empty


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


class _Batch:
    """The rows of batch.json as the captures finish, and the driver's loop."""

    def __init__(self, manifest: Path, out: Path, entries: list[ManifestEntry], reporter: Reporter):
        self.manifest, self.out, self.entries, self.reporter = manifest, out, entries, reporter
        self.rows: dict[str, dict] = {}
        self.started, self.start = _now(), time.perf_counter()
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
                "settings": _full_settings(entry.settings), **fields}

    def plan(self, force: bool) -> None:
        """Mark each capture skipped (up to date, unless ``force``) or pending."""
        for entry in self.entries:
            _recover(self.out / WORK_FOLDER / "work" / entry.name, self.out / entry.name)
            record = None if force else _up_to_date(entry, self.out)
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
        summary = self.summary()
        write_json(self.out / BATCH_FILE, summary)
        with atomic_path(self.out / INDEX_FILE) as tmp:
            tmp.write_text(_index_html(summary), encoding="utf-8")

    def finish(self) -> None:
        self.finished, self.seconds = _now(), time.perf_counter() - self.start
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
                _start_local_ray(workers * threads)
            elif owns:
                _join_cluster(address)

            def terminate(number, frame):  # set after ray.init, which sets its own
                stopped["signal"] = number
                raise KeyboardInterrupt

            if threading.current_thread() is threading.main_thread():  # signals reach the main thread only
                signal.signal(signal.SIGTERM, terminate)
            cpus = int(ray.cluster_resources().get("CPU", 1))
            if threads is None:
                threads = min(FIT_THREADS, int(_largest_node(ray.nodes(), "CPU")) or 1) if workers is None \
                    else max(1, cpus // workers)
            if workers is None:
                workers = max(1, min(cpus // threads, len(to_run)))
            self.engine = {"ray": ray.__version__, "address": address or ("this machine" if owns else "existing"),
                           "nodes": sum(1 for node in ray.nodes() if node.get("Alive")),
                           "workers": workers, "threads_per_capture": threads, "max_retries": MAX_RETRIES}
            env = {"NUMBA_NUM_THREADS": str(threads), "OMP_NUM_THREADS": str(threads)}
            _check_workers(ray, {"num_cpus": threads, "runtime_env": {"env_vars": env}})
            self.write()  # every capture pending
            task = ray.remote(max_retries=MAX_RETRIES, retry_exceptions=False)(_process_capture)
            self._loop(ray, task, to_run, workers, threads, _largest_node(ray.nodes(), "memory"), hooks, in_flight)
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
                "version": __version__, "hooks": hooks}

    def _loop(self, ray, task, to_run: list[ManifestEntry], workers: int, threads: int, memory_cap: float,
              hooks: dict, in_flight: dict) -> None:
        queue = list(reversed(to_run))
        env = {"NUMBA_NUM_THREADS": str(threads), "OMP_NUM_THREADS": str(threads)}  # as _check_workers'
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
            error = f"Ray could not run it: {_last_line(err.cause if err.cause is not None else err)}"
        except ray.exceptions.RayError as err:
            error = f"its worker died on every attempt ({MAX_RETRIES + 1}): {type(err).__name__}: {_last_line(err)}"
        return {"status": "failed", "error": error, "seconds": time.perf_counter() - submitted,
                "attempts": _attempts(self._attempts_path(entry.name))}

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
        ``OUT/.freqbrdf-batch/work/<name>``, from where the next run puts it back (`_recover`).
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


def _last_line(error: BaseException) -> str:
    """Take the last line of an error's text, without terminal colours (Ray's tracebacks end with the cause)."""
    text = re.sub(r"\x1b\[[0-9;]*m", "", str(error)).strip()
    return (text.splitlines() or [type(error).__name__])[-1].strip()


def _worker_facts() -> dict:
    """Tell what a Ray worker runs: its freqbrdf version and host (`_check_workers`)."""
    return {"freqbrdf": __version__, "host": socket.gethostname()}


def _check_workers(ray, options: dict) -> None:
    """Run one small task as the captures will run, before any capture is sent.

    InputError where a worker cannot run this freqbrdf (not installed there, another version).
    """
    try:
        facts = ray.get(ray.remote(_worker_facts).options(max_retries=0, **options).remote(), timeout=300)
    except ray.exceptions.GetTimeoutError:
        raise InputError(None, "no Ray worker started within 300 s: does the cluster have a node with "
                               f"{options['num_cpus']} free CPUs?") from None
    except ray.exceptions.RayError as err:
        cause = err.cause if isinstance(err, ray.exceptions.RayTaskError) and err.cause is not None else err
        raise InputError(None, f"Ray's workers cannot run freqbrdf.batch ({_last_line(cause)}); install freqbrdf "
                               f"{__version__} on every node") from None
    if facts["freqbrdf"] != __version__:
        raise InputError(None, f"Ray's worker on {facts['host']} has freqbrdf {facts['freqbrdf']}, this batch "
                               f"{__version__}: install the same version on every node")


def _largest_node(nodes: list[dict], resource: str) -> float:
    return max((node.get("Resources", {}).get(resource, 0.0) for node in nodes if node.get("Alive")), default=0.0)


def _start_local_ray(cpus: int) -> None:
    import logging

    import ray

    ray.init(address="local", num_cpus=cpus, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR,
             object_store_memory=256 * 2**20,
             # Ray's memory monitor retries a task it stopped without bound by default.
             _system_config={"task_oom_retries": MAX_RETRIES})


def _join_cluster(address: str) -> None:
    """Connect to the Ray cluster at ``address``; InputError at once where nothing answers there.

    Ray itself would try again for minutes; an address with a port (``HOST:PORT`` or
    ``ray://HOST:PORT``) is tried first with a plain connection, for a few seconds.
    """
    import logging

    import ray

    match = re.fullmatch(r"(?:ray://)?\[?([^\]/]+?)\]?:(\d+)", address.strip())
    if match:
        try:
            socket.create_connection((match.group(1), int(match.group(2))), timeout=5).close()
        except OSError as err:
            raise InputError(None, f"no Ray cluster answers at {address} ({err.strerror or err}); start one with "
                                   "`ray start --head`, or leave out --address to run on this machine") from None
    try:
        ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
    except ConnectionError as err:
        raise InputError(None, f"no Ray cluster at {address!r}: {str(err).splitlines()[0]}") from None


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

    def update(self, running: list[tuple[str, float | None]]) -> None:
        if self.live is None:
            return
        from rich.console import Group
        from rich.text import Text

        parts = [f"{name} {seconds:.0f} s" if seconds is not None else f"{name} (queued)"
                 for name, seconds in running]
        self.live.update(Group(self.progress, Text("running: " + ", ".join(parts) if parts else "",
                                                   style="dim", overflow="ellipsis", no_wrap=True)))

    def finished(self, row: dict) -> None:
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


_COLUMNS = (  # (metric key, heading, digits)
    ("observed_fraction", "observed", None), ("entropy_mean", "mean entropy", 2),
    ("base_color_psnr", "base colour PSNR", 2), ("roughness_mae", "roughness MAE", 3),
    ("metallic_mae", "metallic MAE", 3), ("psnr_hdr", "PSNR-H", 2), ("psnr_ldr", "PSNR-L", 2),
    ("ssim", "SSIM", 3), ("lpips", "LPIPS", 3),
)


def _index_html(summary: dict) -> str:
    """index.html: one self-contained page, a table of every capture with links to its report."""
    def cell(value, digits):
        if value is None:
            return "<td></td>"
        if digits is None:
            return f"<td>{value:.0%}</td>"
        return f"<td>{value:.{digits}f}</td>"

    used = [column for column in _COLUMNS
            if any((row.get("metrics") or {}).get(column[0]) is not None for row in summary["captures"])]
    rows = []
    for row in summary["captures"]:
        name = html.escape(row["name"])
        link = row["paths"].get("report") or (f"{row['name']}/summary.json" if row["status"] in ("done", "skipped")
                                              else None)
        title = f'<a href="{html.escape(link)}">{name}</a>' if link else name
        metrics = row.get("metrics") or {}
        seconds = "" if row.get("seconds") is None else f"{row['seconds']:.1f}"
        rows.append(f'<tr class="{row["status"]}"><td>{title}</td><td>{row["status"]}</td><td>{seconds}</td>'
                    f'<td>{row.get("attempts") or ""}</td>'
                    + "".join(cell(metrics.get(key), digits) for key, _, digits in used)
                    + f'<td class="error">{html.escape(row.get("error") or "")}</td></tr>')
    counts = ", ".join(f"{count} {status}" for status, count in summary["counts"].items() if count)
    headings = "".join(f"<th>{html.escape(heading)}</th>" for _, heading, _ in used)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>freqbrdf batch</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 2em; }}
table {{ border-collapse: collapse; }}
th, td {{ padding: 0.3em 0.7em; border-bottom: 1px solid #ddd; text-align: right; }}
th:first-child, td:first-child, td.error {{ text-align: left; }}
tr.failed td {{ color: #b00020; }}
tr.interrupted td, tr.pending td, tr.running td {{ color: #777; }}
</style></head><body>
<h1>freqbrdf batch</h1>
<p>Manifest <code>{html.escape(summary["manifest"])}</code>; {len(summary["captures"])} captures: {counts};
freqbrdf {html.escape(summary["freqbrdf"])}; started {html.escape(summary["started"])}{
    "" if summary["finished"] is None else ", finished " + html.escape(summary["finished"])}.
Seconds are each capture's time to make its outputs (for skipped ones, when they were made).</p>
<table><thead><tr><th>capture</th><th>status</th><th>seconds</th><th>attempts</th>{headings}<th>error</th></tr>
</thead><tbody>
{chr(10).join(rows)}
</tbody></table>
</body></html>
"""
