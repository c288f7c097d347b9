"""``calibrating``: armed in GUIDED/OFFBOARD, COMP_CAL_TURNS > 0 and a GPS fix to place the field model: the magnetometer's
calibration circles (:mod:`companion.process.calibration_turn`), then one more for the start-up
average (``engaged``)."""
from __future__ import annotations

from companion.process.calibration_turn import CalibrationTurn
from companion.process.machine import Event, State
from companion.process.outputs import Outputs
from companion.process.phases.base import Phase, Tick, Transition

__all__ = ["CalibratingPhase"]


class CalibratingPhase(Phase):
    state = State.CALIBRATING

    def __init__(self, calturn: CalibrationTurn, outputs: Outputs) -> None:
        self.calturn = calturn
        self.outputs = outputs

    def enter(self, now: float, transition: Transition) -> Transition | None:
        self.calturn.enter(now)
        return None

    def run(self, now: float, reasons: list[str], dt: float) -> Tick:
        velocity, averaged = self.calturn.tick(now, reasons)
        if averaged:
            return Tick(False, Transition(Event.ENGAGED))
        return Tick(self.outputs.stream(*velocity) if velocity is not None else False)
