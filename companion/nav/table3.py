"""Table 3's position estimate: the geomagnetic fix alone, fused with the INS where it is weak.

``FUS_MODEL 1`` (auto flies the error-state filter, with or without an INS): each cruise step's geomagnetic fix
(eq. 49, Newton from the dead-reckoned prior, on the steering pair with the start-up
calibration already removed) is the position, unless it is weak (Algorithm 1's min |G| < sigma,
read as the smallest singular value of the model's G at the fix in degrees per metre, F counted
at ``F_NT_PER_DEG``: the estimated G is too noisy to judge the fix by) or failed; then, with an
INS, the paper's INS/geomagnetic fusion (eq. 46-58, :mod:`companion.nav.fusion`) gives it.

A fix farther than ``NAV_FIX_GATE_M`` from the dead-reckoned position is a wrong contour
crossing or a disturbed measurement and is dropped, unless there is no INS and the last
``NAV_REANCHOR_N`` dropped fixes agree on where the vehicle is (:mod:`companion.nav.reanchor`):
then the estimate is what is wrong, and the fix is taken.

Uncertainty (east/north covariance ``P``, m^2; the paper gives none for the fix). A taken fix
replaces the estimate, so its covariance is the fix's own::

    P_fix = G^-1 (R_noise + R_model(d)) G^-T

``G`` the model's gradient at the fix (element units per metre), ``R_noise`` the period's
measured standard errors with the ``FUS_RMIN_*`` floor (``FUS_R_*`` where none is measured),
``R_model(d)`` what the field model gets wrong there that the start-up calibration did not
remove: a Gauss-Markov field in distance with 1-sigma ``s`` (``NAV_MERR_DEG``/``NAV_MERR_NT``)
and correlation length ``L`` (``NAV_MERR_KM``), so at a distance ``d`` from the calibration
point the error of the difference is ``2 s^2 (1 - exp(-d / L))``; ``s^2`` without a
calibration. Between fixes (none, dropped) ``P`` grows from the last fix's by the dead
reckoning since it, whose errors are constant over a run (a current, a speed scale, a course
bias) and so grow linearly, not as a random walk: ``(FUS_CUR_MPS t)^2 + (0.02 s)^2 + n
FUS_DR_POS_M^2`` per axis after ``t`` seconds, ``s`` metres and ``n`` steps. Where
the fix is weak and fused with the INS, the Table 3 filter's own 1-sigma is reported.

Against the *next* fix the estimate is judged with :attr:`relative_cov_en_m2`: the same, less
the field model's error, which the next fix a few km on shares (its difference over a step is
what the plausibility check's margin is for). Judged with the full covariance, a 20000 nT
spike whose period's fix jumped 81 km in the paper's world passed as plausible. Before
this, the 1-sigma was ``sqrt(FUS_RC_KM2)`` (1.4 km) always: against ArduPilot SITL the estimate
was up to 95 km off while it said 1.4 km, and that number goes to the flight controller
(GPS accuracy) and into the companion's plausibility and divergence judgements.
"""
from __future__ import annotations

import math

import numpy as np

from companion.nav.config import NavConfig
from companion.nav.elements import ElementSet
from companion.nav.field import PositionFixError, WorldMagneticModel, element_fix, fix_covariance
from companion.nav.fusion import InsGeomagFusion, ModelError
from companion.nav.geo import enu_offset, geodesic_inverse, offset_position
from companion.nav.navfilter import BiasSpec, measured_variance
from companion.nav.reanchor import OffsetConsensus, ReanchorSettings
from companion.nav.small import smallest_singular_value

__all__ = ["F_NT_PER_DEG", "ModelError", "Table3Estimator"]

F_NT_PER_DEG = 360.0   # automatic bounds and the fusion gate: a degree of D or I counts as 360 nT of F


