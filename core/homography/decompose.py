"""Decomposition of a plane-induced homography into rotation, scaled translation and plane normal.

Model (spec 01 §3). A plane n^T X = d (n unit, d > 0, X in camera-1 coordinates) seen by two
cameras related by X2 = R X1 + t induces x2 ~ H x1 between their pixels, with

    H ~ K2 (R + t n^T / d) K1^-1         (cf. Hartley & Zisserman, 2nd ed., result 13.1, there
                                           with the plane written n^T X + d = 0)

which is OpenCV's convention for cv2.decomposeHomographyMat. Every result below reports t
already divided by d (so it is metric once the plane distance, e.g. the camera height, is known).

Method: the SVD-based decomposition of Faugeras & Lustman (1988) as presented by Zhang & Hanson
(1996) and Ma, Soatto, Kosecka & Sastry ("An Invitation to 3-D Vision", 2004, §5.3.3). With
H_e = K2^-1 H K1 = U diag(s1, s2, s3) V^T, scaled so that s2 = 1 (the middle singular value of
R + t n^T is always 1), the problem reduces to the diagonal one diag(s1, 1, s3) = R' + t' n'^T
with R = U R' V^T, t = U t', n = V n' and

    n' = (e1 x1, 0, e3 x3),  x1 = sqrt((s1^2 - 1) / (s1^2 - s3^2)),
                             x3 = sqrt((1 - s3^2) / (s1^2 - s3^2))
    R' = rotation about the second axis by theta,  cos theta = s1 x3^2 + s3 x1^2,
                                                   sin theta = e1 e3 x1 x3 (s1 - s3)
    t' = (s1 - s3) (e1 x1, 0, -e3 x3)

for the sign choices e1, e3 in {+1, -1}.

How the eight algebraic solutions reduce to four, then two:

* Both H_e and -H_e are admissible scalings; each yields the four solutions above, eight in all.
  det(R + t n^T) = 1 + n^T R^T t = d2 / d, the ratio of the plane's distances to the two camera
  centres. Fixing the sign of H_e by det(H_e) > 0 keeps the four solutions with both camera
  centres on the same side of the plane ("the plane in front"); this is the set that
  cv2.decomposeHomographyMat (Malis & Vargas, INRIA RR-6303, 2007) returns, and it is invariant
  to the sign of the H given.
* The four are two pairs (R, t, n) and (R, -t, -n) (e1, e3 -> -e1, -e3). Requiring the observed
  reference points to lie in front of the plane as seen from both cameras, n^T m1 > 0 and
  (R n)^T m2 > 0 for the normalised rays m1, m2 (cv2.filterHomographyDecompByVisibleRefpoints),
  removes one of each pair: two physically realisable solutions remain in general. For every
  point visible in both views m2 ~ H_e m1 with a positive factor (positive depth,
  x2^T H_e x1 > 0), so a point set that violates positive depth leaves no candidate.

Special cases, handled explicitly:

* Pure rotation, s1 = s3 (t = 0): the normal is undefined. One solution is returned, R the
  rotation nearest to H_e, t = 0 and, by convention, n = (0, 0, 1), the optical axis of view 1
  (every n gives the same homography when t = 0; this one passes the visibility test for every
  point in front of both cameras). OpenCV returns n = 0 instead. As in OpenCV, a homography
  with max |H_e^T H_e - I| < rotation_tol (default 1e-3, OpenCV's threshold) is treated as a
  pure rotation: a translation that small (|t/d| below ~5e-4) cannot be resolved from a
  homography estimated with typical pixel noise.
* Translation along the normal, s1 = s2 or s2 = s3 (R^T t parallel to n): the two pairs
  coincide; the unique solution is returned with its sign pair, two candidates (OpenCV returns
  the same two twice).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_matrix, as_points
from core.errors import DegenerateConfiguration, InvalidInput
from core.geometry.rotations import nearest_rotation

Array = NDArray[np.float64]

CASE_SINGULAR: Final = -1
CASE_GENERAL: Final = 0
CASE_PURE_ROTATION: Final = 1
CASE_ALONG_NORMAL: Final = 2
CASE_KNOWN_NORMAL: Final = 3
_CASE_NAMES: Final = {
    CASE_GENERAL: "general",
    CASE_PURE_ROTATION: "pure_rotation",
    CASE_ALONG_NORMAL: "translation_along_normal",
    CASE_KNOWN_NORMAL: "known_normal",
}

# OpenCV's pure-rotation threshold on max |H_e^T H_e - I| (homography_decomp.cpp), kept as the
# default so that both return the same candidate set on the same input.
DEFAULT_ROTATION_TOL: Final = 1e-3
# Singular-value gaps below this many ulps of s1 are below what a 3x3 SVD resolves (its
# singular values carry an absolute error of a few eps * s1): such gaps are treated as zero.
_GAP_ULPS: Final = 64.0
# H_e with s3 / s1 below this is rank-deficient: the plane passes through a camera centre.
_SINGULAR_RCOND: Final = 1e-10


@dataclass(frozen=True)
class PlaneMotion:
    """One decomposition H_e ~ R + t n^T of a plane-induced homography.

    R: (3, 3) rotation taking camera-1 coordinates to camera-2 coordinates (X2 = R X1 + t).
    t: (3,) translation in camera-2 coordinates divided by the plane distance d (unitless).
    n: (3,) unit plane normal in camera-1 coordinates (plane n^T X1 = d).
    case: "general", "pure_rotation", "translation_along_normal" or "known_normal".
    """

    R: Array
    t: Array
    n: Array
    case: str = "general"

    @property
    def distance_ratio(self) -> float:
        """Return d2 / d = 1 + n^T R^T t, the plane's distance from camera 2 over camera 1."""
        return float(1.0 + self.n @ (self.R.T @ self.t))


