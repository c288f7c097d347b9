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

A new course. ``delta`` is not one number: EKF2's yaw error depends on the heading and on
whether the vehicle moves (PX4 SIH rover without GPS, 7 runs: -8..+7 deg, its step at a probe's
turn 0.4-4.9 deg, and after the start of motion it ramped by up to 7 deg at ~0.7 deg/s over the
first 5-16 s). A 20 s record kept the old heading's offset for 20-60 s after each change (the
true heading then peaked 4.3-6.5 deg off 13-15 s into probe 1). So the tracker is told of each
new commanded course or start of motion (:meth:`YawOffsetTracker.new_course`) and then

* restarts its record: samples of the old heading never enter the new one, and those
  stamped before the change (a late sample) are left out;
* holds the old offset until the fresh record spans ``fresh_min_span_s`` (2 s, about 100
  samples at 50 Hz): the offset just before the turn is the better guess for the new heading
  (measured: it was 0.4-4.9 deg off the new heading's, 0.6-7 deg for no trim at all), and the
  sent course does not step to the untrimmed one and back during the turn;
* weighs with ``fresh_tau_s`` (3 s) for ``fresh_s`` (60 s) after the change, the time EKF2's
  error took to settle, then with ``tau_s`` again. Noise: the exponential mean of per-sample
  noise sigma at rate f has sigma / sqrt(2 tau f): 5 deg at 50 Hz gives 0.29 deg with 3 s,
  0.22 deg with 5 s. Replayed open loop on the 7 runs' logs (estimate minus EKF2's true error,
  first 60 s of each probe), the worst error fell from 6.3 to 3.9 deg and the mean from 1.2 to
  0.8 deg; 2 s gave 3.6, 5 s 4.3 (the remaining ~2 deg is not lag: no shorter tau removes it).

``tau_s`` is 5 s, not 20 s, on a held course too: EKF2's error also wanders while the course is
held (once from -5 to +28 deg over 110 s, ~0.25 deg/s: a 20 s record lagged it by 5-6 deg and the
true track ran 7.2 deg off; replayed open loop there, the worst error of the estimate was 6.4 deg
with 20 s, 3.5 with 5 s). Replayed on the 7 baseline runs, +60..158 s of each probe: worst 3.4 deg
with 20 s, 2.7 with 10 s, 2.5 with 5 s.

The very first record (and one after a long gap or a clock that went back) has nothing to hold
and gives no offset before it spans ``min_span_s``: the course is sent untrimmed.

Who says "new course": :mod:`companion.process.control_step` for each new command judged by
:func:`is_new_course` (the first command, the start of motion from a commanded speed at or below
``MOVING_MPS`` = 0.3 m/s, or a course ``NEW_COURSE_DEG`` = 10 deg or more from the last one), and
:mod:`companion.process.phases` when the FC is following again after a hold (it starts moving).

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

__all__ = ["MOVING_MPS", "NEW_COURSE_DEG", "YawOffsetTracker", "is_new_course", "trimmed_course_rad"]

NEW_COURSE_DEG = 10.0   # a commanded course this far from the last one is a new course for the trim
MOVING_MPS = 0.3        # a commanded speed above this after one at or below it is the start of motion


