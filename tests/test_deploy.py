"""deploy/: the systemd unit says what issue 10 asks, and the real companion process speaks sd_notify
(READY once, WATCHDOG at half of WatchdogSec) to a real Unix socket."""
from __future__ import annotations

import configparser
import os
import socket
import subprocess
import sys
from pathlib import Path

from tests.ports import free_port

REPO = Path(__file__).resolve().parents[1]
UNIT = REPO / "deploy" / "fcmpc-companion.service"


def _unit() -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str
    parser.read(UNIT)
    return parser


def test_unit_restarts_on_failure_with_a_watchdog_as_a_non_root_user():
    service = _unit()["Service"]
    assert service["Type"] == "notify" and service["Restart"] == "on-failure"
    assert int(service["WatchdogSec"]) > 0
    assert service["User"] not in ("", "root") and service["Group"] not in ("", "root")
    assert "--signing-key /etc/fcmpc/signing.key" in service["ExecStart"]
    assert service["UMask"] == "0077"
    install = (REPO / "deploy" / "install.sh").read_text()
    assert "chmod 0600 /etc/fcmpc/signing.key" in install


def test_the_running_companion_says_ready_and_feeds_the_watchdog(tmp_path):
    path = str(tmp_path / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(60.0)
    port = free_port()
    env = dict(os.environ, PYTHONPATH=str(REPO), NOTIFY_SOCKET=path, WATCHDOG_USEC="400000")
    proc = subprocess.Popen([sys.executable, "-m", "companion.app", "--connect", f"udp:127.0.0.1:{port}",
                             "--params", str(tmp_path / "c.parm"), "--params-create", "--log-dir",
                             str(tmp_path / "log"), "--quiet", "--max-wall-s", "120"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert sock.recv(100) == b"READY=1"
        feeds = [sock.recv(100) for _ in range(3)]      # no flight controller at all: the loop still runs
        assert feeds == [b"WATCHDOG=1"] * 3
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        sock.close()
