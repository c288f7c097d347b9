"""One Monte Carlo run as a pure function of (scenario, settings, seed): what every engine calls.

A :class:`RunSpec` names everything a run depends on: the scenario (a bundled name, a TOML path
or a :class:`~sitl.scenario.Scenario`), changes to the scenario's fields (a sweep's scenario
keys, e.g. ``sensors.mag_noise_nt``), every registry parameter's value, the seed and whether the
storm is on. :func:`run_specs` flies a batch of them in-process (:func:`fcmpc.montecarlo.inprocess.fly_batch`) and
measures each (:func:`companion.nav.metrics.track_metrics`). Nothing else enters: no clock but the
run's own wall time (reported, never used), no shared random state, so the same spec gives the
same numbers bit for bit in any process of any engine (tested against the local pool).

The truth field of a (scenario, storm) pair is built once per worker process and cached, because
building it (storm data, crust) costs more than a short run.

Signal-to-noise ratio, for storm scenarios (the paper does not define it)::

    SNR = 10 log10( sum_k |dS_wmm(k)|^2 / sum_k |dS_storm(k)|^2 )  [dB]

over the control steps k of the flown track: dS_wmm is the step-to-step change of (D, I) of the
main field along the track, dS_storm the step-to-step change of the storm's own contribution.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields, is_dataclass, replace

import numpy as np

from companion.nav.metrics import track_metrics
from companion.params import NavConfig
from fcmpc.montecarlo.inprocess import CHI2_95_2DOF, InProcessFlight, RunResult, fly_batch, nees_per_step
from sitl.scenario import Scenario, ScenarioError, load_scenario
from sitl.world.build import build_truth_field
from sitl.world.magnetic import TruthField, decl_incl_from_ned

__all__ = [
    "RunOutput",
    "RunRow",
    "RunSpec",
    "apply_scenario_changes",
    "run_spec",
    "run_specs",
    "scenario_keys",
]


@dataclass(frozen=True)
class RunRow:
    """One run's result, flat for CSV and Parquet; distances in km, positions in degrees."""

    controller: str
    seed: int
    storm: bool
    phase: str
    reason: str
    iterations: int
    remaining_km: float
    length_km: float
    step_var_km2: float
    mean_dev_km: float
    max_dev_km: float
    pmr_pct: float
    final_lat: float
    final_lon: float
    snr_db: float
    wall_s: float
    process_model: str = ""          # the position estimator: ins, dead_reckoning or table3
    nees_mean: float = math.nan      # mean over the steps of the filter's NEES (2 when consistent)
    in_ellipse95: float = math.nan   # 1 when the final position lies inside the filter's 95 % ellipse
    sigma_end_km: float = math.nan   # the filter's own 1-sigma (per axis) at the end
    told_r95_km: float = math.nan    # a flown run: the 95 % radius its companion predicted and said before flying


@dataclass(frozen=True)
class RunSpec:
    """Everything one run depends on. ``values``: every registry parameter as (NAME, value),
    the controller included; ``scenario_changes``: (dotted scenario key, value) pairs applied
    with :func:`apply_scenario_changes`; ``data_dir``: where the storm data lives (None: default)."""

    scenario: str | Scenario
    values: tuple[tuple[str, float | int], ...]
    seed: int
    storm: bool = False
    scenario_changes: tuple[tuple[str, float], ...] = ()
    data_dir: str | None = None


@dataclass(frozen=True)
class RunOutput:
    """A run's row and its true track (degrees at each control step, start included)."""

    row: RunRow
    lat_deg: np.ndarray
    lon_deg: np.ndarray


def scenario_keys(scenario: Scenario) -> dict[str, object]:
    """Every numeric or boolean field of a scenario by dotted key (``sensors.mag_noise_nt``,
    ``field_model.crustal.rms_down_nt``, ``alt_m``) with its current value: what a sweep may set."""
    keys: dict[str, object] = {}

    def walk(obj: object, prefix: str) -> None:
        for f in fields(obj):
            value = getattr(obj, f.name)
            if is_dataclass(value):
                walk(value, f"{prefix}{f.name}.")
            elif isinstance(value, (bool, int, float)):
                keys[f"{prefix}{f.name}"] = value
    walk(scenario, "")
    return keys


def apply_scenario_changes(scenario: Scenario, changes: tuple[tuple[str, float], ...]) -> Scenario:
    """The scenario with each dotted key set (booleans from 0/1, integers kept integral).
    Raises :class:`~sitl.scenario.ScenarioError` naming an unknown key."""
    known = scenario_keys(scenario)
    for key, value in changes:
        if key not in known:
            raise ScenarioError(f"no scenario key {key!r} (numeric keys: {', '.join(sorted(known))})")
        old = known[key]
        new = bool(value) if isinstance(old, bool) else int(value) if isinstance(old, int) else float(value)
        scenario = _set_path(scenario, key.split("."), new)
    return scenario


