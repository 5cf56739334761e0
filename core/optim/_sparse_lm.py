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

so an iteration costs O(m) time and memory instead of O((p + m q)^3). Every block operation is a
batched numpy call over the m blocks.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from core.errors import ConvergenceError, InvalidInput

Array = NDArray[np.float64]


class SparseProblem(Protocol):
    """A least-squares problem with one global block and m local blocks of equal size.

    Shapes: global parameters (p,), local parameters (m, q), residuals (m, r). Residual block j
    must depend on the global block and on local block j only. A problem whose blocks have
    unequal residual counts pads them with zero rows (zero residual and zero Jacobian), which
    change nothing in the normal equations.
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
        return s2 * np.linalg.pinv(self.information, hermitian=True)

    def local_covariance(self, sigma2: float | None = None) -> Array:
        """Return the covariance of every local block (m, q, q):
        V_j^-1 + V_j^-1 W_j^T S^-1 W_j V_j^-1, times sigma2 (H&Z eq. A6.11)."""
        s2 = self.residual_variance if sigma2 is None else sigma2
        v_inv = _batched_inv(self.local_information)
        s_inv = np.linalg.pinv(self.information, hermitian=True)
        y = v_inv @ self.cross.transpose(0, 2, 1)  # (m, q, p)
        return s2 * (v_inv + y @ s_inv @ y.transpose(0, 2, 1))


def _batched_inv(v: Array) -> Array:
    try:
        return np.linalg.inv(v)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(v, hermitian=True)


def _normal_blocks(
    res: Array, jg: Array, jl: Array
) -> tuple[Array, Array, Array, Array, Array]:
    m, r, p = jg.shape
    jg_flat = jg.reshape(m * r, p)
    u = jg_flat.T @ jg_flat
    jgt = jg.transpose(0, 2, 1)
    jlt = jl.transpose(0, 2, 1)
    w = jgt @ jl  # (m, p, q)
    v = jlt @ jl  # (m, q, q)
    b_g = jg_flat.T @ res.reshape(m * r)
    b_l = (jlt @ res[:, :, None])[:, :, 0]  # (m, q)
    return u, w, v, b_g, b_l


def solve_sparse_lm(
    problem: SparseProblem,
    x_global: Array,
    x_local: Array,
    *,
    max_iterations: int = 100,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    gtol: float = 1e-12,
    n_residuals: int | None = None,
    damping: Literal["marquardt", "levenberg"] = "marquardt",
) -> SparseLMResult:
    """Return the least-squares solution of `problem` from a starting point, by sparse LM.

    Minimises 0.5 * sum ||r_j(g, l_j)||^2. Damping adds mu * D to the normal equations, with D the
    diagonal of J^T J (Marquardt's scaling, invariant to parameter units) or the identity
    (Levenberg); mu follows Nielsen's rule (Madsen, Nielsen & Tingleff, "Methods for Non-Linear
    Least Squares Problems", 2004, eq. 3.16). Stops when the relative cost decrease of an accepted
    step is below `ftol`, the relative step is below `xtol`, the gradient's infinity norm is below
    `gtol` times the initial one, or after `max_iterations`.

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

    res, jg, jl = problem.jacobians(g, loc)
    if not np.all(np.isfinite(res)):
        raise ConvergenceError("the residuals are not finite at the starting point")
    cost = 0.5 * float(np.sum(res * res))
    initial_cost = cost
    u, w, v, b_g, b_l = _normal_blocks(res, jg, jl)
    g0_norm = max(float(np.max(np.abs(b_g), initial=0.0)), float(np.max(np.abs(b_l), initial=0.0)))

    eye_p = np.eye(p)
    eye_q = np.eye(q)
    diag_floor = 1e-12
    mu = -1.0
    nu = 2.0
    status: Literal["cost", "step", "gradient", "max_iterations"] = "max_iterations"
    iterations = 0
    while iterations < max_iterations:
        grad_inf = max(
            float(np.max(np.abs(b_g), initial=0.0)), float(np.max(np.abs(b_l), initial=0.0))
        )
        if grad_inf <= gtol * max(g0_norm, 1e-300):
            status = "gradient"
            break
        if damping == "marquardt":
            d_g = np.maximum(np.diag(u), diag_floor)
            d_l = np.maximum(np.diagonal(v, axis1=1, axis2=2), diag_floor)
        else:
            d_g = np.ones(p)
            d_l = np.ones((m, q))
        if mu < 0:
            # Start with mu relative to the largest curvature (MN&T eq. 3.14, tau = 1e-3).
            if damping == "marquardt":
                mu = 1e-3
            else:
                mu = 1e-3 * max(float(np.max(np.diag(u))), float(np.max(np.diagonal(v, 0, 1, 2))))
        accepted = False
        while not accepted:
            iterations += 1
            u_d = u + eye_p * (mu * d_g)
            v_d = v + eye_q * (mu * d_l)[:, :, None]
            v_inv = _batched_inv(v_d)
            y = w @ v_inv  # (m, p, q)
            s = u_d - np.einsum("mpq,mrq->pr", y, w)
            rhs = -(b_g - np.einsum("mpq,mq->p", y, b_l))
            try:
                dg = np.linalg.solve(s, rhs)
            except np.linalg.LinAlgError:
                dg = np.linalg.lstsq(s, rhs, rcond=None)[0]
            dl = -np.einsum("mqk,mk->mq", v_inv, b_l + np.einsum("mpq,p->mq", w, dg))

            step_norm = float(np.sqrt(dg @ dg + np.sum(dl * dl)))
            x_norm = float(np.sqrt(g @ g + np.sum(loc * loc)))
            if step_norm <= xtol * (x_norm + xtol):
                status = "step"
                break

            g_new = g + dg
            loc_new = loc + dl
            res_new = problem.residuals(g_new, loc_new)
            cost_new = (
                0.5 * float(np.sum(res_new * res_new)) if np.all(np.isfinite(res_new)) else np.inf
            )
            # Predicted decrease of the linear model: 0.5 h^T (mu D h - b).
            predicted = 0.5 * (
                float(dg @ (mu * d_g * dg - b_g)) + float(np.sum(dl * (mu * d_l * dl - b_l)))
            )
            rho = (cost - cost_new) / predicted if predicted > 0 else -1.0
            if rho > 0 and np.isfinite(cost_new):
                accepted = True
                rel_decrease = (cost - cost_new) / max(cost, 1e-300)
                g, loc, cost = g_new, loc_new, cost_new
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                res, jg, jl = problem.jacobians(g, loc)
                u, w, v, b_g, b_l = _normal_blocks(res, jg, jl)
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
    v_inv = _batched_inv(v)
    information = u - np.einsum("mpq,mqk,mrk->pr", w, v_inv, w)
    return SparseLMResult(
        x_global=g,
        x_local=loc,
        cost=cost,
        initial_cost=initial_cost,
        iterations=iterations,
        status=status,
        n_residuals=int(res.size if n_residuals is None else n_residuals),
        n_parameters=p + m * q,
        information=information,
        local_information=v,
        cross=w,
    )
