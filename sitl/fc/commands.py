"""Commands, modes and setpoints the stand-in obeys (what a companion or ground station sends it).

COMMAND_LONG / COMMAND_INT: arm/disarm, DO_SET_MODE (custom modes only), RTL, message
intervals and one-off REQUEST_MESSAGE, autopilot capabilities, GUIDED_CHANGE_SPEED/_HEADING,
DO_CHANGE_SPEED, EXTERNAL_POSITION_ESTIMATE; every command is answered by COMMAND_ACK on the link it
came in on. SET_MODE,
SET_POSITION_TARGET_GLOBAL_INT / _LOCAL_NED (checked by
:func:`sitl.guidance.interpret_position_target`, acted on only when armed in GUIDED/OFFBOARD),
TIMESYNC (simulated ns), PING, MISSION_REQUEST_LIST (an empty mission) and ODOMETRY (a
companion's estimate, kept for the truth log). The mode and arming rules themselves live in
:class:`sitl.guidance.Guidance`; bad values are refused with a reason, never raised.
"""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.clock import SimClock
from sitl.fc.streams import STREAM_BY_ID
from sitl.guidance import (MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED, MAV_RESULT_UNSUPPORTED, SEVERITY_WARNING,
                           SetpointError, interpret_position_target)

__all__ = ["CommandHandler"]


