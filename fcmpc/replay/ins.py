"""INS-only drift: horizontal strapdown dead reckoning of the log's IMU with its attitude."""
from __future__ import annotations

import math

import numpy as np

from companion.io.sensors.attitude import mat_nb_from_euler
from companion.nav.geo import enu_offset
from fcmpc.replay.logdata import LogData
from fcmpc.replay.records import InsRow
from fcmpc.replay.segments import Segments

__all__ = ["ins_track", "stationary_bias", "ins_drift"]


def ins_track(data: LogData, start_s: float, ref: tuple[float, float],
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


def stationary_bias(data: LogData, start_s: float, end_s: float) -> np.ndarray | None:
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


def ins_drift(data: LogData, seg: Segments, ref: tuple[float, float], gps_e: np.ndarray, gps_n: np.ndarray,
              report_s: tuple[float, ...]) -> tuple[list[InsRow], dict[str, tuple[np.ndarray, ...]], str]:
    """The INS variants (raw IMU from the first fix; statically aligned from the first fix and
    from take-off), their errors against GPS ``report_s`` after their start and at the end of the
    judged span, their tracks, and the name of the one the navigation uses (aligned from the fix)."""
    gps = data.gps
    nav1 = seg.end_s
    rest_end = (seg.takeoff_s - 2.0) if seg.takeoff_s is not None else seg.first_fix_s
    bias = stationary_bias(data, seg.first_fix_s, rest_end)
    tracks: dict[str, tuple[np.ndarray, ...]] = {}
    defs = [("INS, raw IMU, from first fix", seg.first_fix_s, None)]
    if bias is not None:
        defs.append(("INS, static alignment, from first fix", seg.first_fix_s, bias))
        if seg.takeoff_s is not None:
            defs.append(("INS, static alignment, from take-off", seg.takeoff_s, bias))
    rows = []
    for name, start, b in defs:
        ti, pe, pn = ins_track(data, start, ref, b)
        tracks[name] = (ti, pe, pn)
        err = np.hypot(pe - np.interp(ti, gps[:, 0], gps_e), pn - np.interp(ti, gps[:, 0], gps_n))
        errors = {}
        for dt_s in report_s:
            errors[f"+{dt_s:g} s"] = float(np.interp(ti[0] + dt_s, ti, err)) if ti[0] + dt_s <= ti[-1] else math.nan
        errors["end of judged span"] = float(np.interp(nav1, ti, err)) if nav1 <= ti[-1] else math.nan
        rows.append(InsRow(name, float(ti[0]), errors))
    return rows, tracks, (defs[1][0] if len(defs) > 1 else defs[0][0])
