"""Calibrating a camera network by driving a marker over the floor (02 §1, marker kind).

The robot carries a marker at a known height h and offset in its frame, and drives from a known
start pose (which defines the world frame) through M stops; at each stop every camera that sees
the marker gives one detection (pixel and covariance). Each camera's intrinsics and distortion
come from its own calibration (a chessboard shown to it, core.calibration.calibrate_camera)
with their covariance; the robot's poses come from its odometry, as independent increments
between stops with their covariance (`odometry_prior`), so the absolute poses carry the
odometry's correlated covariance.

The robot may carry several markers at different heights (for example its top disc at 0.36 m
and a second disc on a thin mast at 1.2 m, core.sim's `mast_marker`). With one marker, the
points a camera sees lie on one plane, and its tilt rests on the floor distances between its
stops, that is on the odometry: a camera alone in its room (one whose stops no other camera
sees) is then left with a few tenths of a degree of tilt error (Cramer-Rao bound 0.25-0.75 deg
over a 5-minute drive in the default home's bedroom). The image of a marker above another is
a vertical segment at every stop, which gives the tilt directly: the bound falls to 0.1-0.45
deg, and positions within the network's frame from 1-5 cm to 0.3-0.9 cm.

1. Initialisation per camera: the detections undistorted with the camera's own intrinsics and
   the marker's floor positions give its pose (a plane pose,
   core.calibration.estimate_plane_pose). The odometry drifts (up to a metre and ten degrees
   over a long drive), so the drive is taken in growing windows of stops, each solved as in
   step 2 from the previous one's solution; a camera enters with the corrected positions of
   the stops it saw (`_grow`). A camera that saw fewer than `min_poses` stops, or
   whose stops are collinear (the smaller principal standard deviation of their floor positions
   below `min_spread` metres: the plane pose is undetermined), is rejected by name with the
   reason; the others still calibrate.
2. Joint maximum a-posteriori refinement by LM (core.optim, dense over every unknown: the
   increments couple all poses after them). Unknowns: per camera its free intrinsics and
   distortion theta_c and its pose (rvec_c, t_c); the increment corrections eps_j (M, 3). It
   minimises

       sum_(c, j seen) || W_cj (pi_c(X_j(inc + eps)) - u_cj) ||^2
           + sum_c || L_c^T (theta_c - theta_c0) ||^2 + sum_j || L_j^T eps_j ||^2,

   with X_j the marker at pose j (start composed with the corrected increments), W_cj^T W_cj
   the inverse detection covariance, L_c L_c^T and L_j L_j^T the inverse prior covariances.
   The start pose is held fixed, so the world frame has no gauge freedom left. Detections whose
   whitened residual exceeds `outlier_sigma` are dropped and the problem solved again. So are
   the images of a partly hidden marker (an edge of furniture across the disc): its centroid
   moves by up to a radius while the detector, which sees a clean convex blob, reports a
   covariance of hundredths of a pixel, and at a stop only one camera sees, the robot's pose
   there absorbs the error instead of exposing it (the residual stays small; the camera's tilt
   takes the bias). Given the detected `areas`, a detection whose covered area falls short of
   the area the estimated camera projects the disc of known radius to, by more than
   `hidden_fraction` of it and `hidden_px` pixels, is dropped (`disc_image_area`).
3. Covariance: the inverse Gauss-Newton information, scaled by the measured residual variance
   SSE / (N - d). `marker_network_bound` evaluates the same information at the true parameters:
   the Cramer-Rao bound of the calibration (unit residual variance).

Units: metres, radians, pixels.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.calibration.network._odometry import (
    OdometryPrior,
    compose_increments,
    increment_jacobian,
)
from core.calibration.network._records import CalibratedCamera, NetworkCalibration, RejectedCamera
from core.calibration.pose import estimate_plane_pose
from core.calibration.zhang import CameraCalibration
from core.errors import ConvergenceError, DegenerateConfiguration, InvalidInput, NotEnoughPoints
from core.geometry.camera import (
    DISTORTION_NAMES,
    intrinsics_to_matrix,
    left_jacobian_so3,
    project_points,
)
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix, wrap_angle
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]

#: The intrinsic parameters a camera's own calibration may supply, in the order used here.
INTRINSIC_PARAMETERS: tuple[str, ...] = ("fx", "fy", "cx", "cy", *DISTORTION_NAMES)
_POSE_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")


@dataclass(frozen=True)
class IntrinsicsPrior:
    """A camera's own calibration as a prior: K (3, 3) pixels, dist (5,) OpenCV coefficients,
    `names` the estimated parameters among INTRINSIC_PARAMETERS (the others are held at their
    values) and `cov` (p, p) their covariance (pixels^2; unitless for distortion)."""

    K: Array
    dist: Array
    names: tuple[str, ...]
    cov: Array

    @classmethod
    def from_calibration(cls, cal: CameraCalibration) -> IntrinsicsPrior:
        """Return the prior of a Zhang calibration (its estimate and covariance; skew, when it
        was estimated, is held at its value)."""
        names = tuple(n for n in INTRINSIC_PARAMETERS if n in cal.parameter_names)
        idx = [cal.parameter_names.index(n) for n in names]
        return cls(cal.K.copy(), cal.dist.copy(), names, cal.covariance[np.ix_(idx, idx)].copy())

    @property
    def values(self) -> Array:
        """The estimated parameters' values (p,), in the order of `names`."""
        full = np.concatenate([[self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]], self.dist])
        return full[[INTRINSIC_PARAMETERS.index(n) for n in self.names]]


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


