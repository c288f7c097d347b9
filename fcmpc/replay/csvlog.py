"""A generic CSV recording (a phone, a car, any logger) read into :class:`LogData`, with a frame
and handedness check against the GPS course.

One header line, then one row per sample; an empty cell is "no value in this row" (a GPS
column is empty between fixes). Columns, with their units:

============================  =========  ====================================================
column                        required   meaning
============================  =========  ====================================================
``time_s``                    yes        time of the row, seconds (any origin, increasing)
``mag_x_ut`` ``_y_`` ``_z_``  yes        magnetic field, microtesla, body frame: x forward,
                                         y right, z down (right-handed)
``roll_deg`` ``pitch_deg``    yes        attitude (ZYX Euler angles), degrees
``yaw_deg``                   yes        heading, degrees from true north, clockwise
``lat_deg`` ``lon_deg``       yes        GPS position, degrees (rows without a fix: empty)
``alt_m``                     no         GPS altitude, metres (default 0)
``speed_mps`` ``course_deg``  no         GPS ground speed (m/s) and course over ground
                                         (degrees from north, clockwise); derived from the
                                         positions when absent
``acc_x_mps2`` ...            no         specific force, m/s^2, body frame (at rest about
                                         0, 0, -9.81: z down)
``gyro_x_radps`` ...          no         angular rate, rad/s, body frame
``armed``                     no         1 while armed (moving under its own power), else 0
``unix_time_s``               no         UNIX time of the row (the recording's date)
============================  =========  ====================================================

Frame check (:func:`check_frame`): a vehicle's heading follows its course over ground when it
moves (a car, a boat, a walker holding a phone ahead). While the recording moves faster than
:data:`CHECK_SPEED_MPS` and its course turns, the heading from ``yaw_deg`` and the magnetic
heading from the tilt-compensated ``mag`` columns must turn *with* the course: an axis set
that turns the other way is mirrored (left-handed: one axis negated), and the file is refused
with the columns to fix. An accelerometer whose z reads +g at rest points up, and is refused.
"""
from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np

from companion.io.sensors.base import SampleFlag, SensorError, StreamEnd
from companion.nav.geo import enu_offset
from fcmpc.replay.logdata import CSV, LogData, arrays
from fcmpc.replay.stats import circ_std_deg, wrap180

__all__ = ["read_csv", "check_frame", "CSV_SOURCE", "REQUIRED", "CHECK_SPEED_MPS"]

CSV_SOURCE = "unix_time_s column"
REQUIRED = ("time_s", "mag_x_ut", "mag_y_ut", "mag_z_ut", "roll_deg", "pitch_deg", "yaw_deg", "lat_deg", "lon_deg")
OPTIONAL = ("alt_m", "speed_mps", "course_deg", "acc_x_mps2", "acc_y_mps2", "acc_z_mps2", "gyro_x_radps",
            "gyro_y_radps", "gyro_z_radps", "armed", "unix_time_s")
CHECK_SPEED_MPS = 2.0
MIN_COURSE_SPREAD_DEG = 30.0   # the course must turn this much for the check to mean something
FIT_DEG = 30.0                 # a hypothesis fits when heading - course has a spread under this
UT_TO_NT = 1000.0


def _table(path: Path) -> dict[str, np.ndarray]:
    try:
        handle = path.open(newline="", encoding="utf-8")
    except OSError as err:
        raise SensorError(f"cannot read {path}: {err}") from err
    with handle:
        reader = csv.reader(handle)
        header = [h.strip() for h in next(reader, [])]
        missing = [c for c in REQUIRED if c not in header]
        if missing:
            raise SensorError(f"{path}: line 1 lacks the column(s) {', '.join(missing)} (required: "
                              f"{', '.join(REQUIRED)}; see fcmpc.replay.csvlog or the README)")
        wanted = [c for c in REQUIRED + OPTIONAL if c in header]
        index = [header.index(c) for c in wanted]
        rows = []
        for line, row in enumerate(reader, start=2):
            if not any(cell.strip() for cell in row):
                continue
            try:
                rows.append([float(row[k]) if k < len(row) and row[k].strip() else math.nan for k in index])
            except ValueError as err:
                raise SensorError(f"{path}: line {line}: not a number ({err})") from err
    if len(rows) < 2:
        raise SensorError(f"{path}: fewer than two rows of data")
    table = np.array(rows, dtype=float)
    return {c: table[:, k] for k, c in enumerate(wanted)}


