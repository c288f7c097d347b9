"""fcmpc-fly: the simulator and the companion as two processes on loopback, one mission, one result.

    fcmpc-fly                                  # the Pacific mission, closed-loop, lockstep
    fcmpc-fly --short                          # the first 80 km of it (a minute of wall time less)
    fcmpc-fly --scenario long_storm --seed 3 --compare
    fcmpc-fly --autopilot px4 --speedup 500    # PX4 OFFBOARD, paced instead of lockstep

It writes the run's parameter file (the scenario's start, destination, altitude and date,
COMP_ARM_ENABLE = 1), starts the companion (``python -m companion.app``, listening on a free
UDP port like a ground station) and the simulator (``python -m sitl.server --out`` to that
port), waits for the companion to finish the mission, stops the simulator, and prints: the
true remaining distance (from the simulator's truth log, at the step that ended the mission,
and where the vehicle finally stopped), the iterations, the wall time and the path of a PNG
of the flown track. ``--compare`` also flies the same seed in-process
(:func:`sitl.inprocess.fly_in_process`, no sockets) and prints its remaining distance.

Exit status: 0 arrived, 1 the mission failed or a process died, 2 bad arguments, 3 timeout.
Everything lands in ``out/fly/<scenario>-s<seed>-<time>/`` (``--out-dir``): ``fly.parm``,
``companion/`` (tlog, steps.csv, summary.json), ``sitl/`` (truth.csv, summary.json),
``track.png``, ``result.json``.

Pacing: by default the simulator runs in lockstep (``--lockstep``, a boundary every 1 s of
simulated time for ArduPilot, 0.4 s for PX4 whose offboard timeout is 1 s; setpoints at
2.5 Hz): as fast as the two processes can go and deterministic for a seed. ``--speedup N`` paces it at N times real time instead, without waiting for the
companion.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MAVLINK20", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import re  # noqa: E402
import signal  # noqa: E402
import socket  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import asdict, dataclass, field  # noqa: E402
from datetime import datetime  # noqa: E402
from pathlib import Path  # noqa: E402

from companion.io.records import read_steps_csv  # noqa: E402
from companion.nav.geo import geodesic_direct, geodesic_distance_m, geodesic_inverse  # noqa: E402
from companion.params import write_parm_file  # noqa: E402
from sitl.scenario import Scenario, load_scenario  # noqa: E402
from sitl.truthlog import read_truth_csv  # noqa: E402

__all__ = ["FlyOptions", "FlyResult", "fly", "short_destination", "write_short_scenario", "plot_track", "main"]

REPO = Path(__file__).resolve().parents[1]
SHORT_KM = 80.0
# Lockstep boundaries: the simulator applies setpoints only at boundaries, so the period must stay
# below the autopilot's setpoint timeout (ArduPilot GUIDED 3 s, PX4 offboard loss 1 s).
LOCKSTEP_PERIOD_S = {"ardupilot": 1.0, "px4": 0.4}
SETPOINT_RATE_HZ = 2.5        # COMP_SP_RATE_HZ for lockstep runs (PX4 needs > 2 Hz)
# Streams the simulator sends by default that the companion does not use (fewer messages, faster).
SITL_RATES = ("SCALED_IMU:0", "LOCAL_POSITION_NED:0", "SYS_STATUS:0", "GPS_RAW_INT:1", "GLOBAL_POSITION_INT:1")


@dataclass
class FlyOptions:
    scenario: str = "pacific"
    seed: int = 0
    lockstep: bool = True
    speedup: float | None = None
    short: bool = False
    short_km: float = SHORT_KM
    autopilot: str = "ardupilot"
    out_dir: str | None = None
    timeout_s: float = 900.0
    faults: tuple[str, ...] = ()
    extra_params: dict = field(default_factory=dict)
    compare: bool = False
    plot: bool = True
    startup_s: float | None = None
    tlog: bool = True
    quiet: bool = False
    data_dir: str | None = None
    sitl_extra: tuple[str, ...] = ()     # more simulator arguments, e.g. ("--tlog",)
    fc: str = "sim"                      # sim (our stand-in) | ardupilot (real ArduPilot Rover SITL)
    fc_instance: int = 0                 # ArduPilot SITL -I (ports 5760 + 10 i)


@dataclass
class FlyResult:
    status: str                      # arrived | failed | timeout | error
    exit_code: int
    scenario: str
    seed: int
    iterations: int
    remaining_m: float               # true distance to the destination at the mission's last step
    final_remaining_m: float         # ... where the vehicle finally stopped
    est_remaining_m: float           # what the companion believed at the end
    wall_s: float
    sim_s: float
    out_dir: str
    plot_path: str | None
    dest_lat_deg: float
    dest_lon_deg: float
    mc_remaining_m: float = math.nan
    mc_iterations: int = 0
    companion: dict = field(default_factory=dict)
    message: str = ""

    def line(self) -> str:
        text = (f"{self.status}: {self.remaining_m:.0f} m from the destination after {self.iterations} iterations "
                f"({self.sim_s / 3600.0:.2f} h simulated, {self.wall_s:.1f} s wall)")
        if math.isfinite(self.mc_remaining_m):
            text += f"; in-process Monte Carlo, same seed: {self.mc_remaining_m:.0f} m, {self.mc_iterations} iterations"
        return text


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


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _env() -> dict:
    env = dict(os.environ, MAVLINK20="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def _stop(proc: subprocess.Popen | None, grace_s: float = 10.0) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=5.0)


def fly_on_ardupilot(options: FlyOptions) -> FlyResult:
    """The mission against real ArduPilot Rover SITL (:mod:`sitl.firmware.flight`): same result
    and plot as against the stand-in, the truth from ArduPilot's own SIMSTATE."""
    from sitl.firmware.flight import FirmwareFlight, fly_ardupilot

    scenario = load_scenario(options.scenario)
    dest = short_destination(scenario, options.short_km) if options.short else (scenario.dest_lat_deg,
                                                                               scenario.dest_lon_deg)
    out = Path(options.out_dir) if options.out_dir else \
        REPO / "out" / "fly" / f"{scenario.name}-ardupilot-{datetime.now():%Y%m%d-%H%M%S}"
    mission = ("NAV_START_LAT", "NAV_START_LON", "NAV_DEST_LAT", "NAV_DEST_LON")
    values = {**{k: v for k, v in scenario.nav_overrides().items() if k not in mission}, **options.extra_params}
    run = fly_ardupilot(FirmwareFlight(
        start=(scenario.start_lat_deg, scenario.start_lon_deg), destination=dest, out_dir=out, values=values,
        speedup=options.speedup or 50.0, instance=options.fc_instance, start_unix_s=scenario.start_posix,
        timeout_s=options.timeout_s, quiet=options.quiet))
    code = {"arrived": 0, "failed": 1, "timeout": 3}.get(run.status, 1)
    return _evaluate(options, scenario, out, dest, run.status, code, run.message, run.wall_s, truth=run.truth)


