"""A ground-station-side observer of a SITL flight controller: truth, modes, texts.

Connects to a spare port of the firmware (ArduPilot's SERIAL0 or SERIAL1) as a ground station
(system 255), asks for SIMSTATE (the simulator's true position and attitude), VFR_HUD, ATTITUDE
and GPS_RAW_INT, and records what the tests and ``fcmpc-fly --fc ardupilot`` judge: the true
track, the flight mode and arming state, and every STATUSTEXT (the flight controller's and the
companion's, which ArduPilot routes to all its links). Time is the firmware's boot time.

PX4 SIH has no SIMSTATE: its ground truth is HIL_STATE_QUATERNION (SIH's own state, with
``time_usec`` 0), requested on PX4's ground-station link (``udpout:`` to 18570+N; PX4 answers
whoever sent last, so the monitor speaks first and sends a heartbeat every wall second); time
then comes from SYSTEM_TIME and GLOBAL_POSITION_INT. A rate of 0 turns a stream off.
"""
from __future__ import annotations

import csv
import math
import os
import select
import socket
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402

from sitl.physics.mavlink_frames import whole_frames  # noqa: E402

__all__ = ["STARTUP_GUARD_S", "TruthSample", "FirmwareMonitor", "write_truth_csv"]

mavlink = mavutil.mavlink
GCS_SYSID = 255
# The rigs wait for a running firmware's first heartbeat this long at most (a hang guard, not a pace):
# ArduPilot's JSON SITL took more than 60 s to boot at a load average of 30 (a Monte Carlo seed lost)
STARTUP_GUARD_S = 900.0
AUTOPILOT_COMPONENT = 1
# what :meth:`FirmwareMonitor.handle` reads from a component other than the autopilot's; ArduPilot routes
# every broadcast message of its other links to the monitor's (the companion's 10 Hz GPS_INPUT and 5 Hz
# setpoints: two thirds of what SERIAL0 carried, decoded for nothing)
_FROM_ANY_COMPONENT = frozenset(getattr(mavlink, f"MAVLINK_MSG_ID_{name}") for name in (
    "STATUSTEXT", "COMMAND_ACK", "GPS_RAW_INT", "VFR_HUD", "SIMSTATE", "HIL_STATE_QUATERNION"))


@dataclass(frozen=True)
class TruthSample:
    """One SIMSTATE with what the flight controller reported at that moment."""

    time_s: float
    lat_deg: float
    lon_deg: float
    yaw_deg: float          # true heading, from north clockwise
    mode: int
    armed: bool
    groundspeed_mps: float  # the FC's estimate (VFR_HUD)
    gps_fix: int


