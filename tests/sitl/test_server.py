"""The simulator driven by pymavlink over real loopback sockets (the issue's proof list)."""
from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.scenario import load_scenario
from sitl.truthlog import read_truth_csv
from sitl.world.build import build_truth_field
from tests.sitl.conftest import body_to_ned, gps_scenario, sim_ms

ARM, DO_SET_MODE = mavlink.MAV_CMD_COMPONENT_ARM_DISARM, mavlink.MAV_CMD_DO_SET_MODE
SET_INTERVAL, GET_INTERVAL = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAV_CMD_GET_MESSAGE_INTERVAL
HOLD, GUIDED = 4, 15
# velocity only: ignore position (1|2|4), accel (64|128|256), yaw rate (2048); yaw as given by the caller
VEL_YAW_MASK = 0b0000_1001_1100_0111
VEL_ONLY_MASK = VEL_YAW_MASK | 1024


def stop_and_wait(server, timeout: float = 10.0) -> None:
    """Stop the simulator and wait until its records are closed."""
    server.request_stop()
    deadline = time.monotonic() + timeout
    while not server.summary and time.monotonic() < deadline:
        time.sleep(0.02)
    assert server.summary


def arm_guided(client) -> None:
    client.wait_mode(HOLD)
    assert client.command(ARM, 1).result == mavlink.MAV_RESULT_ACCEPTED
    assert client.command(DO_SET_MODE, 1, GUIDED).result == mavlink.MAV_RESULT_ACCEPTED


def send_velocity(client, t_ms: int, vn: float, ve: float, yaw: float = 0.0, mask: int = VEL_ONLY_MASK) -> None:
    client.mav.set_position_target_global_int_send(t_ms, 1, 1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mask,
                                                   0, 0, 0.0, vn, ve, 0.0, 0.0, 0.0, 0.0, yaw, 0.0)


def stream_velocity(client, until_ms: int, vn: float, ve: float, **kw) -> None:
    """Answer every SYSTEM_TIME-paced 5 Hz tick with a setpoint, until simulated ``until_ms``."""
    next_ms = 0
    while True:
        msg = client.recv(["GLOBAL_POSITION_INT"], 10.0)
        t = msg.time_boot_ms
        if t >= next_ms:
            send_velocity(client, t, vn, ve, **kw)
            next_ms = t + 200
        if t >= until_ms:
            return


