"""What the evaluation reads from a log, whatever its format: one boot as arrays on its clock.

Readers: :mod:`fcmpc.replay.mavlog` (DataFlash ``.bin``, MAVLink ``.tlog``), :mod:`fcmpc.replay.ulog` (PX4),
:mod:`fcmpc.replay.csvlog` (CSV); :mod:`fcmpc.replay.reading` picks one by the file's first bytes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from companion.io.sensors.base import StreamEnd

__all__ = ["LogData", "arrays", "ULOG", "CSV"]

ULOG = "ulog"
CSV = "csv"


@dataclass
class LogData:
    """What the evaluation reads from a log, as arrays on the log's clock (seconds).

    ``counts``/``first_s``/``last_s`` are per message kind and instance, named like DataFlash
    (``MAG``, ``MAG2``, ``IMU3``, ``ATT``, ``GPS``) for either log format. ``mag``: t, x, y, z (nT,
    body) of ``mag_instance``, valid samples only. ``imu``: t, ax, ay, az (m/s^2), gx, gy, gz
    (rad/s) of instance 0. ``att``: t, roll, pitch, yaw (rad, yaw unwrapped). ``gps``: t, lat, lon,
    alt (m, ellipsoidal if known else MSL), v_north, v_east (m/s), h_acc (m) of 3D fixes.
    """

    path: Path
    format: str
    mag_instance: int
    counts: dict[str, int]
    first_s: dict[str, float]
    last_s: dict[str, float]
    flagged: dict[str, int]
    end: StreamEnd
    mag: np.ndarray
    imu: np.ndarray
    att: np.ndarray
    gps: np.ndarray
    boot: int = 0
    boots: int = 1
    armed: list[tuple[float, bool]] = field(default_factory=list)
    armed_source: str = ""
    unix_minus_boot_s: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def span_s(self) -> tuple[float, float]:
        return min(self.first_s.values()), max(self.last_s.values())

    @property
    def imu_rate_hz(self) -> float:
        """Median sample rate of IMU 0 (NaN with fewer than two samples)."""
        return _rate(self.imu[:, 0]) if len(self.imu) > 1 else math.nan

    def window(self, t0: float, t1: float) -> LogData:
        """The same log cut to ``t0 <= t <= t1`` (arrays only; counts stay the boot's)."""
        def cut(a: np.ndarray) -> np.ndarray:
            return a[(a[:, 0] >= t0) & (a[:, 0] <= t1)] if len(a) else a
        return replace(self, mag=cut(self.mag), imu=cut(self.imu), att=cut(self.att), gps=cut(self.gps),
                       armed=[e for e in self.armed if t0 <= e[0] <= t1])


def _rate(t: np.ndarray) -> float:
    dt = np.diff(t)
    dt = dt[dt > 0]
    return 1.0 / float(np.median(dt)) if len(dt) else math.nan


def arrays(rows: list, width: int) -> np.ndarray:
    """Rows as a float array sorted by time (column 0), shape (n, width) even when empty."""
    a = np.array(rows, dtype=float).reshape(-1, width)
    return a[np.argsort(a[:, 0], kind="stable")] if len(a) else a
