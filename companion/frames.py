"""Rotations between the body frame and NED, written once (frames per :mod:`companion`).

ZYX Euler angles in radians: yaw (from north, clockwise) about down, then pitch about the
new y, then roll about x. ``mat_nb`` rotates body vectors into NED. The companion's tilt
compensation, the sensor drivers' attitude filter and the simulator's sensor model all use
these functions (:func:`mats_nb_from_euler`: many at once, the Monte Carlo's vectorised sample path).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["Matrix3", "Vector3", "body_to_ned", "mat_nb_from_euler", "mats_nb_from_euler", "ned_to_body", "rotate"]

Vector3 = tuple[float, float, float]
Matrix3 = tuple[Vector3, Vector3, Vector3]


def _rotation_nb(cr, sr, cp, sp, cy, sy):
    """The rows of body -> NED of ZYX Euler angles from their cosines and sines (floats or arrays)."""
    return (
        (cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy),
        (cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy),
        (-sp, sr * cp, cr * cp),
    )


def mat_nb_from_euler(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Matrix3:
    """Rotation matrix body -> NED of ZYX Euler angles."""
    return _rotation_nb(math.cos(roll_rad), math.sin(roll_rad), math.cos(pitch_rad), math.sin(pitch_rad),
                        math.cos(yaw_rad), math.sin(yaw_rad))


def mats_nb_from_euler(roll_rad, pitch_rad, yaw_rad) -> np.ndarray:
    """:func:`mat_nb_from_euler` of arrays of angles (broadcast): matrices (..., 3, 3).

    >>> (mats_nb_from_euler(0.0, 0.0, np.array([0.0, math.pi / 2])).round(9)[1] + 0.0).tolist()   # (+ 0.0: no -0.0)
    [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    """
    rows = _rotation_nb(np.cos(roll_rad), np.sin(roll_rad), np.cos(pitch_rad), np.sin(pitch_rad), np.cos(yaw_rad),
                        np.sin(yaw_rad))
    out = np.empty(np.broadcast(roll_rad, pitch_rad, yaw_rad).shape + (3, 3))
    for i, row in enumerate(rows):
        for j, value in enumerate(row):
            out[..., i, j] = value
    return out


def body_to_ned(vec_b: Vector3, roll_rad: float, pitch_rad: float, yaw_rad: float) -> Vector3:
    """A body-frame vector expressed in NED.

    >>> [round(c, 9) for c in body_to_ned((1.0, 0.0, 0.0), 0.0, 0.0, math.pi / 2)]  # nose east
    [0.0, 1.0, 0.0]
    """
    return rotate(mat_nb_from_euler(roll_rad, pitch_rad, yaw_rad), vec_b)


def rotate(mat: Matrix3, vec: Vector3) -> Vector3:
    """``mat @ vec`` of a 3x3 matrix (rows) and a vector, in floats: one matrix from
    :func:`mat_nb_from_euler` for several vectors of the same instant."""
    x, y, z = vec
    return (mat[0][0] * x + mat[0][1] * y + mat[0][2] * z,
            mat[1][0] * x + mat[1][1] * y + mat[1][2] * z,
            mat[2][0] * x + mat[2][1] * y + mat[2][2] * z)


def ned_to_body(vec_n: Vector3, roll_rad: float, pitch_rad: float, yaw_rad: float) -> Vector3:
    """A NED vector expressed in the body frame (the transpose of :func:`body_to_ned`).

    >>> [round(c, 9) for c in ned_to_body((1.0, 0.0, 0.0), 0.0, 0.0, math.pi / 2)]  # north is to the left
    [0.0, -1.0, 0.0]
    """
    m = mat_nb_from_euler(roll_rad, pitch_rad, yaw_rad)
    n, e, d = vec_n
    return (m[0][0] * n + m[1][0] * e + m[2][0] * d,
            m[0][1] * n + m[1][1] * e + m[2][1] * d,
            m[0][2] * n + m[1][2] * e + m[2][2] * d)
