"""Reading a log for the evaluation: every sample of the log as arrays on the log's clock.

The samples come from :class:`companion.io.sensors.replay.LogReplaySource` (DataFlash ``.bin``
and MAVLink ``.tlog``), replayed as fast as possible.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.io.sensors.base import AttitudeSample, GpsSample, ImuSample, MagSample, StreamEnd
from companion.io.sensors.replay import LogReplaySource

__all__ = ["LogData", "read_log"]

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
    gps_utc_s: float | None

    @property
    def span_s(self) -> tuple[float, float]:
        return min(self.first_s.values()), max(self.last_s.values())


def _key(sample: MagSample | ImuSample | AttitudeSample | GpsSample) -> str:
    if isinstance(sample, AttitudeSample):
        return "ATT"
    base = {MagSample: "MAG", ImuSample: "IMU", GpsSample: "GPS"}[type(sample)]
    return base if sample.instance == 0 else f"{base}{sample.instance + 1}"


def read_log(path: str | os.PathLike[str], mag_instance: int = 0) -> LogData:
    """Replay the whole log as fast as possible and keep what the evaluation needs."""
    src = LogReplaySource(path, speed=None, instances=None, max_batch=100_000)
    counts: dict[str, int] = {}
    first: dict[str, float] = {}
    last: dict[str, float] = {}
    flagged: dict[str, int] = {}
    mag, imu, att, gps = [], [], [], []
    gps_utc: float | None = None
    end: StreamEnd | None = None
    with src:
        fmt = src.format or ""
        while not src.finished:
            for s in src.poll():
                if isinstance(s, StreamEnd):
                    end = s
                    continue
                key = _key(s)
                counts[key] = counts.get(key, 0) + 1
                first.setdefault(key, s.time_s)
                last[key] = s.time_s
                if not s.valid:
                    flagged[key] = flagged.get(key, 0) + 1
                    continue
                if isinstance(s, MagSample):
                    if s.instance == mag_instance:
                        mag.append((s.time_s, *s.mag_body_nt))
                elif isinstance(s, ImuSample):
                    if s.instance == 0:
                        imu.append((s.time_s, *s.accel_body_mps2, *s.gyro_body_radps))
                elif isinstance(s, AttitudeSample):
                    att.append((s.time_s, s.roll_rad, s.pitch_rad, s.yaw_rad))
                elif isinstance(s, GpsSample) and s.instance == 0 and s.has_3d_fix:
                    vn, ve = (s.vel_ned_mps[0], s.vel_ned_mps[1]) if s.vel_ned_mps else (math.nan, math.nan)
                    gps.append((s.time_s, s.lat_deg, s.lon_deg, s.alt_approx_m, vn, ve, s.h_acc_m))
                    if gps_utc is None and s.utc_s is not None:
                        gps_utc = s.utc_s - s.time_s  # UTC of log time 0
    assert end is not None  # a replay always ends with a StreamEnd

    def arr(rows: list, width: int) -> np.ndarray:
        a = np.array(rows, dtype=float).reshape(-1, width)
        return a[np.argsort(a[:, 0], kind="stable")] if len(a) else a

    att_a = arr(att, 4)
    if len(att_a):
        att_a[:, 1:] = np.unwrap(att_a[:, 1:], axis=0)
    gps_a = arr(gps, 7)
    if gps_utc is not None and len(gps_a):
        gps_utc = gps_utc + gps_a[0, 0]
    return LogData(Path(path), fmt, mag_instance, counts, first, last, flagged, end,
                   arr(mag, 4), arr(imu, 7), att_a, gps_a, gps_utc)
