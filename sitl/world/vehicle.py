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

The start (:func:`true_start`): the navigator is given the start a GPS fix reported before take-off;
the vehicle is truly one receiver error (``gps_noise_m`` per axis, 1 sigma) away from it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion import wrap_2pi, wrap_pi
from companion.nav.geo import metres_per_degree, offset_position
from sitl.world.checks import require

__all__ = ["MOTION_STREAM", "NO_MOTION_ERRORS", "MotionErrorConfig", "MotionErrors", "VehicleLimits", "VehicleState",
           "move", "seed_motion_errors", "step_vehicle", "true_start"]


def true_start(lat_deg: float, lon_deg: float, gps_noise_m: float, rng: np.random.Generator) -> tuple[float, float]:
    """Where the vehicle truly is when the navigator is told it starts at (``lat_deg``, ``lon_deg``), a
    GPS fix: that fix less a receiver error drawn east and north with ``gps_noise_m`` (1 sigma, m).
    Without noise, the fix itself (``rng`` untouched).

    >>> true_start(33.0, 152.0, 0.0, np.random.default_rng(0))
    (33.0, 152.0)
    """
    if not gps_noise_m > 0.0:
        return lat_deg, lon_deg
    east_m, north_m = rng.normal(0.0, gps_noise_m, 2)
    lat, lon = offset_position(lat_deg, lon_deg, -east_m, -north_m)
    return float(lat), float(lon)


@dataclass(frozen=True)
class VehicleLimits:
    """Kinematic limits: top speed (m/s), acceleration (m/s^2), turn rate (rad/s)."""

    max_speed_mps: float = 20.0
    accel_mps2: float = 0.5
    turn_rate_radps: float = math.radians(6.0)

    def __post_init__(self) -> None:   # a vehicle that cannot move or turn flies nothing
        require(self, ("max_speed_mps", "accel_mps2", "turn_rate_radps"), lambda v: v > 0.0, "finite and positive")


@dataclass(frozen=True)
class MotionErrorConfig:
    """1-sigma of the per-run motion errors: the water current per axis (m/s), the speed's scale
    error (fraction) and the steering's course bias (deg). All zero: the ideal world."""

    current_mps: float = 0.0
    speed_scale_sigma: float = 0.0
    course_bias_deg: float = 0.0

    def __post_init__(self) -> None:
        require(self, ("current_mps", "speed_scale_sigma", "course_bias_deg"), lambda v: v >= 0.0,
                "finite and not negative (a 1-sigma)")

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

MOTION_STREAM = 6
"""The motion errors' stream among a run's ``numpy.random.SeedSequence(seed).spawn(n)`` streams: the
in-process flight's and the stand-in's [6] (:mod:`fcmpc.montecarlo.inprocess`, :mod:`sitl.fc.server`)."""


def seed_motion_errors(config: MotionErrorConfig, seed: int) -> MotionErrors:
    """Run ``seed``'s motion errors, the same in every world that flies the seed: the in-process
    flight, the stand-in and our world as a firmware's physics (a seed's current drawn anywhere else
    is another current, and the runs of one seed stop being comparable).

    >>> [round(v, 3) for v in seed_motion_errors(MotionErrorConfig(current_mps=0.3), 1006).current_en_mps]
    [-0.136, -0.232]
    """
    stream = np.random.SeedSequence(seed).spawn(MOTION_STREAM + 1)[MOTION_STREAM]
    return MotionErrors.draw(config, np.random.default_rng(stream))


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


MAX_PIECE_TURN_RAD = math.radians(15.0)   # longest arc moved in one piece (chord error < 0.1 %)


