"""sitl.fc.params over real loopback sockets: the stand-in serves its own parameters like ArduPilot (and PX4).

A pymavlink client (the companion's 1/191) lists, reads and sets the flight controller's
parameters; requests addressed to another component or system get no answer from it.
"""
from __future__ import annotations

from types import SimpleNamespace

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.io.fc_params import judge_heading
from sitl.fc.param_table import (MAV_PARAM_TYPE_INT32, MAV_PARAM_TYPE_REAL32, ardupilot_params, heading_source_of,
                                 px4_params)
from sitl.fc.params import NO_INDEX, float_from_int32_bytes, int32_from_float_bytes
from tests.ports import free_port
from tests.sitl.conftest import Client, gps_scenario

ARDUPILOT_NAMES = {"EK3_SRC1_YAW", "COMPASS_USE", "WP_SPEED", "CRUISE_SPEED", "GPS1_TYPE", "GPS2_TYPE",
                   "ARMING_CHECK", "SIM_GPS1_ENABLE", "FS_EKF_ACTION"}
PX4_NAMES = {"EKF2_MAG_TYPE", "EKF2_GPS_CTRL", "EKF2_EV_CTRL"}


def _fc_param_values(client, timeout: float = 5.0) -> dict:
    """Every PARAM_VALUE from the flight controller (component 1) until the list is complete."""
    got: dict = {}
    count = None
    while count is None or len(got) < count:
        msg = client.recv("PARAM_VALUE", timeout, lambda m: m.get_srcComponent() == 1)
        count = msg.param_count
        got[msg.param_id] = msg
    return got


def _no_fc_param_value(client, sim_ms: int) -> list:
    """PARAM_VALUEs from component 1 while simulated time advances by ``sim_ms`` (none expected)."""
    until = client.time_ms() + sim_ms
    return [m for m in client.collect("PARAM_VALUE", until) if m.get_srcComponent() == 1]


def _set(client, name: str, value: float, kind: int, target=(1, 1)):
    client.mav.param_set_send(target[0], target[1], name.encode(), value, kind)
    return client.recv("PARAM_VALUE", 5.0, lambda m: m.param_id == name and m.get_srcComponent() == 1)


def test_list_read_by_name_and_index(sitl):
    server, client = sitl(speedup=20.0, init_s=0.2)
    client.time_ms()
    client.mav.param_request_list_send(1, 1)
    listed = _fc_param_values(client)
    assert ARDUPILOT_NAMES <= set(listed)
    assert sorted(m.param_index for m in listed.values()) == list(range(len(listed)))
    assert len(listed) == len(server.params)
    # the default (realistic) pacific preset takes its heading from the INS: ExternalNav (6), never a GNSS yaw
    assert listed["EK3_SRC1_YAW"].param_value == 6.0 and listed["EK3_SRC1_YAW"].param_type == MAV_PARAM_TYPE_INT32
    assert listed["CRUISE_SPEED"].param_value == pytest.approx(server.guidance.cruise_speed_mps)
    # by name (index -1: ArduPilot answers with the request's index, 65535 on the wire), then by the listed index
    client.mav.param_request_read_send(1, 1, b"FS_EKF_ACTION", -1)
    by_name = client.recv("PARAM_VALUE", 5.0, lambda m: m.get_srcComponent() == 1)
    assert by_name.param_id == "FS_EKF_ACTION" and by_name.param_value == listed["FS_EKF_ACTION"].param_value
    assert by_name.param_index == NO_INDEX
    client.mav.param_request_read_send(1, 0, b"", listed["FS_EKF_ACTION"].param_index)   # component 0 = any
    by_index = client.recv("PARAM_VALUE", 5.0, lambda m: m.get_srcComponent() == 1)
    assert by_index.param_id == "FS_EKF_ACTION" and by_index.param_index == listed["FS_EKF_ACTION"].param_index


