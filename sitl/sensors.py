"""What the simulated flight controller measures and estimates (no sockets, no clocks).

The truth (position, course, speed) comes from :mod:`sitl.world.vehicle`; the field from
:class:`sitl.world.magnetic.TruthField`; the inertial drift from
:class:`sitl.world.ins.InsErrorModel`. This module adds what sits between the truth and the
MAVLink messages of :mod:`sitl.fc`:

* :class:`WaveMotion`: the true roll and pitch of a boat in a seaway (sinusoids of a few
  degrees), so a client must tilt-compensate the magnetometer. Yaw = course over ground.
* :class:`SensorSuite`: magnetometer (field rotated into the body frame by the *true*
  attitude, then the run's calibration residuals of :mod:`sitl.world.magerrors`, fixed bias,
  white noise, quantisation to ``mag_lsb_nt``), accelerometer and gyro (with white noise),
  and the autopilot's attitude estimate: the true attitude plus the slow errors of
  :mod:`sitl.world.attitude` (heading from the scenario's ``heading_source``: an independent
  true-heading sensor, the INS azimuth error, or the compass and an IGRF declination table at
  the flight controller's own position) plus white noise ``attitude_noise_deg``. Each sensor
  is sampled at its own rate; messages carry the latest sample.
* :class:`NavSolution`: the flight controller's position/velocity solution: GPS-aided
  (truth plus a small white error) while GPS has a fix, the INS error model's indicated
  position once it has none.

All noise comes from seeded :class:`numpy.random.Generator` objects: one seed, one run.

Frames and units per :mod:`companion`: NED, body x forward / y right / z down, nT, rad.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from companion.frames import Matrix3, Vector3, mat_nb_from_euler
from companion.nav.geo import radii_of_curvature_m
from sitl.scenario import SensorModel
from sitl.world.attitude import AttitudeErrors, compass_yaw_rad
from sitl.world.ins import InsErrorConfig, InsErrorModel
from sitl.world.magerrors import MagErrors

__all__ = ["Normals", "WaveMotion", "Attitude", "SensorSuite", "NavSolution", "GRAVITY_MPS2", "ErrorModels",
           "make_error_models"]

GRAVITY_MPS2 = 9.80665


class Normals:
    """Standard normal draws from a seeded generator, drawn in blocks (fast scalar access).

    >>> a = Normals(np.random.default_rng(7)); b = Normals(np.random.default_rng(7))
    >>> [a() for _ in range(3)] == [b() for _ in range(3)]
    True
    >>> c = Normals(np.random.default_rng(7), block=4); d = Normals(np.random.default_rng(7), block=4)
    >>> [c.three() for _ in range(5)] == [(d(), d(), d()) for _ in range(5)]   # across block refills
    True
    """

    def __init__(self, rng: np.random.Generator, block: int = 4096) -> None:
        self._rng = rng
        self._block = block
        self._buffer: list[float] = []

    def __call__(self) -> float:
        if not self._buffer:
            self._buffer = self._rng.standard_normal(self._block).tolist()
            self._buffer.reverse()
        return self._buffer.pop()

    def three(self) -> tuple[float, float, float]:
        """Three draws, the same as three calls in a row (one call for a vector's noise)."""
        buffer = self._buffer
        if len(buffer) >= 3:
            return buffer.pop(), buffer.pop(), buffer.pop()
        return self(), self(), self()


@dataclass(frozen=True)
class Attitude:
    """Euler angles (rad; yaw from north clockwise) and body rates (rad/s)."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    roll_rate_radps: float = 0.0
    pitch_rate_radps: float = 0.0
    yaw_rate_radps: float = 0.0

    @property
    def mat_nb(self) -> Matrix3:
        """Body -> NED rotation of these angles, computed once: the magnetometer and the IMU
        sample of one instant rotate by the same true attitude. (Kept in the instance dict as
        functools.cached_property does, without the lock its first access takes in 3.11.)"""
        memo = self.__dict__
        m = memo.get("_mat_nb")
        if m is None:
            m = memo["_mat_nb"] = mat_nb_from_euler(self.roll_rad, self.pitch_rad, self.yaw_rad)
        return m

    def ned_to_body(self, vec_n: Vector3) -> Vector3:
        """``companion.frames.ned_to_body(vec_n, roll, pitch, yaw)``, the same products in the same
        order, with :attr:`mat_nb`."""
        m = self.mat_nb
        n, e, d = vec_n
        return (m[0][0] * n + m[1][0] * e + m[2][0] * d,
                m[0][1] * n + m[1][1] * e + m[2][1] * d,
                m[0][2] * n + m[1][2] * e + m[2][2] * d)

    def body_rates(self) -> tuple[float, float, float]:
        """(p, q, r) body angular rates in rad/s from the Euler angle rates."""
        sr, cr = math.sin(self.roll_rad), math.cos(self.roll_rad)
        sp, cp = math.sin(self.pitch_rad), math.cos(self.pitch_rad)
        dr, dp, dy = self.roll_rate_radps, self.pitch_rate_radps, self.yaw_rate_radps
        return dr - dy * sp, dp * cr + dy * sr * cp, -dp * sr + dy * cr * cp


@dataclass(frozen=True)
class WaveMotion:
    """Roll and pitch of a boat in a regular seaway: ``amp * sin(2 pi t / period + phase)``."""

    roll_amp_deg: float = 3.0
    roll_period_s: float = 8.0
    pitch_amp_deg: float = 2.0
    pitch_period_s: float = 6.3
    pitch_phase_rad: float = 1.0

    def tilt_rad(self, time_s) -> tuple[np.ndarray, np.ndarray]:
        """True (roll, pitch) in radians at an array of times (the vectorised :meth:`attitude`)."""
        t = np.asarray(time_s, float)
        roll = math.radians(self.roll_amp_deg) * np.sin(2.0 * math.pi / self.roll_period_s * t)
        pitch = math.radians(self.pitch_amp_deg) * np.sin(2.0 * math.pi / self.pitch_period_s * t
                                                           + self.pitch_phase_rad)
        return roll, pitch

    def attitude(self, time_s: float, yaw_rad: float, yaw_rate_radps: float = 0.0) -> Attitude:
        """True attitude at ``time_s`` with the given yaw (course over ground for a boat)."""
        wr = 2.0 * math.pi / self.roll_period_s
        wp = 2.0 * math.pi / self.pitch_period_s
        ar, ap = math.radians(self.roll_amp_deg), math.radians(self.pitch_amp_deg)
        roll = ar * math.sin(wr * time_s)
        pitch = ap * math.sin(wp * time_s + self.pitch_phase_rad)
        return Attitude(roll, pitch, yaw_rad, ar * wr * math.cos(wr * time_s),
                        ap * wp * math.cos(wp * time_s + self.pitch_phase_rad), yaw_rate_radps)


@dataclass(frozen=True)
class ErrorModels:
    """One run's slow sensor errors: attitude, magnetometer calibration, declination table."""

    attitude: AttitudeErrors | None
    mag: MagErrors | None
    decl_table_deg: Callable[[float, float], float] | None


def make_error_models(scenario, rng_attitude: np.random.Generator, rng_mag: np.random.Generator) -> ErrorModels:
    """Draw a run's attitude and calibration errors of ``scenario`` (None where it has none) and
    give the flight controller's declination table (IGRF-14 at the scenario's year, or ArduPilot's
    own in its world) when its heading is magnetic. The simulator and the in-process Monte Carlo both call this."""
    from sitl.world.fc_tables import ardupilot_tables
    from sitl.world.igrf import igrf14_model

    attitude = None if scenario.attitude.ideal else AttitudeErrors(scenario.attitude, rng_attitude)
    mag_config = scenario.sensors.mag_errors
    mag = MagErrors.draw(mag_config, rng_mag) if mag_config.active else None
    table = None
    if scenario.heading_source == "magnetic":
        # ArduPilot's EKF takes its declination from the tables its SITL world is made of
        model = ardupilot_tables() if scenario.field_model.main == "ardupilot" else igrf14_model(scenario.year)
        year, alt = scenario.year, scenario.alt_m

        def table(lat_deg, lon_deg):
            return model.elements(lat_deg, lon_deg, alt, year).decl_deg
    return ErrorModels(attitude, mag, table)


class SensorSuite:
    """Magnetometer, accelerometer, gyro and attitude estimate of the simulated autopilot.

    ``sample_mag`` / ``sample_imu`` draw a new sample; the ``mag_nt``, ``accel_mps2``,
    ``gyro_radps`` and ``attitude_est`` attributes hold the latest one for the messages.
    ``attitude_errors`` and ``mag_errors`` are the run's slow errors (None: the ideal world);
    ``decl_table_deg(lat, lon)`` is the flight controller's declination table, needed by the
    ``magnetic`` heading source. White noise comes from ``rng`` in the same order as ever, so
    an ideal scenario draws exactly the samples it drew before these errors existed.
    """

    def __init__(self, model: SensorModel, rng: np.random.Generator, attitude_errors: AttitudeErrors | None = None,
                 mag_errors: MagErrors | None = None,
                 decl_table_deg: Callable[[float, float], float] | None = None) -> None:
        self.model = model
        self._normal = Normals(rng)
        self.attitude_errors = attitude_errors
        self.mag_errors = mag_errors
        self.decl_table_deg = decl_table_deg
        self.mag_clean_nt: tuple[float, float, float] = (0.0, 0.0, 0.0)   # before noise and rounding
        self.mag_nt: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.mag_float_nt: tuple[float, float, float] = (0.0, 0.0, 0.0)   # before quantisation
        self.accel_mps2: tuple[float, float, float] = (0.0, 0.0, -GRAVITY_MPS2)
        self.gyro_radps: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.attitude_est = Attitude(0.0, 0.0, 0.0)

    def sample_mag(self, field_ned_nt: tuple[float, float, float], attitude: Attitude,
                   extra_nt: float = 0.0, time_s: float = 0.0) -> tuple[float, float, float]:
        """Body-frame reading in nT: rotate by the true attitude, apply the calibration residuals
        (at ``time_s``, for the temperature drift), add bias, noise and ``extra_nt`` (a spike,
        on each axis), quantise to ``mag_lsb_nt``.

        The quantised reading is the in-process world's milligauss count, rounded; the reading
        before quantisation (:attr:`mag_float_nt`) is the float a flight controller holds, which
        the stand-in puts into HIGHRES_IMU and truncates into RAW_IMU/SCALED_IMU as the firmware
        does (the companion takes a truncated count at its midpoint: the same error statistics)."""
        m = self.model
        bx, by, bz = attitude.ned_to_body(field_ned_nt)
        if self.mag_errors is not None:
            bx, by, bz = (float(v) for v in self.mag_errors.apply((bx, by, bz), time_s))
        self.mag_clean_nt = (bx, by, bz)
        sigma, lsb = m.mag_noise_nt, m.mag_lsb_nt
        bias = m.mag_bias_nt
        wx, wy, wz = self._normal.three()
        raw = (bx + bias[0] + sigma * wx + extra_nt, by + bias[1] + sigma * wy + extra_nt,
               bz + bias[2] + sigma * wz + extra_nt)
        self.mag_float_nt = raw
        if lsb > 0.0:
            raw = (round(raw[0] / lsb) * lsb, round(raw[1] / lsb) * lsb, round(raw[2] / lsb) * lsb)
        self.mag_nt = raw
        return raw

    def sample_imu(self, attitude: Attitude, accel_ned_mps2: tuple[float, float, float], time_s: float = 0.0,
                   ins: InsErrorModel | None = None,
                   fc_position: Callable[[], tuple[float, float]] | None = None) -> None:
        """Accelerometer (specific force), gyro and the attitude estimate at the true attitude.

        ``ins`` is the flight controller's INS error model (None while GPS-aided);
        ``fc_position()`` its position estimate, called only by the ``magnetic`` source.
        """
        m = self.model
        normal = self._normal
        an, ae, ad = accel_ned_mps2
        fx, fy, fz = attitude.ned_to_body((an, ae, ad - GRAVITY_MPS2))
        sa = m.accel_noise_mps2
        wx, wy, wz = normal.three()
        self.accel_mps2 = (fx + sa * wx, fy + sa * wy, fz + sa * wz)
        p, q, r = attitude.body_rates()
        sg = m.gyro_noise_radps
        wx, wy, wz = normal.three()
        self.gyro_radps = (p + sg * wx, q + sg * wy, r + sg * wz)
        sat = math.radians(m.attitude_noise_deg)
        errors = self.attitude_errors
        if errors is None:
            wx, wy, wz = normal.three()
            self.attitude_est = Attitude(attitude.roll_rad + sat * wx, attitude.pitch_rad + sat * wy,
                                         attitude.yaw_rad + sat * wz, p, q, r)
            return
        d_roll, d_pitch, d_yaw = errors.slow_errors_rad(time_s, attitude.yaw_rad, ins)
        roll = attitude.roll_rad + d_roll + sat * normal()
        pitch = attitude.pitch_rad + d_pitch + sat * normal()
        if errors.config.heading_source == "magnetic":
            if self.decl_table_deg is None or fc_position is None:
                raise ValueError("the magnetic heading source needs a declination table and the FC position")
            decl = self.decl_table_deg(*fc_position())
            yaw = float(compass_yaw_rad(self.mag_clean_nt, roll, pitch, decl)) + sat * normal()
        else:
            yaw = attitude.yaw_rad + d_yaw + sat * normal()
        self.attitude_est = Attitude(roll, pitch, yaw, p, q, r)


class NavSolution:
    """The flight controller's position and velocity solution.

    While GPS has a fix: truth plus white noise (``aided_noise_m`` per axis, velocity
    ``aided_vel_noise_mps``), like a GPS-aided EKF. Without a fix: the INS error model,
    started (initial errors of the scenario's ``[ins]`` table) the first time the fix is
    lost and propagated every ``ins_step_s`` along the true track; between propagations the
    position error is carried forward with the current velocity error, so the reported
    position moves smoothly. When the fix returns the solution is GPS-aided again and the
    next loss starts a fresh INS.
    """

    def __init__(self, ins_config: InsErrorConfig, rng: np.random.Generator, aided_noise_m: float,
                 aided_vel_noise_mps: float = 0.05, ins_step_s: float = 5.0) -> None:
        self.ins_config = ins_config
        self._rng = rng
        self._normal = Normals(rng)
        self.aided_noise_m = aided_noise_m
        self.aided_vel_noise_mps = aided_vel_noise_mps
        self.ins_step_s = ins_step_s
        self.ins: InsErrorModel | None = None
        self._ins_time_s = 0.0
        self._radii = (6.4e6, 6.4e6)
        # the INS state's velocity and position errors as floats (dv_e, dv_n, dlat, dlon), taken
        # after each propagation: read at every instant, they cost a numpy scalar per operation
        self._ins_errors = (0.0, 0.0, 0.0, 0.0)

    @property
    def inertial(self) -> bool:
        """True while the solution is free-inertial (no GPS fix)."""
        return self.ins is not None

    def update(self, time_s: float, gps_fix: bool, lat_deg: float, vel_east_mps: float, vel_north_mps: float) -> None:
        """Advance to ``time_s``: start/stop the INS with the fix, propagate it when a step is due."""
        if gps_fix:
            self.ins = None
            return
        if self.ins is None:
            self.ins = InsErrorModel(self.ins_config, self._rng, lat_deg)
            self._ins_time_s = time_s
            self._radii = tuple(float(r) for r in radii_of_curvature_m(lat_deg))
            self._take_ins_errors()
            return
        dt = time_s - self._ins_time_s
        if dt >= self.ins_step_s:
            self.ins.propagate(dt, lat_deg, vel_east_mps, vel_north_mps)
            self._ins_time_s = time_s
            self._radii = tuple(float(r) for r in radii_of_curvature_m(lat_deg))
            self._take_ins_errors()

    def _take_ins_errors(self) -> None:
        state = self.ins.state
        self._ins_errors = (float(state[3]), float(state[4]), float(state[6]), float(state[7]))

    def position(self, time_s: float, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        """Indicated (lat_deg, lon_deg) at ``time_s`` for the true position."""
        if self.ins is None:
            east = self.aided_noise_m * self._normal()
            north = self.aided_noise_m * self._normal()
            return (lat_deg + math.degrees(north / 6.378e6),
                    lon_deg + math.degrees(east / (6.378e6 * max(1e-6, math.cos(math.radians(lat_deg))))))
        dv_e, dv_n, dlat0, dlon0 = self._ins_errors
        tau = time_s - self._ins_time_s
        m, n = self._radii
        dlat = dlat0 + dv_n * tau / m
        dlon = dlon0 + dv_e * tau / (n * math.cos(math.radians(lat_deg)))
        return lat_deg + math.degrees(dlat), (lon_deg + math.degrees(dlon) + 180.0) % 360.0 - 180.0

    def velocity(self, vel_east_mps: float, vel_north_mps: float) -> tuple[float, float]:
        """Indicated (east, north) velocity in m/s."""
        if self.ins is None:
            s = self.aided_vel_noise_mps
            return vel_east_mps + s * self._normal(), vel_north_mps + s * self._normal()
        dv_e, dv_n = self._ins_errors[:2]   # InsErrorModel.indicated_velocity, on the floats
        return vel_east_mps + dv_e, vel_north_mps + dv_n

    def error_m(self, time_s: float, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        """(east, north) error of the inertial solution in metres; (0, 0) while aided."""
        if self.ins is None:
            return 0.0, 0.0
        lat, lon = self.position(time_s, lat_deg, lon_deg)
        m, n = self._radii
        dlon = (lon - lon_deg + 180.0) % 360.0 - 180.0
        return math.radians(dlon) * n * math.cos(math.radians(lat_deg)), math.radians(lat - lat_deg) * m
