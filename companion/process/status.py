"""The status page's snapshot: built from the companion's parts and handed to the page.

Called from the loop's idle hook; a new snapshot at most every :data:`PUBLISH_WALL_S` of wall
time (5 a second: a vehicle's setpoint tick, COMP_SP_RATE_HZ's default), so a simulator running
the companion a thousand times faster than real time does not pay for a snapshot per tick. The
page (:mod:`companion.io.status_page`) reads only the snapshot, never these parts.
"""
from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from companion.failsafe import Health
from companion.fc_view import FcView
from companion.io.link import MavlinkLink
from companion.io.sensors.base import SampleKind
from companion.io.sensors.mavlink_source import MavlinkDecoder
from companion.io.status_page import SensorHealth, StatusSnapshot
from companion.process.failsafe_response import FailsafeResponse
from companion.process.intake import SampleIntake
from companion.process.machine import PhaseMachine
from companion.process.mission_state import MissionState
from companion.process.preparation import MissionPreparation
from companion.process.settings import Settings
from companion.process.voice import Voice

if TYPE_CHECKING:   # tornado is imported only with --http
    from companion.io.status_page.server import StatusServer

__all__ = ["PUBLISH_WALL_S", "STATUSTEXTS_KEPT", "StatusPublisher", "StatusView"]

PUBLISH_WALL_S = 0.2
STATUSTEXTS_KEPT = 20


class StatusPublisher:
    """Hands the status server a new :class:`StatusSnapshot` of the :class:`StatusView` at most
    every PUBLISH_WALL_S; without a server (no ``--http``) every call does nothing."""

    def __init__(self, view: StatusView, server: StatusServer | None = None, quiet: bool = True) -> None:
        self.view = view
        self.server = server
        self.quiet = quiet
        self.last_wall = -math.inf
        self.failed = False

    @classmethod
    def for_options(cls, view: StatusView, http: str | None, log_dir: Path, quiet: bool) -> StatusPublisher:
        """With ``--http`` (``http``) a server whose port is bound now (in use: OSError; a bad
        address: ValueError); tornado is imported only then."""
        if not http:
            return cls(view, quiet=quiet)
        from companion.io.status_page.address import parse_http_address
        from companion.io.status_page.server import StatusServer

        try:
            return cls(view, StatusServer(*parse_http_address(http), log_dir), quiet)
        except OSError as err:   # in use, no such address: one line naming the option
            raise OSError(err.errno, err.strerror, f"--http {http}") from None

    def start(self) -> None:
        if self.server is not None:
            self.maybe_publish(time.monotonic())
            self.server.start()
            if not self.quiet:
                print(f"fcmpc-companion: status page on {self.server.url}", file=sys.stderr, flush=True)

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()

    def maybe_publish(self, wall: float) -> None:
        """A new snapshot when PUBLISH_WALL_S has passed. A bug in building it must not stop a
        vehicle's companion: it is said once on stderr and the page keeps the last snapshot."""
        if self.server is None or wall - self.last_wall < PUBLISH_WALL_S:
            return
        self.last_wall = wall
        try:
            snapshot = self.view.snapshot()
        except Exception as err:   # noqa: BLE001 - the page is not worth the mission
            if not self.failed:
                print(f"fcmpc-companion: status page not updated: {type(err).__name__}: {err}", file=sys.stderr,
                      flush=True)
            self.failed = True
            return
        self.server.publish(snapshot)


