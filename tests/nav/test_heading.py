"""The heading measured from the vehicle's own magnetometer and accelerometer (companion.nav.heading),
its period average (companion.nav.magnetometer), and the mission's dead reckoning on it.

Oracles: a body-frame field and gravity made with :func:`companion.frames.ned_to_body` from a known
attitude (the heading is then known); the flight controller's attitude deliberately wrong, which the
levelled heading must not see; positions moved with :func:`companion.nav.geo.offset_position`.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.frames import ned_to_body
from companion.nav.field import model_for_date
from companion.nav.heading import flown_velocity_en, levelled_heading_deg
from companion.nav.magnetometer import AttitudeState, MagProcessor
from companion.nav.mission import Measurement, Mission
from companion.params import NavConfig, validate_all

G = 9.80665


def _body(heading_deg: float, roll_deg: float, pitch_deg: float, h_nt: float, z_nt: float):
    """Field and specific force in the body frame of a vehicle at that attitude, the field's horizontal
    part pointing to magnetic north (so the true heading is the magnetic one here)."""
    rpy = (math.radians(roll_deg), math.radians(pitch_deg), math.radians(heading_deg))
    return ned_to_body((h_nt, 0.0, z_nt), *rpy), ned_to_body((0.0, 0.0, -G), *rpy)


@settings(max_examples=300, deadline=None)
@given(heading=st.floats(-179.9, 179.9), roll=st.floats(-40, 40), pitch=st.floats(-40, 40),
       incl=st.floats(-75, 75))
def test_levelled_heading_recovers_the_heading_at_any_tilt(heading, roll, pitch, incl):
    f = 45000.0
    mag, force = _body(heading, roll, pitch, f * math.cos(math.radians(incl)), f * math.sin(math.radians(incl)))
    got = levelled_heading_deg(mag, force)
    assert abs((got - heading + 180.0) % 360.0 - 180.0) < 1e-7


def test_no_heading_without_gravity_or_horizontal_field():
    assert math.isnan(levelled_heading_deg((20000.0, 0.0, 40000.0), (0.0, 0.0, 0.0)))
    assert math.isnan(levelled_heading_deg((0.0, 0.0, 40000.0), (0.0, 0.0, -G)))        # field along gravity
    assert math.isnan(levelled_heading_deg((math.nan, 0.0, 40000.0), (0.0, 0.0, -G)))


def test_flown_velocity_keeps_the_speed_and_takes_the_measured_heading_plus_d():
    v = flown_velocity_en(np.array([6.0, 8.0]), 40.0, 5.0)          # 10 m/s along 45 deg true
    assert float(np.hypot(*v)) == pytest.approx(10.0)
    assert math.degrees(math.atan2(v[0], v[1])) == pytest.approx(45.0)
    commanded = np.array([1.0, 2.0])
    assert flown_velocity_en(commanded, math.nan, 5.0) is commanded   # not measured: the command
    assert np.all(flown_velocity_en(np.zeros(2), 40.0, 5.0) == 0.0)   # nothing commanded: standing


def test_period_heading_ignores_the_flight_controllers_tilt_and_yaw_errors():
    """The averaged heading comes from the samples' own body field and specific force: an attitude
    estimate 3 deg off in roll and pitch and 2 deg off in yaw (what ArduPilot's EKF does without GPS)
    changes the tilt-compensated D, not the levelled heading."""
    proc = MagProcessor()
    heading, rng = 130.0, np.random.default_rng(1)
    for k in range(600):
        t = 0.1 * k
        roll, pitch = 4.0 * math.sin(0.8 * t), 2.0 * math.sin(0.5 * t)   # a boat in waves
        mag, force = _body(heading, roll, pitch, 30000.0, 29000.0)
        proc.add_attitude(AttitudeState(t, math.radians(roll + 3.0), math.radians(pitch - 3.0),
                                        math.radians(heading + 2.0)))
        proc.add_specific_force(t, tuple(f + 0.05 * rng.standard_normal() for f in force), (0.0, 0.0, 0.0))
        proc.add_mag(t, mag)
    avg = proc.take(60.0)
    assert abs(avg.mag_heading_deg - heading) < 0.05
    assert abs(avg.decl_deg) > 1.0          # while the FC-attitude D carries the attitude's errors


def _mission(**values) -> Mission:
    config = NavConfig.from_values({**validate_all({}), "NAV_ELEMENTS": 2, **values})
    return Mission(config)


def _track_after_first_move(dr_heading: int, ins: bool) -> tuple[float, float, float]:
    """(course of the dead-reckoned first move, the commanded course, the measured true heading), deg,
    when the vehicle reports a heading 3 deg off the first probe's command."""
    mission = _mission(NAV_DR_HDG=dr_heading, FUS_MODEL=1)
    c = mission.config
    model = model_for_date(c.year)
    start = model.elements(c.start_lat_deg, c.start_lon_deg, c.alt_m, c.year)
    nan = math.nan
    first = mission.step(Measurement(0.0, float(start.decl_deg), float(start.incl_deg), f_nt=float(start.f_nt)))
    commanded = math.degrees(first.course_rad)
    measured_true = commanded + 3.0
    decl = float(start.decl_deg)
    ins_lat, ins_lon = (c.start_lat_deg, c.start_lon_deg + 0.05) if ins else (nan, nan)
    mission.step(Measurement(c.period_s, float(start.decl_deg), float(start.incl_deg), ins_lat, ins_lon,
                             c.period_s, float(start.f_nt), mag_heading_deg=measured_true - decl))
    dr = mission.dead_reckoned_en
    return math.degrees(math.atan2(dr[0], dr[1])), commanded, measured_true


def test_dead_reckoning_moves_along_the_measured_heading():
    course, commanded, measured = _track_after_first_move(dr_heading=1, ins=False)
    assert course == pytest.approx(measured, abs=1e-6)
    course, commanded, measured = _track_after_first_move(dr_heading=0, ins=False)
    assert course == pytest.approx(commanded, abs=1e-6)


def test_with_an_independent_ins_the_commanded_course_stays():
    course, commanded, _ = _track_after_first_move(dr_heading=1, ins=True)
    assert course == pytest.approx(commanded, abs=1e-6)
