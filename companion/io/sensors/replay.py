"""Replay of recorded flights: ArduPilot DataFlash ``.bin`` logs and MAVLink ``.tlog`` files.

Both are read with pymavlink (``mavutil.mavlink_connection``); the format is recognised
from the first bytes, so a file that is neither gives a :class:`SensorError` before
pymavlink sees it (pymavlink would print a line per unparsable byte).

DataFlash messages used, with what the ArduPilot source says about them:

* ``MAG``/``MAG2``/``MAG3`` (or ``MAG`` with instance field ``I`` in newer logs):
  ``MagX/Y/Z`` in milligauss (1 mG = 100 nT), body frame (after the board and compass
  orientation rotations). They are ``Compass::get_field()``, which is the *corrected*
  field: ``AP_Compass_Backend::correct_field`` adds the offsets ``COMPASS_OFS`` (logged
  as ``OfsX/Y/Z``), applies the diagonal/off-diagonal soft-iron matrix and adds the
  motor compensation (``MOfsX/Y/Z``). The raw sensor reading would be
  ``Mag - Ofs - MOfs`` only when the soft-iron matrix is the identity. This source
  reports ``MagX/Y/Z`` as they are: the calibrated field. ``Health`` = 0 -> UNHEALTHY.
* ``IMU``/``IMU2``/``IMU3`` (or ``I``): ``AccX..`` m/s^2 (specific force), ``GyrX..``
  rad/s, ``Temp`` degC.
* ``ATT``: ``Roll``, ``Pitch``, ``Yaw`` in degrees; yaw is the flight controller's true
  heading estimate, which itself used the compass and a declination.
* ``GPS``/``GPS2`` (or ``I``): ``Status`` (same numbers as MAVLink's fix type), ``Lat``,
  ``Lng`` degrees, ``Alt`` metres above *mean sea level*, ``Spd``, ``GCrs``, ``VZ``,
  ``NSats``; accuracies come from ``GPA`` (``HAcc``, ``VAcc``) or, in Copter 3.3-era
  logs, ``UBX3`` (``hAcc``, ``vAcc``), matched by time.

Time: ``TimeUS`` (us since boot) or, in older logs, ``TimeMS``; old ``GPS`` records
carry GPS time-of-week in ``TimeMS`` and boot time in ``T``, which is what is used.

tlog messages: ``ATTITUDE``; ``RAW_IMU`` in ArduPilot's units (mG, mrad/s, mG --
the MAVLink spec leaves RAW_IMU units open); ``SCALED_IMU``/``2``/``3`` (mG, mrad/s,
mgauss; integer magnetometer counts at the midpoint of their truncation,
:mod:`~companion.io.sensors.mag_units`); ``HIGHRES_IMU`` (SI; gauss, or ArduPilot's 1e-6 gauss
when the log's autopilot HEARTBEAT says ArduPilot); ``GPS_RAW_INT``/``GPS2_RAW``. Time is the vehicle's
boot time from ``time_boot_ms``/``time_usec``; a ``time_usec`` that is UNIX time (ArduPilot's
GPS_RAW_INT) is converted with SYSTEM_TIME, or failing that with the recording timestamps.
For each sensor instance the first message type seen provides it (an autopilot sending
RAW_IMU and SCALED_IMU for the same IMU does not produce duplicates). Only the first
system id that sends sensor data is replayed.

Pacing: as fast as possible (``speed=None``) or at ``speed`` times the recorded rate.
Pacing is the one place wall time enters; ``clock`` and ``sleep`` are injectable.

The end of the log is a :class:`StreamEnd`; TRUNCATED is set when bytes of an incomplete
record remain (a log cut while writing), which is reported, not raised.
"""
from __future__ import annotations

import dataclasses
import math
import os
import struct
import time
from collections import deque
from collections.abc import Callable, Collection, Iterator
from pathlib import Path
from typing import Any

# pymavlink reads MAVLINK20 at import time; without it tlogs parse as MAVLink 1 first.
os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402  (after the environment is set)

from companion import wrap_2pi  # noqa: E402
from companion.io.link.conventions import conventions_for  # noqa: E402
from companion.io.sensors.mag_units import highres_nt_per_unit  # noqa: E402
from companion.io.sensors.tlog import _TLOG_TYPES, _TlogClock, _tlog_convert  # noqa: E402
from companion.io.sensors.base import (  # noqa: E402
    AttitudeSample,
    GpsSample,
    ImuSample,
    MagSample,
    Sample,
    SampleFlag,
    SampleKind,
    SensorError,
    SensorSource,
    StreamEnd,
)

__all__ = ["LogFormat", "LogReplaySource", "log_head", "sniff_log_format"]

