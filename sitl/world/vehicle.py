"""Vehicle kinematics: a point mass that tracks commanded course and speed within limits.

A surface or air vehicle at about 50 km/h: speed follows the command at a bounded
acceleration, course follows at a bounded turn rate, and the position moves along the
geodesic of the current course. Pure: the caller owns time.

Motion errors (:class:`MotionErrors`, drawn per run from :class:`MotionErrorConfig`): what makes
the true track differ from the command on a real vehicle with GPS denied, so that dead reckoning
on the commands is not a gift. The vehicle steers its heading to the command plus
``course_bias_rad`` (a compass deviation, the autopilot's yaw error without GPS: 0.5-7 deg
measured on ArduPilot SITL), through the water at the command times ``speed_scale`` (a throttle
map without GPS: ArduPilot SITL made 7.94 m/s for 8), and the water moves by ``current_en_mps``
(the Kuroshio Extension on the Pacific route: 0.1-1 m/s). ``course_rad``/``speed_mps`` in the
state are then the heading and the speed through the water; ``vel_east/north_mps`` are over
ground. The ideal world has none of them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion import wrap_2pi, wrap_pi
from companion.nav.geo import metres_per_degree

__all__ = ["NO_MOTION_ERRORS", "MotionErrorConfig", "MotionErrors", "VehicleLimits", "VehicleState", "step_vehicle"]


@dataclass(frozen=True)
class VehicleLimits:
    """Kinematic limits: top speed (m/s), acceleration (m/s^2), turn rate (rad/s)."""

    max_speed_mps: float = 20.0
    accel_mps2: float = 0.5
    turn_rate_radps: float = math.radians(6.0)


@dataclass(frozen=True)
class MotionErrorConfig:
    """1-sigma of the per-run motion errors: the water current per axis (m/s), the speed's scale
    error (fraction) and the steering's course bias (deg). All zero: the ideal world."""

    current_mps: float = 0.0
    speed_scale_sigma: float = 0.0
    course_bias_deg: float = 0.0

    @property
    def active(self) -> bool:
        return self.current_mps > 0.0 or self.speed_scale_sigma > 0.0 or self.course_bias_deg > 0.0


@dataclass(frozen=True)
class MotionErrors:
    """One run's motion errors (see the module docstring)."""

    current_en_mps: tuple[float, float] = (0.0, 0.0)
    speed_scale: float = 1.0
    course_bias_rad: float = 0.0

    @classmethod
    def draw(cls, config: MotionErrorConfig, rng: np.random.Generator) -> MotionErrors:
        """One run's errors (none, without touching ``rng``, when ``config`` has none)."""
        if not config.active:
            return NO_MOTION_ERRORS
        current = rng.normal(0.0, 1.0, 2) * config.current_mps
        scale = 1.0 + float(rng.normal()) * config.speed_scale_sigma
        bias = math.radians(float(rng.normal()) * config.course_bias_deg)
        return cls((float(current[0]), float(current[1])), scale, bias)


NO_MOTION_ERRORS = MotionErrors()


@dataclass(frozen=True)
class VehicleState:
    """True state: position (deg), heading = course through the water (rad from north,
    clockwise), speed through the water (m/s), and the water's current (m/s, east/north)."""

    lat_deg: float
    lon_deg: float
    course_rad: float = 0.0
    speed_mps: float = 0.0
    distance_m: float = 0.0  # path length flown so far (through the water)
    current_east_mps: float = 0.0
    current_north_mps: float = 0.0

    @property
    def vel_north_mps(self) -> float:
        """Over ground."""
        return self.speed_mps * math.cos(self.course_rad) + self.current_north_mps

    @property
    def vel_east_mps(self) -> float:
        """Over ground."""
        return self.speed_mps * math.sin(self.course_rad) + self.current_east_mps


def _approach(value: float, target: float, max_change: float) -> float:
    return target if abs(target - value) <= max_change else value + math.copysign(max_change, target - value)


def step_vehicle(state: VehicleState, dt_s: float, cmd_course_rad: float, cmd_speed_mps: float,
                 limits: VehicleLimits, motion: MotionErrors = NO_MOTION_ERRORS) -> VehicleState:
    """State after ``dt_s`` seconds of tracking the command (midpoint integration), with the
    run's ``motion`` errors (none by default).

    Commands outside the limits are clipped; a NaN command holds the current course and
    stops the vehicle, so a bad setpoint can never move it.
    """
    if not (math.isfinite(cmd_course_rad) and math.isfinite(cmd_speed_mps)):
        cmd_course_rad, cmd_speed_mps = state.course_rad, 0.0
    else:
        cmd_course_rad, cmd_speed_mps = cmd_course_rad + motion.course_bias_rad, cmd_speed_mps * motion.speed_scale
    target_speed = min(max(cmd_speed_mps, 0.0), limits.max_speed_mps)
    speed = _approach(state.speed_mps, target_speed, limits.accel_mps2 * dt_s)
    turn = _approach(0.0, wrap_pi(cmd_course_rad - state.course_rad), limits.turn_rate_radps * dt_s)
    course = wrap_2pi(state.course_rad + turn)
    mid_course = state.course_rad + 0.5 * turn
    step_m = 0.5 * (state.speed_mps + speed) * dt_s
    drift_n = motion.current_en_mps[1] * dt_s     # (written so that no errors is bit-identical to before)
    north_m = step_m * math.cos(mid_course) + drift_n
    east_m = step_m * math.sin(mid_course) + motion.current_en_mps[0] * dt_s
    east_per_deg, north_per_deg = metres_per_degree(state.lat_deg + 0.5 * step_m * math.cos(mid_course) / 111e3
                                                    + 0.5 * drift_n / 111e3)
    lat = state.lat_deg + north_m / float(north_per_deg)
    lon = state.lon_deg + east_m / float(east_per_deg)
    return VehicleState(lat, (lon + 180.0) % 360.0 - 180.0, course, speed, state.distance_m + step_m,
                        *motion.current_en_mps)
