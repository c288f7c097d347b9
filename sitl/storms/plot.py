"""Plot of each station's storm deviation (paper Fig. 5), with the INTERMAGNET acknowledgement.

matplotlib is imported when the function is called, so reading storms never needs it.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sitl.storms.common import ACKNOWLEDGEMENT, SUDDEN_COMMENCEMENT_S, StormWindow
from sitl.storms.deviation import eq64_dbh_nt
from sitl.storms.disturbance import StormDisturbance

if TYPE_CHECKING:  # matplotlib is imported lazily by plot_disturbance only
    from matplotlib.figure import Figure

__all__ = ["plot_disturbance"]

def plot_disturbance(
    disturbance: StormDisturbance,
    path_png: str | os.PathLike[str],
    window: StormWindow | tuple[float, float] | None = None,
    *,
    margin_s: float = 0.0,
    acknowledgement: str = ACKNOWLEDGEMENT,
) -> Figure:
    """Plot each station's dH (eq.-64 dB_H dashed), dX, dY, dZ vs UTC over a window (paper Fig. 5).

    ``window``: a :class:`StormWindow`, ``(start_s, end_s)`` POSIX UTC, or None for the whole
    data span; ``margin_s`` widens the plotted span on both sides (the window is shaded).

    Values are the station deviations times ``disturbance.scale`` (what the simulated
    vehicle would meet at the station); the x axis is storm time (UTC). The figure carries
    ``acknowledgement`` (default :data:`ACKNOWLEDGEMENT`, May 2024's; a library storm's is its row's). Writes ``path_png`` (parents created) and returns the Figure.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    import matplotlib.dates as mdates

    if window is None:
        win = StormWindow("data", *disturbance.time_range_s)
    elif isinstance(window, StormWindow):
        win = window
    else:
        win = StormWindow("window", float(window[0]), float(window[1]))
    t0, t1 = win.start_s - margin_s, win.end_s + margin_s
    fig = Figure(figsize=(10.0, 9.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(4, 1, sharex=True)
    labels = ("dH = H - H0 (nT)", "dX north (nT)", "dY east (nT)", "dZ down (nT)")
    for s in disturbance.stations:
        sel = (s.time_s >= t0) & (s.time_s <= t1)
        if not sel.any():
            continue
        when = s.time_s[sel].astype("datetime64[s]")
        k = disturbance.scale
        (line,) = axes[0].plot(when, k * s.dh_nt[sel], lw=0.9, label=f"{s.code} ({s.lat_deg:.1f}, {s.lon_deg:.1f})")
        axes[0].plot(when, k * eq64_dbh_nt(s.dx_nt[sel], s.dy_nt[sel]), lw=0.6, ls="--", color=line.get_color())
        for ax, comp in zip(axes[1:], (s.dx_nt, s.dy_nt, s.dz_nt)):
            ax.plot(when, k * comp[sel], lw=0.9, color=line.get_color())
    for ax, label in zip(axes, labels):
        ax.set_ylabel(label)
        ax.grid(True, lw=0.3)
        if margin_s > 0.0:  # mark the window itself inside the margins
            ax.axvspan(np.datetime64(int(win.start_s), "s"), np.datetime64(int(win.end_s), "s"), color="0.92", zorder=0)
        if t0 <= SUDDEN_COMMENCEMENT_S <= t1:
            ax.axvline(np.datetime64(int(SUDDEN_COMMENCEMENT_S), "s"), color="k", lw=0.6, ls=":")
    axes[0].legend(fontsize=8, ncol=3, title="station (lat, lon); dashed: eq. 64 dB_H", title_fontsize=8)
    axes[-1].set_xlabel("UTC")
    axes[-1].xaxis.set_major_formatter(mdates.DateFormatter("%m-%d %H:%M"))
    scale_txt = "" if disturbance.scale == 1.0 else f", scale {disturbance.scale:g}"
    fig.suptitle(f"Storm disturbance from quiet baseline - {win}{scale_txt}", fontsize=10)
    fig.supxlabel(acknowledgement, fontsize=8, x=0.01, ha="left")  # laid out below the axes
    path = Path(path_png)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return fig
