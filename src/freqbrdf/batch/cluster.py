"""Ray for a batch: how many captures a machine runs at once, and starting or joining Ray.

On this machine a batch runs as many captures at once as its cores give `FIT_THREADS` each and its
available memory holds (`default_workers`, `fit_memory`); each capture's task asks Ray for that
many CPUs and that much memory. `start_local_ray` starts Ray here, `join_cluster` joins a cluster
by its address, and `check_workers` runs one small task (`freqbrdf.batch.tasks.worker_facts`) as
the captures will run, so that a worker without this freqbrdf fails the batch before any capture
is sent. A worker that dies (killed, out of memory) is retried at most `MAX_RETRIES` times.
"""

from __future__ import annotations

import os
import re
import socket

from freqbrdf import __version__
from freqbrdf.batch.tasks import worker_facts
from freqbrdf.errors import InputError

MAX_RETRIES = 2  # Ray's retries of a capture whose worker died
FIT_THREADS = 2  # CPUs (numba threads) per capture by default: what one fit uses well
# Memory one fit is scheduled with, as bytes at texture side T: a fixed part (the interpreter,
# numba, Mitsuba) plus a part growing with the texels; the two sum to the peak of a T = 512 fit
# (docs/results.md#batch) with a margin.
FIT_MEMORY_FIXED = int(0.75 * 2**30)
FIT_MEMORY_AT_512 = int(0.75 * 2**30)


def fit_memory(texture_res: int) -> int:
    """Tell the bytes of memory one capture is scheduled with at texture side ``texture_res``.

    Parameters
    ----------
    texture_res : int
        T of the fit.

    Returns
    -------
    int
        `FIT_MEMORY_FIXED` plus `FIT_MEMORY_AT_512` scaled by the texels, (T / 512)^2.
    """
    return FIT_MEMORY_FIXED + int(FIT_MEMORY_AT_512 * (texture_res / 512) ** 2)


def _available_memory() -> int:
    try:
        with open("/proc/meminfo", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def default_workers(threads: int = FIT_THREADS, texture_res: int = 512, cores: int | None = None,
                    memory: int | None = None) -> int:
    """Count the captures this machine runs at once.

    As many as its cores give ``threads`` each and its available memory holds (`fit_memory`), at
    least one.

    Parameters
    ----------
    threads : int
        CPUs per capture.
    texture_res : int
        The largest T of the captures.
    cores, memory : int, optional
        The machine's cores and available bytes (default: this machine's).

    Returns
    -------
    int
        The number of workers, >= 1.
    """
    cores = (os.cpu_count() or 1) if cores is None else cores
    memory = _available_memory() if memory is None else memory
    return max(1, min(cores // threads, memory // fit_memory(texture_res)))


def last_line(error: BaseException) -> str:
    """Take the last line of an error's text, without terminal colours.

    Ray's tracebacks end with the cause.

    Parameters
    ----------
    error : BaseException
        The error.

    Returns
    -------
    str
        Its text's last line, else its type's name.
    """
    text = re.sub(r"\x1b\[[0-9;]*m", "", str(error)).strip()
    return (text.splitlines() or [type(error).__name__])[-1].strip()


def check_workers(ray, options: dict) -> None:
    """Run one small task as the captures will run, before any capture is sent.

    Parameters
    ----------
    ray : module
        The ``ray`` module, initialised.
    options : dict
        The captures' task options (``num_cpus``, ``runtime_env``).

    Raises
    ------
    InputError
        Where no worker starts within 300 s, or a worker cannot run this freqbrdf (not installed
        there, another version).
    """
    try:
        facts = ray.get(ray.remote(worker_facts).options(max_retries=0, **options).remote(), timeout=300)
    except ray.exceptions.GetTimeoutError:
        raise InputError(None, "no Ray worker started within 300 s: does the cluster have a node with "
                               f"{options['num_cpus']} free CPUs?") from None
    except ray.exceptions.RayError as err:
        cause = err.cause if isinstance(err, ray.exceptions.RayTaskError) and err.cause is not None else err
        raise InputError(None, f"Ray's workers cannot run freqbrdf.batch ({last_line(cause)}); install freqbrdf "
                               f"{__version__} on every node") from None
    if facts["freqbrdf"] != __version__:
        raise InputError(None, f"Ray's worker on {facts['host']} has freqbrdf {facts['freqbrdf']}, this batch "
                               f"{__version__}: install the same version on every node")


def largest_node(nodes: list[dict], resource: str) -> float:
    """Find the most of a resource that one live node of a Ray cluster has.

    Parameters
    ----------
    nodes : list of dict
        ``ray.nodes()``.
    resource : str
        A resource's name (``"CPU"``, ``"memory"``).

    Returns
    -------
    float
        Its amount on the live node that has most of it, 0 where none has it.
    """
    return max((node.get("Resources", {}).get(resource, 0.0) for node in nodes if node.get("Alive")), default=0.0)


def start_local_ray(cpus: int) -> None:
    """Start Ray on this machine, quietly, for this process.

    Parameters
    ----------
    cpus : int
        The CPUs Ray may schedule: the workers times their threads.
    """
    import logging

    import ray

    ray.init(address="local", num_cpus=cpus, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR,
             object_store_memory=256 * 2**20,
             # Ray's memory monitor retries a task it stopped without bound by default.
             _system_config={"task_oom_retries": MAX_RETRIES})


def join_cluster(address: str) -> None:
    """Connect to the Ray cluster at ``address``, failing at once where nothing answers there.

    Ray itself would try again for minutes; an address with a port (``HOST:PORT`` or
    ``ray://HOST:PORT``) is tried first with a plain connection, for a few seconds.

    Parameters
    ----------
    address : str
        ``"auto"``, ``"HOST:PORT"`` or ``"ray://HOST:PORT"``.

    Raises
    ------
    InputError
        Where nothing answers at the address, or Ray cannot connect there.
    """
    import logging

    import ray

    match = re.fullmatch(r"(?:ray://)?\[?([^\]/]+?)\]?:(\d+)", address.strip())
    if match:
        try:
            socket.create_connection((match.group(1), int(match.group(2))), timeout=5).close()
        except OSError as err:
            raise InputError(None, f"no Ray cluster answers at {address} ({err.strerror or err}); start one with "
                                   "`ray start --head`, or leave out --address to run on this machine") from None
    try:
        ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
    except ConnectionError as err:
        raise InputError(None, f"no Ray cluster at {address!r}: {str(err).splitlines()[0]}") from None
