"""Which of freqbrdf's numba kernels this process compiled rather than loaded from numba's cache.

numba's code for a fast-math kernel differs between the process that compiles it and the processes
that load it from the cache (LLVM's loop vectoriser reassociates sums differently), so the results
of the first run after an install or an edit differ, in the last bits, from every later run's. The
command line uses :func:`compiled_here` to run such a first command again in a fresh process, and
:func:`on_first_compilation` to say when the minute of compiling starts.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from numba.core import event
from numba.core.registry import CPUDispatcher


def compiled_here() -> list[str]:
    """List the cached kernels of freqbrdf's loaded modules that this process compiled.

    Returns
    -------
    list of str
        Qualified names of the kernels numba's cache missed, sorted.
    """
    names = set()
    for module_name, module in list(sys.modules.items()):
        if module is None or not module_name.startswith("freqbrdf."):
            continue
        for attribute, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.stats.cache_misses:
                names.add(f"{module_name}.{attribute}")
    return sorted(names)



class _FirstCompilation(event.Listener):
    """Calls back once, at the start of the first compilation of one of freqbrdf's kernels."""

    def __init__(self, callback: Callable[[], None]):
        self.callback = callback
        self.called = False
        self.registered = False

    def on_start(self, compile_event) -> None:
        function = getattr(compile_event.data.get("dispatcher"), "py_func", None)
        if self.called or not getattr(function, "__module__", "").startswith("freqbrdf."):
            return
        self.called = True
        self.callback()

    def on_end(self, compile_event) -> None:
        pass


def on_first_compilation(callback: Callable[[], None]) -> None:
    """Call ``callback`` when numba starts compiling a freqbrdf kernel in this process, once.

    Loading a kernel from numba's cache is no compilation; so a command can say, when it happens,
    why a first run takes a minute longer.

    Parameters
    ----------
    callback : callable () -> None
        What to do, e.g. print a line. A later call replaces it, while no compilation has been seen.
    """
    if _LISTENER.called:
        return
    _LISTENER.callback = callback
    if not _LISTENER.registered:  # one listener per process, however many commands run in it
        event.register("numba:compile", _LISTENER)
        _LISTENER.registered = True


_LISTENER = _FirstCompilation(lambda: None)
