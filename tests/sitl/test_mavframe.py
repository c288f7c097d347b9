"""sitl.mavframe without sockets: the fast encoder is byte-identical to pymavlink."""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.mavframe import FrameEncoder


def test_frame_encoder_matches_pymavlink_byte_for_byte():
    enc = FrameEncoder(1, 1)
    mav = mavlink.MAVLink(None, 1, 1)
    cases = [
        (mavlink.MAVLink_raw_imu_message, (123456789, 1, -2, 3, 4, 5, -6, 300, -20, 295, 0, 0)),
        (mavlink.MAVLink_gps_raw_int_message, (1715364000000000, 3, 330000000, 1520000000, 0, 90, 150, 1389, 9000,
                                               14, 0, 2500, 5000, 100, 0, 0)),
        (mavlink.MAVLink_highres_imu_message, (1, 0.1, 0.2, -9.8, 0.0, 0.0, 0.0, math.nan, 0.0, 0.29, 1013.25, 0.0,
                                               0.0, 25.0, 511, 0)),
        (mavlink.MAVLink_sys_status_message, (1, 2, 3, 100, 12600, -1, -1, 0, 0, 0, 0, 0, 0)),   # extensions left out
        (mavlink.MAVLink_heartbeat_message, (11, 3, 209, 15, 4, 3)),
        (mavlink.MAVLink_statustext_message, (4, b"slow path")),
        (mavlink.MAVLink_command_ack_message, (511, 0, 0, 0, 1, 191)),
    ]
    for _ in range(300):   # through a sequence wrap-around
        for cls, fields in cases:
            mav.seq = enc.seq
            assert enc.frame(cls, *fields) == cls(*fields).pack(mav), cls.msgname
