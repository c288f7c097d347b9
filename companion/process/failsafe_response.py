"""The failsafe response: health judged every tick, and what the companion does about it.

The rules (which conditions, which timeouts) are :mod:`companion.failsafe`'s. This part decides
when they count and acts: before engaging there is nothing to stop, so reasons are only
reported (after the streams had STARTUP_GRACE_S to start); once engaged, entering the failsafe
says why (STATUSTEXT, a ``failsafe`` record), pauses the mission and commands HOLD (ArduPilot) /
AUTO.LOITER (PX4) while the vehicle is under guidance; the failsafe ends after all conditions
were healthy for ``resume_s`` of message time. Re-engaging is the running phase's business
(:mod:`companion.process.phases`).
"""
from __future__ import annotations

import math

from companion.io.link import mavlink
from companion.io.sensors.base import SampleKind
from companion.process.machine import State
from companion.process.options import STARTUP_GRACE_S

__all__ = ["HOLD_RETRY_S", "FailsafeResponse"]

HOLD_RETRY_S = 2.0                # message time between repeated hold commands


class FailsafeResponse:
    """``active`` while in failsafe; each HOLD sent goes into the app's table of pending mode commands."""

    def __init__(self, app) -> None:   # the CompanionApp wiring this part
        self.app = app
        self.active = False
        self.last_hold_cmd = -math.inf

    def evaluate(self) -> list[str]:
        """The reasons to be in failsafe now (``["recovering"]`` while waiting out ``resume_s``)."""
        app = self.app
        now = app.now
        hb_msg, hb_wall = app.link.heartbeat_age_s()
        problems = app.decoder.last_problem
        own = app.intake.source_kinds
        if own:
            problems = {k: v for k, v in problems.items()
                        if not (k == "mag" and SampleKind.MAG in own)
                        and not (k == "attitude" and SampleKind.ATTITUDE in own)}
            problems.update(app.intake.source_problem)
        reasons = app.health.evaluate(
            now, mag_age_s=app.age(SampleKind.MAG), att_age_s=app.age(SampleKind.ATTITUDE),
            hb_age_msg_s=hb_msg, hb_age_wall_s=hb_wall, mag_detail=problems.get("mag", ""),
            att_detail=problems.get("attitude", ""))
        if app.state in (State.WAIT_FC, State.STARTUP) and not app.link.fc.armed:
            # before engaging there is nothing to stop: report (after the streams had time to
            # start), but do not command anything
            if reasons and not self.active and now - app.fc_detected_at > STARTUP_GRACE_S:
                app.out.say(f"FcMPC: not ready: {reasons[0]}", mavlink.MAV_SEVERITY_WARNING)
            if now - app.fc_detected_at > STARTUP_GRACE_S or not reasons:
                self.active = bool(reasons)
            return reasons
        if reasons and app.resume.pending is not None and now - app.fc_detected_at <= STARTUP_GRACE_S:
            return reasons   # resuming after a restart: the streams had no time to start yet
        if reasons and not self.active:
            self.active = True
            app.out.say(f"FcMPC FAILSAFE: {'; '.join(reasons)}"[:200], mavlink.MAV_SEVERITY_CRITICAL)
            app.reporting.record_event("failsafe", "; ".join(reasons))
            self.act()
        elif not reasons and self.active and app.health.resumed(now):
            self.active = False
            app.out.say("FcMPC: healthy again, resuming", mavlink.MAV_SEVERITY_NOTICE)
        return reasons if reasons or not self.active else ["recovering"]

    def act(self) -> None:
        """Pause the mission and hold the vehicle if it is under guidance."""
        app = self.app
        if app.state == State.RUNNING:
            app.clock.pause(app.now)
        fc = app.link.fc
        if fc.armed and fc.guided:
            self.command_hold(app.now)

    def command_hold(self, now: float) -> None:
        if now - self.last_hold_cmd >= HOLD_RETRY_S or not math.isfinite(self.last_hold_cmd):
            link = self.app.link
            link.send_hold_mode()
            conv = link.fc.conventions
            self.app.modes.sent(conv.custom_mode(conv.hold_main, conv.hold_sub), now, "HOLD")
            self.last_hold_cmd = now

    def hold_if_guided(self, now: float) -> None:
        fc = self.app.link.fc
        if fc.armed and fc.guided:
            self.command_hold(now)
