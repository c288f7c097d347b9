"""``done``: arrived, failed, or gave up after MAX_RESTARTS navigation failures: setpoints stop,
hold mode is commanded (and commanded again while the FC stays under guidance)."""
from __future__ import annotations

import math
import time

from companion.io.link import mavlink
from companion.nav.mission import Phase as CorePhase
from companion.process.failsafe_response import FailsafeResponse
from companion.process.machine import Event, State
from companion.process.mission_state import MissionState
from companion.process.outputs import Outputs
from companion.process.phases.base import Phase, Tick, Transition
from companion.process.reporting import Reporting
from companion.process.resume import Resume
from companion.process.voice import Voice

__all__ = ["DonePhase"]


class DonePhase(Phase):
    state = State.DONE

    def __init__(self, state: MissionState, outputs: Outputs, failsafe: FailsafeResponse, resume: Resume,
                 reporting: Reporting, voice: Voice) -> None:
        self.mission_state = state
        self.outputs = outputs
        self.failsafe = failsafe
        self.resume = resume
        self.reporting = reporting
        self.voice = voice

    def enter(self, now: float, transition: Transition) -> Transition | None:
        """The mission's end (its last command is the state's): said, recorded, saved as finished."""
        state, say = self.mission_state, self.voice.say
        cmd = state.command
        failed_reason = transition.why if transition.event == Event.GAVE_UP else ""
        state.done_wall = time.monotonic()
        state.done_msg_s = now
        self.outputs.stream_since = math.nan
        if failed_reason:
            say(f"FcMPC: mission FAILED: {failed_reason}"[:200], mavlink.MAV_SEVERITY_ERROR)
        elif cmd.phase == CorePhase.ARRIVED:
            say(f"FcMPC: arrived after {cmd.step} steps, estimated {cmd.remaining_m:.0f} m to go")
        else:
            say(f"FcMPC: mission {cmd.phase}: {cmd.reason}", mavlink.MAV_SEVERITY_ERROR)
        self.reporting.record_event("done", failed_reason or cmd.reason or cmd.phase)
        self.resume.save(finished=True)
        self.failsafe.hold_if_guided(now)
        return None

    def run(self, now: float, reasons: list[str], dt: float) -> Tick:
        self.failsafe.hold_if_guided(now)
        return Tick()
