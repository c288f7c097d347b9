"""What is down on a magnetometer calibration circle: the accelerometer's level under the flight
controller's attitude, and the level fit of the circle's samples with it (issue 47.3).

:func:`companion.nav.calibration.fit_level_calibration` needs each sample's down in the body frame.
The flight controller's roll and pitch follow the waves sample by sample, but carry its estimate's
mean tilt error: ArduPilot's EKF was +1.4 deg off in pitch on the circle in lockstep (its tilt traded
against an accelerometer bias), and a fit levelled with it turned that error into soft iron; the
mission's gravity-referenced inclination then erred with the heading (-1.3 to +1.6 deg;
docs/notes/2026-12-06-ardupilot-json-lockstep.md section 6). The accelerometer's specific force,
less the turn's centripetal acceleration, is the reference that inclination is measured against.

>>> d = down_from_specific_force([(0.0, 0.1745, -9.81)], [(0.0, 0.0, 0.02181)], 8.0)   # 1.25 deg/s right
>>> [round(float(v), 4) + 0.0 for v in d[0]]
[0.0, 0.0, 1.0]
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from companion.nav.calibration import (
    CalibrationFit,
    CalibrationLimits,
    down_in_body,
    fit_level_calibration,
)

__all__ = ["CIRCLE_COLUMNS", "LEVEL_WINDOW", "down_from_specific_force", "fit_circle_calibration"]


def down_from_specific_force(force_body: ArrayLike, gyro_body_radps: ArrayLike, speed_mps: float) -> np.ndarray:
    """Unit vectors (n, 3) of NED's down in the body frame from the accelerometer alone: the
    specific force with the turn's centripetal acceleration ``w x v`` removed (``v = (speed, 0, 0)``:
    a vehicle moving along its body x at ``speed_mps``; ``w``: the gyro), negated and normalised;
    NaN rows where the force is not finite or zero."""
    f = np.asarray(force_body, dtype=float).reshape(-1, 3)
    w = np.asarray(gyro_body_radps, dtype=float).reshape(-1, 3)
    if len(w) != len(f):
        raise ValueError(f"gyro_body_radps has {len(w)} rows for {len(f)} specific forces")
    centripetal = np.cross(w, np.array([float(speed_mps), 0.0, 0.0]))
    gravity = -(f - centripetal)
    norm = np.linalg.norm(gravity, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        down = gravity / norm[:, None]
    down[~(np.isfinite(norm) & (norm > 0.0))] = np.nan
    return down


CIRCLE_COLUMNS = 11
"""A calibration circle's sample: body field (3, nT), the flight controller's roll and pitch (rad),
specific force (3, m/s^2) and gyro (3, rad/s) of the same instant (NaN: none)."""
LEVEL_WINDOW = 301
"""Samples (about 30 s of a 10 Hz magnetometer) over which :func:`fit_circle_calibration` takes the
accelerometer's level: many wave periods, a few degrees of the circle."""


def _moving_mean(x: np.ndarray, window: int) -> np.ndarray:
    """Centred moving mean of the rows of ``x`` over ``window`` rows (fewer at the ends)."""
    half = window // 2
    csum = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    idx = np.arange(len(x))
    lo, hi = np.maximum(idx - half, 0), np.minimum(idx + half + 1, len(x))
    return (csum[hi] - csum[lo]) / (hi - lo)[:, None]


def fit_circle_calibration(rows: ArrayLike, speed_mps: float, horizontal_nt: float, vertical_nt: float,
                           limits: CalibrationLimits = CalibrationLimits()) -> tuple[CalibrationFit, bool]:
    """The level fit of samples (n, :data:`CIRCLE_COLUMNS`) recorded on circles flown at ``speed_mps``,
    and whether the accelerometer set its level (False: no sample had an IMU reading, the flight
    controller's attitude alone levelled it).

    Each sample's down is the flight controller's (it follows the waves' roll and pitch sample by
    sample, which the accelerometer's specific force, shaken by the waves' accelerations, does
    not), moved by the difference between the specific force's down
    (:func:`down_from_specific_force`, the turn's centripetal part removed) and the attitude's, each
    a moving mean over :data:`LEVEL_WINDOW` samples: the accelerometer sets the level, the attitude
    its motion (the speed-up at the circle's start, whose acceleration tilts the specific force,
    0.5 m/s^2 by 3 deg, is the caller's to leave out). Raises
    :class:`~companion.nav.calibration.CalibrationRefused` as :func:`fit_level_calibration`."""
    rows = np.asarray(rows, dtype=float).reshape(-1, CIRCLE_COLUMNS)
    attitude = down_in_body(rows[:, 3], rows[:, 4])
    gravity = down_from_specific_force(rows[:, 5:8], rows[:, 8:11], speed_mps)
    both = np.isfinite(gravity).all(axis=1) & np.isfinite(attitude).all(axis=1)
    down = attitude
    if both.any():   # the attitude's motion (waves), the accelerometer's level
        shift = _moving_mean(gravity[both], LEVEL_WINDOW) - _moving_mean(attitude[both], LEVEL_WINDOW)
        at, index = np.flatnonzero(both), np.arange(len(rows))
        moved = attitude + np.column_stack([np.interp(index, at, shift[:, k]) for k in range(3)])
        down = moved / np.linalg.norm(moved, axis=1)[:, None]
    fit = fit_level_calibration(rows[:, :3], down, horizontal_nt, vertical_nt, limits)
    return fit, bool(both.any())
