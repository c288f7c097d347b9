"""fcmpc-fly: the simulator and the companion as two processes on loopback, one mission, one result.

    fcmpc-fly                                  # the Pacific mission in the realistic world, closed-loop, lockstep
    fcmpc-fly --short                          # the first 80 km of it (a minute of wall time less)
    fcmpc-fly --scenario paper_pacific         # the paper's idealised Pacific (it says what it gives)
    fcmpc-fly --scenario long_storm --seed 3 --compare   # storm-time parameters fitted on the other storms
    fcmpc-fly --autopilot px4 --speedup 500    # PX4 OFFBOARD, paced instead of lockstep
    fcmpc-fly --fc ardupilot --short           # against real ArduPilot Rover SITL (README: Flying with ArduPilot)
    fcmpc-fly --fc px4 --short --short-km 30   # against real PX4 SITL with SIH (README: Flying with PX4)

The run itself is :func:`fcmpc.fly.runner.fly` (the one runner, :mod:`fcmpc.fly.mission`, against any flight controller); this file is the command line (BLAS threads and MAVLink 2 are set in :mod:`fcmpc.fly`,
before numpy and pymavlink load). While it flies
it prints a progress line on stderr about every 10 s of wall time (step, simulated time,
distance to go as the companion estimates it). At the end it prints where the vehicle came to
rest (the headline), the true distance at the last control step, what the companion believed,
and the path of the track plot. A world that hands the navigator what a vehicle would not have
(the paper's idealised ``paper_*`` presets) says so on stderr before it flies and after the result
(:func:`sitl.gifts.gift_line`).

Exit status: 0 arrived, 1 the mission failed or a process died, 2 bad arguments (one line,
nothing written), 3 timeout, 130 interrupted by Ctrl-C (the records, ``result.json``, the plot
and the summary are still written). Everything lands in
``out/fly/<scenario>-s<seed>-<time>/`` (``--out-dir``): ``fly.parm``, ``companion/`` (tlog,
steps.csv, summary.json), ``sitl/`` (truth.csv, summary.json), ``track.png``, ``result.json``.
"""
from __future__ import annotations

import math
import sys

from companion.cli import ArgumentParser, UsageError, param_items, run_main
from fcmpc.fly.results import FlyResult, result_json, summary_lines
from fcmpc.fly.runner import SHORT_KM, FlyOptions, fly, prepare, short_destination, write_short_scenario
from sitl.gifts import gift_line
from sitl.scenario import ScenarioError

__all__ = ["FlyOptions", "FlyResult", "fly", "short_destination", "write_short_scenario", "build_parser",
           "main"]


