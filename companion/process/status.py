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

from companion.io.sensors.base import SampleKind
from companion.io.status_page import SensorHealth, StatusSnapshot

__all__ = ["PUBLISH_WALL_S", "STATUSTEXTS_KEPT", "StatusPublisher"]

PUBLISH_WALL_S = 0.2
STATUSTEXTS_KEPT = 20


class StatusPublisher:
    """Hands the status server a new :class:`StatusSnapshot` of the app at most every
    PUBLISH_WALL_S; without a server (no ``--http``) every call does nothing."""

    def __init__(self, app, server=None) -> None:   # the CompanionApp wiring this part; a StatusServer
        self.app = app
        self.server = server
        self.last_wall = -math.inf
        self.failed = False

    @classmethod
    def for_options(cls, app) -> StatusPublisher:
        """With ``--http`` a server whose port is bound now (in use: OSError; a bad address:
        ValueError); tornado is imported only then."""
        if not app.opts.http:
            return cls(app)
        from companion.io.status_page.address import parse_http_address
        from companion.io.status_page.server import StatusServer

        try:
            return cls(app, StatusServer(*parse_http_address(app.opts.http), app.log_dir))
        except OSError as err:   # in use, no such address: one line naming the option
            raise OSError(err.errno, err.strerror, f"--http {app.opts.http}") from None

    def start(self) -> None:
        if self.server is not None:
            self.maybe_publish(time.monotonic())
            self.server.start()
            if not self.app.opts.quiet:
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
            snapshot = self.snapshot()
        except Exception as err:   # noqa: BLE001 - the page is not worth the mission
            if not self.failed:
                print(f"fcmpc-companion: status page not updated: {type(err).__name__}: {err}", file=sys.stderr,
                      flush=True)
            self.failed = True
            return
        self.server.publish(snapshot)

    def snapshot(self) -> StatusSnapshot:
        app = self.app
        cmd, fc, nav = app.command, app.link.fc, (app.mission.config if app.mission is not None else app.nav_cfg)
        start = (nav.start_lat_deg, nav.start_lon_deg) if app.mission is not None \
            else app.preparation.start_position()[:2]
        stats = app.link.stats
        nan = math.nan
        return StatusSnapshot(
            wall_time_s=time.time(), msg_time_s=app.now, state=app.state, phase=cmd.phase if cmd else "",
            mission=app.mission_no, step=cmd.step if cmd else 0, restarts=app.restarts,
            est_lat_deg=cmd.est_lat_deg if cmd else nan, est_lon_deg=cmd.est_lon_deg if cmd else nan,
            est_sigma_m=cmd.est_sigma_m if cmd else nan,
            est_cov_en_m2=tuple(cmd.est_cov_en_m2) if cmd else (nan, nan, nan),
            fix_lat_deg=cmd.fix_lat_deg if cmd else nan, fix_lon_deg=cmd.fix_lon_deg if cmd else nan,
            start_lat_deg=float(start[0]), start_lon_deg=float(start[1]),
            dest_lat_deg=nav.dest_lat_deg, dest_lon_deg=nav.dest_lon_deg,
            remaining_m=cmd.remaining_m if cmd else nan,
            course_deg=math.degrees(cmd.course_rad) if cmd else nan, speed_mps=cmd.speed_mps if cmd else nan,
            failsafe=app.failsafe_active, reasons=tuple(app.health.reasons), sensors=self.sensors(),
            fc_autopilot=fc.conventions.name if fc.detected else "", fc_sysid=fc.sysid or 0,
            fc_mode=fc.mode_name, fc_armed=fc.armed,
            link=(("messages in", stats.messages_in), ("messages from the FC", app.messages_from_fc),
                  ("messages out", stats.messages_out), ("bad frames", stats.bad_frames),
                  ("setpoints sent", stats.setpoints_sent), ("setpoints refused", stats.setpoints_refused),
                  ("positions fed", stats.positions_fed), ("failsafes entered", app.health.entered),
                  ("FC reboots", app.link.clock.reboots)),
            statustexts=tuple(app.out.events[-STATUSTEXTS_KEPT:]), fc_statustexts=tuple(app.fc_view.texts))

    def sensors(self) -> tuple[SensorHealth, ...]:
        """The failsafe's inputs (magnetometer, attitude, the FC's heartbeat) against their
        timeouts, and the GPS (a reference only: its absence is no fault)."""
        app = self.app
        limits = app.health.limits
        problems = app.decoder.last_problem
        mag_age, att_age = app.age(SampleKind.MAG), app.age(SampleKind.ATTITUDE)
        hb_age = max(app.link.heartbeat_age_s()) if app.link.fc.detected else math.inf   # either clock (failsafe)
        gps = app.intake.last_gps
        gps_age = app.now - gps.time_s if gps is not None else math.inf
        return (
            SensorHealth("magnetometer", mag_age, limits.mag_timeout_s, mag_age <= limits.mag_timeout_s,
                         problems.get("mag", "")),
            SensorHealth("attitude", att_age, limits.att_timeout_s, att_age <= limits.att_timeout_s,
                         problems.get("attitude", "")),
            SensorHealth("FC heartbeat", hb_age, limits.heartbeat_timeout_s, hb_age <= limits.heartbeat_timeout_s),
            SensorHealth("GPS (reference)", gps_age, math.nan, True,
                         f"fix type {gps.fix_type}" if gps is not None else "none heard"))
