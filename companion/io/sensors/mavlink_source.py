"""Sensor samples from a flight controller's MAVLink streams.

:class:`MavlinkDecoder` turns one message into :mod:`companion.io.sensors.base` samples
(the receive hook the companion application calls for every message of the flight
controller); :class:`MavlinkSource` wraps it with its own connection as a
:class:`~companion.io.sensors.base.SensorSource` for standalone use and tests.

==================  ======================================================================
message             samples (units converted to SI / nT)
==================  ======================================================================
RAW_IMU             ImuSample (mG, mrad/s as ArduPilot sends them) and MagSample (mG -> nT,
                    the midpoint of the truncated count, :mod:`~companion.io.sensors.mag_units`)
SCALED_IMU/2/3      the same, instances 0/1/2
HIGHRES_IMU         ImuSample (SI) and MagSample (the autopilot's unit -> nT: gauss, ArduPilot
                    1e-6 gauss) when its ``fields_updated`` bits say so
ATTITUDE            AttitudeSample (yaw from true north); body rates kept in :attr:`rates`
GPS_RAW_INT         GpsSample (fix type, lat/lon degE7, MSL and ellipsoid altitudes)
GLOBAL_POSITION_INT not a sensor: the flight controller's *inertial solution*, kept as
                    :attr:`MavlinkDecoder.fc_position` (drifts once GPS is denied)
==================  ======================================================================

For each magnetometer instance the first message type that carries it provides it (a
flight controller streaming RAW_IMU and SCALED_IMU for the same sensor gives each sample
once), unless ``mag_message`` names the ones to use, preferred first: then a preferred type
takes the instance over as soon as it arrives (HIGHRES_IMU over RAW_IMU on ArduPilot), and the
type it replaced is listed in :attr:`MavlinkDecoder.superseded` so its stream can be stopped.

Readings that cannot be a field are flagged, not dropped (``valid`` False, so
:class:`~companion.io.sensors.base.StalenessMonitor` does not count them as fresh):
non-finite values (READ_ERROR), int16 saturation -32768/32767 mG, which is how a NaN
reaches the integer messages (OVERFLOW), exactly (0, 0, 0), a dead or absent sensor
(READ_ERROR), and the identical raw triple ``stuck_count`` times in a row while the gyro
of the same messages says the body turned by 2 degrees or more (STUCK; a quiet or noise-free
magnetometer on a still vehicle repeats its reading and is fine,
:class:`~companion.io.sensors.quality.FrozenDetector`).
:attr:`MavlinkDecoder.last_problem` says which. Times are the flight controller's boot time
(:class:`companion.io.link.MessageClock`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion import wrap_2pi
from companion.io.link import MavlinkLink, MessageClock
from companion.io.sensors.base import AttitudeSample, GpsSample, ImuSample, MagSample, Sample, SampleFlag, \
    SensorError, SensorSource
from companion.io.sensors.quality import FrozenDetector
from companion.io.sensors.mag_units import GAUSS_TO_NT, count_to_nt

__all__ = ["FcPosition", "MavlinkDecoder", "MavlinkSource"]

_G_PER_MG = 9.80665e-3
_SCALED_INSTANCE = {"SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}
_INT16_LIMITS = (-32768, 32767)
_NONE = SampleFlag.NONE          # an enum member's class-attribute lookup is a Python call: looked up once
MAG_MESSAGES = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")


@dataclass(frozen=True)
class FcPosition:
    """GLOBAL_POSITION_INT: the flight controller's position solution (degrees, m, m/s)."""

    time_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    vn_mps: float
    ve_mps: float


def _on_earth(lat_deg: float, lon_deg: float) -> bool:
    """A latitude and longitude that name a place (degrees; MAVLink's int32 degE7 fields hold more)."""
    return -90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0


