"""Spherical-harmonic evaluation of a degree-12 geomagnetic main-field model (WMM, IGRF).

Follows the algorithm of the WMM technical report (Chulliat et al., *The US/UK World Magnetic
Model for 2020-2025*, NOAA NCEI): geodetic to geocentric spherical coordinates, time-adjusted
Gauss coefficients ``g(t) = g(t0) + (t - t0) g_dot``, the field sums of Schmidt semi-normalised
associated Legendre functions, and the rotation back to the geodetic north/east/down frame.
Inputs in degrees and metres, output (X, Y, Z) in nT. Pure numpy; no files.

:class:`HarmonicSums` holds the per-term constants of one coefficient set and evaluates

* :meth:`~HarmonicSums.ned`: 1-D arrays of points, with per-point altitudes and epochs or one
  of each for all (the few-point stencil of the geomagnetic fix: the coefficients are then
  adjusted once, with the same numbers per point, bit for bit);
* :meth:`~HarmonicSums.ned_scalar`: one point with ``math`` for the geometry.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["REFERENCE_RADIUS_M", "WMM_DEGREE", "HarmonicSums", "schmidt_polynomials"]

WMM_DEGREE = 12
"""Maximum spherical-harmonic degree (and order) of the standard WMM."""

# WGS84 ellipsoid and the geomagnetic reference radius a = 6371200 m of the WMM technical report.
_WGS84_A_M = 6378137.0
_WGS84_F = 1.0 / 298.257223563
_WGS84_E2 = _WGS84_F * (2.0 - _WGS84_F)
REFERENCE_RADIUS_M = 6371200.0


def schmidt_polynomials(degree: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Schmidt semi-normalised Legendre functions as polynomials, for n = 1..degree, m = 0..n.

    ``P_n^m(s) = c**m * Q_n^m(s)`` with ``s = sin(phi')``, ``c = cos(phi')``; ``Q_n^m`` is a
    polynomial of degree n - m. Returns (n, m, coefficients of Q in powers s**0..s**degree,
    coefficients of dQ/ds), one row per (n, m). Built with the standard recursions
    ``P_n^m = ((2n-1) s P_{n-1}^m - sqrt((n-1)^2 - m^2) P_{n-2}^m) / sqrt(n^2 - m^2)`` and
    ``P_m^m = sqrt(1 - 1/(2m)) c P_{m-1}^{m-1}`` (``P_1^1 = c``). Evaluating all 90 functions is
    then one matrix product; the coefficients stay below 2.2e3 for degree 12, so the cancellation
    costs under 1e-12 of a unit function (tests check against the recursion and scipy).
    """
    size = degree + 1
    q = np.zeros((size, size, size))  # q[n, m] = coefficients of Q_n^m
    q[0, 0, 0] = 1.0
    for m in range(1, size):
        q[m, m] = q[m - 1, m - 1] * (1.0 if m == 1 else math.sqrt(1.0 - 0.5 / m))
    for m in range(size):
        for n in range(m + 1, size):
            times_s = np.roll(q[n - 1, m], 1)  # multiply the polynomial by s
            times_s[0] = 0.0
            q[n, m] = (2 * n - 1) * times_s
            if n - 2 >= m:
                q[n, m] -= math.sqrt((n - 1) ** 2 - m * m) * q[n - 2, m]
            q[n, m] /= math.sqrt(n * n - m * m)
    n_idx, m_idx = np.array([(n, m) for n in range(1, size) for m in range(n + 1)]).T
    coefficients = q[n_idx, m_idx]
    derivative = np.zeros_like(coefficients)
    derivative[:, :-1] = coefficients[:, 1:] * np.arange(1, size)
    return n_idx, m_idx, coefficients, derivative


