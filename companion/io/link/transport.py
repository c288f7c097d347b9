"""Byte transports of the link: UDP with sender addresses, or one pymavlink stream (serial, TCP).

A transport answers three questions: what can be read now, *from whom* (an address per chunk),
and where does a written frame go. Between :meth:`UdpTransport.begin_batch` and
:meth:`~UdpTransport.end_batch` the frames written are packed, whole and in order, into datagrams
of up to ``BATCH_DATAGRAM_BYTES``: against a lockstep simulator the companion answers one pass
of its loop (a setpoint, the 10 Hz GPS_INPUT, a heartbeat) in one datagram instead of one each
(one ``sendto`` per frame was a sixth of the companion's time in a lockstep mission). MAVLink
receivers parse a datagram as a byte stream, but the companion does not batch to a flight
controller (see :meth:`companion.process.companion.CompanionApp.spin`). :class:`UdpTransport` owns its socket instead of pymavlink's
``udpin``/``udpout`` connections, whose listener sends every output to every sender it ever
heard; here ``write`` goes to the addresses the link's peer table names (the flight controller
and allowed ground stations), or, for ``udpout:``, to the one address given. Serial and TCP links
have a single peer, the other end of the wire: :class:`StreamTransport` wraps pymavlink's
connection and reports every chunk from the address ``"stream"``.
"""
from __future__ import annotations

import errno
import socket
from collections.abc import Callable, Hashable

__all__ = ["STREAM", "StreamTransport", "UdpTransport", "open_transport", "parse_connection"]

STREAM = "stream"           # the one address of a serial or TCP link
MAX_DATAGRAMS = 64          # per receive(): bounded work per call, the rest stays in the socket
RCVBUF_BYTES = 4 << 20
BATCH_DATAGRAM_BYTES = 1000  # frames packed into one datagram while batching (PX4 on NuttX reads 1000)


def parse_connection(text: str) -> tuple[str, int]:
    """(pymavlink device, baud) of a connection string; serial as ``DEVICE,BAUD`` or ``DEVICE:BAUD``.

    >>> parse_connection("/dev/ttyAMA0,921600"), parse_connection("udp:127.0.0.1:14550")
    (('/dev/ttyAMA0', 921600), ('udp:127.0.0.1:14550', 115200))
    """
    text = text.strip()
    for sep in (",", ":"):
        if (text.startswith(("/", "COM", "com")) and sep in text):
            device, _, baud = text.rpartition(sep)
            if baud.isdigit():
                return device, int(baud)
    return text, 115200


class UdpTransport:
    """A UDP socket: ``listen`` binds HOST:PORT; otherwise sends to HOST:PORT (and reads replies)."""

    def __init__(self, host: str, port: int, listen: bool,
                 destinations: Callable[[], list[Hashable]] | None = None) -> None:
        # no SO_REUSEADDR: UDP has no TIME_WAIT to wait out, and with it Linux lets another socket
        # bind (or pick as its port 0) a port this one holds, then takes its datagrams: a port in
        # use must be EADDRINUSE, not a silently shared port
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
        except OSError:  # pragma: no cover - platform limits
            pass
        self.listen = listen
        self.remote = (socket.gethostbyname(host), port)
        if listen:
            self.sock.bind(self.remote)
        self.sock.setblocking(False)
        self.destinations = destinations or (list)
        self.send_errors = 0
        self.mav = None    # the link's encoder (fcmpc.bench.companion_process parses through it)
        self._batch: list[bytes] | None = None   # frames written since begin_batch(), not yet sent

    def fileno(self) -> int:
        return self.sock.fileno()

    def receive(self) -> list[tuple[Hashable, bytes]]:
        """Datagrams readable now, each with its sender's address (at most MAX_DATAGRAMS)."""
        out = []
        for _ in range(MAX_DATAGRAMS):
            try:
                data, address = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as err:
                if err.errno in (errno.ECONNREFUSED, errno.ECONNRESET):   # ICMP from an earlier send
                    continue
                break
            out.append((address, data))
        return out

    def write(self, buf: bytes) -> None:
        """One frame: sent now, or kept for :meth:`end_batch` while a batch is open."""
        if self._batch is not None:
            self._batch.append(bytes(buf))
            return
        self._send(buf)

    def begin_batch(self) -> None:
        """Keep the frames written from now on until :meth:`end_batch`."""
        if self._batch is None:
            self._batch = []

    def end_batch(self) -> None:
        """Send the frames kept since :meth:`begin_batch`, whole and in order, packed into datagrams."""
        frames, self._batch = self._batch, None
        if not frames:
            return
        datagram = bytearray()
        for frame in frames:
            if datagram and len(datagram) + len(frame) > BATCH_DATAGRAM_BYTES:
                self._send(bytes(datagram))
                datagram.clear()
            datagram += frame
        self._send(bytes(datagram))

    def _send(self, buf: bytes) -> None:
        targets = self.destinations() if self.listen else [self.remote]
        for address in targets:
            try:
                self.sock.sendto(buf, address)
            except OSError:   # a full buffer or a vanished peer must not stop the companion
                self.send_errors += 1

    def close(self) -> None:
        self.end_batch()
        self.sock.close()


