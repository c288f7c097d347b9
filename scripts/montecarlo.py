"""Monte Carlo of the paper's tables: the navigation core against the simulated world, in-process.

    fcmpc-montecarlo --scenario pacific --runs 50          # Table 5: LTI-, LTV-, Fc-MPC
    fcmpc-montecarlo --scenario long_storm --runs 50       # Table 6: LTV- vs Fc-MPC
    fcmpc-montecarlo --scenario short_storm --runs 50      # Table 7
    fcmpc-montecarlo --scenario pacific_real --runs 50     # the realistic world (issue 9)
    fcmpc-montecarlo --scenario pacific_real --errors -heading,+crustal   # switch error sources
    fcmpc-montecarlo --scenario pacific_real --budget --runs 10           # the error budget

Each run draws its own INS errors and sensor noise from its seed; every controller meets the
same draws for the same seed. Runs go to worker processes with a progress bar. The script
prints the table with the paper's figures beside ours and writes ``runs.csv``,
``summary.json`` and PNG plots into ``out/montecarlo/<scenario>/`` (git-ignored).

For storm scenarios it also flies the same seeds with the storm switched off, so the table
shows what the storm costs each controller, and it defines the signal-to-noise ratio as

    SNR = 10 log10( sum_k |dS_wmm(k)|^2 / sum_k |dS_storm(k)|^2 )  [dB]

over the control steps k of the flown track: dS_wmm is the step-to-step change of (D, I) of
the main field along the track (the signal the gradient estimation lives on), dS_storm the
step-to-step change of the storm's own contribution to (D, I) (what it must reject).
"""
from __future__ import annotations

import os

# Tiny matrices: BLAS threads only fight the worker processes for the two cores.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import csv
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from companion.cli import ArgumentParser, UsageError, param_items, run_main
from companion.nav.metrics import cep50, cep_paper, mean_terminal_location, track_metrics
from companion.nav.geo import geodesic_distance_m
from companion.params import Controller, NavConfig, read_parm_file, validate_all
from sitl.inprocess import CHI2_95_2DOF, fly_in_process, nees_per_step
from scripts.montecarlo_plots import outlier_fence_km, plot_results  # noqa: E402, F401
from sitl.scenario import Scenario, ScenarioError, load_scenario
from sitl.world.build import build_truth_field
from sitl.world.magnetic import decl_incl_from_ned

CONTROLLER_KEYS = {"lti": Controller.LTI, "ltv": Controller.LTV, "fc": Controller.FC}

# The paper's figures (Tables 5-7, and the medians of Section 4.2's text), for the side-by-side.
PAPER = {
    "pacific": {
        "LTI-MPC": {"cep_paper_km": 35.18, "terminal_lon": 157.68, "terminal_lat": 28.15, "mean_terminal_miss_km": 3.55,
                    "mean_dev_km": 0.76, "max_dev_km": 1.41, "pmr_pct": 26.04, "iterations": 171,
                    "step_var_km2": 0.19, "length_km": 864.59},
        "LTV-MPC": {"cep_paper_km": 8.92, "terminal_lon": 157.92, "terminal_lat": 28.04, "mean_terminal_miss_km": 9.03,
                    "mean_dev_km": 0.75, "max_dev_km": 1.42, "pmr_pct": 26.32, "iterations": 169,
                    "step_var_km2": 0.18, "length_km": 837.52},
        "Fc-MPC": {"cep_paper_km": 0.19, "terminal_lon": 158.01, "terminal_lat": 28.02, "mean_terminal_miss_km": 2.25,
                   "mean_dev_km": 0.25, "max_dev_km": 0.35, "pmr_pct": 90.85, "iterations": 164,
                   "step_var_km2": 0.15, "length_km": 812.11},
    },
    "long_storm": {
        "LTV-MPC": {"snr_db": 5.09, "iterations": 189, "step_var_km2": 0.80, "length_km": 937.18, "mean_dev_km": 0.60,
                    "max_dev_km": 1.59, "remaining_km": 9.60, "median_remaining_km": 9.19},
        "Fc-MPC": {"snr_db": 5.25, "iterations": 190, "step_var_km2": 0.80, "length_km": 942.12, "mean_dev_km": 0.59,
                   "max_dev_km": 1.56, "remaining_km": 7.60, "median_remaining_km": 8.23},
    },
    "short_storm": {
        "LTV-MPC": {"snr_db": 9.93, "iterations": 171, "step_var_km2": 0.45, "length_km": 847.53, "mean_dev_km": 0.27,
                    "max_dev_km": 0.44, "remaining_km": 28.06},
        "Fc-MPC": {"snr_db": 10.06, "iterations": 167, "step_var_km2": 0.41, "length_km": 827.00, "mean_dev_km": 0.20,
                   "max_dev_km": 0.30, "remaining_km": 19.72, "median_remaining_km": 18.77},
    },
}


