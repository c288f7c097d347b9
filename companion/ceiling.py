"""The safety ceiling: limits fixed at start that nothing received over the link can raise.

Issue 10: from a stranger's system id, PARAM_SET NAV_SPEED_KMH 300 made the companion send 83 m/s
setpoints (the setpoint guard followed that parameter), failsafe timeouts of 60 s were accepted,
and a new destination redirected the vehicle. The ceiling is read once, from the ``.parm`` file
(or the command line) at start, from the start-up-only parameters of :mod:`companion.params`:

==================  ===============================================================================
SAFE_SPEED_KMH      no setpoint faster, whatever NAV_SPEED_KMH says (the link's setpoint guard uses
                    this, :attr:`SafetyCeiling.speed_mps`); sets of NAV_SPEED_KMH or MPC_U_MAX_KMH
                    above it are refused
SAFE_TMO_S          the longest failsafe timeout: COMP_MAG/ATT/HB_TMO_S above it act as it
                    (:class:`companion.params.CompanionConfig`), and sets above it are refused
SAFE_FENCE_KM       start and destination set over the link must lie within this distance of the
                    start-up route (the geodesic from NAV_START to NAV_DEST at start); 0 turns it off
LINK_GCS_ID1/ID2    the ground-station system ids whose (signed, when signing is on) PARAM_SETs count
==================  ===============================================================================

Start-up-only parameters themselves are served (a ground station can read them) but never set
over the link.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from geographiclib.geodesic import Geodesic

from companion.params import SPEC_BY_NAME

__all__ = ["SafetyCeiling", "distance_to_route_m"]

_KMH = 1.0 / 3.6
_SPEED_NAMES = ("NAV_SPEED_KMH", "MPC_U_MAX_KMH")
_TIMEOUT_NAMES = ("COMP_MAG_TMO_S", "COMP_ATT_TMO_S", "COMP_HB_TMO_S")
_POSITION_NAMES = {"NAV_START_LAT": ("NAV_START", 0), "NAV_START_LON": ("NAV_START", 1),
                   "NAV_DEST_LAT": ("NAV_DEST", 0), "NAV_DEST_LON": ("NAV_DEST", 1)}


def distance_to_route_m(lat_deg: float, lon_deg: float, route: tuple[float, float, float, float]) -> float:
    """Geodesic distance (m) from a point to the route segment (start lat, lon, dest lat, lon), within
    about 1 % of the route's length plus 1 km (points every 1/200 of the route, at most 50 km apart).

    >>> round(distance_to_route_m(33.0, 152.0, (33.0, 152.0, 28.0, 158.0)))
    0
    """
    geod = Geodesic.WGS84
    line = geod.InverseLine(route[0], route[1], route[2], route[3])
    count = max(2, min(2000, int(math.ceil(line.s13 / 50_000.0)), 200))
    best = math.inf
    for k in range(count + 1):
        pos = line.Position(line.s13 * k / count)
        best = min(best, geod.Inverse(lat_deg, lon_deg, pos["lat2"], pos["lon2"])["s12"])
    return best


@dataclass(frozen=True)
class SafetyCeiling:
    """Start-up limits (SI): speed, longest failsafe timeout, fence around the route, allowed GCS ids."""

    speed_mps: float
    timeout_s: float
    fence_m: float
    route: tuple[float, float, float, float]
    gcs_sysids: frozenset[int]

    @classmethod
    def from_values(cls, values: Mapping[str, float]) -> SafetyCeiling:
        """The ceiling of the parameter values read at start (validated values of the registry)."""
        def get(name: str) -> float:
            return float(values.get(name, SPEC_BY_NAME[name].default))

        route = (get("NAV_START_LAT"), get("NAV_START_LON"), get("NAV_DEST_LAT"), get("NAV_DEST_LON"))
        ids = frozenset(int(get(n)) for n in ("LINK_GCS_ID1", "LINK_GCS_ID2")) - {0}
        return cls(get("SAFE_SPEED_KMH") * _KMH, get("SAFE_TMO_S"), get("SAFE_FENCE_KM") * 1e3, route, ids)

    def refusal(self, name: str, value: float, values: Mapping[str, float]) -> str | None:
        """Why a PARAM_SET of ``name`` to ``value`` (already range-checked) must be refused, or None."""
        spec = SPEC_BY_NAME.get(name)
        if spec is None:
            return None
        if spec.boot_only:
            return "start-up only"
        if name in _SPEED_NAMES and value * _KMH > self.speed_mps * (1.0 + 1e-6):
            return f"> SAFE_SPEED_KMH {self.speed_mps / _KMH:g}"
        if name in _TIMEOUT_NAMES and value > self.timeout_s * (1.0 + 1e-6):
            return f"> SAFE_TMO_S {self.timeout_s:g}"
        if name in _POSITION_NAMES and self.fence_m > 0.0:
            prefix, axis = _POSITION_NAMES[name]
            lat = value if axis == 0 else float(values[f"{prefix}_LAT"])
            lon = value if axis == 1 else float(values[f"{prefix}_LON"])
            if distance_to_route_m(lat, lon, self.route) > self.fence_m:
                return f"outside SAFE_FENCE_KM {self.fence_m / 1e3:g}"
        return None
