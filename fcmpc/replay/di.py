"""D and I measured against the model, sample by sample, and per segment of a flight.

Each magnetometer sample is tilt-compensated with the logged roll, pitch and yaw
(:func:`companion.nav.magnetometer.tilt_compensated_di`: D = atan2(E, N), eq. 1, and
I = atan2(Z, H), eq. 2, of the field rotated into NED), screened by the spike filter, and
compared with the model at the GPS position interpolated to its time. Per segment: bias =
mean of (measured - model), spread = standard deviation; for D both are circular (mean
direction and sqrt(-2 ln R)), so errors near +-180 deg do not average to zero.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from companion.nav.field import WorldMagneticModel
from companion.nav.magnetometer import SpikeFilter, tilt_compensated_di
from fcmpc.replay.logdata import LogData
from fcmpc.replay.records import DIRow
from fcmpc.replay.segments import HOVER_SPEED_MPS, HOVER_TILT_DEG, Segments
from fcmpc.replay.stats import circ_mean_deg, circ_std_deg, interp_gps, wrap180, wrap_pi

__all__ = ["MeasuredDI", "measure_di", "segment_rows"]


@dataclass(frozen=True)
class MeasuredDI:
    """Per magnetometer sample (within the GPS span): ``meas`` columns D, I (deg), |F| (nT),
    accepted (1/0); ``model`` the field elements at the GPS position; attitude at the sample."""

    t: np.ndarray
    meas: np.ndarray
    model: Any
    accepted: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray


def measure_di(data: LogData, model: WorldMagneticModel, year: float, spike_nt: float) -> MeasuredDI:
    gps, att = data.gps, data.att
    mag = data.mag[(data.mag[:, 0] >= gps[0, 0]) & (data.mag[:, 0] <= gps[-1, 0])]
    t_m = mag[:, 0]
    roll = np.interp(t_m, att[:, 0], att[:, 1])
    pitch = np.interp(t_m, att[:, 0], att[:, 2])
    yaw = np.interp(t_m, att[:, 0], att[:, 3])
    spikes = SpikeFilter(spike_nt)
    meas = np.full((len(mag), 4), np.nan)  # D, I, |F|, accepted
    for k, row in enumerate(mag):
        d, i, ned = tilt_compensated_di((row[1], row[2], row[3]), roll[k], pitch[k], yaw[k])
        meas[k] = (d, i, math.sqrt(ned[0] ** 2 + ned[1] ** 2 + ned[2] ** 2), 1.0 if spikes.accept(ned) else 0.0)
    lat_m, lon_m, alt_m = interp_gps(gps, t_m)
    return MeasuredDI(t_m, meas, model.elements(lat_m, lon_m, alt_m, year), meas[:, 3] > 0.5, roll, pitch)


def segment_rows(m: MeasuredDI, gps: np.ndarray, seg: Segments, crash_guard_s: float) -> list[DIRow]:
    """One row per segment: ground (before/after the declination step), judged span, hover,
    moving, and after a crash; rows not judged are marked so."""
    t_m, meas, wmm, accepted = m.t, m.meas, m.model, m.accepted
    err_d = wrap180(meas[:, 0] - wmm.decl_deg)
    err_i = meas[:, 1] - wmm.incl_deg
    err_f = meas[:, 2] - wmm.f_nt
    tilt_m = np.degrees(np.maximum(np.abs(wrap_pi(m.roll)), np.abs(wrap_pi(m.pitch))))
    speed_m = np.hypot(np.interp(t_m, gps[:, 0], np.nan_to_num(gps[:, 4])),
                       np.interp(t_m, gps[:, 0], np.nan_to_num(gps[:, 5])))
    nav0, nav1 = seg.nav_start_s, seg.end_s
    in_nav = (t_m >= nav0) & (t_m <= nav1)
    masks: list[tuple[str, float, float, np.ndarray, bool]] = []
    ground_end = seg.takeoff_s if seg.takeoff_s is not None else nav1
    if seg.decl_step_s is not None:
        masks.append(("ground, before declination applied", seg.first_fix_s, seg.decl_step_s,
                      (t_m >= seg.first_fix_s) & (t_m < seg.decl_step_s), False))
        masks.append(("ground, declination applied", seg.decl_step_s, ground_end,
                      (t_m >= seg.decl_step_s) & (t_m < ground_end), False))
    elif seg.takeoff_s is not None:
        masks.append(("ground", seg.first_fix_s, ground_end, (t_m >= seg.first_fix_s) & (t_m < ground_end), False))
    label = "airborne" if seg.takeoff_s is not None else "whole recording after first fix"
    masks.append((label, nav0, nav1, in_nav, True))
    if seg.takeoff_s is not None:
        hover = in_nav & (tilt_m < HOVER_TILT_DEG) & (speed_m < HOVER_SPEED_MPS)
        masks.append(("airborne, hover", nav0, nav1, hover, True))
        masks.append(("airborne, moving or tilted", nav0, nav1, in_nav & ~hover, True))
    if seg.crash_s is not None:
        masks.append((f"crash - {crash_guard_s:g} s and after (excluded)", seg.end_s, float(t_m[-1]),
                      t_m > seg.end_s, False))
    rows = []
    for name, a, b, mask, judged in masks:
        sel = mask & accepted
        n = int(sel.sum())
        if n == 0:
            continue
        rows.append(DIRow(
            name, a, b, n,
            float(wrap180(wmm.decl_deg[sel].mean() + circ_mean_deg(err_d[sel]))), float(wmm.decl_deg[sel].mean()),
            circ_mean_deg(err_d[sel]), circ_std_deg(err_d[sel]),
            float(meas[sel, 1].mean()), float(wmm.incl_deg[sel].mean()),
            float(err_i[sel].mean()), float(err_i[sel].std()), float(err_f[sel].mean()), judged))
    return rows
