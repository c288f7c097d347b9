"""Property-based fuzz of the link layer (hypothesis): whatever any sender sends, the link never
raises, the pinned flight controller's genuine frames always get through, a stranger never
reaches the outputs or the parameters, and the message clock never goes back without a
confirmed reboot (issue 10). The link is driven through :meth:`MavlinkLink.feed`, the same path
:meth:`MavlinkLink.read` takes with each datagram and its sender's address."""
from __future__ import annotations

import math
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

os.environ.setdefault("MAVLINK20", "1")

from companion.io.link import MavlinkLink, mavlink
from companion.io.link.signing import Signing, passphrase_key
from companion.io.param_server import ParamServer
from companion.params import default_values
from fcmpc.soak.hostile import Hostile

FC = ("127.0.0.1", 5760)
SLOW = settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
KEY = passphrase_key("fuzz")


def _frame(name: str, sysid: int = 1, compid: int = 1, **fields) -> bytes:
    return getattr(mavlink, f"MAVLink_{name.lower()}_message")(**fields).pack(mavlink.MAVLink(None, sysid, compid))


HEARTBEAT = _frame("HEARTBEAT", type=11, autopilot=3, base_mode=0, custom_mode=4, system_status=3, mavlink_version=3)

addresses = st.tuples(st.just("127.0.0.1"), st.integers(1024, 1100))
garbage = st.binary(min_size=0, max_size=300)
hostile_seeds = st.integers(0, 2**32 - 1)


def _link(signing: bool = False) -> tuple[MavlinkLink, ParamServer]:
    link = MavlinkLink("udpout:127.0.0.1:9", peer_capacity=8, signing=Signing(KEY) if signing else None,
                       stranger_rate_hz=math.inf)   # every datagram parsed: the parser is what is fuzzed here
    link.open()   # outputs go to the discard port; nothing listens
    server = ParamServer(link, None)
    server.load()
    for msg in link.feed(FC, HEARTBEAT):
        link.observe(msg)
    return link, server


def _deliver(link: MavlinkLink, server: ParamServer, address, data: bytes) -> list:
    out = []
    for msg in link.feed(address, data):
        if link.observe(msg):
            out.append(msg)
        else:
            server.mavlink_packet(msg)
    return out


def _attack(link, server, datagrams, ticks: int = 0) -> None:
    """Interleave the attack with the FC's clock ticking; every tick must get through."""
    t_ms = 10_000
    for k, (address, data) in enumerate(datagrams):
        _deliver(link, server, address, data)
        if k % 3 == 0:
            t_ms += 100
            got = _deliver(link, server, FC, _frame("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=t_ms))
            assert [m.time_boot_ms for m in got] == [t_ms]      # a genuine frame is never swallowed
            assert link.clock.now_s == pytest.approx(t_ms / 1000.0)


@FAST
@given(st.lists(st.tuples(addresses, garbage), max_size=40))
def test_random_bytes_from_anyone_never_hurt_the_fc_stream(datagrams):
    link, server = _link()
    try:
        _attack(link, server, datagrams)
        assert len(link.peers.peers) <= link.peers.capacity
        assert link.peers.destinations() == [FC]
        assert server.values == default_values() and link.fc.sysid == 1 and link.clock.reboots == 0
    finally:
        link.close()


@FAST
@given(hostile_seeds, st.integers(1, 60))
def test_the_soak_classes_never_reboot_redirect_or_reparametrise(seed, count):
    _hostile_run(seed, count, signing=False)


@FAST
@given(hostile_seeds, st.integers(1, 60))
def test_with_signing_no_unsigned_write_lands(seed, count):
    _hostile_run(seed, count, signing=True)


def _hostile_run(seed: int, count: int, signing: bool) -> None:
    link, server = _link(signing)
    source = iter(Hostile(seed, signing=signing))
    try:
        datagrams = [(("127.0.0.1", 2000 + k % 50), next(source)[1]) for k in range(count)]
        _attack(link, server, datagrams)
        assert server.values == default_values()
        assert link.clock.reboots == 0 and link.clock.jumps == 0
        assert (link.fc.sysid, link.fc.custom_mode) == (1, 4)
        assert link.send_setpoint(0.0, 1e3, 1e6) is False     # the speed ceiling holds whatever is asked
    finally:
        link.close()


@FAST
@given(st.lists(st.integers(-(2**31), 2**32 - 1), min_size=1, max_size=30))
def test_one_forged_stamp_at_a_time_never_moves_the_clock_back(stamps_ms):
    """Stamps from the FC's own address (the worst case: a spoofer on its wire), each followed by a
    genuine tick: the clock stays on the genuine base, monotonic, and no reboot is believed."""
    link, server = _link()
    try:
        t_ms, last = 50_000, -math.inf
        for stamp in stamps_ms:
            forged = _frame("ATTITUDE", time_boot_ms=stamp % 2**32, roll=0, pitch=0, yaw=0, rollspeed=0,
                            pitchspeed=0, yawspeed=0)
            _deliver(link, server, FC, forged)
            t_ms += 100
            _deliver(link, server, FC, _frame("SYSTEM_TIME", time_unix_usec=0, time_boot_ms=t_ms))
            assert link.clock.now_s >= last
            last = link.clock.now_s
        assert link.clock.reboots == 0 and link.clock.jumps == 0
    finally:
        link.close()


@pytest.mark.slow
@SLOW
@given(hostile_seeds, st.integers(100, 400))
def test_long_hostile_runs(seed, count):
    _hostile_run(seed, count, signing=seed % 2 == 1)
