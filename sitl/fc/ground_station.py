"""The world's ground station behind the flight controller's telemetry link: the space-weather feed.

A vehicle learns of a storm from its ground station, which sets the companion's parameters over
the telemetry link the flight controller routes (ArduPilot and PX4 forward a ground station's
PARAM_SET to the companion's component). This one keeps the two space-weather readings up to
date: every ``FEED_PERIOD_S`` of simulated time it sends, as PARAM_SETs from ground-station ids
(255, 190: MAVProxy's),

* ``NAV_KP``: the world's planetary Kp (:meth:`sitl.world.magnetic.TruthField.kp`, the 3-hour
  index at the storm time), to 0.001 (Kp is published in thirds: 8.667 is 9-);
* ``NAV_SYMH``: the world's SYM-H (:meth:`~sitl.world.magnetic.TruthField.symh`, OMNI's 1-minute
  index at the storm time), rounded to 0.1 nT as the index is published.

A world without a storm gives a quiet day's indices (Kp 0, SYM-H 0 nT), which are sent like
any. An index the world lacks (a scenario may withhold one: ``[storm] kp_feed``, ``symh_feed``) is
not sent, nor one the ground station is not set to feed
(``--space-weather-feed NAV_SYMH``: an operator with SYM-H and no Kp). The companion takes each only
while it is renewed (``companion.process.control_step``), so a feed that stops is a feed lost,
not a storm frozen at its last value.
"""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.mavframe import FrameEncoder

__all__ = ["FEED_PERIOD_S", "FEED_READINGS", "GCS_COMPID", "GCS_SYSID", "SpaceWeatherFeed", "feed_readings"]

FEED_PERIOD_S = 60.0      # SYM-H is published once a minute
GCS_SYSID, GCS_COMPID = 255, 190
COMPANION_COMPID = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER
FEED_READINGS = ("NAV_KP", "NAV_SYMH")


def feed_readings(text: str) -> tuple[str, ...]:
    """The readings named in ``text`` (comma-separated, any case; empty: none), in
    :data:`FEED_READINGS`' order; ValueError naming an unknown one."""
    names = {name.strip().upper() for name in text.split(",") if name.strip()}
    unknown = sorted(names - set(FEED_READINGS))
    if unknown:
        raise ValueError(f"unknown space-weather reading {', '.join(unknown)}: choose from {', '.join(FEED_READINGS)}")
    return tuple(name for name in FEED_READINGS if name in names)


class SpaceWeatherFeed:
    """Sends ``NAV_KP`` and ``NAV_SYMH`` (or the ``readings`` named) to the companion of system
    ``target_sysid`` (:meth:`send` every ``FEED_PERIOD_S``); ``kp_at`` and ``symh_at``: simulated
    seconds -> the index (NaN: none)."""

    def __init__(self, kp_at, symh_at, outbox, target_sysid: int, readings: tuple[str, ...] = FEED_READINGS) -> None:
        every = ((b"NAV_KP", kp_at, 3), (b"NAV_SYMH", symh_at, 1))   # (name, source, decimals)
        self.readings = tuple(reading for reading in every if reading[0].decode() in readings)
        self.outbox = outbox
        self.target_sysid = target_sysid
        self.encoder = FrameEncoder(GCS_SYSID, GCS_COMPID)

    def send(self, time_s: float) -> None:
        """Each index the world has at simulated time ``time_s`` as a PARAM_SET."""
        for name, source, decimals in self.readings:
            value = source(time_s)
            if math.isfinite(value):
                self.outbox.emit_from(self.encoder, mavlink.MAVLink_param_set_message, self.target_sysid,
                                      COMPANION_COMPID, name, round(float(value), decimals),
                                      mavlink.MAV_PARAM_TYPE_REAL32)
