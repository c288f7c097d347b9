"""The mission's shared mutable state: the one record the companion's parts read and write.

Everything else a part holds is its own (a counter, a timer, a table of pending commands). What
more than one part must see of the running mission lives here, in one dataclass handed to the
parts that need it, so a reader finds the mission's state in one place and each part's
constructor says whether it touches it. Times are message time unless the name says mission
time (``_m``) or wall time (``_wall``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion.nav.mission import Command, Mission

__all__ = ["MissionState"]


@dataclass
class MissionState:
    """The running mission and the clocks that time it.

    >>> s = MissionState()
    >>> s.mission is None and s.mission_no == 0 and math.isnan(s.m0)
    True
    """

    mission: Mission | None = None                   # the navigation core of the running mission
    command: Command | None = None                   # its last command (the one streamed)
    elements_code: int = 0                           # the resolved element set (NAV_ELEMENTS)
    bias: tuple[float, ...] | None = None            # the start-up calibration subtracted
    mission_no: int = 0
    restarts: int = 0                                # navigation failures restarted from so far
    restart_from: tuple[float, float] | None = None  # the last estimate a restart starts from
    last_phase: str = ""                             # the core's phase last said (probe1, cruise, ...)
    m0: float = math.nan                             # mission time of the mission's start
    next_step_m: float = math.nan                    # mission time of the next control step
    startup_begin: float = math.nan                  # the start of the stationary start-up window
    fc_detected_at: float = math.nan                 # the FC heard (again, after a reboot)
    local_ned: tuple[float, float, float] | None = None   # (time, north, east) of LOCAL_POSITION_NED
    done_wall: float = math.nan                      # wall (monotonic) time the mission ended
    done_msg_s: float = math.nan                     # message time the mission ended
    calibration: str = ""                            # what became of COMP_CAL_TURNS' circles ("": none asked)
