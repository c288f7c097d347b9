"""Fc-MPC companion: GPS-free geomagnetic + inertial navigation for a MAVLink vehicle.

Conventions, written once for the whole code base (``companion``, ``sitl``, ``scripts``):

Units
    SI in code: metres, seconds, metres per second, radians, tesla-free nanotesla for
    field components (``*_nt``). A name that carries a unit suffix overrides this:
    ``speed_kmh``, ``decl_deg``, ``lat_deg``, ``dist_km``. Times are seconds of *message
    or simulation time* (``time_s``); wall-clock time never enters ``companion.nav``.

Geodetic positions
    WGS84 latitude/longitude in degrees (``lat_deg``, ``lon_deg``), altitude in metres
    above the ellipsoid (``alt_m``). Distances and azimuths between positions are
    geodesics (geographiclib).

Frames
    n: local North-East-Down (NED) for field vectors and velocities at the link
       (MAVLink's frame): field vector ``(x_nt, y_nt, z_nt)`` = (north, east, down).
    b: body frame, x forward, y right, z down (MAVLink/ArduPilot/PX4).
    Local navigation plane of the MPC (paper Section 2.2): **x east, y north**, metres,
    tangent at the current estimated position; the paper's probing headings
    (theta_1, theta_2) = (0, 270) deg then mean east, then south.

Angles
    ``theta_rad``: the paper's heading (eq. 4), from +x (east) counter-clockwise.
    ``course_rad`` / ``yaw_rad``: navigation heading, from true north clockwise, in
    [0, 2*pi) -- what MAVLink carries. ``course = pi/2 - theta`` (mod 2*pi), converted only
    by :func:`course_from_theta` / :func:`theta_from_course`.

Magnetic elements (eq. 1-2)
    Declination D: angle from true north to the horizontal field, positive east
    (clockwise), ``D = atan2(Y, X)``. Inclination I: angle below the horizontal,
    positive down, ``I = atan2(Z, H)``. Both in degrees in the navigation state,
    ``S = (D, I)`` in degrees, because the paper's constraints (Table 4) are in degrees.

Gradient and MPC units (eq. 5-15)
    ``G`` is the Jacobian d(D, I)/d(x, y) in degrees per metre (rows D, I; columns east,
    north). The input ``U = (v_x, v_y)`` is in m/s, the control period ``T`` in s, so
    ``B = G T`` is in degrees per (m/s). See README "Units of the MPC" for the weights.
"""
from __future__ import annotations

import math

__all__ = ["course_from_theta", "theta_from_course", "wrap_2pi", "wrap_pi"]


def wrap_2pi(angle_rad: float) -> float:
    """Angle wrapped into [0, 2*pi)."""
    wrapped = math.fmod(angle_rad, 2.0 * math.pi)
    return wrapped + 2.0 * math.pi if wrapped < 0.0 else wrapped


def wrap_pi(angle_rad: float) -> float:
    """Angle wrapped into [-pi, pi)."""
    return wrap_2pi(angle_rad + math.pi) - math.pi


def course_from_theta(theta_rad: float) -> float:
    """Course (from north, clockwise, [0, 2*pi)) of the paper's heading theta (from east, CCW).

    >>> round(math.degrees(course_from_theta(math.radians(270.0))), 6)  # paper's theta_2: south
    180.0
    """
    return wrap_2pi(math.pi / 2.0 - theta_rad)


def theta_from_course(course_rad: float) -> float:
    """The paper's heading theta (from east, CCW, [0, 2*pi)) of a course (from north, clockwise)."""
    return wrap_2pi(math.pi / 2.0 - course_rad)
