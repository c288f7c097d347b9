"""The navigator's INS error model: linearised strapdown error equations, discretised exactly.

State (15, the order of the paper's eq. 47 and of PSINS), ENU local level:
``phi_e, phi_n, phi_u`` misalignment (rad), ``dv_e, dv_n, dv_u`` velocity error (m/s),
``dlat, dlon, dh`` position error (rad, rad, m), ``eps_c`` constant gyro drift (rad/s, 3),
``eps_r`` first-order Gauss-Markov gyro drift (rad/s, 3). "Error" is indicated minus true.

Continuous dynamics ``dx/dt = F x + w`` (Titterton & Weston, *Strapdown Inertial Navigation
Technology*, 2nd ed., ch. 12.3; PSINS ``etm``):

* ``dphi/dt = -w_in x phi + dw_in - eps_c - eps_r`` (Earth rate w_ie and transport rate w_en
  at the INS-indicated latitude and velocity; dw_in from the velocity and latitude errors);
* ``d(dv)/dt = f^n x phi - (2 w_ie + w_en) x dv`` with ``f^n = (0, 0, g)``: the Schuler loop
  (period ``2 pi sqrt(R/g)`` = 84.4 min) and Coriolis coupling; the vertical channel is held
  (a baro-aided INS, Table 1's zero vertical error);
* ``dlat/dt = dv_n / M``, ``dlon/dt = dv_e / (N cos lat) + dlat v_e tan(lat) / (N cos lat)``;
* ``d(eps_r)/dt = -eps_r / tau + w_r``, ``E[w_r w_r^T] = 2 sigma_r^2 / tau`` per axis.

Discretisation over one control step (coefficients frozen over the step, re-evaluated every
step at the INS-indicated latitude and the commanded velocity): ``Phi = expm(F T)`` and the
process noise ``Q_d = int_0^T Phi(s) Q_c Phi(s)^T ds`` by Van Loan's method (C. F. Van Loan,
"Computing integrals involving the matrix exponential", IEEE TAC 23(3), 1978):
``expm([[-F, Q_c], [0, F^T]] T) = [[., Phi^-1 Q_d], [0, Phi^T]]``.

This is written from the textbook for the navigator, independently of the simulator's truth
model (``sitl/world/ins.py``); a test checks the discretisation against a fine-step
integration of the same continuous equations.

>>> f = error_dynamics(0.0, 0.0, 0.0, 3600.0)     # at rest on the equator
>>> round(2 * math.pi / math.sqrt(-f[4, 0] * f[0, 4]) / 60, 1)   # Schuler period, minutes
84.3
"""
from __future__ import annotations

import functools
import math

import numpy as np
from scipy.linalg import expm

from companion.nav.geo import radii_of_curvature_m
from companion.registry import settings

__all__ = [
    "ATT",
    "EARTH_RATE_RADPS",
    "GRAVITY_MPS2",
    "LAT",
    "LON",
    "N_INS",
    "VEL",
    "AttitudeSource",
    "InsErrorSpec",
    "discretise",
    "error_dynamics",
    "initial_covariance",
    "misalignment_columns",
    "process_noise_density",
]

EARTH_RATE_RADPS = 7.292115e-5
GRAVITY_MPS2 = 9.7803
ARCSEC = math.radians(1.0 / 3600.0)
DEG_PER_HOUR = math.radians(1.0) / 3600.0
N_INS = 15
ATT, VEL = slice(0, 3), slice(3, 6)
LAT, LON = 6, 7
_BIAS, _MARKOV = slice(9, 12), slice(12, 15)


@settings("ins")
class InsErrorSpec:
    """What the navigator assumes about its INS, 1-sigma per axis: its datasheet, declared by the
    operator (the companion's ``FUS_INS_*``; their defaults are Table 1, the misalignment read as
    arc-seconds, see the README): misalignment about each level axis (``tilt_arcsec``) and in
    azimuth, the horizontal velocity error of both axes together (``vel_err_mps``: per axis this
    over sqrt 2), the position error per axis, the gyro drifts. ``vrw_mps_rts``: velocity random
    walk (accelerometer white noise, m/s per sqrt(s)); Table 1 gives none, a small value keeps
    the filter from trusting a noiseless model absolutely."""

    tilt_arcsec: float
    azimuth_arcsec: float
    vel_err_mps: float
    pos_err_m: float
    gyro_bias_degph: float
    gyro_markov_degph: float
    gyro_markov_tau_s: float
    vrw_mps_rts: float

    @property
    def misalign_arcsec(self) -> tuple[float, float, float]:
        """Misalignment about east, north, up."""
        return self.tilt_arcsec, self.tilt_arcsec, self.azimuth_arcsec

    @property
    def vel_err_axis_mps(self) -> float:
        """Velocity error per horizontal axis."""
        return self.vel_err_mps / math.sqrt(2.0)


