"""Per-sender parsing, the bounded peer table, the pinned flight controller and where outputs go,
over real UDP sockets on loopback (issue 10, items 2-4)."""
from __future__ import annotations

import os
import socket
import time

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from companion.io.link import MavlinkLink, mavlink
from tests.ports import free_port

AUTOPILOT = dict(type=11, autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base_mode=0, custom_mode=4, system_status=3)


def _encoder(sysid: int, compid: int) -> mavlink.MAVLink:
    return mavlink.MAVLink(None, sysid, compid)


def _frame(enc, name: str, **fields) -> bytes:
    return getattr(mavlink, f"MAVLink_{name.lower()}_message")(**fields).pack(enc)


class Sender:
    """A raw UDP socket with its own source port, sending frames or garbage to the link."""

    def __init__(self, port: int, sysid: int = 1, compid: int = 1) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.target = ("127.0.0.1", port)
        self.enc = _encoder(sysid, compid)

    def send(self, name: str, **fields) -> None:
        self.sock.sendto(_frame(self.enc, name, **fields), self.target)

    def raw(self, data: bytes) -> None:
        self.sock.sendto(data, self.target)

    def received(self, quiet_s: float = 0.3) -> list:
        parser = _encoder(0, 0)
        out, deadline = [], time.monotonic() + quiet_s
        while time.monotonic() < deadline:
            try:
                data = self.sock.recv(65535)
            except TimeoutError:
                continue
            out.extend(parser.parse_buffer(data) or [])
        return out

    def close(self) -> None:
        self.sock.close()


def _pump(link: MavlinkLink, until, timeout_s: float = 5.0) -> list:
    """Read the link until ``until(messages so far)`` holds (waits on the socket, never sleeps)."""
    got, deadline = [], time.monotonic() + timeout_s
    while time.monotonic() < deadline and not until(got):
        if link.wait_readable(0.05):
            for msg in link.read():
                link.observe(msg)
                got.append(msg)
    return got


@pytest.fixture
def link():
    port = free_port()
    lk = MavlinkLink(f"udpin:127.0.0.1:{port}", peer_capacity=16)
    lk.open()
    lk.port = port
    yield lk
    lk.close()


