"""What the stand-in sends: messages queued during one simulated instant, then flushed to every link.

:class:`Outbox` encodes each message once (:class:`sitl.mavframe.FrameEncoder`), rate-limits
repeated STATUSTEXT warnings (one per kind per 5 s of *simulated* time), and at the end of
each instant applies the link faults of :class:`sitl.fc.faults.FaultInjector` (loss and
duplication drawn from the seeded link generator; a delay is a FIFO, so no frame overtakes a
delayed one), writes the tlog, and packs the frames into datagrams of at most
``MAX_DATAGRAM_BYTES`` (``batch``) before sending them to every link. With ``hold`` (lockstep)
the frames of each instant, faults applied and tlog written at that instant, are held and sent
at the next lockstep boundary or the end of the run (:meth:`Outbox.flush` with ``release``): the companion's answers are
only read at the boundaries anyway, so it sees the same frames in the same order, in one burst
of datagrams per boundary instead of one per 0.1 s instant (each a wake-up of the companion; a
third of the lockstep mission's system time went to them). With ``coalesce`` (free-run,
``--speedup 0``: no wall clock to keep, nobody waited for) consecutive instants share a
datagram, whole instants while they fit ``MAX_DATAGRAM_BYTES``: an instant's frames are about
180 bytes at the default 10 Hz streams, so about seven instants share a datagram (the
benchmark's hour: 5,041 datagrams instead of 36,001, each a ``sendto`` of ~4 us and a wake-up of
the reader). What must not wait leaves at the end of its instant with everything before it
(``urgent``: a STATUSTEXT, anything queued while input was handled, i.e. every reply), and
:meth:`Outbox.send_coalesced` sends the rest before a forwarded frame and at the end of the run.
The frames, their order and their tlog stamps are those of a run without coalescing.
:attr:`Outbox.delivered_us` is the simulated instant of the newest frame that left with a time stamp
the companion's clock can follow (not lost, not still delayed): the newest time a lockstep companion
can answer (:mod:`sitl.fc.lockstep`).
A reply queued with :meth:`Outbox.emit_reply` leaves on the link its request came in on only
(``reply_link``, set by the router while a handler runs), as ArduPilot answers PARAM_REQUEST_READ
and PARAM_REQUEST_LIST on the requesting channel (``GCS_Param.cpp``: ``reply.chan = req.chan``):
a ground station never sees the flight controller's answers to the companion's reads.
:class:`Counters` is the run's tally of events, reported in the summary.
"""
from __future__ import annotations

import os
import sys

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.clock import SimClock
from sitl.links import MAX_DATAGRAM_BYTES, Link
from sitl.mavframe import FrameEncoder

__all__ = ["STATUSTEXT_MIN_INTERVAL_S", "Counters", "Outbox"]

STATUSTEXT_MIN_INTERVAL_S = 5.0    # per kind of repeated warning
# messages whose time_boot_ms a companion's clock follows (their ids): what makes an instant delivered
TIMED_IDS = frozenset(cls.id for cls in mavlink.mavlink_map.values() if "time_boot_ms" in cls.fieldnames)


def _timed(frame: bytes) -> bool:
    """Whether a frame carries a ``time_boot_ms`` stamp (its id: MAVLink 2 bytes 7-9, little-endian; 1: byte 5)."""
    msg_id = frame[7] | frame[8] << 8 | frame[9] << 16 if frame[0] == 0xFD else frame[5]
    return msg_id in TIMED_IDS


class Counters(dict):
    """Event counts by name (a dict, so the summary can print it as it is)."""

    def add(self, key: str, n: int = 1) -> None:
        self[key] = self.get(key, 0) + n


class _Reply(bytes):
    """An encoded frame for one link only (:meth:`Outbox.emit_reply`); bytes to everything else
    (the link faults, the tlog), so it keeps its place among the frames around it."""

    link: Link


