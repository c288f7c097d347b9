"""Table 3's uncertainty (companion.nav.table3): the fix's own covariance through the gradient,
the field model's error growing away from the calibration point, and dead-reckoning growth
between fixes. Before, the 1-sigma was sqrt(FUS_RC_KM2) = 1.4 km whatever happened (ArduPilot
SITL: the estimate up to 95 km off while it said 1.4 km)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.nav.elements import ELEMENT_SETS, ElementSet
from companion.nav.field import element_fix, model_for_date
from companion.nav.geo import geodesic_distance_m, offset_position
from companion.nav.process import DeadReckoningSpec
from companion.nav.fix import fix_covariance
from companion.nav.table3 import ModelError, Table3Estimator
from tests.nav.test_mission import nav_config

HEADING_FREE = ELEMENT_SETS[ElementSet.HEADING_FREE]


@pytest.fixture(scope="module")
def model():
    return model_for_date(2024.36)


def test_the_fix_covariance_is_the_scatter_of_fixes_through_the_gradient():
    """Element errors drawn with the stated variances, mapped through G^-1: their sample
    covariance is the formula's, within sampling error (200,000 draws: ~0.5 %)."""
    gradient = np.array([[2.0e-6, 9.0e-6], [-3.0e-3, 4.0e-3]])     # deg/m and nT/m: a skewed pair
    variance = np.array([0.05 ** 2, 80.0 ** 2])
    rng = np.random.default_rng(3)
    errors = rng.normal(size=(200_000, 2)) * np.sqrt(variance)
    offsets = np.linalg.solve(gradient, errors.T).T                  # each error's position offset
    np.testing.assert_allclose(fix_covariance(gradient, variance), np.cov(offsets.T), rtol=0.02)


def test_the_model_error_is_zero_at_the_calibration_and_twice_its_variance_far_from_it():
    error = ModelError(sigma_deg=0.1, sigma_nt=100.0, length_m=25e3)
    names = HEADING_FREE.names                                       # (I, F)
    np.testing.assert_allclose(error.variance(names, 0.0), [0.0, 0.0])
    np.testing.assert_allclose(error.variance(names, 25e3), 2.0 * np.array([0.01, 1e4]) * (1.0 - math.exp(-1.0)))
    np.testing.assert_allclose(error.variance(names, 1e9), [0.02, 2e4])   # both ends' errors, independent
    np.testing.assert_allclose(error.variance(names, None), [0.01, 1e4])  # no calibration: the point's error


