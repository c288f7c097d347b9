"""How fast a storm's disturbance moves where the vehicle flies: the rms change per sqrt(hour)
of each field component, the rate a navigator declares for its bias states' active walk
(``FUS_BQA_N``, ``FUS_BQA_E``, ``FUS_BQA_Z``; :mod:`companion.nav.disturbance`).

For a random walk the rms change over a lag ``tau`` is ``q sqrt(tau)``; so
``q = rms(dB(t + tau) - dB(t)) / sqrt(tau)``, taken over the mission along the straight route
from start to destination at the cruise speed, in *mission* time: a storm window compressed onto
the mission (the paper's overlay) moves more slowly than the storm did. Lag one hour: the
control step is six minutes and the disturbance is judged over hours.

>>> import numpy as np
>>> ramp = lambda lat, lon, t: np.stack([t / 360.0, 0 * t, 0 * t], axis=-1)   # dN: 10 nT per hour
>>> [round(float(v), 1) for v in component_rates(ramp, (30.0, 150.0), (30.0, 151.0), 7200.0)]
[10.0, 0.0, 0.0]
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["RATE_LAG_S", "component_rates"]

RATE_LAG_S = 3600.0


def component_rates(storm_ned_nt: Callable, start_deg: tuple[float, float], dest_deg: tuple[float, float],
                    duration_s: float, lag_s: float = RATE_LAG_S, sample_s: float = 60.0) -> np.ndarray:
    """rms change per sqrt(hour) of (dN, dE, dZ) in nT over ``lag_s``, along the straight route from
    ``start_deg`` to ``dest_deg`` (lat, lon) flown in ``duration_s`` mission seconds;
    ``storm_ned_nt(lat, lon, elapsed_s)`` is the disturbance, shape ``(..., 3)``, at mission time
    (:meth:`sitl.world.magnetic.TruthField.storm_ned_nt`)."""
    if not duration_s > lag_s:
        raise ValueError(f"component_rates: a {duration_s:g} s mission is no longer than the {lag_s:g} s lag")
    t = np.arange(0.0, duration_s + 0.5 * sample_s, sample_s)
    frac = t / duration_s
    lat = start_deg[0] + frac * (dest_deg[0] - start_deg[0])
    lon = start_deg[1] + frac * (dest_deg[1] - start_deg[1])
    ned = np.asarray(storm_ned_nt(lat, lon, t), dtype=float)
    k = int(round(lag_s / sample_s))
    change = ned[k:] - ned[:-k]
    return np.sqrt(np.mean(change ** 2, axis=0)) / np.sqrt(lag_s / 3600.0)
