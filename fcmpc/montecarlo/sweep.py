"""Sweeps: the cross product of parameter values, N runs per cell, stored per run and resumable.

    fcmpc-montecarlo --sweep NAV_PERIOD_S=180,360,720 --sweep MPC_N=2,4,8 --runs 20
    fcmpc-montecarlo --sweep sensors.mag_noise_nt=50,150,450 --controllers fc

An axis is ``NAME=v1,v2,...``: a registry parameter (:mod:`companion.params`, checked against
its range) or a scenario key (``section.field`` of the scenario, :func:`fcmpc.montecarlo.runs.scenario_keys`).
Each cell of the cross product flies every chosen controller on seeds ``first_seed ..
first_seed + runs - 1``. Each run's row (every input and every metric) goes to the Parquet
store as it finishes (:class:`fcmpc.montecarlo.store.RunStore`); runs already stored are skipped, so
an interrupted or extended sweep continues where it stopped.
"""
from __future__ import annotations

import difflib
import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.cli import UsageError
from companion.nav.metrics import percentile
from companion.params import (
    SPEC_BY_NAME,
    Controller,
    ParamError,
    validate,
    validate_all,
)
from fcmpc.montecarlo.engines import Engine
from fcmpc.montecarlo.runs import RunSpec, apply_scenario_changes, scenario_keys
from fcmpc.montecarlo.store import RunStore, fly_missing, run_key
from sitl.scenario import Scenario

__all__ = ["SweepAxis", "SweepPlan", "format_cells", "parse_sweep", "plan_sweep", "run_sweep", "summarise_cells"]


@dataclass(frozen=True)
class SweepAxis:
    """One swept input: a registry NAME or a scenario key, and its values in the order given."""

    name: str
    values: tuple[float | int, ...]
    scenario_key: bool = False


def parse_sweep(items: list[str], scenario: Scenario) -> list[SweepAxis]:
    """``NAME=v1,v2,...`` items as axes; a mistake is a :class:`UsageError` naming the item."""
    axes: list[SweepAxis] = []
    known = scenario_keys(scenario)
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        parts = [p.strip() for p in text.split(",")]
        if not sep or not name or not all(parts):
            raise UsageError(f"--sweep {item!r}: expected NAME=V1,V2,... (a registry parameter or a scenario key)")
        is_key = name in known
        if not is_key:
            name = name.upper()
        if name == "NAV_CONTROLLER":
            raise UsageError(f"--sweep {item!r}: choose controllers with --controllers")
        if any(axis.name == name for axis in axes):
            raise UsageError(f"--sweep {item!r}: {name} is swept twice")
        try:
            if is_key:
                values = tuple(float(p) for p in parts)
                if not all(math.isfinite(v) for v in values):
                    raise ValueError("values must be finite")
            else:
                values = tuple(validate(name, p) for p in parts)
        except ParamError as err:
            hint = ""
            if name not in SPEC_BY_NAME:
                close = difflib.get_close_matches(name, [*SPEC_BY_NAME, *known], n=1, cutoff=0.5)
                hint = f" or scenario key; did you mean {close[0]}?" if close else " or scenario key"
            raise UsageError(f"--sweep {item!r}: {err}{hint}") from None
        except ValueError as err:
            raise UsageError(f"--sweep {item!r}: {err}") from None
        if len(set(values)) != len(values):
            raise UsageError(f"--sweep {item!r}: a value is repeated")
        axes.append(SweepAxis(name, values, is_key))
    return axes


@dataclass(frozen=True)
class SweepPlan:
    """Every run of a sweep: ``specs[i]`` with ``keys[i]`` (its store key), ``cells[i]`` (the
    cell's label) and ``inputs[i]`` (the row's input columns)."""

    axes: tuple[SweepAxis, ...]
    specs: tuple[RunSpec, ...]
    keys: tuple[str, ...]
    cells: tuple[str, ...]
    inputs: tuple[dict, ...]


def _label(cell: dict) -> str:
    return " ".join(f"{k}={v:g}" for k, v in cell.items())


