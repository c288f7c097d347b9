"""IGRF-14, the truth side's main field: a different model from the navigator's WMM.

The International Geomagnetic Reference Field, 14th generation (IAGA Working Group V-MOD,
Alken et al. 2025, doi:10.5281/zenodo.14012302), is the model ArduPilot's declination tables
are generated from. Its coefficient file ``data/IGRF14.shc`` (the public IAGA file, as shipped
by the ``ppigrf`` package, MIT) lists the Gauss coefficients g, h in nT every 5 years from
1900 to 2025 and the predicted 2030 values (the 2025-2030 secular variation).

Evaluation: the coefficients of the 5-year interval containing the year, with the linear
secular variation of that interval (IGRF's own interpolation rule), handed to the project's
spherical-harmonic evaluator :class:`companion.nav.field.WorldMagneticModel` (same geodetic
to geocentric conversion and reference radius 6371.2 km as IGRF). That evaluator stops at
degree 12; IGRF's degree-13 terms are dropped rather than changing the navigator's code.
Checked against ``ppigrf`` 2.1.0 at six points on 2024-05-11: 0.09 nT from its degree-12
sum; the dropped degree-13 terms are up to 13 nT at the surface, small beside the crustal
anomaly field (:mod:`sitl.world.crustal`, 100 nT rms) that this world adds anyway.

>>> model = igrf14_model(2024.36)
>>> model.name, model.epoch
('IGRF14', 2020.0)
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from companion.nav.field import WMM_DEGREE, WorldMagneticModel

__all__ = ["IGRF14_FILE", "igrf14_model", "read_shc"]

IGRF14_FILE = Path(__file__).resolve().parent / "data" / "IGRF14.shc"


def read_shc(path: str | Path = IGRF14_FILE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(years, (n, m) rows, values[row, year]) of an IAGA ``.shc`` file; m < 0 marks an h term."""
    rows, values, years = [], [], None
    header_seen = False
    for line in Path(path).read_text(encoding="ascii").splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = line.split()
        if not header_seen:
            header_seen = True           # "N_min N_max N_times order step start end"
            continue
        if years is None:
            years = np.array([float(v) for v in fields])
            continue
        rows.append((int(fields[0]), int(fields[1])))
        values.append([float(v) for v in fields[2:]])
    if years is None or not rows:
        raise ValueError(f"{path}: not an .shc coefficient file")
    table = np.array(values)
    if table.shape[1] != years.size:
        raise ValueError(f"{path}: {table.shape[1]} values per row for {years.size} epochs")
    return years, np.array(rows), table


@lru_cache(maxsize=8)
def igrf14_model(year: float) -> WorldMagneticModel:
    """IGRF-14 (to degree 12) as a :class:`WorldMagneticModel` valid over the 5-year interval
    that contains ``year`` (1900 <= year < 2030)."""
    years, nm, table = read_shc()
    index = int(np.searchsorted(years, year, side="right")) - 1
    if not 0 <= index < years.size - 1:
        raise ValueError(f"IGRF-14 covers {years[0]:.0f}-{years[-1]:.0f}, not {year}")
    epoch, span = years[index], years[index + 1] - years[index]
    now, then = table[:, index], table[:, index + 1]
    coefficients: dict[tuple[int, int], list[float]] = {}
    for (n, m), value, later in zip(nm, now, then):
        if n > WMM_DEGREE:
            continue
        entry = coefficients.setdefault((n, abs(m)), [0.0, 0.0, 0.0, 0.0])
        slot = 1 if m < 0 else 0
        entry[slot] = value
        entry[slot + 2] = (later - value) / span
    rows = np.array([[n, m, *v] for (n, m), v in sorted(coefficients.items())])
    return WorldMagneticModel("IGRF14", float(epoch), rows)
