"""One closed-loop mission: the simulator and the companion as two processes on loopback.

:func:`fly` writes the run's parameter file (the scenario's start, destination, altitude and
date, ``COMP_ARM_ENABLE = 1``), starts the companion (``python -m companion.app``, listening on
a free UDP port like a ground station), waits until it has bound the port (its ``steps.csv``
appears: an event, not a sleep), starts the simulator (``python -m sitl.fc --out`` to that
port), reports progress while the companion flies (one line per control step at most every
``progress_s`` wall seconds, on stderr), lets the companion linger after the mission's end
(:func:`linger_s`: the simulated vehicle's stopping time plus the rest window) so the truth log
shows where the vehicle came to rest, stops the simulator when the companion is done and
evaluates the records (:mod:`fcmpc.fly.results`, :mod:`fcmpc.fly.plots`).

Interrupts: SIGINT (Ctrl-C) or SIGTERM stop both children, and the run is still evaluated:
``result.json``, the plot and the summary say "interrupted", exit code 128 + signal (130 for
Ctrl-C). A second Ctrl-C while the results are written raises ``KeyboardInterrupt``. A child
that stopped on its own before the mission ended (a signal sent to it alone, or a crash) is
reported as such, not as a miss.

Pacing: lockstep by default (a boundary every 1 s of simulated time for ArduPilot, 0.4 s for
PX4 whose offboard timeout is 1 s; setpoints at 2.5 Hz), as fast as the two processes go and
deterministic for a seed; ``speedup`` paces the simulator at N times real time instead.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path
from typing import Callable, Iterable, TextIO

from companion.nav.geo import geodesic_direct, geodesic_inverse
from companion.params import validate_all, write_parm_file
from fcmpc.fly.plots import plot_track
from fcmpc.fly.results import (REST_WINDOW_S, STATUS_EXIT, FlyResult, TruthTrack, distances, read_steps,
                               read_truth_track,
                               write_result)
from sitl.scenario import Scenario, load_scenario

__all__ = ["FlyOptions", "fly", "fly_in_process_alike", "prepare", "finish", "short_destination", "write_short_scenario", "StepProgress",
           "REPO", "SHORT_KM"]

REPO = Path(__file__).resolve().parents[2]
SHORT_KM = 80.0
# Lockstep boundaries: the simulator applies setpoints only at boundaries, so the period must stay
# below the autopilot's setpoint timeout (ArduPilot GUIDED 3 s, PX4 offboard loss 1 s).
LOCKSTEP_PERIOD_S = {"ardupilot": 1.0, "px4": 0.4}
SETPOINT_RATE_HZ = 2.5        # COMP_SP_RATE_HZ for lockstep runs (PX4 needs > 2 Hz)
# Streams the simulator sends by default that the companion does not use (fewer messages, faster).
SITL_RATES = ("SCALED_IMU:0", "LOCAL_POSITION_NED:0", "SYS_STATUS:0", "GPS_RAW_INT:1", "GLOBAL_POSITION_INT:1")
BIND_TIMEOUT_S = 60.0         # wall seconds for the companion to open its link
POLL_S = 0.1


@dataclass(frozen=True)
class FlyOptions:
    scenario: str = "pacific"
    seed: int = 0
    lockstep: bool = True
    speedup: float | None = None
    short: bool = False
    short_km: float = SHORT_KM
    autopilot: str = "ardupilot"
    out_dir: str | None = None
    timeout_s: float = 3600.0            # wall seconds: a hang guard, not a pace
    faults: tuple[str, ...] = ()
    extra_params: dict = field(default_factory=dict)
    compare: bool = False
    plot: bool = True
    startup_s: float | None = None
    tlog: bool = True
    quiet: bool = False                  # children without status lines
    data_dir: str | None = None
    sitl_extra: tuple[str, ...] = ()     # more simulator arguments, e.g. ("--tlog",)
    progress_s: float | None = 10.0      # wall seconds between progress lines on stderr; None: none
    fc: str = "sim"                      # sim: our stand-in; ardupilot: real ArduPilot Rover SITL (fcmpc.fly.firmware)
    fc_instance: int = 0                 # ArduPilot SITL -I (TCP 5760 + 10 i)
    compass: str = "real"                # the firmware's own compass: a real installation's errors, or "ideal"
    physics: str = "builtin"             # the firmware's own (builtin), or our world in lockstep: json (ArduPilot),
                                         # hil (PX4; sitl.firmware.px4_hil)
    nice: int = 0                        # niceness added to both children (os.nice): a lockstep run keeps no
                                         # wall pace, so beside wall-paced work (real firmware) it can yield


def short_destination(scenario: Scenario, distance_km: float = SHORT_KM) -> tuple[float, float]:
    """The point ``distance_km`` from the start along the start-destination geodesic."""
    _, course = geodesic_inverse(scenario.start_lat_deg, scenario.start_lon_deg,
                                 scenario.dest_lat_deg, scenario.dest_lon_deg)
    lat, lon = geodesic_direct(scenario.start_lat_deg, scenario.start_lon_deg, course, distance_km * 1000.0)
    return float(lat), float(lon)


def write_short_scenario(scenario: Scenario, dest: tuple[float, float], path: Path) -> Path:
    """A copy of the scenario's TOML with ``[mission] destination`` replaced."""
    text = Path(scenario.source).read_text(encoding="utf-8")
    new, count = re.subn(r"(?m)^(\s*destination\s*=\s*)\[[^\]]*\]", rf"\g<1>[{dest[0]!r}, {dest[1]!r}]", text)
    if count != 1:
        raise ValueError(f"{scenario.source}: cannot find one 'destination = [...]' line to shorten")
    new = re.sub(r'(?m)^name\s*=\s*"([^"]*)"', r'name = "\1_short"', new, count=1)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(new, encoding="utf-8")
    return path


