"""The ``freqbrdf`` command line. Bad input is one clear line and exit code 2."""

from __future__ import annotations

import sys

import typer
from rich.console import Console

from freqbrdf import __version__
from freqbrdf.errors import InputError

app = typer.Typer(
    name="freqbrdf",
    help="Per-texel BRDF maps and their uncertainty from posed HDR photographs.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
err_console = Console(stderr=True)
_state = {"debug": False}


def _version(value: bool) -> None:
    if value:
        typer.echo(f"freqbrdf {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors."),
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True),
) -> None:
    _state["debug"] = debug


@app.command()
def demo(out: str = typer.Option("out/demo", help="Output folder.")) -> None:
    """Render the bundled capture, fit it, and write the report (not yet available)."""
    err_console.print("freqbrdf demo: not yet available (it lands with the demo issue).")
    raise typer.Exit(1)


def main() -> None:
    try:
        app()
    except InputError as err:
        if _state["debug"]:
            raise
        err_console.print(f"[red]error:[/red] {err}", highlight=False, soft_wrap=True)
        sys.exit(2)


if __name__ == "__main__":
    main()
