"""The linearised geomagnetic fix (``element_fix(..., linear_within_m=...)``): one Gauss-Newton step
from the prior, taken as the fix when it is short, and how far it lies from the converged fix."""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.nav.elements import ELEMENT_SETS, ElementSet
from companion.nav.field import element_fix, element_values_and_gradient, load_wmm
from companion.nav.fix import LINEAR_MAX_CONDITION
from companion.nav.geo import geodesic_direct, geodesic_distance_m, offset_position
from companion.nav.small import solve2

YEAR = 2024.36
# The linearised fix's error is the field's curvature over the step: at most this times the
# step's square (per metre) where cond(G) < LINEAR_MAX_CONDITION. Measured over 2,500 such random
# points of the globe (WMM2020, (D, I), |lat| <= 75 deg, steps 0.1-2 km): at most 7e-6 per metre;
# twice that is the tolerance.
CURVATURE_BOUND_PER_M = 1.4e-5


@pytest.fixture(scope="module")
def model():
    return load_wmm("WMM2020")


def _random_case(model, rng, max_condition: float = LINEAR_MAX_CONDITION):
    """A point anywhere but near the poles, its true (D, I), and a prior 0.1-1 km away where G's
    condition is below ``max_condition``."""
    elements = ELEMENT_SETS[ElementSet.PAPER]
    while True:
        lat, lon = rng.uniform(-75.0, 75.0), rng.uniform(-180.0, 180.0)
        values = element_values_and_gradient(model, elements, lat, lon, 0.0, YEAR)[0]
        prior = geodesic_direct(lat, lon, rng.uniform(0.0, 2.0 * math.pi), rng.uniform(100.0, 1000.0))
        if np.linalg.cond(element_values_and_gradient(model, elements, *prior, 0.0, YEAR)[1]) < max_condition:
            return elements, values, (float(prior[0]), float(prior[1]))


def test_a_short_first_step_is_the_fix_and_lies_within_the_curvature_bound_of_the_converged_one(model):
    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(200):
        elements, truth, prior = _random_case(model, rng)
        at_prior = element_values_and_gradient(model, elements, *prior, 0.0, YEAR)
        linear = element_fix(model, elements, truth, *prior, 0.0, YEAR, report_at_fix=False, at_prior=at_prior,
                             linear_within_m=2000.0)
        # by hand: the step G^-1 (S_true - S(prior)) from the prior, on the same local plane
        step = solve2(at_prior[1], -elements.difference(at_prior[0], truth))
        by_hand = offset_position(*prior, float(step[0]), float(step[1]))
        assert (linear.lat_deg, linear.lon_deg) == (float(by_hand[0]), float(by_hand[1]))
        assert linear.iterations == 1 and np.array_equal(linear.gradient, at_prior[1])
        converged = element_fix(model, elements, truth, *prior, 0.0, YEAR)
        apart_m = geodesic_distance_m(linear.lat_deg, linear.lon_deg, converged.lat_deg, converged.lon_deg)
        step_m = math.hypot(*step)
        assert apart_m <= CURVATURE_BOUND_PER_M * step_m ** 2 + 1e-6, (prior, step_m, apart_m)
        worst = max(worst, apart_m / step_m ** 2)
    assert worst > 0.0      # the linearisation does leave an error: the bound is not vacuous


@pytest.mark.parametrize("case", ["a step longer than the linear range", "an ill-conditioned G"])
def test_the_fix_is_iterated_as_without_the_linear_range_for(model, case):
    rng = np.random.default_rng(6)
    for _ in range(20):
        if case == "an ill-conditioned G":
            while True:
                elements, truth, prior = _random_case(model, rng, max_condition=1e4)
                at_prior = element_values_and_gradient(model, elements, *prior, 0.0, YEAR)
                if np.linalg.cond(at_prior[1]) >= LINEAR_MAX_CONDITION:
                    break
            linear_within_m = 1e6
        else:
            elements, truth, prior = _random_case(model, rng)
            linear_within_m = 50.0
        plain = element_fix(model, elements, truth, *prior, 0.0, YEAR, report_at_fix=False)
        given = element_fix(model, elements, truth, *prior, 0.0, YEAR, report_at_fix=False,
                            linear_within_m=linear_within_m)
        assert (given.lat_deg, given.lon_deg, given.iterations) == (plain.lat_deg, plain.lon_deg, plain.iterations)
        assert plain.iterations >= 2


@pytest.mark.parametrize("bad", [-1.0, math.inf, math.nan])
def test_a_linear_range_that_is_not_a_finite_distance_is_refused(model, bad):
    elements = ELEMENT_SETS[ElementSet.PAPER]
    with pytest.raises(ValueError, match="linear_within_m"):
        element_fix(model, elements, (-5.0, 50.0), 33.0, 152.0, 0.0, YEAR, linear_within_m=bad)


def test_the_estimators_step_tolerance_lands_where_one_metre_does_with_fewer_evaluations(model):
    """``FIX_TOL_M`` (10 m) against ``tol_m`` 1 m from priors 2-20 km off (iterated, beyond the
    linear range): the position after the last Newton step is the same to 3 cm (the step's square
    times the curvature), and a fix often needs one iteration, one model evaluation, fewer."""
    from companion.nav.estimator import FIX_LINEAR_WITHIN_M, FIX_TOL_M

    rng = np.random.default_rng(8)
    elements, fewer = ELEMENT_SETS[ElementSet.PAPER], 0
    for _ in range(100):
        lat, lon = rng.uniform(-75.0, 75.0), rng.uniform(-180.0, 180.0)
        truth = element_values_and_gradient(model, elements, lat, lon, 0.0, YEAR)[0]
        prior = geodesic_direct(lat, lon, rng.uniform(0.0, 2.0 * math.pi), rng.uniform(2e3, 20e3))
        if np.linalg.cond(element_values_and_gradient(model, elements, *prior, 0.0, YEAR)[1]) > 1e3:
            continue
        kwargs = dict(report_at_fix=False, linear_within_m=FIX_LINEAR_WITHIN_M)
        metre = element_fix(model, elements, truth, *prior, 0.0, YEAR, tol_m=1.0, **kwargs)
        ours = element_fix(model, elements, truth, *prior, 0.0, YEAR, tol_m=FIX_TOL_M, **kwargs)
        assert geodesic_distance_m(ours.lat_deg, ours.lon_deg, metre.lat_deg, metre.lon_deg) <= 0.03
        assert ours.iterations <= metre.iterations
        fewer += ours.iterations < metre.iterations
    assert fewer >= 20, fewer
