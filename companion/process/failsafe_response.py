"""The failsafe response: health judged every tick, and what the companion does about it.

The rules (which conditions, which timeouts) are :mod:`companion.failsafe`'s. This part decides
when they count and acts: before engaging there is nothing to stop, so reasons are only
reported (after the streams had STARTUP_GRACE_S to start); once engaged, entering the failsafe
says why (STATUSTEXT, a ``failsafe`` record), pauses the mission and commands HOLD (ArduPilot) /
AUTO.LOITER (PX4) while the vehicle is under guidance; the failsafe ends after all conditions
were healthy for ``resume_s`` of message time. Re-engaging is the running phase's business
(:mod:`companion.process.phases.running`).
"""
from __future__ import annotations

import math

from companion.failsafe import Health
from companion.io.link import MavlinkLink, mavlink
from companion.io.sensors.base import SampleKind
from companion.io.sensors.mavlink_source import MavlinkDecoder
from companion.process.intake import SampleIntake
from companion.process.machine import PhaseMachine, State
from companion.process.mission_clock import MissionClock
from companion.process.mission_state import MissionState
from companion.process.mode_commands import ModeCommands
from companion.process.options import STARTUP_GRACE_S
from companion.process.reporting import Reporting
from companion.process.resume import Resume
from companion.process.voice import Voice

__all__ = ["HOLD_RETRY_S", "FailsafeResponse"]

HOLD_RETRY_S = 2.0                # message time between repeated hold commands


class FailsafeResponse:
    """``active`` while in failsafe; each HOLD sent goes into the table of pending mode commands.
    ``entered`` counts the failsafes of an engaged companion (not the "not ready" before engaging)."""

    def __init__(self, link: MavlinkLink, health: Health, decoder: MavlinkDecoder, intake: SampleIntake,
                 state: MissionState, machine: PhaseMachine, clock: MissionClock, modes: ModeCommands,
                 resume: Resume, reporting: Reporting, voice: Voice) -> None:
        self.link = link
        self.health = health
        self.decoder = decoder
        self.intake = intake
        self.mission_state = state
        self.machine = machine
        self.clock = clock
        self.modes = modes
        self.resume = resume
        self.reporting = reporting
        self.voice = voice
        self.active = False
        self.entered = 0                  # failsafes entered while engaged: said, recorded, acted on
        self.last_hold_cmd = -math.inf

    def fc_rebooted(self) -> None:
        """The FC's old clock is void: a hold is due at once."""
        self.last_hold_cmd = -math.inf

    def evaluate(self) -> list[str]:
        """The reasons to be in failsafe now (``["recovering"]`` while waiting out ``resume_s``)."""
        now = self.link.clock.now_s
        intake, phase, detected_at = self.intake, self.machine.state, self.mission_state.fc_detected_at
        hb_msg, hb_wall = self.link.heartbeat_age_s()
        problems = self.decoder.last_problem
        own = intake.source_kinds
        if own:
            problems = {k: v for k, v in problems.items()
                        if not (k == "mag" and SampleKind.MAG in own)
                        and not (k == "attitude" and SampleKind.ATTITUDE in own)}
            problems.update(intake.source_problem)
        reasons = self.health.evaluate(
            now, mag_age_s=intake.age(SampleKind.MAG, now), att_age_s=intake.age(SampleKind.ATTITUDE, now),
            hb_age_msg_s=hb_msg, hb_age_wall_s=hb_wall, mag_detail=problems.get("mag", ""),
            att_detail=problems.get("attitude", ""))
        if phase in (State.WAIT_FC, State.STARTUP) and not self.link.fc.armed:
            # before engaging there is nothing to stop: report (after the streams had time to
            # start), but do not command anything
            if reasons and not self.active and now - detected_at > STARTUP_GRACE_S:
                self.voice.say(f"FcMPC: not ready: {reasons[0]}", mavlink.MAV_SEVERITY_WARNING)
            if now - detected_at > STARTUP_GRACE_S or not reasons:
                self.active = bool(reasons)
            return reasons
        if reasons and self.resume.pending is not None and now - detected_at <= STARTUP_GRACE_S:
            return reasons   # resuming after a restart: the streams had no time to start yet
        if reasons and not self.active:
            self.active = True
            self.entered += 1
            self.voice.say(f"FcMPC FAILSAFE: {'; '.join(reasons)}"[:200], mavlink.MAV_SEVERITY_CRITICAL)
            self.reporting.record_event("failsafe", "; ".join(reasons))
            self.act()
        elif not reasons and self.active and self.health.resumed(now):
            self.active = False
            self.voice.say("FcMPC: healthy again, resuming", mavlink.MAV_SEVERITY_NOTICE)
        return reasons if reasons or not self.active else ["recovering"]

    def act(self) -> None:
        """Pause the mission and hold the vehicle if it is under guidance."""
        now = self.link.clock.now_s
        if self.machine.state == State.RUNNING:
            self.clock.pause(now)
        fc = self.link.fc
        if fc.armed and fc.guided:
            self.command_hold(now)

    def command_hold(self, now: float) -> None:
        if now - self.last_hold_cmd >= HOLD_RETRY_S or not math.isfinite(self.last_hold_cmd):
            link = self.link
            link.send_hold_mode()
            conv = link.fc.conventions
            self.modes.sent(conv.custom_mode(conv.hold_main, conv.hold_sub), now, "HOLD")
            self.last_hold_cmd = now

    def hold_if_guided(self, now: float) -> None:
        fc = self.link.fc
        if fc.armed and fc.guided:
            self.command_hold(now)
