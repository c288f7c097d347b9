"""The ring current predicted from SYM-H and taken out of the measurements (companion.nav.ring_current)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.nav.elements import ELEMENT_SETS, ElementSet
from companion.nav.estimator import PositionEstimator
from companion.nav.field import model_for_date
from companion.nav.ring_current import ring_current_change_nt, ring_current_elements, symh_value
from companion.nav.step_io import Measurement
from companion.params import NavConfig, validate_all

NAMES = ("decl_deg", "incl_deg", "f_nt", "h_nt", "z_nt")
MODEL = model_for_date(2024.36)
START = (33.0, 152.0)


def _elements(north: float, east: float, down: float) -> np.ndarray:
    h = math.hypot(north, east)
    return np.array([math.degrees(math.atan2(east, north)), math.degrees(math.atan2(down, h)),
                     math.sqrt(h * h + down * down), h, down])


@settings(max_examples=60, deadline=None)
@given(lat=st.floats(-60.0, 60.0), lon=st.floats(-180.0, 180.0), delta_h=st.floats(-400.0, 400.0))
def test_a_change_of_h_along_itself_moves_the_elements_as_the_field_does(lat, lon, delta_h):
    """To first order, exactly the elements of the field whose H grew by ``delta_h`` along itself:
    D not at all, and the rest within the second-order term (F's second derivative along H is
    ``Z^2 / F^3 <= 1 / F``, I's ``2 H Z / F^4`` rad: both within ``delta_h^2 / H``)."""
    n, e, z = (float(v) for v in MODEL.ned(lat, lon, 0.0, 2024.36))
    h = math.hypot(n, e)
    moved = _elements(n + delta_h * n / h, e + delta_h * e / h, z) - _elements(n, e, z)
    predicted = ring_current_elements(NAMES, n, e, z, delta_h)
    assert predicted[0] == pytest.approx(0.0, abs=1e-12)
    assert np.all(np.abs(predicted - moved) <= delta_h * delta_h / h + 1e-9)


def test_symh_readings_and_the_change_since_the_reference():
    """The feed's 'unknown' (99999, OMNI's fill value) and NaN are no value; a change is the ratio
    times the difference."""
    assert math.isnan(symh_value(99999.0)) and math.isnan(symh_value(math.nan)) and symh_value(-412.0) == -412.0
    assert ring_current_change_nt(0.9, -250.0, -50.0) == pytest.approx(-180.0)


def _estimator(**params) -> PositionEstimator:
    config = NavConfig.from_values(validate_all(params))
    return PositionEstimator(config, MODEL, ELEMENT_SETS[ElementSet.PAPER])


def _meas(symh_nt: float, time_s: float = 0.0) -> Measurement:
    e = MODEL.elements(*START, 0.0, 2024.36)
    return Measurement(time_s, e.decl_deg, e.incl_deg, *START, 360.0, e.f_nt, symh_nt=symh_nt)


def _started(estimator: PositionEstimator, symh_nt: float) -> PositionEstimator:
    meas = _meas(symh_nt)
    estimator.start(meas, np.array([meas.decl_deg, meas.incl_deg]), 2.5)
    return estimator


def test_the_estimator_removes_the_change_since_the_start_and_holds_a_silent_feed():
    est = _started(_estimator(), -50.0)
    assert est.ring_current_removed and est.symh_reference_nt == -50.0
    n, e, z = (float(v) for v in MODEL.ned_and_slopes(*START, 0.0, 2024.36)[0])   # the model's field there
    expected = ring_current_elements(("decl_deg", "incl_deg"), n, e, z, -200.0)
    np.testing.assert_allclose(est.ring_current_share(_meas(-250.0, 360.0), START), expected)
    for silent in (math.nan, 99999.0):   # the last value holds: the ring current does not vanish with the feed
        np.testing.assert_allclose(est.ring_current_share(_meas(silent, 720.0), START), expected)
    assert expected[1] > 0.02   # a 200 nT drop of H raises I by tenths of a degree here: worth removing


@pytest.mark.parametrize("params, symh_at_start", [({"FUS_SYMH_K": 0.0}, -50.0), ({}, math.nan), ({}, 99999.0)])
def test_no_correction_without_a_ratio_or_a_reading_at_the_start(params, symh_at_start):
    est = _started(_estimator(**params), symh_at_start)
    assert not est.ring_current_removed
    np.testing.assert_array_equal(est.ring_current_share(_meas(-400.0, 360.0), START), [0.0, 0.0])


def test_the_start_up_walk_of_the_north_is_the_residuals():
    """With the correction the storm's north walks as FUS_SYMH_N/TN (a filter state when
    Gauss-Markov), without it as FUS_BQA_N/TN."""
    on = _started(_estimator(FUS_SYMH_N=61.0, FUS_SYMH_TN=1.3), -50.0)
    off = _started(_estimator(FUS_SYMH_K=0.0, FUS_SYMH_N=61.0, FUS_SYMH_TN=1.3), -50.0)
    assert "N 61 (tau 1.3 h)" in on.storm_walk and "SYM-H" in on.storm_walk
    assert f"N {validate_all({})['FUS_BQA_N']:g}," in off.storm_walk and "SYM-H" not in off.storm_walk
    assert on.filter.ns == off.filter.ns + 1
