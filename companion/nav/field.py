"""World Magnetic Model (WMM) and the geomagnetic position fix.

The navigation state is the pair of magnetic elements ``S = (D, I)`` of the paper's eq. 1-2,
declination ``D = atan2(Y, X)`` (positive east of true north) and inclination
``I = atan2(Z, H)`` (positive down), both in degrees, with ``X`` north, ``Y`` east, ``Z`` down
and ``H = hypot(X, Y)`` in nanotesla (see :mod:`companion`). This module provides

* :class:`WorldMagneticModel`: a numpy evaluator of NOAA ``.COF`` coefficient files (degree 12
  spherical harmonics with linear secular variation), following the algorithm of the WMM
  technical report (Chulliat et al., *The US/UK World Magnetic Model for 2020-2025*, NOAA NCEI):
  geodetic to geocentric spherical coordinates, time-adjusted Gauss coefficients, the field sums
  of Schmidt semi-normalised associated Legendre functions, and the rotation back to the geodetic
  (ellipsoidal) north/east/down frame. It evaluates broadcast arrays.
* :func:`decl_incl_gradient`: the Jacobian ``G = d(D, I)/d(east, north)`` in degrees per metre.
* :func:`geomagnetic_fix`: the geomagnetic position (lambda_c, phi_c) of the paper's eq. 49, the
  point whose model (D, I) equals a measured (D, I), found by Newton iteration from a prior.

The model is pure: the coefficient file is read once when a model is built, and nothing here
reads a clock. By default the coefficient files are the copies shipped inside the ``pygeomag``
package, so the vehicle needs no other data at run time.
"""
from __future__ import annotations

import datetime
import math
import os
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import numpy as np
from numpy.typing import ArrayLike

from companion.nav.elements import ELEMENT_SETS, ElementSet
from companion.nav.geo import offset_position

__all__ = [
    "WMM_DEGREE",
    "WMM2025_SWITCH_YEAR",
    "FieldElements",
    "WorldMagneticModel",
    "load_wmm",
    "model_for_date",
    "decl_incl_gradient",
    "element_gradient",
    "element_fix",
    "PositionFix",
    "PositionFixError",
    "geomagnetic_fix",
]

WMM_DEGREE = 12
"""Maximum spherical-harmonic degree (and order) of the standard WMM."""

WMM2025_SWITCH_YEAR = 2024.87
"""Decimal year from which :func:`model_for_date` uses WMM2025 (released 2024-11-13)."""

# WGS84 ellipsoid and the geomagnetic reference radius a = 6371200 m of the WMM technical report.
_WGS84_A_M = 6378137.0
_WGS84_F = 1.0 / 298.257223563
_WGS84_E2 = _WGS84_F * (2.0 - _WGS84_F)
_REFERENCE_RADIUS_M = 6371200.0

# Points per block in the array path: keeps the (points x 90) temporaries inside the CPU cache.
_BLOCK = 128

_PYGEOMAG_FILES = {"WMM2020": "WMM_2020.COF", "WMM2025": "WMM_2025.COF"}

# Arguments of these types take the scalar path of WorldMagneticModel.elements (floats out).
_SCALAR_TYPES = (float, int, np.floating, np.integer)


@dataclass(frozen=True)
class FieldElements:
    """Magnetic field elements at one or many points (floats, or arrays of the broadcast shape).

    ``x_nt``, ``y_nt``, ``z_nt``: north, east, down components in the geodetic NED frame, nT.
    ``h_nt``: horizontal intensity ``hypot(X, Y)``, nT. ``f_nt``: total intensity, nT.
    ``decl_deg``: declination ``D = atan2(Y, X)`` (paper eq. 1), degrees, positive east, (-180, 180].
    ``incl_deg``: inclination ``I = atan2(Z, H)`` (paper eq. 2), degrees, positive down.
    """

    x_nt: float | np.ndarray
    y_nt: float | np.ndarray
    z_nt: float | np.ndarray
    h_nt: float | np.ndarray
    f_nt: float | np.ndarray
    decl_deg: float | np.ndarray
    incl_deg: float | np.ndarray


