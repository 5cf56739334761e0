"""Hand-eye calibration of a camera on the end effector: X = T_ee_cam from A_k X = X B_k.

Input as OpenCV's calibrateHandEye takes it: absolute poses T_base_ee_i (the arm's forward
kinematics, "gripper to base") and T_cam_target_i (the calibration target seen by the camera,
"target to camera"), i = 1..n. The target is fixed in the arm's base frame, so
W = T_base_ee_i X T_cam_target_i is the same for every view and each pair i < j gives a motion

    A = T_base_ee_j^-1 T_base_ee_i,   B = T_cam_target_j T_cam_target_i^-1,   A X = X B

(Tsai & Lenz 1989, eq. 11; Park & Martin 1994, eq. 1). Every pair is used, as OpenCV does.
Rotation: R_A R_X = R_X R_B; translation: (R_A - I) t_X = R_X t_B - t_A.

Methods (`method=`):
* "tsai": Tsai & Lenz, IEEE T-RA 5(3), 1989: modified Rodrigues vectors P = 2 sin(theta/2) n,
  skew(P_A + P_B) P' = P_B - P_A by least squares, then the translation by least squares.
* "park": Park & Martin, IEEE T-RA 10(5), 1994: alpha = log R_A, beta = log R_B,
  M = sum beta alpha^T, R_X = (M^T M)^-1/2 M^T; then the translation.
* "daniilidis": Daniilidis, IJRR 18(3), 1999: rotation and translation at once from the
  null space of the stacked dual-quaternion constraints (the SVD's two smallest vectors).
* "andreff": Andreff, Horaud & Espiau, 3DIM 1999, sec. 3: R_X from the homogeneous linear
  system (I (x) R_A - R_B^T (x) I) vec(R_X) = 0 stacked over every motion (no parametrisation
  of the rotation), its null vector projected onto SO(3); then t_X from the stacked linear
  translation equations.
* "two-group": the thesis's two-group method (after Ma, IEEE T-RA 12(1), 1996): the arm makes
  two groups of motions. The first are pure translations of the end effector (R_A = I, so
  R_B = I and A X = X B reduces to t_A = R_X t_B, t_B the target's displacement in the camera
  frame, t_Cj - t_Ci): R_X follows from two or more non-parallel translations alone, in closed
  form as the rotation that best maps the camera's translations onto the end effector's
  (orthogonal Procrustes, Arun, Huang & Blostein, IEEE T-PAMI 9(5), 1987). The second are
  motions that rotate about at least two different axes: with R_X known, (R_A - I) t_X =
  R_X t_B - t_A is linear in t_X. The motions are told apart by the end effector's rotation
  (under 0.5 degrees: the first group); the rotation uses the first group only, so the method
  needs views with pure translations among them (core.sim.eye_in_hand.
  hand_eye_views makes them).

With the target's points and their pixels, X is refined by minimising the reprojection error of
every point in every view over X and the target's pose W in the arm's base frame (12
parameters) with core.optim's sparse LM; the covariance of X is the inverse Gauss-Newton
information scaled by the residual variance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.geometry.camera import as_distortion, project_points
from core.geometry.poses import as_pose, invert_pose
from core.geometry.rotations import (
    matrix_to_quaternion,
    matrix_to_rotvec,
    nearest_rotation,
    rotvec_to_matrix,
    skew,
)
from core.manipulation.errors import DegenerateMotions, TooFewMotions
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]
Method = Literal["tsai", "park", "daniilidis", "andreff", "two-group"]
METHODS: tuple[str, ...] = ("tsai", "park", "daniilidis", "andreff", "two-group")

# Rotations smaller than this (rad) carry no axis; two axes closer than this angle are parallel.
_MIN_ROTATION = math.radians(0.5)
_MIN_AXIS_ANGLE = math.radians(2.0)


@dataclass(frozen=True)
class HandEyeCalibration:
    """The hand-eye transform with its uncertainty and diagnostics.

    X: (4, 4) T_ee_cam. covariance: (6, 6) of a perturbation X exp(w, v), w the rotation (rad,
    camera frame) then v the translation (m, camera frame): first order from the motion
    residuals (linear methods, treating the motions as independent) or the inverse information
    of the reprojection refinement. rotation_std_deg: sqrt(trace) of the rotation block, the
    expected RMS rotation error; translation_std_m: the same for the translation.
    rotation_residuals_deg (K,), translation_residuals_m (K,): per motion (pair i < j in the
    order (0, 1), (0, 2), ..., (n-2, n-1)), the angle of (R_A R_X)^T R_X R_B and the norm of
    (R_A - I) t_X - R_X t_B + t_A. T_base_target: (4, 4) the target's pose in the arm's base
    frame (mean over views, or refined). rms_px, per_view_rms_px, iterations: the refinement's
    (None / 0 without one). linear_method: the method that gave the (initial) estimate.
    """

    X: Array
    method: str
    covariance: Array = field(repr=False)
    rotation_std_deg: float
    translation_std_m: float
    rotation_residuals_deg: Array = field(repr=False)
    translation_residuals_m: Array = field(repr=False)
    T_base_target: Array = field(repr=False)
    refined: bool = False
    rms_px: float | None = None
    per_view_rms_px: Array | None = field(default=None, repr=False)
    iterations: int = 0
    linear_method: str = ""

    @property
    def motions(self) -> int:
        """Number of motions (pairs of views) used."""
        return int(self.rotation_residuals_deg.shape[0])


# --------------------------------------------------------------------------------------------
# Motions and their checks


def _as_pose_list(poses: object, name: str) -> Array:
    try:
        arr = np.asarray(poses, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be a list of 4x4 poses: {exc}") from None
    if arr.ndim != 3:
        raise InvalidInput(f"{name} must be a list of 4x4 poses, got shape {arr.shape}")
    return as_pose(arr, name)


def relative_motions(T_base_ee: Array, T_cam_target: Array) -> tuple[Array, Array]:
    """Return the motions (A (K, 4, 4), B (K, 4, 4)) of every pair i < j of views."""
    n = T_base_ee.shape[0]
    i, j = np.triu_indices(n, 1)
    A = invert_pose(T_base_ee[j]) @ T_base_ee[i]
    B = T_cam_target[j] @ invert_pose(T_cam_target[i])
    return A, B


def check_motions(A: Array) -> None:
    """Raise DegenerateMotions unless the motions' rotations (A (K, 4, 4)) turn by at least
    0.5 degrees about at least two axes more than 2 degrees apart: otherwise the rotation of X
    about the common axis and its translation along it are not observable (Tsai & Lenz 1989,
    sec. IV; Chen 1991)."""
    rv = matrix_to_rotvec(A[:, :3, :3])
    ang = np.linalg.norm(rv, axis=1)
    big = ang >= _MIN_ROTATION
    if np.count_nonzero(big) < 2:
        raise DegenerateMotions(
            f"only {np.count_nonzero(big)} of {len(A)} motions rotate the end effector by more "
            "than 0.5 degrees; rotate the arm between views about at least two different axes"
        )
    axes = rv[big] / ang[big, None]
    cosines = np.abs(axes @ axes.T)
    if float(cosines.min()) > math.cos(_MIN_AXIS_ANGLE):
        raise DegenerateMotions(
            "all the arm's rotations between views are about parallel axes (within 2 degrees): "
            "the hand-eye rotation about that axis and the translation along it are "
            "unobservable; add views that rotate the end effector about a second axis"
        )


# --------------------------------------------------------------------------------------------
# Linear solvers


def _translation(A: Array, B: Array, R: Array) -> Array:
    """Return t_X by least squares on (R_A - I) t_X = R_X t_B - t_A stacked over motions."""
    C = (A[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    d = (B[:, :3, 3] @ R.T - A[:, :3, 3]).reshape(-1)
    t = np.linalg.lstsq(C, d, rcond=None)[0]
    return np.asarray(t, dtype=np.float64)


def _rodrigues_modified(R: Array) -> Array:
    """Return P = 2 sin(theta / 2) n (..., 3) of rotations (Tsai & Lenz 1989, eq. 9)."""
    rv = matrix_to_rotvec(R)
    th = np.linalg.norm(rv, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.where(th > 0, rv / np.where(th > 0, th, 1.0), 0.0)
    out: Array = 2.0 * np.sin(th / 2.0) * n
    return out


def _tsai(A: Array, B: Array) -> Array:
    Pa = _rodrigues_modified(A[:, :3, :3])
    Pb = _rodrigues_modified(B[:, :3, :3])
    S = skew(Pa + Pb).reshape(-1, 3)
    p_prime = np.linalg.lstsq(S, (Pb - Pa).reshape(-1), rcond=None)[0]
    P = 2.0 * p_prime / math.sqrt(1.0 + float(p_prime @ p_prime))
    pp = float(P @ P)
    R = (1.0 - pp / 2.0) * np.eye(3) + 0.5 * (np.outer(P, P) + math.sqrt(4.0 - pp) * skew(P))
    return nearest_rotation(R)


def _park(A: Array, B: Array) -> Array:
    alpha = matrix_to_rotvec(A[:, :3, :3])
    beta = matrix_to_rotvec(B[:, :3, :3])
    M = beta.T @ alpha  # sum beta alpha^T
    w, V = np.linalg.eigh(M.T @ M)
    if float(w.min()) <= 1e-15 * max(float(w.max()), 1e-300):
        raise DegenerateMotions("the motions' rotation axes span less than 3D; add motions")
    inv_sqrt = V @ np.diag(1.0 / np.sqrt(w)) @ V.T
    return nearest_rotation(inv_sqrt @ M.T)


def _qmul(p: Array, q: Array) -> Array:
    """Hamilton product of quaternions (..., 4) = (w, x, y, z)."""
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    v = pw * qv + qw * pv + np.cross(pv, qv)
    return np.concatenate([w, v], axis=-1)


def _dual_quat(T: Array) -> tuple[Array, Array]:
    """Return (q, q') (..., 4) with q' = 0.5 (0, t) q: the dual quaternion of rigid motions."""
    q = matrix_to_quaternion(T[..., :3, :3])[..., [3, 0, 1, 2]]  # (w, x, y, z)
    t = np.concatenate([np.zeros((*T.shape[:-2], 1)), T[..., :3, 3]], axis=-1)
    return q, 0.5 * _qmul(t, q)


def _daniilidis(A: Array, B: Array) -> Array:
    qa, qa_d = _dual_quat(A)
    qb, qb_d = _dual_quat(B)
    K = A.shape[0]
    S = np.zeros((K, 6, 8))
    S[:, :3, 0] = qa[:, 1:] - qb[:, 1:]
    S[:, :3, 1:4] = skew(qa[:, 1:] + qb[:, 1:])
    S[:, 3:, 0] = qa_d[:, 1:] - qb_d[:, 1:]
    S[:, 3:, 1:4] = skew(qa_d[:, 1:] + qb_d[:, 1:])
    S[:, 3:, 4] = qa[:, 1:] - qb[:, 1:]
    S[:, 3:, 5:8] = skew(qa[:, 1:] + qb[:, 1:])
    _, _, vt = np.linalg.svd(S.reshape(-1, 8), full_matrices=False)
    v1, v2 = vt[6], vt[7]
    u1, w1 = v1[:4], v1[4:]
    u2, w2 = v2[:4], v2[4:]
    # lambda1 u1 + lambda2 u2 is a unit quaternion orthogonal to its dual part (Daniilidis
    # 1999, eq. 35-36): a quadratic in s = lambda1 / lambda2.
    a, b, c = u1 @ w1, u1 @ w2 + u2 @ w1, u2 @ w2
    if abs(a) > 1e-15:
        disc = max(b * b - 4 * a * c, 0.0)
        roots = [(-b + math.sqrt(disc)) / (2 * a), (-b - math.sqrt(disc)) / (2 * a)]
        vals = [s * s * (u1 @ u1) + 2 * s * (u1 @ u2) + u2 @ u2 for s in roots]
        k = int(np.argmax(vals))
        s, val = roots[k], vals[k]
        l2 = 1.0 / math.sqrt(val)
        l1 = s * l2
    else:
        # a = 0: lambda2 = 0 root or s = -c / b; the unit-norm condition picks lambda2 = 0.
        l1, l2 = 1.0 / math.sqrt(float(u1 @ u1)), 0.0
    q = l1 * u1 + l2 * u2
    qd = l1 * w1 + l2 * w2
    conj = q * np.array([1.0, -1.0, -1.0, -1.0])
    t = 2.0 * _qmul(qd, conj)[1:]
    w, x, y, z = q / np.linalg.norm(q)
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = t
    return X


def _andreff(A: Array, B: Array) -> Array:
    RA, RB = A[:, :3, :3], B[:, :3, :3]
    eye = np.eye(3)
    # Column-major vec: vec(R_A R) = (I (x) R_A) vec R and vec(R R_B) = (R_B^T (x) I) vec R.
    M = np.einsum("ij,kab->kiajb", eye, RA).reshape(-1, 9, 9) - np.einsum(
        "kba,ij->kaibj", RB, eye
    ).reshape(-1, 9, 9)
    _, s, vt = np.linalg.svd(M.reshape(-1, 9), full_matrices=False)
    if s[-2] <= 1e-9 * s[0]:
        raise DegenerateMotions(
            "the linear rotation system has more than one null vector: the motions' rotation "
            "axes are parallel; add motions about a second axis"
        )
    Rm = vt[-1].reshape(3, 3).T  # vec is column-major
    if np.linalg.det(Rm) < 0:
        Rm = -Rm
    return nearest_rotation(Rm)


def _two_group(A: Array, B: Array, shift: Array) -> Array:
    """Return X (4, 4): R_X from the pure translations, then t_X (module docstring).

    shift (K, 3): per motion (pair i < j), t_Cj - t_Ci, the target origin's displacement in the
    camera frame. For a pure translation R_B = I is known, and t_B = t_Cj - R_B t_Ci is that
    displacement: taking it, rather than t_B from the views' estimated rotations, keeps their
    rotation noise (levered by the target's distance) out of the first group."""
    angle = np.linalg.norm(matrix_to_rotvec(A[:, :3, :3]), axis=1)
    pure = angle < _MIN_ROTATION
    ta, tb = A[pure, :3, 3], shift[pure]
    moved = np.linalg.norm(ta, axis=1) > 1e-9
    ta, tb = ta[moved], tb[moved]
    if len(ta) < 2:
        raise DegenerateMotions(
            f"the two-group method needs at least 2 pure translations of the end effector "
            f"(rotating under 0.5 degrees); these views give {len(ta)}: add views that only "
            "translate the camera, along two or more directions"
        )
    directions = ta / np.linalg.norm(ta, axis=1, keepdims=True)
    s = np.linalg.svd(directions, compute_uv=False)
    if s[1] < math.sin(_MIN_AXIS_ANGLE) * s[0]:
        raise DegenerateMotions(
            "the pure translations are all along one direction (within 2 degrees): the "
            "hand-eye rotation about it is unobservable; translate along a second direction"
        )
    # max_R sum t_A . R t_B: R = U diag(1, 1, det(U V^T)) V^T of the SVD of sum t_A t_B^T.
    U, _, Vt = np.linalg.svd(ta.T @ tb)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)) or 1.0)])
    R = U @ D @ Vt
    X = np.eye(4)
    X[:3, :3] = R
    # The second group: only rotating motions constrain t_X (a pure translation's rows vanish).
    X[:3, 3] = _translation(A[~pure], B[~pure], R)
    return X


# --------------------------------------------------------------------------------------------
# Uncertainty of the linear estimate


def _motion_residuals(A: Array, B: Array, X: Array) -> tuple[Array, Array]:
    """Return rotation residual vectors (K, 3) rad and translation residuals (K, 3) m."""
    R, t = X[:3, :3], X[:3, 3]
    rot = matrix_to_rotvec(np.swapaxes(A[:, :3, :3] @ R, -1, -2) @ (R @ B[:, :3, :3]))
    tr = (A[:, :3, :3] - np.eye(3)) @ t - B[:, :3, 3] @ R.T + A[:, :3, 3]
    return rot, tr


def _linear_covariance(A: Array, B: Array, X: Array) -> Array:
    """Return the first-order covariance (6, 6) of (w, v) (camera frame) from the residuals.

    Rotation residual r = log((R_A R_X)^T R_X R_B) under R_X exp(w): dr/dw = R_B^T - I; its
    variance from the residuals with 3K - 3 degrees of freedom. Translation: least squares on
    C t = d with C = R_A - I, propagating the rotation's uncertainty through dd/dw =
    -R_X [t_B]x. The translation of X exp(w, v) moves by R_X v, so v = R_X^T dt."""
    rot, tr = _motion_residuals(A, B, X)
    K = A.shape[0]
    dof = max(3 * K - 3, 1)
    Jr = np.swapaxes(B[:, :3, :3], -1, -2) - np.eye(3)
    info_r = np.einsum("kai,kaj->ij", Jr, Jr)
    s2r = float(np.sum(rot * rot)) / dof
    cov_w = s2r * np.linalg.pinv(info_r)
    C = (A[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    s2t = float(np.sum(tr * tr)) / dof
    CtC_inv = np.linalg.pinv(C.T @ C)
    D = -(X[:3, :3] @ skew(B[:, :3, 3])).reshape(-1, 3)
    G = CtC_inv @ C.T @ D
    cov_t = s2t * CtC_inv + G @ cov_w @ G.T
    cross = G @ cov_w
    Rt = X[:3, :3].T
    cov = np.zeros((6, 6))
    cov[:3, :3] = cov_w
    cov[3:, 3:] = Rt @ cov_t @ Rt.T
    cov[3:, :3] = Rt @ cross
    cov[:3, 3:] = cov[3:, :3].T
    return cov


def _stds(cov: Array) -> tuple[float, float]:
    return (
        math.degrees(math.sqrt(max(float(np.trace(cov[:3, :3])), 0.0))),
        math.sqrt(max(float(np.trace(cov[3:, 3:])), 0.0)),
    )


def _target_in_base(T_base_ee: Array, T_cam_target: Array, X: Array) -> Array:
    """Return the mean over views of W_i = T_base_ee_i X T_cam_target_i (rotation by SVD)."""
    W = T_base_ee @ X @ T_cam_target
    out = np.eye(4)
    out[:3, :3] = nearest_rotation(W[:, :3, :3].mean(axis=0))
    out[:3, 3] = W[:, :3, 3].mean(axis=0)
    return out


# --------------------------------------------------------------------------------------------
# Reprojection refinement


class _HandEyeReprojection:
    """Reprojection error of a fixed target over views, for core.optim.solve_sparse_lm.

    Global parameters g = (w_x, v_x, w_w, v_w) (12,): X = X0 (exp(w_x), v_x) and
    W = W0 (exp(w_w), v_w), each a rotation followed by a translation in the frame's own axes.
    Residual block i: the 2M pixel differences (projected - observed) of view i, where the
    camera sees target point P at X^-1 E_i^-1 W P. No local blocks. The Jacobian is exact at
    g = 0; the solver is restarted from re-centred references until the step vanishes.
    """

    def __init__(
        self, E: Array, X0: Array, W0: Array, P: Array, uv: Array, K: Array, dist: Array
    ) -> None:
        self.Einv = invert_pose(E)
        self.X0, self.W0 = X0, W0
        self.P, self.uv, self.K, self.dist = P, uv, K, dist
        self.m = E.shape[0]

    def poses(self, g: Array) -> tuple[Array, Array]:
        X = self.X0.copy()
        X[:3, :3] = self.X0[:3, :3] @ rotvec_to_matrix(g[0:3])
        X[:3, 3] = self.X0[:3, 3] + self.X0[:3, :3] @ g[3:6]
        W = self.W0.copy()
        W[:3, :3] = self.W0[:3, :3] @ rotvec_to_matrix(g[6:9])
        W[:3, 3] = self.W0[:3, 3] + self.W0[:3, :3] @ g[9:12]
        return X, W

    def _camera_points(self, g: Array) -> tuple[Array, Array]:
        X, W = self.poses(g)
        C = invert_pose(X) @ self.Einv @ W  # (m, 4, 4) T_cam_target per view
        Pc = self.P @ np.swapaxes(C[:, :3, :3], -1, -2) + C[:, None, :3, 3]
        return Pc, C

    def residuals(self, x_global: Array, x_local: Array) -> Array:
        Pc, _ = self._camera_points(x_global)
        z = np.zeros((self.m, 3))
        pts = project_points(Pc, z, z, self.K, self.dist).points
        return (pts - self.uv).reshape(self.m, -1)

    def jacobians(self, x_global: Array, x_local: Array) -> tuple[Array, Array, Array]:
        Pc, C = self._camera_points(x_global)
        z = np.zeros((self.m, 3))
        proj = project_points(Pc, z, z, self.K, self.dist, jacobians=True)
        assert proj.d_pose is not None
        dpix = proj.d_pose[..., 3:6]  # (m, M, 2, 3) = d pixel / d camera-frame point
        M = self.P.shape[0]
        dPc = np.zeros((self.m, M, 3, 12))
        # X = X0 (exp w, v): Pc = exp(-w) (Q - v) with Q the point under X0.
        dPc[..., 0:3] = skew(Pc)
        dPc[..., 3:6] = -np.eye(3)
        # W = W0 (exp w', v'): Pc = C0 (exp(w') P + v').
        Rc = C[:, None, :3, :3]
        dPc[..., 6:9] = -Rc @ skew(self.P)[None]
        dPc[..., 9:12] = np.broadcast_to(Rc, (self.m, M, 3, 3))
        jg = (dpix @ dPc).reshape(self.m, 2 * M, 12)
        res = (proj.points - self.uv).reshape(self.m, -1)
        return res, jg, np.zeros((self.m, 2 * M, 0))


def _refine(
    E: Array, X: Array, W: Array, P: Array, uv: Array, K: Array, dist: Array
) -> tuple[Array, Array, Array, Array, int]:
    """Return (X, W, covariance (12, 12), per-view residuals (m, M, 2), iterations)."""
    m = E.shape[0]
    iterations = 0
    for _ in range(10):
        prob = _HandEyeReprojection(E, X, W, P, uv, K, dist)
        sol = solve_sparse_lm(prob, np.zeros(12), np.zeros((m, 0)), max_iterations=50)
        iterations += sol.iterations
        X, W = prob.poses(sol.x_global)
        if float(np.abs(sol.x_global).max()) < 1e-12:
            break
    prob = _HandEyeReprojection(E, X, W, P, uv, K, dist)
    final = solve_sparse_lm(prob, np.zeros(12), np.zeros((m, 0)), max_iterations=0)
    cov = final.global_covariance()
    res = prob.residuals(np.zeros(12), np.zeros((m, 0))).reshape(m, -1, 2)
    return X, W, cov, res, iterations


# --------------------------------------------------------------------------------------------
# Public entry point


def calibrate_hand_eye(
    T_base_ee: ArrayLike,
    T_cam_target: ArrayLike,
    *,
    method: str = "park",
    object_points: ArrayLike | None = None,
    image_points: ArrayLike | None = None,
    K: ArrayLike | None = None,
    dist: ArrayLike | None = None,
) -> HandEyeCalibration:
    """Return X = T_ee_cam (eye in hand) from n >= 3 views, with its uncertainty.

    T_base_ee: n poses (n, 4, 4) of the end effector in the arm's base frame (metres);
    T_cam_target: n poses (n, 4, 4) of the target in the camera frame (from each view's pose
    estimate, e.g. core.calibration.estimate_plane_pose). method: "tsai", "park", "daniilidis",
    "andreff" or "two-group" (module docstring; "two-group" needs pure translations among the
    views' motions). With object_points (M, 3) (target frame), image_points
    (n, M, 2) pixels and K (3, 3) (dist: OpenCV coefficients, default none), the linear
    estimate is refined by minimising sum_i sum_p ||u_ip - pi(K, dist; X^-1 E_i^-1 W P_p)||^2
    over X and the target's base-frame pose W (sparse LM); rms_px and the covariance come from
    that refinement.

    Raises TooFewMotions (fewer than 3 views), DegenerateMotions (every rotation between views
    about one axis, or too small; for "two-group", fewer than two non-parallel pure
    translations), InvalidInput (shapes, non-rigid poses, unknown method).
    """
    if method not in METHODS:
        raise InvalidInput(f"unknown hand-eye method {method!r}; use one of {', '.join(METHODS)}")
    E = _as_pose_list(T_base_ee, "T_base_ee")
    C = _as_pose_list(T_cam_target, "T_cam_target")
    if E.shape[0] != C.shape[0]:
        raise InvalidInput(
            f"T_base_ee has {E.shape[0]} poses and T_cam_target {C.shape[0]}; give one of each "
            "per view"
        )
    if E.shape[0] < 3:
        raise TooFewMotions(
            f"{E.shape[0]} views give {max(E.shape[0] - 1, 0)} motion(s); hand-eye calibration "
            "needs at least 3 views (2 motions about different axes), 10 or more for accuracy"
        )
    A, B = relative_motions(E, C)
    check_motions(A)
    if method == "daniilidis":
        X = _daniilidis(A, B)
    elif method == "two-group":
        i, j = np.triu_indices(E.shape[0], 1)
        X = _two_group(A, B, C[j, :3, 3] - C[i, :3, 3])
    else:
        R = {"tsai": _tsai, "park": _park, "andreff": _andreff}[method](A, B)
        X = np.eye(4)
        X[:3, :3] = R
        X[:3, 3] = _translation(A, B, R)
    rot, tr = _motion_residuals(A, B, X)
    rot_deg = np.degrees(np.linalg.norm(rot, axis=1))
    tr_m = np.linalg.norm(tr, axis=1)
    W = _target_in_base(E, C, X)
    refine_args = (object_points, image_points, K)
    if all(a is None for a in refine_args):
        cov = _linear_covariance(A, B, X)
        rs, ts = _stds(cov)
        return HandEyeCalibration(
            X=X,
            method=method,
            covariance=cov,
            rotation_std_deg=rs,
            translation_std_m=ts,
            rotation_residuals_deg=rot_deg,
            translation_residuals_m=tr_m,
            T_base_target=W,
            linear_method=method,
        )
    if object_points is None or image_points is None or K is None:
        raise InvalidInput(
            "refinement needs object_points, image_points and K together; give all three or none"
        )
    P, uv, Km = _check_views(object_points, image_points, K, E.shape[0])
    d = as_distortion(dist)
    Xr, Wr, cov12, res, iters = _refine(E, X, W, P, uv, Km, d)
    rot, tr = _motion_residuals(A, B, Xr)
    cov = cov12[:6, :6]
    rs, ts = _stds(cov)
    err2 = np.sum(res * res, axis=2)
    return HandEyeCalibration(
        X=Xr,
        method=f"{method}+refine",
        covariance=cov,
        rotation_std_deg=rs,
        translation_std_m=ts,
        rotation_residuals_deg=np.degrees(np.linalg.norm(rot, axis=1)),
        translation_residuals_m=np.linalg.norm(tr, axis=1),
        T_base_target=Wr,
        refined=True,
        rms_px=float(np.sqrt(err2.mean())),
        per_view_rms_px=np.sqrt(err2.mean(axis=1)),
        iterations=iters,
        linear_method=method,
    )


def _check_views(
    object_points: ArrayLike, image_points: ArrayLike, K: ArrayLike, n: int
) -> tuple[Array, Array, Array]:
    P = np.asarray(object_points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or P.shape[0] < 4 or not np.all(np.isfinite(P)):
        raise InvalidInput(f"object_points must be finite (M, 3) with M >= 4, got {P.shape}")
    try:
        uv = np.asarray(image_points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"image_points must be n arrays of (M, 2) pixels: {exc}") from None
    if uv.shape != (n, P.shape[0], 2) or not np.all(np.isfinite(uv)):
        raise InvalidInput(
            f"image_points must be (n, M, 2) = ({n}, {P.shape[0]}, 2) finite pixels (every "
            f"target point in every view), got {uv.shape}"
        )
    Km = np.asarray(K, dtype=np.float64)
    if Km.shape != (3, 3) or not np.all(np.isfinite(Km)) or Km[0, 0] <= 0 or Km[1, 1] <= 0:
        raise InvalidInput(f"K must be a finite (3, 3) camera matrix, got {Km.shape}")
    return P, uv, Km
