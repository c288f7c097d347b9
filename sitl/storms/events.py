"""The storm library: real storms from one table (``events.toml`` beside this module), each with its
reader, stations, route, mission start and index sources.

Adding a storm is its data folder and one ``[[event]]`` row (``docs/storms.md``); a new data
*format* is one reader in :data:`READERS`. Every reader gives :class:`~sitl.storms.deviation.StationDeviation`
records in geographic north, east, down axes, which :class:`~sitl.storms.disturbance.StormDisturbance`
interpolates (inverse-distance weighting, see :mod:`sitl.storms`):

``iaga2002``
    absolute X, Y, Z (or H, D in arc minutes, Z: converted) per station, files ``<code>*.min`` or
    ``<code>*.txt``; the median over ``baseline_utc`` is removed (:func:`~sitl.storms.deviation.quiet_baseline`).
``gem2008``
    changes in dipole axes, ``<code>.txt``: rotated to geographic axes at the station's geographic
    position (:mod:`sitl.storms.gem2008`, :mod:`sitl.storms.dipole`) about the row's ``dipole_pole``
    (IGRF-14's at the event's epoch; a test recomputes it).
``supermag``
    one file, changes in geographic axes (the last three columns); positions from ``coords``.

The indices: ``kp`` (``gfz:`` GFZ's Kp file, ``celestrak:`` CelesTrak's SW-All) and ``ring``
(``omni:`` OMNI's 1-minute SYM-H, ``rc:`` DTU's hourly RC), read as definitive
:class:`~sitl.storms.published.IndexSeries`; what a vehicle receives is their published form
(:class:`~sitl.storms.published.PublishedIndex`).

>>> [e.name for e in storm_events()]
['may2024', 'halloween2003', 'stpatrick2015', 'march2011']
"""
from __future__ import annotations

import os
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from sitl.storms.common import StormWindow, default_data_dir, utc_s
from sitl.storms.deviation import StationDeviation, station_deviation
from sitl.storms.published import IndexSeries

__all__ = ["EVENTS_FILE", "INDEX_FORMATS", "READERS", "StormEvent", "storm_event", "storm_events"]

EVENTS_FILE = Path(__file__).resolve().parent / "events.toml"
_INDEX_SPAN_S = 2 * 86400.0   # indices are read from two days before the mission to two days after


def _decimal_year(time_s: float) -> float:
    stamp = np.datetime64(int(time_s), "s")
    year = stamp.astype("datetime64[Y]")
    start = float(year.astype("datetime64[s]").astype(np.int64))
    end = float((year + 1).astype("datetime64[s]").astype(np.int64))
    return 1970.0 + float(year.astype(np.int64)) + (time_s - start) / (end - start)


@dataclass(frozen=True)
class StormEvent:
    """One row of the storm table (see the module docstring and ``events.toml``)."""

    name: str
    title: str
    reader: str
    data: str
    stations: tuple[str, ...]
    main_phase_utc: tuple[str, str]
    route: tuple[tuple[float, float], tuple[float, float]]
    start_utc: str
    kp: str
    ring: str
    acknowledgement: str = ""
    baseline_utc: tuple[str, str] | None = None
    coords: dict[str, tuple[float, float]] = field(default_factory=dict)
    dipole_pole: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.reader not in READERS:
            raise ValueError(f"storm {self.name!r}: reader {self.reader!r} not one of {', '.join(READERS)}")
        if self.reader == "iaga2002" and self.baseline_utc is None:
            raise ValueError(f"storm {self.name!r}: reader iaga2002 needs baseline_utc (a quiet window)")
        if self.reader == "gem2008" and self.dipole_pole is None:
            raise ValueError(f"storm {self.name!r}: reader gem2008 needs dipole_pole (the epoch's [lat, lon])")
        for key, value in (("kp", self.kp), ("ring", self.ring)):
            kind = value.partition(":")[0]
            if kind not in INDEX_FORMATS:
                raise ValueError(f"storm {self.name!r}: {key} source {value!r} not '<format>:<path>' with a format "
                                 f"of {', '.join(INDEX_FORMATS)}")
        missing = [c for c in self.stations if self.reader == "supermag" and c.upper() not in self.coords]
        if missing:
            raise ValueError(f"storm {self.name!r}: no coords for {', '.join(missing)}")

    @property
    def main_phase(self) -> StormWindow:
        """The main phase (POSIX UTC)."""
        return StormWindow(f"{self.name} main phase", utc_s(self.main_phase_utc[0]), utc_s(self.main_phase_utc[1]))

    @property
    def start_s(self) -> float:
        """Mission start, POSIX UTC s."""
        return utc_s(self.start_utc)

    @property
    def year(self) -> float:
        """Decimal year of the mission start (the main-field and dipole epoch)."""
        return _decimal_year(self.start_s)

    def deviations(self, data_dir: str | os.PathLike[str] | None = None,
                   stations: tuple[str, ...] = ()) -> list[StationDeviation]:
        """The stations' (``stations``, default the row's) deviations in geographic axes."""
        root = Path(data_dir) if data_dir is not None else default_data_dir()
        return READERS[self.reader](self, root / self.data, tuple(c.lower() for c in (stations or self.stations)))

    def kp_series(self, data_dir: str | os.PathLike[str] | None = None) -> IndexSeries:
        """The definitive Kp around the mission."""
        return self._index(self.kp, data_dir)

    def ring_series(self, data_dir: str | os.PathLike[str] | None = None) -> IndexSeries:
        """The definitive ring-current index (SYM-H or RC, nT) around the mission."""
        return self._index(self.ring, data_dir)

    def _index(self, source: str, data_dir: str | os.PathLike[str] | None) -> IndexSeries:
        kind, _, relative = source.partition(":")
        root = Path(data_dir) if data_dir is not None else default_data_dir()
        return INDEX_FORMATS[kind](root / relative, self.start_s - _INDEX_SPAN_S, self.start_s + _INDEX_SPAN_S)