def test_heartbeat_identity_and_time(sitl):
    server, client = sitl(speedup=20.0, init_s=0.5)
    hb = client.recv("HEARTBEAT", 5.0)
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)
    assert hb.type == mavlink.MAV_TYPE_SURFACE_BOAT and hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    hb = client.wait_mode(HOLD)
    assert hb.system_status == mavlink.MAV_STATE_STANDBY
    st = client.recv("SYSTEM_TIME")
    start_us = int(load_scenario("pacific").start_posix * 1e6)
    assert st.time_unix_usec == start_us + st.time_boot_ms * 1000        # simulated date, not the wall clock
    raw = client.recv("RAW_IMU")
    assert abs(raw.time_usec // 1000 - st.time_boot_ms) < 2000


def test_heartbeat_px4_convention(sitl):
    server, client = sitl(autopilot="px4", init_s=0.2)
    hb = client.recv("HEARTBEAT", 5.0)
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert (hb.custom_mode >> 16) & 0xFF == 4 and hb.custom_mode >> 24 == 3       # AUTO.LOITER


def test_message_interval_changes_stream_rate(sitl):
    server, client = sitl(speedup=50.0)
    client.time_ms()
    assert client.command(SET_INTERVAL, 27, 500_000).result == mavlink.MAV_RESULT_ACCEPTED   # RAW_IMU 2 Hz
    assert client.command(SET_INTERVAL, 26, 40_000).result == mavlink.MAV_RESULT_ACCEPTED    # SCALED_IMU 25 Hz
    assert client.command(SET_INTERVAL, 32, -1).result == mavlink.MAV_RESULT_ACCEPTED        # LOCAL_POSITION_NED off
    assert client.command(SET_INTERVAL, 12345, 100_000).result == mavlink.MAV_RESULT_UNSUPPORTED
    t0 = client.time_ms() + 1000
    msgs = client.collect(["RAW_IMU", "SCALED_IMU", "LOCAL_POSITION_NED"], t0 + 10_000)
    window = [m for m in msgs if t0 <= sim_ms(m) < t0 + 10_000]
    counts = {name: sum(1 for m in window if m.get_type() == name) for name in ("RAW_IMU", "SCALED_IMU",
                                                                                "LOCAL_POSITION_NED")}
    assert counts["RAW_IMU"] == pytest.approx(20, abs=1)        # 10 simulated seconds at 2 Hz
    assert counts["SCALED_IMU"] == pytest.approx(250, abs=2)
    assert counts["LOCAL_POSITION_NED"] == 0
    client.mav.command_long_send(1, 1, GET_INTERVAL, 0, 27, 0, 0, 0, 0, 0, 0)   # reply, then the ACK
    interval = client.recv("MESSAGE_INTERVAL", 5.0, lambda m: m.message_id == 27)
    assert interval.interval_us == 500_000
    # REQUEST_DATA_STREAM (MAV_DATA_STREAM_EXTRA1 = ATTITUDE) at 1 Hz
    client.mav.request_data_stream_send(1, 1, mavlink.MAV_DATA_STREAM_EXTRA1, 1, 1)
    t1 = client.time_ms() + 1000
    att = [m for m in client.collect("ATTITUDE", t1 + 5000) if t1 <= m.time_boot_ms < t1 + 5000]
    assert len(att) == pytest.approx(5, abs=1)


def test_arming_and_modes_accepted_and_refused(sitl):
    server, client = sitl(speedup=20.0, init_s=1e6)           # stays INITIALISING
    hb = client.recv("HEARTBEAT")
    assert hb.custom_mode == 16 and hb.system_status == mavlink.MAV_STATE_BOOT
    assert client.command(ARM, 1).result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    assert client.command(DO_SET_MODE, 1, GUIDED).result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED


def test_arming_guided_and_refusals_when_ready(sitl):
    server, client = sitl(speedup=20.0, init_s=0.2)
    client.wait_mode(HOLD)
    assert client.command(DO_SET_MODE, 1, 99).result == mavlink.MAV_RESULT_FAILED        # unknown mode
    assert client.command(DO_SET_MODE, 1, 10).result == mavlink.MAV_RESULT_FAILED        # AUTO without mission
    assert client.command(DO_SET_MODE, 0, GUIDED).result == mavlink.MAV_RESULT_UNSUPPORTED  # no custom flag
    assert client.command(ARM, 7).result == mavlink.MAV_RESULT_DENIED
    assert client.command(mavlink.MAV_CMD_GUIDED_CHANGE_SPEED, 1, 5.0).result == mavlink.MAV_RESULT_DENIED
    assert client.command(31999, 1, 2, 3).result == mavlink.MAV_RESULT_UNSUPPORTED
    # a velocity setpoint while disarmed is ignored and counted
    t = client.time_ms()
    for k in range(5):
        send_velocity(client, t + k, 5.0, 0.0)
    client.recv("STATUSTEXT", 5.0, lambda m: "ignored" in m.text)
    assert client.command(ARM, 1).result == mavlink.MAV_RESULT_ACCEPTED
    assert client.command(DO_SET_MODE, 1, GUIDED).result == mavlink.MAV_RESULT_ACCEPTED
    hb = client.wait_mode(GUIDED)
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED and hb.system_status == mavlink.MAV_STATE_ACTIVE
    # SET_MODE message (legacy) answers with COMMAND_ACK command=11
    client.mav.set_mode_send(1, 1, HOLD)
    assert client.recv("COMMAND_ACK", 5.0, lambda m: m.command == 11).result == mavlink.MAV_RESULT_ACCEPTED
    client.wait_mode(HOLD)
    assert server.guidance.counters.get("setpoints_ignored_mode", 0) >= 5
    assert server.state.speed_mps == 0.0


def test_velocity_setpoint_moves_vehicle_at_commanded_course_and_speed(sitl, tmp_path):
    scenario = gps_scenario(tmp_path)
    server, client = sitl(scenario=str(scenario), speedup=100.0, init_s=0.2)
    arm_guided(client)
    t0 = client.time_ms()
    vn, ve = 6.0 * math.cos(math.radians(60.0)), 6.0 * math.sin(math.radians(60.0))   # course 060, 6 m/s
    stream_velocity(client, t0 + 40_000, vn, ve)
    gps = client.recv("GPS_RAW_INT")
    assert gps.fix_type == 3
    assert gps.vel / 100.0 == pytest.approx(6.0, abs=0.05)
    assert gps.cog / 100.0 == pytest.approx(60.0, abs=0.5)
    gpi = client.recv("GLOBAL_POSITION_INT")      # GPS-aided FC solution: velocity in cm/s, hdg in cdeg
    assert gpi.vx / 100.0 == pytest.approx(vn, abs=0.3) and gpi.vy / 100.0 == pytest.approx(ve, abs=0.3)
    assert gpi.hdg / 100.0 == pytest.approx(60.0, abs=0.5)
    # yaw not masked: the course follows yaw (here 200 deg) rather than the velocity's direction
    stream_velocity(client, client.time_ms() + 60_000, vn, ve, yaw=math.radians(200.0), mask=VEL_YAW_MASK)
    assert math.degrees(server.state.course_rad) == pytest.approx(200.0, abs=0.5)
    assert server.state.speed_mps == pytest.approx(6.0, abs=1e-6)


def test_velocity_setpoint_truth_log_and_timeout(sitl, tmp_path):
    server, client = sitl(speedup=100.0, init_s=0.2, log_dir=str(tmp_path / "log"))
    arm_guided(client)
    t0 = client.time_ms()
    stream_velocity(client, t0 + 30_000, 0.0, 5.0)             # due east at 5 m/s
    t_stop = client.time_ms()
    client.recv("STATUSTEXT", 10.0, lambda m: "timeout" in m.text)
    hb = client.recv("HEARTBEAT")
    assert hb.custom_mode == GUIDED                             # ArduPilot stays in GUIDED, stopped
    t_end = client.time_ms()
    client.collect("GLOBAL_POSITION_INT", t_end + 15_000)       # time to decelerate
    stop_and_wait(server)
    log = read_truth_csv(tmp_path / "log" / "truth.csv")
    t = np.array(log["time_s"])
    course, speed = np.array(log["course_deg"]), np.array(log["speed_mps"])
    cruising = (t > t0 / 1000 + 17) & (t < t_stop / 1000)      # 15 s to turn 90 deg, 10 s to reach 5 m/s
    assert cruising.sum() > 5
    assert np.allclose(speed[cruising], 5.0, atol=1e-6) and np.allclose(course[cruising], 90.0, atol=0.01)
    lon = np.array(log["lon_deg"])
    assert lon[cruising][-1] > lon[cruising][0]                 # moved east
    assert np.allclose(np.array(log["cmd_speed_mps"])[cruising], 5.0)
    stopped = t > t_stop / 1000 + 3.0 + 5.0 / 0.5 + 1.5
    assert stopped.sum() > 3 and np.all(speed[stopped] == 0.0)
    assert server.guidance.counters.get("setpoint_timeouts", 0) == 1


def test_magnetometer_matches_wmm_declination_inclination(sitl):
    server, client = sitl(speedup=60.0, init_s=0.2)
    msgs = client.collect(["RAW_IMU", "ATTITUDE"], 32_000)
    att = {m.time_boot_ms: m for m in msgs if m.get_type() == "ATTITUDE"}
    d_list, i_list = [], []
    for raw in (m for m in msgs if m.get_type() == "RAW_IMU" and m.time_usec >= 2_000_000):
        a = att.get(raw.time_usec // 1000)
        if a is None:
            continue
        n, e, d = body_to_ned(a.roll, a.pitch, a.yaw, raw.xmag * 100.0, raw.ymag * 100.0, raw.zmag * 100.0)
        d_list.append(math.degrees(math.atan2(e, n)))
        i_list.append(math.degrees(math.atan2(d, math.hypot(n, e))))
    assert len(d_list) >= 250
    sc = load_scenario("pacific")
    wmm = build_truth_field(sc).model.elements(sc.start_lat_deg, sc.start_lon_deg, 0.0, sc.year)
    # 1-sigma of one sample: noise and the 100 nT quantisation over H (D) or F (I), attitude noise
    quant = 100.0 / math.sqrt(12.0)
    sigma_d = math.degrees(math.hypot(sc.sensors.mag_noise_nt, quant) / wmm.h_nt)
    sigma_i = math.degrees(math.hypot(sc.sensors.mag_noise_nt, quant) / wmm.f_nt)
    n = len(d_list)
    assert np.std(d_list) == pytest.approx(sigma_d, rel=0.3)
    assert np.mean(d_list) == pytest.approx(wmm.decl_deg, abs=5 * sigma_d / math.sqrt(n) + 0.005)
    assert np.mean(i_list) == pytest.approx(wmm.incl_deg, abs=5 * sigma_i / math.sqrt(n) + 0.005)
    # the body vector really is tilted: without tilt compensation inclination is off by the wave roll/pitch
    rolls = [abs(a.roll) for a in att.values()]
    assert max(rolls) > math.radians(2.0)


def test_storm_changes_the_field_by_the_scenario_disturbance(sitl, shared_data):
    # the 6-hour long storm compressed into 60 simulated seconds: the main phase comes quickly
    server, client = sitl(scenario="long_storm", speedup=40.0, init_s=0.2, expected_duration_s=60.0,
                          data_dir=str(shared_data))
    msgs = client.collect(["RAW_IMU", "ATTITUDE"], 60_000)
    att = {m.time_boot_ms: m for m in msgs if m.get_type() == "ATTITUDE"}
    sc = load_scenario("long_storm")
    storm = build_truth_field(sc, shared_data, expected_duration_s=60.0)
    quiet = build_truth_field(load_scenario("pacific"))
    meas, truth, calm = [], [], []
    for raw in (m for m in msgs if m.get_type() == "RAW_IMU" and m.time_usec >= 30_000_000):
        a = att.get(raw.time_usec // 1000)
        if a is None:
            continue
        n, e, d = body_to_ned(a.roll, a.pitch, a.yaw, raw.xmag * 100.0, raw.ymag * 100.0, raw.zmag * 100.0)
        meas.append((math.degrees(math.atan2(e, n)), math.degrees(math.atan2(d, math.hypot(n, e)))))
        # the simulator evaluates the field once per simulated second (--field-step 1)
        t_field = math.floor(raw.time_usec / 1e6)
        truth.append([float(v) for v in storm.decl_incl_deg(sc.start_lat_deg, sc.start_lon_deg, 0.0, t_field)])
        calm.append([float(v) for v in quiet.decl_incl_deg(sc.start_lat_deg, sc.start_lon_deg, 0.0, t_field)])
    meas, truth, calm = np.array(meas), np.array(truth), np.array(calm)
    assert len(meas) >= 250
    shift = (truth - calm).mean(axis=0)
    assert abs(shift[1]) > 0.12                       # the storm moves inclination by > 0.12 deg here
    measured_shift = (meas - calm).mean(axis=0)       # what a client sees against the quiet WMM
    assert abs(measured_shift[0] - shift[0]) < 0.04 and abs(measured_shift[1] - shift[1]) < 0.03


def test_malformed_flood_does_not_stop_the_simulator(sitl):
    server, client = sitl(speedup=20.0, init_s=0.2)
    client.wait_mode(HOLD)
    sock = client.conn.port
    target = server.links[0].local_address
    rng = np.random.default_rng(3)
    good = mavlink.MAVLink(None, 1, 191)
    valid = good.command_long_encode(1, 1, SET_INTERVAL, 0, 27, 100_000, 0, 0, 0, 0, 0).pack(good)
    for k in range(400):
        kind = k % 6
        if kind == 0:
            data = rng.integers(0, 256, int(rng.integers(1, 600)), dtype=np.uint8).tobytes()
        elif kind == 1:                                     # valid frame, CRC broken
            data = valid[:-1] + bytes([valid[-1] ^ 0xFF])
        elif kind == 2:                                     # truncated frame
            data = valid[: int(rng.integers(1, len(valid) - 1))]
        elif kind == 3:                                     # unknown message id 0xABCDE
            data = bytes([0xFD, 4, 0, 0, 0, 1, 191, 0xDE, 0xBC, 0x0A, 1, 2, 3, 4, 0x12, 0x34])
        elif kind == 4:                                     # markers with absurd lengths, a MAVLink 1 header
            data = b"\xfd\xff\xff" + b"\xfe\xff" * 50
        else:                                               # many frames glued with garbage between
            data = b"\x00\xfd" + valid[:7] + b"\xfe\x09" + rng.bytes(30)
        sock.sendto(data, target)
    # NaN / out-of-range setpoints and commands
    t = client.time_ms()
    send_velocity(client, t, math.nan, 1.0)
    send_velocity(client, t, 1e6, 0.0)
    client.mav.command_long_send(1, 1, ARM, 0, math.nan, 0, 0, 0, 0, 0, 0)
    client.mav.command_long_send(1, 1, DO_SET_MODE, 0, math.nan, math.inf, 0, 0, 0, 0, 0)
    # still alive: heartbeats continue and a command after the flood is acknowledged
    t_after = client.time_ms()
    client.recv("HEARTBEAT", 5.0, lambda m: True)
    assert client.command(SET_INTERVAL, 27, 100_000).result == mavlink.MAV_RESULT_ACCEPTED
    assert client.time_ms() > t_after
    c = server.counters
    assert c.get("rx_bad_frames", 0) > 50 and c.get("rx_garbage_bytes", 0) > 1000
    assert c.get("rx_unknown_messages", 0) >= 60
    assert c.get("rx_handler_errors", 0) == 0
    assert server.guidance.counters.get("setpoints_ignored_mode", 0) + c.get("setpoints_rejected_nan", 0) >= 1


def test_nan_and_out_of_limit_setpoints_are_rejected_when_guided(sitl):
    server, client = sitl(speedup=20.0, init_s=0.2)
    arm_guided(client)
    t = client.time_ms()
    send_velocity(client, t, math.nan, 1.0)
    send_velocity(client, t, 0.0, math.inf)
    send_velocity(client, t, 100.0, 0.0)                                       # above the 60 km/h limit
    send_velocity(client, t, 1.0, 1.0, yaw=math.nan, mask=VEL_YAW_MASK)
    client.recv("STATUSTEXT", 5.0, lambda m: "rejected" in m.text)
    client.time_ms()
    client.time_ms()
    c = server.counters
    assert c.get("setpoints_rejected_nan", 0) == 3 and c.get("setpoints_rejected_limit", 0) == 1
    assert server.state.speed_mps == 0.0
    assert client.command(mavlink.MAV_CMD_GUIDED_CHANGE_HEADING, 0, math.nan).result == mavlink.MAV_RESULT_DENIED
    assert client.command(mavlink.MAV_CMD_GUIDED_CHANGE_SPEED, 1, -3.0).result == mavlink.MAV_RESULT_DENIED


def test_guided_change_heading_and_speed(sitl):
    server, client = sitl(speedup=100.0, init_s=0.2)
    arm_guided(client)
    assert client.command(mavlink.MAV_CMD_GUIDED_CHANGE_HEADING, 0, 270.0, 0).result == mavlink.MAV_RESULT_ACCEPTED
    assert client.command(mavlink.MAV_CMD_GUIDED_CHANGE_SPEED, 1, 4.0).result == mavlink.MAV_RESULT_ACCEPTED
    client.collect("GLOBAL_POSITION_INT", client.time_ms() + 70_000)       # longer than any setpoint timeout
    assert math.degrees(server.state.course_rad) == pytest.approx(270.0, abs=0.01)
    assert server.state.speed_mps == pytest.approx(4.0)


def test_tcp_master_like_ardupilot_sitl(tmp_path):
    import threading
    from pymavlink import mavutil
    from sitl.server import ServerConfig, SitlServer

    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    server = SitlServer(ServerConfig(masters=(f"tcp:127.0.0.1:{port}",), speedup=20.0, quiet=True,
                                     log_dir=str(tmp_path), init_s=0.2))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        conn = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=255, source_component=190)
        hb = conn.wait_heartbeat(timeout=5)
        assert hb is not None and hb.type == mavlink.MAV_TYPE_SURFACE_BOAT
        conn.mav.param_request_list_send(1, 1)
        names = set()
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and len(names) < len(server.params):
            msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=1)
            if msg is not None:
                names.add(msg.param_id)
        assert {"SYSID_THISMAV", "GUID_TIMEOUT"} <= names
        conn.mav.command_long_send(1, 1, SET_INTERVAL, 0, 30, 50_000, 0, 0, 0, 0, 0)
        ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
        assert ack is not None and ack.result == mavlink.MAV_RESULT_ACCEPTED
        conn.close()
    finally:
        server.request_stop()
        thread.join(10)
    assert not thread.is_alive()


def test_timesync_and_request_message(sitl):
    server, client = sitl(speedup=10.0, init_s=0.2)
    client.time_ms()                  # a udpin client can answer only after it has heard the vehicle
    client.mav.timesync_send(0, 123456789)
    reply = client.recv("TIMESYNC", 5.0, lambda m: m.ts1 == 123456789)
    t = client.time_ms()
    assert reply.tc1 > 0 and abs(reply.tc1 / 1e6 - t) <= 1000     # nanoseconds of simulated time
    assert client.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 148).result == mavlink.MAV_RESULT_ACCEPTED
    version = client.recv("AUTOPILOT_VERSION")
    assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    assert client.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 242).result == mavlink.MAV_RESULT_ACCEPTED
    home = client.recv("HOME_POSITION")
    assert abs(home.latitude / 1e7 - 33.0) < 0.2                # the FC's own (INS) idea of home


