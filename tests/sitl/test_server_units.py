"""Pieces of the simulator without sockets: framing, endpoints, faults, setpoint decoding, modes, clocks, sensors."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.clock import LockstepGate, Pacer
from sitl.guidance import (ARDUPILOT, MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED, MAV_RESULT_FAILED, PX4, Guidance,
                           SetpointError, interpret_position_target)
from sitl.links import EndpointError, parse_endpoint
from sitl.mavframe import FrameEncoder
from sitl.scenario import load_scenario
from companion.frames import body_to_ned, ned_to_body
from sitl.sensors import Attitude, NavSolution, Normals, SensorSuite
from sitl.server import parse_fault
from sitl.world.build import StormUnavailableError, build_truth_field
from sitl.world.ins import InsErrorConfig
from sitl.world.vehicle import VehicleLimits


def test_frame_encoder_matches_pymavlink_byte_for_byte():
    enc = FrameEncoder(1, 1)
    mav = mavlink.MAVLink(None, 1, 1)
    cases = [
        (mavlink.MAVLink_raw_imu_message, (123456789, 1, -2, 3, 4, 5, -6, 300, -20, 295, 0, 0)),
        (mavlink.MAVLink_gps_raw_int_message, (1715364000000000, 3, 330000000, 1520000000, 0, 90, 150, 1389, 9000,
                                               14, 0, 2500, 5000, 100, 0, 0)),
        (mavlink.MAVLink_highres_imu_message, (1, 0.1, 0.2, -9.8, 0.0, 0.0, 0.0, math.nan, 0.0, 0.29, 1013.25, 0.0,
                                               0.0, 25.0, 511, 0)),
        (mavlink.MAVLink_sys_status_message, (1, 2, 3, 100, 12600, -1, -1, 0, 0, 0, 0, 0, 0)),   # extensions left out
        (mavlink.MAVLink_heartbeat_message, (11, 3, 209, 15, 4, 3)),
        (mavlink.MAVLink_statustext_message, (4, b"slow path")),
        (mavlink.MAVLink_command_ack_message, (511, 0, 0, 0, 1, 191)),
    ]
    for _ in range(300):   # through a sequence wrap-around
        for cls, fields in cases:
            mav.seq = enc.seq
            assert enc.frame(cls, *fields) == cls(*fields).pack(mav), cls.msgname


def test_parse_endpoint_and_fault():
    assert parse_endpoint("udp:127.0.0.1:14550").kind == "udpout"
    assert parse_endpoint("udpin:0.0.0.0:14551").kind == "udpin"
    assert parse_endpoint("tcp:127.0.0.1:5760").port == 5760
    assert parse_endpoint("udp:14550").host == "127.0.0.1"
    for bad in ("serial:/dev/ttyS0", "udp:host:port", "tcp:1.2.3.4:70000", "udp"):
        with pytest.raises(EndpointError):
            parse_endpoint(bad)
    f = parse_fault("mag_spike:30:2:5000")
    assert (f.kind, f.at_s, f.duration_s, f.value) == ("mag_spike", 30.0, 2.0, 5000.0)
    assert parse_fault("gps_off:10").duration_s == math.inf
    for bad in ("nope:1", "mag_off", "mag_off:x", "mag_off:-1", "mag_off:1:0", "mag_off:1:2:nan"):
        with pytest.raises(ValueError):
            parse_fault(bad)


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


def test_lockstep_gate_rules():
    gate = LockstepGate(0.2, timeout_s=1.0)
    assert gate.satisfied(0) and not gate.satisfied(200_000)     # at t = 0 one period of slack is free
    gate.observe(None, now_us=200_000)             # before any stamp an untimed message (HEARTBEAT) answers
    assert gate.satisfied(200_000)
    gate.finish(0.0, False)
    assert not gate.satisfied(200_000)
    gate.observe(100, now_us=200_000)              # answered up to 0.1 s >= 0.2 - 0.2
    assert gate.satisfied(200_000) and not gate.satisfied(400_000)
    gate.finish(0.0, False)
    gate.observe(None, now_us=400_000)             # after a stamp, untimed messages no longer answer
    assert not gate.satisfied(400_000)
    gate.observe(300, now_us=400_000)
    assert gate.satisfied(400_000)
    gate.finish(0.01, False)
    assert not gate.satisfied(600_000)
    gate.observe(10_000_000, now_us=600_000)       # a stamp from the future is not simulated time
    assert gate.future_stamps == 1 and gate.peer_time_ms == 300 and not gate.satisfied(600_000)
    gate.finish(1.0, True)
    assert gate.stats()["lockstep_timeouts"] == 1
    assert LockstepGate(0.2, peer=(1, 191)).eligible(1, 191) and not LockstepGate(0.2, peer=(1, 191)).eligible(255, 0)


def test_pacer_deadlines_and_rebase():
    now = [100.0]
    pacer = Pacer(10.0, rebase_after_s=0.5, clock=lambda: now[0])
    assert pacer.deadline(5_000_000) == pytest.approx(100.5)           # 5 s simulated at 10x
    now[0] = 110.0                                                      # stalled 10 s: no burst to catch up
    assert pacer.deadline(6_000_000) is None and pacer.rebases == 1
    assert pacer.deadline(7_000_000) == pytest.approx(110.1)
    assert Pacer(0.0).deadline(10**9) is None


def test_rotations_and_noise_reproducible():
    rng = np.random.default_rng(0)
    for _ in range(20):
        r, p, y = rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-3, 3)
        v = rng.normal(size=3)
        assert np.allclose(body_to_ned(ned_to_body(v, r, p, y), r, p, y), v)
    # level, facing east: north is on the left (-y), down stays down
    assert np.allclose(ned_to_body((0.0, 1.0, 0.0), 0.0, 0.0, math.pi / 2), (1.0, 0.0, 0.0))
    a, b = Normals(np.random.default_rng(5), block=7), Normals(np.random.default_rng(5), block=7)
    assert [a() for _ in range(30)] == [b() for _ in range(30)]


def test_sensor_suite_quantises_and_adds_bias():
    model = load_scenario("pacific").sensors
    from dataclasses import replace
    model = replace(model, mag_noise_nt=0.0, mag_bias_nt=(150.0, 0.0, -250.0), mag_lsb_nt=100.0)
    suite = SensorSuite(model, np.random.default_rng(1))
    x, y, z = suite.sample_mag((30000.0, -2000.0, 29400.0), Attitude(0.0, 0.0, 0.0))
    assert (x, y, z) == (30200.0, -2000.0, 29200.0)                     # 30150 rounds to even hundreds
    x, y, z = suite.sample_mag((30000.0, 0.0, 0.0), Attitude(0.0, 0.0, math.pi / 2), extra_nt=1000.0)
    assert (x, y, z) == (1200.0, -29000.0, 800.0)


def test_nav_solution_aided_then_inertial():
    nav = NavSolution(InsErrorConfig(deterministic=True), np.random.default_rng(0), aided_noise_m=0.5)
    nav.update(0.0, True, 33.0, 0.0, 10.0)
    lat, lon = nav.position(0.0, 33.0, 152.0)
    assert abs(lat - 33.0) < 1e-4 and not nav.inertial
    nav.update(10.0, False, 33.0, 0.0, 10.0)                            # GPS lost: Table 1 errors appear
    lat, lon = nav.position(10.0, 33.0, 152.0)
    assert nav.inertial and (lat - 33.0) * 110_900 == pytest.approx(5000.0, rel=0.01)
    e1 = nav.error_m(12.0, 33.0, 152.0)
    e2 = nav.error_m(14.0, 33.0, 152.0)                                 # moves smoothly between propagations
    assert e1 != e2 and abs(e2[0] - e1[0]) < 30.0


def test_build_truth_field_quiet_is_wmm_and_storm_errors_are_clear(tmp_path):
    sc = load_scenario("pacific")
    truth = build_truth_field(sc)
    wmm = truth.model.elements(33.0, 152.0, 0.0, sc.year)
    assert np.allclose(truth.field_ned_nt(33.0, 152.0, 0.0, 123.0), (wmm.x_nt, wmm.y_nt, wmm.z_nt))
    with pytest.raises(StormUnavailableError, match="storm data"):
        build_truth_field(load_scenario("long_storm"), data_dir=tmp_path)


def test_lockstep_strict_mode_and_stamped_answers():
    strict = LockstepGate(0.2, slack_periods=0)
    strict.observe(None, now_us=0)                 # before any stamp: an untimed message answers
    assert strict.satisfied(0)
    strict.finish(0.0, False)
    strict.observe(200, now_us=200_000)
    assert strict.satisfied(200_000) and not strict.satisfied(400_000)
    strict.finish(0.0, False)
    strict.observe(None, now_us=400_000)           # once stamps were seen only stamps answer
    assert not strict.satisfied(400_000)
    with pytest.raises(ValueError):
        LockstepGate(0.2, slack_periods=2)
