"""The least-squares problems of the homography for the sparse LM (`core.optim`): the dst
transfer error (H&Z eq. 4.6) and the gold standard's reprojection error in both images
(eq. 4.8), in Hartley-normalised coordinates with the gauge H_n[2,2] = 1 and the residuals in
the input units (pixels), with the LM's stopping rule both estimates use.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

# LM stopping: once the next step is predicted to lower the cost by less than 1e-6 of it, take
# it and stop. At the minimum the cost is ~ (N - d) sigma^2 / 2, so that last step moves H by
# at most sqrt(1e-6 (N - d)) of its standard deviations (0.045 at n = 1000 for the gold
# standard): the Jacobian is unchanged to first order and the step itself lands on the
# minimum to second order, so no further linearisation is needed.
_LM_PTOL = 1e-6


def _h_from_params(g: Array) -> Array:
    h = np.empty(9)
    h[:8] = g
    h[8] = 1.0
    return h.reshape(3, 3)


class _Projection:
    """pi(H x) for the 8 free entries g of H (H[2,2] = 1) and points x (2, N) with the pieces
    of its Jacobian, as contiguous length-N rows (elementwise numpy on rows is cheapest)."""

    __slots__ = ("c", "hm", "u", "uv", "v", "x", "y")

    def __init__(self, g: Array, x_t: Array, weight: float) -> None:
        self.hm = hm = _h_from_params(g)
        ph = hm[:, :2] @ x_t + hm[:, 2:]  # (3, N)
        inv_w = 1.0 / ph[2]
        self.x, self.y = x_t
        self.uv = ph[:2] * inv_w  # (2, N)
        self.u, self.v = self.uv
        # d (weight * (x' - pi(H x))) / d (...) carries the factor c = -weight / w.
        self.c = -weight * inv_w

    def point_jacobian(self) -> Array:
        """Return A (2, 2, N) = c d pi(H x) / d x = c (H[:2, :2] - pi(H x) H[2, :2]) / 1, the
        chain rule on x' = (H x)_12 / w (the 1 / w is inside c)."""
        hm = self.hm
        return self.c * (hm[:2, :2, None] - self.uv[:, None, :] * hm[2, :2, None])

    def g_rows(self) -> Array:
        """Return G^T (8, 2, N): d residual / d g for the u-rows [:, 0] and v-rows [:, 1]."""
        f = self.features(np.empty((7, len(self.c))))
        gt = np.zeros((8, 2, len(self.c)))
        gt[0:3, 0] = gt[3:6, 1] = f[0:3]
        gt[6:8, 0], gt[6:8, 1] = f[3:5], f[5:7]
        return gt

    def features(self, out: Array) -> Array:
        """Fill out[:7] with F = c (x, y, 1, -u x, -u y, -v x, -v y), the distinct entries of
        G: its u-row is (F0, F1, F2, 0, 0, 0, F3, F4), its v-row (0, 0, 0, F0, F1, F2, F5, F6)."""
        np.multiply(self.c, self.x, out=out[0])
        np.multiply(self.c, self.y, out=out[1])
        out[2] = self.c
        np.multiply(out[0:2], -self.u, out=out[3:5])
        np.multiply(out[0:2], -self.v, out=out[5:7])
        return out


