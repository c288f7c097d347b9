"""Helpers of the stand-in's socket tests: mode numbers, setpoint masks, arming and setpoint streams through a pymavlink client."""
from __future__ import annotations

import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.ports import free_port

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


def closed_udp_port() -> int:
    """A loopback UDP port nobody listens on (the simulator sends there without a reader); from
    :func:`tests.ports.free_port`, so no other socket of this run is given it."""
    return free_port()
