"""The companion's MAVLink edge, one idea per module.

* :mod:`~companion.io.link.conventions` -- ArduPilot/PX4 modes and masks, the FC's state, the setpoint guard
* :mod:`~companion.io.link.clock` -- message time, judged stamp by stamp (reboots need evidence)
* :mod:`~companion.io.link.peers` -- one parser per sender, a bounded peer table, the pinned peers
* :mod:`~companion.io.link.signing` -- MAVLink 2 signing: key file, persisted timestamp, refusals
* :mod:`~companion.io.link.keygen` -- ``fcmpc-signing-key``: make a key, print the ground-station steps
* :mod:`~companion.io.link.transport` -- UDP with sender addresses, or a pymavlink serial/TCP stream
* :mod:`~companion.io.link.outputs` -- one send helper per output
* :mod:`~companion.io.link.tlog` -- the flushed, rotated ``.tlog``
* :mod:`~companion.io.link.mavlink_link` -- :class:`MavlinkLink`, which ties them together
"""
from __future__ import annotations

from companion.io.link.clock import MessageClock
from companion.io.link.conventions import (
    ARDUPILOT,
    COMPANION_COMPONENT,
    PX4,
    VELOCITY_ONLY_TYPE_MASK,
    VELOCITY_YAW_TYPE_MASK,
    FcConventions,
    FcState,
    Setpoint,
    UnsafeSetpoint,
    conventions_for,
    guard_setpoint,
    mavlink,
)
from companion.io.link.mavlink_link import LinkStats, MavlinkLink
from companion.io.link.outputs import EXT_POS_TIME_WRAP_S, STATUSTEXT_CHUNK
from companion.io.link.peers import PeerPolicy, PeerTable
from companion.io.link.signing import Signing, SigningError
from companion.io.link.transport import parse_connection

__all__ = [
    "ARDUPILOT",
    "COMPANION_COMPONENT",
    "EXT_POS_TIME_WRAP_S",
    "PX4",
    "STATUSTEXT_CHUNK",
    "VELOCITY_ONLY_TYPE_MASK",
    "VELOCITY_YAW_TYPE_MASK",
    "FcConventions",
    "FcState",
    "LinkStats",
    "MavlinkLink",
    "MessageClock",
    "PeerPolicy",
    "PeerTable",
    "Setpoint",
    "Signing",
    "SigningError",
    "UnsafeSetpoint",
    "conventions_for",
    "guard_setpoint",
    "mavlink",
    "parse_connection",
]
