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
* :meth:`~HarmonicSums.ned_scalar`: one point with ``math`` for the geometry;
* :meth:`~HarmonicSums.ned_and_slopes`: one point, with the exact derivatives of (X, Y, Z)
  along geodetic latitude and longitude from the same sums (the fix's and the filter's
  gradient G in one evaluation instead of a 5-point stencil).

The derivatives differentiate each term analytically: with ``P = c**m Q(s)`` (``s = sin(phi')``,
``c = cos(phi')``), ``dP/dphi' = c**(m+1) Q' - m s c**(m-1) Q`` and

    d2P/dphi'2 = c**(m+2) Q'' - (2m+1) s c**m Q' - m c**m Q + m (m-1) s**2 c**(m-2) Q,
    d(m P / c)/dphi' = m c**m Q' - m (m-1) s c**(m-2) Q,

``d(a/r)**(n+2)/dr = -(n+2)/r (a/r)**(n+2)``, and ``d/dlon`` turns the in-phase sum into
``-m`` times the quadrature sum and the quadrature into ``m`` times the in-phase. The geodetic
latitude moves the geocentric point by ``dr/dphi = (M + h) sin(psi)`` and
``dphi'/dphi = (M + h) cos(psi) / r`` (M the meridian radius, ``psi = phi' - phi``), and the
rotation back to the geodetic frame turns with ``dpsi/dphi = dphi'/dphi - 1``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["REFERENCE_RADIUS_M", "WMM_DEGREE", "GeocentricPoint", "HarmonicSums", "field_and_slopes_from_sums",
           "geocentric_point", "schmidt_polynomials"]

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
    return n_idx, m_idx, coefficients, _polynomial_derivative(coefficients)


def _polynomial_derivative(coefficients: np.ndarray) -> np.ndarray:
    """Coefficients (powers s**0, s**1, ...) of the derivative of each row's polynomial."""
    derivative = np.zeros_like(coefficients)
    derivative[:, :-1] = coefficients[:, 1:] * np.arange(1, coefficients.shape[1])
    return derivative


def _slope_matrices(m: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The constants of :meth:`HarmonicSums.ned_and_slopes`: for the in-phase sums (dP, (n+1) P,
    d2P, (n+1) dP, (n+2) dP, (n+1)(n+2) P, m (m P / c)) and the quadrature sums (m P / c,
    d(m P / c), (n+2) m P / c, m dP, m (n+1) P), the coefficient of each basis row U_j of each
    term, per power of s (0, 1, 2), as (3 * sums) x (6 * terms) matrices. With the basis rows
    U = (c^m Q, c^(m+1) Q', c^(m+2) Q'', c^(m-1) Q, c^(m-2) Q, c^m Q'):
    P = U0, m P / c = m U3, dP = U1 - s m U3, d2P = U2 - s (2m+1) U5 - m U0 + s^2 m (m-1) U4,
    d(m P / c) = m U5 - s m (m-1) U4 (the formulas of the module docstring)."""
    one, mm1 = np.ones_like(m), m * (m - 1.0)
    functions = {   # name: {(basis row, power of s): coefficient per term}
        "P": {(0, 0): one}, "mPc": {(3, 0): m}, "dP": {(1, 0): one, (3, 1): -m},
        "d2P": {(2, 0): one, (5, 1): -(2.0 * m + 1.0), (0, 0): -m, (4, 2): mm1},
        "dmPc": {(5, 0): m, (4, 1): -mm1},
    }

    def matrix(sums: list[tuple[str, np.ndarray]]) -> np.ndarray:
        out = np.zeros((3, len(sums), 6, m.size))
        for row, (name, factor) in enumerate(sums):
            for (basis, power), coefficient in functions[name].items():
                out[power, row, basis] += factor * coefficient
        return np.ascontiguousarray(out.reshape(3 * len(sums), 6 * m.size))

    in_phase = matrix([("dP", one), ("P", n + 1.0), ("d2P", one), ("dP", n + 1.0), ("dP", n + 2.0),
                       ("P", (n + 1.0) * (n + 2.0)), ("mPc", m)])
    quadrature = matrix([("mPc", one), ("dmPc", one), ("mPc", n + 2.0), ("dP", m), ("P", m * (n + 1.0))])
    return in_phase, quadrature


@dataclass(frozen=True)
class GeocentricPoint:
    """A geodetic point in geocentric spherical terms: ``s``, ``c`` the sine and cosine of the
    geocentric latitude phi', ``r`` the radius (m), ``cos_psi``, ``sin_psi`` of ``psi = phi' - phi``,
    ``meridian_plus_h`` the meridian radius of curvature plus the altitude (m)."""

    s: float
    c: float
    r: float
    cos_psi: float
    sin_psi: float
    meridian_plus_h: float


def geocentric_point(lat_deg: float, alt_m: float) -> GeocentricPoint:
    """Geodetic latitude and altitude on WGS84 -> :class:`GeocentricPoint`."""
    phi = math.radians(lat_deg)
    sin_phi, cos_phi = math.sin(phi), math.cos(phi)
    w2 = 1.0 - _WGS84_E2 * sin_phi * sin_phi
    prime_vertical = _WGS84_A_M / math.sqrt(w2)
    p = (prime_vertical + alt_m) * cos_phi
    z = (prime_vertical * (1.0 - _WGS84_E2) + alt_m) * sin_phi
    r = math.hypot(p, z)
    s, c = z / r, p / r
    return GeocentricPoint(s, c, r, c * cos_phi + s * sin_phi, s * cos_phi - c * sin_phi,
                           prime_vertical * (1.0 - _WGS84_E2) / w2 + alt_m)


def field_and_slopes_from_sums(a_sums, b_sums, point: GeocentricPoint) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X, Y, Z) in nT, geodetic north/east/down, and its derivatives along geodetic latitude and
    longitude (nT per radian), from the twelve geocentric sums of a model at ``point``.

    ``a_sums`` (in-phase, ``k = (a/r)^(n+2) (g cos m lon + h sin m lon)``): sum k dP/dphi',
    sum (n+1) k P, sum k d2P/dphi'2, sum (n+1) k dP/dphi', sum (n+2) k dP/dphi',
    sum (n+1)(n+2) k P, sum m k (m P / c); ``b_sums`` (quadrature, ``q = (a/r)^(n+2)
    (g sin m lon - h cos m lon)``): sum q (m P / c), sum q d(m P / c)/dphi', sum (n+2) q (m P / c),
    sum m q dP/dphi', sum m (n+1) q P. Then X' = -a0, Z' = -a1, Y' = b0, and the module
    docstring's chain rule through phi', r and psi."""
    cos_psi, sin_psi, r = point.cos_psi, point.sin_psi, point.r
    x_p, z_p, y_p = -a_sums[0], -a_sums[1], b_sums[0]
    dphi_prime = point.meridian_plus_h * cos_psi / r       # dphi'/dphi
    dr_over_r = point.meridian_plus_h * sin_psi / r        # (dr/dphi) / r
    dx_p = -a_sums[2] * dphi_prime + a_sums[4] * dr_over_r
    dz_p = -a_sums[3] * dphi_prime + a_sums[5] * dr_over_r
    dy_p = b_sums[1] * dphi_prime - b_sums[2] * dr_over_r
    x = x_p * cos_psi - z_p * sin_psi
    z_down = x_p * sin_psi + z_p * cos_psi
    dpsi = dphi_prime - 1.0
    lx, ly, lz = b_sums[3], a_sums[6], b_sums[4]
    return (np.array([x, y_p, z_down]),
            np.array([dx_p * cos_psi - dz_p * sin_psi - z_down * dpsi, dy_p,
                      dx_p * sin_psi + dz_p * cos_psi + x * dpsi]),
            np.array([lx * cos_psi - lz * sin_psi, ly, lx * sin_psi + lz * cos_psi]))


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
        # for ned_and_slopes: Q, Q', Q'' in one product, the six basis rows U_j (below), and the
        # sums over them as matrices (one per power of s) of the term constants
        ddq_poly = _polynomial_derivative(dq_poly)
        self._q_dq_ddq_poly_t = np.ascontiguousarray(np.vstack([q_poly, dq_poly, ddq_poly]).T)
        self._u_c_columns = np.stack([m_idx, m_idx + 1, m_idx + 2, np.maximum(m_idx - 1, 0),
                                      np.maximum(m_idx - 2, 0), m_idx])
        self._u_q_rows = np.array([0, 1, 2, 0, 0, 1])
        self._slope_in_phase, self._slope_quadrature = _slope_matrices(m_idx.astype(float), n_idx.astype(float))
        # cos and sin (cos of m lon - pi/2) per order m = 0..12, gathered to the 90 terms by m; powers
        # of c and of a/r per exponent, gathered to the terms: each value computed once, not per term
        orders = np.arange(WMM_DEGREE + 1, dtype=float)
        self._orders_float = orders
        self._trig_orders = np.stack([orders, orders])
        self._trig_phase = np.array([[0.0], [0.5 * math.pi]])
        self._c_exponents = np.arange(WMM_DEGREE + 3)              # c^0 .. c^14 (the basis rows' m + 2 at most)
        self._radial_exponents = np.arange(WMM_DEGREE + 3)         # (a/r)^0 .. (a/r)^14 (n + 2 at most)
        for array in (self._coeffs, self._q_poly_t, self._dq_poly_t, self._q_dq_poly_t, self._q_dq_ddq_poly_t,
                      self._slope_in_phase, self._slope_quadrature):
            array.setflags(write=False)
        self._gh_dt: float | None = None
        self._gh = np.zeros((2, 2, m_idx.size))

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
        c_powers = np.power(c, self._c_exponents)     # each power once, gathered to the terms
        m_p_over_c = self._m_float * c_powers[self._m_minus_1] * q
        p_nm = c_powers[self._m] * q
        dp_nm = c_powers[self._m_plus_1] * dq_ds - s * m_p_over_c

        radial = np.power(REFERENCE_RADIUS_M / r, self._radial_exponents)[self._radial_power]
        angles = math.radians(lon_deg) * self._orders_float
        cos_ml, sin_ml = np.cos(angles)[self._m], np.sin(angles)[self._m]
        in_phase = radial * (g * cos_ml + h * sin_ml)
        quadrature = radial * (g * sin_ml - h * cos_ml)
        x_prime = -float(in_phase @ dp_nm)
        y_prime = float(quadrature @ m_p_over_c)
        z_prime = -float(in_phase @ (self._n_plus_1 * p_nm))

        cos_psi = c * cos_phi + s * sin_phi
        sin_psi = s * cos_phi - c * sin_phi
        return x_prime * cos_psi - z_prime * sin_psi, y_prime, x_prime * sin_psi + z_prime * cos_psi

    def _gh_matrix(self, dt_years: float) -> np.ndarray:
        """``[[g, h], [-h, g]]`` at ``dt_years`` after the epoch (2 x 2 x 90): times (cos, sin)
        of m lon it gives the in-phase and quadrature factors. The last one is kept: a mission
        asks at one date."""
        if dt_years != self._gh_dt:
            g, h = self._coeffs[:2] + dt_years * self._coeffs[2:]
            gh = np.array([[g, h], [-h, g]])
            gh.setflags(write=False)
            self._gh, self._gh_dt = gh, dt_years
        return self._gh

    def ned_and_slopes(self, lat_deg: float, lon_deg: float, alt_m: float,
                       dt_years: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, Y, Z) in nT at one point and its derivatives along geodetic latitude and longitude
        in nT per radian: three arrays of 3, from one evaluation of the sums (module docstring).

        Every function the sums need (P, m P / c, their phi' derivatives, dP and d2P) is a
        combination of six basis rows ``U = (c^m Q, c^(m+1) Q', c^(m+2) Q'', c^(m-1) Q,
        c^(m-2) Q, c^m Q')`` with coefficients in n, m and powers of s, so the twelve sums are
        two matrix products with constant matrices (:func:`_slope_matrices`) and a polynomial
        in s. The field agrees with :meth:`ned_scalar` to rounding; the slopes with central
        differences of it to the differences' own error (tests)."""
        point = geocentric_point(lat_deg, alt_m)
        s, c, r = point.s, point.c, point.r

        q_all = (np.power(s, self._powers) @ self._q_dq_ddq_poly_t).reshape(3, self._m.size)   # Q, Q', Q''
        u = np.power(c, self._c_exponents)[self._u_c_columns] * q_all[self._u_q_rows]   # (6, 90)
        trig = np.cos(math.radians(lon_deg) * self._trig_orders - self._trig_phase)[:, self._m]  # cos, sin of m lon
        # in-phase (a/r)^(n+2) (g cos + h sin) and quadrature (a/r)^(n+2) (g sin - h cos)
        gh = self._gh_matrix(dt_years)
        factors = (gh[:, 0] * trig[0] + gh[:, 1] * trig[1]) * np.power(
            REFERENCE_RADIUS_M / r, self._radial_exponents)[self._radial_power]
        a = (self._slope_in_phase @ (u * factors[0]).ravel()).reshape(3, -1)
        b = (self._slope_quadrature @ (u * factors[1]).ravel()).reshape(3, -1)
        ss = s * s
        # in-phase sums: X', Z', dX'/dphi', dZ'/dphi', r dX'/dr, r dZ'/dr, dY'/dlon (signs below);
        # quadrature sums: Y', dY'/dphi', r dY'/dr, dX'/dlon, dZ'/dlon
        return field_and_slopes_from_sums((a[0] + s * a[1] + ss * a[2]).tolist(),
                                          (b[0] + s * b[1] + ss * b[2]).tolist(), point)

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
