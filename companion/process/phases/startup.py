"""``startup``: the vehicle is stationary while D and I are averaged over the start-up window
(default one control period), which becomes the first measurement; a failsafe reason or a moving
vehicle starts the window again. Entered from ``wait_fc``, after a navigation failure and after an
FC reboot; a saved (or, after a reboot, a kept) mission goes straight on to ``ready``."""
from __future__ import annotations

from companion.fc_view import FcView
from companion.io.link import MavlinkLink
from companion.nav.magnetometer import MagProcessor
from companion.process.machine import Event, State
from companion.process.mission_clock import MissionClock
from companion.process.mission_state import MissionState
from companion.process.phases.base import Phase, Tick, Transition
from companion.process.preparation import MissionPreparation
from companion.process.reporting import Reporting
from companion.process.resume import Resume
from companion.process.settings import Settings
from companion.process.voice import Voice

__all__ = ["StartupPhase"]


class StartupPhase(Phase):
    state = State.STARTUP

    def __init__(self, link: MavlinkLink, settings: Settings, state: MissionState, mag: MagProcessor,
                 clock: MissionClock, preparation: MissionPreparation, fc_view: FcView, resume: Resume,
                 reporting: Reporting, voice: Voice) -> None:
        self.link = link
        self.settings = settings
        self.mission_state = state
        self.mag = mag
        self.clock = clock
        self.preparation = preparation
        self.fc_view = fc_view
        self.resume = resume
        self.reporting = reporting
        self.voice = voice

    def enter(self, now: float, transition: Transition) -> Transition | None:
        self.mission_state.startup_begin = now
        self.clock.reset()
        self.mag.clear()
        why = transition.why
        self.reporting.record_event("start" if why == "start-up" else "restart", why)
        if transition.event == Event.FC_HEARD:
            self.resume.judge_saved()
        if transition.event in (Event.FC_HEARD, Event.FC_REBOOTED) and self.resume.pending is not None:
            return Transition(Event.RESUMED)
        return None

    def moving(self) -> bool:
        """The vehicle may be moving: armed and not in a hold mode (a pilot or a mission drives it).

        The flight controller's velocity is no evidence: without GPS its INS velocity drifts."""
        fc = self.link.fc
        return fc.armed and not fc.holding and not (fc.guided and self.settings.comp.arm_enable)

    def run(self, now: float, reasons: list[str], dt: float) -> Tick:
        state, mag = self.mission_state, self.mag
        if reasons or self.moving():
            state.startup_begin = now
            mag.clear()
            return Tick()
        if now - state.startup_begin >= self.preparation.startup_window() and len(mag.averager):
            if self.fc_view.heading_verdict(now) is None:
                return Tick()   # still reading the FC's heading parameters: keep averaging
            self.voice.say(f"FcMPC: ready, start-up average of {len(mag.averager)} samples"
                           + ("" if self.settings.comp.arm_enable else "; arm in GUIDED/OFFBOARD to start"))
            return Tick(transition=Transition(Event.AVERAGED))
        return Tick()
