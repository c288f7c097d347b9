"""The monitor decodes what it reads and passes over the rest: ArduPilot routes the companion's broadcast
messages (its 10 Hz GPS_INPUT, its setpoints) to the monitor's port, and decoding them was two thirds of
the monitor's parsing. Real frames over a real TCP socket, the firmware's and the companion's interleaved
and cut across reads as a serial stream arrives."""
from __future__ import annotations

import os
import socket

import pytest

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from fcmpc.firmware.monitor import FirmwareMonitor  # noqa: E402
from tests.ports import free_port  # noqa: E402

FC = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
COMPANION = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)


@pytest.fixture
def firmware_port():
    server = socket.create_server(("127.0.0.1", free_port()))
    yield server
    server.close()


def _second(k: int) -> bytes:
    """One second of SERIAL0: the firmware's heartbeat, ATTITUDE and SIMSTATE; the companion's GPS_INPUT,
    setpoint and heartbeat routed to it; at k = 3 a text of the companion's."""
    fc = (mavlink.MAVLink_heartbeat_message(10, 3, 0x81, 4, 4, 3).pack(FC)
          + mavlink.MAVLink_attitude_message(1000 * k + 500, 0, 0, 0.5, 0, 0, 0).pack(FC)
          + mavlink.MAVLink_simstate_message(0, 0, 0.5, 0, 0, 0, 0, 0, 0, 330_000_000 + k, 1_520_000_000)
          .pack(FC))
    companion = (mavlink.MAVLink_gps_input_message(1_715_364_000_000_000 + 1_000_000 * k, 1, 0, 0, 0, 3, 330_000_000,
                                                  1_520_000_000, 0.0, 1.0, 1.0, 0, 0, 0, 0, 5.0, 5.0, 10, 0)
                 .pack(COMPANION)
                 + mavlink.MAVLink_set_position_target_global_int_message(1000 * k + 600, 1, 1, 6, 0xDC7, 0, 0, 0.0,
                                                                          8.0, 0.0, 0.0, 0, 0, 0, 0.0, 0.0)
                 .pack(COMPANION)
                 + mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3).pack(COMPANION))
    text = mavlink.MAVLink_statustext_message(6, b"FcMPC: phase probe1").pack(COMPANION) if k == 3 else b""
    return fc + companion + text


def test_the_monitor_decodes_the_firmwares_frames_and_the_companions_texts_only(firmware_port):
    monitor = FirmwareMonitor(f"tcp:127.0.0.1:{firmware_port.getsockname()[1]}", rates_hz={})
    firmware, _ = firmware_port.accept()
    stream = b"".join(_second(k) for k in range(6))
    for start in range(0, len(stream), 97):        # reads cut frames anywhere
        firmware.sendall(stream[start:start + 97])
    monitor.pump(lambda m: len(m.truth) == 6, 10.0, "six truth samples")
    firmware.close()
    assert [round(s.time_s, 3) for s in monitor.truth] == [0.5, 1.5, 2.5, 3.5, 4.5, 5.5]   # ATTITUDE's time
    assert [s.lat_deg for s in monitor.truth] == pytest.approx([33.0 + k * 1e-7 for k in range(6)])
    assert monitor.mode == 4 and monitor.armed          # the firmware's heartbeat, not the companion's
    assert monitor.texts == [(3.5, 191, "FcMPC: phase probe1")]
    # 3 frames a second of the firmware's and one text were decoded, not the companion's 3 a second
    assert monitor.conn.mav.total_packets_received == 3 * 6 + 1
