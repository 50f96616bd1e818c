"""What a batch keeps on disk, so that a rerun goes on where the last one stopped.

- ``OUT/<name>/batch_entry.json`` (`ENTRY_FILE`), written last into a capture's folder, records
  the content hash of its inputs (`capture_inputs`, `input_record`), the hash of its settings
  (`freqbrdf.batch.settings.settings_hash`), the freqbrdf version and the outputs' sizes;
  `up_to_date` reads it back to decide whether the capture is skipped.
- A capture's folder is made under ``OUT/.freqbrdf-batch/`` (`WORK_FOLDER`) and renamed into place
  as a whole (`publish`); `recover` puts back one that a killed worker left half renamed.
- Each attempt at a capture appends a line to its attempts file (`record_attempt`), which counts
  the retries of workers that died.
- `locked` holds ``OUT/.freqbrdf-batch/lock.json``: one batch at a time writes to OUT.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path

from freqbrdf import __version__
from freqbrdf.batch.manifest import ManifestEntry
from freqbrdf.batch.settings import settings_hash
from freqbrdf.errors import InputError

ENTRY_FILE = "batch_entry.json"  # in OUT/<name>/: written last, so its presence means complete
WORK_FOLDER = ".freqbrdf-batch"  # in OUT/: captures being made, attempt counts, the lock


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while block := handle.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def _is_input_name(name: str) -> bool:
    # Hidden files and the atlas caches earlier versions wrote beside the capture are not inputs.
    return not name.startswith(".") and not name.endswith(".atlas.obj")


def _files_under(folder: Path) -> set[str]:
    found = set()
    for parent, folders, files in os.walk(folder):
        folders[:] = sorted(name for name in folders if not name.startswith("."))
        found.update(str(Path(parent) / name) for name in files if _is_input_name(name))
    return found


def capture_inputs(capture) -> tuple[list[Path], list[Path]]:
    """List the folders watched for added files and the files read of a loaded `Capture`.

    The files are every file under its folder (and, in the Stanford-ORB layout, under its scene's
    ground-truth folder) and every file it names elsewhere (images, masks, environment maps, mesh).

    Parameters
    ----------
    capture : Capture
        The capture, as `freqbrdf.capture.layouts.load` returns it.

    Returns
    -------
    folders : list of Path
        The folders whose added files count as a change, absolute.
    files : list of Path
        Every input file, absolute and sorted.
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


def input_record(folders: list[Path], files: list[Path]) -> dict:
    """Record the inputs of a capture, with the content hash of each file and of all of them.

    The hash covers the files' paths and contents; size and time let a later run skip reading a
    file that was not touched.

    Parameters
    ----------
    folders : list of Path
        The folders watched for added files (`capture_inputs`).
    files : list of Path
        The files read (`capture_inputs`).

    Returns
    -------
    dict
        ``{"folders": [...], "files": {path: [size, mtime_ns, sha256]}, "hash": ...}``, the
        ``inputs`` of ``batch_entry.json``.
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


def up_to_date(entry: ManifestEntry, out: Path) -> dict | None:
    """Read the record of ``OUT/<name>`` if its outputs are complete and up to date.

    Up to date: made from the same inputs, settings and freqbrdf version.

    Parameters
    ----------
    entry : ManifestEntry
        The capture.
    out : Path
        The batch's output folder.

    Returns
    -------
    dict or None
        The content of its ``batch_entry.json``; None where it is missing, incomplete or stale.
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


def recover(work: Path, folder: Path) -> None:
    """Put back a capture's folder that a worker killed in `publish` left in ``work``.

    The new folder where it is complete (its entry file written last), else the old one.

    Parameters
    ----------
    work : Path
        The capture's work folder, ``OUT/.freqbrdf-batch/work/<name>``.
    folder : Path
        Its place, ``OUT/<name>``: left as it is where it exists.
    """
    if folder.exists() or not work.is_dir():
        return
    for candidate in (work / "new", work / "old"):
        if (candidate / ENTRY_FILE).is_file():
            os.replace(candidate, folder)
            return


def publish(staging: Path, folder: Path, old: Path) -> None:
    """Rename ``staging`` to ``folder``, replacing what was there as a whole.

    Parameters
    ----------
    staging : Path
        The complete new folder.
    folder : Path
        Its place.
    old : Path
        Where what was at ``folder`` goes first (in the same file system).
    """
    if folder.exists():
        os.replace(folder, old)
    os.replace(staging, folder)


def record_attempt(path: Path, node: str | None = None) -> int:
    """Append this attempt to the capture's attempts file.

    Parameters
    ----------
    path : Path
        The attempts file (one line per attempt: host, pid, time and Ray's node id, ``-`` where
        none).
    node : str, optional
        The Ray node the attempt runs on.

    Returns
    -------
    int
        This attempt's number, 1 for the first.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a", encoding="utf-8") as handle:
        handle.write(f"{socket.gethostname()} {os.getpid()} {timestamp()} {node or '-'}\n")
    return count_attempts(path)


def count_attempts(path: Path) -> int:
    """Count the attempts recorded in an attempts file (`record_attempt`).

    Parameters
    ----------
    path : Path
        The attempts file.

    Returns
    -------
    int
        Its lines, 0 where it does not exist.
    """
    try:
        return len(path.read_text(encoding="utf-8").splitlines())
    except OSError:
        return 0


@contextlib.contextmanager
def locked(out: Path) -> Iterator[None]:
    """Hold ``OUT/.freqbrdf-batch/lock.json``: one batch at a time writes to OUT.

    A lock left by a process of this host that no longer runs is taken over. On leaving, the lock
    is removed, and so are the work folders where empty.

    Parameters
    ----------
    out : Path
        The batch's output folder.

    Yields
    ------
    None
        While the lock is held.

    Raises
    ------
    InputError
        Where another batch holds it.
    """
    path = out / WORK_FOLDER / "lock.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    me = {"host": socket.gethostname(), "pid": os.getpid(), "since": timestamp()}
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


def timestamp() -> str:
    """Tell the local time, as batch.json and the records write it.

    Returns
    -------
    str
        ISO 8601 to the second, with the UTC offset (``2026-01-31T12:00:00+0100``).
    """
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")
