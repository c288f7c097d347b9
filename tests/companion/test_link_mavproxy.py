"""MAVProxy against the signing companion, real processes on loopback: MAVProxy with the key
(``signing key PASSPHRASE``, as ``fcmpc-signing-key`` prints it) lists and sets the parameters;
MAVProxy without it can read the (signed) values but its unsigned PARAM_SET changes nothing."""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from companion.io.link.signing import passphrase_key, write_key_file
from companion.params import REGISTRY, read_parm_file
from tests.companion.test_ground_station import Console
from tests.ports import free_port
from tests.processes import wait_for_file

REPO = Path(__file__).resolve().parents[2]
PASSPHRASE = "mavproxy-interop-passphrase"

pytestmark = pytest.mark.skipif(importlib.util.find_spec("MAVProxy") is None,
                                reason="MAVProxy not installed (pip install --no-deps MAVProxy next to pymavlink)")


def _mavproxy(port: int, workdir: Path, cmd: str | None) -> Console:
    argv = [sys.executable, "-m", "MAVProxy.mavproxy", "--master", f"udpout:127.0.0.1:{port}", "--target-system",
            "1", "--target-component", "191", "--default-modules", "param,signing", "--state-basedir",
            str(workdir), "--nowait"]
    if cmd:
        argv += ["--cmd", cmd]
    workdir.mkdir(parents=True, exist_ok=True)
    proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            bufsize=1, cwd=workdir, env=dict(os.environ, MAVLINK20="1"))
    return Console(proc)


def _quit(console: Console) -> None:
    console.proc.stdin.close()     # closing stdin quits MAVProxy
    try:
        console.proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        console.proc.kill()
        console.proc.wait(timeout=5)


def test_mavproxy_with_the_key_sets_parameters_without_it_cannot(tmp_path):
    port = free_port()
    parm = tmp_path / "companion.parm"
    key_file = write_key_file(tmp_path / "signing.key", passphrase_key(PASSPHRASE))
    companion = subprocess.Popen(
        [sys.executable, "-m", "companion.app", "--connect", f"udp:127.0.0.1:{port}", "--params", str(parm),
         "--params-create", "--log-dir", str(tmp_path / "companion"), "--signing-key", str(key_file),
         "--max-wall-s", "300", "--quiet"],
        env=dict(os.environ, PYTHONPATH=str(REPO), MAVLINK20="1"), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for_file(tmp_path / "companion" / "steps.csv", [companion], 120.0)
        stranger = _mavproxy(port, tmp_path / "unsigned", None)
        try:
            received = stranger.wait_for("Received", 90.0)
            assert received is not None and f"Received {len(REGISTRY)} parameters" in received, stranger.seen[-20:]
            stranger.send("param set NAV_SPEED_KMH 33")
            # MAVProxy sends the set from its idle loop and retries it; "Failed to set" once every
            # attempt went unanswered is the event that says the unsigned PARAM_SET went out (quitting
            # on an earlier line could close MAVProxy before it sent anything: one loaded CI run)
            assert stranger.wait_for("Failed to set NAV_SPEED_KMH", 60.0) is not None, stranger.seen[-20:]
        finally:
            _quit(stranger)
        signed = _mavproxy(port, tmp_path / "signed", f"signing key {PASSPHRASE}")
        try:
            received = signed.wait_for("Received", 90.0)
            assert received is not None and f"Received {len(REGISTRY)} parameters" in received, signed.seen[-20:]
            signed.send("param set NAV_MAX_STEPS 444")
            deadline = time.monotonic() + 30.0
            values: dict = {}
            while time.monotonic() < deadline and values.get("NAV_MAX_STEPS") != 444:
                values = read_parm_file(parm) if parm.exists() else {}
                time.sleep(0.2)   # polling the file the companion writes
            assert values.get("NAV_MAX_STEPS") == 444 and values.get("NAV_SPEED_KMH") == 50.0, values
        finally:
            _quit(signed)
    finally:
        companion.terminate()
        companion.wait(timeout=30)
    summary = json.loads((tmp_path / "companion" / "summary.json").read_text())
    assert summary["link"]["unsigned_refused"].get("PARAM_SET", 0) >= 1