@dataclass(frozen=True)
class HomographyDecompositionBatch:
    """Every candidate decomposition of B homographies, fixed-size with a validity mask.

    R: (B, 4, 3, 3); t: (B, 4, 3) (divided by the plane distance); n: (B, 4, 3) unit normals.
    valid: (B, 4) bool, which slots hold a distinct candidate. Slots 0 and 1 are one
    (R, t, n), (R, -t, -n) pair and slots 2 and 3 the other; within a pair the candidate with
    n_z >= 0 (plane facing camera 1 along its optical axis) comes first. Pure rotation: slot 0
    only; translation along the normal: slots 0 and 1 only; singular H_e: none.
    case: (B,) int8, CASE_GENERAL, CASE_PURE_ROTATION, CASE_ALONG_NORMAL or CASE_SINGULAR.
    """

    R: Array
    t: Array
    n: Array
    valid: NDArray[np.bool_]
    case: NDArray[np.int8]


def _check_intrinsics(K: Array, name: str) -> None:
    sv = np.linalg.svd(K, compute_uv=False)
    if not np.all(sv[..., -1] > 1e-12 * sv[..., 0]):
        raise DegenerateConfiguration(
            f"{name} is singular; pass the 3x3 intrinsic matrix "
            "[[fx, s, cx], [0, fy, cy], [0, 0, 1]]"
        )


def _euclidean_homography(H: Array, K: Array, K2: Array) -> Array:
    """Return H_e = K2^-1 H K, shape (..., 3, 3) (not yet scaled)."""
    # One inverse of a (3, 3) K2 broadcast over the batch is cheaper than a batched solve.
    return np.linalg.inv(K2) @ H @ K


