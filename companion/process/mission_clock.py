"""Mission time: message time minus the time spent paused.

The core's dead reckoning assumes the last command was flown for the whole period, so the
mission clock must not run while the vehicle holds (failsafe, or the flight controller not
armed in GUIDED/OFFBOARD). The magnetometer pipeline follows: samples taken while paused are
not averaged, and its window is kept on mission time.
"""
from __future__ import annotations

import math

from companion.nav.magnetometer import MagProcessor

__all__ = ["MissionClock"]


class MissionClock:
    """``mission time = message time - offset_s``; frozen at ``paused_since`` while paused.

    >>> c = MissionClock(MagProcessor())
    >>> c.pause(100.0); c.mission_time(130.0)
    100.0
    >>> c.resume(130.0); c.mission_time(131.0)
    101.0
    """

    def __init__(self, mag: MagProcessor) -> None:
        self.mag = mag
        self.offset_s = 0.0             # message time - mission time (the pauses so far)
        self.paused_since = math.nan    # message time the current pause began

    @property
    def paused(self) -> bool:
        return math.isfinite(self.paused_since)

    def mission_time(self, now_s: float) -> float:
        if math.isfinite(self.paused_since):
            return self.paused_since - self.offset_s
        return now_s - self.offset_s

    def reset(self) -> None:
        """A new start-up: no pause, no offset."""
        self.mag.paused = False
        self.mag.mission_offset_s = self.offset_s = 0.0
        self.paused_since = math.nan

    def pause(self, now_s: float) -> None:
        if not math.isfinite(self.paused_since):
            self.paused_since = now_s
            self.mag.paused = True

    def resume(self, now_s: float) -> None:
        if math.isfinite(self.paused_since):
            self.offset_s += now_s - self.paused_since
            self.paused_since = math.nan
            self.mag.mission_offset_s = self.offset_s
            self.mag.paused = False
