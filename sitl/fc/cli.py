"""The ``fcmpc-sitl`` command line: arguments -> :class:`~sitl.fc.config.ServerConfig` -> a run.

Exit 0 after a run (the summary is on stderr and in ``summary.json``), 2 when the scenario,
a setting or an endpoint is refused (the message names it). SIGINT/SIGTERM end the run
cleanly, with records and summary. ``python -m sitl.fc`` runs the same ``main``.
"""
from __future__ import annotations

import argparse
import signal
import sys

from companion.cli import ArgumentParser   # the one-line user-error policy of every console script
from sitl.fc.config import DEFAULT_OUT, DEFAULT_SPEEDUP, ServerConfig
from sitl.fc.ground_station import FEED_READINGS, feed_readings
from sitl.fc.lockstep import HANG_S
from sitl.fc.server import SitlServer
from sitl.guidance import DIALECTS
from sitl.scenario import FAULT_KINDS, ScenarioError

__all__ = ["build_parser", "config_from_args", "main"]


def _feed_readings(text: str) -> tuple[str, ...]:
    try:
        return feed_readings(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="fcmpc-sitl",
        description="MAVLink 2 simulator of an ArduPilot Rover (or PX4) boat flying a geomagnetic-navigation "
                    "scenario faster than real time. Every message carries simulated time.",
    )
    p.add_argument("--scenario", default="pacific",
                   help="bundled scenario name or TOML path (default pacific, the realistic Pacific; paper_* are "
                        "the paper's idealised worlds)")
    p.add_argument("--out", action="append", default=[], metavar="udp:HOST:PORT",
                   help=f"send to HOST:PORT (like ArduPilot SITL/MAVProxy --out); default {DEFAULT_OUT} "
                        "when neither --out nor --master is given. Repeatable")
    p.add_argument("--master", action="append", default=[], metavar="tcp:HOST:PORT",
                   help="listen: tcp:HOST:PORT (TCP server like ArduPilot SITL on 5760) or udpin:HOST:PORT. "
                        "Repeatable")
    p.add_argument("--speedup", type=float, default=None,
                   help="simulated seconds per wall second; 0 = as fast as possible, consecutive instants then "
                        "sharing UDP datagrams of up to 1400 bytes (fewer system calls) "
                        f"(default {DEFAULT_SPEEDUP:g}, or unlimited with --lockstep)")
    p.add_argument("--lockstep", action="store_true", help="advance time only when the companion answers")
    p.add_argument("--lockstep-period", type=float, default=0.2, help="simulated seconds between lockstep boundaries (default 0.2)")
    p.add_argument("--lockstep-timeout", type=float, default=2.0, help="wall seconds to wait for an answer at a boundary (default 2)")
    p.add_argument("--lockstep-start-timeout", type=float, default=60.0,
                   help="wall seconds to wait for the first peer at t=0, 0 = for ever (default 60)")
    p.add_argument("--lockstep-slack", type=int, choices=(0, 1), default=1,
                   help="periods the companion may lag behind a boundary: 1 (default) lets both run in parallel, "
                        "0 makes them alternate")
    p.add_argument("--lockstep-peer", default=None, metavar="SYS:COMP",
                   help="only this sender answers lockstep (default any sender but the simulator)")
    p.add_argument("--lockstep-peer-pid", type=int, default=None, metavar="PID",
                   help="the companion's process id on this machine: wait for its answers as long as it runs "
                        "(no --lockstep-timeout), go on at once when it has ended; a test's world then "
                        "cannot run away from a companion slowed by a busy machine")
    p.add_argument("--lockstep-successor", action="store_true",
                   help="with --lockstep-peer-pid: once that process has ended, wait (up to --lockstep-hang-s) for "
                        "a restarted companion to bind the port it answered from, then wait on that one")
    p.add_argument("--lockstep-hang-s", type=float, default=HANG_S,
                   help="with --lockstep-peer-pid: wall seconds a live companion may leave a boundary unanswered; "
                        "then the run stops with exit code 4, a hang (default %(default)g)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many simulated seconds")
    p.add_argument("--max-sim-s", type=float, default=30 * 3600.0, help="hard limit of simulated time (default 30 h)")
    p.add_argument("--seed", type=int, default=0, help="seed of every noise, INS error and fault draw (default 0)")
    p.add_argument("--autopilot", choices=sorted(DIALECTS), default="ardupilot",
                   help="mode numbering and guided rules: ArduPilot Rover GUIDED (default) or PX4 OFFBOARD")
    p.add_argument("--sysid", type=int, default=1, help="MAVLink system id (default 1)")
    p.add_argument("--setpoint-timeout", type=float, default=None,
                   help="simulated seconds without velocity setpoints before stopping (default 3 ArduPilot, 1 PX4)")
    p.add_argument("--cruise-speed", type=float, default=None, help="m/s for RTL and position targets "
                                                                    "(default NAV_SPEED_KMH)")
    p.add_argument("--init-s", type=float, default=1.0, help="simulated seconds in INITIALISING after boot (default 1)")
    p.add_argument("--cruise", default=None, metavar="COURSE_DEG:SPEED_MPS",
                   help="without a companion: arm in GUIDED/OFFBOARD when ready and hold this course and speed")
    p.add_argument("--fault", action="append", default=[], metavar="KIND:AT_S[:DURATION_S[:VALUE]]",
                   help=f"add a fault to the scenario's schedule; kinds: {', '.join(FAULT_KINDS)}")
    p.add_argument("--rate", action="append", default=[], metavar="MESSAGE:HZ",
                   help="default stream rate, e.g. RAW_IMU:20 or HIGHRES_IMU:10 (0 = off)")
    p.add_argument("--log-dir", default=None, help="records folder (default out/sitl/<scenario>-<time>-<pid>)")
    p.add_argument("--no-truth-log", action="store_true", help="do not write truth.csv")
    p.add_argument("--log-rate", type=float, default=1.0, help="truth.csv rows per simulated second (default 1)")
    p.add_argument("--tlog", nargs="?", const="", default=None, metavar="PATH",
                   help="write a MAVLink .tlog of everything sent and received (default <log-dir>/sitl.tlog)")
    p.add_argument("--summary-json", default=None, help="write the run summary here (default <log-dir>/summary.json)")
    p.add_argument("--data-dir", default=None, help="real data folder for storms (default $FCMPC_DATA_DIR or "
                                                     "../shared/data)")
    p.add_argument("--space-weather-feed", nargs="?", const=",".join(FEED_READINGS), default="", type=_feed_readings,
                   metavar="NAMES",
                   help="a ground station behind this FC sets the companion's readings to the world's every minute: "
                        "NAV_KP (Kp) and NAV_SYMH (SYM-H), or those named (comma-separated)")
    p.add_argument("--expected-duration", type=float, default=None,
                   help="mission seconds the 'compress' storm rule spreads the window over")
    p.add_argument("--field-step", type=float, default=1.0, help="simulated seconds between field evaluations (default 1)")
    p.add_argument("--ins-step", type=float, default=5.0, help="simulated seconds between INS propagations (default 5)")
    p.add_argument("--wave-roll", type=float, default=3.0, help="roll amplitude of the wave motion, deg (default 3)")
    p.add_argument("--wave-pitch", type=float, default=2.0, help="pitch amplitude of the wave motion, deg (default 2)")
    p.add_argument("--no-routing", action="store_true", help="do not forward messages between links")
    p.add_argument("--no-batch", action="store_true", help="one UDP datagram per message")
    p.add_argument("--quiet", action="store_true", help="no banner or summary on stderr")
    return p