def _decompose_normalised(He: Array, rotation_tol: float) -> HomographyDecompositionBatch:
    """Decompose H_e (B, 3, 3) (any scale and sign) by the SVD method; see the module docstring.

    The SVD is taken from the eigen-decomposition H_e^T H_e = V diag(s^2) V^T (LAPACK's
    batched symmetric solver, ~2x faster than the batched general SVD), with s3 = det(H_e) /
    (s1 s2), u1 = H_e v1 / s1, u2 = H_e v2 / s2 and u3 = det(V) u1 x u2; R, t and n are then
    assembled in closed form from these columns (no 3x3 products per candidate).
    """
    B = He.shape[0]
    # Sign: det(H_e) > 0 keeps the solutions with both camera centres on one side of the plane.
    det = np.linalg.det(He)
    He = He * np.where(det < 0, -1.0, 1.0)[:, None, None]
    HtH = np.swapaxes(He, -1, -2) @ He
    lam, V = np.linalg.eigh(HtH)  # ascending eigenvalues
    lam = np.maximum(lam[:, ::-1], 0.0)
    V = V[:, :, ::-1]
    s = np.sqrt(lam)
    # s3 from the determinant keeps full relative precision for small s3 (sqrt(lam3) carries an
    # absolute error of eps * s1^2 / s3).
    s[:, 2] = np.abs(det) / np.maximum(s[:, 0] * s[:, 1], np.finfo(float).tiny)
    singular = ~(s[:, 2] > _SINGULAR_RCOND * s[:, 0])
    s2 = np.where(singular, 1.0, s[:, 1])
    He = He / s2[:, None, None]
    s = s / s2[:, None]
    s = np.where(singular[:, None], 1.0, s)
    s1, s3 = s[:, 0], s[:, 2]

    # Pure rotation by OpenCV's criterion, max |S_ij| with S = H_e^T H_e - I (elementwise), or a
    # gap s1 - s3 too small to resolve.
    S_max = np.max(np.abs(HtH / (s2 * s2)[:, None, None] - np.eye(3)), axis=(1, 2))
    gap_tol = _GAP_ULPS * np.finfo(float).eps * s1
    pure = ~singular & ((S_max < rotation_tol) | (s1 - s3 <= gap_tol))
    along = ~singular & ~pure & ((s1 - 1.0 <= gap_tol) | (1.0 - s3 <= gap_tol))

    # (s1^2 - 1) and (1 - s3^2) as products keep their relative precision near the special cases.
    a1 = np.where(s1 - 1.0 <= gap_tol, 0.0, (s1 - 1.0) * (s1 + 1.0))
    a3 = np.where(1.0 - s3 <= gap_tol, 0.0, (1.0 - s3) * (1.0 + s3))
    den = np.where(pure | singular, 1.0, a1 + a3)
    x1 = np.sqrt(a1 / den)
    x3 = np.sqrt(a3 / den)
    x3 = np.where(pure | singular, 1.0, x3)
    cos_t = s1 * x3 * x3 + s3 * x1 * x1
    sin_abs = x1 * x3 * (s1 - s3)
    d13 = s1 - s3

    # U = H_e V diag(1/s): left singular vectors without a second factorisation. u3 is taken as
    # det(V) u1 x u2 (det U = det V because det H_e > 0), exact however small s3 is.
    v1, v2, v3 = V[:, :, 0], V[:, :, 1], V[:, :, 2]
    u1 = (He @ v1[:, :, None])[:, :, 0] / s1[:, None]
    u2 = (He @ v2[:, :, None])[:, :, 0]
    det_v = np.einsum("bi,bi->b", np.cross(v1, v2), v3)
    u3 = det_v[:, None] * np.cross(u1, u2)

    def outer(a: Array, b: Array) -> Array:
        return a[:, :, None] * b[:, None, :]

    # R = U R' V^T with R' the rotation about the second axis, expanded so that only the two
    # distinct rotations (sin theta = +-|sin theta|) are formed.
    even = cos_t[:, None, None] * (outer(u1, v1) + outer(u3, v3)) + outer(u2, v2)
    odd = sin_abs[:, None, None] * (outer(u3, v1) - outer(u1, v3))
    Ra, Rb = even + odd, even - odd
    R = np.stack([Ra, Ra, Rb, Rb], axis=1)  # (B, 4, 3, 3)

    # Slots: (e1, e3) = (+, +), (-, -), (+, -), (-, +); t = U t', n = V n'.
    e1 = np.array([1.0, -1.0, 1.0, -1.0])[None, :, None]
    e3 = np.array([1.0, -1.0, -1.0, 1.0])[None, :, None]
    xu1 = (x1 * d13)[:, None, None] * u1[:, None, :]
    xu3 = (x3 * d13)[:, None, None] * u3[:, None, :]
    t = e1 * xu1 - e3 * xu3  # (B, 4, 3)
    n = e1 * (x1[:, None, None] * v1[:, None, :]) + e3 * (x3[:, None, None] * v3[:, None, :])

    # Pure rotation: R = U V^T (the rotation nearest to H_e), t = 0, n = optical axis.
    if np.any(pure):
        R[pure, 0] = nearest_rotation(He[pure])
        t[pure] = 0.0
        n[pure] = (0.0, 0.0, 1.0)

    # Within each (R, t, n), (R, -t, -n) pair, put the one with n_z >= 0 first.
    flip = n[:, 0::2, 2] < 0  # (B, 2)
    for k in (0, 2):
        f = flip[:, k // 2]
        for arr in (t, n):
            first, second = arr[f, k].copy(), arr[f, k + 1].copy()
            arr[f, k], arr[f, k + 1] = second, first

    valid = np.ones((B, 4), dtype=bool)
    valid[along, 2:] = False
    valid[pure, 1:] = False
    valid[singular] = False
    case = np.full(B, CASE_GENERAL, dtype=np.int8)
    case[along] = CASE_ALONG_NORMAL
    case[pure] = CASE_PURE_ROTATION
    case[singular] = CASE_SINGULAR
    R[singular] = np.nan
    t[singular] = np.nan
    n[singular] = np.nan
    return HomographyDecompositionBatch(R=R, t=t, n=n, valid=valid, case=case)


def _as_intrinsics_batch(K: ArrayLike, B: int, name: str) -> Array:
    a = np.asarray(K, dtype=np.float64)
    if a.shape == (3, 3):
        a = as_matrix(a, (3, 3), name)
    else:
        a = as_matrix(a, (B, 3, 3), name)
    _check_intrinsics(a, name)
    return a


def decompose_homography_batch(
    H: ArrayLike,
    K: ArrayLike,
    *,
    K2: ArrayLike | None = None,
    rotation_tol: float = DEFAULT_ROTATION_TOL,
) -> HomographyDecompositionBatch:
    """Return every candidate (R, t/d, n) of B plane-induced homographies at once.

    H: (B, 3, 3) pixel homographies, view 1 -> view 2, any scale and sign.
    K: (3, 3) or (B, 3, 3) intrinsics of view 1; K2: the same for view 2 (default K).
    Vectorised over B (no Python loop over homographies): the same candidates as
    decompose_homography with no keyword, in fixed slots with a validity mask (see
    HomographyDecompositionBatch). A singular H_e does not raise here: its slots are invalid
    and its case is CASE_SINGULAR. Raises InvalidInput on wrong shapes or non-finite values and
    DegenerateConfiguration on a singular K or K2.
    """
    Hb = np.asarray(H, dtype=np.float64)
    if Hb.ndim != 3:
        raise InvalidInput(f"H must have shape (B, 3, 3), got {Hb.shape}")
    Hb = as_matrix(Hb, (Hb.shape[0], 3, 3), "H")
    B = Hb.shape[0]
    Kb = _as_intrinsics_batch(K, B, "K")
    K2b = Kb if K2 is None else _as_intrinsics_batch(K2, B, "K2")
    if not rotation_tol >= 0:
        raise InvalidInput(f"rotation_tol must be >= 0, got {rotation_tol}")
    return _decompose_normalised(_euclidean_homography(Hb, Kb, K2b), rotation_tol)


def _rays(points: Array, K: Array) -> Array:
    """Return normalised rays K^-1 (x, y, 1), scaled to unit third coordinate, shape (N, 3)."""
    h = np.hstack([points, np.ones((len(points), 1))])
    m = np.linalg.solve(K, h.T).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return m / m[:, 2:3]


def _visible(R: Array, n: Array, m1: Array, m2: Array) -> NDArray[np.bool_]:
    """Return (k,) mask: n^T m1 > 0 and (R n)^T m2 > 0 for every point (OpenCV's filter)."""
    rn = np.einsum("kij,kj->ki", R, n)
    with np.errstate(invalid="ignore"):
        ok1 = np.all(m1 @ n.T > 0, axis=0)
        ok2 = np.all(m2 @ rn.T > 0, axis=0)
    return ok1 & ok2


def _known_normal(He: Array, n: Array, sign: float) -> PlaneMotion:
    """Return the least-squares (R, t) of lambda H_e = R + t n^T for a known unit normal n.

    Minimises ||lambda H_e - R - t n^T||_F over R in SO(3), t and lambda > 0. For fixed R the
    optimal t is (lambda H_e - R) n, leaving ||(lambda H_e - R) P||_F with P = I - n n^T; the
    optimal R is then the orthogonal Procrustes solution, the rotation nearest to H_e P
    (Schonemann 1966; it does not depend on lambda), and lambda = tr(R^T H_e P) / ||H_e P||_F^2.
    """
    M = sign * He
    P = np.eye(3) - np.outer(n, n)
    MP = M @ P
    R = nearest_rotation(MP)
    lam = float(np.trace(R.T @ MP) / np.sum(MP * MP))
    t = (lam * M - R) @ n
    return PlaneMotion(R=R, t=t, n=n.copy(), case=_CASE_NAMES[CASE_KNOWN_NORMAL])


def decompose_homography(
    H: ArrayLike,
    K: ArrayLike,
    *,
    K2: ArrayLike | None = None,
    points: ArrayLike | None = None,
    points2: ArrayLike | None = None,
    normal: ArrayLike | None = None,
    rotation_tol: float = DEFAULT_ROTATION_TOL,
) -> list[PlaneMotion]:
    """Return the decompositions (R, t/d, n) of a plane-induced homography H ~ K2 (R + t n^T) K^-1.

    H: (3, 3) homography taking view-1 pixels to view-2 pixels, any scale and sign.
    K: (3, 3) intrinsics of view 1; K2: (3, 3) intrinsics of view 2 (default K).
    H_e = K2^-1 H K is scaled so that its middle singular value is 1 and its sign so that
    det(H_e) > 0 (see the module docstring for why this is positive depth for visible points).

    * No keyword: every candidate with both camera centres on the same side of the plane, four
      in general (the set cv2.decomposeHomographyMat returns), two when the translation is along
      the normal, one for a pure rotation.
    * points: (N, 2) view-1 pixels of points on the plane, with points2 (N, 2) their view-2
      pixels (default: the points transferred by H). Only the physically realisable candidates,
      n^T m1 > 0 and (R n)^T m2 > 0 for every ray m1 = K^-1 x1, m2 = K2^-1 x2 (the selection of
      cv2.filterHomographyDecompByVisibleRefpoints); two in general, none if the points violate
      positive depth.
    * normal: (3,) plane normal in view-1 coordinates (normalised here), e.g. the floor from
      calibration: exactly one solution, the least squares fit of H_e = R + t n^T with R a
      rotation (see _known_normal), not a pick among the candidates. If points are also given
      they fix the sign of H_e by positive depth (x2^T H_e x1 > 0 for most points).

    rotation_tol: max |H_e^T H_e - I| below which H is treated as a pure rotation.
    Raises InvalidInput (shapes, NaN), DegenerateConfiguration (singular H_e, K or K2).
    """
    Hm = as_matrix(H, (3, 3), "H")
    Km = as_matrix(K, (3, 3), "K")
    _check_intrinsics(Km, "K")
    K2m = Km if K2 is None else as_matrix(K2, (3, 3), "K2")
    if K2 is not None:
        _check_intrinsics(K2m, "K2")
    if not rotation_tol >= 0:
        raise InvalidInput(f"rotation_tol must be >= 0, got {rotation_tol}")
    p1 = None if points is None else as_points(points, 2, "points", min_count=1)
    if points2 is not None and p1 is None:
        raise InvalidInput("points2 was given without points; pass the view-1 points as well")
    p2 = None if points2 is None else as_points(points2, 2, "points2", min_count=1)
    if p1 is not None and p2 is not None and p1.shape != p2.shape:
        raise InvalidInput(
            f"points and points2 must have the same shape, got {p1.shape} and {p2.shape}"
        )
    n_known = None
    if normal is not None:
        n_known = as_matrix(normal, (3,), "normal")
        norm = float(np.linalg.norm(n_known))
        if norm == 0.0:
            raise InvalidInput("normal is the zero vector; pass the plane's unit normal")
        n_known = n_known / norm

    He = _euclidean_homography(Hm, Km, K2m)
    sv = np.linalg.svd(He, compute_uv=False)
    if not sv[2] > _SINGULAR_RCOND * sv[0]:
        raise DegenerateConfiguration(
            "K2^-1 H K is singular (rank < 3): the plane passes through a camera centre or H was "
            "estimated from degenerate points; re-estimate H from points spread over the plane"
        )
    He = He / sv[1]

    m1 = m2 = None
    if p1 is not None:
        m1 = _rays(p1, Km)
        if p2 is None:
            h2 = np.hstack([p1, np.ones((len(p1), 1))]) @ Hm.T
            with np.errstate(divide="ignore", invalid="ignore"):
                p2 = h2[:, :2] / h2[:, 2:3]
        m2 = _rays(p2, K2m)

    if n_known is not None:
        sign = 1.0 if np.linalg.det(He) > 0 else -1.0
        if m1 is not None and m2 is not None:
            depth = np.einsum("ni,ij,nj->n", m2, He, m1)
            vote = np.sum(np.sign(depth[np.isfinite(depth)]))
            if vote != 0:
                sign = float(np.sign(vote))
        return [_known_normal(He, n_known, sign)]

    res = _decompose_normalised(He[None], rotation_tol)
    keep = np.nonzero(res.valid[0])[0]
    R, t, n = res.R[0, keep], res.t[0, keep], res.n[0, keep]
    if m1 is not None and m2 is not None:
        vis = _visible(R, n, m1, m2)
        R, t, n = R[vis], t[vis], n[vis]
    case = _CASE_NAMES[int(res.case[0])]
    return [PlaneMotion(R=R[i], t=t[i], n=n[i], case=case) for i in range(len(R))]