@dataclass
class YawOffsetTracker:
    """Running circular mean of the FC's yaw minus the levelled magnetic heading (rad).

    Times are message times (s). ``tau_s``: weight time constant. ``max_age_s``: no offset once
    the newest sample is older (a stream stopped). ``min_span_s``: no offset before the first
    record spans this long. After :meth:`new_course`: a fresh record, weighted with
    ``fresh_tau_s`` for ``fresh_s``; the old offset is held until it spans ``fresh_min_span_s``.
    """

    tau_s: float = 5.0
    max_age_s: float = 5.0
    min_span_s: float = 5.0
    fresh_tau_s: float = 3.0
    fresh_s: float = 60.0
    fresh_min_span_s: float = 2.0
    _cos: float = field(default=0.0, init=False)
    _sin: float = field(default=0.0, init=False)
    _first_s: float = field(default=math.nan, init=False)
    _last_s: float = field(default=math.nan, init=False)
    _course_s: float = field(default=math.nan, init=False)     # message time of the last new course
    _held_rad: float = field(default=math.nan, init=False)     # the offset before it, until the fresh record spans

    def new_course(self, time_s: float) -> None:
        """A new commanded course or the start of motion at ``time_s``: the record starts again
        (the offset so far is held meanwhile) and is weighted with ``fresh_tau_s`` for ``fresh_s``."""
        if not math.isfinite(time_s):
            return
        held = self._value()
        self._held_rad = held if math.isfinite(held) else self._held_rad   # two changes in a row: the older holds
        self._cos = self._sin = 0.0
        self._first_s = math.nan
        self._course_s = time_s

    def add(self, time_s: float, fc_yaw_rad: float, mag_body_nt: Vector3, force_body_mps2: Vector3) -> bool:
        """One sample: the FC's yaw at ``time_s`` and the raw body field (nT) and specific force
        (m/s^2) of the same instant; False (ignored) when not finite, not levellable or stamped
        before the last new course."""
        psi_m = levelled_heading_deg(mag_body_nt, force_body_mps2)
        if not (math.isfinite(time_s) and math.isfinite(fc_yaw_rad) and math.isfinite(psi_m)):
            return False
        gap = time_s - self._last_s if math.isfinite(self._last_s) else math.inf
        if gap < 0.0 or gap > 10.0 * self.tau_s:   # the first sample, a long gap, a clock that went
            self._cos = self._sin = 0.0             # back (the FC rebooted): start again, nothing held
            self._first_s, self._course_s, self._held_rad = math.nan, math.nan, math.nan
        elif time_s < self._course_s:               # of the old course, arriving after the change
            return False
        fresh = math.isfinite(self._course_s) and time_s - self._course_s < self.fresh_s
        if math.isfinite(self._first_s):
            keep = math.exp(-gap / (self.fresh_tau_s if fresh else self.tau_s))
        else:
            keep, self._first_s = 0.0, time_s
        offset = fc_yaw_rad - math.radians(psi_m)
        self._cos = keep * self._cos + math.cos(offset)
        self._sin = keep * self._sin + math.sin(offset)
        self._last_s = time_s
        return True

    def _value(self) -> float:
        """The record's mean, or NaN while it spans less than its minimum (or is empty)."""
        span = self.fresh_min_span_s if math.isfinite(self._course_s) else self.min_span_s
        if not (math.isfinite(self._first_s) and self._last_s - self._first_s >= span
                and math.hypot(self._cos, self._sin) > 0.0):
            return math.nan
        return wrap_pi(math.atan2(self._sin, self._cos))

    def offset_rad(self, now_s: float) -> float:
        """``psi_fc - psi_m`` in [-pi, pi), or NaN without a recent, long enough record (nor an
        offset held from before a new course)."""
        if not (math.isfinite(self._last_s) and now_s - self._last_s <= self.max_age_s):
            return math.nan
        value = self._value()
        return value if math.isfinite(value) else self._held_rad


def is_new_course(previous: tuple[float, float] | None, course_rad: float, speed_mps: float) -> bool:
    """Whether the command ``(course_rad, speed_mps)`` after ``previous`` (its course in rad and
    speed in m/s, None for none) starts a new record of the trim: the first command, the start
    of motion (``MOVING_MPS``) or, moving, a course ``NEW_COURSE_DEG`` or more from the last."""
    if not speed_mps > MOVING_MPS:
        return False
    if previous is None or not previous[1] > MOVING_MPS:
        return True
    return not abs(wrap_pi(course_rad - previous[0])) < math.radians(NEW_COURSE_DEG)


def trimmed_course_rad(course_rad: float, fc_minus_magnetic_rad: float, decl_deg: float, max_trim_deg: float) -> float:
    """The course to send so the true heading is ``course_rad``: the course plus the FC's yaw
    error ``wrap(fc_minus_magnetic - D)``, clamped to ``max_trim_deg``; the course itself when
    the offset or D is not finite or ``max_trim_deg`` is 0. Result in [0, 2 pi)."""
    if not (max_trim_deg > 0.0 and math.isfinite(fc_minus_magnetic_rad) and math.isfinite(decl_deg)):
        return course_rad
    limit = math.radians(max_trim_deg)
    delta = min(max(wrap_pi(fc_minus_magnetic_rad - math.radians(decl_deg)), -limit), limit)
    return wrap_2pi(course_rad + delta)
