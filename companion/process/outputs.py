"""What the companion sends the flight controller: its heartbeat, the stream requests, setpoints and
each step's estimate. Words go through :class:`companion.process.voice.Voice`; the position feed and
the operator's status through :class:`companion.process.telemetry.Telemetry`.

No setpoint leaves without :func:`~companion.io.link.guard_setpoint` (inside
:meth:`~companion.io.link.MavlinkLink.send_setpoint`). Times are message time unless
a name ends in ``_wall``.
"""
from __future__ import annotations

import math
import time

from companion import wrap_2pi
from companion.io.link import MavlinkLink, mavlink
from companion.io.px4 import unused_streams
from companion.io.sensors.mag_units import highres_nt_per_unit, mag_messages
from companion.io.sensors.mavlink_source import MavlinkDecoder
from companion.nav.geo import enu_offset, offset_position
from companion.nav.magnetometer import MagProcessor
from companion.nav.period import PeriodAverage
from companion.nav.mission import Command, Phase
from companion.nav.steering import trimmed_course_rad
from companion.process.estimate import CurrentEstimate
from companion.process.machine import STATE_CODES, State
from companion.process.mission_state import MissionState
from companion.process.settings import Settings

__all__ = ["STREAMS_HZ", "Outputs"]

# Streams requested from the flight controller (MAV_CMD_SET_MESSAGE_INTERVAL), Hz.
STREAMS_HZ = {"ATTITUDE": 10.0, "GLOBAL_POSITION_INT": 1.0, "GPS_RAW_INT": 1.0, "GPS2_RAW": 1.0, "SYSTEM_TIME": 1.0}


