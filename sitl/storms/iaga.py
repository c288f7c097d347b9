"""IAGA-2002 reader: one observatory's 1-minute X, Y, Z, F data (INTERMAGNET), and
:func:`load_stations`, which joins each station's daily files in time order.

Missing (99999.00) and not-recorded (88888.00) values become NaN; a malformed or truncated
file raises :class:`~sitl.storms.common.StormDataError` naming the file and the line.
"""
from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sitl.storms.common import DEFAULT_STATIONS, FloatArray, StormDataError, _iso, default_data_dir

__all__ = ["IagaRecord", "load_stations", "read_iaga2002"]

# IAGA-2002 missing (99999.00) and not-recorded (88888.00) markers.
_IAGA_MISSING = (99999.0, 88888.0)
_IAGA_SUFFIXES = (".min", ".txt")   # INTERMAGNET minute files; WDC Kyoto's conversions (JMA)


@dataclass(frozen=True, eq=False)
class IagaRecord:
    """One observatory's IAGA-2002 minute data.

    Attributes
        code: IAGA code, upper case (``"KAK"``).
        name: station name from the header.
        lat_deg: geodetic latitude, degrees north.
        lon_deg: longitude, degrees east in -180..180.
        lon_east_deg: longitude as in the file, degrees east in 0..360.
        elevation_m: elevation in metres (NaN when absent).
        reported: the reported components, e.g. ``"XYZF"`` (from the column header line).
        time_s: sample times, POSIX seconds UTC (float64); FRD's block means are stamped
            at ``:30`` s, the INTERMAGNET minute files at ``:00``.
        x_nt, y_nt, z_nt: geographic north, east, down components in nT (HDZ files are
            converted), NaN where the file has 99999.00 / 88888.00.
        f_nt: total intensity from the F column in nT (NaN when missing or not an F column).
        sources: the file(s) the record was read from.
        header: the header key/value pairs as read (keys lower case).
    """

    code: str
    name: str
    lat_deg: float
    lon_deg: float
    lon_east_deg: float
    elevation_m: float
    reported: str
    time_s: FloatArray
    x_nt: FloatArray
    y_nt: FloatArray
    z_nt: FloatArray
    f_nt: FloatArray
    sources: tuple[Path, ...]
    header: Mapping[str, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.time_s.size)

    @property
    def h_nt(self) -> FloatArray:
        """Horizontal intensity sqrt(X^2 + Y^2), nT."""
        return np.hypot(self.x_nt, self.y_nt)

    @property
    def decl_deg(self) -> FloatArray:
        """Declination atan2(Y, X), degrees east."""
        return np.degrees(np.arctan2(self.y_nt, self.x_nt))

    @property
    def incl_deg(self) -> FloatArray:
        """Inclination atan2(Z, H), degrees down."""
        return np.degrees(np.arctan2(self.z_nt, self.h_nt))


_HEADER_RE = re.compile(r"^\s*(?P<key>\S.*?)\s{2,}(?P<value>.*?)\s*\|\s*$")
_NUM = r"[-+]?\d+\.\d+"
_DATA_RE = re.compile(
    rf"^(?P<date>\d{{4}}-\d{{2}}-\d{{2}}) (?P<time>\d{{2}}:\d{{2}}:\d{{2}}\.\d{{3}})\s+(?P<doy>\d{{1,3}})"
    rf"\s+(?P<v1>{_NUM})\s+(?P<v2>{_NUM})\s+(?P<v3>{_NUM})\s+(?P<v4>{_NUM})\s*$"
)


def _header_float(path: Path, header: dict[str, tuple[int, str]], keys: Sequence[str], *, required: bool) -> float:
    for key in keys:
        if key in header:
            line_no, text = header[key]
            try:
                return float(text.split()[0])
            except (ValueError, IndexError):
                raise StormDataError(path, line_no, f"header {key!r} is not a number: {text!r}") from None
    if required:
        raise StormDataError(path, None, f"header has no {' / '.join(repr(k) for k in keys)} line")
    return math.nan


