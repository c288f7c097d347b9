"""What ``fcmpc-montecarlo`` does without ``--sweep``: the paper's table, or the error budget.

:func:`table_main` flies every controller ``--runs`` times, prints the paper's table beside ours
and writes ``runs.csv``, ``summary.json`` and the plots into ``<out>/<scenario>/``;
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
    (out / "budget.json").write_text(json.dumps({"scenario": real.name, "runs": args.runs, "rows": budget,
                                                 "wall_s": time.perf_counter() - started}, indent=2))
    print(f"\nError budget, {real.name}: Fc-MPC, {args.runs} runs per row "
          f"({time.perf_counter() - started:.0f} s wall)\n")
    print(format_budget(budget))
    print(f"results: {out / 'budget.json'}")
    return 0


def table_main(args: Namespace, scenario_ref: str | Scenario, values: dict, controllers: list[int],
               engine: Engine, storm_params: dict | None = None) -> int:
    """The paper's table for the scenario (a bundled name, or the scenario itself): fly, print,
    write ``runs.csv`` and ``summary.json`` (``storm_params``: where the storm-time parameters come
    from and the storms they were fitted on), and the plots unless ``--no-plots``."""
    started = time.perf_counter()
    scenario, rows, tracks = run_montecarlo(scenario_ref, args.runs, controllers, args.workers, values,
                                            args.data_dir, progress=not args.quiet, first_seed=args.first_seed,
                                            engine=engine)
    wall = time.perf_counter() - started
    storm = scenario.storm.enabled
    summary = summarise(rows, (scenario.dest_lat_deg, scenario.dest_lon_deg))
    prediction = _prediction(scenario, values) if Controller.FC in controllers else None
    if prediction is not None:
        add_prediction(summary, rows, Controller.NAMES[Controller.FC], prediction.arrival_r95_m)
        print("predicted before flying: " + "; ".join(prediction.lines()))
    out = Path(args.out) / scenario.name
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "runs.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(asdict(rows[0])))
        writer.writeheader()
        writer.writerows(asdict(r) for r in rows)
    (out / "summary.json").write_text(json.dumps({"scenario": scenario.name, "runs": args.runs, "wall_s": wall,
                                                  "parameters": values, "storm_params": storm_params,
                                                  "summary": summary,
                                                  "prediction": asdict(prediction) if prediction else None,
                                                  "paper": PAPER.get(scenario.name, {})}, indent=2, default=float))
    print(f"\n{scenario.description}\n{args.runs} runs per controller, {len(rows)} missions in {wall:.1f} s wall "
          f"({args.workers} workers, engine {args.engine})\n")
    print(format_table(scenario.name, summary, storm))
    if not args.no_plots:
        print("\nplots: " + ", ".join(str(p) for p in _plots(args, out, scenario, rows, tracks, values)))
    print(f"results: {out / 'runs.csv'}, {out / 'summary.json'}")
    return 0


def _prediction(scenario: Scenario, values: dict) -> RoutePrediction:
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
