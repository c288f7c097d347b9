"""The companion process against the simulator: it steers only when its parameters allow it."""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(tmp_path: Path, parm_text: str, sim_s: float = 300.0) -> tuple[dict, dict]:
    """Simulator (lockstep, ``sim_s`` simulated seconds) and companion; their summaries."""
    port = _free_port()
    parm = tmp_path / "companion.parm"
    parm.write_text(parm_text, encoding="utf-8")
    env = dict(os.environ, PYTHONPATH=str(REPO), MAVLINK20="1")
    companion = subprocess.Popen(
        [sys.executable, "-m", "companion.app", "--connect", f"udp:127.0.0.1:{port}", "--params", str(parm),
         "--log-dir", str(tmp_path / "companion"), "--lockstep", "--max-wall-s", "60", "--quiet", "--no-tlog"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    sitl = subprocess.Popen(
        [sys.executable, "-m", "sitl.server", "--out", f"udp:127.0.0.1:{port}", "--lockstep", "--duration",
         str(sim_s), "--log-dir", str(tmp_path / "sitl"), "--quiet", "--lockstep-timeout", "0.5"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        sitl.wait(timeout=60)
    finally:
        for proc in (sitl, companion):
            if proc.poll() is None:
                proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)
    return (json.loads((tmp_path / "sitl" / "summary.json").read_text()),
            json.loads((tmp_path / "companion" / "summary.json").read_text()))


def test_arms_and_steers_when_allowed(tmp_path):
    """The control case: a good file with COMP_ARM_ENABLE 1 -> GUIDED, armed, setpoints."""
    sitl, companion = _run(tmp_path, "COMP_ARM_ENABLE 1\nNAV_PERIOD_S 60\n")
    assert sitl["armed"] and sitl["mode"] == "GUIDED"
    assert sitl["rx_by_type"].get("SET_POSITION_TARGET_GLOBAL_INT", 0) > 100
    assert companion["state"] == "running" and companion["param_load_error"] is None


def test_broken_parameter_file_never_arms_or_steers(tmp_path):
    """A file with one bad line: defaults are served and the companion refuses to engage, even
    though the file's other line asks it to arm."""
    sitl, companion = _run(tmp_path, "COMP_ARM_ENABLE 1\nNAV_PERIOD_S 60\nMPC_HORIZON 99\n")
    assert not sitl["armed"] and sitl["mode"] == "HOLD"
    assert sitl["rx_by_type"].get("SET_POSITION_TARGET_GLOBAL_INT", 0) == 0
    assert "MPC_HORIZON" in companion["param_load_error"] and companion["state"] == "startup"
    assert any("params: broken parameter file" in event for event in companion["events"])
    assert (tmp_path / "companion.parm").read_text(encoding="utf-8").endswith("MPC_HORIZON 99\n")   # untouched


@pytest.mark.parametrize("argv", [["--param-encoding", "nonsense"], ["--mag-message", "BOGUS"]])
def test_cli_rejects_bad_arguments(argv):
    result = subprocess.run([sys.executable, "-m", "companion.app", *argv], capture_output=True, text=True,
                            env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=30)
    assert result.returncode == 2 and "invalid choice" in result.stderr
