"""Evaluation metrics of Section 4.1 (eq. 59-63), on WGS84 (geographiclib; step lengths by
Vincenty's iteration, within 0.1 mm of it).

Definitions where the paper leaves room (stated once here, used by every table):

* Path deviation (eq. 60-61): for each iteration's position, the distance to the *shortest
  trajectory* -- the geodesic from start to destination -- measured as the distance to its
  nearest point (cross-track distance), in metres. The paper's ``|d_i - d_hat_i|`` pairs the
  i-th position with "the i-th step of the shortest trajectory"; pairing by index would also
  count along-track lag, which is a speed difference, not a deviation from the path.
* Path matching rate (eq. 62): the share of iteration positions within ``PMR_TOLERANCE_M`` of
  the geodesic, in percent.
* CEP (eq. 59) exactly as printed: ``sqrt(1/N sum d_i^2 I(d_i <= d_50))`` -- note the 1/N
  over *all* runs. The standard CEP50 (the median miss distance) is reported beside it.
* Percentiles (the p90 miss of every table, a latency's p99): the nearest rank, the
  ``ceil(q N)``-th smallest value (:func:`percentile`), an observed value and no interpolation.
  The median (CEP50) stays the usual middle value: the mean of the two middle ones for even N.
* Step variance (eq. 63): sample variance (1/(n-1)) of the step lengths, in m^2.
* Trajectory length: the sum of the geodesic lengths between consecutive iteration positions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from companion.nav.geo import WGS84, geodesic_distance_m, geodesic_inverse
from companion.nav.reference import COARSE, coarse_indices, sampled_geodesic

__all__ = [
    "PMR_TOLERANCE_M",
    "TrackMetrics",
    "track_metrics",
    "cep_paper",
    "cep50",
    "percentile",
    "mean_terminal_location",
    "path_deviation_m",
    "step_lengths_m",
]

PMR_TOLERANCE_M = 300.0
_GEODESIC_SAMPLE_M = 250.0
_WINDOW = 3          # segments either side of the nearest vertex searched exactly
_CHUNK = 64          # points per block of the nearest-vertex search


def _ecef(lat_deg, lon_deg) -> np.ndarray:
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    e2 = WGS84.f * (2.0 - WGS84.f)
    n = WGS84.a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    return np.stack([n * np.cos(lat) * np.cos(lon), n * np.cos(lat) * np.sin(lon), n * (1.0 - e2) * np.sin(lat)], -1)


@lru_cache(maxsize=16)
def _geodesic_polyline(start: tuple[float, float], dest: tuple[float, float]) -> np.ndarray:
    """ECEF vertices (m) of the start->destination geodesic sampled every ~250 m (the reference
    path's samples, :func:`companion.nav.reference.sampled_geodesic`), read-only, once per route
    and process."""
    _, _, lat, lon = sampled_geodesic(start[0], start[1], dest[0], dest[1], _GEODESIC_SAMPLE_M)
    poly = _ecef(lat, lon)
    poly.flags.writeable = False
    return poly


def path_deviation_m(lat_deg, lon_deg, start: tuple[float, float], dest: tuple[float, float]) -> np.ndarray:
    """Distance (m) from each position to the start->destination geodesic (nearest point).

    The geodesic is a polyline of ~250 m chords in 3-D (< 1 mm from the curve here). Along such
    a gently curved line the distance from a point is unimodal, so its nearest segment touches
    the nearest vertex: each point is measured exactly against the :data:`_WINDOW` segments on
    either side of that vertex instead of against all of them (the same minimum; tested against
    the full search). For the same reason the nearest vertex is found in two small searches
    (:func:`companion.nav.reference.coarse_indices`) instead of one over the whole polyline."""
    poly = _geodesic_polyline((float(start[0]), float(start[1])), (float(dest[0]), float(dest[1])))
    points = _ecef(np.asarray(lat_deg, dtype=float), np.asarray(lon_deg, dtype=float)).reshape(-1, 3)
    origin = poly[0]                     # relative coordinates: squares of <= 1e7 m, no cancellation
    rel_poly, rel_points = poly - origin, points - origin
    coarse_index = coarse_indices(len(poly))
    coarse = rel_poly[coarse_index]
    nearest = np.empty(len(points), dtype=int)
    for first in range(0, len(points), _CHUNK):   # chunks keep the (points x vertices) matrix small
        diff = rel_points[first:first + _CHUNK, None, :] - coarse[None, :, :]
        nearest[first:first + _CHUNK] = coarse_index[np.argmin(np.einsum("pvk,pvk->pv", diff, diff), axis=1)]
    near = np.clip(nearest[:, None] + np.arange(-COARSE, COARSE + 1)[None, :], 0, len(poly) - 1)
    diff = rel_poly[near] - rel_points[:, None, :]
    nearest = near[np.arange(len(points)), np.argmin(np.einsum("pvk,pvk->pv", diff, diff), axis=1)]
    seg_index = np.clip(nearest[:, None] + np.arange(-_WINDOW, _WINDOW)[None, :], 0, len(poly) - 2)
    a, b = rel_poly[seg_index], rel_poly[seg_index + 1]           # (points, 2 _WINDOW, 3)
    seg = b - a
    seg_len2 = np.einsum("pwk,pwk->pw", seg, seg)
    t = np.clip(np.einsum("pwk,pwk->pw", rel_points[:, None, :] - a, seg) / seg_len2, 0.0, 1.0)
    gap = a + seg * t[:, :, None] - rel_points[:, None, :]
    return np.sqrt(np.min(np.einsum("pwk,pwk->pw", gap, gap), axis=1))


def step_lengths_m(lat_deg, lon_deg) -> np.ndarray:
    """Geodesic length (m) of each step between consecutive positions (Vincenty's iteration,
    within 0.1 mm of geographiclib; :func:`companion.nav.geo.geodesic_inverse`)."""
    lat, lon = np.asarray(lat_deg, dtype=float).tolist(), np.asarray(lon_deg, dtype=float).tolist()
    return np.array([geodesic_inverse(lat[i], lon[i], lat[i + 1], lon[i + 1])[0] for i in range(len(lat) - 1)])


@dataclass(frozen=True)
class TrackMetrics:
    """Per-run metrics, SI (metres, m^2)."""

    iterations: int
    length_m: float
    step_variance_m2: float
    mean_deviation_m: float
    max_deviation_m: float
    path_matching_rate_pct: float
    remaining_m: float
    final_lat_deg: float
    final_lon_deg: float


def track_metrics(lat_deg, lon_deg, start: tuple[float, float], dest: tuple[float, float],
                  iterations: int | None = None) -> TrackMetrics:
    """Metrics of one trajectory (positions at each iteration, start included)."""
    lat, lon = np.asarray(lat_deg, dtype=float), np.asarray(lon_deg, dtype=float)
    steps = step_lengths_m(lat, lon)
    deviation = path_deviation_m(lat, lon, start, dest)
    return TrackMetrics(
        iterations=int(iterations if iterations is not None else len(steps)),
        length_m=float(steps.sum()),
        step_variance_m2=float(np.var(steps, ddof=1)) if len(steps) > 1 else 0.0,
        mean_deviation_m=float(deviation.mean()),
        max_deviation_m=float(deviation.max()),
        path_matching_rate_pct=float(100.0 * np.mean(deviation <= PMR_TOLERANCE_M)),
        remaining_m=geodesic_distance_m(lat[-1], lon[-1], dest[0], dest[1]),
        final_lat_deg=float(lat[-1]),
        final_lon_deg=float(lon[-1]),
    )


def cep_paper(miss_m) -> float:
    """Eq. 59 exactly as printed: sqrt(1/N * sum(d_i^2 for d_i <= median))."""
    d = np.asarray(miss_m, dtype=float)
    return float(np.sqrt(np.sum(np.where(d <= np.median(d), d**2, 0.0)) / len(d)))


def cep50(miss_m) -> float:
    """Standard CEP50: the median miss distance."""
    return float(np.median(np.asarray(miss_m, dtype=float)))


def percentile(values, q: float) -> float:
    """The ``q``-quantile (0 < q <= 1) by the nearest rank: the ``ceil(q N)``-th smallest of the N
    values (NaN for none).

    >>> percentile([3.0, 1.0, 2.0], 0.5), percentile(range(1, 11), 0.9), percentile([], 0.9)
    (2.0, 9, nan)
    """
    ordered = sorted(values)
    if not ordered:
        return math.nan
    return ordered[min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))]


def mean_terminal_location(lat_deg, lon_deg) -> tuple[float, float]:
    """Average terminal latitude and longitude (Section 4.1.1), longitudes averaged on the circle."""
    lat, lon = np.asarray(lat_deg, dtype=float), np.radians(np.asarray(lon_deg, dtype=float))
    return float(lat.mean()), float(np.degrees(np.arctan2(np.sin(lon).mean(), np.cos(lon).mean())))
