"""The pose of a mark's plane from the ideal pixels of known points on it: the closed form of
their homography refined by Gauss-Newton on the reprojection error (all planes at once), and
the conversion of a pose covariance to one of (rvec, t)."""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from core.calibration.pose import pose_from_homography
from core.errors import DegenerateConfiguration
from core.geometry.rotations import rotvec_to_matrix
from core.homography.dlt import dlt_homography

Array = NDArray[np.float64]


def project_plane(
    obj: Array, R: Array, t: Array, K: Array, jacobian: bool = False
) -> tuple[Array, Array, Array | None]:
    """Return the ideal pixels (F, N, 2) of plane points obj (N, 2) under F poses (R (F, 3, 3),
    t (F, 3)), their depths (F, N) and, with `jacobian`, d pixels / d (left rotation
    perturbation, t) (F, N, 2, 6) (R <- exp([d theta]x) R: d Xc / d theta = -[R X]x)."""
    # (R X, as two products and a sum: einsum's parsing costs more than the arithmetic)
    RX = R[:, None, :, 0] * obj[:, :1] + R[:, None, :, 1] * obj[:, 1:]
    Pc = RX + t[:, None, :]
    z = Pc[..., 2]
    xn = Pc[..., :2] / z[..., None]
    uv = xn @ K[:2, :2].T + K[:2, 2]
    if not jacobian:
        return uv, z, None
    shape = z.shape
    # d normalised / d Pc (F, N, 2, 3), then through K's upper-left block.
    dn = np.zeros((*shape, 2, 3))
    dn[..., 0, 0] = dn[..., 1, 1] = 1.0 / z
    dn[..., :, 2] = -xn / z[..., None]
    du = K[:2, :2] @ dn
    # -[RX]x, (F, N, 3, 3).
    ns = np.zeros((*shape, 3, 3))
    ns[..., 0, 1], ns[..., 0, 2] = RX[..., 2], -RX[..., 1]
    ns[..., 1, 0], ns[..., 1, 2] = -RX[..., 2], RX[..., 0]
    ns[..., 2, 0], ns[..., 2, 1] = RX[..., 1], -RX[..., 0]
    J = np.empty((*shape, 2, 6))
    J[..., :3] = du @ ns
    J[..., 3:] = du
    return uv, z, J


def plane_poses(
    obj: Array, ideal: list[Array], K: Array, iterations: int = 6
) -> list[tuple[Array, Array, float] | None]:
    """Return (R, t, rms px) of planes from their points' ideal pixels (one (N, 2) array per
    plane; None where the points are degenerate): the closed-form pose
    (core.calibration.pose.pose_from_homography) of the first four points' homography, then
    Gauss-Newton on all the points' reprojection error over (rotation, t), all planes at once
    (the estimate_plane_pose criterion, without its general-purpose machinery)."""
    if not ideal:
        return []
    ok = np.ones(len(ideal), bool)
    target = np.array(ideal)
    # The start: the outline's four corners' exact homography (the refinement below makes every
    # corner count); the normalised DLT when there are more and these are degenerate.
    corners = target[:, :4].astype(np.float32)
    src = obj[:4].astype(np.float32)
    Hs = np.array([cv2.getPerspectiveTransform(src, uv) for uv in corners], dtype=np.float64)
    finite = np.isfinite(Hs).all((1, 2))
    Hs[~finite] = 0.0
    for f in (~(finite & (np.abs(np.linalg.det(Hs)) > 1e-12))).nonzero()[0].tolist():
        try:
            Hs[f] = dlt_homography(obj, ideal[f])
        except DegenerateConfiguration:
            ok[f] = False
            Hs[f] = np.eye(3)
    pose = pose_from_homography(Hs, K, obj)
    R, t = np.asarray(pose.R, dtype=np.float64), np.asarray(pose.t, dtype=np.float64)
    for _ in range(iterations):
        uv, _, J = project_plane(obj, R, t, K, jacobian=True)
        assert J is not None
        res = (uv - target).reshape(len(R), -1)
        A = J.reshape(len(R), -1, 6)
        At = np.swapaxes(A, 1, 2)
        N = At @ A
        singular = np.abs(np.linalg.det(N)) < 1e-300
        ok &= ~singular
        N[singular] = np.eye(6)
        step = np.linalg.solve(N, -(At @ res[..., None]))[..., 0]
        R = rotvec_to_matrix(step[:, :3]) @ R
        t = t + step[:, 3:]
        # Converged far below the corners' noise (a 1e-7 relative step moves a 10 cm mark by
        # nanometres).
        scale = np.maximum(1.0, np.linalg.norm(t, axis=1))
        if np.all(np.max(np.abs(step), 1) < 1e-7 * scale):
            break
    uv, z, _ = project_plane(obj, R, t, K)
    ok &= np.all(z > 0, 1)  # else the pose puts the plane behind the camera
    rms = np.sqrt(np.mean(np.sum((uv - target) ** 2, -1), 1))
    return [
        (R[f], t[f], float(rms[f])) if ok[f] and np.isfinite(rms[f]) else None
        for f in range(len(R))
    ]


def rvec_cov(R: Array, cov_theta: Array) -> Array:
    """Convert a covariance of (left rotation perturbation, t) to one of (rvec, t): d rvec =
    J_l(rvec)^-1 d theta, with the closed form J_l^-1 = I - [v]x / 2 + b [v]x^2,
    b = 1 / t^2 - cot(t / 2) / (2 t), t = |v| (Barfoot, "State Estimation for Robotics",
    eq. 7.79; the inverse of core.geometry.camera.left_jacobian_so3)."""
    # (in plain floats: numpy's per-call cost is most of the time on 3 x 3 matrices)
    v0, v1, v2 = cv2.Rodrigues(R)[0].ravel().tolist()
    t = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    b = 1 / 12 + t * t / 720 if t < 1e-3 else 1 / t**2 - 1 / (2 * t * math.tan(t / 2))
    # I - [v]x / 2 + b [v]x^2, with [v]x^2 = v v^T - |v|^2 I.
    s2 = v0 * v0 + v1 * v1 + v2 * v2
    M = np.eye(6)
    M[:3, :3] = [
        [1 + b * (v0 * v0 - s2), 0.5 * v2 + b * v0 * v1, -0.5 * v1 + b * v0 * v2],
        [-0.5 * v2 + b * v1 * v0, 1 + b * (v1 * v1 - s2), 0.5 * v0 + b * v1 * v2],
        [0.5 * v1 + b * v2 * v0, -0.5 * v0 + b * v2 * v1, 1 + b * (v2 * v2 - s2)],
    ]
    return M @ cov_theta @ M.T


def rot_z(psi: float) -> Array:
    """Return the rotation (3, 3) by psi radians about z."""
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
