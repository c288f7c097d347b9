"""The navigator's INS error model (companion.nav.ins_error): exact discretisation and Schuler.

Oracles: a fine-step fourth-order Runge-Kutta integration of the same continuous equations
(dPhi/dt = F Phi, dP/dt = F P + P F^T + Q_c) written here, and the textbook Schuler period
2 pi sqrt(M / g) of the velocity error's free oscillation.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from companion.nav.geo import radii_of_curvature_m
from companion.nav.disturbance import field_jacobian
from companion.nav.ins_error import (GRAVITY_MPS2, LAT, InsErrorSpec, discretise, error_dynamics,
                                     initial_covariance, misalignment_columns, process_noise_density)
from companion.nav.process import InsProcess


def rk4_propagate(f: np.ndarray, q_c: np.ndarray, dt_s: float, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Phi and Q_d by integrating the continuous equations with RK4 in ``steps`` steps."""
    n = f.shape[0]
    phi, q = np.eye(n), np.zeros((n, n))
    h = dt_s / steps
    d_phi = lambda p: f @ p  # noqa: E731
    d_q = lambda p: f @ p + p @ f.T + q_c  # noqa: E731
    for _ in range(steps):
        k1, l1 = d_phi(phi), d_q(q)
        k2, l2 = d_phi(phi + 0.5 * h * k1), d_q(q + 0.5 * h * l1)
        k3, l3 = d_phi(phi + 0.5 * h * k2), d_q(q + 0.5 * h * l2)
        k4, l4 = d_phi(phi + h * k3), d_q(q + h * l3)
        phi = phi + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        q = q + h / 6.0 * (l1 + 2 * l2 + 2 * l3 + l4)
    return phi, q


@pytest.mark.parametrize("lat, ve, vn", [(33.0, 10.3, -9.3), (-45.0, 0.0, 13.9), (0.0, -13.9, 0.0)])
def test_van_loan_matches_a_fine_step_integration(lat, ve, vn):
    """One 360 s control step: Phi and Q_d from Van Loan equal a 3600-step RK4 integration."""
    spec = InsErrorSpec(vrw_mps_rts=1e-3)
    f = error_dynamics(lat, ve, vn, spec.gyro_markov_tau_s)
    q_c = process_noise_density(spec)
    phi, q_d = discretise(f, q_c, 360.0)
    phi_ref, q_ref = rk4_propagate(f, q_c, 360.0, 3600)
    np.testing.assert_allclose(phi, phi_ref, rtol=1e-8, atol=1e-12)
    # each entry to 1e-6 of its correlation scale sqrt(q_ii q_jj) (the states' units differ by
    # orders of magnitude); entries of states without noise (constant drift) only to round-off
    diag = np.diag(q_ref)
    scale = np.sqrt(np.outer(diag, diag))
    round_off = 1e-12 * np.sqrt(np.maximum.outer(diag, diag) * diag.max())
    assert np.all(np.abs(q_d - q_ref) <= 1e-6 * scale + round_off)
    assert np.all(np.linalg.eigvalsh(q_d) > -1e-18)          # a covariance
    np.testing.assert_allclose(q_d, q_d.T, atol=0.0)


@pytest.mark.parametrize("tau_s, sigma_degph", [(1.0, 0.005), (10.0, 100.0), (100.0, 1.0)])
def test_a_markov_drift_much_faster_than_the_step_is_discretised_as_exactly(tau_s, sigma_degph):
    """FUS_INS_GM_TAU down to 1 s against a 360 s step: Van Loan's block then holds exp(360) and
    its Q_d was not a covariance; cut into pieces and composed, Phi and Q_d equal a fine-step RK4
    integration (steps of a tenth of tau) as closely as at Table 1's 3600 s."""
    spec = InsErrorSpec(gyro_markov_degph=sigma_degph, gyro_markov_tau_s=tau_s, vrw_mps_rts=1e-3)
    f = error_dynamics(33.0, 10.3, -9.3, tau_s)
    q_c = process_noise_density(spec)
    phi, q_d = discretise(f, q_c, 360.0)
    phi_ref, q_ref = rk4_propagate(f, q_c, 360.0, max(3600, int(3600.0 / tau_s)))
    np.testing.assert_allclose(phi, phi_ref, rtol=1e-8, atol=1e-12)
    diag = np.diag(q_ref)
    scale = np.sqrt(np.outer(diag, diag))
    round_off = 1e-12 * np.sqrt(np.maximum.outer(diag, diag) * diag.max())
    assert np.all(np.abs(q_d - q_ref) <= 1e-6 * scale + round_off)
    assert np.all(np.linalg.eigvalsh(q_d) > -1e-12 * diag.max())          # a covariance


