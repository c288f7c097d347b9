"""Benchmark of the companion process against the simulator's streams (``fcmpc.bench.sections`` calls it).

The simulator runs as a separate process, started by module name (``python -m sitl.fc``; the
companion never imports it); the companion runs in this process, exactly as ``fcmpc-companion``
would, records included. Three measurements:

``step latency``
    closed loop in lockstep, cruising with NAV_PERIOD_S = 60 s (many steps per simulated hour):
    wall time of each control step (average of the period's samples + plausibility judgement +
    navigation core + outputs), median, 99th percentile and maximum, and the medians of its
    parts: the average, the judgement and the core. Flown twice: with the default navigator
    (issue 14's error-state filter), and with the paper's estimator on (D, I) (``FUS_MODEL 1``,
    ``NAV_ELEMENTS 1``: Table 3's, the work the companion ran before the filter), keys
    ``paper_estimator_*``.
``sustained input``
    the simulator free-running as fast as it can (no lockstep): messages the companion handled
    per wall second and the fraction lost (socket overflow is what falling behind looks like on
    UDP). If nothing is lost the companion kept up and the figure is a lower bound set by the
    simulator's own speed.
``capacity``
    the same recorded stream replayed from memory through parse + receive hook, no socket: the
    companion's CPU-bound ceiling in messages per second.
"""
from __future__ import annotations

import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from companion.process.companion import CompanionApp
from companion.process.options import AppOptions

__all__ = ["run"]

REPO = Path(__file__).resolve().parents[2]
SITL_RATES = ("SCALED_IMU:0", "LOCAL_POSITION_NED:0", "SYS_STATUS:0", "GPS_RAW_INT:1", "GLOBAL_POSITION_INT:1")


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))]


def _fly_against_sitl(workdir: Path, sitl_args: list[str], params: str, lockstep: bool, timeout_s: float):
    """Start the simulator, run a CompanionApp here until the simulator exits; (app, sitl summary)."""
    port = _free_udp_port()
    parm = workdir / "bench.parm"
    parm.write_text(params, encoding="utf-8")
    app = CompanionApp(AppOptions(connect=f"udp:127.0.0.1:{port}", params=str(parm), log_dir=str(workdir / "companion"),
                                  lockstep=lockstep, quiet=True, max_wall_s=timeout_s))
    env = dict(os.environ, MAVLINK20="1", OPENBLAS_NUM_THREADS="1")
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    cmd = [sys.executable, "-m", "sitl.fc", "--out", f"udp:127.0.0.1:{port}", "--log-dir", str(workdir / "sitl"),
           "--summary-json", str(workdir / "sitl" / "summary.json"), "--quiet", "--no-truth-log", *sitl_args]
    for rate in SITL_RATES:
        cmd += ["--rate", rate]
    app.open()
    sitl = subprocess.Popen(cmd, env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def watch() -> None:
        sitl.wait()
        time.sleep(0.5)             # let the last datagrams in
        app.request_stop()

    threading.Thread(target=watch, daemon=True).start()
    try:
        while not app.stopping:
            app.spin()
    finally:
        app.close()
        if sitl.poll() is None:
            sitl.terminate()
            sitl.wait(timeout=10)
    summary = json.loads((workdir / "sitl" / "summary.json").read_text())
    return app, summary


def _capacity(tlog: Path, params: str, workdir: Path, max_messages: int = 300_000) -> float:
    """Messages per second through parse_buffer + CompanionApp.handle, from memory."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(tlog))
    frames = []
    while len(frames) < max_messages:
        msg = log.recv_msg()
        if msg is None:
            break
        if msg.get_srcComponent() == 1 and msg.get_type() != "BAD_DATA":
            frames.append(bytes(msg.get_msgbuf()))
    log.close()
    datagrams, current = [], b""
    for frame in frames:            # the simulator's batching: ~1400-byte datagrams
        if len(current) + len(frame) > 1400:
            datagrams.append(current)
            current = b""
        current += frame
    datagrams.append(current)
    parm = workdir / "capacity.parm"
    parm.write_text(params, encoding="utf-8")
    app = CompanionApp(AppOptions(connect="udpout:127.0.0.1:9", params=str(parm), log_dir=str(workdir / "capacity"),
                                  quiet=True))
    app.open()
    parse = app.link.conn.mav.parse_buffer
    started = time.perf_counter()
    handled = 0
    try:
        for data in datagrams:
            for msg in parse(data) or ():
                app.handle(msg)
                handled += 1
    finally:
        elapsed = time.perf_counter() - started
        app.close()
    return handled / elapsed


PAPER_ESTIMATOR = "FUS_MODEL 1\nNAV_ELEMENTS 1\n"
"""The parameters that make the companion's navigator the paper's estimator on (D, I)."""


def _lockstep(workdir: Path, params: str, step_sim_s: float, timeout_s: float, prefix: str = "") -> dict:
    """One lockstep flight: its control steps' latencies (ms) and the pair's speed, keys prefixed."""
    workdir.mkdir()
    app, sitl = _fly_against_sitl(workdir, ["--lockstep", "--lockstep-period", "1.0", "--duration", str(step_sim_s)],
                                  params, True, timeout_s)
    stepper = app.stepper
    lat = [v * 1e3 for v in stepper.step_latency_s]
    out: dict = {}
    if lat:
        out.update({"control_steps": len(lat), "step_latency_median_ms": round(statistics.median(lat), 3),
                    "step_latency_p99_ms": round(_percentile(lat, 0.99), 3),
                    "step_latency_max_ms": round(max(lat), 3)})
        for part, values in (("average", stepper.average_latency_s), ("judge", stepper.judge_latency_s),
                             ("core", stepper.core_latency_s)):
            out[f"{part}_latency_median_ms"] = round(statistics.median(values) * 1e3, 3)
    out["lockstep_sim_speedup"] = sitl["speedup"]
    out["lockstep_msgs_per_s"] = round(app.messages_from_fc / max(sitl["wall_s"], 1e-9), 1)
    return {prefix + key: value for key, value in out.items()}


def run(step_sim_s: float = 6000.0, free_sim_s: float = 4000.0, timeout_s: float = 300.0) -> dict:
    """The three measurements (see the module docstring) as a flat dict of numbers."""
    params = "COMP_ARM_ENABLE 1\nNAV_PERIOD_S 60\nCOMP_SP_RATE_HZ 2.5\n"
    out: dict = {}
    with tempfile.TemporaryDirectory(prefix="fcmpc-bench-companion-") as tmp:
        workdir = Path(tmp)
        out.update(_lockstep(workdir / "lockstep", params, step_sim_s, timeout_s))
        paper = _lockstep(workdir / "paper", params + PAPER_ESTIMATOR, step_sim_s, timeout_s, "paper_estimator_")
        out.update({key: value for key, value in paper.items() if "latency" in key})
        (workdir / "free").mkdir()
        app, sitl = _fly_against_sitl(workdir / "free", ["--speedup", "0", "--duration", str(free_sim_s), "--tlog"],
                                      params, False, timeout_s)
        sent = sitl["tx_messages"]
        out["free_sim_msgs_per_s"] = sitl["tx_msgs_per_wall_s"]
        out["free_handled_msgs_per_s"] = round(app.messages_from_fc / max(sitl["wall_s"], 1e-9), 1)
        out["free_loss_fraction"] = round(1.0 - app.messages_from_fc / sent, 5) if sent else 0.0
        out["capacity_msgs_per_s"] = round(_capacity(workdir / "free" / "sitl" / "sitl.tlog", params, workdir), 1)
    return out


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))
