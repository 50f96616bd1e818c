"""numba's cache of freqbrdf's kernels, kept in a folder named by the sources the kernels come from.

numba keys a cached kernel on its own source file only (its time stamp and size), while a kernel
carries the code of every jitted function it calls from other files. After an edit (or a pull)
that changes only a called function, the kernel would be loaded stale from the cache and run the
old code: different results for the same sources. So the cache lives in a folder named by a
digest of every package module that mentions numba: an edit to any of them starts a fresh folder
(the first run compiles, `freqbrdf.jit` reruns it from the cache), and a folder is never read
with other sources. Set before numba reads its configuration: `freqbrdf/__init__.py` calls
`key_cache_by_sources` first thing. The setting is numba's, for the whole process: other
libraries' cached functions go to the same folder.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
# A folder of the cache: this prefix, then the first characters of the digest.
FOLDER_PREFIX = "freqbrdf-"
DIGEST_CHARACTERS = 16
# Folders of other digests kept beside the current one in the package's own cache (older ones go).
KEEP_OTHER_FOLDERS = 2


def sources_digest() -> str:
    """Return the sha256 hex digest of the package modules that mention numba (paths and contents).

    Returns
    -------
    str
        64 hex characters.
    """
    digest = hashlib.sha256()
    for path in sorted(PACKAGE.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        text = path.read_bytes()
        if b"numba" in text:
            digest.update(path.relative_to(PACKAGE).as_posix().encode() + b"\0" + text + b"\0")
    return digest.hexdigest()


def cache_folder(base: str | os.PathLike | None = None) -> Path:
    """Return the cache folder for the current sources.

    Parameters
    ----------
    base : path, optional
        Where the folders live: a user's NUMBA_CACHE_DIR; default the package's own
        ``__pycache__/numba`` where it can be written, else ``~/.cache/freqbrdf/numba``
        (``$XDG_CACHE_HOME`` honoured).

    Returns
    -------
    Path
        ``base / "freqbrdf-<digest>"``.
    """
    if base is None:
        base = PACKAGE / "__pycache__" / "numba"
        if not _writable(base):
            base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "freqbrdf" / "numba"
    return Path(base) / f"{FOLDER_PREFIX}{sources_digest()[:DIGEST_CHARACTERS]}"


def key_cache_by_sources() -> Path:
    """Point numba's cache at `cache_folder` (inside a user's NUMBA_CACHE_DIR where one is set).

    Sets NUMBA_CACHE_DIR for numba to read (and for child processes, which keep the folder), or
    numba's configuration where numba is imported already. In the package's own cache, the folders
    of older sources beyond the ``KEEP_OTHER_FOLDERS`` most recent are removed.

    Returns
    -------
    Path
        The folder.
    """
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user and Path(user).name.startswith(FOLDER_PREFIX):
        folder = Path(user)  # set by a parent process: already keyed
    else:
        folder = cache_folder(user or None)
        if not user:
            _prune(folder)
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.CACHE_DIR = str(folder)
    return folder


def _writable(folder: Path) -> bool:
    existing = next((parent for parent in (folder, *folder.parents) if parent.exists()), None)
    return existing is not None and os.access(existing, os.W_OK)


def _prune(folder: Path) -> None:
    """Remove the package cache's folders of other sources but the most recently used few."""
    import shutil

    try:
        others = [path for path in folder.parent.glob(f"{FOLDER_PREFIX}*") if path != folder and path.is_dir()]
        others.sort(key=lambda path: path.stat().st_mtime, reverse=True)
        for path in others[KEEP_OTHER_FOLDERS:]:
            shutil.rmtree(path, ignore_errors=True)
    except OSError:
        pass  # a cache that cannot be tidied still works
