"""Gradient G(k) of (D, I) from the vehicle's own moves (companion.nav.gradient, eq. 5-12).

Oracles: eq. 6-9 and eq. 10 typed out element by element, a linear field whose Jacobian is
known exactly, and the defining properties of the secant (Broyden) update.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.nav.gradient import (
    GradientEstimator,
    GradientUpdate,
    broyden_update,
    gradient_from_moves,
    paper_update,
)


class LinearField:
    """S(p) = S0 + G p for p = (east, north) metres: the gradient is G everywhere."""

    def __init__(self, g: np.ndarray, s0=(-3.9, 44.3)) -> None:
        self.g = np.asarray(g, dtype=float)
        self.s0 = np.asarray(s0, dtype=float)

    def __call__(self, p) -> np.ndarray:
        return self.s0 + self.g @ np.asarray(p, dtype=float)


G_PACIFIC = np.array([[3.4e-6, -3.1e-6], [-0.75e-6, 11.8e-6]])  # deg/m, the WMM's G near 33N 152E


# --- eq. 6-9 -------------------------------------------------------------------------------------
def test_axis_aligned_probes_reproduce_eq_6_to_9_literally():
    """theta = (0, 270): first move east (x1 > x0, y1 = y0), second south (x2 = x1, y2 < y1)."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        x0, y0 = rng.normal(0.0, 1000.0, 2)
        x1, y1 = x0 + rng.uniform(500.0, 6000.0), y0
        x2, y2 = x1, y1 - rng.uniform(500.0, 6000.0)
        d0, d1, d2 = rng.normal(-3.9, 0.05, 3)
        i0, i1, i2 = rng.normal(44.3, 0.05, 3)
        expected = np.array([
            [(d1 - d0) / (x1 - x0), (d2 - d1) / (y2 - y1)],   # eq. 6, eq. 7
            [(i1 - i0) / (x1 - x0), (i2 - i1) / (y2 - y1)],   # eq. 8, eq. 9
        ])
        g = gradient_from_moves(np.array([d1 - d0, i1 - i0]), np.array([x1 - x0, y1 - y0]),
                                np.array([d2 - d1, i2 - i1]), np.array([x2 - x1, y2 - y1]))
        np.testing.assert_allclose(g, expected, rtol=1e-12, atol=0)


def test_non_axis_aligned_moves_recover_a_linear_fields_jacobian_exactly():
    rng = np.random.default_rng(2)
    for _ in range(50):
        field = LinearField(rng.normal(0.0, 1e-5, (2, 2)))
        p0 = rng.normal(0.0, 2000.0, 2)
        a1, a2 = rng.uniform(0.0, 2.0 * math.pi, 2)
        if abs(math.sin(a2 - a1)) < 0.3:
            continue  # too close to parallel: refused, tested below
        p1 = p0 + rng.uniform(500.0, 6000.0) * np.array([math.cos(a1), math.sin(a1)])
        p2 = p1 + rng.uniform(500.0, 6000.0) * np.array([math.cos(a2), math.sin(a2)])
        g = gradient_from_moves(field(p1) - field(p0), p1 - p0, field(p2) - field(p1), p2 - p1)
        np.testing.assert_allclose(g, field.g, rtol=1e-6, atol=1e-14)


@pytest.mark.parametrize("dp2", [np.array([2000.0, 0.0]), np.array([-3000.0, 1e-9]), np.array([0.0, 0.0]),
                                 np.array([1000.0, 150.0])])
def test_parallel_or_empty_moves_are_refused(dp2):
    with pytest.raises(ValueError, match="different directions"):
        gradient_from_moves(np.array([0.01, 0.02]), np.array([5000.0, 0.0]), np.array([0.03, 0.01]), dp2)


# --- updates -------------------------------------------------------------------------------------
def test_broyden_update_explains_the_move_and_leaves_the_orthogonal_direction_alone():
    rng = np.random.default_rng(3)
    for _ in range(50):
        g = rng.normal(0.0, 1e-5, (2, 2))
        dp = rng.normal(0.0, 3000.0, 2)
        ds = rng.normal(0.0, 0.03, 2)
        new = broyden_update(g, ds, dp)
        np.testing.assert_allclose(new @ dp, ds, rtol=1e-10, atol=1e-15)
        v = np.array([-dp[1], dp[0]]) * rng.uniform(0.1, 3.0)  # orthogonal to dp
        np.testing.assert_allclose(new @ v, g @ v, rtol=1e-10, atol=1e-16)
        half = broyden_update(g, ds, dp, gain=0.5)
        np.testing.assert_allclose(half @ dp, g @ dp + 0.5 * (ds - g @ dp), rtol=1e-10, atol=1e-15)