def read_iaga2002(path: str | os.PathLike[str]) -> IagaRecord:
    """Read one IAGA-2002 file (header block, ``|``-terminated comment lines, data header, data).

    Header lines are ``key  value  |`` (the key ends at two blanks); comment lines start
    with ``#`` (after optional blanks) and end with ``|``; the line starting ``DATE`` names
    the columns (``DATE TIME DOY KAKX KAKY KAKZ KAKF``); every following non-blank line must
    be ``YYYY-MM-DD HH:MM:SS.sss DOY`` and four decimal numbers. Components XYZ are kept,
    HDZ (D in minutes of arc, IAGA-2002) are converted to XYZ. 99999.00 and 88888.00
    become NaN.

    Raises:
        StormDataError: malformed header, missing data header line, malformed or truncated
            data line, day-of-year inconsistent with the date, time not increasing, or no
            data; the message is ``<file>:<line>: <what>``.
        FileNotFoundError: the file does not exist.
    """
    path = Path(path)
    header, columns, columns_line, times, values = _parse(path)

    code_entry = header.get("iaga code")
    code = (code_entry[1].split()[0] if code_entry and code_entry[1].split() else columns[3][:-1]).upper()
    letters = "".join(c[-1].upper() for c in columns[3:])
    reported_entry = header.get("reported") or header.get("reporting")
    if reported_entry is not None:
        stated = reported_entry[1].replace(" ", "").upper()
        if stated and stated != letters:
            raise StormDataError(
                path,
                reported_entry[0],
                f"header reports {stated!r} but the data header (line {columns_line}) has {letters!r}",
            )
    lat = _header_float(path, header, ["geodetic latitude"], required=True)
    lon_east = _header_float(path, header, ["geodetic longitude"], required=True) % 360.0
    elevation = _header_float(path, header, ["elevation"], required=False)
    name = header["station name"][1] if "station name" in header else code

    x, y, z, f = _components(path, columns_line, letters, values)
    time_s = np.asarray(times, dtype="datetime64[ms]").astype(np.int64).astype(np.float64) / 1000.0
    return IagaRecord(
        code=code,
        name=name,
        lat_deg=lat,
        lon_deg=lon_east - 360.0 if lon_east >= 180.0 else lon_east,
        lon_east_deg=lon_east,
        elevation_m=elevation,
        reported=letters,
        time_s=time_s,
        x_nt=np.ascontiguousarray(x),
        y_nt=np.ascontiguousarray(y),
        z_nt=np.ascontiguousarray(z),
        f_nt=np.ascontiguousarray(f),
        sources=(path,),
        header={k: v for k, (_, v) in header.items()},
    )


def _parse(path: Path) -> tuple[dict[str, tuple[int, str]], list[str], int, list[np.datetime64],
                                 list[tuple[float, float, float, float]]]:
    """The file's header (key -> (line, value)), its data columns and their line, and the data
    lines' times and four values, each line checked (:func:`read_iaga2002`'s errors)."""
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    header: dict[str, tuple[int, str]] = {}
    columns: list[str] | None = None
    columns_line = 0
    times: list[np.datetime64] = []
    values: list[tuple[float, float, float, float]] = []
    for line_no, line in enumerate(lines, start=1):
        if columns is None:
            stripped = line.strip()
            if not stripped:
                continue
            if stripped.startswith("DATE"):
                columns = stripped.rstrip("|").split()
                columns_line = line_no
                if columns[:3] != ["DATE", "TIME", "DOY"] or len(columns) != 7:
                    raise StormDataError(
                        path, line_no, f"data header must be 'DATE TIME DOY' and 4 components, got {stripped!r}"
                    )
                continue
            if not stripped.endswith("|"):
                if _DATA_RE.match(line):
                    raise StormDataError(path, line_no, "data line before the 'DATE TIME DOY' header line")
                raise StormDataError(path, line_no, f"header/comment line does not end with '|': {line!r}")
            if stripped.startswith("#"):
                continue
            match = _HEADER_RE.match(line)
            if match is None:
                raise StormDataError(path, line_no, f"cannot parse header line {line!r}")
            key = " ".join(match["key"].lower().split())
            header[key] = (line_no, match["value"])
            continue
        if not line.strip():
            continue
        stamp, row = _data_line(path, line_no, line, times[-1] if times else None)
        times.append(stamp)
        values.append(row)

    if columns is None:
        raise StormDataError(path, len(lines), "no 'DATE TIME DOY' data header line (truncated header?)")
    if not times:
        raise StormDataError(path, len(lines), "no data lines after the data header (truncated file?)")
    return header, columns, columns_line, times, values


def _data_line(path: Path, line_no: int, line: str, last: np.datetime64 | None
               ) -> tuple[np.datetime64, tuple[float, float, float, float]]:
    """One data line's time (ms) and four values, checked: the layout, the date, its day of year,
    and a time after ``last``."""
    match = _DATA_RE.match(line)
    if match is None:
        raise StormDataError(
            path,
            line_no,
            "malformed or truncated data line (expected 'YYYY-MM-DD HH:MM:SS.sss DOY' and 4 decimal "
            f"values): {line!r}",
        )
    try:
        stamp = np.datetime64(f"{match['date']}T{match['time']}", "ms")
    except ValueError:
        raise StormDataError(path, line_no, f"invalid date/time {match['date']} {match['time']}") from None
    day0 = stamp.astype("datetime64[D]")
    doy = int((day0 - day0.astype("datetime64[Y]")).astype(np.int64)) + 1
    if int(match["doy"]) != doy:
        raise StormDataError(path, line_no, f"day of year {match['doy']} does not match date {match['date']}")
    if last is not None and stamp <= last:
        raise StormDataError(path, line_no, f"time {match['date']} {match['time']} does not increase")
    return stamp, (float(match["v1"]), float(match["v2"]), float(match["v3"]), float(match["v4"]))


