"""The crustal anomaly along a route: what the crust adds to F, D and I, and what the navigator's map misses.

:func:`route_anomaly` samples the start-destination geodesic (and, if given, a flown track) and
returns, per point, the distance along the route and two differences of the elements
(total intensity F in nT, declination D and inclination I in degrees, signs per :mod:`companion`):

* ``crust``: the truth with its crust minus the truth without (the real crust of EMM2017 and
  the seeded anomaly field, whichever the world has);
* ``map_error``: the quiet truth minus the navigator's map (WMM or WMMHR, NAV_MAP), when the
  map is given: what a fix on that map reads as position error.

:func:`plot_crust_anomaly` draws both, three panels, beside the track plots of ``fcmpc-fly``
and ``fcmpc-montecarlo`` (``crust_anomaly.png``). matplotlib is imported only to draw.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from sitl.world.magnetic import TruthField, decl_incl_from_ned

__all__ = ["RouteAnomaly", "plot_crust_anomaly", "route_anomaly", "write_route_anomaly"]


@dataclass(frozen=True)
class RouteAnomaly:
    """Element differences along a route: ``distance_km`` (n,), and (n, 3) arrays of
    (dF nT, dD deg, dI deg) for ``crust`` and ``map_error`` (None without a map)."""

    distance_km: np.ndarray
    crust: np.ndarray
    map_error: np.ndarray | None
    map_name: str = ""


def _elements(ned: np.ndarray) -> np.ndarray:
    decl, incl = decl_incl_from_ned(ned[..., 0], ned[..., 1], ned[..., 2])
    return np.stack([np.linalg.norm(ned, axis=-1), decl, incl], axis=-1)


def _difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = a - b
    out[..., 1] = (out[..., 1] + 180.0) % 360.0 - 180.0   # D wraps
    return out


def route_anomaly(truth: TruthField, start: tuple[float, float], destination: tuple[float, float], alt_m: float,
                  map_model=None, points: int = 400) -> RouteAnomaly:
    """The crust's and the map's differences at ``points`` points of the geodesic (module docstring)."""
    from companion.nav.geo import WGS84

    line = WGS84.InverseLine(start[0], start[1], destination[0], destination[1])
    along = np.linspace(0.0, line.s13, points)
    positions = [line.Position(s) for s in along]
    lat = np.array([p["lat2"] for p in positions])
    lon = np.array([p["lon2"] for p in positions])
    quiet = replace(truth, disturbance=None)
    main = quiet.main_ned_nt(lat, lon, alt_m)
    with_crust = _elements(main + quiet.crust_ned_nt(lat, lon, alt_m))
    crust = _difference(with_crust, _elements(main))
    map_error = None
    name = ""
    if map_model is not None:
        mapped = np.stack(np.broadcast_arrays(*map_model.ned(lat, lon, alt_m, truth.year)), axis=-1)
        map_error = _difference(with_crust, _elements(mapped))
        name = map_model.name
    return RouteAnomaly(along / 1000.0, crust, map_error, name)


def plot_crust_anomaly(path: str | Path, anomaly: RouteAnomaly, title: str = "") -> Path:
    """Three panels (dF, dD, dI) against the distance along the route; written to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(8.0, 7.5), sharex=True)
    for k, (ax, label) in enumerate(zip(axes, ("dF (nT)", "dD (deg)", "dI (deg)"))):
        ax.plot(anomaly.distance_km, anomaly.crust[:, k], color="tab:brown", lw=1.2, label="crust (truth minus its main field)")
        if anomaly.map_error is not None:
            ax.plot(anomaly.distance_km, anomaly.map_error[:, k], color="tab:blue", lw=1.0, alpha=0.8,
                    label=f"truth minus the navigator's map ({anomaly.map_name})")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("distance along the route (km)")
    fig.suptitle(title or "crustal anomaly along the route", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_route_anomaly(path: str | Path, scenario, values: dict, data_dir=None) -> Path:
    """:func:`plot_crust_anomaly` of ``scenario``'s route and world (seed 0's seeded field, if
    any), against the map the navigator's parameter ``values`` choose (NAV_YEAR, NAV_WMM,
    NAV_MAP; the scenario's date without them): the one call of the tools."""
    from companion.nav.wmm import model_for_setting
    from sitl.world.build import build_truth_field

    truth = build_truth_field(scenario, data_dir)
    year = float(values.get("NAV_YEAR", scenario.year))
    map_model = model_for_setting(year, int(values.get("NAV_WMM", 0)), int(values.get("NAV_MAP", 0)))
    anomaly = route_anomaly(truth, (scenario.start_lat_deg, scenario.start_lon_deg),
                            (scenario.dest_lat_deg, scenario.dest_lon_deg), scenario.alt_m, map_model)
    return plot_crust_anomaly(path, anomaly, f"{scenario.name}: crustal anomaly along the route, and what "
                                             f"{map_model.name} misses")
