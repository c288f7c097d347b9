"""sitl.fc.outbox: a free run coalesces instants into datagrams of whole frames, the frames unchanged.

A free run (``--speedup 0``) packs consecutive instants into one datagram up to
``MAX_DATAGRAM_BYTES``; a paced run sends one datagram per instant. Reassembled, the two carry
the same bytes, and a STATUSTEXT or a reply never waits in a half-filled datagram.
"""
from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.clock import SimClock
from sitl.fc.config import ServerConfig
from sitl.fc.outbox import Counters, Outbox
from sitl.fc.server import SitlServer
from sitl.links import MAX_DATAGRAM_BYTES
from sitl.mavframe import FrameEncoder
from tests.sitl.conftest import read_tlog
from tests.sitl.fc.helpers import closed_udp_port


class Recorder:
    """A link that keeps every datagram it is given."""

    def __init__(self) -> None:
        self.datagrams: list[bytes] = []

    def send(self, data: bytes, exclude: object = None) -> None:
        self.datagrams.append(bytes(data))

    def flush(self) -> None:
        pass


class NoFaults:
    loss = dup = 0.0
    delay_us = 0


def frames_of(datagram: bytes) -> list[bytes]:
    """The MAVLink 2 frames of a datagram, by their length bytes; fails on a partial frame."""
    out, i = [], 0
    while i < len(datagram):
        assert datagram[i] == 0xFD, f"no frame start at byte {i}"
        n = 12 + datagram[i + 1] + (13 if datagram[i + 2] & 1 else 0)
        assert i + n <= len(datagram), "a frame cut at the end of a datagram"
        out.append(datagram[i:i + n])
        i += n
    return out


def outbox(coalesce: bool) -> tuple[Outbox, Recorder, SimClock]:
    clock, link = SimClock(), Recorder()
    out = Outbox(FrameEncoder(1, 1), clock, Counters(), NoFaults(), np.random.default_rng(0), 0)
    out.links, out.coalesce = [link], coalesce
    return out, link, clock


def fly(out: Outbox, clock: SimClock, instants: int = 60) -> None:
    """Instants of a few stream frames each, a STATUSTEXT at instant 17, a reply at 31, a large burst at 40."""
    for k in range(instants):
        clock.t_us = k * 100_000
        out.emit(mavlink.MAVLink_system_time_message, 1_700_000_000_000_000 + clock.t_us, clock.boot_ms)
        out.emit(mavlink.MAVLink_attitude_message, clock.boot_ms, 0.1, 0.2, 0.3 + k, 0.0, 0.0, 0.0)
        if k == 17:
            out.say(None, 6, "hello")
        if k == 31:
            out.urgent = True           # what the router does when it handles a message
            out.emit(mavlink.MAVLink_command_ack_message, 400, 0, 0, 0, 191, 1)
        if k == 40:                      # more than a datagram in one instant (a parameter list)
            for j in range(60):
                out.emit(mavlink.MAVLink_param_value_message, b"P%d" % j, float(j), 9, 60, j)
        out.flush()
    out.send_coalesced()


def test_coalesced_datagrams_carry_the_same_frames_whole_and_in_order():
    plain, plain_link, plain_clock = outbox(coalesce=False)
    fly(plain, plain_clock)
    merged, link, clock = outbox(coalesce=True)
    fly(merged, clock)
    assert b"".join(link.datagrams) == b"".join(plain_link.datagrams)
    assert len(link.datagrams) < len(plain_link.datagrams) / 3
    assert all(len(d) <= MAX_DATAGRAM_BYTES for d in link.datagrams)
    frames = [frames_of(d) for d in link.datagrams]
    # a STATUSTEXT and a reply end their datagram: sent at the end of their instant, not held
    ends = [mavlink.MAVLink(None).decode(bytearray(f[-1])).get_type() for f in frames]
    assert "STATUSTEXT" in ends and "COMMAND_ACK" in ends
    # an instant that fits a datagram is never split: every datagram starts with a SYSTEM_TIME, except
    # the parameter burst's continuations
    starts = [mavlink.MAVLink(None).decode(bytearray(f[0])).get_type() for f in frames]
    assert set(starts) <= {"SYSTEM_TIME", "PARAM_VALUE"} and 1 <= starts.count("PARAM_VALUE") <= 2