MILLIGAUSS_TO_NT = 100.0
GAUSS_TO_NT = 100_000.0
GRAVITY_MPS2 = 9.80665
_ACC_MATCH_S = 0.05  # a GPA/UBX3 record belongs to the GPS record within this time
_BOOT_USEC_LIMIT = 1e14  # time_usec below this (3 years) is time since boot, above UNIX time


class LogFormat:
    DATAFLASH = "dataflash"
    TLOG = "tlog"


def log_head(path: str | os.PathLike[str]) -> bytes:
    """The first 16 bytes of a log, which tell its format; :class:`SensorError` when it cannot be read."""
    try:
        with Path(path).open("rb") as f:
            return f.read(16)
    except OSError as err:
        raise SensorError(f"replay: cannot read log {str(path)!r}: {err}") from err


def sniff_log_format(path: str | os.PathLike[str], head: bytes | None = None) -> str:
    """``"dataflash"`` or ``"tlog"`` from the first bytes (``head``: :func:`log_head`, read when not
    given), else :class:`SensorError`."""
    p = Path(path)
    head = log_head(p) if head is None else head
    if not head:
        raise SensorError(f"replay: log {str(p)!r} is empty")
    # A DataFlash log starts with the FMT record describing FMT: A3 95 80.
    if head[:3] == b"\xa3\x95\x80":
        return LogFormat.DATAFLASH
    if len(head) >= 9 and head[8] in (0xFE, 0xFD):
        (usec,) = struct.unpack(">Q", head[:8])
        if 946_684_800e6 <= usec <= 4_102_444_800e6:  # 2000 .. 2100
            return LogFormat.TLOG
    raise SensorError(
        f"replay: {str(p)!r} is neither an ArduPilot DataFlash .bin log (starts A3 95 80) "
        f"nor a MAVLink .tlog (8-byte timestamp, then FE or FD); it starts {head[:9].hex(' ')}")


