"""`freqbrdf batch --address` on a Ray cluster started apart: two nodes on this machine, token auth.

The cluster is set up as Ray's documentation sets one up: a token file, then ``ray start --head``
and ``ray start --address`` with ``RAY_AUTH_MODE=token``, each node with its own temp dir and
ports, started in a process group of its own so that a node can be killed as a machine that dies.
The nodes are joined at 127.0.0.1; Ray records the machine's own address in its place, which the
kernel routes through its loopback device (Ray's servers listen on every interface, as on any
cluster: the token keeps others out). The batch runs as a user runs it: the command
line in a process of its own, with the token in a file named by ``RAY_AUTH_TOKEN_PATH`` and
``RAY_AUTH_MODE`` unset.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from freqbrdf import batch
from freqbrdf.batch import cluster as batch_cluster
from freqbrdf.batch.runner import TEST_HOOKS_VARIABLE
from freqbrdf.cli import RERUN_VARIABLE
from freqbrdf.errors import InputError
from freqbrdf.images import read_image
from freqbrdf.synthetic.synth import SynthSettings, synthesize

RAY = str(Path(sys.executable).with_name("ray"))
TINY = SynthSettings(mesh="bunny", views=8, resolution=32, spp=4, texture_res=16, test_views=0)
MESHES = ("bunny", "sphere", "plane", "bunny")
MAPS = ("base_color.exr", "roughness.exr", "metallic.exr", "entropy.exr", "roughness_std.exr")
RAY_VARIABLES = ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH", "RAY_ADDRESS")
# Fast detection of a dead node (Ray's defaults take longer): the head's health checks.
HEALTH_CHECKS = {"RAY_health_check_period_ms": "500", "RAY_health_check_timeout_ms": "1000",
                 "RAY_health_check_failure_threshold": "3"}


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def clean_environment(**extra) -> dict:
    """This process's environment without Ray's address and token settings, plus ``extra``."""
    environment = {key: value for key, value in os.environ.items()
                   if key not in RAY_VARIABLES and key != RERUN_VARIABLE}
    return {**environment, **extra}


class LocalCluster:
    """A head and worker nodes started with ``ray start``, token authentication on."""

    def __init__(self, root: Path):
        self.root = root
        self.token = root / "auth_token"
        self.token.write_text(secrets.token_hex(32), encoding="ascii")
        self.port = free_port()
        self.address = f"127.0.0.1:{self.port}"
        self.environment = clean_environment(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN_PATH=str(self.token),
                                             **HEALTH_CHECKS)
        self.nodes: list[tuple[subprocess.Popen, str]] = []  # (`ray start` process, its node id)
        self.temps: list[str] = []
        self.head = self.worker = ""  # node ids

    def start(self, head: bool) -> str:
        """Start a node of one CPU; its Ray node id."""
        temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths have a length limit
        where = ["--head", "--port", str(self.port), "--include-dashboard", "false"] if head \
            else ["--address", self.address]
        process = subprocess.Popen([RAY, "start", *where, "--num-cpus", "1", "--object-store-memory", str(100 * 2**20),
                                    "--disable-usage-stats", "--temp-dir", temp], env=self.environment,
                                   start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.temps.append(temp)
        self.nodes.append((process, ""))
        assert process.wait(timeout=180) == 0, process.stderr.read()
        node = self.node_id(process.pid)
        self.nodes[-1] = (process, node)
        return node

    @staticmethod
    def node_id(group: int) -> str:
        """The node id of the raylet in process group ``group``."""
        listing = subprocess.run(["ps", "-ww", "-eo", "pgid=,args="], capture_output=True, text=True, check=True).stdout
        for line in listing.splitlines():
            found = re.search(r"--node_id=([0-9a-f]+)", line)
            if found and int(line.split()[0]) == group and "raylet" in line:
                return found.group(1)
        raise AssertionError(f"no raylet in process group {group}")

    def kill(self, node: str, *pids: int) -> None:
        """Kill a node's processes with SIGKILL, as a machine that dies, and the workers ``pids`` it ran
        (Ray's workers each lead a process group of their own)."""
        for process, found in self.nodes:
            if found == node:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(process.pid, signal.SIGKILL)
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pid, signal.SIGKILL)

    def stop(self) -> None:
        for process, _ in self.nodes:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
        # Workers leave when their raylet is gone; any still there ran under these temp dirs.
        time.sleep(1.0)
        listing = subprocess.run(["ps", "-ww", "-eo", "pid=,args="], capture_output=True, text=True).stdout
        for line in listing.splitlines():
            if any(temp in line for temp in self.temps):
                with contextlib.suppress(ProcessLookupError, ValueError):
                    os.kill(int(line.split()[0]), signal.SIGKILL)
        for temp in self.temps:
            shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """Four tiny captures."""
    folder = tmp_path_factory.mktemp("captures")
    for index, mesh in enumerate(MESHES):
        synthesize(folder / f"c{index}", dataclasses.replace(TINY, mesh=mesh, seed=index), progress=False)
    return [folder / f"c{index}" for index in range(len(MESHES))]


