"""The paper's Monte Carlo: every controller on the same seeds (and, for a storm, the same seeds
with the storm off), on any engine. What ``fcmpc-montecarlo`` without ``--sweep`` runs."""
from __future__ import annotations

import sys

from companion.params import validate_all
from fcmpc.montecarlo.engines import Engine, run_all
from fcmpc.montecarlo.runs import RunRow, RunSpec
from sitl.scenario import Scenario, load_scenario

__all__ = ["plan_runs", "run_montecarlo"]


def plan_runs(scenario_ref: str | Scenario, scenario: Scenario, runs: int, controllers: list[int], values: dict,
              data_dir: str | None = None, first_seed: int = 0, quiet_too: bool = True) -> list[RunSpec]:
    """The specs in table order: storm runs per controller and seed, then the quiet ones."""
    storm = scenario.storm.enabled
    flags = ([True] if storm else []) + ([False] if quiet_too or not storm else [])
    return [RunSpec(scenario_ref, tuple(validate_all({**values, "NAV_CONTROLLER": c}).items()), first_seed + s,
                    flag, (), data_dir)
            for flag in flags for c in controllers for s in range(runs)]


def run_montecarlo(scenario_ref: str | Scenario, runs: int, controllers: list[int], workers: int, values: dict,
                   data_dir: str | None = None, progress: bool = True, first_seed: int = 0,
                   quiet_too: bool = True, engine: Engine | None = None):
    """All (controller, seed[, storm off]) runs; returns (scenario, rows, tracks) in table order.

    ``scenario_ref`` is a bundled name, a TOML path or a :class:`Scenario` (e.g. with error
    sources switched); ``quiet_too`` also flies a storm scenario's seeds with the storm off;
    ``engine`` defaults to the local pool with ``workers`` processes.
    """
    scenario = load_scenario(scenario_ref) if isinstance(scenario_ref, str) else scenario_ref
    specs = plan_runs(scenario_ref, scenario, runs, controllers, values, data_dir, first_seed, quiet_too)
    engine = engine or Engine("local", workers)
    results = run_all(enumerate(specs), engine)
    if progress:
        from tqdm import tqdm

        results = tqdm(results, total=len(specs), desc=scenario.name, unit="run", file=sys.stderr)
    outputs = dict(results)
    rows: list[RunRow] = [outputs[i].row for i in range(len(specs))]
    tracks = [(outputs[i].lat_deg, outputs[i].lon_deg) for i in range(len(specs))]
    return scenario, rows, tracks