class StepProgress:
    """Follows a growing ``steps.csv`` (rows are flushed one by one) and says where the run is."""

    def __init__(self, path: Path, every_s: float | None, say: Callable[[str], None], clock=time.monotonic) -> None:
        self.path, self.every_s, self.say, self.clock = path, every_s, say, clock
        self._offset = 0
        self._header: list[str] | None = None
        self._partial = ""
        self.last_row: dict | None = None
        self._said_step = -1
        self._said_at = -math.inf
        self._wall0 = clock()

    def poll(self) -> None:
        """Read what was appended; say one line if a new step came and ``every_s`` passed."""
        try:
            with open(self.path, encoding="utf-8", newline="") as handle:
                handle.seek(self._offset)
                chunk = handle.read()
                self._offset = handle.tell()
        except FileNotFoundError:
            return
        text = self._partial + chunk
        lines = text.split("\n")
        self._partial = lines.pop()            # an incomplete last line waits for the next poll
        for row in csv.reader(io.StringIO("\n".join(lines))):
            if not row:
                continue
            if self._header is None:
                self._header = row
                continue
            record = dict(zip(self._header, row))
            if record.get("event") == "step":
                self.last_row = record
        self._maybe_say()

    def _maybe_say(self) -> None:
        row = self.last_row
        if row is None or self.every_s is None:
            return
        step = int(float(row["step"]))
        now = self.clock()
        if step == self._said_step or (self._said_step >= 0 and now - self._said_at < self.every_s):
            return
        self._said_step, self._said_at = step, now
        self.say(self.line(row, now - self._wall0))

    @staticmethod
    def line(row: dict, wall_s: float) -> str:
        remaining = float(row["remaining_m"]) if row.get("remaining_m") else math.nan
        to_go = f"{remaining / 1000.0:.1f} km to go (companion's estimate)" if math.isfinite(remaining) else \
            "distance to go unknown"
        return (f"fcmpc-fly: step {int(float(row['step']))} ({row.get('phase', '')}), "
                f"{float(row['msg_time_s']) / 3600.0:.2f} h simulated, {to_go}, {wall_s:.0f} s wall")


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _env() -> dict:
    env = dict(os.environ, MAVLINK20="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def _niceness(increment: int) -> Callable[[], None] | None:
    """A ``preexec_fn`` that lowers a child's scheduling priority by ``increment`` (None: keep it)."""
    if increment <= 0:
        return None
    return lambda: os.nice(increment)


def _stop(proc: subprocess.Popen | None, grace_s: float = 10.0) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=5.0)


def _stopped_by_signal(returncode: int) -> bool:
    """A child's exit code after SIGINT/SIGTERM: killed (negative) or 128 + signal."""
    return returncode < 0 or returncode in (128 + signal.SIGINT, 128 + signal.SIGTERM)


