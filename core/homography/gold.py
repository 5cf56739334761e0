"""The gold-standard homography (H&Z alg. 4.3, eq. 4.8): Gauss-Newton with the corrected
first-image points eliminated per point in closed form (`_GoldGaussNewton`), started from the
normalised DLT and the Sampson points (H&Z sec. 4.2.6), handing over to the damped sparse LM
(`core.optim`) on `_GoldStandardProblem` when an undamped step fails.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg.lapack import dposv as _posv

from core._numeric import dot
from core.homography.dlt import _EE
from core.homography.problems import _LM_PTOL, _GoldStandardProblem
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]


def _sampson_src(hn: Array, ps_t: Array, pd_t: Array, src_scale: float, dst_scale: float) -> Array:
    """Return the first-image points (N, 2) of the Sampson correction (H&Z sec. 4.2.6)
    from Hartley-normalised points given transposed, (2, N).

    The first-order ML correction of each correspondence for the algebraic errors
    e = x' (h3 . x) - (h1 . x), y' (h3 . x) - (h2 . x), weighted for noise of equal size in both
    images in input units (normalised coordinates scale src and dst noise by src_scale and
    dst_scale). It starts the gold standard next to its optimum, saving an LM iteration.
    """
    ph = hn[:, :2] @ ps_t + hn[:, 2:]  # (3, N)
    w = ph[2]
    e = pd_t * w - ph[:2]  # algebraic errors (2, N)
    # d e / d x (2, 2, N): j[i, k] = x'_i h3k - h_ik; d e / d x' = w I.
    j = pd_t[:, None, :] * hn[2, :2, None] - hn[:2, :2, None]
    # M = J Sigma J^T / s_src^2 with Sigma = diag(s_src^2 I, s_dst^2 I); the src correction is
    # -J_x^T M^-1 e.
    mm = (j[:, None, :, :] * j[None, :, :, :]).sum(axis=2)  # (2, 2, N)
    ww = (dst_scale / src_scale) ** 2 * w * w
    a, b, c = mm[0, 0] + ww, mm[0, 1], mm[1, 1] + ww
    inv_det = 1.0 / (a * c - b * b)
    lam = np.empty_like(e)
    lam[0] = (c * e[0] - b * e[1]) * inv_det
    lam[1] = (a * e[1] - b * e[0]) * inv_det
    return np.ascontiguousarray((ps_t - (j * lam[:, None, :]).sum(axis=0)).T)


# Gold standard by Gauss-Newton with the corrected points eliminated in closed form
#
# For fixed H the corrected point x^_i enters only its own two residual pairs, so the Schur
# complement of the 2 x 2 point blocks has a closed form per point. Linearising
# pi(H x^) ~ pi_0 + P_x dx + P_g dg at the current (H, x^) (P_x = d pi / d x^ (2 x 2),
# P_g = d pi / d g (2 x 8)) and minimising over dx first,
#     min_dx ws^2 ||x - x^ - dx||^2 + wd^2 ||x' - pi_0 - P_x dx - P_g dg||^2
#       = (c - P_g dg)^T Omega (c - P_g dg),   c = x' - pi_0 - P_x (x - x^),
#     Omega = (wd^-2 I + ws^-2 P_x P_x^T)^-1 = ws^2 M^-1,   M = k I + P_x P_x^T,  k = ws^2 / wd^2
# (ws, wd: the pixels per normalised unit of each image), reached at
#     x^_new = x + P_x^T M^-1 (c - P_g dg)
# (the Sampson correction of the linearised constraint). So the Gauss-Newton step of all
# 8 + 2n parameters is the weighted least-squares step dg of S dg = sum_i P_g,i^T Omega_i c_i,
# S = sum_i P_g,i^T Omega_i P_g,i: the Schur complement U - sum_i W_i V_i^-1 W_i^T of the
# sparse LM written out (Woodbury: wd^2 I - wd^2 P_x V^-1 P_x^T wd^2 = Omega), then the points
# by back-substitution (H&Z A6.3 with the 2 x 2 inverses in closed form). Every product of
# P_g's rows is a weight times a monomial of x^ = (x, y): S and the right-hand side are
# gathered from one (9 x n) (n x 6) matrix product.


def _gold_index() -> tuple[NDArray[np.intp], Array]:
    """Return (index, sign) that gather S (8 x 8, row-major) then the right-hand side (8,) from
    the flattened Q = W E^T (9 x 6), W the per-point weights of `_GoldGaussNewton._weights`.

    With P_g's u-row iw (e, 0, -u e_xy) and v-row iw (0, e, -v e_xy) (e = (x, y, 1),
    iw = 1 / (h3 . e)) and Omega = [[o00, o01], [o01, o11]]: S's blocks are
    [0:3, 0:3] = sum o00 iw^2 e e^T, [0:3, 3:6] = sum o01 iw^2 e e^T,
    [3:6, 3:6] = sum o11 iw^2 e e^T, [0:3, 6:8] = -sum alpha_u e e_xy^T,
    [3:6, 6:8] = -sum alpha_v e e_xy^T, [6:8, 6:8] = sum (u, v) . alpha e_xy e_xy^T with
    alpha = Omega (u, v) iw^2; the right-hand side is (sum rho_u e, sum rho_v e,
    -sum (u, v) . rho e_xy) with rho = Omega c iw.
    """
    idx = np.zeros((8, 8), dtype=np.intp)
    sign = np.ones((8, 8))
    for i in range(3):
        for j in range(3):
            idx[i, j] = _EE[i][j]
            idx[i, 3 + j] = idx[3 + j, i] = 6 + _EE[i][j]
            idx[3 + i, 3 + j] = 12 + _EE[i][j]
        for j in range(2):
            for row, w in ((i, 3), (3 + i, 4)):
                idx[row, 6 + j] = idx[6 + j, row] = 6 * w + _EE[i][j]
                sign[row, 6 + j] = sign[6 + j, row] = -1.0
    for i in range(2):
        for j in range(2):
            idx[6 + i, 6 + j] = 30 + _EE[i][j]
    rhs = np.array([39, 40, 41, 45, 46, 47, 51, 52])
    rhs_sign = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 1.0, -1.0, -1.0])
    return np.concatenate([idx.ravel(), rhs]), np.concatenate([sign.ravel(), rhs_sign])


_GOLD_IDX, _GOLD_SIGN = _gold_index()
# The right-hand side's entries of Q = W E^T (9 x 6) in the (3 x 3) product of W[6:9] and the
# monomials (x, y, 1) alone.
_GRAD_IDX = np.array([0, 1, 2, 3, 4, 5, 6, 7])
# Undamped steps the closed-form solver takes before it hands over to the damped sparse LM:
# from the DLT and the Sampson points it converges in two (the cost's relative decrease per
# step runs ~1e-1, ~1e-6, ~1e-11 at sigma = 0.5 px), so more means a hard problem.
_GOLD_GN_STEPS = 8
# A step whose predicted decrease is below this fraction of the cost leaves the next one close
# enough to the minimum to keep the Jacobians (see `_GoldGaussNewton.solve`).
_GOLD_CHORD = 1e-2


@dataclass(frozen=True)
class _GoldSolution:
    """The gold standard's optimum in normalised coordinates (see `_GoldGaussNewton`)."""

    g: Array  # (8,) free entries of H_n
    x_hat: Array  # (2, N) corrected first-image points
    cost: float  # 0.5 sum of squared residuals (pixels)
    information: Array  # (8, 8) reduced Gauss-Newton matrix S (unit-variance residuals)
    iterations: int
    information_inverse: Array | None = None  # S^-1 when the solver has it


