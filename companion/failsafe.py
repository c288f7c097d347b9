"""Failsafe rules of the companion: which conditions stop the vehicle, and when it may go on.

Pure: the application passes ages and flags measured on its clocks; this module answers
with the list of reasons (empty = healthy) and tracks entering and leaving the failsafe.

Conditions (parameters in brackets):

``mag``        no valid magnetometer sample for longer than [COMP_MAG_TMO_S] of message time
               (silent, all-zero, saturated/NaN or stuck samples are not valid)
``attitude``   no finite ATTITUDE for longer than [COMP_ATT_TMO_S] of message time
``heartbeat``  the flight controller's last HEARTBEAT is older than [COMP_HB_TMO_S], judged
               on **both** clocks: message time catches a flight controller that still streams
               but stopped its heartbeat (message time goes on); wall time catches one that
               went silent altogether (then message time stops, and an age in message time
               would never grow). The wall-time rule assumes heartbeats arrive at least every
               COMP_HB_TMO_S of wall time, true on a vehicle and for a simulator at speed-up
               >= 1 (lockstep included: the simulator streams while it waits).
``params``     the parameter file was broken at start-up (never cleared in this run)
``nav``        the navigation core failed: solver failure, estimate diverged from the
               geomagnetic fix by more than [COMP_DIVERGE_KM], or a non-finite command

Recovery: the sensor and link conditions clear when every one of them has been healthy
for ``resume_s`` of message time; ``nav`` clears when the application restarts the mission.

>>> h = Health(HealthLimits(2.0, 2.0, 3.0))
>>> h.evaluate(10.0, mag_age_s=0.1, att_age_s=0.1, hb_age_msg_s=0.5, hb_age_wall_s=0.5)
[]
>>> h.evaluate(12.5, mag_age_s=2.5, att_age_s=0.1, hb_age_msg_s=0.5, hb_age_wall_s=0.5)
['mag: no valid magnetometer sample for 2.5 s']
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["HealthLimits", "Health", "diverged"]


@dataclass(frozen=True)
class HealthLimits:
    mag_timeout_s: float
    att_timeout_s: float
    heartbeat_timeout_s: float
    resume_s: float = 1.0


@dataclass
class Health:
    """Current failsafe reasons and the time they all last cleared."""

    limits: HealthLimits
    reasons: list[str] = field(default_factory=list)
    latched: dict[str, str] = field(default_factory=dict)   # kind -> text, cleared only explicitly
    healthy_since_s: float = math.nan
    entered: int = 0

    def latch(self, kind: str, text: str) -> None:
        """A condition that stays until :meth:`clear` (parameter file, navigation failure)."""
        self.latched[kind] = text

    def clear(self, kind: str) -> None:
        self.latched.pop(kind, None)

    def evaluate(self, now_s: float, *, mag_age_s: float, att_age_s: float, hb_age_msg_s: float,
                 hb_age_wall_s: float, mag_detail: str = "", att_detail: str = "") -> list[str]:
        """Reasons to be in failsafe now (message time ``now_s``)."""
        lim = self.limits
        found: list[str] = []
        if not mag_age_s <= lim.mag_timeout_s:
            found.append(f"mag: no valid magnetometer sample for {_age(mag_age_s)}"
                         + (f" ({mag_detail})" if mag_detail else ""))
        if not att_age_s <= lim.att_timeout_s:
            found.append(f"attitude: no valid attitude for {_age(att_age_s)}"
                         + (f" ({att_detail})" if att_detail else ""))
        if not hb_age_msg_s <= lim.heartbeat_timeout_s or not hb_age_wall_s <= lim.heartbeat_timeout_s:
            which = "message" if not hb_age_msg_s <= lim.heartbeat_timeout_s else "wall"
            age = hb_age_msg_s if which == "message" else hb_age_wall_s
            found.append(f"heartbeat: flight controller silent for {_age(age)} ({which} time)")
        found += [f"{kind}: {text}" for kind, text in self.latched.items()]
        if found and not self.reasons:
            self.entered += 1
        if found:
            self.healthy_since_s = math.nan
        elif math.isnan(self.healthy_since_s):
            self.healthy_since_s = now_s
        self.reasons = found
        return found

    def resumed(self, now_s: float) -> bool:
        """Healthy for at least ``resume_s`` of message time."""
        return not self.reasons and math.isfinite(self.healthy_since_s) and \
            now_s - self.healthy_since_s >= self.limits.resume_s


def _age(age_s: float) -> str:
    return "ever" if not math.isfinite(age_s) else f"{age_s:.1f} s"


def diverged(distance_m: float, limit_m: float) -> bool:
    """True when the estimate and the geomagnetic fix are further apart than the limit.

    >>> diverged(60_000.0, 50_000.0), diverged(float("nan"), 50_000.0)
    (True, False)
    """
    return math.isfinite(distance_m) and distance_m > limit_m