def _components(path: Path, columns_line: int, letters: str, values: list[tuple[float, float, float, float]]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """X, Y, Z and F (nT) from the data values in the reported layout (XYZ* kept, HDZ* with D in
    minutes of arc converted; F NaN unless reported); the missing-value markers become NaN."""
    data = np.asarray(values, dtype=np.float64)
    data[np.isin(data, _IAGA_MISSING)] = np.nan
    cols = {letter: data[:, i] for i, letter in enumerate(letters)}
    if set(letters[:3]) == set("XYZ"):
        x, y, z = cols["X"], cols["Y"], cols["Z"]
    elif set(letters[:3]) == set("HDZ"):
        d_rad = np.radians(cols["D"] / 60.0)
        x, y, z = cols["H"] * np.cos(d_rad), cols["H"] * np.sin(d_rad), cols["Z"]
    else:
        raise StormDataError(path, columns_line, f"unsupported component layout {letters!r} (need XYZ* or HDZ*)")
    f = cols["F"] if letters[3] == "F" else np.full(len(values), np.nan)
    return x, y, z, f

def _concat(records: Sequence[IagaRecord]) -> IagaRecord:
    """Join records of one station (files of consecutive days) in time order."""
    first = records[0]
    for rec in records[1:]:
        if rec.code != first.code or abs(rec.lat_deg - first.lat_deg) > 1e-3 or abs(rec.lon_deg - first.lon_deg) > 1e-3:
            raise StormDataError(
                rec.sources[0], None, f"station {rec.code} at ({rec.lat_deg}, {rec.lon_deg}) does not match "
                f"{first.code} at ({first.lat_deg}, {first.lon_deg}) in {first.sources[0]}"
            )
    ordered = sorted(records, key=lambda r: r.time_s[0])
    time_s = np.concatenate([r.time_s for r in ordered])
    bad = np.flatnonzero(np.diff(time_s) <= 0.0)
    if bad.size:
        raise StormDataError(
            ordered[0].sources[0], None, f"files of station {first.code} overlap in time at {_iso(time_s[bad[0] + 1])}"
        )
    return IagaRecord(
        code=first.code,
        name=first.name,
        lat_deg=first.lat_deg,
        lon_deg=first.lon_deg,
        lon_east_deg=first.lon_east_deg,
        elevation_m=first.elevation_m,
        reported=first.reported,
        time_s=time_s,
        x_nt=np.concatenate([r.x_nt for r in ordered]),
        y_nt=np.concatenate([r.y_nt for r in ordered]),
        z_nt=np.concatenate([r.z_nt for r in ordered]),
        f_nt=np.concatenate([r.f_nt for r in ordered]),
        sources=tuple(p for r in ordered for p in r.sources),
        header=first.header,
    )


def _intermagnet_dir(data_dir: Path) -> Path:
    for candidate in (data_dir / "storms" / "intermagnet", data_dir / "intermagnet"):
        if candidate.is_dir():
            return candidate
    return data_dir


def load_stations(
    data_dir: str | os.PathLike[str] | None = None,
    stations: Iterable[str] = DEFAULT_STATIONS,
) -> dict[str, IagaRecord]:
    """Read and join every ``<code>*.min`` (or ``.txt``) file of each station (10 and 11 May 2024 by default).

    Args:
        data_dir: the shared data root (``.../shared/data``), its ``storms`` folder or the
            ``intermagnet`` folder itself; default :func:`default_data_dir`.
        stations: IAGA codes, any case.

    Returns:
        ``{code_lower: IagaRecord}`` in the order given, each spanning all its files.

    Raises:
        FileNotFoundError: no file for a station. StormDataError: bad file or overlap.
    """
    folder = _intermagnet_dir(Path(data_dir) if data_dir is not None else default_data_dir())
    out: dict[str, IagaRecord] = {}
    for code in stations:
        code = code.lower()
        files = sorted(p for p in folder.iterdir() if p.suffix.lower() in _IAGA_SUFFIXES and p.name.lower().startswith(code))
        if not files:
            raise FileNotFoundError(f"no IAGA-2002 file '{code}*.min' or '.txt' for station {code.upper()} in {folder}")
        out[code] = _concat([read_iaga2002(p) for p in files])
    return out
