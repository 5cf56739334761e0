"""The correspondences a homography is estimated from: checked as a pair, Hartley-normalised
(H&Z alg. 4.2), and tested for the configurations that fix no homography (coincident or
collinear points; for four points, three on a line).

Every estimator of the package (`core.homography.dlt`, `core.homography.estimate`,
`core.homography.ransac`) starts here, on both sides of the correspondences.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_points
from core.errors import DegenerateConfiguration, InvalidInput

Array = NDArray[np.float64]

# Collinearity: a point cloud whose smaller principal axis is below this fraction of the larger
# is a line. The axes come from the 2 x 2 scatter matrix, whose eigenvalues are exact to ~1e-16
# of the larger, i.e. axes to ~1e-8: the threshold sits above that rounding floor (6e-5 px
# across a 640 px image, far below any real measurement's spread).
_COLLINEAR_TOL = 1e-7


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


def _pair_inputs(src: ArrayLike, dst: ArrayLike) -> tuple[Array, Array]:
    s = as_points(src, 2, "src", min_count=4)
    d = as_points(dst, 2, "dst", min_count=4)
    if s.shape != d.shape:
        raise InvalidInput(f"src and dst must have the same shape, got {s.shape} and {d.shape}")
    return s, d


def _triple_dets(p: Array) -> Array:
    """Return (K, 4) signed areas of the four point triples of minimal samples p (K, 4, 2)."""
    out = np.empty((len(p), 4))
    for k, (a, b, c) in enumerate(((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3))):
        u = p[:, b] - p[:, a]
        v = p[:, c] - p[:, a]
        out[:, k] = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    return out