@pytest.fixture(scope="module")
def plain_fit(tmp_path_factory):
    """A capture's plain ``freqbrdf fit`` at T = 16, made once, when first asked for."""
    folder, made = tmp_path_factory.mktemp("plain_fits"), {}

    def fit(capture: Path) -> Path:
        if capture not in made:
            # Where it compiles numba's kernels (a cold cache), it runs again from the cache it wrote.
            done = subprocess.run([sys.executable, "-m", "freqbrdf.cli", "fit", str(capture), "--out",
                                   str(folder / capture.name), "--texture-res", "16", "--quiet"],
                                  capture_output=True, text=True, env=clean_environment(), timeout=900)
            assert done.returncode == 0, done.stderr
            made[capture] = folder / capture.name
        return made[capture]

    return fit


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """A head and a worker node, one CPU each."""
    made = LocalCluster(tmp_path_factory.mktemp("cluster"))
    try:
        made.head = made.start(head=True)
        made.worker = made.start(head=False)
        yield made
    finally:
        made.stop()


def write_manifest(path: Path, captures: list[Path]) -> Path:
    lines = ["name,capture,texture_res,evaluate,report"] + [f"{c.name},{c},16,false,false" for c in captures]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def batch_command(manifest: Path, out: Path, address: str, *options: str) -> list[str]:
    return [sys.executable, "-m", "freqbrdf.cli", "batch", str(manifest), "--out", str(out), "--address", address,
            *options]


def attempts(out: Path) -> dict[str, list[tuple[int, str]]]:
    """Each capture's attempts so far: (worker pid, node id), from this run's attempts files."""
    found = {}
    for path in (out / batch.WORK_FOLDER / "runs").glob("*/*.attempts"):
        with contextlib.suppress(OSError):
            lines = [line.split() for line in path.read_text(encoding="utf-8").splitlines()]
            found[path.stem] = [(int(parts[1]), parts[3]) for parts in lines if len(parts) == 4]
    return found


def same_outputs(made: Path, expected: Path) -> None:
    for name in MAPS:
        assert np.array_equal(read_image(made / name), read_image(expected / name)), (made, name)
    for name in ("spectra.npz", "uncertainty.npz"):
        with np.load(made / name) as found, np.load(expected / name) as reference:
            assert found.files == reference.files
            for key in found.files:
                assert np.array_equal(found[key], reference[key], equal_nan=found[key].dtype.kind == "f"), (made, key)