def test_paper_update_is_eq_10_as_printed():
    g = np.array([[1.0e-5, -2.0e-5], [3.0e-6, 4.0e-5]])
    ds = np.array([0.012, -0.034])
    theta, v, period = math.radians(30.0), 13.9, 360.0
    vx, vy = v * math.cos(theta), v * math.sin(theta)
    new = paper_update(g, ds, theta, vx, vy, period)
    expected = g.copy()
    expected[0, 0] += ds[0] * math.cos(theta) / (vx * period)
    expected[0, 1] += ds[0] * math.sin(theta) / (vy * period)
    expected[1, 0] += ds[1] * math.cos(theta) / (vx * period)
    expected[1, 1] += ds[1] * math.sin(theta) / (vy * period)
    np.testing.assert_allclose(new, expected, rtol=1e-14, atol=0)
    # as the module says: with v_x = v cos(theta) both factors are 1/(v T)
    np.testing.assert_allclose(new - g, np.outer(ds, [1.0, 1.0]) / (v * period), rtol=1e-12)


@pytest.mark.parametrize("theta_deg,zero_column", [(90.0, 0), (0.0, 1), (180.0, 1)])
def test_paper_update_skips_the_column_of_a_zero_velocity_component(theta_deg, zero_column):
    g = np.array([[1.0e-5, -2.0e-5], [3.0e-6, 4.0e-5]])
    ds = np.array([0.02, 0.05])
    theta, v, period = math.radians(theta_deg), 10.0, 100.0
    vx = 0.0 if zero_column == 0 else v * math.cos(theta)
    vy = 0.0 if zero_column == 1 else v * math.sin(theta)
    new = paper_update(g, ds, theta, vx, vy, period)
    assert np.all(np.isfinite(new))
    np.testing.assert_array_equal(new[:, zero_column], g[:, zero_column])
    other = 1 - zero_column
    trig = math.cos(theta) if other == 0 else math.sin(theta)
    velocity = vx if other == 0 else vy
    np.testing.assert_allclose(new[:, other], g[:, other] + ds * trig / (velocity * period), rtol=1e-14)


# --- the estimator's sequence ----------------------------------------------------------------------
def fly(estimator: GradientEstimator, field: LinearField, moves, frozen: bool = False, period: float = 360.0):
    """Feed moves (east, north metres) to the estimator from the origin; returns the G after each."""
    p, out = np.zeros(2), []
    for dp in moves:
        dp = np.asarray(dp, dtype=float)
        q = p + dp
        theta = math.atan2(dp[1], dp[0])
        out.append(estimator.observe(field(q) - field(p), dp, theta, dp[0] / period, dp[1] / period, period,
                                     frozen=frozen))
        p = q
    return out


def test_estimator_needs_both_probes_then_has_the_exact_gradient():
    field = LinearField(G_PACIFIC)
    est = GradientEstimator()
    assert not est.ready
    g1, g2 = fly(est, field, [(5000.0, 0.0), (0.0, -5000.0)])  # Table 4: east, then south
    assert g1 is None and not (g2 is None)
    assert est.ready
    np.testing.assert_allclose(g2, G_PACIFIC, rtol=1e-9)


def test_estimator_ignores_short_and_non_finite_moves_while_probing():
    field = LinearField(G_PACIFIC)
    est = GradientEstimator(min_move_m=200.0)
    out = fly(est, field, [(50.0, 0.0), (5000.0, 0.0), (0.0, 100.0)])
    assert out == [None, None, None]
    assert est.observe(np.array([np.nan, 0.0]), np.array([0.0, -5000.0]), 0.0, 0.0, 0.0, 1.0) is None
    g = fly(est, field, [(0.0, -5000.0)])[-1]
    np.testing.assert_allclose(g, G_PACIFIC, rtol=1e-9)