class Outputs:
    """The setpoint stream (``stream_since``), the heartbeat's times, the stream requests and
    the estimate each step publishes."""

    def __init__(self, link: MavlinkLink, settings: Settings, state: MissionState, mag: MagProcessor,
                 decoder: MavlinkDecoder, estimate: CurrentEstimate, request_streams: bool,
                 mag_message: str | None) -> None:
        """``request_streams``: ask the FC for its streams (``--no-stream-requests``: no);
        ``mag_message``: --mag-message."""
        self.link = link
        self.settings = settings
        self.mission_state = state
        self.mag = mag
        self.decoder = decoder
        self.estimate = estimate
        self.requests_streams = request_streams
        self.mag_message = mag_message
        self.last_hb_sent = -math.inf
        self.last_hb_sent_wall = -math.inf
        self.stream_since = math.nan      # message time since setpoints stream without a gap

    def fc_rebooted(self) -> None:
        """The FC's old clock is void: the heartbeat is due at once."""
        self.last_hb_sent = -math.inf

    def heartbeat(self, phase: str, failsafe: bool) -> None:
        state = mavlink.MAV_STATE_CRITICAL if failsafe else (
            mavlink.MAV_STATE_ACTIVE if phase == State.RUNNING else mavlink.MAV_STATE_STANDBY)
        self.link.send_heartbeat(state, STATE_CODES[phase])
        self.last_hb_sent = self.link.clock.now_s if self.link.clock.started else -math.inf
        self.last_hb_sent_wall = time.monotonic()

    def request_streams(self) -> None:
        """The streams the companion reads, at their rates (unless --no-stream-requests)."""
        if not self.requests_streams:
            return
        link, decoder = self.link, self.decoder
        family = link.fc.conventions.family
        mag_msgs = mag_messages(family, self.mag_message)
        decoder.mag_message = mag_msgs     # PX4 streams HIGHRES_IMU until told otherwise: not that one
        decoder.highres_nt_per_unit = highres_nt_per_unit(family)
        for name in mag_msgs:   # the fallback too, until the preferred one arrives (stop_superseded_streams)
            link.send_message_interval(getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), self.settings.comp.mag_rate_hz)
        for name in unused_streams(family, keep=mag_msgs):   # before LOCAL_POSITION_NED may be asked for
            link.send_message_interval(getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), -1.0)
        for name, hz in STREAMS_HZ.items():
            link.send_message_interval(getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), hz)
        if self.settings.comp.position_publish == 1:
            link.send_message_interval(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 2.0)

    def stop_superseded_streams(self) -> None:
        """Turn off a magnetometer stream the decoder replaced by a preferred one (RAW_IMU once
        ArduPilot's HIGHRES_IMU arrives): the companion would only parse it."""
        decoder = self.decoder
        if decoder.superseded and self.requests_streams:
            for name in sorted(decoder.superseded):
                self.link.send_message_interval(getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), -1.0)
            decoder.superseded.clear()

    # ------------------------------------------------------------------ setpoints
    def zero_setpoint(self) -> bool:
        att = self.mag.attitude
        course = wrap_2pi(att.yaw_rad) if att is not None else 0.0
        return self.stream(course, 0.0)

    def stream_command(self, cmd: Command) -> bool:
        """The navigator's command as a setpoint, its course trimmed by the FC's yaw error
        (``COMP_TRIM_DEG``, :mod:`companion.nav.steering`)."""
        return self.stream(self.course_to_send(cmd), cmd.speed_mps)

    def course_to_send(self, cmd: Command) -> float:
        """``cmd.course_rad`` plus the FC's yaw error (FC yaw minus the true heading we measure)."""
        max_trim = self.settings.comp.trim_max_deg
        mission = self.mission_state.mission
        if not max_trim > 0.0 or mission is None or cmd.done or not cmd.speed_mps > 0.0:
            return cmd.course_rad
        offset = self.mag.yaw_offset.offset_rad(self.link.clock.now_s)
        model = getattr(mission, "model", None)   # (a test's stand-in core has none)
        estimate = self.estimate.position() if math.isfinite(offset) and model is not None else None
        if estimate is None:
            return cmd.course_rad
        nav = mission.config
        decl = float(model.elements(estimate[0], estimate[1], nav.alt_m, nav.year).decl_deg)
        return trimmed_course_rad(cmd.course_rad, offset, decl, max_trim)

    def stream(self, course_rad: float, speed_mps: float) -> bool:
        mission = self.mission_state.mission
        limit = mission.config.speed_mps if mission is not None else self.settings.nav.speed_mps
        ok = self.link.send_setpoint(course_rad, speed_mps, limit)
        if ok and not math.isfinite(self.stream_since):
            self.stream_since = self.link.clock.now_s
        return ok

    # ------------------------------------------------------------------ the estimate
    def publish(self, cmd: Command, avg: PeriodAverage) -> None:
        """Each step: the measurement and the estimate as NAMED_VALUE_FLOAT, and the estimate to the
        FC (EXTERNAL_POSITION_ESTIMATE with COMP_POS_PUB 0, ODOMETRY with 1) while cruising."""
        link, mission = self.link, self.mission_state.mission
        # the navigator's rejections so far: periods (FC_REJ) and geomagnetic fixes beyond its gate (FC_FIXREJ)
        rejected = (getattr(mission, "rejected_measurements", math.nan), getattr(mission, "rejected_fixes", math.nan))
        for name, value in (("FC_D", avg.decl_deg), ("FC_I", avg.incl_deg), ("FC_F", avg.f_nt), ("FC_ERR", cmd.est_sigma_m),
                            ("FC_REM", cmd.remaining_m), ("FC_SOLV", cmd.solver_time_s), ("FC_STEP", cmd.step),
                            ("FC_REJ", rejected[0]), ("FC_FIXREJ", rejected[1])):
            if math.isfinite(value):
                link.send_named_float(name, value)
        if cmd.phase != Phase.CRUISE or not (math.isfinite(cmd.est_lat_deg) and math.isfinite(cmd.est_lon_deg)):
            return
        sigma = cmd.est_sigma_m if math.isfinite(cmd.est_sigma_m) else math.sqrt(self.settings.nav.fusion.rc_m2)
        mode = self.settings.comp.position_publish
        if mode == 0:
            link.send_external_position(cmd.est_lat_deg, cmd.est_lon_deg, sigma)
        elif mode == 1:
            origin = self.local_origin()
            if origin is not None:
                east, north = enu_offset(origin[0], origin[1], cmd.est_lat_deg, cmd.est_lon_deg)
                link.send_odometry(float(north), float(east), sigma)

    def local_origin(self) -> tuple[float, float] | None:
        """The flight controller's local NED origin from GLOBAL_POSITION_INT and LOCAL_POSITION_NED."""
        pos, local = self.decoder.fc_position, self.mission_state.local_ned
        if pos is None or local is None or abs(pos.time_s - local[0]) > 1.0:
            return None
        lat, lon = offset_position(pos.lat_deg, pos.lon_deg, -local[2], -local[1])
        return float(lat), float(lon)
