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
import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

try:
    from fastcrc.crc16 import mcrf4xx as _crc

    def _checksum(data: bytes) -> int:
        return _crc(data, 0xFFFF)
except ImportError:  # pragma: no cover - fastcrc is a dependency
    from pymavlink.generator.mavcrc import x25crc

    def _checksum(data: bytes) -> int:
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


_HEADER = struct.Struct("<BBBBBBBHB")


class _Spec:
    __slots__ = ("packer", "order", "msgid_lo", "msgid_hi", "crc_extra", "name", "nfields")

    def __init__(self, cls) -> None:
        self.packer = cls.unpacker  # the wire struct, fields in wire order
        index = {name: i for i, name in enumerate(cls.fieldnames)}
        order = [index[name] for name in cls.ordered_fieldnames]
        self.order = None if order == list(range(len(order))) else order
        self.msgid_lo = cls.id & 0xFFFF
        self.msgid_hi = cls.id >> 16
        self.crc_extra = bytes([cls.crc_extra])
        self.name = cls.msgname
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
        self.sysid = sysid
        self.compid = compid
        self.seq = 0
        self._specs: dict[type, _Spec | None] = {}
        self._mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)

    def _spec(self, cls) -> _Spec | None:
        try:
            return self._specs[cls]
        except KeyError:
            spec = _Spec(cls) if _scalar(cls) else None
            self._specs[cls] = spec
            return spec

    def frame(self, cls, *fields) -> bytes:
        """The frame of message class ``cls`` with ``fields`` in the order of its ``*_encode`` arguments."""
        spec = self._spec(cls)
        if spec is None:
            return self.pack(cls(*fields))
        if len(fields) < spec.nfields:  # extension fields left out: zeros, as pymavlink's defaults
            fields = fields + (0,) * (spec.nfields - len(fields))
        values = fields if spec.order is None else [fields[i] for i in spec.order]
        payload = spec.packer.pack(*values).rstrip(b"\x00") or b"\x00"
        header = _HEADER.pack(0xFD, len(payload), 0, 0, self.seq, self.sysid, self.compid, spec.msgid_lo,
                              spec.msgid_hi)
        self.seq = (self.seq + 1) & 0xFF
        body = header + payload
        crc = _checksum(body[1:] + spec.crc_extra)
        return body + crc.to_bytes(2, "little")

    def pack(self, msg) -> bytes:
        """Frame of a pymavlink message object (slow path), sharing the sequence counter."""
        mav = self._mav
        mav.seq = self.seq
        frame = msg.pack(mav)
        self.seq = (self.seq + 1) & 0xFF
        return frame
