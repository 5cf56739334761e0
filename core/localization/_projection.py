"""Projection of floor points and the small Jacobians every localisation estimator shares.

For a point (X, Y) on the plane Z = h seen by camera k (Xc = R X + t, pixel u = pi_k(Xc)):

    J_k = d u / d(X, Y) = (d u / d Xc) R[:, :2]                                  (2 x 2)

and for ideal normalised coordinates m = (x, y) (undistorted, K^-1 removed):

    B_k = d u / d m = [[fx, s], [0, fy]] d(distortion) / d m                     (2 x 2)

Both come from the analytic Jacobians of core.geometry.camera.project_points: the derivative
with respect to the translation equals the derivative with respect to Xc.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.geometry.camera import project_points
from core.localization.cameras import NetworkCamera

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PlaneProjection:
    """Pixels (B, 2), camera-frame depths (B,) and, if asked, J = d pixel / d(X, Y) (B, 2, 2)."""

    pixels: Array
    depth: Array
    jacobian: Array | None


def project_plane(
    camera: NetworkCamera, xy: Array, height: float, *, jacobian: bool = False
) -> PlaneProjection:
    """Return the projection of floor points xy (B, 2) at Z = height into `camera`."""
    X = np.empty((xy.shape[0], 3))
    X[:, :2] = xy
    X[:, 2] = height
    p = project_points(X, camera.rvec, camera.t, camera.K, camera.dist, jacobians=jacobian)
    J = None
    if jacobian:
        assert p.d_pose is not None
        J = p.d_pose[:, :, 3:] @ camera.R[:, :2]
    return PlaneProjection(pixels=p.points, depth=p.depth, jacobian=J)


def normalized_to_pixel_jacobian(camera: NetworkCamera, m: Array) -> Array:
    """Return B = d pixel / d m (B, 2, 2) at ideal normalised coordinates m (B, 2)."""
    Xc = np.empty((m.shape[0], 3))
    Xc[:, :2] = m
    Xc[:, 2] = 1.0
    zero = np.zeros(3)
    p = project_points(Xc, zero, zero, camera.K, camera.dist, jacobians=True)
    assert p.d_pose is not None
    # At depth 1, d pixel / d Xc restricted to (Xc_x, Xc_y) is exactly d pixel / d m.
    return p.d_pose[:, :, 3:5]


def inv2(a: Array) -> tuple[Array, Array]:
    """Return (inverses (..., 2, 2), determinants (...)) of 2x2 matrices (..., 2, 2).

    Closed form; singular matrices give non-finite entries, which callers mask.
    """
    det = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    out = np.empty_like(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_det = 1.0 / det
        out[..., 0, 0] = a[..., 1, 1] * inv_det
        out[..., 0, 1] = -a[..., 0, 1] * inv_det
        out[..., 1, 0] = -a[..., 1, 0] * inv_det
        out[..., 1, 1] = a[..., 0, 0] * inv_det
    return out, det


def inv3(a: Array) -> tuple[Array, Array]:
    """Return (inverses (..., 3, 3), determinants (...)) of 3x3 matrices by the adjugate."""
    c00 = a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1]
    c01 = a[..., 1, 2] * a[..., 2, 0] - a[..., 1, 0] * a[..., 2, 2]
    c02 = a[..., 1, 0] * a[..., 2, 1] - a[..., 1, 1] * a[..., 2, 0]
    det = a[..., 0, 0] * c00 + a[..., 0, 1] * c01 + a[..., 0, 2] * c02
    adj = np.empty_like(a)
    adj[..., 0, 0] = c00
    adj[..., 1, 0] = c01
    adj[..., 2, 0] = c02
    adj[..., 0, 1] = a[..., 0, 2] * a[..., 2, 1] - a[..., 0, 1] * a[..., 2, 2]
    adj[..., 1, 1] = a[..., 0, 0] * a[..., 2, 2] - a[..., 0, 2] * a[..., 2, 0]
    adj[..., 2, 1] = a[..., 0, 1] * a[..., 2, 0] - a[..., 0, 0] * a[..., 2, 1]
    adj[..., 0, 2] = a[..., 0, 1] * a[..., 1, 2] - a[..., 0, 2] * a[..., 1, 1]
    adj[..., 1, 2] = a[..., 0, 2] * a[..., 1, 0] - a[..., 0, 0] * a[..., 1, 2]
    adj[..., 2, 2] = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return adj / det[..., None, None], det


def whitening(cov: Array) -> Array:
    """Return W = L^-1 (..., 2, 2) with cov = L L^T (Cholesky), so that W e has unit covariance.

    Non-positive-definite inputs give non-finite entries; the caller validates covariances first.
    """
    a = cov[..., 0, 0]
    b = cov[..., 1, 0]
    c = cov[..., 1, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        l11 = np.sqrt(a)
        l21 = b / l11
        l22 = np.sqrt(c - l21 * l21)
        W = np.zeros_like(cov)
        W[..., 0, 0] = 1.0 / l11
        W[..., 1, 0] = -l21 / (l11 * l22)
        W[..., 1, 1] = 1.0 / l22
    return W