def test_garbage_from_one_sender_never_swallows_anothers_frames(link):
    """The issue's ``fd ff``: before each genuine frame a stranger sends the start of a frame that
    claims 255 bytes; with one shared parser the next frames vanish into it, here none does."""
    fc, stranger = Sender(link.port), Sender(link.port, 200, 1)
    try:
        fc.send("HEARTBEAT", **AUTOPILOT, mavlink_version=3)
        for k in range(16):
            stranger.raw(b"\xfd\xff")
            fc.send("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=1000 + 100 * k)
        got = _pump(link, lambda g: sum(m.get_type() == "SYSTEM_TIME" for m in g) >= 16)
        assert sum(m.get_type() == "SYSTEM_TIME" for m in got) == 16
        assert link.clock.now_s == pytest.approx(2.5)
        # the same sender's own garbage spoils nothing after its datagram: frames never span datagrams
        fc.raw(b"\xfd\xff")
        fc.send("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=2600)
        got = _pump(link, lambda g: any(m.get_type() == "SYSTEM_TIME" for m in g))
        assert [m.time_boot_ms for m in got if m.get_type() == "SYSTEM_TIME"] == [2600]
        assert link.stats.leftover_bytes >= 2 * 17
    finally:
        fc.close()
        stranger.close()


def test_outputs_reach_the_fc_and_allowed_gcs_never_a_stranger(link):
    fc, gcs, stranger = Sender(link.port), Sender(link.port, 255, 190), Sender(link.port, 200, 1)
    try:
        fc.send("HEARTBEAT", **AUTOPILOT, mavlink_version=3)
        gcs.send("HEARTBEAT", type=6, autopilot=8, base_mode=0, custom_mode=0, system_status=4, mavlink_version=3)
        stranger.send("HEARTBEAT", type=6, autopilot=8, base_mode=0, custom_mode=0, system_status=4, mavlink_version=3)
        _pump(link, lambda g: len(g) >= 3)
        assert link.fc.detected and link.fc.sysid == 1
        link.send_heartbeat()
        link.send_statustext("hello")
        assert {m.get_type() for m in fc.received()} == {"HEARTBEAT", "STATUSTEXT"}
        assert {m.get_type() for m in gcs.received()} == {"HEARTBEAT", "STATUSTEXT"}
        assert stranger.received() == []
    finally:
        for s in (fc, gcs, stranger):
            s.close()


def test_peer_table_is_bounded_and_keeps_the_fc(link):
    fc = Sender(link.port)
    strangers = []
    try:
        fc.send("HEARTBEAT", **AUTOPILOT, mavlink_version=3)
        _pump(link, lambda g: len(g) >= 1)
        for k in range(100):   # a hundred fake source ports, each with a heartbeat
            s = Sender(link.port, 100 + k, 1)
            s.send("HEARTBEAT", type=6, autopilot=8, base_mode=0, custom_mode=0, system_status=4, mavlink_version=3)
            strangers.append(s)
        fc.send("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=5000)
        _pump(link, lambda g: any(m.get_type() == "SYSTEM_TIME" for m in g) and len(g) >= 101)
        assert len(link.peers.peers) <= link.peers.capacity == 16
        assert link.peers.evicted >= 100 - 16
        assert link.peers.fc_address in link.peers.peers and link.clock.now_s == 5.0
        link.send_heartbeat()
        assert any(m.get_type() == "HEARTBEAT" for m in fc.received())
        assert all(s.received(0.0) == [] for s in strangers[:5])
    finally:
        fc.close()
        for s in strangers:
            s.close()


def test_fc_pinned_second_autopilot_reported_impostor_dropped(link):
    fc, other, impostor = Sender(link.port), Sender(link.port, 2, 1), Sender(link.port, 1, 1)
    try:
        fc.send("HEARTBEAT", **AUTOPILOT, mavlink_version=3)
        fc.send("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=10_000)
        _pump(link, lambda g: len(g) >= 2)
        other.send("HEARTBEAT", **{**AUTOPILOT, "custom_mode": 15}, mavlink_version=3)
        impostor.send("HEARTBEAT", **{**AUTOPILOT, "custom_mode": 15}, mavlink_version=3)   # FC's ids, other port
        impostor.send("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=15_000)
        fc.send("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=10_100)
        _pump(link, lambda g: any(getattr(m, "time_boot_ms", 0) == 10_100 for m in g))
        assert (link.fc.sysid, link.fc.custom_mode) == (1, 4)             # neither followed
        assert link.clock.now_s == pytest.approx(10.1)                    # the impostor's time never counted
        assert link.peers.impostor_frames == 2
        assert link.new_autopilots() == [(2, 1)] and link.new_autopilots() == []
    finally:
        for s in (fc, other, impostor):
            s.close()


class _Wall:
    """An injected wall clock: moved by hand, or by ``tick`` seconds at every reading."""

    def __init__(self) -> None:
        self.t, self.tick = 0.0, 0.0

    def __call__(self) -> float:
        self.t += self.tick
        return self.t


def test_the_fc_is_re_pinned_only_after_silence_the_companion_listened_to():
    """The FC's frames queued behind an impostor's heartbeat while the companion was blocked for
    10 s (longer than REPIN_WALL_S) do not let the impostor take the link; 6 s of listening to a
    silent FC do (a router or a restarted simulator on a new port)."""
    wall, port = _Wall(), free_port()
    link = MavlinkLink(f"udpin:127.0.0.1:{port}", wall_clock=wall)
    link.open()
    fc, newport = Sender(port), Sender(port)
    try:
        fc.send("HEARTBEAT", **AUTOPILOT, mavlink_version=3)
        _pump(link, lambda g: len(g) >= 1)
        wall.t += 10.0                                                   # the companion is blocked
        newport.send("HEARTBEAT", **{**AUTOPILOT, "custom_mode": 15}, mavlink_version=3)
        fc.send("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=10_100)
        _pump(link, lambda g: any(getattr(m, "time_boot_ms", 0) == 10_100 for m in g))
        assert link.peers.fc_address == fc.sock.getsockname() and link.peers.impostor_frames == 1
        wall.tick = 1.0                                                  # listening to a silent FC
        while link.listened_s < 6.0:
            assert not link.wait_readable(0.0)
        newport.send("HEARTBEAT", **{**AUTOPILOT, "custom_mode": 15}, mavlink_version=3)
        _pump(link, lambda g: len(g) >= 1)
        assert link.peers.fc_address == newport.sock.getsockname() and link.peers.impostor_frames == 1
    finally:
        link.close()
        fc.close()
        newport.close()


def test_fc_sysid_given_on_the_command_line_is_the_only_one_followed():
    port = free_port()
    link = MavlinkLink(f"udpin:127.0.0.1:{port}", sysid=3, fc_compid=1)
    link.open()
    first, wanted = Sender(port, 1, 1), Sender(port, 3, 1)
    try:
        first.send("HEARTBEAT", **AUTOPILOT, mavlink_version=3)
        wanted.send("HEARTBEAT", **AUTOPILOT, mavlink_version=3)
        _pump(link, lambda g: len(g) >= 2)
        assert link.fc.sysid == 3 and link.peers.fc_ids == (3, 1)
    finally:
        link.close()
        first.close()
        wanted.close()


def test_speed_ceiling_caps_setpoints_whatever_the_caller_says():
    port = free_port()
    receiver = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    link = MavlinkLink(f"udpout:127.0.0.1:{port}", speed_ceiling_mps=10.0)
    link.open()
    try:
        assert not link.send_setpoint(0.0, 83.0, 83.4)        # the NAV_SPEED_KMH 300 limit
        assert "above the limit 10.000" in link.stats.last_refusal
        assert link.send_setpoint(0.0, 9.0, 83.4)
        got = receiver.recv_match(type="SET_POSITION_TARGET_GLOBAL_INT", blocking=True, timeout=3.0)
        assert got is not None and got.vx == pytest.approx(9.0)
    finally:
        link.close()
        receiver.close()


def test_a_flood_from_strangers_is_shed_never_the_fcs_frames():
    """Strangers share a budget of datagrams per wall second (here 10, a frozen clock); beyond it
    their datagrams are dropped unparsed, while every one of the FC's is parsed."""
    wall = [0.0]
    link = MavlinkLink("udpout:127.0.0.1:9", wall_clock=lambda: wall[0], stranger_rate_hz=10.0)
    link.open()
    enc = _encoder(1, 1)
    fc = ("127.0.0.1", 5760)
    try:
        for msg in link.feed(fc, _frame(enc, "HEARTBEAT", **AUTOPILOT, mavlink_version=3)):
            link.observe(msg)
        stranger = _encoder(200, 1)
        hb = _frame(stranger, "HEARTBEAT", type=6, autopilot=8, base_mode=0, custom_mode=0, system_status=4,
                    mavlink_version=3)
        parsed = sum(len(link.feed(("127.0.0.1", 3000 + k), hb)) for k in range(500))
        ticks = [link.feed(fc, _frame(enc, "SYSTEM_TIME", time_unix_usec=0, time_boot_ms=1000 + k)) for k in range(50)]
        assert all(len(t) == 1 for t in ticks)
        # the burst of 200, less the token the FC's first heartbeat took before it was pinned; then nothing
        assert parsed == 199 and link.peers.shed == 301
        wall[0] += 1.0
        assert sum(len(link.feed(("127.0.0.1", 4000 + k), hb)) for k in range(50)) == 10   # 10 per second
    finally:
        link.close()
