"""The world's ground station behind the flight controller's telemetry link: the space-weather feed.

A vehicle learns of a storm from its ground station, which sets the companion's parameters over
the telemetry link the flight controller routes (ArduPilot and PX4 forward a ground station's
PARAM_SET to the companion's component). This one keeps ``NAV_SYMH`` up to date: every
``FEED_PERIOD_S`` of simulated time it sends the world's SYM-H
(:meth:`sitl.world.magnetic.TruthField.symh`, OMNI's 1-minute index at the storm time) as a
PARAM_SET from ground-station ids (255, 190: MAVProxy's), rounded to 0.1 nT as the index is
published. A world without SYM-H sends nothing. ``NAV_KP`` is set once before the flight by the
main job (``fcmpc_fly``), as Kp changes every three hours.
"""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.mavframe import FrameEncoder

__all__ = ["FEED_PERIOD_S", "GCS_COMPID", "GCS_SYSID", "SpaceWeatherFeed"]

FEED_PERIOD_S = 60.0      # SYM-H is published once a minute
GCS_SYSID, GCS_COMPID = 255, 190
COMPANION_COMPID = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER


class SpaceWeatherFeed:
    """Sends ``NAV_SYMH`` to the companion of system ``target_sysid`` every ``FEED_PERIOD_S``."""

    def __init__(self, symh_at, outbox, target_sysid: int) -> None:
        self.symh_at = symh_at          # mission seconds -> SYM-H nT (NaN: none)
        self.outbox = outbox
        self.target_sysid = target_sysid
        self.encoder = FrameEncoder(GCS_SYSID, GCS_COMPID)

    def send(self, time_s: float) -> None:
        """The SYM-H at simulated time ``time_s`` as a PARAM_SET, when the world has one."""
        value = self.symh_at(time_s)
        if not math.isfinite(value):
            return
        self.outbox.emit_from(self.encoder, mavlink.MAVLink_param_set_message, self.target_sysid, COMPANION_COMPID,
                              b"NAV_SYMH", round(float(value), 1), mavlink.MAV_PARAM_TYPE_REAL32)
