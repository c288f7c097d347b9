"""fcmpc-companion: the process on the companion board that flies the Fc-MPC mission over MAVLink.

::

    fcmpc-companion --connect udp:127.0.0.1:14550                 # listen, like a GCS on 14550
    fcmpc-companion --connect tcp:127.0.0.1:5760 --params my.parm  # ArduPilot SITL's TCP port
    fcmpc-companion --connect /dev/ttyAMA0,921600 --log-dir /var/log/fcmpc

This module is the entry point only (the command line, ``main``); the process itself is
:class:`companion.process.companion.CompanionApp`, which wires the MAVLink link
(:mod:`companion.io.link`), the parameter server (:mod:`companion.io.param_server`), the
sensor decoder (:mod:`companion.io.sensors.mavlink_source`), the magnetometer pipeline
(:mod:`companion.nav.magnetometer`) and the pure navigation core
(:class:`companion.nav.mission.Mission`) to its parts in :mod:`companion.process` (phase state
machine, failsafe response, outputs, mission preparation, records). Clocks: the navigation sees
only message time (the flight controller's ``time_boot_ms``); wall time only at the edges.

Sequence
    ``wait_fc``: no flight-controller HEARTBEAT yet. ``startup``: streams requested; the vehicle is
    stationary while D and I are averaged over a start-up window (default one control period),
    which becomes the first measurement. ``ready``: with COMP_ARM_ENABLE = 1 the companion switches
    to GUIDED (ArduPilot) or, after >= 1 s of zero-velocity setpoints, OFFBOARD (PX4) and arms;
    with 0 it waits for the operator to do so. ``running``: once the flight controller is armed in
    GUIDED/OFFBOARD the mission starts (start = GPS fix if the receiver has a 3D fix, else
    NAV_START_LAT/LON); every NAV_PERIOD_S of *mission time* the averaged (D, I) and the flight
    controller's INS position (GLOBAL_POSITION_INT; dead reckoning on the commanded velocity when
    it is missing) go into the core, whose course and speed are streamed as setpoints.
    ``done``: arrived or failed: setpoints stop, hold mode is commanded.

Mission time and pauses
    Mission time is message time minus the time spent paused. The mission pauses whenever the
    vehicle is not following (failsafe, or the flight controller not armed in GUIDED/OFFBOARD):
    the core's dead reckoning assumes the last command was flown for the whole period, so the
    clock must not run while the vehicle holds. Samples taken while paused are not averaged.

Failsafes (:mod:`companion.failsafe`)
    Stale magnetometer or attitude, flight-controller heartbeat lost, broken parameter file:
    stop streaming velocity, command HOLD (ArduPilot) / AUTO.LOITER (PX4) if the vehicle was
    under guidance, STATUSTEXT the reason; after all conditions were healthy for 1 s of message
    time, re-engage (if COMP_ARM_ENABLE) and resume. A mode change the companion did not command
    (pilot, ground station, the autopilot's own failsafe) is respected: the mission pauses with a
    STATUSTEXT until GUIDED/OFFBOARD is selected again. Navigation failures (QP failure, estimate
    diverging from the geomagnetic fix by COMP_DIVERGE_KM, a non-finite command) hold the
    vehicle and restart the mission from the last estimate after a new stationary start-up
    (at most 3 restarts). No setpoint ever leaves without :func:`~companion.io.link.guard_setpoint`.

Records (``--log-dir``, default ``out/companion/<time>-<pid>``): ``companion.tlog`` (both
directions), ``steps.csv`` (:mod:`companion.io.records`), ``summary.json``.

Status page (``--http ADDRESS:PORT``, off by default): a read-only web page on the board with
the phase, the estimate, its ellipse and the track, health and the records to download
(:mod:`companion.io.status_page`, docs/status-page.md).

Sensor sources (``--sensors SPEC``): a magnetometer, attitude or GPS beside the link replaces
the flight controller's kind; see :mod:`companion.process.intake`.
"""
from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")
# One BLAS thread, set before numpy loads it: the navigation's matrices are 2 x 2 to 30 x 30,
# where a second OpenBLAS thread only adds its hand-off (the 30 x 30 matrix exponential
# 0.2 -> 2.5 ms, the control step about twice as long on a 2-core board). The simulator, the
# benchmarks and the Monte Carlo set the same.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import signal
import sys
from pathlib import Path

