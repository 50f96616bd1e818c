"""What every ``freqbrdf`` command does around its work (`freqbrdf.cli`).

Load and check the capture before any work, printing its warnings once; say when numba compiles
its kernels and which backend runs; after a first run that compiled kernels, run the command again
from numba's cache so that its results match every later run's (docs/method.md#outputs).
"""

from __future__ import annotations

import os
import sys

from rich.console import Console
from rich.markup import escape

err_console = Console(stderr=True)
# Set in the process that re-runs a command, so that it is re-run once at most; set it yourself to
# keep a first run's results.
RERUN_VARIABLE = "FREQBRDF_RERUN"


def _checked(capture: str, quiet: bool, lmax: int, out: str | None = None):
    """Load a capture and check it before any work (`freqbrdf.capture.checks`, for SH degree ``lmax``).

    Its warnings are printed once, one line per kind (none with ``quiet``), and returned with it
    (``fit`` records them in summary.json); the data warnings the later stages would raise again
    are silenced. When numba starts compiling kernels, that is said. ``out`` (the command's output
    folder) must not be the capture's folder or hold it: refused here, before the work.
    """
    import warnings

    from freqbrdf.images import CaptureDataWarning

    if not quiet:
        _announce_compilation()
    loaded, _, lines = _load_and_check(capture, lmax)
    if out is not None:
        from freqbrdf.outputs.fit_folder import check_output_folder

        check_output_folder(out, {"the capture": loaded.root.resolve()})
    if not quiet:
        for line in lines:
            err_console.print(f"[yellow]warning:[/yellow] {escape(line)}", highlight=False, soft_wrap=True)
    warnings.filterwarnings("ignore", category=CaptureDataWarning)  # said once, above
    return loaded, lines


def _announce_compilation() -> None:
    """Say so when numba starts compiling kernels (its cache is empty or stale), once."""
    from freqbrdf.jit import on_first_compilation

    if os.environ.get(RERUN_VARIABLE):
        return  # the fresh process of `_results_from_cache`: said already
    on_first_compilation(lambda: err_console.print(
        "numba is compiling its kernels on first use (up to about a minute, once: later runs load them from its "
        "cache)", highlight=False))


def _load_and_check(capture: str, lmax: int | None):
    """Load and check a capture: (the capture, its `CaptureCheck`, every warning line of both)."""
    import warnings

    from freqbrdf.capture.checks import check_capture
    from freqbrdf.capture.layouts import load
    from freqbrdf.images import CaptureDataWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CaptureDataWarning)
        loaded = load(capture)
    lines = [str(warning.message) for warning in caught if issubclass(warning.category, CaptureDataWarning)]
    check = check_capture(loaded, lmax=lmax)
    return loaded, check, lines + check.warnings


def _results_from_cache(quiet: bool) -> None:
    """Run this command again in a fresh process if numba compiled kernels in this one.

    Compiled code differs in the last bits from the cached code every later run loads (see
    freqbrdf.jit), so a first run after an install would not reproduce. Call before writing anything.
    """
    from freqbrdf.jit import compiled_here

    compiled = compiled_here()
    if not compiled or os.environ.get(RERUN_VARIABLE):
        return
    if not quiet:
        err_console.print(f"numba compiled {len(compiled)} kernels in this first run; running again from its cache "
                          "so that the results match every later run's", highlight=False)
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, "-m", "freqbrdf.cli", *sys.argv[1:]],
              {**os.environ, RERUN_VARIABLE: "1"})


def _say_backend(device: str, quiet: bool) -> None:
    """Say once on stderr which backend the hot stages run on (``--device``), unless quiet."""
    from freqbrdf.devices import describe_device

    if not quiet:
        err_console.print(f"backend: {escape(describe_device(device))}", highlight=False, soft_wrap=True)
