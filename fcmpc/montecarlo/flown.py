"""Monte Carlo over a flight controller: each run a whole mission of the one runner (``fcmpc-montecarlo --fc``).

Where the in-process Monte Carlo (:mod:`fcmpc.montecarlo.runs`) flies the navigator against our
world in one process, a flown run is what ``fcmpc-fly`` does: the companion as a process against
our stand-in (``--fc sim``) or real firmware (``--fc ardupilot|px4``, its own physics or ours in
lockstep), through :func:`fcmpc.fly.runner.fly`. Each run has its own seed, its own instance
number (:func:`instance_for`, claimed for the run's life: the firmware's ports shift with it) and
its own temporary folder; what is kept of it (``result.json``, the parameters, the companion's
summary and steps) is copied to ``<out>/runs/s<seed>/``. Its row is measured as an in-process row
is (:class:`RunRow`: :func:`companion.nav.metrics.track_metrics` on the true positions at each
control step, start included, ending where the vehicle came to rest), so
:func:`fcmpc.montecarlo.tables.summarise` and ``format_table`` print the same table.

The engines are the in-process Monte Carlo's (:func:`fcmpc.montecarlo.engines.run_all` with
:func:`fly_specs` as the task, one run per task): the local pool, or Dask. A firmware run is tens
of minutes of wall time for the full Pacific (ArduPilot's wall-paced motorboat about 35 min, PX4
longer); ``--short-km`` flies the first kilometres of the route.
"""
from __future__ import annotations

import math
import shutil
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from companion.nav.metrics import track_metrics
from fcmpc.firmware.instances import claimed_instance
from fcmpc.fly.results import FlyResult
from fcmpc.fly.runner import FlyOptions, fly
from fcmpc.montecarlo.runs import RunOutput, RunRow

__all__ = ["FlownSpec", "KEPT", "fly_specs", "instance_for", "plan_flown"]

# What is kept of a run's folder (the firmware's own folders, eeprom, logs and tlogs are not)
KEPT = ("result.json", "fly.parm", "companion.log", "companion/summary.json", "companion/steps.csv")
INSTANCES = {"ardupilot": (80, 89), "px4": (1, 9)}     # ArduPilot -I: TCP 5760 + 10 I; PX4: 0..9 only


@dataclass(frozen=True)
class FlownSpec:
    """One flown run: ``fcmpc-fly``'s options (``out_dir`` and ``fc_instance`` are the run's own,
    set when it flies) and where its records are kept."""

    options: FlyOptions
    keep_dir: str


def plan_flown(options: FlyOptions, runs: int, first_seed: int, out: Path) -> list[tuple[int, FlownSpec]]:
    """``runs`` specs of ``options`` on seeds ``first_seed``... (quiet, no plot, no tlog)."""
    base = replace(options, plot=False, tlog=False, progress_s=None, quiet=True, compare=False)
    return [(k, FlownSpec(replace(base, seed=first_seed + k), str(out / "runs" / f"s{first_seed + k}")))
            for k in range(runs)]


@contextmanager
def instance_for(fc: str, index: int, first: int | None = None) -> Iterator[int]:
    """The instance number of run ``index``, claimed for the block (:func:`fcmpc.firmware.instances.claimed`):
    the first from the run's own slot of the FC's range (ArduPilot 80-89 or ``first``..``first`` + 9,
    PX4 1-9) on, round the range, that no other run claims and whose ports nobody has bound, so runs
    side by side never share one, in one process or in several."""
    if fc not in INSTANCES:
        yield 0   # our stand-in: a free UDP port of its own
        return
    low, high = INSTANCES[fc] if fc != "ardupilot" or first is None else (first, first + 9)
    with claimed_instance(fc, low, high, low + index % (high - low + 1)) as instance:
        yield instance


def fly_specs(batch: list[tuple[int, FlownSpec]]) -> list[tuple[int, RunOutput]]:
    """The engines' task: fly each run of the batch in its own temporary folder and measure it."""
    return [(index, _fly_one(index, spec)) for index, spec in batch]


def _fly_one(index: int, spec: FlownSpec) -> RunOutput:
    options = spec.options
    keep = Path(spec.keep_dir)
    with instance_for(options.fc, index, options.fc_instance or None) as instance, \
            tempfile.TemporaryDirectory(prefix=f"fcmpc-mc-{options.fc}-s{options.seed}-") as tmp:
        started = time.perf_counter()
        result = fly(replace(options, out_dir=tmp, fc_instance=instance))
        wall = time.perf_counter() - started
        output = _measure(result, options, wall)
        for name in KEPT:
            if (Path(tmp) / name).is_file():
                (keep / name).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(Path(tmp) / name, keep / name)
    return output


def _measure(result: FlyResult, options: FlyOptions, wall: float) -> RunOutput:
    """The run's row, on the true track ``fcmpc-fly`` measured its own miss on (the start, each
    control step, the point of rest: :func:`fcmpc.fly.results.true_track`)."""
    lat, lon = np.array(result.track_lat_deg), np.array(result.track_lon_deg)
    m = track_metrics(lat, lon, (lat[0], lon[0]), (result.dest_lat_deg, result.dest_lon_deg), result.iterations)
    row = RunRow(result.controller, options.seed, False, result.status, result.message, m.iterations,
                 result.rest_remaining_m / 1e3, m.length_m / 1e3, m.step_variance_m2 / 1e6,
                 m.mean_deviation_m / 1e3, m.max_deviation_m / 1e3, m.path_matching_rate_pct, m.final_lat_deg,
                 m.final_lon_deg, math.nan, wall, process_model=options.fc,
                 told_r95_km=_told_r95_m(result.companion) / 1e3)
    return RunOutput(row, lat, lon)


def _told_r95_m(companion: dict) -> float:
    """The 95 % radius the run's companion predicted for its own configuration and said before flying
    (its summary's ``route_prediction``, which ``fcmpc-fly`` carries: a vehicle without an INS, on its
    compass, is told what that vehicle can reach, not what the scenario's INS vehicle would); NaN if it
    said none."""
    told = companion.get("route_prediction")
    return float(told["arrival_r95_m"]) if told else math.nan
