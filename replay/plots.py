"""The evaluation's PNG plots: D and I, position errors, headings, track (matplotlib, Agg)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from replay.records import ReplayEvaluation

__all__ = ["write_plots"]

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


def write_plots(ev: ReplayEvaluation, out: Path) -> list[Path]:
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
