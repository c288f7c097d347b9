"""The companion's phases, one class each, driven by :mod:`companion.process.machine`'s table.

::

    base.py         Phase (enter / run / exit), Tick and Transition: what a phase returns
    wait_fc.py      no FC heartbeat yet; leaving it, the FC is said and its streams asked for
    startup.py      the stationary start-up average; a saved mission goes straight on to ready
    ready.py        zero setpoints, GUIDED/OFFBOARD and arming; the next mission built meanwhile
    calibrating.py  the magnetometer's calibration circles (COMP_CAL_TURNS)
    running.py      the mission: start or resume on entering, a control step every NAV_PERIOD_S
    done.py         arrived, failed or given up: hold
    engage.py       GUIDED/OFFBOARD then arm, with retries (ready and running use it)

As ArduPilot's modes (``Rover/mode.h``: ``_enter()``, ``update()``, ``_exit()``; the vehicle
changes mode only through ``set_mode()``), a phase never changes the phase itself: it returns the
transition it wants, and :class:`Phases` takes it through the table, calling the old phase's
:meth:`~base.Phase.exit` and the new one's :meth:`~base.Phase.enter`.
"""
from __future__ import annotations

from companion.io.link import mavlink
from companion.nav.magnetometer import MagProcessor
from companion.nav.period import PeriodAverage
from companion.process.machine import STATE_CODES, Event, IllegalTransition, PhaseMachine, State
from companion.process.mission_state import MissionState
from companion.process.phases.base import Phase, Tick, Transition
from companion.process.phases.calibrating import CalibratingPhase
from companion.process.phases.done import DonePhase
from companion.process.phases.engage import Engage
from companion.process.phases.ready import ReadyPhase
from companion.process.phases.running import RunningPhase
from companion.process.phases.startup import StartupPhase
from companion.process.phases.wait_fc import WaitFcPhase
from companion.process.voice import Voice

__all__ = ["TICK_ORDER", "Phase", "Phases", "Tick", "Transition"]

# The phases a tick runs, in this order: a phase entered on the way runs in the same tick.
TICK_ORDER = (State.STARTUP, State.READY, State.CALIBRATING, State.RUNNING, State.DONE)


class Phases:
    """The current phase's work each tick, and every transition taken through the machine."""

    def __init__(self, machine: PhaseMachine, state: MissionState, mag: MagProcessor, engage: Engage,
                 voice: Voice, wait_fc: WaitFcPhase, startup: StartupPhase, ready: ReadyPhase,
                 calibrating: CalibratingPhase, running: RunningPhase, done: DonePhase) -> None:
        self.machine = machine
        self.mission_state = state
        self.mag = mag
        self.engage = engage
        self.voice = voice
        self.running = running
        self.phases: dict[str, Phase] = {p.state: p for p in (wait_fc, startup, ready, calibrating, running, done)}
        missing = set(STATE_CODES) - set(self.phases)
        if missing:
            raise ValueError(f"no phase object for {sorted(missing)}")

    @property
    def current(self) -> Phase:
        return self.phases[self.machine.state]

    def take(self, transition: Transition | None, now: float) -> None:
        """Take ``transition`` (and any its new phase asks for on entering); one the table lacks
        raises :class:`IllegalTransition` before the current phase is left."""
        while transition is not None:
            if not self.machine.can(transition.event):
                raise IllegalTransition(f"no transition from {self.machine.state} on {transition.event}")
            self.current.exit(now)
            self.machine.fire(transition.event)
            transition = self.current.enter(now, transition)

    def tick(self, now: float, reasons: list[str], dt: float) -> bool:
        """The current phase's work this tick (a phase entered on the way runs too); True if a
        setpoint was sent."""
        sent = False
        for state in TICK_ORDER:
            if self.machine.state != state:
                continue
            result = self.phases[state].run(now, reasons, dt)
            if result.sent is not None:
                sent = result.sent
            self.take(result.transition, now)
        return sent

    def fc_heard(self, now: float) -> None:
        """wait_fc -> startup: the first flight-controller heartbeat with a time stamp."""
        self.take(Transition(Event.FC_HEARD, "start-up"), now)

    def step(self, now: float, t_k: float, window_limit_s: float | None = None, avg: PeriodAverage | None = None) -> None:
        """A control step of the running mission now (at mission time ``t_k``), and what it leads to."""
        self.take(self.running.step(now, t_k, window_limit_s, avg), now)

    def fc_rebooted(self, now: float, last_old_s: float) -> None:
        """The flight controller's clock went back (it rebooted): everything timed on its old clock is
        void (the parts were told), and it comes back disarmed. A running mission goes on, from its
        last estimate with its filter and step clock (:meth:`RunningPhase.fc_rebooted`): no new
        start-up average, no probing again, and not a navigation failure (it uses none of
        MAX_RESTARTS). Otherwise the start-up begins again (a pending resume is kept: its times are
        relative to the mission). ``last_old_s``: the last tick's message time on the old clock."""
        self.engage.fc_rebooted()
        self.running.forget_holds()
        reason = "flight controller rebooted (its clock went back)"
        phase = self.machine.state
        if phase == State.RUNNING:
            transition = self.running.fc_rebooted(now, last_old_s, reason)
        elif phase in (State.STARTUP, State.READY, State.CALIBRATING):
            self.voice.say(f"FcMPC: {reason}", mavlink.MAV_SEVERITY_WARNING)
            self.mag.recorder = None
            self.mission_state.mission = None
            transition = Transition(Event.FC_REBOOTED, reason)
        else:
            return
        self.take(transition, now)
