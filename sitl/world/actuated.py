"""A boat driven by a flight controller's actuator outputs: our world as the firmware's physics.

The stand-in's vehicle (:mod:`sitl.world.vehicle`) tracks a commanded course and speed, as a
flight controller's guidance would. A real autopilot in the loop (ArduPilot's JSON backend, PX4's
HIL interface) closes that loop itself and sends its actuator outputs; this module turns them into
motion and the inertial truth its IMU must sense:

* throttle (normalised, -1..1) sets the speed through the water, reached with a first-order lag;
* steering (normalised, -1..1, positive turns right) sets a yaw rate proportional to the speed
  through the water, as a rudder does, up to ``max_yaw_rate_radps``;
* the position moves along the arc (:func:`sitl.world.vehicle.move`) with the run's water current;
* roll and pitch come from the seaway (:class:`sitl.sensors.WaveMotion`).

:func:`step_boat` is pure: the caller owns time (the lockstep frame). :func:`frame_of` gives the
frame a physics backend sends back: position, NED velocity, attitude, body rates and the specific
force an accelerometer measures (body FRD; at rest level ``(0, 0, -g)``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion import wrap_2pi
from companion.frames import ned_to_body
from sitl.sensors import GRAVITY_MPS2, WaveMotion
from sitl.world.checks import require
from sitl.world.vehicle import NO_MOTION_ERRORS, MotionErrors, VehicleState, move

__all__ = ["BoatDynamics", "PhysicsFrame", "frame_of", "step_boat"]


@dataclass(frozen=True)
class BoatDynamics:
    """A small motorboat: top speed through the water at full throttle (m/s), the speed's time
    constant (s), the yaw rate per unit steering and unit speed (rad/s per m/s), its limit (rad/s)."""

    max_speed_mps: float = 10.0
    speed_tau_s: float = 2.0
    yaw_rate_per_mps: float = math.radians(6.0)
    max_yaw_rate_radps: float = math.radians(40.0)

    def __post_init__(self) -> None:
        require(self, ("max_speed_mps", "speed_tau_s", "yaw_rate_per_mps", "max_yaw_rate_radps"),
                lambda v: v > 0.0, "finite and positive")


def _clip_unit(value: float) -> float:
    """A normalised actuator output in [-1, 1]; a NaN is no output."""
    return min(max(value, -1.0), 1.0) if math.isfinite(value) else 0.0


def step_boat(state: VehicleState, dt_s: float, throttle: float, steering: float, dynamics: BoatDynamics,
              motion: MotionErrors = NO_MOTION_ERRORS) -> tuple[VehicleState, float, float]:
    """The boat after ``dt_s`` seconds of the given normalised outputs, with its yaw rate (rad/s)
    and its acceleration along the heading (m/s^2) over the step.

    >>> s, yaw_rate, accel = step_boat(VehicleState(0.0, 0.0), 1.0, 1.0, 0.0, BoatDynamics())
    >>> round(s.speed_mps, 3), yaw_rate, round(accel, 3)
    (3.935, 0.0, 3.935)
    """
    throttle, steering = _clip_unit(throttle), _clip_unit(steering)
    target = throttle * dynamics.max_speed_mps
    new_speed = target + (state.speed_mps - target) * math.exp(-dt_s / dynamics.speed_tau_s)
    mean_speed = 0.5 * (state.speed_mps + new_speed)
    yaw_rate = steering * dynamics.yaw_rate_per_mps * mean_speed
    yaw_rate = min(max(yaw_rate, -dynamics.max_yaw_rate_radps), dynamics.max_yaw_rate_radps)
    lat, lon, step_m = move(state.lat_deg, state.lon_deg, dt_s, state.speed_mps, new_speed, state.course_rad,
                            yaw_rate * dt_s, motion)
    moved = VehicleState(lat, (lon + 180.0) % 360.0 - 180.0, wrap_2pi(state.course_rad + yaw_rate * dt_s),
                         new_speed, state.distance_m + step_m, *motion.current_en_mps)
    return moved, yaw_rate, (new_speed - state.speed_mps) / dt_s


@dataclass(frozen=True)
class PhysicsFrame:
    """What a physics backend reports at one instant (SI; angles rad, yaw from north clockwise)."""

    time_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    vel_ned_mps: tuple[float, float, float]
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    gyro_frd_radps: tuple[float, float, float]
    accel_frd_mps2: tuple[float, float, float]   # specific force, as an accelerometer measures it


def frame_of(time_s: float, state: VehicleState, yaw_rate_radps: float, accel_mps2: float,
             waves: WaveMotion) -> PhysicsFrame:
    """The frame at ``time_s`` of a boat in ``state`` turning at ``yaw_rate_radps`` and speeding up
    at ``accel_mps2`` along its heading, rolled and pitched by ``waves``.

    >>> f = frame_of(0.0, VehicleState(0.0, 0.0), 0.0, 0.0, WaveMotion(0.0, 8.0, 0.0))
    >>> [round(a, 5) for a in f.accel_frd_mps2]
    [0.0, 0.0, -9.80665]
    """
    att = waves.attitude(time_s, state.course_rad, yaw_rate_radps)
    heading, speed = state.course_rad, state.speed_mps
    # horizontal acceleration in NED: along the heading, and the turn's centripetal part across it
    along, across = accel_mps2, speed * yaw_rate_radps
    acc_n = along * math.cos(heading) - across * math.sin(heading)
    acc_e = along * math.sin(heading) + across * math.cos(heading)
    force = ned_to_body((acc_n, acc_e, -GRAVITY_MPS2), att.roll_rad, att.pitch_rad, att.yaw_rad)
    # Euler rates -> body rates (ZYX)
    sr, cr = math.sin(att.roll_rad), math.cos(att.roll_rad)
    sp, cp = math.sin(att.pitch_rad), math.cos(att.pitch_rad)
    gyro = (att.roll_rate_radps - att.yaw_rate_radps * sp,
            att.pitch_rate_radps * cr + att.yaw_rate_radps * sr * cp,
            -att.pitch_rate_radps * sr + att.yaw_rate_radps * cr * cp)
    return PhysicsFrame(time_s, state.lat_deg, state.lon_deg, 0.0,
                        (state.vel_north_mps, state.vel_east_mps, 0.0), att.roll_rad, att.pitch_rad, att.yaw_rad,
                        gyro, force)
