"""Records of a companion session: one CSV row per control step, and the session summary.

``steps.csv`` columns (one row per call of the navigation core, plus rows for start-up and
restarts, ``event`` says which):

==================  ===========================================================================
wall_time_s         UNIX wall time of the row
msg_time_s          flight-controller boot time of the step (message time)
mission_time_s      time since the mission started, pauses excluded (what the core sees)
mission, step       mission number (restarts count up) and the core's step index
phase               the core's phase after the step (probe1, probe2, cruise, arrived, ...)
decl_deg, incl_deg  the averaged measurement passed to the core (f_nt: total intensity, nT)
samples, window_s   magnetometer samples in the average and the window passed to the core
spikes, invalid     cumulative rejected samples (spike filter; invalid/saturated/stuck/NaN)
ins_lat/lon_deg     INS position passed to the core; ``ins_source`` fc | dead_reckoning | none
est_lat/lon_deg     fused position estimate; est_sigma_m its 1-sigma
fix_lat/lon_deg     geomagnetic fix of the step
fused               1 when the INS was fused (weak gradient)
remaining_m         estimated remaining distance
course_deg          commanded course (from north, clockwise); speed_mps commanded speed
solver_ok           0 when the QP failed; solver_time_s the QP time
step_latency_s      wall time of the whole step (average + core + outputs)
event               step | start | restart | done | failsafe | excluded | reanchored (the
                    excluded fixes agreed: ``jump_m`` the shift, ``est_sigma_m`` its 1-sigma)
reason              the core's or the failsafe's reason text
gps_fix             GPS_RAW_INT fix type at the step (0 none/stale); gps_lat/lon_deg the fix
                    when >= 2D: a reference for evaluation only, never used to steer
incl_se_deg         the period's standard error of I; jump_m, bound_m, noise_m the plausibility
                    verdict (the implied fix's jump, its bound, the noise term)
mag_heading_deg     the magnetic heading measured over the period (magnetometer levelled by the
                    accelerometer); plus the model's D it is the heading dead-reckoned on
sent_course_deg     the course the setpoints carry: course_deg plus the FC's yaw error
                    (``COMP_TRIM_DEG``, :mod:`companion.nav.steering`), else course_deg
==================  ===========================================================================
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path

__all__ = ["STEP_COLUMNS", "StepRecorder", "parse_steps_csv", "read_steps_csv", "write_summary"]

STEP_COLUMNS = (
    "wall_time_s", "msg_time_s", "mission_time_s", "mission", "step", "phase", "decl_deg", "incl_deg", "f_nt", "samples",
    "window_s", "spikes", "invalid", "ins_lat_deg", "ins_lon_deg", "ins_source", "est_lat_deg", "est_lon_deg",
    "est_sigma_m", "fix_lat_deg", "fix_lon_deg", "fused", "remaining_m", "course_deg", "speed_mps", "solver_ok",
    "solver_time_s", "step_latency_s", "event", "reason", "gps_fix", "gps_lat_deg", "gps_lon_deg",
    "incl_se_deg", "jump_m", "bound_m", "noise_m", "mag_heading_deg", "sent_course_deg",
)


def _fmt(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        return "nan" if not math.isfinite(value) else repr(value)
    return str(value)


class StepRecorder:
    """Appends :data:`STEP_COLUMNS` rows; each row is flushed (a crash loses at most the last)."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._file)
        self._writer.writerow(STEP_COLUMNS)
        self._file.flush()
        self.rows = 0

    def write(self, row: dict) -> None:
        unknown = set(row) - set(STEP_COLUMNS)
        if unknown:
            raise KeyError(f"unknown step column(s): {', '.join(sorted(unknown))}")
        self._writer.writerow([_fmt(row.get(name)) for name in STEP_COLUMNS])
        self._file.flush()
        self.rows += 1

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()


def write_summary(path: str | os.PathLike, summary: dict) -> None:
    """The session summary as JSON (written via a temporary file and rename)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.tmp")
    tmp.write_text(json.dumps(summary, indent=1, default=str) + "\n", encoding="utf-8")
    os.replace(tmp, target)


def read_steps_csv(path: str | os.PathLike) -> list[dict]:
    """Rows of a steps.csv with numbers as floats (text columns kept as text)."""
    with open(path, newline="", encoding="utf-8") as handle:
        return parse_steps_csv(handle.read())


def parse_steps_csv(text: str) -> list[dict]:
    """Rows of a steps.csv's text with numbers as floats (text columns kept as text); a row cut
    short (a reader racing the writer) has NaN or "" for the columns it lacks.

    >>> [(r["step"], r["phase"], r["remaining_m"]) for r in parse_steps_csv("step,phase,remaining_m\\n3,cruise,\\n")]
    [(3.0, 'cruise', nan)]
    """
    text_columns = {"phase", "ins_source", "event", "reason"}
    rows = []
    for raw in csv.DictReader(io.StringIO(text, newline="")):
        row = {}
        for key, value in raw.items():
            if key is None:                 # more fields than columns: not ours
                continue
            if key in text_columns:
                row[key] = value or ""
            else:
                try:
                    row[key] = float(value) if value else math.nan
                except ValueError:
                    row[key] = value
        rows.append(row)
    return rows
