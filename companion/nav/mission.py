"""Algorithm 1 as a pure step function: one measurement in, one command out, per period T.

Call :meth:`Mission.step` once per control period with the magnetic state measured at the
end of the move just flown (D and I averaged over the period) and, when available, the INS
position. It returns the heading and speed to fly for the next period, until ``done``.
No sockets, threads, files or clocks: time comes in with the measurement, so the companion,
the simulator and the Monte Carlo all run this same code at any speed.

Sequence (Algorithm 1): k = 0 and 1 fly the probing headings theta_1, theta_2 (Table 4); at
k = 2 the gradient G(2) comes from the two probes (eq. 5-9); from then on G is updated
(eq. 10 or its sound replacement, :mod:`companion.nav.gradient`), the MPC gives u*(k)
(eq. 36) whose direction is the heading (eq. 3-4), and the mission ends when the estimated
distance to the destination is below epsilon, or (``NAV_ARRIVE_LEGS``) after that many legs in
a row each planned to reach the estimated destination, and by default after one last leg to the
estimated destination (``NAV_FINAL_LEG``; :mod:`companion.nav.arrival`).

Controllers (``NAV_CONTROLLER``):

* LTI-MPC: B = G(2) T for the whole mission.
* LTV-MPC: B(k) = G(k) T, updated every step.
* Fc-MPC: LTV-MPC plus flexible correction (eq. 39-45). The geomagnetic position fix
  (lambda_c, phi_c) of eq. 49, fused with the INS where the gradient is weak (eq. 46-58;
  FUS_MODEL 1), or by default the error-state filter's position (:mod:`companion.nav.estimator`,
  run on every step, the probes included), tells where the destination lies; the part of ``S_d - S`` that the linear model cannot
  explain by that displacement is the interference xi(k), and the uniform compensation
  ``B U_a = -xi`` (eq. 43) is applied by shifting the MPC's target (same optimum, see
  :func:`compensation`).

Units of the QP (``MPC_UNITS``), because Table 4's weights come without units:

* 0, scaled (default): S in arc-seconds, U as a fraction of cruise speed. One cruise step
  changes S by 50-200 arcsec here, so Q = F = I outweighs R = 10 I and u* points along the
  linearised direction to the target; a reference governor holds the target within one
  step's reach so the input bounds never bend that direction.
* 1, paper: S in degrees, U in km/h. R = 10 I then outweighs the state cost by ~10^6 and u*
  degenerates to the steepest-descent direction G^T Q (S_d - S); only its direction is used.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion import course_from_theta
from companion.nav.arrival import Arrival
from companion.nav.config import Controller, NavConfig
from companion.nav.elements import ElementSet, element_set, resolve_elements
from companion.nav.estimator import Estimate, FusionModel, PositionEstimator
from companion.nav.field import WorldMagneticModel, element_gradient, model_for_setting
from companion.nav.geo import enu_offset, geodesic_inverse, offset_position
from companion.nav.heading import flown_velocity_en
from companion.nav.gradient import GradientEstimator
from companion.nav.mpc import MpcController, MpcSettings, SOLVERS
from companion.nav.reference import ReferencePath
from companion.nav.rollback import Checkpoint
from companion.nav.screening import MEASUREMENT_ERRORS, REJECTED, finite_filter, held_command, screen, unsound
from companion.nav.small import solve2
from companion.nav.step_io import Command, Measurement, Phase
from companion.nav.table3 import F_NT_PER_DEG, Table3Estimator
from companion.registry import hold_frozen

__all__ = ["REJECTED", "Measurement", "Command", "Phase", "Mission", "compensation", "end_blind", "governed_target",
           "uses_filter"]

KMH = 1.0 / 3.6


def compensation(b: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Uniform compensation U_a with ``B U_a = -xi`` (eq. 43), so that
    ``A S + B (U_h + U_a) + xi = A S + B U_h`` (eq. 42 -> eq. 44). For a singular B the
    least-squares U_a (the compensation B can deliver)."""
    b = np.asarray(b, dtype=float)
    xi = np.asarray(xi, dtype=float)
    try:
        return solve2(b, -xi)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(b, -xi, rcond=None)[0]


