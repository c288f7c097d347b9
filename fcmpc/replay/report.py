"""The report's words: the markdown tables and what the numbers mean (``table.md``)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from companion.nav.fusion import FusionSettings
from fcmpc.replay.evaluate import INS_REPORT_S, MIN_INS_RATE_HZ, SPIKE_NT
from fcmpc.replay.logeval import LogEvaluation
from fcmpc.replay.records import FixRow, ReplayEvaluation

__all__ = ["format_report", "format_log_report"]

def _f(value: float, digits: int = 2) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _km(value_m: float) -> str:
    if value_m is None or not math.isfinite(value_m):
        return "n/a"
    return f"{value_m / 1e3:.1f}" if value_m >= 10e3 else f"{value_m / 1e3:.2f}"


def _hz(rate: float) -> str:
    return "n/a Hz" if not math.isfinite(rate) else f"{rate:.2g} Hz"


def _failed(row: FixRow | None) -> str:
    """The share of fixes that failed, said beside every median of the ones that did not."""
    if row is None or row.n == 0:
        return "no fixes"
    return f"{100.0 * row.failed / row.n:.0f} % of {row.n} failed"


def _unit_words(ev: ReplayEvaluation) -> str:
    parts = []
    if ev.boots > 1:
        parts.append(f"boot {ev.boot + 1} of {ev.boots}")
    if ev.is_flight and ev.flights > 1:
        parts.append(f"flight {ev.flight} of {ev.flights}")
    elif not ev.is_flight:
        parts.append("a recording, not a flight")
    return ", ".join(parts)


def format_log_report(result: LogEvaluation) -> str:
    """A log with several boots or flights: the list of what was evaluated, then each report."""
    lines = [f"# Replay evaluation of `{Path(result.path).name}`: {result.boots} boot(s), "
             f"{len(result.evaluations)} evaluation(s)", ""]
    for label, ev in zip(result.labels, result.evaluations):
        seg = ev.segments
        fix = ev.fix_row(10.0) or (ev.fix_rows[0] if ev.fix_rows else None)
        lines.append(f"- `{label}/`: {_unit_words(ev) or 'the only flight'}, judged {seg.nav_start_s:.1f}-"
                     f"{seg.end_s:.1f} s; fix median "
                     + (f"{_km(fix.fix_median_m)} km over {fix.window_s:g} s ({_failed(fix)})" if fix else "n/a")
                     + "".join(f" (before the calibration {_km(b.fix_median_m)} km, {_failed(b)})"
                               for b in ev.fix_rows_before if fix and b.window_s == fix.window_s)
                     + "".join(f"; warning: {w.split(':')[0]}" for w in ev.warnings))
    for note in result.skipped:
        lines.append(f"- not evaluated: {note}")
    lines.append("")
    return "\n".join(lines) + "\n" + "\n".join(format_report(ev) for ev in result.evaluations)


def format_report(ev: ReplayEvaluation) -> str:
    """The markdown report (what is printed and written to table.md): the header, then one
    section per part of the evaluation."""
    seg = ev.segments
    lines: list[str] = []
    add = lines.append
    t0, t1 = ev.span_s
    what = _unit_words(ev)
    add(f"# Replay evaluation of `{Path(ev.log).name}` against its own GPS" + (f": {what}" if what else ""))
    add("")
    for warning in ev.warnings:
        add(f"**Warning: {warning}.**")
        add("")
    add(f"- Log: {ev.format}, {t1 - t0:.1f} s of sensor data ({t0:.1f}-{t1:.1f} s log time)"
        + (f", date {ev.date} (decimal year {ev.decimal_year:.2f}) from the {ev.date_source}" if ev.date else "")
        + (f" ({ev.date_note})" if ev.date_note else "")
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
        "offsets and soft-iron correction" + ("; then the calibration of section 0" if ev.fix_rows_before else "")
        + f"); {ev.spikes_rejected} samples rejected by the "
        f"{SPIKE_NT:.0f} nT spike filter.")
    add("- Segments, chosen from the data: " + "; ".join(seg.rules) + ".")
    add("")
    for section in (_calibration_section, _di_section, _fix_section, _ins_section, _fused_section, _heading_section,
                    _closing_sections):
        lines += section(ev)
    return "\n".join(lines) + "\n"


def _calibration_section(ev: ReplayEvaluation) -> list[str]:
    """0. The magnetometer calibration applied, and the fix error before and after it."""
    if not ev.calibration:
        return []
    lines = ["## 0. Magnetometer calibration (fcmpc-calibrate's fit; --no-calibration replays the log as recorded)",
             "", *(f"    {line}" for line in ev.calibration.splitlines()), ""]
    if ev.fix_rows_before:
        lines += ["| Window (s) | Fix error median before (km) | after (km) | before / after |", "|---|---|---|---|"]
        for r in ev.fix_rows:
            b = next((x for x in ev.fix_rows_before if x.window_s == r.window_s), None)
            before = b.fix_median_m if b else math.nan
            ratio = before / r.fix_median_m if r.fix_median_m > 0 else math.nan
            lines.append(f"| {r.window_s:g} | {_km(before)} ({_failed(b)}) | {_km(r.fix_median_m)} ({_failed(r)}) "
                         f"| {_f(ratio, 1)} |")
        lines.append("")
    return lines


def _di_section(ev: ReplayEvaluation) -> list[str]:
    """1. D and I measured against the model at the GPS position, per segment."""
    lines: list[str] = []
    add = lines.append
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
    add(f"Bias = mean of (measured - model), spread = standard deviation of single samples "
        f"({_hz(ev.mag_rate_hz)}); for D both are circular (mean direction, sqrt(-2 ln R)), so errors near "
        "+-180 deg do not average to zero; rows in italics are not judged. The measured D "
        "uses the logged yaw, which is the flight controller's own heading estimate computed from this compass and "
        "a declination: D is a consistency check of the flight controller, not an independent measurement. "
        "I does not depend on yaw, only on roll, pitch and the compass calibration, so the I bias is a real "
        "measurement error (calibration, mounting or local field); the F bias shows the calibration is not absolute.")
    add("")
    return lines


def _fix_section(ev: ReplayEvaluation) -> list[str]:
    """2. The geomagnetic fixes against the GPS, per window length."""
    lines: list[str] = []
    add = lines.append
    add("## 2. Geomagnetic position fix (eq. 49) vs GPS")
    add("")
    add(f"Fix from D, I averaged over non-overlapping windows of the judged span, Newton from a prior "
        f"{math.hypot(*ev.prior_offset_m) / 1e3:.0f} km north-east of the GPS position; predicted = |G^-1 e| "
        f"with e the window's (D, I) error and G the model gradient at the GPS position; "
        f"'noise only' = the same with the span's mean error removed (as if the bias were calibrated out).")
    add("")
    add("| Window (s) | Windows | Fix failed | D error mean +- std (deg) | I error mean +- std (deg) "
        "| Fix error median (km), failed share | Fix error p90 (km) | Predicted median (km) | Predicted p90 (km) "
        "| Fix / predicted median [min-max] | Noise only, predicted median (km) |")
    add("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in ev.fix_rows:
        add(f"| {r.window_s:g} | {r.n} | {r.failed} | {r.err_decl_mean_deg:+.2f} +- {r.err_decl_std_deg:.2f} | "
            f"{r.err_incl_mean_deg:+.2f} +- {r.err_incl_std_deg:.2f} | {_km(r.fix_median_m)} ({_failed(r)}) | "
            f"{_km(r.fix_p90_m)} | "
            f"{_km(r.predicted_median_m)} | {_km(r.predicted_p90_m)} | {_f(r.ratio_median)} "
            f"[{_f(r.ratio_min)}-{_f(r.ratio_max)}] | {_km(r.predicted_noise_median_m)} |")
    add("")
    return lines


def _ins_section(ev: ReplayEvaluation) -> list[str]:
    """3. The INS's drift alone against the GPS."""
    lines: list[str] = []
    add = lines.append
    add("## 3. INS-only drift (horizontal error vs GPS, m)")
    add("")
    keys = [f"+{s:g} s" for s in INS_REPORT_S] + ["end of judged span"]
    if math.isfinite(ev.imu_rate_hz) and ev.imu_rate_hz < MIN_INS_RATE_HZ:
        add(f"**Warning: the IMU is logged at {_hz(ev.imu_rate_hz)}; dead reckoning at this rate misses the "
            "vehicle's accelerations, so these numbers are indicative only.**")
        add("")
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
    return lines


