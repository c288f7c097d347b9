"""What the companion sends: one helper per output, each going through the link's encoder.

:class:`LinkOutputs` is mixed into :class:`companion.io.link.mavlink_link.MavlinkLink`; it needs
``mav`` (the encoder), ``fc`` (:class:`~companion.io.link.conventions.FcState`), ``clock``
(:class:`~companion.io.link.clock.MessageClock`), ``stats`` and ``speed_ceiling_mps``, the start-up
safety ceiling on speed that no parameter set over the link can raise: every setpoint passes
:func:`~companion.io.link.conventions.guard_setpoint` with the smaller of the caller's limit and
that ceiling. ``time_boot_ms`` of a setpoint is the latest flight-controller time seen (a lockstep
simulator paces its clock on it).
"""
from __future__ import annotations

import math

from companion.io.link.conventions import UnsafeSetpoint, guard_setpoint, mavlink
from companion.io.link.fastpack import FramePacker
from companion.io.position_feed import gps_week_time

__all__ = ["EXT_POS_TIME_WRAP_S", "FLOAT32_MAX", "STATUSTEXT_CHUNK", "LinkOutputs", "float32"]

GPS_INPUT_IGNORE = (mavlink.GPS_INPUT_IGNORE_FLAG_VEL_HORIZ | mavlink.GPS_INPUT_IGNORE_FLAG_VEL_VERT
                    | mavlink.GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY)
STATUSTEXT_CHUNK = 50
EXT_POS_TIME_WRAP_S = 250.0   # MAV_CMD_EXTERNAL_POSITION_ESTIMATE param1: wrap <= 250 s
FLOAT32_MAX = 3.4028234663852886e38
# the frames sent at a rate (the position feed, setpoints, heartbeats): packed without message objects
GPS_INPUT = FramePacker(mavlink.MAVLink_gps_input_message)
HIL_GPS = FramePacker(mavlink.MAVLink_hil_gps_message)
SETPOINT = FramePacker(mavlink.MAVLink_set_position_target_global_int_message)
HEARTBEAT = FramePacker(mavlink.MAVLink_heartbeat_message)


def float32(value: float) -> float:
    """``value`` as a MAVLink float field can carry it: beyond float32's range, +-inf (pymavlink's
    packing raises OverflowError on such a finite value: a period's F of 1e39 nT stopped the step)."""
    value = float(value)
    return math.copysign(math.inf, value) if math.isfinite(value) and abs(value) > FLOAT32_MAX else value


