"""The linear ground estimators: the DLT triangulation of the 3-D point (`triangulate_linear`)
and the same equations with Z = h imposed (`triangulate_on_plane`), solved by their normal
equations in closed form, vectorised over the batch, with the exact first-order covariance."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.localization._checks import check_height
from core.localization._projection import inv2, inv3, transposed
from core.localization.cameras import NetworkCamera
from core.localization.ground._batch import Raw, run_estimator
from core.localization.ground._estimate import FloorEstimate, PointStatus
from core.localization.ground._observations import (
    Observations,
    check_min_cameras,
    normalized,
    parse_observations,
)

Array = NDArray[np.float64]

# A normal matrix whose det / (trace / n)^n falls below this is treated as singular: the rays do
# not fix the point (parallel to the plane, or to each other for the 3-D triangulation).
_SINGULAR_TOL = 1e-12


@dataclass(frozen=True)
class LinearSolution:
    """The linear least-squares solution of a batch, with its covariance and status per target."""

    theta: Array  # (B, n) the unknowns: (X, Y, Z) or (X, Y)
    cov: Array  # (B, n, n)
    status: NDArray[np.int8]
    n_cameras: NDArray[np.int64]


def solve_linear(obs: Observations, height: float | None, min_cameras: int) -> LinearSolution:
    """Linear least squares on the DLT equations, unknowns (X, Y, Z) or (X, Y) at Z = height.

    Camera k with ideal normalised coordinates m = (x, y) gives two equations linear in the
    point (H&Z eq. 12.1 written with the calibrated P = [R | t], so that they read in normalised
    image units): x (R_3 X + t_3) - (R_1 X + t_1) = 0 and y (R_3 X + t_3) - (R_2 X + t_2) = 0.
    Stacked, A theta = b, solved by the normal equations M theta = A^T b, M = A^T A (n x n,
    closed-form inverse, vectorised over the batch).

    First-order covariance: theta minimises 0.5 |r|^2 with r_i = a_i . theta - b_i, so the
    stationarity g = A^T r = 0 gives d theta / d x_k = -M^-1 d g / d x_k with
    d g / d x_k = R_3 r_{k,x} + a_{k,x} z_k (z_k the depth; likewise for y_k), and
    d theta / d u_k = (d theta / d m_k) B_k^-1 (B_k = d u / d m). Then
    cov = sum_k G_k S_k G_k^T with G_k = d theta / d u_k.
    """
    m, b_inv = normalized(obs)
    n = 3 if height is None else 2
    n_pts = obs.n_points
    M = np.zeros((n_pts, n, n))
    rhs = np.zeros((n_pts, n))
    rows = []
    for k, cam in enumerate(obs.cameras):
        R, t = cam.R, cam.t
        c = t if height is None else R[:, 2] * height + t
        w = obs.visible[k].astype(np.float64)
        x = m[k, :, 0]
        y = m[k, :, 1]
        # Unseen detections get zero rows, which leave the normal equations unchanged.
        ax = (x[:, None] * R[2, :n] - R[0, :n]) * w[:, None]
        ay = (y[:, None] * R[2, :n] - R[1, :n]) * w[:, None]
        bx = (c[0] - x * c[2]) * w
        by = (c[1] - y * c[2]) * w
        M += ax[:, :, None] * ax[:, None, :] + ay[:, :, None] * ay[:, None, :]
        rhs += ax * bx[:, None] + ay * by[:, None]
        rows.append((ax, ay, bx, by, c[2]))
    n_cam = obs.visible.sum(axis=0).astype(np.int64)
    m_inv, det = inv3(M) if n == 3 else inv2(M)
    scale = sum(M[:, i, i] for i in range(n)) / n
    singular = ~(det > _SINGULAR_TOL * scale**n)
    m_inv[singular] = 0.0
    theta = (m_inv @ rhs[:, :, None])[:, :, 0]

    cov = np.zeros((n_pts, n, n))
    behind = np.zeros(n_pts, dtype=bool)
    for k, cam in enumerate(obs.cameras):
        ax, ay, bx, by, c2 = rows[k]
        r3 = cam.R[2, :n]
        z = theta @ r3 + c2
        rx = (ax[:, None, :] @ theta[:, :, None])[:, 0, 0] - bx
        ry = (ay[:, None, :] @ theta[:, :, None])[:, 0, 0] - by
        vis = obs.visible[k]
        behind |= vis & ~(z > 0)
        gx = r3 * rx[:, None] + ax * z[:, None]
        gy = r3 * ry[:, None] + ay * z[:, None]
        G = -(m_inv @ np.stack([gx, gy], axis=-1)) @ b_inv[k]  # (B, n, 2)
        s = obs.cov_of(k, slice(None))
        if isinstance(s, float):
            cov += s * (G @ transposed(G))
        else:
            cov += G @ s @ transposed(G)
    status = np.zeros(n_pts, dtype=np.int8)
    status[behind] = PointStatus.BEHIND_CAMERA
    status[singular] = PointStatus.DEGENERATE
    status[n_cam < min_cameras] = PointStatus.TOO_FEW_CAMERAS
    return LinearSolution(theta, cov, status, n_cam)


def triangulate_linear(
    cameras: Sequence[NetworkCamera],
    pixels: ArrayLike,
    *,
    visible: ArrayLike | None = None,
    pixel_sigma: float = 1.0,
    pixel_cov: ArrayLike | None = None,
    min_cameras: int = 2,
) -> FloorEstimate:
    """Return the linearly triangulated 3-D points and their floor positions (X, Y).

    cameras: C cameras; pixels (C, B, 2) or (C, 2); visible (C, B) or (C,). Each target needs
    at least `min_cameras` >= 2 detections. Minimises the algebraic error of the 2 N equations of
    H&Z sec. 12.2 in normalised image coordinates (the inhomogeneous form, unknowns (X, Y, Z):
    floor targets are never at infinity). `point` is the 3-D point (its Z generally differs from
    the target's true height), `point_cov` its first-order covariance (3 x 3), `cov` the
    marginal covariance of (X, Y). A solution behind a camera that saw it is BEHIND_CAMERA.
    """
    n_min = check_min_cameras(min_cameras, 2)
    obs = parse_observations(cameras, pixels, visible, pixel_sigma, pixel_cov)
    return run_estimator(obs, "linear", None, n_min, lambda o: _linear_raw(o, n_min))


def _linear_raw(obs: Observations, min_cameras: int) -> Raw:
    sol = solve_linear(obs, None, min_cameras)
    return sol.theta, sol.cov, sol.status, sol.n_cameras, 0


def on_plane(theta: Array, cov: Array, height: float) -> tuple[Array, Array]:
    """Return floor positions (B, 2) as points (B, 3) at Z = height, with their (B, 2, 2)
    covariances as (B, 3, 3) (zero Z row and column)."""
    point = np.empty((theta.shape[0], 3))
    point[:, :2] = theta
    point[:, 2] = height
    point_cov = np.zeros((theta.shape[0], 3, 3))
    point_cov[:, :2, :2] = cov
    return point, point_cov


def triangulate_on_plane(
    cameras: Sequence[NetworkCamera],
    pixels: ArrayLike,
    height: float = 0.0,
    *,
    visible: ArrayLike | None = None,
    pixel_sigma: float = 1.0,
    pixel_cov: ArrayLike | None = None,
    min_cameras: int = 1,
) -> FloorEstimate:
    """Return floor positions by linear triangulation constrained to the plane Z = height.

    The DLT equations of `triangulate_linear` with Z = h substituted: 2 N equations in (X, Y),
    solved by linear least squares (closed-form 2 x 2 normal equations, no loop over targets).
    With one camera the two equations are exact and the result is the monocular intersection, so
    `min_cameras` defaults to 1; raise it to require a multi-camera fix. Covariance: the exact
    first-order propagation of the pixel covariance through this estimator (it is not
    efficient: compare `locate_ml`).
    """
    n_min = check_min_cameras(min_cameras, 1)
    h = check_height(height)
    obs = parse_observations(cameras, pixels, visible, pixel_sigma, pixel_cov)
    return run_estimator(obs, "constrained", h, n_min, lambda o: _constrained_raw(o, h, n_min))


def _constrained_raw(obs: Observations, height: float, min_cameras: int) -> Raw:
    sol = solve_linear(obs, height, min_cameras)
    point, point_cov = on_plane(sol.theta, sol.cov, height)
    return point, point_cov, sol.status, sol.n_cameras, 0