def error_dynamics(lat_deg: float, vel_east_mps: float, vel_north_mps: float, markov_tau_s: float) -> np.ndarray:
    """The 15 x 15 continuous error-dynamics matrix F at this latitude and velocity (ENU)."""
    lat = math.radians(lat_deg)
    m, n = radii_of_curvature_m(lat_deg)
    sl, cl, tl = math.sin(lat), math.cos(lat), math.tan(lat)
    ve, vn = vel_east_mps, vel_north_mps
    w_ie = (0.0, EARTH_RATE_RADPS * cl, EARTH_RATE_RADPS * sl)
    w_en = (-vn / m, ve / n, ve * tl / n)
    f = _constant_dynamics(markov_tau_s).copy()    # then the entries that move with lat and v
    _set_minus_skew(f, 0, 0, [a + b for a, b in zip(w_ie, w_en)])
    # dw_in: the transport and Earth rates computed with the wrong velocity and latitude
    f[0, 4] = -1.0 / m
    f[1, 3] = 1.0 / n
    f[2, 3] = tl / n
    f[1, LAT] = -EARTH_RATE_RADPS * sl
    f[2, LAT] = EARTH_RATE_RADPS * cl + ve / (n * cl * cl)
    _set_minus_skew(f, 3, 3, [2.0 * a + b for a, b in zip(w_ie, w_en)])
    f[5, 3:6] = 0.0                                              # vertical channel held
    f[LAT, 4] = 1.0 / m
    f[LON, 3] = 1.0 / (n * cl)
    f[LON, LAT] = ve * tl / (n * cl)
    return f


@functools.lru_cache(maxsize=8)
def _constant_dynamics(markov_tau_s: float) -> np.ndarray:
    """The entries of F that depend on neither latitude nor velocity (read-only; copied)."""
    f = np.zeros((N_INS, N_INS))
    f[ATT, _BIAS] = -np.eye(3)
    f[ATT, _MARKOV] = -np.eye(3)
    f[VEL, ATT] = _skew(np.array([0.0, 0.0, GRAVITY_MPS2]))     # f^n x phi: the Schuler loop
    f[5, :] = 0.0                                                # vertical channel held
    f[_MARKOV, _MARKOV] = -np.eye(3) / markov_tau_s
    f.setflags(write=False)
    return f


def _set_minus_skew(f: np.ndarray, row: int, col: int, v: list[float]) -> None:
    """``f[row:row+3, col:col+3] = -skew(v)`` (the rate cross-product terms), entry by entry."""
    f[row, col + 1], f[row, col + 2] = v[2], -v[1]
    f[row + 1, col], f[row + 1, col + 2] = -v[2], v[0]
    f[row + 2, col], f[row + 2, col + 1] = v[1], -v[0]


def process_noise_density(spec: InsErrorSpec) -> np.ndarray:
    """Q_c, the spectral density of w (15 x 15, diagonal): velocity random walk on the
    horizontal velocity errors and the Markov drift's driving noise 2 sigma^2 / tau."""
    q = np.zeros(N_INS)
    q[3:5] = spec.vrw_mps_rts ** 2
    q[_MARKOV] = 2.0 * (spec.gyro_markov_degph * DEG_PER_HOUR) ** 2 / spec.gyro_markov_tau_s
    return np.diag(q)


