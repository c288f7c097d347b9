"""DataFlash ``.bin`` and MAVLink ``.tlog`` logs into boots of :class:`LogData`.

The samples come from :class:`companion.io.sensors.replay.LogReplaySource`, replayed as fast
as possible, and their armed state and dates from :mod:`fcmpc.replay.events`. A log is split into
boots where the boot time of one kind of sample goes back by more than
:data:`fcmpc.replay.events.REBOOT_BACK_S` (a reboot inside a tlog): each boot has its own clock and
is evaluated on its own.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from companion.io.sensors.base import (
    AttitudeSample,
    GpsSample,
    ImuSample,
    MagSample,
    SampleFlag,
    SensorError,
    StreamEnd,
)
from companion.io.sensors.replay import LogReplaySource
from fcmpc.replay.events import GPS_RAW_SOURCE, REBOOT_BACK_S, BootEvents, read_events
from fcmpc.replay.logdata import LogData, arrays

__all__ = ["read_mavlink_boots"]


def _key(sample: MagSample | ImuSample | AttitudeSample | GpsSample) -> str:
    if isinstance(sample, AttitudeSample):
        return "ATT"
    base = {MagSample: "MAG", ImuSample: "IMU", GpsSample: "GPS"}[type(sample)]
    return base if sample.instance == 0 else f"{base}{sample.instance + 1}"


class _Boot:
    """The samples of one boot while the log is read."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}
        self.first: dict[str, float] = {}
        self.last: dict[str, float] = {}
        self.flagged: dict[str, int] = {}
        self.rows: dict[str, list[tuple[float, ...]]] = {"mag": [], "imu": [], "att": [], "gps": []}
        self.unix_minus_boot: float | None = None


def read_mavlink_boots(path: str | os.PathLike[str], fmt: str, mag_instance: int = 0) -> list[LogData]:
    """Every boot of a DataFlash or tlog file (``fmt`` from :func:`sniff_log_format`), oldest first."""
    boots = _read_samples(path, mag_instance)
    events = read_events(path, fmt)
    notes = []
    if len(events) != len(boots):
        notes.append(f"the sensor samples show {len(boots)} boot(s) but the other messages {len(events)}: "
                     "armed state and dates are matched by order")
    out = []
    for k, (b, end) in enumerate(boots):
        ev = events[k] if k < len(events) else BootEvents()
        dates = dict(ev.unix_minus_boot_s)
        if b.unix_minus_boot is not None:
            dates[GPS_RAW_SOURCE] = b.unix_minus_boot
        out.append(_log_data(Path(path), fmt, mag_instance, b, end, k, len(boots), ev, dates, list(notes)))
    return out


def _read_samples(path: str | os.PathLike[str], mag_instance: int) -> list[tuple[_Boot, StreamEnd]]:
    src = LogReplaySource(path, speed=None, instances=None, max_batch=100_000)
    boots = [_Boot()]
    end: StreamEnd | None = None
    with src:
        while not src.finished:
            for s in src.poll():
                if isinstance(s, StreamEnd):
                    end = s
                    continue
                key = _key(s)
                b = boots[-1]
                if key in b.last and s.time_s < b.last[key] - REBOOT_BACK_S:
                    b = _Boot()  # boot time went back: a reboot
                    boots.append(b)
                b.counts[key] = b.counts.get(key, 0) + 1
                b.first.setdefault(key, s.time_s)
                b.last[key] = s.time_s
                if not s.valid:
                    b.flagged[key] = b.flagged.get(key, 0) + 1
                    continue
                if isinstance(s, MagSample):
                    if s.instance == mag_instance:
                        b.rows["mag"].append((s.time_s, *s.mag_body_nt))
                elif isinstance(s, ImuSample):
                    if s.instance == 0:
                        b.rows["imu"].append((s.time_s, *s.accel_body_mps2, *s.gyro_body_radps))
                elif isinstance(s, AttitudeSample):
                    b.rows["att"].append((s.time_s, s.roll_rad, s.pitch_rad, s.yaw_rad))
                elif isinstance(s, GpsSample) and s.instance == 0 and s.has_3d_fix:
                    vn, ve = (s.vel_ned_mps[0], s.vel_ned_mps[1]) if s.vel_ned_mps else (math.nan, math.nan)
                    b.rows["gps"].append((s.time_s, s.lat_deg, s.lon_deg, s.alt_approx_m, vn, ve, s.h_acc_m))
                    if b.unix_minus_boot is None and s.utc_s is not None:
                        b.unix_minus_boot = s.utc_s - s.time_s
    if end is None:  # a replay always ends with a StreamEnd
        raise SensorError(f"replay of {path} ended without its end marker")
    last = len(boots) - 1
    return [(b, end if k == last else StreamEnd(max(b.last.values(), default=math.nan), SampleFlag.END,
                                                "ended by a reboot"))
            for k, b in enumerate(boots) if b.counts]


def _log_data(path: Path, fmt: str, mag_instance: int, b: _Boot, end: StreamEnd, k: int, n: int,
              ev: BootEvents, dates: dict[str, float], notes: list[str]) -> LogData:
    att = arrays(b.rows["att"], 4)
    if len(att):
        att[:, 1:] = np.unwrap(att[:, 1:], axis=0)
    return LogData(path, fmt, mag_instance, b.counts, b.first, b.last, b.flagged, end,
                   arrays(b.rows["mag"], 4), arrays(b.rows["imu"], 7), att, arrays(b.rows["gps"], 7),
                   boot=k, boots=n, armed=list(ev.armed), armed_source=ev.armed_source,
                   unix_minus_boot_s=dates, notes=notes)
