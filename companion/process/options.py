"""The companion process's options (the command line as data) and the timings its parts share.

All durations are message time unless the name ends in ``_WALL_S``.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["FC_POSITION_MAX_AGE_S", "GPS_START_MAX_AGE_S", "MAX_RESTARTS", "STARTUP_GRACE_S", "AppOptions"]

MAX_RESTARTS = 3                  # navigation failures before the mission is given up
FC_POSITION_MAX_AGE_S = 5.0       # older GLOBAL_POSITION_INT: dead reckoning instead
GPS_START_MAX_AGE_S = 5.0         # a GPS fix this old still gives the start (and the record)
STARTUP_GRACE_S = 5.0             # for the requested streams to arrive before complaining


@dataclass
class AppOptions:
    """What ``fcmpc-companion``'s command line sets (:func:`companion.app.options_from_args`)."""

    connect: str = "udp:127.0.0.1:14550"
    params: str | None = None
    log_dir: str | None = None
    sysid: int | None = None
    lockstep: bool = False
    exit_when_done: bool = False
    param_encoding: str = "auto"
    mag_message: str | None = None
    startup_s: float | None = None
    tlog: bool = True
    request_streams: bool = True
    max_wall_s: float | None = None
    quiet: bool = False
    sensors: str | None = None
    state: str | None = None            # the navigator's saved state (resume); default beside --params
    linger_s: float = 0.0               # --exit-when-done: message time after the end before exiting
    fc_compid: int | None = None        # pin the FC's component too (default: the first autopilot's)
    signing_key: str | None = None      # MAVLink 2 signing key file
    signing_link_id: int = 0
    http: str | None = None             # the status page's ADDRESS:PORT (PORT alone: loopback); None: off
