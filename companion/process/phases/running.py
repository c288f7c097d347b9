"""``running``: armed in GUIDED/OFFBOARD. Entering it starts the mission (or resumes a saved or kept
one); each tick streams the command, and every NAV_PERIOD_S of mission time a control step
(:class:`companion.process.control_step.ControlStep`) returns the next command, which is published,
recorded and streamed at once (not a tick later).

The mission pauses whenever the vehicle is not following (failsafe, or not armed in
GUIDED/OFFBOARD). A mode change the companion did not command is respected: the autopilot's own
failsafe is waited out, a pilot's or ground station's pauses the mission until GUIDED/OFFBOARD is
selected again. A navigation failure holds the vehicle and restarts the mission from the last
estimate after a new stationary start-up (at most MAX_RESTARTS restarts); a flight-controller
reboot is none: the mission goes on from where it was once re-engaged.
"""
from __future__ import annotations

import math
import time

from companion.fc_view import FcView
from companion.io.link import MavlinkLink, mavlink
from companion.nav.elements import ELEMENT_SETS
from companion.nav.magnetometer import MagProcessor
from companion.nav.period import PeriodAverage
from companion.nav.mission import Command, Phase as CorePhase, uses_filter
from companion.params import NavConfig
from companion.process.control_step import ControlStep
from companion.process.estimate import CurrentEstimate
from companion.process.failsafe_response import FailsafeResponse
from companion.process.machine import Event, State
from companion.process.mission_clock import MissionClock
from companion.process.mission_state import MissionState
from companion.process.mode_commands import ModeCommands
from companion.process.operator_commands import OperatorCommands
from companion.process.options import MAX_RESTARTS
from companion.process.outputs import Outputs
from companion.process.phases.base import Phase, Tick, Transition
from companion.process.phases.engage import Engage
from companion.process.preparation import MissionPreparation
from companion.process.reporting import Reporting
from companion.process.resume import Resume
from companion.process.settings import Settings
from companion.process.voice import Voice

__all__ = ["RunningPhase"]