class LinkOutputs:
    """Send helpers (mixin; see the module docstring for what the host class provides)."""

    speed_ceiling_mps: float = math.inf

    def time_boot_ms(self) -> int:
        return int(self.clock.now_s * 1000.0) & 0xFFFFFFFF if self.clock.started else 0

    def send_heartbeat(self, state: int = mavlink.MAV_STATE_ACTIVE, custom_mode: int = 0) -> None:
        """HEARTBEAT of an onboard controller; ``custom_mode`` carries the companion's phase
        (:mod:`companion.operator_status`)."""
        self.send_packed(HEARTBEAT, mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, custom_mode,
                         state, 3)

    def send_setpoint(self, course_rad: float, speed_mps: float, max_speed_mps: float) -> bool:
        """SET_POSITION_TARGET_GLOBAL_INT (velocity, with the yaw where the autopilot wants it), or
        nothing if :func:`guard_setpoint` refuses it under the smaller of ``max_speed_mps`` and the
        start-up speed ceiling."""
        try:
            sp = guard_setpoint(course_rad, speed_mps, min(max_speed_mps, self.speed_ceiling_mps))
        except UnsafeSetpoint as err:
            self.stats.setpoints_refused += 1
            self.stats.last_refusal = str(err)
            return False
        self.send_packed(
            SETPOINT, self.time_boot_ms(), self.fc.sysid, self.fc.compid, mavlink.MAV_FRAME_GLOBAL_INT,
            self.fc.conventions.setpoint_mask, 0, 0, 0.0, sp.vn_mps, sp.ve_mps, 0.0, 0.0, 0.0, 0.0, sp.yaw_rad, 0.0)
        self.stats.setpoints_sent += 1
        return True

    def send_hil_gps(self, *fields) -> None:
        """HIL_GPS with the fields of pymavlink's ``hil_gps_send``, in its order
        (:func:`companion.io.position_feed.send_hil_gps` composes them)."""
        self.send_packed(HIL_GPS, *fields)

    def send_command_long(self, command: int, *params: float) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.fc.acks.pop(command, None)
        self.mav.command_long_send(self.fc.sysid, self.fc.compid, command, 0, *p[:7])

    def send_set_mode(self, main: int, sub: int = 0) -> None:
        """MAV_CMD_DO_SET_MODE with the custom main/sub mode of the detected autopilot."""
        conv = self.fc.conventions
        if conv.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            self.send_command_long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)
        else:
            self.send_command_long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main)

    def send_guided_mode(self) -> None:
        c = self.fc.conventions
        self.send_set_mode(c.guided_main, c.guided_sub)

    def send_hold_mode(self) -> None:
        c = self.fc.conventions
        self.send_set_mode(c.hold_main, c.hold_sub)

    def send_arm(self, arm: bool = True) -> None:
        self.send_command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if arm else 0.0)

    def send_message_interval(self, message_id: int, rate_hz: float) -> None:
        interval_us = -1.0 if rate_hz < 0 else (0.0 if rate_hz == 0 else 1e6 / rate_hz)
        self.send_command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, float(message_id), interval_us)

    def send_statustext(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        """STATUSTEXT, split into 50-character chunks with a shared id when longer."""
        data = text.encode("utf-8", errors="replace")
        if len(data) <= STATUSTEXT_CHUNK:
            self.mav.statustext_send(severity, data, 0, 0)
            return
        self._statustext_id = (self._statustext_id % 65535) + 1
        chunks = [data[i:i + STATUSTEXT_CHUNK] for i in range(0, len(data), STATUSTEXT_CHUNK)]
        for seq, chunk in enumerate(chunks):
            self.mav.statustext_send(severity, chunk, self._statustext_id, seq)
        if len(chunks[-1]) == STATUSTEXT_CHUNK:
            self.mav.statustext_send(severity, b"", self._statustext_id, len(chunks))

    def send_named_float(self, name: str, value: float) -> None:
        if len(name) > 10:
            raise ValueError(f"NAMED_VALUE_FLOAT name {name!r} longer than 10 characters")
        self.mav.named_value_float_send(self.time_boot_ms(), name.encode("ascii"), float32(value))

    def send_named_int(self, name: str, value: int) -> None:
        if len(name) > 10:
            raise ValueError(f"NAMED_VALUE_INT name {name!r} longer than 10 characters")
        self.mav.named_value_int_send(self.time_boot_ms(), name.encode("ascii"), int(value))

    def send_command_ack(self, command: int, result: int, target_system: int, target_component: int) -> None:
        """COMMAND_ACK of a command the companion received (to its sender)."""
        self.mav.command_ack_send(command, result, 0, 0, target_system, target_component)

    def send_position_cov(self, lat_deg: float, lon_deg: float, cov_ne_m2: tuple[float, float, float],
                          vn_mps: float, ve_mps: float) -> bool:
        """GLOBAL_POSITION_INT_COV of the navigator's estimate to the ground station: latitude and
        longitude (degE7), altitude unknown (0, only the horizontal is estimated), velocity north
        and east (m/s), and the horizontal covariance ``cov_ne_m2`` (north-north, north-east,
        east-east, m^2) in the 6x6 matrix's first two rows and columns (states lat, lon, alt, vx,
        vy, vz, row-major); every other entry NaN (unknown). An unknown horizontal covariance is
        sent as NaN in the first entry, as the message defines."""
        if not (math.isfinite(lat_deg) and math.isfinite(lon_deg) and -90.0 <= lat_deg <= 90.0):
            return False
        cov = [math.nan] * 36
        nn, ne, ee = (float(v) for v in cov_ne_m2)
        if all(math.isfinite(v) for v in (nn, ne, ee)):
            cov[0], cov[1], cov[6], cov[7] = nn, ne, ne, ee
        lon = ((lon_deg + 180.0) % 360.0) - 180.0
        vn = float(vn_mps) if math.isfinite(vn_mps) else math.nan
        ve = float(ve_mps) if math.isfinite(ve_mps) else math.nan
        self.mav.global_position_int_cov_send(int(self.clock.now_s * 1e6) if self.clock.started else 0,
                                              mavlink.MAV_ESTIMATOR_TYPE_NAIVE, int(round(lat_deg * 1e7)),
                                              int(round(lon * 1e7)), 0, 0, vn, ve, math.nan, cov)
        return True

    def send_external_position(self, lat_deg: float, lon_deg: float, sigma_m: float) -> bool:
        """MAV_CMD_EXTERNAL_POSITION_ESTIMATE as COMMAND_INT (ArduPilot accepts it only there).

        param1 message time wrapped at 250 s, param2 processing delay 0, param3 1-sigma accuracy
        (m), x/y latitude/longitude in degE7, z NaN (altitude not used).
        """
        if not (math.isfinite(lat_deg) and math.isfinite(lon_deg) and -90.0 <= lat_deg <= 90.0):
            return False
        accuracy = float32(sigma_m) if math.isfinite(sigma_m) and sigma_m > 0.0 else math.nan
        stamp = math.fmod(self.clock.now_s, EXT_POS_TIME_WRAP_S) if self.clock.started else 0.0
        lon = ((lon_deg + 180.0) % 360.0) - 180.0
        self.mav.command_int_send(self.fc.sysid, self.fc.compid, mavlink.MAV_FRAME_GLOBAL,
                                  mavlink.MAV_CMD_EXTERNAL_POSITION_ESTIMATE, 0, 0,
                                  stamp, 0.0, accuracy, math.nan,
                                  int(round(lat_deg * 1e7)), int(round(lon * 1e7)), math.nan)
        return True

    def send_odometry(self, north_m: float, east_m: float, sigma_m: float) -> bool:
        """ODOMETRY in the flight controller's local NED frame (position only; the rest unknown)."""
        if not (math.isfinite(north_m) and math.isfinite(east_m)):
            return False
        var = float32(float(sigma_m) ** 2) if math.isfinite(sigma_m) and sigma_m > 0.0 else math.nan
        nan = math.nan
        pose_cov = [nan] * 21
        pose_cov[0], pose_cov[6] = var, var   # upper-triangular row-major: xx at 0, yy at 6
        self.mav.odometry_send(int(self.clock.now_s * 1e6) if self.clock.started else 0,
                               mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
                               float(north_m), float(east_m), nan, [nan, nan, nan, nan], nan, nan, nan,
                               nan, nan, nan, pose_cov, [nan] * 21, 0, mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 50)
        return True

    def send_gps_input(self, lat_deg: float, lon_deg: float, sigma_m: float, alt_m: float = 0.0,
                       satellites: int = 10) -> bool:
        """GPS_INPUT as a MAVLink GPS (ArduPilot GPSn_TYPE 14, gps_id 1 = the second GPS).

        Position only (velocities flagged ignored: the flight controller derives them from the
        positions); ``horiz_accuracy`` the honest 1-sigma; GPS week and week-ms from the flight
        controller's own clock (SYSTEM_TIME), as its GPS checks compare them.
        """
        if not (math.isfinite(lat_deg) and math.isfinite(lon_deg) and -90.0 <= lat_deg <= 90.0):
            return False
        if self.clock.unix_minus_boot_s is None or not self.clock.started:
            return False   # no date yet: a GPS without time fails the flight controller's checks
        unix_s = self.clock.now_s + self.clock.unix_minus_boot_s
        week, week_ms = gps_week_time(unix_s)
        accuracy = float(sigma_m) if math.isfinite(sigma_m) and sigma_m > 0.0 else 100.0
        lon = ((lon_deg + 180.0) % 360.0) - 180.0
        self.send_packed(GPS_INPUT, int(unix_s * 1e6), 1, GPS_INPUT_IGNORE, week_ms, week, 3,
                                int(round(lat_deg * 1e7)), int(round(lon * 1e7)), float(alt_m),
                                1.0, 1.0, 0.0, 0.0, 0.0, 0.0, min(accuracy, 1e6), 5.0, satellites)
        self.stats.positions_fed += 1
        return True