class _Interrupts:
    """SIGINT/SIGTERM set a flag while the children run (main thread only); a second Ctrl-C raises."""

    def __init__(self) -> None:
        self.signum = 0
        self._old: dict[int, object] = {}

    def __enter__(self) -> "_Interrupts":
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                self._old[signum] = signal.signal(signum, self._handle)
        return self

    def _handle(self, signum, frame) -> None:  # noqa: ARG002
        self.signum = self.signum or signum
        signal.signal(signal.SIGINT, signal.default_int_handler)

    def __exit__(self, *exc) -> None:
        for signum, old in self._old.items():
            signal.signal(signum, old)


def prepare(options: FlyOptions) -> tuple[Scenario, tuple[float, float], dict]:
    """Validate everything the user gave before anything is written: the scenario, the short
    destination and the parameter values (:class:`companion.params.ParamError` names the bad one)."""
    scenario = load_scenario(options.scenario)
    if options.autopilot not in LOCKSTEP_PERIOD_S:
        raise ValueError(f"autopilot {options.autopilot!r}: choose from {', '.join(LOCKSTEP_PERIOD_S)}")
    dest = (scenario.dest_lat_deg, scenario.dest_lon_deg)
    if options.short:
        if not options.short_km > 0.0:
            raise ValueError(f"--short-km {options.short_km:g}: must be > 0")
        dest = short_destination(scenario, options.short_km)
    values = {**scenario.nav_overrides(), "NAV_DEST_LAT": dest[0], "NAV_DEST_LON": dest[1], "COMP_ARM_ENABLE": 1}
    if options.lockstep:
        values["COMP_SP_RATE_HZ"] = SETPOINT_RATE_HZ
    values = validate_all({**values, **options.extra_params})
    # the route's real crust: synthesised here the first time (seconds; cached), so a missing
    # coefficient file is said now and the simulator starts on the cached grid
    from sitl.world.build import crust_grid
    crust_grid(scenario, options.data_dir)
    return scenario, dest, values


def linger_s(scenario: Scenario) -> float:
    """Simulated seconds after the mission's end for the simulated vehicle to stop from top speed
    (its deceleration limit) and then stay still for the rest window of :mod:`fcmpc.fly.results`."""
    return scenario.vehicle.max_speed_mps / scenario.vehicle.accel_mps2 + REST_WINDOW_S + 5.0


def _commands(options: FlyOptions, scenario: Scenario, out: Path, parm: Path, scenario_arg: str,
              port: int) -> tuple[list, list]:
    companion = [sys.executable, "-m", "companion.app", "--connect", f"udp:127.0.0.1:{port}", "--params", str(parm),
                 "--log-dir", str(out / "companion"), "--exit-when-done", "--linger-s", f"{linger_s(scenario):g}",
                 "--max-wall-s", str(options.timeout_s)]
    if options.lockstep:
        companion.append("--lockstep")
    if options.startup_s is not None:
        companion += ["--startup-s", str(options.startup_s)]
    if not options.tlog:
        companion.append("--no-tlog")
    if options.quiet:
        companion.append("--quiet")
    sitl = [sys.executable, "-m", "sitl.fc", "--scenario", scenario_arg, "--seed", str(options.seed),
            "--out", f"udp:127.0.0.1:{port}", "--log-dir", str(out / "sitl"), "--autopilot", options.autopilot,
            "--quiet"]
    for rate in SITL_RATES:
        sitl += ["--rate", rate]
    if options.lockstep:
        sitl += ["--lockstep", "--lockstep-period", str(LOCKSTEP_PERIOD_S[options.autopilot])]
        if options.speedup:
            sitl += ["--speedup", str(options.speedup)]
    else:
        sitl += ["--speedup", str(options.speedup if options.speedup is not None else 1000.0)]
    for fault in options.faults:
        sitl += ["--fault", fault]
    if options.data_dir:
        sitl += ["--data-dir", options.data_dir]
    if scenario.storm.kp_feed or scenario.storm.symh_feed:
        # the ground station keeps NAV_KP and NAV_SYMH up to date, as in-process the world does: a
        # storm's indices, or a quiet day's (the scenario's [storm] kp_feed / symh_feed withhold them)
        sitl.append("--space-weather-feed")
    return companion, sitl + list(options.sitl_extra)


