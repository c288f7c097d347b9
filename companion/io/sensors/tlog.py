"""MAVLink telemetry logs (``.tlog``) for the log replay source: the boot clock and sample conversion.

A tlog stamps each message with the ground station's UNIX time; the vehicle's own times are
boot times (``time_boot_ms``) or UNIX times (GPS ``time_usec``). :class:`_TlogClock` puts every
message on the vehicle's boot clock, boot by boot; :func:`_tlog_convert` turns one message into
:mod:`companion.io.sensors.base` samples. Used by :mod:`companion.io.sensors.replay`.
"""
from __future__ import annotations

import math
import os
from typing import Any

# pymavlink reads MAVLINK20 at import time; without it tlogs parse as MAVLink 1 first.
os.environ.setdefault("MAVLINK20", "1")


from companion import wrap_2pi  # noqa: E402
from companion.io.sensors.base import (  # noqa: E402
    AttitudeSample,
    GpsSample,
    ImuSample,
    MagSample,
)
from companion.io.sensors.mag_units import GAUSS_TO_NT, count_to_nt  # noqa: E402

__all__: list[str] = []   # used by companion.io.sensors.replay only


GRAVITY_MPS2 = 9.80665
_BOOT_USEC_LIMIT = 1e14  # time_usec below this (3 years) is time since boot, above UNIX time

_TLOG_TYPES = frozenset({"ATTITUDE", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3",
                         "HIGHRES_IMU", "GPS_RAW_INT", "GPS2_RAW", "SYSTEM_TIME"})


class _TlogClock:
    """Puts every tlog message on the vehicle's boot clock.

    A reboot (boot time going back by more than ``REBOOT_BACK_S``) forgets the UNIX-minus-boot
    offset of the previous boot, so UNIX stamps are not put on the old boot's clock until the
    new boot's SYSTEM_TIME arrives (the recording timestamps bridge the gap).
    """

    REBOOT_BACK_S = 1.0

    def __init__(self) -> None:
        self.unix_minus_boot: float | None = None
        self.boot_minus_capture: float | None = None
        self.last_boot_s: float | None = None

    def _seen(self, t: float) -> None:
        if self.last_boot_s is not None and t < self.last_boot_s - self.REBOOT_BACK_S:
            self.unix_minus_boot = None  # a reboot: the old offset belongs to the old boot
        self.last_boot_s = t

    def system_time(self, msg: Any) -> None:
        self._seen(msg.time_boot_ms * 1e-3)
        if msg.time_unix_usec:
            self.unix_minus_boot = msg.time_unix_usec * 1e-6 - msg.time_boot_ms * 1e-3

    def _boot(self, t: float, msg: Any) -> float:
        self._seen(t)
        self.boot_minus_capture = t - msg._timestamp
        return t

    def time_s(self, msg: Any) -> float | None:
        ms = getattr(msg, "time_boot_ms", None)
        if ms is not None:
            return self._boot(ms * 1e-3, msg)
        us = getattr(msg, "time_usec", 0)
        if 0 < us < _BOOT_USEC_LIMIT:
            return self._boot(us * 1e-6, msg)
        if us and self.unix_minus_boot is not None:
            return us * 1e-6 - self.unix_minus_boot
        if self.boot_minus_capture is not None:
            return msg._timestamp + self.boot_minus_capture
        return None


def _tlog_convert(msg: Any, mtype: str, t: float,
                  highres_nt_per_unit: float = GAUSS_TO_NT) -> list[MagSample | ImuSample | AttitudeSample | GpsSample]:
    """One message's samples; ``highres_nt_per_unit``: the recording autopilot's HIGHRES_IMU unit."""
    if mtype == "ATTITUDE":
        return [AttitudeSample(t, msg.roll, msg.pitch, wrap_2pi(msg.yaw))]
    if mtype in ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"):
        if mtype == "RAW_IMU":
            instance = int(getattr(msg, "id", 0) or 0)
        else:
            instance = {"SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}[mtype]
        g = GRAVITY_MPS2 * 1e-3
        temp = getattr(msg, "temperature", 0)
        return [
            ImuSample(t, (msg.xacc * g, msg.yacc * g, msg.zacc * g),
                      (msg.xgyro * 1e-3, msg.ygyro * 1e-3, msg.zgyro * 1e-3),
                      temp * 0.01 if temp else None, instance),
            MagSample(t, (count_to_nt(msg.xmag), count_to_nt(msg.ymag), count_to_nt(msg.zmag)), instance),
        ]
    if mtype == "HIGHRES_IMU":
        instance = int(getattr(msg, "id", 0) or 0)
        updated = msg.fields_updated
        out: list[MagSample | ImuSample | AttitudeSample | GpsSample] = []
        if updated & 0x3F:
            out.append(ImuSample(t, (msg.xacc, msg.yacc, msg.zacc), (msg.xgyro, msg.ygyro, msg.zgyro),
                                 msg.temperature, instance))
        if updated & 0x1C0:
            k = highres_nt_per_unit
            out.append(MagSample(t, (msg.xmag * k, msg.ymag * k, msg.zmag * k), instance))
        return out
    if mtype in ("GPS_RAW_INT", "GPS2_RAW"):
        us = msg.time_usec
        utc_s = us * 1e-6 if us >= _BOOT_USEC_LIMIT else None
        return [_tlog_gps(msg, t, 0 if mtype == "GPS_RAW_INT" else 1, utc_s)]
    return []


def _tlog_gps(msg: Any, t: float, instance: int, utc_s: float | None) -> GpsSample:
    vel = None
    if msg.vel != 0xFFFF and msg.cog != 0xFFFF:
        c = math.radians(msg.cog * 0.01)
        speed = msg.vel * 0.01
        vel = (speed * math.cos(c), speed * math.sin(c), math.nan)
    h_acc = getattr(msg, "h_acc", 0)
    v_acc = getattr(msg, "v_acc", 0)
    alt_ell = getattr(msg, "alt_ellipsoid", 0)
    return GpsSample(
        time_s=t, lat_deg=msg.lat / 1e7, lon_deg=msg.lon / 1e7,
        alt_m=alt_ell * 1e-3 if alt_ell else math.nan, fix_type=int(msg.fix_type),
        h_acc_m=h_acc * 1e-3 if h_acc else math.nan, v_acc_m=v_acc * 1e-3 if v_acc else math.nan,
        vel_ned_mps=vel, num_sv=int(msg.satellites_visible) if msg.satellites_visible != 255 else 0,
        alt_msl_m=msg.alt * 1e-3, utc_s=utc_s, instance=instance)