@dataclass(frozen=True)
class _Cam:
    name: str
    index: int  # into the caller's cameras
    prior: IntrinsicsPrior
    rvec: Array
    t: Array
    seen: NDArray[np.bool_]


def _chol_whitener(cov: Array) -> Array:
    """Return W (..., n, n) with W^T W = cov^-1."""
    return np.swapaxes(np.linalg.cholesky(np.linalg.inv(cov)), -1, -2)


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


def _disc_rim_image(
    X: Array, rvec: Array, t: Array, K: Array, dist: Array, radius: Array, n: int
) -> Array:
    """Return the distorted images (M, n, 2) of n points evenly spread on the rim of each
    horizontal disc of `radius` (M,) metres centred at X (M, 3)."""
    phi = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    rim = np.stack([np.cos(phi), np.sin(phi), np.zeros(n)], axis=1)
    pts = X[:, None, :] + radius[:, None, None] * rim[None]  # (M, n, 3)
    return project_points(pts.reshape(-1, 3), rvec, t, K, dist).points.reshape(len(X), n, 2)


def _polygon_moments(uv: Array) -> tuple[Array, Array]:
    """Return the areas (M,) and area centroids (M, 2) of closed polygons (M, n, 2) (the
    shoelace formula and its first moments)."""
    x, y = uv[..., 0], uv[..., 1]
    x1, y1 = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)
    cross = x * y1 - x1 * y
    a = 0.5 * cross.sum(axis=1)
    safe = np.where(a == 0.0, 1.0, a)
    c = np.stack([((x + x1) * cross).sum(axis=1), ((y + y1) * cross).sum(axis=1)], axis=1)
    return np.abs(a), c / (6.0 * safe[:, None])


def disc_centre_offset(
    X: Array, rvec: Array, t: Array, K: Array, dist: Array, radius: ArrayLike, n: int = 48
) -> Array:
    """Return the pixel offset (M, 2) of the area centroid of a horizontal disc's image from
    the image of its centre, for discs of `radius` metres (one value, or (M,)) centred at
    X (M, 3): what a blob detector's centroid measures (core.localization.detect).

    Two effects move it, both second order in the disc's size. Perspective: the disc's ideal
    image is an ellipse whose centre is not the image of the disc's centre (Hartley & Zisserman
    eq. 2.13; ~0.1 px for the twin's 5 cm marker at 3 m). Lens distortion: the image of that
    ellipse through a curved map is no ellipse, and its area centroid is not the distorted
    centre; with the default home's k1 = -0.28 it is c + k1 f x rho^2 off (x the normalised
    distance from the axis, rho the disc's radius in focal units): 0.2-0.6 px for the mast's
    8 cm disc at 1.5-2.5 m, off the axis. Both are in the area centroid of the distorted
    image of the rim, here an inscribed polygon of n points (an affine image of a regular
    polygon has its ellipse's centre; what the map adds beyond affine is O(n^-2) of the
    offset)."""
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(X),))
    out = np.zeros((len(X), 2))
    on = r > 0
    if not np.any(on):
        return out
    uv = _disc_rim_image(X[on], rvec, t, K, dist, r[on], n)
    _, centroid = _polygon_moments(uv)
    out[on] = centroid - project_points(X[on], rvec, t, K, dist).points
    return out


