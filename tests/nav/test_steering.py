"""The course trimmed by the flight controller's yaw error (companion.nav.steering) and the
magnetometer pipeline that measures that error.

Oracles: a body-frame field and gravity made with :func:`companion.frames.ned_to_body` from a known
true attitude and declination; the flight controller's yaw set to the true heading plus a known
error, which the trim must take out; noise of PX4 SIH's size on the field.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.frames import ned_to_body
from companion.nav.magnetometer import AttitudeState, MagProcessor
from companion.nav.heading import levelled_heading_deg
from companion.nav.steering import YawOffsetTracker, is_new_course, trimmed_course_rad

G = 9.80665


def _sample(heading_deg: float, roll_deg: float, pitch_deg: float, decl_deg: float, incl_deg: float = 50.0,
            f_nt: float = 45000.0):
    """Body field and specific force of a vehicle with true heading ``heading_deg`` where the field
    points ``decl_deg`` east of true north."""
    h, z = f_nt * math.cos(math.radians(incl_deg)), f_nt * math.sin(math.radians(incl_deg))
    d = math.radians(decl_deg)
    rpy = (math.radians(roll_deg), math.radians(pitch_deg), math.radians(heading_deg))
    return ned_to_body((h * math.cos(d), h * math.sin(d), z), *rpy), ned_to_body((0.0, 0.0, -G), *rpy)


@settings(max_examples=200, deadline=None)
@given(heading=st.floats(0.0, 359.9), decl=st.floats(-25.0, 25.0), error=st.floats(-25.0, 25.0),
       roll=st.floats(-20.0, 20.0), pitch=st.floats(-20.0, 20.0), course=st.floats(0.0, 359.9))
def test_the_trim_makes_the_true_heading_the_course(heading, decl, error, roll, pitch, course):
    """An FC whose yaw is the true heading plus ``error`` steers that yaw onto what it is sent; the
    sent course is the course plus the error, so the true heading it flies is the course."""
    tracker = YawOffsetTracker(tau_s=10.0)
    mag, force = _sample(heading, roll, pitch, decl)
    for k in range(100):
        tracker.add(0.1 * k, math.radians(heading + error), mag, force)
    sent = trimmed_course_rad(math.radians(course), tracker.offset_rad(9.9), decl, 30.0)
    flown = math.degrees(sent) - error                  # the FC's yaw on `sent`, less its error
    assert abs((flown - course + 180.0) % 360.0 - 180.0) < 1e-6


def test_the_offset_averages_noise_of_sih_size():
    """SIH's field noise (2500 nT per axis) at 50 Hz over the 5 s time constant: the offset within
    0.5 deg of a 17 deg yaw error (one sample's heading scatters by about 4 deg)."""
    rng = np.random.default_rng(7)
    tracker = YawOffsetTracker()
    decl, heading, error = 8.0, 200.0, 17.0
    mag, force = _sample(heading, 1.0, -2.0, decl)
    for k in range(50 * 120):
        noisy = np.asarray(mag) + rng.normal(0.0, 2500.0, 3)
        tracker.add(0.02 * k, math.radians(heading + error), tuple(noisy), force)
    delta = math.degrees(tracker.offset_rad(0.02 * (50 * 120 - 1))) - decl
    assert delta == pytest.approx(error, abs=0.5)


def test_no_offset_before_enough_samples_nor_after_the_stream_stops():
    tracker = YawOffsetTracker(tau_s=20.0, max_age_s=5.0, min_span_s=5.0)
    mag, force = _sample(90.0, 0.0, 0.0, 0.0)
    for k in range(40):                                  # 3.9 s of samples
        tracker.add(0.1 * k, math.radians(95.0), mag, force)
    assert math.isnan(tracker.offset_rad(3.9))
    for k in range(40, 80):
        tracker.add(0.1 * k, math.radians(95.0), mag, force)
    assert math.degrees(tracker.offset_rad(7.9)) == pytest.approx(5.0, abs=1e-9)
    assert math.isnan(tracker.offset_rad(7.9 + 5.1))      # the stream stopped
    assert not tracker.add(8.0, math.nan, mag, force)
    assert tracker.add(1.0, math.radians(80.0), mag, force)     # the FC rebooted: its clock starts again
    assert math.isnan(tracker.offset_rad(1.0))                   # and so does the record (not 5 deg)
    for k in range(11, 80):
        tracker.add(0.1 * k, math.radians(80.0), mag, force)
    assert math.degrees(tracker.offset_rad(7.9)) == pytest.approx(-10.0, abs=1e-9)
    assert not tracker.add(8.0, 0.0, mag, (0.0, 0.0, 0.0))  # no gravity: nothing to level with


def test_the_trim_is_clamped_and_off_without_an_offset():
    course = math.radians(10.0)
    assert trimmed_course_rad(course, math.radians(40.0), 0.0, 30.0) == pytest.approx(math.radians(40.0))
    assert trimmed_course_rad(course, math.radians(-40.0), 0.0, 30.0) == pytest.approx(math.radians(340.0))
    assert trimmed_course_rad(course, math.nan, 0.0, 30.0) == course
    assert trimmed_course_rad(course, math.radians(5.0), math.nan, 30.0) == course
    assert trimmed_course_rad(course, math.radians(5.0), 0.0, 0.0) == course   # COMP_TRIM_DEG 0: off


def test_the_magnetometer_pipeline_measures_the_fc_yaw_error_and_ignores_turns():
    """MagProcessor feeds its tracker from the FC's attitude and the same instant's IMU: a 12 deg yaw
    error is measured while steady; samples turning faster than ``max_turn_radps`` are left out."""
    proc = MagProcessor(track_yaw_offset=True)
    decl, heading, error = -6.0, 135.0, 12.0
    mag, force = _sample(heading, 2.0, 3.0, decl)
    for k in range(300):
        t = 0.1 * k
        turning = 100 <= k < 150
        proc.add_attitude(AttitudeState.from_body_rates(t, math.radians(2.0), math.radians(3.0),
                                                        math.radians(heading + (90.0 if turning else error)), 0.0, 0.0, 0.0))
        proc.add_specific_force(t, force, (0.0, 0.0, 0.5 if turning else 0.0))
        proc.add_mag(t, mag)
    proc.flush()
    assert math.degrees(proc.yaw_offset.offset_rad(29.9)) - decl == pytest.approx(error, abs=1e-6)


def test_a_new_course_replaces_the_old_headings_offset_within_seconds_and_stays_quiet():
    """EKF2's yaw error is heading-dependent: +5 deg on the first probe's heading, -3 deg after the
    turn to the second. Told of the new course, the trim holds +5 during the turn, gives -3 within
    1 deg from 3 s after the change on (the old record alone: still +1.5 after 10 s), and with per-sample
    heading noise of ~5 deg at 50 Hz its estimate scatters by under 0.5 deg (1-sigma) while
    weighted with ``fresh_tau_s`` (3 s) and under 0.25 deg once back on ``tau_s`` (5 s) (seed 11:
    5.1 deg per sample; 0.24 and 0.14 deg)."""
    rng = np.random.default_rng(11)
    tracker = YawOffsetTracker()
    decl = 4.0
    mag_a, force_a = _sample(45.0, 1.0, -1.0, decl)
    mag_b, force_b = _sample(135.0, -1.0, 2.0, decl)

    def noisy(mag):
        return tuple(np.asarray(mag) + rng.normal(0.0, 2500.0, 3))

    def delta(t):
        return math.degrees(tracker.offset_rad(t)) - decl

    scatter = [(levelled - 45.0 + decl + 180.0) % 360.0 - 180.0 for levelled in
               (levelled_heading_deg(noisy(mag_a), force_a)
                for _ in range(2000))]
    assert 4.0 < float(np.std(scatter)) < 6.0                    # the per-sample noise the bounds are for
    t = 0.0
    for _ in range(50 * 120):                                     # two minutes on the first heading
        tracker.add(t, math.radians(45.0 + 5.0), noisy(mag_a), force_a)
        t += 0.02
    assert delta(t) == pytest.approx(5.0, abs=0.5)
    change = t
    tracker.new_course(change)                                    # the turn: 4 s, no samples (turning)
    assert delta(change + 1.0) == pytest.approx(delta(change), abs=1e-12)   # the old offset holds
    t = change + 4.0
    fresh, settled = [], []
    while t < change + 200.0:
        tracker.add(t, math.radians(135.0 - 3.0), noisy(mag_b), force_b)
        if t - change >= 4.0 + tracker.fresh_min_span_s + 1.0:    # 3 s of fresh samples on
            assert delta(t) == pytest.approx(-3.0, abs=1.0), t - change
            if t - change < tracker.fresh_s:
                fresh.append(delta(t))
            elif t - change > tracker.fresh_s + 3.0 * tracker.tau_s:   # the steady record, settled
                settled.append(delta(t))
        elif t - change < 4.0 + tracker.fresh_min_span_s - 0.05:  # the fresh record still short: +5 held
            assert delta(t) == pytest.approx(5.0, abs=0.5)
        t += 0.02
    assert float(np.std(fresh)) < 0.5 and float(np.std(settled)) < 0.25
    assert abs(float(np.mean(settled)) + 3.0) < 0.3


def test_without_being_told_the_record_keeps_the_old_heading():
    """The reference the test above improves on: the old 20 s record alone, 10 s after the turn."""
    tracker = YawOffsetTracker(tau_s=20.0)
    mag_a, force_a = _sample(45.0, 0.0, 0.0, 0.0)
    mag_b, force_b = _sample(135.0, 0.0, 0.0, 0.0)
    for k in range(50 * 120):
        tracker.add(0.02 * k, math.radians(50.0), mag_a, force_a)
    for k in range(50 * 10):
        tracker.add(124.0 + 0.02 * k, math.radians(132.0), mag_b, force_b)
    assert math.degrees(tracker.offset_rad(134.0)) > 1.0          # still far from -3


def test_samples_of_the_old_course_and_a_reboot_after_the_change():
    tracker = YawOffsetTracker()
    mag, force = _sample(90.0, 0.0, 0.0, 0.0)
    for k in range(400):
        tracker.add(0.02 * k, math.radians(95.0), mag, force)
    tracker.new_course(8.0)
    assert not tracker.add(7.99, math.radians(70.0), mag, force)  # stamped before the change: left out
    assert math.degrees(tracker.offset_rad(8.0)) == pytest.approx(5.0, abs=1e-9)
    assert math.isnan(tracker.offset_rad(7.98 + tracker.max_age_s + 0.1))   # the stream stopped: none held
    tracker.new_course(8.5)                                       # a second change before the record spans
    for k in range(int(tracker.fresh_min_span_s / 0.02) + 1):
        tracker.add(8.5 + 0.02 * k, math.radians(85.0), mag, force)
    assert math.degrees(tracker.offset_rad(11.0)) == pytest.approx(-5.0, abs=1e-9)
    assert tracker.add(1.0, math.radians(80.0), mag, force)       # the FC rebooted: nothing held
    assert math.isnan(tracker.offset_rad(1.0))
    for k in range(1, int(tracker.min_span_s / 0.02) + 2):       # and the first record's span applies
        tracker.add(1.0 + 0.02 * k, math.radians(80.0), mag, force)
    assert math.degrees(tracker.offset_rad(6.1)) == pytest.approx(-10.0, abs=1e-9)


@pytest.mark.parametrize("previous,course_deg,speed,new", [
    (None, 45.0, 3.0, True),             # the first command: motion starts
    ((math.radians(45.0), 0.0), 45.0, 3.0, True),     # from standing
    ((math.radians(45.0), 3.0), 54.0, 3.0, False),    # 9 deg: the 20 s record follows
    ((math.radians(45.0), 3.0), 135.0, 3.0, True),    # the turn between probes
    ((math.radians(355.0), 3.0), 3.0, 3.0, False),    # across north: 8 deg
    ((math.radians(355.0), 3.0), 6.0, 3.0, True),     # 11 deg
    ((math.radians(45.0), 3.0), 45.0, 5.0, False),    # a new speed only
    ((math.radians(45.0), 3.0), 135.0, 0.0, False),   # stopping (arrived)
    (None, 45.0, 0.0, False),
])
def test_what_is_a_new_course(previous, course_deg, speed, new):
    assert is_new_course(previous, math.radians(course_deg), speed) is new


def test_an_error_wandering_on_a_held_course_is_followed():
    """EKF2's yaw error ramping at 0.25 deg/s on a held course (measured once: -5 to +28 deg over
    110 s): the trim lags it by ``tau_s`` times the rate, 1.25 deg with 5 s (5 deg with 20 s)."""
    tracker = YawOffsetTracker()
    mag, force = _sample(45.0, 0.0, 0.0, 0.0)
    tracker.new_course(0.0)
    t = 0.0
    while t < 200.0:
        error = 0.0 if t < 80.0 else 0.25 * (t - 80.0)          # steady for the fresh record, then the ramp
        tracker.add(t, math.radians(45.0 + error), mag, force)
        t += 0.02
    assert 0.25 * (t - 0.02 - 80.0) - math.degrees(tracker.offset_rad(t)) == pytest.approx(1.25, abs=0.1)
