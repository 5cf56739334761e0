"""Levenberg-Marquardt for arrow-shaped problems, with Schur-complement elimination.

The parameters split into one *global* block g (p values: a homography, a camera's intrinsics, a
whole camera network) and m *local* blocks l_j (q values each: a corrected point, a view's pose, a
target pose). Residual block j (r values) depends on g and on l_j only, so the Gauss-Newton
normal equations have the arrow structure

    [ U    W ] [dg]     [b_g]        U = sum_j Jg_j^T Jg_j         (p x p)
    [ W^T  V ] [dl] = - [b_l],       W_j = Jg_j^T Jl_j             (p x q)
                                     V = blockdiag(Jl_j^T Jl_j)    (m blocks of q x q)

with V block-diagonal. Eliminating V (Hartley & Zisserman, 2nd ed., A6.3; Triggs et al., "Bundle
Adjustment - A Modern Synthesis", sec. 6.1) leaves the small reduced system

    S dg = -(b_g - sum_j W_j V_j^-1 b_l_j),     S = U - sum_j W_j V_j^-1 W_j^T,
    dl_j = -V_j^-1 (b_l_j + W_j^T dg),

so an iteration costs O(m) time and memory instead of O((p + m q)^3).

Internally the per-block quantities are stored block index last (W as (p, q, m), V as (q, q, m),
b_l as (q, m)): every small-matrix operation is then a handful of numpy calls on contiguous
length-m rows, and the sums over blocks are single BLAS matrix products. A small stack of
(m, q, q) blocks costs numpy far more per block than these row operations.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from core._numeric import dot
from core.errors import ConvergenceError, InvalidInput

Array = NDArray[np.float64]
NormalBlocks = tuple[Array, Array, Array, Array, Array, Array]


class SparseProblem(Protocol):
    """A least-squares problem with one global block and m local blocks of equal size.

    Shapes: global parameters (p,), local parameters (m, q) (q may be 0: a dense problem over
    the global block), residuals (m, r). Residual block j must depend on the global block and on
    local block j only. A problem whose blocks have unequal residual counts pads them with zero
    rows (zero residual and zero Jacobian), which change nothing in the normal equations.

    A problem may also define `normal_equations(x_global, x_local)` returning
    (residuals (m, r), U (p, p), W (p, q, m), V (q, q, m), b_g (p,), b_l (q, m)) with
    b = J^T res, block index last; the solver then uses it instead of `jacobians`, so a problem
    with exploitable structure (zero Jacobian rows, identity blocks) can assemble the blocks
    directly. It must agree with the blocks built from `jacobians`.
    """

    def residuals(self, x_global: Array, x_local: Array) -> Array:
        """Return the residuals, shape (m, r)."""
        ...

    def jacobians(self, x_global: Array, x_local: Array) -> tuple[Array, Array, Array]:
        """Return (residuals (m, r), d res / d global (m, r, p), d res / d local (m, r, q))."""
        ...


@dataclass(frozen=True)
class SparseLMResult:
    """Solution of a sparse LM run, with the information needed for covariances.

    `cost` is 0.5 * sum of squared residuals. `information` is the undamped Gauss-Newton
    reduced matrix S at the solution (p x p); `local_information` the blocks V_j (m, q, q) and
    `cross` the blocks W_j (m, p, q), from which `global_covariance` and `local_covariance`
    derive (unit-variance residuals; multiply by `residual_variance` for the estimated scale).
    """

    x_global: Array
    x_local: Array
    cost: float
    initial_cost: float
    iterations: int
    status: Literal["cost", "step", "gradient", "max_iterations"]
    n_residuals: int
    n_parameters: int
    information: Array = field(repr=False)
    local_information: Array = field(repr=False)
    cross: Array = field(repr=False)

    @property
    def rms(self) -> float:
        """Root mean square of the residuals."""
        return float(np.sqrt(2.0 * self.cost / max(self.n_residuals, 1)))

    @property
    def residual_variance(self) -> float:
        """Unbiased estimate of the per-residual variance: 2 cost / (N - d)."""
        dof = self.n_residuals - self.n_parameters
        if dof <= 0:
            return float("nan")
        return 2.0 * self.cost / dof

    def global_covariance(self, sigma2: float | None = None) -> Array:
        """Return the covariance of the global block (p x p): sigma2 * S^-1 (H&Z eq. A6.9).

        sigma2 defaults to `residual_variance`. A gauge freedom left in S is removed with the
        pseudo-inverse.
        """
        s2 = self.residual_variance if sigma2 is None else sigma2
        return np.asarray(s2 * np.linalg.pinv(self.information, hermitian=True), np.float64)

    def local_covariance(self, sigma2: float | None = None) -> Array:
        """Return the covariance of every local block (m, q, q):
        V_j^-1 + V_j^-1 W_j^T S^-1 W_j V_j^-1, times sigma2 (H&Z eq. A6.11)."""
        s2 = self.residual_variance if sigma2 is None else sigma2
        v_inv = _inv_blocks(self.local_information.transpose(1, 2, 0)).transpose(2, 0, 1)
        s_inv = np.linalg.pinv(self.information, hermitian=True)
        y = v_inv @ self.cross.transpose(0, 2, 1)  # (m, q, p)
        out: Array = s2 * (v_inv + y @ s_inv @ y.transpose(0, 2, 1))
        return out


def _inv_blocks(v: Array) -> Array:
    """Return the inverses of symmetric blocks stored block index last, (q, q, m).

    q = 1 and q = 2 use the closed form on contiguous rows; larger q a batched LAPACK call.
    Singular blocks fall back to the pseudo-inverse, which leaves their null space undamped.
    """
    q = v.shape[0]
    if q == 0:
        return np.empty_like(v)
    if q > 2:
        vm = np.ascontiguousarray(v.transpose(2, 0, 1))
        try:
            return np.ascontiguousarray(np.linalg.inv(vm).transpose(1, 2, 0))
        except np.linalg.LinAlgError:
            return np.ascontiguousarray(np.linalg.pinv(vm, hermitian=True).transpose(1, 2, 0))
    out = np.empty_like(v)
    with np.errstate(divide="ignore", invalid="ignore"):
        if q == 1:
            np.divide(1.0, v, out=out)
        else:
            a, b, c, d = v[0, 0], v[0, 1], v[1, 0], v[1, 1]
            inv_det = 1.0 / (a * d - b * c)
            np.multiply(d, inv_det, out=out[0, 0])
            np.multiply(-b, inv_det, out=out[0, 1])
            np.multiply(-c, inv_det, out=out[1, 0])
            np.multiply(a, inv_det, out=out[1, 1])
    if q == 2 and np.isfinite(inv_det).all():
        return out
    bad = ~np.isfinite(out.reshape(q * q, -1)).all(axis=0)
    if np.any(bad):
        fix = np.linalg.pinv(np.ascontiguousarray(v[:, :, bad].transpose(2, 0, 1)), hermitian=True)
        out[:, :, bad] = fix.transpose(1, 2, 0)
    return out


def _block_matvec(a: Array, x: Array) -> Array:
    """Return y (k, m) with y[:, j] = A_j x_j for A (k, q, m), x (q, m)."""
    y = a[:, 0] * x[0]
    for k in range(1, a.shape[1]):
        y += a[:, k] * x[k]
    return y


def _normal_blocks(res: Array, jg: Array, jl: Array) -> NormalBlocks:
    """Return (res, U, W (p, q, m), V (q, q, m), b_g, b_l (q, m)) from the block Jacobians."""
    m, r, p = jg.shape
    q = jl.shape[2]
    jg_flat = jg.reshape(m * r, p)
    u = jg_flat.T @ jg_flat
    b_g = jg_flat.T @ res.reshape(m * r)
    if q == 0:
        return res, u, np.zeros((p, 0, m)), np.zeros((0, 0, m)), b_g, np.zeros((0, m))
    jlt = jl.transpose(0, 2, 1)
    w = np.ascontiguousarray((jlt @ jg).transpose(2, 1, 0))
    v = np.ascontiguousarray((jlt @ jl).transpose(1, 2, 0))
    b_l = np.ascontiguousarray((jlt @ res[:, :, None])[:, :, 0].T)
    return res, u, w, v, b_g, b_l


def _evaluate(problem: SparseProblem, g: Array, loc: Array) -> NormalBlocks:
    hook = getattr(problem, "normal_equations", None)
    if hook is not None:
        out: NormalBlocks = hook(g, loc)
        return out
    return _normal_blocks(*problem.jacobians(g, loc))


def _schur(
    u: Array, w: Array, v_inv: Array, work: tuple[Array, Array] | None = None
) -> tuple[Array, Array]:
    """Return (S = U - sum_j W_j V_j^-1 W_j^T, Y = W V^-1 (p, q, m)).

    `work`: two (p, q, m) buffers reused across iterations (Y is the first); allocating fresh
    block-sized temporaries every iteration costs page faults comparable to the arithmetic.
    """
    p, q, m = w.shape
    y, tmp = work if work is not None else (np.empty((p, q, m)), np.empty((p, q, m)))
    np.multiply(w[:, 0:1, :], v_inv[0], out=y)
    for k in range(1, q):
        np.multiply(w[:, k : k + 1, :], v_inv[k], out=tmp)
        y += tmp
    s = u - y.reshape(p, q * m) @ w.reshape(p, q * m).T
    return s, y


def _half_sum_sq(a: Array) -> float:
    """Return 0.5 * sum(a**2) without copying a transposed (Fortran-ordered) view."""
    flat = (a.T if a.T.flags.c_contiguous else a).ravel()
    return 0.5 * dot(flat, flat)


def _inf_norm(a: Array) -> float:
    return float(np.abs(a).max()) if a.size else 0.0


def solve_sparse_lm(
    problem: SparseProblem,
    x_global: Array,
    x_local: Array,
    *,
    max_iterations: int = 100,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    gtol: float = 1e-12,
    ptol: float = 0.0,
    n_residuals: int | None = None,
    damping: Literal["marquardt", "levenberg"] = "marquardt",
) -> SparseLMResult:
    """Return the least-squares solution of `problem` from a starting point, by sparse LM.

    Minimises 0.5 * sum ||r_j(g, l_j)||^2. Damping adds mu * D to the normal equations, with D the
    diagonal of J^T J (Marquardt's scaling, invariant to parameter units) or the identity
    (Levenberg); mu follows Nielsen's rule (Madsen, Nielsen & Tingleff, "Methods for Non-Linear
    Least Squares Problems", 2004, eq. 3.16). Stops when the relative cost decrease of an accepted
    step is below `ftol`, the relative step is below `xtol`, the gradient's infinity norm is below
    `gtol` times the initial one, or after `max_iterations` (counting rejected steps too;
    `max_iterations=0` only evaluates the information at the starting point). With `ptol` > 0 it
    also stops when the decrease the linear model predicts for the next step is below `ptol`
    times the cost: it takes that step (if it does not raise the cost) without linearising again,
    so the information returned is that of the previous iterate. The step then moves the
    parameters by at most sqrt(2 ptol cost) of their standard deviations (unit-variance
    residuals), small enough that the Jacobian is unchanged to first order, while the iterate
    itself lands as close to the minimum as a full Gauss-Newton step gets it. To that end, with
    `ptol` > 0 a step right after an accepted one is first tried undamped (Gauss-Newton); when it
    is the last, its reduced matrix is the information. This saves one evaluation of the normal
    equations, a large share of a problem that converges in two or three steps.

    Local blocks may be empty (x_local of shape (m, 0)): the problem is then a dense LM over the
    global block, with the m residual blocks only organising the residuals.

    `n_residuals` is the number of real residuals when the problem pads blocks with zeros
    (default: every residual counts); it sets the degrees of freedom of `residual_variance`.
    Raises ConvergenceError when the residuals become non-finite.
    """
    g = np.array(x_global, dtype=np.float64, copy=True)
    loc = np.array(x_local, dtype=np.float64, copy=True)
    if g.ndim != 1 or loc.ndim != 2:
        raise InvalidInput(
            f"x_global must have shape (p,) and x_local (m, q); got {g.shape} and {loc.shape}"
        )
    p = g.shape[0]
    m, q = loc.shape

    res, u, w, v, b_g, b_l = _evaluate(problem, g, loc)
    cost = _half_sum_sq(res)
    if not np.isfinite(cost):
        raise ConvergenceError("the residuals are not finite at the starting point")
    initial_cost = cost
    grad_norm = g0_norm = max(_inf_norm(b_g), _inf_norm(b_l))

    diag_floor = 1e-12
    work = (np.empty((p, q, m)), np.empty((p, q, m)))
    information: Array | None = None
    mu = -1.0
    nu = 2.0
    status: Literal["cost", "step", "gradient", "max_iterations"] = "max_iterations"
    iterations = 0
    while iterations < max_iterations:
        if grad_norm <= gtol * max(g0_norm, 1e-300):
            status = "gradient"
            break
        if damping == "marquardt":
            d_g = np.maximum(u.diagonal(), diag_floor)
            d_l = np.maximum(v.reshape(q * q, m)[:: q + 1], diag_floor)  # (q, m)
        else:
            d_g = np.ones(p)
            d_l = np.ones((q, m))
        if mu < 0:
            # Start with mu relative to the largest curvature (MN&T eq. 3.14, tau = 1e-3).
            if damping == "marquardt":
                mu = 1e-3
            else:
                mu = 1e-3 * max(_inf_norm(u.diagonal()), _inf_norm(v.reshape(q * q, m)[:: q + 1]))
        x_norm = float(np.sqrt(g @ g + loc.ravel() @ loc.ravel()))
        accepted = False
        while not accepted:
            # With ptol, a step right after an accepted one is first tried undamped: near the
            # minimum that is the Gauss-Newton step, and its reduced matrix is the information,
            # so a converged last step needs no further Schur complement.
            gauss_newton = ptol > 0.0 and nu == 2.0 and iterations > 0
            damp = 0.0 if gauss_newton else mu
            iterations += 1
            u_d = u.copy()
            u_d.flat[:: p + 1] += damp * d_g
            if q:
                v_d = v.copy()
                v_d.reshape(q * q, m)[:: q + 1] += damp * d_l
                v_inv = _inv_blocks(v_d)
                s, y = _schur(u_d, w, v_inv, work)
                rhs = y.reshape(p, q * m) @ b_l.ravel() - b_g
            else:
                s, rhs = u_d, -b_g
            try:
                dg = np.linalg.solve(s, rhs)
            except np.linalg.LinAlgError:
                dg = np.linalg.lstsq(s, rhs, rcond=None)[0]
            if q:
                t = b_l + (dg @ w.reshape(p, q * m)).reshape(q, m)
                dl = -_block_matvec(v_inv, t)  # (q, m)
            else:
                dl = np.zeros((0, m))

            step_norm = float(np.sqrt(dg @ dg + dl.ravel() @ dl.ravel()))
            if step_norm <= xtol * (x_norm + xtol):
                status = "step"
                break

            # Predicted decrease of the linear model: 0.5 h^T (mu D h - b).
            predicted = 0.5 * (
                float(dg @ (damp * d_g * dg - b_g))
                + float(dl.ravel() @ (damp * d_l * dl - b_l).ravel())
            )
            # Right after an accepted step (damping not inflated by rejections) a predicted
            # decrease below ptol of the cost means converged: take this last step if it does
            # not raise the cost, and stop without linearising again.
            last = nu == 2.0 and 0.0 <= predicted <= ptol * cost
            if last and gauss_newton:
                information = s

            g_new = g + dg
            loc_new = loc + dl.T
            cost_new = _half_sum_sq(problem.residuals(g_new, loc_new))
            if not np.isfinite(cost_new):
                cost_new = np.inf
            if last:
                if cost_new <= cost:
                    g, loc, cost = g_new, loc_new, cost_new
                status = "cost"
                break
            rho = (cost - cost_new) / predicted if predicted > 0 else -1.0
            if rho > 0 and np.isfinite(cost_new):
                accepted = True
                rel_decrease = (cost - cost_new) / max(cost, 1e-300)
                g, loc, cost = g_new, loc_new, cost_new
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                res, u, w, v, b_g, b_l = _evaluate(problem, g, loc)
                grad_norm = max(_inf_norm(b_g), _inf_norm(b_l))
                if rel_decrease <= ftol or cost == 0.0:
                    status = "cost"
            else:
                mu *= nu
                nu *= 2.0
                if mu > 1e30 or not np.isfinite(mu):
                    status = "step"
                    break
            if iterations >= max_iterations:
                break
        if status != "max_iterations":
            break

    if not np.isfinite(cost):
        raise ConvergenceError("the sparse LM produced non-finite residuals")
    if information is None:
        information = _schur(u, w, _inv_blocks(v))[0] if q else u
    return SparseLMResult(
        x_global=g,
        x_local=loc,
        cost=cost,
        initial_cost=initial_cost,
        iterations=iterations,
        status=status,
        n_residuals=int(res.size if n_residuals is None else n_residuals),
        n_parameters=p + m * q,
        information=0.5 * (information + information.T),
        local_information=v.transpose(2, 0, 1),
        cross=w.transpose(2, 0, 1),
    )
