"""One soak: simulator + companion as real processes on loopback, hostile datagrams, a verdict.

The simulator (our stand-in, lockstep: its time advances only when the companion answers)
flies a short-period mission with the companion (``COMP_ARM_ENABLE 1``), both started and
stopped by the one mission runner (:class:`fcmpc.fly.mission.MissionProcesses`). While it runs, a
sender on this process throws :class:`~fcmpc.soak.hostile.Hostile` datagrams at the companion's
port from a pool of source ports larger than the companion's peer table, paced at ``rate_hz``
(a flood beyond what a 2-core machine parses is a denial of service, not a parser test). Then
the records are judged:

* crashes: the companion exited on its own or by a signal other than our SIGTERM;
* setpoints (every SET_POSITION_TARGET_GLOBAL_INT in ``companion.tlog``) non-finite, or faster
  than the cruise speed set at start;
* missions stalled: no new control step during the soak although at least three control
  periods of message time passed while the companion was running;
* parameters changed by strangers: any value in the ``.parm`` file different after the soak
  (nobody legitimate sets one);
* what the companion believed: flight-controller reboots, mission restarts, failsafes.
"""
from __future__ import annotations

import json
import math
import signal
import socket
import subprocess
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from fcmpc.fly.mission import CompanionRun, MissionProcesses
from fcmpc.fly.standin import StandIn
from fcmpc.soak.hostile import CLASSES, Hostile

__all__ = ["SoakResult", "format_table", "judge_setpoints", "soak"]

PERIOD_S = 60.0         # 600 m probing moves at cruise: enough for the gradient
CRUISE_KMH = 36.0
SOURCE_PORTS = 64        # more than the companion's peer table (32): eviction is exercised


@dataclass
class SoakResult:
    sent: Counter = field(default_factory=Counter)
    crashes: int = 0
    setpoints: int = 0
    nonfinite_setpoints: int = 0
    over_limit_setpoints: int = 0
    missions_stalled: int = 0
    params_changed: list[str] = field(default_factory=list)
    fc_reboots_believed: int = 0
    mission_restarts: int = 0
    failsafes: int = 0
    steps_during: int = 0
    link: dict = field(default_factory=dict)
    wall_s: float = 0.0

    @property
    def all_zero(self) -> bool:
        return not (self.crashes or self.nonfinite_setpoints or self.over_limit_setpoints or self.missions_stalled
                    or self.params_changed or self.fc_reboots_believed or self.mission_restarts)


def judge_setpoints(tlogs: list[Path], limit_mps: float) -> tuple[int, int, int]:
    """(setpoints, non-finite, faster than ``limit_mps``) among the companion's sent setpoints (system 1,
    component 191; :class:`~fcmpc.soak.hostile.Hostile` never uses system 1 for a stranger's frames)."""
    from pymavlink import mavutil

    total = nonfinite = over = 0
    for path in tlogs:
        log = mavutil.mavlink_connection(str(path))
        while True:
            msg = log.recv_match(type="SET_POSITION_TARGET_GLOBAL_INT")
            if msg is None:
                break
            if (msg.get_srcSystem(), msg.get_srcComponent()) != (1, 191):
                continue   # the tlog holds both directions: a stranger's SET_POSITION_TARGET is not ours
            total += 1
            values = (msg.vx, msg.vy, msg.vz, msg.yaw)
            if not all(math.isfinite(v) for v in values):
                nonfinite += 1
            elif math.hypot(msg.vx, msg.vy) > limit_mps * (1.0 + 1e-6):
                over += 1
        log.close()
    return total, nonfinite, over


def _step_rows(steps_csv: Path) -> list[float]:
    if not steps_csv.exists():
        return []
    from companion.io.records import read_steps_csv

    return [row["msg_time_s"] for row in read_steps_csv(steps_csv) if row["event"] == "step"]


def _processes(workdir: Path, signing_key: Path | None) -> tuple[MissionProcesses, Path]:
    """The stand-in and the companion of a soak (not yet started) and the companion's parameter file."""
    from companion.params import write_parm_file

    parm = workdir / "companion.parm"
    write_parm_file(parm, {"COMP_ARM_ENABLE": 1, "NAV_PERIOD_S": PERIOD_S, "NAV_SPEED_KMH": CRUISE_KMH,
                           "NAV_MAX_STEPS": 100000})
    args = ("--startup-s", str(PERIOD_S), "--quiet", *(("--signing-key", str(signing_key)) if signing_key else ()))
    fc = StandIn(("--lockstep", "--duration", "1e6", "--quiet", "--lockstep-timeout", "0.5", "--no-truth-log"),
                 companion_args=("--lockstep",))
    return MissionProcesses(fc, CompanionRun(parm, workdir / "companion", args, grace_s=60.0), workdir), parm


