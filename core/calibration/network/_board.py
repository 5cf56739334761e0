"""Calibrating a camera network from a chessboard carried by the robot (02 §1, board kind).

The robot carries a chessboard at a known mounting T_robot_board; at pose j the robot stands at
(x_j, y_j, yaw_j). Each camera's detections of the board's corners give a full Zhang
calibration (core.calibration.calibrate_camera: intrinsics and distortion) and the board's pose
T_camera_board_j per view, so every view chains the camera into the world:

    T_world_camera = T_world_robot_j  T_robot_board  T_board_camera_j.

A chessboard whose grid is symmetric under a half turn is detected in one of two corner orders;
both are chained and the order (and any view inconsistent with the others) is decided by a vote
among the views. The joint refinement (sparse LM) then has global block all cameras'
(fx, fy, cx, cy, distortion, rvec, t) and local blocks the robot pose corrections
(dx, dy, dyaw) with the recorded poses as Gaussian prior, minimising

    sum_(c, j seen, i) || (pi_c(T_world_robot(x_j + d_j) T_robot_board P_i) - u_cji) / sigma ||^2
        + sum_j || (d_j / (sigma_xy, sigma_xy, sigma_yaw)) ||^2.

Units: metres, radians, pixels.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.calibration.network._records import CalibratedCamera, NetworkCalibration, RejectedCamera
from core.calibration.zhang import DISTORTION_MODELS, calibrate_camera
from core.errors import ConvergenceError, DegenerateConfiguration, InvalidInput, NotEnoughPoints
from core.geometry.camera import intrinsics_to_matrix, project_points
from core.geometry.poses import invert_pose
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]

_INTRINSIC_NAMES = ("fx", "fy", "cx", "cy")
_DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")
_POSE_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")


@dataclass(frozen=True)
class _BoardInit:
    name: str
    index: int  # into the caller's cameras
    intr: Array  # (4,) fx, fy, cx, cy
    dist: Array  # (5,)
    rvec: Array  # R_camera_world
    t: Array
    used: NDArray[np.bool_]  # (M,) views kept
    corners: Array  # (M, N, 2) in the board's model order (flipped views re-ordered)
    outliers: int


def _robot_matrices(poses: Array) -> Array:
    """Return T_world_robot (M, 4, 4) of floor poses (M, 3) = (x m, y m, yaw rad)."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    T = np.tile(np.eye(4), (len(poses), 1, 1))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
    T[:, 0, 3], T[:, 1, 3] = poses[:, 0], poses[:, 1]
    return T


def _half_turn(points: Array) -> tuple[Array, NDArray[np.int64]]:
    """Return the half turn F (4, 4) about the board's normal through the grid's centre and the
    permutation (N,) it applies to the model points, when the grid maps onto itself under it."""
    lo, hi = points[:, :2].min(0), points[:, :2].max(0)
    F = np.diag([-1.0, -1.0, 1.0, 1.0])
    F[:2, 3] = lo + hi
    turned = points @ F[:3, :3].T + F[:3, 3]
    d = np.linalg.norm(turned[:, None, :] - points[None, :, :], axis=-1)
    perm = np.argmin(d, axis=1)
    ok = np.allclose(d[np.arange(len(points)), perm], 0.0, atol=1e-9 * max(1.0, float(hi.max())))
    return F, perm if ok and len(set(perm.tolist())) == len(points) else np.arange(len(points))


