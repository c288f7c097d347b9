"""The pure parts of the real-firmware adaptation: heading verdicts, parameter reads, the position
feed, element sets and the gravity-referenced inclination."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.frames import mat_nb_from_euler
from companion.io.fc_params import FcParamReader, judge_heading
from companion.io.position_feed import PositionFeed
from companion.nav.elements import ELEMENT_SETS, ElementSet
from companion.nav.geo import geodesic_distance_m, offset_position
from companion.nav.magnetometer import decl_incl_deg, gravity_inclination_deg


@pytest.mark.parametrize("values, compass", [
    ({"EK3_SRC1_YAW": 1, "COMPASS_USE": 1, "AHRS_EKF_TYPE": 3}, True),
    ({"EK3_SRC1_YAW": 3, "COMPASS_USE": 1, "AHRS_EKF_TYPE": 3}, True),    # falls back to the compass without GPS
    ({"EK3_SRC1_YAW": 2, "COMPASS_USE": 1, "AHRS_EKF_TYPE": 3}, False),   # dual-antenna GPS yaw
    ({"EK3_SRC1_YAW": 3, "COMPASS_USE": 0, "AHRS_EKF_TYPE": 3}, False),
    ({"EK3_SRC1_YAW": 8, "COMPASS_USE": 0, "AHRS_EKF_TYPE": 3}, False),   # GSF
    ({"EK3_SRC1_YAW": 6, "COMPASS_USE": 1, "AHRS_EKF_TYPE": 3}, False),   # ExternalNav
    ({"EK3_SRC1_YAW": 2, "COMPASS_USE": 1, "AHRS_EKF_TYPE": 2}, True),    # EKF2 uses the compass
])
def test_ardupilot_heading_verdicts(values, compass):
    verdict = judge_heading("ardupilot", values)
    assert verdict.compass_derived is compass and "EK" in verdict.reason or "AHRS" in verdict.reason


def test_px4_heading_verdicts():
    assert judge_heading("px4", {"EKF2_MAG_TYPE": 0}).compass_derived is True
    assert judge_heading("px4", {"EKF2_MAG_TYPE": 5, "EKF2_GPS_CTRL": 15}).compass_derived is False
    assert judge_heading("px4", {}).compass_derived is None


def test_param_reader_backs_off_and_gives_up():
    reader = FcParamReader(("EK3_SRC1_YAW", "COMPASS_USE"), first_retry_s=1.0, deadline_s=10.0)
    sent = [t for t in np.arange(0.0, 12.0, 0.1) if reader.due(float(t))]
    assert [round(t, 1) for t in sent] == [0.0, 1.0, 3.0, 7.0]      # 1, 2, 4 s apart, none after 10 s
    assert reader.expired(10.0) and not reader.complete


def test_feed_starts_without_a_step_and_blends_at_the_stated_speed():
    feed = PositionFeed(blend_mps=3.0)
    feed.start(0.0, 33.0, 152.0, 50.0)
    assert feed.correct_to(0.0, 33.0, 152.1, 1000.0) == pytest.approx(9340.0, rel=0.01)   # 9.3 km east
    feed.set_velocity(0.0, 0.0, 0.0)
    previous = feed.sample(0.0)
    assert (previous.lat_deg, previous.lon_deg) == (33.0, 152.0)    # no step when the feed starts
    for k in range(1, 301):
        sample = feed.sample(k * 0.1)
        moved = geodesic_distance_m(previous.lat_deg, previous.lon_deg, sample.lat_deg, sample.lon_deg)
        assert moved <= 3.0 * 0.1 * 1.001                            # never faster than the blend speed
        previous = sample
    assert feed.pending_m == pytest.approx(9340.0 - 90.0, rel=0.01)


def test_feed_flies_on_with_the_commanded_velocity():
    feed = PositionFeed()
    feed.start(100.0, 33.0, 152.0, 50.0)
    feed.set_velocity(100.0, 8.0, 0.0)                               # north at 8 m/s
    a, b = feed.sample(100.0), feed.sample(200.0)
    assert geodesic_distance_m(a.lat_deg, a.lon_deg, b.lat_deg, b.lon_deg) == pytest.approx(800.0, rel=1e-3)
    assert b.lat_deg > a.lat_deg and b.lon_deg == pytest.approx(a.lon_deg)


def test_feed_turns_onto_a_new_course_at_its_acceleration_and_keeps_the_speed():
    """A new course turns the fed velocity at COMP_FEED_ACCEL (speed x turn rate), as the boat turns,
    instead of a corner the flight controller's IMU never measured; the speed holds through the turn."""
    feed = PositionFeed(accel_mps2=0.5)
    feed.start(0.0, 33.0, 152.0, 5.0, (3.0, 0.0))                    # north at 3 m/s, the FC's velocity
    feed.set_velocity(0.0, 0.0, -3.0)                                 # new course: west
    samples = [feed.sample(k * 0.1) for k in range(0, 201)]
    speeds = [math.hypot(s.vn_mps, s.ve_mps) for s in samples]
    assert min(speeds) == pytest.approx(3.0, abs=1e-9)                # no corner cut through a lower speed
    courses = [math.degrees(math.atan2(s.ve_mps, s.vn_mps)) for s in samples]
    turned_at = next(k for k, c in enumerate(courses) if c <= -90.0 + 1e-9) * 0.1
    assert turned_at == pytest.approx(math.pi / 2 / (0.5 / 3.0), abs=0.15)   # 90 deg at 0.5/3 rad/s: 9.4 s
    for a, b in zip(samples, samples[1:]):                            # the acceleration is bounded ...
        dv = math.hypot(b.vn_mps - a.vn_mps, b.ve_mps - a.ve_mps)
        assert dv <= 0.5 * 0.1 * 1.000001
        moved = geodesic_distance_m(a.lat_deg, a.lon_deg, b.lat_deg, b.lon_deg)   # ... and the track flies it
        assert moved == pytest.approx(0.3, rel=2e-3)
    # an arc: after the turn the track is one turn radius (3 / (0.5 / 3) = 18 m) north of where it began
    end = samples[-1]
    assert geodesic_distance_m(33.0, 152.0, end.lat_deg, 152.0) == pytest.approx(18.0, abs=0.5)
    # sampled once at the end, the same track (a feed sampled late is not a different feed)
    once = PositionFeed(accel_mps2=0.5)
    once.start(0.0, 33.0, 152.0, 5.0, (3.0, 0.0))
    once.set_velocity(0.0, 0.0, -3.0)
    late = once.sample(20.0)
    assert geodesic_distance_m(late.lat_deg, late.lon_deg, end.lat_deg, end.lon_deg) < 0.01