def fly(options: FlyOptions) -> FlyResult:
    """Run one closed-loop mission; see the module docstring."""
    wall0 = time.monotonic()
    scenario = load_scenario(options.scenario)
    stamp = f"{datetime.now():%Y%m%d-%H%M%S}-{os.getpid()}"
    out = Path(options.out_dir) if options.out_dir else \
        REPO / "out" / "fly" / f"{scenario.name}{'-short' if options.short else ''}-s{options.seed}-{stamp}"
    out.mkdir(parents=True, exist_ok=True)
    scenario_arg = options.scenario
    dest = (scenario.dest_lat_deg, scenario.dest_lon_deg)
    if options.short:
        dest = short_destination(scenario, options.short_km)
        scenario_arg = str(write_short_scenario(scenario, dest, out / f"{scenario.name}_short.toml"))
    values = {**scenario.nav_overrides(), "NAV_DEST_LAT": dest[0], "NAV_DEST_LON": dest[1],
              "COMP_ARM_ENABLE": 1, **options.extra_params}
    if options.lockstep and "COMP_SP_RATE_HZ" not in options.extra_params:
        values["COMP_SP_RATE_HZ"] = SETPOINT_RATE_HZ
    parm = out / "fly.parm"
    write_parm_file(parm, values, header=f"fcmpc-fly: scenario {scenario.name}, seed {options.seed}")
    port = _free_udp_port()
    env = _env()
    companion_cmd = [sys.executable, "-m", "companion.app", "--connect", f"udp:127.0.0.1:{port}",
                     "--params", str(parm), "--log-dir", str(out / "companion"), "--exit-when-done",
                     "--max-wall-s", str(options.timeout_s)]
    if options.lockstep:
        companion_cmd.append("--lockstep")
    if options.startup_s is not None:
        companion_cmd += ["--startup-s", str(options.startup_s)]
    if not options.tlog:
        companion_cmd.append("--no-tlog")
    if options.quiet:
        companion_cmd.append("--quiet")
    sitl_cmd = [sys.executable, "-m", "sitl.server", "--scenario", scenario_arg, "--seed", str(options.seed),
                "--out", f"udp:127.0.0.1:{port}", "--log-dir", str(out / "sitl"), "--autopilot", options.autopilot,
                "--quiet"]
    for rate in SITL_RATES:
        sitl_cmd += ["--rate", rate]
    if options.lockstep:
        sitl_cmd += ["--lockstep", "--lockstep-period", str(LOCKSTEP_PERIOD_S[options.autopilot])]
        if options.speedup:
            sitl_cmd += ["--speedup", str(options.speedup)]
    else:
        sitl_cmd += ["--speedup", str(options.speedup if options.speedup is not None else 1000.0)]
    for fault in options.faults:
        sitl_cmd += ["--fault", fault]
    if options.data_dir:
        sitl_cmd += ["--data-dir", options.data_dir]
    sitl_cmd += list(options.sitl_extra)
    companion = sitl = None
    status, code, message = "error", 1, ""
    companion_log = open(out / "companion.log", "w", encoding="utf-8")
    sitl_log = open(out / "sitl.log", "w", encoding="utf-8")
    try:
        companion = subprocess.Popen(companion_cmd, env=env, cwd=REPO, stdout=companion_log, stderr=subprocess.STDOUT)
        time.sleep(0.2)   # let it bind the port before the simulator starts talking
        sitl = subprocess.Popen(sitl_cmd, env=env, cwd=REPO, stdout=sitl_log, stderr=subprocess.STDOUT)
        deadline = wall0 + options.timeout_s + 30.0
        while True:
            rc = companion.poll()
            if rc is not None:
                code = rc
                status = {0: "arrived", 1: "failed", 3: "timeout"}.get(rc, "error")
                break
            if sitl.poll() is not None:
                status, code, message = "error", 1, f"simulator exited with {sitl.returncode}"
                break
            if time.monotonic() > deadline:
                status, code, message = "timeout", 3, f"no result within {options.timeout_s:g} s"
                break
            time.sleep(0.1)
    finally:
        _stop(companion)
        _stop(sitl)
        companion_log.close()
        sitl_log.close()
    if status == "error" and not message:
        message = f"companion exited with {code}; see {out / 'companion.log'}"
    result = _evaluate(options, scenario, out, dest, status, code, message, time.monotonic() - wall0)
    if options.compare:
        _compare_in_process(options, scenario_arg, dest, result)
    (out / "result.json").write_text(json.dumps(asdict(result), indent=1, default=str) + "\n", encoding="utf-8")
    return result