class LogReplaySource(SensorSource):
    """Samples from a recorded log, in log order, optionally paced to recorded time.

    ``instances``: sensor instances to replay (0 = primary MAG/IMU/GPS); None for all.
    ``max_batch``: most samples returned by one ``poll``.
    """

    provides = frozenset({SampleKind.MAG, SampleKind.ATTITUDE, SampleKind.GPS})

    time_base = "log"

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        speed: float | None = None,
        instances: Collection[int] | None = (0,),
        max_batch: int = 1000,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        name: str | None = None,
    ) -> None:
        super().__init__()
        if speed is not None and not speed > 0.0:
            raise ValueError(f"replay speed must be > 0 (or None for as fast as possible), got {speed}")
        if max_batch < 1:
            raise ValueError(f"max_batch must be >= 1, got {max_batch}")
        self.path = Path(path)
        self.speed = speed
        self.instances = None if instances is None else frozenset(instances)
        self.max_batch = max_batch
        self._clock = clock
        self._sleep = sleep
        self.name = name or f"replay:{self.path.name}"
        self.format: str | None = None
        self._reader: Any = None
        self._samples: Iterator[Sample] | None = None
        self._ahead: deque[Sample] = deque()
        self._finished = False
        self._t0: float | None = None
        self._wall0 = 0.0

    @property
    def finished(self) -> bool:
        return self._finished

    # -- opening -------------------------------------------------------------------------

    def open(self) -> None:
        self.close()  # opening again restarts the replay from the beginning
        self.format = sniff_log_format(self.path)
        try:
            if self.format == LogFormat.DATAFLASH:
                if self.path.suffix.lower() == ".bin":
                    self._reader = mavutil.mavlink_connection(str(self.path))
                else:  # mavlink_connection picks the reader by extension
                    from pymavlink import DFReader

                    self._reader = DFReader.DFReader_binary(str(self.path))
                self._samples = self._dataflash_samples()
            else:
                self._reader = mavutil.mavlogfile(str(self.path))
                self._samples = self._tlog_samples()
        except (OSError, ValueError, struct.error) as err:
            raise SensorError(f"{self.name}: pymavlink cannot read {str(self.path)!r}: {err}") from err
        self._ahead.clear()
        self._finished = False
        self._t0 = None

    def close(self) -> None:
        if self._reader is not None:
            try:
                self._reader.close()
            except (OSError, ValueError, AttributeError):
                pass  # already closed, or a reader without close(): nothing to release
        self._reader = None
        self._samples = None

    # -- pacing --------------------------------------------------------------------------

    def _peek(self) -> Sample | None:
        if not self._ahead and self._samples is not None:
            nxt = next(self._samples, None)
            if nxt is not None:
                self._ahead.append(nxt)
        return self._ahead[0] if self._ahead else None

    def poll(self, timeout_s: float = 0.0) -> list[Sample]:
        """The next samples in log order; paced when ``speed`` is set."""
        if self._samples is None:
            if self._finished:
                return []
            raise SensorError(f"{self.name}: poll() before open()")
        out: list[Sample] = []
        deadline = self._clock() + timeout_s
        while len(out) < self.max_batch:
            nxt = self._peek()
            if nxt is None:
                break
            if self.speed is not None and not isinstance(nxt, StreamEnd):
                now = self._clock()
                if self._t0 is None:
                    self._t0, self._wall0 = nxt.time_s, now
                due = self._wall0 + (nxt.time_s - self._t0) / self.speed
                if due > now:
                    if out:
                        break
                    if due > deadline:
                        if deadline > now:
                            self._sleep(deadline - now)
                        break
                    self._sleep(due - now)
            out.append(self._ahead.popleft())
            if isinstance(out[-1], StreamEnd):
                self._finished = True
                self._samples = None
                break
        self.stats.count(out)
        return out

    def _wanted(self, instance: int) -> bool:
        return self.instances is None or instance in self.instances

    # -- DataFlash -----------------------------------------------------------------------

    def _dataflash_samples(self) -> Iterator[Sample]:
        reader = self._reader
        pending_gps: GpsSample | None = None
        accuracy: dict[int, tuple[float, float, float]] = {}  # instance -> (t, h, v)
        imu_errors: dict[int, tuple[int, int]] = {}
        last_time = math.nan
        while True:
            msg = reader.recv_match()
            if msg is None:
                break
            kind = _DF_KINDS.get(msg.get_type())
            if kind is None:
                continue
            base, default_instance = kind
            t = _df_time(msg, base)
            if t is None:
                continue
            last_time = t
            instance = _df_instance(msg, default_instance)

            if base == "ACC":
                h = _first(msg, "HAcc", "hAcc")
                v = _first(msg, "VAcc", "vAcc")
                if h is not None and v is not None:
                    accuracy[instance] = (t, float(h), float(v))
                    if (pending_gps is not None and pending_gps.instance == instance
                            and abs(pending_gps.time_s - t) <= _ACC_MATCH_S):
                        yield dataclasses.replace(pending_gps, h_acc_m=float(h), v_acc_m=float(v))
                        pending_gps = None
                continue
            if pending_gps is not None:
                yield pending_gps  # no accuracy record followed it
                pending_gps = None
            if base != "ATT" and not self._wanted(instance):
                continue

            if base == "MAG":
                health = getattr(msg, "Health", None)
                flags = SampleFlag.UNHEALTHY if health is not None and not health else SampleFlag.NONE
                yield MagSample(t, (msg.MagX * MILLIGAUSS_TO_NT, msg.MagY * MILLIGAUSS_TO_NT,
                                    msg.MagZ * MILLIGAUSS_TO_NT), instance, flags)
            elif base == "IMU":
                yield ImuSample(t, (msg.AccX, msg.AccY, msg.AccZ), (msg.GyrX, msg.GyrY, msg.GyrZ),
                                _first(msg, "Temp", "T"), instance, _imu_flags(msg, instance, imu_errors))
            elif base == "ATT":
                yield AttitudeSample(t, math.radians(msg.Roll), math.radians(msg.Pitch),
                                     wrap_2pi(math.radians(msg.Yaw)))
            else:  # GPS
                sample = _df_gps(msg, t, instance)
                acc = accuracy.get(instance)
                if acc is not None and abs(acc[0] - t) <= _ACC_MATCH_S:
                    yield dataclasses.replace(sample, h_acc_m=acc[1], v_acc_m=acc[2])
                else:
                    pending_gps = sample  # newer logs write GPA right after GPS
        if pending_gps is not None:
            yield pending_gps
        # DFReader_binary stops at the first record it cannot complete; bytes left over
        # mean the log was cut inside a record.
        offset = getattr(reader, "offset", None)
        length = getattr(reader, "data_len", None)
        left = (length - offset) if offset is not None and length is not None else 0
        yield _end(last_time, left)

    # -- tlog ----------------------------------------------------------------------------

    def _tlog_samples(self) -> Iterator[Sample]:
        reader = self._reader
        state = _TlogClock()
        owner: dict[tuple[str, int], str] = {}  # (kind, instance) -> message type
        system_id: int | None = None
        highres_unit = GAUSS_TO_NT
        consumed = 0
        last_time = math.nan
        while True:
            msg = reader.recv_match()
            if msg is None:
                break
            mtype = msg.get_type()
            if mtype == "BAD_DATA":
                consumed += len(msg.get_msgbuf())
                self.stats.record_error("tlog: unparsable bytes")
                continue
            consumed += 8 + len(msg.get_msgbuf())
            if mtype == "HEARTBEAT" and msg.get_srcComponent() == 1 and msg.autopilot != mavutil.mavlink.MAV_AUTOPILOT_INVALID:
                highres_unit = highres_nt_per_unit(conventions_for(msg.autopilot).family)   # its HIGHRES_IMU unit
            if mtype not in _TLOG_TYPES:
                continue
            src = msg.get_srcSystem()
            if system_id is None and mtype != "SYSTEM_TIME":
                system_id = src
            if src != system_id and system_id is not None:
                continue
            if mtype == "SYSTEM_TIME":
                state.system_time(msg)
                continue
            t = state.time_s(msg)
            if t is None:
                self.stats.dropped += 1  # a UNIX-time stamp before any boot-time reference
                continue
            last_time = t
            for sample in _tlog_convert(msg, mtype, t, highres_unit):
                key = (sample.kind.value, 0 if isinstance(sample, AttitudeSample) else sample.instance)
                if owner.setdefault(key, mtype) != mtype:
                    continue
                if isinstance(sample, AttitudeSample) or self._wanted(sample.instance):
                    yield sample
        left = 0
        size = self.path.stat().st_size
        if consumed < size:
            left = size - consumed
        yield _end(last_time, left)


