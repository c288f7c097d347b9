"""The simulated vehicle inside the stand-in: true motion, true field, sensors and the FC's own solution.

One object holds the world's state at the current simulated instant:

* motion: from the true start (:meth:`sitl.scenario.Scenario.true_start`: a GPS error away from the
  scenario's start, unless ``exact_start``), :func:`sitl.world.vehicle.step_vehicle` towards the
  commanded ``(course, speed)`` (``cmd``), with the scenario's motion errors (current, speed scale, course bias) drawn for the
  seed, and the NED acceleration and yaw rate the IMU needs;
* field: the truth field (WMM + storm, :class:`sitl.world.magnetic.TruthField`) at the true
  position, re-evaluated every ``field_step_s``; its storm part is kept for the truth log;
* attitude: course over ground plus wave roll and pitch (:class:`sitl.sensors.WaveMotion`);
* sensors: the magnetometer and IMU samples (:class:`sitl.sensors.SensorSuite`) already
  scaled to the int16 units of RAW_IMU/SCALED_IMU (mGauss, milli-g, mrad/s);
* the flight controller's navigation solution (:class:`sitl.sensors.NavSolution`): GPS-aided
  while there is a fix, then the INS error model; ``home`` is its position at boot.

Values are memoised per instant (``t_us``) so every message of one instant agrees.
"""
from __future__ import annotations

from dataclasses import replace

from companion import wrap_pi
from companion.nav.geo import metres_per_degree
from sitl.clock import US_PER_S, SimClock
from sitl.mavframe import int16, int16_truncated
from sitl.scenario import Scenario
from sitl.sensors import GRAVITY_MPS2, NavSolution, SensorSuite, WaveMotion, make_error_models
from sitl.world.magnetic import TruthField
from sitl.world.vehicle import NO_MOTION_ERRORS, MotionErrors, VehicleState, step_vehicle

__all__ = ["VehicleSim"]


