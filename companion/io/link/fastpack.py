"""The companion's periodic frames packed with a precomputed struct instead of a pymavlink message object.

``mav.gps_input_send(...)`` builds a message object, packs its fields, builds a header object,
packs it, and computes the CRC through a CRC object: for the 10 Hz position feed (GPS_INPUT,
HIL_GPS) and the setpoint stream that was about a fifth of the companion's time per message
received (docs/notes/2026-12-06-capacity.md). :class:`FramePacker` packs the same bytes
directly from the arguments of pymavlink's ``*_send`` (same order): the class's own ``unpacker``
struct and ``crc_extra``, MAVLink 2's trailing-zero trim, the encoder's sequence and ids.
With signing on, the frame goes through pymavlink (``mav.send``), which signs it.
``tests/companion/test_fastpack.py`` compares the bytes with pymavlink's.
"""
from __future__ import annotations

import inspect
import struct
from operator import itemgetter

from companion.io.link.conventions import mavlink

__all__ = ["FramePacker"]

_HEADER = struct.Struct("<BBBBBBBHB")
_CRC = struct.Struct("<H")
_mcrf4xx = getattr(mavlink, "mcrf4xx", None)


class FramePacker:
    """Unsigned MAVLink 2 frames of one message class (``cls``: pymavlink's generated class, with
    no array fields), from the arguments its ``*_send`` takes."""

    def __init__(self, cls) -> None:
        if sum(cls.lengths) != len(cls.lengths):
            raise ValueError(f"{cls.msgname}: array fields are packed by pymavlink only")
        self.cls = cls
        positions = [cls.fieldnames.index(name) for name in cls.ordered_fieldnames]
        self._wire = itemgetter(*positions)         # declaration order -> wire order
        self._pack = cls.unpacker.pack
        self._extra = bytes([cls.crc_extra])
        self._id_low, self._id_high = cls.id & 0xFFFF, cls.id >> 16
        params = list(inspect.signature(cls.__init__).parameters.values())[1:]
        self._defaults = tuple(p.default for p in params)   # the extension fields' defaults (0)
        self._count = len(params)

    def frame(self, mav, *args) -> bytes:
        """The frame pymavlink's ``mav.send`` would write for ``cls(*args)`` (unsigned), with
        ``mav``'s sequence number and ids; raises as pymavlink's packing does (struct.error)."""
        if len(args) < self._count:
            args = args + self._defaults[len(args):]
        payload = self._pack(*self._wire(args))
        payload = payload.rstrip(b"\x00") or payload[:1]          # MAVLink 2 trims trailing zeros
        frame = _HEADER.pack(253, len(payload), 0, 0, mav.seq, mav.srcSystem, mav.srcComponent, self._id_low,
                             self._id_high) + payload
        if _mcrf4xx is not None:
            crc = _mcrf4xx(self._extra, _mcrf4xx(memoryview(frame)[1:], 0xFFFF))
        else:
            x25 = mavlink.x25crc(frame[1:])
            x25.accumulate(self._extra)
            crc = x25.crc
        return frame + _CRC.pack(crc)

    def send(self, mav, *args) -> bytes | None:
        """Write the frame to ``mav``'s file as ``mav.send`` does: the frame, or None when signing
        is on (then pymavlink packed, signed and sent it, and its send callback saw it)."""
        if mav.signing.sign_outgoing:
            mav.send(self.cls(*args))
            return None
        frame = self.frame(mav, *args)
        mav.file.write(frame)
        mav.seq = (mav.seq + 1) % 256
        mav.total_packets_sent += 1
        mav.total_bytes_sent += len(frame)
        return frame