class StatusView:
    """The status page's :meth:`snapshot`, read from the parts it names (it changes none)."""

    def __init__(self, link: MavlinkLink, machine: PhaseMachine, state: MissionState, settings: Settings,
                 preparation: MissionPreparation, failsafe: FailsafeResponse, health: Health, intake: SampleIntake,
                 decoder: MavlinkDecoder, fc_view: FcView, voice: Voice) -> None:
        self.link = link
        self.machine = machine
        self.mission_state = state
        self.settings = settings
        self.preparation = preparation
        self.failsafe = failsafe
        self.health = health
        self.intake = intake
        self.decoder = decoder
        self.fc_view = fc_view
        self.voice = voice

    def snapshot(self) -> StatusSnapshot:
        state, link = self.mission_state, self.link
        cmd, fc, nav = state.command, link.fc, (state.mission.config if state.mission is not None else self.settings.nav)
        start = (nav.start_lat_deg, nav.start_lon_deg) if state.mission is not None \
            else self.preparation.start_position()[:2]
        stats = link.stats
        nan = math.nan
        return StatusSnapshot(
            wall_time_s=time.time(), msg_time_s=link.clock.now_s, state=self.machine.state,
            phase=cmd.phase if cmd else "", mission=state.mission_no, step=cmd.step if cmd else 0,
            restarts=state.restarts,
            est_lat_deg=cmd.est_lat_deg if cmd else nan, est_lon_deg=cmd.est_lon_deg if cmd else nan,
            est_sigma_m=cmd.est_sigma_m if cmd else nan,
            est_cov_en_m2=tuple(cmd.est_cov_en_m2) if cmd else (nan, nan, nan),
            fix_lat_deg=cmd.fix_lat_deg if cmd else nan, fix_lon_deg=cmd.fix_lon_deg if cmd else nan,
            start_lat_deg=float(start[0]), start_lon_deg=float(start[1]),
            dest_lat_deg=nav.dest_lat_deg, dest_lon_deg=nav.dest_lon_deg,
            remaining_m=cmd.remaining_m if cmd else nan,
            course_deg=math.degrees(cmd.course_rad) if cmd else nan, speed_mps=cmd.speed_mps if cmd else nan,
            failsafe=self.failsafe.active, reasons=tuple(self.health.reasons), sensors=self.sensors(),
            fc_autopilot=fc.conventions.name if fc.detected else "", fc_sysid=fc.sysid or 0,
            fc_mode=fc.mode_name, fc_armed=fc.armed,
            link=(("messages in", stats.messages_in), ("messages from the FC", self.intake.messages_from_fc),
                  ("messages out", stats.messages_out), ("bad frames", stats.bad_frames),
                  ("setpoints sent", stats.setpoints_sent), ("setpoints refused", stats.setpoints_refused),
                  ("positions fed", stats.positions_fed), ("failsafes entered", self.failsafe.entered),
                  ("FC reboots", link.clock.reboots)),
            statustexts=tuple(self.voice.events[-STATUSTEXTS_KEPT:]), fc_statustexts=tuple(self.fc_view.texts))

    def sensors(self) -> tuple[SensorHealth, ...]:
        """The failsafe's inputs (magnetometer, attitude, the FC's heartbeat) against their
        timeouts, and the GPS (a reference only: its absence is no fault)."""
        link, now = self.link, self.link.clock.now_s
        limits = self.health.limits
        problems = self.decoder.last_problem
        mag_age, att_age = self.intake.age(SampleKind.MAG, now), self.intake.age(SampleKind.ATTITUDE, now)
        hb_age = max(link.heartbeat_age_s()) if link.fc.detected else math.inf   # either clock (failsafe)
        gps = self.intake.last_gps
        gps_age = now - gps.time_s if gps is not None else math.inf
        return (
            SensorHealth("magnetometer", mag_age, limits.mag_timeout_s, mag_age <= limits.mag_timeout_s,
                         problems.get("mag", "")),
            SensorHealth("attitude", att_age, limits.att_timeout_s, att_age <= limits.att_timeout_s,
                         problems.get("attitude", "")),
            SensorHealth("FC heartbeat", hb_age, limits.heartbeat_timeout_s, hb_age <= limits.heartbeat_timeout_s),
            SensorHealth("GPS (reference)", gps_age, math.nan, True,
                         f"fix type {gps.fix_type}" if gps is not None else "none heard"))
