"""The log's date and the World Magnetic Model that covers it.

Models are the coefficient files pygeomag ships (WMM2010 to WMM2025) or a user's ``.COF``.
"""
from __future__ import annotations

import datetime
from pathlib import Path

from companion.io.sensors.replay import LogFormat
from companion.nav.field import WorldMagneticModel
from replay.logdata import LogData

__all__ = ["PYGEOMAG_MODELS", "log_decimal_year", "select_model"]

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

GPS_EPOCH = datetime.datetime(1980, 1, 6, tzinfo=datetime.timezone.utc)


def log_decimal_year(data: LogData) -> tuple[float, str] | None:
    """(decimal year, ISO date) of the first 3D GPS fix, from the log's GPS time; None if unknown.

    tlog: GPS_RAW_INT's UNIX time_usec (the replay source's ``utc_s``). DataFlash: the first GPS
    record with a 3D fix carries the GPS week (``Week``/``GWk``) and time of week (``TimeMS``/
    ``GMS``, ms), read here with pymavlink (leap seconds are irrelevant for a decimal year).
    """
    when: datetime.datetime | None = None
    if data.gps_utc_s is not None:
        when = datetime.datetime.fromtimestamp(data.gps_utc_s, tz=datetime.timezone.utc)
    elif data.format == LogFormat.DATAFLASH:
        from pymavlink import DFReader

        reader = DFReader.DFReader_binary(str(data.path))
        try:
            while True:
                msg = reader.recv_match(type=["GPS"])
                if msg is None:
                    break
                if getattr(msg, "Status", 0) < 3:
                    continue
                week = getattr(msg, "GWk", getattr(msg, "Week", None))
                tow_ms = getattr(msg, "GMS", None)
                if tow_ms is None and getattr(msg, "T", None) is not None:
                    tow_ms = getattr(msg, "TimeMS", None)  # Copter 3.3: TimeMS is GPS time of week
                if week and tow_ms is not None:
                    when = GPS_EPOCH + datetime.timedelta(weeks=int(week), milliseconds=float(tow_ms))
                break
        finally:
            reader.close()
    if when is None:
        return None
    start = datetime.datetime(when.year, 1, 1, tzinfo=datetime.timezone.utc)
    end = datetime.datetime(when.year + 1, 1, 1, tzinfo=datetime.timezone.utc)
    return when.year + (when - start) / (end - start), when.date().isoformat()


def _pygeomag_cof(name: str) -> Path:
    import pygeomag

    return Path(pygeomag.__file__).resolve().parent / "wmm" / PYGEOMAG_MODELS[name]


def select_model(spec: str | None, year: float | None) -> tuple[WorldMagneticModel, str]:
    """The model and a line saying why: ``spec`` = a name (WMM2015), a .COF path, or None (auto)."""
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
            raise ValueError(f"{model.name} is valid {model.valid_from:.3f}..{model.valid_until:.1f}, "
                             f"the log is from {year:.2f}")
        return model, why
    if year is None:
        raise ValueError("the log carries no GPS date; pass --model (e.g. --model WMM2015)")
    for key in reversed(_AUTO_ORDER):
        model = WorldMagneticModel.from_cof(_pygeomag_cof(key))
        if model.valid_from <= year < model.valid_until:
            return model, f"{model.name} (auto: the log's date is {year:.2f})"
    raise ValueError(f"no shipped World Magnetic Model covers {year:.2f}; pass --model path.COF")
