"""Spherical-harmonic sums of a high-degree field model (WMMHR-2025: degree 133), stable at any degree.

The degree-12 sums of :mod:`companion.nav.harmonics` write the Legendre functions as
polynomials in ``s = sin(phi')``; at degree 133 those polynomials' coefficients pass 1e40 and
their sum cancels to noise. Here the Schmidt semi-normalised functions come from the standard
three-term recursion in the degree (the WMM technical report's, stable at any degree)::

    P_m^m = sqrt(1 - 1/(2m)) c P_(m-1)^(m-1)          (P_0^0 = 1, P_1^1 = c)
    P_n^m = ((2n - 1) s P_(n-1)^m - sqrt((n-1)^2 - m^2) P_(n-2)^m) / sqrt(n^2 - m^2)

solved for every (n, m) of one point at once as a lower-triangular banded system (LAPACK
``dtbtrs``: forward substitution, exactly the recursion, one call), with
``s = sin(phi') = cos(theta)``, ``c = cos(phi') = sin(theta)``. Derivatives along the
colatitude need no division by ``c``: ``dP_n^m/dtheta = (sqrt((n+m)(n-m+1)) P_n^(m-1) -
sqrt((n-m)(n+m+1)) P_n^(m+1)) / 2`` (the m = 0 and m = 1 rows carry sqrt(2) from the
semi-normalisation), applied twice for the second derivative; ``m P / c`` divides by ``c``
(floored at 1e-12 at the poles, where ``P_n^m`` holds ``c^m``). The sums, the geodetic
conversion and the chain rule of the slopes are :mod:`companion.nav.harmonics`' own
(:func:`~companion.nav.harmonics.field_and_slopes_from_sums`).

Cost at degree 133 (9045 terms; tests/nav/test_wmmhr.py measures it): a few hundred
microseconds per point for the field, about twice that with the slopes.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dtbtrs

from companion.nav.harmonics import REFERENCE_RADIUS_M, field_and_slopes_from_sums, geocentric_point

__all__ = ["HighDegreeSums"]

_POLE_FLOOR = 1e-12   # cos(phi') at the poles: m P / c stays finite (P holds c^m)


class HighDegreeSums:
    """The field sums of one coefficient set to degree N: ``table[0..3, n, m]`` = g, h, g_dot,
    h_dot (nT, nT/year; zero where absent), evaluated at ``year - epoch``. The interface of
    :class:`companion.nav.harmonics.HarmonicSums` (``ned_scalar``, ``ned``, ``ned_and_slopes``).

    The (n, m) terms are kept in one flat vector ordered by order then degree (m = 0: n = 0..N,
    m = 1: n = 1..N, ...), the order in which the recursion in n is a banded system."""

    def __init__(self, table: np.ndarray) -> None:
        table = np.array(table, dtype=float)
        if table.ndim != 3 or table.shape[0] != 4 or table.shape[1] != table.shape[2]:
            raise ValueError(f"coefficient table of shape {table.shape}, expected (4, N + 1, N + 1)")
        self.degree = size = table.shape[1] - 1
        m_idx = np.concatenate([np.full(size + 1 - m, m) for m in range(size + 1)])
        n_idx = np.concatenate([np.arange(m, size + 1) for m in range(size + 1)])
        n, m = n_idx.astype(float), m_idx.astype(float)
        first = n_idx == m_idx                          # each order's sectoral term P_m^m
        self._first = np.flatnonzero(first)
        root = np.sqrt(np.where(first, 1.0, n * n - m * m))
        # band storage of the lower-triangular system: row 0 the diagonal (1), row 1 the term of
        # P_(n-1)^m in the equation of P_n^m (-a s, at the column of P_(n-1)^m), row 2 P_(n-2)^m's (b)
        self._a = np.zeros(n.size)
        self._a[:-1] = np.where(first[1:], 0.0, -(2.0 * n[1:] - 1.0) / root[1:])
        self._b = np.zeros(n.size)
        second_on = ~first[2:] & ~first[1:-1]
        self._b[:-2] = np.where(second_on, np.sqrt(np.maximum((n[2:] - 1.0) ** 2 - m[2:] ** 2, 0.0)) / root[2:], 0.0)
        self._band = np.zeros((3, n.size), order="F")
        self._band[0] = 1.0
        self._sectoral_factor = np.array([1.0, 1.0] + [math.sqrt(1.0 - 0.5 / k) for k in range(2, size + 1)]).cumprod()
        self._orders = np.arange(size + 1, dtype=float)
        # dP/dtheta = up * P_n^(m-1) - down * P_n^(m+1): gathers into the flat vector, with a
        # zero slot at the end for terms outside m <= n
        position = {(int(a), int(b)): j for j, (a, b) in enumerate(zip(n_idx, m_idx))}
        zero = n.size
        self._up_at = np.array([position.get((a, b - 1), zero) for a, b in zip(n_idx, m_idx)])
        self._down_at = np.array([position.get((a, b + 1), zero) for a, b in zip(n_idx, m_idx)])
        up = 0.5 * np.sqrt(np.maximum((n + m) * (n - m + 1.0), 0.0)) * np.where(m_idx == 1, math.sqrt(2.0), 1.0)
        down = 0.5 * np.sqrt(np.maximum((n - m) * (n + m + 1.0), 0.0)) * np.where(m_idx == 0, math.sqrt(2.0), 1.0)
        self._up = np.where(self._up_at < zero, up, 0.0)
        self._down = np.where(self._down_at < zero, down, 0.0)
        self._n_plus_1, self._m, self._m_idx = n + 1.0, m, m_idx
        self._radial_power = n + 2.0
        self._coeffs = table[:, n_idx, m_idx]           # (4, terms)
        self._gh_dt: float | None = None
        self._gh = self._coeffs[:2]

    def _legendre(self, s: float, c: float) -> np.ndarray:
        """P_n^m (Schmidt semi-normalised) of every term at one point, with one zero slot appended."""
        band = self._band
        band[1] = self._a * s
        band[2] = self._b
        rhs = np.zeros((self._a.size, 1))
        rhs[self._first, 0] = self._sectoral_factor * c ** self._orders
        solution, info = dtbtrs(band, rhs, uplo="L")
        if info != 0:
            raise ArithmeticError(f"Legendre recursion failed (LAPACK dtbtrs info {info})")
        return np.append(solution[:, 0], 0.0)

    def _d_theta(self, p: np.ndarray) -> np.ndarray:
        """d/dtheta of the functions ``p`` (flat, zero slot appended): the recurrence in m."""
        return np.append(self._up * p[self._up_at] - self._down * p[self._down_at], 0.0)

    def _gh_at(self, dt_years: float) -> np.ndarray:
        if dt_years != self._gh_dt:
            self._gh = self._coeffs[:2] + dt_years * self._coeffs[2:]
            self._gh_dt = dt_years
        return self._gh

    def _sums(self, lat_deg: float, lon_deg: float, alt_m: float, dt_years: float, slopes: bool):
        """The geocentric point and the in-phase and quadrature sums of
        :func:`field_and_slopes_from_sums` (the first two and the first alone without ``slopes``)."""
        point = geocentric_point(lat_deg, alt_m)
        legendre = self._legendre(point.s, point.c)
        p = legendre[:-1]
        dp = -self._d_theta(legendre)                   # d/dphi' = -d/dtheta
        g, h = self._gh_at(dt_years)
        angles = math.radians(lon_deg) * self._orders
        cos_ml, sin_ml = np.cos(angles)[self._m_idx], np.sin(angles)[self._m_idx]
        radial = (REFERENCE_RADIUS_M / point.r) ** self._radial_power
        k = radial * (g * cos_ml + h * sin_ml)
        q = radial * (g * sin_ml - h * cos_ml)
        c_floor = max(point.c, _POLE_FLOOR)
        m_p_c = self._m * p / c_floor
        kn1 = k * self._n_plus_1
        if not slopes:
            return point, [float(k @ dp[:-1]), float(kn1 @ p)], [float(q @ m_p_c)]
        d2p = self._d_theta(-dp)[:-1]                   # d2/dphi'2 = d2/dtheta2
        dp = dp[:-1]
        d_m_p_c = self._m * (dp / c_floor + p * point.s / (c_floor * c_floor))   # d(m P / c)/dphi'
        qm = q * self._m
        a_sums = [k @ dp, kn1 @ p, k @ d2p, kn1 @ dp, (kn1 + k) @ dp, (kn1 * (self._n_plus_1 + 1.0)) @ p,
                  (k * self._m) @ m_p_c]
        b_sums = [q @ m_p_c, q @ d_m_p_c, (q * (self._n_plus_1 + 1.0)) @ m_p_c, qm @ dp, (qm * self._n_plus_1) @ p]
        return point, [float(v) for v in a_sums], [float(v) for v in b_sums]

    def ned_scalar(self, lat_deg: float, lon_deg: float, alt_m: float, dt_years: float) -> tuple[float, float, float]:
        """(X, Y, Z) in nT, geodetic north/east/down, at one point."""
        point, (a0, a1), (b0,) = self._sums(lat_deg, lon_deg, alt_m, dt_years, slopes=False)
        x_p, z_p = -a0, -a1
        return (x_p * point.cos_psi - z_p * point.sin_psi, b0, x_p * point.sin_psi + z_p * point.cos_psi)

    def ned(self, lat_deg: np.ndarray, lon_deg: np.ndarray, alt_m: np.ndarray | float,
            dt_years: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, Y, Z) in nT for 1-D arrays of points (``alt_m`` and ``dt_years`` arrays of the
        same length or floats): :meth:`ned_scalar` per point."""
        lat, lon = np.asarray(lat_deg, dtype=float), np.asarray(lon_deg, dtype=float)
        alt, dt = np.broadcast_to(alt_m, lat.shape), np.broadcast_to(dt_years, lat.shape)
        out = np.array([self.ned_scalar(float(a), float(b), float(c), float(d))
                        for a, b, c, d in zip(lat, lon, alt, dt)]).reshape(lat.shape + (3,))
        return out[..., 0], out[..., 1], out[..., 2]

    def ned_and_slopes(self, lat_deg: float, lon_deg: float, alt_m: float,
                       dt_years: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, Y, Z) in nT at one point and its exact derivatives along geodetic latitude and
        longitude, nT per radian (:func:`field_and_slopes_from_sums`)."""
        point, a_sums, b_sums = self._sums(lat_deg, lon_deg, alt_m, dt_years, slopes=True)
        return field_and_slopes_from_sums(a_sums, b_sums, point)