def discretise(f: np.ndarray, q_c: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``(Phi, Q_d)`` of ``dx/dt = F x + w`` over ``dt_s`` seconds, exactly (Van Loan 1978).

    Van Loan's block holds ``expm(-F T)``, which grows as ``exp(T / tau)`` for a state decaying
    with time constant tau (the Markov drift): beyond a few tau, ``Q_d`` is a difference of huge
    numbers (a 1 s tau over a 360 s step gave a covariance that was not positive definite). So
    the step is cut into ``2^k`` equal pieces no longer than the fastest decay on F's diagonal
    and composed by doubling, ``(Phi, Q) -> (Phi Phi, Phi Q Phi^T + Q)``; one piece, as before,
    whenever ``T`` is within that time constant (Table 1: 360 s against 3600 s)."""
    fastest = float(np.max(-np.diagonal(f), initial=0.0))
    doublings = math.ceil(math.log2(dt_s * fastest)) if dt_s * fastest > 1.0 else 0
    phi, q_d = _van_loan(f, q_c, dt_s / 2 ** doublings)
    for _ in range(doublings):
        q_d = phi @ q_d @ phi.T + q_d
        phi = phi @ phi
    return phi, 0.5 * (q_d + q_d.T)


def _van_loan(f: np.ndarray, q_c: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    n = f.shape[0]
    block = np.zeros((2 * n, 2 * n))
    block[:n, :n] = -f
    block[:n, n:] = q_c
    block[n:, n:] = f.T
    e = expm(block * dt_s)
    phi = e[n:, n:].T
    return phi, phi @ e[:n, n:]


def initial_covariance(spec: InsErrorSpec, lat_deg: float) -> np.ndarray:
    """P_0 of the 15 INS error states from the spec (the vertical states held at zero)."""
    m, n = (float(r) for r in radii_of_curvature_m(lat_deg))
    sigma = np.zeros(N_INS)
    sigma[ATT] = np.array(spec.misalign_arcsec) * ARCSEC
    sigma[3:5] = spec.vel_err_axis_mps
    sigma[LAT] = spec.pos_err_m / m
    sigma[LON] = spec.pos_err_m / (n * math.cos(math.radians(lat_deg)))
    sigma[_BIAS] = spec.gyro_bias_degph * DEG_PER_HOUR
    sigma[_MARKOV] = spec.gyro_markov_degph * DEG_PER_HOUR
    return np.diag(sigma ** 2)


class AttitudeSource:
    """Values of FUS_ATT_INS: which part of the attitude that levels and turns the magnetometer into
    north-east-down is this INS's own."""

    NONE = 0      # an AHRS of its own: its errors are the bias states'
    TILT = 1      # roll and pitch from the INS, the heading from a true-heading sensor
    ALL = 2       # roll, pitch and heading from the INS (a navigation-grade INS's attitude)

    @staticmethod
    def columns(source: int) -> tuple[int, ...]:
        """The misalignment states (0 phi_e, 1 phi_n, 2 phi_u) the measured field carries."""
        return {AttitudeSource.NONE: (), AttitudeSource.TILT: (0, 1), AttitudeSource.ALL: (0, 1, 2)}[source]


def misalignment_columns(field_jacobian: np.ndarray, ned_nt: np.ndarray) -> np.ndarray:
    """``d(elements) / d(phi_e, phi_n, phi_u)`` (elements x 3): what the INS misalignment does to
    elements measured with the INS's attitude.

    The attitude turns the body-frame field into north-east-down; the misalignment ``phi`` (ENU,
    indicated minus true) turns it by the rotation vector ``(-phi_n, -phi_e, phi_u)`` in NED (the
    Euler errors of :meth:`sitl.world.ins.InsErrorModel.attitude_error_rad`, whatever the
    heading), so the measured field is ``B + theta x B`` and the elements move by
    ``J (theta x B)``, with ``field_jacobian`` J = d(elements)/d(N, E, Z) at the field
    ``ned_nt`` (:func:`companion.nav.disturbance.field_jacobian`). The yaw column of D is one
    radian per radian (D moves with the heading error); F does not move.

    >>> from companion.nav.disturbance import field_jacobian
    >>> ned = np.array([27000.0, -1500.0, 30000.0])
    >>> cols = misalignment_columns(field_jacobian(("decl_deg", "f_nt"), *ned), ned)
    >>> [round(float(v), 6) + 0.0 for v in cols[:, 2]]   # phi_u: D by 57.3 deg per rad, F not at all
    [57.29578, 0.0]
    """
    b = np.asarray(ned_nt, dtype=float)
    # theta = P phi: per unit phi_e, phi_n, phi_u the NED rotation vectors (0, -1, 0), (-1, 0, 0), (0, 0, 1)
    turn = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return field_jacobian @ (-_skew(b) @ turn)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