@dataclass(frozen=True)
class RunRow:
    """One run's result, flat for CSV."""

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
    process_model: str = ""      # the position estimator: ins, dead_reckoning or table3
    nees_mean: float = math.nan  # mean over the steps of the filter's NEES (2 when consistent)
    in_ellipse95: float = math.nan   # 1 when the final position lies inside the filter's 95 % ellipse
    sigma_end_km: float = math.nan   # the filter's own 1-sigma (per axis) at the end


# --- worker side -------------------------------------------------------------------------------
_WORKER: dict = {}


def _init_worker(scenario_ref: str | Scenario, values: dict, data_dir: str | None) -> None:
    scenario = load_scenario(scenario_ref) if isinstance(scenario_ref, str) else scenario_ref
    _WORKER["scenario"] = scenario
    _WORKER["values"] = values
    _WORKER["truth"] = {True: build_truth_field(scenario, data_dir) if scenario.storm.enabled else None,
                        False: build_truth_field(replace(scenario, storm=replace(scenario.storm, enabled=False)))}


def _snr_db(truth, lat, lon, period_s: float, alt_m: float) -> float:
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


def run_one(task: tuple[int, int, bool]) -> tuple[RunRow, np.ndarray, np.ndarray]:
    """Fly one (controller, seed, storm on/off) and measure it."""
    controller, seed, storm = task
    scenario: Scenario = _WORKER["scenario"]
    truth = _WORKER["truth"][storm]
    nav = NavConfig.from_values({**_WORKER["values"], "NAV_CONTROLLER": controller})
    started = time.perf_counter()
    result = fly_in_process(nav, scenario, seed, truth)
    wall = time.perf_counter() - started
    start, dest = (nav.start_lat_deg, nav.start_lon_deg), (nav.dest_lat_deg, nav.dest_lon_deg)
    m = track_metrics(result.true_lat_deg, result.true_lon_deg, start, dest, result.iterations)
    nees = nees_per_step(result)
    end = result.est_cov_en_m2[-1] if len(result.est_cov_en_m2) else (math.nan,) * 3
    row = RunRow(result.controller, seed, storm, result.phase, result.reason, m.iterations, m.remaining_m / 1e3,
                 m.length_m / 1e3, m.step_variance_m2 / 1e6, m.mean_deviation_m / 1e3, m.max_deviation_m / 1e3,
                 m.path_matching_rate_pct, m.final_lat_deg, m.final_lon_deg,
                 _snr_db(truth, result.true_lat_deg, result.true_lon_deg, nav.period_s, nav.alt_m), wall,
                 result.process_model, float(np.nanmean(nees)) if np.any(np.isfinite(nees)) else math.nan,
                 float(nees[-1] <= CHI2_95_2DOF) if len(nees) and math.isfinite(nees[-1]) else math.nan,
                 math.sqrt(0.5 * (end[0] + end[2])) / 1e3)
    return row, result.true_lat_deg, result.true_lon_deg