def test_reads_and_lists_are_answered_on_the_asking_link_only(sitl):
    """As ArduPilot (GCS_Param.cpp: a read's reply is queued for the requesting channel, a list is sent
    on it; a set's new value goes to every active channel): a ground station on another link never
    sees the answers to the companion's reads. It did (every link got them, with the table's index),
    and MAVSDK, downloading the companion's list (1/191) there, filed the flight controller's
    EK3_SRC1_YAW and COMPASS_USE among the companion's parameters in two CI runs."""
    from pymavlink import mavutil

    port = free_port()
    _, client = sitl(speedup=20.0, init_s=0.2, masters=(f"tcp:127.0.0.1:{port}",))
    client.time_ms()
    gcs = Client(mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=255, source_component=190))
    try:
        until_ms = gcs.time_ms() + 3000                        # connected: the stand-in sends it its streams
        client.mav.param_request_read_send(1, 1, b"EK3_SRC1_YAW", -1)     # the companion's reads
        client.mav.param_request_read_send(1, 1, b"COMPASS_USE", -1)
        client.mav.param_request_list_send(1, 1)
        assert {"EK3_SRC1_YAW", "COMPASS_USE"} <= set(_fc_param_values(client))
        gcs.mav.param_request_read_send(1, 1, b"CRUISE_SPEED", -1)        # the ground station's own read
        seen = [m for m in gcs.collect("PARAM_VALUE", until_ms) if m.get_srcComponent() == 1]
        assert [m.param_id for m in seen] == ["CRUISE_SPEED"], [m.param_id for m in seen]
        assert "CRUISE_SPEED" not in [m.param_id for m in _no_fc_param_value(client, 1000)]
        # a set's new value goes to every link: to the ground station that set it and to the companion
        gcs.mav.param_set_send(1, 1, b"CRUISE_SPEED", 4.5, MAV_PARAM_TYPE_REAL32)
        for receiver in (gcs, client):
            answer = receiver.recv("PARAM_VALUE", 5.0, lambda m: m.param_id == "CRUISE_SPEED")
            assert answer.param_value == pytest.approx(4.5) and answer.param_index == NO_INDEX
    finally:
        gcs.conn.close()


def test_requests_for_other_components_or_systems_get_no_answer(sitl):
    server, client = sitl(speedup=50.0, init_s=0.2)
    client.time_ms()
    client.mav.param_request_list_send(1, 191)        # the companion's own parameters
    client.mav.param_request_read_send(1, 191, b"EK3_SRC1_YAW", -1)
    client.mav.param_set_send(1, 191, b"CRUISE_SPEED", 2.0, MAV_PARAM_TYPE_REAL32)
    client.mav.param_request_list_send(2, 1)          # another vehicle
    assert _no_fc_param_value(client, 3000) == []
    assert server.params["CRUISE_SPEED"] != 2.0
    client.mav.param_request_list_send(1, 0)          # but a broadcast to our system is answered
    assert ARDUPILOT_NAMES <= set(_fc_param_values(client))


def test_param_set_is_range_checked_and_answered(sitl):
    server, client = sitl(speedup=20.0, init_s=0.2)
    client.time_ms()
    speed = _set(client, "CRUISE_SPEED", 4.5, MAV_PARAM_TYPE_REAL32)
    assert speed.param_value == pytest.approx(4.5) and server.guidance.cruise_speed_mps == pytest.approx(4.5)
    assert _set(client, "EK3_SRC1_YAW", 1, MAV_PARAM_TYPE_INT32).param_value == 1.0
    for value in (4.0, 7.0, 1.5, float("nan")):       # not an EK3 yaw source, not an integer, not a number
        assert _set(client, "EK3_SRC1_YAW", value, MAV_PARAM_TYPE_INT32).param_value == 1.0
    # the refusal is announced (once per 5 s of simulated time) just before the PARAM_VALUE that answers it
    assert "EK3_SRC1_YAW refused: one of 0, 1, 2, 3, 6, 8" in client.statustexts
    too_fast = server.scenario.vehicle.max_speed_mps + 1.0
    assert _set(client, "CRUISE_SPEED", too_fast, MAV_PARAM_TYPE_REAL32).param_value == pytest.approx(4.5)
    assert _set(client, "SYSID_THISMAV", 7, MAV_PARAM_TYPE_INT32).param_value == 1.0     # read-only
    client.mav.param_set_send(1, 1, b"NO_SUCH_PARAM", 1.0, MAV_PARAM_TYPE_REAL32)        # no answer, counted
    assert _no_fc_param_value(client, 2000) == []
    assert server.counters["param_set_unknown"] == 1 and server.counters["param_set_refused"] >= 6


def test_sim_gps1_enable_zero_denies_gps_like_a_fault(sitl, tmp_path):
    server, client = sitl(scenario=str(gps_scenario(tmp_path)), speedup=50.0, init_s=0.2)
    assert client.recv("GPS_RAW_INT", 5.0).fix_type == 3
    assert _set(client, "SIM_GPS1_ENABLE", 0, MAV_PARAM_TYPE_INT32).param_value == 0.0
    assert any("GPS1 disabled" in text for text in client.statustexts)
    assert client.recv("GPS_RAW_INT", 5.0, lambda m: m.fix_type == 0).satellites_visible == 0
    status = client.recv("SYS_STATUS", 5.0)
    assert not status.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_GPS
    assert _set(client, "SIM_GPS1_ENABLE", 1, MAV_PARAM_TYPE_INT32).param_value == 1.0
    assert client.recv("GPS_RAW_INT", 5.0, lambda m: m.fix_type == 3).lat != 0