class StreamTransport:
    """A pymavlink serial or TCP connection: one peer, bytes in order."""

    def __init__(self, device: str, baud: int, source_system: int, source_component: int) -> None:
        from pymavlink import mavutil

        self.conn = mavutil.mavlink_connection(device, baud=baud, source_system=source_system,
                                               source_component=source_component, autoreconnect=True)
        self.mav = None
        self._batch: list[bytes] | None = None   # frames written since begin_batch(), not yet sent

    def fileno(self) -> int | None:
        return getattr(self.conn, "fd", None)

    def receive(self) -> list[tuple[Hashable, bytes]]:
        try:
            data = self.conn.recv(1 << 16)
        except (OSError, ConnectionError):
            data = b""
        return [(STREAM, bytes(data))] if data else []

    def write(self, buf: bytes) -> None:
        """One frame: written now, or kept for :meth:`end_batch` while a batch is open."""
        if self._batch is not None:
            self._batch.append(bytes(buf))
            return
        self._write(buf)

    def begin_batch(self) -> None:
        """Keep the frames written from now on until :meth:`end_batch` (a lockstep simulator's TCP link:
        one write a pass of the loop; one a frame was 13 % of the companion's CPU against ArduPilot's
        JSON lockstep relay, where the 10 Hz GPS_INPUT goes out frame by frame)."""
        if self._batch is None:
            self._batch = []

    def end_batch(self) -> None:
        """Write the frames kept since :meth:`begin_batch`, in order, in one go."""
        frames, self._batch = self._batch, None
        if frames:
            self._write(b"".join(frames))

    def _write(self, buf: bytes) -> None:
        try:
            self.conn.write(buf)
        except OSError:  # pragma: no cover - a dropped TCP peer reconnects
            pass

    def close(self) -> None:
        self.end_batch()
        try:
            self.conn.close()
        except OSError:  # pragma: no cover
            pass


def open_transport(connect: str, destinations: Callable[[], list[Hashable]], source_system: int,
                   source_component: int) -> UdpTransport | StreamTransport:
    """The transport of a connection string (``udp:``/``udpin:`` listen, ``udpout:`` send first, else pymavlink)."""
    device, baud = parse_connection(connect)
    kind, _, rest = device.partition(":")
    if kind in ("udp", "udpin", "udpout") and rest:
        host, _, port = rest.rpartition(":")
        if not port.isdigit():
            raise ValueError(f"{connect}: expected {kind}:HOST:PORT")
        return UdpTransport(host or "0.0.0.0", int(port), listen=kind != "udpout", destinations=destinations)
    return StreamTransport(device, baud, source_system, source_component)