def _evaluate(options: FlyOptions, scenario: Scenario, out: Path, dest: tuple[float, float], status: str, code: int,
              message: str, wall_s: float, truth: dict | None = None) -> FlyResult:
    truth_path, steps_path = out / "sitl" / "truth.csv", out / "companion" / "steps.csv"
    summary_path = out / "companion" / "summary.json"
    companion = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    if truth is None:
        truth = read_truth_csv(truth_path) if truth_path.exists() else {}
    steps = [row for row in read_steps_csv(steps_path) if row["event"] == "step"] if steps_path.exists() else []
    remaining = final = est_remaining = sim_s = math.nan
    iterations = 0
    if truth.get("time_s"):
        times = truth["time_s"]
        final = geodesic_distance_m(truth["lat_deg"][-1], truth["lon_deg"][-1], *dest)
        sim_s = times[-1]
        if steps:
            end_time = steps[-1]["msg_time_s"]
            index = min(range(len(times)), key=lambda i: abs(times[i] - end_time))
            remaining = geodesic_distance_m(truth["lat_deg"][index], truth["lon_deg"][index], *dest)
            iterations = int(steps[-1]["step"])
            est_remaining = steps[-1]["remaining_m"]
    plot_path = None
    if options.plot and truth.get("time_s"):
        try:
            plot_path = str(plot_track(out / "track.png", scenario, dest, truth, steps, remaining))
        except Exception as err:  # noqa: BLE001 - a plot must not hide the result
            message = (message + "; " if message else "") + f"plot failed: {err}"
    return FlyResult(status=status, exit_code=code, scenario=scenario.name, seed=options.seed, iterations=iterations,
                     remaining_m=remaining, final_remaining_m=final, est_remaining_m=est_remaining, wall_s=wall_s,
                     sim_s=sim_s, out_dir=str(out), plot_path=plot_path, dest_lat_deg=dest[0], dest_lon_deg=dest[1],
                     companion={k: v for k, v in companion.items() if k != "events"}, message=message)


