"""Benchmark of the companion process against the simulator's streams (``fcmpc.bench.sections`` calls it).

The simulator runs as a separate process, started by module name (``python -m sitl.fc``; the
companion never imports it); the companion runs in this process, exactly as ``fcmpc-companion``
would, records included. Three measurements:

``CPU per simulated hour``
    closed loop in lockstep for one simulated hour of mission at the stand-in's stream rates
    (ATTITUDE and the magnetometer's IMU message 10 Hz, GLOBAL_POSITION_INT, GPS_RAW_INT,
    HEARTBEAT and SYSTEM_TIME 1 Hz; the companion answers with the 10 Hz position feed, 2.5 Hz
    setpoints and its heartbeat): the CPU seconds of this process (``time.process_time``)
    over the flight, scaled to 3,600 s of message time, beside the *floor*: the CPU seconds
    pymavlink's own ``parse_buffer`` takes to parse the same messages and nothing else. The
    control step's latency (once per NAV_PERIOD_S) is no longer a target (issue 49): what a
    mission costs the companion board is.
``sustained input``
    the simulator free-running as fast as it can (no lockstep): messages the companion handled
    per wall second and the fraction lost (socket overflow is what falling behind looks like on
    UDP). If nothing is lost the companion kept up and the figure is a lower bound set by the
    simulator's own speed.
``capacity``
    the same recorded stream replayed from memory through the link's receive path
    (:meth:`~companion.io.link.mavlink_link.MavlinkLink.feed`: peers, parsing, the tlog) and the
    receive hook, no socket in: the companion's CPU-bound ceiling in messages per CPU second of
    the receiving thread, the median of ``repeat`` replays and their spread, beside the CPU
    seconds its other thread (the route's prediction while READY) took meanwhile and the floor
    for the same datagrams (pymavlink's ``parse_buffer`` alone, per CPU second of the thread).
    What it counts: every frame of the flight controller's (component 1) in the free-running
    stand-in's tlog (ATTITUDE and HIGHRES_IMU 10 Hz, GLOBAL_POSITION_INT, GPS_RAW_INT, HEARTBEAT,
    SYSTEM_TIME 1 Hz, a few STATUSTEXT and COMMAND_ACK), in its ~1400-byte datagrams; the CPU of
    the thread that parses them, records them in the tlog and handles them, including what that
    triggers (the 10 Hz GPS_INPUT, 2.5 Hz setpoints and heartbeats packed, recorded and sent to a
    bound socket, the control steps); not the prediction's thread.
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
from fcmpc.fly.standin import SITL_RATES, free_udp_port     # the stand-in's streams as fcmpc-fly asks for them

__all__ = ["run"]

REPO = Path(__file__).resolve().parents[2]


def _fly_against_sitl(workdir: Path, sitl_args: list[str], params: str, lockstep: bool, timeout_s: float):
    """Start the simulator, run a CompanionApp here until the simulator exits; (app, sitl summary,
    CPU seconds of this process while the companion flew)."""
    port = free_udp_port()
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
    cpu0 = time.process_time()
    try:
        while not app.stopping:
            app.spin()
        cpu_s = time.process_time() - cpu0
    finally:
        app.close()
        if sitl.poll() is None:
            sitl.terminate()
            sitl.wait(timeout=10)
    summary = json.loads((workdir / "sitl" / "summary.json").read_text())
    return app, summary, cpu_s


SECONDS_PER_HOUR = 3600.0


def _frames(tlog: Path, max_messages: int) -> list[bytes]:
    """The flight controller's frames (component 1) of a simulator's tlog, in order."""
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
    return frames


def _datagrams(frames: list[bytes]) -> list[bytes]:
    """The simulator's batching: frames packed into ~1400-byte datagrams."""
    datagrams, current = [], b""
    for frame in frames:
        if len(current) + len(frame) > 1400:
            datagrams.append(current)
            current = b""
        current += frame
    datagrams.append(current)
    return datagrams


def parse_floor_cpu_s(datagrams: list[bytes]) -> tuple[float, int]:
    """(CPU seconds of this thread, messages) of pymavlink's ``MAVLink.parse_buffer`` over
    ``datagrams``, nothing else (the thread's: a replay's prediction thread may still be running)."""
    from companion.io.link.conventions import mavlink

    parser = mavlink.MAVLink(None, 1, 191)
    started = time.thread_time()
    count = sum(len(parser.parse_buffer(data) or ()) for data in datagrams)
    return time.thread_time() - started, count


