"""sitl.fc.faults: a run of ``python -m sitl.fc`` with every fault kind, checked from its tlog and CSV
(``fc_reboot`` in a run of its own, of a boat cruising armed)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.io.sensors.mag_units import count_to_nt
from sitl.scenario import load_scenario
from sitl.truthlog import read_truth_csv
from tests.sitl.conftest import REPO, body_to_ned, read_tlog, run_cli
from tests.sitl.fc.helpers import closed_udp_port

FAULTS = ["mag_off:10:5", "mag_stuck:20:5", "mag_spike:30:2:5000", "mag_nan:35:3", "heartbeat_off:40:5",
          "link_loss:50:5:0.5", "link_duplicate:55:3:1", "link_delay:58:2:0.5"]


@pytest.fixture(scope="module")
def fault_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("faults")
    # one fault from the scenario file ([[faults]]), the others from --fault
    text = (REPO / "sitl" / "scenarios" / "paper_pacific.toml").read_text()
    text += '\n[[faults]]\nkind = "gps_off"\nat_s = 45.0\nduration_s = 5.0\n'
    scenario = tmp / "pacific_faults.toml"
    scenario.write_text(text)
    args = ["--scenario", str(scenario), "--speedup", "0", "--duration", "62", "--init-s", "0.2", "--seed", "3",
            "--rate", "HIGHRES_IMU:10", "--tlog", "--out", f"udp:127.0.0.1:{closed_udp_port()}"]
    for fault in FAULTS:
        args += ["--fault", fault]
    summary, log_dir = run_cli(args, tmp)
    messages = read_tlog(log_dir / "sitl.tlog")
    start = load_scenario("paper_pacific").start_posix
    for msg in messages:
        msg.sim_s = msg._timestamp - start        # when it was sent, in simulated seconds
    return summary, log_dir, messages


def _of(messages, name, t0=-1.0, t1=1e9):
    return [m for m in messages if m.get_type() == name and t0 <= m.sim_s < t1]


def test_fault_schedule_reported(fault_run):
    summary, log_dir, messages = fault_run
    texts = [m.text for m in _of(messages, "STATUSTEXT")]
    for kind in ("mag_off", "mag_stuck", "mag_spike", "mag_nan", "heartbeat_off", "gps_off", "link_loss"):
        if kind != "link_loss":            # its own announcement may be lost on the lossy link
            assert any(f"{kind} ON" in t for t in texts), kind
        assert summary["counters"][f"fault_{kind}"] == 1
    log = read_truth_csv(log_dir / "truth.csv")
    faults = dict(zip(log["time_s"], log["faults"]))
    assert faults[12.0] == "mag_off" and faults[31.0] == "mag_spike=5000" and faults[9.0] == ""


def test_mag_off_stuck_nan(fault_run):
    _, _, messages = fault_run
    assert all((m.xmag, m.ymag, m.zmag) == (0, 0, 0) for m in _of(messages, "RAW_IMU", 10.0, 15.0))
    assert all((m.xmag, m.ymag, m.zmag) == (0, 0, 0) for m in _of(messages, "SCALED_IMU", 10.0, 15.0))
    around = _of(messages, "RAW_IMU", 5.0, 10.0) + _of(messages, "RAW_IMU", 15.0, 20.0)
    assert all(m.xmag != 0 or m.zmag != 0 for m in around)
    stuck = {(m.xmag, m.ymag, m.zmag) for m in _of(messages, "RAW_IMU", 20.0, 25.0)}
    before = _of(messages, "RAW_IMU", 19.85, 20.0)[-1]
    assert stuck == {(before.xmag, before.ymag, before.zmag)}
    assert len({(m.xmag, m.ymag, m.zmag) for m in _of(messages, "RAW_IMU", 25.0, 30.0)}) > 10
    assert all(m.xmag == m.ymag == m.zmag == 32767 for m in _of(messages, "RAW_IMU", 35.0, 38.0))
    highres = _of(messages, "HIGHRES_IMU", 35.0, 38.0)
    assert highres and all(math.isnan(m.xmag) and m.fields_updated & 0x1C0 for m in highres)
    off = _of(messages, "HIGHRES_IMU", 10.0, 15.0)
    # a dead sensor's zeros, marked as read, as in RAW_IMU: the companion says "reads exactly zero"
    assert off and all((m.xmag, m.ymag, m.zmag) == (0.0, 0.0, 0.0) and m.fields_updated & 0x1C0 == 0x1C0
                       for m in off)
    status = _of(messages, "SYS_STATUS", 10.5, 15.0)
    assert status and all(not m.onboard_control_sensors_health & 4 for m in status)


def test_mag_spike_adds_value_on_each_axis(fault_run):
    _, log_dir, messages = fault_run
    log = read_truth_csv(log_dir / "truth.csv")
    field = {t: (n, e, d) for t, n, e, d in zip(log["time_s"], log["field_n_nt"], log["field_e_nt"], log["field_d_nt"])}
    att = {m.time_boot_ms: m for m in _of(messages, "ATTITUDE")}

    def residual_body(t0, t1):
        out = []
        for raw in _of(messages, "RAW_IMU", t0, t1):
            a = att[raw.time_usec // 1000]
            n, e, d = field[float(math.floor(raw.time_usec / 1e6))]
            # expected body vector: the true NED field seen through the (estimated) attitude
            m_ned = body_to_ned(a.roll, a.pitch, a.yaw, count_to_nt(raw.xmag), count_to_nt(raw.ymag), count_to_nt(raw.zmag))
            out.append(np.subtract(m_ned, (n, e, d)))
        return np.mean(out, axis=0)

    quiet = residual_body(26.0, 30.0)
    spike = residual_body(30.0, 32.0)
    assert np.all(np.abs(quiet) < 60.0)
    # (5000, 5000, 5000) nT in the body frame, seen in NED through a few degrees of tilt
    assert np.all(np.abs(spike - 5000.0) < 800.0)
    assert np.linalg.norm(spike) == pytest.approx(5000.0 * math.sqrt(3.0), rel=0.02)


def test_heartbeat_off_and_gps_off(fault_run):
    _, _, messages = fault_run
    assert len(_of(messages, "HEARTBEAT", 40.0, 45.0)) == 0
    assert len(_of(messages, "HEARTBEAT", 35.0, 40.0)) == 5 and len(_of(messages, "HEARTBEAT", 45.0, 50.0)) == 5
    assert {m.fix_type for m in _of(messages, "GPS_RAW_INT", 45.0, 50.0)} == {0}        # receiver gone
    assert {m.fix_type for m in _of(messages, "GPS_RAW_INT", 40.0, 45.0)} == {1}        # denied (no fix)


def test_link_loss_duplicate_delay(fault_run):
    summary, _, messages = fault_run
    lost = len(_of(messages, "RAW_IMU", 50.0, 55.0))
    assert 12 <= lost <= 38                                   # 50 sent, half dropped (seeded)
    assert summary["counters"]["tx_dropped_fault"] > 50
    dup = _of(messages, "RAW_IMU", 55.0, 58.0)
    assert len(dup) == 60 and all(a.get_seq() == b.get_seq() for a, b in zip(dup[::2], dup[1::2]))
    delayed = [m for m in _of(messages, "RAW_IMU", 58.0, 61.0) if 58.0 <= m.time_usec / 1e6 < 60.0]
    assert delayed and all(m.sim_s - m.time_usec / 1e6 == pytest.approx(0.5, abs=1e-3) for m in delayed)
    # when the delay ends the queue drains in order (a FIFO link): nothing overtakes
    drained = _of(messages, "RAW_IMU", 60.0, 60.6)
    assert [m.time_usec for m in drained] == sorted(m.time_usec for m in drained)
    prompt = _of(messages, "RAW_IMU", 60.6, 62.0)
    assert prompt and all(abs(m.sim_s - m.time_usec / 1e6) < 1e-3 for m in prompt)


def test_storm_onset_fault(tmp_path, shared_data):
    _, log_dir = run_cli(["--scenario", "paper_long_storm", "--speedup", "0", "--duration", "40", "--expected-duration",
                          "60", "--fault", "storm_onset:20", "--data-dir", str(shared_data),
                          "--out", f"udp:127.0.0.1:{closed_udp_port()}"], tmp_path)
    log = read_truth_csv(log_dir / "truth.csv")
    t = np.array(log["time_s"])
    dist = np.abs(np.array([log["dist_n_nt"], log["dist_e_nt"], log["dist_d_nt"]])).sum(axis=0)
    assert np.all(dist[t < 20] == 0.0) and np.all(dist[t >= 20] > 10.0)


def test_fc_reboot_restarts_the_boot_clock_disarms_and_keeps_the_position(tmp_path):
    """An ``fc_reboot`` at 20 s (initialising for 1 s) of a boat cruising armed in GUIDED (--cruise)."""
    summary, log_dir = run_cli(["--speedup", "0", "--duration", "30", "--init-s", "0.2", "--seed", "3",
                                "--cruise", "90:5", "--fault", "fc_reboot:20:1", "--tlog",
                                "--out", f"udp:127.0.0.1:{closed_udp_port()}"], tmp_path)
    messages = read_tlog(log_dir / "sitl.tlog")
    start = load_scenario("paper_pacific").start_posix
    for msg in messages:
        msg.sim_s = msg._timestamp - start
    assert summary["counters"]["fault_fc_reboot"] == 1
    # time_boot_ms and boot-based time_usec restart at 0; SYSTEM_TIME's UNIX time runs on
    for name, stamp_s in (("ATTITUDE", lambda m: m.time_boot_ms * 1e-3), ("RAW_IMU", lambda m: m.time_usec * 1e-6),
                          ("GLOBAL_POSITION_INT", lambda m: m.time_boot_ms * 1e-3),
                          ("SYSTEM_TIME", lambda m: m.time_boot_ms * 1e-3)):
        sent = _of(messages, name)
        assert [m for m in sent if m.sim_s < 20.0] and [m for m in sent if m.sim_s >= 20.0], name
        for m in sent:
            boot = 0.0 if m.sim_s < 20.0 else 20.0
            assert stamp_s(m) == pytest.approx(m.sim_s - boot, abs=2e-3), (name, m.sim_s)
    assert all(m.time_unix_usec * 1e-6 - start == pytest.approx(m.sim_s, abs=2e-3) for m in _of(messages, "SYSTEM_TIME"))
    # armed in GUIDED before; disarmed, INITIALISING for 1 s, then its ready mode (HOLD), not armed again
    beats = [m for m in _of(messages, "HEARTBEAT") if m.get_srcComponent() == 1]
    armed = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert all(m.custom_mode == 15 and m.base_mode & armed for m in beats if 1.0 <= m.sim_s < 20.0)
    booting = [m for m in beats if 20.0 <= m.sim_s < 21.0]
    assert booting and all(m.custom_mode == 16 and not m.base_mode & armed for m in booting)
    ready = [m for m in beats if m.sim_s >= 21.0]
    assert ready and all(m.custom_mode == 4 and not m.base_mode & armed for m in ready)
    texts = [m.text for m in _of(messages, "STATUSTEXT", 20.0)]
    assert any("fc_reboot ON" in t for t in texts) and any("ready, mode HOLD" in t for t in texts)
    # the boat itself goes on from where it was (no jump), stopping once disarmed
    log = read_truth_csv(log_dir / "truth.csv")
    t = np.array(log["time_s"])
    lat, lon = np.radians(log["lat_deg"]), np.radians(log["lon_deg"])
    step_m = 6.371e6 * np.hypot(np.diff(lat), np.diff(lon) * np.cos(lat[1:]))
    assert np.all(step_m <= 5.0 * np.diff(t) + 0.5)
    speed = dict(zip(log["time_s"], log["speed_mps"]))
    assert speed[19.0] == pytest.approx(5.0, abs=0.2) and speed[29.0] <= 1.0     # 0.5 m/s² of braking
    armed_log = dict(zip(log["time_s"], log["armed"]))
    assert armed_log[19.0] == 1 and armed_log[21.0] == 0 and armed_log[29.0] == 0
