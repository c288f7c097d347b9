"""Measured-data evaluation like the paper's Table 8: a recorded flight replayed open-loop.

    fcmpc-replay ../shared/data/logs/log171.bin
    python -m scripts.replay LOG [--model WMM2015|path.COF] [--window-s 1,10,30] [--out DIR]

``LOG`` is an ArduPilot DataFlash ``.bin`` or a MAVLink ``.tlog`` (read by
:class:`companion.io.sensors.replay.LogReplaySource`). The log's own GPS is the truth; the
navigation side sees only the magnetometer, the IMU and the flight controller's attitude, and
GPS only once, at the first 3D fix (start position and velocity of the INS, start of the mission).

What it reports (markdown on stdout, and ``table.md``, ``summary.json``, ``windows.csv`` and PNG
plots in ``out/replay/<log stem>/``):

1. D and I measured (body field rotated to NED with the logged roll/pitch/yaw) against the World
   Magnetic Model at the GPS position, per flight segment: bias (mean of measured - model) and
   spread (standard deviation). The logged yaw is the flight controller's heading estimate,
   which was itself computed from this compass and a declination, so the measured D is a
   consistency check of the flight controller, not an independent measurement. I is
   independent of yaw (it depends on roll, pitch and the compass calibration only).
2. The geomagnetic position fix (eq. 49, :func:`companion.nav.field.geomagnetic_fix`) from D and
   I averaged over windows, started from a prior = GPS position + an offset, against GPS; and the
   linearised prediction ``|G^-1 e|`` from the window's (D, I) error e and the model gradient G at
   the GPS position.
3. INS-only drift: strapdown dead reckoning of the log's IMU (specific force rotated with the
   logged attitude) from the first GPS fix, horizontal error against GPS.
4. The fused position: :class:`companion.nav.fusion.InsGeomagFusion` with Table 3's settings,
   fed once per window with the INS position and the fix.
5. The heading the controller would have commanded: :class:`companion.nav.mission.Mission`
   (Fc-MPC, start = first GPS fix, destination = last airborne GPS position) stepped once per
   window with the measured D, I and the INS position, open-loop (its commands are not flown);
   its course against the GPS course over ground of the window the command is for.

How the segments are chosen (from the data, printed with the table): the first 3D GPS fix; on
the ground before take-off, the time the measured D steps by more than 5 degrees (the flight
controller starting to apply its declination); take-off = the first of three consecutive GPS
fixes with ground speed > 1 m/s or altitude > 1.5 m above the median of the first 10 s of
fixes; crash = the first attitude sample after take-off tilted more than 60 degrees; the
airborne span ends ``--crash-guard-s`` (10 s) before a crash, or at the last airborne-looking
fix. Within the airborne span, "hover" is tilt < 10 deg and GPS speed < 1 m/s.
"""
from __future__ import annotations

import argparse
import csv
import datetime
import json
import math
import os
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from companion import wrap_2pi
from companion.io.sensors.base import (
    AttitudeSample,
    GpsSample,
    ImuSample,
    MagSample,
    SensorError,
    StreamEnd,
)
from companion.io.sensors.attitude import mat_nb_from_euler
from companion.io.sensors.replay import LogFormat, LogReplaySource, sniff_log_format
from companion.nav.field import (
    PositionFixError,
    WorldMagneticModel,
    decl_incl_gradient,
    geomagnetic_fix,
)
from companion.nav.fusion import FusionSettings, InsGeomagFusion
from companion.nav.geo import enu_offset, geodesic_distance_m, geodesic_inverse, offset_position
from companion.nav.magnetometer import PeriodAverager, SpikeFilter, tilt_compensated_di
from companion.nav.mission import Measurement, Mission, Phase
from companion.params import Controller, NavConfig, default_values

__all__ = [
    "LogData",
    "Segments",
    "ReplayEvaluation",
    "read_log",
    "find_segments",
    "select_model",
    "log_decimal_year",
    "evaluate",
    "format_report",
    "write_outputs",
    "main",
]

# World Magnetic Models shipped inside pygeomag, oldest first (auto-selection takes the newest
# model whose validity span holds the log's date).
PYGEOMAG_MODELS = {
    "WMM2010": "WMM_2010.COF",
    "WMM2015": "WMM_2015.COF",
    "WMM2015V2": "WMM_2015v2.COF",
    "WMM2020": "WMM_2020.COF",
    "WMM2025": "WMM_2025.COF",
}
_AUTO_ORDER = ("WMM2010", "WMM2015", "WMM2020", "WMM2025")

GPS_EPOCH = datetime.datetime(1980, 1, 6, tzinfo=datetime.timezone.utc)
DEFAULT_WINDOWS_S = (1.0, 10.0, 30.0)
INS_REPORT_S = (10.0, 30.0, 60.0)

# Segment rules (see the module docstring).
TAKEOFF_SPEED_MPS = 1.0
TAKEOFF_CLIMB_M = 1.5
TAKEOFF_CONSECUTIVE = 3
GROUND_REFERENCE_S = 10.0
CRASH_TILT_DEG = 60.0
HOVER_TILT_DEG = 10.0
HOVER_SPEED_MPS = 1.0
DECL_STEP_DEG = 5.0
DECL_STEP_HALF_S = 3.0
MOVING_COURSE_MPS = 1.0      # a window's course over ground is defined above this mean speed
SPIKE_NT = 5000.0            # COMP_SPIKE_NT default


# --------------------------------------------------------------------------------------------
# Reading the log
# --------------------------------------------------------------------------------------------


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


def log_decimal_year(data: LogData) -> tuple[float, str] | None:
    """(decimal year, ISO date) of the first 3D GPS fix, from the log's GPS time; None if unknown.

    tlog: GPS_RAW_INT's UNIX time_usec (the replay source's ``utc_s``). DataFlash: the first GPS
    record with a 3D fix carries the GPS week (``Week``/``GWk``) and time of week (``TimeMS``/
    ``GMS``, ms), read here with pymavlink (leap seconds are irrelevant for a decimal year).
    """
    when: datetime.datetime | None = None
    if data.gps_utc_s is not None:
        when = datetime.datetime.fromtimestamp(data.gps_utc_s, tz=datetime.timezone.utc)
    elif data.format == LogFormat.DATAFLASH:
        from pymavlink import DFReader

        reader = DFReader.DFReader_binary(str(data.path))
        try:
            while True:
                msg = reader.recv_match(type=["GPS"])
                if msg is None:
                    break
                if getattr(msg, "Status", 0) < 3:
                    continue
                week = getattr(msg, "GWk", getattr(msg, "Week", None))
                tow_ms = getattr(msg, "GMS", None)
                if tow_ms is None and getattr(msg, "T", None) is not None:
                    tow_ms = getattr(msg, "TimeMS", None)  # Copter 3.3: TimeMS is GPS time of week
                if week and tow_ms is not None:
                    when = GPS_EPOCH + datetime.timedelta(weeks=int(week), milliseconds=float(tow_ms))
                break
        finally:
            reader.close()
    if when is None:
        return None
    start = datetime.datetime(when.year, 1, 1, tzinfo=datetime.timezone.utc)
    end = datetime.datetime(when.year + 1, 1, 1, tzinfo=datetime.timezone.utc)
    return when.year + (when - start) / (end - start), when.date().isoformat()


def _pygeomag_cof(name: str) -> Path:
    import pygeomag

    return Path(pygeomag.__file__).resolve().parent / "wmm" / PYGEOMAG_MODELS[name]


