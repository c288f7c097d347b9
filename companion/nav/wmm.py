"""The World Magnetic Model (and WMMHR): NOAA ``.COF`` coefficient files, validity span, field elements.

The navigation state is the pair of magnetic elements ``S = (D, I)`` of the paper's eq. 1-2,
declination ``D = atan2(Y, X)`` (positive east of true north) and inclination
``I = atan2(Z, H)`` (positive down), both in degrees, with ``X`` north, ``Y`` east, ``Z`` down
and ``H = hypot(X, Y)`` in nanotesla (see :mod:`companion`). :class:`WorldMagneticModel` reads a
coefficient file once and evaluates broadcast arrays with :class:`~companion.nav.harmonics.HarmonicSums`.
By default the coefficient files are the copies shipped inside the ``pygeomag`` package, so the
vehicle needs no other data at run time. Nothing here reads a clock.
"""
from __future__ import annotations

import datetime
import math
import os
from dataclasses import dataclass
from functools import cache
from importlib import resources

import numpy as np
from numpy.typing import ArrayLike

from companion.nav.harmonics import WMM_DEGREE, HarmonicSums, schmidt_polynomials
from companion.nav.highdegree import HighDegreeSums

__all__ = ["KEPT_EVALUATIONS", "MAP_WMMHR", "WMM2025_SWITCH_YEAR", "WMM_NAMES", "FieldElements", "WorldMagneticModel", "load_wmm",
           "model_for_date", "model_for_setting"]

WMM2025_SWITCH_YEAR = 2024.87
"""Decimal year from which :func:`model_for_date` uses WMM2025 (released 2024-11-13)."""

WMM_NAMES = {1: "WMM2020", 2: "WMM2025"}
"""The models NAV_WMM forces (0: by date, :func:`model_for_setting`)."""

KEPT_EVALUATIONS = 4
"""Exact one-point evaluations (:meth:`WorldMagneticModel.ned_and_slopes`) a model keeps: enough
for one control step's window centre, the fix's iterates after it, and the update back at the
centre (with the INS's attitude, :mod:`companion.nav.navfilter`)."""

# Points per block in the array path: keeps the (points x 90) temporaries inside the CPU cache.
_BLOCK = 128

_PYGEOMAG_FILES = {"WMM2020": "WMM_2020.COF", "WMM2025": "WMM_2025.COF", "WMMHR2025": "WMMHR_2025.COF"}

