"""The simulator's speed benchmark: how fast it runs and how many messages a reader gets, without loss.

Runs ``python -m sitl.fc`` as a separate process against a UDP reader in this process
(``fcmpc-bench`` reports it; README "Benchmarks").
"""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["benchmark"]


def _free_udp_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    sock.bind(("127.0.0.1", 0))
    return sock


def _count_frames(data: bytes) -> tuple[int, int]:
    """(MAVLink 2 frames, stray bytes) of a datagram, walking the length bytes of the headers."""
    frames = stray = 0
    i, n = 0, len(data)
    while i < n:
        if data[i] == 0xFD and i + 2 < n:
            i += 12 + data[i + 1] + (13 if data[i + 2] & 1 else 0)
            frames += 1
        else:
            i += 1
            stray += 1
    return frames, stray


def benchmark(duration_sim_s: float = 3600.0, speedup: float | None = None, scenario: str = "paper_pacific",
              extra_args: tuple[str, ...] = ("--cruise", "132.3:13.9"), decode_every: int = 20,
              timeout_s: float = 600.0) -> dict:
    """Speed of the simulator on a scenario, with a reader draining its UDP output.

    The simulator runs as a separate process (``python -m sitl.fc``, unlimited speed-up
    unless ``speedup`` is given, default 10 Hz IMU/magnetometer streams, truth log on, the boat
    cruising at 50 km/h towards the destination by ``--cruise``: ``extra_args``). This process
    reads its UDP output, counts the frames of every datagram from their headers and decodes
    one datagram in ``decode_every`` completely with pymavlink, CRC checked (1 = all; a full
    decode costs the reader about a core at these rates, which on a 2-core machine slows the
    simulator it measures). Returns ``sim_s``, ``wall_s``, ``speedup`` (simulated over wall
    time), ``tx_messages`` and ``tx_msgs_per_s`` (sent, per wall second), ``rx_messages`` and
    ``rx_msgs_per_s`` (received by the reader), ``rx_loss`` (fraction lost on the way),
    ``rx_decoded`` and ``rx_bad`` (frames decoded, and failing to decode).
    """
    sock = _free_udp_socket()
    port = sock.getsockname()[1]
    sock.settimeout(0.2)
    with tempfile.TemporaryDirectory(prefix="fcmpc-bench-") as tmp:
        summary_path = Path(tmp) / "summary.json"
        cmd = [sys.executable, "-m", "sitl.fc", "--scenario", scenario, "--out", f"udp:127.0.0.1:{port}",
               "--duration", str(duration_sim_s), "--speedup", str(speedup if speedup else 0),
               "--log-dir", tmp, "--summary-json", str(summary_path), "--quiet", *extra_args]
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", MAVLINK20="1")
        repo = str(Path(__file__).resolve().parents[2])
        env["PYTHONPATH"] = repo + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        mav = mavlink.MAVLink(None)
        mav.robust_parsing = True
        rx = decoded = bad = datagrams = 0
        first = last = None
        deadline = time.monotonic() + timeout_s
        try:
            while time.monotonic() < deadline:
                try:
                    data = sock.recv(65535)
                except socket.timeout:
                    if proc.poll() is not None:
                        break
                    continue
                now = time.perf_counter()
                first = first or now
                last = now
                datagrams += 1
                frames, stray = _count_frames(data)
                rx += frames
                bad += stray
                if decode_every and datagrams % decode_every == 0:
                    for msg in mav.parse_buffer(data) or ():
                        if isinstance(msg, mavlink.MAVLink_bad_data):
                            bad += 1
                        else:
                            decoded += 1
        finally:
            if proc.poll() is None:
                proc.terminate()
            _, err = proc.communicate(timeout=30)
            sock.close()
        if not summary_path.exists():
            raise RuntimeError(f"simulator did not finish: {err.decode(errors='replace')[-2000:]}")
        summary = json.loads(summary_path.read_text())
    tx = summary["tx_messages"]
    wall = summary["wall_s"]
    reader_wall = (last - first) if first and last and last > first else wall
    return {
        "scenario": scenario, "sim_s": summary["sim_s"], "wall_s": wall, "speedup": summary["speedup"],
        "tx_messages": tx, "tx_msgs_per_s": round(tx / wall, 1), "rx_messages": rx,
        "rx_msgs_per_s": round(rx / reader_wall, 1), "rx_loss": round(1.0 - rx / tx, 4) if tx else 0.0,
        "rx_decoded": decoded, "rx_bad": bad,
    }