def select_model(spec: str | None, year: float | None) -> tuple[WorldMagneticModel, str]:
    """The model and a line saying why: ``spec`` = a name (WMM2015), a .COF path, or None (auto)."""
    if spec:
        key = spec.upper().replace("-", "").replace("_", "")
        if key in PYGEOMAG_MODELS:
            model = WorldMagneticModel.from_cof(_pygeomag_cof(key))
            why = f"{model.name} (--model {spec}, pygeomag's {PYGEOMAG_MODELS[key]})"
        elif Path(spec).is_file():
            model = WorldMagneticModel.from_cof(spec)
            why = f"{model.name} (--model {spec})"
        else:
            raise ValueError(f"--model {spec!r}: neither one of {sorted(PYGEOMAG_MODELS)} nor a .COF file")
        if year is not None and not model.valid_from <= year < model.valid_until:
            raise ValueError(f"{model.name} is valid {model.valid_from:.3f}..{model.valid_until:.1f}, "
                             f"the log is from {year:.2f}")
        return model, why
    if year is None:
        raise ValueError("the log carries no GPS date; pass --model (e.g. --model WMM2015)")
    for key in reversed(_AUTO_ORDER):
        model = WorldMagneticModel.from_cof(_pygeomag_cof(key))
        if model.valid_from <= year < model.valid_until:
            return model, f"{model.name} (auto: the log's date is {year:.2f})"
    raise ValueError(f"no shipped World Magnetic Model covers {year:.2f}; pass --model path.COF")


# --------------------------------------------------------------------------------------------
# Segments
# --------------------------------------------------------------------------------------------


@dataclass
class Segments:
    """Times (log seconds) that split the flight; None when the data shows no such event."""

    first_fix_s: float
    ground_alt_m: float
    decl_step_s: float | None
    takeoff_s: float | None
    crash_s: float | None
    end_s: float
    rules: list[str] = field(default_factory=list)

    @property
    def nav_start_s(self) -> float:
        """Start of the span the navigation is judged on: take-off, else the first fix."""
        return self.takeoff_s if self.takeoff_s is not None else self.first_fix_s


def _tilt_deg(att: np.ndarray) -> np.ndarray:
    return np.degrees(np.maximum(np.abs(_wrap_pi(att[:, 1])), np.abs(_wrap_pi(att[:, 2]))))


