"""The heading the open-loop Fc-MPC would have commanded, against the course over ground flown.

Each window goes through the companion's own navigation step (:class:`companion.nav.navigator.Navigator`), its
plausibility judge included: a window it excludes is counted and the last command stands.
"""
from __future__ import annotations

import math

import numpy as np

from companion import wrap_2pi
from companion.nav.field import WorldMagneticModel, decl_incl_gradient
from companion.nav.elements import ElementSet
from companion.nav.geo import geodesic_distance_m, geodesic_inverse
from companion.nav.mission import Mission, Phase
from companion.nav.navigator import Navigator, Period
from companion.nav.period import PeriodAverage
from companion.params import Controller, NavConfig, default_values
from fcmpc.replay.records import HeadingRow, WindowRecord
from fcmpc.replay.stats import interp_gps, percentile, wrap180

__all__ = ["model_di_gradient", "course_deg", "run_mission", "MOVING_COURSE_MPS"]

MOVING_COURSE_MPS = 1.0      # a window's course over ground is defined above this mean speed


def model_di_gradient(model: WorldMagneticModel, lat: float, lon: float, alt: float,
                       year: float) -> tuple[float, float, np.ndarray]:
    el = model.elements(lat, lon, alt, year)
    return float(el.decl_deg), float(el.incl_deg), decl_incl_gradient(model, lat, lon, alt, year)


def course_deg(gps: np.ndarray, gps_e: np.ndarray, gps_n: np.ndarray, a: float, b: float) -> float:
    """GPS course over ground (deg from north) over [a, b]; NaN when slower than MOVING_COURSE_MPS."""
    de = float(np.interp(b, gps[:, 0], gps_e) - np.interp(a, gps[:, 0], gps_e))
    dn = float(np.interp(b, gps[:, 0], gps_n) - np.interp(a, gps[:, 0], gps_n))
    if math.hypot(de, dn) < MOVING_COURSE_MPS * (b - a):
        return math.nan
    return math.degrees(wrap_2pi(math.atan2(de, dn)))


def run_mission(recs: list[WindowRecord], w: float, model: WorldMagneticModel, year: float,
                 ref: tuple[float, float], dest: tuple[float, float], alt: float, cruise_mps: float,
                 gps: np.ndarray, gps_e: np.ndarray, gps_n: np.ndarray, ins_latlon) -> HeadingRow:
    config = NavConfig.from_values(default_values()).replace(
        start_lat_deg=ref[0], start_lon_deg=ref[1], dest_lat_deg=dest[0], dest_lon_deg=dest[1],
        alt_m=alt, year=year, speed_mps=cruise_mps, period_s=w, controller=Controller.FC,
        # a probe moves speed * T, of which the gradient sees half after the window-centre correction
        grad_min_move_m=min(1.0, 0.25 * cruise_mps * w), arrive_m=5.0, max_steps=100_000,
        s_min_d=-180.0, s_max_d=180.0, s_min_i=-90.0, s_max_i=90.0,
        elements=ElementSet.PAPER)   # the windows measure the paper's pair, D and I
    mission = Mission(config, model)
    # the start is the first GPS fix: a known start, where the companion's filter calibrates its biases
    mission.set_start_fix(config.gps_sigma_m)
    navigator = Navigator(mission)   # the companion's step: the plausibility judge included
    diffs, ideal_diffs, est_errors, excluded = [], [], [], 0
    last_phase, reason = "", ""
    for k, r in enumerate(recs):
        ins_lat, ins_lon = ins_latlon(r.end_s)
        average = PeriodAverage(r.decl_deg, r.incl_deg, r.count, r.centre_s, r.start_s, r.end_s,
                                decl_se_deg=r.decl_se_deg, incl_se_deg=r.incl_se_deg)
        result = navigator.step(Period(r.end_s, average, w, ins_lat, ins_lon))
        excluded += result.excluded
        cmd = navigator.command
        last_phase, reason = cmd.phase, cmd.reason
        if cmd.phase == Phase.CRUISE:
            la, lo, _ = interp_gps(gps, r.end_s)
            est_errors.append(geodesic_distance_m(cmd.est_lat_deg, cmd.est_lon_deg, float(la), float(lo)))
        if k + 1 >= len(recs):
            break
        nxt = recs[k + 1]
        nxt.command_phase = cmd.phase
        nxt.command_course_deg = math.degrees(cmd.course_rad)
        nxt.flown_course_deg = course_deg(gps, gps_e, gps_n, nxt.start_s, nxt.end_s)
        la, lo, _ = interp_gps(gps, nxt.start_s)
        nxt.ideal_course_deg = math.degrees(geodesic_inverse(float(la), float(lo), *dest)[1])
        if cmd.done:
            break
        if cmd.phase == Phase.CRUISE and math.isfinite(nxt.flown_course_deg):
            diffs.append(abs(float(wrap180(nxt.command_course_deg - nxt.flown_course_deg))))
            ideal_diffs.append(abs(float(wrap180(nxt.ideal_course_deg - nxt.flown_course_deg))))
        if nxt.command_phase == Phase.CRUISE:
            nxt.mission_est_error_m = est_errors[-1] if est_errors else math.nan
    return HeadingRow(w, mission.k, len(diffs), percentile(diffs, 50), percentile(ideal_diffs, 50),
                      last_phase, reason, percentile(est_errors, 50), excluded)
