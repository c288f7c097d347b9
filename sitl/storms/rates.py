"""How fast a storm's disturbance moves where the vehicle flies: the rms change per sqrt(hour)
of each field component, the rate a navigator declares for its bias states' active walk
(``FUS_BQA_N``, ``FUS_BQA_E``, ``FUS_BQA_Z``; :mod:`companion.nav.disturbance`).

For a random walk the rms change over a lag ``tau`` is ``q sqrt(tau)``; so
``q = rms(dB(t + tau) - dB(t)) / sqrt(tau)``, taken over the mission along the straight route
from start to destination at the cruise speed, in *mission* time: a storm window compressed onto
the mission (the paper's overlay) moves more slowly than the storm did. :func:`component_rates`
takes a lag of one hour by default; the walks a navigator declares (:func:`component_walks`) and
their correlations are of one control step's change.

>>> import numpy as np
>>> ramp = lambda lat, lon, t: np.stack([t / 360.0, 0 * t, 0 * t], axis=-1)   # dN: 10 nT per hour
>>> [round(float(v), 1) for v in component_rates(ramp, (30.0, 150.0), (30.0, 151.0), 7200.0)]
[10.0, 0.0, 0.0]
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["FIT_LAGS_H", "MAY_REVERT", "RATE_LAG_S", "STEP_LAG_S", "component_correlations", "component_rates",
           "component_walks", "structure_function"]

RATE_LAG_S = 3600.0
# one control step (NAV_PERIOD_S's default): the filter's noise is per step, so the walks' rates and
# correlations are those of one step's change
STEP_LAG_S = 360.0
FIT_LAGS_H = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0)   # lags of the structure function a walk is fitted to
MEAN_REVERTING = 0.25   # a component is Gauss-Markov when its fitted correlation time is below this share of the mission


def _route_samples(storm_ned_nt: Callable, start_deg: tuple[float, float], dest_deg: tuple[float, float],
                   duration_s: float, sample_s: float) -> np.ndarray:
    """(dN, dE, dZ) every ``sample_s`` along the straight route flown in ``duration_s`` mission seconds."""
    t = np.arange(0.0, duration_s + 0.5 * sample_s, sample_s)
    frac = t / duration_s
    lat = start_deg[0] + frac * (dest_deg[0] - start_deg[0])
    lon = start_deg[1] + frac * (dest_deg[1] - start_deg[1])
    return np.asarray(storm_ned_nt(lat, lon, t), dtype=float)


def _lag_steps(lag_s: float, sample_s: float, count: int, duration_s: float) -> int:
    k = int(round(lag_s / sample_s))
    if not 0 < k < count:
        raise ValueError(f"lag {lag_s:g} s does not fit a {duration_s:g} s mission")
    return k


def structure_function(storm_ned_nt: Callable, start_deg: tuple[float, float], dest_deg: tuple[float, float],
                       duration_s: float, lags_s: np.ndarray, sample_s: float = 60.0) -> np.ndarray:
    """Mean squared change of (dN, dE, dZ) over each lag (rows) along the straight route flown in
    ``duration_s`` mission seconds (nT^2), the disturbance as in :func:`component_rates`."""
    ned = _route_samples(storm_ned_nt, start_deg, dest_deg, duration_s, sample_s)
    rows = []
    for lag in lags_s:
        k = _lag_steps(lag, sample_s, len(ned), duration_s)
        rows.append(np.mean((ned[k:] - ned[:-k]) ** 2, axis=0))
    return np.array(rows)


def component_correlations(storm_ned_nt: Callable, start_deg: tuple[float, float], dest_deg: tuple[float, float],
                           duration_s: float, lag_s: float = STEP_LAG_S,
                           sample_s: float = 60.0) -> tuple[float, float, float]:
    """Correlation (N-E, N-Z, E-Z) of the components' changes over ``lag_s`` along the route, the
    disturbance as in :func:`component_rates`: the ``FUS_BQA_RNE/RNZ/REZ`` a navigator declares.
    Taken about zero, as the walks are (a change's mean is part of its walk).

    >>> import numpy as np
    >>> together = lambda lat, lon, t: np.stack([np.sin(t / 900.0), -2.0 * np.sin(t / 900.0), 0 * t + 1.0], axis=-1)
    >>> [round(v, 3) for v in component_correlations(together, (30.0, 150.0), (30.0, 151.0), 7200.0)]
    [-1.0, 0.0, 0.0]
    """
    ned = _route_samples(storm_ned_nt, start_deg, dest_deg, duration_s, sample_s)
    k = _lag_steps(lag_s, sample_s, len(ned), duration_s)
    change = ned[k:] - ned[:-k]
    second = change.T @ change / len(change)
    scale = np.sqrt(np.diag(second))
    scale = np.where(scale > 0.0, scale, 1.0)   # a component that never changes correlates with nothing
    r = second / np.outer(scale, scale)
    return float(r[0, 1]), float(r[0, 2]), float(r[1, 2])


#: Which components may revert: the east, from field-aligned and ionospheric currents that come
#: and go. The meridian-plane components carry the ring current, which builds over a main phase
#: and decays over days: a random walk (measured: the long storm's dZ fitted as Gauss-Markov,
#: tau 1.5 h, cost 1.7 km median, 50 seeds, its -30 to -66 nT held for hours).
MAY_REVERT = (False, True, False)


def component_walks(storm_ned_nt: Callable, start_deg: tuple[float, float], dest_deg: tuple[float, float],
                    duration_s: float, may_revert: tuple[bool, bool, bool] = MAY_REVERT,
                    step_s: float = STEP_LAG_S) -> tuple[np.ndarray, np.ndarray]:
    """The walk of each component (dN, dE, dZ) a navigator declares: short-lag rate ``q`` (nT per
    sqrt(hour)) and correlation time ``tau`` (hours, 0: random walk); only the components of
    ``may_revert`` are fitted as Gauss-Markov.

    ``q`` is the rms change over one control step ``step_s`` per sqrt(hour): the filter's noise is
    per step. A storm's disturbance is smoother over a step than over hours (the short storm's
    north, SYM-H removed: 33.7 nT/rt(h) over 6 min, 47.4 over 1 h), and the walk at the hourly rate
    made the filter conservative (NEES 1.27) and its miss larger (5.05 against 3.53 km, 50 seeds;
    long storm 3.00 against 2.87).

    Whether and how fast a component reverts (``tau``) comes from the structure function ``D(lag)``
    over :data:`FIT_LAGS_H` (those that leave a third of the mission's samples to compare), fitted
    by a first-order Gauss-Markov process, ``D = 2 s^2 (1 - exp(-lag / tau))`` (least squares on
    the relative error, ``tau`` on a log grid from 0.05 h to ten missions, ``s^2`` in closed form).
    Where the fitted ``tau`` is not below a quarter of the mission the component does not revert on
    the mission's scale: a random walk."""
    lags_h = np.array([lag for lag in FIT_LAGS_H if lag * 3600.0 <= duration_s * 2.0 / 3.0])
    _check_lag(duration_s, step_s)
    # the fit's lags and the step's from one sampling of the route
    d_all = structure_function(storm_ned_nt, start_deg, dest_deg, duration_s,
                               np.append(lags_h * 3600.0, step_s))
    d, q = d_all[:-1], np.sqrt(d_all[-1]) / np.sqrt(step_s / 3600.0)
    tau = np.zeros(3)
    grid = np.geomspace(0.05, 10.0 * duration_s / 3600.0, 400)   # up to ten missions: a random walk fits there
    for c in np.flatnonzero(may_revert):
        weight = 1.0 / np.maximum(d[:, c], 1e-12) ** 2
        shape = 1.0 - np.exp(-lags_h[None, :] / grid[:, None])                # (grid, lags)
        s2 = (shape * weight * d[:, c]).sum(axis=1) / (shape * shape * weight).sum(axis=1)
        error = ((d[:, c] - s2[:, None] * shape) ** 2 * weight).sum(axis=1)
        best = int(np.argmin(error))
        if grid[best] < MEAN_REVERTING * duration_s / 3600.0:
            tau[c] = grid[best]
    return np.asarray(q, dtype=float), tau


def component_rates(storm_ned_nt: Callable, start_deg: tuple[float, float], dest_deg: tuple[float, float],
                    duration_s: float, lag_s: float = RATE_LAG_S, sample_s: float = 60.0) -> np.ndarray:
    """rms change per sqrt(hour) of (dN, dE, dZ) in nT over ``lag_s``, along the straight route from
    ``start_deg`` to ``dest_deg`` (lat, lon) flown in ``duration_s`` mission seconds;
    ``storm_ned_nt(lat, lon, elapsed_s)`` is the disturbance, shape ``(..., 3)``, at mission time
    (:meth:`sitl.world.magnetic.TruthField.storm_ned_nt`)."""
    _check_lag(duration_s, lag_s)
    d = structure_function(storm_ned_nt, start_deg, dest_deg, duration_s, np.array([lag_s]), sample_s)[0]
    return np.sqrt(d) / np.sqrt(lag_s / 3600.0)


def _check_lag(duration_s: float, lag_s: float) -> None:
    if not duration_s > lag_s:
        raise ValueError(f"component_rates: a {duration_s:g} s mission is no longer than the {lag_s:g} s lag")
