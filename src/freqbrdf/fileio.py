"""Atomic file output: write to a temporary sibling, rename on success, remove on failure.

An output folder is replaced as a whole, so it must be one freqbrdf wrote (`OUTPUT_MARKER`, or a
file an earlier version left, `LEGACY_OUTPUT_FILES`), an empty folder or a new path: a folder of
the user's, the current folder or one that contains it is refused before any work, unless
`allow_replacing_foreign_folders` (``freqbrdf --force``). Concurrent writers to one folder take
turns at the swap (a lock on the parent folder); the last one's folder stays.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import fcntl
import json
import math
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from freqbrdf.errors import InputError

# The file every output folder holds: how freqbrdf knows a folder it may replace.
OUTPUT_MARKER = ".freqbrdf"
# Files by which a folder written before OUTPUT_MARKER existed is known as freqbrdf's.
LEGACY_OUTPUT_FILES = ("summary.json", "metrics.json", "report.html", "observations.npz", "next_views.json")
_replace_foreign = contextvars.ContextVar("replace_foreign", default=False)


def allow_replacing_foreign_folders(allow: bool) -> None:
    """Let output folders replace existing folders that freqbrdf did not write (``freqbrdf --force``).

    Parameters
    ----------
    allow : bool
        Whether to allow it, for the rest of this context (the process, for the command line).
    """
    _replace_foreign.set(bool(allow))


def is_output_folder(folder: str | Path) -> bool:
    """Tell whether a folder is one freqbrdf may replace: empty, or written by freqbrdf.

    Parameters
    ----------
    folder : str or Path
        An existing folder.

    Returns
    -------
    bool
        True where it is empty, holds `OUTPUT_MARKER` or one of `LEGACY_OUTPUT_FILES`.
    """
    try:  # one listing: another writer may be swapping the folder right now
        names = set(os.listdir(folder))
    except FileNotFoundError:  # swapped away in the meantime: nothing of the user's
        return True
    return not names or OUTPUT_MARKER in names or bool(names & set(LEGACY_OUTPUT_FILES))


def check_output_path(path: str | Path, folder: bool, replaced: bool = False) -> None:
    """Refuse a path that cannot become a folder or a file, before any work.

    Where it exists it must be one already (a file is not replaced by a folder, nor a folder by a
    file), and its nearest existing ancestor must be a folder the process may write in. A folder
    to be replaced as a whole must not be the current folder or contain it, and where it exists it
    must be an output folder (`is_output_folder`) unless `allow_replacing_foreign_folders`.

    Parameters
    ----------
    path : str or Path
        The output path.
    folder : bool
        Whether it is to be a folder (else a file).
    replaced : bool, optional
        Whether the folder is replaced as a whole (`atomic_directory`).

    Raises
    ------
    InputError
        If ``path`` is of the other kind, an ancestor is a file, or the folder may not be replaced.
    PermissionError
        If the nearest existing ancestor cannot be written in.
    """
    path = Path(path)
    try:  # one stat: another writer may be swapping the folder right now
        is_dir = stat.S_ISDIR(path.stat().st_mode)
    except (FileNotFoundError, NotADirectoryError):
        is_dir = None
    if is_dir is not None and is_dir != folder:
        raise InputError(path, "exists and is not a folder" if folder else "is a folder, not a file")
    ancestor = path.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if ancestor.exists() and not ancestor.is_dir():
        raise InputError(ancestor, "is a file, so nothing can be written under it")
    if folder and replaced:
        resolved, here = path.resolve(), Path.cwd().resolve()
        if resolved == here or resolved in here.parents:
            raise InputError(path, "is the current folder or contains it, and an output folder is replaced as a "
                                   "whole: choose a new folder")
        if is_dir and not _replace_foreign.get() and not is_output_folder(path):
            raise InputError(path, "exists and holds files freqbrdf did not write, which would be replaced: "
                                   "choose another folder, or pass --force (freqbrdf --force COMMAND ...)")
    if ancestor.exists() and not os.access(ancestor, os.W_OK | os.X_OK):
        raise PermissionError(errno.EACCES, "permission denied: nothing can be written here", str(ancestor))


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; it replaces ``path`` only if the block succeeds.

    The temporary name keeps the suffix, so writers that pick a format by extension still work.
    On failure the temporary file is removed and ``path`` is left as it was.

    Parameters
    ----------
    path : str or Path
        The file to write; its parent folders are created.

    Yields
    ------
    Path
        The temporary file to write to (it exists, empty).

    Raises
    ------
    InputError
        If ``path`` cannot become a file (`check_output_path`).
    """
    path = Path(path)
    check_output_path(path, folder=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    _plain_permissions(tmp, 0o666)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def atomic_directory(path: str | Path) -> Iterator[Path]:
    """Yield a temporary directory that becomes ``path`` only if the block succeeds.

    An existing ``path`` is replaced as a whole, so readers never see a half-written result; on
    failure the temporary directory is removed and ``path`` is left as it was.

    Parameters
    ----------
    path : str or Path
        The folder to write; its parent folders are created.

    Yields
    ------
    Path
        The temporary directory to write into (it exists, empty).

    Raises
    ------
    InputError
        If ``path`` cannot become a folder or may not be replaced (`check_output_path`).
    PermissionError
        If nothing can be written there.
    """
    path = Path(path)
    check_output_path(path, folder=True, replaced=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    _plain_permissions(tmp, 0o777)
    try:
        yield tmp
        (tmp / OUTPUT_MARKER).write_text(json.dumps({"written_by": "freqbrdf"}) + "\n", encoding="utf-8")
        with _folder_lock(path.parent):  # concurrent writers to one folder take turns at the swap
            if path.exists():
                old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old.", dir=path.parent))
                os.replace(path, old)
                os.replace(tmp, path)
                shutil.rmtree(old)
            else:
                os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)


@contextlib.contextmanager
def _folder_lock(folder: Path) -> Iterator[None]:
    """Hold an exclusive lock on a folder (flock on its descriptor) for the block."""
    descriptor = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX)
        yield
    finally:
        fcntl.flock(descriptor, fcntl.LOCK_UN)
        os.close(descriptor)


def _plain_permissions(path: Path, mode: int) -> None:
    """Give ``path`` what a plain open()/mkdir() would (umask); mkstemp/mkdtemp create 0600/0700."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, mode & ~umask)


def write_json(path: str | Path, document: dict) -> None:
    """Write a document as indented JSON, atomically; NaN and infinities become null (strict JSON).

    Parameters
    ----------
    path : str or Path
        The file.
    document : dict
        The document; numpy scalars and arrays are converted to plain Python values.
    """
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(_json_ready(document), indent=2, allow_nan=False) + "\n", encoding="utf-8")


def _json_ready(value):
    """Convert to plain Python types for json: numpy scalars and arrays, non-finite floats -> None."""
    if isinstance(value, dict):
        return {str(key): _json_ready(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(item) for item in value]
    if isinstance(value, np.ndarray):
        return _json_ready(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    return value
