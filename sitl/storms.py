"""Real magnetic-storm data (May 2024 'Gannon' storm) and the storm disturbance field of the SITL.

The simulated vehicle sees ``WMM + storm disturbance`` (paper Section 4.2). This module
provides the disturbance half, built from INTERMAGNET 1-minute observatory data, and
readers for the indices that document the storm (OMNI SYM-H/AE, GFZ Kp).

Conventions (see :mod:`companion`)
    * Field vectors are geographic North-East-Down in nT: ``(dn, de, dd)`` = (dX, dY, dZ).
    * Times are **POSIX seconds, UTC, float64** (``time_s``), everywhere in this module:
      file time stamps, baselines, windows and queries. :func:`utc_s` converts an ISO
      string. Storm time is mapped onto mission time by :class:`StormTimeMap` and by the
      ``time_offset_s`` of :class:`StormDisturbance`.
    * Latitude/longitude in degrees; longitudes are accepted in either -180..180 or
      0..360 (IAGA-2002 files store 0..360 east).

Quiet baseline (:data:`QUIET_BASELINE`)
    A station's disturbance is its recorded field minus the **median of each component over
    2024-05-10 12:00-17:00 UTC**, the five hours before the storm sudden commencement
    (17:07 UTC). This interval is local night at the four western-Pacific stations (KAK,
    GUA, CTA, CNB: about 21-03 local time), where the solar-quiet (Sq) current system is
    weakest: there each component stays within 35 nT peak-to-peak and changes by less than
    10 nT in any 2 minutes (tested), against storm deviations of several hundred nT. Kp was
    3+ in 12-15 UTC (not a textbook quiet interval; no quiet day is in the files). The
    median is robust to short pulsations. FRD is in local morning then and its Y drifts by
    70 nT in the interval (Sq); ``StormDisturbance.from_records`` accepts a per-station
    window if that matters (FRD weighs about 1 % in the western Pacific).
    The diurnal Sq variation is **not** removed: the deviations contain the storm *and*
    the regular day-time Sq variation (tens of nT at mid latitudes). The secular variation
    over two days (< 0.1 nT) is negligible.

Spatial interpolation (:class:`StormDisturbance`)
    Inverse-distance weighting (Shepard, power 2) on the great-circle angle between the
    query point and the stations. With five stations (four in the western Pacific
    35S-36N, one in the eastern USA) no covariance model can be fitted, so a
    kriging/Gaussian-process fit would rest on an invented range parameter; IDW has none
    beyond the power. IDW reproduces each station exactly at its own location, is a convex
    combination (it never invents a disturbance larger than one observed), is smooth
    (power 2: differentiable everywhere, so the disturbance adds no kinks to the D/I
    gradients the MPC estimates; an exponential-covariance kriging would put a cusp at
    every station) and is fast. Its limits: flat spots (zero gradient) at the stations;
    far from every station it tends to a weighted mean of the stations; it ignores the
    latitude/local-time structure of the storm field, so it is meaningful only near the
    network (the paper's mission area 27-34N, 145-165E lies between KAK and GUA, which
    carry 83-95 % of the weight there). NED components of different stations are
    combined as they are, each in its own local frame, as gridded observatory products
    do (the meridians of KAK and GUA converge by about 2 degrees, so a few percent of dX
    leaks into dY).

Data acknowledgement: INTERMAGNET; observatories KAK (JMA), GUA, FRD (USGS), CTA, CNB
(Geoscience Australia). Any figure showing these data must carry
:data:`ACKNOWLEDGEMENT` (the plot function does).
"""
from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:  # matplotlib is imported lazily by plot_disturbance only
    from matplotlib.figure import Figure

__all__ = [
    "ACKNOWLEDGEMENT",
    "DEFAULT_STATIONS",
    "LONG_STORM",
    "QUIET_BASELINE",
    "SHORT_STORM",
    "SUDDEN_COMMENCEMENT_S",
    "IagaRecord",
    "KpRecord",
    "OmniIndices",
    "StationDeviation",
    "StormDataError",
    "StormDisturbance",
    "StormTimeMap",
    "StormWindow",
    "default_data_dir",
    "di_shift_deg",
    "eq64_dbh_nt",
    "load_stations",
    "plot_disturbance",
    "quiet_baseline",
    "read_gfz_kp",
    "read_iaga2002",
    "read_omni_symh",
    "sharpest_window",
    "station_deviation",
    "utc_s",
]

FloatArray = NDArray[np.float64]

