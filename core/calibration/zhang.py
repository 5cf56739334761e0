"""Camera calibration from several views of a plane (Zhang 2000, "A flexible new technique for
camera calibration", IEEE PAMI 22(11); equation numbers below refer to that paper).

1. One world-plane homography per view, H_j ~ K [r1 r2 t] (normalised DLT, H&Z alg. 4.2).
2. Closed form for B = K^-T K^-1 (eq. 5): each view gives h1^T B h2 = 0 and
   h1^T B h1 = h2^T B h2 (eq. 3-4), i.e. two rows of V b = 0 (eq. 8-9), b = (B11, B12, B22, B13,
   B23, B33). Five intrinsics need >= 3 views; with zero skew the column of B12 is dropped
   (B12 = 0 exactly) and >= 2 views suffice. K follows from B (appendix B).
3. Extrinsics per view from K^-1 H (sec. 3.1) with the nearest rotation (appendix C).
4. Radial distortion (k1, k2) by linear least squares (eq. 13), the others start at zero.
5. Maximum-likelihood refinement of sum_ij ||m_ij - m(K, dist, R_j, t_j, M_ij)||^2 (eq. 14) by
   the sparse Schur-complement LM of `core.optim` (global block: intrinsics and distortion;
   local blocks: one 6-dof pose per view) with analytic Jacobians.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_points
from core.calibration.pose import plane_points, pose_from_homography
from core.errors import DegenerateConfiguration, InvalidInput, NotEnoughPoints
from core.geometry.camera import (
    DISTORTION_NAMES,
    INTRINSIC_NAMES,
    Pose,
    ReprojectionProblem,
    intrinsics_to_matrix,
    project_points,
)
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix
from core.homography.dlt import dlt_homography
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]

#: Distortion models: name -> indices into (k1, k2, p1, p2, k3) that are estimated.
DISTORTION_MODELS: dict[str, tuple[int, ...]] = {
    "none": (),
    "k1": (0,),
    "k1k2": (0, 1),
    "k1k2p1p2": (0, 1, 2, 3),
    "k1k2p1p2k3": (0, 1, 2, 3, 4),
}

PARAMETER_NAMES: tuple[str, ...] = INTRINSIC_NAMES + DISTORTION_NAMES

# Null-space test of V b = 0: a second singular value below this fraction of the largest means
# the views do not fix B (parallel planes, fronto-parallel views, too few distinct orientations).
_NULLSPACE_TOL = 1e-9


@dataclass(frozen=True)
class CameraCalibration:
    """Intrinsics, distortion and per-view poses of a camera calibrated from a planar pattern.

    K: (3, 3) [[fx, skew, cx], [0, fy, cy], [0, 0, 1]], pixels. dist: (5,) OpenCV order
    (k1, k2, p1, p2, k3), zeros where not estimated; applied to ideal normalised coordinates
    (see `core.geometry.camera`). rms: sqrt(sum of squared 2D reprojection errors / number of
    points), pixels, as cv2.calibrateCamera reports it. per_view_rms: (m,) the same per view.
    std_intrinsics: standard deviation of each of fx, fy, cx, cy, skew, k1, k2, p1, p2, k3
    (pixels, or unitless for distortion), from the Gauss-Newton covariance with the residual
    variance estimated as SSE / (2 N - d); 0.0 for parameters held fixed (as OpenCV reports).
    poses: one `Pose` per view, plane-to-camera (Xc = R X + t, t in the pattern's length unit);
    `rvecs`, `tvecs` give them as (m, 3) arrays, as cv2.calibrateCamera does.
    covariance: (p, p) covariance of the estimated parameters, named by `parameter_names`.
    iterations, status: of the LM refinement. initial_K, initial_dist: the closed-form start.
    """

    K: Array
    dist: Array
    rms: float
    per_view_rms: Array
    std_intrinsics: dict[str, float]
    poses: tuple[Pose, ...]
    iterations: int
    status: str
    image_size: tuple[int, int]
    distortion: str
    skew: bool
    parameter_names: tuple[str, ...]
    covariance: Array = field(repr=False)
    initial_K: Array = field(repr=False)
    initial_dist: Array = field(repr=False)

    @property
    def rvecs(self) -> Array:
        """Rotation vectors of the view poses, (m, 3), radians."""
        return matrix_to_rotvec(np.stack([p.R for p in self.poses]))

    @property
    def tvecs(self) -> Array:
        """Translations of the view poses, (m, 3), pattern length unit."""
        return np.stack([p.t for p in self.poses])


def _v_rows(H: Array, i: int, j: int) -> Array:
    """Return v_ij (m, 6) of Zhang's eq. (7) for H (m, 3, 3): h_i^T B h_j = v_ij^T b."""
    hi, hj = H[:, :, i], H[:, :, j]
    return np.stack(
        [
            hi[:, 0] * hj[:, 0],
            hi[:, 0] * hj[:, 1] + hi[:, 1] * hj[:, 0],
            hi[:, 1] * hj[:, 1],
            hi[:, 2] * hj[:, 0] + hi[:, 0] * hj[:, 2],
            hi[:, 2] * hj[:, 1] + hi[:, 1] * hj[:, 2],
            hi[:, 2] * hj[:, 2],
        ],
        -1,
    )


def intrinsics_from_homographies(
    homographies: ArrayLike, image_size: tuple[int, int], *, skew: bool = True
) -> Array:
    """Return K (3, 3) from world-plane homographies (m, 3, 3) by Zhang's closed form.

    Solves V b = 0 (eq. 9) in the least-squares sense (right singular vector of the smallest
    singular value) and recovers K from B (appendix B). Pixels are first scaled and centred by
    the image size (w, h) for conditioning, and every homography scaled to unit norm. With
    skew=False, B12 = 0 is imposed exactly. Needs m >= 3 (m >= 2 without skew). Raises
    NotEnoughPoints for too few views and DegenerateConfiguration when the views do not fix B
    (all planes parallel to each other, e.g. all fronto-parallel) or B is not positive definite.
    """
    Hs = np.asarray(homographies, dtype=np.float64)
    m = Hs.shape[0]
    need = 3 if skew else 2
    if m < need:
        raise NotEnoughPoints(
            f"{m} views given; Zhang's method needs at least {need} views "
            f"({'with' if skew else 'without'} skew)"
        )
    w, h = float(image_size[0]), float(image_size[1])
    s = 0.5 * (w + h)
    T = np.array([[1.0 / s, 0.0, -0.5 * w / s], [0.0, 1.0 / s, -0.5 * h / s], [0.0, 0.0, 1.0]])
    Hn = T @ Hs
    Hn /= np.linalg.norm(Hn, axis=(1, 2))[:, None, None]
    V = np.concatenate([_v_rows(Hn, 0, 1), _v_rows(Hn, 0, 0) - _v_rows(Hn, 1, 1)], 0)
    cols = [0, 1, 2, 3, 4, 5] if skew else [0, 2, 3, 4, 5]
    _, sv, vt = np.linalg.svd(V[:, cols])
    # A unique b needs rank len(cols) - 1 (2 views without skew give exactly that: 4 x 5).
    sv = np.concatenate([sv, np.zeros(len(cols) - len(sv))])
    if sv[-2] <= _NULLSPACE_TOL * sv[0]:
        raise DegenerateConfiguration(
            "the views do not determine the intrinsics: the pattern planes are parallel to each "
            "other (e.g. all fronto-parallel) or too few distinct orientations; tilt the pattern "
            "differently in each view"
        )
    b = np.zeros(6)
    b[cols] = vt[-1]
    if b[0] < 0:
        b = -b
    B11, B12, B22, B13, B23, B33 = b
    den = B11 * B22 - B12 * B12
    if B11 <= 0 or den <= 0:
        raise DegenerateConfiguration(
            "the closed-form B = K^-T K^-1 is not positive definite; the views are nearly "
            "parallel or the correspondences are wrong"
        )
    v0 = (B12 * B13 - B11 * B23) / den
    lam = B33 - (B13 * B13 + v0 * (B12 * B13 - B11 * B23)) / B11
    if lam <= 0:
        raise DegenerateConfiguration(
            "the closed-form B = K^-T K^-1 is not positive definite; the views are nearly "
            "parallel or the correspondences are wrong"
        )
    alpha = np.sqrt(lam / B11)
    beta = np.sqrt(lam * B11 / den)
    gamma = -B12 * alpha * alpha * beta / lam
    u0 = gamma * v0 / beta - B13 * alpha * alpha / lam
    Kn = intrinsics_to_matrix([alpha, beta, u0, v0, gamma])
    K = np.linalg.solve(T, Kn)
    return K / K[2, 2]


def _check_views(
    object_points: Sequence[ArrayLike], image_points: Sequence[ArrayLike]
) -> tuple[list[Array], list[Array]]:
    if isinstance(object_points, np.ndarray) and object_points.ndim == 2:
        raise InvalidInput(
            "object_points must be a list of (N_i, 3) or (N_i, 2) arrays, one a view"
        )
    if isinstance(image_points, np.ndarray) and image_points.ndim == 2:
        raise InvalidInput("image_points must be a list of (N_i, 2) arrays, one a view")
    if len(object_points) != len(image_points):
        raise InvalidInput(
            f"object_points has {len(object_points)} views but image_points {len(image_points)}"
        )
    obj, img = [], []
    for j, (o, i) in enumerate(zip(object_points, image_points, strict=True)):
        xy = plane_points(o, f"object_points[{j}]")
        uv = np.asarray(i, dtype=np.float64)
        if uv.ndim == 3 and uv.shape[1] == 1:  # OpenCV's (N, 1, 2)
            uv = uv[:, 0]
        uv = as_points(uv, 2, f"image_points[{j}]", min_count=4)
        if len(xy) != len(uv):
            raise InvalidInput(
                f"view {j}: {len(xy)} object points but {len(uv)} image points; they must pair up"
            )
        obj.append(xy)
        img.append(uv)
    return obj, img


def _radial_init(X: Array, uv: Array, mask: Array, K: Array, poses: Pose, n_radial: int) -> Array:
    """Return (k1[, k2]) by Zhang's linear least squares, eq. (13), on all points."""
    rvec = matrix_to_rotvec(poses.R)
    pr = project_points(X, rvec, poses.t, K)
    Xc = np.einsum("mij,mnj->mni", poses.R, X) + poses.t[:, None, :]
    x = Xc[..., 0] / Xc[..., 2]
    y = Xc[..., 1] / Xc[..., 2]
    r2 = (x * x + y * y)[mask]
    du = (pr.points[..., 0] - K[0, 2])[mask]
    dv = (pr.points[..., 1] - K[1, 2])[mask]
    rows = [np.concatenate([du * r2**k, dv * r2**k]) for k in range(1, n_radial + 1)]
    D = np.stack(rows, -1)
    d = np.concatenate(
        [(uv[..., 0] - pr.points[..., 0])[mask], (uv[..., 1] - pr.points[..., 1])[mask]]
    )
    return np.linalg.lstsq(D, d, rcond=None)[0]


def calibrate_camera(
    object_points: Sequence[ArrayLike],
    image_points: Sequence[ArrayLike],
    image_size: tuple[int, int],
    *,
    skew: bool = False,
    distortion: str = "k1k2p1p2",
    max_iterations: int = 100,
    ftol: float = 1e-14,
    initial_K: ArrayLike | None = None,
) -> CameraCalibration:
    """Return the calibration of a camera from m views of a planar pattern (Zhang 2000).

    object_points: m arrays (N_j, 3) with Z = 0, or (N_j, 2), pattern coordinates in any length
    unit (the poses' translations come out in it); image_points: m arrays (N_j, 2) (or OpenCV's
    (N_j, 1, 2)) of the same points in pixels; image_size: (width, height) pixels, used to
    condition the closed form. skew: estimate the skew K[0, 1] (else 0, as OpenCV). distortion:
    one of "none", "k1", "k1k2", "k1k2p1p2", "k1k2p1p2k3" (OpenCV's model; the others are 0).

    Minimises the total squared reprojection error sum_j sum_i ||m_ij - m(K, dist, R_j, t_j,
    M_ij)||^2 (Zhang eq. 14, with OpenCV's distortion) over the intrinsics, distortion and all
    poses, starting from the closed form (module docstring). With the same model this is the
    optimum cv2.calibrateCamera finds. Needs >= 3 views (>= 2 when skew=False), >= 4 points per
    view and more residuals than parameters. Raises NotEnoughPoints, InvalidInput,
    DegenerateConfiguration (views that do not fix the intrinsics), ConvergenceError.
    `max_iterations` and `ftol` tune the refinement: the LM stops when an accepted step lowers
    the cost by less than `ftol` relative (1e-14: past OpenCV's own stopping point, so both
    report the same optimum). `initial_K` (3, 3) replaces the closed form's K as the starting
    point (for views whose strong lens distortion, which the closed form ignores, leaves
    B = K^-T K^-1 indefinite; a nominal K is enough).
    """
    if distortion not in DISTORTION_MODELS:
        raise InvalidInput(
            f"unknown distortion model {distortion!r}; use one of {', '.join(DISTORTION_MODELS)}"
        )
    try:
        w, h = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise InvalidInput(f"image_size must be (width, height), got {image_size!r}") from None
    if w <= 0 or h <= 0:
        raise InvalidInput(f"image_size must be positive (width, height), got {image_size!r}")
    obj, img = _check_views(object_points, image_points)
    m = len(obj)
    need = 3 if skew else 2
    if m < need:
        raise NotEnoughPoints(
            f"{m} views given; calibration needs at least {need} views of the pattern "
            f"({'with' if skew else 'without'} skew)"
        )
    dist_idx = DISTORTION_MODELS[distortion]
    intr_idx = (0, 1, 2, 3, 4) if skew else (0, 1, 2, 3)
    free = [*intr_idx, *(5 + i for i in dist_idx)]
    p = len(free)
    counts = np.array([len(o) for o in obj])
    n_total = int(counts.sum())
    if 2 * n_total <= p + 6 * m:
        raise NotEnoughPoints(
            f"{n_total} points give {2 * n_total} residuals for {p + 6 * m} unknowns; "
            "add views or points"
        )

    # Pad every view to N_max points by repeating its first point; the mask zeroes them.
    n_max = int(counts.max())
    X = np.zeros((m, n_max, 3))
    uv = np.zeros((m, n_max, 2))
    mask = np.zeros((m, n_max), bool)
    for j in range(m):
        n = counts[j]
        X[j, :, :2] = obj[j][0]
        X[j, :n, :2] = obj[j]
        uv[j] = img[j][0]
        uv[j, :n] = img[j]
        mask[j, :n] = True

    Hs = np.empty((m, 3, 3))
    for j in range(m):
        try:
            Hs[j] = dlt_homography(obj[j], img[j])
        except DegenerateConfiguration as exc:
            raise DegenerateConfiguration(f"view {j}: {exc}") from None
    if initial_K is None:
        K0 = intrinsics_from_homographies(Hs, (w, h), skew=skew)
    else:
        K0 = np.asarray(initial_K, dtype=np.float64)
        if K0.shape != (3, 3) or not np.all(np.isfinite(K0)) or K0[0, 0] <= 0 or K0[1, 1] <= 0:
            raise InvalidInput(f"initial_K must be a finite (3, 3) camera matrix, got {K0}")
    poses0 = pose_from_homography(Hs, K0, X[..., :2])
    dist0 = np.zeros(5)
    n_radial = min(2, len(dist_idx))
    if n_radial:
        dist0[:n_radial] = _radial_init(X, uv, mask, K0, poses0, n_radial)

    full0 = np.array([K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], K0[0, 1], *dist0])
    if not skew:
        full0[4] = 0.0
    sel = np.zeros((10, p))
    sel[free, np.arange(p)] = 1.0
    base = full0.copy()
    base[free] = 0.0
    problem = ReprojectionProblem(X, uv, mask, base, sel)
    x_local0 = np.concatenate([matrix_to_rotvec(poses0.R), poses0.t], 1)
    sol = solve_sparse_lm(
        problem,
        full0[free],
        x_local0,
        max_iterations=max_iterations,
        ftol=ftol,
        n_residuals=2 * n_total,
    )
    full = problem.full(sol.x_global)
    res = problem.residuals(sol.x_global, sol.x_local).reshape(m, n_max, 2)
    sq = np.sum(res * res, axis=(1, 2))
    cov = sol.global_covariance()
    std = dict.fromkeys(PARAMETER_NAMES, 0.0)
    for k, i in enumerate(free):
        std[PARAMETER_NAMES[i]] = float(np.sqrt(max(cov[k, k], 0.0)))
    R = rotvec_to_matrix(sol.x_local[:, :3])
    return CameraCalibration(
        K=intrinsics_to_matrix(full[:5]),
        dist=full[5:].copy(),
        rms=float(np.sqrt(sq.sum() / n_total)),
        per_view_rms=np.sqrt(sq / counts),
        std_intrinsics=std,
        poses=tuple(Pose(R=R[j], t=sol.x_local[j, 3:].copy()) for j in range(m)),
        iterations=sol.iterations,
        status=sol.status,
        image_size=(w, h),
        distortion=distortion,
        skew=skew,
        parameter_names=tuple(PARAMETER_NAMES[i] for i in free),
        covariance=cov,
        initial_K=K0,
        initial_dist=dist0,
    )
