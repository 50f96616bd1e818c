"""The one error type for bad user input: it always names the file and the problem."""

from __future__ import annotations

from pathlib import Path


class InputError(Exception):
    """Bad input. ``str(err)`` is ``"<file>: <problem>"``, fit for a one-line CLI message."""

    def __init__(self, path: str | Path | None, problem: str):
        self.path = None if path is None else Path(path)
        self.problem = problem
        where = str(self.path) if self.path is not None else "input"
        super().__init__(f"{where}: {problem}")
