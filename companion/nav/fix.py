"""Element gradients and the geomagnetic position fix (the paper's eq. 49) on a field model.

* :func:`element_gradient` / :func:`decl_incl_gradient`: the Jacobian ``G = dS/d(east, north)``
  of an element set's S in element units per metre: exact, from the derivatives of the harmonic
  sums at the point (one evaluation; :mod:`companion.nav.harmonics`), or by central differences
  in the local plane when a step is given.
* :func:`element_fix` / :func:`geomagnetic_fix`: the position (lambda_c, phi_c) whose model
  elements equal measured ones, by Newton iteration from a prior.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from companion.nav.elements import ELEMENT_SETS, ElementSet
from companion.nav.geo import offset_position, radii_of_curvature_m
from companion.nav.small import condition2, inverse2, solve2
from companion.nav.wmm import WorldMagneticModel

__all__ = ["PositionFix", "PositionFixError", "decl_incl_gradient", "element_fix", "element_gradient", "fix_covariance",
           "element_values_and_gradient", "geomagnetic_fix"]


def _element_values_and_slopes(names: tuple[str, ...], ned: list[float],
                               slopes: list[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """The elements ``names`` from (X, Y, Z) in nT and their derivatives from those of (X, Y, Z)
    (``slopes``: (east, north) per component), by the chain rule of eq. 1-2:
    ``dD = (X dY - Y dX) / H^2``, ``dI = (H dZ - Z dH) / F^2``, ``dH = (X dX + Y dY) / H``,
    ``dF = (X dX + Y dY + Z dZ) / F``; angles in degrees."""
    x, y, z = ned
    (dxe, dxn), (dye, dyn), (dze, dzn) = slopes
    h = math.hypot(x, y)
    f = math.hypot(h, z)
    dhe, dhn = (x * dxe + y * dye) / h, (x * dxn + y * dyn) / h
    values, rows = [], []
    for name in names:
        if name == "decl_deg":
            k = _DEG / (h * h)
            values.append(math.degrees(math.atan2(y, x)))
            rows.append(((x * dye - y * dxe) * k, (x * dyn - y * dxn) * k))
        elif name == "incl_deg":
            k = _DEG / (f * f)
            values.append(math.degrees(math.atan2(z, h)))
            rows.append(((h * dze - z * dhe) * k, (h * dzn - z * dhn) * k))
        elif name == "f_nt":
            values.append(f)
            rows.append(((x * dxe + y * dye + z * dze) / f, (x * dxn + y * dyn + z * dzn) / f))
        elif name == "h_nt":
            values.append(h)
            rows.append((dhe, dhn))
        elif name == "z_nt":
            values.append(z)
            rows.append((dze, dzn))
        else:
            raise ValueError(f"no slope for element {name!r}")
    return np.array(values), np.array(rows)


_DEG = math.degrees(1.0)


def _elements_and_gradient(
    model: WorldMagneticModel, lat_deg: float, lon_deg: float, alt_m: float, year: float,
    step_m: float | None = None, elements: ElementSet = ELEMENT_SETS[ElementSet.PAPER],
) -> tuple[np.ndarray, np.ndarray]:
    """The elements S at the point and G = dS/d(east, north) per metre.

    ``step_m`` None (default): exact, from the derivatives of the harmonic sums at the point
    (:meth:`WorldMagneticModel.ned_and_slopes`), per metre of the local plane of
    :func:`companion.nav.geo.offset_position` (east ``N cos(lat)``, north ``M`` metres per
    radian). A number: central differences over +-step_m east and north in that plane, one
    5-point model call; the error is O(step^2) times the third derivative, ~1e-6 relative at
    500 m. Declination differences are wrapped, so G stays right where D crosses +-180 degrees
    (the exact slopes never wrap).
    """
    if step_m is None:
        ned, d_lat, d_lon = model.ned_and_slopes(lat_deg, lon_deg, alt_m, year)
        meridian, prime_vertical = radii_of_curvature_m(float(lat_deg))
        east_m_per_rad = prime_vertical * math.cos(math.radians(lat_deg))
        per_metre = [(e / east_m_per_rad, n / meridian) for e, n in zip(d_lon.tolist(), d_lat.tolist())]
        return _element_values_and_slopes(elements.names, ned.tolist(), per_metre)
    east = np.array([0.0, step_m, -step_m, 0.0, 0.0])
    north = np.array([0.0, 0.0, 0.0, step_m, -step_m])
    lats, lons = offset_position(lat_deg, lon_deg, east, north)
    values = elements.values(model.elements(lats, lons, alt_m, year))   # (2, 5)
    span = 2.0 * step_m
    gradient = np.stack([elements.difference(values[:, 1], values[:, 2]),
                         elements.difference(values[:, 3], values[:, 4])], axis=1) / span
    return values[:, 0].copy(), gradient


def element_values_and_gradient(model: WorldMagneticModel, elements: ElementSet, lat_deg: float, lon_deg: float,
                                alt_m: float, year: float) -> tuple[np.ndarray, np.ndarray]:
    """The elements S at a point and their exact Jacobian ``G = dS/d(east, north)`` per metre,
    from one evaluation of the harmonic sums (S as ``model.elements`` gives it, to rounding)."""
    return _elements_and_gradient(model, lat_deg, lon_deg, alt_m, year, None, elements)


def element_gradient(
    model: WorldMagneticModel,
    elements: ElementSet,
    lat_deg: float,
    lon_deg: float,
    alt_m: float,
    year: float,
    step_m: float | None = None,
) -> np.ndarray:
    """Jacobian ``G = dS/d(east, north)`` of an element set's S, per metre (rows in the set's
    order): exact by default, central differences of +-``step_m`` metres when given."""
    if step_m is not None and not (math.isfinite(step_m) and step_m > 0.0):
        raise ValueError(f"step_m must be a positive number of metres, got {step_m}")
    return _elements_and_gradient(model, lat_deg, lon_deg, alt_m, year, step_m, elements)[1]


def decl_incl_gradient(
    model: WorldMagneticModel,
    lat_deg: float,
    lon_deg: float,
    alt_m: float,
    year: float,
    step_m: float | None = None,
) -> np.ndarray:
    """Jacobian ``G = d(D, I)/d(east, north)`` at a position, in degrees per metre.

    Rows (D, I), columns (east, north) of the MPC's local plane (x east, y north, metres,
    :func:`companion.nav.geo.offset_position`): exact from the harmonic sums' derivatives, or
    by central differences of +-``step_m`` metres when given (declination differences
    wrapped). :func:`element_gradient` on the paper's element set.
    """
    return element_gradient(model, ELEMENT_SETS[ElementSet.PAPER], lat_deg, lon_deg, alt_m, year, step_m)


class PositionFixError(RuntimeError):
    """The geomagnetic position fix failed: no convergence, ill-conditioned gradient or bad input."""


@dataclass(frozen=True)
class PositionFix:
    """A geomagnetic position fix (the paper's (lambda_c, phi_c), eq. 49).

    ``lat_deg``, ``lon_deg``: WGS84 degrees. ``iterations``: Newton steps taken.
    ``residual_deg``: norm of the element residual at the fix, in the elements' units (degrees
    for (D, I); mixed degrees and nT for (I, F)). ``condition``: 2-norm
    condition number of G at the fix (large means one direction is poorly observable).
    ``gradient``: the model's G at the fix, element units per metre (rows in the element set's
    order; columns east, north): an element error e maps to a position error G^-1 e.
    """

    lat_deg: float
    lon_deg: float
    iterations: int
    residual_deg: float
    condition: float
    gradient: np.ndarray | None = None


# Beyond this latitude the local east/north plane (and the +-step gradient) degenerates.
_MAX_FIX_LAT_DEG = 89.5
LINEAR_MAX_CONDITION = 20.0   # element_fix takes a short first step as the fix only below this cond(G)


def geomagnetic_fix(
    model: WorldMagneticModel,
    decl_deg: float,
    incl_deg: float,
    prior_lat_deg: float,
    prior_lon_deg: float,
    alt_m: float,
    year: float,
    **newton: float,
) -> PositionFix:
    """The position whose model (D, I) equals the measured (D, I): the paper's eq. 49.

    :func:`element_fix` on the paper's element set; ``newton`` are its iteration settings
    (``max_iter``, ``tol_m``, ``max_step_m``, ``max_condition``, ``step_m``).
    """
    return element_fix(model, ELEMENT_SETS[ElementSet.PAPER], (decl_deg, incl_deg), prior_lat_deg,
                       prior_lon_deg, alt_m, year, **newton)


def element_fix(
    model: WorldMagneticModel,
    elements: ElementSet,
    target: ArrayLike,
    prior_lat_deg: float,
    prior_lon_deg: float,
    alt_m: float,
    year: float,
    max_iter: int = 20,
    tol_m: float = 1.0,
    max_step_m: float = 200e3,
    max_condition: float = 1e6,
    step_m: float | None = None,
    report_at_fix: bool = True,
    at_prior: tuple[np.ndarray, np.ndarray] | None = None,
    linear_within_m: float = 0.0,
) -> PositionFix:
    """The position whose model elements equal the measured ``target`` (eq. 49 on any element set).

    Newton iteration on the square system ``S(p) = target`` in the local east/north plane,
    starting at the prior position: at each iterate p solve ``G dp = -r`` with the residual
    ``r = S(p) - target`` (declination wrapped) and G from :func:`element_gradient` (exact, or
    central differences of +-``step_m`` when given), shorten dp
    to at most ``max_step_m`` metres, and move with :func:`companion.nav.geo.offset_position`.
    It has converged once a step is shorter than ``tol_m`` metres; the fix is the position after
    that step, with its residual and condition there (``report_at_fix`` False: those of the
    iterate before it, less than ``tol_m`` away, which saves one model evaluation; the position
    is the same). ``at_prior``: the elements and exact G at the prior when the caller has them
    already (:func:`element_values_and_gradient`; the first iterate then costs no evaluation).
    ``linear_within_m``: where G is well conditioned (below :data:`LINEAR_MAX_CONDITION`), a first
    step shorter than this is the fix, the linearised one (one Gauss-Newton step from the prior, as
    a Kalman update linearises; no evaluation there), with the residual, condition and G of the
    prior. Its error is the field's curvature over the step, growing as the step's square, and
    amplified by G's condition: over 2,500 random points of the globe with a condition below 20
    (WMM2020, (D, I), steps 0.1-2 km) at most 7e-6 per metre times the step squared (7 m at 1 km;
    median 2.4e-7), against 2.4e-4 (62 m at 1 km) over all conditions up to 1e4. 0 (the
    default): always iterate to ``tol_m``.

    Element contours can cross more than once on the globe; the iteration finds the crossing the
    prior leads to, so the prior should be within a few hundred km. Raises PositionFixError for
    non-finite inputs, when cond(G) exceeds ``max_condition`` (the two contours nearly parallel:
    the fix is unobservable along one direction), when an iterate nears a geographic pole, or
    when ``max_iter`` steps do not converge (e.g. a pair the field never takes nearby).
    A year outside the model's span raises the model's ValueError.
    """
    target = np.asarray(target, dtype=float)
    if not math.isfinite(sum(target.tolist()) + prior_lat_deg + prior_lon_deg + alt_m + year):
        inputs = {**dict(zip(elements.names, target.tolist())), "prior_lat_deg": prior_lat_deg,
                  "prior_lon_deg": prior_lon_deg, "alt_m": alt_m, "year": year}
        bad = {k: v for k, v in inputs.items() if not math.isfinite(v)}
        raise PositionFixError(f"geomagnetic fix needs finite inputs, got {bad or inputs}")
    if max_iter < 1 or not (tol_m > 0.0 and max_step_m > 0.0 and (step_m is None or step_m > 0.0)
                            and 0.0 <= linear_within_m < math.inf):
        raise ValueError(
            f"need max_iter >= 1, positive tol_m, max_step_m, step_m and a finite linear_within_m >= 0; got "
            f"{max_iter}, {tol_m}, {max_step_m}, {step_m}, {linear_within_m}"
        )
    if abs(prior_lat_deg) > _MAX_FIX_LAT_DEG:
        raise PositionFixError(
            f"prior latitude {prior_lat_deg} deg is too close to a pole for the local east/north plane"
        )

    lat, lon = float(prior_lat_deg), float(prior_lon_deg)
    last_step_m = math.inf
    for iteration in range(max_iter + 1):
        if iteration == 0 and at_prior is not None and step_m is None:
            values, gradient = at_prior
        else:
            values, gradient = _elements_and_gradient(model, lat, lon, alt_m, year, step_m, elements)
        residual = elements.difference(values, target)
        residual_norm = math.hypot(*residual)
        condition = condition2(gradient)
        if not condition <= max_condition:  # also catches NaN
            raise PositionFixError(f"gradient ill-conditioned (condition {condition:.3g} > {max_condition:.3g}) "
                                   f"{_where(lat, lon, iteration, residual_norm)}")
        if last_step_m < tol_m:
            return PositionFix(lat, lon, iteration, residual_norm, condition, gradient)
        if iteration == max_iter:
            break
        step = solve2(gradient, -residual)
        last_step_m = math.hypot(*step)
        linear = iteration == 0 and last_step_m < linear_within_m and condition < LINEAR_MAX_CONDITION
        if last_step_m > max_step_m:
            step *= max_step_m / last_step_m
        new_lat, new_lon = offset_position(lat, lon, step[0], step[1])
        prev_lat, prev_lon, lat, lon = lat, lon, float(new_lat), float(new_lon)
        if abs(lat) > _MAX_FIX_LAT_DEG:
            raise PositionFixError(f"iterate reached latitude {lat:.3f} deg, too close to a pole; "
                                   f"{_where(prev_lat, prev_lon, iteration, residual_norm)}")
        if linear or (not report_at_fix and last_step_m < tol_m):
            return PositionFix(lat, lon, iteration + 1, residual_norm, condition, gradient)
    raise PositionFixError(
        f"no convergence within {max_iter} iterations: {_where(lat, lon, iteration, residual_norm)}, "
        f"last Newton step {last_step_m:.3g} m "
        f"(target {elements.label} = {tuple(float(v) for v in target)})"
    )


def _where(lat: float, lon: float, iteration: int, residual_norm: float) -> str:
    """Where a fix failed, for its error message (formatted only when one is raised)."""
    return f"at ({lat:.6f}, {lon:.6f}) deg after {iteration} iterations, residual {residual_norm:.3g}"


def fix_covariance(gradient: np.ndarray, element_covariance: np.ndarray) -> np.ndarray:
    """East/north covariance (m^2) of a fix from its element errors through the gradient ``G``
    (element units per metre): ``G^-1 C G^-T``, C given as the variances (its diagonal, 1-D) or
    whole (2-D). Raises numpy's LinAlgError for a singular G."""
    inverse = inverse2(gradient)
    c = np.asarray(element_covariance, dtype=float)
    return (inverse * c) @ inverse.T if c.ndim == 1 else inverse @ c @ inverse.T
