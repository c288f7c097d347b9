"""The lockstep relay between ArduPilot's SERIAL1 and the companion (sitl.physics.relay), over real
loopback TCP: a socket stands in for ArduPilot's SERIAL1 port, another for the companion.

What ArduPilot judges a MAVLink GPS's health on (``AP_GPS::update_instance``: the time between the
updates its GPS driver takes, one per loop; over 245 ms twice in a row, or 215 ms on average, is
"not healthy") needs the companion's 10 Hz GPS_INPUT to reach it one frame at a time, 100 ms of
firmware time apart: the relay forwards each frame at its own stamp plus a fixed latency, and at most
one GPS_INPUT per firmware loop. The gate on ArduPilot's clock waits for the companion only when a
frame could be due that it has not sent yet, and never for what it cannot answer.
"""
from __future__ import annotations

import contextlib
import os
import select
import socket

import pytest

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from fcmpc.firmware.instances import claimed_instance  # noqa: E402
from sitl.physics.relay import CompanionRelay, relay_port, serial1_port  # noqa: E402

UNIX0_US = 1_715_364_000_000_000     # SITL's start date, UNIX us at boot
FC_MAV = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
CO_MAV = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)


def _gps(boot_us: int) -> bytes:
    """GPS_INPUT at firmware time ``boot_us``, stamped in UNIX time as the companion stamps it."""
    return mavlink.MAVLink_gps_input_message(UNIX0_US + boot_us, 1, 0, 0, 0, 3, 330_000_000, 1_520_000_000, 0.0,
                                             1.0, 1.0, 0, 0, 0, 0, 5.0, 5.0, 10, 0).pack(CO_MAV)


def _gps_and_setpoint(first_boot_us: int, setpoint_ms: int) -> bytes:
    """Three GPS_INPUT 100 ms apart from ``first_boot_us``, then a setpoint stamped ``setpoint_ms``."""
    return b"".join(_gps(first_boot_us + 100_000 * k) for k in range(3)) + _setpoint(setpoint_ms)


def _setpoint(time_boot_ms: int) -> bytes:
    return mavlink.MAVLink_set_position_target_global_int_message(
        time_boot_ms, 1, 1, 6, 0xDC7, 0, 0, 0.0, 8.0, 0.0, 0.0, 0, 0, 0, 0.0, 0.0).pack(CO_MAV)


def _attitude(time_boot_ms: int) -> bytes:
    return mavlink.MAVLink_attitude_message(time_boot_ms, 0, 0, 0, 0, 0, 0).pack(FC_MAV)


def _readable(sock: socket.socket) -> None:
    """Until ``sock`` has data (an event; the 5 s are a hang guard)."""
    assert select.select([sock], [], [], 5.0)[0], "nothing arrived"


class _Loopback:
    """The relay with a socket as ArduPilot's SERIAL1 and another as the companion."""

    def __init__(self, **options) -> None:
        self.claims = contextlib.ExitStack()      # the instance, held until close()
        self.instance = self.claims.enter_context(claimed_instance("ardupilot", 66, 99))
        self.fc_server = socket.create_server(("127.0.0.1", serial1_port(self.instance)))
        self.relay = CompanionRelay(self.instance, hold_from_s=0.0, **options)
        self.relay._tries = 0                  # connect at the first pump
        self.relay.pump_fc()
        self.fc, _ = self.fc_server.accept()
        self.companion = socket.create_connection(("127.0.0.1", relay_port(self.instance)))

    def from_fc(self, data: bytes) -> None:
        """ArduPilot writes ``data``; the relay passes it on (the companion reads it)."""
        self.fc.sendall(data)
        _readable(self.relay.fc)
        self.relay.pump_fc()
        _readable(self.companion)
        self.companion.recv(65536)

    def from_companion(self, data: bytes) -> None:
        """The companion sends ``data``; it waits in the relay's socket until the relay reads it."""
        self.companion.sendall(data)
        _readable(self.relay.companion)

    def loops(self, first_us: int, end_us: int) -> list[tuple[int, str]]:
        """ArduPilot's loops, 20 ms apart: what each read (its firmware time, the message type)."""
        arrived = []
        for now_us in range(first_us, end_us, 20_000):
            sent = self.relay.frames_to_fc
            self.relay.frame(now_us)
            self.relay.answered(now_us)
            if self.relay.frames_to_fc > sent:
                _readable(self.fc)
                arrived += [(now_us, m.get_type()) for m in mavlink.MAVLink(None).parse_buffer(self.fc.recv(65536))]
        return arrived

    def close(self) -> None:
        for sock in (self.companion, self.fc, self.fc_server):
            sock.close()
        self.relay.close()
        self.claims.close()


@pytest.fixture
def loopback():
    made: list[_Loopback] = []
    yield lambda **options: made.append(_Loopback(**options)) or made[-1]
    for rig in made:
        rig.close()