def _fused_section(ev: ReplayEvaluation) -> list[str]:
    """4. Table 3's fused position against the GPS, per window length."""
    lines: list[str] = []
    add = lines.append
    add("## 4. Fused position (Table 3 filter: Q_c 0.05 km^2, R_c 2 km^2, P_0 1 km^2) vs GPS")
    add("")
    add("| Window (s) | Steps | Fused median (km) | Fused p90 (km) | Fused at end (km) | Filter sigma at end (km) "
        "| INS alone median (m) | Fix alone median (km) |")
    add("|---|---|---|---|---|---|---|---|")
    for r in ev.fused_rows:
        add(f"| {r.window_s:g} | {r.steps} | {_km(r.fused_median_m)} | {_km(r.fused_p90_m)} | {_km(r.fused_final_m)} | "
            f"{_km(r.sigma_final_m)} | {_f(r.ins_median_m, 0)} | "
            f"{_km(r.fix_median_m)} ({_failed(ev.fix_row(r.window_s))}) |")
    add("")
    rc_km = math.sqrt(FusionSettings().rc_m2) / 1e3
    worst = max(ev.fused_rows, key=lambda r: r.fused_median_m, default=None)
    add("The INS fed to the filter is the statically aligned one from the first fix; the filter steps once per window."
        + (f" Table 3's R_c trusts the fix to {rc_km:.1f} km (1 sigma), so with fixes hundreds of km off the filter "
           f"walks towards the fix while its own sigma ({_km(worst.sigma_final_m)} km) says nothing about its error."
           if worst is not None and worst.fused_median_m > 10e3 * rc_km else ""))
    add("")
    return lines


