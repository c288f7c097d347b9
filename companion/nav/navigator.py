"""One navigation step: a period's average becomes a fix, a filter update and a command.

:meth:`Navigator.step` is the one place this happens; the companion
(:class:`companion.process.control_step.ControlStep`), the in-process Monte Carlo
(:class:`fcmpc.montecarlo.inprocess.InProcessFlight`) and the log replay (:func:`fcmpc.replay.heading.run_mission`)
all call it, so every figure the Monte Carlo prints describes what the vehicle runs. In order:

1. **The measurement** (:meth:`Navigator.measurement`): the period's D and F as averaged; I
   gravity-referenced for a heading-free element set when the period had gravity samples, else
   tilt-compensated (:func:`companion.nav.period.measured_inclination`); H and Z from F and that I
   (no heading enters either), their standard errors from F's and I's
   (:func:`companion.nav.elements.hz_standard_errors`); the INS position and the space-weather
   readings the vehicle had at the step (:class:`Period`).
2. **Plausibility** (:mod:`companion.nav.plausibility`): from the second step on, the measurement is
   judged against the last estimate flown on with the last command; an implausible one is
   excluded (no command: the last one flies on, and the next period is measured one period later)
   unless the excluded fixes agree, when the core re-anchors there and takes it; once the last
   command has carried the vehicle to the estimated destination, an excluded period ends the
   mission there instead of flying it on past it, blind (:func:`companion.nav.arrival.passed_destination`).
3. **The core's step** (:meth:`companion.nav.mission.Mission.step`: the fix, the filter's update,
   the MPC), which never raises on a measurement (:mod:`companion.nav.screening`).
4. At the first step, the start (a known position): the |F| level the plausibility band is judged
   about (:meth:`Navigator.learn_f_reference`).
5. What the command changes for the next period's samples: a new course or speed lets the
   gravity-referenced I wait :data:`SETTLE_AFTER_COMMAND_S` (the turn's and the speed change's
   accelerations tilt the specific force), and a new course restarts the steering trim's
   estimate (:func:`companion.nav.steering.is_new_course`).

Pure: no sockets, clocks or files; time comes from the period. The caller owns what surrounds the
step: where the samples come from, the checks of the command against the vehicle's limits, what is
said and recorded.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from companion.nav.arrival import passed_destination
from companion.nav.elements import hz_standard_errors
from companion.nav.geo import geodesic_inverse, offset_position
from companion.nav.heading import window_heading_rad
from companion.nav.mission import Command, Measurement, Mission, end_blind
from companion.nav.period import PeriodAverage, measured_inclination
from companion.nav.plausibility import Judgement, MagPlausibility, element_noise, f_offset_nt, judge, navigator_bias
from companion.nav.steering import is_new_course
from companion.nav.step_io import Phase

__all__ = ["NEW_COMMAND_COURSE_RAD", "SETTLE_AFTER_COMMAND_S", "Navigator", "Period", "StepResult"]

SETTLE_AFTER_COMMAND_S = 60.0     # gravity-referenced I waits this long after a new course or speed
NEW_COMMAND_COURSE_RAD = 0.02     # a course change beyond this is a new command for the settling wait


@dataclass(frozen=True)
class Period:
    """What a navigator is given at a control step.

    ``time_s``: the step's time (the core's clock, seconds since the mission's start);
    ``average``: the period's average (:class:`~companion.nav.period.PeriodAverage`); ``window_s``:
    the span the average refers to, ending at ``time_s`` (0: an instantaneous value); the INS
    position (degrees; NaN when there is none independent of this navigator); ``kp`` and
    ``symh_nt``: the space-weather readings the vehicle has now (NaN: none).
    """

    time_s: float
    average: PeriodAverage
    window_s: float
    ins_lat_deg: float = math.nan
    ins_lon_deg: float = math.nan
    kp: float = math.nan
    symh_nt: float = math.nan


@dataclass(frozen=True)
class StepResult:
    """What one step gave. ``command`` None: the period was excluded (``judgement`` says why) and
    the last command flies on. ``reanchored``: (shift east/north m, its 1-sigma m) when the
    excluded fixes agreed and the estimate was moved there. ``verdict``: (severity name, text) the
    plausibility check has to say, if anything. ``settle``: the command is a new course or speed
    (gravity-referenced I waits :data:`SETTLE_AFTER_COMMAND_S`); ``new_course``: a new course for
    the steering trim."""

    measurement: Measurement
    command: Command | None
    judgement: Judgement | None = None
    reanchored: tuple[np.ndarray, float] | None = None
    verdict: tuple[str, str] | None = None
    settle: bool = False
    new_course: bool = False
    judge_s: float = math.nan     # seconds the judgement and the core's step took (the injected timer's)
    core_s: float = math.nan

    @property
    def excluded(self) -> bool:
        return self.command is None


class Navigator:
    """A mission's navigation step and the state it keeps between steps: the core (``mission``),
    the plausibility check's (``plausibility``: exclusions in a row, the re-anchoring consensus,
    the |F| reference) and the last command flown (``command``, None before the first step).
    ``timer``: a clock (seconds) to time the judgement and the core's step with, for a benchmark
    (None: not timed); nothing else reads it."""

    def __init__(self, mission: Mission, plausibility: MagPlausibility | None = None,
                 command: Command | None = None, timer: Callable[[], float] | None = None) -> None:
        self.mission = mission
        self.plausibility = MagPlausibility() if plausibility is None else plausibility
        self.command = command
        self.timer = timer

    def measurement(self, period: Period) -> Measurement:
        """The core's measurement of ``period`` (module docstring, 1)."""
        avg = period.average
        incl, incl_se = measured_inclination(avg, self.mission.measured.heading_free)
        # H and Z from F and the (gravity-referenced) I: no heading enters either
        h_nt, z_nt = avg.f_nt * math.cos(math.radians(incl)), avg.f_nt * math.sin(math.radians(incl))
        h_se, z_se = hz_standard_errors(avg.f_nt, incl, avg.f_se_nt, incl_se)
        return Measurement(period.time_s, avg.decl_deg, incl, period.ins_lat_deg, period.ins_lon_deg, period.window_s,
                           avg.f_nt, h_nt, z_nt, avg.decl_se_deg, incl_se, avg.f_se_nt, h_se, z_se,
                           avg.mag_heading_deg, period.kp, period.symh_nt)

    def step(self, period: Period) -> StepResult:
        """One control step on ``period`` (module docstring). Never raises on a measurement."""
        timer = self.timer or (lambda: math.nan)
        meas = self.measurement(period)
        previous = self.command
        judge0 = timer()
        judgement, reanchored, verdict = self._judge(meas)
        core0 = timer()
        if judgement is not None and not judgement.ok and reanchored is None:
            if not self._overdue(judgement):
                ended = self._end_blind(previous, meas, judgement)
                if ended is not None:
                    return StepResult(meas, ended[0], judgement, None, ended[1], judge_s=core0 - judge0)
                return StepResult(meas, None, judgement, None, verdict, judge_s=core0 - judge0)
            verdict = ("WARNING", f"FcMPC: {self.plausibility.taken_anyway()} periods excluded in a row: this one "
                                  f"is taken ({judgement.words()})")
        command = self.mission.step(meas)
        core_s = timer() - core0
        if previous is None:
            self.learn_f_reference(meas)
        before = None if previous is None else (previous.course_rad, previous.speed_mps)
        settle = (previous is None or abs(previous.course_rad - command.course_rad) > NEW_COMMAND_COURSE_RAD
                  or previous.speed_mps != command.speed_mps)
        new_course = is_new_course(before, command.course_rad, command.speed_mps)
        self.command = command
        return StepResult(meas, command, judgement, reanchored, verdict, settle, new_course, core0 - judge0, core_s)

    def _end_blind(self, previous: Command | None, meas: Measurement,
                   judgement: Judgement) -> tuple[Command, tuple[str, str]] | None:
        """(the mission's end, what to say) when the excluded period ``meas`` came after the last
        command had reached the estimated destination; None to fly it on."""
        config = self.mission.config
        if previous is None or previous.done or previous.phase != Phase.CRUISE:
            return None
        _, bearing = geodesic_inverse(previous.est_lat_deg, previous.est_lon_deg, config.dest_lat_deg,
                                      config.dest_lon_deg)
        off_course = math.remainder(previous.course_rad - bearing, 2.0 * math.pi)
        if not passed_destination(previous.remaining_m, off_course, previous.speed_mps, meas.time_s - previous.time_s,
                                  config.arrive_m):
            return None
        reason = f"at the estimated destination on dead reckoning, the period after the leg there excluded ({judgement.words()})"
        command = end_blind(self.mission, meas.time_s, reason)
        self.command = command
        return command, ("WARNING", f"FcMPC: arrived {reason}")

    def _overdue(self, judgement: Judgement) -> bool:
        """True when this exclusion would exceed NAV_EXCL_MAX in a row: the period is taken (the core's
        own screening and fix gate still judge it), so that a wrong estimate or |F| reference cannot
        exclude every later period and the vehicle fly its last course on for good (realistic
        Pacific, seed 23: every period |F|-band excluded for 31 h from the first step on)."""
        limit = self.mission.config.excl_max
        return limit > 0 and self.plausibility.in_a_row > limit

    def learn_f_reference(self, meas: Measurement) -> None:
        """At the first step, the start (a known position): learn the |F| level the band is judged
        about, with the bias the core chose to subtract there. Learnt before the core's first step,
        it took the bias before auto had fallen back to Table 3's constant calibration (zero), and
        every later step subtracted the calibration a second time (PX4 SIH, +590 nT: periods judged
        1000-1040 nT off and excluded, 4 of 11 in 30 minutes)."""
        mission = self.mission
        model = getattr(mission, "model", None)   # (a test's stand-in core has none)
        config = mission.config
        self.plausibility.f_reference_nt = None if model is None else f_offset_nt(
            model, mission.elements, config.year, config.alt_m, meas.f_nt, mission.bias,
            config.start_lat_deg, config.start_lon_deg)

    def _judge(self, meas: Measurement) -> tuple[Judgement | None, tuple[np.ndarray, float] | None,
                                                 tuple[str, str] | None]:
        """(judgement, re-anchoring, verdict) of ``meas`` against the predicted position
        (:mod:`companion.nav.plausibility`); no judgement at the first step (nothing to judge
        against) or once the last command is final or has no estimate."""
        cmd, mission, plausibility = self.command, self.mission, self.plausibility
        config = mission.config
        if cmd is None or cmd.done or not (math.isfinite(cmd.est_lat_deg) and math.isfinite(cmd.est_lon_deg)):
            return None, None, None
        dt = max(meas.time_s - 0.5 * meas.window_s - cmd.time_s, 0.0)   # to the centre of the window
        flown = cmd.speed_mps * dt
        lat, lon = offset_position(cmd.est_lat_deg, cmd.est_lon_deg, flown * math.sin(cmd.course_rad),
                                   flown * math.cos(cmd.course_rad))
        # against this fix: the estimate's uncertainty less the field-model error the two share
        sigma = next(v for v in (cmd.next_fix_sigma_m, cmd.est_sigma_m, math.sqrt(config.fusion.rc_m2))
                     if math.isfinite(v))
        reference = plausibility.f_reference_nt
        if reference is None or not math.isfinite(reference):   # resumed mid-route: no start to learn it at
            reference = 0.0
        # judged as the navigator will see it: with the error-state filter, its bias states (which
        # follow a storm it has recognised) are removed and their uncertainty widens the bound;
        # judged against the start-up calibration alone, a storm the filter was tracking drove the
        # implied jump past the bound and every later step was excluded (short storm, seed 0)
        velocity = np.array([cmd.speed_mps * math.sin(cmd.course_rad), cmd.speed_mps * math.cos(cmd.course_rad)])
        bias, bias_sigma = navigator_bias(mission, window_heading_rad(meas, velocity))
        se = {"decl_deg": meas.decl_se_deg, "incl_deg": meas.incl_se_deg, "f_nt": meas.f_se_nt}
        noise = np.hypot(element_noise(mission.elements, meas.incl_deg, meas.f_nt, se), bias_sigma)
        judgement = judge(mission.model, mission.elements, config.year, config.alt_m, mission.elements.values(meas),
                          meas.f_nt, mission.bias, float(lat), float(lon), sigma, flown, plausibility.limits,
                          f_reference_nt=reference, noise=noise, fix_bias=bias)
        # only a dead-reckoned estimate can be re-anchored: with an independent INS, fixes that
        # agree far from it are biased fixes (dead_reckons)
        steps = config.reanchor_steps if getattr(mission, "dead_reckons", False) else 0
        agreed = plausibility.agreed_shift(judgement, cmd.speed_mps * config.period_s, steps)
        if agreed is not None:   # the excluded fixes agree: the estimate is wrong, not the sensor
            mission.reanchor(*agreed)
            return judgement, agreed, None
        return judgement, None, plausibility.verdict(judgement)
