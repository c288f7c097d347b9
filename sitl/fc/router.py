"""Input and routing of the stand-in: bytes from every link -> MAVLink frames -> handlers, and forwarding.

:class:`Router` reads every readable socket, splits the bytes into MAVLink 1/2 frames by
their length bytes (a TCP stream keeps a per-client buffer; a datagram stands alone),
decodes each with pymavlink (bad CRC or an unknown message: resynchronise one byte later and
count it), and handles each frame: its own echo is dropped; a message not addressed to this
vehicle (``target_system``/``target_component``) is forwarded to the other links and peers
like MAVProxy/ArduPilot routing does, so a ground station on TCP reaches a companion on
UDP; HEARTBEATs register peers; the rest goes to the handler of its name. In lockstep the
frames are queued (``pending``) and handled in order at the boundaries (:mod:`sitl.fc.lockstep`).
A handler that raises is counted and announced, never lets a message stop the simulator.
"""
from __future__ import annotations

import os
import selectors
from collections import deque

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.clock import SimClock
from sitl.guidance import SEVERITY_INFO, SEVERITY_WARNING
from sitl.links import Link

__all__ = ["Router"]

MAX_STREAM_BUFFER_BYTES = 65536


class Router:
    """Reads, decodes, forwards and dispatches what arrives on the links."""

    def __init__(self, links: list[Link], selector: selectors.BaseSelector, out, clock: SimClock, counters, *,
                 sysid: int, compid: int, routing: bool, gate=None) -> None:
        self.links = links
        self.selector = selector
        self.out = out
        self.clock = clock
        self.counters = counters
        self.sysid, self.compid = sysid, compid
        self.routing = routing
        self.gate = gate
        self.handlers: dict = {}
        self.tlog = None
        self.peers: dict[tuple[int, int], int] = {}   # (sysid, compid) -> MAV_TYPE
        self.rx_by_type: dict[str, int] = {}
        self.pending: deque = deque()   # lockstep: (link, peer, message, frame, read) read but not yet handled
        self.reads = 0                  # datagrams (stream reads) so far: ``read`` tells a pending frame's
        self._decoder = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self._stream_buffers: dict[object, bytearray] = {}

    def poll(self, timeout: float) -> int:
        """Read every readable socket (waiting up to ``timeout`` s) and handle what arrived."""
        try:
            events = self.selector.select(timeout)
        except (OSError, ValueError):
            return 0
        n = 0
        for key, _ in events:
            link: Link = key.data
            try:
                chunks = link.on_readable(key.fileobj, self.selector)
            except OSError:
                self.counters.add("rx_socket_errors")
                continue
            for peer, data, is_datagram in chunks:
                n += self.receive(link, peer, data, is_datagram)
        return n

    def receive(self, link: Link, peer, data: bytes, is_datagram: bool) -> int:
        """Split ``data`` into frames and handle (or, in lockstep, queue) each; returns their number."""
        self.counters.add("rx_bytes", len(data))
        key = (link.index, peer)
        if is_datagram:
            buf = bytearray(data)
        else:
            if not data:  # TCP client closed
                self._stream_buffers.pop(key, None)
                return 0
            buf = self._stream_buffers.setdefault(key, bytearray())
            buf += data
        handled = 0
        self.reads += 1
        read = self.reads
        i, n = 0, len(buf)
        decode = self._decoder.decode
        while i < n:
            magic = buf[i]
            if magic == 0xFD:
                if n - i < 3:
                    break
                length = 12 + buf[i + 1] + (13 if buf[i + 2] & 1 else 0)
            elif magic == 0xFE:
                if n - i < 2:
                    break
                length = 8 + buf[i + 1]
            else:
                j = n
                for marker in (0xFD, 0xFE):
                    k = buf.find(marker, i + 1)
                    if k != -1 and k < j:
                        j = k
                self.counters.add("rx_garbage_bytes", j - i)
                i = j
                continue
            if n - i < length:
                break
            frame = buf[i:i + length]
            try:
                msg = decode(frame)
            except Exception:  # bad CRC, bad length, bad signature: resynchronise one byte later
                self.counters.add("rx_bad_frames")
                i += 1
                continue
            if isinstance(msg, mavlink.MAVLink_unknown):
                self.counters.add("rx_unknown_messages")  # CRC cannot be checked: skip one byte, resynchronise
                i += 1
                continue
            i += length
            handled += 1
            if self.gate is None:
                self.handle_frame(link, peer, msg, bytes(frame))
            else:   # lockstep: handled in order at the boundaries
                self.pending.append((link, peer, msg, bytes(frame), read))
        if is_datagram:
            if i < n:
                self.counters.add("rx_truncated_bytes", n - i)
        else:
            del buf[:i]
            if len(buf) > MAX_STREAM_BUFFER_BYTES:
                self.counters.add("rx_garbage_bytes", len(buf))
                buf.clear()
        return handled

    def handle_frame(self, link: Link, peer, msg, frame: bytes) -> None:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src == (self.sysid, self.compid):
            self.counters.add("rx_own_echo")
            return
        # a reply (COMMAND_ACK, PARAM_VALUE, mission protocol) leaves at the end of this instant,
        # not in a later coalesced datagram of a free run
        self.out.urgent = True
        name = msg.get_type()
        self.counters.add("rx_messages")
        self.rx_by_type[name] = self.rx_by_type.get(name, 0) + 1
        if self.tlog is not None:
            self.tlog.write(self.out.start_unix_us + self.clock.t_us, frame)
        target_sys = getattr(msg, "target_system", None)
        target_comp = getattr(msg, "target_component", None)
        for_us = (target_sys in (None, 0, self.sysid)) and (target_comp in (None, 0, self.compid))
        if self.routing and (target_sys != self.sysid or target_comp not in (self.compid,)) and \
                (len(self.links) > 1 or link.peer_count() > 1):
            self.out.send_coalesced()   # a forwarded frame does not overtake ours sent before it
            # counted before it leaves: whoever receives the frame then finds it counted (a test
            # that read the counter on receipt raced the count, under load)
            self.counters.add("rx_routed")
            for other in self.links:
                other.send(frame, exclude=peer if other is link else None)
        if self.gate is not None and self.gate.eligible(*src):
            stamp = getattr(msg, "time_boot_ms", None)
            self.gate.observe(stamp if isinstance(stamp, int) else None, self.clock.boot_us)
        if name == "HEARTBEAT":
            if src not in self.peers:
                self.out.say(None, SEVERITY_INFO, f"Peer {src[0]}/{src[1]} type {msg.type} connected")
            self.peers[src] = msg.type
            return
        if not for_us:
            self.counters.add("rx_not_for_us")
            return
        handler = self.handlers.get(name)
        if handler is None:
            self.counters.add("rx_unhandled")
            return
        self.out.reply_link = link     # a reply (Outbox.emit_reply) goes back on this link only
        try:
            handler(msg)
        except Exception as err:  # never let a message kill the simulator
            self.counters.add("rx_handler_errors")
            self.out.say("handler_error", SEVERITY_WARNING, f"SITL: {msg.get_type()} failed: {type(err).__name__}")
            if os.environ.get("FCMPC_SITL_DEBUG"):
                raise
        finally:
            self.out.reply_link = None
