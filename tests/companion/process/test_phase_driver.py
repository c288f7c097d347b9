"""The phase driver: a phase returns the transition it wants; the driver takes it through the
table (the old phase's exit, the machine, the new phase's enter) and runs a phase entered on the
way in the same tick, as the companion's tick always did."""
from __future__ import annotations

import pytest

from companion.process.machine import Event, IllegalTransition, PhaseMachine, State
from companion.process.mission_state import MissionState
from companion.process.phases import Phase, Phases, Tick, Transition


class Recorded(Phase):
    """A phase that records what the driver asked of it and answers from a script."""

    def __init__(self, state: str, log: list, run: Tick = Tick(), enter: Transition | None = None) -> None:
        self.state, self.log, self._run, self._enter = state, log, run, enter

    def enter(self, now, transition):
        self.log.append(("enter", self.state, transition.event))
        return self._enter

    def run(self, now, reasons, dt):
        self.log.append(("run", self.state))
        return self._run

    def exit(self, now):
        self.log.append(("exit", self.state))


def _driver(log: list, **scripts) -> tuple[Phases, PhaseMachine]:
    machine = PhaseMachine()
    phases = {s: Recorded(s, log, **scripts.get(s, {})) for s in
              (State.WAIT_FC, State.STARTUP, State.READY, State.CALIBRATING, State.RUNNING, State.DONE)}
    driver = Phases(machine, MissionState(), None, None, None, *phases.values())
    return driver, machine


def test_a_phase_entered_on_the_way_runs_in_the_same_tick():
    log: list = []
    driver, machine = _driver(log, **{State.STARTUP: {"run": Tick(transition=Transition(Event.AVERAGED))},
                                      State.READY: {"run": Tick(True, Transition(Event.ENGAGED))},
                                      State.RUNNING: {"run": Tick(None)}})
    driver.fc_heard(10.0)
    assert machine.state == State.STARTUP and log == [("exit", "wait_fc"), ("enter", "startup", "fc_heard")]
    log.clear()
    assert driver.tick(11.0, [], 0.2) is True                  # ready's setpoint; running said nothing
    assert machine.state == State.RUNNING
    assert log == [("run", "startup"), ("exit", "startup"), ("enter", "ready", "averaged"), ("run", "ready"),
                   ("exit", "ready"), ("enter", "running", "engaged"), ("run", "running")]


def test_a_transition_asked_for_on_entering_is_taken_and_a_phase_left_backwards_waits_a_tick():
    log: list = []
    driver, machine = _driver(log, **{State.RUNNING: {"enter": Transition(Event.NAV_FAILED, "first step failed")}})
    machine.state = State.READY
    driver.take(Transition(Event.ENGAGED), 5.0)
    assert machine.state == State.STARTUP                       # running -> startup on entering
    assert [e for e in log if e[0] == "enter"] == [("enter", "running", "engaged"), ("enter", "startup", "nav_failed")]
    log.clear()
    assert driver.tick(6.0, [], 0.2) is False and log == [("run", "startup")]


def test_a_transition_the_table_lacks_raises_before_the_phase_is_left():
    log: list = []
    driver, machine = _driver(log, **{State.STARTUP: {"run": Tick(transition=Transition(Event.ENDED))}})
    driver.fc_heard(0.0)
    log.clear()
    with pytest.raises(IllegalTransition):
        driver.tick(1.0, [], 0.2)
    assert machine.state == State.STARTUP and log == [("run", "startup")]   # not left, nothing entered
