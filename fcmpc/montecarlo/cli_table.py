"""What ``fcmpc-montecarlo`` does without ``--sweep``: the paper's table, or the error budget.

:func:`table_main` flies every controller ``--runs`` times in-process, :func:`flown_main` as whole
missions against a flight controller (``--fc``); :func:`report` prints the paper's table beside
ours and writes ``runs.csv``, ``summary.json`` and the plots into ``<out>/<scenario>/``;
:func:`budget_main` flies Fc-MPC with each error source of the realistic world alone, none and
all, and writes ``budget.json``.
"""
from __future__ import annotations

import csv
import json
import time
from argparse import Namespace
from dataclasses import asdict
from pathlib import Path

from companion.nav.prediction import RoutePrediction, predict_route
from companion.params import Controller, NavConfig
from fcmpc.montecarlo.batch import run_montecarlo
from fcmpc.montecarlo.budget import format_budget, run_budget
from fcmpc.montecarlo.engines import Engine
from fcmpc.montecarlo.tables import PAPER, add_prediction, format_table, summarise
from sitl.scenario import Scenario

__all__ = ["budget_main", "table_main"]


def budget_main(args: Namespace, real: Scenario, values: dict, engine: Engine) -> int:
    """The error budget of ``real`` (``--budget``): printed, and written to ``budget.json``."""
    started = time.perf_counter()
    budget = run_budget(real, args.runs, args.workers, values, args.data_dir, not args.quiet, args.first_seed,
                        engine)
    out = Path(args.out) / real.name
    out.mkdir(parents=True, exist_ok=True)
    vehicle = {"heading_source": real.heading_source, "ins_onboard": real.ins.onboard}
    (out / "budget.json").write_text(json.dumps({"scenario": real.name, "runs": args.runs, **vehicle, "rows": budget,
                                                 "wall_s": time.perf_counter() - started}, indent=2))
    carried = "an INS" if real.ins.onboard else "no INS"
    print(f"\nError budget, {real.name} ({real.heading_source} heading, {carried}): Fc-MPC, {args.runs} runs per row "
          f"({time.perf_counter() - started:.0f} s wall)\n")
    print(format_budget(budget))
    print(f"results: {out / 'budget.json'}")
    return 0


def table_main(args: Namespace, scenario_ref: str | Scenario, values: dict, controllers: list[int],
               engine: Engine, storm_params: dict | None = None) -> int:
    """The paper's table for the scenario (a bundled name, or the scenario itself), flown in-process."""
    started = time.perf_counter()
    scenario, rows, tracks = run_montecarlo(scenario_ref, args.runs, controllers, args.workers, values,
                                            args.data_dir, progress=not args.quiet, first_seed=args.first_seed,
                                            engine=engine)
    return report(args, scenario, values, controllers, rows, tracks, time.perf_counter() - started, storm_params)


def flown_main(args: Namespace, scenario: Scenario, values: dict, overrides: dict, controllers: list[int],
               engine: Engine, storm_params: dict | None = None) -> int:
    """The same table, each run a whole mission of the one runner against ``args.fc`` (``--fc``:
    :mod:`fcmpc.montecarlo.flown`); records of each run in ``<out>/<scenario>-<fc>/runs/s<seed>/``."""
    import sys
    from dataclasses import replace

    from fcmpc.fly.runner import FlyOptions
    from fcmpc.montecarlo.engines import run_all
    from fcmpc.montecarlo.flown import fly_specs, plan_flown

    from fcmpc.fly.runner import short_destination

    started = time.perf_counter()
    dest = (scenario.dest_lat_deg, scenario.dest_lon_deg)
    if args.short_km is not None:     # the leg flown: its destination is the table's and the prediction's
        dest = short_destination(scenario, args.short_km)
        values = {**values, "NAV_DEST_LAT": dest[0], "NAV_DEST_LON": dest[1]}
    name = f"{scenario.name}-{args.fc}{'-' + args.physics if args.physics != 'builtin' else ''}"
    out = Path(args.out) / name
    base = FlyOptions(scenario=args.scenario, short=args.short_km is not None, short_km=args.short_km or 0.0,
                      fc=args.fc, physics=args.physics, compass=args.compass, timeout_s=args.timeout,
                      speedup=args.speedup, lockstep=args.speedup is None,
                      data_dir=args.data_dir, fc_instance=args.fc_instance or 0)
    specs = []
    for controller in controllers:
        options = replace(base, extra_params={**overrides, "NAV_CONTROLLER": controller})
        specs += [(len(specs) + k, spec) for k, spec in plan_flown(options, args.runs, args.first_seed, out)]
    if len(controllers) > 1:     # one folder per controller and seed
        specs = [(i, replace(s, keep_dir=f"{s.keep_dir}-c{s.options.extra_params['NAV_CONTROLLER']}"))
                 for i, s in specs]
    results = run_all(specs, engine, fly_specs, batched=False)
    if not args.quiet:
        from tqdm import tqdm

        results = tqdm(results, total=len(specs), desc=name, unit="run", file=sys.stderr)
    outputs = dict(results)
    # our stand-in flies the scenario's world, storm included; firmware flies in its own
    storm = scenario.storm.enabled and args.fc == "sim"
    rows = [replace(outputs[i].row, storm=storm) for i in range(len(specs))]
    tracks = [(outputs[i].lat_deg, outputs[i].lon_deg) for i in range(len(specs))]
    return report(args, scenario, values, controllers, rows, tracks, time.perf_counter() - started, storm_params,
                  name, dest, told=True)