class Outbox:
    """Queue of encoded frames for the current simulated instant, and their delivery."""

    def __init__(self, encoder: FrameEncoder, clock: SimClock, counters: Counters, faults, link_rng,
                 start_unix_us: int, batch: bool = True, quiet: bool = False, hold: bool = False) -> None:
        self.encoder = encoder
        self._frame_of = encoder.frame_of
        self.clock = clock
        self.counters = counters
        self.faults = faults            # reads .loss, .dup, .delay_us
        self.link_rng = link_rng
        self.start_unix_us = start_unix_us
        self.batch = batch
        self.quiet = quiet
        self.hold = hold                # lockstep: send only when a boundary releases
        self._held: list[bytes] = []
        self.links: list[Link] = []
        self.tlog = None
        self.tx_by_type: dict[str, int] = {}
        self.delayed: list[tuple[int, int, bytes]] = []   # (release, instant, frame) of a link_delay fault
        self.delivered_us = -1          # the instant (t_us) of the newest timed frame that left
        self._out: list[bytes] = []
        self._last_say: dict[str, float] = {}
        self.coalesce = False           # free-run: instants share datagrams (set by the server)
        self.urgent = False             # what this instant queued must not wait for later ones (read when coalescing)
        self._coalesced: list[bytes] = []
        self._coalesced_bytes = 0
        self.reply_link: Link | None = None   # the link of the request being handled (set by the router)
        self._replied = False           # a reply was ever queued: deliveries look for frames of one link

    def emit(self, cls, *fields) -> None:
        """Queue one message (class and ``*_encode`` arguments) for the end of this iteration."""
        self._out.append(self._frame_of(cls, fields))
        counts = self.tx_by_type
        name = cls.msgname
        counts[name] = counts.get(name, 0) + 1

    def emit_reply(self, cls, *fields) -> None:
        """Queue one message for the link the request being handled came in on only (every link
        outside a handler)."""
        if self.reply_link is None:
            self.emit(cls, *fields)
            return
        frame = _Reply(self._frame_of(cls, fields))
        frame.link = self.reply_link
        self._replied = True
        self._out.append(frame)
        self.tx_by_type[cls.msgname] = self.tx_by_type.get(cls.msgname, 0) + 1

    def emit_from(self, encoder: FrameEncoder, cls, *fields) -> None:
        """Queue one message another system sends through this flight controller (a ground
        station behind its telemetry link): encoded with that system's ``encoder``."""
        self._out.append(encoder.frame_of(cls, fields))
        self.tx_by_type[cls.msgname] = self.tx_by_type.get(cls.msgname, 0) + 1

    def say(self, key: str | None, severity: int, text: str) -> None:
        """STATUSTEXT (at most one per ``key`` per 5 s of simulated time when ``key`` is given)."""
        now = self.clock.time_s
        if key is not None:
            last = self._last_say.get(key)
            if last is not None and now - last < STATUSTEXT_MIN_INTERVAL_S:
                self.counters.add("statustext_suppressed")
                return
            self._last_say[key] = now
        if not self.quiet and os.environ.get("FCMPC_SITL_ECHO"):
            print(f"[{now:10.1f}] {text}", file=sys.stderr)
        self.emit(mavlink.MAVLink_statustext_message, severity, text.encode("ascii", "replace")[:50])
        self.urgent = True              # an announcement is news: not held for a coalesced datagram

    def relay_events(self, source) -> None:
        """Announce (and clear) the ``(severity, text)`` events a part such as Guidance collected."""
        events, source.events = source.events, []
        for severity, text in events:
            self.say(None, severity, text)

    def _impair(self, frames: list[bytes]) -> list[bytes]:
        """Loss and duplication faults, drawn per frame from the link generator (what is delivered of
        an instant is judged by :meth:`_delivered` on the frames kept)."""
        loss, dup = self.faults.loss, self.faults.dup
        kept = []
        rand = self.link_rng.random
        for frame in frames:
            if loss and rand() < loss:
                self.counters.add("tx_dropped_fault")
                continue
            kept.append(frame)
            if dup and rand() < dup:
                kept.append(frame)
                self.counters.add("tx_duplicated_fault")
        return kept

    def _delay(self, frames: list[bytes]) -> list[bytes]:
        """A FIFO link with latency: frames leave in order, none overtakes a delayed one. Each keeps its
        instant, so :attr:`delivered_us` follows what left, not what was sent (a delay that ends
        still holds the frames queued behind it)."""
        now_us, delay_us = self.clock.t_us, self.faults.delay_us
        if frames:
            release = now_us + delay_us
            if self.delayed:
                release = max(release, self.delayed[-1][0])
            self.delayed.extend((release, now_us, frame) for frame in frames)
            if delay_us:
                self.counters.add("tx_delayed_fault", len(frames))
        k = 0
        while k < len(self.delayed) and self.delayed[k][0] <= now_us:
            k += 1
        left, frames = self.delayed[:k], [frame for _, _, frame in self.delayed[:k]]
        del self.delayed[:k]
        self.delivered_us = max([self.delivered_us, *(t for _, t, frame in left if _timed(frame))])
        return frames

    def flush(self, release: bool = True) -> None:
        """Send what this instant queued (after the link faults) to every link; with ``hold``, only
        when ``release`` (a lockstep boundary), together with what earlier instants held back; with
        ``coalesce`` (free-run), into the datagram being filled (:meth:`_coalesce`)."""
        frames, self._out = self._out, []
        faults = self.faults
        if faults.loss or faults.dup:
            frames = self._impair(frames)
        if faults.delay_us or self.delayed:
            frames = self._delay(frames)
        elif frames and (not faults.loss or any(map(_timed, frames))):
            self.delivered_us = self.clock.t_us     # without a loss fault every instant has its stamps
        if frames:
            self.counters.add("tx_messages", len(frames))
            if self.tlog is not None:
                stamp = self.start_unix_us + self.clock.t_us
                for frame in frames:
                    self.tlog.write(stamp, frame)
        if self.hold:
            self._held += frames
            if not release:
                return
            frames, self._held = self._held, []
        if self.coalesce:
            self._coalesce(frames)
            return
        if not frames:
            for link in self.links:
                link.flush()
            return
        if self._replied and any(type(frame) is _Reply for frame in frames):
            for link in self.links:     # each link its own frames, in their order
                for chunk in self._chunks([f for f in frames if type(f) is not _Reply or f.link is link]):
                    link.send(chunk)
            return
        chunks = self._chunks(frames)
        for link in self.links:
            for chunk in chunks:
                link.send(chunk)

    def _chunks(self, frames: list[bytes]) -> list[bytes]:
        """``frames`` as datagrams: one per frame, or (``batch``) joined up to ``MAX_DATAGRAM_BYTES``."""
        if not self.batch:
            return frames
        if sum(map(len, frames)) <= MAX_DATAGRAM_BYTES:
            return [b"".join(frames)] if frames else []   # an instant's frames fit one datagram (the usual case)
        chunks, current, size = [], [], 0
        for frame in frames:
            if size + len(frame) > MAX_DATAGRAM_BYTES and current:
                chunks.append(b"".join(current))
                current, size = [], 0
            current.append(frame)
            size += len(frame)
        chunks.append(b"".join(current))
        return chunks

    def _coalesce(self, frames: list[bytes]) -> None:
        """Free-run: add this instant's frames to the datagram being filled; send it when they would
        not fit, or at once when ``urgent``. An instant always stays whole in one datagram if it fits."""
        if frames:
            size = sum(map(len, frames))
            if self._coalesced_bytes + size > MAX_DATAGRAM_BYTES:
                self.send_coalesced()
            if size <= MAX_DATAGRAM_BYTES:
                self._coalesced += frames
                self._coalesced_bytes += size
            else:   # larger than a datagram (a parameter list): chunked at frame boundaries, as without coalescing
                for frame in frames:
                    if self._coalesced_bytes + len(frame) > MAX_DATAGRAM_BYTES:
                        self.send_coalesced()
                    self._coalesced.append(frame)
                    self._coalesced_bytes += len(frame)
        if self.urgent:
            self.urgent = False
            self.send_coalesced()
        elif not frames:
            for link in self.links:
                link.flush()

    def send_coalesced(self) -> None:
        """Send the frames coalesced so far as one datagram (free-run): before anything that must
        not overtake them (a forwarded frame) and at the end of the run."""
        if self._coalesced:
            frames, self._coalesced, self._coalesced_bytes = self._coalesced, [], 0
            data = b"".join(frames)
            directed = self._replied and any(type(frame) is _Reply for frame in frames)
            for link in self.links:
                if directed:
                    data = b"".join(f for f in frames if type(f) is not _Reply or f.link is link)
                if data:
                    link.send(data)
