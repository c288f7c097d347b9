"""The track plot of one closed-loop run: what happened, at the scale where it happened.

Four panels: (a) the whole route (geodesic, true track, the flight controller's drifting INS,
the companion's estimates) in lon/lat; (b) the destination zoomed in, east/north in km, with the
true position at the last control step, where the vehicle came to rest and what the companion
believed; (c) cross-track error against time: distance of the true track and of the estimates
to the start-destination geodesic (:func:`companion.nav.metrics.path_deviation_m`); (d) the
estimate's error (estimate minus truth at each control step) and the INS error against time.
The title says how the run ended; a failed, interrupted or timed-out run says so, in km.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from companion.nav.geo import enu_offset
from companion.nav.metrics import path_deviation_m
from fcmpc.fly.results import FlyResult, TruthTrack

__all__ = ["plot_track", "title_for"]

MAX_POINTS = 2000        # truth points used for the error panels (the track is subsampled)
ZOOM_MIN_HALF_M = 1000.0


def _km(metres: float) -> str:
    return f"{metres / 1000.0:.2f} km" if math.isfinite(metres) else "unknown"


def title_for(result: FlyResult, name: str) -> str:
    """One line for the figure: how the run ended and the three distances, in km."""
    rest = _km(result.rest_remaining_m)
    if result.status == "arrived":
        where = "came to rest" if result.came_to_rest else "last seen (still moving)"
        return (f"{name}: arrived, {where} {rest} from the destination "
                f"(last step {_km(result.step_remaining_m)}, companion believed {_km(result.believed_remaining_m)})")
    what = {"interrupted": "INTERRUPTED", "timeout": "TIMED OUT", "failed": "FAILED"}.get(result.status, "ERROR")
    return f"{name}: {what} after {result.iterations} steps, {rest} from the destination"


def plot_track(path: str | Path, start: tuple[float, float], dest: tuple[float, float], truth: TruthTrack,
               steps: list[dict], result: FlyResult, name: str = "") -> Path:
    """Write the four-panel PNG (see the module docstring) to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from geographiclib.geodesic import Geodesic

    fig, axes = plt.subplots(2, 2, figsize=(12.0, 9.5), dpi=100)
    (ax_map, ax_zoom), (ax_xte, ax_err) = axes
    line = Geodesic.WGS84.InverseLine(start[0], start[1], *dest)
    geo = [line.Position(line.s13 * k / 200) for k in range(201)]
    est = np.array([(r["msg_time_s"], r["est_lat_deg"], r["est_lon_deg"]) for r in steps
                    if math.isfinite(r["est_lat_deg"]) and math.isfinite(r["est_lon_deg"])]).reshape(-1, 3)

    # (a) the whole route
    ax_map.plot([g["lon2"] for g in geo], [g["lat2"] for g in geo], "k--", lw=0.8, label="geodesic")
    if truth.fc_lon_deg is not None:
        ax_map.plot(truth.fc_lon_deg, truth.fc_lat_deg, color="0.6", lw=0.8, label="FC INS (drifting)")
    ax_map.plot(truth.lon_deg, truth.lat_deg, color="tab:blue", lw=1.4, label="true track")
    if len(est):
        ax_map.plot(est[:, 2], est[:, 1], ".", color="tab:orange", ms=3, label="companion estimate")
    ax_map.plot(start[1], start[0], "g^", ms=9, label="start")
    ax_map.plot(dest[1], dest[0], "r*", ms=12, label="destination")
    ax_map.set_xlabel("longitude (deg)")
    ax_map.set_ylabel("latitude (deg)")
    ax_map.set_aspect(1.0 / math.cos(math.radians(0.5 * (start[0] + dest[0]))))
    ax_map.set_title("(a) route", fontsize=9)
    ax_map.legend(loc="best", fontsize=7)

    # (b) the destination, east/north km
    e_t, n_t = (np.asarray(v) / 1000.0 for v in enu_offset(dest[0], dest[1], truth.lat_deg, truth.lon_deg))
    rest = (e_t[-1], n_t[-1])
    marks = [rest]
    ax_zoom.plot(e_t, n_t, color="tab:blue", lw=1.4, label="true track")
    if steps:
        step_pos = truth.position_at(steps[-1]["msg_time_s"])
        e_s, n_s = (float(v) / 1000.0 for v in enu_offset(dest[0], dest[1], *step_pos))
        ax_zoom.plot(e_s, n_s, "bs", ms=7, mfc="none", label="true, last control step")
        marks.append((e_s, n_s))
    if len(est):
        e_e, n_e = (np.asarray(v) / 1000.0 for v in enu_offset(dest[0], dest[1], est[:, 1], est[:, 2]))
        ax_zoom.plot(e_e, n_e, ".", color="tab:orange", ms=4, label="companion estimate")
        ax_zoom.plot(e_e[-1], n_e[-1], "o", color="tab:orange", ms=8, mfc="none", label="believed at last step")
        marks.append((e_e[-1], n_e[-1]))
    ax_zoom.plot(*rest, "bo", ms=7, label="at rest" if result.came_to_rest else "last seen (moving)")
    ax_zoom.plot(0.0, 0.0, "r*", ms=14, label="destination")
    half = max(ZOOM_MIN_HALF_M / 1000.0, 1.3 * max(math.hypot(*m) for m in marks))
    ax_zoom.set_xlim(-half, half)
    ax_zoom.set_ylim(-half, half)
    ax_zoom.set_aspect("equal")
    ax_zoom.set_xlabel("east of the destination (km)")
    ax_zoom.set_ylabel("north of the destination (km)")
    ax_zoom.set_title("(b) the destination", fontsize=9)
    ax_zoom.legend(loc="best", fontsize=7)

    # (c) cross-track error, (d) estimate and INS error, against time (h)
    every = max(1, len(truth) // MAX_POINTS)
    t_h = truth.time_s[::every] / 3600.0
    ax_xte.plot(t_h, path_deviation_m(truth.lat_deg[::every], truth.lon_deg[::every], start, dest) / 1000.0,
                color="tab:blue", lw=1.2, label="true track")
    if len(est):
        ax_xte.plot(est[:, 0] / 3600.0, path_deviation_m(est[:, 1], est[:, 2], start, dest) / 1000.0, ".",
                    color="tab:orange", ms=4, label="companion estimate")
        true_at = np.array([truth.position_at(t) for t in est[:, 0]])
        e_err, n_err = enu_offset(start[0], start[1], est[:, 1], est[:, 2])
        e_tru, n_tru = enu_offset(start[0], start[1], true_at[:, 0], true_at[:, 1])
        error = np.hypot(np.asarray(e_err) - e_tru, np.asarray(n_err) - n_tru) / 1000.0
        ax_err.plot(est[:, 0] / 3600.0, error, "o-", color="tab:orange", ms=3, lw=0.8, label="companion estimate")
    if truth.fc_lat_deg is not None:
        e_fc, n_fc = enu_offset(start[0], start[1], truth.fc_lat_deg[::every], truth.fc_lon_deg[::every])
        e_tr, n_tr = enu_offset(start[0], start[1], truth.lat_deg[::every], truth.lon_deg[::every])
        ax_err.plot(t_h, np.hypot(np.asarray(e_fc) - e_tr, np.asarray(n_fc) - n_tr) / 1000.0, color="0.6", lw=0.8,
                    label="FC INS")
    ax_xte.set_ylabel("distance to the geodesic (km)")
    ax_xte.set_title("(c) cross-track error", fontsize=9)
    ax_err.set_ylabel("position error (km)")
    ax_err.set_title("(d) estimate error", fontsize=9)
    for ax in (ax_xte, ax_err):
        ax.set_xlabel("simulated time (h)")
        ax.legend(loc="best", fontsize=7)
    for ax in axes.flat:
        ax.grid(True, lw=0.3)
    fig.suptitle(title_for(result, name), fontsize=10, color="black" if result.status == "arrived" else "tab:red")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path)