@pytest.mark.slow
def test_batch_across_two_nodes_survives_a_lost_node(ray_cluster, captures, plain_fit, tmp_path):
    """Four captures on two nodes; the worker node is killed (with its worker) while a capture runs
    there, after another capture finished. That capture is retried on the head; none is lost or
    fitted twice; batch.json parses whenever read; the outputs of the retried capture and of one
    finished before the kill equal a plain ``fit``'s."""
    plain_fit(captures[0])  # numba's kernels compiled (where the cache is cold) once, before the workers load them
    out = tmp_path / "out"
    manifest = write_manifest(tmp_path / "m.csv", captures)
    environment = clean_environment(RAY_AUTH_TOKEN_PATH=str(ray_cluster.token),
                                    # every first attempt waits 2 s: a capture seen started is still running
                                    **{TEST_HOOKS_VARIABLE: json.dumps({"first_attempt_sleep_s": 2.0})})
    command = subprocess.Popen(batch_command(manifest, out, ray_cluster.address, "--workers", "2", "--threads", "1"),
                               env=environment, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)
    seen: dict[str, list[tuple[int, str]]] = {}
    reads = 0
    killed = finished_before = None
    try:
        deadline = time.monotonic() + 600  # worker start-up and fits on a machine other jobs may share
        while command.poll() is None:
            assert time.monotonic() < deadline, "the batch did not finish"
            if (out / batch.BATCH_FILE).is_file():
                json.loads((out / batch.BATCH_FILE).read_text(encoding="utf-8"))  # written whole, or not at all
                reads += 1
            seen.update(attempts(out))
            done = {path.parent.name for path in out.glob(f"*/{batch.ENTRY_FILE}")}
            running = [(name, pid) for name, tries in seen.items() for pid, node in tries[-1:]
                       if node == ray_cluster.worker and name not in done and len(tries) == 1]
            if killed is None and running and done:
                killed, pid = running[0]
                finished_before = {name: {str(p.relative_to(out / name)): p.stat().st_mtime_ns
                                          for p in (out / name).rglob("*") if p.is_file()} for name in done}
                ray_cluster.kill(ray_cluster.worker, pid)
            time.sleep(0.1)
        stdout, stderr = command.communicate()
    finally:
        if command.poll() is None:
            os.killpg(command.pid, signal.SIGKILL)
    assert command.returncode == 0, stderr
    assert killed is not None, f"no capture ran on the worker node after another finished: {seen}"
    assert f"joined the Ray cluster at {ray_cluster.address}" in stderr, stderr
    assert f"token from {ray_cluster.token}" in stderr and "2 nodes, 2 CPUs" in stderr, stderr
    assert reads > 0
    summary = json.loads((out / batch.BATCH_FILE).read_text(encoding="utf-8"))
    assert summary["counts"]["done"] == len(captures) and summary["engine"]["cluster"]["nodes"] == 2
    rows = {row["name"]: row for row in summary["captures"]}
    # The killed capture's first attempt ran on the worker node, its second (its only fit) on the head.
    assert [node for _, node in seen[killed]][:1] == [ray_cluster.worker]
    assert rows[killed]["attempts"] == 2 and rows[killed]["worker"]["node"] == ray_cluster.head, rows[killed]
    entry = json.loads((out / killed / batch.ENTRY_FILE).read_text(encoding="utf-8"))
    assert entry["attempts"] == 2 and entry["worker"]["node"] == ray_cluster.head
    for name, row in rows.items():
        if name != killed:
            assert row["attempts"] == 1, row  # fitted once: no second attempt
    # Captures finished before the kill (on either node) are kept as they were.
    for name, files in finished_before.items():
        assert {str(p.relative_to(out / name)): p.stat().st_mtime_ns
                for p in (out / name).rglob("*") if p.is_file()} == files, name
    assert {node for tries in seen.values() for _, node in tries} == {ray_cluster.head, ray_cluster.worker}
    for name in (killed, sorted(finished_before)[0]):
        same_outputs(out / name, plain_fit(captures[0].parent / name))
    ray_cluster.worker = ray_cluster.start(head=False)  # the cluster whole again for the next tests