def disc_image_area(
    X: Array, rvec: Array, t: Array, K: Array, dist: Array, radius: ArrayLike, n: int = 48
) -> Array:
    """Return the image area (M,) in pixels of horizontal discs of `radius` (metres; one
    value, or (M,)) centred at X (M, 3), seen by the camera (rvec, t world-to-camera, K,
    dist): the area of the distorted images of n points on each rim (shoelace formula; the
    inscribed polygon's area, short of the ellipse's by about 2 pi^2 / (3 n^2), 0.3 % for
    n = 48)."""
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(X),))
    area, _ = _polygon_moments(_disc_rim_image(X, rvec, t, K, dist, r, n))
    return area


@dataclass(frozen=True)
class _Layout:
    """Where each observation column's marker is: the robot carries K markers, and column
    n = j K + k holds marker k at stop j: `stop` (N,) the stop, `offset` (N, 2) and `height`
    (N,) the marker's place on the robot, `radius` (N,) its disc's radius, `first` (N,) the
    columns of marker 0 (one height: what a camera's plane pose starts from)."""

    stop: NDArray[np.intp]
    offset: Array
    height: Array
    radius: Array
    first: NDArray[np.bool_]
    markers: int

    @classmethod
    def of(cls, stops: int, offsets: Array, heights: Array, radii: Array) -> _Layout:
        k = len(heights)
        return cls(
            stop=np.repeat(np.arange(stops), k),
            offset=np.tile(offsets, (stops, 1)),
            height=np.tile(heights, stops),
            radius=np.tile(radii, stops),
            first=np.tile(np.arange(k) == 0, stops),
            markers=k,
        )

    def head(self, stops: int) -> _Layout:
        """The layout of the first `stops` stops."""
        n = stops * self.markers
        return _Layout(
            self.stop[:n],
            self.offset[:n],
            self.height[:n],
            self.radius[:n],
            self.first[:n],
            self.markers,
        )

    def points(self, poses: Array) -> tuple[Array, Array]:
        """Return the markers' world points (N, 3) at the robot poses (M, 3) and d X / d pose
        of their stops (N, 3, 3)."""
        P = poses[self.stop]
        c, s = np.cos(P[:, 2]), np.sin(P[:, 2])
        o = self.offset
        ro = np.stack([c * o[:, 0] - s * o[:, 1], s * o[:, 0] + c * o[:, 1]], 1)
        X = np.column_stack([P[:, :2] + ro, self.height])
        dX = np.zeros((len(P), 3, 3))
        dX[:, 0, 0] = dX[:, 1, 1] = 1.0
        dX[:, 0, 2] = -ro[:, 1]
        dX[:, 1, 2] = ro[:, 0]
        return X, dX


