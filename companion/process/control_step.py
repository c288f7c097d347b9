"""One control step: the period's average and the INS position into the core, its command checked.

Every NAV_PERIOD_S of *mission time* the averaged (D, I) (or (I, F)) and the flight
controller's INS position (GLOBAL_POSITION_INT; dead reckoning on the commanded velocity when
it is missing; nothing while that position is GPS-aided or our own estimate fed back) go into
the core. A non-finite command, a solver failure or an estimate diverging from the geomagnetic
fix (by COMP_DIVERGE_KM and beyond the two's joint 99.99 % ellipse,
:func:`companion.failsafe.diverged`) is a navigation failure (:meth:`Phases.nav_failure`).
"""
from __future__ import annotations

import math
import time

import numpy as np

from companion.failsafe import diverged
from companion.io.link import mavlink
from companion.nav.elements import hz_standard_errors
from companion.nav.geo import enu_offset, offset_position
from companion.nav.heading import window_heading_rad
from companion.nav.mission import Measurement, Phase
from companion.nav.steering import is_new_course
from companion.process.filter_words import FilterWords
from companion.process.options import FC_POSITION_MAX_AGE_S
from companion.process.plausibility import Judgement, element_noise, f_offset_nt, judge, navigator_bias
from companion.registry import READINGS

__all__ = ["SETTLE_AFTER_COMMAND_S", "ControlStep"]

SETTLE_AFTER_COMMAND_S = 60.0     # gravity-referenced I waits this long after a new course or speed
# a rejected period (HOLD: the last command flies on) is a warning; a failed mission an error
_PHASE_SEVERITY = {Phase.HOLD: mavlink.MAV_SEVERITY_WARNING, Phase.FAILED: mavlink.MAV_SEVERITY_ERROR}


