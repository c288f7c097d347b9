"""What the companion sends: STATUSTEXT, its heartbeat, setpoints, the estimate and the position feed
(GPS_INPUT to ArduPilot, HIL_GPS to PX4: :mod:`companion.io.position_feed`).

No setpoint leaves without :func:`~companion.io.link.guard_setpoint` (inside
:meth:`~companion.io.link.MavlinkLink.send_setpoint`). Times are message time unless
a name ends in ``_wall``.
"""
from __future__ import annotations

import math
import sys
import time

from companion import wrap_2pi
from companion.io.link import mavlink
from companion.io.position_feed import feed_message_name, send_echo, send_feed
from companion.io.px4 import unused_streams
from companion.io.sensors.mag_units import highres_nt_per_unit, mag_messages
from companion.nav.geo import enu_offset, offset_position
from companion.nav.mission import Command, Phase
from companion.nav.steering import trimmed_course_rad
from companion.operator_status import STATUS_PERIOD_WALL_S, failsafe_bits, space_weather_bits
from companion.process.filter_words import FilterState
from companion.process.machine import STATE_CODES, State
from companion.registry import READINGS
from companion.process.options import FC_POSITION_MAX_AGE_S, STARTUP_GRACE_S

__all__ = ["STREAMS_HZ", "Outputs"]

ECHO_SIGMA_M = 50.0               # what the echo of the FC's own GPS-aided position is worth to the feed
FEED_PERIOD_S = 0.1               # GPS_INPUT rate (message time)
ECHO_SATELLITES = 6               # fewer than a real receiver: the FC keeps its own GPS as primary
FEED_SATELLITES = 10

# Streams requested from the flight controller (MAV_CMD_SET_MESSAGE_INTERVAL), Hz.
STREAMS_HZ = {"ATTITUDE": 10.0, "GLOBAL_POSITION_INT": 1.0, "GPS_RAW_INT": 1.0, "GPS2_RAW": 1.0, "SYSTEM_TIME": 1.0}


