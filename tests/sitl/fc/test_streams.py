"""sitl.fc.streams over real loopback sockets: message intervals change what arrives how often."""
from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.sitl.conftest import sim_ms
from tests.sitl.fc.helpers import GET_INTERVAL, SET_INTERVAL


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
    # it has no answer: the window starts after one that follows it (a loaded client reads a SYSTEM_TIME
    # older than the request by more than the 1 s margin, 20 ms of wall time at 50x)
    client.mav.command_long_send(1, 1, GET_INTERVAL, 0, 30, 0, 0, 0, 0, 0, 0)
    assert client.recv("MESSAGE_INTERVAL", 5.0, lambda m: m.message_id == 30).interval_us == 1_000_000
    t1 = client.time_ms() + 1000
    att = [m for m in client.collect("ATTITUDE", t1 + 5000) if t1 <= m.time_boot_ms < t1 + 5000]
    assert len(att) == pytest.approx(5, abs=1)


def test_reset_after_a_reboot_restores_the_start_up_rates():
    from sitl.clock import SimClock
    from sitl.fc.streams import DEFAULT_RATES_HZ, StreamScheduler

    clock = SimClock(5_000_000)
    streams = StreamScheduler({name: (lambda: None) for name in DEFAULT_RATES_HZ}, ("ATTITUDE:4",), clock, None, {})
    assert streams.set_message_interval(27, 500_000) == mavlink.MAV_RESULT_ACCEPTED    # RAW_IMU 2 Hz
    assert streams.set_message_interval(30, -1) == mavlink.MAV_RESULT_ACCEPTED         # ATTITUDE off
    clock.t_us = 9_000_000
    streams.reset()
    assert streams.streams["RAW_IMU"].interval_us == 100_000          # the default 10 Hz again
    assert streams.streams["ATTITUDE"].interval_us == 250_000         # the --rate given at start
    assert streams.streams["RAW_IMU"].next_us == 9_000_000
