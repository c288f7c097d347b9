"""sitl.fc.telemetry over real loopback sockets: identity, simulated time, and the magnetometer's field (quiet and storm)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.io.sensors.mag_units import count_to_nt
from sitl.scenario import load_scenario
from sitl.world.build import build_truth_field
from tests.sitl.conftest import body_to_ned
from tests.sitl.fc.helpers import HOLD


def test_heartbeat_identity_and_time(sitl):
    server, client = sitl(speedup=20.0, init_s=0.5)
    hb = client.recv("HEARTBEAT", 5.0)
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)
    assert hb.type == mavlink.MAV_TYPE_SURFACE_BOAT and hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    hb = client.wait_mode(HOLD)
    assert hb.system_status == mavlink.MAV_STATE_STANDBY
    st = client.recv("SYSTEM_TIME")
    start_us = int(load_scenario("paper_pacific").start_posix * 1e6)
    assert st.time_unix_usec == start_us + st.time_boot_ms * 1000        # simulated date, not the wall clock
    raw = client.recv("RAW_IMU")
    assert abs(raw.time_usec // 1000 - st.time_boot_ms) < 2000


def test_heartbeat_px4_convention(sitl):
    server, client = sitl(autopilot="px4", init_s=0.2)
    hb = client.recv("HEARTBEAT", 5.0)
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert (hb.custom_mode >> 16) & 0xFF == 4 and hb.custom_mode >> 24 == 3       # AUTO.LOITER


def test_magnetometer_matches_wmm_declination_inclination(sitl):
    server, client = sitl(scenario="paper_pacific", speedup=60.0, init_s=0.2)   # the truth is WMM
    msgs = client.collect(["RAW_IMU", "ATTITUDE"], 32_000)
    att = {m.time_boot_ms: m for m in msgs if m.get_type() == "ATTITUDE"}
    d_list, i_list = [], []
    for raw in (m for m in msgs if m.get_type() == "RAW_IMU" and m.time_usec >= 2_000_000):
        a = att.get(raw.time_usec // 1000)
        if a is None:
            continue
        n, e, d = body_to_ned(a.roll, a.pitch, a.yaw, count_to_nt(raw.xmag), count_to_nt(raw.ymag), count_to_nt(raw.zmag))
        d_list.append(math.degrees(math.atan2(e, n)))
        i_list.append(math.degrees(math.atan2(d, math.hypot(n, e))))
    assert len(d_list) >= 250
    sc = load_scenario("paper_pacific")
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
    server, client = sitl(scenario="paper_long_storm", speedup=40.0, init_s=0.2, expected_duration_s=60.0,
                          data_dir=str(shared_data))
    msgs = client.collect(["RAW_IMU", "ATTITUDE"], 60_000)
    att = {m.time_boot_ms: m for m in msgs if m.get_type() == "ATTITUDE"}
    sc = load_scenario("paper_long_storm")
    storm = build_truth_field(sc, shared_data, expected_duration_s=60.0)
    quiet = build_truth_field(load_scenario("paper_pacific"))
    meas, truth, calm = [], [], []
    for raw in (m for m in msgs if m.get_type() == "RAW_IMU" and m.time_usec >= 30_000_000):
        a = att.get(raw.time_usec // 1000)
        if a is None:
            continue
        n, e, d = body_to_ned(a.roll, a.pitch, a.yaw, count_to_nt(raw.xmag), count_to_nt(raw.ymag), count_to_nt(raw.zmag))
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
