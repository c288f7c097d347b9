"""Fit the storm-time parameters by what they do to the navigator's miss on the training storms.

    fcmpc-fit-storms --loo all --by-miss          # -> params/storms-<names>-by-miss.parm, one per held-out storm
    fcmpc-fit-storms --loo may2024 --by-miss --seeds 4 --workers 2

The walks measured on the training storms' truth (:func:`fcmpc.montecarlo.fit_storms.fit_storm`,
pooled) say how fast a storm moved the field; whether the navigator does better trusting them,
and the ring-current correction from the published index, is another question, answered here by
flying the navigator. Each candidate is the training storms' pooled walks with the rates
(``FUS_BQA_N/E/Z``, ``FUS_SYMH_N``) scaled by ``s`` (:data:`SCALES`) and the ring-current ratio
``FUS_SYMH_K`` = ``k`` (:data:`RATIOS`; 0: the index's ring current is not removed; the north
residual ``FUS_SYMH_*`` is measured on the truth with that ``k`` removed). Each candidate flies
every training storm (``<name>_real``, indices as published, Fc-MPC in-process) on the tuning seeds
(0..n-1, at most 99: never the judging seeds >= 1000), and so does the same world with the index
feed switched off. The score is the mean over the training storms of the candidate's mean miss over
the feed-off mean miss on the same seeds (1: the index pays nothing; storms weigh alike whatever
their size); the lowest wins. So the fit can choose not to trust the index (``k`` 0, small walks)
when the index does not help on the training storms; it cannot switch the feed off, which is the
world's (the score says when every candidate does worse than no feed).

Every (storm, parameters, seed) run is flown once for all training sets of a call (the sets of a
leave-one-out share most candidates' storms).
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, fields

import numpy as np

from companion.params import Controller, validate_all
from fcmpc.montecarlo.engines import Engine
from fcmpc.montecarlo.runs import RunRow, RunSpec, apply_scenario_changes
from fcmpc.montecarlo.store import RunStore, fly_missing, run_key
from sitl.scenario import Scenario, load_scenario

__all__ = ["FEED_OFF", "RATIOS", "SCALES", "TUNING_SEEDS", "Candidate", "Fit", "Walks", "candidates", "fit_by_miss",
           "format_fit"]

SCALES = (0.1, 0.3, 1.0)        # the pooled walk rates times this
RATIOS = (0.0, 0.5, 1.0)        # FUS_SYMH_K: none, half, the symmetric ring current's (cos of geomagnetic lat.)
TUNING_SEEDS = range(0, 100)    # the only seeds a fit may fly (judging: 1000 on)
RATES = ("FUS_BQA_N", "FUS_BQA_E", "FUS_BQA_Z", "FUS_SYMH_N")
FEED_OFF = (("storm.kp_feed", 0.0), ("storm.symh_feed", 0.0))   # neither index reaches the navigator


@dataclass(frozen=True)
class Candidate:
    """One set of storm-time values: the pooled walks' rates times ``scale``, ``FUS_SYMH_K`` = ``ratio``."""

    scale: float
    ratio: float
    values: tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class Fit:
    """A training set's result: the chosen candidate, and every candidate's score and per-storm
    (mean miss km, feed-off mean miss km, share inside the own 95 % ellipse)."""

    storms: tuple[str, ...]
    chosen: Candidate
    scores: tuple[tuple[Candidate, float, dict[str, tuple[float, float, float]]], ...]
    seeds: tuple[int, ...]


Walks = Callable[[Sequence[str], float], dict[str, float]]   # (training storms, FUS_SYMH_K) -> pooled walks


def candidates(names: Sequence[str], walks: Walks, scales: Sequence[float] = SCALES,
               ratios: Sequence[float] = RATIOS) -> list[Candidate]:
    """The grid of :data:`SCALES` x :data:`RATIOS` on the walks pooled over ``names``
    (``walks``: :func:`fcmpc.montecarlo.fit_storms.fit_storms` with the residual at that ratio)."""
    out = []
    for ratio in ratios:
        pooled = walks(names, ratio if ratio > 0.0 else 1.0)
        for scale in scales:
            values = {k: round(v * scale, 1) if k in RATES else v for k, v in pooled.items()}
            out.append(Candidate(scale, ratio, tuple(sorted({**values, "FUS_SYMH_K": ratio}.items()))))
    return out


def _spec(scenario: Scenario, values: Iterable[tuple[str, float]], seed: int, feed_off: bool,
          data_dir: str | None) -> RunSpec:
    merged = validate_all({**scenario.nav_overrides(), **dict(values), "NAV_CONTROLLER": Controller.FC})
    return RunSpec(scenario.name, tuple(merged.items()), seed, True, FEED_OFF if feed_off else (), data_dir)