def plan_sweep(scenario_ref: str | Scenario, scenario: Scenario, axes: list[SweepAxis], runs: int,
               controllers: list[int], overrides: dict, data_dir: str | None = None,
               first_seed: int = 0) -> SweepPlan:
    """The cross product of the axes x controllers x seeds, in that order. ``overrides``: registry
    values set for the whole sweep (``--params``, ``--param``) over the scenario's own."""
    specs, keys, cells, inputs = [], [], [], []
    for combo in itertools.product(*(axis.values for axis in axes)):
        cell = {axis.name: value for axis, value in zip(axes, combo)}
        changes = tuple((a.name, v) for a, v in zip(axes, combo) if a.scenario_key)
        try:
            flown = apply_scenario_changes(scenario, changes)
        except ValueError as err:
            raise UsageError(f"--sweep {_label(cell)}: {err}") from None
        params = {a.name: v for a, v in zip(axes, combo) if not a.scenario_key}
        described = {**scenario_keys(flown)}
        for controller in controllers:
            values = validate_all({**flown.nav_overrides(), **overrides, **params, "NAV_CONTROLLER": controller})
            for seed in range(first_seed, first_seed + runs):
                spec = RunSpec(scenario_ref, tuple(values.items()), seed, flown.storm.enabled, changes, data_dir)
                specs.append(spec)
                keys.append(run_key(spec, repr(flown)))
                cells.append(_label(cell))
                inputs.append({"scenario": flown.name, "cell": _label(cell), **values, **described})
    return SweepPlan(tuple(axes), tuple(specs), tuple(keys), tuple(cells), tuple(inputs))


def run_sweep(plan: SweepPlan, store: RunStore, engine: Engine, progress: bool = True,
              flush_every: int = 64, flush_s: float = 30.0) -> dict:
    """Fly the runs of ``plan`` not yet in ``store``, appending rows as they finish.
    Returns counts: planned, skipped (already stored), flown, and the wall seconds."""
    flown = fly_missing(plan.specs, plan.keys, store, engine, plan.inputs, "sweep", progress, flush_every, flush_s)
    return {"planned": flown.planned, "skipped": flown.skipped, "flown": len(flown.rows), "wall_s": flown.wall_s}


def summarise_cells(rows: list[dict], axes: tuple[SweepAxis, ...]) -> list[dict]:
    """Per (cell, controller): runs, arrived, median/mean/p90 miss (km), mean path deviation,
    iterations and length, in the order the cells were planned."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for row in rows:
        groups.setdefault((row["cell"], row["controller"]), []).append(row)
    out = []
    for (cell, controller), members in groups.items():
        miss = np.array([r["remaining_km"] for r in members])
        entry = {**{a.name: members[0][a.name] for a in axes}, "cell": cell, "controller": controller,
                 "runs": len(members), "arrived": sum(r["phase"] == "arrived" for r in members),
                 "median_km": float(np.median(miss)), "mean_km": float(miss.mean()),
                 "p90_km": float(percentile(miss, 0.9)),
                 "mean_dev_km": float(np.mean([r["mean_dev_km"] for r in members])),
                 "iterations": float(np.mean([r["iterations"] for r in members])),
                 "length_km": float(np.mean([r["length_km"] for r in members]))}
        out.append(entry)
    return out


def format_cells(summary: list[dict], axes: tuple[SweepAxis, ...]) -> str:
    """The per-cell summary as a Markdown table."""
    names = [a.name for a in axes]
    head = names + ["controller", "runs", "arrived", "median miss (km)", "mean (km)", "p90 (km)",
                    "mean dev (km)", "iterations", "length (km)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in summary:
        cells = [f"{s[n]:g}" for n in names] + [s["controller"], str(s["runs"]), str(s["arrived"]),
                                                 f"{s['median_km']:.2f}", f"{s['mean_km']:.2f}", f"{s['p90_km']:.2f}",
                                                 f"{s['mean_dev_km']:.2f}", f"{s['iterations']:.1f}",
                                                 f"{s['length_km']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def controller_names(controllers: list[int]) -> list[str]:
    return [Controller.NAMES[c] for c in controllers]


def sweep_folder(out: str | Path, scenario: Scenario) -> Path:
    """Where a scenario's sweeps live: ``<out>/<scenario>/sweep`` (runs/ holds the Parquet parts)."""
    return Path(out) / scenario.name / "sweep"
