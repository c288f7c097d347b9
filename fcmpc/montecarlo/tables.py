"""The paper's tables beside ours: per-controller summaries of Monte Carlo runs (Tables 5-7).

:func:`summarise` reduces a scenario's :class:`~fcmpc.montecarlo.runs.RunRow` s to the numbers of the
paper's tables (CEP as eq. 59 prints it and CEP50, terminal location, deviations, PMR,
iterations, step variance, length, SNR); :func:`format_table` lays them out as "ours (paper)".
"""
from __future__ import annotations

import math

import numpy as np

from companion.nav.geo import geodesic_distance_m
from companion.nav.metrics import cep50, cep_paper, mean_terminal_location
from fcmpc.montecarlo.runs import RunRow

__all__ = ["PAPER", "format_table", "summarise"]

# The paper's figures (Tables 5-7, and the medians of Section 4.2's text), for the side-by-side.
PAPER = {
    "paper_pacific": {
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
    "paper_long_storm": {
        "LTV-MPC": {"snr_db": 5.09, "iterations": 189, "step_var_km2": 0.80, "length_km": 937.18, "mean_dev_km": 0.60,
                    "max_dev_km": 1.59, "remaining_km": 9.60, "median_remaining_km": 9.19},
        "Fc-MPC": {"snr_db": 5.25, "iterations": 190, "step_var_km2": 0.80, "length_km": 942.12, "mean_dev_km": 0.59,
                   "max_dev_km": 1.56, "remaining_km": 7.60, "median_remaining_km": 8.23},
    },
    "paper_short_storm": {
        "LTV-MPC": {"snr_db": 9.93, "iterations": 171, "step_var_km2": 0.45, "length_km": 847.53, "mean_dev_km": 0.27,
                    "max_dev_km": 0.44, "remaining_km": 28.06},
        "Fc-MPC": {"snr_db": 10.06, "iterations": 167, "step_var_km2": 0.41, "length_km": 827.00, "mean_dev_km": 0.20,
                   "max_dev_km": 0.30, "remaining_km": 19.72, "median_remaining_km": 18.77},
    },
}


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
    ("Predicted before flying (issue 46)", None, None),
    ("Predicted 95 % radius at arrival (km)", "pred_r95_km", "{:.2f}"),
    ("Miss inside predicted 95 % (%)", "pred95_pct", "{:.0f}"),
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
    ("Predicted 95 % radius at arrival (km)", "pred_r95_km", "{:.2f}"),
    ("Miss inside predicted 95 % (%)", "pred95_pct", "{:.0f}"),
]


def add_prediction(summary: dict, rows: list[RunRow], name: str, r95_m: float | None) -> None:
    """The prediction made before flying (:mod:`companion.nav.prediction`) beside what the runs
    did: its 95 % radius and the share of ``name``'s runs whose miss at rest fell inside it.
    ``r95_m`` None: each run's own (``told_r95_km``, what a flown run's companion said), the
    radius shown their median."""
    mine = [r for r in rows if r.controller == name and r.storm == any(x.storm for x in rows)]
    radii_km = [r.told_r95_km if r95_m is None else r95_m / 1e3 for r in mine]
    if name not in summary or not mine or not all(math.isfinite(k) for k in radii_km):
        return
    summary[name]["pred_r95_km"] = float(np.median(radii_km))
    summary[name]["pred95_pct"] = 100.0 * float(np.mean([r.remaining_km <= k for r, k in zip(mine, radii_km)]))


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


