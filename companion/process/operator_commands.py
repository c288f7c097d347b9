"""Commands an operator sends the companion: COMMAND_LONG to its component (191), answered by COMMAND_ACK.

``MAV_CMD_DO_PAUSE_CONTINUE`` param1 0: **hold**. Running: the mission pauses (its clock stops),
zero-velocity setpoints replace the command, and HOLD (ArduPilot) / AUTO.LOITER (PX4) is commanded
while the vehicle is under guidance; nothing re-engages until resumed. Ready: the companion does
not engage. Accepted again while held (nothing changes).

``MAV_CMD_DO_PAUSE_CONTINUE`` param1 1: **resume**. Held: the hold ends; running and armed but not
in GUIDED/OFFBOARD, the companion selects it, and the mission goes on where it stopped. Not held
while running: also selects GUIDED/OFFBOARD (the operator takes back a pilot's pause), accepted.

``MAV_CMD_MISSION_START``: **start**. Ready or in start-up: the companion selects GUIDED/OFFBOARD and
arms as COMP_ARM_ENABLE 1 would, for the rest of this run (start-up: once the average is taken).

Results: ACCEPTED; TEMPORARILY_REJECTED where the phase cannot take it yet (no flight controller,
start-up for hold/resume); DENIED where it never will (done; start while running); UNSUPPORTED
for any other command. Each accepted command is said as a STATUSTEXT. Only ground stations the
link allows reach here (LINK_GCS_ID*; with signing, signed frames only: :mod:`companion.io.link`).
"""
from __future__ import annotations

from companion.io.link import MavlinkLink, mavlink
from companion.process.failsafe_response import FailsafeResponse
from companion.process.machine import PhaseMachine, State
from companion.process.mission_clock import MissionClock
from companion.process.mode_commands import ModeCommands
from companion.process.outputs import Outputs
from companion.process.reporting import Reporting
from companion.process.settings import Settings
from companion.process.voice import Voice

__all__ = ["OperatorCommands"]


class OperatorCommands:
    """``held`` (the operator's hold) and ``start_requested`` (engage as with COMP_ARM_ENABLE 1)."""

    def __init__(self, link: MavlinkLink, settings: Settings, machine: PhaseMachine, clock: MissionClock,
                 modes: ModeCommands, failsafe: FailsafeResponse, outputs: Outputs, reporting: Reporting,
                 voice: Voice) -> None:
        self.link = link
        self.settings = settings
        self.machine = machine
        self.clock = clock
        self.modes = modes
        self.failsafe = failsafe
        self.outputs = outputs
        self.reporting = reporting
        self.voice = voice
        self.held = False
        self.start_requested = False
        self.received = 0

    def addressed(self, msg) -> bool:
        """A COMMAND_LONG for this companion (its component exactly: a broadcast is the FC's)."""
        link = self.link
        return msg.target_component == link.component and msg.target_system in (0, link.sysid)

    def mavlink_packet(self, msg) -> None:
        """A COMMAND_LONG addressed to this companion from an allowed ground station: act on it and
        acknowledge it to its sender (a stranger's gets no reply, as its PARAM_* do not)."""
        if msg.get_type() != "COMMAND_LONG" or not (self.addressed(msg) and self.link.from_allowed_gcs(msg)):
            return
        self.received += 1
        if msg.command == mavlink.MAV_CMD_DO_PAUSE_CONTINUE:
            result = self.resume() if round(msg.param1) == 1 else self.hold()
        elif msg.command == mavlink.MAV_CMD_MISSION_START:
            result = self.start()
        else:
            result = mavlink.MAV_RESULT_UNSUPPORTED
        self.link.send_command_ack(msg.command, result, msg.get_srcSystem(), msg.get_srcComponent())

    def engage_allowed(self) -> bool:
        """May the companion select GUIDED/OFFBOARD and arm on its own (COMP_ARM_ENABLE or start)?"""
        return not self.held and (bool(self.settings.comp.arm_enable) or self.start_requested)

    # ------------------------------------------------------------------ the commands
    def hold(self) -> int:
        phase, now = self.machine.state, self.link.clock.now_s
        if phase == State.DONE:
            return mavlink.MAV_RESULT_DENIED
        if phase not in (State.READY, State.RUNNING):
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        if not self.held:
            self.held = True
            self.voice.say("FcMPC: held by the operator; resume to go on", mavlink.MAV_SEVERITY_NOTICE)
            self.reporting.record_event("hold", "operator")
        if phase == State.RUNNING:
            self.clock.pause(now)
        self.failsafe.hold_if_guided(now)
        return mavlink.MAV_RESULT_ACCEPTED

    def resume(self) -> int:
        phase = self.machine.state
        if phase == State.DONE:
            return mavlink.MAV_RESULT_DENIED
        if not self.held and phase != State.RUNNING:
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        if self.held:
            self.held = False
            self.voice.say("FcMPC: resumed by the operator", mavlink.MAV_SEVERITY_NOTICE)
            self.reporting.record_event("resume", "operator")
        fc = self.link.fc
        if phase == State.RUNNING and fc.armed and not fc.guided:
            self.select_guided()
        return mavlink.MAV_RESULT_ACCEPTED

    def start(self) -> int:
        phase = self.machine.state
        if phase in (State.DONE, State.RUNNING):
            return mavlink.MAV_RESULT_DENIED
        if phase == State.WAIT_FC:
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        self.held = False
        if not self.start_requested:
            self.start_requested = True
            self.voice.say("FcMPC: start by the operator: engaging" + (" once the start-up average is taken"
                                                                       if phase == State.STARTUP else ""),
                           mavlink.MAV_SEVERITY_NOTICE)
        return mavlink.MAV_RESULT_ACCEPTED

    def held_tick(self, now: float, following: bool) -> bool:
        """A running tick while held: no command and no step; HOLD commanded (and retried) while the
        FC is still under guidance, with zero-velocity setpoints meanwhile. True if one was sent."""
        self.failsafe.hold_if_guided(now)
        return self.outputs.zero_setpoint() if following else False

    def select_guided(self) -> None:
        link = self.link
        conv = link.fc.conventions
        link.send_guided_mode()
        self.modes.sent(conv.custom_mode(conv.guided_main, conv.guided_sub), link.clock.now_s, "GUIDED")
