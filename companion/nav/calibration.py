"""Magnetometer hard- and soft-iron calibration fitted from samples: an ellipsoid scaled to the model.

Pure: body-frame samples (nT) and the model's total intensity at the known position (nT) in, a
:class:`CalibrationFit` out; no files, clocks or sockets. Used on logs (``fcmpc-calibrate``,
``fcmpc-replay``) and on the vehicle.

The distorted samples ``m`` of a constant field lie on an ellipsoid; the correction is the
companion's :class:`~companion.nav.magnetometer.MagCalibration`, ``c = W (m - o)``, with ``o``
the hard-iron offset (nT, subtracted) and ``W`` a symmetric soft-iron matrix chosen so that
``|c|`` is the model's ``F``:

1. **Algebraic fit** (Li & Griffiths 2004, "Least squares ellipsoid specific fitting", the
   ``4J - I^2 = 1`` constraint): the quadric ``m^T A m + b^T m + d = 0`` that is an ellipsoid,
   from one generalised eigenproblem; samples are centred and scaled first for conditioning.
2. **Geometric refinement**: ``o`` and the six entries of ``W`` minimise
   ``sum (|W (m - o)| - F)^2`` (scipy's Levenberg-Marquardt), started from step 1. Residuals
   measured on the corrected field make the fit exactly equivariant: the same samples distorted
   by any known ``A m + h`` give the calibration composed with it.
3. **Quality**: the residual ``rms(|c| - F)`` (nT), and the coverage of directions: the share of
   :data:`SPHERE_CELLS` equal-area cells of the unit sphere the corrected directions visit, and
   the eigenvalues of their scatter (``cov(c/|c|)``: 1/3 each on a uniform sphere, one near 0
   when the vehicle only turned about one axis). A full soft iron needs directions in three
   dimensions: too little coverage is refused with :class:`CalibrationRefused`, which says what
   was measured against what is needed.

A vehicle that only turns about its vertical axis (a boat's or a car's circles) gives a ring of
directions: the full fit is refused, and :func:`fit_level_calibration` fits what a ring can
tell (what is down on such a circle: :mod:`companion.nav.circle_level`), with the attitude's roll and pitch and the model's horizontal and vertical components:
the hard iron (3), the horizontal soft iron (x-x, x-y, y-y) and a vertical scale taken as the
mean of the horizontal ones (it cannot be told from the vertical hard iron on a ring).

No library fit is used: the PyPI packages for magnetometer calibration (magcal, magyc,
circuitpython-mag-cal) are single-author tools without a maintained release line; the fit is
twenty lines of numpy and scipy.

>>> rng = np.random.default_rng(1)
>>> u = rng.normal(size=(400, 3)); u /= np.linalg.norm(u, axis=1)[:, None]
>>> true_w = np.array([[1.1, 0.05, 0.0], [0.05, 0.9, 0.02], [0.0, 0.02, 1.0]])
>>> m = np.linalg.solve(true_w, 50000.0 * u.T).T + (3000.0, -1500.0, 800.0)
>>> fit = fit_calibration(m, 50000.0)
>>> [round(v) for v in fit.offset_nt], round(fit.residual_nt, 6)
([3000, -1500, 800], 0.0)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from companion.frames import Matrix3, Vector3
from companion.nav.magnetometer import MILLIGAUSS_TO_NT, MagCalibration

__all__ = [
    "SPHERE_CELLS",
    "CalibrationLimits",
    "CalibrationFit",
    "CalibrationRefused",
    "fit_calibration",
    "fit_level_calibration",
    "down_in_body",
    "direction_coverage",
    "ardupilot_compass_params",
    "companion_params",
]

_BANDS, _SECTORS = 6, 12
SPHERE_CELLS = _BANDS * _SECTORS   # equal-area cells: 6 bands of equal height (z) x 12 sectors


class CalibrationRefused(ValueError):
    """The samples cannot give a trustworthy calibration; the message says what was measured."""


@dataclass(frozen=True)
class CalibrationLimits:
    """What a fit must meet to be accepted.

    ``min_samples``: samples needed; ``min_cell_share``: share of :data:`SPHERE_CELLS` visited by
    the corrected directions; ``min_scatter``: the smallest eigenvalue of the directions' scatter
    (1/3 on a uniform sphere; a turn about one axis leaves one near 0); ``max_residual``: the rms
    of ``|c| - F`` as a share of ``F``.
    """

    min_samples: int = 100
    min_cell_share: float = 0.25
    min_scatter: float = 0.01
    max_residual: float = 0.05


@dataclass(frozen=True)
class CalibrationFit:
    """A hard/soft-iron calibration ``c = soft_iron @ (m - offset_nt)`` and its quality.

    ``field_nt``: the model's total intensity the fit is scaled to (the mean, if one per
    sample); ``residual_nt``: rms of ``|c| - |B|`` over the samples; ``cell_share``: share of the sphere's cells visited;
    ``scatter``: eigenvalues of the corrected directions' scatter, ascending; ``samples``: count.
    """

    offset_nt: Vector3
    soft_iron: Matrix3
    field_nt: float
    residual_nt: float
    cell_share: float
    scatter: Vector3
    samples: int
    level: bool = False   # fitted by fit_level_calibration: cell_share is then the share of heading sectors

    @property
    def calibration(self) -> MagCalibration:
        return MagCalibration(self.offset_nt, self.soft_iron)

    def describe(self) -> str:
        """Several lines for an operator: the fit and its quality."""
        w = self.soft_iron
        return "\n".join([
            f"hard iron (subtracted): {', '.join(f'{v:+.0f}' for v in self.offset_nt)} nT",
            "soft iron: " + "; ".join(" ".join(f"{v:+.4f}" for v in row) for row in w),
            f"scaled to the model's |B| = {self.field_nt:.0f} nT; residual {self.residual_nt:.0f} nT rms "
            f"({100.0 * self.residual_nt / self.field_nt:.2f} %) over {self.samples} samples",
            (f"level fit (turns about the vertical): {100.0 * self.cell_share:.0f} % of {_SECTORS} heading sectors; "
             "vertical soft iron taken as the horizontal mean" if self.level else
             f"coverage: {100.0 * self.cell_share:.0f} % of {SPHERE_CELLS} sphere cells")
            + f", direction scatter eigenvalues {', '.join(f'{v:.3f}' for v in self.scatter)} (uniform sphere 0.333)",
        ])

    def status_text(self) -> str:
        """One line of at most 50 characters (a MAVLink STATUSTEXT)."""
        o = self.offset_nt
        return (f"MagCal {o[0] / 1e3:+.1f} {o[1] / 1e3:+.1f} {o[2] / 1e3:+.1f}uT "
                f"r{self.residual_nt:.0f}nT c{100.0 * self.cell_share:.0f}%")[:50]


def direction_coverage(directions: ArrayLike) -> tuple[float, Vector3]:
    """(share of the sphere's equal-area cells visited, ascending eigenvalues of the scatter) of
    vectors (n, 3), normalised here.

    >>> share, scatter = direction_coverage([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    >>> round(share * SPHERE_CELLS), round(scatter[0], 3)
    (2, 0.0)
    """
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    u = u / np.linalg.norm(u, axis=1)[:, None]
    band = np.minimum(((u[:, 2] + 1.0) * 0.5 * _BANDS).astype(int), _BANDS - 1)
    sector = np.minimum(((np.arctan2(u[:, 1], u[:, 0]) + math.pi) / (2.0 * math.pi) * _SECTORS).astype(int),
                        _SECTORS - 1)
    share = len(np.unique(band * _SECTORS + sector)) / SPHERE_CELLS
    scatter = np.linalg.eigvalsh(np.cov(u.T)) if len(u) > 1 else np.zeros(3)
    return share, tuple(float(v) for v in np.clip(scatter, 0.0, None))  # type: ignore[return-value]


def _algebraic_ellipsoid(x: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Li & Griffiths' ellipsoid through centred, scaled samples: (centre, M) with
    ``(x - centre)^T M (x - centre) = 1``; None if the samples admit no ellipsoid."""
    xx, yy, zz = x[:, 0], x[:, 1], x[:, 2]
    d = np.column_stack([xx * xx, yy * yy, zz * zz, 2 * yy * zz, 2 * xx * zz, 2 * xx * yy,
                         2 * xx, 2 * yy, 2 * zz, np.ones(len(x))])
    s = d.T @ d
    s11, s12, s22 = s[:6, :6], s[:6, 6:], s[6:, 6:]
    c1 = np.zeros((6, 6))   # 4J - I^2 = v1^T C1 v1 (Li & Griffiths' constraint with k = 4)
    c1[:3, :3] = np.ones((3, 3)) - 2.0 * np.eye(3)
    c1[3:, 3:] = -4.0 * np.eye(3)
    try:
        reduced = s11 - s12 @ np.linalg.solve(s22, s12.T)
        values, vectors = np.linalg.eig(np.linalg.solve(c1, reduced))
    except np.linalg.LinAlgError:
        return None
    values, vectors = values.real, vectors.real
    # the ellipsoid is the eigenvector meeting 4J - I^2 > 0 with the largest eigenvalue (positive,
    # or zero to rounding on noiseless samples)
    ellipsoids = np.flatnonzero(np.einsum("ij,ik,kj->j", vectors, c1, vectors) > 0.0)
    if not len(ellipsoids):
        return None
    v1 = vectors[:, ellipsoids[np.argmax(values[ellipsoids])]]
    v2 = -np.linalg.solve(s22, s12.T @ v1)
    a, b, c, f, g, h = v1
    p, q, r, dd = v2
    quad = np.array([[a, h, g], [h, b, f], [g, f, c]])
    lin = np.array([p, q, r])
    try:
        centre = -np.linalg.solve(quad, lin)
    except np.linalg.LinAlgError:
        return None
    scale = centre @ quad @ centre - dd
    if not (math.isfinite(scale) and scale != 0.0):
        return None
    m = quad / scale
    if np.linalg.eigvalsh(m).min() <= 0.0:
        return None
    return centre, m


def _sym_sqrt(m: np.ndarray) -> np.ndarray:
    values, vectors = np.linalg.eigh(m)
    return (vectors * np.sqrt(np.clip(values, 0.0, None))) @ vectors.T


_UPPER = (np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2]))


def _unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = np.empty((3, 3))
    w[_UPPER] = p[3:]
    w[_UPPER[1], _UPPER[0]] = p[3:]
    return p[:3], w


def fit_calibration(samples_nt: ArrayLike, field_nt: float | ArrayLike,
                    limits: CalibrationLimits = CalibrationLimits()) -> CalibrationFit:
    """The calibration of body-frame samples (n, 3, nT) of a field of total intensity
    ``field_nt`` (the model's at the known position: one value, or one per sample for a vehicle
    that travelled); :class:`CalibrationRefused` naming the reason when the samples are too few,
    admit no ellipsoid, cover too few directions or fit it too loosely. Samples with a
    non-finite component are dropped first."""
    from scipy.optimize import least_squares

    m = np.asarray(samples_nt, dtype=float).reshape(-1, 3)
    f = np.broadcast_to(np.asarray(field_nt, dtype=float), (len(m),))
    if not (np.isfinite(f).all() and (f > 0.0).all()):
        raise ValueError(f"field_nt must be positive numbers of nT, got {field_nt!r}")
    keep = np.isfinite(m).all(axis=1)
    m, f = m[keep], f[keep]
    if len(m) < limits.min_samples:
        raise CalibrationRefused(f"{len(m)} finite magnetometer samples; a calibration needs at least "
                                 f"{limits.min_samples}")
    mean = m.mean(axis=0)
    spread = float(np.sqrt(((m - mean) ** 2).sum(axis=1).mean()))
    if not spread > 0.0:
        raise CalibrationRefused("the magnetometer samples do not vary: the vehicle did not turn")
    algebraic = _algebraic_ellipsoid((m - mean) / spread)
    if algebraic is None:
        share, scatter = direction_coverage(m - mean)
        raise CalibrationRefused(
            f"the samples lie on no ellipsoid (directions about their mean cover {100 * share:.0f} % of the "
            f"sphere, smallest scatter {scatter[0]:.3f}): turn the vehicle through more attitudes")
    centre, shape = algebraic
    f_mean = float(f.mean())
    w0 = _sym_sqrt(shape) * f_mean / spread
    start = np.concatenate([mean + spread * centre, w0[_UPPER]])

    def residuals(p: np.ndarray) -> np.ndarray:
        o, w = _unpack(p)
        return np.linalg.norm((m - o) @ w, axis=1) - f   # w is symmetric: (m - o) @ w = (w (m - o))^T

    solution = least_squares(residuals, start, method="lm", x_scale=np.abs(start) + 1e-3, max_nfev=500)
    offset, w = _unpack(solution.x)
    if np.linalg.eigvalsh(w).min() <= 0.0:   # the symmetric root is the positive definite one
        values, vectors = np.linalg.eigh(w)
        w = (vectors * np.abs(values)) @ vectors.T
    corrected = (m - offset) @ w
    residual = float(np.sqrt(np.mean((np.linalg.norm(corrected, axis=1) - f) ** 2)))
    share, scatter = direction_coverage(corrected)
    fit = CalibrationFit(tuple(float(v) for v in offset),  # type: ignore[arg-type]
                         tuple(tuple(float(v) for v in row) for row in w),  # type: ignore[arg-type]
                         f_mean, residual, share, scatter, len(m))
    problems = []
    if share < limits.min_cell_share:
        problems.append(f"the directions cover {100 * share:.0f} % of the sphere's {SPHERE_CELLS} cells "
                        f"(needs {100 * limits.min_cell_share:.0f} %)")
    if scatter[0] < limits.min_scatter:
        problems.append(f"their smallest scatter eigenvalue is {scatter[0]:.3f} (needs {limits.min_scatter:.3f}; "
                        "a turn about one axis only leaves one near 0)")
    if residual > limits.max_residual * f_mean:
        problems.append(f"the residual is {residual:.0f} nT rms, {100 * residual / f_mean:.1f} % of |B| "
                        f"(at most {100 * limits.max_residual:.0f} %)")
    if problems:
        raise CalibrationRefused("calibration refused: " + "; ".join(problems) + ": turn the vehicle through "
                                 "more attitudes (pitch and roll as well as yaw)\n" + fit.describe())
    return fit


def down_in_body(roll_rad: ArrayLike, pitch_rad: ArrayLike) -> np.ndarray:
    """Unit vectors (n, 3) of NED's down in the body frame (ZYX Euler, :mod:`companion.frames`):
    the last row of the body-to-NED matrix, which yaw does not change."""
    roll, pitch = np.asarray(roll_rad, dtype=float), np.asarray(pitch_rad, dtype=float)
    return np.column_stack([-np.sin(pitch), np.sin(roll) * np.cos(pitch), np.cos(roll) * np.cos(pitch)])


def fit_level_calibration(samples_nt: ArrayLike, down_body: ArrayLike, horizontal_nt: float, vertical_nt: float,
                          limits: CalibrationLimits = CalibrationLimits()) -> CalibrationFit:
    """The calibration of a vehicle that turned about its vertical axis (samples (n, 3) nT with
    ``down_body`` (n, 3) from :func:`down_in_body`): the corrected field's horizontal magnitude
    is made the model's ``horizontal_nt`` and its down component ``vertical_nt``.

    ``cell_share`` is then the share of 12 sectors of heading the horizontal field visited
    (refused below 3/4: turn a full circle) and ``scatter`` the direction scatter as for
    :func:`fit_calibration` (reported, not judged)."""
    from scipy.optimize import least_squares

    m = np.asarray(samples_nt, dtype=float).reshape(-1, 3)
    d = np.asarray(down_body, dtype=float).reshape(-1, 3)
    if len(d) != len(m):
        raise ValueError(f"down_body has {len(d)} rows for {len(m)} samples")
    if not (math.isfinite(horizontal_nt) and horizontal_nt > 0.0 and math.isfinite(vertical_nt)):
        raise ValueError(f"horizontal_nt {horizontal_nt!r} and vertical_nt {vertical_nt!r} must be finite, "
                         "the first positive")
    keep = np.isfinite(m).all(axis=1) & np.isfinite(d).all(axis=1)
    m, d = m[keep], d[keep]
    if len(m) < limits.min_samples:
        raise CalibrationRefused(f"{len(m)} finite magnetometer samples with attitude; a calibration needs at "
                                 f"least {limits.min_samples}")
    field = math.hypot(horizontal_nt, vertical_nt)

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xz, yz = (p[6], p[7]) if len(p) > 6 else (0.0, 0.0)
        w = np.array([[p[3], p[4], xz], [p[4], p[5], yz], [xz, yz, 0.5 * (p[3] + p[5])]])
        return p[:3], w

    def residuals(p: np.ndarray) -> np.ndarray:
        o, w = unpack(p)
        c = (m - o) @ w
        down = np.sum(c * d, axis=1)
        across = np.sqrt(np.maximum(np.sum(c * c, axis=1) - down * down, 0.0))
        return np.concatenate([across - horizontal_nt, down - vertical_nt])

    centre = m.mean(axis=0)
    level = m - centre - np.sum((m - centre) * d, axis=1)[:, None] * d
    radius = float(np.sqrt(np.mean(np.sum(level * level, axis=1))))
    if not radius > 0.0:
        raise CalibrationRefused("the magnetometer samples do not vary: the vehicle did not turn")
    scale = horizontal_nt / radius
    start = np.array([centre[0], centre[1], float(np.mean(m[:, 2])) - vertical_nt / scale, scale, 0.0, scale])
    solution = least_squares(residuals, start, method="lm", x_scale=np.abs(start) + 1e-3, max_nfev=500)
    # the vertical-horizontal cross terms (xz, yz) make the down component swing with the heading;
    # a level ring sees that swing, but they trade off against the hard iron under noise, so they
    # are kept only where they explain the data: the residual at least 10 % lower with them
    crossed = least_squares(residuals, np.concatenate([solution.x, [0.0, 0.0]]), method="lm",
                            x_scale=np.concatenate([np.abs(solution.x) + 1e-3, [1e-2, 1e-2]]), max_nfev=500)
    if np.sqrt(np.mean(crossed.fun ** 2)) < 0.9 * np.sqrt(np.mean(solution.fun ** 2)):
        solution = crossed
    offset, w = unpack(solution.x)
    corrected = (m - offset) @ w
    residual = float(np.sqrt(np.mean(residuals(solution.x) ** 2)))
    down = np.sum(corrected * d, axis=1)
    horizontal = corrected - down[:, None] * d
    # heading sectors of the horizontal field, in a frame levelled by the attitude (body x projected)
    ref_x = np.array([1.0, 0.0, 0.0]) - d[:, 0:1] * d
    ref_y = np.cross(d, ref_x)
    angle = np.arctan2(np.sum(horizontal * ref_y, axis=1), np.sum(horizontal * ref_x, axis=1))
    sectors = len(np.unique(np.minimum(((angle + math.pi) / (2 * math.pi) * _SECTORS).astype(int), _SECTORS - 1)))
    share = sectors / _SECTORS
    _, scatter = direction_coverage(corrected)
    fit = CalibrationFit(tuple(float(v) for v in offset),  # type: ignore[arg-type]
                         tuple(tuple(float(v) for v in row) for row in w),  # type: ignore[arg-type]
                         field, residual, share, scatter, len(m), level=True)
    problems = []
    if share < 0.75:
        problems.append(f"the heading of the field visited {sectors} of {_SECTORS} sectors (needs 9: a full circle)")
    if residual > limits.max_residual * field:
        problems.append(f"the residual is {residual:.0f} nT rms, {100 * residual / field:.1f} % of |B| "
                        f"(at most {100 * limits.max_residual:.0f} %)")
    if problems:
        raise CalibrationRefused("level calibration refused: " + "; ".join(problems) + "\n" + fit.describe())
    return fit


def companion_params(fit: CalibrationFit) -> dict[str, float]:
    """The companion's ``MAG_*`` parameters for ``fit`` (offset in milligauss, subtracted)."""
    return registry_values(fit.calibration)


def ardupilot_compass_params(fit: CalibrationFit, compass: int = 1,
                             current: dict[str, float] | None = None) -> tuple[dict[str, float], float]:
    """ArduPilot's equivalents of ``fit`` and the angle (deg) of the rotation they leave out.

    ArduPilot corrects ``[[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]]
    (raw + OFS)``, OFS in milligauss and added (so ``-offset``). ArduPilot logs and streams the
    field it has already corrected with the ``current`` COMPASS_* values: a fit of that field is
    composed with them, ``W M (raw + OFS - M^-1 o)``, and ``W M``, not symmetric in general, is
    replaced by its symmetric polar factor (same magnitudes, directions turned by the returned
    angle). Without ``current`` the fitted field is taken as the raw one (angle 0).
    """
    prefix, suffix = "COMPASS_", "" if compass == 1 else str(compass)
    o, w = np.array(fit.offset_nt), np.array(fit.soft_iron)
    old_ofs, old_m = np.zeros(3), np.eye(3)
    if current:
        def value(kind: str, axis: str, default: float) -> float:
            return float(current.get(f"{prefix}{kind}{suffix}_{axis}", default))
        old_ofs = np.array([value("OFS", a, 0.0) for a in "XYZ"]) * MILLIGAUSS_TO_NT
        dia = [value("DIA", a, 1.0) or 1.0 for a in "XYZ"]   # ArduPilot reads DIA 0 as 1 (never calibrated)
        odi = [value("ODI", a, 0.0) for a in "XYZ"]
        old_m = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]], [odi[1], odi[2], dia[2]]])
    total = w @ old_m
    symmetric = _sym_sqrt(total.T @ total)
    rotation = total @ np.linalg.inv(symmetric)
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(rotation) - 1.0) / 2.0))))
    ofs = (old_ofs - np.linalg.solve(old_m, o)) / MILLIGAUSS_TO_NT
    out = {f"{prefix}OFS{suffix}_{a}": float(ofs[k]) for k, a in enumerate("XYZ")}
    out.update({f"{prefix}DIA{suffix}_{a}": float(symmetric[k, k]) for k, a in enumerate("XYZ")})
    out.update({f"{prefix}ODI{suffix}_X": float(symmetric[0, 1]), f"{prefix}ODI{suffix}_Y": float(symmetric[0, 2]),
                f"{prefix}ODI{suffix}_Z": float(symmetric[1, 2])})
    return out, angle


