"""The local model-error states (companion.nav.local_error): order 1 is the filter's former
Gauss-Markov in distance, order 2 a smooth (critically damped) one that keeps its variance."""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.nav.local_error import LocalError

SIGMA = np.array([0.05, 0.04, 50.0])   # D, I (deg), F (nT)
LENGTH_M = 25_000.0


def _rms_change(local: LocalError, distance_m: float) -> np.ndarray:
    """Stationary rms change of each element's value over ``distance_m``: sqrt(2 (P - Phi P)) of the values."""
    p = local.initial_covariance()
    phi, _ = local.transition(distance_m)
    cross = (phi @ p)[:local.elements, :local.elements]
    return np.sqrt(2.0 * (np.diag(p)[:local.elements] - np.diag(cross)))


def test_order_one_is_the_former_gauss_markov():
    local = LocalError(SIGMA, LENGTH_M, 1)
    phi, q = local.transition(5_000.0)
    decay = math.exp(-5_000.0 / LENGTH_M)
    np.testing.assert_array_equal(phi, np.eye(3) * decay)
    np.testing.assert_allclose(q, np.diag(SIGMA ** 2 * (1.0 - decay ** 2)), rtol=1e-15)
    np.testing.assert_array_equal(local.columns(3), np.eye(3))


@pytest.mark.parametrize("order", [1, 2])
def test_the_stationary_covariance_is_kept(order):
    local = LocalError(SIGMA, LENGTH_M, order)
    p = local.initial_covariance()
    for distance in (0.0, 1_000.0, 5_000.0, 60_000.0):
        phi, q = local.transition(distance)
        np.testing.assert_allclose(phi @ p @ phi.T + q, p, rtol=1e-9, atol=1e-12 * np.max(p))


def test_order_two_is_smooth_and_only_its_values_are_measured():
    rough, smooth = LocalError(SIGMA, LENGTH_M, 1), LocalError(SIGMA, LENGTH_M, 2)
    assert smooth.n == 6
    np.testing.assert_array_equal(smooth.columns(3), np.hstack([np.eye(3), np.zeros((3, 3))]))
    # over a short leg: order 1 sigma sqrt(2 d / L), order 2 about sigma d / L (linear in the lag)
    np.testing.assert_allclose(_rms_change(rough, 1_000.0), SIGMA * math.sqrt(2.0 * 1_000.0 / LENGTH_M), rtol=0.03)
    np.testing.assert_allclose(_rms_change(smooth, 1_000.0), SIGMA * 1_000.0 / LENGTH_M, rtol=0.03)
    ratio = _rms_change(smooth, 2_000.0) / _rms_change(smooth, 1_000.0)
    np.testing.assert_allclose(ratio, 2.0, rtol=0.05)
    # far apart both forget: (1 + d/L) exp(-d/L) against exp(-d/L)
    far = 10 * LENGTH_M
    np.testing.assert_allclose(_rms_change(smooth, far), SIGMA * math.sqrt(2.0), rtol=1e-3)


def test_an_order_other_than_one_or_two_is_refused():
    with pytest.raises(ValueError, match="FUS_GM_ORDER"):
        LocalError(SIGMA, LENGTH_M, 3)
