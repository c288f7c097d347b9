"""The evaluation of one flight: D and I vs the model (:mod:`fcmpc.replay.di`), the geomagnetic fix
(eq. 49) and its |G^-1 e| prediction per averaging window, INS drift (:mod:`fcmpc.replay.ins`), the
Table 3 fusion (eq. 46-58), and the open-loop Fc-MPC mission (:mod:`fcmpc.replay.heading`)."""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from companion.nav.field import PositionFixError, WorldMagneticModel, decl_incl_gradient, geomagnetic_fix
from companion.nav.fusion import FusionSettings, InsGeomagFusion
from companion.nav.geo import enu_offset, geodesic_distance_m, offset_position
from companion.nav.period import PeriodAverager
from fcmpc.replay.di import measure_di, segment_rows
from fcmpc.replay.heading import model_di_gradient, run_mission
from fcmpc.replay.ins import ins_drift
from fcmpc.replay.logdata import LogData
from fcmpc.replay.models import LogDate
from fcmpc.replay.records import FixRow, FusedRow, HeadingRow, ReplayEvaluation, WindowRecord
from fcmpc.replay.segments import Flight, Segments, find_segments
from fcmpc.replay.stats import circ_mean_deg, circ_std_deg, interp_gps, percentile, wrap180

__all__ = ["evaluate_flight", "DEFAULT_WINDOWS_S", "INS_REPORT_S", "SPIKE_NT"]

DEFAULT_WINDOWS_S = (1.0, 10.0, 30.0)
INS_REPORT_S = (10.0, 30.0, 60.0)
SPIKE_NT = 5000.0            # COMP_SPIKE_NT default
F_RATIO_TOLERANCE = 0.15     # |F| measured / model beyond 1 +- this: the magnetometer is uncalibrated
MIN_INS_RATE_HZ = 20.0       # below this IMU rate the dead reckoning is flagged


