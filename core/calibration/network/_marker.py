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

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.calibration.network._intrinsics_prior import IntrinsicsPrior
from core.calibration.network._marker_image import disc_centre_offset, disc_image_area
from core.calibration.network._marker_layout import MarkerLayout, check_detections, marker_places
from core.calibration.network._marker_problem import MarkerProblem, ProblemCamera, chol_whitener
from core.calibration.network._odometry import OdometryPrior, compose_increments, increment_jacobian
from core.calibration.network._records import CalibratedCamera, NetworkCalibration, RejectedCamera
from core.calibration.pose import estimate_plane_pose
from core.errors import ConvergenceError, DegenerateConfiguration, InvalidInput, NotEnoughPoints
from core.geometry.camera import project_points
from core.geometry.rotations import matrix_to_rotvec
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]

_POSE_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")


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
) -> ProblemCamera | RejectedCamera:
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
    return ProblemCamera(name, index, prior, matrix_to_rotvec(pose.R), t, seen.copy())


def _grow(
    names: Sequence[str],
    intrinsics: Sequence[IntrinsicsPrior],
    uv: Array,
    vis: NDArray[np.bool_],
    cov: Array,
    odometry: OdometryPrior,
    layout: MarkerLayout,
    min_poses: int,
    min_spread: float,
    max_iterations: int,
    window: int = 15,
) -> tuple[list[ProblemCamera], list[RejectedCamera], Array]:
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
    cams: dict[int, ProblemCamera] = {}
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
        problem = MarkerProblem(
            in_cams,
            np.where(vis[order, :n, None], uv[order, :n], 0.0),
            chol_whitener(cov[order, :n]),
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
    heights, offsets, radii = marker_places(height, offset, radius)
    n_markers = len(heights)
    uv, vis, cov = check_detections(
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
    layout = MarkerLayout.of(M, offsets, heights, radii)
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
    W = chol_whitener(cov[idx])
    pix = np.where(vis[idx][..., None], uv[idx], 0.0)
    g = g_init
    iterations = 0
    rounds = 5
    for round_ in range(rounds):
        problem = MarkerProblem(cams, pix, W, used, odometry, layout)
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
        params = problem.unpack(g, k)
        K, d, rv, t = params
        u = used[k]
        pred = project_points(X[u], rv, t, K, d).points
        pred = pred + disc_centre_offset(X[u], rv, t, K, d, layout.radius[u])
        resid = pred - uv[cm.index][u]
        sq_px += float(np.sum(resid**2))
        sq_w += float(np.sum(np.einsum("mij,mj->mi", W[k][u], resid) ** 2))
        out.append(
            CalibratedCamera.refined(
                cm.name,
                params,
                problem.unpack(x0, k),
                gcov,
                slice(problem.start[k], problem.start[k + 1]),
                residuals=resid,
                poses_seen=int(vis[cm.index].reshape(M, -1).any(axis=1).sum()),
                outliers=int(vis[cm.index].sum() - u.sum()),
                parameter_names=(*cm.prior.names, *_POSE_NAMES),
                pose_index=layout.stop[u],
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
