"""Predict before flying: what this route and this vehicle can reach (issue 46, item 7).

Two questions, answered from the navigator's own configuration and map before the mission:

1. **Which directions can the field see?** Along the start-destination geodesic, the gradients of
   the elements the navigator will measure (which depends on the declared heading source: a
   compass-derived yaw leaves (I, F)), whitened by their declared noise (FUS_R_DEG, FUS_R_NT).
   Where two elements' gradients are nearly parallel, the position across their common gradient
   is dead reckoning: the angle between them, and the weakest direction's bearing, are reported.

2. **How far off will it arrive?** The navigator's own covariance analysis: the mission
   (:class:`companion.nav.mission.Mission`, the same step the vehicle runs) flown along its own
   commands in a nominal world where the vehicle goes where it is told and every period's
   measurement is the map's value at the centre of its window, with the declared noise (the
   local model-error states at the route's crustal strength, :mod:`companion.nav.crust`: the
   filter's own value, from the same function). The measurements then never surprise the
   filter, so its covariance is what it would be on a quiet
   day on this route; its value at arrival, as a radius holding 95 % of a Gaussian with that
   covariance, is the prediction. A disturbed day, a storm or a map that is worse than the
   filter declares make the real miss larger: the Monte Carlo checks how often the bound holds
   (``fcmpc-montecarlo`` prints it per preset).

Nothing here reads a clock, a socket or a file.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.nav.elements import ElementSet, element_set, resolve_elements
from companion.nav.fix import element_values_and_gradient
from companion.nav.geo import geodesic_direct, geodesic_distance_m, geodesic_inverse
from companion.nav.period import PeriodAverage
from companion.nav.step_io import Phase

__all__ = ["RoutePrediction", "predict_route", "radius95_m", "UNOBSERVABLE_DEG"]

UNOBSERVABLE_DEG = 10.0   # gradients closer than this: across them the position is dead reckoning
_DRAWS = 200_000          # Gaussian draws for the 95 % radius (deterministic: a fixed seed)


@dataclass(frozen=True)
class RoutePrediction:
    """What :func:`predict_route` found. Angles in degrees, distances in metres."""

    elements: str                   # the element set the navigator will measure, e.g. "(I, F)"
    gradient_angle_min_deg: float   # along the route, the smallest angle between the best-separated pair of gradients
    gradient_angle_median_deg: float
    weakest_bearing_deg: float      # the direction (from north, clockwise, mod 180) seen least, at the worst point
    arrival_sigma_m: float          # the navigator's 1-sigma per axis at arrival, sqrt((ee + nn) / 2)
    arrival_r95_m: float            # radius holding 95 % of the arrival covariance
    arrival_cov_en_m2: tuple[float, float, float]   # ee, en, nn
    steps: int
    completed: bool                 # the nominal mission arrived (False: it failed or ran out of steps)
    reason: str = ""
    local_scale: float = 1.0        # the route's crust on the local model-error states (companion.nav.crust)

    @property
    def unobservable(self) -> bool:
        return self.gradient_angle_min_deg < UNOBSERVABLE_DEG

    def lines(self) -> list[str]:
        """The prediction in a few short lines (each fits a STATUSTEXT's 50 characters with a prefix)."""
        out = [f"elements {self.elements}, gradients {self.gradient_angle_min_deg:.0f}-"
               f"{self.gradient_angle_median_deg:.0f} deg apart"]
        if self.local_scale > 1.0:
            out.append(f"strong crust: map error x{self.local_scale:.2f}")
        if self.completed:
            out.append(f"predicted miss {self.arrival_sigma_m / 1e3:.1f} km 1-sigma per axis, "
                       f"95 % within {self.arrival_r95_m / 1e3:.1f} km")
        else:
            out.append(f"no prediction: {self.reason}")
        if self.unobservable:
            out.append(f"warning: position across {self.weakest_bearing_deg:.0f} deg is dead reckoning")
        return out


def radius95_m(cov_en_m2: tuple[float, float, float]) -> float:
    """Radius of the circle holding 95 % of a zero-mean Gaussian with covariance (ee, en, nn).

    >>> round(radius95_m((1.0, 0.0, 1.0)), 2)   # isotropic: sqrt(chi2_2(0.95)) = 2.45
    2.45
    >>> round(radius95_m((1.0, 0.0, 1e-12)), 2)  # one axis: 1.96
    1.96
    """
    ee, en, nn = cov_en_m2
    lam = np.linalg.eigvalsh(np.array([[ee, en], [en, nn]]))
    if not np.isfinite(lam).all():
        return math.nan
    z = np.random.default_rng(0).standard_normal((_DRAWS, 2))
    r2 = np.maximum(lam[0], 0.0) * z[:, 0] ** 2 + np.maximum(lam[1], 0.0) * z[:, 1] ** 2
    return float(math.sqrt(np.quantile(r2, 0.95)))


def _whitened_gradient(model, elements: ElementSet, lat: float, lon: float, alt_m: float, year: float,
                       r_deg: float, r_nt: float) -> np.ndarray:
    _, g = element_values_and_gradient(model, elements, lat, lon, alt_m, year)
    scale = np.array([1.0 / (r_deg if name.endswith("_deg") else r_nt) for name in elements.names])
    return g * scale[:, None]


def _angles(gw: np.ndarray) -> tuple[float, float]:
    """The angle between the best-separated pair of element gradients (0: all parallel, 90: at
    right angles; a third element helps only if it is apart from the others), and the bearing of
    the direction the whitened gradient sees least."""
    rows = [r / np.linalg.norm(r) for r in gw if np.linalg.norm(r) > 0.0]
    best = 0.0
    for i in range(len(rows)):
        for j in range(i + 1, len(rows)):
            best = max(best, math.degrees(math.acos(min(1.0, abs(float(rows[i] @ rows[j]))))))
    _, _, vt = np.linalg.svd(gw)
    east, north = vt[-1]
    return best, math.degrees(math.atan2(east, north)) % 180.0


def predict_route(config, model=None, *, compass_derived: bool, has_ins: bool,
                  start_sigma_m: float | None = None, samples: int = 41) -> RoutePrediction:
    """Predict the route of ``config`` (a :class:`companion.nav.config.NavConfig`) for a vehicle whose
    yaw is (not) ``compass_derived`` and which does (not) carry an independent INS position.
    ``model``: the navigator's map (None: the one the mission picks). ``start_sigma_m``: the
    start fix's 1-sigma (None: ``config.gps_sigma_m``)."""
    from companion.nav.mission import Mission
    from companion.nav.navigator import Navigator

    config = config.replace(elements=resolve_elements(config.elements, compass_derived))
    mission = Mission(config, model)
    model = mission.model
    measured = element_set(config.elements)
    c = config
    start, dest = (c.start_lat_deg, c.start_lon_deg), (c.dest_lat_deg, c.dest_lon_deg)
    angles, worst = [], (90.0, math.nan)
    length_m, azimuth = geodesic_inverse(*start, *dest)
    for f in np.linspace(0.0, 1.0, samples):
        lat, lon = geodesic_direct(*start, azimuth, float(f) * length_m)
        gw = _whitened_gradient(model, measured, lat, lon, c.alt_m, c.year, c.filter.r_deg, c.filter.r_nt)
        angle, bearing = _angles(gw)
        angles.append(angle)
        if angle <= worst[0]:
            worst = (angle, bearing)

    mission.set_start_fix(c.gps_sigma_m if start_sigma_m is None else start_sigma_m)
    lat, lon = start
    t, window, course, speed = 0.0, c.period_s, 0.0, 0.0
    navigator = Navigator(mission)   # the vehicle's own step, its plausibility judge included
    cmd = navigator.step(_nominal(model, c, lat, lon, lat, lon, t, window, course, has_ins)).command
    periods = 1
    while not cmd.done and cmd.step < c.max_steps and periods < 2 * c.max_steps:
        course, speed = cmd.course_rad, cmd.speed_mps
        d = speed * c.period_s
        mid = geodesic_direct(lat, lon, course, d / 2.0)
        lat, lon = geodesic_direct(lat, lon, course, d)
        t += c.period_s
        cmd = navigator.step(_nominal(model, c, lat, lon, *mid, t, window, course, has_ins)).command or cmd
        periods += 1
    cov = tuple(float(v) for v in cmd.est_cov_en_m2)
    arrived = cmd.phase == Phase.ARRIVED
    sigma = math.sqrt(0.5 * (cov[0] + cov[2])) if np.isfinite(cov).all() else math.nan
    reason = "" if arrived else (cmd.reason or f"the nominal mission ended {cmd.phase} after {cmd.step} steps")
    if arrived and not math.isfinite(sigma):
        arrived, reason = False, "the navigator gives no covariance (FUS_MODEL 1)"
    return RoutePrediction(measured.label, float(min(angles)), float(np.median(angles)), float(worst[1]),
                           sigma, radius95_m(cov) if arrived else math.nan, cov, cmd.step, arrived,
                           reason + (f" ({geodesic_distance_m(lat, lon, *dest) / 1e3:.1f} km to go)" if reason else ""),
                           mission.estimator.local_scale if mission.estimator is not None else 1.0)


def _nominal(model, c, lat: float, lon: float, mid_lat: float, mid_lon: float, t: float, window: float,
             course_rad: float, has_ins: bool):
    """The period in the nominal world: the map at the window's centre, declared noise (no measured
    standard errors), as a :class:`companion.nav.navigator.Period`."""
    from companion.nav.navigator import Period

    e = model.elements(mid_lat, mid_lon, c.alt_m, c.year)
    decl = float(e.decl_deg)
    heading = (math.degrees(course_rad) - decl) % 360.0
    ins = (lat, lon) if has_ins else (math.nan, math.nan)
    average = PeriodAverage(decl, float(e.incl_deg), 1, t - 0.5 * window, t - window, t, f_nt=float(e.f_nt),
                            mag_heading_deg=heading)
    return Period(t, average, window, *ins)