class CommandHandler:
    """Handlers of the command, mode and setpoint messages; ``handlers()`` maps message names to them."""

    def __init__(self, out, guidance, dialect, vehicle, streams, telemetry, faults, clock: SimClock,
                 counters) -> None:
        self.out = out
        self.guidance = guidance
        self.dialect = dialect
        self.vehicle = vehicle
        self.streams = streams
        self.telemetry = telemetry
        self.faults = faults
        self.clock = clock
        self.counters = counters

    def handlers(self) -> dict:
        return {
            "COMMAND_LONG": self.on_command,
            "COMMAND_INT": self.on_command,
            "SET_MODE": self.on_set_mode,
            "REQUEST_DATA_STREAM": self.streams.on_request_data_stream,
            "SET_POSITION_TARGET_GLOBAL_INT": self.on_position_target,
            "SET_POSITION_TARGET_LOCAL_NED": self.on_position_target,
            "TIMESYNC": self.on_timesync,
            "MISSION_REQUEST_LIST": self.on_mission_request_list,
            "PING": self.on_ping,
            "ODOMETRY": self.on_odometry,
        }

    def ack(self, msg, command: int, result: int) -> None:
        self.counters.add(f"ack_{mavlink.enums['MAV_RESULT'][result].name[11:].lower()}" if result in
                          mavlink.enums["MAV_RESULT"] else "ack_other")
        # on the asking link only, as ArduPilot answers a command on the channel it came in on
        # (GCS_MAVLINK::handle_command_long_packet, mavlink_msg_command_ack_send(chan, ...))
        self.out.emit_reply(mavlink.MAVLink_command_ack_message, command, result, 0, 0, msg.get_srcSystem(),
                            msg.get_srcComponent())

    def on_command(self, msg) -> None:
        is_int = msg.get_type() == "COMMAND_INT"
        cmd = msg.command
        p = [msg.param1, msg.param2, msg.param3, msg.param4]
        if is_int:
            p += [msg.x / 1e7 if msg.frame not in (1, 4, 7, 8, 9, 12) else float(msg.x), msg.y / 1e7, msg.z]
        else:
            p += [msg.param5, msg.param6, msg.param7]
        g = self.guidance
        t = self.clock.time_s
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] not in (0.0, 1.0):
                result = MAV_RESULT_DENIED
            else:
                result = g.request_arm(p[0] == 1.0, t)
        elif cmd == mavlink.MAV_CMD_DO_SET_MODE:
            if not math.isfinite(p[0]) or not int(p[0]) & 1:
                result = MAV_RESULT_UNSUPPORTED   # only custom modes
            else:
                mode = self.dialect.mode_from_command(p[1], p[2])
                result = g.request_mode(mode, t, f"{p[1]:g}/{p[2]:g}")
        elif cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            result = g.request_mode(self.dialect.rtl_mode, t)
        elif cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self.streams.set_message_interval(p[0], p[1])
        elif cmd == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            result = self.streams.get_message_interval(p[0])
        elif cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
            if not self._can_send_once(p[0]):
                self.counters.add("interval_unsupported")
                self.ack(msg, cmd, MAV_RESULT_UNSUPPORTED)
            else:
                self.ack(msg, cmd, MAV_RESULT_ACCEPTED)
                self._send_once(int(p[0]))
            return
        elif cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self.ack(msg, cmd, MAV_RESULT_ACCEPTED)
            self.telemetry.send_autopilot_version()
            return
        elif cmd == mavlink.MAV_CMD_GUIDED_CHANGE_SPEED:
            result = g.change_speed(p[1]) if p[0] in (0.0, 1.0) else MAV_RESULT_DENIED
        elif cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            result = g.change_speed(p[1])
        elif cmd == mavlink.MAV_CMD_GUIDED_CHANGE_HEADING:
            if p[0] not in (0.0, 1.0) or not (math.isfinite(p[1]) and -360.0 <= p[1] <= 360.0):
                self.counters.add("commands_bad_value")
                result = MAV_RESULT_DENIED
            else:
                result = g.change_heading(math.radians(p[1]))
        elif cmd == mavlink.MAV_CMD_EXTERNAL_POSITION_ESTIMATE:
            result = self._external_position(p)
        else:
            self.counters.add("commands_unsupported")
            result = MAV_RESULT_UNSUPPORTED
        if g.events:
            self.out.relay_events(g)
        self.ack(msg, cmd, result)

    def _external_position(self, p: list[float]) -> int:
        lat, lon = p[4], p[5]
        if not (math.isfinite(lat) and math.isfinite(lon) and -90.0 <= lat <= 90.0 and -180.0 <= lon <= 360.0):
            self.counters.add("commands_bad_value")
            return MAV_RESULT_DENIED
        self.vehicle.ext_estimate = (lat, lon)
        self.counters.add("external_position_estimates")
        return MAV_RESULT_ACCEPTED

    @staticmethod
    def _can_send_once(msg_id: float) -> bool:
        return math.isfinite(msg_id) and (int(msg_id) in STREAM_BY_ID or int(msg_id) in (49, 148))

    def _send_once(self, msg_id: int) -> None:
        if msg_id == 148:
            self.telemetry.send_autopilot_version()
        elif msg_id == 49:
            self.telemetry.send_gps_global_origin()
        elif msg_id == 0 and self.faults.heartbeat_off:
            return
        else:
            self.streams.streams[STREAM_BY_ID[msg_id]].send()

    def on_set_mode(self, msg) -> None:
        if not msg.base_mode & 1:
            result = MAV_RESULT_UNSUPPORTED
        else:
            result = self.guidance.request_mode(self.dialect.mode_from_custom(msg.custom_mode), self.clock.time_s,
                                                str(msg.custom_mode))
        self.out.relay_events(self.guidance)
        self.ack(msg, mavlink.MAVLINK_MSG_ID_SET_MODE, result)

    def on_position_target(self, msg) -> None:
        g, v = self.guidance, self.vehicle
        is_global = msg.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"
        fc_lat, fc_lon = v.fc_position()
        common = dict(frame=msg.coordinate_frame, type_mask=msg.type_mask, vx=msg.vx, vy=msg.vy, yaw=msg.yaw,
                      max_speed_mps=v.scenario.vehicle.max_speed_mps, current_yaw_rad=v.state.course_rad,
                      fc_lat_deg=fc_lat, fc_lon_deg=fc_lon, origin=v.home)
        try:
            if is_global:
                target = interpret_position_target(**common, lat_deg=msg.lat_int / 1e7, lon_deg=msg.lon_int / 1e7)
            else:
                target = interpret_position_target(**common, x_m=msg.x, y_m=msg.y)
        except SetpointError as err:
            self.counters.add(f"setpoints_rejected_{err.reason}")
            self.out.say(f"setpoint_{err.reason}", SEVERITY_WARNING, f"Setpoint rejected: {err}")
            return
        t = self.clock.time_s
        if not g.accept_setpoint(t):
            self.out.say("setpoint_mode", SEVERITY_WARNING,
                         f"Setpoint ignored: {'disarmed' if not g.armed else 'mode ' + g.mode}")
            return
        g.apply_target(target, t)

    def on_timesync(self, msg) -> None:
        if msg.tc1 == 0:
            # tc1 = our boot clock in ns (never 0: tc1 == 0 marks a request)
            self.out.emit(mavlink.MAVLink_timesync_message, max(1, self.clock.boot_us * 1000), msg.ts1)

    def on_odometry(self, msg) -> None:
        """An external estimate in the FC's local NED frame (x north, y east of home) for the truth log."""
        if msg.frame_id not in (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_FRD) or \
                not (math.isfinite(msg.x) and math.isfinite(msg.y)):
            self.counters.add("odometry_ignored")
            return
        v = self.vehicle
        lat = v.home[0] + msg.x / v.home_scale[1]
        lon = (v.home[1] + msg.y / v.home_scale[0] + 180.0) % 360.0 - 180.0
        v.ext_estimate = (lat, lon)
        self.counters.add("odometry_estimates")

    def on_ping(self, msg) -> None:
        if msg.target_system == 0:   # a request: answer with the same seq and time, addressed to the sender
            self.out.emit(mavlink.MAVLink_ping_message, msg.time_usec, msg.seq, msg.get_srcSystem(),
                          msg.get_srcComponent())

    def on_mission_request_list(self, msg) -> None:
        self.out.emit(mavlink.MAVLink_mission_count_message, msg.get_srcSystem(), msg.get_srcComponent(), 0,
                      getattr(msg, "mission_type", 0))