# --- summary -----------------------------------------------------------------------------------
def summarise(rows: list[RunRow], dest: tuple[float, float]) -> dict:
    """Per controller (storm runs only when a storm is flown): the table's numbers."""
    summary: dict = {}
    storm_flown = any(r.storm for r in rows)
    for name in dict.fromkeys(r.controller for r in rows):
        main = [r for r in rows if r.controller == name and r.storm == storm_flown]
        miss = np.array([r.remaining_km for r in main])
        lat, lon = mean_terminal_location([r.final_lat for r in main], [r.final_lon for r in main])
        entry = {
            "runs": len(main), "arrived": sum(r.phase == "arrived" for r in main),
            "cep_paper_km": cep_paper(miss), "cep50_km": cep50(miss),
            "terminal_lat": lat, "terminal_lon": lon,
            "mean_terminal_miss_km": geodesic_distance_m(lat, lon, *dest) / 1e3,
            "remaining_km": float(miss.mean()), "median_remaining_km": float(np.median(miss)),
            "max_remaining_km": float(miss.max()),
        }
        for key in ("mean_dev_km", "max_dev_km", "pmr_pct", "iterations", "step_var_km2", "length_km", "snr_db"):
            entry[key] = float(np.mean([getattr(r, key) for r in main]))
        # the filter's honesty: mean NEES over runs and steps, share of runs ending inside its 95 % ellipse
        nees = [r.nees_mean for r in main if math.isfinite(r.nees_mean)]
        inside = [r.in_ellipse95 for r in main if math.isfinite(r.in_ellipse95)]
        entry["nees_mean"] = float(np.mean(nees)) if nees else math.nan
        entry["ellipse95_pct"] = 100.0 * float(np.mean(inside)) if inside else math.nan
        entry["sigma_end_km"] = float(np.nanmedian([r.sigma_end_km for r in main])) if nees else math.nan
        if storm_flown:
            quiet = np.array([r.remaining_km for r in rows if r.controller == name and not r.storm])
            entry["median_remaining_quiet_km"] = float(np.median(quiet)) if len(quiet) else math.nan
        summary[name] = entry
    return summary


ROWS_QUIET = [
    ("Accuracy", None, None),
    ("CEP, eq. 59 as printed (km)", "cep_paper_km", "{:.2f}"),
    ("CEP50, median miss (km)", "cep50_km", "{:.2f}"),
    ("Terminal longitude (E deg)", "terminal_lon", "{:.3f}"),
    ("Terminal latitude (N deg)", "terminal_lat", "{:.3f}"),
    ("Mean terminal location miss (km)", "mean_terminal_miss_km", "{:.2f}"),
    ("Remaining distance, mean (km)", "remaining_km", "{:.2f}"),
    ("Remaining distance, max (km)", "max_remaining_km", "{:.2f}"),
    ("Stability", None, None),
    ("Mean deviation (km)", "mean_dev_km", "{:.2f}"),
    ("Max deviation (km)", "max_dev_km", "{:.2f}"),
    ("PMR, within 0.3 km (%)", "pmr_pct", "{:.1f}"),
    ("Efficiency", None, None),
    ("Iterations", "iterations", "{:.1f}"),
    ("Variability, step var (km^2)", "step_var_km2", "{:.3f}"),
    ("Trajectory length (km)", "length_km", "{:.1f}"),
    ("Arrived (runs)", "arrived", "{:.0f}"),
    ("Honest uncertainty (issue 14)", None, None),
    ("NEES, mean (2 if consistent)", "nees_mean", "{:.2f}"),
    ("Miss inside own 95 % ellipse (%)", "ellipse95_pct", "{:.0f}"),
    ("Own 1-sigma at the end, median (km)", "sigma_end_km", "{:.2f}"),
]
ROWS_STORM = [
    ("Signal-to-noise ratio (dB)", "snr_db", "{:.2f}"),
    ("Iterations", "iterations", "{:.1f}"),
    ("Step Var (km^2)", "step_var_km2", "{:.3f}"),
    ("Trajectory length (km)", "length_km", "{:.1f}"),
    ("Mean path deviation (km)", "mean_dev_km", "{:.2f}"),
    ("Max path deviation (km)", "max_dev_km", "{:.2f}"),
    ("Remaining distance, mean (km)", "remaining_km", "{:.2f}"),
    ("Remaining distance, median (km)", "median_remaining_km", "{:.2f}"),
    ("  same seeds, storm off, median (km)", "median_remaining_quiet_km", "{:.2f}"),
    ("Arrived (runs)", "arrived", "{:.0f}"),
    ("NEES, mean (2 if consistent)", "nees_mean", "{:.2f}"),
    ("Miss inside own 95 % ellipse (%)", "ellipse95_pct", "{:.0f}"),
]


