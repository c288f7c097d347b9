"""Monte Carlo of the paper's tables: the navigation core against the simulated world, in-process.

    fcmpc-montecarlo --scenario pacific --runs 50          # Table 5: LTI-, LTV-, Fc-MPC
    fcmpc-montecarlo --scenario long_storm --runs 50       # Table 6: LTV- vs Fc-MPC
    fcmpc-montecarlo --scenario short_storm --runs 50      # Table 7

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
from sitl.inprocess import fly_in_process
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


# --- worker side -------------------------------------------------------------------------------
_WORKER: dict = {}


def _init_worker(scenario_ref: str, values: dict, data_dir: str | None) -> None:
    scenario = load_scenario(scenario_ref)
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
    row = RunRow(result.controller, seed, storm, result.phase, result.reason, m.iterations, m.remaining_m / 1e3,
                 m.length_m / 1e3, m.step_variance_m2 / 1e6, m.mean_deviation_m / 1e3, m.max_deviation_m / 1e3,
                 m.path_matching_rate_pct, m.final_lat_deg, m.final_lon_deg,
                 _snr_db(truth, result.true_lat_deg, result.true_lon_deg, nav.period_s, nav.alt_m), wall)
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
def plot_results(out: Path, scenario: Scenario, rows: list[RunRow], tracks: list, storm: bool) -> list[Path]:
    """Trajectories on a lon/lat map (Fig. 4/7/9) and box plots (Fig. 6/8)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from companion.nav.geo import WGS84

    written = []
    names = list(dict.fromkeys(r.controller for r in rows))
    fig, ax = plt.subplots(figsize=(7, 6))
    line = WGS84.InverseLine(scenario.start_lat_deg, scenario.start_lon_deg, scenario.dest_lat_deg, scenario.dest_lon_deg)
    geo = [line.Position(s) for s in np.linspace(0, line.s13, 200)]
    geo_lon, geo_lat = np.array([p["lon2"] for p in geo]), np.array([p["lat2"] for p in geo])
    ax.plot(geo_lon, geo_lat, "k--", lw=1, label="geodesic")
    shown = [(r, t) for r, t in zip(rows, tracks) if r.storm == storm]
    fence = outlier_fence_km([r for r, _ in shown], line.s13 / 1000.0)
    inside = [t for r, t in shown if r.max_dev_km <= fence]
    lon_all = np.concatenate([geo_lon] + [np.asarray(t[1]) for t in inside])
    lat_all = np.concatenate([geo_lat] + [np.asarray(t[0]) for t in inside])
    colours = dict(zip(names, ("tab:red", "tab:blue", "tab:green")))
    for name in names:
        runs = [(r, t) for r, t in shown if r.controller == name]
        best = min(runs, key=lambda rt: rt[0].remaining_km)
        far = [r for r, _ in runs if r.max_dev_km > fence]
        for run, (lat, lon) in runs:
            ax.plot(lon, lat, color=colours[name], lw=0.4, alpha=0.25, ls=":" if run.max_dev_km > fence else "-")
        ax.plot(best[1][1], best[1][0], color=colours[name], lw=1.5, label=f"{name} (best of {len(runs)})")
        if far:
            ax.plot([], [], color=colours[name], lw=0.8, ls=":",
                    label=f"{name}: {len(far)} run(s) beyond the frame (max deviation up to "
                          f"{max(r.max_dev_km for r in far):.0f} km)")
    ax.plot(scenario.start_lon_deg, scenario.start_lat_deg, "ko")
    ax.plot(scenario.dest_lon_deg, scenario.dest_lat_deg, "k*", ms=12)
    pad_lon, pad_lat = 0.05 * np.ptp(lon_all) + 0.01, 0.05 * np.ptp(lat_all) + 0.01
    ax.set_xlim(lon_all.min() - pad_lon, lon_all.max() + pad_lon)
    ax.set_ylim(lat_all.min() - pad_lat, lat_all.max() + pad_lat)
    ax.set_xlabel("longitude (deg E)")
    ax.set_ylabel("latitude (deg N)")
    ax.set_title(f"{scenario.name}: trajectories (frame: runs within {fence:.0f} km of the geodesic)", fontsize=10)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    written.append(out / "trajectories.png")
    fig.savefig(written[-1], dpi=120)
    plt.close(fig)

    fig, axes = plt.subplots(1, 4, figsize=(14, 4))
    for ax, (key, label) in zip(axes, (("iterations", "iterations"), ("step_var_km2", "step variance (km^2)"),
                                       ("length_km", "trajectory length (km)"), ("remaining_km", "remaining (km)"))):
        ax.boxplot([[getattr(r, key) for r in rows if r.controller == n and r.storm == storm] for n in names])
        ax.set_xticks(range(1, len(names) + 1), names)
        ax.set_title(label)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{scenario.name}: {sum(1 for r in rows if r.storm == storm) // len(names)} Monte Carlo runs")
    fig.tight_layout()
    written.append(out / "boxplots.png")
    fig.savefig(written[-1], dpi=120)
    plt.close(fig)
    return written


def outlier_fence_km(rows: list[RunRow], route_km: float) -> float:
    """Maximum path deviation beyond which a run does not set the trajectory plot's frame: the
    upper Tukey fence (Q3 + 3 IQR) of the runs' maximum deviations, at least 5 % of the route, so
    one wandering run cannot shrink the others to a sliver; such runs are drawn dotted, clipped
    and counted in the legend."""
    dev = np.array([r.max_dev_km for r in rows], dtype=float)
    dev = dev[np.isfinite(dev)]
    if dev.size == 0:
        return math.inf
    q1, q3 = np.percentile(dev, [25, 75])
    return float(max(q3 + 3.0 * (q3 - q1), 0.05 * route_km))


# --- main --------------------------------------------------------------------------------------
def run_montecarlo(scenario_ref: str, runs: int, controllers: list[int], workers: int, values: dict,
                   data_dir: str | None = None, progress: bool = True, first_seed: int = 0):
    """All (controller, seed[, storm off]) runs; returns (rows, tracks)."""
    scenario = load_scenario(scenario_ref)
    tasks = [(c, first_seed + s, True) for c in controllers for s in range(runs)] if scenario.storm.enabled else []
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
    overrides = read_parm_file(args.params) if args.params else {}
    overrides.update(param_items(args.param))
    values = validate_all({**scenario.nav_overrides(), **overrides})
    keys = args.controllers.split(",") if args.controllers else (["ltv", "fc"] if scenario.storm.enabled else ["lti", "ltv", "fc"])
    try:
        controllers = [CONTROLLER_KEYS[k.strip().lower()] for k in keys]
    except KeyError as err:
        parser.error(f"--controllers: unknown controller {err}; choose from {', '.join(CONTROLLER_KEYS)}")
    check_missions(values, controllers)

    started = time.perf_counter()
    scenario, rows, tracks = run_montecarlo(args.scenario, args.runs, controllers, args.workers, values,
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
