"""From body-frame magnetometer samples to the averaged (D, I) of one control period (eq. 2).

Pure (samples in, in message time and SI units; results out). Per sample:

1. **Calibration**: ``m_cal = W (m_raw - offset)`` (hard iron, then soft iron;
   ``MAG_OFS_*`` in milligauss are subtracted, then the symmetric soft-iron matrix with
   ``MAG_SCALE_*`` on its diagonal and ``MAG_SOFT_*`` off it multiplies). Note that ArduPilot's
   ``COMPASS_OFS_*`` are *added* to the raw field: copy them here with the opposite sign.
2. **Tilt compensation**: the body vector is rotated into NED with the attitude (roll, pitch,
   yaw; ZYX Euler, yaw from true north clockwise) *at the sample's time*, the attitude being
   propagated from the latest ATTITUDE message with its body rates (a boat turning at 6 deg/s
   would otherwise smear D by the message spacing times the rate).
3. **D and I** per :mod:`companion`: ``D = atan2(E, N)``, ``I = atan2(Dn, hypot(N, E))``.
4. **Spike rejection**: a sample whose NED components differ from the running median of the
   last ``window`` samples by more than ``spike_nt`` (``COMP_SPIKE_NT``) is rejected and
   counted. Rejected samples still enter the median window, so a real, lasting change of the
   field (a level step, not a spike) is accepted after half a window.
5. **Gravity-referenced inclination** (for the heading-free element set): with the
   accelerometer's specific force ``f`` of the same instant, ``I_g = asin(-m . f / (|m| |f|))``:
   the angle between the field and the horizontal plane, from the two sensors alone,
   rotation-invariant, so it needs no heading. On a vehicle holding course and speed the mean
   specific force is gravity (waves and heave average out); samples while turning
   (``|gyro z| > max_turn_radps``: centripetal acceleration tilts ``f``) and until
   ``settle_until_s`` after a new command (the speed change after a turn tilts ``f`` along the
   track: 1 m/s^2 is 6 degrees) are left out of it.
6. **Averaging**: D (unwrapped around the first sample) and I are averaged over the accepted
   samples of the period, which is what the in-process Monte Carlo means by "D and I averaged
   along the period's path" (:mod:`fcmpc.montecarlo.inprocess`). The result also carries the mean sample
   time, so the caller can tell the core how far back the average refers
   (``window_s = 2 * (t_end - mean_time)``).

The period's I_g is a ratio of averages, not an average of per-sample angles, and every average
carries its standard error from the period's own scatter: :mod:`companion.nav.inclination`.

>>> d, i = decl_incl_deg(20000.0, 5000.0, 40000.0)
>>> round(d, 4), round(i, 4)
(14.0362, 62.734)
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import NamedTuple

from companion.frames import Matrix3, Vector3, body_to_ned, mat_nb_from_euler, rotate
from companion.nav.period import PeriodAverage, PeriodAverager
from companion.nav.steering import YawOffsetTracker

__all__ = [
    "MILLIGAUSS_TO_NT",
    "GAUSS_TO_NT",
    "MagCalibration",
    "AttitudeState",
    "decl_incl_deg",
    "gravity_inclination_deg",
    "tilt_compensated_di",
    "SpikeFilter",
    "MagProcessor",
    "MagStats",
]

MILLIGAUSS_TO_NT = 100.0   # 1 mG = 1e-7 T = 100 nT
GAUSS_TO_NT = 1e5



_IDENTITY3: Matrix3 = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class MagCalibration:
    """Hard- and soft-iron correction in the body frame: ``soft_iron @ (m - offset_nt)``.

    ``offset_nt`` is the hard-iron bias to *subtract* (ArduPilot's COMPASS_OFS parameters
    have the opposite sign: they are added). The registry's per-axis ``MAG_SCALE_*`` is the
    diagonal soft-iron matrix (:meth:`from_mgauss`); a direct sensor may carry a full one.

    >>> MagCalibration.from_mgauss((1.0, 0.0, 0.0), (2.0, 1.0, 1.0)).apply((300.0, 1.0, 2.0))
    (400.0, 1.0, 2.0)
    """

    offset_nt: Vector3 = (0.0, 0.0, 0.0)
    soft_iron: Matrix3 = _IDENTITY3

    def __post_init__(self) -> None:
        if len(self.offset_nt) != 3:
            raise ValueError(f"MagCalibration.offset_nt must have 3 components, got {self.offset_nt!r}")
        if len(self.soft_iron) != 3 or any(len(row) != 3 for row in self.soft_iron):
            raise ValueError(f"MagCalibration.soft_iron must be 3x3, got {self.soft_iron!r}")

    @classmethod
    def from_mgauss(cls, offset_mgauss: Vector3, scale: Vector3,
                    off_diagonal: Vector3 = (0.0, 0.0, 0.0)) -> MagCalibration:
        """From the registry's ``MAG_OFS_*`` (mG), ``MAG_SCALE_*`` (the soft iron's diagonal) and
        ``MAG_SOFT_XY/XZ/YZ`` (its symmetric off-diagonal entries)."""
        sx, sy, sz = (float(v) for v in scale)
        xy, xz, yz = (float(v) for v in off_diagonal)
        return cls(tuple(float(o) * MILLIGAUSS_TO_NT for o in offset_mgauss),
                   ((sx, xy, xz), (xy, sy, yz), (xz, yz, sz)))

    def apply(self, mag_body_nt: Vector3) -> Vector3:
        """``soft_iron @ (m - offset)`` in nT."""
        o, (m0, m1, m2) = self.offset_nt, self.soft_iron
        d0, d1, d2 = mag_body_nt[0] - o[0], mag_body_nt[1] - o[1], mag_body_nt[2] - o[2]
        return (m0[0] * d0 + m0[1] * d1 + m0[2] * d2, m1[0] * d0 + m1[1] * d1 + m1[2] * d2,
                m2[0] * d0 + m2[1] * d1 + m2[2] * d2)


def decl_incl_deg(north_nt: float, east_nt: float, down_nt: float) -> tuple[float, float]:
    """Declination (east of true north) and inclination (below horizontal), degrees (eq. 2)."""
    return (math.degrees(math.atan2(east_nt, north_nt)),
            math.degrees(math.atan2(down_nt, math.hypot(north_nt, east_nt))))


def gravity_inclination_deg(mag_body_nt: Vector3, specific_force_body: Vector3) -> float:
    """Inclination from the field and the accelerometer alone (NaN if either is zero or not finite).

    >>> round(gravity_inclination_deg((20000.0, 0.0, 20000.0), (0.0, 0.0, -9.81)), 6)   # level
    45.0
    >>> round(gravity_inclination_deg((0.0, 0.0, 28284.27), (-6.94, 0.0, -6.94)), 3)    # pitched 45 deg
    45.0
    """
    mx, my, mz = mag_body_nt
    fx, fy, fz = specific_force_body
    m = math.sqrt(mx * mx + my * my + mz * mz)
    f = math.sqrt(fx * fx + fy * fy + fz * fz)
    if not (m > 0.0 and f > 0.0) or not math.isfinite(m * f):
        return math.nan
    sine = -(mx * fx + my * fy + mz * fz) / (m * f)
    return math.degrees(math.asin(max(-1.0, min(1.0, sine))))


def tilt_compensated_di(mag_body_nt: Vector3, roll_rad: float, pitch_rad: float,
                        yaw_rad: float) -> tuple[float, float, Vector3]:
    """(D deg, I deg, field NED nT) of a calibrated body-frame field at the given attitude."""
    ned = body_to_ned(mag_body_nt, roll_rad, pitch_rad, yaw_rad)
    d, i = decl_incl_deg(*ned)
    return d, i, ned


class AttitudeState(NamedTuple):
    """An attitude estimate at ``time_s`` with Euler-angle rates (rad/s) to propagate it.

    A named tuple: one is made per ATTITUDE message (10 Hz), and a frozen dataclass of seven fields
    took three times as long to make (the dataclasses' constructors were 5 % of the capacity replay)."""

    time_s: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    roll_rate_radps: float = 0.0
    pitch_rate_radps: float = 0.0
    yaw_rate_radps: float = 0.0

    @classmethod
    def from_body_rates(cls, time_s: float, roll: float, pitch: float, yaw: float,
                        p: float, q: float, r: float) -> AttitudeState:
        """From MAVLink ATTITUDE (body rates p, q, r) -> Euler rates (ZYX kinematics)."""
        sr, cr = math.sin(roll), math.cos(roll)
        cp = math.cos(pitch)
        tp = math.tan(pitch)
        if abs(cp) < 1e-6:  # gimbal lock: do not propagate
            return cls(time_s, roll, pitch, yaw)
        return cls(time_s, roll, pitch, yaw,
                   p + (q * sr + r * cr) * tp,
                   q * cr - r * sr,
                   (q * sr + r * cr) / cp)

    @property
    def finite(self) -> bool:
        f = math.isfinite
        return (f(self.time_s) and f(self.roll_rad) and f(self.pitch_rad) and f(self.yaw_rad)
                and f(self.roll_rate_radps) and f(self.pitch_rate_radps) and f(self.yaw_rate_radps))

    def at(self, time_s: float, max_dt_s: float = 0.5) -> tuple[float, float, float]:
        """(roll, pitch, yaw) propagated to ``time_s`` (at most ``max_dt_s`` either way)."""
        dt = min(max(time_s - self.time_s, -max_dt_s), max_dt_s)
        return (self.roll_rad + self.roll_rate_radps * dt, self.pitch_rad + self.pitch_rate_radps * dt,
                self.yaw_rad + self.yaw_rate_radps * dt)


class SpikeFilter:
    """Rejects a NED sample further than ``threshold_nt`` (any component) from the running median.

    Judges only once ``min_samples`` are in the window; every finite sample, accepted or not,
    enters the window. The medians are recomputed every ``refresh`` samples (a median a few
    samples old is as good a reference and costs a quarter).

    >>> f = SpikeFilter(1000.0, window=5, min_samples=3, refresh=1)
    >>> [f.accept((20000.0 + k, 0.0, 40000.0)) for k in range(4)] + [f.accept((30000.0, 0.0, 40000.0))]
    [True, True, True, True, False]
    """

    def __init__(self, threshold_nt: float, window: int = 15, min_samples: int = 5, refresh: int = 4) -> None:
        if window < 3 or min_samples < 1 or refresh < 1:
            raise ValueError("spike filter needs window >= 3, min_samples >= 1, refresh >= 1")
        self.threshold_nt = float(threshold_nt)
        self.min_samples = min_samples
        self.refresh = refresh
        self._hist = (deque(maxlen=window), deque(maxlen=window), deque(maxlen=window))
        self._median: tuple[float, float, float] | None = None
        self._age = 0

    @staticmethod
    def _median_of(values) -> float:
        ordered = sorted(values)
        mid = len(ordered) // 2
        return ordered[mid] if len(ordered) % 2 else 0.5 * (ordered[mid - 1] + ordered[mid])

    def accept(self, ned_nt: Vector3) -> bool:
        hist = self._hist
        ok = True
        if len(hist[0]) >= self.min_samples:
            if self._median is None or self._age >= self.refresh:
                self._median = (self._median_of(hist[0]), self._median_of(hist[1]), self._median_of(hist[2]))
                self._age = 0
            m, limit = self._median, self.threshold_nt
            ok = abs(ned_nt[0] - m[0]) <= limit and abs(ned_nt[1] - m[1]) <= limit and abs(ned_nt[2] - m[2]) <= limit
        self._age += 1
        hist[0].append(ned_nt[0])
        hist[1].append(ned_nt[1])
        hist[2].append(ned_nt[2])
        return ok

    def reset(self) -> None:
        for hist in self._hist:
            hist.clear()
        self._median = None


@dataclass
class MagStats:
    """Counters of the magnetometer path (all since start)."""

    samples: int = 0
    accepted: int = 0
    spikes: int = 0
    non_finite: int = 0
    no_attitude: int = 0
    paused: int = 0
    last_reject: str = ""

    def as_dict(self) -> dict[str, int]:
        return {k: v for k, v in self.__dict__.items() if k != "last_reject"}


@dataclass
class MagProcessor:
    """Calibration, tilt compensation, spike rejection and averaging of one magnetometer.

    Feed ATTITUDE with :meth:`add_attitude` and field samples with :meth:`add_mag` in message
    order (message time); :meth:`take` closes a period, in mission time (message time minus
    ``mission_offset_s``). ``paused`` samples (failsafe) are counted, not used.
    """

    calibration: MagCalibration = field(default_factory=MagCalibration)
    spike_nt: float = 5000.0
    max_attitude_age_s: float = 0.5
    stats: MagStats = field(default_factory=MagStats)
    paused: bool = False
    mission_offset_s: float = 0.0
    """Subtracted from message time for the averager (time spent paused: mission time)."""

    max_turn_radps: float = math.radians(1.5)
    """Gravity-referenced I leaves out samples turning faster than this (centripetal acceleration)."""
    settle_until_s: float = -math.inf
    """Message time before which gravity-referenced I is left out (a new command's transient)."""
    track_yaw_offset: bool = False
    """Feed :attr:`yaw_offset` (only the steering trim, ``COMP_TRIM_DEG`` > 0, reads it)."""
    recorder: object = None
    """``recorder(time_s, calibrated_body_nt, roll_rad, pitch_rad, imu)`` per sample kept (the calibration
    circles); ``imu``: ``(time_s, specific_force_body, gyro_body)`` of the same instant, or None."""

    def __post_init__(self) -> None:
        self.spikes = SpikeFilter(self.spike_nt)
        self.averager = PeriodAverager()
        self.attitude: AttitudeState | None = None
        self.last_di: tuple[float, float] = (math.nan, math.nan)
        self._pending: tuple[float, Vector3, tuple | None] | None = None
        self._imu: tuple[float, Vector3, Vector3] | None = None
        self.yaw_offset = YawOffsetTracker()
        """The FC's yaw minus the levelled magnetic heading (:mod:`companion.nav.steering`), paused or not."""

    def add_specific_force(self, time_s: float, accel_body_mps2: Vector3, gyro_body_radps: Vector3) -> None:
        """The accelerometer and gyro of the next magnetometer sample (same message or instant)."""
        self._imu = (time_s, accel_body_mps2, gyro_body_radps)

    def _imu_for(self, time_s: float) -> tuple | None:
        imu = self._imu
        return imu if imu is not None and abs(imu[0] - time_s) <= 0.02 else None

    def configure(self, calibration: MagCalibration, spike_nt: float) -> None:
        """New calibration / spike threshold (parameters changed); keeps the period's samples."""
        self.calibration = calibration
        if spike_nt != self.spike_nt:
            self.spike_nt = spike_nt
            self.spikes.threshold_nt = float(spike_nt)

    def add_attitude(self, attitude: AttitudeState) -> bool:
        """Use this attitude from now on; False (ignored) if not finite.

        A magnetometer sample waiting for the attitude of its own time (flight controllers
        send the IMU message before ATTITUDE of the same instant) is processed now.
        """
        if not attitude.finite:
            return False
        self.attitude = attitude
        pending = self._pending
        if pending is not None and pending[0] <= attitude.time_s + 1e-6:
            self._pending = None
            self._process(*pending)
        return True

    def add_mag(self, time_s: float, mag_body_nt: Vector3) -> None:
        """Queue one sample; it is processed with the attitude of its time (see :meth:`add_attitude`)."""
        att = self.attitude
        if self._pending is not None:
            pending, self._pending = self._pending, None
            self._process(*pending)
        imu = self._imu_for(time_s)
        if (att is None or time_s > att.time_s + 1e-6) and math.isfinite(time_s):
            self._pending = (time_s, mag_body_nt, imu)
            return
        self._process(time_s, mag_body_nt, imu)

    def flush(self) -> None:
        """Process a waiting sample with the attitude propagated to its time."""
        if self._pending is not None:
            pending, self._pending = self._pending, None
            self._process(*pending)

    def _process(self, time_s: float, mag_body_nt: Vector3, imu: tuple | None = None) -> bool:
        st = self.stats
        st.samples += 1
        f = math.isfinite
        if not (f(time_s) and f(mag_body_nt[0]) and f(mag_body_nt[1]) and f(mag_body_nt[2])):
            st.non_finite += 1
            st.last_reject = "non-finite magnetometer sample"
            return False
        att = self.attitude
        if att is None or abs(time_s - att.time_s) > self.max_attitude_age_s:
            st.no_attitude += 1
            st.last_reject = "no attitude near the sample time"
            return False
        calibrated = self.calibration.apply(mag_body_nt)
        rpy = att.at(time_s, self.max_attitude_age_s)
        rotation = mat_nb_from_euler(*rpy)   # tilt compensation; the specific force's below too
        ned = rotate(rotation, calibrated)
        d, i = decl_incl_deg(*ned)
        if not self.spikes.accept(ned):
            st.spikes += 1
            st.last_reject = "spike"
            return False
        self.last_di = (d, i)
        if self.recorder is not None:
            self.recorder(time_s, calibrated, rpy[0], rpy[1], imu)
        if self.track_yaw_offset and imu is not None and abs(imu[2][2]) <= self.max_turn_radps:
            self.yaw_offset.add(time_s, rpy[2], calibrated, imu[1])
        if self.paused:
            st.paused += 1
            return False
        dot, force_ned = math.nan, (math.nan, math.nan, math.nan)
        if imu is not None and abs(imu[2][2]) <= self.max_turn_radps and time_s >= self.settle_until_s:
            f = imu[1]
            dot = calibrated[0] * f[0] + calibrated[1] * f[1] + calibrated[2] * f[2]
            force_ned = rotate(rotation, f)
            self.averager.add(time_s - self.mission_offset_s, d, i, ned, dot, force_ned, calibrated, f)
        else:
            self.averager.add(time_s - self.mission_offset_s, d, i, ned, dot, force_ned)
        st.accepted += 1
        return True

    def take(self, end_mission_time_s: float) -> PeriodAverage:
        """Average of the accepted samples up to ``end_mission_time_s`` (mission time)."""
        self.flush()
        return self.averager.take(end_mission_time_s)

    def drop_before(self, mission_time_s: float) -> None:
        """Forget accepted samples older than ``mission_time_s`` (a sliding start-up window)."""
        self.averager.drop_before(mission_time_s)

    def clear(self) -> None:
        """Drop the samples of the current period (e.g. after a pause)."""
        self.averager.clear()