class MavlinkDecoder:
    """MAVLink message -> samples, on the flight controller's clock."""

    def __init__(self, clock: MessageClock, mag_message: str | tuple[str, ...] | None = None,
                 stuck_count: int = 20, imu: bool = True, highres_nt_per_unit: float = GAUSS_TO_NT) -> None:
        self.clock = clock
        self.imu = imu   # False: skip ImuSample (a user that needs only the magnetometer saves the work)
        self.mag_message = mag_message
        self.highres_nt_per_unit = highres_nt_per_unit   # the autopilot's HIGHRES_IMU unit (mag_units)
        self.superseded: set[str] = set()   # magnetometer messages a preferred one replaced
        self._mag_type: dict[int, str] = {}
        self._stuck: dict[int, FrozenDetector] = {}
        self._gyro: tuple[float, float, float] | None = None
        self._stuck_count = stuck_count
        self.rates: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.fc_position: FcPosition | None = None
        self.last_problem: dict[str, str] = {}   # "mag"/"attitude" -> why the last sample was invalid
        self._decoders = {"ATTITUDE": self._attitude, "HIGHRES_IMU": self._highres_imu, "RAW_IMU": self._scaled_imu,
                          "GPS_RAW_INT": self._gps_raw_int, "GLOBAL_POSITION_INT": self._global_position_int,
                          **{name: self._scaled_imu for name in _SCALED_INSTANCE}}   # message type -> its decoder

    def _mag_flags(self, instance: int, raw: tuple, saturates: bool, time_s: float = math.nan) -> SampleFlag:
        flags = _NONE
        f = math.isfinite
        if not saturates and not (f(raw[0]) and f(raw[1]) and f(raw[2])):
            flags |= SampleFlag.READ_ERROR
            self.last_problem["mag"] = "non-finite magnetometer values"
            return flags
        lo, hi = _INT16_LIMITS
        if saturates and (raw[0] in (lo, hi) or raw[1] in (lo, hi) or raw[2] in (lo, hi)):
            flags |= SampleFlag.OVERFLOW
            self.last_problem["mag"] = "saturated magnetometer (int16 limit: NaN at the source?)"
        elif raw[0] == 0 and raw[1] == 0 and raw[2] == 0:
            flags |= SampleFlag.READ_ERROR
            self.last_problem["mag"] = "magnetometer reads exactly zero (sensor off?)"
        detector = self._stuck.get(instance)
        if detector is None:
            detector = self._stuck[instance] = FrozenDetector(self._stuck_count)
        if detector.check(raw, time_s, self._gyro) is not _NONE:
            if not flags:   # a stuck zero or saturated reading keeps its more telling reason
                self.last_problem["mag"] = (f"magnetometer stuck ({self._stuck_count} identical readings "
                                            "while the vehicle turned)")
            flags |= SampleFlag.STUCK
        return flags

    def _stale_since(self, instance: int, flags: SampleFlag) -> float:
        """For a frozen reading, the time of the first of its repeats (else NaN)."""
        # ``flags and``: a clean sample (most) skips IntFlag's Python-level ``&``
        return self._stuck[instance].repeating_since_s if flags and flags & SampleFlag.STUCK else math.nan

    def _time(self, msg) -> float | None:
        ms = getattr(msg, "time_boot_ms", None)
        if ms is not None:
            return ms * 1e-3
        return self.clock.stamp_usec(getattr(msg, "time_usec", 0))

    @property
    def mag_message(self) -> tuple[str, ...] | None:
        """The magnetometer messages in use, preferred first (None: the first that arrives)."""
        return self._mag_messages

    @mag_message.setter
    def mag_message(self, names: str | tuple[str, ...] | None) -> None:
        names = (names,) if isinstance(names, str) else (tuple(names) if names else None)
        for name in names or ():
            if name not in MAG_MESSAGES:
                raise ValueError(f"magnetometer message {name!r} not one of {', '.join(MAG_MESSAGES)}")
        self._mag_messages = names

    def _owns_mag(self, instance: int, mtype: str) -> bool:
        preferred = self._mag_messages
        if preferred is None:
            return self._mag_type.setdefault(instance, mtype) == mtype
        if mtype not in preferred:
            return False
        current = self._mag_type.get(instance)
        if current not in preferred or preferred.index(mtype) <= preferred.index(current):
            if current is not None and current != mtype:
                self.superseded.add(current)
            self._mag_type[instance] = mtype
            return True
        return False

    def decode(self, msg) -> list[Sample]:
        """The samples in ``msg`` (a pymavlink message), by its type's decoder (:attr:`_decoders`)."""
        decoder = self._decoders.get(msg._type)
        return decoder(msg) if decoder is not None else []

    def _attitude(self, msg) -> list[Sample]:
        t = msg.time_boot_ms * 1e-3
        roll, pitch, yaw = msg.roll, msg.pitch, msg.yaw
        rates = self.rates = (msg.rollspeed, msg.pitchspeed, msg.yawspeed)
        f = math.isfinite
        if f(roll) and f(pitch) and f(yaw) and f(rates[0]) and f(rates[1]) and f(rates[2]):
            return [AttitudeSample(t, roll, pitch, wrap_2pi(yaw))]
        self.last_problem["attitude"] = "non-finite ATTITUDE"
        return [AttitudeSample(t, math.nan, math.nan, math.nan, flags=SampleFlag.READ_ERROR)]

    def _highres_imu(self, msg) -> list[Sample]:
        t = self._time(msg)
        if t is None:
            return []
        instance = int(getattr(msg, "id", 0) or 0)
        out = []
        updated = msg.fields_updated
        if self.imu and updated & 0x3F:
            out.append(ImuSample(t, (msg.xacc, msg.yacc, msg.zacc), (msg.xgyro, msg.ygyro, msg.zgyro),
                                 msg.temperature, instance))
        if updated & 0x1C0 and self._owns_mag(instance, "HIGHRES_IMU"):
            raw = (msg.xmag, msg.ymag, msg.zmag)
            if updated & 0x38:
                self._gyro = (msg.xgyro, msg.ygyro, msg.zgyro)
            scale = self.highres_nt_per_unit
            mag = (raw[0] * scale, raw[1] * scale, raw[2] * scale)
            flags = self._mag_flags(instance, raw, False, t)
            out.append(MagSample(t, mag, instance, flags, self._stale_since(instance, flags)))
        return out

    def _scaled_imu(self, msg) -> list[Sample]:
        """RAW_IMU and SCALED_IMU/2/3 (mG, mrad/s)."""
        t = self._time(msg)
        if t is None:
            return []
        mtype = msg._type
        instance = int(getattr(msg, "id", 0) or 0) if mtype == "RAW_IMU" else _SCALED_INSTANCE[mtype]
        out: list[Sample] = []
        if self.imu:
            out.append(ImuSample(t, (msg.xacc * _G_PER_MG, msg.yacc * _G_PER_MG, msg.zacc * _G_PER_MG),
                                 (msg.xgyro * 1e-3, msg.ygyro * 1e-3, msg.zgyro * 1e-3), None, instance))
        if self._owns_mag(instance, mtype):
            raw = (msg.xmag, msg.ymag, msg.zmag)
            self._gyro = (msg.xgyro * 1e-3, msg.ygyro * 1e-3, msg.zgyro * 1e-3)
            flags = self._mag_flags(instance, raw, True, t)
            out.append(MagSample(t, (count_to_nt(raw[0]), count_to_nt(raw[1]), count_to_nt(raw[2])), instance,
                                 flags, self._stale_since(instance, flags)))
        return out

    def _gps_raw_int(self, msg) -> list[Sample]:
        t = self._time(msg)
        if t is None:
            t = self.clock.now_s
        alt_ell = getattr(msg, "alt_ellipsoid", 0)
        h_acc = getattr(msg, "h_acc", 0)
        lat, lon = msg.lat * 1e-7, msg.lon * 1e-7
        on_earth = _on_earth(lat, lon)
        if not on_earth:
            self.last_problem["gps"] = f"GPS_RAW_INT outside the Earth: lat {lat:g}, lon {lon:g}"
        return [GpsSample(time_s=t, lat_deg=lat, lon_deg=lon,
                          alt_m=alt_ell * 1e-3 if alt_ell else math.nan, fix_type=int(msg.fix_type),
                          h_acc_m=h_acc * 1e-3 if h_acc else math.nan,
                          num_sv=int(msg.satellites_visible) if msg.satellites_visible != 255 else 0,
                          alt_msl_m=msg.alt * 1e-3, flags=_NONE if on_earth else SampleFlag.READ_ERROR)]

    def _global_position_int(self, msg) -> list[Sample]:
        """Not a sensor: kept as :attr:`fc_position` (no samples)."""
        if msg.lat == 0 and msg.lon == 0:   # "no position" as ArduPilot and PX4 send it
            return []
        lat, lon = msg.lat * 1e-7, msg.lon * 1e-7
        if not _on_earth(lat, lon):   # int32 degE7 reaches 214 deg: not a position
            self.last_problem["position"] = f"GLOBAL_POSITION_INT outside the Earth: lat {lat:g}, lon {lon:g}"
            return []
        self.fc_position = FcPosition(msg.time_boot_ms * 1e-3, lat, lon, msg.alt * 1e-3, msg.vx * 0.01,
                                      msg.vy * 0.01)
        return []


class MavlinkSource(SensorSource):
    """A flight controller's sensors over its own MAVLink connection (standalone use, tests).

    ``poll`` reads what arrived, keeps the flight-controller state and clock of the link, and
    returns the decoded samples. The companion application instead shares one link between
    this decoder, the parameter server and the outputs.
    """

    def __init__(self, connect: str, name: str = "mavlink", mag_message: str | None = None) -> None:
        super().__init__()
        self.name = name
        self.link = MavlinkLink(connect)
        self.decoder = MavlinkDecoder(self.link.clock, mag_message)
        self._open = False

    def open(self) -> None:
        try:
            self.link.open()
        except OSError as err:
            raise SensorError(f"{self.name}: cannot open {self.link.connect_text!r}: {err}") from err
        self._open = True

    def poll(self, timeout_s: float = 0.0) -> list[Sample]:
        if not self._open:
            raise SensorError(f"{self.name}: poll() before open()")
        out: list[Sample] = []
        if self.link.wait_readable(timeout_s):
            for msg in self.link.read():
                if self.link.observe(msg):
                    out.extend(self.decoder.decode(msg))
        self.stats.count(out)
        return out

    def close(self) -> None:
        if self._open:
            self.link.close()
            self._open = False
