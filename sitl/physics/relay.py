"""The companion's MAVLink link to ArduPilot, through the world's process, so the world can wait for it.

ArduPilot's SERIAL1 (TCP ``5762 + 10 I``) is the companion's port on a vehicle; here the world's
process connects to it and listens for the companion on ``relay_port(I)`` (TCP ``9008 + 10 I``).
What ArduPilot sends is passed on as it is read (unparsed but for the headers, from which
the newest firmware time passed on is kept: the firmware's stream is the heavy direction). What
the companion sends is split into MAVLink frames (pymavlink) and held: at each lockstep boundary
(every ``period_s`` of physics time) the frames go to ArduPilot in order up to and including the one
that answers (:meth:`sitl.clock.LockstepGate.satisfied`: stamped, as ``companion --lockstep`` stamps
them, with a firmware time no older than one period before the newest time the companion had been
given at the previous boundary); the rest wait for the next boundary. The threshold follows what the
companion was given, not ArduPilot's clock: ArduPilot's serial output lags its clock by a
bandwidth-limited queue (a threshold on its clock stalled 464 s into a run). The companion's timing
therefore never decides when ArduPilot sees a message, only the message sequence does. (Passing the
companion's frames on at once instead, every 0.1 s, or all of them at each boundary, left ArduPilot
calling its GPS_INPUT feed "GPS 2: not healthy" in each of three runs; see the dated note.)

From ``hold_from_s`` of physics time the world waits for the companion to appear (the runner starts
it after the firmware's start-up and compass calibration): its start is a fixed firmware time too.
Until its first stamped frame (its lockstep loop needs the firmware's messages, so the world cannot
hold for that) any frame answers a boundary; its start (imports, maps) took 23-48 s of wall time at
a load average of 25, under the 120 s each boundary waits before going on.
"""
from __future__ import annotations

import errno
import os
import select
import socket
import time
from collections import deque

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from sitl.clock import LockstepGate  # noqa: E402

__all__ = ["CompanionRelay", "relay_port", "serial1_port"]

# messages ArduPilot streams with time_boot_ms, and its offset in the payload: ATTITUDE, ATTITUDE_QUATERNION,
# LOCAL_POSITION_NED, GLOBAL_POSITION_INT, RC_CHANNELS, SCALED_IMU(2, 3) first; SYSTEM_TIME after its uint64
_STAMP_OFFSET = {30: 0, 31: 0, 32: 0, 33: 0, 65: 0, 26: 0, 116: 0, 129: 0, 2: 8}
GPS_INPUT_ID = 232
LATENCY_S = 1.2          # from a frame's stamp to ArduPilot: above its release lag (0.3-1.1 s measured, see the note)
LATE_US = 20_000         # a frame forwarded more than one physics frame after its due time is late


def relay_port(instance: int) -> int:
    """Where the companion connects (TCP) for ArduPilot instance ``instance``.

    >>> relay_port(0), relay_port(2)
    (9008, 9028)
    """
    return 9008 + 10 * instance


def serial1_port(instance: int) -> int:
    return 5762 + 10 * instance


