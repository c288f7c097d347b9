"""The navigator's position now: the last command's estimate flown on with that command, else the
start the next mission would use. Read by what leaves (the trim, the position feed, the operator's
status); nothing here changes the mission."""
from __future__ import annotations

import math

from companion.io.link.clock import MessageClock
from companion.nav.geo import offset_position
from companion.process.mission_clock import MissionClock
from companion.process.mission_state import MissionState
from companion.process.preparation import MissionPreparation
from companion.process.settings import Settings

__all__ = ["CurrentEstimate"]


class CurrentEstimate:
    """:meth:`position` and :meth:`sigma_m` of the navigator's latest estimate."""

    def __init__(self, state: MissionState, clock: MissionClock, msg_clock: MessageClock,
                 preparation: MissionPreparation, settings: Settings) -> None:
        self.mission_state = state
        self.clock = clock
        self.msg_clock = msg_clock
        self.preparation = preparation
        self.settings = settings

    def position(self) -> tuple[float, float] | None:
        """The navigator's latest position: the mission's estimate, else the start it would use."""
        state = self.mission_state
        cmd = state.command
        if cmd is not None and math.isfinite(cmd.est_lat_deg) and math.isfinite(cmd.est_lon_deg):
            # flown on with the command since its step (mission time stops while paused)
            mission_now = self.clock.mission_time(self.msg_clock.now_s)
            dt = max(mission_now - state.m0 - cmd.time_s, 0.0) if not cmd.done else 0.0
            lat, lon = offset_position(cmd.est_lat_deg, cmd.est_lon_deg, cmd.speed_mps * math.sin(cmd.course_rad) * dt,
                                       cmd.speed_mps * math.cos(cmd.course_rad) * dt)
            return float(lat), float(lon)
        lat, lon, _ = self.preparation.start_position()
        return (lat, lon) if math.isfinite(lat) and math.isfinite(lon) else None

    def sigma_m(self) -> float:
        """The estimate's 1-sigma (m): the last command's, else the fusion's fix noise."""
        cmd = self.mission_state.command
        if cmd is not None and math.isfinite(cmd.est_sigma_m):
            return cmd.est_sigma_m
        return math.sqrt(self.settings.nav.fusion.rc_m2)
