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


class Answering:
    """A client that keeps a lockstep stand-in going as a companion does: every SYSTEM_TIME (the mark of
    a boundary) read while it waits for something else is answered at once with a stamped message,
    the velocity setpoint ``steer`` when set, else a NAMED_VALUE_FLOAT (alive, not steering). The world
    then waits for this client however slow a loaded machine makes it, and what happens in simulated
    time (a setpoint timeout, a turn) no longer depends on the wall."""

    def __init__(self, client, hang_s: float = 300.0) -> None:
        self.client, self.hang_s = client, hang_s
        self.steer: tuple[float, float] | None = None      # (vn, ve) m/s sent at every boundary
        self.last_ms = -1

    def _answer(self, t_ms: int) -> None:
        if t_ms <= self.last_ms:
            return
        self.last_ms = t_ms
        if self.steer is not None:
            send_velocity(self.client, t_ms, *self.steer)
        else:
            self.client.mav.named_value_float_send(t_ms, b"ALIVE", 0.0)

    def recv(self, types, predicate=None):
        """The next message of ``types`` satisfying ``predicate``, answering every boundary meanwhile
        (``hang_s`` of wall time is only a hang guard)."""
        types = {types} if isinstance(types, str) else set(types)
        deadline = time.monotonic() + self.hang_s
        while time.monotonic() < deadline:
            msg = self.client.recv(["SYSTEM_TIME", *types], self.hang_s)
            if msg.get_type() == "SYSTEM_TIME":
                self._answer(msg.time_boot_ms)
            if msg.get_type() in types and (predicate is None or predicate(msg)):
                return msg
        raise TimeoutError(f"no {sorted(types)} within {self.hang_s} s")

    def time_ms(self) -> int:
        return self.recv("SYSTEM_TIME").time_boot_ms

    def until(self, t_ms: int, types=()) -> list:
        """Every message of ``types`` until simulated ``t_ms`` (boundaries answered)."""
        out = []
        while True:
            msg = self.recv(["SYSTEM_TIME", *([types] if isinstance(types, str) else types)])
            if msg.get_type() != "SYSTEM_TIME":
                out.append(msg)
            elif msg.time_boot_ms >= t_ms:
                return out

    def command(self, command: int, *params: float):
        """COMMAND_LONG; its COMMAND_ACK."""
        p = list(params) + [0.0] * (7 - len(params))
        self.client.mav.command_long_send(1, 1, command, 0, *p)
        return self.recv("COMMAND_ACK", lambda m: m.command == command)

    def arm_guided(self) -> None:
        self.recv("HEARTBEAT", lambda m: m.get_srcComponent() == 1 and m.custom_mode == HOLD)
        assert self.command(ARM, 1).result == mavlink.MAV_RESULT_ACCEPTED
        assert self.command(DO_SET_MODE, 1, GUIDED).result == mavlink.MAV_RESULT_ACCEPTED
