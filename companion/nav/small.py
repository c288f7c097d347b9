"""Closed forms for the 2 x 2 (and up to 3 x 3) linear algebra of one navigation step.

The navigator's matrices are tiny: G of the steering pair and B = G T are 2 x 2, the innovation
covariance S is m x m with m the 2-3 measured elements. On those numpy's LAPACK calls cost
10-50 times their arithmetic (argument checks, array wrapping); these closed forms give the same
answers, to rounding, for plain floats:

* :func:`solve2` / :func:`inverse2`: Cramer's rule, ``x = adj(A) b / det A``;
* :func:`whiten`: ``L^-1 y`` with ``S = L L^T`` (Cholesky), by forward substitution; numpy's
  for m > 3.

Singular input raises numpy's ``LinAlgError``, as numpy does (an exactly zero determinant; a
non-positive pivot of S). For entries whose products underflow (below ~1e-154) the determinant
rounds to zero: far outside the navigator's matrices (G ~1e-6 deg/m, B in QP units ~1-1e3).
Cramer's rule is forward-stable on 2 x 2 systems to a few ulps times the condition number, which
the fix bounds (``max_condition`` 1e6); tested against numpy on random and near-singular
matrices (``tests/nav/test_small.py``).

* :func:`condition2` / :func:`smallest_singular_value`: a 2 x 2 matrix's singular values from
  ``sigma1^2 + sigma2^2 = |A|_F^2`` and ``sigma1 sigma2 = |det A|`` (the fix's conditioning, the
  plausibility gate's weak gradient; LAPACK's SVD took ~85 us).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["condition2", "inverse2", "smallest_singular_value", "solve2", "whiten"]


def solve2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with ``a x = b`` for a 2 x 2 ``a`` and a 2-vector ``b``."""
    (a11, a12), (a21, a22) = a.tolist()
    b1, b2 = b.tolist()
    det = a11 * a22 - a12 * a21
    if det == 0.0:
        raise np.linalg.LinAlgError("Singular matrix")
    return np.array([(a22 * b1 - a12 * b2) / det, (a11 * b2 - a21 * b1) / det])


def inverse2(a: np.ndarray) -> np.ndarray:
    """The inverse of a 2 x 2 matrix."""
    (a11, a12), (a21, a22) = np.asarray(a, dtype=float).tolist()
    det = a11 * a22 - a12 * a21
    if det == 0.0:
        raise np.linalg.LinAlgError("Singular matrix")
    return np.array([[a22 / det, -a12 / det], [-a21 / det, a11 / det]])


def condition2(g: np.ndarray) -> float:
    """2-norm condition number of a 2x2 matrix (closed form; inf when singular, NaN propagates)."""
    a, b, c, d = (float(v) for v in g.ravel())
    frobenius2 = a * a + b * b + c * c + d * d
    det = abs(a * d - b * c)
    if det == 0.0:
        return math.inf
    # sigma_max / sigma_min from sigma1^2 + sigma2^2 = |G|_F^2 and sigma1 * sigma2 = |det G|
    ratio = frobenius2 / (2.0 * det)
    return ratio + math.sqrt(max(ratio * ratio - 1.0, 0.0))


def smallest_singular_value(matrix: np.ndarray) -> float:
    """The smallest singular value of ``matrix``; a finite 2 x 2 one in closed form, ``|det| / sigma_max``
    with ``sigma_max^2 = (|M|_F^2 + sqrt(|M|_F^4 - 4 det^2)) / 2`` (no cancellation in the small one),
    anything else by :func:`numpy.linalg.svd` (which raises on NaN).

    >>> smallest_singular_value(np.array([[3.0, 0.0], [0.0, -0.5]])), smallest_singular_value(np.zeros((2, 2)))
    (0.5, 0.0)
    """
    if matrix.shape != (2, 2) or not np.isfinite(matrix).all():
        return float(np.linalg.svd(matrix, compute_uv=False)[-1])
    (a, b), (c, d) = matrix.tolist()
    det = abs(a * d - b * c)
    frobenius2 = a * a + b * b + c * c + d * d
    largest = math.sqrt(0.5 * (frobenius2 + math.sqrt(max(frobenius2 * frobenius2 - 4.0 * det * det, 0.0))))
    return det / largest if largest > 0.0 else 0.0


def whiten(s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``L^-1 y`` where ``S = L L^T`` is the Cholesky factor of the symmetric positive-definite
    ``s`` (its lower triangle is read): ``y^T S^-1 y`` is the squared norm of the result."""
    m = len(y)
    if m > 3:
        return np.linalg.solve(np.linalg.cholesky(s), y)
    rows, values = s.tolist(), y.tolist()
    low: list[list[float]] = []
    out: list[float] = []
    for i in range(m):
        row = []
        for j in range(i):
            row.append((rows[i][j] - sum(row[k] * low[j][k] for k in range(j))) / low[j][j])
        pivot = rows[i][i] - sum(v * v for v in row)
        if not pivot > 0.0:   # also NaN
            raise np.linalg.LinAlgError("Matrix is not positive definite")
        row.append(math.sqrt(pivot))
        low.append(row)
        out.append((values[i] - sum(row[k] * out[k] for k in range(i))) / row[i])
    return np.array(out)
