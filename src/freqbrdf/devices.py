"""Where the hot stages run: the CPU (the reference) or a CUDA device (docs/method.md#sh-fit, docs/method.md#estimation, docs/method.md#entropy).

The SH least squares, the global search and the entropy have numba CPU kernels and, in the
private ``_cuda_kernels`` modules beside them, CUDA kernels compiled by numba-cuda (the ``[gpu]``
extra) from the same per-texel functions. `resolve_device` turns the ``Config.device`` setting
("auto", "cpu" or "cuda") into the backend that runs; `cuda_status` says whether CUDA can.

The rest is for the CUDA kernels' callers: moving the kernels' named records (tuples of arrays)
to the device and back, per-thread scratch, and the launch size. Under numba's CUDA simulator
(``NUMBA_ENABLE_CUDASIM=1``, for tests without a GPU) the records stay host arrays: the simulator
hands arrays inside tuples to the kernels unchanged, so the per-texel functions they call run as
the CPU compiled them.
"""

from __future__ import annotations

import functools
import importlib.util
import os
from typing import Literal, NamedTuple

import numpy as np

__all__ = ["DEVICES", "CudaStatus", "Device", "cuda_status", "describe_device", "resolve_device"]

Device = Literal["auto", "cpu", "cuda"]
DEVICES: tuple[str, ...] = ("auto", "cpu", "cuda")
"""The values of ``Config.device`` and of ``--device``."""

# Threads per CUDA block of the per-texel kernels.
THREADS_PER_BLOCK = 128
# The share of the device's free memory the per-thread scratch of one launch may take.
SCRATCH_SHARE = 0.25


class CudaStatus(NamedTuple):
    """Whether the CUDA backend can run here.

    Attributes
    ----------
    available : bool
        A CUDA device answers (or numba's CUDA simulator is on).
    simulator : bool
        numba's CUDA simulator is on (``NUMBA_ENABLE_CUDASIM=1``): kernels run on the CPU, slowly.
    extra_installed : bool
        numba-cuda (the ``[gpu]`` extra) is installed.
    name : str
        The device's name, or why there is none.
    """

    available: bool
    simulator: bool
    extra_installed: bool
    name: str


@functools.cache
def cuda_status() -> CudaStatus:
    """Find out, once per process, whether a CUDA device and numba-cuda are present.

    Returns
    -------
    CudaStatus
        What `resolve_device` decides on.
    """
    extra = importlib.util.find_spec("numba_cuda") is not None
    simulator = os.environ.get("NUMBA_ENABLE_CUDASIM", "0") not in ("", "0")
    if not (extra or simulator):  # no kernels to run: the driver is not probed (a quarter second)
        return CudaStatus(False, False, False, "numba-cuda (the [gpu] extra) is not installed")
    try:
        from numba import cuda

        available = bool(cuda.is_available())
        if simulator:
            name = "numba's CUDA simulator"
        elif available:
            name = cuda.get_current_device().name
            name = name.decode() if isinstance(name, bytes) else str(name)
        else:
            name = "no CUDA device or driver found"
    except Exception as err:  # a broken toolkit or driver is "no CUDA" to the automatic choice
        available, name = False, f"CUDA unusable ({type(err).__name__}: {err})"
    return CudaStatus(available, simulator, extra, name)


def resolve_device(device: str) -> str:
    """Turn a ``Config.device`` setting into the backend that runs.

    Parameters
    ----------
    device : {"auto", "cpu", "cuda"}
        "auto": CUDA where a device answers and numba-cuda (the ``[gpu]`` extra) is installed,
        else the CPU; "cuda" insists on CUDA (numba's simulator counts, for tests).

    Returns
    -------
    str
        "cpu" or "cuda".

    Raises
    ------
    ValueError
        For a value not in `DEVICES`, or "cuda" where no CUDA device answers.
    """
    if device not in DEVICES:
        raise ValueError(f"device must be one of {', '.join(DEVICES)}; got {device!r}")
    if device == "cpu":
        return "cpu"
    status = cuda_status()
    if device == "cuda":
        if not status.available:
            raise ValueError(f"device 'cuda' asked for, but {status.name}; install the [gpu] extra on a machine "
                             "with an NVIDIA GPU, or use --device cpu")
        return "cuda"
    return "cuda" if status.available and status.extra_installed and not status.simulator else "cpu"