MAP_WMMHR = 1
"""NAV_MAP's value for WMMHR-2025 (0: the WMM, NAV_WMM picks which)."""

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

        Every (n, m) pair with 1 <= n <= degree, 0 <= m <= n must be present; the degree is the
        file's (12 for the WMM, 133 for WMMHR: :class:`~companion.nav.highdegree.HighDegreeSums`). With
        ``allow_extrapolation`` the model evaluates any year (linear secular variation, which
        degrades quickly outside the 5-year span); otherwise years outside
        [valid_from, valid_until) raise ValueError.
        """
        self.name = name
        self.epoch = float(epoch)
        self.valid_until = self.epoch + 5.0
        self.valid_from = self.epoch if release_year is None else min(self.epoch, float(release_year))
        self.allow_extrapolation = bool(allow_extrapolation)

        rows = np.asarray(coefficients, dtype=float).reshape(-1, 6)
        self._rows = rows.copy()
        self.degree = degree = max(WMM_DEGREE, int(rows[:, 0].max()) if rows.size else 0)
        table = np.zeros((4, degree + 1, degree + 1))
        seen = np.zeros((degree + 1, degree + 1), dtype=bool)
        for n, m, *values in rows:
            n, m = int(n), int(m)
            if not (1 <= n and 0 <= m <= n):
                raise ValueError(f"{name}: coefficient (n={n}, m={m}) outside 1 <= n, 0 <= m <= n")
            table[:, n, m] = values
            seen[n, m] = True
        n_all, m_all = np.tril_indices(degree + 1)
        if not seen[n_all[n_all >= 1], m_all[n_all >= 1]].all():
            raise ValueError(f"{name}: coefficient file lacks some of the (n, m) pairs up to degree {degree}")
        if degree == WMM_DEGREE:
            n_idx, m_idx, _, _ = schmidt_polynomials(WMM_DEGREE)
            self._sums = HarmonicSums(table[:, n_idx, m_idx])
        else:   # WMMHR: the stable recursion (the degree-12 polynomials do not hold at degree 133)
            self._sums = HighDegreeSums(table)
        self._recent_slopes: dict[tuple[float, float, float, float], tuple] = {}

    @classmethod
    def from_cof(cls, path: str | os.PathLike[str], allow_extrapolation: bool = False) -> WorldMagneticModel:
        """Load a NOAA ``.COF`` file (header ``epoch name release-date``, rows ``n m g h gd hd``)."""
        with open(path, encoding="ascii") as handle:
            text = handle.read()
        epoch, name, release_year, rows = _parse_cof(text, os.fspath(path))
        return cls(name, epoch, rows, release_year, allow_extrapolation)

    def band(self, min_degree: int, max_degree: int | None = None) -> WorldMagneticModel:
        """This model's degrees ``min_degree`` to ``max_degree`` (default: its top) alone, at its
        epoch, without secular variation, valid at any year: e.g. WMMHR-2025's degrees 16-133, the
        crust's long wavelengths (:mod:`companion.nav.crust`).

        >>> round(float(load_wmm("WMMHR2025").band(16).ned(-38.0, 164.0, 0.0, 2030.0)[2]), 1)   # nT down
        -47.9
        """
        rows = self._rows.copy()
        top = self.degree if max_degree is None else max_degree
        rows[(rows[:, 0] < min_degree) | (rows[:, 0] > top), 2:4] = 0.0
        rows[:, 4:] = 0.0
        return WorldMagneticModel(f"{self.name} n{min_degree}-{top}", self.epoch, rows, allow_extrapolation=True)

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

    def ned_and_slopes(self, lat_deg: float, lon_deg: float, alt_m: float,
                       year: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, Y, Z) in nT at one point and its exact derivatives along geodetic latitude and
        longitude, nT per radian (:meth:`HarmonicSums.ned_and_slopes`), as read-only arrays.
        The last :data:`KEPT_EVALUATIONS` answers are kept: a step asks at the window centre for
        the filter's update, the geomagnetic fix starts there, and its iterates come between."""
        key = (float(lat_deg), float(lon_deg), float(alt_m), float(year))
        recent = self._recent_slopes
        answer = recent.get(key)
        if answer is not None:
            return answer
        if abs(lat_deg) > 90.0:
            raise ValueError(f"latitude {lat_deg} deg outside [-90, 90]")
        self._check_year(key[3])
        answer = self._sums.ned_and_slopes(key[0], key[1], key[2], key[3] - self.epoch)
        for array in answer:
            array.setflags(write=False)
        if len(recent) >= KEPT_EVALUATIONS:
            # the oldest (dicts keep their insertion order); pop, not del: the route's prediction
            # (companion.process.forecast, a thread of its own) evaluates the same model as the
            # control step, and both may drop the same oldest answer (a KeyError in the step)
            recent.pop(next(iter(recent), None), None)
        recent[key] = answer
        return answer

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
        return _elements_from_ned(*self.ned(lat_deg, lon_deg, alt_m, year))

    def ned(
        self, lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike, year: ArrayLike
    ) -> tuple[float | np.ndarray, float | np.ndarray, float | np.ndarray]:
        """(X, Y, Z) in nT, north/east/down: :meth:`elements`' first three, without the others
        (the simulator's truth field wants the vector alone); the same arguments and errors."""
        scalar_alt_year = isinstance(alt_m, _SCALAR_TYPES) and isinstance(year, _SCALAR_TYPES)
        if scalar_alt_year and isinstance(lat_deg, _SCALAR_TYPES) and isinstance(lon_deg, _SCALAR_TYPES):
            if abs(lat_deg) > 90.0:
                raise ValueError(f"latitude {lat_deg} deg outside [-90, 90]")
            self._check_year(float(year))
            return self._sums.ned_scalar(float(lat_deg), float(lon_deg), float(alt_m), float(year) - self.epoch)
        if (scalar_alt_year and isinstance(lat_deg, np.ndarray) and isinstance(lon_deg, np.ndarray)
                and lat_deg.ndim == 1 and lat_deg.shape == lon_deg.shape and 0 < lat_deg.size <= _BLOCK):
            # a few points at one altitude and date (the fix's stencil): one block, no broadcasting
            lat, lon = lat_deg.astype(float, copy=False), lon_deg.astype(float, copy=False)
            if np.abs(lat).max() > 90.0:
                raise ValueError(f"latitude outside [-90, 90]: {lat[np.abs(lat) > 90.0][0]} deg")
            self._check_year(float(year))
            return self._sums.ned(lat, lon, float(alt_m), float(year) - self.epoch)

        lat, lon, alt, yr = np.broadcast_arrays(
            *(np.asarray(v, dtype=float) for v in (lat_deg, lon_deg, alt_m, year))
        )
        if (np.abs(lat) > 90.0).any():
            raise ValueError(f"latitude outside [-90, 90]: {lat[np.abs(lat) > 90.0].ravel()[0]} deg")
        self._check_year(yr)
        shape = lat.shape
        lat, lon, alt, yr = (v.ravel() for v in (lat, lon, alt, yr))
        x, y, z = (np.empty(lat.size) for _ in range(3))
        for start in range(0, lat.size, _BLOCK):
            block = slice(start, start + _BLOCK)
            x[block], y[block], z[block] = self._sums.ned(lat[block], lon[block], alt[block], yr[block] - self.epoch)
        return x.reshape(shape), y.reshape(shape), z.reshape(shape)


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
    """The model ``"WMM2020"``, ``"WMM2025"`` or ``"WMMHR2025"`` (WMMHR-2025, degree 133) from
    the coefficient files shipped with pygeomag (cached).

    The returned model refuses years outside its span; build one with
    ``WorldMagneticModel.from_cof(path, allow_extrapolation=True)`` to extrapolate.
    """
    key = name.upper().replace("-", "").replace("_", "")
    if key not in _PYGEOMAG_FILES:
        raise ValueError(f"unknown model {name!r}; expected one of {sorted(_PYGEOMAG_FILES)}")
    return _load_shipped(key)


