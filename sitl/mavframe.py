"""Fast MAVLink 2 framing for the simulator's streams (byte-identical to pymavlink's ``pack``).

pymavlink builds a message object, a header object and a bytearray per frame (about 4 us);
the simulator sends tens of thousands of frames per wall second. :class:`FrameEncoder`
packs the payload with a precompiled :class:`struct.Struct` in wire order, strips trailing
zero bytes (MAVLink 2 truncation), adds the header and the CRC-16/MCRF4XX with the message's
CRC_EXTRA (``fastcrc`` when installed, pymavlink's implementation otherwise). Only messages
with scalar fields take the fast path; anything else (arrays, strings) goes through
pymavlink. Signing is not supported (the simulator does not sign).
"""
from __future__ import annotations

import math
import operator

from pymavlink.dialects.v20 import ardupilotmega as mavlink

try:
    from fastcrc.crc16 import mcrf4xx as _crc   # _crc(data, 0xFFFF): the MAVLink checksum in C
except ImportError:  # pragma: no cover - fastcrc is a dependency
    from pymavlink.generator.mavcrc import x25crc

    def _crc(data: bytes, initial: int) -> int:   # x25crc starts at 0xFFFF, the only initial used here
        return x25crc(data).crc

__all__ = ["INT16_MAX", "FrameEncoder", "int16", "int16_truncated"]

INT16_MAX = 32767


def int16(value: float) -> int:
    """``value`` rounded and saturated to an int16 field (MAVLink's RAW_IMU, SCALED_IMU, velocities).

    >>> int16(40000.4), int16(-1.6)
    (32767, -2)
    """
    v = int(round(value))
    return INT16_MAX if v > INT16_MAX else (-INT16_MAX - 1 if v < -INT16_MAX - 1 else v)

def int16_truncated(value: float) -> int:
    """``value`` as ArduPilot and PX4 put a float into an int16 magnetometer field: a C conversion,
    truncated toward zero, and saturated.

    >>> int16_truncated(302.9), int16_truncated(-21.8), int16_truncated(-40000.0)
    (302, -21, -32768)
    """
    if not math.isfinite(value):
        return INT16_MAX
    v = int(value)
    return INT16_MAX if v > INT16_MAX else (-INT16_MAX - 1 if v < -INT16_MAX - 1 else v)


_SLOW = object()   # a message class with arrays or strings: pymavlink packs it


class _Spec:
    """What one scalar message class needs per frame, worked out once."""

    __slots__ = ("pack", "reorder", "msgid", "crc_extra", "nfields")

    def __init__(self, cls) -> None:
        self.pack = cls.unpacker.pack  # the wire struct, fields in wire order
        index = {name: i for i, name in enumerate(cls.fieldnames)}
        order = [index[name] for name in cls.ordered_fieldnames]
        # the *_encode order -> wire order (larger types first); None when they agree
        self.reorder = None if order == list(range(len(order))) else operator.itemgetter(*order)
        self.msgid = cls.id.to_bytes(3, "little")
        self.crc_extra = bytes([cls.crc_extra])
        self.nfields = len(cls.fieldnames)


def _scalar(cls) -> bool:
    return not any(cls.array_lengths) and len(cls.ordered_fieldnames) == len(cls.fieldnames)


class FrameEncoder:
    """MAVLink 2 frames from (sysid, compid), one sequence counter.

    >>> enc = FrameEncoder(1, 1)
    >>> mav = mavlink.MAVLink(None, 1, 1)
    >>> msg = mavlink.MAVLink_attitude_message(1000, 0.1, -0.2, 3.0, 0.0, 0.0, 0.01)
    >>> enc.frame(mavlink.MAVLink_attitude_message, 1000, 0.1, -0.2, 3.0, 0.0, 0.0, 0.01) == msg.pack(mav)
    True
    """

    def __init__(self, sysid: int, compid: int) -> None:
        self._sysid = sysid
        self._compid = compid
        self._source = bytes((sysid, compid))   # header bytes 5-6, after the sequence number
        self.seq = 0
        self._specs: dict[type, _Spec | object] = {}
        self._mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)

    @property
    def sysid(self) -> int:
        return self._sysid

    @property
    def compid(self) -> int:
        return self._compid

    def frame(self, cls, *fields) -> bytes:
        """The frame of message class ``cls`` with ``fields`` in the order of its ``*_encode`` arguments."""
        return self.frame_of(cls, fields)

    def frame_of(self, cls, fields: tuple) -> bytes:
        """:meth:`frame` with the fields as one tuple (the outbox's call: no second tuple per message)."""
        spec = self._specs.get(cls)
        if spec is None:
            spec = self._specs[cls] = _Spec(cls) if _scalar(cls) else _SLOW
        if spec is _SLOW:
            return self.pack(cls(*fields))
        if len(fields) < spec.nfields:  # extension fields left out: zeros, as pymavlink's defaults
            fields = fields + (0,) * (spec.nfields - len(fields))
        if spec.reorder is not None:
            fields = spec.reorder(fields)
        payload = spec.pack(*fields).rstrip(b"\x00") or b"\x00"   # MAVLink 2 truncation
        seq = self.seq
        self.seq = (seq + 1) & 0xFF
        # the header after the magic byte: length, incompat/compat flags (0), seq, source, message id
        body = bytes((len(payload), 0, 0, seq)) + self._source + spec.msgid + payload
        crc = _crc(body + spec.crc_extra, 0xFFFF)
        return b"\xfd" + body + crc.to_bytes(2, "little")

    def pack(self, msg) -> bytes:
        """Frame of a pymavlink message object (slow path), sharing the sequence counter."""
        mav = self._mav
        mav.seq = self.seq
        frame = msg.pack(mav)
        self.seq = (self.seq + 1) & 0xFF
        return frame
