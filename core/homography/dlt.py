"""The normalised DLT (H&Z alg. 4.2): the homography that minimises the algebraic error of the
2N x 9 system on Hartley-normalised points, the start of every iterative estimate and the
model RANSAC refits on a consensus set.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg.lapack import dsyev as _syev

from core.errors import DegenerateConfiguration
from core.homography.normalization import _normalize_t, _pair_inputs

Array = NDArray[np.float64]

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
