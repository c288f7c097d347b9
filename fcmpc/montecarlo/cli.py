"""Monte Carlo of the paper's tables and sweeps: the navigation core against the simulated world.

    fcmpc-montecarlo --runs 50                                  # the realistic Pacific: LTI-, LTV-, Fc-MPC
    fcmpc-montecarlo --scenario paper_pacific --runs 50         # Table 5, in the paper's idealised world
    fcmpc-montecarlo --scenario paper_long_storm --runs 50      # Table 6: LTV- vs Fc-MPC (idealised)
    fcmpc-montecarlo --scenario halloween2003_real --controllers fc   # a real storm, storm-time parameters
                                                                # fitted on the other storms (--storm-params loo)
    fcmpc-montecarlo --scenario pacific --errors -heading,+crustal   # switch error sources
    fcmpc-montecarlo --scenario pacific --budget --runs 10           # the error budget
    fcmpc-montecarlo --sweep NAV_PERIOD_S=180,360,720 --sweep MPC_N=2,4,8 --runs 20 --controllers fc
    fcmpc-montecarlo --engine dask [--cluster tcp://HOST:8786] ...        # on a Dask cluster
    fcmpc-montecarlo --fc ardupilot --runs 16                   # each run a whole mission against ArduPilot SITL
    fcmpc-montecarlo --fc px4 --physics hil --runs 4 --short-km 30   # PX4 in lockstep with our world, a 30 km leg

The library is :mod:`fcmpc.montecarlo`; this is its command line. Each run draws its own INS errors
and sensor noise from its seed; every controller meets the same draws for the same seed.
A world that hands the navigator what a vehicle would not have (the ``paper_*`` presets: true
heading, its own map as the truth, exact start ...) says so first (:func:`sitl.gifts.gift_line`).
Without ``--sweep`` it prints the paper's table beside ours and writes ``runs.csv``,
``summary.json`` and plots into ``out/montecarlo/<scenario>/``; with ``--sweep`` one Parquet row
per run into ``out/montecarlo/<scenario>/sweep/runs/`` (a second call skips the runs stored),
the per-cell table (``summary.csv``) and line/heat-map plots (``sweep/plots/``).

With ``--fc sim|ardupilot|px4`` each run is a whole mission of the one runner (what ``fcmpc-fly``
flies: the companion as a process against our stand-in or the firmware, :mod:`fcmpc.montecarlo.flown`),
each with its own seed, instance number and temporary folder; the same table, in
``out/montecarlo/<scenario>-<fc>/``. One worker by default against firmware.

A storm world is scored leave-one-storm-out: its storm-time parameters fitted on the library's other
storms (:mod:`fcmpc.montecarlo.fit_storms`), never on its own (refused), and ``summary.json`` names the
training storms (``storm_params``).
"""
from __future__ import annotations

import os

# Tiny matrices: BLAS threads only fight the worker processes for the two cores.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import math
import sys
from dataclasses import replace
from pathlib import Path

from companion.cli import ArgumentParser, UsageError, param_items, positive_int, run_main
from companion.params import Controller, NavConfig, read_parm_file, validate_all
from fcmpc.montecarlo.budget import realistic_counterpart
from fcmpc.montecarlo.cli_table import budget_main, table_main
from fcmpc.montecarlo.engines import ENGINES, Engine
from sitl.gifts import gift_line
from sitl.scenario import ScenarioError, load_scenario
from sitl.world.build import StormUnavailableError

