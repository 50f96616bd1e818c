"""Shared test helpers."""

from __future__ import annotations

import sys

import pytest

from freqbrdf.cli import main


@pytest.fixture
def run_cli(monkeypatch):
    """Run the ``freqbrdf`` command line in-process; returns its exit code."""

    def run(*arguments) -> int:
        monkeypatch.setattr(sys, "argv", ["freqbrdf", *map(str, arguments)])
        with pytest.raises(SystemExit) as exit_info:
            main()
        return exit_info.value.code or 0

    return run
