"""PX4 ULog (``.ulg``) logs read with pyulog, the PX4 project's own reader, into :class:`LogData`.

Topics (the first instance unless ``mag_instance`` says otherwise; times are the topic's
``timestamp``, microseconds since boot, so a ULog is one boot). Both log generations are read:
current PX4 (1.8 on) and the 1.6-era schema, where the magnetometer lived in ``sensor_combined``
and the position only in ``vehicle_local_position`` with its reference:

* magnetometer: ``vehicle_magnetometer.magnetometer_ga[3]`` (the calibrated field, body FRD,
  gauss), else ``sensor_mag.x/y/z`` (gauss, the driver's reading; then the report says the
  calibration is the driver's), else ``sensor_combined.magnetometer_ga[3]`` (PX4 1.6);
* attitude: ``vehicle_attitude.q[4]`` (Hamilton w, x, y, z rotating body FRD into NED) turned
  into roll, pitch, yaw (ZYX);
* IMU: ``sensor_combined.accelerometer_m_s2[3]`` (specific force, m/s^2) and ``gyro_rad[3]`` (rad/s);
* GPS: ``vehicle_gps_position`` (or ``sensor_gps`` in newer PX4): ``lat``/``lon`` (1e-7 deg) or
  ``latitude_deg``/``longitude_deg``, ``alt`` (mm MSL) or ``altitude_msl_m``, ``vel_n_m_s``,
  ``vel_e_m_s``, ``fix_type`` (3D from 3), ``eph`` (m), ``time_utc_usec`` (the log's date); a log
  without either (PX4 1.6 logged no raw GPS by default) takes its positions from
  ``vehicle_local_position``: ``x``/``y`` (m north/east of ``ref_lat``/``ref_lon``, deg),
  ``ref_alt - z`` (m MSL), ``vx``/``vy``, ``eph``, where ``xy_global`` is set and the reference
  is not 0/0; these are the estimator's GPS-aided positions, not raw fixes, and the report says
  so. Such a log carries no date (the header's ``time_ref_utc`` is a time-zone offset): ``--date``;
* armed state: ``vehicle_status.arming_state`` (2 = armed), else ``actuator_armed.armed``.
"""
from __future__ import annotations

import math
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np

from companion.io.sensors.base import SampleFlag, SensorError, StreamEnd
from fcmpc.replay.logdata import ULOG, LogData

__all__ = ["read_ulog", "ULOG_GPS_SOURCE", "ULOG_TOPICS"]

ULOG_GPS_SOURCE = "vehicle_gps_position.time_utc_usec"
ULOG_TOPICS = ["vehicle_magnetometer", "sensor_mag", "vehicle_attitude", "sensor_combined",
               "vehicle_gps_position", "sensor_gps", "vehicle_local_position", "vehicle_status", "actuator_armed"]
GAUSS_TO_NT = 1e5
RELATIVE_TIMESTAMP_INVALID = 2147483647   # PX4's sensor_combined: "this sensor has no new data"
ARMING_STATE_ARMED = 2


def _topic(ulog: Any, name: str, instance: int = 0) -> dict[str, np.ndarray] | None:
    for d in ulog.data_list:
        if d.name == name and d.multi_id == instance:
            return d.data
    return None


def _vector(data: dict[str, np.ndarray], *names: str) -> np.ndarray:
    return np.column_stack([np.asarray(data[n], dtype=float) for n in names])