from companion.cli import ArgumentParser, UsageError, one_line, run_main
from companion.io.param_server import ENCODINGS
from companion.io.sensors.base import SensorError
from companion.io.sensors.mavlink_source import MAG_MESSAGES
from companion.io.status_page.address import parse_http_address
from companion.process.companion import CompanionApp, apply_live_config
from companion.process.intake import SourceTimeMap, source_kinds
from companion.process.machine import State
from companion.process.options import AppOptions

__all__ = [
    "AppOptions",
    "CompanionApp",
    "SourceTimeMap",
    "State",
    "apply_live_config",
    "build_parser",
    "main",
    "options_from_args",
    "source_kinds",
]

# ---------------------------------------------------------------------- CLI
def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="fcmpc-companion",
        description="Fc-MPC geomagnetic navigation companion: flies a GPS-free mission over MAVLink "
                    "(ArduPilot GUIDED or PX4 OFFBOARD) as component 191.")
    p.add_argument("--connect", "--master", dest="connect", default="udp:127.0.0.1:14550",
                   help="pymavlink connection: udp:HOST:PORT (listen), udpout:HOST:PORT, tcp:HOST:PORT, "
                        "tcpin:HOST:PORT, or a serial device DEVICE,BAUD; default udp:127.0.0.1:14550")
    p.add_argument("--params", default=None, metavar="FILE",
                   help=".parm file loaded at start and rewritten atomically on every PARAM_SET; it must exist "
                        "unless --params-create is given; default <log-dir>/companion.parm (created)")
    p.add_argument("--params-create", action="store_true",
                   help="start from the defaults when the --params FILE does not exist yet (it is written on "
                        "the first PARAM_SET)")
    p.add_argument("--log-dir", default=None, help="records folder; default out/companion/<time>-<pid>")
    p.add_argument("--sysid", "--fc-sysid", dest="sysid", type=int, default=None,
                   help="only follow the flight controller with this system id; default the first one heard, "
                        "then fixed for the run")
    p.add_argument("--fc-compid", type=int, default=None,
                   help="only follow the flight controller with this component id; default the first autopilot's")
    p.add_argument("--signing-key", default=None, metavar="FILE",
                   help="MAVLink 2 signing key file (make one with fcmpc-signing-key; permission 0600): sign every "
                        "output, refuse unsigned PARAM_SET, COMMAND_* and SET_*")
    p.add_argument("--signing-link-id", type=int, default=0, metavar="N",
                   help="link id in this link's signatures, 0..255; default 0")
    p.add_argument("--lockstep", action="store_true",
                   help="send a timed message every setpoint period even when not steering "
                        "(a lockstep simulator waits for it)")
    p.add_argument("--exit-when-done", action="store_true",
                   help="exit when the mission ends (after --linger-s): 0 arrived, 1 failed")
    p.add_argument("--linger-s", type=float, default=0.0, metavar="S",
                   help="with --exit-when-done: keep running this many seconds of message time after the "
                        "mission ended, e.g. until the vehicle has come to rest; default 0")
    p.add_argument("--param-encoding", choices=ENCODINGS, default="auto",
                   help="INT32 parameter values: C cast (ArduPilot), bytewise (PX4), or from the FC; default auto")
    p.add_argument("--mag-message", choices=MAG_MESSAGES, default=None,
                   help="magnetometer message to use; default the FC's raw one (ArduPilot RAW_IMU, PX4 SCALED_IMU: "
                        "PX4's HIGHRES_IMU has EKF2's bias estimate subtracted), or the first one it sends "
                        "with --no-stream-requests")
    p.add_argument("--sensors", default=None, metavar="SPEC",
                   help="read sensors from this source instead of the FC's streams (kinds it lacks still come "
                        "from the FC): i2c:/dev/i2c-1, ubx:/dev/ttyACM0:115200, dronecan:can0, "
                        "dronecan:virtual:vbus0, replay:log.bin?speed=1, or several joined with +; "
                        "default MAVLink only")
    p.add_argument("--state", default=None, metavar="FILE",
                   help="the navigator's state, saved atomically every step and read at start: a restart within "
                        "300 s of message time resumes the mission, an older state starts a new one from its last "
                        "estimate; default beside --params (<params>.navstate), else in --log-dir")
    p.add_argument("--startup-s", type=float, default=None,
                   help="stationary averaging before the first step, s of message time; default NAV_PERIOD_S")
    p.add_argument("--no-tlog", action="store_true", help="do not record companion.tlog")
    p.add_argument("--no-stream-requests", action="store_true",
                   help="do not send MAV_CMD_SET_MESSAGE_INTERVAL (use the FC's configured rates)")
    p.add_argument("--http", default=None, metavar="ADDRESS:PORT", type=_http_address,
                   help="serve the read-only status page (state, estimate plot, health, records to download) "
                        "on ADDRESS:PORT; a PORT alone listens on loopback (127.0.0.1); default off "
                        "(docs/status-page.md)")
    p.add_argument("--max-wall-s", type=float, default=None, help="exit (code 3) after this many wall seconds")
    p.add_argument("--quiet", action="store_true", help="no status lines on stderr")
    return p