@cache
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


def model_for_setting(year: float, wmm: int, nav_map: int = 0) -> WorldMagneticModel:
    """The model the settings ask for: NAV_MAP ``nav_map`` 0 the WMM, whose NAV_WMM ``wmm`` 0 picks
    it by the date ``year`` (NAV_YEAR, :func:`model_for_date`), 1 WMM2020, 2 WMM2025
    (:data:`WMM_NAMES`); NAV_MAP 1 (:data:`MAP_WMMHR`) WMMHR-2025, degree 133, which holds the
    crust's wavelengths down to 300 km. WMMHR-2025 covers 2024.87-2030.0 (released 2024-11-13,
    epoch 2025.0): an earlier date raises ValueError rather than running its secular variation
    backwards (a mission before its release flies the WMM of its date, as a vehicle then did).

    >>> model_for_setting(2025.5, 0, 1).name
    'WMMHR2025'
    """
    if int(nav_map) == MAP_WMMHR:
        model = load_wmm("WMMHR2025")
        if not model.valid_from <= year < model.valid_until:
            raise ValueError(f"WMMHR2025 covers {model.valid_from:.2f}..{model.valid_until:.2f}, not NAV_YEAR {year:g} "
                             "(NAV_MAP 1): the map is not extrapolated; fly NAV_MAP 0 (the WMM) or a later date")
        return model
    return model_for_date(year, WMM_NAMES.get(int(wmm)))