class _MarkerProblem:
    """The joint refinement (module docstring, step 2) for core.optim.solve_sparse_lm, as one
    dense block: global = every camera's (free intrinsics, rvec, t), then eps (3 M)."""

    def __init__(
        self,
        cams: Sequence[_Cam],
        pixels: Array,
        whiten: Array,
        used: NDArray[np.bool_],
        odometry: OdometryPrior,
        layout: _Layout,
    ) -> None:
        self.cams = cams
        self.layout = layout
        self.uv = pixels  # (C, N, 2)
        self.W = whiten  # (C, N, 2, 2)
        self.used = used  # (C, N)
        self.odo = odometry
        sizes = [len(c.prior.names) + 6 for c in cams]
        self.start = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        self.M = len(odometry.increments)
        self.N = len(layout.stop)
        self.n_cam = int(self.start[-1])
        self.n = self.n_cam + 3 * self.M
        self.Lc = [_chol_whitener(c.prior.cov) if len(c.prior.names) else None for c in cams]
        self.Lj = _chol_whitener(odometry.cov)  # (M, 3, 3)

    def x0(self) -> Array:
        parts = [np.concatenate([c.prior.values, c.rvec, c.t]) for c in self.cams]
        return np.concatenate([*parts, np.zeros(3 * self.M)])

    def unpack(self, g: Array, k: int) -> tuple[Array, Array, Array, Array]:
        """Return K (3, 3), dist (5,), rvec (3,), t (3,) of camera k."""
        c = self.cams[k]
        p = g[self.start[k] : self.start[k + 1]]
        full = np.concatenate(
            [[c.prior.K[0, 0], c.prior.K[1, 1], c.prior.K[0, 2], c.prior.K[1, 2]], c.prior.dist]
        )
        full[[INTRINSIC_PARAMETERS.index(n) for n in c.prior.names]] = p[:-6]
        K = intrinsics_to_matrix([full[0], full[1], full[2], full[3], c.prior.K[0, 1]])
        return K, full[4:9].copy(), p[-6:-3], p[-3:]

    def poses(self, g: Array) -> Array:
        """Return the robot poses (M, 3) for the corrected increments."""
        eps = g[self.n_cam :].reshape(self.M, 3)
        return compose_increments(self.odo.start, self.odo.increments + eps)

    def marker(self, poses: Array) -> tuple[Array, Array]:
        """Return the markers' world points (N, 3) and d X / d pose (N, 3, 3) (`_Layout`)."""
        return self.layout.points(poses)

    def jacobians(self, g: Array, loc: Array) -> tuple[Array, Array, Array]:
        C, M, N = len(self.cams), self.M, self.N
        poses = self.poses(g)
        X, dX = self.marker(poses)
        eps = g[self.n_cam :].reshape(M, 3)
        D = increment_jacobian(self.odo.start, self.odo.increments + eps).reshape(M, 3, 3 * M)
        D = D[self.layout.stop]  # (N, 3, 3 M)
        n_int = [len(c.prior.names) for c in self.cams]
        rows = 2 * C * N + sum(n_int) + 3 * M
        res = np.zeros(rows)
        J = np.zeros((rows, self.n))
        r = 0
        for k, cam in enumerate(self.cams):
            K, d, rv, t = self.unpack(g, k)
            pr = project_points(X, rv, t, K, d, jacobians=True)
            assert pr.d_intrinsics is not None and pr.d_distortion is not None
            assert pr.d_pose is not None
            w = self.used[k][:, None, None] * self.W[k]  # (N, 2, 2)
            # The area-centroid offset is second order in the disc's size: it enters the
            # prediction, its derivatives are left out of the Jacobian.
            pred = pr.points + disc_centre_offset(X, rv, t, K, d, self.layout.radius)
            res[r : r + 2 * N] = np.einsum("mij,mj->mi", w, pred - self.uv[k]).ravel()
            d_all = np.concatenate([pr.d_intrinsics[..., :4], pr.d_distortion], axis=-1)
            sel = [INTRINSIC_PARAMETERS.index(n) for n in cam.prior.names]
            jc = np.concatenate([d_all[..., sel], pr.d_pose], axis=-1)  # (N, 2, P)
            J[r : r + 2 * N, self.start[k] : self.start[k + 1]] = (w @ jc).reshape(2 * N, -1)
            # Xc = R X + t: d pixel / d X = (d pixel / d t) R.
            dpix = pr.d_pose[..., 3:6] @ rotvec_to_matrix(rv) @ dX  # (N, 2, 3)
            J[r : r + 2 * N, self.n_cam :] = np.einsum("mab,mbk->mak", w @ dpix, D).reshape(
                2 * N, -1
            )
            r += 2 * N
        for k, cam in enumerate(self.cams):
            L = self.Lc[k]
            if L is None:
                continue
            p = g[self.start[k] : self.start[k] + n_int[k]]
            res[r : r + n_int[k]] = L @ (p - cam.prior.values)
            J[r : r + n_int[k], self.start[k] : self.start[k] + n_int[k]] = L
            r += n_int[k]
        res[r:] = np.einsum("mij,mj->mi", self.Lj, eps).ravel()
        for j in range(M):
            J[r + 3 * j : r + 3 * j + 3, self.n_cam + 3 * j : self.n_cam + 3 * j + 3] = self.Lj[j]
        return res[None], J[None], np.zeros((1, rows, 0))

    def residuals(self, g: Array, loc: Array) -> Array:
        return self.jacobians(g, loc)[0]

    def pixel_rows(self, res: Array) -> Array:
        """Return the whitened pixel residuals (C, N, 2) from a residual vector."""
        C = len(self.cams)
        return res.ravel()[: 2 * C * self.N].reshape(C, self.N, 2)


