"""The local model-error states of the navigation filter: the map's error along the route.

What the measured elements carry beyond the main-field map and the start-up calibration
changes along the route (the crust, the map's own error): per element a Gauss-Markov process
in the *distance travelled* ``d`` (standing still does not decorrelate it), of stationary
1-sigma ``sigma`` and correlation length ``L`` (FUS_GM_DEG, FUS_GM_NT, FUS_GM_KM), of order
one or two (FUS_GM_ORDER):

* order 1, ``m' = -m / L + w``: autocorrelation ``sigma^2 exp(-d / L)``. Its paths are rough:
  over a short leg ``d`` it changes by ``sigma sqrt(2 d / L)``, so within one control step it
  may take up a position error as large as the step's share of the whole variance.
* order 2, critically damped, ``m'' = -2 m' / L - m / L^2 + w`` (states ``m`` and ``m'``, the
  error's slope along the track): autocorrelation ``sigma^2 (1 + d / L) exp(-d / L)``. Its paths
  are smooth, changing over a short leg by about ``sigma d / L``, as a band-limited field does:
  the real crust (EMM2017, wavelengths of 51 km and more) minus WMM along the Pacific route
  changes by 0.0026 deg of D per km and 0.013 deg per 5 km (linearly with the lag), where the
  first-order process of the same variance and length changes by 0.03 deg per 5 km.

Only ``m`` enters the measurement (:attr:`LocalError.columns`); the slope is what makes the
process smooth. Discretised exactly over each step's distance (Van Loan, as the INS error,
:func:`companion.nav.ins_error.discretise`).

>>> local = LocalError(np.array([0.05]), 25_000.0, 2)
>>> phi, q = local.transition(5_000.0)
>>> round(float(np.sqrt(2.0 * 0.05 ** 2 - 2.0 * phi[0] @ local.initial_covariance()[:, 0])), 4)   # rms change over 5 km
0.0094
"""
from __future__ import annotations

import functools
import math

import numpy as np

from companion.nav.ins_error import discretise

__all__ = ["LocalError"]


@functools.lru_cache(maxsize=64)
def _unit_step(order: int, length_m: float, distance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Q_d) of the unit-variance process over ``distance_m`` (order x order, read-only)."""
    if order == 1:
        decay = math.exp(-distance_m / length_m)
        phi, q = np.array([[decay]]), np.array([[1.0 - decay * decay]])
    else:
        w = 1.0 / length_m
        f = np.array([[0.0, 1.0], [-w * w, -2.0 * w]])
        q_c = np.array([[0.0, 0.0], [0.0, 4.0 * w ** 3]])   # stationary var(m) = 1, var(m') = w^2
        phi, q = discretise(f, q_c, distance_m)
    phi.setflags(write=False)
    q.setflags(write=False)
    return phi, q


class LocalError:
    """Local model-error states, ``order`` per element: the values first, then (order 2) the slopes."""

    def __init__(self, sigma: np.ndarray, length_m: float, order: int) -> None:
        if order not in (1, 2):
            raise ValueError(f"FUS_GM_ORDER must be 1 or 2, not {order}")
        self.sigma = np.asarray(sigma, dtype=float)
        self.length_m = float(length_m)
        self.order = order
        self.elements = len(self.sigma)
        self.n = self.elements * order

    def columns(self, nb: int) -> np.ndarray:
        """How the states enter the ``nb`` measured elements (nb x n): each element's value, one for one."""
        c = np.zeros((nb, self.n))
        c[:self.elements, :self.elements] = np.eye(nb)[:self.elements, :self.elements]
        return c

    def _blocks(self, unit: np.ndarray, scale: np.ndarray) -> np.ndarray:
        """The per-element ``order x order`` block ``unit`` scaled by ``scale`` per element, laid out
        values first, then slopes (n x n)."""
        m = self.elements
        out = np.zeros((self.n, self.n))
        for i in range(self.order):
            for j in range(self.order):
                out[i * m:(i + 1) * m, j * m:(j + 1) * m] = np.diag(unit[i, j] * scale)
        return out

    def initial_covariance(self) -> np.ndarray:
        """The stationary covariance: ``sigma^2`` for the values, ``(sigma / L)^2`` for the slopes."""
        unit = np.diag([1.0, 1.0 / self.length_m ** 2][:self.order])
        return self._blocks(unit, self.sigma ** 2)

    def transition(self, distance_m: float) -> tuple[np.ndarray, np.ndarray]:
        """``(Phi, Q_d)`` over ``distance_m`` travelled (n x n each)."""
        phi, q = _unit_step(self.order, self.length_m, float(distance_m))
        return self._blocks(phi, np.ones(self.elements)), self._blocks(q, self.sigma ** 2)
