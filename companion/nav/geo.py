"""Geodesy for the navigation plane: WGS84 geodesics and small local east/north offsets.

Long distances (remaining distance, path length, the reference track) are geodesics from
geographiclib. Within one control step (a few km) the MPC works in a local tangent plane,
x east and y north in metres (see :mod:`companion`); :func:`enu_offset` and
:func:`offset_position` convert with the WGS84 radii of curvature, exact to first order
and accurate to centimetres over a few kilometres.
"""
from __future__ import annotations

import math

import numpy as np
from geographiclib.geodesic import Geodesic

__all__ = [
    "WGS84",
    "geodesic_distance_m",
    "geodesic_inverse",
    "geodesic_direct",
    "radii_of_curvature_m",
    "enu_offset",
    "offset_position",
]

WGS84 = Geodesic.WGS84
_A = WGS84.a
_E2 = WGS84.f * (2.0 - WGS84.f)


def radii_of_curvature_m(lat_deg: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Meridian radius M and prime-vertical radius N (metres) at geodetic latitude."""
    s2 = np.sin(np.radians(lat_deg)) ** 2
    w = np.sqrt(1.0 - _E2 * s2)
    return _A * (1.0 - _E2) / w**3, _A / w


def metres_per_degree(lat_deg: float | np.ndarray, alt_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(east metres per degree of longitude, north metres per degree of latitude)."""
    m, n = radii_of_curvature_m(lat_deg)
    return (
        np.radians(1.0) * (n + alt_m) * np.cos(np.radians(lat_deg)),
        np.radians(1.0) * (m + alt_m),
    )


def enu_offset(lat0_deg: float, lon0_deg: float, lat_deg, lon_deg) -> tuple[np.ndarray, np.ndarray]:
    """Local (east_m, north_m) of positions relative to a reference, tangent at the reference."""
    east_per_deg, north_per_deg = metres_per_degree(lat0_deg)
    dlon = (np.asarray(lon_deg) - lon0_deg + 180.0) % 360.0 - 180.0
    return dlon * east_per_deg, (np.asarray(lat_deg) - lat0_deg) * north_per_deg


def offset_position(lat_deg: float, lon_deg: float, east_m, north_m) -> tuple[np.ndarray, np.ndarray]:
    """Position displaced by a local (east_m, north_m) from (lat_deg, lon_deg)."""
    east_per_deg, north_per_deg = metres_per_degree(lat_deg)
    lat = lat_deg + np.asarray(north_m) / north_per_deg
    lon = (lon_deg + np.asarray(east_m) / east_per_deg + 180.0) % 360.0 - 180.0
    return lat, lon


def geodesic_inverse(lat1_deg: float, lon1_deg: float, lat2_deg: float, lon2_deg: float) -> tuple[float, float]:
    """(distance_m, initial course_rad from north clockwise) of the geodesic from 1 to 2."""
    g = WGS84.Inverse(lat1_deg, lon1_deg, lat2_deg, lon2_deg, Geodesic.DISTANCE | Geodesic.AZIMUTH)
    return g["s12"], math.radians(g["azi1"]) % (2.0 * math.pi)


def geodesic_distance_m(lat1_deg: float, lon1_deg: float, lat2_deg: float, lon2_deg: float) -> float:
    """Geodesic distance in metres."""
    return WGS84.Inverse(lat1_deg, lon1_deg, lat2_deg, lon2_deg, Geodesic.DISTANCE)["s12"]


def geodesic_direct(lat_deg: float, lon_deg: float, course_rad: float, distance_m: float) -> tuple[float, float]:
    """End point (lat_deg, lon_deg) after distance_m along the geodesic starting at course_rad."""
    g = WGS84.Direct(lat_deg, lon_deg, math.degrees(course_rad), distance_m, Geodesic.LATITUDE | Geodesic.LONGITUDE)
    return g["lat2"], (g["lon2"] + 180.0) % 360.0 - 180.0
