"""Sockets of the simulator: UDP out (like ArduPilot SITL's ``--out``), UDP in, TCP server.

Endpoint strings (``--out`` / ``--master``):

``udp:HOST:PORT`` or ``udpout:HOST:PORT``
    send to HOST:PORT from an ephemeral port (a ground station or companion listens there,
    pymavlink ``udpin:0.0.0.0:PORT``, MAVSDK ``udpin://0.0.0.0:PORT``); whatever is sent
    back to that ephemeral port is received.
``udpin:HOST:PORT``
    listen on HOST:PORT; send to every address heard from (a client connects with
    pymavlink ``udpout:HOST:PORT``, which must send first).
``tcp:HOST:PORT`` or ``tcpin:HOST:PORT``
    listen for TCP clients, like ArduPilot SITL's SERIAL0 on 5760 (pymavlink
    ``tcp:HOST:PORT``, MAVProxy ``--master tcp:HOST:PORT``).

All sockets are non-blocking. A frame that cannot be written (full socket buffer, TCP
client backlog above ``TCP_BACKLOG_BYTES``) is dropped and counted, as a serial link
with a full buffer would drop it; the simulator never blocks on a slow client.
"""
from __future__ import annotations

import errno
import selectors
import socket
from dataclasses import dataclass

__all__ = ["Endpoint", "parse_endpoint", "Link", "UdpOutLink", "UdpInLink", "TcpServerLink", "open_link",
           "MAX_DATAGRAM_BYTES", "TCP_BACKLOG_BYTES", "bound_udp_ports"]

MAX_DATAGRAM_BYTES = 1400          # below the Ethernet MTU and MAVSDK's 2048-byte receive buffer
TCP_BACKLOG_BYTES = 1 << 20
SOCKET_BUFFER_BYTES = 4 << 20
MAX_UDP_PEERS = 8


def bound_udp_ports() -> set[int]:
    """The local ports of every UDP socket bound on this machine (Linux's /proc/net/udp and udp6; empty
    where there are none). A killed process's sockets are closed at once, before it is reaped.

    >>> sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); sock.bind(("127.0.0.1", 0))
    >>> sock.getsockname()[1] in bound_udp_ports(); sock.close()
    True
    """
    ports: set[int] = set()
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(table) as handle:
                rows = handle.read().splitlines()[1:]
        except OSError:
            continue
        ports.update(int(r.split()[1].rsplit(":", 1)[1], 16) for r in rows)
    return ports


class EndpointError(ValueError):
    """An endpoint string that cannot be used."""


@dataclass(frozen=True)
class Endpoint:
    kind: str      # "udpout" | "udpin" | "tcpin"
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.kind}:{self.host}:{self.port}"


_KINDS = {"udp": "udpout", "udpout": "udpout", "udpin": "udpin", "tcp": "tcpin", "tcpin": "tcpin"}


