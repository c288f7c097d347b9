"""The magnetometer's alignment to the body: a small rotation fitted against the model's field direction.

Pure: calibrated body-frame samples (nT), the attitude at each sample (rad) and the model's NED
field at the known (GPS) position in, an :class:`AlignmentFit` out; no files, clocks or sockets.

A hard/soft-iron fit (:mod:`companion.nav.calibration`) scaled to ``|B|`` makes the corrected
field's *magnitude* right but cannot tell a rotation: a magnetometer mounted a few degrees off the
frame the attitude refers to (the board's level trim, a bracket, an external compass declared with
an approximate ``COMPASS_ORIENT``) reads the right ``|B|`` in the wrong direction, which shifts the
measured inclination by up to the misalignment, and a geomagnetic fix by hundreds of km. With GPS
at calibration time the model gives the field's *direction* too, and with the known attitude that
constrains the rotation ``R`` with ``aligned = R c`` (``c`` the hard/soft-iron corrected sample).
ArduPilot's large-vehicle calibration uses the model the same way (``MAV_CMD_FIXED_MAG_CAL_YAW``,
ArduPilot PR #12863: the compass offsets made consistent with the WMM at the known location and
yaw); here the model's direction fits a rotation instead of offsets.

``R`` is ZYX Euler (roll, pitch, yaw; :mod:`companion.frames`), the registry's ``MAG_ROT_ROLL``,
``MAG_ROT_PIT``, ``MAG_ROT_YAW`` (deg), applied after the hard and soft iron. Two fits:

* ``axes="xy"`` (the default): roll and pitch of ``R`` from the *inclination* alone,
  ``asin(R c . down)`` against the model's ``I``, with ``down`` from the attitude's roll and pitch
  only. The yaw the flight controller reports is, on ArduPilot and PX4, fused from this very
  compass (and ArduPilot's changes by the declination it starts applying after the first fix), so
  it cannot judge the compass; roll and pitch come from gravity. A tilt changes ``I`` by an amount
  that swings with the heading, so the vehicle must have turned: at one heading only the tilt about
  the field's horizontal normal is seen, and a tilt cannot be told from a constant bias of ``I``.
* ``axes="xyz"``: the whole rotation from the field vector, ``R c`` against the model's field in
  the body frame (with the reported yaw): for a yaw independent of this compass (GPS heading, dual
  antennas).

Quality: the residual (deg rms, before and after), and the fit's information ``J^T J / n`` (its
eigenvalues: about 1/2 each on evenly spread headings, one near 0 when the headings leave an angle
unseen) and the standard errors of the angles from the residual's scatter, widened by its
correlation in time (the AR(1) factor of its lag-1 autocorrelation: samples must be in time order). Refused with :class:`AlignmentRefused` when too few samples, an
eigenvalue below :attr:`AlignmentLimits.min_information`, a standard error above
:attr:`AlignmentLimits.max_std_deg` or an angle beyond :data:`MAX_ROTATION_DEG`.

>>> rng = np.random.default_rng(3)
>>> yaw = np.linspace(0.0, 2 * math.pi, 360, endpoint=False); zero = np.zeros_like(yaw)
>>> field = np.tile([20000.0, 5000.0, -50000.0], (360, 1))
>>> body = np.einsum("kji,kj->ki", mats_nb_from_euler(zero, zero, yaw), field)
>>> mounted = body @ np.array(rotation_matrix((1.0, -2.0, 0.0)))      # R^T b: the sensor's frame
>>> fit = fit_alignment(mounted, zero, zero, yaw, field)
>>> [round(v, 3) for v in fit.rotation_deg], round(fit.residual_deg, 6)
([1.0, -2.0, 0.0], 0.0)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from companion.frames import Matrix3, Vector3, mat_nb_from_euler, mats_nb_from_euler
from companion.nav.calibration import CalibrationRefused, down_in_body
from companion.nav.magnetometer import MagCalibration

__all__ = ["MAX_ROTATION_DEG", "AlignmentLimits", "AlignmentFit", "AlignmentRefused", "fit_alignment",
           "rotation_matrix", "aligned", "alignment_params"]

MAX_ROTATION_DEG = 15.0   # the registry's MAG_ROT_* range: beyond it the declared orientation is wrong
_AXES = {"xy": (0, 1), "xyz": (0, 1, 2)}
_NAMES = ("roll", "pitch", "yaw")


class AlignmentRefused(CalibrationRefused):
    """The attitudes cannot give a trustworthy alignment; the message says what was measured."""


@dataclass(frozen=True)
class AlignmentLimits:
    """What an alignment fit must meet: ``min_samples``; ``min_information``: the smallest
    eigenvalue of ``J^T J / n`` (about 0.5 on evenly spread headings); ``max_std_deg``: the
    largest standard error of a fitted angle."""

    min_samples: int = 100
    min_information: float = 0.02
    max_std_deg: float = 1.0


@dataclass(frozen=True)
class AlignmentFit:
    """``aligned = rotation_matrix(rotation_deg) @ calibrated`` and its quality.

    ``rotation_deg``: roll, pitch, yaw (deg; yaw 0 when ``axes`` is ``"xy"``); ``residual_deg`` and
    ``before_deg``: rms of the fitted residual (inclination error for ``"xy"``, angle between the
    measured and the model's direction for ``"xyz"``) after and before; ``bias_before_deg`` /
    ``bias_after_deg``: the mean inclination error; ``std_deg``: standard errors of the fitted
    angles (NaN for one not fitted); ``information``: eigenvalues of ``J^T J / n``, ascending.
    """

    rotation_deg: Vector3
    axes: str
    residual_deg: float
    before_deg: float
    bias_before_deg: float
    bias_after_deg: float
    std_deg: Vector3
    information: tuple[float, ...]
    samples: int

    @property
    def matrix(self) -> Matrix3:
        return rotation_matrix(self.rotation_deg)

    def describe(self) -> str:
        """Two lines for an operator."""
        r, s = self.rotation_deg, self.std_deg
        angles = ", ".join(f"{_NAMES[k]} {r[k]:+.2f} +- {s[k]:.2f}" for k in _AXES[self.axes])
        return (f"alignment ({self.axes}: {'inclination only, yaw-free' if self.axes == 'xy' else 'field vector'}): "
                f"{angles} deg (MAG_ROT_*) over {self.samples} samples\n"
                f"  residual {self.before_deg:.2f} -> {self.residual_deg:.2f} deg rms, inclination bias "
                f"{self.bias_before_deg:+.2f} -> {self.bias_after_deg:+.2f} deg; information "
                + ", ".join(f"{v:.3f}" for v in self.information))


def rotation_matrix(rotation_deg: ArrayLike) -> Matrix3:
    """The rotation of ZYX Euler angles (roll, pitch, yaw in degrees) from the magnetometer's
    frame into the body's."""
    r, p, y = (math.radians(float(v)) for v in np.asarray(rotation_deg, dtype=float).reshape(3))
    return mat_nb_from_euler(r, p, y)


def aligned(calibration: MagCalibration, rotation_deg: ArrayLike) -> MagCalibration:
    """``calibration`` followed by the rotation: ``R W (m - o)`` (the soft-iron matrix is then
    not symmetric; :class:`MagCalibration` applies any 3x3).

    >>> c = aligned(MagCalibration((100.0, 0.0, 0.0)), (0.0, 0.0, 90.0))
    >>> [round(v, 6) + 0.0 for v in c.apply((1100.0, 0.0, 0.0))]
    [0.0, 1000.0, 0.0]
    """
    if not np.any(np.asarray(rotation_deg, dtype=float)):
        return calibration
    w = np.array(rotation_matrix(rotation_deg)) @ np.array(calibration.soft_iron, dtype=float)
    return MagCalibration(calibration.offset_nt, tuple(tuple(float(v) for v in row) for row in w))  # type: ignore[arg-type]


def alignment_params(fit: AlignmentFit) -> dict[str, float]:
    """The registry's ``MAG_ROT_ROLL/PIT/YAW`` (deg) of ``fit``."""
    return dict(zip(("MAG_ROT_ROLL", "MAG_ROT_PIT", "MAG_ROT_YAW"), (float(v) for v in fit.rotation_deg)))


def _inclination(u: np.ndarray, down: np.ndarray) -> np.ndarray:
    return np.arcsin(np.clip(np.sum(u * down, axis=1), -1.0, 1.0))


def _correlation_factor(residual: np.ndarray) -> float:
    """How many times fewer independent samples the time-ordered residual (n, k) holds: the
    AR(1) variance inflation ``(1 + rho) / (1 - rho)`` of its lag-1 autocorrelation (at least 1)."""
    r = residual - residual.mean(axis=0)
    denominator = float(np.sum(r * r))
    if len(r) < 3 or not denominator > 0.0:
        return 1.0
    rho = min(float(np.sum(r[1:] * r[:-1])) / denominator, 0.99)
    return max(1.0, (1.0 + rho) / (1.0 - rho))


def fit_alignment(samples_nt: ArrayLike, roll_rad: ArrayLike, pitch_rad: ArrayLike, yaw_rad: ArrayLike,
                  field_ned_nt: ArrayLike, axes: str = "xy",
                  limits: AlignmentLimits = AlignmentLimits()) -> AlignmentFit:
    """The rotation that turns calibrated body-frame samples (n, 3, nT) into the model's field
    direction (``field_ned_nt``: (n, 3) or one (3,) NED vector, nT) under the attitude at each
    sample; ``axes`` ``"xy"`` (roll and pitch from the inclination, yaw-free) or ``"xyz"`` (with
    the reported yaw). :class:`AlignmentRefused` names what the samples lack; rows with a
    non-finite value are dropped first."""
    from scipy.optimize import least_squares

    if axes not in _AXES:
        raise ValueError(f"axes must be one of {sorted(_AXES)}, got {axes!r}")
    m = np.asarray(samples_nt, dtype=float).reshape(-1, 3)
    att = np.column_stack([np.broadcast_to(np.asarray(a, dtype=float), (len(m),))
                           for a in (roll_rad, pitch_rad, yaw_rad)])
    b = np.broadcast_to(np.asarray(field_ned_nt, dtype=float), (len(m), 3))
    keep = np.isfinite(m).all(axis=1) & np.isfinite(att).all(axis=1) & np.isfinite(b).all(axis=1)
    keep &= np.linalg.norm(m, axis=1) > 0.0
    m, att, b = m[keep], att[keep], b[keep]
    if len(m) < limits.min_samples:
        raise AlignmentRefused(f"{len(m)} samples with attitude; an alignment needs at least {limits.min_samples}")
    u = m / np.linalg.norm(m, axis=1)[:, None]
    fitted = _AXES[axes]
    if axes == "xy":
        down = down_in_body(att[:, 0], att[:, 1])
        target = np.arcsin(np.clip(b[:, 2] / np.linalg.norm(b, axis=1), -1.0, 1.0))   # the model's I

        def residuals(p: np.ndarray) -> np.ndarray:
            rot = np.array(rotation_matrix(np.degrees([p[0], p[1], 0.0])))
            return _inclination(u @ rot.T, down) - target
    else:
        body = np.einsum("kji,kj->ki", mats_nb_from_euler(att[:, 0], att[:, 1], att[:, 2]), b)
        body /= np.linalg.norm(body, axis=1)[:, None]

        def residuals(p: np.ndarray) -> np.ndarray:
            rot = np.array(rotation_matrix(np.degrees(p)))
            return (u @ rot.T - body).ravel()

    start = np.zeros(len(fitted))
    solution = least_squares(residuals, start, method="lm", x_scale=np.full(len(fitted), 0.01), max_nfev=200)
    per_sample = 1 if axes == "xy" else 3

    def rms_deg(r: np.ndarray) -> float:
        if axes == "xy":
            return math.degrees(float(np.sqrt(np.mean(r * r))))
        return math.degrees(float(np.sqrt(np.mean(np.sum(r.reshape(-1, 3) ** 2, axis=1)))))

    jac = solution.jac
    info = jac.T @ jac / len(m)
    eig = np.linalg.eigvalsh(info)
    dof = max(1, per_sample * len(m) - len(fitted))
    sigma2 = float(np.sum(solution.fun ** 2)) / dof
    try:
        cov = np.linalg.inv(jac.T @ jac) * sigma2 * _correlation_factor(solution.fun.reshape(len(m), -1))
        std = np.degrees(np.sqrt(np.clip(np.diag(cov), 0.0, None)))
    except np.linalg.LinAlgError:
        std = np.full(len(fitted), math.inf)
    angles = np.zeros(3)
    angles[list(fitted)] = np.degrees(solution.x)
    stds = np.full(3, math.nan)
    stds[list(fitted)] = std
    final = rotation_matrix(angles)
    level_down = down_in_body(att[:, 0], att[:, 1])
    model_incl = np.degrees(np.arcsin(np.clip(b[:, 2] / np.linalg.norm(b, axis=1), -1.0, 1.0)))
    bias_before = float(np.mean(np.degrees(_inclination(u, level_down)) - model_incl))
    bias_after = float(np.mean(np.degrees(_inclination(u @ np.array(final).T, level_down)) - model_incl))
    fit = AlignmentFit(tuple(float(v) for v in angles), axes, rms_deg(solution.fun), rms_deg(residuals(start)),  # type: ignore[arg-type]
                       bias_before, bias_after, tuple(float(v) for v in stds),  # type: ignore[arg-type]
                       tuple(float(v) for v in eig), len(m))
    problems = []
    if eig[0] < limits.min_information:
        problems.append(f"the attitudes leave an angle unseen (information {eig[0]:.3f}, needs "
                        f"{limits.min_information:.3f}): turn through more headings")
    if np.nanmax(stds) > limits.max_std_deg:
        problems.append(f"a standard error of {np.nanmax(stds):.2f} deg (at most {limits.max_std_deg:.2f})")
    if np.max(np.abs(angles)) > MAX_ROTATION_DEG:
        problems.append(f"a rotation of {np.max(np.abs(angles)):.1f} deg (at most {MAX_ROTATION_DEG:.0f}: "
                        "check the magnetometer's declared orientation)")
    if problems:
        raise AlignmentRefused("alignment refused: " + "; ".join(problems) + "\n" + fit.describe())
    return fit
