"""One control step: the period's average and the INS position into the navigator, its command checked.

Every NAV_PERIOD_S of *mission time* the period's average (:class:`companion.nav.period.PeriodAverage`),
the flight controller's INS position (GLOBAL_POSITION_INT; dead reckoning on the commanded velocity
when it is missing; nothing while that position is GPS-aided or our own estimate fed back) and the
space-weather readings go into :meth:`companion.nav.navigator.Navigator.step`, which forms the
measurement, judges its plausibility and steps the core; this part says and records what it
decided. A non-finite command, a solver failure or an estimate diverging from the geomagnetic
fix (by COMP_DIVERGE_KM and beyond the two's joint 99.99 % ellipse,
:func:`companion.failsafe.diverged`) is a navigation failure, which the step returns
(:class:`StepOutcome`); the running phase (:mod:`companion.process.phases.running`) acts on it.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from companion.failsafe import diverged
from companion.fc_view import FcView
from companion.io.link.clock import MessageClock
from companion.io.link import mavlink
from companion.io.param_server import ParamServer
from companion.io.sensors.mavlink_source import MavlinkDecoder
from companion.nav.geo import enu_offset, offset_position
from companion.nav.magnetometer import MagProcessor
from companion.nav.mission import Command, Measurement, Phase
from companion.nav.navigator import SETTLE_AFTER_COMMAND_S, Navigator, Period, StepResult
from companion.nav.period import PeriodAverage
from companion.nav.plausibility import Judgement, MagPlausibility
from companion.process.filter_words import FilterWords
from companion.process.mission_state import MissionState
from companion.process.options import FC_POSITION_MAX_AGE_S
from companion.process.reporting import Reporting, plausibility_record
from companion.process.settings import Settings
from companion.process.voice import Voice
from companion.registry import READINGS

__all__ = ["ControlStep", "StepOutcome"]

# a rejected period (HOLD: the last command flies on) is a warning; a failed mission an error
_PHASE_SEVERITY = {Phase.HOLD: mavlink.MAV_SEVERITY_WARNING, Phase.FAILED: mavlink.MAV_SEVERITY_ERROR}


@dataclass(frozen=True)
class StepOutcome:
    """A step that reached the core: its command and what it was computed from. ``fault``: why
    the command is a navigation failure ("" if it is not); ``settle``, ``new_course``: the
    navigator's word on what the command changes for the samples (:class:`StepResult`)."""

    command: Command
    measurement: Measurement
    average: PeriodAverage
    ins_source: str
    fault: str
    judgement: Judgement | None
    settle: bool = False
    new_course: bool = False


