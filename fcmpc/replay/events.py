"""What a log says besides its sensors, per boot: armed state and the sources of the date.

One pass over a DataFlash ``.bin`` or MAVLink ``.tlog`` with pymavlink, on the same boot
clock as :class:`companion.io.sensors.replay.LogReplaySource` and with the same reboot rule
(:data:`REBOOT_BACK_S`): a boot ends where a message's boot time goes back by more than
that against the last message of its type.

Armed state:
  * tlog: ``HEARTBEAT.base_mode`` bit ``MAV_MODE_FLAG_SAFETY_ARMED`` (128) of the vehicle
    (the first system sending sensor data; ground stations' heartbeats, autopilot type
    ``MAV_AUTOPILOT_INVALID``, are ignored); a heartbeat has no time field, so its time is
    its recording timestamp moved onto the boot clock by the last boot-timed message.
  * DataFlash: ``EV`` records ``Id`` 10 (ARMED) and 11 (DISARMED), which carry no time in
    older logs (the time of the record before is used), and ``ARM`` records (``ArmState``).

Dates (UNIX time minus boot time, from the best source first):
  * ``GPS week and time of week``: DataFlash ``GPS`` (``GWk``/``GMS``, or ``Week``/``TimeMS``
    in Copter 3.3-era logs), first 3D fix; GPS time runs 18 s ahead of UTC (irrelevant here).
  * ``GPS_RAW_INT.time_usec``: a UNIX time when it is >= 1e14 us (some ArduPilot versions
    put boot time there instead, which carries no date).
  * ``SYSTEM_TIME.time_unix_usec``: the autopilot's UNIX time, when non-zero.
  * ``tlog recording timestamps``: the ground station's clock when it recorded the message.
"""
from __future__ import annotations

import datetime
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402  (after the environment is set)

from companion.io.sensors.replay import LogFormat  # noqa: E402

__all__ = ["BootEvents", "read_events", "utc_text", "REBOOT_BACK_S", "GPS_EPOCH_UNIX_S",
           "GPS_WEEK_SOURCE", "GPS_RAW_SOURCE", "SYSTEM_TIME_SOURCE", "TLOG_SOURCE"]

REBOOT_BACK_S = 1.0
GPS_EPOCH_UNIX_S = 315_964_800.0  # 1980-01-06 00:00 UTC
_BOOT_USEC_LIMIT = 1e14
_UNIX_MIN_S = 946_684_800.0   # 2000-01-01
_UNIX_MAX_S = 4_102_444_800.0  # 2100-01-01
ARMED_FLAG = 128  # MAV_MODE_FLAG_SAFETY_ARMED
GPS_WEEK_SOURCE = "GPS week and time of week"
GPS_RAW_SOURCE = "GPS_RAW_INT.time_usec"
SYSTEM_TIME_SOURCE = "SYSTEM_TIME.time_unix_usec"
TLOG_SOURCE = "tlog recording timestamps"


@dataclass
class BootEvents:
    """One boot's armed transitions ``(boot time s, armed)`` and date offsets by source."""

    armed: list[tuple[float, bool]] = field(default_factory=list)
    armed_source: str = ""
    unix_minus_boot_s: dict[str, float] = field(default_factory=dict)

    def set_armed(self, t: float, armed: bool, source: str) -> None:
        if not self.armed or self.armed[-1][1] != armed:
            self.armed.append((t, armed))
        if source not in self.armed_source.split(" and "):
            self.armed_source = f"{self.armed_source} and {source}" if self.armed_source else source

    def date(self, source: str, unix_minus_boot: float) -> None:
        if _UNIX_MIN_S <= unix_minus_boot <= _UNIX_MAX_S:
            self.unix_minus_boot_s.setdefault(source, unix_minus_boot)


class _Boots:
    """The reboot rule: per message type, boot time going back by more than REBOOT_BACK_S."""

    def __init__(self) -> None:
        self.boots: list[BootEvents] = [BootEvents()]
        self._last: dict[str, float] = {}

    def at(self, key: str, t: float) -> BootEvents:
        last = self._last.get(key)
        if last is not None and t < last - REBOOT_BACK_S:
            self.boots.append(BootEvents())
            self._last = {}
        self._last[key] = t
        return self.boots[-1]

    @property
    def current(self) -> BootEvents:
        return self.boots[-1]