ACKNOWLEDGEMENT = (
    "Data: INTERMAGNET; observatories KAK (JMA), GUA, FRD (USGS), CTA, CNB (Geoscience Australia)"
)
DEFAULT_STATIONS: tuple[str, ...] = ("kak", "gua", "cta", "cnb", "frd")

# IAGA-2002 missing (99999.00) and not-recorded (88888.00) markers.
_IAGA_MISSING = (99999.0, 88888.0)
# OMNI fill values of the AE / SYM-H columns (and of the other columns of the CSV).
_OMNI_FILL = (9999.99, 99999.9, 99999.0, 999999.0)
_EXACT_RAD = 1e-10  # query within ~0.6 mm of a station: take the station value exactly


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
    return Path(__file__).resolve().parents[1].parent / "shared" / "data"


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
LONG_STORM = StormWindow("long storm", utc_s("2024-05-10T18:00"), utc_s("2024-05-11T00:00"))

#: Stand-in for the paper's short event (6 May 2024 13:13-14:46 Beijing time, 93 min, no data
#: here): the 93-minute window of largest mean |dH/dt| averaged over the five stations that
#: includes or follows the 17:07 sudden commencement, searched up to the end of 10 May UTC (the
#: same window wins when the search runs to the end of the data, 11 May 23:59). Computed by
#: :func:`sharpest_window` on the real data; a test recomputes it and checks this constant.
#: It lies inside :data:`LONG_STORM` (KAK alone gives 22:01-23:34 UTC).
SHORT_STORM = StormWindow("short storm", utc_s("2024-05-10T21:41"), utc_s("2024-05-10T23:14"))