def _end(last_time: float, bytes_left: int) -> StreamEnd:
    if bytes_left > 0:
        return StreamEnd(last_time, SampleFlag.END | SampleFlag.TRUNCATED,
                         f"log ends inside a record: {bytes_left} bytes left unparsed")
    return StreamEnd(last_time, SampleFlag.END, "end of log")


def _first(msg: Any, *names: str) -> Any:
    for name in names:
        value = getattr(msg, name, None)
        if value is not None:
            return value
    return None


def _df_time(msg: Any, base: str) -> float | None:
    us = getattr(msg, "TimeUS", None)
    if us is not None:
        return us * 1e-6
    if base == "GPS":
        boot_ms = getattr(msg, "T", None)  # old GPS: TimeMS is GPS time of week
        if boot_ms is not None:
            return boot_ms * 1e-3
    ms = getattr(msg, "TimeMS", None)
    return None if ms is None else ms * 1e-3


def _df_instance(msg: Any, default: int) -> int:
    for name in ("I", "Instance"):
        value = getattr(msg, name, None)
        if value is not None:
            return int(value)
    return default


def _imu_flags(msg: Any, instance: int, errors: dict[int, tuple[int, int]]) -> SampleFlag:
    flags = SampleFlag.NONE
    if getattr(msg, "GH", 1) == 0 or getattr(msg, "AH", 1) == 0:
        flags |= SampleFlag.UNHEALTHY
    # Cumulative error counters of the sensor driver: ErrG/ErrA (old), EG/EA (ArduPilot 4).
    err = (int(_first(msg, "ErrG", "EG") or 0), int(_first(msg, "ErrA", "EA") or 0))
    previous = errors.get(instance)
    errors[instance] = err
    if previous is not None and (err[0] > previous[0] or err[1] > previous[1]):
        flags |= SampleFlag.READ_ERROR  # the sensor driver counted an error on this sample
    return flags


def _df_gps(msg: Any, t: float, instance: int) -> GpsSample:
    spd = getattr(msg, "Spd", None)
    crs = getattr(msg, "GCrs", None)
    vz = getattr(msg, "VZ", None)
    vel = None
    if spd is not None and crs is not None:
        c = math.radians(crs)
        vel = (spd * math.cos(c), spd * math.sin(c), vz if vz is not None else math.nan)
    return GpsSample(
        time_s=t, lat_deg=msg.Lat, lon_deg=msg.Lng, alt_m=math.nan, fix_type=int(msg.Status),
        vel_ned_mps=vel, num_sv=int(_first(msg, "NSats") or 0), alt_msl_m=float(msg.Alt),
        instance=instance)


# DataFlash message -> (what it is, instance when the record has no instance field).
# ACC: the accuracy records that accompany GPS (GPA in newer logs, UBX3 in Copter 3.3).
_DF_KINDS: dict[str, tuple[str, int]] = {
    "MAG": ("MAG", 0), "MAG2": ("MAG", 1), "MAG3": ("MAG", 2),
    "IMU": ("IMU", 0), "IMU2": ("IMU", 1), "IMU3": ("IMU", 2),
    "ATT": ("ATT", 0),
    "GPS": ("GPS", 0), "GPS2": ("GPS", 1),
    "GPA": ("ACC", 0), "GPA2": ("ACC", 1), "UBX3": ("ACC", 0),
}