class HarmonicSums:
    """The field sums of one coefficient set (g, h, g_dot, h_dot per (n, m), nT and nT/year,
    in the order of :func:`schmidt_polynomials`), evaluated at ``year - epoch``."""

    def __init__(self, coeffs: np.ndarray) -> None:
        n_idx, m_idx, q_poly, dq_poly = schmidt_polynomials(WMM_DEGREE)
        self._m = m_idx
        self._q_poly_t = np.ascontiguousarray(q_poly.T)  # (13, 90): powers of s -> Q_n^m
        self._dq_poly_t = np.ascontiguousarray(dq_poly.T)
        self._coeffs = np.array(coeffs, dtype=float)
        self._m_float = m_idx.astype(float)
        self._n_plus_1 = n_idx + 1.0
        # column of c**(m-1); for m = 0 any column will do, the term is multiplied by m = 0
        self._m_minus_1 = np.maximum(m_idx - 1, 0)
        self._m_plus_1 = m_idx + 1
        self._radial_power = n_idx + 2  # (a/r)**(n+2)
        self._powers = np.arange(WMM_DEGREE + 1)
        self._c_powers = np.arange(WMM_DEGREE + 2)
        self._orders = np.arange(WMM_DEGREE + 1)
        self._q_dq_poly_t = np.ascontiguousarray(np.hstack([self._q_poly_t, self._dq_poly_t]))
        for array in (self._coeffs, self._q_poly_t, self._dq_poly_t, self._q_dq_poly_t):
            array.setflags(write=False)

    def ned_scalar(self, lat_deg: float, lon_deg: float, alt_m: float, dt_years: float) -> tuple[float, float, float]:
        """(X, Y, Z) in nT at one point: :meth:`ned` with math for the geometry and one numpy
        call per step over the 90 terms, about half the time of a one-point array call."""
        phi = math.radians(lat_deg)
        sin_phi, cos_phi = math.sin(phi), math.cos(phi)
        prime_vertical = _WGS84_A_M / math.sqrt(1.0 - _WGS84_E2 * sin_phi * sin_phi)
        p = (prime_vertical + alt_m) * cos_phi
        z = (prime_vertical * (1.0 - _WGS84_E2) + alt_m) * sin_phi
        r = math.hypot(p, z)
        s, c = z / r, p / r

        g, h = self._coeffs[:2] + dt_years * self._coeffs[2:]
        q_and_dq = np.power(s, self._powers) @ self._q_dq_poly_t
        q, dq_ds = q_and_dq[: self._m.size], q_and_dq[self._m.size :]
        m_p_over_c = self._m_float * np.power(c, self._m_minus_1) * q
        p_nm = np.power(c, self._m) * q
        dp_nm = np.power(c, self._m + 1) * dq_ds - s * m_p_over_c

        radial = np.power(REFERENCE_RADIUS_M / r, self._radial_power)
        angles = math.radians(lon_deg) * self._m_float
        cos_ml, sin_ml = np.cos(angles), np.sin(angles)
        in_phase = radial * (g * cos_ml + h * sin_ml)
        quadrature = radial * (g * sin_ml - h * cos_ml)
        x_prime = -float(in_phase @ dp_nm)
        y_prime = float(quadrature @ m_p_over_c)
        z_prime = -float(in_phase @ (self._n_plus_1 * p_nm))

        cos_psi = c * cos_phi + s * sin_phi
        sin_psi = s * cos_phi - c * sin_phi
        return x_prime * cos_psi - z_prime * sin_psi, y_prime, x_prime * sin_psi + z_prime * cos_psi

    def ned(self, lat_deg: np.ndarray, lon_deg: np.ndarray, alt_m: np.ndarray | float,
            dt_years: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, Y, Z) in nT, geodetic north/east/down, for 1-D arrays of points; ``alt_m`` and
        ``dt_years`` (years since the epoch) are arrays of the same length or floats."""
        phi = np.radians(lat_deg)
        lam = np.radians(lon_deg)
        sin_phi, cos_phi = np.sin(phi), np.cos(phi)

        # 1. Geodetic -> geocentric spherical: prime-vertical radius, then r and phi'.
        prime_vertical = _WGS84_A_M / np.sqrt(1.0 - _WGS84_E2 * sin_phi * sin_phi)
        p = (prime_vertical + alt_m) * cos_phi
        z = (prime_vertical * (1.0 - _WGS84_E2) + alt_m) * sin_phi
        r = np.hypot(p, z)
        s, c = z / r, p / r  # sin(phi'), cos(phi')

        # 2. Time-adjusted Gauss coefficients g(t) = g(t0) + (t - t0) g_dot: one row per point,
        # or one row for all (the same numbers, computed once).
        dt = dt_years[:, None] if isinstance(dt_years, np.ndarray) else dt_years
        g0, h0, g_dot, h_dot = self._coeffs
        g = g0 + dt * g_dot
        h = h0 + dt * h_dot

        # 3. Legendre functions P = c**m Q(s); m P / cos(phi') = m c**(m-1) Q stays finite at the
        # poles, so the east sum needs neither a division by cos(phi') nor a pole special case.
        s_powers = s[:, None] ** self._powers
        q = s_powers @ self._q_poly_t
        dq_ds = s_powers @ self._dq_poly_t
        c_powers = c[:, None] ** self._c_powers
        m_p_over_c = c_powers[:, self._m_minus_1] * self._m_float * q
        p_nm = c_powers[:, self._m] * q
        # dP/dphi' = c dP/ds = c**(m+1) dQ/ds - m s c**(m-1) Q
        dp_nm = c_powers[:, self._m_plus_1] * dq_ds - s[:, None] * m_p_over_c

        radial = (REFERENCE_RADIUS_M / r)[:, None] ** self._radial_power
        angles = lam[:, None] * self._orders
        cos_ml, sin_ml = np.cos(angles)[:, self._m], np.sin(angles)[:, self._m]  # 13 cos, not 90
        in_phase = radial * (g * cos_ml + h * sin_ml)
        quadrature = radial * (g * sin_ml - h * cos_ml)

        # 4. Field sums in geocentric spherical components (X' north, Y' east, Z' down):
        #    X' = -sum (a/r)^(n+2) (g cos m.lon + h sin m.lon) dP/dphi'
        #    Y' = sum (a/r)^(n+2) m (g sin m.lon - h cos m.lon) P / cos(phi')
        #    Z' = -sum (n+1) (a/r)^(n+2) (g cos m.lon + h sin m.lon) P
        x_prime = -np.einsum("ij,ij->i", in_phase, dp_nm)
        y_prime = np.einsum("ij,ij->i", quadrature, m_p_over_c)
        z_prime = -np.einsum("ij,ij->i", in_phase * self._n_plus_1, p_nm)

        # 5. Rotate back to the geodetic frame by psi = phi' - phi.
        cos_psi = c * cos_phi + s * sin_phi
        sin_psi = s * cos_phi - c * sin_phi
        return x_prime * cos_psi - z_prime * sin_psi, y_prime, x_prime * sin_psi + z_prime * cos_psi