def read_events(path: str | os.PathLike[str], fmt: str) -> list[BootEvents]:
    """The armed transitions and date sources of each boot of a DataFlash or tlog file."""
    if fmt == LogFormat.DATAFLASH:
        return _dataflash_events(Path(path))
    return _tlog_events(Path(path))


def _df_time(msg: Any) -> float | None:
    us = getattr(msg, "TimeUS", None)
    if us is not None:
        return us * 1e-6
    if msg.get_type() == "GPS" and getattr(msg, "T", None) is not None:
        return msg.T * 1e-3  # Copter 3.3: TimeMS is GPS time of week, T is boot time
    ms = getattr(msg, "TimeMS", None)
    return None if ms is None else ms * 1e-3


def _dataflash_events(path: Path) -> list[BootEvents]:
    from pymavlink import DFReader

    reader = DFReader.DFReader_binary(str(path))
    boots = _Boots()
    last_t = math.nan
    try:
        while (msg := reader.recv_match()) is not None:
            mtype = msg.get_type()
            t = _df_time(msg)
            if t is not None:
                boot = boots.at(mtype, t)
                last_t = t
            else:
                boot = boots.current
            if mtype == "EV" and getattr(msg, "Id", None) in (10, 11) and math.isfinite(last_t):
                boot.set_armed(last_t, msg.Id == 10, "DataFlash EV")
            elif mtype == "ARM" and t is not None and getattr(msg, "ArmState", None) is not None:
                boot.set_armed(t, bool(msg.ArmState), "DataFlash ARM")
            elif mtype == "GPS" and t is not None and getattr(msg, "Status", 0) >= 3:
                week = getattr(msg, "GWk", getattr(msg, "Week", None))
                tow_ms = getattr(msg, "GMS", None)
                if tow_ms is None and getattr(msg, "T", None) is not None:
                    tow_ms = getattr(msg, "TimeMS", None)
                if week and tow_ms is not None:
                    boot.date(GPS_WEEK_SOURCE, GPS_EPOCH_UNIX_S + int(week) * 604800.0 + tow_ms * 1e-3 - t)
    finally:
        reader.close()
    return boots.boots


def _tlog_events(path: Path) -> list[BootEvents]:
    reader = mavutil.mavlogfile(str(path))
    boots = _Boots()
    boot_minus_capture: float | None = None
    vehicle: int | None = None
    try:
        while (msg := reader.recv_match()) is not None:
            mtype = msg.get_type()
            if mtype == "BAD_DATA":
                continue
            src = msg.get_srcSystem()
            if mtype == "HEARTBEAT":
                if msg.autopilot == mavutil.mavlink.MAV_AUTOPILOT_INVALID or msg.type == mavutil.mavlink.MAV_TYPE_GCS:
                    continue
                vehicle = src if vehicle is None else vehicle
                if src == vehicle and boot_minus_capture is not None:
                    boots.current.set_armed(msg._timestamp + boot_minus_capture,
                                            bool(msg.base_mode & ARMED_FLAG), "HEARTBEAT base_mode")
                continue
            ms = getattr(msg, "time_boot_ms", None)
            us = getattr(msg, "time_usec", None)
            if ms is not None:
                t = ms * 1e-3
            elif us is not None and 0 < us < _BOOT_USEC_LIMIT:
                t = us * 1e-6
            else:
                if (mtype == "GPS_RAW_INT" and us and msg.fix_type >= 3 and boot_minus_capture is not None
                        and (vehicle is None or src == vehicle)):
                    # a UNIX time_usec: the GPS's own date, put on the boot clock by the recording
                    boots.current.date(GPS_RAW_SOURCE, us * 1e-6 - (msg._timestamp + boot_minus_capture))
                continue
            if vehicle is not None and src != vehicle:
                continue
            boot = boots.at(mtype, t)
            boot_minus_capture = t - msg._timestamp
            boot.date(TLOG_SOURCE, msg._timestamp - t)
            if mtype == "SYSTEM_TIME" and msg.time_unix_usec:
                boot.date(SYSTEM_TIME_SOURCE, msg.time_unix_usec * 1e-6 - t)
    finally:
        reader.close()
    return boots.boots


def utc_text(unix_s: float) -> str:
    """ISO date and time (UTC, to the second) of a UNIX time."""
    return datetime.datetime.fromtimestamp(unix_s, tz=datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S")
