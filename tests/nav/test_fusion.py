"""INS / geomagnetic fusion (companion.nav.fusion, eq. 46-58, Table 3).

Oracle: the Kalman predict and update of eq. 52-56 written out with numpy from Table 3's
matrices (built here, not taken from the filter), and for the diagonal Table 3 case the
scalar closed form per axis.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.nav.fusion import H_B, FusionFeedback, FusionSettings, InsGeomagFusion
from companion.params import NavConfig

KM2 = 1e6  # m^2 per km^2


def table3(config: NavConfig):
    """Table 3 in m^2: Q_c, R_c, P_0 (15 x 15 / 2 x 2), F and H_B written out."""
    pos = lambda v: np.diag([0.0] * 3 + [v, v] + [0.0] * 10)  # noqa: E731
    h = np.zeros((2, 15))
    h[0, 3] = h[1, 4] = 1.0  # eq. 51: (0_2x3, I_2, 0_2x10)
    return pos(config.fusion.qc_m2), np.eye(2) * config.fusion.rc_m2, pos(config.fusion.p0_m2), np.eye(15), h


def kalman_by_hand(x, p, dz, q, r, f, h):
    """Eq. 52-56."""
    x_prior = f @ x                                    # eq. 52
    p_prior = f @ p @ f.T + q                          # eq. 53
    k = p_prior @ h.T @ np.linalg.inv(h @ p_prior @ h.T + r)   # eq. 54
    x_post = x_prior + k @ (dz - h @ x_prior)          # eq. 55
    p_post = (np.eye(15) - k @ h) @ p_prior            # eq. 56
    return x_post, p_post


def test_navconfig_defaults_are_table_3_in_square_metres():
    config = NavConfig()
    assert config.fusion.qc_m2 == pytest.approx(0.05 * KM2)
    assert config.fusion.rc_m2 == pytest.approx(2.0 * KM2)
    assert config.fusion.p0_m2 == pytest.approx(1.0 * KM2)
    np.testing.assert_array_equal(H_B, table3(config)[4])
    defaults = FusionSettings()
    assert (defaults.qc_m2, defaults.rc_m2, defaults.p0_m2) == pytest.approx(
        (config.fusion.qc_m2, config.fusion.rc_m2, config.fusion.p0_m2))


def test_two_kalman_steps_match_the_hand_computation():
    config = NavConfig()
    q, r, p0, f, h = table3(config)
    fusion = InsGeomagFusion(FusionSettings(config.fusion.qc_m2, config.fusion.rc_m2, config.fusion.p0_m2))
    x, p = np.zeros(15), p0
    steps = [(np.array([5200.0, 4700.0]), np.array([300.0, -450.0])),      # (INS, fix) local metres
             (np.array([10400.0, -800.0]), np.array([5600.0, -5300.0]))]
    for ins, fix in steps:
        x, p = kalman_by_hand(x, p, ins - fix, q, r, f, h)               # eq. 50: dZ = Z_m - Z_c
        result = fusion.step(ins, fix)
        np.testing.assert_allclose([result.east_m, result.north_m], ins - x[3:5], rtol=1e-12, atol=1e-6)
        np.testing.assert_allclose(fusion.kf.P, p, rtol=1e-10, atol=1e-6)
        assert result.sigma_m == pytest.approx(math.sqrt(0.5 * (p[3, 3] + p[4, 4])), rel=1e-12)
        assert result.innovation_m == pytest.approx(tuple(ins - fix))
    np.testing.assert_allclose(fusion.error_estimate_m, x[3:5], rtol=1e-12)


def test_first_step_matches_the_scalar_closed_form_of_table_3():
    """Diagonal P, Q, R: per axis K = (P0 + Qc) / (P0 + Qc + Rc), P = (1 - K)(P0 + Qc)."""
    p0, qc, rc = 1.0 * KM2, 0.05 * KM2, 2.0 * KM2
    gain = (p0 + qc) / (p0 + qc + rc)
    fusion = InsGeomagFusion(FusionSettings(qc, rc, p0))
    ins, fix = np.array([5000.0, 5000.0]), np.array([0.0, 0.0])
    result = fusion.step(ins, fix)
    assert result.east_m == pytest.approx(5000.0 * (1.0 - gain), rel=1e-12)
    assert result.north_m == pytest.approx(5000.0 * (1.0 - gain), rel=1e-12)
    assert result.sigma_m == pytest.approx(math.sqrt((1.0 - gain) * (p0 + qc)), rel=1e-12)
    # only the position block moves: attitude, velocity and drift states stay zero
    assert np.count_nonzero(fusion.kf.x[[0, 1, 2] + list(range(5, 15))]) == 0


def test_paper_feedback_adds_the_correction_to_the_geomagnetic_fix_eq_58():
    config = NavConfig()
    q, r, p0, f, h = table3(config)
    fusion = InsGeomagFusion(FusionSettings(config.fusion.qc_m2, config.fusion.rc_m2, config.fusion.p0_m2,
                                            FusionFeedback.PAPER))
    x, p = np.zeros(15), p0
    for ins, fix in ((np.array([5200.0, 4700.0]), np.array([300.0, -450.0])),
                     (np.array([9000.0, 100.0]), np.array([4100.0, -4900.0]))):
        x, p = kalman_by_hand(x, p, ins - fix, q, r, f, h)
        result = fusion.step(ins, fix)
        # (lambda_c, phi_c)(k+1) = (lambda_c, phi_c)(k) + (d lambda, d phi): fix plus the estimate
        np.testing.assert_allclose([result.east_m, result.north_m], fix + x[3:5], rtol=1e-12, atol=1e-6)


def test_predict_only_grows_the_covariance_and_keeps_correcting_the_ins():
    config = NavConfig()
    q, r, p0, f, h = table3(config)
    fusion = InsGeomagFusion(FusionSettings(config.fusion.qc_m2, config.fusion.rc_m2, config.fusion.p0_m2))
    fusion.step(np.array([5000.0, 5000.0]), np.array([0.0, 0.0]))
    p_before, x_before = fusion.kf.P.copy(), fusion.error_estimate_m
    ins = np.array([7000.0, 6000.0])
    result = fusion.predict_only(ins)
    np.testing.assert_allclose(fusion.kf.P, f @ p_before @ f.T + q, rtol=1e-12)
    np.testing.assert_allclose([result.east_m, result.north_m], ins - x_before, rtol=1e-12)
    assert result.sigma_m > math.sqrt(0.5 * (p_before[3, 3] + p_before[4, 4]))


def test_repeated_fixes_converge_on_a_constant_ins_error():
    """A constant INS offset seen through noisy fixes: the estimate approaches the offset."""
    rng = np.random.default_rng(0)
    offset = np.array([5000.0, -3000.0])
    fusion = InsGeomagFusion(FusionSettings())
    truth = np.zeros(2)
    for _ in range(200):
        truth = truth + np.array([3000.0, -2000.0])
        result = fusion.step(truth + offset, truth + rng.normal(0.0, math.sqrt(2.0e6), 2))
    # steady state of the scalar Riccati equation P = (P + Qc) Rc / (P + Qc + Rc):
    # P^2 + Qc P - Qc Rc = 0; the per-axis error is N(0, P), so 4 sigma bounds it
    qc, rc = 0.05e6, 2.0e6
    p_ss = (-qc + math.sqrt(qc * qc + 4.0 * qc * rc)) / 2.0
    assert 0.5 * (fusion.kf.P[3, 3] + fusion.kf.P[4, 4]) == pytest.approx(p_ss, rel=1e-6)
    bound = 4.0 * math.sqrt(p_ss)
    np.testing.assert_allclose([result.east_m, result.north_m], truth, atol=bound)
    np.testing.assert_allclose(fusion.error_estimate_m, offset, atol=bound)