class VehicleSim:
    """World state of the stand-in's vehicle; ``faults`` supplies the sensor and GPS fault flags."""

    def __init__(self, scenario: Scenario, truth: TruthField, clock: SimClock, faults, rng_sensors, rng_nav,
                 rng_gps, *, ins_step_s: float, wave_roll_deg: float, wave_pitch_deg: float, rng_att=None,
                 rng_cal=None, rng_motion=None, rng_start=None) -> None:
        sc = scenario
        self.scenario = scenario
        self.clock = clock
        self.faults = faults            # reads .gps_off, .mag_stuck, .mag_spike_nt
        self.truth_full = truth
        self.truth = truth
        # the vehicle is truly a GPS error away from the start the navigator is given (NAV_START)
        start = sc.true_start(rng_start) if rng_start is not None else (sc.start_lat_deg, sc.start_lon_deg)
        self.state = VehicleState(*start, 0.0, 0.0)
        self.wave = WaveMotion(roll_amp_deg=wave_roll_deg, pitch_amp_deg=wave_pitch_deg)
        errors = make_error_models(sc, rng_att, rng_cal)   # sitl.world's attitude/calibration errors
        self.sensors = SensorSuite(sc.sensors, rng_sensors, errors.attitude, errors.mag, errors.decl_table_deg)
        self.motion = MotionErrors.draw(sc.motion, rng_motion) if rng_motion is not None else NO_MOTION_ERRORS
        self.nav = NavSolution(sc.ins, rng_nav, aided_noise_m=0.2 * sc.sensors.gps_noise_m, ins_step_s=ins_step_s)
        self.gps_rng = rng_gps
        self.cmd = (0.0, 0.0)           # commanded (course rad, speed m/s)
        self.accel_ned = (0.0, 0.0, 0.0)
        self.yaw_rate = 0.0
        self.mag_ints = (0, 0, 0)
        self.imu_ints = (0, 0, -1000, 0, 0, 0)
        self.field = (0.0, 0.0, 0.0)
        self.dist = (0.0, 0.0, 0.0)
        self.field_us = -1
        self.ext_estimate: tuple[float, float] | None = None   # a companion's position estimate, for the log
        self._fc_memo: tuple[int, tuple[float, float]] | None = None
        self._att_memo = None
        self.set_storm_scale(faults.storm_scale)
        self.home = (0.0, 0.0)
        self.home_scale = (1.0, 1.0)

    def set_home(self) -> None:
        """Home = the FC's solution now; its tangent-plane scale factors are computed once."""
        self.home = self.fc_position()
        self.home_scale = tuple(float(v) for v in metres_per_degree(self.home[0]))

    def set_storm_scale(self, scale: float | None) -> None:
        """Scale the storm part of the truth field (None: as the scenario has it)."""
        if scale is None:
            self.truth = self.truth_full
        else:
            self.truth = replace(self.truth_full, storm_scale=self.truth_full.storm_scale * scale)
        self.field_us = -1

    @property
    def gps_fix(self) -> bool:
        return self.clock.time_s < self.scenario.sensors.gps_denied_after_s and not self.faults.gps_off

    def fc_position(self) -> tuple[float, float]:
        """The flight controller's (lat, lon) in degrees now."""
        memo = self._fc_memo
        t_us = self.clock.t_us
        if memo is not None and memo[0] == t_us:
            return memo[1]
        s = self.state
        t = self.clock.time_s
        self.nav.update(t, self.gps_fix, s.lat_deg, s.vel_east_mps, s.vel_north_mps)
        pos = self.nav.position(t, s.lat_deg, s.lon_deg)
        self._fc_memo = (t_us, pos)
        return pos

    def fc_velocity(self) -> tuple[float, float]:
        """The flight controller's (east, north) velocity in m/s."""
        s = self.state
        return self.nav.velocity(s.vel_east_mps, s.vel_north_mps)

    def update_field(self) -> None:
        s, truth = self.state, self.truth
        t = self.clock.time_s
        alt = self.scenario.alt_m
        self.field, main = truth.point_ned_nt(s.lat_deg, s.lon_deg, alt, t)
        if truth.disturbance is not None and truth.storm_scale != 0.0:   # the storm's part, for the truth log
            self.dist = (self.field[0] - main[0], self.field[1] - main[1], self.field[2] - main[2])
        else:
            self.dist = (0.0, 0.0, 0.0)
        self.field_us = self.clock.t_us

    def true_attitude(self):
        memo = self._att_memo
        t_us = self.clock.t_us
        if memo is not None and memo[0] == t_us:
            return memo[1]
        att = self.wave.attitude(self.clock.time_s, self.state.course_rad, self.yaw_rate)
        self._att_memo = (t_us, att)
        return att

    def advance(self, t_next_us: int) -> None:
        """Move the vehicle from the clock's time to ``t_next_us`` under the current command."""
        dt = (t_next_us - self.clock.t_us) / US_PER_S
        if dt <= 0.0:
            return
        before = self.state
        course_cmd, speed_cmd = self.cmd
        self.state = after = step_vehicle(before, dt, course_cmd, speed_cmd, self.scenario.vehicle, self.motion)
        self.accel_ned = ((after.vel_north_mps - before.vel_north_mps) / dt,
                          (after.vel_east_mps - before.vel_east_mps) / dt, 0.0)
        self.yaw_rate = wrap_pi(after.course_rad - before.course_rad) / dt

    def sample_mag(self) -> None:
        """A new magnetometer sample (held while the ``mag_stuck`` fault is on)."""
        faults = self.faults
        if faults.mag_stuck:
            return
        if self.field_us < 0:
            self.update_field()
        self.sensors.sample_mag(self.field, self.true_attitude(), faults.mag_spike_nt, self.clock.time_s)
        x, y, z = self.sensors.mag_float_nt   # the firmware's float field
        # nT -> mGauss, truncated as the firmware does (companion.io.sensors.mag_units)
        self.mag_ints = (int16_truncated(x / 100.0), int16_truncated(y / 100.0), int16_truncated(z / 100.0))

    def sample_imu(self) -> None:
        sensors = self.sensors
        sensors.sample_imu(self.true_attitude(), self.accel_ned, self.clock.time_s, self.nav.ins, self.fc_position)
        ax, ay, az = sensors.accel_mps2
        gx, gy, gz = sensors.gyro_radps
        k = 1000.0 / GRAVITY_MPS2
        self.imu_ints = (int16(ax * k), int16(ay * k), int16(az * k),
                         int16(gx * 1000.0), int16(gy * 1000.0), int16(gz * 1000.0))
