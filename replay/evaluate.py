"""The evaluation of one log: D and I vs the model, fixes (eq. 49), INS, fusion, open-loop mission."""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from companion.nav.field import PositionFixError, decl_incl_gradient, geomagnetic_fix
from companion.nav.fusion import FusionSettings, InsGeomagFusion
from companion.nav.geo import enu_offset, geodesic_distance_m, offset_position
from companion.nav.magnetometer import PeriodAverager, SpikeFilter, tilt_compensated_di
from replay.heading import model_di_gradient, run_mission
from replay.ins import ins_track, stationary_bias
from replay.logdata import read_log
from replay.models import log_decimal_year, select_model
from replay.records import DIRow, FixRow, FusedRow, HeadingRow, InsRow, ReplayEvaluation, WindowRecord
from replay.segments import HOVER_SPEED_MPS, HOVER_TILT_DEG, find_segments
from replay.stats import interp_gps, percentile, wrap180, wrap_pi

__all__ = ["evaluate", "DEFAULT_WINDOWS_S", "INS_REPORT_S", "SPIKE_NT"]

DEFAULT_WINDOWS_S = (1.0, 10.0, 30.0)
INS_REPORT_S = (10.0, 30.0, 60.0)
SPIKE_NT = 5000.0            # COMP_SPIKE_NT default


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
    lat_m, lon_m, alt_m = interp_gps(gps, t_m)
    wmm = model.elements(lat_m, lon_m, alt_m, year)
    err_d = wrap180(meas[:, 0] - wmm.decl_deg)
    err_i = meas[:, 1] - wmm.incl_deg
    err_f = meas[:, 2] - wmm.f_nt
    accepted = meas[:, 3] > 0.5

    seg = find_segments(data, t_m, meas[:, 0], crash_guard_s)
    tilt_m = np.degrees(np.maximum(np.abs(wrap_pi(roll)), np.abs(wrap_pi(pitch))))
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
    bias = stationary_bias(data, seg.first_fix_s, rest_end)
    tracks: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    ins_defs = [("INS, raw IMU, from first fix", seg.first_fix_s, None)]
    if bias is not None:
        ins_defs.append(("INS, static alignment, from first fix", seg.first_fix_s, bias))
        if seg.takeoff_s is not None:
            ins_defs.append(("INS, static alignment, from take-off", seg.takeoff_s, bias))
    for name, start, b in ins_defs:
        ti, pe, pn = ins_track(data, start, ref, b)
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
            la, lo, al = (float(v) for v in interp_gps(gps, tc))
            decl, incl, g = model_di_gradient(model, la, lo, al, year)
            e = np.array([float(wrap180(avg.decl_deg - decl)), avg.incl_deg - incl])
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
            la, lo, al = (float(v) for v in interp_gps(gps, r.centre_s))
            g = model_di_gradient(model, la, lo, al, year)[2]
            e_noise = np.array([r.err_decl_deg, r.err_incl_deg]) - mean_e
            r.predicted_noise_m = float(np.hypot(*np.linalg.solve(g, e_noise)))
        fixes = [r.fix_error_m for r in recs]
        preds = [r.predicted_m for r in recs]
        ratios = [r.fix_error_m / r.predicted_m for r in recs if math.isfinite(r.fix_error_m) and r.predicted_m > 0]
        fix_rows.append(FixRow(
            w, len(recs), sum(1 for r in recs if r.fix_failed),
            float(mean_e[0]), float(np.std([r.err_decl_deg for r in recs])),
            float(mean_e[1]), float(np.std([r.err_incl_deg for r in recs])),
            percentile(fixes, 50), percentile(fixes, 90), percentile(preds, 50), percentile(preds, 90),
            percentile(ratios, 50), min(ratios) if ratios else math.nan, max(ratios) if ratios else math.nan,
            percentile([r.predicted_noise_m for r in recs], 50)))

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
            w, len(recs), percentile([r.fused_error_m for r in recs], 50),
            percentile([r.fused_error_m for r in recs], 90), recs[-1].fused_error_m,
            percentile([r.ins_error_m for r in recs], 50), percentile(fixes, 50), recs[-1].fused_sigma_m))

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
