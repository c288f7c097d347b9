"""The stand-in's telemetry: one method per message it sends, filled from the simulated vehicle.

What each message means (README "Simulator"): the magnetometer fields of RAW_IMU/SCALED_IMU
(mGauss, truncated toward zero as ArduPilot and PX4 do) and HIGHRES_IMU (gauss as imitating PX4,
ArduPilot's 1e-6 gauss as imitating ArduPilot) are the true field in the body frame plus sensor errors;
ATTITUDE the true attitude plus noise; GPS_RAW_INT the raw receiver fix (truth plus noise,
fix_type 3; 1 when the scenario denies GPS, 0 on a ``gps_off`` fault); GLOBAL_POSITION_INT and
LOCAL_POSITION_NED the flight controller's own solution. Every time field is simulated time:
``time_boot_ms`` and boot-based ``time_usec`` since the autopilot's last boot (``SimClock.boot_us``,
restarted by an ``fc_reboot`` fault), SYSTEM_TIME.time_unix_usec the scenario's start plus
simulated time (it runs on through a reboot). Sensor faults show as
zeros (``mag_off``), saturation or NaN (``mag_nan``), unhealthy SYS_STATUS bits, or no
HEARTBEAT (``heartbeat_off``).
"""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion import wrap_2pi, wrap_pi
from sitl.clock import SimClock
from sitl.mavframe import INT16_MAX, int16

__all__ = ["CAPABILITIES", "MAV_TYPE_SURFACE_BOAT", "PX4_CAPABILITIES", "Telemetry"]

