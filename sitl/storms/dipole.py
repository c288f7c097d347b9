"""The centred dipole of the main field at an epoch: its north pole, geomagnetic (dipole) coordinates, and
the rotation of a field change from dipole axes (north towards the dipole's north pole) to
geographic axes.

The dipole's north geomagnetic pole is where the axis of the degree-1 field meets the northern
hemisphere: colatitude ``theta0 = acos(-g10 / B0)`` and longitude ``phi0 = atan2(-h11, -g11)``,
``B0 = sqrt(g10^2 + g11^2 + h11^2)`` (IGRF-14 coefficients at the epoch, linear within their
5-year interval; e.g. Laundal and Richmond 2017, Space Sci. Rev. 206, "Magnetic coordinate
systems", section 3.1). Geomagnetic coordinates are the spherical coordinates about that axis, the
geomagnetic longitude counted from the meridian through the geographic south pole (0 at the
half-plane containing the geographic poles on the far side of the dipole pole), as in those
definitions.

The dipole declination at a point, ``delta``, is the azimuth (east of geographic north) of the
great circle towards the dipole's north pole: the angle between geographic and geomagnetic north.
A change ``(n_m, e_m, d)`` in dipole axes is ``(n_m cos delta - e_m sin delta, n_m sin delta +
e_m cos delta, d)`` in geographic north, east, down (the vertical is the same). Points are on the
sphere (geocentric latitude): the ellipsoid moves a station's latitude by up to 0.2 degrees,
below the 0.1-degree precision of the geomagnetic coordinates the GEM files carry.

The pole of an event's epoch is a column of the storm table (``dipole_pole``; the storm modules
read no field model): for the Halloween storm IGRF-14's at 2003.83, which a test recomputes from
the IGRF-14 coefficients.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from sitl.storms.common import FloatArray

__all__ = ["dipole_declination_deg", "dipole_pole_deg", "geographic_from_geomagnetic", "rotate_dipole_to_geographic"]


def dipole_pole_deg(g10: float, g11: float, h11: float) -> tuple[float, float]:
    """(latitude, longitude) in degrees of the north dipole pole of degree-1 Gauss coefficients (nT).

    >>> [round(v, 2) for v in dipole_pole_deg(-29404.8, -1450.9, 4652.5)]   # IGRF 2020.0
    [80.59, -72.68]
    """
    b0 = math.sqrt(g10 ** 2 + g11 ** 2 + h11 ** 2)
    return 90.0 - math.degrees(math.acos(-g10 / b0)), math.degrees(math.atan2(-h11, -g11))


def _pole_rotation(pole_deg: tuple[float, float]) -> np.ndarray:
    """Rotation taking geographic unit vectors to geomagnetic ones (rows: the geomagnetic axes)."""
    lat0, lon0 = np.radians(pole_deg)
    z = np.array([np.cos(lat0) * np.cos(lon0), np.cos(lat0) * np.sin(lon0), np.sin(lat0)])
    y = np.cross([0.0, 0.0, 1.0], z)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    return np.array([x, y, z])


def _unit(lat_deg: ArrayLike, lon_deg: ArrayLike) -> np.ndarray:
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)


def geographic_from_geomagnetic(mlat_deg: ArrayLike, mlon_deg: ArrayLike,
                                pole_deg: tuple[float, float]) -> tuple[FloatArray, FloatArray]:
    """Geographic (latitude, longitude in -180..180) of geomagnetic (dipole) coordinates about the
    north dipole pole ``pole_deg`` (lat, lon)."""
    v = _unit(mlat_deg, mlon_deg) @ _pole_rotation(pole_deg)
    return np.degrees(np.arcsin(np.clip(v[..., 2], -1.0, 1.0))), np.degrees(np.arctan2(v[..., 1], v[..., 0]))


def dipole_declination_deg(lat_deg: ArrayLike, lon_deg: ArrayLike, pole_deg: tuple[float, float]) -> FloatArray:
    """Azimuth (degrees east of geographic north) of the dipole's north pole ``pole_deg`` seen from each point."""
    plat, plon = np.radians(pole_deg)
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    dlon = plon - lon
    return np.degrees(np.arctan2(np.sin(dlon) * np.cos(plat),
                                 np.cos(lat) * np.sin(plat) - np.sin(lat) * np.cos(plat) * np.cos(dlon)))


def rotate_dipole_to_geographic(n_m: ArrayLike, e_m: ArrayLike, delta_deg: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Geographic (north, east) of a horizontal change given in dipole axes at dipole declination ``delta_deg``.

    >>> [round(float(v), 6) for v in rotate_dipole_to_geographic(1.0, 0.0, 90.0)]
    [0.0, 1.0]
    """
    d = np.radians(delta_deg)
    n, e = np.asarray(n_m, dtype=np.float64), np.asarray(e_m, dtype=np.float64)
    return n * np.cos(d) - e * np.sin(d), n * np.sin(d) + e * np.cos(d)
