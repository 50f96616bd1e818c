"""Ray for a batch: how many captures a machine runs at once, and starting or joining Ray.

On this machine a batch runs as many captures at once as its cores give `FIT_THREADS` each and its
available memory holds (`default_workers`, `fit_memory`); each capture's task asks Ray for that
many CPUs and that much memory. `start_local_ray` starts Ray here. `join_cluster` joins a cluster
by its address as Ray's documentation sets one up (``ray start --head``, ``ray start --address``,
token authentication): it sends Ray's token where it finds one (`find_token`, `use_token`), asks
the head at once whether it takes the token and whether a node of the cluster runs here, and makes
each way joining can fail one `InputError` line. `check_workers` runs one small task
(`freqbrdf.batch.tasks.worker_facts`) on every node as the captures will run, so that a node
without this freqbrdf, or that does not see the captures and the output folder, fails the batch
before any capture is sent. A worker or node that dies (killed, out of memory, lost) has its
capture retried at most `MAX_RETRIES` times.
"""

from __future__ import annotations

import contextlib
import os
import re
import socket
import sys
from pathlib import Path

from freqbrdf import __version__
from freqbrdf.batch.tasks import worker_facts
from freqbrdf.errors import InputError

AUTH_MODE_VARIABLE = "RAY_AUTH_MODE"  # Ray's switch of token authentication: "token" or "disabled"
TOKEN_FILE = Path("~/.ray/auth_token")  # Ray's token file (`ray get-auth-token --generate` writes it)
HEAD_TIMEOUT_S = 10.0  # how long the head of a cluster joined has to answer
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


def check_workers(ray, options: dict, paths: list[str], out: str) -> list[dict]:
    """Run one small task on every node that can take a capture, before any capture is sent.

    Each node's task runs as the captures will (the same CPUs and runtime environment) and tells
    its freqbrdf version and whether it sees every capture and can write to ``out``: on a cluster
    those must be at the same paths on every node.

    Parameters
    ----------
    ray : module
        The ``ray`` module, initialised.
    options : dict
        The captures' task options (``num_cpus``, ``runtime_env``).
    paths : list of str
        The captures, absolute.
    out : str
        The batch's output folder, absolute.

    Returns
    -------
    list of dict
        Each node's `freqbrdf.batch.tasks.worker_facts`.

    Raises
    ------
    InputError
        Where no worker starts within 300 s, a worker cannot run this freqbrdf (not installed
        there, another version), or a node does not see a capture or cannot write to ``out``.
    """
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    nodes = [node for node in ray.nodes()
             if node.get("Alive") and node.get("Resources", {}).get("CPU", 0) >= options["num_cpus"]]
    if not nodes:
        raise InputError(None, f"no node of the Ray cluster has {options['num_cpus']} CPUs for a capture: ask for "
                               "fewer --threads")
    task = ray.remote(worker_facts)
    refs = [task.options(max_retries=0, scheduling_strategy=NodeAffinitySchedulingStrategy(node["NodeID"], soft=False),
                         **options).remote(paths, out) for node in nodes]
    try:
        found = ray.get(refs, timeout=300)
    except ray.exceptions.GetTimeoutError:
        raise InputError(None, "no Ray worker started within 300 s on every node: does each node have "
                               f"{options['num_cpus']} free CPUs?") from None
    except ray.exceptions.RayError as err:
        cause = err.cause if isinstance(err, ray.exceptions.RayTaskError) and err.cause is not None else err
        raise InputError(None, f"Ray's workers cannot run freqbrdf.batch ({last_line(cause)}); install freqbrdf "
                               f"{__version__} on every node") from None
    for node, facts in zip(nodes, found):
        where = f"{facts['host']} ({node['NodeManagerAddress']})"
        if facts["freqbrdf"] != __version__:
            raise InputError(None, f"Ray's worker on {where} has freqbrdf {facts['freqbrdf']}, this batch "
                                   f"{__version__}: install the same version on every node")
        if facts["missing"]:
            raise InputError(facts["missing"][0], f"Ray's node {where} does not see this capture"
                             + (f" (nor {len(facts['missing']) - 1} more)" if len(facts["missing"]) > 1 else "")
                             + ": the captures and --out must be at the same paths on every node")
        if not facts["writable"]:
            raise InputError(out, f"Ray's node {where} cannot write here: the captures and --out must be at the "
                                  "same paths on every node")
    return found


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


