"""fcmpc-bench's companion section: its parts run on a real stream and its rows say what they measured.

Cheap by design: no simulator here (``fcmpc-bench`` runs the whole section); no timing is asserted.
"""
from __future__ import annotations

from fcmpc.bench.companion_process import _datagrams, capacity_msgs_per_s, parse_floor_cpu_s
from companion.io.link.conventions import mavlink
from fcmpc.bench.sections import companion_rows


def _stream(seconds: int) -> list[bytes]:
    """An ArduPilot Rover's frames at the stand-in's rates: HEARTBEAT, SYSTEM_TIME and
    GLOBAL_POSITION_INT at 1 Hz, ATTITUDE and HIGHRES_IMU (with its magnetometer) at 10 Hz."""
    enc = mavlink.MAVLink(None, 1, 1)
    frames = []

    def add(msg) -> None:
        frames.append(msg.pack(enc))
        enc.seq = (enc.seq + 1) % 256

    for tenth in range(seconds * 10):
        ms = 1000 + tenth * 100
        if tenth % 10 == 0:
            add(enc.heartbeat_encode(10, 3, 0, 4, 4))
            add(enc.system_time_encode(1_700_000_000_000_000 + ms * 1000, ms))
            add(enc.global_position_int_encode(ms, 325000000, 1522500000, 0, 0, 0, 0, 0, 0))
        add(enc.highres_imu_encode(ms * 1000, 0.0, 0.0, -9.81, 0.0, 0.0, 0.001, 0.2, 0.05, 0.4, 1013.0, 0.0, 0.0,
                                   20.0, 0x1FF, 0))
        add(enc.attitude_encode(ms, 0.0, 0.0, 0.5, 0.0, 0.0, 0.001))
    return frames


def test_the_capacity_replay_and_the_parse_floor_run_on_a_recorded_stream(tmp_path):
    frames = _stream(60)
    datagrams = _datagrams(frames)
    assert b"".join(datagrams) == b"".join(frames) and max(map(len, datagrams)) <= 1400
    cpu_s, parsed = parse_floor_cpu_s(datagrams)
    assert parsed == len(frames) and cpu_s >= 0.0
    rate, others_cpu_s = capacity_msgs_per_s(datagrams, "NAV_PERIOD_S 60\n", tmp_path)
    assert rate > 0.0 and others_cpu_s >= 0.0


def test_the_rows_put_the_missions_cpu_beside_the_parse_floor_and_the_capacity_beside_its_first_version():
    rows = companion_rows({"mission_cpu_s_per_sim_hour": 12.5, "parse_floor_cpu_s_per_sim_hour": 0.9,
                           "messages_per_sim_hour": 87500, "lockstep_sim_speedup": 600.0, "capacity_msgs_per_s": 60000.0,
                           "capacity_spread_msgs_per_s": [52000, 61000], "capacity_other_threads_cpu_s": 4.25,
                           "capacity_parse_floor_msgs_per_s": 130000.0})
    cpu, speedup, capacity, spread, others, floor = rows
    assert cpu[1] == "12.5 s" and "87,500 messages" in cpu[2] and cpu[2].endswith("0.9 s")
    assert speedup[:2] == ("companion lockstep_sim_speedup", "600.0")
    assert capacity[1] == "60000.0" and "55,400" in capacity[2] and capacity[3] == ">= 55,000"
    assert others[1] == "4.25 s" and "prediction" in others[0]
    assert spread[1] == "52000-61000" and floor[1] == "130000.0" and "parse_buffer" in floor[2]
