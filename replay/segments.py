"""Segmentation of a log: first fix, declination step on the ground, take-off, crash, end.

The rules are in :mod:`replay` and printed with every report.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from replay.logdata import LogData
from replay.stats import tilt_deg, wrap180

__all__ = ["Segments", "find_segments", "HOVER_TILT_DEG", "HOVER_SPEED_MPS"]

# Segment rules (see the module docstring).
TAKEOFF_SPEED_MPS = 1.0
TAKEOFF_CLIMB_M = 1.5
TAKEOFF_CONSECUTIVE = 3
GROUND_REFERENCE_S = 10.0
CRASH_TILT_DEG = 60.0
HOVER_TILT_DEG = 10.0
HOVER_SPEED_MPS = 1.0
DECL_STEP_DEG = 5.0
DECL_STEP_HALF_S = 3.0


@dataclass
class Segments:
    """Times (log seconds) that split the flight; None when the data shows no such event."""

    first_fix_s: float
    ground_alt_m: float
    decl_step_s: float | None
    takeoff_s: float | None
    crash_s: float | None
    end_s: float
    rules: list[str] = field(default_factory=list)

    @property
    def nav_start_s(self) -> float:
        """Start of the span the navigation is judged on: take-off, else the first fix."""
        return self.takeoff_s if self.takeoff_s is not None else self.first_fix_s


def find_segments(data: LogData, decl_t: np.ndarray, decl_deg: np.ndarray, crash_guard_s: float = 10.0) -> Segments:
    """Segment times from GPS, attitude and the measured D (rules in the module docstring)."""
    gps = data.gps
    t = gps[:, 0]
    first_fix = float(t[0])
    ground_alt = float(np.median(gps[t <= first_fix + GROUND_REFERENCE_S, 3]))
    speed = np.hypot(gps[:, 4], gps[:, 5])
    flying = (np.nan_to_num(speed) > TAKEOFF_SPEED_MPS) | (gps[:, 3] > ground_alt + TAKEOFF_CLIMB_M)
    run = np.convolve(flying.astype(int), np.ones(TAKEOFF_CONSECUTIVE, dtype=int), mode="valid")
    hits = np.flatnonzero(run == TAKEOFF_CONSECUTIVE)
    takeoff = float(t[hits[0]]) if len(hits) else None
    rules = [
        f"first 3D GPS fix at {first_fix:.1f} s; ground altitude {ground_alt:.1f} m "
        f"(median of the first {GROUND_REFERENCE_S:.0f} s of fixes)",
    ]
    crash = None
    end = float(t[-1])
    if takeoff is None:
        rules.append("no take-off found (GPS never faster than 1 m/s nor 1.5 m above ground): "
                     "the whole log after the first fix is evaluated as one segment")
    else:
        rules.append(f"take-off at {takeoff:.1f} s: first of {TAKEOFF_CONSECUTIVE} consecutive fixes with "
                     f"ground speed > {TAKEOFF_SPEED_MPS:g} m/s or altitude > ground + {TAKEOFF_CLIMB_M:g} m")
        att = data.att
        after = att[:, 0] > takeoff
        over = np.flatnonzero(after & (tilt_deg(att) > CRASH_TILT_DEG))
        if len(over):
            crash = float(att[over[0], 0])
        airborne_fixes = t[flying & (t >= takeoff)]
        end = float(airborne_fixes[-1])
        if crash is not None:
            end = min(end, crash - crash_guard_s)
            rules.append(f"crash at {crash:.1f} s: first attitude tilted > {CRASH_TILT_DEG:g} deg after take-off; "
                         f"the airborne span ends {crash_guard_s:g} s earlier, at {end:.1f} s")
        else:
            rules.append(f"no crash (tilt never > {CRASH_TILT_DEG:g} deg); the airborne span ends at the last "
                         f"airborne-looking fix, {end:.1f} s")
    # The declination step on the ground: largest jump between the medians of D over the
    # DECL_STEP_HALF_S before and after a time, if larger than DECL_STEP_DEG.
    step = None
    ground_end = takeoff if takeoff is not None else end
    sel = (decl_t >= first_fix) & (decl_t < ground_end)
    if sel.sum() > 10:
        times, values = decl_t[sel], decl_deg[sel]
        best, best_t = 0.0, None
        for k in range(len(times)):
            before = values[(times >= times[k] - DECL_STEP_HALF_S) & (times < times[k])]
            later = values[(times >= times[k]) & (times < times[k] + DECL_STEP_HALF_S)]
            if len(before) < 5 or len(later) < 5:
                continue
            jump = abs(float(wrap180(np.median(later) - np.median(before))))
            if jump > best:
                best, best_t = jump, float(times[k])
        if best_t is not None and best > DECL_STEP_DEG:
            step = best_t
            rules.append(f"declination step on the ground at {step:.1f} s (median D jumps {best:.1f} deg: the "
                         "flight controller starts applying its declination); the ground data before it is "
                         "excluded from the judgement")
    if takeoff is not None:
        rules.append(f"hover = airborne with tilt < {HOVER_TILT_DEG:g} deg and GPS speed < {HOVER_SPEED_MPS:g} m/s")
    return Segments(first_fix, ground_alt, step, takeoff, crash, end, rules)