def _http_address(text: str) -> str:
    """argparse ``type`` of --http: the text, checked (its one-line error names the option)."""
    try:
        parse_http_address(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    return text


def options_from_args(args: argparse.Namespace) -> AppOptions:
    return AppOptions(connect=args.connect, params=args.params, log_dir=args.log_dir, sysid=args.sysid,
                      lockstep=args.lockstep, exit_when_done=args.exit_when_done, param_encoding=args.param_encoding,
                      mag_message=args.mag_message, startup_s=args.startup_s, tlog=not args.no_tlog,
                      request_streams=not args.no_stream_requests, max_wall_s=args.max_wall_s, quiet=args.quiet,
                      sensors=args.sensors, linger_s=args.linger_s, state=args.state,
                      fc_compid=args.fc_compid, signing_key=args.signing_key, signing_link_id=args.signing_link_id,
                      http=args.http)


def _run(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if args.params is not None and not args.params_create and not Path(args.params).is_file():
        # a typo in a path must not fly the default mission
        raise UsageError(f"--params {args.params}: no such file (give --params-create to start from the "
                         f"defaults and create it)")
    try:
        app = CompanionApp(options_from_args(args))
    except SensorError as err:
        raise UsageError(f"--sensors {args.sensors}: {one_line(err)}") from None
    except (OSError, ValueError) as err:
        raise UsageError(one_line(err)) from None
    if app.params.load_error:
        print(f"fcmpc-companion: parameter file rejected, serving defaults and refusing to steer: "
              f"{app.params.load_error}", file=sys.stderr)
    stopped_by: list[int] = []

    def stop(signum, frame):
        stopped_by.append(signum)
        app.request_stop()

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    try:
        code = app.run()
    except SensorError as err:
        raise UsageError(f"sensor source {args.sensors!r} failed: {one_line(err)}") from None
    except OSError as err:
        raise UsageError(one_line(err)) from None
    if stopped_by and app.exit_code is None:
        return 128 + stopped_by[0]        # stopped before the mission ended: not "arrived"
    return code


def main(argv: list[str] | None = None) -> int:
    return run_main("fcmpc-companion", lambda: _run(argv))


if __name__ == "__main__":
    sys.exit(main())
