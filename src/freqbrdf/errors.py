"""The one error type for bad user input: it always names the file and the problem."""

from __future__ import annotations

from pathlib import Path


class InputError(Exception):
    """Bad input from the user, naming the file at fault.

    ``str(err)`` is ``"<file>: <problem>"`` (the problem alone where no file is at fault, e.g. an
    option's value), fit for a one-line CLI message.

    Parameters
    ----------
    path : str or Path or None
        The file at fault; None where none is.
    problem : str
        What is wrong with it.

    Attributes
    ----------
    path : Path or None
        The file at fault.
    problem : str
        What is wrong with it.
    """

    def __init__(self, path: str | Path | None, problem: str):
        self.path = None if path is None else Path(path)
        self.problem = problem
        # A path may hold line breaks or other control characters (a mistyped transforms entry):
        # written escaped, so that the message stays one line.
        where = None if self.path is None else _one_line(str(self.path))
        super().__init__(_one_line(problem) if where is None else f"{where}: {_one_line(problem)}")


def _one_line(text: str) -> str:
    """Return ``text`` with its control characters escaped as Python writes them (a line break as backslash n)."""
    return "".join(character if character.isprintable() else character.encode("unicode_escape").decode("ascii")
                   for character in text)