def describe_device(device: str) -> str:
    """Say in one line which backend a ``Config.device`` setting runs on, and why.

    Parameters
    ----------
    device : {"auto", "cpu", "cuda"}
        The setting.

    Returns
    -------
    str
        E.g. "cuda (NVIDIA H200)" or "cpu (auto: numba-cuda is not installed)".

    Raises
    ------
    ValueError
        As `resolve_device`.
    """
    chosen = resolve_device(device)
    status = cuda_status()
    if chosen == "cuda":
        return f"cuda ({status.name})"
    if device == "cpu":
        return "cpu (asked for)"
    if not status.available:
        return f"cpu (auto: {status.name})"
    if status.simulator:
        return "cpu (auto: the CUDA simulator is only for tests; --device cuda uses it)"
    return "cpu (auto: numba-cuda is not installed: pip install 'freqbrdf[gpu]')"


# ---------------------------------------------------------------------------------------------
# For the CUDA kernels' callers


def _is_array(value) -> bool:
    return isinstance(value, np.ndarray)


def to_device(record):
    """Copy a kernel's record (a tuple, possibly nested, of arrays and scalars) to the device.

    Arrays become contiguous device arrays; scalars stay. Under the simulator the record is
    returned as it is (module docstring): the per-texel functions see the CPU's own arrays.
    """
    if isinstance(record, tuple):
        values = [to_device(value) for value in record]
        return type(record)(*values) if hasattr(record, "_fields") else tuple(values)
    if not _is_array(record) or cuda_status().simulator:
        return record
    from numba import cuda

    return cuda.to_device(np.ascontiguousarray(record))


def copy_to_host(device_record, host_record) -> None:
    """Copy the arrays of a record `to_device` made back into the host record's arrays.

    Each host array receives its device array's contents. A no-op under the simulator, where the
    kernels wrote the host arrays.
    """
    if isinstance(host_record, tuple):
        for device_value, host_value in zip(device_record, host_record):
            copy_to_host(device_value, host_value)
        return
    if not _is_array(host_record) or device_record is host_record:
        return
    if host_record.flags.c_contiguous:
        device_record.copy_to_host(host_record)
    else:
        host_record[...] = device_record.copy_to_host()


def slot_scratch(template, n_slots: int):
    """Give each of n_slots threads its own copy of a scratch record: arrays of shape (n_slots, ...).

    template holds one thread's arrays with their initial contents, which every slot receives.
    """
    if isinstance(template, tuple):
        values = [slot_scratch(value, n_slots) for value in template]
        return type(template)(*values) if hasattr(template, "_fields") else tuple(values)
    if not _is_array(template):
        return template
    stacked = np.empty((n_slots, *template.shape), template.dtype)
    stacked[...] = template
    if cuda_status().simulator:
        return stacked
    from numba import cuda

    return cuda.to_device(stacked)


def record_bytes(record) -> int:
    """Return the bytes of a record's arrays."""
    if isinstance(record, tuple):
        return sum(record_bytes(value) for value in record)
    return int(record.nbytes) if _is_array(record) else 0


def launch_size(n_items: int, slot_bytes: int) -> tuple[int, int]:
    """Return (blocks, threads per block) for one thread per item, within the scratch's memory.

    Threads take items in a grid-stride loop, so fewer threads than items is correct; the scratch
    of all threads stays within `SCRATCH_SHARE` of the device's free memory.
    """
    n_threads = max(n_items, 1)
    if not cuda_status().simulator and slot_bytes > 0:
        from numba import cuda

        free, _ = cuda.current_context().get_memory_info()
        n_threads = min(n_threads, max(int(SCRATCH_SHARE * free) // slot_bytes, THREADS_PER_BLOCK))
    threads = min(THREADS_PER_BLOCK, n_threads)
    return (n_threads + threads - 1) // threads, threads
