"""MPC of the magnetic state (companion.nav.mpc, paper eq. 13-38).

Oracles, each a different route from the code under test:

* M and C: matrices written out block by block from eq. 21-22, and the state recursion of
  eq. 19 simulated step by step.
* H and h: the cost J(U) of eq. 23 evaluated literally (a loop over the horizon); the QP form
  must reproduce it up to a constant for any U, and its minimiser must be the minimiser that
  scipy.optimize finds on the looped J.
* Constraints: separable problems whose clipped solution is known in closed form, KKT sign
  conditions, scipy's SLSQP on the looped J with the same constraints, and the two QP
  backends (OSQP, daqp) against each other.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize

from companion.nav.mpc import MpcController, MpcSettings, prediction_matrices, qp_cost


# --- helpers: eq. 19 and eq. 23 written literally -----------------------------------------------
def simulate(a: np.ndarray, b: np.ndarray, s0: np.ndarray, u_bar: np.ndarray) -> np.ndarray:
    """S(k+1|k) ... S(k+N|k) by the recursion of eq. 19, stacked."""
    horizon = len(u_bar) // 2
    states, s = [], np.asarray(s0, dtype=float)
    for j in range(horizon):
        s = a @ s + b @ u_bar[2 * j:2 * j + 2]
        states.append(s)
    return np.concatenate(states)


def cost_loop(a, b, s0, s_d, q, f, r, u_bar) -> float:
    """J(k) of eq. 23: sum_j U^T R U + sum_{i<N} (S_i - S_d)^T Q (.) + (S_N - S_d)^T F (.)."""
    horizon = len(u_bar) // 2
    q, f, r = np.diag(q), np.diag(f), np.diag(r)
    total, s = 0.0, np.asarray(s0, dtype=float)
    for j in range(horizon):
        u = u_bar[2 * j:2 * j + 2]
        total += u @ r @ u
        s = a @ s + b @ u
        e = s - s_d
        total += e @ (f if j == horizon - 1 else q) @ e
    return float(total)


def random_b(rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    return rng.normal(0.0, scale, (2, 2))


# --- eq. 20-22 -----------------------------------------------------------------------------------
def test_prediction_matrices_n2_identity_a_match_hand_built_blocks():
    b = np.array([[0.3, -0.7], [1.1, 0.2]])
    z, i2 = np.zeros((2, 2)), np.eye(2)
    m_hand = np.vstack([i2, i2])                       # (A, A^2)^T with A = I
    c_hand = np.block([[b, z], [b, b]])                # [[B, 0], [AB, B]]
    m, c = prediction_matrices(b, 2)
    assert m.shape == (4, 2) and c.shape == (4, 4)
    np.testing.assert_array_equal(m, m_hand)
    np.testing.assert_array_equal(c, c_hand)


def test_prediction_matrices_n3_non_identity_a_match_hand_built_blocks():
    a = np.array([[0.9, 0.2], [-0.1, 1.05]])
    b = np.array([[0.0, 2.0], [-1.5, 0.4]])            # one exact zero: still a plain product
    a2 = a @ a
    z = np.zeros((2, 2))
    m_hand = np.vstack([a, a2, a2 @ a])
    c_hand = np.block([[b, z, z], [a @ b, b, z], [a2 @ b, a @ b, b]])
    m, c = prediction_matrices(b, 3, a)
    np.testing.assert_allclose(m, m_hand, rtol=0, atol=1e-15)
    np.testing.assert_allclose(c, c_hand, rtol=0, atol=1e-15)


@pytest.mark.parametrize("horizon", [1, 2, 4, 6])
def test_stacked_prediction_equals_the_step_by_step_recursion(horizon):
    rng = np.random.default_rng(horizon)
    a = np.eye(2) + rng.normal(0.0, 0.2, (2, 2))
    b = random_b(rng)
    s0 = rng.normal(0.0, 5.0, 2)
    m, c = prediction_matrices(b, horizon, a)
    for _ in range(5):
        u_bar = rng.normal(0.0, 3.0, 2 * horizon)
        np.testing.assert_allclose(m @ s0 + c @ u_bar, simulate(a, b, s0, u_bar), rtol=1e-12, atol=1e-12)


# --- eq. 36-38 -----------------------------------------------------------------------------------
@pytest.mark.parametrize("horizon,identity_a", [(1, True), (2, True), (3, False), (5, True)])
def test_qp_form_reproduces_the_looped_cost_up_to_a_constant(horizon, identity_a):
    """J(U) = 0.5 U^T H U + h^T U + J(0) for any U: H and h are eq. 37-38 of *this* J."""
    rng = np.random.default_rng(10 + horizon)
    a = np.eye(2) if identity_a else np.array([[1.0, 0.1], [-0.05, 0.95]])
    b = random_b(rng)
    s0, s_d = rng.normal(0.0, 3.0, 2), rng.normal(0.0, 3.0, 2)
    q, f, r = np.array([1.5, 0.7]), np.array([3.0, 0.4]), np.array([0.2, 2.5])  # F != Q on purpose
    m, c = prediction_matrices(b, horizon, a)
    hess, grad = qp_cost(m, c, s0, np.tile(s_d, horizon), q, f, r)
    np.testing.assert_allclose(hess, hess.T, atol=0)
    constant = cost_loop(a, b, s0, s_d, q, f, r, np.zeros(2 * horizon))
    for _ in range(8):
        u_bar = rng.normal(0.0, 4.0, 2 * horizon)
        quadratic = 0.5 * u_bar @ hess @ u_bar + grad @ u_bar + constant
        assert quadratic == pytest.approx(cost_loop(a, b, s0, s_d, q, f, r, u_bar), rel=1e-11, abs=1e-9)


def test_qp_gradient_matches_finite_differences_of_the_looped_cost():
    """h is the gradient of J at U = 0 (eq. 38 with the factor 2 that eq. 37 implies)."""
    rng = np.random.default_rng(3)
    b = random_b(rng)
    s0, s_d = rng.normal(0.0, 2.0, 2), rng.normal(0.0, 2.0, 2)
    q, f, r = np.array([1.0, 2.0]), np.array([1.0, 1.0]), np.array([10.0, 10.0])
    m, c = prediction_matrices(b, 2)
    _, grad = qp_cost(m, c, s0, np.tile(s_d, 2), q, f, r)
    step = 1e-5
    fd = np.array([(cost_loop(np.eye(2), b, s0, s_d, q, f, r, step * e)
                    - cost_loop(np.eye(2), b, s0, s_d, q, f, r, -step * e)) / (2 * step) for e in np.eye(4)])
    np.testing.assert_allclose(grad, fd, rtol=1e-7, atol=1e-7)


@pytest.mark.parametrize("solver", ["osqp", "daqp"])
@pytest.mark.parametrize("horizon", [1, 2, 3])
def test_unconstrained_qp_minimiser_equals_brute_force_minimiser(solver, horizon):
    rng = np.random.default_rng(100 + horizon)
    b = random_b(rng)
    s0, s_d = rng.normal(0.0, 2.0, 2), rng.normal(0.0, 2.0, 2)
    q, f, r = (1.0, 2.0), (3.0, 1.0), (0.5, 0.8)
    ctrl = MpcController(MpcSettings(horizon=horizon, q=q, f=f, r=r, u_lower=(-50.0, -50.0),
                                     u_upper=(50.0, 50.0), solver=solver))
    sol = ctrl.solve(b, s0, s_d)
    assert sol.ok, sol.status
    brute = minimize(lambda u: cost_loop(np.eye(2), b, s0, s_d, np.array(q), np.array(f), np.array(r), u),
                     np.zeros(2 * horizon), method="BFGS", options={"gtol": 1e-10})
    assert np.max(np.abs(brute.x)) < 10.0  # the optimum is well inside the box: unconstrained
    np.testing.assert_allclose(sol.u_all, brute.x, atol=1e-5)
    np.testing.assert_allclose(sol.u_first, sol.u_all[:2])


# --- constraints (eq. 29-34) -----------------------------------------------------------------------
@pytest.mark.parametrize("solver", ["osqp", "daqp"])
def test_separable_problem_outside_the_box_is_clipped_to_the_bound(solver):
    """N = 1, diagonal B, Q, F, R: H is diagonal, so the box solution is the clipped
    unconstrained one, u_i = clip(-h_i / H_ii)."""
    b = np.diag([2.0, -0.5])
    s0, s_d = np.array([0.0, 0.0]), np.array([10.0, 3.0])
    f, r = np.array([1.0, 1.0]), np.array([0.1, 0.1])
    unconstrained = b.diagonal() * f * (s_d - s0) / (b.diagonal() ** 2 * f + r)  # per axis, by hand
    assert unconstrained[0] > 1.0 and unconstrained[1] < -1.0
    ctrl = MpcController(MpcSettings(horizon=1, q=(1.0, 1.0), f=tuple(f), r=tuple(r),
                                     u_lower=(-1.0, -1.0), u_upper=(1.0, 1.0), solver=solver))
    sol = ctrl.solve(b, s0, s_d)
    assert sol.ok, sol.status
    np.testing.assert_allclose(sol.u_first, np.clip(unconstrained, -1.0, 1.0), atol=1e-6)


@pytest.mark.parametrize("solver", ["osqp", "daqp"])
def test_box_clipping_satisfies_kkt_and_matches_bounded_brute_force(solver):
    rng = np.random.default_rng(7)
    horizon, bound = 2, 1.0
    q, f, r = np.array([1.0, 1.0]), np.array([1.0, 1.0]), np.array([0.05, 0.05])
    for trial in range(10):
        b = random_b(rng)
        s0, s_d = rng.normal(0.0, 1.0, 2), rng.normal(0.0, 1.0, 2) + 20.0 * rng.choice([-1, 1], 2)
        m, c = prediction_matrices(b, horizon)
        hess, grad = qp_cost(m, c, s0, np.tile(s_d, horizon), q, f, r)
        free = np.linalg.solve(hess, -grad)
        assert np.max(np.abs(free)) > bound  # the unconstrained optimum leaves the box
        ctrl = MpcController(MpcSettings(horizon=horizon, q=tuple(q), f=tuple(f), r=tuple(r),
                                         u_lower=(-bound,) * 2, u_upper=(bound,) * 2, solver=solver))
        sol = ctrl.solve(b, s0, s_d)
        assert sol.ok, sol.status
        u = sol.u_all
        assert np.all(u <= bound + 1e-6) and np.all(u >= -bound - 1e-6)
        assert np.any(np.abs(np.abs(u) - bound) < 1e-6)  # something is on the bound
        g = hess @ u + grad  # KKT: at an upper bound the cost still falls outwards (g <= 0) ...
        scale = np.max(np.abs(grad))
        for ui, gi in zip(u, g):
            if ui > bound - 1e-6:
                assert gi <= 1e-5 * scale
            elif ui < -bound + 1e-6:
                assert gi >= -1e-5 * scale
            else:  # ... and an interior component is stationary
                assert abs(gi) <= 1e-5 * scale
        brute = minimize(lambda x: cost_loop(np.eye(2), b, s0, s_d, q, f, r, x), np.zeros(2 * horizon),
                         method="L-BFGS-B", bounds=[(-bound, bound)] * (2 * horizon),
                         options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 10000})
        assert cost_loop(np.eye(2), b, s0, s_d, q, f, r, u) <= brute.fun + 1e-7 * max(1.0, abs(brute.fun)), trial
        np.testing.assert_allclose(u, brute.x, atol=1e-4)


@pytest.mark.parametrize("solver", ["osqp", "daqp"])
def test_active_state_constraint_is_respected(solver):
    """S_max just above the current state: the optimum would overshoot it, the QP stops on it."""
    horizon = 2
    q, f, r = np.array([1.0, 1.0]), np.array([1.0, 1.0]), np.array([1.0, 1.0])
    b = np.array([[1.0, 0.3], [-0.2, 0.8]])
    s0, s_d = np.array([0.0, 0.0]), np.array([5.0, 5.0])
    s_upper = (0.5, 0.8)  # close to S(k): active
    ctrl = MpcController(MpcSettings(horizon=horizon, q=tuple(q), f=tuple(f), r=tuple(r), u_lower=(-10.0, -10.0),
                                     u_upper=(10.0, 10.0), s_upper=s_upper, solver=solver))
    sol = ctrl.solve(b, s0, s_d)
    assert sol.ok, sol.status
    predicted = simulate(np.eye(2), b, s0, sol.u_all)
    tiled = np.tile(s_upper, horizon)
    assert np.all(predicted <= tiled + 1e-5)
    assert np.max(predicted - tiled) > -1e-5  # at least one state constraint is active
    # the free optimum violates the bound, so the constraint matters
    m, c = prediction_matrices(b, horizon)
    hess, grad = qp_cost(m, c, s0, np.tile(s_d, horizon), q, f, r)
    assert np.any(simulate(np.eye(2), b, s0, np.linalg.solve(hess, -grad)) > tiled)
    # brute force with the same constraints (scipy SLSQP on the looped J)
    cons = [{"type": "ineq", "fun": lambda x: tiled - simulate(np.eye(2), b, s0, x)}]
    brute = minimize(lambda x: cost_loop(np.eye(2), b, s0, s_d, q, f, r, x), np.zeros(2 * horizon),
                     method="SLSQP", bounds=[(-10.0, 10.0)] * (2 * horizon), constraints=cons,
                     options={"ftol": 1e-12, "maxiter": 1000})
    assert np.all(simulate(np.eye(2), b, s0, brute.x) <= tiled + 1e-6)
    assert cost_loop(np.eye(2), b, s0, s_d, q, f, r, sol.u_all) <= brute.fun + 1e-6
    np.testing.assert_allclose(sol.u_all, brute.x, atol=1e-4)


@pytest.mark.parametrize("solver", ["osqp", "daqp"])
def test_a_state_beyond_its_bounds_is_admitted_and_brought_back_not_farther_out(solver):
    """S beyond S_max: the paper's hard bounds (eq. 34) leave no feasible input; admitted (the
    default) the box is widened to S for the step, so the optimum is the brute-force one under
    the widened box, and it moves toward a target inside, never farther out."""
    horizon, q, f, r = 2, np.array([1.0, 1.0]), np.array([1.0, 1.0]), np.array([1.0, 1.0])
    b = np.array([[1.0, 0.3], [-0.2, 0.8]])
    s0, s_d = np.array([3.0, -1.0]), np.array([0.0, 0.0])    # D beyond S_max = 1, I inside
    settings = dict(horizon=horizon, q=tuple(q), f=tuple(f), r=tuple(r), u_lower=(-1.0, -1.0), u_upper=(1.0, 1.0),
                    s_lower=(-2.0, -2.0), s_upper=(1.0, 1.0), solver=solver)
    hard = MpcController(MpcSettings(**settings, admit_state=False)).solve(b, s0, s_d)
    assert not hard.ok and np.all(np.isnan(hard.u_all))
    admitted = MpcController(MpcSettings(**settings)).solve(b, s0, s_d)
    assert admitted.ok, admitted.status
    predicted = simulate(np.eye(2), b, s0, admitted.u_all)
    upper, lower = np.tile([3.0, 1.0], horizon), np.tile([-2.0, -2.0], horizon)   # widened to S on D's side
    assert np.all(predicted <= upper + 1e-6) and np.all(predicted >= lower - 1e-6)
    assert predicted[0] < s0[0]                                    # back toward the box
    cons = [{"type": "ineq", "fun": lambda x: upper - simulate(np.eye(2), b, s0, x)},
            {"type": "ineq", "fun": lambda x: simulate(np.eye(2), b, s0, x) - lower}]
    brute = minimize(lambda x: cost_loop(np.eye(2), b, s0, s_d, q, f, r, x), np.zeros(2 * horizon),
                     method="SLSQP", bounds=[(-1.0, 1.0)] * (2 * horizon), constraints=cons,
                     options={"ftol": 1e-12, "maxiter": 1000})
    np.testing.assert_allclose(admitted.u_all, brute.x, atol=1e-4)


def test_inside_the_bounds_admitting_the_state_changes_nothing():
    """Every random problem whose state lies inside its box: the same answer to the last bit."""
    rng = np.random.default_rng(11)
    settings = dict(horizon=3, s_lower=(-5.0, -5.0), s_upper=(5.0, 5.0))
    plain, admitted = (MpcController(MpcSettings(**settings, admit_state=a)) for a in (False, True))
    for _ in range(200):
        b, s0, s_d = random_b(rng), rng.uniform(-4.9, 4.9, 2), rng.uniform(-8.0, 8.0, 2)
        one, two = plain.solve(b, s0, s_d), admitted.solve(b, s0, s_d)
        assert one.ok == two.ok and np.array_equal(one.u_all, two.u_all)


@pytest.mark.parametrize("bound", [1.0, 2.5, 40.0])
@pytest.mark.parametrize("horizon", [1, 2, 3])
def test_osqp_and_daqp_agree_on_hundreds_of_random_problems(horizon, bound):
    """150 random problems per case, each with a box-only and a box+state-constrained
    controller: 300 solves per backend. Agreement is measured relative to the bound size."""
    rng = np.random.default_rng(2024 + horizon)
    weights = dict(q=(1.0, 2.0), f=(1.5, 1.0), r=(0.3 / bound**2, 0.6 / bound**2))
    settings = dict(horizon=horizon, u_lower=(-bound, -bound), u_upper=(bound, bound), **weights)
    # one controller per backend for all problems: warm starts between unrelated problems too
    ctrl_box = {s: MpcController(MpcSettings(solver=s, **settings)) for s in ("osqp", "daqp")}
    s_lo, s_hi = (-3.0, -2.0), (2.0, 4.0)
    ctrl_state = {s: MpcController(MpcSettings(solver=s, s_lower=s_lo, s_upper=s_hi, **settings))
                  for s in ("osqp", "daqp")}
    worst = 0.0
    for trial in range(150):
        b = random_b(rng, scale=10.0 ** rng.uniform(-1, 1)) / bound  # B U of the same size for any bound
        if trial % 5 == 0:
            b[rng.integers(2), rng.integers(2)] = 0.0
        target = rng.normal(0.0, 8.0, 2)
        for ctrls, s0 in ((ctrl_box, rng.normal(0.0, 3.0, 2)),
                          (ctrl_state, rng.uniform(np.array(s_lo) + 0.2, np.array(s_hi) - 0.2))):  # U = 0 feasible
            sol_o, sol_d = ctrls["osqp"].solve(b, s0, target), ctrls["daqp"].solve(b, s0, target)
            assert sol_o.ok and sol_d.ok, (trial, sol_o.status, sol_d.status)
            for sol in (sol_o, sol_d):
                assert np.all(np.abs(sol.u_all) <= bound * (1 + 1e-6))
            worst = max(worst, float(np.max(np.abs(sol_o.u_all - sol_d.u_all))) / bound)
    assert worst < 1e-4


def test_daqp_keeps_the_input_inside_a_box_that_is_not_unit_size():
    """Paper bounds U in [0, 40] km/h (MPC_UNITS=1 / MPC_U_BOUNDS=1 with MPC_SOLVER=1) are such a box."""
    ctrl = MpcController(MpcSettings(horizon=1, q=(1.0, 1.0), f=(1.0, 1.0), r=(1e-6, 1e-6),
                                     u_lower=(0.0, 0.0), u_upper=(40.0, 40.0), solver="daqp"))
    sol = ctrl.solve(np.eye(2), np.zeros(2), np.array([1000.0, 1000.0]))  # wants U = (1000, 1000)
    assert sol.ok
    np.testing.assert_allclose(sol.u_first, [40.0, 40.0], atol=1e-6)


@pytest.mark.parametrize("solver", ["osqp", "daqp"])
def test_same_controller_stays_correct_when_b_gains_and_loses_exact_zeros(solver):
    """Building CSC from a dense matrix drops zeros; the OSQP pattern must not depend on B."""
    ctrl = MpcController(MpcSettings(horizon=2, q=(1.0, 1.0), f=(1.0, 1.0), r=(0.5, 0.5),
                                     u_lower=(-20.0, -20.0), u_upper=(20.0, 20.0), solver=solver))
    s0, s_d = np.array([1.0, -2.0]), np.array([3.0, 1.5])
    sequence = [
        np.diag([1.0, 2.0]),                         # zeros off the diagonal
        np.array([[1.0, 0.5], [-0.4, 2.0]]),         # all non-zero
        np.array([[0.0, 0.5], [0.0, 2.0]]),          # a zero column
        np.array([[0.7, -1.2], [0.9, 0.3]]),
        np.array([[0.0, 0.0], [0.0, 1.0]]),          # singular, mostly zeros
        np.array([[1.3, 0.2], [0.1, -0.8]]),
    ]
    for b in sequence:
        m, c = prediction_matrices(b, 2)
        hess, grad = qp_cost(m, c, s0, np.tile(s_d, 2), np.ones(2), np.ones(2), np.full(2, 0.5))
        expected = np.linalg.solve(hess, -grad)  # closed form; well inside the +-20 box
        assert np.max(np.abs(expected)) < 20.0
        sol = ctrl.solve(b, s0, s_d)
        assert sol.ok, sol.status
        np.testing.assert_allclose(sol.u_all, expected, atol=1e-5, err_msg=str(b))


def test_non_finite_inputs_fail_cleanly_and_bad_settings_are_refused():
    ctrl = MpcController(MpcSettings())
    for b, s, t in ((np.full((2, 2), np.nan), np.zeros(2), np.ones(2)),
                    (np.eye(2), np.array([np.inf, 0.0]), np.ones(2)),
                    (np.eye(2), np.zeros(2), np.array([0.0, np.nan]))):
        sol = ctrl.solve(b, s, t)
        assert not sol.ok and np.all(np.isnan(sol.u_first))
    # after a failure, the controller still solves a good problem
    assert ctrl.solve(np.eye(2), np.zeros(2), np.full(2, 0.1)).ok
    with pytest.raises(ValueError, match="solver"):
        MpcController(MpcSettings(solver="cvxopt"))
    with pytest.raises(ValueError, match="horizon"):
        MpcController(MpcSettings(horizon=0))
    assert math.isfinite(ctrl.solve(np.eye(2), np.zeros(2), np.ones(2)).solve_time_s)
