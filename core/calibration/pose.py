"""Pose of a known plane from one image and known intrinsics (Zhang 2000, sec. 3.1; H&Z 8.8).

A world-plane homography H ~ K [r1 r2 t] maps plane coordinates (X, Y, 1) (Z = 0) to pixels.
With K known, [r1 r2 t] = lambda K^-1 H, lambda = 1 / ||K^-1 h1||, the sign chosen so that the
plane lies in front of the camera; r3 = r1 x r2 and the nearest rotation by SVD (Zhang 2000,
appendix C). The closed form then seeds a Levenberg-Marquardt refinement of the reprojection
error over the six pose parameters (rotation vector, translation).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_matrix, as_points
from core.errors import DegenerateConfiguration, InvalidInput
from core.geometry.camera import Pose, ReprojectionProblem, as_distortion, undistort_points
from core.geometry.rotations import matrix_to_rotvec, nearest_rotation, rotvec_to_matrix
from core.homography.dlt import dlt_homography
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]

# Out-of-plane coordinates above this fraction of the pattern's extent are not "on Z = 0".
_PLANAR_TOL = 1e-9


def plane_points(points: ArrayLike, name: str, min_count: int = 4) -> Array:
    """Return plane points as (N, 2) (X, Y) from (N, 2) or (N, 3) input with Z = 0.

    Raises InvalidInput for wrong shapes, non-finite values or Z != 0, NotEnoughPoints when
    fewer than `min_count` points are given.
    """
    a = np.asarray(points)
    if a.ndim == 2 and a.shape[1] == 3:
        p = as_points(a, 3, name, min_count)
        extent = float(np.max(np.abs(p[:, :2]), initial=0.0))
        if np.max(np.abs(p[:, 2]), initial=0.0) > _PLANAR_TOL * max(extent, 1e-300):
            raise InvalidInput(
                f"{name} must lie on the plane Z = 0 (a planar pattern); give (X, Y, 0) or (X, Y)"
            )
        return p[:, :2].copy()
    return as_points(a, 2, name, min_count)


def pose_from_homography(
    H: ArrayLike, K: ArrayLike, object_points: ArrayLike | None = None
) -> Pose:
    """Return the plane-to-camera pose (R (..., 3, 3), t (..., 3)) of world-plane homographies.

    H: (..., 3, 3), mapping plane (X, Y, 1) to pixels (undistorted); K: (3, 3). Closed form of
    Zhang 2000, eq. (3)-(4): lambda = 1 / ||K^-1 h1||, r1 = lambda K^-1 h1, r2 = lambda K^-1 h2,
    r3 = r1 x r2, t = lambda K^-1 h3, then R = nearest rotation of [r1 r2 r3] (appendix C).
    The sign of lambda puts the plane in front of the camera: positive mean depth of
    `object_points` ((N, 2), or (..., N, 2) matching H's batch) when given, else t_z > 0.
    t is in the plane's length unit.
    """
    Hm = np.asarray(H, dtype=np.float64)
    Ki = np.linalg.inv(np.asarray(K, dtype=np.float64))
    A = Ki @ Hm
    lam = 1.0 / np.linalg.norm(A[..., :, 0], axis=-1)
    if object_points is None:
        depth = A[..., 2, 2]
    else:
        xy = np.asarray(object_points, dtype=np.float64)
        # The depth of plane point (X, Y) is lambda (a31 X + a32 Y + a33).
        depth = np.mean(A[..., 2, 0:1] * xy[:, 0] + A[..., 2, 1:2] * xy[:, 1], -1) + A[..., 2, 2]
    lam = np.where(depth < 0, -lam, lam)
    A = A * lam[..., None, None]
    r1, r2 = A[..., :, 0], A[..., :, 1]
    M = np.stack([r1, r2, np.cross(r1, r2)], -1)
    return Pose(R=nearest_rotation(M), t=A[..., :, 2].copy())


@dataclass(frozen=True)
class PoseEstimate:
    """Pose of a plane (plane-to-camera, Xc = R X + t) from one view, with its uncertainty.

    R: (3, 3); t: (3,) in the plane's length unit; `rvec` (3,) the rotation vector of R.
    `rms`: root mean square 2D reprojection error per point (pixels), sqrt(sum ||e_i||^2 / N),
    as cv2.calibrateCamera reports it. `covariance`: (6, 6) covariance of (rvec, t), from the
    Gauss-Newton information scaled by the residual variance (or sigma^2 when given).
    `residuals`: (N, 2) projected minus observed pixels. `iterations`: LM iterations (0 when
    not refined).
    """

    R: Array
    t: Array
    rms: float
    covariance: Array = field(repr=False)
    residuals: Array = field(repr=False)
    iterations: int

    @property
    def rvec(self) -> Array:
        """Rotation vector (3,) of R (axis times angle, radians)."""
        return matrix_to_rotvec(self.R)

    @property
    def pose(self) -> Pose:
        """The pose as a `Pose`."""
        return Pose(R=self.R, t=self.t)


def estimate_plane_pose(
    object_points: ArrayLike,
    image_points: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike | None = None,
    *,
    refine: bool = True,
    sigma: float | None = None,
    max_iterations: int = 50,
) -> PoseEstimate:
    """Return the pose of a plane from N >= 4 points seen in one image with known intrinsics.

    object_points: (N, 2) or (N, 3) with Z = 0, plane coordinates (any length unit);
    image_points: (N, 2) pixels; K: (3, 3); dist: known OpenCV distortion (k1, k2, p1, p2, k3),
    held fixed. Initialisation: the normalised DLT homography of the undistorted pixels
    (H&Z alg. 4.2) and `pose_from_homography`. With `refine` (default) the reprojection error
    sum_i ||x_i - pi(K, dist, R, t; X_i)||^2 is minimised over (rvec, t) by the sparse LM
    (a maximum-likelihood estimate under i.i.d. Gaussian pixel noise). `sigma` (pixels), when
    known, scales the covariance instead of the residual variance estimate.
    Raises NotEnoughPoints, InvalidInput, DegenerateConfiguration (collinear points; plane seen
    edge-on).
    """
    xy = plane_points(object_points, "object_points")
    uv = as_points(image_points, 2, "image_points", min_count=4)
    if len(xy) != len(uv):
        raise InvalidInput(
            f"object_points and image_points differ in length: {len(xy)} and {len(uv)}"
        )
    Km = as_matrix(K, (3, 3), "K")
    if Km[0, 0] <= 0 or Km[1, 1] <= 0 or Km[1, 0] != 0 or Km[2, 0] != 0 or Km[2, 1] != 0:
        raise InvalidInput("K must be upper triangular with positive focal lengths")
    d = as_distortion(dist)
    ideal = undistort_points(uv, Km, d, to_pixels=True) if np.any(d) else uv
    H = dlt_homography(xy, ideal)
    pose = pose_from_homography(H, Km, xy)
    x_local = np.concatenate([matrix_to_rotvec(pose.R), pose.t])[None, :]
    n = len(xy)
    X3 = np.concatenate([xy, np.zeros((n, 1))], 1)[None]
    intr = np.array([Km[0, 0], Km[1, 1], Km[0, 2], Km[1, 2], Km[0, 1]])
    problem = ReprojectionProblem(
        X3, uv[None], np.ones((1, n), bool), np.concatenate([intr, d]), np.zeros((10, 0))
    )
    g = np.zeros(0)
    iterations = 0
    if refine:
        sol = solve_sparse_lm(problem, g, x_local, max_iterations=max_iterations, ftol=1e-14)
        x_local = sol.x_local
        iterations = sol.iterations
    res, _, jl = problem.jacobians(g, x_local)
    depth = (rotvec_to_matrix(x_local[0, :3]) @ X3[0].T)[2] + x_local[0, 5]
    if np.any(depth <= 0):
        raise DegenerateConfiguration(
            "the refined pose puts pattern points behind the camera; the plane is seen nearly "
            "edge-on or the correspondences are wrong"
        )
    info = jl[0].T @ jl[0]
    sse = float(np.sum(res * res))
    s2 = sigma**2 if sigma is not None else (sse / (2 * n - 6) if n > 3 else float("nan"))
    if np.linalg.cond(info) > 1e14:
        raise DegenerateConfiguration(
            "the pose is not determined by these points (information matrix singular)"
        )
    cov = s2 * np.linalg.inv(info)
    return PoseEstimate(
        R=rotvec_to_matrix(x_local[0, :3]),
        t=x_local[0, 3:].copy(),
        rms=float(np.sqrt(sse / n)),
        covariance=cov,
        residuals=res.reshape(n, 2),
        iterations=iterations,
    )