def test_probing_moves_along_one_line_give_no_gradient_and_do_not_raise():
    """A vehicle that did not turn for its second probe (the moves east, then east again, or back
    west) gives no gradient, as moves too short do; it raised ValueError out of the core before,
    the fuzz of tests/nav/test_mission_fuzz.py found it. Ten degrees apart is still too close
    (MIN_MOVE_SINE 0.2, 11.5 deg); a later move at an angle gives the exact gradient."""
    field = LinearField(G_PACIFIC)
    for second in ((4000.0, 0.0), (-5000.0, 0.0), (5000.0 * math.cos(0.17), 5000.0 * math.sin(0.17))):
        est = GradientEstimator()
        assert fly(est, field, [(5000.0, 0.0), second]) == [None, None]
        np.testing.assert_allclose(fly(est, field, [(0.0, -5000.0)])[-1], G_PACIFIC, rtol=1e-9)


def test_frozen_estimator_keeps_the_probe_gradient_lti():
    true_field = LinearField(G_PACIFIC)
    est = GradientEstimator()
    fly(est, true_field, [(5000.0, 0.0), (0.0, -5000.0)])
    probe_g = est.g.copy()
    other = LinearField(G_PACIFIC * 3.0 + 1e-6)  # the field "changes": LTI must not notice
    outs = fly(est, other, [(3000.0, -4000.0), (-2000.0, -4500.0)], frozen=True)
    for g in outs:
        np.testing.assert_array_equal(g, probe_g)


def test_broyden_estimator_tracks_a_changed_field_and_skips_short_moves():
    est = GradientEstimator(GradientUpdate.BROYDEN, min_move_m=200.0)
    fly(est, LinearField(G_PACIFIC), [(5000.0, 0.0), (0.0, -5000.0)])
    new_field = LinearField(G_PACIFIC + np.array([[1e-6, 2e-6], [-3e-6, 1e-6]]))
    before = est.g.copy()
    np.testing.assert_array_equal(fly(est, new_field, [(100.0, 50.0)])[-1], before)  # too short: kept
    dp1, dp2 = np.array([3000.0, -4000.0]), np.array([-4000.0, -3000.0])  # orthogonal moves
    g1 = fly(est, new_field, [dp1])[-1]
    np.testing.assert_allclose(g1, broyden_update(before, new_field.g @ dp1, dp1), rtol=1e-12)
    g2 = fly(est, new_field, [dp2])[-1]
    np.testing.assert_allclose(g2 @ dp2, new_field.g @ dp2, rtol=1e-10)
    # the second update leaves G dp1 alone (dp1 is orthogonal to dp2), so G now explains both
    # moves: two independent secants of a linear field pin G down exactly
    np.testing.assert_allclose(g2, new_field.g, rtol=1e-9, atol=1e-15)


def test_paper_method_applies_eq_10_after_the_probes():
    field = LinearField(G_PACIFIC)
    est = GradientEstimator(GradientUpdate.PAPER)
    fly(est, field, [(5000.0, 0.0), (0.0, -5000.0)])
    before = est.g.copy()
    dp, period = np.array([3000.0, -4000.0]), 360.0
    theta = math.atan2(dp[1], dp[0])
    g = fly(est, field, [dp], period=period)[-1]
    ds = field.g @ dp
    np.testing.assert_allclose(g, paper_update(before, ds, theta, dp[0] / period, dp[1] / period, period),
                               rtol=1e-12)
    # eq. 10 adds the whole change to both columns: on a linear field it drifts away from the truth
    assert np.linalg.norm(g - field.g) > np.linalg.norm(before - field.g)


def test_two_moves_method_uses_the_last_two_displacements():
    est = GradientEstimator(GradientUpdate.TWO_MOVES)
    fly(est, LinearField(G_PACIFIC), [(5000.0, 0.0), (0.0, -5000.0)])
    new_field = LinearField(G_PACIFIC * 1.5)
    # first update pairs the second probe (old field) with the new move; the next uses two new moves
    fly(est, new_field, [(4000.0, -3000.0)])
    g = fly(est, new_field, [(-1000.0, -5000.0)])[-1]
    np.testing.assert_allclose(g, new_field.g, rtol=1e-9)
    # a move parallel to the previous one falls back to the Broyden update
    before = est.g.copy()
    dp = np.array([-1100.0, -5500.0])
    g = fly(est, new_field, [dp])[-1]
    np.testing.assert_allclose(g, broyden_update(before, new_field.g @ dp, dp), rtol=1e-12)
