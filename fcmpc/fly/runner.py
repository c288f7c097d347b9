"""fcmpc-fly's mission: the scenario and the user's options turned into a flight of the one runner.

:func:`fly` checks everything the user gave before anything is written (:func:`prepare`), picks
the flight controller (our stand-in, :class:`fcmpc.fly.standin.StandIn`, or firmware through
:func:`fcmpc.fly.firmware.firmware_flight`), writes the run's parameter file, flies it with the
one runner (:func:`fcmpc.fly.mission.run_mission`: the processes, the watch, Ctrl-C, stop by
PID), reports progress while the companion flies (one line per control step at most every
``progress_s`` wall seconds, on stderr), and evaluates the records the same way whichever flight
controller flew (:func:`finish`: the three distances, ``result.json``, the plot).

Pacing against the stand-in: lockstep by default (a boundary every 1 s of simulated time for
ArduPilot, 0.4 s for PX4 whose offboard timeout is 1 s; setpoints at 2.5 Hz), as fast as the two
processes go and deterministic for a seed; ``speedup`` paces the simulator at N times real time
instead.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import sys
import time
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path
from typing import Callable, Iterable, TextIO

from companion.nav.geo import geodesic_direct, geodesic_inverse
from companion.params import Controller, validate_all, write_parm_file
from fcmpc.fly.mission import REPO, CompanionRun, run_mission
from fcmpc.fly.plots import plot_track
from fcmpc.fly.results import FlyResult, TruthTrack, distances, read_steps, true_track, write_result
from fcmpc.fly.standin import LOCKSTEP_PERIOD_S, StandIn, linger_s, stand_in_args
from sitl.scenario import Scenario, load_scenario

__all__ = ["FlyOptions", "fly", "fly_in_process_alike", "prepare", "finish", "short_destination",
           "write_short_scenario", "StepProgress", "REPO", "SHORT_KM", "companion_run", "stand_in"]

SHORT_KM = 80.0
SETPOINT_RATE_HZ = 2.5        # COMP_SP_RATE_HZ for lockstep runs (PX4 needs > 2 Hz)


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
                                         # hil (PX4; sitl.physics.px4_hil)
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


def fly(options: FlyOptions, stderr: TextIO | None = None) -> FlyResult:
    """Fly one mission against ``options.fc`` and evaluate it; see the module docstring. User errors
    raise before any folder is created (``ScenarioError``, ``ParamError``, ``ValueError``,
    ``FirmwareMissing``)."""
    err = stderr if stderr is not None else sys.stderr
    wall0 = time.monotonic()
    scenario, dest, values = prepare(options)

    def say(text: str) -> None:
        if options.progress_s is not None:
            print(f"fcmpc-fly: {text}", file=err, flush=True)

    stamp = f"{datetime.now():%Y%m%d-%H%M%S}-{os.getpid()}"
    if options.fc == "sim":
        name = f"{scenario.name}{'-short' if options.short else ''}-s{options.seed}-{stamp}"
    else:
        from fcmpc.fly.firmware import firmware_flight

        fc, values = firmware_flight(options, scenario, dest, values, say)     # FirmwareMissing: nothing written
        name = f"{scenario.name}-{options.fc}-{stamp}"
    out = Path(options.out_dir) if options.out_dir else REPO / "out" / "fly" / name
    out.mkdir(parents=True, exist_ok=True)
    scenario_arg = options.scenario
    if options.fc == "sim":
        if options.short:
            scenario_arg = str(write_short_scenario(scenario, dest, out / f"{scenario.name}_short.toml"))
        fc = stand_in(options, scenario, scenario_arg)
    parm = out / "fly.parm"
    write_parm_file(parm, values, header=f"fcmpc-fly: scenario {scenario.name}, seed {options.seed}, {fc.name}")
    progress = StepProgress(out / "companion" / "steps.csv", options.progress_s,
                            lambda text: print(text, file=err, flush=True))
    say(f"flying {scenario.name}{' (short)' if options.short else ''}, seed {options.seed}, against {fc.name}; "
        f"records in {out}")
    outcome, truth = run_mission(fc, companion_run(options, parm, out), out, options.timeout_s, progress.poll, say)
    return finish(options, scenario, out, dest, outcome.status, outcome.code, outcome.message, wall0, scenario_arg,
                  truth, values)


def stand_in(options: FlyOptions, scenario: Scenario, scenario_arg: str) -> StandIn:
    """Our stand-in flying ``scenario_arg`` (a bundled name or a TOML file) as ``options`` say."""
    lockstep = ("--lockstep",) if options.lockstep else ()
    return StandIn(stand_in_args(options, scenario, scenario_arg), nice=options.nice,
                   companion_args=("--linger-s", f"{linger_s(scenario):g}", *lockstep))


def companion_run(options: FlyOptions, parm: Path, out: Path) -> CompanionRun:
    """The companion of a ``fcmpc-fly`` run: ``parm``, records in ``<out>/companion``, ending with the
    mission (``--exit-when-done``) or after ``timeout_s`` of wall time."""
    args = ["--exit-when-done", "--max-wall-s", str(options.timeout_s)]
    if options.startup_s is not None:
        args += ["--startup-s", str(options.startup_s)]
    if not options.tlog:
        args.append("--no-tlog")
    if options.quiet:
        args.append("--quiet")
    return CompanionRun(parm, out / "companion", tuple(args), options.nice)


def finish(options: FlyOptions, scenario: Scenario, out: Path, dest: tuple[float, float], status: str, code: int,
           message: str, wall0: float, scenario_arg: str | None = None, truth: TruthTrack | None = None,
           values: dict | None = None) -> FlyResult:
    """Evaluate the records in ``out`` (the truth track, steps.csv, the companion's summary), plot,
    write ``result.json``; independent of which flight controller produced the truth track.
    ``values``: the flown parameters (the start and the controller; default the scenario's)."""
    steps = read_steps(out / "companion" / "steps.csv")
    summary_path = out / "companion" / "summary.json"
    companion = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    d = distances(truth, steps, dest)
    values = validate_all(values or scenario.nav_overrides())   # a firmware flight's values are what it set
    lat, lon = true_track(truth, steps, (values["NAV_START_LAT"], values["NAV_START_LON"]), d["rest_index"])
    result = FlyResult(status=status, exit_code=code, scenario=scenario.name, seed=options.seed,
                       iterations=d["iterations"], rest_remaining_m=d["rest_remaining_m"],
                       step_remaining_m=d["step_remaining_m"], believed_remaining_m=d["believed_remaining_m"],
                       came_to_rest=d["came_to_rest"], wall_s=time.monotonic() - wall0, sim_s=d["sim_s"],
                       out_dir=str(out), plot_path=None, dest_lat_deg=dest[0], dest_lon_deg=dest[1],
                       companion={k: v for k, v in companion.items() if k != "events"}, message=message,
                       controller=Controller.NAMES[int(values["NAV_CONTROLLER"])], track_lat_deg=lat, track_lon_deg=lon)
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
    """The in-process runs (:func:`fcmpc.montecarlo.inprocess.fly_in_process`) of this flight's scenario, destination
    and parameters, one per seed (the truth field built once): what ``--compare`` prints, and a spread
    of seeds for the tests."""
    from companion.params import NavConfig
    from fcmpc.montecarlo.inprocess import fly_in_process
    from sitl.world.build import build_truth_field

    scenario = load_scenario(scenario_arg)
    values = {**scenario.nav_overrides(), "NAV_DEST_LAT": dest[0], "NAV_DEST_LON": dest[1], **options.extra_params}
    nav = NavConfig.from_values(validate_all(values))
    truth = build_truth_field(scenario, options.data_dir)
    return [fly_in_process(nav, scenario, seed, truth) for seed in seeds]
