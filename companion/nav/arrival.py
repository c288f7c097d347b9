"""When a mission has arrived: Algorithm 1's epsilon, or a bounded number of legs flown to the
estimated destination; and the last leg that ends it at rest there.

Algorithm 1 stops when the *estimated* distance to the destination is below epsilon
(``NAV_ARRIVE_M``). Where the estimate's own 1-sigma is far larger than epsilon (a storm: 4-5 km),
each period's update moves the estimate by more than epsilon: the vehicle flies to where it
estimated the destination, then turns to where it now estimates it, and circles there until one
estimate happens to fall inside epsilon (ten periods in a closed-loop short storm, 2026-12-04).

Each such leg acts on the filter's newest estimate, so it is worth flying while the updates are
information; but the mission must end. A *final leg* is one planned to reach the destination
within the period (the remaining distance within one period at cruise speed). After
``NAV_ARRIVE_LEGS`` final legs in a row the vehicle has arrived wherever the last one ended, as
ArduPilot's Rover counts a waypoint reached once it has passed it, not only within its radius.
``NAV_ARRIVE_LEGS`` 0 keeps Algorithm 1's rule alone (the paper).

Once arrived, with ``NAV_FINAL_LEG`` 1 (the default), the vehicle flies one *last leg* to the
estimated destination and the mission ends at the next step, so the vehicle comes to rest where
the estimate puts the destination, instead of up to epsilon from it, still moving at the last
leg's speed. Only for Fc-MPC, whose position estimate says where the destination is, and not with
a constant speed (``NAV_SPEED_MODE`` 1), whose leg would overshoot.

A period excluded by the plausibility check (:mod:`companion.nav.plausibility`) leaves the last
command flying on. Once that leg has covered the distance to the estimated destination
(:func:`passed_destination`), flying it on would only carry the vehicle past it, blind: the
mission ends there instead, at rest where the estimate puts the destination, and says why
(ArduPilot lockstep Pacific, 2026-12-06: 35 periods excluded after the final legs, the vehicle
driven on for 3 h and stopped 77 km away, never at rest).

A rule on the estimate's own uncertainty (stop when the destination lies inside its 1-sigma
ellipse after a final leg) was measured and not kept: it drops a correction the filter has just
made, and at ten times the magnetometer noise its median miss rose from 0.985 to 1.034 km.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion.nav.config import NavConfig

__all__ = [
    "BELOW_EPSILON",
    "PASSED_MAX_OFF_COURSE_RAD",
    "Arrival",
    "arrival_reason",
    "is_final_leg",
    "legs_reason",
    "passed_destination",
]

BELOW_EPSILON = "estimated distance below epsilon"


def legs_reason(legs: int) -> str:
    """The arrival reason after ``legs`` final legs."""
    return f"flown {legs} legs to the estimated destination"


def is_final_leg(remaining_m: float, speed_mps: float, period_s: float) -> bool:
    """A leg from ``remaining_m`` (m) is planned to reach the destination within one period."""
    return remaining_m <= speed_mps * period_s


PASSED_MAX_OFF_COURSE_RAD = math.radians(45.0)   # a leg further off the bearing is not one to the destination


def passed_destination(remaining_m: float, off_course_rad: float, speed_mps: float, elapsed_s: float,
                       arrive_m: float) -> bool:
    """A leg commanded ``remaining_m`` (m) from the estimated destination, on a course
    ``off_course_rad`` off the bearing to it (within :data:`PASSED_MAX_OFF_COURSE_RAD`), flown on at
    ``speed_mps`` for ``elapsed_s``, has come within ``arrive_m`` (epsilon) of its closest approach.

    >>> passed_destination(1700.0, 0.1, 5.7, 300.0, 500.0), passed_destination(20000.0, 0.0, 8.0, 300.0, 500.0)
    (True, False)
    >>> passed_destination(1700.0, 2.0, 5.7, 300.0, 500.0)   # a probe leg away from it
    False
    """
    if not (math.isfinite(remaining_m) and abs(off_course_rad) <= PASSED_MAX_OFF_COURSE_RAD):
        return False
    return speed_mps * max(elapsed_s, 0.0) >= remaining_m * math.cos(off_course_rad) - arrive_m


def arrival_reason(remaining_m: float, arrive_m: float, final_legs: int, arrive_legs: int) -> str | None:
    """Why the mission has arrived, or None if it has not.

    ``remaining_m``: the estimated distance to the destination (m); ``arrive_m``: epsilon (m);
    ``final_legs``: the final legs flown in a row until now; ``arrive_legs``: NAV_ARRIVE_LEGS
    (0: epsilon only).
    """
    if remaining_m < arrive_m:
        return BELOW_EPSILON
    if 0 < arrive_legs <= final_legs:
        return legs_reason(final_legs)
    return None


@dataclass
class Arrival:
    """The arrival rule's memory over a mission: the final legs flown in a row, and once arrived
    with a last leg to fly (``NAV_FINAL_LEG`` 1), why."""

    final_legs: int = 0
    arrived: str | None = None

    def judge(self, remaining_m: float, config: NavConfig, positioned: bool) -> str | None:
        """Why the mission ends at this step, or None to fly on (the last leg included);
        ``config``: the mission's settings; ``positioned``: the
        remaining distance is from a position estimate (Fc-MPC). LTI- and LTV-MPC have none, only
        the field's linear extrapolation ``G^-1 (S_d - S)``, whose direction over the last few
        hundred metres is the noise's: they stop at once (with a last leg LTV-MPC ended 0.85 km
        off against 0.59, 50 quiet seeds)."""
        if self.arrived is not None:   # the last leg, flown to the estimate a period ago, is over
            return f"{self.arrived}, then the last leg"
        reason = arrival_reason(remaining_m, config.arrive_m, self.final_legs, config.arrive_legs)
        if reason is not None and (config.final_leg == 0 or config.speed_mode == 1 or not positioned):
            return reason
        self.arrived = reason
        return None

    def flew(self, remaining_m: float, config: NavConfig) -> None:
        """A leg was commanded from ``remaining_m`` (m) from the estimated destination."""
        self.final_legs = self.final_legs + 1 if is_final_leg(remaining_m, config.speed_mps, config.period_s) else 0
