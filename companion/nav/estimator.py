"""The mission's position estimator: the navigation filter run once per control step.

Chooses the process model at the first step (``FUS_MODEL`` 2 INS, 3 dead reckoning; 0 auto takes
the INS model when the measurement carries an INS position independent of this navigator, and
dead reckoning without one: README "Without an INS"), starts
the filter at the mission's start (a GPS-known start is a position measurement with
``FUS_GPS_M``; with ``NAV_CALIBRATE 1`` the start-up average is also an element measurement
there, which observes the bias states against the model: the start-up calibration, carried
into the denied leg *with its uncertainty* as the bias states' covariance), then on every step
predicts over the move flown and updates with the averaged elements.

The geomagnetic fix (eq. 49, on the steering pair, bias-corrected) is still computed from the
prior (the linearised fix when it is near, ``FIX_LINEAR_WITHIN_M``): it is reported, and a fix
farther than ``NAV_FIX_GATE_M`` from the prior estimate whose measurement is also outside the
filter's own 99.99 % innovation ellipse (``FIX_GATE_PROBABILITY``, chi-square on the element
count) marks a wrong contour crossing or a disturbed measurement, so
that step's update is skipped. Judged in kilometres alone, a dead-reckoning filter whose 1-sigma
had grown past the distance rejected every fix for the rest of the mission (``pacific``
without an INS, (I, F), 20 seeds: the worst ended 1,743 km off, mean 114 km; with the ellipse the
worst is 116 km, mean 37 km). Unless the
filter dead-reckons and the last ``NAV_REANCHOR_N`` rejected fixes agree on where the vehicle
is: then the estimate, not the measurement, is wrong, and the filter re-anchors at the fix
(:mod:`companion.nav.reanchor`). With an independent INS, agreeing fixes far from it are biased
fixes, and the gate stands.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2

from companion.nav.crust import local_error_scale
from companion.nav.disturbance import COMPONENT_WALK, ONSET_STEPS, index_says_quiet, storm_declared
from companion.nav.elements import ElementSet
from companion.nav.field import (PositionFixError, WorldMagneticModel, element_fix, element_values_and_gradient,
                                 fix_covariance)
from companion.nav.geo import enu_offset, geodesic_inverse, offset_position
from companion.nav.heading import window_heading_rad
from companion.nav.ins_error import AttitudeSource
from companion.nav.navfilter import NavigationFilter
from companion.nav.process import DeadReckoningProcess, InsProcess
from companion.nav.reanchor import OffsetConsensus, ReanchorSettings
from companion.nav.ring_current import ring_current_change_nt, ring_current_elements, symh_value

__all__ = ["REWIND_STEPS", "Estimate", "FusionModel", "PositionEstimator"]

REWIND_EXTRA = 4   # ... before the loud ones (8 seeds: long storm 11 km with 4, 16-26 km with 2 or 10)
REWIND_STEPS = ONSET_STEPS + REWIND_EXTRA   # steps kept to fly again when a disturbance is recognised
FIX_GATE_PROBABILITY = 0.9999   # a fix beyond NAV_FIX_GATE_M is rejected only outside this innovation ellipse
# The step's fix is reported and judged (the gate above, the companion's divergence check, both at
# tens of km), never fused: the filter takes the elements themselves. So a fix within this of the
# window centre is the linearised one, one Gauss-Newton step from the model evaluation the update
# makes anyway (element_fix's linear_within_m, where cond(G) < 20: off the converged fix by at most
# 7 m at 1 km over the globe, against its own noise of hundreds of metres); farther or worse
# conditioned ones are iterated until a Newton step is shorter than FIX_TOL_M. The position after
# that last step is off by its step's square times the curvature (at most 2.4e-4 per metre over the
# globe: under 3 cm for a 10 m step), so 10 m loses nothing of a 1 m tolerance and saves the model
# evaluation that confirmed it (the realistic pacific: 2.98 -> 2.55 evaluations a step; fixes moved by at
# most 1.4e-5 m, misses the same to the millimetre).
FIX_LINEAR_WITHIN_M = 1000.0
FIX_TOL_M = 10.0
# what the companion says of FUS_ATT_INS beside the INS process model
_ATTITUDE_WORDS = {AttitudeSource.NONE: "", AttitudeSource.TILT: "; its tilt levels the magnetometer",
                   AttitudeSource.ALL: "; its attitude levels and turns the magnetometer"}


@functools.lru_cache(maxsize=8)
def _gate_nis(probability: float, dof: int) -> float:
    """The NIS beyond which a far fix is implausible (chi-square quantile): cached, scipy's ppf
    costs ~100 us and the answer depends on the gate and the element count only."""
    return float(chi2.ppf(probability, dof))


class FusionModel:
    """Values of FUS_MODEL."""

    AUTO = 0
    TABLE3 = 1
    INS = 2
    DEAD_RECKONING = 3


@dataclass(frozen=True)
class Estimate:
    """One step's estimate: position (deg), its east/north covariance (m^2: ee, en, nn), the
    1-sigma per axis (RMS of the two), the bias estimates (element units), the NIS of the
    update (NaN without one), whether a disturbance is active, the fix (NaN when none)."""

    lat_deg: float
    lon_deg: float
    cov_en_m2: tuple[float, float, float]
    sigma_m: float
    bias: tuple[float, ...]
    nis: float = math.nan
    disturbed: bool = False
    fix_lat_deg: float = math.nan
    fix_lon_deg: float = math.nan
    updated: bool = False
    fix_cov_en_m2: tuple[float, float, float] = (math.nan, math.nan, math.nan)


def _space_weather(meas, config) -> tuple[bool, bool]:
    """Whether the step's space-weather readings (Kp, SYM-H) declare a storm by the settings'
    thresholds (FUS_KP_ON, FUS_SYMH_ON), and whether they say the field is quiet."""
    readings = (meas.kp, config.kp_on, symh_value(meas.symh_nt), config.symh_on_nt)
    return storm_declared(*readings), index_says_quiet(*readings)


class PositionEstimator:
    """Builds the filter at the first step and runs it on every later one."""

    def __init__(self, config, model: WorldMagneticModel, measured: ElementSet) -> None:
        self.config = config
        self.model = model
        self.measured = measured
        self.steering = measured.steering()
        self.local_scale = local_error_scale(config)   # the route's crust on the local-error states
        self.settings = replace(config.filter, bias=config.filter.bias.with_local_scale(self.local_scale))
        self.filter: NavigationFilter | None = None
        self.reason = ""
        self.rejected = 0
        self.rewinds = 0
        self.calibrate_start = True
        self.consensus = OffsetConsensus(ReanchorSettings(steps=config.reanchor_steps))
        self._ins = (math.nan, math.nan)
        self._history: list = []
        self.symh_reference_nt = math.nan   # SYM-H at the start: the ring current's reference (NaN: none)
        self._symh_last = math.nan          # the last SYM-H received, held while the feed is silent

    def parts(self) -> tuple:
        """The objects whose own attributes a step changes (:class:`companion.nav.rollback.Checkpoint`)."""
        f = self.filter   # (its bias walk's position is set anew by every predict)
        return (self, self.consensus) + ((f, f.kf, f.process, f.monitor) if f is not None else ())

    @property
    def process_name(self) -> str:
        return self.filter.process.name if self.filter is not None else ""

    @property
    def storm_walk(self) -> str:
        """How the bias states walk while a storm is declared, in words."""
        b = self.config.filter.bias
        if b.qa_mode == COMPONENT_WALK:
            removed = self.ring_current_removed
            if removed:
                b = b.after_ring_current()
            parts = [f"{name} {q:g}" + (f" (tau {tau:g} h)" if tau > 0.0 else "")
                     for name, q, tau in zip("NEZ", b.qa_ned_nt_rth, b.qa_ned_tau_h)]
            corr = b.qa_ned_corr
            return ("biases walk by field component " + ", ".join(parts) + " nT/rt(h)"
                    + (", N after SYM-H" if removed else "")
                    + (", correlated NE {:g} NZ {:g} EZ {:g}".format(*corr) if any(corr) else ""))
        return f"biases walk per element {b.qa_deg_rth:g} deg, {b.qa_nt_rth:g} nT/rt(h)"

    @property
    def ring_current_removed(self) -> bool:
        """The ring current predicted from SYM-H is taken out of every measurement: a SYM-H came
        with the start and ``FUS_SYMH_K`` > 0 (:mod:`companion.nav.ring_current`)."""
        return math.isfinite(self.symh_reference_nt)

    def ring_current_share(self, meas, position: tuple[float, float]) -> np.ndarray:
        """The predicted ring current's share of each measured element at ``position`` (deg),
        zero without a correction; a SYM-H missing this step holds the last one."""
        if not self.ring_current_removed:
            return np.zeros(len(self.measured.names))
        symh = symh_value(meas.symh_nt)
        if math.isfinite(symh):
            self._symh_last = symh
        delta_h = ring_current_change_nt(self.config.symh_ratio, self._symh_last, self.symh_reference_nt)
        # the model's field with slopes, which the model keeps: the step's update asks for it at
        # the same window centre next, and gets it without a second evaluation
        ned, _, _ = self.model.ned_and_slopes(position[0], position[1], self.config.alt_m, self.config.year)
        return ring_current_elements(self.measured.names, *(float(v) for v in ned), delta_h)

    @property
    def dead_reckons(self) -> bool:
        """The position has no independent source between fixes (the dead-reckoning process):
        only then do agreeing rejected fixes mean the estimate is wrong. With an INS they mean
        the fixes are biased (measured: re-anchoring on them in the realistic world, whose D
        carries the compass's heading error, took the median miss from 67 to 163 km)."""
        return self.filter is not None and isinstance(self.filter.process, DeadReckoningProcess)

    def start(self, meas, measured: np.ndarray, start_sigma_m: float | None) -> Estimate:
        """The first step, at the mission's start: choose the process model, set the prior, and
        observe the start position (GPS) and, when calibrating, the biases there."""
        c = self.config
        have_ins = meas.has_ins
        if c.fusion_model == FusionModel.DEAD_RECKONING or (c.fusion_model == FusionModel.AUTO and not have_ins):
            pos_sigma = start_sigma_m if start_sigma_m is not None else self.settings.ins.pos_err_m
            process = DeadReckoningProcess(self.settings.dead_reckoning, c.start_lat_deg, c.start_lon_deg, pos_sigma)
            course = "the measured heading" if c.dr_heading == 1 else "the commanded course"
            self.reason = (f"dead reckoning on {course}: FUS_MODEL 3" if c.fusion_model == FusionModel.DEAD_RECKONING
                           else f"dead reckoning on {course}: no independent INS position")
        elif have_ins:
            process = InsProcess(self.settings.ins, meas.ins_lat_deg)
            ins = self.settings.ins
            self.reason = (f"INS error model (gyros {ins.gyro_bias_degph:g} + {ins.gyro_markov_degph:g} deg/h): an "
                           "independent INS position is available" + _ATTITUDE_WORDS[c.filter.attitude_from_ins])
        else:
            raise ValueError("FUS_MODEL 2 (INS) needs an independent INS position at the start")
        self.symh_reference_nt = symh_value(meas.symh_nt) if c.symh_ratio > 0.0 else math.nan
        self._symh_last = self.symh_reference_nt
        settings = self.settings
        if self.ring_current_removed:   # what the prediction misses walks as the storm's north
            settings = replace(settings, bias=settings.bias.after_ring_current())
        self.filter = NavigationFilter(process, self.measured, settings, self.model, c.alt_m, c.year)
        # at the known start F's innovation is calibration, whatever an index says of the day
        self.filter.monitor.declare(_space_weather(meas, c)[0], index_quiet=True)
        measured = measured - self.ring_current_share(meas, (c.start_lat_deg, c.start_lon_deg))
        self._ins = (meas.ins_lat_deg, meas.ins_lon_deg)
        self.filter.set_heading(window_heading_rad(meas))
        if start_sigma_m is not None:
            self.filter.update_position(c.start_lat_deg, c.start_lon_deg, start_sigma_m, *self._ins)
            if c.calibrate and self.calibrate_start:
                self.filter.calibrate(measured, *self._ins, self.measured.standard_errors(meas))
        return self._estimate(updated=start_sigma_m is not None)

    def step(self, meas, measured: np.ndarray, dt_s: float, vel_en_mps: np.ndarray, lag_en_m: np.ndarray,
             fallback: tuple[float, float], shift: tuple[np.ndarray, float] | None = None) -> Estimate:
        """Predict over the move just flown and update with the averaged elements.
        ``fallback``: the dead-reckoned position, used when the INS model has no INS this step;
        ``shift``: (east/north offset m, 1-sigma m) to re-anchor the estimate by before the
        update (the companion's plausibility check found its excluded fixes agreeing).

        When this step switches the disturbance on, the filter goes back to before the loud
        steps that switched it on and flies them again with the raised bias noise: the onset
        needs ``ONSET_STEPS`` loud steps (one high NIS is noise), and a bias drift the filter
        absorbed meanwhile into the INS error states (tilt, gyro drift) would be carried, and
        extrapolated, for the rest of the mission."""
        f = self.filter
        inputs = (meas, measured, dt_s, vel_en_mps, lag_en_m, fallback, shift)
        self._history.append((f.snapshot(), (self._ins, self._symh_last), inputs, list(self.consensus.offsets)))
        del self._history[:-REWIND_STEPS]
        was_active = f.monitor.active
        estimate = self._step(*inputs)
        if f.monitor.active and not was_active:
            back = min(len(self._history), f.monitor.loud_steps + REWIND_EXTRA)
            replay = self._history[-back:]
            state, (self._ins, self._symh_last), _, offsets = replay[0]
            self.consensus.offsets = list(offsets)
            activations = f.monitor.activations
            f.restore(state)
            f.monitor.active, f.monitor.activations = True, activations
            for _, _, again, _ in replay:
                estimate = self._step(*again)
            self.rewinds += 1
        return estimate

    def _step(self, meas, measured, dt_s, vel_en_mps, lag_en_m, fallback, shift=None) -> Estimate:
        f = self.filter
        have_ins = meas.has_ins
        lat_now = meas.ins_lat_deg if have_ins else fallback[0]
        f.monitor.declare(*_space_weather(meas, self.config))
        f.predict(dt_s, vel_en_mps, lat_now, f.position(*self._ins))
        f.set_heading(window_heading_rad(meas, vel_en_mps))
        if isinstance(f.process, InsProcess):
            if not have_ins:   # no INS this step: keep the covariance honest, steer on dead reckoning
                return self._estimate(position=fallback)
            self._ins = (meas.ins_lat_deg, meas.ins_lon_deg)
        prior = f.position(*self._ins)
        if shift is not None:
            offset, sigma = shift
            f.reset_position(*offset_position(prior[0], prior[1], float(offset[0]), float(offset[1])), sigma,
                             *self._ins)
            self.consensus.clear()
            prior = f.position(*self._ins)
        # the model at the window centre, evaluated once: the fix's first iterate and the update
        centre = f.window_centre(lag_en_m, *self._ins)
        measured = measured - self.ring_current_share(meas, centre)
        at_centre = element_values_and_gradient(self.model, self.measured, *centre, self.config.alt_m,
                                                self.config.year)
        fix, fix_gradient = self._fix(measured, centre, lag_en_m, at_centre)
        fix_cov = self._fix_covariance(meas, fix_gradient) if fix is not None else None
        if fix is not None and geodesic_inverse(prior[0], prior[1], *fix)[0] > self.config.fix_gate_m \
                and self._implausible(measured, lag_en_m, meas, at_centre):
            agreed = self.consensus.rejected(np.array(enu_offset(prior[0], prior[1], *fix))) \
                if self.dead_reckons else None
            if agreed is None:
                self.rejected += 1   # not a fix: a wrong contour crossing or a disturbed measurement
                return self._estimate()
            # the last rejected fixes agree: the estimate is what is wrong; start again at the fix
            f.reset_position(*fix, 0.5 * self.consensus.settings.tolerance_m, *self._ins)
            at_centre = None    # the estimate moved: its window centre with it
        else:
            self.consensus.clear()
        # without a fix the gate judges the update's own move instead: the linearised update of
        # a measurement far outside the filter's ellipse can throw the estimate thousands of km
        # (an uncalibrated compass in a car, D 90 deg off: 1,160 km in one step, then off the Earth)
        before = f.snapshot() if fix is None else None
        f.update_elements(measured, lag_en_m, *self._ins, self.measured.standard_errors(meas), at_centre)
        if before is not None and not f.last_nis <= self._gate_nis() \
                and not geodesic_inverse(prior[0], prior[1], *f.position(*self._ins))[0] <= self.config.fix_gate_m:
            f.restore(before)
            self.rejected += 1
            return self._estimate()
        return self._estimate(fix=fix, updated=True, fix_cov=fix_cov)

    def _fix_covariance(self, meas, gradient: np.ndarray) -> tuple[float, float, float] | None:
        """East/north covariance (m^2) of the bias-corrected fix on the steering pair:
        ``G^-1 C G^-T`` (:func:`companion.nav.field.fix_covariance`) with C the uncertainty of the
        biases at this heading plus the noise (:meth:`NavigationFilter.beyond_position_covariance`)
        and G the fix's own (at its last iterate); None where G is singular. With the heading
        states a fix right after a turn is as uncertain as the bias there, and judged so (the
        companion's divergence check)."""
        n = len(self.steering.names)
        c = self.filter.beyond_position_covariance(self.measured.standard_errors(meas))[:n, :n]
        try:
            cov = fix_covariance(gradient, c)
        except np.linalg.LinAlgError:
            return None
        return float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])

    def _implausible(self, measured: np.ndarray, lag_en_m: np.ndarray, meas, at_centre=None) -> bool:
        """The measurement's NIS against the filter's own innovation covariance is beyond
        ``FIX_GATE_PROBABILITY``: a far fix is a blunder only if the filter is sure it is far. The
        NIS has as many degrees of freedom as the elements the filter measures this step (F set
        aside: two)."""
        f = self.filter
        nis = f.innovation_nis(measured, lag_en_m, *self._ins, self.measured.standard_errors(meas), at_centre)
        return not nis <= self._gate_nis()

    def _gate_nis(self) -> float:
        """The NIS beyond which a measurement is implausible, on the elements the filter measures now."""
        f = self.filter
        return _gate_nis(FIX_GATE_PROBABILITY, len(self.measured.measured_rows(f.monitor.declared,
                                                                                f.monitor.index_quiet)))

    def _fix(self, measured: np.ndarray, start: tuple[float, float], lag_en_m: np.ndarray, at_centre=None):
        """The bias-corrected geomagnetic fix on the steering pair from ``start`` (the window
        centre behind the prior), referred to the end of the step like the estimate, and the
        model's G there; (None, None) when it fails. ``at_centre``: the measured set's elements
        and G at ``start``, the fix's first iterate."""
        n = len(self.steering.names)
        target = measured[:n] - self.filter.bias[:n]
        first = None if at_centre is None else (at_centre[0][:n], at_centre[1][:n])
        try:
            fix = element_fix(self.model, self.steering, target, *start, self.config.alt_m, self.config.year,
                              report_at_fix=False, at_prior=first,   # the position is all we use
                              linear_within_m=FIX_LINEAR_WITHIN_M, tol_m=FIX_TOL_M)
        except PositionFixError:
            return None, None
        moved = offset_position(fix.lat_deg, fix.lon_deg, float(lag_en_m[0]), float(lag_en_m[1]))
        return (float(moved[0]), float(moved[1])), fix.gradient

    def _estimate(self, fix=None, updated: bool = False, position=None, fix_cov=None) -> Estimate:
        f = self.filter
        lat, lon = position if position is not None else f.position(*self._ins)
        cov = f.covariance_en(lat)
        return Estimate(float(lat), float(lon), (float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])),
                        math.sqrt(0.5 * (cov[0, 0] + cov[1, 1])), tuple(float(b) for b in f.bias),
                        f.last_nis if updated else math.nan, f.monitor.active,
                        fix[0] if fix else math.nan, fix[1] if fix else math.nan, updated,
                        fix_cov if fix_cov is not None else (math.nan, math.nan, math.nan))