class RunningPhase(Phase):
    """Whether the FC followed at the last tick, and whose hold it is in when it does not."""

    state = State.RUNNING

    def __init__(self, link: MavlinkLink, settings: Settings, state: MissionState, mag: MagProcessor,
                 clock: MissionClock, stepper: ControlStep, preparation: MissionPreparation, outputs: Outputs,
                 estimate: CurrentEstimate, fc_view: FcView, modes: ModeCommands, operator: OperatorCommands,
                 engage: Engage, failsafe: FailsafeResponse, resume: Resume, reporting: Reporting,
                 voice: Voice) -> None:
        self.link = link
        self.settings = settings
        self.mission_state = state
        self.mag = mag
        self.clock = clock
        self.stepper = stepper
        self.preparation = preparation
        self.outputs = outputs
        self.estimate = estimate
        self.fc_view = fc_view
        self.modes = modes
        self.operator = operator
        self.engage = engage
        self.failsafe = failsafe
        self.resume = resume
        self.reporting = reporting
        self.voice = voice
        self.fc_failsafe_hold = ""      # the FC's own failsafe that took it out of GUIDED (re-engage when cleared)
        self.our_hold = False           # the FC left GUIDED for a mode we commanded (re-engage when healthy)
        self.was_following = False

    def forget_holds(self) -> None:
        """The FC rebooted: whatever hold it was in is gone."""
        self.our_hold = False
        self.fc_failsafe_hold = ""

    # ------------------------------------------------------------------ enter: the mission starts
    def enter(self, now: float, transition: Transition) -> Transition | None:
        self.was_following = True
        if self.resume.pending is not None:   # a saved mission, or the one kept over an FC reboot
            self.resume.resume_mission(now)
            return None
        return self.start(now)

    def start(self, now: float) -> Transition | None:
        """A new mission from the start-up average, and its first step."""
        state, prep, say = self.mission_state, self.preparation, self.voice.say
        if self.settings.dirty:
            self.settings.apply()
        lat, lon, source = prep.start_position()
        state.elements_code, why = prep.resolve_elements(now)
        config = prep.mission_config(lat, lon, state.elements_code)
        state.m0 = self.clock.mission_time(now)
        startup = self.mag.take(state.m0)
        state.bias, calibration = prep.calibration(config, startup, source)
        mission = state.mission = prep.take_mission(config)
        mission.set_bias(state.bias)
        # the error-state filter starts from the known start (a GPS fix, or the declared NAV_START
        # the mission is planned from), a position measurement with FUS_GPS_M, and observes the
        # biases there with the start-up average: the start it already trusts to FUS_GPS_M is as
        # good for the bias states as for the position. Without that calibration the bias states
        # (prior FUS_B0) are first pinned one step later against the INS-predicted position
        # (1-sigma 2.5 km after 360 s of a 10 m/s velocity error), and what they absorb then stays
        # as an offset: closed loop against the stand-in (no GPS, NAV_START) the short mission
        # ended 0.9 km off against 0.3 km in-process, which calibrates; in-process without the
        # calibration, 0.9 km. Table 3's constant bias (set_bias) stays GPS-only.
        mission.set_start_fix(config.gps_sigma_m if source in ("GPS", "NAV_START") else None,
                              calibrate=source in ("GPS", "NAV_START"))
        state.mission_no += 1
        self.resume.new_mission()
        state.last_phase = ""
        say(f"FcMPC: mission {state.mission_no} start {lat:.4f},{lon:.4f} ({source})")
        elements = ELEMENT_SETS[state.elements_code]
        aside = f"; {elements.f_condition}" if uses_filter(config) and elements.f_condition else ""
        say(f"FcMPC: elements {elements.label}: {why}{aside}"[:200])
        if calibration:
            say(f"FcMPC: {calibration}"[:200])
        transition = self.step(now, state.m0, window_limit_s=0.0, avg=startup)
        self.say_how_it_navigates(config)
        return transition

    def say_how_it_navigates(self, config: NavConfig) -> None:
        """After the mission's first step: the position filter it runs, the ring current it removes,
        and what it steers by, each in a STATUSTEXT."""
        mission, say = self.mission_state.mission, self.voice.say
        estimator = getattr(mission, "estimator", None) if mission is not None else None
        if estimator is not None and estimator.reason:
            say(f"FcMPC: position filter: {estimator.reason}"[:200])
        if estimator is not None and estimator.ring_current_removed:
            say(f"FcMPC: ring current removed: NAV_SYMH {estimator.symh_reference_nt:g} nT at the start, "
                f"its change x FUS_SYMH_K {config.symh_ratio:g} along H"[:200])
        trim = self.settings.comp.trim_max_deg
        say(f"FcMPC: steering: the measured heading, course trimmed by the FC's yaw error up to {trim:g} deg"
            if trim > 0.0 else "FcMPC: steering: the FC's yaw (COMP_TRIM_DEG 0)")

    # ------------------------------------------------------------------ run
    def run(self, now: float, reasons: list[str], dt: float) -> Tick:
        fc, state = self.link.fc, self.mission_state
        following = fc.armed and fc.guided
        if self.was_following and not following and not fc.guided \
                and self.modes.confirm(fc.custom_mode, fc.last_heartbeat_time_s):
            self.our_hold = True   # the FC shows a mode we commanded (however late): ours to take back
        elif self.was_following and not following:
            # a mode change we did not ask for: the autopilot's own failsafe is waited out and the
            # mission re-engages when it clears; a pilot's or ground station's is respected, and
            # the mission waits until GUIDED/OFFBOARD is selected again
            conv = fc.conventions
            guided = conv.mode_name(conv.custom_mode(conv.guided_main, conv.guided_sub))
            self.fc_failsafe_hold = self.fc_view.fc_failsafe
            why = f"its own failsafe ({self.fc_failsafe_hold}): re-engaging when it clears" \
                if self.fc_failsafe_hold else "mission paused"
            self.voice.say(f"FcMPC: FC left {guided} (now {fc.mode_name}{'' if fc.armed else ', disarmed'}): "
                           f"{why}"[:200], mavlink.MAV_SEVERITY_WARNING)
        if following:
            self.fc_failsafe_hold = ""
            self.our_hold = False
            if not self.was_following and state.command is not None and state.command.speed_mps > 0.0:
                self.mag.yaw_offset.new_course(now)   # moving again after a hold: a new record for the trim
        self.was_following = following
        flying = following and not self.operator.held     # the operator's hold counts as not following
        self.stepper.advance_dead_reckoning(now, dt, flying and not reasons)
        if reasons or not flying:
            self.clock.pause(now)
        else:
            self.clock.resume(now)   # pending mode commands stay: a late HOLD of ours is still ours
        if reasons:
            return Tick(False)
        if self.operator.held:
            return Tick(self.operator.held_tick(now, following))
        # the stream first: its cadence is the FC's proof of life (PX4 leaves OFFBOARD after
        # COM_OF_LOSS_T without one), whatever the step below costs
        sent = self.outputs.stream_command(state.command) if state.command is not None else False
        if not following:
            if self.our_hold or (self.fc_failsafe_hold and not self.fc_view.fc_failsafe):
                self.engage.engage(now)   # our failsafe's hold, or the FC's own failsafe cleared: take it back
            return Tick(sent)
        if self.clock.mission_time(now) >= state.next_step_m:
            previous = state.command
            transition = self.step(now, state.next_step_m)
            if transition is not None:
                return Tick(sent, transition)
            if state.command is not None and state.command is not previous:
                # the step's new command goes out now, not a tick (1 / COMP_SP_RATE_HZ) later
                sent = self.outputs.stream_command(state.command) or sent
        return Tick(sent)

    # ------------------------------------------------------------------ the step's result
    def step(self, now: float, t_k: float, window_limit_s: float | None = None,
             avg: PeriodAverage | None = None) -> Transition | None:
        """The control step at mission time ``t_k``, and what its command does: published,
        recorded, then a navigation failure, the mission's end, or the command flown on."""
        wall0 = time.perf_counter()
        outcome = self.stepper.step(t_k, window_limit_s, avg)
        if outcome is None:   # no period reached the core: the last command flies on
            return None
        cmd, state = outcome.command, self.mission_state
        self.outputs.publish(cmd, outcome.average)
        if self.fc_view.feeding_own and cmd.phase == CorePhase.CRUISE:
            self.fc_view.feed.correct_to(now, cmd.est_lat_deg, cmd.est_lon_deg, self.estimate.sigma_m())
        latency = time.perf_counter() - wall0
        self.stepper.took(latency)
        self.reporting.record_step(cmd, outcome.measurement, outcome.average, outcome.ins_source, latency, "step",
                                   outcome.fault or cmd.reason, self.outputs.course_to_send(cmd), outcome.judgement)
        if outcome.fault:
            return self.nav_failure(now, outcome.fault, cmd)
        self.stepper.adopt(now, outcome)
        words = self.stepper.phase_words(cmd)
        if words is not None:
            self.voice.say(*words)
        if cmd.done:
            return Transition(Event.ENDED, cmd.reason or cmd.phase)
        state.next_step_m = t_k + state.mission.config.period_s
        self.resume.save()
        return None

    def nav_failure(self, now: float, reason: str, cmd: Command) -> Transition:
        """Hold the vehicle; restart from the last estimate, or give up after MAX_RESTARTS."""
        state = self.mission_state
        self.voice.say(f"FcMPC FAILSAFE: {reason}"[:200], mavlink.MAV_SEVERITY_CRITICAL)
        self.failsafe.hold_if_guided(now)
        state.restarts += 1
        if state.restarts > MAX_RESTARTS:
            state.command = cmd
            return Transition(Event.GAVE_UP, f"{reason}; gave up after {MAX_RESTARTS} restarts")
        est = (cmd.est_lat_deg, cmd.est_lon_deg)
        if not all(math.isfinite(v) for v in est) and state.command is not None:
            est = (state.command.est_lat_deg, state.command.est_lon_deg)
        state.restart_from = est if all(math.isfinite(v) for v in est) else None
        state.mission = None
        state.command = None
        return Transition(Event.NAV_FAILED, f"restart {state.restarts} after: {reason}")

    # ------------------------------------------------------------------ an FC reboot
    def fc_rebooted(self, now: float, last_old_s: float, reason: str) -> Transition:
        """The FC rebooted under the mission: it goes on from its last estimate once re-engaged
        (kept by :meth:`Resume.continue_after_reboot`), unless no tick ran on the old clock to go
        on from (a navigation failure) or there is no mission yet."""
        state = self.mission_state
        if state.mission is not None and state.command is not None and math.isfinite(last_old_s):
            self.resume.continue_after_reboot(last_old_s)
            self.voice.say(f"FcMPC: {reason}: mission {state.mission_no} goes on from its last estimate at step "
                           f"{state.command.step} once re-armed"[:200], mavlink.MAV_SEVERITY_WARNING)
            return Transition(Event.FC_REBOOTED, reason)
        if state.command is not None:
            return self.nav_failure(now, reason, state.command)
        self.voice.say(f"FcMPC: {reason}", mavlink.MAV_SEVERITY_WARNING)
        self.mag.recorder = None
        state.mission = None
        return Transition(Event.FC_REBOOTED, reason)
