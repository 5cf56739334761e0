"""Place a real camera from floor points: its pose (and focal length when unknown) from pixels
whose world positions are known.

An installer clicks N >= 4 points on a camera's image and the same points on the floor plan
(or measures them with a tape). The points give the camera's pose T_world_camera; when the
camera's intrinsics are not known yet the focal length too, with square pixels, no skew, no
distortion and the principal point at the image's centre ((W - 1) / 2, (H - 1) / 2), the model
of the single-view calibration (core.calibration.single_view; Zhang 2000, sec. 3.1).

A clicked pair can be wrong (the wrong tile corner, a swapped pair), so the fit is robust:

1. hypotheses: every 4-point sample of the points that share one height (the floor, usually)
   gives a world-plane homography (exact, H&Z alg. 4.1 on normalised points), then the focal
   length by the closed form of `focal_from_homography` when it is unknown, then the pose by
   `pose_from_homography` (Zhang 2000, eq. 3-4, appendix C);
2. least median of squares (Rousseeuw 1984): the hypotheses whose median squared reprojection
   error over all points is smallest are each refined on the points they fit (local
   optimisation, Chum, Matas & Kittler 2003) and the refined one of least median wins; its
   robust scale (`_robust_sigma`, Rousseeuw & Leroy 1987, eq. 4.1.9) sets the inlier threshold
   at 3.5 sigma on a pixel's error, never below `min_threshold_px` (a careful click is good to
   about a pixel, so a perfect fit must not reject a 1.5 px click);
3. refinement: the reprojection error sum_i ||x_i - pi(K, dist, R, t; X_i)||^2 of the inliers is
   minimised over (f, rvec, t), or (rvec, t) with known intrinsics, by the project's sparse LM
   (core.optim) with the distortion fixed: the maximum-likelihood estimate under i.i.d. Gaussian
   pixel noise. The inliers are then chosen again (`_consistent`): each pair's residual is
   tested as a prediction of the others (its leverage removed) against a robust scale, until
   the set no longer changes.

A wrong pair is found when N >= 6 (at N = 4 or 5 a wrong pair can still be fitted by a
different camera). The covariance of (f, rvec, t) is the Gauss-Newton inverse
sigma^2 (J^T J)^-1 with sigma^2 the inliers' residual variance (H&Z eq. A6.9), propagated to the
camera's position and orientation in the world frame by the Jacobian of that map.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_matrix, as_points
from core.calibration.pose import pose_from_homography
from core.calibration.single_view import focal_from_homography
from core.errors import DegenerateConfiguration, InvalidInput, NotEnoughPoints
from core.geometry.camera import (
    ReprojectionProblem,
    as_distortion,
    intrinsics_to_matrix,
    project_points,
    undistort_points,
)
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix
from core.homography.ransac import _four_point_homographies
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]

# At most this many 4-point samples are scored; all of them when there are fewer. 200 samples
# contain an all-inlier one with probability 1 - 1e-5 at 60 % inliers (1 - (1 - 0.6^4)^200).
MAX_SAMPLES = 200
# Points closer together than this (rms distance to their centroid, metres) are "one spot".
MIN_SPREAD_M = 0.05
# Pixels closer together than this (rms distance to their centroid) are "one spot" on the image.
MIN_SPREAD_PX = 3.0
# A point set whose second principal spread is below this fraction of its first is a line.
COLLINEAR_RATIO = 0.02
# Points within this height (metres) of each other share a plane for the hypotheses.
_HEIGHT_TOL = 1e-3


@dataclass(frozen=True)
class CameraPlacement:
    """A camera placed from floor points.

    T_world_camera: (4, 4), camera-to-world (OpenCV camera frame: x right, y down, z forward);
    K: (3, 3) pixels; dist: (5,) OpenCV distortion (the camera's, or zeros); f_estimated: whether
    the focal length was estimated (no intrinsics given).
    residuals: (N, 2) projected minus clicked pixels of every point, rejected ones included;
    residuals_px: (N,) their lengths; inliers: (N,) bool; rejected: indices of the points left
    out of the fit; rms: sqrt(mean ||e_i||^2) over the inliers, pixels.
    std_position_m: (3,) standard deviations of the camera's centre in the world frame, metres;
    std_rotation_deg: (3,) of the camera's orientation as small rotations about the world's
    x, y, z axes, degrees; std_f_px: of the focal length, pixels (None when not estimated).
    covariance: of (f, rvec, t) (f only when estimated), world-to-camera parametrisation.
    """

    T_world_camera: Array
    K: Array
    dist: Array
    f_estimated: bool
    residuals: Array = field(repr=False)
    residuals_px: Array = field(repr=False)
    inliers: NDArray[np.bool_] = field(repr=False)
    rejected: NDArray[np.intp]
    rms: float
    std_position_m: Array
    std_rotation_deg: Array
    std_f_px: float | None
    covariance: Array = field(repr=False)
    iterations: int = 0


def place_camera(
    world_points: ArrayLike,
    image_points: ArrayLike,
    image_size: tuple[int, int],
    K: ArrayLike | None = None,
    dist: ArrayLike | None = None,
    *,
    min_threshold_px: float = 2.0,
    seed: int | np.random.Generator | None = 0,
) -> CameraPlacement:
    """Return the camera's placement from N >= 4 pixel <-> world correspondences.

    world_points: (N, 3) world (x, y, z) metres, or (N, 2) floor (x, y) with z = 0;
    image_points: (N, 2) distorted pixels; image_size: (W, H) pixels. K (3, 3) and dist (OpenCV,
    up to 5) when the intrinsics are known (the pose alone is estimated, the pixels undistorted
    for the hypotheses); K None: square pixels, centred principal point, no distortion, the
    focal length estimated. At least 4 points must share one height (the floor) for the
    hypotheses. min_threshold_px: the smallest inlier threshold (module docstring); seed: for
    the sample draw when there are more than MAX_SAMPLES samples.

    Raises NotEnoughPoints (N < 4), InvalidInput (shapes, NaN), DegenerateConfiguration (points
    on a line or at one spot, in the world or in the image; a view that fixes no focal length;
    no hypothesis with the points in front of the camera).
    """
    X = _world(world_points)
    uv = as_points(image_points, 2, "image_points", min_count=4)
    if len(X) != len(uv):
        raise InvalidInput(
            f"world_points and image_points differ in length: {len(X)} and {len(uv)}"
        )
    w, h = (int(v) for v in image_size)
    if w <= 0 or h <= 0:
        raise InvalidInput(f"image_size must be positive (W, H), got {image_size}")
    _check_spread(X, "world points", MIN_SPREAD_M, "m")
    _check_spread(uv, "pixels", MIN_SPREAD_PX, "px")
    f_estimated = K is None
    if K is None:
        if dist is not None and np.any(as_distortion(dist)):
            raise InvalidInput("a distortion needs its K; give both or neither")
        cx, cy = 0.5 * (w - 1), 0.5 * (h - 1)
        intr0 = np.array([0.0, 0.0, cx, cy, 0.0])
        d = np.zeros(5)
        ideal = uv
    else:
        Km = as_matrix(K, (3, 3), "K")
        if Km[0, 0] <= 0 or Km[1, 1] <= 0 or Km[1, 0] != 0 or Km[2, 0] != 0 or Km[2, 1] != 0:
            raise InvalidInput("K must be upper triangular with positive focal lengths")
        intr0 = np.array([Km[0, 0], Km[1, 1], Km[0, 2], Km[1, 2], Km[0, 1]])
        d = as_distortion(dist)
        ideal = undistort_points(uv, Km, d, to_pixels=True) if np.any(d) else uv

    n = len(X)
    dof_model = 7 if f_estimated else 6
    base = np.concatenate([intr0, d])
    sel = np.zeros((10, 1 if f_estimated else 0))
    if f_estimated:
        sel[0, 0] = sel[1, 0] = 1.0
    # Local optimisation of the best hypotheses (Chum, Matas & Kittler 2003): a 4-point
    # hypothesis carries the noise of its 4 clicks, so each of the few best is refined on the
    # points it fits (at least half of them) and scored again by its median.
    half = max(4, (n + 1) // 2 + 1)
    best: tuple[float, Array, Array, int] | None = None
    for f0, rv0, t0 in _best_hypotheses(X, ideal, intr0, f_estimated, seed):
        g0 = np.array([f0]) if f_estimated else np.zeros(0)
        loc0 = np.concatenate([rv0, t0])[None]
        err0 = _errors(X, ideal, g0, loc0, intr0, f_estimated)
        mask = err0 < _threshold(_robust_sigma(err0, n, dof_model), min_threshold_px)
        mask[np.argsort(err0)[:half]] = True
        g1, loc1, it, _ = _refine(X, uv, mask, g0, loc0, base, sel)
        score = float(np.median(_errors(X, ideal, g1, loc1, intr0, f_estimated)))
        if best is None or score < best[0]:
            best = (score, g1, loc1, it)
    assert best is not None
    _, g, loc, iterations = best
    err = _errors(X, ideal, g, loc, intr0, f_estimated)
    sigma = _robust_sigma(err, n, dof_model)
    inliers = err < _threshold(sigma, min_threshold_px)
    for _ in range(5):
        if np.count_nonzero(inliers) < 4:
            raise DegenerateConfiguration(
                f"only {np.count_nonzero(inliers)} of {n} points agree on one camera; check the "
                "pairs (each pixel must be the image of its floor point) and add points"
            )
        g, loc, it, problem = _refine(X, uv, inliers, g, loc, base, sel)
        iterations += it
        new = _consistent(problem, g, loc, X, uv, inliers, dof_model, min_threshold_px)
        if np.array_equal(new, inliers):
            break
        inliers = new
    full = problem.full(g)
    res_all = project_points(X, loc[0, :3], loc[0, 3:], intrinsics_to_matrix(full[:5]), d)
    res = res_all.points - uv
    err = np.linalg.norm(res, axis=1)
    if np.any(res_all.depth[inliers] <= 0):
        raise DegenerateConfiguration(
            "the fitted camera sees some points from behind; the pairs are inconsistent (a "
            "pixel matched to the wrong floor point?)"
        )
    return _result(problem, g, loc, X, uv, res, err, inliers, d, f_estimated, iterations)


def _robust_sigma(err: Array, n: int, d: int) -> float:
    """Return the robust scale of one pixel coordinate from the errors |e| of n points: |e| of
    an isotropic Gaussian pixel is Rayleigh with median 1.1774 sigma, and (1 + 5 / (2n - d))
    corrects the median of few residuals (Rousseeuw & Leroy 1987, eq. 4.1.9, with 2n residuals
    and d parameters)."""
    return float(np.median(err)) / 1.1774 * (1.0 + 5.0 / max(2 * n - d, 1))


def _threshold(sigma: float, min_threshold_px: float) -> float:
    """Return the inlier threshold on |e|: 3.5 sigma, under which a good point falls with
    probability 1 - exp(-3.5^2 / 2) = 99.8 %, never below min_threshold_px."""
    return max(3.5 * sigma, min_threshold_px)


def _consistent(
    problem: ReprojectionProblem,
    g: Array,
    loc: Array,
    X: Array,
    uv: Array,
    inliers: NDArray[np.bool_],
    d: int,
    min_threshold_px: float,
) -> NDArray[np.bool_]:
    """Return which points agree with the least-squares fit of the `inliers`.

    Each point's residual e_i is tested as a prediction of the others (regression diagnostics,
    Cook & Weisberg 1982): with H_i = J_i (J^T J)^-1 J_i^T (2 x 2, J the inliers' Jacobian), a
    fitted point's residual has covariance sigma^2 (I - H_i) and an excluded point's
    sigma^2 (I + H_i), so q_i = e_i^T (I -+ H_i)^-1 e_i / sigma^2 is chi-square with 2 dof
    whether the point was fitted or not. sigma^2 is robust: the median of q_i sigma^2 over all
    points over the chi-square median 2 ln 2, with the small-sample factor (1 + 5 / (2n - d))^2
    (Rousseeuw & Leroy 1987, eq. 4.1.9). A point agrees when q_i < 3.5^2 (a good point fails
    with probability exp(-3.5^2 / 2) = 0.2 %) or |e_i| < min_threshold_px.
    """
    n = len(X)
    _, jg, jl = problem.jacobians(g, loc)
    J = np.concatenate([jg[0], jl[0]], axis=1)
    full = problem.full(g)
    proj = project_points(
        X, loc[0, :3], loc[0, 3:], intrinsics_to_matrix(full[:5]), full[5:], jacobians=True
    )
    assert proj.d_pose is not None and proj.d_intrinsics is not None
    e = proj.points - uv
    Ji = np.concatenate([proj.d_intrinsics @ problem.P[:5], proj.d_pose], axis=2)  # (N, 2, p+6)
    Hi = Ji @ np.linalg.pinv(J.T @ J) @ Ji.transpose(0, 2, 1)
    sign = np.where(inliers, -1.0, 1.0)[:, None, None]
    C = np.eye(2) + sign * Hi
    det = C[:, 0, 0] * C[:, 1, 1] - C[:, 0, 1] * C[:, 1, 0]
    # A fitted point of leverage ~1 cannot be tested (the fit passes through it): q = 0.
    testable = det > 1e-6
    Ci = np.linalg.inv(np.where(testable[:, None, None], C, np.eye(2)))
    q = np.where(testable, np.einsum("ni,nij,nj->n", e, Ci, e), 0.0)
    sigma2 = float(np.median(q[testable])) / (2.0 * np.log(2.0)) if np.any(testable) else 0.0
    sigma2 *= (1.0 + 5.0 / max(2 * n - d, 1)) ** 2
    agree = (q < 3.5**2 * sigma2) | (np.linalg.norm(e, axis=1) < min_threshold_px)
    return np.asarray(agree, dtype=bool)


def _refine(
    X: Array, uv: Array, mask: NDArray[np.bool_], g: Array, loc: Array, base: Array, sel: Array
) -> tuple[Array, Array, int, ReprojectionProblem]:
    """Return (g, loc, iterations, problem) of the LM on the points of `mask`."""
    m = int(np.count_nonzero(mask))
    problem = ReprojectionProblem(X[mask][None], uv[mask][None], np.ones((1, m), bool), base, sel)
    sol = solve_sparse_lm(problem, g, loc, max_iterations=100, ftol=1e-14)
    return sol.x_global, sol.x_local, sol.iterations, problem


def _world(points: ArrayLike) -> Array:
    a = np.asarray(points)
    if a.ndim == 2 and a.shape[1] == 2:
        p = as_points(a, 2, "world_points", min_count=4)
        return np.concatenate([p, np.zeros((len(p), 1))], axis=1)
    return as_points(a, 3, "world_points", min_count=4)


def _check_spread(p: Array, name: str, min_spread: float, unit: str) -> None:
    """Raise DegenerateConfiguration when the points are at one spot or on one line."""
    q = p - p.mean(axis=0)
    sv = np.linalg.svd(q, compute_uv=False) / np.sqrt(len(p))
    if sv[0] < min_spread:
        raise DegenerateConfiguration(
            f"all {name} are within {sv[0]:.3g} {unit} of one spot; spread the points over the "
            f"camera's view of the floor (at least {min_spread} {unit} apart)"
        )
    if sv[1] < COLLINEAR_RATIO * sv[0]:
        raise DegenerateConfiguration(
            f"the {name} lie on a line; add points away from that line (a floor plane needs "
            "points spread in two directions)"
        )


def _samples(index: NDArray[np.intp], rng: np.random.Generator) -> NDArray[np.intp]:
    """Return (K, 4) index samples: all 4-subsets of `index`, or MAX_SAMPLES distinct random
    ones when there are more."""
    k = len(index)
    total = k * (k - 1) * (k - 2) * (k - 3) // 24
    if total <= MAX_SAMPLES:
        return np.array(list(combinations(index, 4)), dtype=np.intp).reshape(-1, 4)
    draws = np.argsort(rng.random((MAX_SAMPLES, k)), axis=1)[:, :4]
    return index[np.sort(draws, axis=1)]


def _normalise(p: Array) -> tuple[Array, Array]:
    c = p.mean(axis=0)
    s = np.sqrt(2.0) / max(float(np.mean(np.linalg.norm(p - c, axis=1))), 1e-300)
    T = np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])
    return T, (p - c) * s


def _best_hypotheses(
    X: Array,
    ideal: Array,
    intr0: Array,
    f_estimated: bool,
    seed: int | np.random.Generator | None,
    keep: int = 4,
) -> list[tuple[float, Array, Array]]:
    """Return (f, rvec, t) of the `keep` hypotheses of least median of squares (module
    docstring), best first."""
    z = np.round(X[:, 2] / _HEIGHT_TOL)
    values, counts = np.unique(z, return_counts=True)
    if counts.max() < 4:
        raise NotEnoughPoints(
            "at least 4 points must share one height (e.g. 4 on the floor, z = 0) to start the "
            "fit; add floor points"
        )
    z0 = float(values[np.argmax(counts)] * _HEIGHT_TOL)
    plane = np.flatnonzero(z == values[np.argmax(counts)])
    _check_spread(X[plane, :2], "points of one height", MIN_SPREAD_M, "m")
    samples = _samples(plane, np.random.default_rng(seed))
    Ts, ps = _normalise(X[:, :2])
    Td, pd = _normalise(ideal)
    hn, valid = _four_point_homographies(ps[samples], pd[samples])
    H = np.linalg.solve(Td, hn[valid] @ Ts)
    samples = samples[valid]
    cx, cy = intr0[2], intr0[3]
    fronto = 0
    if f_estimated:
        # The focal length of each hypothesis by the closed form (one 2 x 2 solve each).
        focal = np.full(len(H), np.nan)
        for k, Hk in enumerate(H):
            try:
                focal[k] = focal_from_homography(Hk, (cx, cy))[0]
            except DegenerateConfiguration:
                fronto += 1
        good = np.isfinite(focal)
        H, samples, focal = H[good], samples[good], focal[good]
        Ks = intrinsics_to_matrix(
            np.stack([focal, focal, *np.broadcast_arrays(cx, cy, 0.0 * focal)], -1)
        )
    else:
        focal = np.zeros(len(H))
        Ks = np.broadcast_to(intrinsics_to_matrix(intr0), (len(H), 3, 3))
    if len(H) == 0:
        scored: list[tuple[float, float, Array, Array]] = []
    else:
        # Every hypothesis at once: pose_from_homography of K^-1 H with K = I.
        pose = pose_from_homography(np.linalg.solve(Ks, H), np.eye(3), X[samples, :2])
        # The homography is of the plane z = z0: move its origin back to the world's.
        t_all = pose.t - pose.R[..., :, 2] * z0
        Xc = np.einsum("kij,nj->kni", pose.R, X) + t_all[:, None, :]
        depth = Xc[..., 2]
        xh = Xc / np.where(depth > 0, depth, 1.0)[..., None]
        pix = np.einsum("kij,knj->kni", Ks, xh)[..., :2]
        e2 = np.where(depth > 0, np.sum((pix - ideal) ** 2, axis=-1), np.inf)
        score = np.median(e2, axis=1)
        order = [int(k) for k in np.argsort(score) if np.isfinite(score[k])]
        scored = [
            (float(score[k]), float(focal[k]), matrix_to_rotvec(pose.R[k]), t_all[k])
            for k in order[:keep]
        ]
    if not scored:
        if f_estimated and fronto:
            raise DegenerateConfiguration(
                "these points give no focal length: the floor is seen face-on (or nearly) or "
                "the points do not fit a pinhole camera with a centred principal point; give "
                "the camera's intrinsics (calibrate it with a chessboard) or add points"
            )
        raise DegenerateConfiguration(
            "no camera puts these points in front of it; check that each pixel matches its "
            "floor point"
        )
    return [(f, rv, t) for _, f, rv, t in scored]


def _errors(X: Array, ideal: Array, g: Array, loc: Array, intr0: Array, f_estimated: bool) -> Array:
    intr = intr0.copy()
    if f_estimated:
        intr[0] = intr[1] = g[0]
    proj = project_points(X, loc[0, :3], loc[0, 3:], intrinsics_to_matrix(intr))
    return np.asarray(np.linalg.norm(proj.points - ideal, axis=1), np.float64)


def _camera_in_world(params: Array, p: int) -> tuple[Array, Array]:
    """Return (R_world_camera, centre) of (f?, rvec, t) parameters."""
    R = rotvec_to_matrix(params[p : p + 3])
    return R.T, -R.T @ params[p + 3 : p + 6]


def _result(
    problem: ReprojectionProblem,
    g: Array,
    loc: Array,
    X: Array,
    uv: Array,
    res: Array,
    err: Array,
    inliers: NDArray[np.bool_],
    d: Array,
    f_estimated: bool,
    iterations: int,
) -> CameraPlacement:
    r, jg, jl = problem.jacobians(g, loc)
    J = np.concatenate([jg[0], jl[0]], axis=1)
    p = len(g)
    m = int(np.count_nonzero(inliers))
    dof = 2 * m - J.shape[1]
    s2 = float(np.sum(r * r)) / dof if dof > 0 else float("nan")
    info = J.T @ J
    if np.linalg.cond(info) > 1e14:
        raise DegenerateConfiguration(
            "the points do not determine the camera (information matrix singular); spread them "
            "over the floor"
        )
    cov = s2 * np.linalg.inv(info)
    x = np.concatenate([g, loc[0]])
    R_wc, C = _camera_in_world(x, p)
    # d(centre, world rotation angles) / d(f?, rvec, t) by central differences: the map is
    # smooth and 7 x 6 small, so a step of 1e-6 of each parameter's scale is accurate to 1e-9.
    Jw = np.zeros((6, len(x)))
    for k in range(len(x)):
        step = 1e-6 * max(abs(x[k]), 1.0)
        hi, lo = x.copy(), x.copy()
        hi[k] += step
        lo[k] -= step
        R_hi, C_hi = _camera_in_world(hi, p)
        R_lo, C_lo = _camera_in_world(lo, p)
        Jw[:3, k] = (C_hi - C_lo) / (2 * step)
        Jw[3:, k] = (matrix_to_rotvec(R_hi @ R_wc.T) - matrix_to_rotvec(R_lo @ R_wc.T)) / (2 * step)
    cw = Jw @ cov @ Jw.T
    std = np.sqrt(np.maximum(np.diag(cw), 0.0))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_wc, C
    full = problem.full(g)
    return CameraPlacement(
        T_world_camera=T,
        K=intrinsics_to_matrix(full[:5]),
        dist=d.copy(),
        f_estimated=f_estimated,
        residuals=res,
        residuals_px=err,
        inliers=inliers,
        rejected=np.flatnonzero(~inliers),
        rms=float(np.sqrt(np.mean(err[inliers] ** 2))),
        std_position_m=std[:3],
        std_rotation_deg=np.degrees(std[3:]),
        std_f_px=float(np.sqrt(max(cov[0, 0], 0.0))) if f_estimated else None,
        covariance=cov,
        iterations=iterations,
    )