def _heading_section(ev: ReplayEvaluation) -> list[str]:
    """5. The heading the controller would have commanded against the heading flown."""
    lines: list[str] = []
    add = lines.append
    add("## 5. Heading the controller would have commanded vs the heading flown")
    add("")
    add(f"Mission: {ev.mission_note}. Open-loop: the commands are not flown, so the measurements come from the "
        "pilot's path, not from the commanded one. The command issued at the end of a window is compared with the "
        "GPS course over ground of the next window (windows slower than 1 m/s and the two probing steps excluded). "
        "'Ideal' = the geodesic course from the true (GPS) position to the destination, for scale: the pilot was not "
        "flying to a destination either.")
    add("")
    add("| Window (s) | Mission steps | Excluded | Compared | Median abs(commanded - flown) (deg) "
        "| Median abs(ideal - flown) (deg) | Mission position error median (km) | Mission state at end |")
    add("|---|---|---|---|---|---|---|---|")
    for r in ev.heading_rows:
        state = r.final_phase + (f" ({r.reason})" if r.reason else "")
        add(f"| {r.window_s:g} | {r.steps} | {r.excluded} | {r.compared} | {_f(r.median_abs_diff_deg, 0)} | "
            f"{_f(r.ideal_median_abs_diff_deg, 0)} | {_km(r.est_error_median_m)} | {state} |")
    add("")
    return lines


def _closing_sections(ev: ReplayEvaluation) -> list[str]:
    """What the numbers mean, and the evaluation's limitations."""
    lines: list[str] = []
    add = lines.append
    meaning = _meaning(ev)
    if meaning:
        add("## What the numbers mean")
        add("")
        add(meaning)
        add("")
    add("## Limitations")
    add("")
    add(f"This is a {ev.segments.end_s - ev.segments.nav_start_s:.0f} s {'flight' if ev.is_flight else 'recording'} "
        "within "
        f"{max(1.0, _track_extent_m(ev)):.0f} m of its first fix, not the paper's measured experiment (Section 4.3: "
        "Xi'an to Jiayuguan, 1,368 km of GPS track in Table 8): the field model changes by far less across the "
        f"whole {'flight' if ev.is_flight else 'recording'} than the sensor's noise, so it can show the size of "
        "the measurement errors and what they do "
        "to a fix, not whether Fc-MPC reaches a destination. "
        "The heading comparison is a plumbing check of the open-loop controller, not a navigation result.")
    return lines


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
        f"{_km(fix.fix_median_m)} km from GPS ({_failed(fix)}{', not in the median' if fix.failed else ''}; "
        f"|G^-1 e| predicts "
        f"{_km(fix.predicted_median_m)} km). Calibrating "
        f"the mean bias away perfectly would still leave {_km(fix.predicted_noise_median_m)} km from the "
        f"window-to-window spread alone{_averaging_words(ev)}. The IMU dead-reckons ({ins.name}) to "
        f"{_f(ins.errors_m['+30 s'], 0)} m after 30 s and {_f(ins.errors_m['+60 s'], 0)} m after 60 s; a fix that "
        f"helps it at the 100 m level "
        f"needs D and I right to about {good_deg:.4f} deg ({good_deg * 3600:.1f} arcsec), "
        f"about {_two_figures(typical_deg / good_deg):,.0f} times smaller than the errors measured here. On this "
        f"log the geomagnetic fix is good to {_magnitude_words(fix.fix_median_m)}: that only means something on "
        f"routes much longer "
        f"than the error, and only after a calibration of the bias against the model that a {minutes:.1f}-minute "
        f"{'flight' if ev.is_flight else 'recording'} at one place cannot check."
        + (" And first of all: the magnetometer is uncalibrated (|F| is "
           f"{ev.f_ratio:.2f} times the model's), so these errors are the installation's, not the method's."
           if ev.uncalibrated else ""))


def _track_extent_m(ev: ReplayEvaluation) -> float:
    s = ev.series
    if "gps_e" not in s or not len(s["gps_e"]):
        return 0.0
    return float(np.max(np.hypot(s["gps_e"], s["gps_n"])))
