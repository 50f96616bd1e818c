"""Progress reporting shared by every long stage: rich progress bars, or silence for scripts."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
)

Advance = Callable[[int], None]


class Reporter:
    """Hand out progress bars per stage.

    Parameters
    ----------
    enabled : bool, optional
        Show bars; False makes every bar a no-op.
    console : rich.console.Console, optional
        Where bars are drawn; default a console on standard error.
    """

    def __init__(self, enabled: bool = True, console: Console | None = None):
        self.enabled = enabled
        self.console = console or Console(stderr=True)

    @contextlib.contextmanager
    def stage(self, description: str, total: int) -> Iterator[Advance]:
        """Show a progress bar for one stage while the block runs.

        Parameters
        ----------
        description : str
            The stage's name, shown left of the bar.
        total : int
            Number of steps.

        Yields
        ------
        callable (steps: int = 1) -> None
            Advances the bar by ``steps``.
        """
        if not self.enabled:
            yield lambda steps=1: None
            return
        columns = (
            TextColumn("{task.description:<24}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
        )
        with Progress(*columns, console=self.console, transient=False) as progress:
            task = progress.add_task(description, total=total)
            yield lambda steps=1: progress.advance(task, steps)


SILENT = Reporter(enabled=False)
