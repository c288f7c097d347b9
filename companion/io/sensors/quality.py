"""Plausibility checks that hardware sources apply before handing out a sample.

Both checks look only at consecutive readings of one sensor, so they are cheap and need
no model: a *stuck* sensor repeats the identical raw reading (real sensors always show a
few LSB of noise), a *spike* is a jump of the field magnitude that no vehicle rotation
can produce (rotation changes the components, not the magnitude).
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Hashable
from dataclasses import dataclass

from companion.io.sensors.base import SampleFlag, Vector3

__all__ = ["MagChecks", "MagQualityCheck", "RepeatDetector", "FrozenDetector"]

_NONE, _STUCK = SampleFlag.NONE, SampleFlag.STUCK   # an enum member's lookup is a Python call: once here


class RepeatDetector:
    """Flags STUCK once the same raw reading has been seen ``limit`` times in a row.

    >>> d = RepeatDetector(limit=3)
    >>> [d.check((1, 2, 3)) for _ in range(4)][-1] == SampleFlag.STUCK
    True
    """

    def __init__(self, limit: int) -> None:
        if limit < 2:
            raise ValueError(f"stuck limit must be >= 2 repeats, got {limit}")
        self.limit = limit
        self._last: Hashable | None = None
        self._repeats = 0

    def check(self, raw: Hashable) -> SampleFlag:
        if raw == self._last:
            self._repeats += 1
        else:
            self._last = raw
            self._repeats = 1
        return SampleFlag.STUCK if self._repeats >= self.limit else SampleFlag.NONE


STILL_RADPS = math.radians(0.5)   # a gyro reading below this may be bias (uncalibrated MEMS), not a turn


class FrozenDetector:
    """Flags STUCK when the raw reading stays identical while the vehicle turned.

    A quiet magnetometer (ArduPilot SITL's is noise-free; a real one at 10 Hz with a coarse LSB
    can repeat its value) may repeat its reading for as long as the vehicle holds its
    attitude. A *frozen* one repeats it although the body turned: a rotation of ``min_turn_rad``
    changes the body-frame field by ``|B| min_turn_rad`` (about 7 mG per degree at 42 000 nT, seven
    LSB of a MAVLink SCALED_IMU reading), so the judgement needs ``limit`` identical readings in a
    row *and* a net rotation of at least ``min_turn_rad`` (1 deg) within the last ``window_s`` (5 s)
    of the repetition, measured by integrating the gyro vector (``|sum omega dt|``, the raw rate
    sensor: an attitude *estimate* can wander while the vehicle is still, e.g. an EKF without GPS,
    and would flag a good sensor). The *net* rotation, not the path: a boat rocking in waves
    returns to the attitude, and the field to the reading, it had, and summing ``|omega| dt`` also
    sums the gyro's noise (a stationary ArduPilot SITL boat was called stuck after hours). Within a
    *window*, not since the repetition began: the gyro's bias integrates without bound (ArduPilot
    SITL's boat, still on a noise-free compass, reached 2 deg in 93 s and, judged frozen for good,
    never armed). The rate is the gyro's minus its slowly learned bias (an exponential mean over
    ``bias_tau_s``, 120 s, started from the first reading when it is below ``STILL_RADPS``):
    ArduPilot SITL's still boat reported 2 mrad/s on every axis (0.11 deg/s) while its noise-free
    compass repeated its reading; waves average out of that mean, a turn of a few tens of seconds
    barely moves it, and a bias it has not yet learned integrates to 0.55 deg in the 5 s window,
    under the 1 deg. A wave roll of the stand-in's 3 deg (8 s period) turns the boat 1 deg within
    about 2 s, so with 20 readings at 10 Hz a frozen sensor is judged 2-3 s after it froze
    (it took 6 s with 2 deg in 10 s). Without any gyro nothing is flagged.

    :attr:`repeating_since_s` is the time of the first of the identical readings: once the sensor
    is judged frozen, the readings since then were not fresh either (the failsafe's age counts
    from there, so the HOLD follows the judgement at once).

    >>> d = FrozenDetector(limit=3, min_turn_rad=0.02)
    >>> [d.check((1, 2, 3), k * 0.1, (0.0, 0.0, 0.0)) for k in range(5)][-1] == SampleFlag.NONE   # still
    True
    >>> d.check((1, 2, 3), 0.5, (0.0, 0.0, 0.5)) == SampleFlag.STUCK                               # turning
    True
    """

    def __init__(self, limit: int, min_turn_rad: float = math.radians(1.0), window_s: float = 5.0,
                 bias_tau_s: float = 120.0) -> None:
        if limit < 2:
            raise ValueError(f"stuck limit must be >= 2 repeats, got {limit}")
        if not window_s > 0.0:
            raise ValueError(f"frozen-compass window must be > 0 s, got {window_s}")
        self.limit = limit
        self.min_turn_rad = min_turn_rad
        self.window_s = window_s
        self.bias_tau_s = bias_tau_s
        self._bias: list[float] | None = None      # rad/s, the gyro's slowly learned bias
        self._last: Hashable | None = None
        self._repeats = 0
        self._turns: deque[tuple[float, float, float, float]] = deque()   # (time_s, rotation vector, rad)
        self._time_s = math.nan
        self.repeating_since_s = math.nan   # time of the first of the identical readings
        self._frozen = False            # judged frozen: stays so until the reading changes

    def check(self, raw: Hashable, time_s: float, gyro_radps: tuple[float, float, float] | None) -> SampleFlag:
        dt = time_s - self._time_s if math.isfinite(self._time_s) else 0.0
        self._time_s = time_s
        rate = None
        isfinite = math.isfinite
        if gyro_radps is not None and isfinite(gyro_radps[0]) and isfinite(gyro_radps[1]) \
                and isfinite(gyro_radps[2]):
            gx, gy, gz = gyro_radps
            bias = self._bias
            if bias is None:   # a first reading at rest is the bias; one while turning is not
                still = math.sqrt(gx * gx + gy * gy + gz * gz) <= STILL_RADPS
                bias = self._bias = [gx, gy, gz] if still else [0.0, 0.0, 0.0]
            elif 0.0 < dt < 1.0:
                gain = dt / self.bias_tau_s
                bias = self._bias = [bias[0] + gain * (gx - bias[0]), bias[1] + gain * (gy - bias[1]),
                                     bias[2] + gain * (gz - bias[2])]
            rate = (gx - bias[0], gy - bias[1], gz - bias[2])
        if raw != self._last:
            self._last, self._repeats, self._frozen = raw, 1, False
            self.repeating_since_s = time_s
            self._turns.clear()
            return _NONE
        self._repeats += 1
        turns = self._turns
        if rate is not None and 0.0 < dt < 1.0:
            turns.append((time_s, rate[0] * dt, rate[1] * dt, rate[2] * dt))
        while turns and turns[0][0] <= time_s - self.window_s:
            turns.popleft()
        turned = math.sqrt(sum(sum(t[k] for t in turns) ** 2 for k in (1, 2, 3)))
        # once frozen, the same reading stays frozen: a rocking boat turns back to where the sensor
        # froze (the net rotation falls under min_turn_rad again), which proves nothing new
        if self._frozen or (self._repeats >= self.limit and turned >= self.min_turn_rad):
            self._frozen = True
            return _STUCK
        return _NONE


@dataclass(frozen=True)
class MagChecks:
    """Thresholds of :class:`MagQualityCheck`.

    ``stuck_count``: identical raw readings in a row that mean a frozen sensor.
    ``spike_nt``: largest believable change of the field magnitude between consecutive
    samples (at 100 Hz, motor-current interference stays well below 10 000 nT).
    ``rebase_count``: consecutive spikes after which the new level is accepted as real
    (the vehicle moved next to iron) instead of flagging it forever.
    """

    stuck_count: int = 10
    spike_nt: float = 15000.0
    rebase_count: int = 3

    def __post_init__(self) -> None:
        if self.stuck_count < 2:
            raise ValueError(f"MagChecks.stuck_count must be >= 2, got {self.stuck_count}")
        if not self.spike_nt > 0.0:
            raise ValueError(f"MagChecks.spike_nt must be > 0 nT, got {self.spike_nt}")
        if self.rebase_count < 1:
            raise ValueError(f"MagChecks.rebase_count must be >= 1, got {self.rebase_count}")


class MagQualityCheck:
    """Stuck and spike detection for one magnetometer."""

    def __init__(self, checks: MagChecks | None = None) -> None:
        self.checks = checks or MagChecks()
        self._repeat = RepeatDetector(self.checks.stuck_count)
        self._reference_nt: float | None = None
        self._spikes = 0

    def check(self, raw: Hashable, field_nt: Vector3) -> SampleFlag:
        """Flags for a reading; ``raw`` is the undecoded value used for the stuck test."""
        flags = self._repeat.check(raw)
        magnitude = math.sqrt(sum(c * c for c in field_nt))
        if self._reference_nt is None:
            self._reference_nt = magnitude
        elif abs(magnitude - self._reference_nt) > self.checks.spike_nt:
            self._spikes += 1
            if self._spikes >= self.checks.rebase_count:
                # A level that persists is the field, not a glitch: accept it.
                self._reference_nt = magnitude
                self._spikes = 0
            return flags | SampleFlag.SPIKE
        else:
            self._reference_nt = magnitude
            self._spikes = 0
        return flags