# --------------------------------------------------------------------------------------
# IAGA-2002 reader
# --------------------------------------------------------------------------------------


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
        if times and stamp <= times[-1]:
            raise StormDataError(path, line_no, f"time {match['date']} {match['time']} does not increase")
        times.append(stamp)
        values.append((float(match["v1"]), float(match["v2"]), float(match["v3"]), float(match["v4"])))

    if columns is None:
        raise StormDataError(path, len(lines), "no 'DATE TIME DOY' data header line (truncated header?)")
    if not times:
        raise StormDataError(path, len(lines), "no data lines after the data header (truncated file?)")

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
    f = cols["F"] if letters[3] == "F" else np.full(len(times), np.nan)
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
    """Read and join every ``<code>*.min`` file of each station (10 and 11 May 2024).

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
        files = sorted(p for p in folder.glob("*.min") if p.name.lower().startswith(code))
        if not files:
            raise FileNotFoundError(f"no IAGA-2002 file '{code}*.min' for station {code.upper()} in {folder}")
        out[code] = _concat([read_iaga2002(p) for p in files])
    return out


# --------------------------------------------------------------------------------------
# OMNI and Kp readers
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class OmniIndices:
    """OMNI 1-minute AE and SYM-H indices.

    ``time_s`` POSIX seconds UTC as stamped in the file (the file header says the stamps
    are the beginning of each averaging bin); ``ae_nt``, ``symh_nt`` in nT, NaN for fill
    values (9999.99 / 99999.9 / 99999).
    """

    time_s: FloatArray
    ae_nt: FloatArray
    symh_nt: FloatArray
    source: Path


def read_omni_symh(path: str | os.PathLike[str]) -> OmniIndices:
    """Read the CDAWeb OMNI CSV: ``#`` comment lines, one column header line, then rows.

    The columns are found by name in the header line (``EPOCH_TIME...``, ``...AE...``,
    ``SYM/H...``); times are ISO ``2024-05-09T06:00:00.000Z``.

    Raises:
        StormDataError: no header line, missing columns, a malformed or truncated row
            (wrong number of fields, unparsable time or number), times not increasing.
    """
    path = Path(path)
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    cols: list[str] | None = None
    i_ae = i_sym = -1
    times: list[np.datetime64] = []
    ae: list[float] = []
    sym: list[float] = []
    for line_no, line in enumerate(lines, start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        if cols is None:
            if not fields[0].upper().startswith("EPOCH"):
                raise StormDataError(path, line_no, f"expected the 'EPOCH_TIME,...' column header, got {line!r}")
            cols = [f.upper() for f in fields]
            i_ae = next((i for i, c in enumerate(cols) if re.search(r"(^|[^A-Z])AE([^A-Z]|$)", c)), -1)
            i_sym = next((i for i, c in enumerate(cols) if c.startswith("SYM/H") or c.startswith("SYM_H")), -1)
            if i_ae < 0 or i_sym < 0:
                raise StormDataError(path, line_no, f"no AE and SYM/H columns in {line!r}")
            continue
        if len(fields) != len(cols):
            raise StormDataError(
                path, line_no, f"expected {len(cols)} comma-separated fields, got {len(fields)} (truncated?): {line!r}"
            )
        try:
            stamp = np.datetime64(fields[0].rstrip("Z"), "ms")
            a, s = float(fields[i_ae]), float(fields[i_sym])
        except ValueError:
            raise StormDataError(path, line_no, f"cannot parse time/AE/SYM-H in {line!r}") from None
        if times and stamp <= times[-1]:
            raise StormDataError(path, line_no, f"time {fields[0]} does not increase")
        times.append(stamp)
        ae.append(a)
        sym.append(s)
    if cols is None or not times:
        raise StormDataError(path, len(lines), "no data rows (truncated file?)")
    ae_arr = np.asarray(ae)
    sym_arr = np.asarray(sym)
    for arr in (ae_arr, sym_arr):
        arr[np.isclose(arr[:, None], np.asarray(_OMNI_FILL)[None, :], rtol=0.0, atol=1e-6).any(axis=1)] = np.nan
    time_s = np.asarray(times, dtype="datetime64[ms]").astype(np.int64).astype(np.float64) / 1000.0
    return OmniIndices(time_s=time_s, ae_nt=ae_arr, symh_nt=sym_arr, source=path)


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

    def kp_at(self, time_s: ArrayLike) -> FloatArray:
        """Kp of the 3-hour interval containing each POSIX time (NaN outside the file)."""
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


# --------------------------------------------------------------------------------------
# Baseline and station deviations
# --------------------------------------------------------------------------------------


def quiet_baseline(record: IagaRecord, window: StormWindow = QUIET_BASELINE) -> tuple[float, float, float]:
    """Median (X, Y, Z) in nT of a station over the half-open quiet window [start, end).

    Raises:
        ValueError: no valid sample of some component in the window.
    """
    inside = (record.time_s >= window.start_s) & (record.time_s < window.end_s)
    base = []
    for comp, values in (("X", record.x_nt), ("Y", record.y_nt), ("Z", record.z_nt)):
        sel = values[inside]
        if not np.isfinite(sel).any():
            raise ValueError(f"station {record.code}: no valid {comp} sample in the baseline window {window}")
        base.append(float(np.nanmedian(sel)))
    return base[0], base[1], base[2]


@dataclass(frozen=True, eq=False)
class StationDeviation:
    """A station's deviation from its quiet baseline: ``d* = recorded - baseline`` in nT (NED).

    ``time_s`` POSIX UTC; ``dx_nt, dy_nt, dz_nt`` may hold NaN where the file had gaps;
    ``x0_nt, y0_nt, z0_nt`` the baseline; ``lon_deg`` in -180..180.
    """

    code: str
    lat_deg: float
    lon_deg: float
    time_s: FloatArray
    dx_nt: FloatArray
    dy_nt: FloatArray
    dz_nt: FloatArray
    x0_nt: float
    y0_nt: float
    z0_nt: float

    @property
    def dh_nt(self) -> FloatArray:
        """Change of horizontal intensity H - H0 in nT (not eq. 64; see :func:`eq64_dbh_nt`)."""
        return np.hypot(self.x0_nt + self.dx_nt, self.y0_nt + self.dy_nt) - math.hypot(self.x0_nt, self.y0_nt)

    @property
    def dd_deg(self) -> FloatArray:
        """Change of declination from the baseline, degrees (positive east)."""
        d = np.arctan2(self.y0_nt + self.dy_nt, self.x0_nt + self.dx_nt) - math.atan2(self.y0_nt, self.x0_nt)
        return np.degrees((d + np.pi) % (2.0 * np.pi) - np.pi)


def station_deviation(record: IagaRecord, window: StormWindow = QUIET_BASELINE) -> StationDeviation:
    """The record minus its :func:`quiet_baseline` (gaps stay NaN)."""
    x0, y0, z0 = quiet_baseline(record, window)
    return StationDeviation(
        code=record.code,
        lat_deg=record.lat_deg,
        lon_deg=record.lon_deg,
        time_s=record.time_s,
        dx_nt=record.x_nt - x0,
        dy_nt=record.y_nt - y0,
        dz_nt=record.z_nt - z0,
        x0_nt=x0,
        y0_nt=y0,
        z0_nt=z0,
    )


# --------------------------------------------------------------------------------------
# Disturbance field
# --------------------------------------------------------------------------------------


def eq64_dbh_nt(dx_nt: ArrayLike, dy_nt: ArrayLike) -> FloatArray:
    """Paper eq. 64: ``dB_H = sign(dB_x) * sqrt(dB_x^2 + dB_y^2)`` in nT.

    The paper's ``|dB_x| / dB_x`` is undefined at ``dB_x = 0``; there the sign is taken +.
    """
    dx = np.asarray(dx_nt, dtype=np.float64)
    dy = np.asarray(dy_nt, dtype=np.float64)
    return np.where(dx < 0.0, -1.0, 1.0) * np.hypot(dx, dy)


def di_shift_deg(
    x_nt: ArrayLike, y_nt: ArrayLike, z_nt: ArrayLike, dn_nt: ArrayLike, de_nt: ArrayLike, dd_nt: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Exact change of (D, I) in degrees when ``(dn, de, dd)`` is added to the field ``(x, y, z)``.

    ``dD = D(B + dB) - D(B)`` wrapped to [-180, 180), ``dI = I(B + dB) - I(B)``, with
    ``D = atan2(Y, X)`` (east +) and ``I = atan2(Z, H)`` (down +) as in :mod:`companion`.
    For small disturbances ``dD ~ (X dY - Y dX) / H^2`` and ``dI ~ (H dZ - Z dH) / F^2`` rad.
    """
    x, y, z = (np.asarray(v, dtype=np.float64) for v in (x_nt, y_nt, z_nt))
    x1, y1, z1 = x + np.asarray(dn_nt), y + np.asarray(de_nt), z + np.asarray(dd_nt)
    d = np.arctan2(y1, x1) - np.arctan2(y, x)
    d = (d + np.pi) % (2.0 * np.pi) - np.pi
    i = np.arctan2(z1, np.hypot(x1, y1)) - np.arctan2(z, np.hypot(x, y))
    return np.degrees(d), np.degrees(i)


