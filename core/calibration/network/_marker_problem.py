"""The joint maximum a-posteriori refinement of the marker calibration (step 2 of
core.calibration.network._marker's docstring) as a problem for core.optim: every camera's free
intrinsics and pose and the odometry increments' corrections, their whitened residuals and
Jacobians."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.calibration.network._intrinsics_prior import INTRINSIC_PARAMETERS, IntrinsicsPrior
from core.calibration.network._marker_image import disc_centre_offset
from core.calibration.network._marker_layout import MarkerLayout
from core.calibration.network._odometry import (
    OdometryPrior,
    compose_increments,
    increment_jacobian,
)
from core.geometry.camera import intrinsics_to_matrix, project_points
from core.geometry.rotations import rotvec_to_matrix

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ProblemCamera:
    """A camera in the refinement: its name, its index among the caller's cameras, its
    intrinsics prior, its initial pose (rvec, t world-to-camera) and the columns it saw."""

    name: str
    index: int  # into the caller's cameras
    prior: IntrinsicsPrior
    rvec: Array
    t: Array
    seen: NDArray[np.bool_]


def chol_whitener(cov: Array) -> Array:
    """Return W (..., n, n) with W^T W = cov^-1."""
    return np.swapaxes(np.linalg.cholesky(np.linalg.inv(cov)), -1, -2)


class MarkerProblem:
    """The joint refinement (core.calibration.network._marker, step 2) for
    core.optim.solve_sparse_lm, as one dense block: global = every camera's (free intrinsics,
    rvec, t), then eps (3 M)."""

    def __init__(
        self,
        cams: Sequence[ProblemCamera],
        pixels: Array,
        whiten: Array,
        used: NDArray[np.bool_],
        odometry: OdometryPrior,
        layout: MarkerLayout,
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
        self.Lc = [chol_whitener(c.prior.cov) if len(c.prior.names) else None for c in cams]
        self.Lj = chol_whitener(odometry.cov)  # (M, 3, 3)

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
        """Return the markers' world points (N, 3) and d X / d pose (N, 3, 3) (`MarkerLayout`)."""
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
