"""The companion's phases as an explicit state machine: the table below is the whole of it.

::

    wait_fc --fc_heard--> startup --averaged/resumed--> ready --engaged--> running --ended/gave_up--> done
                            ^  ^                  |  |                ^   |
                            |  +---fc_rebooted----+  +--calibrate--> calibrating (COMP_CAL_TURNS)
                            +---------nav_failed / fc_rebooted--------+---+

``wait_fc``  no flight-controller HEARTBEAT yet.
``startup``  streams requested; the vehicle is stationary while D and I are averaged.
``ready``    the average is taken; zero setpoints, GUIDED/OFFBOARD and arming (COMP_ARM_ENABLE 1).
``calibrating``  armed in GUIDED/OFFBOARD, COMP_CAL_TURNS > 0 and a GPS start: the magnetometer's
             calibration circles, then one more for the start-up average (``engaged``).
``running``  armed in GUIDED/OFFBOARD: a control step every NAV_PERIOD_S of mission time.
``done``     arrived, failed, or gave up after MAX_RESTARTS navigation failures: hold.

A failsafe is not a phase: it overlays ``running`` (the mission pauses, the vehicle holds) and is
decided by :mod:`companion.process.failsafe_response`. What each phase does on a tick and what a
transition does (start a mission, restart it, finish) is in :mod:`companion.process.phases`.
Drawing it: ``print(to_dot())`` and Graphviz.

>>> m = PhaseMachine()
>>> m.fire(Event.FC_HEARD)
'startup'
>>> m.fire(Event.ENGAGED)  # doctest: +IGNORE_EXCEPTION_DETAIL
Traceback (most recent call last):
...
companion.process.machine.IllegalTransition: no transition from startup on engaged
"""
from __future__ import annotations

__all__ = [
    "FAILSAFE_CODE",
    "STATE_CODES",
    "TRANSITIONS",
    "Event",
    "IllegalTransition",
    "PhaseMachine",
    "State",
    "to_dot",
]


class State:
    """The phases (plain strings: they are written to steps.csv and summary.json as they are)."""

    WAIT_FC = "wait_fc"
    STARTUP = "startup"
    READY = "ready"
    CALIBRATING = "calibrating"
    RUNNING = "running"
    DONE = "done"


class Event:
    FC_HEARD = "fc_heard"            # the first flight-controller heartbeat with a time stamp
    AVERAGED = "averaged"            # the stationary start-up window is full, the heading source known
    RESUMED = "resumed"              # a recent saved state: no start-up average, the saved mission goes on
    CALIBRATE = "calibrate"          # armed in GUIDED/OFFBOARD with COMP_CAL_TURNS: the calibration circles
    ENGAGED = "engaged"              # armed in GUIDED/OFFBOARD and healthy: the mission starts
    ENDED = "ended"                  # the core says arrived or failed
    NAV_FAILED = "nav_failed"        # solver failure, divergence, non-finite command: restart
    GAVE_UP = "gave_up"              # a navigation failure after MAX_RESTARTS restarts
    FC_REBOOTED = "fc_rebooted"      # the flight controller's clock went back


# (phase, event) -> next phase. Anything else is a bug and raises.
TRANSITIONS: dict[tuple[str, str], str] = {
    (State.WAIT_FC, Event.FC_HEARD): State.STARTUP,
    (State.STARTUP, Event.AVERAGED): State.READY,
    (State.STARTUP, Event.RESUMED): State.READY,
    (State.STARTUP, Event.FC_REBOOTED): State.STARTUP,
    (State.READY, Event.ENGAGED): State.RUNNING,
    (State.READY, Event.CALIBRATE): State.CALIBRATING,
    (State.CALIBRATING, Event.ENGAGED): State.RUNNING,
    (State.CALIBRATING, Event.FC_REBOOTED): State.STARTUP,
    (State.READY, Event.FC_REBOOTED): State.STARTUP,
    (State.RUNNING, Event.ENDED): State.DONE,
    (State.RUNNING, Event.GAVE_UP): State.DONE,
    (State.RUNNING, Event.NAV_FAILED): State.STARTUP,
    (State.RUNNING, Event.FC_REBOOTED): State.STARTUP,
}

# The FC_STATE value the companion streams in lockstep (4: failsafe, whatever the phase).
STATE_CODES = {State.WAIT_FC: 0, State.STARTUP: 1, State.READY: 2, State.RUNNING: 3, State.DONE: 5,
               State.CALIBRATING: 6}
FAILSAFE_CODE = 4


class IllegalTransition(RuntimeError):
    """An event the current phase has no transition for: a bug in the caller."""


class PhaseMachine:
    """The current phase and the transitions taken (message time, from, event, to)."""

    def __init__(self, state: str = State.WAIT_FC) -> None:
        self.state = state
        self.history: list[tuple[str, str, str]] = []

    def can(self, event: str) -> bool:
        return (self.state, event) in TRANSITIONS

    def fire(self, event: str) -> str:
        """Take the transition for ``event`` from the current phase; the new phase."""
        try:
            new = TRANSITIONS[(self.state, event)]
        except KeyError:
            raise IllegalTransition(f"no transition from {self.state} on {event}") from None
        self.history.append((self.state, event, new))
        del self.history[:-100]
        self.state = new
        return new

    def code(self, failsafe: bool) -> int:
        return FAILSAFE_CODE if failsafe else STATE_CODES[self.state]


def to_dot() -> str:
    """The transition table as a Graphviz digraph."""
    edges = "\n".join(f'  {a} -> {b} [label="{e}"];' for (a, e), b in TRANSITIONS.items())
    return f"digraph companion {{\n{edges}\n}}\n"
