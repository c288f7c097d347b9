"""The companion's MAVLink link to ArduPilot, through the world's process, so the world can wait for it.

ArduPilot's SERIAL1 (TCP ``5762 + 10 I``) is the companion's port on a vehicle; here the world's
process connects to it and listens for the companion on ``relay_port(I)`` (TCP ``9008 + 10 I``).
What ArduPilot sends is passed on every ``pump_period_s`` of firmware time, unparsed but for the
headers, from which the newest firmware time passed on is kept (the heavy direction). What the
companion sends is split into MAVLink frames (:mod:`sitl.physics.mavlink_frames`: the header and the
stamp's bytes read, the frame passed on as sent), each due at a fixed firmware time: its own
stamp (``time_boot_ms`` as ``companion --lockstep`` stamps it: the newest firmware time it has seen;
GPS_INPUT's UNIX ``time_usec`` placed on the boot clock with SYSTEM_TIME's pairing) plus
``latency_s``; an unstamped frame (HEARTBEAT, COMMAND_LONG) keeps its place after the one before it.
ArduPilot's loop at firmware time ``T`` reads the frames due by ``T``, at most one GPS_INPUT a loop,
so the 10 Hz feed arrives every 100 ms of firmware time, as from a GPS (a feed passed on in bursts
left ArduPilot calling it "GPS 2: not healthy"; see the dated note).

**The gate, on ArduPilot's clock.** Before ArduPilot's loop at ``T`` runs, every frame due by ``T``
must be known, or which loop reads it would depend on the machine's pace. The companion's stamps never
go back, so one frame due after ``T`` (a stamp later than ``T - latency``) proves it: the world reads
the companion only when the frames it holds are all due by ``T`` (lazily, once per few hundred ms of
firmware time), and waits (``select`` on the companion's socket: an event, never a poll) only when the
companion has not yet answered that far. The companion may thus run up to ``latency_s`` less what it
has not been given yet (``pump_period_s``, the serial link's queue) and its answer period behind the
world without the world stopping: the world and the companion meet only when the companion falls that
far behind, instead of every 0.2 s (the first version waited at 594,375 boundaries on the Pacific and
spent two thirds of its wall time there). The gate cannot stall: the companion can answer only what it
was given, so the wait also ends once it has answered the newest firmware time passed on, less two
answer periods (``fallback``, counted; frames due earlier than that are then forwarded late, counted).
Determinism: which loop reads a frame is fixed by its stamp, and the stamp by the companion's message
sequence, not by when either process runs; a run depends on the machine only through a lockstep
timeout (``timeout_s`` of wall time, a hang guard) or a fallback, both counted in :meth:`stats`.

From ``hold_from_s`` of firmware time the world waits for the companion to appear (the runner starts
it after the firmware's start-up and compass calibration); until its first stamped frame (its lockstep
loop needs the firmware's messages, so the world cannot hold for that) the gate is open.
"""
from __future__ import annotations

import errno
import select
import socket
import struct
import time
from collections import deque

from pymavlink.dialects.v20 import common as mavlink2

from sitl.physics.mavlink_frames import TIME_BOOT_MS_OFFSET, time_boot_ms, whole_frames

__all__ = ["CompanionRelay", "FirmwareTimes", "relay_port", "serial1_port"]

# the messages ArduPilot streams with time_boot_ms (its offset in the payload from pymavlink's layouts)
_STAMP_OFFSET = {msgid: TIME_BOOT_MS_OFFSET[msgid] for msgid in (
    mavlink2.MAVLINK_MSG_ID_ATTITUDE, mavlink2.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mavlink2.MAVLINK_MSG_ID_RC_CHANNELS, mavlink2.MAVLINK_MSG_ID_SCALED_IMU,
    mavlink2.MAVLINK_MSG_ID_SCALED_IMU2, mavlink2.MAVLINK_MSG_ID_SCALED_IMU3, mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME)}
GPS_INPUT_ID = mavlink2.MAVLINK_MSG_ID_GPS_INPUT
_SYSTEM_TIME = mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME
_GPS_INPUT_TIME_USEC = struct.Struct("<Q")   # GPS_INPUT's first field on the wire
LATENCY_S = 1.2          # from a frame's stamp to ArduPilot (see the note); > pump period + 2 answer periods
ANSWER_PERIOD_S = 0.2    # the companion sends a stamped frame at least this often (COMP_SP_RATE_HZ 5, --lockstep)
PUMP_PERIOD_S = 0.2      # ArduPilot's output passed on to the companion this often (firmware time)
LATE_US = 20_000         # a frame forwarded more than one physics frame after its due time is late


