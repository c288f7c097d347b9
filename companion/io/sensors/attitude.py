"""Attitude from an IMU and magnetometer: a Mahony filter and the rotations around it.

Frames as in :mod:`companion`: body b (x forward, y right, z down) and NED n. A rotation
``mat_nb`` takes body vectors into NED; Euler angles are ZYX (yaw, pitch, roll). The
accelerometer measures specific force, so at rest it reads minus gravity, (0, 0, -g)
when level.

The filter (Mahony, Hamel & Pflimlin 2008, the explicit complementary filter on SO(3))
integrates the gyro and pulls the estimate towards the measured gravity direction and,
for yaw only, towards the horizontal magnetic field (the DCM/ArduPilot way: the yaw error
is the azimuth error of the field in the horizontal plane, applied about the vertical).
Keeping the magnetometer out of roll and pitch is what the downstream tilt compensation
of the magnetometer needs: a magnetic disturbance must not tilt the reference.

>>> f = MahonyFilter()
>>> att = f.update(0.0, (0.0, 0.0, -9.81), (0.0, 0.0, 0.0), (20000.0, 0.0, 50000.0))
>>> [round(math.degrees(a), 3) for a in att]
[0.0, 0.0, 0.0]
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion import wrap_2pi, wrap_pi
from companion.frames import Matrix3, Vector3, body_to_ned, mat_nb_from_euler, ned_to_body

__all__ = [
    "Matrix3",
    "MahonyFilter",
    "MahonyGains",
    "body_to_ned",
    "euler_from_quaternion",
    "heading_from_mag",
    "mat_nb_from_euler",
    "ned_to_body",
    "quaternion_from_euler",
    "tilt_from_accel",
]

Quaternion = tuple[float, float, float, float]

GRAVITY_MPS2 = 9.80665
_INTEGRATE_BELOW = 0.05  # rad/s of correction, i.e. about 3 degrees of error at kp = 1


def _mul(mat: Matrix3, vec: Vector3) -> Vector3:
    return (
        mat[0][0] * vec[0] + mat[0][1] * vec[1] + mat[0][2] * vec[2],
        mat[1][0] * vec[0] + mat[1][1] * vec[1] + mat[1][2] * vec[2],
        mat[2][0] * vec[0] + mat[2][1] * vec[1] + mat[2][2] * vec[2],
    )


def _mul_t(mat: Matrix3, vec: Vector3) -> Vector3:
    return (
        mat[0][0] * vec[0] + mat[1][0] * vec[1] + mat[2][0] * vec[2],
        mat[0][1] * vec[0] + mat[1][1] * vec[1] + mat[2][1] * vec[2],
        mat[0][2] * vec[0] + mat[1][2] * vec[1] + mat[2][2] * vec[2],
    )


def tilt_from_accel(accel_body_mps2: Vector3) -> tuple[float, float]:
    """Roll and pitch (rad) of a vehicle at rest from its specific force.

    >>> roll, pitch = 0.2, -0.1  # right wing down, nose down
    >>> f = (9.81 * math.sin(pitch), -9.81 * math.sin(roll) * math.cos(pitch),
    ...      -9.81 * math.cos(roll) * math.cos(pitch))
    >>> [round(a, 9) for a in tilt_from_accel(f)]
    [0.2, -0.1]
    """
    fx, fy, fz = accel_body_mps2
    return math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))


def heading_from_mag(mag_body_nt: Vector3, roll_rad: float, pitch_rad: float) -> float:
    """Magnetic heading (rad, [0, 2*pi)): the tilt-compensated field's azimuth, negated.

    Rotating the body vector by roll and pitch only gives the field in a level frame
    aligned with the vehicle's heading, where it reads (H cos psi, -H sin psi, Z).
    """
    x, y, _ = body_to_ned(mag_body_nt, roll_rad, pitch_rad, 0.0)
    return wrap_2pi(math.atan2(-y, x))


def quaternion_from_euler(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Quaternion:
    """Unit quaternion (w, x, y, z) of the body -> NED rotation."""
    cr, sr = math.cos(roll_rad / 2), math.sin(roll_rad / 2)
    cp, sp = math.cos(pitch_rad / 2), math.sin(pitch_rad / 2)
    cy, sy = math.cos(yaw_rad / 2), math.sin(yaw_rad / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quaternion(q: Quaternion) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad; yaw in [0, 2*pi)) of a body -> NED quaternion."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, wrap_2pi(yaw)


def _cross(a: Vector3, b: Vector3) -> Vector3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@dataclass(frozen=True)
class MahonyGains:
    """Tuning of :class:`MahonyFilter`.

    ``kp``: proportional gain (1/s) on the gravity error; the tilt time constant is about
    1/kp. ``kp_yaw``: the same for the magnetic yaw error. ``ki``: integral gain (1/s^2)
    that learns the gyro bias. ``accel_gate``: the accelerometer corrects only while
    its norm is within this fraction of g (no correction during hard manoeuvres).
    ``max_dt_s``: a gap longer than this restarts the filter from accel and mag.
    """

    kp: float = 1.0
    kp_yaw: float = 0.5
    ki: float = 0.05
    accel_gate: float = 0.2
    max_dt_s: float = 0.5

    def __post_init__(self) -> None:
        for name in ("kp", "kp_yaw", "ki"):
            if getattr(self, name) < 0.0:
                raise ValueError(f"MahonyGains.{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 < self.accel_gate < 1.0:
            raise ValueError(f"MahonyGains.accel_gate must be in (0, 1), got {self.accel_gate}")
        if not self.max_dt_s > 0.0:
            raise ValueError(f"MahonyGains.max_dt_s must be > 0 s, got {self.max_dt_s}")


class MahonyFilter:
    """Quaternion Mahony AHRS in NED; yaw magnetic unless ``declination_rad`` is given.

    Call :meth:`update` with each IMU sample (and the magnetometer when a new one is
    available); the first call, and any call after a gap, initialises the attitude from
    the accelerometer tilt and the tilt-compensated magnetic heading.
    """

    def __init__(self, gains: MahonyGains | None = None, declination_rad: float | None = None) -> None:
        self.gains = gains or MahonyGains()
        self.declination_rad = declination_rad
        self.reset()

    @property
    def yaw_reference(self) -> str:
        return "magnetic" if self.declination_rad is None else "true"

    def reset(self) -> None:
        self._q: Quaternion | None = None
        self._bias_int: Vector3 = (0.0, 0.0, 0.0)
        self._last_time_s: float | None = None

    @property
    def quaternion(self) -> Quaternion | None:
        return self._q

    @property
    def initialised(self) -> bool:
        return self._q is not None

    def _initialise(self, accel: Vector3, mag: Vector3 | None) -> None:
        roll, pitch = tilt_from_accel(accel)
        yaw = 0.0
        if mag is not None:
            yaw = heading_from_mag(mag, roll, pitch) + (self.declination_rad or 0.0)
        self._q = quaternion_from_euler(roll, pitch, yaw)
        self._bias_int = (0.0, 0.0, 0.0)

    def update(
        self,
        time_s: float,
        accel_body_mps2: Vector3,
        gyro_body_radps: Vector3,
        mag_body_nt: Vector3 | None = None,
    ) -> tuple[float, float, float]:
        """Advance to ``time_s``; returns (roll, pitch, yaw) in radians."""
        dt = None if self._last_time_s is None else time_s - self._last_time_s
        self._last_time_s = time_s
        if self._q is None or dt is None or dt <= 0.0 or dt > self.gains.max_dt_s:
            self._initialise(accel_body_mps2, mag_body_nt)
            return euler_from_quaternion(self._q)  # type: ignore[arg-type]

        w, x, y, z = self._q
        # Earth's down axis seen from the body: third row of mat_nb.
        v_down = (2.0 * (x * z - w * y), 2.0 * (y * z + w * x), w * w - x * x - y * y + z * z)
        ex = ey = ez = 0.0

        accel_norm = math.sqrt(sum(c * c for c in accel_body_mps2))
        if abs(accel_norm / GRAVITY_MPS2 - 1.0) < self.gains.accel_gate:
            # The gravity direction (down) is minus the specific force.
            a = (-accel_body_mps2[0] / accel_norm, -accel_body_mps2[1] / accel_norm,
                 -accel_body_mps2[2] / accel_norm)
            e = _cross(a, v_down)
            ex, ey, ez = e[0] * self.gains.kp, e[1] * self.gains.kp, e[2] * self.gains.kp

        if mag_body_nt is not None:
            # Yaw error measured in the horizontal plane: the azimuth of the field seen
            # through the current attitude should be the declination. Correcting about
            # the earth's vertical only keeps magnetic disturbances out of roll and pitch,
            # and using the angle (not a cross product of unit vectors, which shrinks by
            # cos^2 I) keeps the yaw time constant 1/kp_yaw at any inclination.
            h = _mul(_quat_to_mat(self._q), mag_body_nt)
            if math.hypot(h[0], h[1]) > 1e-3 * math.sqrt(h[0] ** 2 + h[1] ** 2 + h[2] ** 2):
                err = wrap_pi((self.declination_rad or 0.0) - math.atan2(h[1], h[0]))
                k = err * self.gains.kp_yaw
                ex, ey, ez = ex + k * v_down[0], ey + k * v_down[1], ez + k * v_down[2]

        bi = self._bias_int
        # Integrate only small errors: the integral is for the slowly varying gyro bias,
        # and winding it up during a start-up transient costs a long tail afterwards.
        if self.gains.ki > 0.0 and ex * ex + ey * ey + ez * ez < _INTEGRATE_BELOW ** 2:
            bi = (bi[0] + self.gains.ki * ex * dt, bi[1] + self.gains.ki * ey * dt,
                  bi[2] + self.gains.ki * ez * dt)
            self._bias_int = bi
        gx = gyro_body_radps[0] + ex + bi[0]
        gy = gyro_body_radps[1] + ey + bi[1]
        gz = gyro_body_radps[2] + ez + bi[2]

        # q_dot = 0.5 * q (x) (0, omega), integrated over dt, then renormalised.
        half = 0.5 * dt
        qw = w + (-x * gx - y * gy - z * gz) * half
        qx = x + (w * gx + y * gz - z * gy) * half
        qy = y + (w * gy - x * gz + z * gx) * half
        qz = z + (w * gz + x * gy - y * gx) * half
        n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        self._q = (qw / n, qx / n, qy / n, qz / n)
        return euler_from_quaternion(self._q)


def _quat_to_mat(q: Quaternion) -> Matrix3:
    w, x, y, z = q
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )
