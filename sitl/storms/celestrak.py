"""CelesTrak space-weather reader (``SW-All.txt``, format CssiSpaceWeather 1.2): the eight 3-hourly
Kp values of each UTC day (the file gives Kp x 10, thirds as 3, 7: 53 is 5+), observed lines only.

Lines between ``BEGIN OBSERVED`` and ``END OBSERVED``: ``yyyy mm dd BSRN ND Kp1..Kp8 Sum Ap1..Ap8 ...``
(https://celestrak.org/SpaceData/SpaceWx-format.php).
"""
from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from sitl.storms.common import StormDataError
from sitl.storms.published import IndexSeries

__all__ = ["CELESTRAK_FILE", "read_celestrak_kp"]

#: The CelesTrak file under the shared data folder.
CELESTRAK_FILE = ("indices", "celestrak_SW-All.txt")


def read_celestrak_kp(path: str | os.PathLike[str], start_s: float = -np.inf, end_s: float = np.inf) -> IndexSeries:
    """Kp (thirds as decimals: 5.333 is 5+) of the observed 3-hour intervals that overlap
    ``[start_s, end_s]`` (POSIX UTC). The file (25,000 lines) is parsed once per version
    (path, size, modification time).

    Raises:
        StormDataError: no observed block, a short or unparsable line (named), days out of order.
    """
    path = Path(path)
    stat = path.stat()
    starts, kp = _observed_kp(path, stat.st_size, stat.st_mtime_ns)
    keep = (starts + 10800.0 > start_s) & (starts <= end_s)
    if not keep.any():
        raise StormDataError(path, None, "no observed Kp in the requested span")
    return IndexSeries("Kp", starts[keep], 10800.0, kp[keep])


@lru_cache(maxsize=2)
def _observed_kp(path: Path, size: int, mtime_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Every observed 3-hour interval's start (POSIX s) and Kp in thirds (read-only arrays)."""
    starts: list[float] = []
    values: list[float] = []
    inside = False
    for line_no, line in enumerate(path.read_text(encoding="ascii", errors="replace").splitlines(), start=1):
        text = line.strip()
        if text == "BEGIN OBSERVED":
            inside = True
            continue
        if text == "END OBSERVED":
            break
        if not inside or not text:
            continue
        parts = text.split()
        if len(parts) < 13:
            raise StormDataError(path, line_no, f"expected date, BSRN, ND and eight Kp, got {text!r}")
        try:
            day = np.datetime64(f"{int(parts[0]):04d}-{int(parts[1]):02d}-{int(parts[2]):02d}", "s")
            kp = [int(v) / 10.0 for v in parts[5:13]]
        except ValueError:
            raise StormDataError(path, line_no, f"cannot parse the date or Kp in {text!r}") from None
        day_s = float(day.astype(np.int64))
        if starts and day_s <= starts[-1]:
            raise StormDataError(path, line_no, f"day {day} does not follow the previous one")
        starts.extend(day_s + 10800.0 * k for k in range(8))
        values.extend(kp)
    if not starts:
        raise StormDataError(path, None, "no observed Kp (no 'BEGIN OBSERVED' block?)")
    start_arr = np.asarray(starts)
    kp_arr = np.round(np.asarray(values) * 3.0) / 3.0   # 53 -> 5.333: the thirds the tenths stand for
    start_arr.flags.writeable = False
    kp_arr.flags.writeable = False
    return start_arr, kp_arr
