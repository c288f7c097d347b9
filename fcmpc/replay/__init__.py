"""Measured-data evaluation like the paper's Table 8: a recorded flight replayed open-loop.

    fcmpc-replay ../shared/data/logs/log171.bin
    python -m fcmpc.replay LOG [--model WMM2015|path.COF] [--window-s 1,10,30] [--out DIR]

``LOG`` is an ArduPilot DataFlash ``.bin`` or a MAVLink ``.tlog`` (read by
:class:`companion.io.sensors.replay.LogReplaySource`). The log's own GPS is the truth; the
navigation side sees only the magnetometer, the IMU and the flight controller's attitude, and
GPS only once, at the first 3D fix (start position and velocity of the INS, start of the mission).

What it reports (markdown on stdout, and ``table.md``, ``summary.json``, ``windows.csv`` and PNG
plots in ``out/replay/<log stem>/``):

1. D and I measured (body field rotated to NED with the logged roll/pitch/yaw) against the World
   Magnetic Model at the GPS position, per flight segment: bias (mean of measured - model) and
   spread (standard deviation). The logged yaw is the flight controller's heading estimate,
   which was itself computed from this compass and a declination, so the measured D is a
   consistency check of the flight controller, not an independent measurement. I is
   independent of yaw (it depends on roll, pitch and the compass calibration only).
2. The geomagnetic position fix (eq. 49, :func:`companion.nav.field.geomagnetic_fix`) from D and
   I averaged over windows, started from a prior = GPS position + an offset, against GPS; and the
   linearised prediction ``|G^-1 e|`` from the window's (D, I) error e and the model gradient G at
   the GPS position.
3. INS-only drift: strapdown dead reckoning of the log's IMU (specific force rotated with the
   logged attitude) from the first GPS fix, horizontal error against GPS.
4. The fused position: :class:`companion.nav.fusion.InsGeomagFusion` with Table 3's settings,
   fed once per window with the INS position and the fix.
5. The heading the controller would have commanded: :class:`companion.nav.mission.Mission`
   (Fc-MPC, start = first GPS fix, destination = last airborne GPS position) stepped once per
   window with the measured D, I and the INS position, open-loop (its commands are not flown);
   its course against the GPS course over ground of the window the command is for.

How the segments are chosen (from the data, printed with the table): the first 3D GPS fix; on
the ground before take-off, the time the measured D steps by more than 5 degrees (the flight
controller starting to apply its declination); take-off = the first of three consecutive GPS
fixes with ground speed > 1 m/s or altitude > 1.5 m above the median of the first 10 s of
fixes; crash = the first attitude sample after take-off tilted more than 60 degrees; the
airborne span ends ``--crash-guard-s`` (10 s) before a crash, or at the last airborne-looking
fix. Within the airborne span, "hover" is tilt < 10 deg and GPS speed < 1 m/s.

Modules: :mod:`fcmpc.replay.logdata` (reading), :mod:`fcmpc.replay.models` (date, field model),
:mod:`fcmpc.replay.segments` (segmentation), :mod:`fcmpc.replay.evaluate` with :mod:`fcmpc.replay.ins` and
:mod:`fcmpc.replay.heading` (the evaluation), :mod:`fcmpc.replay.records` (results), :mod:`fcmpc.replay.report`
(the words), :mod:`fcmpc.replay.plots`, :mod:`fcmpc.replay.outputs`, :mod:`fcmpc.replay.cli` (``fcmpc-replay``).
``companion/`` never imports this package.
"""
from __future__ import annotations

from fcmpc.replay.logdata import LogData
from fcmpc.replay.reading import read_boots
from fcmpc.replay.logeval import LogEvaluation, evaluate, evaluate_log
from fcmpc.replay.models import LogDate, log_date, select_model
from fcmpc.replay.outputs import summary_dict, write_outputs
from fcmpc.replay.records import ReplayEvaluation
from fcmpc.replay.report import format_report
from fcmpc.replay.segments import Segments, find_segments

__all__ = [
    "LogData",
    "Segments",
    "ReplayEvaluation",
    "LogEvaluation",
    "LogDate",
    "read_boots",
    "evaluate_log",
    "find_segments",
    "select_model",
    "log_date",
    "evaluate",
    "format_report",
    "summary_dict",
    "write_outputs",
]
