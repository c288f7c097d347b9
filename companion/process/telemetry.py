"""Where the companion says the vehicle is: the position feed to the flight controller (GPS_INPUT to
ArduPilot, HIL_GPS to PX4: :mod:`companion.io.position_feed`) and the operator's status
(:mod:`companion.operator_status`). Times are message time unless a name ends in ``_wall``."""
from __future__ import annotations

import math

from companion.failsafe import Health
from companion.fc_view import FcView
from companion.io.link import MavlinkLink, mavlink
from companion.io.param_server import ParamServer
from companion.io.position_feed import feed_message_name, send_echo, send_feed
from companion.io.sensors.mavlink_source import MavlinkDecoder
from companion.operator_status import STATUS_PERIOD_WALL_S, failsafe_bits, space_weather_bits
from companion.process.calibration_turn import CalibrationTurn
from companion.process.estimate import CurrentEstimate
from companion.process.failsafe_response import FailsafeResponse
from companion.process.filter_words import FilterState
from companion.process.machine import PhaseMachine, State
from companion.process.mission_clock import MissionClock
from companion.process.mission_state import MissionState
from companion.process.options import FC_POSITION_MAX_AGE_S, STARTUP_GRACE_S
from companion.process.settings import Settings
from companion.process.voice import Voice
from companion.registry import READINGS

__all__ = ["ECHO_SIGMA_M", "FEED_PERIOD_S", "Telemetry"]

ECHO_SIGMA_M = 50.0               # what the echo of the FC's own GPS-aided position is worth to the feed
FEED_PERIOD_S = 0.1               # GPS_INPUT rate (message time)
ECHO_SATELLITES = 6               # fewer than a real receiver: the FC keeps its own GPS as primary
FEED_SATELLITES = 10