CONTROLLER_KEYS = {"lti": Controller.LTI, "ltv": Controller.LTV, "fc": Controller.FC}


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(prog="fcmpc-montecarlo", description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="pacific", help="bundled name or TOML path; default pacific")
    parser.add_argument("--runs", type=positive_int, default=50, help="runs per controller (and cell); default 50")
    parser.add_argument("--controllers", default=None,
                        help="comma list of lti,ltv,fc; default all three (ltv,fc for storm scenarios)")
    parser.add_argument("--workers", type=positive_int, default=None,
                        help="worker processes (or a local cluster's workers); default one per core (one with "
                             "--fc ardupilot|px4)")
    parser.add_argument("--engine", choices=ENGINES, default="local",
                        help="local process pool (default), dask (pip install -e '.[cluster]') or ray")
    parser.add_argument("--cluster", default=None, metavar="ADDRESS",
                        help="a running scheduler (dask tcp://HOST:8786, ray ray://HOST:10001); "
                             "default: start a local cluster of --workers")
    parser.add_argument("--sweep", action="append", default=[], metavar="NAME=V1,V2,...",
                        help="sweep a registry parameter or scenario key (e.g. sensors.mag_noise_nt); "
                             "repeat for the cross product; results per run in Parquet, resumable")
    parser.add_argument("--first-seed", type=int, default=0, help="seed of the first run; default 0")
    parser.add_argument("--params", metavar="FILE", help="a .parm file overlaid on the defaults")
    parser.add_argument("--storm-params", default=None, metavar="loo|registry|NAMES",
                        help="a storm world's storm-time parameters (fcmpc.montecarlo.fit_storms): loo (default) fitted on "
                             "every other storm of the library, NAMES a comma list of storms to fit on, registry the "
                             "registry's (fitted on may2024); refused when fitted on the world's own storm")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="override one parameter (repeatable)")
    parser.add_argument("--data-dir", default=None, help="real data folder; default ../shared/data")
    parser.add_argument("--out", default="out/montecarlo", help="output folder; default out/montecarlo")
    parser.add_argument("--no-plots", action="store_true")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--errors", default=None, metavar="SPEC",
                        help="switch error sources of the realistic world on (+name) or off (-name), comma "
                             "separated: heading, main_field, crustal, calibration, noise, storm, motion, ins; 'none', 'all'")
    parser.add_argument("--process-model", choices=("ins", "dead_reckoning"), default=None,
                        help="the error-state filter's process model (FUS_MODEL 2 or 3); default auto (the INS here)")
    parser.add_argument("--no-ins", action="store_true",
                        help="the vehicle carries no navigation-grade INS (ArduPilot, PX4 on MEMS sensors): "
                             "the navigator gets no INS position, and auto flies the dead-reckoning filter")
    parser.add_argument("--heading-source", choices=("true", "ins", "magnetic"), default=None,
                        help="override the scenario's [attitude] heading_source")
    flown = parser.add_argument_group("whole missions against a flight controller (fcmpc-fly's runner)")
    flown.add_argument("--fc", choices=("sim", "ardupilot", "px4"), default=None,
                       help="fly each run as a mission: our stand-in (sim), ArduPilot Rover SITL or PX4 SITL; "
                            "default: in-process")
    flown.add_argument("--physics", choices=("builtin", "json", "hil"), default="builtin",
                       help="with --fc ardupilot|px4: the firmware's own physics, or our world in lockstep "
                            "(json: ArduPilot, hil: PX4); default builtin")
    flown.add_argument("--short-km", type=float, default=None, metavar="KM",
                       help="with --fc: fly only the first KM of the route")
    flown.add_argument("--compass", choices=("real", "ideal"), default="real",
                       help="with --fc ardupilot: the firmware's compass (fcmpc-fly --compass); default real")
    flown.add_argument("--fc-instance", type=int, default=None, metavar="I",
                       help="with --fc ardupilot: the first instance number of the runs; default 80 (PX4: 1-9)")
    flown.add_argument("--speedup", type=float, default=None, metavar="N",
                       help="with --fc: the firmware's pace (ArduPilot's built-in boat default 50, PX4 SIH 10; "
                            "a loaded machine wants less), or the stand-in paced at N instead of lockstep")
    flown.add_argument("--timeout", type=float, default=7200.0, metavar="S",
                       help="with --fc: wall seconds before a run is given up; default 7200")
    parser.add_argument("--budget", action="store_true",
                        help="error budget: Fc-MPC with each error source alone, none and all (--runs per row)")
    return parser


def check_missions(values: dict, controllers: list[int]) -> None:
    """Build each controller's mission once here, so a refused configuration (the destination's
    field outside the state bounds, ...) is one line before any worker starts, not a traceback."""
    from companion.nav.mission import Mission

    for controller in controllers:
        try:
            Mission(NavConfig.from_values({**values, "NAV_CONTROLLER": controller}))
        except ValueError as err:
            raise UsageError(f"mission refused: {err}") from None


def storm_parameters(args, scenario, from_file: dict) -> tuple[dict, dict | None]:
    """The storm-time parameters a storm world is scored with and where they come from (recorded in the
    summary): a ``--params`` file that sets any (its header names its training storms), else
    ``--storm-params`` (default ``loo``). Refuses (:class:`fcmpc.montecarlo.fit_storms.OwnStormError`)
    parameters fitted on the world's own storm; a world without a storm gets none."""
    from fcmpc.montecarlo.fit_storms import DEFAULTS_FITTED_ON, STORM_PARAMS, check_held_out, fitted_on, storm_params_for

    if not scenario.storm.enabled:
        if args.storm_params:
            raise UsageError(f"--storm-params: scenario {scenario.name!r} has no storm")
        return {}, None
    if args.params and any(name in from_file for name in STORM_PARAMS):
        if args.storm_params:
            raise UsageError(f"--storm-params and --params {args.params}, which sets storm-time parameters: choose one")
        names = fitted_on(args.params)
        check_held_out(scenario, names)
        return {}, {"source": f"--params {args.params}", "storms": list(names) if names is not None else None}
    spec = args.storm_params or "loo"
    if spec.strip().lower() == "registry":
        check_held_out(scenario, DEFAULTS_FITTED_ON)
        return {}, {"source": "registry defaults", "storms": list(DEFAULTS_FITTED_ON)}
    values, names = storm_params_for(scenario, spec, args.data_dir)
    print(f"storm parameters fitted on {','.join(names)} (--storm-params {spec}); "
          + " ".join(f"{k}={v:g}" for k, v in values.items()), flush=True)
    return values, {"source": f"--storm-params {spec}", "storms": list(names)}


