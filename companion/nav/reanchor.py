"""Re-anchoring: when consistently rejected fixes say the estimate, not the sensor, is wrong.

Every gate that judges a geomagnetic fix against the current estimate (the core's
``NAV_FIX_GATE_M``, the companion's plausibility check) takes that estimate as the truth. Once
the estimate is wrong by more than the gate (one accepted outlier, a wrong contour crossing,
dead reckoning that drifted while fixes were weak), every later *good* fix looks like a jump and
is rejected: the gate locks in, and the vehicle flies its last course away from the destination
(ArduPilot SITL, full Pacific run: one outlier accepted, the next 40 periods rejected as
130-160 km jumps, 333 km to go after 26 h).

The flight controllers' own estimators answer this the same way: EKF3 and EKF2 reset their
position to GPS once its innovations have failed the gate for a timeout. Here the test is
sharper than a timeout. Each rejected fix is an offset from the dead-reckoned prediction,
``o_k = fix_k - prediction_k`` (east, north, m). An estimate that is off by ``e`` gives
``o_k = -e + noise`` on every step, the same vector, because the prediction moves with the
commanded velocity as the vehicle does. A disturbed sensor (a spike, a turn transient) gives
offsets that scatter. So after ``steps`` rejections in a row whose offsets all lie within
``tolerance_m`` of their mean, the estimate is shifted by the newest offset and the fix is
taken; an accepted fix clears the run. The shifted estimate gets a position 1-sigma of
``tolerance_m / 2`` unless the caller knows the fix's noise better.

What it cannot tell apart: a sensor offset that stays constant in position (a calibration jump
that every later fix inherits) also gives agreeing offsets. The |F| band catches such offsets
that change F; for the rest, with no independent position, the measurement is all there is,
and EKF3 makes the same choice for GPS.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ReanchorSettings", "OffsetConsensus"]


@dataclass(frozen=True)
class ReanchorSettings:
    """``steps`` rejections in a row (0: never re-anchor, the gate stands), their offsets within
    ``tolerance_m`` of their mean (m; the caller may widen it by the fixes' own noise)."""

    steps: int = 3
    tolerance_m: float = 5000.0


@dataclass
class OffsetConsensus:
    """The run of consecutive rejected fixes' offsets, and whether they agree.

    >>> c = OffsetConsensus(ReanchorSettings(steps=3, tolerance_m=2000.0))
    >>> [c.rejected(np.array([60e3 + d, -40e3])) is not None for d in (0.0, 800.0, -500.0)]
    [False, False, True]
    >>> c.rejected(np.array([10e3, 5e3])) is None    # a new run starts after a re-anchor
    True
    """

    settings: ReanchorSettings = ReanchorSettings()
    offsets: list[np.ndarray] = field(default_factory=list)
    reanchors: int = 0

    def clear(self) -> None:
        """A fix passed the gate, or was rejected for another reason (the sensor, not the
        estimate): the run of rejections is over."""
        self.offsets.clear()

    def rejected(self, offset_en_m: np.ndarray, extra_tolerance_m: float = 0.0) -> np.ndarray | None:
        """A fix was rejected ``offset_en_m`` (east, north, m) from the prediction. Returns the
        shift to apply to the estimate (the newest offset) when the run's last ``steps`` offsets
        agree within ``tolerance_m + extra_tolerance_m`` of their mean, else None."""
        offset = np.asarray(offset_en_m, dtype=float)
        n = self.settings.steps
        if n <= 0 or offset.shape != (2,) or not np.all(np.isfinite(offset)):
            self.offsets.clear()
            return None
        self.offsets.append(offset)
        del self.offsets[:-n]
        if len(self.offsets) < n:
            return None
        run = np.stack(self.offsets)
        spread = float(np.max(np.hypot(*(run - run.mean(axis=0)).T)))
        if spread > self.settings.tolerance_m + max(extra_tolerance_m, 0.0):
            return None
        self.offsets.clear()
        self.reanchors += 1
        return offset