def euler_from_quaternion(q: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) in rad, ZYX, of Hamilton quaternions (w, x, y, z) rotating body into NED."""
    w, x, y, z = (q[:, k] for k in range(4))
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.column_stack([roll, pitch, yaw])


def read_ulog(path: str | os.PathLike[str], mag_instance: int = 0) -> LogData:
    """One PX4 ULog as :class:`LogData`; SensorError when pyulog cannot read it."""
    from pyulog import ULog

    p = Path(path)
    try:
        ulog = ULog(str(p), ULOG_TOPICS)
    except (OSError, ValueError, struct.error, IndexError, KeyError, UnicodeDecodeError) as err:
        raise SensorError(f"{p}: a PX4 ULog that pyulog cannot read: {err}") from err
    counts: dict[str, int] = {}
    first: dict[str, float] = {}
    last: dict[str, float] = {}
    notes: list[str] = []

    def take(key: str, t: np.ndarray) -> None:
        if len(t):
            counts[key], first[key], last[key] = len(t), float(t[0]), float(t[-1])

    mag = np.empty((0, 4))
    data = _topic(ulog, "vehicle_magnetometer", mag_instance)
    if data is not None:
        mag = np.column_stack([data["timestamp"] * 1e-6, GAUSS_TO_NT * _vector(
            data, "magnetometer_ga[0]", "magnetometer_ga[1]", "magnetometer_ga[2]")])
    elif (data := _topic(ulog, "sensor_mag", mag_instance)) is not None:
        mag = np.column_stack([data["timestamp"] * 1e-6, GAUSS_TO_NT * _vector(data, "x", "y", "z")])
        notes.append("magnetometer from sensor_mag (the driver's reading; no vehicle_magnetometer in the log)")
    elif (data := _topic(ulog, "sensor_combined")) is not None and "magnetometer_ga[0]" in data:
        mag = np.column_stack([_old_mag_time(data), GAUSS_TO_NT * _vector(
            data, "magnetometer_ga[0]", "magnetometer_ga[1]", "magnetometer_ga[2]")])
        mag = mag[np.isfinite(mag).all(axis=1)]
        if len(mag):   # each sample once: sensor_combined repeats the last one between magnetometer updates
            mag = mag[np.concatenate([[True], np.diff(mag[:, 0]) > 0.0])]
        notes.append("magnetometer from sensor_combined.magnetometer_ga (a PX4 1.6-era log)")
    take("MAG", mag[:, 0])

    att = np.empty((0, 4))
    if (data := _topic(ulog, "vehicle_attitude")) is not None:
        q = _vector(data, "q[0]", "q[1]", "q[2]", "q[3]")
        att = np.column_stack([data["timestamp"] * 1e-6, euler_from_quaternion(q)])
        att[:, 1:] = np.unwrap(att[:, 1:], axis=0)
    take("ATT", att[:, 0])

    imu = np.empty((0, 7))
    if (data := _topic(ulog, "sensor_combined")) is not None:
        imu = np.column_stack([data["timestamp"] * 1e-6,
                               _vector(data, *(f"accelerometer_m_s2[{k}]" for k in range(3))),
                               _vector(data, *(f"gyro_rad[{k}]" for k in range(3)))])
    take("IMU", imu[:, 0])

    gps, dates = _gps(ulog)
    if not len(gps):
        gps = _local_position_fixes(ulog)
        if len(gps):
            notes.append("positions from vehicle_local_position and its reference (ref_lat/ref_lon: no raw GPS "
                         "topic in this log): the estimator's GPS-aided position stands in for the GPS")
    if len(gps):
        counts["GPS"] = len(gps)
        first["GPS"], last["GPS"] = float(gps[0, 0]), float(gps[-1, 0])
    armed, armed_source = _armed(ulog)
    if not counts:
        raise SensorError(f"{p}: a PX4 ULog without any of the topics {', '.join(ULOG_TOPICS[:6])}")
    end = StreamEnd(max(last.values()), SampleFlag.END, "end of log")
    return LogData(p, ULOG, mag_instance, counts, first, last, {}, end, mag, imu, att, gps,
                   armed=armed, armed_source=armed_source, unix_minus_boot_s=dates, notes=notes)


def _gps(ulog: Any) -> tuple[np.ndarray, dict[str, float]]:
    data = _topic(ulog, "vehicle_gps_position")
    if data is None:
        data = _topic(ulog, "sensor_gps")
    if data is None:
        return np.empty((0, 7)), {}
    t = data["timestamp"] * 1e-6
    if "latitude_deg" in data:
        lat, lon = data["latitude_deg"].astype(float), data["longitude_deg"].astype(float)
    else:
        lat, lon = data["lat"] * 1e-7, data["lon"] * 1e-7
    alt = data["altitude_msl_m"].astype(float) if "altitude_msl_m" in data else data["alt"] * 1e-3
    n = len(t)
    vn = data["vel_n_m_s"].astype(float) if "vel_n_m_s" in data else np.full(n, math.nan)
    ve = data["vel_e_m_s"].astype(float) if "vel_e_m_s" in data else np.full(n, math.nan)
    eph = data["eph"].astype(float) if "eph" in data else np.full(n, math.nan)
    fixed = data["fix_type"] >= 3
    gps = np.column_stack([t, lat, lon, alt, vn, ve, eph])[fixed]
    dates = {}
    utc = data.get("time_utc_usec")
    if utc is not None:
        ok = np.flatnonzero(fixed & (utc > 0))
        if len(ok):
            dates[ULOG_GPS_SOURCE] = float(utc[ok[0]]) * 1e-6 - float(t[ok[0]])
    return gps, dates


def _old_mag_time(data: dict[str, np.ndarray]) -> np.ndarray:
    """Sample times (s) of sensor_combined's magnetometer: ``timestamp`` plus
    ``magnetometer_timestamp_relative`` (us; PX4's RELATIVE_TIMESTAMP_INVALID marks none)."""
    t = data["timestamp"].astype(float)
    rel = data.get("magnetometer_timestamp_relative")
    if rel is None:
        return t * 1e-6
    rel = rel.astype(float)
    return np.where(rel == RELATIVE_TIMESTAMP_INVALID, np.nan, t + rel) * 1e-6


def _local_position_fixes(ulog: Any) -> np.ndarray:
    """GPS-like rows (t, lat, lon, alt, vn, ve, eph) from vehicle_local_position's x/y and its
    global reference, where the reference is valid; empty when the log has none."""
    from companion.nav.geo import offset_position

    data = _topic(ulog, "vehicle_local_position")
    if data is None or "ref_lat" not in data:
        return np.empty((0, 7))
    ref_lat, ref_lon = data["ref_lat"].astype(float), data["ref_lon"].astype(float)
    ok = np.isfinite(ref_lat) & np.isfinite(ref_lon) & ((ref_lat != 0.0) | (ref_lon != 0.0))
    if "xy_global" in data:
        ok &= data["xy_global"].astype(bool)
    if "xy_valid" in data:
        ok &= data["xy_valid"].astype(bool)
    if not ok.any():
        return np.empty((0, 7))
    rows = np.flatnonzero(ok)
    lat = np.empty(len(rows))
    lon = np.empty(len(rows))
    for j, k in enumerate(rows):   # a reference may move (an EKF reset): each row from its own
        lat[j], lon[j] = offset_position(float(ref_lat[k]), float(ref_lon[k]), float(data["y"][k]),
                                         float(data["x"][k]))
    n = len(rows)
    alt = (data["ref_alt"].astype(float) - data["z"].astype(float))[rows] if "ref_alt" in data else np.full(n, np.nan)
    vn = data["vx"].astype(float)[rows] if "vx" in data else np.full(n, math.nan)
    ve = data["vy"].astype(float)[rows] if "vy" in data else np.full(n, math.nan)
    eph = data["eph"].astype(float)[rows] if "eph" in data else np.full(n, math.nan)
    out = np.column_stack([data["timestamp"][rows] * 1e-6, lat, lon, alt, vn, ve, eph])
    return out[np.isfinite(out[:, :3]).all(axis=1)]


def _armed(ulog: Any) -> tuple[list[tuple[float, bool]], str]:
    data = _topic(ulog, "vehicle_status")
    if data is not None and "arming_state" in data:
        states, source = data["arming_state"] == ARMING_STATE_ARMED, "vehicle_status.arming_state"
    elif (data := _topic(ulog, "actuator_armed")) is not None and "armed" in data:
        states, source = data["armed"].astype(bool), "actuator_armed.armed"
    else:
        return [], ""
    t = data["timestamp"] * 1e-6
    out: list[tuple[float, bool]] = []
    for k in range(len(t)):
        if not out or out[-1][1] != bool(states[k]):
            out.append((float(t[k]), bool(states[k])))
    return out, source
