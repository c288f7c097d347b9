"""The fast datagram decoder gives exactly pymavlink's messages, on valid, fuzzed and garbage bytes."""
from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from companion.io.link.conventions import mavlink
from companion.io.link.fastparse import parse_datagram


def _parser():
    parser = mavlink.MAVLink(None, 1, 191)
    parser.robust_parsing = True
    return parser


def _state(msg) -> dict:
    state = dict(vars(msg))
    state["_header"] = vars(state["_header"]) if "_header" in state else None
    return {"class": type(msg), **state}


def _same(data: bytes, chunks: int = 1) -> list:
    """Both parsers over ``data`` cut into ``chunks`` pieces (a byte stream): the same messages."""
    fast, slow = _parser(), _parser()
    cut = sorted(random.Random(len(data)).choices(range(len(data) + 1), k=chunks - 1))
    bounds = [0, *cut, len(data)]
    got, want = [], []
    for a, b in zip(bounds, bounds[1:]):
        got += parse_datagram(fast, data[a:b])
        want += slow.parse_buffer(data[a:b]) or []
    assert [_state(m) for m in got] == [_state(m) for m in want]
    assert fast.buf_len() == slow.buf_len()
    return got


def _frames(seed: int, count: int) -> bytes:
    """``count`` frames of the messages the companion hears, as an ArduPilot would send them."""
    rng = random.Random(seed)
    enc = mavlink.MAVLink(None, 1, 1)
    out = b""
    for _ in range(count):
        kind = rng.randrange(7)
        if kind == 0:
            msg = enc.attitude_encode(rng.randrange(1 << 32), *(rng.uniform(-4, 4) for _ in range(6)))
        elif kind == 1:
            msg = enc.highres_imu_encode(rng.randrange(1 << 64), *(rng.uniform(-1, 1) for _ in range(13)),
                                         rng.randrange(1 << 16), rng.randrange(256))
        elif kind == 2:
            msg = enc.heartbeat_encode(10, 3, rng.randrange(256), rng.randrange(1 << 32), 4)
        elif kind == 3:
            msg = enc.global_position_int_encode(rng.randrange(1 << 32), *(rng.randrange(-1 << 31, 1 << 31)
                                                                          for _ in range(4)), 0, 0, 0, 0)
        elif kind == 4:
            msg = enc.statustext_encode(6, b"PreArm: " + bytes(rng.randrange(65, 90) for _ in range(rng.randrange(30))))
        elif kind == 5:
            msg = enc.raw_imu_encode(rng.randrange(1 << 64), *(rng.randrange(-32768, 32768) for _ in range(9)))
        else:
            msg = enc.system_time_encode(rng.randrange(1 << 64), rng.randrange(1 << 32))
        out += msg.pack(enc)
        enc.seq = (enc.seq + 1) % 256
    return out


def test_a_datagram_of_the_companions_messages_decodes_to_pymavlinks_messages():
    msgs = _same(_frames(1, 300))
    assert len(msgs) == 300 and msgs[0].get_type() != "BAD_DATA"


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 1 << 30), count=st.integers(1, 20), flips=st.lists(st.tuples(st.integers(0, 1 << 20),
                                                                                        st.integers(0, 255)),
                                                                              max_size=4),
       cut=st.integers(0, 1 << 20), chunks=st.integers(1, 4))
def test_fuzzed_frames_decode_as_pymavlink_decodes_them(seed, count, flips, cut, chunks):
    data = bytearray(_frames(seed, count))
    for where, value in flips:
        data[where % len(data)] = value
    data = bytes(data[:len(data) - cut % 12])
    _same(data, 1)
    _same(data, chunks)


@settings(max_examples=150, deadline=None)
@given(data=st.binary(max_size=600), chunks=st.integers(1, 3))
def test_garbage_decodes_as_pymavlink_decodes_it(data, chunks):
    _same(data, chunks)
    _same(b"\xfd" + data, chunks)
    _same(_frames(len(data), 2) + data, chunks)
