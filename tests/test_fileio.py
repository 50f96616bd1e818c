"""Atomic outputs: a folder or file appears whole or not at all, and never replaces the wrong kind."""

from __future__ import annotations

import pytest

from freqbrdf.errors import InputError
from freqbrdf.fileio import atomic_directory, atomic_path


def test_a_folder_replaces_the_old_one_whole_and_a_failed_write_keeps_it(tmp_path):
    out = tmp_path / "out"
    with atomic_directory(out) as folder:
        (folder / "a.txt").write_text("first")
    # A stray file where the old folder is parked does not get in the way.
    (tmp_path / ".out.old").write_text("stray")
    with atomic_directory(out) as folder:
        (folder / "b.txt").write_text("second")
    assert sorted(p.name for p in out.iterdir()) == ["b.txt"]
    with pytest.raises(RuntimeError), atomic_directory(out) as folder:
        (folder / "c.txt").write_text("half")
        raise RuntimeError("the writer failed")
    assert sorted(p.name for p in out.iterdir()) == ["b.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_file_is_not_replaced_by_a_folder_nor_a_folder_by_a_file(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("keep me")
    with pytest.raises(InputError, match="a_file: exists and is not a folder"), atomic_directory(a_file):
        pytest.fail("the block must not run")
    with pytest.raises(InputError, match="a_file: is a file, so nothing can be written under it"):
        with atomic_directory(a_file / "deeper" / "out"):
            pytest.fail("the block must not run")
    a_folder = tmp_path / "a_folder"
    a_folder.mkdir()
    with pytest.raises(InputError, match="a_folder: is a folder, not a file"), atomic_path(a_folder):
        pytest.fail("the block must not run")
    assert a_file.read_text() == "keep me" and a_folder.is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "a_folder"]
