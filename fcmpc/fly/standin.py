"""Our flight-controller stand-in (``python -m sitl.fc``) as a flight controller of the one runner.

The companion listens first on a free UDP port (as a ground station does), and the stand-in is
started once the companion has opened it, sending there (``--out``). Its truth is the
``sitl/truth.csv`` it writes itself; the companion lingers after the mission's end
(:func:`linger_s`) so that the truth shows where the vehicle came to rest.
"""
from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

from fcmpc.fly.mission import REPO, child_env, niceness, stopped_by_signal
from fcmpc.fly.results import REST_WINDOW_S, TruthTrack, read_truth_track
from fcmpc.firmware.processes import stop_process
from sitl.scenario import Scenario

__all__ = ["LOCKSTEP_PERIOD_S", "SITL_RATES", "StandIn", "free_udp_port", "linger_s", "stand_in_args"]

# Lockstep boundaries: the simulator applies setpoints only at boundaries, so the period must stay
# below the autopilot's setpoint timeout (ArduPilot GUIDED 3 s, PX4 offboard loss 1 s).
LOCKSTEP_PERIOD_S = {"ardupilot": 1.0, "px4": 0.4}
# Streams the simulator sends by default that the companion does not use (fewer messages, faster).
SITL_RATES = ("SCALED_IMU:0", "LOCAL_POSITION_NED:0", "SYS_STATUS:0", "GPS_RAW_INT:1", "GLOBAL_POSITION_INT:1")


def linger_s(scenario: Scenario) -> float:
    """Simulated seconds after the mission's end for the simulated vehicle to stop from top speed
    (its deceleration limit) and then stay still for the rest window of :mod:`fcmpc.fly.results`."""
    return scenario.vehicle.max_speed_mps / scenario.vehicle.accel_mps2 + REST_WINDOW_S + 5.0


def stand_in_args(options, scenario: Scenario, scenario_arg: str) -> tuple[str, ...]:
    """The stand-in's options for a ``fcmpc-fly`` run (:class:`fcmpc.fly.runner.FlyOptions`): the
    scenario and seed, the autopilot's conventions, its pacing, faults and space-weather feed."""
    args = ["--scenario", scenario_arg, "--seed", str(options.seed), "--autopilot", options.autopilot, "--quiet"]
    for rate in SITL_RATES:
        args += ["--rate", rate]
    if options.lockstep:
        args += ["--lockstep", "--lockstep-period", str(LOCKSTEP_PERIOD_S[options.autopilot])]
        if options.speedup:
            args += ["--speedup", str(options.speedup)]
    else:
        args += ["--speedup", str(options.speedup if options.speedup is not None else 1000.0)]
    for fault in options.faults:
        args += ["--fault", fault]
    if options.data_dir:
        args += ["--data-dir", options.data_dir]
    if scenario.storm.kp_feed or scenario.storm.symh_feed:
        # the ground station keeps NAV_KP and NAV_SYMH up to date, as in-process the world does: a
        # storm's indices, or a quiet day's (the scenario's [storm] kp_feed / symh_feed withhold them)
        args.append("--space-weather-feed")
    return (*args, *options.sitl_extra)


def free_udp_port() -> int:
    """A UDP port of loopback nobody has bound (the companion binds it next, as a ground station does)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class StandIn:
    """``python -m sitl.fc`` with ``args`` (:func:`stand_in_args`, or the soak's), records in
    ``<out>/sitl``; ``companion_args``: what the companion needs for it (``--lockstep``,
    ``--linger-s``); ``nice``: niceness added to the process."""

    name = "our stand-in"

    def __init__(self, args: tuple[str, ...], companion_args: tuple[str, ...] = (), nice: int = 0) -> None:
        self.args, self.companion_args, self.nice = tuple(args), tuple(companion_args), nice
        self.port = free_udp_port()
        self.process: subprocess.Popen | None = None
        self.out: Path | None = None
        self._log = None

    @property
    def companion_url(self) -> str:
        return f"udp:127.0.0.1:{self.port}"

    def start(self, out: Path) -> list[str]:
        self.out = Path(out)
        return []

    def companion_ready(self, pid: int) -> None:
        """Start the stand-in; in lockstep it waits for the companion's answers as long as process
        ``pid`` lives (``--lockstep-peer-pid``), never for a wall timeout a busy machine can miss, and
        after a crash on the companion restarted on the same port (``--lockstep-successor``)."""
        self._log = open(self.out / "sitl.log", "wb")
        peer = ("--lockstep-peer-pid", str(pid), "--lockstep-successor") if "--lockstep" in self.args else ()
        self.process = subprocess.Popen(
            [sys.executable, "-m", "sitl.fc", "--out", f"udp:127.0.0.1:{self.port}", "--log-dir",
             str(self.out / "sitl"), *self.args, *peer], env=child_env(), cwd=REPO, stdin=subprocess.DEVNULL,
            stdout=self._log, stderr=subprocess.STDOUT, preexec_fn=niceness(self.nice))

    def wait(self, timeout_s: float) -> tuple[str, str] | None:
        time.sleep(timeout_s)     # the stand-in's news are in its records; nothing to read on the way
        rc = self.process.poll() if self.process is not None else None
        if rc is None:
            return None
        if stopped_by_signal(rc) or rc == 0:
            return "interrupted", f"the simulator stopped (exit code {rc}) before the mission ended"
        return "error", f"the simulator exited with {rc}; see {self.out / 'sitl.log'}"

    def settle(self, timeout_s: float) -> None:    # noqa: ARG002 - the companion lingered (linger_s)
        return None

    def stop(self) -> None:
        stop_process(self.process)
        if self._log is not None:
            self._log.close()
            self._log = None

    def truth(self) -> TruthTrack | None:
        return read_truth_track(self.out / "sitl" / "truth.csv") if self.out is not None else None
