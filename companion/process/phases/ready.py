"""``ready``: the average is taken; zero-velocity setpoints (a sliding start-up window meanwhile);
with COMP_ARM_ENABLE 1 GUIDED (ArduPilot) or, after >= 1 s of setpoints, OFFBOARD (PX4), then arm,
backing off when the FC refuses; with 0 the operator does so. The next mission is built meanwhile
(:meth:`MissionPreparation.prepare`). Armed in GUIDED/OFFBOARD: the calibration circles first
(COMP_CAL_TURNS, with a GPS fix to place the field model; else a WARNING says why not) or the mission (``engaged``)."""
from __future__ import annotations

from companion.io.link import MavlinkLink
from companion.nav.magnetometer import MagProcessor
from companion.process.calibration_turn import CalibrationTurn
from companion.process.machine import Event, State
from companion.process.operator_commands import OperatorCommands
from companion.process.outputs import Outputs
from companion.process.phases.base import Phase, Tick, Transition
from companion.process.phases.engage import Engage
from companion.process.preparation import MissionPreparation
from companion.process.resume import Resume

__all__ = ["ReadyPhase"]


class ReadyPhase(Phase):
    state = State.READY

    def __init__(self, link: MavlinkLink, mag: MagProcessor, preparation: MissionPreparation,
                 operator: OperatorCommands, outputs: Outputs, resume: Resume, calturn: CalibrationTurn,
                 engage: Engage) -> None:
        self.link = link
        self.mag = mag
        self.preparation = preparation
        self.operator = operator
        self.outputs = outputs
        self.resume = resume
        self.calturn = calturn
        self.engage = engage

    def run(self, now: float, reasons: list[str], dt: float) -> Tick:
        self.mag.drop_before(now - self.preparation.startup_window())   # a sliding window while waiting
        if reasons:
            return Tick(False)
        fc = self.link.fc
        if fc.armed and fc.guided and not self.operator.held:
            sent = self.outputs.zero_setpoint()   # no gap: the FC stops after 3 s without a setpoint
            if self.resume.pending is None and self.calturn.wanted():
                return Tick(sent, Transition(Event.CALIBRATE))
            return Tick(sent, Transition(Event.ENGAGED))   # the running phase starts or resumes the mission
        sent = self.outputs.zero_setpoint()
        if self.resume.pending is None:
            self.preparation.prepare(now)
        self.engage.engage(now)
        return Tick(sent)