def build_parser() -> ArgumentParser:
    p = ArgumentParser(prog="fcmpc-fly", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="pacific",
                   help="bundled scenario (pacific, long_storm, short_storm: realistic; paper_pacific, "
                        "paper_long_storm, paper_short_storm: the paper's idealised worlds) or a TOML file; "
                        "default pacific")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulator's noise and INS errors; default 0")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--lockstep", action="store_true",
                      help="pacing when --speedup is not given: the simulator waits for the companion every 1 s "
                           "(ArduPilot) or 0.4 s (PX4) of simulated time")
    pace.add_argument("--speedup", type=float, default=None, metavar="N",
                      help="pace the simulator at N times real time instead of lockstep")
    p.add_argument("--short", action="store_true", help="move the destination along the route to --short-km "
                                                        "from the start")
    p.add_argument("--short-km", type=float, default=SHORT_KM, metavar="KM",
                   help=f"distance of the --short destination; default {SHORT_KM:g}")
    p.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot",
                   help="flight-controller conventions our simulator speaks (--fc sim); default ardupilot")
    p.add_argument("--fc", choices=("sim", "ardupilot", "px4"), default="sim",
                   help="flight controller: our stand-in (fcmpc-sitl), real ArduPilot Rover SITL "
                        "($FCMPC_ARDUPILOT or ../shared/ardupilot/ardurover), or real PX4 SITL with SIH "
                        "($FCMPC_PX4 or ../shared/px4); GPS denied from take-off on both; default sim")
    p.add_argument("--fc-instance", type=int, default=0, metavar="I",
                   help="ArduPilot SITL instance (-I): its TCP ports are 5760 + 10 I; PX4 instance (0-9): the "
                        "companion listens on UDP 14540 + I; default 0")
    p.add_argument("--compass", choices=("real", "real-nomot", "ideal"), default="real",
                   help="with --fc ardupilot: the firmware's compass with a real installation's hard and soft iron, "
                        "noise and motor interference, calibrated as a boat's user does (real, the default; "
                        "real-nomot: with --physics json, its motor left uncompensated, COMPASS_MOTCT 0), or "
                        "SITL's perfect one (ideal); see fcmpc/firmware/compass.py")
    p.add_argument("--physics", choices=("builtin", "sih", "json", "hil"), default="builtin",
                   help="the firmware's physics: its own (builtin: ArduPilot's motorboat paced by the wall clock, "
                        "PX4's SIH paced by --speedup; 'sih' says the same), or our world in lockstep with the "
                        "firmware and the companion: json (--fc ardupilot, its JSON backend) or hil (--fc px4, its "
                        "MAVLink simulator interface); docs/integrator.md; default builtin")
    p.add_argument("--fault", action="append", default=[], metavar="KIND:AT_S[:DURATION_S[:VALUE]]",
                   help="simulator fault (repeatable)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="companion parameter (repeatable), checked against the registry before anything starts")
    p.add_argument("--storm-params", default="loo", metavar="loo|registry|NAMES",
                   help="a storm world's storm-time parameters (fcmpc-fit-storms): loo (default) fitted on every "
                        "other storm of the library, NAMES a comma list of storms to fit on, registry the "
                        "registry's (fitted on may2024); refused when fitted on the world's own storm")
    p.add_argument("--compare", action="store_true", help="also fly the same seed in-process and print it")
    p.add_argument("--out-dir", default=None, help="records folder; default out/fly/<scenario>-s<seed>-<time>")
    p.add_argument("--timeout", type=float, default=3600.0, metavar="S",
                   help="wall seconds before giving up (a hang guard: the full mission takes about a minute "
                        "on an idle machine, much longer on a loaded one); default 3600")
    p.add_argument("--no-plot", action="store_true", help="no track.png")
    p.add_argument("--no-tlog", action="store_true", help="companion without .tlog (faster, smaller)")
    p.add_argument("--no-progress", action="store_true", help="no progress lines while flying")
    p.add_argument("--data-dir", default=None, help="storm data folder; default ../shared/data")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    return p


def _run(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if args.timeout <= 0:
        raise UsageError(f"--timeout {args.timeout:g}: must be > 0")
    if args.speedup is not None and not (math.isfinite(args.speedup) and args.speedup > 0):
        raise UsageError(f"--speedup {args.speedup:g}: must be > 0")
    options = FlyOptions(scenario=args.scenario, seed=args.seed, lockstep=args.speedup is None,
                         speedup=args.speedup, short=args.short, short_km=args.short_km, autopilot=args.autopilot,
                         out_dir=args.out_dir, timeout_s=args.timeout, faults=tuple(args.fault),
                         extra_params=param_items(args.param), compare=args.compare, plot=not args.no_plot,
                         tlog=not args.no_tlog, data_dir=args.data_dir,
                         progress_s=None if args.no_progress or args.json else 10.0, fc=args.fc,
                         fc_instance=args.fc_instance, compass=args.compass,
                         physics="builtin" if args.physics == "sih" else args.physics)
    try:
        scenario, _, _ = prepare(options)          # nothing is written before this passes
        options = _with_storm_params(options, scenario, args.storm_params)
    except ValueError as err:     # ScenarioError, ParamError and the option checks
        raise UsageError(str(err)) from None
    gifted = gift_line(scenario) if options.fc == "sim" else ""   # real firmware flies in its own world
    if gifted:
        print(f"fcmpc-fly: {gifted}", file=sys.stderr, flush=True)
    from fcmpc.firmware import FirmwareMissing

    if options.fc == "px4" and not 0 <= options.fc_instance <= 9:
        raise UsageError(f"--fc-instance {options.fc_instance}: PX4 instances are 0..9")
    try:
        result = fly(options)
    except FirmwareMissing as err:
        raise UsageError(str(err)) from None
    if args.json:
        print(result_json(result), end="")
    else:
        lines = summary_lines(result)
        print(f"fcmpc-fly: {lines[0]}")
        print("\n".join(lines[1:]))
        if gifted:
            print(f"fcmpc-fly: {gifted}")
    return result.exit_code


def _with_storm_params(options: FlyOptions, scenario, spec: str) -> FlyOptions:
    """The options with a storm world's storm-time parameters fitted without its storm (``spec``: loo,
    a comma list of storms, or registry), said on stderr; a ``--param`` the user gave wins. A world
    without a storm, or ``registry``, flies as given."""
    from dataclasses import replace

    from fcmpc.montecarlo.fit_storms import storm_params_for

    if not scenario.storm.enabled or spec.strip().lower() == "registry":
        return options
    fitted, names = storm_params_for(scenario, spec, options.data_dir)
    print(f"fcmpc-fly: storm-time parameters fitted on {','.join(names)}, not on {scenario.storm.event} "
          f"(--storm-params {spec})", file=sys.stderr, flush=True)
    return replace(options, extra_params={**fitted, **options.extra_params})


def main(argv: list[str] | None = None) -> int:
    return run_main("fcmpc-fly", lambda: _run(argv), (ScenarioError,))


if __name__ == "__main__":
    sys.exit(main())