def _fill_gaps(time_s: FloatArray, values: FloatArray, code: str, comp: str) -> FloatArray:
    ok = np.isfinite(values)
    if not ok.any():
        raise ValueError(f"station {code}: component {comp} has no valid sample")
    if ok.all():
        return values
    return np.interp(time_s, time_s[ok], values[ok])


class _TimeGroup:
    """Stations sharing one time grid: the interpolation index is found once for all of them.

    The table holds value and slope-to-next-sample, ``(2, m * 3, T)``, station-major rows
    ``(s0 dn, s0 de, s0 dd, s1 dn, ...)``, so each row is one contiguous time series.
    """

    def __init__(self, time_s: FloatArray, station_index: list[int], values: FloatArray) -> None:
        self.time_s = time_s  # (T,)
        self.station_index = np.asarray(station_index)  # (m,)
        rows = values.reshape(time_s.size, -1).T  # values: (T, m, 3) -> (m * 3, T)
        table = np.zeros((2,) + rows.shape)
        table[0] = rows
        table[1, :, :-1] = np.diff(rows, axis=1)
        self.table = table
        dt = np.diff(time_s)
        self.step = float(dt[0]) if dt.size and np.all(dt == dt[0]) else None  # uniform grid: no search
        self.inv_dt = np.append(1.0 / dt, 0.0) if dt.size else np.zeros(1)

    def interp(self, t: FloatArray) -> FloatArray:
        """Values at times t, shape ``(m, 3) + t.shape`` (edge values held outside the grid)."""
        grid = self.time_s
        flat = t.reshape(-1)
        last = grid.size - 1
        if self.step is not None:
            pos = np.floor((flat - grid[0]) / self.step)
            i = np.clip(np.nan_to_num(pos, nan=0.0), 0, last).astype(np.intp)
        else:
            i = np.clip(np.searchsorted(grid, flat, side="right") - 1, 0, last)
        frac = np.clip((flat - grid[i]) * self.inv_dt[i], 0.0, 1.0)  # NaN time stays NaN
        g = np.take(self.table, i, axis=2)  # (2, m * 3, N)
        out = g[0] + g[1] * frac
        return out.reshape((self.station_index.size, 3) + t.shape)