def test_lockstep_advances_only_with_the_companion(sitl):
    server, client = sitl(lockstep=True, lockstep_timeout_s=0.3, lockstep_start_timeout_s=10.0, init_s=0.2,
                          speedup=None, duration_s=None)
    # answer each boundary (SYSTEM_TIME at every 0.2 s) with a setpoint stamped with that time
    answered = 0
    last = -1
    while answered < 50:
        st = client.recv("SYSTEM_TIME", 5.0)
        if st.time_boot_ms > last:
            last = st.time_boot_ms
            client.mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            answered += 1
    t_answered = client.time_ms()
    assert server.gate.timeouts == 0
    assert t_answered == pytest.approx(50 * 200, abs=600)
    # silence: one period per timeout (0.3 s wall), never a deadlock
    time.sleep(1.0)
    advanced = server.t_us / 1000 - t_answered
    assert 0 < advanced <= 6 * 200
    assert server.gate.timeouts >= 2


def test_lockstep_timed_answers_are_exact(sitl):
    server, client = sitl(lockstep=True, lockstep_timeout_s=2.0, init_s=0.2, speedup=None, duration_s=None)
    for _ in range(30):
        st = client.recv("SYSTEM_TIME", 5.0)
        # a setpoint stamped with the boundary it answers (ignored in HOLD, but it answers the step)
        send_velocity(client, st.time_boot_ms, 0.0, 0.0)
    time.sleep(0.3)
    # the simulator can be at most one period ahead of the last answered boundary
    assert server.gate.timeouts == 0
    assert server.gate.peer_time_ms >= 0
    assert server.t_us / 1000 <= server.gate.peer_time_ms + 2 * 200


