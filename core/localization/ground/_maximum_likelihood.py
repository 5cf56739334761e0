"""The maximum-likelihood ground estimator: per target, the point of the plane Z = h whose
projections best fit the detections (whitened reprojection error), refined by the sparse
Levenberg-Marquardt of core.optim from the constrained linear estimate."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.localization._checks import check_height
from core.localization._projection import inv2, project_plane, whitening
from core.localization.cameras import NetworkCamera
from core.localization.ground._batch import Raw, run_estimator
from core.localization.ground._estimate import FloorEstimate, PointStatus
from core.localization.ground._linear import on_plane, solve_linear
from core.localization.ground._observations import (
    Observations,
    check_min_cameras,
    parse_observations,
)
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]


class _PlaneReprojection:
    """The ML problem as local blocks only: block j is target j's (X, Y), its residuals the
    whitened reprojection errors S^-1/2 (pi_k(X, Y, h) - u_k) of the cameras that saw it (zero
    rows for the others)."""

    def __init__(
        self,
        cameras: tuple[NetworkCamera, ...],
        pixels: Array,
        visible: NDArray[np.bool_],
        whiten: Array | None,
        pixel_sigma: float,
        height: float,
    ) -> None:
        self.cameras = cameras
        self.pixels = pixels
        self.visible = visible
        self.whiten = whiten
        self.inv_sigma = 1.0 / pixel_sigma
        self.height = height

    def _evaluate(self, xy: Array, jacobian: bool) -> tuple[Array, Array | None]:
        n_pts = xy.shape[0]
        n_cam = len(self.cameras)
        res = np.zeros((n_pts, 2 * n_cam))
        jac = np.zeros((n_pts, 2 * n_cam, 2)) if jacobian else None
        for k, cam in enumerate(self.cameras):
            p = project_plane(cam, xy, self.height, jacobian=jacobian)
            e = p.pixels - self.pixels[k]
            Jk = p.jacobian
            if self.whiten is None:
                e = e * self.inv_sigma
                Jk = None if Jk is None else Jk * self.inv_sigma
            else:
                e = (self.whiten[k] @ e[:, :, None])[:, :, 0]
                Jk = None if Jk is None else self.whiten[k] @ Jk
            vis = self.visible[k]
            res[:, 2 * k : 2 * k + 2] = np.where(vis[:, None], e, 0.0)
            if jac is not None and Jk is not None:
                jac[:, 2 * k : 2 * k + 2] = np.where(vis[:, None, None], Jk, 0.0)
        return res, jac

    def residuals(self, x_global: Array, x_local: Array) -> Array:
        return self._evaluate(x_local, False)[0]

    def jacobians(self, x_global: Array, x_local: Array) -> tuple[Array, Array, Array]:
        res, jac = self._evaluate(x_local, True)
        assert jac is not None
        return res, np.zeros((x_local.shape[0], res.shape[1], 0)), jac


def locate_ml(
    cameras: Sequence[NetworkCamera],
    pixels: ArrayLike,
    height: float = 0.0,
    *,
    visible: ArrayLike | None = None,
    pixel_sigma: float = 1.0,
    pixel_cov: ArrayLike | None = None,
    min_cameras: int = 1,
    max_iterations: int = 50,
) -> FloorEstimate:
    """Return the maximum-likelihood floor positions on the plane Z = height.

    Minimises, per target, sum_k (pi_k(X, Y, h) - u_k)^T S_k^-1 (pi_k(X, Y, h) - u_k) over
    (X, Y) for Gaussian pixel noise of covariance S_k (sigma^2 I by default), starting from
    `triangulate_on_plane`. This is H&Z's optimal triangulation (sec. 12.3) restricted to the
    plane: equivalently, the image points corrected to be consistent with one point of the plane.
    The targets are refined together (in chunks) by the sparse Levenberg-Marquardt of
    core.optim with local blocks only (one 2-vector per target, no shared parameters), so the
    cost is linear in B.

    Covariance: (sum_k J_k^T S_k^-1 J_k)^-1 with J_k = d pi_k / d(X, Y) at the estimate, the
    inverse Fisher information, which the ML estimate attains to first order (the Cramer-Rao
    bound of core.localization.bounds, evaluated at the estimate instead of the truth).
    `iterations` reports the LM iterations (the largest over the chunks of a large batch).
    """
    n_min = check_min_cameras(min_cameras, 1)
    h = check_height(height)
    if int(max_iterations) != max_iterations or max_iterations < 0:
        raise InvalidInput(f"max_iterations must be a non-negative integer, got {max_iterations}")
    obs = parse_observations(cameras, pixels, visible, pixel_sigma, pixel_cov)
    n_iter = int(max_iterations)
    return run_estimator(obs, "ml", h, n_min, lambda o: _ml_raw(o, h, n_min, n_iter))


def _ml_raw(obs: Observations, h: float, n_min: int, max_iterations: int) -> Raw:
    init = solve_linear(obs, h, n_min)
    status = init.status.copy()
    theta = init.theta.copy()
    cov = np.full((obs.n_points, 2, 2), np.nan)
    idx = np.flatnonzero(status == PointStatus.OK)
    iterations = 0
    if idx.size:
        whiten = None if obs.pixel_cov is None else whitening(obs.pixel_cov[:, idx])
        problem = _PlaneReprojection(
            obs.cameras, obs.pixels[:, idx], obs.visible[:, idx], whiten, obs.pixel_sigma, h
        )
        fit = solve_sparse_lm(
            problem,
            np.zeros(0),
            theta[idx],
            max_iterations=max_iterations,
            n_residuals=2 * int(obs.visible[:, idx].sum()),
        )
        iterations = fit.iterations
        theta[idx] = fit.x_local
        cov_idx, det = inv2(fit.local_information)
        finite = np.all(np.isfinite(fit.x_local), axis=1) & (det > 0)
        depth_ok = np.zeros(idx.size, dtype=bool)
        depth_ok[finite] = True
        for k, cam in enumerate(obs.cameras):
            z = fit.x_local[finite] @ cam.R[2, :2] + (cam.R[2, 2] * h + cam.t[2])
            depth_ok[finite] &= ~obs.visible[k, idx[finite]] | (z > 0)
        cov[idx] = cov_idx
        status[idx[~finite]] = PointStatus.DEGENERATE
        status[idx[finite & ~depth_ok]] = PointStatus.BEHIND_CAMERA
    point, point_cov = on_plane(theta, cov, h)
    return point, point_cov, status, init.n_cameras, iterations
