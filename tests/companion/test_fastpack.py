"""The precomputed packers write exactly the frames pymavlink's ``*_send`` writes, signed or not."""
from __future__ import annotations

import inspect
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.io.link.conventions import mavlink
from companion.io.link.fastpack import FramePacker
from companion.io.link.outputs import GPS_INPUT, HEARTBEAT, HIL_GPS, SETPOINT


class _Sink:
    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, buf) -> None:
        self.frames.append(bytes(buf))


def _pair(seq: int, sysid: int, key: bytes | None = None):
    pair = []
    for _ in range(2):
        mav = mavlink.MAVLink(_Sink(), sysid, 191)
        mav.seq = seq
        if key is not None:
            mav.signing.secret_key, mav.signing.sign_outgoing, mav.signing.timestamp = key, True, 1234567
        pair.append(mav)
    return pair


def _ints(fmt: str):
    bits = {"B": 8, "H": 16, "I": 32, "Q": 64}
    if fmt in bits:
        return st.integers(0, (1 << bits[fmt]) - 1)
    signed = {"b": 8, "h": 16, "i": 32, "q": 64}[fmt]
    return st.integers(-(1 << (signed - 1)), (1 << (signed - 1)) - 1)


def _args(packer: FramePacker):
    """Arguments for ``packer``'s ``*_send`` in declaration order, any value its fields carry; the
    extension fields sometimes left to their defaults."""
    cls = packer.cls
    codes = dict(zip(cls.ordered_fieldnames, struct.Struct(cls.unpacker.format).format.lstrip("<")))
    fields = [st.floats(width=32, allow_nan=True) if codes[name] == "f" else
              st.floats(allow_nan=True) if codes[name] == "d" else _ints(codes[name]) for name in cls.fieldnames]
    required = sum(default is inspect.Parameter.empty for default in packer._defaults)
    return st.tuples(st.tuples(*fields), st.integers(required, len(fields))).map(lambda drawn: drawn[0][:drawn[1]])


def _same_frames(packer: FramePacker, args: tuple, seq: int, sysid: int, key: bytes | None) -> None:
    ours, theirs = _pair(seq, sysid, key)
    got = packer.send(ours, *args)
    theirs.send(packer.cls(*args))
    assert ours.file.frames == theirs.file.frames and ours.seq == theirs.seq
    assert got is None if key else got == theirs.file.frames[0]
    if key:
        assert ours.signing.timestamp == theirs.signing.timestamp


@pytest.mark.parametrize("packer", [GPS_INPUT, HIL_GPS, SETPOINT, HEARTBEAT], ids=lambda p: p.cls.msgname)
@settings(max_examples=25, deadline=None)
@given(data=st.data(), seq=st.integers(0, 255), sysid=st.integers(0, 255), signed=st.booleans())
def test_a_packed_frame_is_pymavlinks_frame(packer, data, seq, sysid, signed):
    args = data.draw(_args(packer))
    _same_frames(packer, args, seq, sysid, bytes(range(32)) if signed else None)


def test_a_value_pymavlink_cannot_pack_is_refused_alike():
    ours, theirs = _pair(0, 1)
    with pytest.raises(struct.error):
        GPS_INPUT.send(ours, -1, *([0] * 17))
    with pytest.raises(struct.error):
        theirs.send(GPS_INPUT.cls(-1, *([0] * 17)))
    assert ours.file.frames == theirs.file.frames == [] and ours.seq == theirs.seq == 0


def test_messages_with_arrays_are_left_to_pymavlink():
    with pytest.raises(ValueError, match="array"):
        FramePacker(mavlink.MAVLink_odometry_message)
