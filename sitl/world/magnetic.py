"""The true magnetic field the simulated vehicle flies through: main field + crust + storm.

``TruthField`` sums a main-field model (the navigator's own WMM in the paper's ideal world,
IGRF-14 in the realistic one: :mod:`sitl.world.igrf`), the real crust along the route (EMM2017
degrees 16-790 on a grid, :mod:`sitl.world.emm`; the realistic default), an optional seeded
small-scale anomaly field (:mod:`sitl.world.crustal`) and an optional time-varying storm disturbance
(:mod:`sitl.storms`). The Monte Carlo and the MAVLink simulator both read the field here, so
each part changes what either sees in the same way.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from companion.nav.field import WorldMagneticModel
from sitl.world.crustal import CrustalConfig, CrustalField
from sitl.world.emm import CrustGrid

__all__ = ["Disturbance", "TruthField", "decl_incl_from_ned", "CRUSTAL_SEED_KEY", "QUIET_INDEX", "quiet_index"]

CRUSTAL_SEED_KEY = 0x63727374
"""Second word of the crustal field's seed ``[seed, CRUSTAL_SEED_KEY]``: its own stream."""
QUIET_INDEX = 0.0   # Kp and SYM-H (nT) of a field nothing disturbs


def quiet_index(posix_s: float) -> float:
    """A space-weather index of a world without a storm: :data:`QUIET_INDEX` at any time."""
    return QUIET_INDEX


class Disturbance(Protocol):
    """A time-varying field disturbance in north/east/down nT (``sitl.storms.StormDisturbance``)."""

    def disturbance_ned_nt(self, lat_deg, lon_deg, time_s): ...


def decl_incl_from_ned(north_nt, east_nt, down_nt) -> tuple[np.ndarray, np.ndarray]:
    """Declination and inclination in degrees of a NED field vector (eq. 2, signs per ``companion``)."""
    horizontal = np.hypot(north_nt, east_nt)
    return np.degrees(np.arctan2(east_nt, north_nt)), np.degrees(np.arctan2(down_nt, horizontal))