def format_table(scenario: str, summary: dict, storm: bool) -> str:
    """The paper's table layout: 'ours (paper)' per controller."""
    names = list(summary)
    paper = PAPER.get(scenario, {})
    width = 38
    lines = [f"{'Metric':<{width}}" + "".join(f"{n + ' ours (paper)':>24}" for n in names)]
    for label, key, fmt in (ROWS_STORM if storm else ROWS_QUIET):
        if key is None:
            lines.append(label)
            continue
        cells = []
        for name in names:
            ours = fmt.format(summary[name].get(key, math.nan))
            ref = paper.get(name, {}).get(key)
            cells.append(f"{ours} ({fmt.format(ref)})" if ref is not None else f"{ours} (-)")
        lines.append(f"  {label:<{width - 2}}" + "".join(f"{c:>24}" for c in cells))
    return "\n".join(lines)


# --- plots -------------------------------------------------------------------------------------
def run_montecarlo(scenario_ref: str | Scenario, runs: int, controllers: list[int], workers: int, values: dict,
                   data_dir: str | None = None, progress: bool = True, first_seed: int = 0,
                   quiet_too: bool = True):
    """All (controller, seed[, storm off]) runs; returns (scenario, rows, tracks).

    ``scenario_ref`` is a bundled name, a TOML path or a :class:`Scenario` (e.g. with error
    sources switched); ``quiet_too`` also flies a storm scenario's seeds with the storm off.
    """
    scenario = load_scenario(scenario_ref) if isinstance(scenario_ref, str) else scenario_ref
    storm = scenario.storm.enabled
    tasks = [(c, first_seed + s, True) for c in controllers for s in range(runs)] if storm else []
    if quiet_too or not storm:
        tasks += [(c, first_seed + s, False) for c in controllers for s in range(runs)]
    rows, tracks = [], []
    if workers <= 1:
        _init_worker(scenario_ref, values, data_dir)
        results = map(run_one, tasks)
        pool = None
    else:
        pool = ProcessPoolExecutor(workers, initializer=_init_worker, initargs=(scenario_ref, values, data_dir))
        results = pool.map(run_one, tasks, chunksize=max(1, len(tasks) // (8 * workers)))
    try:
        if progress:
            from tqdm import tqdm

            results = tqdm(results, total=len(tasks), desc=scenario.name, unit="run", file=sys.stderr)
        for row, lat, lon in results:
            rows.append(row)
            tracks.append((lat, lon))
    finally:
        if pool is not None:
            pool.shutdown()
    return scenario, rows, tracks


def run_budget(real: Scenario, runs: int, workers: int, values: dict, data_dir: str | None = None,
               progress: bool = True, first_seed: int = 0) -> list[dict]:
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
        _, flown, _ = run_montecarlo(scenario, runs, [Controller.FC], workers, values, data_dir, progress,
                                     first_seed, quiet_too=False)
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
                     "median_km": float(np.median(miss)), "p90_km": float(np.percentile(miss, 90)),
                     "arrived": int(sum(r.phase == "arrived" for r in flown)), "runs": runs})
    return rows


def format_budget(rows: list[dict]) -> str:
    """The budget as a Markdown table (the README carries one from a real run)."""
    lines = ["| Error source (alone) | median abs e_D (deg) | median abs e_I (deg) | predicted abs(G^-1 e), median (km) "
             "| miss, median (km) | miss, p90 (km) | arrived |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['source']} | {r['e_decl_deg']:.4f} | {r['e_incl_deg']:.4f} | {r['predicted_km']:.1f} "
                     f"| {r['median_km']:.2f} | {r['p90_km']:.2f} | {r['arrived']}/{r['runs']} |")
    return "\n".join(lines)


def realistic_counterpart(scenario: Scenario) -> Scenario:
    """The ``*_real`` preset a scenario's error sources are switched from (itself if there is none)."""
    if scenario.name.endswith("_real"):
        return scenario
    try:
        return load_scenario(f"{scenario.name}_real")
    except ScenarioError:
        return scenario


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise ValueError(text)
    return value


