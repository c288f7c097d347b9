"""The storm disturbance field (dn, de, dd) in nT: station deviations interpolated linearly in
time and by inverse-distance weighting (power 2, great-circle angle) in space.

Exact at each station, a convex combination of the stations elsewhere, smooth (no kinks in
the D/I gradients); see :mod:`sitl.storms` for the choice of IDW over kriging.
"""
from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from sitl.storms.common import DEFAULT_STATIONS, QUIET_BASELINE, FloatArray, StormWindow, _iso
from sitl.storms.deviation import StationDeviation, eq64_dbh_nt, station_deviation
from sitl.storms.iaga import IagaRecord, load_stations

__all__ = ["StormDisturbance"]

_EXACT_RAD = 1e-10  # query within ~0.6 mm of a station: take the station value exactly


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
