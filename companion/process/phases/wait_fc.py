"""``wait_fc``: no flight-controller HEARTBEAT yet. Leaving it, the FC is said, its parameters and
streams are asked for."""
from __future__ import annotations

from companion.fc_view import FcView
from companion.io.link import MavlinkLink
from companion.process.machine import State
from companion.process.mission_state import MissionState
from companion.process.outputs import Outputs
from companion.process.phases.base import Phase
from companion.process.voice import Voice

__all__ = ["WaitFcPhase"]


class WaitFcPhase(Phase):
    state = State.WAIT_FC

    def __init__(self, link: MavlinkLink, state: MissionState, fc_view: FcView, outputs: Outputs,
                 voice: Voice) -> None:
        self.link = link
        self.mission_state = state
        self.fc_view = fc_view
        self.outputs = outputs
        self.voice = voice

    def exit(self, now: float) -> None:
        fc = self.link.fc
        self.mission_state.fc_detected_at = now
        self.voice.say(f"FcMPC: {fc.conventions.name} FC sysid {fc.sysid} detected, mode {fc.mode_name}")
        self.fc_view.start(fc.conventions.family, fc.conventions.param_bytewise, now)
        self.outputs.request_streams()