_positive_int.__name__ = "integer >= 1"     # argparse names the type in its one-line error


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(prog="fcmpc-montecarlo", description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="pacific", help="bundled name or TOML path; default pacific")
    parser.add_argument("--runs", type=_positive_int, default=50, help="runs per controller; default 50")
    parser.add_argument("--controllers", default=None,
                        help="comma list of lti,ltv,fc; default all three (ltv,fc for storm scenarios)")
    parser.add_argument("--workers", type=_positive_int, default=os.cpu_count() or 1,
                        help="worker processes; default one per core")
    parser.add_argument("--first-seed", type=int, default=0, help="seed of the first run; default 0")
    parser.add_argument("--params", metavar="FILE", help="a .parm file overlaid on the defaults")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="override one parameter (repeatable)")
    parser.add_argument("--data-dir", default=None, help="real data folder; default ../shared/data")
    parser.add_argument("--out", default="out/montecarlo", help="output folder; default out/montecarlo")
    parser.add_argument("--no-plots", action="store_true")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--errors", default=None, metavar="SPEC",
                        help="switch error sources of the realistic world on (+name) or off (-name), comma "
                             "separated: heading, main_field, crustal, calibration, noise, storm, ins; 'none', 'all'")
    parser.add_argument("--heading-source", choices=("true", "ins", "magnetic"), default=None,
                        help="override the scenario's [attitude] heading_source")
    parser.add_argument("--process-model", choices=("ins", "dead_reckoning"), default=None,
                        help="the error-state filter's process model (FUS_MODEL 2 or 3); default auto (the INS here)")
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


def _run(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
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
    overrides = read_parm_file(args.params) if args.params else {}
    overrides.update(param_items(args.param))
    if args.process_model:
        overrides["FUS_MODEL"] = {"ins": 2, "dead_reckoning": 3}[args.process_model]
    values = validate_all({**scenario.nav_overrides(), **overrides})
    keys = args.controllers.split(",") if args.controllers else (["ltv", "fc"] if scenario.storm.enabled else ["lti", "ltv", "fc"])
    try:
        controllers = [CONTROLLER_KEYS[k.strip().lower()] for k in keys]
    except KeyError as err:
        parser.error(f"--controllers: unknown controller {err}; choose from {', '.join(CONTROLLER_KEYS)}")
    check_missions(values, controllers)

    if args.budget:
        started = time.perf_counter()
        budget = run_budget(real, args.runs, args.workers, values, args.data_dir, not args.quiet, args.first_seed)
        out = Path(args.out) / real.name
        out.mkdir(parents=True, exist_ok=True)
        (out / "budget.json").write_text(json.dumps({"scenario": real.name, "runs": args.runs, "rows": budget,
                                                     "wall_s": time.perf_counter() - started}, indent=2))
        print(f"\nError budget, {real.name}: Fc-MPC, {args.runs} runs per row "
              f"({time.perf_counter() - started:.0f} s wall)\n")
        print(format_budget(budget))
        print(f"results: {out / 'budget.json'}")
        return 0
    started = time.perf_counter()
    scenario, rows, tracks = run_montecarlo(scenario, args.runs, controllers, args.workers, values,
                                            args.data_dir, progress=not args.quiet, first_seed=args.first_seed)
    wall = time.perf_counter() - started
    storm = scenario.storm.enabled
    summary = summarise(rows, (scenario.dest_lat_deg, scenario.dest_lon_deg))
    out = Path(args.out) / scenario.name
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "runs.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(asdict(rows[0])))
        writer.writeheader()
        writer.writerows(asdict(r) for r in rows)
    (out / "summary.json").write_text(json.dumps({"scenario": scenario.name, "runs": args.runs, "wall_s": wall,
                                                  "parameters": values, "summary": summary,
                                                  "paper": PAPER.get(scenario.name, {})}, indent=2, default=float))
    print(f"\n{scenario.description}\n{args.runs} runs per controller, {len(rows)} missions in {wall:.1f} s wall "
          f"({args.workers} workers)\n")
    print(format_table(scenario.name, summary, storm))
    if not args.no_plots:
        written = plot_results(out, scenario, rows, tracks, storm)
        if storm:
            from sitl import storms

            truth = build_truth_field(scenario, args.data_dir)
            window = storms.StormWindow(scenario.name, *scenario.storm.window_posix)
            storms.plot_disturbance(truth.disturbance, out / "disturbance.png", window)
            written.append(out / "disturbance.png")
        print("\nplots: " + ", ".join(str(p) for p in written))
    print(f"results: {out / 'runs.csv'}, {out / 'summary.json'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_main("fcmpc-montecarlo", lambda: _run(argv), (ScenarioError,))


if __name__ == "__main__":
    sys.exit(main())