def test_companion_frames_reach_ardupilot_at_their_stamp_plus_the_latency_one_gps_per_loop(loopback):
    rig = loopback(timeout_s=5.0, latency_s=1.0)
    relay = rig.relay
    # ArduPilot at 90.339 s: SYSTEM_TIME (its time_boot_ms truncated to 3 bytes by MAVLink 2) then ATTITUDE
    rig.from_fc(mavlink.MAVLink_system_time_message(UNIX0_US + 90_339_000, 90_339).pack(FC_MAV) + _attitude(90_400))
    assert relay.times.time_ms == 90_400 and relay.times.unix_minus_boot_us == UNIX0_US
    # three GPS_INPUT 100 ms apart (UNIX time) and a setpoint on the boot clock
    rig.from_companion(_setpoint(90_100) + _gps_and_setpoint(90_200_000, 90_400))
    arrived = rig.loops(90_420_000, 91_420_000)
    assert arrived == [(91_100_000, "SET_POSITION_TARGET_GLOBAL_INT"), (91_200_000, "GPS_INPUT"),
                       (91_300_000, "GPS_INPUT"), (91_400_000, "GPS_INPUT"),
                       (91_400_000, "SET_POSITION_TARGET_GLOBAL_INT")]
    assert relay.late_frames == 0 and relay.waits == 0 and relay.timeouts == 0
    # three GPS_INPUT stamped within 20 ms: one per loop (ArduPilot's driver keeps only a loop's newest)
    rig.from_fc(_attitude(91_500))
    rig.from_companion(b"".join(_gps(91_400_000 + 10_000 * k) for k in range(3)) + _setpoint(91_500))
    assert rig.loops(91_420_000, 92_520_000) == [
        (92_400_000, "GPS_INPUT"), (92_420_000, "GPS_INPUT"), (92_440_000, "GPS_INPUT"),
        (92_500_000, "SET_POSITION_TARGET_GLOBAL_INT")]
    assert relay.late_frames == 0 and relay.waits == 0


def test_the_gate_waits_only_for_what_the_companion_could_have_answered(loopback):
    """The world runs on while every frame due is known, reads the companion only as due times near,
    waits when the companion has been given enough to answer and has not (here: never, so the hang
    guard ends it, counted), and does not wait for what it was not given (the serial link's lag)."""
    rig = loopback(timeout_s=0.3, latency_s=1.2)
    relay = rig.relay
    rig.from_fc(_attitude(100_000))
    rig.from_companion(_setpoint(100_000))          # due at 101.2 s
    rig.loops(100_020_000, 101_200_000)             # up to the frame before its due time: nothing to wait for
    assert (relay.reads, relay.waits, relay.timeouts) == (1, 0, 0)
    # the companion was given ArduPilot's time up to 100.8 s: it could have answered 100.4 s by now
    rig.from_fc(_attitude(100_800))
    assert rig.loops(101_200_000, 101_220_000) == [(101_200_000, "SET_POSITION_TARGET_GLOBAL_INT")]
    assert (relay.waits, relay.timeouts, relay.fallbacks) == (1, 1, 0)
    # its answer (stamped 100.8 s, due at 102.0 s) lets the world run to 102.0 s without waiting
    rig.from_companion(_setpoint(100_800))
    assert rig.loops(101_220_000, 102_000_000) == []
    assert (relay.reads, relay.waits, relay.timeouts, relay.fallbacks) == (3, 1, 1, 0)
    # given nothing newer (ArduPilot's output trails its clock by more than the latency) the companion
    # cannot answer: the gate does not wait for it, and counts a fallback
    assert rig.loops(102_000_000, 102_100_000) == [(102_000_000, "SET_POSITION_TARGET_GLOBAL_INT")]
    assert (relay.waits, relay.timeouts, relay.fallbacks) == (1, 1, 5)


def test_the_latency_must_cover_what_the_companion_cannot_have_answered():
    with pytest.raises(ValueError, match="latency"):
        CompanionRelay(0, latency_s=0.5, pump_period_s=0.2, answer_period_s=0.2)


def test_the_motor_field_reaches_ardupilot_over_the_relays_link(loopback):
    """With a relay the world sets the motor's field (SIM_MAG1_OFS) over the relay's SERIAL1 link, not a
    SERIAL2 port SITL would poll three times a loop for it."""
    from sitl.physics.motor_field import MotorField, MotorFieldConfig

    rig = loopback(timeout_s=5.0, latency_s=1.0)
    config = MotorFieldConfig((-0.71, -0.14, 0.68), (10.0, 20.0, 30.0))
    motor = MotorField(rig.instance, config, send=rig.relay.to_fc)
    motor.update(1_000_000, 0.5)                # 25 A
    _readable(rig.fc)
    sets = {m.param_id: m.param_value for m in mavlink.MAVLink(None).parse_buffer(rig.fc.recv(65536))}
    assert sets == pytest.approx(dict(zip(("SIM_MAG1_OFS_X", "SIM_MAG1_OFS_Y", "SIM_MAG1_OFS_Z"),
                                          config.offsets_at(25.0))), abs=1e-4)
    assert motor.updates == 1 and motor.sock is None
