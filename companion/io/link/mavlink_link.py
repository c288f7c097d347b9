"""The companion's MAVLink connection: transport, per-sender parsing, pinned peers, signing, records.

One :class:`MavlinkLink` owns one connection (``udp:``/``udpin:`` listen, ``udpout:`` send first,
``tcp:`` client, ``tcpin:`` server, a serial device as ``DEVICE,BAUD``). It speaks MAVLink 2 as
component 191 (MAV_COMP_ID_ONBOARD_COMPUTER) of the flight controller's system, parses each
sender's bytes with that sender's own parser (:mod:`companion.io.link.peers`), pins the flight
controller, judges its time stamps (:mod:`companion.io.link.clock`), signs and checks
signatures when given a key (:mod:`companion.io.link.signing`), records both directions to a
``.tlog`` (:mod:`companion.io.link.tlog`), and offers one send helper per output
(:mod:`companion.io.link.outputs`). It holds no navigation state: the application decides
*what* to send; the link decides *how*, *to whom*, and refuses what must never go out.
"""
from __future__ import annotations

import contextlib
import math
import select
import time
from collections.abc import Callable, Hashable, Iterator
from dataclasses import dataclass
from pathlib import Path

from companion.io.link.clock import MessageClock
from companion.io.link.fastparse import parse_datagram
from companion.io.link.conventions import (
    COMPANION_COMPONENT,
    FcState,
    conventions_for,
    mavlink,
)
from companion.io.link.outputs import LinkOutputs
from companion.io.link.peers import (
    PEER_CAPACITY,
    STRANGER_RATE_HZ,
    PeerPolicy,
    PeerTable,
)
from companion.io.link.signing import Signing
from companion.io.link.tlog import Tlog
from companion.io.link.transport import STREAM, open_transport
from companion.params import SPEC_BY_NAME

__all__ = ["LinkStats", "MavlinkLink"]

SIGNING_TICK_WALL_S = 1.0


@dataclass
class LinkStats:
    messages_in: int = 0
    bytes_in: int = 0
    bad_frames: int = 0
    leftover_bytes: int = 0        # bytes of an incomplete frame at the end of a datagram (dropped)
    messages_out: int = 0
    setpoints_sent: int = 0
    setpoints_refused: int = 0
    positions_fed: int = 0
    dropped_stamps: int = 0        # FC messages dropped by the clock's judgement
    before_heartbeat: int = 0      # FC messages dropped because they came before its first heartbeat
    last_refusal: str = ""


