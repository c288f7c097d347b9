"""The lockstep relay between ArduPilot's SERIAL1 and the companion (sitl.physics.relay), over real
loopback TCP: a socket stands in for ArduPilot's SERIAL1 port, another for the companion.

What ArduPilot judges a MAVLink GPS's health on (``AP_GPS::update_instance``: the time between the
updates its GPS driver takes, one per loop; over 245 ms twice in a row, or 215 ms on average, is
"not healthy") needs the companion's 10 Hz GPS_INPUT to reach it one frame at a time, 100 ms of
firmware time apart: the relay forwards each released frame at its own stamp plus a fixed latency,
and at most one GPS_INPUT per firmware loop.
"""
from __future__ import annotations

import os
import socket
import time

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from fcmpc.firmware.ardupilot import free_instance  # noqa: E402
from sitl.physics.relay import CompanionRelay, relay_port, serial1_port  # noqa: E402

UNIX0_US = 1_715_364_000_000_000     # SITL's start date, UNIX us at boot


def _read_all(sock: socket.socket, wait_s: float = 0.05) -> bytes:
    out, end = b"", time.monotonic() + wait_s
    while time.monotonic() < end:
        try:
            chunk = sock.recv(65536)
        except BlockingIOError:
            time.sleep(0.002)
            continue
        if not chunk:
            break
        out += chunk
    return out


def _gps_and_setpoint(mav, first_boot_us: int, setpoint_ms: int) -> bytes:
    """Three GPS_INPUT 100 ms apart from ``first_boot_us`` (in UNIX time, as the companion stamps them), then
    a setpoint stamped ``setpoint_ms`` on the boot clock."""
    frames = b""
    for k in range(3):
        frames += mavlink.MAVLink_gps_input_message(
            UNIX0_US + first_boot_us + 100_000 * k, 1, 0, 0, 0, 3, 330_000_000, 1_520_000_000, 0.0,
            1.0, 1.0, 0, 0, 0, 0, 5.0, 5.0, 10, 0).pack(mav)
    return frames + _setpoint(mav, setpoint_ms)


def _setpoint(mav, time_boot_ms: int) -> bytes:
    return mavlink.MAVLink_set_position_target_global_int_message(
        time_boot_ms, 1, 1, 6, 0xDC7, 0, 0, 0.0, 8.0, 0.0, 0.0, 0, 0, 0, 0.0, 0.0).pack(mav)


def test_companion_frames_reach_ardupilot_at_their_stamp_plus_the_latency_one_gps_per_loop():
    instance = free_instance(first=66, last=99)
    fc_server = socket.create_server(("127.0.0.1", serial1_port(instance)))
    relay = CompanionRelay(instance, timeout_s=5.0, hold_from_s=0.0, latency_s=1.0)
    try:
        relay._tries = 0                  # connect at the first pump
        relay.pump_fc()
        fc, _ = fc_server.accept()
        fc.setblocking(False)
        companion = socket.create_connection(("127.0.0.1", relay_port(instance)))
        fc_mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        co_mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
        # ArduPilot at 90.339 s: SYSTEM_TIME (its time_boot_ms truncated to 3 bytes by MAVLink 2) then ATTITUDE
        fc.sendall(mavlink.MAVLink_system_time_message(UNIX0_US + 90_339_000, 90_339).pack(fc_mav)
                   + mavlink.MAVLink_attitude_message(90_400, 0, 0, 0, 0, 0, 0).pack(fc_mav))
        time.sleep(0.05)
        relay.pump_fc()
        assert relay.fc_time_ms == 90_400 and relay.unix_minus_boot_us == UNIX0_US
        # the companion's first frame, a stamped setpoint: released at the first boundary (nothing asked yet)
        companion.sendall(_setpoint(co_mav, 90_100))
        relay.boundary(90_600_000)
        # three GPS_INPUT 100 ms apart (UNIX time) and a setpoint on the boot clock, the boundary's answer
        companion.sendall(_gps_and_setpoint(co_mav, 90_200_000, 90_450))
        time.sleep(0.05)
        relay.boundary(90_800_000)        # the threshold follows 90.4 s: released up to the setpoint
        assert len(relay._due) == 5
        arrived = []
        for now_us in range(90_820_000, 91_600_000, 20_000):   # ArduPilot's loops, 20 ms apart
            relay.deliver(now_us)
            parser = mavlink.MAVLink(None)
            arrived += [(now_us, m.get_type()) for m in parser.parse_buffer(_read_all(fc, 0.01)) or ()]
        assert arrived == [(91_100_000, "SET_POSITION_TARGET_GLOBAL_INT"), (91_200_000, "GPS_INPUT"),
                           (91_300_000, "GPS_INPUT"), (91_400_000, "GPS_INPUT"),
                           (91_460_000, "SET_POSITION_TARGET_GLOBAL_INT")]
        assert relay.late_frames == 0
        # released late (after their due time: a slow companion): forwarded at once, one GPS_INPUT per loop
        fc.sendall(mavlink.MAVLink_attitude_message(92_500, 0, 0, 0, 0, 0, 0).pack(fc_mav))
        companion.sendall(_gps_and_setpoint(co_mav, 91_000_000, 92_450))
        time.sleep(0.05)
        relay.boundary(92_600_000)        # answered already (the threshold follows 90.4 s)
        relay.boundary(92_800_000)        # the threshold follows 92.5 s: released up to the setpoint
        arrived = []
        for now_us in range(92_820_000, 93_500_000, 20_000):
            relay.deliver(now_us)
            parser = mavlink.MAVLink(None)
            arrived += [(now_us, m.get_type()) for m in parser.parse_buffer(_read_all(fc, 0.01)) or ()]
        assert arrived == [(92_820_000, "GPS_INPUT"), (92_840_000, "GPS_INPUT"), (92_860_000, "GPS_INPUT"),
                           (93_460_000, "SET_POSITION_TARGET_GLOBAL_INT")]
        assert relay.late_frames == 3
        companion.close()
        fc.close()
    finally:
        relay.close()
        fc_server.close()