def test_free_propagation_oscillates_at_the_schuler_period():
    """A north tilt error at rest, propagated in 60 s steps by the filter's own process model:
    the north velocity error crosses zero every half Schuler period, 2 pi sqrt(M / g) / 2."""
    lat = 33.0
    process = InsProcess(InsErrorSpec(), lat)
    phi, _ = process.transition(60.0, lat, np.zeros(2))
    x = np.zeros(process.n)
    x[0] = math.radians(10.0 / 3600.0)                        # 10 arcsec about east
    vn = []
    for _ in range(int(6 * 3600 / 60)):
        x = phi @ x
        vn.append(x[4])
    vn = np.array(vn)
    crossings = np.flatnonzero(np.sign(vn[1:]) != np.sign(vn[:-1]))
    t = 60.0 * (crossings + 1 - vn[crossings + 1] / (vn[crossings + 1] - vn[crossings]))   # interpolated
    half_periods = np.diff(t)
    m, _ = radii_of_curvature_m(lat)
    schuler = 2.0 * math.pi * math.sqrt(float(m) / GRAVITY_MPS2)
    assert len(half_periods) >= 6
    assert np.median(half_periods) == pytest.approx(schuler / 2.0, rel=0.01)
    # and the amplitude is the tilt's g phi / omega_s, not growing (no gyro drift here)
    tilt = math.radians(10.0 / 3600.0)
    assert np.max(np.abs(vn)) == pytest.approx(GRAVITY_MPS2 * tilt / (2.0 * math.pi / schuler), rel=0.05)


def test_initial_covariance_is_table_1():
    spec = InsErrorSpec()
    p0 = initial_covariance(spec, 33.0)
    m, _ = radii_of_curvature_m(33.0)
    assert math.sqrt(p0[LAT, LAT]) * float(m) == pytest.approx(5000.0)
    assert math.sqrt(p0[2, 2]) == pytest.approx(math.radians(500.0 / 3600.0))
    assert p0[5, 5] == 0.0 and p0[8, 8] == 0.0                # vertical channel held


@pytest.mark.parametrize("names", [("decl_deg", "incl_deg"), ("decl_deg", "incl_deg", "f_nt"), ("incl_deg", "f_nt"),
                                   ("h_nt", "z_nt")])
def test_misalignment_columns_are_the_elements_of_the_turned_field(names):
    """Oracle: the elements of the field turned by scipy's Rotation of the rotation vector
    (-phi_n, -phi_e, phi_u) in north-east-down, by central differences of 1e-6 rad per state."""
    ned = np.array([27500.0, -1800.0, 31000.0])
    columns = misalignment_columns(field_jacobian(names, *ned), ned)

    def elements(b: np.ndarray) -> np.ndarray:
        h = math.hypot(b[0], b[1])
        values = {"decl_deg": math.degrees(math.atan2(b[1], b[0])), "incl_deg": math.degrees(math.atan2(b[2], h)),
                  "f_nt": math.hypot(h, b[2]), "h_nt": h, "z_nt": b[2]}
        return np.array([values[name] for name in names])

    eps = 1e-6
    for state, turn in enumerate(([0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0])):   # phi_e, phi_n, phi_u
        plus = Rotation.from_rotvec(eps * np.array(turn)).apply(ned)
        minus = Rotation.from_rotvec(-eps * np.array(turn)).apply(ned)
        assert columns[:, state] == pytest.approx((elements(plus) - elements(minus)) / (2.0 * eps), rel=1e-5, abs=1e-5)
