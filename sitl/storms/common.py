"""Shared pieces of the storm modules: POSIX-UTC time helpers, the data folder, the error type,
and the storm windows of 10 May 2024 (quiet baseline, long and short storm, sudden commencement).

Times are POSIX seconds, UTC, float64 (``time_s``) throughout :mod:`sitl.storms`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["ACKNOWLEDGEMENT", "DEFAULT_STATIONS", "FloatArray", "KP_FILE", "LONG_STORM", "OMNI_FILE", "QUIET_BASELINE", "SHORT_STORM",
           "SUDDEN_COMMENCEMENT_S", "StormDataError", "StormWindow", "default_data_dir", "utc_s"]

FloatArray = NDArray[np.float64]

ACKNOWLEDGEMENT = (
    "Data: INTERMAGNET; observatories KAK (JMA), GUA, FRD (USGS), CTA, CNB (Geoscience Australia)"
)
DEFAULT_STATIONS: tuple[str, ...] = ("kak", "gua", "cta", "cnb", "frd")


def utc_s(iso: str | np.datetime64) -> float:
    """POSIX seconds (UTC, float) of an ISO-8601 time such as ``"2024-05-10T17:07"``.

    >>> utc_s("1970-01-01T00:01")
    60.0
    """
    text = str(iso).rstrip("Z")
    return float(np.datetime64(text, "ms").astype(np.int64)) / 1000.0


def _iso(time_s: float) -> str:
    """ISO-8601 UTC text of POSIX seconds, to the second (for messages and titles)."""
    return str(np.datetime64(int(round(time_s)), "s")) + "Z"


def default_data_dir() -> Path:
    """The read-only real data folder: ``$FCMPC_DATA_DIR`` or ``<project>/../shared/data``."""
    env = os.environ.get("FCMPC_DATA_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2].parent / "shared" / "data"


class StormDataError(ValueError):
    """A data file is malformed or truncated; the message names the file and the line."""

    def __init__(self, path: Path | str, line_no: int | None, message: str) -> None:
        where = f"{path}:{line_no}" if line_no is not None else f"{path}"
        super().__init__(f"{where}: {message}")
        self.path = Path(path)
        self.line_no = line_no


# --------------------------------------------------------------------------------------
# Storm windows and key times
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StormWindow:
    """A storm-time interval ``[start_s, end_s]`` in POSIX UTC seconds."""

    name: str
    start_s: float
    end_s: float

    def __post_init__(self) -> None:
        if not self.end_s > self.start_s:
            raise ValueError(f"storm window {self.name!r}: end {self.end_s} <= start {self.start_s}")

    @property
    def duration_s(self) -> float:
        """Length of the window in seconds."""
        return self.end_s - self.start_s

    def __str__(self) -> str:
        return f"{self.name}: {_iso(self.start_s)} .. {_iso(self.end_s)} ({self.duration_s / 60.0:.0f} min)"


#: Storm sudden commencement seen at all five stations (+53..+56 nT in H within 2 min).
SUDDEN_COMMENCEMENT_S: float = utc_s("2024-05-10T17:07")

#: Quiet baseline interval, half-open [start, end): 2024-05-10 12:00-17:00 UTC (see module doc).
QUIET_BASELINE = StormWindow("quiet baseline", utc_s("2024-05-10T12:00"), utc_s("2024-05-10T17:00"))

#: Paper's long event, 02:00-08:00 Beijing time 11 May 2024 = 18:00-24:00 UTC 10 May (main phase).
#: The GFZ Kp excerpt under ``<data>/storms/`` (:func:`sitl.storms.read_gfz_kp`).
KP_FILE = "gfz_Kp_ap_Ap_SN_F107_2024-04-21_to_2024-06-30_excerpt.txt"
#: The OMNI 1-minute AE and SYM-H excerpt under ``<data>/storms/`` (:func:`sitl.storms.read_omni_symh`).
OMNI_FILE = "omni_hro2_1min_20240509-13_symh_ae.csv"

LONG_STORM = StormWindow("long storm", utc_s("2024-05-10T18:00"), utc_s("2024-05-11T00:00"))

#: Stand-in for the paper's short event (6 May 2024 13:13-14:46 Beijing time, 93 min, no data
#: here): the 93-minute window of largest mean |dH/dt| averaged over the five stations that
#: includes or follows the 17:07 sudden commencement, searched up to the end of 10 May UTC (the
#: same window wins when the search runs to the end of the data, 11 May 23:59). Computed by
#: :func:`sharpest_window` on the real data; a test recomputes it and checks this constant.
#: It lies inside :data:`LONG_STORM` (KAK alone gives 22:01-23:34 UTC).
SHORT_STORM = StormWindow("short storm", utc_s("2024-05-10T21:41"), utc_s("2024-05-10T23:14"))