def _compare_in_process(options: FlyOptions, scenario_arg: str, dest: tuple[float, float], result: FlyResult) -> None:
    from companion.params import NavConfig, validate_all
    from sitl.inprocess import fly_in_process
    from sitl.world.build import build_truth_field

    scenario = load_scenario(scenario_arg)
    values = {**scenario.nav_overrides(), "NAV_DEST_LAT": dest[0], "NAV_DEST_LON": dest[1], **options.extra_params}
    nav = NavConfig.from_values(validate_all(values))
    run = fly_in_process(nav, scenario, options.seed, build_truth_field(scenario, options.data_dir))
    result.mc_remaining_m = run.remaining_m
    result.mc_iterations = run.iterations


def plot_track(path: Path, scenario: Scenario, dest: tuple[float, float], truth: dict, steps: list[dict],
               remaining_m: float = math.nan) -> Path:
    """PNG of the flown track (lon/lat): truth, the flight controller's INS, the companion's
    estimates, start, destination and the start-destination geodesic."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from geographiclib.geodesic import Geodesic

    line = Geodesic.WGS84.InverseLine(scenario.start_lat_deg, scenario.start_lon_deg, *dest)
    n = 100
    geo = [line.Position(line.s13 * k / n) for k in range(n + 1)]
    fig, ax = plt.subplots(figsize=(7.5, 6.0), dpi=110)
    ax.plot([g["lon2"] for g in geo], [g["lat2"] for g in geo], "k--", lw=0.8, label="geodesic")
    if truth.get("fc_lon_deg"):
        ax.plot(truth["fc_lon_deg"], truth["fc_lat_deg"], color="0.6", lw=0.8, label="FC INS (drifting)")
    ax.plot(truth["lon_deg"], truth["lat_deg"], color="tab:blue", lw=1.6, label="true track")
    est = [(row["est_lon_deg"], row["est_lat_deg"]) for row in steps
           if math.isfinite(row["est_lon_deg"]) and math.isfinite(row["est_lat_deg"])]
    if est:
        ax.plot([e[0] for e in est], [e[1] for e in est], ".", color="tab:orange", ms=3, label="companion estimate")
    ax.plot(scenario.start_lon_deg, scenario.start_lat_deg, "g^", ms=9, label="start")
    ax.plot(dest[1], dest[0], "r*", ms=12, label="destination")
    stopped = geodesic_distance_m(truth["lat_deg"][-1], truth["lon_deg"][-1], *dest)
    at_end = f"{remaining_m:.0f} m from the destination at the last step, " if math.isfinite(remaining_m) else ""
    ax.set_title(f"{scenario.name}, closed loop: {at_end}stopped at {stopped:.0f} m", fontsize=10)
    ax.set_xlabel("longitude (deg)")
    ax.set_ylabel("latitude (deg)")
    ax.set_aspect(1.0 / math.cos(math.radians(0.5 * (scenario.start_lat_deg + dest[0]))))
    ax.grid(True, lw=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fcmpc-fly", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--scenario", default="pacific", help="bundled scenario (pacific, long_storm, short_storm) or TOML")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulator's noise and INS errors")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--lockstep", action="store_true",
                      help="the default: the simulator waits for the companion every 1 s (ArduPilot) or 0.4 s (PX4) "
                           "of simulated time")
    pace.add_argument("--speedup", type=float, default=None,
                      help="pace the simulator at this many times real time instead of lockstep")
    p.add_argument("--short", action="store_true", help=f"move the destination to {SHORT_KM:g} km from the start")
    p.add_argument("--short-km", type=float, default=SHORT_KM, help="distance of the --short destination")
    p.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot",
                   help="conventions of our stand-in (--fc sim)")
    p.add_argument("--fc", choices=("sim", "ardupilot"), default="sim",
                   help="flight controller: our stand-in (fcmpc-sitl), or real ArduPilot Rover SITL "
                        "($FCMPC_ARDUPILOT or ../shared/ardupilot/ardurover; GPS denied from take-off)")
    p.add_argument("--fc-instance", type=int, default=0, help="ArduPilot SITL instance (-I): TCP 5760+10*I")
    p.add_argument("--fault", action="append", default=[], help="simulator fault KIND:AT_S[:DURATION_S[:VALUE]]")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="extra companion parameter")
    p.add_argument("--compare", action="store_true", help="also fly the same seed in-process and print it")
    p.add_argument("--out-dir", default=None, help="records folder (default out/fly/<scenario>-s<seed>-<time>)")
    p.add_argument("--timeout", type=float, default=900.0, help="wall seconds before giving up")
    p.add_argument("--no-plot", action="store_true")
    p.add_argument("--no-tlog", action="store_true", help="companion without .tlog (faster, smaller)")
    p.add_argument("--data-dir", default=None, help="storm data folder (default ../shared/data)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    extra = {}
    for item in args.param:
        name, sep, value = item.partition("=")
        if not sep:
            print(f"fcmpc-fly: --param {item!r}: expected NAME=VALUE", file=sys.stderr)
            return 2
        extra[name.strip().upper()] = float(value)
    options = FlyOptions(scenario=args.scenario, seed=args.seed, lockstep=args.speedup is None,
                         speedup=args.speedup, short=args.short, short_km=args.short_km, autopilot=args.autopilot,
                         out_dir=args.out_dir, timeout_s=args.timeout, faults=tuple(args.fault), extra_params=extra,
                         compare=args.compare, plot=not args.no_plot, tlog=not args.no_tlog, data_dir=args.data_dir,
                         fc=args.fc, fc_instance=args.fc_instance)
    from sitl.firmware import FirmwareMissing

    try:
        result = fly_on_ardupilot(options) if options.fc == "ardupilot" else fly(options)
    except (ValueError, OSError, FirmwareMissing) as err:
        print(f"fcmpc-fly: {err}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(asdict(result), indent=1, default=str))
    else:
        print(f"fcmpc-fly: {result.line()}")
        print(f"  estimated remaining {result.est_remaining_m:.0f} m; stopped {result.final_remaining_m:.0f} m "
              f"from the destination")
        if result.plot_path:
            print(f"  track plot: {result.plot_path}")
        print(f"  records:    {result.out_dir}")
        if result.message:
            print(f"  note: {result.message}")
    return 0 if result.status == "arrived" else (3 if result.status == "timeout" else 1)


if __name__ == "__main__":
    sys.exit(main())