def _init_camera(
    name: str,
    index: int,
    prior: IntrinsicsPrior,
    xy: Array,
    uv: Array,
    seen: NDArray[np.bool_],
    height: float,
    min_poses: int,
    min_spread: float,
) -> _Cam | RejectedCamera:
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
    try:
        pose = estimate_plane_pose(pts, uv[seen], prior.K, prior.dist)
    except (DegenerateConfiguration, NotEnoughPoints, ConvergenceError) as exc:
        return RejectedCamera(name, f"the camera's pose could not be initialised: {exc}", n)
    # The plane frame is the world shifted up by h: Xc = R (X - h e3) + t.
    t = pose.t - pose.R[:, 2] * height
    return _Cam(name, index, prior, matrix_to_rotvec(pose.R), t, seen.copy())


def _grow(
    names: Sequence[str],
    intrinsics: Sequence[IntrinsicsPrior],
    uv: Array,
    vis: NDArray[np.bool_],
    cov: Array,
    odometry: OdometryPrior,
    layout: _Layout,
    min_poses: int,
    min_spread: float,
    max_iterations: int,
    window: int = 15,
) -> tuple[list[_Cam], list[RejectedCamera], Array]:
    """Return the cameras that can be calibrated, those rejected and a starting point for the
    joint refinement, found stop by stop: the odometry drifts (metres and degrees over a long
    drive), so cameras initialised from the raw odometry can start too far from each other for
    the refinement to converge. The drive is taken in growing windows of `window` stops; each
    window's problem is solved from the previous window's solution (its new stops placed by
    the odometry from the last corrected pose), and a camera enters when the stops it saw
    within the window first suffice, initialised from the corrected positions of its images
    of the first marker (one height: a plane pose)."""
    C, M = len(names), len(odometry.increments)
    eps = np.zeros((M, 3))
    state: dict[int, Array] = {}  # camera index -> its global parameters
    cams: dict[int, _Cam] = {}
    last_reject: dict[int, RejectedCamera] = {}
    ends = [*range(window, M, window), M]
    for end in ends:
        sub = OdometryPrior(odometry.start, odometry.increments[:end], odometry.cov[:end])
        lay = layout.head(end)
        n = len(lay.stop)
        poses = compose_increments(sub.start, sub.increments + eps[:end])
        X, _ = lay.points(poses)
        first = lay.first
        for k in range(C):
            if k in cams:
                continue
            r = _init_camera(
                names[k],
                k,
                intrinsics[k],
                X[first, :2],
                uv[k, :n][first],
                vis[k, :n][first],
                float(lay.height[0]),
                min_poses,
                min_spread,
            )
            if isinstance(r, RejectedCamera):
                last_reject[k] = r
                continue
            cams[k] = r
            state[k] = np.concatenate([r.prior.values, r.rvec, r.t])
            last_reject.pop(k, None)
        if not cams or max_iterations == 0:
            continue
        order = sorted(cams)
        in_cams = [cams[k] for k in order]
        problem = _MarkerProblem(
            in_cams,
            np.where(vis[order, :n, None], uv[order, :n], 0.0),
            _chol_whitener(cov[order, :n]),
            vis[order, :n],
            sub,
            lay,
        )
        g0 = np.concatenate([*(state[k] for k in order), eps[:end].ravel()])
        sol = solve_sparse_lm(problem, g0, np.zeros((1, 0)), max_iterations=max_iterations)
        for i, k in enumerate(order):
            state[k] = sol.x_global[problem.start[i] : problem.start[i + 1]].copy()
        eps[:end] = sol.x_global[problem.n_cam :].reshape(end, 3)
    order = sorted(cams)
    g = np.concatenate([*(state[k] for k in order), eps.ravel()]) if order else eps.ravel()
    return [cams[k] for k in order], [last_reject[k] for k in sorted(last_reject)], g


