"""Sparse Schur-complement LM against SciPy's dense solver and the dense covariance."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from core.errors import ConvergenceError, InvalidInput
from core.optim import solve_sparse_lm
from core.optim._sparse_lm import _normal_blocks

P, M, R = 3, 12, 5  # global size, blocks, residuals per block


class _RandomProblem:
    """Block j: r_j = z + 0.2 z^3 - y_j with z = A_j g + B_j l_j + c_j (smooth, non-linear,
    arrow-shaped): every residual block touches the global block and its own local block."""

    def __init__(self, q: int, seed: int) -> None:
        rng = np.random.default_rng(seed)
        self.q = q
        self.a = rng.normal(size=(M, R, P))
        self.b = rng.normal(size=(M, R, q))
        self.c = rng.normal(size=(M, R)) * 0.3
        self.g_true = rng.normal(size=P)
        self.l_true = rng.normal(size=(M, q))
        self.y = self._model(self.g_true, self.l_true) + 0.05 * rng.normal(size=(M, R))

    def _z(self, g: np.ndarray, loc: np.ndarray) -> np.ndarray:
        return self.a @ g + (self.b @ loc[:, :, None])[:, :, 0] + self.c

    def _model(self, g: np.ndarray, loc: np.ndarray) -> np.ndarray:
        z = self._z(g, loc)
        return z + 0.2 * z**3

    def residuals(self, g: np.ndarray, loc: np.ndarray) -> np.ndarray:
        return self._model(g, loc) - self.y

    def jacobians(self, g: np.ndarray, loc: np.ndarray):
        z = self._z(g, loc)
        d = (1.0 + 0.6 * z**2)[:, :, None]
        return self.residuals(g, loc), d * self.a, d * self.b

    # Dense view for the references.
    def flat_residuals(self, theta: np.ndarray) -> np.ndarray:
        return self.residuals(theta[:P], theta[P:].reshape(M, self.q)).ravel()

    def dense_jacobian(self, theta: np.ndarray) -> np.ndarray:
        _, jg, jl = self.jacobians(theta[:P], theta[P:].reshape(M, self.q))
        jac = np.zeros((M * R, P + M * self.q))
        for j in range(M):
            jac[j * R : (j + 1) * R, :P] = jg[j]
            jac[j * R : (j + 1) * R, P + j * self.q : P + (j + 1) * self.q] = jl[j]
        return jac


class _HookedProblem(_RandomProblem):
    """The same problem assembling its normal equations itself (the optional fast path)."""

    def normal_equations(self, g: np.ndarray, loc: np.ndarray):
        return _normal_blocks(*self.jacobians(g, loc))


@pytest.mark.parametrize("q", [0, 1, 2, 3])
def test_optimum_matches_scipy(q: int) -> None:
    prob = _RandomProblem(q, seed=10 + q)
    g0 = prob.g_true + 0.3
    l0 = prob.l_true - 0.2
    ours = solve_sparse_lm(prob, g0, l0)
    ref = least_squares(
        prob.flat_residuals,
        np.concatenate([g0, l0.ravel()]),
        jac=prob.dense_jacobian,
        method="lm",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    theta = np.concatenate([ours.x_global, ours.x_local.ravel()])
    # Both converge to the same isolated minimum of a smooth problem; at 1e-12 ftol/xtol the
    # parameters agree far below 1e-8 (the optimum is well conditioned: cond(J) ~ 10).
    assert ours.status in ("cost", "step", "gradient")
    np.testing.assert_allclose(theta, ref.x, rtol=0, atol=1e-8)
    assert ours.cost == pytest.approx(ref.cost, rel=1e-12)
    assert ours.cost < ours.initial_cost


@pytest.mark.parametrize("q", [0, 1, 2, 3])
def test_covariance_matches_dense_inverse(q: int) -> None:
    prob = _RandomProblem(q, seed=20 + q)
    res = solve_sparse_lm(prob, prob.g_true, prob.l_true)
    theta = np.concatenate([res.x_global, res.x_local.ravel()])
    jac = prob.dense_jacobian(theta)
    s2 = 2.0 * res.cost / (jac.shape[0] - jac.shape[1])
    dense = s2 * np.linalg.inv(jac.T @ jac)
    assert res.residual_variance == pytest.approx(s2, rel=1e-12)
    # The Schur complement inverse is algebraically the global block of the dense inverse;
    # the two differ only by rounding (cond(J^T J) ~ 1e2 here).
    np.testing.assert_allclose(res.global_covariance(), dense[:P, :P], rtol=1e-9, atol=0)
    if q:
        local = res.local_covariance()
        for j in range(M):
            blk = dense[P + j * q : P + (j + 1) * q, P + j * q : P + (j + 1) * q]
            np.testing.assert_allclose(local[j], blk, rtol=1e-9, atol=1e-15)


def test_structured_normal_equations_take_the_same_path() -> None:
    plain = solve_sparse_lm(_RandomProblem(2, 5), np.zeros(P), np.zeros((M, 2)))
    hooked = solve_sparse_lm(_HookedProblem(2, 5), np.zeros(P), np.zeros((M, 2)))
    # Same arithmetic in the same order: identical iterates.
    assert hooked.iterations == plain.iterations
    np.testing.assert_array_equal(hooked.x_global, plain.x_global)
    np.testing.assert_array_equal(hooked.information, plain.information)


@pytest.mark.parametrize("q", [0, 2])
def test_predicted_decrease_stop_lands_on_the_optimum(q: int) -> None:
    prob = _RandomProblem(q, seed=30 + q)
    g0, l0 = prob.g_true + 0.3, prob.l_true - 0.2
    full = solve_sparse_lm(prob, g0, l0)
    ptol = 1e-6
    fast = solve_sparse_lm(prob, g0, l0, ptol=ptol)
    assert fast.iterations < full.iterations  # the early stop is exercised
    theta_full = np.concatenate([full.x_global, full.x_local.ravel()])
    theta_fast = np.concatenate([fast.x_global, fast.x_local.ravel()])
    sd = np.sqrt(
        np.diag(np.linalg.inv(prob.dense_jacobian(theta_full).T @ prob.dense_jacobian(theta_full)))
    )
    # Documented bound: the last step moves the parameters by at most sqrt(2 ptol cost)
    # standard deviations (unit-variance residuals), and being a Gauss-Newton step it lands
    # far closer than that to the minimum; the cost is within ptol of the minimum.
    assert np.max(np.abs(theta_fast - theta_full) / sd) <= np.sqrt(2 * ptol * full.cost)
    assert fast.cost <= full.cost * (1 + ptol)
    # The information is that of the previous iterate, a step of < 1e-3 sd away: equal to the
    # optimum's to first order (observed 3e-7 relative).
    np.testing.assert_allclose(fast.information, full.information, rtol=1e-4)


def test_levenberg_damping_reaches_the_same_optimum() -> None:
    prob = _RandomProblem(2, 7)
    a = solve_sparse_lm(prob, np.zeros(P), np.zeros((M, 2)), damping="marquardt")
    b = solve_sparse_lm(prob, np.zeros(P), np.zeros((M, 2)), damping="levenberg")
    np.testing.assert_allclose(a.x_global, b.x_global, atol=1e-8)


def test_zero_iterations_only_evaluates_the_start() -> None:
    prob = _RandomProblem(1, 3)
    res = solve_sparse_lm(prob, prob.g_true, prob.l_true, max_iterations=0)
    np.testing.assert_array_equal(res.x_global, prob.g_true)
    assert res.iterations == 0 and res.status == "max_iterations"
    assert res.cost == res.initial_cost


def test_bad_inputs_raise_typed_errors() -> None:
    prob = _RandomProblem(1, 3)
    with pytest.raises(InvalidInput):
        solve_sparse_lm(prob, np.zeros((P, 1)), np.zeros((M, 1)))
    with pytest.raises(ConvergenceError):
        solve_sparse_lm(prob, np.full(P, np.nan), np.zeros((M, 1)))
