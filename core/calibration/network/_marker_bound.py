"""The Cramer-Rao bound of the marker calibration: the inverse of its Gauss-Newton information
at the true parameters, as each camera's focal, position and orientation errors, in the start
pose's world frame and in the network's own geometry (floor rigid motion removed)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.calibration.network._intrinsics_prior import IntrinsicsPrior
from core.calibration.network._marker_layout import MarkerLayout, check_detections, marker_places
from core.calibration.network._marker_problem import MarkerProblem, ProblemCamera, chol_whitener
from core.calibration.network._odometry import OdometryPrior
from core.errors import InvalidInput
from core.geometry.camera import left_jacobian_so3
from core.geometry.rotations import matrix_to_rotvec, wrap_angle

Array = NDArray[np.float64]


@dataclass(frozen=True)
class CameraBound:
    """The Cramer-Rao bound of one camera's calibration: standard deviation of the focal length
    (fx + fy) / 2 in percent, root mean square position error (sqrt of the trace of the
    centre's covariance) metres and root mean square orientation error degrees, in the world
    frame the start pose defines; `aligned_position_m`, `aligned_rotation_deg` the same after
    the floor rigid motion that best aligns all the cameras' centres is removed
    (`floor_gauge_projector`: the network's own geometry; NaN with fewer than 2 cameras)."""

    name: str
    focal_pct: float
    position_m: float
    rotation_deg: float
    aligned_position_m: float
    aligned_rotation_deg: float


def centre_rotation_jacobian(R: Array, t: Array) -> Array:
    """Return d (c, phi) / d (rvec, t) (6, 6) of a camera with R_camera_world = exp(rvec) = R
    and t_camera_world = t: c = -R^T t its centre (metres) and phi its orientation error as a
    world-frame rotation vector (R_world_camera_est = exp(phi) R_world_camera). A perturbed
    rotation exp(rvec + d) is exp(J_l d) R (J_l the left Jacobian of SO(3)), so
    d c = -R^T [t]x J_l d - R^T dt and phi = -R^T J_l d."""
    Jl = left_jacobian_so3(matrix_to_rotvec(R))
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    F = np.zeros((6, 6))
    F[:3, :3] = -R.T @ tx @ Jl
    F[:3, 3:] = -R.T
    F[3:, :3] = -R.T @ Jl
    return F


def floor_gauge_projector(centres: ArrayLike) -> Array:
    """Return T (6 C, 6 C) that removes from per-camera errors (centre (3), world rotation
    vector (3), camera by camera) the floor rigid motion (x, y, yaw) that best aligns the
    centres (least squares over their x, y): the errors of the network's own geometry, free of
    where its world frame was put. First order; needs C >= 2 cameras (a 2D Procrustes fit)."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    C = len(c)
    G = np.zeros((6 * C, 3))
    B = np.zeros((2 * C, 6 * C))
    for k in range(C):
        G[6 * k : 6 * k + 3] = [[1.0, 0.0, -c[k, 1]], [0.0, 1.0, c[k, 0]], [0.0, 0.0, 0.0]]
        G[6 * k + 5, 2] = 1.0
        B[2 * k, 6 * k] = B[2 * k + 1, 6 * k + 1] = 1.0
    return np.eye(6 * C) - G @ np.linalg.pinv(B @ G) @ B


def marker_network_bound(
    names: Sequence[str],
    intrinsics: Sequence[IntrinsicsPrior],
    true_K: ArrayLike,
    true_dist: ArrayLike,
    true_R: ArrayLike,
    true_t: ArrayLike,
    true_poses: ArrayLike,
    visible: ArrayLike,
    odometry: OdometryPrior,
    height: ArrayLike,
    *,
    offset: ArrayLike = (0.0, 0.0),
    pixel_cov: ArrayLike | None = None,
    pixel_sigma: float = 0.5,
) -> tuple[CameraBound, ...]:
    """Return the Cramer-Rao bound of each camera's calibration by `calibrate_network_marker`.

    The inverse of the problem's Gauss-Newton information (unit-variance whitened residuals)
    at the true parameters: true_K (C, 3, 3), true_dist (C, 5), true_R (C, 3, 3) and true_t
    (C, 3) (R_camera_world, t_camera_world), true_poses (M, 3) the robot's true stops; the
    priors (intrinsics' and odometry increments' covariances) and the detections' visibility
    and covariance as the calibration has them. For scoring and planning (which drive length
    and pixel noise reach a target): it needs the truth. Several markers as in
    `calibrate_network_marker` (`height` (K,), `offset` (K, 2), visible (C, M, K)).
    """
    C = len(names)
    Ks = np.asarray(true_K, dtype=np.float64).reshape(C, 3, 3)
    ds = np.asarray(true_dist, dtype=np.float64).reshape(C, 5)
    Rs = np.asarray(true_R, dtype=np.float64).reshape(C, 3, 3)
    ts = np.asarray(true_t, dtype=np.float64).reshape(C, 3)
    P = np.asarray(true_poses, dtype=np.float64).reshape(-1, 3)
    M = len(odometry.increments)
    if len(P) != M:
        raise InvalidInput(f"true_poses must be (M, 3) with M = {M}; got {P.shape}")
    heights, offsets, radii = marker_places(height, offset, 0.0)
    n_markers = len(heights)
    shape = (C, M, 2) if n_markers == 1 else (C, M, n_markers, 2)
    uv, vis, cov = check_detections(
        names, intrinsics, np.zeros(shape), visible, odometry, pixel_cov, pixel_sigma, n_markers
    )
    # Linearise at the truth: increments that compose to the true poses, priors centred on it.
    prev = np.vstack([odometry.start, P[:-1]])
    rel = P[:, :2] - prev[:, :2]
    cp, sp = np.cos(prev[:, 2]), np.sin(prev[:, 2])
    inc = np.column_stack(
        [
            cp * rel[:, 0] + sp * rel[:, 1],
            -sp * rel[:, 0] + cp * rel[:, 1],
            wrap_angle(P[:, 2] - prev[:, 2]),
        ]
    )
    odo = OdometryPrior(odometry.start, inc, odometry.cov)
    cams = []
    for k in range(C):
        pr = intrinsics[k]
        truth = IntrinsicsPrior(Ks[k], ds[k], pr.names, pr.cov)
        cams.append(ProblemCamera(names[k], k, truth, matrix_to_rotvec(Rs[k]), ts[k], vis[k]))
    problem = MarkerProblem(
        cams, uv, chol_whitener(cov), vis, odo, MarkerLayout.of(M, offsets, heights, radii)
    )
    _, J, _ = problem.jacobians(problem.x0(), np.zeros((1, 0)))
    info = J[0].T @ J[0]
    cov_all = np.linalg.inv(info)
    F = np.zeros((6 * C, problem.n))
    focal_rows = np.zeros((C, problem.n))
    for k in range(C):
        end = problem.start[k + 1]
        F[6 * k : 6 * k + 6, end - 6 : end] = centre_rotation_jacobian(Rs[k], ts[k])
        names_k = cams[k].prior.names
        f = 0.5 * (Ks[k, 0, 0] + Ks[k, 1, 1])
        for n in ("fx", "fy"):
            if n in names_k:
                focal_rows[k, problem.start[k] + names_k.index(n)] = 0.5 * 100 / f
    Y = F @ cov_all @ F.T
    centres = np.einsum("kji,kj->ki", Rs, -ts)
    Ya = np.full_like(Y, np.nan)
    if C >= 2:
        T = floor_gauge_projector(centres)
        Ya = T @ Y @ T.T
    fvar = np.einsum("ki,ij,kj->k", focal_rows, cov_all, focal_rows)

    def rt(a: Array, k: int, i: int) -> float:
        return float(np.sqrt(np.trace(a[6 * k + i : 6 * k + i + 3, 6 * k + i : 6 * k + i + 3])))

    out = []
    for k, name in enumerate(names):
        out.append(
            CameraBound(
                name=name,
                focal_pct=float(np.sqrt(fvar[k])),
                position_m=rt(Y, k, 0),
                rotation_deg=float(np.degrees(rt(Y, k, 3))),
                aligned_position_m=rt(Ya, k, 0),
                aligned_rotation_deg=float(np.degrees(rt(Ya, k, 3))),
            )
        )
    return tuple(out)
