"""Calibrating a camera network by driving the robot's marker over the floor (02 §1, marker kind).

The robot carries a marker at a known height h; at each of M recorded poses its floor position
(X_j, Y_j) is known (odometry or a scripted programme) with covariance sigma_t^2 I. Every point
lies on the plane Z = h, so each camera sees one world-plane homography. Per camera:

1. Too few poses (< `min_poses`) or a degenerate track (the floor points' smaller principal
   standard deviation below `min_spread` metres: collinear, H undetermined) reject the camera
   by name with the reason; the others still calibrate.
2. Single-view calibration (core.calibration.single_view: principal point given, zero skew,
   unit aspect, known distortion held fixed) gives the focal length f and the plane-to-camera
   pose, i.e. T_camera_world with the plane's origin at (0, 0, h). Detections whose
   reprojection error exceeds `outlier_px` (a partly hidden marker) are dropped and the camera
   is calibrated again.
3. A joint refinement by the sparse LM (core.optim): global block all cameras' (f, rvec, t),
   7 per camera; local blocks the marker's floor position per robot pose, with the recorded
   pose as a Gaussian prior. It minimises

       sum_(c, j seen) || L_cj^T (pi_c(X_j, Y_j, h) - u_cj) ||^2
           + sum_j || (x_j - x0_j) / sigma_t ||^2

   (L_cj L_cj^T = S_cj^-1, the inverse pixel covariance of the detection), the maximum
   a-posteriori estimate under Gaussian pixel noise and pose prior. With sigma_t = 0 the target
   positions are held fixed (the recorded poses taken as exact) and only the cameras move.

The distortion is not estimated (the marker kind needs it known or negligible); the caller
passes each camera's known coefficients. Units: metres, radians, pixels.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.calibration.single_view import calibrate_single_view
from core.errors import DegenerateConfiguration, InvalidInput, NotEnoughPoints
from core.geometry.camera import as_distortion, intrinsics_to_matrix, project_points
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]

_PER_CAMERA = 7  # f, rvec (3), t (3)


@dataclass(frozen=True)
class CalibratedCamera:
    """One camera of the network after calibration.

    K (3, 3) pixels (fx = fy = f, principal point as given); dist (5,) the known distortion;
    R (3, 3) = R_camera_world, t (3,) = t_camera_world metres (Xc = R X + t). `std` (7,) the
    standard deviations of (f px, rvec rad, t m) from the joint information; `residuals` (N, 2)
    pixels (projected - detected) of the N detections used; `initial_K`, `initial_R`,
    `initial_t`: the single-view estimate before the joint refinement; `outliers`: detections
    dropped.
    """

    name: str
    K: Array
    dist: Array
    R: Array
    t: Array
    std: Array = field(repr=False)
    residuals: Array = field(repr=False)
    poses_seen: int
    outliers: int
    initial_K: Array = field(repr=False)
    initial_R: Array = field(repr=False)
    initial_t: Array = field(repr=False)

    @property
    def focal(self) -> float:
        """Focal length f in pixels."""
        return float(self.K[0, 0])

    @property
    def position(self) -> Array:
        """Optical centre in the world (3,), metres."""
        return -self.R.T @ self.t

    @property
    def T_world_camera(self) -> Array:
        """Pose (4, 4) mapping camera coordinates to world coordinates."""
        T = np.eye(4)
        T[:3, :3] = self.R.T
        T[:3, 3] = self.position
        return T

    @property
    def rms(self) -> float:
        """Root mean square reprojection error per detection, pixels."""
        if len(self.residuals) == 0:
            return float("nan")
        return float(np.sqrt(np.mean(np.sum(self.residuals**2, axis=1))))


@dataclass(frozen=True)
class RejectedCamera:
    """A camera left out of the calibration: its name, why, and how many poses it saw."""

    name: str
    reason: str
    poses_seen: int


@dataclass(frozen=True)
class NetworkCalibration:
    """The calibrated network: `cameras` (calibrated), `rejected` (by name with the reason),
    `targets` (M, 2) refined marker floor positions metres and `target_cov` (M, 2, 2) m^2
    (the prior where no camera saw the pose), the joint `rms` pixels (whitened residuals'
    RMS when covariances were given) and LM `iterations`."""

    cameras: tuple[CalibratedCamera, ...]
    rejected: tuple[RejectedCamera, ...]
    targets: Array = field(repr=False)
    target_cov: Array = field(repr=False)
    rms: float
    iterations: int

    def camera(self, name: str) -> CalibratedCamera:
        """Return the calibrated camera called `name`; raise InvalidInput otherwise."""
        for c in self.cameras:
            if c.name == name:
                return c
        why = {r.name: r.reason for r in self.rejected}.get(name, "unknown camera")
        raise InvalidInput(f"camera {name!r} is not calibrated: {why}")


@dataclass(frozen=True)
class _Init:
    name: str
    f: float
    cx: float
    cy: float
    dist: Array
    rvec: Array
    t: Array
    used: NDArray[np.bool_]
    outliers: int


def _whiteners(cov: Array) -> Array:
    """Return W (..., 2, 2) with W^T W = cov^-1 (W = L^T, L the Cholesky factor of cov^-1)."""
    inv = np.linalg.inv(cov)
    return np.swapaxes(np.linalg.cholesky(inv), -1, -2)


class _NetworkProblem:
    """The joint refinement for core.optim.solve_sparse_lm (module docstring, step 3).

    Global (7 C,): per camera (f, rvec, t). Local (M, 2) target floor positions, or (M, 0)
    when they are held fixed. Residual block j (2 C + 2): whitened pixel errors of pose j in
    every camera (zero where unseen), then the prior's two rows.
    """

    def __init__(
        self,
        inits: Sequence[_Init],
        pixels: Array,
        used: NDArray[np.bool_],
        whiten: Array,
        xy0: Array,
        height: float,
        target_sigma: float,
    ) -> None:
        self.cams = inits
        self.uv = pixels  # (C, M, 2)
        self.w = used.astype(np.float64)  # (C, M)
        self.W = whiten  # (C, M, 2, 2)
        self.xy0 = xy0
        self.h = height
        self.sigma = target_sigma
        self.free = target_sigma > 0

    def _points(self, loc: Array) -> Array:
        xy = loc if self.free else self.xy0
        return np.column_stack([xy, np.full(len(xy), self.h)])

    def jacobians(self, g: Array, loc: Array) -> tuple[Array, Array, Array]:
        C, M = self.w.shape
        X = self._points(loc)
        res = np.zeros((M, 2 * C + 2))
        jg = np.zeros((M, 2 * C + 2, _PER_CAMERA * C))
        q = 2 if self.free else 0
        jl = np.zeros((M, 2 * C + 2, q))
        for c, ini in enumerate(self.cams):
            p = g[_PER_CAMERA * c : _PER_CAMERA * (c + 1)]
            K = intrinsics_to_matrix([p[0], p[0], ini.cx, ini.cy, 0.0])
            pr = project_points(X, p[1:4], p[4:7], K, ini.dist, jacobians=True)
            assert pr.d_intrinsics is not None and pr.d_pose is not None
            wc = self.w[c][:, None, None] * self.W[c]  # (M, 2, 2)
            e = np.einsum("mij,mj->mi", wc, pr.points - self.uv[c])
            res[:, 2 * c : 2 * c + 2] = e
            d_f = pr.d_intrinsics[..., 0] + pr.d_intrinsics[..., 1]  # (M, 2)
            jac = np.concatenate([d_f[..., None], pr.d_pose], axis=-1)  # (M, 2, 7)
            jg[:, 2 * c : 2 * c + 2, _PER_CAMERA * c : _PER_CAMERA * (c + 1)] = wc @ jac
            if self.free:
                # Xc = R X + t, so d pixel / d X = (d pixel / d t) R; keep the X, Y columns.
                R = rotvec_to_matrix(p[1:4])
                jl[:, 2 * c : 2 * c + 2, :] = wc @ (pr.d_pose[..., 3:6] @ R)[..., :2]
        if self.free:
            res[:, -2:] = (loc - self.xy0) / self.sigma
            jl[:, -2:, :] = np.eye(2) / self.sigma
        return res, jg, jl

    def residuals(self, g: Array, loc: Array) -> Array:
        return self.jacobians(g, loc)[0]


def _init_camera(
    name: str,
    xy: Array,
    uv: Array,
    seen: NDArray[np.bool_],
    principal_point: Array,
    dist: Array,
    height: float,
    min_poses: int,
    min_spread: float,
    outlier_px: float,
) -> _Init | RejectedCamera:
    n = int(seen.sum())
    if n < min_poses:
        return RejectedCamera(name, f"too few poses: saw {n}, needs at least {min_poses}", n)
    pts = xy[seen]
    spread = float(np.sqrt(max(np.linalg.eigvalsh(np.cov(pts.T))[0], 0.0)))
    if spread < min_spread:
        return RejectedCamera(
            name,
            f"degenerate (collinear) track: the poses it saw spread {100 * spread:.1f} cm "
            f"across their line, needs {100 * min_spread:.0f} cm; drive across its view",
            n,
        )
    used = seen.copy()
    try:
        for _ in range(3):
            sv = calibrate_single_view(
                xy[used], uv[used], principal_point, unit_aspect=True, dist=dist
            )
            # Residuals over every seen pose under the current estimate: a detection dropped
            # earlier comes back if the refit explains it.
            X = np.column_stack([xy, np.zeros(len(xy))])
            proj = project_points(X, sv.pose.rvec, sv.pose.t, sv.K, dist).points
            err = np.linalg.norm(proj - uv, axis=1)
            keep = seen & (err <= outlier_px)
            if np.array_equal(keep, used) or keep.sum() < min_poses:
                break
            used = keep
    except (DegenerateConfiguration, NotEnoughPoints) as exc:
        return RejectedCamera(name, f"single-view calibration failed: {exc}", n)
    if used.sum() < min_poses:
        return RejectedCamera(
            name, f"too few consistent poses: {int(used.sum())} within {outlier_px} px", n
        )
    # The plane frame is the world shifted up by h: Xc = R (X - h e3) + t.
    R = sv.pose.R
    t = sv.pose.t - R[:, 2] * height
    return _Init(
        name=name,
        f=float(sv.K[0, 0]),
        cx=float(principal_point[0]),
        cy=float(principal_point[1]),
        dist=dist,
        rvec=matrix_to_rotvec(R),
        t=t,
        used=used,
        outliers=int(seen.sum() - used.sum()),
    )


def calibrate_network_marker(
    names: Sequence[str],
    principal_points: ArrayLike,
    distortions: ArrayLike,
    pixels: ArrayLike,
    visible: ArrayLike,
    targets: ArrayLike,
    height: float,
    *,
    pixel_cov: ArrayLike | None = None,
    pixel_sigma: float = 0.2,
    target_sigma: float = 0.0,
    min_poses: int = 6,
    min_spread: float = 0.15,
    outlier_px: float = 1.5,
    refine: bool = True,
    max_iterations: int = 50,
) -> NetworkCalibration:
    """Return the calibrated network from a marker driven over the floor (module docstring).

    names: C camera names; principal_points (C, 2) pixels (given); distortions (C, 5) known
    OpenCV coefficients (k1, k2, p1, p2, k3); pixels (C, M, 2) detected marker centres
    (distorted, anything where unseen); visible (C, M) bool; targets (M, 2) the recorded floor
    positions of the marker (metres, world frame); height: the marker's Z (metres).
    pixel_cov (C, M, 2, 2) px^2 per detection, or pixel_sigma (px) for all. target_sigma
    (metres): the recorded positions' standard deviation, the prior of the joint refinement
    (0: held fixed). Raises InvalidInput for inconsistent shapes; a camera that cannot be
    calibrated is listed in `rejected`, never raised.
    """
    C = len(names)
    pp = np.asarray(principal_points, dtype=np.float64).reshape(C, 2)
    dist = np.asarray(distortions, dtype=np.float64).reshape(C, -1)
    uv = np.asarray(pixels, dtype=np.float64)
    vis = np.asarray(visible, dtype=bool)
    xy0 = np.asarray(targets, dtype=np.float64)
    M = xy0.shape[0] if xy0.ndim == 2 else -1
    if xy0.ndim != 2 or xy0.shape[1] != 2 or uv.shape != (C, M, 2) or vis.shape != (C, M):
        raise InvalidInput(
            f"need targets (M, 2), pixels (C, M, 2), visible (C, M) for C = {C} names; got "
            f"{xy0.shape}, {uv.shape}, {vis.shape}"
        )
    if not np.all(np.isfinite(xy0)) or not np.all(np.isfinite(uv[vis])):
        raise InvalidInput("targets and the visible pixels must be finite")
    if not (np.isfinite(target_sigma) and target_sigma >= 0):
        raise InvalidInput(f"target_sigma must be >= 0 metres, got {target_sigma}")
    if pixel_cov is None:
        cov = np.broadcast_to(pixel_sigma**2 * np.eye(2), (C, M, 2, 2)).copy()
    else:
        cov = np.asarray(pixel_cov, dtype=np.float64).reshape(C, M, 2, 2).copy()
        cov[~vis] = np.eye(2)
    inits: list[_Init] = []
    rejected: list[RejectedCamera] = []
    for c, name in enumerate(names):
        r = _init_camera(
            name,
            xy0,
            np.where(vis[c][:, None], uv[c], 0.0),
            vis[c],
            pp[c],
            as_distortion(dist[c]),
            float(height),
            min_poses,
            min_spread,
            outlier_px,
        )
        if isinstance(r, RejectedCamera):
            rejected.append(r)
        else:
            inits.append(r)
    if not inits:
        prior = _prior_cov(M, target_sigma)
        return NetworkCalibration((), tuple(rejected), xy0.copy(), prior, float("nan"), 0)
    idx = [list(names).index(i.name) for i in inits]
    used = np.stack([i.used for i in inits])
    problem = _NetworkProblem(
        inits,
        np.where(vis[idx][..., None], uv[idx], 0.0),
        used,
        _whiteners(cov[idx]),
        xy0,
        float(height),
        float(target_sigma),
    )
    g0 = np.concatenate([np.concatenate([[i.f], i.rvec, i.t]) for i in inits])
    loc0 = xy0.copy() if target_sigma > 0 else np.zeros((M, 0))
    n_res = int(2 * used.sum() + (2 * M if target_sigma > 0 else 0))
    sol = solve_sparse_lm(
        problem,
        g0,
        loc0,
        max_iterations=max_iterations if refine else 0,
        ftol=1e-12,
        n_residuals=n_res,
    )
    g = sol.x_global
    gcov = sol.global_covariance(1.0)
    res = problem.residuals(g, sol.x_local)
    cams = []
    for k, ini in enumerate(inits):
        p = g[_PER_CAMERA * k : _PER_CAMERA * (k + 1)]
        K = intrinsics_to_matrix([p[0], p[0], ini.cx, ini.cy, 0.0])
        R = rotvec_to_matrix(p[1:4])
        pts = problem._points(sol.x_local)[ini.used]
        proj = project_points(pts, p[1:4], p[4:7], K, ini.dist).points
        s = slice(_PER_CAMERA * k, _PER_CAMERA * (k + 1))
        p0 = g0[s]
        cams.append(
            CalibratedCamera(
                name=ini.name,
                K=K,
                dist=ini.dist,
                R=R,
                t=p[4:7].copy(),
                std=np.sqrt(np.maximum(np.diag(gcov)[s], 0.0)),
                residuals=proj - uv[idx[k]][ini.used],
                poses_seen=int(vis[idx[k]].sum()),
                outliers=ini.outliers,
                initial_K=intrinsics_to_matrix([p0[0], p0[0], ini.cx, ini.cy, 0.0]),
                initial_R=rotvec_to_matrix(p0[1:4]),
                initial_t=p0[4:7].copy(),
            )
        )
    if target_sigma > 0:
        targets_out = sol.x_local.copy()
        tcov = sol.local_covariance(1.0)
    else:
        targets_out, tcov = xy0.copy(), _prior_cov(M, 0.0)
    pix = res[:, : 2 * len(inits)]
    rms = float(np.sqrt(np.sum(pix**2) / max(used.sum(), 1)))
    return NetworkCalibration(
        cameras=tuple(cams),
        rejected=tuple(rejected),
        targets=targets_out,
        target_cov=tcov,
        rms=rms,
        iterations=sol.iterations,
    )


def _prior_cov(m: int, sigma: float) -> Array:
    return np.broadcast_to(sigma**2 * np.eye(2), (m, 2, 2)).copy()
