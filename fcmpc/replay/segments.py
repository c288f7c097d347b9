"""Segmentation of one boot: its flights (armed spans that left the ground), and per flight the
first fix, the declination step on the ground, take-off, crash and the end of the airborne span.

A flight is an armed span (``LogData.armed``: HEARTBEAT base_mode, DataFlash EV/ARM, PX4
vehicle_status, a CSV ``armed`` column) in which the vehicle left the ground: the first of
:data:`TAKEOFF_CONSECUTIVE` consecutive armed GPS fixes with ground speed above
:data:`TAKEOFF_SPEED_MPS` or altitude more than :data:`TAKEOFF_CLIMB_M` above the ground
altitude at arming (median of the fixes of the :data:`GROUND_REFERENCE_S` before arming).
GPS altitude drifting on the ground while disarmed is therefore never a take-off, and each
armed span is a flight of its own. A log without any armed state falls back to GPS alone
(ground = the first :data:`GROUND_REFERENCE_S` of fixes) and says so. The rules actually applied
are printed with every report.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fcmpc.replay.logdata import LogData
from fcmpc.replay.stats import tilt_deg, wrap180

__all__ = ["Flight", "Segments", "find_flights", "find_segments", "HOVER_TILT_DEG", "HOVER_SPEED_MPS"]

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
    armed_s: float | None = None
    disarmed_s: float | None = None
    judged_from_s: float | None = None   # the end of the samples a calibration was fitted on

    @property
    def nav_start_s(self) -> float:
        """Start of the span the navigation is judged on: take-off, else the first fix; not before
        ``judged_from_s`` (fcmpc-replay judges only samples its calibration did not see)."""
        start = self.takeoff_s if self.takeoff_s is not None else self.first_fix_s
        return start if self.judged_from_s is None else max(start, self.judged_from_s)


@dataclass(frozen=True)
class Flight:
    """One flight of a boot: armed span (None: the log has no armed state), take-off, and the
    window of the boot's data its evaluation reads (from the previous disarm to its own)."""

    armed_s: float | None
    disarmed_s: float | None
    takeoff_s: float
    ground_alt_m: float
    window_s: tuple[float, float]


def _takeoff(gps: np.ndarray, ground_alt: float, allowed: np.ndarray) -> tuple[float | None, np.ndarray]:
    """First of TAKEOFF_CONSECUTIVE allowed fixes that look airborne; and the airborne mask."""
    speed = np.nan_to_num(np.hypot(gps[:, 4], gps[:, 5]))
    flying = allowed & ((speed > TAKEOFF_SPEED_MPS) | (gps[:, 3] > ground_alt + TAKEOFF_CLIMB_M))
    run = np.convolve(flying.astype(int), np.ones(TAKEOFF_CONSECUTIVE, dtype=int), mode="valid")
    hits = np.flatnonzero(run == TAKEOFF_CONSECUTIVE)
    return (float(gps[hits[0], 0]) if len(hits) else None), flying


def armed_spans(data: LogData) -> list[tuple[float, float | None]]:
    """(armed, disarmed or None) from the boot's armed transitions."""
    spans: list[tuple[float, float | None]] = []
    start = None
    for t, armed in data.armed:
        if armed and start is None:
            start = t
        elif not armed and start is not None:
            spans.append((start, t))
            start = None
    if start is not None:
        spans.append((start, None))
    return spans


def _ground_alt(gps: np.ndarray, armed_s: float) -> float:
    t = gps[:, 0]
    before = (t >= armed_s - GROUND_REFERENCE_S) & (t <= armed_s)
    if not before.any():
        before = t <= max(armed_s, float(t[0])) + 2.0
    return float(np.median(gps[before, 3])) if before.any() else float(gps[0, 3])


def find_flights(data: LogData) -> tuple[list[Flight], list[str]]:
    """The boot's flights, and a line for each armed span that never left the ground."""
    gps = data.gps
    if len(gps) == 0:
        return [], []
    t = gps[:, 0]
    if not data.armed_source:
        ground = float(np.median(gps[t <= t[0] + GROUND_REFERENCE_S, 3]))
        takeoff, _ = _takeoff(gps, ground, np.ones(len(t), dtype=bool))
        return ([Flight(None, None, takeoff, ground, (-np.inf, np.inf))] if takeoff is not None else []), []
    flights, notes = [], []
    spans = armed_spans(data)
    previous_end = -np.inf
    for k, (a, b) in enumerate(spans):
        ground = _ground_alt(gps, a)
        allowed = (t >= a) & (t <= (b if b is not None else np.inf))
        takeoff, _ = _takeoff(gps, ground, allowed)
        until = b if b is not None else (spans[k + 1][0] if k + 1 < len(spans) else np.inf)
        if takeoff is None:
            notes.append(f"armed {a:.1f}-" + (f"{b:.1f} s" if b is not None else "end") +
                         " but never left the ground (no 3 consecutive armed fixes faster than "
                         f"{TAKEOFF_SPEED_MPS:g} m/s or {TAKEOFF_CLIMB_M:g} m above the ground at arming): not a flight")
        else:
            flights.append(Flight(a, b, takeoff, ground, (previous_end, until)))
        previous_end = until
    return flights, notes


def find_segments(data: LogData, decl_t: np.ndarray, decl_deg: np.ndarray, crash_guard_s: float = 10.0,
                  flight: Flight | None = None) -> Segments:
    """Segment times of one flight (None: a recording that is not a flight) from GPS, attitude,
    the armed state and the measured D (rules in the module docstring)."""
    gps = data.gps
    t = gps[:, 0]
    first_fix = float(t[0])
    armed_s = flight.armed_s if flight is not None else None
    disarmed_s = flight.disarmed_s if flight is not None else None
    if flight is not None and armed_s is not None:
        ground_alt = flight.ground_alt_m
        rules = [f"first 3D GPS fix at {first_fix:.1f} s; armed at {armed_s:.1f} s"
                 + (f", disarmed at {disarmed_s:.1f} s" if disarmed_s is not None else ", never disarmed")
                 + f" ({data.armed_source}); ground altitude {ground_alt:.1f} m (median of the fixes of the "
                 f"{GROUND_REFERENCE_S:.0f} s before arming)"]
        allowed = (t >= armed_s) & (t <= (disarmed_s if disarmed_s is not None else np.inf))
    else:
        ground_alt = float(np.median(gps[t <= first_fix + GROUND_REFERENCE_S, 3]))
        rules = [f"first 3D GPS fix at {first_fix:.1f} s; ground altitude {ground_alt:.1f} m "
                 f"(median of the first {GROUND_REFERENCE_S:.0f} s of fixes)"]
        if not data.armed_source:
            rules.append("the log has no armed state (HEARTBEAT, EV/ARM, vehicle_status, armed column): "
                         "take-off from GPS alone")
        allowed = np.ones(len(t), dtype=bool)
    takeoff, flying = _takeoff(gps, ground_alt, allowed) if flight is not None else (None, allowed)
    crash = None
    end = float(t[-1])
    if takeoff is None:
        rules.append("not a flight (never armed and off the ground): the whole recording after the first "
                     "fix is evaluated as one segment")
    else:
        rules.append(f"take-off at {takeoff:.1f} s: first of {TAKEOFF_CONSECUTIVE} consecutive "
                     + ("armed " if armed_s is not None else "")
                     + f"fixes with ground speed > {TAKEOFF_SPEED_MPS:g} m/s or altitude > ground + "
                     f"{TAKEOFF_CLIMB_M:g} m")
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
    return Segments(first_fix, ground_alt, step, takeoff, crash, end, rules, armed_s, disarmed_s)
