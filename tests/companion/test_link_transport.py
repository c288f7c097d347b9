"""The UDP transport's batching, over real loopback sockets: the frames of one pass of the
companion's loop leave packed, whole and in order, into datagrams a MAVLink receiver parses as a
byte stream; outside a batch each frame is its own datagram. A port in use is refused, not shared."""
from __future__ import annotations

import errno
import os
import socket

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.io.link.transport import BATCH_DATAGRAM_BYTES, StreamTransport, UdpTransport  # noqa: E402
from tests.ports import free_port  # noqa: E402


def _receiver() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(5.0)
    return sock


def _datagrams(sock: socket.socket) -> list[bytes]:
    """Every datagram queued on ``sock`` (it waits for the first, then takes what is there)."""
    out = [sock.recv(65535)]
    sock.setblocking(False)
    try:
        while True:
            out.append(sock.recv(65535))
    except BlockingIOError:
        pass
    finally:
        sock.settimeout(5.0)
    return out


@pytest.fixture
def pair():
    """A sending transport (``udpout``-like) and the loopback socket it sends to."""
    rx = _receiver()
    tx = UdpTransport("127.0.0.1", rx.getsockname()[1], listen=False)
    yield tx, rx
    tx.close()
    rx.close()


def _frames(count: int) -> list[bytes]:
    mav = mavlink.MAVLink(None, 1, 191)
    return [mavlink.MAVLink_named_value_float_message(k, b"FC_STATE", float(k)).pack(mav) for k in range(count)]


def test_a_batch_leaves_as_one_datagram_of_whole_frames_in_order(pair):
    tx, rx = pair
    frames = _frames(5)
    tx.begin_batch()
    for frame in frames:
        tx.write(frame)
    rx.setblocking(False)
    try:
        assert rx.recv(65535) is None, "sent before the batch ended"
    except BlockingIOError:
        pass
    rx.settimeout(5.0)
    tx.end_batch()
    [datagram] = _datagrams(rx)
    assert datagram == b"".join(frames)
    parsed = mavlink.MAVLink(None).parse_buffer(datagram)
    assert [m.time_boot_ms for m in parsed] == list(range(5))


def test_a_large_batch_is_split_at_frame_boundaries_under_the_datagram_limit(pair):
    tx, rx = pair
    frames = _frames(200)        # 200 x 30 bytes: several datagrams' worth
    tx.begin_batch()
    for frame in frames:
        tx.write(frame)
    tx.end_batch()
    datagrams = _datagrams(rx)
    assert len(datagrams) > 1 and all(len(d) <= BATCH_DATAGRAM_BYTES for d in datagrams)
    parser = mavlink.MAVLink(None)
    parsed = [m for d in datagrams for m in parser.parse_buffer(d) or []]
    assert [m.time_boot_ms for m in parsed] == list(range(200))   # no frame split, lost or reordered


def test_outside_a_batch_each_frame_is_its_own_datagram(pair):
    tx, rx = pair
    frames = _frames(3)
    for frame in frames:
        tx.write(frame)
    got = []
    while len(got) < 3:
        got += _datagrams(rx)
    assert got == frames


def test_a_batch_on_a_tcp_link_leaves_in_one_write_in_order():
    """Against a lockstep simulator on TCP (ArduPilot's JSON relay) a pass of the loop is one write."""
    server = socket.create_server(("127.0.0.1", 0))
    tx = StreamTransport(f"tcp:127.0.0.1:{server.getsockname()[1]}", 115200, 1, 191)
    peer, _ = server.accept()
    try:
        frames = _frames(5)
        tx.begin_batch()
        for frame in frames:
            tx.write(frame)
        peer.setblocking(False)
        with pytest.raises(BlockingIOError):
            peer.recv(65535)            # nothing written before the batch ended
        tx.end_batch()
        peer.settimeout(5.0)
        got = b""
        while len(got) < len(b"".join(frames)):
            got += peer.recv(65535)
        assert got == b"".join(frames)
    finally:
        tx.close()
        peer.close()
        server.close()


def test_a_port_in_use_is_refused_not_shared():
    """Another socket holds the port (pymavlink's udpin sets SO_REUSEADDR): listening there is
    EADDRINUSE; with SO_REUSEADDR on both, Linux let the bind succeed and the newer socket took
    every datagram sent to the port."""
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    holder.bind(("127.0.0.1", free_port()))
    try:
        with pytest.raises(OSError) as err:
            UdpTransport("127.0.0.1", holder.getsockname()[1], listen=True)
        assert err.value.errno == errno.EADDRINUSE
    finally:
        holder.close()
