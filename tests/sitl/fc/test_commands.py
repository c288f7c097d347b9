"""sitl.fc.commands over real loopback sockets: arming, modes, setpoints, heading/speed changes, TIMESYNC, REQUEST_MESSAGE, estimates."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.truthlog import read_truth_csv
from tests.sitl.conftest import gps_scenario
from tests.sitl.fc.helpers import (ARM, DO_SET_MODE, GUIDED, HOLD, VEL_YAW_MASK, Answering, arm_guided,
                                   send_velocity, stop_and_wait, stream_velocity)


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
    # GUID_TIMEOUT 60 s: at 100x a stall of this client of 30 ms of wall time is the default 3 s of
    # simulated time, and the vehicle slowed for a lost setpoint (a CI run at load 3-4: 5.85 m/s);
    # what is judged here is the course and speed flown, the timeout is test_velocity_setpoint_truth_log_and_timeout's
    server, client = sitl(scenario=str(scenario), speedup=100.0, init_s=0.2, setpoint_timeout_s=60.0)
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
    # in lockstep with this client, which answers every boundary (Answering): the 3 s setpoint timeout
    # is simulated time whatever the load (wall-paced at 10x it was 300 ms of this client's wall time,
    # and a loaded machine stalled it that long: 2 timeouts counted in 2 of 3 loaded runs)
    server, client = sitl(scenario="paper_pacific", lockstep=True, speedup=None, init_s=0.2,   # exact motion
                          log_dir=str(tmp_path / "log"))
    companion = Answering(client)
    companion.arm_guided()
    t0 = companion.time_ms()
    companion.steer = (0.0, 5.0)                                # due east at 5 m/s, a setpoint every boundary
    companion.until(t0 + 30_000)
    companion.steer = None                                      # alive, no more setpoints
    t_stop = companion.last_ms
    companion.recv("STATUSTEXT", lambda m: "timeout" in m.text)
    hb = companion.recv("HEARTBEAT", lambda m: m.get_srcComponent() == 1)
    assert hb.custom_mode == GUIDED                             # ArduPilot stays in GUIDED, stopped
    t_end = companion.time_ms()
    companion.until(t_end + 15_000)                             # time to decelerate
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
    # from the simulated instant the timeout dropped the command (in the truth log: the client's own
    # reading of the time lags the simulator's on a loaded machine): 10 s to decelerate from 5 m/s
    cmd = np.array(log["cmd_speed_mps"])
    timed_out = t[(t > t_stop / 1000) & (cmd == 0.0)][0]
    stopped = t > timed_out + 5.0 / 0.5 + 1.0
    assert stopped.sum() > 3 and np.all(speed[stopped] == 0.0)
    assert server.guidance.counters.get("setpoint_timeouts", 0) == 1


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
    server, client = sitl(scenario="paper_pacific", speedup=100.0, init_s=0.2)   # exact motion
    arm_guided(client)
    assert client.command(mavlink.MAV_CMD_GUIDED_CHANGE_HEADING, 0, 270.0, 0).result == mavlink.MAV_RESULT_ACCEPTED
    assert client.command(mavlink.MAV_CMD_GUIDED_CHANGE_SPEED, 1, 4.0).result == mavlink.MAV_RESULT_ACCEPTED
    client.collect("GLOBAL_POSITION_INT", client.time_ms() + 70_000)       # longer than any setpoint timeout
    assert math.degrees(server.state.course_rad) == pytest.approx(270.0, abs=0.01)
    assert server.state.speed_mps == pytest.approx(4.0)


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


def test_commands_are_acknowledged_on_the_asking_link_only(sitl):
    """As ArduPilot (GCS_MAVLINK answers a command with ``mavlink_msg_command_ack_send(chan, ...)``, the
    channel it came in on): a ground station on another link never sees the acknowledgements of the
    companion's commands, and the companion never sees the ground station's. Every link got every
    COMMAND_ACK before."""
    from pymavlink import mavutil

    from tests.ports import free_port
    from tests.sitl.conftest import Client

    port = free_port()
    _, client = sitl(speedup=20.0, init_s=0.2, masters=(f"tcp:127.0.0.1:{port}",))
    client.time_ms()
    gcs = Client(mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=255, source_component=190))
    try:
        gcs.time_ms()                                              # connected: it receives the streams
        interval = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
        capabilities = mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
        assert client.command(interval, mavlink.MAVLINK_MSG_ID_ATTITUDE, 100000).result == \
            mavlink.MAV_RESULT_ACCEPTED
        seen_by_gcs = [m.command for m in gcs.collect("COMMAND_ACK", client.time_ms() + 1000)]
        assert interval not in seen_by_gcs, seen_by_gcs
        assert gcs.command(capabilities, 1).result == mavlink.MAV_RESULT_ACCEPTED
        seen_by_companion = [m.command for m in client.collect("COMMAND_ACK", gcs.time_ms() + 1000)]
        assert capabilities not in seen_by_companion, seen_by_companion
    finally:
        gcs.conn.close()
