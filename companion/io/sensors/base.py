"""The sensor-source interface: timestamped samples, the source contract, errors, staleness.

Every source (MPU9250 over I2C, u-blox over serial, DroneCAN, log replay, MAVLink) turns
its own protocol into the same immutable samples, so the navigation code never asks
which source it has.

Units and frames follow :mod:`companion`: SI, nanotesla for field components, body frame
x forward, y right, z down; attitude angles in radians with yaw from true (or, where the
sample says so, magnetic) north, clockwise, in [0, 2*pi).

Time
    ``time_s`` is seconds on *the source's clock*: monotonic, and comparable between the
    kinds of sample that one source delivers, never between two sources' clocks unless a
    combined source shares one. Log replay and MAVLink use the vehicle's boot time carried
    in the messages. The MPU9250 has no clock of its own, so the direct hardware sources
    (I2C, serial, CAN) stamp samples with the host's monotonic clock at reception; this
    also gives the I2C + u-blox combination one time base. Device time that exists (the
    receiver's UTC) travels alongside in its own field.

Flags
    A sample the source decoded but does not trust carries :class:`SampleFlag` bits and
    ``valid`` is False; sources report such samples instead of dropping them, so a caller
    can count them, and never raise for them.

>>> s = MagSample(time_s=12.5, mag_body_nt=(21000.0, 4000.0, -52000.0))
>>> s.valid, round(s.magnitude_nt)
(True, 56223)
"""
from __future__ import annotations

import abc
import enum
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import ClassVar

__all__ = [
    "AttitudeSample",
    "GpsSample",
    "ImuSample",
    "MagSample",
    "Sample",
    "SampleFlag",
    "SampleKind",
    "SensorError",
    "SensorSource",
    "SourceStats",
    "StalenessMonitor",
    "StreamEnd",
    "Vector3",
]

from companion.frames import Vector3  # noqa: E402  (re-exported: the samples' vector type)


class SampleKind(str, enum.Enum):
    """What a sample measures; the key of :class:`StalenessMonitor`."""

    MAG = "mag"
    IMU = "imu"
    ATTITUDE = "attitude"
    GPS = "gps"
    END = "end"


class SampleFlag(enum.IntFlag):
    """Why a sample should not be trusted (several may be set)."""

    NONE = 0
    STUCK = 1
    """The same raw reading repeated too many times: a frozen sensor or bus."""
    OVERFLOW = 2
    """The sensor reported saturation (AK8963 HOFL) or a value beyond its range."""
    SPIKE = 4
    """A jump larger than the source's plausibility limit between consecutive samples."""
    READ_ERROR = 8
    """Part of the reading failed; the values present are unreliable."""
    UNHEALTHY = 16
    """The producer itself marked the reading unhealthy (e.g. DataFlash ``Health`` = 0)."""
    END = 32
    """End of a finite stream (log replay); only on :class:`StreamEnd`."""
    TRUNCATED = 64
    """The stream ended inside a record: the log was cut; only on :class:`StreamEnd`."""


#: Bits that make a measurement sample invalid.
INVALIDATING = (
    SampleFlag.STUCK | SampleFlag.OVERFLOW | SampleFlag.SPIKE | SampleFlag.READ_ERROR
    | SampleFlag.UNHEALTHY
)


@dataclass(frozen=True, slots=True)
class MagSample:
    """Magnetic field in the body frame, nanotesla, after the source's calibration."""

    time_s: float
    mag_body_nt: Vector3
    instance: int = 0
    """Which magnetometer of the source (DataFlash MAG2 -> 1, DroneCAN sensor_id)."""
    flags: SampleFlag = SampleFlag.NONE
    stale_since_s: float = math.nan
    """For a STUCK sample: since when (same clock as ``time_s``) the reading has not changed, so
    the samples since then were not fresh either; NaN when not known."""
    kind: ClassVar[SampleKind] = SampleKind.MAG

    @property
    def valid(self) -> bool:
        return not self.flags & INVALIDATING

    @property
    def magnitude_nt(self) -> float:
        return math.sqrt(sum(c * c for c in self.mag_body_nt))


@dataclass(frozen=True, slots=True)
class ImuSample:
    """Specific force and angular rate in the body frame.

    ``accel_body_mps2`` is what an accelerometer measures (specific force), so a level
    vehicle at rest reads about (0, 0, -9.81) with z down -- ArduPilot's convention.
    """

    time_s: float
    accel_body_mps2: Vector3
    gyro_body_radps: Vector3
    temperature_c: float | None = None
    instance: int = 0
    flags: SampleFlag = SampleFlag.NONE
    kind: ClassVar[SampleKind] = SampleKind.IMU

    @property
    def valid(self) -> bool:
        return not self.flags & INVALIDATING


@dataclass(frozen=True, slots=True)
class AttitudeSample:
    """Roll, pitch, yaw (ZYX Euler, body to NED), radians; yaw in [0, 2*pi).

    ``yaw_reference`` is ``"true"`` when yaw is measured from true north (a flight
    controller's estimate, or a filter given the declination), ``"magnetic"`` otherwise.
    """

    time_s: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    yaw_reference: str = "true"
    flags: SampleFlag = SampleFlag.NONE
    kind: ClassVar[SampleKind] = SampleKind.ATTITUDE

    @property
    def valid(self) -> bool:
        return not self.flags & INVALIDATING