@pytest.mark.slow
def test_rerun_after_the_driver_is_killed_resumes(ray_cluster, captures, plain_fit, tmp_path):
    """The batch's own process killed with SIGKILL while a capture runs: batch.json parses, Ray
    stops that capture's worker, and a rerun (``--address auto`` through ``RAY_ADDRESS``) skips
    the finished capture and makes the other."""
    plain_fit(captures[0])  # numba's kernels compiled (where the cache is cold) once, before the workers load them
    out = tmp_path / "out"
    manifest = write_manifest(tmp_path / "m.csv", captures[:2])
    name = captures[1].name
    environment = clean_environment(RAY_AUTH_TOKEN_PATH=str(ray_cluster.token),
                                    **{TEST_HOOKS_VARIABLE: json.dumps({"sleep_s": {name: 600}})})
    command = subprocess.Popen(batch_command(manifest, out, ray_cluster.address, "--workers", "1", "--threads", "1",
                                             "--quiet"), env=environment, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 600
        while not attempts(out).get(name):
            assert command.poll() is None and time.monotonic() < deadline, command.stderr.read()
            time.sleep(0.1)
        worker = attempts(out)[name][0][0]
        command.kill()  # the driver alone, as a machine that loses it
        command.wait(timeout=60)
    finally:
        if command.poll() is None:
            os.killpg(command.pid, signal.SIGKILL)
    summary = json.loads((out / batch.BATCH_FILE).read_text(encoding="utf-8"))
    statuses = [row["status"] for row in summary["captures"]]
    assert statuses[0] == "done" and statuses[1] in ("pending", "running") and summary["finished"] is None
    deadline = time.monotonic() + 120  # Ray ends the workers of a driver that is gone
    while Path(f"/proc/{worker}").exists():
        assert time.monotonic() < deadline, f"the dead driver's worker {worker} still runs"
        time.sleep(0.2)
    finished = (out / captures[0].name / batch.ENTRY_FILE).stat().st_mtime_ns
    done = subprocess.run(batch_command(manifest, out, "auto", "--json"), capture_output=True, text=True,
                          env=clean_environment(RAY_AUTH_TOKEN_PATH=str(ray_cluster.token),
                                                RAY_ADDRESS=ray_cluster.address), timeout=600)
    assert done.returncode == 0, done.stderr
    resumed = json.loads(done.stdout)
    assert [row["status"] for row in resumed["captures"]] == ["skipped", "done"]
    assert resumed["engine"]["cluster"]["head"].endswith(f":{ray_cluster.port}")
    assert (out / captures[0].name / batch.ENTRY_FILE).stat().st_mtime_ns == finished
    same_outputs(out / name, plain_fit(captures[1]))
    assert not (out / batch.WORK_FOLDER).exists()


JOIN = ("import sys; from freqbrdf.batch.cluster import join_cluster; from freqbrdf.errors import InputError\n"
        "try:\n    print(join_cluster(sys.argv[1]))\nexcept InputError as err:\n    print('InputError:', err)")


def join(address: str, **environment) -> str:
    """`join_cluster` in a process of its own (Ray keeps its token settings per process): its line."""
    done = subprocess.run([sys.executable, "-c", JOIN, address], capture_output=True, text=True, timeout=120,
                          env=clean_environment(**environment))
    assert done.returncode == 0, done.stderr
    return done.stdout.strip().splitlines()[-1]


@pytest.mark.slow
def test_each_way_joining_fails_is_one_line(ray_cluster, captures, tmp_path, run_cli, capsys):
    empty_home = tmp_path / "home"
    empty_home.mkdir()
    manifest = write_manifest(tmp_path / "m.csv", captures[:1])
    # No token anywhere: one line on standard error (none of Ray's own), naming the places Ray reads one from.
    done = subprocess.run(batch_command(manifest, tmp_path / "out", ray_cluster.address), capture_output=True,
                          text=True, timeout=120, env=clean_environment(HOME=str(empty_home)))
    assert done.returncode == 2 and done.stderr == (
        f"error: the Ray cluster at {ray_cluster.address} asks for its token and none is set: put it (`ray "
        "get-auth-token` on the head) in RAY_AUTH_TOKEN, a file named by RAY_AUTH_TOKEN_PATH or "
        f"{empty_home}/.ray/auth_token\n"), done.stderr
    assert not (tmp_path / "out").exists()
    # Another cluster's token.
    line = join(ray_cluster.address, RAY_AUTH_TOKEN="not-the-token")
    assert line.startswith(f"InputError: the Ray cluster at {ray_cluster.address} refused the token from "
                           "RAY_AUTH_TOKEN"), line
    # RAY_AUTH_MODE=token without a token.
    line = join(ray_cluster.address, HOME=str(empty_home), RAY_AUTH_MODE="token")
    assert line.startswith("InputError: RAY_AUTH_MODE=token but no Ray token is set"), line
    # The token in Ray's own token file (~/.ray/auth_token), nothing else set: joined.
    (empty_home / ".ray").mkdir()
    shutil.copy(ray_cluster.token, empty_home / ".ray" / "auth_token")
    line = join(ray_cluster.address, HOME=str(empty_home))
    assert "'nodes': 2, 'cpus': 2" in line and f"'token': '{empty_home}/.ray/auth_token'" in line, line
    # A head that is not this cluster's node here: the driver of HOST:PORT runs on a node.
    script = JOIN.replace("from freqbrdf.batch.cluster import join_cluster",
                          "from freqbrdf.batch.cluster import join_cluster; from ray._private import services; "
                          "services.find_node_ids = lambda: []")
    done = subprocess.run([sys.executable, "-c", script, ray_cluster.address], capture_output=True, text=True,
                          timeout=120, env=clean_environment(RAY_AUTH_TOKEN_PATH=str(ray_cluster.token)))
    assert done.stdout.strip().endswith("runs on this machine: run `ray start --address="
                                        f"{ray_cluster.address}` here first, run the batch on a node, or join by "
                                        "ray://HEAD:10001 (Ray Client)"), done.stdout + done.stderr

    # The same for a missing token file, and for an address of no known form or where nothing answers.
    for address, message in [("127.0.0.1", "--address '127.0.0.1' is not auto, HOST:PORT or ray://HOST:PORT"),
                             (f"127.0.0.1:{free_port()}", "no Ray cluster answers at 127.0.0.1:")]:
        assert batch_cluster.parse_address(ray_cluster.address) == ("gcs", "127.0.0.1", ray_cluster.port)
        with pytest.raises(InputError, match=re.escape(message)):
            batch_cluster.join_cluster(address)
    missing = tmp_path / "no_token"
    done = subprocess.run(batch_command(manifest, tmp_path / "out", ray_cluster.address), capture_output=True,
                          text=True, timeout=120, env=clean_environment(RAY_AUTH_TOKEN_PATH=str(missing)))
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1, done.stderr
    assert done.stderr.startswith(f"error: {missing}: RAY_AUTH_TOKEN_PATH names this token file, which cannot be "
                                  "read"), done.stderr
    assert not (tmp_path / "out").exists()
    assert run_cli("batch", manifest, "--out", tmp_path / "out", "--address", "head:port") == 2
    assert "is not auto, HOST:PORT or ray://HOST:PORT" in capsys.readouterr().err


@pytest.mark.slow
def test_ray_client_address_without_grpcio(ray_cluster):
    """``ray://`` is Ray Client, whose transport (grpcio, ``ray[client]``) Ray does not install."""
    try:
        import grpc  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("grpcio is installed here: Ray Client's absence cannot be shown")
    with pytest.raises(InputError, match=re.escape(f"--address ray://{ray_cluster.address} (Ray Client) needs the "
                                                   "grpcio package on this machine: pip install 'ray[client]'")):
        batch_cluster.join_cluster(f"ray://{ray_cluster.address}")


def test_find_token_in_rays_order(tmp_path, monkeypatch):
    """RAY_AUTH_TOKEN, else the file RAY_AUTH_TOKEN_PATH names, else ~/.ray/auth_token."""
    for name in RAY_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    assert batch_cluster.find_token() is None
    (tmp_path / ".ray").mkdir()
    (tmp_path / ".ray" / "auth_token").write_text("home-token\n", encoding="ascii")
    assert batch_cluster.find_token() == str(tmp_path / ".ray" / "auth_token")
    named = tmp_path / "token"
    named.write_text("named-token", encoding="ascii")
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(named))
    assert batch_cluster.find_token() == str(named)
    monkeypatch.setenv("RAY_AUTH_TOKEN", "the-token")
    assert batch_cluster.find_token() == "RAY_AUTH_TOKEN"
    monkeypatch.delenv("RAY_AUTH_TOKEN")
    named.write_text("  \n", encoding="ascii")
    with pytest.raises(InputError, match=f"^{re.escape(str(named))}: RAY_AUTH_TOKEN_PATH names this token file, "
                                         "which is empty$"):
        batch_cluster.find_token()


