"""Shared test fixtures; builders live in tests/helpers.py (importable from every test folder)."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `import helpers` from tests in subfolders

from freqbrdf.cli import RERUN_VARIABLE, main

# The command line re-runs a first run that compiled numba kernels in a fresh process (os.execve):
# never the test process. test_cli.py tests that re-run in a child process of its own.
os.environ[RERUN_VARIABLE] = "1"
# Generated atlases go to a cache of the test run's own, not the user's.
os.environ["FREQBRDF_CACHE"] = tempfile.mkdtemp(prefix="freqbrdf-cache-")


@pytest.fixture
def run_cli(monkeypatch):
    """Run the ``freqbrdf`` command line in-process; returns its exit code."""

    def run(*arguments) -> int:
        monkeypatch.setattr(sys, "argv", ["freqbrdf", *map(str, arguments)])
        with pytest.raises(SystemExit) as exit_info:
            main()
        return exit_info.value.code or 0

    return run