def chained(first: MagCalibration, fit: CalibrationFit) -> MagCalibration:
    """The calibration ``fit`` found on samples already corrected by ``first``, as one from the raw
    samples: ``W (W1 (m - o1) - o) = W W1 (m - (o1 + W1^-1 o))``. ``W W1`` is replaced by its
    symmetric polar factor (the registry's MAG_SCALE_*/MAG_SOFT_* hold a symmetric matrix); with
    ``first`` the identity, as on a vehicle not yet calibrated, that is ``W`` itself.

    >>> fit = CalibrationFit((100.0, 0.0, 0.0), ((1.1, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), 5e4, 0.0,
    ...                      1.0, (0.3, 0.3, 0.3), 500, True)
    >>> c = chained(MagCalibration((10.0, 0.0, 0.0)), fit)
    >>> [round(v, 6) for v in c.offset_nt], round(c.soft_iron[0][0], 6)
    ([110.0, 0.0, 0.0], 1.1)
    """
    w1, o1 = np.array(first.soft_iron, dtype=float), np.array(first.offset_nt, dtype=float)
    w, o = np.array(fit.soft_iron, dtype=float), np.array(fit.offset_nt, dtype=float)
    product = w @ w1
    u, s, vt = np.linalg.svd(product)
    symmetric = vt.T @ np.diag(s) @ vt          # the polar factor P of product = R P
    offset = o1 + np.linalg.solve(w1, o)
    return MagCalibration(tuple(float(v) for v in offset), tuple(tuple(float(v) for v in row) for row in symmetric))


def registry_values(calibration: MagCalibration) -> dict[str, float]:
    """The companion's ``MAG_*`` parameters of a calibration (offset in milligauss, subtracted)."""
    o, w = calibration.offset_nt, calibration.soft_iron
    out = {f"MAG_OFS_{a}": o[k] / MILLIGAUSS_TO_NT for k, a in enumerate("XYZ")}
    out.update({f"MAG_SCALE_{a}": w[k][k] for k, a in enumerate("XYZ")})
    out.update({"MAG_SOFT_XY": w[0][1], "MAG_SOFT_XZ": w[0][2], "MAG_SOFT_YZ": w[1][2]})
    return out