def test_parse_address():
    assert batch_cluster.parse_address("auto") == ("auto", None, None)
    assert batch_cluster.parse_address("head.example:6379") == ("gcs", "head.example", 6379)
    assert batch_cluster.parse_address("ray://10.0.0.2:10001") == ("client", "10.0.0.2", 10001)
    assert batch_cluster.parse_address("[::1]:6379") == ("gcs", "::1", 6379)
    for address in ("head", "head:", "head:0", "head:70000", "http://head:6379", "ray://head"):
        with pytest.raises(InputError, match="is not auto, HOST:PORT or ray://HOST:PORT"):
            batch_cluster.parse_address(address)


def test_a_retry_answers_with_what_its_run_made(tmp_path):
    """A capture made by this run (its worker died after the rename, or during it) is not made again."""
    from freqbrdf import __version__
    from freqbrdf.batch import tasks

    out = tmp_path / "out"
    folder, work = out / "a", out / batch.WORK_FOLDER / "work" / "a"
    settings = {"texture_res": 16}
    spec = {"name": "a", "capture": str(tmp_path / "nowhere"), "folder": str(folder), "work": str(work),
            "attempts": str(out / batch.WORK_FOLDER / "runs" / "r1" / "a.attempts"), "settings": settings,
            "settings_hash": batch.settings_hash(settings), "version": __version__, "run": "r1", "hooks": {}}
    made = work / "new"  # left half renamed: complete in the work folder, nothing in its place
    made.mkdir(parents=True)
    (made / "maps.bin").write_bytes(b"abc")
    entry = {"run": "r1", "settings_hash": spec["settings_hash"], "outputs": {"maps.bin": 3}, "attempts": 1,
             "metrics": {"observed_fraction": 0.5}, "evaluated": False, "inputs": {"hash": "h"}}
    (made / batch.ENTRY_FILE).write_text(json.dumps(entry), encoding="utf-8")
    row = tasks.process_capture(spec)  # the capture does not exist: a fit would fail
    assert row["status"] == "done" and row["attempts"] == 1 and row["made_by_attempt"] == 1, row
    assert row["metrics"] == {"observed_fraction": 0.5} and row["input_hash"] == "h"
    assert (folder / "maps.bin").read_bytes() == b"abc" and not made.exists()
    # Another run's outputs, or incomplete ones, are made again (here: fail, the capture missing).
    (folder / batch.ENTRY_FILE).write_text(json.dumps({**entry, "run": "r0"}), encoding="utf-8")
    assert tasks._made_in_this_run(spec) is None
    (folder / batch.ENTRY_FILE).write_text(json.dumps(entry), encoding="utf-8")
    (folder / "maps.bin").write_bytes(b"ab")
    assert tasks._made_in_this_run(spec) is None
    row = tasks.process_capture(spec)
    assert row["status"] == "failed" and row["attempts"] == 2 and "nowhere" in row["error"], row
