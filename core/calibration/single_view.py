"""Focal length(s) from a single view of a plane, with the principal point known.

One world-plane homography H ~ K [r1 r2 t] gives two constraints on B = K^-T K^-1 (Zhang 2000,
eq. 3-4): h1^T B h2 = 0 and h1^T B h1 = h2^T B h2. With the principal point (cx, cy) known and
zero skew, translating it to the origin, H' = T H, leaves K' = diag(fx, fy, 1) and
B' = diag(a, b, 1), a = 1/fx^2, b = 1/fy^2, so both constraints are linear in (a, b):

    h11 h12 a + h21 h22 b = -h31 h32
    (h11^2 - h12^2) a + (h21^2 - h22^2) b = -(h31^2 - h32^2)

(a) unit aspect ratio (fx = fy = f): a = b, solved by least squares from both equations;
(b) fx and fy: the 2 x 2 system. (Zhang 2000, sec. 3.1, remark on one view; H&Z ex. 8.8.)
Both need the plane tilted: a fronto-parallel view (r31 = r32 = 0) makes every coefficient
vanish, and a tilt about one image axis only leaves fx or fy undetermined in case (b).
The closed form then seeds a maximum-likelihood refinement of the focal length(s) and the pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_matrix, as_points
from core.calibration.pose import plane_points, pose_from_homography
from core.errors import DegenerateConfiguration, InvalidInput
from core.geometry.camera import (
    Pose,
    ReprojectionProblem,
    as_distortion,
    intrinsics_to_matrix,
    undistort_points,
)
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix
from core.homography.dlt import dlt_homography
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]

# The constraint coefficients scale with sin^2 of the plane's tilt; below this (relative to the
# homography's scale) the view is treated as fronto-parallel: a tilt under ~0.06 degrees.
_TILT_TOL = 1e-6


@dataclass(frozen=True)
class SingleViewCalibration:
    """Intrinsics (principal point given, zero skew) and pose from one view of a plane.

    K: (3, 3) pixels; `pose`: plane-to-camera (Xc = R X + t, t in the pattern's length unit);
    rms: sqrt(sum ||e_i||^2 / N) pixels (0 when noise-free); `focal_std`: standard deviations
    of (fx, fy) in pixels from the Gauss-Newton covariance (equal when fx = fy is imposed);
    `initial_K`: the closed form before refinement; `unit_aspect`: whether fx = fy was imposed.
    """

    K: Array
    pose: Pose
    rms: float
    focal_std: tuple[float, float]
    unit_aspect: bool
    iterations: int
    initial_K: Array = field(repr=False)


def focal_from_homography(
    H: ArrayLike, principal_point: ArrayLike, *, unit_aspect: bool = True
) -> tuple[float, float]:
    """Return (fx, fy) in pixels from one world-plane homography H (3, 3) and a known
    principal point (cx, cy), zero skew.

    Solves the two constraints of the module docstring: by least squares for a = 1/f^2 when
    `unit_aspect` (then fx = fy), else the 2 x 2 system for (1/fx^2, 1/fy^2). The homography is
    scaled first so that the equations' coefficients are commensurate. Raises
    DegenerateConfiguration when the view is fronto-parallel (the constraints vanish), tilted
    about one image axis only (case b), or the solution is not a real focal length.
    """
    Hm = as_matrix(H, (3, 3), "H")
    c = as_points(np.asarray(principal_point, dtype=np.float64).reshape(1, 2), 2, "principal_point")
    T = np.array([[1.0, 0.0, -c[0, 0]], [0.0, 1.0, -c[0, 1]], [0.0, 0.0, 1.0]])
    Hp = T @ Hm
    # Pass 1 scales pixels by a guess of f (the image size, ~2 |c|); pass 2 by that estimate, so
    # that H'' ~ [r1 r2 t] and the coefficients equal -r31 r32 and r32^2 - r31^2: O(sin^2 tilt).
    # The coefficients stay O(sin^2 tilt) for any s within a few orders of magnitude of f, so
    # the degeneracy test is made in pass 1, before a possibly meaningless estimate rescales H.
    s = 2.0 * max(abs(float(c[0, 0])), abs(float(c[0, 1])), 1.0)
    ab, sv, tilt = _solve_inverse_squares(Hp, s, unit_aspect)
    if sv[0] <= _TILT_TOL or tilt <= _TILT_TOL:
        raise DegenerateConfiguration(
            "the view is fronto-parallel (or nearly): the plane's tilt gives no constraint on "
            "the focal length; tilt the plane away from the image plane"
        )
    if sv[-1] <= _TILT_TOL:
        raise DegenerateConfiguration(
            "the plane is tilted about one image axis only, so fx and fy are not both "
            "determined; use unit_aspect=True or a view tilted about both axes"
        )
    if np.all(ab > 0) and np.all(np.isfinite(ab)):
        s = float(np.sqrt(np.prod(s / np.sqrt(ab))))
        ab, sv, _ = _solve_inverse_squares(Hp, s, unit_aspect)
    if not np.all(ab > 0) or not np.all(np.isfinite(ab)):
        raise DegenerateConfiguration(
            "the single-view constraints give no real focal length (1/f^2 <= 0); the view is "
            "nearly fronto-parallel or the principal point is wrong"
        )
    f = s / np.sqrt(ab)
    return float(f[0]), float(f[1])


def _solve_inverse_squares(Hp: Array, s: float, unit_aspect: bool) -> tuple[Array, Array, float]:
    """Return (a, b) = ((s / fx)^2, (s / fy)^2), the singular values of the constraint matrix
    and the norm of its right-hand side (both O(sin^2 tilt)), for H' (principal point at the
    origin) with pixels scaled by 1 / s."""
    h = np.diag([1.0 / s, 1.0 / s, 1.0]) @ Hp
    h = h / np.sqrt(0.5 * float(np.sum(h[:, :2] ** 2)))
    A = np.array(
        [
            [h[0, 0] * h[0, 1], h[1, 0] * h[1, 1]],
            [h[0, 0] ** 2 - h[0, 1] ** 2, h[1, 0] ** 2 - h[1, 1] ** 2],
        ]
    )
    rhs = -np.array([h[2, 0] * h[2, 1], h[2, 0] ** 2 - h[2, 1] ** 2])
    tilt = float(np.linalg.norm(rhs))
    if unit_aspect:
        col = A.sum(axis=1)
        nrm = float(col @ col)
        a = float(col @ rhs) / nrm if nrm > 0 else np.nan
        return np.array([a, a]), np.array([np.sqrt(nrm)]), tilt
    sv = np.linalg.svd(A, compute_uv=False)
    if sv[-1] <= 0:
        return np.array([np.nan, np.nan]), sv, tilt
    return np.linalg.solve(A, rhs), sv, tilt


def calibrate_single_view(
    object_points: ArrayLike,
    image_points: ArrayLike,
    principal_point: ArrayLike,
    *,
    unit_aspect: bool = True,
    dist: ArrayLike | None = None,
    refine: bool = True,
    max_iterations: int = 50,
) -> SingleViewCalibration:
    """Return K and the pose from one view of a plane, with the principal point known.

    object_points: (N, 2) or (N, 3) with Z = 0, N >= 4, pattern units; image_points: (N, 2)
    pixels; principal_point: (cx, cy) pixels; skew is zero. unit_aspect: fx = fy = f (case a)
    or fx, fy free (case b). dist: known distortion (k1, k2, p1, p2, k3), held fixed.
    The closed form (`focal_from_homography` on the DLT homography of undistorted pixels) and
    `pose_from_homography` start a sparse-LM refinement (`refine`) minimising the reprojection
    error sum_i ||x_i - pi(K, dist, R, t; X_i)||^2 over the focal length(s) and the pose.
    Raises NotEnoughPoints, InvalidInput, DegenerateConfiguration (fronto-parallel view).
    """
    xy = plane_points(object_points, "object_points")
    uv = as_points(image_points, 2, "image_points", min_count=4)
    if len(xy) != len(uv):
        raise InvalidInput(
            f"object_points and image_points differ in length: {len(xy)} and {len(uv)}"
        )
    c = as_points(np.asarray(principal_point, dtype=np.float64).reshape(1, 2), 2, "principal_point")
    cx, cy = float(c[0, 0]), float(c[0, 1])
    d = as_distortion(dist)
    n = len(xy)

    def k_of(fx: float, fy: float) -> Array:
        return intrinsics_to_matrix([fx, fy, cx, cy, 0.0])

    if np.any(d):
        # Undistortion needs a focal length; iterate the closed form on the refined pixels.
        f0 = focal_from_homography(dlt_homography(xy, uv), (cx, cy), unit_aspect=unit_aspect)
        for _ in range(3):
            ideal = undistort_points(uv, k_of(*f0), d, to_pixels=True)
            f0 = focal_from_homography(dlt_homography(xy, ideal), (cx, cy), unit_aspect=unit_aspect)
        H = dlt_homography(xy, undistort_points(uv, k_of(*f0), d, to_pixels=True))
    else:
        H = dlt_homography(xy, uv)
        f0 = focal_from_homography(H, (cx, cy), unit_aspect=unit_aspect)
    K0 = k_of(*f0)
    pose0 = pose_from_homography(H, K0, xy)

    sel = np.zeros((10, 1 if unit_aspect else 2))
    if unit_aspect:
        sel[0, 0] = sel[1, 0] = 1.0
        g0 = np.array([0.5 * (f0[0] + f0[1])])
    else:
        sel[0, 0] = sel[1, 1] = 1.0
        g0 = np.array(f0)
    base = np.array([0.0, 0.0, cx, cy, 0.0, *d])
    X3 = np.concatenate([xy, np.zeros((n, 1))], 1)[None]
    problem = ReprojectionProblem(X3, uv[None], np.ones((1, n), bool), base, sel)
    loc0 = np.concatenate([matrix_to_rotvec(pose0.R), pose0.t])[None]
    g, loc, iterations = g0, loc0, 0
    if refine:
        sol = solve_sparse_lm(problem, g0, loc0, max_iterations=max_iterations, ftol=1e-14)
        g, loc, iterations = sol.x_global, sol.x_local, sol.iterations
    res, jg, jl = problem.jacobians(g, loc)
    J = np.concatenate([jg[0], jl[0]], 1)
    sse = float(np.sum(res * res))
    dof = 2 * n - J.shape[1]
    s2 = sse / dof if dof > 0 else float("nan")
    cov = s2 * np.linalg.pinv(J.T @ J)
    std = np.sqrt(np.maximum(np.diag(cov)[: len(g)], 0.0))
    full = problem.full(g)
    return SingleViewCalibration(
        K=intrinsics_to_matrix(full[:5]),
        pose=Pose(R=rotvec_to_matrix(loc[0, :3]), t=loc[0, 3:].copy()),
        rms=float(np.sqrt(sse / n)),
        focal_std=(float(std[0]), float(std[0] if unit_aspect else std[1])),
        unit_aspect=unit_aspect,
        iterations=iterations,
        initial_K=K0,
    )