def parse_address(address: str) -> tuple[str, str | None, int | None]:
    """Tell the kind of a cluster's address and its host and port.

    Parameters
    ----------
    address : str
        ``"auto"``, ``"HOST:PORT"`` (the head's port of ``ray start --head --port``) or
        ``"ray://HOST:PORT"`` (Ray Client, port 10001 by default).

    Returns
    -------
    kind : str
        ``"auto"``, ``"gcs"`` (a driver on a node of the cluster) or ``"client"`` (Ray Client).
    host : str or None
        The host (None for ``"auto"``).
    port : int or None
        The port (None for ``"auto"``).

    Raises
    ------
    InputError
        Where the address has none of these forms.
    """
    text = address.strip()
    if text == "auto":
        return "auto", None, None
    match = re.fullmatch(r"(ray://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})", text)
    if not match or not 0 < int(match.group(3)) < 65536:
        raise InputError(None, f"--address {address!r} is not auto, HOST:PORT or ray://HOST:PORT")
    return ("client" if match.group(1) else "gcs"), match.group(2).strip("[]"), int(match.group(3))


def find_token() -> str | None:
    """Tell where Ray's token for this process is, in Ray's order; None where there is none.

    ``RAY_AUTH_TOKEN`` (the token itself), else the file ``RAY_AUTH_TOKEN_PATH`` names, else
    Ray's token file `TOKEN_FILE` (``~/.ray/auth_token``, as ``ray get-auth-token --generate``
    writes it).

    Returns
    -------
    str or None
        ``"RAY_AUTH_TOKEN"`` or the token file's path; None where none is set.

    Raises
    ------
    InputError
        Where ``RAY_AUTH_TOKEN_PATH`` names a file that cannot be read or is empty (Ray would end
        the process).
    """
    if os.environ.get("RAY_AUTH_TOKEN", "").strip():
        return "RAY_AUTH_TOKEN"
    named = os.environ.get("RAY_AUTH_TOKEN_PATH")
    if named:
        path = Path(named).expanduser()
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as err:
            raise InputError(path, "RAY_AUTH_TOKEN_PATH names this token file, which cannot be read "
                                   f"({getattr(err, 'strerror', None) or err})") from None
        if not text.strip():
            raise InputError(path, "RAY_AUTH_TOKEN_PATH names this token file, which is empty")
        return str(path)
    path = TOKEN_FILE.expanduser()
    try:
        return str(path) if path.read_text(encoding="utf-8").strip() else None
    except (OSError, UnicodeDecodeError):
        return None


def _token_places() -> str:
    return f"RAY_AUTH_TOKEN, a file named by RAY_AUTH_TOKEN_PATH or {TOKEN_FILE.expanduser()}"


def use_token() -> str | None:
    """Have this process send Ray's token to the cluster it joins, where it has one.

    Ray sends a token only where ``RAY_AUTH_MODE=token``, which a head started by
    ``ray start --head`` with a token does not tell the processes that join it; so where
    ``RAY_AUTH_MODE`` is unset and a token is found (`find_token`), this process sets it, as Ray
    itself does for ``address="auto"``. A cluster without token authentication ignores the token.
    ``RAY_AUTH_MODE=disabled`` is left as it is.

    Returns
    -------
    str or None
        Where the token comes from (`find_token`), None where none is sent.

    Raises
    ------
    InputError
        Where ``RAY_AUTH_MODE=token`` and no token is found, or `find_token` refuses its file.
    """
    source = find_token()
    mode = os.environ.get(AUTH_MODE_VARIABLE)
    if mode is not None and mode.strip().lower() != "token":
        return None
    if source is None:
        if mode is not None:
            raise InputError(None, f"{AUTH_MODE_VARIABLE}=token but no Ray token is set: put the cluster's token "
                                   f"(`ray get-auth-token` on its head) in {_token_places()}")
        return None
    if mode is None:
        os.environ[AUTH_MODE_VARIABLE] = "token"
        try:  # Ray reads the mode once; its own switch to token mode reads it again (Ray >= 2.52)
            from ray._private.authentication.authentication_token_setup import _enable_token_auth
        except ImportError:
            pass
        else:
            _enable_token_auth()
    with contextlib.suppress(ImportError, AttributeError):
        from ray._raylet import AuthenticationTokenLoader

        AuthenticationTokenLoader.instance().reset_cache()
    return source