def evaluate_flight(
    data: LogData,
    flight: Flight | None,
    model: WorldMagneticModel,
    model_note: str,
    date: LogDate,
    windows_s: tuple[float, ...] = DEFAULT_WINDOWS_S,
    prior_offset_km: float = 10.0,
    crash_guard_s: float = 10.0,
    judged_from_s: float | None = None,
) -> ReplayEvaluation:
    """Evaluate one flight of one boot (``flight`` None: a recording that is not a flight).

    ``data`` is the boot's data cut to the flight's window; ValueError when it lacks GPS,
    magnetometer or attitude samples. ``judged_from_s``: the judged span starts no earlier (the
    end of the samples a calibration was fitted on).
    """
    path = data.path
    where = f"{path}" + (f" (boot {data.boot + 1} of {data.boots})" if data.boots > 1 else "")
    if len(data.gps) < 2:
        raise ValueError(f"{where}: fewer than two 3D GPS fixes; the evaluation needs the log's GPS as truth")
    if len(data.mag) < 2 or len(data.att) < 2:
        raise ValueError(f"{where}: needs magnetometer {data.mag_instance} and attitude samples "
                         f"(got {len(data.mag)} and {len(data.att)})")
    year = date.decimal_year
    mag_instance = data.mag_instance
    gps = data.gps
    # --- 1. per-sample D, I (measured) and the model at the GPS position ------------------------
    di = measure_di(data, model, year, SPIKE_NT)
    t_m, meas, wmm, accepted = di.t, di.meas, di.model, di.accepted
    seg = replace(find_segments(data, t_m, meas[:, 0], crash_guard_s, flight), judged_from_s=judged_from_s)
    nav0, nav1 = seg.nav_start_s, seg.end_s
    in_nav = (t_m >= nav0) & (t_m <= nav1)
    if int((in_nav & accepted).sum()) < 2:
        raise ValueError(f"{where}: fewer than two magnetometer {data.mag_instance} samples in the judged span "
                         f"{nav0:.1f}-{nav1:.1f} s")
    di_rows = segment_rows(di, gps, seg, crash_guard_s)

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
    ins_rows, tracks, nav_ins_name = ins_drift(data, seg, ref, gps_e, gps_n, INS_REPORT_S)
    ins_t, ins_e, ins_n = tracks[nav_ins_name]

    def ins_latlon(t: float) -> tuple[float, float]:
        la, lo = offset_position(ref[0], ref[1], float(np.interp(t, ins_t, ins_e)), float(np.interp(t, ins_t, ins_n)))
        return float(la), float(lo)

    # --- 2, 4, 5: per window ---------------------------------------------------------------------
    rate_hz = 1.0 / float(np.median(np.diff(t_m))) if len(t_m) > 1 else 10.0
    warnings = list(data.notes) + _warnings(data, seg, meas[in_nav & accepted, 2], wmm.f_nt[in_nav & accepted],
                                            rate_hz)
    airborne_speed = np.hypot(gps[:, 4], gps[:, 5])[(gps[:, 0] >= nav0) & (gps[:, 0] <= nav1)]
    cruise_mps = max(1.0, float(np.nanmedian(airborne_speed))) if len(airborne_speed) else 1.0
    fix_rows: list[FixRow] = []
    fused_rows: list[FusedRow] = []
    heading_rows: list[HeadingRow] = []
    all_windows: list[WindowRecord] = []
    mission_note = (
        f"Fc-MPC, start = first fix ({ref[0]:.6f}, {ref[1]:.6f}), destination = last fix of the judged span "
        f"({dest[0]:.6f}, {dest[1]:.6f}), {geodesic_distance_m(*ref, *dest):.0f} m apart; cruise speed "
        f"{cruise_mps:.1f} m/s (median GPS speed of the judged span), period = window; state bounds widened to "
        f"D in [-180, 180], I in [-90, 90] deg (Table 4's I in [10, 100] excludes the southern hemisphere)")
    judged = np.flatnonzero(in_nav & accepted)
    t_judged, meas_judged = t_m[judged], meas[judged]
    for w in windows_s:
        recs, fix_pos, gradients = _window_records(w, t_judged, meas_judged, nav0, nav1, rate_hz, gps, model, year,
                                                   prior_offset)
        if not recs:
            continue
        fix_rows.append(_fix_row(w, recs, gradients))
        fused_rows.append(_fused_row(w, recs, fix_pos, ref, (ins_t, ins_e, ins_n), gps, gps_e, gps_n))
        # 5. the mission, open-loop: the command issued at the end of window k is for window k+1
        heading_rows.append(run_mission(recs, w, model, year, ref, dest, seg.ground_alt_m, cruise_mps,
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
        log=str(path), format=data.format, model=model.name, model_note=model_note, date=date.iso,
        decimal_year=float(year), mag_instance=mag_instance, counts=dict(data.counts),
        first_s=dict(data.first_s), last_s=dict(data.last_s), flagged=dict(data.flagged),
        truncated=data.end.truncated, end_detail=data.end.detail, segments=seg,
        gradient_deg_per_km=(g_ref * 1e3).tolist(), gradient_singular_deg_per_km=(sv * 1e3).tolist(),
        wmm_at_start={"decl_deg": float(start_el.decl_deg), "incl_deg": float(start_el.incl_deg),
                      "f_nt": float(start_el.f_nt)},
        spikes_rejected=int((~accepted).sum()), di_rows=di_rows, fix_rows=fix_rows, ins_rows=ins_rows,
        fused_rows=fused_rows, heading_rows=heading_rows, windows=all_windows, mission_note=mission_note,
        prior_offset_m=prior_offset, mag_rate_hz=rate_hz, source_note=_source_note(Path(path)),
        date_source=date.source, date_note=date.note, boot=data.boot, boots=data.boots,
        imu_rate_hz=data.imu_rate_hz, f_ratio=_f_ratio(meas[in_nav & accepted, 2], wmm.f_nt[in_nav & accepted]),
        warnings=warnings, series=series)


def _window_records(w: float, t_m: np.ndarray, meas: np.ndarray, nav0: float, nav1: float, rate_hz: float,
                    gps: np.ndarray, model: WorldMagneticModel, year: float, prior_offset: tuple[float, float]
                    ) -> tuple[list[WindowRecord], list[tuple[float, float] | None], list[np.ndarray]]:
    """2. The judged span cut into windows of ``w`` seconds (``t_m``, ``meas``: the judged samples):
    per window with at least half its samples, the averaged D and I against the model at the GPS
    position there, the |G^-1 e| prediction, and the geomagnetic fix from a prior ``prior_offset``
    (east, north m) off the truth; with each window's fix position (None where it failed) and the
    model's G at its GPS position."""
    recs: list[WindowRecord] = []
    fix_pos: list[tuple[float, float] | None] = []
    gradients: list[np.ndarray] = []
    averager = PeriodAverager()
    for k in range(len(t_m)):
        averager.add(float(t_m[k]), float(meas[k, 0]), float(meas[k, 1]))
    for a in np.arange(nav0, nav1 - w + 1e-9, w):
        b = a + w
        avg = averager.take(b - 1e-9)
        if avg.count < max(1, int(0.5 * w * rate_hz)):
            continue
        tc = avg.mean_time_s
        la, lo, al = (float(v) for v in interp_gps(gps, tc))
        decl, incl, g = model_di_gradient(model, la, lo, al, year)
        e = np.array([float(wrap180(avg.decl_deg - decl)), avg.incl_deg - incl])
        pred = float(np.hypot(*np.linalg.solve(g, e)))
        rec = WindowRecord(w, float(a), float(b), float(tc), avg.count, avg.decl_deg, avg.incl_deg,
                           float(e[0]), float(e[1]), pred, decl_se_deg=avg.decl_se_deg, incl_se_deg=avg.incl_se_deg)
        prior = offset_position(la, lo, *prior_offset)
        try:
            fix = geomagnetic_fix(model, avg.decl_deg, avg.incl_deg, float(prior[0]), float(prior[1]), al, year)
            rec.fix_error_m = geodesic_distance_m(fix.lat_deg, fix.lon_deg, la, lo)
            fix_pos.append((fix.lat_deg, fix.lon_deg))
        except PositionFixError as err:
            rec.fix_failed = str(err)
            fix_pos.append(None)
        recs.append(rec)
        gradients.append(g)
    return recs, fix_pos, gradients


def _fix_row(w: float, recs: list[WindowRecord], gradients: list[np.ndarray]) -> FixRow:
    """The fixes of one window length: the windows' D/I error (mean and spread), the fix error
    against its |G^-1 e| prediction; sets each record's noise-only prediction (its error less the
    mean error, through its window's G, ``gradients``)."""
    mean_e = np.array([circ_mean_deg([r.err_decl_deg for r in recs]), np.mean([r.err_incl_deg for r in recs])])
    for r, g in zip(recs, gradients):
        e_noise = np.array([float(wrap180(r.err_decl_deg - mean_e[0])), r.err_incl_deg - mean_e[1]])
        r.predicted_noise_m = float(np.hypot(*np.linalg.solve(g, e_noise)))
    fixes = [r.fix_error_m for r in recs]
    preds = [r.predicted_m for r in recs]
    ratios = [r.fix_error_m / r.predicted_m for r in recs if math.isfinite(r.fix_error_m) and r.predicted_m > 0]
    return FixRow(
        w, len(recs), sum(1 for r in recs if r.fix_failed),
        float(mean_e[0]), circ_std_deg([r.err_decl_deg for r in recs]),
        float(mean_e[1]), float(np.std([r.err_incl_deg for r in recs])),
        percentile(fixes, 50), percentile(fixes, 90), percentile(preds, 50), percentile(preds, 90),
        percentile(ratios, 50), min(ratios) if ratios else math.nan, max(ratios) if ratios else math.nan,
        percentile([r.predicted_noise_m for r in recs], 50))


def _fused_row(w: float, recs: list[WindowRecord], fix_pos: list[tuple[float, float] | None],
               ref: tuple[float, float], ins_track: tuple[np.ndarray, np.ndarray, np.ndarray], gps: np.ndarray,
               gps_e: np.ndarray, gps_n: np.ndarray) -> FusedRow:
    """4. Table 3's fusion of one window length, in local metres from the first fix (``ref``):
    the INS (``ins_track``: time, east, north) with each window's fix; sets each record's INS and
    fused errors against the GPS and the fusion's 1-sigma."""
    ins_t, ins_e, ins_n = ins_track
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
    fixes = [r.fix_error_m for r in recs]
    return FusedRow(
        w, len(recs), percentile([r.fused_error_m for r in recs], 50),
        percentile([r.fused_error_m for r in recs], 90), recs[-1].fused_error_m,
        percentile([r.ins_error_m for r in recs], 50), percentile(fixes, 50), recs[-1].fused_sigma_m)


def _source_note(path: Path) -> str:
    """A pointer to the log's provenance file (``<stem>.SOURCE.md`` beside it), if there is one."""
    note = path.with_name(path.stem + ".SOURCE.md")
    return f"source and licence of the log: {note.name}" if note.is_file() else ""


def _f_ratio(f_meas: np.ndarray, f_model: np.ndarray) -> float:
    """Median of measured |F| over the model's F (1 for a calibrated magnetometer)."""
    return float(np.median(f_meas / f_model)) if len(f_meas) else math.nan


def _warnings(data: LogData, seg: Segments, f_meas: np.ndarray, f_model: np.ndarray, mag_rate_hz: float) -> list[str]:
    """What makes this log's numbers mean less than they seem, in words for the report."""
    out = []
    ratio = _f_ratio(f_meas, f_model)
    if math.isfinite(ratio) and abs(ratio - 1.0) > F_RATIO_TOLERANCE:
        out.append(f"UNCALIBRATED MAGNETOMETER: the measured |F| is a median {ratio:.2f} times the model's "
                   f"({float(np.median(f_meas)) / 1e3:.1f} uT against {float(np.median(f_model)) / 1e3:.1f} uT; a "
                   f"calibrated one is within {F_RATIO_TOLERANCE:.0%}): hard/soft-iron offsets are not removed, so "
                   "D and I below measure the installation, not the Earth's field; calibrate the compass first")
    imu_hz = data.imu_rate_hz
    if math.isfinite(imu_hz) and imu_hz < MIN_INS_RATE_HZ:
        out.append(f"IMU at {imu_hz:.2g} Hz: dead reckoning needs tens of Hz (a flight controller logs 50-400); "
                   "the INS-only and fused figures from these samples are indicative only")
    if seg.takeoff_s is None:
        out.append("not a flight: " + ("the vehicle was never armed in this recording" if data.armed_source
                                       else "GPS never showed a take-off") + "; the numbers describe a recording "
                   "on the ground or carried, not navigation in the air")
    return out