MAV_TYPE_SURFACE_BOAT = 11
MAV_STATE_BOOT, MAV_STATE_STANDBY, MAV_STATE_ACTIVE = 1, 3, 4
SENSOR_GYRO, SENSOR_ACCEL, SENSOR_MAG, SENSOR_GPS, SENSOR_GEOFENCE, SENSOR_AHRS = 1, 2, 4, 32, 0x100000, 0x200000
CAPABILITIES = (mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
# PX4 encodes INT32 parameters bytewise in PARAM_VALUE's float (see sitl.fc.params)
PX4_CAPABILITIES = (CAPABILITIES & ~mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT) \
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE


class Telemetry:
    """Encoders of the vehicle's messages into the outbox (``senders()`` feeds the stream scheduler)."""

    def __init__(self, out, vehicle, faults, guidance, dialect, clock: SimClock, counters, sysid: int) -> None:
        self.out = out
        self.vehicle = vehicle
        self.faults = faults
        self.guidance = guidance
        self.dialect = dialect
        self.clock = clock
        self.counters = counters
        self.sysid = sysid
        self.scenario = vehicle.scenario
        self.start_unix_us = out.start_unix_us
        self.last_system_time_us = -1

    def senders(self) -> dict:
        """Stream name -> method that sends it."""
        return {"HEARTBEAT": self.send_heartbeat, "SYS_STATUS": self.send_sys_status,
                "SYSTEM_TIME": self.send_system_time, "RAW_IMU": self.send_raw_imu,
                "SCALED_IMU": self.send_scaled_imu, "ATTITUDE": self.send_attitude,
                "GLOBAL_POSITION_INT": self.send_global_position_int, "GPS_RAW_INT": self.send_gps_raw_int,
                "LOCAL_POSITION_NED": self.send_local_position_ned, "HIGHRES_IMU": self.send_highres_imu,
                "VFR_HUD": self.send_vfr_hud, "HOME_POSITION": self.send_home_position,
                "EXTENDED_SYS_STATE": self.send_extended_sys_state}

    def send_heartbeat(self) -> None:
        if self.faults.heartbeat_off:
            self.counters.add("heartbeats_suppressed")
            return
        g = self.guidance
        status = MAV_STATE_BOOT if not g.ready else (MAV_STATE_ACTIVE if g.armed else MAV_STATE_STANDBY)
        self.out.emit(mavlink.MAVLink_heartbeat_message, MAV_TYPE_SURFACE_BOAT, self.dialect.autopilot, g.base_mode,
                      g.custom_mode, status, 3)

    def send_system_time(self) -> None:
        t_us = self.clock.t_us
        self.last_system_time_us = t_us
        # UNIX time runs on through a reboot; the boot time restarts at 0
        self.out.emit(mavlink.MAVLink_system_time_message, self.start_unix_us + t_us, self.clock.boot_ms)

    def send_sys_status(self) -> None:
        faults = self.faults
        present = SENSOR_GYRO | SENSOR_ACCEL | SENSOR_MAG | SENSOR_GPS | SENSOR_AHRS
        health = present | SENSOR_GEOFENCE   # like ArduPilot: the fence bit is healthy while not breached
        if faults.mag_off or faults.mag_nan or faults.mag_stuck:
            health &= ~SENSOR_MAG
        if not self.vehicle.gps_fix:
            health &= ~SENSOR_GPS
        errors = self.counters.get("rx_bad_frames", 0)
        self.out.emit(mavlink.MAVLink_sys_status_message, present, present, health, 100, 12600, -1, -1,
                      int(faults.loss * 10000), min(errors, 65535), 0, 0, 0, 0)

    def _mag_mgauss(self) -> tuple[int, int, int]:
        if self.faults.mag_off:
            return 0, 0, 0
        if self.faults.mag_nan:   # int16 cannot carry NaN: saturated, an impossible 3.3 G reading
            return INT16_MAX, INT16_MAX, INT16_MAX
        return self.vehicle.mag_ints

    def send_raw_imu(self) -> None:
        self.out.emit(mavlink.MAVLink_raw_imu_message, self.clock.boot_us, *self.vehicle.imu_ints, *self._mag_mgauss(),
                      0, 0)

    def send_scaled_imu(self) -> None:
        self.out.emit(mavlink.MAVLink_scaled_imu_message, self.clock.boot_ms, *self.vehicle.imu_ints,
                      *self._mag_mgauss(), 0)

    def send_highres_imu(self) -> None:
        sensors = self.vehicle.sensors
        ax, ay, az = sensors.accel_mps2
        gx, gy, gz = sensors.gyro_radps
        updated = 0b111111
        if self.faults.mag_off:   # as in RAW_IMU: a dead sensor's zeros, marked as read
            mx = my = mz = 0.0
            updated |= 0b111000000
        elif self.faults.mag_nan:
            mx = my = mz = math.nan
            updated |= 0b111000000
        else:
            # nT -> gauss (PX4, the spec) or ArduPilot's compass.get_field() * 1000: 1e-6 gauss
            per_nt = 1e-5 if self.dialect.autopilot == mavlink.MAV_AUTOPILOT_PX4 else 10.0
            mx, my, mz = (v * per_nt for v in sensors.mag_float_nt)
            updated |= 0b111000000
        self.out.emit(mavlink.MAVLink_highres_imu_message, self.clock.boot_us, ax, ay, az, gx, gy, gz, mx, my, mz,
                      1013.25, 0.0, self.scenario.alt_m, 25.0, updated, 0)

    def send_attitude(self) -> None:
        a = self.vehicle.sensors.attitude_est
        self.out.emit(mavlink.MAVLink_attitude_message, self.clock.boot_ms, a.roll_rad, a.pitch_rad,
                      wrap_pi(a.yaw_rad), a.roll_rate_radps, a.pitch_rate_radps, a.yaw_rate_radps)

    def send_global_position_int(self) -> None:
        v = self.vehicle
        lat, lon = v.fc_position()
        ve, vn = v.fc_velocity()
        hdg = int(round(math.degrees(wrap_2pi(v.sensors.attitude_est.yaw_rad)) * 100.0)) % 36000
        alt_mm = int(round(self.scenario.alt_m * 1000.0))
        self.out.emit(mavlink.MAVLink_global_position_int_message,
                      self.clock.boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), alt_mm, 0,
                      int16(vn * 100.0), int16(ve * 100.0), 0, hdg)

    def send_local_position_ned(self) -> None:
        v = self.vehicle
        lat, lon = v.fc_position()
        # enu_offset() of the home tangent plane, with its scale factors computed once
        east = ((lon - v.home[1] + 180.0) % 360.0 - 180.0) * v.home_scale[0]
        north = (lat - v.home[0]) * v.home_scale[1]
        ve, vn = v.fc_velocity()
        self.out.emit(mavlink.MAVLink_local_position_ned_message, self.clock.boot_ms, float(north), float(east),
                      0.0, vn, ve, 0.0)

    def send_gps_raw_int(self) -> None:
        v = self.vehicle
        s = v.state
        stamp = self.start_unix_us + self.clock.t_us
        if not v.gps_fix:
            fix = 0 if self.faults.gps_off else 1
            self.out.emit(mavlink.MAVLink_gps_raw_int_message, stamp, fix, 0, 0, 0, 65535, 65535, 65535, 65535, 0,
                          0, 0, 0, 0, 0, 0)
            return
        sigma = self.scenario.sensors.gps_noise_m
        dn, de = v.gps_rng.normal(0.0, sigma, 2) if sigma > 0 else (0.0, 0.0)
        lat = s.lat_deg + math.degrees(dn / 6.3675e6)
        lon = s.lon_deg + math.degrees(de / (6.3781e6 * math.cos(math.radians(s.lat_deg))))
        cog = int(round(math.degrees(s.course_rad) * 100.0)) % 36000
        h_acc = int(sigma * 1000.0)
        alt_mm = int(self.scenario.alt_m * 1000)
        self.out.emit(mavlink.MAVLink_gps_raw_int_message,
                      stamp, 3, int(round(lat * 1e7)), int(round(lon * 1e7)), alt_mm, 90, 150,
                      int(round(s.speed_mps * 100.0)), cog, 14, alt_mm, h_acc, 2 * h_acc, 100, 0, 0)

    def send_vfr_hud(self) -> None:
        s = self.vehicle.state
        throttle = int(100 * s.speed_mps / self.scenario.vehicle.max_speed_mps)
        self.out.emit(mavlink.MAVLink_vfr_hud_message, s.speed_mps, s.speed_mps,
                      int(math.degrees(wrap_2pi(self.vehicle.sensors.attitude_est.yaw_rad))) % 360,
                      throttle, self.scenario.alt_m, 0.0)

    def send_home_position(self) -> None:
        lat, lon = self.vehicle.home
        self.out.emit(mavlink.MAVLink_home_position_message, int(round(lat * 1e7)), int(round(lon * 1e7)),
                      int(self.scenario.alt_m * 1000), 0.0, 0.0, 0.0,
                      [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, self.clock.boot_us)

    def send_extended_sys_state(self) -> None:
        self.out.emit(mavlink.MAVLink_extended_sys_state_message, 0, 1)  # landed state ON_GROUND (on the water)

    def send_gps_global_origin(self) -> None:
        lat, lon = self.vehicle.home
        self.out.emit(mavlink.MAVLink_gps_global_origin_message, int(round(lat * 1e7)), int(round(lon * 1e7)),
                      int(self.scenario.alt_m * 1000), self.clock.boot_us)

    def send_autopilot_version(self) -> None:
        capabilities = PX4_CAPABILITIES if self.dialect.autopilot == mavlink.MAV_AUTOPILOT_PX4 else CAPABILITIES
        self.out.emit(mavlink.MAVLink_autopilot_version_message,
                      capabilities, self.dialect.version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0,
                      0x5157_0000 + self.sysid, [0] * 18)
