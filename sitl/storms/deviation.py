"""A station's deviation from its quiet baseline (median of 12:00-17:00 UTC on 10 May 2024), the
paper's eq. 64 horizontal disturbance, and the exact (D, I) shift a disturbance causes.

See :mod:`sitl.storms` for why that baseline, and what it leaves in (the Sq variation).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from sitl.storms.common import QUIET_BASELINE, FloatArray, StormWindow
from sitl.storms.iaga import IagaRecord

__all__ = ["StationDeviation", "di_shift_deg", "eq64_dbh_nt", "quiet_baseline", "station_deviation"]


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
