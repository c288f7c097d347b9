"""The error budget: Fc-MPC with each error source of the realistic world alone, none and all.

Per row: the median |e_D|, |e_I| the source puts on the destination's measurement, the fix
error |G^-1 e| it predicts (:func:`sitl.budget.predicted_fix_error`) and the measured misses.
"""
from __future__ import annotations

import numpy as np

from companion.nav.metrics import percentile
from companion.params import Controller
from fcmpc.montecarlo.batch import run_montecarlo
from fcmpc.montecarlo.engines import Engine
from sitl.scenario import PAPER_PREFIX, Scenario, ScenarioError, load_scenario
from sitl.world.build import build_truth_field

__all__ = ["format_budget", "realistic_counterpart", "run_budget"]


def run_budget(real: Scenario, runs: int, workers: int, values: dict, data_dir: str | None = None,
               progress: bool = True, first_seed: int = 0, engine: Engine | None = None) -> list[dict]:
    """The error budget: Fc-MPC with each source of ``real`` alone, with none and with all.

    Per row: the median |e_D|, |e_I| the source puts on the destination's measurement, the
    predicted fix error |G^-1 e| (median over the seeds; for "all" the sum of the sources' e
    per seed), and the measured median and 90th-percentile miss over ``runs`` missions.
    """
    from sitl.budget import SOURCES, only, predicted_fix_error
    from sitl.world.build import expected_mission_duration_s

    duration = expected_mission_duration_s(real)
    seeds = [first_seed + k for k in range(runs)]
    predicted = {source: [predicted_fix_error(real, source, seed, duration,
                                              lambda sc: build_truth_field(sc, data_dir)) for seed in seeds]
                 for source in SOURCES if source != "storm" or real.storm.enabled}
    rows = []
    for source in ("none", *predicted, "all"):
        scenario = only(real, None if source == "none" else source)
        # the row's installation: its attitude is the INS's only where its heading errors are on
        row_values = {**values, "FUS_ATT_INS": scenario.attitude.ins_share}
        _, flown, _ = run_montecarlo(scenario, runs, [Controller.FC], workers, row_values, data_dir, progress,
                                     first_seed, quiet_too=False, engine=engine)
        miss = np.array([r.remaining_km for r in flown])
        if source == "all":
            from companion.nav.field import decl_incl_gradient, model_for_date
            g = decl_incl_gradient(model_for_date(real.year), real.dest_lat_deg, real.dest_lon_deg, real.alt_m,
                                   real.year)
            e = np.array([[sum(p[k].decl_deg for p in predicted.values()), sum(p[k].incl_deg for p in predicted.values())]
                          for k in range(runs)])
            fix = np.hypot(*np.linalg.solve(g, e.T)) / 1e3
        elif source == "none":
            e, fix = np.zeros((runs, 2)), np.zeros(runs)
        else:
            e = np.array([[p.decl_deg, p.incl_deg] for p in predicted[source]])
            fix = np.array([p.fix_error_m for p in predicted[source]]) / 1e3
        rows.append({"source": source, "e_decl_deg": float(np.median(np.abs(e[:, 0]))),
                     "e_incl_deg": float(np.median(np.abs(e[:, 1]))), "predicted_km": float(np.median(fix)),
                     "median_km": float(np.median(miss)), "p90_km": float(percentile(miss, 0.9)),
                     "arrived": int(sum(r.phase == "arrived" for r in flown)), "runs": runs})
    return rows


def format_budget(rows: list[dict]) -> str:
    """The budget as a Markdown table (the README carries one from a real run)."""
    lines = [("| Error source (alone) | median abs e_D (deg) | median abs e_I (deg) | predicted abs(G^-1 e), median (km) "
             "| miss, median (km) | miss, p90 (km) | arrived |"),
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['source']} | {r['e_decl_deg']:.4f} | {r['e_incl_deg']:.4f} | {r['predicted_km']:.1f} "
                     f"| {r['median_km']:.2f} | {r['p90_km']:.2f} | {r['arrived']}/{r['runs']} |")
    return "\n".join(lines)


def realistic_counterpart(scenario: Scenario) -> Scenario:
    """The realistic preset a scenario's error sources are switched from: a ``paper_*`` preset's
    realistic namesake (``paper_pacific`` -> ``pacific``), else the scenario itself."""
    if not scenario.name.startswith(PAPER_PREFIX):
        return scenario
    try:
        return load_scenario(scenario.name.removeprefix(PAPER_PREFIX))
    except ScenarioError:
        return scenario
