"""``module load fcmpc`` in MAVProxy against the running companion and the simulator, real processes
on loopback, MAVProxy headless through its console on a pipe (as tests/companion/test_link_mavproxy.py):
the module loads, ``fcmpc start`` starts the mission, ``fcmpc status`` shows the phase and a
finite 1-sigma from the live companion, ``fcmpc help`` the registry's unit and range, and hold /
resume are acknowledged by the companion and change what it does."""
from __future__ import annotations

import importlib.util
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from companion.registry import SPEC_BY_NAME
from tests.companion.test_ground_station import Console, running_vehicle
from tests.companion.test_link_mavproxy import _quit

REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(importlib.util.find_spec("MAVProxy") is None,
                                reason="MAVProxy not installed (pip install --no-deps MAVProxy next to pymavlink)")

# a short control period: the start-up average is one period (2 s of wall time at 5x)
PARMS = "NAV_PERIOD_S 10\n"


def _mavproxy(port: int, workdir: Path) -> Console:
    """MAVProxy as an operator runs it (its target component is the autopilot's: not 191)."""
    workdir.mkdir(parents=True, exist_ok=True)
    proc = subprocess.Popen(
        [sys.executable, "-m", "MAVProxy.mavproxy", "--master", f"udpin:127.0.0.1:{port}", "--target-system", "1",
         "--default-modules", "link", "--state-basedir", str(workdir), "--nowait"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1, cwd=workdir,
        env=dict(os.environ, MAVLINK20="1", PYTHONPATH=str(REPO)))
    return Console(proc)


def _said(console: Console, since: int, text: str, timeout_s: float) -> bool:
    """``text`` in a line read since line ``since`` (what follows a command comes in no fixed order: the
    companion's STATUSTEXT, its COMMAND_ACK, the FC's mode change), or in one within ``timeout_s``."""
    return any(text in line for line in console.seen[since:]) or console.wait_for(text, timeout_s) is not None


def _status(console: Console) -> tuple[str, float]:
    """``fcmpc status``: (phase, 1-sigma in m, NaN when unknown)."""
    console.send("fcmpc status")
    phase_line = console.wait_for("fcmpc: phase", 15.0)
    sigma_line = console.wait_for("estimate 1-sigma", 15.0)
    assert phase_line is not None and sigma_line is not None, console.seen[-20:]
    phase = phase_line.split("fcmpc: phase ", 1)[1].split()[0].rstrip(",")
    found = re.search(r"1-sigma (\d+(?:\.\d+)?) m", sigma_line)
    return phase, float(found.group(1)) if found else math.nan


def test_fcmpc_module_against_the_running_companion(tmp_path):
    with running_vehicle(tmp_path, PARMS) as (port, _parm):
        console = _mavproxy(port, tmp_path / "mavproxy")
        try:
            console.send("module load fcmpc")
            assert console.wait_for("Loaded module fcmpc", 30.0) is not None, console.seen[-20:]
            spec = SPEC_BY_NAME["NAV_SPEED_KMH"]
            console.send("fcmpc help NAV_SPEED_KMH")
            assert console.wait_for(f"unit: {spec.unit}; range [{spec.minimum:g}, {spec.maximum:g}]", 10.0), \
                console.seen[-20:]
            console.send("fcmpc start")
            assert console.wait_for("fcmpc: start: ACCEPTED by the companion", 30.0), console.seen[-20:]
            # the companion selects GUIDED, arms, starts the mission and steps: its STATUSTEXT says so
            assert console.wait_for("FcMPC: step 1 phase", 60.0), console.seen[-30:]
            phase, sigma = _status(console)
            assert phase == "running" and math.isfinite(sigma) and sigma > 0.0, console.seen[-20:]
            for word, said, mode in (("hold", "held by the operator", "Mode HOLD"),   # the FC told to hold
                                     ("resume", "resumed by the operator", "Mode GUIDED")):  # back under guidance
                since = len(console.seen)
                console.send(f"fcmpc {word}")
                for text in (f"fcmpc: {word}: ACCEPTED by the companion", f"FcMPC: {said}", mode):
                    assert _said(console, since, text, 15.0), (text, console.seen[since:])
            console.send("module unload fcmpc")
            assert console.wait_for("Unloaded module fcmpc", 15.0), console.seen[-20:]
            assert not [line for line in console.seen if "Traceback" in line or "fcmpc" in line and "rror" in line]
        finally:
            _quit(console)
    summary = json.loads((tmp_path / "companion" / "summary.json").read_text())
    assert summary["operator"]["commands"] == 3 and not summary["operator"]["held"]
    assert summary["missions"] == 1