def _set_path(obj, path: list[str], value):
    if len(path) == 1:
        return replace(obj, **{path[0]: value})
    return replace(obj, **{path[0]: _set_path(getattr(obj, path[0]), path[1:], value)})


# --- worker side: caches of one process ---------------------------------------------------------
_SCENARIOS: dict[tuple, Scenario] = {}
_TRUTHS: dict[tuple, TruthField] = {}


def _world(spec: RunSpec) -> tuple[Scenario, TruthField]:
    ref = spec.scenario if isinstance(spec.scenario, str) else id(spec.scenario)
    key = (ref, spec.scenario_changes)
    scenario = _SCENARIOS.get(key) if isinstance(spec.scenario, str) else None
    if scenario is None:
        base = load_scenario(spec.scenario) if isinstance(spec.scenario, str) else spec.scenario
        scenario = apply_scenario_changes(base, spec.scenario_changes)
        if isinstance(spec.scenario, str):
            _SCENARIOS[key] = scenario
    truth_key = (repr(scenario), spec.storm, spec.data_dir)
    truth = _TRUTHS.get(truth_key)
    if truth is None:
        flown = scenario if spec.storm else replace(scenario, storm=replace(scenario.storm, enabled=False))
        truth = build_truth_field(flown, spec.data_dir if spec.storm else None)
        _TRUTHS[truth_key] = truth
    return scenario, truth


def _snr_db(truth: TruthField, lat: np.ndarray, lon: np.ndarray, period_s: float, alt_m: float) -> float:
    if truth.disturbance is None or len(lat) < 3:
        return math.nan
    times = np.arange(len(lat)) * period_s
    total = truth.field_ned_nt(lat, lon, alt_m, times)
    quiet = replace(truth, disturbance=None).field_ned_nt(lat, lon, alt_m, times)
    s_total = np.stack(decl_incl_from_ned(total[:, 0], total[:, 1], total[:, 2]), -1)
    s_wmm = np.stack(decl_incl_from_ned(quiet[:, 0], quiet[:, 1], quiet[:, 2]), -1)
    signal = np.sum(np.diff(s_wmm, axis=0) ** 2)
    noise = np.sum(np.diff(s_total - s_wmm, axis=0) ** 2)
    return float(10.0 * np.log10(signal / noise)) if noise > 0 else math.inf


def run_spec(spec: RunSpec) -> RunOutput:
    """Fly one run and measure it."""
    return run_specs([(0, spec)])[0][1]


def run_specs(batch: list[tuple[int, RunSpec]]) -> list[tuple[int, RunOutput]]:
    """A batch of (index, spec): one task of an engine (the function every engine maps), so small
    runs do not pay one round trip each. Its runs fly side by side (:func:`fcmpc.montecarlo.inprocess.fly_batch`:
    each as it would alone, bit for bit); each run's ``wall_s`` is its share of the batch's."""
    worlds = [_world(spec) for _, spec in batch]
    navs = [NavConfig.from_values(dict(spec.values)) for _, spec in batch]
    started = time.perf_counter()
    results = fly_batch([InProcessFlight(nav, scenario, spec.seed, truth)
                         for (_, spec), nav, (scenario, truth) in zip(batch, navs, worlds)])
    wall = (time.perf_counter() - started) / max(1, len(batch))
    return [(index, _output(spec, nav, result, truth, wall))
            for (index, spec), nav, result, (_, truth) in zip(batch, navs, results, worlds)]


def _output(spec: RunSpec, nav: NavConfig, result: RunResult, truth: TruthField, wall: float) -> RunOutput:
    """One run's row of metrics and its track."""
    start, dest = (nav.start_lat_deg, nav.start_lon_deg), (nav.dest_lat_deg, nav.dest_lon_deg)
    lat, lon = result.track_to_rest()   # the miss where the vehicle stops, not where the last step found it
    m = track_metrics(lat, lon, start, dest, result.iterations)
    nees = nees_per_step(result)
    end = result.est_cov_en_m2[-1] if len(result.est_cov_en_m2) else (math.nan,) * 3
    row = RunRow(result.controller, spec.seed, spec.storm, result.phase, result.reason, m.iterations,
                 m.remaining_m / 1e3, m.length_m / 1e3, m.step_variance_m2 / 1e6, m.mean_deviation_m / 1e3,
                 m.max_deviation_m / 1e3, m.path_matching_rate_pct, m.final_lat_deg, m.final_lon_deg,
                 _snr_db(truth, lat, lon, nav.period_s, nav.alt_m), wall,
                 result.process_model, float(np.nanmean(nees)) if np.any(np.isfinite(nees)) else math.nan,
                 float(nees[-1] <= CHI2_95_2DOF) if len(nees) and math.isfinite(nees[-1]) else math.nan,
                 math.sqrt(0.5 * (end[0] + end[2])) / 1e3)
    return RunOutput(row, lat, lon)