def _mean_rotation(Rs: Array) -> Array:
    """Return the chordal L2 mean (3, 3) of rotations (K, 3, 3) (Hartley et al., "Rotation
    averaging", IJCV 2013, sec. 5.3): the rotation nearest to their arithmetic mean."""
    U, _, Vt = np.linalg.svd(Rs.sum(0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return np.asarray(U @ D @ Vt)


def _pose_distance(Ta: Array, Tb: Array) -> tuple[Array, Array]:
    """Return the rotation angle (rad) and the centre distance (m) between poses (..., 4, 4)."""
    Rrel = np.einsum("...ji,...jk->...ik", Ta[..., :3, :3], Tb[..., :3, :3])
    cos = np.clip((np.trace(Rrel, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    return np.arccos(cos), np.linalg.norm(Ta[..., :3, 3] - Tb[..., :3, 3], axis=-1)


def _init_board_camera(
    name: str,
    index: int,
    corners: Array,
    seen: NDArray[np.bool_],
    image_size: tuple[int, int],
    board_points: Array,
    T_robot_board: Array,
    T_world_robot: Array,
    distortion: str,
    min_views: int,
    max_angle: float,
    max_offset: float,
    outlier_factor: float,
) -> _BoardInit | RejectedCamera:
    n = int(seen.sum())
    if n < min_views:
        return RejectedCamera(name, f"too few board views: saw {n}, needs at least {min_views}", n)
    views = np.flatnonzero(seen)
    F, perm = _half_turn(board_points)
    try:
        for _ in range(4):
            cal = calibrate_camera(
                [board_points] * len(views),
                [corners[j] for j in views],
                image_size,
                distortion=distortion,
            )
            # A detection whose corners are in a mirrored order still has a homography but no
            # pose: it fits badly and pulls the intrinsics; drop such views and calibrate again.
            bad = cal.per_view_rms > max(outlier_factor * float(np.median(cal.per_view_rms)), 0.3)
            if not bad.any() or len(views) - bad.sum() < min_views:
                break
            views = views[~bad]
    except (DegenerateConfiguration, NotEnoughPoints, ConvergenceError) as exc:
        return RejectedCamera(name, f"Zhang calibration failed: {exc}", n)
    n = len(views)
    T_cb = np.tile(np.eye(4), (n, 1, 1))
    for k, p in enumerate(cal.poses):
        T_cb[k, :3, :3], T_cb[k, :3, 3] = p.R, p.t
    # Both corner orders as world poses of the camera (2, n, 4, 4): as detected, and turned.
    T_wb = T_world_robot[views] @ T_robot_board
    cand = np.stack([T_wb @ invert_pose(T_cb), T_wb @ F @ invert_pose(T_cb)])
    flat = cand.reshape(-1, 4, 4)
    ang, off = _pose_distance(flat[:, None], flat[None, :])
    near = (ang <= max_angle) & (off <= max_offset)
    # Score a candidate by how many views have a candidate near it; the best is the reference.
    votes = near.reshape(2 * n, 2, n).any(axis=1).sum(axis=1)
    ref = flat[int(np.argmax(votes))]
    ang_r, off_r = _pose_distance(cand, ref[None, None])
    turn = (ang_r[1] + off_r[1]) < (ang_r[0] + off_r[0])
    pick = np.where(turn, 1, 0)
    keep = (ang_r[pick, np.arange(n)] <= max_angle) & (off_r[pick, np.arange(n)] <= max_offset)
    if keep.sum() < min_views:
        return RejectedCamera(
            name,
            f"too few consistent board views: {int(keep.sum())} of {int(seen.sum())} agree "
            f"on the camera's pose within {np.degrees(max_angle):.0f} deg and "
            f"{100 * max_offset:.0f} cm",
            int(seen.sum()),
        )
    ordered = corners.copy()
    inv = np.argsort(perm)
    for v_turned in views[turn]:
        # Detected corner i is model point perm[i]: put it back in the model's order.
        ordered[v_turned] = corners[v_turned][inv]
    used = np.zeros(len(seen), bool)
    used[views[keep]] = True
    if not keep.all() or turn.any():
        try:
            cal = calibrate_camera(
                [board_points] * int(keep.sum()),
                [ordered[j] for j in np.flatnonzero(used)],
                image_size,
                distortion=distortion,
            )
        except (DegenerateConfiguration, NotEnoughPoints, ConvergenceError) as exc:
            return RejectedCamera(name, f"Zhang calibration failed: {exc}", int(seen.sum()))
    T_cb = np.tile(np.eye(4), (len(cal.poses), 1, 1))
    for k, p in enumerate(cal.poses):
        T_cb[k, :3, :3], T_cb[k, :3, 3] = p.R, p.t
    T_wc = T_world_robot[used] @ T_robot_board @ invert_pose(T_cb)
    R_wc = _mean_rotation(T_wc[:, :3, :3])
    centre = T_wc[:, :3, 3].mean(0)
    return _BoardInit(
        name=name,
        index=index,
        intr=np.array([cal.K[0, 0], cal.K[1, 1], cal.K[0, 2], cal.K[1, 2]]),
        dist=cal.dist.copy(),
        rvec=matrix_to_rotvec(R_wc.T),
        t=-R_wc.T @ centre,
        used=used,
        corners=ordered,
        outliers=int(seen.sum() - keep.sum()),
    )


class _BoardProblem:
    """The joint refinement of the board kind for core.optim.solve_sparse_lm.

    Global (P C,): per camera (fx, fy, cx, cy, the free distortion coefficients, rvec, t).
    Local (M, 3) robot pose corrections (dx, dy, dyaw), or (M, 0) when the poses are held
    fixed. Residual block j (2 N C + 3): pixel errors / sigma of pose j's N corners in every
    camera (zero where unused), then the prior's three rows.
    """

    def __init__(
        self,
        inits: Sequence[_BoardInit],
        dist_idx: tuple[int, ...],
        points_robot: Array,
        poses: Array,
        pixel_sigma: float,
        prior_sigma: Array,
    ) -> None:
        self.cams = inits
        self.di = list(dist_idx)
        self.P = 4 + len(dist_idx) + 6
        self.B = points_robot  # (N, 3)
        self.poses = poses  # (M, 3)
        self.w = np.stack([i.used for i in inits]).astype(np.float64) / pixel_sigma  # (C, M)
        self.uv = np.stack([i.corners for i in inits])  # (C, M, N, 2)
        self.prior = prior_sigma  # (3,)
        self.free = bool(np.all(prior_sigma > 0))

    def unpack(self, g: Array, c: int) -> tuple[Array, Array, Array, Array]:
        """Return K (3, 3), dist (5,), rvec (3,), t (3,) of camera c from the global block."""
        p = g[self.P * c : self.P * (c + 1)]
        K = intrinsics_to_matrix([p[0], p[1], p[2], p[3], 0.0])
        d = np.zeros(5)
        d[self.di] = p[4 : 4 + len(self.di)]
        return K, d, p[-6:-3], p[-3:]

    def world_points(self, loc: Array) -> tuple[Array, Array]:
        """Return the corners in the world (M, N, 3) and their robot-frame offsets turned by
        the yaw (M, N, 3) for the corrected poses."""
        x = self.poses + (loc if self.free else 0.0)
        c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
        bx, by = self.B[:, 0], self.B[:, 1]
        rb = np.stack(
            [
                c[:, None] * bx - s[:, None] * by,
                s[:, None] * bx + c[:, None] * by,
                np.broadcast_to(self.B[:, 2], (len(x), len(self.B))),
            ],
            -1,
        )
        X = rb.copy()
        X[..., 0] += x[:, 0:1]
        X[..., 1] += x[:, 1:2]
        return X, rb

    def jacobians(self, g: Array, loc: Array) -> tuple[Array, Array, Array]:
        C, M = self.w.shape
        N = self.B.shape[0]
        X, rb = self.world_points(loc)
        nr = 2 * N * C + 3
        res = np.zeros((M, nr))
        jg = np.zeros((M, nr, self.P * C))
        q = 3 if self.free else 0
        jl = np.zeros((M, nr, q))
        # d X / d (dx, dy, dyaw), (M, N, 3, 3): unit x, unit y, and e_z x (R b).
        dX = np.zeros((M, N, 3, 3))
        dX[..., 0, 0] = 1.0
        dX[..., 1, 1] = 1.0
        dX[..., 0, 2] = -rb[..., 1]
        dX[..., 1, 2] = rb[..., 0]
        for c in range(C):
            K, d, rv, t = self.unpack(g, c)
            pr = project_points(
                X, np.broadcast_to(rv, (M, 3)), np.broadcast_to(t, (M, 3)), K, d, jacobians=True
            )
            assert pr.d_intrinsics is not None and pr.d_pose is not None
            assert pr.d_distortion is not None
            w = self.w[c][:, None, None, None]  # (M, 1, 1, 1)
            rows = slice(2 * N * c, 2 * N * (c + 1))
            res[:, rows] = (w[..., 0] * (pr.points - self.uv[c])).reshape(M, 2 * N)
            jac = np.concatenate(
                [pr.d_intrinsics[..., :4], pr.d_distortion[..., self.di], pr.d_pose], axis=-1
            )
            cols = slice(self.P * c, self.P * (c + 1))
            jg[:, rows, cols] = (w * jac).reshape(M, 2 * N, self.P)
            if self.free:
                R = rotvec_to_matrix(rv)
                dpix_dX = pr.d_pose[..., 3:6] @ R  # (M, N, 2, 3)
                jl[:, rows, :] = (w * (dpix_dX @ dX)).reshape(M, 2 * N, 3)
        if self.free:
            res[:, -3:] = loc / self.prior
            jl[:, -3:, :] = np.diag(1.0 / self.prior)
        return res, jg, jl

    def residuals(self, g: Array, loc: Array) -> Array:
        return self.jacobians(g, loc)[0]


def calibrate_network_board(
    names: Sequence[str],
    image_sizes: ArrayLike,
    corners: ArrayLike,
    visible: ArrayLike,
    board_points: ArrayLike,
    T_robot_board: ArrayLike,
    robot_poses: ArrayLike,
    *,
    distortion: str = "k1k2p1p2",
    pixel_sigma: float = 0.2,
    pose_sigma: tuple[float, float] = (0.0, 0.0),
    min_views: int = 8,
    max_angle_deg: float = 10.0,
    max_offset: float = 0.5,
    outlier_factor: float = 3.0,
    refine: bool = True,
    max_iterations: int = 50,
) -> NetworkCalibration:
    """Return the calibrated network from a chessboard carried by the robot (module docstring,
    board kind).

    names: C camera names; image_sizes (C, 2) (width, height) pixels; corners (C, M, N, 2) the
    board's N inner corners detected in camera c at robot pose j (distorted pixels, in the
    detector's order, which for a grid symmetric under a half turn may be the model's order
    reversed; anything where unseen); visible (C, M) bool; board_points (N, 3) the model points
    in the board frame (metres, Z = 0; core.calibration.board_object_points); T_robot_board
    (4, 4) the board's mounting on the robot (robot frame: x forward, y left, z up, origin on
    the floor under the base centre); robot_poses (M, 3) the recorded poses (x m, y m, yaw rad).
    distortion: the model each camera's Zhang calibration estimates (zhang.DISTORTION_MODELS;
    k3 is left out by default: it is only observed near the image corners, which a board on a
    robot seldom reaches, and unobserved it extrapolates wildly).
    pixel_sigma: the corners' standard deviation (px). pose_sigma (metres, radians): the
    recorded poses' standard deviation per axis and in yaw, the prior of the joint refinement
    ((0, 0): held fixed, only the cameras move). A camera with fewer than `min_views` board
    views, whose Zhang calibration fails, or with fewer than `min_views` views agreeing on its
    world pose within `max_angle_deg` degrees and `max_offset` metres, is listed in `rejected`.
    Raises InvalidInput for inconsistent shapes or options.
    """
    C = len(names)
    sizes = np.asarray(image_sizes, dtype=np.int64).reshape(C, 2)
    uv = np.asarray(corners, dtype=np.float64)
    vis = np.asarray(visible, dtype=bool)
    P = np.asarray(board_points, dtype=np.float64)
    Trb = np.asarray(T_robot_board, dtype=np.float64)
    x0 = np.asarray(robot_poses, dtype=np.float64)
    M = x0.shape[0] if x0.ndim == 2 else -1
    N = P.shape[0] if P.ndim == 2 else -1
    if (
        x0.ndim != 2
        or x0.shape[1] != 3
        or P.ndim != 2
        or P.shape[1] != 3
        or uv.shape != (C, M, N, 2)
        or vis.shape != (C, M)
        or Trb.shape != (4, 4)
    ):
        raise InvalidInput(
            f"need robot_poses (M, 3), board_points (N, 3), corners (C, M, N, 2), visible "
            f"(C, M), T_robot_board (4, 4) for C = {C} names; got {x0.shape}, {P.shape}, "
            f"{uv.shape}, {vis.shape}, {Trb.shape}"
        )
    if N < 4 or not np.allclose(P[:, 2], 0.0):
        raise InvalidInput("board_points must hold >= 4 points on the plane Z = 0")
    if not np.all(np.isfinite(x0)) or not np.all(np.isfinite(uv[vis])):
        raise InvalidInput("robot_poses and the visible corners must be finite")
    if distortion not in DISTORTION_MODELS:
        raise InvalidInput(
            f"unknown distortion model {distortion!r}; use one of {', '.join(DISTORTION_MODELS)}"
        )
    sig = np.array([pose_sigma[0], pose_sigma[0], pose_sigma[1]], dtype=np.float64)
    if not (np.all(np.isfinite(sig)) and np.all(sig >= 0)) or (np.any(sig > 0) != np.all(sig > 0)):
        raise InvalidInput(f"pose_sigma must be both > 0 or both 0, got {pose_sigma}")
    if not pixel_sigma > 0:
        raise InvalidInput(f"pixel_sigma must be > 0 pixels, got {pixel_sigma}")
    T_wr = _robot_matrices(x0)
    inits: list[_BoardInit] = []
    rejected: list[RejectedCamera] = []
    for c, name in enumerate(names):
        r = _init_board_camera(
            name,
            c,
            np.where(vis[c][:, None, None], uv[c], 0.0),
            vis[c],
            (int(sizes[c, 0]), int(sizes[c, 1])),
            P,
            Trb,
            T_wr,
            distortion,
            min_views,
            np.radians(max_angle_deg),
            max_offset,
            outlier_factor,
        )
        if isinstance(r, RejectedCamera):
            rejected.append(r)
        else:
            inits.append(r)
    prior = np.broadcast_to(np.diag(sig**2), (M, 3, 3)).copy()
    if not inits:
        nan = float("nan")
        return NetworkCalibration((), tuple(rejected), x0.copy(), prior, nan, nan, nan, 0)
    dist_idx = DISTORTION_MODELS[distortion]
    points_robot = P @ Trb[:3, :3].T + Trb[:3, 3]
    problem = _BoardProblem(inits, dist_idx, points_robot, x0, float(pixel_sigma), sig)
    g0 = np.concatenate(
        [np.concatenate([i.intr, i.dist[list(dist_idx)], i.rvec, i.t]) for i in inits]
    )
    loc0 = np.zeros((M, 3 if problem.free else 0))
    used = np.stack([i.used for i in inits])
    n_res = int(2 * N * used.sum() + (3 * M if problem.free else 0))
    sol = solve_sparse_lm(
        problem,
        g0,
        loc0,
        max_iterations=max_iterations if refine else 0,
        ftol=1e-12,
        n_residuals=n_res,
    )
    g = sol.x_global
    # Scaled by the measured residual variance: the corners' sigma is a configured guess.
    s2 = sol.residual_variance
    gcov = sol.global_covariance(s2)
    X, _ = problem.world_points(sol.x_local)
    names_p = (*_INTRINSIC_NAMES, *(_DIST_NAMES[i] for i in dist_idx), *_POSE_NAMES)
    cams = []
    sq = 0.0
    for k, ini in enumerate(inits):
        params = problem.unpack(g, k)
        K, d, rv, t = params
        proj = project_points(X[ini.used], rv, t, K, d).points  # (m, N, 2)
        resid = (proj - ini.corners[ini.used]).reshape(-1, 2)
        sq += float(np.sum(resid**2))
        cams.append(
            CalibratedCamera.refined(
                ini.name,
                params,
                problem.unpack(g0, k),
                gcov,
                slice(problem.P * k, problem.P * (k + 1)),
                residuals=resid,
                poses_seen=int(vis[ini.index].sum()),
                outliers=ini.outliers,
                parameter_names=names_p,
                pose_index=np.repeat(np.flatnonzero(ini.used), N),
            )
        )
    if problem.free:
        targets = x0 + sol.x_local
        tcov = sol.local_covariance(s2)
    else:
        targets, tcov = x0.copy(), prior
    return NetworkCalibration(
        cameras=tuple(cams),
        rejected=tuple(rejected),
        targets=targets,
        target_cov=tcov,
        rms_px=float(np.sqrt(sq / max(N * int(used.sum()), 1))),
        rms_whitened=float(np.sqrt(sq / max(N * int(used.sum()), 1))) / float(pixel_sigma),
        residual_variance=float(s2),
        iterations=sol.iterations,
    )