def test_px4_serves_its_names_bytewise(sitl):
    server, client = sitl(autopilot="px4", speedup=20.0, init_s=0.2)
    client.time_ms()
    client.mav.param_request_list_send(1, 1)
    listed = _fc_param_values(client)
    assert PX4_NAMES <= set(listed) and ARDUPILOT_NAMES & set(listed) == {"SIM_GPS1_ENABLE"}   # a simulator switch
    decoded = {name: int32_from_float_bytes(m.param_value) for name, m in listed.items()
               if m.param_type == MAV_PARAM_TYPE_INT32}
    # the INS's heading (the default pacific): yaw from outside the FC, no GNSS heading (GPS is denied)
    assert decoded["EKF2_MAG_TYPE"] == 5 and decoded["EKF2_GPS_CTRL"] == 7 and decoded["EKF2_EV_CTRL"] == 8
    assert decoded["MAV_SYS_ID"] == 1
    answer = _set(client, "EKF2_GPS_CTRL", float_from_int32_bytes(5), MAV_PARAM_TYPE_INT32)
    assert int32_from_float_bytes(answer.param_value) == 5 and server.params["EKF2_GPS_CTRL"] == 5.0
    assert _set(client, "COM_OF_LOSS_T", 2.5, MAV_PARAM_TYPE_REAL32).param_value == pytest.approx(2.5)
    assert server.guidance.setpoint_timeout_s == pytest.approx(2.5)
    client.mav.command_long_send(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0)
    version = client.recv("AUTOPILOT_VERSION", 5.0)
    assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE


@pytest.mark.parametrize("declared,ek3,mag_type", [(None, 6, 5), ("true", 6, 5), ("ins", 6, 5),
                                                   ("magnetic", 1, 1)])
def test_heading_source_sets_the_yaw_source(declared, ek3, mag_type):
    # the key may sit in [attitude] or [sensors], as an attribute or a mapping key; absent means "true"
    holders = [SimpleNamespace(attitude=SimpleNamespace(heading_source=declared)),
               SimpleNamespace(attitude={"heading_source": declared}),
               SimpleNamespace(sensors=SimpleNamespace(heading_source=declared))]
    for scenario in holders:
        source = heading_source_of(scenario)
        common = dict(sysid=1, cruise_speed_mps=13.9, setpoint_timeout_s=3.0, max_speed_mps=20.0, speedup=1.0,
                      heading_source=source)
        ap = {p.name: p.default for p in ardupilot_params(**common)}
        px4 = {p.name: p.default for p in px4_params(**common)}
        assert (ap["EK3_SRC1_YAW"], px4["EKF2_MAG_TYPE"]) == (ek3, mag_type)


@pytest.mark.parametrize("source", ["true", "ins", "magnetic"])
def test_the_advertised_yaw_source_is_the_one_the_world_gives(source):
    """The companion's own judge (companion.io.fc_params, what fc_view asks) reads the stand-in's
    parameters as compass-derived exactly when the world's yaw comes from the compass, and no GNSS
    yaw is advertised: the stand-in's GPS has no fix after take-off (EK3_SRC1_YAW 2 or 3 with a
    denied GPS, or EKF2_GPS_CTRL's dual-antenna bit, would claim a heading it never gives)."""
    common = dict(sysid=1, cruise_speed_mps=13.9, setpoint_timeout_s=3.0, max_speed_mps=20.0, speedup=1.0,
                  heading_source=source)
    ap = {p.name: p.default for p in ardupilot_params(**common)}
    px4 = {p.name: p.default for p in px4_params(**common)}
    for family, values in (("ardupilot", ap), ("px4", px4)):
        assert judge_heading(family, values).compass_derived is (source == "magnetic"), (family, values)
    assert ap["EK3_SRC1_YAW"] not in (2.0, 3.0) and not int(px4["EKF2_GPS_CTRL"]) & 8


def test_unknown_heading_source_is_a_clear_error():
    with pytest.raises(ValueError, match="heading_source 'compass'.*true, ins, magnetic"):
        heading_source_of(SimpleNamespace(sensors=SimpleNamespace(heading_source="compass")))
