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
               would never grow). The wall time is the time the companion spent waiting on its
               link since that heartbeat (``MavlinkLink.listened_s``): a dead flight controller
               sends nothing while the companion waits, whereas time the companion was busy or
               blocked (a long step, a loaded machine; in lockstep the world waiting for it) is
               not the flight controller's silence, and its frames of that time are still queued.
``params``     the parameter file was broken at start-up (never cleared in this run)
``nav``        the navigation core failed: solver failure, estimate diverged from the
               geomagnetic fix by more than [COMP_DIVERGE_KM] and beyond their joint 99.99 %
               ellipse (:func:`diverged`), or a non-finite command

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

import numpy as np

__all__ = ["DIVERGE_CHI2", "Health", "HealthLimits", "diverged"]


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


DIVERGE_CHI2 = 18.42   # chi-square, 2 degrees of freedom, 99.99 %: one false alarm in 10^4 steps


def diverged(gap_en_m: float | tuple[float, float], limit_m: float,
             cov_en_m2: np.ndarray | None = None) -> bool:
    """True when the estimate and the geomagnetic fix have come apart: further than ``limit_m``
    (COMP_DIVERGE_KM) **and**, when the covariance of their difference is known (``cov_en_m2``,
    2 x 2 east/north m^2: the estimate's plus the fix's), outside its 99.99 % ellipse
    (``DIVERGE_CHI2``). ``gap_en_m``: the fix minus the estimate (east, north, m), or only its
    length (then the kilometres alone judge).

    In kilometres alone, a filter that rightly does not follow every fix crossed the limit
    near the destination with 50-75 km of field-model error along the route while its own
    1-sigma said as much (ArduPilot SITL, full Pacific run: a restart there ended 147 km off).

    >>> diverged(60_000.0, 50_000.0), diverged(float("nan"), 50_000.0)
    (True, False)
    >>> wide = np.diag([40e3 ** 2, 40e3 ** 2])                 # a 40 km 1-sigma: 60 km is 1.5 sigma
    >>> diverged((60e3, 0.0), 50e3, wide), diverged((60e3, 0.0), 50e3, wide / 100.0)
    (False, True)
    """
    gap = np.atleast_1d(np.asarray(gap_en_m, dtype=float))
    distance = float(np.hypot(*gap)) if gap.size == 2 else float(gap[0])
    if not (math.isfinite(distance) and distance > limit_m):
        return False
    if gap.size != 2 or cov_en_m2 is None:
        return True
    cov = np.asarray(cov_en_m2, dtype=float)
    if cov.shape != (2, 2) or not np.all(np.isfinite(cov)):
        return True
    try:
        return float(gap @ np.linalg.solve(cov, gap)) > DIVERGE_CHI2
    except np.linalg.LinAlgError:
        return True