@contextlib.contextmanager
def _native_stderr_silenced():
    """Send what is written to file descriptor 2 (by Ray's C++ code too) to /dev/null meanwhile."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w", encoding="ascii") as sink:
            os.dup2(sink.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _check_head(address: str, gcs_address: str, token: str | None) -> list:
    """Ask the cluster's head for its live nodes, at once, as the driver will connect.

    Raises InputError where the head refuses the token or nothing answers there as a Ray head.
    """
    import ray  # noqa: F401 - ray._raylet needs ray's own initialisation
    from ray._raylet import InnerGcsClient

    try:
        with _native_stderr_silenced():  # Ray's C++ client logs each refused try; the error below says it once
            client = InnerGcsClient.standalone(gcs_address, None, int(HEAD_TIMEOUT_S * 1000))
            nodes = client.get_all_node_info(timeout=HEAD_TIMEOUT_S)
    except Exception as err:  # noqa: BLE001 - Ray's errors have no common type for these
        text = last_line(err)
        if type(err).__name__ == "AuthenticationError" or "Authentication" in text or "Unauthenticated" in text:
            if token is None:
                raise InputError(None, f"the Ray cluster at {address} asks for its token and none is set: put it "
                                       f"(`ray get-auth-token` on the head) in {_token_places()}") from None
            raise InputError(None, f"the Ray cluster at {address} refused the token from {token}: give the head's "
                                   "(`ray get-auth-token` on the head prints it)") from None
        raise InputError(None, f"nothing at {address} answers as a Ray cluster's head within {HEAD_TIMEOUT_S:.0f} s "
                               f"({text.split('. ')[0]}); give the port of `ray start --head --port`") from None
    from ray.core.generated.gcs_pb2 import GcsNodeInfo

    return [node for node in nodes.values() if node.state == GcsNodeInfo.GcsNodeState.ALIVE]


def join_cluster(address: str) -> dict:
    """Connect this process to the Ray cluster at ``address`` as a batch's driver; what it joined.

    Each way joining can fail is one `InputError` line, found before Ray itself would try again
    for minutes: an address of no known form, nothing answering there (a plain connection of 5 s),
    no token where the cluster asks for one or a token it refuses (`use_token`), a head that does
    not answer as one, no node of the cluster on this machine (a driver joining by
    ``HOST:PORT`` runs on a node; elsewhere ``ray://`` is the way), Ray Client without its
    package, and what Ray's own connection refuses (another Ray version, say).

    Parameters
    ----------
    address : str
        ``"auto"`` (``RAY_ADDRESS``, else the cluster ``ray start`` started on this machine),
        ``"HOST:PORT"`` or ``"ray://HOST:PORT"``.

    Returns
    -------
    dict
        ``address`` (as given), ``head`` (the head's address as Ray resolved it), ``mode``
        (``"driver"`` or ``"client"``), ``token`` (where the token came from, else None),
        ``nodes`` (live nodes) and ``cpus`` (their CPUs).

    Raises
    ------
    InputError
        For each way joining fails, before any capture is sent.
    """
    import logging

    kind, host, port = parse_address(address)
    import ray
    from ray._private import services

    head = None
    if kind == "auto":
        try:
            head = services.canonicalize_bootstrap_address("auto")
        except (ConnectionError, ValueError, RuntimeError) as err:
            head = None
            reason = last_line(err)
        else:
            reason = "no RAY_ADDRESS and no `ray start` on this machine"
        if head is None:
            raise InputError(None, f"--address auto finds no Ray cluster ({reason}); start one with `ray start "
                                   "--head`, or give HOST:PORT") from None
        host, _, port_text = head.rpartition(":")
        port = int(port_text)
    else:
        head = f"{host}:{port}"
    try:
        socket.create_connection((host.strip("[]"), port), timeout=5).close()
    except OSError as err:
        raise InputError(None, f"no Ray cluster answers at {address} ({err.strerror or err}); start one with "
                               "`ray start --head`, or leave out --address to run on this machine") from None
    if kind == "client":
        try:
            import grpc  # noqa: F401 - Ray Client's transport
        except ImportError:
            raise InputError(None, f"--address {address} (Ray Client) needs the grpcio package on this machine: "
                                   "pip install 'ray[client]'") from None
    token = use_token()
    if kind != "client":
        alive = _check_head(address, head, token)
        local = set(services.find_node_ids())
        if not any(node.node_id.hex() in local for node in alive):
            raise InputError(None, f"no node of the Ray cluster at {address} runs on this machine: run `ray start "
                                   f"--address={head}` here first, run the batch on a node, or join by "
                                   "ray://HEAD:10001 (Ray Client)") from None
    try:
        ray.init(address=address.strip(), log_to_driver=False, logging_level=logging.ERROR)
    except Exception as err:  # noqa: BLE001 - ConnectionError, RuntimeError (versions), Ray's own errors
        text = last_line(err.__cause__ if isinstance(err, ConnectionError) and err.__cause__ else err)
        raise InputError(None, f"cannot join the Ray cluster at {address}: {text}") from None
    nodes = [node for node in ray.nodes() if node.get("Alive")]
    return {"address": address.strip(), "head": head, "mode": "client" if kind == "client" else "driver",
            "token": token, "nodes": len(nodes),
            "cpus": int(sum(node.get("Resources", {}).get("CPU", 0) for node in nodes))}
