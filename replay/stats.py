"""Small numeric helpers shared by the evaluation: angle wrapping, tilt, percentiles."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["wrap_pi", "wrap180", "tilt_deg", "percentile", "interp_gps"]

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
