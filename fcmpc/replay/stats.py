"""Small numeric helpers shared by the evaluation: angle wrapping, tilt, percentiles."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["wrap_pi", "wrap180", "tilt_deg", "percentile", "interp_gps", "circ_mean_deg", "circ_std_deg"]

def tilt_deg(att: np.ndarray) -> np.ndarray:
    return np.degrees(np.maximum(np.abs(wrap_pi(att[:, 1])), np.abs(wrap_pi(att[:, 2]))))


def wrap_pi(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def wrap180(a: Any) -> Any:
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def interp_gps(gps: np.ndarray, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GPS latitude, longitude, altitude interpolated at times t (held at the ends)."""
    return (np.interp(t, gps[:, 0], gps[:, 1]), np.interp(t, gps[:, 0], gps[:, 2]),
            np.interp(t, gps[:, 0], gps[:, 3]))


def percentile(values: list[float] | np.ndarray, q: float) -> float:
    a = np.asarray([v for v in values if math.isfinite(v)], dtype=float)
    return float(np.percentile(a, q)) if len(a) else math.nan


def circ_mean_deg(a_deg: np.ndarray | list[float]) -> float:
    """Circular mean of angles in degrees, in (-180, 180] (NaN for no angles)."""
    a = np.radians(np.asarray(a_deg, dtype=float))
    if not len(a):
        return math.nan
    return float(np.degrees(np.arctan2(np.sin(a).mean(), np.cos(a).mean())))


def circ_std_deg(a_deg: np.ndarray | list[float]) -> float:
    """Circular standard deviation ``sqrt(-2 ln R)`` in degrees, R the mean resultant length.

    Equal to the linear standard deviation for small spreads, and right for angles that wrap
    at +-180 deg, where a linear standard deviation of wrapped values is meaningless.
    """
    a = np.radians(np.asarray(a_deg, dtype=float))
    if not len(a):
        return math.nan
    r = math.hypot(float(np.sin(a).mean()), float(np.cos(a).mean()))
    return float(np.degrees(math.sqrt(-2.0 * math.log(min(max(r, 1e-300), 1.0)))))