def test_nothing_is_left_behind_at_the_end():
    out, link, clock = outbox(coalesce=True)
    out.emit(mavlink.MAVLink_system_time_message, 1, 2)
    out.flush()
    assert link.datagrams == []
    out.send_coalesced()
    assert len(link.datagrams) == 1 and len(frames_of(link.datagrams[0])) == 1


def run_recorded(tmp_path, name: str, speedup: float) -> tuple[list[bytes], list]:
    """A 30 s run (a fault's STATUSTEXT at 10 s); its datagrams (as sent to the link) and its tlog."""
    server = SitlServer(ServerConfig(outs=(f"udp:127.0.0.1:{closed_udp_port()}",), speedup=speedup, duration_s=30.0,
                                     seed=4, quiet=True, log_dir=str(tmp_path / name), tlog="",
                                     faults=("mag_off:10:2",), cruise=(90.0, 5.0), init_s=0.2))
    recorder = Recorder()
    server.out.links = [recorder]
    server.run()
    return recorder.datagrams, read_tlog(tmp_path / name / "sitl.tlog")


def test_a_free_run_sends_a_paced_runs_frames_in_fewer_datagrams(tmp_path):
    free, tlog = run_recorded(tmp_path, "free", 0.0)
    paced, _ = run_recorded(tmp_path, "paced", 300.0)
    assert b"".join(free) == b"".join(paced) == b"".join(m.get_msgbuf() for m in tlog)
    # paced: one datagram per instant (the tlog's distinct stamps), as before coalescing
    assert len(paced) == len({m._timestamp for m in tlog})
    assert all(len(d) <= MAX_DATAGRAM_BYTES for d in free) and len(free) < len(paced) / 3
    # free: datagrams end at instants (never inside one); the instants of STATUSTEXTs end theirs
    stamps = [m._timestamp for m in tlog]
    ends, k = set(), 0
    for datagram in free:
        k += len(frames_of(datagram))
        ends.add(k)
        assert k == len(stamps) or stamps[k] != stamps[k - 1], "an instant split between datagrams"
    said = [i for i, m in enumerate(tlog) if m.get_type() == "STATUSTEXT"]
    assert any("mag_off ON" in tlog[i].text for i in said)
    for i in said:
        end = i + 1
        while end < len(stamps) and stamps[end] == stamps[i]:
            end += 1
        assert end in ends, f"{tlog[i].text!r} held for a later instant's datagram"


class PeerRecorder(Recorder):
    """A link the router can forward to (one peer)."""

    index = 0

    def peer_count(self) -> int:
        return 1


def test_input_makes_the_instant_urgent_and_a_forwarded_frame_never_overtakes_ours():
    from sitl.fc.router import Router

    out, _, clock = outbox(coalesce=True)
    links = [PeerRecorder(), PeerRecorder()]
    links[1].index = 1
    out.links = links
    router = Router(links, None, out, clock, Counters(), sysid=1, compid=1, routing=True)
    out.emit(mavlink.MAVLink_system_time_message, 1, 2)
    out.flush()                                     # coalesced: not sent yet
    assert links[0].datagrams == [] and not out.urgent
    ground = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    for_other = ground.command_long_encode(2, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(ground)
    router.receive(links[0], ("127.0.0.1", 1), for_other, True)
    ours, forwarded = links[1].datagrams        # ours first, then the forwarded frame
    assert frames_of(ours)[0][7] == 2 and forwarded == for_other   # byte 7: msgid low byte (SYSTEM_TIME = 2)
    assert out.urgent                               # whatever it answers leaves at the end of this instant