class ControlStep:
    """The step, its latencies and the dead-reckoned INS position between FC positions."""

    def __init__(self, settings: Settings, state: MissionState, params: ParamServer, mag: MagProcessor,
                 decoder: MavlinkDecoder, fc_view: FcView, plausibility: MagPlausibility, msg_clock: MessageClock,
                 reporting: Reporting, voice: Voice) -> None:
        self.settings = settings
        self.mission_state = state
        self.params = params
        self.mag = mag
        self.decoder = decoder
        self.fc_view = fc_view
        self.plausibility = plausibility
        self.msg_clock = msg_clock
        self.reporting = reporting
        self.voice = voice
        self.dr: tuple[float, float, float] | None = None          # (time, lat, lon) dead reckoning
        # wall seconds of each step that reached the core: the whole step (to the outputs sent: the
        # running phase's, :meth:`took`), and its parts the benchmark splits it into: the period's
        # average, the plausibility judgement, the core
        self.step_latency_s: list[float] = []
        self.average_latency_s: list[float] = []
        self.judge_latency_s: list[float] = []
        self.core_latency_s: list[float] = []
        self.judgement: Judgement | None = None                     # the last step's plausibility verdict
        self.fresh: dict[str, bool] = {}                             # a space-weather reading fresh at the last step
        self.words = FilterWords()                                   # the filter's changes, said

    def fc_rebooted(self) -> None:
        """The FC's old clock is void: so is the dead reckoning timed on it."""
        self.dr = None

    def took(self, latency_s: float) -> None:
        """The whole step's wall time, measured by the running phase once its outputs are sent."""
        self.step_latency_s.append(latency_s)

    # ------------------------------------------------------------------ INS position
    def advance_dead_reckoning(self, now: float, dt: float, moving: bool) -> None:
        pos = self.decoder.fc_position
        command = self.mission_state.command
        if pos is not None and now - pos.time_s <= FC_POSITION_MAX_AGE_S:
            self.dr = (now, pos.lat_deg, pos.lon_deg)
            return
        if self.dr is None:
            return
        if moving and command is not None and dt > 0.0:
            c, v = command.course_rad, command.speed_mps
            lat, lon = offset_position(self.dr[1], self.dr[2], v * math.sin(c) * dt, v * math.cos(c) * dt)
            self.dr = (now, float(lat), float(lon))

    def ins_position(self, now: float) -> tuple[float, float, str]:
        independent, why = self.fc_view.position_independent(now)
        if not independent:   # GPS-aided or our own estimate: never an INS to fuse with
            return math.nan, math.nan, f"none: FC position {why}"
        pos = self.decoder.fc_position
        if pos is not None and now - pos.time_s <= FC_POSITION_MAX_AGE_S:
            return pos.lat_deg, pos.lon_deg, "fc"
        if self.dr is not None:
            return self.dr[1], self.dr[2], "dead_reckoning"
        return math.nan, math.nan, "none"

    # ------------------------------------------------------------------ the step
    def step(self, t_k: float, window_limit_s: float | None = None, avg=None) -> StepOutcome | None:
        """The control step at mission time ``t_k`` (``avg``: the start-up average for the first):
        the core's command and what it came from, or None when no period reached the core (no
        samples, or the period excluded: the next step is then one period later)."""
        state = self.mission_state
        now = self.msg_clock.now_s
        if self.settings.dirty:
            for name in self.settings.apply(state.mission):
                self.voice.say(f"FcMPC: {name} applies to the next mission", mavlink.MAV_SEVERITY_NOTICE)
        mission = state.mission
        period = mission.config.period_s
        average0 = time.perf_counter()
        if avg is None:
            avg = self.mag.take(t_k)
        average_latency = time.perf_counter() - average0
        if not avg.valid:
            # nothing to measure (should not happen: a silent magnetometer pauses the mission);
            # keep flying the command and measure again one period later (the core's dead
            # reckoning uses the actual time between steps)
            state.next_step_m = t_k + period
            self.voice.say("FcMPC: no magnetometer samples in the period, step postponed", mavlink.MAV_SEVERITY_WARNING)
            return None
        ins_lat, ins_lon, ins_source = self.ins_position(now)
        # the space-weather readings, while the ground station keeps them fresh: Kp (NAV_KP; negative:
        # none) and the ring-current index (NAV_SYMH)
        kp = self.reading("NAV_KP", now)
        kp = kp if kp >= 0.0 else math.nan
        symh = self.reading("NAV_SYMH", now)
        window = avg.window_s(t_k, period if window_limit_s is None else window_limit_s)
        navigator = Navigator(mission, self.plausibility, state.command, timer=time.perf_counter)
        result = navigator.step(Period(t_k - state.m0, avg, window, ins_lat, ins_lon, kp, symh))
        meas, cmd = result.measurement, result.command
        self.judgement = result.judgement
        if not self.report_judgement(result, meas):
            state.next_step_m = t_k + period   # fly the last command; measure again one period later
            return None
        said = self.words.start_words(mission, kp, symh) if state.command is None else self.words.step(mission, kp, symh)
        for text, severity in said:     # a storm declared, a disturbance, F weighed or set aside
            self.voice.say(text, severity)
        self.average_latency_s.append(average_latency)
        self.judge_latency_s.append(result.judge_s)
        self.core_latency_s.append(result.core_s)
        return StepOutcome(cmd, meas, avg, ins_source, self.fault(cmd), self.judgement, result.settle, result.new_course)

    def adopt(self, now: float, outcome: StepOutcome) -> None:
        """``outcome``'s command becomes the mission's command: after a turn or a speed change the
        magnetometer pipeline waits out the transient (no gravity-referenced I for
        SETTLE_AFTER_COMMAND_S), and on a new course the trim's record of the FC's yaw error starts again."""
        if outcome.settle:
            self.mag.settle_until_s = now + SETTLE_AFTER_COMMAND_S   # turn and speed transient: no I_g
        if outcome.new_course:
            self.mag.yaw_offset.new_course(now)   # the trim: the FC's yaw error differs on the new heading
        self.mission_state.command = outcome.command

    def phase_words(self, cmd: Command) -> tuple[str, int] | None:
        """The words for a command whose core phase (probe1, cruise, hold, ...) is new, with their
        severity; None when the phase is the one last said."""
        if cmd.phase == self.mission_state.last_phase:
            return None
        self.mission_state.last_phase = cmd.phase
        return (f"FcMPC: step {cmd.step} phase {cmd.phase}"
                + (f", {cmd.remaining_m / 1000.0:.1f} km to go" if math.isfinite(cmd.remaining_m) else "")
                + (f": {cmd.reason}" if cmd.reason else ""), _PHASE_SEVERITY.get(cmd.phase, mavlink.MAV_SEVERITY_NOTICE))

    def reading(self, name: str, now: float) -> float:
        """The reading ``name`` (:data:`companion.registry.READINGS`: read here, at the step, so a new
        value rebuilds no configuration) as this step's: its value
        while the ground station has set it within its lifetime of message time ``now``, else NaN.
        A reading that lapses is said once (the operator's feed has stopped)."""
        max_age_s = READINGS[name]
        fresh = self.params.age_s(name, now) <= max_age_s
        if self.fresh.get(name, False) and not fresh:
            self.voice.say(f"FcMPC: {name} not renewed for {max_age_s / 60.0:g} min: unknown until the ground "
                             f"station sets it", mavlink.MAV_SEVERITY_WARNING)
        self.fresh[name] = fresh
        return float(self.params.values[name]) if fresh else math.nan

    def report_judgement(self, result: StepResult, meas: Measurement) -> bool:
        """Say and record the plausibility check's verdict on this step (:mod:`companion.nav.plausibility`);
        False if the period was excluded."""
        judgement = result.judgement
        if result.reanchored is not None:   # the excluded fixes agreed: the estimate was wrong, not the sensor
            shift, sigma = result.reanchored
            words = self.plausibility.reanchor_words(shift)
            self.voice.say(words, mavlink.MAV_SEVERITY_WARNING)
            self.reporting.record_event("reanchored", words, **{**plausibility_record(meas, judgement),
                                        "jump_m": float(np.hypot(*shift)), "est_sigma_m": sigma})
            return True
        if result.verdict is not None:
            self.voice.say(result.verdict[1][:200], getattr(mavlink, f"MAV_SEVERITY_{result.verdict[0]}"))
        if not result.excluded:
            return True
        self.reporting.record_event("excluded", judgement.words(), decl_deg=meas.decl_deg, incl_deg=meas.incl_deg,
                                    f_nt=meas.f_nt, window_s=meas.window_s, est_lat_deg=judgement.pred_lat_deg,
                                    est_lon_deg=judgement.pred_lon_deg, est_sigma_m=judgement.sigma_m,
                                    **plausibility_record(meas, judgement))
        return False

    def fault(self, cmd) -> str:
        """Why ``cmd`` is a navigation failure ("" if it is not)."""
        if not cmd.done and not (math.isfinite(cmd.course_rad) and math.isfinite(cmd.speed_mps)):
            return "non-finite command from the navigation core"
        if not cmd.solver_ok:
            return f"solver failure: {cmd.reason}"
        if not all(math.isfinite(v) for v in (cmd.est_lat_deg, cmd.est_lon_deg, cmd.fix_lat_deg, cmd.fix_lon_deg)):
            return ""
        gap = np.array(enu_offset(cmd.est_lat_deg, cmd.est_lon_deg, cmd.fix_lat_deg, cmd.fix_lon_deg))
        if diverged(gap, self.settings.comp.diverge_m, self.gap_covariance(cmd)):
            return f"estimate diverged: {float(np.hypot(*gap)) / 1000.0:.1f} km from the geomagnetic fix"
        return ""

    def gap_covariance(self, cmd) -> np.ndarray | None:
        """Covariance (east/north, m^2) of the fix minus the estimate: the filter's own covariance
        (or its 1-sigma per axis on Table 3's path) plus the fix's own: the filter's (its biases'
        uncertainty at this heading and the noise, through G^-1) or, on Table 3's path, the
        noise from this period's scatter (the plausibility check's noise term, 3 sigma through
        G^-1, split over two axes).
        None when the estimate's uncertainty is not known."""
        ee, en, nn = cmd.est_cov_en_m2
        if all(math.isfinite(v) for v in (ee, en, nn)):
            cov = np.array([[ee, en], [en, nn]])
        elif math.isfinite(cmd.est_sigma_m):
            cov = np.eye(2) * cmd.est_sigma_m ** 2
        else:
            return None
        fe, fen, fn = cmd.fix_cov_en_m2
        if all(math.isfinite(v) for v in (fe, fen, fn)):   # the filter's: biases at this heading + noise
            return cov + np.array([[fe, fen], [fen, fn]])
        judged = self.judgement
        if judged is not None and math.isfinite(judged.noise_m):
            cov = cov + np.eye(2) * (judged.noise_m / 3.0) ** 2 / 2.0
        return cov
