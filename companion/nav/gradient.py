"""Estimating the gradient G(k) of (D, I) from the vehicle's own moves (eq. 5-12).

``G`` is the 2x2 Jacobian d(D, I)/d(x, y): rows D, I in degrees; columns east, north in
metres (see :mod:`companion`). No field model is used here: only measured changes of D and I
and the displacements that produced them, which is what makes the method mapless.

Start-up (eq. 6-9): two probing moves, theta_1 then theta_2 (Table 4: east, then south).
The paper divides each change by one coordinate change (eq. 6-9). :func:`gradient_from_moves`
solves ``G [dp_1 dp_2] = [dS_1 dS_2]`` instead, which is the same for axis-aligned probes and
stays right when the vehicle did not move exactly along an axis.

Updates while cruising (selectable, ``GRAD_UPDATE``):

* ``BROYDEN`` (default): the secant update ``G += beta (dS - G dp) dp^T / |dp|^2``. It makes G
  explain the last move exactly (beta = 1) and leaves the component across the move alone.
* ``PAPER`` (eq. 10 as printed): ``G += [dD; dI] [cos(theta)/(v_x T), sin(theta)/(v_y T)]``.
  Since ``v_x = v cos(theta)`` both factors equal ``1/(v T)``: the *whole* change in S is
  added to *both* columns on every step, so G grows without bound on a straight track, and a
  zero velocity component divides by zero (we then skip that column). Kept for comparison.
* ``TWO_MOVES``: a fresh estimate from the last two displacements (eq. 6-9 generalised),
  when they are far enough from parallel; otherwise the Broyden update.

Start (``GRAD_INIT``): 0 keeps G(2) from the probes; 1 (default) replaces it by the field
model's gradient at the estimated position (:meth:`GradientEstimator.start_from`). The model is
already used for every fix, so this costs no independence; two probe moves alone gave G poor
enough for LTI-MPC's fixed B to diverge in 3 of 50 runs.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["GradientUpdate", "MIN_MOVE_SINE", "gradient_from_moves", "broyden_update", "paper_update", "GradientEstimator"]


class GradientUpdate:
    """Values of GRAD_UPDATE."""

    BROYDEN = 0
    PAPER = 1
    TWO_MOVES = 2


MIN_MOVE_SINE = 0.2   # two moves closer to parallel than this (11.5 deg) give no gradient


def gradient_from_moves(ds1: np.ndarray, dp1: np.ndarray, ds2: np.ndarray, dp2: np.ndarray,
                        min_sine: float = MIN_MOVE_SINE) -> np.ndarray:
    """G from two moves: ``G = [dS_1 dS_2] [dp_1 dp_2]^-1`` (eq. 6-9 for axis-aligned moves).

    ``ds*`` are (dD, dI) in degrees, ``dp*`` (east, north) displacements in metres.
    Raises ValueError when the two moves are too close to parallel (|sin angle| < min_sine).
    """
    moves = np.column_stack([dp1, dp2]).astype(float)
    norm = np.linalg.norm(dp1) * np.linalg.norm(dp2)
    if norm == 0.0 or abs(np.linalg.det(moves)) / norm < min_sine:
        raise ValueError("gradient needs two moves in different directions")
    return np.linalg.solve(moves.T, np.column_stack([ds1, ds2]).T).T


def broyden_update(g: np.ndarray, ds: np.ndarray, dp: np.ndarray, gain: float = 1.0) -> np.ndarray:
    """Secant (Broyden) update: the new G maps ``dp`` onto ``ds`` (for gain 1)."""
    dp = np.asarray(dp, dtype=float)
    return g + gain * np.outer(np.asarray(ds, dtype=float) - g @ dp, dp) / float(dp @ dp)


def paper_update(g: np.ndarray, ds: np.ndarray, theta_rad: float, v_x: float, v_y: float, period_s: float) -> np.ndarray:
    """Eq. 10 as printed. A velocity component of zero leaves its column unchanged."""
    row = np.zeros(2)
    if v_x != 0.0:
        row[0] = math.cos(theta_rad) / (v_x * period_s)
    if v_y != 0.0:
        row[1] = math.sin(theta_rad) / (v_y * period_s)
    return g + np.outer(np.asarray(ds, dtype=float), row)


class GradientEstimator:
    """Keeps G(k) from the probing moves and updates it after each move.

    ``observe(ds, dp, theta_rad, v_x, v_y, period_s)`` is called once per control step with
    the change of S and the displacement of the step just flown.
    """

    def __init__(self, method: int = GradientUpdate.BROYDEN, min_move_m: float = 200.0, gain: float = 1.0) -> None:
        self.method = method
        self.min_move_m = min_move_m
        self.gain = gain
        self.g: np.ndarray | None = None
        self._moves: list[tuple[np.ndarray, np.ndarray]] = []

    @property
    def ready(self) -> bool:
        return self.g is not None

    def start_from(self, g: np.ndarray) -> np.ndarray:
        """Replace G by a given one (GRAD_INIT 1: the field model's gradient at the estimated
        position after the probes) and keep updating from there; returns it."""
        g = np.asarray(g, dtype=float)
        if g.shape != (2, 2) or not np.isfinite(g).all():
            raise ValueError(f"a starting gradient must be a finite 2 x 2 matrix, got {g!r}")
        self.g = g.copy()
        return self.g

    def observe(self, ds: np.ndarray, dp: np.ndarray, theta_rad: float, v_x: float, v_y: float,
                period_s: float, frozen: bool = False) -> np.ndarray | None:
        """Record one move; return the current G (None until both probes are in).

        ``frozen`` keeps G as it is after the probes (LTI-MPC).
        """
        ds = np.asarray(ds, dtype=float)
        dp = np.asarray(dp, dtype=float)
        if not (np.isfinite(ds).all() and np.isfinite(dp).all()):
            return self.g
        moved = float(np.linalg.norm(dp)) >= self.min_move_m
        if self.g is None:
            if moved:
                self._moves.append((ds, dp))
            if len(self._moves) >= 2:
                (ds1, dp1), (ds2, dp2) = self._moves[-2:]
                try:
                    self.g = gradient_from_moves(ds1, dp1, ds2, dp2)
                except ValueError:   # two moves along one line (the vehicle did not turn): no gradient yet
                    self.g = None
            return self.g
        if frozen or not moved:
            return self.g
        if self.method == GradientUpdate.PAPER:
            self.g = paper_update(self.g, ds, theta_rad, v_x, v_y, period_s)
        elif self.method == GradientUpdate.TWO_MOVES and self._moves:
            ds1, dp1 = self._moves[-1]
            try:
                self.g = gradient_from_moves(ds1, dp1, ds, dp)
            except ValueError:
                self.g = broyden_update(self.g, ds, dp, self.gain)
        else:
            self.g = broyden_update(self.g, ds, dp, self.gain)
        self._moves = [(ds, dp)]
        return self.g