def _markers(height: ArrayLike, offset: ArrayLike, radius: ArrayLike) -> tuple[Array, Array, Array]:
    """Return the K markers' heights (K,), offsets (K, 2) and radii (K,) from one value each
    or one per marker; InvalidInput when they disagree or are not finite."""
    try:
        h = np.atleast_1d(np.asarray(height, dtype=np.float64)).reshape(-1)
        o = np.asarray(offset, dtype=np.float64)
        r = np.atleast_1d(np.asarray(radius, dtype=np.float64)).reshape(-1)
    except (TypeError, ValueError):
        raise InvalidInput("marker heights, offsets and radii must be numbers (metres)") from None
    k = len(h)
    if k == 0 or o.size != 2 * k or len(r) not in (1, k):
        raise InvalidInput(
            f"need one (x, y) offset per marker height and one radius or one per marker: "
            f"{k} heights, offsets {o.shape}, {len(r)} radii"
        )
    o = o.reshape(k, 2)
    r = np.broadcast_to(r, (k,)).copy()
    if not (np.all(np.isfinite(h)) and np.all(np.isfinite(o)) and np.all(np.isfinite(r))):
        raise InvalidInput("marker heights, offsets and radii must be finite")
    if np.any(r < 0):
        raise InvalidInput("marker radii must be >= 0 metres")
    return h, o, r


def _check_inputs(
    names: Sequence[str],
    intrinsics: Sequence[IntrinsicsPrior],
    pixels: ArrayLike,
    visible: ArrayLike,
    odometry: OdometryPrior,
    pixel_cov: ArrayLike | None,
    pixel_sigma: float,
    markers: int = 1,
) -> tuple[Array, NDArray[np.bool_], Array]:
    """Return pixels (C, N, 2), visibility (C, N) and covariances (C, N, 2, 2) with N = M K
    columns, column j K + k marker k at stop j (`_Layout`), from pixels (C, M, 2) and visible
    (C, M) for one marker or (C, M, K, 2) and (C, M, K) for K."""
    C, K = len(names), markers
    M = len(odometry.increments)
    N = M * K
    try:
        uv = np.asarray(pixels, dtype=np.float64)
        vis = np.asarray(visible, dtype=bool)
    except (TypeError, ValueError):
        raise InvalidInput("pixels must be numbers and visible booleans") from None
    if K == 1 and uv.shape == (C, M, 2):
        uv = uv.reshape(C, M, 1, 2)
    if K == 1 and vis.shape == (C, M):
        vis = vis.reshape(C, M, 1)
    if len(intrinsics) != C or uv.shape != (C, M, K, 2) or vis.shape != (C, M, K):
        shape = "(C, M, 2) and (C, M)" if K == 1 else f"(C, M, {K}, 2) and (C, M, {K})"
        raise InvalidInput(
            f"need one intrinsics prior per camera, pixels and visible {shape} for C = {C} "
            f"names, M = {M} odometry stops and {K} marker(s); got {len(intrinsics)} priors, "
            f"{uv.shape}, {vis.shape}"
        )
    uv = uv.reshape(C, N, 2)
    vis = vis.reshape(C, N)
    if not np.all(np.isfinite(uv[vis])):
        raise InvalidInput("the visible pixels must be finite")
    if pixel_cov is None:
        if not pixel_sigma > 0:
            raise InvalidInput(f"pixel_sigma must be > 0 pixels, got {pixel_sigma}")
        cov = np.broadcast_to(pixel_sigma**2 * np.eye(2), (C, N, 2, 2)).copy()
    else:
        try:
            cov = np.asarray(pixel_cov, dtype=np.float64).reshape(C, N, 2, 2).copy()
        except (TypeError, ValueError):
            raise InvalidInput(f"pixel_cov must be 2 x 2 px^2 per pixel, {C * N} of them") from None
        cov[~vis] = np.eye(2)
        if not np.all(np.isfinite(cov)) or np.any(np.linalg.eigvalsh(cov)[..., 0] <= 0):
            raise InvalidInput("pixel_cov must be positive definite where visible")
    return uv, vis, cov