class ControlStep:
    """The step, its latencies and the dead-reckoned INS position between FC positions."""

    def __init__(self, app) -> None:   # the CompanionApp wiring this part
        self.app = app
        self.dr: tuple[float, float, float] | None = None          # (time, lat, lon) dead reckoning
        # wall seconds of each step that reached the core: the whole step (to the outputs sent), and
        # its parts the benchmark splits it into: the period's average, the plausibility judgement, the core
        self.step_latency_s: list[float] = []
        self.average_latency_s: list[float] = []
        self.judge_latency_s: list[float] = []
        self.core_latency_s: list[float] = []
        self.judgement: Judgement | None = None                     # the last step's plausibility verdict
        self.fresh: dict[str, bool] = {}                             # a space-weather reading fresh at the last step
        self.words = FilterWords()                                   # the filter's changes, said

    # ------------------------------------------------------------------ INS position
    def advance_dead_reckoning(self, now: float, dt: float, moving: bool) -> None:
        app = self.app
        pos = app.decoder.fc_position
        if pos is not None and now - pos.time_s <= FC_POSITION_MAX_AGE_S:
            self.dr = (now, pos.lat_deg, pos.lon_deg)
            return
        if self.dr is None:
            return
        if moving and app.command is not None and dt > 0.0:
            c, v = app.command.course_rad, app.command.speed_mps
            lat, lon = offset_position(self.dr[1], self.dr[2], v * math.sin(c) * dt, v * math.cos(c) * dt)
            self.dr = (now, float(lat), float(lon))

    def ins_position(self, now: float) -> tuple[float, float, str]:
        app = self.app
        independent, why = app.fc_view.position_independent(now)
        if not independent:   # GPS-aided or our own estimate: never an INS to fuse with
            return math.nan, math.nan, f"none: FC position {why}"
        pos = app.decoder.fc_position
        if pos is not None and now - pos.time_s <= FC_POSITION_MAX_AGE_S:
            return pos.lat_deg, pos.lon_deg, "fc"
        if self.dr is not None:
            return self.dr[1], self.dr[2], "dead_reckoning"
        return math.nan, math.nan, "none"

    # ------------------------------------------------------------------ the step
    def step(self, t_k: float, window_limit_s: float | None = None, avg=None) -> None:
        """The control step at mission time ``t_k`` (``avg``: the start-up average for the first)."""
        app = self.app
        wall0 = time.perf_counter()
        now = app.now
        if app.params_dirty:
            app.apply_params()
        mission = app.mission
        period = mission.config.period_s
        average0 = time.perf_counter()
        if avg is None:
            avg = app.mag.take(t_k)
        average_latency = time.perf_counter() - average0
        if not avg.valid:
            # nothing to measure (should not happen: a silent magnetometer pauses the mission);
            # keep flying the command and measure again one period later (the core's dead
            # reckoning uses the actual time between steps)
            app.next_step_m = t_k + period
            app.out.say("FcMPC: no magnetometer samples in the period, step postponed", mavlink.MAV_SEVERITY_WARNING)
            return
        window = avg.window_s(t_k, period if window_limit_s is None else window_limit_s)
        ins_lat, ins_lon, ins_source = self.ins_position(now)
        incl = app.preparation.inclination(avg)
        # H and Z from F and the (gravity-referenced) I: no heading enters either
        h_nt, z_nt = avg.f_nt * math.cos(math.radians(incl)), avg.f_nt * math.sin(math.radians(incl))
        incl_se = app.preparation.inclination_se(avg)
        # measured standard errors: the filter's measurement noise (FUS_R_SRC 1) and the plausibility bound
        h_se, z_se = hz_standard_errors(avg.f_nt, incl, avg.f_se_nt, incl_se)
        # the space-weather readings, while the ground station keeps them fresh: Kp (NAV_KP; negative:
        # none) and the ring-current index (NAV_SYMH)
        kp = self.reading("NAV_KP", now)
        kp = kp if kp >= 0.0 else math.nan
        symh = self.reading("NAV_SYMH", now)
        meas = Measurement(t_k - app.m0, avg.decl_deg, incl, ins_lat, ins_lon, window, avg.f_nt, h_nt, z_nt,
                           avg.decl_se_deg, incl_se, avg.f_se_nt, h_se, z_se, avg.mag_heading_deg, kp, symh)
        se = {"decl_deg": avg.decl_se_deg, "incl_deg": incl_se, "f_nt": avg.f_se_nt}
        self.judgement = None
        judge0 = time.perf_counter()
        if self.excluded(t_k, meas, se):
            app.next_step_m = t_k + period   # fly the last command; measure again one period later
            return
        core0 = time.perf_counter()
        cmd = mission.step(meas)
        core_latency = time.perf_counter() - core0
        if app.command is None:
            self.learn_f_reference(meas)
        said = self.words.start_words(mission, kp, symh) if app.command is None else self.words.step(mission, kp, symh)
        for text, severity in said:     # a storm declared, a disturbance, F weighed or set aside
            app.out.say(text, severity)
        nav_fault = self.fault(cmd)
        app.out.publish(cmd, avg)
        if app.fc_view.feeding_own and cmd.phase == Phase.CRUISE:
            app.fc_view.feed.correct_to(now, cmd.est_lat_deg, cmd.est_lon_deg, app.out.feed_sigma())
        latency = time.perf_counter() - wall0
        self.step_latency_s.append(latency)
        self.average_latency_s.append(average_latency)
        self.judge_latency_s.append(core0 - judge0)
        self.core_latency_s.append(core_latency)
        app.reporting.record_step(cmd, meas, avg, ins_source, latency, "step", nav_fault or cmd.reason)
        if nav_fault:
            app.phases.nav_failure(nav_fault, cmd)
            return
        previous = app.command
        if previous is None or abs(previous.course_rad - cmd.course_rad) > 0.02 or previous.speed_mps != cmd.speed_mps:
            app.mag.settle_until_s = now + SETTLE_AFTER_COMMAND_S   # turn and speed transient: no I_g
        if is_new_course(None if previous is None else (previous.course_rad, previous.speed_mps), cmd.course_rad,
                         cmd.speed_mps):
            app.mag.yaw_offset.new_course(now)   # the trim: the FC's yaw error differs on the new heading
        app.command = cmd
        if cmd.phase != app.last_phase:
            app.out.say(f"FcMPC: step {cmd.step} phase {cmd.phase}"
                        + (f", {cmd.remaining_m / 1000.0:.1f} km to go" if math.isfinite(cmd.remaining_m) else "")
                        + (f": {cmd.reason}" if cmd.reason else ""),
                        _PHASE_SEVERITY.get(cmd.phase, mavlink.MAV_SEVERITY_NOTICE))
            app.last_phase = cmd.phase
        if cmd.done:
            app.phases.finish(cmd)
            return
        app.next_step_m = t_k + mission.config.period_s
        app.resume.save()

    def reading(self, name: str, now: float) -> float:
        """The reading ``name`` (:data:`companion.registry.READINGS`: read here, at the step, so a new
        value rebuilds no configuration) as this step's: its value
        while the ground station has set it within its lifetime of message time ``now``, else NaN.
        A reading that lapses is said once (the operator's feed has stopped)."""
        max_age_s = READINGS[name]
        fresh = self.app.params.age_s(name, now) <= max_age_s
        if self.fresh.get(name, False) and not fresh:
            self.app.out.say(f"FcMPC: {name} not renewed for {max_age_s / 60.0:g} min: unknown until the ground "
                             f"station sets it", mavlink.MAV_SEVERITY_WARNING)
        self.fresh[name] = fresh
        return float(self.app.params.values[name]) if fresh else math.nan

    def learn_f_reference(self, meas: Measurement) -> None:
        """At the first step, the start (a known position): learn the |F| level the band is judged
        about, with the bias the core chose to subtract there. Learnt before the core's first step,
        it took the bias before auto had fallen back to Table 3's constant calibration (zero), and
        every later step subtracted the calibration a second time (PX4 SIH, +590 nT: periods judged
        1000-1040 nT off and excluded, 4 of 11 in 30 minutes)."""
        mission = self.app.mission
        model = getattr(mission, "model", None)   # (a test's stand-in core has none)
        config = mission.config
        self.app.plausibility.f_reference_nt = None if model is None else f_offset_nt(
            model, mission.elements, config.year, config.alt_m, meas.f_nt, mission.bias,
            config.start_lat_deg, config.start_lon_deg)

    def excluded(self, t_k: float, meas: Measurement, se: dict[str, float] | None = None) -> bool:
        """Judge the measurement against the predicted position (:mod:`companion.process.plausibility`);
        True if it is excluded (said, recorded). The first step has no prediction to judge against.
        ``se``: standard errors of the period's averages (``decl_deg``, ``incl_deg``, ``f_nt``)."""
        app = self.app
        cmd, mission = app.command, app.mission
        config = mission.config
        if cmd is None:   # the first step, at the start: nothing to judge against (learn_f_reference)
            return False
        if cmd.done or not (math.isfinite(cmd.est_lat_deg) and math.isfinite(cmd.est_lon_deg)):
            return False
        dt = max(meas.time_s - 0.5 * meas.window_s - cmd.time_s, 0.0)   # to the centre of the window
        flown = cmd.speed_mps * dt
        lat, lon = offset_position(cmd.est_lat_deg, cmd.est_lon_deg, flown * math.sin(cmd.course_rad),
                                   flown * math.cos(cmd.course_rad))
        # against this fix: the estimate's uncertainty less the field-model error the two share
        sigma = next(v for v in (cmd.next_fix_sigma_m, cmd.est_sigma_m, math.sqrt(app.nav_cfg.fusion.rc_m2))
                     if math.isfinite(v))
        reference = app.plausibility.f_reference_nt
        if reference is None or not math.isfinite(reference):   # resumed mid-route: no start to learn it at
            reference = 0.0
        # judged as the navigator will see it: with the error-state filter, its bias states (which
        # follow a storm it has recognised) are removed and their uncertainty widens the bound;
        # judged against the start-up calibration alone, a storm the filter was tracking drove the
        # implied jump past the bound and every later step was excluded (short storm, seed 0)
        velocity = np.array([cmd.speed_mps * math.sin(cmd.course_rad), cmd.speed_mps * math.cos(cmd.course_rad)])
        bias, bias_sigma = navigator_bias(mission, window_heading_rad(meas, velocity))
        noise = np.hypot(element_noise(mission.elements, meas.incl_deg, meas.f_nt, se or {}), bias_sigma)
        judgement = judge(mission.model, mission.elements, config.year, config.alt_m, mission.elements.values(meas),
                          meas.f_nt, mission.bias, float(lat), float(lon), sigma, flown, app.plausibility.limits,
                          f_reference_nt=reference, noise=noise, fix_bias=bias)
        self.judgement = judgement
        # only a dead-reckoned estimate can be re-anchored: with an independent INS, fixes that
        # agree far from it are biased fixes (dead_reckons)
        steps = config.reanchor_steps if getattr(mission, "dead_reckons", False) else 0
        agreed = app.plausibility.agreed_shift(judgement, cmd.speed_mps * config.period_s, steps)
        if agreed is not None:   # the excluded fixes agree: the estimate is wrong, not the sensor
            mission.reanchor(*agreed)
            words = app.plausibility.reanchor_words(agreed[0])
            app.out.say(words, mavlink.MAV_SEVERITY_WARNING)
            app.reporting.record_event("reanchored", words, **{**app.reporting.plausibility_record(meas),
                                       "jump_m": float(np.hypot(*agreed[0])), "est_sigma_m": agreed[1]})
            return False
        said = app.plausibility.verdict(judgement)
        if said is not None:
            app.out.say(said[1][:200], getattr(mavlink, f"MAV_SEVERITY_{said[0]}"))
        if judgement.ok:
            return False
        app.reporting.record_event("excluded", judgement.words(), decl_deg=meas.decl_deg, incl_deg=meas.incl_deg,
                                   f_nt=meas.f_nt, window_s=meas.window_s, est_lat_deg=float(lat),
                                   est_lon_deg=float(lon), est_sigma_m=sigma,
                                   **app.reporting.plausibility_record(meas))
        return True

    def fault(self, cmd) -> str:
        """Why ``cmd`` is a navigation failure ("" if it is not)."""
        if not cmd.done and not (math.isfinite(cmd.course_rad) and math.isfinite(cmd.speed_mps)):
            return "non-finite command from the navigation core"
        if not cmd.solver_ok:
            return f"solver failure: {cmd.reason}"
        if not all(math.isfinite(v) for v in (cmd.est_lat_deg, cmd.est_lon_deg, cmd.fix_lat_deg, cmd.fix_lon_deg)):
            return ""
        gap = np.array(enu_offset(cmd.est_lat_deg, cmd.est_lon_deg, cmd.fix_lat_deg, cmd.fix_lon_deg))
        if diverged(gap, self.app.comp_cfg.diverge_m, self.gap_covariance(cmd)):
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
