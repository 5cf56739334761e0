"""Registering a calibrated camera network to the world by points known in both frames (02 §1).

The marker drive fixes the network's frame by the robot's start pose: its heading is known to
the cameras only through the odometry of the first metres driven, whose slip (about 0.6 degree
per metre on the default robot) the Cramer-Rao bound carries into every camera. Points whose
world position is known without the odometry (the robot's marker where the robot read a
signpost, whose payload carries its pose in the world) and whose position the network measures
tie the frame to the world instead.

`register_planar` estimates the floor rigid motion (theta about the vertical, then tx, ty)
taking network coordinates to the world, w = R(theta) n + t, from K >= 2 pairs with their 2 x 2
covariances, by weighted least squares: residual r_k = R n_k + t - w_k with weight
(C_w,k + R C_n,k R^T)^-1, started from the weighted Procrustes solution and refined by
Gauss-Newton; the covariance of (theta, tx, ty) is the inverse of J^T W J scaled by the measured
residual variance when K > 2 pairs (chi-square per degree of freedom, floored at one: a scatter
smaller than claimed does not shrink the claim). `registered` applies it to every camera (and
the refined robot poses) of a `NetworkCalibration`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.calibration.network._records import NetworkCalibration
from core.errors import DegenerateConfiguration, InvalidInput
from core.geometry.rotations import wrap_angle

Array = NDArray[np.float64]

# Pairs closer than this (m) to their centroid do not fix a heading.
MIN_SPREAD_M = 0.5


@dataclass(frozen=True)
class PlanarRegistration:
    """w = R(theta) n + t: `theta` radians, `t` (2,) metres, `cov` (3, 3) of (theta, tx, ty),
    `residuals` (K, 2) metres (R n_k + t - w_k), `chi2` the whitened residuals' sum of
    squares (2K - 3 degrees of freedom)."""

    theta: float
    t: Array
    cov: Array
    residuals: Array
    chi2: float

    @property
    def matrix(self) -> Array:
        """The motion as a 4 x 4 transform (rotation about Z, translation in the floor)."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        T = np.eye(4)
        T[:2, :2] = [[c, -s], [s, c]]
        T[:2, 3] = self.t
        return T

    @property
    def theta_std_deg(self) -> float:
        """Standard deviation of theta, degrees."""
        return float(np.degrees(math.sqrt(max(self.cov[0, 0], 0.0))))


