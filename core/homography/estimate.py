"""Homography estimation: normalised DLT (more estimators build on it)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_points
from core.errors import DegenerateConfiguration, InvalidInput
from core.geometry.normalization import hartley_normalization

Array = NDArray[np.float64]

# Relative tolerance for collinearity: |det| of a point triple (normalised coordinates, mean
# distance sqrt(2) from the centroid) below this is treated as collinear.
_COLLINEAR_TOL = 1e-9


def check_homography_configuration(src: Array, dst: Array) -> None:
    """Raise DegenerateConfiguration when the point sets cannot determine a homography.

    Checks both sides: all points collinear (or coincident), and, for exactly four points, any
    three of them collinear.
    """
    for name, pts in (("src", src), ("dst", dst)):
        _, p = hartley_normalization(pts)
        if not np.any(p):
            raise DegenerateConfiguration(f"all {name} points coincide; spread the points out")
        # Singular values of the centred cloud: the smallest ~ 0 means all points on a line.
        sv = np.linalg.svd(p, compute_uv=False)
        if sv[-1] <= _COLLINEAR_TOL * max(sv[0], 1e-300) * np.sqrt(len(p)):
            raise DegenerateConfiguration(
                f"all {name} points are collinear; a homography needs points spread over the plane"
            )
        if len(p) == 4:
            h = np.hstack([p, np.ones((4, 1))])
            for skip in range(4):
                tri = np.delete(h, skip, axis=0)
                if abs(np.linalg.det(tri)) <= 1e-7:
                    raise DegenerateConfiguration(
                        f"three of the four {name} points are collinear; "
                        "no three of four points may lie on a line"
                    )


def dlt_homography(src: ArrayLike, dst: ArrayLike) -> Array:
    """Return H (3x3, H[2,2] = 1) with dst ~ H src by the normalised DLT (H&Z alg. 4.2).

    src, dst: (N, 2) pixel or metric coordinates, N >= 4. Minimises the algebraic error of the
    2N x 9 system on Hartley-normalised points. Raises NotEnoughPoints, InvalidInput or
    DegenerateConfiguration.
    """
    s = as_points(src, 2, "src", min_count=4)
    d = as_points(dst, 2, "dst", min_count=4)
    if s.shape != d.shape:
        raise InvalidInput(f"src and dst must have the same shape, got {s.shape} and {d.shape}")
    check_homography_configuration(s, d)
    Ts, ps = hartley_normalization(s)
    Td, pd = hartley_normalization(d)
    n = len(ps)
    x, y = ps[:, 0], ps[:, 1]
    u, v = pd[:, 0], pd[:, 1]
    zero, one = np.zeros(n), np.ones(n)
    a = np.empty((2 * n, 9))
    a[0::2] = np.stack([x, y, one, zero, zero, zero, -u * x, -u * y, -u], axis=1)
    a[1::2] = np.stack([zero, zero, zero, x, y, one, -v * x, -v * y, -v], axis=1)
    # The right singular vector of the smallest singular value; A^T A (9x9) keeps it O(n).
    _, sv, vt = np.linalg.svd(a.T @ a) if n > 64 else np.linalg.svd(a)
    if sv[-2] <= 1e-12 * sv[0]:
        raise DegenerateConfiguration(
            "the DLT system has a null space of dimension > 1; the points do not fix a homography"
        )
    hn = vt[-1].reshape(3, 3)
    H = np.linalg.solve(Td, hn @ Ts)
    if abs(H[2, 2]) < 1e-12 * np.abs(H).max():
        raise DegenerateConfiguration(
            "the homography maps the origin to infinity (H[2,2] = 0); cannot normalise H[2,2] = 1"
        )
    return H / H[2, 2]