@dataclass
class FirmwareMonitor:
    """Reads one firmware port; :meth:`pump` until a condition, never sleeps."""

    connect: str
    target_system: int = 1
    rates_hz: dict = field(default_factory=lambda: {"SIMSTATE": 2.0, "VFR_HUD": 2.0, "GPS_RAW_INT": 1.0})
    time_s: float = math.nan
    mode: int = -1
    armed: bool = False
    texts: list = field(default_factory=list)
    truth: list = field(default_factory=list)

    def __post_init__(self) -> None:
        self.conn = mavutil.mavlink_connection(self.connect, source_system=GCS_SYSID, source_component=190,
                                               autoreconnect=False)
        self._gps_fix = 0
        self._groundspeed = math.nan
        self._chunks: dict[tuple[int, int], str] = {}
        self._hello_wall_s = -math.inf
        self.acks: dict[int, int] = {}          # COMMAND_ACK results of the autopilot, by command
        self.params: dict[str, float] = {}      # PARAM_VALUEs the autopilot sent
        self._pending: deque = deque()           # read from the socket, not yet handled
        self._unread = bytearray()              # TCP: an incomplete frame at the end of the last read
        self.listeners: dict = {}               # message type -> callable(msg): more than the truth (a calibration)

    @property
    def gps_fix(self) -> int:
        """GPS_RAW_INT's fix type, as last reported (0 before any)."""
        return self._gps_fix

    def _statustext(self, msg) -> None:
        """One text per STATUSTEXT, or per id across its 50-character chunks (MAVLink 2)."""
        comp, text = msg.get_srcComponent(), msg.text
        chunk_id = getattr(msg, "id", 0)
        if not chunk_id:
            self.texts.append((self.time_s, comp, text))
            return
        key = (comp, chunk_id)
        self._chunks[key] = self._chunks.get(key, "") + text
        if len(text.encode()) < 50:   # the last chunk is shorter (an empty one closes a full one)
            self.texts.append((self.time_s, comp, self._chunks.pop(key)))

    def start(self, timeout_s: float = 60.0, alive: Callable[[], bool] | None = None) -> None:
        """Wait for the autopilot's heartbeat (saying hello first on a ``udpout:`` link), then ask
        for the streams. With ``alive`` (are the firmware's processes running?) the wait lasts as
        long as they run, ``timeout_s`` being only a hang guard, and ends at once when they have
        gone: a firmware that boots slowly on a loaded machine is waited for, a dead one is not."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if alive is not None and not alive():
                raise RuntimeError(f"the flight controller exited before its first heartbeat on {self.connect}")
            self._hello()
            msg = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
            if msg is not None and msg.get_srcComponent() == 1 and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID:
                self.target_system = msg.get_srcSystem()
                break
        else:
            raise TimeoutError(f"no heartbeat on {self.connect} within {timeout_s:g} s")
        for name, hz in self.rates_hz.items():
            self.send_command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, getattr(mavlink, f"MAVLINK_MSG_ID_{name}"),
                              1e6 / hz if hz > 0 else -1)

    def _hello(self) -> None:
        """A ground-station heartbeat, at most once per wall second, on links where we speak first."""
        if self.connect.startswith("udpout:") and time.monotonic() - self._hello_wall_s >= 1.0:
            self._hello_wall_s = time.monotonic()
            self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def send_command(self, command: int, *params: float) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.conn.mav.command_long_send(self.target_system, 1, command, 0, *p[:7])

    def set_param(self, name: str, value: float) -> None:
        self.conn.mav.param_set_send(self.target_system, 1, name.encode("ascii"), float(value),
                                     mavlink.MAV_PARAM_TYPE_REAL32)

    def set_param_int32_bytewise(self, name: str, value: int) -> None:
        """PARAM_SET of a PX4 INT32 parameter: the integer's bytes in the float (PX4's encoding)."""
        import struct

        raw = struct.unpack("<f", struct.pack("<i", int(value)))[0]
        self.conn.mav.param_set_send(self.target_system, 1, name.encode("ascii"), raw, mavlink.MAV_PARAM_TYPE_INT32)

    def read_params(self, names, timeout_wall_s: float = 30.0) -> dict[str, float]:
        """Ask for each named parameter (PARAM_REQUEST_READ) and wait for their values."""
        for name in names:
            self.params.pop(name, None)
            self.conn.mav.param_request_read_send(self.target_system, 1, name.encode("ascii"), -1)
        self.pump(lambda m: all(n in m.params for n in names), timeout_wall_s, f"the values of {', '.join(names)}")
        return {name: self.params[name] for name in names}

    def pump(self, until, timeout_wall_s: float, what: str = "condition") -> None:
        """Read messages until ``until(self)`` is true; TimeoutError after ``timeout_wall_s``."""
        deadline = time.monotonic() + timeout_wall_s
        pending = self._pending
        while not until(self):
            if pending:
                self.handle(pending.popleft())
                continue
            if time.monotonic() > deadline:
                raise TimeoutError(f"{what} not reached within {timeout_wall_s:g} s of wall time "
                                   f"(firmware time {self.time_s:.1f} s, mode {self.mode}, armed {self.armed}); "
                                   f"last texts: {self.texts[-5:]}")
            self._hello()
            self._read(0.5)

    def _read(self, wait_s: float) -> None:
        """What the port has (waiting up to ``wait_s`` for it) into :attr:`_pending`. On TCP (ArduPilot's
        SERIAL0) all of it in one read: pymavlink's ``recv_match`` reads a message in two system calls
        (header, then the rest), and the monitor was a fifth of a lockstep run's CPU seconds. Only frames
        :meth:`handle` reads are decoded (the autopilot's, and other components' texts and acks)."""
        conn = self.conn
        if not isinstance(conn, mavutil.mavtcp) or conn.port is None:
            msg = conn.recv_match(blocking=True, timeout=wait_s)
            if msg is not None:
                self._pending.append(msg)
            return
        if not select.select([conn.port], [], [], wait_s)[0]:
            return
        unread = self._unread
        while True:
            data = conn.recv(262144)
            # acknowledge at once (Linux leaves quick-ack mode after a read): ArduPilot SITL sleeps a wall
            # millisecond at a time while SERIAL0's unacknowledged output exceeds 1 kB (SITL_State: "check the
            # outbound TCP queue size"), and a delayed ACK (40 ms) kept it there
            conn.port.setsockopt(socket.IPPROTO_TCP, socket.TCP_QUICKACK, 1)
            unread += data
            wanted = b"".join(frame for msgid, _, frame in whole_frames(unread)
                              if frame[6] == AUTOPILOT_COMPONENT or msgid in _FROM_ANY_COMPONENT)
            if wanted:
                self._pending.extend(m for m in conn.mav.parse_buffer(wanted) or () if m.get_type() != "BAD_DATA")
            # a frame cut by the read: its rest follows at once (the firmware writes whole frames); read it
            # now, so that pymavlink's own reads (drain, a test's recv_match) start on a frame's first byte
            if not data or not unread or not select.select([conn.port], [], [], 1.0)[0]:
                return

    def drain(self) -> None:
        """Read every message already queued, without waiting: :attr:`time_s` is then the firmware's
        time of the newest one (a monitor that has not read for a while lags the firmware by what
        sits in its socket: seconds of firmware time at a speed-up on a loaded machine)."""
        while self._pending:
            self.handle(self._pending.popleft())
        while (msg := self.conn.recv_match(blocking=False)) is not None:
            self.handle(msg)

    def handle(self, msg) -> None:
        mtype = msg.get_type()
        boot_ms = getattr(msg, "time_boot_ms", None)
        if boot_ms is not None and msg.get_srcComponent() == 1 and msg.get_srcSystem() == self.target_system:
            self.time_s = boot_ms * 1e-3
        listener = self.listeners.get(mtype)
        if listener is not None and msg.get_srcComponent() == 1 and msg.get_srcSystem() == self.target_system:
            listener(msg)
        if mtype == "HEARTBEAT" and msg.get_srcComponent() == 1 and msg.get_srcSystem() == self.target_system:
            self.mode, self.armed = msg.custom_mode, bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        elif mtype == "STATUSTEXT":
            self._statustext(msg)
        elif mtype == "COMMAND_ACK" and msg.get_srcSystem() == self.target_system:
            self.acks[msg.command] = msg.result
        elif mtype == "PARAM_VALUE" and msg.get_srcSystem() == self.target_system and msg.get_srcComponent() == 1:
            name = msg.param_id.decode("ascii", "replace") if isinstance(msg.param_id, bytes) else msg.param_id
            self.params[name.rstrip("\x00")] = float(msg.param_value)
        elif mtype == "GPS_RAW_INT":
            self._gps_fix = msg.fix_type
        elif mtype == "VFR_HUD":
            self._groundspeed = msg.groundspeed
        elif mtype == "SIMSTATE" and math.isfinite(self.time_s):
            self.truth.append(TruthSample(self.time_s, msg.lat * 1e-7, msg.lng * 1e-7,
                                          math.degrees(msg.yaw) % 360.0, self.mode, self.armed,
                                          self._groundspeed, self._gps_fix))
        elif mtype == "HIL_STATE_QUATERNION" and math.isfinite(self.time_s):
            w, x, y, z = msg.attitude_quaternion
            yaw = math.degrees(math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))) % 360.0
            self.truth.append(TruthSample(self.time_s, msg.lat * 1e-7, msg.lon * 1e-7, yaw, self.mode, self.armed,
                                          math.hypot(msg.vx, msg.vy) * 0.01, self._gps_fix))

    def texts_matching(self, needle: str, component: int | None = None) -> list:
        return [t for t in self.texts if needle in t[2] and (component is None or t[1] == component)]

    def close(self) -> None:
        self.conn.close()


def write_truth_csv(path: Path, samples: list[TruthSample]) -> None:
    """The monitor's truth samples as ``truth.csv``: firmware time (s), true position (deg), yaw (deg),
    mode, armed, the FC's ground speed (m/s) and GPS fix."""
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["time_s", "lat_deg", "lon_deg", "yaw_deg", "mode", "armed", "groundspeed_mps", "gps_fix"])
        for sample in samples:
            writer.writerow([f"{sample.time_s:.3f}", f"{sample.lat_deg:.8f}", f"{sample.lon_deg:.8f}",
                             f"{sample.yaw_deg:.2f}", sample.mode, int(sample.armed), f"{sample.groundspeed_mps:.2f}",
                             sample.gps_fix])
