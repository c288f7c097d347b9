"""GEM 2008/2009 dB/dt challenge observation files (CCMC; Pulkkinen et al. 2013, Space Weather 11):
one station a file, 1-minute changes from a quiet baseline in geomagnetic (dipole) axes.

Layout: ``#`` header lines, a column-name line (``Year Month Day Hour Min Sec GeomagLat GeomagLon
B_NorthGeomag B_EastGeomag B_DownGeomag``), a units line (``[year] ...``), then one line a minute.
Fill values (the files write ``NaN``; the data README also names values above 9000 nT) are NaN. The files give the station only in geomagnetic coordinates:
its geographic position is the inverse dipole transform of the epoch (:mod:`sitl.storms.dipole`),
and the horizontal change is rotated from dipole to geographic axes by the dipole declination
there. Checked against the observatories' published positions (FRD, OTT, FUR, WNG, FRN, NEW) to
0.3 degrees (tests).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from sitl.storms.common import StormDataError
from sitl.storms.deviation import StationDeviation
from sitl.storms.dipole import dipole_declination_deg, geographic_from_geomagnetic, rotate_dipole_to_geographic

__all__ = ["GEM_FILL_ABOVE_NT", "GemRecord", "read_gem2008", "gem_deviation"]

GEM_FILL_ABOVE_NT = 9000.0   # the files' fill values are above this


class GemRecord:
    """One GEM observation file: ``time_s`` POSIX UTC, geomagnetic ``mlat_deg``/``mlon_deg``, and the
    change ``n_m``, ``e_m``, ``d`` (nT) in dipole axes, NaN at fill values."""

    def __init__(self, code: str, time_s: np.ndarray, mlat_deg: float, mlon_deg: float,
                 n_m: np.ndarray, e_m: np.ndarray, d: np.ndarray, source: Path) -> None:
        self.code, self.time_s, self.mlat_deg, self.mlon_deg = code, time_s, mlat_deg, mlon_deg
        self.n_m, self.e_m, self.d, self.source = n_m, e_m, d, source


def read_gem2008(path: str | os.PathLike[str]) -> GemRecord:
    """Read one GEM observation file; the station code is the file's stem, upper case.

    Raises:
        StormDataError: no column line, a line of other than 11 numbers, a station that moves, times
            not increasing, or no data (the message names the line).
    """
    path = Path(path)
    rows: list[list[float]] = []
    seen_columns = False
    for line_no, line in enumerate(path.read_text(encoding="ascii", errors="replace").splitlines(), start=1):
        text = line.strip()
        if not text or text.startswith("#") or text.startswith("["):
            continue
        if text.startswith("Year"):
            seen_columns = True
            continue
        if not seen_columns:
            raise StormDataError(path, line_no, "data before the 'Year Month Day ...' column line")
        parts = text.split()
        try:
            values = [float(v) for v in parts]
        except ValueError:
            raise StormDataError(path, line_no, f"cannot parse {text!r}") from None
        if len(values) != 11:
            raise StormDataError(path, line_no, f"expected 11 numbers, got {len(values)} (truncated?)")
        if rows and (values[6], values[7]) != (rows[0][6], rows[0][7]):
            raise StormDataError(path, line_no, "the station's geomagnetic coordinates change")
        rows.append(values)
    if not rows:
        raise StormDataError(path, None, "no data lines")
    data = np.asarray(rows)
    stamps = np.array([np.datetime64(f"{int(r[0]):04d}-{int(r[1]):02d}-{int(r[2]):02d}T{int(r[3]):02d}:{int(r[4]):02d}", "s")
                       + np.timedelta64(int(r[5]), "s") for r in rows])
    time_s = stamps.astype(np.int64).astype(np.float64)
    if (np.diff(time_s) <= 0.0).any():
        bad = int(np.flatnonzero(np.diff(time_s) <= 0.0)[0]) + 1
        raise StormDataError(path, None, f"time does not increase at data row {bad + 1}")
    change = data[:, 8:11].copy()
    change[np.abs(change) > GEM_FILL_ABOVE_NT] = np.nan
    return GemRecord(path.stem.upper(), time_s, float(data[0, 6]), float(data[0, 7]),
                     change[:, 0], change[:, 1], change[:, 2], path)


def gem_deviation(record: GemRecord, pole_deg: tuple[float, float]) -> StationDeviation:
    """The record in geographic axes at its geographic position, about the north dipole pole
    ``pole_deg`` (lat, lon) of the epoch. The files carry changes only: the baseline (``x0_nt`` ...) is NaN."""
    lat, lon = geographic_from_geomagnetic(record.mlat_deg, record.mlon_deg, pole_deg)
    dn, de = rotate_dipole_to_geographic(record.n_m, record.e_m, dipole_declination_deg(lat, lon, pole_deg))
    return StationDeviation(code=record.code, lat_deg=float(lat), lon_deg=float(lon), time_s=record.time_s,
                            dx_nt=dn, dy_nt=de, dz_nt=record.d, x0_nt=np.nan, y0_nt=np.nan, z0_nt=np.nan)
