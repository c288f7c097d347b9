"""The heading the vehicle flew, from its own magnetometer and accelerometer (no FC attitude).

A flight controller's yaw without GPS is a compass yaw through its own tilt estimate and its
declination table; measured on ArduPilot Rover SITL (motorboat, GPS denied, 360 s windows on
steady courses) it was 0.5-2.6 deg off the true heading, the error changing with the course,
because its tilt estimate wanders without GPS. The same window's *means* of the raw body-frame
field ``m`` and specific force ``f`` give the horizontal plane from gravity itself (waves and heave
average out of ``f`` on a steady course): with ``d = -f / |f|`` the down axis in the body frame,

    m_h = m - (m . d) d,    x_h = x - (x . d) d,    x = (1, 0, 0) (body forward)
    n = m_h / |m_h|,        e = d x n               (magnetic north and east, body frame)
    psi_m = atan2(x_h . e, x_h . n)                  (magnetic heading, clockwise from magnetic north)

and the true heading is ``psi_m + D`` with D from the field model at the estimated position
(:mod:`companion`'s convention: D positive east of true north, headings clockwise from north).
Measured there: ``psi_m`` plus WMM's D was 0.14 +- 0.01 deg off the true heading over 13 windows,
which is the difference between ArduPilot's declination table and WMM at that place; the
flight controller's own yaw was 0.8 deg off in the median, 2.6 deg at worst.

The means are taken over the samples the gravity-referenced inclination uses (not turning, not
settling after a new command: :class:`companion.nav.magnetometer.MagProcessor`), so the heading
is that of the period's steady part. Pure: vectors in, degrees out.

>>> round(levelled_heading_deg((20000.0 * 0.5, -20000.0 * 0.8660254, 40000.0), (0.0, 0.0, -9.81)), 6)
60.0
"""
from __future__ import annotations

import math

import numpy as np

from companion.frames import Vector3

__all__ = ["flown_velocity_en", "levelled_heading_deg", "window_heading_rad"]


def levelled_heading_deg(mag_body_nt: Vector3, force_body_mps2: Vector3) -> float:
    """Magnetic heading of body x (deg in (-180, 180], clockwise from magnetic north) from the
    mean body-frame field and specific force; NaN when either is zero or not finite, or the field
    is vertical (no horizontal component to point along)."""
    fx, fy, fz = (float(v) for v in force_body_mps2)
    norm_f = math.sqrt(fx * fx + fy * fy + fz * fz)
    if not (norm_f > 0.0 and math.isfinite(norm_f)):
        return math.nan
    d = (-fx / norm_f, -fy / norm_f, -fz / norm_f)
    m = tuple(float(v) for v in mag_body_nt)
    along = m[0] * d[0] + m[1] * d[1] + m[2] * d[2]
    mh = (m[0] - along * d[0], m[1] - along * d[1], m[2] - along * d[2])
    norm_h = math.sqrt(mh[0] * mh[0] + mh[1] * mh[1] + mh[2] * mh[2])
    if not (norm_h > 1e-9 * max(1.0, math.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])) and math.isfinite(norm_h)):
        return math.nan
    n = (mh[0] / norm_h, mh[1] / norm_h, mh[2] / norm_h)
    e = (d[1] * n[2] - d[2] * n[1], d[2] * n[0] - d[0] * n[2], d[0] * n[1] - d[1] * n[0])
    # x_h . n = x . n and x_h . e = x . e (n and e are horizontal): the first components
    return math.degrees(math.atan2(e[0], n[0]))


def flown_velocity_en(commanded_en_mps: np.ndarray, mag_heading_deg: float, decl_deg: float) -> np.ndarray:
    """The velocity (east, north, m/s) flown over a period: the commanded speed along the measured
    true heading ``mag_heading_deg + decl_deg``; the commanded velocity itself when the heading is
    not measured (NaN) or nothing was commanded.

    >>> [round(float(v), 6) for v in flown_velocity_en(np.array([0.0, 8.0]), 88.0, 2.0)]
    [8.0, 0.0]
    """
    commanded = np.asarray(commanded_en_mps, dtype=float)
    speed = float(np.hypot(*commanded))
    heading = mag_heading_deg + decl_deg
    if not (math.isfinite(heading) and speed > 0.0):
        return commanded
    course = math.radians(heading)
    return np.array([speed * math.sin(course), speed * math.cos(course)])


def window_heading_rad(meas, vel_en_mps: np.ndarray | None = None, min_speed_mps: float = 0.5) -> float:
    """The true heading held over a measured window (rad from north) for the navigation filter's
    heading states: ``meas.mag_heading_deg`` plus the window's measured declination
    ``meas.decl_deg``, else the course of the velocity flown (east, north m/s) when faster than
    ``min_speed_mps``, else NaN (not known)."""
    heading = meas.mag_heading_deg + meas.decl_deg
    if math.isfinite(heading):
        return math.radians(heading)
    if vel_en_mps is not None and math.hypot(*vel_en_mps) > min_speed_mps:
        return math.atan2(float(vel_en_mps[0]), float(vel_en_mps[1]))
    return math.nan
