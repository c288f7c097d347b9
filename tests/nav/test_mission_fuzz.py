"""Property-based fuzz of the navigation core (hypothesis): whatever finite measurements arrive, in
whatever order of magnitude, ``Mission.step`` never raises and never commands a NaN course or a
speed above the configured cruise; an error inside the core ends the mission FAILED, with its
reason, for the caller's failsafe.

Oracle: the contract of :meth:`companion.nav.mission.Mission.step` and the configured speed.
Measurements: D in [-180, 180] deg, I in [-90, 90], F up to 1e5 nT, an INS position anywhere on
the Earth or none, windows up to 1e4 s, steps of 0.1 s to 5000 s, Kp, SYM-H and the magnetic
heading present or not; six configurations (the INS filter, Table 3, dead reckoning, LTV-MPC,
(D, I, F), (I, F)); with and without a GPS-known start.
"""
from __future__ import annotations

import math
import warnings

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.nav.mission import CORE_ERROR, Mission
from companion.nav.step_io import Measurement
from companion.params import NavConfig, validate_all

CONFIGS = ({}, {"FUS_MODEL": 1}, {"FUS_MODEL": 3}, {"NAV_CONTROLLER": 1}, {"NAV_ELEMENTS": 4}, {"NAV_ELEMENTS": 2})


def _finite(low: float, high: float):
    return st.floats(low, high, allow_nan=False, allow_infinity=False)


def _or_none(values):
    return st.one_of(st.just(math.nan), values)


STEP = st.tuples(_finite(0.1, 5000.0), _finite(-180.0, 180.0), _finite(-90.0, 90.0), _or_none(_finite(-90.0, 90.0)),
                 _or_none(_finite(-180.0, 180.0)), _finite(0.0, 1e4), _finite(0.0, 1e5), _or_none(_finite(0.0, 9.0)),
                 _or_none(_finite(-2000.0, 500.0)), _or_none(_finite(0.0, 360.0)))
FAST = settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
SLOW = settings(max_examples=2000, deadline=None, suppress_health_check=list(HealthCheck))


def _fly(config_index: int, steps: list, gps_start: bool) -> None:
    mission = Mission(NavConfig.from_values(validate_all(CONFIGS[config_index])))
    if gps_start:
        mission.set_start_fix(2.5)
    t = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # overflow on the way to a failed mission is fine
        for dt, decl, incl, ins_lat, ins_lon, window, f_nt, kp, symh, heading in steps:
            t += dt
            cmd = mission.step(Measurement(t, decl, incl, ins_lat, ins_lon, window, f_nt, kp=kp, symh_nt=symh,
                                           mag_heading_deg=heading))
            assert cmd.done or (math.isfinite(cmd.course_rad) and math.isfinite(cmd.speed_mps)), cmd
            assert 0.0 <= cmd.speed_mps <= mission.config.speed_mps * (1.0 + 1e-12), cmd
            if not cmd.solver_ok:
                assert cmd.done and cmd.reason, cmd
            if cmd.reason.startswith(CORE_ERROR):
                assert cmd.done and cmd.speed_mps == 0.0


@FAST
@given(st.sampled_from(range(len(CONFIGS))), st.lists(STEP, min_size=1, max_size=12), st.booleans())
def test_no_measurement_makes_the_core_raise_or_command_nan(config_index, steps, gps_start):
    _fly(config_index, steps, gps_start)


@pytest.mark.slow
@SLOW
@given(st.sampled_from(range(len(CONFIGS))), st.lists(STEP, min_size=1, max_size=40), st.booleans())
def test_no_long_measurement_sequence_makes_the_core_raise_or_command_nan(config_index, steps, gps_start):
    _fly(config_index, steps, gps_start)