class Table3Estimator:
    """The fix, the gate, and the Table 3 fusion filter; ``rejected`` counts dropped fixes."""

    def __init__(self, config: NavConfig, model: WorldMagneticModel, elements: ElementSet) -> None:
        self.config, self.model, self.elements = config, model, elements
        self.fusion = InsGeomagFusion(config.fusion)
        self.consensus = OffsetConsensus(ReanchorSettings(steps=config.reanchor_steps))
        self.rejected = 0
        self._degree_equivalent = np.array([F_NT_PER_DEG if n.endswith("_nt") else 1.0 for n in elements.names])
        self.model_error: ModelError = config.model_error
        self.calibrated = False      # the start-up calibration is removed (Mission.set_bias)
        self.estimated = False       # cov_en_m2 is an estimate's (a cruise step has been estimated)
        self.cov_en_m2 = np.eye(2) * config.gps_sigma_m ** 2   # the start: GPS-known
        self._declared = BiasSpec.per_element(elements.names, config.filter.r_deg, config.filter.r_nt)
        self._floor = BiasSpec.per_element(elements.names, config.filter.r_min_deg, config.filter.r_min_nt)
        self._last: tuple[float, tuple[float, float]] = (0.0, (config.start_lat_deg, config.start_lon_deg))
        # the last fix (or the start): its covariance and time, the distance and steps flown since
        self._anchor_cov, self._anchor_time_s, self._flown_m, self._steps = self.cov_en_m2, 0.0, 0.0, 0
        self.relative_cov_en_m2 = self._anchor_relative_cov = self.cov_en_m2

    def parts(self) -> tuple:
        """The objects whose own attributes a step changes (:class:`companion.nav.rollback.Checkpoint`)."""
        return self, self.consensus, self.fusion, self.fusion.kf

    def command_fields(self) -> dict:
        """The uncertainty a :class:`companion.nav.mission.Command` carries from this path, once
        a cruise step has been estimated: ``est_cov_en_m2`` (east-east, east-north, north-north,
        m^2) and ``next_fix_sigma_m``."""
        if not self.estimated:
            return {}
        c = self.cov_en_m2
        return {"est_cov_en_m2": (float(c[0, 0]), float(c[0, 1]), float(c[1, 1])),
                "next_fix_sigma_m": self.relative_sigma_m}

    @property
    def relative_sigma_m(self) -> float:
        """1-sigma per axis of :attr:`relative_cov_en_m2` (m): the estimate against the next fix."""
        return math.sqrt(0.5 * float(self.relative_cov_en_m2[0, 0] + self.relative_cov_en_m2[1, 1]))

    def _dead_reckoned_growth(self, time_s: float, est: tuple[float, float]) -> np.ndarray:
        """What the dead reckoning since the last fix adds to ``P`` at ``time_s`` (module
        docstring); advances the distance and steps flown."""
        c = self.config.filter.dead_reckoning
        self._flown_m += geodesic_inverse(*self._last[1], est[0], est[1])[0]
        self._steps += 1
        dt = max(time_s - self._anchor_time_s, 0.0)
        grown = (c.current_sigma_mps * dt) ** 2 + (c.speed_frac * self._flown_m) ** 2 \
            + self._steps * c.pos_sigma_m ** 2
        return np.eye(2) * grown

    def estimate(self, est: tuple[float, float], s: np.ndarray, lag_en_m: np.ndarray, ins_lat_deg: float,
                 ins_lon_deg: float, time_s: float = math.nan,
                 standard_errors: np.ndarray | None = None) -> tuple[tuple[float, float], tuple[float, float], bool, float]:
        """(position, fix or NaNs, fused with the INS, 1-sigma m per axis) for the step at mission
        time ``time_s`` whose dead-reckoned position is ``est``, measuring ``s`` (its standard
        errors ``standard_errors``, NaN or None: not measured) at the window centre ``lag_en_m``
        behind it. The covariance is left in :attr:`cov_en_m2`."""
        position, fix, fused, sigma, cov, relative = self._estimate(est, s, lag_en_m, ins_lat_deg, ins_lon_deg,
                                                                    time_s, standard_errors)
        self.cov_en_m2, self.relative_cov_en_m2, self.estimated = cov, relative, True
        now = time_s if math.isfinite(time_s) else self._last[0]
        self._last = (now, position)
        if not (math.isnan(fix[0]) and not fused):   # a fix (or the fused position): dead reckon from here
            self._anchor_cov, self._anchor_relative_cov = cov, relative
            self._anchor_time_s, self._flown_m, self._steps = now, 0.0, 0
        return position, fix, fused, sigma

    def _estimate(self, est, s, lag_en_m, ins_lat_deg, ins_lon_deg, time_s, standard_errors):
        c = self.config
        have_ins = math.isfinite(ins_lat_deg) and math.isfinite(ins_lon_deg)
        grown = self._dead_reckoned_growth(time_s if math.isfinite(time_s) else self._last[0], est)
        cov, relative = self._anchor_cov + grown, self._anchor_relative_cov + grown
        gradient = None
        lag_e, lag_n = (float(v) for v in lag_en_m)
        prior = offset_position(est[0], est[1], -lag_e, -lag_n)
        try:
            # the position is what is used, with G at the last iterate (under tol_m from it): the
            # model is not evaluated once more at the fix itself
            found = element_fix(self.model, self.elements, s, float(prior[0]), float(prior[1]), c.alt_m, c.year,
                                report_at_fix=False)
            fix = tuple(float(v) for v in offset_position(found.lat_deg, found.lon_deg, lag_e, lag_n))
            gradient = found.gradient
            # the fix is as good as the field's gradient where it lands (an error e moves it G^-1 e)
            in_degrees = found.gradient / self._degree_equivalent[:, None]
            weak = smallest_singular_value(in_degrees) < c.fusion_sigma_deg_per_m
        except PositionFixError:
            fix, weak = None, True
        if fix is not None and geodesic_inverse(est[0], est[1], *fix)[0] > c.fix_gate_m:
            # farther from the dead-reckoned position than the vehicle can have strayed in a step
            # (a wrong crossing of the contours, a disturbed measurement): not a fix, unless the
            # last rejected fixes agree on where the vehicle is (the estimate is what is wrong)
            if have_ins or self.consensus.rejected(np.array(enu_offset(est[0], est[1], *fix))) is None:
                fix, weak = None, True
                self.rejected += 1
        elif fix is not None:
            self.consensus.clear()
        position, fused = est, False
        if weak and have_ins:
            ins_en = np.array(enu_offset(c.start_lat_deg, c.start_lon_deg, ins_lat_deg, ins_lon_deg))
            if fix is not None:
                result = self.fusion.step(ins_en, np.array(enu_offset(c.start_lat_deg, c.start_lon_deg, *fix)))
            else:
                result = self.fusion.predict_only(ins_en)
            position = tuple(float(v) for v in offset_position(c.start_lat_deg, c.start_lon_deg,
                                                               result.east_m, result.north_m))
            fused, cov = True, np.eye(2) * result.sigma_m ** 2
            relative = cov
        elif fix is not None:
            position = fix
            cov, relative = self._fix_covariances(gradient, fix, standard_errors)
        sigma = math.sqrt(0.5 * float(cov[0, 0] + cov[1, 1]))
        return position, (fix if fix is not None else (math.nan, math.nan)), fused, sigma, cov, relative

    def _fix_covariances(self, gradient: np.ndarray, fix: tuple[float, float],
                         standard_errors: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """``P_fix`` (module docstring) of a fix at ``fix`` with the model's gradient there, and
        the same of its noise alone (what the estimate is against the next fix: the model's
        error is shared between neighbouring fixes)."""
        c = self.config
        n = len(self.elements.names)
        se = np.full(n, np.nan) if standard_errors is None else np.asarray(standard_errors, dtype=float)[:n]
        distance = geodesic_inverse(c.start_lat_deg, c.start_lon_deg, *fix)[0] if self.calibrated else None
        noise = measured_variance(se, self._floor, self._declared)   # as the error-state filter's R
        try:
            return (fix_covariance(gradient, noise + self.model_error.variance(self.elements.names, distance)),
                    fix_covariance(gradient, noise))
        except np.linalg.LinAlgError:   # a singular G (the fix's Newton steps would have failed first):
            wide = np.eye(2) * c.fix_gate_m ** 2   # as uncertain as the gate lets a fix be
            return wide, wide
