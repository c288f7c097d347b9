"""sitl.guidance without sockets: setpoint decoding and refusals, setpoint timeouts, PX4 offboard rules, RTL."""
from __future__ import annotations

import math

import pytest

from sitl.guidance import (ARDUPILOT, MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED, MAV_RESULT_FAILED, PX4,
                           Guidance, SetpointError, interpret_position_target)
from sitl.world.vehicle import VehicleLimits


def _decode(**kw):
    base = dict(frame=6, type_mask=0b0000_1101_1100_0111, vx=0.0, vy=0.0, yaw=0.0, max_speed_mps=16.7,
                current_yaw_rad=0.0, fc_lat_deg=33.0, fc_lon_deg=152.0, origin=(33.0, 152.0), lat_deg=0.0,
                lon_deg=0.0)
    base.update(kw)
    return interpret_position_target(**base)


def test_setpoint_type_mask_velocity_yaw_position():
    t = _decode(vx=0.0, vy=5.0)                                         # yaw ignored: course of the velocity
    assert math.degrees(t.course_rad) == pytest.approx(90.0) and t.speed_mps == pytest.approx(5.0)
    t = _decode(vx=3.0, vy=-3.0, yaw=math.radians(10.0), type_mask=0b0000_1001_1100_0111)   # yaw used
    assert math.degrees(t.course_rad) == pytest.approx(10.0) and t.speed_mps == pytest.approx(math.hypot(3, 3))
    t = _decode(vx=math.nan, vy=math.nan, yaw=math.radians(-90.0), type_mask=0b0000_1001_1111_1111)  # yaw only
    assert math.degrees(t.course_rad) == pytest.approx(270.0) and t.speed_mps is None
    t = _decode(lat_deg=33.1, lon_deg=152.2, type_mask=0b0000_1101_1111_1000)   # position, velocity masked
    assert (t.lat_deg, t.lon_deg) == (33.1, 152.2)
    t = _decode(frame=8, lat_deg=None, lon_deg=None, vx=2.0, vy=0.0, current_yaw_rad=math.radians(30.0))  # body
    assert math.degrees(t.course_rad) == pytest.approx(30.0)
    t = _decode(frame=1, lat_deg=None, lon_deg=None, x_m=1000.0, y_m=0.0, type_mask=0b0000_1101_1111_1000)
    assert t.lat_deg == pytest.approx(33.0 + 1000.0 / 110_900.0, abs=1e-4) and t.lon_deg == pytest.approx(152.0)


@pytest.mark.parametrize("kw,reason", [
    (dict(vx=math.nan), "nan"), (dict(vy=math.inf), "nan"), (dict(vx=20.0), "limit"),
    (dict(frame=1), "frame"), (dict(frame=1, lat_deg=None, lon_deg=None, x_m=0.0, y_m=0.0), None),
    (dict(type_mask=0xFFF), "empty"), (dict(type_mask=0b0101_1111_1111), "unsupported"),
    (dict(yaw=100.0, type_mask=0b0000_1001_1100_0111), "limit"),
    (dict(lat_deg=95.0, type_mask=0b0000_1101_1111_1000), "limit"),
])
def test_setpoint_rejections(kw, reason):
    if reason is None:
        _decode(**kw)
        return
    with pytest.raises(SetpointError) as err:
        _decode(**kw)
    assert err.value.reason == reason


def test_ardupilot_guidance_timeout_stops_and_stays_guided():
    g = Guidance(ARDUPILOT, VehicleLimits(), 13.9)
    g.set_ready()
    assert g.request_mode("GUIDED", 0.0) == MAV_RESULT_ACCEPTED
    assert not g.accept_setpoint(0.0)                                    # disarmed
    assert g.request_arm(True, 0.0) == MAV_RESULT_ACCEPTED and g.accept_setpoint(0.0)
    g.apply_target(_decode(vx=0.0, vy=5.0), 1.0)
    assert g.command(2.0, 0.0, 33.0, 152.0) == (pytest.approx(math.pi / 2), 5.0)
    assert g.command(4.1, 0.0, 33.0, 152.0)[1] == 0.0                   # 3 s of silence
    assert g.mode == "GUIDED" and g.counters["setpoint_timeouts"] == 1
    assert any("timeout" in text for _, text in g.events)
    assert g.request_mode(None, 5.0, "99") == MAV_RESULT_FAILED
    assert g.request_mode("AUTO", 5.0) == MAV_RESULT_FAILED


def test_px4_offboard_needs_a_setpoint_stream_and_falls_back_to_hold():
    g = Guidance(PX4, VehicleLimits(), 13.9)
    g.set_ready()
    assert g.request_arm(True, 0.0) == MAV_RESULT_ACCEPTED
    assert g.request_mode("OFFBOARD", 0.0) == MAV_RESULT_DENIED          # nothing streamed yet
    assert g.accept_setpoint(1.0)                                         # PX4 stores setpoints in any mode
    g.apply_target(_decode(vx=4.0, vy=0.0), 1.0)
    assert g.command(1.1, 0.0, 33.0, 152.0)[1] == 0.0                    # not offboard yet: holds
    assert g.request_mode("OFFBOARD", 1.2) == MAV_RESULT_ACCEPTED
    assert g.command(1.3, 0.0, 33.0, 152.0) == (0.0, 4.0)                 # the streamed setpoint applies
    assert g.command(2.5, 0.0, 33.0, 152.0)[1] == 0.0                    # 1 s of silence: offboard lost
    assert g.mode == "AUTO.LOITER"
    assert PX4.custom_mode("OFFBOARD") == 6 << 16
    assert PX4.mode_from_command(4, 3) == "AUTO.LOITER" and PX4.mode_from_command(6, 0) == "OFFBOARD"
    assert ARDUPILOT.mode_from_command(15, 0) == "GUIDED" and ARDUPILOT.mode_from_command(15.5, 0) is None


def test_rtl_drives_home_and_stops():
    g = Guidance(ARDUPILOT, VehicleLimits(accel_mps2=0.5), 10.0)
    g.set_ready()
    g.home = (33.0, 152.0)
    g.request_arm(True, 0.0)
    assert g.request_mode("RTL", 0.0) == MAV_RESULT_ACCEPTED
    course, speed = g.command(0.0, 0.0, 33.01, 152.0)                   # 1.1 km north of home
    assert math.degrees(course) == pytest.approx(180.0, abs=0.1) and speed == 10.0
    assert g.command(0.0, 0.0, 33.0 + 1e-6, 152.0)[1] == 0.0            # arrived
