"""Process models of the navigation filter: what happens to the position error between steps.

Two models answer the same questions (a small protocol, so :mod:`companion.nav.navfilter`
never branches on the model):

* :class:`InsProcess`: a navigation-grade INS whose solution is independent of this navigator
  (the paper's INS). The state is the INS error of :mod:`companion.nav.ins_error` (15 states,
  Schuler and Earth-rate coupling), propagated exactly over each step. The INS is never
  corrected (open-loop: the flight controller's INS is not ours to reset); the fused position
  is the INS-indicated position minus the estimated error.
* :class:`DeadReckoningProcess`: no independent INS (ArduPilot or PX4 with MEMS sensors, whose
  position after GPS loss is our own estimate fed back). The navigator keeps a nominal position,
  advanced by the commanded (or measured) velocity plus the estimated current; the state is the
  error of that nominal position (east, north, m) and of the current (east, north, m/s), the
  current a random walk. After each update the error is folded into the nominal position and
  the current and reset to zero (error-state feedback).

Each model gives: its size ``n``, the prior covariance ``p0``, the transition ``(Phi, Q_d)`` of
one step, the position estimate, and ``J = d(true east, north) / d(state)`` in metres, which
maps any position-like measurement (a GPS fix, the field's gradient) onto the state.
"""
from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from companion.nav.geo import offset_position, radii_of_curvature_m
from companion.nav.ins_error import (
    LAT,
    LON,
    N_INS,
    InsErrorSpec,
    discretise,
    error_dynamics,
    initial_covariance,
    process_noise_density,
)
from companion.registry import settings

__all__ = ["DeadReckoningProcess", "DeadReckoningSpec", "InsProcess", "ProcessModel"]

HOUR_S = 3600.0


class InsProcess:
    """INS error states; the position estimate is the INS-indicated position minus the error."""

    name = "ins"
    n = N_INS

    def __init__(self, spec: InsErrorSpec, lat_deg: float) -> None:
        self.spec = spec
        self.q_c = process_noise_density(spec)
        self.p0 = initial_covariance(spec, lat_deg)

    def transition(self, dt_s: float, lat_deg: float, vel_en_mps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Phi and Q_d over ``dt_s`` at the INS-indicated latitude and the (commanded) velocity."""
        f = error_dynamics(lat_deg, float(vel_en_mps[0]), float(vel_en_mps[1]), self.spec.gyro_markov_tau_s)
        return discretise(f, self.q_c, dt_s)

    def position(self, x: np.ndarray, ins_lat_deg: float, ins_lon_deg: float) -> tuple[float, float]:
        """True position estimate: INS minus the estimated error (degrees)."""
        return ins_lat_deg - math.degrees(x[LAT]), ins_lon_deg - math.degrees(x[LON])

    def jacobian(self, lat_deg: float) -> np.ndarray:
        """d(true east, north in m) / d(state): true = INS - error."""
        m, n = (float(r) for r in radii_of_curvature_m(lat_deg))
        j = np.zeros((2, self.n))
        j[0, LON] = -n * math.cos(math.radians(lat_deg))
        j[1, LAT] = -m
        return j

    def advance(self, x: np.ndarray, dt_s: float, vel_en_mps: np.ndarray) -> None:
        """Nothing to move: the INS solution moves by itself."""

    def snapshot(self) -> None:
        return None

    def restore(self, state: None) -> None:
        """Nothing kept outside the filter's state."""

    def reset(self, x: np.ndarray) -> np.ndarray:
        """Open loop: the INS is not corrected, the error estimate is kept whole."""
        return x


@settings("dead_reckoning")
class DeadReckoningSpec:
    """Dead-reckoning uncertainty: ``pos_sigma_m`` per step (the vehicle's turns and speed
    changes between commands), ``speed_frac`` of each step's length (speed/course error of
    the commanded velocity), the current's prior ``current_sigma_mps`` and its random walk
    ``current_q_mps_rth`` (m/s per sqrt(hour))."""

    pos_sigma_m: float
    current_sigma_mps: float
    current_q_mps_rth: float
    speed_frac: ClassVar[float] = 0.02   # a property of the commanded velocity, not a setting


class DeadReckoningProcess:
    """Nominal position + current, with error states (de, dn, dce, dcn)."""

    name = "dead_reckoning"
    n = 4

    def __init__(self, spec: DeadReckoningSpec, lat_deg: float, lon_deg: float, pos_sigma_m: float) -> None:
        self.spec = spec
        self.nominal = (float(lat_deg), float(lon_deg))
        self.current = np.zeros(2)
        self.p0 = np.diag([pos_sigma_m ** 2] * 2 + [spec.current_sigma_mps ** 2] * 2)

    def transition(self, dt_s: float, lat_deg: float, vel_en_mps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position error integrates the current error; the current is a random walk."""
        f = np.zeros((4, 4))
        f[0, 2] = f[1, 3] = 1.0
        q_c = np.diag([0.0, 0.0] + [self.spec.current_q_mps_rth ** 2 / HOUR_S] * 2)
        phi, q_d = discretise(f, q_c, dt_s)
        step = float(np.hypot(*vel_en_mps)) * dt_s
        q_d[0:2, 0:2] += np.eye(2) * (self.spec.pos_sigma_m ** 2 + (self.spec.speed_frac * step) ** 2)
        return phi, q_d

    def snapshot(self) -> tuple:
        return self.nominal, self.current.copy()

    def restore(self, state: tuple) -> None:
        self.nominal, current = state
        self.current = current.copy()

    def advance(self, x: np.ndarray, dt_s: float, vel_en_mps: np.ndarray) -> None:
        """Move the nominal position by the commanded velocity plus the estimated current."""
        moved = (np.asarray(vel_en_mps, dtype=float) + self.current) * dt_s
        lat, lon = offset_position(*self.nominal, float(moved[0]), float(moved[1]))
        self.nominal = (float(lat), float(lon))

    def position(self, x: np.ndarray, ins_lat_deg: float = math.nan, ins_lon_deg: float = math.nan) -> tuple[float, float]:
        """True position estimate: the nominal position plus the estimated error."""
        lat, lon = offset_position(*self.nominal, float(x[0]), float(x[1]))
        return float(lat), float(lon)

    def jacobian(self, lat_deg: float) -> np.ndarray:
        j = np.zeros((2, self.n))
        j[0, 0] = j[1, 1] = 1.0
        return j

    def reset(self, x: np.ndarray) -> np.ndarray:
        """Fold the estimated errors into the nominal position and the current; zero them."""
        self.nominal = self.position(x)
        self.current = self.current + x[2:4]
        out = x.copy()
        out[0:4] = 0.0
        return out


ProcessModel = InsProcess | DeadReckoningProcess
