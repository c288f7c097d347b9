"""The confidence ellipse of a horizontal position estimate, on the map.

A 2-D Gaussian with covariance ``C`` (north-north, north-east, east-east; m^2) holds probability
``p`` inside ``x^T C^-1 x <= k^2`` with ``k^2 = -2 ln(1 - p)``: the chi-square quantile of 2
degrees of freedom in closed form (5.991 for 95 %). The semi-axes are ``k sqrt(lambda_i)`` along
the eigenvectors of ``C``.

>>> round(chi2_2dof(0.95), 3)
5.991
>>> a = ellipse_axes((400.0**2, 0.0, 100.0**2), 0.95)
>>> round(a.semi_major_m), round(a.semi_minor_m), round(math.degrees(a.major_azimuth_rad))
(979, 245, 0)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.nav.geo import offset_position

__all__ = ["EllipseAxes", "chi2_2dof", "ellipse_axes", "ellipse_points"]


def chi2_2dof(p: float) -> float:
    """The ``p``-quantile of the chi-square distribution with 2 degrees of freedom."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"probability {p!r} not in (0, 1)")
    return -2.0 * math.log1p(-p)


@dataclass(frozen=True)
class EllipseAxes:
    semi_major_m: float
    semi_minor_m: float
    major_azimuth_rad: float     # of the major axis, from north clockwise, in [0, pi)


def _matrix(cov_ne_m2: tuple[float, float, float]) -> np.ndarray:
    nn, ne, ee = (float(v) for v in cov_ne_m2)
    mat = np.array([[nn, ne], [ne, ee]])
    if not np.all(np.isfinite(mat)) or nn < 0.0 or ee < 0.0 or nn * ee - ne * ne < -1e-9 * max(nn * ee, 1.0):
        raise ValueError(f"not a covariance (north-north, north-east, east-east m^2): {cov_ne_m2!r}")
    return mat


def ellipse_axes(cov_ne_m2: tuple[float, float, float], p: float = 0.95) -> EllipseAxes:
    """Semi-axes (m) and the major axis's azimuth of the ``p`` confidence ellipse of ``cov_ne_m2``."""
    values, vectors = np.linalg.eigh(_matrix(cov_ne_m2))     # ascending
    k = math.sqrt(chi2_2dof(p))
    north, east = vectors[:, 1]
    return EllipseAxes(k * math.sqrt(max(values[1], 0.0)), k * math.sqrt(max(values[0], 0.0)),
                       math.atan2(east, north) % math.pi)


def ellipse_points(lat_deg: float, lon_deg: float, cov_ne_m2: tuple[float, float, float], p: float = 0.95,
                   count: int = 48) -> list[tuple[float, float]]:
    """The ellipse about (``lat_deg``, ``lon_deg``) as ``count`` + 1 (lat, lon) points, closed."""
    axes = ellipse_axes(cov_ne_m2, p)
    t = np.linspace(0.0, 2.0 * math.pi, count + 1)
    t[-1] = 0.0   # closed exactly
    major, minor = axes.semi_major_m * np.cos(t), axes.semi_minor_m * np.sin(t)
    az = axes.major_azimuth_rad    # the major axis's unit vector (east, north) = (sin az, cos az)
    east = major * math.sin(az) + minor * math.cos(az)
    north = major * math.cos(az) - minor * math.sin(az)
    lat, lon = offset_position(lat_deg, lon_deg, east, north)
    return [(float(a), float(b)) for a, b in zip(lat, lon)]