def report(args: Namespace, scenario: Scenario, values: dict, controllers: list[int], rows: list, tracks: list,
           wall: float, storm_params: dict | None = None, name: str | None = None,
           dest: tuple[float, float] | None = None, told: bool = False) -> int:
    """Print the paper's table beside ours, write ``runs.csv`` and ``summary.json`` (``storm_params``:
    where the storm-time parameters come from and the storms they were fitted on) into
    ``<out>/<name>`` (default the scenario's name), and the plots unless ``--no-plots``; ``dest``: the
    destination flown (default the scenario's). ``told``: flown runs, whose prediction is what each
    run's companion said for its own configuration (the firmware's vehicle, not the scenario's)."""
    storm = scenario.storm.enabled and any(r.storm for r in rows)
    summary = summarise(rows, dest or (scenario.dest_lat_deg, scenario.dest_lon_deg))
    prediction = route_prediction(scenario, values) if Controller.FC in controllers and not told else None
    if prediction is not None:
        add_prediction(summary, rows, Controller.NAMES[Controller.FC], prediction.arrival_r95_m)
        print("predicted before flying: " + "; ".join(prediction.lines()))
    elif told and Controller.FC in controllers:
        add_prediction(summary, rows, Controller.NAMES[Controller.FC], None)
    out = Path(args.out) / (name or scenario.name)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "runs.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(asdict(rows[0])))
        writer.writeheader()
        writer.writerows(asdict(r) for r in rows)
    (out / "summary.json").write_text(json.dumps({"scenario": scenario.name, "runs": args.runs, "wall_s": wall,
                                                  "fc": getattr(args, "fc", None) or "in-process",
                                                  "parameters": values, "storm_params": storm_params,
                                                  "summary": summary,
                                                  "prediction": asdict(prediction) if prediction else None,
                                                  "paper": PAPER.get(scenario.name, {})}, indent=2, default=float))
    against = f", against {args.fc}" if getattr(args, "fc", None) else ""
    print(f"\n{scenario.description}\n{args.runs} runs per controller, {len(rows)} missions in {wall:.1f} s wall "
          f"({args.workers} workers, engine {args.engine}{against})\n")
    print(format_table(scenario.name, summary, storm))
    if not args.no_plots:
        print("\nplots: " + ", ".join(str(p) for p in _plots(args, out, scenario, rows, tracks, values)))
    print(f"results: {out / 'runs.csv'}, {out / 'summary.json'}")
    return 0


def route_prediction(scenario: Scenario, values: dict) -> RoutePrediction:
    """What the vehicle of this world would be told before flying: its heading source and INS
    as the scenario declares them, the navigator's settings of the runs."""
    config = NavConfig.from_values({**values, "NAV_CONTROLLER": Controller.FC})
    return predict_route(config, compass_derived=scenario.heading_source == "magnetic", has_ins=scenario.ins.onboard)


def _plots(args: Namespace, out: Path, scenario: Scenario, rows: list, tracks, values: dict) -> list[Path]:
    """The tracks and misses, the crustal anomaly along the route (and what the map misses), and
    for a storm the disturbance along the route."""
    from fcmpc.montecarlo.plots import plot_results
    from sitl.world.anomaly import write_route_anomaly

    written = plot_results(out, scenario, rows, tracks, scenario.storm.enabled)
    written.append(write_route_anomaly(out / "crust_anomaly.png", scenario, values, args.data_dir))
    if scenario.storm.enabled:
        from sitl import storms
        from sitl.world.build import build_truth_field

        from sitl.storms.events import storm_event
        from sitl.world.build import expected_mission_duration_s

        truth = build_truth_field(scenario, args.data_dir)
        span = (scenario.storm.window_posix if scenario.storm.time_map == "compress" else
                (scenario.start_posix, scenario.start_posix + expected_mission_duration_s(scenario)))
        storms.plot_disturbance(truth.disturbance, out / "disturbance.png", storms.StormWindow(scenario.name, *span),
                                acknowledgement=storm_event(scenario.storm.event).acknowledgement)
        written.append(out / "disturbance.png")
    return written
