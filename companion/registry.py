"""The parameter registry: every tunable value of the companion, declared once.

Each :class:`ParamSpec` gives a name of at most 16 characters (MAVLink's ``param_id``), its
type, default, range, unit and description. Three kinds: settings (``_p``), start-up-only
settings the link cannot change (``_boot``: the safety ceiling and who may write), and
*readings* (``_reading``: measurements a ground station keeps up to date, such as Kp, each with
the lifetime after which a value not renewed over the link counts as none; :data:`READINGS`).
What is derived from the registry (validation, ``.parm`` files, the configurations the code
reads) lives in :mod:`companion.params`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping, TypeVar

__all__ = ["MAX_NAME_LEN", "READINGS", "REGISTRY", "SPEC_BY_FIELD", "SPEC_BY_NAME", "ParamError", "ParamSpec",
           "from_values", "hold_frozen", "settings"]

MAX_NAME_LEN = 16  # MAVLink PARAM_VALUE.param_id is char[16]


class ParamError(ValueError):
    """A parameter name or value that the registry refuses."""


@dataclass(frozen=True)
class ParamSpec:
    """Declaration of one parameter: ``value`` must satisfy ``minimum <= value <= maximum``."""

    name: str
    kind: type  # int or float
    default: float
    minimum: float
    maximum: float
    unit: str
    doc: str
    boot_only: bool = False   # set only from the command line or the .parm file at start, never over the link
    # a reading, not a setting: a measurement the ground station renews; its value counts only while
    # set over the link within this many seconds of message time (one from the .parm file never does)
    max_age_s: float | None = None
    # where the value goes: the settings group (a dataclass decorated with :func:`settings`) and
    # its field, which holds ``value * scale`` (the unit conversion, declared here once: km/h ->
    # m/s, km -> m, km^2 -> m^2); None for values no settings class holds (readings, the start-up
    # ceiling, the magnetometer calibration the companion collects)
    group: str | None = None
    field: str | None = None
    scale: float = 1.0
    frozen: bool = False      # a running mission keeps its value: a change applies to the next one

    def field_value(self, value: float | int) -> float | int:
        """``value`` (in this parameter's unit) as its settings field holds it."""
        return value * self.scale if self.scale != 1.0 else value

    def coerce(self, value: float) -> float | int:
        """The value as this parameter's type, or ParamError naming the parameter and range."""
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ParamError(f"{self.name}: {value!r} is not a number") from None
        if not math.isfinite(number):
            raise ParamError(f"{self.name}: {value!r} is not finite")
        if self.kind is int:
            if number != round(number):
                raise ParamError(f"{self.name}: {value!r} is not an integer")
            number = int(round(number))
        if not self.minimum <= number <= self.maximum:
            raise ParamError(
                f"{self.name}: {value!r} is out of range [{self.minimum:g}, {self.maximum:g}] {self.unit}".rstrip()
            )
        return number


def _p(name: str, kind: type, default: float, minimum: float, maximum: float, unit: str, doc: str, *,
       to: str | None = None, scale: float = 1.0, frozen: bool = False) -> ParamSpec:
    """A setting; ``to="group.field"`` names the settings field it becomes (times ``scale``),
    ``frozen``: a running mission keeps it until it ends."""
    group, _, field = to.partition(".") if to else (None, "", None)
    return ParamSpec(name, kind, default, minimum, maximum, unit, doc, group=group, field=field, scale=scale,
                     frozen=frozen)


def _boot(name: str, kind: type, default: float, minimum: float, maximum: float, unit: str, doc: str) -> ParamSpec:
    """A start-up-only parameter: the parameter server serves it but refuses every PARAM_SET of it."""
    return ParamSpec(name, kind, default, minimum, maximum, unit, doc + " (start-up only: --params file)", True)


def _reading(name: str, default: float, minimum: float, maximum: float, unit: str, max_age_s: float,
             doc: str) -> ParamSpec:
    """A reading (a float): a value counts only while the ground station renews it within
    ``max_age_s`` of message time, and the description says so."""
    lifetime = f"{max_age_s / 3600.0:g} h" if max_age_s >= 3600.0 else f"{max_age_s / 60.0:g} min"
    return ParamSpec(name, float, default, minimum, maximum, unit,
                     f"{doc}, and so is a value not set over the link in the last {lifetime} (one left in the "
                     ".parm file is none)", max_age_s=max_age_s)


# Kp is a 3-hour index: one not renewed within an index period and half an hour of publication
# delay is none; a Kp left in the .parm file from another day would declare (or deny) a storm for
# the whole flight
_KP_MAX_AGE_S = 3.5 * 3600.0
# SYM-H is published every minute: one older than a quarter of an hour is none; one from another
# day, taken as the start's reference, would shift every later measurement by the day's difference
_SYMH_MAX_AGE_S = 900.0

_KMH_TO_MPS = 1.0 / 3.6
_KM_TO_M = 1000.0
_KM2_TO_M2 = 1e6
_PER_KM_TO_PER_M = 1e-3

REGISTRY: tuple[ParamSpec, ...] = (
    # --- mission (Table 4, "Mission Settings") ---
    _p("NAV_START_LAT", float, 33.0, -89.0, 89.0, "deg", "start latitude (lambda_0, phi_0), WGS84", to="nav.start_lat_deg", frozen=True),
    _p("NAV_START_LON", float, 152.0, -180.0, 180.0, "deg", "start longitude", to="nav.start_lon_deg", frozen=True),
    _p("NAV_DEST_LAT", float, 28.0, -89.0, 89.0, "deg", "destination latitude (lambda_d, phi_d)", to="nav.dest_lat_deg", frozen=True),
    _p("NAV_DEST_LON", float, 158.0, -180.0, 180.0, "deg", "destination longitude", to="nav.dest_lon_deg", frozen=True),
    _p("NAV_ALT_M", float, 0.0, -500.0, 20000.0, "m", "altitude above the ellipsoid used for the field model", to="nav.alt_m", frozen=True),
    _p("NAV_YEAR", float, 2024.36, 2020.0, 2029.99, "year", "decimal year for the field model (paper: 2024.36)", to="nav.year", frozen=True),
    _p("NAV_WMM", int, 0, 0, 2, "", "field model: 0 by date (WMM2020 before 2024.87), 1 WMM2020, 2 WMM2025", to="nav.wmm", frozen=True),
    _p("NAV_MAP", int, 0, 0, 1, "", "the navigator's field map: 0 the WMM (the paper's; NAV_WMM picks which), 1 WMMHR-2025 (degree 133: also the crust's wavelengths down to 300 km; covers NAV_YEAR 2024.87-2030, never extrapolated)", to="nav.nav_map"),
    _p("NAV_SPEED_KMH", float, 50.0, 1.0, 300.0, "km/h", "cruise speed v (Table 4)", to="nav.speed_mps", scale=_KMH_TO_MPS),
    _p("NAV_PERIOD_S", float, 360.0, 1.0, 7200.0, "s", "control period T (Table 4 gives 10 without unit; see README)", to="nav.period_s"),
    _p("NAV_LOOKAHEAD_M", float, 10000.0, 0.0, 1e6, "m", "Fc-MPC aims this far ahead on the start-destination geodesic; 0 aims at the destination", to="nav.lookahead_m"),
    _p("NAV_ARRIVE_M", float, 500.0, 10.0, 100000.0, "m", "arrival threshold epsilon on the estimated distance", to="nav.arrive_m"),
    _p("NAV_FINAL_LEG", int, 1, 0, 1, "", "on arrival: 1 fly the remainder to the estimated destination for one more period, then stop (Fc-MPC, not with NAV_SPEED_MODE 1); 0 stop at once (the paper)", to="nav.final_leg"),
    _p("NAV_ARRIVE_LEGS", int, 3, 0, 1000, "", "arrived after this many legs in a row each planned to reach the estimated destination (0: epsilon only, the paper)", to="nav.arrive_legs"),
    _p("NAV_MAX_STEPS", int, 1000, 3, 100000, "", "give up after this many control steps", to="nav.max_steps"),
    _p("NAV_PROBE1_DEG", float, 0.0, 0.0, 360.0, "deg", "first probing heading theta_1, from east counter-clockwise", to="nav.probe1_deg", frozen=True),
    _p("NAV_PROBE2_DEG", float, 270.0, 0.0, 360.0, "deg", "second probing heading theta_2, from east counter-clockwise", to="nav.probe2_deg", frozen=True),
    _p("NAV_CONTROLLER", int, 2, 0, 2, "", "0 LTI-MPC, 1 LTV-MPC, 2 Fc-MPC", to="nav.controller", frozen=True),
    _p("NAV_ELEMENTS", int, 0, 0, 5, "", "navigation state S: 0 auto (5 with an independent heading, else 2), 1 (D, I) paper, 2 (I, F) heading-free, 3 (H, Z) heading-free, 4 (D, I, F) weighted, F set aside by the filter while a space-weather reading declares a storm (NAV_KP, NAV_SYMH: feed them), 5 (D, I, F) with F weighed only while a fresh reading says quiet (without a feed: (D, I))", to="nav.elements", frozen=True),
    _p("COMP_HEADING_SRC", int, 0, 0, 2, "", "heading the FC reports: 0 detect (EK3_SRC1_YAW/COMPASS_USE, EKF2_MAG_TYPE), 1 independent of the compass, 2 compass-derived", to="companion.heading_source"),
    _p("NAV_CALIBRATE", int, 1, 0, 1, "", "1 subtract the start-up bias (measured minus model at a GPS-known start) from every measurement", to="nav.calibrate", frozen=True),
    _p("NAV_FIX_GATE_M", float, 50000.0, 100.0, 1e7, "m", "a geomagnetic fix farther than this from the dead-reckoned position is rejected (the step keeps dead reckoning)", to="nav.fix_gate_m"),
    _p("NAV_MERR_DEG", float, 0.3, 0.0, 10.0, "deg", "Table 3's uncertainty: 1-sigma of the field model's D/I error at a point (crust, main-field model), uncorrelated beyond NAV_MERR_KM", to="model_error.sigma_deg", frozen=True),
    _p("NAV_MERR_NT", float, 300.0, 0.0, 1e5, "nT", "Table 3's uncertainty: 1-sigma of the field model's F/H/Z error at a point", to="model_error.sigma_nt", frozen=True),
    _p("NAV_MERR_KM", float, 25.0, 0.01, 1e5, "km", "Table 3's uncertainty: correlation length of the field model's error (how far the start-up calibration holds)", to="model_error.length_m", scale=_KM_TO_M, frozen=True),
    _p("NAV_EXCL_MAX", int, 5, 0, 1000, "", "after this many periods in a row excluded by the plausibility check (|F| band, fix jump), the next one is taken anyway (the core's own screening and fix gate NAV_FIX_GATE_M still apply): a wrong estimate or |F| reference makes every later period implausible, and the vehicle would fly its last course on for good; 0 never (before 2026-12-06)", to="nav.excl_max"),
    _p("NAV_REANCHOR_N", int, 0, 0, 100, "", "dead reckoning without an INS: after this many rejected fixes in a row that agree on where the vehicle is, the estimate re-anchors there; 0 never (default: in the realistic world agreeing rejected fixes were biased fixes)", to="nav.reanchor_steps"),
    _p("NAV_DR_HDG", int, 1, 0, 1, "", "dead reckoning between fixes (no independent INS position) on 0 the commanded course, 1 the heading measured over the period (magnetometer levelled by the accelerometer, plus the model's D) where it is measured", to="nav.dr_heading"),
    _reading("NAV_KP", -1.0, -1.0, 9.0, "", _KP_MAX_AGE_S, "planetary geomagnetic index Kp now, from a space-weather service via the ground station (GFZ, NOAA SWPC; update it every 3 h): at or above FUS_KP_ON the navigator takes a storm as on from that step; -1 unknown (the innovations alone decide)"),
    _reading("NAV_SYMH", 99999.0, -3000.0, 99999.0, "nT", _SYMH_MAX_AGE_S, "the ring-current index SYM-H now, from a space-weather service via the ground station (Kyoto WDC, NASA OMNI; one value a minute, update it every few minutes): the navigator removes the ring current's change since the start from every measurement (FUS_SYMH_K); 99999 (OMNI's fill value) unknown"),
    _p("NAV_SPEED_MODE", int, 0, 0, 1, "", "0 slow down to land on the destination, 1 constant cruise speed (paper)", to="nav.speed_mode"),
    # --- gradient estimation (eq. 5-12) ---
    _p("GRAD_UPDATE", int, 0, 0, 2, "", "0 Broyden secant update, 1 eq. 10 as printed, 2 fresh estimate from last two moves", to="nav.grad_update", frozen=True),
    _p("GRAD_MIN_MOVE_M", float, 200.0, 1.0, 100000.0, "m", "skip a gradient update when the step moved less than this", to="nav.grad_min_move_m", frozen=True),
    # --- MPC (eq. 13-38) ---
    _p("MPC_HORIZON", int, 2, 1, 20, "", "prediction horizon N", to="nav.horizon"),
    _p("MPC_Q_D", float, 1.0, 0.0, 1e9, "", "state weight Q on D (Table 4: Q = I)", to="nav.q_d"),
    _p("MPC_Q_I", float, 1.0, 0.0, 1e9, "", "state weight Q on I", to="nav.q_i"),
    _p("MPC_F_D", float, 1.0, 0.0, 1e9, "", "terminal weight F on D (Table 4: F = I)", to="nav.f_d"),
    _p("MPC_F_I", float, 1.0, 0.0, 1e9, "", "terminal weight F on I", to="nav.f_i"),
    _p("MPC_R_X", float, 10.0, 1e-9, 1e9, "", "input weight R on v_x (Table 4: R = 10 I)", to="nav.r_x"),
    _p("MPC_R_Y", float, 10.0, 1e-9, 1e9, "", "input weight R on v_y", to="nav.r_y"),
    _p("MPC_UNITS", int, 0, 0, 1, "", "units the weights apply to: 0 scaled (arcsec, U/v), 1 paper (deg, km/h)", to="nav.mpc_units"),
    _p("MPC_U_BOUNDS", int, 0, 0, 1, "", "0 symmetric |v_x|,|v_y| <= v, 1 paper U in [0, 40]^2 km/h, signs by quadrant", to="nav.u_bounds", frozen=True),
    _p("MPC_U_MAX_KMH", float, 40.0, 1.0, 300.0, "km/h", "per-axis input bound U_max for MPC_U_BOUNDS = 1 (Table 4)", to="nav.u_max_mps", scale=_KMH_TO_MPS),
    _p("MPC_S_MIN_D", float, -10.0, -180.0, 180.0, "deg", "state bound S_min on D (Table 4)", to="nav.s_min_d"),
    _p("MPC_S_MIN_I", float, 10.0, -90.0, 90.0, "deg", "state bound S_min on I (Table 4)", to="nav.s_min_i"),
    _p("MPC_S_MAX_D", float, 100.0, -180.0, 180.0, "deg", "state bound S_max on D (Table 4)", to="nav.s_max_d"),
    _p("MPC_S_MAX_I", float, 100.0, -90.0, 100.0, "deg", "state bound S_max on I (Table 4)", to="nav.s_max_i"),
    _p("MPC_S_MIN_F", float, 20000.0, 0.0, 100000.0, "nT", "state bound S_min on total intensity F (element set (I, F), MPC_S_AUTO = 0)", to="nav.s_min_f"),
    _p("MPC_S_MAX_F", float, 70000.0, 0.0, 100000.0, "nT", "state bound S_max on F", to="nav.s_max_f"),
    _p("MPC_S_AUTO", int, 1, 0, 1, "", "1 state bounds from the mission's start and destination field +- MPC_S_MARGIN; 0 the MPC_S_MIN_*/MAX_* values (Table 4)", to="nav.s_auto", frozen=True),
    _p("MPC_S_MARGIN", float, 10.0, 0.1, 90.0, "deg", "margin of the automatic state bounds for D and I (F: 360 nT per degree)", to="nav.s_margin_deg", frozen=True),
    _p("MPC_S_ADMIT", int, 1, 0, 1, "", "1 (default) the state bounds admit the current state: a state S beyond them widens them to S for that step, so the QP stays feasible and the vehicle may move back inside, not farther out; 0 the paper's hard bounds (eq. 34: the QP is infeasible and the mission fails)", to="nav.s_admit"),
    _p("MPC_SOLVER", int, 0, 0, 1, "", "QP backend: 0 OSQP, 1 daqp (exact dense active set)", to="nav.solver"),
    # --- fusion (eq. 46-58, Table 3) ---
    _p("FUS_SIGMA", float, 0.001, 0.0, 10.0, "deg/km", "fuse with the INS when the fix is weak: smallest singular value of the model G", to="nav.fusion_sigma_deg_per_m", scale=_PER_KM_TO_PER_M),
    _p("FUS_QC_KM2", float, 0.05, 0.0, 1e6, "km^2", "process noise Q_c on the position error (Table 3)", to="fusion.qc_m2", scale=_KM2_TO_M2, frozen=True),
    _p("FUS_RC_KM2", float, 2.0, 1e-9, 1e6, "km^2", "measurement noise R_c of INS minus geomagnetic fix (Table 3)", to="fusion.rc_m2", scale=_KM2_TO_M2, frozen=True),
    _p("FUS_P0_KM2", float, 1.0, 1e-9, 1e6, "km^2", "initial covariance P_0 of the position error (Table 3)", to="fusion.p0_m2", scale=_KM2_TO_M2, frozen=True),
    _p("FUS_FEEDBACK", int, 0, 0, 1, "", "0 INS corrected by the estimated error, 1 eq. 58 as printed", to="fusion.feedback", frozen=True),
    # --- estimation filter (issue 14: companion/nav/navfilter.py) ---
    _p("FUS_MODEL", int, 0, 0, 3, "", "position estimator: 0 auto (error-state filter with the INS process model when an independent INS position is there, else with dead reckoning), 1 Table 3 (paper: fix, fused only where weak), 2 error-state INS, 3 error-state dead reckoning", to="nav.fusion_model", frozen=True),
    _p("FUS_R_DEG", float, 0.002, 1e-6, 10.0, "deg", "declared 1-sigma noise of an averaged D or I", to="filter.r_deg", frozen=True),
    _p("FUS_R_NT", float, 2.0, 1e-3, 10000.0, "nT", "declared 1-sigma noise of an averaged F, H or Z", to="filter.r_nt", frozen=True),
    _p("FUS_R_SRC", int, 1, 0, 1, "", "measurement noise of the error-state filter: 1 each period's measured standard errors with FUS_RMIN_* added in quadrature (FUS_R_DEG/FUS_R_NT where none is measured), 0 the declared FUS_R_DEG/FUS_R_NT", to="filter.r_source", frozen=True),
    _p("FUS_RMIN_DEG", float, 0.0005, 0.0, 10.0, "deg", "floor added in quadrature to a measured D or I standard error (errors the period's scatter cannot show)", to="filter.r_min_deg", frozen=True),
    _p("FUS_RMIN_NT", float, 0.5, 0.0, 10000.0, "nT", "floor added in quadrature to a measured F, H or Z standard error", to="filter.r_min_nt", frozen=True),
    _p("FUS_B0_DEG", float, 0.5, 1e-6, 90.0, "deg", "prior 1-sigma of the D/I bias states (measured minus model)", to="bias.sigma0_deg", frozen=True),
    _p("FUS_B0_NT", float, 500.0, 1e-3, 1e5, "nT", "prior 1-sigma of the F/H/Z bias states", to="bias.sigma0_nt", frozen=True),
    _p("FUS_BQ_DEG", float, 0.002, 0.0, 10.0, "deg/rt(h)", "random walk of the D/I bias states while quiet", to="bias.q_deg_rth", frozen=True),
    _p("FUS_BQ_NT", float, 2.0, 0.0, 1e4, "nT/rt(h)", "random walk of the F/H/Z bias states while quiet", to="bias.q_nt_rth", frozen=True),
    _p("FUS_BQD_DEG", float, 0.0075, 0.0, 1.0, "deg/rt(km)", "random walk of the D/I bias states per distance travelled: the main-field model's error against the start-up calibration grows with the distance from the start (0.2 deg in 800 km)", to="bias.qd_deg_rkm", frozen=True),
    _p("FUS_BQD_NT", float, 7.5, 0.0, 1000.0, "nT/rt(km)", "random walk of the F/H/Z bias states per distance travelled (200 nT in 800 km)", to="bias.qd_nt_rkm", frozen=True),
    _p("FUS_BQA_DEG", float, 0.05, 0.0, 10.0, "deg/rt(h)", "random walk of the D/I bias states while the innovations say a disturbance is active", to="bias.qa_deg_rth", frozen=True),
    _p("FUS_BQA_NT", float, 40.0, 0.0, 1e4, "nT/rt(h)", "random walk of the F/H/Z bias states while a disturbance is active", to="bias.qa_nt_rth", frozen=True),
    _p("FUS_ATT_INS", int, 2, 0, 2, "", "with the INS process model, which part of the attitude that levels and turns the magnetometer into north-east-down is the INS's own: 2 roll, pitch and heading (a navigation-grade INS's attitude), 1 roll and pitch (the heading from a true-heading sensor), 0 none (an AHRS of its own); that part's misalignment states enter the measured elements", to="filter.attitude_from_ins", frozen=True),
    _p("FUS_BH_DEG", float, 0.3, 0.0, 5.0, "deg", "prior 1-sigma of each heading harmonic (cos, sin of psi and 2 psi) of the D/I calibration residual: a body-frame hard/soft-iron residual changes D and I when the vehicle turns; 0: no such states (before 2026-12-02). 0.3 deg: a residual of one AK8963 LSB (150 nT) per axis against a horizontal field of about 29 uT (0.1 until 2026-12-06; with the plausibility check in the Monte Carlo, 0.1 excluded the periods that teach these states: realistic Pacific seeds 0-19, 17.2 km median against 10.1 at 0.3)", to="bias.heading_deg"),
    _p("FUS_BH_NT", float, 200.0, 0.0, 5000.0, "nT", "prior 1-sigma of each heading harmonic of the F/H/Z calibration residual; 0: no such states (before 2026-12-02)", to="bias.heading_nt"),
    _p("FUS_BQA_ADAPT", int, 1, 0, 1, "", "while the innovations (not a Kp) say a disturbance is active: 1 (default) the bias states walk at FUS_BQA_DEG/NT scaled by covariance matching (the averaged NIS), between the quiet FUS_BQ_* and FUS_BQA_*; 0 at FUS_BQA_* always (before 2026-12-02)", to="bias.qa_adapt", frozen=True),
    _p("FUS_BQA_SADAPT", int, 3, 0, 3, "", "while an index declares a storm: 3 (default) the declared walk, and the position covariance the navigator reports (and judges plausibility by) scaled by the declared storm's a-posteriori variance factor, the mean NIS/m of its updates, at least 1; 1 its walk (FUS_BQA_N/E/Z, FUS_SYMH_N, or FUS_BQA_DEG/NT with FUS_BQA_MODE 0) scaled by covariance matching (the averaged NIS), never below the declared walk and at most 100 times it; 2 the same, raised only while the averaged NIS is beyond the innovations' onset threshold (3.5, set for a false-alarm rate); 0 the declared walk always (before 2026-12-06). 3 chosen on tuning seeds 0-49, feed on, parameters fitted without each storm: Halloween 2003 84 -> 94 % inside the own 95 % ellipse (median 13.9 -> 13.6 km), St Patrick's 2015 94 -> 98 % (same miss), May 2024 and March 2011 unchanged; 1 and 2 cost St Patrick's its accuracy (seeds 0-15: median 7.8 -> 14.4 / 12.4 km; docs/storms.md)", to="bias.storm_adapt", frozen=True),
    _p("FUS_BQA_MODE", int, 1, 0, 1, "", "how the bias states walk while a Kp declares a storm (FUS_KP_ON): 1 (default) along the field components at FUS_BQA_N/E/Z through the elements' Jacobian, on top of the quiet walk (a storm moves H, so I and F together, and D less); 0 per element at FUS_BQA_DEG/NT. A disturbance only the innovations found walks per element, FUS_BQA_ADAPT", to="bias.qa_mode"),
    _p("FUS_BQA_N", float, 60.0, 0.0, 1e4, "nT/rt(h)", "FUS_BQA_MODE 1: random walk of the disturbance's north component while active (its change over one 6-min step: 10 May 2024 along the Pacific route from 18 UTC, real time). Like every storm-time default (FUS_BQA_N/E/Z/T*/R*, FUS_SYMH_N/TN/RNE/RNZ) fitted on the may2024 storm only: a storm world is scored with values fitted on other storms (fcmpc-fit-storms, fcmpc-montecarlo --storm-params loo)", to="bias.qa_n_nt_rth"),
    _p("FUS_BQA_E", float, 46.0, 0.0, 1e4, "nT/rt(h)", "FUS_BQA_MODE 1: random walk of the disturbance's east component while active (fitted on the may2024 storm, see FUS_BQA_N)", to="bias.qa_e_nt_rth"),
    _p("FUS_BQA_Z", float, 30.0, 0.0, 1e4, "nT/rt(h)", "FUS_BQA_MODE 1: random walk of the disturbance's down component while active (fitted on the may2024 storm, see FUS_BQA_N)", to="bias.qa_z_nt_rth"),
    _p("FUS_BQA_TN", float, 0.0, 0.0, 1000.0, "h", "FUS_BQA_MODE 1: correlation time of the disturbance's north component, which is then Gauss-Markov (a state of the filter) wandering at FUS_BQA_N over short lags; 0 (default) a random walk", to="bias.qa_tn_h"),
    _p("FUS_BQA_TE", float, 0.0, 0.0, 1000.0, "h", "FUS_BQA_MODE 1: correlation time of the east component (0: random walk)", to="bias.qa_te_h"),
    _p("FUS_BQA_TZ", float, 0.0, 0.0, 1000.0, "h", "FUS_BQA_MODE 1: correlation time of the down component (0: random walk)", to="bias.qa_tz_h"),
    _p("FUS_BQA_RNE", float, 0.0, -1.0, 1.0, "", "FUS_BQA_MODE 1: correlation of the disturbance's north and east changes over a step while declared (a storm's currents move the components together; 0 independent; three values no correlation matrix has are taken at the nearest one)", to="bias.qa_rne"),
    _p("FUS_BQA_RNZ", float, 0.0, -1.0, 1.0, "", "FUS_BQA_MODE 1: correlation of the north and down changes (see FUS_BQA_RNE)", to="bias.qa_rnz"),
    _p("FUS_BQA_REZ", float, 0.0, -1.0, 1.0, "", "FUS_BQA_MODE 1: correlation of the east and down changes (see FUS_BQA_RNE)", to="bias.qa_rez"),
    _p("FUS_KP_ON", float, 5.0, 0.0, 9.0, "", "a Kp (NAV_KP, or the simulated world's space-weather feed) at or above this declares a storm: the bias states walk as FUS_BQA_MODE says from that step on, and the innovations cannot end it while it lasts (5: a G1 storm on NOAA's scale)", to="nav.kp_on"),
    _p("FUS_SYMH_ON", float, -50.0, -3000.0, 0.0, "nT", "a SYM-H (NAV_SYMH, or the simulated world's feed) at or below this declares a storm as FUS_KP_ON does (either index suffices): -50, a moderate storm on the Dst scale (Gonzalez et al. 1994; SYM-H is a 1-min Dst); -3000 never", to="nav.symh_on_nt"),
    _p("FUS_SYMH_K", float, 1.0, 0.0, 3.0, "", "the ring current's change of H at the vehicle per nT of SYM-H change (NAV_SYMH): subtracted from each measurement along the local horizontal field; 0 never (measured 1.02 along the Pacific route, 10 May 2024; fcmpc-fit-storms --by-miss chooses it on the training storms by the navigator's miss, and the storm worlds are scored with that choice)", to="nav.symh_ratio"),
    _p("FUS_SYMH_N", float, 77.0, 0.0, 1e4, "nT/rt(h)", "with a SYM-H correction: the north component's residual, in place of FUS_BQA_N: its change over one 6-min step (10 May 2024 along the Pacific route, real time: fitted on the may2024 storm, see FUS_BQA_N)", to="bias.symh_n_nt_rth"),
    _p("FUS_SYMH_TN", float, 0.9, 0.0, 1000.0, "h", "with a SYM-H correction: the north residual's correlation time, in place of FUS_BQA_TN (Gauss-Markov: the prediction's error comes and goes; real time 0.88 h; 0 a random walk)", to="bias.symh_tn_h"),
    _p("FUS_SYMH_RNE", float, 0.0, -1.0, 1.0, "", "with a SYM-H correction: the north residual's correlation with the east changes, in place of FUS_BQA_RNE", to="bias.symh_rne"),
    _p("FUS_SYMH_RNZ", float, 0.0, -1.0, 1.0, "", "with a SYM-H correction: the north residual's correlation with the down changes, in place of FUS_BQA_RNZ", to="bias.symh_rnz"),
    _p("FUS_GM_DEG", float, 0.05, 0.0, 10.0, "deg", "local model error states of the D/I elements (crust, main-field model): stationary 1-sigma of a Gauss-Markov process in distance; 0 with FUS_GM_NT 0: no such states", to="bias.local_deg", frozen=True),
    _p("FUS_GM_NT", float, 50.0, 0.0, 1e4, "nT", "local model error states of the F/H/Z elements: stationary 1-sigma", to="bias.local_nt", frozen=True),
    _p("FUS_GM_KM", float, 25.0, 0.01, 1e5, "km", "local model error states: correlation length in distance travelled", to="bias.local_length_m", scale=_KM_TO_M, frozen=True),
    _p("FUS_GM_ORDER", int, 1, 1, 2, "", "local model error states: order of the Gauss-Markov process in distance: 1 rough (each step may change it by sigma sqrt(2 d / L)), 2 smooth, critically damped, a value and its slope along the track per element (changes by about sigma d / L over a short leg, as the crust, a band-limited field, does)", to="bias.local_order", frozen=True),
    # the INS the error-state filter assumes (its datasheet, 1-sigma; defaults: Table 1, the misalignment read as arc-seconds)
    _p("FUS_INS_TILT", float, 50.0, 0.0, 36000.0, "arcsec", "INS process model: initial misalignment about each level axis (tilt)", to="ins.tilt_arcsec"),
    _p("FUS_INS_AZ", float, 500.0, 0.0, 36000.0, "arcsec", "INS process model: initial azimuth misalignment (heading)", to="ins.azimuth_arcsec"),
    _p("FUS_INS_VEL", float, 10.0, 0.0, 100.0, "m/s", "INS process model: initial horizontal velocity error, both axes together (per axis this over sqrt 2)", to="ins.vel_err_mps"),
    _p("FUS_INS_POS", float, 5000.0, 0.0, 1e6, "m", "INS process model: initial position error per horizontal axis, before the start-up fix", to="ins.pos_err_m"),
    _p("FUS_INS_GB", float, 0.01, 0.0, 100.0, "deg/h", "INS process model: constant gyro drift per axis (a state the filter estimates)", to="ins.gyro_bias_degph"),
    _p("FUS_INS_GM", float, 0.005, 0.0, 100.0, "deg/h", "INS process model: first-order Gauss-Markov gyro drift per axis", to="ins.gyro_markov_degph"),
    _p("FUS_INS_GM_TAU", float, 3600.0, 1.0, 1e6, "s", "INS process model: correlation time of the Gauss-Markov gyro drift", to="ins.gyro_markov_tau_s"),
    _p("FUS_INS_VRW", float, 1e-4, 1e-6, 1.0, "m/s/rt(s)", "INS process model: velocity random walk (accelerometer white noise); never zero: it keeps the filter from trusting a noiseless model absolutely (a position covariance of zero)", to="ins.vrw_mps_rts"),
    _p("FUS_DR_POS_M", float, 150.0, 0.0, 1e5, "m", "dead reckoning: position error added per step (turns, speed changes)", to="dead_reckoning.pos_sigma_m", frozen=True),
    _p("FUS_CUR_MPS", float, 0.3, 0.0, 10.0, "m/s", "dead reckoning: prior 1-sigma of the current (drift) per axis", to="dead_reckoning.current_sigma_mps", frozen=True),
    _p("FUS_CUR_Q", float, 0.05, 0.0, 10.0, "m/s/rt(h)", "dead reckoning: random walk of the current", to="dead_reckoning.current_q_mps_rth", frozen=True),
    _p("FUS_GPS_M", float, 5.0, 0.1, 1e4, "m", "1-sigma of a GPS start position the filter starts from", to="nav.gps_sigma_m", frozen=True),
    _p("GRAD_INIT", int, 1, 0, 1, "", "G after the probing moves: 0 from the probes (eq. 5-9), 1 the model's gradient at the estimated position", to="nav.grad_init", frozen=True),
    # --- companion process (link, outputs, failsafes) ---
    _p("COMP_SP_RATE_HZ", float, 5.0, 2.5, 50.0, "Hz", "setpoint stream rate (PX4 offboard needs > 2 Hz)", to="companion.setpoint_rate_hz"),
    _p("COMP_ARM_ENABLE", int, 0, 0, 1, "", "1 lets the companion switch to GUIDED/OFFBOARD and arm", to="companion.arm_enable"),
    _p("COMP_POS_PUB", int, 3, 0, 3, "", "give the FC our position: 0 EXTERNAL_POSITION_ESTIMATE, 1 ODOMETRY, 2 off, 3 GPS_INPUT as its second GPS (an echo while its own GPS works)", to="companion.position_publish"),
    _p("COMP_FEED_ACC_M", float, 5.0, 0.5, 1000.0, "m", "horizontal accuracy claimed in GPS_INPUT: the feed's short-term (relative) accuracy; the EKF diverges when told the km-level absolute one", to="companion.feed_accuracy_m"),
    _p("COMP_FEED_BLEND", float, 0.5, 0.1, 20.0, "m/s", "speed at which a new estimate is blended into the fed position: no steps the EKF would reject, and slow because the FC's speed loop sees the fed speed (GUIDED velocity steering needs no position)", to="companion.feed_blend_mps"),
    _p("COMP_FEED_ACCEL", float, 0.0, 0.0, 20.0, "m/s^2", "largest acceleration of the fed track: a new command turns the fed velocity at most this fast, as the vehicle turns (speed x turn rate; PX4's rover at 3 m/s: 0.5), so the FC's IMU and the feed agree; 0 steps it (a corner the IMU never measured: EKF2 took it into tilt and gyro bias)", to="companion.feed_accel_mps2"),
    _p("COMP_MAG_HZ", float, 10.0, 1.0, 100.0, "Hz", "magnetometer stream rate asked of the FC: up to the sensor's own rate, every sample is averaged (PX4 SIH makes 50 distinct samples/s); in SITL at N x real time the companion decodes N times as many per wall second", to="companion.mag_rate_hz"),
    _p("COMP_CAL_TURNS", int, 0, 0, 3, "", "magnetometer calibration before the mission (GPS-known start): after arming, this many slow full circles at the cruise speed, then the hard and soft iron fitted (level fit) against the field model at the start, applied to MAG_*, said in STATUSTEXT, and one more circle as the start-up average with the motor running; 0 off (MAG_* as set)", to="companion.cal_turns"),
    _p("COMP_CAL_DPS", float, 1.2, 0.2, 1.5, "deg/s", "turn rate of the calibration circles (COMP_CAL_TURNS); at most 1.5 so the gravity-referenced inclination keeps its samples", to="companion.cal_rate_dps"),
    _p("COMP_TRIM_DEG", float, 0.0, 0.0, 45.0, "deg", "steer the measured true heading (levelled magnetometer + model D) onto the course: the setpoint's course is trimmed by the FC's yaw error, at most this; 0 off (the FC's yaw is trusted)", to="companion.trim_max_deg"),
    _p("COMP_MAG_TMO_S", float, 2.0, 0.1, 60.0, "s", "magnetometer older than this is stale (failsafe)", to="companion.mag_timeout_s"),
    _p("COMP_ATT_TMO_S", float, 2.0, 0.1, 60.0, "s", "attitude older than this is stale (failsafe)", to="companion.att_timeout_s"),
    _p("COMP_HB_TMO_S", float, 3.0, 0.5, 60.0, "s", "flight-controller heartbeat older than this is lost", to="companion.heartbeat_timeout_s"),
    _p("COMP_SPIKE_NT", float, 5000.0, 10.0, 1e6, "nT", "reject a magnetometer sample this far from the running median", to="companion.spike_nt"),
    _p("COMP_DIVERGE_KM", float, 50.0, 0.1, 10000.0, "km", "estimate diverged: fix and fused position further apart than this and outside their joint 99.99 % ellipse", to="companion.diverge_m", scale=_KM_TO_M),
    # --- safety ceiling and who may write (start-up only: the link cannot raise them, issue 10) ---
    _boot("SAFE_SPEED_KMH", float, 60.0, 1.0, 300.0, "km/h", "speed no setpoint may exceed, whatever NAV_SPEED_KMH says"),
    _boot("SAFE_TMO_S", float, 5.0, 0.1, 60.0, "s", "longest failsafe timeout: COMP_*_TMO_S above it act as this"),
    _boot("SAFE_FENCE_KM", float, 100.0, 0.0, 20000.0, "km", "start and destination set over the link must lie this close to the start-up route; 0 off"),
    _boot("LINK_GCS_ID1", int, 255, 0, 255, "", "ground-station system id allowed to set parameters and receive outputs; 0 none"),
    _boot("LINK_GCS_ID2", int, 0, 0, 255, "", "a second allowed ground-station system id (MAVSDK's default is 245); 0 none"),
    _p("LINK_TLOG_MB", float, 100.0, 0.0, 1e5, "MB", "companion.tlog is rotated at this size (3 older files kept); 0 no cap"),
    _p("MAG_OFS_X", float, 0.0, -3000.0, 3000.0, "mGauss", "hard-iron offset subtracted from body x (opposite sign of ArduPilot's COMPASS_OFS_X, which is added)", to="companion.mag_ofs_x"),
    _p("MAG_OFS_Y", float, 0.0, -3000.0, 3000.0, "mGauss", "hard-iron offset, body y", to="companion.mag_ofs_y"),
    _p("MAG_OFS_Z", float, 0.0, -3000.0, 3000.0, "mGauss", "hard-iron offset, body z", to="companion.mag_ofs_z"),
    _p("MAG_SCALE_X", float, 1.0, 0.2, 5.0, "", "soft iron's diagonal, applied after the offset, body x", to="companion.mag_scale_x"),
    _p("MAG_SCALE_Y", float, 1.0, 0.2, 5.0, "", "scale, body y", to="companion.mag_scale_y"),
    _p("MAG_SCALE_Z", float, 1.0, 0.2, 5.0, "", "scale, body z", to="companion.mag_scale_z"),
    _p("MAG_SOFT_XY", float, 0.0, -2.0, 2.0, "", "soft iron off the diagonal, x-y (a symmetric matrix with MAG_SCALE_* on its diagonal; fcmpc-calibrate fits it)", to="companion.mag_soft_xy"),
    _p("MAG_SOFT_XZ", float, 0.0, -2.0, 2.0, "", "soft iron off the diagonal, x-z", to="companion.mag_soft_xz"),
    _p("MAG_SOFT_YZ", float, 0.0, -2.0, 2.0, "", "soft iron off the diagonal, y-z", to="companion.mag_soft_yz"),
    _p("MAG_ROT_ROLL", float, 0.0, -15.0, 15.0, "deg", "magnetometer's alignment to the body, applied after the soft iron: roll of the rotation from the sensor's frame into the body's (ZYX Euler; fcmpc-calibrate fits it against the model's field direction at the GPS position)", to="companion.mag_rot_roll"),
    _p("MAG_ROT_PIT", float, 0.0, -15.0, 15.0, "deg", "magnetometer's alignment to the body: pitch of the rotation", to="companion.mag_rot_pit"),
    _p("MAG_ROT_YAW", float, 0.0, -15.0, 15.0, "deg", "magnetometer's alignment to the body: yaw of the rotation (fitted only with fcmpc-calibrate --align xyz: a yaw fused from this compass cannot judge it)", to="companion.mag_rot_yaw"),
)

SPEC_BY_NAME: dict[str, ParamSpec] = {spec.name: spec for spec in REGISTRY}
# the readings, with how long one lasts after its last link set (s of message time)
READINGS: dict[str, float] = {spec.name: spec.max_age_s for spec in REGISTRY if spec.max_age_s is not None}

for _spec in REGISTRY:  # a registry error is a programming error: fail at import, loudly
    if len(_spec.name) > MAX_NAME_LEN or not _spec.minimum <= _spec.default <= _spec.maximum:
        raise RuntimeError(f"bad registry entry {_spec}")
SPEC_BY_FIELD: dict[tuple[str, str], ParamSpec] = {(spec.group, spec.field): spec for spec in REGISTRY
                                                   if spec.group is not None}
if len(SPEC_BY_FIELD) != sum(spec.group is not None for spec in REGISTRY):
    raise RuntimeError("two registry entries name the same settings field")


# --- settings classes built from the registry ---------------------------------------------------

_T = TypeVar("_T")


def settings(group: str):
    """Class decorator: a frozen dataclass whose fields are the registry entries of ``group``.

    Each annotated field takes its default from its entry (``field_value(default)``, with the
    entry's unit conversion); a field may instead hold a nested settings class
    (``field(default_factory=OtherSettings)``), and ``ClassVar`` annotations are constants, not
    fields. A field without an entry, an entry without a field, or a default written in the
    class raises at import: a value has one declaration, the registry's.

    >>> from companion.nav.navfilter import BiasSpec
    >>> BiasSpec().q_deg_rth == SPEC_BY_NAME["FUS_BQ_DEG"].default
    True
    """
    def build(cls: type[_T]) -> type[_T]:
        entries = {spec.field: spec for (g, _), spec in SPEC_BY_FIELD.items() if g == group}
        annotations = {name: str(kind) for name, kind in cls.__dict__.get("__annotations__", {}).items()
                       if not str(kind).startswith(("ClassVar", "typing.ClassVar"))}
        for name in annotations:
            own = cls.__dict__.get(name, dataclasses.MISSING)
            if own is not dataclasses.MISSING:
                if not (isinstance(own, dataclasses.Field) and hasattr(own.default_factory, "settings_group")):
                    raise RuntimeError(f"{cls.__name__}.{name}: a settings class declares no default of its own "
                                       f"(the registry's entry is the default)")
                continue
            spec = entries.get(name)
            if spec is None:
                raise RuntimeError(f"{cls.__name__}.{name}: no registry entry has to=\"{group}.{name}\"")
            setattr(cls, name, dataclasses.field(default=spec.field_value(spec.kind(spec.default)),
                                                 metadata={"param": spec.name}))
        unused = sorted(set(entries) - set(annotations))
        if unused:
            raise RuntimeError(f"{cls.__name__} has no field for registry group {group!r} field(s) {unused}")
        cls.settings_group = group  # type: ignore[attr-defined]
        if "from_values" not in cls.__dict__:
            cls.from_values = classmethod(from_values)  # type: ignore[attr-defined]
        return dataclasses.dataclass(frozen=True)(cls)
    return build


def from_values(cls: type[_T], values: Mapping[str, Any]) -> _T:
    """``cls`` (a :func:`settings` class) from parameter values by registry name, each converted
    by its entry; names not given (and unknown names) leave the registry default: validate first
    (:func:`companion.params.validate_all`)."""
    kwargs = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        name = f.metadata.get("param")
        if name is None:
            kwargs[f.name] = from_values(f.default_factory, values)  # type: ignore[arg-type]
        elif name in values:
            kwargs[f.name] = SPEC_BY_NAME[name].field_value(values[name])
    return cls(**kwargs)


def hold_frozen(old: _T, new: _T) -> tuple[_T, list[str]]:
    """``new`` with every frozen-in-flight value (``frozen=True``) kept as in ``old``, nested
    settings included, and the registry names of the frozen values that differed (they apply to
    the next mission)."""
    kept: dict[str, Any] = {}
    deferred: list[str] = []
    for f in dataclasses.fields(old):  # type: ignore[arg-type]
        before, after = getattr(old, f.name), getattr(new, f.name)
        name = f.metadata.get("param")
        if name is None:
            kept[f.name], inner = hold_frozen(before, after)
            deferred += inner
        elif SPEC_BY_NAME[name].frozen:
            kept[f.name] = before
            if after != before:
                deferred.append(name)
    return dataclasses.replace(new, **kept), deferred  # type: ignore[type-var]
