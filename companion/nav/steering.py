"""The course to send a flight controller whose yaw is off the true heading.

A flight controller steers its *own* yaw (or velocity) estimate onto the commanded course, so the
vehicle's true heading is the command minus the estimate's yaw error ``delta``:

    psi_true = c_sent - delta,      delta = psi_fc - psi_true

Without GPS that error is not small. Measured on PX4 SITL (SIH rover, GPS lost, our position fed
as HIL_GPS): EKF2's yaw followed the fed track, and the true track ran 14-20 deg off the command
(the feed blends new estimates in at ``COMP_FEED_BLEND`` across a 3 m/s track, and EKF2's yaw
turns until its inertial velocity agrees); on ArduPilot Rover SITL EKF3's yaw was 0.4-2.9 deg off.

The companion measures the true heading itself (:mod:`companion.nav.heading`: the magnetometer
levelled by the accelerometer, so neither the FC's yaw nor its tilt enters; plus D from the field
model at the estimated position), so it can estimate ``delta`` and send

    c_sent = c + delta_hat,         |delta_hat| <= max_trim

``delta_hat`` is the circular mean of per-sample ``psi_fc - psi_m`` (FC yaw minus the levelled
magnetic heading of the same instant), weighted exponentially in message time (``tau_s``),
from samples taken while not turning; D is subtracted when the course is formed. In steady
state the loop does not feed back on itself: the fed track follows the navigator's course ``c``,
not ``c_sent``, so ``delta`` does not depend on the trim.

Angles: radians, headings and courses clockwise from true north (the project's convention);
``psi_m`` from magnetic north. Pure: samples and times in, angles out.

>>> t = YawOffsetTracker(tau_s=10.0)
>>> for k in range(200):   # FC yaw 10 deg; the field says the body points 60 deg east of magnetic north
...     _ = t.add(0.1 * k, math.radians(10.0), (20000.0 * 0.5, -20000.0 * 0.8660254, 40000.0), (0.0, 0.0, -9.81))
>>> round(math.degrees(t.offset_rad(19.9)), 6)       # psi_fc - psi_m
-50.0
>>> round(math.degrees(trimmed_course_rad(math.radians(90.0), t.offset_rad(19.9), -55.0, 30.0)), 6)
95.0
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from companion import wrap_2pi, wrap_pi
from companion.frames import Vector3
from companion.nav.heading import levelled_heading_deg

__all__ = ["YawOffsetTracker", "trimmed_course_rad"]


@dataclass
class YawOffsetTracker:
    """Running circular mean of the FC's yaw minus the levelled magnetic heading (rad).

    ``tau_s``: weight time constant (message time). ``max_age_s``: no offset once the newest
    sample is older (a stream stopped). ``min_span_s``: no offset before samples span this long.
    """

    tau_s: float = 20.0
    max_age_s: float = 5.0
    min_span_s: float = 5.0
    _cos: float = field(default=0.0, init=False)
    _sin: float = field(default=0.0, init=False)
    _first_s: float = field(default=math.nan, init=False)
    _last_s: float = field(default=math.nan, init=False)

    def add(self, time_s: float, fc_yaw_rad: float, mag_body_nt: Vector3, force_body_mps2: Vector3) -> bool:
        """One sample: the FC's yaw at ``time_s`` and the raw body field (nT) and specific force
        (m/s^2) of the same instant; False (ignored) when not finite or not levellable."""
        psi_m = levelled_heading_deg(mag_body_nt, force_body_mps2)
        if not (math.isfinite(time_s) and math.isfinite(fc_yaw_rad) and math.isfinite(psi_m)):
            return False
        gap = time_s - self._last_s if math.isfinite(self._last_s) else math.inf
        if gap < 0.0 or gap > 10.0 * self.tau_s:   # the first sample, a long gap, a clock that went
            keep, self._first_s = 0.0, time_s       # back (the FC rebooted): start again
        else:
            keep = math.exp(-gap / self.tau_s)
        offset = fc_yaw_rad - math.radians(psi_m)
        self._cos = keep * self._cos + math.cos(offset)
        self._sin = keep * self._sin + math.sin(offset)
        self._last_s = time_s
        return True

    def offset_rad(self, now_s: float) -> float:
        """``psi_fc - psi_m`` in [-pi, pi), or NaN without a recent, long enough record."""
        if not (math.isfinite(self._last_s) and now_s - self._last_s <= self.max_age_s
                and self._last_s - self._first_s >= self.min_span_s and math.hypot(self._cos, self._sin) > 0.0):
            return math.nan
        return wrap_pi(math.atan2(self._sin, self._cos))


def trimmed_course_rad(course_rad: float, fc_minus_magnetic_rad: float, decl_deg: float, max_trim_deg: float) -> float:
    """The course to send so the true heading is ``course_rad``: the course plus the FC's yaw
    error ``wrap(fc_minus_magnetic - D)``, clamped to ``max_trim_deg``; the course itself when
    the offset or D is not finite or ``max_trim_deg`` is 0. Result in [0, 2 pi)."""
    if not (max_trim_deg > 0.0 and math.isfinite(fc_minus_magnetic_rad) and math.isfinite(decl_deg)):
        return course_rad
    limit = math.radians(max_trim_deg)
    delta = min(max(wrap_pi(fc_minus_magnetic_rad - math.radians(decl_deg)), -limit), limit)
    return wrap_2pi(course_rad + delta)
