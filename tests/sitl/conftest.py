"""Helpers of the simulator tests: a SITL on real loopback sockets and a pymavlink client.

``sitl`` (fixture) starts :class:`sitl.fc.SitlServer` in a background thread with its
UDP output pointed at a pymavlink ``udpin`` socket on a port of :mod:`tests.ports`; ``run_cli`` runs
``python -m sitl.fc`` as a subprocess. Everything is bounded in wall time.
"""
from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest  # noqa: E402
from pymavlink import mavutil  # noqa: E402

from sitl.fc import ServerConfig, SitlServer  # noqa: E402
from tests.ports import free_port  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
COMPANION = (1, 191)  # the companion computer's system/component


@dataclass
class Client:
    """A pymavlink udpin endpoint the simulator sends to, acting as the companion (1/191)."""

    conn: object
    statustexts: list[str] = field(default_factory=list)

    @property
    def mav(self):
        return self.conn.mav

    def recv(self, types, timeout: float = 5.0, predicate=None):
        """Next message of ``types`` (name or list) satisfying ``predicate``, within ``timeout`` wall s."""
        types = [types] if isinstance(types, str) else list(types)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = self.conn.recv_match(blocking=True, timeout=max(0.01, min(0.5, deadline - time.monotonic())))
            if msg is None:
                continue
            name = msg.get_type()
            if name == "STATUSTEXT":
                self.statustexts.append(msg.text)
            if name in types and (predicate is None or predicate(msg)):
                return msg
        raise TimeoutError(f"no {types} within {timeout} s")

    def collect(self, types, until_ms: int, timeout: float = 20.0, time_of=None) -> list:
        """Every message of ``types`` until one with simulated time >= ``until_ms``."""
        types = [types] if isinstance(types, str) else list(types)
        time_of = time_of or sim_ms
        out = []
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = self.conn.recv_match(blocking=True, timeout=0.5)
            if msg is None:
                continue
            if msg.get_type() == "STATUSTEXT":
                self.statustexts.append(msg.text)
            if msg.get_type() in types:
                out.append(msg)
            t = time_of(msg)
            if t is not None and t >= until_ms:
                return out
        raise TimeoutError(f"simulated time did not reach {until_ms} ms within {timeout} s")

    def command(self, command: int, *params: float, timeout: float = 5.0, target=(1, 1)):
        """COMMAND_LONG; returns its COMMAND_ACK."""
        p = list(params) + [0.0] * (7 - len(params))
        self.mav.command_long_send(target[0], target[1], command, 0, *p)
        return self.recv("COMMAND_ACK", timeout, lambda m: m.command == command)

    def wait_mode(self, custom_mode: int, timeout: float = 5.0):
        return self.recv("HEARTBEAT", timeout, lambda m: m.get_srcComponent() == 1 and m.custom_mode == custom_mode)

    def time_ms(self, timeout: float = 5.0) -> int:
        return self.recv("SYSTEM_TIME", timeout).time_boot_ms


def sim_ms(msg) -> int | None:
    """Simulated time of a message in ms (time_boot_ms, or time_usec since boot), None without one."""
    t = getattr(msg, "time_boot_ms", None)
    if t is not None:
        return t
    if msg.get_type() in ("RAW_IMU", "HIGHRES_IMU"):
        return msg.time_usec // 1000
    return None


def open_client() -> tuple[Client, int]:
    """A udpin client on a port of :func:`tests.ports.free_port`. Not ``udpin:...:0``: pymavlink sets
    SO_REUSEADDR, with which Linux may bind port 0 to a port another such socket holds (another
    test's client or ground station), and the newer socket then gets that port's datagrams."""
    port = free_port()
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=COMPANION[0],
                                      source_component=COMPANION[1], dialect="ardupilotmega")
    conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    return Client(conn), port


@pytest.fixture
def sitl(tmp_path):
    """Factory: ``sitl(**config)`` -> (server, client); stopped and joined at teardown."""
    started = []

    def start(**overrides):
        client, port = open_client()
        config = dict(outs=(f"udp:127.0.0.1:{port}",), speedup=50.0, log_dir=str(tmp_path / f"run{len(started)}"),
                      quiet=True, duration_s=3600.0, seed=1)
        config.update(overrides)
        server = SitlServer(ServerConfig(**config))
        thread = threading.Thread(target=server.run, daemon=True, name="sitl")
        thread.start()
        started.append((server, thread, client))
        if not server.ready_event.wait(10):
            raise RuntimeError("SITL did not start")
        return server, client

    yield start
    for server, thread, client in started:
        server.request_stop()
        thread.join(10)
        client.conn.close()
        assert not thread.is_alive(), "SITL thread did not stop"


def run_cli(args: list[str], tmp_path: Path, timeout: float = 300.0) -> tuple[dict, Path]:
    """Run ``python -m sitl.fc`` to completion; returns (summary, log_dir). ``timeout`` only guards
    against a hang: a loaded 2-core machine took 75 s of wall time for 6.6 s of CPU."""
    log_dir = tmp_path / "cli"
    cmd = [sys.executable, "-m", "sitl.fc", "--log-dir", str(log_dir), "--quiet", *args]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", MAVLINK20="1")
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    proc = subprocess.run(cmd, env=env, capture_output=True, timeout=timeout, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")[-3000:]
    return json.loads((log_dir / "summary.json").read_text()), log_dir


def read_tlog(path: Path) -> list:
    """Every message of a .tlog, with ``_timestamp`` (simulated UNIX seconds)."""
    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    out = []
    while True:
        msg = conn.recv_match()
        if msg is None:
            break
        out.append(msg)
    conn.close()
    return out


def gps_scenario(tmp_path: Path, denied_after_s: float = 1e9, name: str = "pacific_gps") -> Path:
    """A copy of the bundled pacific scenario whose GPS keeps its fix (for ground-truth telemetry)."""
    text = (REPO / "sitl" / "scenarios" / "paper_pacific.toml").read_text()
    text = text.replace('name = "paper_pacific"', f'name = "{name}"')
    text = text.replace("gps_denied_after_s = 0.0", f"gps_denied_after_s = {denied_after_s}")
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


def body_to_ned(roll: float, pitch: float, yaw: float, x: float, y: float, z: float):
    """Rotate a body vector into NED (ZYX Euler angles, rad)."""
    sr, cr, sp, cp, sy, cy = (math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch),
                              math.sin(yaw), math.cos(yaw))
    n = cp * cy * x + (sr * sp * cy - cr * sy) * y + (cr * sp * cy + sr * sy) * z
    e = cp * sy * x + (sr * sp * sy + cr * cy) * y + (cr * sp * sy - sr * cy) * z
    d = -sp * x + sr * cp * y + cr * cp * z
    return n, e, d
