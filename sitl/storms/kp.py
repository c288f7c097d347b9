"""GFZ Kp reader: three-hourly Kp and ap, and the daily Ap, one row per UTC day.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from sitl.storms.common import FloatArray, StormDataError
from sitl.storms.published import IndexSeries

__all__ = ["KpRecord", "read_gfz_kp"]

@dataclass(frozen=True, eq=False)
class KpRecord:
    """GFZ Kp, one row per UTC day.

    ``day_s``: POSIX seconds of 00:00 UTC of each day; ``kp``: (days, 8) three-hourly Kp
    (thirds as decimals: 5.333 is 5+), NaN for -1; ``ap``: (days, 8); ``ap_daily``: Ap.
    """

    day_s: FloatArray
    kp: FloatArray
    ap: FloatArray
    ap_daily: FloatArray
    source: Path

    def series(self) -> IndexSeries:
        """The definitive Kp as 3-hour intervals (:class:`~sitl.storms.published.IndexSeries`)."""
        starts = (self.day_s[:, None] + 10800.0 * np.arange(8)[None, :]).ravel()
        return IndexSeries("Kp", starts, 10800.0, self.kp.ravel())

    def kp_at(self, time_s: ArrayLike) -> FloatArray:
        """The definitive Kp of the 3-hour interval containing each POSIX time (NaN outside the
        file): the truth, not what a feed has at that time (:mod:`sitl.storms.published`)."""
        t = np.asarray(time_s, dtype=np.float64)
        day = np.searchsorted(self.day_s, t, side="right") - 1
        offset = t - self.day_s[np.clip(day, 0, None)]
        ok = (day >= 0) & (offset < 86400.0)
        out = np.full(t.shape, np.nan)
        out[ok] = self.kp[day[ok], (offset[ok] // 10800.0).astype(np.int64)]
        return out


def read_gfz_kp(path: str | os.PathLike[str]) -> KpRecord:
    """Read the GFZ ``Kp_ap_Ap_SN_F107`` text file (``#`` header, 28 blank-separated fields a day).

    Fields: YYYY MM DD days days_m Bsr dB Kp1..Kp8 ap1..ap8 Ap SN F10.7obs F10.7adj D.
    Duplicate days (the excerpt repeats 2024-05-06) must be identical and are kept once.

    Raises:
        StormDataError: a row with the wrong number of fields or unparsable numbers, a
            duplicate day with different values, or no rows.
    """
    path = Path(path)
    rows: dict[np.datetime64, tuple[list[float], list[float], float, int]] = {}
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    for line_no, line in enumerate(lines, start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 28:
            raise StormDataError(path, line_no, f"expected 28 fields, got {len(parts)} (truncated?): {line!r}")
        try:
            day = np.datetime64(f"{int(parts[0]):04d}-{int(parts[1]):02d}-{int(parts[2]):02d}", "D")
            kp = [float(v) for v in parts[7:15]]
            ap = [float(v) for v in parts[15:23]]
            ap_daily = float(parts[23])
        except ValueError:
            raise StormDataError(path, line_no, f"cannot parse numbers in {line!r}") from None
        if day in rows and rows[day][:3] != (kp, ap, ap_daily):
            raise StormDataError(path, line_no, f"day {day} repeated with different values (first at line {rows[day][3]})")
        rows.setdefault(day, (kp, ap, ap_daily, line_no))
    if not rows:
        raise StormDataError(path, len(lines), "no data rows")
    days = sorted(rows)
    kp_arr = np.asarray([rows[d][0] for d in days])
    ap_arr = np.asarray([rows[d][1] for d in days])
    apd = np.asarray([rows[d][2] for d in days])
    kp_arr[kp_arr < 0] = np.nan
    ap_arr[ap_arr < 0] = np.nan
    apd[apd < 0] = np.nan
    day_s = np.asarray(days, dtype="datetime64[s]").astype(np.int64).astype(np.float64)
    return KpRecord(day_s=day_s, kp=kp_arr, ap=ap_arr, ap_daily=apd, source=path)