def _as_points(value: ArrayLike, name: str) -> Array:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be numeric, shape (K, 2): {exc}") from None
    if a.ndim != 2 or a.shape[1] != 2:
        raise InvalidInput(f"{name} must have shape (K, 2), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidInput(f"{name} contains NaN or infinite values")
    return a


def _as_covs(value: ArrayLike, k: int, name: str) -> Array:
    try:
        c = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be numeric, shape (K, 2, 2): {exc}") from None
    if c.shape != (k, 2, 2) or not np.all(np.isfinite(c)):
        raise InvalidInput(f"{name} must be {k} finite 2 x 2 covariances, got shape {c.shape}")
    if np.any(np.linalg.eigvalsh(0.5 * (c + np.swapaxes(c, 1, 2)))[:, 0] <= 0):
        raise InvalidInput(f"{name} must be positive definite")
    return c


def register_planar(
    network_xy: ArrayLike,
    network_cov: ArrayLike,
    world_xy: ArrayLike,
    world_cov: ArrayLike,
    *,
    iterations: int = 10,
) -> PlanarRegistration:
    """Return the floor rigid motion taking `network_xy` (K, 2) to `world_xy` (K, 2), each
    with covariances (K, 2, 2) (module docstring). Raises InvalidInput for bad shapes or
    values and DegenerateConfiguration for fewer than 2 pairs or pairs within MIN_SPREAD_M of
    their centroid (no heading)."""
    n = _as_points(network_xy, "network_xy")
    w = _as_points(world_xy, "world_xy")
    if n.shape != w.shape:
        raise InvalidInput(f"network_xy {n.shape} and world_xy {w.shape} must match")
    k = len(n)
    Cn = _as_covs(network_cov, k, "network_cov")
    Cw = _as_covs(world_cov, k, "world_cov")
    if k < 2:
        raise DegenerateConfiguration(f"registration needs at least 2 points, got {k}")
    spread = float(np.max(np.linalg.norm(w - w.mean(0), axis=1)))
    if spread < MIN_SPREAD_M:
        raise DegenerateConfiguration(
            f"registration points lie within {spread:.2f} m of their centroid (need "
            f"{MIN_SPREAD_M} m): they fix no heading"
        )
    # Weighted Procrustes (scalar weights: the covariances' traces) to start.
    a = 1.0 / (np.trace(Cn, axis1=1, axis2=2) + np.trace(Cw, axis1=1, axis2=2))
    nc = (a[:, None] * n).sum(0) / a.sum()
    wc = (a[:, None] * w).sum(0) / a.sum()
    dn, dw = n - nc, w - wc
    theta = math.atan2(
        float(np.sum(a * (dn[:, 0] * dw[:, 1] - dn[:, 1] * dw[:, 0]))),
        float(np.sum(a * (dn[:, 0] * dw[:, 0] + dn[:, 1] * dw[:, 1]))),
    )
    c, s = math.cos(theta), math.sin(theta)
    t = wc - np.array([[c, -s], [s, c]]) @ nc
    p = np.array([theta, *t])
    for _ in range(iterations):
        r, J, Wt = _linearised(p, n, w, Cn, Cw)
        H = np.einsum("kai,kab,kbj->ij", J, Wt, J)
        g = np.einsum("kai,kab,kb->i", J, Wt, r)
        step = np.linalg.solve(H, -g)
        p = p + step
        if np.max(np.abs(step)) < 1e-12:
            break
    r, J, Wt = _linearised(p, n, w, Cn, Cw)
    H = np.einsum("kai,kab,kbj->ij", J, Wt, J)
    chi2 = float(np.einsum("ka,kab,kb->", r, Wt, r))
    dof = 2 * k - 3
    scale = max(chi2 / dof, 1.0) if dof > 0 else 1.0
    return PlanarRegistration(
        theta=float(p[0]), t=p[1:].copy(), cov=np.linalg.inv(H) * scale, residuals=r, chi2=chi2
    )


def _linearised(p: Array, n: Array, w: Array, Cn: Array, Cw: Array) -> tuple[Array, Array, Array]:
    """Return the residuals (K, 2), their Jacobians d r / d (theta, tx, ty) (K, 2, 3) and
    the weights (K, 2, 2) at p = (theta, tx, ty)."""
    c, s = math.cos(p[0]), math.sin(p[0])
    R = np.array([[c, -s], [s, c]])
    dR = np.array([[-s, -c], [c, -s]])
    r = n @ R.T + p[1:] - w
    J = np.zeros((len(n), 2, 3))
    J[:, :, 0] = n @ dR.T
    J[:, :, 1:] = np.eye(2)
    Wt = np.linalg.inv(Cw + R @ Cn @ R.T)
    return r, J, Wt


def registered(calibration: NetworkCalibration, reg: PlanarRegistration) -> NetworkCalibration:
    """Return `calibration` moved into the world by `reg` (w = R n + t, about the vertical):
    every camera's pose (R_cw' = R_cw R^T, t' = t - R_cw' t_reg) and the refined robot poses
    with their covariances. The cameras' own parameter covariances are those of the network's
    frame; `reg.cov` is what the registration adds."""
    T = reg.matrix
    Rz, tz = T[:3, :3], T[:3, 3]
    cams = []
    for cam in calibration.cameras:
        R = cam.R @ Rz.T
        cams.append(
            replace(
                cam,
                R=R,
                t=cam.t - R @ tz,
                initial_R=cam.initial_R @ Rz.T,
                initial_t=cam.initial_t - cam.initial_R @ Rz.T @ tz,
            )
        )
    P = np.asarray(calibration.targets, dtype=np.float64).copy()
    if P.size:
        P[:, :2] = P[:, :2] @ Rz[:2, :2].T + tz[:2]
        P[:, 2] = wrap_angle(P[:, 2] + reg.theta)
    G = np.eye(3)
    G[:2, :2] = Rz[:2, :2]
    cov = G @ np.asarray(calibration.target_cov) @ G.T if P.size else calibration.target_cov
    return replace(calibration, cameras=tuple(cams), targets=P, target_cov=cov)
