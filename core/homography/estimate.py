"""Homography estimation: normalised DLT, transfer-error LM, gold-standard ML, LO-RANSAC.

Two cases (spec 01, section 1):

* world-plane homography: src are exact metric plane coordinates, only dst is noisy; the ML
  estimate minimises the transfer error in dst (`method="transfer"`, H&Z eq. 4.6);
* plane-induced homography between two images: both sides are noisy; the ML estimate is the gold
  standard (`method="gold"`, H&Z alg. 4.3, eq. 4.8), solved by Gauss-Newton with the corrected
  first-image points eliminated by their Schur complement in closed form (`_GoldGaussNewton`),
  handing over to the damped sparse LM (core.optim) when an undamped step fails.

Every iterative estimate runs in Hartley-normalised coordinates (H&Z alg. 4.2) with the gauge
H_n[2,2] = 1 and the residuals kept in the input units (pixels), then maps H and its covariance
back to the input coordinates with the gauge H[2,2] = 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg.lapack import dposv as _posv
from scipy.linalg.lapack import dsyev as _syev

from core._numeric import dot
from core._validate import as_points
from core.errors import DegenerateConfiguration, InvalidInput
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]
Method = Literal["gold", "transfer", "dlt"]

# Collinearity: a point cloud whose smaller principal axis is below this fraction of the larger
# is a line. The axes come from the 2 x 2 scatter matrix, whose eigenvalues are exact to ~1e-16
# of the larger, i.e. axes to ~1e-8: the threshold sits above that rounding floor (6e-5 px
# across a 640 px image, far below any real measurement's spread).
_COLLINEAR_TOL = 1e-7
# A RANSAC minimal sample whose point triples have |det| below this (normalised coordinates,
# where a well-spread triple has |det| ~ 1) is too close to collinear to give a useful model.
_SAMPLE_DET_TOL = 1e-6
# Hypotheses x points scored per numpy call in RANSAC: large enough to amortise the call
# overhead, small enough to keep the (K, 3, N) temporaries in cache-friendly sizes.
_RANSAC_BATCH_ELEMENTS = 400_000
# LM stopping: once the next step is predicted to lower the cost by less than 1e-6 of it, take
# it and stop. At the minimum the cost is ~ (N - d) sigma^2 / 2, so that last step moves H by
# at most sqrt(1e-6 (N - d)) of its standard deviations (0.045 at n = 1000 for the gold
# standard): the Jacobian is unchanged to first order and the step itself lands on the
# minimum to second order, so no further linearisation is needed.
_LM_PTOL = 1e-6


def _normalize_t(points: Array, name: str) -> tuple[Array, Array]:
    """Return (T (3, 3), normalised points transposed (2, N)) by Hartley normalisation (H&Z
    alg. 4.2: centroid at the origin, mean distance sqrt(2); the transform of
    core.geometry.normalization.hartley_normalization), checking the configuration on the way.

    Raises DegenerateConfiguration when the points coincide, are collinear, or (N = 4) have three
    collinear points. Rows are contiguous: every later per-point operation runs on them.
    """
    n = len(points)
    q = np.array(points.T, order="C")
    cx, cy = (np.add.reduce(q, axis=1) / n).tolist()
    q[0] -= cx
    q[1] -= cy
    r = q[0] * q[0]
    r += q[1] * q[1]
    mean_dist = float(np.add.reduce(np.sqrt(r, out=r))) / n
    if not mean_dist > 0.0:
        raise DegenerateConfiguration(f"all {name} points coincide; spread the points out")
    k = math.sqrt(2.0) / mean_dist
    q *= k
    # Eigenvalues of the centred scatter (2 x 2): the smallest ~ 0 means all points on a line.
    (sxx, sxy), (_, syy) = np.einsum("in,jn->ij", q, q).tolist()
    half_tr, det = 0.5 * (sxx + syy), sxx * syy - sxy * sxy
    lam_max = half_tr + math.sqrt(max(half_tr * half_tr - det, 0.0))
    lam_min = det / lam_max
    if lam_min <= _COLLINEAR_TOL**2 * lam_max:
        raise DegenerateConfiguration(
            f"all {name} points are collinear; a homography needs points spread over the plane"
        )
    if n == 4 and np.any(np.abs(_triple_dets(q.T[None]))[0] <= 2e-7):
        raise DegenerateConfiguration(
            f"three of the four {name} points are collinear; "
            "no three of four points may lie on a line"
        )
    T = np.array([[k, 0.0, -k * cx], [0.0, k, -k * cy], [0.0, 0.0, 1.0]])
    return T, q


def check_homography_configuration(src: Array, dst: Array) -> None:
    """Raise DegenerateConfiguration when the point sets cannot determine a homography.

    src, dst: (N, 2). Checks both sides: all points collinear (or coincident), and, for exactly
    four points, any three of them collinear.
    """
    _normalize_t(np.asarray(src, dtype=np.float64), "src")
    _normalize_t(np.asarray(dst, dtype=np.float64), "dst")


# Index pairs of e = (x, y, 1) into the monomials (x x, x y, y y, x, y, 1): e_i e_j = E[_EE[i][j]].
_EE = ((0, 1, 3), (1, 2, 4), (3, 4, 5))


def _dlt_index() -> NDArray[np.intp]:
    """Return the indices that gather A^T A (9 x 9, row-major) of the DLT from the flattened
    Q = (1, u, v, u^2 + v^2) (4, N) times the monomials (6, N) transposed, with a zero appended
    (index 24): A's u-row (p, 0, -u p) and v-row (0, p, -v p), p = (x, y, 1), give the blocks
    [0:3, 0:3] = [3:6, 3:6] = sum p p^T, [0:3, 6:9] = -sum u p p^T,
    [3:6, 6:9] = -sum v p p^T, [6:9, 6:9] = sum (u^2 + v^2) p p^T and [0:3, 3:6] = 0 (the
    signs are applied to the gathered entries)."""
    idx = np.full((9, 9), 24, dtype=np.intp)
    for i in range(3):
        for j in range(3):
            e = _EE[i][j]
            idx[i, j] = idx[3 + i, 3 + j] = e
            idx[i, 6 + j] = idx[6 + j, i] = 6 + e
            idx[3 + i, 6 + j] = idx[6 + j, 3 + i] = 12 + e
            idx[6 + i, 6 + j] = 18 + e
    return idx.ravel()


_DLT_IDX = _dlt_index()
_DLT_SIGN = np.where((np.arange(81) // 9 >= 6) != (np.arange(81) % 9 >= 6), -1.0, 1.0)


def _monomials(p: Array) -> Array:
    """Return (x x, x y, y y, x, y, 1) (6, N) of points p (2, N)."""
    e = np.empty((6, p.shape[1]))
    x, y = p
    np.multiply(x, x, out=e[0])
    np.multiply(x, y, out=e[1])
    np.multiply(y, y, out=e[2])
    e[3:5] = p
    e[5] = 1.0
    return e


def _dlt_normalized(ps_t: Array, pd_t: Array) -> Array:
    """Return H (3x3, unit Frobenius norm) with pd ~ H ps, from the 2N x 9 DLT system (H&Z
    eq. 4.3) on points (transposed, (2, N)) that are already Hartley-normalised."""
    n = ps_t.shape[1]
    # A^T A without forming A: every entry is a weight (1, u, v or u^2 + v^2) times a monomial
    # of (x, y), so one (4 x N) (N x 6) product holds them all.
    w = np.empty((4, n))
    w[0] = 1.0
    w[1:3] = pd_t
    np.multiply(pd_t[0], pd_t[0], out=w[3])
    w[3] += pd_t[1] * pd_t[1]
    q = np.zeros(25)
    q[:24] = (w @ _monomials(ps_t).T).ravel()
    ata = (q[_DLT_IDX] * _DLT_SIGN).reshape(9, 9)
    # The right singular vector of A's smallest singular value, as the eigenvector of A^T A
    # (9 x 9): O(n) and one small LAPACK call (an SVD of the 2N x 9 matrix costs more, and far
    # more again when a threaded BLAS competes for busy cores). On normalised points the
    # eigenvector keeps ~1e-13 relative accuracy for exact data.
    lam, vec, info = _syev(ata)
    # Singular values are the square roots: the second smallest <= 1e-7 of the largest.
    if info != 0 or max(float(lam[1]), 0.0) <= 1e-14 * float(lam[8]):
        raise DegenerateConfiguration(
            "the DLT system has a null space of dimension > 1; the points do not fix a homography"
        )
    return vec[:, 0].reshape(3, 3)


def _pair_inputs(src: ArrayLike, dst: ArrayLike) -> tuple[Array, Array]:
    s = as_points(src, 2, "src", min_count=4)
    d = as_points(dst, 2, "dst", min_count=4)
    if s.shape != d.shape:
        raise InvalidInput(f"src and dst must have the same shape, got {s.shape} and {d.shape}")
    return s, d


def _unit_h22(H: Array, what: str = "the homography") -> Array:
    if abs(H[2, 2]) < 1e-12 * np.abs(H).max():
        raise DegenerateConfiguration(
            f"{what} maps the origin to infinity (H[2,2] = 0); cannot normalise H[2,2] = 1"
        )
    return H / H[2, 2]


def dlt_homography(src: ArrayLike, dst: ArrayLike) -> Array:
    """Return H (3x3, H[2,2] = 1) with dst ~ H src by the normalised DLT (H&Z alg. 4.2).

    src, dst: (N, 2) pixel or metric coordinates, N >= 4. Minimises the algebraic error of the
    2N x 9 system on Hartley-normalised points. Raises NotEnoughPoints, InvalidInput or
    DegenerateConfiguration.
    """
    s, d = _pair_inputs(src, dst)
    Ts, ps_t = _normalize_t(s, "src")
    Td, pd_t = _normalize_t(d, "dst")
    hn = _dlt_normalized(ps_t, pd_t)
    return _unit_h22(np.asarray(np.linalg.solve(Td, hn @ Ts), np.float64))


# --------------------------------------------------------------------------------------------
# Least-squares problems for the sparse LM (normalised coordinates, residuals in input units)


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


# --------------------------------------------------------------------------------------------
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
        rho = W[6:8]
        np.multiply(O[0:2], c[0], out=rho)
        rho += O[1:3] * c[1]
        c_omega_c = self.ws2 * dot(c, rho)
        rho *= iw
        np.multiply(uv[0], rho[0], out=W[8])
        W[8] += uv[1] * rho[1]
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
        O, W, E = self.O, self.W, self.E
        rho = W[6:8]
        np.multiply(O[0:2], c[0], out=rho)
        rho += O[1:3] * c[1]
        c_omega_c = self.ws2 * dot(c, rho)
        rho *= iw
        np.multiply(uv[0], rho[0], out=W[8])
        W[8] += uv[1] * rho[1]
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


# --------------------------------------------------------------------------------------------
# Result and public estimator


@dataclass(frozen=True)
class HomographyFit:
    """A fitted homography dst ~ H src with its diagnostics.

    Attributes:
        H: (3, 3) homography in the input coordinates, H[2, 2] = 1.
        rms: root mean square of the residuals the method minimises, per coordinate, in the
            input units of the images (pixels): for "transfer" and "dlt",
            sqrt(sum_i ||x'_i - pi(H x_i)||^2 / (2 n)); for "gold",
            sqrt(sum_i (||x_i - x^_i||^2 + ||x'_i - pi(H x^_i)||^2) / (4 n)); n counts inliers.
            Under Gaussian noise sigma it tends to sigma sqrt(1 - 4/n) (transfer) and
            sigma sqrt((n - 4) / (2 n)) (gold): sigma sqrt(1 - d / N) for N measurements and d
            parameters (H&Z ch. 5, spec 01 sec. 1).
        cov: (9, 9) covariance of H's entries (row-major), gauge H[2,2] = 1 removed (zero row and
            column 8), scaled by the estimated residual variance 2 cost / (N - d): the inverse of
            the gauge-fixed Gauss-Newton information (H&Z ch. 5 and A6.4), propagated from the
            normalised coordinates.
            For "dlt" it is the transfer-error covariance evaluated at the DLT estimate
            (first-order; exact for the transfer estimator). NaN when n = 4 (no redundancy).
        inliers: (N,) bool mask of the correspondences used; all True without RANSAC.
        iterations: LM iterations of the refinement (0 for "dlt").
        method: the estimator that produced H.
        src_corrected: for "gold", (N, 2) the ML estimates x^_i of the first-image points
            (NaN rows for outliers); None otherwise.
        ransac_iterations: minimal samples drawn by RANSAC (0 without RANSAC).
    """

    H: Array
    rms: float
    cov: Array = field(repr=False)
    inliers: NDArray[np.bool_] = field(repr=False)
    iterations: int
    method: Method
    src_corrected: Array | None = field(default=None, repr=False)
    ransac_iterations: int = 0

    @property
    def n_inliers(self) -> int:
        """Number of correspondences used in the final fit."""
        return int(np.count_nonzero(self.inliers))


def _denormalize(g: Array, cov_g: Array, Ts: Array, Td: Array) -> tuple[Array, Array]:
    """Return (H, cov_H (9x9)) in input coordinates from H_n = H(g) with covariance cov_g.

    H = Td^-1 H_n Ts / (.)[2,2]; the covariance propagates by the Jacobian of that map (linear
    in H_n, then the gauge normalisation H[2,2] = 1), so row/column 8 come out zero.
    """
    (k, _, tx), (_, _, ty), _ = Td.tolist()  # Td = [[k, 0, tx], [0, k, ty], [0, 0, 1]]
    td_inv = np.array([[1.0 / k, 0.0, -tx / k], [0.0, 1.0 / k, -ty / k], [0.0, 0.0, 1.0]])
    h_raw = td_inv @ _h_from_params(g) @ Ts
    h = h_raw.ravel()
    h22 = float(h[8])
    H = _unit_h22(h_raw)
    # Row-major vec(A X B) = kron(A, B^T) vec(X); columns 0..7 are the free entries of H_n.
    m = (td_inv[:, None, :, None] * Ts.T[None, :, None, :]).reshape(9, 9)[:, :8]
    jac = m - h[:, None] * (m[8] / h22)
    jac *= 1.0 / h22
    cov = jac @ cov_g @ jac.T
    cov[8, :] = 0.0
    cov[:, 8] = 0.0
    cov += cov.T
    cov *= 0.5
    return H, cov


def fit_homography(
    src: ArrayLike,
    dst: ArrayLike,
    *,
    method: Method = "gold",
    robust: bool | Literal["ransac"] = False,
    ransac_threshold: float = 3.0,
    ransac_confidence: float = 0.999,
    ransac_max_iterations: int = 5000,
    seed: int | np.random.Generator | None = 0,
    max_iterations: int = 50,
) -> HomographyFit:
    """Return the HomographyFit of dst ~ H src by the chosen estimator.

    src, dst: (N, 2) corresponding points, N >= 4 (pixels; src may be metric plane coordinates).

    method:
        "dlt": normalised DLT (H&Z alg. 4.2), algebraic error.
        "transfer": LM on the dst transfer error sum ||x'_i - pi(H x_i)||^2 over the 8 dof of H
            (H&Z eq. 4.6); the ML estimate when src is exact (world-plane homography).
        "gold": gold-standard ML (H&Z alg. 4.3): minimises
            sum ||x_i - x^_i||^2 + ||x'_i - pi(H x^_i)||^2 (eq. 4.8) over H and the corrected
            points x^_i, by Gauss-Newton with the points eliminated in closed form (the sparse
            LM's Schur complement written out per point; the damped sparse LM takes over when a
            step fails); the ML estimate under equal isotropic Gaussian noise in both images
            (plane-induced homography).
        The iterative methods start from the DLT (and, for "gold", the Sampson points) and stop
        after `max_iterations`.
    robust: False, or True / "ransac" for LO-RANSAC (Chum, Matas & Kittler 2003) on 4-point
        minimal samples scored by the truncated dst transfer error (MSAC), with inliers at
        transfer error < `ransac_threshold` (input units of dst), refitting the DLT on the
        inliers of every new best model, and an adaptive sample count reaching
        `ransac_confidence`, capped at `ransac_max_iterations`; `seed` (int or Generator) makes
        it deterministic. The chosen method then runs on the inliers.

    Raises NotEnoughPoints (N < 4), InvalidInput (shape, NaN/inf, unknown option),
    DegenerateConfiguration (collinear points, no consensus, H[2,2] = 0).
    """
    s, d = _pair_inputs(src, dst)
    if method not in ("gold", "transfer", "dlt"):
        raise InvalidInput(f"method must be 'gold', 'transfer' or 'dlt', got {method!r}")
    if robust not in (False, True, "ransac"):
        raise InvalidInput(f"robust must be False, True or 'ransac', got {robust!r}")
    n = len(s)
    inliers = np.ones(n, dtype=bool)
    ransac_iterations = 0
    if robust:
        check_homography_configuration(s, d)
        if not (ransac_threshold > 0 and np.isfinite(ransac_threshold)):
            raise InvalidInput(f"ransac_threshold must be > 0, got {ransac_threshold}")
        if not 0 < ransac_confidence < 1:
            raise InvalidInput(f"ransac_confidence must be in (0, 1), got {ransac_confidence}")
        consensus = _lo_ransac(
            s,
            d,
            ransac_threshold,
            ransac_confidence,
            max(int(ransac_max_iterations), 1),
            np.random.default_rng(seed),
        )
        inliers, ransac_iterations = consensus.inliers, consensus.samples
        s, d = s[inliers], d[inliers]

    Ts, ps_t = _normalize_t(s, "src")
    Td, pd_t = _normalize_t(d, "dst")
    hn = _unit_h22(_dlt_normalized(ps_t, pd_t), "the normalised DLT estimate")
    g0 = hn.ravel()[:8]
    src_scale, dst_scale = float(Ts[0, 0]), float(Td[0, 0])

    m = ps_t.shape[1]
    corrected: Array | None = None
    if method == "gold":
        fit = _fit_gold(ps_t, pd_t, hn, src_scale, dst_scale, max_iterations)
        g, information, cost, iterations = fit.g, fit.information, fit.cost, fit.iterations
        inverse = fit.information_inverse
        n_residuals, n_parameters = 4 * m, 8 + 2 * m
        x_hat = ((fit.x_hat - Ts[:2, 2:]) / src_scale).T
        if robust:
            corrected = np.full((n, 2), np.nan)
            corrected[inliers] = x_hat
        else:
            corrected = x_hat
    else:
        lm = solve_sparse_lm(
            _TransferProblem(ps_t, pd_t, dst_scale),
            g0,
            np.zeros((m, 0)),
            max_iterations=0 if method == "dlt" else max_iterations,
            ptol=_LM_PTOL,
        )
        g, information, cost, iterations = lm.x_global, lm.information, lm.cost, lm.iterations
        inverse = None
        n_residuals, n_parameters = 2 * m, 8
    # Residual variance 2 cost / (N - d) (NaN without redundancy, n = 4).
    dof = n_residuals - n_parameters
    variance = 2.0 * cost / dof if dof > 0 else float("nan")
    # The gauge H_n[2,2] = 1 leaves no freedom, so S is invertible (pinv would cost 8x more).
    if inverse is not None:
        cov_g: Array = variance * inverse
    else:
        try:
            cov_g = variance * np.asarray(np.linalg.inv(information), np.float64)
        except np.linalg.LinAlgError:
            cov_g = variance * np.linalg.pinv(information, hermitian=True).astype(np.float64)
    H, cov = _denormalize(g, cov_g, Ts, Td)
    return HomographyFit(
        H=H,
        rms=float(np.sqrt(2.0 * cost / n_residuals)),
        cov=cov,
        inliers=inliers,
        iterations=iterations,
        method=method,
        src_corrected=corrected,
        ransac_iterations=ransac_iterations,
    )


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


def transfer_covariance(fit: HomographyFit, points: ArrayLike) -> Array:
    """Return the (N, 2, 2) covariance of pi(H x) for points x (N, 2) in src coordinates.

    First-order propagation of `fit.cov` (H&Z ch. 5): J cov J^T with J = d pi(H x) / d vec(H)
    (2 x 9). The points themselves are taken as exact; units are those of dst, squared.
    """
    x = as_points(points, 2, "points")
    ph = x @ fit.H[:, :2].T + fit.H[:, 2]
    inv_w = 1.0 / ph[:, 2]
    uv = ph[:, :2] * inv_w[:, None]
    xh = np.hstack([x, np.ones((len(x), 1))]) * inv_w[:, None]
    jac = np.zeros((len(x), 2, 9))
    jac[:, 0, 0:3] = xh
    jac[:, 1, 3:6] = xh
    jac[:, :, 6:9] = -uv[:, :, None] * xh[:, None, :]
    out: Array = jac @ fit.cov @ jac.transpose(0, 2, 1)
    return out


# --------------------------------------------------------------------------------------------
# LO-RANSAC


@dataclass(frozen=True)
class _Consensus:
    inliers: NDArray[np.bool_]
    samples: int


def _triple_dets(p: Array) -> Array:
    """Return (K, 4) signed areas of the four point triples of minimal samples p (K, 4, 2)."""
    out = np.empty((len(p), 4))
    for k, (a, b, c) in enumerate(((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3))):
        u = p[:, b] - p[:, a]
        v = p[:, c] - p[:, a]
        out[:, k] = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    return out


def _basis_maps(p: Array) -> Array:
    """Return B (K, 3, 3) mapping e1, e2, e3, (1,1,1) to the four points of each sample
    (columns p1, p2, p3 scaled by lambda with [p1 p2 p3] lambda = p4); requires no three
    points collinear."""
    ph = np.concatenate([p, np.ones((*p.shape[:2], 1))], axis=2)  # (K, 4, 3)
    a = ph[:, :3].transpose(0, 2, 1)
    lam = np.linalg.solve(a, ph[:, 3, :, None])[:, :, 0]
    return a * lam[:, None, :]


def _four_point_homographies(ps: Array, pd: Array) -> tuple[Array, NDArray[np.bool_]]:
    """Return (H (K, 3, 3), valid (K,)) with pd ~ H ps exactly for every minimal sample.

    Samples with a (nearly) collinear triple on either side, or whose triples change orientation
    inconsistently (impossible for points in front of a camera), are invalid.
    """
    ds, dd = _triple_dets(ps), _triple_dets(pd)
    prod = ds * dd
    valid = np.all(np.abs(ds) > _SAMPLE_DET_TOL, axis=1) & np.all(
        np.abs(dd) > _SAMPLE_DET_TOL, axis=1
    )
    valid &= np.all(prod > 0, axis=1) | np.all(prod < 0, axis=1)
    ps = np.where(valid[:, None, None], ps, _UNIT_SQUARE)
    pd = np.where(valid[:, None, None], pd, _UNIT_SQUARE)
    bs, bd = _basis_maps(ps), _basis_maps(pd)
    # H = Bd Bs^-1, solved as Bs^T H^T = Bd^T.
    h = np.linalg.solve(bs.transpose(0, 2, 1), bd.transpose(0, 2, 1)).transpose(0, 2, 1)
    return np.asarray(h, np.float64), valid


_UNIT_SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def _transfer_errors2(h: Array, ps_h: Array, pd_t: Array) -> Array:
    """Return (K, N) squared dst transfer errors of hypotheses h (K, 3, 3); ps_h (3, N) are the
    homogeneous src points, pd_t (2, N) the dst points. Points mapped to infinity get an
    infinite error."""
    ph = h @ ps_h  # (K, 3, N)
    w = ph[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_w = 1.0 / w
        du = ph[:, 0] * inv_w - pd_t[0]
        dv = ph[:, 1] * inv_w - pd_t[1]
        e2 = du * du + dv * dv
    return np.where(np.isfinite(e2), e2, np.inf)


def _required_samples(inlier_ratio: float, confidence: float) -> float:
    """Return the number of minimal samples for `confidence` of one all-inlier sample."""
    w4 = inlier_ratio**4
    if w4 >= 1.0:
        return 0.0
    if w4 <= 0.0:
        return np.inf
    return float(np.log1p(-confidence) / np.log1p(-w4))


def _lo_ransac(
    s: Array,
    d: Array,
    threshold: float,
    confidence: float,
    max_samples: int,
    rng: np.random.Generator,
) -> _Consensus:
    """Return the consensus set of LO-RANSAC (Chum, Matas & Kittler, DAGM 2003) with MSAC
    scoring (Torr & Zisserman 2000): the truncated squared dst transfer error."""
    n = len(s)
    _, ps_t = _normalize_t(s, "src")
    Td, pd_t = _normalize_t(d, "dst")
    ps, pd = ps_t.T, pd_t.T
    thr2 = (threshold * Td[0, 0]) ** 2
    ps_h = np.vstack([ps_t, np.ones(n)])
    # Batches start small (32 samples already find an all-inlier one with 99.98 % probability
    # at 70 % inliers) and double while more are needed, up to a memory-bounded size.
    max_batch = int(np.clip(_RANSAC_BATCH_ELEMENTS // n, 8, 512))
    batch = min(32, max_batch)

    best_score = np.inf
    best_mask = np.zeros(n, dtype=bool)
    needed = float(max_samples)
    drawn = 0
    while drawn < min(needed, max_samples):
        k = int(min(batch, max_samples - drawn))
        batch = min(2 * batch, max_batch)
        idx = rng.integers(0, n, size=(k, 4))
        drawn += k
        srt = np.sort(idx, axis=1)
        idx = idx[np.all(srt[:, 1:] != srt[:, :-1], axis=1)]
        if len(idx) == 0:
            continue
        hyps, valid = _four_point_homographies(ps[idx], pd[idx])
        hyps = hyps[valid]
        if len(hyps) == 0:
            continue
        e2 = _transfer_errors2(hyps, ps_h, pd_t)
        scores = np.minimum(e2, thr2).sum(axis=1)
        j = int(np.argmin(scores))
        if scores[j] >= best_score:
            continue
        best_score = float(scores[j])
        best_mask = e2[j] < thr2
        # Local optimisation: refit on the consensus set while the score improves.
        for _ in range(5):
            if np.count_nonzero(best_mask) < 5:
                break
            try:
                h_lo = _dlt_normalized(ps_t[:, best_mask], pd_t[:, best_mask])
            except DegenerateConfiguration:
                break
            e2_lo = _transfer_errors2(h_lo[None], ps_h, pd_t)[0]
            score_lo = float(np.minimum(e2_lo, thr2).sum())
            if score_lo >= best_score:
                break
            best_score = score_lo
            best_mask = e2_lo < thr2
        needed = _required_samples(np.count_nonzero(best_mask) / n, confidence)

    if np.count_nonzero(best_mask) < 4:
        raise DegenerateConfiguration(
            "RANSAC found no model with 4 or more inliers; raise ransac_threshold or check the "
            "correspondences"
        )
    return _Consensus(inliers=best_mask, samples=drawn)