class Telemetry:
    """The position feed (every FEED_PERIOD_S of message time) and the operator's status (every
    STATUS_PERIOD_WALL_S of wall time)."""

    def __init__(self, link: MavlinkLink, settings: Settings, state: MissionState, machine: PhaseMachine,
                 failsafe: FailsafeResponse, calturn: CalibrationTurn, clock: MissionClock, decoder: MavlinkDecoder,
                 fc_view: FcView, estimate: CurrentEstimate, params: ParamServer, health: Health,
                 voice: Voice) -> None:
        self.link = link
        self.settings = settings
        self.mission_state = state
        self.machine = machine
        self.failsafe = failsafe
        self.calturn = calturn
        self.clock = clock
        self.decoder = decoder
        self.fc_view = fc_view
        self.estimate = estimate
        self.params = params
        self.health = health
        self.voice = voice
        self.last_status_wall = -math.inf   # the operator's status, wall time
        self.next_feed_s = -math.inf

    def fc_rebooted(self) -> None:
        """The FC's old clock is void: the feed is due at once."""
        self.next_feed_s = -math.inf

    # ------------------------------------------------------------------ the operator's status
    def operator_status_due(self, wall: float) -> None:
        """The operator's status, once every STATUS_PERIOD_WALL_S of wall time (``wall``: monotonic)."""
        if wall - self.last_status_wall >= STATUS_PERIOD_WALL_S:
            self.last_status_wall = wall
            self.operator_status()

    def operator_status(self) -> None:
        """Once a second of wall time: what an operator's ground station shows
        (:mod:`companion.operator_status` gives the fields their meaning)."""
        link, mission = self.link, self.mission_state.mission
        if link.conn is None:
            return
        cmd = self.mission_state.command
        if cmd is not None:
            estimate = self.estimate.position()
            if estimate is not None:
                ee, en, nn = cmd.est_cov_en_m2
                vn, ve = self.commanded_velocity_ne()
                link.send_position_cov(estimate[0], estimate[1], (nn, en, ee), vn, ve)
            for name, value in (("FC_ERR", cmd.est_sigma_m), ("FC_REM", cmd.remaining_m)):
                if math.isfinite(value):
                    link.send_named_float(name, value)
        link.send_named_int("FC_FS", failsafe_bits(self.health.reasons, self.failsafe.active))
        filt = FilterState.of(mission) if mission is not None else None
        now = link.clock.now_s
        fresh = {name: self.params.age_s(name, now) <= max_age for name, max_age in READINGS.items()}
        link.send_named_int("FC_SWX", space_weather_bits(
            kp_fresh=fresh.get("NAV_KP", False), symh_fresh=fresh.get("NAV_SYMH", False),
            declared=bool(filt and filt.declared), disturbed=bool(filt and filt.active),
            f_weighed=filt.f_weighed if filt is not None else None))

    def commanded_velocity_ne(self) -> tuple[float, float]:
        """The commanded velocity (north, east; m/s) while the vehicle follows it (the mission's, or
        the calibration circle's: a position feed that stood still while the boat circled, GPS
        denied, made ArduPilot's EKF call a variance failsafe), else zero."""
        phase, failsafe = self.machine.state, self.failsafe.active
        if phase == State.CALIBRATING and not failsafe:   # the calibration circle's
            course, speed = self.calturn.velocity(self.link.clock.now_s)
            return speed * math.cos(course), speed * math.sin(course)
        following = phase == State.RUNNING and not failsafe and not self.clock.paused
        cmd = self.mission_state.command if following else None
        if cmd is None or cmd.done:
            return 0.0, 0.0
        return cmd.speed_mps * math.cos(cmd.course_rad), cmd.speed_mps * math.sin(cmd.course_rad)

    # ------------------------------------------------------------------ GPS_INPUT
    def feed_due(self, now: float) -> None:
        """Called for every flight-controller message: the feed at 10 Hz of message time (ArduPilot
        calls a GPS unhealthy when its updates average over 245 ms apart)."""
        if now >= self.next_feed_s and self.machine.state != State.WAIT_FC:
            self.next_feed_s = now + FEED_PERIOD_S
            self.feed_position(now)

    def feed_position(self, now: float) -> None:
        """GPS_INPUT at the tick rate (COMP_POS_PUB 3), see :mod:`companion.fc_view`.

        While the FC's own GPS has a fix, the feed echoes the FC's GPS-aided position, claiming
        fewer satellites than a real receiver, so the FC keeps its own GPS as primary and its
        arming checks see a healthy second GPS. Once its GPS is lost, the feed flies on from the
        last echo with the commanded velocity and blends towards the navigator's estimate.
        """
        view, feed = self.fc_view, self.fc_view.feed
        accuracy_m = self.settings.comp.feed_accuracy_m
        if not view.feed_wanted() or self.machine.state == State.WAIT_FC:
            feed.stop()
            return
        pos = self.decoder.fc_position
        fresh = pos is not None and now - pos.time_s <= FC_POSITION_MAX_AGE_S
        if view.gps_has_fix(now):
            if fresh:
                feed.start(now, pos.lat_deg, pos.lon_deg, ECHO_SIGMA_M, (pos.vn_mps, pos.ve_mps))
                if view.feeding_own:
                    self.voice.say("FcMPC: FC has GPS again: position feed echoes it", mavlink.MAV_SEVERITY_NOTICE)
                view.feeding_own = False
                send_echo(self.link, view.family, pos, now, accuracy_m, ECHO_SATELLITES)
            return
        if not view.gps_seen and self.link.clock.now_s - self.mission_state.fc_detected_at < STARTUP_GRACE_S:
            return   # no GPS_RAW_INT yet: do not take a slow stream for a lost GPS
        # the navigator's position: needed to start the feed or to start feeding our own, not after
        estimate = self.estimate.position() if not (feed.started and view.feeding_own) else None
        if not feed.started:
            if estimate is None:
                return
            feed.start(now, estimate[0], estimate[1], self.estimate.sigma_m())
        if not view.feeding_own:
            view.feeding_own = True
            if estimate is not None:
                feed.correct_to(now, estimate[0], estimate[1], self.estimate.sigma_m())
            self.voice.say(f"FcMPC: FC has no GPS: feeding our position ({feed_message_name(view.family)})",
                           mavlink.MAV_SEVERITY_NOTICE)
        vn, ve = self.commanded_velocity_ne()
        if (vn, ve) != feed.target_ne:
            feed.set_velocity(now, vn, ve)
        sample = feed.sample(now)
        if sample is not None:
            send_feed(self.link, view.family, sample.lat_deg, sample.lon_deg, accuracy_m,
                      FEED_SATELLITES, sample.vn_mps, sample.ve_mps)
