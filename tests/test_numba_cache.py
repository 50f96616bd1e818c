"""numba's cache keyed by the kernels' sources (freqbrdf._numba_cache)."""

from __future__ import annotations

import os
import time

import numba

from freqbrdf import _numba_cache


def test_the_package_points_numbas_cache_at_the_folder_of_its_sources():
    configured = os.environ["NUMBA_CACHE_DIR"]
    digest = _numba_cache.sources_digest()[: _numba_cache.DIGEST_CHARACTERS]
    assert os.path.basename(configured) == _numba_cache.FOLDER_PREFIX + digest
    assert numba.core.config.CACHE_DIR == configured


def test_the_digest_follows_the_modules_that_mention_numba_only(tmp_path, monkeypatch):
    (tmp_path / "kernels.py").write_text("import numba\n")
    (tmp_path / "plain.py").write_text("x = 1\n")
    monkeypatch.setattr(_numba_cache, "PACKAGE", tmp_path)
    first = _numba_cache.sources_digest()
    (tmp_path / "plain.py").write_text("x = 2\n")
    assert _numba_cache.sources_digest() == first
    (tmp_path / "kernels.py").write_text("import numba  # edited\n")
    assert _numba_cache.sources_digest() != first


def test_a_users_cache_folder_holds_ours_and_a_child_process_keeps_it(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    monkeypatch.setattr(numba.core.config, "CACHE_DIR", "")
    folder = _numba_cache.key_cache_by_sources()
    assert folder.parent == tmp_path / "mine" and folder.name.startswith(_numba_cache.FOLDER_PREFIX)
    assert os.environ["NUMBA_CACHE_DIR"] == str(folder) == numba.core.config.CACHE_DIR
    assert _numba_cache.key_cache_by_sources() == folder  # the environment a child process inherits


def test_old_folders_are_pruned_beyond_the_most_recent_few(tmp_path):
    base = tmp_path / "numba"
    for age, name in enumerate(("freqbrdf-a", "freqbrdf-b", "freqbrdf-c", "freqbrdf-d")):
        (base / name).mkdir(parents=True)
        stamp = time.time() - 100 * (age + 1)
        os.utime(base / name, (stamp, stamp))
    (base / "other").mkdir()
    _numba_cache._prune(base / "freqbrdf-new")
    assert sorted(path.name for path in base.iterdir()) == ["freqbrdf-a", "freqbrdf-b", "other"]