@dataclass(frozen=True, slots=True)
class GpsSample:
    """A GNSS fix.

    ``fix_type`` uses MAVLink's GPS_FIX_TYPE numbers: 0 no GPS, 1 no fix, 2 2D, 3 3D,
    4 DGPS, 5 RTK float, 6 RTK fixed. ``alt_m`` is height above the WGS84 ellipsoid and
    ``alt_msl_m`` above mean sea level; either is NaN when the source does not give it
    (a DataFlash log has MSL only). Accuracies are 1-sigma-like receiver estimates in
    metres, NaN when unknown. ``vel_ned_mps`` is None when unknown; its down component
    is NaN when only ground speed and course are known. ``utc_s`` is the receiver's UTC
    time as POSIX seconds when the receiver reports it valid.
    """

    time_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    fix_type: int
    h_acc_m: float = math.nan
    v_acc_m: float = math.nan
    vel_ned_mps: Vector3 | None = None
    num_sv: int = 0
    alt_msl_m: float = math.nan
    utc_s: float | None = None
    instance: int = 0
    flags: SampleFlag = SampleFlag.NONE
    kind: ClassVar[SampleKind] = SampleKind.GPS

    @property
    def valid(self) -> bool:
        return not self.flags & INVALIDATING

    @property
    def has_3d_fix(self) -> bool:
        return self.fix_type >= 3

    @property
    def alt_approx_m(self) -> float:
        """Ellipsoidal height if known, else MSL height: good enough for a field model.

        The geoid undulation (< 110 m) changes the main field by a few nT at most.
        """
        return self.alt_m if math.isfinite(self.alt_m) else self.alt_msl_m


@dataclass(frozen=True, slots=True)
class StreamEnd:
    """The last item of a finite source; ``flags`` holds END, plus TRUNCATED if cut."""

    time_s: float
    flags: SampleFlag = SampleFlag.END
    detail: str = ""
    kind: ClassVar[SampleKind] = SampleKind.END

    @property
    def valid(self) -> bool:
        return not self.flags & SampleFlag.TRUNCATED

    @property
    def truncated(self) -> bool:
        return bool(self.flags & SampleFlag.TRUNCATED)


Sample = MagSample | ImuSample | AttitudeSample | GpsSample | StreamEnd


class SensorError(Exception):
    """A sensor source cannot do what was asked: absent device, wrong chip, bad file.

    The message names the source and says what to check. Raised from ``open()``;
    during ``poll()`` sources count read errors in :class:`SourceStats` instead of
    raising, so one bad transaction does not stop navigation.
    """


@dataclass
class SourceStats:
    """Counters a source keeps while it runs (mutable, owned by the source)."""

    samples: int = 0
    flagged: int = 0
    read_errors: int = 0
    checksum_errors: int = 0
    dropped: int = 0
    last_error: str | None = None

    def count(self, samples: Iterable[Sample]) -> None:
        for s in samples:
            if s.kind is SampleKind.END:
                continue
            self.samples += 1
            if not s.valid:
                self.flagged += 1

    def record_error(self, error: BaseException | str) -> None:
        self.read_errors += 1
        self.last_error = str(error)


class SensorSource(abc.ABC):
    """One input of the companion, MAVProxy-module shaped: open, receive hook, close.

    ``poll(timeout_s)`` is the receive hook: it returns the samples that became
    available, waiting at most ``timeout_s`` for the first one (0 = do not wait), and
    returns an empty list when nothing arrived. Subclasses set ``name`` and fill
    ``stats``; a finite source sets ``finished`` after it delivered its :class:`StreamEnd`.
    """

    name: str = "source"
    provides: frozenset[SampleKind] = frozenset({SampleKind.MAG})
    """The kinds of sample this source delivers: the companion then ignores the flight
    controller's samples of those kinds (two magnetometers are never mixed)."""
    time_base: str = "host"
    """Which clock ``time_s`` is on: ``"host"`` (monotonic, at reception) for live
    hardware, ``"log"`` for a replay, ``"vehicle"`` for the autopilot's boot time."""

    def __init__(self) -> None:
        self.stats = SourceStats()

    @property
    def finished(self) -> bool:
        """True when a finite source has nothing more to give (live sources: never)."""
        return False

    @abc.abstractmethod
    def open(self) -> None:
        """Acquire the device or file; raise :class:`SensorError` with a clear reason."""

    @abc.abstractmethod
    def poll(self, timeout_s: float = 0.0) -> list[Sample]:
        """Samples received since the last call, waiting up to ``timeout_s`` for one."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the device or file; safe to call twice."""

    def __enter__(self) -> SensorSource:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}>"


@dataclass
class StalenessMonitor:
    """Per-kind time of the last valid sample, to detect a sensor that went quiet.

    Flagged samples do not refresh the kind: a magnetometer that only sends overflowed
    readings is as stale as a silent one. ``now_s`` must be on the same clock as the
    samples (the source's clock, see the module docstring).

    >>> m = StalenessMonitor()
    >>> m.update([MagSample(10.0, (1.0, 0.0, 0.0))])
    >>> m.is_stale("mag", now_s=10.4, timeout_s=0.5), m.is_stale("gps", 10.4, 0.5)
    (False, True)
    """

    _last: dict[SampleKind, float] = field(default_factory=dict)

    def update(self, samples: Iterable[Sample]) -> None:
        for s in samples:
            if s.kind is SampleKind.END or not s.valid:
                continue
            last = self._last.get(s.kind)
            if last is None or s.time_s > last:
                self._last[s.kind] = s.time_s

    def last_time(self, kind: SampleKind | str) -> float | None:
        return self._last.get(SampleKind(kind))

    def age(self, kind: SampleKind | str, now_s: float) -> float:
        """Seconds since the last valid sample of ``kind``; infinity if none yet."""
        last = self.last_time(kind)
        return math.inf if last is None else now_s - last

    def is_stale(self, kind: SampleKind | str, now_s: float, timeout_s: float) -> bool:
        return self.age(kind, now_s) > timeout_s