class StormDisturbance:
    """Storm disturbance field ``(dn, de, dd)`` in nT from observatory deviations.

    ``disturbance(lat, lon, t) = scale * IDW_stations(deviation_station(t + time_offset_s))``

    Time: linear interpolation between each station's samples (1 minute; FRD stamped at
    :30 s); gaps (NaN) in a station's record are bridged linearly in time at construction.
    Space: inverse-distance weighting, power ``power`` (default 2), on the great-circle
    angle; exact at each station's location (see the module docstring for the choice).

    Args:
        stations: station deviations (:func:`station_deviation`), distinct locations.
        scale: factor applied to the disturbance (1 = as recorded). ``sitl.world.magnetic.TruthField``
            has its own ``storm_scale``; set one of the two, not both.
        time_offset_s: added to the query time to get storm time (POSIX UTC):
            ``storm_time = time_s + time_offset_s``. With :class:`StormTimeMap` doing the
            mapping, leave it 0.
        power: IDW exponent (> 1 keeps the field smooth at the stations).
        outside: storm times outside :attr:`time_range_s`: ``"raise"`` (ValueError),
            ``"hold"`` (first/last values) or ``"zero"`` (no disturbance).
    """

    def __init__(
        self,
        stations: Sequence[StationDeviation],
        *,
        scale: float = 1.0,
        time_offset_s: float = 0.0,
        power: float = 2.0,
        outside: Literal["raise", "hold", "zero"] = "raise",
    ) -> None:
        if not stations:
            raise ValueError("StormDisturbance needs at least one station")
        if outside not in ("raise", "hold", "zero"):
            raise ValueError(f"outside must be 'raise', 'hold' or 'zero', not {outside!r}")
        if not power > 0.0:
            raise ValueError(f"IDW power must be > 0, got {power}")
        self.stations: tuple[StationDeviation, ...] = tuple(stations)
        self.scale = float(scale)
        self.time_offset_s = float(time_offset_s)
        self.power = float(power)
        self.outside = outside
        lat_rad = np.radians([s.lat_deg for s in self.stations])
        lon_rad = np.radians([s.lon_deg for s in self.stations])
        self._cos_lat = np.cos(lat_rad)
        self._half = (np.sin(0.5 * lat_rad), np.cos(0.5 * lat_rad), np.sin(0.5 * lon_rad), np.cos(0.5 * lon_rad))
        sep = self._angles(lat_rad, lon_rad)  # (M, M)
        np.fill_diagonal(sep, np.inf)
        if (sep < 1e-6).any():
            raise ValueError("two stations share one location; IDW needs distinct stations")
        groups: dict[bytes, list[int]] = {}
        for k, s in enumerate(self.stations):
            if s.time_s.ndim != 1 or s.time_s.size == 0 or (np.diff(s.time_s) <= 0).any():
                raise ValueError(f"station {s.code}: time_s must be non-empty and strictly increasing")
            groups.setdefault(np.ascontiguousarray(s.time_s, dtype=np.float64).tobytes(), []).append(k)
        self._groups: list[_TimeGroup] = []
        for idx in groups.values():
            t = np.asarray(self.stations[idx[0]].time_s, dtype=np.float64)
            values = np.empty((t.size, len(idx), 3))
            for j, k in enumerate(idx):
                s = self.stations[k]
                for c, (comp, v) in enumerate((("X", s.dx_nt), ("Y", s.dy_nt), ("Z", s.dz_nt))):
                    values[:, j, c] = _fill_gaps(t, np.asarray(v, dtype=np.float64), s.code, comp)
            self._groups.append(_TimeGroup(t, idx, values))
        self._t_lo = max(float(s.time_s[0]) for s in self.stations)
        self._t_hi = min(float(s.time_s[-1]) for s in self.stations)
        if self._t_hi < self._t_lo:
            raise ValueError("the stations' time spans do not overlap")

    @classmethod
    def from_records(
        cls,
        records: Mapping[str, IagaRecord] | Sequence[IagaRecord],
        baseline: StormWindow | Mapping[str, StormWindow] = QUIET_BASELINE,
        **kwargs: object,
    ) -> StormDisturbance:
        """Build from IAGA records (e.g. :func:`load_stations`) and a quiet baseline window.

        ``baseline`` is one window for all stations or ``{code: window}`` (codes any case;
        stations not named use :data:`QUIET_BASELINE`).
        """
        recs = list(records.values()) if isinstance(records, Mapping) else list(records)
        if isinstance(baseline, StormWindow):
            windows = {r.code: baseline for r in recs}
        else:
            named = {k.upper(): v for k, v in baseline.items()}
            windows = {r.code: named.get(r.code, QUIET_BASELINE) for r in recs}
        return cls([station_deviation(r, windows[r.code]) for r in recs], **kwargs)  # type: ignore[arg-type]

    @classmethod
    def from_data_dir(
        cls,
        data_dir: str | os.PathLike[str] | None = None,
        stations: Iterable[str] = DEFAULT_STATIONS,
        **kwargs: object,
    ) -> StormDisturbance:
        """:func:`load_stations` then :meth:`from_records`."""
        return cls.from_records(load_stations(data_dir, stations), **kwargs)  # type: ignore[arg-type]

    def with_mapping(self, *, scale: float | None = None, time_offset_s: float | None = None) -> StormDisturbance:
        """A copy sharing the data, with another scale and/or time offset."""
        new = object.__new__(StormDisturbance)
        new.__dict__.update(self.__dict__)
        if scale is not None:
            new.scale = float(scale)
        if time_offset_s is not None:
            new.time_offset_s = float(time_offset_s)
        return new

    @property
    def codes(self) -> tuple[str, ...]:
        """Station codes in order."""
        return tuple(s.code for s in self.stations)

    @property
    def time_range_s(self) -> tuple[float, float]:
        """Storm-time span (POSIX UTC) covered by every station."""
        return self._t_lo, self._t_hi

    def _angles(self, lat_rad: FloatArray, lon_rad: FloatArray) -> FloatArray:
        """Great-circle angles (rad) from the stations to points of any shape: shape (M, ...).

        Haversine, with sin((a - b)/2) expanded as sin(a/2)cos(b/2) - cos(a/2)sin(b/2) so the
        transcendental functions run per point, not per point and station; the expansion is
        exactly 0 for a point on a station.
        """
        expand = (slice(None),) + (None,) * np.ndim(lat_rad)
        s_sa, s_ca, s_sl, s_cl = (v[expand] for v in self._half)
        dlat = s_ca * np.sin(0.5 * lat_rad) - s_sa * np.cos(0.5 * lat_rad)
        dlon = s_cl * np.sin(0.5 * lon_rad) - s_sl * np.cos(0.5 * lon_rad)
        hav = dlat * dlat + (self._cos_lat[expand] * np.cos(lat_rad)) * (dlon * dlon)
        np.clip(hav, 0.0, 1.0, out=hav)
        return 2.0 * np.arcsin(np.sqrt(hav))

    def _weights(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> FloatArray:
        """IDW weights, station-major: shape ``(M,) + broadcast(lat, lon).shape``."""
        lat, lon = np.broadcast_arrays(np.asarray(lat_deg, dtype=np.float64), np.asarray(lon_deg, dtype=np.float64))
        ang = self._angles(np.radians(lat), np.radians(lon))
        exact = ang < _EXACT_RAD
        with np.errstate(divide="ignore"):
            w = 1.0 / (ang * ang) if self.power == 2.0 else ang ** (-self.power)
        hit = exact.any(axis=0)
        if hit.any():
            w[:, hit] = exact[:, hit]
        w /= w.sum(axis=0)
        return w

    def weights(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> FloatArray:
        """IDW weights of the stations at positions: shape ``broadcast(lat, lon).shape + (M,)``, summing to 1.

        ``w_j = a_j^-p / sum_k a_k^-p`` with ``a`` the great-circle angle; a point within
        1e-10 rad (0.6 mm) of a station takes that station's weight 1.
        """
        return np.moveaxis(self._weights(lat_deg, lon_deg), 0, -1)

    def _storm_time(self, time_s: ArrayLike) -> FloatArray:
        t = np.asarray(time_s, dtype=np.float64) + self.time_offset_s
        if self.outside == "raise":
            bad = (t < self._t_lo) | (t > self._t_hi)
            if bad.any():
                first = float(t[bad].flat[0])
                raise ValueError(
                    f"storm time {_iso(first)} outside the data span {_iso(self._t_lo)} .. {_iso(self._t_hi)} "
                    "(check the StormTimeMap / time_offset_s, or use outside='hold'/'zero')"
                )
        return t

    def station_values(self, time_s: ArrayLike) -> FloatArray:
        """Unscaled station deviations (dn, de, dd) at storm times ``time_s + time_offset_s``.

        Shape ``(M, 3) + shape(time_s)``, nT.
        """
        t = self._storm_time(time_s)
        out = np.empty((len(self.stations), 3) + t.shape)
        for g in self._groups:
            out[g.station_index] = g.interp(t)
        if self.outside == "zero":
            out[..., (t < self._t_lo) | (t > self._t_hi)] = 0.0
        return out

    def disturbance_ned_nt(
        self, lat_deg: ArrayLike, lon_deg: ArrayLike, time_s: ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Disturbance (dn, de, dd) in nT (north, east, down) at positions and POSIX UTC times.

        ``lat_deg``, ``lon_deg`` and ``time_s`` broadcast together (numpy rules) to the shape
        of the three returned arrays. Spatial weights are computed at the shape of
        ``broadcast(lat, lon)`` and time interpolation at the shape of ``time_s``, so a scalar
        time with 10^5 positions interpolates time once. NaN inputs give NaN outputs.

        Raises:
            ValueError: with ``outside="raise"``, a storm time outside :attr:`time_range_s`.
        """
        w = self._weights(lat_deg, lon_deg)  # (M, *ll)
        vals = self.station_values(time_s)  # (M, 3, *t)
        out = np.einsum("m...,mk...->k...", w, vals)  # (3, *broadcast shape)
        if self.scale != 1.0:
            out *= self.scale
        return out[0], out[1], out[2]

    def dbh_nt(self, lat_deg: ArrayLike, lon_deg: ArrayLike, time_s: ArrayLike) -> FloatArray:
        """Paper eq. 64 of the interpolated disturbance: ``sign(dn) * hypot(dn, de)`` in nT."""
        dn, de, _ = self.disturbance_ned_nt(lat_deg, lon_deg, time_s)
        return eq64_dbh_nt(dn, de)


# --------------------------------------------------------------------------------------
# Scenario time mapping
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StormTimeMap:
    """How mission elapsed time (s since mission start) maps onto storm time (POSIX UTC).

    rule ``"utc"``: ``storm = mission_start_utc_s + elapsed`` (the mission flies through the
    storm in real time, starting at ``mission_start_utc_s``).

    rule ``"compress"``: the storm window ``[window.start_s, window.end_s]`` is mapped
    linearly onto ``[0, mission_duration_s]`` of mission time (the paper's use: a six-hour
    storm record spans the whole simulated mission). ``storm = start + elapsed * k`` with
    ``k = window.duration_s / mission_duration_s``; beyond the expected duration the map
    continues linearly (the disturbance's ``outside`` policy then applies at the data end).
    """

    rule: Literal["utc", "compress"]
    mission_start_utc_s: float | None = None
    window: StormWindow | None = None
    mission_duration_s: float | None = None

    def __post_init__(self) -> None:
        if self.rule == "utc":
            if self.mission_start_utc_s is None or not math.isfinite(self.mission_start_utc_s):
                raise ValueError("rule 'utc' needs mission_start_utc_s (POSIX UTC seconds)")
        elif self.rule == "compress":
            if self.window is None:
                raise ValueError("rule 'compress' needs a storm window")
            if self.mission_duration_s is None or not self.mission_duration_s > 0.0:
                raise ValueError("rule 'compress' needs mission_duration_s > 0")
        else:
            raise ValueError(f"unknown storm time rule {self.rule!r} (use 'utc' or 'compress')")

    @classmethod
    def utc(cls, mission_start_utc_s: float) -> StormTimeMap:
        """Real-time rule starting the mission at ``mission_start_utc_s``."""
        return cls("utc", mission_start_utc_s=float(mission_start_utc_s))

    @classmethod
    def compress(cls, window: StormWindow, mission_duration_s: float) -> StormTimeMap:
        """Window-onto-mission rule."""
        return cls("compress", window=window, mission_duration_s=float(mission_duration_s))

    @property
    def rate(self) -> float:
        """Storm seconds per mission second (1 for ``"utc"``)."""
        if self.rule == "utc":
            return 1.0
        assert self.window is not None and self.mission_duration_s is not None
        return self.window.duration_s / self.mission_duration_s

    def storm_time_s(self, mission_elapsed_s: ArrayLike) -> FloatArray:
        """Storm time (POSIX UTC seconds) of mission elapsed seconds (array or scalar)."""
        e = np.asarray(mission_elapsed_s, dtype=np.float64)
        if self.rule == "utc":
            assert self.mission_start_utc_s is not None
            return self.mission_start_utc_s + e
        assert self.window is not None
        return self.window.start_s + e * self.rate


# --------------------------------------------------------------------------------------
# Short-storm window
# --------------------------------------------------------------------------------------


def sharpest_window(
    records: Mapping[str, IagaRecord] | Sequence[IagaRecord],
    length_s: float = 93 * 60.0,
    *,
    search: tuple[float, float] | None = None,
    step_s: float = 60.0,
    name: str = "short storm",
) -> StormWindow:
    """The window of ``length_s`` with the largest mean |dH/dt| averaged over the stations.

    Mean |dH/dt| over ``[t0, t0 + L]`` is the total variation of H in the window divided by
    L, evaluated per station from minute differences of ``H = hypot(X, Y)`` (intervals
    touching a NaN count as zero change) and averaged over the stations. Start times are
    tried every ``step_s`` (on whole minutes) with the window inside ``search``.

    Args:
        search: (earliest start, latest end) in POSIX UTC. Default: from the sudden
            commencement minus ``length_s - step_s`` (the window must contain or follow
            the 17:07 commencement) to 2024-05-11 00:00 UTC (the main phase of 10 May).

    Returns:
        The first window of largest mean |dH/dt|.
    """
    recs = list(records.values()) if isinstance(records, Mapping) else list(records)
    if not recs:
        raise ValueError("no station records")
    lo, hi = search if search is not None else (SUDDEN_COMMENCEMENT_S - length_s + step_s, utc_s("2024-05-11T00:00"))
    first = math.ceil(lo / step_s) * step_s
    starts = np.arange(first, hi - length_s + 0.5 * step_s, step_s)
    if starts.size == 0:
        raise ValueError(f"search span {_iso(lo)} .. {_iso(hi)} shorter than the window ({length_s} s)")
    mean_rate = np.zeros(starts.size)
    for r in recs:
        dh = np.abs(np.diff(r.h_nt))
        dh[~np.isfinite(dh)] = 0.0
        cum = np.concatenate([[0.0], np.cumsum(dh)])  # total variation up to each sample
        if r.time_s[0] > starts[0] or r.time_s[-1] < starts[-1] + length_s:
            raise ValueError(f"station {r.code} does not cover the search span")
        mean_rate += (np.interp(starts + length_s, r.time_s, cum) - np.interp(starts, r.time_s, cum)) / length_s
    best = int(np.argmax(mean_rate))
    return StormWindow(name, float(starts[best]), float(starts[best] + length_s))


# --------------------------------------------------------------------------------------
# Plot
# --------------------------------------------------------------------------------------


def plot_disturbance(
    disturbance: StormDisturbance,
    path_png: str | os.PathLike[str],
    window: StormWindow | tuple[float, float] | None = None,
    *,
    margin_s: float = 0.0,
) -> Figure:
    """Plot each station's dH (eq.-64 dB_H dashed), dX, dY, dZ vs UTC over a window (paper Fig. 5).

    ``window``: a :class:`StormWindow`, ``(start_s, end_s)`` POSIX UTC, or None for the whole
    data span; ``margin_s`` widens the plotted span on both sides (the window is shaded).

    Values are the station deviations times ``disturbance.scale`` (what the simulated
    vehicle would meet at the station); the x axis is storm time (UTC). The figure carries
    :data:`ACKNOWLEDGEMENT`. Writes ``path_png`` (parents created) and returns the Figure.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    import matplotlib.dates as mdates

    if window is None:
        win = StormWindow("data", *disturbance.time_range_s)
    elif isinstance(window, StormWindow):
        win = window
    else:
        win = StormWindow("window", float(window[0]), float(window[1]))
    t0, t1 = win.start_s - margin_s, win.end_s + margin_s
    fig = Figure(figsize=(10.0, 9.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(4, 1, sharex=True)
    labels = ("dH = H - H0 (nT)", "dX north (nT)", "dY east (nT)", "dZ down (nT)")
    for s in disturbance.stations:
        sel = (s.time_s >= t0) & (s.time_s <= t1)
        if not sel.any():
            continue
        when = s.time_s[sel].astype("datetime64[s]")
        k = disturbance.scale
        (line,) = axes[0].plot(when, k * s.dh_nt[sel], lw=0.9, label=f"{s.code} ({s.lat_deg:.1f}, {s.lon_deg:.1f})")
        axes[0].plot(when, k * eq64_dbh_nt(s.dx_nt[sel], s.dy_nt[sel]), lw=0.6, ls="--", color=line.get_color())
        for ax, comp in zip(axes[1:], (s.dx_nt, s.dy_nt, s.dz_nt)):
            ax.plot(when, k * comp[sel], lw=0.9, color=line.get_color())
    for ax, label in zip(axes, labels):
        ax.set_ylabel(label)
        ax.grid(True, lw=0.3)
        if margin_s > 0.0:  # mark the window itself inside the margins
            ax.axvspan(np.datetime64(int(win.start_s), "s"), np.datetime64(int(win.end_s), "s"), color="0.92", zorder=0)
        if t0 <= SUDDEN_COMMENCEMENT_S <= t1:
            ax.axvline(np.datetime64(int(SUDDEN_COMMENCEMENT_S), "s"), color="k", lw=0.6, ls=":")
    axes[0].legend(fontsize=8, ncol=3, title="station (lat, lon); dashed: eq. 64 dB_H", title_fontsize=8)
    axes[-1].set_xlabel("UTC")
    axes[-1].xaxis.set_major_formatter(mdates.DateFormatter("%m-%d %H:%M"))
    scale_txt = "" if disturbance.scale == 1.0 else f", scale {disturbance.scale:g}"
    fig.suptitle(f"Storm disturbance from quiet baseline - {win}{scale_txt}", fontsize=10)
    fig.supxlabel(ACKNOWLEDGEMENT, fontsize=8, x=0.01, ha="left")  # laid out below the axes
    path = Path(path_png)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return fig