class CompanionRelay:
    """ArduPilot SERIAL1 <-> the companion, the companion's frames released at lockstep boundaries."""

    def __init__(self, instance: int, timeout_s: float = 30.0, period_s: float = 0.2, hold_from_s: float = 90.0,
                 start_timeout_s: float = 600.0, latency_s: float = LATENCY_S) -> None:
        self.instance = instance
        self.latency_us = int(round(latency_s * 1e6))
        self.gate = LockstepGate(period_s, timeout_s=timeout_s, start_timeout_s=start_timeout_s, slack_periods=0)
        self.hold_from_us = int(hold_from_s * 1e6)
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", relay_port(instance)))
        self.listener.listen(1)
        self.listener.setblocking(False)
        self.fc: socket.socket | None = None
        self.companion: socket.socket | None = None
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self._held: deque = deque()
        self._due: deque = deque()       # released frames, (firmware time due in us, frame), in order
        self._due_us = 0                 # the due time of the last frame scheduled (never goes back)
        self.unix_minus_boot_us: int | None = None   # SYSTEM_TIME's pairing: GPS_INPUT's stamp in boot time
        self.late_frames = 0             # frames forwarded more than a frame after their due time
        self.max_late_us = 0
        self.release_lag: dict[int, int] = {}
        self.gps_gaps: dict[int, int] = {}    # firmware loops between GPS_INPUTs forwarded
        self._last_gps_us = 0
        self._now_us = 0
        self.fc_time_ms = 0              # the newest firmware time passed on to the companion
        self._fc_tail = b""              # an incomplete frame at the end of the last read
        self._answer_ms = 0              # what the companion must have answered at this boundary
        self._tries = 0
        self.bytes_to_companion = 0
        self.frames_to_fc = 0
        self.start_wait_wall_s = 0.0

    # ------------------------------------------------------------------ connections
    def _connect_fc(self) -> None:
        self._tries += 1
        if self._tries % 50 != 1:      # ArduPilot opens SERIAL1 after its first frames: try now and then
            return
        try:
            sock = socket.create_connection(("127.0.0.1", serial1_port(self.instance)), timeout=1.0)
        except OSError:
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        self.fc = sock

    def _accept(self) -> None:
        try:
            sock, _ = self.listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        self.companion = sock

    # ------------------------------------------------------------------ ArduPilot -> companion
    def _note_fc_time(self, data: bytes) -> None:
        """The newest ``time_boot_ms`` of ArduPilot's own frames in ``data``, by their headers alone
        (the firmware's stream is the heavy direction: no decoding, no CRC)."""
        buf = self._fc_tail + data if self._fc_tail else data
        i, end, newest = 0, len(buf), self.fc_time_ms
        while i < end:
            magic = buf[i]
            if magic == 0xFD:
                if i + 10 > end:
                    break
                size = 12 + buf[i + 1] + (13 if buf[i + 2] & 1 else 0)
                if i + size > end:
                    break
                msgid = buf[i + 7] | buf[i + 8] << 8 | buf[i + 9] << 16
                offset = _STAMP_OFFSET.get(msgid)
                if offset is not None and buf[i + 6] == 1 and buf[i + 1] > offset:
                    # MAVLink 2 drops a payload's trailing zero bytes: SYSTEM_TIME's time_boot_ms, its last
                    # field, arrives as 3 bytes for its first 4.6 hours
                    p, stop = i + 10 + offset, i + 10 + buf[i + 1]
                    stamp = int.from_bytes(buf[p:min(p + 4, stop)], "little")
                    newest = max(newest, stamp)
                    if msgid == 2:      # SYSTEM_TIME: time_unix_usec (uint64) before time_boot_ms
                        unix_us = int.from_bytes(buf[i + 10:i + 18], "little")
                        if unix_us:
                            self.unix_minus_boot_us = unix_us - stamp * 1000
                i += size
            elif magic == 0xFE:
                if i + 2 > end or i + 8 + buf[i + 1] > end:
                    break
                i += 8 + buf[i + 1]
            else:
                i += 1
        self._fc_tail = bytes(buf[i:]) if i < end else b""
        self.fc_time_ms = newest

    def pump_fc(self) -> None:
        """Pass on everything ArduPilot has written (dropped while no companion is connected)."""
        if self.fc is None:
            self._connect_fc()
            if self.fc is None:
                return
        if self.companion is None:
            self._accept()
        while True:
            try:
                data = self.fc.recv(262144)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                data = b""
            if not data:            # ArduPilot closed the port
                self.fc.close()
                self.fc = None
                return
            self._note_fc_time(data)
            if self.companion is not None:
                self._to_companion(data)

    def _to_companion(self, data: bytes) -> None:
        try:
            self.companion.setblocking(True)
            self.companion.sendall(data)
            self.bytes_to_companion += len(data)
        except OSError:
            self._companion_lost()
        else:
            self.companion.setblocking(False)

    def _companion_lost(self) -> None:
        if self.companion is not None:
            self.companion.close()
        self.companion = None
        self._held.clear()

    # ------------------------------------------------------------------ companion -> ArduPilot
    def _read_companion(self, wait_s: float) -> None:
        if self.companion is None:
            if wait_s > 0.0:
                select.select([self.listener], [], [], wait_s)
            self._accept()
            return
        if wait_s > 0.0:
            select.select([self.companion], [], [], wait_s)
        try:
            data = self.companion.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as err:
            data = b"" if err.errno != errno.EAGAIN else None
            if data is None:
                return
        if not data:
            self._companion_lost()
            return
        self._held.extend(self._parser.parse_buffer(data) or ())

    def _release(self, boundary_us: int) -> bool:
        """Forward held frames in order until one answers ``boundary_us``; True when answered."""
        gate = self.gate
        while not gate.satisfied(boundary_us):
            if not self._held:
                return False
            msg = self._held.popleft()
            stamp = getattr(msg, "time_boot_ms", None)
            gate.observe(stamp if isinstance(stamp, int) else None, self.fc_time_ms * 1000)
            self._schedule(msg, stamp)
        return True

    def _schedule(self, msg, stamp_ms) -> None:
        """Queue a released frame for the firmware time of its own stamp plus :attr:`latency_us`; an
        unstamped frame (HEARTBEAT, COMMAND_LONG) keeps its place after the one before it. GPS_INPUT
        carries UNIX time (``time_usec``), placed on the boot clock with SYSTEM_TIME's pairing."""
        if isinstance(stamp_ms, int) and stamp_ms > 0:
            stamp_us = stamp_ms * 1000
        elif msg.get_msgId() == GPS_INPUT_ID and self.unix_minus_boot_us is not None:
            stamp_us = msg.time_usec - self.unix_minus_boot_us
        else:
            stamp_us = 0
        if stamp_us:
            lag = (self._now_us - stamp_us) // 100_000       # released this late after its stamp (0.1 s bins)
            self.release_lag[lag] = self.release_lag.get(lag, 0) + 1
        self._due_us = max(self._due_us, stamp_us + self.latency_us)
        self._due.append((self._due_us, msg))

    def deliver(self, now_us: int) -> None:
        """Forward the released frames due by the firmware time ``now_us`` (called before each frame's
        answer, so ArduPilot's loop at ``now_us`` reads them): each reaches ArduPilot a fixed latency
        after its stamp, so the 10 Hz GPS_INPUT arrives every 100 ms of firmware time, as from a GPS."""
        due = self._due
        gps = False
        while due and due[0][0] <= now_us:
            due_us, msg = due[0]
            if msg.get_msgId() == GPS_INPUT_ID:
                if gps:             # one per loop: ArduPilot's GPS driver keeps only the newest of a loop
                    return
                gps = True
                gap = (now_us - self._last_gps_us) // 20_000     # in firmware loops
                self.gps_gaps[gap] = self.gps_gaps.get(gap, 0) + 1
                self._last_gps_us = now_us
            due.popleft()
            late = now_us - due_us
            if late > LATE_US:
                self.late_frames += 1
                self.max_late_us = max(self.max_late_us, late)
            self._forward(msg)

    def _forward(self, msg) -> None:
        if self.fc is None:
            return
        self.fc.setblocking(True)
        try:
            self.fc.sendall(msg.get_msgbuf())
            self.frames_to_fc += 1
        except OSError:
            pass
        if self.fc is not None:
            self.fc.setblocking(False)

    def boundary(self, now_us: int) -> None:
        """ArduPilot has run its loop at our time ``now_us``: pass its output on, then wait until the
        companion has answered what it was given up to the last boundary (less one period: it
        answers once per setpoint period of firmware time)."""
        self.pump_fc()
        self._now_us = now_us
        gate = self.gate
        boundary_us = self._answer_ms * 1000 - gate.period_us
        self._answer_ms = self.fc_time_ms
        if not gate.peer_heard:
            if now_us < self.hold_from_us or self.fc is None:
                self._read_companion(0.0)
                if not self._held:
                    return
            else:                       # hold the world until the companion speaks
                start = time.monotonic()
                while not self._held and time.monotonic() - start < gate.start_timeout_s:
                    self.pump_fc()
                    self._read_companion(0.05)
                self.start_wait_wall_s += time.monotonic() - start
                if not self._held:
                    return
        start = time.monotonic()
        deadline = start + gate.timeout_s
        timed_out = False
        while not self._release(boundary_us):
            if self.companion is None:      # gone (it exits when the mission is done): the world runs on
                break
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                timed_out = True
                break
            self._read_companion(min(remaining, 0.05))
        gate.finish(time.monotonic() - start, timed_out)

    def stats(self) -> dict:
        return {**self.gate.stats(), "relay_bytes_to_companion": self.bytes_to_companion,
                "relay_frames_to_fc": self.frames_to_fc, "fc_time_s": self.fc_time_ms / 1000.0,
                "start_wait_wall_s": round(self.start_wait_wall_s, 3), "relay_latency_s": self.latency_us / 1e6,
                "relay_late_frames": self.late_frames, "relay_max_late_s": self.max_late_us / 1e6,
                "relay_release_lag_hist_0.1s": dict(sorted(self.release_lag.items())),
                "relay_gps_gap_hist_loops": dict(sorted((k, v) for k, v in self.gps_gaps.items() if k < 100))}

    def close(self) -> None:
        for sock in (self.fc, self.companion, self.listener):
            if sock is not None:
                sock.close()
