"""Records of a simulator run: the truth CSV the evaluation scripts read, and a MAVLink .tlog.

Truth CSV (``truth.csv``), one row per ``--log-rate`` period of simulated time:

=================  ====================================================================
column             meaning
=================  ====================================================================
time_s             simulated time since the simulator started (= mission elapsed time), s
lat_deg, lon_deg   true position (WGS84)
course_deg         true course over ground, from north clockwise (= yaw of the boat)
speed_mps          true speed over ground
vn_mps, ve_mps     true velocity north, east
roll_deg, pitch_deg true attitude (wave motion)
cmd_course_deg     course the autopilot is tracking (commanded), deg
cmd_speed_mps      speed the autopilot is tracking (commanded), m/s
mode, armed        autopilot mode name, 1 if armed
fc_lat_deg, fc_lon_deg  flight controller's solution (what GLOBAL_POSITION_INT reports)
fc_err_e_m, fc_err_n_m  its error east/north, m (0 while GPS-aided)
gps_fix            1 while GPS_RAW_INT has a 3D fix
field_n_nt, field_e_nt, field_d_nt  true field (WMM + disturbance) NED at the true position, nT
dist_n_nt, dist_e_nt, dist_d_nt     storm disturbance part of it, nT
decl_deg, incl_deg true declination / inclination of the true field
distance_m         path length flown
remaining_m        geodesic distance from the true position to the scenario destination (Vincenty, 0.1 mm)
est_lat_deg, est_lon_deg  last position estimate the companion sent (MAV_CMD_EXTERNAL_POSITION_ESTIMATE), empty if none
faults             active faults, ``kind`` or ``kind=value``, separated by ``;``
boot_s             the autopilot's boot time (its ``time_boot_ms`` / 1000): ``time_s`` until an
                   ``fc_reboot`` fault restarts it at 0; what the companion's message time is
=================  ====================================================================

Tlog: the pymavlink .tlog format (what ``mavlogdump.py`` and MAVProxy read): per message an
8-byte big-endian timestamp in microseconds followed by the raw MAVLink frame. The
timestamp is **simulated** UNIX time (scenario ``start_utc`` + simulated time), so a replay
sees the simulated clock. Both directions are recorded.
"""
from __future__ import annotations

import csv
import math
import struct
from pathlib import Path

__all__ = ["TRUTH_COLUMNS", "TruthLog", "TlogWriter", "read_truth_csv"]

TRUTH_COLUMNS = (
    "time_s", "lat_deg", "lon_deg", "course_deg", "speed_mps", "vn_mps", "ve_mps", "roll_deg", "pitch_deg",
    "cmd_course_deg", "cmd_speed_mps", "mode", "armed", "fc_lat_deg", "fc_lon_deg", "fc_err_e_m", "fc_err_n_m",
    "gps_fix", "field_n_nt", "field_e_nt", "field_d_nt", "dist_n_nt", "dist_e_nt", "dist_d_nt",
    "decl_deg", "incl_deg", "distance_m", "remaining_m", "est_lat_deg", "est_lon_deg", "faults", "boot_s",
)

# printf-style formats per column (default %.3f): ``%`` formats a float as str.format's "{:.3f}"
# does, at about half the cost
_FORMATS = {
    "time_s": "%.3f", "boot_s": "%.3f", "lat_deg": "%.8f", "lon_deg": "%.8f", "fc_lat_deg": "%.8f", "fc_lon_deg": "%.8f",
    "est_lat_deg": "%.8f", "est_lon_deg": "%.8f", "course_deg": "%.4f", "cmd_course_deg": "%.4f",
    "decl_deg": "%.5f", "incl_deg": "%.5f", "roll_deg": "%.3f", "pitch_deg": "%.3f",
}
_COLUMN_FORMATS = tuple((name, _FORMATS.get(name, "%.3f")) for name in TRUTH_COLUMNS)


class TruthLog:
    """CSV writer of :data:`TRUTH_COLUMNS` rows (dicts); flushed on close.

    A cell is empty for a missing value or None, ``nan`` for a non-finite float, the column's
    format for a float, ``str`` of anything else."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "w", newline="", encoding="utf-8", buffering=1 << 16)
        self._writer = csv.writer(self._file)
        self._writer.writerow(TRUTH_COLUMNS)
        self.rows = 0

    def write(self, row: dict) -> None:
        cells = []
        cell = cells.append
        isfinite = math.isfinite
        for name, fmt in _COLUMN_FORMATS:   # one loop, no call per cell: a row is written every second
            value = row.get(name)
            if value is None:
                cell("")
            elif isinstance(value, float):
                cell(fmt % value if isfinite(value) else "nan")
            else:
                cell(str(value))
        self._writer.writerow(cells)
        self.rows += 1

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()


class TlogWriter:
    """pymavlink .tlog: ``>Q`` microseconds + frame, per message."""

    _stamp = struct.Struct(">Q")

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb", buffering=1 << 16)
        self.messages = 0

    def write(self, time_usec: int, frame: bytes) -> None:
        self._file.write(self._stamp.pack(time_usec) + frame)
        self.messages += 1

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()


def read_truth_csv(path: str | Path) -> dict[str, list]:
    """Columns of a truth CSV as lists (numbers as float, ``mode``/``faults`` as str)."""
    with open(path, newline="", encoding="utf-8") as handle:
        reader = csv.DictReader(handle)
        columns: dict[str, list] = {name: [] for name in reader.fieldnames or ()}
        for row in reader:
            for name, text in row.items():
                if name in ("mode", "faults"):
                    columns[name].append(text)
                else:
                    columns[name].append(float(text) if text not in ("", None) else math.nan)
    return columns