class MavlinkLink(LinkOutputs):
    """One MAVLink connection of the companion (component 191).

    ``sysid``/``fc_compid`` pin the flight controller (default: the first autopilot heard);
    ``gcs_sysids`` are the ground stations that receive outputs and may set parameters;
    ``speed_ceiling_mps`` caps every setpoint whatever the caller's limit (default the registry's
    SAFE_SPEED_KMH); ``signing`` signs
    every output and refuses unsigned commands and parameter writes; ``tlog_max_bytes`` rotates
    the record (0: no cap).
    """

    def __init__(self, connect: str, sysid: int | None = None, component: int = COMPANION_COMPONENT,
                 tlog_path=None, wall_clock: Callable[[], float] = time.monotonic, *, fc_compid: int | None = None,
                 gcs_sysids: frozenset[int] = frozenset({255}), speed_ceiling_mps: float | None = None,
                 signing: Signing | None = None, tlog_max_bytes: int = 0, peer_capacity: int = PEER_CAPACITY,
                 stranger_rate_hz: float = STRANGER_RATE_HZ) -> None:
        self.connect_text = connect
        self.fixed_sysid = sysid
        self.component = component
        self.tlog_path = Path(tlog_path) if tlog_path else None
        self.tlog_max_bytes = tlog_max_bytes
        self.wall = wall_clock
        # wall seconds spent waiting on the socket (wait_readable): the clock a silent flight controller
        # is judged on, which the companion's own busy or blocked time does not advance
        self.listened_s = 0.0
        # no ceiling given: the registry's default SAFE_SPEED_KMH, never none at all
        self.speed_ceiling_mps = (SPEC_BY_NAME["SAFE_SPEED_KMH"].default / 3.6 if speed_ceiling_mps is None
                                  else speed_ceiling_mps)
        self.signing = signing
        self.fc = FcState()
        self.clock = MessageClock()
        self.stats = LinkStats()
        self.peers = PeerTable(self._new_parser, wall_clock, peer_capacity,
                               PeerPolicy(sysid, fc_compid, frozenset(gcs_sysids)), stranger_rate_hz,
                               listened=lambda: self.listened_s)
        self.conn = None
        self._mav = None
        self._tlog: Tlog | None = None
        self._statustext_id = 0
        self._next_signing_tick = -math.inf
        self.reported_autopilots: set[tuple[int, int]] = set()

    def apply_ceiling(self, ceiling, tlog_max_bytes: int | None = None) -> None:
        """Take the start-up safety ceiling (:class:`companion.ceiling.SafetyCeiling`): the speed cap
        of every setpoint and the allowed ground-station ids; optionally the tlog size cap."""
        self.speed_ceiling_mps = ceiling.speed_mps
        self.peers.policy.gcs_sysids = frozenset(ceiling.gcs_sysids)
        if tlog_max_bytes is not None:
            self.tlog_max_bytes = int(tlog_max_bytes)

    def counters(self) -> dict:
        """What the link refused or dropped, for the session summary and the soak table."""
        out = {"bad_frames": self.stats.bad_frames, "leftover_bytes": self.stats.leftover_bytes,
               "impostor_frames": self.peers.impostor_frames, "peers_evicted": self.peers.evicted,
               "stranger_datagrams_shed": self.peers.shed,
               "dropped_stamps": self.stats.dropped_stamps, "before_heartbeat": self.stats.before_heartbeat,
               "out_of_order": self.clock.out_of_order,
               "far_future": self.clock.far_future, "far_past": self.clock.far_past,
               "fc_reboots": self.clock.reboots, "time_jumps": self.clock.jumps,
               "other_autopilots": sorted(self.peers.other_autopilots)}
        if self.signing is not None:
            out["unsigned_refused"] = dict(self.signing.refused)
            out["bad_signatures"] = self.signing.bad_signatures
        return out

    # --- connection -------------------------------------------------------------------------
    def _new_parser(self):
        parser = mavlink.MAVLink(None, self.fixed_sysid or 1, self.component)
        parser.robust_parsing = True
        if self.signing is not None:
            self.signing.setup_parser(parser)
        return parser

    def open(self) -> None:
        self.conn = open_transport(self.connect_text, self.peers.destinations, self.fixed_sysid or 1, self.component)
        self._mav = mavlink.MAVLink(self.conn, self.fixed_sysid or 1, self.component)
        self.conn.mav = self._mav
        if self.signing is not None:
            self.signing.setup_encoder(self._mav)
        if self.tlog_path is not None:
            self._tlog = Tlog(self.tlog_path, self.tlog_max_bytes)
        self._mav.set_send_callback(self._log_sent)

    def close(self) -> None:
        if self._tlog is not None:
            self._tlog.close()
            self._tlog = None
        if self.conn is not None:
            self.conn.close()
            self.conn = None

    @contextlib.contextmanager
    def batched(self) -> Iterator[None]:
        """Frames sent inside go out together at the end (packed into datagrams on UDP)."""
        conn = self.conn
        if conn is None:
            yield
            return
        conn.begin_batch()
        try:
            yield
        finally:
            conn.end_batch()

    def __enter__(self) -> MavlinkLink:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def mav(self):
        return self._mav

    @property
    def sysid(self) -> int:
        return self._mav.srcSystem

    def _log_sent(self, msg) -> None:
        self._log_frame(msg.get_msgbuf())

    def _log_frame(self, frame: bytes) -> None:
        self.stats.messages_out += 1
        if self._tlog is not None:
            self._tlog.write(frame)

    def send_packed(self, packer, *args) -> None:
        """``packer``'s message (:class:`~companion.io.link.fastpack.FramePacker`) with the arguments
        of pymavlink's ``*_send``, logged as every output is."""
        frame = packer.send(self._mav, *args)
        if frame is not None:   # signed: pymavlink sent it, and its send callback logged it
            self._log_frame(frame)

    # --- receiving ----------------------------------------------------------------------------
    def wait_readable(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` wall seconds for bytes to read; the wait advances :attr:`listened_s`."""
        fd = self.conn.fileno() if self.conn is not None else None
        start = self.wall()
        try:
            if fd is None:  # pragma: no cover - connections without a file descriptor
                time.sleep(timeout_s)
                return True
            readable, _, _ = select.select([fd], [], [], max(timeout_s, 0.0))
        except (OSError, ValueError):
            return False
        finally:
            self.listened_s += max(0.0, self.wall() - start)
        return bool(readable)

    def read(self, max_bytes: int = 1 << 16) -> list:
        """Messages parsed from what can be read now, each sender through its own parser.

        Frames claiming the pinned flight controller's ids from another address are dropped
        (:attr:`PeerTable.impostor_frames`); each message carries its sender's address as
        ``_fcmpc_address``.
        """
        self._signing_tick()
        if self._tlog is not None:
            self._tlog.maybe_flush()
        out = []
        for address, data in self.conn.receive():
            out.extend(self.feed(address, data))
        return out

    def feed(self, address: Hashable, data: bytes) -> list:
        """Parse ``data`` from ``address`` (one datagram or stream chunk); the admitted messages."""
        stats = self.stats
        stats.bytes_in += len(data)
        if not self.peers.admit_datagram(address):
            return []
        peer = self.peers.peer(address)
        peer.bytes_in += len(data)
        parser = peer.parser
        signing = self.signing
        if signing is not None:
            signing.before_parse(parser, self._mav)
        try:
            msgs = parse_datagram(parser, data)
        except Exception:  # noqa: BLE001 - a corrupt frame must not stop the companion
            msgs = []
            stats.bad_frames += 1
            peer.bad_frames += 1
        if address != STREAM and parser.buf_len():   # UDP: a frame never spans datagrams
            stats.leftover_bytes += parser.buf_len()
            parser.buf, parser.buf_index, parser.expected_length = bytearray(), 0, mavlink.HEADER_LEN_V1 + 2
        if signing is not None:
            signing.after_parse(parser, self._mav)
        out = []
        admit, systems = self.peers.admit, peer.systems
        for msg in msgs:
            if msg._type == "BAD_DATA":
                stats.bad_frames += 1
                peer.bad_frames += 1
                continue
            if not admit(address, msg):
                continue
            systems.add(msg._header.srcSystem)
            msg._fcmpc_address = address
            out.append(msg)
        peer.frames += len(out)
        stats.messages_in += len(out)
        tlog = self._tlog
        if tlog is not None:
            tlog.write_all([msg._msgbuf for msg in out])   # one time stamp: they arrived together
            tlog.maybe_flush()
        return out

    def _signing_tick(self) -> None:
        if self.signing is None or self._mav is None:
            return
        now = self.wall()
        if now >= self._next_signing_tick:
            self._next_signing_tick = now + SIGNING_TICK_WALL_S
            self.signing.tick(self._mav)

    def from_allowed_gcs(self, msg) -> bool:
        """True if ``msg`` comes from an allowed ground-station system id (signed, when signing is on:
        unsigned parameter writes and commands never get this far)."""
        return msg.get_srcSystem() in self.peers.policy.gcs_sysids

    def observe(self, msg) -> bool:
        """Update flight-controller state and message time; True if ``msg`` is the pinned FC's and kept.

        The flight controller is the first system whose component sends a HEARTBEAT with a real
        autopilot (not MAV_AUTOPILOT_INVALID) and matches ``--fc-sysid``/``--fc-compid`` when
        given; its system id becomes ours unless fixed. Its time stamps are judged by
        :class:`MessageClock`: a message whose stamp is out of order or on an unconfirmed time
        base is dropped (False). A second autopilot is reported once through
        :attr:`reported_autopilots` (the application says so), never followed.
        """
        fc, peers = self.fc, self.peers
        if peers.fc_ids is None:   # a message handed in directly (not through read): pin here
            peers.admit(getattr(msg, "_fcmpc_address", None), msg)
        ids = peers.fc_ids
        if ids is None:
            return False
        header = msg._header
        if header.srcSystem != ids[0] or header.srcComponent != ids[1]:
            return False
        if not fc.detected:
            # Nothing of the FC's is kept before the heartbeat that says which autopilot it is: one
            # read can hold its ATTITUDE before that heartbeat, which pins it while the batch is
            # parsed, and a message kept then started the companion on the default (ArduPilot)
            # conventions against PX4 (wrong magnetometer messages, F -42,184 nT, every step excluded)
            if msg.get_type() != "HEARTBEAT":
                self.stats.before_heartbeat += 1
                return False
            fc.sysid, fc.compid = ids
            fc.conventions = conventions_for(msg.autopilot)
            if self._mav is not None:
                self._mav.srcSystem = ids[0]
        if not self._judge_time(msg):
            self.stats.dropped_stamps += 1
            return False
        now_wall = self.wall()
        fc.last_message_wall_s = now_wall
        clock = self.clock
        if fc.heartbeats and not math.isfinite(fc.last_heartbeat_time_s) and clock.started:
            fc.last_heartbeat_time_s = clock.now_s   # the heartbeat came before the first time stamp
        mtype = msg._type
        if mtype == "HEARTBEAT":
            clock.heartbeat()
            fc.heartbeats += 1
            fc.vehicle_type = msg.type
            fc.base_mode, fc.custom_mode, fc.system_status = msg.base_mode, msg.custom_mode, msg.system_status
            fc.last_heartbeat_time_s = clock.now_s
            fc.last_heartbeat_listened_s = self.listened_s
        elif mtype == "COMMAND_ACK" and getattr(msg, "target_component", 0) in (0, self.component):
            fc.acks[msg.command] = msg.result
        return True

    def _judge_time(self, msg) -> bool:
        clock = self.clock
        fields = msg.__dict__   # a message's fields are its attributes
        boot_ms = fields.get("time_boot_ms")
        if msg._type == "SYSTEM_TIME":
            return clock.observe_system_time(msg.time_unix_usec, boot_ms)
        if boot_ms is not None:
            return clock.judge(boot_ms * 1e-3)
        usec = fields.get("time_usec")
        if usec and usec < clock.UNIX_USEC_LIMIT:
            return clock.judge(usec * 1e-6)
        return True

    def new_autopilots(self) -> list[tuple[int, int]]:
        """Autopilots other than the pinned one heard since the last call (report them, do not follow)."""
        fresh = sorted(self.peers.other_autopilots - self.reported_autopilots)
        self.reported_autopilots.update(fresh)
        return fresh

    def heartbeat_age_s(self) -> tuple[float, float]:
        """(message-time age, wall-time age) of the FC's last heartbeat. The wall-time age counts only
        the time spent waiting on the socket since (:attr:`listened_s`): a dead flight controller
        sends nothing while the companion waits, but time the companion itself was busy or blocked
        (a long step; in lockstep the world waiting for it) is not the flight controller's silence,
        and its frames of that time are still queued."""
        msg_age = self.clock.now_s - self.fc.last_heartbeat_time_s if self.clock.started else math.inf
        return msg_age, self.listened_s - self.fc.last_heartbeat_listened_s