def _scripted_companion(client, boundaries: int) -> None:
    """A deterministic companion: arm and GUIDED once the vehicle is ready, then at every lockstep
    boundary a setpoint computed from the latest GLOBAL_POSITION_INT, stamped with the boundary."""
    latest = None
    commanded = False
    answered = 0
    while answered < boundaries:
        msg = client.recv(["SYSTEM_TIME", "GLOBAL_POSITION_INT", "HEARTBEAT"], 10.0)
        name = msg.get_type()
        if name == "GLOBAL_POSITION_INT":
            latest = msg
        elif name == "HEARTBEAT":
            if msg.get_srcComponent() == 1 and msg.custom_mode == HOLD and not commanded:
                client.mav.command_long_send(1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0)
                client.mav.command_long_send(1, 1, DO_SET_MODE, 0, 1, GUIDED, 0, 0, 0, 0, 0)
                commanded = True
        else:
            b = msg.time_boot_ms
            north = (32.99 - latest.lat / 1e7) if latest else 0.0
            east = (152.01 - latest.lon / 1e7) if latest else 0.0
            course = math.atan2(east * math.cos(math.radians(33.0)), north)
            speed = 6.0 + 2.0 * math.sin(b / 7000.0)
            send_velocity(client, b, speed * math.cos(course), speed * math.sin(course))
            answered += 1


