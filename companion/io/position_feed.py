"""Feeding the companion's position to a flight controller that has lost its GPS.

Without GPS, ArduPilot's EKF3 and PX4's EKF2 stop aiding: ArduPilot reports an EKF variance
failsafe within seconds and switches to HOLD. The companion then supplies its own estimate as a
MAVLink GPS (GPS_INPUT; ArduPilot ``GPS2_TYPE 14``, PX4 through its MAVLink GPS driver), so the
flight controller stays healthy and keeps executing the companion's velocity setpoints.

What the flight controller does with it (measured on ArduPilot Rover SITL, see
``../shared/ardupilot/README.md`` and the README's "Flying with ArduPilot"):

* it trusts a GPS to 100 m at best, whatever accuracy we claim, so position noise becomes
  velocity error: the fed position must be *smooth*;
* a step of a few km fails its innovation gate (a glitch, then a variance failsafe): a new
  estimate is *blended in* at ``blend_mps`` instead of stepped.

:class:`PositionFeed` is the pure part: an anchor (time, position), the velocity the vehicle is
commanded to fly, and the correction still to be blended in. ``position(t)`` is the anchor
moved by the velocity, plus the correction applied so far, which grows by at most
``blend_mps * dt`` per call. When the feed starts (GPS just lost), it starts at the flight
controller's last GPS-aided position, so there is no step at the switch-over, and blends
towards the companion's estimate from there.

Everything is in message time; positions in degrees, offsets in metres east/north.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion.nav.geo import enu_offset, offset_position

__all__ = ["FeedSample", "PositionFeed", "gps_week_time", "GPS_EPOCH_UNIX_S", "GPS_LEAP_S"]

GPS_EPOCH_UNIX_S = 315964800.0   # 1980-01-06T00:00:00Z
GPS_LEAP_S = 18.0                # GPS - UTC since 2017-01-01
WEEK_S = 604800.0


def gps_week_time(unix_s: float) -> tuple[int, int]:
    """(GPS week, milliseconds of the week) of a UNIX time.

    >>> gps_week_time(1715364000.0)   # 2024-05-10T18:00:00Z
    (2313, 496818000)
    """
    gps_s = unix_s - GPS_EPOCH_UNIX_S + GPS_LEAP_S
    week = int(gps_s // WEEK_S)
    return week, int(round((gps_s - week * WEEK_S) * 1000.0))


@dataclass(frozen=True)
class FeedSample:
    """One fed position: degrees, the 1-sigma we claim (m), and the velocity (m/s, north/east)."""

    time_s: float
    lat_deg: float
    lon_deg: float
    sigma_m: float
    vn_mps: float
    ve_mps: float


class PositionFeed:
    """A smooth position for the flight controller: anchor + velocity * t + blended correction."""

    def __init__(self, blend_mps: float = 0.5) -> None:
        if not blend_mps > 0.0:
            raise ValueError(f"blend_mps must be positive, got {blend_mps}")
        self.blend_mps = blend_mps
        self.anchor: tuple[float, float, float] | None = None    # (time, lat, lon)
        self.velocity_ne = (0.0, 0.0)
        self.applied_en = [0.0, 0.0]
        self.pending_en = [0.0, 0.0]
        self.sigma_m = math.nan
        self.last_time_s = math.nan

    @property
    def started(self) -> bool:
        return self.anchor is not None

    def start(self, time_s: float, lat_deg: float, lon_deg: float, sigma_m: float) -> None:
        """Begin at a position (the FC's last GPS-aided one) with nothing to blend yet."""
        self.anchor = (time_s, lat_deg, lon_deg)
        self.applied_en, self.pending_en = [0.0, 0.0], [0.0, 0.0]
        self.sigma_m = sigma_m
        self.last_time_s = time_s

    def stop(self) -> None:
        self.anchor = None

    def _raw(self, time_s: float) -> tuple[float, float]:
        t0, lat0, lon0 = self.anchor
        dt = time_s - t0
        east = self.velocity_ne[1] * dt + self.applied_en[0]
        north = self.velocity_ne[0] * dt + self.applied_en[1]
        lat, lon = offset_position(lat0, lon0, east, north)
        return float(lat), float(lon)

    def set_velocity(self, time_s: float, vn_mps: float, ve_mps: float) -> None:
        """Fly on with a new commanded velocity from ``time_s`` (re-anchors, no jump)."""
        if self.anchor is None:
            return
        lat, lon = self._raw(time_s)
        self.anchor = (time_s, lat, lon)
        self.applied_en = [0.0, 0.0]
        self.velocity_ne = (vn_mps if math.isfinite(vn_mps) else 0.0, ve_mps if math.isfinite(ve_mps) else 0.0)

    def correct_to(self, time_s: float, lat_deg: float, lon_deg: float, sigma_m: float) -> float:
        """The companion's estimate at ``time_s``: blend the difference in; returns its size (m)."""
        if self.anchor is None or not (math.isfinite(lat_deg) and math.isfinite(lon_deg)):
            return math.nan
        lat, lon = self._raw(time_s)
        east, north = enu_offset(lat, lon, lat_deg, lon_deg)
        self.pending_en = [float(east), float(north)]
        if math.isfinite(sigma_m):
            self.sigma_m = sigma_m
        return math.hypot(east, north)

    def sample(self, time_s: float) -> FeedSample | None:
        """The position to send at ``time_s``, blending at most ``blend_mps`` since the last call."""
        if self.anchor is None:
            return None
        dt = max(time_s - self.last_time_s, 0.0) if math.isfinite(self.last_time_s) else 0.0
        self.last_time_s = time_s
        size = math.hypot(*self.pending_en)
        if size > 0.0:
            take = min(1.0, self.blend_mps * dt / size)
            for k in (0, 1):
                self.applied_en[k] += take * self.pending_en[k]
                self.pending_en[k] -= take * self.pending_en[k]
        lat, lon = self._raw(time_s)
        return FeedSample(time_s, lat, lon, self.sigma_m, self.velocity_ne[0], self.velocity_ne[1])

    @property
    def pending_m(self) -> float:
        return math.hypot(*self.pending_en)
