"""Atomic file output: write to a temporary sibling, rename on success, remove on failure."""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from freqbrdf.errors import InputError


def check_output_path(path: str | Path, folder: bool) -> None:
    """Refuse a path that cannot become a folder or a file.

    Where it exists it must be one already (a file is not replaced by a folder, nor a folder by a
    file), and its nearest existing ancestor must be a folder.

    Parameters
    ----------
    path : str or Path
        The output path.
    folder : bool
        Whether it is to be a folder (else a file).

    Raises
    ------
    InputError
        If ``path`` is of the other kind or an ancestor is a file.
    """
    path = Path(path)
    if path.exists() and path.is_dir() != folder:
        raise InputError(path, "exists and is not a folder" if folder else "is a folder, not a file")
    ancestor = path.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if ancestor.exists() and not ancestor.is_dir():
        raise InputError(ancestor, "is a file, so nothing can be written under it")


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
        If ``path`` cannot become a folder (`check_output_path`).
    """
    path = Path(path)
    check_output_path(path, folder=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    _plain_permissions(tmp, 0o777)
    try:
        yield tmp
        if path.exists():
            old = path.with_name(f".{path.name}.old")
            if old.is_dir():
                shutil.rmtree(old)
            elif old.exists():  # a stray file of that name
                old.unlink()
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old)
        else:
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)


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