def _decimal_year(date: datetime.date) -> float:
    start = datetime.date(date.year, 1, 1)
    days_in_year = (datetime.date(date.year + 1, 1, 1) - start).days
    return date.year + (date - start).days / days_in_year


def _schmidt_polynomials(degree: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
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


def _parse_cof(text: str, source: str) -> tuple[float, str, float | None, np.ndarray]:
    """(epoch, name, release decimal year or None, rows of n m g h g_dot h_dot) of a .COF text."""
    lines = [line for line in text.splitlines() if line.strip()]
    if not lines:
        raise ValueError(f"{source}: empty coefficient file")
    header = lines[0].split()
    try:
        epoch = float(header[0])
        name = header[1].replace("-", "")
    except (IndexError, ValueError) as exc:
        raise ValueError(f"{source}: bad header line {lines[0]!r}") from exc
    release_year = None
    if len(header) >= 3:
        try:
            release_year = _decimal_year(datetime.datetime.strptime(header[2], "%m/%d/%Y").date())
        except ValueError:
            release_year = None
    rows = []
    for line in lines[1:]:
        if line.startswith("9999"):
            break
        fields = line.split()
        if len(fields) != 6:
            raise ValueError(f"{source}: expected 'n m g h g_dot h_dot', got {line!r}")
        rows.append([float(v) for v in fields])
    return epoch, name, release_year, np.array(rows)


class WorldMagneticModel:
    """A World Magnetic Model loaded from a NOAA ``.COF`` coefficient file.

    Attributes: ``name`` (``"WMM2020"``), ``epoch`` (decimal year of the coefficients, 2020.0),
    ``valid_from`` (decimal year), ``valid_until`` (``epoch + 5``, exclusive).

    ``valid_from`` is the epoch, or the release date when that is earlier (WMM2025: released
    2024-11-13 = 2024.866, epoch 2025.0): NOAA replaces the previous model from the release, and
    :func:`model_for_date` hands out WMM2025 from :data:`WMM2025_SWITCH_YEAR`.
    """

    def __init__(
        self,
        name: str,
        epoch: float,
        coefficients: np.ndarray,
        release_year: float | None = None,
        allow_extrapolation: bool = False,
    ) -> None:
        """Build from rows ``(n, m, g_nT, h_nT, g_dot_nT_per_year, h_dot_nT_per_year)``.

        All 90 (n, m) pairs with 1 <= n <= 12, 0 <= m <= n must be present. With
        ``allow_extrapolation`` the model evaluates any year (linear secular variation, which
        degrades quickly outside the 5-year span); otherwise years outside
        [valid_from, valid_until) raise ValueError.
        """
        self.name = name
        self.epoch = float(epoch)
        self.valid_until = self.epoch + 5.0
        self.valid_from = self.epoch if release_year is None else min(self.epoch, float(release_year))
        self.allow_extrapolation = bool(allow_extrapolation)

        n_idx, m_idx, q_poly, dq_poly = _schmidt_polynomials(WMM_DEGREE)
        table = np.zeros((4, WMM_DEGREE + 1, WMM_DEGREE + 1))
        seen = np.zeros((WMM_DEGREE + 1, WMM_DEGREE + 1), dtype=bool)
        rows = np.asarray(coefficients, dtype=float).reshape(-1, 6)
        for n, m, *values in rows:
            n, m = int(n), int(m)
            if not (1 <= n <= WMM_DEGREE and 0 <= m <= n):
                raise ValueError(f"{name}: coefficient (n={n}, m={m}) outside degree {WMM_DEGREE}")
            table[:, n, m] = values
            seen[n, m] = True
        if not seen[n_idx, m_idx].all():
            raise ValueError(f"{name}: coefficient file lacks some of the {n_idx.size} (n, m) pairs")
        g, h, g_dot, h_dot = table[:, n_idx, m_idx]

        # Per-term constants, one entry per (n, m), in the order of _schmidt_polynomials.
        self._m = m_idx
        self._q_poly_t = np.ascontiguousarray(q_poly.T)  # (13, 90): powers of s -> Q_n^m
        self._dq_poly_t = np.ascontiguousarray(dq_poly.T)
        self._coeffs = np.stack([g, h, g_dot, h_dot])
        self._m_float = m_idx.astype(float)
        self._n_plus_1 = n_idx + 1.0
        # column of c**(m-1); for m = 0 any column will do, the term is multiplied by m = 0
        self._m_minus_1 = np.maximum(m_idx - 1, 0)
        self._radial_power = n_idx + 2  # (a/r)**(n+2)
        self._powers = np.arange(WMM_DEGREE + 1)
        self._q_dq_poly_t = np.ascontiguousarray(np.hstack([self._q_poly_t, self._dq_poly_t]))
        for array in (self._coeffs, self._q_poly_t, self._dq_poly_t, self._q_dq_poly_t):
            array.setflags(write=False)

    @classmethod
    def from_cof(cls, path: str | os.PathLike[str], allow_extrapolation: bool = False) -> WorldMagneticModel:
        """Load a NOAA ``.COF`` file (header ``epoch name release-date``, rows ``n m g h gd hd``)."""
        with open(path, encoding="ascii") as handle:
            text = handle.read()
        epoch, name, release_year, rows = _parse_cof(text, os.fspath(path))
        return cls(name, epoch, rows, release_year, allow_extrapolation)

    def __repr__(self) -> str:
        return (
            f"WorldMagneticModel({self.name!r}, epoch={self.epoch}, valid {self.valid_from:.3f}"
            f"..{self.valid_until}, allow_extrapolation={self.allow_extrapolation})"
        )

    def _check_year(self, year: np.ndarray | float) -> None:
        """Raise ValueError unless every year is in [valid_from, valid_until) (NaN is outside)."""
        if self.allow_extrapolation:
            return
        if isinstance(year, float):
            if self.valid_from <= year < self.valid_until:
                return
            bad = year
        else:
            outside = ~((year >= self.valid_from) & (year < self.valid_until))
            if not outside.any():
                return
            bad = year[outside].ravel()[0]
        raise ValueError(
            f"{self.name} is valid for decimal years [{self.valid_from:.3f}, {self.valid_until:.1f}); "
            f"got {bad}. Use model_for_date() to pick the model, or allow_extrapolation=True."
        )

    def elements(
        self, lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike, year: ArrayLike
    ) -> FieldElements:
        """Field elements at geodetic positions and decimal years (all arguments broadcast).

        ``lat_deg``, ``lon_deg``: WGS84 geodetic degrees; ``alt_m``: metres above the WGS84
        ellipsoid (the WMM is specified for -1 km to 850 km); ``year``: decimal year. Returns
        floats when every argument is a scalar, arrays of the broadcast shape otherwise. NaN
        positions give NaN elements; a latitude beyond +-90 degrees or a year outside the model's
        span raises ValueError.
        """
        if all(isinstance(v, _SCALAR_TYPES) for v in (lat_deg, lon_deg, alt_m, year)):
            if abs(lat_deg) > 90.0:
                raise ValueError(f"latitude {lat_deg} deg outside [-90, 90]")
            self._check_year(float(year))
            xyz = self._field_ned_scalar(float(lat_deg), float(lon_deg), float(alt_m), float(year))
            return _elements_from_ned(*xyz)

        lat, lon, alt, yr = np.broadcast_arrays(
            *(np.asarray(v, dtype=float) for v in (lat_deg, lon_deg, alt_m, year))
        )
        if np.any(np.abs(lat) > 90.0):
            raise ValueError(f"latitude outside [-90, 90]: {lat[np.abs(lat) > 90.0].ravel()[0]} deg")
        self._check_year(yr)
        shape = lat.shape
        lat, lon, alt, yr = (v.ravel() for v in (lat, lon, alt, yr))
        x, y, z = (np.empty(lat.size) for _ in range(3))
        for start in range(0, lat.size, _BLOCK):
            block = slice(start, start + _BLOCK)
            x[block], y[block], z[block] = self._field_ned(lat[block], lon[block], alt[block], yr[block])
        return _elements_from_ned(x.reshape(shape), y.reshape(shape), z.reshape(shape))

    def _field_ned_scalar(
        self, lat_deg: float, lon_deg: float, alt_m: float, year: float
    ) -> tuple[float, float, float]:
        """(X, Y, Z) in nT at one point: :meth:`_field_ned` with math for the geometry and one
        numpy call per step over the 90 terms, about half the time of a one-point array call."""
        phi = math.radians(lat_deg)
        sin_phi, cos_phi = math.sin(phi), math.cos(phi)
        prime_vertical = _WGS84_A_M / math.sqrt(1.0 - _WGS84_E2 * sin_phi * sin_phi)
        p = (prime_vertical + alt_m) * cos_phi
        z = (prime_vertical * (1.0 - _WGS84_E2) + alt_m) * sin_phi
        r = math.hypot(p, z)
        s, c = z / r, p / r

        g, h = self._coeffs[:2] + (year - self.epoch) * self._coeffs[2:]
        q_and_dq = np.power(s, self._powers) @ self._q_dq_poly_t
        q, dq_ds = q_and_dq[: self._m.size], q_and_dq[self._m.size :]
        m_p_over_c = self._m_float * np.power(c, self._m_minus_1) * q
        p_nm = np.power(c, self._m) * q
        dp_nm = np.power(c, self._m + 1) * dq_ds - s * m_p_over_c

        radial = np.power(_REFERENCE_RADIUS_M / r, self._radial_power)
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

    def _field_ned(
        self, lat_deg: np.ndarray, lon_deg: np.ndarray, alt_m: np.ndarray, year: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, Y, Z) in nT, geodetic north/east/down, for 1-D arrays (the WMM report's algorithm)."""
        phi = np.radians(lat_deg)
        lam = np.radians(lon_deg)
        sin_phi, cos_phi = np.sin(phi), np.cos(phi)

        # 1. Geodetic -> geocentric spherical: prime-vertical radius, then r and phi'.
        prime_vertical = _WGS84_A_M / np.sqrt(1.0 - _WGS84_E2 * sin_phi * sin_phi)
        p = (prime_vertical + alt_m) * cos_phi
        z = (prime_vertical * (1.0 - _WGS84_E2) + alt_m) * sin_phi
        r = np.hypot(p, z)
        s, c = z / r, p / r  # sin(phi'), cos(phi')

        # 2. Time-adjusted Gauss coefficients g(t) = g(t0) + (t - t0) g_dot, one row per point.
        dt = (year - self.epoch)[:, None]
        g0, h0, g_dot, h_dot = self._coeffs
        g = g0 + dt * g_dot
        h = h0 + dt * h_dot

        # 3. Legendre functions P = c**m Q(s); m P / cos(phi') = m c**(m-1) Q stays finite at the
        # poles, so the east sum needs neither a division by cos(phi') nor a pole special case.
        s_powers = s[:, None] ** self._powers
        q = s_powers @ self._q_poly_t
        dq_ds = s_powers @ self._dq_poly_t
        c_powers = c[:, None] ** np.arange(WMM_DEGREE + 2)
        m_p_over_c = c_powers[:, self._m_minus_1] * self._m_float * q
        p_nm = c_powers[:, self._m] * q
        # dP/dphi' = c dP/ds = c**(m+1) dQ/ds - m s c**(m-1) Q
        dp_nm = c_powers[:, self._m + 1] * dq_ds - s[:, None] * m_p_over_c

        radial = (_REFERENCE_RADIUS_M / r)[:, None] ** self._radial_power
        angles = lam[:, None] * np.arange(WMM_DEGREE + 1)
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


def _elements_from_ned(x: float | np.ndarray, y: float | np.ndarray, z: float | np.ndarray) -> FieldElements:
    """The seven elements from X, Y, Z (nT); D and I per the paper's eq. 1-2, in degrees."""
    if isinstance(x, float):
        h = math.hypot(x, y)
        return FieldElements(
            x, y, z, h, math.hypot(h, z), math.degrees(math.atan2(y, x)), math.degrees(math.atan2(z, h))
        )
    h = np.hypot(x, y)
    f = np.hypot(h, z)
    return FieldElements(x, y, z, h, f, np.degrees(np.arctan2(y, x)), np.degrees(np.arctan2(z, h)))


def load_wmm(name: str) -> WorldMagneticModel:
    """The model ``"WMM2020"`` or ``"WMM2025"`` from the coefficient files shipped with pygeomag (cached).

    The returned model refuses years outside its span; build one with
    ``WorldMagneticModel.from_cof(path, allow_extrapolation=True)`` to extrapolate.
    """
    key = name.upper().replace("-", "").replace("_", "")
    if key not in _PYGEOMAG_FILES:
        raise ValueError(f"unknown model {name!r}; expected one of {sorted(_PYGEOMAG_FILES)}")
    return _load_shipped(key)


@lru_cache(maxsize=None)
def _load_shipped(key: str) -> WorldMagneticModel:
    resource = resources.files("pygeomag").joinpath("wmm").joinpath(_PYGEOMAG_FILES[key])
    with resources.as_file(resource) as path:
        model = WorldMagneticModel.from_cof(path)
    if model.name != key:
        raise ValueError(f"{path} holds {model.name}, expected {key}")
    return model


def model_for_date(year: float, override: str | None = None) -> WorldMagneticModel:
    """The WMM to use at a decimal year: WMM2020 before 2024.87, WMM2025 from then on.

    WMM2025 was released on 2024-11-13 (decimal year 2024.87) and replaces WMM2020 from that
    day, so the paper's epoch 2024.36 uses WMM2020. ``override`` (``"WMM2020"``/``"WMM2025"``)
    forces a model whatever the year. Without it, a year no model covers raises ValueError.
    """
    if override is not None:
        return load_wmm(override)
    if not math.isfinite(year):
        raise ValueError(f"decimal year must be finite, got {year}")
    model = load_wmm("WMM2020" if year < WMM2025_SWITCH_YEAR else "WMM2025")
    if not model.valid_from <= year < model.valid_until:
        raise ValueError(
            f"no World Magnetic Model covers decimal year {year}: WMM2020 from "
            f"{load_wmm('WMM2020').valid_from:.3f}, WMM2025 until {load_wmm('WMM2025').valid_until:.1f}"
        )
    return model


def _elements_and_gradient(
    model: WorldMagneticModel, lat_deg: float, lon_deg: float, alt_m: float, year: float, step_m: float,
    elements: ElementSet = ELEMENT_SETS[ElementSet.PAPER],
) -> tuple[np.ndarray, np.ndarray]:
    """The two elements S at the point and G = dS/d(east, north) per metre, from one model call.

    Central differences over +-step_m east and north in the local tangent plane; the error is
    O(step^2) times the third derivative, negligible for the smooth degree-12 field at 500 m.
    Declination differences are wrapped, so G stays right where D crosses +-180 degrees.
    """
    east = np.array([0.0, step_m, -step_m, 0.0, 0.0])
    north = np.array([0.0, 0.0, 0.0, step_m, -step_m])
    lats, lons = offset_position(lat_deg, lon_deg, east, north)
    values = elements.values(model.elements(lats, lons, alt_m, year))   # (2, 5)
    span = 2.0 * step_m
    gradient = np.stack([elements.difference(values[:, 1], values[:, 2]),
                         elements.difference(values[:, 3], values[:, 4])], axis=1) / span
    return values[:, 0].copy(), gradient


def element_gradient(
    model: WorldMagneticModel,
    elements: ElementSet,
    lat_deg: float,
    lon_deg: float,
    alt_m: float,
    year: float,
    step_m: float = 500.0,
) -> np.ndarray:
    """Jacobian ``G = dS/d(east, north)`` of an element set's S, per metre (rows in the set's order)."""
    if not (math.isfinite(step_m) and step_m > 0.0):
        raise ValueError(f"step_m must be a positive number of metres, got {step_m}")
    return _elements_and_gradient(model, lat_deg, lon_deg, alt_m, year, step_m, elements)[1]


def decl_incl_gradient(
    model: WorldMagneticModel,
    lat_deg: float,
    lon_deg: float,
    alt_m: float,
    year: float,
    step_m: float = 500.0,
) -> np.ndarray:
    """Jacobian ``G = d(D, I)/d(east, north)`` at a position, in degrees per metre.

    Rows (D, I), columns (east, north) of the MPC's local plane (x east, y north, metres), by
    central differences of +-``step_m`` metres (:func:`companion.nav.geo.offset_position`), all
    four points in one vectorised model call. Declination differences are wrapped, so G stays
    right where D crosses +-180 degrees. :func:`element_gradient` on the paper's element set.
    """
    return element_gradient(model, ELEMENT_SETS[ElementSet.PAPER], lat_deg, lon_deg, alt_m, year, step_m)


class PositionFixError(RuntimeError):
    """The geomagnetic position fix failed: no convergence, ill-conditioned gradient or bad input."""


@dataclass(frozen=True)
class PositionFix:
    """A geomagnetic position fix (the paper's (lambda_c, phi_c), eq. 49).

    ``lat_deg``, ``lon_deg``: WGS84 degrees. ``iterations``: Newton steps taken.
    ``residual_deg``: norm of the element residual at the fix, in the elements' units (degrees
    for (D, I); mixed degrees and nT for (I, F)). ``condition``: 2-norm
    condition number of G at the fix (large means one direction is poorly observable).
    ``gradient``: the model's G at the fix, element units per metre (rows in the element set's
    order; columns east, north): an element error e maps to a position error G^-1 e.
    """

    lat_deg: float
    lon_deg: float
    iterations: int
    residual_deg: float
    condition: float
    gradient: np.ndarray | None = None


def _condition_2x2(g: np.ndarray) -> float:
    """2-norm condition number of a 2x2 matrix (closed form; inf when singular, NaN propagates)."""
    a, b, c, d = (float(v) for v in g.ravel())
    frobenius2 = a * a + b * b + c * c + d * d
    det = abs(a * d - b * c)
    if det == 0.0:
        return math.inf
    # sigma_max / sigma_min from sigma1^2 + sigma2^2 = |G|_F^2 and sigma1 * sigma2 = |det G|
    ratio = frobenius2 / (2.0 * det)
    return ratio + math.sqrt(max(ratio * ratio - 1.0, 0.0))


# Beyond this latitude the local east/north plane (and the +-step gradient) degenerates.
_MAX_FIX_LAT_DEG = 89.5


def geomagnetic_fix(
    model: WorldMagneticModel,
    decl_deg: float,
    incl_deg: float,
    prior_lat_deg: float,
    prior_lon_deg: float,
    alt_m: float,
    year: float,
    **newton: float,
) -> PositionFix:
    """The position whose model (D, I) equals the measured (D, I): the paper's eq. 49.

    :func:`element_fix` on the paper's element set; ``newton`` are its iteration settings
    (``max_iter``, ``tol_m``, ``max_step_m``, ``max_condition``, ``step_m``).
    """
    return element_fix(model, ELEMENT_SETS[ElementSet.PAPER], (decl_deg, incl_deg), prior_lat_deg,
                       prior_lon_deg, alt_m, year, **newton)


def element_fix(
    model: WorldMagneticModel,
    elements: ElementSet,
    target: ArrayLike,
    prior_lat_deg: float,
    prior_lon_deg: float,
    alt_m: float,
    year: float,
    max_iter: int = 20,
    tol_m: float = 1.0,
    max_step_m: float = 200e3,
    max_condition: float = 1e6,
    step_m: float = 500.0,
) -> PositionFix:
    """The position whose model elements equal the measured ``target`` (eq. 49 on any element set).

    Newton iteration on the square system ``S(p) = target`` in the local east/north plane,
    starting at the prior position: at each iterate p solve ``G dp = -r`` with the residual
    ``r = S(p) - target`` (declination wrapped) and G from :func:`element_gradient`, shorten dp
    to at most ``max_step_m`` metres, and move with :func:`companion.nav.geo.offset_position`.
    It has converged once a step is shorter than ``tol_m`` metres; the fix is the position after
    that step, with its residual and condition.

    Element contours can cross more than once on the globe; the iteration finds the crossing the
    prior leads to, so the prior should be within a few hundred km. Raises PositionFixError for
    non-finite inputs, when cond(G) exceeds ``max_condition`` (the two contours nearly parallel:
    the fix is unobservable along one direction), when an iterate nears a geographic pole, or
    when ``max_iter`` steps do not converge (e.g. a pair the field never takes nearby).
    A year outside the model's span raises the model's ValueError.
    """
    target = np.asarray(target, dtype=float)
    inputs = {
        **dict(zip(elements.names, (float(v) for v in target))), "prior_lat_deg": prior_lat_deg,
        "prior_lon_deg": prior_lon_deg, "alt_m": alt_m, "year": year,
    }
    bad = {k: v for k, v in inputs.items() if not math.isfinite(v)}
    if bad:
        raise PositionFixError(f"geomagnetic fix needs finite inputs, got {bad}")
    if max_iter < 1 or not (tol_m > 0.0 and max_step_m > 0.0 and step_m > 0.0):
        raise ValueError(
            f"need max_iter >= 1 and positive tol_m, max_step_m, step_m; got {max_iter}, {tol_m}, "
            f"{max_step_m}, {step_m}"
        )
    if abs(prior_lat_deg) > _MAX_FIX_LAT_DEG:
        raise PositionFixError(
            f"prior latitude {prior_lat_deg} deg is too close to a pole for the local east/north plane"
        )

    lat, lon = float(prior_lat_deg), float(prior_lon_deg)
    last_step_m = math.inf
    for iteration in range(max_iter + 1):
        values, gradient = _elements_and_gradient(model, lat, lon, alt_m, year, step_m, elements)
        residual = elements.difference(values, target)
        residual_norm = math.hypot(*residual)
        condition = _condition_2x2(gradient)
        where = f"at ({lat:.6f}, {lon:.6f}) deg after {iteration} iterations, residual {residual_norm:.3g}"
        if not condition <= max_condition:  # also catches NaN
            raise PositionFixError(
                f"gradient ill-conditioned (condition {condition:.3g} > {max_condition:.3g}) {where}"
            )
        if last_step_m < tol_m:
            return PositionFix(lat, lon, iteration, residual_norm, condition, gradient)
        if iteration == max_iter:
            break
        step = np.linalg.solve(gradient, -residual)
        last_step_m = math.hypot(*step)
        if last_step_m > max_step_m:
            step *= max_step_m / last_step_m
        new_lat, new_lon = offset_position(lat, lon, step[0], step[1])
        lat, lon = float(new_lat), float(new_lon)
        if abs(lat) > _MAX_FIX_LAT_DEG:
            raise PositionFixError(f"iterate reached latitude {lat:.3f} deg, too close to a pole; {where}")
    raise PositionFixError(
        f"no convergence within {max_iter} iterations: {where}, last Newton step {last_step_m:.3g} m "
        f"(target {elements.label} = {tuple(float(v) for v in target)})"
    )