def _iaga(event: StormEvent, folder: Path, stations: tuple[str, ...]) -> list[StationDeviation]:
    from sitl.storms.iaga import load_stations
    assert event.baseline_utc is not None   # checked at construction
    window = StormWindow(f"{event.name} quiet baseline", utc_s(event.baseline_utc[0]), utc_s(event.baseline_utc[1]))
    return [station_deviation(record, window) for record in load_stations(folder, stations).values()]


def _gem(event: StormEvent, folder: Path, stations: tuple[str, ...]) -> list[StationDeviation]:
    from sitl.storms.gem2008 import gem_deviation, read_gem2008
    assert event.dipole_pole is not None   # checked at construction
    return [gem_deviation(read_gem2008(folder / f"{code}.txt"), event.dipole_pole) for code in stations]


def _supermag(event: StormEvent, path: Path, stations: tuple[str, ...]) -> list[StationDeviation]:
    from sitl.storms.supermag import read_supermag
    record = read_supermag(path)
    out = []
    for code in stations:
        key = code.upper()
        if key not in record.nez_geo:
            raise FileNotFoundError(f"{path}: no station {key} (has {', '.join(sorted(record.nez_geo))})")
        lat, lon = event.coords[key]
        nez = record.nez_geo[key]
        out.append(StationDeviation(code=key, lat_deg=float(lat), lon_deg=float(lon), time_s=record.time_s,
                                    dx_nt=nez[:, 0], dy_nt=nez[:, 1], dz_nt=nez[:, 2],
                                    x0_nt=np.nan, y0_nt=np.nan, z0_nt=np.nan))
    return out


def _gfz(path: Path, start_s: float, end_s: float) -> IndexSeries:
    from sitl.storms.kp import read_gfz_kp
    return read_gfz_kp(path).series()


def _omni(path: Path, start_s: float, end_s: float) -> IndexSeries:
    from sitl.storms.omni import read_omni_symh
    return read_omni_symh(path).series()


def _celestrak(path: Path, start_s: float, end_s: float) -> IndexSeries:
    from sitl.storms.celestrak import read_celestrak_kp
    return read_celestrak_kp(path, start_s, end_s)


def _rc(path: Path, start_s: float, end_s: float) -> IndexSeries:
    from sitl.storms.rc import read_rc_index
    return read_rc_index(path, start_s, end_s)


#: Data formats of station files: reader name -> (event, file or folder, station codes) -> deviations.
READERS: dict[str, Callable[[StormEvent, Path, tuple[str, ...]], list[StationDeviation]]] = {
    "iaga2002": _iaga, "gem2008": _gem, "supermag": _supermag}
#: Index formats: name -> (path, start, end) -> definitive series.
INDEX_FORMATS: dict[str, Callable[[Path, float, float], IndexSeries]] = {
    "gfz": _gfz, "omni": _omni, "celestrak": _celestrak, "rc": _rc}


@lru_cache(maxsize=4)
def _table(path: Path) -> tuple[StormEvent, ...]:
    rows = tomllib.loads(path.read_text(encoding="utf-8")).get("event", [])
    events = []
    for index, row in enumerate(rows, start=1):
        try:
            events.append(StormEvent(
                **{**row, "stations": tuple(row["stations"]), "main_phase_utc": tuple(row["main_phase_utc"]),
                   "route": (tuple(row["route"][0]), tuple(row["route"][1])),
                   "baseline_utc": tuple(row["baseline_utc"]) if "baseline_utc" in row else None,
                   "dipole_pole": tuple(row["dipole_pole"]) if "dipole_pole" in row else None,
                   "coords": {k.upper(): tuple(v) for k, v in row.get("coords", {}).items()}}))
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise ValueError(f"{path}: event #{index} ({row.get('name', '?')}): {err}") from None
    names = [e.name for e in events]
    if len(set(names)) != len(names):
        raise ValueError(f"{path}: event names repeat: {names}")
    return tuple(events)


def storm_events(path: str | os.PathLike[str] = EVENTS_FILE) -> tuple[StormEvent, ...]:
    """Every event of the table."""
    return _table(Path(path))


def storm_event(name: str, path: str | os.PathLike[str] = EVENTS_FILE) -> StormEvent:
    """The event called ``name``; ValueError naming the known ones."""
    for event in storm_events(path):
        if event.name == name:
            return event
    raise ValueError(f"no storm {name!r} in {path} (known: {', '.join(e.name for e in storm_events(path))})")