def state_bounds(c: NavConfig, elements: ElementSet, s_start: np.ndarray,
                 s_dest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """S_min, S_max in element units: from the start and destination field +- MPC_S_MARGIN
    (MPC_S_AUTO = 1), or the MPC_S_MIN_*/MAX_* values (Table 4), which must hold the
    destination's field."""
    margins = np.array([c.s_margin_deg * (F_NT_PER_DEG if n.endswith("_nt") else 1.0) for n in elements.names])
    if c.s_auto == 1:
        ends = np.stack([s_start, s_dest])
        return ends.min(axis=0) - margins, ends.max(axis=0) + margins
    table = {"decl_deg": (c.s_min_d, c.s_max_d, "MPC_S_MIN_D/MPC_S_MAX_D"),
             "incl_deg": (c.s_min_i, c.s_max_i, "MPC_S_MIN_I/MPC_S_MAX_I"),
             "f_nt": (c.s_min_f, c.s_max_f, "MPC_S_MIN_F/MPC_S_MAX_F")}
    for value, name in zip(s_dest, elements.names):
        if name not in table:
            raise ValueError(f"{elements.label} has no MPC_S_MIN/MAX parameters: set MPC_S_AUTO 1")
        low, high, names = table[name]
        if not low <= value <= high:
            # Table 4's bounds suit the paper's northern mid-latitude mission only
            raise ValueError(f"the destination's field ({value:.2f}) lies outside the state bounds "
                             f"[{low:g}, {high:g}] of {names}: widen them, or set MPC_S_AUTO 1")
    return (np.array([table[n][0] for n in elements.names]), np.array([table[n][1] for n in elements.names]))


def uses_filter(config: NavConfig) -> bool:
    """Whether the error-state filter (issue 14) estimates the position: Fc-MPC, unless Table 3
    (FUS_MODEL 1) is chosen."""
    return config.controller == Controller.FC and config.fusion_model != FusionModel.TABLE3


def qp_units(c: NavConfig, elements: ElementSet) -> tuple[np.ndarray, float]:
    """(QP state units per element unit, metres per second per QP input unit)."""
    return elements.qp_scale(c.mpc_units), (KMH if c.mpc_units == 1 else c.speed_mps)


def mpc_settings(c: NavConfig, elements: ElementSet, s_lower: np.ndarray, s_upper: np.ndarray) -> MpcSettings:
    """The QP's settings for a mission: weights, horizon, U bounds and the state bounds in QP units."""
    s_unit, u_unit = qp_units(c, elements)
    if c.u_bounds == 1:
        u_lower, u_upper = (0.0, 0.0), (c.u_max_mps / u_unit,) * 2
    else:
        u_lower, u_upper = (-c.speed_mps / u_unit,) * 2, (c.speed_mps / u_unit,) * 2
    return MpcSettings(horizon=c.horizon, q=(c.q_d, c.q_i), f=(c.f_d, c.f_i), r=(c.r_x, c.r_y),
                       u_lower=u_lower, u_upper=u_upper, s_lower=tuple(float(v) for v in s_lower * s_unit),
                       s_upper=tuple(float(v) for v in s_upper * s_unit), solver=SOLVERS[c.solver],
                       admit_state=c.s_admit == 1)


@dataclass
class _Last:
    time_s: float
    s: np.ndarray
    velocity_en: np.ndarray  # commanded (east, north) m/s of the move now being flown
    theta_rad: float
    sample_en: np.ndarray    # dead-reckoned local position (m from start) the measurement refers to
    speed_mps: float = math.nan   # commanded speed (NaN in a snapshot from before it was kept: |velocity_en|)


class Mission:
    """One mission from start to destination; see the module docstring.

    ``bias``: the start-up calibration of the element set's two elements (measured minus model
    at a known start, in the elements' units), subtracted from every measurement; None for
    none. ``config.elements`` 0 (auto) means an independent heading here, (D, I, F) with F weighed
    only while a space-weather index says quiet: the caller resolves auto from the heading source
    it knows about.
    """

    def __init__(self, config: NavConfig, model: WorldMagneticModel | None = None,
                 bias: tuple[float, float] | None = None) -> None:
        self.config = config
        if model is None:
            model = model_for_setting(config.year, config.wmm, config.nav_map)
        self.model = model
        self.measured: ElementSet = element_set(config.elements or resolve_elements(0, compass_derived=False))
        self.elements: ElementSet = self.measured.steering()     # what the gradient and the MPC see
        self.estimator = PositionEstimator(config, model, self.measured) if uses_filter(config) else None
        self.estimate: Estimate | None = None
        self.start_sigma_m: float | None = None
        self.table3 = Table3Estimator(config, model, self.elements)   # the path of FUS_MODEL 1
        self.set_bias(bias)
        field_at = lambda lat, lon: self.elements.values(model.elements(lat, lon, config.alt_m, config.year))  # noqa: E731
        self.s_dest = field_at(config.dest_lat_deg, config.dest_lon_deg)
        self.s_lower, self.s_upper = state_bounds(config, self.elements, field_at(config.start_lat_deg,
                                                                                 config.start_lon_deg), self.s_dest)
        self.gradient = GradientEstimator(config.grad_update, config.grad_min_move_m)
        self.mpc = MpcController(mpc_settings(self.config, self.elements, self.s_lower, self.s_upper))
        de, dn = enu_offset(config.start_lat_deg, config.start_lon_deg, config.dest_lat_deg, config.dest_lon_deg)
        # paper bounds U in [0, U_max]^2: the quadrant towards the destination gives the signs
        self.quadrant = np.array([1.0 if de >= 0 else -1.0, 1.0 if dn >= 0 else -1.0])
        self.reference = ReferencePath((config.start_lat_deg, config.start_lon_deg),
                                       (config.dest_lat_deg, config.dest_lon_deg))
        self.k = 0
        self.est = (config.start_lat_deg, config.start_lon_deg)
        self.dead_reckoned_en = np.zeros(2)
        self.window_lag_en = np.zeros(2)
        self.last: _Last | None = None
        self.finished: Command | None = None
        self.rejected_fixes = 0
        self.rejected_measurements = 0   # steps whose measurement was rejected (Mission.step)
        self._shift: tuple[np.ndarray, float] | None = None
        self._had_ins = False
        self.arrival = Arrival()

    def set_bias(self, bias: tuple[float, ...] | None) -> None:
        """The start-up calibration to subtract from every measurement (None: none), before the
        first step. Only Table 3's path subtracts it as a constant; the error-state filter
        observes the biases itself at a GPS-known start (:meth:`set_start_fix`) and carries them
        as uncertain states."""
        n = len(self.measured.names)
        value = np.zeros(n) if bias is None else np.asarray(bias, dtype=float)
        if value.shape != (n,) or not np.isfinite(value).all():
            raise ValueError(f"the element bias must be {n} finite numbers, got {bias!r}")
        self._given_bias = value
        self.bias = value if self.estimator is None else np.zeros(n)
        self.table3.calibrated = bias is not None

    def set_start_fix(self, sigma_m: float | None, calibrate: bool = True) -> None:
        """The start position is known to this 1-sigma (None: it is not), before the first step;
        ``calibrate``: the start-up average there may observe the biases (a GPS-known start)."""
        self.start_sigma_m = sigma_m
        if self.estimator is not None:
            self.estimator.calibrate_start = calibrate

    def reconfigure(self, new: NavConfig) -> list[str]:
        """Take a changed configuration at the next step; returns the registry names of changes
        kept for the next mission (the registry's ``frozen`` entries). Weights, horizon,
        bounds, speed, period, thresholds and the QP backend apply at once (the QP is rebuilt
        when its own settings changed; a new space-weather reading, every minute in a storm,
        leaves it and its warm start as they are)."""
        old = self.config
        merged, deferred = hold_frozen(old, new)
        if merged != old:
            before = mpc_settings(old, self.elements, self.s_lower, self.s_upper)
            self.config = self.table3.config = merged
            settings = mpc_settings(merged, self.elements, self.s_lower, self.s_upper)
            if settings != before:
                self.mpc = MpcController(settings)
        return deferred

    @property
    def dead_reckons(self) -> bool:
        """The estimate has no independent position between fixes (dead reckoning, or Table 3's
        path without an INS at the last step): agreeing rejected fixes then mean it is wrong."""
        if self.estimator is not None:
            return self.estimator.dead_reckons
        return not self._had_ins

    def reanchor(self, shift_en_m: np.ndarray, sigma_m: float) -> None:
        """Shift the estimate by ``shift_en_m`` (east, north, m) at the next step, before its
        update, with position 1-sigma ``sigma_m``: the caller's own gate (the companion's
        plausibility check) found its rejected fixes agreeing (:mod:`companion.nav.reanchor`);
        callers do this only where :attr:`dead_reckons`."""
        shift = np.asarray(shift_en_m, dtype=float)
        if shift.shape != (2,) or not np.isfinite(shift).all() or not (math.isfinite(sigma_m) and sigma_m > 0.0):
            raise ValueError(f"a re-anchoring shift is two finite metres and a positive 1-sigma, got {shift_en_m!r}, "
                             f"{sigma_m!r}")
        self._shift = (shift, float(sigma_m))

    # --- snapshot (issue 10: resume after a restart) -------------------------------------------
    REBUILT = frozenset({"model", "mpc"})   # rebuilt from the configuration, never in a snapshot

    def snapshot(self) -> dict:
        """The core's state (estimate, filters, gradient, phase, step, reference, last command):
        everything but the parts :meth:`restore` rebuilds from the configuration. Shallow: it
        shares the mission's objects, so pickle it before the mission steps on."""
        return {k: v for k, v in vars(self).items() if k not in self.REBUILT}

    @classmethod
    def restore(cls, state: dict) -> Mission:
        """The mission a :meth:`snapshot` was taken of: built from its configuration, given its state."""
        mission = cls(state["config"])
        mission.__dict__.update(state)
        return mission

    # --- the step ------------------------------------------------------------------------------
    def step(self, meas: Measurement) -> Command:
        """Advance one control period, never raising on a measurement (:mod:`companion.nav.screening`):
        a period outside its domain, or whose step raised or left what cannot stand, is rejected,
        the step taken back (:class:`~companion.nav.rollback.Checkpoint`), counted in
        :attr:`rejected_measurements`, answered HOLD with the last command flown on."""
        if self.finished is not None:
            return self.finished
        meas, why = screen(meas, self.measured.names, self.measured.values(meas),
                           None if self.last is None else self.last.time_s)
        if not why:
            path = self.table3.parts() if self.estimator is None else self.estimator.parts()   # the path in use
            saved = Checkpoint(self, self.gradient, self.arrival, *path)
            try:
                command = self._step(meas)
                kf = self.table3.fusion.kf if self.estimator is None else getattr(self.estimator.filter, "kf", None)
                why = unsound(command, self.config.speed_mps, kf is None or finite_filter(kf))
            except MEASUREMENT_ERRORS as err:
                why = f"{type(err).__name__}: {err}"
            if not why:
                return command
            saved.restore()
            self._shift = None   # a re-anchoring the step carried goes with it (the caller's check finds it again)
        self.rejected_measurements += 1
        return held_command(meas.time_s, why, self.last, self.est, self.k, self.config.speed_mps, self._filter_fields())

    def _step(self, meas: Measurement) -> Command:
        measured = self.measured.values(meas) - self.bias
        s = measured[:2]
        c = self.config
        if self.last is None:  # k = 0: at the start, fly theta_1
            if self.estimator is not None:
                self._take(self.estimator.start(meas, measured, self.start_sigma_m))
            return self._probe(meas.time_s, s, math.radians(c.probe1_deg), Phase.PROBE_1)
        self._had_ins = meas.has_ins
        dt = meas.time_s - self.last.time_s
        flown = self.last.velocity_en   # dead reckoning, NAV_DR_HDG 1: along the measured heading (the FC steers on its own yaw)
        if c.dr_heading == 1 and not meas.has_ins and math.isfinite(meas.mag_heading_deg):
            decl = self.model.elements(*self.est, c.alt_m, c.year).decl_deg
            flown = flown_velocity_en(flown, meas.mag_heading_deg, float(decl))
        moved = flown * dt
        self.est = tuple(float(v) for v in offset_position(self.est[0], self.est[1], moved[0], moved[1]))
        self.dead_reckoned_en = self.dead_reckoned_en + moved
        shift, self._shift = self._shift, None
        if shift is not None and self.estimator is None:   # Table 3's path: the estimate is the position
            self.est = tuple(float(v) for v in offset_position(self.est[0], self.est[1], *shift[0]))
            self.table3.consensus.clear()
        # the averaged measurement describes the centre of its window, half a window back
        self.window_lag_en = flown * min(max(meas.window_s, 0.0), dt) / 2.0
        sample_en = self.dead_reckoned_en - self.window_lag_en
        if self.estimator is not None:   # the filter runs on every step, the probes included
            self._take(self.estimator.step(meas, measured, dt, flown, self.window_lag_en, self.est,
                                           shift))
        g = self.gradient.observe(self.elements.difference(s, self.last.s), sample_en - self.last.sample_en, self.last.theta_rad,
                                  *self.last.velocity_en, dt, frozen=c.controller == Controller.LTI)
        if self.k == 2 and g is not None and c.grad_init == 1:
            # GRAD_INIT 1: start from the model's gradient where the vehicle is estimated to be
            # (the model already makes the fixes); two probe moves alone can give a G poor
            # enough for LTI-MPC's fixed B to diverge
            g = self.gradient.start_from(element_gradient(self.model, self.elements, *self.est, c.alt_m, c.year))
        if self.k == 1:
            return self._probe(meas.time_s, s, math.radians(c.probe2_deg), Phase.PROBE_2)
        if g is None:
            return self._finish(meas.time_s, Phase.FAILED, "no gradient: the probing moves were too short or along one line")
        return self._cruise(meas, s, g)

    def _cruise(self, meas: Measurement, s: np.ndarray, g: np.ndarray) -> Command:
        c = self.config
        fix, fused, sigma = (math.nan, math.nan), False, math.nan
        s_now = s
        if c.controller == Controller.FC:
            fix, fused, sigma = self._estimate_position(meas, s, g)
            if self.estimate is not None:   # the MPC sees S with the estimated biases removed
                s_now = s - np.asarray(self.estimate.bias[:2])
            remaining, course_to_dest = geodesic_inverse(self.est[0], self.est[1], c.dest_lat_deg, c.dest_lon_deg)
            to_dest = remaining * np.array([math.sin(course_to_dest), math.cos(course_to_dest)])
            to_aim = to_dest
            if c.lookahead_m > 0.0 and remaining > c.lookahead_m:
                aim = self.reference.aim_point(self.est[0], self.est[1], c.lookahead_m)
                distance, course_to_aim = geodesic_inverse(self.est[0], self.est[1], *aim)
                to_aim = distance * np.array([math.sin(course_to_aim), math.cos(course_to_aim)])
            xi = self.elements.difference(self.s_dest, s_now) - g @ to_aim   # what the linear model cannot explain
            target = self.s_dest - xi                      # = S + G * to_aim
        else:
            try:
                to_dest = solve2(g, self.elements.difference(self.s_dest, s))
                remaining = float(np.hypot(*to_dest))
            except np.linalg.LinAlgError:   # G singular: no way to the destination; one is the last move's
                to_dest, remaining = self.last.velocity_en, math.inf
            xi = np.zeros(2)
            target = self.s_dest
        ended = self.arrival.judge(remaining, c, c.controller == Controller.FC)   # (a last leg to fly: not yet)
        if ended is not None:
            return self._finish(meas.time_s, Phase.ARRIVED, ended, remaining, fix, fused, sigma)
        if self.k >= c.max_steps and self.arrival.arrived is None:
            return self._finish(meas.time_s, Phase.FAILED, "step limit reached", remaining, fix, fused, sigma)

        s_unit, u_unit = qp_units(c, self.elements)
        b = s_unit[:, None] * g * c.period_s * u_unit         # B = G T in QP units (eq. 15)
        if c.u_bounds == 1:
            b = b * self.quadrant                             # solve in the destination's quadrant
        target_qp = target * s_unit
        if c.mpc_units == 0:
            target_qp = governed_target(s_now * s_unit, target_qp, b, c.speed_mps / u_unit)
        if not np.isfinite(np.concatenate([b.ravel(), s_now * s_unit, target_qp])).all():   # rejected (Mission.step)
            raise FloatingPointError(f"non-finite QP data: B {b.tolist()}, S {s_now.tolist()}, target {target.tolist()}")
        solution = self.mpc.solve(b, s_now * s_unit, target_qp)
        if not solution.ok:   # finite data the QP cannot solve (bounds that do not hold S): the failsafe's
            return self._finish(meas.time_s, Phase.FAILED, f"QP failed: {solution.status}", remaining, fix, fused,
                                sigma, solver_ok=False)
        u = solution.u_first * u_unit * (self.quadrant if c.u_bounds == 1 else 1.0)   # m/s, east/north
        # the optimum can be (numerically) no move, e.g. the corner of the paper's one-quadrant
        # box: eq. 4 then gives no heading, so head for the estimated destination
        direction = u if float(np.hypot(*u)) >= 1e-6 * c.speed_mps else to_dest
        theta = math.atan2(direction[1], direction[0])        # eq. 4, quadrant resolved by atan2
        speed = c.speed_mps if c.speed_mode == 1 else min(c.speed_mps, remaining / c.period_s)
        self.arrival.flew(remaining, c)
        u_a = compensation(b, xi * s_unit) * u_unit if xi.any() else np.zeros(2)
        command = self._command(meas.time_s, Phase.CRUISE, theta, speed, remaining, fix, fused, sigma,
                                u_first=(float(u[0]), float(u[1])), u_a=(float(u_a[0]), float(u_a[1])),
                                solver_time_s=solution.solve_time_s)
        self._advance(meas.time_s, s, theta, speed)
        return command

    def _take(self, estimate: Estimate) -> None:
        self.estimate = estimate
        self.est = (estimate.lat_deg, estimate.lon_deg)
        self.rejected_fixes = self.estimator.rejected

    def _filter_fields(self) -> dict:
        e = self.estimate   # the filter's own 1-sigma and covariance go out with every command
        if e is None:        # Table 3's path: its covariance once it has estimated (cruise)
            return self.table3.command_fields()
        return {"est_cov_en_m2": e.cov_en_m2, "nis": e.nis, "disturbed": e.disturbed, "bias": e.bias,
                "est_sigma_m": e.sigma_m, "fix_cov_en_m2": e.fix_cov_en_m2}

    def _estimate_position(self, meas: Measurement, s: np.ndarray, g: np.ndarray):
        """The error-state filter's estimate of this step (already made in :meth:`step`), or
        Table 3's path (:mod:`companion.nav.table3`): (fix, fused, 1-sigma)."""
        if self.estimate is not None:
            e = self.estimate
            return (e.fix_lat_deg, e.fix_lon_deg), e.updated, e.sigma_m
        self.est, fix, fused, sigma = self.table3.estimate(self.est, s, self.window_lag_en, meas.ins_lat_deg,
                                                           meas.ins_lon_deg, meas.time_s, self.elements.standard_errors(meas))
        self.rejected_fixes = self.table3.rejected
        return fix, fused, sigma

    # --- bookkeeping -------------------------------------------------------------------------
    def _probe(self, time_s: float, s: np.ndarray, theta: float, phase: str) -> Command:
        c = self.config
        remaining, _ = geodesic_inverse(self.est[0], self.est[1], c.dest_lat_deg, c.dest_lon_deg)
        command = self._command(time_s, phase, theta, c.speed_mps, remaining, (math.nan, math.nan), False, math.nan)
        self._advance(time_s, s, theta, c.speed_mps)
        return command

    def _advance(self, time_s: float, s: np.ndarray, theta: float, speed: float) -> None:
        self.last = _Last(time_s, s, speed * np.array([math.cos(theta), math.sin(theta)]), theta,
                          self.dead_reckoned_en - self.window_lag_en, float(speed))
        self.k += 1

    def _command(self, time_s, phase, theta, speed, remaining, fix, fused, sigma, **extra) -> Command:
        return Command(**{**dict(time_s=time_s, step=self.k, phase=phase, course_rad=course_from_theta(theta),
                                 speed_mps=float(speed), done=False, est_lat_deg=self.est[0],
                                 est_lon_deg=self.est[1], est_sigma_m=float(sigma), remaining_m=float(remaining),
                                 theta_rad=theta, fix_lat_deg=fix[0], fix_lon_deg=fix[1], fused=fused,
                                 u_first_mps=extra.get("u_first", (math.nan, math.nan)),
                                 compensation_mps=extra.get("u_a", (0.0, 0.0)),
                                 solver_time_s=extra.get("solver_time_s", 0.0)), **self._filter_fields()})

    def _finish(self, time_s, phase, reason, remaining=math.nan, fix=(math.nan, math.nan), fused=False,
                sigma=math.nan, solver_ok=True) -> Command:
        course = course_from_theta(self.last.theta_rad) if self.last is not None else 0.0
        self.finished = Command(**{**dict(time_s=time_s, step=self.k, phase=phase, course_rad=course, speed_mps=0.0,
                                          done=True, est_lat_deg=self.est[0], est_lon_deg=self.est[1],
                                          est_sigma_m=float(sigma), remaining_m=float(remaining),
                                          fix_lat_deg=fix[0], fix_lon_deg=fix[1], fused=fused,
                                          solver_ok=solver_ok, reason=reason), **self._filter_fields()})
        return self.finished


def end_blind(mission: Mission, time_s: float, reason: str) -> Command:
    """End ``mission`` at ``time_s`` without a measurement (the navigator excluded the period after the
    last leg had reached the estimated destination, :func:`companion.nav.arrival.passed_destination`):
    the estimate dead-reckoned along the last command to ``time_s``, arrived there."""
    if mission.finished is not None:
        return mission.finished
    last, c = mission.last, mission.config
    if last is not None:
        moved = last.velocity_en * max(time_s - last.time_s, 0.0)
        mission.est = tuple(float(v) for v in offset_position(mission.est[0], mission.est[1], moved[0], moved[1]))
    remaining, _ = geodesic_inverse(mission.est[0], mission.est[1], c.dest_lat_deg, c.dest_lon_deg)
    return mission._finish(time_s, Phase.ARRIVED, reason, remaining)


def governed_target(s_qp: np.ndarray, target_qp: np.ndarray, b: np.ndarray, reach_units: float) -> np.ndarray:
    """Reference governor: pull the target to within ``reach_units`` of input (one step at full
    speed) along the linearised path ``S + B u``, so the optimum stays inside the input bounds."""
    try:
        needed = solve2(b, target_qp - s_qp)    # input that reaches the target in one step
    except np.linalg.LinAlgError:
        return target_qp
    size = float(np.hypot(*needed))
    return target_qp if size <= reach_units else s_qp + (target_qp - s_qp) * (reach_units / size)