def config_from_args(args: argparse.Namespace) -> ServerConfig:
    cruise = None
    if args.cruise:
        course, _, speed = args.cruise.partition(":")
        cruise = (float(course), float(speed or 0.0))
    peer = None
    if args.lockstep_peer:
        a, _, b = args.lockstep_peer.partition(":")
        peer = (int(a), int(b))
    return ServerConfig(
        scenario=args.scenario, outs=tuple(args.out), masters=tuple(args.master), speedup=args.speedup,
        lockstep=args.lockstep, lockstep_period_s=args.lockstep_period, lockstep_timeout_s=args.lockstep_timeout,
        lockstep_start_timeout_s=args.lockstep_start_timeout, lockstep_peer=peer,
        lockstep_peer_pid=args.lockstep_peer_pid, lockstep_successor=args.lockstep_successor,
        lockstep_hang_s=args.lockstep_hang_s, lockstep_slack=args.lockstep_slack, duration_s=args.duration,
        max_sim_s=args.max_sim_s, seed=args.seed, autopilot=args.autopilot, sysid=args.sysid,
        setpoint_timeout_s=args.setpoint_timeout, cruise_speed_mps=args.cruise_speed, init_s=args.init_s,
        cruise=cruise,
        log_dir=args.log_dir, truth_log=not args.no_truth_log, log_rate_hz=args.log_rate, tlog=args.tlog,
        faults=tuple(args.fault), rates=tuple(args.rate), field_step_s=args.field_step, ins_step_s=args.ins_step,
        wave_roll_deg=args.wave_roll, wave_pitch_deg=args.wave_pitch, data_dir=args.data_dir,
        space_weather_feed=args.space_weather_feed,
        expected_duration_s=args.expected_duration, routing=not args.no_routing, batch=not args.no_batch,
        summary_json=args.summary_json, quiet=args.quiet)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        server = SitlServer(config_from_args(args))
    except (ScenarioError, ValueError, OSError, RuntimeError) as err:
        print(f"fcmpc-sitl: {err}", file=sys.stderr)
        return 2

    def stop(signum, frame):  # noqa: ARG001
        server.request_stop()

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    summary = server.run()
    return 4 if summary.get("lockstep_hangs") else 0    # a companion that lived but never answered