def _run(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.workers is None:
        args.workers = 1 if args.fc in ("ardupilot", "px4") else os.cpu_count() or 1
    if args.fc is not None:
        _check_flown(args)
    scenario = load_scenario(args.scenario)
    real = realistic_counterpart(scenario)
    if args.heading_source:
        real = replace(real, attitude=replace(real.attitude, heading_source=args.heading_source))
        scenario = replace(scenario, attitude=replace(scenario.attitude, heading_source=args.heading_source))
    if args.errors:
        from sitl.budget import parse_errors, with_errors
        try:
            scenario = with_errors(scenario, parse_errors(args.errors), real)
        except ValueError as err:
            parser.error(str(err))
    if args.no_ins:   # the vehicle carries none: the world flown and the budget's base alike
        scenario = replace(scenario, ins=replace(scenario.ins, onboard=False))
        real = replace(real, ins=replace(real.ins, onboard=False))
    gifted = gift_line(real if args.budget else scenario)
    if gifted:
        print(gifted, flush=True)
    overrides = read_parm_file(args.params) if args.params else {}
    storm_values, fitted = storm_parameters(args, scenario, overrides)
    overrides = {**storm_values, **overrides, **param_items(args.param)}
    if args.process_model:
        overrides["FUS_MODEL"] = {"ins": 2, "dead_reckoning": 3}[args.process_model]
    values = validate_all({**scenario.nav_overrides(), **overrides})
    keys = args.controllers.split(",") if args.controllers else (
        ["fc"] if args.fc else ["ltv", "fc"] if scenario.storm.enabled else ["lti", "ltv", "fc"])
    try:
        controllers = [CONTROLLER_KEYS[k.strip().lower()] for k in keys]
    except KeyError as err:
        parser.error(f"--controllers: unknown controller {err}; choose from {', '.join(CONTROLLER_KEYS)}")
    if args.cluster and args.engine == "local":
        raise UsageError("--cluster needs --engine dask or ray")
    engine = Engine(args.engine, args.workers, args.cluster)
    # a bundled name travels to the workers as text (they load it once); anything else as the object
    bundled = not Path(args.scenario).suffix and scenario == load_scenario(args.scenario)
    scenario_ref = args.scenario if bundled else scenario
    if args.sweep:
        from fcmpc.montecarlo.cli_sweep import sweep_main

        return sweep_main(args, scenario_ref, scenario, controllers, overrides, engine, check_missions, fitted)
    check_missions(values, controllers)
    if args.fc is not None:
        from fcmpc.montecarlo.cli_table import flown_main

        return flown_main(args, scenario, values, overrides, controllers, engine, fitted)

    if args.budget:
        return budget_main(args, real, values, engine)
    return table_main(args, scenario_ref, values, controllers, engine, fitted)


def _check_flown(args) -> None:
    """``--fc`` flies the scenario as fcmpc-fly does: options that change the in-process world refused."""
    given = [name for name, on in (("--sweep", args.sweep), ("--budget", args.budget), ("--errors", args.errors),
                                   ("--no-ins", args.no_ins), ("--heading-source", args.heading_source),
                                   ("--process-model", args.process_model)) if on]
    if given:
        raise UsageError(f"--fc {args.fc} flies the scenario's world as fcmpc-fly does: {', '.join(given)} "
                         f"is for the in-process Monte Carlo")
    if args.short_km is not None and not args.short_km > 0:
        raise UsageError(f"--short-km {args.short_km:g}: must be > 0")
    if not args.timeout > 0:
        raise UsageError(f"--timeout {args.timeout:g}: must be > 0")
    if args.speedup is not None and not (math.isfinite(args.speedup) and args.speedup > 0):
        raise UsageError(f"--speedup {args.speedup:g}: must be > 0")
    allowed = {"sim": ("builtin",), "ardupilot": ("builtin", "json"), "px4": ("builtin", "hil")}[args.fc]
    if args.physics not in allowed:
        raise UsageError(f"--physics {args.physics} with --fc {args.fc}: choose {' or '.join(allowed)}")


def main(argv: list[str] | None = None) -> int:
    return run_main("fcmpc-montecarlo", lambda: _run(argv), (ScenarioError, StormUnavailableError))


if __name__ == "__main__":
    sys.exit(main())
