"""The route's crustal strength, read from a map the vehicle carries, and the local-error scale it sets.

The local model-error states (:mod:`companion.nav.local_error`, FUS_GM_DEG / FUS_GM_NT) and the
biases' per-distance walk (FUS_BQD_DEG / FUS_BQD_NT) stand for what the map misses along the
route: mostly the crust's wavelengths shorter than the map's. Their strength was set on the
Pacific route, over ocean floor; over continental crust (the Tasman route crosses the
Lord Howe Rise) the map misses about twice as much, and a filter that declares the Pacific's
strength there is over-confident (issue 46.7).

What a vehicle can know of the crust before flying is a published model of it. WMMHR-2025
(NOAA NCEI, degree 133, shipped with pygeomag: the map of NAV_MAP 1, and on the vehicle whichever
map the fixes use) holds the crust's long wavelengths, degrees 16-133 (about 300-2500 km). The crust's amplitude is a regional
property (continental crust is thicker and more magnetic than ocean floor at every wavelength),
so the strength of those degrees along the route stands for the strength of the unresolved ones
too. The route's crustal strength is the rms, over the start-destination geodesic, of the field
vector of WMMHR-2025's degrees 16-133 (nT): 48 nT on the Pacific route (33N 152E -> 28N 158E),
84 nT on the Tasman route (40S 160E -> 36S 168E). FUS_GM_CRUST is the strength at which FUS_GM_DEG
and FUS_GM_NT hold, and the biases' per-distance walk FUS_BQD_DEG / FUS_BQD_NT (what the map misses
at the longer wavelengths, 51-300 km for WMMHR); a stronger route scales all four by its strength
over FUS_GM_CRUST, a weaker one keeps them (a weak long-wavelength crust does not promise a weak short-wavelength one:
along the route off Japan, WMMHR's band is half the Pacific's while the map's error is twice it).

A mission dated before WMMHR-2025's release (2024.87) could not have carried it: no scaling.
The truth's crust (EMM2017 in the simulated world) is never read here. Nothing here reads a
clock, a socket or a file other than the shipped coefficients.

>>> round(route_crust_rms_nt(33.0, 152.0, 28.0, 158.0, 0.0), 0)   # the Pacific route, nT
48.0
"""
from __future__ import annotations

import functools
import math

import numpy as np

from companion.nav.geo import geodesic_direct, geodesic_inverse
from companion.nav.wmm import load_wmm

__all__ = ["CRUST_DEGREES", "CRUST_MAP", "local_error_scale", "route_crust_rms_nt"]

CRUST_MAP = "WMMHR2025"
CRUST_DEGREES = (16, 133)   # the crust's part of WMMHR-2025 (degrees 1-15 are the core's)
_SAMPLES = 41               # points along the geodesic (every ~20 km on an 800 km route)


@functools.cache
def _crust_model():
    return load_wmm(CRUST_MAP).band(*CRUST_DEGREES)


@functools.lru_cache(maxsize=32)
def route_crust_rms_nt(start_lat_deg: float, start_lon_deg: float, dest_lat_deg: float, dest_lon_deg: float,
                       alt_m: float) -> float:
    """Rms (nT) along the geodesic start -> destination of the field vector of WMMHR-2025's
    degrees 16-133 at ``alt_m`` (the crust's long wavelengths; static, so any date)."""
    length_m, azimuth = geodesic_inverse(start_lat_deg, start_lon_deg, dest_lat_deg, dest_lon_deg)
    points = np.array([geodesic_direct(start_lat_deg, start_lon_deg, azimuth, f * length_m)
                       for f in np.linspace(0.0, 1.0, _SAMPLES)])
    model = _crust_model()
    x, y, z = model.ned(points[:, 0], points[:, 1], float(alt_m), model.epoch)
    return float(math.sqrt(np.mean(x * x + y * y + z * z)))


def local_error_scale(config) -> float:
    """The factor (>= 1) on the local model-error states' sigmas (FUS_GM_DEG, FUS_GM_NT) and the
    biases' per-distance walk (FUS_BQD_DEG, FUS_BQD_NT) for the mission of ``config`` (a :class:`companion.nav.config.NavConfig`): the route's crustal strength
    over FUS_GM_CRUST, or 1 with FUS_GM_CRUST 0, without local states, or before WMMHR-2025 existed.
    The filter (:class:`companion.nav.estimator.PositionEstimator`) and the pre-flight prediction
    (:mod:`companion.nav.prediction`, through the same estimator) both take it from here."""
    bias = config.filter.bias
    if bias.local_crust_nt <= 0.0 or not bias.has_local or config.year < load_wmm(CRUST_MAP).valid_from:
        return 1.0
    rms = route_crust_rms_nt(float(config.start_lat_deg), float(config.start_lon_deg), float(config.dest_lat_deg),
                             float(config.dest_lon_deg), float(config.alt_m))
    return max(1.0, rms / bias.local_crust_nt) if math.isfinite(rms) else 1.0