class Outputs:
    """The companion's sink: every message it originates goes through here."""

    def __init__(self, app) -> None:   # the CompanionApp wiring this part
        self.app = app
        self.link = app.link
        self.events: list[str] = []       # everything said, with its message time (summary.json)
        self.last_hb_sent = -math.inf
        self.last_hb_sent_wall = -math.inf
        self.last_status_wall = -math.inf   # the operator's status (companion.operator_status), wall time
        self.stream_since = math.nan      # message time since setpoints stream without a gap
        self.next_feed_s = -math.inf

    # ------------------------------------------------------------------ words
    def stamp(self) -> str:
        """``[message time]``, or ``[no FC time]`` before the first time-stamped message."""
        now = self.app.now
        return f"[{now:10.1f}]" if math.isfinite(now) else "[no FC time]"

    def say(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        """STATUSTEXT to the vehicle, a line on stderr (unless --quiet), an event in the summary."""
        self.events.append(f"{self.stamp()} {text}")
        if not self.app.opts.quiet:
            print(f"fcmpc-companion {self.stamp()} {text}", file=sys.stderr, flush=True)
        if self.link.conn is not None:
            self.link.send_statustext(text, severity)

    def heartbeat(self) -> None:
        app = self.app
        state = mavlink.MAV_STATE_CRITICAL if app.failsafe_active else (
            mavlink.MAV_STATE_ACTIVE if app.state == State.RUNNING else mavlink.MAV_STATE_STANDBY)
        self.link.send_heartbeat(state, STATE_CODES[app.state])
        self.last_hb_sent = app.now if self.link.clock.started else -math.inf
        self.last_hb_sent_wall = time.monotonic()

    def request_streams(self) -> None:
        link, app = self.link, self.app
        family = link.fc.conventions.family
        mag_msgs = mag_messages(family, app.opts.mag_message)
        app.decoder.mag_message = mag_msgs     # PX4 streams HIGHRES_IMU until told otherwise: not that one
        app.decoder.highres_nt_per_unit = highres_nt_per_unit(family)
        for name in mag_msgs:   # the fallback too, until the preferred one arrives (stop_superseded_streams)
            link.send_message_interval(getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), app.comp_cfg.mag_rate_hz)
        for name in unused_streams(family, keep=mag_msgs):   # before LOCAL_POSITION_NED may be asked for
            link.send_message_interval(getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), -1.0)
        for name, hz in STREAMS_HZ.items():
            link.send_message_interval(getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), hz)
        if app.comp_cfg.position_publish == 1:
            link.send_message_interval(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 2.0)

    def stop_superseded_streams(self) -> None:
        """Turn off a magnetometer stream the decoder replaced by a preferred one (RAW_IMU once
        ArduPilot's HIGHRES_IMU arrives): the companion would only parse it."""
        decoder = self.app.decoder
        if decoder.superseded and self.app.opts.request_streams:
            for name in sorted(decoder.superseded):
                self.link.send_message_interval(getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), -1.0)
            decoder.superseded.clear()

    # ------------------------------------------------------------------ setpoints
    def zero_setpoint(self) -> bool:
        att = self.app.mag.attitude
        course = wrap_2pi(att.yaw_rad) if att is not None else 0.0
        return self.stream(course, 0.0)

    def stream_command(self, cmd: Command) -> bool:
        """The navigator's command as a setpoint, its course trimmed by the FC's yaw error
        (``COMP_TRIM_DEG``, :mod:`companion.nav.steering`)."""
        return self.stream(self.course_to_send(cmd), cmd.speed_mps)

    def course_to_send(self, cmd: Command) -> float:
        """``cmd.course_rad`` plus the FC's yaw error (FC yaw minus the true heading we measure)."""
        app = self.app
        max_trim = app.comp_cfg.trim_max_deg
        if not max_trim > 0.0 or app.mission is None or cmd.done or not cmd.speed_mps > 0.0:
            return cmd.course_rad
        offset = app.mag.yaw_offset.offset_rad(app.now)
        model = getattr(app.mission, "model", None)   # (a test's stand-in core has none)
        estimate = self.current_estimate() if math.isfinite(offset) and model is not None else None
        if estimate is None:
            return cmd.course_rad
        nav = app.mission.config
        decl = float(model.elements(estimate[0], estimate[1], nav.alt_m, nav.year).decl_deg)
        return trimmed_course_rad(cmd.course_rad, offset, decl, max_trim)

    def stream(self, course_rad: float, speed_mps: float) -> bool:
        app = self.app
        limit = app.mission.config.speed_mps if app.mission is not None else app.nav_cfg.speed_mps
        ok = self.link.send_setpoint(course_rad, speed_mps, limit)
        if ok and not math.isfinite(self.stream_since):
            self.stream_since = app.now
        return ok

    # ------------------------------------------------------------------ the estimate
    def publish(self, cmd: Command, avg) -> None:
        """Each step: the measurement and the estimate as NAMED_VALUE_FLOAT, and the estimate to the
        FC (EXTERNAL_POSITION_ESTIMATE with COMP_POS_PUB 0, ODOMETRY with 1) while cruising."""
        link, app = self.link, self.app
        # the navigator's rejections so far: periods (FC_REJ) and geomagnetic fixes beyond its gate (FC_FIXREJ)
        rejected = (getattr(app.mission, "rejected_measurements", math.nan), getattr(app.mission, "rejected_fixes", math.nan))
        for name, value in (("FC_D", avg.decl_deg), ("FC_I", avg.incl_deg), ("FC_F", avg.f_nt), ("FC_ERR", cmd.est_sigma_m),
                            ("FC_REM", cmd.remaining_m), ("FC_SOLV", cmd.solver_time_s), ("FC_STEP", cmd.step),
                            ("FC_REJ", rejected[0]), ("FC_FIXREJ", rejected[1])):
            if math.isfinite(value):
                link.send_named_float(name, value)
        if cmd.phase != Phase.CRUISE or not (math.isfinite(cmd.est_lat_deg) and math.isfinite(cmd.est_lon_deg)):
            return
        sigma = cmd.est_sigma_m if math.isfinite(cmd.est_sigma_m) else math.sqrt(app.nav_cfg.fusion.rc_m2)
        mode = app.comp_cfg.position_publish
        if mode == 0:
            link.send_external_position(cmd.est_lat_deg, cmd.est_lon_deg, sigma)
        elif mode == 1:
            origin = self.local_origin()
            if origin is not None:
                east, north = enu_offset(origin[0], origin[1], cmd.est_lat_deg, cmd.est_lon_deg)
                link.send_odometry(float(north), float(east), sigma)

    def local_origin(self) -> tuple[float, float] | None:
        """The flight controller's local NED origin from GLOBAL_POSITION_INT and LOCAL_POSITION_NED."""
        pos, local = self.app.decoder.fc_position, self.app.local_ned
        if pos is None or local is None or abs(pos.time_s - local[0]) > 1.0:
            return None
        lat, lon = offset_position(pos.lat_deg, pos.lon_deg, -local[2], -local[1])
        return float(lat), float(lon)

    def operator_status_due(self, wall: float) -> None:
        """The operator's status, once every STATUS_PERIOD_WALL_S of wall time (``wall``: monotonic)."""
        if wall - self.last_status_wall >= STATUS_PERIOD_WALL_S:
            self.last_status_wall = wall
            self.operator_status()

    def operator_status(self) -> None:
        """Once a second of wall time: what an operator's ground station shows
        (:mod:`companion.operator_status` gives the fields their meaning)."""
        app, link = self.app, self.link
        if link.conn is None:
            return
        cmd = app.command
        if cmd is not None:
            estimate = self.current_estimate()
            if estimate is not None:
                ee, en, nn = cmd.est_cov_en_m2
                vn, ve = self.commanded_velocity_ne()
                link.send_position_cov(estimate[0], estimate[1], (nn, en, ee), vn, ve)
            for name, value in (("FC_ERR", cmd.est_sigma_m), ("FC_REM", cmd.remaining_m)):
                if math.isfinite(value):
                    link.send_named_float(name, value)
        link.send_named_int("FC_FS", failsafe_bits(app.health.reasons, app.failsafe_active))
        filt = FilterState.of(app.mission) if app.mission is not None else None
        fresh = {name: app.params.age_s(name, app.now) <= max_age for name, max_age in READINGS.items()}
        link.send_named_int("FC_SWX", space_weather_bits(
            kp_fresh=fresh.get("NAV_KP", False), symh_fresh=fresh.get("NAV_SYMH", False),
            declared=bool(filt and filt.declared), disturbed=bool(filt and filt.active),
            f_weighed=filt.f_weighed if filt is not None else None))

    def commanded_velocity_ne(self) -> tuple[float, float]:
        """The commanded velocity (north, east; m/s) while the vehicle follows it (the mission's, or
        the calibration circle's: a position feed that stood still while the boat circled, GPS
        denied, made ArduPilot's EKF call a variance failsafe), else zero."""
        app = self.app
        if app.state == State.CALIBRATING and not app.failsafe_active:   # the calibration circle's
            course, speed = app.phases.calturn.velocity(app.now)
            return speed * math.cos(course), speed * math.sin(course)
        following = app.state == State.RUNNING and not app.failsafe_active and not app.clock.paused
        cmd = app.command if following else None
        if cmd is None or cmd.done:
            return 0.0, 0.0
        return cmd.speed_mps * math.cos(cmd.course_rad), cmd.speed_mps * math.sin(cmd.course_rad)

    # ------------------------------------------------------------------ GPS_INPUT
    def feed_due(self, now: float) -> None:
        """Called for every flight-controller message: the feed at 10 Hz of message time (ArduPilot
        calls a GPS unhealthy when its updates average over 245 ms apart)."""
        if now >= self.next_feed_s and self.app.state != State.WAIT_FC:
            self.next_feed_s = now + FEED_PERIOD_S
            self.feed_position(now)

    def feed_position(self, now: float) -> None:
        """GPS_INPUT at the tick rate (COMP_POS_PUB 3), see :mod:`companion.fc_view`.

        While the FC's own GPS has a fix, the feed echoes the FC's GPS-aided position, claiming
        fewer satellites than a real receiver, so the FC keeps its own GPS as primary and its
        arming checks see a healthy second GPS. Once its GPS is lost, the feed flies on from the
        last echo with the commanded velocity and blends towards the navigator's estimate.
        """
        app = self.app
        view, feed = app.fc_view, app.fc_view.feed
        if not view.feed_wanted() or app.state == State.WAIT_FC:
            feed.stop()
            return
        pos = app.decoder.fc_position
        fresh = pos is not None and now - pos.time_s <= FC_POSITION_MAX_AGE_S
        if view.gps_has_fix(now):
            if fresh:
                feed.start(now, pos.lat_deg, pos.lon_deg, ECHO_SIGMA_M)
                if view.feeding_own:
                    self.say("FcMPC: FC has GPS again: position feed echoes it", mavlink.MAV_SEVERITY_NOTICE)
                view.feeding_own = False
                send_echo(self.link, view.family, pos, now, app.comp_cfg.feed_accuracy_m, ECHO_SATELLITES)
            return
        if not view.gps_seen and app.now - app.fc_detected_at < STARTUP_GRACE_S:
            return   # no GPS_RAW_INT yet: do not take a slow stream for a lost GPS
        # the navigator's position: needed to start the feed or to start feeding our own, not after
        estimate = self.current_estimate() if not (feed.started and view.feeding_own) else None
        if not feed.started:
            if estimate is None:
                return
            feed.start(now, estimate[0], estimate[1], self.feed_sigma())
        if not view.feeding_own:
            view.feeding_own = True
            if estimate is not None:
                feed.correct_to(now, estimate[0], estimate[1], self.feed_sigma())
            self.say(f"FcMPC: FC has no GPS: feeding our position ({feed_message_name(view.family)})",
                     mavlink.MAV_SEVERITY_NOTICE)
        vn, ve = self.commanded_velocity_ne()
        if (vn, ve) != feed.velocity_ne:
            feed.set_velocity(now, vn, ve)
        sample = feed.sample(now)
        if sample is not None:
            send_feed(self.link, view.family, sample.lat_deg, sample.lon_deg, app.comp_cfg.feed_accuracy_m,
                      FEED_SATELLITES, sample.vn_mps, sample.ve_mps)

    def current_estimate(self) -> tuple[float, float] | None:
        """The navigator's latest position: the mission's estimate, else the start it would use."""
        app = self.app
        cmd = app.command
        if cmd is not None and math.isfinite(cmd.est_lat_deg) and math.isfinite(cmd.est_lon_deg):
            # flown on with the command since its step (mission time stops while paused)
            dt = max(app.mission_time() - app.m0 - cmd.time_s, 0.0) if not cmd.done else 0.0
            lat, lon = offset_position(cmd.est_lat_deg, cmd.est_lon_deg, cmd.speed_mps * math.sin(cmd.course_rad) * dt,
                                       cmd.speed_mps * math.cos(cmd.course_rad) * dt)
            return float(lat), float(lon)
        lat, lon, _ = app.preparation.start_position()
        return (lat, lon) if math.isfinite(lat) and math.isfinite(lon) else None

    def feed_sigma(self) -> float:
        app = self.app
        cmd = app.command
        if cmd is not None and math.isfinite(cmd.est_sigma_m):
            return cmd.est_sigma_m
        return math.sqrt(app.nav_cfg.fusion.rc_m2)
