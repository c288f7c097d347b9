"""The reference path: the start-to-destination geodesic, the paper's "shortest trajectory".

Fc-MPC aims at a point a fixed distance ahead on this path (like ArduPilot's L1 guidance)
instead of at the destination itself, so an estimate error at one step is steered back to
the path at the next instead of shifting the rest of the track.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from geographiclib.geodesic import Geodesic

from companion.nav.geo import WGS84, metres_per_degree

__all__ = ["COARSE", "ReferencePath", "coarse_indices", "sampled_geodesic"]

COARSE = 16    # the nearest sample is searched among every 16th first, then beside it


def coarse_indices(count: int) -> np.ndarray:
    """Every :data:`COARSE`-th index of ``count`` samples, and the last: where a two-step nearest
    search looks first (along a gently curved path the distance is unimodal in the index, so the
    nearest sample lies within ``COARSE`` of the nearest of these)."""
    return np.unique(np.append(np.arange(0, count, COARSE), count - 1))


@lru_cache(maxsize=16)
def sampled_geodesic(lat0: float, lon0: float, lat1: float, lon1: float, spacing_m: float):
    """(length m, along m, lat deg, lon deg) of the geodesic sampled every ``spacing_m`` or less,
    read-only arrays. Cached: sampling a 799 km route costs 3200 geodesic positions (~0.1 s),
    and every mission of a Monte Carlo flies the same route (and its metrics measure against it)."""
    line = WGS84.InverseLine(lat0, lon0, lat1, lon1)
    count = max(2, math.ceil(line.s13 / spacing_m) + 1)
    along = np.linspace(0.0, line.s13, count)
    points = [line.Position(s, Geodesic.LATITUDE | Geodesic.LONGITUDE) for s in along]
    lat = np.array([p["lat2"] for p in points])
    lon = np.array([p["lon2"] for p in points])
    for array in (along, lat, lon):
        array.setflags(write=False)
    return line.s13, along, lat, lon


class ReferencePath:
    """The geodesic sampled every ``spacing_m`` metres; nearest point and lookahead point."""

    def __init__(self, start: tuple[float, float], dest: tuple[float, float], spacing_m: float = 250.0) -> None:
        self.length_m, self.along_m, self.lat_deg, self.lon_deg = sampled_geodesic(
            float(start[0]), float(start[1]), float(dest[0]), float(dest[1]), float(spacing_m))
        self._coarse = coarse_indices(len(self.lat_deg))

    def nearest_index(self, lat_deg: float, lon_deg: float) -> int:
        """Index of the sample nearest to a position (local metric; exact enough at 250 m spacing),
        in two small searches (:func:`coarse_indices`) instead of one over the whole path (the
        same index; tested)."""
        east_per_deg, north_per_deg = metres_per_degree(lat_deg)
        coarse = self._coarse
        rough = int(coarse[np.argmin(self._distance2(coarse, lat_deg, lon_deg, east_per_deg, north_per_deg))])
        near = np.arange(max(0, rough - COARSE), min(len(self.lat_deg), rough + COARSE + 1))
        return int(near[np.argmin(self._distance2(near, lat_deg, lon_deg, east_per_deg, north_per_deg))])

    def _distance2(self, index: np.ndarray, lat_deg: float, lon_deg: float, east_per_deg: float,
                   north_per_deg: float) -> np.ndarray:
        d_east = ((self.lon_deg[index] - lon_deg + 180.0) % 360.0 - 180.0) * east_per_deg
        d_north = (self.lat_deg[index] - lat_deg) * north_per_deg
        return d_east * d_east + d_north * d_north

    def aim_point(self, lat_deg: float, lon_deg: float, lookahead_m: float) -> tuple[float, float]:
        """The path point ``lookahead_m`` beyond the one nearest to the position (the end at most)."""
        along = self.along_m[self.nearest_index(lat_deg, lon_deg)] + lookahead_m
        index = min(int(np.searchsorted(self.along_m, along)), len(self.along_m) - 1)
        return float(self.lat_deg[index]), float(self.lon_deg[index])