def _companion_outcome(rc: int, summary: dict) -> tuple[str, str]:
    """(status, message) from the companion's exit code and summary."""
    if rc == 0 and summary.get("arrived"):
        return "arrived", ""
    if rc == 1:
        return "failed", f"the mission failed: {summary.get('phase', '')}".rstrip(": ")
    if rc == 3:
        return "timeout", "the companion gave up (--max-wall-s)"
    if _stopped_by_signal(rc) or rc == 0:
        return "interrupted", f"the companion was stopped (exit code {rc}) before the mission ended"
    return "error", f"the companion exited with {rc}"


def fly(options: FlyOptions, stderr: TextIO | None = None) -> FlyResult:
    """Run one closed-loop mission; see the module docstring. User errors raise before any folder
    is created (``ScenarioError``, ``ParamError``, ``ValueError``)."""
    err = stderr if stderr is not None else sys.stderr
    wall0 = time.monotonic()
    scenario, dest, values = prepare(options)
    stamp = f"{datetime.now():%Y%m%d-%H%M%S}-{os.getpid()}"
    out = Path(options.out_dir) if options.out_dir else \
        REPO / "out" / "fly" / f"{scenario.name}{'-short' if options.short else ''}-s{options.seed}-{stamp}"
    out.mkdir(parents=True, exist_ok=True)
    scenario_arg = options.scenario
    if options.short:
        scenario_arg = str(write_short_scenario(scenario, dest, out / f"{scenario.name}_short.toml"))
    parm = out / "fly.parm"
    write_parm_file(parm, values, header=f"fcmpc-fly: scenario {scenario.name}, seed {options.seed}")
    companion_cmd, sitl_cmd = _commands(options, scenario, out, parm, scenario_arg, _free_udp_port())

    def say(text: str) -> None:
        print(text, file=err, flush=True)

    progress = StepProgress(out / "companion" / "steps.csv", options.progress_s, say)
    companion = sitl = None
    status, code, message = "error", 1, ""
    companion_log = open(out / "companion.log", "w", encoding="utf-8")
    sitl_log = open(out / "sitl.log", "w", encoding="utf-8")
    with _Interrupts() as interrupts:
        try:
            env = _env()
            yield_cpu = _niceness(options.nice)
            companion = subprocess.Popen(companion_cmd, env=env, cwd=REPO, stdout=companion_log,
                                         stderr=subprocess.STDOUT, preexec_fn=yield_cpu)
            bound = out / "companion" / "steps.csv"      # created right after the link is open
            deadline = time.monotonic() + BIND_TIMEOUT_S
            while not bound.exists() and companion.poll() is None and not interrupts.signum:
                if time.monotonic() > deadline:
                    break
                time.sleep(POLL_S)
            if bound.exists() and companion.poll() is None and not interrupts.signum:
                sitl = subprocess.Popen(sitl_cmd, env=env, cwd=REPO, stdout=sitl_log, stderr=subprocess.STDOUT,
                                        preexec_fn=yield_cpu)
                if options.progress_s is not None:
                    say(f"fcmpc-fly: flying {scenario.name}{' (short)' if options.short else ''}, seed "
                        f"{options.seed}; records in {out}")
            status, code, message = _watch(options, companion, sitl, interrupts, progress, wall0, out)
        finally:
            _stop(companion)
            _stop(sitl)
            companion_log.close()
            sitl_log.close()
        if interrupts.signum:
            status, code = "interrupted", 128 + interrupts.signum
            message = f"stopped by {signal.Signals(interrupts.signum).name}" + (f"; {message}" if message else "")
    return finish(options, scenario, out, dest, status, code, message, wall0, scenario_arg)