def _wrap_pi(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def _wrap180(a: Any) -> Any:
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def find_segments(data: LogData, decl_t: np.ndarray, decl_deg: np.ndarray, crash_guard_s: float = 10.0) -> Segments:
    """Segment times from GPS, attitude and the measured D (rules in the module docstring)."""
    gps = data.gps
    t = gps[:, 0]
    first_fix = float(t[0])
    ground_alt = float(np.median(gps[t <= first_fix + GROUND_REFERENCE_S, 3]))
    speed = np.hypot(gps[:, 4], gps[:, 5])
    flying = (np.nan_to_num(speed) > TAKEOFF_SPEED_MPS) | (gps[:, 3] > ground_alt + TAKEOFF_CLIMB_M)
    run = np.convolve(flying.astype(int), np.ones(TAKEOFF_CONSECUTIVE, dtype=int), mode="valid")
    hits = np.flatnonzero(run == TAKEOFF_CONSECUTIVE)
    takeoff = float(t[hits[0]]) if len(hits) else None
    rules = [
        f"first 3D GPS fix at {first_fix:.1f} s; ground altitude {ground_alt:.1f} m "
        f"(median of the first {GROUND_REFERENCE_S:.0f} s of fixes)",
    ]
    crash = None
    end = float(t[-1])
    if takeoff is None:
        rules.append("no take-off found (GPS never faster than 1 m/s nor 1.5 m above ground): "
                     "the whole log after the first fix is evaluated as one segment")
    else:
        rules.append(f"take-off at {takeoff:.1f} s: first of {TAKEOFF_CONSECUTIVE} consecutive fixes with "
                     f"ground speed > {TAKEOFF_SPEED_MPS:g} m/s or altitude > ground + {TAKEOFF_CLIMB_M:g} m")
        att = data.att
        after = att[:, 0] > takeoff
        over = np.flatnonzero(after & (_tilt_deg(att) > CRASH_TILT_DEG))
        if len(over):
            crash = float(att[over[0], 0])
        airborne_fixes = t[flying & (t >= takeoff)]
        end = float(airborne_fixes[-1])
        if crash is not None:
            end = min(end, crash - crash_guard_s)
            rules.append(f"crash at {crash:.1f} s: first attitude tilted > {CRASH_TILT_DEG:g} deg after take-off; "
                         f"the airborne span ends {crash_guard_s:g} s earlier, at {end:.1f} s")
        else:
            rules.append(f"no crash (tilt never > {CRASH_TILT_DEG:g} deg); the airborne span ends at the last "
                         f"airborne-looking fix, {end:.1f} s")
    # The declination step on the ground: largest jump between the medians of D over the
    # DECL_STEP_HALF_S before and after a time, if larger than DECL_STEP_DEG.
    step = None
    ground_end = takeoff if takeoff is not None else end
    sel = (decl_t >= first_fix) & (decl_t < ground_end)
    if sel.sum() > 10:
        times, values = decl_t[sel], decl_deg[sel]
        best, best_t = 0.0, None
        for k in range(len(times)):
            before = values[(times >= times[k] - DECL_STEP_HALF_S) & (times < times[k])]
            later = values[(times >= times[k]) & (times < times[k] + DECL_STEP_HALF_S)]
            if len(before) < 5 or len(later) < 5:
                continue
            jump = abs(float(_wrap180(np.median(later) - np.median(before))))
            if jump > best:
                best, best_t = jump, float(times[k])
        if best_t is not None and best > DECL_STEP_DEG:
            step = best_t
            rules.append(f"declination step on the ground at {step:.1f} s (median D jumps {best:.1f} deg: the "
                         "flight controller starts applying its declination); the ground data before it is "
                         "excluded from the judgement")
    if takeoff is not None:
        rules.append(f"hover = airborne with tilt < {HOVER_TILT_DEG:g} deg and GPS speed < {HOVER_SPEED_MPS:g} m/s")
    return Segments(first_fix, ground_alt, step, takeoff, crash, end, rules)


# --------------------------------------------------------------------------------------------
# Evaluation
# --------------------------------------------------------------------------------------------


@dataclass
class DIRow:
    segment: str
    start_s: float
    end_s: float
    n: int
    decl_meas_deg: float
    decl_wmm_deg: float
    decl_bias_deg: float
    decl_std_deg: float
    incl_meas_deg: float
    incl_wmm_deg: float
    incl_bias_deg: float
    incl_std_deg: float
    f_bias_nt: float
    judged: bool


@dataclass
class WindowRecord:
    """One averaging window of the navigation span, for one window length."""

    window_s: float
    start_s: float
    end_s: float
    centre_s: float
    count: int
    decl_deg: float
    incl_deg: float
    err_decl_deg: float
    err_incl_deg: float
    predicted_m: float
    predicted_noise_m: float = math.nan
    fix_error_m: float = math.nan
    fix_failed: str = ""
    ins_error_m: float = math.nan
    fused_error_m: float = math.nan
    fused_sigma_m: float = math.nan
    command_phase: str = ""
    command_course_deg: float = math.nan
    flown_course_deg: float = math.nan
    ideal_course_deg: float = math.nan
    mission_est_error_m: float = math.nan


@dataclass
class FixRow:
    window_s: float
    n: int
    failed: int
    err_decl_mean_deg: float
    err_decl_std_deg: float
    err_incl_mean_deg: float
    err_incl_std_deg: float
    fix_median_m: float
    fix_p90_m: float
    predicted_median_m: float
    predicted_p90_m: float
    ratio_median: float
    ratio_min: float
    ratio_max: float
    predicted_noise_median_m: float


@dataclass
class InsRow:
    name: str
    start_s: float
    errors_m: dict[str, float]


@dataclass
class FusedRow:
    window_s: float
    steps: int
    fused_median_m: float
    fused_p90_m: float
    fused_final_m: float
    ins_median_m: float
    fix_median_m: float
    sigma_final_m: float


@dataclass
class HeadingRow:
    window_s: float
    steps: int
    compared: int
    median_abs_diff_deg: float
    ideal_median_abs_diff_deg: float
    final_phase: str
    reason: str
    est_error_median_m: float


@dataclass
class ReplayEvaluation:
    log: str
    format: str
    model: str
    model_note: str
    date: str | None
    decimal_year: float
    mag_instance: int
    counts: dict[str, int]
    first_s: dict[str, float]
    last_s: dict[str, float]
    flagged: dict[str, int]
    truncated: bool
    end_detail: str
    segments: Segments
    gradient_deg_per_km: list[list[float]]
    gradient_singular_deg_per_km: list[float]
    wmm_at_start: dict[str, float]
    spikes_rejected: int
    di_rows: list[DIRow]
    fix_rows: list[FixRow]
    ins_rows: list[InsRow]
    fused_rows: list[FusedRow]
    heading_rows: list[HeadingRow]
    windows: list[WindowRecord]
    mission_note: str
    prior_offset_m: tuple[float, float]
    mag_rate_hz: float = math.nan
    source_note: str = ""
    # time series for the plots (not in summary.json)
    series: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def span_s(self) -> tuple[float, float]:
        return min(self.first_s.values()), max(self.last_s.values())

    def di_row(self, segment: str) -> DIRow | None:
        return next((r for r in self.di_rows if r.segment == segment), None)

    def fix_row(self, window_s: float) -> FixRow | None:
        return next((r for r in self.fix_rows if r.window_s == window_s), None)


def _interp_gps(gps: np.ndarray, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GPS latitude, longitude, altitude interpolated at times t (held at the ends)."""
    return (np.interp(t, gps[:, 0], gps[:, 1]), np.interp(t, gps[:, 0], gps[:, 2]),
            np.interp(t, gps[:, 0], gps[:, 3]))


def _percentile(values: list[float] | np.ndarray, q: float) -> float:
    a = np.asarray([v for v in values if math.isfinite(v)], dtype=float)
    return float(np.percentile(a, q)) if len(a) else math.nan


def _ins_track(data: LogData, start_s: float, ref: tuple[float, float],
               bias_body: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Horizontal strapdown dead reckoning from ``start_s``: (t, east_m, north_m) from ``ref``.

    Position and velocity are GPS's at ``start_s`` (the nearest fix at or after it), then only the
    IMU: the specific force of IMU 0, minus ``bias_body``, rotated into NED with the logged
    attitude interpolated to each IMU sample, integrated twice (trapezoid). Gravity has no
    horizontal component, so no gravity model enters the horizontal channel.
    """
    gps, imu, att = data.gps, data.imu, data.att
    k0 = min(int(np.searchsorted(gps[:, 0], start_s)), len(gps) - 1)
    t0 = gps[k0, 0]
    e0, n0 = enu_offset(ref[0], ref[1], gps[k0, 1], gps[k0, 2])
    vn0, ve0 = np.nan_to_num(gps[k0, 4]), np.nan_to_num(gps[k0, 5])
    sel = imu[:, 0] >= t0
    ti = np.concatenate([[t0], imu[sel, 0]])
    f_b = imu[sel, 1:4]
    if bias_body is not None:
        f_b = f_b - bias_body
    r = np.interp(imu[sel, 0], att[:, 0], att[:, 1])
    p = np.interp(imu[sel, 0], att[:, 0], att[:, 2])
    y = np.interp(imu[sel, 0], att[:, 0], att[:, 3])
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    # first two rows of mat_nb_from_euler (north, east), vectorised
    a_n = cp * cy * f_b[:, 0] + (sr * sp * cy - cr * sy) * f_b[:, 1] + (cr * sp * cy + sr * sy) * f_b[:, 2]
    a_e = cp * sy * f_b[:, 0] + (sr * sp * sy + cr * cy) * f_b[:, 1] + (cr * sp * sy - sr * cy) * f_b[:, 2]
    a_n = np.concatenate([[a_n[0] if len(a_n) else 0.0], a_n])
    a_e = np.concatenate([[a_e[0] if len(a_e) else 0.0], a_e])
    dt = np.diff(ti)
    v_n = vn0 + np.concatenate([[0.0], np.cumsum(0.5 * (a_n[1:] + a_n[:-1]) * dt)])
    v_e = ve0 + np.concatenate([[0.0], np.cumsum(0.5 * (a_e[1:] + a_e[:-1]) * dt)])
    p_n = float(n0) + np.concatenate([[0.0], np.cumsum(0.5 * (v_n[1:] + v_n[:-1]) * dt)])
    p_e = float(e0) + np.concatenate([[0.0], np.cumsum(0.5 * (v_e[1:] + v_e[:-1]) * dt)])
    return ti, p_e, p_n


def _stationary_bias(data: LogData, start_s: float, end_s: float) -> np.ndarray | None:
    """Accelerometer bias in the body frame from a stationary period (static alignment).

    ``b = mean(f_b) - C_bn (0, 0, -|mean f_b|)``: what makes the mean horizontal specific force
    zero at rest. It absorbs the horizontal accelerometer bias and the attitude's tilt error
    together, as an INS's levelling does. None if the period is shorter than 5 s.
    """
    imu, att = data.imu, data.att
    sel = (imu[:, 0] >= start_s) & (imu[:, 0] < end_s)
    if end_s - start_s < 5.0 or sel.sum() < 50:
        return None
    f_mean = imu[sel, 1:4].mean(axis=0)
    t_mid = float(np.median(imu[sel, 0]))
    c = np.array(mat_nb_from_euler(*(float(np.interp(t_mid, att[:, 0], att[:, k])) for k in (1, 2, 3))))
    return f_mean - c.T @ np.array([0.0, 0.0, -float(np.linalg.norm(f_mean))])


def evaluate(
    path: str | os.PathLike[str],
    model_spec: str | None = None,
    windows_s: tuple[float, ...] = DEFAULT_WINDOWS_S,
    prior_offset_km: float = 10.0,
    crash_guard_s: float = 10.0,
    mag_instance: int = 0,
) -> ReplayEvaluation:
    """Run the whole evaluation; raises SensorError/ValueError with a clear message on bad input."""
    data = read_log(path, mag_instance)
    if len(data.gps) < 2:
        raise ValueError(f"{path}: fewer than two 3D GPS fixes; the evaluation needs the log's GPS as truth")
    if len(data.mag) < 2 or len(data.att) < 2:
        raise ValueError(f"{path}: needs magnetometer {mag_instance} and attitude samples "
                         f"(got {len(data.mag)} and {len(data.att)})")
    dated = log_decimal_year(data)
    year, date = (dated if dated is not None else (None, None))
    model, model_note = select_model(model_spec, year)
    if year is None:
        year = 0.5 * (model.valid_from + model.valid_until)
        model_note += f"; no date in the log, evaluated at {year:.2f}"

    gps, att = data.gps, data.att
    # --- 1. per-sample D, I (measured) and the model at the GPS position ------------------------
    mag = data.mag[(data.mag[:, 0] >= gps[0, 0]) & (data.mag[:, 0] <= gps[-1, 0])]
    t_m = mag[:, 0]
    roll = np.interp(t_m, att[:, 0], att[:, 1])
    pitch = np.interp(t_m, att[:, 0], att[:, 2])
    yaw = np.interp(t_m, att[:, 0], att[:, 3])
    spikes = SpikeFilter(SPIKE_NT)
    meas = np.full((len(mag), 4), np.nan)  # D, I, |F|, accepted
    for k, row in enumerate(mag):
        d, i, ned = tilt_compensated_di((row[1], row[2], row[3]), roll[k], pitch[k], yaw[k])
        meas[k] = (d, i, math.sqrt(ned[0] ** 2 + ned[1] ** 2 + ned[2] ** 2), 1.0 if spikes.accept(ned) else 0.0)
    lat_m, lon_m, alt_m = _interp_gps(gps, t_m)
    wmm = model.elements(lat_m, lon_m, alt_m, year)
    err_d = _wrap180(meas[:, 0] - wmm.decl_deg)
    err_i = meas[:, 1] - wmm.incl_deg
    err_f = meas[:, 2] - wmm.f_nt
    accepted = meas[:, 3] > 0.5

    seg = find_segments(data, t_m, meas[:, 0], crash_guard_s)
    tilt_m = np.degrees(np.maximum(np.abs(_wrap_pi(roll)), np.abs(_wrap_pi(pitch))))
    speed_m = np.hypot(np.interp(t_m, gps[:, 0], np.nan_to_num(gps[:, 4])),
                       np.interp(t_m, gps[:, 0], np.nan_to_num(gps[:, 5])))
    nav0, nav1 = seg.nav_start_s, seg.end_s
    in_nav = (t_m >= nav0) & (t_m <= nav1)
    segment_masks: list[tuple[str, float, float, np.ndarray, bool]] = []
    ground_end = seg.takeoff_s if seg.takeoff_s is not None else nav1
    if seg.decl_step_s is not None:
        segment_masks.append(("ground, before declination applied", seg.first_fix_s, seg.decl_step_s,
                              (t_m >= seg.first_fix_s) & (t_m < seg.decl_step_s), False))
        segment_masks.append(("ground, declination applied", seg.decl_step_s, ground_end,
                              (t_m >= seg.decl_step_s) & (t_m < ground_end), False))
    elif seg.takeoff_s is not None:
        segment_masks.append(("ground", seg.first_fix_s, ground_end,
                              (t_m >= seg.first_fix_s) & (t_m < ground_end), False))
    label = "airborne" if seg.takeoff_s is not None else "whole log after first fix"
    segment_masks.append((label, nav0, nav1, in_nav, True))
    if seg.takeoff_s is not None:
        hover = in_nav & (tilt_m < HOVER_TILT_DEG) & (speed_m < HOVER_SPEED_MPS)
        segment_masks.append(("airborne, hover", nav0, nav1, hover, True))
        segment_masks.append(("airborne, moving or tilted", nav0, nav1, in_nav & ~hover, True))
    if seg.crash_s is not None:
        segment_masks.append((f"crash - {crash_guard_s:g} s and after (excluded)", seg.end_s, float(t_m[-1]),
                              t_m > seg.end_s, False))
    di_rows = []
    for name, a, b, mask, judged in segment_masks:
        m = mask & accepted
        n = int(m.sum())
        if n == 0:
            continue
        di_rows.append(DIRow(
            name, a, b, n,
            float(wmm.decl_deg[m].mean() + err_d[m].mean()), float(wmm.decl_deg[m].mean()),
            float(err_d[m].mean()), float(err_d[m].std()),
            float(meas[m, 1].mean()), float(wmm.incl_deg[m].mean()),
            float(err_i[m].mean()), float(err_i[m].std()), float(err_f[m].mean()), judged))

    # --- references -------------------------------------------------------------------------------
    ref = (float(gps[0, 1]), float(gps[0, 2]))  # the first 3D fix: INS start, mission start, frame
    k_end = int(np.clip(np.searchsorted(gps[:, 0], nav1, side="right") - 1, 0, len(gps) - 1))
    dest = (float(gps[k_end, 1]), float(gps[k_end, 2]))
    g_ref = decl_incl_gradient(model, ref[0], ref[1], seg.ground_alt_m, year)
    sv = np.linalg.svd(g_ref, compute_uv=False)
    start_el = model.elements(ref[0], ref[1], seg.ground_alt_m, year)
    prior_offset = (prior_offset_km * 1e3 / math.sqrt(2.0),) * 2  # north-east of the truth

    # --- 3. INS ----------------------------------------------------------------------------------
    gps_e, gps_n = enu_offset(ref[0], ref[1], gps[:, 1], gps[:, 2])
    ins_rows: list[InsRow] = []
    rest_end = (seg.takeoff_s - 2.0) if seg.takeoff_s is not None else seg.first_fix_s
    bias = _stationary_bias(data, seg.first_fix_s, rest_end)
    tracks: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    ins_defs = [("INS, raw IMU, from first fix", seg.first_fix_s, None)]
    if bias is not None:
        ins_defs.append(("INS, static alignment, from first fix", seg.first_fix_s, bias))
        if seg.takeoff_s is not None:
            ins_defs.append(("INS, static alignment, from take-off", seg.takeoff_s, bias))
    for name, start, b in ins_defs:
        ti, pe, pn = _ins_track(data, start, ref, b)
        tracks[name] = (ti, pe, pn)
        err = np.hypot(pe - np.interp(ti, gps[:, 0], gps_e), pn - np.interp(ti, gps[:, 0], gps_n))
        errors = {}
        for dt_s in INS_REPORT_S:
            errors[f"+{dt_s:g} s"] = float(np.interp(ti[0] + dt_s, ti, err)) if ti[0] + dt_s <= ti[-1] else math.nan
        errors["end of airborne span"] = float(np.interp(nav1, ti, err)) if nav1 <= ti[-1] else math.nan
        ins_rows.append(InsRow(name, float(ti[0]), errors))
    nav_ins_name = ins_defs[1][0] if len(ins_defs) > 1 else ins_defs[0][0]
    ins_t, ins_e, ins_n = tracks[nav_ins_name]

    def ins_latlon(t: float) -> tuple[float, float]:
        la, lo = offset_position(ref[0], ref[1], float(np.interp(t, ins_t, ins_e)), float(np.interp(t, ins_t, ins_n)))
        return float(la), float(lo)

    # --- 2, 4, 5: per window ---------------------------------------------------------------------
    rate_hz = 1.0 / float(np.median(np.diff(t_m))) if len(t_m) > 1 else 10.0
    airborne_speed = np.hypot(gps[:, 4], gps[:, 5])[(gps[:, 0] >= nav0) & (gps[:, 0] <= nav1)]
    cruise_mps = max(1.0, float(np.nanmedian(airborne_speed))) if len(airborne_speed) else 1.0
    fix_rows: list[FixRow] = []
    fused_rows: list[FusedRow] = []
    heading_rows: list[HeadingRow] = []
    all_windows: list[WindowRecord] = []
    mission_note = (
        f"Fc-MPC, start = first fix ({ref[0]:.6f}, {ref[1]:.6f}), destination = last airborne fix "
        f"({dest[0]:.6f}, {dest[1]:.6f}), {geodesic_distance_m(*ref, *dest):.0f} m apart; cruise speed "
        f"{cruise_mps:.1f} m/s (median airborne GPS speed), period = window; state bounds widened to "
        f"D in [-180, 180], I in [-90, 90] deg (Table 4's I in [10, 100] excludes the southern hemisphere)")
    for w in windows_s:
        recs: list[WindowRecord] = []
        fix_pos: list[tuple[float, float] | None] = []
        averager = PeriodAverager()
        sel = np.flatnonzero(in_nav & accepted)
        for k in sel:
            averager.add(float(t_m[k]), float(meas[k, 0]), float(meas[k, 1]))
        edges = np.arange(nav0, nav1 - w + 1e-9, w)
        for a in edges:
            b = a + w
            avg = averager.take(b - 1e-9)
            if avg.count < max(1, int(0.5 * w * rate_hz)):
                continue
            tc = avg.mean_time_s
            la, lo, al = (float(v) for v in _interp_gps(gps, tc))
            decl, incl, g = _model_di_gradient(model, la, lo, al, year)
            e = np.array([float(_wrap180(avg.decl_deg - decl)), avg.incl_deg - incl])
            pred = float(np.hypot(*np.linalg.solve(g, e)))
            rec = WindowRecord(w, float(a), float(b), float(tc), avg.count, avg.decl_deg, avg.incl_deg,
                               float(e[0]), float(e[1]), pred)
            prior = offset_position(la, lo, *prior_offset)
            try:
                fix = geomagnetic_fix(model, avg.decl_deg, avg.incl_deg, float(prior[0]), float(prior[1]), al, year)
                rec.fix_error_m = geodesic_distance_m(fix.lat_deg, fix.lon_deg, la, lo)
                fix_pos.append((fix.lat_deg, fix.lon_deg))
            except PositionFixError as err:
                rec.fix_failed = str(err)
                fix_pos.append(None)
            recs.append(rec)
        if not recs:
            continue
        mean_e = np.array([np.mean([r.err_decl_deg for r in recs]), np.mean([r.err_incl_deg for r in recs])])
        for r in recs:
            la, lo, al = (float(v) for v in _interp_gps(gps, r.centre_s))
            g = _model_di_gradient(model, la, lo, al, year)[2]
            e_noise = np.array([r.err_decl_deg, r.err_incl_deg]) - mean_e
            r.predicted_noise_m = float(np.hypot(*np.linalg.solve(g, e_noise)))
        fixes = [r.fix_error_m for r in recs]
        preds = [r.predicted_m for r in recs]
        ratios = [r.fix_error_m / r.predicted_m for r in recs if math.isfinite(r.fix_error_m) and r.predicted_m > 0]
        fix_rows.append(FixRow(
            w, len(recs), sum(1 for r in recs if r.fix_failed),
            float(mean_e[0]), float(np.std([r.err_decl_deg for r in recs])),
            float(mean_e[1]), float(np.std([r.err_incl_deg for r in recs])),
            _percentile(fixes, 50), _percentile(fixes, 90), _percentile(preds, 50), _percentile(preds, 90),
            _percentile(ratios, 50), min(ratios) if ratios else math.nan, max(ratios) if ratios else math.nan,
            _percentile([r.predicted_noise_m for r in recs], 50)))

        # 4. fusion, Table 3 settings, in local metres from the first fix
        fusion = InsGeomagFusion(FusionSettings())
        for r, fixed in zip(recs, fix_pos):
            ie, inn = float(np.interp(r.centre_s, ins_t, ins_e)), float(np.interp(r.centre_s, ins_t, ins_n))
            ge, gn = float(np.interp(r.centre_s, gps[:, 0], gps_e)), float(np.interp(r.centre_s, gps[:, 0], gps_n))
            r.ins_error_m = math.hypot(ie - ge, inn - gn)
            if fixed is not None:
                fe, fn = enu_offset(ref[0], ref[1], *fixed)
                res = fusion.step(np.array([ie, inn]), np.array([float(fe), float(fn)]))
            else:
                res = fusion.predict_only(np.array([ie, inn]))
            r.fused_error_m = math.hypot(res.east_m - ge, res.north_m - gn)
            r.fused_sigma_m = res.sigma_m
        fused_rows.append(FusedRow(
            w, len(recs), _percentile([r.fused_error_m for r in recs], 50),
            _percentile([r.fused_error_m for r in recs], 90), recs[-1].fused_error_m,
            _percentile([r.ins_error_m for r in recs], 50), _percentile(fixes, 50), recs[-1].fused_sigma_m))

        # 5. the mission, open-loop: the command issued at the end of window k is for window k+1
        heading_rows.append(_run_mission(recs, w, model, year, ref, dest, seg.ground_alt_m, cruise_mps,
                                         gps, gps_e, gps_n, ins_latlon))
        all_windows += recs

    series = {
        "t_mag": t_m, "decl_meas": meas[:, 0], "incl_meas": meas[:, 1], "decl_wmm": np.asarray(wmm.decl_deg),
        "incl_wmm": np.asarray(wmm.incl_deg), "accepted": accepted,
        "t_gps": gps[:, 0], "gps_e": np.asarray(gps_e), "gps_n": np.asarray(gps_n),
    }
    for name, (ti, pe, pn) in tracks.items():
        series[f"ins:{name}"] = np.column_stack([ti, pe, pn])
    return ReplayEvaluation(
        log=str(path), format=data.format, model=model.name, model_note=model_note, date=date,
        decimal_year=float(year), mag_instance=mag_instance, counts=dict(data.counts),
        first_s=dict(data.first_s), last_s=dict(data.last_s), flagged=dict(data.flagged),
        truncated=data.end.truncated, end_detail=data.end.detail, segments=seg,
        gradient_deg_per_km=(g_ref * 1e3).tolist(), gradient_singular_deg_per_km=(sv * 1e3).tolist(),
        wmm_at_start={"decl_deg": float(start_el.decl_deg), "incl_deg": float(start_el.incl_deg),
                      "f_nt": float(start_el.f_nt)},
        spikes_rejected=int((~accepted).sum()), di_rows=di_rows, fix_rows=fix_rows, ins_rows=ins_rows,
        fused_rows=fused_rows, heading_rows=heading_rows, windows=all_windows, mission_note=mission_note,
        prior_offset_m=prior_offset, mag_rate_hz=rate_hz, source_note=_source_note(Path(path)), series=series)


def _source_note(path: Path) -> str:
    """A pointer to the log's provenance file (``<stem>.SOURCE.md`` beside it), if there is one."""
    note = path.with_name(path.stem + ".SOURCE.md")
    return f"source and licence of the log: {note.name}" if note.is_file() else ""


def _model_di_gradient(model: WorldMagneticModel, lat: float, lon: float, alt: float,
                       year: float) -> tuple[float, float, np.ndarray]:
    el = model.elements(lat, lon, alt, year)
    return float(el.decl_deg), float(el.incl_deg), decl_incl_gradient(model, lat, lon, alt, year)


def _course_deg(gps: np.ndarray, gps_e: np.ndarray, gps_n: np.ndarray, a: float, b: float) -> float:
    """GPS course over ground (deg from north) over [a, b]; NaN when slower than MOVING_COURSE_MPS."""
    de = float(np.interp(b, gps[:, 0], gps_e) - np.interp(a, gps[:, 0], gps_e))
    dn = float(np.interp(b, gps[:, 0], gps_n) - np.interp(a, gps[:, 0], gps_n))
    if math.hypot(de, dn) < MOVING_COURSE_MPS * (b - a):
        return math.nan
    return math.degrees(wrap_2pi(math.atan2(de, dn)))


def _run_mission(recs: list[WindowRecord], w: float, model: WorldMagneticModel, year: float,
                 ref: tuple[float, float], dest: tuple[float, float], alt: float, cruise_mps: float,
                 gps: np.ndarray, gps_e: np.ndarray, gps_n: np.ndarray, ins_latlon) -> HeadingRow:
    config = NavConfig.from_values(default_values()).replace(
        start_lat_deg=ref[0], start_lon_deg=ref[1], dest_lat_deg=dest[0], dest_lon_deg=dest[1],
        alt_m=alt, year=year, speed_mps=cruise_mps, period_s=w, controller=Controller.FC,
        # a probe moves speed * T, of which the gradient sees half after the window-centre correction
        grad_min_move_m=min(1.0, 0.25 * cruise_mps * w), arrive_m=5.0, max_steps=100_000,
        s_min_d=-180.0, s_max_d=180.0, s_min_i=-90.0, s_max_i=90.0)
    mission = Mission(config, model)
    diffs, ideal_diffs, est_errors = [], [], []
    last_phase, reason = "", ""
    for k, r in enumerate(recs):
        ins_lat, ins_lon = ins_latlon(r.end_s)
        cmd = mission.step(Measurement(r.end_s, r.decl_deg, r.incl_deg, ins_lat, ins_lon, window_s=w))
        last_phase, reason = cmd.phase, cmd.reason
        if cmd.phase == Phase.CRUISE:
            la, lo, _ = _interp_gps(gps, r.end_s)
            est_errors.append(geodesic_distance_m(cmd.est_lat_deg, cmd.est_lon_deg, float(la), float(lo)))
        if k + 1 >= len(recs):
            break
        nxt = recs[k + 1]
        nxt.command_phase = cmd.phase
        nxt.command_course_deg = math.degrees(cmd.course_rad)
        nxt.flown_course_deg = _course_deg(gps, gps_e, gps_n, nxt.start_s, nxt.end_s)
        la, lo, _ = _interp_gps(gps, nxt.start_s)
        nxt.ideal_course_deg = math.degrees(geodesic_inverse(float(la), float(lo), *dest)[1])
        if cmd.done:
            break
        if cmd.phase == Phase.CRUISE and math.isfinite(nxt.flown_course_deg):
            diffs.append(abs(float(_wrap180(nxt.command_course_deg - nxt.flown_course_deg))))
            ideal_diffs.append(abs(float(_wrap180(nxt.ideal_course_deg - nxt.flown_course_deg))))
        if nxt.command_phase == Phase.CRUISE:
            nxt.mission_est_error_m = est_errors[-1] if est_errors else math.nan
    return HeadingRow(w, mission.k, len(diffs), _percentile(diffs, 50), _percentile(ideal_diffs, 50),
                      last_phase, reason, _percentile(est_errors, 50))


# --------------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------------


def _f(value: float, digits: int = 2) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _km(value_m: float) -> str:
    if value_m is None or not math.isfinite(value_m):
        return "n/a"
    return f"{value_m / 1e3:.1f}" if value_m >= 10e3 else f"{value_m / 1e3:.2f}"


def format_report(ev: ReplayEvaluation) -> str:
    """The markdown report (what is printed and written to table.md)."""
    seg = ev.segments
    lines: list[str] = []
    add = lines.append
    t0, t1 = ev.span_s
    add(f"# Replay evaluation of `{Path(ev.log).name}` against its own GPS")
    add("")
    add(f"- Log: {ev.format}, {t1 - t0:.1f} s of sensor data ({t0:.1f}-{t1:.1f} s log time)"
        + (f", date {ev.date} (decimal year {ev.decimal_year:.2f})" if ev.date else "")
        + (f"; TRUNCATED: {ev.end_detail}" if ev.truncated else "") + ".")
    add(f"- Field model: {ev.model_note}. At the first fix: D {ev.wmm_at_start['decl_deg']:.2f} deg, "
        f"I {ev.wmm_at_start['incl_deg']:.2f} deg, F {ev.wmm_at_start['f_nt']:.0f} nT; gradient G = "
        f"[[{ev.gradient_deg_per_km[0][0]:.4f}, {ev.gradient_deg_per_km[0][1]:.4f}], "
        f"[{ev.gradient_deg_per_km[1][0]:.4f}, {ev.gradient_deg_per_km[1][1]:.4f}]] deg/km "
        f"(rows D, I; columns east, north), singular values {ev.gradient_singular_deg_per_km[0]:.4f} and "
        f"{ev.gradient_singular_deg_per_km[1]:.4f} deg/km.")
    counts = ", ".join(f"{k} {v}" for k, v in sorted(ev.counts.items()))
    add(f"- Samples: {counts}" + (f"; flagged: {ev.flagged}" if ev.flagged else "") + "."
        + (f" ({ev.source_note})" if ev.source_note else ""))
    add(f"- Magnetometer: instance {ev.mag_instance} (body field as logged, i.e. after the flight controller's "
        f"offsets and soft-iron correction); {ev.spikes_rejected} samples rejected by the "
        f"{SPIKE_NT:.0f} nT spike filter.")
    add("- Segments, chosen from the data: " + "; ".join(seg.rules) + ".")
    add("")
    add("## 1. D and I measured vs the model at the GPS position")
    add("")
    add("| Segment | Span (s) | Samples | D meas (deg) | D model (deg) | D bias (deg) | D spread (deg) "
        "| I meas (deg) | I model (deg) | I bias (deg) | I spread (deg) | F bias (nT) |")
    add("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in ev.di_rows:
        name = r.segment if r.judged else f"*{r.segment}*"
        add(f"| {name} | {r.start_s:.0f}-{r.end_s:.0f} | {r.n} | {r.decl_meas_deg:.2f} | {r.decl_wmm_deg:.2f} | "
            f"{r.decl_bias_deg:+.2f} | {r.decl_std_deg:.2f} | {r.incl_meas_deg:.2f} | {r.incl_wmm_deg:.2f} | "
            f"{r.incl_bias_deg:+.2f} | {r.incl_std_deg:.2f} | {r.f_bias_nt:+.0f} |")
    add("")
    add(f"Bias = mean of (measured - model), spread = standard deviation of single samples ({ev.mag_rate_hz:.0f} Hz); "
        "rows in italics are not judged. The measured D "
        "uses the logged yaw, which is the flight controller's own heading estimate computed from this compass and "
        "a declination: D is a consistency check of the flight controller, not an independent measurement. "
        "I does not depend on yaw, only on roll, pitch and the compass calibration, so the I bias is a real "
        "measurement error (calibration, mounting or local field); the F bias shows the calibration is not absolute.")
    add("")
    add("## 2. Geomagnetic position fix (eq. 49) vs GPS")
    add("")
    add(f"Fix from D, I averaged over non-overlapping windows of the airborne span, Newton from a prior "
        f"{math.hypot(*ev.prior_offset_m) / 1e3:.0f} km north-east of the GPS position; predicted = |G^-1 e| "
        f"with e the window's (D, I) error and G the model gradient at the GPS position; "
        f"'noise only' = the same with the span's mean error removed (as if the bias were calibrated out).")
    add("")
    add("| Window (s) | Windows | Fix failed | D error mean +- std (deg) | I error mean +- std (deg) "
        "| Fix error median (km) | Fix error p90 (km) | Predicted median (km) | Predicted p90 (km) "
        "| Fix / predicted median [min-max] | Noise only, predicted median (km) |")
    add("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in ev.fix_rows:
        add(f"| {r.window_s:g} | {r.n} | {r.failed} | {r.err_decl_mean_deg:+.2f} +- {r.err_decl_std_deg:.2f} | "
            f"{r.err_incl_mean_deg:+.2f} +- {r.err_incl_std_deg:.2f} | {_km(r.fix_median_m)} | {_km(r.fix_p90_m)} | "
            f"{_km(r.predicted_median_m)} | {_km(r.predicted_p90_m)} | {_f(r.ratio_median)} "
            f"[{_f(r.ratio_min)}-{_f(r.ratio_max)}] | {_km(r.predicted_noise_median_m)} |")
    add("")
    add("## 3. INS-only drift (horizontal error vs GPS, m)")
    add("")
    keys = [f"+{s:g} s" for s in INS_REPORT_S] + ["end of airborne span"]
    add("| INS | Start (s) | " + " | ".join(keys) + " |")
    add("|---|---|" + "---|" * len(keys))
    for r in ev.ins_rows:
        add(f"| {r.name} | {r.start_s:.1f} | " + " | ".join(_f(r.errors_m[k], 1) for k in keys) + " |")
    add("")
    add("Strapdown dead reckoning of IMU 0 with the logged attitude (the flight controller's GPS-aided estimate, "
        "better than a free-running MEMS attitude would be), GPS position and velocity at the start, nothing after. "
        "Static alignment: the body-frame accelerometer bias that zeroes the mean horizontal specific force while "
        "standing on the ground before take-off (levelling, no GPS).")
    add("")
    add("## 4. Fused position (Table 3 filter: Q_c 0.05 km^2, R_c 2 km^2, P_0 1 km^2) vs GPS")
    add("")
    add("| Window (s) | Steps | Fused median (km) | Fused p90 (km) | Fused at end (km) | Filter sigma at end (km) "
        "| INS alone median (m) | Fix alone median (km) |")
    add("|---|---|---|---|---|---|---|---|")
    for r in ev.fused_rows:
        add(f"| {r.window_s:g} | {r.steps} | {_km(r.fused_median_m)} | {_km(r.fused_p90_m)} | {_km(r.fused_final_m)} | "
            f"{_km(r.sigma_final_m)} | {_f(r.ins_median_m, 0)} | {_km(r.fix_median_m)} |")
    add("")
    rc_km = math.sqrt(FusionSettings().rc_m2) / 1e3
    worst = max(ev.fused_rows, key=lambda r: r.fused_median_m, default=None)
    add("The INS fed to the filter is the statically aligned one from the first fix; the filter steps once per window."
        + (f" Table 3's R_c trusts the fix to {rc_km:.1f} km (1 sigma), so with fixes hundreds of km off the filter "
           f"walks towards the fix while its own sigma ({_km(worst.sigma_final_m)} km) says nothing about its error."
           if worst is not None and worst.fused_median_m > 10e3 * rc_km else ""))
    add("")
    add("## 5. Heading the controller would have commanded vs the heading flown")
    add("")
    add(f"Mission: {ev.mission_note}. Open-loop: the commands are not flown, so the measurements come from the "
        "pilot's path, not from the commanded one. The command issued at the end of a window is compared with the "
        "GPS course over ground of the next window (windows slower than 1 m/s and the two probing steps excluded). "
        "'Ideal' = the geodesic course from the true (GPS) position to the destination, for scale: the pilot was not "
        "flying to a destination either.")
    add("")
    add("| Window (s) | Mission steps | Compared | Median abs(commanded - flown) (deg) "
        "| Median abs(ideal - flown) (deg) | Mission position error median (km) | Mission state at end |")
    add("|---|---|---|---|---|---|---|")
    for r in ev.heading_rows:
        state = r.final_phase + (f" ({r.reason})" if r.reason else "")
        add(f"| {r.window_s:g} | {r.steps} | {r.compared} | {_f(r.median_abs_diff_deg, 0)} | "
            f"{_f(r.ideal_median_abs_diff_deg, 0)} | {_km(r.est_error_median_m)} | {state} |")
    add("")
    meaning = _meaning(ev)
    if meaning:
        add("## What the numbers mean")
        add("")
        add(meaning)
        add("")
    add("## Limitations")
    add("")
    add(f"This is a {ev.segments.end_s - ev.segments.nav_start_s:.0f} s flight within "
        f"{max(1.0, _track_extent_m(ev)):.0f} m of its first fix, not the paper's measured experiment (Section 4.3: "
        "Xi'an to Jiayuguan, 1,368 km of GPS track in Table 8): the field model changes by far less across the "
        "whole flight than the sensor's noise, so it can show the size of the measurement errors and what they do "
        "to a fix, not whether Fc-MPC reaches a destination. "
        "The heading comparison is a plumbing check of the open-loop controller, not a navigation result.")
    return "\n".join(lines) + "\n"


def _averaging_words(ev: ReplayEvaluation) -> str:
    """How much longer averaging reduces the D spread (little, if the errors are correlated)."""
    rows = sorted(ev.fix_rows, key=lambda r: r.window_s)
    if len(rows) < 2:
        return ""
    a, b = rows[0], rows[-1]
    white = a.err_decl_std_deg * math.sqrt(a.window_s / b.window_s)
    if b.err_decl_std_deg < 2.0 * white:
        return ""
    return (f", and averaging longer helps little: the D spread is {a.err_decl_std_deg:.1f} deg over {a.window_s:g} s "
            f"and still {b.err_decl_std_deg:.1f} deg over {b.window_s:g} s (white noise would give {white:.1f}), "
            f"because the errors are correlated over tens of seconds (likely heading and tilt errors in manoeuvres "
            f"and motor currents), not independent from sample to sample")


def _two_figures(value: float) -> float:
    if not (math.isfinite(value) and value > 0.0):
        return value
    return round(value, 1 - int(math.floor(math.log10(value))))


def _magnitude_words(value_m: float) -> str:
    if not math.isfinite(value_m):
        return "unknown"
    for limit, words in ((1e3, "metres"), (10e3, "kilometres"), (100e3, "tens of km"), (1000e3, "hundreds of km")):
        if value_m < limit:
            return words
    return "thousands of km"


def _meaning(ev: ReplayEvaluation) -> str:
    """Position error = (D, I) error / (D, I) spatial gradient, in this log's numbers."""
    if not ev.fix_rows or not ev.ins_rows:
        return ""
    fix = ev.fix_row(10.0) or ev.fix_rows[len(ev.fix_rows) // 2]
    s_max, s_min = ev.gradient_singular_deg_per_km
    ins = next((r for r in ev.ins_rows if "from take-off" in r.name), ev.ins_rows[-1])
    good_deg = 0.1 * s_min  # (D, I) error of a 100 m fix along the weakly observable direction
    typical_deg = math.hypot(math.hypot(fix.err_decl_mean_deg, fix.err_decl_std_deg),
                             math.hypot(fix.err_incl_mean_deg, fix.err_incl_std_deg))
    minutes = (ev.segments.end_s - ev.segments.nav_start_s) / 60.0
    return (
        f"Position error is roughly the (D, I) error divided by the (D, I) spatial gradient. Here the gradient is "
        f"{s_min:.4f}-{s_max:.4f} deg/km, so every degree of error in D or I moves the fix "
        f"{1.0 / s_max:.0f}-{1.0 / s_min:.0f} km. Averaged over {fix.window_s:g} s windows of the judged span, "
        f"this magnetometer's D is off by {fix.err_decl_mean_deg:+.2f} +- {fix.err_decl_std_deg:.2f} deg and I by "
        f"{fix.err_incl_mean_deg:+.2f} +- {fix.err_incl_std_deg:.2f} deg, and the geomagnetic fix lands a median "
        f"{_km(fix.fix_median_m)} km from GPS (|G^-1 e| predicts {_km(fix.predicted_median_m)} km). Calibrating "
        f"the mean bias away perfectly would still leave {_km(fix.predicted_noise_median_m)} km from the "
        f"window-to-window spread alone{_averaging_words(ev)}. The IMU dead-reckons ({ins.name}) to "
        f"{_f(ins.errors_m['+30 s'], 0)} m after 30 s and {_f(ins.errors_m['+60 s'], 0)} m after 60 s; a fix that "
        f"helps it at the 100 m level "
        f"needs D and I right to about {good_deg:.4f} deg ({good_deg * 3600:.1f} arcsec), "
        f"about {_two_figures(typical_deg / good_deg):,.0f} times smaller than the errors measured here. On this "
        f"log the geomagnetic fix is good to {_magnitude_words(fix.fix_median_m)}: that only means something on "
        f"routes much longer "
        f"than the error, and only after a calibration of the bias against the model that a {minutes:.1f}-minute "
        f"flight at one place cannot check.")


def _track_extent_m(ev: ReplayEvaluation) -> float:
    s = ev.series
    if "gps_e" not in s or not len(s["gps_e"]):
        return 0.0
    return float(np.max(np.hypot(s["gps_e"], s["gps_n"])))


def _json_clean(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _json_clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_clean(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, (np.integer, np.bool_)):
        return value.item()
    return value


def summary_dict(ev: ReplayEvaluation) -> dict[str, Any]:
    """Everything but the time series and per-window records, JSON-ready (NaN -> null)."""
    out = {k: getattr(ev, k) for k in ev.__dataclass_fields__ if k not in ("series", "windows")}
    out = {k: asdict(v) if hasattr(v, "__dataclass_fields__") else
           [asdict(x) for x in v] if isinstance(v, list) and v and hasattr(v[0], "__dataclass_fields__") else v
           for k, v in out.items()}
    return _json_clean(out)


def write_outputs(ev: ReplayEvaluation, out: Path, plots: bool = True) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    written = [out / "table.md", out / "summary.json", out / "windows.csv"]
    (out / "table.md").write_text(format_report(ev))
    (out / "summary.json").write_text(json.dumps(summary_dict(ev), indent=1, allow_nan=False))
    with open(out / "windows.csv", "w", newline="") as handle:
        names = list(WindowRecord.__dataclass_fields__)
        writer = csv.DictWriter(handle, fieldnames=names)
        writer.writeheader()
        for r in ev.windows:
            writer.writerow({k: getattr(r, k) for k in names})
    if plots:
        written += _plots(ev, out)
    return written


def _save(fig, path: Path) -> Path:
    """Lay out, write as PNG and close a figure; returns its path."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _shade(ax, ev: ReplayEvaluation) -> None:
    seg = ev.segments
    ax.axvspan(seg.nav_start_s, seg.end_s, color="tab:green", alpha=0.08, lw=0)
    marks = ((seg.decl_step_s, "decl. applied"), (seg.takeoff_s, "take-off"), (seg.crash_s, "crash"))
    for k, (t, label) in enumerate(marks):
        if t is not None:
            ax.axvline(t, color="grey", ls=":", lw=1)
            ax.text(t, 0.99 - 0.06 * k, f" {label}", transform=ax.get_xaxis_transform(), fontsize=7, va="top",
                    color="grey")


def _plots(ev: ReplayEvaluation, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = ev.series
    written = []
    windows = sorted({r.window_s for r in ev.windows})
    colours = dict(zip(windows, ("tab:blue", "tab:orange", "tab:red", "tab:purple", "tab:brown")))

    fig, axes = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    for ax, key, label in ((axes[0], "decl", "D (deg)"), (axes[1], "incl", "I (deg)")):
        ok = s["accepted"]
        ax.plot(s["t_mag"][ok], s[f"{key}_meas"][ok], ".", ms=1.5, color="0.6", label="measured, 10 Hz")
        for w in windows:
            recs = [r for r in ev.windows if r.window_s == w]
            values = [r.decl_deg if key == "decl" else r.incl_deg for r in recs]
            ax.step([r.start_s for r in recs] + [recs[-1].end_s], values + values[-1:], where="post",
                    color=colours[w], lw=1.2, label=f"measured, {w:g} s mean")
        ax.plot(s["t_mag"], s[f"{key}_wmm"], "k-", lw=1.5, label=f"{ev.model} at GPS position")
        _shade(ax, ev)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylim(-20, 40)
    axes[1].set_ylim(-80, -55) if ev.wmm_at_start["incl_deg"] < 0 else axes[1].set_ylim(55, 80)
    axes[0].legend(fontsize=7, ncol=3, loc="lower right")
    axes[1].set_xlabel("log time (s)")
    axes[0].set_title(f"{Path(ev.log).name}: D and I measured vs {ev.model} (green: airborne span judged)")
    written.append(_save(fig, out / "di.png"))

    fig, ax = plt.subplots(figsize=(10, 5.5))
    for w in windows:
        recs = [r for r in ev.windows if r.window_s == w]
        t = [r.centre_s for r in recs]
        ax.plot(t, [r.fix_error_m for r in recs], "o-", ms=3, lw=0.8, color=colours[w], label=f"fix, {w:g} s")
        ax.plot(t, [r.predicted_m for r in recs], ":", lw=1, color=colours[w], label=f"|G^-1 e|, {w:g} s")
        ax.plot(t, [r.fused_error_m for r in recs], "s--", ms=3, lw=0.8, color=colours[w], alpha=0.6,
                label=f"fused, {w:g} s")
    gps_t = s["t_gps"]
    ins_styles = (("k", "-"), ("0.45", "--"), ("tab:green", "-."))
    for key, (colour, style) in zip([k for k in s if k.startswith("ins:")], ins_styles):
        ti, pe, pn = s[key].T
        err = np.hypot(pe - np.interp(ti, gps_t, s["gps_e"]), pn - np.interp(ti, gps_t, s["gps_n"]))
        ax.plot(ti, np.maximum(err, 0.1), lw=1.4, color=colour, ls=style, label=key[4:])
    _shade(ax, ev)
    ax.set_yscale("log")
    ax.set_ylabel("horizontal error vs GPS (m)")
    ax.set_xlabel("log time (s)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("Geomagnetic fix, INS-only drift and fused error")
    written.append(_save(fig, out / "errors.png"))

    fig, ax = plt.subplots(figsize=(10, 4.5))
    for w in windows:
        recs = [r for r in ev.windows if r.window_s == w and r.command_phase]
        t = [r.centre_s for r in recs]
        ax.plot(t, [r.command_course_deg for r in recs], "o", ms=3, color=colours[w], label=f"commanded, {w:g} s")
        ax.plot(t, [r.flown_course_deg for r in recs], "x", ms=4, color=colours[w], alpha=0.6,
                label=f"flown (GPS), {w:g} s")
    _shade(ax, ev)
    ax.set_ylim(0, 360)
    ax.set_yticks(range(0, 361, 90))
    ax.set_ylabel("course (deg from north)")
    ax.set_xlabel("log time (s)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=3)
    ax.set_title("Course commanded by the open-loop Fc-MPC vs course over ground flown")
    written.append(_save(fig, out / "heading.png"))

    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    ax.plot(s["gps_e"], s["gps_n"], "k-", lw=1.5, label="GPS")
    for key in [k for k in s if k.startswith("ins:")]:
        ti, pe, pn = s[key].T
        sel = ti <= ev.segments.end_s
        ax.plot(pe[sel], pn[sel], lw=1, label=key[4:])
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east of first fix (m)")
    ax.set_ylabel("north of first fix (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("Track: GPS vs INS-only (to the end of the airborne span)")
    written.append(_save(fig, out / "track.png"))
    return written


# --------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------


def _windows(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"--window-s takes seconds separated by commas, got {text!r}") from err
    if not values or any(not (v > 0.0 and math.isfinite(v)) for v in values):
        raise argparse.ArgumentTypeError(f"--window-s needs positive seconds, got {text!r}")
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("log", metavar="LOG", help="ArduPilot DataFlash .bin or MAVLink .tlog")
    parser.add_argument("--model", default=None,
                        help="WMM2010|WMM2015|WMM2015V2|WMM2020|WMM2025 or a .COF path (default: by the log's date)")
    parser.add_argument("--window-s", type=_windows, default=DEFAULT_WINDOWS_S,
                        help="averaging windows in seconds, comma separated (default 1,10,30)")
    parser.add_argument("--out", default=None, help="output folder (default out/replay/<log stem>)")
    parser.add_argument("--mag-instance", type=int, default=0, help="magnetometer instance (default 0, the primary)")
    parser.add_argument("--prior-offset-km", type=float, default=10.0,
                        help="the fix's prior is the GPS position moved this far north-east (default 10)")
    parser.add_argument("--crash-guard-s", type=float, default=10.0,
                        help="the airborne span ends this long before a detected crash (default 10)")
    parser.add_argument("--no-plots", action="store_true")
    args = parser.parse_args(argv)
    try:
        sniff_log_format(args.log)
        ev = evaluate(args.log, args.model, args.window_s, args.prior_offset_km, args.crash_guard_s,
                      args.mag_instance)
    except (SensorError, ValueError, OSError) as err:
        print(f"fcmpc-replay: {err}", file=sys.stderr)
        return 2
    report = format_report(ev)
    print(report)
    out = Path(args.out) if args.out else Path("out") / "replay" / Path(args.log).stem
    written = write_outputs(ev, out, plots=not args.no_plots)
    print(f"written: {', '.join(str(p) for p in written)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