def step_vehicle(state: VehicleState, dt_s: float, cmd_course_rad: float, cmd_speed_mps: float,
                 limits: VehicleLimits, motion: MotionErrors = NO_MOTION_ERRORS) -> VehicleState:
    """State after ``dt_s`` seconds of tracking the command, with the run's ``motion`` errors
    (none by default).

    Speed and course change at their limits until they reach the command, then hold: the step is
    split where either reaches it, and each piece moves its mean speed's distance along an arc
    (the chord along its mid course; a long turn in arcs of at most 15 deg). Unsplit, a 30 s step
    from 6.6 m/s to a stop moved 106 m where the vehicle, stopped after 13 s, moves 44 m.

    Commands outside the limits are clipped; a NaN command holds the current course and
    stops the vehicle, so a bad setpoint can never move it.
    """
    if not (math.isfinite(cmd_course_rad) and math.isfinite(cmd_speed_mps)):
        cmd_course_rad, cmd_speed_mps = state.course_rad, 0.0
    else:
        cmd_course_rad, cmd_speed_mps = cmd_course_rad + motion.course_bias_rad, cmd_speed_mps * motion.speed_scale
    target_speed = min(max(cmd_speed_mps, 0.0), limits.max_speed_mps)
    wanted_turn = wrap_pi(cmd_course_rad - state.course_rad)
    if wanted_turn == 0.0 and target_speed == state.speed_mps:
        # holding course and speed (nine steps in ten): the one straight piece the split below
        # makes of such a step, without it (bit for bit the same state; tested)
        lat, lon, step_m = move(state.lat_deg, state.lon_deg, dt_s, state.speed_mps, state.speed_mps,
                                 state.course_rad, 0.0, motion)
        return VehicleState(lat, (lon + 180.0) % 360.0 - 180.0, wrap_2pi(state.course_rad), state.speed_mps,
                            state.distance_m + step_m, *motion.current_en_mps)
    return _tracked(state, dt_s, cmd_course_rad, target_speed, wanted_turn, limits, motion)


def _tracked(state: VehicleState, dt_s: float, cmd_course_rad: float, target_speed: float, wanted_turn: float,
             limits: VehicleLimits, motion: MotionErrors) -> VehicleState:
    """:func:`step_vehicle` while the speed or the course still moves to the command: the step
    split where either reaches it, each piece along its arc."""
    reached = [abs(target_speed - state.speed_mps) / limits.accel_mps2 if limits.accel_mps2 > 0.0 else math.inf,
               abs(wanted_turn) / limits.turn_rate_radps if limits.turn_rate_radps > 0.0 else math.inf]
    ends = sorted({t for t in reached if 0.0 < t < dt_s}) + [dt_s]
    lat, lon, distance = state.lat_deg, state.lon_deg, state.distance_m
    start_t, speed, course = 0.0, state.speed_mps, state.course_rad
    turned = 0.0
    for end_t in ends:
        new_speed = _approach(state.speed_mps, target_speed, limits.accel_mps2 * end_t)
        turn = _approach(0.0, wanted_turn, limits.turn_rate_radps * end_t) - turned
        pieces = max(1, math.ceil(abs(turn) / MAX_PIECE_TURN_RAD))   # a long turn: short arcs
        for k in range(pieces):
            a, b = speed + (new_speed - speed) * k / pieces, speed + (new_speed - speed) * (k + 1) / pieces
            lat, lon, step_m = move(lat, lon, (end_t - start_t) / pieces, a, b, course + turn * k / pieces,
                                     turn / pieces, motion)
            distance += step_m
        start_t, speed, course, turned = end_t, new_speed, wrap_2pi(state.course_rad + turned + turn), turned + turn
    return VehicleState(lat, (lon + 180.0) % 360.0 - 180.0, course, speed, distance, *motion.current_en_mps)


def move(lat_deg: float, lon_deg: float, dt_s: float, speed_mps: float, new_speed_mps: float, course_rad: float,
          turn_rad: float, motion: MotionErrors) -> tuple[float, float, float]:
    """Position (deg) and path length (m, through the water) after ``dt_s`` of a speed and course
    changing linearly (midpoint rule), with the current's drift."""
    mid_course = course_rad + 0.5 * turn_rad
    step_m = 0.5 * (speed_mps + new_speed_mps) * dt_s
    half = 0.5 * turn_rad     # an arc's chord: its length times sinc(turn / 2), along the mid course
    chord_m = step_m * (math.sin(half) / half) if half != 0.0 else step_m
    drift_n = motion.current_en_mps[1] * dt_s     # (written so that no errors is bit-identical to before)
    north_m = chord_m * math.cos(mid_course) + drift_n
    east_m = chord_m * math.sin(mid_course) + motion.current_en_mps[0] * dt_s
    east_per_deg, north_per_deg = metres_per_degree(lat_deg + 0.5 * chord_m * math.cos(mid_course) / 111e3
                                                    + 0.5 * drift_n / 111e3)
    return lat_deg + north_m / float(north_per_deg), lon_deg + east_m / float(east_per_deg), step_m
