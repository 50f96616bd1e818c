"""Atomic outputs: a folder or file appears whole or not at all, and never replaces the wrong kind."""

from __future__ import annotations

import contextvars
import os
import threading

import pytest

from freqbrdf.errors import InputError
from freqbrdf.fileio import (
    OUTPUT_MARKER,
    allow_replacing_foreign_folders,
    atomic_directory,
    atomic_path,
    check_output_path,
    is_output_folder,
)


def names(folder) -> list[str]:
    """The folder's entries, the output marker left out."""
    return sorted(p.name for p in folder.iterdir() if p.name != OUTPUT_MARKER)


def test_a_folder_replaces_the_old_one_whole_and_a_failed_write_keeps_it(tmp_path):
    out = tmp_path / "out"
    with atomic_directory(out) as folder:
        (folder / "a.txt").write_text("first")
    assert (out / OUTPUT_MARKER).is_file()
    # A stray file where an old folder might be parked neither gets in the way nor is removed.
    (tmp_path / ".out.old").write_text("stray")
    with atomic_directory(out) as folder:
        (folder / "b.txt").write_text("second")
    assert names(out) == ["b.txt"]
    with pytest.raises(RuntimeError), atomic_directory(out) as folder:
        (folder / "c.txt").write_text("half")
        raise RuntimeError("the writer failed")
    assert names(out) == ["b.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".out.old", "out"]


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


def test_a_folder_freqbrdf_did_not_write_is_refused_before_the_work_and_kept(tmp_path, monkeypatch):
    mine = tmp_path / "thesis"
    mine.mkdir()
    (mine / "thesis.txt").write_text("years of work")
    with pytest.raises(InputError, match="thesis: exists and holds files freqbrdf did not write"):
        check_output_path(mine, folder=True, replaced=True)
    with pytest.raises(InputError, match="did not write"), atomic_directory(mine):
        pytest.fail("the block must not run")
    assert names(mine) == ["thesis.txt"] and (mine / "thesis.txt").read_text() == "years of work"
    # An empty folder, or one an earlier version wrote (summary.json), may be replaced.
    empty = tmp_path / "empty"
    empty.mkdir()
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / "summary.json").write_text("{}")
    assert is_output_folder(empty) and is_output_folder(earlier) and not is_output_folder(mine)
    # --force lets it replace the user's folder.
    context = contextvars.copy_context()

    def forced():
        allow_replacing_foreign_folders(True)
        with atomic_directory(mine) as folder:
            (folder / "fit.txt").write_text("fit")

    context.run(forced)
    assert names(mine) == ["fit.txt"]
    # The current folder, and any folder containing it, is never replaced.
    monkeypatch.chdir(tmp_path / "empty")
    with pytest.raises(InputError, match="is the current folder or contains it"):
        check_output_path(".", folder=True, replaced=True)
    with pytest.raises(InputError, match="is the current folder or contains it"):
        check_output_path(tmp_path, folder=True, replaced=True)


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write in a read-only folder, so there is nothing to refuse")
def test_a_folder_nothing_can_be_written_in_is_refused_before_the_work(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        with pytest.raises(PermissionError, match="permission denied") as refusal:
            check_output_path(locked / "out", folder=True, replaced=True)
        assert refusal.value.filename == str(locked)
    finally:
        locked.chmod(0o755)


def test_concurrent_writers_to_one_folder_leave_one_whole_result(tmp_path):
    out = tmp_path / "out"
    with atomic_directory(out) as folder:
        (folder / "start.txt").write_text("start")
    start = threading.Barrier(4)
    failures = []

    def write(index):
        try:
            start.wait()
            for round_ in range(5):
                with atomic_directory(out) as folder:
                    for part in range(3):
                        (folder / f"part{part}.txt").write_text(f"{index}-{round_}")
        except Exception as err:  # noqa: BLE001 - every failure is reported below
            failures.append(err)

    threads = [threading.Thread(target=write, args=(index,)) for index in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert failures == []
    contents = {(out / f"part{part}.txt").read_text() for part in range(3)}
    assert names(out) == ["part0.txt", "part1.txt", "part2.txt"] and len(contents) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