def read_csv(path: str | os.PathLike[str]) -> LogData:
    """A CSV recording as :class:`LogData`, after :func:`check_frame`; SensorError on bad input."""
    p = Path(path)
    col = _table(p)
    t = col["time_s"]
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        bad = int(np.flatnonzero(~np.isfinite(t) | np.r_[False, np.diff(t) <= 0])[0]) + 2
        raise SensorError(f"{p}: line {bad}: time_s must be present and increasing")
    mag_cols = ("mag_x_ut", "mag_y_ut", "mag_z_ut")
    has_mag = np.all(np.isfinite(np.column_stack([col[c] for c in mag_cols])), axis=1)
    mag = np.column_stack([t, *(UT_TO_NT * col[c] for c in mag_cols)])[has_mag]
    att_cols = ("roll_deg", "pitch_deg", "yaw_deg")
    has_att = np.all(np.isfinite(np.column_stack([col[c] for c in att_cols])), axis=1)
    att = np.column_stack([t, *(np.radians(col[c]) for c in att_cols)])[has_att]
    att[:, 1:] = np.unwrap(att[:, 1:], axis=0)
    imu = np.empty((0, 7))
    if all(f"acc_{a}_mps2" in col for a in "xyz"):
        gyro = [col.get(f"gyro_{a}_radps", np.zeros(len(t))) for a in "xyz"]
        imu = np.column_stack([t, *(col[f"acc_{a}_mps2"] for a in "xyz"), *gyro])
        imu = imu[np.all(np.isfinite(imu[:, :4]), axis=1)]
    gps = _gps(col)
    counts, first, last = {}, {}, {}
    for key, a in (("MAG", mag), ("ATT", att), ("IMU", imu), ("GPS", gps)):
        if len(a):
            counts[key], first[key], last[key] = len(a), float(a[0, 0]), float(a[-1, 0])
    armed: list[tuple[float, bool]] = []
    if "armed" in col:
        for tk, value in zip(t, col["armed"]):
            if math.isfinite(value) and (not armed or armed[-1][1] != (value > 0.5)):
                armed.append((float(tk), value > 0.5))
    dates = {}
    if "unix_time_s" in col and np.isfinite(col["unix_time_s"]).any():
        k = int(np.flatnonzero(np.isfinite(col["unix_time_s"]))[0])
        dates[CSV_SOURCE] = float(col["unix_time_s"][k] - t[k])
    data = LogData(p, CSV, 0, counts, first, last, {}, StreamEnd(float(t[-1]), SampleFlag.END, "end of file"),
                   mag, imu, att, gps, armed=armed, armed_source="CSV armed column" if armed else "",
                   unix_minus_boot_s=dates)
    data.notes.extend(check_frame(data))
    return data


def _gps(col: dict[str, np.ndarray]) -> np.ndarray:
    t = col["time_s"]
    fix = np.isfinite(col["lat_deg"]) & np.isfinite(col["lon_deg"])
    t, lat, lon = t[fix], col["lat_deg"][fix], col["lon_deg"][fix]
    alt = col["alt_m"][fix] if "alt_m" in col else np.zeros(len(t))
    if "speed_mps" in col and "course_deg" in col:
        c = np.radians(col["course_deg"][fix])
        vn, ve = col["speed_mps"][fix] * np.cos(c), col["speed_mps"][fix] * np.sin(c)
    elif len(t) > 2:
        e, n = enu_offset(float(lat[0]), float(lon[0]), lat, lon)
        vn, ve = np.gradient(np.asarray(n, dtype=float), t), np.gradient(np.asarray(e, dtype=float), t)
    else:
        vn = ve = np.full(len(t), math.nan)
    return arrays(np.column_stack([t, lat, lon, alt, vn, ve, np.full(len(t), math.nan)]).tolist(), 7)


def _turns_with(heading_deg: np.ndarray, course_deg: np.ndarray) -> tuple[float, float]:
    """Spread of heading - course (turning with the course) and of heading + course (mirrored)."""
    return circ_std_deg(wrap180(heading_deg - course_deg)), circ_std_deg(wrap180(heading_deg + course_deg))


def check_frame(data: LogData) -> list[str]:
    """Refuse mirrored or upside-down axes (SensorError); return notes on what could not be checked."""
    notes = []
    name = data.path.name
    imu = data.imu
    if len(imu):
        g_z = float(np.median(imu[:, 3]))
        if g_z > 5.0:
            raise SensorError(f"{name}: acc_z_mps2 reads {g_z:+.1f} m/s^2 on average: the z axis points up; the "
                              "columns must be body x forward, y right, z down (at rest about 0, 0, -9.81)")
    gps = data.gps
    speed = np.hypot(gps[:, 4], gps[:, 5]) if len(gps) else np.empty(0)
    moving = gps[np.nan_to_num(speed) > CHECK_SPEED_MPS]
    if len(moving) < 10:
        return notes + [f"frame not checked: fewer than 10 GPS fixes faster than {CHECK_SPEED_MPS:g} m/s"]
    course = np.degrees(np.arctan2(moving[:, 5], moving[:, 4]))
    if circ_std_deg(course) < MIN_COURSE_SPREAD_DEG:
        return notes + ["frame not checked: the course never turned enough to tell a mirrored axis"]
    t = moving[:, 0]
    att = data.att
    yaw = np.degrees(np.interp(t, att[:, 0], att[:, 3]))
    same, mirrored = _turns_with(yaw, course)
    if mirrored < FIT_DEG and mirrored < 0.5 * same:
        raise SensorError(f"{name}: yaw_deg turns against the GPS course (heading - course spreads {same:.0f} deg, "
                          f"heading + course only {mirrored:.0f} deg): the attitude is mirrored; yaw_deg must be "
                          "degrees from north, clockwise")
    from companion.nav.magnetometer import tilt_compensated_di

    mag = data.mag
    roll, pitch = np.interp(t, att[:, 0], att[:, 1]), np.interp(t, att[:, 0], att[:, 2])
    body = np.column_stack([np.interp(t, mag[:, 0], mag[:, k]) for k in (1, 2, 3)])
    # D with yaw 0 is the field's direction from the nose: the magnetic heading is its negative.
    heading_m = np.array([-tilt_compensated_di(tuple(b), r, p, 0.0)[0] for b, r, p in zip(body, roll, pitch)])
    same_m, mirrored_m = _turns_with(heading_m, course)
    if mirrored_m < FIT_DEG and mirrored_m < 0.5 * same_m:
        raise SensorError(f"{name}: the magnetometer axes are mirrored: the heading from mag_x_ut/mag_y_ut/mag_z_ut "
                          f"turns against the GPS course (spread {same_m:.0f} deg, mirrored {mirrored_m:.0f} deg); "
                          "negate or swap one axis so they are x forward, y right, z down")
    if same > FIT_DEG or same_m > FIT_DEG:
        notes.append(f"frame check inconclusive: heading - course spreads {same:.0f} deg (yaw) and {same_m:.0f} deg "
                     "(magnetometer) while moving; a vehicle whose heading does not follow its course cannot be checked")
    return notes
