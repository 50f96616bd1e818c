"""Which of freqbrdf's numba kernels this process compiled rather than loaded from numba's cache.

numba's code for a fast-math kernel differs between the process that compiles it and the processes
that load it from the cache (LLVM's loop vectoriser reassociates sums differently), so the results
of the first run after an install or an edit differ, in the last bits, from every later run's. The
command line uses :func:`compiled_here` to run such a first command again in a fresh process.
"""

from __future__ import annotations

import sys

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