@pytest.mark.parametrize("slack", [1, 0])
def test_lockstep_closed_loop_is_bit_reproducible(sitl, tmp_path, slack):
    logs = []
    for run in range(2):
        folder = tmp_path / f"run{run}"
        server, client = sitl(lockstep=True, lockstep_slack=slack, speedup=None, duration_s=60.0, init_s=0.2,
                              seed=11, log_dir=str(folder), tlog=str(folder / "sitl.tlog"))
        _scripted_companion(client, boundaries=301)           # 0.0, 0.2, ... 60.0
        stop_and_wait(server)
        assert server.gate.timeouts == 0 and server.summary["sim_s"] == pytest.approx(60.0)
        assert server.state.distance_m > 150.0
        logs.append((folder / "truth.csv").read_bytes())
    assert logs[0] == logs[1]


def test_external_position_estimate_lands_in_truth_log(sitl, tmp_path):
    server, client = sitl(speedup=50.0, init_s=0.2, log_dir=str(tmp_path / "est"))
    client.time_ms()
    client.mav.command_int_send(1, 1, mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_CMD_EXTERNAL_POSITION_ESTIMATE, 0, 0,
                                0.0, 0.0, 250.0, math.nan, int(33.01 * 1e7), int(152.02 * 1e7), math.nan)
    ack = client.recv("COMMAND_ACK", 5.0, lambda m: m.command == mavlink.MAV_CMD_EXTERNAL_POSITION_ESTIMATE)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    client.collect("SYSTEM_TIME", client.time_ms() + 2000)
    stop_and_wait(server)
    log = read_truth_csv(tmp_path / "est" / "truth.csv")
    assert log["est_lat_deg"][-1] == pytest.approx(33.01) and log["est_lon_deg"][-1] == pytest.approx(152.02)
    assert math.isnan(log["est_lat_deg"][0])


def test_routing_between_links(sitl):
    from pymavlink import mavutil

    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    server, client = sitl(speedup=20.0, init_s=0.2, masters=(f"tcp:127.0.0.1:{port}",))
    client.time_ms()
    gcs = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=255, source_component=190)
    try:
        assert gcs.wait_heartbeat(timeout=5) is not None
        # a ground station on TCP asks the companion (1/191, on UDP) for its parameters through the vehicle
        gcs.mav.param_request_list_send(1, 191)
        msg = client.recv("PARAM_REQUEST_LIST", 5.0)
        assert (msg.get_srcSystem(), msg.target_component) == (255, 191)
        # and the companion's answer goes back to the ground station
        client.mav.named_value_float_send(1234, b"FCMPC_D", -3.9)
        got = gcs.recv_match(type="NAMED_VALUE_FLOAT", blocking=True, timeout=5)
        assert got is not None and got.name == "FCMPC_D"
    finally:
        gcs.close()
    assert server.counters.get("rx_routed", 0) >= 2
