"""What ``fcmpc-montecarlo --sweep`` does: plan the cells, fly what is not stored, report.

Prints the per-cell table (also ``summary.csv`` and ``summary.json``), the runs per second of
this call, and writes a line plot per swept value and a heat map per swept pair into
``<out>/<scenario>/sweep/plots/``.
"""
from __future__ import annotations

import csv
import json
from argparse import Namespace
from collections.abc import Callable

from fcmpc.montecarlo.engines import Engine
from fcmpc.montecarlo.store import RunStore
from fcmpc.montecarlo.sweep import (
    format_cells,
    parse_sweep,
    plan_sweep,
    run_sweep,
    summarise_cells,
    sweep_folder,
)
from sitl.scenario import Scenario

__all__ = ["sweep_main"]


def sweep_main(args: Namespace, scenario_ref: str | Scenario, scenario: Scenario, controllers: list[int],
               overrides: dict, engine: Engine, check: Callable[[dict, list[int]], None],
               storm_params: dict | None = None) -> int:
    """Run a sweep from parsed arguments; ``check`` refuses a cell's mission before any run;
    ``storm_params`` (where the storm-time parameters come from) goes into ``summary.json``."""
    if args.budget:
        from companion.cli import UsageError

        raise UsageError("--sweep and --budget: choose one")
    axes = parse_sweep(args.sweep, scenario)
    plan = plan_sweep(scenario_ref, scenario, axes, args.runs, controllers, overrides, args.data_dir,
                      args.first_seed)
    checked: set = set()
    for spec in plan.specs:
        values = {k: v for k, v in spec.values if k != "NAV_CONTROLLER"}
        key = tuple(sorted(values.items()))
        if key not in checked:
            check(values, controllers)
            checked.add(key)
    folder = sweep_folder(args.out, scenario)
    store = RunStore(folder / "runs")
    counts = run_sweep(plan, store, engine, progress=not args.quiet)
    rows = store.read(set(plan.keys)).to_pylist()
    summary = summarise_cells(rows, plan.axes)
    with open(folder / "summary.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(summary[0]))
        writer.writeheader()
        writer.writerows(summary)
    rate = counts["flown"] / counts["wall_s"] if counts["wall_s"] > 0 else 0.0
    workers = engine.worker_count if not engine.cluster else "cluster"
    (folder / "summary.json").write_text(json.dumps({"scenario": scenario.name, "axes": [a.name for a in axes],
                                                     "runs_per_cell": args.runs, **counts,
                                                     "runs_per_s": rate, "engine": engine.kind,
                                                     "workers": workers, "storm_params": storm_params,
                                                     "cells": summary, "run_keys": list(plan.keys)}, indent=2, default=float))
    cells = len(plan.specs) // max(1, args.runs * len(controllers))
    print(f"\n{scenario.name}: {cells} cells x {len(controllers)} controllers x {args.runs} runs = "
          f"{counts['planned']} runs; {counts['skipped']} already stored, {counts['flown']} flown in "
          f"{counts['wall_s']:.1f} s wall ({rate:.2f} runs/s, engine {engine.kind}, workers {workers})\n")
    print(format_cells(summary, plan.axes))
    if not args.no_plots:
        from fcmpc.montecarlo.sweep_plots import plot_sweep

        written = plot_sweep(folder / "plots", rows, plan.axes)
        print("\nplots: " + ", ".join(str(p) for p in written))
    print(f"results: {store.folder} ({len(rows)} rows), {folder / 'summary.csv'}")
    return 0