def fit_by_miss(training_sets: Sequence[Sequence[str]], walks: Walks, seeds: Sequence[int], engine: Engine,
                data_dir: str | os.PathLike[str] | None = None, scales: Sequence[float] = SCALES,
                ratios: Sequence[float] = RATIOS, progress: bool = True, store: RunStore | None = None) -> list[Fit]:
    """Each training set's candidates flown on its storms and ``seeds`` (feed on, and off), scored,
    the best chosen; ``store`` keeps every run as it finishes, so a second call flies only what is
    missing. Raises ValueError for a seed outside :data:`TUNING_SEEDS`."""
    seeds = tuple(int(s) for s in seeds)
    if not seeds or any(s not in TUNING_SEEDS for s in seeds):
        raise ValueError(f"tuning seeds must lie in {TUNING_SEEDS.start}..{TUNING_SEEDS.stop - 1} (judging: 1000 on)")
    folder = None if data_dir is None else str(data_dir)
    grids = {tuple(names): candidates(names, walks, scales, ratios) for names in training_sets}
    scenarios = {storm: load_scenario(f"{storm}_real") for names in grids for storm in names}   # each read once
    worlds = {(storm, off): repr(apply_scenario_changes(scenario, FEED_OFF if off else ()))
              for storm, scenario in scenarios.items() for off in (False, True)}
    specs: dict[tuple, RunSpec] = {}
    for names, grid in grids.items():
        for storm in names:
            for seed in seeds:
                specs.setdefault((storm, (), seed, True), _spec(scenarios[storm], (), seed, True, folder))
                for cand in grid:
                    specs.setdefault((storm, cand.values, seed, False),
                                     _spec(scenarios[storm], cand.values, seed, False, folder))
    rows = _fly(specs, {k: run_key(spec, worlds[(k[0], k[3])]) for k, spec in specs.items()}, engine, store, progress)
    fits = []
    for names, grid in grids.items():
        scored = []
        for cand in grid:
            per_storm = {}
            for storm in names:
                on = [rows[(storm, cand.values, s, False)] for s in seeds]
                off = [rows[(storm, (), s, True)] for s in seeds]
                inside = float(np.nanmean([r.in_ellipse95 for r in on]))
                per_storm[storm] = (float(np.mean([r.remaining_km for r in on])),
                                    float(np.mean([r.remaining_km for r in off])), inside)
            score = float(np.mean([on / off for on, off, _ in per_storm.values()]))
            scored.append((cand, score, per_storm))
        best = min(scored, key=lambda item: (item[1], item[0].ratio, item[0].scale))[0]
        fits.append(Fit(names, best, tuple(scored), seeds))
    return fits


def _fly(specs: dict[tuple, RunSpec], digests: dict[tuple, str], engine: Engine, store: RunStore | None,
         progress: bool) -> dict[tuple, RunRow]:
    """Every spec's row: flown when ``store`` lacks it (:func:`fcmpc.montecarlo.store.fly_missing`), else read."""
    keys = list(specs)
    flown = fly_missing([specs[k] for k in keys], [digests[k] for k in keys], store, engine, None,
                        "fit by miss", progress)
    rows = {keys[i]: row for i, row in flown.rows.items()}
    if len(rows) < len(keys):
        stored = {r["run_key"]: r for r in store.read({digests[k] for k in keys if k not in rows}).to_pylist()}
        names = [f.name for f in fields(RunRow)]
        rows.update({k: RunRow(**{n: stored[digests[k]][n] for n in names}) for k in keys if k not in rows})
    return rows


def format_fit(fit: Fit) -> str:
    """A training set's scores as a table, the chosen candidate marked."""
    lines = [f"training storms {','.join(fit.storms)}, seeds {fit.seeds[0]}-{fit.seeds[-1]}: "
             "score = mean over storms of (mean miss / feed-off mean miss)",
             "scale  FUS_SYMH_K  score  " + "  ".join(f"{s} (km, inside)" for s in fit.storms)]
    for cand, score, per_storm in fit.scores:
        mark = " <- chosen" if cand == fit.chosen else ""
        cells = "  ".join(f"{on:.1f}/{off:.1f}, {inside:.0%}" for on, off, inside in per_storm.values())
        lines.append(f"{cand.scale:5.2f}  {cand.ratio:10.2f}  {score:5.3f}  {cells}{mark}")
    return "\n".join(lines)
