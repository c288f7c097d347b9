"""Synthetic recordings for the replay tests: a vehicle flown through phases over the WMM2015
field, written as real MAVLink frames (pymavlink) into a .tlog.

Each phase holds its armed state, ground speed, course (= heading), climb rate and a GPS
altitude drift; an optional tumble (roll/pitch swinging by up to 120/60 deg, as in a compass
calibration dance). The magnetometer reads the model field rotated into the body frame, times
``mag_scale`` (an uncalibrated sensor reads too much), plus seeded white noise.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from companion.frames import mat_nb_from_euler  # noqa: E402
from companion.nav.field import WorldMagneticModel  # noqa: E402
from companion.nav.geo import offset_position  # noqa: E402

__all__ = ["Phase", "Track", "fly", "write_tlog", "wmm2015", "UNIX_2018"]

UNIX_2018 = 1_527_811_200.0  # 2018-06-01 00:00:00 UTC
YEAR_2018 = 2018.41
G = 9.80665


def wmm2015() -> WorldMagneticModel:
    import pygeomag

    return WorldMagneticModel.from_cof(Path(pygeomag.__file__).resolve().parent / "wmm" / "WMM_2015.COF")


@dataclass(frozen=True)
class Phase:
    duration_s: float
    armed: bool = False
    speed_mps: float = 0.0
    course_deg: float = 0.0
    climb_mps: float = 0.0
    alt_drift_mps: float = 0.0
    turn_dps: float = 0.0
    tumble: bool = False


@dataclass
class Track:
    """Per-sample truth at ``rate_hz``: time from boot (s), position, velocity, attitude, sensors."""

    t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray          # GPS altitude (truth + drift)
    vn: np.ndarray
    ve: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    yaw: np.ndarray
    mag_nt: np.ndarray       # (n, 3) body
    acc: np.ndarray          # (n, 3) body specific force
    armed: np.ndarray
    takeoffs: list[float]


def fly(phases: list[Phase], rate_hz: float = 10.0, t0: float = 2.0, lat0: float = -35.3,
        lon0: float = 149.1, alt0: float = 600.0, mag_scale: float = 1.0, seed: int = 0,
        year: float = YEAR_2018, model: WorldMagneticModel | None = None) -> Track:
    model = model or wmm2015()
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    rows = []
    e = n = up = drift = 0.0
    course = 0.0
    t = t0
    takeoffs: list[float] = []
    was_moving = False
    for ph in phases:
        course = ph.course_deg if ph.turn_dps == 0.0 else course
        for k in range(int(round(ph.duration_s * rate_hz))):
            moving = ph.armed and (ph.speed_mps > 0 or ph.climb_mps != 0)
            if moving and not was_moving:
                takeoffs.append(t)
            was_moving = moving
            course += ph.turn_dps * dt
            c = math.radians(course)
            vn, ve = ph.speed_mps * math.cos(c), ph.speed_mps * math.sin(c)
            n += vn * dt
            e += ve * dt
            up += ph.climb_mps * dt
            drift += ph.alt_drift_mps * dt
            roll = math.radians(120.0 * math.sin(0.9 * t)) if ph.tumble else 0.0
            pitch = math.radians(60.0 * math.sin(0.6 * t)) if ph.tumble else 0.0
            yaw = math.radians(course + (200.0 * math.sin(0.3 * t) if ph.tumble else 0.0))
            rows.append((t, e, n, up, drift, vn, ve, roll, pitch, yaw, float(ph.armed)))
            t += dt
    a = np.array(rows)
    lat, lon = offset_position(lat0, lon0, a[:, 1], a[:, 2])
    lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
    el = model.elements(lat, lon, alt0 + a[:, 3], year)
    ned = np.column_stack([el.x_nt, el.y_nt, el.z_nt])
    mag = np.empty_like(ned)
    acc = np.empty_like(ned)
    for k in range(len(a)):
        c_nb = np.array(mat_nb_from_euler(a[k, 7], a[k, 8], a[k, 9]))
        mag[k] = mag_scale * (c_nb.T @ ned[k])
        acc[k] = c_nb.T @ np.array([0.0, 0.0, -G])
    mag += rng.normal(0.0, 50.0, mag.shape)
    return Track(a[:, 0], lat, lon, alt0 + a[:, 3] + a[:, 4], a[:, 5], a[:, 6], a[:, 7], a[:, 8], a[:, 9],
                 mag, acc, a[:, 10] > 0.5, takeoffs)


def write_tlog(path: Path, boots: list[tuple[Track, float]], *, gps_time: str = "unix",
               system_time: bool = True, heartbeat: bool = True, gps_every: int = 2) -> Path:
    """Boots of tracks into one tlog; each boot is ``(track, UNIX time of boot time 0)``.

    ``gps_time``: ``"unix"`` (GPS_RAW_INT.time_usec in UNIX us) or ``"boot"`` (boot us, as some
    ArduPilot versions send); ``system_time``: SYSTEM_TIME carries the UNIX time (else 0).
    """
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    out = bytearray()

    def put(msg, unix_s: float) -> None:
        out.extend(int(unix_s * 1e6).to_bytes(8, "big") + msg.pack(mav))

    for track, unix0 in boots:
        last_second = -1
        for k, t in enumerate(track.t):
            unix = unix0 + t
            if int(t) != last_second:
                last_second = int(t)
                if heartbeat:
                    mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
                        mavlink.MAV_MODE_FLAG_SAFETY_ARMED if track.armed[k] else 0)
                    put(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                          mode, 5, mavlink.MAV_STATE_ACTIVE, 3), unix)
                put(mavlink.MAVLink_system_time_message(int(unix * 1e6) if system_time else 0, int(t * 1e3)), unix)
            put(mavlink.MAVLink_attitude_message(int(t * 1e3), track.roll[k], track.pitch[k],
                                                 math.remainder(track.yaw[k], 2 * math.pi), 0.0, 0.0, 0.0), unix)
            mg = track.mag_nt[k] / 100.0
            acc = track.acc[k] * 1000.0 / G
            put(mavlink.MAVLink_raw_imu_message(int(t * 1e6), *(int(round(v)) for v in acc), 0, 0, 0,
                                                *(int(round(v)) for v in mg), 0, 0), unix)
            if k % gps_every == 0:
                speed = math.hypot(track.vn[k], track.ve[k])
                cog = math.degrees(math.atan2(track.ve[k], track.vn[k])) % 360.0
                put(mavlink.MAVLink_gps_raw_int_message(
                    int((unix if gps_time == "unix" else t) * 1e6), 3, int(round(track.lat[k] * 1e7)),
                    int(round(track.lon[k] * 1e7)), int(round(track.alt[k] * 1e3)), 80, 120,
                    int(round(speed * 100)), int(round(cog * 100)) % 36000, 12), unix)
    path.write_bytes(bytes(out))
    return path


def quaternion(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Hamilton (w, x, y, z) of ZYX Euler angles (body -> NED), as PX4 logs vehicle_attitude.q."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.column_stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


def write_ulog(path: Path, track: Track, unix0: float, gps_every: int = 2, generation: str = "current") -> Path:
    """A PX4-style ULog of a track: vehicle_magnetometer, vehicle_attitude, sensor_combined,
    vehicle_gps_position (with time_utc_usec) and vehicle_status (arming_state 2 = armed).

    ``generation="px4-1.6"``: the 1.6-era schema instead: the magnetometer in
    ``sensor_combined.magnetometer_ga`` (with its relative timestamp) and the position only in
    ``vehicle_local_position`` (x north, y east, z down from ``ref_lat``/``ref_lon``/``ref_alt``,
    ``xy_global``); no GPS topic, so no date."""
    from companion.nav.geo import enu_offset
    from tests.replay.ulog_writer import ULogWriter

    old = generation == "px4-1.6"
    w = ULogWriter()
    w.topic("vehicle_attitude", [("uint64_t", "timestamp"), ("float[4]", "q")])
    if old:
        w.topic("sensor_combined", [("uint64_t", "timestamp"), ("float[3]", "gyro_rad"),
                                    ("float[3]", "accelerometer_m_s2"), ("float[3]", "magnetometer_ga"),
                                    ("int32_t", "magnetometer_timestamp_relative")])
        w.topic("vehicle_local_position", [("uint64_t", "timestamp"), ("uint64_t", "ref_timestamp"),
                                           ("double", "ref_lat"), ("double", "ref_lon"), ("float", "x"),
                                           ("float", "y"), ("float", "z"), ("float", "vx"), ("float", "vy"),
                                           ("float", "ref_alt"), ("float", "eph"), ("bool", "xy_global")])
    else:
        w.topic("vehicle_magnetometer", [("uint64_t", "timestamp"), ("float[3]", "magnetometer_ga")])
        w.topic("sensor_combined", [("uint64_t", "timestamp"), ("float[3]", "gyro_rad"),
                                    ("float[3]", "accelerometer_m_s2")])
        w.topic("vehicle_gps_position", [("uint64_t", "timestamp"), ("uint64_t", "time_utc_usec"), ("int32_t", "lat"),
                                         ("int32_t", "lon"), ("int32_t", "alt"), ("float", "eph"),
                                         ("float", "vel_n_m_s"), ("float", "vel_e_m_s"), ("uint8_t", "fix_type")])
    w.topic("vehicle_status", [("uint64_t", "timestamp"), ("uint8_t", "arming_state")])
    q = quaternion(track.roll, track.pitch, track.yaw)
    ref = (float(track.lat[0]), float(track.lon[0]), float(track.alt[0]))
    for k, t in enumerate(track.t):
        us = int(round(t * 1e6))
        w.add("vehicle_attitude", (us, tuple(q[k])))
        if old:
            w.add("sensor_combined", (us, (0.0, 0.0, 0.0), tuple(track.acc[k]), tuple(track.mag_nt[k] / 1e5), 0))
        else:
            w.add("vehicle_magnetometer", (us, tuple(track.mag_nt[k] / 1e5)))
            w.add("sensor_combined", (us, (0.0, 0.0, 0.0), tuple(track.acc[k])))
        if k % gps_every == 0:
            if old:
                east, north = enu_offset(ref[0], ref[1], float(track.lat[k]), float(track.lon[k]))
                w.add("vehicle_local_position", (us, 0, ref[0], ref[1], float(north), float(east),
                                                 ref[2] - float(track.alt[k]), track.vn[k], track.ve[k], ref[2],
                                                 0.8, True))
            else:
                w.add("vehicle_gps_position", (us, int((unix0 + t) * 1e6), int(round(track.lat[k] * 1e7)),
                                               int(round(track.lon[k] * 1e7)), int(round(track.alt[k] * 1e3)), 0.8,
                                               track.vn[k], track.ve[k], 3))
        if k % 10 == 0:
            w.add("vehicle_status", (us, 2 if track.armed[k] else 1))
    return w.write(path)


def write_csv(path: Path, track: Track, unix0: float | None = None, gps_every: int = 2) -> Path:
    """The CSV columns of fcmpc.replay.csvlog (mag in uT, angles in degrees, GPS every other row)."""
    import csv

    with path.open("w", newline="") as handle:
        out = csv.writer(handle)
        out.writerow(["time_s", "mag_x_ut", "mag_y_ut", "mag_z_ut", "roll_deg", "pitch_deg", "yaw_deg",
                      "lat_deg", "lon_deg", "alt_m", "acc_x_mps2", "acc_y_mps2", "acc_z_mps2", "armed"]
                     + (["unix_time_s"] if unix0 is not None else []))
        for k, t in enumerate(track.t):
            gps = [f"{track.lat[k]:.8f}", f"{track.lon[k]:.8f}", f"{track.alt[k]:.2f}"] if k % gps_every == 0 else [""] * 3
            out.writerow([f"{t:.3f}", *(f"{v / 1e3:.4f}" for v in track.mag_nt[k]),
                          *(f"{math.degrees(a):.3f}" for a in (track.roll[k], track.pitch[k], track.yaw[k])),
                          *gps, *(f"{v:.4f}" for v in track.acc[k]), int(track.armed[k])]
                         + ([f"{unix0 + t:.3f}"] if unix0 is not None else []))
    return path
