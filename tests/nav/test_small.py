"""The closed-form small linear algebra against numpy's LAPACK calls."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from companion.nav.small import inverse2, solve2, whiten

# the navigator's 2 x 2 matrices: G ~1e-6 deg/m, B = G T in QP units ~1e0-1e3; products of
# entries below ~1e-154 underflow (numpy's LU then calls a subnormal matrix singular, Cramer's
# determinant rounds to zero): outside what the closed forms are for
finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False).filter(lambda v: v == 0.0 or abs(v) > 1e-100)


@settings(max_examples=300, deadline=None)
@given(st.lists(finite, min_size=6, max_size=6))
def test_solve2_and_inverse2_agree_with_numpy(values):
    a, b = np.array(values[:4]).reshape(2, 2), np.array(values[4:])
    cond = np.linalg.cond(a)
    assume(cond < 1e8)   # the fix rejects G beyond 1e6
    expected = np.linalg.solve(a, b)
    # forward error of a backward-stable 2 x 2 solve: a few ulps times the condition number
    tolerance = 1e-14 * cond * (np.abs(expected).max() + np.abs(np.linalg.inv(a) @ b).max() + 1e-300)
    np.testing.assert_allclose(solve2(a, b), expected, rtol=0, atol=tolerance + 1e-300)
    np.testing.assert_allclose(inverse2(a) @ a, np.eye(2), rtol=0, atol=1e-13 * cond)


def test_singular_matrices_raise_like_numpy():
    singular = np.array([[1.0, 2.0], [2.0, 4.0]])
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.solve(singular, np.ones(2))
    with pytest.raises(np.linalg.LinAlgError):
        solve2(singular, np.ones(2))
    with pytest.raises(np.linalg.LinAlgError):
        inverse2(singular)


def test_nan_propagates_instead_of_raising():
    a = np.array([[1.0, np.nan], [0.5, 2.0]])
    assert np.all(np.isnan(solve2(a, np.ones(2))))


@pytest.mark.parametrize("m", [1, 2, 3, 5])
def test_whiten_is_the_cholesky_forward_substitution(m):
    rng = np.random.default_rng(m)
    for _ in range(200):
        root = rng.normal(size=(m, m)) * rng.lognormal(0.0, 1.0, size=m)
        s = root @ root.T + np.eye(m) * 1e-3
        y = rng.normal(size=m)
        expected = np.linalg.solve(np.linalg.cholesky(s), y)
        got = whiten(s, y)
        scale = 1e-14 * np.linalg.cond(s) * np.abs(expected).max()
        np.testing.assert_allclose(got, expected, rtol=0, atol=scale)
        assert got @ got == pytest.approx(y @ np.linalg.solve(s, y), rel=1e-12 * np.linalg.cond(s))


def test_whiten_rejects_a_matrix_that_is_not_positive_definite():
    with pytest.raises(np.linalg.LinAlgError):
        whiten(np.array([[1.0, 2.0], [2.0, 1.0]]), np.ones(2))
    with pytest.raises(np.linalg.LinAlgError):
        whiten(np.array([[np.nan, 0.0], [0.0, 1.0]]), np.ones(2))