def _global_index() -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Return index pairs into the 7 x 9 Gram matrix M = F [F; r]^T (flattened, with a zero
    appended at position 63) such that U (8 x 8, row-major) then b_g (8,) = M[ia] + M[ib]."""
    zero = 63
    pairs: list[tuple[int, int]] = []
    for r in range(8):
        for c in range(8):
            lo, hi = min(r, c), max(r, c)
            if hi < 3 or (3 <= lo and hi < 6):  # both in 0:3 or both in 3:6: F_0:3 F_0:3^T
                pairs.append((9 * (lo % 3) + hi % 3, zero))
            elif lo >= 6:  # 6:8 x 6:8: both the u-row and the v-row contribute
                pairs.append((9 * (lo - 3) + hi - 3, 9 * (lo - 1) + hi - 1))
            elif hi >= 6:  # 0:6 x 6:8: u-row (F3, F4) for 0:3, v-row (F5, F6) for 3:6
                pairs.append((9 * (lo % 3) + (hi - 3 if lo < 3 else hi - 1), zero))
            else:  # 0:3 x 3:6: never in the same row of G
                pairs.append((zero, zero))
    for r in range(8):
        if r < 6:
            pairs.append((9 * (r % 3) + (7 if r < 3 else 8), zero))
        else:
            pairs.append((9 * (r - 3) + 7, 9 * (r - 1) + 8))
    ia, ib = zip(*pairs, strict=True)
    return np.array(ia), np.array(ib)


_GLOBAL_IA, _GLOBAL_IB = _global_index()


def _global_blocks(f: Array) -> tuple[Array, Array]:
    """Return (U = sum_i G_i^T G_i (8 x 8), b_g = sum_i G_i^T r_i (8,)) from one product of the
    rows f (9, N) = (F (7, N), r_u, r_v): the zero pattern of G makes U's two 3 x 3 diagonal
    blocks equal, so a 7 x 9 Gram matrix holds everything (gathered by precomputed indices)."""
    m = np.zeros(64)
    m[:63] = (f[:7] @ f.T).ravel()
    t = m[_GLOBAL_IA] + m[_GLOBAL_IB]
    return t[:64].reshape(8, 8), t[64:]


class _TransferProblem:
    """Residuals (N, 2) = (dst_i - pi(H src_i)) / s_dst: the dst transfer error in input units
    (H&Z eq. 4.6). Global block: the 8 free entries of H_n (H_n[2,2] = 1); no local blocks."""

    def __init__(self, src_t: Array, dst_t: Array, dst_scale: float) -> None:
        self.src_t = src_t
        self.dst_t = dst_t
        self.w_dst = 1.0 / dst_scale

    def _residuals_t(self, pr: _Projection) -> Array:
        res_t = np.empty((2, len(pr.u)))
        np.multiply(self.w_dst, self.dst_t[0] - pr.u, out=res_t[0])
        np.multiply(self.w_dst, self.dst_t[1] - pr.v, out=res_t[1])
        return res_t

    def residuals(self, g: Array, x_local: Array) -> Array:
        pr = _Projection(g, self.src_t, self.w_dst)
        return self._residuals_t(pr).T

    def jacobians(self, g: Array, x_local: Array) -> tuple[Array, Array, Array]:
        pr = _Projection(g, self.src_t, self.w_dst)
        jg = np.ascontiguousarray(pr.g_rows().transpose(2, 1, 0))
        return self._residuals_t(pr).T, jg, np.zeros((len(pr.u), 2, 0))

    def normal_equations(
        self, g: Array, x_local: Array
    ) -> tuple[Array, Array, Array, Array, Array, Array]:
        pr = _Projection(g, self.src_t, self.w_dst)
        n = len(pr.u)
        f = np.empty((9, n))
        pr.features(f)
        res_t = f[7:9]
        np.multiply(self.w_dst, self.dst_t[0] - pr.u, out=res_t[0])
        np.multiply(self.w_dst, self.dst_t[1] - pr.v, out=res_t[1])
        u_mat, b_g = _global_blocks(f)
        return res_t.T, u_mat, np.zeros((8, 0, n)), np.zeros((0, 0, n)), b_g, np.zeros((0, n))


class _GoldStandardProblem:
    """Residuals (N, 4) = ((x_i - x^_i) / s_src, (x'_i - pi(H x^_i)) / s_dst): the reprojection
    error in both images in input units (H&Z eq. 4.8). Global block: the 8 free entries of H_n;
    local block i: the corrected first-image point x^_i (normalised coordinates).

    Per point the Jacobian is [[0, -I / s_src], [G_i, A_i]] with G_i = d pi / d h (2 x 8) and
    A_i = d pi / d x^ (2 x 2), both times -1 / s_dst; `normal_equations` assembles the blocks
    from these pieces with row operations over the points instead of generic block products.
    It writes into buffers owned by the problem, so each call overwrites the arrays the
    previous one returned (the solver only holds the latest); block-sized temporaries
    allocated afresh at every call cost page faults comparable to the arithmetic.
    """

    def __init__(self, src_t: Array, dst_t: Array, src_scale: float, dst_scale: float) -> None:
        self.src_t = src_t
        self.dst_t = dst_t
        self.w_src = 1.0 / src_scale
        self.w_dst = 1.0 / dst_scale
        n = src_t.shape[1]
        self._f = np.empty((9, n))
        self._res = np.empty((4, n))
        self._w = np.empty((8, 2, n))
        self._aa = np.empty((2, 2, 2, n))
        self._v = np.empty((2, 2, n))
        self._ar = np.empty((2, 2, n))
        self._b_l = np.empty((2, n))

    def _residuals_t(self, pr: _Projection) -> Array:
        res_t = np.empty((4, len(pr.u)))
        np.multiply(self.w_src, self.src_t[0] - pr.x, out=res_t[0])
        np.multiply(self.w_src, self.src_t[1] - pr.y, out=res_t[1])
        np.multiply(self.w_dst, self.dst_t[0] - pr.u, out=res_t[2])
        np.multiply(self.w_dst, self.dst_t[1] - pr.v, out=res_t[3])
        return res_t

    def residuals(self, g: Array, x_local: Array) -> Array:
        return self._residuals_t(_Projection(g, x_local.T, self.w_dst)).T

    def jacobians(self, g: Array, x_local: Array) -> tuple[Array, Array, Array]:
        pr = _Projection(g, x_local.T, self.w_dst)
        n = len(x_local)
        jg = np.zeros((n, 4, 8))
        jg[:, 2:, :] = pr.g_rows().transpose(2, 1, 0)
        jl = np.zeros((n, 4, 2))
        jl[:, 0, 0] = jl[:, 1, 1] = -self.w_src
        jl[:, 2:, :] = pr.point_jacobian().transpose(2, 0, 1)
        return self._residuals_t(pr).T, jg, jl

    def normal_equations(
        self, g: Array, x_local: Array
    ) -> tuple[Array, Array, Array, Array, Array, Array]:
        x_t = x_local.T
        pr = _Projection(g, x_t, self.w_dst)
        ws = self.w_src
        f = pr.features(self._f)
        rd = f[7:9]
        np.subtract(self.dst_t, pr.uv, out=rd)
        rd *= self.w_dst
        u_mat, b_g = _global_blocks(f)
        res_t = self._res
        rs = res_t[:2]
        np.subtract(self.src_t, x_t, out=rs)
        rs *= ws
        res_t[2:] = rd
        a = pr.point_jacobian()  # (2, 2, N): a[i, k] = d res_dst_i / d x^_k
        # W_i = G_i^T A_i (8 x 2), from G's zero pattern (see _Projection.features).
        w, ar = self._w, self._ar
        np.multiply(f[0:3, None], a[0], out=w[0:3])
        np.multiply(f[0:3, None], a[1], out=w[3:6])
        np.multiply(f[3:5, None], a[0], out=w[6:8])
        np.multiply(f[5:7, None], a[1], out=ar)
        w[6:8] += ar
        # V_i = I / s_src^2 + A_i^T A_i; b_l = J_l^T res = -res_src / s_src + A_i^T res_dst.
        vb = np.sum(
            np.multiply(a[:, :, None, :], a[:, None, :, :], out=self._aa), axis=0, out=self._v
        )
        vb[0, 0] += ws * ws
        vb[1, 1] += ws * ws
        b_l = np.sum(np.multiply(a, rd[:, None, :], out=ar), axis=0, out=self._b_l)
        b_l -= ws * rs
        return res_t.T, u_mat, w, vb, b_g, b_l