def _watch(options: FlyOptions, companion: subprocess.Popen, sitl: subprocess.Popen | None, interrupts: _Interrupts,
           progress: StepProgress, wall0: float, out: Path) -> tuple[str, int, str]:
    """Wait for the companion to finish; (status, exit code, message)."""
    if sitl is None:
        rc = companion.poll()
        if rc is not None:
            return "error", 1, f"the companion exited with {rc} before opening its link; see {out / 'companion.log'}"
        if interrupts.signum:
            return "interrupted", 130, ""
        return "error", 1, f"the companion did not open its link within {BIND_TIMEOUT_S:g} s"
    deadline = wall0 + options.timeout_s + 30.0
    while not interrupts.signum:
        progress.poll()
        rc = companion.poll()
        if rc is not None:
            summary_path = out / "companion" / "summary.json"
            summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
            status, message = _companion_outcome(rc, summary)
            if status == "error":
                message += f"; see {out / 'companion.log'}"
            return status, STATUS_EXIT[status], message
        if sitl.poll() is not None:
            rc = sitl.returncode
            if _stopped_by_signal(rc) or rc == 0:
                return "interrupted", 130, f"the simulator stopped (exit code {rc}) before the mission ended"
            return "error", 1, f"the simulator exited with {rc}; see {out / 'sitl.log'}"
        if time.monotonic() > deadline:
            return "timeout", 3, f"no result within {options.timeout_s:g} s"
        time.sleep(POLL_S)
    return "interrupted", 128 + interrupts.signum, ""


def finish(options: FlyOptions, scenario: Scenario, out: Path, dest: tuple[float, float], status: str, code: int,
           message: str, wall0: float, scenario_arg: str | None = None, truth: TruthTrack | None = None) -> FlyResult:
    """Evaluate the records in ``out`` (truth track, steps.csv, companion summary), plot, write
    ``result.json``; independent of which simulator produced the truth track (``truth``: given,
    or the stand-in's ``sitl/truth.csv``)."""
    if truth is None:
        truth = read_truth_track(out / "sitl" / "truth.csv")
    steps = read_steps(out / "companion" / "steps.csv")
    summary_path = out / "companion" / "summary.json"
    companion = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    d = distances(truth, steps, dest)
    result = FlyResult(status=status, exit_code=code, scenario=scenario.name, seed=options.seed,
                       iterations=d["iterations"], rest_remaining_m=d["rest_remaining_m"],
                       step_remaining_m=d["step_remaining_m"], believed_remaining_m=d["believed_remaining_m"],
                       came_to_rest=d["came_to_rest"], wall_s=time.monotonic() - wall0, sim_s=d["sim_s"],
                       out_dir=str(out), plot_path=None, dest_lat_deg=dest[0], dest_lon_deg=dest[1],
                       companion={k: v for k, v in companion.items() if k != "events"}, message=message)
    if truth is None:
        result = replace(result, message=(message + "; " if message else "") + "no truth track was written")
    if options.compare and status != "interrupted":
        result = _compare_in_process(options, scenario_arg or options.scenario, dest, result)
    if options.plot and truth is not None:
        try:
            path = plot_track(out / "track.png", (scenario.start_lat_deg, scenario.start_lon_deg), dest, truth, steps,
                              result, scenario.name + (" (short)" if options.short else ""))
            result = replace(result, plot_path=str(path))
            from sitl.world.anomaly import write_route_anomaly
            write_route_anomaly(out / "crust_anomaly.png", scenario,
                                {**scenario.nav_overrides(), **options.extra_params}, options.data_dir)
        except Exception as exc:  # noqa: BLE001 - a plot must not hide the result
            result = replace(result, message=(result.message + "; " if result.message else "") + f"plot failed: {exc}")
    write_result(out, result)
    return result


def _compare_in_process(options: FlyOptions, scenario_arg: str, dest: tuple[float, float],
                        result: FlyResult) -> FlyResult:
    [run] = fly_in_process_alike(options, scenario_arg, dest, [options.seed])
    return replace(result, mc_remaining_m=run.remaining_m, mc_iterations=run.iterations)


def fly_in_process_alike(options: FlyOptions, scenario_arg: str, dest: tuple[float, float], seeds: Iterable[int]):
    """The in-process runs (:func:`sitl.inprocess.fly_in_process`) of this flight's scenario, destination
    and parameters, one per seed (the truth field built once): what ``--compare`` prints, and a spread
    of seeds for the tests."""
    from companion.params import NavConfig
    from sitl.inprocess import fly_in_process
    from sitl.world.build import build_truth_field

    scenario = load_scenario(scenario_arg)
    values = {**scenario.nav_overrides(), "NAV_DEST_LAT": dest[0], "NAV_DEST_LON": dest[1], **options.extra_params}
    nav = NavConfig.from_values(validate_all(values))
    truth = build_truth_field(scenario, options.data_dir)
    return [fly_in_process(nav, scenario, seed, truth) for seed in seeds]
