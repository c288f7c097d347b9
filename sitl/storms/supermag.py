"""SuperMAG ASCII download (one file, all stations): 1-minute changes with the baseline removed.

Layout: a free-text header (with the acknowledgement SuperMAG requires, kept as
:attr:`SupermagRecord.acknowledgement`) ending in a line of ``=``; then for each minute a time
line ``yyyy mm dd HH MM SS ...`` and one tab-separated line per station: IAGA code, magnetic local
time, magnetic colatitude, declination (deg), solar zenith angle, N E Z in local magnetic axes,
N E Z in geographic axes (nT). The geographic columns are used. The file has no station positions:
they come from the event table (``coords``).
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sitl.storms.common import FloatArray, StormDataError

__all__ = ["SupermagRecord", "read_supermag"]

_TIME_RE = re.compile(r"^(\d{4})\s+(\d{2})\s+(\d{2})\s+(\d{2})\s+(\d{2})\s+(\d{2})(\s|$)")


@dataclass(frozen=True, eq=False)
class SupermagRecord:
    """``time_s`` (T,) POSIX UTC; per station code (upper case) arrays (T,) of the declination
    ``decl_deg``, the magnetic-axes ``nez_mag`` and geographic-axes ``nez_geo`` (T, 3) in nT, NaN where
    the station has no line that minute; ``acknowledgement``: the header's required text."""

    time_s: FloatArray
    decl_deg: dict[str, FloatArray]
    nez_mag: dict[str, FloatArray]
    nez_geo: dict[str, FloatArray]
    acknowledgement: str
    source: Path


def read_supermag(path: str | os.PathLike[str]) -> SupermagRecord:
    """Read a SuperMAG ASCII file.

    Raises:
        StormDataError: no ``====`` separator, a station line before any time line, a station line
            of other than 11 fields or with unparsable numbers, times not increasing (line named).
    """
    path = Path(path)
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    try:
        body = next(i for i, line in enumerate(lines) if line.startswith("====")) + 1
    except StopIteration:
        raise StormDataError(path, None, "no '====' line ending the header") from None
    header = "\n".join(lines[:body - 1])
    ack = re.search(r"acknowledge[^\n]*\n(.*?)\n\s*\n?\s*\*{5,}", header, re.S | re.I)
    times: list[float] = []
    rows: dict[str, dict[int, list[float]]] = {}
    for line_no, line in enumerate(lines[body:], start=body + 1):
        if not line.strip():
            continue
        match = _TIME_RE.match(line)
        if match:
            y, mo, d, h, mi, s = (int(g) for g in match.groups()[:6])
            stamp = float(np.datetime64(f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}:{mi:02d}:{s:02d}", "s").astype(np.int64))
            if times and stamp <= times[-1]:
                raise StormDataError(path, line_no, "time does not increase")
            times.append(stamp)
            continue
        if not times:
            raise StormDataError(path, line_no, "station line before the first time line")
        parts = line.split("\t")
        if len(parts) != 11:
            raise StormDataError(path, line_no, f"expected 11 tab-separated fields, got {len(parts)}: {line!r}")
        try:
            values = [float(v) for v in parts[1:]]
        except ValueError:
            raise StormDataError(path, line_no, f"cannot parse the numbers of {line!r}") from None
        rows.setdefault(parts[0].strip().upper(), {})[len(times) - 1] = values
    if not times:
        raise StormDataError(path, len(lines), "no data after the header")
    count = len(times)
    decl, mag, geo = {}, {}, {}
    for code, by_minute in rows.items():
        table = np.full((count, 10), np.nan)
        for k, values in by_minute.items():
            table[k] = values
        decl[code], mag[code], geo[code] = table[:, 2], table[:, 4:7], table[:, 7:10]
    return SupermagRecord(np.asarray(times), decl, mag, geo, " ".join(ack.group(1).split()) if ack else "", path)