def test_feed_without_an_acceleration_limit_steps_as_before():
    feed = PositionFeed()
    feed.start(0.0, 33.0, 152.0, 5.0, (3.0, 0.0))
    feed.set_velocity(0.0, 0.0, -3.0)
    sample = feed.sample(10.0)
    assert (sample.vn_mps, sample.ve_mps) == (0.0, -3.0)
    assert geodesic_distance_m(33.0, 152.0, sample.lat_deg, sample.lon_deg) == pytest.approx(30.0, rel=1e-3)
    assert sample.lat_deg == pytest.approx(33.0, abs=1e-9)            # due west from the command's time on
    with pytest.raises(ValueError, match="accel_mps2"):
        PositionFeed(accel_mps2=0.0)


def test_a_reboot_voids_the_gps_fix_timed_on_the_old_clock():
    """A fix seen at old-clock 1300 s would count as fresh on the new clock until 1303 s: the FC's
    position would be taken for GPS-aided for 20 minutes after a reboot, and never fused."""
    from companion.fc_view import FcView

    view = FcView(heading_source=1, position_publish=3)
    gps = type("Gps", (), {"get_type": lambda self: "GPS_RAW_INT", "fix_type": 3})()
    view.packet(gps, 1300.0)
    view.feeding_own = True
    assert view.gps_has_fix(5.0) and not view.position_independent(5.0)[0]   # what the old clock would say
    view.rebooted()
    assert not view.gps_has_fix(5.0) and view.position_independent(5.0) == (True, "free inertial")
    assert not view.feeding_own


def test_element_sets():
    di, i_f = ELEMENT_SETS[ElementSet.PAPER], ELEMENT_SETS[ElementSet.HEADING_FREE]
    assert di.uses_declination and not i_f.uses_declination
    np.testing.assert_allclose(di.difference([179.0, 40.0], [-179.0, 41.0]), [-2.0, -1.0])
    np.testing.assert_allclose(i_f.difference([40.0, 42000.0], [41.0, 41990.0]), [-1.0, 10.0])
    np.testing.assert_allclose(i_f.qp_scale(0), [3600.0, 10.0])
    assert i_f.label == "(I, F)"


angles = st.floats(-math.pi, math.pi, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(roll=st.floats(-0.6, 0.6), pitch=st.floats(-0.6, 0.6), yaw=angles,
       incl=st.floats(-85.0, 85.0), decl=st.floats(-30.0, 30.0))
def test_gravity_inclination_needs_no_attitude(roll, pitch, yaw, incl, decl):
    """I from field and accelerometer alone equals the true I at any attitude (rotation invariance)."""
    f_nt = 45000.0
    h = f_nt * math.cos(math.radians(incl))
    ned = (h * math.cos(math.radians(decl)), h * math.sin(math.radians(decl)), f_nt * math.sin(math.radians(incl)))
    rot = np.array(mat_nb_from_euler(roll, pitch, yaw))              # body -> NED
    mag_body = rot.T @ np.array(ned)
    specific_force_body = rot.T @ np.array([0.0, 0.0, -9.80665])       # at rest: minus gravity
    assert gravity_inclination_deg(tuple(mag_body), tuple(specific_force_body)) == pytest.approx(incl, abs=1e-7)
    assert decl_incl_deg(*ned)[1] == pytest.approx(incl, abs=1e-9)


def test_feed_samples_are_the_anchor_offsets_computed_afresh():
    """The feed keeps its anchor's metres per degree between re-anchors: every sample, through turns
    (re-anchors each sample) and straight legs (one anchor), is ``offset_position`` of the anchor
    computed without it, bit for bit."""
    feed = PositionFeed(blend_mps=2.0, accel_mps2=0.3)
    feed.start(0.0, -41.3, 174.8, 20.0, (2.0, 1.0))
    feed.correct_to(0.0, -41.31, 174.79, 30.0)
    for k in range(600):
        t = k * 0.1
        if k in (100, 300):
            feed.set_velocity(t, -3.0 if k == 100 else 0.5, 2.5)
        sample = feed.sample(t)
        t0, lat0, lon0 = feed.anchor
        dt = t - t0
        lat, lon = offset_position(lat0, lon0, feed.velocity_ne[1] * dt + feed.applied_en[0],
                                   feed.velocity_ne[0] * dt + feed.applied_en[1])
        assert (sample.lat_deg, sample.lon_deg) == (lat, lon)
