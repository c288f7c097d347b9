"""Hostile datagrams, by class, from a seeded generator (the attacker and fault injector of issue 10).

=====================  =========================================================================
class                  what one datagram is
=====================  =========================================================================
prefix_fd_ff           ``fd ff`` (or ``fe ff``): a frame start claiming 255 bytes (the issue's)
garbage                1-300 random bytes, often starting with a MAVLink marker
bitflip                a genuine-looking flight-controller frame with 1-3 bytes changed
truncated              a valid frame cut short
unknown_message        a well-formed frame of a message id nobody knows
stranger_param_set     PARAM_SET from a system that is not an allowed ground station, to this
                       system or to all, of the values that took the vehicle in the issue
                       (NAV_SPEED_KMH 300, 60 s timeouts, COMP_DIVERGE_KM 1e4, a new NAV_DEST, ...)
stranger_command       COMMAND_LONG / SET_MODE / SET_POSITION_TARGET from a stranger
spoofed_fc             the flight controller's ids from another address: stamps far in the past
                       or future, SYSTEM_TIME of a "reboot", HEARTBEATs in other modes
unsigned_gcs_write     (with signing on) PARAM_SET / COMMAND_LONG from the GCS id 255, unsigned
=====================  =========================================================================
"""
from __future__ import annotations

import os
import random
from collections.abc import Iterator

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["CLASSES", "DANGEROUS_SETS", "Hostile"]

DANGEROUS_SETS = (("NAV_SPEED_KMH", 300.0), ("COMP_HB_TMO_S", 60.0), ("COMP_MAG_TMO_S", 60.0),
                  ("COMP_DIVERGE_KM", 10000.0), ("COMP_SPIKE_NT", 1e6), ("NAV_DEST_LAT", 10.0),
                  ("NAV_DEST_LON", 120.0), ("SAFE_SPEED_KMH", 300.0), ("LINK_GCS_ID2", 200.0),
                  ("COMP_ARM_ENABLE", 0.0), ("NAV_MAX_STEPS", 3.0))
CLASSES = ("prefix_fd_ff", "garbage", "bitflip", "truncated", "unknown_message", "stranger_param_set",
           "stranger_command", "spoofed_fc", "unsigned_gcs_write")


_ENCODERS: dict[tuple[int, int], mavlink.MAVLink] = {}


def _pack(msg, sysid: int, compid: int) -> bytes:
    enc = _ENCODERS.get((sysid, compid))
    if enc is None:
        enc = _ENCODERS[(sysid, compid)] = mavlink.MAVLink(None, sysid, compid)
    return msg.pack(enc)


class Hostile:
    """Datagrams of every class in turn (``signing``: include unsigned writes from the GCS id)."""

    def __init__(self, seed: int = 0, signing: bool = False, fc_ids: tuple[int, int] = (1, 1)) -> None:
        self.rng = random.Random(seed)
        self.fc_ids = fc_ids
        self.classes = CLASSES if signing else CLASSES[:-1]

    def __iter__(self) -> Iterator[tuple[str, bytes]]:
        while True:
            kind = self.rng.choice(self.classes)
            yield kind, getattr(self, kind)()

    def _fc_frame(self) -> bytes:
        r = self.rng
        msg = r.choice((
            mavlink.MAVLink_heartbeat_message(11, 3, r.choice((1, 129)), r.choice((0, 4, 10, 15)), 4, 3),
            mavlink.MAVLink_attitude_message(r.randrange(2**32), r.uniform(-1, 1), r.uniform(-1, 1),
                                             r.uniform(-3, 3), 0, 0, 0),
            mavlink.MAVLink_system_time_message(r.randrange(2**63), r.randrange(2**32)),
            mavlink.MAVLink_raw_imu_message(r.randrange(2**63), 0, 0, 1000, 0, 0, 0, r.randrange(-600, 600),
                                            r.randrange(-600, 600), r.randrange(-600, 600)),
        ))
        return _pack(msg, *self.fc_ids)

    def prefix_fd_ff(self) -> bytes:
        return self.rng.choice((b"\xfd\xff", b"\xfe\xff", b"\xfd\xff\x00"))

    def garbage(self) -> bytes:
        r = self.rng
        data = r.randbytes(r.randrange(1, 300))
        return (r.choice((b"\xfd", b"\xfe", b"")) + data)[:300]

    def bitflip(self) -> bytes:
        data = bytearray(self._fc_frame())
        for _ in range(self.rng.randrange(1, 4)):
            data[self.rng.randrange(len(data))] ^= 1 << self.rng.randrange(8)
        return bytes(data)

    def truncated(self) -> bytes:
        data = self._fc_frame()
        return data[:self.rng.randrange(1, len(data))]

    def unknown_message(self) -> bytes:
        r = self.rng
        payload = r.randbytes(r.randrange(1, 40))
        msgid = r.randrange(50000, 2**24)
        header = bytes((0xFD, len(payload), 0, 0, r.randrange(256), 1, 1,
                        msgid & 0xFF, (msgid >> 8) & 0xFF, msgid >> 16))
        return header + payload + r.randbytes(2)

    def stranger_param_set(self) -> bytes:
        r = self.rng
        name, value = r.choice(DANGEROUS_SETS)
        target = r.choice((1, 0))
        msg = mavlink.MAVLink_param_set_message(target, r.choice((191, 0)), name.encode(), value,
                                                mavlink.MAV_PARAM_TYPE_REAL32)
        return _pack(msg, r.choice((r.randrange(2, 245), 246, 200, 254)), 190)

    def stranger_command(self) -> bytes:
        r = self.rng
        msg = r.choice((
            mavlink.MAVLink_command_long_message(1, r.choice((1, 191)), mavlink.MAV_CMD_DO_SET_MODE, 0, 1,
                                                 r.choice((0, 4, 15)), 0, 0, 0, 0, 0),
            mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0,
                                                 0, 0),
            mavlink.MAVLink_set_mode_message(1, 1, 4),
            mavlink.MAVLink_set_position_target_global_int_message(0, 1, 1, 6, 3527, 0, 0, 0, 83.0, 0, 0, 0, 0, 0,
                                                                   0, 0),
        ))
        return _pack(msg, r.randrange(2, 245), r.randrange(256))

    def spoofed_fc(self) -> bytes:
        r = self.rng
        if r.random() < 0.3:
            msg = mavlink.MAVLink_system_time_message(r.choice((0, 1_700_000_000_000_000)), r.randrange(0, 5000))
            return _pack(msg, *self.fc_ids)
        return self._fc_frame()

    def unsigned_gcs_write(self) -> bytes:
        r = self.rng
        if r.random() < 0.5:
            name, value = r.choice(DANGEROUS_SETS)
            msg = mavlink.MAVLink_param_set_message(1, 191, name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32)
        else:
            msg = mavlink.MAVLink_command_long_message(1, 191, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0)
        return _pack(msg, 255, 190)
