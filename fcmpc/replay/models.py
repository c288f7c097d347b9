"""The log's date, where it came from, and the World Magnetic Model that covers it.

A log's date is taken from the best source it has (:data:`DATE_SOURCES`, best first: the
GPS's own time, then the autopilot's UNIX clock, then the recorder's clock), and the report
says which. A model is used only inside its validity span: a date outside it is refused with
the date and its source, never replaced by a date the log does not carry. Models are the
coefficient files pygeomag ships (WMM2010 to WMM2025) or a user's ``.COF``.
"""
from __future__ import annotations

import datetime
from dataclasses import dataclass
from pathlib import Path

from companion.nav.field import WorldMagneticModel
from fcmpc.replay.csvlog import CSV_SOURCE
from fcmpc.replay.events import GPS_RAW_SOURCE, GPS_WEEK_SOURCE, SYSTEM_TIME_SOURCE, TLOG_SOURCE
from fcmpc.replay.logdata import LogData
from fcmpc.replay.ulog import ULOG_GPS_SOURCE

__all__ = ["PYGEOMAG_MODELS", "DATE_SOURCES", "LogDate", "log_date", "select_model"]

USER_SOURCE = "--date"
DATE_SOURCES = (GPS_WEEK_SOURCE, GPS_RAW_SOURCE, ULOG_GPS_SOURCE, SYSTEM_TIME_SOURCE, CSV_SOURCE, TLOG_SOURCE)
_DISAGREE_S = 86400.0


@dataclass(frozen=True)
class LogDate:
    """When the log's first 3D fix (else first sample) was taken, and from which source."""

    decimal_year: float
    iso: str
    source: str
    note: str = ""


def _decimal_year(when: datetime.datetime) -> float:
    start = datetime.datetime(when.year, 1, 1, tzinfo=datetime.timezone.utc)
    end = datetime.datetime(when.year + 1, 1, 1, tzinfo=datetime.timezone.utc)
    return when.year + (when - start) / (end - start)


def log_date(data: LogData, user_date: str | None = None) -> LogDate | None:
    """The date of the log from its best source (or ``user_date``, YYYY-MM-DD); None if it has none."""
    t0 = float(data.gps[0, 0]) if len(data.gps) else data.span_s[0]
    if user_date:
        try:
            when = datetime.datetime.strptime(user_date, "%Y-%m-%d").replace(tzinfo=datetime.timezone.utc)
        except ValueError as err:
            raise ValueError(f"--date {user_date!r}: expected YYYY-MM-DD") from err
        return LogDate(_decimal_year(when), when.date().isoformat(), USER_SOURCE)
    found = [(name, data.unix_minus_boot_s[name]) for name in DATE_SOURCES if name in data.unix_minus_boot_s]
    if not found:
        return None
    name, offset = found[0]
    when = datetime.datetime.fromtimestamp(offset + t0, tz=datetime.timezone.utc)
    others = [f"{other} says {datetime.datetime.fromtimestamp(o + t0, tz=datetime.timezone.utc).date()}"
              for other, o in found[1:] if abs(o - offset) > _DISAGREE_S]
    note = ("; ".join(others) + f": {name} is trusted") if others else ""
    return LogDate(_decimal_year(when), when.date().isoformat(), name, note)


# World Magnetic Models shipped inside pygeomag, oldest first (auto-selection takes the newest
# model whose validity span holds the log's date).
PYGEOMAG_MODELS = {
    "WMM2010": "WMM_2010.COF",
    "WMM2015": "WMM_2015.COF",
    "WMM2015V2": "WMM_2015v2.COF",
    "WMM2020": "WMM_2020.COF",
    "WMM2025": "WMM_2025.COF",
}
_AUTO_ORDER = ("WMM2010", "WMM2015", "WMM2020", "WMM2025")

def _pygeomag_cof(name: str) -> Path:
    import pygeomag

    return Path(pygeomag.__file__).resolve().parent / "wmm" / PYGEOMAG_MODELS[name]


def select_model(spec: str | None, date: LogDate | None) -> tuple[WorldMagneticModel, str]:
    """The model and a line saying why: ``spec`` = a name (WMM2015), a .COF path, or None (auto).

    ValueError when the log has no date (pass ``--date``) or the date lies outside the model's
    validity (outside every shipped model's, for auto).
    """
    year = date.decimal_year if date is not None else None
    said = f"the log is from {date.iso} ({date.decimal_year:.2f}, by its {date.source})" if date else ""
    if spec:
        key = spec.upper().replace("-", "").replace("_", "")
        if key in PYGEOMAG_MODELS:
            model = WorldMagneticModel.from_cof(_pygeomag_cof(key))
            why = f"{model.name} (--model {spec}, pygeomag's {PYGEOMAG_MODELS[key]})"
        elif Path(spec).is_file():
            model = WorldMagneticModel.from_cof(spec)
            why = f"{model.name} (--model {spec})"
        else:
            raise ValueError(f"--model {spec!r}: neither one of {sorted(PYGEOMAG_MODELS)} nor a .COF file")
        if year is not None and not model.valid_from <= year < model.valid_until:
            raise ValueError(f"{model.name} is valid {model.valid_from:.3f}..{model.valid_until:.1f}, {said}; "
                             "pick a model that covers the date")
        if year is None:
            raise ValueError(f"the log carries no date (no GPS time, SYSTEM_TIME or recording time), and "
                             f"{model.name} changes with time; pass --date YYYY-MM-DD")
        return model, why
    if year is None:
        raise ValueError("the log carries no date (no GPS time, SYSTEM_TIME or recording time); "
                         "pass --date YYYY-MM-DD")
    for key in reversed(_AUTO_ORDER):
        model = WorldMagneticModel.from_cof(_pygeomag_cof(key))
        if model.valid_from <= year < model.valid_until:
            return model, f"{model.name} (auto: {said})"
    raise ValueError(f"no shipped World Magnetic Model covers {said}; pass --model path.COF")