def _wait_steps(steps_csv: Path, count: int, procs: list[subprocess.Popen], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while len(_step_rows(steps_csv)) < count:
        if any(p.poll() is not None for p in procs) or time.monotonic() > deadline:
            return
        time.sleep(0.5)


def soak(frames: int, workdir: Path, seed: int = 0, rate_hz: float = 2000.0, signing_key: Path | None = None,
         progress=None) -> SoakResult:
    """Run one soak of ``frames`` hostile datagrams; the verdict (module docstring)."""
    workdir.mkdir(parents=True, exist_ok=True)
    result = SoakResult()
    started = time.monotonic()
    processes, parm = _processes(workdir, signing_key)
    steps_csv = workdir / "companion" / "steps.csv"
    sockets = []
    with processes:
        companion, sitl = processes.companion, processes.fc.process
        _wait_steps(steps_csv, 1, [companion, sitl], 300.0)   # the mission is running before the attack
        before_parm = parm.read_text(encoding="utf-8")
        steps_before = len(_step_rows(steps_csv))
        sockets = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(SOURCE_PORTS)]
        target = ("127.0.0.1", processes.fc.port)
        try:
            hostile = iter(Hostile(seed, signing=signing_key is not None))
            next_send = time.monotonic()
            for k in range(frames):
                kind, data = next(hostile)
                try:
                    sockets[k % SOURCE_PORTS].sendto(data, target)
                except OSError:
                    pass
                result.sent[kind] += 1
                next_send += 1.0 / rate_hz
                delay = next_send - time.monotonic()
                if delay > 0.002:
                    time.sleep(delay)   # pacing the attacker (wall time is this harness's own business)
                if progress is not None and k % 1000 == 0:
                    progress(k)
                if companion.poll() is not None:
                    break
            msg_during = _step_rows(steps_csv)
            _wait_steps(steps_csv, len(msg_during) + 2, [companion, sitl], 300.0)   # and it still steps afterwards
            after_steps = _step_rows(steps_csv)
            result.steps_during = len(after_steps) - steps_before
            result.missions_stalled = int(result.steps_during < 2)
            if companion.poll() is not None:
                result.crashes = 1
            after_parm = parm.read_text(encoding="utf-8")
            result.params_changed = sorted(set(after_parm.split("\n")) ^ set(before_parm.split("\n")))
        finally:
            for sock in sockets:
                sock.close()
    if processes.companion_exit not in (0, 128 + signal.SIGTERM, -signal.SIGTERM):
        result.crashes = 1
    summary_path = workdir / "companion" / "summary.json"
    if summary_path.exists():
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
        result.link = summary.get("link", {})
        result.fc_reboots_believed = int(result.link.get("fc_reboots", 0))
        result.mission_restarts = int(summary.get("restarts", 0))
        result.failsafes = int(summary.get("failsafes", 0))
    tlogs = sorted((workdir / "companion").glob("companion.tlog*"))
    result.setpoints, result.nonfinite_setpoints, result.over_limit_setpoints = judge_setpoints(tlogs, CRUISE_KMH / 3.6)
    result.wall_s = time.monotonic() - started
    return result


def format_table(result: SoakResult) -> str:
    """The issue's table: frames sent per class, then what went wrong (all zero is the goal)."""
    rows = [(f"frames sent: {kind}", result.sent.get(kind, 0)) for kind in CLASSES if kind in result.sent]
    rows += [
        ("frames sent: total", sum(result.sent.values())),
        ("companion crashes", result.crashes),
        ("setpoints sent (checked)", result.setpoints),
        ("non-finite setpoints", result.nonfinite_setpoints),
        (f"setpoints over cruise ({CRUISE_KMH:g} km/h)", result.over_limit_setpoints),
        ("missions stalled", result.missions_stalled),
        ("parameters changed by strangers", len(result.params_changed)),
        ("FC reboots believed (none happened)", result.fc_reboots_believed),
        ("mission restarts", result.mission_restarts),
        ("failsafes entered", result.failsafes),
        ("control steps during the soak", result.steps_during),
    ]
    for key in ("stranger_datagrams_shed", "bad_frames", "impostor_frames", "peers_evicted", "dropped_stamps", "far_future", "far_past",
                "out_of_order", "param_sets_from_strangers", "bad_signatures"):
        if key in result.link:
            rows.append((f"link: {key}", result.link[key]))
    if "unsigned_refused" in result.link:
        rows.append(("link: unsigned refused", sum(result.link["unsigned_refused"].values())))
    width = max(len(name) for name, _ in rows)
    lines = [f"| {'what':<{width}} | {'count':>9} |", f"|{'-' * (width + 2)}|{'-' * 11}|"]
    lines += [f"| {name:<{width}} | {value:>9} |" for name, value in rows]
    return "\n".join(lines)