class _GoldGaussNewton:
    """Gauss-Newton on the gold-standard cost (H&Z eq. 4.8) with the corrected points
    eliminated per point in closed form (see the section comment); every per-point quantity
    is a contiguous length-N row, so an iteration is a few dozen vectorised operations."""

    def __init__(self, ps_t: Array, pd_t: Array, src_scale: float, dst_scale: float) -> None:
        n = ps_t.shape[1]
        self.ps, self.pd = ps_t, pd_t
        self.ws2 = 1.0 / (src_scale * src_scale)
        self.wd2 = 1.0 / (dst_scale * dst_scale)
        self.k = self.ws2 / self.wd2
        self.P = np.empty((4, n))  # P_x rows: du/dx, du/dy, dv/dx, dv/dy
        self.O = np.empty((3, n))  # M^-1 rows: (00, 01, 11)
        self.M = np.empty((3, n))
        self.V = np.empty((3, n))
        self.W = np.empty((9, n))
        self.E = np.empty((6, n))
        self.E[5] = 1.0

    def evaluate(self, H: Array, xh: Array) -> tuple[float, Array, Array, Array, Array]:
        """Return (cost, 1 / w (N,), pi(H x^) (2, N), x' - pi (2, N), x - x^ (2, N)) at H and
        the homogeneous corrected points xh (3, N)."""
        ph = H @ xh
        iw = np.divide(1.0, ph[2])
        uv = ph[:2]
        uv *= iw
        rd = self.pd - uv
        es = self.ps - xh[:2]
        cost = 0.5 * (self.wd2 * dot(rd, rd) + self.ws2 * dot(es, es))
        return cost, iw, uv, rd, es

    def jacobian(self, H: Array, iw: Array, uv: Array) -> None:
        """Fill P (P_x) and O (M^-1) at the current point."""
        P, O, m, v = self.P, self.O, self.M, self.V
        # P_x = (H[:2, :2] - pi H[2, :2]) / w, the chain rule on pi = (H x)_12 / w: each entry
        # is linear in (1, u, v) / w, so one (4 x 3) (3 x N) product gives them all.
        v[0] = iw
        np.multiply(uv, iw, out=v[1:3])
        h0, h1, h2 = H[0], H[1], H[2]
        lin = np.array(
            [
                [h0[0], -h2[0], 0.0],
                [h0[1], -h2[1], 0.0],
                [h1[0], 0.0, -h2[0]],
                [h1[1], 0.0, -h2[1]],
            ]
        )
        np.matmul(lin, v, out=P)
        # m = (M11, -M01, M00) of M = k I + P_x P_x^T, so that M^-1 = m / det(M).
        sq = P * P
        sr = sq.reshape(2, 2, -1)
        np.add(sr[::-1, 0], sr[::-1, 1], out=m[::2])
        m[::2] += self.k
        t = P[0:2] * P[2:4]
        np.negative(t[0], out=m[1])
        m[1] -= t[1]
        det = m[0] * m[2]
        det -= m[1] * m[1]
        np.divide(m, det, out=O)

    def offset(self, rd: Array, es: Array) -> Array:
        """Return c = x' - pi - P_x (x - x^), the linearised dst residual at x^ = x."""
        pr = self.P.reshape(2, 2, -1)
        c = rd - pr[:, 0] * es[0]
        c -= pr[:, 1] * es[1]
        return c

    def correct(self, eps: Array, out: Array) -> None:
        """Write x^ = x + P_x^T M^-1 eps into out (2, N)."""
        O, P = self.O, self.P
        z = O[0:2] * eps[0]  # (M^-1)'s rows (00, 01) and (01, 11)
        z += O[1:3] * eps[1]
        np.multiply(P[0:2], z[0], out=out)
        out += P[2:4] * z[1]
        out += self.ps

    def rhs_weights(self, iw: Array, uv: Array, c: Array) -> float:
        """Return c^T Omega c summed, having written the right-hand side's weights into W[6:9]:
        rho = M^-1 c / w (rows 6-7) and (u, v) . rho (row 8)."""
        O, W = self.O, self.W
        rho = W[6:8]
        np.multiply(O[0:2], c[0], out=rho)
        rho += O[1:3] * c[1]
        c_omega_c = self.ws2 * dot(c, rho)
        rho *= iw
        np.multiply(uv[0], rho[0], out=W[8])
        W[8] += uv[1] * rho[1]
        return c_omega_c

    def reduced_system(
        self, iw: Array, uv: Array, c: Array, xh: Array
    ) -> tuple[Array, Array, float]:
        """Return (S (8 x 8), rhs (8,), c^T Omega c summed) at the current linearisation."""
        O, W, E = self.O, self.W, self.E
        iw2 = iw * iw
        np.multiply(O, iw2, out=W[0:3])
        alpha = W[3:5]
        np.multiply(O[0:2], uv[0], out=alpha)
        alpha += O[1:3] * uv[1]
        alpha *= iw2
        np.multiply(uv[0], alpha[0], out=W[5])
        W[5] += uv[1] * alpha[1]
        c_omega_c = self.rhs_weights(iw, uv, c)
        x, y = xh[0], xh[1]
        np.multiply(x, x, out=E[0])
        np.multiply(x, y, out=E[1])
        np.multiply(y, y, out=E[2])
        E[3:5] = xh[:2]
        t = (W @ E.T).ravel()[_GOLD_IDX]
        t *= _GOLD_SIGN
        t *= self.ws2
        return t[:64].reshape(8, 8), t[64:], c_omega_c

    def gradient(self, iw: Array, uv: Array, c: Array, xh: Array) -> tuple[Array, float]:
        """Return (rhs (8,), c^T Omega c summed) of `reduced_system` alone (its weights 6-8
        against the monomials (x, y, 1)), with the current M^-1."""
        W, E = self.W, self.E
        c_omega_c = self.rhs_weights(iw, uv, c)
        E[3:5] = xh[:2]
        t = (W[6:9] @ E[3:6].T).ravel()[_GRAD_IDX]
        t *= _GOLD_SIGN[64:]
        t *= self.ws2
        return t, c_omega_c

    def solve(self, hn: Array, max_steps: int, ptol: float) -> tuple[_GoldSolution, bool]:
        """Return (the last accepted iterate, converged) from H_n = hn and the Sampson points.

        Converged: the step's predicted decrease fell below ptol of the cost, and the step was
        taken (unless it raised the cost) without linearising again, as `solve_sparse_lm` does
        with ptol; the information is then that of the previous iterate. Not converged: a step
        raised the cost or S was not positive definite before that, or max_steps ran out; the
        iterate is the best so far, for the damped LM to continue from.
        """
        n = self.ps.shape[1]
        H = hn.copy()
        xh = np.empty((3, n))
        xh[2] = 1.0
        xh[:2] = self.ps
        cost, iw, uv, rd, es = self.evaluate(H, xh)
        # The Sampson start: the corrected points for H fixed (dg = 0, x^ = x, so c = x' - pi).
        self.jacobian(H, iw, uv)
        self.correct(rd, xh[:2])
        cost, iw, uv, rd, es = self.evaluate(H, xh)
        xn = np.empty_like(xh)
        xn[2] = 1.0
        d = np.zeros(9)
        # Right-hand sides of each step's Cholesky solve: the gradient, then the identity, so
        # the step that ends the solve also gives S^-1 for the covariance.
        b = np.zeros((8, 9))
        b[:, 1:] = np.eye(8)
        steps = 0
        chord = False
        while steps < max_steps:
            steps += 1
            if chord:
                # Close to the minimum (the previous step's predicted decrease below
                # _GOLD_CHORD of the cost) P_x, M^-1 and S are kept from the previous
                # linearisation and only the residuals and the gradient are new: the iterate
                # moved by about one standard deviation of H, which changes them by
                # ~(sigma / sqrt(n)) / (image size), and the step is that fraction off the
                # Gauss-Newton step (<1e-3 of a standard deviation; the stopping rule itself
                # allows 0.045 at n = 1000).
                c = self.offset(rd, es)
                rhs, c_omega_c = self.gradient(iw, uv, c, xh)
            else:
                # Exact Jacobians at the first step: keeping the Sampson start's (the points
                # moved by ~sigma) leaves the second step's decrease ~20x larger, at the
                # stopping threshold, so a third step would often be needed.
                self.jacobian(H, iw, uv)
                c = self.offset(rd, es)
                S, rhs, c_omega_c = self.reduced_system(iw, uv, c, xh)
            b[:, 0] = rhs
            _, x, info = _posv(S, b)
            dg = x[:, 0]
            # The decrease to the linear model's minimum, 0.5 (c^T Omega c - rhs . dg).
            predicted = cost - 0.5 * (c_omega_c - float(rhs @ dg))
            if info != 0 or not np.isfinite(predicted):
                break
            d[:8] = dg
            D = d.reshape(3, 3)
            q = D @ xh
            eps = uv * q[2]
            np.subtract(q[:2], eps, out=eps)
            eps *= iw
            np.subtract(c, eps, out=eps)  # c - P_g dg
            self.correct(eps, xn[:2])
            Hn = H + D
            trial = self.evaluate(Hn, xn)
            last = predicted <= ptol * cost
            chord = predicted <= _GOLD_CHORD * cost
            if trial[0] <= cost:
                H, xh, xn = Hn, xn, xh
                cost, iw, uv, rd, es = trial
            elif not last:
                break
            if last:
                g = H.ravel()[:8].copy()
                return _GoldSolution(g, xh[:2], cost, S, steps, x[:, 1:]), True
        nan = np.full((8, 8), np.nan)
        return _GoldSolution(H.ravel()[:8].copy(), xh[:2], cost, nan, steps), False


def _fit_gold(
    ps_t: Array, pd_t: Array, hn: Array, src_scale: float, dst_scale: float, max_iterations: int
) -> _GoldSolution:
    """Return the gold standard's optimum from the DLT estimate hn: closed-form Gauss-Newton
    from the Sampson points, handed over to the damped sparse LM when a step fails."""
    solver = _GoldGaussNewton(ps_t, pd_t, src_scale, dst_scale)
    sol, converged = solver.solve(hn, min(max_iterations, _GOLD_GN_STEPS), _LM_PTOL)
    if converged:
        return sol
    # A step that raised the cost (a problem far from linear, e.g. points near the horizon)
    # or the step cap: the damped sparse LM continues from the best iterate.
    lm = solve_sparse_lm(
        _GoldStandardProblem(ps_t, pd_t, src_scale, dst_scale),
        sol.g,
        sol.x_hat.T,
        max_iterations=max(max_iterations - sol.iterations, 0),
        ptol=_LM_PTOL,
    )
    return _GoldSolution(
        lm.x_global, lm.x_local.T, lm.cost, lm.information, sol.iterations + lm.iterations
    )
