"""Engaging: GUIDED (ArduPilot) or OFFBOARD (PX4), then arming, with retries and the FC's refusals
backed off; used by the ready phase and by the running phase to take the vehicle back."""
from __future__ import annotations

import math

from companion.fc_view import FcView
from companion.io.link import MavlinkLink, mavlink
from companion.process.mode_commands import ModeCommands
from companion.process.operator_commands import OperatorCommands
from companion.process.outputs import Outputs
from companion.process.voice import Voice

__all__ = ["COMMAND_RETRY_S", "Engage"]

COMMAND_RETRY_S = 2.0             # message time between retries of mode commands


class Engage:
    """The last mode and arm commands' times (message time)."""

    def __init__(self, link: MavlinkLink, modes: ModeCommands, fc_view: FcView, operator: OperatorCommands,
                 outputs: Outputs, voice: Voice) -> None:
        self.link = link
        self.modes = modes
        self.fc_view = fc_view
        self.operator = operator
        self.outputs = outputs
        self.voice = voice
        self.last_mode_cmd = -math.inf
        self.last_arm_cmd = -math.inf

    def fc_rebooted(self) -> None:
        """The FC's old clock is void: commands are due at once."""
        self.last_mode_cmd = self.last_arm_cmd = -math.inf

    def engage(self, now: float) -> None:
        """GUIDED/OFFBOARD then arm, with retries (only with COMP_ARM_ENABLE = 1)."""
        fc = self.link.fc
        if not self.operator.engage_allowed():   # COMP_ARM_ENABLE 0 (and no operator's start), or held
            return
        conv = fc.conventions
        since = self.outputs.stream_since
        streamed = now - since if math.isfinite(since) else 0.0
        if not fc.guided:
            if streamed >= conv.offboard_prestream_s and now - self.last_mode_cmd >= COMMAND_RETRY_S:
                self.link.send_guided_mode()
                self.modes.sent(conv.custom_mode(conv.guided_main, conv.guided_sub), now, "GUIDED")
                self.last_mode_cmd = now
        elif not fc.armed:
            self.arm_with_backoff(now)

    def arm_with_backoff(self, now: float) -> None:
        """Arm; a refusal (COMMAND_ACK) is said once with the FC's reason, and the retry backs off."""
        fc, backoff = self.link.fc, self.fc_view.arming
        arm = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
        result = fc.acks.pop(arm, None)
        if result is not None and result not in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
            wait = backoff.refused(self.fc_view.prearm_text)
            self.voice.say(f"FcMPC: arming refused by the FC ({backoff.last_reason or f'result {result}'}); "
                           f"retry in {wait:g} s"[:200], mavlink.MAV_SEVERITY_WARNING)
        if now - self.last_arm_cmd >= backoff.interval_s:
            self.fc_view.prearm_text = ""
            self.link.send_arm(True)
            self.last_arm_cmd = now