def parse_endpoint(text: str) -> Endpoint:
    """``udp:127.0.0.1:14550`` -> Endpoint("udpout", "127.0.0.1", 14550).

    >>> parse_endpoint("tcp:0.0.0.0:5760")
    Endpoint(kind='tcpin', host='0.0.0.0', port=5760)
    """
    parts = text.strip().split(":")
    if len(parts) == 2:  # "udp:14550" -> localhost
        parts = [parts[0], "127.0.0.1", parts[1]]
    if len(parts) != 3 or parts[0].lower() not in _KINDS:
        raise EndpointError(f"endpoint {text!r}: expected udp:HOST:PORT, udpin:HOST:PORT or tcp:HOST:PORT")
    try:
        port = int(parts[2])
    except ValueError:
        raise EndpointError(f"endpoint {text!r}: port {parts[2]!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise EndpointError(f"endpoint {text!r}: port out of range")
    return Endpoint(_KINDS[parts[0].lower()], parts[1] or "127.0.0.1", port)


class Link:
    """One endpoint. ``peers`` are opaque keys; ``recv`` returns ``[(peer, bytes, is_datagram)]``."""

    def __init__(self, endpoint: Endpoint, index: int) -> None:
        self.endpoint = endpoint
        self.index = index
        self.tx_dropped = 0
        self.tx_bytes = 0
        self.rx_bytes = 0

    def register(self, selector: selectors.BaseSelector) -> None:
        raise NotImplementedError

    def on_readable(self, sock: socket.socket, selector: selectors.BaseSelector) -> list[tuple[object, bytes, bool]]:
        raise NotImplementedError

    def send(self, data: bytes, exclude: object = None) -> None:
        raise NotImplementedError

    def flush(self) -> None:
        """Retry pending output (TCP)."""

    def peer_count(self) -> int:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    @property
    def local_address(self) -> tuple[str, int]:
        raise NotImplementedError


def _udp_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for opt in (socket.SO_SNDBUF, socket.SO_RCVBUF):
        try:
            sock.setsockopt(socket.SOL_SOCKET, opt, SOCKET_BUFFER_BYTES)
        except OSError:  # pragma: no cover - platform limit
            pass
    sock.setblocking(False)
    return sock


def _read_datagrams(sock: socket.socket, link: Link) -> list[tuple[object, bytes, bool]]:
    out = []
    for _ in range(256):  # bounded: a flood cannot starve the simulation
        try:
            data, addr = sock.recvfrom(65535)
        except (BlockingIOError, InterruptedError):
            break
        except OSError:  # ICMP port unreachable of an earlier send, etc.
            break
        link.rx_bytes += len(data)
        out.append((addr, data, True))
    return out


class UdpOutLink(Link):
    """Sends to a fixed address; receives whatever comes back to its ephemeral port."""

    def __init__(self, endpoint: Endpoint, index: int) -> None:
        super().__init__(endpoint, index)
        self.sock = _udp_socket()
        self.sock.bind(("0.0.0.0" if endpoint.host not in ("127.0.0.1", "localhost") else "127.0.0.1", 0))
        self.destination = (socket.gethostbyname(endpoint.host), endpoint.port)

    def register(self, selector: selectors.BaseSelector) -> None:
        selector.register(self.sock, selectors.EVENT_READ, self)

    def on_readable(self, sock, selector):
        return _read_datagrams(self.sock, self)

    def send(self, data: bytes, exclude: object = None) -> None:
        if exclude == self.destination:
            return
        try:
            self.sock.sendto(data, self.destination)
            self.tx_bytes += len(data)
        except (BlockingIOError, InterruptedError):
            self.tx_dropped += 1
        except OSError:  # nobody listening (ECONNREFUSED from an ICMP), network down
            self.tx_dropped += 1

    def peer_count(self) -> int:
        return 1

    def close(self) -> None:
        self.sock.close()

    @property
    def local_address(self):
        return self.sock.getsockname()


class UdpInLink(Link):
    """Listens on a port; sends to every address it has heard from (at most 8, newest kept)."""

    def __init__(self, endpoint: Endpoint, index: int) -> None:
        super().__init__(endpoint, index)
        self.sock = _udp_socket()
        # no SO_REUSEADDR: UDP has no TIME_WAIT to wait out, and with it Linux lets a second socket
        # bind a port in use (the newer one silently takes its datagrams): a port in use is EADDRINUSE
        self.sock.bind((endpoint.host, endpoint.port))
        self.peers: list[tuple[str, int]] = []

    def register(self, selector):
        selector.register(self.sock, selectors.EVENT_READ, self)

    def on_readable(self, sock, selector):
        out = _read_datagrams(self.sock, self)
        for addr, _, _ in out:
            if addr not in self.peers:
                self.peers.append(addr)
                del self.peers[:-MAX_UDP_PEERS]
        return out

    def send(self, data: bytes, exclude: object = None) -> None:
        for addr in self.peers:
            if addr == exclude:
                continue
            try:
                self.sock.sendto(data, addr)
                self.tx_bytes += len(data)
            except OSError:
                self.tx_dropped += 1

    def peer_count(self) -> int:
        return len(self.peers)

    def close(self) -> None:
        self.sock.close()

    @property
    def local_address(self):
        return self.sock.getsockname()


class TcpServerLink(Link):
    """A TCP server; each client gets every frame (backlog bounded, excess dropped)."""

    def __init__(self, endpoint: Endpoint, index: int) -> None:
        super().__init__(endpoint, index)
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.server.bind((endpoint.host, endpoint.port))
        self.server.listen(8)
        self.server.setblocking(False)
        self.clients: dict[socket.socket, bytearray] = {}
        self._selector: selectors.BaseSelector | None = None

    def register(self, selector):
        self._selector = selector
        selector.register(self.server, selectors.EVENT_READ, self)

    def _drop_client(self, sock: socket.socket) -> None:
        self.clients.pop(sock, None)
        if self._selector is not None:
            try:
                self._selector.unregister(sock)
            except (KeyError, ValueError):
                pass
        sock.close()

    def on_readable(self, sock, selector):
        if sock is self.server:
            try:
                client, _ = self.server.accept()
            except OSError:
                return []
            client.setblocking(False)
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.clients[client] = bytearray()
            selector.register(client, selectors.EVENT_READ, self)
            return []
        try:
            data = sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return []
        except OSError:
            data = b""
        if not data:
            self._drop_client(sock)
            return [(("tcp", id(sock)), b"", False)]
        self.rx_bytes += len(data)
        return [(("tcp", id(sock)), data, False)]

    def _write(self, sock: socket.socket, backlog: bytearray) -> None:
        try:
            sent = sock.send(backlog)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._drop_client(sock)
            return
        self.tx_bytes += sent
        del backlog[:sent]

    def send(self, data: bytes, exclude: object = None) -> None:
        for sock, backlog in list(self.clients.items()):
            if ("tcp", id(sock)) == exclude:
                continue
            if len(backlog) + len(data) > TCP_BACKLOG_BYTES:
                self.tx_dropped += 1
                continue
            backlog += data
            self._write(sock, backlog)

    def flush(self) -> None:
        for sock, backlog in list(self.clients.items()):
            if backlog:
                self._write(sock, backlog)

    def peer_count(self) -> int:
        return len(self.clients)

    def close(self) -> None:
        for sock in list(self.clients):
            self._drop_client(sock)
        self.server.close()

    @property
    def local_address(self):
        return self.server.getsockname()


def open_link(endpoint: Endpoint, index: int) -> Link:
    """Open the socket(s) of an endpoint; OSError (e.g. EADDRINUSE) propagates with the endpoint named."""
    cls = {"udpout": UdpOutLink, "udpin": UdpInLink, "tcpin": TcpServerLink}[endpoint.kind]
    try:
        return cls(endpoint, index)
    except OSError as err:
        raise OSError(err.errno or errno.EIO, f"cannot open {endpoint}: {err.strerror or err}") from err
