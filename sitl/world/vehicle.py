"""Vehicle kinematics: a point mass that tracks commanded course and speed within limits.

A surface or air vehicle at about 50 km/h: speed follows the command at a bounded
acceleration, course follows at a bounded turn rate, and the position moves along the
geodesic of the current course. Pure: the caller owns time.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion import wrap_2pi, wrap_pi
from companion.nav.geo import metres_per_degree

__all__ = ["VehicleLimits", "VehicleState", "step_vehicle"]


@dataclass(frozen=True)
class VehicleLimits:
    """Kinematic limits: top speed (m/s), acceleration (m/s^2), turn rate (rad/s)."""

    max_speed_mps: float = 20.0
    accel_mps2: float = 0.5
    turn_rate_radps: float = math.radians(6.0)


@dataclass(frozen=True)
class VehicleState:
    """True state: position (deg), course over ground (rad from north, clockwise), speed (m/s)."""

    lat_deg: float
    lon_deg: float
    course_rad: float = 0.0
    speed_mps: float = 0.0
    distance_m: float = 0.0  # path length flown so far

    @property
    def vel_north_mps(self) -> float:
        return self.speed_mps * math.cos(self.course_rad)

    @property
    def vel_east_mps(self) -> float:
        return self.speed_mps * math.sin(self.course_rad)


def _approach(value: float, target: float, max_change: float) -> float:
    return target if abs(target - value) <= max_change else value + math.copysign(max_change, target - value)


def step_vehicle(state: VehicleState, dt_s: float, cmd_course_rad: float, cmd_speed_mps: float,
                 limits: VehicleLimits) -> VehicleState:
    """State after ``dt_s`` seconds of tracking the command (midpoint integration).

    Commands outside the limits are clipped; a NaN command holds the current course and
    stops the vehicle, so a bad setpoint can never move it.
    """
    if not (math.isfinite(cmd_course_rad) and math.isfinite(cmd_speed_mps)):
        cmd_course_rad, cmd_speed_mps = state.course_rad, 0.0
    target_speed = min(max(cmd_speed_mps, 0.0), limits.max_speed_mps)
    speed = _approach(state.speed_mps, target_speed, limits.accel_mps2 * dt_s)
    turn = _approach(0.0, wrap_pi(cmd_course_rad - state.course_rad), limits.turn_rate_radps * dt_s)
    course = wrap_2pi(state.course_rad + turn)
    mid_course = state.course_rad + 0.5 * turn
    step_m = 0.5 * (state.speed_mps + speed) * dt_s
    east_per_deg, north_per_deg = metres_per_degree(state.lat_deg + 0.5 * step_m * math.cos(mid_course) / 111e3)
    lat = state.lat_deg + step_m * math.cos(mid_course) / float(north_per_deg)
    lon = state.lon_deg + step_m * math.sin(mid_course) / float(east_per_deg)
    return VehicleState(lat, (lon + 180.0) % 360.0 - 180.0, course, speed, state.distance_m + step_m)