def relay_port(instance: int) -> int:
    """Where the companion connects (TCP) for ArduPilot instance ``instance``.

    >>> relay_port(0), relay_port(2)
    (9008, 9028)
    """
    return 9008 + 10 * instance


def serial1_port(instance: int) -> int:
    return 5762 + 10 * instance


class FirmwareTimes:
    """The newest ``time_boot_ms`` in ArduPilot's output, and SYSTEM_TIME's pairing of UNIX and boot time,
    read from the frames' headers alone (the firmware's stream is the heavy direction: no decoding, no CRC)."""

    def __init__(self) -> None:
        self.time_ms = 0                 # the newest firmware time seen
        self.unix_minus_boot_us: int | None = None
        self._tail = b""                 # an incomplete frame at the end of the last read

    def feed(self, data: bytes) -> None:
        """The next bytes of ArduPilot's output."""
        buf = self._tail + data if self._tail else data
        i, end, newest = 0, len(buf), self.time_ms
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
                    if msgid == _SYSTEM_TIME:   # time_unix_usec (uint64) before time_boot_ms
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
        self._tail = bytes(buf[i:]) if i < end else b""
        self.time_ms = newest


class CompanionRelay:
    """ArduPilot SERIAL1 <-> the companion, the companion's frames due at their stamps plus the latency."""

    def __init__(self, instance: int, timeout_s: float = 30.0, hold_from_s: float = 90.0,
                 start_timeout_s: float = 600.0, latency_s: float = LATENCY_S,
                 pump_period_s: float = PUMP_PERIOD_S, answer_period_s: float = ANSWER_PERIOD_S) -> None:
        if not latency_s > pump_period_s + 2.0 * answer_period_s:
            raise ValueError(f"relay latency {latency_s} s: must exceed what the companion cannot have answered yet, "
                             f"the pump period {pump_period_s} s and two answer periods ({answer_period_s} s each)")
        self.instance = instance
        self.latency_us = int(round(latency_s * 1e6))
        self.pump_period_us = int(round(pump_period_s * 1e6))
        self.fallback_us = int(round(2.0 * answer_period_s * 1e6))
        self.timeout_s = timeout_s
        self.start_timeout_s = start_timeout_s
        self.hold_from_us = int(hold_from_s * 1e6)
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", relay_port(instance)))
        self.listener.listen(1)
        self.listener.setblocking(False)
        self.fc: socket.socket | None = None
        self.companion: socket.socket | None = None
        self._from_companion = bytearray()   # what the companion sent, up to an incomplete last frame
        self._due: deque = deque()       # the companion's frames, (firmware time due in us, stamped, msgid, frame)
        self._due_us = 0                 # the due time of the last frame scheduled (never goes back)
        self._stamped = False            # the companion has sent a stamped frame: the gate is closed from now on
        self._heard = False
        self._next_pump_us = 0
        self.late_frames = 0             # stamped frames forwarded more than a frame after their due time
        self.max_late_us = 0
        self.fc_lag: dict[int, int] = {}  # firmware time minus the newest time passed on, at each pump (0.1 s bins)
        self.gps_gaps: dict[int, int] = {}    # firmware loops between GPS_INPUTs forwarded
        self._last_gps_us = 0
        self.times = FirmwareTimes()     # of what was passed on to the companion
        self._tries = 0
        self.bytes_to_companion = 0
        self.frames_to_fc = 0
        self.start_wait_wall_s = 0.0
        self.reads = 0                   # the companion's socket read because a frame's due time was near
        self.waits = 0                   # ... and the world had to wait for it
        self.wait_wall_s = 0.0
        self.max_wait_wall_s = 0.0
        self.timeouts = 0
        self.fallbacks = 0
        self.last_fallback_us = -1       # firmware time of the last one (before the companion's own streams
        #                                  flow, ArduPilot's only timed message on its port comes once a second)

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
    def pump_fc(self, now_us: int | None = None) -> None:
        """Pass on everything ArduPilot has written (dropped while no companion is connected);
        ``now_us``: the firmware's time, for the statistics of how far its output trails it."""
        if self.fc is None:
            self._connect_fc()
            if self.fc is None:
                return
        if self.companion is None:
            self._accept()
        fc = self.fc
        while True:
            try:
                data = fc.recv(262144)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                data = b""
            if not data:            # ArduPilot closed the port
                fc.close()
                self.fc = None
                return
            # acknowledge at once (Linux leaves quick-ack mode again after a read): SITL's TCP port writes
            # small frames with Nagle's algorithm on, so each waited in ArduPilot's send queue for our
            # delayed ACK (40 ms of wall time) or its retransmission timer (200 ms); its output trailed the
            # firmware's clock by up to 0.9 s on a loaded machine (ss -ti: Send-Q held, 0.5 % retransmitted)
            fc.setsockopt(socket.IPPROTO_TCP, socket.TCP_QUICKACK, 1)
            self.times.feed(data)
            if self.companion is not None:
                self._to_companion(data)
        if now_us is not None and self.times.time_ms:
            lag = (now_us - self.times.time_ms * 1000) // 100_000
            self.fc_lag[lag] = self.fc_lag.get(lag, 0) + 1

    def _to_companion(self, data: bytes) -> None:
        sock = self.companion
        try:
            sent = sock.send(data)          # loopback: all of it, unless the companion is far behind
            if sent < len(data):
                sock.setblocking(True)
                sock.sendall(data[sent:])
                sock.setblocking(False)
            self.bytes_to_companion += len(data)
        except BlockingIOError:
            sock.setblocking(True)
            try:
                sock.sendall(data)
                self.bytes_to_companion += len(data)
            except OSError:
                self._companion_lost()
                return
            sock.setblocking(False)
        except OSError:
            self._companion_lost()

    def _companion_lost(self) -> None:
        if self.companion is not None:
            self.companion.close()
        self.companion = None

    # ------------------------------------------------------------------ companion -> ArduPilot
    def _read_companion(self) -> None:
        """Schedule whatever the companion has sent (without waiting)."""
        try:
            data = self.companion.recv(262144)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as err:
            if err.errno == errno.EAGAIN:
                return
            data = b""
        if not data:
            self._companion_lost()
            return
        self._heard = True
        self._from_companion += data
        for msgid, payload, frame in whole_frames(self._from_companion):
            self._schedule(msgid, payload, frame)

    def _schedule(self, msgid: int, payload: bytes, frame: bytes) -> None:
        """Queue a frame for the firmware time of its own stamp plus :attr:`latency_us`; an unstamped
        frame (HEARTBEAT, COMMAND_LONG) keeps its place after the one before it. GPS_INPUT carries UNIX
        time (``time_usec``), placed on the boot clock with SYSTEM_TIME's pairing. A stamp later than
        anything passed on (another boot's) counts as none."""
        stamp_ms = time_boot_ms(msgid, payload)
        if stamp_ms:
            stamp_us = stamp_ms * 1000
        elif msgid == GPS_INPUT_ID and self.times.unix_minus_boot_us is not None:
            time_usec, = _GPS_INPUT_TIME_USEC.unpack((payload + bytes(8))[:8])
            stamp_us = time_usec - self.times.unix_minus_boot_us
        else:
            stamp_us = 0
        stamped = 0 < stamp_us <= self.times.time_ms * 1000 + self.fallback_us
        if stamped:
            self._stamped = True
            self._due_us = max(self._due_us, stamp_us + self.latency_us)
        self._due.append((self._due_us, stamped, msgid, frame))

    def frame(self, now_us: int) -> None:
        """Before ArduPilot's loop at firmware time ``now_us`` (called before each frame's answer):
        make sure every frame due by ``now_us`` is known (the gate), and forward those, at most one
        GPS_INPUT a loop."""
        if self._due_us <= now_us:
            self._gate(now_us)
        due = self._due
        if due and due[0][0] <= now_us:
            self._deliver(now_us)

    def answered(self, now_us: int) -> None:
        """After the answer that lets ArduPilot's loop at ``now_us`` run: pass its output on when a pump
        is due (while ArduPilot runs its loop, off the round trip's critical path)."""
        if now_us >= self._next_pump_us:
            self._next_pump_us = now_us + self.pump_period_us
            self.pump_fc(now_us)

    def _gate(self, now_us: int) -> None:
        """Read the companion; once it sends stamped frames, wait until one is due after ``now_us``
        (or it answered the newest firmware time passed on, less the fallback; or it is gone)."""
        if self.companion is None:
            if self._heard or now_us < self.hold_from_us or self.fc is None:
                return              # not yet held for, or gone (it exits when its mission is done)
            start = time.monotonic()          # hold the world until the companion speaks
            while not self._heard and time.monotonic() - start < self.start_timeout_s:
                self.pump_fc()
                if self.companion is None:
                    select.select([self.listener], [], [], 0.5)
                    continue
                select.select([self.companion], [], [], 0.5)
                if self.companion is not None:
                    self._read_companion()
            self.start_wait_wall_s += time.monotonic() - start
            return
        self.reads += 1
        self._read_companion()
        if self._due_us > now_us or not self._stamped:
            return
        answered_us = self.times.time_ms * 1000 - self.fallback_us
        if self._due_us - self.latency_us >= answered_us:
            self.fallbacks += 1         # answered all it could: the serial link trails by more than the latency
            self.last_fallback_us = now_us
            return
        self.waits += 1
        start = time.monotonic()
        deadline = start + self.timeout_s
        while self._due_us <= now_us and self.companion is not None:
            if self._due_us - self.latency_us >= answered_us:
                self.fallbacks += 1
                self.last_fallback_us = now_us
                break
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                self.timeouts += 1
                break
            select.select([self.companion], [], [], min(remaining, 1.0))
            self._read_companion()
        waited = time.monotonic() - start
        self.wait_wall_s += waited
        self.max_wait_wall_s = max(self.max_wait_wall_s, waited)

    def _deliver(self, now_us: int) -> None:
        due = self._due
        out = []
        gps = False
        while due and due[0][0] <= now_us:
            due_us, stamped, msgid, frame = due[0]
            if msgid == GPS_INPUT_ID:
                if gps:             # one per loop: ArduPilot's GPS driver keeps only the newest of a loop
                    break
                gps = True
                gap = (now_us - self._last_gps_us) // 20_000     # in firmware loops
                self.gps_gaps[gap] = self.gps_gaps.get(gap, 0) + 1
                self._last_gps_us = now_us
            due.popleft()
            if stamped:
                late = now_us - due_us
                if late > LATE_US:
                    self.late_frames += 1
                    self.max_late_us = max(self.max_late_us, late)
            out.append(frame)
        if out and self.to_fc(b"".join(out)):
            self.frames_to_fc += len(out)

    def to_fc(self, data: bytes) -> bool:
        """Write ``data`` to ArduPilot's SERIAL1 (whole frames); False while it is not connected."""
        fc = self.fc
        if fc is None:
            return False
        fc.setblocking(True)
        try:
            fc.sendall(data)
        except OSError:
            return False
        finally:
            fc.setblocking(False)
        return True

    def stats(self) -> dict:
        return {"lockstep_reads": self.reads, "lockstep_waits": self.waits, "lockstep_timeouts": self.timeouts,
                "lockstep_fallbacks": self.fallbacks, "lockstep_last_fallback_s": self.last_fallback_us / 1e6, "lockstep_wait_wall_s": round(self.wait_wall_s, 3),
                "lockstep_max_wait_wall_s": round(self.max_wait_wall_s, 3),
                "relay_bytes_to_companion": self.bytes_to_companion,
                "relay_frames_to_fc": self.frames_to_fc, "fc_time_s": self.times.time_ms / 1000.0,
                "start_wait_wall_s": round(self.start_wait_wall_s, 3), "relay_latency_s": self.latency_us / 1e6,
                "relay_pump_period_s": self.pump_period_us / 1e6,
                "relay_late_frames": self.late_frames, "relay_max_late_s": self.max_late_us / 1e6,
                "relay_fc_lag_hist_0.1s": dict(sorted(self.fc_lag.items())),
                "relay_gps_gap_hist_loops": dict(sorted((k, v) for k, v in self.gps_gaps.items() if k < 100))}

    def close(self) -> None:
        for sock in (self.fc, self.companion, self.listener):
            if sock is not None:
                sock.close()
