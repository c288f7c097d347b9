"""MAVLink 2 frames read on the lockstep bridges' hot paths without pymavlink's parser.

pymavlink's ``parse_buffer`` builds a message object and checks every frame's checksum in Python:
on PX4's lockstep path (:mod:`sitl.physics.px4_hil`) that was a third of our world's CPU seconds
(py-spy --gil on the full Pacific: PX4's outputs once a frame, and the companion's messages the
lockstep gate reads for their time; docs/notes/2026-12-06-px4-hil-lockstep.md, section 9), and
ArduPilot's relay (:mod:`sitl.physics.relay`) read every companion message the same way. The
bridges need three things from them: PX4's outputs, a message's ``time_boot_ms`` and the frame's
bytes to pass on. The layouts are
pymavlink's (its ``unpacker`` structs and field orders); the checksums are not checked: these links
are TCP and UDP on this machine, which deliver their bytes intact.
"""
from __future__ import annotations

import re
import struct

from pymavlink.dialects.v20 import common as mavlink2

__all__ = ["MAVLINK2_MAGIC", "TIME_BOOT_MS_OFFSET", "actuator_controls", "frames", "time_boot_ms", "whole_frames"]

MAVLINK2_MAGIC, MAVLINK2_HEADER, MAVLINK2_CRC, MAVLINK2_SIGNATURE = 0xFD, 10, 2, 13
_ACTUATORS = mavlink2.MAVLink_hil_actuator_controls_message


def frames(buf: bytearray) -> list[tuple[int, bytes]]:
    """``(msgid, payload)`` of the whole MAVLink 2 frames at the head of ``buf``, which are removed from
    it (an incomplete last frame stays for the next read); bytes before a frame's start are dropped.
    The payload is as sent: MAVLink 2 drops its trailing zero bytes.

    >>> mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    >>> wire = b"x" + mav.heartbeat_encode(1, 12, 0, 0, 0).pack(mav) + mav.system_time_encode(5, 7).pack(mav)
    >>> buf = bytearray(wire[:-3])
    >>> [m for m, _ in frames(buf)], len(buf) > 0
    ([0], True)
    >>> buf += wire[-3:]
    >>> [m for m, _ in frames(buf)], len(buf)
    ([2], 0)
    """
    return _split(buf, False)


def whole_frames(buf: bytearray) -> list[tuple[int, bytes, bytes]]:
    """As :func:`frames`, with each frame's bytes as sent (header, payload, checksum, signature): for
    passing a frame on unchanged.

    >>> mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=191)
    >>> wire = mav.system_time_encode(5, 7).pack(mav)
    >>> [(m, f == wire) for m, _, f in whole_frames(bytearray(wire))]
    [(2, True)]
    """
    return _split(buf, True)


def _split(buf: bytearray, whole: bool) -> list[tuple]:
    found = []
    start, end = 0, len(buf)
    while start < end:
        if buf[start] != MAVLINK2_MAGIC:
            nxt = buf.find(MAVLINK2_MAGIC, start)
            start = end if nxt < 0 else nxt
            continue
        if end - start < MAVLINK2_HEADER:
            break
        length = buf[start + 1]
        total = MAVLINK2_HEADER + length + MAVLINK2_CRC + (MAVLINK2_SIGNATURE if buf[start + 2] & 1 else 0)
        if end - start < total:
            break
        msgid = buf[start + 7] | buf[start + 8] << 8 | buf[start + 9] << 16
        payload = bytes(buf[start + MAVLINK2_HEADER:start + MAVLINK2_HEADER + length])
        found.append((msgid, payload, bytes(buf[start:start + total])) if whole else (msgid, payload))
        start += total
    del buf[:start]
    return found


def actuator_controls(buf: bytearray) -> list[tuple]:
    """The fields (``time_usec, flags, controls[16], mode``) of every HIL_ACTUATOR_CONTROLS among the
    whole frames at the head of ``buf`` (:func:`frames`); other messages are skipped.

    >>> px4 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    >>> buf = bytearray(b"".join(px4.hil_actuator_controls_encode(t, [0.5, -0.25] + [0.0] * 14, 129, 0).pack(px4)
    ...                          for t in (20000, 40000)))
    >>> [(f[0], f[2], f[3], f[-1]) for f in actuator_controls(buf)]
    [(20000, 0.5, -0.25, 129), (40000, 0.5, -0.25, 129)]
    """
    unpack, size = _ACTUATORS.unpacker.unpack, _ACTUATORS.unpacker.size
    return [unpack(payload + bytes(size - len(payload))) for msgid, payload in frames(buf)
            if msgid == _ACTUATORS.id and len(payload) <= size]


def _time_boot_ms_offsets() -> dict[int, int]:
    """msgid -> byte offset of ``time_boot_ms`` in the payload, for every message of the dialect that has one."""
    offsets = {}
    for msgid, cls in mavlink2.mavlink_map.items():
        if "time_boot_ms" not in cls.ordered_fieldnames:
            continue
        codes = re.findall(r"\d*[a-zA-Z?]", cls.unpacker.format.lstrip("<"))
        index = cls.ordered_fieldnames.index("time_boot_ms")
        offsets[msgid] = struct.calcsize("<" + "".join(codes[:index]))
    return offsets


TIME_BOOT_MS_OFFSET = _time_boot_ms_offsets()
"""msgid -> the byte offset of ``time_boot_ms`` in the payload (pymavlink's layouts), every message that has one."""
_UINT32 = struct.Struct("<I")


def time_boot_ms(msgid: int, payload: bytes) -> int | None:
    """The message's ``time_boot_ms`` (None: it has none), as pymavlink would decode it.

    >>> mav = mavlink2.MAVLink(None)
    >>> [time_boot_ms(m, p) for m, p in frames(bytearray(mav.system_time_encode(5, 7).pack(mav)
    ...     + mav.heartbeat_encode(1, 12, 0, 0, 0).pack(mav) + mav.named_value_float_encode(0, b"x", 0.0).pack(mav)))]
    [7, None, 0]
    """
    offset = TIME_BOOT_MS_OFFSET.get(msgid)
    if offset is None:
        return None
    field = payload[offset:offset + 4]
    return _UINT32.unpack(field + bytes(4 - len(field)))[0]