def test_a_taken_fix_reports_its_own_covariance_and_a_dropped_one_grows_it(model):
    """A fix 8 km from the dead-reckoned position is taken: the covariance is the fix's, from
    the measured standard errors (plus the floor) and the model error at its distance from the
    start. The next steps' fixes are 200 km off (beyond NAV_FIX_GATE_M): dropped, and the
    covariance grows by the dead reckoning since the fix, nothing else."""
    config = nav_config(NAV_ELEMENTS=2, FUS_MODEL=1)
    table3 = Table3Estimator(config, model, HEADING_FREE)
    table3.calibrated = True
    dead_reckoned = offset_position(config.start_lat_deg, config.start_lon_deg, 30e3, -20e3)
    truth = tuple(float(v) for v in offset_position(*dead_reckoned, 8e3, 0.0))
    here = HEADING_FREE.values(model.elements(*truth, config.alt_m, config.year))
    se = np.array([0.01, 20.0])
    position, fix, fused, sigma = table3.estimate(dead_reckoned, here, np.zeros(2), math.nan, math.nan, 3600.0, se)
    assert geodesic_distance_m(*position, *truth) < 1.0 and not fused and fix == position
    found = element_fix(model, HEADING_FREE, here, *truth, config.alt_m, config.year)
    variance = se ** 2 + np.array([config.filter.r_min_deg, config.filter.r_min_nt]) ** 2 \
        + table3.model_error.variance(HEADING_FREE.names,
                                      geodesic_distance_m(config.start_lat_deg, config.start_lon_deg, *truth))
    expected = fix_covariance(found.gradient, variance)
    np.testing.assert_allclose(table3.cov_en_m2, expected, rtol=1e-3)
    assert sigma == pytest.approx(math.sqrt(0.5 * np.trace(expected)), rel=1e-3)
    assert sigma > 5e3   # (I, F) on a Pacific route: kilometres to tens of, not 1.4 km
    # against the next fix (a few km on, the same model error): the fix's noise alone
    noise_only = fix_covariance(found.gradient, se ** 2 + np.array([config.filter.r_min_deg, config.filter.r_min_nt]) ** 2)
    np.testing.assert_allclose(table3.relative_cov_en_m2, noise_only, rtol=1e-3)
    assert table3.relative_sigma_m < 0.5 * sigma

    flown = 10e3
    moved = tuple(float(v) for v in offset_position(*position, 0.0, flown))
    far = HEADING_FREE.values(model.elements(*offset_position(*moved, 0.0, 200e3), config.alt_m, config.year))
    before = table3.cov_en_m2.copy()
    position2, fix2, _, sigma2 = table3.estimate(moved, far, np.zeros(2), math.nan, math.nan, 3600.0 + 360.0, se)
    assert position2 == moved and all(math.isnan(v) for v in fix2) and table3.rejected == 1
    grown = config.filter.dead_reckoning.pos_sigma_m ** 2 + (DeadReckoningSpec.speed_frac * flown) ** 2 \
        + (config.filter.dead_reckoning.current_sigma_mps * 360.0) ** 2
    np.testing.assert_allclose(table3.cov_en_m2, before + np.eye(2) * grown, rtol=1e-6)
    np.testing.assert_allclose(table3.relative_cov_en_m2, noise_only + np.eye(2) * grown, rtol=1e-3)
    assert sigma2 > sigma
    # a second dropped step: the dead reckoning's errors are constant (a current, a speed scale),
    # so they grow with the time and distance since the fix, not as a random walk
    moved2 = tuple(float(v) for v in offset_position(*moved, 0.0, flown))
    table3.estimate(moved2, far, np.zeros(2), math.nan, math.nan, 3600.0 + 720.0, se)
    grown2 = 2 * config.filter.dead_reckoning.pos_sigma_m ** 2 + (DeadReckoningSpec.speed_frac * 2 * flown) ** 2 \
        + (config.filter.dead_reckoning.current_sigma_mps * 720.0) ** 2
    np.testing.assert_allclose(table3.cov_en_m2, before + np.eye(2) * grown2, rtol=1e-6)


def test_a_changed_gate_reaches_table3_in_flight(model):
    """NAV_FIX_GATE_M applies at once (not frozen in flight): Table 3's path judges with it."""
    from companion.nav.mission import Mission

    config = nav_config(FUS_MODEL=1)
    mission = Mission(config, model)
    assert mission.reconfigure(config.replace(fix_gate_m=20e3)) == []
    assert mission.table3.config.fix_gate_m == 20e3


def test_a_setting_outside_the_qp_keeps_the_qp_and_a_new_weight_rebuilds_it(model):
    """A setting the QP does not hold (the fusion's storm threshold) is taken at once but keeps the
    QP (and OSQP's warm start); a changed weight or horizon rebuilds the QP (a changed speed does
    not: the QP's input is a fraction of the cruise speed)."""
    from companion.nav.mission import Mission

    config = nav_config()
    mission = Mission(config, model)
    qp = mission.mpc
    assert mission.reconfigure(config.replace(kp_on=7.0)) == []
    assert mission.config.kp_on == 7.0
    assert mission.mpc is qp
    mission.reconfigure(mission.config.replace(r_x=2.0 * config.r_x))
    assert mission.mpc is not qp and mission.mpc.settings.r[0] == 2.0 * config.r_x
    rebuilt = mission.mpc
    mission.reconfigure(mission.config.replace(speed_mps=0.5 * config.speed_mps))
    assert mission.mpc is rebuilt and mission.config.speed_mps == 0.5 * config.speed_mps
    mission.reconfigure(mission.config.replace(horizon=config.horizon + 2))
    assert mission.mpc is not rebuilt and mission.mpc.settings.horizon == config.horizon + 2