@dataclass(frozen=True)
class TruthField:
    """Main field ``model`` at ``year``, plus crust, plus a disturbance at ``storm_time_s(elapsed_s)``.

    ``model`` is the *truth's* main-field model (not necessarily the navigator's).
    ``storm_time_s`` maps mission elapsed seconds onto the disturbance's own time axis (POSIX
    UTC seconds); ``storm_scale`` multiplies the disturbance. ``crust`` is the real crust on the
    route's grid (the same for every seed), or None. ``crustal_config`` and
    ``crustal_origin`` describe the anomaly field; ``crustal`` is its realisation for one seed
    (:meth:`for_seed`). ``space_weather``: the planetary Kp at a storm time (POSIX seconds ->
    Kp, :meth:`sitl.storms.KpRecord.kp_at`), what a space-weather service reports while the
    storm is on (:meth:`kp`); ``ring_current`` the ring-current index likewise (:meth:`symh`: SYM-H, or RC
    for storms without SYM-H). For a storm both are feeds as published
    (:class:`sitl.storms.published.PublishedIndex`: the last interval published by the storm time,
    quick-look errors drawn per run by :meth:`for_seed`).
    """

    model: WorldMagneticModel
    year: float
    disturbance: Disturbance | None = None
    storm_time_s: object = None  # callable elapsed_s -> POSIX seconds, or None
    storm_scale: float = 1.0
    crustal_config: CrustalConfig = CrustalConfig()
    crustal_origin: tuple[float, float] = (0.0, 0.0)
    crustal: CrustalField | None = None
    crust: CrustGrid | None = None
    space_weather: object = None  # callable POSIX seconds -> Kp, or None
    ring_current: object = None   # callable POSIX seconds -> SYM-H nT, or None

    def kp(self, elapsed_s: float) -> float:
        """The planetary Kp a space-weather service gives at this mission time: the storm's own
        (at its storm time, whatever ``storm_scale``), a quiet day's 0 while the world has no
        disturbance, NaN without Kp data or without the feed (``[storm] kp_feed`` false: the
        navigator's innovations alone decide)."""
        return self._storm_index(self.space_weather, elapsed_s)

    def symh(self, elapsed_s: float) -> float:
        """The ring-current index SYM-H (nT) a space-weather service gives at this mission time:
        the storm's own at its storm time, a quiet day's 0 nT while the world has no disturbance,
        NaN without SYM-H data or without the feed (``[storm] symh_feed`` false)."""
        return self._storm_index(self.ring_current, elapsed_s)

    def _storm_index(self, index, elapsed_s: float) -> float:
        """``index`` (POSIX seconds -> value) at this mission time's storm time; NaN without the
        index (no feed); 0 (:func:`quiet_index`) while the world has no disturbance (none, or one
        scaled to nothing): the index of a field nothing disturbs, which is what a service
        reports on a quiet day (Kp 0 to 1, SYM-H within ten or so nT)."""
        if index is None:
            return math.nan
        if self.disturbance is None or self.storm_scale == 0.0:
            return QUIET_INDEX
        return float(index(self._storm_time(elapsed_s)))

    def _storm_time(self, elapsed_s):
        """The storm's own time (POSIX s) at mission time ``elapsed_s``."""
        return self.storm_time_s(elapsed_s) if self.storm_time_s is not None else elapsed_s

    def for_seed(self, seed: int) -> TruthField:
        """The same field with the crustal anomaly drawn for ``seed``, and the space-weather feeds'
        quick-look errors of that run (:meth:`sitl.storms.published.PublishedIndex.for_seed`)."""
        out = self
        feeds = {name: getattr(self, name).for_seed(seed) for name in ("space_weather", "ring_current")
                 if hasattr(getattr(self, name), "for_seed")}
        if feeds:
            out = replace(out, **feeds)
        if not self.crustal_config.enabled:
            return out
        rng = np.random.default_rng([int(seed), CRUSTAL_SEED_KEY])
        return replace(out, crustal=CrustalField.draw(self.crustal_config, rng, *self.crustal_origin))

    def main_ned_nt(self, lat_deg, lon_deg, alt_m) -> np.ndarray:
        """The main-field model alone (..., 3) north/east/down in nT."""
        return np.stack(np.broadcast_arrays(*self.model.ned(lat_deg, lon_deg, alt_m, self.year)), axis=-1)

    def storm_ned_nt(self, lat_deg, lon_deg, elapsed_s) -> np.ndarray | None:
        """The disturbance's part (..., 3) in nT, or None when there is none."""
        if self.disturbance is None or self.storm_scale == 0.0:
            return None
        dn, de, dd = self.disturbance.disturbance_ned_nt(lat_deg, lon_deg, self._storm_time(elapsed_s))
        return self.storm_scale * np.stack(np.broadcast_arrays(dn, de, dd), axis=-1)

    def field_ned_nt(self, lat_deg, lon_deg, alt_m, elapsed_s) -> np.ndarray:
        """True field (..., 3) north/east/down in nT."""
        ned = self.main_ned_nt(lat_deg, lon_deg, alt_m)
        ned = self._add_crust(ned, lat_deg, lon_deg, alt_m)
        storm = self.storm_ned_nt(lat_deg, lon_deg, elapsed_s)
        if storm is not None:
            ned = ned + storm
        return ned

    def point_ned_nt(self, lat_deg: float, lon_deg: float, alt_m: float,
                     elapsed_s: float) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """:meth:`field_ned_nt` at one point as floats, and the main field's part of it, from one
        evaluation of the main field (the simulator's per-step call: without crust or storm no
        array is built, with them the same array sums as :meth:`field_ned_nt`)."""
        x, y, z = self.model.ned(lat_deg, lon_deg, alt_m, self.year)
        main_ned = (float(x), float(y), float(z))
        storm = self.storm_ned_nt(lat_deg, lon_deg, elapsed_s)
        if self.crustal is None and self.crust is None and storm is None:
            return main_ned, main_ned
        ned = self._add_crust(np.array(main_ned), lat_deg, lon_deg, alt_m)
        if storm is not None:
            ned = ned + storm
        return (float(ned[0]), float(ned[1]), float(ned[2])), main_ned

    def crust_ned_nt(self, lat_deg, lon_deg, alt_m) -> np.ndarray:
        """The crust's part (..., 3) in nT: the real crust plus the seeded small-scale field, each
        if the world has it (zeros without either)."""
        shape = np.broadcast_shapes(np.shape(lat_deg), np.shape(lon_deg), np.shape(alt_m))
        return self._add_crust(np.zeros(shape + (3,)), lat_deg, lon_deg, alt_m)

    def _add_crust(self, ned: np.ndarray, lat_deg, lon_deg, alt_m) -> np.ndarray:
        if self.crust is not None:
            ned = ned + self.crust.ned_nt(lat_deg, lon_deg, alt_m)
        if self.crustal is not None:
            ned = ned + self.crustal.ned_nt(lat_deg, lon_deg, alt_m)
        return ned

    def decl_incl_deg(self, lat_deg, lon_deg, alt_m, elapsed_s) -> tuple[np.ndarray, np.ndarray]:
        """True (D, I) in degrees."""
        ned = self.field_ned_nt(lat_deg, lon_deg, alt_m, elapsed_s)
        return decl_incl_from_ned(ned[..., 0], ned[..., 1], ned[..., 2])