def _mission_cost(workdir: Path, params: str, sim_s: float, timeout_s: float) -> dict:
    """One lockstep flight of ``sim_s`` of message time: the companion's CPU seconds per simulated
    hour beside pymavlink's floor for the same messages, and the pair's speed."""
    workdir.mkdir()
    app, sitl, cpu_s = _fly_against_sitl(workdir, ["--lockstep", "--lockstep-period", "1.0", "--duration", str(sim_s),
                                                   "--tlog"], params, True, timeout_s)
    hours = sitl["sim_s"] / SECONDS_PER_HOUR
    floor_s, parsed = parse_floor_cpu_s(_datagrams(_frames(workdir / "sitl" / "sitl.tlog", 10 ** 7)))
    return {"mission_cpu_s_per_sim_hour": round(cpu_s / hours, 3),
            "parse_floor_cpu_s_per_sim_hour": round(floor_s / hours, 3),
            "messages_per_sim_hour": round(parsed / hours),
            "lockstep_sim_speedup": sitl["speedup"],
            "lockstep_msgs_per_s": round(app.messages_from_fc / max(sitl["wall_s"], 1e-9), 1)}


def capacity_msgs_per_s(datagrams: list[bytes], params: str, workdir: Path) -> tuple[float, float]:
    """(messages per CPU second of the receiving thread, CPU seconds of the process's other
    threads meanwhile) through the link's receive path (MavlinkLink.feed) and CompanionApp.handle,
    from memory (the flight controller's address, as a UDP link sees it).

    CPU time, not wall time: on a shared machine the wall clock also counts the other processes'
    turns (at load 17 on 2 cores it read a fifth of the CPU figure); alone, the two agree. The
    receiving thread's (``time.thread_time``), not the process's: while READY the companion
    predicts the route once per configuration on a thread of its own
    (:mod:`companion.process.forecast`), several CPU seconds that are not a message's cost and
    would, within a replay of 96,000 messages, outweigh them; they are the second number."""
    workdir.mkdir(parents=True, exist_ok=True)
    parm = workdir / "capacity.parm"
    parm.write_text(params, encoding="utf-8")
    # the flight controller's socket: bound, so what the companion sends is delivered (and dropped
    # when its buffer is full) as to a listening autopilot, not bounced as to a closed port
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as fc_socket:
        fc_socket.bind(("127.0.0.1", 0))
        app = CompanionApp(AppOptions(connect=f"udpout:127.0.0.1:{fc_socket.getsockname()[1]}", params=str(parm),
                                      log_dir=str(workdir / "companion"), quiet=True))
        app.open()
        feed, handle, address = app.link.feed, app.handle, ("127.0.0.1", 5760)
        handled = 0
        started, process_started = time.thread_time(), time.process_time()
        try:
            for data in datagrams:
                for msg in feed(address, data):
                    handle(msg)
                    handled += 1
        finally:
            elapsed = time.thread_time() - started
            others = time.process_time() - process_started - elapsed
            app.close()
    return handled / max(elapsed, 1e-9), max(others, 0.0)


def run(mission_sim_s: float = SECONDS_PER_HOUR, free_sim_s: float = 4000.0, timeout_s: float = 300.0,
        repeat: int = 5) -> dict:
    """The three measurements (see the module docstring) as a flat dict of numbers."""
    params = "COMP_ARM_ENABLE 1\nNAV_PERIOD_S 60\nCOMP_SP_RATE_HZ 2.5\n"
    out: dict = {}
    with tempfile.TemporaryDirectory(prefix="fcmpc-bench-companion-") as tmp:
        workdir = Path(tmp)
        out.update(_mission_cost(workdir / "lockstep", params, mission_sim_s, timeout_s))
        (workdir / "free").mkdir()
        app, sitl, _ = _fly_against_sitl(workdir / "free", ["--speedup", "0", "--duration", str(free_sim_s), "--tlog"],
                                         params, False, timeout_s)
        sent = sitl["tx_messages"]
        out["free_sim_msgs_per_s"] = sitl["tx_msgs_per_wall_s"]
        out["free_handled_msgs_per_s"] = round(app.messages_from_fc / max(sitl["wall_s"], 1e-9), 1)
        out["free_loss_fraction"] = round(1.0 - app.messages_from_fc / sent, 5) if sent else 0.0
        datagrams = _datagrams(_frames(workdir / "free" / "sitl" / "sitl.tlog", 300_000))
        replays = [capacity_msgs_per_s(datagrams, params, workdir / f"capacity{k}") for k in range(repeat)]
        rates = [rate for rate, _ in replays]
        out["capacity_msgs_per_s"] = round(statistics.median(rates), 1)
        out["capacity_spread_msgs_per_s"] = [round(min(rates)), round(max(rates))]
        out["capacity_other_threads_cpu_s"] = round(statistics.median(others for _, others in replays), 2)
        floors = [parse_floor_cpu_s(datagrams) for _ in range(repeat)]
        out["capacity_parse_floor_msgs_per_s"] = round(statistics.median(n / max(s, 1e-9) for s, n in floors), 1)
        out["capacity_messages"] = floors[0][1]
    return out


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))
