"""The navigation core never raises on a measurement (issue 47, item 1).

Property (hypothesis): whatever periods arrive, finite, NaN, infinite, huge, tiny or of the wrong
sign, in D, I, F, their standard errors, the INS position, the window, the step's length, Kp,
SYM-H and the magnetic heading, ``Mission.step`` raises nothing; every command is finite, its speed
within [0, NAV_SPEED], its estimate on the Earth; the mission fails only for a mission's reasons
(no gradient from the probes, the step limit, a QP its finite data leave unsolvable), never for a
measurement; a rejected measurement is
answered HOLD with the last command flown on, and counted. Six configurations (the INS filter,
Table 3, dead reckoning, LTV-MPC, (D, I, F), (I, F)); with and without a GPS-known start.

Examples: hypothesis's default (100) in CI; ``--hypothesis-profile=long`` for 100,000
(tests/conftest.py). The regression below is the replayed car log's failure, found first.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.nav.elements import ElementSet
from companion.nav.geo import geodesic_distance_m, offset_position
from companion.nav.mission import REJECTED, Mission, Phase
from companion.nav.step_io import Measurement
from companion.params import Controller, NavConfig, default_values, validate_all

CONFIGS = ({}, {"FUS_MODEL": 1}, {"FUS_MODEL": 3}, {"NAV_CONTROLLER": 1}, {"NAV_ELEMENTS": 4}, {"NAV_ELEMENTS": 2})
# the only ways a mission may fail here: no gradient from the probes, the step limit, a QP that
# finite data leave unsolvable (bounds that do not hold S: the failsafe's, as before)
MISSION_REASONS = ("no gradient", "step limit", "QP failed")


def _finite(low: float, high: float):
    return st.floats(low, high, allow_nan=False, allow_infinity=False)


def _any(values):
    """Mostly ``values``; else anything a float can be (NaN, +-inf, +-1e308, 5e-324, -0.0 ...)."""
    return st.one_of(values, values, values, st.floats())


def _or_none(values):
    return st.one_of(st.just(math.nan), values)


# (dt, D, I, F, D se, I se, F se, INS lat, INS lon, window, Kp, SYM-H, magnetic heading)
PERIOD = st.tuples(_any(_finite(0.1, 5000.0)), _any(_finite(-180.0, 180.0)), _any(_finite(-90.0, 90.0)),
                   _any(_finite(2e4, 7e4)), _or_none(_any(_finite(0.0, 1.0))), _or_none(_any(_finite(0.0, 1.0))),
                   _or_none(_any(_finite(0.0, 100.0))), _or_none(_any(_finite(-90.0, 90.0))),
                   _or_none(_any(_finite(-180.0, 180.0))), _any(_finite(0.0, 1e4)), _or_none(_any(_finite(0.0, 9.0))),
                   _or_none(_any(_finite(-2000.0, 500.0))), _or_none(_any(_finite(0.0, 360.0))))


def assert_sound(mission: Mission, cmd, rejected_before: int) -> None:
    """The contract of :meth:`Mission.step` for one answer."""
    speed = mission.config.speed_mps
    assert math.isfinite(cmd.course_rad) and math.isfinite(cmd.speed_mps), cmd
    assert 0.0 <= cmd.speed_mps <= speed * (1.0 + 1e-9), cmd
    assert abs(cmd.est_lat_deg) <= 90.0 and math.isfinite(cmd.est_lon_deg), cmd
    if cmd.phase == Phase.FAILED:
        assert cmd.reason.startswith(MISSION_REASONS), cmd
    assert cmd.solver_ok or cmd.reason.startswith("QP failed"), cmd
    rejected = mission.rejected_measurements - rejected_before
    if cmd.phase == Phase.HOLD:
        assert rejected == 1 and cmd.reason.startswith(REJECTED) and not cmd.done, cmd
    else:
        assert rejected == 0, cmd


def _fly(config_index: int, periods: list, gps_start: bool) -> None:
    mission = Mission(NavConfig.from_values(validate_all(CONFIGS[config_index])))
    if gps_start:
        mission.set_start_fix(2.5)
    t, last = 0.0, None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # overflow on the way to a rejected measurement is fine
        for dt, decl, incl, f_nt, d_se, i_se, f_se, ins_lat, ins_lon, window, kp, symh, heading in periods:
            t = t + dt
            before = mission.rejected_measurements
            cmd = mission.step(Measurement(t, decl, incl, ins_lat, ins_lon, window, f_nt, decl_se_deg=d_se,
                                           incl_se_deg=i_se, f_se_nt=f_se, kp=kp, symh_nt=symh,
                                           mag_heading_deg=heading))
            assert_sound(mission, cmd, before)
            if cmd.phase == Phase.HOLD and last is not None and not last.done:   # the last command flies on
                assert (cmd.course_rad, cmd.speed_mps) == (last.course_rad, last.speed_mps), (cmd, last)
            if cmd.done:
                break
            last = cmd


@settings(deadline=None, suppress_health_check=list(HealthCheck))
@given(st.sampled_from(range(len(CONFIGS))), st.lists(PERIOD, min_size=1, max_size=12), st.booleans())
def test_no_period_makes_the_core_raise_fail_or_command_out_of_limits(config_index, periods, gps_start):
    _fly(config_index, periods, gps_start)


def test_an_uncalibrated_compass_in_a_car_is_rejected_not_a_failed_mission():
    """The replayed car log's failure (``failed (navigation core error: ValueError: latitude 115.94
    deg outside [-90, 90])``), rebuilt: the replay's mission (Fc-MPC on (D, I), 1 s periods, the
    INS filter from a drifting INS, no GPS-known start) with a magnetometer uncalibrated inside a
    car: D off by 90 deg times the cosine of the heading, I by 30 deg times its sine, 5 deg of noise.
    Where no fix converges, the filter's linearised update of such a period threw the estimate
    1,160 km in one step and then beyond the pole (main, 2026-12-06: FAILED at step 28, latitude
    108.77). Now each such update is beyond the gate (an implausible NIS moving the estimate farther
    than NAV_FIX_GATE_M) and rejected, counted; no step moves the estimate farther than the gate."""
    ref, dest, w, cruise = (50.0, 8.0), (50.8, 8.9), 1.0, 17.0
    config = NavConfig.from_values(default_values()).replace(
        start_lat_deg=ref[0], start_lon_deg=ref[1], dest_lat_deg=dest[0], dest_lon_deg=dest[1], alt_m=100.0,
        year=2025.5, speed_mps=cruise, period_s=w, controller=Controller.FC, grad_min_move_m=1.0, arrive_m=5.0,
        max_steps=100_000, s_min_d=-180.0, s_max_d=180.0, s_min_i=-90.0, s_max_i=90.0, elements=ElementSet.PAPER)
    mission = Mission(config)
    rng = np.random.default_rng(0)
    (lat, lon), course, last = ref, 0.3, None
    for k in range(60):
        course += rng.normal(0.0, 0.05)
        lat, lon = (float(v) for v in offset_position(lat, lon, cruise * w * math.sin(course),
                                                      cruise * w * math.cos(course)))
        e = mission.model.elements(lat, lon, config.alt_m, config.year)
        decl = float(e.decl_deg) + 90.0 * math.cos(course) + rng.normal(0.0, 5.0)
        incl = float(e.incl_deg) + 30.0 * math.sin(course) + rng.normal(0.0, 5.0)
        before = mission.rejected_measurements
        cmd = mission.step(Measurement(k * w, decl, incl, lat + 1e-5 * k, lon, window_s=w))
        assert_sound(mission, cmd, before)
        assert cmd.phase in (Phase.PROBE_1, Phase.PROBE_2, Phase.CRUISE, Phase.HOLD), cmd
        if last is not None:
            jump = geodesic_distance_m(last.est_lat_deg, last.est_lon_deg, cmd.est_lat_deg, cmd.est_lon_deg)
            assert jump <= config.fix_gate_m, (k, jump)
        last = cmd
    assert mission.rejected_fixes >= 10   # the gate's rejections, counted


def test_a_singular_gradient_and_no_move_from_the_qp_fly_on_along_the_last_move():
    """Found by the long profile (seed 2, after 16 min): LTV-MPC, constant (0, 0) periods, the
    third one rejected (F 0 nT); at the first cruise step G is singular, so no distance to the
    destination, and the QP's optimum is no move: the heading fell back to a direction never
    computed (UnboundLocalError, a programmer's error the core rightly let through). It flies on
    along the last move."""
    mission = Mission(NavConfig.from_values(validate_all({"NAV_CONTROLLER": 1})))
    t, last = 0.0, None
    for dt, f_nt, heading in ((1.0, 2e4, math.nan), (570.0, 2e4, math.nan), (1.0, 0.0, math.nan),
                              (14.0, 2e4, math.nan), (27.0, 2e4, 49.0)):
        t += dt
        before = mission.rejected_measurements
        cmd = mission.step(Measurement(t, 0.0, 0.0, window_s=0.0, f_nt=f_nt, mag_heading_deg=heading))
        assert_sound(mission, cmd, before)
        last = cmd
    assert last.phase == Phase.CRUISE and last.speed_mps > 0.0, last
