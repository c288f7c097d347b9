"""The evaluation's PNG plots: D and I, position errors, headings, track (matplotlib, Agg)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fcmpc.replay.evaluate import MIN_INS_RATE_HZ
from fcmpc.replay.records import ReplayEvaluation
from fcmpc.replay.stats import circ_mean_deg, wrap180

__all__ = ["write_plots", "di_figure", "errors_figure", "heading_figure", "track_figure", "data_limits"]

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
    marks = ((seg.armed_s, "armed"), (seg.decl_step_s, "decl. applied"), (seg.takeoff_s, "take-off"),
             (seg.crash_s, "crash"), (seg.disarmed_s, "disarmed"))
    for k, (t, label) in enumerate(marks):
        if t is not None:
            ax.axvline(t, color="grey", ls=":", lw=1)
            ax.text(t, 0.99 - 0.06 * k, f" {label}", transform=ax.get_xaxis_transform(), fontsize=7, va="top",
                    color="grey")


def data_limits(measured: np.ndarray, model: np.ndarray, pad_deg: float = 1.0) -> tuple[float, float]:
    """Axis limits that hold 99 % of the measured values (the rest are spikes) and all of the
    model, padded by 5 % of the range and at least ``pad_deg``."""
    values = np.asarray(measured, dtype=float)
    values = values[np.isfinite(values)]
    lo = min(float(np.percentile(values, 0.5)) if len(values) else np.inf, float(np.nanmin(model)))
    hi = max(float(np.percentile(values, 99.5)) if len(values) else -np.inf, float(np.nanmax(model)))
    pad = max(pad_deg, 0.05 * (hi - lo))
    return lo - pad, hi + pad


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _colours(ev: ReplayEvaluation) -> tuple[list[float], dict[float, str]]:
    windows = sorted({r.window_s for r in ev.windows})
    return windows, dict(zip(windows, ("tab:blue", "tab:orange", "tab:red", "tab:purple", "tab:brown")))


def _ins_caveat(ev: ReplayEvaluation) -> str:
    rate = ev.imu_rate_hz
    return f" (WARNING: IMU at {rate:.2g} Hz, indicative only)" if np.isfinite(rate) and rate < MIN_INS_RATE_HZ else ""


def _span_words(ev: ReplayEvaluation) -> str:
    return "airborne span" if ev.is_flight else "recording (not a flight)"


def di_figure(ev: ReplayEvaluation):
    """D and I measured (at the log's real rate and as window means) vs the model; axes from the data."""
    plt = _pyplot()
    s = ev.series
    windows, colours = _colours(ev)
    fig, axes = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    ok = s["accepted"]
    for ax, key, label in ((axes[0], "decl", "D (deg)"), (axes[1], "incl", "I (deg)")):
        model = s[f"{key}_wmm"]
        meas = s[f"{key}_meas"]
        centre = circ_mean_deg(wrap180(meas[ok] - model[ok])) if key == "decl" else 0.0

        def unwrapped(t: np.ndarray, values: np.ndarray) -> np.ndarray:
            """D around the model + its circular mean error, so nothing jumps across +-180 deg."""
            if key != "decl":
                return values
            m = np.interp(t, s["t_mag"], model)
            return m + centre + wrap180(np.asarray(values) - m - centre)

        meas = unwrapped(s["t_mag"], meas)
        ax.plot(s["t_mag"][ok], meas[ok], ".", ms=1.5, color="0.6",
                label=f"measured, {ev.mag_rate_hz:.2g} Hz")
        for w in windows:
            recs = [r for r in ev.windows if r.window_s == w]
            values = list(unwrapped(np.array([r.centre_s for r in recs]),
                                    np.array([r.decl_deg if key == "decl" else r.incl_deg for r in recs])))
            ax.step([r.start_s for r in recs] + [recs[-1].end_s], values + values[-1:], where="post",
                    color=colours[w], lw=1.2, label=f"measured, {w:g} s mean")
        ax.plot(s["t_mag"], model, "k-", lw=1.5, label=f"{ev.model} at GPS position")
        _shade(ax, ev)
        ax.set_ylim(*data_limits(meas[ok], model))
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=3, loc="best")
    axes[1].set_xlabel("log time (s)")
    axes[0].set_title(f"{Path(ev.log).name}: D and I measured vs {ev.model} (green: {_span_words(ev)} judged)"
                      + (f"\nWARNING: uncalibrated magnetometer (|F| {ev.f_ratio:.2f} x model)" if ev.uncalibrated
                         else ""))
    return fig


def errors_figure(ev: ReplayEvaluation):
    """Fix, predicted, fused and INS-only horizontal errors against time (log scale)."""
    plt = _pyplot()
    s = ev.series
    windows, colours = _colours(ev)
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
    ax.set_title("Geomagnetic fix, INS-only drift and fused error" + _ins_caveat(ev))
    return fig


def heading_figure(ev: ReplayEvaluation):
    """Course commanded by the open-loop Fc-MPC vs course over ground flown."""
    plt = _pyplot()
    windows, colours = _colours(ev)
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
    return fig


def track_figure(ev: ReplayEvaluation):
    """GPS track vs INS-only tracks, to the end of the judged span."""
    plt = _pyplot()
    s = ev.series
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
    ax.set_title(f"Track: GPS vs INS-only (to the end of the {_span_words(ev)})" + _ins_caveat(ev))
    return fig


def write_plots(ev: ReplayEvaluation, out: Path) -> list[Path]:
    """di.png, errors.png, heading.png, track.png in ``out``."""
    figures = (("di.png", di_figure), ("errors.png", errors_figure), ("heading.png", heading_figure),
               ("track.png", track_figure))
    return [_save(build(ev), out / name) for name, build in figures]
