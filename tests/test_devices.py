"""The backend switch (freqbrdf.devices, Config.device, --device) and the CUDA kernels against the CPU's.

The CUDA kernels run under numba's CUDA simulator in a fresh process (NUMBA_ENABLE_CUDASIM must be
set before numba.cuda is imported; tests/cuda_simulator_run.py), on tiny inputs. There they call the
CPU kernels' own compiled per-texel functions, so the results are bit-identical once numba has
cached the kernels (the first, compiling run may differ in the last bits: freqbrdf.jit). On a device the
per-texel functions are compiled for CUDA (fused multiply-adds, libdevice's exp, log and sqrt), so
results may differ in the last bits: the tolerances below, checked by the device test.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from freqbrdf import devices
from freqbrdf.config import Config

SIMULATOR_RUN = Path(__file__).resolve().parent / "cuda_simulator_run.py"
# Largest absolute difference allowed between the CUDA kernels' results and the CPU's, per stage: the
# coefficients, losses and likelihoods are O(1) in these inputs; the search's roughness and metallic
# come from grid, Brent and Newton steps whose decisions rounding can move by their tolerances.
DEVICE_TOLERANCE = {"fit_sh": 1e-4, "search": 1e-3, "entropy": 1e-4}


def _run_kernels(simulator: bool) -> dict:
    environment = dict(os.environ, NUMBA_ENABLE_CUDASIM="1" if simulator else "0")
    completed = subprocess.run([sys.executable, str(SIMULATOR_RUN)], env=environment, capture_output=True, text=True,
                               timeout=600)
    assert completed.returncode == 0, completed.stderr[-4000:]
    return json.loads(completed.stdout.strip().splitlines()[-1])


def _status(available: bool, simulator: bool = False, extra: bool = True) -> devices.CudaStatus:
    return devices.CudaStatus(available, simulator, extra, "a test device" if available else "no CUDA device")


def test_cuda_kernels_under_the_simulator_match_the_cpu():
    report = _run_kernels(simulator=True)
    assert report.pop("simulator") is True
    expected = {"fit_sh.exponential", "fit_sh.none", "search.default", "search.g1_lambert", "search.robust_off",
                "entropy.calibrated", "entropy.paper", "entropy.angular"}
    assert set(report) == expected
    # Bit for bit once numba has cached the kernels; in the process that compiles them, fast-math code
    # may differ in the last bits between a kernel's compiled copies (freqbrdf.jit): the device tolerances.
    beyond = {f"{stage}.{field}": value for stage, fields in report.items() for field, value in fields.items()
              if not value <= DEVICE_TOLERANCE[stage.split(".")[0]]}
    assert not beyond, beyond


def test_cuda_kernels_on_a_device_match_the_cpu_within_tolerance():
    status = devices.cuda_status()
    if not (status.available and not status.simulator):
        pytest.skip(f"needs a CUDA device (numba-cuda and an NVIDIA GPU): {status.name}")
    report = _run_kernels(simulator=False)
    assert report.pop("simulator") is False
    beyond = {f"{stage}.{field}": value for stage, fields in report.items() for field, value in fields.items()
              if not value <= DEVICE_TOLERANCE[stage.split(".")[0]]}
    assert not beyond, beyond


def test_cpu_is_always_cpu_and_unknown_devices_are_refused():
    assert devices.resolve_device("cpu") == "cpu"
    with pytest.raises(ValueError, match="device must be one of"):
        devices.resolve_device("gpu")
    with pytest.raises(ValueError, match="Config.device must be one of"):
        Config(device="gpu")


@pytest.mark.parametrize("status, expected", [
    (_status(True), "cuda"),
    (_status(True, extra=False), "cpu"),  # the builtin numba.cuda alone: no [gpu] extra
    (_status(False), "cpu"),
    (_status(True, simulator=True), "cpu"),  # the simulator is for tests: only an explicit "cuda" uses it
])
def test_auto_takes_cuda_only_with_a_device_and_the_extra(monkeypatch, status, expected):
    monkeypatch.setattr(devices, "cuda_status", lambda: status)
    assert devices.resolve_device("auto") == expected
    assert devices.describe_device("auto").startswith(expected)


def test_cuda_without_a_device_is_refused_with_the_reason(monkeypatch):
    monkeypatch.setattr(devices, "cuda_status", lambda: _status(False))
    with pytest.raises(ValueError, match="no CUDA device.*--device cpu"):
        devices.resolve_device("cuda")
    monkeypatch.setattr(devices, "cuda_status", lambda: _status(True, simulator=True))
    assert devices.resolve_device("cuda") == "cuda"


def test_the_cli_refuses_cuda_without_a_device_before_any_work(monkeypatch, run_cli, capsys, tmp_path):
    monkeypatch.setattr(devices, "cuda_status", lambda: _status(False))
    assert run_cli("fit", str(tmp_path), "--out", str(tmp_path / "fit"), "--device", "cuda") == 2
    assert "no CUDA device" in capsys.readouterr().err


def test_the_cli_says_the_backend_in_one_line_unless_quiet(monkeypatch, capsys):
    from freqbrdf import cli

    monkeypatch.setattr(devices, "cuda_status", lambda: _status(False))
    cli._say_backend("auto", quiet=False)
    assert capsys.readouterr().err == "backend: cpu (auto: no CUDA device)\n"
    cli._say_backend("auto", quiet=True)
    assert capsys.readouterr().err == ""
