"""The Monte Carlo's plots: trajectories (robust to a wandering run) and miss distances (Fig. 4-9).

matplotlib is imported when a plot is drawn, so workers never load it.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from companion.nav.metrics import percentile
from sitl.scenario import Scenario

__all__ = ["outlier_fence_km", "plot_results"]


def plot_results(out: Path, scenario: Scenario, rows: list, tracks: list, storm: bool) -> list[Path]:
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


def outlier_fence_km(rows: list, route_km: float) -> float:
    """Maximum path deviation beyond which a run does not set the trajectory plot's frame: the
    upper Tukey fence (Q3 + 3 IQR) of the runs' maximum deviations, at least 5 % of the route, so
    one wandering run cannot shrink the others to a sliver; such runs are drawn dotted, clipped
    and counted in the legend."""
    dev = np.array([r.max_dev_km for r in rows], dtype=float)
    dev = dev[np.isfinite(dev)]
    if dev.size == 0:
        return math.inf
    q1, q3 = percentile(dev, 0.25), percentile(dev, 0.75)
    return float(max(q3 + 3.0 * (q3 - q1), 0.05 * route_km))