def calibrate_network_marker(
    names: Sequence[str],
    intrinsics: Sequence[IntrinsicsPrior],
    pixels: ArrayLike,
    visible: ArrayLike,
    odometry: OdometryPrior,
    height: ArrayLike,
    *,
    offset: ArrayLike = (0.0, 0.0),
    radius: ArrayLike = 0.0,
    pixel_cov: ArrayLike | None = None,
    pixel_sigma: float = 0.5,
    areas: ArrayLike | None = None,
    min_poses: int = 6,
    min_spread: float = 0.15,
    outlier_sigma: float = 5.0,
    hidden_fraction: float = 0.15,
    hidden_px: float = 8.0,
    refine: bool = True,
    max_iterations: int = 50,
) -> NetworkCalibration:
    """Return the calibrated network from a marker driven over the floor (module docstring).

    names: C camera names; intrinsics: C priors from each camera's own calibration; pixels
    (C, M, 2) detected marker centres (distorted pixels, anything where unseen); visible (C, M)
    bool; odometry: the start pose and the M increments between stops with their covariance
    (`odometry_prior`); height: the marker's Z (metres); offset: the marker's (x, y) in the
    robot frame (metres); radius: the marker disc's radius (metres; 0 for a point-like marker
    such as an LED): a blob detector measures the area centroid of the disc's distorted
    image, which the model predicts (`disc_centre_offset`). pixel_cov (C, M, 2, 2) px^2 per
    detection, or pixel_sigma (px) for all. areas (C, M): each detection's covered area in
    pixels (a blob detector's; NaN where unknown), which with `radius` > 0 drops the images of
    a partly hidden marker (module docstring, step 2).

    Several markers at different heights (K of them: `height` (K,), `offset` (K, 2), `radius`
    one or (K,); pixels (C, M, K, 2), visible, areas (C, M, K), pixel_cov (C, M, K, 2, 2)):
    the image of a marker above another gives each camera its tilt at every stop, where one
    marker's give it only through the odometry between the stops (module docstring). The
    first marker starts each camera's plane pose.

    A camera that cannot be calibrated is listed in `rejected`, never raised; InvalidInput for
    inconsistent shapes or values.
    """
    heights, offsets, radii = _markers(height, offset, radius)
    n_markers = len(heights)
    uv, vis, cov = _check_inputs(
        names, intrinsics, pixels, visible, odometry, pixel_cov, pixel_sigma, n_markers
    )
    if not (0.0 <= hidden_fraction < 1.0 and hidden_px >= 0.0):
        raise InvalidInput("need 0 <= hidden_fraction < 1 and hidden_px >= 0")
    area = None
    if areas is not None:
        try:
            area = np.asarray(areas, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidInput("areas must be numbers of pixels, like visible") from None
        if area.size != vis.size:
            raise InvalidInput(f"areas must be shaped like visible, got {area.shape}")
        area = area.reshape(vis.shape)
        if np.any(area[vis] < 0):
            raise InvalidInput("areas must be >= 0 pixels (NaN where unknown)")
    M = len(odometry.increments)
    layout = _Layout.of(M, offsets, heights, radii)
    recorded = odometry.poses
    cams, rejected, g_init = _grow(
        names,
        intrinsics,
        uv,
        vis,
        cov,
        odometry,
        layout,
        min_poses,
        min_spread,
        max_iterations if refine else 0,
    )
    prior_cov = odometry.pose_covariance()
    if not cams:
        tcov = np.stack([prior_cov[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] for j in range(M)])
        nan = float("nan")
        return NetworkCalibration((), tuple(rejected), recorded, tcov, nan, nan, nan, 0)
    idx = [cm.index for cm in cams]
    used = vis[idx].copy()
    W = _chol_whitener(cov[idx])
    pix = np.where(vis[idx][..., None], uv[idx], 0.0)
    g = g_init
    iterations = 0
    rounds = 5
    for round_ in range(rounds):
        problem = _MarkerProblem(cams, pix, W, used, odometry, layout)
        start = g
        n_res = int(2 * used.sum() + sum(len(cm.prior.names) for cm in cams) + 3 * M)
        sol = solve_sparse_lm(
            problem,
            start,
            np.zeros((1, 0)),
            max_iterations=max_iterations if refine else 0,
            ftol=1e-12,
            n_residuals=n_res,
        )
        g, iterations = sol.x_global, iterations + sol.iterations
        e = np.linalg.norm(problem.pixel_rows(problem.residuals(g, sol.x_local)), axis=-1)
        keep = used.copy()
        if area is not None and np.any(radii > 0):
            # First the hidden markers, judged by their area alone: until they are gone, the
            # residuals of good detections at the same stops are pulled with them.
            X, _ = problem.marker(problem.poses(g))
            for k, cm in enumerate(cams):
                K, d, rv, t = problem.unpack(g, k)
                expected = disc_image_area(X, rv, t, K, d, layout.radius)
                short = expected - area[cm.index]  # NaN (unknown) compares False
                hidden = short > np.maximum(hidden_px, hidden_fraction * expected)
                keep[k] &= ~(hidden & (layout.radius > 0))
        if np.array_equal(keep, used):
            keep &= e <= outlier_sigma
        if np.array_equal(keep, used) or round_ == rounds - 1:
            break  # (the last round's answer stands with the detections it used)
        used = keep
    assert g is not None
    s2 = sol.residual_variance
    gcov = sol.global_covariance(s2)
    poses = problem.poses(g)
    X, _ = problem.marker(poses)
    out = []
    sq_px = sq_w = 0.0
    x0 = problem.x0()
    for k, cm in enumerate(cams):
        K, d, rv, t = problem.unpack(g, k)
        u = used[k]
        pred = project_points(X[u], rv, t, K, d).points
        pred = pred + disc_centre_offset(X[u], rv, t, K, d, layout.radius[u])
        resid = pred - uv[cm.index][u]
        sq_px += float(np.sum(resid**2))
        sq_w += float(np.sum(np.einsum("mij,mj->mi", W[k][u], resid) ** 2))
        K0, _, rv0, t0 = problem.unpack(x0, k)
        sl = slice(problem.start[k], problem.start[k + 1])
        out.append(
            CalibratedCamera(
                name=cm.name,
                K=K,
                dist=d,
                R=rotvec_to_matrix(rv),
                t=t.copy(),
                std=np.sqrt(np.maximum(np.diag(gcov)[sl], 0.0)),
                residuals=resid,
                poses_seen=int(vis[cm.index].reshape(M, -1).any(axis=1).sum()),
                outliers=int(vis[cm.index].sum() - u.sum()),
                initial_K=K0,
                initial_R=rotvec_to_matrix(rv0),
                initial_t=t0.copy(),
                parameter_names=(*cm.prior.names, *_POSE_NAMES),
                pose_index=layout.stop[u],
                covariance=gcov[sl, sl].copy(),
                detections=int(vis[cm.index].sum()),
            )
        )
    # Covariance of the poses: D Cov(eps) D^T per pose (the blocks on the diagonal).
    D = increment_jacobian(odometry.start, odometry.increments + g[problem.n_cam :].reshape(M, 3))
    D2 = D.reshape(3 * M, 3 * M)
    ce = gcov[problem.n_cam :, problem.n_cam :]
    pc = D2 @ ce @ D2.T
    tcov = np.stack([pc[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] for j in range(M)])
    n = max(int(used.sum()), 1)
    return NetworkCalibration(
        cameras=tuple(out),
        rejected=tuple(rejected),
        targets=poses,
        target_cov=tcov,
        rms_px=float(np.sqrt(sq_px / n)),
        rms_whitened=float(np.sqrt(sq_w / (2 * n))),
        residual_variance=float(s2),
        iterations=iterations,
    )


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
    heights, offsets, radii = _markers(height, offset, 0.0)
    n_markers = len(heights)
    shape = (C, M, 2) if n_markers == 1 else (C, M, n_markers, 2)
    uv, vis, cov = _check_inputs(
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
        cams.append(_Cam(names[k], k, truth, matrix_to_rotvec(Rs[k]), ts[k], vis[k]))
    problem = _MarkerProblem(
        cams, uv, _chol_whitener(cov), vis, odo, _Layout.of(M, offsets, heights, radii)
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
